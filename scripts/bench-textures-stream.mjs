// Textured streaming bench (issue 11): headless Chromium drives the viewer along the streaming
// benches' camera path (scripts/bench-path.mjs) over a textured scan served by the real
// server on an emulated link, once per build of the scan with a different fragment-quality
// spread (the TexMesh paper's ΔQ: 0 is uniform JPEG quality, the default 10 follows feature
// density). Per view it prints the bytes received until the canvas first reaches a target
// PSNR against the server's render of the same camera (2×2 supersampled at 0.5 px: the
// full-resolution reference), until it is within 1 dB of the PSNR it settles at, and until it settles at 1 px.
// Figures are printed, never asserted.
// Usage: scripts/bench-textures-stream [--mesh FILE.gltf|FILE.obj|synth:N] [--texture-side 2048]
//        [--spreads 0,10] [--psnr 30] [--mbps N] [--latency MS] [--view-timeout S]
// (synth:N: the demo generator's relief of N triangles with its texture, written as OBJ + MTL +
// JPEG by meshwiki-bench.)

import { execFileSync } from 'node:child_process';
import { mkdtempSync, readFileSync, readdirSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { basename, dirname, join } from 'node:path';

import { cameraPath, openOnLink, option } from './bench-path.mjs';
import { SHARED_MESHES } from '../tests/browser/support/env.mjs';
import { ADMIN, startServer } from '../tests/browser/support/server.mjs';
import { launch } from '../tests/browser/support/browser.mjs';
import { capture, compareWithImage, serverRenderUrl } from '../tests/browser/support/pixels.mjs';
import { leafVertices, regionAt } from '../tests/browser/support/regions.mjs';
import { storedZip } from '../tests/browser/support/zip.mjs';

const opt = option(process.argv.slice(2));
const MESH = opt('mesh', join(SHARED_MESHES, 'mask_bali_100k_textured_gltf/mask-gltf-2.0_separated-valid.gltf'));
/** Texels a side of the generated relief's texture (`--mesh synth:N`). */
const TEXTURE_SIDE = opt('texture-side', '2048');
const SPREADS = opt('spreads', '0,10').split(',').map(Number);
const TARGET = Number(opt('psnr', '30'));
const MBPS = Number(opt('mbps', '16'));
const LATENCY_MS = Number(opt('latency', '20'));
const VIEW_TIMEOUT = Number(opt('view-timeout', '180')) * 1000;
/** How often the canvas is compared with the reference while a view streams. */
const SAMPLE_MS = 1000;

const mb = (b) => (b / 1e6).toFixed(2).padStart(6);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** Uploads the glTF and the files beside it as one .zip, built with `spread`; the model. */
async function upload(api, gltf, spread) {
  const dir = dirname(gltf);
  const files = readdirSync(dir).filter((f) => /\.(gltf|glb|bin|obj|mtl|jpe?g|png|webp)$/i.test(f));
  const zip = storedZip(files.map((f) => [`scan/${f}`, readFileSync(join(dir, f))]));
  const q = new URLSearchParams({ title: `${basename(gltf)} ΔQ ${spread}`, filename: 'scan.zip', texture_spread: String(spread) });
  const res = await api.request('POST', `/api/v1/models/upload?${q}`, { body: zip, headers: { 'Content-Type': 'application/zip' }, raw: true });
  const text = await res.text();
  if (res.status !== 202) throw new Error(`upload: HTTP ${res.status}: ${text}`);
  const { model, job } = JSON.parse(text);
  for (;;) {
    const j = await api.get(`/api/v1/jobs/${job.id}`);
    if (j.status === 'done') return { model: await api.get(`/api/v1/models/${model.id}`), report: j.report };
    if (j.status === 'failed' || j.status === 'cancelled') throw new Error(`build ${j.status}: ${j.message}`);
    await sleep(250);
  }
}

async function run(server, model, path) {
  const browser = await launch();
  try {
    const { page } = await openOnLink(browser, server, model, ADMIN, path, { mbps: MBPS, latencyMs: LATENCY_MS, timeout: VIEW_TIMEOUT });
    const rows = [];
    let before = 0;
    for (const [i, cam] of path.entries()) {
      if (i > 0) await page.evaluate((c) => window.meshwikiViewer.setCamera(c), cam);
      const frames0 = (await page.evaluate(() => window.meshwikiViewer.stats())).frames;
      const start = Date.now();
      let url = null;
      let reached = null;
      let last = null;
      const samples = [];
      for (;;) {
        const s = await page.evaluate(() => window.meshwikiViewer.stats());
        if (Date.now() - start > VIEW_TIMEOUT) throw new Error(`view ${cam.name} did not settle`);
        if (s.frames > (i === 0 ? 0 : frames0) && s.drawn > 0) {
          const frame = await capture(page, 'bench');
          // The reference: the server's render at twice the size and 0.5 px, which the page
          // scales down 2:1 (bilinear at the centre of each 2×2 block: their mean), so the
          // reference is neither coarser nor more aliased than a 1 px frame should be.
          url ??= (await serverRenderUrl(page, model.id, { width: frame.width * 2, height: frame.height * 2 })) + '&px=0.5';
          last = await compareWithImage(page, 'bench', url);
          samples.push({ bytes: s.bytes - before, psnr: last.psnr });
          if (reached === null && last.psnr >= TARGET) reached = { ms: Date.now() - start, bytes: s.bytes - before };
          if (s.settled) {
            // The first sample within 1 dB of where the view settles (its own ceiling: the
            // viewer and the server's rasteriser differ a little at every scale).
            const near = samples.find((x) => x.psnr >= last.psnr - 1);
            rows.push({ name: cam.name, ms: Date.now() - start, bytes: s.bytes - before, psnr: last.psnr, reached, near: near.bytes });
            before = s.bytes;
            break;
          }
        }
        await sleep(SAMPLE_MS);
      }
    }
    return rows;
  } finally {
    await browser.close();
  }
}

/** The scan to upload: `MESH`, or the generated relief written as OBJ + MTL + JPEG by
 * `meshwiki-bench textures synth:N --write-obj` into `scratch`. */
function scanPath(scratch) {
  if (!MESH.startsWith('synth:')) return MESH;
  const bench = join(process.env.CARGO_TARGET_DIR || 'target', 'debug', 'meshwiki-bench');
  execFileSync(bench, ['textures', MESH, '--texture-side', TEXTURE_SIDE, '--write-obj', scratch], { stdio: 'inherit' });
  return join(scratch, 'scan.obj');
}

async function main() {
  const scratch = mkdtempSync(join(tmpdir(), 'mw-bench-textures-'));
  // Written before the server starts: a kept-alive connection left idle while the scan is
  // written would be closed under the upload.
  const MESH_PATH = scanPath(scratch);
  const server = await startServer();
  try {
    console.log(`meshwiki bench textures-stream: ${MESH.startsWith('synth:') ? `generated relief ${MESH}, ${TEXTURE_SIDE}² texture` : basename(MESH)}, link ${MBPS} Mbit/s, ${LATENCY_MS} ms latency (Chromium emulation), target ${TARGET} dB against the server's render (2×2 supersampled, 0.5 px)`);
    const results = [];
    for (const spread of SPREADS) {
      const { model, report } = await upload(server.api, MESH_PATH, spread);
      const leaves = await leafVertices(join(server.dataDir, model.lod_path));
      const p = regionAt(leaves, [0, 0, 1], [0, 0, 0], 0.01).seed;
      const path = cameraPath(leaves.table.center, leaves.table.radius, p);
      const atlases = report?.textures ? report.textures.featured.image_bytes + report.textures.plain.image_bytes : 0;
      results.push({ spread, rows: await run(server, model, path), atlases, file: leaves.table.fileBytes });
    }
    for (const r of results) {
      console.log(`\n  ΔQ ${r.spread}: LOD file ${mb(r.file)} MB, atlases ${mb(r.atlases)} MB`);
      console.log(`    view           MB to ${TARGET} dB   MB to settled -1 dB   MB to settle at 1 px   PSNR settled`);
      for (const row of r.rows) {
        const to = row.reached ? mb(row.reached.bytes) : '(not reached)';
        console.log(`    ${row.name.padEnd(14)} ${to.padStart(12)}   ${mb(row.near).padStart(19)}   ${mb(row.bytes).padStart(20)}   ${row.psnr.toFixed(2).padStart(9)} dB`);
      }
      const sum = (f) => r.rows.reduce((s, x) => s + f(x), 0);
      const toTarget = sum((x) => (x.reached ? x.reached.bytes : x.bytes));
      const mean = sum((x) => x.psnr) / r.rows.length;
      console.log(`    path           ${mb(toTarget).padStart(12)}   ${mb(sum((x) => x.near)).padStart(19)}   ${mb(sum((x) => x.bytes)).padStart(20)}   ${mean.toFixed(2).padStart(9)} dB (mean; a view that never reaches the target counts its bytes to settle)`);
    }
  } finally {
    await server.stop();
    rmSync(scratch, { recursive: true, force: true });
  }
}

main().catch((e) => {
  console.error(e);
  process.exit(1);
});
