//! Server-rendered pages (askama templates in `templates/`), readable without JavaScript.
//! Every form post carries the session's CSRF token in a hidden `csrf_token` field.

pub mod account;
pub mod admin;
pub mod contents;
pub mod jobs;
pub mod models;
pub mod search;

use actix_web::http::StatusCode;
use actix_web::http::header::{self, ContentType};
use actix_web::{HttpResponse, web};
use askama::Template;
use serde::Deserialize;

use super::PageError;
use super::auth::{CsrfForm, PageAuth};
use crate::store::users::Role;

/// The logged-in user as the layout shows it.
#[derive(Debug, Clone)]
pub struct UserInfo {
    /// Id.
    pub id: i64,
    /// User name.
    pub username: String,
    /// Role name.
    pub role: String,
    /// Admin?
    pub is_admin: bool,
    /// Editor or admin?
    pub can_edit: bool,
}

/// What the base layout needs.
#[derive(Debug, Clone)]
pub struct Layout {
    /// Page title.
    pub title: String,
    /// Logged-in user.
    pub user: Option<UserInfo>,
    /// CSRF token for forms.
    pub csrf: String,
}

impl Layout {
    /// Layout for a logged-in page.
    pub fn new(auth: &PageAuth, title: impl Into<String>) -> Layout {
        let u = auth.user();
        Layout {
            title: title.into(),
            user: Some(UserInfo {
                id: u.id,
                username: u.username.clone(),
                role: u.role.to_string(),
                is_admin: u.role >= Role::Admin,
                can_edit: u.role >= Role::Editor,
            }),
            csrf: auth.csrf().to_string(),
        }
    }

    /// Layout for a page without a session.
    pub fn anonymous(title: impl Into<String>) -> Layout {
        Layout {
            title: title.into(),
            user: None,
            csrf: String::new(),
        }
    }

    /// Whether the user may edit.
    pub fn can_edit(&self) -> bool {
        self.user.as_ref().is_some_and(|u| u.can_edit)
    }
}

/// A form with only the CSRF field.
#[derive(Debug, Deserialize)]
pub struct CsrfOnly {
    /// CSRF token.
    #[serde(default)]
    pub csrf_token: String,
}

impl CsrfForm for CsrfOnly {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

/// Renders a template as a 200 HTML response.
pub fn render<T: Template>(t: &T) -> Result<HttpResponse, PageError> {
    render_status(StatusCode::OK, t)
}

/// Renders a template as an HTML response with `status`.
pub fn render_status<T: Template>(status: StatusCode, t: &T) -> Result<HttpResponse, PageError> {
    Ok(HttpResponse::build(status)
        .content_type(ContentType::html())
        .body(t.render()?))
}

/// 303 See Other to `to`.
pub fn redirect(to: &str) -> HttpResponse {
    HttpResponse::SeeOther()
        .insert_header((header::LOCATION, to.to_string()))
        .finish()
}

/// Normalises form text: CRLF → LF.
pub fn lf(s: &str) -> String {
    s.replace("\r\n", "\n")
}

async fn home() -> HttpResponse {
    redirect("/models")
}

/// Mounts every page.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/").route(web::get().to(home)));
    account::configure(cfg);
    models::configure(cfg);
    contents::configure(cfg);
    search::configure(cfg);
    admin::configure(cfg);
    jobs::configure(cfg);
}
