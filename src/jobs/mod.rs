//! Background jobs: LOD builds of uploaded scans, of the demo relief, and (run in their own
//! process) of `meshwiki import`.
//!
//! * A job is created `queued` with its model (`pending`) in one transaction
//!   ([`Jobs::submit_upload`], [`Jobs::submit_demo`]). Workers (one by default,
//!   `BuildSettings::workers`) claim the oldest queued job and build it on a blocking thread
//!   ([`meshwiki_engine::lod::build_file`]) into `models/<model id>.mwlod`, written under a
//!   temporary name and renamed when complete.
//! * Progress goes through [`JobProgress`] (atomics) and a ticker task that writes it to the
//!   database a few times a second and reads back cancellation requests, so cancelling works
//!   from any process ([`Jobs::cancel`]).
//! * The end is one transaction: job `done` and model `ready` with its statistics and
//!   thumbnail, or job `failed`/`cancelled` and model `failed` with the message. Uploaded
//!   inputs are removed once their job ends; the engine removes its scratch on every error.
//! * On start ([`Jobs::start`]) jobs left `running` by a crash are queued again and what a
//!   killed build left behind (`models/.<name>.build-<pid>`, `models/*.tmp-<pid>`, unclaimed
//!   uploads) is removed. On shutdown running builds are stopped and queued again.

pub mod archive;
pub mod lumigraph;
pub mod progress;
pub mod thumbnail;

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use meshwiki_engine::lod::{
    BuildError, BuildOptions, BuildReport, LodFile, VertexOrder, build_from,
};
use meshwiki_engine::mesh::{
    ImportError, ImportErrorKind, MeshSink, SourceInfo, SourceTexture, TexturedFace, VertexBatch,
    synth,
};
use meshwiki_engine::progress::Progress;
use serde::Serialize;
use tokio::sync::{Notify, broadcast};

pub use progress::JobProgress;

use crate::config::Settings;
use crate::search::SearchIndex;
use crate::store::attachments::{self, NewAttachment};
use crate::store::jobs::{
    self, BuiltModel, CancelOutcome, Job, JobKind, JobOptions, JobStatus, NewJob,
};
use crate::store::models::{BBox, Model, NewModel};
use crate::store::{Db, StoreError};

/// How often a running job's progress is written to the database.
const TICK: Duration = Duration::from_millis(400);
/// How long an idle worker waits before looking at the queue again.
const IDLE_POLL: Duration = Duration::from_secs(5);
/// How long shutdown waits for running builds to stop.
const SHUTDOWN_WAIT: Duration = Duration::from_secs(30);

/// Errors of the job runner.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// The database failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// A file operation failed.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// Invalid input.
    #[error("{0}")]
    Invalid(String),
    /// Input larger than allowed.
    #[error("{0}")]
    TooLarge(String),
}

/// A change of a job, for live displays (`Jobs::subscribe`).
#[derive(Debug, Clone, Serialize)]
pub struct JobEvent {
    /// Job id.
    pub id: i64,
    /// Its model.
    pub model_id: Option<i64>,
    /// State.
    pub status: JobStatus,
    /// Stage.
    pub stage: String,
    /// Units of the stage done.
    pub done: i64,
    /// Units of the stage in all.
    pub total: i64,
    /// Estimate of the whole job, 0–100.
    pub percent: f64,
    /// Error or status message.
    pub message: Option<String>,
}

impl From<&Job> for JobEvent {
    fn from(j: &Job) -> JobEvent {
        JobEvent {
            id: j.id,
            model_id: j.model_id,
            status: j.status,
            stage: j.stage.clone(),
            done: j.done,
            total: j.total,
            percent: j.percent,
            message: j.message.clone(),
        }
    }
}

/// How a job ended.
#[derive(Debug, Clone)]
pub enum JobEnd {
    /// Built; the model is ready.
    Done(Box<BuildReport>),
    /// Failed with this message.
    Failed(String),
    /// Cancelled.
    Cancelled,
    /// Stopped by a shutdown and queued again.
    Requeued,
    /// An image repository was built; its report.
    Rendered(serde_json::Value),
}

/// What a build reads.
#[derive(Debug, Clone)]
pub enum Source {
    /// A scan file (format from its extension).
    File(PathBuf),
    /// The generated demo relief of about this many triangles.
    Demo(u64),
}

/// The job runner, shared by the server (workers) and `meshwiki import` (one job run in place).
#[derive(Clone)]
pub struct Jobs {
    inner: Arc<Inner>,
}

struct Inner {
    db: Db,
    settings: Arc<Settings>,
    search: Option<SearchIndex>,
    wake: Notify,
    /// Wakes the upload sweeper early (shutdown).
    wake_sweeper: Notify,
    running: Mutex<HashMap<i64, Arc<JobProgress>>>,
    shutdown: AtomicBool,
    workers: Mutex<Vec<tokio::task::JoinHandle<()>>>,
    events: broadcast::Sender<JobEvent>,
}

impl std::fmt::Debug for Jobs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Jobs")
            .field("running", &self.running_ids())
            .finish()
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Whether process `pid` is a live meshwiki process: this one, or (Linux) one whose
/// `/proc/<pid>/comm` is this program's name (so a recycled pid is not taken for a build).
/// Elsewhere only this process counts.
pub fn process_alive(pid: i64) -> bool {
    if pid == std::process::id() as i64 {
        return true;
    }
    if !cfg!(target_os = "linux") || pid <= 0 {
        return false;
    }
    let comm = |p: &Path| std::fs::read_to_string(p.join("comm")).ok();
    match (
        comm(&Path::new("/proc").join(pid.to_string())),
        comm(Path::new("/proc/self")),
    ) {
        (Some(other), Some(me)) => other == me,
        _ => false,
    }
}

/// Parses a byte size: `1073741824`, `512M`, `1G`, `1.5GiB`, `800MB` (binary units).
pub fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let value: f64 = num
        .parse()
        .map_err(|_| format!("invalid size {s:?}: expected e.g. 512M or 1G"))?;
    let mult: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "k" | "kb" | "kib" => 1 << 10,
        "m" | "mb" | "mib" => 1 << 20,
        "g" | "gb" | "gib" => 1 << 30,
        "t" | "tb" | "tib" => 1 << 40,
        other => return Err(format!("invalid size unit {other:?} in {s:?}")),
    };
    let bytes = value * mult as f64;
    if !bytes.is_finite() || bytes < 1.0 || bytes > u64::MAX as f64 / 2.0 {
        return Err(format!("size {s:?} out of range"));
    }
    Ok(bytes as u64)
}

/// The extension of an uploaded file name, if it names a format the importer reads.
/// The name is used for nothing else.
pub fn scan_extension(file_name: &str) -> Option<String> {
    let last = file_name.rsplit(['/', '\\']).next().unwrap_or("");
    let ext = Path::new(last).extension()?.to_str()?.to_ascii_lowercase();
    meshwiki_engine::mesh::Format::from_path(Path::new(&format!("x.{ext}")))?;
    Some(ext)
}

/// File extensions the importer reads.
pub const SCAN_EXTENSIONS: &str = ".ply, .obj, .gltf, .glb, .stl or .off";

/// A finished build: the engine's report and the exact bounds of the input.
#[derive(Debug, Clone)]
pub struct Built {
    /// The engine's report.
    pub report: BuildReport,
    /// Smallest input coordinates.
    pub bbox_min: [f32; 3],
    /// Largest input coordinates.
    pub bbox_max: [f32; 3],
}

/// Builds the LOD file of `source` at `output` (temporary name, renamed when complete).
pub fn run_build(
    source: &Source,
    output: &Path,
    options: &BuildOptions,
    progress: &dyn Progress,
) -> Result<Built, BuildError> {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    let report = match source {
        Source::File(path) => build_from(
            |sink| {
                let mut s = InputSink {
                    sink,
                    progress,
                    count: false,
                    lo: &mut lo,
                    hi: &mut hi,
                };
                meshwiki_engine::mesh::import(path, &mut s, progress)
            },
            output,
            options,
            progress,
        )?,
        Source::Demo(triangles) => {
            let relief = synth::Relief::new(*triangles, synth::DEFAULT_SEED);
            let stats = relief.stats(false);
            build_from(
                |sink| {
                    progress.stage(progress::GENERATE_STAGE, relief.triangle_count());
                    let mut s = InputSink {
                        sink,
                        progress,
                        count: true,
                        lo: &mut lo,
                        hi: &mut hi,
                    };
                    relief.stream(&mut s)?;
                    Ok(stats)
                },
                output,
                options,
                progress,
            )?
        }
    };
    if lo.iter().any(|v| !v.is_finite()) {
        (lo, hi) = (report.bbox_min, report.bbox_max);
    }
    Ok(Built {
        report,
        bbox_min: lo,
        bbox_max: hi,
    })
}

/// Passes the input on to the builder, keeping its exact bounds; with `count`, reports
/// triangles as progress and stops when cancelled (readers do that themselves).
struct InputSink<'a> {
    sink: &'a mut dyn MeshSink,
    progress: &'a dyn Progress,
    count: bool,
    lo: &'a mut [f32; 3],
    hi: &'a mut [f32; 3],
}

impl MeshSink for InputSink<'_> {
    fn begin(&mut self, info: &SourceInfo) -> Result<(), ImportError> {
        self.sink.begin(info)
    }

    fn vertices(&mut self, batch: VertexBatch<'_>) -> Result<(), ImportError> {
        for p in batch.positions {
            for (k, &c) in p.iter().enumerate() {
                self.lo[k] = self.lo[k].min(c);
                self.hi[k] = self.hi[k].max(c);
            }
        }
        self.sink.vertices(batch)
    }

    fn triangles(&mut self, triangles: &[[u32; 3]]) -> Result<(), ImportError> {
        self.counted(triangles.len())?;
        self.sink.triangles(triangles)
    }

    // Textured scans: the textures and the corners' coordinates go on to the build (without
    // these two, the defaults dropped them and every upload built with vertex colours only).
    fn texture(&mut self, texture: SourceTexture) -> Result<(), ImportError> {
        self.sink.texture(texture)
    }

    fn textured_triangles(
        &mut self,
        triangles: &[[u32; 3]],
        faces: &[TexturedFace],
    ) -> Result<(), ImportError> {
        self.counted(triangles.len())?;
        self.sink.textured_triangles(triangles, faces)
    }
}

impl InputSink<'_> {
    /// Counts generated triangles (demo jobs) and stops when the job is cancelled.
    fn counted(&mut self, triangles: usize) -> Result<(), ImportError> {
        if !self.count {
            return Ok(());
        }
        if self.progress.cancelled() {
            return Err(ImportError::new(
                Path::new("demo relief"),
                meshwiki_engine::mesh::Location::File,
                ImportErrorKind::Cancelled,
            ));
        }
        self.progress.advance(triangles as u64);
        Ok(())
    }
}

/// `models/<id>.mwlod`, relative to the data directory.
pub fn lod_relative_path(model_id: i64) -> String {
    format!("models/{model_id}.mwlod")
}

/// A path relative to the data directory made only of plain components.
fn plain_relative(rel: &str) -> Option<&Path> {
    let p = Path::new(rel);
    (p.components().count() >= 2 && p.components().all(|c| matches!(c, Component::Normal(_))))
        .then_some(p)
}

/// The model an uploaded scan is for.
#[derive(Debug, Clone, Copy)]
pub enum UploadTarget<'a> {
    /// A new model with these fields.
    New(&'a NewModel),
    /// An existing model without a built scan (pending, failed or cancelled): a retry.
    Existing(i64),
}

/// A received upload: a complete file in `uploads/` under a temporary name.
#[derive(Debug)]
pub struct ReceivedScan {
    /// The temporary file (moved into place by [`Jobs::submit_upload`], removed if dropped).
    pub temp: crate::uploads::TempUpload,
    /// Its size.
    pub bytes: u64,
    /// Lower-case extension (checked with [`scan_extension`]).
    pub extension: String,
    /// Display name (sanitised uploader's file name).
    pub display_name: String,
    /// The files the scan refers to (a glTF's `.bin` and textures, an OBJ's MTL and images),
    /// uploaded with it; empty for a single-file scan.
    pub companions: Vec<Companion>,
    /// The scan's path relative to the folder of its companions ([`companion_path`]; its
    /// file name when uploaded alone).
    pub relative: String,
}

/// A file uploaded with a scan, stored beside it under its relative path.
#[derive(Debug)]
pub struct Companion {
    /// Relative path ([`companion_path`]).
    pub relative: String,
    /// The received bytes.
    pub temp: crate::uploads::TempUpload,
    /// Their length.
    pub bytes: u64,
}

/// Most files uploaded with one scan.
pub const MAX_SCAN_FILES: usize = 64;

/// The relative path under which an uploaded file is stored beside its scan: the browser's
/// relative path (a folder upload names `folder/file.bin`), each component a plain name
/// (no `.`, `..`, empty, absolute or drive part, control character, or more than 200 bytes),
/// at most 8 deep. `None` for anything else: a scan's references are resolved in its own
/// folder only (see the importers), so no name can point elsewhere.
pub fn companion_path(raw: &str) -> Option<String> {
    let parts: Vec<&str> = raw.split(['/', '\\']).collect();
    let plain = |c: &&str| {
        !c.is_empty()
            && *c != "."
            && *c != ".."
            && c.len() <= 200
            && !c.contains(':')
            && !c.chars().any(char::is_control)
    };
    (parts.len() <= 8 && parts.iter().all(plain)).then(|| parts.join("/"))
}

impl Jobs {
    /// A runner over `db` (nothing starts until [`Jobs::start`]); `search` is kept in step
    /// with what jobs write (the demo model's seeded content).
    pub fn new(db: Db, settings: Arc<Settings>, search: Option<SearchIndex>) -> Jobs {
        Jobs {
            inner: Arc::new(Inner {
                db,
                settings,
                search,
                wake: Notify::new(),
                wake_sweeper: Notify::new(),
                running: Mutex::new(HashMap::new()),
                shutdown: AtomicBool::new(false),
                workers: Mutex::new(Vec::new()),
                events: broadcast::channel(256).0,
            }),
        }
    }

    /// Ids of the jobs this process is running.
    pub fn running_ids(&self) -> Vec<i64> {
        lock(&self.inner.running).keys().copied().collect()
    }

    /// Live job changes (progress and state), for push displays.
    pub fn subscribe(&self) -> broadcast::Receiver<JobEvent> {
        self.inner.events.subscribe()
    }

    fn emit(&self, job: &Job) {
        let _ = self.inner.events.send(JobEvent::from(job));
    }

    async fn emit_id(&self, id: i64) {
        if let Ok(job) = jobs::get(&self.inner.db, id).await {
            self.emit(&job);
        }
    }

    /// Recovers from a crash (jobs left running are queued again, leftovers removed) and
    /// starts the workers. Call once, in the server, before serving.
    pub async fn start(&self) -> Result<jobs::Recovered, JobError> {
        let recovered = jobs::recover(&self.inner.db, process_alive).await?;
        for id in &recovered.requeued {
            tracing::warn!(job = id, "build interrupted by a restart: queued again");
        }
        for id in &recovered.failed {
            tracing::warn!(job = id, "meshwiki import process gone: job failed");
        }
        self.cleanup_leftovers().await?;
        let n = self.inner.settings.build.workers.max(1);
        let mut workers = lock(&self.inner.workers);
        for k in 0..n {
            let me = self.clone();
            workers.push(tokio::spawn(async move { me.worker(k).await }));
        }
        let me = self.clone();
        workers.push(tokio::spawn(async move { me.sweeper().await }));
        Ok(recovered)
    }

    /// Wakes a worker (a job was queued).
    pub fn wake(&self) {
        self.inner.wake.notify_one();
    }

    /// Stops the workers: running builds are cancelled and queued again for the next start.
    pub async fn shutdown(&self) {
        self.inner.shutdown.store(true, Ordering::SeqCst);
        for p in lock(&self.inner.running).values() {
            p.cancel();
        }
        self.inner.wake.notify_waiters();
        self.inner.wake_sweeper.notify_waiters();
        let handles: Vec<_> = lock(&self.inner.workers).drain(..).collect();
        for h in handles {
            if tokio::time::timeout(SHUTDOWN_WAIT, h).await.is_err() {
                tracing::warn!("a build did not stop within {SHUTDOWN_WAIT:?}");
            }
        }
    }

    /// Removes, every `settings.upload_sweep`, the temporary uploads of processes that
    /// died while this one runs (another server or `meshwiki import` on the same data
    /// directory), and any this process no longer holds.
    async fn sweeper(&self) {
        let dir = self.inner.settings.uploads_dir();
        while !self.shutting_down() {
            let every = self.inner.settings.upload_sweep;
            let _ = tokio::time::timeout(every, self.inner.wake_sweeper.notified()).await;
            if self.shutting_down() {
                break;
            }
            let d = dir.clone();
            let removed =
                tokio::task::spawn_blocking(move || crate::uploads::sweep(&d, &process_alive))
                    .await
                    .unwrap_or_default();
            for p in removed {
                tracing::info!(path = %p.display(), "removed the temporary file of an interrupted upload");
            }
        }
    }

    fn shutting_down(&self) -> bool {
        self.inner.shutdown.load(Ordering::SeqCst)
    }

    async fn worker(&self, k: usize) {
        let pid = std::process::id() as i64;
        while !self.shutting_down() {
            match jobs::claim_next(&self.inner.db, pid).await {
                Ok(Some(job)) => {
                    tracing::info!(worker = k, job = job.id, model = ?job.model_id, "build started");
                    self.emit(&job);
                    let end = self.execute(job, Arc::new(JobProgress::default())).await;
                    tracing::debug!(worker = k, ?end, "build ended");
                }
                Ok(None) => {
                    let _ = tokio::time::timeout(IDLE_POLL, self.inner.wake.notified()).await;
                }
                Err(e) => {
                    tracing::error!(error = %e, "cannot claim a job");
                    tokio::time::sleep(IDLE_POLL).await;
                }
            }
        }
    }

    /// Stores an uploaded scan and queues its build with `options`, for a new model or for an
    /// existing one without a built scan (see [`jobs::create_for_model`]); returns the model
    /// and the job.
    pub async fn submit_upload(
        &self,
        scan: ReceivedScan,
        target: UploadTarget<'_>,
        options: JobOptions,
        user_id: i64,
    ) -> Result<(Model, Job), JobError> {
        let uploads = self.inner.settings.uploads_dir();
        let display_name = scan.display_name.clone();
        let bytes = scan.bytes + scan.companions.iter().map(|c| c.bytes).sum::<u64>();
        let (rel, dest) = if scan.companions.is_empty() {
            let name = format!("src-{}.{}", crate::random_hex(12), scan.extension);
            let dest = uploads.join(&name);
            let (temp, to) = (scan.temp, dest.clone());
            tokio::task::spawn_blocking(move || temp.persist(&to))
                .await
                .map_err(|e| JobError::Invalid(e.to_string()))??;
            (format!("uploads/{name}"), dest)
        } else {
            // The scan and its companions in a folder of their own, at their relative paths.
            let name = format!("src-{}", crate::random_hex(12));
            let dir = uploads.join(&name);
            let main = scan.relative.clone();
            let (to, files) = (dir.clone(), scan);
            let placed = tokio::task::spawn_blocking(move || -> std::io::Result<()> {
                std::fs::create_dir(&to)?;
                let mut all = vec![(files.relative, files.temp)];
                all.extend(files.companions.into_iter().map(|c| (c.relative, c.temp)));
                for (relative, temp) in all {
                    let dest = to.join(&relative);
                    if let Some(parent) = dest.parent() {
                        std::fs::create_dir_all(parent)?;
                    }
                    if dest.exists() {
                        return Err(std::io::Error::new(
                            std::io::ErrorKind::AlreadyExists,
                            format!("{relative} is uploaded twice"),
                        ));
                    }
                    temp.persist(&dest)?;
                }
                Ok(())
            })
            .await
            .map_err(|e| JobError::Invalid(e.to_string()))?;
            if let Err(e) = placed {
                let _ = tokio::fs::remove_dir_all(&dir).await;
                return Err(match e.kind() {
                    std::io::ErrorKind::AlreadyExists => JobError::Invalid(e.to_string()),
                    _ => e.into(),
                });
            }
            (format!("uploads/{name}/{main}"), dir)
        };
        let new = NewJob {
            kind: JobKind::Upload,
            source_path: Some(rel),
            source_name: display_name,
            source_bytes: bytes.min(i64::MAX as u64) as i64,
            options,
            running_pid: None,
        };
        let created = match target {
            UploadTarget::New(model) => {
                jobs::create_with_model(&self.inner.db, model, &new, user_id).await
            }
            UploadTarget::Existing(id) => {
                jobs::create_for_model(&self.inner.db, id, &new, user_id).await
            }
        };
        match created {
            Ok((model, job)) => {
                tracing::info!(job = job.id, model = model.id, bytes, "upload queued");
                self.emit(&job);
                self.wake();
                Ok((model, job))
            }
            Err(e) => {
                remove_path(&dest).await;
                Err(e.into())
            }
        }
    }

    /// Queues the build of the generated demo relief of about `triangles` triangles.
    pub async fn submit_demo(
        &self,
        triangles: u64,
        model: &NewModel,
        user_id: i64,
    ) -> Result<(Model, Job), JobError> {
        let relief = synth::Relief::new(triangles, synth::DEFAULT_SEED);
        let new = NewJob {
            kind: JobKind::Demo,
            source_path: None,
            source_name: format!("generated relief ({} triangles)", relief.triangle_count()),
            source_bytes: 0,
            options: JobOptions {
                triangles: Some(triangles),
                ..JobOptions::default()
            },
            running_pid: None,
        };
        let (model, job) = jobs::create_with_model(&self.inner.db, model, &new, user_id).await?;
        self.emit(&job);
        self.wake();
        Ok((model, job))
    }

    /// Cancels job `id`: a queued job ends at once, a running one stops at its next check
    /// (within a second or so).
    pub async fn cancel(&self, id: i64, user_id: Option<i64>) -> Result<CancelOutcome, JobError> {
        let outcome = jobs::request_cancel(&self.inner.db, id, user_id).await?;
        match &outcome {
            CancelOutcome::Cancelled(job) => {
                self.remove_source(job).await;
                self.emit(job);
            }
            CancelOutcome::Requested(job) => {
                if let Some(p) = lock(&self.inner.running).get(&id) {
                    p.cancel();
                }
                self.emit(job);
            }
            CancelOutcome::Finished(_) => {}
        }
        Ok(outcome)
    }

    /// Cancels every active job of a model (before the model is deleted).
    pub async fn cancel_for_model(
        &self,
        model_id: i64,
        user_id: Option<i64>,
    ) -> Result<(), JobError> {
        for job in jobs::active_for_model(&self.inner.db, model_id).await? {
            self.cancel(job.id, user_id).await?;
        }
        Ok(())
    }

    fn build_options(&self, job: &Job) -> BuildOptions {
        let b = &self.inner.settings.build;
        let d = BuildOptions::default();
        BuildOptions {
            max_patch_triangles: job
                .options
                .max_patch_triangles
                .unwrap_or(b.max_patch_triangles) as usize,
            memory_budget: job
                .options
                .memory_budget
                .unwrap_or(b.memory_budget)
                .min(usize::MAX as u64) as usize,
            threads: job.options.threads.map(|t| t as usize).or(b.threads),
            simplifier: job.options.simplifier.unwrap_or_default(),
            texture_quality: job
                .options
                .texture_quality
                .map_or(d.texture_quality, |q| q.clamp(1, 100)),
            texture_spread: job
                .options
                .texture_spread
                .map_or(d.texture_spread, |s| s.min(100)),
            normal_maps: job.options.normal_maps.unwrap_or(d.normal_maps),
            // Morton unless asked: smaller files (docs/FORMAT.md, "Vertex ids").
            vertex_order: job.options.vertex_order.unwrap_or(VertexOrder::Morton),
            ..d
        }
    }

    fn source_of(&self, job: &Job) -> Result<Source, String> {
        match job.kind {
            JobKind::Upload => job
                .source_path
                .as_deref()
                .and_then(plain_relative)
                .filter(|p| p.starts_with("uploads"))
                .map(|p| Source::File(self.inner.settings.data_dir.join(p)))
                .ok_or_else(|| "the uploaded file of this job is missing".to_string()),
            JobKind::File => job
                .source_path
                .as_ref()
                .map(|p| Source::File(PathBuf::from(p)))
                .ok_or_else(|| "the job names no input file".to_string()),
            JobKind::Demo => Ok(Source::Demo(job.options.triangles.unwrap_or(2_000_000))),
            JobKind::Lumigraph => Err("an image repository job builds no hierarchy".into()),
        }
    }

    /// Removes the uploaded input of an upload job.
    async fn remove_source(&self, job: &Job) {
        if job.kind != JobKind::Upload {
            return;
        }
        let Some(rel) = job.source_path.as_deref().and_then(plain_relative) else {
            return;
        };
        if !rel.starts_with("uploads") {
            return;
        }
        // `uploads/src-…` (one file) or `uploads/src-…/…` (a scan with its companions).
        let Some(top) = rel.components().nth(1) else {
            return;
        };
        remove_path(&self.inner.settings.uploads_dir().join(top)).await;
    }

    /// Runs a claimed (`running`) job to its end: build, thumbnail, final transaction.
    /// Used by the workers and, in its own process, by `meshwiki import`.
    pub async fn execute(&self, job: Job, progress: Arc<JobProgress>) -> JobEnd {
        lock(&self.inner.running).insert(job.id, progress.clone());
        let ticker = {
            let me = self.clone();
            let (id, model_id, p) = (job.id, job.model_id, progress.clone());
            tokio::spawn(async move { me.tick(id, model_id, p).await })
        };
        let end = match self.build(&job, &progress).await {
            Ok(end) => end,
            Err(e) => {
                tracing::error!(job = job.id, error = %e, "job bookkeeping failed");
                let msg = format!("build failed: {e}");
                let _ = jobs::finish_failed(&self.inner.db, job.id, JobStatus::Failed, &msg).await;
                JobEnd::Failed(msg)
            }
        };
        ticker.abort();
        lock(&self.inner.running).remove(&job.id);
        self.emit_id(job.id).await;
        end
    }

    /// Writes progress every [`TICK`] while it changes and picks up cancellation requests.
    async fn tick(&self, id: i64, model_id: Option<i64>, progress: Arc<JobProgress>) {
        let mut last = None;
        let mut interval = tokio::time::interval(TICK);
        interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            interval.tick().await;
            let snap = progress.snapshot();
            let cancel = if last.as_ref() != Some(&snap) {
                let r = jobs::update_progress(&self.inner.db, id, &snap).await;
                let _ = self.inner.events.send(JobEvent {
                    id,
                    model_id,
                    status: JobStatus::Running,
                    stage: snap.stage.clone(),
                    done: snap.done,
                    total: snap.total,
                    percent: snap.percent,
                    message: None,
                });
                last = Some(snap);
                r
            } else {
                jobs::cancel_requested(&self.inner.db, id).await
            };
            match cancel {
                Ok(true) => progress.cancel(),
                Ok(false) => {}
                Err(e) => tracing::warn!(job = id, error = %e, "cannot record progress"),
            }
        }
    }

    async fn build(&self, job: &Job, progress: &Arc<JobProgress>) -> Result<JobEnd, JobError> {
        if job.kind == JobKind::Lumigraph {
            return self.build_lumigraph(job, progress).await;
        }
        let db = &self.inner.db;
        let Some(model_id) = job.model_id else {
            jobs::finish_failed(db, job.id, JobStatus::Cancelled, "the model was deleted").await?;
            return Ok(JobEnd::Cancelled);
        };
        let source = match self.source_of(job) {
            Ok(s) => s,
            Err(msg) => {
                jobs::finish_failed(db, job.id, JobStatus::Failed, &msg).await?;
                return Ok(JobEnd::Failed(msg));
            }
        };
        let rel = lod_relative_path(model_id);
        let output = self.inner.settings.data_dir.join(&rel);
        let options = self.build_options(job);
        let result = {
            let (output, progress) = (output.clone(), progress.clone());
            tokio::task::spawn_blocking(move || run_build(&source, &output, &options, &*progress))
                .await
        };
        let Built {
            report,
            bbox_min,
            bbox_max,
        } = match result {
            Ok(Ok(built)) => built,
            Ok(Err(BuildError::Cancelled)) | Err(_) if self.shutting_down() => {
                jobs::requeue(db, job.id).await?;
                tracing::info!(job = job.id, "build stopped by shutdown: queued again");
                return Ok(JobEnd::Requeued);
            }
            Ok(Err(BuildError::Cancelled)) => {
                jobs::finish_failed(db, job.id, JobStatus::Cancelled, jobs::CANCELLED_MESSAGE)
                    .await?;
                self.remove_source(job).await;
                tracing::info!(job = job.id, "build cancelled");
                return Ok(JobEnd::Cancelled);
            }
            Ok(Err(e)) => {
                let msg = self.describe_error(job, &e);
                jobs::finish_failed(db, job.id, JobStatus::Failed, &msg).await?;
                self.remove_source(job).await;
                tracing::warn!(job = job.id, error = %msg, "build failed");
                return Ok(JobEnd::Failed(msg));
            }
            Err(join) => {
                let msg = format!("build crashed: {join}");
                jobs::finish_failed(db, job.id, JobStatus::Failed, &msg).await?;
                self.remove_source(job).await;
                tracing::error!(job = job.id, error = %msg, "build crashed");
                return Ok(JobEnd::Failed(msg));
            }
        };
        progress.stage(progress::THUMBNAIL_STAGE, 1);
        let thumbnail = match job.created_by {
            Some(user) => self.thumbnail(model_id, &output, user).await,
            None => None,
        };
        progress.advance(1);
        let built = BuiltModel {
            vertex_count: report.import.vertices.min(i64::MAX as u64) as i64,
            triangle_count: report.import.triangles.min(i64::MAX as u64) as i64,
            bbox: BBox {
                min: bbox_min.map(f64::from),
                max: bbox_max.map(f64::from),
            },
            lod_path: rel,
            thumbnail_attachment_id: thumbnail,
            report: serde_json::to_value(&report).unwrap_or_default(),
        };
        // The demo model is seeded before its job ends, so "done" means everything is there.
        let seed = job.kind == JobKind::Demo && job.created_by.is_some();
        if !jobs::finish_done(db, job.id, model_id, &built, !seed).await? {
            let _ = tokio::fs::remove_file(&output).await;
            let _ = tokio::fs::remove_file(meshwiki_engine::segment::path_for(&output)).await;
            jobs::finish_failed(db, job.id, JobStatus::Cancelled, "the model was deleted").await?;
            self.remove_source(job).await;
            return Ok(JobEnd::Cancelled);
        }
        self.remove_source(job).await;
        tracing::info!(
            job = job.id,
            model = model_id,
            triangles = report.import.triangles,
            nodes = report.nodes,
            seconds = report.seconds,
            "build done"
        );
        if seed && let Some(user) = job.created_by {
            let lod = output.clone();
            match crate::seed::seed_demo_model(db, &self.inner.settings, model_id, &lod, user).await
            {
                Ok(true) => {
                    tracing::info!(model = model_id, "seeded the demo model");
                    if let Some(search) = &self.inner.search
                        && let Err(e) = search.sync(db).await
                    {
                        tracing::warn!(error = %e, "search index update failed; will retry");
                    }
                }
                Ok(false) => {}
                Err(e) => tracing::warn!(error = %e, "cannot seed the demo model"),
            }
            jobs::mark_done(db, job.id, &built.report).await?;
        }
        Ok(JobEnd::Done(Box::new(report)))
    }

    /// The build error as shown to users: the internal upload name replaced by the
    /// uploader's file name.
    fn describe_error(&self, job: &Job, e: &BuildError) -> String {
        let msg = e.to_string();
        match (job.kind, job.source_path.as_deref()) {
            (JobKind::Upload, Some(p)) => match Path::new(p).file_name().and_then(|n| n.to_str()) {
                Some(internal) if !job.source_name.is_empty() => {
                    msg.replace(internal, &job.source_name)
                }
                _ => msg,
            },
            _ => msg,
        }
    }

    /// Renders, stores and returns the thumbnail attachment of a built model (errors are
    /// logged: a model without a thumbnail is still ready).
    async fn thumbnail(&self, model_id: i64, lod_path: &Path, user_id: i64) -> Option<i64> {
        let settings = self.inner.settings.clone();
        let path = lod_path.to_path_buf();
        let stored = tokio::task::spawn_blocking(move || -> Result<(String, usize), String> {
            let lod = LodFile::open(&path).map_err(|e| e.to_string())?;
            let png = thumbnail::render_png(&settings.render, Arc::new(lod))
                .map_err(|e| e.to_string())?;
            let sha = crate::blobs::write_bytes(&settings, &png).map_err(|e| e.to_string())?;
            Ok((sha, png.len()))
        })
        .await;
        let (sha256, size) = match stored {
            Ok(Ok(s)) => s,
            Ok(Err(e)) => {
                tracing::warn!(model = model_id, error = %e, "no thumbnail");
                return None;
            }
            Err(e) => {
                tracing::warn!(model = model_id, error = %e, "thumbnail renderer crashed");
                return None;
            }
        };
        let new = NewAttachment {
            sha256,
            media_type: "image/png".into(),
            size: size as i64,
            original_name: format!("model-{model_id}-thumbnail.png"),
        };
        match attachments::create(&self.inner.db, &new, None, user_id).await {
            Ok(a) => Some(a.id),
            Err(e) => {
                tracing::warn!(model = model_id, error = %e, "cannot record the thumbnail");
                None
            }
        }
    }

    /// Removes what crashed builds and uploads left behind: engine scratch directories and
    /// temporary files of dead processes in `models/`, LOD files of deleted models, stale
    /// temporary files and unclaimed inputs in `uploads/`, repository images no model uses
    /// (run before the workers start: a running build's images are not recorded yet).
    pub async fn cleanup_leftovers(&self) -> Result<(), JobError> {
        let settings = self.inner.settings.clone();
        let lods = jobs::model_lod_paths(&self.inner.db).await?;
        let sources = jobs::pending_sources(&self.inner.db).await?;
        let images = crate::store::lumigraph::used_blobs(&self.inner.db).await?;
        let removed = tokio::task::spawn_blocking(move || {
            let mut removed = cleanup_dirs(&settings, &lods, &sources)?;
            removed.extend(crate::blobs::remove_unused(
                &settings,
                crate::blobs::Bucket::Lumigraph,
                &images,
            )?);
            Ok::<_, std::io::Error>(removed)
        })
        .await
        .map_err(|e| JobError::Invalid(e.to_string()))??;
        for p in removed {
            tracing::info!(path = %p.display(), "removed leftover of an interrupted build");
        }
        Ok(())
    }
}

/// Removes a file or a folder; a missing one is fine.
async fn remove_path(path: &Path) {
    let p = path.to_path_buf();
    let result = tokio::task::spawn_blocking(move || crate::remove_file_or_dir(&p))
        .await
        .unwrap_or_else(|e| Err(std::io::Error::other(e)));
    if let Err(e) = result {
        tracing::warn!(path = %path.display(), error = %e, "cannot remove upload");
    }
}

/// The pid at the end of a leftover's name (`.x.mwlod.build-<pid>`, `x.mwlod.tmp-<pid>`).
fn leftover_pid(name: &str) -> Option<i64> {
    let (_, pid) = name
        .rsplit_once(".build-")
        .or_else(|| name.rsplit_once(".tmp-"))?;
    pid.parse().ok()
}

fn cleanup_dirs(
    settings: &Settings,
    lods: &[(i64, Option<String>)],
    sources: &[String],
) -> std::io::Result<Vec<PathBuf>> {
    let mut removed = Vec::new();
    let model_ids: std::collections::HashSet<i64> = lods.iter().map(|(id, _)| *id).collect();
    if let Ok(dir) = std::fs::read_dir(settings.models_dir()) {
        for entry in dir.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            let path = entry.path();
            let leftover = match leftover_pid(&name) {
                Some(pid) => !process_alive(pid),
                None => name
                    .strip_suffix(".mwlod")
                    .or_else(|| name.strip_suffix(".mwseg"))
                    .and_then(|id| id.parse::<i64>().ok())
                    .is_some_and(|id| !model_ids.contains(&id)),
            };
            if !leftover {
                continue;
            }
            match crate::remove_file_or_dir(&path) {
                Ok(()) => removed.push(path),
                Err(e) => tracing::warn!(path = %path.display(), error = %e, "cannot remove"),
            }
        }
    }
    // Temporary files of dead processes (or that no guard of this one holds), then queued
    // inputs no job refers to.
    let uploads = settings.uploads_dir();
    removed.extend(crate::uploads::sweep(&uploads, &process_alive));
    // A queued input is `uploads/src-…` or, with its companions, `uploads/src-…/…`.
    let keep: std::collections::HashSet<&str> = sources
        .iter()
        .filter_map(|s| s.strip_prefix("uploads/"))
        .filter_map(|s| s.split('/').next())
        .collect();
    if let Ok(dir) = std::fs::read_dir(&uploads) {
        for entry in dir.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            let path = entry.path();
            let orphan = name.starts_with("src-") && !keep.contains(name.as_str());
            if orphan {
                match crate::remove_file_or_dir(&path) {
                    Ok(()) => removed.push(path),
                    Err(e) => tracing::warn!(path = %path.display(), error = %e, "cannot remove"),
                }
            }
        }
    }
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("1G"), Ok(1 << 30));
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size("4096"), Ok(4096));
        assert!(parse_size("").is_err());
        assert!(parse_size("1X").is_err());
        assert!(parse_size("-1G").is_err());
    }

    #[test]
    fn only_the_extension_of_an_upload_name_counts() {
        assert_eq!(scan_extension("scan.PLY").as_deref(), Some("ply"));
        assert_eq!(scan_extension("../../etc/x.obj").as_deref(), Some("obj"));
        assert_eq!(scan_extension("a\\b\\c.glb").as_deref(), Some("glb"));
        assert_eq!(scan_extension("notes.txt"), None);
        assert_eq!(scan_extension("noext"), None);
    }

    #[test]
    fn leftover_names() {
        assert_eq!(leftover_pid(".3.mwlod.build-1234"), Some(1234));
        assert_eq!(leftover_pid("3.mwlod.tmp-77"), Some(77));
        assert_eq!(leftover_pid("3.mwlod"), None);
    }
}
