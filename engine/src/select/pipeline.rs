//! From strokes to selected pixels, per tool (system paper §4.1, §4.2): the plain lasso takes
//! its polygon; markup and the heavy lasso seed the graph ([`super::seeds`]) and cut it
//! ([`super::graph_cut`]), keeping what is connected to the foreground seeds.

use super::SelectError;
use super::buffers::Buffers;
use super::energy::EnergyParams;
use super::graph_cut::{self, CutStats};
use super::mask::StrokeMask;
use super::seeds;
use super::segments::{ViewSegments, stroke_segments};
use crate::segment::SegmentFile;

/// The selection tools.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Tool {
    /// The conventional lasso: a polygon.
    Lasso,
    /// Foreground and background strokes (Lazy Snapping).
    Markup,
    /// One thick stroke along the boundary (§4.2).
    HeavyLasso,
}

impl Tool {
    /// Name as in the API.
    pub fn as_str(self) -> &'static str {
        match self {
            Tool::Lasso => "lasso",
            Tool::Markup => "markup",
            Tool::HeavyLasso => "heavy_lasso",
        }
    }
}

/// Selected pixels of a view.
#[derive(Debug, Clone, PartialEq)]
pub struct PixelSelection {
    pub width: u32,
    pub height: u32,
    /// Per pixel, row-major: selected (always on the model).
    pub selected: Vec<bool>,
    pub count: usize,
    /// The cut, for the tools that make one.
    pub cut: Option<CutStats>,
    /// Placing the seeds (the lasso's fill, the strokes' hard constraints), milliseconds.
    pub seeds_ms: f64,
}

/// Runs `tool` on the strokes of `mask` over the rendered `buffers`. `color_cue`: whether the
/// model has colours (see [`graph_cut::graph_cut`]); `segments`: the model's surface
/// segments, when it has them (the tools that cut look up the view's, [`super::segments`]).
pub fn select_pixels(
    tool: Tool,
    mask: &StrokeMask,
    buffers: &Buffers<'_>,
    params: &EnergyParams,
    color_cue: bool,
    segments: Option<&SegmentFile>,
) -> Result<PixelSelection, SelectError> {
    buffers.check()?;
    params.validate()?;
    if mask.width != buffers.width || mask.height != buffers.height {
        return Err(SelectError::SizeMismatch {
            what: "the stroke mask",
            got_w: mask.width,
            got_h: mask.height,
            width: buffers.width,
            height: buffers.height,
        });
    }
    if buffers.covered_count() == 0 {
        return Err(SelectError::NothingVisible);
    }
    let started = std::time::Instant::now();
    let ms = |t: std::time::Instant| t.elapsed().as_secs_f64() * 1e3;
    let (selected, cut, seeds_ms) = match tool {
        Tool::Lasso => (seeds::lasso(mask, buffers)?, None, ms(started)),
        Tool::Markup | Tool::HeavyLasso => {
            let mut s = if tool == Tool::Markup {
                seeds::markup(mask, buffers)?
            } else {
                seeds::heavy_lasso(mask, buffers)?
            };
            if let Some(file) = segments {
                s.segments = Some(stroke_segments(&ViewSegments::of(file, buffers), &s));
            }
            let seeds_ms = ms(started);
            let (mut selected, stats) = graph_cut::graph_cut(buffers, &s, params, color_cue)?;
            graph_cut::keep_connected_to_seeds(&mut selected, &s);
            (selected, Some(stats), seeds_ms)
        }
    };
    let count = selected.iter().filter(|&&s| s).count();
    Ok(PixelSelection {
        width: buffers.width,
        height: buffers.height,
        selected,
        count,
        cut,
        seeds_ms,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::select::buffers::OwnedBuffers;
    use crate::select::mask;

    /// A disc of different normals inside a flat view, and a heavy lasso band drawn around it
    /// off-centre (the boundary lies anywhere inside the band).
    #[test]
    fn heavy_lasso_snaps_to_the_normal_edge_inside_the_band() {
        let (w, h) = (80u32, 80u32);
        let mut b = OwnedBuffers::flat(w, h);
        let inside = |x: f32, y: f32| (x - 40.0).powi(2) + (y - 40.0).powi(2) < 18.0f32.powi(2);
        for y in 0..h {
            for x in 0..w {
                if inside(x as f32 + 0.5, y as f32 + 0.5) {
                    b.normal[(y * w + x) as usize] = [0.0, 0.6, 0.8];
                }
            }
        }
        let mut m = StrokeMask::empty(w, h).unwrap();
        for y in 0..h {
            for x in 0..w {
                let r = ((x as f32 + 0.5 - 42.0).powi(2) + (y as f32 + 0.5 - 39.0).powi(2)).sqrt();
                if (12.0..26.0).contains(&r) {
                    m.labels[(y * w + x) as usize] = mask::HEAVY;
                }
            }
        }
        let v = b.view();
        let sel = select_pixels(
            Tool::HeavyLasso,
            &m,
            &v,
            &EnergyParams::default(),
            false,
            None,
        )
        .unwrap();
        let wrong = (0..(w * h) as usize)
            .filter(|&i| {
                let (x, y) = ((i % w as usize) as f32 + 0.5, (i / w as usize) as f32 + 0.5);
                sel.selected[i] != inside(x, y)
            })
            .count();
        assert_eq!(wrong, 0, "{} selected", sel.count);
    }

    #[test]
    fn without_cues_the_heavy_lasso_follows_the_middle_of_the_band() {
        let (w, h) = (60u32, 60u32);
        let b = OwnedBuffers::flat(w, h);
        let mut m = StrokeMask::empty(w, h).unwrap();
        for y in 0..h {
            for x in 0..w {
                let r = ((x as f32 + 0.5 - 30.0).powi(2) + (y as f32 + 0.5 - 30.0).powi(2)).sqrt();
                if (10.0..20.0).contains(&r) {
                    m.labels[(y * w + x) as usize] = mask::HEAVY;
                }
            }
        }
        let v = b.view();
        let sel = select_pixels(
            Tool::HeavyLasso,
            &m,
            &v,
            &EnergyParams::default(),
            false,
            None,
        )
        .unwrap();
        // The middle circle (r = 15) has area ≈ 707 pixels.
        let area = std::f32::consts::PI * 15.0 * 15.0;
        assert!(
            (sel.count as f32 - area).abs() < area * 0.12,
            "{} vs {area}",
            sel.count
        );
    }

    #[test]
    fn nothing_visible_and_size_mismatch_are_errors() {
        let mut b = OwnedBuffers::flat(8, 8);
        b.node.iter_mut().for_each(|n| *n = crate::render::NO_NODE);
        let m = StrokeMask::new(8, 8, vec![mask::LASSO; 64]).unwrap();
        assert_eq!(
            select_pixels(
                Tool::Lasso,
                &m,
                &b.view(),
                &EnergyParams::default(),
                false,
                None
            ),
            Err(SelectError::NothingVisible)
        );
        let b = OwnedBuffers::flat(8, 8);
        let m = StrokeMask::new(4, 4, vec![mask::LASSO; 16]).unwrap();
        assert!(matches!(
            select_pixels(
                Tool::Lasso,
                &m,
                &b.view(),
                &EnergyParams::default(),
                false,
                None
            ),
            Err(SelectError::SizeMismatch { .. })
        ));
    }
}
