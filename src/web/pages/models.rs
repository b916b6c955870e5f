//! `/models` (list, admin create) and `/models/{id}` (model page: viewer placeholder, parts
//! and the contents assigned to them, assignment forms for editors). The assignment form takes
//! a content's title (or `#id`); a script turns it into a search picker, and without it the
//! server finds the content by title, or sends the editor back to the part with a message and
//! the matching contents to pick from.

use actix_web::{HttpResponse, web};
use askama::Template;
use serde::Deserialize;

use super::filters;
use super::{Layout, redirect, render};
use meshwiki_engine::camera::Camera;

use crate::app::lumigraph::{GeometryGrant, LumigraphDescription};
use crate::app::models::Purpose;
use crate::search::SearchHit;
use crate::store::assignments::{self, AssignedContent};
use crate::store::models::{self, Model, NewModel};
use crate::store::parts::{self, Part};
use crate::store::users::Role;
use crate::store::{Page, StoreError, contents};
use crate::web::auth::{CsrfForm, PageForm, PageReader};
use crate::web::error::encode_component;
use crate::web::search::{SearchQuery, run};
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
    .service(crate::web::resource("/models/{id}/public").route(web::post().to(set_public)))
    .service(crate::web::resource("/models/{id}/lumigraph").route(web::post().to(build_lumigraph)))
    .service(crate::web::resource("/models/{id}/edit").route(web::post().to(edit)))
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
    models: Vec<ModelRow>,
}

/// A model as the list shows it.
struct ModelRow {
    model: Model,
    /// Its status in words: `cancelled` for a model whose latest build was cancelled (its
    /// status is `failed`), else the status.
    status: &'static str,
}

async fn list(state: web::Data<AppState>, reader: PageReader) -> Result<HttpResponse, PageError> {
    let page = Page::new(Some(1000), None);
    let (layout, models) = match &reader.auth {
        Some(auth) => (
            Layout::new(auth, "Models"),
            models::list(&state.db, page).await?,
        ),
        // Anonymous visitors see the public models; with none, the login page.
        None => {
            let public = models::list_public(&state.db, page).await?;
            reader.allow(!public.is_empty())?;
            (Layout::anonymous("Models"), public)
        }
    };
    let cancelled = crate::store::jobs::cancelled_models(&state.db).await?;
    let models = models
        .into_iter()
        .map(|model| ModelRow {
            status: status_words(&model, cancelled.contains(&model.id)),
            model,
        })
        .collect();
    render(&ModelsPage { layout, models })
}

/// A model's status as the pages say it: `cancelled` for a failed model whose latest build was
/// cancelled, else its status.
fn status_words(model: &Model, latest_cancelled: bool) -> &'static str {
    if model.status == models::ModelStatus::Failed && latest_cancelled {
        "cancelled"
    } else {
        model.status.as_str()
    }
}

/// The title and description form of the model page (editors).
#[derive(Debug, Deserialize)]
struct EditModelForm {
    #[serde(default)]
    csrf_token: String,
    title: String,
    #[serde(default)]
    description: String,
}

impl CsrfForm for EditModelForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

async fn edit(
    state: web::Data<AppState>,
    id: web::Path<i64>,
    post: PageForm<EditModelForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Editor)?;
    let patch = models::ModelPatch {
        title: Some(post.form.title.clone()),
        description: Some(post.form.description.replace("\r\n", "\n")),
        ..Default::default()
    };
    models::update(&state.db, *id, &patch, post.auth.id()).await?;
    // A new title is searchable in the contents on the model's parts.
    state.sync_search().await;
    Ok(redirect(&format!("/models/{}", *id)))
}

/// The public-access form of the model page (admins).
#[derive(Debug, Deserialize)]
struct PublicForm {
    #[serde(default)]
    csrf_token: String,
    /// Checked: anonymous visitors may view the model.
    #[serde(default)]
    public: Option<String>,
    /// Checked: the geometry stays on the server (`geometry_access` = `sparse`).
    #[serde(default)]
    sparse: Option<String>,
}

impl CsrfForm for PublicForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

async fn set_public(
    state: web::Data<AppState>,
    id: web::Path<i64>,
    post: PageForm<PublicForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Admin)?;
    let patch = models::ModelPatch {
        public: Some(post.form.public.is_some()),
        geometry_access: Some(if post.form.sparse.is_some() {
            models::GeometryAccess::Sparse
        } else {
            models::GeometryAccess::Full
        }),
        ..Default::default()
    };
    models::update(&state.db, *id, &patch, post.auth.id()).await?;
    Ok(redirect(&format!("/models/{}", *id)))
}

/// The image repository form of the model page (admins).
#[derive(Debug, Deserialize)]
struct LumigraphForm {
    #[serde(default)]
    csrf_token: String,
    /// Grid points per axis.
    grid: Option<u32>,
    /// Image side.
    size: Option<u32>,
}

impl CsrfForm for LumigraphForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

/// Builds (or rebuilds) the model's image repository; the page shows the job's progress.
async fn build_lumigraph(
    state: web::Data<AppState>,
    id: web::Path<i64>,
    post: PageForm<LumigraphForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Admin)?;
    let f = &post.form;
    state
        .start_lumigraph(post.auth.user(), *id, f.grid, f.size)
        .await?;
    Ok(redirect(&format!("/models/{}", *id)))
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
    home: Option<&Camera>,
    geometry: Option<GeometryGrant>,
) -> String {
    let json = serde_json::json!({
        "model": model,
        "parts": parts,
        "can_edit": can_edit,
        // What of the geometry this reader may stream: everything, or (a model that keeps its
        // geometry on the server) the sparse mesh, which the viewer then shades image-based.
        "geometry": match geometry {
            Some(GeometryGrant::Sparse(e)) => serde_json::json!({"full": false, "sparse_error": e}),
            _ => serde_json::json!({"full": true}),
        },
        // The first view: the side the model's thumbnail shows (the viewer frames it to its own
        // canvas).
        "home": home.map(|c| serde_json::json!({
            "eye": c.eye.to_array(),
            "target": c.target.to_array(),
            "up": c.up.to_array(),
            "fovy": c.fovy_deg,
        })),
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
    /// The status in words (`cancelled` when the latest build was).
    status: &'static str,
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
    /// What became of an assignment form that could not be carried out.
    assign_notice: Option<AssignNotice>,
    /// The image repository (admins, ready models).
    lumigraph: Option<LumigraphDescription>,
}

/// The model page's query: the outcome of an assignment form sent back to its part
/// (`?assign_part=&assign_error=&assign_q=`); other parameters (the viewer's `part`, `q`) are
/// the viewer's.
#[derive(Debug, Default, Deserialize)]
struct ShowQuery {
    #[serde(default)]
    assign_part: String,
    #[serde(default)]
    assign_error: String,
    #[serde(default)]
    assign_q: String,
}

/// Why an assignment form of the model page was sent back, shown by its part's form.
struct AssignNotice {
    part_id: i64,
    message: String,
    /// What the editor typed (the form keeps it).
    query: String,
    /// Contents matching it, to pick one (several matches, no exact title).
    candidates: Vec<SearchHit>,
}

/// Longest text the assignment form searches for.
const ASSIGN_QUERY_CHARS: usize = 200;
/// Contents the assignment form offers when a title matches several.
const ASSIGN_CANDIDATES: usize = 10;

/// Contents matching the assignment form's text, best first.
async fn assign_candidates(state: &AppState, text: &str) -> Result<Vec<SearchHit>, PageError> {
    Ok(run(
        state,
        &SearchQuery {
            q: text.to_string(),
            model: None,
            limit: Some(ASSIGN_CANDIDATES),
            offset: None,
        },
        None,
    )
    .await?
    .hits)
}

impl AssignNotice {
    /// The notice of the model page's query; `assigned(part)`: the contents part `part` already
    /// shows (never offered again).
    async fn from_query(
        state: &AppState,
        q: &ShowQuery,
        assigned: impl Fn(i64) -> Vec<i64>,
    ) -> Result<Option<Self>, PageError> {
        let Ok(part_id) = q.assign_part.trim().parse::<i64>() else {
            return Ok(None);
        };
        let query: String = q.assign_q.trim().chars().take(ASSIGN_QUERY_CHARS).collect();
        let quoted = format!("\u{201c}{query}\u{201d}");
        let mut candidates = Vec::new();
        let message = match q.assign_error.as_str() {
            "empty" => {
                "Type the title of a content, or its number such as #12, to assign it.".into()
            }
            "missing" => format!(
                "There is no content {quoted}. Type its title to find it, or check the number."
            ),
            "already" => format!("{quoted} is already assigned to this part."),
            "choose" | "none" => {
                let hits = if query.is_empty() {
                    Vec::new()
                } else {
                    assign_candidates(state, &query).await?
                };
                let found = hits.len();
                let skip = assigned(part_id);
                candidates = hits.into_iter().filter(|h| !skip.contains(&h.id)).collect();
                if found == 0 {
                    format!(
                        "No content matches {quoted}. Check the spelling, or create the content \
                         first (Contents \u{203a} New content)."
                    )
                } else if candidates.is_empty() {
                    format!("Every content matching {quoted} is already assigned to this part.")
                } else if candidates.len() == 1 {
                    format!("No content is titled {quoted}; did you mean this one?")
                } else {
                    format!("Several contents match {quoted}: pick one.")
                }
            }
            _ => return Ok(None),
        };
        Ok(Some(AssignNotice {
            part_id,
            message,
            query,
            candidates,
        }))
    }
}

fn fmt3(v: &[f64; 3]) -> String {
    format!("({:.3}, {:.3}, {:.3})", v[0], v[1], v[2])
}

async fn show(
    state: web::Data<AppState>,
    reader: PageReader,
    id: web::Path<i64>,
    query: web::Query<ShowQuery>,
) -> Result<HttpResponse, PageError> {
    if reader.auth.is_none() {
        reader.allow(crate::store::visibility::model(&state.db, *id).await?)?;
    }
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
    let (layout, build_job) = match &reader.auth {
        Some(auth) => (
            Layout::new(auth, model.title.clone()),
            crate::store::jobs::latest_for_model(&state.db, model.id)
                .await?
                .map(super::jobs::JobView::new),
        ),
        None => (Layout::anonymous(model.title.clone()), None),
    };
    let can_edit = layout.can_edit();
    let assign_notice = if can_edit {
        AssignNotice::from_query(&state, &query, |part| {
            views
                .iter()
                .filter(|v| v.part.id == part)
                .flat_map(|v| v.contents.iter().map(|c| c.id))
                .collect()
        })
        .await?
    } else {
        None
    };
    let ready = model.status == models::ModelStatus::Ready;
    let home = if ready {
        state
            .models
            .open(&state.db, model.id, Purpose::Serve)
            .await
            .ok()
            .map(|open| crate::jobs::thumbnail::camera(&open.lod))
    } else {
        None
    };
    let is_admin = layout.user.as_ref().is_some_and(|u| u.is_admin);
    let lumigraph = if ready && is_admin {
        state.lumigraph(model.id).await.ok()
    } else {
        None
    };
    let geometry = if ready {
        let user = reader.auth.as_ref().map(|a| a.user());
        state.geometry_grant(user, model.id).await.ok()
    } else {
        None
    };
    let status = status_words(
        &model,
        build_job
            .as_ref()
            .is_some_and(|j| j.job.status == crate::store::jobs::JobStatus::Cancelled),
    );
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
        status,
        assign_notice,
        build_job,
        can_edit,
        viewer_enabled: ready && crate::web::vendor::available(),
        viewer_message,
        import_map: crate::web::vendor::IMPORT_MAP,
        viewer_data: viewer_json(
            &model,
            &views,
            can_edit,
            &state.client_config(),
            home.as_ref(),
            geometry,
        ),
        lumigraph,
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
    /// The content picked (the picker's choice, or a button of the list of matches); a number,
    /// `#` allowed.
    #[serde(default)]
    content_id: String,
    /// What the editor typed: a content's title (or words of it), or its number (`#12`).
    #[serde(default)]
    content: String,
}

impl CsrfForm for AssignForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

/// A content number as typed: `12` or `#12`.
fn content_number(text: &str) -> Option<i64> {
    let t = text.trim();
    let t = t.strip_prefix('#').unwrap_or(t).trim();
    (!t.is_empty() && t.bytes().all(|b| b.is_ascii_digit()))
        .then(|| t.parse().ok())
        .flatten()
}

/// The content an assignment form names, or the reason it names none (`assign_error`).
enum Named {
    Content(i64),
    Refused(&'static str),
}

async fn named_content(state: &AppState, form: &AssignForm) -> Result<Named, PageError> {
    let picked = form.content_id.trim();
    let text = if picked.is_empty() {
        form.content.trim()
    } else {
        picked
    };
    if text.is_empty() {
        return Ok(Named::Refused("empty"));
    }
    let id = match content_number(text) {
        Some(id) => id,
        None if !picked.is_empty() => return Ok(Named::Refused("missing")),
        None => {
            // A title: the one content of exactly that title (letter case aside), else the
            // matches to pick from.
            let query: String = text.chars().take(ASSIGN_QUERY_CHARS).collect();
            let hits = assign_candidates(state, &query).await?;
            let wanted = query.to_lowercase();
            let mut exact = hits
                .iter()
                .filter(|h| h.title.trim().to_lowercase() == wanted);
            return Ok(match (exact.next(), exact.next()) {
                (Some(h), None) => Named::Content(h.id),
                _ if hits.is_empty() => Named::Refused("none"),
                _ => Named::Refused("choose"),
            });
        }
    };
    match contents::get(&state.db, id).await {
        Ok(_) => Ok(Named::Content(id)),
        Err(StoreError::NotFound(_)) => Ok(Named::Refused("missing")),
        Err(e) => Err(e.into()),
    }
}

/// Back to the part's form on the model page, saying why nothing was assigned.
fn refused(part: &Part, code: &str, typed: &str) -> HttpResponse {
    let typed: String = typed.trim().chars().take(ASSIGN_QUERY_CHARS).collect();
    redirect(&format!(
        "/models/{}?assign_part={}&assign_error={code}&assign_q={}#part-{}",
        part.model_id,
        part.id,
        encode_component(&typed),
        part.id
    ))
}

async fn assign(
    state: web::Data<AppState>,
    part_id: web::Path<i64>,
    post: PageForm<AssignForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Editor)?;
    let part = parts::get(&state.db, *part_id).await?;
    let form = &post.form;
    let typed = if form.content_id.trim().is_empty() {
        &form.content
    } else {
        &form.content_id
    };
    let content_id = match named_content(&state, form).await? {
        Named::Content(id) => id,
        Named::Refused(code) => return Ok(refused(&part, code, typed)),
    };
    match assignments::assign(&state.db, part.id, content_id, None, post.auth.id()).await {
        Ok(()) => {}
        Err(StoreError::Conflict(_)) => {
            let title = contents::get(&state.db, content_id)
                .await
                .map(|c| c.title)
                .unwrap_or_else(|_| format!("#{content_id}"));
            return Ok(refused(&part, "already", &title));
        }
        Err(StoreError::Invalid(_)) => return Ok(refused(&part, "missing", typed)),
        Err(e) => return Err(e.into()),
    }
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
