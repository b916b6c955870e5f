//! Content pages: list, view, new, edit (with preview), history, diff between any two
//! revisions, old revisions, revert, attachments. A save on a stale revision answers 409
//! with a merge page showing both versions.

use actix_multipart::Multipart;
use actix_web::http::StatusCode;
use actix_web::{HttpRequest, HttpResponse, web};
use askama::Template;
use serde::Deserialize;

use super::filters;
use super::{CsrfOnly, Layout, lf, redirect, render, render_status};
use crate::app::AppError;
use crate::app::contents::{EditConflict, OnStale};
use crate::store::Page;
use crate::store::assignments::{self, AssignedPart};
use crate::store::attachments::{self, Attachment};
use crate::store::contents::{self, Content, ContentEdit, Revision, RevisionSummary};
use crate::store::users::Role;
use crate::web::auth::{CsrfForm, PageAuth, PageForm, PageReader};
use crate::web::contents::{DiffQuery, RevisionDiff, diff_of};
use crate::web::{AppState, PageError};
use crate::wiki::{diff, markdown};

/// Mounts the pages.
pub fn configure(cfg: &mut web::ServiceConfig) {
    use crate::web::resource;
    cfg.service(resource("/contents").route(web::get().to(list)))
        .service(
            resource("/contents/new")
                .route(web::get().to(new_page))
                .route(web::post().to(create)),
        )
        .service(resource("/contents/{id:\\d+}").route(web::get().to(show)))
        .service(
            resource("/contents/{id:\\d+}/edit")
                .route(web::get().to(edit_page))
                .route(web::post().to(save)),
        )
        .service(resource("/contents/{id:\\d+}/history").route(web::get().to(history)))
        .service(resource("/contents/{id:\\d+}/diff").route(web::get().to(diff_page)))
        .service(
            resource("/contents/{id:\\d+}/revisions/{number:\\d+}")
                .route(web::get().to(revision_page)),
        )
        .service(resource("/contents/{id:\\d+}/revert").route(web::post().to(revert)))
        .service(resource("/contents/{id:\\d+}/attachments").route(web::post().to(upload)))
        .service(
            resource("/contents/{id:\\d+}/attachments/{attachment_id:\\d+}/remove")
                .route(web::post().to(detach)),
        );
}

#[derive(Debug, Deserialize)]
struct ListQuery {
    offset: Option<i64>,
}

#[derive(Template)]
#[template(path = "contents.html")]
struct ContentsPage {
    layout: Layout,
    contents: Vec<Content>,
    total: i64,
    offset: i64,
    prev: Option<i64>,
    next: Option<i64>,
}

async fn list(
    state: web::Data<AppState>,
    auth: PageAuth,
    q: web::Query<ListQuery>,
) -> Result<HttpResponse, PageError> {
    let page = Page::new(Some(100), q.offset);
    let items = contents::list(&state.db, page).await?;
    let total = contents::count(&state.db).await?;
    render(&ContentsPage {
        layout: Layout::new(&auth, "Contents"),
        prev: (page.offset > 0).then(|| (page.offset - page.limit).max(0)),
        next: (page.offset + page.limit < total).then_some(page.offset + page.limit),
        offset: page.offset,
        contents: items,
        total,
    })
}

#[derive(Template)]
#[template(path = "content.html")]
struct ContentPage {
    layout: Layout,
    content: Content,
    html: String,
    /// The thumbnail is shown beside the body (not when the body shows it).
    show_thumbnail: bool,
    author: String,
    attachments: Vec<Attachment>,
    parts: Vec<AssignedPart>,
    can_edit: bool,
    /// After a save merged with a concurrent one: that revision.
    merged_with: Option<Revision>,
}

/// Query of the content page.
#[derive(Debug, Deserialize)]
struct ShowQuery {
    /// The save just made was merged with this revision (shown as a notice).
    merged: Option<i64>,
}

async fn show(
    state: web::Data<AppState>,
    reader: PageReader,
    id: web::Path<i64>,
    query: web::Query<ShowQuery>,
) -> Result<HttpResponse, PageError> {
    if reader.auth.is_none() {
        // Anonymous visitors read what is assigned to a part of a public model.
        reader.allow(crate::store::visibility::content(&state.db, *id).await?)?;
    }
    let content = contents::get(&state.db, *id).await?;
    let merged_with = match query.merged {
        Some(n) => contents::revision(&state.db, content.id, n).await.ok(),
        None => None,
    };
    let current = contents::revision(&state.db, content.id, content.current_revision).await?;
    let attachments = attachments::list_for_content(&state.db, content.id).await?;
    let mut parts = assignments::parts_for_content(&state.db, content.id).await?;
    let layout = match &reader.auth {
        Some(auth) => Layout::new(auth, content.title.clone()),
        None => {
            let public = crate::store::visibility::public_models(&state.db).await?;
            parts.retain(|p| public.contains(&p.model_id));
            Layout::anonymous(content.title.clone())
        }
    };
    let html = markdown::render(&content.body);
    render(&ContentPage {
        can_edit: layout.can_edit(),
        layout,
        show_thumbnail: crate::web::contents::show_thumbnail(
            content.thumbnail_attachment_id,
            &html,
        ),
        html,
        author: current.author,
        content,
        attachments,
        parts,
        merged_with,
    })
}

#[derive(Template)]
#[template(path = "content_edit.html")]
struct EditPage {
    layout: Layout,
    is_new: bool,
    action: String,
    content_id: i64,
    base_revision: i64,
    /// The title as saved (the breadcrumb's), whatever the form holds.
    saved_title: String,
    title: String,
    caption: String,
    body: String,
    comment: String,
    preview_html: String,
    attachments: Vec<Attachment>,
    error: String,
}

impl EditPage {
    fn blank(layout: Layout) -> EditPage {
        EditPage {
            layout,
            is_new: true,
            action: "/contents/new".into(),
            content_id: 0,
            base_revision: 0,
            saved_title: String::new(),
            title: String::new(),
            caption: String::new(),
            body: String::new(),
            comment: String::new(),
            preview_html: String::new(),
            attachments: Vec::new(),
            error: String::new(),
        }
    }
}

#[derive(Debug, Deserialize)]
struct EditForm {
    #[serde(default)]
    csrf_token: String,
    #[serde(default)]
    base_revision: Option<i64>,
    title: String,
    #[serde(default)]
    caption: String,
    #[serde(default)]
    body: String,
    #[serde(default)]
    comment: String,
    #[serde(default)]
    action: String,
}

impl CsrfForm for EditForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

impl EditForm {
    fn edit(&self) -> ContentEdit {
        ContentEdit {
            title: self.title.clone(),
            caption: lf(&self.caption),
            body: lf(&self.body),
            comment: self.comment.clone(),
        }
    }
}

async fn new_page(auth: PageAuth) -> Result<HttpResponse, PageError> {
    auth.require(Role::Editor)?;
    render(&EditPage::blank(Layout::new(&auth, "New content")))
}

async fn create(
    state: web::Data<AppState>,
    post: PageForm<EditForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Editor)?;
    let edit = post.form.edit();
    let invalid = state.validate_edit(&edit).err();
    if post.form.action == "preview" || invalid.is_some() {
        let mut page = EditPage::blank(Layout::new(&post.auth, "New content"));
        page.preview_html = markdown::render(&edit.body);
        page.error = invalid.map(|e| e.to_string()).unwrap_or_default();
        let status = if page.error.is_empty() {
            StatusCode::OK
        } else {
            StatusCode::BAD_REQUEST
        };
        page.title = edit.title;
        page.caption = edit.caption;
        page.body = edit.body;
        page.comment = edit.comment;
        return render_status(status, &page);
    }
    let content = contents::create(&state.db, &edit, None, post.auth.id()).await?;
    state.sync_search().await;
    Ok(redirect(&format!("/contents/{}", content.id)))
}

async fn edit_page(
    state: web::Data<AppState>,
    auth: PageAuth,
    id: web::Path<i64>,
) -> Result<HttpResponse, PageError> {
    auth.require(Role::Editor)?;
    let content = contents::get(&state.db, *id).await?;
    let attachments = attachments::list_for_content(&state.db, content.id).await?;
    render(&EditPage {
        layout: Layout::new(&auth, format!("Edit {}", content.title)),
        is_new: false,
        action: format!("/contents/{}/edit", content.id),
        content_id: content.id,
        base_revision: content.current_revision,
        saved_title: content.title.clone(),
        title: content.title,
        caption: content.caption,
        body: content.body,
        comment: String::new(),
        preview_html: String::new(),
        attachments,
        error: String::new(),
    })
}

#[derive(Template)]
#[template(path = "content_merge.html")]
struct MergePage {
    layout: Layout,
    content_id: i64,
    base: i64,
    theirs: Revision,
    theirs_html: String,
    /// Title, caption and body to put in the form: the merge (conflicts between markers), or
    /// without a base your edit as it was.
    form: ContentEdit,
    /// Conflicts left in the form.
    conflicts: usize,
    /// The base is known: the diffs below are against it.
    three_way: bool,
    /// What they changed since the base (three-way), or from theirs to yours.
    their_changes_html: String,
    /// What you changed since the base (three-way only).
    your_changes_html: String,
    /// Field changes worth a line: (field, before, after), theirs then yours.
    field_changes: Vec<(String, String, String, String)>,
}

impl MergePage {
    fn new(layout: Layout, content_id: i64, c: EditConflict) -> MergePage {
        let EditConflict {
            base_number,
            base,
            theirs,
            yours,
            merged,
        } = c;
        let theirs_html = markdown::render(&theirs.body);
        match (base, merged) {
            (Some(base), Some(m)) => {
                let mut field_changes = Vec::new();
                for (name, b, t, y) in [
                    ("Title", &base.title, &theirs.title, yours.title.trim()),
                    (
                        "Caption",
                        &base.caption,
                        &theirs.caption,
                        yours.caption.as_str(),
                    ),
                ] {
                    if b != t || b != y {
                        field_changes.push((name.to_string(), b.clone(), t.clone(), y.to_string()));
                    }
                }
                MergePage {
                    layout,
                    content_id,
                    base: base_number,
                    their_changes_html: diff::diff(&base.body, &theirs.body, 3).html,
                    your_changes_html: diff::diff(&base.body, &yours.body, 3).html,
                    theirs_html,
                    conflicts: m.conflicts,
                    form: ContentEdit {
                        title: m.title,
                        caption: m.caption,
                        body: m.body,
                        comment: yours.comment,
                    },
                    three_way: true,
                    field_changes,
                    theirs,
                }
            }
            _ => MergePage {
                layout,
                content_id,
                base: base_number,
                their_changes_html: diff::diff(&theirs.body, &yours.body, 3).html,
                your_changes_html: String::new(),
                theirs_html,
                conflicts: 0,
                form: yours,
                three_way: false,
                field_changes: Vec::new(),
                theirs,
            },
        }
    }
}

async fn save(
    state: web::Data<AppState>,
    id: web::Path<i64>,
    post: PageForm<EditForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Editor)?;
    let content = contents::get(&state.db, *id).await?;
    let edit = post.form.edit();
    let base = post.form.base_revision.unwrap_or(content.current_revision);
    let invalid = state.validate_edit(&edit).err();
    if post.form.action == "preview" || invalid.is_some() {
        let attachments = attachments::list_for_content(&state.db, content.id).await?;
        let error = invalid.map(|e| e.to_string()).unwrap_or_default();
        let status = if error.is_empty() {
            StatusCode::OK
        } else {
            StatusCode::BAD_REQUEST
        };
        return render_status(
            status,
            &EditPage {
                layout: Layout::new(&post.auth, format!("Edit {}", content.title)),
                is_new: false,
                action: format!("/contents/{}/edit", content.id),
                content_id: content.id,
                base_revision: base,
                preview_html: markdown::render(&edit.body),
                saved_title: content.title.clone(),
                title: edit.title,
                caption: edit.caption,
                body: edit.body,
                comment: edit.comment,
                attachments,
                error,
            },
        );
    }
    // A stale edit that merges cleanly with what was saved since is saved merged, as wikis do;
    // an overlap comes back as the merge page.
    match state
        .save_content(
            post.auth.id(),
            content.id,
            base,
            &edit,
            None,
            OnStale::SaveCleanMerge,
        )
        .await
    {
        Ok(saved) => Ok(redirect(&match saved.merged_with {
            Some(r) => format!("/contents/{}?merged={}", saved.content.id, r.number),
            None => format!("/contents/{}", saved.content.id),
        })),
        Err(AppError::EditConflict(c)) => {
            let layout = Layout::new(&post.auth, format!("Edit conflict: {}", c.theirs.title));
            render_status(
                StatusCode::CONFLICT,
                &MergePage::new(layout, content.id, *c),
            )
        }
        Err(e) => Err(e.into()),
    }
}

#[derive(Template)]
#[template(path = "content_history.html")]
struct HistoryPage {
    layout: Layout,
    content: Content,
    revisions: Vec<RevisionSummary>,
    can_edit: bool,
}

async fn history(
    state: web::Data<AppState>,
    auth: PageAuth,
    id: web::Path<i64>,
) -> Result<HttpResponse, PageError> {
    let content = contents::get(&state.db, *id).await?;
    let revisions = contents::revisions(&state.db, content.id).await?;
    let layout = Layout::new(&auth, format!("History of {}", content.title));
    render(&HistoryPage {
        can_edit: layout.can_edit(),
        layout,
        content,
        revisions,
    })
}

#[derive(Template)]
#[template(path = "content_diff.html")]
struct DiffPage {
    layout: Layout,
    content: Content,
    d: RevisionDiff,
}

async fn diff_page(
    state: web::Data<AppState>,
    auth: PageAuth,
    id: web::Path<i64>,
    q: web::Query<DiffQuery>,
) -> Result<HttpResponse, PageError> {
    let content = contents::get(&state.db, *id).await?;
    let d = diff_of(&state, content.id, &q).await?;
    render(&DiffPage {
        layout: Layout::new(&auth, format!("Diff of {}", content.title)),
        content,
        d,
    })
}

#[derive(Template)]
#[template(path = "content_revision.html")]
struct RevisionPage {
    layout: Layout,
    content: Content,
    revision: Revision,
    html: String,
    can_edit: bool,
}

async fn revision_page(
    state: web::Data<AppState>,
    auth: PageAuth,
    path: web::Path<(i64, i64)>,
) -> Result<HttpResponse, PageError> {
    let (id, number) = path.into_inner();
    let content = contents::get(&state.db, id).await?;
    let revision = contents::revision(&state.db, id, number).await?;
    let layout = Layout::new(
        &auth,
        format!("{} (revision {})", revision.title, revision.number),
    );
    render(&RevisionPage {
        can_edit: layout.can_edit(),
        layout,
        html: markdown::render(&revision.body),
        content,
        revision,
    })
}

#[derive(Debug, Deserialize)]
struct RevertForm {
    #[serde(default)]
    csrf_token: String,
    revision: i64,
    base_revision: i64,
    /// Why (the revert's edit comment).
    #[serde(default)]
    comment: String,
}

impl CsrfForm for RevertForm {
    fn csrf_token(&self) -> &str {
        &self.csrf_token
    }
}

async fn revert(
    state: web::Data<AppState>,
    id: web::Path<i64>,
    post: PageForm<RevertForm>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Editor)?;
    let f = &post.form;
    let comment = f.comment.trim();
    contents::revert(
        &state.db,
        *id,
        f.revision,
        Some(f.base_revision),
        (!comment.is_empty()).then_some(comment),
        post.auth.id(),
    )
    .await?;
    state.sync_search().await;
    state.events.publish(crate::app::events::Event::content(
        crate::app::events::EventKind::ContentUpdated,
        *id,
    ));
    Ok(redirect(&format!("/contents/{}", *id)))
}

async fn upload(
    state: web::Data<AppState>,
    auth: PageAuth,
    req: HttpRequest,
    id: web::Path<i64>,
    form: Multipart,
) -> Result<HttpResponse, PageError> {
    // A multipart form is no `PageForm`: check the origin here, as every other form does.
    crate::web::auth::check_origin(&req)?;
    auth.require(Role::Editor)?;
    contents::get(&state.db, *id).await?;
    let received = crate::web::attachments::receive(&state, form, Some(auth.csrf()))
        .await
        .map_err(PageError::Api)?;
    attachments::create(&state.db, &received.attachment, Some(*id), auth.id()).await?;
    state.sync_search().await;
    Ok(redirect(&format!("/contents/{}/edit#attachments", *id)))
}

async fn detach(
    state: web::Data<AppState>,
    path: web::Path<(i64, i64)>,
    post: PageForm<CsrfOnly>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Editor)?;
    let (id, attachment_id) = path.into_inner();
    attachments::unlink(&state.db, id, attachment_id, post.auth.id()).await?;
    state.sync_search().await;
    Ok(redirect(&format!("/contents/{id}/edit#attachments")))
}
