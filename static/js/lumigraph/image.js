// One image of a model's Grid-Lumigraph repository (engine/src/lumigraph/image.rs, docs/FORMAT.md
// "Lumigraph image"): albedo (optional), normals and view depth of the full-resolution surface
// as seen from a grid point. `parseImage` reads the container; `pixels` decodes a section to
// RGBA bytes as stored (no colour management).

const MAGIC = [0x4d, 0x57, 0x4c, 0x49]; // "MWLI"
const HEADER = 32;
/** Depth code of a pixel without surface. */
export const NO_DEPTH = 65535;

/**
 * Reads the container.
 * @returns {{side: number, depthSide: number, range: [number, number], normalAxis: number|null,
 *   albedo: Uint8Array|null, normal: Uint8Array, depth: Uint8Array}} the sections' bytes (JPEG,
 *   JPEG, PNG); `range`: the depths of codes 0 and 65534; `normalAxis`: the face's axis where the
 *   normals are in face order (worldOrder), else null (x, y, z order)
 */
export function parseImage(buffer) {
  const b = new Uint8Array(buffer);
  if (b.length < HEADER || MAGIC.some((m, i) => b[i] !== m)) throw new Error('not a lumigraph image');
  if (b[4] !== 1) throw new Error(`unsupported lumigraph image version ${b[4]}`);
  const v = new DataView(buffer instanceof ArrayBuffer ? buffer : b.buffer, b.byteOffset, b.byteLength);
  const side = v.getUint16(6, true);
  const depthSide = v.getUint16(8, true);
  const d0 = v.getFloat32(12, true);
  const d1 = v.getFloat32(16, true);
  // Code m is d1 (0 in images of earlier builds: 65534); `range` is code 0's and code 65534's
  // depth, whatever m.
  const m = Math.min(v.getUint16(10, true) || NO_DEPTH - 1, NO_DEPTH - 1);
  const range = [d0, d0 + ((d1 - d0) * (NO_DEPTH - 1)) / m];
  const lens = [v.getUint32(20, true), v.getUint32(24, true), v.getUint32(28, true)];
  if (HEADER + lens[0] + lens[1] + lens[2] !== b.length) throw new Error('lumigraph image: section lengths disagree with its size');
  const a = HEADER + lens[0];
  const n = a + lens[1];
  // Flags bit 1: normals in face order (green the component along the face's axis, bits 2-3).
  const normalAxis = (b[5] & 2) !== 0 ? (b[5] >> 2) & 3 : null;
  if (normalAxis === 3) throw new Error('lumigraph image: no such face axis');
  return {
    side,
    depthSide,
    range,
    normalAxis,
    albedo: (b[5] & 1) !== 0 ? b.subarray(HEADER, a) : null,
    normal: b.subarray(a, n),
    depth: b.subarray(n),
  };
}

/** RGBA bytes of an encoded image (`type` its media type), exactly as stored. */
export async function pixels(bytes, type, side) {
  const bitmap = await createImageBitmap(new Blob([bytes], { type }), { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
  try {
    if (bitmap.width !== side || bitmap.height !== side) throw new Error(`lumigraph image: a ${bitmap.width}x${bitmap.height} section, ${side}x${side} expected`);
    const canvas = typeof OffscreenCanvas !== 'undefined' ? new OffscreenCanvas(side, side) : Object.assign(document.createElement('canvas'), { width: side, height: side });
    const ctx = canvas.getContext('2d', { willReadFrequently: true });
    ctx.drawImage(bitmap, 0, 0);
    return ctx.getImageData(0, 0, side, side).data;
  } finally {
    bitmap.close();
  }
}

/**
 * Puts RGBA normals in face order for a face along `axis` (green the component along it, red
 * the next axis's, blue the one after: engine/src/lumigraph/image.rs face_order) back in x, y,
 * z order, in place.
 */
export function worldOrder(px, axis) {
  const [r, g, b] = [(axis + 1) % 3, axis, (axis + 2) % 3];
  for (let i = 0; i < px.length; i += 4) {
    const c0 = px[i];
    const c1 = px[i + 1];
    const c2 = px[i + 2];
    px[i + r] = c0;
    px[i + g] = c1;
    px[i + b] = c2;
  }
  return px;
}

/** View depth of depth code `q` of an image with depth range `range` (null: no surface). */
export function depthOf(q, range) {
  return q >= NO_DEPTH ? null : range[0] + (q / (NO_DEPTH - 1)) * (range[1] - range[0]);
}
