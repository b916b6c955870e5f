// Bandwidth budget (Cheng, Basu & Pan eq. 15: choose the refinement so that what is sent fits
// the bandwidth B times the longest acceptable wait T). The viewer measures B from completed
// requests (bytes over the time at least one request was in flight), optionally capped by a
// user setting, and never has more than B·T bytes outstanding: whatever is requested arrives
// within T, so a camera move is answered within T instead of after a long queue.

/** Measured throughput: bytes per second of busy time, exponentially smoothed. */
export class Throughput {
  constructor(initial = 1_000_000, halfLifeBytes = 2_000_000) {
    this.rate = initial;
    this.halfLife = halfLifeBytes;
    this.active = 0;
    this.busySince = 0;
    this.busyMs = 0;
    this.bytes = 0;
    this.samples = 0;
  }

  /** A request starts (`now` in ms). */
  start(now) {
    if (this.active++ === 0) this.busySince = now;
  }

  /** A request of `bytes` finished (or failed with 0 bytes). */
  finish(now, bytes) {
    this.bytes += bytes;
    if (--this.active === 0) {
      this.busyMs += now - this.busySince;
    }
    const busy = this.busyMs + (this.active > 0 ? now - this.busySince : 0);
    if (bytes > 0 && busy > 0) {
      // Rate over the busy time since the last sample, blended by bytes.
      const rate = (this.bytes * 1000) / busy;
      const w = Math.min(1, this.bytes / this.halfLife);
      this.rate = this.samples === 0 ? rate : this.rate * (1 - w) + rate * w;
      this.samples++;
      if (this.bytes > this.halfLife) {
        this.bytes = 0;
        this.busyMs = 0;
        if (this.active > 0) this.busySince = now;
      }
    }
  }

  estimate() {
    return this.rate;
  }
}

/**
 * Picks, from candidates sorted by decreasing priority, the prefix whose bytes fit the budget
 * B·T beside what is already in flight (eq. 15 with M the patch bytes). At least one request
 * is allowed when nothing is in flight, so a patch larger than B·T still comes.
 * @param {{bytes: number}[]} candidates
 * @param {{bandwidth: number, maxWait: number, inFlightBytes: number, inFlight: number, maxInFlight: number}} b
 */
export function fitBudget(candidates, b) {
  const budget = b.bandwidth * b.maxWait;
  const chosen = [];
  let bytes = b.inFlightBytes;
  let count = b.inFlight;
  for (const c of candidates) {
    if (count >= b.maxInFlight) break;
    if (bytes + c.bytes > budget && count > 0) break;
    chosen.push(c);
    bytes += c.bytes;
    count++;
  }
  return chosen;
}
