//! `/admin/jobs` (admin): jobs with live progress, a multipart upload form and cancel
//! buttons, usable without JavaScript (the page refreshes itself while a job runs).

use actix_multipart::Multipart;
use actix_web::ResponseError as _;
use actix_web::http::StatusCode;
use actix_web::{HttpRequest, HttpResponse, web};
use askama::Template;
use futures_util::StreamExt;

use super::filters;
use super::{CsrfOnly, Layout, redirect, render_status};
use crate::app::uploads::{BuildChoices, ScanFor};
use crate::jobs::archive::ReceivedFile;
use crate::jobs::{MAX_SCAN_FILES, SCAN_EXTENSIONS, companion_path};
use crate::store::Page;
use crate::store::jobs::{self, Job, JobOptions, JobStatus};
use crate::store::models::{self, ModelStatus};
use crate::store::users::Role;
use crate::web::auth::{PageAuth, PageForm};
use crate::web::jobs::check_title;
use crate::web::multipart::{TextFields, multipart_error};
use crate::web::{ApiError, AppState, PageError};
use meshwiki_engine::lod::VertexOrder;
use meshwiki_engine::lod::segsimplify::Simplifier;

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(crate::web::resource("/admin/jobs").route(web::get().to(page)))
        .service(crate::web::resource("/admin/jobs/upload").route(web::post().to(page_upload)))
        .service(crate::web::resource("/admin/jobs/{id}/cancel").route(web::post().to(page_cancel)))
        .service(
            crate::web::resource("/admin/models/{id}/delete")
                .route(web::post().to(page_delete_model)),
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
    /// The latest build of a model left without a built scan (failed or cancelled): the page
    /// offers to upload the scan again or to delete the model.
    pub retry: bool,
    /// Its build options, offered again by the retry form.
    pub build: BuildFields,
}

impl JobView {
    /// View of `job`.
    pub fn new(job: Job) -> JobView {
        JobView {
            active: !job.status.is_finished(),
            percent: format!("{:.1}", job.percent),
            retry: false,
            build: BuildFields::of(&job.options),
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
    /// The upload form's text, kept after an error.
    kept: Kept,
    /// The server's patch triangle budget (the form's placeholder).
    default_patch_triangles: u32,
    max_upload_mb: u64,
    extensions: &'static str,
}

/// The upload form's text, put back after an error.
#[derive(Debug, Clone, Default)]
struct Kept {
    title: String,
    description: String,
    build: BuildFields,
}

/// The upload form's build options as text (so a refused value comes back as it was; empty:
/// the server's default).
#[derive(Debug, Clone, Default)]
pub struct BuildFields {
    simplifier: String,
    patch_triangles: String,
    texture_quality: String,
    texture_spread: String,
    /// The normal-maps checkbox: "on" when ticked.
    normal_maps: String,
    vertex_order: String,
}

impl BuildFields {
    /// The options a job was built with.
    fn of(options: &JobOptions) -> BuildFields {
        fn text<T: ToString>(v: Option<T>) -> String {
            v.map(|v| v.to_string()).unwrap_or_default()
        }
        BuildFields {
            simplifier: text(options.simplifier.map(|s| s.as_str())),
            patch_triangles: text(options.max_patch_triangles),
            texture_quality: text(options.texture_quality),
            texture_spread: text(options.texture_spread),
            normal_maps: if options.normal_maps == Some(true) {
                "on".to_string()
            } else {
                String::new()
            },
            vertex_order: text(options.vertex_order.map(|o| o.as_str())),
        }
    }

    /// Whether any option differs from the server's default (the form shows them unfolded).
    fn any(&self) -> bool {
        [
            &self.simplifier,
            &self.patch_triangles,
            &self.texture_quality,
            &self.texture_spread,
            &self.normal_maps,
            &self.vertex_order,
        ]
        .iter()
        .any(|v| !v.trim().is_empty())
    }

    /// The build options of the form, parsed: empty fields are the server's defaults.
    fn choices(&self) -> Result<BuildChoices, ApiError> {
        fn number<T: std::str::FromStr>(name: &str, v: &str) -> Result<Option<T>, ApiError> {
            let v = v.trim();
            if v.is_empty() {
                return Ok(None);
            }
            v.parse()
                .map(Some)
                .map_err(|_| ApiError::bad(format!("{name} must be a whole number, not {v:?}")))
        }
        let simplifier = match self.simplifier.trim() {
            "" => None,
            name => Some(name.parse::<Simplifier>().map_err(ApiError::bad)?),
        };
        let vertex_order = match self.vertex_order.trim() {
            "" => None,
            name => Some(name.parse::<VertexOrder>().map_err(ApiError::bad)?),
        };
        // Ranges are checked where every route's are (`App::submit_scan`).
        Ok(BuildChoices {
            simplifier,
            patch_triangles: number("patch_triangles", &self.patch_triangles)?,
            texture_quality: number("texture_quality", &self.texture_quality)?,
            texture_spread: number("texture_spread", &self.texture_spread)?,
            normal_maps: match self.normal_maps.trim() {
                "" => None,
                "on" | "true" => Some(true),
                other => {
                    return Err(ApiError::bad(format!(
                        "normal_maps must be on or absent, not {other:?}"
                    )));
                }
            },
            vertex_order,
        })
    }
}

async fn jobs_page(
    state: &AppState,
    auth: &PageAuth,
    status: StatusCode,
    error: String,
    kept: Kept,
) -> Result<HttpResponse, PageError> {
    let list = jobs::list(&state.db, None, Page::new(Some(200), None)).await?;
    let mut jobs: Vec<JobView> = list.into_iter().map(JobView::new).collect();
    // Newest first: the first job seen of a model is its latest.
    let mut seen = std::collections::HashSet::new();
    for view in &mut jobs {
        let Some(model_id) = view.job.model_id else {
            continue;
        };
        if !seen.insert(model_id)
            || !matches!(view.job.status, JobStatus::Failed | JobStatus::Cancelled)
        {
            continue;
        }
        view.retry = matches!(
            models::get(&state.db, model_id).await.map(|m| m.status),
            Ok(ModelStatus::Pending | ModelStatus::Failed)
        );
    }
    render_status(
        status,
        &JobsPage {
            layout: Layout::new(auth, "Jobs"),
            any_active: jobs.iter().any(|j| j.active),
            jobs,
            error,
            kept,
            default_patch_triangles: state.settings.build.max_patch_triangles,
            max_upload_mb: state.settings.build.upload_bytes >> 20,
            extensions: SCAN_EXTENSIONS,
        },
    )
}

async fn page(state: web::Data<AppState>, auth: PageAuth) -> Result<HttpResponse, PageError> {
    auth.require(Role::Admin)?;
    jobs_page(
        &state,
        &auth,
        StatusCode::OK,
        String::new(),
        Kept::default(),
    )
    .await
}

/// The upload form as read.
struct UploadForm {
    files: Vec<ReceivedFile>,
    /// The text fields.
    kept: Kept,
    /// An existing model to give the scan (a retry).
    model: Option<i64>,
}

/// Reads the upload form: text fields (`csrf_token` first, `title`, `description`, or
/// `model` for a retry) and the files, streamed to `uploads/`.
async fn receive_form(
    state: &AppState,
    auth: &PageAuth,
    form: Multipart,
) -> Result<UploadForm, (ApiError, Kept)> {
    let mut fields = TextFields::new();
    let read = read_form(state, auth, form, &mut fields).await;
    let mut take = |name: &str| fields.remove(name).unwrap_or_default();
    let kept = Kept {
        title: take("title"),
        description: take("description"),
        build: BuildFields {
            simplifier: take("simplifier"),
            patch_triangles: take("patch_triangles"),
            texture_quality: take("texture_quality"),
            texture_spread: take("texture_spread"),
            normal_maps: take("normal_maps"),
            vertex_order: take("vertex_order"),
        },
    };
    match read {
        Ok((files, model)) => Ok(UploadForm { files, kept, model }),
        Err(e) => Err((e, kept)),
    }
}

/// [`receive_form`]'s reading: the text fields into `fields`, the files (one scan and the
/// files it refers to: a glTF's `.bin` and textures, an OBJ's MTL and images, picked together
/// or as their folder; or one `.zip` of them) and the model id.
async fn read_form(
    state: &AppState,
    auth: &PageAuth,
    mut form: Multipart,
    fields: &mut TextFields,
) -> Result<(Vec<ReceivedFile>, Option<i64>), ApiError> {
    let limit = state.settings.build.upload_bytes;
    let dir = state.settings.uploads_dir();
    let mut files: Vec<ReceivedFile> = Vec::new();
    let mut total = 0u64;
    while let Some(field) = form.next().await {
        let mut field = field.map_err(multipart_error)?;
        let name = field.name().unwrap_or("").to_string();
        let filename = field
            .content_disposition()
            .and_then(|cd| cd.get_filename())
            .map(str::to_string);
        if name == "file" {
            let sent = fields.get("csrf_token").unwrap_or("");
            if !crate::web::auth::constant_time_eq(sent, auth.csrf()) {
                return Err(ApiError::Forbidden(
                    "missing or invalid CSRF token: reload the page and try again".into(),
                ));
            }
            let filename = filename.unwrap_or_default();
            if filename.is_empty() {
                // An empty file input (e.g. the folder picker left unused).
                while let Some(chunk) = field.next().await {
                    chunk.map_err(multipart_error)?;
                }
                continue;
            }
            if files.len() == MAX_SCAN_FILES {
                return Err(ApiError::bad(format!(
                    "upload at most {MAX_SCAN_FILES} files: the scan and the files it refers to"
                )));
            }
            let relative = companion_path(&filename).ok_or_else(|| {
                ApiError::bad(format!(
                    "{:?} is not a plain file name",
                    crate::web::attachments::sanitize_name(&filename)
                ))
            })?;
            let stream = (&mut field).map(|c| c.map_err(multipart_error));
            let left = limit.saturating_sub(total);
            let spooled = crate::web::multipart::spool(&dir, stream, left, false, || {
                crate::web::jobs::too_large(limit)
            })
            .await?;
            total += spooled.bytes;
            files.push(ReceivedFile {
                relative,
                temp: spooled.temp,
                bytes: spooled.bytes,
            });
        } else {
            fields.read(name, &mut field, 64 * 1024).await?;
        }
    }
    if files.is_empty() {
        return Err(ApiError::bad("choose a scan file to upload"));
    }
    let model = match fields.get("model").map(str::trim).filter(|m| !m.is_empty()) {
        Some(m) => Some(
            m.parse::<i64>()
                .map_err(|_| ApiError::bad(format!("{m:?} is not a model id")))?,
        ),
        None => None,
    };
    Ok((files, model))
}

async fn page_upload(
    state: web::Data<AppState>,
    auth: PageAuth,
    req: HttpRequest,
    form: Multipart,
) -> Result<HttpResponse, PageError> {
    auth.require(Role::Admin)?;
    crate::web::auth::check_origin(&req)?;
    let form = match receive_form(&state, &auth, form).await {
        Ok(r) => r,
        Err((e @ ApiError::Forbidden(_), _)) => return Err(e.into()),
        Err((e, kept)) => {
            return jobs_page(&state, &auth, e.status_code(), e.message(), kept).await;
        }
    };
    let UploadForm { files, kept, model } = form;
    // What the person typed comes back with an error, so a refused upload loses nothing.
    let build = match kept.build.choices() {
        Ok(b) => b,
        Err(e) => {
            drop(files);
            return jobs_page(&state, &auth, e.status_code(), e.message(), kept).await;
        }
    };
    let target = match model {
        Some(id) => ScanFor::Existing(id),
        None => match check_title(&kept.title, state.settings.limits.title_chars) {
            Ok(title) => ScanFor::New {
                title,
                description: kept.description.clone(),
            },
            Err(e) => {
                drop(files);
                return jobs_page(&state, &auth, StatusCode::BAD_REQUEST, e.message(), kept).await;
            }
        },
    };
    match state.submit_scan(files, target, &build, auth.id()).await {
        Ok((model, _job)) => Ok(redirect(&format!("/models/{}", model.id))),
        Err(e) => {
            let e = ApiError::from(e);
            jobs_page(&state, &auth, e.status_code(), e.message(), kept).await
        }
    }
}

async fn page_delete_model(
    state: web::Data<AppState>,
    id: web::Path<i64>,
    post: PageForm<CsrfOnly>,
) -> Result<HttpResponse, PageError> {
    post.auth.require(Role::Admin)?;
    state.delete_model(post.auth.id(), *id).await?;
    Ok(redirect("/admin/jobs"))
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
