//! A model's Grid-Lumigraph image repository (system paper §5.3): its description, its
//! build (admins) and its images, keyed by grid point and direction.

use actix_web::http::header;
use actix_web::{HttpRequest, HttpResponse, web};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

use super::auth::{Auth, Reader};
use super::lod::IMMUTABLE;
use super::{ApiError, AppState};
use crate::app::lumigraph::{IMAGE_MEDIA_TYPE, LumigraphDescription, LumigraphImage};
use crate::store::jobs::Job;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        super::resource("/api/v1/models/{id}/lumigraph")
            .route(web::get().to(describe))
            .route(web::post().to(start)),
    )
    .service(
        super::resource("/api/v1/models/{id}/lumigraph/images/{x}/{y}/{z}/{d}")
            .route(web::get().to(image)),
    );
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(describe, start, image))]
pub(super) struct Api;

/// The model's image repository
///
/// Its status (`none`, `queued`, `building`, `ready`, `failed`), the grid (points per axis,
/// the viewing box it spans corner to corner, the spacing), the images (side, 90° field of
/// view, the six directions `d` = 0..5 with their up vectors, the media type), what is
/// recorded so far, and the sparse mesh clients draw the images onto.
#[utoipa::path(get, path = "/api/v1/models/{id}/lumigraph", tag = "lumigraph",
    params(("id" = i64, Path, description = "model id")),
    responses((status = 200, description = "The repository", body = LumigraphDescription)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn describe(
    state: web::Data<AppState>,
    reader: Reader,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *id).await?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CACHE_CONTROL, "no-store"))
        .json(state.lumigraph(*id).await?))
}

/// What to build.
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct LumigraphRequest {
    /// Grid points per axis, 2 to 64 (default 6: minutes on a software renderer for a
    /// 1M-triangle scan; the paper used 16 and 32).
    pub grid: Option<u32>,
    /// Image side in pixels, 16 to 2048 (default 512).
    pub size: Option<u32>,
}

/// The queued build.
#[derive(Debug, Serialize, ToSchema)]
pub struct LumigraphStarted {
    /// The repository (status `queued`, or `building` once a worker has taken the job).
    pub lumigraph: LumigraphDescription,
    /// The job that builds it (progress, cancel: `/api/v1/jobs/{id}`).
    pub job: Job,
}

/// Build (or rebuild) the model's image repository
///
/// Queues a background job that renders every grid point's six images from the model's
/// hierarchy, replacing the repository the model has. A repository of more than 2^36 pixels
/// in all (grid³ × 6 × size²) is refused (400). The job shows live progress, can be
/// cancelled, and resumes after a crash. The model must be ready, with no job queued or
/// running (409).
#[utoipa::path(post, path = "/api/v1/models/{id}/lumigraph", tag = "lumigraph",
    params(("id" = i64, Path, description = "model id")),
    request_body = LumigraphRequest,
    responses(
        (status = 202, description = "Queued", body = LumigraphStarted),
        (status = 409, description = "The model is not ready or has a job queued or running",
            body = super::openapi::ErrorBody),
    ),
    security(("sessionCookie" = ["admin"])))]
async fn start(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
    body: web::Bytes,
) -> Result<HttpResponse, ApiError> {
    // An empty body takes the defaults; anything else must be the JSON object.
    let body: LumigraphRequest = if body.iter().all(u8::is_ascii_whitespace) {
        LumigraphRequest::default()
    } else {
        serde_json::from_slice(&body)
            .map_err(|e| ApiError::bad(format!("invalid JSON body: {e}")))?
    };
    let (lumigraph, job) = state
        .start_lumigraph(auth.user(), *id, body.grid, body.size)
        .await?;
    Ok(HttpResponse::Accepted().json(LumigraphStarted { lumigraph, job }))
}

/// Which version of the repository a client expects.
#[derive(Debug, Deserialize, IntoParams)]
struct ImageQuery {
    /// The repository's `job_id`: a rebuilt repository answers 404 instead of an image of
    /// another grid (clients put it in the URL so their caches never mix two builds).
    v: Option<i64>,
    /// Refinement level, 0 (the default: the grid itself) to the description's `levels`;
    /// `x`, `y`, `z` count that level's points. A finer level's image is rendered the first
    /// time it is asked for.
    level: Option<u32>,
}

/// One image of the repository
///
/// The image of grid point `(x, y, z)` of refinement level `level` in direction `d`
/// (`docs/FORMAT.md`, "Lumigraph image": albedo, normals and view depth), immutable: `ETag`
/// its SHA-256, long cache; an image that shows nothing, or a point inside the object, is
/// `204`. Images of finer levels (points near the model, for close views) are rendered the
/// first time they are asked for and stored.
#[utoipa::path(get, path = "/api/v1/models/{id}/lumigraph/images/{x}/{y}/{z}/{d}",
    tag = "lumigraph",
    params(
        ("id" = i64, Path, description = "model id"),
        ("x" = u32, Path, description = "grid point, 0 to (grid - 1) * 2^level"),
        ("y" = u32, Path, description = "grid point, 0 to (grid - 1) * 2^level"),
        ("z" = u32, Path, description = "grid point, 0 to (grid - 1) * 2^level"),
        ("d" = u32, Path, description = "direction, 0 to 5 (+x, -x, +y, -y, +z, -z)"),
        ImageQuery,
        ("If-None-Match" = Option<String>, Header, description = "an ETag seen before"),
    ),
    responses(
        (status = 200, description = "The image", body = super::openapi::Binary,
            content_type = "application/vnd.meshwiki.lumigraph-image",
            headers(
                ("ETag" = String, description = "the image's SHA-256, quoted"),
                ("Cache-Control" = String, description = "`public, max-age=31536000, immutable`"),
            )),
        (status = 204, description = "The image shows nothing (or its point is inside the object)"),
        (status = 304, description = "Not modified (If-None-Match)"),
        (status = 404, description = "No repository, a key outside the grid (or a finer level's point away from the model), an image not rendered yet, or another version",
            body = super::openapi::ErrorBody),
        (status = 503, description = "An image of a finer level not rendered: the model's refined images are at their storage cap (MESHWIKI_REFINED_IMAGES_CAP), or the render queue is full",
            body = super::openapi::ErrorBody),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn image(
    state: web::Data<AppState>,
    reader: Reader,
    req: HttpRequest,
    path: web::Path<(i64, u32, u32, u32, u32)>,
    q: web::Query<ImageQuery>,
) -> Result<HttpResponse, ApiError> {
    let (id, x, y, z, d) = path.into_inner();
    reader.model(&state.db, id).await?;
    match state
        .lumigraph_image(id, q.level.unwrap_or(0), [x, y, z, d], q.v)
        .await?
    {
        LumigraphImage::Empty => Ok(HttpResponse::NoContent()
            .insert_header((header::CACHE_CONTROL, IMMUTABLE))
            .finish()),
        LumigraphImage::Image { path, sha256 } => {
            let etag = format!("\"{sha256}\"");
            if super::lod::not_modified(&req, &etag) {
                return Ok(HttpResponse::NotModified()
                    .insert_header((header::ETAG, etag))
                    .insert_header((header::CACHE_CONTROL, IMMUTABLE))
                    .finish());
            }
            let bytes = tokio::fs::read(&path).await.map_err(|e| {
                ApiError::internal(format!("image {sha256} of model {id} unreadable: {e}"))
            })?;
            Ok(HttpResponse::Ok()
                .insert_header((header::CONTENT_TYPE, IMAGE_MEDIA_TYPE))
                .insert_header((header::ETAG, etag))
                .insert_header((header::CACHE_CONTROL, IMMUTABLE))
                .body(bytes))
        }
    }
}
