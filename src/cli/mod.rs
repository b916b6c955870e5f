//! Command-line interface. One file per subcommand; add a variant to [`Command`] and a match
//! arm in [`run`] to extend it. Every subcommand takes `--data-dir` (env `MESHWIKI_DATA_DIR`);
//! settings also come from `MESHWIKI_*` variables. The benchmarks are a separate binary
//! (`bench/`, `meshwiki-bench`): the product binary keeps only what an operator runs.

pub mod demo;
pub mod export_cut;
pub mod import;
pub mod lod;
pub mod reindex;
pub mod render_check;
pub mod serve;
pub mod user;

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use meshwiki::Settings;
use meshwiki::config::{DEFAULT_BIND, DEFAULT_DATA_DIR};

/// meshwiki: a knowledge server that attaches wiki information to regions of huge 3D scans.
#[derive(Debug, Parser)]
#[command(name = "meshwiki", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Serve the web UI and JSON API.
    Serve(ServerArgs),
    /// Manage user accounts.
    #[command(subcommand)]
    User(UserCommand),
    /// Rebuild the full-text search index from the database (stop the server first).
    Reindex(DataDirArgs),
    /// Create (or reset) the demo admin, print its password, seed demo content and (first
    /// run) build the generated demo scan in the background, serve.
    Demo(demo::DemoArgs),
    /// Import a scan: create a model and build its LOD hierarchy, with a progress bar.
    Import(import::Args),
    /// Write the mesh of one cut through a model's hierarchy as binary PLY (`original_id`).
    ExportCut(export_cut::Args),
    /// Developer tools for `.mwlod` files (build one from a scan, dump it as JSON).
    #[command(subcommand)]
    Lod(lod::LodCommand),
    /// The renderer's self-test: open the adapter, render a generated relief, check the image.
    RenderCheck(render_check::Args),
}

/// `user` subcommands.
#[derive(Debug, Subcommand)]
pub enum UserCommand {
    /// Add a user; the password is read from standard input.
    Add(user::AddArgs),
}

/// The data directory.
#[derive(Debug, Clone, Args)]
pub struct DataDirArgs {
    /// Data directory (database, search index, attachments, models).
    #[arg(long, env = "MESHWIKI_DATA_DIR", default_value = DEFAULT_DATA_DIR)]
    pub data_dir: PathBuf,
}

/// Options of the HTTP server.
#[derive(Debug, Clone, Args)]
pub struct ServerArgs {
    /// Data directory.
    #[command(flatten)]
    pub data: DataDirArgs,
    /// Address to listen on (port 0 picks a free port).
    #[arg(long, env = "MESHWIKI_BIND", default_value = DEFAULT_BIND)]
    pub bind: String,
    /// Largest attachment upload, in MiB.
    #[arg(long, env = "MESHWIKI_MAX_UPLOAD_MB", default_value_t = 64)]
    pub max_upload_mb: u64,
    /// Largest JSON request body, in KiB.
    #[arg(long, env = "MESHWIKI_MAX_JSON_KB", default_value_t = 2048)]
    pub max_json_kb: usize,
    /// Mark the session cookie Secure (serve behind HTTPS).
    #[arg(long, env = "MESHWIKI_COOKIE_SECURE")]
    pub cookie_secure: bool,
    /// HTTP worker threads (0: one per core).
    #[arg(long, env = "MESHWIKI_WORKERS", default_value_t = 0)]
    pub workers: usize,
    /// Session lifetime in hours.
    #[arg(long, env = "MESHWIKI_SESSION_HOURS", default_value_t = 336)]
    pub session_hours: i64,
    /// Addresses of reverse proxies whose `X-Forwarded-For` names the client (comma-separated;
    /// without one, the connection's peer address is the client, whatever headers say).
    #[arg(long, env = "MESHWIKI_TRUSTED_PROXIES", value_delimiter = ',')]
    pub trusted_proxies: Vec<std::net::IpAddr>,
    /// Seconds between sweeps of `uploads/` for files of interrupted uploads.
    #[arg(
        long,
        env = "MESHWIKI_UPLOAD_SWEEP_SECS",
        default_value_t = 60,
        hide = true
    )]
    pub upload_sweep_secs: u64,
    /// Largest model (scan) upload, in MiB.
    #[arg(long, env = "MESHWIKI_MAX_MODEL_UPLOAD_MB", default_value_t = 65536)]
    pub max_model_upload_mb: u64,
    /// LOD builds run at the same time.
    #[arg(long, env = "MESHWIKI_BUILD_WORKERS", default_value_t = 1)]
    pub build_workers: usize,
    /// Memory budget of one LOD build (e.g. 512M, 1G).
    #[arg(long, env = "MESHWIKI_BUILD_MEMORY", default_value = "1G", value_parser = meshwiki::jobs::parse_size)]
    pub build_memory: u64,
    /// Threads of one LOD build (0: all cores).
    #[arg(long, env = "MESHWIKI_BUILD_THREADS", default_value_t = 0)]
    pub build_threads: usize,
    /// Storage of a model's image-repository images of refinement levels, rendered when a
    /// reader first asks for them (e.g. 512M, 4G); past it the server renders no more of them
    /// (503) and readers keep the coarser levels.
    #[arg(long, env = "MESHWIKI_REFINED_IMAGES_CAP", default_value = "1G", value_parser = meshwiki::jobs::parse_size)]
    pub refined_images_cap: u64,
    /// Server-side rendering.
    #[command(flatten)]
    pub render: RenderArgs,
}

/// Options of server-side rendering (render API, thumbnails, best views).
#[derive(Debug, Clone, Args)]
pub struct RenderArgs {
    /// GPU adapter: auto (a GPU, else the software adapter), software, hardware or none.
    #[arg(long, env = "MESHWIKI_RENDER_ADAPTER", default_value = "auto")]
    pub render_adapter: String,
    /// Renders running at the same time.
    #[arg(long, env = "MESHWIKI_RENDER_WORKERS", default_value_t = 2)]
    pub render_workers: usize,
    /// Render requests waiting for a worker; more get 503 with Retry-After.
    #[arg(long, env = "MESHWIKI_RENDER_QUEUE", default_value_t = 8)]
    pub render_queue: usize,
    /// Memory that renders in flight may hold together (e.g. 768M, 1G).
    #[arg(long, env = "MESHWIKI_RENDER_MEMORY", default_value = "768M", value_parser = meshwiki::jobs::parse_size)]
    pub render_memory: u64,
    /// Budget of the shared patch cache (e.g. 256M).
    #[arg(long, env = "MESHWIKI_RENDER_CACHE", default_value = "256M", value_parser = meshwiki::jobs::parse_size)]
    pub render_cache: u64,
    /// Largest rendered image, in pixels.
    #[arg(long, env = "MESHWIKI_RENDER_MAX_PIXELS", default_value_t = 2048 * 2048)]
    pub render_max_pixels: u64,
    /// Largest rendered image side, in pixels.
    #[arg(long, env = "MESHWIKI_RENDER_MAX_SIDE", default_value_t = 4096)]
    pub render_max_side: u32,
    /// Longest wait of a queued render request before it gets 503, in seconds.
    #[arg(long, env = "MESHWIKI_RENDER_QUEUE_WAIT", default_value_t = 30)]
    pub render_queue_wait: u64,
}

impl RenderArgs {
    /// The render settings of these options.
    pub fn settings(&self) -> meshwiki::config::RenderSettings {
        meshwiki::config::RenderSettings {
            adapter: self.render_adapter.clone(),
            workers: self.render_workers.clamp(1, 64),
            queue: self.render_queue.min(10_000),
            memory_bytes: self.render_memory.max(16 << 20),
            cache_bytes: self.render_cache.max(1 << 20),
            max_pixels: self.render_max_pixels.clamp(1, 8192 * 8192),
            max_side: self.render_max_side.clamp(16, 8192),
            queue_wait_secs: self.render_queue_wait.clamp(1, 3600),
        }
    }
}

impl ServerArgs {
    /// Settings from these options.
    pub fn settings(&self) -> Settings {
        let mut s = Settings::new(&self.data.data_dir);
        s.bind = self.bind.clone();
        s.cookie_secure = self.cookie_secure;
        s.workers = self.workers;
        s.limits.upload_bytes = self.max_upload_mb.max(1) * 1024 * 1024;
        s.limits.json_body = self.max_json_kb.max(16) * 1024;
        s.limits.session_ttl_secs = self.session_hours.clamp(1, 24 * 365) * 3600;
        s.limits.refined_image_bytes = self.refined_images_cap;
        s.trusted_proxies = self.trusted_proxies.clone();
        s.upload_sweep = std::time::Duration::from_secs(self.upload_sweep_secs.clamp(1, 86_400));
        s.build.upload_bytes = self.max_model_upload_mb.max(1).saturating_mul(1024 * 1024);
        s.build.workers = self.build_workers.clamp(1, 64);
        s.build.memory_budget = self.build_memory.max(64 << 20);
        s.build.threads = (self.build_threads > 0).then_some(self.build_threads);
        s.render = self.render.settings();
        s
    }
}

/// Runs a parsed command line.
pub async fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Serve(args) => serve::run(args).await,
        Command::User(UserCommand::Add(args)) => user::add(args).await,
        Command::Reindex(args) => reindex::run(args).await,
        Command::Demo(args) => demo::run(args).await,
        Command::Import(args) => import::run(args).await,
        Command::ExportCut(args) => export_cut::run(args).await,
        Command::Lod(command) => lod::run(command),
        Command::RenderCheck(args) => {
            tokio::task::spawn_blocking(move || render_check::run(&args)).await?
        }
    }
}
