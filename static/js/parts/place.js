// Label placement of the callouts (system paper §2.2), a port of the engine's rule
// (engine/src/render/callouts.rs, `place`): the same candidates in the same order, the same
// costs, the same tie-breaking (the first candidate of strictly lowest cost wins), the same
// rounding. The arithmetic is rounded to f32 (Math.fround) at every step as the engine
// computes it, so the same input gives the same placement, bit for bit;
// tests/browser/callouts.test.mjs checks this against the server on real data.

const f = Math.fround;

/** Directions of the candidates around an anchor, in the order they are tried. */
const AROUND_DIRECTIONS = [[1, -1], [-1, -1], [1, 1], [-1, 1], [1, 0], [-1, 0], [0, -1], [0, 1]];
/** Distances (pixels) of the candidates around an anchor, nearest first. */
const AROUND_DISTANCES = [16, 32, 56, 88, 128];
/** Cost added to candidates along an image side. */
const SIDE_COST = 40;
/** Cost of a leader crossing a placed leader. */
const CROSS_LEADER_PENALTY = 1000;
/** Cost of a leader crossing a placed label, or of a label crossing a placed leader. */
const CROSS_LABEL_PENALTY = 500;
/** Cost of a label covering (or coming within ANCHOR_GAP of) another part's anchor. */
const ANCHOR_PENALTY = 300;
/** Gap around other anchors for ANCHOR_PENALTY. */
const ANCHOR_GAP = 4;
/** Cost of a label lying entirely over the model rather than the background. */
export const COVER_PENALTY = 150;

/** Rust's `f32::round`: halves away from zero. */
function round(x) {
  return x < 0 ? -Math.round(-x) : Math.round(x);
}

/** `Rect::overlaps`: whether `s` and `o` come closer than `gap`. */
function overlaps(s, o, gap) {
  return s.x < f(f(o.x + o.w) + gap) && o.x < f(f(s.x + s.w) + gap) && s.y < f(f(o.y + o.h) + gap) && o.y < f(f(s.y + s.h) + gap);
}

function contains(r, p) {
  return p[0] >= r.x && p[0] <= f(r.x + r.w) && p[1] >= r.y && p[1] <= f(r.y + r.h);
}

/** Point of `r` nearest to `p`. */
function closest(r, p) {
  return [Math.min(Math.max(p[0], r.x), f(r.x + r.w)), Math.min(Math.max(p[1], r.y), f(r.y + r.h))];
}

function orient(a, b, c) {
  return f(f(f(b[0] - a[0]) * f(c[1] - a[1])) - f(f(b[1] - a[1]) * f(c[0] - a[0])));
}

/** Whether segments `ab` and `cd` properly cross (shared endpoints do not count). */
function segmentsCross(a, b, c, d) {
  const o1 = orient(a, b, c);
  const o2 = orient(a, b, d);
  const o3 = orient(c, d, a);
  const o4 = orient(c, d, b);
  return f(o1 * o2) < 0 && f(o3 * o4) < 0;
}

/** Whether segment `ab` touches rectangle `r`. */
function segmentCrossesRect(r, a, b) {
  if (contains(r, a) || contains(r, b)) return true;
  const x1 = f(r.x + r.w);
  const y1 = f(r.y + r.h);
  const c = [[r.x, r.y], [x1, r.y], [x1, y1], [r.x, y1]];
  for (let i = 0; i < 4; i++) if (segmentsCross(a, b, c[i], c[(i + 1) % 4])) return true;
  return false;
}

function distance(a, b) {
  const dx = f(a[0] - b[0]);
  const dy = f(a[1] - b[1]);
  return f(Math.sqrt(f(f(dx * dx) + f(dy * dy))));
}

/** Share of `r` over the model in the depth buffer `cover` (sampled every 4 pixels). */
function surfaceShare(cover, width, r) {
  let n = 0;
  let over = 0;
  const yEnd = f(r.y + r.h);
  const xEnd = f(r.x + r.w);
  for (let y = f(r.y + 1); y < yEnd; y = f(y + 4)) {
    for (let x = f(r.x + 1); x < xEnd; x = f(x + 4)) {
      // `as usize`: truncation, negatives to 0.
      const i = Math.max(0, Math.trunc(y)) * width + Math.max(0, Math.trunc(x));
      if (i < cover.length) {
        n++;
        if (Number.isFinite(cover[i])) over++;
      }
    }
  }
  return n === 0 ? 0 : f(over / n);
}

/**
 * The candidate rectangles of a label of `size` for `anchor` in a `width`×`height` image, in
 * the order placeLabels tries them: around the anchor at growing distances, then along the
 * left and right sides, then along the top and bottom (engine: `candidates`).
 * @returns {{rect: {x: number, y: number, w: number, h: number}, placement: string, base: number}[]}
 */
export function candidates(anchor, size, width, height, margin) {
  const a = [f(anchor[0]), f(anchor[1])];
  const lw = f(size[0]);
  const lh = f(size[1]);
  const gap = f(margin);
  const w = f(width);
  const h = f(height);
  const hw = f(lw * 0.5);
  const hh = f(lh * 0.5);
  const out = [];
  for (const dist of AROUND_DISTANCES) {
    for (const [dx, dy] of AROUND_DIRECTIONS) {
      const cx = f(a[0] + f(dx * f(dist + hw)));
      const cy = f(a[1] + f(dy * f(f(dist * 0.75) + hh)));
      out.push({ rect: { x: round(f(cx - hw)), y: round(f(cy - hh)), w: lw, h: lh }, placement: 'around', base: 0 });
    }
  }
  const step = f(lh + gap);
  const rows = Math.trunc(f(h / step)) + 1;
  const top = f(a[1] - hh);
  for (let i = 0; i < rows; i++) {
    for (const sign of [1, -1]) {
      const y = round(f(top + f(sign * i * step)));
      out.push({ rect: { x: gap, y, w: lw, h: lh }, placement: 'left', base: SIDE_COST });
      out.push({ rect: { x: f(f(w - gap) - lw), y, w: lw, h: lh }, placement: 'right', base: SIDE_COST });
    }
  }
  const hstep = f(hw + gap);
  const columns = Math.trunc(f(w / hstep)) + 1;
  const left = f(a[0] - hw);
  for (let i = 0; i < columns; i++) {
    for (const sign of [1, -1]) {
      const x = round(f(left + f(sign * i * hstep)));
      out.push({ rect: { x, y: gap, w: lw, h: lh }, placement: 'top', base: SIDE_COST });
      out.push({ rect: { x, y: f(f(h - gap) - lh), w: lw, h: lh }, placement: 'bottom', base: SIDE_COST });
    }
  }
  return out;
}

/**
 * Places labels (system paper §2.2) in a `width`×`height` image: greedily, in the order of
 * `items` (their priority), each label at the cheapest of its candidates that lies at least
 * `margin` inside the image and at least `margin` away from every label placed before. The
 * cost is the leader's length (anchor to the label's nearest point), plus SIDE_COST along the
 * sides, CROSS_LEADER_PENALTY per placed leader the leader crosses, CROSS_LABEL_PENALTY per
 * placed label the leader crosses and per placed leader the label crosses, ANCHOR_PENALTY per
 * other item's anchor the label covers, and, with a `cover` depth buffer (row-major,
 * `width`×`height`, finite on the model), COVER_PENALTY times the share of the label over
 * the model. The first candidate of strictly lowest cost wins.
 * @param {{anchor: number[], size: number[]}[]} items anchor [x, y] and label size [w, h], in pixels
 * @param {number} width
 * @param {number} height
 * @param {number} margin
 * @param {ArrayLike<number>|null} [cover] depth buffer for the cover penalty (null: none)
 * @returns {({label: {x: number, y: number, w: number, h: number}, end: number[], placement: string}|null)[]}
 *   per item, its label's rectangle, the leader's end and the kind of place, or null (no room)
 */
export function placeLabels(items, width, height, margin, cover = null) {
  const gap = f(margin);
  const w = f(width);
  const h = f(height);
  const anchors = items.map((it) => [f(it.anchor[0]), f(it.anchor[1])]);
  const placed = []; // {r, s0, s1}
  const out = [];
  for (let k = 0; k < items.length; k++) {
    const a = anchors[k];
    let best = null;
    for (const { rect: r, placement, base } of candidates(a, items[k].size, width, height, margin)) {
      if (r.x < gap || r.y < gap || f(r.x + r.w) > f(w - gap) || f(r.y + r.h) > f(h - gap)) continue;
      if (placed.some((p) => overlaps(p.r, r, gap))) continue;
      const end = closest(r, a);
      let cost = f(base + distance(a, end));
      // Penalties are never negative: a candidate already as dear as the best loses.
      if (best && cost >= best.cost) continue;
      if (cover) cost = f(cost + f(COVER_PENALTY * surfaceShare(cover, width, r)));
      for (const p of placed) {
        if (segmentsCross(a, end, p.s0, p.s1)) cost = f(cost + CROSS_LEADER_PENALTY);
        if (segmentCrossesRect(p.r, a, end)) cost = f(cost + CROSS_LABEL_PENALTY);
        if (segmentCrossesRect(r, p.s0, p.s1)) cost = f(cost + CROSS_LABEL_PENALTY);
      }
      for (let j = 0; j < anchors.length; j++) {
        if (j !== k && overlaps(r, { x: anchors[j][0], y: anchors[j][1], w: 0, h: 0 }, ANCHOR_GAP)) cost = f(cost + ANCHOR_PENALTY);
      }
      if (!best || cost < best.cost) best = { cost, r, placement, end };
    }
    if (best) {
      placed.push({ r: best.r, s0: a, s1: best.end });
      out.push({ label: best.r, end: best.end, placement: best.placement });
    } else {
      out.push(null);
    }
  }
  return out;
}
