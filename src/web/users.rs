//! `/api/v1/users`: account management (admin only) and the audit log.

use actix_web::{HttpResponse, web};
use serde::Deserialize;

use super::auth::Auth;
use super::{ApiError, AppState, PageQuery};
use crate::store::users::{self, Role, UserPatch};
use crate::store::{Page, audit};

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        super::resource("/api/v1/users")
            .route(web::get().to(list))
            .route(web::post().to(create)),
    )
    .service(
        super::resource("/api/v1/users/{id}")
            .route(web::get().to(get))
            .route(web::patch().to(update))
            .route(web::delete().to(disable)),
    )
    .service(super::resource("/api/v1/audit").route(web::get().to(audit_log)));
}

/// New account.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NewUser {
    /// User name.
    pub username: String,
    /// Password (8–1024 characters).
    pub password: String,
    /// Role.
    pub role: Role,
}

async fn list(
    state: web::Data<AppState>,
    auth: Auth,
    q: web::Query<PageQuery>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    Ok(HttpResponse::Ok().json(users::list(&state.db, q.page()).await?))
}

async fn create(
    state: web::Data<AppState>,
    auth: Auth,
    body: web::Json<NewUser>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let user = users::create(
        &state.db,
        &body.username,
        &body.password,
        body.role,
        Some(auth.id()),
    )
    .await?;
    Ok(HttpResponse::Created().json(user))
}

async fn get(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    Ok(HttpResponse::Ok().json(users::get(&state.db, *id).await?))
}

/// Refuses changes that would lock the acting admin out.
pub fn guard_self(actor: i64, target: i64, patch: &UserPatch) -> Result<(), ApiError> {
    if actor == target
        && (patch.disabled == Some(true) || patch.role.is_some_and(|r| r != Role::Admin))
    {
        return Err(ApiError::Conflict(
            "you cannot disable or demote your own account".into(),
        ));
    }
    Ok(())
}

async fn update(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
    body: web::Json<PatchBody>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let patch = UserPatch {
        role: body.role,
        password: body.password.clone(),
        disabled: body.disabled,
    };
    guard_self(auth.id(), *id, &patch)?;
    Ok(HttpResponse::Ok().json(users::update(&state.db, *id, &patch, Some(auth.id())).await?))
}

/// Body of `PATCH /api/v1/users/{id}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatchBody {
    /// New role.
    pub role: Option<Role>,
    /// New password.
    pub password: Option<String>,
    /// Disable / re-enable.
    pub disabled: Option<bool>,
}

async fn disable(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let patch = UserPatch {
        disabled: Some(true),
        ..Default::default()
    };
    guard_self(auth.id(), *id, &patch)?;
    Ok(HttpResponse::Ok().json(users::update(&state.db, *id, &patch, Some(auth.id())).await?))
}

#[derive(Debug, Deserialize)]
struct AuditQuery {
    entity: Option<String>,
    entity_id: Option<i64>,
    limit: Option<i64>,
    offset: Option<i64>,
}

async fn audit_log(
    state: web::Data<AppState>,
    auth: Auth,
    q: web::Query<AuditQuery>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    let entity = match (&q.entity, q.entity_id) {
        (Some(e), Some(id)) => Some((e.as_str(), id)),
        (None, None) => None,
        _ => return Err(ApiError::bad("give both entity and entity_id, or neither")),
    };
    let page = Page::new(q.limit, q.offset);
    Ok(HttpResponse::Ok().json(audit::list(&state.db, entity, page).await?))
}
