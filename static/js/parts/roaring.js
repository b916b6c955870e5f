// Read-only RoaringBitmap in the standard portable serialisation
// (https://github.com/RoaringBitmap/RoaringFormatSpec): array, bitmap and run containers.
// `GET /api/v1/parts/{id}/vertices` serves a part's original vertex ids in this format.

const SERIAL_COOKIE_NO_RUNCONTAINER = 12346;
const SERIAL_COOKIE = 12347;
const NO_OFFSET_THRESHOLD = 4;
const ARRAY_MAX = 4096;

class ArrayContainer {
  constructor(values) {
    this.values = values; // sorted Uint16Array
  }
  has(low) {
    const v = this.values;
    let lo = 0;
    let hi = v.length - 1;
    while (lo <= hi) {
      const mid = (lo + hi) >>> 1;
      if (v[mid] < low) lo = mid + 1;
      else if (v[mid] > low) hi = mid - 1;
      else return true;
    }
    return false;
  }
  *lows() {
    yield* this.values;
  }
}

class BitmapContainer {
  constructor(words) {
    this.words = words; // Uint32Array(2048)
  }
  has(low) {
    return (this.words[low >>> 5] & (1 << (low & 31))) !== 0;
  }
  *lows() {
    for (let w = 0; w < this.words.length; w++) {
      let bits = this.words[w];
      while (bits !== 0) {
        const t = bits & -bits;
        yield w * 32 + (31 - Math.clz32(t));
        bits ^= t;
      }
    }
  }
}

class RunContainer {
  constructor(starts, lengths) {
    this.starts = starts; // Uint16Array, sorted
    this.lengths = lengths; // Uint16Array, run length - 1
  }
  has(low) {
    const s = this.starts;
    let lo = 0;
    let hi = s.length - 1;
    let found = -1;
    while (lo <= hi) {
      const mid = (lo + hi) >>> 1;
      if (s[mid] <= low) {
        found = mid;
        lo = mid + 1;
      } else {
        hi = mid - 1;
      }
    }
    return found >= 0 && low <= s[found] + this.lengths[found];
  }
  *lows() {
    for (let r = 0; r < this.starts.length; r++) {
      for (let v = this.starts[r]; v <= this.starts[r] + this.lengths[r]; v++) yield v;
    }
  }
}

/** An immutable set of 32-bit unsigned integers. */
export class RoaringBitmap {
  constructor(keys, containers, size) {
    this.keys = keys;
    this.containers = containers;
    this.size = size;
    this.index = new Map();
    keys.forEach((k, i) => this.index.set(k, containers[i]));
  }

  /** Whether `value` (0 ≤ value < 2^32) is in the set. */
  has(value) {
    const c = this.index.get(Math.floor(value / 65536));
    return c !== undefined && c.has(value % 65536);
  }

  /** Every value, ascending. */
  *values() {
    for (let i = 0; i < this.keys.length; i++) {
      const high = this.keys[i] * 65536;
      for (const low of this.containers[i].lows()) yield high + low;
    }
  }

  /** An empty set. */
  static empty() {
    return new RoaringBitmap([], [], 0);
  }

  /**
   * Parses the portable serialisation.
   * @param {ArrayBuffer|Uint8Array} data
   */
  static deserialize(data) {
    const bytes = data instanceof Uint8Array ? data : new Uint8Array(data);
    if (bytes.length === 0) return RoaringBitmap.empty();
    const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    let at = 0;
    const need = (n) => {
      if (at + n > bytes.length) throw new Error('roaring bitmap truncated');
    };
    need(4);
    const cookie = view.getUint32(0, true);
    at = 4;
    let count;
    let runFlags = null;
    if ((cookie & 0xffff) === SERIAL_COOKIE) {
      count = (cookie >>> 16) + 1;
      const flagBytes = Math.ceil(count / 8);
      need(flagBytes);
      runFlags = bytes.subarray(at, at + flagBytes);
      at += flagBytes;
    } else if (cookie === SERIAL_COOKIE_NO_RUNCONTAINER) {
      need(4);
      count = view.getUint32(at, true);
      at += 4;
    } else {
      throw new Error('not a portable roaring bitmap');
    }
    if (count > 65536) throw new Error('roaring bitmap has too many containers');
    need(count * 4);
    const keys = new Array(count);
    const cards = new Array(count);
    for (let i = 0; i < count; i++) {
      keys[i] = view.getUint16(at, true);
      cards[i] = view.getUint16(at + 2, true) + 1;
      at += 4;
    }
    if (runFlags === null || count >= NO_OFFSET_THRESHOLD) {
      need(count * 4);
      at += count * 4; // offsets: containers follow in order anyway
    }
    const containers = new Array(count);
    let size = 0;
    const u16s = (n) => {
      need(n * 2);
      const out = new Uint16Array(n);
      for (let k = 0; k < n; k++) out[k] = view.getUint16(at + 2 * k, true);
      at += n * 2;
      return out;
    };
    for (let i = 0; i < count; i++) {
      const isRun = runFlags !== null && (runFlags[i >>> 3] & (1 << (i & 7))) !== 0;
      if (isRun) {
        need(2);
        const runs = view.getUint16(at, true);
        at += 2;
        const pairs = u16s(runs * 2);
        const starts = new Uint16Array(runs);
        const lengths = new Uint16Array(runs);
        let card = 0;
        for (let r = 0; r < runs; r++) {
          starts[r] = pairs[2 * r];
          lengths[r] = pairs[2 * r + 1];
          card += lengths[r] + 1;
        }
        containers[i] = new RunContainer(starts, lengths);
        size += card;
      } else if (cards[i] <= ARRAY_MAX) {
        containers[i] = new ArrayContainer(u16s(cards[i]));
        size += cards[i];
      } else {
        need(8192);
        const words = new Uint32Array(2048);
        for (let w = 0; w < 2048; w++) words[w] = view.getUint32(at + 4 * w, true);
        at += 8192;
        containers[i] = new BitmapContainer(words);
        size += cards[i];
      }
    }
    return new RoaringBitmap(keys, containers, size);
  }
}
