// The information panel and the assign step (issue 16) in Debian's headless Chromium against
// the real server, on a small generated relief imported through the real pipeline: the words of
// a query found again in rendered Markdown (Node); a part's information opened from its callout
// by keyboard and closed by Escape (focus back on the callout), the hover card gone once a
// click opens the panel; a search result whose matching paragraph, far down a long content, is
// marked and scrolled into the panel's view; a note written in the assign step of a new region
// (labelled fields, keyboard only, the server's message on a refused note) that becomes a
// content assigned to the part; the model page's assignment form picking a content by search,
// and without the picker a title or a wrong number sent back to the part with a message.

import { after, before, describe, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { searchTerms, variants } from '../../static/js/parts/match.js';
import { noteTitle } from '../../static/js/select/assign.js';
import { writeRelief } from './support/env.mjs';
import { ADMIN, homeDirection, importScan, seedPart, startServer } from './support/server.mjs';
import { launch, login, poll, waitViewer } from './support/browser.mjs';
import { capture } from './support/pixels.mjs';
import { leafVertices, regionAt } from './support/regions.mjs';
import { circle, drag, surfaceCentre, waitSelection } from './support/select.mjs';

test('the words of a query: phrases split, exclusions and operators dropped, light stems', () => {
  assert.deepEqual(searchTerms('Survey "May  campaign" -lost -"old text" title:Nose AND Éclat+'), ['survey', 'may', 'campaign', 'nose', 'eclat']);
  assert.deepEqual(searchTerms('   '), []);
  assert.ok(variants('noses').includes('nose'));
  assert.ok(variants('studies').includes('study'));
  assert.ok(variants('surveyed').includes('survey'));
  assert.deepEqual(variants('bus'), ['bus']);
  assert.equal(noteTitle('## The **north** [cornice](https://x.org)\n\nmore'), 'The north cornice');
  assert.equal(noteTitle('\n\n- first point\n'), 'first point');
  assert.equal(noteTitle('x'.repeat(100)).length, 80);
});

// A body whose matching paragraph is far below the panel's first screen.
const FILLER = Array.from({ length: 30 }, (_, k) => `Paragraph ${k + 1} of the condition survey: the surface is sound here.`);
const LONG_BODY = [...FILLER, 'The **tufa** block bears the quarry mark of the xylographer workshop.', 'Last paragraph.'].join('\n\n');

describe('the information panel and the assign step on the real server', () => {
  let server;
  let browser;
  let model;
  let seeded;
  let tmp;
  let rendering = true;
  const settled = (s) => s.settled && s.drawn > 0;

  before(async () => {
    tmp = mkdtempSync(join(tmpdir(), 'mw-panel-'));
    server = await startServer();
    model = await importScan(server.api, writeRelief(join(tmp, 'relief.ply'), 90), 'Panel test relief');
    const leaves = await leafVertices(join(server.dataDir, model.lod_path));
    const region = regionAt(leaves, [0, 0, 1], [0, 0, 0], 0.2);
    seeded = await seedPart(server.api, model.id, {
      title: 'Central dome',
      caption: 'The raised centre',
      body: LONG_BODY,
      vertexIds: region.ids,
      center: region.center,
    });
    const probe = await server.api.request('GET', `/api/v1/models/${model.id}/render?w=16&h=16`, { raw: true });
    if (probe.status === 503) {
      const msg = await probe.text();
      if (process.env.MESHWIKI_REQUIRE_GPU_TESTS === '1') throw new Error(`no renderer: ${msg}`);
      console.log(`# selections need a Vulkan adapter (lavapipe): the assign-step test is skipped: ${msg}`);
      rendering = false;
    }
    browser = await launch();
  });

  after(async () => {
    await browser?.close();
    await server?.stop();
    if (tmp) rmSync(tmp, { recursive: true, force: true });
  });

  /** Saves a screenshot when MESHWIKI_SHOTS names a directory (to look at the pages). */
  async function shot(page, name) {
    if (process.env.MESHWIKI_SHOTS) await page.screenshot({ path: join(process.env.MESHWIKI_SHOTS, `${name}.png`), fullPage: true });
  }

  async function openModel(query = '') {
    const page = await browser.page();
    await login(page, server.base, ADMIN);
    await page.goto(`${server.base}/models/${model.id}${query}`);
    return page;
  }

  test('a callout opens the panel by keyboard, Escape closes it; a click hides the hover card', async () => {
    const page = await openModel();
    await waitViewer(page, (s) => settled(s) && s.callouts.includes(seeded.part.id));
    const label = page.locator(`.callout[data-part-id="${seeded.part.id}"]`);
    const panel = page.locator('.viewer-panel');

    // Keyboard: focus the callout, Enter opens the information, Escape closes it.
    await label.focus();
    await page.keyboard.press('Enter');
    await panel.locator('.panel-content').waitFor({ timeout: 10_000 });
    assert.match(page.url(), new RegExp(`[?&]part=${seeded.part.id}`));
    await page.keyboard.press('Escape');
    await panel.waitFor({ state: 'hidden', timeout: 5_000 });
    assert.doesNotMatch(page.url(), /[?&]part=/, 'the closed part stays in the URL');
    assert.equal((await page.evaluate(() => window.meshwikiViewer.stats())).selected, null);

    // Focus inside the panel (its close button): Escape closes it and focus returns to the callout.
    await label.focus();
    await page.keyboard.press('Enter');
    await panel.locator('.panel-content').waitFor({ timeout: 10_000 });
    await panel.locator('.panel-close').focus();
    await page.keyboard.press('Escape');
    await panel.waitFor({ state: 'hidden', timeout: 5_000 });
    assert.equal(await page.evaluate(() => document.activeElement?.dataset.partId), String(seeded.part.id), 'focus not back on the callout');

    // Escape in the page's search field is the field's: the panel stays open.
    await label.focus();
    await page.keyboard.press('Enter');
    await panel.locator('.panel-content').waitFor({ timeout: 10_000 });
    await page.locator('.quick-search input').focus();
    await page.keyboard.press('Escape');
    assert.ok(await panel.isVisible(), 'Escape in the search field closed the panel');
    await panel.locator('.panel-close').click();
    await panel.waitFor({ state: 'hidden', timeout: 5_000 });

    // The hover card: shown over the part, gone once a click opens the panel, not back while
    // the pointer stays on the part whose information is open.
    const at = await page.evaluate((id) => window.meshwikiViewer.partScreen(id), seeded.part.id);
    const box = await page.locator('.viewer-canvas').boundingBox();
    await page.mouse.move(box.x + at.x, box.y + at.y);
    await waitViewer(page, (s) => s.hovered === seeded.part.id, 10_000);
    const preview = page.locator('.viewer-preview');
    await preview.waitFor({ state: 'visible', timeout: 5_000 });
    await page.mouse.click(box.x + at.x, box.y + at.y);
    await panel.locator('.panel-content').waitFor({ timeout: 10_000 });
    assert.ok(!(await preview.isVisible()), 'the hover card stays over the view after the click');
    // The panel narrowed the view: find the part again, and hover it there.
    await page.waitForTimeout(300);
    const at2 = await page.evaluate((id) => window.meshwikiViewer.partScreen(id), seeded.part.id);
    const box2 = await page.locator('.viewer-canvas').boundingBox();
    await page.mouse.move(box2.x + at2.x + 2, box2.y + at2.y + 1);
    await waitViewer(page, (s) => s.hovered === seeded.part.id, 10_000);
    await page.waitForTimeout(200);
    assert.ok(!(await preview.isVisible()), 'the hover card came back over the open part');
    await page.close();
  });

  test('the view keeps its width: the panel is a drawer over it, resized by its handle; the view is the reader\'s to light and steer', async () => {
    // The first patches are held back a moment: the view says it is loading and shows no
    // callouts over an empty view.
    const page = await browser.page();
    await login(page, server.base, ADMIN);
    let release;
    const held = new Promise((r) => (release = r));
    // Patches come one by one or as runs read from the file.
    const patches = /\/api\/v1\/models\/\d+\/lod\/(patches\/\d+|file)$/;
    await page.route(patches, async (route) => {
      await held;
      await route.continue().catch(() => {});
    });
    await page.goto(`${server.base}/models/${model.id}`);
    await page.locator('.viewer-loading').waitFor({ state: 'visible', timeout: 30_000 });
    assert.match(await page.locator('.viewer-loading').textContent(), /Loading the model/);
    assert.equal(await page.locator('.viewer-overlay').isVisible(), false, 'callouts over an empty view');
    release();
    let s = await waitViewer(page, (v) => settled(v) && v.callouts.includes(seeded.part.id));
    assert.equal(await page.locator('.viewer-loading').isVisible(), false);
    assert.match(await page.locator('.viewer-status').textContent(), /^Sharp/, 'the status speaks plainly');
    // The live view replaces the thumbnail beside it.
    assert.equal(await page.locator('.model-thumb').count(), 0, 'the thumbnail repeats the live view');
    // The first view is the side the thumbnail shows (the server's home view).
    const home = await homeDirection(server.api, model.id);
    const cam = await page.evaluate(() => window.meshwikiViewer.camera());
    const dir = cam.eye.map((v, k) => v - cam.target[k]);
    const cos = dir.reduce((a, v, k) => a + v * home[k], 0) / Math.hypot(...dir);
    assert.ok(cos > 0.999, `the viewer opens on another side than the thumbnail: cos ${cos}`);

    // The drawer: over the view, which keeps its width; callouts stay left of it.
    const canvas = page.locator('.viewer-canvas');
    const wide = await canvas.boundingBox();
    await page.locator(`.callout[data-part-id="${seeded.part.id}"]`).click();
    const panel = page.locator('.viewer-panel');
    await panel.locator('.panel-content').waitFor({ timeout: 10_000 });
    await page.waitForTimeout(300);
    const after = await canvas.boundingBox();
    assert.equal(Math.round(after.width), Math.round(wide.width), 'opening the panel narrowed the view');
    const drawer = await panel.boundingBox();
    assert.ok(Math.abs(drawer.x + drawer.width - (wide.x + wide.width)) < 2 && drawer.height >= wide.height - 2, `the panel is not a drawer over the view: ${JSON.stringify({ drawer, wide })}`);
    await shot(page, 'drawer');
    const labels = await page.locator('.callout:not([hidden])').evaluateAll((els) => els.map((e) => e.getBoundingClientRect().right));
    assert.ok(labels.every((r) => r <= drawer.x + 1), `callouts under the drawer: ${labels} vs ${drawer.x}`);
    // Its handle: a separator the keyboard moves; the width is kept.
    const handle = page.getByRole('separator', { name: 'Resize the information panel' });
    await handle.focus();
    for (let k = 0; k < 3; k++) await page.keyboard.press('ArrowLeft');
    const widened = await panel.boundingBox();
    assert.ok(widened.width >= drawer.width + 90, `ArrowLeft did not widen the drawer: ${drawer.width} → ${widened.width}`);
    assert.equal(Number(await handle.getAttribute('aria-valuenow')), Math.round(widened.width));
    await page.reload();
    await waitViewer(page, settled);
    await page.locator(`.callout[data-part-id="${seeded.part.id}"]`).click();
    await panel.locator('.panel-content').waitFor({ timeout: 10_000 });
    assert.ok(Math.abs((await panel.boundingBox()).width - widened.width) < 2, 'the width was not kept');
    await page.keyboard.press('Escape');
    await panel.waitFor({ state: 'hidden', timeout: 5_000 });

    // The keyboard steers the focused view: arrows turn it about the target, + zooms, Home resets.
    await canvas.focus();
    const c0 = await page.evaluate(() => window.meshwikiViewer.camera());
    const dist = (c) => Math.hypot(...c.eye.map((v, k) => v - c.target[k]));
    await page.keyboard.press('ArrowLeft');
    const c1 = await page.evaluate(() => window.meshwikiViewer.camera());
    assert.ok(Math.hypot(...c1.eye.map((v, k) => v - c0.eye[k])) > dist(c0) * 0.05, 'ArrowLeft did not turn the view');
    assert.ok(Math.abs(dist(c1) - dist(c0)) < dist(c0) * 1e-3, 'turning changed the distance');
    assert.deepEqual(c1.target, c0.target);
    await page.keyboard.press('+');
    const c2 = await page.evaluate(() => window.meshwikiViewer.camera());
    assert.ok(dist(c2) < dist(c1) * 0.9, `+ did not zoom in: ${dist(c1)} → ${dist(c2)}`);
    await page.keyboard.press('Shift+ArrowUp');
    const c3 = await page.evaluate(() => window.meshwikiViewer.camera());
    assert.notDeepEqual(c3.target, c2.target, 'Shift+arrow did not move the view');
    await page.keyboard.press('Home');
    await page.waitForTimeout(700);
    const c4 = await page.evaluate(() => window.meshwikiViewer.camera());
    assert.ok(Math.hypot(...c4.eye.map((v, k) => v - c0.eye[k])) < dist(c0) * 1e-3, 'Home did not reset the view');

    // Light and background: the reader's choice, drawn, and kept for the next visit.
    s = await waitViewer(page, settled);
    const plain = await capture(page, 'look-plain');
    await page.locator('.viewer-settings > summary').click();
    await page.getByRole('radio', { name: 'White' }).check();
    await page.getByRole('radio', { name: /Raking light/ }).check();
    await shot(page, 'view-menu');
    await page.keyboard.press('Escape');
    const lit = await capture(page, 'look-raking-white');
    assert.ok(lit.background[0] > 240 && lit.background[1] > 240 && lit.background[2] > 240, `background not white: ${lit.background}`);
    assert.ok(Math.abs(lit.meanSurface - plain.meanSurface) > 3, `the light did not change the surface: ${plain.meanSurface} → ${lit.meanSurface}`);
    await page.reload();
    await waitViewer(page, settled);
    assert.equal(await page.evaluate(() => document.getElementById('viewer').dataset.background), 'white');
    await page.evaluate(() => localStorage.removeItem('meshwiki-look'));
    await page.close();
  });

  test('on a phone the panel opens in view, as a sheet over the viewer; pages do not overflow sideways', async () => {
    const page = await openModel();
    await page.setViewportSize({ width: 390, height: 844 });
    await waitViewer(page, (s) => settled(s) && s.callouts.includes(seeded.part.id));
    await page.locator(`.callout[data-part-id="${seeded.part.id}"]`).click();
    const panel = page.locator('.viewer-panel');
    await panel.waitFor({ state: 'visible' });
    const box = await panel.boundingBox();
    assert.ok(box, 'the panel has a box');
    assert.ok(box.y >= 0 && box.y + box.height <= 844 + 0.5, `the panel is within the screen: ${JSON.stringify(box)}`);
    assert.ok(box.height >= 120, `the panel shows its information: ${JSON.stringify(box)}`);
    assert.match(await panel.textContent(), /Central dome/);
    // Still closed by its button, and the models page fits the screen's width.
    await page.keyboard.press('Escape');
    await panel.waitFor({ state: 'hidden' });
    for (const path of ['/models', `/models/${model.id}`, '/search?q=dome']) {
      await page.goto(`${server.base}${path}`);
      const wide = await page.evaluate(() => document.documentElement.scrollWidth);
      assert.ok(wide <= 390, `${path} is ${wide} px wide on a 390 px screen`);
    }
    await page.close();
  });

  test('a search result opens the panel with the matching paragraph marked and in view', async () => {
    const page = await browser.page();
    await login(page, server.base, ADMIN);
    await page.goto(`${server.base}/search?q=${encodeURIComponent('xylographer tufa')}`);
    const link = page.locator(`.hit-parts a.part-link[data-part-id="${seeded.part.id}"]`);
    assert.equal(await link.count(), 1, 'the hit has no link to the part');
    assert.match(await link.getAttribute('href'), /[?&]q=xylographer%20tufa/, 'the link does not carry the search');
    await Promise.all([page.waitForNavigation(), link.click()]);
    await waitViewer(page, (s) => s.selected === seeded.part.id);
    const panel = page.locator('.viewer-panel');
    await panel.locator('.panel-content').waitFor({ timeout: 10_000 });
    const hit = panel.locator('.search-hit');
    await hit.waitFor({ timeout: 5_000 });
    assert.match(await hit.textContent(), /quarry mark of the xylographer workshop/);
    assert.deepEqual(await hit.locator('mark.search-match').allTextContents(), ['tufa', 'xylographer']);
    assert.equal(await panel.locator('mark.search-match').count(), 2, 'words marked outside the match');
    // The paragraph is far down (30 paragraphs before it): the panel scrolled to it.
    const seen = await page.evaluate(() => {
      const p = document.querySelector('.viewer-panel');
      const h = p.querySelector('.search-hit');
      const a = p.getBoundingClientRect();
      const b = h.getBoundingClientRect();
      return { scrollTop: p.scrollTop, inPanel: b.top >= a.top && b.bottom <= a.bottom, inWindow: b.top >= 0 && b.bottom <= window.innerHeight };
    });
    assert.ok(seen.scrollTop > 0, 'the panel did not scroll');
    assert.ok(seen.inPanel && seen.inWindow, `the match is not in view: ${JSON.stringify(seen)}`);
    await shot(page, 'panel-search-match');
    // Another part (none): the search no longer applies.
    await page.keyboard.press('Escape');
    await panel.waitFor({ state: 'hidden', timeout: 5_000 });
    assert.doesNotMatch(page.url(), /[?&]q=/);
    await page.close();
  });

  test('the model page assigns a content picked by search; without the picker, a title or a wrong number', async () => {
    const target = await server.api.post('/api/v1/contents', { title: 'Mason marks register', caption: 'Quarry signs', body: 'Signs of the masons.' });
    await server.api.post('/api/v1/contents', { title: 'Mason lodge', body: 'The lodge of the masons.' });
    await server.api.post('/api/v1/contents', { title: 'Mason tools', body: 'Chisels of the masons.' });
    const page = await openModel();
    const form = page.locator(`#part-${seeded.part.id} form[data-content-picker]`);
    const field = form.getByLabel('Assign content');
    assert.equal(await field.count(), 1, 'the field has no label');

    // The picker: typing lists the matches, arrow keys and Enter pick one, Assign assigns it.
    await field.focus();
    await page.keyboard.type('register');
    const option = form.locator(`[role=option][data-content-id="${target.id}"]`);
    await option.waitFor({ timeout: 5_000 });
    assert.equal(await field.getAttribute('aria-expanded'), 'true');
    await page.keyboard.press('ArrowDown');
    await page.keyboard.press('Enter');
    assert.equal(await form.locator('input[name=content_id]').inputValue(), String(target.id));
    assert.equal(await field.inputValue(), 'Mason marks register');
    await shot(page, 'panel-picker');
    await Promise.all([page.waitForNavigation(), form.locator('button[type=submit]').click()]);
    let assigned = await server.api.get(`/api/v1/parts/${seeded.part.id}/contents`);
    assert.ok(assigned.some((c) => c.id === target.id), 'the picked content is not assigned');
    assert.match(new URL(page.url()).pathname, new RegExp(`^/models/${model.id}$`));

    // Without the script: the form posts what was typed.
    const go = async (content) => {
      const r = await page.request.post(`${server.base}/parts/${seeded.part.id}/contents`, {
        form: { csrf_token: await page.locator('input[name=csrf_token]').first().inputValue(), content_id: '', content },
        maxRedirects: 0,
      });
      assert.equal(r.status(), 303, await r.text());
      return r.headers().location;
    };
    // A wrong number: back to the part on the model page, with a message.
    let to = await go('#987654');
    assert.match(to, new RegExp(`^/models/${model.id}\\?assign_part=${seeded.part.id}&assign_error=missing`));
    await page.goto(server.base + to);
    const notice = page.locator(`#part-${seeded.part.id} .assign-notice [role=alert]`);
    assert.match(await notice.textContent(), /There is no content “#987654”/);
    assert.equal(await page.locator(`#part-${seeded.part.id} input[name=content]`).inputValue(), '#987654', 'the typed text is lost');
    // Words matching several contents: the ones not assigned yet, to pick from.
    to = await go('mason');
    assert.match(to, /assign_error=choose/);
    await page.goto(server.base + to);
    assert.match(await notice.textContent(), /Several contents match “mason”/);
    await shot(page, 'panel-assign-choose');
    const offered = await page.locator(`#part-${seeded.part.id} .assign-candidates button`).allTextContents();
    assert.deepEqual(offered.sort(), ['Mason lodge', 'Mason tools'], 'an assigned content is offered again');
    const lodge = page.locator(`#part-${seeded.part.id} .assign-candidates button`, { hasText: 'Mason lodge' });
    await Promise.all([page.waitForNavigation(), lodge.click()]);
    // An exact title (letter case aside) is assigned at once.
    to = await go('central dome');
    assert.match(to, /assign_error=already/, 'assigning it again is not refused with a message');
    const third = await server.api.post('/api/v1/contents', { title: 'Drainage channel', body: 'Rain water.' });
    to = await go('drainage CHANNEL');
    assert.equal(to, `/models/${model.id}#part-${seeded.part.id}`);
    assigned = await server.api.get(`/api/v1/parts/${seeded.part.id}/contents`);
    assert.deepEqual(assigned.map((c) => c.title), ['Central dome', 'Mason marks register', 'Mason lodge', third.title]);
    assert.match(await (await page.request.get(`${server.base}/models/${model.id}?assign_part=${seeded.part.id}&assign_error=none&assign_q=zzz`)).text(), /No content matches “zzz”/);
    await page.close();
  });

  test('a new region gets a note written in the assign step', async (t) => {
    if (!rendering) return t.skip('no renderer on this machine');
    const page = await openModel();
    await waitViewer(page, settled);
    await capture(page, 'before');
    const c = await surfaceCentre(page, 'before');
    assert.ok(c.pixels > 2_000, `too little of the model in view: ${c.pixels} pixels`);
    const canvas = page.locator('.viewer-canvas');
    const box = await canvas.boundingBox();
    // A lasso away from the seeded centre part.
    const r = Math.min(box.width, box.height);
    const at = { x: c.x + r * 0.25, y: c.y + r * 0.2 };
    await page.locator('.select-tools button[data-tool=lasso]').click();
    const b = await canvas.boundingBox();
    await drag(page, circle(at.x, at.y, r * 0.08).map((p) => ({ x: b.x + p.x, y: b.y + p.y })));
    const s = await waitSelection(page, (s) => s.drafts.length === 1 || s.error !== '');
    assert.equal(s.error, '', 'the lasso failed');
    await page.locator('.select-tools button[data-action=confirm]').click();
    const card = page.locator('.select-assign');
    await card.waitFor({ state: 'visible', timeout: 20_000 });
    const partId = Number(await card.getAttribute('data-part-id'));
    assert.notEqual(partId, seeded.part.id);

    const note = card.getByLabel('Write a note (Markdown)');
    assert.equal(await note.count(), 1, 'the note has no labelled field');
    assert.equal(await card.getByLabel('Title').count(), 1, 'the title has no label');
    const message = card.locator('.assign-message');

    // Empty: the step says so; nothing is created.
    await card.getByRole('button', { name: 'Add note' }).click();
    assert.match(await message.textContent(), /Write the note first/);
    assert.match(await message.getAttribute('class'), /error/);
    await shot(page, 'panel-note-empty');

    // Refused by the server (a body over its limit): the server's message shows in the step.
    const limit = (await server.api.get('/api/v1/config')).body_bytes;
    await note.fill('x'.repeat(limit + 10));
    await card.getByRole('button', { name: 'Add note' }).click();
    await poll(page, () => document.querySelector('.select-assign .assign-message')?.textContent, (v) => /failed/.test(v || ''), 20_000);
    assert.match(await message.textContent(), new RegExp(`Saving the note failed: body must be at most ${limit} bytes`));
    assert.equal((await server.api.get(`/api/v1/parts/${partId}/contents`)).length, 0);
    await note.fill('');

    // By keyboard only: the title, then Tab on to the note, Ctrl+Enter saves it.
    const body = 'The **cornice** was repaired in 1911.\n\n- stone: tufa\n- mortar: lime';
    await card.getByLabel('Title').focus();
    await page.keyboard.type('Cornice repair');
    let tabs = 0;
    while (!(await page.evaluate(() => document.activeElement?.name === 'note')) && tabs < 12) {
      await page.keyboard.press('Tab');
      tabs++;
    }
    assert.ok(tabs < 12, 'the note cannot be reached with Tab');
    await page.keyboard.type(body);
    // Escape while the note holds text keeps the step (and the text).
    await page.keyboard.press('Escape');
    assert.ok(await card.isVisible(), 'Escape threw the note away');
    await shot(page, 'panel-note-typed');
    await page.keyboard.press('Control+Enter');
    await card.locator('.assign-assigned li').first().waitFor({ timeout: 10_000 });
    assert.doesNotMatch(await message.getAttribute('class'), /error/, await message.textContent());
    assert.equal(await note.inputValue(), '', 'the note is not cleared');

    // A second note without a title takes its first line.
    await note.fill('## Bird damage\n\nDroppings on the ledge.');
    await card.getByRole('button', { name: 'Add note' }).click();
    await card.locator('.assign-assigned li').nth(1).waitFor({ timeout: 10_000 });

    const assigned = await server.api.get(`/api/v1/parts/${partId}/contents`);
    assert.deepEqual(assigned.map((x) => x.title), ['Cornice repair', 'Bird damage']);
    const first = await server.api.get(`/api/v1/contents/${assigned[0].id}`);
    assert.equal(first.body.trim(), body);
    assert.match(first.html, /<strong>cornice<\/strong>/);
    assert.match(first.html, /<li>mortar: lime<\/li>/);

    // Done (Escape in an empty field): the part's information opens with the notes.
    await note.focus();
    await page.keyboard.press('Escape');
    await card.waitFor({ state: 'hidden', timeout: 5_000 });
    const panel = page.locator('.viewer-panel');
    await panel.locator('.panel-content').first().waitFor({ timeout: 10_000 });
    assert.equal(await panel.getAttribute('data-part-id'), String(partId));
    assert.match(await panel.textContent(), /Cornice repair/);
    // The same Escape did not also close the panel it opened; the next one does.
    await page.keyboard.press('Escape');
    await panel.waitFor({ state: 'hidden', timeout: 5_000 });
    await page.close();
  });
});
