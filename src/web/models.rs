//! `/api/v1/models`: scans. Anyone logged in reads; editors patch descriptive fields;
//! admins create and delete.

use actix_web::{HttpResponse, web};

use super::auth::{Auth, Reader};
use super::{ApiError, AppState, PageQuery};
use crate::store::models::{self, Model, ModelPatch, NewModel};
use crate::store::users::Role;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        super::resource("/api/v1/models")
            .route(web::get().to(list))
            .route(web::post().to(create)),
    )
    .service(
        super::resource("/api/v1/models/{id}")
            .route(web::get().to(get))
            .route(web::patch().to(update))
            .route(web::delete().to(delete)),
    );
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(list, create, get, update, delete))]
pub(super) struct Api;

/// List models
///
/// Newest first.
#[utoipa::path(get, path = "/api/v1/models", tag = "models",
    params(super::PageQuery),
    responses((status = 200, description = "Models, newest first", body = Vec<Model>)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn list(
    state: web::Data<AppState>,
    reader: Reader,
    q: web::Query<PageQuery>,
) -> Result<HttpResponse, ApiError> {
    // Anonymous visitors see the public models only (and, with none, must log in).
    let list = if reader.is_anonymous() {
        if crate::store::visibility::public_models(&state.db)
            .await?
            .is_empty()
        {
            return Err(ApiError::Unauthorized);
        }
        models::list_public(&state.db, q.page()).await?
    } else {
        models::list(&state.db, q.page()).await?
    };
    Ok(HttpResponse::Ok().json(list))
}

/// Create an empty model record
///
/// The model starts with status `pending` and no geometry; scans are uploaded with
/// `POST /api/v1/models/upload`, which creates the model and its build job together.
#[utoipa::path(post, path = "/api/v1/models", tag = "models",
    request_body = NewModel,
    responses((status = 201, description = "Created", body = Model)),
    security(("sessionCookie" = ["admin"])))]
async fn create(
    state: web::Data<AppState>,
    auth: Auth,
    body: web::Json<NewModel>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let model = models::create(&state.db, &body, auth.id()).await?;
    Ok(HttpResponse::Created().json(model))
}

/// Get a model.
#[utoipa::path(get, path = "/api/v1/models/{id}", tag = "models",
    params(("id" = i64, Path, description = "model id")),
    responses((status = 200, description = "The model", body = Model)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn get(
    state: web::Data<AppState>,
    reader: Reader,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *id).await?;
    Ok(HttpResponse::Ok().json(models::get(&state.db, *id).await?))
}

/// Change a model's title, description, thumbnail or access
///
/// A new title re-indexes, for search, every content assigned to the model's parts. `public`
/// and `geometry_access` are admins' to change (403 otherwise).
#[utoipa::path(patch, path = "/api/v1/models/{id}", tag = "models",
    params(("id" = i64, Path, description = "model id")),
    request_body = ModelPatch,
    responses((status = 200, description = "Updated", body = Model)),
    security(("sessionCookie" = ["editor"])))]
async fn update(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
    body: web::Json<ModelPatch>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    if body.public.is_some() || body.geometry_access.is_some() {
        // Opening a model to anonymous visitors, or its geometry to viewers, is an admin's
        // decision.
        auth.require(Role::Admin)?;
    }
    let model = models::update(&state.db, *id, &body, auth.id()).await?;
    state.sync_search().await;
    Ok(HttpResponse::Ok().json(model))
}

/// Delete a model
///
/// Its parts and their assignments go with it (contents stay), a build still running for it
/// stops, and its LOD file is removed.
#[utoipa::path(delete, path = "/api/v1/models/{id}", tag = "models",
    params(("id" = i64, Path, description = "model id")),
    responses((status = 204, description = "Deleted")),
    security(("sessionCookie" = ["admin"])))]
async fn delete(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    state.delete_model(auth.id(), *id).await?;
    Ok(HttpResponse::NoContent().finish())
}
