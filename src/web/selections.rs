//! Region selection on the server (issue 6; system paper §4): strokes in, a *draft* selection
//! of exact full-resolution vertices out; confirming a draft makes (or edits) a part.
//!
//! `POST /api/v1/models/{id}/selections` (editors) takes a multipart form with
//!
//! * `request`: JSON `{"tool", "mode", "camera", "point", "scale", "part_id", "base", "params",
//!   "pixel_error"}` — `tool` is `lasso`, `markup`, `heavy_lasso`, `point` or `segment` (a
//!   click selecting the whole surface segment under it at `scale`, see [`super::segments`]);
//!   `mode` is
//!   `replace` (default), `add` or `subtract`; `camera` is the view the strokes were drawn on
//!   (`eye`, `target`, `up`, `fovy` in degrees, `width` and `height` in pixels); `point` the
//!   clicked pixel `[x, y]` of the point tool; `part_id` a part to edit (its vertex set is the
//!   base of add/subtract, and confirming updates it); `base` a previous draft of the same
//!   user to build on instead (several strokes before confirming); `params` the energy's
//!   weights ([`EnergyParams`](meshwiki_engine::select::EnergyParams)); `pixel_error` the cut's threshold (default 1 px);
//! * `mask`: the stroke mask, a PNG of the camera's size whose grey levels are labels:
//!   0 none, 1 foreground, 2 background, 3 heavy band, 4 lasso inside
//!   ([`meshwiki_engine::select::mask`]). The point and segment tools need no mask (the
//!   request may then be sent as plain JSON).
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

use actix_multipart::Multipart;
use actix_web::http::header;
use actix_web::{HttpRequest, HttpResponse, web};
use futures_util::StreamExt;
use utoipa::ToSchema;

use super::auth::Auth;
use super::{ApiError, AppState};
use crate::app::selections::{
    ConfirmRequest, MAX_MASK_BYTES, MAX_REQUEST_BYTES, SelectionDraft, SelectionRequest,
};
use crate::store::part_revisions::{self, PartRevision};
use crate::store::parts::{self, Part};
use crate::store::users::Role;

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

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(
    create,
    get,
    discard,
    mask_png,
    vertices,
    confirm,
    revisions,
    revision_vertices
))]
pub(super) struct Api;

/// The multipart form of `POST /api/v1/models/{id}/selections` (it documents what
/// `read_body` reads; fields in any order, each at most once).
#[derive(ToSchema)]
pub struct SelectionForm {
    /// The selection request (JSON, at most 64 KiB).
    pub request: SelectionRequest,
    /// The stroke mask (at most 32 MiB): a PNG of the camera's size whose grey levels are
    /// labels: 0 none, 1 foreground, 2 background, 3 heavy band, 4 lasso inside. Every tool
    /// but `point` needs it.
    #[schema(value_type = Option<String>, format = Binary)]
    pub mask: Option<Vec<u8>>,
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

// ---- handlers -------------------------------------------------------------------------------

/// Make a draft selection
///
/// Strokes (or a click) on one view in, a draft of exact full-resolution vertices out. The
/// body is a `multipart/form-data` form with a `request` field (JSON) and a `mask` field
/// (the stroke mask PNG, `image/png` or `application/octet-stream`); the point tool needs no
/// mask, so its request may also be sent as the whole `application/json` body. The server
/// renders the view's colour, normal, depth and id buffers on the render pool (the same
/// admission, worker and memory limits as every render), cuts, back-projects the selected
/// pixels to original vertex ids (occluded surfaces are never selected), combines them with
/// the base (`part_id` or a previous draft `base`) in `mode`, and keeps the result for 30
/// minutes as the user's draft. Drafts belong to their user: anyone else gets 404. Bad input
/// is a 400 with a message: a mask that is not a label image or of the wrong size, empty
/// strokes, a heavy lasso that encloses nothing, a camera that sees nothing or is invalid, a
/// view beyond the render limits, an unknown form field.
#[utoipa::path(post, path = "/api/v1/models/{id}/selections", tag = "selections",
    params(("id" = i64, Path, description = "model id")),
    request_body(
        description = "A multipart form (`request` + `mask`), or for the point tool the request as JSON",
        content(
            (inline(SelectionForm) = "multipart/form-data",
                encoding(
                    ("request" = (content_type = "application/json")),
                    ("mask" = (content_type = "image/png, application/octet-stream")),
                )),
            (SelectionRequest = "application/json"),
        )),
    responses(
        (status = 201, description = "The draft", body = SelectionDraft),
        (status = 409, description = "The model is not ready (pending, building or failed)",
            body = super::openapi::ErrorBody),
        (status = 413, description = "The request field (64 KiB) or the mask (32 MiB) is too large",
            body = super::openapi::ErrorBody),
        (status = 415, description = "Neither multipart/form-data nor application/json, or a mask that is not a PNG",
            body = super::openapi::ErrorBody),
        (status = 503, description = "Render queue full or out of render memory (with Retry-After, seconds), or no GPU adapter on the server",
            body = super::openapi::ErrorBody,
            headers(("Retry-After" = u32, description = "seconds; absent when rendering is unavailable"))),
    ),
    security(("sessionCookie" = ["editor"])))]
async fn create(
    state: web::Data<AppState>,
    auth: Auth,
    model_id: web::Path<i64>,
    req: HttpRequest,
    payload: web::Payload,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let (request, mask) = read_body(&req, payload).await?;
    let draft = state.select(auth.id(), *model_id, request, mask).await?;
    Ok(HttpResponse::Created().json(draft.json(true)))
}

/// Get a draft selection
///
/// The user's own draft (anyone else's is 404), with the selected pixels as a data URL.
#[utoipa::path(get, path = "/api/v1/selections/{draft}", tag = "selections",
    params(("draft" = String, Path, description = "draft id")),
    responses((status = 200, description = "The draft", body = SelectionDraft)),
    security(("sessionCookie" = ["viewer"])))]
async fn get(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    let d = state.selections.get(&id, auth.id())?;
    Ok(HttpResponse::Ok().json(d.json(true)))
}

/// Discard a draft selection
///
/// The user's own draft (anyone else's is 404).
#[utoipa::path(delete, path = "/api/v1/selections/{draft}", tag = "selections",
    params(("draft" = String, Path, description = "draft id")),
    responses((status = 204, description = "Discarded")),
    security(("sessionCookie" = ["viewer"])))]
async fn discard(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    let d = state.selections.get(&id, auth.id())?;
    state.selections.remove(&d.id);
    Ok(HttpResponse::NoContent().finish())
}

/// The draft's selected pixels
///
/// A PNG of the view's size, alpha 255 where selected.
#[utoipa::path(get, path = "/api/v1/selections/{draft}/mask", tag = "selections",
    params(("draft" = String, Path, description = "draft id")),
    responses((status = 200, description = "The mask", body = super::openapi::Binary,
        content_type = "image/png")),
    security(("sessionCookie" = ["viewer"])))]
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

/// The draft's vertex set
///
/// A serialised `RoaringBitmap` (portable format) of original vertex ids.
#[utoipa::path(get, path = "/api/v1/selections/{draft}/vertices", tag = "selections",
    params(("draft" = String, Path, description = "draft id")),
    responses((status = 200, description = "The vertex set", body = super::openapi::Binary,
        content_type = "application/octet-stream")),
    security(("sessionCookie" = ["viewer"])))]
async fn vertices(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<String>,
) -> Result<HttpResponse, ApiError> {
    let d = state.selections.get(&id, auth.id())?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "application/octet-stream"))
        .body(parts::serialize_vertex_set(&d.set.vertices)))
}

/// Confirm a draft selection
///
/// Creates a part from the draft (201), or updates the part it edits (200) as a revision
/// with the tool and the view; the draft is then gone. The body is optional (empty: the
/// defaults). The part gets its best view and thumbnail from the render service.
#[utoipa::path(post, path = "/api/v1/selections/{draft}/confirm", tag = "selections",
    params(("draft" = String, Path, description = "draft id")),
    request_body = Option<ConfirmRequest>,
    responses(
        (status = 201, description = "A part created", body = Part),
        (status = 200, description = "The edited part updated", body = Part),
        (status = 409, description = "The edited part changed since the draft was made",
            body = super::openapi::ErrorBody),
    ),
    security(("sessionCookie" = ["editor"])))]
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
    let (part, created) = state.confirm_selection(auth.id(), &id, &body).await?;
    let status = if created {
        actix_web::http::StatusCode::CREATED
    } else {
        actix_web::http::StatusCode::OK
    };
    Ok(HttpResponse::build(status).json(part))
}

/// A part's history
///
/// Every revision of the part, oldest first: created, edited through `/api/v1/parts` or a
/// selection, deleted; with its state then (kind, centre, vertex count, camera), author,
/// time, comment, and the selection tool and view when a selection made it. A part made
/// before revisions were kept has none.
#[utoipa::path(get, path = "/api/v1/parts/{id}/revisions", tag = "parts",
    params(("id" = i64, Path, description = "part id")),
    responses((status = 200, description = "The revisions, oldest first", body = Vec<PartRevision>)),
    security(("sessionCookie" = ["viewer"])))]
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

/// A part's vertex set at a revision
///
/// A serialised `RoaringBitmap` (portable format) of original vertex ids (empty when the
/// revision had none).
#[utoipa::path(get, path = "/api/v1/parts/{id}/revisions/{number}/vertices", tag = "parts",
    params(
        ("id" = i64, Path, description = "part id"),
        ("number" = i64, Path, description = "revision number (1 = creation)"),
    ),
    responses((status = 200, description = "The vertex set", body = super::openapi::Binary,
        content_type = "application/octet-stream")),
    security(("sessionCookie" = ["viewer"])))]
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
