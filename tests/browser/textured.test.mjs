// A textured scan in the viewer (issue 11): the Bali mask (../shared/data) built through the real
// pipeline from a zip of its glTF, buffer and texture, drawn by the viewer at the 1 px cut with
// every drawn patch's atlas decoded, and compared with the server's render of the same camera,
// which draws the same atlases. Without ../shared/data the test is skipped with a message.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, mkdtempSync, readFileSync, readdirSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { SHARED_MESHES } from './support/env.mjs';
import { ADMIN, importScan, startServer } from './support/server.mjs';
import { closePage, launch, login, waitViewer } from './support/browser.mjs';
import { capture, compareWithImage, serverRenderUrl } from './support/pixels.mjs';
import { storedZip } from './support/zip.mjs';

const MASK = join(SHARED_MESHES, 'mask_bali_100k_textured_gltf');
let server;
let browser;
let model;
let tmp;

before(async () => {
  if (!existsSync(MASK)) return;
  tmp = mkdtempSync(join(tmpdir(), 'mw-textured-'));
  const files = readdirSync(MASK).filter((f) => /\.(gltf|bin|jpg|png)$/i.test(f));
  const zip = join(tmp, 'mask.zip');
  writeFileSync(zip, storedZip(files.map((f) => [`mask/${f}`, readFileSync(join(MASK, f))])));
  server = await startServer();
  model = await importScan(server.api, zip, 'Textured mask');
  browser = await launch();
});

after(async () => {
  await browser?.close();
  await server?.stop();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

test('a textured scan draws its atlases, and matches a server render of the same camera', { timeout: 300_000 }, async (t) => {
  if (!model) {
    t.diagnostic('../shared/data is absent: the textured viewer test needs the Bali mask');
    t.skip('no Bali mask');
    return;
  }
  assert.equal(model.status, 'ready');
  const page = await browser.page();
  await login(page, server.base, ADMIN);
  await page.goto(`${server.base}/models/${model.id}`);
  const s = await waitViewer(page, (s) => s.settled && s.drawn > 0 && s.texturesWanted > 0 && s.texturesReady === s.texturesWanted);
  t.diagnostic(`${s.drawn} patches drawn, ${s.texturesReady} with their atlas, ${s.triangles} triangles, ${s.bytes} bytes`);
  assert.equal(s.texturesWanted, s.drawn, 'every drawn patch of a textured model has an atlas');
  assert.ok(s.maxError <= 1.0001, `cut not at 1 px: ${s.maxError}`);
  const frame = await capture(page, 'home');
  assert.ok(frame.fraction > 0.05, `canvas is blank: ${JSON.stringify(frame)}`);
  const cmp = await compareWithImage(page, 'home', await serverRenderUrl(page, model.id, frame));
  t.diagnostic(`server render: silhouette IoU ${cmp.iou.toFixed(3)}, mean colour difference ${cmp.meanAbsDiff?.toFixed(1)}`);
  assert.ok(cmp.iou > 0.97, `silhouettes differ: ${JSON.stringify(cmp)}`);
  assert.ok(cmp.meanAbsDiff < 8, `colours differ: ${JSON.stringify(cmp)}`);
  await closePage(page);
});
