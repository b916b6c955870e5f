// Client side of the Grid-Lumigraph (system paper §5.1, §5.3, Fig. 15): for the current view,
// the images of the grid points nearest to the eye, fetched as the view needs them and kept
// on the GPU in texture arrays that the scene's shader projects onto the sparse mesh.
//
// - Points: the `SLOTS` lattice points nearest to the eye (clamped into the viewing box) on the
//   eye's side of the view's target, so the images' rays are the closest to the view's rays
//   the repository has.
// - Faces: of each point, only the directions that see a drawn patch (the bounding cube of each
//   drawn patch's sphere, seen from the point, names the faces it falls in).
// - Requests: nearest point first, at most `maxInFlight` at once, `?v=<job>` in the URL so the
//   browser cache (the images are immutable) never mixes two builds. Empty images (204) are
//   remembered and not asked again.
// - Textures: layer `slot * 6 + d` of three arrays — albedo and normals at the image side,
//   depth (16-bit code in red/green) at `depth_size` — and per layer its depth range and whether
//   it holds an albedo (`layerInfo`), per slot its point (`points`).

import * as THREE from 'three';
import { parseImage, pixels } from './image.js';

/** Grid points whose images are resident at once. */
export const SLOTS = 4;
const LAYERS = SLOTS * 6;
/** The eye moves this share of the grid spacing before the points are chosen again. */
const RESELECT = 0.1;

function arrayTexture(side, filter) {
  const data = new Uint8Array(side * side * 4 * LAYERS);
  const tex = new THREE.DataArrayTexture(data, side, side, LAYERS);
  tex.format = THREE.RGBAFormat;
  tex.type = THREE.UnsignedByteType;
  tex.colorSpace = THREE.NoColorSpace;
  tex.minFilter = filter;
  tex.magFilter = filter;
  tex.generateMipmaps = false;
  tex.wrapS = THREE.ClampToEdgeWrapping;
  tex.wrapT = THREE.ClampToEdgeWrapping;
  tex.needsUpdate = true;
  return tex;
}

export class Repository {
  /**
   * @param {number} modelId
   * @param {object} description GET /api/v1/models/{id}/lumigraph (status `ready`)
   * @param {{onChange: Function, fetch?: Function, maxInFlight?: number,
   *   settings?: {bandwidth: number, maxWait: number}}} o `settings`: the streamer's (a user's
   *   bandwidth cap in bytes/s, 0 for none, shared with patch streaming)
   */
  constructor(modelId, description, o) {
    this.modelId = modelId;
    this.d = description;
    this.onChange = o.onChange;
    this.fetch = o.fetch || ((url, init) => fetch(url, init));
    this.maxInFlight = o.maxInFlight || 4;
    this.settings = o.settings || { bandwidth: 0, maxWait: 1 };
    // A request's size before it is known: the repository's mean image.
    this.meanBytes = description.counts.images > 0 ? description.counts.bytes / description.counts.images : 32 << 10;
    this.tokens = 0;
    this.tokensAt = performance.now();
    this.n = description.grid;
    this.side = description.size;
    this.depthSide = description.depth_size;
    this.min = description.box.min;
    this.spacing = description.spacing;
    // Models without colours have no albedo sections: a one-texel array until one arrives.
    this.albedo = arrayTexture(1, THREE.LinearFilter);
    this.normal = arrayTexture(this.side, THREE.LinearFilter);
    this.depth = arrayTexture(this.depthSide, THREE.NearestFilter);
    this.points = Array.from({ length: SLOTS }, () => new THREE.Vector4(0, 0, 0, 0));
    this.layerInfo = Array.from({ length: LAYERS }, () => new THREE.Vector4(0, 0, 0, 0));
    // The shader names a direction's face by its dominant axis: d = 2 axis + (negative).
    description.directions.forEach((d, k) => {
      const axis = k >> 1;
      if (d.forward[axis] !== (k & 1 ? -1 : 1)) throw new Error(`lumigraph: direction ${k} is not along axis ${axis}`);
    });
    this.forward = description.directions.map((d) => new THREE.Vector3(...d.forward));
    this.up = description.directions.map((d) => new THREE.Vector3(...d.up));
    this.slots = new Array(SLOTS).fill(null); // slot -> point key "x,y,z"
    this.loaded = new Set(); // "x,y,z,d" resident in its slot's layer
    this.empty = new Set(); // "x,y,z,d" known to show nothing
    this.inFlight = new Set();
    this.failed = new Map();
    this.lastEye = null;
    this.waiting = 0;
    this.stats = { bytes: 0, requests: 0, images: 0, empty: 0, errors: 0 };
    this.closed = false;
  }

  /** Point (x, y, z) in world space. */
  position(p) {
    return [0, 1, 2].map((a) => this.min[a] + p[a] * this.spacing);
  }

  /**
   * The `SLOTS` lattice points nearest to `eye` among those on the eye's side of the view's
   * target (a point beyond it sees the surface from behind: its rays point against the view's).
   */
  nearest(eye, target) {
    const n = this.n;
    const c = [0, 1, 2].map((a) => Math.min(n - 1, Math.max(0, (eye[a] - this.min[a]) / this.spacing)));
    const r = [0, 1, 2].map((a) => Math.round(c[a]));
    const cands = [];
    const view = [0, 1, 2].map((a) => target[a] - eye[a]);
    for (let dz = -3; dz <= 3; dz++) {
      for (let dy = -3; dy <= 3; dy++) {
        for (let dx = -3; dx <= 3; dx++) {
          const p = [r[0] + dx, r[1] + dy, r[2] + dz];
          if (p.some((v) => v < 0 || v >= n)) continue;
          const w = this.position(p);
          const dist = Math.hypot(w[0] - eye[0], w[1] - eye[1], w[2] - eye[2]);
          const ahead = (target[0] - w[0]) * view[0] + (target[1] - w[1]) * view[1] + (target[2] - w[2]) * view[2];
          cands.push({ p, dist: ahead > 0 ? dist : dist + 1e6 });
        }
      }
    }
    cands.sort((a, b) => a.dist - b.dist);
    return cands.slice(0, SLOTS).map((c) => c.p);
  }

  /** Face (0..5) of a point that sees direction `v`: its dominant axis, `2 axis + negative`. */
  face(v) {
    const a = [Math.abs(v[0]), Math.abs(v[1]), Math.abs(v[2])];
    const axis = a[0] >= a[1] && a[0] >= a[2] ? 0 : a[1] >= a[2] ? 1 : 2;
    return 2 * axis + (v[axis] >= 0 ? 0 : 1);
  }

  /**
   * Follows the view: chooses the points for `camera` (its eye), asks for the faces that see
   * the `drawn` nodes (bounds in `table.bounds`), and starts what fits in flight.
   */
  update(camera, drawn, table) {
    if (this.closed) return;
    const eye = camera.eye;
    const moved = !this.lastEye || Math.hypot(eye[0] - this.lastEye[0], eye[1] - this.lastEye[1], eye[2] - this.lastEye[2]) > RESELECT * this.spacing;
    if (moved) {
      this.lastEye = eye.slice();
      this.assign(this.nearest(eye, camera.target));
    }
    const wanted = [];
    const b = table.bounds;
    for (let s = 0; s < SLOTS; s++) {
      const key = this.slots[s];
      if (key === null) continue;
      const p = key.split(',').map(Number);
      const g = this.position(p);
      const count = new Array(6).fill(0);
      for (const node of drawn) {
        const cx = b[node * 4] - g[0];
        const cy = b[node * 4 + 1] - g[1];
        const cz = b[node * 4 + 2] - g[2];
        // The middle of the patch's bounds (its sphere's cube shrunk by half): a face that
        // sees only a corner of a patch's bounding cube rarely sees the patch.
        const r = 0.5 * b[node * 4 + 3];
        for (let k = 0; k < 8; k++) count[this.face([cx + (k & 1 ? r : -r), cy + (k & 2 ? r : -r), cz + (k & 4 ? r : -r)])]++;
      }
      for (let d = 0; d < 6; d++) {
        if (count[d] === 0) continue;
        const id = `${key},${d}`;
        if (this.loaded.has(id) || this.empty.has(id) || this.inFlight.has(id)) continue;
        const failedAt = this.failed.get(id);
        if (failedAt !== undefined && performance.now() - failedAt < 3000) continue;
        wanted.push({ slot: s, p, d, id, priority: s * 1e6 - count[d] });
      }
    }
    wanted.sort((a, b) => a.priority - b.priority);
    this.waiting = wanted.length;
    // A user's bandwidth cap (token bucket holding at most B·T bytes, as patch streaming's).
    const cap = this.settings.bandwidth;
    const now = performance.now();
    if (cap > 0) this.tokens = Math.min(cap * this.settings.maxWait, this.tokens + ((now - this.tokensAt) / 1000) * cap);
    this.tokensAt = now;
    for (const w of wanted) {
      if (this.inFlight.size >= this.maxInFlight) break;
      if (cap > 0) {
        if (this.tokens < this.meanBytes && this.inFlight.size > 0) {
          if (!this.paceTimer) this.paceTimer = setTimeout(() => {
            this.paceTimer = null;
            this.onChange();
          }, 50);
          break;
        }
        this.tokens -= this.meanBytes;
      }
      this.request(w);
    }
  }

  /** Keeps the slots of points still wanted, gives the others' slots to the new points. */
  assign(points) {
    const keys = points.map((p) => p.join(','));
    const staying = new Set(keys.filter((k) => this.slots.includes(k)));
    const incoming = keys.filter((k) => !staying.has(k));
    for (let s = 0; s < SLOTS; s++) {
      if (this.slots[s] !== null && staying.has(this.slots[s])) continue;
      const old = this.slots[s];
      if (old !== null) for (let d = 0; d < 6; d++) this.loaded.delete(`${old},${d}`);
      const key = incoming.shift() ?? null;
      this.slots[s] = key;
      for (let d = 0; d < 6; d++) this.layerInfo[s * 6 + d].set(0, 0, 0, 0);
      if (key === null) {
        this.points[s].set(0, 0, 0, 0);
        continue;
      }
      const w = this.position(key.split(',').map(Number));
      this.points[s].set(w[0], w[1], w[2], 1);
    }
  }

  async request(w) {
    const key = w.p.join(',');
    this.inFlight.add(w.id);
    this.stats.requests++;
    try {
      const url = `/api/v1/models/${this.modelId}/lumigraph/images/${w.p[0]}/${w.p[1]}/${w.p[2]}/${w.d}?v=${this.d.job_id}`;
      const res = await this.fetch(url, { credentials: 'same-origin' });
      if (res.status === 204) {
        this.empty.add(w.id);
        this.stats.empty++;
        return;
      }
      if (!res.ok) throw new Error(`image ${w.id}: HTTP ${res.status}`);
      const buf = await res.arrayBuffer();
      this.stats.bytes += buf.byteLength;
      const img = parseImage(buf);
      if (img.side !== this.side || img.depthSide !== this.depthSide) throw new Error(`image ${w.id}: size ${img.side}`);
      const [albedo, normal, depth] = await Promise.all([
        img.albedo ? pixels(img.albedo, 'image/jpeg', img.side) : null,
        pixels(img.normal, 'image/jpeg', img.side),
        pixels(img.depth, 'image/png', img.depthSide),
      ]);
      const s = this.slots.indexOf(key);
      if (this.closed || s < 0) return;
      const layer = s * 6 + w.d;
      const put = (tex, px, side) => {
        tex.image.data.set(px, layer * side * side * 4);
        tex.addLayerUpdate(layer);
        tex.needsUpdate = true;
      };
      if (albedo) {
        if (this.albedo.image.width !== this.side) {
          this.albedo.dispose();
          this.albedo = arrayTexture(this.side, THREE.LinearFilter);
        }
        put(this.albedo, albedo, this.side);
      }
      put(this.normal, normal, this.side);
      put(this.depth, depth, this.depthSide);
      this.layerInfo[layer].set(1, img.range[0], img.range[1], albedo ? 1 : 0);
      this.loaded.add(w.id);
      this.failed.delete(w.id);
      this.stats.images++;
    } catch (e) {
      this.stats.errors++;
      this.failed.set(w.id, performance.now());
      console.warn('meshwiki viewer:', e.message || e);
    } finally {
      this.inFlight.delete(w.id);
      if (!this.closed) this.onChange();
    }
  }

  /** Whether every face the last update wanted is resident or known empty. */
  settled() {
    return this.inFlight.size === 0 && this.waiting === 0;
  }

  close() {
    this.closed = true;
    clearTimeout(this.paceTimer);
    for (const t of [this.albedo, this.normal, this.depth]) t.dispose();
  }
}
