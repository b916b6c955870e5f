//! `lumigraphs` and `lumigraph_images`: each model's Grid-Lumigraph image repository (system
//! paper §5.2.2) and where its build stands. [`start`] queues the build (a job of kind
//! `lumigraph`) and drops the previous repository in one transaction; the job records each
//! grid point's six images in one transaction ([`record_point`]), so a build interrupted by a
//! crash resumes at the points it has not recorded; [`finish`] makes it `ready` with the job
//! `done`. Image bytes live outside the database under their SHA-256 (`crate::blobs`).

use serde::{Deserialize, Serialize};
use sqlx::Row;
use sqlx::sqlite::SqliteRow;
use utoipa::ToSchema;

use super::jobs::{self, Job, JobKind, JobOptions, NewJob};
use super::models::{self, ModelStatus};
use super::{Db, Result, StoreError, Tx};

/// Where a repository's build stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum LumigraphStatus {
    /// The model has no repository.
    None,
    /// Its build waits for a worker.
    Queued,
    /// Its build runs.
    Building,
    /// Every image is recorded.
    Ready,
    /// The build failed or was cancelled (see `message`).
    Failed,
}

impl LumigraphStatus {
    /// Name as served.
    pub fn as_str(self) -> &'static str {
        match self {
            LumigraphStatus::None => "none",
            LumigraphStatus::Queued => "queued",
            LumigraphStatus::Building => "building",
            LumigraphStatus::Ready => "ready",
            LumigraphStatus::Failed => "failed",
        }
    }

    fn parse(s: &str) -> LumigraphStatus {
        match s {
            "queued" => LumigraphStatus::Queued,
            "building" => LumigraphStatus::Building,
            "ready" => LumigraphStatus::Ready,
            "failed" => LumigraphStatus::Failed,
            _ => LumigraphStatus::None,
        }
    }
}

/// A model's repository.
#[derive(Debug, Clone, PartialEq)]
pub struct Lumigraph {
    /// Its model.
    pub model_id: i64,
    /// Grid points per axis.
    pub grid: u32,
    /// Image side in pixels.
    pub size: u32,
    /// Build state.
    pub status: LumigraphStatus,
    /// The job that builds (built) it.
    pub job_id: Option<i64>,
    /// Why the build failed.
    pub message: Option<String>,
    /// Render time so far, in seconds.
    pub seconds: f64,
    /// Last change.
    pub updated_at: String,
}

fn from_row(r: &SqliteRow) -> std::result::Result<Lumigraph, sqlx::Error> {
    let status: String = r.try_get("status")?;
    Ok(Lumigraph {
        model_id: r.try_get("model_id")?,
        grid: r.try_get::<i64, _>("grid")?.clamp(0, u32::MAX as i64) as u32,
        size: r.try_get::<i64, _>("size")?.clamp(0, u32::MAX as i64) as u32,
        status: LumigraphStatus::parse(&status),
        job_id: r.try_get("job_id")?,
        message: r.try_get("message")?,
        seconds: r.try_get("seconds")?,
        updated_at: r.try_get("updated_at")?,
    })
}

const COLUMNS: &str = "model_id, grid, size, status, job_id, message, seconds, updated_at";

/// What one stored key holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Entry {
    /// An image, stored under this SHA-256, of this many bytes.
    Image {
        /// Content address.
        sha256: String,
        /// Size in bytes.
        bytes: i64,
    },
    /// The image shows nothing (the paper's empty flag).
    Empty,
    /// The grid point lies inside the object.
    Inside,
}

impl Entry {
    /// The row's `kind`, `sha256` and `bytes`.
    fn columns(&self) -> (&'static str, Option<&str>, i64) {
        match self {
            Entry::Image { sha256, bytes } => ("image", Some(sha256.as_str()), *bytes),
            Entry::Empty => ("empty", None, 0),
            Entry::Inside => ("inside", None, 0),
        }
    }
}

/// Counts of a repository's recorded keys.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, ToSchema)]
pub struct Counts {
    /// Grid points recorded (level 0, the grid the build renders).
    pub points: i64,
    /// Stored images of level 0.
    pub images: i64,
    /// Images of level 0 that show nothing.
    pub empty: i64,
    /// Grid points inside the object (no images).
    pub inside_points: i64,
    /// Bytes of the stored images of level 0.
    pub bytes: i64,
    /// Images of finer levels rendered so far (on first request).
    pub refined_images: i64,
    /// Their bytes.
    pub refined_bytes: i64,
}

/// A model's repository, if it ever had one.
pub async fn get(db: &Db, model_id: i64) -> Result<Option<Lumigraph>> {
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM lumigraphs WHERE model_id = ?"
    )))
    .bind(model_id)
    .fetch_optional(&db.read)
    .await?;
    Ok(row.as_ref().map(from_row).transpose()?)
}

/// Queues the build of model `model_id`'s repository with `grid` points per axis and
/// `size`-pixel images, replacing any previous one (whose images' SHA-256 are returned, for
/// the caller to remove the files no other key uses). [`StoreError::Conflict`] unless the
/// model is ready and has no job queued or running.
pub async fn start(
    db: &Db,
    model_id: i64,
    grid: u32,
    size: u32,
    user_id: i64,
) -> Result<(Lumigraph, Job, Vec<String>)> {
    let mut tx = db.begin().await?;
    let model = models::get_tx(&mut tx, model_id).await?;
    if model.status != ModelStatus::Ready {
        return Err(StoreError::Conflict(format!(
            "model {model_id} is {}: only a ready model gets an image repository",
            model.status.as_str()
        )));
    }
    jobs::check_idle_tx(&mut tx, model_id).await?;
    let old = blobs_of(&mut *tx, model_id).await?;
    sqlx::query("DELETE FROM lumigraph_images WHERE model_id = ?")
        .bind(model_id)
        .execute(&mut *tx)
        .await?;
    let new = NewJob {
        kind: JobKind::Lumigraph,
        source_path: None,
        source_name: format!("image repository ({grid}³ points, {size}² images)"),
        source_bytes: 0,
        options: JobOptions {
            grid: Some(grid),
            size: Some(size),
            ..JobOptions::default()
        },
        running_pid: None,
    };
    let job_id = jobs::insert_tx(&mut tx, model_id, &new, user_id).await?;
    let now = crate::now_rfc3339();
    sqlx::query(
        "INSERT INTO lumigraphs (model_id, grid, size, status, job_id, message, seconds,
         created_at, updated_at) VALUES (?, ?, ?, 'queued', ?, NULL, 0, ?, ?)
         ON CONFLICT (model_id) DO UPDATE SET grid = excluded.grid, size = excluded.size,
         status = 'queued', job_id = excluded.job_id, message = NULL, seconds = 0,
         updated_at = excluded.updated_at",
    )
    .bind(model_id)
    .bind(grid)
    .bind(size)
    .bind(job_id)
    .bind(&now)
    .bind(&now)
    .execute(&mut *tx)
    .await?;
    let row = sqlx::query(sqlx::AssertSqlSafe(format!(
        "SELECT {COLUMNS} FROM lumigraphs WHERE model_id = ?"
    )))
    .bind(model_id)
    .fetch_one(&mut *tx)
    .await?;
    let lumigraph = from_row(&row)?;
    let job = jobs::get_tx(&mut tx, job_id).await?;
    tx.commit().await?;
    Ok((lumigraph, job, old))
}

/// Sets the status (and message) of `model_id`'s repository while job `job_id` owns it.
pub(super) async fn set_status_tx(
    tx: &mut Tx,
    model_id: i64,
    job_id: i64,
    status: &str,
    message: Option<&str>,
) -> Result<()> {
    sqlx::query(
        "UPDATE lumigraphs SET status = ?, message = ?, updated_at = ?
         WHERE model_id = ? AND job_id = ?",
    )
    .bind(status)
    .bind(message)
    .bind(crate::now_rfc3339())
    .bind(model_id)
    .bind(job_id)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Grid points already recorded (a resumed build skips them).
pub async fn recorded_points(db: &Db, model_id: i64) -> Result<Vec<[u32; 3]>> {
    let rows = sqlx::query(
        "SELECT DISTINCT x, y, z FROM lumigraph_images WHERE model_id = ? AND level = 0",
    )
    .bind(model_id)
    .fetch_all(&db.read)
    .await?;
    rows.iter()
        .map(|r| {
            let c = |k: &str| {
                r.try_get::<i64, _>(k)
                    .map(|v| v.clamp(0, u32::MAX as i64) as u32)
            };
            Ok([c("x")?, c("y")?, c("z")?])
        })
        .collect::<std::result::Result<_, sqlx::Error>>()
        .map_err(StoreError::from)
}

/// Records the six keys of grid point `point` for job `job_id` (ignored when another job
/// owns the repository now); adds `seconds` of render time.
pub async fn record_point(
    db: &Db,
    model_id: i64,
    job_id: i64,
    point: [u32; 3],
    entries: &[Entry; 6],
    seconds: f64,
) -> Result<bool> {
    let mut tx = db.begin().await?;
    let n = sqlx::query(
        "UPDATE lumigraphs SET seconds = seconds + ?, updated_at = ?
         WHERE model_id = ? AND job_id = ?",
    )
    .bind(seconds)
    .bind(crate::now_rfc3339())
    .bind(model_id)
    .bind(job_id)
    .execute(&mut *tx)
    .await?
    .rows_affected();
    if n == 0 {
        return Ok(false);
    }
    for (d, e) in entries.iter().enumerate() {
        let (kind, sha, bytes) = e.columns();
        sqlx::query(
            "INSERT OR REPLACE INTO lumigraph_images
             (model_id, level, x, y, z, d, kind, sha256, bytes) VALUES (?, 0, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(model_id)
        .bind(point[0])
        .bind(point[1])
        .bind(point[2])
        .bind(d as i64)
        .bind(kind)
        .bind(sha)
        .bind(bytes)
        .execute(&mut *tx)
        .await?;
    }
    tx.commit().await?;
    Ok(true)
}

/// Ends job `job_id` as done and its repository as `ready`, in one transaction.
pub async fn finish(db: &Db, model_id: i64, job_id: i64, report: &serde_json::Value) -> Result<()> {
    let mut tx = db.begin().await?;
    set_status_tx(&mut tx, model_id, job_id, "ready", None).await?;
    jobs::done_tx(&mut tx, job_id, report).await?;
    super::audit::record(
        &mut tx,
        None,
        "lumigraph.built",
        "model",
        Some(model_id),
        serde_json::json!({"job_id": job_id, "report": report}),
    )
    .await?;
    tx.commit().await?;
    Ok(())
}

/// Records image `key` of refinement level `level` (rendered on first request) for the
/// repository job `job_id` built, if it is still the model's ready repository, and returns
/// what the key holds: `entry`, or what a concurrent request recorded first (it stays);
/// `None` when the repository was rebuilt or deleted meanwhile.
pub async fn record_refined(
    db: &Db,
    model_id: i64,
    job_id: i64,
    level: u32,
    key: [u32; 4],
    entry: Entry,
) -> Result<Option<Entry>> {
    let (kind, sha, bytes) = entry.columns();
    let n = sqlx::query(
        "INSERT OR IGNORE INTO lumigraph_images
         (model_id, level, x, y, z, d, kind, sha256, bytes)
         SELECT ?, ?, ?, ?, ?, ?, ?, ?, ? FROM lumigraphs
         WHERE model_id = ? AND job_id = ? AND status = 'ready'",
    )
    .bind(model_id)
    .bind(level)
    .bind(key[0])
    .bind(key[1])
    .bind(key[2])
    .bind(key[3])
    .bind(kind)
    .bind(sha)
    .bind(bytes)
    .bind(model_id)
    .bind(job_id)
    .execute(&db.write)
    .await?
    .rows_affected();
    if n > 0 {
        return Ok(Some(entry));
    }
    entry_at(&db.write, model_id, level, key).await
}

/// What key `(x, y, z, d)` of refinement level `level` of `model_id`'s repository holds
/// (`None`: not recorded).
pub async fn entry(db: &Db, model_id: i64, level: u32, key: [u32; 4]) -> Result<Option<Entry>> {
    entry_at(&db.read, model_id, level, key).await
}

async fn entry_at<'e>(
    e: impl sqlx::SqliteExecutor<'e>,
    model_id: i64,
    level: u32,
    key: [u32; 4],
) -> Result<Option<Entry>> {
    let row = sqlx::query(
        "SELECT kind, sha256, bytes FROM lumigraph_images
         WHERE model_id = ? AND level = ? AND x = ? AND y = ? AND z = ? AND d = ?",
    )
    .bind(model_id)
    .bind(level)
    .bind(key[0])
    .bind(key[1])
    .bind(key[2])
    .bind(key[3])
    .fetch_optional(e)
    .await?;
    let Some(r) = row else {
        return Ok(None);
    };
    let kind: String = r.try_get("kind")?;
    Ok(Some(match kind.as_str() {
        "image" => Entry::Image {
            sha256: r
                .try_get::<Option<String>, _>("sha256")?
                .unwrap_or_default(),
            bytes: r.try_get("bytes")?,
        },
        "inside" => Entry::Inside,
        _ => Entry::Empty,
    }))
}

/// Bytes of `model_id`'s stored images of refinement levels (level > 0).
pub async fn refined_bytes(db: &Db, model_id: i64) -> Result<i64> {
    let bytes: i64 = sqlx::query_scalar(
        "SELECT COALESCE(SUM(bytes), 0) FROM lumigraph_images WHERE model_id = ? AND level > 0",
    )
    .bind(model_id)
    .fetch_one(&db.read)
    .await?;
    Ok(bytes)
}

/// Counts of `model_id`'s recorded keys.
pub async fn counts(db: &Db, model_id: i64) -> Result<Counts> {
    let r = sqlx::query(
        "SELECT COUNT(DISTINCT CASE WHEN level = 0 THEN x || ',' || y || ',' || z END)
                    AS points,
                COALESCE(SUM(level = 0 AND kind = 'image'), 0) AS images,
                COALESCE(SUM(level = 0 AND kind = 'empty'), 0) AS empty,
                COALESCE(SUM(level = 0 AND kind = 'inside'), 0) AS inside,
                COALESCE(SUM(CASE WHEN level = 0 THEN bytes END), 0) AS bytes,
                COALESCE(SUM(level > 0 AND kind = 'image'), 0) AS refined_images,
                COALESCE(SUM(CASE WHEN level > 0 THEN bytes END), 0) AS refined_bytes
         FROM lumigraph_images WHERE model_id = ?",
    )
    .bind(model_id)
    .fetch_one(&db.read)
    .await?;
    Ok(Counts {
        points: r.try_get("points")?,
        images: r.try_get("images")?,
        empty: r.try_get("empty")?,
        inside_points: r.try_get::<i64, _>("inside")? / 6,
        bytes: r.try_get("bytes")?,
        refined_images: r.try_get("refined_images")?,
        refined_bytes: r.try_get("refined_bytes")?,
    })
}

/// Every SHA-256 some key uses (files under `lumigraph/` not among them are garbage).
pub async fn used_blobs(db: &Db) -> Result<std::collections::HashSet<String>> {
    let shas: Vec<String> =
        sqlx::query_scalar("SELECT DISTINCT sha256 FROM lumigraph_images WHERE sha256 IS NOT NULL")
            .fetch_all(&db.read)
            .await?;
    Ok(shas.into_iter().collect())
}

/// The SHA-256 of `model_id`'s repository images.
pub async fn model_blobs(db: &Db, model_id: i64) -> Result<Vec<String>> {
    blobs_of(&db.read, model_id).await
}

async fn blobs_of<'e>(e: impl sqlx::SqliteExecutor<'e>, model_id: i64) -> Result<Vec<String>> {
    Ok(sqlx::query_scalar(
        "SELECT DISTINCT sha256 FROM lumigraph_images WHERE model_id = ? AND sha256 IS NOT NULL",
    )
    .bind(model_id)
    .fetch_all(e)
    .await?)
}
