//! Settings: where the data directory lives, what it contains, and the server's limits.
//!
//! Layout of the data directory:
//! ```text
//! meshwiki.db            SQLite database (WAL)
//! index/                 tantivy full-text index
//! attachments/ab/cdef..  attachment files, content-addressed by SHA-256
//! models/                LOD files of imported scans (`<model id>.mwlod`)
//! uploads/               files being received, and uploaded scans awaiting their build
//! ```

use std::path::{Path, PathBuf};

/// What `meshwiki serve` prints on standard output, followed by its address, once it
/// listens (tests and benches wait for it).
pub const LISTENING: &str = "meshwiki listening on ";

/// Default interval of the sweep of `uploads/` for files of interrupted uploads.
pub const UPLOAD_SWEEP_EVERY: std::time::Duration = std::time::Duration::from_secs(60);

/// Default bind address of `meshwiki serve`.
pub const DEFAULT_BIND: &str = "127.0.0.1:8080";
/// Default data directory.
pub const DEFAULT_DATA_DIR: &str = "./data";

/// Size and time limits of the server.
#[derive(Debug, Clone)]
pub struct Limits {
    /// Largest JSON request body, in bytes.
    pub json_body: usize,
    /// Largest URL-encoded form body, in bytes.
    pub form_body: usize,
    /// Largest uploaded attachment, in bytes.
    pub upload_bytes: u64,
    /// Longest title, in characters.
    pub title_chars: usize,
    /// Longest content body, in bytes.
    pub body_bytes: usize,
    /// Largest number of vertex ids in a region part.
    pub part_vertices: usize,
    /// Session lifetime in seconds.
    pub session_ttl_secs: i64,
    /// Bytes of a model's image-repository images of refinement levels (rendered when first
    /// asked for, by any reader) past which no more are rendered.
    pub refined_image_bytes: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            json_body: 2 * 1024 * 1024,
            form_body: 2 * 1024 * 1024,
            upload_bytes: 64 * 1024 * 1024,
            title_chars: 300,
            body_bytes: 1024 * 1024,
            part_vertices: 50_000_000,
            session_ttl_secs: 14 * 24 * 3600,
            refined_image_bytes: 1 << 30,
        }
    }
}

/// Settings of background LOD builds (jobs) and model uploads.
#[derive(Debug, Clone)]
pub struct BuildSettings {
    /// Builds run at the same time.
    pub workers: usize,
    /// Memory budget of one build, in bytes.
    pub memory_budget: u64,
    /// Worker threads of one build (`None`: all cores).
    pub threads: Option<usize>,
    /// Triangle budget of a patch.
    pub max_patch_triangles: u32,
    /// Largest model upload, in bytes.
    pub upload_bytes: u64,
}

impl Default for BuildSettings {
    fn default() -> Self {
        BuildSettings {
            workers: 1,
            memory_budget: 1 << 30,
            threads: None,
            max_patch_triangles: meshwiki_engine::lod::build::DEFAULT_MAX_PATCH_TRIANGLES,
            upload_bytes: 64 << 30,
        }
    }
}

/// Settings of server-side rendering (`MESHWIKI_RENDER_*`): the GPU adapter, the bounded
/// worker pool and its memory budgets (see `crate::render`).
#[derive(Debug, Clone)]
pub struct RenderSettings {
    /// `auto` (a GPU when present, else the software adapter), `software`, `hardware`, or
    /// `none` (rendering off).
    pub adapter: String,
    /// Renders running at the same time.
    pub workers: usize,
    /// Render requests waiting for a worker; more get 503 with `Retry-After`.
    pub queue: usize,
    /// Bytes that renders in flight may hold together (render targets, read-back, responses).
    pub memory_bytes: u64,
    /// Budget of the shared patch cache (resident bytes).
    pub cache_bytes: u64,
    /// Largest image, in pixels.
    pub max_pixels: u64,
    /// Largest image side, in pixels.
    pub max_side: u32,
    /// Longest wait of a queued request before it gets 503, in seconds.
    pub queue_wait_secs: u64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            adapter: "auto".into(),
            workers: 2,
            queue: 8,
            memory_bytes: 768 << 20,
            cache_bytes: 256 << 20,
            max_pixels: 2048 * 2048,
            max_side: 4096,
            queue_wait_secs: 30,
        }
    }
}

/// Server settings, built by the CLI from flags and `MESHWIKI_*` environment variables.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Root of the data directory.
    pub data_dir: PathBuf,
    /// Address the HTTP server binds to.
    pub bind: String,
    /// Mark the session cookie `Secure` (set when served over HTTPS).
    pub cookie_secure: bool,
    /// Number of HTTP worker threads (0: one per core).
    pub workers: usize,
    /// Reverse proxies trusted to name the client in `X-Forwarded-For`.
    pub trusted_proxies: Vec<std::net::IpAddr>,
    /// How often `uploads/` is swept for files of interrupted uploads.
    pub upload_sweep: std::time::Duration,
    /// Limits.
    pub limits: Limits,
    /// Background builds.
    pub build: BuildSettings,
    /// Server-side rendering.
    pub render: RenderSettings,
}

impl Settings {
    /// Settings for `data_dir` with every other value at its default.
    pub fn new(data_dir: impl Into<PathBuf>) -> Self {
        Settings {
            data_dir: data_dir.into(),
            bind: DEFAULT_BIND.to_string(),
            cookie_secure: false,
            workers: 0,
            trusted_proxies: Vec::new(),
            upload_sweep: UPLOAD_SWEEP_EVERY,
            limits: Limits::default(),
            build: BuildSettings::default(),
            render: RenderSettings::default(),
        }
    }

    /// The SQLite database file.
    pub fn db_path(&self) -> PathBuf {
        self.data_dir.join("meshwiki.db")
    }

    /// The tantivy index directory.
    pub fn index_dir(&self) -> PathBuf {
        self.data_dir.join("index")
    }

    /// Root of the content-addressed attachment store.
    pub fn attachments_dir(&self) -> PathBuf {
        self.data_dir.join("attachments")
    }

    /// Directory reserved for LOD files of imported models.
    pub fn models_dir(&self) -> PathBuf {
        self.data_dir.join("models")
    }

    /// Directory of the image repositories' images (content-addressed, as attachments).
    pub fn lumigraph_dir(&self) -> PathBuf {
        self.data_dir.join("lumigraph")
    }

    /// Path of the repository image with the given SHA-256 (hex): `lumigraph/ab/cdef...`.
    pub fn lumigraph_path(&self, sha256: &str) -> Option<PathBuf> {
        content_path(&self.lumigraph_dir(), sha256)
    }

    /// Directory for files being received (temporary names, renamed when complete).
    pub fn uploads_dir(&self) -> PathBuf {
        self.data_dir.join("uploads")
    }

    /// Path of the attachment with the given SHA-256 (hex): `attachments/ab/cdef...`.
    /// Returns `None` unless `sha256` is 64 lower-case hex digits, so no caller-supplied
    /// string can ever become a path.
    pub fn attachment_path(&self, sha256: &str) -> Option<PathBuf> {
        content_path(&self.attachments_dir(), sha256)
    }

    /// Creates the data directory and its sub-directories.
    pub fn ensure_dirs(&self) -> std::io::Result<()> {
        for dir in [
            self.data_dir.clone(),
            self.index_dir(),
            self.attachments_dir(),
            self.models_dir(),
            self.uploads_dir(),
            self.lumigraph_dir(),
        ] {
            std::fs::create_dir_all(&dir)?;
        }
        Ok(())
    }

    /// The data directory.
    pub fn data_dir(&self) -> &Path {
        &self.data_dir
    }
}

/// `dir/ab/cdef...` for a well-formed SHA-256 (64 lower-case hex digits), else `None`.
fn content_path(dir: &Path, sha256: &str) -> Option<PathBuf> {
    if sha256.len() != 64
        || !sha256
            .bytes()
            .all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
    {
        return None;
    }
    Some(dir.join(&sha256[..2]).join(&sha256[2..]))
}
