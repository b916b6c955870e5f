//! Relational store: SQLite through sqlx, one module per table family.
//!
//! Two pools share one database file: `read` (several connections, WAL readers never block)
//! and `write` (a single connection). Every write transaction goes through [`Db::begin`],
//! which opens it with `BEGIN IMMEDIATE` on the single writer connection, so concurrent
//! requests queue for the writer instead of failing with `SQLITE_BUSY`, and a commit is
//! durable (`synchronous=FULL`) before the request that made it returns.

pub mod assignments;
pub mod attachments;
pub mod audit;
pub mod changes;
pub mod contents;
pub mod jobs;
pub mod lumigraph;
pub mod models;
pub mod part_revisions;
pub mod parts;
pub mod sessions;
pub mod users;
pub mod visibility;

use std::borrow::Cow;
use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

use sqlx::migrate::{Migration, MigrationSource, MigrationType, Migrator};
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePool, SqlitePoolOptions, SqliteSynchronous,
};
use sqlx::{AssertSqlSafe, SqlSafeStr};

/// A write transaction.
pub type Tx = sqlx::Transaction<'static, sqlx::Sqlite>;

/// Errors of the store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The named entity does not exist.
    #[error("{0} not found")]
    NotFound(&'static str),
    /// The change conflicts with existing data (e.g. a duplicate name).
    #[error("{0}")]
    Conflict(String),
    /// The change is not valid (e.g. a reference to a missing row).
    #[error("{0}")]
    Invalid(String),
    /// A content save named a revision that is no longer current.
    #[error("revision {base} is not the current revision {}", .current.number)]
    StaleRevision {
        /// The revision the save was based on.
        base: i64,
        /// The current revision, in full.
        current: Box<contents::Revision>,
    },
    /// The database failed.
    #[error("database error: {0}")]
    Db(#[from] sqlx::Error),
    /// A schema migration failed.
    #[error("migration failed: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
}

impl StoreError {
    /// Maps unique / foreign-key violations of `err` to [`StoreError::Conflict`] /
    /// [`StoreError::Invalid`] with the given messages; other errors pass through.
    pub fn map_constraint(err: sqlx::Error, unique: &str, foreign: &str) -> StoreError {
        if let Some(db) = err.as_database_error() {
            if db.is_unique_violation() {
                return StoreError::Conflict(unique.to_string());
            }
            if db.is_foreign_key_violation() {
                return StoreError::Invalid(foreign.to_string());
            }
        }
        StoreError::Db(err)
    }
}

/// Result of store functions.
pub type Result<T> = std::result::Result<T, StoreError>;

/// The database: a pool of readers and a single writer.
#[derive(Clone, Debug)]
pub struct Db {
    /// Read-only connections.
    pub read: SqlitePool,
    /// The single writer connection.
    pub write: SqlitePool,
}

/// Migrations embedded in the binary (`migrations/*.sql`); a new migration file gets a new
/// entry in [`MIGRATIONS`].
#[derive(Debug)]
struct Embedded;

const MIGRATIONS: &[(i64, &str, &str)] = &[
    (
        1,
        "initial",
        include_str!("../../migrations/0001_initial.sql"),
    ),
    (2, "jobs", include_str!("../../migrations/0002_jobs.sql")),
    (
        6,
        "part_revisions",
        include_str!("../../migrations/0006_part_revisions.sql"),
    ),
    (
        7,
        "part_revision_comments",
        include_str!("../../migrations/0007_part_revision_comments.sql"),
    ),
    (
        8,
        "public_models",
        include_str!("../../migrations/0008_public_models.sql"),
    ),
    (
        9,
        "lumigraph",
        include_str!("../../migrations/0009_lumigraph.sql"),
    ),
    (
        10,
        "lumigraph_levels",
        include_str!("../../migrations/0010_lumigraph_levels.sql"),
    ),
];

impl MigrationSource<'static> for Embedded {
    fn resolve(
        self,
    ) -> futures_util::future::BoxFuture<
        'static,
        std::result::Result<Vec<Migration>, sqlx::error::BoxDynError>,
    > {
        Box::pin(async move {
            Ok(MIGRATIONS
                .iter()
                .map(|(version, description, sql)| {
                    Migration::new(
                        *version,
                        Cow::Borrowed(*description),
                        MigrationType::Simple,
                        AssertSqlSafe(*sql).into_sql_str(),
                        false,
                    )
                })
                .collect())
        })
    }
}

impl Db {
    /// Opens (creating if needed) the database at `path` and applies pending migrations.
    pub async fn open(path: &Path) -> Result<Db> {
        let base = SqliteConnectOptions::from_str("sqlite:")?
            .filename(path)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Full)
            .foreign_keys(true)
            .busy_timeout(Duration::from_secs(30));
        let write = SqlitePoolOptions::new()
            .max_connections(1)
            .min_connections(1)
            .acquire_timeout(Duration::from_secs(120))
            .connect_with(base.clone().create_if_missing(true))
            .await?;
        Migrator::new(Embedded).await?.run(&write).await?;
        let read = SqlitePoolOptions::new()
            .max_connections(8)
            .acquire_timeout(Duration::from_secs(60))
            .connect_with(base.read_only(true))
            .await?;
        Ok(Db { read, write })
    }

    /// Begins a write transaction (`BEGIN IMMEDIATE` on the single writer).
    ///
    /// A commit that failed (a full disk, an I/O error) can leave the writer connection inside
    /// a transaction as sqlx sees it, and every later `BEGIN` on it would fail: that
    /// connection is closed (SQLite rolls back whatever it still held) and a fresh one takes
    /// its place, so a failed write costs that one request, not every write after it.
    pub async fn begin(&self) -> Result<Tx> {
        match self.write.begin_with("BEGIN IMMEDIATE").await {
            Err(sqlx::Error::InvalidSavePointStatement | sqlx::Error::BeginFailed) => {
                tracing::warn!(
                    "the database writer was left inside a failed transaction: reopening it"
                );
                let mut conn = self.write.acquire().await?;
                conn.close_on_drop();
                drop(conn);
                Ok(self.write.begin_with("BEGIN IMMEDIATE").await?)
            }
            other => Ok(other?),
        }
    }

    /// Closes both pools (checkpointing the WAL).
    pub async fn close(&self) {
        self.read.close().await;
        self.write.close().await;
    }
}

/// Page of a list: `limit` rows from `offset`.
#[derive(Debug, Clone, Copy)]
pub struct Page {
    /// Rows to return.
    pub limit: i64,
    /// Rows to skip.
    pub offset: i64,
}

impl Page {
    /// Largest page size.
    pub const MAX: i64 = 1000;

    /// A page clamped to `1..=MAX` rows (default 100) from a non-negative offset.
    pub fn new(limit: Option<i64>, offset: Option<i64>) -> Page {
        Page {
            limit: limit.unwrap_or(100).clamp(1, Self::MAX),
            offset: offset.unwrap_or(0).max(0),
        }
    }

    /// Every row (for internal use).
    pub fn all() -> Page {
        Page {
            limit: i64::MAX,
            offset: 0,
        }
    }
}
