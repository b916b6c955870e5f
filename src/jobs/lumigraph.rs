//! Building a model's Grid-Lumigraph image repository (system paper §5.2.2) as a background
//! job: grid point by grid point, the six images are rendered by the process's render service
//! as background work of its pool (`meshwiki_engine::lumigraph::sample_point`), stored under
//! their SHA-256 (`crate::blobs`, bucket `lumigraph`) and recorded in one transaction per
//! point (`store::lumigraph::record_point`). Progress counts points; a cancellation stops at
//! the next point; a shutdown or a crash leaves the recorded points, and the job, queued again,
//! resumes after them. The end prints the cost: images, empty ones, bytes, seconds.

use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;
use meshwiki_engine::lod::LodFile;
use meshwiki_engine::lumigraph::image::Quality;
use meshwiki_engine::lumigraph::sample::{self, PointImages};
use meshwiki_engine::lumigraph::{Grid, grid};
use meshwiki_engine::progress::Progress;
use meshwiki_engine::render::RenderModel;

use super::progress::LUMIGRAPH_STAGE;
use super::{JobEnd, JobError, JobProgress, Jobs, plain_relative};
use crate::blobs::{self, Bucket};
use crate::render::RenderService;
use crate::store::jobs::{self as store_jobs, Job, JobStatus};
use crate::store::lumigraph::{self, Entry, Lumigraph};
use crate::store::models;

/// Grid points per axis of a repository when the request names none: a few minutes for a
/// 1M-triangle scan on the software adapter (GPUs take 16 or 32, as in the paper).
pub const DEFAULT_GRID: u32 = 6;
/// Image side when the request names none (the paper's).
pub const DEFAULT_SIZE: u32 = 512;
/// How finely the albedo and normal images are coded (`lumigraph::image::Quality`).
pub const QUALITY: Quality = Quality {
    albedo: 80,
    normal_steps: [8, 24],
};

/// Pixels a repository may hold in all (images × side²): the paper's largest grid, 32³ points
/// of 512² images, fits; 64³ points of 512² images do not.
pub const MAX_PIXELS: u64 = 1 << 36;

/// Checks a requested grid: points per axis and image side within the engine's bounds, and
/// the whole repository within [`MAX_PIXELS`].
pub fn check_request(grid: u32, size: u32) -> Result<(), JobError> {
    grid::check_shape(grid, size).map_err(|e| JobError::Invalid(e.to_string()))?;
    let images = (grid as u64).pow(3) * 6;
    if images * (size as u64).pow(2) > MAX_PIXELS {
        return Err(JobError::Invalid(format!(
            "a repository of {images} images of {size}x{size} pixels is larger than this server \
             builds ({} gigapixels at most): use fewer grid points or smaller images",
            MAX_PIXELS >> 30
        )));
    }
    Ok(())
}

impl Jobs {
    /// Queues the build of model `model_id`'s image repository (`grid` points per axis,
    /// `size`-pixel images), replacing the one it has; the replaced images' files go once no
    /// other repository uses them.
    pub async fn submit_lumigraph(
        &self,
        model_id: i64,
        grid: u32,
        size: u32,
        user_id: i64,
    ) -> Result<(Lumigraph, Job), JobError> {
        check_request(grid, size)?;
        let db = &self.inner.db;
        let (repo, job, old) = lumigraph::start(db, model_id, grid, size, user_id).await?;
        self.remove_unused_images(old).await;
        tracing::info!(
            job = job.id,
            model = model_id,
            grid,
            size,
            "image repository queued"
        );
        self.emit(&job);
        self.wake();
        Ok((repo, job))
    }

    /// Removes the image files among `shas` that no repository uses any more.
    pub async fn remove_unused_images(&self, shas: Vec<String>) {
        if shas.is_empty() {
            return;
        }
        let used = match lumigraph::used_blobs(&self.inner.db).await {
            Ok(u) => u,
            Err(e) => {
                tracing::warn!(error = %e, "cannot list the repository images in use");
                return;
            }
        };
        let gone: Vec<String> = shas.into_iter().filter(|s| !used.contains(s)).collect();
        let settings = self.inner.settings.clone();
        let _ =
            tokio::task::spawn_blocking(move || blobs::remove(&settings, Bucket::Lumigraph, &gone))
                .await;
    }

    /// Runs a claimed lumigraph job (see the module's documentation).
    pub(super) async fn build_lumigraph(
        &self,
        job: &Job,
        progress: &Arc<JobProgress>,
    ) -> Result<JobEnd, JobError> {
        let db = &self.inner.db;
        let fail = |msg: String| async move {
            store_jobs::finish_failed(db, job.id, JobStatus::Failed, &msg).await?;
            Ok::<_, JobError>(JobEnd::Failed(msg))
        };
        let Some(model_id) = job.model_id else {
            store_jobs::finish_failed(db, job.id, JobStatus::Cancelled, "the model was deleted")
                .await?;
            return Ok(JobEnd::Cancelled);
        };
        let (Some(points), Some(size)) = (job.options.grid, job.options.size) else {
            return fail("the job names no grid".into()).await;
        };
        let model = models::get(db, model_id).await?;
        let Some(path) = model
            .lod_path
            .as_deref()
            .and_then(plain_relative)
            .map(|p| self.inner.settings.data_dir.join(p))
        else {
            return fail(format!("model {model_id} has no LOD file")).await;
        };
        let service = RenderService::shared(&self.inner.settings.render);
        if let Err(e) = service.renderer() {
            return fail(e.to_string()).await;
        }
        // The hierarchy alone: images need no surface segments (those serve selection).
        let opened = tokio::task::spawn_blocking(move || {
            LodFile::open(&path).map(|lod| RenderModel::new(Arc::new(lod)))
        })
        .await
        .map_err(|e| JobError::Invalid(e.to_string()))?;
        let render_model = match opened {
            Ok(m) => Arc::new(m),
            Err(e) => return fail(format!("cannot open the model's LOD file: {e}")).await,
        };
        let lod = render_model.lod();
        let h = lod.header();
        let with_albedo = lod.has_colors() || lod.has_texture();
        let grid = match Grid::new(Vec3::from(h.bbox_min), Vec3::from(h.bbox_max), points, size) {
            Ok(g) => g,
            Err(e) => return fail(e.to_string()).await,
        };
        let recorded: HashSet<[u32; 3]> = lumigraph::recorded_points(db, model_id)
            .await?
            .into_iter()
            .collect();
        progress.stage(LUMIGRAPH_STAGE, grid.point_count());
        progress.advance(recorded.len() as u64);
        if !recorded.is_empty() {
            tracing::info!(
                job = job.id,
                points = recorded.len(),
                "image repository resumed after the points already recorded"
            );
        }
        let started = Instant::now();
        let bytes = sample::frame_bytes(&grid);
        let mut end = None;
        for key in grid.keys() {
            if recorded.contains(&key) {
                continue;
            }
            if progress.is_cancelled() {
                end = Some(if self.shutting_down() {
                    store_jobs::requeue(db, job.id).await?;
                    JobEnd::Requeued
                } else {
                    store_jobs::finish_failed(
                        db,
                        job.id,
                        JobStatus::Cancelled,
                        "image repository build cancelled",
                    )
                    .await?;
                    JobEnd::Cancelled
                });
                break;
            }
            let t = Instant::now();
            let ticket = match service.admit_background(bytes).await {
                Ok(t) => t,
                Err(e) => {
                    end = Some(fail(e.to_string()).await?);
                    break;
                }
            };
            let (m, g, settings) = (render_model.clone(), grid, self.inner.settings.clone());
            let sampled = service
                .run(ticket, move |r| -> Result<[Entry; 6], String> {
                    let images = sample::sample_point(r, &m, &g, key, with_albedo, QUALITY)
                        .map_err(|e| e.to_string())?;
                    let PointImages::Images(images) = images else {
                        return Ok(std::array::from_fn(|_| Entry::Inside));
                    };
                    let mut entries: [Entry; 6] = std::array::from_fn(|_| Entry::Empty);
                    for (e, image) in entries.iter_mut().zip(images) {
                        if let Some(bytes) = image {
                            let sha256 =
                                blobs::write_bytes_to(&settings, Bucket::Lumigraph, &bytes)
                                    .map_err(|e| format!("cannot store an image: {e}"))?;
                            *e = Entry::Image {
                                sha256,
                                bytes: bytes.len() as i64,
                            };
                        }
                    }
                    Ok(entries)
                })
                .await;
            let entries = match sampled {
                Ok((Ok(entries), _)) => entries,
                Ok((Err(msg), _)) => {
                    end = Some(fail(format!("rendering grid point {key:?} failed: {msg}")).await?);
                    break;
                }
                Err(e) => {
                    end = Some(fail(e.to_string()).await?);
                    break;
                }
            };
            let secs = t.elapsed().as_secs_f64();
            if !lumigraph::record_point(db, model_id, job.id, key, &entries, secs).await? {
                // Another build replaced this one (the model was rebuilt or deleted).
                store_jobs::finish_failed(
                    db,
                    job.id,
                    JobStatus::Cancelled,
                    "replaced by another image repository build",
                )
                .await?;
                end = Some(JobEnd::Cancelled);
                break;
            }
            progress.advance(1);
        }
        if let Ok(r) = service.renderer() {
            r.forget(&render_model);
        }
        if let Some(end) = end {
            return Ok(end);
        }
        let counts = lumigraph::counts(db, model_id).await?;
        let seconds = lumigraph::get(db, model_id)
            .await?
            .map(|l| l.seconds)
            .unwrap_or_default();
        let report = serde_json::json!({
            "grid": points,
            "size": size,
            "points": counts.points,
            "images": counts.images,
            "empty": counts.empty,
            "inside_points": counts.inside_points,
            "bytes": counts.bytes,
            "seconds": seconds,
            "this_run_seconds": started.elapsed().as_secs_f64(),
        });
        lumigraph::finish(db, model_id, job.id, &report).await?;
        tracing::info!(
            job = job.id,
            model = model_id,
            images = counts.images,
            empty = counts.empty,
            inside_points = counts.inside_points,
            mb = counts.bytes as f64 / 1e6,
            seconds,
            "image repository built"
        );
        Ok(JobEnd::Rendered(report))
    }
}
