//! `/api/v1/session`: log in (sets the session cookie, returns the CSRF token), who am I,
//! log out.

use actix_web::{HttpRequest, HttpResponse, web};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::auth::{self, Auth};
use super::{ApiError, AppState};
use crate::store::{sessions, users};

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        super::resource("/api/v1/session")
            .route(web::post().to(login))
            .route(web::get().to(whoami))
            .route(web::delete().to(logout)),
    );
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(login, whoami, logout))]
pub(super) struct Api;

/// Login request.
#[derive(Debug, Deserialize, ToSchema)]
pub struct LoginRequest {
    /// User name.
    pub username: String,
    /// Password.
    pub password: String,
}

/// The current session: its CSRF token, expiry and user.
#[derive(Debug, Serialize, ToSchema)]
pub struct SessionInfo {
    /// The session's CSRF token: send it in the `X-CSRF-Token` header of every
    /// state-changing request (POST, PUT, PATCH, DELETE).
    pub csrf_token: String,
    /// Expiry of the session, in Unix seconds.
    pub expires_at: i64,
    /// The logged-in user.
    pub user: users::User,
}

/// Log in
///
/// Sets the HttpOnly session cookie and returns the CSRF token. After repeated failures for
/// one account from one client address (or from one address over all accounts), attempts
/// are refused for a while (429, with `Retry-After`), right password or not.
#[utoipa::path(post, path = "/api/v1/session", tag = "session",
    request_body = LoginRequest,
    responses(
        (status = 200, description = "Logged in (the session cookie is set)", body = SessionInfo,
            headers(("Set-Cookie" = String, description = "The HttpOnly session cookie"))),
        (status = 401, description = "Wrong user name or password",
            body = super::openapi::ErrorBody),
        (status = 403,
            description = "Cross-origin request refused (the Origin header names another host)",
            body = super::openapi::ErrorBody),
        (status = 429, description = "Too many failed logins: try again later",
            body = super::openapi::ErrorBody,
            headers(("Retry-After" = u64,
                description = "Seconds until an attempt is heard again")))),
    security(()))]
async fn login(
    req: HttpRequest,
    state: web::Data<AppState>,
    body: web::Json<LoginRequest>,
) -> Result<HttpResponse, ApiError> {
    auth::check_origin(&req)?;
    let user = auth::attempt_login(&req, &state, &body.username, &body.password).await?;
    let ttl = state.settings.limits.session_ttl_secs;
    let s = sessions::create(&state.db, user.id, ttl).await?;
    Ok(HttpResponse::Ok()
        .cookie(auth::session_cookie(
            &s.token,
            ttl,
            state.settings.cookie_secure,
        ))
        .insert_header(("Cache-Control", "no-store"))
        .json(SessionInfo {
            csrf_token: s.csrf_token,
            expires_at: s.expires_at,
            user,
        }))
}

/// The current session and user.
#[utoipa::path(get, path = "/api/v1/session", tag = "session",
    responses((status = 200, description = "The session", body = SessionInfo)),
    security(("sessionCookie" = ["viewer"])))]
async fn whoami(auth: Auth) -> HttpResponse {
    let session = auth.0;
    HttpResponse::Ok()
        .insert_header(("Cache-Control", "no-store"))
        .json(SessionInfo {
            csrf_token: session.csrf_token,
            expires_at: session.expires_at,
            user: session.user,
        })
}

/// Log out
///
/// Ends the session and removes its cookie.
#[utoipa::path(delete, path = "/api/v1/session", tag = "session",
    responses((status = 204, description = "Logged out")),
    security(("sessionCookie" = ["viewer"])))]
async fn logout(state: web::Data<AppState>, auth: Auth) -> Result<HttpResponse, ApiError> {
    sessions::delete(&state.db, auth.0.id, auth.id()).await?;
    Ok(HttpResponse::NoContent()
        .cookie(auth::removal_cookie(state.settings.cookie_secure))
        .finish())
}
