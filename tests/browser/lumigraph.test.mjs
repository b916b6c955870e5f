// The network mode (issue 12): a viewer account opens a model whose geometry stays on the
// server. The page shows the model image-based — the sparse mesh shaded by the model's
// Grid-Lumigraph images — with its parts and callouts; no request of the page is refused (the
// viewer asks for no patch finer than the sparse mesh and never for the whole file); the
// frame matches the server's full-resolution render of the same camera more closely than the
// sparse mesh alone does.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { writeRelief } from './support/env.mjs';
import { importScan, seedPart, startServer } from './support/server.mjs';
import { launch, login, poll, waitViewer } from './support/browser.mjs';
import { capture, compareWithImage, serverRenderUrl } from './support/pixels.mjs';

let server;
let browser;
let tmp;

before(async () => {
  tmp = mkdtempSync(join(tmpdir(), 'mw-lumigraph-'));
  server = await startServer();
  browser = await launch();
});

after(async () => {
  await browser?.close();
  await server?.stop();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

async function waitJob(id) {
  for (let k = 0; k < 1200; k++) {
    const j = await server.api.get(`/api/v1/jobs/${id}`);
    if (j.status === 'done') return j;
    if (j.status === 'failed' || j.status === 'cancelled') throw new Error(`job ${id} ${j.status}: ${j.message}`);
    await new Promise((r) => setTimeout(r, 250));
  }
  throw new Error(`job ${id} did not finish`);
}

test('a model whose geometry stays on the server is seen image-based, with its parts and callouts', { timeout: 600_000 }, async (t) => {
  const model = await importScan(server.api, writeRelief(join(tmp, 'relief.ply'), 200), 'Guarded relief');
  const { part } = await seedPart(server.api, model.id, { title: 'Guarded rosette', body: 'On the relief.', vertexIds: [0, 1, 2, 200, 201, 202], center: [-0.5, -0.5, 0] });
  const started = await server.api.post(`/api/v1/models/${model.id}/lumigraph`, { grid: 5, size: 256 });
  const job = await waitJob(started.job.id);
  t.diagnostic(`repository: ${JSON.stringify(job.report)}`);
  await server.api.request('PATCH', `/api/v1/models/${model.id}`, { json: { geometry_access: 'sparse' } });
  await server.api.post('/api/v1/users', { username: 'vicky', password: 'vicky-password-1', role: 'viewer' });

  const page = await browser.page();
  const refused = [];
  const patches = [];
  page.on('response', (r) => {
    if (r.status() === 401 || r.status() === 403) refused.push(`${r.status()} ${r.url()}`);
    const m = /\/lod\/patches\/(\d+)/.exec(r.url());
    if (m) patches.push(Number(m[1]));
  });
  await login(page, server.base, { username: 'vicky', password: 'vicky-password-1' });
  await page.goto(`${server.base}/models/${model.id}`);
  const settled = (s) => s.mode === 'image' && s.lumigraph && s.lumigraph.images > 0 && s.settled && s.triangles > 0;
  const s = await waitViewer(page, settled, 300_000);
  t.diagnostic(`image-based: ${s.drawn} patches, ${s.triangles} triangles, ${s.bytes} patch bytes, ${JSON.stringify(s.lumigraph)}`);
  assert.deepEqual(refused, [], 'no request of the page was refused');
  assert.ok(s.lumigraph.bytes > 0 && s.lumigraph.layers > 0);

  // Only the sparse mesh came: a fraction of the scan's triangles.
  const lod = await server.api.get(`/api/v1/models/${model.id}/lod`);
  const desc = await server.api.get(`/api/v1/models/${model.id}/lumigraph`);
  for (const n of patches) {
    const node = lod.nodes[n];
    assert.ok(node.parent_error === null || node.parent_error > desc.sparse.error, `patch ${n} is finer than the sparse mesh`);
  }
  assert.ok(s.triangles < model.triangle_count / 4, `${s.triangles} of ${model.triangle_count} triangles drawn`);

  // The part's callout and information.
  await poll(page, () => window.meshwikiViewer.stats().callouts, (c) => c.includes(part.id));
  assert.match(await page.textContent('body'), /Guarded rosette/);

  // Against the server's full-resolution render of the same camera.
  const frame = await capture(page, 'image');
  const url = await serverRenderUrl(page, model.id, frame);
  const image = await compareWithImage(page, 'image', url);
  // The same frame without the images: the sparse mesh's own shading.
  await page.evaluate(() => window.meshwikiViewer.setImageShading(false));
  await capture(page, 'sparse');
  const sparse = await compareWithImage(page, 'sparse', url);
  await page.evaluate(() => window.meshwikiViewer.setImageShading(true));
  t.diagnostic(`against the full-resolution render: image-based IoU ${image.iou.toFixed(3)}, mean difference ${image.meanAbsDiff.toFixed(2)}; sparse mesh alone ${sparse.meanAbsDiff.toFixed(2)}`);
  assert.ok(image.iou > 0.95, `silhouettes differ: ${JSON.stringify(image)}`);
  assert.ok(image.meanAbsDiff < sparse.meanAbsDiff, `the images do not improve the sparse mesh: ${JSON.stringify({ image, sparse })}`);
  await page.close();
});

test("the viewer's refinement rule is the server's: it asks for no refined point the server refuses", { timeout: 600_000 }, async () => {
  const { Repository } = await import('../../static/js/lumigraph/repository.js');
  const model = await importScan(server.api, writeRelief(join(tmp, 'levels.ply'), 120), 'Refined relief');
  const started = await server.api.post(`/api/v1/models/${model.id}/lumigraph`, { grid: 4, size: 32 });
  await waitJob(started.job.id);
  const d = await server.api.get(`/api/v1/models/${model.id}/lumigraph`);
  assert.ok(d.levels >= 2 && d.model_box, JSON.stringify(d));
  const repo = new Repository(model.id, d, { onChange: () => {} });
  let compared = 0;
  let refused = 0;
  for (let level = 1; level <= d.levels; level++) {
    const n = repo.levelPoints(level);
    const mid = (n - 1) / 2;
    // Along each axis through the middle: the points on either side of where the level's
    // region (the model's box widened by its margin) ends.
    for (let axis = 0; axis < 3; axis++) {
      const at = (k) => [0, 1, 2].map((a) => (a === axis ? k : a === 2 ? mid + 1 : mid));
      for (let k = 0; k + 1 < n; k++) {
        if (repo.refines(level, at(k)) === repo.refines(level, at(k + 1))) continue;
        for (const j of [k - 1, k, k + 1, k + 2]) {
          if (j < 0 || j >= n) continue;
          const [l, p] = Repository.canonical(level, at(j));
          if (l === 0) continue;
          const res = await server.api.request('GET', `/api/v1/models/${model.id}/lumigraph/images/${p.join('/')}/${axis * 2}?level=${l}`, { raw: true });
          const kept = repo.refines(l, p);
          assert.equal(res.status === 404, !kept, `level ${l} point ${p}: the viewer says ${kept ? 'kept' : 'not kept'}, the server answers ${res.status}`);
          if (kept) assert.ok(res.status === 200 || res.status === 204, `level ${l} point ${p}: ${res.status}`);
          compared++;
          if (!kept) refused++;
        }
      }
    }
  }
  assert.ok(compared >= 12 && refused > 0 && refused < compared, `${compared} points compared, ${refused} refused`);
  repo.close();
});
