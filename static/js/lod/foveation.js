// Foveated refinement threshold (Cheng, Basu & Pan, "Parametric Foveation for Progressive
// Texture and Model Transmission": eq. 1–3 for one fovea, eq. 13–14 for several).
//
// The paper resamples around a fovea with the log transform v(r) = s · ln(α r + 1) (eq. 1):
// sample positions are evenly spaced in v, so the spacing in r grows with the distance to the
// fovea as dr/dv = (α r + 1) / (s α). We use that spacing, normalised to 1 at the fovea, as the
// factor by which the pixel threshold of the cut may grow away from it:
//
//   threshold(r) = target · (α r + 1),   r = distance to the nearest fovea / model radius,
//
// capped at r_max (beyond it eq. 3's scale s maps everything to v_max: the periphery keeps the
// resolution of r_max). α is the paper's distortion parameter: large α gives a sharp fovea and
// a coarse periphery, small α a gentle falloff. Several foveae combine as eq. 13–14: each
// point takes its nearest fovea, i.e. the best (smallest) threshold.
//
// The threshold is evaluated on a sphere (the distance from the fovea to the sphere's nearest
// point), so group members and products, which share spheres, decide together; and a sphere
// that contains another is never given a larger threshold, which keeps cuts consistent.

/** Default distortion α and cap r_max (fractions of the model radius). */
export const DEFAULT_ALPHA = 12;
export const DEFAULT_RMAX = 1.5;

/**
 * Distance from the nearest fovea to a sphere, in model radii (eq. 14: the minimum over
 * foveae), 0 when a fovea is inside it; `Infinity` without foveae.
 */
export function foveaDistance(foveae, cx, cy, cz, r, modelRadius) {
  let best = Infinity;
  for (let i = 0; i < foveae.length; i++) {
    const f = foveae[i];
    const d = Math.max(0, Math.hypot(f[0] - cx, f[1] - cy, f[2] - cz) - r);
    if (d < best) best = d;
  }
  return best / modelRadius;
}

/**
 * The pixel threshold for a sphere: `target` at a fovea, growing as the inverse sampling
 * density of the log transform away from it; `target` everywhere without foveae.
 * @param {{target: number, foveae: number[][], alpha: number, rMax: number, modelRadius: number}} f
 */
export function threshold(f, cx, cy, cz, r) {
  if (f.foveae.length === 0) return f.target;
  const d = foveaDistance(f.foveae, cx, cy, cz, r, f.modelRadius);
  return f.target * (f.alpha * Math.min(d, f.rMax) + 1);
}

/** The log transform itself (eq. 1) and the scale that maps r_max to v_max (eq. 3). */
export function logTransform(r, alpha, s) {
  return Math.log(r * alpha + 1) * s;
}
export function scaleFor(vMax, rMax, alpha) {
  return vMax / Math.log(rMax * alpha + 1);
}
