//! The application layer: the one place where use cases are orchestrated. A web handler
//! parses its request, calls a function here and turns the result into a response; the CLI,
//! the background tasks and the tests call the same functions.
//!
//! [`App`] holds the services (store, search, jobs, render, the model registry, the event
//! bus, draft selections, login throttle). Dependencies run one way: `web`/`cli` → `app` →
//! `jobs` → `render`/`search`/`seed` → `store`/`blobs` → engine (checked by
//! `tests/server/layers.rs`).
//!
//! * [`models`]: the model registry (one opener and cache of `.mwlod` files, one readiness
//!   check), and deleting models;
//! * [`parts`]: every create, edit and delete of a part, each a revision;
//! * [`contents`]: saving content edits, a stale one merged three-way with what was saved since;
//! * [`selections`]: draft selections and their confirmation into parts;
//! * [`events`]: the live-update bus;
//! * [`views`]: best views and thumbnails of parts, in the background;
//! * [`client`]: the limits and settings clients size their requests to;
//! * [`uploads`]: scans into the build queue (a `.zip` unpacked), resumable upload sessions;
//! * [`lumigraph`]: the network mode: image repositories and who may read a model's geometry.

pub mod client;
pub mod contents;
pub mod error;
pub mod events;
pub mod lumigraph;
pub mod models;
pub mod parts;
pub mod selections;
pub mod uploads;
pub mod views;

use std::sync::Arc;

pub use error::AppError;

use crate::config::Settings;
use crate::jobs::{JobEvent, Jobs};
use crate::render::RenderService;
use crate::search::{SearchError, SearchIndex};
use crate::store::jobs::JobStatus;
use crate::store::{Db, StoreError};
use crate::throttle::LoginThrottle;

/// The application: its services and settings. Cheap to clone.
#[derive(Debug, Clone)]
pub struct App {
    /// The database.
    pub db: Db,
    /// The search index.
    pub search: SearchIndex,
    /// Settings.
    pub settings: Arc<Settings>,
    /// Change events for live viewers and the part views.
    pub events: events::Events,
    /// Background builds (uploads, demo model).
    pub jobs: Jobs,
    /// Open models (`.mwlod` files) of ready models.
    pub models: models::ModelRegistry,
    /// Server-side rendering: GPU device, patch cache, bounded worker pool.
    pub render: RenderService,
    /// Draft region selections of every user.
    pub selections: selections::Drafts,
    /// Failed logins, for back-off.
    pub logins: LoginThrottle,
    /// Resumable scan uploads in progress.
    pub uploads: crate::upload_sessions::Sessions,
}

/// Why the application could not start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// The data directory could not be prepared.
    #[error("cannot prepare data directory {path}: {source}")]
    DataDir {
        /// The directory.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The database could not be opened or migrated.
    #[error("cannot open database: {0}")]
    Store(#[from] StoreError),
    /// The search index could not be opened.
    #[error("cannot open search index: {0}")]
    Search(#[from] SearchError),
    /// The background builds could not start (crash recovery failed).
    #[error("cannot start the background builds: {0}")]
    Jobs(String),
}

/// Background tasks of a started application; they end with the process.
pub struct Background {
    _views: Option<Arc<views::PartViews>>,
}

impl std::fmt::Debug for Background {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Background")
            .field("part_views", &self._views.is_some())
            .finish()
    }
}

impl App {
    /// Prepares the data directory, opens the database (migrating it), the search index
    /// (catching it up with the database) and the render device.
    pub async fn open(settings: Settings) -> Result<App, StartError> {
        settings
            .ensure_dirs()
            .map_err(|source| StartError::DataDir {
                path: settings.data_dir.display().to_string(),
                source,
            })?;
        let db = Db::open(&settings.db_path()).await?;
        let search = SearchIndex::open(&settings.index_dir(), &db).await?;
        let settings = Arc::new(settings);
        // Opening the GPU device blocks for a moment.
        let render_settings = settings.render.clone();
        let render = tokio::task::spawn_blocking(move || RenderService::shared(&render_settings))
            .await
            .unwrap_or_else(|e| {
                tracing::error!(error = %e, "opening the render device crashed");
                RenderService::open(&crate::config::RenderSettings {
                    adapter: "none".into(),
                    ..settings.render.clone()
                })
            });
        Ok(App {
            models: models::ModelRegistry::new(settings.data_dir.clone(), render.clone()),
            render,
            selections: selections::Drafts::default(),
            logins: LoginThrottle::default(),
            uploads: crate::upload_sessions::Sessions::new(
                &settings.uploads_dir(),
                crate::upload_sessions::SESSION_LIFETIME,
            ),
            jobs: Jobs::new(db.clone(), settings.clone(), Some(search.clone())),
            db,
            search,
            settings,
            events: events::Events::new(),
        })
    }

    /// Starts the background work: crash recovery and the build workers, the part views,
    /// and the registry's watch on finished builds (a rebuilt model is reopened).
    pub async fn start(&self) -> Result<Background, StartError> {
        self.jobs
            .start()
            .await
            .map_err(|e| StartError::Jobs(e.to_string()))?;
        let mut builds = self.jobs.subscribe();
        let registry = self.models.clone();
        tokio::spawn(async move {
            use tokio::sync::broadcast::error::RecvError;
            loop {
                match builds.recv().await {
                    Ok(JobEvent {
                        status: JobStatus::Done,
                        model_id: Some(m),
                        ..
                    }) => registry.forget(m),
                    Ok(_) | Err(RecvError::Lagged(_)) => {}
                    Err(RecvError::Closed) => break,
                }
            }
        });
        self.sweep_uploads(self.settings.upload_sweep);
        let views = views::PartViews::start(self);
        Ok(Background { _views: views })
    }

    /// Stops the build workers (their jobs are queued again) and closes the database.
    pub async fn shutdown(&self) {
        self.jobs.shutdown().await;
        self.db.close().await;
    }

    /// Brings the search index up to date after a committed change. A failure is logged,
    /// not returned: the change is durable and the index catches up on the next sync.
    pub async fn sync_search(&self) {
        if let Err(e) = self.search.sync(&self.db).await {
            tracing::error!(error = %e, "search index update failed; will retry");
        }
    }
}
