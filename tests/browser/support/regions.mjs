// Regions of a real scan for seeded parts: the original ids of the full-resolution vertices
// near a point, read from the model's LOD file with the (Rust-verified) patch decoder.

import { readFileSync } from 'node:fs';
import { decodePatch } from '../../../static/js/lod/decode.js';
import { parseBinary } from '../../../static/js/lod/table.js';
import { decoderDeps } from './env.mjs';

/**
 * A LOD file's bytes and its tables, parsed by the browser's reader from the header and
 * tables that precede the blobs (their offset: the header's u64 at byte 136, docs/FORMAT.md).
 */
export function readLod(lodPath) {
  const file = new Uint8Array(readFileSync(lodPath));
  const view = new DataView(file.buffer, file.byteOffset, file.byteLength);
  const blobsOffset = view.getUint32(136, true) + view.getUint32(140, true) * 2 ** 32;
  return { file, table: parseBinary(file.slice(0, blobsOffset).buffer) };
}

/** Every full-resolution vertex of a LOD file: {ids, positions, table}. */
export async function leafVertices(lodPath) {
  const deps = await decoderDeps();
  const { file, table } = readLod(lodPath);
  const ids = [];
  const positions = [];
  for (let i = 0; i < table.nodeCount; i++) {
    if (table.level[i] !== 0) continue;
    const p = decodePatch(file.subarray(table.offset[i], table.offset[i] + table.length[i]), table.grid, deps);
    for (let v = 0; v < p.vertexCount; v++) {
      ids.push(p.ids[v]);
      positions.push([p.positions[v * 3], p.positions[v * 3 + 1], p.positions[v * 3 + 2]]);
    }
  }
  return { ids, positions, table };
}

/**
 * The vertex most extreme along `dir` among those within `spread` (model radii) of the axis
 * through the centre, and the ids of the vertices within `radius` (model radii) of it.
 */
export function regionAt(mesh, dir, offset = [0, 0, 0], radius = 0.12) {
  const { table } = mesh;
  const R = table.radius;
  const c = table.center.map((v, k) => v + offset[k] * R);
  let best = -Infinity;
  let seed = null;
  for (const p of mesh.positions) {
    const rel = p.map((v, k) => v - c[k]);
    const along = rel[0] * dir[0] + rel[1] * dir[1] + rel[2] * dir[2];
    const off = Math.hypot(rel[0] - along * dir[0], rel[1] - along * dir[1], rel[2] - along * dir[2]);
    if (off < 0.05 * R && along > best) {
      best = along;
      seed = p;
    }
  }
  if (!seed) throw new Error('no vertex on that axis');
  const ids = new Set();
  const sum = [0, 0, 0];
  mesh.positions.forEach((p, i) => {
    if (Math.hypot(p[0] - seed[0], p[1] - seed[1], p[2] - seed[2]) <= radius * R) {
      ids.add(mesh.ids[i]);
      for (let k = 0; k < 3; k++) sum[k] += p[k];
    }
  });
  const n = ids.size;
  return { ids: [...ids].sort((a, b) => a - b), center: sum.map((v) => v / n), seed };
}
