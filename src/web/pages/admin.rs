//! `/admin/users`: user management (admins only).

use actix_web::http::StatusCode;
use actix_web::{HttpResponse, web};
use askama::Template;
use serde::Deserialize;

use super::filters;
use super::{Layout, redirect, render_status};
use crate::store::Page;
use crate::store::users::{self, Role, User, UserPatch};
use crate::web::auth::{CsrfForm, PageAuth, PageForm};
use crate::web::{AppState, PageError};

/// Mounts the pages.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        crate::web::resource("/admin/users")
            .route(web::get().to(list))
            .route(web::post().to(create)),
    )
    .service(crate::web::resource("/admin/users/{id}").route(web::post().to(update)));
}

#[derive(Template)]
#[template(path = "admin_users.html")]
struct UsersPage {
    layout: Layout,
    users: Vec<User>,
    roles: Vec<&'static str>,
    error: String,
}

async fn page(
    state: &AppState,
    auth: &PageAuth,
    status: StatusCode,
    error: String,
) -> Result<HttpResponse, PageError> {
    let users = users::list(&state.db, Page::new(Some(1000), None)).await?;
    render_status(
        status,
        &UsersPage {
            layout: Layout::new(auth, "Users"),
            users,
            roles: Role::ALL.iter().map(|r| r.as_str()).collect(),
            error,
        },
    )
}

async fn list(state: web::Data<AppState>, auth: PageAuth) -> Result<HttpResponse, PageError> {
    auth.require(Role::Admin)?;
    page(&state, &auth, StatusCode::OK, String::new()).await
}

#[derive(Debug, Deserialize)]
struct CreateForm {
    #[serde(default)]
    csrf_token: String,
    username: String,
    password: String,
    role: Role,
}

impl CsrfForm for CreateForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

async fn create(
    state: web::Data<AppState>,
    post: PageForm<CreateForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Admin)?;
    let f = &post.form;
    match users::create(
        &state.db,
        f.username.trim(),
        &f.password,
        f.role,
        Some(post.auth.id()),
    )
    .await
    {
        Ok(_) => Ok(redirect("/admin/users")),
        Err(e @ (crate::store::StoreError::Invalid(_) | crate::store::StoreError::Conflict(_))) => {
            page(&state, &post.auth, StatusCode::BAD_REQUEST, e.to_string()).await
        }
        Err(e) => Err(e.into()),
    }
}

#[derive(Debug, Deserialize)]
struct UpdateForm {
    #[serde(default)]
    csrf_token: String,
    role: Role,
    #[serde(default)]
    disabled: Option<String>,
    #[serde(default)]
    password: String,
}

impl CsrfForm for UpdateForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

async fn update(
    state: web::Data<AppState>,
    id: web::Path<i64>,
    post: PageForm<UpdateForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Admin)?;
    let f = &post.form;
    let patch = UserPatch {
        role: Some(f.role),
        disabled: Some(f.disabled.is_some()),
        password: (!f.password.is_empty()).then(|| f.password.clone()),
    };
    if let Err(e) = crate::web::users::guard_self(post.auth.id(), *id, &patch) {
        return page(&state, &post.auth, StatusCode::CONFLICT, e.to_string()).await;
    }
    match users::update(&state.db, *id, &patch, Some(post.auth.id())).await {
        Ok(_) => Ok(redirect("/admin/users")),
        Err(e @ crate::store::StoreError::Invalid(_)) => {
            page(&state, &post.auth, StatusCode::BAD_REQUEST, e.to_string()).await
        }
        Err(e) => Err(e.into()),
    }
}
