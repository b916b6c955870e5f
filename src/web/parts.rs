//! Parts (identified points and regions on a model): `/api/v1/models/{id}/parts`,
//! `/api/v1/parts/{id}` and the raw vertex set `/api/v1/parts/{id}/vertices`.

use actix_web::{HttpResponse, http::header, web};

use super::auth::Auth;
use super::{ApiError, AppState};
use crate::store::models;
use crate::store::parts::{self, NewPart, PartPatch};
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

async fn list(
    state: web::Data<AppState>,
    _auth: Auth,
    model_id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    models::get(&state.db, *model_id).await?;
    Ok(HttpResponse::Ok().json(parts::list_for_model(&state.db, *model_id).await?))
}

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

async fn get(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    Ok(HttpResponse::Ok().json(parts::get(&state.db, *id).await?))
}

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

async fn delete(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    state.delete_part(auth.id(), *id, None).await?;
    Ok(HttpResponse::NoContent().finish())
}

/// The part's vertex set as a serialised `RoaringBitmap` (portable format).
async fn vertices(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    let bytes = parts::vertices(&state.db, *id).await?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "application/octet-stream"))
        .body(bytes))
}
