//! One ground-truth region through the real selection API (system paper §4.3's measure):
//! a camera that frames it, its visible vertices and on-screen mask, each simulated tool's
//! strokes submitted, and `|selected Δ truth| / |truth|` for each.

use anyhow::Result;
use glam::{Quat, Vec3};
use meshwiki_engine::camera::Camera;
use meshwiki_engine::render::best_view::{BestViewOptions, framing_camera};
use meshwiki_engine::select::mask::{self, StrokeMask};
use roaring::RoaringBitmap;
use serde::Serialize;

use super::client::Api;
use super::psb::{Region, Segmentation};
use super::strokes::{self, Rng, UserModel};

/// Fewest pixels of a region on screen for it to be evaluated.
pub const MIN_PIXELS: usize = 200;
/// Fewest visible vertices of a region for it to be evaluated.
pub const MIN_VISIBLE: u64 = 20;

/// The tools evaluated, in the order they are reported; the last is the reference.
pub const TOOLS: [(&str, &str); 4] = [
    ("heavy_lasso", "heavy lasso"),
    ("markup", "markup"),
    ("lasso", "lasso"),
    ("exact_mask", "exact mask (ref.)"),
];

/// One tool on one region.
#[derive(Debug, Clone, Serialize)]
pub struct ToolResult {
    pub tool: &'static str,
    /// `|S Δ T| / |T|` (1 when the server refused the strokes: nothing selected).
    pub error: f64,
    pub false_positives: u64,
    pub false_negatives: u64,
    pub selected: u64,
    /// Wall time of the POST, milliseconds (absent when refused).
    pub latency_ms: Option<f64>,
    pub server_ms: Option<f64>,
    /// The server's message when it refused the strokes.
    pub refused: Option<String>,
}

/// One region's outcome.
#[derive(Debug, Clone, Serialize)]
pub struct RegionResult {
    pub model: u32,
    pub category: &'static str,
    pub segment: u32,
    pub region_vertices: u64,
    pub visible_truth: u64,
    pub pixels: usize,
    pub camera: serde_json::Value,
    /// Heavy band width drawn and markup pixels.
    pub band_px: f32,
    pub markup_pixels: [usize; 2],
    pub tools: Vec<ToolResult>,
}

/// Why a region was left out.
#[derive(Debug, Clone, Serialize)]
pub enum Skip {
    /// Fewer than [`MIN_PIXELS`] on screen or [`MIN_VISIBLE`] visible vertices.
    BarelyVisible { pixels: usize, visible: u64 },
}

/// Directions tried to frame a region: its mean normal, then tilted by 35° and 65° at six
/// azimuths (as `engine::render::best_view`).
fn directions(normal: Vec3) -> Vec<Vec3> {
    let n = if normal.length_squared() > 1e-12 {
        normal.normalize()
    } else {
        Vec3::Z
    };
    let side = n.any_orthonormal_vector();
    let mut out = vec![n];
    for tilt in [35f32, 65.0] {
        for k in 0..6 {
            let axis = Quat::from_axis_angle(n, k as f32 * std::f32::consts::TAU / 6.0) * side;
            out.push((Quat::from_axis_angle(axis, tilt.to_radians()) * n).normalize());
        }
    }
    out
}

fn region_mask(ids: &[u32], seg: &Segmentation, segment: u32) -> Vec<bool> {
    ids.iter()
        .map(|&v| seg.vertex_segment.get(v as usize) == Some(&segment))
        .collect()
}

/// The camera that frames `region` and shows most of it: each direction is probed at a
/// quarter of the size through the render API, scored by the region's pixels; a direction
/// replaces the mean normal's only when it shows 15 % more.
fn frame(api: &Api, model: i64, seg: &Segmentation, region: &Region, w: u32, h: u32) -> Result<Camera> {
    let opts = BestViewOptions {
        fovy_deg: 40.0,
        margin: 1.3,
        ..BestViewOptions::default()
    };
    let (pw, ph) = ((w / 4).max(16), (h / 4).max(16));
    let mut best: Option<(Vec3, usize)> = None;
    for dir in directions(region.normal) {
        let probe = framing_camera(region.center, dir, region.extent, &opts, pw, ph);
        let ids = api.vertex_ids(model, &probe)?;
        let score = region_mask(&ids, seg, region.segment)
            .iter()
            .filter(|&&b| b)
            .count();
        if best.is_none_or(|(_, s)| score as f64 > s as f64 * 1.15) {
            best = Some((dir, score));
        }
    }
    let dir = best.map_or(Vec3::Z, |(d, _)| d);
    Ok(framing_camera(region.center, dir, region.extent, &opts, w, h))
}

fn score(tool: &'static str, truth: &RoaringBitmap, got: Result<(RoaringBitmap, f64, f64), String>) -> ToolResult {
    let (set, latency, server, refused) = match got {
        Ok((s, l, sv)) => (s, Some(l), Some(sv), None),
        Err(msg) => (RoaringBitmap::new(), None, None, Some(msg)),
    };
    let fp = set.difference_len(truth);
    let fneg = truth.difference_len(&set);
    ToolResult {
        tool,
        error: (fp + fneg) as f64 / truth.len().max(1) as f64,
        false_positives: fp,
        false_negatives: fneg,
        selected: set.len(),
        latency_ms: latency,
        server_ms: server,
        refused,
    }
}

/// Submits one stroke mask as `tool` and fetches the draft's vertices.
fn submit(
    api: &Api,
    model: i64,
    tool: &str,
    camera: &Camera,
    labels: Vec<u8>,
) -> Result<std::result::Result<(RoaringBitmap, f64, f64), String>> {
    let m = StrokeMask::new(camera.width, camera.height, labels)?;
    Ok(match api.select(model, tool, camera, &m.encode_png())? {
        Ok(d) => {
            let set = api.take_vertices(&d.id)?;
            if set.len() != d.vertex_count {
                tracing::warn!(draft = %d.id, "vertex count {} but {} vertices", d.vertex_count, set.len());
            }
            Ok((set, d.latency_ms, d.server_ms))
        }
        Err(msg) => Err(msg),
    })
}

/// What one region is evaluated with.
pub struct Case<'a> {
    pub api: &'a Api,
    pub model_id: i64,
    pub psb_id: u32,
    pub seg: &'a Segmentation,
    pub region: &'a Region,
    pub width: u32,
    pub height: u32,
    pub user: UserModel,
    pub seed: u64,
}

/// Evaluates every tool on one region.
pub fn region(c: &Case<'_>) -> Result<std::result::Result<RegionResult, Skip>> {
    let (w, h) = (c.width as usize, c.height as usize);
    let camera = frame(c.api, c.model_id, c.seg, c.region, c.width, c.height)?;
    let ids = c.api.vertex_ids(c.model_id, &camera)?;
    let on_screen = region_mask(&ids, c.seg, c.region.segment);
    let covered: Vec<bool> = ids.iter().map(|&v| v != u32::MAX).collect();
    let pixels = on_screen.iter().filter(|&&b| b).count();

    // Visible ground truth: what a lasso over the whole view selects, within the region.
    let whole = vec![mask::LASSO; w * h];
    let visible = match submit(c.api, c.model_id, "lasso", &camera, whole)? {
        Ok((set, _, _)) => set,
        Err(_) => RoaringBitmap::new(),
    };
    let truth = &visible & &c.region.vertices;
    if pixels < MIN_PIXELS || truth.len() < MIN_VISIBLE {
        return Ok(Err(Skip::BarelyVisible {
            pixels,
            visible: truth.len(),
        }));
    }

    let stream = (c.psb_id as u64) << 32 | c.region.segment as u64;
    let mut rng = Rng::new(c.seed, stream);
    let s = strokes::draw(&on_screen, &covered, w, h, c.user, &mut rng);
    let exact: Vec<u8> = on_screen
        .iter()
        .map(|&b| if b { mask::LASSO } else { mask::NONE })
        .collect();
    let mut tools = Vec::new();
    for ((name, _), labels) in TOOLS.iter().zip([s.heavy_lasso, s.markup, s.lasso, exact]) {
        let api_tool = if *name == "exact_mask" { "lasso" } else { *name };
        let got = submit(c.api, c.model_id, api_tool, &camera, labels)?;
        if let Err(msg) = &got {
            tracing::info!(model = c.psb_id, segment = c.region.segment, tool = name, "refused: {msg}");
        }
        tools.push(score(name, &truth, got));
    }
    tracing::debug!(
        model = c.psb_id,
        segment = c.region.segment,
        pixels,
        truth = truth.len(),
        errors = ?tools.iter().map(|t| t.error).collect::<Vec<_>>(),
        "region"
    );
    Ok(Ok(RegionResult {
        model: c.psb_id,
        category: super::psb::category(c.psb_id),
        segment: c.region.segment,
        region_vertices: c.region.vertices.len(),
        visible_truth: truth.len(),
        pixels,
        camera: super::client::camera_json(&camera),
        band_px: s.band_px,
        markup_pixels: [s.markup_fg, s.markup_bg],
        tools,
    }))
}
