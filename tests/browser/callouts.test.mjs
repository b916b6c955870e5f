// The viewer's callout label placement (static/js/parts/place.js `placeLabels`) against the
// server's (engine/src/render/callouts.rs `place`, through GET /api/v1/models/{id}/render/callouts)
// on a real scan imported through the real pipeline: parts seeded on the surface the server
// renders, labelled with titles of varied length, seen from several cameras in small images so
// that the labels crowd and the costs decide. The browser is given the server's visible anchors
// and label sizes in the server's order and the depth buffer of the same view
// (GET /api/v1/models/{id}/render/buffers) for the cover penalty, and must place every label
// exactly where the server did: same rectangles, same leader ends, same labels left out.

import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { candidates, placeLabels } from '../../static/js/parts/place.js';
import { sampleMesh } from './support/env.mjs';
import { importScan, seedPart, startServer } from './support/server.mjs';

const BACKGROUND_ID = 0xffffffff;
const WORDS = ['Rosette', 'carved', 'acanthus', 'leaf', 'of', 'the', 'left', 'cheek', 'with', 'weathered',
  'marble', 'surface', 'and', 'a', 'later', 'restoration', 'in', 'plaster'];
/** Title lengths, cycled: short ones, long ones, and some longer than the server's 40 characters. */
const TITLE_LENGTHS = [4, 9, 15, 22, 30, 38, 47, 60];

let server;
let tmp;
let model;

before(async () => {
  tmp = mkdtempSync(join(tmpdir(), 'mw-callouts-'));
  const mesh = sampleMesh(tmp);
  server = await startServer();
  model = await importScan(server.api, mesh.path, `Callouts on ${mesh.name}`);
});

after(async () => {
  await server?.stop();
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

/**
 * GET `path?query` as a Response; waits out a busy render queue (503 with Retry-After).
 * Returns null when the server cannot render at all (503 without Retry-After: no GPU adapter).
 */
async function render(path, query) {
  const url = `${path}?${new URLSearchParams(query)}`;
  for (let attempt = 0; ; attempt++) {
    const res = await server.api.request('GET', url, { raw: true });
    if (res.status === 503) {
      const retry = res.headers.get('retry-after');
      const text = await res.text();
      if (retry === null) return { unavailable: text };
      assert.ok(attempt < 30, `GET ${url}: still busy after ${attempt} tries: ${text}`);
      await new Promise((r) => setTimeout(r, Math.min(5, Math.max(1, Number(retry) || 1)) * 1000));
      continue;
    }
    if (!res.ok) throw new Error(`GET ${url}: HTTP ${res.status}: ${(await res.text()).slice(0, 300)}`);
    return { res };
  }
}

/** The body of render/buffers (layout in src/web/render.rs): its header and its arrays. */
function parseBuffers(buf) {
  const bytes = new Uint8Array(buf);
  const view = new DataView(buf);
  assert.equal(new TextDecoder().decode(bytes.subarray(0, 4)), 'MWRB');
  assert.equal(view.getUint32(4, true), 1, 'buffers version');
  const length = view.getUint32(8, true);
  const header = JSON.parse(new TextDecoder().decode(bytes.subarray(12, 12 + length)));
  const arrays = {};
  for (const b of header.buffers) {
    assert.ok(b.offset + b.bytes <= buf.byteLength, `${b.name} lies inside the body`);
    if (b.type === 'f32') {
      const a = new Float32Array(b.bytes / 4);
      for (let i = 0; i < a.length; i++) a[i] = view.getFloat32(b.offset + 4 * i, true);
      arrays[b.name] = a;
    } else if (b.type === 'u32') {
      const a = new Uint32Array(b.bytes / 4);
      for (let i = 0; i < a.length; i++) a[i] = view.getUint32(b.offset + 4 * i, true);
      arrays[b.name] = a;
    }
  }
  return { header, arrays };
}

async function buffers(query) {
  const r = await render(`/api/v1/models/${model.id}/render/buffers`, query);
  if (r.unavailable) return r;
  return parseBuffers(await r.res.arrayBuffer());
}

async function calloutLayout(query) {
  const r = await render(`/api/v1/models/${model.id}/render/callouts`, query);
  if (r.unavailable) return r;
  return r.res.json();
}

const add = (a, b) => a.map((v, k) => v + b[k]);
const sub = (a, b) => a.map((v, k) => v - b[k]);
const scale = (a, s) => a.map((v) => v * s);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const normalize = (a) => scale(a, 1 / Math.hypot(...a));

/** `v` rotated by `deg` degrees about the unit `axis` (Rodrigues). */
function rotate(v, axis, deg) {
  const t = (deg * Math.PI) / 180;
  const k = normalize(axis);
  return add(add(scale(v, Math.cos(t)), scale(cross(k, v), Math.sin(t))), scale(k, dot(k, v) * (1 - Math.cos(t))));
}

/** The world point seen at pixel `(x, y)` at view depth `d` (engine/src/camera.rs `project`, inverted). */
function unproject(cam, x, y, d) {
  const f = normalize(sub(cam.target, cam.eye));
  const r = normalize(cross(f, cam.up));
  const u = cross(r, f);
  const s = cam.height / (2 * Math.tan((cam.fovy * Math.PI) / 360));
  const px = x + 0.5 - cam.width / 2;
  const py = cam.height / 2 - (y + 0.5);
  return add(add(add(cam.eye, scale(f, d)), scale(r, (px * d) / s)), scale(u, (py * d) / s));
}

function title(k) {
  const len = TITLE_LENGTHS[k % TITLE_LENGTHS.length];
  let t = `${k + 1}.`;
  for (let i = k; t.length < len; i++) t += ` ${WORDS[i % WORDS.length]}`;
  return t.slice(0, len).trim();
}

/**
 * Seeds up to `max` parts on the surface seen by the overview camera: a grid over the model's
 * extent in the image, each hit pixel's surface point as the part's centre (its callout anchor)
 * and the original vertex ids drawn around it as its vertex set.
 */
async function seedParts(setup, max) {
  const { width: w, height: h } = setup.header;
  const depth = setup.arrays.depth;
  const vertex = setup.arrays.vertex;
  let [x0, y0, x1, y1] = [w, h, -1, -1];
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      if (!Number.isFinite(depth[y * w + x])) continue;
      x0 = Math.min(x0, x);
      x1 = Math.max(x1, x);
      y0 = Math.min(y0, y);
      y1 = Math.max(y1, y);
    }
  }
  assert.ok(x1 > x0 + 20 && y1 > y0 + 20, `the model covers ${x0}..${x1} × ${y0}..${y1} of the overview`);
  const [cols, rows] = [9, 7];
  const seeds = new Set();
  const parts = [];
  for (let j = 0; j < rows && parts.length < max; j++) {
    for (let i = 0; i < cols && parts.length < max; i++) {
      const x = Math.floor(x0 + ((i + 0.5) * (x1 - x0)) / cols);
      const y = Math.floor(y0 + ((j + 0.5) * (y1 - y0)) / rows);
      const at = y * w + x;
      if (!Number.isFinite(depth[at]) || vertex[at] === BACKGROUND_ID || seeds.has(vertex[at])) continue;
      seeds.add(vertex[at]);
      const ids = new Set();
      for (let dy = -2; dy <= 2; dy++) {
        for (let dx = -2; dx <= 2; dx++) {
          const [px, py] = [x + dx, y + dy];
          if (px < 0 || py < 0 || px >= w || py >= h) continue;
          const id = vertex[py * w + px];
          if (id !== BACKGROUND_ID) ids.add(id);
        }
      }
      const k = parts.length;
      const { part } = await seedPart(server.api, model.id, {
        title: title(k),
        vertexIds: [...ids].sort((a, b) => a - b),
        center: unproject(setup.header.camera, x, y, depth[at]),
      });
      parts.push(part);
    }
  }
  return parts;
}

/** Cameras around the overview, in small images so that the labels crowd. */
function views(cam) {
  const off = sub(cam.eye, cam.target);
  const side = cross(off, cam.up);
  const at = (eye, w, h) => ({
    eye: eye.join(','),
    target: cam.target.join(','),
    up: cam.up.join(','),
    fovy: String(cam.fovy),
    w: String(w),
    h: String(h),
  });
  return [
    { name: 'overview, 240×180', query: { w: '240', h: '180' } },
    { name: 'overview eye, 200×150', query: at(cam.eye, 200, 150) },
    { name: 'turned 12°, 256×160', query: at(add(cam.target, rotate(off, cam.up, 12)), 256, 160) },
    { name: 'turned −18° and tilted 10°, 180×240', query: at(add(cam.target, rotate(rotate(off, cam.up, -18), side, 10)), 180, 240) },
    { name: 'closer, 320×200', query: at(add(cam.target, scale(off, 0.7)), 320, 200) },
    { name: 'overview eye, 420×400 (font scale 2)', query: at(cam.eye, 420, 400) },
  ];
}

test('the browser places every callout label exactly where the server did', { timeout: 900_000 }, async (t) => {
  const setup = await buffers({ w: '320', h: '240', buffers: 'depth,ids' });
  if (setup.unavailable) {
    t.skip(`the server cannot render: ${setup.unavailable}`);
    return;
  }
  const parts = await seedParts(setup, 40);
  assert.ok(parts.length >= 12, `only ${parts.length} parts could be seeded on the surface`);
  t.diagnostic(`${parts.length} parts seeded on model ${model.id}`);
  // The route labels every part of the model, at most 64.
  const labelled = Math.min(64, (await server.api.get(`/api/v1/models/${model.id}/parts`)).length);
  assert.ok(labelled >= parts.length);

  const totals = { labels: 0, placed: 0, noRoom: 0, away: 0, sides: 0, coverMatters: 0 };
  for (const v of views(setup.header.camera)) {
    const layout = await calloutLayout(v.query);
    const frame = await buffers({ ...v.query, buffers: 'depth' });
    assert.ok(!layout.unavailable && !frame.unavailable, `${v.name}: the server stopped rendering`);
    const { width, height, margin, labels } = layout;
    assert.equal(frame.header.width, width, `${v.name}: same image`);
    assert.equal(frame.header.height, height, `${v.name}: same image`);
    // f32 values: the buffers header may spell them as f64, the layout as the shortest f32.
    const f32s = (c) => JSON.parse(JSON.stringify(c, (_, x) => (typeof x === 'number' ? Math.fround(x) : x)));
    assert.deepEqual(f32s(frame.header.camera), f32s(layout.camera), `${v.name}: same camera`);
    const depth = frame.arrays.depth;
    assert.equal(depth.length, width * height, `${v.name}: a depth per pixel`);
    assert.ok(Array.isArray(labels) && Number.isInteger(margin), `${v.name}: the layout lists its labels and margin`);
    assert.equal(
      labels.length + layout.hidden.filter((h) => h.reason !== 'no_room').length,
      labelled,
      `${v.name}: every part is either a label to place or hidden before placement`,
    );

    const spots = placeLabels(labels, width, height, margin, depth);
    assert.equal(spots.length, labels.length);
    const noRoom = layout.hidden.filter((h) => h.reason === 'no_room').map((h) => h.part);
    assert.deepEqual(
      labels.filter((_, k) => spots[k] === null).map((l) => l.part),
      noRoom,
      `${v.name}: the same labels find no room`,
    );
    const placed = labels.filter((_, k) => spots[k] !== null);
    assert.deepEqual(
      layout.callouts.map((c) => c.part),
      placed.map((l) => l.part),
      `${v.name}: the same labels are placed, in the same order`,
    );
    let next = 0;
    let away = 0;
    let sides = 0;
    for (const [k, label] of labels.entries()) {
      const spot = spots[k];
      if (spot === null) continue;
      const c = layout.callouts[next++];
      const what = `${v.name}: part ${label.part} (label ${k}, "${c.text}")`;
      assert.deepEqual(c.anchor.map(Math.fround), label.anchor.map(Math.fround), `${what}: anchor`);
      assert.deepEqual([c.label.w, c.label.h], label.size, `${what}: label size`);
      assert.deepEqual(
        { label: spot.label, end: spot.end, placement: spot.placement },
        {
          label: { x: Math.fround(c.label.x), y: Math.fround(c.label.y), w: Math.fround(c.label.w), h: Math.fround(c.label.h) },
          end: c.leader[1].map(Math.fround),
          placement: c.placement,
        },
        `${what}: placed where the server placed it`,
      );
      assert.deepEqual(c.leader[0].map(Math.fround), label.anchor.map(Math.fround), `${what}: the leader starts at the anchor`);
      const first = candidates(label.anchor, label.size, width, height, margin)[0].rect;
      if (first.x !== spot.label.x || first.y !== spot.label.y) away++;
      if (spot.placement !== 'around') sides++;
    }
    const without = placeLabels(labels, width, height, margin, null);
    const coverMatters = without.some((s, k) => JSON.stringify(s) !== JSON.stringify(spots[k]));
    t.diagnostic(
      `${v.name}: ${labels.length} labels, ${placed.length} placed (${away} away from the first candidate, ` +
        `${sides} along a side), ${noRoom.length} without room; the cover penalty ${coverMatters ? 'changes' : 'does not change'} the layout`,
    );
    totals.labels += labels.length;
    totals.placed += placed.length;
    totals.noRoom += noRoom.length;
    totals.away += away;
    totals.sides += sides;
    totals.coverMatters += coverMatters ? 1 : 0;
  }
  t.diagnostic(JSON.stringify(totals));
  assert.ok(totals.labels >= 3 * parts.length, `crowded views: ${totals.labels} labels over 6 views of ${parts.length} parts`);
  assert.ok(totals.placed > 0, 'some labels are placed');
  assert.ok(totals.away > 0, 'the costs matter: some labels are placed away from their first candidate');
  assert.ok(totals.noRoom > 0, 'crowded views: some labels find no room');
});
