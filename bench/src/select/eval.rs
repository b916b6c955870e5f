//! One ground-truth region through the real selection API (system paper §4.3's measure):
//! a camera that frames it, its visible vertices and on-screen mask, each simulated tool's
//! strokes submitted, and `|selected Δ truth| / |truth|` for each.
//!
//! Vertices on the segment boundary belong to the region and to its neighbour (a `.seg`
//! labels faces): selecting them or not is right either way, so they are not counted as
//! mis-selected (`error`); `strict_error` counts them.

use std::path::Path;

use anyhow::{Context, Result};
use glam::{Quat, Vec3};
use meshwiki_engine::camera::Camera;
use meshwiki_engine::render::best_view::{BestViewOptions, framing_camera};
use meshwiki_engine::select::mask::{self, StrokeMask};
use roaring::RoaringBitmap;
use serde::Serialize;

use super::client::{Api, Stages};
use super::strokes::{self, Rng, UserModel};
use super::truth::{Region, Segmentation};

/// Fewest pixels of a region on screen for it to be evaluated.
pub const MIN_PIXELS: usize = 200;
/// Fewest visible vertices of a region for it to be evaluated.
pub const MIN_VISIBLE: u64 = 20;

/// The tools evaluated, in the order they are reported: the three tools, the exact
/// on-screen mask sent as a lasso (the reference: what back-projection alone loses), and the
/// two graph-cut tools on the pixels alone (surface segments off: `w_seg` 0, `seg_edge` 1),
/// side by side with the same strokes.
pub const TOOLS: [(&str, &str); 6] = [
    ("heavy_lasso", "heavy lasso"),
    ("markup", "markup"),
    ("lasso", "lasso"),
    ("exact_mask", "exact mask (ref.)"),
    ("heavy_lasso_pixels", "heavy lasso, pixels"),
    ("markup_pixels", "markup, pixels"),
];

/// The API tool and energy parameters of a [`TOOLS`] entry; `params` (the `--params`
/// option) are sent with the heavy lasso and markup, under the pixels-only overrides.
fn api_of(
    name: &str,
    params: Option<&serde_json::Value>,
) -> (&'static str, Option<serde_json::Value>) {
    let with = |extra: serde_json::Value| {
        let mut p = params.cloned().unwrap_or_else(|| serde_json::json!({}));
        if let (Some(p), Some(e)) = (p.as_object_mut(), extra.as_object()) {
            p.extend(e.clone());
        }
        Some(p).filter(|p| p.as_object().is_some_and(|o| !o.is_empty()))
    };
    let pixels_only = || {
        with(
            serde_json::json!({"w_seg": 0.0, "w_seg_out": 0.0, "w_seg_apart": 0.0, "w_seg_far": 0.0, "seg_edge": 1.0}),
        )
    };
    match name {
        "heavy_lasso" => ("heavy_lasso", with(serde_json::json!({}))),
        "markup" => ("markup", with(serde_json::json!({}))),
        "heavy_lasso_pixels" => ("heavy_lasso", pixels_only()),
        "markup_pixels" => ("markup", pixels_only()),
        _ => ("lasso", None),
    }
}

/// One tool on one region.
#[derive(Debug, Clone, Serialize)]
pub struct ToolResult {
    pub tool: &'static str,
    /// `|(S Δ T) \ boundary| / |T|` (1 when the server refused the strokes: nothing
    /// selected).
    pub error: f64,
    /// `|S Δ T| / |T|`.
    pub strict_error: f64,
    pub false_positives: u64,
    pub false_negatives: u64,
    pub selected: u64,
    /// Strokes sent (a second one subtracts the holes of the region's outline).
    pub strokes: usize,
    /// Wall time of each POST, milliseconds (none when the first was refused).
    pub latency_ms: Vec<f64>,
    /// The server's timings of each POST, per stage.
    pub stages: Vec<Stages>,
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
fn frame(
    api: &Api,
    model: i64,
    seg: &Segmentation,
    region: &Region,
    w: u32,
    h: u32,
) -> Result<Camera> {
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
    Ok(framing_camera(
        region.center,
        dir,
        region.extent,
        &opts,
        w,
        h,
    ))
}

/// What a tool's strokes gave: the selected vertices, each POST's latency and server time,
/// or the server's refusal of the first stroke.
struct Submitted {
    set: RoaringBitmap,
    latency_ms: Vec<f64>,
    stages: Vec<Stages>,
    refused: Option<String>,
}

fn score(
    tool: &'static str,
    truth: &RoaringBitmap,
    boundary: &RoaringBitmap,
    got: &Submitted,
) -> ToolResult {
    let extra = &got.set - truth;
    let missed = truth - &got.set;
    let fp = extra.difference_len(boundary);
    let fneg = missed.difference_len(boundary);
    let n = truth.len().max(1) as f64;
    ToolResult {
        tool,
        error: (fp + fneg) as f64 / n,
        strict_error: (extra.len() + missed.len()) as f64 / n,
        false_positives: fp,
        false_negatives: fneg,
        selected: got.set.len(),
        strokes: got.latency_ms.len(),
        latency_ms: got.latency_ms.clone(),
        stages: got.stages.clone(),
        refused: got.refused.clone(),
    }
}

/// Submits the strokes of one tool — the first replaces, the others (around holes) are
/// subtracted from the draft so far — and fetches the final draft's vertices. With `dump`,
/// each step's selected pixels are written there with the strokes and the region.
fn submit(
    api: &Api,
    model: i64,
    (tool, params): (&str, Option<&serde_json::Value>),
    camera: &Camera,
    steps: Vec<Vec<u8>>,
    dump: Option<(&Path, &[bool], &[bool])>,
) -> Result<Submitted> {
    let mut out = Submitted {
        set: RoaringBitmap::new(),
        latency_ms: Vec::new(),
        stages: Vec::new(),
        refused: None,
    };
    let mut draft: Option<String> = None;
    let mut count = 0;
    for (k, labels) in steps.into_iter().enumerate() {
        let m = StrokeMask::new(camera.width, camera.height, labels)?;
        match api.select(
            model,
            tool,
            params,
            camera,
            &m.encode_png(),
            draft.as_deref(),
        )? {
            Ok(d) => {
                if let Some((path, region, covered)) = dump {
                    let png = api.selection_png(&d.id)?;
                    let path = if k == 0 {
                        path.to_path_buf()
                    } else {
                        path.with_extension(format!("{}.png", k + 1))
                    };
                    write_dump(&path, &m, region, covered, &png)?;
                }
                count = d.vertex_count;
                out.latency_ms.push(d.latency_ms);
                out.stages.push(d.stages);
                if let Some(old) = draft.replace(d.id) {
                    api.discard(&old)?;
                }
            }
            // A refused first stroke selects nothing; a refused later one changes nothing.
            Err(msg) => {
                tracing::info!(tool, step = k + 1, "refused: {msg}");
                if k == 0 {
                    out.refused = Some(msg);
                    return Ok(out);
                }
            }
        }
    }
    if let Some(d) = draft {
        out.set = api.vertices(&d)?;
        if out.set.len() != count {
            tracing::warn!(draft = %d, "the draft has {count} vertices but its set {}", out.set.len());
        }
        api.discard(&d)?;
    }
    Ok(out)
}

/// Writes a picture of a selection: the model grey, the region green, the selected pixels
/// blue, the strokes red (heavy band, lasso outline), yellow (foreground) and magenta
/// (background).
fn write_dump(
    path: &Path,
    strokes: &StrokeMask,
    region: &[bool],
    covered: &[bool],
    selection_png: &[u8],
) -> Result<()> {
    let sel = image::load_from_memory_with_format(selection_png, image::ImageFormat::Png)
        .context("the selection mask is not a PNG")?
        .to_rgba8();
    let (w, h) = (strokes.width, strokes.height);
    let l = &strokes.labels;
    let mut img = image::RgbImage::new(w, h);
    for (x, y, p) in img.enumerate_pixels_mut() {
        let i = (y * w + x) as usize;
        let mut c = if covered[i] {
            [90u8, 90, 90]
        } else {
            [20, 20, 20]
        };
        if region[i] {
            c[1] = 150;
        }
        if sel.get_pixel(x, y).0[3] > 0 {
            c[2] = 255;
        }
        let lasso_edge = l[i] == mask::LASSO
            && [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .any(|(dx, dy)| {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    nx >= 0
                        && ny >= 0
                        && nx < w as i64
                        && ny < h as i64
                        && l[(ny as u32 * w + nx as u32) as usize] != mask::LASSO
                });
        match l[i] {
            mask::HEAVY => c[0] = 200,
            mask::FOREGROUND => c = [255, 255, 0],
            mask::BACKGROUND => c = [255, 0, 255],
            _ if lasso_edge => c = [255, 0, 0],
            _ => {}
        }
        *p = image::Rgb(c);
    }
    img.save(path)
        .with_context(|| format!("writing {}", path.display()))
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
    /// Write pictures of every selection here.
    pub dump: Option<&'a Path>,
    /// Energy parameters sent with the heavy lasso and markup.
    pub params: Option<&'a serde_json::Value>,
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
    let visible = submit(
        c.api,
        c.model_id,
        ("lasso", None),
        &camera,
        vec![whole],
        None,
    )?
    .set;
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
    let steps = |first: Vec<u8>, holes: Option<Vec<u8>>| {
        [Some(first), holes].into_iter().flatten().collect()
    };
    let heavy: Vec<Vec<u8>> = steps(s.heavy_lasso, s.heavy_lasso_holes);
    let all: [Vec<Vec<u8>>; 6] = [
        heavy.clone(),
        vec![s.markup.clone()],
        steps(s.lasso, s.lasso_holes),
        vec![exact],
        heavy,
        vec![s.markup],
    ];
    for ((name, _), labels) in TOOLS.iter().zip(all) {
        let (api_tool, params) = api_of(name, c.params);
        let file = c
            .dump
            .map(|d| d.join(format!("{}_{}_{name}.png", c.psb_id, c.region.segment)));
        let dump = file.as_deref().map(|f| (f, &on_screen[..], &covered[..]));
        let got = submit(
            c.api,
            c.model_id,
            (api_tool, params.as_ref()),
            &camera,
            labels,
            dump,
        )?;
        tools.push(score(name, &truth, &c.region.shared, &got));
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
