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

use actix_multipart::Multipart;
use actix_web::http::header;
use actix_web::{HttpRequest, HttpResponse, web};
use futures_util::StreamExt;

use super::auth::Auth;
use super::{ApiError, AppState};
use crate::app::selections::{ConfirmRequest, MAX_MASK_BYTES, MAX_REQUEST_BYTES, SelectionRequest};
use crate::store::part_revisions;
use crate::store::parts;
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
        .body(parts::serialize_vertex_set(&d.set.vertices)))
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
    let (part, created) = state.confirm_selection(auth.id(), &id, &body).await?;
    let status = if created {
        actix_web::http::StatusCode::CREATED
    } else {
        actix_web::http::StatusCode::OK
    };
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
