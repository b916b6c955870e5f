// View-dependent streaming of patches: runs the cut (cut.js) for the current camera, fetches
// the patches it asks for, largest visible projected error first, with a bounded number of
// requests and bytes in flight (budget.js, eq. 15), decodes them in workers, and keeps the GPU
// memory within budget (cache.js). Neighbouring patches are contiguous in the file (locality
// order), so a run of them is fetched with one Range request on `/lod/file`.

import { Cut, makeView } from './cut.js';
import { PatchCache } from './cache.js';
import { Throughput, fitBudget } from './budget.js';
import { DEFAULT_ALPHA, DEFAULT_RMAX } from './foveation.js';

/** Settings a user can change (toolbar). */
export const DEFAULT_SETTINGS = {
  pixelError: 1, // target screen-space error, pixels
  bandwidth: 0, // cap in bytes/s; 0 = as measured
  maxWait: 1.0, // longest wait per refinement, seconds (T of eq. 15)
  maxInFlight: 6,
  gpuBudget: 384 << 20, // resident patch bytes
  alpha: DEFAULT_ALPHA, // foveation distortion
  rMax: DEFAULT_RMAX,
  batchBytes: 1 << 20, // largest Range request
};

const RETRY_MS = 3000;

/**
 * RGBA bytes a textured patch's atlas is assumed to take per byte of its blob before the
 * image's size is known: a low guess (JPEGs of quality 85 decode to some 10–30 times their
 * size), so scheduling errs towards fetching; the cache counts the real size (`patchBytes`)
 * and evicts accordingly.
 */
const TEXTURE_BYTES_PER_BLOB_BYTE = 10;

/**
 * Bytes a decoded patch holds (GPU buffers and the CPU copy of its ids); a textured patch adds
 * its coordinates and its texture, width × height × 4 (RGBA8, no mipmaps).
 */
export function patchBytes(p) {
  const texture = p.uvs
    ? p.uvs.byteLength + ((p.imageWidth || 0) * (p.imageHeight || 0) + (p.normalMapWidth || 0) * (p.normalMapHeight || 0)) * 4
    : 0;
  return p.positions.byteLength + p.normals.byteLength + (p.colors ? p.colors.byteLength : 0) + p.indices.byteLength + p.ids.byteLength + p.vertexCount * 2 + texture;
}

export class Streamer {
  /**
   * @param {{modelId: number, table: object, pool: object, onLoad: Function, onEvict: Function,
   *   onChange: Function, settings?: object, fetch?: Function}} o
   */
  constructor(o) {
    this.modelId = o.modelId;
    this.table = o.table;
    this.pool = o.pool;
    this.onLoad = o.onLoad;
    this.onEvict = o.onEvict;
    this.onChange = o.onChange;
    this.fetch = o.fetch || ((url, init) => fetch(url, init));
    this.settings = { ...DEFAULT_SETTINGS, ...(o.settings || {}) };
    this.cut = new Cut(this.table);
    this.resident = new Uint8Array(this.table.nodeCount);
    this.cache = new PatchCache(this.settings.gpuBudget);
    this.throughput = new Throughput();
    this.inFlight = new Map(); // node -> bytes
    this.inFlightBytes = 0;
    this.failed = new Map(); // node -> time of failure
    this.foveae = [];
    this.probes = null; // where the fovea error is measured (default: the foveae)
    // Visibility feedback (cut.js `wanted`): drawn nodes the last visibility pass showed no
    // pixel of, and the camera and drawn set that pass saw.
    this.occluded = new Uint8Array(this.table.nodeCount);
    this.visibilityKey = null;
    this.viewKey = null;
    this.tokens = 0;
    this.tokensAt = performance.now();
    this.stats = { bytes: 0, requests: 0, patches: 0, evicted: 0, errors: 0, bytesByLevel: [] };
    this.last = null;
    this.closed = false;
  }

  setSettings(changes) {
    Object.assign(this.settings, changes);
    this.cache.budget = this.settings.gpuBudget;
  }

  setFoveae(points) {
    this.foveae = points.map((p) => [p[0], p[1], p[2]]);
  }

  /** Effective bandwidth B: measured, capped by the user's setting. */
  bandwidth() {
    const measured = this.throughput.estimate();
    return this.settings.bandwidth > 0 ? Math.min(this.settings.bandwidth, measured) : measured;
  }

  /**
   * Recomputes the cut for `camera` ({eye, target, up, fovy, width, height}), evicts what is no
   * longer needed, starts the requests that fit the budget; returns the cut's result.
   */
  update(camera) {
    const foveation = {
      target: this.settings.pixelError,
      foveae: this.foveae,
      alpha: this.settings.alpha,
      rMax: this.settings.rMax,
      modelRadius: this.table.radius,
    };
    const view = makeView(camera, foveation);
    const result = this.cut.run(view, this.resident, 0, this.probes, this.occluded);
    this.viewKey = viewKey(camera, result.draw);
    this.cache.touch(result.draw);
    for (const node of this.cache.evict(this.cut.pinned)) {
      this.resident[node] = 0;
      this.stats.evicted++;
      this.onEvict(node);
    }
    this.schedule(result.requests);
    result.inFlight = this.inFlight.size;
    this.last = result;
    return result;
  }

  /** Whether nothing more is wanted for the last camera (the cut reached its target). */
  settled() {
    return !!this.last && this.last.requests.length === 0 && this.inFlight.size === 0 && !this.visibilityStale();
  }

  /** Whether the last cut's camera or drawn set differ from what the last visibility pass saw. */
  visibilityStale() {
    return this.viewKey !== this.visibilityKey;
  }

  /**
   * Records a visibility pass of the last cut: `seen` holds the drawn nodes that covered a
   * sample. Nodes too small on screen to be sure of (`minRadiusPx`) count as shown.
   */
  setVisibility(camera, seen, minRadiusPx) {
    const draw = this.last ? this.last.draw : [];
    const t = this.table;
    const b = t.bounds;
    const pixelScale = camera.height / (2 * Math.tan((camera.fovy * Math.PI) / 360));
    const e = camera.eye;
    const next = new Uint8Array(t.nodeCount);
    for (const n of draw) {
      if (seen.has(n)) continue;
      const d = Math.hypot(b[n * 4] - e[0], b[n * 4 + 1] - e[1], b[n * 4 + 2] - e[2]);
      const r = b[n * 4 + 3];
      if (d > r && (r * pixelScale) / d >= minRadiusPx) next[n] = 1;
    }
    this.occluded = next;
    this.visibilityKey = this.viewKey;
  }

  schedule(requests) {
    if (this.closed) return;
    const now = performance.now();
    const t = this.table;
    const candidates = [];
    for (const r of requests) {
      if (this.inFlight.has(r.node)) continue;
      const failedAt = this.failed.get(r.node);
      if (failedAt !== undefined && now - failedAt < RETRY_MS) continue;
      candidates.push({ node: r.node, priority: r.priority, bytes: t.length[r.node] });
    }
    if (candidates.length === 0) return;
    candidates.sort((a, b) => b.priority - a.priority || t.offset[a.node] - t.offset[b.node]);
    // Memory: stop when what is wanted no longer fits beside the pinned set.
    const affordable = [];
    let extra = 0;
    for (const c of candidates) {
      let estimate = t.vertices[c.node] * 34 + t.triangles[c.node] * 6;
      if (t.hasTexture) estimate += t.vertices[c.node] * 8 + t.length[c.node] * TEXTURE_BYTES_PER_BLOB_BYTE;
      if (!this.cache.fits(extra + estimate, this.cut.pinned) && c.priority !== Infinity) break;
      extra += estimate;
      affordable.push(c);
    }
    // Pacing for a user bandwidth cap (token bucket holding at most B·T bytes).
    let paced = affordable;
    if (this.settings.bandwidth > 0) {
      const cap = this.settings.bandwidth;
      this.tokens = Math.min(cap * this.settings.maxWait, this.tokens + ((now - this.tokensAt) / 1000) * cap);
      this.tokensAt = now;
      paced = [];
      let tokens = this.tokens;
      for (const c of affordable) {
        // A patch larger than the bucket goes alone, once the bucket is full.
        const alone = paced.length === 0 && this.inFlight.size === 0 && tokens >= cap * this.settings.maxWait * 0.999;
        if (c.bytes > tokens && !alone) break;
        tokens -= c.bytes;
        paced.push(c);
      }
      this.tokens = tokens;
      if (paced.length < affordable.length && !this.paceTimer) {
        this.paceTimer = setTimeout(() => {
          this.paceTimer = null;
          this.onChange();
        }, 50);
      }
    }
    const chosen = fitBudget(paced, {
      bandwidth: this.bandwidth(),
      maxWait: this.settings.maxWait,
      inFlightBytes: this.inFlightBytes,
      inFlight: this.inFlight.size,
      maxInFlight: this.settings.maxInFlight,
    });
    for (const run of this.batches(chosen)) this.request(run);
  }

  /** Groups chosen nodes into runs of contiguous blobs (one Range request each). */
  batches(chosen) {
    const t = this.table;
    const sorted = chosen.map((c) => c.node).sort((a, b) => t.offset[a] - t.offset[b]);
    const runs = [];
    let run = [];
    let runBytes = 0;
    for (const node of sorted) {
      const prev = run[run.length - 1];
      if (run.length > 0 && t.offset[prev] + t.length[prev] === t.offset[node] && runBytes + t.length[node] <= this.settings.batchBytes) {
        run.push(node);
        runBytes += t.length[node];
      } else {
        if (run.length > 0) runs.push(run);
        run = [node];
        runBytes = t.length[node];
      }
    }
    if (run.length > 0) runs.push(run);
    return runs;
  }

  async request(run) {
    const t = this.table;
    let bytes = 0;
    for (const node of run) {
      this.inFlight.set(node, t.length[node]);
      bytes += t.length[node];
    }
    this.inFlightBytes += bytes;
    this.stats.requests++;
    this.throughput.start(performance.now());
    let received = 0;
    try {
      const base = `/api/v1/models/${this.modelId}/lod`;
      let buffers;
      if (run.length === 1) {
        const res = await this.fetch(`${base}/patches/${run[0]}`, { credentials: 'same-origin' });
        if (!res.ok) throw new Error(`patch ${run[0]}: HTTP ${res.status}`);
        const buf = await res.arrayBuffer();
        buffers = [buf];
        received = buf.byteLength;
      } else {
        const first = t.offset[run[0]];
        const last = run[run.length - 1];
        const end = t.offset[last] + t.length[last] - 1;
        const res = await this.fetch(`${base}/file`, { credentials: 'same-origin', headers: { Range: `bytes=${first}-${end}` } });
        if (res.status !== 206) throw new Error(`patches ${run.join(',')}: HTTP ${res.status}`);
        const all = await res.arrayBuffer();
        received = all.byteLength;
        if (all.byteLength !== end - first + 1) throw new Error('short range response');
        buffers = run.map((node) => all.slice(t.offset[node] - first, t.offset[node] - first + t.length[node]));
      }
      this.stats.bytes += received;
      const byLevel = this.stats.bytesByLevel;
      for (const node of run) {
        const level = t.level[node];
        while (byLevel.length <= level) byLevel.push(0);
        byLevel[level] += t.length[node];
      }
      this.throughput.finish(performance.now(), received);
      received = -1;
      await Promise.all(run.map((node, k) => this.decoded(node, buffers[k])));
    } catch (e) {
      if (received >= 0) this.throughput.finish(performance.now(), received);
      this.stats.errors++;
      console.warn('meshwiki viewer:', e.message || e);
      const now = performance.now();
      for (const node of run) if (!this.resident[node]) this.failed.set(node, now);
    } finally {
      for (const node of run) this.inFlight.delete(node);
      this.inFlightBytes -= bytes;
      if (!this.closed) this.onChange();
    }
  }

  async decoded(node, buffer) {
    if (this.closed || this.resident[node]) return;
    try {
      const patch = await this.pool.decode(buffer, this.table.grid, this.table.crc[node]);
      if (this.closed || this.resident[node]) return;
      this.resident[node] = 1;
      this.failed.delete(node);
      this.cache.add(node, patchBytes(patch));
      this.stats.patches++;
      this.onLoad(node, patch);
    } catch (e) {
      this.stats.errors++;
      this.failed.set(node, performance.now());
      console.warn(`meshwiki viewer: patch ${node}:`, e.message || e);
    }
  }

  close() {
    this.closed = true;
    clearTimeout(this.paceTimer);
  }
}

/** Identity of a camera and drawn set (what a visibility pass depends on). */
function viewKey(c, draw) {
  let h = 0;
  for (const n of draw) h = (Math.imul(h, 31) + n + 1) | 0;
  return `${c.eye.join(',')};${c.target.join(',')};${c.up.join(',')};${c.fovy};${c.width}x${c.height};${draw.length};${h}`;
}
