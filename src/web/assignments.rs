//! Assignments (contents attached to parts): `/api/v1/parts/{id}/contents` and the reverse
//! `/api/v1/contents/{id}/parts`.

use actix_web::{HttpResponse, web};
use serde::Deserialize;
use utoipa::ToSchema;

use super::auth::{Auth, Reader};
use super::{ApiError, AppState};
use crate::app::events::{Event, EventKind};
use crate::store::assignments::{self, AssignedContent, AssignedPart};
use crate::store::contents;
use crate::store::users::Role;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        super::resource("/api/v1/parts/{id}/contents")
            .route(web::get().to(list))
            .route(web::post().to(assign))
            .route(web::put().to(reorder)),
    )
    .service(
        super::resource("/api/v1/parts/{id}/contents/{content_id}")
            .route(web::delete().to(unassign)),
    )
    .service(super::resource("/api/v1/contents/{id}/parts").route(web::get().to(parts_of)));
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(list, assign, reorder, unassign, parts_of))]
pub(super) struct Api;

/// Body of `POST /api/v1/parts/{id}/contents`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct AssignRequest {
    /// Content to assign.
    pub content_id: i64,
    /// 1-based position (default: last).
    #[serde(default)]
    pub position: Option<i64>,
}

/// Body of `PUT /api/v1/parts/{id}/contents`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ReorderRequest {
    /// Every assigned content id, in the new order.
    pub content_ids: Vec<i64>,
}

/// Contents assigned to a part, in order.
#[utoipa::path(get, path = "/api/v1/parts/{id}/contents", tag = "assignments",
    params(("id" = i64, Path, description = "part id")),
    responses((status = 200, description = "Assigned contents", body = Vec<AssignedContent>)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn list(
    state: web::Data<AppState>,
    reader: Reader,
    part: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.part(&state.db, *part).await?;
    Ok(HttpResponse::Ok().json(assignments::contents_for_part(&state.db, *part).await?))
}

/// Assign a content to a part
///
/// At `position` (1-based; default: last); the contents after it move down. A content that
/// does not exist is a 400.
#[utoipa::path(post, path = "/api/v1/parts/{id}/contents", tag = "assignments",
    params(("id" = i64, Path, description = "part id")),
    request_body = AssignRequest,
    responses(
        (status = 201, description = "The part's contents, in order", body = Vec<AssignedContent>),
        (status = 409, description = "Already assigned", body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["editor"])))]
async fn assign(
    state: web::Data<AppState>,
    auth: Auth,
    part: web::Path<i64>,
    body: web::Json<AssignRequest>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    assignments::assign(&state.db, *part, body.content_id, body.position, auth.id()).await?;
    state.sync_search().await;
    publish_part_contents(&state, *part).await;
    Ok(HttpResponse::Created().json(assignments::contents_for_part(&state.db, *part).await?))
}

/// Reorder a part's contents
///
/// `content_ids` must name every content assigned to the part exactly once (400 otherwise).
#[utoipa::path(put, path = "/api/v1/parts/{id}/contents", tag = "assignments",
    params(("id" = i64, Path, description = "part id")),
    request_body = ReorderRequest,
    responses(
        (status = 200, description = "The part's contents, in order", body = Vec<AssignedContent>)),
    security(("sessionCookie" = ["editor"])))]
async fn reorder(
    state: web::Data<AppState>,
    auth: Auth,
    part: web::Path<i64>,
    body: web::Json<ReorderRequest>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    assignments::reorder(&state.db, *part, &body.content_ids, auth.id()).await?;
    publish_part_contents(&state, *part).await;
    Ok(HttpResponse::Ok().json(assignments::contents_for_part(&state.db, *part).await?))
}

/// Remove a content from a part
///
/// The content itself stays; the part's other contents close up.
#[utoipa::path(delete, path = "/api/v1/parts/{id}/contents/{content_id}", tag = "assignments",
    params(
        ("id" = i64, Path, description = "part id"),
        ("content_id" = i64, Path, description = "content id")),
    responses((status = 204, description = "Removed")),
    security(("sessionCookie" = ["editor"])))]
async fn unassign(
    state: web::Data<AppState>,
    auth: Auth,
    path: web::Path<(i64, i64)>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let (part, content) = path.into_inner();
    assignments::unassign(&state.db, part, content, auth.id()).await?;
    state.sync_search().await;
    publish_part_contents(&state, part).await;
    Ok(HttpResponse::NoContent().finish())
}

/// Parts a content is assigned to.
#[utoipa::path(get, path = "/api/v1/contents/{id}/parts", tag = "assignments",
    params(("id" = i64, Path, description = "content id")),
    responses((status = 200, description = "Parts", body = Vec<AssignedPart>)),
    security(("sessionCookie" = ["viewer"])))]
async fn parts_of(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    contents::get(&state.db, *id).await?;
    Ok(HttpResponse::Ok().json(assignments::parts_for_content(&state.db, *id).await?))
}

/// Tells live viewers that the contents of part `part_id` changed (after the commit).
pub async fn publish_part_contents(state: &AppState, part_id: i64) {
    match crate::store::parts::get(&state.db, part_id).await {
        Ok(part) => {
            state
                .events
                .publish(Event::part(EventKind::PartContents, part.model_id, part.id))
        }
        Err(e) => tracing::warn!(part_id, error = %e, "cannot publish assignment change"),
    }
}
