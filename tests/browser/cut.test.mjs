// The browser's view-dependent cut (static/js/lod/cut.js) against the engine's cut rule
// (engine/src/lod/cut.rs `cut_view`, through `meshwiki lod cut`) on hierarchies the engine
// built from real scans: with every patch resident, no fovea and no occlusion feedback, the
// browser draws exactly the engine's cut, for views all around the model, far and close, at
// several pixel thresholds and image sizes. The engine computes in f32 and the browser in
// f64, so a node may differ only where one of its tests sits on the threshold (a ratio or a
// culling distance within 1e-4 of its bound); the test reports how many did.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { Cut, makeView, projectedError } from '../../static/js/lod/cut.js';
import { meshwiki, sampleMesh } from './support/env.mjs';
import { readLod } from './support/regions.mjs';

const DIRECTIONS = [
  [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
  [1, 1, 1], [-1, 1, 1], [1, -1, 1], [1, 1, -1], [-1, -1, 1], [-1, 1, -1], [1, -1, -1], [-1, -1, -1],
].map((d) => {
  const l = Math.hypot(...d);
  return d.map((v) => v / l);
});


/** Views around the root sphere: far, near, close-up inside it, two sizes and thresholds. */
function views(t) {
  const r0 = t.roots[0];
  let c = [t.bounds[r0 * 4], t.bounds[r0 * 4 + 1], t.bounds[r0 * 4 + 2]];
  let radius = 0;
  for (const r of t.roots) radius = Math.max(radius, t.bounds[r * 4 + 3] + Math.hypot(t.bounds[r * 4] - c[0], t.bounds[r * 4 + 1] - c[1], t.bounds[r * 4 + 2] - c[2]));
  c = c.map(Math.fround);
  const out = [];
  let k = 0;
  for (const d of DIRECTIONS) {
    for (const dist of [0.35, 1.4, 3, 8, 60]) {
      const eye = c.map((v, i) => Math.fround(v + d[i] * dist * radius));
      const up = Math.abs(d[1]) > 0.9 ? [0, 0, 1] : [0, 1, 0];
      // Close views look off-centre, so the frustum cuts through the model.
      const target = dist < 1 ? c.map((v, i) => Math.fround(v + (i === (k % 3) ? 0.3 * radius : 0))) : c;
      const [width, height] = k % 2 ? [1280, 720] : [640, 480];
      const pixelError = [1, 0.75, 3][k % 3];
      out.push({ eye, target, up, fovy: k % 4 === 3 ? 60 : 45, width, height, pixel_error: pixelError });
      k++;
    }
  }
  return { views: out, radius };
}

/** How close node `i` is to flipping any test of the cut rule (0: on a bound). */
function margin(t, cut, view, i, radius) {
  const m = [];
  for (const g of [t.producer[i], t.memberOf[i]]) if (g >= 0) m.push(Math.abs(cut.ratio[g] - 1));
  const ls = t.lodSphere;
  const own = projectedError(view, t.lodError[i], ls[i * 4], ls[i * 4 + 1], ls[i * 4 + 2], ls[i * 4 + 3]);
  m.push(Math.abs(own / view.foveation.target - 1));
  const b = t.bounds;
  const [cx, cy, cz, r] = [b[i * 4], b[i * 4 + 1], b[i * 4 + 2], b[i * 4 + 3]];
  const e = view.eye;
  const f = view.forward;
  const [tx, ty, tz] = [cx - e[0], cy - e[1], cz - e[2]];
  m.push(Math.abs(tx * f[0] + ty * f[1] + tz * f[2] + r) / radius);
  for (const p of view.planes) m.push(Math.abs(p[0] * cx + p[1] * cy + p[2] * cz + p[3] + r) / radius);
  const cutoff = t.cone[i * 4 + 3];
  if (cutoff < 1) {
    const along = tx * t.cone[i * 4] + ty * t.cone[i * 4 + 1] + tz * t.cone[i * 4 + 2];
    m.push(Math.abs(along - cutoff * Math.hypot(tx, ty, tz) - r) / radius);
  }
  return Math.min(...m);
}

test('the browser draws the engine\'s cut for every view of real hierarchies', async (t) => {
  const tmp = mkdtempSync(join(tmpdir(), 'mw-cut-'));
  t.after(() => rmSync(tmp, { recursive: true, force: true }));
  const meshes = [
    sampleMesh(tmp, ['igea_269k.ply', 'stanford_armadillo_346k.ply']),
    sampleMesh(tmp, ['gargoyle_50k_vcolor.ply', 'laurana_bust_50k_vcolor.ply']),
  ];
  for (const [k, mesh] of meshes.entries()) {
    const lod = join(tmp, `m${k}.mwlod`);
    meshwiki(['lod', 'build', mesh.path, lod]);
    const tab = readLod(lod).table;
    const { views: list, radius } = views(tab);
    const viewsPath = join(tmp, `views${k}.json`);
    writeFileSync(viewsPath, JSON.stringify(list));
    const engine = JSON.parse(meshwiki(['lod', 'cut', lod, '--views', viewsPath]));
    assert.equal(engine.length, list.length);
    const cut = new Cut(tab);
    const resident = new Uint8Array(tab.nodeCount).fill(1);
    let drawn = 0;
    let nearBound = 0;
    const distinct = new Set();
    let leaves = 0;
    let roots = 0;
    const isRoot = new Set(tab.roots);
    for (const [v, cam] of list.entries()) {
      const view = makeView(cam, { foveae: [], target: cam.pixel_error, modelRadius: radius });
      const mine = cut.run(view, resident).draw;
      const theirs = new Set(engine[v]);
      const ours = new Set(mine);
      const differ = [...mine.filter((i) => !theirs.has(i)), ...engine[v].filter((i) => !ours.has(i))];
      for (const i of differ) {
        const m = margin(tab, cut, view, i, radius);
        assert.ok(m < 1e-4, `${mesh.name}, view ${v} (${JSON.stringify(cam)}): node ${i} is ${ours.has(i) ? 'drawn by the browser only' : 'in the engine\'s cut only'}, ${m.toExponential(2)} from any bound`);
      }
      nearBound += differ.length;
      drawn += mine.length;
      distinct.add(mine.join(','));
      if (mine.some((i) => tab.producer[i] < 0)) leaves++;
      if (mine.some((i) => isRoot.has(i))) roots++;
    }
    // The views really exercise the rule: many different cuts, some down to full resolution,
    // some still at the roots.
    assert.ok(distinct.size >= 8, `${mesh.name}: only ${distinct.size} distinct cuts`);
    assert.ok(leaves > 0 && roots > 0, `${mesh.name}: ${leaves} views reach full resolution, ${roots} draw a root`);
    t.diagnostic(`${mesh.name}: ${tab.nodeCount} nodes, ${list.length} views, ${distinct.size} distinct cuts, ${drawn} nodes drawn in all, identical but ${nearBound} on a bound (f32 vs f64)`);
  }
});
