// Uploading a real scan through the web UI (issue 16, item 2): the Bali mask's glTF folder
// (the .gltf, its .bin buffer and its texture image: three files) picked together on the jobs
// page, sent with visible upload progress through a resumable upload session (one dropped
// connection on the way, retried), built, and opened in the viewer; and a .zip of a scan,
// cut off after its first chunk, the page closed, then picked again: the upload resumes where
// it stopped and builds. Without ../shared/data a generated glTF with a separate buffer stands
// in for the mask.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, mkdtempSync, readFileSync, readdirSync, rmSync, writeFileSync } from 'node:fs';
import { randomBytes } from 'node:crypto';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { SHARED_MESHES } from './support/env.mjs';
import { storedZip } from './support/zip.mjs';
import { ADMIN, startServer } from './support/server.mjs';
import { closePage, gotoSettled, launch, login, poll, waitViewer } from './support/browser.mjs';

let server;
let browser;
let tmp;

before(async () => {
  tmp = mkdtempSync(join(tmpdir(), 'mw-upload-'));
  server = await startServer();
  browser = await launch();
});

after(async () => {
  await browser?.close();
  await server?.stop();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

/** A glTF grid whose buffer is the separate file grid.bin; returns the two paths. */
function generatedGltf(dir, n = 120) {
  const floats = new Float32Array(n * n * 3);
  for (let y = 0; y < n; y++) {
    for (let x = 0; x < n; x++) {
      const [u, v] = [x / (n - 1), y / (n - 1)];
      floats.set([u, v, 0.1 * Math.sin(u * 9) * Math.cos(v * 7)], (y * n + x) * 3);
    }
  }
  const idx = [];
  for (let y = 0; y < n - 1; y++) {
    for (let x = 0; x < n - 1; x++) {
      const i = y * n + x;
      idx.push(i, i + 1, i + n + 1, i, i + n + 1, i + n);
    }
  }
  const indices = new Uint32Array(idx);
  const bin = Buffer.concat([Buffer.from(floats.buffer), Buffer.from(indices.buffer)]);
  const gltf = {
    asset: { version: '2.0' },
    scene: 0, scenes: [{ nodes: [0] }], nodes: [{ mesh: 0 }],
    meshes: [{ primitives: [{ attributes: { POSITION: 0 }, indices: 1 }] }],
    buffers: [{ uri: 'grid.bin', byteLength: bin.length }],
    bufferViews: [
      { buffer: 0, byteOffset: 0, byteLength: floats.byteLength },
      { buffer: 0, byteOffset: floats.byteLength, byteLength: indices.byteLength },
    ],
    accessors: [
      { bufferView: 0, componentType: 5126, count: n * n, type: 'VEC3', min: [0, 0, -0.1], max: [1, 1, 0.1] },
      { bufferView: 1, componentType: 5125, count: indices.length, type: 'SCALAR' },
    ],
  };
  writeFileSync(join(dir, 'grid.gltf'), JSON.stringify(gltf));
  writeFileSync(join(dir, 'grid.bin'), bin);
  return [join(dir, 'grid.gltf'), join(dir, 'grid.bin')];
}

/** Records what the upload form shows (the page navigates away when done). */
async function recordProgress(page) {
  await page.addInitScript(() => {
    const seen = () => {
      const bar = document.querySelector('progress[data-upload-progress]');
      const status = document.querySelector('[data-upload-status]');
      if (bar && !bar.hidden && bar.value > Number(sessionStorage.getItem('mw-progress') || -1)) {
        sessionStorage.setItem('mw-progress', String(bar.value));
      }
      if (status && status.textContent) {
        sessionStorage.setItem('mw-status', status.textContent);
        const all = JSON.parse(sessionStorage.getItem('mw-statuses') || '[]');
        if (all[all.length - 1] !== status.textContent) sessionStorage.setItem('mw-statuses', JSON.stringify([...all, status.textContent].slice(-200)));
      }
    };
    setInterval(seen, 5);
    document.addEventListener('DOMContentLoaded', () => {
      new MutationObserver(seen).observe(document.body, { subtree: true, childList: true, characterData: true, attributes: true });
    });
  });
}

function scanFiles() {
  const bali = join(SHARED_MESHES, 'mask_bali_100k_textured_gltf');
  if (existsSync(bali)) {
    const files = readdirSync(bali).filter((f) => /\.(gltf|bin|jpg|png)$/i.test(f)).map((f) => join(bali, f));
    return { files, name: 'the Bali mask', scan: /\.gltf$/ };
  }
  console.log('# ../shared/data is absent: a generated glTF with a separate buffer stands in for the Bali mask');
  return { files: generatedGltf(tmp), name: 'a generated glTF', scan: /\.gltf$/ };
}

test('a glTF with its buffer and texture uploads through the page, with progress and a dropped connection, and opens', { timeout: 600_000 }, async (t) => {
  const { files, name } = scanFiles();
  t.diagnostic(`${name}: ${files.length} files`);
  const page = await browser.page();
  await recordProgress(page);
  await login(page, server.base, ADMIN);
  // The connection drops once, on the second chunk sent: the upload retries and goes on.
  let chunks = 0;
  await page.route('**/api/v1/uploads/*/files/*', (route) => (++chunks === 2 ? route.abort('connectionreset') : route.continue()));
  await page.goto(`${server.base}/admin/jobs`);
  await page.fill('input[name=title]', 'Uploaded mask');
  // Build options, folded away until opened.
  const form = 'form[data-upload]:not(.retry)';
  await page.click(`${form} [data-build-options] summary`);
  await page.fill(`${form} input[name=texture_quality]`, '70');
  await page.fill(`${form} input[name=patch_triangles]`, '2048');
  await page.setInputFiles('#scan-files', files);
  await Promise.all([page.waitForURL(/\/models\/\d+$/, { timeout: 120_000 }), page.click('form[data-upload] button[type=submit]')]);
  const progress = await poll(page, () => ({ value: Number(sessionStorage.getItem('mw-progress')), statuses: JSON.parse(sessionStorage.getItem('mw-statuses') || '[]') }), () => true);
  assert.equal(progress.value, 100, `the upload's progress reached 100 % (${JSON.stringify(progress)})`);
  assert.ok(progress.statuses.some((s) => /^Uploading: /.test(s)), `the progress was said in words: ${progress.statuses}`);
  assert.ok(progress.statuses.some((s) => /Connection lost.*resumes where it stopped/.test(s)), `the dropped connection was said: ${progress.statuses}`);
  assert.ok(chunks >= files.length + 1, `${chunks} chunks for ${files.length} files, one sent again`);

  const id = Number(new URL(page.url()).pathname.split('/').pop());
  const model = await poll(page, async (mid) => (await fetch(`/api/v1/models/${mid}`)).json(), (m) => m.status === 'ready' || m.status === 'failed', 300_000, id);
  assert.equal(model.status, 'ready', model.error);
  const jobs = await server.api.get('/api/v1/jobs?limit=1');
  assert.match(jobs[0].source_name, /\.gltf$/);
  assert.equal(jobs[0].options.texture_quality, 70, 'the form\'s build options reached the build');
  assert.equal(jobs[0].options.max_patch_triangles, 2048);
  await gotoSettled(page, `${server.base}/models/${id}`);
  const stats = await waitViewer(page, (s) => s.triangles > 0);
  assert.ok(stats.triangles > 0, 'the viewer draws the uploaded scan');
  await closePage(page);
});

test('a .zip cut off after its first chunk resumes when picked again after a reload, and builds', { timeout: 600_000 }, async () => {
  const [gltf, bin] = generatedGltf(mkdtempSync(join(tmp, 'zip-')), 60);
  // 20 MB of photographs the scan does not use: the archive takes three chunks.
  const zip = storedZip([
    ['grid/grid.gltf', readFileSync(gltf)],
    ['grid/grid.bin', readFileSync(bin)],
    ['grid/photos/unused.dat', randomBytes(20 << 20)],
  ]);
  const zipPath = join(tmp, 'grid.zip');
  writeFileSync(zipPath, zip);
  const page = await browser.page();
  await recordProgress(page);
  await login(page, server.base, ADMIN);
  // The network fails for good after the first chunk.
  let sent = 0;
  await page.route('**/api/v1/uploads/*/files/*', (route) => (++sent === 1 ? route.continue() : route.abort('internetdisconnected')));
  await page.goto(`${server.base}/admin/jobs`);
  await page.fill('input[name=title]', 'Zipped grid');
  await page.setInputFiles('#scan-files', zipPath);
  await page.click('form[data-upload] button[type=submit]');
  await poll(page, () => sessionStorage.getItem('mw-status') || '', (s) => /Connection lost/.test(s), 60_000);
  const first = await poll(page, async () => {
    const key = Object.keys(localStorage).find((k) => k.startsWith('meshwiki-upload:'));
    if (!key) return null;
    const r = await fetch(`/api/v1/uploads/${localStorage.getItem(key)}`);
    return r.ok ? r.json() : null;
  }, (s) => s && s.files[0].received > 0, 30_000);
  assert.equal(first.files[0].received, first.chunk_size, 'the first chunk is held');

  // The page is closed and opened again; the same file picked again resumes.
  await page.unroute('**/api/v1/uploads/*/files/*');
  await page.goto(`${server.base}/admin/jobs`);
  await poll(page, () => sessionStorage.setItem('mw-statuses', '[]') ?? true);
  await page.fill('input[name=title]', 'Zipped grid');
  await page.setInputFiles('#scan-files', zipPath);
  await Promise.all([page.waitForURL(/\/models\/\d+$/, { timeout: 120_000 }), page.click('form[data-upload] button[type=submit]')]);
  // The model page may reload itself when the build ends: poll waits that out.
  const statuses = await poll(page, () => JSON.parse(sessionStorage.getItem('mw-statuses') || '[]'), () => true);
  assert.ok(statuses.some((s) => /resumed at 8\.0 MB/.test(s)), `resumed, not started again: ${statuses}`);
  const id = Number(new URL(page.url()).pathname.split('/').pop());
  const model = await poll(page, async (mid) => (await fetch(`/api/v1/models/${mid}`)).json(), (m) => m.status === 'ready' || m.status === 'failed', 300_000, id);
  assert.equal(model.status, 'ready', model.error);
  assert.equal(model.source_name, 'grid.gltf');
  assert.equal(model.triangle_count, 2 * 59 * 59);
  await closePage(page);
});

/** A binary PLY relief of about 2·n² triangles (a build of several seconds for n = 1000). */
function reliefPly(path, n) {
  const header = `ply\nformat binary_little_endian 1.0\nelement vertex ${n * n}\nproperty float x\nproperty float y\nproperty float z\nelement face ${2 * (n - 1) * (n - 1)}\nproperty list uchar int vertex_indices\nend_header\n`;
  const vertices = Buffer.alloc(n * n * 12);
  for (let y = 0, o = 0; y < n; y++) {
    for (let x = 0; x < n; x++, o += 12) {
      vertices.writeFloatLE(x / n, o);
      vertices.writeFloatLE(y / n, o + 4);
      vertices.writeFloatLE(0.05 * Math.sin(x * 0.07) * Math.cos(y * 0.05), o + 8);
    }
  }
  const faces = Buffer.alloc(2 * (n - 1) * (n - 1) * 13);
  let o = 0;
  const face = (a, b, c) => {
    faces.writeUInt8(3, o);
    faces.writeInt32LE(a, o + 1);
    faces.writeInt32LE(b, o + 5);
    faces.writeInt32LE(c, o + 9);
    o += 13;
  };
  for (let y = 0; y < n - 1; y++) {
    for (let x = 0; x < n - 1; x++) {
      const v = y * n + x;
      face(v, v + 1, v + n + 1);
      face(v, v + n + 1, v + n);
    }
  }
  writeFileSync(path, Buffer.concat([Buffer.from(header), vertices, faces]));
  return path;
}

test('the jobs page reloads when a build ends, but not over a form being filled in', { timeout: 300_000 }, async () => {
  const ply = readFileSync(reliefPly(join(tmp, 'relief.ply'), 1000));
  const start = async (title) => {
    const res = await server.api.request('POST', `/api/v1/models/upload?title=${title}&filename=relief.ply`, { body: ply, headers: { 'Content-Type': 'application/octet-stream' }, raw: true });
    assert.equal(res.status, 202, await res.clone().text());
    return (await res.json()).job.id;
  };
  const statusOf = (page, id) => page.evaluate((jid) => document.getElementById(`job-${jid}`)?.getAttribute('data-job-status') ?? null, id);
  const page = await browser.page();
  await login(page, server.base, ADMIN);

  // Something typed in the upload form: the build's end shows in its row, the page stays.
  let job = await start('Busy');
  await page.goto(`${server.base}/admin/jobs`);
  assert.ok(['queued', 'running'].includes(await statusOf(page, job)), 'the build is still under way when the page opens');
  await page.evaluate(() => { window.__kept = true; });
  await page.fill('form[data-upload]:not(.retry) input[name=title]', 'Half typed');
  await poll(page, (jid) => document.getElementById(`job-${jid}`)?.getAttribute('data-job-status'), (s) => s === 'done', 120_000, job);
  await new Promise((r) => setTimeout(r, 2000));
  assert.equal(await page.evaluate(() => window.__kept), true, 'the page was not reloaded');
  assert.equal(await page.inputValue('form[data-upload]:not(.retry) input[name=title]'), 'Half typed');

  // A page nobody typed into reloads to show the result.
  job = await start('Idle');
  await page.goto(`${server.base}/admin/jobs`);
  assert.ok(['queued', 'running'].includes(await statusOf(page, job)), 'the build is still under way when the page opens');
  await page.evaluate(() => { window.__kept = true; });
  await poll(page, () => window.__kept === undefined, Boolean, 120_000);
  // The reloaded document may still be loading: its row is waited for, and must say done.
  const reloaded = await poll(page, (jid) => document.getElementById(`job-${jid}`)?.getAttribute('data-job-status') ?? null, (s) => s !== null, 30_000, job);
  assert.equal(reloaded, 'done');
  await closePage(page);
});
