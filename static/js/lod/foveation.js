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
// The threshold is a property of a group, so its members and products decide together and
// every cut stays watertight: the distance from the fovea to the nearest of the group's own
// patches, members and products (their tight bounding spheres). Group error spheres contain
// all their descendants and are large, so the distance to them would be zero for most of the
// model; the patches' tight bounds put the fovea's own patches at the target and the rest
// further out. A coarse group may then want less refinement than one of its descendants;
// the cut then refines the coarse group too, as the descendant needs it (cut.js `wanted`).

/** Default distortion α and cap r_max (fractions of the model radius). */
export const DEFAULT_ALPHA = 20;
export const DEFAULT_RMAX = 1.5;

/**
 * Distance from the nearest fovea (eq. 14: the minimum over foveae) to a sphere's nearest
 * point, in model radii: 0 when a fovea is inside it, `Infinity` without foveae.
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
 * The pixel threshold at distance `d` (model radii) from the nearest fovea: `target` at the
 * fovea, growing as the inverse sampling density of the log transform away from it;
 * `target` everywhere without foveae.
 * @param {{target: number, foveae: number[][], alpha: number, rMax: number}} f
 */
export function thresholdAt(f, d) {
  if (f.foveae.length === 0) return f.target;
  return f.target * (f.alpha * Math.min(d, f.rMax) + 1);
}

/** The threshold for a sphere (its nearest point to a fovea). */
export function threshold(f, cx, cy, cz, r) {
  if (f.foveae.length === 0) return f.target;
  return thresholdAt(f, foveaDistance(f.foveae, cx, cy, cz, r, f.modelRadius));
}

/** The log transform itself (eq. 1) and the scale that maps r_max to v_max (eq. 3). */
export function logTransform(r, alpha, s) {
  return Math.log(r * alpha + 1) * s;
}
export function scaleFor(vMax, rMax, alpha) {
  return vMax / Math.log(rMax * alpha + 1);
}
