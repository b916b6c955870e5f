//! Resumable scan uploads (admin): a session lists the files, each file is sent in chunks
//! appended at the offset the server holds (the `Upload-Offset` header, as in tus), and the
//! complete session is finished into a model and its build job. An interrupted transfer asks
//! for the session's state and resumes from the last acknowledged byte.
//!
//! * `POST /api/v1/uploads` `{"files": [{"path", "size"}]}` → 201, the session;
//! * `GET /api/v1/uploads/{id}` → the session (bytes received per file);
//! * `PATCH /api/v1/uploads/{id}/files/{index}` with `Upload-Offset: N` and the bytes → 204
//!   with the new `Upload-Offset`; 409 with the held `Upload-Offset` when N is not it;
//! * `POST /api/v1/uploads/{id}/finish` `{"title", "description"}` or `{"model"}` → 202, the
//!   model and its job, as `POST /api/v1/models/upload`;
//! * `DELETE /api/v1/uploads/{id}` → 204, the session and its bytes removed.

use actix_web::http::header;
use actix_web::{HttpRequest, HttpResponse, web};
use futures_util::StreamExt;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::auth::Auth;
use super::jobs::{UploadedModel, check_title};
use super::openapi::ErrorBody;
use super::{ApiError, AppState};
use crate::app::uploads::{BuildChoices, ScanFor};
use crate::store::users::Role;
use crate::upload_sessions::{SessionError, SessionFile, SessionState};

/// The header that carries a file's offset (request: where the chunk starts; response: the
/// bytes held).
pub const UPLOAD_OFFSET: &str = "Upload-Offset";
/// The chunk size clients are asked to use: large enough that per-request costs vanish,
/// small enough that an interruption loses little.
pub const CHUNK_BYTES: u64 = 8 << 20;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/uploads").route(web::post().to(create)))
        .service(
            super::resource("/api/v1/uploads/{id}")
                .route(web::get().to(status))
                .route(web::delete().to(remove)),
        )
        .service(
            super::resource("/api/v1/uploads/{id}/files/{index}").route(web::patch().to(append)),
        )
        .service(super::resource("/api/v1/uploads/{id}/finish").route(web::post().to(finish)));
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(create, status, append, finish, remove))]
pub(super) struct Api;

/// A file to upload.
#[derive(Debug, Deserialize, ToSchema)]
pub struct UploadFileSpec {
    /// Relative path, as the scan refers to it (`scene.gltf`, `textures/albedo.jpg`): plain
    /// components only.
    pub path: String,
    /// Size in bytes.
    pub size: u64,
}

/// A new upload: one scan with the files it refers to, or one `.zip` of them.
#[derive(Debug, Deserialize, ToSchema)]
pub struct NewUpload {
    /// The files (at most 64).
    pub files: Vec<UploadFileSpec>,
}

/// A file of an upload.
#[derive(Debug, Serialize, ToSchema)]
pub struct UploadFileState {
    /// Relative path.
    pub path: String,
    /// Declared size.
    pub size: u64,
    /// Bytes received (and safe on disk): resume from here.
    pub received: u64,
}

/// An upload session.
#[derive(Debug, Serialize, ToSchema)]
pub struct UploadSession {
    /// Session id.
    pub id: String,
    /// Creation time (RFC 3339).
    pub created_at: String,
    /// When it is removed if no more bytes arrive (RFC 3339).
    pub expires_at: String,
    /// Whether every file is complete (it can be finished).
    pub complete: bool,
    /// The chunk size to send in.
    pub chunk_size: u64,
    /// The files, in the order declared (their index is their position).
    pub files: Vec<UploadFileState>,
}

impl From<SessionState> for UploadSession {
    fn from(s: SessionState) -> UploadSession {
        UploadSession {
            complete: s.complete(),
            id: s.id,
            created_at: s.created_at,
            expires_at: s.expires_at,
            chunk_size: CHUNK_BYTES,
            files: s
                .files
                .into_iter()
                .map(|f| UploadFileState {
                    path: f.path,
                    size: f.size,
                    received: f.received,
                })
                .collect(),
        }
    }
}

/// What the finished upload becomes: a new model (`title`, `description`) or the scan of an
/// existing model without a built scan (`model`: a retry).
#[derive(Debug, Deserialize, ToSchema)]
pub struct FinishUpload {
    /// Title of the new model (1–300 characters); not used with `model`.
    pub title: Option<String>,
    /// Description of the new model (Markdown).
    #[serde(default)]
    pub description: String,
    /// An existing model (pending, or its build failed or was cancelled) to give the scan.
    pub model: Option<i64>,
    /// Build options (each optional: the server's default where absent).
    #[serde(default)]
    pub build: BuildChoices,
}

fn session_error(e: SessionError) -> ApiError {
    ApiError::from(crate::app::AppError::from(e))
}

/// Start a resumable scan upload
///
/// Lists the files (one scan with the files it refers to, or one `.zip`) and their sizes;
/// refused at once when they cannot make a scan or exceed the upload limit. Send each file
/// with `PATCH /api/v1/uploads/{id}/files/{index}`, then finish the session.
#[utoipa::path(post, path = "/api/v1/uploads", tag = "jobs",
    request_body = NewUpload,
    responses(
        (status = 201, description = "Opened", body = UploadSession,
            headers(("Location" = String, description = "/api/v1/uploads/{id}"))),
        (status = 413, description = "Larger than --max-model-upload-mb", body = ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
async fn create(
    state: web::Data<AppState>,
    auth: Auth,
    body: web::Json<NewUpload>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let files = body
        .into_inner()
        .files
        .into_iter()
        .map(|f| SessionFile {
            path: f.path,
            size: f.size,
        })
        .collect();
    let s = state.open_upload(auth.id(), files).await?;
    Ok(HttpResponse::Created()
        .insert_header((header::LOCATION, format!("/api/v1/uploads/{}", s.id)))
        .json(UploadSession::from(s)))
}

/// An upload's state
///
/// The bytes received per file: an interrupted upload resumes from there.
#[utoipa::path(get, path = "/api/v1/uploads/{id}", tag = "jobs",
    params(("id" = String, Path, description = "Session id")),
    responses((status = 200, description = "The session", body = UploadSession)),
    security(("sessionCookie" = ["admin"])))]
async fn status(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let s = state
        .uploads
        .status(&id, auth.id())
        .await
        .map_err(session_error)?;
    Ok(HttpResponse::Ok().json(UploadSession::from(s)))
}

/// Send a chunk of a file
///
/// The body is appended to file `index` if `Upload-Offset` is the number of bytes the server
/// holds of it (else 409, with the held offset in `Upload-Offset`); the answer's
/// `Upload-Offset` is the new number, synced to disk. A body that breaks off keeps what
/// arrived: ask for the session's state and resume.
#[utoipa::path(patch, path = "/api/v1/uploads/{id}/files/{index}", tag = "jobs",
    params(("id" = String, Path, description = "Session id"),
        ("index" = usize, Path, description = "The file's position in the session"),
        ("Upload-Offset" = u64, Header, description = "Where this chunk starts")),
    request_body(content = super::openapi::Binary, content_type = "application/offset+octet-stream",
        description = "The next bytes of the file"),
    responses(
        (status = 204, description = "Appended",
            headers(("Upload-Offset" = u64, description = "Bytes of the file held now"))),
        (status = 409, description = "The file holds another number of bytes than `Upload-Offset` (see the answer's `Upload-Offset`), or another request writes it now",
            body = ErrorBody,
            headers(("Upload-Offset" = u64, description = "Bytes of the file held now"))),
        (status = 413, description = "The chunk goes beyond the file's declared size", body = ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
async fn append(
    state: web::Data<AppState>,
    auth: Auth,
    req: HttpRequest,
    path: web::Path<(String, usize)>,
    payload: web::Payload,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let (id, index) = path.into_inner();
    let offset = req
        .headers()
        .get(UPLOAD_OFFSET)
        .and_then(|v| v.to_str().ok())
        .map(str::trim)
        .filter(|v| !v.is_empty() && v.bytes().all(|b| b.is_ascii_digit()))
        .and_then(|v| v.parse::<u64>().ok())
        .ok_or_else(|| {
            ApiError::bad(
                "send the Upload-Offset header: the byte of the file this chunk starts at",
            )
        })?;
    let body = payload.map(|c| c.map_err(|e| e.to_string()));
    match state
        .uploads
        .append(&id, auth.id(), index, offset, body)
        .await
    {
        Ok(at) => Ok(HttpResponse::NoContent()
            .insert_header((UPLOAD_OFFSET, at.to_string()))
            .finish()),
        Err(e @ SessionError::Offset { offset, .. }) => Ok(HttpResponse::Conflict()
            .insert_header((UPLOAD_OFFSET, offset.to_string()))
            .json(ErrorBody {
                error: e.to_string(),
            })),
        Err(e) => Err(session_error(e)),
    }
}

/// Finish an upload into a build
///
/// Every file must be complete. The files become one scan (a `.zip` is unpacked) and, as with
/// `POST /api/v1/models/upload`, a new model (`title`, `description`) or the retry of an
/// existing one (`model`) is queued for its build; the session is gone.
#[utoipa::path(post, path = "/api/v1/uploads/{id}/finish", tag = "jobs",
    params(("id" = String, Path, description = "Session id")),
    request_body = FinishUpload,
    responses(
        (status = 202, description = "Queued", body = UploadedModel,
            headers(("Location" = String, description = "The job: /api/v1/jobs/{id}"))),
        (status = 400, description = "A file is incomplete, or a build option is out of range", body = ErrorBody),
        (status = 409, description = "`model` already has a built scan, or a build queued or running; or a chunk is being written",
            body = ErrorBody),
        (status = 413, description = "A .zip that unpacks beyond the limits", body = ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
async fn finish(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
    body: web::Json<FinishUpload>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let FinishUpload {
        title,
        description,
        model,
        build,
    } = body.into_inner();
    let target = match model {
        Some(m) => ScanFor::Existing(m),
        None => ScanFor::New {
            title: check_title(
                title.as_deref().unwrap_or(""),
                state.settings.limits.title_chars,
            )?,
            description,
        },
    };
    let (model, job) = state.finish_upload(auth.id(), &id, target, &build).await?;
    Ok(HttpResponse::Accepted()
        .insert_header((header::LOCATION, format!("/api/v1/jobs/{}", job.id)))
        .json(UploadedModel { model, job }))
}

/// Cancel an upload
///
/// The session and every byte received are removed.
#[utoipa::path(delete, path = "/api/v1/uploads/{id}", tag = "jobs",
    params(("id" = String, Path, description = "Session id")),
    responses(
        (status = 204, description = "Removed"),
        (status = 409, description = "A chunk is being written now", body = ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
async fn remove(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    state
        .uploads
        .remove(&id, auth.id())
        .await
        .map_err(session_error)?;
    Ok(HttpResponse::NoContent().finish())
}
