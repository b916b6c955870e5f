//! `/login` and `/logout`.

use actix_web::ResponseError as _;
use actix_web::{HttpRequest, HttpResponse, web};
use askama::Template;
use serde::Deserialize;

use super::{CsrfOnly, Layout, redirect, render, render_status};
use crate::store::sessions;
use crate::web::auth::{self, PageAuth, PageForm};
use crate::web::error::safe_next;
use crate::web::{ApiError, AppState, PageError};

/// Mounts the pages.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        crate::web::resource("/login")
            .route(web::get().to(login_page))
            .route(web::post().to(login)),
    )
    .service(
        crate::web::resource("/logout")
            .route(web::get().to(logout_page))
            .route(web::post().to(logout)),
    );
}

#[derive(Template)]
#[template(path = "login.html")]
struct LoginPage {
    layout: Layout,
    next: String,
    username: String,
    error: String,
}

#[derive(Debug, Deserialize)]
struct NextQuery {
    next: Option<String>,
}

async fn login_page(req: HttpRequest, q: web::Query<NextQuery>) -> Result<HttpResponse, PageError> {
    let next = safe_next(q.next.as_deref().unwrap_or("/models")).to_string();
    if auth::current_session(&req).await?.is_some() {
        return Ok(redirect(&next));
    }
    render(&LoginPage {
        layout: Layout::anonymous("Log in"),
        next,
        username: String::new(),
        error: String::new(),
    })
}

#[derive(Debug, Deserialize)]
struct LoginForm {
    username: String,
    password: String,
    #[serde(default)]
    next: String,
}

async fn login(
    req: HttpRequest,
    state: web::Data<AppState>,
    form: web::Form<LoginForm>,
) -> Result<HttpResponse, PageError> {
    auth::check_origin(&req)?;
    let next = safe_next(&form.next).to_string();
    let user = match auth::attempt_login(&req, &state, &form.username, &form.password).await {
        Ok(user) => user,
        Err(e @ (ApiError::BadCredentials | ApiError::TooManyRequests { .. })) => {
            let error = match e.retry_after() {
                Some(secs) => format!("Too many failed logins: try again in {secs} s."),
                None => "Invalid user name or password.".into(),
            };
            let mut resp = render_status(
                e.status_code(),
                &LoginPage {
                    layout: Layout::anonymous("Log in"),
                    next,
                    username: form.username.clone(),
                    error,
                },
            )?;
            if let Some(secs) = e.retry_after() {
                resp.headers_mut().insert(
                    actix_web::http::header::RETRY_AFTER,
                    actix_web::http::header::HeaderValue::from(secs),
                );
            }
            return Ok(resp);
        }
        Err(e) => return Err(e.into()),
    };
    let ttl = state.settings.limits.session_ttl_secs;
    let s = sessions::create(&state.db, user.id, ttl).await?;
    let mut resp = redirect(&next);
    resp.add_cookie(&auth::session_cookie(
        &s.token,
        ttl,
        state.settings.cookie_secure,
    ))
    .map_err(|e| PageError::Api(crate::web::ApiError::internal(e)))?;
    Ok(resp)
}

#[derive(Template)]
#[template(path = "logout.html")]
struct LogoutPage {
    layout: Layout,
}

async fn logout_page(auth: PageAuth) -> Result<HttpResponse, PageError> {
    render(&LogoutPage {
        layout: Layout::new(&auth, "Log out"),
    })
}

async fn logout(
    state: web::Data<AppState>,
    post: PageForm<CsrfOnly>,
) -> Result<HttpResponse, PageError> {
    sessions::delete(&state.db, post.auth.0.id, post.auth.id()).await?;
    let mut resp = redirect("/login");
    resp.add_cookie(&auth::removal_cookie(state.settings.cookie_secure))
        .map_err(|e| PageError::Api(crate::web::ApiError::internal(e)))?;
    Ok(resp)
}
