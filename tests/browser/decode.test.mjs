// The browser's patch decoder (static/js/lod/decode.js) against the reference decoder
// (engine/src/lod/codec.rs, through `meshwiki lod dump`) on LOD files the engine built from
// real scans: identical original ids, grid positions, world positions, triangles, colours
// and normals, and for a textured scan texture coordinates and atlas images. Hand-built blobs
// (no binary needed) check the textured layout of docs/FORMAT.md "Patch blob": the image
// section in front of the payload, the sixth stream of texture coordinates, wedge vertices.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { existsSync, mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';

import { decodePatch, decodeYCoCg, DecodeError, imageSize, isWebp, JFIF_APP0, jpegSize, predict, STANDARD_DHT, standardDqt, walk, webpSize } from '../../static/js/lod/decode.js';
import { crc32, parseBinary } from '../../static/js/lod/table.js';
import { patchBytes } from '../../static/js/lod/stream.js';
import { SHARED_MESHES, decoderDeps, importStatic, meshwiki, sampleMesh } from './support/env.mjs';
import { readLod } from './support/regions.mjs';

function checkFile(lodPath, dumpPath, deps, codec = undefined) {
  const { file, table } = readLod(lodPath);
  const dump = JSON.parse(readFileSync(dumpPath, 'utf8'));
  assert.equal(table.nodeCount, dump.node_count);
  assert.equal(table.groupCount, dump.group_count);
  assert.deepEqual(table.grid.origin, dump.grid.origin);
  assert.equal(table.grid.step, dump.grid.step);
  assert.equal(dump.patches.length, table.nodeCount);
  let vertices = 0;
  let sorted = 0;
  let leaves = 0;
  let sortedLeaves = 0;
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
    // Textures (`lod dump` gives `uvs` per vertex and the image's length and CRC-32; binaries
    // from before textures give neither, and build untextured models only).
    // Normal maps (coarse patches of a build with them; `lod dump` gives their length and
    // CRC-32, and texture coordinates for them on untextured scans too).
    if (ref.normal_map_length != null) {
      assert.ok(p.normalMap, `normal map of node ${i}`);
      assert.equal(p.normalMap.length, ref.normal_map_length, `normal map length of node ${i}`);
      assert.equal(crc32(p.normalMap), ref.normal_map_crc32, `normal map of node ${i}`);
      assert.ok(jpegSize(p.normalMap), `node ${i}'s normal map is a JPEG with a size`);
      assert.deepEqual(Array.from(p.uvs), ref.uvs.flat().map(Math.fround), `texture coordinates of node ${i}`);
    } else {
      assert.equal(p.normalMap, null, `normal map of node ${i}`);
    }
    if (dump.has_texture) {
      assert.ok(p.image, `image of node ${i}`);
      assert.equal(p.image.length, ref.image_length, `image length of node ${i}`);
      assert.equal(crc32(p.image), ref.image_crc32, `image of node ${i}`);
      // The size the viewer reads from the image's header (JPEG or WebP) is the one the
      // engine's decoder finds (binaries from before `image_size` give none).
      assert.ok(imageSize(p.image), `node ${i}'s image has a size`);
      if (ref.image_size !== undefined) {
        assert.deepEqual(imageSize(p.image), { width: ref.image_size[0], height: ref.image_size[1] }, `image size of node ${i}`);
      }
      if (codec !== undefined) assert.equal(isWebp(p.image), codec === 'webp', `node ${i}'s image is ${codec}`);
      assert.deepEqual(Array.from(p.uvs), ref.uvs.flat().map(Math.fround), `texture coordinates of node ${i}`);
      // Wedges: copies of a vertex (one per chart) decode to the same grid position.
      const at = new Map();
      for (let v = 0; v < n; v++) {
        const g = `${p.gridPositions[v * 3]},${p.gridPositions[v * 3 + 1]},${p.gridPositions[v * 3 + 2]}`;
        const seen = at.get(p.ids[v]);
        if (seen === undefined) at.set(p.ids[v], g);
        else assert.equal(g, seen, `copies of vertex ${p.ids[v]} in node ${i}`);
      }
    } else {
      assert.equal(p.image, null, `image of node ${i}`);
      if (ref.normal_map_length == null) assert.equal(p.uvs, null, `texture coordinates of node ${i}`);
    }
    vertices += n;
    sorted += p.sortedIds;
    if (table.level[i] === 0) {
      leaves += 1;
      sortedLeaves += p.sortedIds;
    }
  }
  assert.equal(table.hasTexture, !!dump.has_texture);
  assert.equal(table.hasNormalMaps, !!dump.has_normal_maps);
  return { nodes: table.nodeCount, vertices, sorted, leaves, sortedLeaves };
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
    const { nodes, vertices, sorted, leaves, sortedLeaves } = checkFile(lod, dump, deps);
    // `lod build` numbers vertices in Morton order, so the leaves (full precision) list their
    // ids sorted (payload flag bit 3), which costs far less than predicting them; coarse
    // patches keep whichever is shorter.
    assert.ok(sortedLeaves * 10 >= leaves * 9, `${sortedLeaves} of ${leaves} leaves list sorted ids`);
    t.diagnostic(`${mesh.name}: ${nodes} patches (${sorted} with sorted ids), ${vertices} vertices decoded identically`);
  }
});

test('decodes normal maps exactly as the engine does', async (t) => {
  const deps = await decoderDeps();
  const tmp = mkdtempSync(join(tmpdir(), 'mw-decode-nm-'));
  t.after(() => rmSync(tmp, { recursive: true, force: true }));
  const mesh = sampleMesh(tmp, ['gargoyle_50k_vcolor.ply', 'laurana_bust_50k_vcolor.ply']);
  const lod = join(tmp, 'mapped.mwlod');
  const dump = join(tmp, 'mapped.json');
  meshwiki(['lod', 'build', '--normal-maps', mesh.path, lod]);
  meshwiki(['lod', 'dump', lod, '--out', dump]);
  const { nodes, vertices } = checkFile(lod, dump, deps);
  const { table } = readLod(lod);
  assert.ok(table.hasNormalMaps && !table.hasTexture);
  const mapped = JSON.parse(readFileSync(dump, 'utf8')).patches.filter((p) => p.normal_map_length != null).length;
  assert.equal(mapped, Array.from(table.level).filter((l) => l > 0).length, 'every coarse patch has a normal map');
  t.diagnostic(`${mesh.name}: ${nodes} patches (${mapped} with normal maps), ${vertices} vertices decoded identically`);
});

/** The textured scan of ../shared/data (glTF with a JPEG texture). */
const TEXTURED_GLTF = join(SHARED_MESHES, 'mask_bali_100k_textured_gltf', 'mask-gltf-2.0_separated-valid.gltf');

test('decodes every patch of a textured LOD file exactly as the engine does', async (t) => {
  if (!existsSync(TEXTURED_GLTF)) {
    t.skip(`${TEXTURED_GLTF} is absent`);
    return;
  }
  const deps = await decoderDeps();
  const tmp = mkdtempSync(join(tmpdir(), 'mw-decode-tex-'));
  t.after(() => rmSync(tmp, { recursive: true, force: true }));
  // The default (WebP atlases, which on this scan reach JPEG's error in fewer bytes), JPEG
  // atlases (their tables and headers left out), and WebP atlases beside JPEG normal maps
  // (the JPEG flags then speak of the normal maps alone).
  const variants = [
    { name: 'default', args: [], codec: 'webp' },
    { name: 'jpeg', args: ['--atlas-codec', 'jpeg'], codec: 'jpeg' },
    { name: 'normal-maps', args: ['--normal-maps'], codec: 'webp' },
  ];
  for (const { name, args, codec } of variants) {
    const lod = join(tmp, `${name}.mwlod`);
    const dump = join(tmp, `${name}.json`);
    meshwiki(['lod', 'build', ...args, TEXTURED_GLTF, lod]);
    meshwiki(['lod', 'dump', lod, '--out', dump]);
    const { nodes, vertices } = checkFile(lod, dump, deps, codec);
    const { table } = readLod(lod);
    assert.ok(table.hasTexture, 'the textured scan builds a textured model');
    assert.equal(table.hasNormalMaps, name === 'normal-maps');
    t.diagnostic(`${TEXTURED_GLTF} (${name}): ${nodes} textured patches, ${vertices} vertices decoded identically`);
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

// --- hand-built blobs --------------------------------------------------------------------

/** Appends the zigzag LEB128 varint of an exact integer (decode.js `readVarint` inverted). */
function putVarint(out, v) {
  let z = v >= 0 ? 2 * v : -2 * v - 1;
  do {
    const low = z % 128;
    z = Math.floor(z / 128);
    out.push(z > 0 ? low | 0x80 : low);
  } while (z > 0);
}

const u32le = (v) => [v & 255, (v >>> 8) & 255, (v >>> 16) & 255, (v >>> 24) & 255];

/** A minimal baseline JPEG header: SOI, APP0 (JFIF), SOF0 of `width`×`height`, EOI. */
function fakeJpeg(width, height) {
  const app0 = [0xff, 0xe0, 0, 16, 0x4a, 0x46, 0x49, 0x46, 0, 1, 1, 0, 0, 1, 0, 1, 0, 0];
  const sof0 = [0xff, 0xc0, 0, 17, 8, height >> 8, height & 255, width >> 8, width & 255, 3, 1, 0x22, 0, 2, 0x11, 1, 3, 0x11, 1];
  return Uint8Array.from([0xff, 0xd8, ...app0, 0xff, 0xff, ...sof0, 0xff, 0xd9]);
}

/**
 * A square of two texture charts, as the engine stores it (docs/FORMAT.md "Textures"):
 * vertices 4 and 5 are copies of 1 and 2 (same original id and grid position) with their own
 * texture coordinates, so each triangle has its chart.
 */
const SQUARE = {
  min: [100, 200, 300],
  grid: [
    [0, 0, 0],
    [4, 0, 1],
    [0, 4, 2],
    [4, 4, 3],
    [4, 0, 1],
    [0, 4, 2],
  ],
  ids: [10, 11, 12, 13, 11, 12],
  indices: [0, 1, 2, 4, 3, 5],
  // u16 u, v per vertex; v = 0 is the image's top row.
  uvs: [
    [0, 0],
    [30000, 0],
    [0, 65535],
    [65535, 12345],
    [40000, 1],
    [32768, 65535],
  ],
  colors: [
    [200, 10, 20, 255],
    [10, 200, 20, 255],
    [10, 20, 200, 255],
    [90, 90, 90, 255],
    [10, 200, 20, 255],
    [10, 20, 200, 255],
  ],
};

/**
 * Encodes SQUARE at full precision (shift 0) into a blob: meshoptimizer's encoders for the
 * indices, colours (stored as given: the decoder's YCoCg inversion applies to them) and texture
 * coordinates, the decoder's own traversal for the position and id residuals, zero normal
 * residuals. `texture`: with the image section and the coordinate stream; `compression`: the
 * header byte (the payload is stored uncompressed either way; tests decompress it themselves).
 */
function encodeSquare(encoder, decoder, { texture, image = fakeJpeg(64, 48), normalMap = null, compression = 0, charts = null }) {
  const n = SQUARE.grid.length;
  const t = SQUARE.indices.length / 3;
  const idxS = encoder.encodeIndexBuffer(new Uint8Array(Uint32Array.from(SQUARE.indices).buffer), t * 3, 4);
  // The index codec may rotate triangles: residuals follow the order the decoder sees.
  const decoded = new Uint8Array(t * 12);
  decoder.decodeIndexBuffer(decoded, t * 3, 4, idxS);
  const indices = new Uint32Array(decoded.buffer);
  const pos = SQUARE.grid.flat();
  const posS = [];
  const idsS = [];
  walk(indices, n, (v, kind, a, b, c) => {
    for (let k = 0; k < 3; k++) putVarint(posS, pos[v * 3 + k] - predict(pos, 3, k, kind, a, b, c));
    putVarint(idsS, SQUARE.ids[v] - predict(SQUARE.ids, 1, 0, kind, a, b, c));
  });
  const colS = encoder.encodeVertexBuffer(Uint8Array.from(SQUARE.colors.flat()), n, 4);
  // Every vertex of two triangles is a border vertex: two residuals (0) each.
  const norS = new Uint8Array(2 * n);
  const uvBytes = new Uint8Array(n * 4);
  SQUARE.uvs.forEach(([u, v], i) => uvBytes.set([u & 255, u >> 8, v & 255, v >> 8], i * 4));
  let uvS = texture ? encoder.encodeVertexBuffer(uvBytes, n, 4) : new Uint8Array(0);
  if (charts) {
    // Texture coordinates by chart (payload flag bit 4): a u32 count, then eight f32 a chart.
    const maps = new Uint8Array(new Float32Array(charts.flat()).buffer);
    uvS = Uint8Array.from([...u32le(charts.length), ...maps]);
  }
  const streams = [idxS, Uint8Array.from(posS), Uint8Array.from(idsS), colS, norS, uvS];
  const flags = 1 | 2 | (texture || charts ? 4 : 0) | (charts ? 16 : 0);
  const header = [...u32le(n), ...u32le(t), ...u32le(flags), ...u32le(0), ...SQUARE.min.flatMap(u32le), ...streams.flatMap((s) => u32le(s.length))];
  assert.equal(header.length, 52);
  const payload = Uint8Array.from([...header, ...streams.flatMap((s) => Array.from(s))]);
  const blobFlags = (texture && image ? 1 : 0) | (normalMap ? 2 : 0);
  const head = [0x4d, 0x57, 0x50, 0x32, compression, blobFlags, 0, 0, ...u32le(payload.length)];
  const section = texture && image ? [...u32le(image.length), ...image] : [];
  const nmSection = normalMap ? [...u32le(normalMap.length), ...normalMap] : [];
  return { blob: Uint8Array.from([...head, ...section, ...nmSection, ...payload]), payload, image };
}

async function encoderDeps() {
  const { MeshoptEncoder } = await importStatic('meshoptimizer/encoder');
  await MeshoptEncoder.ready;
  return MeshoptEncoder;
}

/** Everything of a decoded patch but its texture. */
function geometry(p) {
  const { uvs: _uvs, image: _image, normalMap: _normalMap, ...rest } = p;
  return Object.fromEntries(Object.entries(rest).map(([k, v]) => [k, ArrayBuffer.isView(v) ? Array.from(v) : v]));
}

test('textured blobs: image section, texture coordinates and wedge vertices (hand-built)', async () => {
  const deps = await decoderDeps();
  const encoder = await encoderDeps();
  const grid = { origin: [0.5, -1, 2], step: 0.25 };
  const { blob, payload, image } = encodeSquare(encoder, deps.meshopt, { texture: true });
  const p = decodePatch(blob, grid, deps);
  assert.equal(p.vertexCount, 6);
  assert.equal(p.triangleCount, 2);
  assert.deepEqual(Array.from(p.ids), SQUARE.ids);
  assert.deepEqual(Array.from(p.gridPositions), SQUARE.grid.flatMap((g) => g.map((x, k) => x + SQUARE.min[k])));
  // Wedge copies: the same point, their own texture coordinates.
  assert.deepEqual(Array.from(p.positions.subarray(12, 18)), Array.from(p.positions.subarray(3, 9)));
  assert.ok(p.uvs instanceof Float32Array);
  assert.deepEqual(Array.from(p.uvs), SQUARE.uvs.flat().map((q) => Math.fround(q / 65535)));
  assert.equal(p.uvs[5], 1, 'v = 65535 is the bottom row');
  assert.ok(p.image instanceof Uint8Array);
  assert.deepEqual(Array.from(p.image), Array.from(image));
  // A copy with its own buffer (the worker transfers it without moving the blob).
  assert.equal(p.image.buffer.byteLength, image.length);
  assert.deepEqual(jpegSize(p.image), { width: 64, height: 48 });
  const colors = Uint8Array.from(SQUARE.colors.flat());
  decodeYCoCg(colors);
  assert.deepEqual(Array.from(p.colors), Array.from(colors), 'the colour stream still decodes in place');
  assert.equal(p.normals.length, 18);

  // zstd: what is decompressed starts after the image section.
  const zstd = encodeSquare(encoder, deps.meshopt, { texture: true, compression: 1 });
  let given = null;
  const fake = {
    ...deps,
    decompress: (data, out) => {
      given = data;
      out.set(zstd.payload);
      return out;
    },
  };
  const pz = decodePatch(zstd.blob, grid, fake);
  assert.deepEqual(Array.from(given), Array.from(payload));
  assert.deepEqual(Array.from(pz.uvs), Array.from(p.uvs));
  assert.deepEqual(Array.from(pz.image), Array.from(image));

  // Without texture (the layout from before textures): the same geometry, neither uvs nor image.
  const plain = decodePatch(encodeSquare(encoder, deps.meshopt, { texture: false }).blob, grid, deps);
  assert.equal(plain.uvs, null);
  assert.equal(plain.image, null);
  assert.deepEqual(geometry(plain), geometry(p));
  // An image section without texture coordinates decodes; the viewer then draws vertex colours.
  const empty = decodePatch(encodeSquare(encoder, deps.meshopt, { texture: true, image: new Uint8Array(0) }).blob, grid, deps);
  assert.equal(empty.image.length, 0);

  // A normal-map section after the image section, or alone (an untextured scan's coarse
  // patch): the same geometry and coordinates.
  const normalMap = fakeJpeg(32, 16);
  const both = decodePatch(encodeSquare(encoder, deps.meshopt, { texture: true, normalMap }).blob, grid, deps);
  assert.deepEqual(Array.from(both.image), Array.from(image));
  assert.deepEqual(Array.from(both.normalMap), Array.from(normalMap));
  assert.equal(both.normalMap.buffer.byteLength, normalMap.length);
  assert.deepEqual(jpegSize(both.normalMap), { width: 32, height: 16 });
  assert.deepEqual(Array.from(both.uvs), Array.from(p.uvs));
  const alone = decodePatch(encodeSquare(encoder, deps.meshopt, { texture: true, image: null, normalMap }).blob, grid, deps);
  assert.equal(alone.image, null);
  assert.deepEqual(Array.from(alone.normalMap), Array.from(normalMap));
  assert.deepEqual(geometry(alone), geometry(both));
  assert.equal(p.normalMap, null);
  // Sections stored without their Huffman tables (blob flag bit 2) get the standard ones back,
  // right before the scan header, in both images.
  const sof = [0xff, 0xc0, 0, 11, 8, 0, 16, 0, 32, 1, 1, 0x11, 0];
  const sos = [0xff, 0xda, 0, 8, 1, 1, 0, 0, 63, 0, 0x12, 0x34, 0xff, 0xd9];
  const stripped = Uint8Array.from([0xff, 0xd8, ...sof, ...sos]);
  const restored = Uint8Array.from([0xff, 0xd8, ...sof, ...STANDARD_DHT, ...sos]);
  const tablesOff = encodeSquare(encoder, deps.meshopt, { texture: true, image: stripped, normalMap: stripped }).blob;
  tablesOff[5] |= 4;
  const whole = decodePatch(tablesOff, grid, deps);
  assert.deepEqual(Array.from(whole.image), Array.from(restored));
  assert.deepEqual(Array.from(whole.normalMap), Array.from(restored));
  assert.deepEqual(jpegSize(whole.image), { width: 32, height: 16 });
  // Also without their JFIF segment and quantisation tables (bit 3): the quality byte first;
  // the segment after SOI and the scaled Annex K.1 tables after the frame header come back.
  const headless = encodeSquare(encoder, deps.meshopt, { texture: true, image: Uint8Array.from([87, ...stripped]), normalMap: Uint8Array.from([30, ...stripped]) }).blob;
  headless[5] |= 4 | 8;
  const headed = decodePatch(headless, grid, deps);
  const withHeaders = (q) => [0xff, 0xd8, ...JFIF_APP0, ...sof, ...standardDqt(q), ...STANDARD_DHT, ...sos];
  assert.deepEqual(Array.from(headed.image), withHeaders(87));
  assert.deepEqual(Array.from(headed.normalMap), withHeaders(30));
  assert.deepEqual(jpegSize(headed.image), { width: 32, height: 16 });
  // Quality 50 is Annex K.1 itself (its first luminance and chrominance values), 100 all ones.
  assert.deepEqual(Array.from(standardDqt(50).subarray(5, 9)), [16, 11, 12, 14]);
  assert.deepEqual(Array.from(standardDqt(50).subarray(69 + 5, 69 + 9)), [17, 18, 18, 24]);
  assert.ok(standardDqt(100).every((v, i) => i % 69 < 5 || v === 1));
  // A quality byte out of range: the bytes after it as they are.
  const noQuality = encodeSquare(encoder, deps.meshopt, { texture: true, image: Uint8Array.from([0, ...stripped]) }).blob;
  noQuality[5] |= 8;
  assert.deepEqual(Array.from(decodePatch(noQuality, grid, deps).image), Array.from(stripped));
  // Annex K.3: the DC luminance table's code length counts.
  assert.deepEqual(Array.from(STANDARD_DHT.subarray(5, 21)), [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0]);
  // A normal map declared longer than the blob.
  const bad = encodeSquare(encoder, deps.meshopt, { texture: true, image: null, normalMap }).blob;
  bad.set(u32le(bad.length), 12);
  assert.throws(() => decodePatch(bad, grid, deps), DecodeError);
});

test('textured blobs that do not decode are errors (hand-built)', async () => {
  const deps = await decoderDeps();
  const encoder = await encoderDeps();
  const grid = { origin: [0, 0, 0], step: 1 };
  const { blob } = encodeSquare(encoder, deps.meshopt, { texture: true });
  for (let cut = 0; cut < blob.length; cut++) {
    assert.throws(() => decodePatch(blob.subarray(0, cut), grid, deps), DecodeError, `truncated at ${cut}`);
  }
  // An image length past the end of the blob.
  for (const len of [blob.length, blob.length - 15, 0xffffffff]) {
    const bad = blob.slice();
    bad.set(u32le(len), 12);
    assert.throws(() => decodePatch(bad, grid, deps), (e) => e instanceof DecodeError && e.message === 'blob truncated', `image length ${len}`);
  }
  // The image flag on a blob without image section: the payload's first bytes read as length.
  const plain = encodeSquare(encoder, deps.meshopt, { texture: false }).blob.slice();
  plain[5] = 1;
  assert.throws(() => decodePatch(plain, grid, deps), DecodeError);
  // Texture coordinates flagged, their stream missing.
  const n = SQUARE.grid.length;
  const noUvs = encodeSquare(encoder, deps.meshopt, { texture: false }).blob.slice();
  noUvs[12 + 8] |= 4;
  assert.throws(() => decodePatch(noUvs, grid, deps), (e) => e instanceof DecodeError && /uvs/.test(e.message), `${n} vertices, no stream`);
});

test('texture coordinates by chart: one affine map per chart, bit for bit (hand-built)', async () => {
  const deps = await decoderDeps();
  const encoder = await encoderDeps();
  const grid = { origin: [0, 0, 0], step: 1 };
  // The square's two triangles share no vertex (4 and 5 are copies of 1 and 2): two charts,
  // numbered by their first triangle. Maps with coefficients that do not round evenly.
  const charts = [
    [0.1, 0.0, 0.0, 0.25, 0.0, 0.2, 0.01, 0.1],
    [-0.03, 0.07, 0.3, 0.6, 0.011, -0.05, 0.2, 0.5],
  ];
  const { blob, payload } = encodeSquare(encoder, deps.meshopt, { texture: true, charts });
  const p = decodePatch(blob, grid, deps);
  const f = Float32Array.from(charts.flat());
  // Chart of each vertex: its triangle's place in the decoded index buffer.
  const chartOf = new Int32Array(p.vertexCount).fill(-1);
  for (let i = 0; i < p.indices.length; i++) chartOf[p.indices[i]] = Math.floor(i / 3);
  for (let v = 0; v < p.vertexCount; v++) {
    const [x, y, z] = [0, 1, 2].map((k) => p.gridPositions[v * 3 + k] - SQUARE.min[k]);
    const c = chartOf[v];
    for (let k = 0; k < 2; k++) {
      const m = c * 8 + k * 4;
      const want = Math.fround(((f[m] * x + f[m + 1] * y) + f[m + 2] * z) + f[m + 3]);
      assert.equal(p.uvs[v * 2 + k], want, `vertex ${v} coordinate ${k}`);
    }
  }
  // Everything else decodes as with coordinates per vertex.
  assert.deepEqual(geometry(p), geometry(decodePatch(encodeSquare(encoder, deps.meshopt, { texture: true }).blob, grid, deps)));
  // A chart count that is not the triangles' is an error.
  for (const bad of [charts.slice(0, 1), [...charts, charts[0]]]) {
    const b = encodeSquare(encoder, deps.meshopt, { texture: true, charts: bad }).blob;
    assert.throws(() => decodePatch(b, grid, deps), (e) => e instanceof DecodeError && /uvs/.test(e.message), `${bad.length} charts`);
  }
  // The chart flag without the texture coordinates flag is an error.
  const noUvFlag = blob.slice();
  noUvFlag[blob.length - payload.length + 8] &= ~4;
  assert.throws(() => decodePatch(noUvFlag, grid, deps), DecodeError);
});

test('WebP sizes come from the first chunk', () => {
  // Lossy: frame tag (3 bytes), start code, then 14-bit width and height (2 bits of scale).
  const riff = (chunk, body) => {
    const size = 4 + 8 + body.length;
    return Uint8Array.from([...'RIFF'].map((c) => c.charCodeAt(0)).concat([size & 255, size >> 8, 0, 0], [...`WEBP${chunk}`].map((c) => c.charCodeAt(0)), [body.length & 255, body.length >> 8, 0, 0], body));
  };
  const lossy = riff('VP8 ', [0x30, 0x01, 0x00, 0x9d, 0x01, 0x2a, 0x00, 0x10 | 0x40, 0x00, 0x08, 0, 0]);
  assert.equal(isWebp(lossy), true);
  assert.deepEqual(webpSize(lossy), { width: 4096, height: 2048 });
  assert.deepEqual(imageSize(lossy), { width: 4096, height: 2048 });
  // A broken start code, a truncated file, and a JPEG are no WebP sizes.
  const broken = lossy.slice();
  broken[24] = 0;
  assert.equal(webpSize(broken), null);
  assert.equal(webpSize(lossy.subarray(0, 28)), null);
  assert.equal(webpSize(fakeJpeg(64, 48)), null);
  assert.deepEqual(imageSize(fakeJpeg(64, 48)), { width: 64, height: 48 });
  // Lossless: signature 0x2f, then 14-bit width − 1 and height − 1.
  const w = 300 - 1;
  const h = 200 - 1;
  const bits = w | (h << 14);
  const lossless = riff('VP8L', [0x2f, bits & 255, (bits >> 8) & 255, (bits >> 16) & 255, (bits >>> 24) & 255, 0, 0, 0, 0, 0]);
  assert.deepEqual(webpSize(lossless), { width: 300, height: 200 });
  // Extended: flags (4 bytes), then 24-bit canvas width − 1 and height − 1.
  const extended = riff('VP8X', [0, 0, 0, 0, 0x3f, 0x01, 0x00, 0xef, 0x00, 0x00]);
  assert.deepEqual(webpSize(extended), { width: 320, height: 240 });
});

test('JPEG sizes come from the frame header', () => {
  assert.deepEqual(jpegSize(fakeJpeg(4096, 2048)), { width: 4096, height: 2048 });
  assert.deepEqual(jpegSize(fakeJpeg(1, 1)), { width: 1, height: 1 });
  assert.equal(jpegSize(new Uint8Array(0)), null);
  assert.equal(jpegSize(Uint8Array.from([0x89, 0x50, 0x4e, 0x47])), null);
  assert.equal(jpegSize(fakeJpeg(64, 48).subarray(0, 24)), null);
  const real = join(SHARED_MESHES, 'mask_bali_100k_textured_gltf', 'Image_0.jpg');
  if (existsSync(real)) assert.deepEqual(jpegSize(new Uint8Array(readFileSync(real))), { width: 4096, height: 4096 });
});

test('a textured patch counts its texture (width × height × 4) in the GPU budget', () => {
  const n = 6;
  const patch = {
    vertexCount: n,
    positions: new Float32Array(n * 3),
    normals: new Float32Array(n * 3),
    colors: new Uint8Array(n * 4),
    ids: new Uint32Array(n),
    indices: new Uint16Array(6),
    uvs: null,
    image: null,
    imageWidth: 0,
    imageHeight: 0,
  };
  const plain = patchBytes(patch);
  assert.equal(plain, 72 + 72 + 24 + 12 + 24 + 12);
  const textured = { ...patch, uvs: new Float32Array(n * 2), image: fakeJpeg(64, 48), imageWidth: 64, imageHeight: 48 };
  assert.equal(patchBytes(textured), plain + n * 8 + 64 * 48 * 4);
});

test('the model header flag bit 2 reads as hasTexture', () => {
  for (const flags of [0, 3, 4, 7]) {
    const bytes = new Uint8Array(256);
    bytes.set([0x4d, 0x57, 0x4c, 0x4f, 0x44, 0x00, 0x0d, 0x0a]);
    const view = new DataView(bytes.buffer);
    view.setUint32(8, 1, true);
    view.setUint32(12, flags, true);
    // Empty tables right after the header; their CRC-32 is that of no bytes.
    for (const at of [112, 120, 128, 136]) view.setUint32(at, 256, true);
    for (const at of [152, 156, 160]) view.setUint32(at, crc32(new Uint8Array(0)), true);
    view.setUint32(252, crc32(bytes.subarray(0, 252)), true);
    const t = parseBinary(bytes.buffer);
    assert.equal(t.hasTexture, (flags & 4) !== 0, `flags ${flags}`);
    assert.equal(t.hasColors, (flags & 1) !== 0);
    assert.equal(t.hasNormals, (flags & 2) !== 0);
  }
});
