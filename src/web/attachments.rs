//! Attachments: upload (multipart, streamed to a temporary file in `uploads/` while hashing,
//! then renamed to its content address `attachments/ab/cdef...`), metadata, download with
//! safe headers, and links to contents.
//!
//! The uploader's file name is kept for display and the download's `Content-Disposition`
//! only; it is never used as a path.

use actix_multipart::Multipart;
use actix_web::body::SizedStream;
use actix_web::http::header;
use actix_web::{HttpResponse, web};
use futures_util::StreamExt;
use tokio::io::AsyncReadExt;
use utoipa::ToSchema;

use super::auth::{Auth, Reader};
use super::multipart::{TextFields, multipart_error, spool};
use super::{ApiError, AppState};
use crate::store::attachments::{self, Attachment, NewAttachment};
use crate::store::contents;
use crate::store::users::Role;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/attachments").route(web::post().to(upload)))
        .service(super::resource("/api/v1/attachments/{id}").route(web::get().to(get)))
        .service(
            super::resource("/api/v1/attachments/{id}/download").route(web::get().to(download)),
        )
        .service(
            super::resource("/api/v1/contents/{id}/attachments")
                .route(web::get().to(list_for_content))
                .route(web::post().to(upload_to_content)),
        )
        .service(
            super::resource("/api/v1/contents/{id}/attachments/{attachment_id}")
                .route(web::put().to(link))
                .route(web::delete().to(unlink)),
        );
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(
    upload,
    get,
    download,
    list_for_content,
    upload_to_content,
    link,
    unlink
))]
pub(super) struct Api;

/// The multipart form of `POST /api/v1/attachments` (documentation only; [`receive`] reads
/// it as a stream).
#[derive(ToSchema)]
pub struct AttachmentUpload {
    /// The file: exactly one file part (named `file`, or any part with a file name). Its file
    /// name is kept for display only; its declared media type is kept when well-formed, else
    /// guessed from the name.
    #[schema(value_type = String, format = Binary)]
    pub file: Vec<u8>,
    /// Attach the upload to this content, at the end of its list (a text field; empty means
    /// none).
    pub content_id: Option<i64>,
}

/// The multipart form of `POST /api/v1/contents/{id}/attachments` (documentation only;
/// [`receive`] reads it as a stream).
#[derive(ToSchema)]
pub struct ContentAttachmentUpload {
    /// The file: exactly one file part (named `file`, or any part with a file name). Its file
    /// name is kept for display only; its declared media type is kept when well-formed, else
    /// guessed from the name.
    #[schema(value_type = String, format = Binary)]
    pub file: Vec<u8>,
}

/// A file received from a multipart upload, stored under its content address.
#[derive(Debug)]
pub struct Received {
    /// What to record.
    pub attachment: NewAttachment,
    /// The other (text) fields of the form.
    pub fields: TextFields,
}

/// Keeps only the last path component, drops control characters, caps the length.
pub fn sanitize_name(name: &str) -> String {
    let last = name.rsplit(['/', '\\']).next().unwrap_or("");
    let clean: String = last
        .chars()
        .filter(|c| !c.is_control() && !matches!(c, '"' | '<' | '>'))
        .take(200)
        .collect();
    let clean = clean.trim().trim_start_matches('.').to_string();
    if clean.is_empty() {
        "file".into()
    } else {
        clean
    }
}

/// A syntactically plain `type/subtype` media type (parameters dropped), or
/// `application/octet-stream`.
pub fn clean_media_type(declared: Option<&str>, name: &str) -> String {
    let plain = |m: &str| {
        let m = m
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase();
        let ok = m.len() <= 100
            && m.split_once('/').is_some_and(|(a, b)| {
                !a.is_empty()
                    && !b.is_empty()
                    && m.bytes().all(|c| {
                        c.is_ascii_alphanumeric() || matches!(c, b'/' | b'.' | b'+' | b'-')
                    })
            });
        ok.then_some(m)
    };
    match declared.and_then(plain) {
        Some(m) if m != "application/octet-stream" => m,
        _ => mime_guess::from_path(name)
            .first()
            .map(|m| m.essence_str().to_string())
            .and_then(|m| plain(&m))
            .unwrap_or_else(|| "application/octet-stream".into()),
    }
}

/// Reads a multipart form with one `file` field. With `csrf`, a `csrf_token` text field
/// holding that value must come before the file (HTML forms); otherwise 403.
pub async fn receive(
    state: &AppState,
    mut form: Multipart,
    csrf: Option<&str>,
) -> Result<Received, ApiError> {
    let limit = state.settings.limits.upload_bytes;
    let mut fields = TextFields::new();
    let mut received: Option<NewAttachment> = None;
    while let Some(field) = form.next().await {
        let mut field = field.map_err(multipart_error)?;
        let name = field.name().unwrap_or("").to_string();
        let filename = field
            .content_disposition()
            .and_then(|cd| cd.get_filename())
            .map(str::to_string);
        if name == "file" || (filename.is_some() && name != "csrf_token") {
            if received.is_some() {
                return Err(ApiError::bad("upload exactly one file per request"));
            }
            if let Some(expected) = csrf {
                let sent = fields.get("csrf_token").unwrap_or("");
                if !super::auth::constant_time_eq(sent, expected) {
                    return Err(ApiError::Forbidden(
                        "missing or invalid CSRF token: reload the page and try again".into(),
                    ));
                }
            }
            let original_name = sanitize_name(filename.as_deref().unwrap_or("file"));
            let media_type = clean_media_type(
                field.content_type().map(|m| m.essence_str()),
                &original_name,
            );
            let stream = (&mut field).map(|c| c.map_err(multipart_error));
            let spooled = spool(&state.settings.uploads_dir(), stream, limit, true, || {
                ApiError::PayloadTooLarge(format!(
                    "attachment larger than the limit of {limit} bytes"
                ))
            })
            .await?;
            let sha256 = spooled.sha256.unwrap_or_default();
            let settings = state.settings.clone();
            let (tmp, sha) = (spooled.temp, sha256.clone());
            tokio::task::spawn_blocking(move || crate::blobs::commit_temp(&settings, tmp, &sha))
                .await
                .map_err(ApiError::internal)??;
            received = Some(NewAttachment {
                sha256,
                media_type,
                size: spooled.bytes as i64,
                original_name,
            });
        } else {
            fields.read(name, &mut field, 4096).await?;
        }
    }
    let attachment = received.ok_or_else(|| ApiError::bad("no file field in the upload"))?;
    Ok(Received { attachment, fields })
}

/// Upload a file
///
/// Multipart field `file`, optional field `content_id` to attach it to a content. The file is
/// stored under its SHA-256 (content address); its name is kept for display only.
#[utoipa::path(post, path = "/api/v1/attachments", tag = "attachments",
    request_body(content = inline(AttachmentUpload), content_type = "multipart/form-data"),
    responses(
        (status = 201, description = "Uploaded", body = Attachment),
        (status = 413, description = "File larger than the upload limit, or too many or too \
            large text fields", body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["editor"])))]
async fn upload(
    state: web::Data<AppState>,
    auth: Auth,
    form: Multipart,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let r = receive(&state, form, None).await?;
    let content_id = match r.fields.get("content_id").map(str::trim) {
        None | Some("") => None,
        Some(s) => Some(
            s.parse::<i64>()
                .map_err(|_| ApiError::bad("content_id must be an integer"))?,
        ),
    };
    let a = attachments::create(&state.db, &r.attachment, content_id, auth.id()).await?;
    if content_id.is_some() {
        state.sync_search().await;
    }
    Ok(HttpResponse::Created().json(a))
}

/// Upload a file and attach it to a content
///
/// Multipart field `file`; the attachment goes at the end of the content's list.
#[utoipa::path(post, path = "/api/v1/contents/{id}/attachments", tag = "attachments",
    params(("id" = i64, Path, description = "content id")),
    request_body(content = inline(ContentAttachmentUpload), content_type = "multipart/form-data"),
    responses(
        (status = 201, description = "Uploaded", body = Attachment),
        (status = 413, description = "File larger than the upload limit, or too many or too \
            large text fields", body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["editor"])))]
async fn upload_to_content(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
    form: Multipart,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    contents::get(&state.db, *id).await?;
    let r = receive(&state, form, None).await?;
    let a = attachments::create(&state.db, &r.attachment, Some(*id), auth.id()).await?;
    state.sync_search().await;
    Ok(HttpResponse::Created().json(a))
}

/// Attachment metadata.
#[utoipa::path(get, path = "/api/v1/attachments/{id}", tag = "attachments",
    params(("id" = i64, Path, description = "attachment id")),
    responses((status = 200, description = "The attachment", body = Attachment)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn get(
    state: web::Data<AppState>,
    reader: Reader,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.attachment(&state.db, *id).await?;
    Ok(HttpResponse::Ok().json(attachments::get(&state.db, *id).await?))
}

/// Media types shown inline; everything else (HTML, SVG, JS, PDF, ...) downloads.
fn is_passive(media_type: &str) -> bool {
    matches!(
        media_type,
        "image/png" | "image/jpeg" | "image/gif" | "image/webp" | "image/avif" | "text/plain"
    ) || media_type.starts_with("audio/")
        || media_type.starts_with("video/")
}

/// `Content-Disposition` for a download of `a`.
pub fn disposition(a: &Attachment) -> String {
    let kind = if is_passive(&a.media_type) {
        "inline"
    } else {
        "attachment"
    };
    let ascii: String = a
        .original_name
        .chars()
        .map(|c| {
            if c.is_ascii_graphic() && c != '"' && c != '\\' || c == ' ' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!(
        "{kind}; filename=\"{ascii}\"; filename*=UTF-8''{}",
        super::error::encode_component(&a.original_name).replace('/', "%2F")
    )
}

/// Streams an attachment's file with safe headers.
pub async fn serve_file(state: &AppState, a: &Attachment) -> Result<HttpResponse, ApiError> {
    let path = state
        .settings
        .attachment_path(&a.sha256)
        .ok_or_else(|| ApiError::internal("attachment with malformed hash"))?;
    let file = tokio::fs::File::open(&path).await.map_err(|e| {
        tracing::error!(path = %path.display(), error = %e, "attachment file missing");
        ApiError::NotFound("attachment file is missing".into())
    })?;
    let len = file.metadata().await?.len();
    let stream = futures_util::stream::unfold(Some(file), |file| async move {
        let mut file = file?;
        let mut buf = vec![0u8; 64 * 1024];
        match file.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((Ok::<_, std::io::Error>(web::Bytes::from(buf)), Some(file)))
            }
            Err(e) => Some((Err(e), None)),
        }
    });
    let media = if a.media_type == "text/plain" {
        "text/plain; charset=utf-8".to_string()
    } else {
        a.media_type.clone()
    };
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, media))
        .insert_header((header::CONTENT_DISPOSITION, disposition(a)))
        .insert_header(("X-Content-Type-Options", "nosniff"))
        .insert_header((
            "Content-Security-Policy",
            "default-src 'none'; img-src 'self'; media-src 'self'; style-src 'unsafe-inline'; sandbox",
        ))
        .insert_header((header::ETAG, format!("\"{}\"", a.sha256)))
        .insert_header((header::CACHE_CONTROL, "private, max-age=86400"))
        .body(SizedStream::new(len, Box::pin(stream))))
}

/// Download the file
///
/// Sent as its stored media type with `X-Content-Type-Options: nosniff` and a sandboxing
/// `Content-Security-Policy`; passive types (common images, audio, video, plain text) inline,
/// active ones (HTML, SVG, JS, PDF, ...) with `Content-Disposition: attachment`.
#[utoipa::path(get, path = "/api/v1/attachments/{id}/download", tag = "attachments",
    params(("id" = i64, Path, description = "attachment id")),
    responses((status = 200, description = "The file", body = super::openapi::Binary,
        content_type = "*/*",
        headers(
            ("Content-Disposition" = String,
                description = "`inline` or `attachment`, with the original file name"),
            ("ETag" = String, description = "The SHA-256 of the file, quoted"),
            ("X-Content-Type-Options" = String, description = "`nosniff`")))),
    security((), ("sessionCookie" = ["viewer"])))]
async fn download(
    state: web::Data<AppState>,
    reader: Reader,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.attachment(&state.db, *id).await?;
    let a = attachments::get(&state.db, *id).await?;
    serve_file(&state, &a).await
}

/// Attachments of a content, in order.
#[utoipa::path(get, path = "/api/v1/contents/{id}/attachments", tag = "attachments",
    params(("id" = i64, Path, description = "content id")),
    responses((status = 200, description = "Attachments", body = Vec<Attachment>)),
    security(("sessionCookie" = ["viewer"])))]
async fn list_for_content(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    contents::get(&state.db, *id).await?;
    Ok(HttpResponse::Ok().json(attachments::list_for_content(&state.db, *id).await?))
}

/// Attach an existing attachment
///
/// At the end of the content's list.
#[utoipa::path(put, path = "/api/v1/contents/{id}/attachments/{attachment_id}",
    tag = "attachments",
    params(
        ("id" = i64, Path, description = "content id"),
        ("attachment_id" = i64, Path, description = "attachment id")),
    responses(
        (status = 200, description = "Attachments of the content, in order",
            body = Vec<Attachment>),
        (status = 409, description = "Already attached", body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["editor"])))]
async fn link(
    state: web::Data<AppState>,
    auth: Auth,
    path: web::Path<(i64, i64)>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let (content, attachment) = path.into_inner();
    attachments::get(&state.db, attachment).await?;
    attachments::link(&state.db, content, attachment, auth.id()).await?;
    state.sync_search().await;
    Ok(HttpResponse::Ok().json(attachments::list_for_content(&state.db, content).await?))
}

/// Detach an attachment
///
/// The attachment itself stays (other contents or thumbnails may use it).
#[utoipa::path(delete, path = "/api/v1/contents/{id}/attachments/{attachment_id}",
    tag = "attachments",
    params(
        ("id" = i64, Path, description = "content id"),
        ("attachment_id" = i64, Path, description = "attachment id")),
    responses((status = 204, description = "Detached")),
    security(("sessionCookie" = ["editor"])))]
async fn unlink(
    state: web::Data<AppState>,
    auth: Auth,
    path: web::Path<(i64, i64)>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let (content, attachment) = path.into_inner();
    attachments::unlink(&state.db, content, attachment, auth.id()).await?;
    state.sync_search().await;
    Ok(HttpResponse::NoContent().finish())
}
