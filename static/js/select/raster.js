// Stroke masks without antialiasing (engine/src/select/mask.rs): one label per pixel of the
// request camera, row-major, top row first. Lasso polygons are filled by scanlines (even-odd,
// pixel centres), strokes are discs swept along their segments; every pixel holds exactly
// one label, never a blend. Also the request size: the view's CSS size within the server's
// limits, and the scale from CSS pixels to mask pixels.

/** Labels of the wire format. */
export const LABEL = Object.freeze({ NONE: 0, FOREGROUND: 1, BACKGROUND: 2, HEAVY: 3, LASSO: 4 });

/** No limit (the server's own come from GET /api/v1/config, `view_limits`). */
const UNLIMITED = Object.freeze({ maxSide: Infinity, maxPixels: Infinity });

/**
 * The mask size for a view of `width`×`height` CSS pixels: the same size when the server
 * allows it, else scaled down uniformly (both sides by the same factor, rounded down).
 * @returns {{width: number, height: number, sx: number, sy: number}} sx, sy: mask px per CSS px
 */
export function fitSize(width, height, limits = UNLIMITED) {
  const w = Math.max(1, Math.round(width));
  const h = Math.max(1, Math.round(height));
  const s = Math.min(1, limits.maxSide / Math.max(w, h), Math.sqrt(limits.maxPixels / (w * h)));
  const W = Math.max(1, Math.min(limits.maxSide, Math.floor(w * s)));
  const H = Math.max(1, Math.min(limits.maxSide, Math.floor(h * s)));
  return { width: W, height: H, sx: W / w, sy: H / h };
}

/** Fills polygon `points` ({x, y}, mask pixels; closed implicitly) with `label`, even-odd. */
export function fillPolygon(labels, width, height, points, label) {
  const n = points.length;
  if (n < 3) return 0;
  let minY = Infinity;
  let maxY = -Infinity;
  for (const p of points) {
    minY = Math.min(minY, p.y);
    maxY = Math.max(maxY, p.y);
  }
  const y0 = Math.max(0, Math.ceil(minY - 0.5));
  const y1 = Math.min(height - 1, Math.floor(maxY - 0.5));
  const xs = [];
  let filled = 0;
  for (let y = y0; y <= y1; y++) {
    const yc = y + 0.5;
    xs.length = 0;
    for (let i = 0, j = n - 1; i < n; j = i++) {
      const a = points[j];
      const b = points[i];
      if (a.y <= yc !== b.y <= yc) xs.push(a.x + ((yc - a.y) / (b.y - a.y)) * (b.x - a.x));
    }
    xs.sort((p, q) => p - q);
    for (let k = 0; k + 1 < xs.length; k += 2) {
      // Pixels whose centre x + 0.5 lies in [xs[k], xs[k + 1]).
      const from = Math.max(0, Math.ceil(xs[k] - 0.5));
      const to = Math.min(width - 1, Math.ceil(xs[k + 1] - 0.5) - 1);
      const row = y * width;
      for (let x = from; x <= to; x++) labels[row + x] = label;
      if (to >= from) filled += to - from + 1;
    }
  }
  return filled;
}

/** Labels the pixels whose centres lie within `radius` of segment a–b (a disc swept along it). */
export function sweepDisc(labels, width, height, a, b, radius, label) {
  const r = Math.max(0.5, radius);
  const x0 = Math.max(0, Math.floor(Math.min(a.x, b.x) - r));
  const x1 = Math.min(width - 1, Math.ceil(Math.max(a.x, b.x) + r));
  const y0 = Math.max(0, Math.floor(Math.min(a.y, b.y) - r));
  const y1 = Math.min(height - 1, Math.ceil(Math.max(a.y, b.y) + r));
  const dx = b.x - a.x;
  const dy = b.y - a.y;
  const len2 = dx * dx + dy * dy;
  const r2 = r * r;
  for (let y = y0; y <= y1; y++) {
    const py = y + 0.5;
    for (let x = x0; x <= x1; x++) {
      const px = x + 0.5;
      let t = len2 > 0 ? ((px - a.x) * dx + (py - a.y) * dy) / len2 : 0;
      t = t < 0 ? 0 : t > 1 ? 1 : t;
      const ex = px - (a.x + t * dx);
      const ey = py - (a.y + t * dy);
      if (ex * ex + ey * ey <= r2) labels[y * width + x] = label;
    }
  }
}

/** A stroke of brush `radius` along `points` (closed: back to the first point too). */
export function strokePath(labels, width, height, points, radius, label, closed = false) {
  if (points.length === 0) return;
  if (points.length === 1) {
    sweepDisc(labels, width, height, points[0], points[0], radius, label);
    return;
  }
  for (let i = 1; i < points.length; i++) sweepDisc(labels, width, height, points[i - 1], points[i], radius, label);
  if (closed) sweepDisc(labels, width, height, points[points.length - 1], points[0], radius, label);
}

/**
 * Rasterises strokes drawn in CSS pixels into a mask of `size` (from `fitSize`).
 * @param {{kind: 'lasso'|'heavy'|'foreground'|'background', points: {x: number, y: number}[],
 *   width?: number}[]} strokes `width`: brush diameter in CSS pixels
 * @returns {Uint8Array} width × height labels
 */
export function rasterise(strokes, size) {
  const { width, height, sx, sy } = size;
  const labels = new Uint8Array(width * height);
  const scale = (points) => points.map((p) => ({ x: p.x * sx, y: p.y * sy }));
  const radius = (s) => (Math.max(1, s.width || 1) * Math.min(sx, sy)) / 2;
  // Background first, then foreground over it: a pixel drawn both ways counts as foreground.
  const order = { lasso: 0, heavy: 1, background: 2, foreground: 3 };
  for (const s of [...strokes].sort((a, b) => order[a.kind] - order[b.kind])) {
    const pts = scale(s.points);
    if (s.kind === 'lasso') fillPolygon(labels, width, height, pts, LABEL.LASSO);
    else if (s.kind === 'heavy') strokePath(labels, width, height, pts, radius(s), LABEL.HEAVY, true);
    else strokePath(labels, width, height, pts, radius(s), s.kind === 'foreground' ? LABEL.FOREGROUND : LABEL.BACKGROUND);
  }
  return labels;
}

/** How many pixels hold each label (tests, diagnostics). */
export function histogram(labels) {
  const h = [0, 0, 0, 0, 0];
  for (const v of labels) h[v]++;
  return h;
}
