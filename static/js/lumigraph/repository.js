// Client side of the Grid-Lumigraph (system paper §5.1, §5.3, Fig. 15): for the current view,
// the images of the grid points nearest to the eye, fetched as the view needs them and kept
// on the GPU in texture arrays that the scene's shader projects onto the sparse mesh.
//
// - Points: the `SLOTS` lattice points nearest to the image eye on the eye's side of the view's
//   target, so the images' rays are the closest to the view's rays the repository has. The
//   image eye lies on the way from the target to the eye, where an image's texel is as fine as
//   the view's pixel (a 90° image of `size` pixels against the view's field of view and height),
//   and the lattice is the refinement level whose spacing is at most half its distance to the
//   target (engine/src/lumigraph/grid.rs, "Refinement levels"; finer levels are kept near the
//   model only, and their images are rendered on the server when first asked for).
// - Faces: the fewest images that serve the drawn patches (a greedy cover of points of the
//   patches' surfaces within the view by the images the shader would weigh within BLEND of the
//   best there).
// - Requests: nearest point first, at most `maxInFlight` at once, `?v=<job>` in the URL so the
//   browser cache (the images are immutable) never mixes two builds. Empty images (204) are
//   remembered and not asked again.
// - Textures: layer `slot * 6 + d` of three arrays — albedo and normals at the image side,
//   depth (16-bit code in red/green) at `depth_size` — and per layer its depth range and whether
//   it holds an albedo (`layerInfo`), per slot its point (`points`).

import * as THREE from 'three';
import { inFrustum, makeView } from '../lod/cut.js';
import { parseImage, pixels, worldOrder } from './image.js';

/** Grid points whose images are resident at once. */
export const SLOTS = 4;
const LAYERS = SLOTS * 6;
/** The image eye moves this share of its level's spacing before the points are chosen again. */
const RESELECT = 0.1;
/** A level's spacing is at most this share of the image eye's distance to the target. */
const LEVEL_SPACING = 0.5;
/** The shader's weight of an image: exp(SHARPNESS (cos - 1)) / depth² (viewer/scene.js). */
export const SHARPNESS = 40;
/** An image serves a point where its weight is at least this share of the best image's. */
const BLEND = 0.3;
/** Share of a view's sample points left to the sparse mesh rather than fetch one more image. */
const UNCOVERED = 0.02;
/** Sample points count within the view's field widened by this factor (a twentieth a side). */
const VIEW_MARGIN = 1.1;

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

/**
 * The cut's view of `camera` (lod/cut.js `makeView`: its frustum's planes), the tangents of its
 * half-fields times VIEW_MARGIN: where the repository keeps its sample points.
 */
function widenedView(camera) {
  const fovy = (360 / Math.PI) * Math.atan(VIEW_MARGIN * Math.tan(((camera.fovy ?? 45) * Math.PI) / 360));
  return makeView({ ...camera, up: camera.up ?? [0, 1, 0], fovy, width: camera.width ?? 1, height: camera.height ?? 1 }, null);
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
    this.levels = description.levels ?? 0;
    this.margin = description.refine_margin ?? 0;
    this.modelBox = description.model_box;
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
    this.slots = new Array(SLOTS).fill(null); // slot -> point key "level:x,y,z"
    this.loaded = new Set(); // "level:x,y,z,d" resident in its slot's layer
    this.empty = new Set(); // "level:x,y,z,d" known to show nothing
    this.inFlight = new Set();
    this.failed = new Map();
    this.lastEye = null;
    this.waiting = 0;
    this.stats = { bytes: 0, requests: 0, images: 0, empty: 0, errors: 0 };
    this.closed = false;
  }

  /** Spacing of refinement level `level`. */
  levelSpacing(level) {
    return this.spacing / 2 ** level;
  }

  /** Point `p` = [x, y, z] of level `level` in world space. */
  position(level, p) {
    const s = this.levelSpacing(level);
    return [0, 1, 2].map((a) => this.min[a] + p[a] * s);
  }

  /** Points per axis of level `level` (grid::level_points). */
  levelPoints(level) {
    return (this.n - 1) * 2 ** level + 1;
  }

  /**
   * The point named by its coarsest level (Grid::canonical): a point of level l with even
   * indices is level l - 1's with half of them.
   */
  static canonical(level, p) {
    while (level > 0 && p.every((v) => v % 2 === 0)) {
      p = p.map((v) => v / 2);
      level--;
    }
    return [level, p];
  }

  /** Whether level `level` keeps point `p` (Grid::refines: near the model's bounding box). */
  refines(level, p) {
    if (level === 0) return true;
    if (!this.modelBox) return false;
    const w = this.position(level, p);
    // (A thousandth of a spacing more, as the server: the lattice often lands exactly on the
    // margin, and such a point is then kept whatever the rounding.)
    const m = (this.margin + 1e-3) * this.levelSpacing(level);
    return [0, 1, 2].every((a) => w[a] >= this.modelBox[0][a] - m && w[a] <= this.modelBox[1][a] + m);
  }

  /**
   * Where images serve the view best, and at which level: `{eye, level}`. A 90° image of
   * `size` pixels at distance h from the target has texels as fine as the view's pixels
   * (field of view `fovy`, `height` pixels, at distance d) when h = d · tan(fovy / 2) · size /
   * height; the level is the coarsest whose spacing is at most LEVEL_SPACING · h, and a
   * coarser one where that level keeps no point there.
   */
  imageEye(camera) {
    const { eye, target } = camera;
    const d = Math.hypot(eye[0] - target[0], eye[1] - target[1], eye[2] - target[2]);
    const fovy = ((camera.fovy ?? 45) * Math.PI) / 180;
    const ratio = Math.min(1, (Math.tan(fovy / 2) * this.side) / Math.max(1, camera.height ?? this.side));
    const at = [0, 1, 2].map((a) => target[a] + (eye[a] - target[a]) * ratio);
    const h = d * ratio;
    let level = h > 0 ? Math.ceil(Math.log2(this.spacing / (LEVEL_SPACING * h))) : this.levels;
    level = Math.max(0, Math.min(this.levels, level));
    while (level > 0) {
      const s = this.levelSpacing(level);
      const p = [0, 1, 2].map((a) => Math.round((at[a] - this.min[a]) / s));
      if (this.refines(level, p)) break;
      level--;
    }
    return { eye: at, level };
  }

  /**
   * The `SLOTS` points of `level` nearest to `eye` (the image eye) among those it keeps on the
   * eye's side of the view's `target` (a point beyond it sees the surface from behind: its
   * rays point against the view's), as canonical keys.
   */
  nearest(eye, target, level, viewEye) {
    const n = this.levelPoints(level);
    const s = this.levelSpacing(level);
    const c = [0, 1, 2].map((a) => Math.min(n - 1, Math.max(0, (eye[a] - this.min[a]) / s)));
    const r = [0, 1, 2].map((a) => Math.round(c[a]));
    const cands = [];
    const view = [0, 1, 2].map((a) => target[a] - viewEye[a]);
    for (let dz = -3; dz <= 3; dz++) {
      for (let dy = -3; dy <= 3; dy++) {
        for (let dx = -3; dx <= 3; dx++) {
          const p = [r[0] + dx, r[1] + dy, r[2] + dz];
          if (p.some((v) => v < 0 || v >= n) || !this.refines(level, p)) continue;
          const w = this.position(level, p);
          const dist = Math.hypot(w[0] - eye[0], w[1] - eye[1], w[2] - eye[2]);
          const ahead = (target[0] - w[0]) * view[0] + (target[1] - w[1]) * view[1] + (target[2] - w[2]) * view[2];
          cands.push({ p, dist: ahead > 0 ? dist : dist + 1e6 });
        }
      }
    }
    cands.sort((a, b) => a.dist - b.dist);
    return cands.slice(0, SLOTS).map((c) => Repository.canonical(level, c.p));
  }

  /** Key of point `p` of level `level` (canonical). */
  static key(level, p) {
    return `${level}:${p.join(',')}`;
  }

  /** [level, p] of key `key`. */
  static parse(key) {
    const [l, p] = key.split(':');
    return [Number(l), p.split(',').map(Number)];
  }

  /** Face (0..5) of a point that sees direction `v`: its dominant axis, `2 axis + negative`. */
  face(v) {
    const a = [Math.abs(v[0]), Math.abs(v[1]), Math.abs(v[2])];
    const axis = a[0] >= a[1] && a[0] >= a[2] ? 0 : a[1] >= a[2] ? 1 : 2;
    return 2 * axis + (v[axis] >= 0 ? 0 : 1);
  }

  /**
   * Follows the view: chooses the points for `camera` (its eye), asks for the faces that see
   * the `drawn` nodes (bounds in `table.bounds`), and starts what fits in flight. `surface`,
   * where given, returns points on a drawn node's patch (a few of its vertices, as x, y, z
   * triples) or null where the patch is not resident.
   */
  update(camera, drawn, table, surface = null) {
    if (this.closed) return;
    const { eye, level } = this.imageEye(camera);
    const moved =
      !this.lastEye || level !== this.lastLevel || Math.hypot(eye[0] - this.lastEye[0], eye[1] - this.lastEye[1], eye[2] - this.lastEye[2]) > RESELECT * this.levelSpacing(level);
    if (moved) {
      this.lastEye = eye.slice();
      this.lastLevel = level;
      this.assign(this.nearest(eye, camera.target, level, camera.eye));
    }
    // The faces worth their bytes. At sample points of every drawn patch (points of its
    // surface within the view, or without its geometry its bounding cube's corners, shrunk by
    // half) an image is good if the shader would weigh it within BLEND of the best image there
    // (as the shader weighs them: by the angle between the image's ray and the view's, and
    // 1 / depth²). The face a point asks for is the one the shader picks for it, by the
    // direction from the image's point, so the samples must lie where the surface does: on a
    // flat patch the cube's corners lie half its radius above and below it, where they ask for
    // faces the surface does not need and miss faces it does, and corners outside the view ask
    // for faces no pixel shows. Images resident or on their way cover their samples; then,
    // greedily, the image good at most uncovered samples is wanted, until all but UNCOVERED of
    // them are covered: the few images that serve the view, not every face of every point that
    // sees some of it (nearby points see nearly the same).
    const b = table.bounds;
    const at = [];
    for (let s = 0; s < SLOTS; s++) {
      const key = this.slots[s];
      if (key === null) continue;
      const [level, p] = Repository.parse(key);
      at.push({ s, key, level, p, g: this.position(level, p) });
    }
    const ce = camera.eye;
    const now = performance.now();
    const samples = [];
    const candidates = new Map();
    const weights = [];
    const view = widenedView(camera);
    const q = [0, 0, 0];
    for (const node of drawn) {
      const points = surface ? surface(node) : null;
      const count = points ? points.length / 3 : 8;
      const r = 0.5 * b[node * 4 + 3];
      for (let k = 0; k < count; k++) {
        if (points) {
          q[0] = points[3 * k];
          q[1] = points[3 * k + 1];
          q[2] = points[3 * k + 2];
          if (!inFrustum(view, q[0], q[1], q[2])) continue;
        } else {
          q[0] = b[node * 4] + (k & 1 ? r : -r);
          q[1] = b[node * 4 + 1] + (k & 2 ? r : -r);
          q[2] = b[node * 4 + 2] + (k & 4 ? r : -r);
        }
        const e = [q[0] - ce[0], q[1] - ce[1], q[2] - ce[2]];
        const el = Math.hypot(e[0], e[1], e[2]) || 1;
        weights.length = 0;
        let best = 0;
        for (const a of at) {
          const v = [q[0] - a.g[0], q[1] - a.g[1], q[2] - a.g[2]];
          const d = this.face(v);
          const z = Math.abs(v[d >> 1]);
          const id = `${a.key},${d}`;
          if (z <= 0 || this.empty.has(id)) continue;
          const failedAt = this.failed.get(id);
          if (failedAt !== undefined && now - failedAt < 3000) continue;
          const c = (v[0] * e[0] + v[1] * e[1] + v[2] * e[2]) / (el * Math.hypot(v[0], v[1], v[2]));
          if (c <= 0) continue;
          const w = (Math.exp(SHARPNESS * (c - 1)) + 1e-6) / (z * z);
          weights.push({ id, a, d, w });
          best = Math.max(best, w);
        }
        const good = [];
        let covered = false;
        for (const { id, a, d, w } of weights) {
          if (w < BLEND * best) continue;
          good.push(id);
          if (!candidates.has(id)) candidates.set(id, { a, d });
          if (this.loaded.has(id) || this.inFlight.has(id)) covered = true;
        }
        if (good.length > 0 && !covered) samples.push(good);
      }
    }
    const wanted = [];
    let open = samples;
    const floor = UNCOVERED * samples.length;
    while (open.length > floor && wanted.length < LAYERS) {
      const count = new Map();
      for (const good of open) for (const id of good) count.set(id, (count.get(id) || 0) + 1);
      let pick = null;
      let most = 0;
      for (const [id, n] of count) {
        const c = candidates.get(id);
        // (Ties go to the point nearest the image eye: the lower slot.)
        if (n > most || (n === most && pick && c.a.s < candidates.get(pick).a.s)) {
          pick = id;
          most = n;
        }
      }
      if (!pick) break;
      const { a, d } = candidates.get(pick);
      wanted.push({ slot: a.s, level: a.level, p: a.p, d, id: pick, priority: wanted.length });
      open = open.filter((good) => !good.includes(pick));
    }
    wanted.sort((a, b) => a.priority - b.priority);
    this.waiting = wanted.length;
    // A user's bandwidth cap (token bucket holding at most B·T bytes, as patch streaming's).
    const cap = this.settings.bandwidth;
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
    const keys = points.map(([level, p]) => Repository.key(level, p));
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
      const w = this.position(...Repository.parse(key));
      this.points[s].set(w[0], w[1], w[2], 1);
    }
  }

  async request(w) {
    const key = Repository.key(w.level, w.p);
    this.inFlight.add(w.id);
    this.stats.requests++;
    try {
      const level = w.level > 0 ? `&level=${w.level}` : '';
      const url = `/api/v1/models/${this.modelId}/lumigraph/images/${w.p[0]}/${w.p[1]}/${w.p[2]}/${w.d}?v=${this.d.job_id}${level}`;
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
      put(this.normal, img.normalAxis === null ? normal : worldOrder(normal, img.normalAxis), this.side);
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
