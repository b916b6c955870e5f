// The parts of the model as the viewer knows them: the part records and their assigned
// contents (embedded in the page, refreshed by live events), their vertex sets (roaring
// bitmaps of original ids) and, per resident patch, which of its vertices belong to which part.
// Marks are exact at every level of detail: a patch vertex belongs to a part iff its original
// id is in the part's set (system paper §2.1.2: the Part ID is recorded on the vertices).

import { RoaringBitmap } from './roaring.js';

async function getJson(url) {
  const res = await fetch(url, { credentials: 'same-origin', headers: { Accept: 'application/json' } });
  if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
  return res.json();
}

export class PartStore {
  /**
   * @param {number} modelId
   * @param {object[]} parts part records with their `contents`, as embedded in the page
   * @param {number} modelRadius
   * @param {number} modelVertices vertices of the full-resolution scan
   */
  constructor(modelId, parts, modelRadius, modelVertices) {
    this.modelId = modelId;
    this.modelRadius = modelRadius;
    this.modelVertices = Math.max(1, modelVertices || 1);
    this.parts = new Map();
    this.membership = new Map(); // node -> Map(partId -> Uint32Array of local vertex indices)
    this.patches = new Map(); // node -> {ids, positions, normals}
    this.listeners = new Set();
    for (const p of parts) this.put(p, p.contents || []);
  }

  onChange(fn) {
    this.listeners.add(fn);
  }

  emit(what) {
    for (const fn of this.listeners) fn(what);
  }

  put(part, contents) {
    const old = this.parts.get(part.id);
    const entry = {
      id: part.id,
      part,
      contents,
      bitmap: null,
      extent: 0,
      normal: [0, 0, 0],
      matched: 0,
      version: part.updated_at,
    };
    if (old && old.version === part.updated_at && old.bitmap) {
      entry.bitmap = old.bitmap;
      entry.extent = old.extent;
      entry.normal = old.normal;
      entry.matched = old.matched;
    }
    this.parts.set(part.id, entry);
    return entry;
  }

  /** Title shown on the label: the first assigned content's title, else "Part N". */
  title(id) {
    const e = this.parts.get(id);
    if (!e) return '';
    return e.contents.length > 0 ? e.contents[0].title : `Part ${id}`;
  }

  /** The part's extent: from its matched vertices, else estimated from its vertex count. */
  extent(id) {
    const e = this.parts.get(id);
    if (!e) return 0;
    if (e.matched > 0) return Math.max(e.extent, this.modelRadius * 0.005);
    const fraction = e.part.vertex_count / this.modelVertices;
    return Math.max(this.modelRadius * 0.01, this.modelRadius * 2 * Math.sqrt(fraction));
  }

  /** Unit mean normal of the matched vertices, or null. */
  normal(id) {
    const e = this.parts.get(id);
    if (!e) return null;
    const l = Math.hypot(...e.normal);
    return l > 0 ? e.normal.map((v) => v / l) : null;
  }

  /** Fetches the vertex sets not loaded yet, then indexes the resident patches again. */
  async loadBitmaps() {
    const jobs = [];
    for (const e of this.parts.values()) {
      if (e.bitmap || e.part.vertex_count === 0) continue;
      jobs.push(
        fetch(`/api/v1/parts/${e.id}/vertices`, { credentials: 'same-origin' })
          .then((r) => (r.ok ? r.arrayBuffer() : Promise.reject(new Error(`vertices of part ${e.id}: HTTP ${r.status}`))))
          .then((buf) => {
            if (this.parts.get(e.id) === e) e.bitmap = RoaringBitmap.deserialize(buf);
          })
          .catch((err) => console.warn('meshwiki viewer:', err.message)),
      );
    }
    if (jobs.length === 0) return;
    await Promise.all(jobs);
    this.reindexAll();
    this.emit('bitmaps');
  }

  /** Records a resident patch and finds the parts' vertices in it. */
  addPatch(node, patch) {
    this.patches.set(node, patch);
    this.indexPatch(node);
  }

  removePatch(node) {
    this.patches.delete(node);
    this.membership.delete(node);
  }

  indexPatch(node) {
    const patch = this.patches.get(node);
    const found = new Map();
    for (const e of this.parts.values()) {
      const list = this.match(e, patch);
      if (list) found.set(e.id, list);
    }
    this.membership.set(node, found);
  }

  reindexAll() {
    for (const e of this.parts.values()) {
      e.extent = 0;
      e.matched = 0;
      e.normal = [0, 0, 0];
    }
    for (const node of this.patches.keys()) this.indexPatch(node);
  }

  match(e, patch) {
    if (!e.bitmap) return null;
    const { ids, positions, normals } = patch;
    const c = e.part.center;
    const out = [];
    for (let v = 0; v < ids.length; v++) {
      if (!e.bitmap.has(ids[v])) continue;
      out.push(v);
      const d = Math.hypot(positions[v * 3] - c[0], positions[v * 3 + 1] - c[1], positions[v * 3 + 2] - c[2]);
      if (d > e.extent) e.extent = d;
      e.normal[0] += normals[v * 3];
      e.normal[1] += normals[v * 3 + 1];
      e.normal[2] += normals[v * 3 + 2];
      e.matched++;
    }
    return out.length ? Uint32Array.from(out) : null;
  }

  /** Parts whose vertex sets hold any of `ids` (original vertex ids under the cursor). */
  partsWithAny(ids) {
    const out = [];
    for (const e of this.parts.values()) {
      if (e.bitmap && ids.some((id) => e.bitmap.has(id))) out.push(e.id);
    }
    return out;
  }

  /** Local vertex indices of part `id` in patch `node`. */
  verticesIn(node, id) {
    const m = this.membership.get(node);
    return (m && m.get(id)) || null;
  }

  /** Refetches one part and its contents (live events). */
  async reloadPart(id) {
    try {
      const [part, contents] = await Promise.all([getJson(`/api/v1/parts/${id}`), getJson(`/api/v1/parts/${id}/contents`)]);
      if (part.model_id !== this.modelId) return;
      this.put(part, contents);
      await this.loadBitmaps();
      this.emit('parts');
    } catch (err) {
      console.warn('meshwiki viewer:', err.message);
    }
  }

  removePart(id) {
    if (!this.parts.delete(id)) return;
    for (const m of this.membership.values()) m.delete(id);
    this.emit('parts');
  }

  async reloadContents(id) {
    const e = this.parts.get(id);
    if (!e) return this.reloadPart(id);
    try {
      e.contents = await getJson(`/api/v1/parts/${id}/contents`);
      this.emit('parts');
    } catch (err) {
      console.warn('meshwiki viewer:', err.message);
    }
  }

  /** A content changed: refresh the parts that show it. */
  async contentChanged(contentId) {
    const affected = [...this.parts.values()].filter((e) => e.contents.some((c) => c.id === contentId));
    await Promise.all(affected.map((e) => this.reloadContents(e.id)));
  }

  /** Reloads every part (after a missed event). */
  async reloadAll() {
    try {
      const parts = await getJson(`/api/v1/models/${this.modelId}/parts`);
      const seen = new Set(parts.map((p) => p.id));
      for (const id of [...this.parts.keys()]) if (!seen.has(id)) this.parts.delete(id);
      await Promise.all(parts.map((p) => this.reloadPart(p.id)));
      this.emit('parts');
    } catch (err) {
      console.warn('meshwiki viewer:', err.message);
    }
  }
}
