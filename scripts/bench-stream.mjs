// Streaming bench: headless Chromium drives the viewer along a fixed camera path over a real
// scan served by the real server, on an emulated network link, and prints time to first image,
// time to 1 px quality, bytes transferred in total and per view, then the same path with a
// fovea set on the close-up's surface point, against the size of the full-resolution model.
// Figures are printed, never asserted.
// Usage: scripts/bench-stream [--mesh FILE] [--mbps N] [--latency MS] [--view-timeout S]

import { statSync } from 'node:fs';
import { join } from 'node:path';

import { cameraPath, openOnLink, option, pickMesh } from './bench-path.mjs';
import { ADMIN, importScan, startServer } from '../tests/browser/support/server.mjs';
import { launch, poll } from '../tests/browser/support/browser.mjs';
import { leafVertices, regionAt } from '../tests/browser/support/regions.mjs';

const opt = option(process.argv.slice(2));
const MBPS = Number(opt('mbps', '16'));
const LATENCY_MS = Number(opt('latency', '20'));
// Software GL draws a few hundred thousand triangles per second: large scans need longer.
const VIEW_TIMEOUT = Number(opt('view-timeout', '180')) * 1000;

async function run(server, model, path, probe, fovea) {
  const browser = await launch();
  try {
    const { page, t0 } = await openOnLink(browser, server, model, ADMIN, path, { mbps: MBPS, latencyMs: LATENCY_MS, timeout: VIEW_TIMEOUT });
    await page.evaluate(({ probe, fovea }) => {
      window.meshwikiViewer.setProbes([probe]);
      if (fovea) window.meshwikiViewer.setFoveae([probe]);
    }, { probe, fovea });
    const rows = [];
    let firstImage = null;
    for (const [i, cam] of path.entries()) {
      const frames0 = i === 0 ? 0 : (await page.evaluate(() => window.meshwikiViewer.stats())).frames;
      const start = i === 0 ? t0 : Date.now();
      if (i > 0) await page.evaluate((c) => window.meshwikiViewer.setCamera(c), cam);
      const before = i === 0 ? 0 : rows[i - 1].bytesAfter;
      let atFovea = null;
      const done = await poll(page, () => window.meshwikiViewer?.stats(), (s) => {
        if (!s || s.frames <= frames0 || s.drawn === 0) return false;
        if (atFovea === null && s.foveaError <= 1.0001) atFovea = { ms: Date.now() - start, bytes: s.bytes - before };
        return s.settled;
      }, VIEW_TIMEOUT);
      if (i === 0) firstImage = done.firstImageMs;
      rows.push({
        name: cam.name,
        ms: Date.now() - start,
        bytes: done.bytes - before,
        bytesAfter: done.bytes,
        triangles: done.triangles,
        maxError: done.maxError,
        foveaError: done.foveaError,
        atFovea,
      });
    }
    const stats = await page.evaluate(() => window.meshwikiViewer.stats());
    return { rows, firstImage, navigationToFirstImage: firstImage, stats };
  } finally {
    await browser.close();
  }
}

const mb = (b) => (b / 1e6).toFixed(2).padStart(7);

async function main() {
  const mesh = pickMesh(opt('mesh', null));
  const server = await startServer();
  try {
    const t = Date.now();
    const model = await importScan(server.api, mesh.path, `bench ${mesh.name}`);
    const importMs = Date.now() - t;
    const lodPath = join(server.dataDir, model.lod_path);
    const leaves = await leafVertices(lodPath);
    const { table } = leaves;
    const p = regionAt(leaves, [0, 0, 1], [0, 0, 0], 0.01).seed;
    const path = cameraPath(table.center, table.radius, p);
    console.log(`meshwiki bench stream: ${mesh.name} (${model.vertex_count} vertices, ${model.triangle_count} triangles), imported in ${(importMs / 1000).toFixed(1)} s`);
    console.log(`  LOD: ${table.nodeCount} patches, ${table.levelCount} levels; link ${MBPS} Mbit/s, ${LATENCY_MS} ms latency (Chromium network emulation), headless, software GL`);
    console.log(`  full resolution: scan file ${mb(statSync(mesh.path).size)} MB, full-resolution patches ${mb(table.leafBytes)} MB, whole LOD file ${mb(table.fileBytes)} MB`);
    const plain = await run(server, model, path, p, false);
    const foveated = await run(server, model, path, p, true);
    for (const [label, r] of [['without fovea', plain], ['with a fovea on the close-up point', foveated]]) {
      console.log(`\n  ${label}: first image ${Math.round(r.firstImage)} ms after navigation start (tables ${r.stats.tableBytes} bytes)`);
      console.log(`    view           settled in    bytes (MB)  triangles  max err px   point at 1 px after: time, MB`);
      for (const row of r.rows) {
        const fov = row.atFovea ? `${String(row.atFovea.ms).padStart(8)} ms ${mb(row.atFovea.bytes)}` : '   (not reached)';
        console.log(`    ${row.name.padEnd(14)} ${String(row.ms).padStart(8)} ms  ${mb(row.bytes)}   ${String(row.triangles).padStart(9)}  ${row.maxError.toFixed(2).padStart(9)}   ${fov}`);
      }
      const total = r.rows.reduce((s, x) => s + x.bytes, 0);
      const time = r.rows.reduce((s, x) => s + x.ms, 0);
      console.log(`    total          ${String(time).padStart(8)} ms  ${mb(total)}   = ${((100 * total) / table.leafBytes).toFixed(1)}% of the full-resolution patches, ${((100 * total) / statSync(mesh.path).size).toFixed(1)}% of the scan file`);
      const byLevel = r.stats.bytesByLevel || [];
      const leaf = byLevel[0] || 0;
      console.log(`    by level (0 = full resolution): ${byLevel.map((b, l) => `L${l} ${(b / 1e6).toFixed(2)}`).join(', ')} MB; full-resolution patches fetched: ${((100 * leaf) / table.leafBytes).toFixed(0)}% of them`);
    }
    const plainTotal = plain.rows.reduce((s, x) => s + x.bytes, 0);
    const fovTotal = foveated.rows.reduce((s, x) => s + x.bytes, 0);
    const closeUp = 4;
    const plainClose = plain.rows.slice(0, closeUp).reduce((s, x) => s + x.bytes, 0) + (plain.rows[closeUp].atFovea?.bytes ?? plain.rows[closeUp].bytes);
    const fovClose = foveated.rows.slice(0, closeUp).reduce((s, x) => s + x.bytes, 0) + (foveated.rows[closeUp].atFovea?.bytes ?? foveated.rows[closeUp].bytes);
    console.log(`\n  bytes until the close-up shows the fovea point at 1 px (path so far): ${mb(plainClose)} MB without a fovea, ${mb(fovClose)} MB with it (${((100 * fovClose) / plainClose).toFixed(0)}%)`);
    console.log(`  whole path: ${mb(plainTotal)} MB without, ${mb(fovTotal)} MB with the fovea (${((100 * fovTotal) / plainTotal).toFixed(0)}%)`);
  } finally {
    await server.stop();
  }
}

main().catch((e) => {
  console.error(e);
  process.exit(1);
});
