// A small pool of decoding workers (1–2, leaving the main thread free): each request goes to
// the worker with the fewest pending jobs.

export class DecoderPool {
  constructor(size = Math.max(1, Math.min(2, (navigator.hardwareConcurrency || 2) - 1))) {
    this.workers = [];
    this.pending = new Map();
    this.nextId = 1;
    for (let i = 0; i < size; i++) {
      const worker = new Worker(new URL('./worker.js', import.meta.url), { type: 'module' });
      const slot = { worker, load: 0 };
      worker.onmessage = (e) => this.settle(slot, e.data);
      worker.onerror = (e) => this.fail(slot, e.message || 'decoder worker failed');
      this.workers.push(slot);
    }
  }

  /** Decodes `blob` (ArrayBuffer, transferred) into a patch; rejects on a bad blob. */
  decode(blob, grid, crc) {
    const slot = this.workers.reduce((a, b) => (b.load < a.load ? b : a));
    const id = this.nextId++;
    slot.load++;
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject, slot });
      slot.worker.postMessage({ id, blob, grid, crc }, [blob]);
    });
  }

  settle(slot, data) {
    const job = this.pending.get(data.id);
    if (!job) return;
    this.pending.delete(data.id);
    slot.load--;
    if (data.error) job.reject(new Error(data.error));
    else job.resolve(data.patch);
  }

  fail(slot, message) {
    for (const [id, job] of this.pending) {
      if (job.slot === slot) {
        this.pending.delete(id);
        slot.load--;
        job.reject(new Error(message));
      }
    }
  }

  terminate() {
    for (const s of this.workers) s.worker.terminate();
    this.workers = [];
  }
}
