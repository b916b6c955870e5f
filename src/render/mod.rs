//! Server-side rendering (issue 4): one [`RenderService`] per process owns the GPU device
//! (a hardware adapter when there is one, else Mesa's lavapipe), the engine's [`Renderer`]
//! with its patch cache (one global budget), and the bounded worker pool ([`pool`]) every
//! render goes through: the render API (`web::render`), selections (`app::selections`), model
//! thumbnails (`jobs::thumbnail`) and part thumbnails and best views (`app::views`). Models
//! are opened by the application's model registry (`app::models`), which drops a closed
//! model's patches from the cache.
//!
//! Where no adapter opens, the service is *unavailable*: it logs why once at start-up, the
//! render routes answer 503 with that message, and everything else is served as usual.

pub mod pool;

use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use meshwiki_engine::camera::Camera;
use meshwiki_engine::render::encode::{self, EncodeError, ImageFormat};
use meshwiki_engine::render::{
    AdapterChoice, Highlight, Outputs, RenderError, RenderModel, RenderOptions, Renderer,
    RendererOptions,
};

use crate::config::RenderSettings;
pub use pool::{MemoryHold, Pool, PoolError, Ticket};

/// Why a render could not be served.
#[derive(Debug, thiserror::Error)]
pub enum RenderServiceError {
    /// No GPU adapter (or rendering switched off).
    #[error("server-side rendering is unavailable: {0}")]
    Unavailable(String),
    /// Not admitted by the pool.
    #[error(transparent)]
    Pool(#[from] PoolError),
    /// The request cannot be rendered as asked (size, camera, options).
    #[error("{0}")]
    Invalid(String),
    /// The GPU ran out of memory; retrying later may work.
    #[error("the renderer is out of GPU memory; retry later")]
    OutOfMemory,
    /// The LOD file cannot be opened or read.
    #[error("cannot read the model's LOD file: {0}")]
    Lod(String),
    /// The GPU or the render task failed.
    #[error("render failed: {0}")]
    Failed(String),
    /// The image could not be encoded.
    #[error("cannot encode the image: {0}")]
    Encode(#[from] EncodeError),
}

impl From<RenderError> for RenderServiceError {
    fn from(e: RenderError) -> Self {
        match e {
            RenderError::Camera(_)
            | RenderError::TooManyPixels { .. }
            | RenderError::TooWide { .. }
            | RenderError::BadOption(_)
            | RenderError::TooManyTints { .. } => RenderServiceError::Invalid(e.to_string()),
            RenderError::OutOfMemory => RenderServiceError::OutOfMemory,
            RenderError::Patch { .. } | RenderError::BadNode(_) => {
                RenderServiceError::Lod(e.to_string())
            }
            RenderError::Gpu(m) => RenderServiceError::Failed(m),
        }
    }
}

struct Inner {
    renderer: Result<Arc<Renderer>, String>,
    adapter: Option<String>,
    pool: Pool,
    settings: RenderSettings,
}

/// The process's renderer, pool and open models (cheap to clone).
#[derive(Clone)]
pub struct RenderService {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for RenderService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RenderService")
            .field("adapter", &self.inner.adapter)
            .field("admitted", &self.inner.pool.admitted())
            .finish()
    }
}

impl RenderService {
    /// Opens the adapter named by `settings.adapter` (blocking, up to a second or so) and
    /// logs which one it picked, or why there is none.
    pub fn open(settings: &RenderSettings) -> RenderService {
        let renderer = match settings.adapter.trim().to_ascii_lowercase().as_str() {
            "none" | "off" => {
                Err("rendering is switched off (MESHWIKI_RENDER_ADAPTER=none)".into())
            }
            name => match AdapterChoice::parse(name) {
                None => Err(format!(
                    "unknown render adapter {name:?} (expected auto, software, hardware or none)"
                )),
                Some(choice) => {
                    let options = RendererOptions {
                        cache_bytes: settings.cache_bytes.max(1 << 20),
                        batch_bytes: (settings.cache_bytes / 3).clamp(1 << 20, 96 << 20),
                        max_pixels: settings
                            .max_pixels
                            .clamp(1, Camera::MAX_SIDE as u64 * Camera::MAX_SIDE as u64),
                    };
                    Renderer::open(choice, options)
                        .map(Arc::new)
                        .map_err(|e| e.to_string())
                }
            },
        };
        let adapter = match &renderer {
            Ok(r) => {
                let d = r.device();
                tracing::info!(
                    adapter = %d.describe(),
                    software = d.is_software(),
                    workers = settings.workers,
                    queue = settings.queue,
                    memory_mb = settings.memory_bytes >> 20,
                    cache_mb = settings.cache_bytes >> 20,
                    "server-side rendering ready"
                );
                Some(d.describe())
            }
            Err(e) => {
                tracing::error!(
                    error = %e,
                    "server-side rendering unavailable: render routes answer 503, thumbnails \
                     use the CPU fallback, parts get no best view"
                );
                None
            }
        };
        RenderService {
            inner: Arc::new(Inner {
                renderer,
                adapter,
                pool: Pool::new(
                    settings.workers,
                    settings.queue,
                    settings.memory_bytes,
                    Duration::from_secs(settings.queue_wait_secs.max(1)),
                ),
                settings: settings.clone(),
            }),
        }
    }

    /// The process-wide service (one device, one cache, one pool), opened with `settings`
    /// on first use.
    pub fn shared(settings: &RenderSettings) -> RenderService {
        static SHARED: OnceLock<RenderService> = OnceLock::new();
        SHARED.get_or_init(|| RenderService::open(settings)).clone()
    }

    /// The renderer, or why there is none.
    pub fn renderer(&self) -> Result<&Arc<Renderer>, RenderServiceError> {
        self.inner
            .renderer
            .as_ref()
            .map_err(|e| RenderServiceError::Unavailable(e.clone()))
    }

    /// Whether renders can be served.
    pub fn available(&self) -> bool {
        self.inner.renderer.is_ok()
    }

    /// Name, type and backend of the adapter in use.
    pub fn adapter(&self) -> Option<&str> {
        self.inner.adapter.as_deref()
    }

    /// The settings it was opened with.
    pub fn settings(&self) -> &RenderSettings {
        &self.inner.settings
    }

    /// The worker pool.
    pub fn pool(&self) -> &Pool {
        &self.inner.pool
    }

    /// Admits a foreground (HTTP) render holding `bytes` (see [`Pool::admit`]).
    pub async fn admit(&self, bytes: u64) -> Result<Ticket, RenderServiceError> {
        self.renderer()?;
        Ok(self.inner.pool.admit(bytes).await?)
    }

    /// Admits background work holding `bytes` (see [`Pool::admit_background`]).
    pub async fn admit_background(&self, bytes: u64) -> Result<Ticket, RenderServiceError> {
        self.renderer()?;
        Ok(self.inner.pool.admit_background(bytes).await?)
    }

    /// Runs `f` with the renderer on a blocking thread under `ticket`. The ticket travels
    /// with the work, so a request dropped by its client still holds its worker and memory
    /// until the render ends; what is returned keeps the ticket's memory (for the response).
    pub async fn run<T, F>(
        &self,
        ticket: Ticket,
        f: F,
    ) -> Result<(T, MemoryHold), RenderServiceError>
    where
        F: FnOnce(&Renderer) -> T + Send + 'static,
        T: Send + 'static,
    {
        let renderer = self.renderer()?.clone();
        let started = Instant::now();
        let (out, ticket) = tokio::task::spawn_blocking(move || (f(&renderer), ticket))
            .await
            .map_err(|e| RenderServiceError::Failed(format!("render task: {e}")))?;
        self.inner.pool.record(started.elapsed());
        Ok((out, ticket.into_memory()))
    }

    /// [`RenderService::run`] for callers on a blocking thread (model thumbnails at the end
    /// of a build): waits for a worker as background work. Outside a tokio runtime it runs
    /// without admission.
    pub fn run_blocking<T>(
        &self,
        bytes: u64,
        f: impl FnOnce(&Renderer) -> T,
    ) -> Result<T, RenderServiceError> {
        let renderer = self.renderer()?;
        let _ticket = match tokio::runtime::Handle::try_current() {
            Ok(h) => Some(h.block_on(self.inner.pool.admit_background(bytes))?),
            Err(_) => None,
        };
        let started = Instant::now();
        let out = f(renderer);
        self.inner.pool.record(started.elapsed());
        Ok(out)
    }
}

/// Bytes a thumbnail of `width`×`height` holds at its peak (frame and encoded image).
pub fn thumbnail_bytes(width: u32, height: u32) -> u64 {
    Outputs::IMAGE.frame_bytes(width, height) + width as u64 * height as u64 * 4
}

/// Renders a thumbnail, the one code path of model and part thumbnails: the 1-pixel cut from
/// `camera` (whose size is the thumbnail's), `highlights` tinted, transparent background,
/// as PNG.
pub fn thumbnail_png(
    renderer: &Renderer,
    model: &RenderModel,
    camera: &Camera,
    highlights: &[Highlight<'_>],
) -> Result<Vec<u8>, RenderServiceError> {
    let options = RenderOptions {
        outputs: Outputs::IMAGE,
        ..RenderOptions::default()
    };
    let frame = renderer.render(model, camera, &options, highlights)?;
    let color = frame
        .color
        .ok_or_else(|| RenderServiceError::Failed("no colour buffer".into()))?;
    Ok(encode::encode(
        &color,
        camera.width,
        camera.height,
        ImageFormat::Png,
        90,
        [255, 255, 255],
    )?)
}
