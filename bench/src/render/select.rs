//! Selection latency on the model of `bench render` (issue 15, item 3): on cameras of the path,
//! each tool runs the engine's whole selection on the view (`select_on_view`: render the
//! buffers the tool reads, seeds, graph, max-flow, back-projection to original vertex ids) on
//! strokes a user might draw around a region of the visible surface, and the p50 of every stage
//! is printed per tool. The region is a disc on screen around the middle covered pixel, its
//! radius a quarter of the visible model's own (about 1/16 of what is seen): the lasso fills
//! it, the heavy lasso traces its outline with a 12-pixel band, markup draws a foreground dot
//! inside and a background ring outside, the point tool clicks its centre.

use std::time::Instant;

use anyhow::{Context, Result};
use meshwiki_engine::camera::Camera;
use meshwiki_engine::render::{NO_NODE, Outputs, RenderModel, RenderOptions, Renderer};
use meshwiki_engine::select::{EnergyParams, Input, StrokeMask, Tool, mask, select_on_view};

use super::{PIXEL_ERROR, percentile};

/// Width of the heavy lasso's band, pixels (as `bench select`).
const BAND: f32 = 12.0;

const TOOLS: [&str; 4] = ["heavy lasso", "markup", "lasso", "point"];

/// One selection's stages, milliseconds.
#[derive(Debug, Clone, Copy, Default)]
struct Stages {
    render: f64,
    seeds: f64,
    graph: f64,
    maxflow: f64,
    backproject: f64,
    total: f64,
}

/// The region's disc on screen: centre and radius in pixels, or `None` when nothing is seen.
fn region(
    renderer: &Renderer,
    model: &RenderModel,
    cam: &Camera,
) -> Result<Option<([f32; 2], f32)>> {
    let options = RenderOptions {
        outputs: Outputs {
            color: false,
            normal: false,
            depth: false,
            ids: true,
        },
        ..RenderOptions::default()
    };
    let frame = renderer.render(model, cam, &options, &[])?;
    let Some(ids) = &frame.ids else {
        return Ok(None);
    };
    let covered: Vec<usize> = (0..ids.node.len())
        .filter(|&i| ids.node[i] != NO_NODE)
        .collect();
    let Some(&middle) = covered.get(covered.len() / 2) else {
        return Ok(None);
    };
    let w = cam.width as usize;
    let centre = [(middle % w) as f32 + 0.5, (middle / w) as f32 + 0.5];
    let radius = 0.25 * (covered.len() as f32 / std::f32::consts::PI).sqrt();
    Ok(Some((centre, radius.max(2.0 * BAND))))
}

/// The strokes of `tool` around the disc.
fn strokes(tool: &str, cam: &Camera, [cx, cy]: [f32; 2], r: f32) -> Result<StrokeMask> {
    let mut m = StrokeMask::empty(cam.width, cam.height)?;
    let w = cam.width as usize;
    for (i, label) in m.labels.iter_mut().enumerate() {
        let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
        let d = ((x - cx).powi(2) + (y - cy).powi(2)).sqrt();
        *label = match tool {
            "lasso" if d <= r => mask::LASSO,
            "heavy lasso" if (d - r).abs() <= BAND * 0.5 => mask::HEAVY,
            "markup" if d <= r * 0.3 => mask::FOREGROUND,
            "markup" if (d - r * 1.6).abs() <= 3.0 => mask::BACKGROUND,
            _ => mask::NONE,
        };
    }
    Ok(m)
}

/// Runs every tool on `cameras` and prints the p50 of each stage per tool.
pub fn run(renderer: &Renderer, model: &RenderModel, cameras: &[Camera]) -> Result<()> {
    let params = EnergyParams::default();
    let mut per_tool: Vec<Vec<Stages>> = vec![Vec::new(); TOOLS.len()];
    let mut refused = vec![0usize; TOOLS.len()];
    for cam in cameras {
        let Some((centre, r)) = region(renderer, model, cam).context("region")? else {
            continue;
        };
        for (k, tool) in TOOLS.iter().enumerate() {
            let m;
            let input = match *tool {
                "point" => Input::Click(centre),
                _ => {
                    m = strokes(tool, cam, centre, r)?;
                    let tool = match *tool {
                        "heavy lasso" => Tool::HeavyLasso,
                        "markup" => Tool::Markup,
                        _ => Tool::Lasso,
                    };
                    Input::Strokes {
                        tool,
                        mask: &m,
                        params: &params,
                    }
                }
            };
            let t = Instant::now();
            match select_on_view(renderer, model, cam, input, PIXEL_ERROR, None) {
                Ok(s) => per_tool[k].push(Stages {
                    render: s.render_ms,
                    seeds: s.seeds_ms,
                    graph: s.cut.as_ref().map_or(0.0, |c| c.build_ms),
                    maxflow: s.cut.as_ref().map_or(0.0, |c| c.solve_ms),
                    backproject: s.backprojection.ms,
                    total: t.elapsed().as_secs_f64() * 1e3,
                }),
                Err(e) => {
                    tracing::info!(tool, "refused: {e}");
                    refused[k] += 1;
                }
            }
        }
    }
    println!(
        "selection on the view ({} cameras of the path, a region of ~1/16 of the visible model; engine path, no HTTP), p50 ms:",
        cameras.len()
    );
    println!(
        "  {:<12} {:>8} {:>8} {:>8} {:>8} {:>10} {:>8} {:>8}",
        "tool", "render", "seeds", "graph", "max-flow", "back-proj.", "total", "refused"
    );
    for (k, tool) in TOOLS.iter().enumerate() {
        let s = &per_tool[k];
        let p = |f: fn(&Stages) -> f64| {
            let mut v: Vec<f64> = s.iter().map(f).collect();
            v.sort_by(f64::total_cmp);
            percentile(&v, 0.5)
        };
        println!(
            "  {:<12} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>10.1} {:>8.1} {:>8}",
            tool,
            p(|s| s.render),
            p(|s| s.seeds),
            p(|s| s.graph),
            p(|s| s.maxflow),
            p(|s| s.backproject),
            p(|s| s.total),
            refused[k]
        );
    }
    Ok(())
}
