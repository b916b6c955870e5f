// Unit tests of the viewer's pure modules on real data: the roaring bitmap reader against
// bitmaps the server (roaring-rs) serialised, the streaming cut on a real LOD file (always a
// watertight cover, refinement only with loaded members, foveae refine their surroundings
// first), the foveation threshold, the bandwidth budget and the LRU cache.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { RoaringBitmap } from '../../static/js/parts/roaring.js';
import { parseBinary } from '../../static/js/lod/table.js';
import { Cut, makeView } from '../../static/js/lod/cut.js';
import { threshold, thresholdAt, logTransform, scaleFor } from '../../static/js/lod/foveation.js';
import { fitBudget, Throughput } from '../../static/js/lod/budget.js';
import { PatchCache } from '../../static/js/lod/cache.js';
import { meshwiki, sampleMesh } from './support/env.mjs';
import { startServer } from './support/server.mjs';

let tmp;
let table;

before(() => {
  tmp = mkdtempSync(join(tmpdir(), 'mw-units-'));
  const mesh = sampleMesh(tmp);
  const lod = join(tmp, 'm.mwlod');
  meshwiki(['lod', 'build', mesh.path, lod]);
  const file = new Uint8Array(readFileSync(lod));
  const view = new DataView(file.buffer, file.byteOffset, file.byteLength);
  table = parseBinary(file.slice(0, view.getUint32(136, true)).buffer);
});

after(() => rmSync(tmp, { recursive: true, force: true }));

test('reads roaring bitmaps serialised by the server: array, bitmap and run containers', async () => {
  const server = await startServer();
  try {
    const api = server.api;
    const model = await api.post('/api/v1/models', { title: 'bitmaps' });
    const sets = {
      sparse: [0, 5, 65535, 65536, 1_000_000, 4_000_000_000, 4_294_967_295],
      dense: Array.from({ length: 20000 }, (_, i) => 70000 + i * 3),
      runs: Array.from({ length: 30000 }, (_, i) => 200_000 + i),
    };
    for (const [name, ids] of Object.entries(sets)) {
      const part = await api.post(`/api/v1/models/${model.id}/parts`, { kind: 'region', center: [0, 0, 0], vertex_ids: ids });
      const res = await api.request('GET', `/api/v1/parts/${part.id}/vertices`, { raw: true });
      const bitmap = RoaringBitmap.deserialize(await res.arrayBuffer());
      assert.equal(bitmap.size, ids.length, name);
      assert.deepEqual([...bitmap.values()], ids, name);
      for (const id of ids) assert.ok(bitmap.has(id), `${name} has ${id}`);
      for (const id of [1, 65534, 69999, 70001, 199_999, 230_000, 4_294_967_294]) assert.equal(bitmap.has(id), ids.includes(id), `${name} ${id}`);
    }
    assert.equal(RoaringBitmap.deserialize(new Uint8Array(0)).size, 0);
    assert.throws(() => RoaringBitmap.deserialize(new Uint8Array([1, 2, 3, 4, 5])));
  } finally {
    await server.stop();
  }
});

const camera = (t, distance, dir = [0, 0, 1]) => ({
  eye: t.center.map((c, k) => c + dir[k] * distance * t.radius),
  target: t.center,
  up: [0, 1, 0],
  fovy: 40,
  width: 800,
  height: 600,
});
const foveation = (t, foveae = []) => ({ target: 1, foveae, alpha: 20, rMax: 1.5, modelRadius: t.radius });

/** Checks that the cut replaces groups whole: refined groups show no product, others no member. */
function assertCut(t, cut) {
  for (let g = 0; g < t.groupCount; g++) {
    const members = [...t.members[g]].map((m) => cut.inCut[m]);
    const products = [...t.products[g]].map((p) => cut.inCut[p]);
    if (cut.refined[g]) {
      assert.ok(products.every((x) => !x), `group ${g} refined but a product is still in the cut`);
    } else {
      assert.ok(members.every((x) => !x), `group ${g} not refined but a member is in the cut`);
    }
  }
  // A leaf is in the cut exactly when the group it is a member of is refined.
  for (let i = 0; i < t.nodeCount; i++) {
    if (t.level[i] !== 0) continue;
    const g = t.memberOf[i];
    assert.equal(cut.inCut[i] === 1, g >= 0 && cut.refined[g] === 1, `leaf ${i}`);
  }
}

test('the streaming cut is a watertight cover whatever is loaded, and refines only loaded groups', () => {
  const t = table;
  const cut = new Cut(t);
  const resident = new Uint8Array(t.nodeCount);
  // Nothing loaded: only roots, all requested.
  let r = cut.run(makeView(camera(t, 3), foveation(t)), resident);
  assert.equal(r.draw.length, 0);
  const first = r.requests.filter((q) => q.priority === Infinity).map((q) => q.node);
  assert.deepEqual(first.sort((a, b) => a - b), [...t.roots].sort((a, b) => a - b), 'roots come first');
  assertCut(t, cut);
  // Load in the order asked, one request at a time: each cut stays valid and every drawn node
  // is loaded; the requests come largest error first.
  let steps = 0;
  for (; steps < t.nodeCount; steps++) {
    r = cut.run(makeView(camera(t, 0.9), foveation(t)), resident);
    assertCut(t, cut);
    for (const n of r.draw) assert.ok(resident[n], `drawn node ${n} not loaded`);
    for (let k = 1; k < r.requests.length; k++) {
      if (r.requests[k - 1].priority !== Infinity) assert.ok(r.requests[k - 1].priority >= 0);
    }
    if (r.requests.length === 0) break;
    const next = r.requests.reduce((a, b) => (b.priority > a.priority ? b : a));
    resident[next.node] = 1;
  }
  assert.ok(steps > 3, 'refined through several levels');
  assert.ok(r.maxRatio <= 1 + 1e-6, `settled cut above target: ${r.maxRatio}`);
  // Evicting a drawn node's group members makes the cut fall back, never leave a hole.
  const drawnBefore = r.draw.length;
  for (const n of r.draw) if (t.level[n] === 0) resident[n] = 0;
  r = cut.run(makeView(camera(t, 0.9), foveation(t)), resident);
  assertCut(t, cut);
  for (const n of r.draw) assert.ok(resident[n]);
  assert.ok(r.draw.length > 0 && drawnBefore > 0);
});

test('a fovea refines its surroundings to the target and leaves the periphery coarser', () => {
  const t = table;
  const all = new Uint8Array(t.nodeCount).fill(1);
  const cam = camera(t, 0.8);
  const fovea = [t.center[0], t.center[1], t.center[2] + 0.5 * t.radius];
  const plain = new Cut(t).run(makeView(cam, foveation(t)), all, 0, [fovea]);
  const fov = new Cut(t).run(makeView(cam, foveation(t, [fovea])), all, 0, [fovea]);
  assert.ok(fov.foveaError <= 1 + 1e-6, `fovea not at 1 px: ${fov.foveaError}`);
  assert.ok(fov.triangles <= plain.triangles, `${fov.triangles} > ${plain.triangles}`);
  assert.ok(fov.maxError >= plain.maxError);
});

test('patches a visibility pass saw no pixel of stay coarse; the rest still reaches the target, watertight', () => {
  const t = table;
  const cam = camera(t, 0.9);
  const all = new Uint8Array(t.nodeCount).fill(1);
  const full = new Cut(t).run(makeView(cam, foveation(t)), all);
  // A coarse cut (only the top levels loaded) is what a visibility pass saw; hide its
  // patches on one side of the model.
  let coarse = null;
  for (let level = t.levelCount - 1; level >= 1; level--) {
    const top = new Uint8Array(t.nodeCount);
    for (let i = 0; i < t.nodeCount; i++) top[i] = t.level[i] >= level ? 1 : 0;
    coarse = new Cut(t).run(makeView(cam, foveation(t)), top);
    if (coarse.draw.length >= t.nodeCount / 5) break;
  }
  const occluded = new Uint8Array(t.nodeCount);
  let hidden = 0;
  for (const n of coarse.draw) {
    if (t.bounds[n * 4] < t.center[0]) {
      occluded[n] = 1;
      hidden++;
    }
  }
  assert.ok(hidden > 0 && hidden < coarse.draw.length, `hidden ${hidden} of ${coarse.draw.length}`);
  const cut = new Cut(t);
  const r = cut.run(makeView(cam, foveation(t)), all, 0, null, occluded);
  assertCut(t, cut);
  assert.ok(r.triangles < full.triangles, `occlusion saved nothing: ${r.triangles} vs ${full.triangles}`);
  assert.ok(r.maxRatio <= 1 + 1e-6, `shown surface above target: ${r.maxRatio}`);
  // Every hidden patch still drawn is one of those hidden (not refined) or was needed by a
  // finer group that wants refinement next to the visible side.
  const stillCoarse = r.draw.filter((n) => occluded[n]).length;
  assert.ok(stillCoarse > 0, 'no hidden patch stayed coarse');
});

test('foveation follows the log transform and takes the nearest fovea', () => {
  const f = { target: 1, foveae: [[0, 0, 0], [10, 0, 0]], alpha: 4, rMax: 2, modelRadius: 1 };
  assert.equal(threshold(f, 0, 0, 0, 0.1), 1);
  assert.equal(threshold(f, 9.5, 0, 0, 0), 1 + 4 * 0.5);
  assert.equal(threshold(f, 5, 0, 0, 0), 1 + 4 * 2, 'capped at r_max');
  assert.equal(thresholdAt({ ...f, foveae: [] }, 3), 1);
  // Sample spacing of eq. 1 normalised at the fovea equals the threshold factor.
  const s = scaleFor(10, 2, 4);
  const spacing = (r) => 1 / ((logTransform(r + 1e-6, 4, s) - logTransform(r, 4, s)) / 1e-6);
  assert.ok(Math.abs(spacing(0.5) / spacing(0) - thresholdAt(f, 0.5)) < 1e-3);
});

test('the budget fits B·T and the throughput follows completed requests', () => {
  const c = [{ bytes: 400 }, { bytes: 400 }, { bytes: 400 }];
  assert.equal(fitBudget(c, { bandwidth: 1000, maxWait: 1, inFlightBytes: 0, inFlight: 0, maxInFlight: 8 }).length, 2);
  assert.equal(fitBudget(c, { bandwidth: 1000, maxWait: 1, inFlightBytes: 900, inFlight: 1, maxInFlight: 8 }).length, 0);
  assert.equal(fitBudget([{ bytes: 5000 }], { bandwidth: 1000, maxWait: 1, inFlightBytes: 0, inFlight: 0, maxInFlight: 8 }).length, 1, 'an oversized patch still goes alone');
  assert.equal(fitBudget(c, { bandwidth: 1e9, maxWait: 1, inFlightBytes: 0, inFlight: 0, maxInFlight: 2 }).length, 2);
  const tp = new Throughput(1);
  tp.start(0);
  tp.finish(1000, 500_000);
  assert.ok(Math.abs(tp.estimate() - 500_000) < 1);
});

test('the cache evicts least recently used, never pinned nodes', () => {
  const cache = new PatchCache(100);
  for (const n of [1, 2, 3, 4]) cache.add(n, 40);
  cache.touch([1]);
  const pinned = new Uint8Array(8);
  pinned[2] = 1;
  assert.deepEqual(cache.evict(pinned), [3, 4]);
  assert.equal(cache.bytes, 80);
  assert.ok(cache.fits(20, pinned));
  assert.ok(!cache.fits(200, pinned));
});
