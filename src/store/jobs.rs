//! `jobs`: background LOD builds and their progress. A job is created `queued` together with
//! its model (one transaction), claimed (`running`) by a worker, and ends `done` (the model
//! `ready` with its statistics, in the same transaction), `failed` or `cancelled` (the model
//! `failed` with the message). The runner lives in `crate::jobs`. A `lumigraph` job renders
//! the image repository of a ready model (`store::lumigraph`): it moves that repository's
//! status instead, and never the model's.

use meshwiki_engine::lod::VertexOrder;
use meshwiki_engine::lod::segsimplify::Simplifier;
use serde::{Deserialize, Serialize};
use sqlx::Row;
use sqlx::sqlite::SqliteRow;
use utoipa::ToSchema;

use super::models::{self, BBox, Model, ModelStatus, NewModel};
use super::{Db, Page, Result, StoreError, Tx};

/// Where a job's input comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, sqlx::Type, ToSchema)]
#[serde(rename_all = "lowercase")]
#[sqlx(rename_all = "lowercase")]
pub enum JobKind {
    /// A file uploaded to the server (`uploads/src-*`), owned by the job.
    Upload,
    /// A local file imported with `meshwiki import` (run by that process).
    File,
    /// The generated demo relief.
    Demo,
    /// The Grid-Lumigraph image repository of a ready model.
    Lumigraph,
}

impl JobKind {
    /// Name as stored.
    pub fn as_str(self) -> &'static str {
        match self {
            JobKind::Upload => "upload",
            JobKind::File => "file",
            JobKind::Demo => "demo",
            JobKind::Lumigraph => "lumigraph",
        }
    }

    /// Whether the job builds its model's hierarchy (and so moves the model's status).
    pub fn builds_model(self) -> bool {
        !matches!(self, JobKind::Lumigraph)
    }
}

/// State of a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, sqlx::Type, ToSchema)]
#[serde(rename_all = "lowercase")]
#[sqlx(rename_all = "lowercase")]
pub enum JobStatus {
    /// Waiting for a worker.
    Queued,
    /// Building.
    Running,
    /// Finished; the model is ready.
    Done,
    /// Failed; `message` says why.
    Failed,
    /// Cancelled by an admin.
    Cancelled,
}

impl JobStatus {
    /// Name as stored.
    pub fn as_str(self) -> &'static str {
        match self {
            JobStatus::Queued => "queued",
            JobStatus::Running => "running",
            JobStatus::Done => "done",
            JobStatus::Failed => "failed",
            JobStatus::Cancelled => "cancelled",
        }
    }

    /// Whether the job has ended.
    pub fn is_finished(self) -> bool {
        matches!(
            self,
            JobStatus::Done | JobStatus::Failed | JobStatus::Cancelled
        )
    }
}

/// Build options of a job (stored as JSON).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct JobOptions {
    /// Memory budget of the build, in bytes (default: the server's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub memory_budget: Option<u64>,
    /// Triangle budget of a patch (default: the server's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_patch_triangles: Option<u32>,
    /// Worker threads (default: the server's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threads: Option<u32>,
    /// How the hierarchy's levels are simplified (default `quadric`; `segments`: the
    /// mesh-segmentation paper's segment-driven vertex removal, measured by
    /// `meshwiki-bench simplify`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simplifier: Option<Simplifier>,
    /// JPEG quality (1–100) of textured scans' atlases, the mean of each level's (default 85).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture_quality: Option<u8>,
    /// How far an atlas' quality moves with the feature density of its patch (the TexMesh
    /// paper's ΔQ; 0: uniform quality; default 10).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture_spread: Option<u8>,
    /// Bake normal maps into the coarse patches (issue 11; default off, see
    /// `meshwiki-bench normals`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normal_maps: Option<bool>,
    /// How the model's vertices are numbered (default `morton`: by the Morton code of their
    /// positions, smaller files; `source`: ids are the scan file's vertex indices).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vertex_order: Option<VertexOrder>,
    /// Triangles of the generated relief (demo jobs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub triangles: Option<u64>,
    /// Grid points per axis (lumigraph jobs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<u32>,
    /// Image side in pixels (lumigraph jobs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<u32>,
}

/// A job.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct Job {
    /// Id.
    pub id: i64,
    /// Where the input comes from.
    pub kind: JobKind,
    /// The model it builds (none once that model is deleted).
    pub model_id: Option<i64>,
    /// State.
    pub status: JobStatus,
    /// Input: relative to the data directory (upload), a local path (file), none (demo).
    #[serde(skip)]
    pub source_path: Option<String>,
    /// Display name of the input.
    pub source_name: String,
    /// Size of the input in bytes.
    pub source_bytes: i64,
    /// Build options.
    pub options: JobOptions,
    /// Current stage of the build (e.g. `import`, `generating`, `partitioning`,
    /// `simplifying level 2`, `writing`, `thumbnail`, `done`).
    pub stage: String,
    /// Units of the current stage done.
    pub done: i64,
    /// Units of the current stage in all.
    pub total: i64,
    /// Estimate of the whole job's progress, 0–100.
    pub percent: f64,
    /// Error or status message (why it failed).
    pub message: Option<String>,
    /// The engine's build report once done.
    #[schema(value_type = Option<Object>)]
    pub report: Option<serde_json::Value>,
    /// Times the job was started.
    pub attempts: i64,
    /// Whether a cancellation was requested.
    pub cancel_requested: bool,
    /// Creator.
    pub created_by: Option<i64>,
    /// Creation time.
    #[schema(format = DateTime)]
    pub created_at: String,
    /// Start of the latest attempt.
    #[schema(format = DateTime)]
    pub started_at: Option<String>,
    /// End time.
    #[schema(format = DateTime)]
    pub finished_at: Option<String>,
    /// Last change (progress included).
    #[schema(format = DateTime)]
    pub updated_at: String,
    /// Process running it.
    #[serde(skip)]
    pub runner_pid: Option<i64>,
}

const COLUMNS: &str = "id, kind, model_id, status, source_path, source_name, source_bytes, \
    options, stage, done, total, percent, message, report, attempts, cancel_requested, \
    runner_pid, created_by, created_at, started_at, finished_at, updated_at";

fn from_row(r: &SqliteRow) -> std::result::Result<Job, sqlx::Error> {
    let options: String = r.try_get("options")?;
    let report: Option<String> = r.try_get("report")?;
    Ok(Job {
        id: r.try_get("id")?,
        kind: r.try_get("kind")?,
        model_id: r.try_get("model_id")?,
        status: r.try_get("status")?,
        source_path: r.try_get("source_path")?,
        source_name: r.try_get("source_name")?,
        source_bytes: r.try_get("source_bytes")?,
        options: serde_json::from_str(&options).unwrap_or_default(),
        stage: r.try_get("stage")?,
        done: r.try_get("done")?,
        total: r.try_get("total")?,
        percent: r.try_get("percent")?,
        message: r.try_get("message")?,
        report: report.and_then(|s| serde_json::from_str(&s).ok()),
        attempts: r.try_get("attempts")?,
        cancel_requested: r.try_get::<i64, _>("cancel_requested")? != 0,
        runner_pid: r.try_get("runner_pid")?,
        created_by: r.try_get("created_by")?,
        created_at: r.try_get("created_at")?,
        started_at: r.try_get("started_at")?,
        finished_at: r.try_get("finished_at")?,
        updated_at: r.try_get("updated_at")?,
    })
}

/// A job to create.
#[derive(Debug, Clone)]
pub struct NewJob {
    /// Where the input comes from.
    pub kind: JobKind,
    /// Input path (see [`Job::source_path`]).
    pub source_path: Option<String>,
    /// Display name of the input.
    pub source_name: String,
    /// Size of the input.
    pub source_bytes: i64,
    /// Build options.
    pub options: JobOptions,
    /// Create it `running` by this process (`meshwiki import`) instead of `queued`.
    pub running_pid: Option<i64>,
}

pub(super) async fn get_tx(tx: &mut Tx, id: i64) -> Result<Job> {
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM jobs WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&mut **tx)
    .await?
    .ok_or(StoreError::NotFound("job"))?;
    Ok(from_row(&row)?)
}

/// Creates a model and the job that builds it, in one transaction. The model is `pending`
/// while the job is queued, `building` when it is created running.
pub async fn create_with_model(
    db: &Db,
    model: &NewModel,
    job: &NewJob,
    user_id: i64,
) -> Result<(Model, Job)> {
    let mut tx = db.begin().await?;
    let created = models::create_tx(&mut tx, model, user_id).await?;
    let id = insert_tx(&mut tx, created.id, job, user_id).await?;
    let created = models::get_tx(&mut tx, created.id).await?;
    let job = get_tx(&mut tx, id).await?;
    tx.commit().await?;
    Ok((created, job))
}

/// Queues `job` to build the scan of existing model `model_id` again: a model whose build
/// failed or was cancelled, or that never had one (status `pending` or `failed`, no job of it
/// queued or running). The model goes back to `pending`. [`StoreError::Conflict`] otherwise
/// (a ready model keeps its scan: its parts name that scan's vertices).
pub async fn create_for_model(
    db: &Db,
    model_id: i64,
    job: &NewJob,
    user_id: i64,
) -> Result<(Model, Job)> {
    let mut tx = db.begin().await?;
    check_takes_scan(&models::get_tx(&mut tx, model_id).await?)?;
    check_idle_tx(&mut tx, model_id).await?;
    set_model_status_tx(&mut tx, model_id, ModelStatus::Pending, None).await?;
    let id = insert_tx(&mut tx, model_id, job, user_id).await?;
    let model = models::get_tx(&mut tx, model_id).await?;
    let job = get_tx(&mut tx, id).await?;
    tx.commit().await?;
    Ok((model, job))
}

/// [`StoreError::Conflict`] while model `model_id` has a job (a build or an image repository)
/// queued or running.
pub(super) async fn check_idle_tx(tx: &mut Tx, model_id: i64) -> Result<()> {
    let active: i64 = sqlx::query_scalar(
        "SELECT COUNT(*) FROM jobs WHERE model_id = ? AND status IN ('queued', 'running')",
    )
    .bind(model_id)
    .fetch_one(&mut **tx)
    .await?;
    if active > 0 {
        return Err(StoreError::Conflict(format!(
            "model {model_id} already has a job queued or running"
        )));
    }
    Ok(())
}

/// [`StoreError::Conflict`] unless `model` can take a new scan: it has none built (status
/// `pending`, or `failed` after a failed or cancelled build).
pub fn check_takes_scan(model: &Model) -> Result<()> {
    if matches!(model.status, ModelStatus::Pending | ModelStatus::Failed) {
        return Ok(());
    }
    Err(StoreError::Conflict(format!(
        "model {} is {}: only a model without a built scan (pending, or its build failed or \
         was cancelled) takes a new one",
        model.id,
        model.status.as_str()
    )))
}

/// Inserts `job` for `model_id` (running at once when it names its runner), with its audit
/// entry; returns its id.
pub(super) async fn insert_tx(
    tx: &mut Tx,
    model_id: i64,
    job: &NewJob,
    user_id: i64,
) -> Result<i64> {
    let now = crate::now_rfc3339();
    let (status, started) = match job.running_pid {
        Some(_) => (JobStatus::Running, Some(now.clone())),
        None => (JobStatus::Queued, None),
    };
    let options = serde_json::to_string(&job.options).unwrap_or_else(|_| "{}".into());
    let id: i64 = sqlx::query_scalar(
        "INSERT INTO jobs (kind, model_id, status, source_path, source_name, source_bytes,
         options, attempts, runner_pid, created_by, created_at, started_at, updated_at)
         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING id",
    )
    .bind(job.kind)
    .bind(model_id)
    .bind(status)
    .bind(&job.source_path)
    .bind(&job.source_name)
    .bind(job.source_bytes)
    .bind(options)
    .bind(i64::from(job.running_pid.is_some()))
    .bind(job.running_pid)
    .bind(user_id)
    .bind(&now)
    .bind(started)
    .bind(&now)
    .fetch_one(&mut **tx)
    .await?;
    if job.running_pid.is_some() && job.kind.builds_model() {
        set_model_status_tx(tx, model_id, ModelStatus::Building, None).await?;
    }
    super::audit::record(
        tx,
        Some(user_id),
        "job.create",
        "job",
        Some(id),
        serde_json::json!({"model_id": model_id, "kind": job.kind, "source_name": job.source_name}),
    )
    .await?;
    Ok(id)
}

async fn set_model_status_tx(
    tx: &mut Tx,
    model_id: i64,
    status: ModelStatus,
    error: Option<&str>,
) -> Result<bool> {
    let n = sqlx::query("UPDATE models SET status = ?, error = ?, updated_at = ? WHERE id = ?")
        .bind(status)
        .bind(error)
        .bind(crate::now_rfc3339())
        .bind(model_id)
        .execute(&mut **tx)
        .await?
        .rows_affected();
    Ok(n > 0)
}

/// A job by id.
pub async fn get(db: &Db, id: i64) -> Result<Job> {
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM jobs WHERE id = ?"
    )))
    .bind(id)
    .fetch_optional(&db.read)
    .await?
    .ok_or(StoreError::NotFound("job"))?;
    Ok(from_row(&row)?)
}

/// Jobs, newest first, optionally only those with `status`.
pub async fn list(db: &Db, status: Option<JobStatus>, page: Page) -> Result<Vec<Job>> {
    let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM jobs WHERE (?1 IS NULL OR status = ?1)
         ORDER BY id DESC LIMIT ?2 OFFSET ?3"
    )))
    .bind(status)
    .bind(page.limit)
    .bind(page.offset)
    .fetch_all(&db.read)
    .await?;
    Ok(rows
        .iter()
        .map(from_row)
        .collect::<std::result::Result<_, _>>()?)
}

/// The latest job of a model.
pub async fn latest_for_model(db: &Db, model_id: i64) -> Result<Option<Job>> {
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM jobs WHERE model_id = ? ORDER BY id DESC LIMIT 1"
    )))
    .bind(model_id)
    .fetch_optional(&db.read)
    .await?;
    Ok(row.as_ref().map(from_row).transpose()?)
}

/// The models whose latest build was cancelled (their status is `failed`; pages say
/// "cancelled").
pub async fn cancelled_models(db: &Db) -> Result<std::collections::HashSet<i64>> {
    let ids: Vec<i64> = sqlx::query_scalar(
        "SELECT model_id FROM jobs WHERE status = 'cancelled' AND id IN
         (SELECT MAX(id) FROM jobs WHERE model_id IS NOT NULL GROUP BY model_id)",
    )
    .fetch_all(&db.read)
    .await?;
    Ok(ids.into_iter().collect())
}

/// Whether any job of `kind` was ever created.
pub async fn exists_of_kind(db: &Db, kind: JobKind) -> Result<bool> {
    let n: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM jobs WHERE kind = ?")
        .bind(kind)
        .fetch_one(&db.read)
        .await?;
    Ok(n > 0)
}

/// Claims the oldest queued job for process `pid`: it becomes `running` (one more attempt)
/// and its model `building`.
pub async fn claim_next(db: &Db, pid: i64) -> Result<Option<Job>> {
    let mut tx = db.begin().await?;
    let now = crate::now_rfc3339();
    let id: Option<i64> = sqlx::query_scalar(
        "UPDATE jobs SET status = 'running', attempts = attempts + 1, runner_pid = ?,
         started_at = ?, updated_at = ?, stage = '', done = 0, total = 0, percent = 0,
         message = NULL
         WHERE id = (SELECT id FROM jobs WHERE status = 'queued' ORDER BY id LIMIT 1)
         RETURNING id",
    )
    .bind(pid)
    .bind(&now)
    .bind(&now)
    .fetch_optional(&mut *tx)
    .await?;
    let Some(id) = id else {
        return Ok(None);
    };
    let job = get_tx(&mut tx, id).await?;
    if let Some(model) = job.model_id {
        if job.kind.builds_model() {
            set_model_status_tx(&mut tx, model, ModelStatus::Building, None).await?;
        } else {
            super::lumigraph::set_status_tx(&mut tx, model, id, "building", None).await?;
        }
    }
    tx.commit().await?;
    Ok(Some(job))
}

/// Progress of a running job.
#[derive(Debug, Clone, PartialEq)]
pub struct ProgressUpdate {
    /// Stage name.
    pub stage: String,
    /// Units of the stage done.
    pub done: i64,
    /// Units of the stage in all.
    pub total: i64,
    /// Estimate of the whole job, 0–100.
    pub percent: f64,
}

/// Records the progress of a running job; returns whether a cancellation was requested.
pub async fn update_progress(db: &Db, id: i64, p: &ProgressUpdate) -> Result<bool> {
    let mut tx = db.begin().await?;
    sqlx::query(
        "UPDATE jobs SET stage = ?, done = ?, total = ?, percent = ?, updated_at = ?
         WHERE id = ? AND status = 'running'",
    )
    .bind(&p.stage)
    .bind(p.done)
    .bind(p.total)
    .bind(p.percent)
    .bind(crate::now_rfc3339())
    .bind(id)
    .execute(&mut *tx)
    .await?;
    let cancel: Option<i64> = sqlx::query_scalar("SELECT cancel_requested FROM jobs WHERE id = ?")
        .bind(id)
        .fetch_optional(&mut *tx)
        .await?;
    tx.commit().await?;
    Ok(cancel.unwrap_or(1) != 0)
}

/// Whether a cancellation of job `id` was requested (or the job is gone).
pub async fn cancel_requested(db: &Db, id: i64) -> Result<bool> {
    let cancel: Option<i64> = sqlx::query_scalar("SELECT cancel_requested FROM jobs WHERE id = ?")
        .bind(id)
        .fetch_optional(&db.read)
        .await?;
    Ok(cancel.unwrap_or(1) != 0)
}

/// What a cancellation request did.
#[derive(Debug, Clone)]
pub enum CancelOutcome {
    /// The job was queued and is now cancelled (its model failed).
    Cancelled(Job),
    /// The job is running; its worker stops it soon.
    Requested(Job),
    /// The job had already ended.
    Finished(Job),
}

/// Message of a model whose build was cancelled.
pub const CANCELLED_MESSAGE: &str = "build cancelled";

/// Requests the cancellation of job `id`.
pub async fn request_cancel(db: &Db, id: i64, user_id: Option<i64>) -> Result<CancelOutcome> {
    let mut tx = db.begin().await?;
    let job = get_tx(&mut tx, id).await?;
    let now = crate::now_rfc3339();
    let outcome = match job.status {
        JobStatus::Queued => {
            sqlx::query(
                "UPDATE jobs SET status = 'cancelled', cancel_requested = 1, message = ?,
                 finished_at = ?, updated_at = ? WHERE id = ?",
            )
            .bind(CANCELLED_MESSAGE)
            .bind(&now)
            .bind(&now)
            .bind(id)
            .execute(&mut *tx)
            .await?;
            if let Some(model) = job.model_id {
                end_model_tx(&mut tx, &job, model, CANCELLED_MESSAGE).await?;
            }
            CancelOutcome::Cancelled(get_tx(&mut tx, id).await?)
        }
        JobStatus::Running => {
            sqlx::query("UPDATE jobs SET cancel_requested = 1, updated_at = ? WHERE id = ?")
                .bind(&now)
                .bind(id)
                .execute(&mut *tx)
                .await?;
            CancelOutcome::Requested(get_tx(&mut tx, id).await?)
        }
        _ => return Ok(CancelOutcome::Finished(job)),
    };
    super::audit::record(
        &mut tx,
        user_id,
        "job.cancel",
        "job",
        Some(id),
        serde_json::json!({"model_id": job.model_id}),
    )
    .await?;
    tx.commit().await?;
    Ok(outcome)
}

/// Active (queued or running) jobs of a model.
pub async fn active_for_model(db: &Db, model_id: i64) -> Result<Vec<Job>> {
    let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM jobs WHERE model_id = ? AND status IN ('queued', 'running')"
    )))
    .bind(model_id)
    .fetch_all(&db.read)
    .await?;
    Ok(rows
        .iter()
        .map(from_row)
        .collect::<std::result::Result<_, _>>()?)
}

/// Statistics of a finished build.
#[derive(Debug, Clone)]
pub struct BuiltModel {
    /// Vertices of the input.
    pub vertex_count: i64,
    /// Triangles of the input.
    pub triangle_count: i64,
    /// Bounds of the input.
    pub bbox: BBox,
    /// LOD file, relative to the data directory.
    pub lod_path: String,
    /// Thumbnail attachment.
    pub thumbnail_attachment_id: Option<i64>,
    /// The engine's report.
    pub report: serde_json::Value,
}

/// Makes the model of job `id` ready with `built` and, with `end_job`, ends the job as done,
/// in one transaction (without `end_job`, [`mark_done`] ends it after follow-up work).
/// Returns `false` (and changes nothing) when the model no longer exists.
pub async fn finish_done(
    db: &Db,
    id: i64,
    model_id: i64,
    built: &BuiltModel,
    end_job: bool,
) -> Result<bool> {
    let mut tx = db.begin().await?;
    let now = crate::now_rfc3339();
    let b = built.bbox;
    let n = sqlx::query(
        "UPDATE models SET status = 'ready', error = NULL, vertex_count = ?, triangle_count = ?,
         bbox_min_x = ?, bbox_min_y = ?, bbox_min_z = ?, bbox_max_x = ?, bbox_max_y = ?,
         bbox_max_z = ?, lod_path = ?,
         thumbnail_attachment_id = COALESCE(?, thumbnail_attachment_id), updated_at = ?
         WHERE id = ?",
    )
    .bind(built.vertex_count)
    .bind(built.triangle_count)
    .bind(b.min[0])
    .bind(b.min[1])
    .bind(b.min[2])
    .bind(b.max[0])
    .bind(b.max[1])
    .bind(b.max[2])
    .bind(&built.lod_path)
    .bind(built.thumbnail_attachment_id)
    .bind(&now)
    .bind(model_id)
    .execute(&mut *tx)
    .await?
    .rows_affected();
    if n == 0 {
        return Ok(false);
    }
    if end_job {
        done_tx(&mut tx, id, &built.report).await?;
    }
    super::audit::record(
        &mut tx,
        None,
        "model.built",
        "model",
        Some(model_id),
        serde_json::json!({
            "job_id": id,
            "vertex_count": built.vertex_count,
            "triangle_count": built.triangle_count,
            "lod_path": built.lod_path,
        }),
    )
    .await?;
    tx.commit().await?;
    Ok(true)
}

pub(super) async fn done_tx(tx: &mut Tx, id: i64, report: &serde_json::Value) -> Result<()> {
    let now = crate::now_rfc3339();
    sqlx::query(
        "UPDATE jobs SET status = 'done', stage = 'done', percent = 100, message = NULL,
         report = ?, finished_at = ?, updated_at = ? WHERE id = ?",
    )
    .bind(report.to_string())
    .bind(&now)
    .bind(&now)
    .bind(id)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Ends job `id` as done (after [`finish_done`] without `end_job`).
pub async fn mark_done(db: &Db, id: i64, report: &serde_json::Value) -> Result<()> {
    let mut tx = db.begin().await?;
    done_tx(&mut tx, id, report).await?;
    tx.commit().await?;
    Ok(())
}

/// Ends job `id` as failed or cancelled with `message`; its model (if any) becomes `failed`
/// with the same message.
pub async fn finish_failed(db: &Db, id: i64, status: JobStatus, message: &str) -> Result<()> {
    let mut tx = db.begin().await?;
    let job = get_tx(&mut tx, id).await?;
    let now = crate::now_rfc3339();
    sqlx::query(
        "UPDATE jobs SET status = ?, message = ?, finished_at = ?, updated_at = ? WHERE id = ?",
    )
    .bind(status)
    .bind(message)
    .bind(&now)
    .bind(&now)
    .bind(id)
    .execute(&mut *tx)
    .await?;
    if let Some(model) = job.model_id {
        end_model_tx(&mut tx, &job, model, message).await?;
    }
    super::audit::record(
        &mut tx,
        None,
        "job.end",
        "job",
        Some(id),
        serde_json::json!({"status": status, "message": message}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Puts a running job back in the queue (the server is shutting down); its model is
/// `pending` again.
pub async fn requeue(db: &Db, id: i64) -> Result<()> {
    let mut tx = db.begin().await?;
    let job = get_tx(&mut tx, id).await?;
    sqlx::query(
        "UPDATE jobs SET status = 'queued', stage = '', done = 0, total = 0, percent = 0,
         runner_pid = NULL, updated_at = ? WHERE id = ? AND status = 'running'",
    )
    .bind(crate::now_rfc3339())
    .bind(id)
    .execute(&mut *tx)
    .await?;
    if let Some(model) = job.model_id {
        queued_again_tx(&mut tx, &job, model).await?;
    }
    tx.commit().await?;
    Ok(())
}

/// A failed or cancelled job's model is `failed` with `message`; a lumigraph job's
/// repository is (the model stays as it is).
async fn end_model_tx(tx: &mut Tx, job: &Job, model: i64, message: &str) -> Result<()> {
    if job.kind.builds_model() {
        set_model_status_tx(tx, model, ModelStatus::Failed, Some(message)).await?;
    } else {
        super::lumigraph::set_status_tx(tx, model, job.id, "failed", Some(message)).await?;
    }
    Ok(())
}

/// A job queued again: its model is `pending` again, or its repository `queued`.
async fn queued_again_tx(tx: &mut Tx, job: &Job, model: i64) -> Result<()> {
    if job.kind.builds_model() {
        set_model_status_tx(tx, model, ModelStatus::Pending, None).await?;
    } else {
        super::lumigraph::set_status_tx(tx, model, job.id, "queued", None).await?;
    }
    Ok(())
}

/// Message of a `meshwiki import` job whose process died.
pub const INTERRUPTED_MESSAGE: &str = "import interrupted: the `meshwiki import` process ended before the build finished; \
     run the import again";

/// What [`recover`] did.
#[derive(Debug, Clone, Default)]
pub struct Recovered {
    /// Jobs queued again.
    pub requeued: Vec<i64>,
    /// `meshwiki import` jobs whose process died, now failed.
    pub failed: Vec<i64>,
}

/// After a crash: running jobs whose process is gone (`alive` says which processes live)
/// are recovered: server jobs (uploads, demo) go back to the queue (their models `pending`),
/// `meshwiki import` jobs fail. Jobs of live processes are left alone.
pub async fn recover(db: &Db, alive: impl Fn(i64) -> bool) -> Result<Recovered> {
    let mut tx = db.begin().await?;
    let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM jobs WHERE status = 'running'"
    )))
    .fetch_all(&mut *tx)
    .await?;
    let jobs: Vec<Job> = rows
        .iter()
        .map(from_row)
        .collect::<std::result::Result<_, _>>()?;
    let mut out = Recovered::default();
    let now = crate::now_rfc3339();
    for job in jobs {
        if job.runner_pid.is_some_and(&alive) {
            continue;
        }
        match job.kind {
            JobKind::Upload | JobKind::Demo | JobKind::Lumigraph => {
                sqlx::query(
                    "UPDATE jobs SET status = 'queued', stage = '', done = 0, total = 0,
                     percent = 0, runner_pid = NULL, updated_at = ? WHERE id = ?",
                )
                .bind(&now)
                .bind(job.id)
                .execute(&mut *tx)
                .await?;
                if let Some(model) = job.model_id {
                    queued_again_tx(&mut tx, &job, model).await?;
                }
                out.requeued.push(job.id);
            }
            JobKind::File => {
                sqlx::query(
                    "UPDATE jobs SET status = 'failed', message = ?, finished_at = ?,
                     updated_at = ? WHERE id = ?",
                )
                .bind(INTERRUPTED_MESSAGE)
                .bind(&now)
                .bind(&now)
                .bind(job.id)
                .execute(&mut *tx)
                .await?;
                if let Some(model) = job.model_id {
                    set_model_status_tx(
                        &mut tx,
                        model,
                        ModelStatus::Failed,
                        Some(INTERRUPTED_MESSAGE),
                    )
                    .await?;
                }
                out.failed.push(job.id);
            }
        }
    }
    if !out.requeued.is_empty() || !out.failed.is_empty() {
        super::audit::record(
            &mut tx,
            None,
            "job.recover",
            "job",
            None,
            serde_json::json!({"requeued": out.requeued, "failed": out.failed}),
        )
        .await?;
    }
    tx.commit().await?;
    Ok(out)
}

/// Source paths of queued or running upload jobs (files in `uploads/` still needed).
pub async fn pending_sources(db: &Db) -> Result<Vec<String>> {
    Ok(sqlx::query_scalar(
        "SELECT source_path FROM jobs WHERE kind = 'upload' AND status IN ('queued', 'running')
         AND source_path IS NOT NULL",
    )
    .fetch_all(&db.read)
    .await?)
}

/// LOD paths of every model (relative to the data directory).
pub async fn model_lod_paths(db: &Db) -> Result<Vec<(i64, Option<String>)>> {
    let rows = sqlx::query("SELECT id, lod_path FROM models")
        .fetch_all(&db.read)
        .await?;
    rows.iter()
        .map(|r| Ok((r.try_get("id")?, r.try_get("lod_path")?)))
        .collect::<std::result::Result<_, sqlx::Error>>()
        .map_err(StoreError::from)
}
