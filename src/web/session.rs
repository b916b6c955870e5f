//! `/api/v1/session`: log in (sets the session cookie, returns the CSRF token), who am I,
//! log out.

use actix_web::{HttpRequest, HttpResponse, web};
use serde::{Deserialize, Serialize};

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

/// Login request.
#[derive(Debug, Deserialize)]
pub struct LoginRequest {
    /// User name.
    pub username: String,
    /// Password.
    pub password: String,
}

#[derive(Serialize)]
struct SessionInfo<'a> {
    csrf_token: &'a str,
    expires_at: i64,
    user: &'a users::User,
}

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
            csrf_token: &s.csrf_token,
            expires_at: s.expires_at,
            user: &user,
        }))
}

async fn whoami(auth: Auth) -> HttpResponse {
    HttpResponse::Ok()
        .insert_header(("Cache-Control", "no-store"))
        .json(SessionInfo {
            csrf_token: &auth.0.csrf_token,
            expires_at: auth.0.expires_at,
            user: &auth.0.user,
        })
}

async fn logout(state: web::Data<AppState>, auth: Auth) -> Result<HttpResponse, ApiError> {
    sessions::delete(&state.db, auth.0.id, auth.id()).await?;
    Ok(HttpResponse::NoContent()
        .cookie(auth::removal_cookie(state.settings.cookie_secure))
        .finish())
}
