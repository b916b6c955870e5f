//! `/api/v1/users`: account management (admin only) and the audit log.

use actix_web::{HttpResponse, web};
use serde::Deserialize;
use utoipa::{IntoParams, ToSchema};

use super::auth::Auth;
use super::{ApiError, AppState, PageQuery};
use crate::store::audit::AuditEntry;
use crate::store::users::{self, Role, User, UserPatch};
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

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(list, create, get, update, disable, audit_log))]
pub(super) struct Api;

/// New account.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewUser {
    /// User name: 1–64 letters, digits, `.`, `_` or `-`.
    #[schema(min_length = 1, max_length = 64)]
    pub username: String,
    /// Password (8–1024 characters).
    #[schema(min_length = 8, max_length = 1024)]
    pub password: String,
    /// Role.
    pub role: Role,
}

/// List users
///
/// By user name.
#[utoipa::path(get, path = "/api/v1/users", tag = "users",
    params(PageQuery),
    responses((status = 200, description = "Users, by name", body = Vec<User>)),
    security(("sessionCookie" = ["admin"])))]
async fn list(
    state: web::Data<AppState>,
    auth: Auth,
    q: web::Query<PageQuery>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    Ok(HttpResponse::Ok().json(users::list(&state.db, q.page()).await?))
}

/// Create a user.
#[utoipa::path(post, path = "/api/v1/users", tag = "users",
    request_body = NewUser,
    responses(
        (status = 201, description = "Created", body = User),
        (status = 409, description = "User name taken", body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
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

/// Get a user.
#[utoipa::path(get, path = "/api/v1/users/{id}", tag = "users",
    params(("id" = i64, Path, description = "user id")),
    responses((status = 200, description = "The user", body = User)),
    security(("sessionCookie" = ["admin"])))]
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

/// Change a user's role, password or disabled flag
///
/// Changing the password or disabling the account ends the user's sessions. Admins cannot
/// disable or demote their own account.
#[utoipa::path(patch, path = "/api/v1/users/{id}", tag = "users",
    params(("id" = i64, Path, description = "user id")),
    request_body = PatchBody,
    responses(
        (status = 200, description = "Updated", body = User),
        (status = 409,
            description = "Would lock out the acting admin (own account disabled or demoted)",
            body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
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

/// Body of `PATCH /api/v1/users/{id}`: changes to a user; an absent field stays as it is.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(as = UserPatch)]
pub struct PatchBody {
    /// New role.
    pub role: Option<Role>,
    /// New password (8–1024 characters; ends the user's sessions).
    #[schema(min_length = 8, max_length = 1024)]
    pub password: Option<String>,
    /// Disable (true; ends the user's sessions) or re-enable (false).
    pub disabled: Option<bool>,
}

/// Disable a user
///
/// Accounts are never erased: their revisions keep their author. Disabling ends the user's
/// sessions; admins cannot disable their own account.
#[utoipa::path(delete, path = "/api/v1/users/{id}", tag = "users",
    params(("id" = i64, Path, description = "user id")),
    responses(
        (status = 200, description = "Disabled", body = User),
        (status = 409, description = "Would lock out the acting admin (own account)",
            body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["admin"])))]
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

/// Query of the audit log.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct AuditQuery {
    /// Entity kind, e.g. `content` (give `entity_id` too).
    entity: Option<String>,
    /// Entity id (give `entity` too).
    entity_id: Option<i64>,
    /// Rows to return (1–1000, default 100).
    limit: Option<i64>,
    /// Rows to skip.
    offset: Option<i64>,
}

/// Audit log
///
/// Who changed what, when: newest first, optionally only the entries of one entity.
#[utoipa::path(get, path = "/api/v1/audit", tag = "users",
    params(AuditQuery),
    responses((status = 200, description = "Entries, newest first", body = Vec<AuditEntry>)),
    security(("sessionCookie" = ["admin"])))]

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
