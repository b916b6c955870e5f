//! `/api/v1/contents`: wiki pages with revisions. Every save names its `base_revision`; a
//! stale base answers 409 with both versions. Anyone logged in reads; editors create, save
//! and revert; admins delete.

use actix_web::{HttpResponse, web};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

use super::auth::{Auth, Reader};
use super::{ApiError, AppState, PageQuery};
use crate::app::contents::OnStale;
use crate::app::events::{Event, EventKind};
use crate::store::attachments::{self, Attachment};
use crate::store::contents::{self, Content, ContentEdit, Revision, RevisionSummary};
use crate::store::models::double_option;
use crate::store::users::Role;
use crate::wiki::{diff, markdown};

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(
        super::resource("/api/v1/contents")
            .route(web::get().to(list))
            .route(web::post().to(create)),
    )
    .service(super::resource("/api/v1/preview").route(web::post().to(preview)))
    .service(
        super::resource("/api/v1/contents/{id}")
            .route(web::get().to(get))
            .route(web::put().to(save))
            .route(web::delete().to(delete)),
    )
    .service(super::resource("/api/v1/contents/{id}/revisions").route(web::get().to(revisions)))
    .service(
        super::resource("/api/v1/contents/{id}/revisions/{number}").route(web::get().to(revision)),
    )
    .service(super::resource("/api/v1/contents/{id}/diff").route(web::get().to(diff_revisions)))
    .service(super::resource("/api/v1/contents/{id}/revert").route(web::post().to(revert)));
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(
    list,
    create,
    preview,
    get,
    save,
    delete,
    revisions,
    revision,
    diff_revisions,
    revert
))]
pub(super) struct Api;

/// A content with its rendered body.
#[derive(Debug, Serialize, ToSchema)]
pub struct ContentView {
    /// The content.
    #[serde(flatten)]
    pub content: Content,
    /// Sanitised HTML of the body.
    pub html: String,
    /// Whether to show the thumbnail beside the body: false without one, or when the body
    /// already shows that image (a dropped picture is both), so no one sees it twice.
    pub show_thumbnail: bool,
    /// Attachments, in order (absent in lists).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub attachments: Option<Vec<Attachment>>,
}

impl ContentView {
    fn new(content: Content, attachments: Option<Vec<Attachment>>) -> ContentView {
        let html = markdown::render(&content.body);
        ContentView {
            show_thumbnail: show_thumbnail(content.thumbnail_attachment_id, &html),
            html,
            content,
            attachments,
        }
    }
}

/// Whether a content's thumbnail `thumbnail` is shown beside its rendered body `html`: not
/// when the body shows the same attachment already.
pub fn show_thumbnail(thumbnail: Option<i64>, html: &str) -> bool {
    thumbnail.is_some_and(|t| !html.contains(&format!("src=\"/api/v1/attachments/{t}/download\"")))
}

/// Body of `POST /api/v1/contents`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewContent {
    /// Title.
    pub title: String,
    /// Caption.
    #[serde(default)]
    pub caption: String,
    /// Markdown body.
    #[serde(default)]
    pub body: String,
    /// Comment of revision 1.
    #[serde(default)]
    pub comment: String,
    /// Thumbnail attachment.
    #[serde(default)]
    pub thumbnail_attachment_id: Option<i64>,
}

/// Body of `PUT /api/v1/contents/{id}`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SaveContent {
    /// The revision this edit is based on.
    pub base_revision: i64,
    /// Title.
    pub title: String,
    /// Caption.
    #[serde(default)]
    pub caption: String,
    /// Markdown body.
    #[serde(default)]
    pub body: String,
    /// Edit comment.
    #[serde(default)]
    pub comment: String,
    /// New thumbnail (`null` clears; absent leaves it).
    #[serde(default, with = "double_option")]
    #[schema(value_type = Option<i64>)]
    pub thumbnail_attachment_id: Option<Option<i64>>,
}

/// List contents
///
/// Most recently changed first, each with its rendered HTML (without attachments).
#[utoipa::path(get, path = "/api/v1/contents", tag = "contents",
    params(PageQuery),
    responses((status = 200, description = "Contents", body = Vec<ContentView>)),
    security(("sessionCookie" = ["viewer"])))]
async fn list(
    state: web::Data<AppState>,
    _auth: Auth,
    q: web::Query<PageQuery>,
) -> Result<HttpResponse, ApiError> {
    let items: Vec<ContentView> = contents::list(&state.db, q.page())
        .await?
        .into_iter()
        .map(|c| ContentView::new(c, None))
        .collect();
    Ok(HttpResponse::Ok().json(items))
}

/// Create a content
///
/// The creation is revision 1, with the author and the optional comment.
#[utoipa::path(post, path = "/api/v1/contents", tag = "contents",
    request_body = NewContent,
    responses((status = 201, description = "Created", body = ContentView)),
    security(("sessionCookie" = ["editor"])))]
async fn create(
    state: web::Data<AppState>,
    auth: Auth,
    body: web::Json<NewContent>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let body = body.into_inner();
    let edit = ContentEdit {
        title: body.title,
        caption: body.caption,
        body: body.body,
        comment: body.comment,
    };
    state.validate_edit(&edit)?;
    let content =
        contents::create(&state.db, &edit, body.thumbnail_attachment_id, auth.id()).await?;
    state.sync_search().await;
    Ok(HttpResponse::Created().json(ContentView::new(content, Some(Vec::new()))))
}

/// Get a content with its rendered HTML and attachments.
#[utoipa::path(get, path = "/api/v1/contents/{id}", tag = "contents",
    params(("id" = i64, Path, description = "content id")),
    responses((status = 200, description = "The content", body = ContentView)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn get(
    state: web::Data<AppState>,
    reader: Reader,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.content(&state.db, *id).await?;
    let content = contents::get(&state.db, *id).await?;
    let att = attachments::list_for_content(&state.db, *id).await?;
    Ok(HttpResponse::Ok().json(ContentView::new(content, Some(att))))
}

/// Save a new revision
///
/// The edit names the revision it is based on (`base_revision`); when that is no longer the
/// current revision the save is refused with 409 and both versions (never a lost update).
#[utoipa::path(put, path = "/api/v1/contents/{id}", tag = "contents",
    params(("id" = i64, Path, description = "content id")),
    request_body = SaveContent,
    responses(
        (status = 200, description = "Saved", body = ContentView),
        (status = 409, description = "Edit conflict: `base_revision` is not the current \
            revision; the body carries the current revision and the rejected edit",
            body = super::error::EditConflict)),
    security(("sessionCookie" = ["editor"])))]
async fn save(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
    body: web::Json<SaveContent>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let body = body.into_inner();
    let edit = ContentEdit {
        title: body.title,
        caption: body.caption,
        body: body.body,
        comment: body.comment,
    };
    let saved = state
        .save_content(
            auth.id(),
            *id,
            body.base_revision,
            &edit,
            body.thumbnail_attachment_id,
            OnStale::Report,
        )
        .await?;
    let att = attachments::list_for_content(&state.db, *id).await?;
    Ok(HttpResponse::Ok().json(ContentView::new(saved.content, Some(att))))
}

/// Delete a content
///
/// With its history, assignments and attachment links (the attachments themselves stay).
#[utoipa::path(delete, path = "/api/v1/contents/{id}", tag = "contents",
    params(("id" = i64, Path, description = "content id")),
    responses((status = 204, description = "Deleted")),
    security(("sessionCookie" = ["admin"])))]
async fn delete(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Admin)?;
    contents::delete(&state.db, *id, auth.id()).await?;
    state.sync_search().await;
    state
        .events
        .publish(Event::content(EventKind::ContentDeleted, *id));
    Ok(HttpResponse::NoContent().finish())
}

/// History of a content, newest first.
#[utoipa::path(get, path = "/api/v1/contents/{id}/revisions", tag = "contents",
    params(("id" = i64, Path, description = "content id")),
    responses((status = 200, description = "Revisions", body = Vec<RevisionSummary>)),
    security(("sessionCookie" = ["viewer"])))]
async fn revisions(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    Ok(HttpResponse::Ok().json(contents::revisions(&state.db, *id).await?))
}

/// A revision with its rendered body.
#[derive(Debug, Serialize, ToSchema)]
struct RevisionView {
    /// The revision.
    #[serde(flatten)]
    revision: Revision,
    /// Sanitised HTML of the revision's body.
    html: String,
}

/// One revision in full, with rendered HTML.
#[utoipa::path(get, path = "/api/v1/contents/{id}/revisions/{number}", tag = "contents",
    params(
        ("id" = i64, Path, description = "content id"),
        ("number" = i64, Path, description = "revision number")),
    responses((status = 200, description = "The revision", body = RevisionView)),
    security(("sessionCookie" = ["viewer"])))]
async fn revision(
    state: web::Data<AppState>,
    _auth: Auth,
    path: web::Path<(i64, i64)>,
) -> Result<HttpResponse, ApiError> {
    let (id, number) = path.into_inner();
    let revision = contents::revision(&state.db, id, number).await?;
    Ok(HttpResponse::Ok().json(RevisionView {
        html: markdown::render(&revision.body),
        revision,
    }))
}

/// `from` / `to` revision numbers of a diff.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct DiffQuery {
    /// Older revision (default: the one before `to`).
    pub from: Option<i64>,
    /// Newer revision (default: current).
    pub to: Option<i64>,
}

/// Diff of one field.
#[derive(Debug, Serialize, ToSchema)]
pub struct FieldDiff {
    /// Value at `from`.
    pub from: String,
    /// Value at `to`.
    pub to: String,
    /// Whether it changed.
    pub changed: bool,
}

/// Diff between two revisions.
#[derive(Debug, Serialize, ToSchema)]
pub struct RevisionDiff {
    /// Content id.
    pub content_id: i64,
    /// Older revision number.
    pub from: i64,
    /// Newer revision number.
    pub to: i64,
    /// Title change.
    pub title: FieldDiff,
    /// Caption change.
    pub caption: FieldDiff,
    /// Body diff (HTML table, unified text, counts).
    pub body: diff::Diff,
}

/// Diffs two revisions of a content (defaults: previous → current).
pub async fn diff_of(state: &AppState, id: i64, q: &DiffQuery) -> Result<RevisionDiff, ApiError> {
    let content = contents::get(&state.db, id).await?;
    let to = q.to.unwrap_or(content.current_revision);
    let from = q.from.unwrap_or((to - 1).max(1));
    let a = contents::revision(&state.db, id, from).await?;
    let b = contents::revision(&state.db, id, to).await?;
    let body = diff::diff(&a.body, &b.body, 3);
    Ok(RevisionDiff {
        content_id: id,
        from,
        to,
        title: FieldDiff {
            changed: a.title != b.title,
            from: a.title,
            to: b.title,
        },
        caption: FieldDiff {
            changed: a.caption != b.caption,
            from: a.caption,
            to: b.caption,
        },
        body,
    })
}

/// Diff between two revisions
///
/// Of the title, the caption and the body (an HTML table with changed words marked, a
/// unified diff, line counts). Defaults: from the revision before `to`, to the current one.
#[utoipa::path(get, path = "/api/v1/contents/{id}/diff", tag = "contents",
    params(("id" = i64, Path, description = "content id"), DiffQuery),
    responses((status = 200, description = "The diff", body = RevisionDiff)),
    security(("sessionCookie" = ["viewer"])))]
async fn diff_revisions(
    state: web::Data<AppState>,
    _auth: Auth,
    id: web::Path<i64>,
    q: web::Query<DiffQuery>,
) -> Result<HttpResponse, ApiError> {
    Ok(HttpResponse::Ok().json(diff_of(&state, *id, &q).await?))
}

/// Body of `POST /api/v1/contents/{id}/revert`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RevertRequest {
    /// Revision to restore.
    pub revision: i64,
    /// If given, the save fails with 409 unless this is the current revision.
    #[serde(default)]
    pub base_revision: Option<i64>,
    /// Edit comment (default "Reverted to revision N").
    #[serde(default)]
    pub comment: Option<String>,
}

/// Revert to an old revision
///
/// Saves a copy of the old revision's text as a new revision (the thumbnail is left as it
/// is). With `base_revision`, the save is refused with 409 unless that is the current
/// revision.
#[utoipa::path(post, path = "/api/v1/contents/{id}/revert", tag = "contents",
    params(("id" = i64, Path, description = "content id")),
    request_body = RevertRequest,
    responses(
        (status = 200, description = "Reverted", body = ContentView),
        (status = 409, description = "Edit conflict: `base_revision` is not the current \
            revision; the body carries the current revision (`yours` is null)",
            body = super::error::EditConflict)),
    security(("sessionCookie" = ["editor"])))]
async fn revert(
    state: web::Data<AppState>,
    auth: Auth,
    id: web::Path<i64>,
    body: web::Json<RevertRequest>,
) -> Result<HttpResponse, ApiError> {
    auth.require(Role::Editor)?;
    let content = contents::revert(
        &state.db,
        *id,
        body.revision,
        body.base_revision,
        body.comment.as_deref(),
        auth.id(),
    )
    .await?;
    state.sync_search().await;
    state
        .events
        .publish(Event::content(EventKind::ContentUpdated, *id));
    let att = attachments::list_for_content(&state.db, *id).await?;
    Ok(HttpResponse::Ok().json(ContentView::new(content, Some(att))))
}

/// Body of `POST /api/v1/preview`.
#[derive(Debug, Deserialize, ToSchema)]
pub struct PreviewRequest {
    /// Markdown to render.
    pub body: String,
}

/// Answer of `POST /api/v1/preview`.
#[derive(Debug, Serialize, ToSchema)]
pub struct PreviewHtml {
    /// Sanitised HTML of the Markdown, as a content's `html`.
    pub html: String,
}

/// Render Markdown to sanitised HTML
///
/// As a content's body would be rendered; nothing is saved.
#[utoipa::path(post, path = "/api/v1/preview", tag = "contents",
    request_body = PreviewRequest,
    responses(
        (status = 200, description = "The HTML", body = PreviewHtml),
        (status = 413, description = "Body larger than the content body limit",
            body = super::openapi::ErrorBody)),
    security(("sessionCookie" = ["viewer"])))]
async fn preview(
    state: web::Data<AppState>,
    _auth: Auth,
    body: web::Json<PreviewRequest>,
) -> Result<HttpResponse, ApiError> {
    if body.body.len() > state.settings.limits.body_bytes {
        return Err(ApiError::PayloadTooLarge("body too large".into()));
    }
    Ok(HttpResponse::Ok().json(PreviewHtml {
        html: markdown::render(&body.body),
    }))
}
