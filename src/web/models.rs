//! `/api/v1/models`: scans. Anyone logged in reads; editors patch descriptive fields;
//! admins create and delete.

use std::path::{Component, Path};

use actix_web::{HttpResponse, web};

use super::auth::Auth;
use super::{ApiError, AppState, PageQuery};
use crate::Settings;
use crate::store::models::{self, ModelPatch, NewModel};
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

async fn list(
    state: web::Data<AppState>,
    _auth: Auth,
    q: web::Query<PageQuery>,
) -> Result<HttpResponse, ApiError> {
    Ok(HttpResponse::Ok().json(models::list(&state.db, q.page()).await?))
}

async fn create(
    state: web::Data<AppState>,
    auth: Auth,
    body: web::Json<NewModel>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let model = models::create(&state.db, &body, auth.id()).await?;
    Ok(HttpResponse::Created().json(model))
}

async fn get(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    Ok(HttpResponse::Ok().json(models::get(&state.db, *id).await?))
}

async fn update(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
    body: web::Json<ModelPatch>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let model = models::update(&state.db, *id, &body, auth.id()).await?;
    state.sync_search().await;
    Ok(HttpResponse::Ok().json(model))
}

async fn delete(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    // A build still running for this model stops (and leaves nothing behind).
    state.jobs.cancel_for_model(*id, Some(auth.id())).await?;
    let model = models::delete(&state.db, *id, auth.id()).await?;
    state.models.forget(model.id);
    state.sync_search().await;
    if let Some(lod) = &model.lod_path {
        remove_model_file(&state.settings, lod).await;
    }
    Ok(HttpResponse::NoContent().finish())
}

/// Removes a model's LOD file (or directory) if `relative` is a plain path inside
/// `models/` of the data directory; anything else is left alone.
pub async fn remove_model_file(settings: &Settings, relative: &str) {
    let rel = Path::new(relative);
    let plain = rel.components().all(|c| matches!(c, Component::Normal(_)));
    if !plain || !rel.starts_with("models") || rel.components().count() < 2 {
        tracing::warn!(path = relative, "not removing LOD path outside models/");
        return;
    }
    let path = settings.data_dir.join(rel);
    let result = match tokio::fs::metadata(&path).await {
        Ok(m) if m.is_dir() => tokio::fs::remove_dir_all(&path).await,
        Ok(_) => tokio::fs::remove_file(&path).await,
        Err(_) => Ok(()),
    };
    if let Err(e) = result {
        tracing::warn!(path = %path.display(), error = %e, "cannot remove LOD file");
    }
}
