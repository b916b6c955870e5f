// One region selection in progress (src/web/selections.rs): the chain of server drafts, each
// built on the previous one through `base` (or on the edited part through `part_id`), so undo
// goes back to the previous draft id; confirm turns the newest draft into a part (or updates
// the edited part); cancel discards every draft. Requests are sent one at a time.

import { RoaringBitmap } from '../parts/roaring.js';
import { ApiError } from './api.js';

export class SelectionSession {
  /**
   * @param {number} modelId
   * @param {import('./api.js').Api} api
   * @param {() => void} onChange called when the drafts or the busy state change
   */
  constructor(modelId, api, onChange) {
    this.modelId = modelId;
    this.api = api;
    this.onChange = onChange;
    this.partId = null;
    this.stack = []; // [{draft, bitmap}], oldest first
    this.busy = false;
    this.generation = 0; // bumped by cancel and edit: answers to older requests are dropped
    this.limits = null; // {maxSide, maxPixels}: the server's largest view
  }

  /** The server's view limits: given by the page, else asked once (GET /api/v1/config). */
  async viewLimits() {
    if (!this.limits) {
      const { view_limits: v } = await this.api.get('/api/v1/config');
      this.limits = { maxSide: v.max_side, maxPixels: v.max_pixels };
    }
    return this.limits;
  }

  /** The newest draft ({draft, bitmap}) or null. */
  get top() {
    return this.stack.length ? this.stack[this.stack.length - 1] : null;
  }

  /** Starts editing part `partId` (null: a new part), discarding the drafts. */
  async edit(partId) {
    await this.discardAll();
    this.partId = partId;
    this.onChange();
  }

  /**
   * Sends one selection: `request` without its base (added here), `mask` a PNG blob or null
   * (point tool). `replaceTop`: the result replaces the newest draft (a markup refined by
   * more strokes) and builds on the draft below it. Resolves to the new draft's JSON.
   */
  async select(request, mask, { replaceTop = false } = {}) {
    if (this.busy) throw new ApiError(0, 'the previous selection is still being computed');
    this.busy = true;
    this.onChange();
    const generation = this.generation;
    try {
      const below = replaceTop ? this.stack[this.stack.length - 2] : this.top;
      const body = { ...request };
      if (below) body.base = below.draft.id;
      else if (this.partId !== null) body.part_id = this.partId;
      const draft = await this.post(body, mask);
      const bitmap = RoaringBitmap.deserialize(await this.api.bytes(`/api/v1/selections/${draft.id}/vertices`));
      if (generation !== this.generation) {
        this.forget(draft.id);
        const e = new ApiError(0, 'the selection was cancelled');
        e.cancelled = true;
        throw e;
      }
      if (replaceTop && this.stack.length) this.forget(this.stack.pop().draft.id);
      this.stack.push({ draft, bitmap });
      return draft;
    } finally {
      this.busy = false;
      this.onChange();
    }
  }

  async post(body, mask) {
    const url = `/api/v1/models/${this.modelId}/selections`;
    if (!mask) return this.api.post(url, body);
    const form = new FormData();
    form.append('request', JSON.stringify(body));
    form.append('mask', mask, 'mask.png');
    return this.api.post(url, form);
  }

  /** Goes back to the previous draft (the newest is discarded on the server). */
  undo() {
    if (this.busy || this.stack.length === 0) return false;
    this.forget(this.stack.pop().draft.id);
    this.onChange();
    return true;
  }

  /** Makes the newest draft a part; resolves to {part, created}. */
  async confirm() {
    const top = this.top;
    if (!top || this.busy) throw new ApiError(0, 'nothing is selected yet');
    this.busy = true;
    this.onChange();
    try {
      const res = await this.api.send('POST', `/api/v1/selections/${top.draft.id}/confirm`, {});
      const part = await res.json();
      this.stack.pop();
      for (const e of this.stack) this.forget(e.draft.id);
      this.stack = [];
      this.partId = null;
      return { part, created: res.status === 201 };
    } finally {
      this.busy = false;
      this.onChange();
    }
  }

  /** Discards every draft and ends the edit. */
  async cancel() {
    await this.discardAll();
    this.partId = null;
    this.onChange();
  }

  async discardAll() {
    this.generation++;
    const ids = this.stack.map((e) => e.draft.id);
    this.stack = [];
    await Promise.all(ids.map((id) => this.forget(id)));
  }

  /** Deletes a draft on the server; a draft already gone (expired) is no error. */
  forget(id) {
    return this.api.delete(`/api/v1/selections/${id}`).catch((e) => {
      if (!(e instanceof ApiError && e.status === 404)) console.warn('meshwiki selection:', e.message);
    });
  }
}
