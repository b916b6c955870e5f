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
    /// What the last change did, said after its redirect.
    notice: String,
}

/// The users page's query after a change: what was done to which user.
#[derive(Debug, Default, Deserialize)]
struct Done {
    /// `created` or `updated`.
    done: Option<String>,
    /// The user.
    user: Option<i64>,
}

impl Done {
    /// The notice about it, from the user as now stored.
    fn notice(&self, users: &[User]) -> String {
        let Some(u) = self.user.and_then(|id| users.iter().find(|u| u.id == id)) else {
            return String::new();
        };
        let state = if u.disabled { ", disabled" } else { "" };
        match self.done.as_deref() {
            Some("created") => format!("User {} was created, role {}.", u.username, u.role),
            Some("updated") => format!("User {} was saved: role {}{state}.", u.username, u.role),
            _ => String::new(),
        }
    }
}

async fn page(
    state: &AppState,
    auth: &PageAuth,
    status: StatusCode,
    error: String,
    done: &Done,
) -> Result<HttpResponse, PageError> {
    let users = users::list(&state.db, Page::new(Some(1000), None)).await?;
    render_status(
        status,
        &UsersPage {
            layout: Layout::new(auth, "Users"),
            notice: done.notice(&users),
            users,
            roles: Role::ALL.iter().map(|r| r.as_str()).collect(),
            error,
        },
    )
}

async fn list(
    state: web::Data<AppState>,
    auth: PageAuth,
    done: web::Query<Done>,
) -> Result<HttpResponse, PageError> {
    auth.require(Role::Admin)?;
    page(&state, &auth, StatusCode::OK, String::new(), &done).await
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
        Ok(u) => Ok(redirect(&format!(
            "/admin/users?done=created&user={}",
            u.id
        ))),
        Err(e @ (crate::store::StoreError::Invalid(_) | crate::store::StoreError::Conflict(_))) => {
            page(
                &state,
                &post.auth,
                StatusCode::BAD_REQUEST,
                e.to_string(),
                &Done::default(),
            )
            .await
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
        return page(
            &state,
            &post.auth,
            StatusCode::CONFLICT,
            e.to_string(),
            &Done::default(),
        )
        .await;
    }
    match users::update(&state.db, *id, &patch, Some(post.auth.id())).await {
        Ok(_) => Ok(redirect(&format!("/admin/users?done=updated&user={}", *id))),
        Err(e @ crate::store::StoreError::Invalid(_)) => {
            page(
                &state,
                &post.auth,
                StatusCode::BAD_REQUEST,
                e.to_string(),
                &Done::default(),
            )
            .await
        }
        Err(e) => Err(e.into()),
    }
}
