//! Region selection on the server (issue 6; system paper §4): strokes in, a *draft* selection
//! of exact full-resolution vertices out; confirming a draft makes (or edits) a part.
//!
//! `POST /api/v1/models/{id}/selections` (editors) takes a multipart form with
//!
//! * `request`: JSON `{"tool", "mode", "camera", "point", "part_id", "base", "params",
//!   "pixel_error"}` — `tool` is `lasso`, `markup`, `heavy_lasso` or `point`; `mode` is
//!   `replace` (default), `add` or `subtract`; `camera` is the view the strokes were drawn on
//!   (`eye`, `target`, `up`, `fovy` in degrees, `width` and `height` in pixels); `point` the
//!   clicked pixel `[x, y]` of the point tool; `part_id` a part to edit (its vertex set is the
//!   base of add/subtract, and confirming updates it); `base` a previous draft of the same
//!   user to build on instead (several strokes before confirming); `params` the energy's
//!   weights ([`EnergyParams`]); `pixel_error` the cut's threshold (default 1 px);
//! * `mask`: the stroke mask, a PNG of the camera's size whose grey levels are labels:
//!   0 none, 1 foreground, 2 background, 3 heavy band, 4 lasso inside
//!   ([`meshwiki_engine::select::mask`]). The point tool needs no mask (the request may then
//!   be sent as plain JSON).
//!
//! The server renders colour, normal, depth and id buffers for that camera on the render pool
//! (the same admission, worker and memory limits as every render), cuts
//! ([`meshwiki_engine::select`]), back-projects the selected pixels to original vertex ids
//! (occluded surfaces are never selected), combines them with the base in `mode`, keeps the
//! result as a draft for 30 minutes and answers 201 with it: `id`, `vertex_count`, `center`
//! (a vertex of the selection near its centroid), `added` / `removed` against the base, the
//! selected pixels as a PNG data URL (`mask`, alpha 255 where selected) and timings.
//! Drafts belong to their user: anyone else gets 404, so concurrent selections never mix.
//!
//! `GET /api/v1/selections/{draft}` (its JSON), `.../mask` (PNG), `.../vertices`
//! (serialised RoaringBitmap), `DELETE` (discard), `POST .../confirm` (`{"kind"}` optional):
//! creates a part (201) or updates the edited part (200; 409 when the part changed since the
//! draft was made). The part gets its best view and thumbnail from the render service.
//! `GET /api/v1/parts/{id}/revisions` lists a part's history, `.../revisions/{n}/vertices`
//! its vertex set at revision `n`.
//!
//! Bad input is a 4xx with a message: a mask that is not a PNG (415) or not a label image,
//! of the wrong size, empty strokes, a heavy lasso that encloses nothing, a camera that sees
//! nothing or is invalid (400), a model still building (409), viewers (403).

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use actix_multipart::Multipart;
use actix_web::http::header;
use actix_web::{HttpRequest, HttpResponse, web};
use futures_util::StreamExt;
use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::Culling;
use meshwiki_engine::render::{Cut, Outputs, RenderOptions};
use meshwiki_engine::select::mask::{self, MaskError, StrokeMask};
use meshwiki_engine::select::modes::{self, Mode, VertexSet};
use meshwiki_engine::select::{
    BackProjectOptions, Buffers, EnergyParams, SelectError, Tool, back_project, point,
    select_pixels,
};
use roaring::RoaringBitmap;
use serde::{Deserialize, Serialize};
use serde_json::json;

use super::auth::Auth;
use super::events::{Event, EventKind};
use super::{ApiError, AppState};
use crate::render::RenderServiceError;
use crate::store::models::{self, ModelStatus};
use crate::store::part_revisions::{self, SelectionWrite};
use crate::store::parts::{self, PartKind};
use crate::store::users::Role;

/// How long a draft is kept.
pub const DRAFT_TTL: Duration = Duration::from_secs(30 * 60);
/// Drafts kept per user (the oldest goes first).
const DRAFTS_PER_USER: usize = 64;
/// Drafts kept in all.
const DRAFTS_TOTAL: usize = 2048;
/// Bytes of vertex sets and masks kept in all.
const DRAFT_BYTES: usize = 512 << 20;
/// Largest stroke mask upload.
const MAX_MASK_BYTES: usize = 32 << 20;
/// Largest `request` field.
const MAX_REQUEST_BYTES: usize = 64 << 10;
/// Per-pixel bytes of the selection's own work (mask, seeds, graph), for admission.
const SELECT_BYTES_PER_PIXEL: u64 = 128;
/// Bytes reserved for back-projection (decoded leaves, hits).
const BACKPROJECT_BYTES: u64 = 64 << 20;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/models/{id}/selections").route(web::post().to(create)))
        .service(
            super::resource("/api/v1/selections/{draft}")
                .route(web::get().to(get))
                .route(web::delete().to(discard)),
        )
        .service(super::resource("/api/v1/selections/{draft}/mask").route(web::get().to(mask_png)))
        .service(
            super::resource("/api/v1/selections/{draft}/vertices").route(web::get().to(vertices)),
        )
        .service(
            super::resource("/api/v1/selections/{draft}/confirm").route(web::post().to(confirm)),
        )
        .service(super::resource("/api/v1/parts/{id}/revisions").route(web::get().to(revisions)))
        .service(
            super::resource("/api/v1/parts/{id}/revisions/{number}/vertices")
                .route(web::get().to(revision_vertices)),
        );
}

// ---- request --------------------------------------------------------------------------------

/// The tools of the API: the engine's three plus a single click.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ToolName {
    /// Polygon.
    Lasso,
    /// Foreground and background strokes.
    Markup,
    /// One thick stroke along the boundary.
    HeavyLasso,
    /// A click: a point part.
    Point,
}

impl ToolName {
    fn engine(self) -> Option<Tool> {
        match self {
            ToolName::Lasso => Some(Tool::Lasso),
            ToolName::Markup => Some(Tool::Markup),
            ToolName::HeavyLasso => Some(Tool::HeavyLasso),
            ToolName::Point => None,
        }
    }

    fn as_str(self) -> &'static str {
        match self {
            ToolName::Point => "point",
            t => t.engine().map_or("point", Tool::as_str),
        }
    }
}

/// The view the strokes were drawn on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewCamera {
    /// Eye.
    pub eye: [f32; 3],
    /// Point looked at.
    pub target: [f32; 3],
    /// Up vector.
    pub up: [f32; 3],
    /// Vertical field of view, degrees.
    pub fovy: f32,
    /// Viewport width in pixels.
    pub width: u32,
    /// Viewport height in pixels.
    pub height: u32,
}

impl ViewCamera {
    fn engine(&self) -> Camera {
        Camera {
            eye: Vec3::from(self.eye),
            target: Vec3::from(self.target),
            up: Vec3::from(self.up),
            fovy_deg: self.fovy,
            width: self.width,
            height: self.height,
        }
    }
}

/// The `request` field.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SelectionRequest {
    /// Tool.
    pub tool: ToolName,
    /// How the result combines with the base.
    #[serde(default)]
    pub mode: Mode,
    /// The view.
    pub camera: ViewCamera,
    /// Point tool: the clicked pixel.
    #[serde(default)]
    pub point: Option<[f32; 2]>,
    /// A part to edit.
    #[serde(default)]
    pub part_id: Option<i64>,
    /// A previous draft to build on.
    #[serde(default)]
    pub base: Option<String>,
    /// Energy weights.
    #[serde(default)]
    pub params: Option<EnergyParams>,
    /// Pixel error of the rendered cut.
    #[serde(default)]
    pub pixel_error: Option<f32>,
}

fn mask_error(e: MaskError) -> ApiError {
    match e {
        MaskError::NotPng => ApiError::UnsupportedMediaType(
            "the stroke mask must be a PNG image (8-bit greyscale, labels 0-4)".into(),
        ),
        other => ApiError::bad(other.to_string()),
    }
}

fn select_error(e: SelectError) -> ApiError {
    if e.is_input_error() {
        ApiError::bad(e.to_string())
    } else {
        ApiError::internal(e)
    }
}

/// Reads the body: a multipart form (`request` + `mask`) or, for the point tool, JSON.
async fn read_body(
    req: &HttpRequest,
    payload: web::Payload,
) -> Result<(SelectionRequest, Option<Vec<u8>>), ApiError> {
    let ct = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    let parse = |bytes: &[u8]| -> Result<SelectionRequest, ApiError> {
        serde_json::from_slice(bytes)
            .map_err(|e| ApiError::bad(format!("invalid selection request: {e}")))
    };
    if ct.starts_with("application/json") {
        let mut body = Vec::new();
        let mut payload = payload;
        while let Some(chunk) = payload.next().await {
            let chunk = chunk.map_err(|e| ApiError::bad(format!("cannot read the body: {e}")))?;
            body.extend_from_slice(&chunk);
            if body.len() > MAX_REQUEST_BYTES {
                return Err(ApiError::PayloadTooLarge(format!(
                    "a selection request is at most {MAX_REQUEST_BYTES} bytes"
                )));
            }
        }
        return Ok((parse(&body)?, None));
    }
    if !ct.starts_with("multipart/form-data") {
        return Err(ApiError::UnsupportedMediaType(
            "send the selection as multipart/form-data with a `request` (JSON) and a `mask` \
             (PNG) field, or a point selection as application/json"
                .into(),
        ));
    }
    let mut form = Multipart::new(req.headers(), payload);
    let (mut request, mut mask): (Option<SelectionRequest>, Option<Vec<u8>>) = (None, None);
    while let Some(field) = form.next().await {
        let mut field = field.map_err(|e| ApiError::bad(format!("invalid multipart body: {e}")))?;
        let name = field.name().unwrap_or("").to_string();
        let (limit, seen) = match name.as_str() {
            "request" => (MAX_REQUEST_BYTES, request.is_some()),
            "mask" => (MAX_MASK_BYTES, mask.is_some()),
            other => {
                return Err(ApiError::bad(format!(
                    "unknown form field {other:?} (expected request and mask)"
                )));
            }
        };
        if seen {
            return Err(ApiError::bad(format!(
                "the form has more than one {name} field"
            )));
        }
        if name == "mask"
            && let Some(m) = field.content_type()
            && m.essence_str() != "image/png"
            && m.essence_str() != "application/octet-stream"
        {
            return Err(ApiError::UnsupportedMediaType(format!(
                "the stroke mask must be image/png, not {}",
                m.essence_str()
            )));
        }
        let mut bytes = Vec::new();
        while let Some(chunk) = field.next().await {
            let chunk = chunk.map_err(|e| ApiError::bad(format!("invalid multipart body: {e}")))?;
            bytes.extend_from_slice(&chunk);
            if bytes.len() > limit {
                return Err(ApiError::PayloadTooLarge(format!(
                    "the {name} field is larger than {limit} bytes"
                )));
            }
        }
        if name == "request" {
            request = Some(parse(&bytes)?);
        } else {
            mask = Some(bytes);
        }
    }
    let request = request.ok_or_else(|| ApiError::bad("the form has no `request` field"))?;
    Ok((request, mask))
}

/// The LOD file of a ready model: 404 unknown, 409 not ready.
async fn ready_lod(state: &AppState, model_id: i64) -> Result<PathBuf, ApiError> {
    let model = models::get(&state.db, model_id).await?;
    match model.status {
        ModelStatus::Ready => {}
        ModelStatus::Pending | ModelStatus::Building => {
            return Err(ApiError::Conflict(format!(
                "model {model_id} is {}: regions can be selected once its status is ready",
                model.status.as_str()
            )));
        }
        ModelStatus::Failed => {
            return Err(ApiError::Conflict(format!(
                "model {model_id} cannot be selected on: its build failed"
            )));
        }
    }
    let rel = model
        .lod_path
        .as_deref()
        .filter(|p| {
            let p = Path::new(p);
            p.components().count() >= 2 && p.components().all(|c| matches!(c, Component::Normal(_)))
        })
        .ok_or_else(|| ApiError::Conflict(format!("model {model_id} has no LOD file")))?;
    Ok(state.settings.data_dir.join(rel))
}

// ---- drafts ---------------------------------------------------------------------------------

/// A draft selection, kept until confirmed, discarded or expired.
#[derive(Debug)]
pub struct Draft {
    id: String,
    user_id: i64,
    model_id: i64,
    tool: ToolName,
    mode: Mode,
    kind: PartKind,
    part_id: Option<i64>,
    /// `updated_at` of the edited part when the draft was made.
    part_updated_at: Option<String>,
    set: VertexSet,
    camera: ViewCamera,
    mask_png: Vec<u8>,
    info: serde_json::Value,
    created: Instant,
}

impl Draft {
    fn bytes(&self) -> usize {
        self.set.vertices.serialized_size() + self.mask_png.len() + 1024
    }

    fn center(&self) -> Option<[f64; 3]> {
        self.set.anchor.map(|a| a.map(f64::from))
    }

    fn json(&self, with_mask: bool) -> serde_json::Value {
        let mut v = self.info.clone();
        v["vertex_count"] = json!(self.set.vertices.len());
        v["center"] = json!(self.center());
        if with_mask {
            v["mask"] = json!(format!("data:image/png;base64,{}", base64(&self.mask_png)));
        }
        v
    }
}

/// The drafts of every user (in memory; a restart drops them).
#[derive(Debug, Clone, Default)]
pub struct Drafts {
    inner: Arc<Mutex<HashMap<String, Arc<Draft>>>>,
}

impl Drafts {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, Arc<Draft>>> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Keeps `draft`, dropping expired drafts and the oldest beyond the limits.
    fn insert(&self, draft: Draft) -> Arc<Draft> {
        let draft = Arc::new(draft);
        let mut map = self.lock();
        map.retain(|_, d| d.created.elapsed() < DRAFT_TTL);
        let mut mine: Vec<(Instant, String)> = map
            .values()
            .filter(|d| d.user_id == draft.user_id)
            .map(|d| (d.created, d.id.clone()))
            .collect();
        mine.sort();
        while mine.len() >= DRAFTS_PER_USER {
            let (_, id) = mine.remove(0);
            map.remove(&id);
        }
        let mut bytes: usize = map.values().map(|d| d.bytes()).sum::<usize>() + draft.bytes();
        while !map.is_empty() && (map.len() >= DRAFTS_TOTAL || bytes > DRAFT_BYTES) {
            let Some(oldest) = map.values().min_by_key(|d| d.created).map(|d| d.id.clone()) else {
                break;
            };
            if let Some(d) = map.remove(&oldest) {
                bytes -= d.bytes();
            }
        }
        map.insert(draft.id.clone(), draft.clone());
        draft
    }

    /// The live draft `id` of `user_id` (404 otherwise: other users' drafts do not exist for
    /// them).
    fn get(&self, id: &str, user_id: i64) -> Result<Arc<Draft>, ApiError> {
        let map = self.lock();
        map.get(id)
            .filter(|d| d.user_id == user_id && d.created.elapsed() < DRAFT_TTL)
            .cloned()
            .ok_or_else(|| ApiError::NotFound(format!("no selection draft {id}")))
    }

    fn remove(&self, id: &str) {
        self.lock().remove(id);
    }
}

/// Standard base64 with padding (for the mask's data URL).
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (c.get(1).copied().unwrap_or(0) as u32) << 8
            | c.get(2).copied().unwrap_or(0) as u32;
        out.push(A[(n >> 18) as usize & 63] as char);
        out.push(A[(n >> 12) as usize & 63] as char);
        out.push(if c.len() > 1 {
            A[(n >> 6) as usize & 63] as char
        } else {
            '='
        });
        out.push(if c.len() > 2 {
            A[n as usize & 63] as char
        } else {
            '='
        });
    }
    out
}

// ---- the work on the render pool ------------------------------------------------------------

/// What the render thread returns.
struct Outcome {
    bp: meshwiki_engine::select::BackProjection,
    /// Point tool: the picked point.
    picked: Option<point::PickedPoint>,
    selected_pixels: usize,
    mask_png: Vec<u8>,
    cut: Option<meshwiki_engine::select::cut::CutStats>,
    render_ms: f64,
    cut_ms: f64,
}

enum WorkError {
    Render(RenderServiceError),
    Select(SelectError),
}

impl From<WorkError> for ApiError {
    fn from(e: WorkError) -> ApiError {
        match e {
            WorkError::Render(e) => e.into(),
            WorkError::Select(e) => select_error(e),
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn work(
    renderer: &meshwiki_engine::render::Renderer,
    model: &meshwiki_engine::render::Model,
    camera: &Camera,
    tool: ToolName,
    stroke: Option<&StrokeMask>,
    click: Option<[f32; 2]>,
    params: &EnergyParams,
    pixel_error: f32,
    base: Option<&RoaringBitmap>,
) -> Result<Outcome, WorkError> {
    let options = RenderOptions {
        cut: Cut::View {
            pixel_error,
            culling: Culling::ALL,
        },
        outputs: Outputs::ALL,
        ..RenderOptions::default()
    };
    let frame = renderer
        .render(model, camera, &options, &[])
        .map_err(|e| WorkError::Render(e.into()))?;
    let render_ms = frame.stats.total_ms;
    let buffers = Buffers::from_frame(&frame).map_err(WorkError::Select)?;
    if buffers.covered_count() == 0 {
        return Err(WorkError::Select(SelectError::NothingVisible));
    }
    let t = Instant::now();
    let (w, h) = (camera.width, camera.height);
    if let Some([x, y]) = click {
        let picked = point::pick(model.lod(), camera, &buffers, x, y).map_err(WorkError::Select)?;
        let mut selected = vec![false; buffers.len()];
        selected[picked.y as usize * w as usize + picked.x as usize] = true;
        let mut bp = meshwiki_engine::select::BackProjection::default();
        bp.vertices.insert(picked.vertex);
        bp.sum = picked.position.map(f64::from);
        bp.anchor = Some(picked.position);
        bp.positions = vec![(picked.vertex, picked.position)];
        if base.is_some_and(|b| b.contains(picked.vertex)) {
            bp.count_in_base = 1;
            bp.sum_in_base = bp.sum;
        }
        return Ok(Outcome {
            bp,
            picked: Some(picked),
            selected_pixels: 1,
            mask_png: mask::selection_png(w, h, &selected),
            cut: None,
            render_ms,
            cut_ms: t.elapsed().as_secs_f64() * 1e3,
        });
    }
    let (Some(engine_tool), Some(stroke)) = (tool.engine(), stroke) else {
        return Err(WorkError::Select(SelectError::EmptyStrokes(
            "the request needs a stroke mask".into(),
        )));
    };
    let color_cue = model.lod().has_colors();
    let sel = select_pixels(engine_tool, stroke, &buffers, params, color_cue)
        .map_err(WorkError::Select)?;
    let cut_ms = t.elapsed().as_secs_f64() * 1e3;
    let bp = back_project(
        model.lod(),
        camera,
        &buffers,
        &sel.selected,
        base,
        &BackProjectOptions::default(),
    )
    .map_err(WorkError::Select)?;
    Ok(Outcome {
        mask_png: mask::selection_png(w, h, &sel.selected),
        selected_pixels: sel.count,
        cut: sel.cut,
        bp,
        picked: None,
        render_ms,
        cut_ms,
    })
}

// ---- handlers -------------------------------------------------------------------------------

async fn create(
    state: web::Data<AppState>,
    auth: Auth,
    model_id: web::Path<i64>,
    req: HttpRequest,
    payload: web::Payload,
) -> Result<HttpResponse, ApiError> {
    let started = Instant::now();
    auth.require(Role::Editor)?;
    let model_id = *model_id;
    let (request, mask_bytes) = read_body(&req, payload).await?;

    // The view.
    let camera = request.camera.engine();
    camera
        .validate()
        .map_err(|e| ApiError::bad(format!("invalid camera: {e}")))?;
    let rs = state.render.settings();
    let (w, h) = (camera.width, camera.height);
    if w.max(h) > rs.max_side || w as u64 * h as u64 > rs.max_pixels {
        return Err(ApiError::bad(format!(
            "a {w}x{h} view is too large: at most {} pixels a side and {} pixels",
            rs.max_side, rs.max_pixels
        )));
    }
    let params = request.params.unwrap_or_default();
    params.validate().map_err(select_error)?;
    let pixel_error = request.pixel_error.unwrap_or(1.0);
    if !(pixel_error.is_finite() && (0.0..=64.0).contains(&pixel_error)) {
        return Err(ApiError::bad("pixel_error must be within [0, 64]"));
    }

    // The strokes.
    let (stroke, click) = match request.tool {
        ToolName::Point => {
            let p = request
                .point
                .ok_or_else(|| ApiError::bad("the point tool needs `point`: [x, y] in pixels"))?;
            if request.mode != Mode::Replace {
                return Err(ApiError::bad("the point tool only replaces (mode replace)"));
            }
            (None, Some(p))
        }
        _ => {
            if request.point.is_some() {
                return Err(ApiError::bad("`point` belongs to the point tool only"));
            }
            let bytes = mask_bytes.ok_or_else(|| {
                ApiError::bad("the request needs a `mask` field: the stroke mask PNG")
            })?;
            let m = StrokeMask::decode_png(&bytes).map_err(mask_error)?;
            if (m.width, m.height) != (w, h) {
                return Err(ApiError::bad(format!(
                    "the stroke mask is {}x{} but the viewport is {w}x{h}",
                    m.width, m.height
                )));
            }
            (Some(m), None)
        }
    };
    let path = ready_lod(&state, model_id).await?;

    // The base: a part being edited, or a previous draft.
    let mut part_updated_at = None;
    let base: Option<VertexSet> = match (request.part_id, request.base.as_deref()) {
        (Some(_), Some(_)) => {
            return Err(ApiError::bad("give `part_id` or `base`, not both"));
        }
        (Some(pid), None) => {
            let part = parts::get(&state.db, pid).await?;
            if part.model_id != model_id {
                return Err(ApiError::bad(format!(
                    "part {pid} is not on model {model_id}"
                )));
            }
            let blob = parts::vertex_set_raw(&state.db, pid).await?;
            let set = crate::render::views::vertex_set(blob.as_deref())
                .map_err(|e| ApiError::internal(format!("part {pid}: {e}")))?;
            part_updated_at = Some(part.updated_at.clone());
            let n = set.len() as f64;
            Some(VertexSet {
                sum: part.center.map(|c| c * n),
                anchor: Some(part.center.map(|c| c as f32)),
                vertices: set,
            })
        }
        (None, Some(id)) => {
            let d = state.selections.get(id, auth.id())?;
            if d.model_id != model_id {
                return Err(ApiError::bad(format!(
                    "draft {id} is on model {}, not {model_id}",
                    d.model_id
                )));
            }
            part_updated_at = d.part_updated_at.clone();
            Some(d.set.clone())
        }
        (None, None) => None,
    };
    let base_part = request.part_id.or_else(|| {
        request
            .base
            .as_deref()
            .and_then(|id| state.selections.get(id, auth.id()).ok())
            .and_then(|d| d.part_id)
    });
    if request.mode == Mode::Subtract && base.as_ref().is_none_or(|b| b.vertices.is_empty()) {
        return Err(ApiError::bad(
            "subtract needs something to subtract from: a `part_id` or a `base` draft",
        ));
    }

    // Render, cut and back-project on the render pool.
    let service = state.render.clone();
    service.renderer()?;
    let model = service.model(model_id, path).await?;
    let base_bytes = base
        .as_ref()
        .map_or(0, |b| b.vertices.serialized_size() as u64);
    let bytes = Outputs::ALL.frame_bytes(w, h)
        + SELECT_BYTES_PER_PIXEL * w as u64 * h as u64
        + BACKPROJECT_BYTES
        + base_bytes;
    let ticket = service.admit(bytes).await?;
    let base_set = base.as_ref().map(|b| b.vertices.clone());
    let tool = request.tool;
    let (outcome, _hold) = service
        .run(ticket, move |r| {
            work(
                r,
                &model,
                &camera,
                tool,
                stroke.as_ref(),
                click,
                &params,
                pixel_error,
                base_set.as_ref(),
            )
        })
        .await?;
    let outcome = outcome?;

    // Combine with the base.
    let empty = VertexSet::default();
    let base_ref = base.as_ref().unwrap_or(&empty);
    let mode = if base.is_some() {
        request.mode
    } else {
        Mode::Replace
    };
    let set = modes::combine(base_ref, &outcome.bp, mode);
    let added = set.vertices.difference_len(&base_ref.vertices);
    let removed = base_ref.vertices.difference_len(&set.vertices);
    let kind = if request.tool == ToolName::Point {
        PartKind::Point
    } else {
        PartKind::Region
    };
    let id = crate::random_hex(16);
    let total_ms = started.elapsed().as_secs_f64() * 1e3;
    let expires = time::OffsetDateTime::now_utc() + DRAFT_TTL;
    let info = json!({
        "id": id,
        "model_id": model_id,
        "tool": request.tool,
        "mode": mode,
        "kind": kind,
        "part_id": base_part,
        "base": request.base,
        "camera": request.camera,
        "width": w,
        "height": h,
        "selected_pixels": outcome.selected_pixels,
        "selected_vertices": outcome.bp.vertices.len(),
        "added": added,
        "removed": removed,
        "point": outcome.picked,
        "graph": outcome.cut,
        "backprojection": {
            "drawn_patches": outcome.bp.drawn_nodes,
            "leaves": outcome.bp.leaves,
            "vertices_tested": outcome.bp.vertices_tested,
        },
        "timings_ms": {
            "render": outcome.render_ms,
            "cut": outcome.cut_ms,
            "backproject": outcome.bp.ms,
            "total": total_ms,
        },
        "expires_at": expires.format(&time::format_description::well_known::Rfc3339).ok(),
    });
    tracing::info!(
        model_id,
        tool = request.tool.as_str(),
        mode = mode.as_str(),
        vertices = set.vertices.len(),
        pixels = outcome.selected_pixels,
        ms = total_ms,
        "selection draft"
    );
    let draft = state.selections.insert(Draft {
        id,
        user_id: auth.id(),
        model_id,
        tool: request.tool,
        mode,
        kind,
        part_id: base_part,
        part_updated_at,
        set,
        camera: request.camera,
        mask_png: outcome.mask_png,
        info,
        created: Instant::now(),
    });
    Ok(HttpResponse::Created().json(draft.json(true)))
}

async fn get(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    let d = state.selections.get(&id, auth.id())?;
    Ok(HttpResponse::Ok().json(d.json(true)))
}

async fn discard(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    let d = state.selections.get(&id, auth.id())?;
    state.selections.remove(&d.id);
    Ok(HttpResponse::NoContent().finish())
}

async fn mask_png(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    let d = state.selections.get(&id, auth.id())?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "image/png"))
        .body(d.mask_png.clone()))
}

async fn vertices(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    let d = state.selections.get(&id, auth.id())?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "application/octet-stream"))
        .body(part_revisions::serialize(&d.set.vertices)))
}

/// Body of `POST /api/v1/selections/{draft}/confirm`.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfirmRequest {
    /// Kind of the part (default: point for the point tool, else region).
    #[serde(default)]
    pub kind: Option<PartKind>,
}

async fn confirm(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
    body: web::Bytes,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let body: ConfirmRequest = if body.iter().all(|b| b.is_ascii_whitespace()) {
        ConfirmRequest::default()
    } else {
        serde_json::from_slice(&body)
            .map_err(|e| ApiError::bad(format!("invalid confirmation: {e}")))?
    };
    let d = state.selections.get(&id, auth.id())?;
    let kind = body.kind.unwrap_or(d.kind);
    let center = d
        .center()
        .or_else(|| d.set.centroid())
        .ok_or_else(|| ApiError::bad("the selection is empty: nothing to confirm"))?;
    let write = SelectionWrite {
        kind,
        center,
        set: &d.set.vertices,
        tool: d.tool.as_str(),
        action: match d.part_id {
            None => "create",
            Some(_) => d.mode.as_str(),
        },
        view: Some(json!(d.camera)),
    };
    let limit = state.settings.limits.part_vertices;
    let (part, status) = match d.part_id {
        None => (
            part_revisions::create_part(&state.db, d.model_id, &write, auth.id(), limit).await?,
            actix_web::http::StatusCode::CREATED,
        ),
        Some(pid) => {
            let expected = d.part_updated_at.as_deref().unwrap_or("");
            (
                part_revisions::update_part(&state.db, pid, &write, expected, auth.id(), limit)
                    .await?,
                actix_web::http::StatusCode::OK,
            )
        }
    };
    state.selections.remove(&d.id);
    let kind = if status == actix_web::http::StatusCode::CREATED {
        EventKind::PartCreated
    } else {
        EventKind::PartUpdated
    };
    state
        .events
        .publish(Event::part(kind, part.model_id, part.id));
    tracing::info!(part = part.id, draft = %d.id, vertices = part.vertex_count, "selection confirmed");
    Ok(HttpResponse::build(status).json(part))
}

async fn revisions(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    let list = part_revisions::list(&state.db, *id).await?;
    if list.is_empty() {
        // A part made before revisions were kept has none; an unknown part is 404.
        parts::get(&state.db, *id).await?;
    }
    Ok(HttpResponse::Ok().json(list))
}

async fn revision_vertices(
    state: web::Data<AppState>,
    _auth: Auth,
    path: web::Path<(i64, i64)>,
) -> Result<HttpResponse, ApiError> {
    let (id, number) = *path;
    let bytes = part_revisions::vertices(&state.db, id, number).await?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "application/octet-stream"))
        .body(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc_4648() {
        assert_eq!(base64(b""), "");
        assert_eq!(base64(b"f"), "Zg==");
        assert_eq!(base64(b"fo"), "Zm8=");
        assert_eq!(base64(b"foo"), "Zm9v");
        assert_eq!(base64(b"foobar"), "Zm9vYmFy");
    }
}
