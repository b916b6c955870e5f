// Decoding side of `MWP3` patch blobs (docs/FORMAT.md "Patch blob"), the browser twin of
// engine/src/lod/rangecoder.rs (adaptive binary range decoder, residual channels),
// engine/src/lod/frontcoder.rs (front-based connectivity) and
// engine/src/lod/parallelogram.rs (multi-way parallelogram prediction). The engine is the
// reference; tests/browser/decode.test.mjs checks this module against it on real scans.
//
// Arithmetic: the range coder works on unsigned 32-bit values held in doubles (every product
// is below 2^32, so exact); residuals, positions and ids are exact integers in doubles
// (below 2^53).

const PROB_BITS = 15;
const PROB_ONE = 1 << PROB_BITS;
const MAX_RATE = 5;
const TOP = 2 ** 24;
/** Largest bit length of a zigzag-mapped residual (engine: MAX_RESIDUAL_BITS). */
export const MAX_RESIDUAL_BITS = 40;
const LENGTH_TREE_BITS = 6;
const ADAPTIVE_MANTISSA = 4;

/** Adaptive probabilities: `p` (of a 0, 15 bits) and bits seen, in two typed arrays. */
export class Bits {
  constructor(count) {
    this.p = new Uint16Array(count).fill(PROB_ONE / 2);
    this.seen = new Uint8Array(count);
  }
}

/** The adaptation shift after `seen` bits: 1 + the bit length of seen + 2, capped (engine: Bit::rate). */
const RATE = Uint8Array.from({ length: 256 }, (_, seen) => Math.min(1 + (32 - Math.clz32(seen + 2)), MAX_RATE));

/** Range decoder (LZMA's); reading past the end yields zero bytes and sets `overrun`. */
export class RangeDecoder {
  constructor(bytes) {
    this.bytes = bytes;
    this.at = 0;
    this.range = 0xffffffff;
    this.code = 0;
    for (let i = 0; i < 5; i++) this.code = ((this.code * 256) % 4294967296) + this.nextByte();
  }

  nextByte() {
    const b = this.at < this.bytes.length ? this.bytes[this.at] : 0;
    this.at++;
    return b;
  }

  get overrun() {
    return this.at > this.bytes.length;
  }

  normalize() {
    while (this.range < TOP) {
      this.range *= 256;
      this.code = ((this.code * 256) % 4294967296) + this.nextByte();
    }
  }

  /** One bit with the adaptive probability `i` of `bits`. */
  bit(bits, i) {
    const p = bits.p[i];
    const bound = (this.range >>> PROB_BITS) * p;
    let bit;
    if (this.code < bound) {
      this.range = bound;
      bit = 0;
    } else {
      this.code -= bound;
      this.range -= bound;
      bit = 1;
    }
    const seen = bits.seen[i];
    const r = RATE[seen];
    bits.p[i] = bit ? p - (p >>> r) : p + ((PROB_ONE - p) >>> r);
    if (seen < 255) bits.seen[i] = seen + 1;
    if (this.range < TOP) this.normalize();
    return bit;
  }

  /** `count` equiprobable bits, most significant first, as an exact integer. */
  direct(count) {
    let value = 0;
    for (let i = 0; i < count; i++) {
      this.range = Math.floor(this.range / 2);
      let bit = 0;
      if (this.code >= this.range) {
        this.code -= this.range;
        bit = 1;
      }
      value = value * 2 + bit;
      if (this.range < TOP) this.normalize();
    }
    return value;
  }

  /** A `nbits`-bit value through the bit tree at `base` in `bits` (`2^nbits` entries). */
  tree(bits, base, nbits) {
    let node = 1;
    for (let i = 0; i < nbits; i++) node = node * 2 + this.bit(bits, base + node);
    return node - (1 << nbits);
  }
}

/** The adaptive probabilities of one kind of residual (engine: rangecoder::Channel). */
export class Channel {
  constructor() {
    this.lengths = new Bits(1 << LENGTH_TREE_BITS);
    this.mantissa = new Bits((MAX_RESIDUAL_BITS + 1) << ADAPTIVE_MANTISSA);
  }

  /** A signed residual, or null when its bit length is beyond MAX_RESIDUAL_BITS. */
  get(dec) {
    const k = dec.tree(this.lengths, 0, LENGTH_TREE_BITS);
    if (k > MAX_RESIDUAL_BITS) return null;
    let z;
    if (k === 0) z = 0;
    else if (k === 1) z = 1;
    else {
      const below = k - 1;
      const adaptive = Math.min(below, ADAPTIVE_MANTISSA);
      const rest = below - adaptive;
      const top = dec.tree(this.mantissa, k << ADAPTIVE_MANTISSA, adaptive);
      const low = dec.direct(rest);
      z = 2 ** below + top * 2 ** rest + low;
    }
    return z % 2 === 1 ? -(z + 1) / 2 : z / 2;
  }
}

// Connectivity (engine: frontcoder.rs).
const VERTEX = 0;
const LEFT = 1;
const RIGHT = 2;
const END = 3;
const SPLIT = 4;
const BOUNDARY = 5;
const SYMBOL_BITS = 3;
const DEGREE_CAP = 5;
const CONTEXTS = ((DEGREE_CAP + 1) * (DEGREE_CAP + 1)) << 2;

/** Prediction kinds of the traversal (engine: frontcoder::Prediction). */
export const PARALLELOGRAM = 0;
export const MIDPOINT = 1;
export const COPY = 2;
export const ZERO = 3;

class FrontError extends Error {}

/**
 * Decodes `t` triangles over `n` vertices. Returns `{ indices, kind, pa, pb, pc }`: the
 * triangles and each vertex's traversal prediction (kind and up to three vertices), or
 * throws when the stream does not decode.
 */
export function decodeConnectivity(bytes, n, t) {
  const dec = new RangeDecoder(bytes);
  const symbols = new Bits(CONTEXTS << SYMBOL_BITS);
  const old = new Bits(1);
  const indexChannel = new Channel();
  const indices = new Uint32Array(3 * t);
  let written = 0;
  const kind = new Uint8Array(n);
  const pa = new Uint32Array(n);
  const pb = new Uint32Array(n);
  const pc = new Uint32Array(n);
  let created = 0;
  const degree = new Uint32Array(n);
  // Front edges: a, b, o, prev, next, active (grown as needed).
  let cap = 64;
  let fa = new Uint32Array(cap);
  let fb = new Uint32Array(cap);
  let fo = new Uint32Array(cap);
  let fprev = new Uint32Array(cap);
  let fnext = new Uint32Array(cap);
  let factive = new Uint8Array(cap);
  let edges = 0;
  let head = 0;
  const grow = () => {
    cap *= 2;
    const g = (old) => {
      const a = new old.constructor(cap);
      a.set(old);
      return a;
    };
    fa = g(fa);
    fb = g(fb);
    fo = g(fo);
    fprev = g(fprev);
    fnext = g(fnext);
    factive = g(factive);
  };
  const push = (a, b, o) => {
    if (edges === cap) grow();
    const e = edges++;
    fa[e] = a;
    fb[e] = b;
    fo[e] = o;
    fprev[e] = e;
    fnext[e] = e;
    factive[e] = 1;
    return e;
  };
  const link = (x, y) => {
    fnext[x] = y;
    fprev[y] = x;
  };
  const emit = (x, y, z) => {
    indices[written++] = x;
    indices[written++] = y;
    indices[written++] = z;
    degree[x]++;
    degree[y]++;
    degree[z]++;
  };
  const leftIs = (e, c) => {
    const p = fprev[e];
    return p !== e && factive[p] === 1 && fb[p] === fa[e] && fa[p] === c;
  };
  const rightIs = (e, c) => {
    const q = fnext[e];
    return q !== e && factive[q] === 1 && fa[q] === fb[e] && fb[q] === c;
  };
  const readIndex = () => {
    const back = indexChannel.get(dec);
    if (back === null || back < 0 || created - 1 - back < 0) throw new FrontError();
    return created - 1 - back;
  };
  const s = [0, 0, 0];
  while (written < 3 * t) {
    for (let k = 0; k < 3; k++) {
      if (dec.bit(old, 0)) {
        s[k] = readIndex();
      } else {
        if (created >= n) throw new FrontError();
        const v = created++;
        if (k === 0) {
          if (v > 0) {
            kind[v] = COPY;
            pa[v] = v - 1;
          } else kind[v] = ZERO;
        } else if (k === 1) {
          kind[v] = COPY;
          pa[v] = s[0];
        } else {
          kind[v] = MIDPOINT;
          pa[v] = s[0];
          pb[v] = s[1];
        }
        s[k] = v;
      }
    }
    if (s[0] === s[1] || s[1] === s[2] || s[0] === s[2]) throw new FrontError();
    emit(s[0], s[1], s[2]);
    const e0 = push(s[0], s[1], s[2]);
    const e1 = push(s[1], s[2], s[0]);
    const e2 = push(s[2], s[0], s[1]);
    link(e0, e1);
    link(e1, e2);
    link(e2, e0);
    while (written < 3 * t) {
      let e = -1;
      while (head < edges) {
        const x = head++;
        if (factive[x]) {
          e = x;
          break;
        }
      }
      if (e < 0) break;
      const a = fa[e];
      const b = fb[e];
      const dA = Math.min(degree[a], DEGREE_CAP);
      const dB = Math.min(degree[b], DEGREE_CAP);
      const context = ((dA * (DEGREE_CAP + 1) + dB) << 2) | (factive[fprev[e]] << 1) | factive[fnext[e]];
      const symbol = dec.tree(symbols, context << SYMBOL_BITS, SYMBOL_BITS);
      let c;
      if (symbol === BOUNDARY) {
        factive[e] = 0;
        continue;
      } else if (symbol === VERTEX) {
        if (created >= n) throw new FrontError();
        c = created++;
        kind[c] = PARALLELOGRAM;
        pa[c] = a;
        pb[c] = b;
        pc[c] = fo[e];
      } else if (symbol === LEFT || symbol === END) {
        c = fa[fprev[e]];
        if (!leftIs(e, c) || (symbol === END && !rightIs(e, c))) throw new FrontError();
      } else if (symbol === RIGHT) {
        c = fb[fnext[e]];
        if (!rightIs(e, c)) throw new FrontError();
      } else if (symbol === SPLIT) {
        c = readIndex();
        if (c === a || c === b) throw new FrontError();
      } else {
        throw new FrontError();
      }
      // Front update (engine: Front::apply); the triangle is (a, c, b).
      const p = fprev[e];
      const q = fnext[e];
      factive[e] = 0;
      if (symbol === LEFT) {
        factive[p] = 0;
        const pp = fprev[p];
        const m = push(c, b, a);
        link(pp, m);
        link(m, q);
      } else if (symbol === RIGHT) {
        factive[q] = 0;
        const qq = fnext[q];
        const m = push(a, c, b);
        link(p, m);
        link(m, qq);
      } else if (symbol === END) {
        factive[p] = 0;
        factive[q] = 0;
        link(fprev[p], fnext[q]);
      } else {
        const m1 = push(a, c, b);
        const m2 = push(c, b, a);
        link(p, m1);
        link(m1, m2);
        link(m2, q);
      }
      emit(a, c, b);
    }
    if (dec.overrun) throw new FrontError();
  }
  if (created !== n || dec.overrun) throw new FrontError();
  return { indices, kind, pa, pb, pc };
}

/**
 * Multi-way parallelograms (engine: parallelogram.rs): for each vertex, the triples
 * (x, y, o) as flat arrays `start` (n + 1) and `triples` (3 per entry); with the border
 * vertices (`border`, as decode.js `borderVertices` finds them) from the same edge table.
 */
export function parallelograms(indices, n) {
  const t = indices.length / 3;
  // Undirected edges in an open-addressing table (Map keys above 2^31 are slow): per slot
  // its two ends, its first two triangles in order and its use count; further triangles of
  // non-manifold edges in `more`.
  let cap = 16;
  while (cap < 6 * t) cap *= 2;
  const mask = cap - 1;
  const lo = new Int32Array(cap).fill(-1);
  const hi = new Int32Array(cap);
  const first = new Int32Array(cap);
  const second = new Int32Array(cap).fill(-1);
  const uses = new Uint32Array(cap);
  const more = new Map();
  const slotOf = (a, b) => {
    const x = a < b ? a : b;
    const y = a < b ? b : a;
    let h = (Math.imul(x, 0x9e3779b1) ^ Math.imul(y, 0x85ebca77)) & mask;
    while (lo[h] !== -1 && (lo[h] !== x || hi[h] !== y)) h = (h + 1) & mask;
    if (lo[h] === -1) {
      lo[h] = x;
      hi[h] = y;
    }
    return h;
  };
  for (let f = 0; f < t; f++) {
    for (let k = 0; k < 3; k++) {
      const slot = slotOf(indices[3 * f + k], indices[3 * f + ((k + 1) % 3)]);
      const u = uses[slot]++;
      if (u === 0) first[slot] = f;
      else if (u === 1) second[slot] = f;
      else {
        const l = more.get(slot);
        if (l) l.push(f);
        else more.set(slot, [f]);
      }
    }
  }
  // Border vertices: the ends of edges used by exactly one triangle (decode.js borderVertices).
  const border = new Uint8Array(n);
  for (let h = 0; h < cap; h++) {
    if (lo[h] !== -1 && uses[h] === 1) {
      border[lo[h]] = 1;
      border[hi[h]] = 1;
    }
  }
  // The third corner of triangle g opposite edge (x, y), if before v; else -1.
  const thirdBefore = (g, x, y, v) => {
    for (let j = 0; j < 3; j++) {
      const u = indices[3 * g + j];
      if (u !== x && u !== y) return u < v ? u : -1;
    }
    return -1;
  };
  // Per corner, its parallelogram's third vertex (or -1); counted per vertex, then laid out
  // in triangle order.
  const thirds = new Int32Array(3 * t).fill(-1);
  const count = new Uint32Array(n + 1);
  for (let f = 0; f < t; f++) {
    for (let k = 0; k < 3; k++) {
      const v = indices[3 * f + k];
      const x = indices[3 * f + ((k + 1) % 3)];
      const y = indices[3 * f + ((k + 2) % 3)];
      if (x >= v || y >= v) continue;
      const slot = slotOf(x, y);
      let third = first[slot] !== f ? thirdBefore(first[slot], x, y, v) : -1;
      if (third < 0 && second[slot] >= 0 && second[slot] !== f) third = thirdBefore(second[slot], x, y, v);
      if (third < 0 && more.has(slot)) {
        for (const g of more.get(slot)) {
          if (g === f) continue;
          third = thirdBefore(g, x, y, v);
          if (third >= 0) break;
        }
      }
      if (third >= 0) {
        thirds[3 * f + k] = third;
        count[v + 1]++;
      }
    }
  }
  const start = new Uint32Array(n + 1);
  for (let v = 0; v < n; v++) start[v + 1] = start[v] + count[v + 1];
  const total = start[n];
  const triples = new Uint32Array(total * 3);
  const fill = start.slice(0, n);
  for (let c = 0; c < 3 * t; c++) {
    const third = thirds[c];
    if (third < 0) continue;
    const f = (c / 3) | 0;
    const k = c - 3 * f;
    const v = indices[c];
    const at = 3 * fill[v]++;
    triples[at] = indices[3 * f + ((k + 1) % 3)];
    triples[at + 1] = indices[3 * f + ((k + 2) % 3)];
    triples[at + 2] = third;
  }
  return { start, triples, border };
}
