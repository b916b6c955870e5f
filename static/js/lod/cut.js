// View-dependent cut with streaming (docs/FORMAT.md "Cut rule"; system paper §3.3).
//
// A group is *refined* (its members drawn instead of its products) when its projected error
// exceeds the pixel threshold at its sphere (foveated, see foveation.js). Groups are decided
// from the coarsest level down, so a group can only be refined once all its products are in
// the current cut; and, because patches stream in, only when every visible member is loaded.
// Until then its products stay drawn, so no hole ever shows (the paper's "insert the ancestor
// node into the rendering list"). A group whose error became acceptable again stays refined
// until its products are back in memory. Roots are the fallback of everything and are always
// requested first.
//
// Culling (frustum on `bounds`, back-face on `cone`) only removes nodes from what is drawn and
// from what must be loaded.

import { foveaDistance, thresholdAt } from './foveation.js';

const EPS = 1.1920929e-7;

/** Camera quantities the cut needs, from eye/target/up/fovy and the viewport height. */
export function makeView({ eye, target, up, fovy, width, height }, foveation) {
  const f = normalize(sub(target, eye));
  const r = normalize(cross(f, up));
  const u = cross(r, f);
  const halfV = Math.tan((fovy * Math.PI) / 360);
  const halfH = halfV * (width / Math.max(height, 1));
  const plane = (n) => {
    const m = normalize(n);
    return [m[0], m[1], m[2], -dot(m, eye)];
  };
  return {
    eye,
    forward: f,
    planes: [
      plane(add(r, scale(f, halfH))),
      plane(add(scale(r, -1), scale(f, halfH))),
      plane(add(u, scale(f, halfV))),
      plane(add(scale(u, -1), scale(f, halfV))),
    ],
    pixelScale: height / (2 * halfV),
    eyeLength: Math.hypot(eye[0], eye[1], eye[2]),
    foveation,
  };
}

/** Screen-space size in pixels of object-space `error` at a sphere (∞ inside it). */
export function projectedError(view, error, cx, cy, cz, r) {
  if (error <= 0) return 0;
  if (!Number.isFinite(error)) return Infinity;
  const e = view.eye;
  const d = Math.hypot(e[0] - cx, e[1] - cy, e[2] - cz) - r;
  if (d <= EPS * Math.max(view.eyeLength, 1)) return Infinity;
  return (error * view.pixelScale) / d;
}

/** Whether a sphere (a point where `r` is 0) lies at least partly inside the view's frustum. */
export function inFrustum(view, x, y, z, r = 0) {
  for (const p of view.planes) {
    if (p[0] * x + p[1] * y + p[2] * z + p[3] < -r) return false;
  }
  return true;
}

function nodeVisible(t, view, i) {
  const b = t.bounds;
  const cx = b[i * 4];
  const cy = b[i * 4 + 1];
  const cz = b[i * 4 + 2];
  const r = b[i * 4 + 3];
  const e = view.eye;
  const f = view.forward;
  const tx = cx - e[0];
  const ty = cy - e[1];
  const tz = cz - e[2];
  if (tx * f[0] + ty * f[1] + tz * f[2] < -r) return false;
  if (!inFrustum(view, cx, cy, cz, r)) return false;
  const cutoff = t.cone[i * 4 + 3];
  if (cutoff >= 1) return true;
  const along = tx * t.cone[i * 4] + ty * t.cone[i * 4 + 1] + tz * t.cone[i * 4 + 2];
  return !(along >= cutoff * Math.hypot(tx, ty, tz) + r);
}

/** Per-model cut state, reused frame after frame. */
export class Cut {
  constructor(table) {
    this.t = table;
    this.inCut = new Uint8Array(table.nodeCount);
    this.visible = new Uint8Array(table.nodeCount);
    this.refined = new Uint8Array(table.groupCount);
    /** Per group: refinement wanted for this view, after occlusion (see `wanted`). */
    this.demand = new Uint8Array(table.groupCount);
    this.hidden = new Uint8Array(table.groupCount);
    this.ratio = new Float64Array(table.groupCount);
    /** Nodes that must stay in memory: the cut and, as fallback, the products it replaced. */
    this.pinned = new Uint8Array(table.nodeCount);
    /**
     * Groups of at most this error never refine: the sparse mesh of a model that keeps its
     * geometry on the server (lod::sparse: its nodes' parent error exceeds the floor). -1: none.
     */
    this.floor = -1;
  }

  /**
   * Distance (model radii) from the nearest fovea to the nearest of group `g`'s own patches,
   * members and products: a patch whose bounds hold a fovea then has its group, and so itself,
   * refined to the target exactly.
   */
  groupFoveaDistance(g, fov) {
    if (fov.foveae.length === 0) return Infinity;
    const b = this.t.bounds;
    let d = Infinity;
    for (const list of [this.t.members[g], this.t.products[g]]) {
      for (const m of list) {
        d = Math.min(d, foveaDistance(fov.foveae, b[m * 4], b[m * 4 + 1], b[m * 4 + 2], b[m * 4 + 3], fov.modelRadius));
      }
    }
    return d;
  }

  /**
   * Which groups want refinement for this view (`demand`, with `ratio` the projected error over
   * the foveated threshold). Occlusion (visibility feedback, as virtual texturing's feedback
   * buffer): a node is hidden when the last visibility pass drew it and it showed no pixel, or
   * when the group it is a member of is hidden; a group is hidden when all its visible
   * products are (coarsest first, so hiddenness flows down to the patches under a hidden
   * one). A hidden group does not refine, so hidden surface is not streamed at full
   * resolution.
   *
   * A group also wants refinement when a finer group that does needs it, since a group refines
   * only once all its products are in the cut (finest first, so that need is known): a hidden
   * neighbour, or a coarse group whose foveated threshold is larger than a descendant's
   * (foveation.js), then never holds a wanted refinement back.
   */
  wanted(view, occluded) {
    const t = this.t;
    const { visible, demand, ratio, hidden } = this;
    const fov = view.foveation;
    const gs = t.groupSphere;
    const order = t.groupOrder;
    hidden.fill(0);
    if (occluded) {
      for (const g of order) {
        let anyVisible = false;
        let shown = false;
        for (const p of t.products[g]) {
          if (!visible[p]) continue;
          anyVisible = true;
          const up = t.memberOf[p];
          if (!occluded[p] && !(up >= 0 && hidden[up])) {
            shown = true;
            break;
          }
        }
        hidden[g] = anyVisible && !shown ? 1 : 0;
      }
    }
    for (let k = order.length - 1; k >= 0; k--) {
      const g = order[k];
      const r = projectedError(view, t.groupError[g], gs[g * 4], gs[g * 4 + 1], gs[g * 4 + 2], gs[g * 4 + 3]) / thresholdAt(fov, this.groupFoveaDistance(g, fov));
      ratio[g] = r;
      let want = r > 1 && !hidden[g];
      if (!want) {
        for (const m of t.members[g]) {
          const producer = t.producer[m];
          if (producer >= 0 && demand[producer]) want = true;
        }
      }
      demand[g] = want ? 1 : 0;
    }
  }

  /**
   * Decides what to draw and what to load.
   * @param view from makeView
   * @param {Uint8Array} resident 1 for nodes whose patch is decoded and on the GPU
   * @param {number} foveaRadius distance (model radii) from a fovea within which drawn patches count for `foveaError`
   *   (0: the patches whose bounds hold it)
   * @param {number[][]|null} probes points where `foveaError` is measured instead of the foveae
   * @param {Uint8Array|null} occluded 1 for nodes drawn in the last visibility pass of this
   *   view that showed no pixel (see `wanted`)
   * @returns {{draw: number[], requests: {node: number, priority: number}[], triangles: number,
   *   maxError: number, maxRatio: number, foveaError: number, pending: number}}
   */
  run(view, resident, foveaRadius = 0, probes = null, occluded = null) {
    const t = this.t;
    const { inCut, visible, refined, pinned } = this;
    const fov = view.foveation;
    const requests = [];
    const requested = new Set();
    const ask = (node, priority) => {
      if (!resident[node] && !requested.has(node)) {
        requested.add(node);
        requests.push({ node, priority });
      }
    };
    for (let i = 0; i < t.nodeCount; i++) visible[i] = nodeVisible(t, view, i) ? 1 : 0;
    inCut.fill(0);
    pinned.fill(0);
    for (const r of t.roots) {
      inCut[r] = 1;
      ask(r, Infinity);
    }
    this.wanted(view, occluded);
    const { demand, ratio: ratios } = this;
    let pending = 0;
    for (const g of t.groupOrder) {
      refined[g] = 0;
      if (t.groupError[g] <= this.floor) continue;
      const products = t.products[g];
      const members = t.members[g];
      let allIn = true;
      for (const p of products) if (!inCut[p]) allIn = false;
      if (!allIn) continue;
      const ratio = ratios[g];
      const want = demand[g] === 1;
      let membersReady = true;
      for (const m of members) if (visible[m] && !resident[m]) membersReady = false;
      let productsReady = true;
      for (const p of products) if (visible[p] && !resident[p]) productsReady = false;
      const refine = membersReady && (want || !productsReady);
      if (want && !membersReady) {
        pending++;
        for (const m of members) if (visible[m]) ask(m, ratio);
      } else if (refine && !want) {
        for (const p of products) if (visible[p]) ask(p, ratio);
      }
      if (refine) {
        // (A group none of whose members is visible refines for free, so the visible
        // descendants of its products' neighbours are not held back.)
        refined[g] = 1;
        for (const p of products) {
          inCut[p] = 0;
          pinned[p] = 1;
        }
        for (const m of members) inCut[m] = 1;
      }
    }
    const draw = [];
    let triangles = 0;
    let maxError = 0;
    let maxRatio = 0;
    let foveaError = 0;
    const ls = t.lodSphere;
    for (let i = 0; i < t.nodeCount; i++) {
      if (inCut[i]) pinned[i] = 1;
      if (!inCut[i] || !visible[i] || !resident[i]) continue;
      draw.push(i);
      triangles += t.triangles[i];
      // What no pixel shows has no visible error.
      if (occluded && occluded[i]) continue;
      const cx = ls[i * 4];
      const cy = ls[i * 4 + 1];
      const cz = ls[i * 4 + 2];
      const cr = ls[i * 4 + 3];
      const err = projectedError(view, t.lodError[i], cx, cy, cz, cr);
      if (err > maxError) maxError = err;
      const b = t.bounds;
      const ratio = err / thresholdAt(fov, foveaDistance(fov.foveae, b[i * 4], b[i * 4 + 1], b[i * 4 + 2], b[i * 4 + 3], fov.modelRadius));
      if (ratio > maxRatio) maxRatio = ratio;
      const points = probes || fov.foveae;
      if (points.length > 0) {
        for (const f of points) {
          const d = Math.hypot(f[0] - b[i * 4], f[1] - b[i * 4 + 1], f[2] - b[i * 4 + 2]) - b[i * 4 + 3];
          if (d <= foveaRadius * fov.modelRadius && err > foveaError) foveaError = err;
        }
      }
    }
    return { draw, requests, triangles, maxError, maxRatio, foveaError, pending };
  }
}

function sub(a, b) {
  return [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
}
function add(a, b) {
  return [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
}
function scale(a, s) {
  return [a[0] * s, a[1] * s, a[2] * s];
}
function dot(a, b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}
function normalize(a) {
  const l = Math.hypot(a[0], a[1], a[2]) || 1;
  return [a[0] / l, a[1] / l, a[2] / l];
}
