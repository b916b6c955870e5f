//! Region selection (system paper §4): draft selections and their confirmation into parts.
//!
//! A draft is made on one view: the request names the tool, the camera, the base it builds
//! on (a part, or a previous draft of the same user) and how it combines (replace, add,
//! subtract); the engine renders the view's buffers, cuts and back-projects
//! ([`select_on_view`]); the result is kept for [`DRAFT_TTL`] as the user's draft. Drafts
//! belong to their user: anyone else gets "not found", so concurrent selections never mix.
//! Confirming a draft writes a part through [`super::parts`] — a revision with the tool and
//! the view it was made from.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::render::Outputs;
use meshwiki_engine::segment::SegmentFile;
use meshwiki_engine::select::graph_cut::CutStats;
use meshwiki_engine::select::mask::{MaskError, StrokeMask};
use meshwiki_engine::select::modes::{self, Mode, VertexSet};
use meshwiki_engine::select::point::PickedPoint;
use meshwiki_engine::select::{
    EnergyParams, Input, SelectError, Tool, ViewSelectError, select_on_view,
};
use roaring::RoaringBitmap;
use serde::{Deserialize, Serialize};
use serde_json::json;
use utoipa::ToSchema;

use super::models::Purpose;
use super::{App, AppError};
use crate::store::parts::{self, Action, Part, PartKind, PartState, Provenance};

/// How long a draft is kept.
pub const DRAFT_TTL: Duration = Duration::from_secs(30 * 60);
/// Drafts kept per user (the oldest goes first).
const DRAFTS_PER_USER: usize = 64;
/// Drafts kept in all.
const DRAFTS_TOTAL: usize = 2048;
/// Bytes of vertex sets and masks kept in all.
const DRAFT_BYTES: usize = 512 << 20;
/// Largest stroke mask upload.
pub const MAX_MASK_BYTES: usize = 32 << 20;
/// Largest `request` field.
pub const MAX_REQUEST_BYTES: usize = 64 << 10;
/// Per-pixel bytes of the selection's own work (mask, seeds, graph), for admission.
const SELECT_BYTES_PER_PIXEL: u64 = 128;
/// Bytes reserved for back-projection (decoded leaves, hits).
const BACKPROJECT_BYTES: u64 = 64 << 20;

// ---- request --------------------------------------------------------------------------------

/// The tools of the API: the engine's three plus a single click.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
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
    /// A click: the whole surface segment under it at a scale (suggested regions).
    Segment,
}

impl ToolName {
    fn engine(self) -> Option<Tool> {
        match self {
            ToolName::Lasso => Some(Tool::Lasso),
            ToolName::Markup => Some(Tool::Markup),
            ToolName::HeavyLasso => Some(Tool::HeavyLasso),
            ToolName::Point | ToolName::Segment => None,
        }
    }

    /// Name as in the API.
    pub fn as_str(self) -> &'static str {
        match self {
            ToolName::Point => "point",
            ToolName::Segment => "segment",
            t => t.engine().map_or("point", Tool::as_str),
        }
    }
}

/// The view the strokes were drawn on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ViewCamera {
    /// Eye position.
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
    /// The view of an engine camera.
    pub fn of(c: &Camera) -> ViewCamera {
        ViewCamera {
            eye: c.eye.to_array(),
            target: c.target.to_array(),
            up: c.up.to_array(),
            fovy: c.fovy_deg,
            width: c.width,
            height: c.height,
        }
    }

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

/// A selection request: the `request` field of the multipart form (or the whole JSON body
/// of a point selection).
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SelectionRequest {
    /// Tool (`point` and `segment` need `point` and no mask; the others need the stroke
    /// mask).
    pub tool: ToolName,
    /// How the result combines with the base (default `replace`; the point tool only
    /// replaces; `subtract` needs a non-empty base).
    #[serde(default)]
    pub mode: Mode,
    /// The view the strokes were drawn on (or the click made on).
    pub camera: ViewCamera,
    /// Point and segment tools: the clicked pixel `[x, y]`.
    #[serde(default)]
    pub point: Option<[f32; 2]>,
    /// Segment tool: the scale of the model's surface segments (0: finest; default: the
    /// suggested scale of `GET /api/v1/models/{id}/segments`).
    #[serde(default)]
    pub scale: Option<u32>,
    /// A part of this model to edit: its vertex set is the base of add/subtract, and
    /// confirming updates it (not with `base`).
    #[serde(default)]
    pub part_id: Option<i64>,
    /// A previous draft of the same user on this model to build on instead (several strokes
    /// before confirming; not with `part_id`).
    #[serde(default)]
    pub base: Option<String>,
    /// The energy's weights (default: the engine's).
    #[serde(default)]
    pub params: Option<EnergyParams>,
    /// Pixel error of the rendered cut, 0-64 (default 1).
    #[serde(default)]
    pub pixel_error: Option<f32>,
}

fn mask_error(e: MaskError) -> AppError {
    match e {
        MaskError::NotPng => AppError::UnsupportedMedia(
            "the stroke mask must be a PNG image (8-bit greyscale, labels 0-4)".into(),
        ),
        other => AppError::Invalid(other.to_string()),
    }
}

fn select_error(e: SelectError) -> AppError {
    if e.is_input_error() {
        AppError::Invalid(e.to_string())
    } else {
        AppError::internal(e)
    }
}

fn view_error(e: ViewSelectError) -> AppError {
    match e {
        ViewSelectError::Render(e) => AppError::Render(e.into()),
        ViewSelectError::Select(e) => select_error(e),
    }
}

/// 409: a segment request on a model built before surface segments.
fn no_segments(model_id: i64) -> AppError {
    AppError::Conflict(format!(
        "model {model_id} has no surface segments (it was built before them): rebuild it"
    ))
}

/// The scale asked for (default: the suggested one), checked against the model's.
fn checked_scale(
    segments: &SegmentFile,
    model_id: i64,
    scale: Option<u32>,
) -> Result<usize, AppError> {
    let scale = scale.map_or(segments.suggested_scale(), |s| s as usize);
    if scale >= segments.scales() {
        return Err(AppError::invalid(format!(
            "scale {scale} does not exist: model {model_id}'s segments have scales 0 to {}",
            segments.scales() - 1
        )));
    }
    Ok(scale)
}

// ---- surface segments -----------------------------------------------------------------------

/// A segment: its scale and its number there.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
pub struct SegmentRef {
    /// Scale (0: finest).
    pub scale: u32,
    /// Number of the segment at that scale.
    pub id: u32,
}

/// One scale of a model's surface segments.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct SegmentScale {
    /// Scale (0: finest).
    pub scale: u32,
    /// Segments at this scale.
    pub segments: u32,
}

/// A model's surface segments (`GET /api/v1/models/{id}/segments`).
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct SegmentScales {
    /// Model.
    pub model_id: i64,
    /// Every scale, finest first (each coarser one has about half the segments).
    pub scales: Vec<SegmentScale>,
    /// The scale a viewer offers first: the finest with at most 48 segments.
    pub suggested_scale: u32,
}

/// A segment's vertices (`GET /api/v1/models/{id}/segments/{scale}/vertices`).
#[derive(Debug, Clone)]
pub struct SegmentMembers {
    /// The segment.
    pub segment: SegmentRef,
    /// Its original vertex ids.
    pub vertices: RoaringBitmap,
    /// Identifies the model's build (the segments change only with it).
    pub build: String,
}

// ---- drafts ---------------------------------------------------------------------------------

/// Back-projection statistics of a draft.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct BackprojectionStats {
    /// Patches drawn under the selected pixels.
    pub drawn_patches: usize,
    /// Leaves reached down the DAG.
    pub leaves: usize,
    /// Full-resolution vertices tested.
    pub vertices_tested: u64,
}

/// Timings of a draft, milliseconds.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct SelectionTimings {
    /// Rendering the view's buffers.
    pub render: f64,
    /// Selecting the pixels (the graph cut, or the click): `seeds`, `graph` and `maxflow`
    /// together.
    pub cut: f64,
    /// Of `cut`: placing the seeds from the strokes (the lasso's whole work).
    pub seeds: f64,
    /// Of `cut`: building the graph on the strokes' window (0 without a graph cut).
    pub graph: f64,
    /// Of `cut`: solving the maximum flow (0 without a graph cut).
    pub maxflow: f64,
    /// Back-projecting to original vertex ids.
    pub backproject: f64,
    /// The whole request.
    pub total: f64,
}

/// A draft selection as the API shows it: what `POST /api/v1/models/{id}/selections` made,
/// kept for 30 minutes for its user until confirmed or discarded.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct SelectionDraft {
    /// Id of the draft (random hex).
    pub id: String,
    /// Model.
    pub model_id: i64,
    /// Tool that made it.
    pub tool: ToolName,
    /// How it combined with its base (`replace` when it had none).
    pub mode: Mode,
    /// Kind of the part it makes (point for the point tool, else region).
    pub kind: PartKind,
    /// The part it edits (the request's `part_id`, or its base draft's): confirming updates
    /// it; `null`: confirming creates a part.
    pub part_id: Option<i64>,
    /// The previous draft it was built on.
    pub base: Option<String>,
    /// The view it was made on.
    pub camera: ViewCamera,
    /// Viewport width in pixels.
    pub width: u32,
    /// Viewport height in pixels.
    pub height: u32,
    /// Pixels selected on the view.
    pub selected_pixels: usize,
    /// Vertices the view selected (before combining with the base).
    pub selected_vertices: u64,
    /// Vertices in the draft that were not in the base.
    pub added: u64,
    /// Vertices of the base that are not in the draft.
    pub removed: u64,
    /// Point and segment tools: the picked point.
    pub point: Option<PickedPoint>,
    /// Segment tool: the segment selected.
    pub segment: Option<SegmentRef>,
    /// Stroke tools: the graph cut's statistics.
    pub graph: Option<CutStats>,
    /// Back-projection statistics.
    pub backprojection: BackprojectionStats,
    /// Timings.
    pub timings_ms: SelectionTimings,
    /// When the draft expires.
    #[schema(format = DateTime)]
    pub expires_at: Option<String>,
    /// Vertices in the draft.
    pub vertex_count: u64,
    /// A vertex of the selection near its centroid (model coordinates); `null` when empty.
    pub center: Option<[f64; 3]>,
    /// The selected pixels as a PNG data URL (alpha 255 where selected).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
}

/// A draft selection, kept until confirmed, discarded or expired.
#[derive(Debug)]
pub struct Draft {
    /// Id (random).
    pub id: String,
    /// Owner.
    pub user_id: i64,
    /// Model.
    pub model_id: i64,
    /// Tool.
    pub tool: ToolName,
    /// Mode it combined with its base.
    pub mode: Mode,
    /// Kind of the part it makes.
    pub kind: PartKind,
    /// Part it edits.
    pub part_id: Option<i64>,
    /// `updated_at` of the edited part when the draft was made.
    pub part_updated_at: Option<String>,
    /// The vertex set.
    pub set: VertexSet,
    /// The view.
    pub camera: ViewCamera,
    /// The selected pixels (PNG).
    pub mask_png: Vec<u8>,
    info: SelectionDraft,
    created: Instant,
}

impl Draft {
    fn bytes(&self) -> usize {
        self.set.vertices.serialized_size() + self.mask_png.len() + 1024
    }

    /// Its anchor on the surface.
    pub fn center(&self) -> Option<[f64; 3]> {
        self.set.anchor.map(|a| a.map(f64::from))
    }

    /// The draft as the API shows it (with the mask as a data URL).
    pub fn json(&self, with_mask: bool) -> SelectionDraft {
        SelectionDraft {
            vertex_count: self.set.vertices.len(),
            center: self.center(),
            mask: with_mask.then(|| format!("data:image/png;base64,{}", base64(&self.mask_png))),
            ..self.info.clone()
        }
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
    pub fn get(&self, id: &str, user_id: i64) -> Result<Arc<Draft>, AppError> {
        let map = self.lock();
        map.get(id)
            .filter(|d| d.user_id == user_id && d.created.elapsed() < DRAFT_TTL)
            .cloned()
            .ok_or_else(|| AppError::NotFound(format!("no selection draft {id}")))
    }

    /// Discards draft `id`.
    pub fn remove(&self, id: &str) {
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

/// Body of `POST /api/v1/selections/{draft}/confirm` (optional: an empty body confirms with
/// the defaults).
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ConfirmRequest {
    /// Kind of the part (default: point for the point tool, else region).
    #[serde(default)]
    pub kind: Option<PartKind>,
    /// Comment kept in the part's history.
    #[serde(default)]
    pub comment: Option<String>,
}

impl App {
    /// Makes a draft selection on model `model_id` for `user_id` (an editor): the view is
    /// checked against the render limits, the strokes (`mask_png`, a label PNG of the view's
    /// size) or the click against the tool, the base (a part or a previous draft) loaded; the
    /// buffers are rendered, cut and back-projected on the render pool
    /// ([`select_on_view`]), the result combined with the base in the request's mode.
    pub async fn select(
        &self,
        user_id: i64,
        model_id: i64,
        request: SelectionRequest,
        mask_bytes: Option<Vec<u8>>,
    ) -> Result<Arc<Draft>, AppError> {
        let started = Instant::now();

        // The view.
        let camera = request.camera.engine();
        camera
            .validate()
            .map_err(|e| AppError::invalid(format!("invalid camera: {e}")))?;
        let rs = self.render.settings();
        let (w, h) = (camera.width, camera.height);
        if w.max(h) > rs.max_side || w as u64 * h as u64 > rs.max_pixels {
            return Err(AppError::invalid(format!(
                "a {w}x{h} view is too large: at most {} pixels a side and {} pixels",
                rs.max_side, rs.max_pixels
            )));
        }
        let params = request.params.unwrap_or_default();
        params.validate().map_err(select_error)?;
        let pixel_error = request.pixel_error.unwrap_or(1.0);
        if !(pixel_error.is_finite() && (0.0..=64.0).contains(&pixel_error)) {
            return Err(AppError::invalid("pixel_error must be within [0, 64]"));
        }

        // The strokes.
        if request.scale.is_some() && request.tool != ToolName::Segment {
            return Err(AppError::invalid(
                "`scale` belongs to the segment tool only",
            ));
        }
        let (stroke, click) = match request.tool {
            ToolName::Point | ToolName::Segment => {
                let tool = request.tool.as_str();
                let p = request.point.ok_or_else(|| {
                    AppError::invalid(format!("the {tool} tool needs `point`: [x, y] in pixels"))
                })?;
                if request.tool == ToolName::Point && request.mode != Mode::Replace {
                    return Err(AppError::invalid(
                        "the point tool only replaces (mode replace)",
                    ));
                }
                if mask_bytes.is_some() {
                    return Err(AppError::invalid(format!(
                        "the {tool} tool takes a click, not a stroke mask"
                    )));
                }
                (None, Some(p))
            }
            _ => {
                if request.point.is_some() {
                    return Err(AppError::invalid(
                        "`point` belongs to the point and segment tools only",
                    ));
                }
                let bytes = mask_bytes.ok_or_else(|| {
                    AppError::invalid("the request needs a `mask` field: the stroke mask PNG")
                })?;
                let m = StrokeMask::decode_png(&bytes).map_err(mask_error)?;
                if (m.width, m.height) != (w, h) {
                    return Err(AppError::invalid(format!(
                        "the stroke mask is {}x{} but the viewport is {w}x{h}",
                        m.width, m.height
                    )));
                }
                (Some(m), None)
            }
        };
        let open = self
            .models
            .open(&self.db, model_id, Purpose::Select)
            .await?;
        let scale = match request.tool {
            ToolName::Segment => {
                let segments = open
                    .render
                    .segments()
                    .ok_or_else(|| no_segments(model_id))?;
                Some(checked_scale(segments, model_id, request.scale)?)
            }
            _ => None,
        };

        // The base: a part being edited, or a previous draft.
        let mut part_updated_at = None;
        let base: Option<VertexSet> = match (request.part_id, request.base.as_deref()) {
            (Some(_), Some(_)) => {
                return Err(AppError::invalid("give `part_id` or `base`, not both"));
            }
            (Some(pid), None) => {
                let part = parts::get(&self.db, pid).await?;
                if part.model_id != model_id {
                    return Err(AppError::invalid(format!(
                        "part {pid} is not on model {model_id}"
                    )));
                }
                let blob = parts::vertex_set_raw(&self.db, pid).await?;
                let set = parts::parse_vertex_set(blob.as_deref())
                    .map_err(|e| AppError::internal(format!("part {pid}: {e}")))?;
                part_updated_at = Some(part.updated_at.clone());
                let n = set.len() as f64;
                Some(VertexSet {
                    sum: part.center.map(|c| c * n),
                    anchor: Some(part.center.map(|c| c as f32)),
                    vertices: set,
                })
            }
            (None, Some(id)) => {
                let d = self.selections.get(id, user_id)?;
                if d.model_id != model_id {
                    return Err(AppError::invalid(format!(
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
                .and_then(|id| self.selections.get(id, user_id).ok())
                .and_then(|d| d.part_id)
        });
        if request.mode == Mode::Subtract && base.as_ref().is_none_or(|b| b.vertices.is_empty()) {
            return Err(AppError::invalid(
                "subtract needs something to subtract from: a `part_id` or a `base` draft",
            ));
        }

        // Render, cut and back-project on the render pool.
        let service = self.render.clone();
        service.renderer()?;
        let model = open.render.clone();
        let base_bytes = base
            .as_ref()
            .map_or(0, |b| b.vertices.serialized_size() as u64);
        let bytes = Outputs::ALL.frame_bytes(w, h)
            + SELECT_BYTES_PER_PIXEL * w as u64 * h as u64
            + BACKPROJECT_BYTES
            + base_bytes;
        let ticket = service.admit(bytes).await?;
        let base_set = base.as_ref().map(|b| b.vertices.clone());
        let tool = request.tool.engine();
        let (outcome, _hold) = service
            .run(ticket, move |r| {
                let input = match (click, scale, tool, stroke.as_ref()) {
                    (Some(point), Some(scale), _, _) => Input::Segment { point, scale },
                    (Some(p), None, _, _) => Input::Click(p),
                    (None, _, Some(tool), Some(mask)) => Input::Strokes {
                        tool,
                        mask,
                        params: &params,
                    },
                    _ => {
                        return Err(ViewSelectError::Select(SelectError::EmptyStrokes(
                            "the request needs a stroke mask".into(),
                        )));
                    }
                };
                select_on_view(r, &model, &camera, input, pixel_error, base_set.as_ref())
            })
            .await?;
        let outcome = outcome.map_err(view_error)?;

        // Combine with the base.
        let empty = VertexSet::default();
        let base_ref = base.as_ref().unwrap_or(&empty);
        let mode = if base.is_some() {
            request.mode
        } else {
            Mode::Replace
        };
        let set = modes::combine(base_ref, &outcome.backprojection, mode);
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
        let info = SelectionDraft {
            id: id.clone(),
            model_id,
            tool: request.tool,
            mode,
            kind,
            part_id: base_part,
            base: request.base.clone(),
            camera: request.camera,
            width: w,
            height: h,
            selected_pixels: outcome.selected_pixels,
            selected_vertices: outcome.backprojection.vertices.len(),
            added,
            removed,
            point: outcome.picked,
            segment: outcome.segment.map(|(scale, id)| SegmentRef {
                scale: scale as u32,
                id,
            }),
            graph: outcome.cut.clone(),
            backprojection: BackprojectionStats {
                drawn_patches: outcome.backprojection.drawn_nodes,
                leaves: outcome.backprojection.leaves,
                vertices_tested: outcome.backprojection.vertices_tested,
            },
            timings_ms: SelectionTimings {
                render: outcome.render_ms,
                cut: outcome.cut_ms,
                seeds: outcome.seeds_ms,
                graph: outcome.cut.as_ref().map_or(0.0, |c| c.build_ms),
                maxflow: outcome.cut.as_ref().map_or(0.0, |c| c.solve_ms),
                backproject: outcome.backprojection.ms,
                total: total_ms,
            },
            expires_at: expires
                .format(&time::format_description::well_known::Rfc3339)
                .ok(),
            vertex_count: set.vertices.len(),
            center: set.anchor.map(|a| a.map(f64::from)),
            mask: None,
        };
        tracing::info!(
            model_id,
            tool = request.tool.as_str(),
            mode = mode.as_str(),
            vertices = set.vertices.len(),
            pixels = outcome.selected_pixels,
            ms = total_ms,
            "selection draft"
        );
        Ok(self.selections.insert(Draft {
            id,
            user_id,
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
        }))
    }

    /// The surface segments of model `model_id`: its scales (409 when it has none).
    pub async fn segment_scales(&self, model_id: i64) -> Result<SegmentScales, AppError> {
        let open = self
            .models
            .open(&self.db, model_id, Purpose::Select)
            .await?;
        let segments = open
            .render
            .segments()
            .ok_or_else(|| no_segments(model_id))?;
        Ok(SegmentScales {
            model_id,
            scales: (0..segments.scales())
                .map(|s| SegmentScale {
                    scale: s as u32,
                    segments: segments.count(s),
                })
                .collect(),
            suggested_scale: segments.suggested_scale() as u32,
        })
    }

    /// The segment at `scale` of model `model_id` that holds original vertex `vertex`, with
    /// all its vertices (what the viewer previews under the cursor before a segment click);
    /// 404 when the vertex is in no segment.
    pub async fn segment_members(
        &self,
        model_id: i64,
        scale: u32,
        vertex: u32,
    ) -> Result<SegmentMembers, AppError> {
        let open = self
            .models
            .open(&self.db, model_id, Purpose::Select)
            .await?;
        let segments = open
            .render
            .segments()
            .ok_or_else(|| no_segments(model_id))?;
        let scale = checked_scale(segments, model_id, Some(scale))?;
        let id = segments.segment_of(vertex, scale).ok_or_else(|| {
            AppError::NotFound(format!(
                "vertex {vertex} of model {model_id} lies in no surface segment"
            ))
        })?;
        let build = open.etag.trim_matches('"').to_string();
        let open2 = open.clone();
        let vertices = tokio::task::spawn_blocking(move || {
            open2.render.segments().and_then(|s| s.members(scale, id))
        })
        .await
        .map_err(AppError::internal)?
        .ok_or_else(|| AppError::internal(format!("segment {id} at scale {scale} unreadable")))?;
        Ok(SegmentMembers {
            segment: SegmentRef {
                scale: scale as u32,
                id,
            },
            vertices,
            build,
        })
    }

    /// Confirms draft `draft_id` of `user_id`: creates a part (`true`) or updates the part it
    /// edits (`false`; [`AppError::Store`] conflict when that part changed since), as a
    /// revision with the tool and view, and announces it.
    pub async fn confirm_selection(
        &self,
        user_id: i64,
        draft_id: &str,
        confirm: &ConfirmRequest,
    ) -> Result<(Part, bool), AppError> {
        let d = self.selections.get(draft_id, user_id)?;
        let kind = confirm.kind.unwrap_or(d.kind);
        let center = d
            .center()
            .or_else(|| d.set.centroid())
            .ok_or_else(|| AppError::invalid("the selection is empty: nothing to confirm"))?;
        if kind == PartKind::Region && d.set.vertices.is_empty() {
            return Err(AppError::invalid(
                "the selection is empty: a region part needs at least one vertex",
            ));
        }
        let prov = Provenance {
            user_id,
            comment: confirm.comment.clone(),
            tool: Some(d.tool.as_str().to_string()),
            view: Some(json!(d.camera)),
        };
        let state = PartState {
            kind,
            center,
            vertices: d.set.vertices.clone(),
            camera: None,
            thumbnail_attachment_id: None,
        };
        let (part, created) = match d.part_id {
            None => (
                self.create_part_with(d.model_id, &state, &prov).await?,
                true,
            ),
            Some(pid) => {
                let action = match d.mode {
                    Mode::Replace => Action::Replace,
                    Mode::Add => Action::Add,
                    Mode::Subtract => Action::Subtract,
                };
                let expected = d.part_updated_at.as_deref().unwrap_or("");
                let part = self
                    .change_part(
                        pid,
                        action,
                        move |s| {
                            s.kind = state.kind;
                            s.center = state.center;
                            s.vertices = state.vertices;
                            Ok(())
                        },
                        Some(expected),
                        &prov,
                    )
                    .await?;
                (part, false)
            }
        };
        self.selections.remove(&d.id);
        tracing::info!(part = part.id, draft = %d.id, vertices = part.vertex_count, "selection confirmed");
        Ok((part, created))
    }
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
