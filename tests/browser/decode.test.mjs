// The browser's patch decoder (static/js/lod/decode.js) against the reference decoder
// (engine/src/lod/codec.rs, through `meshwiki lod dump`) on LOD files the engine built from
// real scans: identical original ids, grid positions, world positions, triangles, colours
// and normals.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { decodePatch, DecodeError } from '../../static/js/lod/decode.js';
import { crc32 } from '../../static/js/lod/table.js';
import { decoderDeps, meshwiki, sampleMesh } from './support/env.mjs';
import { readLod } from './support/regions.mjs';

function checkFile(lodPath, dumpPath, deps) {
  const { file, table } = readLod(lodPath);
  const dump = JSON.parse(readFileSync(dumpPath, 'utf8'));
  assert.equal(table.nodeCount, dump.node_count);
  assert.equal(table.groupCount, dump.group_count);
  assert.deepEqual(table.grid.origin, dump.grid.origin);
  assert.equal(table.grid.step, dump.grid.step);
  assert.equal(dump.patches.length, table.nodeCount);
  let vertices = 0;
  for (const ref of dump.patches) {
    const i = ref.node;
    assert.equal(table.offset[i], ref.offset);
    assert.equal(table.length[i], ref.length);
    const blob = file.subarray(table.offset[i], table.offset[i] + table.length[i]);
    assert.equal(crc32(blob), table.crc[i], `crc of node ${i}`);
    const p = decodePatch(blob, table.grid, deps);
    const n = ref.original_ids.length;
    assert.equal(p.vertexCount, n, `vertex count of node ${i}`);
    assert.equal(p.vertexCount, table.vertices[i]);
    assert.equal(p.triangleCount, table.triangles[i]);
    assert.deepEqual(Array.from(p.ids), ref.original_ids, `original ids of node ${i}`);
    assert.deepEqual(Array.from(p.gridPositions), ref.grid_positions.flat(), `grid positions of node ${i}`);
    assert.deepEqual(Array.from(p.positions), ref.positions.flat().map(Math.fround), `positions of node ${i}`);
    assert.deepEqual(Array.from(p.indices), ref.indices, `triangles of node ${i}`);
    if (dump.has_colors) assert.deepEqual(Array.from(p.colors), ref.colors.flat(), `colours of node ${i}`);
    else assert.equal(p.colors, null);
    if (dump.has_normals) assert.deepEqual(Array.from(p.normals), ref.normals.flat().map(Math.fround), `normals of node ${i}`);
    vertices += n;
  }
  return { nodes: table.nodeCount, vertices };
}

test('decodes every patch of real LOD files exactly as the engine does', async (t) => {
  const deps = await decoderDeps();
  const tmp = mkdtempSync(join(tmpdir(), 'mw-decode-'));
  t.after(() => rmSync(tmp, { recursive: true, force: true }));
  const meshes = [
    sampleMesh(tmp, ['igea_269k.ply', 'stanford_armadillo_346k.ply']),
    sampleMesh(tmp, ['gargoyle_50k_vcolor.ply', 'laurana_bust_50k_vcolor.ply']),
  ];
  for (const [k, mesh] of meshes.entries()) {
    const lod = join(tmp, `m${k}.mwlod`);
    const dump = join(tmp, `m${k}.json`);
    meshwiki(['lod', 'build', mesh.path, lod]);
    meshwiki(['lod', 'dump', lod, '--out', dump]);
    const { nodes, vertices } = checkFile(lod, dump, deps);
    t.diagnostic(`${mesh.name}: ${nodes} patches, ${vertices} vertices decoded identically`);
  }
});

test('corrupt blobs are errors, never crashes or hangs', async () => {
  const deps = await decoderDeps();
  const grid = { origin: [0, 0, 0], step: 1 };
  assert.throws(() => decodePatch(new Uint8Array(0), grid, deps), DecodeError);
  assert.throws(() => decodePatch(new TextEncoder().encode('MWP2\x01\0\0\0\xff\xff\xff\x00garbage'), grid, deps), DecodeError);
  const tmp = mkdtempSync(join(tmpdir(), 'mw-corrupt-'));
  try {
    const mesh = sampleMesh(tmp, ['gargoyle_50k_vcolor.ply']);
    const lod = join(tmp, 'c.mwlod');
    meshwiki(['lod', 'build', mesh.path, lod]);
    const { file, table } = readLod(lod);
    const last = table.nodeCount - 1;
    const blob = file.slice(table.offset[last], table.offset[last] + table.length[last]);
    for (let cut = 0; cut < blob.length; cut += 97) {
      try {
        decodePatch(blob.subarray(0, cut), table.grid, deps);
      } catch (e) {
        assert.ok(e instanceof DecodeError, `truncated at ${cut}: ${e}`);
      }
    }
    for (let i = 12; i < blob.length; i += 13) {
      const flipped = blob.slice();
      flipped[i] ^= 0x5a;
      try {
        decodePatch(flipped, table.grid, deps);
      } catch (e) {
        assert.ok(e instanceof DecodeError, `flipped byte ${i}: ${e}`);
      }
    }
  } finally {
    rmSync(tmp, { recursive: true, force: true });
  }
});
