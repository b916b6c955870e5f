//! A model's surface segments (issue 13; mesh-segmentation paper §3.1): what the viewer's
//! *Segments* tool previews under the cursor before a click selects a whole segment
//! (`POST /api/v1/models/{id}/selections` with `"tool": "segment"`).
//!
//! `GET /api/v1/models/{id}/segments` lists the scales (finest first, each coarser one with
//! about half the segments) and the scale offered first; `GET …/segments/{scale}/vertices
//! ?vertex=V` answers the segment at that scale holding original vertex `V`: its vertex set
//! as a serialised `RoaringBitmap` (what part and draft highlights are made of), its number
//! in `X-Segment`. Readers of the model may ask (segments name vertex ids, not geometry, so
//! `geometry_access = sparse` does not hide them). A model built before segments answers 409,
//! a scale it does not have 400, a vertex in no segment 404.

use actix_web::http::header;
use actix_web::{HttpRequest, HttpResponse, web};
use serde::Deserialize;
use utoipa::IntoParams;

use super::auth::Reader;
use super::{ApiError, AppState};
use crate::app::selections::SegmentScales;
use crate::store::parts;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/models/{id}/segments").route(web::get().to(scales)))
        .service(
            super::resource("/api/v1/models/{id}/segments/{scale}/vertices")
                .route(web::get().to(vertices)),
        );
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(scales, vertices))]
pub(super) struct Api;

/// The model's surface segments
///
/// Every scale of the segment hierarchy computed at build time, finest first, with its
/// segment count, and the scale a viewer offers first.
#[utoipa::path(get, path = "/api/v1/models/{id}/segments", tag = "selections",
    params(("id" = i64, Path, description = "model id")),
    responses(
        (status = 200, description = "The scales", body = SegmentScales),
        (status = 409, description = "The model was built before surface segments",
            body = super::openapi::ErrorBody),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn scales(
    state: web::Data<AppState>,
    reader: Reader,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *id).await?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CACHE_CONTROL, "no-cache"))
        .json(state.segment_scales(*id).await?))
}

/// Which segment.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
pub struct VertexQuery {
    /// An original vertex id: the segment holding it is answered.
    pub vertex: u32,
}

/// The vertices of the segment holding a vertex
///
/// The segment at `scale` that holds original vertex `vertex`, as a serialised
/// `RoaringBitmap` (portable format) of original vertex ids; the segment's number is in the
/// `X-Segment` header. The answer changes only when the model is rebuilt (`ETag`).
#[utoipa::path(get, path = "/api/v1/models/{id}/segments/{scale}/vertices", tag = "selections",
    params(("id" = i64, Path, description = "model id"),
        ("scale" = u32, Path, description = "scale (0: finest)"), VertexQuery),
    responses(
        (status = 200, description = "The segment's vertex set", body = super::openapi::Binary,
            content_type = "application/octet-stream",
            headers(("X-Segment" = u32, description = "the segment's number at this scale"))),
        (status = 304, description = "Not modified"),
        (status = 404, description = "The vertex lies in no segment", body = super::openapi::ErrorBody),
        (status = 409, description = "The model was built before surface segments",
            body = super::openapi::ErrorBody),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn vertices(
    state: web::Data<AppState>,
    reader: Reader,
    req: HttpRequest,
    path: web::Path<(i64, u32)>,
    q: web::Query<VertexQuery>,
) -> Result<HttpResponse, ApiError> {
    let (id, scale) = path.into_inner();
    reader.model(&state.db, id).await?;
    let m = state.segment_members(id, scale, q.vertex).await?;
    let etag = format!("\"{}-{}-{}\"", m.build, m.segment.scale, m.segment.id);
    let segment = m.segment.id.to_string();
    if super::lod::not_modified(&req, &etag) {
        return Ok(HttpResponse::NotModified()
            .insert_header((header::ETAG, etag))
            .insert_header(("X-Segment", segment))
            .finish());
    }
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "application/octet-stream"))
        .insert_header((header::ETAG, etag))
        .insert_header((header::CACHE_CONTROL, "no-cache"))
        .insert_header(("X-Segment", segment))
        .body(parts::serialize_vertex_set(&m.vertices)))
}
