// Patch blob decoder: docs/FORMAT.md "Patch blob", the browser twin of
// engine/src/lod/codec.rs (the reference). Pure: the meshoptimizer decoder and a zstd
// decompressor are passed in, so the same module runs in the viewer's worker and in Node tests.
//
// Arithmetic: positions, ids and their residuals exceed 2^31, so everything is done on
// doubles holding exact integers (|v| < 2^53); no 32-bit bitwise operator touches them.
// Normals: every vertex gets the area-weighted normal of the integer grid positions (f64,
// exact); border vertices add a stored octahedral residual (8 bits) to that prediction.
// Layouts: `MWP3` blobs (what builds write) have front-coded connectivity and range-coded
// positions, ids, colours and normals, predicted by multi-way parallelograms
// (./rangecoder.js); `MWP2` blobs (older files) meshoptimizer's index and vertex codecs and
// varint residuals.
// Textures (docs/FORMAT.md "Patch blob", "Textures"): a textured blob carries its atlas (a
// JPEG) in an image section before the payload, and the payload a sixth stream of u16 texture
// coordinates; vertices where the atlas' charts meet come once per chart (same original id,
// same grid position), which changes nothing else here.

import { Channel, RangeDecoder, decodeConnectivity, parallelograms, COPY, MIDPOINT, PARALLELOGRAM } from './rangecoder.js';

const MAGIC = [0x4d, 0x57, 0x50]; // "MWP", then '2' or '3' (the layout version)
const POSITION_CHANNELS = 16;
const ID_CHANNELS = 2;
const NORMAL_CHANNELS = 2;
const COLOUR_CHANNELS = 4;
const COMPRESSION_NONE = 0;
const COMPRESSION_ZSTD = 1;
const FLAG_COLORS = 1;
const FLAG_NORMALS = 2;
const FLAG_UVS = 4;
/** `MWP3` payload flag: ids listed in the Morton order of the decoded grid points. */
const FLAG_SORTED_IDS = 8;
/** Payload flag (with `FLAG_UVS`): texture coordinates as one affine map per atlas chart. */
const FLAG_CHART_UVS = 16;
/** Payload flag (with `FLAG_NORMALS`): one stored normal per original id (copies share it). */
const FLAG_NORMALS_BY_ID = 32;
const KNOWN_FLAGS = FLAG_COLORS | FLAG_NORMALS | FLAG_UVS | FLAG_SORTED_IDS | FLAG_CHART_UVS | FLAG_NORMALS_BY_ID;
/** Blob header flag (byte 5): an image section (u32 length, then the JPEG) follows byte 12. */
const BLOB_IMAGE = 1;
/** Blob header flag (byte 5): a normal-map section (u32 length, then the JPEG) follows. */
const BLOB_NORMALS = 2;
/** Blob header flag (byte 5): the sections' JPEGs omit their (standard) Huffman tables. */
const BLOB_STANDARD_HUFFMAN = 4;
/**
 * Blob header flag (byte 5), with BLOB_STANDARD_HUFFMAN: the sections' JPEGs also omit their JFIF
 * APP0 segment and their (standard, scaled) quantisation tables; each starts with its quality.
 */
const BLOB_STANDARD_HEADERS = 8;
/**
 * Blob header flag (byte 5), with BLOB_IMAGE: the image section is a WebP, stored whole; the
 * JPEG flags then speak of the normal-map section alone.
 */
const BLOB_IMAGE_WEBP = 16;

/**
 * The standard Huffman tables of ITU-T T.81 Annex K.3 as four DHT segments (DC and AC
 * luminance, DC and AC chrominance), exactly as the engine's encoder writes them
 * (engine/src/lod/jpegtables.rs `STANDARD_DHT`, docs/FORMAT.md "Patch blob").
 */
export const STANDARD_DHT = Uint8Array.from(
  ('ffc4001f0000010501010101010100000000000000000102030405060708090a0bffc400b51000020103030204030505' +
  '04040000017d01020300041105122131410613516107227114328191a1082342b1c11552d1f02433627282090a161718' +
  '191a25262728292a3435363738393a434445464748494a535455565758595a636465666768696a737475767778797a83' +
  '8485868788898a92939495969798999aa2a3a4a5a6a7a8a9aab2b3b4b5b6b7b8b9bac2c3c4c5c6c7c8c9cad2d3d4d5d6' +
  'd7d8d9dae1e2e3e4e5e6e7e8e9eaf1f2f3f4f5f6f7f8f9faffc4001f0100030101010101010101010000000000000102' +
  '030405060708090a0bffc400b51100020102040403040705040400010277000102031104052131061241510761711322' +
  '328108144291a1b1c109233352f0156272d10a162434e125f11718191a262728292a35363738393a434445464748494a' +
  '535455565758595a636465666768696a737475767778797a82838485868788898a92939495969798999aa2a3a4a5a6a7' +
  'a8a9aab2b3b4b5b6b7b8b9bac2c3c4c5c6c7c8c9cad2d3d4d5d6d7d8d9dae2e3e4e5e6e7e8e9eaf2f3f4f5f6f7f8f9fa').match(/../g).map((b) => parseInt(b, 16)),
);

/** The JFIF APP0 segment the engine's encoder writes (engine/src/lod/jpegtables.rs `JFIF_APP0`). */
export const JFIF_APP0 = Uint8Array.from([
  0xff, 0xe0, 0x00, 0x10, 0x4a, 0x46, 0x49, 0x46, 0x00, 0x01, 0x02, 0x00, 0x00, 0x01, 0x00, 0x01, 0x00, 0x00,
]);

/** ITU-T T.81 Annex K.1's quantisation tables (luminance, chrominance) in a DQT's zigzag order. */
const ANNEX_K1 = [
  [16, 11, 12, 14, 12, 10, 16, 14, 13, 14, 18, 17, 16, 19, 24, 40, 26, 24, 22, 22, 24, 49,
    35, 37, 29, 40, 58, 51, 61, 60, 57, 51, 56, 55, 64, 72, 92, 78, 64, 68, 87, 69, 55, 56,
    80, 109, 81, 87, 95, 98, 103, 104, 103, 62, 77, 113, 121, 112, 100, 120, 92, 101, 103, 99],
  [17, 18, 18, 24, 21, 24, 47, 26, 26, 47, 99, 66, 56, 66, ...new Array(50).fill(99)],
];

/**
 * The two DQT segments the engine's encoder writes at `quality` (1–100): Annex K.1 scaled as
 * the IJG library does (engine/src/lod/jpegtables.rs `standard_dqt`, docs/FORMAT.md).
 */
export function standardDqt(quality) {
  const q = Math.min(100, Math.max(1, quality));
  const scale = q < 50 ? Math.floor(5000 / q) : 200 - 2 * q;
  const out = new Uint8Array(2 * 69);
  ANNEX_K1.forEach((table, t) => {
    out.set([0xff, 0xdb, 0x00, 0x43, t], t * 69);
    table.forEach((b, i) => {
      out[t * 69 + 5 + i] = Math.min(255, Math.max(1, Math.floor((b * scale + 50) / 100)));
    });
  });
  return out;
}

/**
 * A JPEG stored without its JFIF segment and quantisation tables made whole: its first byte is
 * the quality; SOI, JFIF_APP0, the frame header, standardDqt(quality), then the rest (the bytes
 * after the quality as they are where that does not fit: the image decoder then refuses them).
 */
export function withStandardHeaders(stored) {
  const rest = stored.subarray(1);
  const quality = stored[0];
  if (!(quality >= 1 && quality <= 100) || rest.length < 6
    || rest[0] !== 0xff || rest[1] !== 0xd8 || rest[2] !== 0xff || rest[3] !== 0xc0) {
    return rest.slice();
  }
  const sofEnd = 4 + ((rest[4] << 8) | rest[5]);
  if (sofEnd > rest.length) return rest.slice();
  const dqt = standardDqt(quality);
  const out = new Uint8Array(rest.length + JFIF_APP0.length + dqt.length);
  out.set(rest.subarray(0, 2));
  out.set(JFIF_APP0, 2);
  out.set(rest.subarray(2, sofEnd), 2 + JFIF_APP0.length);
  out.set(dqt, sofEnd + JFIF_APP0.length);
  out.set(rest.subarray(sofEnd), sofEnd + JFIF_APP0.length + dqt.length);
  return out;
}

/**
 * A JPEG stored without its Huffman tables made whole: STANDARD_DHT right before its first
 * SOS marker (the bytes as they are where no SOS is found: the image decoder then refuses
 * them as it would have).
 */
export function withStandardHuffman(jpeg) {
  if (jpeg.length < 2 || jpeg[0] !== 0xff || jpeg[1] !== 0xd8) return jpeg;
  let at = 2;
  while (at + 4 <= jpeg.length && jpeg[at] === 0xff) {
    if (jpeg[at + 1] === 0xda) {
      const out = new Uint8Array(jpeg.length + STANDARD_DHT.length);
      out.set(jpeg.subarray(0, at));
      out.set(STANDARD_DHT, at);
      out.set(jpeg.subarray(at), at + STANDARD_DHT.length);
      return out;
    }
    at += 2 + ((jpeg[at + 2] << 8) | jpeg[at + 3]);
  }
  return jpeg;
}
const STREAMS = 6;
const UV_SCALE = 65535;
const PAYLOAD_HEADER = 52;
const MAX_ELEMENTS = 1 << 20;
const MAX_SHIFT = 24;
const MAX_PAYLOAD = 64 << 20;
const U32_MAX = 4294967295;

/** A blob that does not decode. */
export class DecodeError extends Error {
  constructor(message) {
    super(message);
    this.name = 'DecodeError';
  }
}

function u32(bytes, at) {
  if (at + 4 > bytes.length) throw new DecodeError('blob truncated');
  return (bytes[at] | (bytes[at + 1] << 8) | (bytes[at + 2] << 16)) + bytes[at + 3] * 16777216;
}

/** Reads a zigzag LEB128 varint as an exact integer. `cursor.at` advances. */
export function readVarint(bytes, cursor) {
  let z = 0;
  let scale = 1;
  for (let i = 0; i < 10; i++) {
    if (cursor.at >= bytes.length) throw new DecodeError('varint stream truncated');
    const byte = bytes[cursor.at++];
    z += (byte & 0x7f) * scale;
    if ((byte & 0x80) === 0) {
      if (z > Number.MAX_SAFE_INTEGER) throw new DecodeError('varint out of range');
      return z % 2 === 1 ? -(z + 1) / 2 : z / 2;
    }
    scale *= 128;
  }
  throw new DecodeError('varint too long');
}

/** Vertices on an edge used by exactly one triangle. */
export function borderVertices(indices, vertexCount) {
  const count = new Map();
  for (let i = 0; i + 2 < indices.length; i += 3) {
    for (let k = 0; k < 3; k++) {
      const a = indices[i + k];
      const b = indices[i + ((k + 1) % 3)];
      const key = a < b ? a * vertexCount + b : b * vertexCount + a;
      count.set(key, (count.get(key) || 0) + 1);
    }
  }
  const border = new Uint8Array(vertexCount);
  for (const [key, c] of count) {
    if (c !== 1) continue;
    const a = Math.floor(key / vertexCount);
    const b = key - a * vertexCount;
    border[a] = 1;
    border[b] = 1;
  }
  return border;
}

const floorShift = (v, s) => Math.floor(v / 2 ** s);

/**
 * Walks the triangles in order and calls `visit(v, kind, a, b, c)` for each vertex the first
 * time a triangle uses it: kind 0 = parallelogram a + b - c, 1 = midpoint of a and b,
 * 2 = copy of a, 3 = zero (the very first vertex). Mirrors `Predictor::walk`.
 */
export function walk(indices, n, visit) {
  const known = new Uint8Array(n);
  const opposite = new Map();
  let last = -1;
  let visited = 0;
  for (let i = 0; i + 2 < indices.length; i += 3) {
    for (let k = 0; k < 3; k++) {
      const v = indices[i + k];
      if (known[v]) continue;
      const a = indices[i + ((k + 1) % 3)];
      const b = indices[i + ((k + 2) % 3)];
      const ka = known[a];
      const kb = known[b];
      if (ka && kb) {
        const c = opposite.get(a < b ? a * n + b : b * n + a);
        if (c !== undefined) visit(v, 0, a, b, c);
        else visit(v, 1, a, b, 0);
      } else if (ka) {
        visit(v, 2, a, 0, 0);
      } else if (kb) {
        visit(v, 2, b, 0, 0);
      } else if (last >= 0) {
        visit(v, 2, last, 0, 0);
      } else {
        visit(v, 3, 0, 0, 0);
      }
      known[v] = 1;
      last = v;
      visited++;
    }
    for (let k = 0; k < 3; k++) {
      const a = indices[i + k];
      const b = indices[i + ((k + 1) % 3)];
      const key = a < b ? a * n + b : b * n + a;
      if (!opposite.has(key)) opposite.set(key, indices[i + ((k + 2) % 3)]);
    }
  }
  return visited;
}

/** The prediction of `walk`'s `kind` for component `k` of `values` (`stride` per vertex). */
export function predict(values, stride, k, kind, a, b, c) {
  switch (kind) {
    case 0:
      return values[a * stride + k] + values[b * stride + k] - values[c * stride + k];
    case 1:
      return Math.floor((values[a * stride + k] + values[b * stride + k]) / 2);
    case 2:
      return values[a * stride + k];
    default:
      return 0;
  }
}

const f = Math.fround;

/**
 * Area-weighted unit vertex normals of a triangle set (+Z for isolated vertices), in f32
 * arithmetic step by step like the reference, so degenerate fans give the same result.
 */
export function computedNormals(positions, indices, vertexCount) {
  const acc = new Float32Array(vertexCount * 3);
  for (let i = 0; i + 2 < indices.length; i += 3) {
    const ia = indices[i] * 3;
    const ib = indices[i + 1] * 3;
    const ic = indices[i + 2] * 3;
    const ux = f(positions[ib] - positions[ia]);
    const uy = f(positions[ib + 1] - positions[ia + 1]);
    const uz = f(positions[ib + 2] - positions[ia + 2]);
    const wx = f(positions[ic] - positions[ia]);
    const wy = f(positions[ic + 1] - positions[ia + 1]);
    const wz = f(positions[ic + 2] - positions[ia + 2]);
    const nx = f(f(uy * wz) - f(uz * wy));
    const ny = f(f(uz * wx) - f(ux * wz));
    const nz = f(f(ux * wy) - f(uy * wx));
    for (const o of [ia, ib, ic]) {
      acc[o] += nx;
      acc[o + 1] += ny;
      acc[o + 2] += nz;
    }
  }
  for (let o = 0; o < acc.length; o += 3) {
    const len = f(Math.sqrt(f(f(f(acc[o] * acc[o]) + f(acc[o + 1] * acc[o + 1])) + f(acc[o + 2] * acc[o + 2]))));
    if (len > 0) {
      acc[o] /= len;
      acc[o + 1] /= len;
      acc[o + 2] /= len;
    } else {
      acc[o] = 0;
      acc[o + 1] = 0;
      acc[o + 2] = 1;
    }
  }
  return acc;
}

const OCT_SCALE = 127;

/**
 * Area-weighted vertex normals from the integer grid coordinates, in f64 (exact products,
 * triangle-order sums: bit-identical to the reference `grid_normals`).
 */
export function gridNormals(pos, indices, n) {
  const acc = new Float64Array(n * 3);
  for (let i = 0; i + 2 < indices.length; i += 3) {
    const a = indices[i] * 3;
    const b = indices[i + 1] * 3;
    const c = indices[i + 2] * 3;
    const ux = pos[b] - pos[a];
    const uy = pos[b + 1] - pos[a + 1];
    const uz = pos[b + 2] - pos[a + 2];
    const wx = pos[c] - pos[a];
    const wy = pos[c + 1] - pos[a + 1];
    const wz = pos[c + 2] - pos[a + 2];
    const nx = uy * wz - uz * wy;
    const ny = uz * wx - ux * wz;
    const nz = ux * wy - uy * wx;
    for (const o of [a, b, c]) {
      acc[o] += nx;
      acc[o + 1] += ny;
      acc[o + 2] += nz;
    }
  }
  for (let o = 0; o < acc.length; o += 3) {
    const len = Math.sqrt(acc[o] * acc[o] + acc[o + 1] * acc[o + 1] + acc[o + 2] * acc[o + 2]);
    if (len > 0) {
      acc[o] /= len;
      acc[o + 1] /= len;
      acc[o + 2] /= len;
    } else {
      acc[o] = 0;
      acc[o + 1] = 0;
      acc[o + 2] = 1;
    }
  }
  return acc;
}

/** Octahedral coordinates of a unit vector (8 bits, `floor(x + 0.5)` rounding) into `out`. */
export function octEncode(nx, ny, nz, out) {
  const l1 = Math.abs(nx) + Math.abs(ny) + Math.abs(nz);
  if (!(l1 > 0)) {
    out[0] = 0;
    out[1] = 0;
    return out;
  }
  let x = nx / l1;
  let y = ny / l1;
  if (nz < 0) {
    const ax = Math.abs(x);
    const ay = Math.abs(y);
    x = (1 - ay) * (x >= 0 ? 1 : -1);
    y = (1 - ax) * (y >= 0 ? 1 : -1);
  }
  out[0] = Math.floor(x * OCT_SCALE + 0.5);
  out[1] = Math.floor(y * OCT_SCALE + 0.5);
  return out;
}

/** Unit vector of octahedral coordinates, written as f32 at `out[at..at + 3]`. */
export function octDecode(qx, qy, out, at) {
  let x = Math.min(Math.max(qx, -127), 127) / OCT_SCALE;
  let y = Math.min(Math.max(qy, -127), 127) / OCT_SCALE;
  const z = 1 - Math.abs(x) - Math.abs(y);
  if (z < 0) {
    const nx = (1 - Math.abs(y)) * (x >= 0 ? 1 : -1);
    const ny = (1 - Math.abs(x)) * (y >= 0 ? 1 : -1);
    x = nx;
    y = ny;
  }
  const len = Math.sqrt(x * x + y * y + z * z);
  out[at] = x / len;
  out[at + 1] = y / len;
  out[at + 2] = z / len;
}

/**
 * Inverts meshoptimizer's colour filter in place (YCoCg, scale in alpha's high bit) with exact
 * integer rounding, byte for byte as the engine's `decode_ycocg` (meshoptimizer's own SIMD
 * decoder rounds through an approximate reciprocal, so it differs by one across platforms).
 * @param {Uint8Array} c RGBA8 values, 4 per vertex
 */
export function decodeYCoCg(c) {
  for (let i = 0; i < c.length; i += 4) {
    const aRaw = c[i + 3];
    let scale = aRaw;
    scale |= scale >> 1;
    scale |= scale >> 2;
    scale |= scale >> 4;
    const y = c[i];
    const co = (c[i + 1] << 24) >> 24;
    const cg = (c[i + 2] << 24) >> 24;
    const a = ((aRaw << 1) & scale) | (aRaw & 1);
    const expand = (v) =>
      scale === 0 || v <= 0 ? 0 : Math.min(255, Math.floor((2 * v * 255 + scale) / (2 * scale)));
    c[i] = expand(y + co - cg);
    c[i + 1] = expand(y + cg);
    c[i + 2] = expand(y - co - cg);
    c[i + 3] = expand(a);
  }
}

/**
 * Whether `bytes` is a WebP file (a RIFF container of form `WEBP`).
 * @param {Uint8Array} bytes
 */
export function isWebp(bytes) {
  return !!bytes && bytes.length >= 12 && ascii(bytes, 0, 4) === 'RIFF' && ascii(bytes, 8, 12) === 'WEBP';
}

function ascii(bytes, from, to) {
  return String.fromCharCode(...bytes.subarray(from, to));
}

/**
 * Width and height of an atlas image (JPEG or WebP) from its header, without decoding it;
 * null when it is neither or its header holds no size.
 * @param {Uint8Array} bytes
 * @returns {{width: number, height: number}|null}
 */
export function imageSize(bytes) {
  return isWebp(bytes) ? webpSize(bytes) : jpegSize(bytes);
}

/**
 * Width and height of a WebP image from its first chunk: a lossy `VP8 ` frame header (14-bit
 * sizes after the start code), a lossless `VP8L` header (14-bit sizes less one) or an extended
 * `VP8X` header (24-bit canvas sizes less one); null otherwise.
 * @param {Uint8Array} bytes
 * @returns {{width: number, height: number}|null}
 */
export function webpSize(bytes) {
  if (!isWebp(bytes) || bytes.length < 30) return null;
  const chunk = ascii(bytes, 12, 16);
  let width = 0;
  let height = 0;
  if (chunk === 'VP8 ') {
    if (bytes[23] !== 0x9d || bytes[24] !== 0x01 || bytes[25] !== 0x2a) return null;
    width = (bytes[26] | (bytes[27] << 8)) & 0x3fff;
    height = (bytes[28] | (bytes[29] << 8)) & 0x3fff;
  } else if (chunk === 'VP8L') {
    if (bytes[20] !== 0x2f) return null;
    const bits = bytes[21] | (bytes[22] << 8) | (bytes[23] << 16) | (bytes[24] << 24);
    width = (bits & 0x3fff) + 1;
    height = ((bits >>> 14) & 0x3fff) + 1;
  } else if (chunk === 'VP8X') {
    width = (bytes[24] | (bytes[25] << 8) | (bytes[26] << 16)) + 1;
    height = (bytes[27] | (bytes[28] << 8) | (bytes[29] << 16)) + 1;
  } else {
    return null;
  }
  return width > 0 && height > 0 ? { width, height } : null;
}

/**
 * Width and height of a JPEG image from its frame header (the first SOFn marker), without
 * decoding it; null when `bytes` is not a JPEG or has no frame header with a size.
 * @param {Uint8Array} bytes
 * @returns {{width: number, height: number}|null}
 */
export function jpegSize(bytes) {
  if (!bytes || bytes.length < 4 || bytes[0] !== 0xff || bytes[1] !== 0xd8) return null;
  let at = 2;
  while (at + 3 < bytes.length) {
    if (bytes[at] !== 0xff) return null;
    const marker = bytes[at + 1];
    if (marker === 0xff) {
      at++; // fill byte
      continue;
    }
    at += 2;
    // Markers without a length: TEM, RSTn, SOI; EOI or SOS before a frame header: no size.
    if (marker === 0x01 || (marker >= 0xd0 && marker <= 0xd8)) continue;
    if (marker === 0xd9 || marker === 0xda) return null;
    const len = (bytes[at] << 8) | bytes[at + 1];
    if (len < 2) return null;
    // SOF0..SOF15 but DHT (C4), JPG (C8) and DAC (CC): precision, height, width.
    if (marker >= 0xc0 && marker <= 0xcf && marker !== 0xc4 && marker !== 0xc8 && marker !== 0xcc) {
      if (len < 7 || at + 7 > bytes.length) return null;
      const height = (bytes[at + 3] << 8) | bytes[at + 4];
      const width = (bytes[at + 5] << 8) | bytes[at + 6];
      return width > 0 && height > 0 ? { width, height } : null;
    }
    at += len;
  }
  return null;
}

/** A reader of range-coded residuals by channel (engine: codec's `Source::Range`). */
function residualSource(bytes, channels, name) {
  const dec = new RangeDecoder(bytes);
  const ch = Array.from({ length: channels }, () => new Channel());
  return (c) => {
    const r = ch[c].get(dec);
    if (r === null || dec.overrun) throw new DecodeError(`stream ${name} does not decode`);
    return r;
  };
}

/**
 * `MWP3` positions and ids (engine: codec's decode loop with `position_guess`, `id_guess`,
 * `role_channel`): each vertex in order, predicted by the mean of its multi-way
 * parallelograms (ids: the median of the clamped ones), or by its traversal prediction when
 * it has none; position residuals by channel of the axis' role.
 */
function decodeResiduals(conn, multi, n, shift, border, posS, idsS, pos, ids, sortedIds) {
  const { kind, pa, pb, pc } = conn;
  const posSource = residualSource(posS, POSITION_CHANNELS, 'positions');
  const idSource = residualSource(idsS, ID_CHANNELS, 'original ids');
  const guess = [0, 0, 0];
  const values = [];
  for (let v = 0; v < n; v++) {
    const from = multi.start[v];
    const to = multi.start[v + 1];
    const isPara = kind[v] === PARALLELOGRAM;
    let normal = -1;
    if (to > from) {
      const m = to - from;
      for (let k = 0; k < 3; k++) {
        let sum = 0;
        for (let j = from; j < to; j++) {
          const x = multi.triples[3 * j];
          const y = multi.triples[3 * j + 1];
          const o = multi.triples[3 * j + 2];
          sum += pos[x * 3 + k] + pos[y * 3 + k] - pos[o * 3 + k];
        }
        guess[k] = Math.floor(sum / m);
      }
      normal = normalAxis(pos, multi.triples[3 * from], multi.triples[3 * from + 1], multi.triples[3 * from + 2]);
    } else {
      for (let k = 0; k < 3; k++) guess[k] = predict(pos, 3, k, kind[v], pa[v], pb[v], pc[v]);
      if (isPara) normal = normalAxis(pos, pa[v], pb[v], pc[v]);
    }
    const interior = !(border[v] || shift === 0);
    for (let k = 0; k < 3; k++) {
      const channel =
        normal >= 0
          ? 12 + (k !== normal ? 1 : 0) + (interior ? 2 : 0)
          : k + (interior ? 3 : 0) + (isPara ? 6 : 0);
      const r = posSource(channel);
      pos[v * 3 + k] = interior ? (floorShift(guess[k], shift) + r) * 2 ** shift : guess[k] + r;
    }
    if (sortedIds) continue;
    let id;
    if (to > from) {
      values.length = 0;
      for (let j = from; j < to; j++) {
        const a = ids[multi.triples[3 * j]];
        const b = ids[multi.triples[3 * j + 1]];
        const c = ids[multi.triples[3 * j + 2]];
        values.push(Math.min(Math.max(a + b - c, Math.min(a, b)), Math.max(a, b)));
      }
      values.sort((x, y) => x - y);
      id = values[values.length >> 1];
    } else {
      id = predict(ids, 1, 0, kind[v], pa[v], pb[v], pc[v]);
    }
    ids[v] = id + idSource(isPara ? 1 : 0);
  }
}

/**
 * Whether grid point `a` (index `i` of `g`, three u32 per point) comes before `b` in Morton
 * order, ties by index (engine: vertex_order::morton_cmp): of the axis whose coordinates
 * differ in the highest bit (at an equal bit z, then y), the smaller first. Grid coordinates
 * are below 2^32, so `(x ^ y) >>> 0` is their exact xor.
 */
function mortonBefore(g, i, j) {
  const msbBelow = (x, y) => x < y && x < (x ^ y) >>> 0;
  let axis = 2;
  let top = (g[3 * i + 2] ^ g[3 * j + 2]) >>> 0;
  for (const k of [1, 0]) {
    const d = (g[3 * i + k] ^ g[3 * j + k]) >>> 0;
    if (msbBelow(top, d)) {
      axis = k;
      top = d;
    }
  }
  if (top === 0) return i < j;
  return g[3 * i + axis] < g[3 * j + axis];
}

/**
 * `MWP3` ids with payload flag 3 (engine: codec's `morton_sequence`): the vertices sorted by
 * the Morton order of their decoded grid points (ties by vertex), each id the previous one
 * (−1 before the first) plus 1 plus a residual of the stream's one channel.
 */
function decodeSortedIds(gridPositions, n, idsS, ids) {
  const source = residualSource(idsS, 1, 'original ids');
  const sequence = Array.from({ length: n }, (_, v) => v);
  sequence.sort((i, j) => (i === j ? 0 : mortonBefore(gridPositions, i, j) ? -1 : 1));
  let previous = -1;
  for (const v of sequence) {
    previous = previous + 1 + source(0);
    ids[v] = previous;
  }
}

/**
 * `MWP3` colours (engine: codec's colour loop with `Parallelograms::colour`): the four
 * filtered bytes per vertex (chroma signed), each predicted by the floored mean over the
 * vertex's parallelograms' x and y corners, or else over its traversal prediction's first
 * two vertices (one for a copy, none for the first vertex), plus a range-coded residual.
 * Writes the filtered bytes into `out` (n × 4).
 */
function decodeColours(conn, multi, n, colS, out) {
  const { kind, pa, pb } = conn;
  const source = residualSource(colS, COLOUR_CHANNELS, 'colors');
  const values = new Float64Array(n * 4);
  const sum = [0, 0, 0, 0];
  let m = 0;
  const add = (u) => {
    for (let k = 0; k < 4; k++) sum[k] += values[u * 4 + k];
    m++;
  };
  for (let v = 0; v < n; v++) {
    const from = multi.start[v];
    const to = multi.start[v + 1];
    sum.fill(0);
    m = 0;
    if (to > from) {
      for (let j = from; j < to; j++) {
        add(multi.triples[3 * j]);
        add(multi.triples[3 * j + 1]);
      }
    } else if (kind[v] === PARALLELOGRAM || kind[v] === MIDPOINT) {
      add(pa[v]);
      add(pb[v]);
    } else if (kind[v] === COPY) {
      add(pa[v]);
    }
    for (let k = 0; k < 4; k++) {
      const value = (m > 0 ? Math.floor(sum[k] / m) : 0) + source(k);
      const signed = k === 1 || k === 2;
      if (signed ? value < -128 || value > 127 : value < 0 || value > 255) {
        throw new DecodeError('stream colors does not decode');
      }
      values[v * 4 + k] = value;
      out[v * 4 + k] = value & 0xff;
    }
  }
}

/** The axis closest to the normal of triangle (a, b, c) (engine: codec's `normal_axis`). */
function normalAxis(pos, a, b, c) {
  const u0 = pos[b * 3] - pos[a * 3];
  const u1 = pos[b * 3 + 1] - pos[a * 3 + 1];
  const u2 = pos[b * 3 + 2] - pos[a * 3 + 2];
  const w0 = pos[c * 3] - pos[a * 3];
  const w1 = pos[c * 3 + 1] - pos[a * 3 + 1];
  const w2 = pos[c * 3 + 2] - pos[a * 3 + 2];
  const n0 = Math.abs(u1 * w2 - u2 * w1);
  const n1 = Math.abs(u2 * w0 - u0 * w2);
  const n2 = Math.abs(u0 * w1 - u1 * w0);
  if (n0 >= n1 && n0 >= n2) return 0;
  return n1 >= n2 ? 1 : 2;
}

/**
 * Each vertex's atlas chart (engine `chart_uv::charts`): triangles that share a vertex are one
 * chart, numbered by their first triangle; a vertex no triangle uses gets -1.
 * @returns {{chart: Int32Array, count: number}}
 */
function charts(indices, n) {
  const parent = new Uint32Array(n);
  for (let v = 0; v < n; v++) parent[v] = v;
  const find = (v) => {
    while (parent[v] !== v) {
      parent[v] = parent[parent[v]];
      v = parent[v];
    }
    return v;
  };
  for (let i = 0; i + 2 < indices.length; i += 3) {
    for (let k = 1; k < 3; k++) {
      const a = find(indices[i]);
      const b = find(indices[i + k]);
      parent[Math.max(a, b)] = Math.min(a, b);
    }
  }
  const label = new Int32Array(n).fill(-1);
  let count = 0;
  for (let i = 0; i + 2 < indices.length; i += 3) {
    const r = find(indices[i]);
    if (label[r] < 0) label[r] = count++;
  }
  const chart = new Int32Array(n);
  for (let v = 0; v < n; v++) chart[v] = label[find(v)];
  return { chart, count };
}

/**
 * Texture coordinates from chart maps (payload flag bit 4, docs/FORMAT.md): a u32 count, then
 * per chart eight f32 `a0 a1 a2 t` for u and for v; a vertex's coordinate is
 * `fround(((a0·x + a1·y) + a2·z) + t)` in doubles, of its grid position relative to the patch
 * minimum, bit for bit the engine's (`chart_uv::evaluate`).
 */
function chartUvs(stream, indices, pos, n) {
  if (stream.length < 4) throw new DecodeError('stream uvs does not decode');
  const count = u32(stream, 0);
  if (stream.length !== 4 + 32 * count) throw new DecodeError('stream uvs does not decode');
  const maps = new Float32Array(count * 8);
  const view = new DataView(stream.buffer, stream.byteOffset + 4, 32 * count);
  for (let i = 0; i < count * 8; i++) maps[i] = view.getFloat32(4 * i, true);
  const { chart, count: found } = charts(indices, n);
  if (found !== count) throw new DecodeError('stream uvs does not decode');
  const uvs = new Float32Array(n * 2);
  for (let v = 0; v < n; v++) {
    const c = chart[v];
    if (c < 0) continue;
    const [x, y, z] = [pos[v * 3], pos[v * 3 + 1], pos[v * 3 + 2]];
    for (let k = 0; k < 2; k++) {
      const m = c * 8 + k * 4;
      uvs[v * 2 + k] = maps[m] * x + maps[m + 1] * y + maps[m + 2] * z + maps[m + 3];
    }
  }
  return uvs;
}

/**
 * Decodes one patch blob.
 * @param {Uint8Array} blob
 * @param {{origin: number[], step: number}} grid the model grid (header)
 * @param {{meshopt: object, decompress: (data: Uint8Array, out: Uint8Array) => Uint8Array}} deps
 *   meshoptimizer's `MeshoptDecoder` (ready) and a zstd decompressor (fzstd's `decompress`)
 * @returns {{vertexCount: number, triangleCount: number, shift: number,
 *   gridPositions: Uint32Array, positions: Float32Array, ids: Uint32Array,
 *   indices: Uint32Array, colors: Uint8Array|null, normals: Float32Array|null,
 *   uvs: Float32Array|null, image: Uint8Array|null, normalMap: Uint8Array|null,
 *   border: Uint8Array, sortedIds: boolean}}
 *   `uvs`: texture coordinates (u, v per vertex, v = 0 the image's top row) when the payload
 *   has them; `image`: the atlas (JPEG bytes, a copy owning its buffer) when the blob has an
 *   image section; `normalMap`: the normal map (JPEG bytes, a copy) when it has one;
 *   `sortedIds`: whether the blob lists its ids in Morton order (payload flag bit 3).
 */
export function decodePatch(blob, grid, deps) {
  if (!(blob instanceof Uint8Array)) throw new DecodeError('blob must be a Uint8Array');
  if (blob.length < 12) throw new DecodeError('blob truncated');
  for (let i = 0; i < 3; i++) if (blob[i] !== MAGIC[i]) throw new DecodeError('bad blob magic');
  if (blob[3] !== 0x32 && blob[3] !== 0x33) throw new DecodeError('bad blob magic');
  const v3 = blob[3] === 0x33;
  const payloadLen = u32(blob, 8);
  if (payloadLen > MAX_PAYLOAD) throw new DecodeError('patch declares implausible sizes');
  // Blob flags (byte 5): the image sections (colour atlas, then normal map) come first, the
  // payload after them.
  let body = 12;
  const section = (flag) => {
    if (!(blob[5] & flag)) return null;
    if (body + 4 > blob.length) throw new DecodeError('blob truncated');
    const len = u32(blob, body);
    const end = body + 4 + len;
    if (end > blob.length) throw new DecodeError('blob truncated');
    const bytes = blob.slice(body + 4, end);
    body = end;
    return bytes;
  };
  const whole = (bytes) => {
    if (!bytes) return bytes;
    const headed = blob[5] & BLOB_STANDARD_HEADERS ? withStandardHeaders(bytes) : bytes;
    return blob[5] & BLOB_STANDARD_HUFFMAN ? withStandardHuffman(headed) : headed;
  };
  const image = blob[5] & BLOB_IMAGE_WEBP ? section(BLOB_IMAGE) : whole(section(BLOB_IMAGE));
  const normalMap = whole(section(BLOB_NORMALS));
  let payload;
  if (blob[4] === COMPRESSION_NONE) {
    payload = blob.subarray(body);
  } else if (blob[4] === COMPRESSION_ZSTD) {
    try {
      payload = deps.decompress(blob.subarray(body), new Uint8Array(payloadLen));
    } catch (e) {
      throw new DecodeError(`decompression failed: ${e && e.message}`);
    }
  } else {
    throw new DecodeError(`unknown compression ${blob[4]}`);
  }
  if (payload.length !== payloadLen || payload.length < PAYLOAD_HEADER) {
    throw new DecodeError('blob truncated');
  }
  const n = u32(payload, 0);
  const t = u32(payload, 4);
  const flags = u32(payload, 8);
  const shift = u32(payload, 12);
  if (n > MAX_ELEMENTS || t > MAX_ELEMENTS || shift > MAX_SHIFT) {
    throw new DecodeError('patch declares implausible sizes');
  }
  const sortedIds = (flags & FLAG_SORTED_IDS) !== 0;
  if (
    (flags & ~KNOWN_FLAGS) !== 0 ||
    (sortedIds && !v3) ||
    (flags & FLAG_CHART_UVS && !(flags & FLAG_UVS)) ||
    (flags & FLAG_NORMALS_BY_ID && !(flags & FLAG_NORMALS))
  ) {
    throw new DecodeError(`patch declares unknown flags 0x${flags.toString(16)}`);
  }
  const min = [u32(payload, 16), u32(payload, 20), u32(payload, 24)];
  const streams = [];
  let at = PAYLOAD_HEADER;
  // The sixth length (byte 48) was reserved, always 0, before texture coordinates existed.
  for (let i = 0; i < STREAMS; i++) {
    const len = u32(payload, 28 + 4 * i);
    if (at + len > payload.length) throw new DecodeError('blob truncated');
    streams.push(payload.subarray(at, at + len));
    at += len;
  }
  const [idxS, posS, idsS, colS, norS, uvS] = streams;
  const { meshopt } = deps;

  const pos = new Float64Array(n * 3);
  const ids = new Float64Array(n);
  let indices;
  let border;
  let conn = null;
  let multi = null;
  if (v3) {
    try {
      conn = decodeConnectivity(idxS, n, t);
    } catch {
      throw new DecodeError('stream indices does not decode');
    }
    indices = conn.indices;
    multi = parallelograms(indices, n);
    border = multi.border;
    decodeResiduals(conn, multi, n, shift, border, posS, idsS, pos, ids, sortedIds);
  } else {
    const indexBytes = new Uint8Array(t * 3 * 4);
    if (t > 0) {
      try {
        meshopt.decodeIndexBuffer(indexBytes, t * 3, 4, idxS);
      } catch {
        throw new DecodeError('stream indices does not decode');
      }
    }
    indices = new Uint32Array(indexBytes.buffer, 0, t * 3);
    for (let i = 0; i < indices.length; i++) {
      if (indices[i] >= n) throw new DecodeError('stream indices does not decode');
    }
    border = borderVertices(indices, n);
    const posCursor = { at: 0 };
    const idsCursor = { at: 0 };
    const visited = walk(indices, n, (v, kind, a, b, c) => {
      if (border[v] || shift === 0) {
        for (let k = 0; k < 3; k++) {
          pos[v * 3 + k] = predict(pos, 3, k, kind, a, b, c) + readVarint(posS, posCursor);
        }
      } else {
        const scale = 2 ** shift;
        for (let k = 0; k < 3; k++) {
          const guess = floorShift(predict(pos, 3, k, kind, a, b, c), shift);
          pos[v * 3 + k] = (guess + readVarint(posS, posCursor)) * scale;
        }
      }
      ids[v] = predict(ids, 1, 0, kind, a, b, c) + readVarint(idsS, idsCursor);
    });
    if (visited !== n) throw new DecodeError('stream positions does not decode');
  }

  const gridPositions = new Uint32Array(n * 3);
  const positions = new Float32Array(n * 3);
  for (let v = 0; v < n; v++) {
    for (let k = 0; k < 3; k++) {
      const g = pos[v * 3 + k] + min[k];
      if (!(g >= 0 && g <= U32_MAX)) throw new DecodeError('stream positions does not decode');
      gridPositions[v * 3 + k] = g;
      positions[v * 3 + k] = grid.origin[k] + grid.step * g;
    }
  }
  if (sortedIds) decodeSortedIds(gridPositions, n, idsS, ids);
  const originalIds = new Uint32Array(n);
  for (let v = 0; v < n; v++) {
    if (!(ids[v] >= 0 && ids[v] <= U32_MAX)) throw new DecodeError('stream original ids does not decode');
    originalIds[v] = ids[v];
  }

  let colors = null;
  if (flags & FLAG_COLORS) {
    colors = new Uint8Array(n * 4);
    if (n > 0) {
      if (v3) {
        decodeColours(conn, multi, n, colS, colors);
      } else {
        try {
          meshopt.decodeVertexBuffer(colors, n, 4, colS);
        } catch {
          throw new DecodeError('stream colors does not decode');
        }
      }
      decodeYCoCg(colors);
    }
  }
  let normals = null;
  if (flags & FLAG_NORMALS) {
    const predicted = gridNormals(pos, indices, n);
    normals = Float32Array.from(predicted);
    const cursor = { at: 0 };
    const q = [0, 0];
    const source = v3 ? residualSource(norS, NORMAL_CHANNELS, 'normals') : null;
    // With flag bit 5, a border vertex whose id an earlier border vertex has takes its normal.
    const first = flags & FLAG_NORMALS_BY_ID ? new Map() : null;
    for (let v = 0; v < n; v++) {
      if (!border[v]) continue;
      if (first) {
        const earlier = first.get(originalIds[v]);
        if (earlier !== undefined) {
          normals.set(normals.subarray(earlier * 3, earlier * 3 + 3), v * 3);
          continue;
        }
        first.set(originalIds[v], v);
      }
      octEncode(predicted[v * 3], predicted[v * 3 + 1], predicted[v * 3 + 2], q);
      const qx = q[0] + (v3 ? source(0) : readVarint(norS, cursor));
      const qy = q[1] + (v3 ? source(1) : readVarint(norS, cursor));
      octDecode(qx, qy, normals, v * 3);
    }
  }
  let uvs = null;
  if (flags & FLAG_CHART_UVS) {
    uvs = chartUvs(uvS, indices, pos, n);
  } else if (flags & FLAG_UVS) {
    // u16 u, u16 v (little-endian) per vertex through the vertex codec; q / 65535 in [0, 1].
    uvs = new Float32Array(n * 2);
    if (n > 0) {
      const q = new Uint8Array(n * 4);
      try {
        meshopt.decodeVertexBuffer(q, n, 4, uvS);
      } catch {
        throw new DecodeError('stream uvs does not decode');
      }
      for (let i = 0; i < n * 2; i++) uvs[i] = (q[2 * i] | (q[2 * i + 1] << 8)) / UV_SCALE;
    }
  }
  return {
    vertexCount: n,
    triangleCount: t,
    shift,
    gridPositions,
    positions,
    ids: originalIds,
    indices,
    colors,
    normals,
    uvs,
    image,
    normalMap,
    border,
    sortedIds,
  };
}
