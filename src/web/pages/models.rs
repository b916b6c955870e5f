//! `/models` (list, admin create) and `/models/{id}` (model page: viewer placeholder, parts
//! and the contents assigned to them, assignment forms for editors).

use actix_web::{HttpResponse, web};
use askama::Template;
use serde::Deserialize;

use super::{Layout, redirect, render};
use crate::store::assignments::{self, AssignedContent};
use crate::store::models::{self, Model, NewModel};
use crate::store::parts::{self, Part};
use crate::store::users::Role;
use crate::store::{Page, contents};
use crate::web::auth::{CsrfForm, PageAuth, PageForm};
use crate::web::{AppState, PageError};
use crate::wiki::markdown;

/// Mounts the pages.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        crate::web::resource("/models")
            .route(web::get().to(list))
            .route(web::post().to(create)),
    )
    .service(crate::web::resource("/models/{id}").route(web::get().to(show)))
    .service(crate::web::resource("/parts/{id}/contents").route(web::post().to(assign)))
    .service(
        crate::web::resource("/parts/{id}/contents/{content_id}/remove")
            .route(web::post().to(unassign)),
    );
}

#[derive(Template)]
#[template(path = "models.html")]
struct ModelsPage {
    layout: Layout,
    models: Vec<Model>,
}

async fn list(state: web::Data<AppState>, auth: PageAuth) -> Result<HttpResponse, PageError> {
    let models = models::list(&state.db, Page::new(Some(1000), None)).await?;
    render(&ModelsPage {
        layout: Layout::new(&auth, "Models"),
        models,
    })
}

#[derive(Debug, Deserialize)]
struct CreateForm {
    #[serde(default)]
    csrf_token: String,
    title: String,
    #[serde(default)]
    description: String,
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
    let new = NewModel {
        title: post.form.title.clone(),
        description: super::lf(&post.form.description),
        source_name: String::new(),
    };
    let model = models::create(&state.db, &new, post.auth.id()).await?;
    Ok(redirect(&format!("/models/{}", model.id)))
}

#[derive(serde::Serialize)]
struct PartView {
    #[serde(flatten)]
    part: Part,
    #[serde(skip)]
    center: String,
    contents: Vec<AssignedContent>,
}

/// JSON embedded in the model page for the viewer (no extra round trips at start-up).
/// Escaped so that it cannot close its `<script type="application/json">` element.
fn viewer_json(
    model: &Model,
    parts: &[PartView],
    can_edit: bool,
    config: &crate::app::client::ClientConfig,
) -> String {
    let json = serde_json::json!({
        "model": model,
        "parts": parts,
        "can_edit": can_edit,
        // The server's limits, as GET /api/v1/config gives them (selection masks must fit
        // its largest view).
        "config": config,
    })
    .to_string();
    json.replace('<', "\\u003c")
        .replace('>', "\\u003e")
        .replace('&', "\\u0026")
}

#[derive(Template)]
#[template(path = "model.html")]
struct ModelPage {
    layout: Layout,
    model: Model,
    description_html: String,
    bbox: String,
    parts: Vec<PartView>,
    can_edit: bool,
    /// The viewer's scripts are included (dependencies installed, model ready).
    viewer_enabled: bool,
    /// What the viewer's place says when it is not running.
    viewer_message: String,
    /// Import map of the viewer's modules.
    import_map: &'static str,
    /// [`viewer_json`].
    viewer_data: String,
    /// The model's latest build job (progress while it runs).
    build_job: Option<super::jobs::JobView>,
}

fn fmt3(v: &[f64; 3]) -> String {
    format!("({:.3}, {:.3}, {:.3})", v[0], v[1], v[2])
}

async fn show(
    state: web::Data<AppState>,
    auth: PageAuth,
    id: web::Path<i64>,
) -> Result<HttpResponse, PageError> {
    let model = models::get(&state.db, *id).await?;
    let mut views = Vec::new();
    for part in parts::list_for_model(&state.db, model.id).await? {
        let contents = assignments::contents_for_part(&state.db, part.id).await?;
        views.push(PartView {
            center: fmt3(&part.center),
            part,
            contents,
        });
    }
    let bbox = model
        .bbox
        .map(|b| format!("{} – {}", fmt3(&b.min), fmt3(&b.max)))
        .unwrap_or_else(|| "unknown".into());
    let build_job = crate::store::jobs::latest_for_model(&state.db, model.id)
        .await?
        .map(super::jobs::JobView::new);
    let layout = Layout::new(&auth, model.title.clone());
    let can_edit = layout.can_edit();
    let ready = model.status == models::ModelStatus::Ready;
    let viewer_message = if !crate::web::vendor::available() {
        "The 3D viewer is unavailable on this server: its front-end dependencies are not \
         installed (npm ci --prefix static)."
            .to_string()
    } else if !ready {
        format!(
            "The 3D view of \u{201c}{}\u{201d} appears once the scan is imported (status: {}).",
            model.title,
            model.status.as_str()
        )
    } else {
        format!(
            "Loading the 3D view of \u{201c}{}\u{201d}\u{2026}",
            model.title
        )
    };
    render(&ModelPage {
        build_job,
        can_edit,
        viewer_enabled: ready && crate::web::vendor::available(),
        viewer_message,
        import_map: crate::web::vendor::IMPORT_MAP,
        viewer_data: viewer_json(&model, &views, can_edit, &state.client_config()),
        layout,
        description_html: markdown::render(&model.description),
        bbox,
        parts: views,
        model,
    })
}

#[derive(Debug, Deserialize)]
struct AssignForm {
    #[serde(default)]
    csrf_token: String,
    content_id: String,
}

impl CsrfForm for AssignForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

async fn assign(
    state: web::Data<AppState>,
    part_id: web::Path<i64>,
    post: PageForm<AssignForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Editor)?;
    let content_id: i64 = post
        .form
        .content_id
        .trim()
        .trim_start_matches('#')
        .parse()
        .map_err(|_| crate::web::ApiError::bad("content id must be a number"))?;
    contents::get(&state.db, content_id).await?;
    let part = parts::get(&state.db, *part_id).await?;
    assignments::assign(&state.db, part.id, content_id, None, post.auth.id()).await?;
    state.sync_search().await;
    crate::web::assignments::publish_part_contents(&state, part.id).await;
    Ok(redirect(&format!(
        "/models/{}#part-{}",
        part.model_id, part.id
    )))
}

async fn unassign(
    state: web::Data<AppState>,
    path: web::Path<(i64, i64)>,
    post: PageForm<super::CsrfOnly>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Editor)?;
    let (part_id, content_id) = path.into_inner();
    let part = parts::get(&state.db, part_id).await?;
    assignments::unassign(&state.db, part_id, content_id, post.auth.id()).await?;
    state.sync_search().await;
    crate::web::assignments::publish_part_contents(&state, part.id).await;
    Ok(redirect(&format!(
        "/models/{}#part-{}",
        part.model_id, part.id
    )))
}
