// The 3D viewer in Debian's headless Chromium (playwright-core), against the real server
// binary on a temporary data directory, with a real scan imported through the real pipeline:
// the model drawn (and compared with a server render when the server offers one), a seeded
// part's callout, hover highlighting, the information panel, a search result landing on the
// part, a part created in one browser showing in a second within 5 s, no hole while streaming.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { sampleMesh } from './support/env.mjs';
import { ADMIN, homeDirection, importScan, seedPart, startServer } from './support/server.mjs';
import { launch, login, poll, waitViewer } from './support/browser.mjs';
import { capture, compareWithImage, holes, serverRenderUrl } from './support/pixels.mjs';
import { leafVertices, regionAt } from './support/regions.mjs';

let server;
let browser;
let second;
let model;
let seeded;
let tmp;
const settled = (s) => s.settled && s.drawn > 0;

before(async () => {
  tmp = mkdtempSync(join(tmpdir(), 'mw-viewer-'));
  const mesh = sampleMesh(tmp);
  server = await startServer();
  model = await importScan(server.api, mesh.path, 'Igea test scan');
  const leaves = await leafVertices(join(server.dataDir, model.lod_path));
  // A region facing the home view (the side the thumbnail shows): the front-most point and its
  // neighbourhood.
  const region = regionAt(leaves, await homeDirection(server.api, model.id));
  seeded = await seedPart(server.api, model.id, {
    title: 'Weathered nose',
    caption: 'Erosion of the marble',
    body: 'The **nose** shows strong erosion. Keyword: zephyrine.',
    vertexIds: region.ids,
    center: region.center,
  });
  seeded.vertexCount = region.ids.length;
  browser = await launch();
  second = await launch();
});

after(async () => {
  await browser?.close();
  await second?.close();
  await server?.stop();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

async function openModel(b, query = '', hash = '') {
  const page = await b.page();
  await login(page, server.base, ADMIN);
  await page.goto(`${server.base}/models/${model.id}${query}${hash}`);
  return page;
}

test('draws the model, and matches a server render of the same camera', async (t) => {
  const page = await openModel(browser);
  const s = await waitViewer(page, settled);
  t.diagnostic(`first image after ${Math.round(s.firstImageMs)} ms; ${s.drawn} patches, ${s.triangles} triangles, ${s.bytes} bytes`);
  const frame = await capture(page, 'home');
  assert.ok(frame.fraction > 0.05, `canvas is blank: ${JSON.stringify(frame)}`);
  assert.ok(s.maxError <= 1.0001, `cut not at 1 px: ${s.maxError}`);
  const url = await serverRenderUrl(page, model.id, frame);
  const res = await page.evaluate(async (url) => {
    const r = await fetch(url);
    return { status: r.status, type: r.headers.get('Content-Type'), text: r.ok ? '' : await r.text() };
  }, url);
  if (res.status === 404 && /no route/.test(res.text)) {
    t.diagnostic('GET /api/v1/models/{id}/render is not served yet: server-render comparison skipped');
    t.skip('server render endpoint missing');
    return;
  }
  assert.equal(res.status, 200, `render: ${res.text}`);
  const cmp = await compareWithImage(page, 'home', url);
  t.diagnostic(`server render: silhouette IoU ${cmp.iou.toFixed(3)}, mean colour difference ${cmp.meanAbsDiff?.toFixed(1)}`);
  assert.ok(cmp.iou > 0.97, `silhouettes differ: ${JSON.stringify(cmp)}`);
  assert.ok(cmp.meanAbsDiff < 8, `colours differ: ${JSON.stringify(cmp)}`);
  await page.close();
});

test('a seeded part shows its callout; hovering highlights it with a preview; a click opens its information', async () => {
  const page = await openModel(browser);
  await waitViewer(page, (s) => settled(s) && s.callouts.includes(seeded.part.id));
  const label = page.locator(`.callout[data-part-id="${seeded.part.id}"]`);
  assert.ok(await label.isVisible(), 'callout label not visible');
  assert.equal((await label.textContent()).trim(), 'Weathered nose');
  const leader = await page.locator('.callout-leaders line').count();
  assert.ok(leader >= 1, 'no leader line');

  const before = await capture(page, 'plain');
  const at = await page.evaluate((id) => window.meshwikiViewer.partScreen(id), seeded.part.id);
  const box = await page.locator('.viewer-canvas').boundingBox();
  await page.mouse.move(box.x + at.x, box.y + at.y);
  await waitViewer(page, (s) => s.hovered === seeded.part.id, 10_000);
  const lit = await capture(page, 'hover');
  assert.ok(lit.hover > before.hover + 200, `part not tinted on hover: ${before.hover} → ${lit.hover}`);
  assert.ok(lit.outline > 50, `no bold boundary: ${lit.outline} outline pixels`);
  await shot(page, 'hover');
  const preview = page.locator('.viewer-preview');
  assert.ok(await preview.isVisible(), 'no hover preview');
  assert.match(await preview.textContent(), /Weathered nose/);
  assert.match(await preview.textContent(), /Erosion of the marble/);

  await page.mouse.click(box.x + at.x, box.y + at.y);
  const panel = page.locator('.viewer-panel');
  await panel.locator('.panel-content').waitFor({ timeout: 10_000 });
  const text = await panel.textContent();
  assert.match(text, /Weathered nose/);
  assert.match(text, /strong erosion/);
  assert.equal(await panel.locator('strong').first().textContent(), 'nose', 'rendered Markdown expected');
  assert.ok(await panel.locator(`a[href="/contents/${seeded.content.id}/history"]`).count(), 'history link');
  assert.ok(await panel.locator(`a[href="/contents/${seeded.content.id}/edit"]`).count(), 'edit link');
  assert.match(page.url(), new RegExp(`[?&]part=${seeded.part.id}`));
  await shot(page, 'panel');
  await page.close();
});

test('a search result lands on the part: framed, highlighted, its information open', async () => {
  const page = await browser.page();
  await login(page, server.base, ADMIN);
  await page.goto(`${server.base}/search?q=zephyrine`);
  const link = page.locator(`.hit-parts a.part-link[data-part-id="${seeded.part.id}"]`);
  assert.equal(await link.count(), 1, 'search hit has no link to the part');
  // The region is named by its information, as its callout is, not by a number.
  assert.match(await link.textContent(), /^Weathered nose on /);
  // Start far from the part: the landing must frame it.
  await Promise.all([page.waitForNavigation(), link.click()]);
  const s = await waitViewer(page, (s) => settled(s) && s.selected === seeded.part.id);
  assert.equal(s.selected, seeded.part.id);
  await page.locator('.viewer-panel .panel-content').waitFor({ timeout: 10_000 });
  assert.match(await page.locator('.viewer-panel').textContent(), /Weathered nose/);
  const at = await page.evaluate((id) => window.meshwikiViewer.partScreen(id), seeded.part.id);
  const frame = await capture(page, 'landing');
  assert.ok(at && at.x > 0 && at.y > 0 && at.x < frame.width && at.y < frame.height, `part centre not in view: ${JSON.stringify(at)}`);
  assert.ok(frame.selected > 500, `part not highlighted after landing: ${frame.selected} tinted pixels`);
  await page.close();
});

test('a part created in one browser appears in a second within 5 seconds', async (t) => {
  const watcher = await openModel(second);
  await waitViewer(watcher, settled);
  const editor = await openModel(browser);
  await waitViewer(editor, settled);
  const leaves = await leafVertices(join(server.dataDir, model.lod_path));
  const region = regionAt(leaves, [0.4, 0.5, 0.77].map((v) => v / Math.hypot(0.4, 0.5, 0.77)), [0, 0, 0], 0.1);
  const started = Date.now();
  const partId = await editor.evaluate(async ({ modelId, region }) => {
    const csrf = document.querySelector('input[name=csrf_token]').value;
    const post = async (url, body) => {
      const r = await fetch(url, { method: 'POST', headers: { 'Content-Type': 'application/json', 'X-CSRF-Token': csrf }, body: JSON.stringify(body) });
      if (!r.ok) throw new Error(`${url}: ${r.status} ${await r.text()}`);
      return r.json();
    };
    const content = await post('/api/v1/contents', { title: 'Fresh inscription', body: 'Added live.' });
    const part = await post(`/api/v1/models/${modelId}/parts`, { kind: 'region', center: region.center, vertex_ids: region.ids });
    await post(`/api/v1/parts/${part.id}/contents`, { content_id: content.id });
    return part.id;
  }, { modelId: model.id, region });
  await poll(watcher, (id) => window.meshwikiViewer.parts().find((p) => p.id === id && p.title === 'Fresh inscription' && p.bitmap), Boolean, 5_000, partId);
  const ms = Date.now() - started;
  t.diagnostic(`new part ${partId} shown in the second browser after ${ms} ms`);
  assert.ok(ms <= 5_000);
  // It is drawn like any part: its label appears in the watcher.
  await poll(watcher, (id) => document.querySelector(`.callout[data-part-id="${id}"]`)?.textContent, (v) => v === 'Fresh inscription', 5_000, partId);
  // The page's list of parts below the viewer follows too, without a reload.
  await poll(watcher, (id) => document.querySelector(`#model-parts #part-${id} h3`)?.textContent, (v) => !!v && v.includes('Fresh inscription'), 5_000, partId);
  await watcher.close();
  await editor.close();
});

test('no hole while streaming: frames during loading cover what the final frame covers', async (t) => {
  const page = await second.page();
  await login(page, server.base, ADMIN);
  const cdp = await page.context().newCDPSession(page);
  await cdp.send('Network.enable');
  // ~2 Mbit/s with latency: loading takes a while and is seen half way.
  await cdp.send('Network.emulateNetworkConditions', { offline: false, latency: 40, downloadThroughput: 250_000, uploadThroughput: 250_000 });
  // A close view of the face: deep refinement.
  const c = leavesCamera(model);
  await page.goto(`${server.base}/models/${model.id}#camera=${c}`);
  await waitViewer(page, (s) => s.drawn > 0, 60_000);
  const frames = [];
  for (let i = 0; i < 200; i++) {
    const s = await page.evaluate(() => window.meshwikiViewer.stats());
    await capture(page, `f${i}`);
    if (i === 2) await shot(page, 'streaming');
    frames.push({ name: `f${i}`, drawn: s.drawn, bytes: s.bytes });
    if (s.settled) break;
    await new Promise((r) => setTimeout(r, 120));
  }
  await cdp.send('Network.emulateNetworkConditions', { offline: false, latency: 0, downloadThroughput: -1, uploadThroughput: -1 });
  await waitViewer(page, settled);
  await capture(page, 'final');
  let worst = null;
  const distinct = new Set(frames.map((f) => f.bytes)).size;
  for (const f of frames) {
    const h = await holes(page, f.name, 'final', 4);
    if (!worst || h.holes > worst.holes) worst = h;
  }
  t.diagnostic(`${frames.length} frames while loading (${distinct} distinct loading states), worst: ${worst.holes} hole pixels of ${worst.interior}`);
  assert.ok(distinct >= 3, 'loading was not observed in several states');
  assert.ok(worst.interior > 10_000, `too little surface to judge: ${worst.interior} pixels`);
  assert.equal(worst.holes, 0, `background seen through the surface: ${JSON.stringify(worst)}`);
  await page.close();
});

/** Saves a screenshot when MESHWIKI_SHOTS names a directory (to look at the pages). */
async function shot(page, name) {
  if (process.env.MESHWIKI_SHOTS) await page.screenshot({ path: join(process.env.MESHWIKI_SHOTS, `${name}.png`) });
}

/** A camera close to the front of the model (a third of its size in view). */
function leavesCamera(m) {
  const b = m.bbox;
  const c = [0, 1, 2].map((k) => (b.min[k] + b.max[k]) / 2);
  const r = Math.hypot(...[0, 1, 2].map((k) => (b.max[k] - b.min[k]) / 2));
  const eye = [c[0] + 0.1 * r, c[1] + 0.15 * r, c[2] + 1.3 * r];
  return [...eye, c[0], c[1] + 0.1 * r, c[2] + 0.5 * r, 0, 1, 0, 40].map((v) => Number(v.toPrecision(6))).join(',');
}
