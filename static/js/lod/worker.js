// Decoding worker: checks a patch blob's CRC, decodes it (decode.js) and sends back
// GPU-ready arrays (transferred, not copied), and for textured patches the atlas' image bytes
// (decoded to a bitmap on the main thread, scene.js) with its size read from its header.
// Started as a module worker by workers.js.
// Import maps do not reach workers, so the vendor modules are imported by URL.

import { MeshoptDecoder } from '/static/vendor/meshoptimizer/meshopt_decoder.mjs';
import { decompress } from '/static/vendor/fzstd/esm/index.mjs';
import { decodePatch, computedNormals, imageSize, jpegSize } from './decode.js';
import { crc32 } from './table.js';

const ready = MeshoptDecoder.ready.then(() => ({ meshopt: MeshoptDecoder, decompress }));

/** Packs a decoded patch for the GPU: u16 indices when they fit, i8 normals are not worth it. */
function pack(p) {
  const indices = p.vertexCount <= 65536 ? Uint16Array.from(p.indices) : p.indices;
  const normals = p.normals || computedNormals(p.positions, p.indices, p.vertexCount);
  // A texture needs both the image and the coordinates (docs/FORMAT.md "Textures").
  const textured = p.image !== null && p.uvs !== null;
  const size = textured ? imageSize(p.image) : null;
  const mapped = p.normalMap !== null && p.uvs !== null;
  const mapSize = mapped ? jpegSize(p.normalMap) : null;
  return {
    vertexCount: p.vertexCount,
    triangleCount: p.triangleCount,
    positions: p.positions,
    normals,
    colors: p.colors,
    ids: p.ids,
    indices,
    uvs: textured || mapped ? p.uvs : null,
    image: textured ? p.image : null,
    imageWidth: size ? size.width : 0,
    imageHeight: size ? size.height : 0,
    normalMap: mapped ? p.normalMap : null,
    normalMapWidth: mapSize ? mapSize.width : 0,
    normalMapHeight: mapSize ? mapSize.height : 0,
  };
}

self.onmessage = async (event) => {
  const { id, blob, grid, crc } = event.data;
  try {
    const deps = await ready;
    const bytes = new Uint8Array(blob);
    if (crc !== undefined && crc32(bytes) !== crc) throw new Error('patch failed its checksum');
    const patch = pack(decodePatch(bytes, grid, deps));
    const transfer = [patch.positions.buffer, patch.normals.buffer, patch.ids.buffer, patch.indices.buffer];
    if (patch.colors) transfer.push(patch.colors.buffer);
    // decodePatch's image is a copy with its own buffer, so this does not move the blob.
    if (patch.uvs) transfer.push(patch.uvs.buffer);
    if (patch.image) transfer.push(patch.image.buffer);
    if (patch.normalMap) transfer.push(patch.normalMap.buffer);
    self.postMessage({ id, patch }, transfer);
  } catch (e) {
    self.postMessage({ id, error: String((e && e.message) || e) });
  }
};
