// The LOD tables (docs/FORMAT.md "File layout"): header, node records, group records and
// links, parsed from `GET /api/v1/models/{id}/lod?format=binary` (or normalised from the JSON
// form) into flat typed arrays the cut walks every frame.

const HEADER_BYTES = 256;
const NODE_BYTES = 128;
const GROUP_BYTES = 48;
const NO_GROUP = 0xffffffff;
const MAGIC = [0x4d, 0x57, 0x4c, 0x4f, 0x44, 0x00, 0x0d, 0x0a]; // "MWLOD\0\r\n"
/** Header flags (docs/FORMAT.md "File layout", byte 12). */
const HAS_COLORS = 1;
const HAS_NORMALS = 2;
/** Every patch carries a texture atlas (an image section and texture coordinates). */
const HAS_TEXTURE = 4;
const HAS_NORMAL_MAPS = 8;

let crcTable = null;

/** CRC-32 (IEEE) of `bytes`. */
export function crc32(bytes) {
  if (!crcTable) {
    crcTable = new Uint32Array(256);
    for (let i = 0; i < 256; i++) {
      let c = i;
      for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
      crcTable[i] = c >>> 0;
    }
  }
  let crc = 0xffffffff;
  for (let i = 0; i < bytes.length; i++) crc = crcTable[(crc ^ bytes[i]) & 0xff] ^ (crc >>> 8);
  return (crc ^ 0xffffffff) >>> 0;
}

function u64(view, at) {
  return view.getUint32(at, true) + view.getUint32(at + 4, true) * 4294967296;
}

function emptyTables(nodeCount, groupCount) {
  return {
    nodeCount,
    groupCount,
    level: new Uint32Array(nodeCount),
    triangles: new Uint32Array(nodeCount),
    vertices: new Uint32Array(nodeCount),
    offset: new Float64Array(nodeCount),
    length: new Uint32Array(nodeCount),
    crc: new Uint32Array(nodeCount),
    bounds: new Float32Array(nodeCount * 4),
    cone: new Float32Array(nodeCount * 4),
    lodSphere: new Float32Array(nodeCount * 4),
    lodError: new Float32Array(nodeCount),
    parentSphere: new Float32Array(nodeCount * 4),
    parentError: new Float32Array(nodeCount),
    producer: new Int32Array(nodeCount),
    memberOf: new Int32Array(nodeCount),
    groupSphere: new Float32Array(groupCount * 4),
    groupError: new Float32Array(groupCount),
    groupLevel: new Uint32Array(groupCount),
    members: new Array(groupCount),
    products: new Array(groupCount),
  };
}

/** Finishes a table: roots and the group order the cut needs (coarsest level first). */
function finish(t) {
  const roots = [];
  for (let i = 0; i < t.nodeCount; i++) if (t.memberOf[i] < 0) roots.push(i);
  t.roots = Uint32Array.from(roots);
  const order = Array.from({ length: t.groupCount }, (_, g) => g);
  order.sort((a, b) => t.groupLevel[b] - t.groupLevel[a] || a - b);
  t.groupOrder = Uint32Array.from(order);
  const c = [(t.bbox.min[0] + t.bbox.max[0]) / 2, (t.bbox.min[1] + t.bbox.max[1]) / 2, (t.bbox.min[2] + t.bbox.max[2]) / 2];
  const half = [0, 1, 2].map((k) => (t.bbox.max[k] - t.bbox.min[k]) / 2);
  t.center = c;
  t.radius = Math.max(Math.hypot(half[0], half[1], half[2]), 1e-9);
  let leafBytes = 0;
  let leafTriangles = 0;
  for (let i = 0; i < t.nodeCount; i++) {
    if (t.level[i] === 0) {
      leafBytes += t.length[i];
      leafTriangles += t.triangles[i];
    }
  }
  t.leafBytes = leafBytes;
  t.leafTriangles = leafTriangles;
  return t;
}

/**
 * Parses the binary tables (the file's first `blobs_offset` bytes).
 * @param {ArrayBuffer} buffer
 */
export function parseBinary(buffer) {
  const bytes = new Uint8Array(buffer);
  if (bytes.length < HEADER_BYTES) throw new Error('LOD tables truncated');
  for (let i = 0; i < 8; i++) if (bytes[i] !== MAGIC[i]) throw new Error('not a meshwiki LOD file');
  const view = new DataView(buffer);
  const version = view.getUint32(8, true);
  if (version !== 1) throw new Error(`unsupported LOD version ${version}`);
  if (crc32(bytes.subarray(0, 252)) !== view.getUint32(252, true)) throw new Error('LOD header checksum mismatch');
  const flags = view.getUint32(12, true);
  const nodeCount = view.getUint32(16, true);
  const groupCount = view.getUint32(20, true);
  const linkCount = view.getUint32(24, true);
  const nodesOffset = u64(view, 112);
  const groupsOffset = u64(view, 120);
  const linksOffset = u64(view, 128);
  const end = linksOffset + 4 * linkCount;
  if (nodesOffset + nodeCount * NODE_BYTES > bytes.length || groupsOffset + groupCount * GROUP_BYTES > bytes.length || end > bytes.length) {
    throw new Error('LOD tables truncated');
  }
  const checks = [
    [nodesOffset, nodeCount * NODE_BYTES, 152, 'node table'],
    [groupsOffset, groupCount * GROUP_BYTES, 156, 'group table'],
    [linksOffset, linkCount * 4, 160, 'links'],
  ];
  for (const [at, len, crcAt, what] of checks) {
    if (crc32(bytes.subarray(at, at + len)) !== view.getUint32(crcAt, true)) throw new Error(`LOD ${what} checksum mismatch`);
  }
  const t = emptyTables(nodeCount, groupCount);
  t.version = version;
  t.hasColors = (flags & HAS_COLORS) !== 0;
  t.hasNormals = (flags & HAS_NORMALS) !== 0;
  t.hasTexture = (flags & HAS_TEXTURE) !== 0;
  t.hasNormalMaps = (flags & HAS_NORMAL_MAPS) !== 0;
  t.levelCount = view.getUint32(28, true);
  t.inputVertices = u64(view, 32);
  t.inputTriangles = u64(view, 40);
  t.bbox = {
    min: [0, 1, 2].map((k) => view.getFloat32(48 + 4 * k, true)),
    max: [0, 1, 2].map((k) => view.getFloat32(60 + 4 * k, true)),
  };
  t.grid = { origin: [0, 1, 2].map((k) => view.getFloat64(72 + 8 * k, true)), step: view.getFloat64(96, true) };
  t.maxPatchTriangles = view.getUint32(104, true);
  t.blobsOffset = u64(view, 136);
  t.blobsLength = u64(view, 144);
  t.fileBytes = t.blobsOffset + t.blobsLength;
  for (let i = 0; i < nodeCount; i++) {
    const o = nodesOffset + i * NODE_BYTES;
    t.offset[i] = u64(view, o);
    t.length[i] = view.getUint32(o + 8, true);
    t.crc[i] = view.getUint32(o + 12, true);
    t.triangles[i] = view.getUint32(o + 16, true);
    t.vertices[i] = view.getUint32(o + 20, true);
    t.level[i] = view.getUint32(o + 24, true);
    for (let k = 0; k < 4; k++) {
      t.bounds[i * 4 + k] = view.getFloat32(o + 32 + 4 * k, true);
      t.cone[i * 4 + k] = view.getFloat32(o + 48 + 4 * k, true);
      t.lodSphere[i * 4 + k] = view.getFloat32(o + 64 + 4 * k, true);
      t.parentSphere[i * 4 + k] = view.getFloat32(o + 96 + 4 * k, true);
    }
    t.lodError[i] = view.getFloat32(o + 80, true);
    t.parentError[i] = view.getFloat32(o + 84, true);
    const producer = view.getUint32(o + 112, true);
    const memberOf = view.getUint32(o + 116, true);
    t.producer[i] = producer === NO_GROUP ? -1 : producer;
    t.memberOf[i] = memberOf === NO_GROUP ? -1 : memberOf;
  }
  const link = (first, count) => {
    if (first + count > linkCount) throw new Error('LOD group links out of range');
    const out = new Uint32Array(count);
    for (let k = 0; k < count; k++) {
      const id = view.getUint32(linksOffset + 4 * (first + k), true);
      if (id >= nodeCount) throw new Error('LOD group names a missing node');
      out[k] = id;
    }
    return out;
  };
  for (let g = 0; g < groupCount; g++) {
    const o = groupsOffset + g * GROUP_BYTES;
    for (let k = 0; k < 4; k++) t.groupSphere[g * 4 + k] = view.getFloat32(o + 4 * k, true);
    t.groupError[g] = view.getFloat32(o + 16, true);
    t.groupLevel[g] = view.getUint32(o + 20, true);
    t.members[g] = link(view.getUint32(o + 24, true), view.getUint32(o + 28, true));
    t.products[g] = link(view.getUint32(o + 32, true), view.getUint32(o + 36, true));
  }
  for (let i = 0; i < nodeCount; i++) {
    if (t.producer[i] >= groupCount || t.memberOf[i] >= groupCount) throw new Error('LOD node names a missing group');
  }
  return finish(t);
}

/** Normalises the JSON form of `GET /api/v1/models/{id}/lod` to the same tables. */
export function fromJson(json) {
  const t = emptyTables(json.node_count, json.group_count);
  t.version = json.version;
  t.hasColors = !!json.has_colors;
  t.hasNormals = !!json.has_normals;
  t.hasTexture = !!json.has_texture;
  t.hasNormalMaps = !!json.has_normal_maps;
  t.levelCount = json.level_count;
  t.inputVertices = json.input_vertices;
  t.inputTriangles = json.input_triangles;
  t.bbox = { min: json.bbox.min, max: json.bbox.max };
  t.grid = { origin: json.grid.origin, step: json.grid.step };
  t.maxPatchTriangles = json.max_patch_triangles;
  t.fileBytes = json.file_bytes;
  for (const node of json.nodes) {
    const i = node.id;
    t.offset[i] = node.offset;
    t.length[i] = node.length;
    t.crc[i] = node.crc32;
    t.triangles[i] = node.triangles;
    t.vertices[i] = node.vertices;
    t.level[i] = node.level;
    t.bounds.set(node.bounds, i * 4);
    t.cone.set(node.cone, i * 4);
    t.lodSphere.set(node.lod_sphere, i * 4);
    t.parentSphere.set(node.parent_sphere, i * 4);
    t.lodError[i] = node.lod_error;
    t.parentError[i] = node.parent_error === null ? Infinity : node.parent_error;
    t.producer[i] = node.producer === null ? -1 : node.producer;
    t.memberOf[i] = node.member_of === null ? -1 : node.member_of;
  }
  for (const group of json.groups) {
    const g = group.id;
    t.groupSphere.set(group.sphere, g * 4);
    t.groupError[g] = group.error;
    t.groupLevel[g] = group.level;
    t.members[g] = Uint32Array.from(group.members);
    t.products[g] = Uint32Array.from(group.products);
  }
  return finish(t);
}
