//! The selection energy of system paper §4.1.1:
//! `E(X) = Σ_i E1(x_i) + λ Σ_(i,j) E2(x_i, x_j)` (eq. 1).
//!
//! **Data term** (eq. 2–3): `E1 = w_c·E1'c + w_n·E1'n`. Seeds are hard constraints (a
//! foreground seed costs ∞ as background and 0 as foreground, and the reverse); an unknown
//! pixel costs `d^F / (d^F + d^B)` as foreground and `d^B / (d^F + d^B)` as background, where
//! `d` is its distance to the foreground or background seed set: for colour, the distance to
//! the nearest mean colour of the seed set; for normals, `min_n |1 − N(i)·N_n|` over the mean
//! normals of the seed set. The paper's "average of the initial set" is a single mean; seeds
//! are split into up to [`EnergyParams::clusters`] groups by k-means first (as Lazy Snapping
//! does for colour), since a marker around a curved part sees many normals.
//!
//! **Smoothness term** (eq. 4): `E2 = |x_i − x_j|·(w_c·g(C_ij) + w_n·g(N_ij) + w_d·g(D_ij))`
//! with `C_ij` the colour difference, `N_ij = 1 − N_i·N_j` the normal difference and `D_ij` the
//! relative depth difference `|d_i − d_j| / min(d_i, d_j)` of neighbouring pixels. `g` is the
//! decreasing `g(x) = exp(−β x²)`, with `β = 1 / (2⟨x²⟩)` estimated over the view (Boykov &
//! Jolly's contrast normalisation), so one set of weights works at any scale. A cue that is
//! constant over the view (a scan without colour) carries no boundary and is left out.
//! Diagonal edges are divided by √2 (8-connected grid, as the paper's graph).
//!
//! **Stroke distance (markup).** Scans without colour leave eq. 3 only normals, which are
//! weak (a smooth part shows every normal) and ambiguous (far surfaces face the same way), so
//! the cut either shrinks onto the strokes or floods every similarly facing surface. Markup
//! therefore adds a geodesic data term ([`EnergyParams::w_geo`]) in the spirit of Bai &
//! Sapiro's geodesic segmentation ("A geodesic framework for fast interactive image and video
//! segmentation and matting", ICCV 2007) and Criminisi et al.'s GeoS (ECCV 2008): with `D^F`,
//! `D^B` the geodesic distances to the nearest foreground / background stroke over the
//! 8-connected pixel graph, a pixel costs `D^F / (D^F + D^B)` as foreground and
//! `D^B / (D^F + D^B)` as background — the same normalised form as eq. 3. The path length
//! grows steeply across normal creases and depth discontinuities (the geometric edges where
//! PSB regions meet), so strokes claim the surface they lie on up to its edges (see
//! [`super::seeds::markup`]).

use super::SelectError;
use super::buffers::Buffers;

/// Weights of the energy. `w_c`, `w_n`, `w_d` and `lambda` are the paper's; `clusters` and
/// `band_prior` are this implementation's (see the module documentation and
/// [`super::seeds`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct EnergyParams {
    /// Weight of texture colour (data and smoothness terms).
    pub w_c: f32,
    /// Weight of surface normals (data and smoothness terms).
    pub w_n: f32,
    /// Weight of depth (smoothness term).
    pub w_d: f32,
    /// λ: weight of the smoothness term against the data term.
    pub lambda: f32,
    /// Seed groups per set for the data term's distances (1 = the paper's single average).
    pub clusters: usize,
    /// Heavy lasso only: weight of the band prior, which makes each band pixel lean towards
    /// foreground on the inner half of the band and background on the outer half, so that
    /// without any image cue the cut follows the middle of the stroke rather than hugging the
    /// shorter inner edge (graph cuts' shrinking bias). 0 disables it.
    pub band_prior: f32,
    /// Markup only: weight of the geodesic stroke-distance data term (module documentation).
    /// 0 disables it.
    pub w_geo: f32,
    /// Markup only: λ of markup, whose data term also carries the stroke distance and so
    /// balances against a stronger smoothness term than the heavy lasso's.
    pub markup_lambda: f32,
    /// Models with surface segments: weight of the segment prior, how strongly a pixel in a
    /// segment claimed by one side's strokes leans to that side ([`super::segments`]).
    /// 0 disables it.
    pub w_seg: f32,
    /// Markup on models with surface segments: how strongly a pixel in no segment claimed by
    /// a stroke leans to the background (markup selects what its strokes claim, it does not
    /// spread over the surface no stroke speaks for). 0 disables it.
    pub w_seg_out: f32,
    /// Markup on models with surface segments: how much more a pixel leans to the background
    /// when its stroke-free segment shows more of the view than all the foreground strokes
    /// claim — another part no stroke spoke for ([`super::segments`]). 0 disables it.
    pub w_seg_apart: f32,
    /// Markup on models with surface segments: how much more a pixel in no claimed segment
    /// leans to the background per claim radius (`√` of the pixels the foreground strokes
    /// claim) by which its geodesic distance to the nearest stroke, of either side, exceeds
    /// `seg_far` claim radii (up to [`super::graph_cut::FAR_CAP`] radii). Surface far from
    /// every stroke is surface no stroke spoke for: with a single background stroke, the
    /// relative stroke distance alone handed all of it to the foreground. 0 disables it.
    pub w_seg_far: f32,
    /// Markup on models with surface segments: the distance to the nearest stroke, in claim
    /// radii, from which `w_seg_far` counts.
    pub seg_far: f32,
    /// Models with surface segments: factor of the smoothness term between pixels of
    /// different stroke segments (1: segment boundaries are no cheaper to cut than anywhere
    /// else; towards 0: the cut follows them).
    pub seg_edge: f32,
}

impl Default for EnergyParams {
    fn default() -> Self {
        EnergyParams {
            w_c: 1.0,
            w_n: 1.0,
            w_d: 1.0,
            lambda: 2.0,
            clusters: 4,
            band_prior: 0.25,
            w_geo: 4.0,
            markup_lambda: 6.0,
            w_seg: 2.0,
            w_seg_out: 1.0,
            w_seg_apart: 4.0,
            w_seg_far: W_SEG_FAR,
            seg_far: SEG_FAR,
            seg_edge: 0.5,
        }
    }
}

/// Default of [`EnergyParams::w_seg_far`]. `meshwiki-bench select --sweep` (seed 4), markup's
/// mean error per setting without it and with it: 45.2 → 38.2%, 23.0 → 22.3%, 12.7 → 14.5%,
/// 10.5 → 10.0%, 34.4 → 36.9%, 77.1 → 57.3% (the worst setting, two foreground strokes and one
/// background stroke). It costs the settings with many strokes or very short ones a point or
/// two and takes a fifth off the worst. With 1.0 and `seg_far` 1 the worst fell to 50.4% but
/// the three-and-six-stroke setting rose to 15.7%.
pub const W_SEG_FAR: f32 = 0.5;

/// Default of [`EnergyParams::seg_far`] (see [`W_SEG_FAR`]).
pub const SEG_FAR: f32 = 2.0;

/// Most seed groups.
pub const MAX_CLUSTERS: usize = 16;

impl EnergyParams {
    /// Checks every weight is finite and non-negative and some smoothness weight is positive.
    pub fn validate(&self) -> Result<(), SelectError> {
        let w = [
            ("w_c", self.w_c),
            ("w_n", self.w_n),
            ("w_d", self.w_d),
            ("lambda", self.lambda),
            ("band_prior", self.band_prior),
            ("w_geo", self.w_geo),
            ("markup_lambda", self.markup_lambda),
            ("w_seg", self.w_seg),
            ("w_seg_out", self.w_seg_out),
            ("w_seg_apart", self.w_seg_apart),
            ("w_seg_far", self.w_seg_far),
            ("seg_far", self.seg_far),
            ("seg_edge", self.seg_edge),
        ];
        for (name, v) in w {
            if !(v.is_finite() && (0.0..=1e4).contains(&v)) {
                return Err(SelectError::BadParams(format!(
                    "{name} must be within [0, 10000], got {v}"
                )));
            }
        }
        if !(1..=MAX_CLUSTERS).contains(&self.clusters) {
            return Err(SelectError::BadParams(format!(
                "clusters must be within 1..={MAX_CLUSTERS}, got {}",
                self.clusters
            )));
        }
        Ok(())
    }
}

#[inline]
fn rgb(c: [u8; 4]) -> [f32; 3] {
    [
        c[0] as f32 / 255.0,
        c[1] as f32 / 255.0,
        c[2] as f32 / 255.0,
    ]
}

#[inline]
fn dist2(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

#[inline]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let l = dot(v, v).sqrt();
    if l > 1e-12 {
        [v[0] / l, v[1] / l, v[2] / l]
    } else {
        [0.0, 0.0, 0.0]
    }
}

/// k-means with farthest-point initialisation (deterministic), a few Lloyd iterations.
fn kmeans(points: &[[f32; 3]], k: usize, unit: bool) -> Vec<[f32; 3]> {
    if points.is_empty() {
        return Vec::new();
    }
    // Subsample large seed sets: the means barely change and the cost stays bounded.
    const MAX_POINTS: usize = 4096;
    let step = points.len().div_ceil(MAX_POINTS).max(1);
    let pts: Vec<[f32; 3]> = points.iter().step_by(step).copied().collect();
    let mut centres = vec![pts[0]];
    let mut nearest: Vec<f32> = pts.iter().map(|p| dist2(*p, pts[0])).collect();
    while centres.len() < k {
        let (far, d) =
            nearest.iter().enumerate().fold(
                (0, 0.0f32),
                |acc, (i, &d)| if d > acc.1 { (i, d) } else { acc },
            );
        if d <= 1e-10 {
            break;
        }
        let c = pts[far];
        centres.push(c);
        for (n, p) in nearest.iter_mut().zip(&pts) {
            *n = n.min(dist2(*p, c));
        }
    }
    let mut assign = vec![0usize; pts.len()];
    for _ in 0..8 {
        for (a, p) in assign.iter_mut().zip(&pts) {
            *a = (0..centres.len())
                .min_by(|&x, &y| dist2(*p, centres[x]).total_cmp(&dist2(*p, centres[y])))
                .unwrap_or(0);
        }
        let mut sums = vec![([0f64; 3], 0usize); centres.len()];
        for (&a, p) in assign.iter().zip(&pts) {
            for (s, &c) in sums[a].0.iter_mut().zip(p) {
                *s += c as f64;
            }
            sums[a].1 += 1;
        }
        for (c, (s, n)) in centres.iter_mut().zip(&sums) {
            if *n > 0 {
                let m = s.map(|v| (v / *n as f64) as f32);
                *c = if unit { normalize(m) } else { m };
            }
        }
    }
    centres
}

/// The mean colours and mean normals of one seed set (eq. 3's "initial foreground set" or
/// "background set").
#[derive(Debug, Clone, PartialEq)]
pub struct SeedModel {
    pub colors: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
}

impl SeedModel {
    /// Fits the model to the seed pixels `pixels` (covered ones only).
    pub fn fit(buffers: &Buffers<'_>, pixels: &[u32], clusters: usize) -> SeedModel {
        let mut colors = Vec::with_capacity(pixels.len());
        let mut normals = Vec::with_capacity(pixels.len());
        for &p in pixels {
            let p = p as usize;
            if p < buffers.len() && buffers.covered(p) {
                colors.push(rgb(buffers.color[p]));
                normals.push(buffers.normal[p]);
            }
        }
        SeedModel {
            colors: kmeans(&colors, clusters, false),
            normals: kmeans(&normals, clusters, true),
        }
    }

    /// Whether the set had no covered pixel.
    pub fn is_empty(&self) -> bool {
        self.colors.is_empty()
    }

    /// `d` for colour: distance to the nearest mean colour.
    pub fn color_distance(&self, c: [u8; 4]) -> f32 {
        let c = rgb(c);
        self.colors
            .iter()
            .map(|m| dist2(c, *m))
            .fold(f32::INFINITY, f32::min)
            .sqrt()
    }

    /// `d` for normals: `min_n |1 − N(i)·N_n|`.
    pub fn normal_distance(&self, n: [f32; 3]) -> f32 {
        self.normals
            .iter()
            .map(|m| (1.0 - dot(n, *m)).abs())
            .fold(f32::INFINITY, f32::min)
    }
}

/// Eq. 3's soft costs `(E'(x=1), E'(x=0))` from the distances to the two sets.
#[inline]
pub fn soft_costs(d_fg: f32, d_bg: f32) -> (f32, f32) {
    let s = d_fg + d_bg;
    if s > 1e-12 && s.is_finite() {
        (d_fg / s, d_bg / s)
    } else {
        (0.5, 0.5)
    }
}

/// The data term of eq. 2 for one unknown pixel: `(cost as foreground, cost as background)`.
#[derive(Debug, Clone)]
pub struct DataTerm {
    pub fg: SeedModel,
    pub bg: SeedModel,
    /// Effective colour and normal weights (0 for a cue the view does not have).
    pub w_c: f32,
    pub w_n: f32,
}

impl DataTerm {
    /// From the seed models, with the weights of `params` (colour dropped when `color_cue` is
    /// false).
    pub fn new(fg: SeedModel, bg: SeedModel, params: &EnergyParams, color_cue: bool) -> DataTerm {
        DataTerm {
            fg,
            bg,
            w_c: if color_cue { params.w_c } else { 0.0 },
            w_n: params.w_n,
        }
    }

    /// `(E1(x=1), E1(x=0))` of pixel `i`.
    pub fn costs(&self, buffers: &Buffers<'_>, i: usize) -> (f32, f32) {
        let (mut f, mut b) = (0.0, 0.0);
        if self.w_c > 0.0 {
            let c = buffers.color[i];
            let (cf, cb) = soft_costs(self.fg.color_distance(c), self.bg.color_distance(c));
            f += self.w_c * cf;
            b += self.w_c * cb;
        }
        if self.w_n > 0.0 {
            let n = buffers.normal[i];
            let (nf, nb) = soft_costs(self.fg.normal_distance(n), self.bg.normal_distance(n));
            f += self.w_n * nf;
            b += self.w_n * nb;
        }
        (f, b)
    }
}

/// The three differences of eq. 4 between pixels `i` and `j`: colour, normal, depth.
#[inline]
pub fn differences(buffers: &Buffers<'_>, i: usize, j: usize) -> [f32; 3] {
    let c = dist2(rgb(buffers.color[i]), rgb(buffers.color[j])).sqrt();
    let n = (1.0 - dot(buffers.normal[i], buffers.normal[j])).max(0.0);
    let (di, dj) = (buffers.depth[i], buffers.depth[j]);
    let d = (di - dj).abs() / di.min(dj).max(f32::MIN_POSITIVE);
    [c, n, if d.is_finite() { d } else { 0.0 }]
}

/// The smoothness term of eq. 4 with contrast normalisation estimated on a view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Smoothness {
    /// `β` of colour, normal and depth (`g(x) = exp(−β x²)`).
    pub beta: [f32; 3],
    /// Effective weights `w_c, w_n, w_d` (0 for a cue constant over the view).
    pub weight: [f32; 3],
}

impl Smoothness {
    /// Estimates `β = 1 / (2⟨x²⟩)` per cue over the covered neighbour pairs of the view (right
    /// and down neighbours). Without `color_cue` (a model without vertex colours, whose
    /// rendered colour is only shading) colour is left out.
    pub fn estimate(buffers: &Buffers<'_>, params: &EnergyParams, color_cue: bool) -> Smoothness {
        let (w, h) = (buffers.width as usize, buffers.height as usize);
        let mut sum = [0f64; 3];
        let mut count = 0u64;
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if !buffers.covered(i) {
                    continue;
                }
                for j in [(x + 1 < w).then(|| i + 1), (y + 1 < h).then(|| i + w)]
                    .into_iter()
                    .flatten()
                {
                    if buffers.covered(j) {
                        let d = differences(buffers, i, j);
                        for k in 0..3 {
                            sum[k] += (d[k] as f64) * (d[k] as f64);
                        }
                        count += 1;
                    }
                }
            }
        }
        let weights = [
            if color_cue { params.w_c } else { 0.0 },
            params.w_n,
            params.w_d,
        ];
        let mut beta = [0f32; 3];
        let mut weight = [0f32; 3];
        for k in 0..3 {
            let mean = if count > 0 {
                sum[k] / count as f64
            } else {
                0.0
            };
            if mean > 1e-12 {
                beta[k] = (1.0 / (2.0 * mean)) as f32;
                weight[k] = weights[k];
            }
        }
        Smoothness { beta, weight }
    }

    /// Whether any cue varies over the view.
    pub fn has_cue(&self) -> bool {
        self.weight.iter().any(|&w| w > 0.0)
    }

    /// `w_c·g(C) + w_n·g(N) + w_d·g(D)` for the differences `d` (eq. 4 without `|x_i − x_j|`).
    #[inline]
    pub fn weight_of(&self, d: [f32; 3]) -> f32 {
        let mut s = 0.0;
        for ((&w, &beta), &dk) in self.weight.iter().zip(&self.beta).zip(&d) {
            if w > 0.0 {
                s += w * (-beta * dk * dk).exp();
            }
        }
        s
    }

    /// Edge weight between pixels `i` and `j`.
    #[inline]
    pub fn edge(&self, buffers: &Buffers<'_>, i: usize, j: usize) -> f32 {
        self.weight_of(differences(buffers, i, j))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::select::buffers::OwnedBuffers;

    #[test]
    fn soft_costs_follow_eq_3() {
        assert_eq!(soft_costs(0.0, 1.0), (0.0, 1.0));
        assert_eq!(soft_costs(3.0, 1.0), (0.75, 0.25));
        assert_eq!(soft_costs(0.0, 0.0), (0.5, 0.5));
    }

    #[test]
    fn seed_models_measure_distance_to_the_nearest_mean() {
        let mut b = OwnedBuffers::flat(4, 1);
        b.color = vec![
            [255, 0, 0, 255],
            [250, 0, 0, 255],
            [0, 0, 255, 255],
            [0, 255, 0, 255],
        ];
        b.normal = vec![
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let v = b.view();
        let m = SeedModel::fit(&v, &[0, 1, 2], 2);
        assert_eq!(m.colors.len(), 2);
        assert!(m.color_distance([252, 0, 0, 255]) < 0.02);
        assert!(m.color_distance([0, 0, 255, 255]) < 1e-6);
        assert!(m.color_distance([0, 255, 0, 255]) > 1.0);
        assert!(m.normal_distance([1.0, 0.0, 0.0]) < 1e-6);
        assert!((m.normal_distance([0.0, 1.0, 0.0]) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn smoothness_is_cheap_across_edges_and_ignores_constant_cues() {
        // Two flat halves of different colour, same normal and depth.
        let mut b = OwnedBuffers::flat(8, 4);
        for y in 0..4 {
            for x in 4..8 {
                b.color[y * 8 + x] = [20, 200, 40, 255];
            }
        }
        let v = b.view();
        let s = Smoothness::estimate(&v, &EnergyParams::default(), true);
        assert!(s.weight[0] > 0.0 && s.weight[1] == 0.0 && s.weight[2] == 0.0);
        let inside = s.edge(&v, 0, 1);
        let across = s.edge(&v, 3, 4);
        assert!(inside > 0.99 && across < 0.05, "{inside} {across}");
    }

    #[test]
    fn params_are_validated() {
        assert!(EnergyParams::default().validate().is_ok());
        let bad = EnergyParams {
            lambda: f32::NAN,
            ..EnergyParams::default()
        };
        assert!(bad.validate().is_err());
        let bad = EnergyParams {
            clusters: 0,
            ..EnergyParams::default()
        };
        assert!(bad.validate().is_err());
    }
}
