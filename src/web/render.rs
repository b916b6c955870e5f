//! Server-side rendering of a model's hierarchy (issue 4; system paper §3.3, §2.2):
//!
//! * `GET /api/v1/models/{id}/render?...` — the image (PNG, JPEG or lossless WebP): parts
//!   tinted, the hovered part outlined, callouts drawn on request;
//! * `GET /api/v1/models/{id}/render/buffers?...` — normal, depth and id buffers (and colour
//!   on request) for tools, in the binary layout of [`BUFFERS_MAGIC`] below;
//! * `GET /api/v1/models/{id}/render/callouts?...` — the callout layout as JSON, for the
//!   browser to draw as HTML.
//!
//! Parameters (all optional): `eye`, `target`, `up` (`x,y,z`; without `eye` the model's
//! overview camera, without `target` the model's centre, `up` defaults to +Y), `fovy`
//! (degrees, 1–170, default 45), `w`, `h` (default 640×480, at most `MESHWIKI_RENDER_MAX_SIDE`
//! per side and `MESHWIKI_RENDER_MAX_PIXELS` in all), `parts` (part ids to tint, in order,
//! at most 64), `hover` (a part id to outline), `px` (pixel error of the cut, 0.25–64,
//! default 1); image only: `format` (`png`, `jpeg`, `webp`), `quality` (JPEG, 1–100),
//! `callouts` (`1` draws labels for `parts` and `hover`, or for every part of the model when
//! none is named); buffers only: `buffers` (a subset of `color,normal,depth,ids`, default
//! `normal,depth,ids`). Every value is checked (400 with a message); unknown model 404, model
//! not ready 409; renders go through the bounded pool (`crate::render`): a full queue gives
//! 503 with `Retry-After`, no GPU adapter gives 503. Anyone logged in may render.
//!
//! Buffers layout (little endian): bytes 0–3 the magic `MWRB`, 4–7 u32 version (1), 8–11 u32
//! `J`, the length of the JSON header that follows (UTF-8, padded with spaces to a multiple of
//! 4), then the arrays, each at the byte `offset` (from the start of the body) and of the
//! `bytes` its entry in the header's `buffers` list gives. All are row-major, top row first,
//! `width × height` elements of `components` values of `type`:
//! `color` u8×4 (RGBA), `normal` f32×3 (world-space unit normal, 0 on the background), `depth`
//! f32 (linear view depth, +inf on the background), `node` u32 (patch id), `vertex` u32
//! (original vertex id of the model: the corner of the drawn triangle nearest to the pixel
//! centre), `triangle` u32 (index in its patch), `highlight` u32 (bits 0–7: 1-based index of
//! the tinting part in `parts`, bit 8: hovered part, bit 31: covered); ids are `0xFFFFFFFF`
//! on the background.

use std::pin::Pin;
use std::task::{Context, Poll};

use actix_web::body::{BodySize, MessageBody};
use actix_web::http::header::{self, ContentEncoding};
use actix_web::{HttpResponse, web};
use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::Culling;
use meshwiki_engine::render::best_view::{BestViewOptions, framing_camera};
use meshwiki_engine::render::callouts::{self, CalloutPart, CalloutStyle, LayoutOptions};
use meshwiki_engine::render::encode::{self, ImageFormat};
use meshwiki_engine::render::highlight::TINTS;
use meshwiki_engine::render::{
    Cut, Frame, Highlight, Outputs, RenderModel, RenderOptions, RenderStats, Renderer,
};
use roaring::RoaringBitmap;
use serde::{Deserialize, Serialize};
use serde_json::json;
use utoipa::openapi::path::{Parameter, ParameterIn};
use utoipa::{IntoParams, ToSchema};

use super::auth::Reader;
use super::{ApiError, AppState};
use crate::app::models::Purpose;
use crate::app::selections::ViewCamera;
use crate::config::RenderSettings;
use crate::render::{MemoryHold, PoolError, RenderService, RenderServiceError};
use crate::store::{assignments, parts};

/// Magic of the buffers body.
pub const BUFFERS_MAGIC: &[u8; 4] = b"MWRB";
/// Version of the buffers body.
pub const BUFFERS_VERSION: u32 = 1;
/// Most parts named in `parts` (tinted) or labelled with callouts.
pub const MAX_PARTS: usize = 64;
/// Default image size.
const DEFAULT_SIZE: (u32, u32) = (640, 480);
/// Default vertical field of view.
const DEFAULT_FOVY: f32 = 45.0;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/models/{id}/render").route(web::get().to(image)))
        .service(
            super::resource("/api/v1/models/{id}/render/buffers").route(web::get().to(buffers)),
        )
        .service(
            super::resource("/api/v1/models/{id}/render/callouts")
                .route(web::get().to(callouts_json)),
        );
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(image, buffers, callouts_json))]
pub(super) struct Api;

impl From<RenderServiceError> for ApiError {
    fn from(e: RenderServiceError) -> ApiError {
        match e {
            RenderServiceError::Unavailable(_) => ApiError::Unavailable {
                message: e.to_string(),
                retry_after: None,
            },
            RenderServiceError::Pool(PoolError::Busy { retry_after, .. }) => {
                ApiError::Unavailable {
                    message: e.to_string(),
                    retry_after: Some(retry_after),
                }
            }
            RenderServiceError::OutOfMemory => ApiError::Unavailable {
                message: e.to_string(),
                retry_after: Some(5),
            },
            RenderServiceError::Pool(PoolError::TooLarge { .. })
            | RenderServiceError::Invalid(_) => ApiError::BadRequest(e.to_string()),
            RenderServiceError::Lod(_)
            | RenderServiceError::Failed(_)
            | RenderServiceError::Encode(_) => ApiError::internal(e),
        }
    }
}

/// Query parameters (strings, parsed by `Params::parse` for precise messages). In the
/// OpenAPI document each route lists the ones it takes ([`ImageQuery`], [`BuffersQuery`],
/// [`CalloutsQuery`]); the others answer 400 there.
#[derive(Debug, Default, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct RenderQuery {
    /// Camera position x,y,z (default: the model's overview camera).
    eye: Option<String>,
    /// Point looked at x,y,z (default: the model's centre; needs `eye`; not the eye itself).
    target: Option<String>,
    /// Up vector x,y,z, not zero (default: +Y, or +Z when looking along Y, with `eye`; the
    /// overview camera's up without).
    up: Option<String>,
    /// Vertical field of view in degrees, 1-170 (default 45).
    #[param(value_type = Option<f32>, minimum = 1, maximum = 170)]
    fovy: Option<String>,
    /// Image width, 1 to `MESHWIKI_RENDER_MAX_SIDE` (default 640); `w`×`h` at most
    /// `MESHWIKI_RENDER_MAX_PIXELS`.
    #[param(value_type = Option<u32>, minimum = 1)]
    w: Option<String>,
    /// Image height, 1 to `MESHWIKI_RENDER_MAX_SIDE` (default 480).
    #[param(value_type = Option<u32>, minimum = 1)]
    h: Option<String>,
    /// Comma-separated part ids of this model to tint, in order (at most 64).
    parts: Option<String>,
    /// A part id of this model to outline (the hovered part).
    #[param(value_type = Option<i64>, minimum = 1)]
    hover: Option<String>,
    /// Pixel error of the view-dependent cut, 0.25-64 (default 1).
    #[param(value_type = Option<f32>, minimum = 0.25, maximum = 64)]
    px: Option<String>,
    /// Image format: `png` (default), `jpeg` (or `jpg`) or `webp` (lossless).
    format: Option<String>,
    /// JPEG quality 1-100 (default 90).
    #[param(value_type = Option<u8>, minimum = 1, maximum = 100)]
    quality: Option<String>,
    /// `1` or `true`: draw labels (the first assigned content's title) with leader lines for
    /// the parts named in `parts`/`hover`, or for every part of the model when none is named;
    /// `0` or `false` (default): none.
    callouts: Option<String>,
    /// Comma-separated subset of `color`, `normal`, `depth`, `ids` (default
    /// `normal,depth,ids`).
    buffers: Option<String>,
}

/// The parameters of [`RenderQuery`] that `route` takes (the OpenAPI parameters of its
/// operation).
fn route_params(route: Route, provider: impl Fn() -> Option<ParameterIn>) -> Vec<Parameter> {
    RenderQuery::into_params(provider)
        .into_iter()
        .filter(|p| match p.name.as_str() {
            "format" | "quality" | "callouts" => route == Route::Image,
            "buffers" => route == Route::Buffers,
            _ => true,
        })
        .collect()
}

/// The query of `GET /api/v1/models/{id}/render` in the OpenAPI document: [`RenderQuery`]
/// without `buffers`.
pub struct ImageQuery;

impl IntoParams for ImageQuery {
    fn into_params(provider: impl Fn() -> Option<ParameterIn>) -> Vec<Parameter> {
        route_params(Route::Image, provider)
    }
}

/// The query of `GET /api/v1/models/{id}/render/buffers` in the OpenAPI document:
/// [`RenderQuery`] without `format`, `quality` and `callouts`.
pub struct BuffersQuery;

impl IntoParams for BuffersQuery {
    fn into_params(provider: impl Fn() -> Option<ParameterIn>) -> Vec<Parameter> {
        route_params(Route::Buffers, provider)
    }
}

/// The query of `GET /api/v1/models/{id}/render/callouts` in the OpenAPI document:
/// [`RenderQuery`] without `format`, `quality`, `callouts` and `buffers`.
pub struct CalloutsQuery;

impl IntoParams for CalloutsQuery {
    fn into_params(provider: impl Fn() -> Option<ParameterIn>) -> Vec<Parameter> {
        route_params(Route::Callouts, provider)
    }
}

/// Which route parses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Route {
    Image,
    Buffers,
    Callouts,
}

/// Checked parameters.
#[derive(Debug, Clone)]
struct Params {
    eye: Option<Vec3>,
    target: Option<Vec3>,
    up: Option<Vec3>,
    fovy: f32,
    width: u32,
    height: u32,
    parts: Vec<i64>,
    hover: Option<i64>,
    px: f32,
    format: ImageFormat,
    quality: u8,
    callouts: bool,
    outputs: Outputs,
}

fn given(v: &Option<String>) -> Option<&str> {
    v.as_deref().map(str::trim).filter(|s| !s.is_empty())
}

fn vec3(name: &str, v: &Option<String>) -> Result<Option<Vec3>, ApiError> {
    let Some(s) = given(v) else { return Ok(None) };
    let bad = || {
        ApiError::bad(format!(
            "{name} must be three finite numbers x,y,z, got {s:?}"
        ))
    };
    let nums: Vec<f32> = s
        .split(',')
        .map(|t| t.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    match nums[..] {
        [x, y, z] if x.is_finite() && y.is_finite() && z.is_finite() => {
            Ok(Some(Vec3::new(x, y, z)))
        }
        _ => Err(bad()),
    }
}

fn number<T: std::str::FromStr + PartialOrd + std::fmt::Display + Copy>(
    name: &str,
    v: &Option<String>,
    range: std::ops::RangeInclusive<T>,
    default: T,
) -> Result<T, ApiError> {
    let Some(s) = given(v) else {
        return Ok(default);
    };
    let bad = || {
        ApiError::bad(format!(
            "{name} must be a number from {} to {}, got {s:?}",
            range.start(),
            range.end()
        ))
    };
    let n: T = s.parse().map_err(|_| bad())?;
    // NaN fails `contains`.
    if range.contains(&n) {
        Ok(n)
    } else {
        Err(bad())
    }
}

fn part_id(name: &str, s: &str) -> Result<i64, ApiError> {
    s.trim()
        .parse::<i64>()
        .ok()
        .filter(|&id| id > 0)
        .ok_or_else(|| ApiError::bad(format!("{name} must list part ids, got {s:?}")))
}

/// A boolean query parameter. One rule for every boolean of the API: `1` or `true`, `0` or
/// `false` (as in JSON); anything else is a 400.
fn flag(name: &str, v: &Option<String>) -> Result<bool, ApiError> {
    match given(v) {
        None | Some("0" | "false") => Ok(false),
        Some("1" | "true") => Ok(true),
        Some(other) => Err(ApiError::bad(format!(
            "{name} must be 1, 0, true or false, got {other:?}"
        ))),
    }
}

impl Params {
    fn parse(q: &RenderQuery, route: Route, limits: &RenderSettings) -> Result<Params, ApiError> {
        let only = |name: &str, v: &Option<String>, on: Route, path: &str| {
            if v.is_some() && route != on {
                Err(ApiError::bad(format!(
                    "parameter {name} applies to {path} only"
                )))
            } else {
                Ok(())
            }
        };
        only("format", &q.format, Route::Image, "/render")?;
        only("quality", &q.quality, Route::Image, "/render")?;
        only("callouts", &q.callouts, Route::Image, "/render")?;
        only("buffers", &q.buffers, Route::Buffers, "/render/buffers")?;

        let eye = vec3("eye", &q.eye)?;
        let target = vec3("target", &q.target)?;
        let up = vec3("up", &q.up)?;
        if eye.is_none() && target.is_some() {
            return Err(ApiError::bad("target needs an eye"));
        }
        if let (Some(e), Some(t)) = (eye, target)
            && e.distance_squared(t) <= f32::MIN_POSITIVE
        {
            return Err(ApiError::bad("eye and target must differ"));
        }
        if up.is_some_and(|u| u.length_squared() <= f32::MIN_POSITIVE) {
            return Err(ApiError::bad("up must not be zero"));
        }
        let fovy = number("fovy", &q.fovy, 1.0f32..=170.0, DEFAULT_FOVY)?;
        let side = limits.max_side.clamp(16, Camera::MAX_SIDE);
        let width = number("w", &q.w, 1u32..=side, DEFAULT_SIZE.0.min(side))?;
        let height = number("h", &q.h, 1u32..=side, DEFAULT_SIZE.1.min(side))?;
        let pixels = width as u64 * height as u64;
        if pixels > limits.max_pixels {
            return Err(ApiError::bad(format!(
                "image of {width}x{height} = {pixels} pixels exceeds the limit of {} pixels",
                limits.max_pixels
            )));
        }
        let mut parts = Vec::new();
        if let Some(list) = given(&q.parts) {
            for s in list.split(',') {
                let id = part_id("parts", s)?;
                if !parts.contains(&id) {
                    parts.push(id);
                }
                if parts.len() > MAX_PARTS {
                    return Err(ApiError::bad(format!(
                        "at most {MAX_PARTS} parts per render"
                    )));
                }
            }
        }
        let hover = given(&q.hover).map(|s| part_id("hover", s)).transpose()?;
        let px = number("px", &q.px, 0.25f32..=64.0, 1.0)?;
        let format = match given(&q.format) {
            None => ImageFormat::Png,
            Some(f) => ImageFormat::parse(f).ok_or_else(|| {
                ApiError::bad(format!("format must be png, jpeg or webp, got {f:?}"))
            })?,
        };
        let quality = number("quality", &q.quality, 1u8..=100, 90)?;
        let callouts = flag("callouts", &q.callouts)?;
        let outputs = match route {
            Route::Image if callouts => Outputs::IMAGE_DEPTH,
            Route::Image => Outputs::IMAGE,
            Route::Callouts => Outputs {
                depth: true,
                ..Outputs::default()
            },
            Route::Buffers => {
                let mut o = Outputs::default();
                let list = given(&q.buffers).unwrap_or("normal,depth,ids");
                for b in list.split(',') {
                    match b.trim() {
                        "color" | "colour" => o.color = true,
                        "normal" => o.normal = true,
                        "depth" => o.depth = true,
                        "ids" => o.ids = true,
                        other => {
                            return Err(ApiError::bad(format!(
                                "buffers must list color, normal, depth or ids, got {other:?}"
                            )));
                        }
                    }
                }
                o
            }
        };
        Ok(Params {
            eye,
            target,
            up,
            fovy,
            width,
            height,
            parts,
            hover,
            px,
            format,
            quality,
            callouts,
            outputs,
        })
    }

    /// The camera on `model` (defaults as in the module documentation).
    fn camera(&self, model: &RenderModel) -> Result<Camera, ApiError> {
        let (w, h) = (self.width, self.height);
        let cam = match self.eye {
            None => {
                let overview = crate::jobs::thumbnail::camera(model.lod());
                let dir = (overview.eye - overview.target).normalize_or_zero();
                let opts = BestViewOptions {
                    fovy_deg: self.fovy,
                    margin: 1.05,
                    up: self.up.unwrap_or(overview.up),
                    ..BestViewOptions::default()
                };
                framing_camera(overview.target, dir, model.radius(), &opts, w, h)
            }
            Some(eye) => {
                let target = self.target.unwrap_or_else(|| model.center());
                let dir = (target - eye).normalize_or_zero();
                let up = self.up.unwrap_or(if dir.cross(Vec3::Y).length() > 1e-3 {
                    Vec3::Y
                } else {
                    Vec3::Z
                });
                Camera {
                    eye,
                    target,
                    up,
                    fovy_deg: self.fovy,
                    width: w,
                    height: h,
                }
            }
        };
        cam.validate()
            .map_err(|e| ApiError::bad(format!("invalid camera: {e}")))?;
        Ok(cam)
    }

    /// Parts named (tinted ones, then the hovered one if not among them).
    fn named(&self) -> Vec<i64> {
        let mut v = self.parts.clone();
        if let Some(h) = self.hover
            && !v.contains(&h)
        {
            v.push(h);
        }
        v
    }
}

/// The callout layout of a view (`GET /api/v1/models/{id}/render/callouts`), for the browser
/// to draw as HTML.
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = CalloutLayout)]
pub struct CalloutsJson {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// The camera used.
    pub camera: ViewCamera,
    /// Font pixel size of the labels (1 = 5×7 glyphs; 1 below 400 pixels of height).
    pub font_scale: u32,
    /// Placed callouts, in priority order.
    pub callouts: Vec<callouts::Callout>,
    /// Parts that got no callout, with the reason.
    pub hidden: Vec<callouts::HiddenCallout>,
    /// Smallest gap in pixels between labels and from the image border.
    pub margin: u32,
    /// The input of the label placement: every part whose anchor is visible (in view, not
    /// occluded), in priority order, with its anchor and label size; the placed `callouts`
    /// and the `no_room` entries of `hidden` are these parts. With `margin` and the depth
    /// buffer of the same view (`render/buffers`), the browser's placement
    /// (`static/js/parts/place.js`) gives the same layout.
    pub labels: Vec<callouts::CalloutLabel>,
}

/// Checks that every named part is on the model; returns the bytes of their vertex sets.
async fn check_parts(state: &AppState, model_id: i64, ids: &[i64]) -> Result<u64, ApiError> {
    let mut bytes = 0u64;
    for &id in ids {
        match parts::model_and_set_size(&state.db, id).await? {
            None => return Err(ApiError::bad(format!("unknown part {id}"))),
            Some((m, _)) if m != model_id => {
                return Err(ApiError::bad(format!(
                    "part {id} is not on model {model_id}"
                )));
            }
            Some((_, size)) => bytes += size.max(0) as u64,
        }
    }
    Ok(bytes)
}

/// Vertex sets of the named parts, in order.
async fn load_sets(state: &AppState, ids: &[i64]) -> Result<Vec<(i64, RoaringBitmap)>, ApiError> {
    let mut out = Vec::with_capacity(ids.len());
    for &id in ids {
        let blob = parts::vertex_set_raw(&state.db, id).await?;
        let set = parts::parse_vertex_set(blob.as_deref())
            .map_err(|e| ApiError::internal(format!("part {id}: {e}")))?;
        out.push((id, set));
    }
    Ok(out)
}

/// Callout anchors and titles: the named parts, or every part of the model.
async fn callout_parts(
    state: &AppState,
    model_id: i64,
    named: &[i64],
    model: &RenderModel,
) -> Result<Vec<CalloutPart>, ApiError> {
    let all = parts::list_for_model(&state.db, model_id).await?;
    let chosen: Vec<&parts::Part> = if named.is_empty() {
        all.iter().take(MAX_PARTS).collect()
    } else {
        named
            .iter()
            .filter_map(|id| all.iter().find(|p| p.id == *id))
            .collect()
    };
    let mut out = Vec::with_capacity(chosen.len());
    for p in chosen {
        let title = assignments::contents_for_part(&state.db, p.id)
            .await?
            .into_iter()
            .next()
            .map(|c| c.title)
            .unwrap_or_else(|| format!("Part {}", p.id));
        let anchor = Vec3::new(p.center[0] as f32, p.center[1] as f32, p.center[2] as f32);
        if !anchor.is_finite() {
            continue;
        }
        out.push(CalloutPart {
            part: p.id,
            anchor,
            title,
            radius: model.radius() * 0.02,
        });
    }
    Ok(out)
}

/// The highlights of `sets`: `tinted` first ones tinted in order, `hover` outlined.
fn highlights<'a>(
    sets: &'a [(i64, RoaringBitmap)],
    tinted: usize,
    hover: Option<i64>,
) -> Vec<Highlight<'a>> {
    sets.iter()
        .enumerate()
        .map(|(i, (id, set))| Highlight {
            vertices: set,
            tint: (i < tinted).then(|| TINTS[i % TINTS.len()]),
            outline: hover == Some(*id),
        })
        .collect()
}

/// Draws the view-dependent cut of `params` for `camera`, with the highlights of `sets`.
fn render_view(
    r: &Renderer,
    model: &RenderModel,
    camera: &Camera,
    params: &Params,
    sets: &[(i64, RoaringBitmap)],
) -> Result<Frame, RenderServiceError> {
    let marks = highlights(sets, params.parts.len(), params.hover);
    let options = RenderOptions {
        cut: Cut::View {
            pixel_error: params.px,
            culling: Culling::ALL,
        },
        outputs: params.outputs,
        ..RenderOptions::default()
    };
    Ok(r.render(model, camera, &options, &marks)?)
}

/// A response body that keeps its render's memory reserved until it is sent.
struct HeldBody {
    data: Option<web::Bytes>,
    len: u64,
    _hold: MemoryHold,
}

impl MessageBody for HeldBody {
    type Error = std::convert::Infallible;

    fn size(&self) -> BodySize {
        BodySize::Sized(self.len)
    }

    fn poll_next(
        self: Pin<&mut Self>,
        _cx: &mut Context<'_>,
    ) -> Poll<Option<Result<web::Bytes, Self::Error>>> {
        Poll::Ready(self.get_mut().data.take().map(Ok))
    }
}

fn held(data: Vec<u8>, hold: MemoryHold) -> HeldBody {
    HeldBody {
        len: data.len() as u64,
        data: Some(web::Bytes::from(data)),
        _hold: hold,
    }
}

/// What every route does first: parameters, service, model, parts.
struct Prepared {
    service: RenderService,
    params: Params,
    model: RenderModel,
    camera: Camera,
    set_bytes: u64,
}

async fn prepare(
    state: &AppState,
    model_id: i64,
    q: &RenderQuery,
    route: Route,
) -> Result<Prepared, ApiError> {
    let service = state.render.clone();
    let params = Params::parse(q, route, service.settings())?;
    service.renderer()?;
    let open = state
        .models
        .open(&state.db, model_id, Purpose::Render)
        .await?;
    let set_bytes = check_parts(state, model_id, &params.named()).await?;
    let model = open.render.clone();
    let camera = params.camera(&model)?;
    Ok(Prepared {
        service,
        params,
        model,
        camera,
        set_bytes,
    })
}

fn stats_headers(resp: &mut actix_web::HttpResponseBuilder, stats: &RenderStats) {
    resp.insert_header(("X-Render-Triangles", stats.triangles.to_string()))
        .insert_header(("X-Render-Patches", stats.nodes.to_string()))
        .insert_header(("X-Render-Ms", format!("{:.1}", stats.total_ms)));
}

/// Render the model
///
/// The model's hierarchy drawn from a camera (view-dependent cut of `px` pixels): the parts
/// in `parts` tinted in order, the `hover` part outlined, callouts drawn on request. Runs on
/// a bounded worker pool (`MESHWIKI_RENDER_WORKERS`, `MESHWIKI_RENDER_QUEUE`); every
/// parameter is checked (400 with a message), as is every named part (on this model).
#[utoipa::path(get, path = "/api/v1/models/{id}/render", tag = "render",
    params(("id" = i64, Path, description = "model id"), ImageQuery),
    responses(
        (status = 200, description = "The image (`Content-Encoding: identity`)",
            content(
                (super::openapi::Binary = "image/png"),
                (super::openapi::Binary = "image/jpeg"),
                (super::openapi::Binary = "image/webp"),
            ),
            headers(
                ("X-Render-Triangles" = u64, description = "triangles drawn"),
                ("X-Render-Patches" = u64, description = "patches drawn"),
                ("X-Render-Ms" = f64, description = "render time in milliseconds"),
            )),
        (status = 409, description = "The model is not ready (pending, building or failed)",
            body = super::openapi::ErrorBody),
        (status = 503, description = "Render queue full or out of render memory (with Retry-After, seconds), or no GPU adapter on the server",
            body = super::openapi::ErrorBody,
            headers(("Retry-After" = u32, description = "seconds; absent when rendering is unavailable"))),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn image(
    state: web::Data<AppState>,
    reader: Reader,
    model_id: web::Path<i64>,
    q: web::Query<RenderQuery>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *model_id).await?;
    let model_id = *model_id;
    let p = prepare(&state, model_id, &q, Route::Image).await?;
    let (w, h) = (p.params.width, p.params.height);
    let bytes = p.params.outputs.frame_bytes(w, h) + w as u64 * h as u64 * 4 + 2 * p.set_bytes;
    let ticket = p.service.admit(bytes).await?;
    let named = p.params.named();
    let sets = load_sets(&state, &named).await?;
    let labels = if p.params.callouts {
        callout_parts(&state, model_id, &named, &p.model).await?
    } else {
        Vec::new()
    };
    let (params, model, camera) = (p.params, p.model, p.camera);
    let (result, hold) = p
        .service
        .run(ticket, move |r| -> Result<_, RenderServiceError> {
            let mut frame = render_view(r, &model, &camera, &params, &sets)?;
            let mut color = frame
                .color
                .take()
                .ok_or_else(|| RenderServiceError::Failed("no colour buffer".into()))?;
            if params.callouts {
                let opts = LayoutOptions::for_height(camera.height);
                let layout = callouts::layout(&labels, &camera, frame.depth.as_deref(), &opts)
                    .map_err(|e| RenderServiceError::Invalid(e.to_string()))?;
                frame.depth = None;
                callouts::draw(
                    &mut color,
                    &layout,
                    &CalloutStyle {
                        font_scale: opts.font_scale,
                        ..CalloutStyle::default()
                    },
                );
            }
            let bytes = encode::encode(
                &color,
                camera.width,
                camera.height,
                params.format,
                params.quality,
                [255, 255, 255],
            )?;
            Ok((bytes, frame.stats, params.format))
        })
        .await?;
    let (data, stats, format) = result?;
    let mut resp = HttpResponse::Ok();
    resp.insert_header((header::CONTENT_TYPE, format.mime()))
        .insert_header(ContentEncoding::Identity);
    stats_headers(&mut resp, &stats);
    Ok(resp.body(held(data, hold)))
}

/// Per-pixel buffers for tools
///
/// Body (little endian): `MWRB`, u32 version 1, u32 `J`, `J` bytes of JSON header (UTF-8,
/// padded with spaces to a multiple of 4: width, height, camera, pixel_error, parts, hover,
/// background, stats, buffers: `[{name, type, components, offset, bytes}]`), then the arrays
/// at their offsets, row-major, top row first: `color` u8×4, `normal` f32×3 (0 on the
/// background), `depth` f32 (linear view depth, +inf on the background), `node` u32,
/// `vertex` u32 (original vertex id of the model), `triangle` u32 (index in its patch),
/// `highlight` u32 (bits 0-7: 1-based index in `parts`, bit 8: hover, bit 31: covered); ids
/// are 0xFFFFFFFF on the background.
#[utoipa::path(get, path = "/api/v1/models/{id}/render/buffers", tag = "render",
    params(("id" = i64, Path, description = "model id"), BuffersQuery),
    responses(
        (status = 200, description = "The buffers (`Content-Encoding: identity`)",
            body = super::openapi::Binary, content_type = "application/octet-stream",
            headers(
                ("X-Render-Triangles" = u64, description = "triangles drawn"),
                ("X-Render-Patches" = u64, description = "patches drawn"),
                ("X-Render-Ms" = f64, description = "render time in milliseconds"),
            )),
        (status = 409, description = "The model is not ready (pending, building or failed)",
            body = super::openapi::ErrorBody),
        (status = 503, description = "Render queue full or out of render memory (with Retry-After, seconds), or no GPU adapter on the server",
            body = super::openapi::ErrorBody,
            headers(("Retry-After" = u32, description = "seconds; absent when rendering is unavailable"))),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn buffers(
    state: web::Data<AppState>,
    reader: Reader,
    model_id: web::Path<i64>,
    q: web::Query<RenderQuery>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *model_id).await?;
    let p = prepare(&state, *model_id, &q, Route::Buffers).await?;
    let (w, h) = (p.params.width, p.params.height);
    let o = p.params.outputs;
    if o.normal || o.depth || o.ids {
        // Depth, normals and vertex ids are the full-resolution surface.
        state
            .require_full_geometry(reader.user(), *model_id, "depth, normal and id buffers")
            .await?;
    }
    let per_px = 4 * o.color as u64 + 12 * o.normal as u64 + 4 * o.depth as u64 + 16 * o.ids as u64;
    let bytes = o.frame_bytes(w, h) + per_px * w as u64 * h as u64 + 4096 + 2 * p.set_bytes;
    let ticket = p.service.admit(bytes).await?;
    let sets = load_sets(&state, &p.params.named()).await?;
    let (params, model, camera) = (p.params, p.model, p.camera);
    let (result, hold) = p
        .service
        .run(ticket, move |r| -> Result<_, RenderServiceError> {
            let frame = render_view(r, &model, &camera, &params, &sets)?;
            Ok(buffers_body(frame, &camera, &params))
        })
        .await?;
    let (data, stats) = result?;
    let mut resp = HttpResponse::Ok();
    resp.insert_header((header::CONTENT_TYPE, "application/octet-stream"))
        .insert_header(ContentEncoding::Identity);
    stats_headers(&mut resp, &stats);
    Ok(resp.body(held(data, hold)))
}

/// Lays out the buffers body (see the module documentation), consuming the frame.
fn buffers_body(
    mut frame: meshwiki_engine::render::Frame,
    camera: &Camera,
    params: &Params,
) -> (Vec<u8>, RenderStats) {
    let n = frame.width as u64 * frame.height as u64;
    type Entry = (&'static str, &'static str, u32);
    let mut entries: Vec<Entry> = Vec::new();
    if frame.color.is_some() {
        entries.push(("color", "u8", 4));
    }
    if frame.normal.is_some() {
        entries.push(("normal", "f32", 3));
    }
    if frame.depth.is_some() {
        entries.push(("depth", "f32", 1));
    }
    if frame.ids.is_some() {
        for name in ["node", "vertex", "triangle", "highlight"] {
            entries.push((name, "u32", 1));
        }
    }
    // Header with placeholder offsets first, to know its length; offsets are fixed-width.
    let header_for = |base: u64| {
        let mut offset = base;
        let list: Vec<serde_json::Value> = entries
            .iter()
            .map(|(name, ty, comps)| {
                let bytes = n * *comps as u64 * if *ty == "u8" { 1 } else { 4 };
                let e = json!({"name": name, "type": ty, "components": comps,
                               "offset": offset, "bytes": bytes});
                offset += bytes;
                e
            })
            .collect();
        json!({
            "version": BUFFERS_VERSION,
            "width": frame.width,
            "height": frame.height,
            "camera": ViewCamera::of(camera),
            "pixel_error": params.px,
            "parts": params.parts,
            "hover": params.hover,
            "background": {"normal": [0.0, 0.0, 0.0], "depth": "inf", "id": u32::MAX},
            "stats": {"patches": frame.stats.nodes, "triangles": frame.stats.triangles,
                      "loaded": frame.stats.loaded, "ms": frame.stats.total_ms},
            "buffers": list,
        })
        .to_string()
    };
    // The header's length depends on the offsets' digits: iterate to a fixed point.
    let mut base = 12u64;
    let mut text = header_for(base);
    for _ in 0..4 {
        let padded = (text.len() as u64).div_ceil(4) * 4;
        if 12 + padded == base {
            break;
        }
        base = 12 + padded;
        text = header_for(base);
    }
    let padded = (text.len()).div_ceil(4) * 4;
    let total: u64 = base
        + entries
            .iter()
            .map(|(_, ty, c)| n * *c as u64 * if *ty == "u8" { 1 } else { 4 })
            .sum::<u64>();
    let mut out = Vec::with_capacity(total as usize);
    out.extend_from_slice(BUFFERS_MAGIC);
    out.extend_from_slice(&BUFFERS_VERSION.to_le_bytes());
    out.extend_from_slice(&(padded as u32).to_le_bytes());
    out.extend_from_slice(text.as_bytes());
    out.resize(12 + padded, b' ');
    debug_assert_eq!(out.len() as u64, base);
    if let Some(c) = frame.color.take() {
        out.extend_from_slice(bytemuck_bytes_u8(&c));
    }
    if let Some(nrm) = frame.normal.take() {
        for v in nrm {
            for x in v {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    if let Some(d) = frame.depth.take() {
        for x in d {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    if let Some(ids) = frame.ids.take() {
        for list in [ids.node, ids.vertex, ids.triangle, ids.highlight] {
            for x in list {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    (out, frame.stats)
}

fn bytemuck_bytes_u8(px: &[[u8; 4]]) -> &[u8] {
    px.as_flattened()
}

/// The callout layout of a view
///
/// For the browser to draw as HTML: each visible part's anchor (its centre) projected,
/// labels (the first assigned content's title, else `Part <id>`) placed without overlap,
/// leader lines; the parts named in `parts`/`hover`, or every part of the model (at most 64)
/// when none is named. Parts hidden (behind, outside, occluded, no room) are listed with the
/// reason.
#[utoipa::path(get, path = "/api/v1/models/{id}/render/callouts", tag = "render",
    params(("id" = i64, Path, description = "model id"), CalloutsQuery),
    responses(
        (status = 200, description = "The layout", body = CalloutsJson),
        (status = 409, description = "The model is not ready (pending, building or failed)",
            body = super::openapi::ErrorBody),
        (status = 503, description = "Render queue full or out of render memory (with Retry-After, seconds), or no GPU adapter on the server",
            body = super::openapi::ErrorBody,
            headers(("Retry-After" = u32, description = "seconds; absent when rendering is unavailable"))),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn callouts_json(
    state: web::Data<AppState>,
    reader: Reader,
    model_id: web::Path<i64>,
    q: web::Query<RenderQuery>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *model_id).await?;
    let model_id = *model_id;
    let p = prepare(&state, model_id, &q, Route::Callouts).await?;
    let (w, h) = (p.params.width, p.params.height);
    let ticket = p
        .service
        .admit(p.params.outputs.frame_bytes(w, h) + 2 * p.set_bytes)
        .await?;
    let named = p.params.named();
    let labels = callout_parts(&state, model_id, &named, &p.model).await?;
    let (params, model, camera) = (p.params, p.model, p.camera);
    let (result, _hold) = p
        .service
        .run(ticket, move |r| -> Result<_, RenderServiceError> {
            let frame = render_view(r, &model, &camera, &params, &[])?;
            let opts = LayoutOptions::for_height(camera.height);
            let layout = callouts::layout(&labels, &camera, frame.depth.as_deref(), &opts)
                .map_err(|e| RenderServiceError::Invalid(e.to_string()))?;
            Ok((layout, opts))
        })
        .await?;
    let (layout, opts) = result?;
    Ok(HttpResponse::Ok().json(CalloutsJson {
        width: layout.width,
        height: layout.height,
        camera: ViewCamera::of(&camera),
        font_scale: opts.font_scale,
        callouts: layout.callouts,
        hidden: layout.hidden,
        margin: opts.margin,
        labels: layout.labels,
    }))
}

/// Parses query string `text` for every render route and checks what is accepted against
/// `limits` (the oracle of the mutation test and of the fuzz target; panics on a violation).
/// Returns (accepted, refused) parses.
#[doc(hidden)]
pub fn checked_query(text: &str, limits: &RenderSettings) -> (u32, u32) {
    let Ok(query) = web::Query::<RenderQuery>::from_query(text) else {
        return (0, 1);
    };
    let (mut accepted, mut refused) = (0, 0);
    for route in [Route::Image, Route::Buffers, Route::Callouts] {
        match Params::parse(&query, route, limits) {
            Ok(p) => {
                accepted += 1;
                assert!(p.width >= 1 && p.width <= limits.max_side, "{text}");
                assert!(p.height >= 1 && p.height <= limits.max_side, "{text}");
                assert!(
                    p.width as u64 * p.height as u64 <= limits.max_pixels,
                    "{text}"
                );
                assert!(
                    p.fovy.is_finite() && (1.0..=170.0).contains(&p.fovy),
                    "{text}"
                );
                assert!(p.px.is_finite() && (0.25..=64.0).contains(&p.px), "{text}");
                assert!(p.parts.len() <= MAX_PARTS, "{text}");
                for v in [p.eye, p.target, p.up].into_iter().flatten() {
                    assert!(v.is_finite(), "{text}");
                }
            }
            Err(e) => {
                refused += 1;
                assert!(!e.message().is_empty(), "{text}");
            }
        }
    }
    (accepted, refused)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic mutation of real viewer queries (issue 14 §8): no panic, and every
    /// accepted query is within the limits.
    #[test]
    fn mutated_queries_are_refused_or_within_limits() {
        let seeds = [
            "eye=0.1,0.2,2.5&target=0,0,0&up=0,1,0&fovy=45&w=640&h=480&parts=1,2,3&hover=2&px=1&format=jpeg&quality=80&callouts=1",
            "w=1280&h=720&px=0.5&buffers=normal,depth,ids&eye=1e3,-2e3,5&target=1,1,1",
            "w=400&h=300&parts=7&callouts=true",
        ];
        let pieces = [
            "",
            "0",
            "-1",
            "1e39",
            "nan",
            "inf",
            "4294967296",
            ",",
            "&",
            "=",
            "%00",
            "%zz",
            "%2C",
            "99999999999999999999",
            "w=",
            "&w=70000",
            "&h=0",
            "&px=1e-9",
            "&fovy=170.0001",
            "&parts=",
            "&parts=-5",
            "&callouts=yes",
            "&buffers=",
            "&eye=1,2",
            "&unknown=1",
        ];
        let limits = RenderSettings::default();
        let mut rng = 0x2545_F491_4F6C_DD1Du64;
        let mut next = |n: usize| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng % n as u64) as usize
        };
        let (mut accepted, mut refused) = (0u32, 0u32);
        for case in 0..10_000 {
            let mut q = seeds[case % seeds.len()].as_bytes().to_vec();
            for _ in 0..1 + next(3) {
                let at = next(q.len() + 1);
                match next(4) {
                    0 => q.truncate(at),
                    1 => {
                        let end = (at + next(8)).min(q.len());
                        q.drain(at.min(end)..end);
                    }
                    2 => {
                        let p = pieces[next(pieces.len())].as_bytes();
                        q.splice(at..at, p.iter().copied());
                    }
                    _ => {
                        if let Some(b) = q.get_mut(at) {
                            *b = [b'0', b'9', b'.', b'-', b',', b'&', b'=', b'e', 0xFF][next(9)];
                        }
                    }
                }
            }
            let text = String::from_utf8_lossy(&q).into_owned();
            let (a, r) = checked_query(&text, &limits);
            accepted += a;
            refused += r;
        }
        println!("render queries: 10000 cases, {accepted} accepted, {refused} refused, 0 panics");
        assert!(accepted > 0 && refused > 0);
    }
}
