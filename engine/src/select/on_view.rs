//! Selection on a view, in one call (system paper §4.1): render the view's colour, normal,
//! depth and id buffers from the view-dependent cut, select pixels (the graph cut of the
//! strokes, §4.2, or a single click), and back-project them to original vertex ids of the
//! full-resolution scan (§4.1.2). The server runs this on its render pool; the viewer only
//! ever sends strokes and a camera.

use std::time::Instant;

use roaring::RoaringBitmap;

use super::SelectError;
use super::backproject::{BackProjectOptions, BackProjection, back_project};
use super::buffers::Buffers;
use super::energy::EnergyParams;
use super::graph_cut::CutStats;
use super::mask::{self, StrokeMask};
use super::multilevel;
use super::pipeline::{PixelSelection, Tool, select_pixels};
use super::point::{self, PickedPoint};
use super::suggest::select_segment;
use crate::camera::Camera;
use crate::lod::Culling;
use crate::render::{Cut, Outputs, RenderError, RenderModel, RenderOptions, Renderer};

/// What selects on the view: strokes for a tool, or a click.
#[derive(Debug, Clone, Copy)]
pub enum Input<'a> {
    /// A tool's stroke mask (of the camera's size).
    Strokes {
        /// The tool.
        tool: Tool,
        /// The strokes.
        mask: &'a StrokeMask,
        /// The energy's weights.
        params: &'a EnergyParams,
    },
    /// A click at pixel `[x, y]`: the nearest visible vertex (a point part).
    Click([f32; 2]),
    /// A click at pixel `point`: the whole surface segment there at `scale` (suggested
    /// regions, [`super::suggest`]).
    Segment {
        /// The clicked pixel `[x, y]`.
        point: [f32; 2],
        /// The segments' scale (0: fine).
        scale: usize,
    },
}

/// The result on the view.
#[derive(Debug, Clone)]
pub struct ViewSelection {
    /// Selected vertices (with sums against `base`, for combining modes).
    pub backprojection: BackProjection,
    /// The click's picked point.
    pub picked: Option<PickedPoint>,
    /// A segment click: the segment's scale and number.
    pub segment: Option<(usize, u32)>,
    /// Selected pixels.
    pub selected_pixels: usize,
    /// The selected pixels as a PNG (alpha 255 where selected).
    pub mask_png: Vec<u8>,
    /// The graph's statistics (strokes only).
    pub cut: Option<CutStats>,
    /// Rendering the buffers, milliseconds.
    pub render_ms: f64,
    /// Selecting the pixels, milliseconds (seeds, graph and max-flow together, or the click).
    pub cut_ms: f64,
    /// Of `cut_ms`: placing the seeds, milliseconds (0 for a click).
    pub seeds_ms: f64,
}

/// Why a selection on a view failed.
#[derive(Debug, thiserror::Error)]
pub enum ViewSelectError {
    /// Rendering the buffers failed.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// The selection failed (most variants: bad input).
    #[error(transparent)]
    Select(#[from] SelectError),
}

/// Pixels kept around the strokes' bounding box (the heavy lasso's outer marker needs the
/// area outside its band to be seen from the window's border).
const WINDOW_MARGIN: u32 = 2;
/// Half the side of the square drawn around a click.
const CLICK_RADIUS: u32 = 4;

/// The part of the view a selection reads, `[x, y, width, height]` (`None`: all of it). The
/// lasso selects only inside its outline and the heavy lasso's cut only decides its band, so
/// both need only their strokes' bounding box (plus [`WINDOW_MARGIN`]); a click needs its
/// pixel. Markup's cut decides every pixel of the view (a short stroke may claim a part much
/// larger than the strokes' box): it reads the whole view, coarse to fine on views of at
/// least [`multilevel::MIN_PIXELS`] ([`multilevel`]). Inside the
/// window the buffers are those of the whole view (the same cut, drawn with an off-centre
/// crop of the same projection), so the selection is the same.
fn window(input: &Input<'_>, camera: &Camera) -> Option<[u32; 4]> {
    let (w, h) = (camera.width, camera.height);
    let square = |x0: u32, y0: u32, x1: u32, y1: u32, margin: u32| {
        let (x0, y0) = (x0.saturating_sub(margin), y0.saturating_sub(margin));
        let (x1, y1) = ((x1 + 1 + margin).min(w), (y1 + 1 + margin).min(h));
        (x0 < x1 && y0 < y1).then_some([x0, y0, x1 - x0, y1 - y0])
    };
    match *input {
        Input::Click([x, y]) | Input::Segment { point: [x, y], .. } => {
            if !(x.is_finite() && y.is_finite() && x >= 0.0 && y >= 0.0) {
                return None;
            }
            let (x, y) = (x as u32, y as u32);
            if x >= w || y >= h {
                return None;
            }
            square(x, y, x, y, CLICK_RADIUS)
        }
        Input::Strokes { tool, mask, .. } => {
            if mask.width != w || mask.height != h || tool == Tool::Markup {
                return None;
            }
            let drawn = mask.labels.iter().map(|&l| l != 0);
            let [x0, y0, x1, y1] = mask::bounding_box(drawn, w as usize)?.map(|v| v as u32);
            // `square` takes the last pixel, not the end.
            square(x0, y0, x1 - 1, y1 - 1, WINDOW_MARGIN)
        }
    }
}

/// Renders `camera`'s buffers of `model` with a view cut of `pixel_error`, selects `input` on
/// them and back-projects to original vertex ids; `base` is the vertex set the result will
/// be combined with (its sums are counted, see [`BackProjection`]).
pub fn select_on_view(
    renderer: &Renderer,
    model: &RenderModel,
    camera: &Camera,
    input: Input<'_>,
    pixel_error: f32,
    base: Option<&RoaringBitmap>,
) -> Result<ViewSelection, ViewSelectError> {
    let options = RenderOptions {
        cut: Cut::View {
            pixel_error,
            culling: Culling::ALL,
        },
        outputs: Outputs::ALL,
        window: window(&input, camera),
        ..RenderOptions::default()
    };
    if let Input::Strokes {
        tool: Tool::Markup,
        mask,
        params,
    } = input
        && multilevel::applies(camera)
    {
        let t = Instant::now();
        let (frame, sel, render_ms) =
            multilevel::markup_on_view(renderer, model, camera, mask, params, &options)?;
        let buffers = Buffers::from_frame(&frame)?;
        let cut_ms = t.elapsed().as_secs_f64() * 1e3 - render_ms;
        return strokes_result(model, camera, &buffers, sel, base, render_ms, cut_ms);
    }
    let frame = renderer
        .render(model, camera, &options, &[])?
        .embed(camera.width, camera.height);
    let render_ms = frame.stats.total_ms;
    let buffers = Buffers::from_frame(&frame)?;
    if buffers.covered_count() == 0 {
        return Err(SelectError::NothingVisible.into());
    }
    let t = Instant::now();
    let (w, h) = (camera.width, camera.height);
    match input {
        Input::Click([x, y]) => {
            let picked = point::pick(model.lod(), camera, &buffers, x, y)?;
            let mut selected = vec![false; buffers.len()];
            selected[picked.y as usize * w as usize + picked.x as usize] = true;
            let backprojection = BackProjection::of_point(&picked, base);
            Ok(ViewSelection {
                backprojection,
                picked: Some(picked),
                selected_pixels: 1,
                mask_png: mask::selection_png(w, h, &selected),
                cut: None,
                segment: None,
                render_ms,
                cut_ms: t.elapsed().as_secs_f64() * 1e3,
                seeds_ms: 0.0,
            })
        }
        Input::Segment {
            point: [x, y],
            scale,
        } => {
            let file = model.segments().ok_or(SelectError::NoSegments)?;
            let picked = point::pick(model.lod(), camera, &buffers, x, y)?;
            let cut_ms = t.elapsed().as_secs_f64() * 1e3;
            let chosen = select_segment(model.lod(), file, &picked, scale, base)?;
            // The view's pixels showing the segment (where the window was drawn).
            let selected: Vec<bool> = (0..buffers.len())
                .map(|i| {
                    buffers.covered(i)
                        && file.segment_of(buffers.vertex[i], scale) == Some(chosen.segment)
                })
                .collect();
            let mut backprojection = chosen.backprojection;
            backprojection.ms = t.elapsed().as_secs_f64() * 1e3 - cut_ms;
            Ok(ViewSelection {
                selected_pixels: selected.iter().filter(|s| **s).count(),
                mask_png: mask::selection_png(w, h, &selected),
                backprojection,
                picked: Some(picked),
                cut: None,
                segment: Some((chosen.scale, chosen.segment)),
                render_ms,
                cut_ms,
                seeds_ms: 0.0,
            })
        }
        Input::Strokes { tool, mask, params } => {
            let color_cue = model.lod().has_colors();
            let sel = select_pixels(tool, mask, &buffers, params, color_cue, model.segments())?;
            let cut_ms = t.elapsed().as_secs_f64() * 1e3;
            strokes_result(model, camera, &buffers, sel, base, render_ms, cut_ms)
        }
    }
}

/// The result of a stroke tool: its selected pixels back-projected.
fn strokes_result(
    model: &RenderModel,
    camera: &Camera,
    buffers: &Buffers<'_>,
    sel: PixelSelection,
    base: Option<&RoaringBitmap>,
    render_ms: f64,
    cut_ms: f64,
) -> Result<ViewSelection, ViewSelectError> {
    let backprojection = back_project(
        model.lod(),
        camera,
        buffers,
        &sel.selected,
        base,
        &BackProjectOptions::default(),
    )?;
    Ok(ViewSelection {
        mask_png: mask::selection_png(camera.width, camera.height, &sel.selected),
        selected_pixels: sel.count,
        cut: sel.cut,
        backprojection,
        picked: None,
        segment: None,
        render_ms,
        cut_ms,
        seeds_ms: sel.seeds_ms,
    })
}
