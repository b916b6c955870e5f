//! Parts (identified points and regions on a model): `/api/v1/models/{id}/parts`,
//! `/api/v1/parts/{id}` and the raw vertex set `/api/v1/parts/{id}/vertices`.

use actix_web::{HttpResponse, http::header, web};

use super::auth::{Auth, Reader};
use super::{ApiError, AppState};
use crate::store::models;
use crate::store::parts::{self, NewPart, Part, PartPatch};
use crate::store::users::Role;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        super::resource("/api/v1/models/{id}/parts")
            .route(web::get().to(list))
            .route(web::post().to(create)),
    )
    .service(
        super::resource("/api/v1/parts/{id}")
            .route(web::get().to(get))
            .route(web::patch().to(update))
            .route(web::delete().to(delete)),
    )
    .service(super::resource("/api/v1/parts/{id}/vertices").route(web::get().to(vertices)));
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(list, create, get, update, delete, vertices))]
pub(super) struct Api;

/// List a model's parts.
#[utoipa::path(get, path = "/api/v1/models/{id}/parts", tag = "parts",
    params(("id" = i64, Path, description = "model id")),
    responses((status = 200, description = "The model's parts", body = Vec<Part>)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn list(
    state: web::Data<AppState>,
    reader: Reader,
    model_id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *model_id).await?;
    models::get(&state.db, *model_id).await?;
    Ok(HttpResponse::Ok().json(parts::list_for_model(&state.db, *model_id).await?))
}

/// Create a part
///
/// Points need only a centre; regions also their original vertex ids. The creation is the
/// part's first revision, with the author and the optional comment.
#[utoipa::path(post, path = "/api/v1/models/{id}/parts", tag = "parts",
    params(("id" = i64, Path, description = "model id")),
    request_body = NewPart,
    responses((status = 201, description = "Created", body = Part)),
    security(("sessionCookie" = ["editor"])))]
async fn create(
    state: web::Data<AppState>,
    auth: Auth,
    model_id: web::Path<i64>,
    body: web::Json<NewPart>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let part = state.create_part(auth.id(), *model_id, &body).await?;
    Ok(HttpResponse::Created().json(part))
}

/// Get a part.
#[utoipa::path(get, path = "/api/v1/parts/{id}", tag = "parts",
    params(("id" = i64, Path, description = "part id")),
    responses((status = 200, description = "The part", body = Part)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn get(
    state: web::Data<AppState>,
    reader: Reader,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.part(&state.db, *id).await?;
    Ok(HttpResponse::Ok().json(parts::get(&state.db, *id).await?))
}

/// Change a part
///
/// Every change is a revision in the part's history (`/api/v1/parts/{id}/revisions`), with
/// the author and the optional comment.
#[utoipa::path(patch, path = "/api/v1/parts/{id}", tag = "parts",
    params(("id" = i64, Path, description = "part id")),
    request_body = PartPatch,
    responses((status = 200, description = "Updated", body = Part)),
    security(("sessionCookie" = ["editor"])))]
async fn update(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
    body: web::Json<PartPatch>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let part = state.edit_part(auth.id(), *id, &body).await?;
    Ok(HttpResponse::Ok().json(part))
}

/// Delete a part
///
/// Its assignments go; its contents stay, and its history keeps a `delete` revision.
#[utoipa::path(delete, path = "/api/v1/parts/{id}", tag = "parts",
    params(("id" = i64, Path, description = "part id")),
    responses((status = 204, description = "Deleted")),
    security(("sessionCookie" = ["editor"])))]
async fn delete(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    state.delete_part(auth.id(), *id, None).await?;
    Ok(HttpResponse::NoContent().finish())
}

/// The part's vertex set
///
/// A serialised `RoaringBitmap` (portable format) of original vertex ids.
#[utoipa::path(get, path = "/api/v1/parts/{id}/vertices", tag = "parts",
    params(("id" = i64, Path, description = "part id")),
    responses((status = 200, description = "The vertex set", body = super::openapi::Binary,
        content_type = "application/octet-stream")),
    security((), ("sessionCookie" = ["viewer"])))]
async fn vertices(
    state: web::Data<AppState>,
    reader: Reader,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.part(&state.db, *id).await?;
    let bytes = parts::vertices(&state.db, *id).await?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "application/octet-stream"))
        .body(bytes))
}
