// The viewer's region-selection tools (issue 6): the mask rasteriser (no antialiasing, exact
// fills) in Node; then in Debian's headless Chromium against the real server with a real scan, as an
// admin: a lasso dragged with the mouse gives a draft whose exact highlight and vertex count
// show at once without moving the camera; undo discards it; a heavy lasso that encloses
// nothing shows the server's message; a heavy lasso, an added lasso and undo chain drafts;
// confirming makes a part with the draft's vertex set; a dropped text file, a link and a
// searched content are assigned to it; *Edit region* grows it; markup (foreground, then
// background with Shift, then a refining stroke) and a point part; viewers get no tools.

import { after, before, describe, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { RoaringBitmap } from '../../static/js/parts/roaring.js';
import { LABEL, fillPolygon, fitSize, histogram, rasterise, strokePath } from '../../static/js/select/raster.js';
import { sampleMesh } from './support/env.mjs';
import { ADMIN, addUser, importScan, startServer } from './support/server.mjs';
import { launch, login, poll, waitViewer } from './support/browser.mjs';
import { capture } from './support/pixels.mjs';
import { circle, drag, dropFile, selection, shownVertexCount, surfaceCentre, waitSelection } from './support/select.mjs';

const VIEWER = { username: 'vera', password: 'viewer-password-1' };

test('the stroke mask: exact scanline fills and swept discs, one label per pixel, scaled to the limits', () => {
  const w = 40;
  const h = 30;
  const square = new Uint8Array(w * h);
  assert.equal(fillPolygon(square, w, h, [{ x: 10, y: 5 }, { x: 30, y: 5 }, { x: 30, y: 25 }, { x: 10, y: 25 }], LABEL.LASSO), 400);
  assert.deepEqual(histogram(square), [w * h - 400, 0, 0, 0, 400]);
  assert.equal(square[5 * w + 10], LABEL.LASSO);
  assert.equal(square[5 * w + 9], 0);
  assert.equal(square[25 * w + 10], 0, 'the bottom edge is outside (pixel centres)');
  // A self-overlapping polygon (even-odd) and one off the image do not throw or spill.
  const star = new Uint8Array(w * h);
  const pts = [0, 1, 2, 3, 4].map((k) => ({ x: 20 + 14 * Math.cos((k * 4 * Math.PI) / 5), y: 15 + 14 * Math.sin((k * 4 * Math.PI) / 5) }));
  const n = fillPolygon(star, w, h, pts, LABEL.LASSO);
  // The oracle: the crossing-number test at every pixel centre.
  const inside = (x, y) => {
    let odd = false;
    for (let i = 0, j = pts.length - 1; i < pts.length; j = i++) {
      const a = pts[j];
      const b = pts[i];
      if (a.y <= y !== b.y <= y && x < a.x + ((y - a.y) / (b.y - a.y)) * (b.x - a.x)) odd = !odd;
    }
    return odd;
  };
  let expected = 0;
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      assert.equal(star[y * w + x], inside(x + 0.5, y + 0.5) ? LABEL.LASSO : 0, `pixel ${x},${y}`);
      expected += inside(x + 0.5, y + 0.5) ? 1 : 0;
    }
  }
  assert.equal(n, expected);
  assert.ok(n > 100, `${n}`);
  assert.equal(star[15 * w + 20], 0, 'the star centre is outside under even-odd');
  fillPolygon(star, w, h, [{ x: -50, y: -50 }, { x: 100, y: -50 }, { x: 100, y: 100 }], LABEL.LASSO);
  assert.ok(star.every((v) => v === 0 || v === LABEL.LASSO));

  // A closed thick ring leaves its inside empty; the band holds only label 3.
  const ring = rasterise([{ kind: 'heavy', width: 6, points: [{ x: 5, y: 5 }, { x: 35, y: 5 }, { x: 35, y: 25 }, { x: 5, y: 25 }] }], fitSize(w, h));
  const hist = histogram(ring);
  assert.equal(hist[1] + hist[2] + hist[4], 0);
  assert.ok(hist[3] > 2 * (30 + 20) * 5, `${hist}`);
  assert.equal(ring[15 * w + 20], 0, 'inside of the ring');
  assert.equal(ring[5 * w + 20], LABEL.HEAVY, 'on the closing edge');
  assert.equal(ring[15 * w + 5], LABEL.HEAVY, 'closed back to the first point');
  // A disc of radius 3: pixels whose centres are within 3 px.
  const dot = new Uint8Array(w * h);
  strokePath(dot, w, h, [{ x: 20, y: 15 }], 3, LABEL.FOREGROUND);
  assert.equal(histogram(dot)[1], 32);
  // Foreground wins over background where they cross.
  const marks = rasterise(
    [
      { kind: 'foreground', width: 4, points: [{ x: 20, y: 0 }, { x: 20, y: 30 }] },
      { kind: 'background', width: 4, points: [{ x: 0, y: 15 }, { x: 40, y: 15 }] },
    ],
    fitSize(w, h),
  );
  assert.equal(marks[15 * w + 20], LABEL.FOREGROUND);
  assert.equal(marks[15 * w + 2], LABEL.BACKGROUND);

  // Limits: both sides scaled by one factor, within the side and pixel limits.
  assert.deepEqual(fitSize(700, 480), { width: 700, height: 480, sx: 1, sy: 1 });
  const big = fitSize(6000, 3000, { maxSide: 4096, maxPixels: 2048 * 2048 });
  assert.ok(big.width <= 4096 && big.width * big.height <= 2048 * 2048, JSON.stringify(big));
  assert.ok(Math.abs(big.width / big.height - 2) < 0.01 && Math.abs(big.sx - big.sy) < 0.001);
  const scaled = rasterise([{ kind: 'lasso', points: [{ x: 0, y: 0 }, { x: 6000, y: 0 }, { x: 6000, y: 3000 }, { x: 0, y: 3000 }] }], big);
  assert.equal(histogram(scaled)[4], big.width * big.height);
});

describe('the selection tools on the real server', () => {
  let server;
  let browser;
  let model;
  let tmp;
  let rendering = true;
  const settled = (s) => s.settled && s.drawn > 0;

  before(async () => {
    tmp = mkdtempSync(join(tmpdir(), 'mw-select-'));
    const mesh = sampleMesh(tmp, ['gargoyle_50k_vcolor.ply', 'igea_269k.ply']);
    server = await startServer();
    model = await importScan(server.api, mesh.path, 'Selection test scan');
    addUser(server.dataDir, VIEWER.username, 'viewer', VIEWER.password);
    const probe = await server.api.request('GET', `/api/v1/models/${model.id}/render?w=16&h=16`, { raw: true });
    if (probe.status === 503) {
      const msg = await probe.text();
      if (process.env.MESHWIKI_REQUIRE_GPU_TESTS === '1') throw new Error(`no renderer: ${msg}`);
      console.log(`# SKIPPED: selections need a Vulkan adapter (lavapipe): ${msg}`);
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

  async function vertexSet(path) {
    const res = await server.api.request('GET', path, { raw: true });
    assert.equal(res.status, 200, `${path}: ${res.status}`);
    return RoaringBitmap.deserialize(await res.arrayBuffer());
  }

  test('select, preview, undo, bad input, heavy lasso, confirm, assign information, edit the region', async (t) => {
    if (!rendering) return t.skip('no renderer on this machine');
    const page = await browser.page();
    await login(page, server.base, ADMIN);
    await page.goto(`${server.base}/models/${model.id}`);
    await waitViewer(page, settled);
    const tools = page.locator('.select-tools');
    assert.ok(await tools.isVisible(), 'no Select tools for an admin');
    const box = await page.locator('.viewer-canvas').boundingBox();
    const before = await capture(page, 'before');
    let c = await surfaceCentre(page, 'before');
    assert.ok(c.pixels > 5_000, `too little of the model in view: ${c.pixels} pixels`);
    const r = Math.min(box.width, box.height);
    // Gestures in canvas coordinates (clicking the toolbar may scroll the page).
    const toPage = async (points) => {
      const canvas = page.locator('.viewer-canvas');
      await canvas.scrollIntoViewIfNeeded();
      const b = await canvas.boundingBox();
      return points.map((p) => ({ x: b.x + p.x, y: b.y + p.y }));
    };
    const draw = async (points, options) => drag(page, await toPage(points), options);
    const camera0 = await page.evaluate(() => window.meshwikiViewer.camera());

    // A lasso dragged with the mouse: the draft shows at once, exact, with its vertex count.
    await tools.locator('button[data-tool=lasso]').click();
    let started = Date.now();
    await draw(circle(c.x, c.y, r * 0.14));
    let s = await waitSelection(page, (s) => s.drafts.length === 1 || s.error);
    assert.equal(s.error, '', 'the lasso failed');
    const lasso = s.drafts[0];
    t.diagnostic(`lasso: ${lasso.vertex_count} vertices, ${lasso.selected_pixels} pixels of a ${lasso.width}x${lasso.height} view in ${Date.now() - started} ms`);
    assert.equal(lasso.tool, 'lasso');
    assert.deepEqual([lasso.width, lasso.height], [Math.round(box.width), Math.round(box.height)], 'mask and camera of the canvas size');
    assert.ok(lasso.vertex_count > 0);
    assert.equal(lasso.bitmap, lasso.vertex_count, 'the highlight uses the draft vertex set');
    assert.equal(await shownVertexCount(page), lasso.vertex_count, 'vertex count shown in the toolbar');
    assert.match(await page.locator('.select-status').textContent(), new RegExp(`${lasso.vertex_count.toLocaleString('en-US')} vertices`));
    assert.deepEqual(await page.evaluate(() => window.meshwikiViewer.camera()), camera0, 'drawing moved the camera');
    assert.ok(s.matched > 0, 'no draft vertex found in the resident patches');
    const lit = await capture(page, 'lasso');
    await shot(page, 'select-lasso');
    t.diagnostic(`tinted pixels: ${before.selected} before, ${lit.selected} with the draft`);
    assert.ok(lit.selected > before.selected + Math.max(300, lasso.selected_pixels * 0.5), `draft not highlighted: ${before.selected} → ${lit.selected} (${lasso.selected_pixels} selected)`);

    // Undo: back to no draft, the draft discarded on the server, the highlight gone.
    await tools.locator('button[data-action=undo]').click();
    s = await waitSelection(page, (s) => s.drafts.length === 0);
    assert.equal(await shownVertexCount(page), null);
    const undone = await capture(page, 'undone');
    assert.ok(undone.selected < before.selected + 100, `highlight left after undo: ${undone.selected}`);
    const gone = await page.evaluate((id) => fetch(`/api/v1/selections/${id}`).then((r) => r.status), lasso.id);
    assert.equal(gone, 404, 'the undone draft still exists');

    // Bad input: a heavy stroke that encloses nothing shows the server's message.
    await tools.locator('button[data-tool=heavy_lasso]').click();
    await tools.locator('.select-brush input').fill('24');
    await tools.locator('.select-brush input').dispatchEvent('change');
    await draw([c, { x: c.x + 12, y: c.y }]);
    s = await waitSelection(page, (s) => s.error !== '');
    assert.match(s.error, /enclose/);
    const shown = page.locator('.select-error');
    assert.ok(await shown.isVisible(), 'the error is not shown');
    assert.equal((await shown.textContent()).trim(), s.error);
    assert.equal(s.drafts.length, 0);
    await shot(page, 'select-error');

    // A heavy lasso around the same place, then a lasso added next to it, then undo.
    started = Date.now();
    await draw(circle(c.x, c.y, r * 0.16));
    s = await waitSelection(page, (s) => s.drafts.length === 1 || s.error !== '');
    assert.equal(s.error, '', 'the heavy lasso failed');
    const heavy = s.drafts[0];
    t.diagnostic(`heavy lasso: ${heavy.vertex_count} vertices in ${Date.now() - started} ms`);
    assert.equal(heavy.tool, 'heavy_lasso');
    assert.ok(heavy.vertex_count > 0);
    assert.ok(!(await shown.isVisible()), 'the old error is still shown');
    await tools.locator('button[data-mode=add]').click();
    await tools.locator('button[data-tool=lasso]').click();
    await draw(circle(c.x + r * 0.2, c.y, r * 0.07, 16));
    s = await waitSelection(page, (s) => s.drafts.length === 2 || s.error !== '');
    assert.equal(s.error, '', 'the added lasso failed');
    assert.equal(s.drafts[1].base, heavy.id, 'drafts are chained through base');
    assert.equal(s.drafts[1].mode, 'add');
    assert.ok(s.drafts[1].vertex_count > heavy.vertex_count, `add did not grow: ${heavy.vertex_count} → ${s.drafts[1].vertex_count}`);
    await shot(page, 'select-added');
    await tools.locator('button[data-action=undo]').click();
    s = await waitSelection(page, (s) => s.drafts.length === 1);
    assert.equal(await shownVertexCount(page), heavy.vertex_count);

    // Confirm: a part holding exactly the heavy lasso's vertices; the assign step opens.
    await tools.locator('button[data-action=confirm]').click();
    const card = page.locator('.select-assign');
    await card.waitFor({ state: 'visible', timeout: 20_000 });
    const partId = Number(await card.getAttribute('data-part-id'));
    const parts = await server.api.get(`/api/v1/models/${model.id}/parts`);
    const part = parts.find((p) => p.id === partId);
    assert.ok(part, `part ${partId} not in ${JSON.stringify(parts.map((p) => p.id))}`);
    assert.equal(part.kind, 'region');
    assert.equal(part.vertex_count, heavy.vertex_count);
    assert.equal((await vertexSet(`/api/v1/parts/${partId}/vertices`)).size, heavy.vertex_count);
    s = await selection(page);
    assert.equal(s.drafts.length, 0);
    assert.equal(s.tool, null);

    // Assign: a text file dropped onto the region, a link, and existing information found by search.
    const existing = await server.api.post('/api/v1/contents', { title: 'Griffin legend', caption: 'Older account', body: 'The quillwort legend of the griffin.' });
    await card.locator('input[name=title]').fill('Carved note');
    const dropped = await dropFile(page, '.viewer-stage', { name: 'note.txt', type: 'text/plain', text: 'Inscription reads: VELOX.' });
    assert.deepEqual(dropped, { accepted: true, handled: true }, 'the stage does not take dropped files');
    await card.locator('.assign-assigned li').nth(0).waitFor({ timeout: 10_000 });
    await card.locator('input[name=title]').fill('Reference photo archive');
    await card.locator('input[name=url]').fill('https://example.org/archive/gargoyle');
    await card.locator('.assign-link button[type=submit]').click();
    await card.locator('.assign-assigned li').nth(1).waitFor({ timeout: 10_000 });
    await card.locator('input[name=q]').fill('quillwort');
    await card.locator('.assign-search button[type=submit]').click();
    await card.locator(`.assign-results li[data-content-id="${existing.id}"] .assign-pick`).click();
    await card.locator('.assign-assigned li').nth(2).waitFor({ timeout: 10_000 });
    await shot(page, 'select-assign');
    assert.doesNotMatch(await card.locator('.assign-message').getAttribute('class'), /error/, await card.locator('.assign-message').textContent());
    const assigned = await server.api.get(`/api/v1/parts/${partId}/contents`);
    assert.deepEqual(assigned.map((x) => x.title), ['Carved note', 'Reference photo archive', 'Griffin legend']);
    const note = await server.api.get(`/api/v1/contents/${assigned[0].id}`);
    assert.equal(note.attachments.length, 1);
    assert.equal(note.attachments[0].original_name, 'note.txt');
    assert.match(note.html, /VELOX/);
    const linkContent = await server.api.get(`/api/v1/contents/${assigned[1].id}`);
    assert.match(linkContent.html, /href="https:\/\/example\.org\/archive\/gargoyle"/);
    await card.locator('button[data-action=assign-done]').click();
    assert.ok(!(await card.isVisible()));
    await page.locator('.viewer-panel .panel-content').first().waitFor({ timeout: 10_000 });
    assert.match(await page.locator('.viewer-panel').textContent(), /Carved note/);

    // Edit region: the part open in the panel grows by a lasso; confirming updates it. The
    // panel's drawer covers the view's right side: draw where it leaves the model in sight.
    await capture(page, 'panel');
    c = await surfaceCentre(page, 'panel');
    await tools.locator('button[data-action=edit-region]').click();
    s = await waitSelection(page, (s) => s.editing === partId);
    assert.equal(s.mode, 'add');
    assert.equal(s.tool, 'lasso');
    await draw(circle(c.x, c.y, Math.min(r * 0.25, (c.right - c.x) * 0.8), 20));
    s = await waitSelection(page, (s) => s.drafts.length === 1 || s.error !== '');
    assert.equal(s.error, '', 'the edit failed');
    assert.equal(s.drafts[0].part_id, partId);
    const grown = s.drafts[0].vertex_count;
    assert.ok(grown > heavy.vertex_count, `the edit did not grow the part: ${heavy.vertex_count} → ${grown}`);
    await tools.locator('button[data-action=confirm]').click();
    await card.waitFor({ state: 'visible', timeout: 20_000 });
    const updated = await server.api.get(`/api/v1/parts/${partId}`);
    assert.equal(updated.vertex_count, grown);
    assert.equal((await server.api.get(`/api/v1/models/${model.id}/parts`)).length, 1, 'the edit made a new part');
    await page.keyboard.press('Escape');
    assert.ok(!(await card.isVisible()), 'Escape does not close the assign step');

    // Markup (Lazy Snapping): a foreground stroke alone waits for the background; a background
    // stroke (Shift) around it gives a draft; a further stroke refines that same draft.
    await tools.locator('button[data-mode=replace]').click();
    await tools.locator('button[data-tool=markup]').click();
    await draw([{ x: c.x - 12, y: c.y }, { x: c.x + 12, y: c.y }]);
    await new Promise((resolve) => setTimeout(resolve, 300));
    s = await selection(page);
    assert.equal(s.drafts.length + (s.busy ? 1 : 0), 0, 'markup sent without a background stroke');
    assert.match(await page.locator('.select-status').textContent(), /background/);
    await draw(circle(c.x, c.y, 70, 24), { modifiers: ['Shift'] });
    s = await waitSelection(page, (s) => s.drafts.length === 1 || s.error !== '');
    assert.equal(s.error, '', 'the markup failed');
    const markup = s.drafts[0];
    assert.equal(markup.tool, 'markup');
    assert.ok(markup.vertex_count > 0);
    await draw([{ x: c.x, y: c.y - 15 }, { x: c.x, y: c.y + 15 }]);
    s = await waitSelection(page, (s) => (s.drafts.length === 1 && s.drafts[0].id !== markup.id) || s.error !== '');
    assert.equal(s.error, '', 'the refined markup failed');
    assert.equal(s.drafts.length, 1, 'a refining stroke stacked a new draft');
    await shot(page, 'select-markup');
    assert.ok(!s.drafts[0].base, 'the refined markup builds on the refined draft');
    assert.equal(await page.evaluate((id) => fetch(`/api/v1/selections/${id}`).then((r) => r.status), markup.id), 404, 'the replaced markup draft still exists');
    await tools.locator('button[data-action=undo]').click();
    await waitSelection(page, (s) => s.drafts.length === 0);

    // Point: a click gives a one-vertex draft; confirming makes a point part.
    await tools.locator('button[data-tool=point]').click();
    const [p] = await toPage([c]);
    await page.mouse.click(p.x, p.y);
    s = await waitSelection(page, (s) => s.drafts.length === 1 || s.error !== '');
    assert.equal(s.error, '', 'the point failed');
    assert.equal(s.drafts[0].tool, 'point');
    assert.equal(s.drafts[0].vertex_count, 1);
    // A marker shows the picked point (one tinted vertex is too small to see), where clicked.
    const marker = page.locator('.point-marker[data-point=draft]');
    await marker.waitFor({ state: 'visible', timeout: 5_000 });
    const m = await marker.boundingBox();
    assert.ok(Math.hypot(m.x + m.width / 2 - p.x, m.y + m.height / 2 - p.y) < 12, `the marker is not at the click: ${JSON.stringify({ m, p })}`);
    assert.match(await tools.textContent(), /1 vertex\b/);
    await tools.locator('button[data-action=confirm]').click();
    await poll(page, () => document.querySelector('.select-assign:not([hidden])')?.dataset.partId, (v) => v && Number(v) !== partId, 20_000);
    const pointId = Number(await card.getAttribute('data-part-id'));
    const pointPart = await server.api.get(`/api/v1/parts/${pointId}`);
    assert.equal(pointPart.kind, 'point');
    assert.equal(pointPart.vertex_count, 1);
    await page.keyboard.press('Escape');

    // Escape leaves an active tool (and the camera moves again).
    await tools.locator('button[data-tool=markup]').click();
    assert.equal((await selection(page)).tool, 'markup');
    await page.keyboard.press('Escape');
    s = await waitSelection(page, (s) => s.tool === null);
    assert.equal(s.drafts.length, 0);
    await page.close();
  });

  test('segments: the segment under the cursor is previewed, a click selects it whole, Shift-click adds one', async (t) => {
    if (!rendering) return t.skip('no renderer on this machine');
    const page = await browser.page();
    await login(page, server.base, ADMIN);
    await page.goto(`${server.base}/models/${model.id}`);
    await waitViewer(page, settled);
    await capture(page, 'segments');
    const c = await surfaceCentre(page, 'segments');
    const tools = page.locator('.select-tools');
    const canvas = page.locator('.viewer-canvas');
    await tools.locator('button[data-tool=segment]').click();
    let s = await waitSelection(page, (s) => s.tool === 'segment' && s.segmentScale !== null);
    const scales = await server.api.get(`/api/v1/models/${model.id}/segments`);
    assert.equal(s.segmentScale, scales.suggested_scale);
    assert.ok(await tools.locator('.select-scale').isVisible(), 'no segment size control');
    assert.match(await tools.locator('.select-scale-count').textContent(), new RegExp(`${scales.scales[s.segmentScale].segments} segments`));

    // The previewed segment under a canvas point (null: none), once the hover settled.
    const b = await canvas.boundingBox();
    const hover = async (x, y) => {
      await page.mouse.move(b.x + x, b.y + y);
      return (await poll(page, () => window.meshwikiViewer.selection(), (s) => !s.segmentPending, 10_000)).segment;
    };
    // A point well inside a segment: the same one 8 px around it (so the client's pick on
    // the drawn patches and the server's on the full-resolution scan agree).
    const inside = async (x, y) => {
      const a = await hover(x, y);
      if (!a) return null;
      for (const [dx, dy] of [[8, 0], [-8, 0], [0, 8], [0, -8]]) {
        const n = await hover(x + dx, y + dy);
        if (!n || n.id !== a.id) return null;
      }
      return hover(x, y);
    };
    const candidates = [];
    for (let ring = 0; ring < 4; ring++) {
      for (let k = 0; k < (ring === 0 ? 1 : 8); k++) {
        const a = (k / 8) * Math.PI * 2;
        candidates.push({ x: c.x + Math.cos(a) * ring * 25, y: c.y + Math.sin(a) * ring * 25 });
      }
    }
    let first = null;
    let second = null;
    for (const p of candidates) {
      const seg = await inside(p.x, p.y);
      if (!seg) continue;
      if (!first) first = { ...p, seg };
      else if (seg.id !== first.seg.id) {
        second = { ...p, seg };
        break;
      }
    }
    assert.ok(first && second, 'no two segments found well inside under the cursor');
    // The preview is the segment's exact vertex set, found in the resident patches.
    await hover(first.x, first.y);
    s = await waitSelection(page, (s) => s.segment && s.segment.id === first.seg.id && s.segment.matched > 0);
    await shot(page, 'select-segment-hover');

    // A click selects it whole: the draft is the segment the preview showed.
    await page.mouse.click(b.x + first.x, b.y + first.y);
    s = await waitSelection(page, (s) => s.drafts.length === 1 || s.error !== '');
    assert.equal(s.error, '', 'the segment click failed');
    assert.equal(s.drafts[0].tool, 'segment');
    assert.equal(s.drafts[0].vertex_count, first.seg.size);
    assert.equal(await shownVertexCount(page), first.seg.size);
    assert.ok(s.matched > 0, 'the draft is not highlighted');

    // Shift-click adds the second segment (disjoint at one scale).
    await page.keyboard.down('Shift');
    await page.mouse.click(b.x + second.x, b.y + second.y);
    await page.keyboard.up('Shift');
    s = await waitSelection(page, (s) => s.drafts.length === 2 || s.error !== '');
    assert.equal(s.error, '', 'the added segment failed');
    assert.equal(s.drafts[1].mode, 'add');
    assert.equal(s.drafts[1].vertex_count, first.seg.size + second.seg.size);
    await shot(page, 'select-segment-added');

    // A finer size: more segments, and the preview follows at that scale.
    if (s.segmentScale > 0) {
      const finer = s.segmentScale - 1;
      await tools.locator('.select-scale input').evaluate((el, v) => {
        el.value = String(v);
        el.dispatchEvent(new Event('input', { bubbles: true }));
      }, finer);
      s = await waitSelection(page, (s) => s.segmentScale === finer);
      assert.match(await tools.locator('.select-scale-count').textContent(), new RegExp(`${scales.scales[finer].segments} segments`));
      await hover(first.x + 1, first.y);
      s = await poll(page, () => window.meshwikiViewer.selection(), (s) => s.segment && s.segment.scale === finer, 10_000);
      assert.ok(s.segment.size <= first.seg.size, 'a finer segment is larger than the coarser one holding it');
    }

    // Confirmed: a region part holding exactly the two segments.
    const draftSet = await vertexSet(`/api/v1/selections/${s.drafts[1].id}/vertices`);
    await tools.locator('button[data-action=confirm]').click();
    const partId = Number(await poll(page, () => document.querySelector('.select-assign:not([hidden])')?.dataset.partId, (v) => Boolean(v), 20_000));
    const part = await server.api.get(`/api/v1/parts/${partId}`);
    assert.equal(part.kind, 'region');
    assert.equal(part.vertex_count, first.seg.size + second.seg.size);
    const partSet = await vertexSet(`/api/v1/parts/${partId}/vertices`);
    assert.equal(partSet.size, draftSet.size);
    assert.ok([...draftSet.values()].every((v) => partSet.has(v)), 'the part is not the confirmed segments');
    const revisions = await server.api.get(`/api/v1/parts/${partId}/revisions`);
    assert.equal(revisions[0].tool, 'segment');
    await page.keyboard.press('Escape');
    s = await waitSelection(page, (s) => s.drafts.length === 0 && s.assigning === null);
    await page.close();
  });

  test('viewers get no selection tools', async () => {
    const page = await browser.page();
    await page.context().clearCookies();
    await login(page, server.base, VIEWER);
    await page.goto(`${server.base}/models/${model.id}`);
    await waitViewer(page);
    assert.equal(await page.locator('.select-tools').count(), 0);
    assert.equal(await page.evaluate(() => window.meshwikiViewer.selection()), null);
    await page.close();
  });
});
