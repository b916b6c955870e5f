//! Model uploads and build jobs.
//!
//! * `POST /api/v1/models/upload?title=&filename=[&description=]` (admin): the raw request
//!   body is the scan (or a `.zip` of it with the files it refers to), streamed to `uploads/` (never held in memory), then a model and its
//!   build job are created (202 with both). The file name only supplies the extension (the
//!   format); it is shown to users but never used as a path.
//! * `GET /api/v1/jobs` (admin), `GET /api/v1/jobs/{id}` (anyone logged in),
//!   `POST /api/v1/jobs/{id}/cancel` (admin).
//!
//! The admin page of jobs is `pages::jobs`.

use actix_web::http::header;
use actix_web::{HttpRequest, HttpResponse, web};
use futures_util::StreamExt;
use serde::{Deserialize, Serialize};
use serde_json::json;
use utoipa::{IntoParams, ToSchema};

use super::auth::Auth;
use super::multipart;
use super::{ApiError, AppState, PageQuery};
use crate::app::uploads::{BuildChoices, ScanFor};
use crate::jobs::archive::ReceivedFile;
use crate::jobs::{JobError, SCAN_EXTENSIONS, scan_extension};
use crate::store::jobs::{self, CancelOutcome, Job, JobStatus};
use crate::store::models::Model;
use crate::store::users::Role;
use meshwiki_engine::lod::VertexOrder;
use meshwiki_engine::lod::segsimplify::Simplifier;

/// Mounts the routes (before `models`: `/api/v1/models/upload` must win over `/{id}`).
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/models/upload").route(web::post().to(upload)))
        .service(super::resource("/api/v1/jobs").route(web::get().to(list)))
        .service(super::resource("/api/v1/jobs/{id}").route(web::get().to(get)))
        .service(super::resource("/api/v1/jobs/{id}/cancel").route(web::post().to(cancel)));
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(upload, list, get, cancel))]
pub(super) struct Api;

impl From<JobError> for ApiError {
    fn from(e: JobError) -> ApiError {
        match e {
            JobError::Store(s) => s.into(),
            JobError::Invalid(m) => ApiError::bad(m),
            JobError::TooLarge(m) => ApiError::PayloadTooLarge(m),
            JobError::Io(e) => ApiError::internal(format!("I/O: {e}")),
        }
    }
}

/// Whether model `id` can take a new scan (the store checks again when queueing).
pub async fn check_retry(state: &AppState, id: i64) -> Result<(), ApiError> {
    let model = crate::store::models::get(&state.db, id).await?;
    Ok(jobs::check_takes_scan(&model)?)
}

pub(crate) fn too_large(limit: u64) -> ApiError {
    ApiError::PayloadTooLarge(format!(
        "model upload larger than the limit of {limit} bytes (--max-model-upload-mb)"
    ))
}

pub(crate) fn check_title(title: &str, max: usize) -> Result<String, ApiError> {
    let t = title.trim();
    let n = t.chars().count();
    if n == 0 || n > max {
        return Err(ApiError::bad(format!(
            "title must be 1 to {max} characters"
        )));
    }
    Ok(t.to_string())
}

/// Checks that an uploaded file's name tells a scan format (or a `.zip` of a scan).
pub(crate) fn check_scan_name(filename: &str) -> Result<(), ApiError> {
    if scan_extension(filename).is_some() || crate::jobs::archive::is_zip(filename) {
        return Ok(());
    }
    Err(ApiError::bad(format!(
        "cannot tell the format of {:?}: the file name must end in {SCAN_EXTENSIONS} (or .zip, holding the scan and the files it refers to)",
        super::attachments::sanitize_name(filename)
    )))
}

/// Query of the raw upload.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct UploadQuery {
    /// Title of the new model (1–300 characters); not used with `model`.
    title: Option<String>,
    /// An existing model without a built scan (pending, or its build failed or was
    /// cancelled) that gets this scan instead of a new model: a retry. 409 for a ready model
    /// or one whose build is queued or running.
    model: Option<i64>,
    /// The scan's file name: only its extension (.ply, .obj, .gltf, .glb, .stl, .off, or .zip
    /// for an archive of the scan and the files it refers to) is used, to pick the format; it
    /// is shown to users but never used as a path.
    #[param(value_type = String, required = true)]
    filename: Option<String>,
    /// Description of the model (Markdown).
    #[serde(default)]
    description: String,
    /// How the levels are simplified: `quadric` (the default) or `segments`.
    #[param(value_type = Option<String>)]
    simplifier: Option<Simplifier>,
    /// Triangle budget of every patch (256–65536; default the server's).
    patch_triangles: Option<u32>,
    /// JPEG quality (1–100) of a textured scan's atlases (default 85).
    texture_quality: Option<u8>,
    /// How far an atlas' quality moves with its patch's feature density (0–50; default 10).
    texture_spread: Option<u8>,
    /// Bake a normal map into every coarse patch (default false).
    normal_maps: Option<bool>,
    /// How the model's vertices are numbered: `morton` (the default) or `source` (ids are
    /// the scan file's vertex indices).
    #[param(value_type = Option<String>)]
    vertex_order: Option<VertexOrder>,
}

impl UploadQuery {
    fn build(&self) -> BuildChoices {
        BuildChoices {
            simplifier: self.simplifier,
            patch_triangles: self.patch_triangles,
            texture_quality: self.texture_quality,
            texture_spread: self.texture_spread,
            normal_maps: self.normal_maps,
            vertex_order: self.vertex_order,
        }
    }
}

/// What an upload created: the model (status `pending`) and the job that builds it.
#[derive(Debug, Serialize, ToSchema)]
pub struct UploadedModel {
    /// The new model.
    pub model: Model,
    /// Its build job (poll `GET /api/v1/jobs/{id}` for its progress).
    pub job: Job,
}

/// Upload a scan and queue its LOD build
///
/// The raw request body is the scan (or a `.zip` of the scan and the files it refers to,
/// e.g. a glTF with its `.bin` and textures), streamed to disk (never held in memory); then a model
/// (status `pending`) and its build job are created, or, with `model`, the build of that
/// existing model is queued again with the new scan. The `Location` header names the job.
#[utoipa::path(post, path = "/api/v1/models/upload", tag = "jobs",
    params(UploadQuery),
    request_body(content = super::openapi::Binary, content_type = "application/octet-stream",
        description = "The scan file"),
    responses(
        (status = 202, description = "Queued", body = UploadedModel,
            headers(("Location" = String, description = "The job: /api/v1/jobs/{id}"))),
        (status = 400, description = "No filename, an empty body, or a build option out of range",
            body = super::openapi::ErrorBody),
        (status = 409, description = "`model` already has a built scan, or a build queued or running",
            body = super::openapi::ErrorBody),
        (status = 413, description = "Larger than --max-model-upload-mb",
            body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
async fn upload(
    state: web::Data<AppState>,
    auth: Auth,
    req: HttpRequest,
    q: web::Query<UploadQuery>,
    payload: web::Payload,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    // Before the body is read: options out of range are refused at once.
    let build = q.build();
    build.job_options().map_err(ApiError::from)?;
    let title = match q.model {
        Some(_) => String::new(),
        None => check_title(
            q.title.as_deref().unwrap_or(""),
            state.settings.limits.title_chars,
        )?,
    };
    if let Some(id) = q.model {
        // Before the body is read: a model that cannot take a scan is refused at once.
        check_retry(&state, id).await?;
    }
    let filename = q
        .filename
        .as_deref()
        .ok_or_else(|| ApiError::bad("the filename query parameter is required (e.g. scan.ply)"))?;
    check_scan_name(filename)?;
    let limit = state.settings.build.upload_bytes;
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    if declared.is_some_and(|n| n > limit) {
        return Err(too_large(limit));
    }
    let display = super::attachments::sanitize_name(filename);
    let body = payload.map(|c| c.map_err(|e| ApiError::bad(format!("upload interrupted: {e}"))));
    let dir = state.settings.uploads_dir();
    let spooled = multipart::spool(&dir, body, limit, false, || too_large(limit)).await?;
    if spooled.bytes == 0 {
        return Err(ApiError::bad("the upload is empty"));
    }
    let file = ReceivedFile {
        relative: display,
        temp: spooled.temp,
        bytes: spooled.bytes,
    };
    let target = match q.model {
        Some(id) => ScanFor::Existing(id),
        None => ScanFor::New {
            title,
            description: q.description.clone(),
        },
    };
    let (model, job) = state
        .submit_scan(vec![file], target, &build, auth.id())
        .await?;
    Ok(HttpResponse::Accepted()
        .insert_header((header::LOCATION, format!("/api/v1/jobs/{}", job.id)))
        .json(UploadedModel { model, job }))
}

/// Query of the job list.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct ListQuery {
    /// Only jobs in this state (queued, running, done, failed, cancelled).
    status: Option<String>,
    /// Rows to return (1–1000, default 100).
    limit: Option<i64>,
    /// Rows to skip.
    offset: Option<i64>,
}

fn parse_status(s: &str) -> Result<JobStatus, ApiError> {
    serde_json::from_value(json!(s.trim())).map_err(|_| {
        ApiError::bad(format!(
            "unknown job status {s:?}: use queued, running, done, failed or cancelled"
        ))
    })
}

/// List build jobs
///
/// Newest first, optionally only those in one state.
#[utoipa::path(get, path = "/api/v1/jobs", tag = "jobs",
    params(ListQuery),
    responses((status = 200, description = "Jobs, newest first", body = Vec<Job>)),
    security(("sessionCookie" = ["admin"])))]
async fn list(
    state: web::Data<AppState>,
    auth: Auth,
    q: web::Query<ListQuery>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let status = q.status.as_deref().map(parse_status).transpose()?;
    let page = PageQuery {
        limit: q.limit,
        offset: q.offset,
    }
    .page();
    Ok(HttpResponse::Ok().json(jobs::list(&state.db, status, page).await?))
}

/// A build job with its progress
///
/// Poll it while it runs.
#[utoipa::path(get, path = "/api/v1/jobs/{id}", tag = "jobs",
    params(("id" = i64, Path, description = "job id")),
    responses((status = 200, description = "The job", body = Job)),
    security(("sessionCookie" = ["viewer"])))]
async fn get(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    Ok(HttpResponse::Ok().json(jobs::get(&state.db, *id).await?))
}

/// Cancel a build job
///
/// A queued job is cancelled at once (200), a running one stops within about a second (202);
/// its model becomes `failed` and nothing is left on disk.
#[utoipa::path(post, path = "/api/v1/jobs/{id}/cancel", tag = "jobs",
    params(("id" = i64, Path, description = "job id")),
    responses(
        (status = 200, description = "Cancelled", body = Job),
        (status = 202, description = "Cancellation requested", body = Job),
        (status = 409, description = "The job has already ended",
            body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
async fn cancel(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    match state.jobs.cancel(*id, Some(auth.id())).await? {
        CancelOutcome::Cancelled(job) => Ok(HttpResponse::Ok().json(job)),
        CancelOutcome::Requested(job) => Ok(HttpResponse::Accepted().json(job)),
        CancelOutcome::Finished(job) => Err(ApiError::Conflict(format!(
            "job {} has already ended ({})",
            job.id,
            job.status.as_str()
        ))),
    }
}
