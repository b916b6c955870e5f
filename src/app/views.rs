//! Best views and thumbnails of parts (system paper §2.2: search results and links jump to a
//! region, shown framed and unoccluded).
//!
//! A background task keeps every part of a ready model with a camera and a thumbnail:
//!
//! * a part without a camera gets its best view: from its vertices' centre, mean normal and
//!   extent ([`best_view::part_geometry`]), the engine's [`best_view::best_view`] picks the
//!   direction that sees most of the part unoccluded; it is stored with `auto: true`. A point
//!   part without vertices is framed from the model's centre through the point. Cameras given
//!   by clients are kept (see `store::parts::Camera`);
//! * a part without a thumbnail gets one: its camera at 320×240, the part tinted, stored as
//!   an attachment (`thumbnail_attachment_id`) through [`crate::render::thumbnail_png`], the code path
//!   of model thumbnails too.
//!
//! Work arrives from the change events (a part created or changed, by any route), from
//! finished builds (the parts of a model that just became ready) and, at start-up, from a
//! sweep of the database, so nothing is lost to a restart. The result is written only if the
//! part's vertex set is unchanged, and announced as `part.updated`. Parts run one at a time
//! as background work of the render pool. A part whose views failed is retried once it
//! changes (or at the next start).

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::{Arc, Mutex};

use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::render::best_view::{self, BestViewOptions};
use meshwiki_engine::render::highlight::TINTS;
use meshwiki_engine::render::{Highlight, RenderModel};
use roaring::RoaringBitmap;
use tokio::sync::{Notify, broadcast};

use super::App;
use super::events::{Event, EventKind, Events};
use super::models::{ModelRegistry, Purpose};
use crate::config::Settings;
use crate::jobs::JobEvent;
use crate::render::{RenderService, RenderServiceError, thumbnail_bytes, thumbnail_png};
use crate::store::attachments::{self, NewAttachment};
use crate::store::jobs::JobStatus;
use crate::store::parts::{self, Part};
use crate::store::{Db, StoreError};

/// Size of part thumbnails (as model thumbnails).
pub const THUMB_WIDTH: u32 = crate::jobs::thumbnail::WIDTH;
/// Height of part thumbnails.
pub const THUMB_HEIGHT: u32 = crate::jobs::thumbnail::HEIGHT;
/// Memory reserved for the work on one part besides its thumbnail (probes, geometry).
const WORK_BYTES: u64 = 48 << 20;

/// Why a part got no view.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// The database failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// Rendering failed.
    #[error(transparent)]
    Render(#[from] RenderServiceError),
    /// The model could not be opened.
    #[error(transparent)]
    Model(#[from] super::AppError),
    /// The thumbnail could not be stored.
    #[error("cannot store the thumbnail: {0}")]
    Io(#[from] std::io::Error),
}

/// The engine camera of a stored camera, at `width`×`height`.
pub fn engine_camera(c: &parts::Camera, width: u32, height: u32) -> Camera {
    let v = |a: [f64; 3]| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
    Camera {
        eye: v(c.eye),
        target: v(c.target),
        up: v(c.up),
        fovy_deg: c.fovy as f32,
        width,
        height,
    }
}

/// The stored camera of an engine camera (`auto`: computed by the server).
pub fn stored_camera(c: &Camera, auto: bool) -> parts::Camera {
    let v = |a: Vec3| [a.x as f64, a.y as f64, a.z as f64];
    parts::Camera {
        eye: v(c.eye),
        target: v(c.target),
        up: v(c.up),
        fovy: c.fovy_deg as f64,
        auto,
    }
}

/// What one part needs.
struct Job {
    part: Part,
    blob: Option<Vec<u8>>,
}

/// What the render thread returns.
struct Done {
    camera: Option<Camera>,
    png: Option<Vec<u8>>,
    score: Option<f32>,
}

/// Computes the best view of `set` on `model` (a framing of the point for empty sets).
pub fn compute_best_view(
    renderer: &meshwiki_engine::render::Renderer,
    model: &RenderModel,
    set: &RoaringBitmap,
    center: [f64; 3],
) -> Result<(Camera, Option<f32>), RenderServiceError> {
    let opts = BestViewOptions {
        width: THUMB_WIDTH * 2,
        height: THUMB_HEIGHT * 2,
        ..BestViewOptions::default()
    };
    let geometry = if set.is_empty() {
        None
    } else {
        best_view::part_geometry(model.lod(), set)
            .map_err(|e| RenderServiceError::Lod(e.to_string()))?
    };
    match geometry {
        Some(g) => {
            let view = best_view::best_view(renderer, model, set, &g, &opts)?;
            Ok((view.camera, Some(view.score)))
        }
        None => {
            let p = Vec3::new(center[0] as f32, center[1] as f32, center[2] as f32);
            let p = if p.is_finite() { p } else { model.center() };
            let out = p - model.center();
            let dir = if out.length() > model.radius() * 1e-3 {
                out.normalize()
            } else {
                Vec3::new(0.3, 0.4, 1.0).normalize()
            };
            let cam = best_view::framing_camera(
                p,
                dir,
                model.radius() * 0.12,
                &opts,
                opts.width,
                opts.height,
            );
            Ok((cam, None))
        }
    }
}

/// The background task (see the module documentation).
pub struct PartViews {
    db: Db,
    settings: Arc<Settings>,
    service: RenderService,
    models: ModelRegistry,
    events: Events,
    queue: Mutex<(VecDeque<i64>, HashSet<i64>)>,
    wake: Notify,
    /// Parts whose views failed, with their `updated_at` then.
    failed: Mutex<HashMap<i64, String>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl PartViews {
    /// Starts the task: the start-up sweep, then the event subscriptions. Does nothing but
    /// log when rendering is unavailable.
    pub fn start(app: &App) -> Option<Arc<PartViews>> {
        if !app.render.available() {
            tracing::warn!("parts get no best views or thumbnails: rendering is unavailable");
            return None;
        }
        let me = Arc::new(PartViews {
            db: app.db.clone(),
            settings: app.settings.clone(),
            service: app.render.clone(),
            models: app.models.clone(),
            events: app.events.clone(),
            queue: Mutex::new((VecDeque::new(), HashSet::new())),
            wake: Notify::new(),
            failed: Mutex::new(HashMap::new()),
        });
        let changes = app.events.subscribe();
        let builds = app.jobs.subscribe();
        tokio::spawn(me.clone().listen(changes, builds));
        tokio::spawn(me.clone().work());
        Some(me)
    }

    /// Queues part `id` (once).
    pub fn enqueue(&self, id: i64) {
        let mut q = lock(&self.queue);
        if q.1.insert(id) {
            q.0.push_back(id);
            self.wake.notify_one();
        }
    }

    async fn sweep(&self, model_id: Option<i64>) {
        match parts::needing_views(&self.db, model_id).await {
            Ok(ids) => {
                if !ids.is_empty() {
                    tracing::info!(parts = ids.len(), model = ?model_id, "parts queued for best views and thumbnails");
                }
                for id in ids {
                    self.enqueue(id);
                }
            }
            Err(e) => tracing::warn!(error = %e, "cannot list parts needing views"),
        }
    }

    async fn listen(
        self: Arc<Self>,
        mut changes: broadcast::Receiver<Event>,
        mut builds: broadcast::Receiver<JobEvent>,
    ) {
        self.sweep(None).await;
        loop {
            tokio::select! {
                e = changes.recv() => match e {
                    Ok(Event { kind: EventKind::PartCreated | EventKind::PartUpdated, part_id: Some(id), .. }) => self.enqueue(id),
                    Ok(_) => {}
                    Err(broadcast::error::RecvError::Lagged(_)) => self.sweep(None).await,
                    Err(broadcast::error::RecvError::Closed) => break,
                },
                j = builds.recv() => match j {
                    Ok(JobEvent { status: JobStatus::Done, model_id: Some(m), .. }) => {
                        self.sweep(Some(m)).await;
                    }
                    Ok(_) => {}
                    Err(broadcast::error::RecvError::Lagged(_)) => self.sweep(None).await,
                    Err(broadcast::error::RecvError::Closed) => break,
                },
            }
        }
    }

    async fn work(self: Arc<Self>) {
        loop {
            let next = {
                let mut q = lock(&self.queue);
                let id = q.0.pop_front();
                if let Some(id) = id {
                    q.1.remove(&id);
                }
                id
            };
            let Some(id) = next else {
                self.wake.notified().await;
                continue;
            };
            match self.process(id).await {
                Ok(()) => {}
                Err(e) => tracing::warn!(part = id, error = %e, "no best view or thumbnail"),
            }
        }
    }

    /// Loads what part `id` needs, or `None` when it needs nothing (or cannot be done now).
    async fn prepare(&self, id: i64) -> Result<Option<Job>, ViewError> {
        let part = match parts::get(&self.db, id).await {
            Ok(p) => p,
            Err(StoreError::NotFound(_)) => return Ok(None),
            Err(e) => return Err(e.into()),
        };
        if part.camera.is_some() && part.thumbnail_attachment_id.is_some() {
            return Ok(None);
        }
        if lock(&self.failed).get(&id) == Some(&part.updated_at) {
            return Ok(None);
        }
        match self
            .models
            .ready_path(&self.db, part.model_id, Purpose::Render)
            .await
        {
            Ok(_) => {}
            // Done when the model's build ends.
            Err(super::AppError::Conflict(_)) => return Ok(None),
            Err(e) => return Err(e.into()),
        }
        let blob = parts::vertex_set_raw(&self.db, id).await?;
        Ok(Some(Job { part, blob }))
    }

    async fn process(&self, id: i64) -> Result<(), ViewError> {
        let Some(job) = self.prepare(id).await? else {
            return Ok(());
        };
        let updated_at = job.part.updated_at.clone();
        let result = self.render(&job).await;
        let done = match result {
            Ok(d) => d,
            Err(e) => {
                lock(&self.failed).insert(id, updated_at);
                return Err(e);
            }
        };
        lock(&self.failed).remove(&id);
        let thumbnail = match done.png {
            Some(png) => {
                let settings = self.settings.clone();
                let size = png.len() as i64;
                let sha256 =
                    tokio::task::spawn_blocking(move || crate::blobs::write_bytes(&settings, &png))
                        .await
                        .map_err(|e| std::io::Error::other(e.to_string()))??;
                let new = NewAttachment {
                    sha256,
                    media_type: "image/png".into(),
                    size,
                    original_name: format!("part-{id}-thumbnail.png"),
                };
                Some(
                    attachments::create(&self.db, &new, None, job.part.created_by)
                        .await?
                        .id,
                )
            }
            None => None,
        };
        let camera = done.camera.map(|c| stored_camera(&c, true));
        let written = parts::set_generated_view(
            &self.db,
            id,
            camera.as_ref(),
            thumbnail,
            job.blob.as_deref(),
        )
        .await?;
        if written {
            tracing::info!(
                part = id,
                model = job.part.model_id,
                best_view = camera.is_some(),
                score = ?done.score,
                thumbnail = ?thumbnail,
                "part views stored"
            );
            self.events
                .publish(Event::part(EventKind::PartUpdated, job.part.model_id, id));
        } else {
            tracing::debug!(part = id, "part changed meanwhile: views dropped");
        }
        Ok(())
    }

    async fn render(&self, job: &Job) -> Result<Done, ViewError> {
        let set = parts::parse_vertex_set(job.blob.as_deref())?;
        let model = self
            .models
            .open(&self.db, job.part.model_id, Purpose::Render)
            .await?
            .render
            .clone();
        let ticket = self
            .service
            .admit_background(WORK_BYTES + thumbnail_bytes(THUMB_WIDTH, THUMB_HEIGHT))
            .await?;
        let stored = job.part.camera;
        let want_thumbnail = job.part.thumbnail_attachment_id.is_none();
        let center = job.part.center;
        let (result, _memory) = self
            .service
            .run(ticket, move |r| -> Result<Done, RenderServiceError> {
                let (camera, score) = match stored {
                    Some(c) => (engine_camera(&c, THUMB_WIDTH * 2, THUMB_HEIGHT * 2), None),
                    None => compute_best_view(r, &model, &set, center)?,
                };
                let png = if want_thumbnail {
                    let thumb = Camera {
                        width: THUMB_WIDTH,
                        height: THUMB_HEIGHT,
                        ..camera
                    };
                    let marks = [Highlight {
                        vertices: &set,
                        tint: Some(TINTS[0]),
                        outline: false,
                    }];
                    let marks: &[Highlight] = if set.is_empty() { &[] } else { &marks };
                    Some(thumbnail_png(r, &model, &thumb, marks)?)
                } else {
                    None
                };
                Ok(Done {
                    camera: stored.is_none().then_some(camera),
                    png,
                    score,
                })
            })
            .await?;
        Ok(result?)
    }
}
