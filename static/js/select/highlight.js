// The draft's exact highlight (and, with another instance, the segment previewed under the
// cursor, select/segments.js): the draft's vertex set (a roaring bitmap of original ids, from
// `GET /api/v1/selections/{draft}/vertices`) matched against every resident patch by the same
// machinery as the parts' highlights (PartStore), so the preview is exact at every level of
// detail and follows streaming.

import { PartStore } from '../parts/parts.js';

const DRAFT = 'draft';

export class DraftHighlight {
  constructor(modelId, modelRadius, modelVertices) {
    this.store = new PartStore(modelId, [], modelRadius, modelVertices);
    this.draftId = null;
  }

  /** Whether a draft is shown. */
  get active() {
    return this.draftId !== null;
  }

  addPatch(node, patch) {
    this.store.addPatch(node, patch);
  }

  removePatch(node) {
    this.store.removePatch(node);
  }

  /** Shows `draft` (its JSON) with its vertex set `bitmap`; null clears. */
  show(draft, bitmap) {
    this.showSet(draft && bitmap ? draft.id : null, bitmap, draft ? draft.center : null);
  }

  /** Shows the vertex set `bitmap` under the name `key` (null clears; the same key again
   * changes nothing). */
  showSet(key, bitmap, center = null) {
    if (key !== null && key === this.draftId) return;
    this.store.parts.clear();
    this.draftId = null;
    if (key !== null && bitmap) {
      const entry = this.store.put({ id: DRAFT, center: center || [0, 0, 0], vertex_count: bitmap.size, updated_at: key }, []);
      entry.bitmap = bitmap;
      this.draftId = key;
    }
    this.store.reindexAll();
  }

  /** Local vertex indices of the draft in patch `node`, or null. */
  verticesIn(node) {
    return this.active ? this.store.verticesIn(node, DRAFT) : null;
  }

  /** Draft vertices found in the resident patches. */
  matched() {
    const e = this.store.parts.get(DRAFT);
    return e ? e.matched : 0;
  }
}
