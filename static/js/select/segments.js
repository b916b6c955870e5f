// Suggested regions (issue 13; the mesh-segmentation paper's surface segments, §3.1): while
// the *Segments* tool is active, the segment under the cursor at the chosen scale is
// previewed — its exact vertex set (GET /api/v1/models/{id}/segments/{scale}/vertices
// ?vertex=V) highlighted like a draft — and a click selects it on the server (the
// controller sends `"tool": "segment"`). Segments already fetched answer later hovers from
// memory (a bitmap holding the vertex is its segment), so moving within a segment costs no
// request; one request runs at a time and only the newest hover is followed.

import { RoaringBitmap } from '../parts/roaring.js';
import { DraftHighlight } from './highlight.js';

/** Segments kept per scale (most recently used first). */
const KEEP = 24;

export class SegmentPreview {
  /**
   * @param {number} modelId
   * @param {import('./api.js').Api} api
   * @param {number} radius model radius
   * @param {number} vertices vertices of the full-resolution scan
   * @param {() => void} changed called when the previewed segment changes
   */
  constructor(modelId, api, radius, vertices, changed) {
    this.modelId = modelId;
    this.api = api;
    this.changed = changed;
    this.highlight = new DraftHighlight(modelId, radius, vertices);
    this.scales = null; // [{scale, segments}], finest first
    this.scale = null;
    this.unavailable = ''; // why the model has no segments
    this.loading = null;
    this.cache = new Map(); // scale -> [{id, bitmap}]
    this.wanted = null; // newest hovered vertex
    this.fetching = false;
    this.shown = null; // {scale, id, size}
  }

  /** Loads the model's scales once (the suggested one becomes the current scale). */
  load() {
    if (!this.loading) {
      this.loading = this.api
        .get(`/api/v1/models/${this.modelId}/segments`)
        .then((d) => {
          this.scales = d.scales;
          if (this.scale === null) this.scale = d.suggested_scale;
        })
        .catch((e) => {
          this.unavailable = e.message;
          this.loading = null;
        });
    }
    return this.loading;
  }

  /** Sets the scale (0: finest) and drops the preview. */
  setScale(scale) {
    if (!this.scales || scale === this.scale || scale < 0 || scale >= this.scales.length) return;
    this.scale = scale;
    this.hover(this.wanted);
  }

  /** Segments at the current scale. */
  get count() {
    return this.scales && this.scale !== null ? this.scales[this.scale].segments : 0;
  }

  /** Previews the segment holding original vertex `vertex` (null: none). */
  hover(vertex) {
    this.wanted = vertex;
    if (vertex === null || vertex === undefined || this.scale === null) {
      this.show(null);
      return;
    }
    const hit = this.cached(this.scale, vertex);
    if (hit) {
      this.show(hit);
      return;
    }
    if (!this.fetching) this.fetch(this.scale, vertex);
  }

  cached(scale, vertex) {
    const list = this.cache.get(scale) || [];
    const i = list.findIndex((e) => e.bitmap.has(vertex));
    if (i < 0) return null;
    const [e] = list.splice(i, 1);
    list.unshift(e);
    return e;
  }

  async fetch(scale, vertex) {
    this.fetching = true;
    try {
      const res = await this.api.send('GET', `/api/v1/models/${this.modelId}/segments/${scale}/vertices?vertex=${vertex}`);
      const bitmap = RoaringBitmap.deserialize(await res.arrayBuffer());
      const entry = { scale, id: Number(res.headers.get('X-Segment')), bitmap };
      const list = this.cache.get(scale) || [];
      list.unshift(entry);
      if (list.length > KEEP) list.length = KEEP;
      this.cache.set(scale, list);
    } catch (e) {
      // A vertex in no segment (404) previews nothing; other failures are not the hover's to report.
      if (e.status !== 404) console.warn('meshwiki segments:', e.message);
    } finally {
      this.fetching = false;
    }
    // Follow the newest hover (it may have moved on while this one was fetched).
    const v = this.wanted;
    if (v === null) return;
    const hit = this.cached(this.scale, v);
    if (hit) this.show(hit);
    else if (!(scale === this.scale && v === vertex)) this.fetch(this.scale, v);
  }

  show(entry) {
    const key = entry ? `${entry.scale}:${entry.id}` : null;
    const was = this.shown ? `${this.shown.scale}:${this.shown.id}` : null;
    if (key === was) return;
    this.shown = entry ? { scale: entry.scale, id: entry.id, size: entry.bitmap.size } : null;
    this.highlight.showSet(key, entry ? entry.bitmap : null);
    this.changed();
  }

  addPatch(node, patch) {
    this.highlight.addPatch(node, patch);
  }

  removePatch(node) {
    this.highlight.removePatch(node);
  }

  /** Local vertex indices of the previewed segment in patch `node`, or null. */
  verticesIn(node) {
    return this.highlight.verticesIn(node);
  }
}
