// GPU-memory budget with least-recently-used eviction. Nodes the cut pins (drawn, or the
// fallback of what is drawn) are never evicted; others go oldest first once the resident
// bytes exceed the budget.

export class PatchCache {
  constructor(budgetBytes) {
    this.budget = budgetBytes;
    this.bytes = 0;
    this.entries = new Map(); // node -> bytes, in least-recently-used order
  }

  has(node) {
    return this.entries.has(node);
  }

  add(node, bytes) {
    this.entries.delete(node);
    this.entries.set(node, bytes);
    this.bytes += bytes;
  }

  /** Marks nodes as used now (the drawn ones, every frame). */
  touch(nodes) {
    for (const node of nodes) {
      const bytes = this.entries.get(node);
      if (bytes === undefined) continue;
      this.entries.delete(node);
      this.entries.set(node, bytes);
    }
  }

  /** Whether `extra` more bytes fit without evicting anything pinned. */
  fits(extra, pinned) {
    let free = this.budget - this.bytes;
    if (free >= extra) return true;
    for (const [node, bytes] of this.entries) {
      if (!pinned[node]) free += bytes;
      if (free >= extra) return true;
    }
    return false;
  }

  /** Evicts unpinned nodes, oldest first, until within budget; returns them. */
  evict(pinned) {
    const out = [];
    if (this.bytes <= this.budget) return out;
    for (const [node, bytes] of this.entries) {
      if (this.bytes <= this.budget) break;
      if (pinned[node]) continue;
      this.entries.delete(node);
      this.bytes -= bytes;
      out.push(node);
    }
    return out;
  }

  remove(node) {
    const bytes = this.entries.get(node);
    if (bytes === undefined) return;
    this.entries.delete(node);
    this.bytes -= bytes;
  }
}
