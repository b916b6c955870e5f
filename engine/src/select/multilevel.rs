//! Markup coarse to fine: the banded multilevel graph cut of Lombaert, Sun, Grady and Xu
//! ("A multilevel banded graph cuts method for fast image segmentation", ICCV 2005), with the
//! view rendered at each level instead of an image pyramid.
//!
//! Markup's cut decides every pixel of the view (a short stroke may claim a part much larger
//! than its strokes' box), so on a whole 1280×720 view it pays for rendering four buffers,
//! two geodesic searches and a graph over every covered pixel. Here:
//!
//! 1. **Coarse level**: the view is rendered at half its size in each direction (the same
//!    projection; the cut at the same pixel error, so coarser patches), the stroke mask
//!    reduced to it ([`reduce_mask`]), and the whole markup cut runs there
//!    ([`super::seeds::markup`], stroke segments, [`super::graph_cut`]): a quarter of the
//!    pixels.
//! 2. **Band**: a full-resolution pixel is decided by the coarse cut when every coarse pixel
//!    within [`BAND`] of its own agrees (foreground when all are selected, background when none
//!    is); the others — the band around the coarse boundary — are left to the fine cut. The
//!    strokes stay hard constraints at both levels.
//! 3. **Fine level**: only the window around the coarse selection (and its band) is rendered
//!    at full resolution ([`RenderOptions::window`]: the same cut's pixels), and the cut runs on
//!    the band alone, with the coarse level's seed models, stroke distances and stroke
//!    segments (claims name segments of the model, so they hold on both renderings).
//!
//! Back-projection then reads the full-resolution buffers of the window, which hold every
//! selected pixel. What the coarse level cannot see (a feature thinner than two pixels far
//! from the coarse boundary) the fine level does not recover: the price of the method, which
//! `meshwiki-bench select` measures against the exact-mask reference.

use std::time::Instant;

use super::SelectError;
use super::buffers::Buffers;
use super::energy::{EnergyParams, SeedModel};
use super::graph_cut::{self, CutStats};
use super::mask::{self, StrokeMask};
use super::on_view::ViewSelectError;
use super::pipeline::PixelSelection;
use super::seeds::{self, BG, FG, OFF, Seeds, UNKNOWN};
use super::segments::{StrokeClaims, ViewSegments};
use crate::camera::Camera;
use crate::render::{Frame, RenderModel, RenderOptions, Renderer};

/// Half-width of the band the fine level decides, in coarse pixels (each two full-resolution
/// pixels): Lombaert et al. use one to two.
pub const BAND: usize = 2;

/// Views with fewer pixels than this are cut at full resolution in one level: the coarse
/// level would be too small to hold the strokes' shapes.
pub const MIN_PIXELS: u64 = 320 * 240;

/// Whether markup on `camera`'s view goes coarse to fine.
pub fn applies(camera: &Camera) -> bool {
    camera.width as u64 * camera.height as u64 >= MIN_PIXELS
}

/// The coarse level's camera: the same view at half the size (rounded up).
pub fn coarse_camera(camera: &Camera) -> Camera {
    Camera {
        width: camera.width.div_ceil(2),
        height: camera.height.div_ceil(2),
        ..*camera
    }
}

/// The coarse pixel holding full-resolution pixel `(x, y)` of a `w` × `h` view.
fn coarse_of(x: usize, y: usize, [w, h, cw, ch]: [usize; 4]) -> usize {
    (y * ch / h).min(ch - 1) * cw + (x * cw / w).min(cw - 1)
}

/// The stroke mask reduced to `cw` × `ch`: a coarse pixel takes the stroke label drawn on
/// most of its full-resolution pixels (foreground or background; none on a tie).
pub fn reduce_mask(mask: &StrokeMask, cw: u32, ch: u32) -> StrokeMask {
    let (w, h) = (mask.width as usize, mask.height as usize);
    let dims = [w, h, cw as usize, ch as usize];
    let mut votes = vec![(0u16, 0u16); cw as usize * ch as usize];
    for (i, &label) in mask.labels.iter().enumerate().take(w * h) {
        let c = coarse_of(i % w, i / w, dims);
        match label {
            mask::FOREGROUND => votes[c].0 += 1,
            mask::BACKGROUND => votes[c].1 += 1,
            _ => {}
        }
    }
    StrokeMask {
        width: cw,
        height: ch,
        labels: votes
            .iter()
            .map(|&(f, b)| match f.cmp(&b) {
                std::cmp::Ordering::Greater => mask::FOREGROUND,
                std::cmp::Ordering::Less => mask::BACKGROUND,
                std::cmp::Ordering::Equal => 0,
            })
            .collect(),
    }
}

/// Per coarse pixel, whether any pixel within `r` (Chebyshev) has `value` (a separable box
/// dilation).
fn near(selected: &[bool], value: bool, w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut rows = vec![false; w * h];
    for y in 0..h {
        let row = &selected[y * w..(y + 1) * w];
        // Prefix counts of `value` along the row.
        let mut prefix = vec![0u32; w + 1];
        for x in 0..w {
            prefix[x + 1] = prefix[x] + u32::from(row[x] == value);
        }
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r + 1).min(w));
            rows[y * w + x] = prefix[b] > prefix[a];
        }
    }
    let mut out = vec![false; w * h];
    for x in 0..w {
        let mut prefix = vec![0u32; h + 1];
        for y in 0..h {
            prefix[y + 1] = prefix[y] + u32::from(rows[y * w + x]);
        }
        for y in 0..h {
            let (a, b) = (y.saturating_sub(r), (y + r + 1).min(h));
            out[y * w + x] = prefix[b] > prefix[a];
        }
    }
    out
}

/// The coarse level's cut and what the fine level reuses of it.
struct Coarse {
    width: usize,
    height: usize,
    /// Per coarse pixel: some pixel within [`BAND`] is selected / is not.
    near_selected: Vec<bool>,
    near_unselected: Vec<bool>,
    stroke_position: Option<Vec<f32>>,
    stroke_distance: Option<Vec<f32>>,
    claims: Option<StrokeClaims>,
    models: (SeedModel, SeedModel),
    stats: CutStats,
    seeds_ms: f64,
}

fn coarse_cut(
    buffers: &Buffers<'_>,
    mask: &StrokeMask,
    params: &EnergyParams,
    color_cue: bool,
    segments: Option<&crate::segment::SegmentFile>,
) -> Result<Coarse, SelectError> {
    let t = Instant::now();
    let mut s = seeds::markup(mask, buffers)?;
    let claims = segments.map(|file| {
        let view = ViewSegments::of(file, buffers);
        let claims = StrokeClaims::of(&view, &s);
        s.segments = Some(claims.prior(&view, &s.role));
        claims
    });
    let models = (
        SeedModel::fit(buffers, &s.fg_samples, params.clusters),
        SeedModel::fit(buffers, &s.bg_samples, params.clusters),
    );
    let seeds_ms = t.elapsed().as_secs_f64() * 1e3;
    let (mut selected, stats) =
        graph_cut::graph_cut_with(buffers, &s, params, color_cue, models.clone())?;
    graph_cut::keep_connected_to_seeds(&mut selected, &s);
    let (w, h) = (buffers.width as usize, buffers.height as usize);
    Ok(Coarse {
        width: w,
        height: h,
        near_selected: near(&selected, true, w, h, BAND),
        near_unselected: near(&selected, false, w, h, BAND),
        stroke_position: s.stroke_position.take(),
        stroke_distance: s.stroke_distance.take(),
        claims,
        models,
        stats,
        seeds_ms,
    })
}

impl Coarse {
    /// The full-resolution window `[x, y, width, height]` of a `w` × `h` view holding every
    /// pixel the coarse selection or its band may select; `None` when nothing is selected.
    fn window(&self, w: u32, h: u32) -> Option<[u32; 4]> {
        let (cw, ch) = (self.width, self.height);
        let [x0, y0, x1, y1] = mask::bounding_box(self.near_selected.iter().copied(), cw)?;
        // Coarse pixel c covers full-resolution pixels [⌈c·w/cw⌉, ⌈(c+1)·w/cw⌉); one more of
        // margin for rounding.
        let (w, h) = (w as usize, h as usize);
        let fx0 = (x0 * w / cw).saturating_sub(1);
        let fy0 = (y0 * h / ch).saturating_sub(1);
        let fx1 = ((x1 * w).div_ceil(cw) + 1).min(w);
        let fy1 = ((y1 * h).div_ceil(ch) + 1).min(h);
        Some([
            fx0 as u32,
            fy0 as u32,
            (fx1 - fx0) as u32,
            (fy1 - fy0) as u32,
        ])
    }

    /// The fine level's seeds on `buffers`: strokes hard, pixels the coarse cut decides hard,
    /// the band unknown.
    fn fine_seeds(
        &self,
        mask: &StrokeMask,
        buffers: &Buffers<'_>,
        segments: Option<&crate::segment::SegmentFile>,
    ) -> Seeds {
        let (w, h) = (buffers.width as usize, buffers.height as usize);
        let dims = [w, h, self.width, self.height];
        let n = w * h;
        // `coarse_of` split by axis: coarse row offset per row, coarse column per column.
        let row: Vec<usize> = (0..h).map(|y| coarse_of(0, y, dims)).collect();
        let col: Vec<usize> = (0..w).map(|x| coarse_of(x, 0, dims)).collect();
        let coarse_of = |i: usize| row[i / w] + col[i % w];
        let mut role = vec![OFF; n];
        let (mut fg, mut bg) = (Vec::new(), Vec::new());
        for (i, r) in role.iter_mut().enumerate() {
            if !buffers.covered(i) {
                continue;
            }
            *r = match mask.labels.get(i) {
                Some(&mask::FOREGROUND) => {
                    fg.push(i as u32);
                    FG
                }
                Some(&mask::BACKGROUND) => {
                    bg.push(i as u32);
                    BG
                }
                _ => {
                    let c = coarse_of(i);
                    match (self.near_selected[c], self.near_unselected[c]) {
                        (true, true) => UNKNOWN,
                        (true, false) => FG,
                        (false, _) => BG,
                    }
                }
            };
        }
        // A coarse per-pixel field read at each full-resolution pixel.
        let upsample = |coarse: &Option<Vec<f32>>| {
            coarse
                .as_ref()
                .map(|c| (0..n).map(|i| c[coarse_of(i)]).collect())
        };
        let mut s = Seeds {
            width: buffers.width,
            height: buffers.height,
            role,
            fg_samples: fg,
            bg_samples: bg,
            band_position: None,
            stroke_position: upsample(&self.stroke_position),
            stroke_distance: upsample(&self.stroke_distance),
            segments: None,
        };
        if let (Some(file), Some(claims)) = (segments, &self.claims) {
            let view = ViewSegments::of(file, buffers);
            s.segments = Some(claims.prior(&view, &s.role));
        }
        s
    }
}

/// Markup on `camera`'s view of `model`, coarse to fine (see the module documentation):
/// the full-resolution frame of the window holding the selection (embedded in the view), the
/// selected pixels on it, and the milliseconds spent rendering both levels.
pub fn markup_on_view(
    renderer: &Renderer,
    model: &RenderModel,
    camera: &Camera,
    mask: &StrokeMask,
    params: &EnergyParams,
    options: &RenderOptions,
) -> Result<(Frame, PixelSelection, f64), ViewSelectError> {
    params.validate()?;
    let (w, h) = (camera.width, camera.height);
    if mask.width != w || mask.height != h {
        return Err(SelectError::SizeMismatch {
            what: "the stroke mask",
            got_w: mask.width,
            got_h: mask.height,
            width: w,
            height: h,
        }
        .into());
    }
    let color_cue = model.lod().has_colors();
    let segments = model.segments();

    let coarse_cam = coarse_camera(camera);
    let coarse_frame = renderer.render(
        model,
        &coarse_cam,
        &RenderOptions {
            window: None,
            ..options.clone()
        },
        &[],
    )?;
    let mut render_ms = coarse_frame.stats.total_ms;
    let coarse_buffers = Buffers::from_frame(&coarse_frame)?;
    if coarse_buffers.covered_count() == 0 {
        return Err(SelectError::NothingVisible.into());
    }
    let coarse_mask = reduce_mask(mask, coarse_cam.width, coarse_cam.height);
    let coarse = coarse_cut(&coarse_buffers, &coarse_mask, params, color_cue, segments)?;
    drop(coarse_frame);

    let window = coarse.window(w, h);
    let frame = renderer
        .render(
            model,
            camera,
            &RenderOptions {
                window,
                ..options.clone()
            },
            &[],
        )?
        .embed(w, h);
    render_ms += frame.stats.total_ms;
    let buffers = Buffers::from_frame(&frame)?;
    if buffers.covered_count() == 0 {
        return Err(SelectError::NothingVisible.into());
    }
    let t = Instant::now();
    let fine = coarse.fine_seeds(mask, &buffers, segments);
    let seeds_ms = coarse.seeds_ms + t.elapsed().as_secs_f64() * 1e3;
    let (mut selected, stats) =
        graph_cut::graph_cut_with(&buffers, &fine, params, color_cue, coarse.models.clone())?;
    graph_cut::keep_connected_to_seeds(&mut selected, &fine);
    let count = selected.iter().filter(|&&s| s).count();
    let cut = CutStats {
        nodes: coarse.stats.nodes + stats.nodes,
        unknown: coarse.stats.unknown + stats.unknown,
        flow: stats.flow,
        build_ms: coarse.stats.build_ms + stats.build_ms,
        solve_ms: coarse.stats.solve_ms + stats.solve_ms,
    };
    let selection = PixelSelection {
        width: w,
        height: h,
        selected,
        count,
        cut: Some(cut),
        seeds_ms,
    };
    Ok((frame, selection, render_ms))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mask_is_reduced_by_majority_and_pixels_map_to_their_block() {
        let mut m = StrokeMask::empty(5, 3).unwrap();
        // Row 0: F F B . B ; row 1: F B B . . ; row 2: . . . . F
        for (i, l) in [1, 1, 2, 0, 2, 1, 2, 2, 0, 0, 0, 0, 0, 0, 1]
            .iter()
            .enumerate()
        {
            m.labels[i] = *l;
        }
        let r = reduce_mask(&m, 3, 2);
        // Block (0,0) = {F,F,F,B}: F; block (1,0) = {B,.,B,.}: B; block (2,0) = {B,.}: B;
        // block (0,1) = {.,.}: none; (1,1) = {.,.}: none; (2,1) = {F}: F.
        assert_eq!(r.labels, vec![1, 2, 2, 0, 0, 1]);
        assert_eq!(coarse_of(4, 2, [5, 3, 3, 2]), 5);
        assert_eq!(coarse_of(1, 1, [5, 3, 3, 2]), 0);
    }

    #[test]
    fn near_dilates_by_the_radius() {
        let (w, h) = (7, 5);
        let mut s = vec![false; w * h];
        s[2 * w + 3] = true;
        let d = near(&s, true, w, h, 1);
        let on: Vec<usize> = (0..w * h).filter(|&i| d[i]).collect();
        assert_eq!(
            on,
            vec![
                w + 2,
                w + 3,
                w + 4,
                2 * w + 2,
                2 * w + 3,
                2 * w + 4,
                3 * w + 2,
                3 * w + 3,
                3 * w + 4
            ]
        );
        let u = near(&s, false, w, h, 1);
        assert!(
            u.iter().all(|&b| b),
            "every pixel has an unselected one within 1"
        );
    }
}
