//! The graph cut (system paper §4.1.1): "the image is represented by a graph G = (V, E) where
//! V corresponds to pixels ... and E corresponds to connections between eight neighboring
//! pixels"; the labelling minimising eq. 1 is the minimum cut, found with the min-cut/max-flow
//! algorithm of Boykov and Kolmogorov ([`super::maxflow_grid`]).
//!
//! t-links carry the data term (eq. 2–3, plus the heavy lasso's band prior or markup's
//! geodesic stroke distance), hard seeds a
//! capacity of [`HARD`]; n-links carry `λ·E2` (eq. 4). Only pixels showing the model are in
//! the graph: every link of a pixel off the model is zero. The grid is cropped to the bounding
//! box of the pixels the cut decides (one pixel of margin): outside it every pixel is a seed.

use std::time::Instant;

use super::SelectError;
use super::buffers::Buffers;
use super::energy::{DataTerm, EnergyParams, SeedModel, Smoothness};
use super::maxflow_grid::{GridEdges, GridGraph};
use super::seeds::{BG, FG, OFF, Seeds, UNKNOWN};

/// Most claim radii beyond [`EnergyParams::seg_far`] that count in the far-from-strokes
/// lean: a pixel that far is as surely apart as any farther one.
pub const FAR_CAP: f32 = 4.0;

/// Capacity of a hard constraint (the "∞" of eq. 3): far above any sum of soft costs.
pub const HARD: f32 = 1e9;

/// What a cut did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct CutStats {
    /// Pixels in the graph (the cropped window).
    pub nodes: usize,
    /// Pixels the cut decided (neither seed nor off the model).
    pub unknown: usize,
    /// Value of the maximum flow (the minimum energy, hard parts excluded).
    pub flow: f64,
    /// Building the graph, milliseconds.
    pub build_ms: f64,
    /// Solving the maximum flow, milliseconds.
    pub solve_ms: f64,
}

/// Bounding box `[x0, x1) × [y0, y1)` of the unknown pixels, one pixel of margin.
fn window(seeds: &Seeds) -> Option<(usize, usize, usize, usize)> {
    let (w, h) = (seeds.width as usize, seeds.height as usize);
    let unknown = seeds.role.iter().map(|&r| r == UNKNOWN);
    super::mask::bounding_box(unknown, w).map(|[x0, y0, x1, y1]| {
        (
            x0.saturating_sub(1),
            y0.saturating_sub(1),
            (x1 + 1).min(w),
            (y1 + 1).min(h),
        )
    })
}

/// Solves eq. 1 for `seeds` on `buffers`: returns per pixel whether it is foreground (always
/// false off the model). `color_cue`: whether the model has colours (else colour is left out
/// of both terms: the rendered colour of an uncoloured scan is only shading).
pub fn graph_cut(
    buffers: &Buffers<'_>,
    seeds: &Seeds,
    params: &EnergyParams,
    color_cue: bool,
) -> Result<(Vec<bool>, CutStats), SelectError> {
    let models = (
        SeedModel::fit(buffers, &seeds.fg_samples, params.clusters),
        SeedModel::fit(buffers, &seeds.bg_samples, params.clusters),
    );
    graph_cut_with(buffers, seeds, params, color_cue, models)
}

/// [`graph_cut`] with the foreground and background seed models given (fitted elsewhere:
/// the coarse level of [`super::multilevel`] fits them on the strokes of the whole view).
pub fn graph_cut_with(
    buffers: &Buffers<'_>,
    seeds: &Seeds,
    params: &EnergyParams,
    color_cue: bool,
    (fg, bg): (SeedModel, SeedModel),
) -> Result<(Vec<bool>, CutStats), SelectError> {
    params.validate()?;
    let t0 = Instant::now();
    let (w, h) = (buffers.width as usize, buffers.height as usize);
    if seeds.role.len() != w * h {
        return Err(SelectError::SizeMismatch {
            what: "the seeds",
            got_w: seeds.width,
            got_h: seeds.height,
            width: buffers.width,
            height: buffers.height,
        });
    }
    let mut out: Vec<bool> = seeds.role.iter().map(|&r| r == FG).collect();
    let mut stats = CutStats::default();
    let Some((x0, y0, x1, y1)) = window(seeds) else {
        return Ok((out, stats));
    };
    let (ww, wh) = (x1 - x0, y1 - y0);
    let m = ww * wh;
    let global = |lx: usize, ly: usize| (y0 + ly) * w + x0 + lx;

    let smooth = Smoothness::estimate(buffers, params, color_cue);
    let data = DataTerm::new(fg, bg, params, color_cue);
    let mut source = vec![0f32; m];
    let mut sink = vec![0f32; m];
    let mut right = vec![0f32; m];
    let mut down = vec![0f32; m];
    let mut down_right = vec![0f32; m];
    let mut down_left = vec![0f32; m];
    // Markup's data term also carries the stroke distance, so it balances at its own λ.
    let lambda = if seeds.stroke_position.is_some() {
        params.markup_lambda
    } else {
        params.lambda
    };
    let diagonal = lambda / std::f32::consts::SQRT_2;
    for ly in 0..wh {
        for lx in 0..ww {
            let l = ly * ww + lx;
            let g = global(lx, ly);
            let role = seeds.role[g];
            match role {
                FG => source[l] = HARD,
                BG => sink[l] = HARD,
                UNKNOWN => {
                    stats.unknown += 1;
                    let (mut cf, mut cb) = data.costs(buffers, g);
                    if let Some(pos) = &seeds.band_position
                        && params.band_prior > 0.0
                        && pos[g].is_finite()
                    {
                        cf += params.band_prior * pos[g];
                        cb += params.band_prior * (1.0 - pos[g]);
                    }
                    if let Some(pos) = &seeds.stroke_position
                        && params.w_geo > 0.0
                    {
                        cf += params.w_geo * pos[g];
                        cb += params.w_geo * (1.0 - pos[g]);
                    }
                    if let Some(p) = &seeds.segments {
                        match p.side[g] {
                            1 => cb += params.w_seg,
                            -1 => cf += params.w_seg,
                            _ if seeds.stroke_position.is_some() => {
                                cf += params.w_seg_out;
                                let radius = params.seg_far * p.fg_radius;
                                if let Some(d) = &seeds.stroke_distance
                                    && params.w_seg_far > 0.0
                                    && radius > 0.0
                                {
                                    // Claim radii beyond `seg_far` to the nearest stroke.
                                    let t = d[g] / radius - 1.0;
                                    cf += params.w_seg_far * t.clamp(0.0, FAR_CAP);
                                }
                                if p.apart[g] {
                                    cf += params.w_seg_apart;
                                }
                            }
                            _ => {}
                        }
                    }
                    // Cutting the source link puts the pixel in the background.
                    source[l] = cb;
                    sink[l] = cf;
                }
                _ => continue,
            }
            let link = |dx: isize, dy: usize, factor: f32, arr: &mut Vec<f32>| {
                let nx = lx as isize + dx;
                let ny = ly + dy;
                if nx < 0 || nx as usize >= ww || ny >= wh {
                    return;
                }
                let q = global(nx as usize, ny);
                let rq = seeds.role[q];
                if rq == OFF || (rq == role && role != UNKNOWN) {
                    return;
                }
                let mut factor = factor;
                if let Some(p) = &seeds.segments
                    && p.region[g] != p.region[q]
                {
                    factor *= params.seg_edge;
                }
                arr[l] = factor * smooth.edge(buffers, g, q);
            };
            link(1, 0, lambda, &mut right);
            link(0, 1, lambda, &mut down);
            link(1, 1, diagonal, &mut down_right);
            link(-1, 1, diagonal, &mut down_left);
        }
    }
    stats.nodes = m;
    let edges = GridEdges {
        right: &right,
        down: &down,
        down_right: &down_right,
        down_left: &down_left,
    };
    let mut graph = GridGraph::symmetric(ww, wh, &source, &sink, &edges)?;
    let t1 = Instant::now();
    stats.build_ms = (t1 - t0).as_secs_f64() * 1e3;
    stats.flow = graph.maxflow();
    stats.solve_ms = t1.elapsed().as_secs_f64() * 1e3;
    let labels = graph.labels();
    for ly in 0..wh {
        for lx in 0..ww {
            let g = global(lx, ly);
            if seeds.role[g] == UNKNOWN {
                out[g] = labels[ly * ww + lx] == 1;
            }
        }
    }
    for (o, &r) in out.iter_mut().zip(&seeds.role) {
        if r == OFF || r == BG {
            *o = false;
        }
    }
    Ok((out, stats))
}

/// Keeps the selected pixels 8-connected to a foreground seed through selected pixels
/// (islands the cut found elsewhere are dropped, as a user expects of strokes).
pub fn keep_connected_to_seeds(selected: &mut [bool], seeds: &Seeds) {
    let (w, h) = (seeds.width as usize, seeds.height as usize);
    let mut keep = vec![false; selected.len()];
    let mut stack: Vec<usize> = (0..selected.len())
        .filter(|&i| selected[i] && seeds.role[i] == FG)
        .collect();
    for &i in &stack {
        keep[i] = true;
    }
    while let Some(i) = stack.pop() {
        let (x, y) = (i % w, i / w);
        for dy in -1isize..=1 {
            for dx in -1isize..=1 {
                let (nx, ny) = (x as isize + dx, y as isize + dy);
                if nx < 0 || ny < 0 || nx as usize >= w || ny as usize >= h {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                if selected[j] && !keep[j] {
                    keep[j] = true;
                    stack.push(j);
                }
            }
        }
    }
    selected.copy_from_slice(&keep);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::select::buffers::OwnedBuffers;
    use crate::select::mask::{self, StrokeMask};
    use crate::select::seeds;

    /// Markup with a foreground stroke on the left and a background stroke on the right.
    fn strokes(w: u32, h: u32) -> StrokeMask {
        let mut m = StrokeMask::empty(w, h).unwrap();
        for y in 2..h - 2 {
            m.labels[(y * w + 2) as usize] = mask::FOREGROUND;
            m.labels[(y * w + w - 3) as usize] = mask::BACKGROUND;
        }
        m
    }

    fn left_half_selected(sel: &[bool], w: usize, split: usize) -> usize {
        sel.iter()
            .enumerate()
            .filter(|&(i, &s)| s != (i % w < split))
            .count()
    }

    #[test]
    fn two_colours_split_at_the_colour_edge() {
        let (w, h) = (40u32, 20u32);
        let mut b = OwnedBuffers::flat(w, h);
        for i in 0..(w * h) as usize {
            if i % w as usize >= 23 {
                b.color[i] = [30, 90, 200, 255];
            } else {
                b.color[i] = [200, 60, 30, 255];
            }
        }
        let v = b.view();
        let s = seeds::markup(&strokes(w, h), &v).unwrap();
        let (sel, stats) = graph_cut(&v, &s, &EnergyParams::default(), true).unwrap();
        assert_eq!(left_half_selected(&sel, w as usize, 23), 0);
        assert!(stats.unknown > 0 && stats.flow > 0.0);
    }

    #[test]
    fn normal_creases_split_without_colour() {
        let (w, h) = (40u32, 20u32);
        let b = OwnedBuffers::creased(w, h, 15);
        let v = b.view();
        let s = seeds::markup(&strokes(w, h), &v).unwrap();
        // Colour is ignored (no colour cue), the normal edge decides.
        let (sel, _) = graph_cut(&v, &s, &EnergyParams::default(), false).unwrap();
        assert_eq!(left_half_selected(&sel, w as usize, 15), 0);
    }

    #[test]
    fn depth_steps_split_without_colour_or_normals() {
        let (w, h) = (40u32, 20u32);
        let mut b = OwnedBuffers::flat(w, h);
        for i in 0..(w * h) as usize {
            if i % w as usize >= 28 {
                b.depth[i] = 1.5;
            }
        }
        let v = b.view();
        let s = seeds::markup(&strokes(w, h), &v).unwrap();
        let params = EnergyParams {
            w_n: 0.0,
            ..EnergyParams::default()
        };
        let (sel, _) = graph_cut(&v, &s, &params, false).unwrap();
        assert_eq!(left_half_selected(&sel, w as usize, 28), 0);
    }

    #[test]
    fn pixels_off_the_model_are_never_selected() {
        let (w, h) = (20u32, 10u32);
        let mut b = OwnedBuffers::flat(w, h);
        for y in 0..h as usize {
            for x in 8..12 {
                b.node[y * w as usize + x] = crate::render::NO_NODE;
                b.depth[y * w as usize + x] = f32::INFINITY;
            }
        }
        let v = b.view();
        let s = seeds::markup(&strokes(w, h), &v).unwrap();
        let (mut sel, _) = graph_cut(&v, &s, &EnergyParams::default(), false).unwrap();
        keep_connected_to_seeds(&mut sel, &s);
        for y in 0..h as usize {
            for x in 8..w as usize {
                assert!(!sel[y * w as usize + x], "({x}, {y})");
            }
        }
        assert!(sel[5 * w as usize + 3]);
    }

    /// Markup's far-from-strokes lean ([`EnergyParams::w_seg_far`]): a foreground stroke at
    /// one end of a long flat strip and a background stroke at the other, each claiming the
    /// few columns around it. Without the lean the cut falls where the stroke distances
    /// balance; with it the stroke-free middle, far from both, goes to the background, and only
    /// pixels farther than `seg_far` claim radii from every stroke change side.
    #[test]
    fn surface_far_from_every_stroke_leans_to_the_background() {
        use crate::select::segments::SegmentPrior;
        let (w, h) = (100usize, 20usize);
        let b = OwnedBuffers::flat(w as u32, h as u32);
        let v = b.view();
        let mut m = StrokeMask::empty(w as u32, h as u32).unwrap();
        for y in 8..12 {
            m.labels[y * w + 2] = mask::FOREGROUND;
            m.labels[y * w + w - 3] = mask::BACKGROUND;
        }
        let mut s = seeds::markup(&m, &v).unwrap();
        let claim = 6;
        let column = |i: usize| match i % w {
            x if x < claim => 0,
            x if x >= w - claim => 1,
            _ => 2,
        };
        let n = w * h;
        let fg_radius = ((claim * h) as f32).sqrt();
        s.segments = Some(SegmentPrior {
            side: (0..n).map(|i| [1, -1, 0][column(i)]).collect(),
            region: (0..n).map(|i| column(i) as u64).collect(),
            apart: vec![false; n],
            fg_radius,
        });
        let select = |w_seg_far: f32| {
            let params = EnergyParams {
                w_seg_far,
                ..EnergyParams::default()
            };
            let (mut sel, _) = graph_cut(&v, &s, &params, false).unwrap();
            keep_connected_to_seeds(&mut sel, &s);
            sel
        };
        let defaults = EnergyParams::default();
        assert!(defaults.w_seg_far > 0.0);
        let (without, with) = (select(0.0), select(defaults.w_seg_far));
        let count = |sel: &[bool]| sel.iter().filter(|&&x| x).count();
        assert!(
            count(&with) + 2 * h <= count(&without),
            "{} vs {}",
            count(&with),
            count(&without)
        );
        let radius = defaults.seg_far * fg_radius;
        let distance = s.stroke_distance.as_ref().unwrap();
        for i in 0..n {
            assert!(!with[i] || without[i], "pixel {i} gained");
            if without[i] && !with[i] {
                assert!(
                    distance[i] > radius,
                    "pixel {i}: {} <= {radius}",
                    distance[i]
                );
            }
        }
    }
}
