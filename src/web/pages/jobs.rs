//! `/admin/jobs` (admin): jobs with live progress, a multipart upload form and cancel
//! buttons, usable without JavaScript (the page refreshes itself while a job runs).

use actix_multipart::Multipart;
use actix_web::ResponseError as _;
use actix_web::http::StatusCode;
use actix_web::{HttpRequest, HttpResponse, web};
use askama::Template;
use futures_util::StreamExt;

use super::{CsrfOnly, Layout, redirect, render_status};
use crate::jobs::{ReceivedScan, SCAN_EXTENSIONS};
use crate::store::Page;
use crate::store::jobs::{self, Job};
use crate::store::models::NewModel;
use crate::store::users::Role;
use crate::web::auth::{PageAuth, PageForm};
use crate::web::jobs::{check_title, extension_of, receive_scan};
use crate::web::multipart::{TextFields, multipart_error};
use crate::web::{ApiError, AppState, PageError};

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(crate::web::resource("/admin/jobs").route(web::get().to(page)))
        .service(crate::web::resource("/admin/jobs/upload").route(web::post().to(page_upload)))
        .service(
            crate::web::resource("/admin/jobs/{id}/cancel").route(web::post().to(page_cancel)),
        );
}

/// A job as the page shows it.
pub struct JobView {
    /// The job.
    pub job: Job,
    /// Whether it can still be cancelled.
    pub active: bool,
    /// `12.5` → `"12.5"`.
    pub percent: String,
}

impl JobView {
    /// View of `job`.
    pub fn new(job: Job) -> JobView {
        JobView {
            active: !job.status.is_finished(),
            percent: format!("{:.1}", job.percent),
            job,
        }
    }
}

#[derive(Template)]
#[template(path = "admin_jobs.html")]
struct JobsPage {
    layout: Layout,
    jobs: Vec<JobView>,
    any_active: bool,
    error: String,
    max_upload_mb: u64,
    extensions: &'static str,
}

async fn jobs_page(
    state: &AppState,
    auth: &PageAuth,
    status: StatusCode,
    error: String,
) -> Result<HttpResponse, PageError> {
    let list = jobs::list(&state.db, None, Page::new(Some(200), None)).await?;
    let jobs: Vec<JobView> = list.into_iter().map(JobView::new).collect();
    render_status(
        status,
        &JobsPage {
            layout: Layout::new(auth, "Jobs"),
            any_active: jobs.iter().any(|j| j.active),
            jobs,
            error,
            max_upload_mb: state.settings.build.upload_bytes >> 20,
            extensions: SCAN_EXTENSIONS,
        },
    )
}

async fn page(state: web::Data<AppState>, auth: PageAuth) -> Result<HttpResponse, PageError> {
    auth.require(Role::Admin)?;
    jobs_page(&state, &auth, StatusCode::OK, String::new()).await
}

/// Reads the upload form: text fields (`csrf_token` first, `title`, `description`) and one
/// `file`, streamed to `uploads/`.
async fn receive_form(
    state: &AppState,
    auth: &PageAuth,
    mut form: Multipart,
) -> Result<(ReceivedScan, String, String), ApiError> {
    let limit = state.settings.build.upload_bytes;
    let mut fields = TextFields::new();
    let mut scan = None;
    while let Some(field) = form.next().await {
        let mut field = field.map_err(multipart_error)?;
        let name = field.name().unwrap_or("").to_string();
        let filename = field
            .content_disposition()
            .and_then(|cd| cd.get_filename())
            .map(str::to_string);
        if name == "file" {
            if scan.is_some() {
                return Err(ApiError::bad("upload exactly one file"));
            }
            let sent = fields.get("csrf_token").unwrap_or("");
            if !crate::web::auth::constant_time_eq(sent, auth.csrf()) {
                return Err(ApiError::Forbidden(
                    "missing or invalid CSRF token: reload the page and try again".into(),
                ));
            }
            let filename = filename.unwrap_or_default();
            let extension = extension_of(&filename)?;
            let display = crate::web::attachments::sanitize_name(&filename);
            let stream = (&mut field).map(|c| c.map_err(multipart_error));
            scan = Some(receive_scan(state, Box::pin(stream), extension, display, limit).await?);
        } else {
            fields.read(name, &mut field, 64 * 1024).await?;
        }
    }
    let scan = scan.ok_or_else(|| ApiError::bad("choose a scan file to upload"))?;
    let title = fields.remove("title").unwrap_or_default();
    let description = fields.remove("description").unwrap_or_default();
    Ok((scan, title, description))
}

async fn page_upload(
    state: web::Data<AppState>,
    auth: PageAuth,
    req: HttpRequest,
    form: Multipart,
) -> Result<HttpResponse, PageError> {
    auth.require(Role::Admin)?;
    crate::web::auth::check_origin(&req)?;
    let (scan, title, description) = match receive_form(&state, &auth, form).await {
        Ok(r) => r,
        Err(e @ ApiError::Forbidden(_)) => return Err(e.into()),
        Err(e) => return jobs_page(&state, &auth, e.status_code(), e.message()).await,
    };
    let title = match check_title(&title, state.settings.limits.title_chars) {
        Ok(t) => t,
        Err(e) => {
            drop(scan);
            return jobs_page(&state, &auth, StatusCode::BAD_REQUEST, e.message()).await;
        }
    };
    let model = NewModel {
        title,
        description: description.replace("\r\n", "\n"),
        source_name: scan.display_name.clone(),
    };
    let (model, _job) = state
        .jobs
        .submit_upload(scan, &model, auth.id())
        .await
        .map_err(ApiError::from)?;
    Ok(redirect(&format!("/models/{}", model.id)))
}

async fn page_cancel(
    state: web::Data<AppState>,
    id: web::Path<i64>,
    post: PageForm<CsrfOnly>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Admin)?;
    state
        .jobs
        .cancel(*id, Some(post.auth.id()))
        .await
        .map_err(ApiError::from)?;
    Ok(redirect("/admin/jobs"))
}
