//! Headless rendering of hierarchy cuts with wgpu (system paper §3.3, §4.1.1, §4.1.2, §2.2).
//!
//! A [`Renderer`] draws the view-dependent cut of a [`RenderModel`] for a [`Camera`]: frustum and
//! normal-cone culling with refinement to a pixel threshold ([`crate::lod::cut_view`]), patches
//! streamed through an out-of-core GPU cache with a byte budget ([`cache`]). It returns the
//! buffers a caller asks for as flat arrays: shaded colour, per-pixel normal, linear depth and
//! the id buffer (node, original vertex id, triangle) selection runs on, with parts tinted and
//! the hovered part outlined ([`highlight`]). [`callouts`] lays out part labels, [`best_view`]
//! finds a camera for a part, [`encode`] writes PNG/JPEG/WebP.
//!
//! A `Renderer` is `Send + Sync`; `render(&self, ...)` may be called from several threads.

pub mod best_view;
pub mod cache;
pub mod callouts;
pub mod device;
pub mod encode;
mod font;
mod frame;
pub mod highlight;
mod pipeline;

pub use cache::CacheStats;
pub use device::{AdapterChoice, DeviceError, GpuDevice};
pub use highlight::Highlight;

use crate::camera::{Camera, CameraError};
use crate::lod::{Culling, FormatError, LodFile, cut};
use crate::segment::{SegmentFile, SegmentFileError};
use cache::{GpuPatch, Key, PatchCache};
use glam::Vec3;
use highlight::Prepared;
use pipeline::Pipelines;
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// `IdBuffer::node` of background pixels.
pub const NO_NODE: u32 = u32::MAX;
/// `IdBuffer::vertex` / `triangle` of background pixels.
pub const NO_ID: u32 = u32::MAX;
/// Mask bit set in `IdBuffer::highlight` on every covered pixel.
pub const COVERED_BIT: u32 = 1 << 31;
/// Patches decoded at a time before their upload.
const UPLOAD_CHUNK: usize = 32;
/// How long a render waits for the GPU before giving up.
const GPU_TIMEOUT: Duration = Duration::from_secs(120);

/// Why a render failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("invalid camera: {0}")]
    Camera(#[from] CameraError),
    #[error("image of {width}x{height} pixels exceeds the limit of {max} pixels")]
    TooManyPixels { width: u32, height: u32, max: u64 },
    #[error("image side {side} exceeds the device limit of {max}")]
    TooWide { side: u32, max: u32 },
    #[error("invalid render option: {0}")]
    BadOption(String),
    #[error("at most {max} tinted parts per render, got {count}")]
    TooManyTints { count: usize, max: usize },
    #[error("node {0} is not in the model")]
    BadNode(u32),
    #[error("patch {node} cannot be read: {source}")]
    Patch { node: u32, source: FormatError },
    #[error("GPU out of memory")]
    OutOfMemory,
    #[error("GPU error: {0}")]
    Gpu(String),
}

/// The segments beside the LOD file at `lod` (`.mwseg`), if there is a valid one for it; a
/// missing file is normal (models built before segments), an invalid one is logged and
/// ignored (selection then works on the pixels alone).
pub fn open_segments(lod: &Path) -> Option<Arc<SegmentFile>> {
    let path = crate::segment::path_for(lod);
    match SegmentFile::open(&path) {
        Ok(f) => Some(Arc::new(f)),
        Err(SegmentFileError::Io(e)) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => {
            tracing::warn!(path = %path.display(), error = %e, "segment file ignored");
            None
        }
    }
}

/// A model the renderer can draw: an open LOD file and a process-unique id (its cache key).
#[derive(Clone)]
pub struct RenderModel {
    id: u64,
    lod: Arc<LodFile>,
    radius: f32,
    /// The surface segments of the scan, when its build made them.
    segments: Option<Arc<SegmentFile>>,
}

static NEXT_MODEL: AtomicU64 = AtomicU64::new(1);

impl RenderModel {
    /// Wraps an open LOD file.
    pub fn new(lod: Arc<LodFile>) -> RenderModel {
        let h = lod.header();
        let (lo, hi) = (Vec3::from(h.bbox_min), Vec3::from(h.bbox_max));
        let mut radius = (hi - lo).length() * 0.5;
        if !radius.is_finite() || radius <= 0.0 {
            radius = lod
                .nodes()
                .iter()
                .map(|n| n.bounds[3])
                .fold(0.0, f32::max)
                .max(1e-6);
        }
        RenderModel {
            id: NEXT_MODEL.fetch_add(1, Ordering::Relaxed),
            lod,
            radius,
            segments: None,
        }
    }

    /// The model with its surface segments.
    pub fn with_segments(mut self, segments: Option<Arc<SegmentFile>>) -> RenderModel {
        self.segments = segments;
        self
    }

    /// The surface segments, if the model has them.
    pub fn segments(&self) -> Option<&SegmentFile> {
        self.segments.as_deref()
    }

    /// Opens (maps and validates) a `.mwlod` file, and the segments beside it when there are
    /// any ([`open_segments`]).
    pub fn open(path: &Path) -> Result<RenderModel, FormatError> {
        Ok(RenderModel::new(Arc::new(LodFile::open(path)?)).with_segments(open_segments(path)))
    }

    pub fn id(&self) -> u64 {
        self.id
    }

    pub fn lod(&self) -> &LodFile {
        &self.lod
    }

    /// Centre of the model's bounding box.
    pub fn center(&self) -> Vec3 {
        let h = self.lod.header();
        (Vec3::from(h.bbox_min) + Vec3::from(h.bbox_max)) * 0.5
    }

    /// Half the diagonal of the model's bounding box.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Side lengths of the model's bounding box along x, y and z.
    pub fn extents(&self) -> [f32; 3] {
        let h = self.lod.header();
        [0, 1, 2].map(|k| (h.bbox_max[k] - h.bbox_min[k]).abs())
    }

    /// The axis (0 = x, 1 = y, 2 = z) along which the bounding box is thinnest: the way a
    /// relief faces.
    pub fn thin_axis(&self) -> usize {
        let ext = self.extents();
        (0..3)
            .min_by(|&a, &b| ext[a].total_cmp(&ext[b]))
            .unwrap_or(2)
    }

    /// The three original vertex ids of triangle `triangle` of patch `node` (as in the id
    /// buffer), decoded from the file.
    pub fn triangle_ids(&self, node: u32, triangle: u32) -> Result<[u32; 3], RenderError> {
        let p = self
            .lod
            .patch(node)
            .map_err(|source| RenderError::Patch { node, source })?;
        let t = triangle as usize * 3;
        let tri = p.indices.get(t..t + 3).ok_or(RenderError::BadNode(node))?;
        let id = |i: u32| {
            p.original_ids
                .get(i as usize)
                .copied()
                .ok_or(RenderError::BadNode(node))
        };
        Ok([id(tri[0])?, id(tri[1])?, id(tri[2])?])
    }
}

/// Which patches to draw.
#[derive(Debug, Clone, PartialEq)]
pub enum Cut {
    /// View-dependent cut: culled, refined until the projected error is at most `pixel_error`.
    View { pixel_error: f32, culling: Culling },
    /// Every patch within `max_error` (object space) of the scan; `0` = full resolution.
    Uniform { max_error: f32, frustum: bool },
    /// These nodes.
    Nodes(Vec<u32>),
}

impl Default for Cut {
    /// The paper's default: 1 pixel, all culling.
    fn default() -> Self {
        Cut::View {
            pixel_error: 1.0,
            culling: Culling::ALL,
        }
    }
}

/// Which buffers to read back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Outputs {
    pub color: bool,
    pub normal: bool,
    pub depth: bool,
    pub ids: bool,
}

impl Outputs {
    /// Rough bytes one render of `width`×`height` pixels holds at its peak (render targets,
    /// read-back buffers and returned arrays), for admission control by callers.
    pub fn frame_bytes(&self, width: u32, height: u32) -> u64 {
        let px = width as u64 * height as u64;
        let buffers = self.normal || self.ids;
        // colour + mask/normal + depth targets, ids target in buffers mode
        let mut per_px = 4 + 4 + 4 + if buffers { 16 } else { 0 };
        // read-back copies and the returned arrays
        per_px += if self.color { 4 + 4 } else { 0 };
        per_px += if self.normal { 4 + 12 } else { 0 };
        per_px += if self.depth { 4 + 4 } else { 0 };
        per_px += if self.ids { 16 + 16 } else { 0 };
        px * per_px
    }

    /// Shaded colour only (images, thumbnails).
    pub const IMAGE: Outputs = Outputs {
        color: true,
        normal: false,
        depth: false,
        ids: false,
    };
    /// Colour and depth (images with callouts: depth decides which anchors are visible).
    pub const IMAGE_DEPTH: Outputs = Outputs {
        color: true,
        normal: false,
        depth: true,
        ids: false,
    };
    /// Everything (selection).
    pub const ALL: Outputs = Outputs {
        color: true,
        normal: true,
        depth: true,
        ids: true,
    };
}

/// Options of one render.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    pub cut: Cut,
    pub outputs: Outputs,
    /// Colour of pixels with no surface.
    pub background: [u8; 4],
    /// Albedo of models without vertex colours.
    pub base_color: [u8; 4],
    /// Ambient light; the headlight contributes `1 - ambient`.
    pub ambient: f32,
    /// Outline of outlined (hovered) parts: colour (alpha = opacity) and width in pixels.
    pub outline_color: [u8; 4],
    pub outline_width: u32,
    /// Draw only this rectangle of the camera's view, `[x, y, width, height]` in pixels: the
    /// frame is that size ([`Frame::origin`] its corner in the view) and holds the view's own
    /// pixels (the cut is the whole view's; patches wholly outside the rectangle are not
    /// drawn). `None`: the whole view.
    pub window: Option<[u32; 4]>,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            cut: Cut::default(),
            outputs: Outputs::IMAGE,
            background: [0, 0, 0, 0],
            base_color: [209, 204, 194, 255],
            ambient: 0.25,
            outline_color: [255, 214, 0, 255],
            outline_width: 3,
            window: None,
        }
    }
}

/// Largest outline width accepted, in pixels.
pub const MAX_OUTLINE_WIDTH: u32 = 16;

/// The id buffer: per pixel, the node drawn there, the original id of the triangle corner
/// nearest to the pixel centre (always a vertex of that triangle), the triangle's index within
/// the node's patch ([`RenderModel::triangle_ids`] gives its three original ids) and the highlight
/// mask (tint index, [`highlight::OUTLINE_BIT`], [`COVERED_BIT`]). Background: [`NO_NODE`],
/// [`NO_ID`], [`NO_ID`], 0. Row-major, top row first.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IdBuffer {
    pub node: Vec<u32>,
    pub vertex: Vec<u32>,
    pub triangle: Vec<u32>,
    pub highlight: Vec<u32>,
}

/// What a render did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct RenderStats {
    /// Patches and triangles drawn.
    pub nodes: usize,
    pub triangles: u64,
    /// Patches decoded and uploaded for this render (cache misses).
    pub loaded: usize,
    pub hits: usize,
    pub batches: usize,
    /// Vertices of drawn patches inside a highlighted part (shared border vertices count once
    /// per patch).
    pub highlighted_vertices: u64,
    /// Near plane used (world units).
    pub near: f32,
    pub cut_ms: f64,
    pub load_ms: f64,
    /// Encoding, GPU work and read-back (everything but the cut and the patch loads).
    pub draw_ms: f64,
    pub total_ms: f64,
    pub cache: CacheStats,
    /// Where the draw time went.
    pub profile: FrameProfile,
}

/// Where a frame's time went (milliseconds), pass by pass, for the render bench's profile.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct FrameProfile {
    /// Creating the render targets and the frame's uniforms.
    pub targets_ms: f64,
    /// Recording the passes (draw records, masks, bind groups, commands).
    pub encode_ms: f64,
    /// Submitting them (a software adapter may do part of the drawing here: it transforms
    /// vertices on the submitting thread).
    pub submit_ms: f64,
    /// Waiting for the GPU to finish drawing (and copying into the read-back buffers).
    pub gpu_ms: f64,
    /// Mapping the read-back buffers and decoding the frame's buffers from them.
    pub read_ms: f64,
    /// Bytes read back.
    pub read_bytes: u64,
}

/// A rendered frame; buffers not asked for are `None`. Row-major, top row first.
#[derive(Debug, Clone, Default)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    /// Where the frame's top-left pixel lies in the camera's view (`[0, 0]` unless a
    /// [`RenderOptions::window`] was drawn).
    pub origin: [u32; 2],
    /// Shaded colour (RGBA8, alpha 255 on the surface, the background colour elsewhere).
    pub color: Option<Vec<[u8; 4]>>,
    /// World-space unit normal facing the viewer; zero on the background.
    pub normal: Option<Vec<[f32; 3]>>,
    /// Linear view depth (distance along the view direction); `f32::INFINITY` on the background.
    pub depth: Option<Vec<f32>>,
    pub ids: Option<IdBuffer>,
    pub stats: RenderStats,
}

impl Frame {
    /// The frame placed in a `width` × `height` view at its origin, the rest background
    /// (colour 0, normal 0, depth `INFINITY`, ids [`NO_NODE`], [`NO_ID`], [`NO_ID`], 0): the
    /// frame a render of the whole view gives inside the window.
    pub fn embed(self, width: u32, height: u32) -> Frame {
        let [ox, oy] = self.origin;
        if self.origin == [0, 0] && self.width == width && self.height == height {
            return self;
        }
        let (fw, fh) = (self.width as usize, self.height as usize);
        let (w, h) = (width as usize, height as usize);
        let (ox, oy) = (ox as usize, oy as usize);
        fn place<T: Copy>(src: &[T], background: T, f: [usize; 4], [w, h]: [usize; 2]) -> Vec<T> {
            let [ox, oy, fw, fh] = f;
            let mut out = vec![background; w * h];
            let n = fw.min(w.saturating_sub(ox));
            for y in 0..fh.min(h.saturating_sub(oy)) {
                let at = (oy + y) * w + ox;
                out[at..at + n].copy_from_slice(&src[y * fw..y * fw + n]);
            }
            out
        }
        let f = [ox, oy, fw, fh];
        let v = [w, h];
        Frame {
            width,
            height,
            origin: [0, 0],
            color: self.color.as_deref().map(|c| place(c, [0u8; 4], f, v)),
            normal: self.normal.as_deref().map(|n| place(n, [0f32; 3], f, v)),
            depth: self.depth.as_deref().map(|d| place(d, f32::INFINITY, f, v)),
            ids: self.ids.as_ref().map(|ids| IdBuffer {
                node: place(&ids.node, NO_NODE, f, v),
                vertex: place(&ids.vertex, NO_ID, f, v),
                triangle: place(&ids.triangle, NO_ID, f, v),
                highlight: place(&ids.highlight, 0, f, v),
            }),
            stats: self.stats,
        }
    }
}

/// Renderer settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RendererOptions {
    /// Budget of the patch cache (resident bytes).
    pub cache_bytes: u64,
    /// Most patch bytes one render pins at a time; larger cuts are drawn in several batches.
    pub batch_bytes: u64,
    /// Largest image, in pixels (at most `Camera::MAX_SIDE²`).
    pub max_pixels: u64,
}

impl Default for RendererOptions {
    fn default() -> Self {
        RendererOptions {
            cache_bytes: 512 << 20,
            batch_bytes: 96 << 20,
            max_pixels: 4096 * 4096,
        }
    }
}

/// Headless renderer: device, pipelines and patch cache.
pub struct Renderer {
    gpu: Arc<GpuDevice>,
    pipelines: Pipelines,
    cache: PatchCache,
    options: RendererOptions,
}

fn gpu_err(e: wgpu::Error) -> RenderError {
    match e {
        wgpu::Error::OutOfMemory { .. } => RenderError::OutOfMemory,
        other => RenderError::Gpu(other.to_string()),
    }
}

impl Renderer {
    /// A renderer on an open device.
    pub fn new(gpu: Arc<GpuDevice>, options: RendererOptions) -> Renderer {
        let pipelines = Pipelines::new(&gpu.device, &gpu.queue);
        Renderer {
            pipelines,
            cache: PatchCache::new(options.cache_bytes),
            gpu,
            options,
        }
    }

    /// Opens a device (see [`AdapterChoice`]) and makes a renderer on it.
    pub fn open(choice: AdapterChoice, options: RendererOptions) -> Result<Renderer, DeviceError> {
        Ok(Renderer::new(GpuDevice::new(choice)?, options))
    }

    pub fn device(&self) -> &GpuDevice {
        &self.gpu
    }

    pub fn options(&self) -> &RendererOptions {
        &self.options
    }

    pub fn cache_stats(&self) -> CacheStats {
        self.cache.stats()
    }

    /// Drops a model's patches from the cache.
    pub fn forget(&self, model: &RenderModel) {
        self.cache.forget_model(model.id);
    }

    /// Drops every cached patch.
    pub fn clear_cache(&self) {
        self.cache.clear();
    }

    /// Colour image (RGBA8, row-major) of the default 1-pixel cut.
    pub fn render_image(
        &self,
        model: &RenderModel,
        camera: &Camera,
        highlights: &[Highlight<'_>],
    ) -> Result<Frame, RenderError> {
        self.render(model, camera, &RenderOptions::default(), highlights)
    }

    /// Every buffer (colour, normal, depth, ids) of the default 1-pixel cut, for selection.
    pub fn render_buffers(
        &self,
        model: &RenderModel,
        camera: &Camera,
        highlights: &[Highlight<'_>],
    ) -> Result<Frame, RenderError> {
        let options = RenderOptions {
            outputs: Outputs::ALL,
            ..RenderOptions::default()
        };
        self.render(model, camera, &options, highlights)
    }

    /// Checks a render's parameters.
    pub fn validate(&self, camera: &Camera, options: &RenderOptions) -> Result<(), RenderError> {
        camera.validate()?;
        let (w, h) = (camera.width, camera.height);
        let max = self
            .options
            .max_pixels
            .min(Camera::MAX_SIDE as u64 * Camera::MAX_SIDE as u64);
        if w as u64 * h as u64 > max {
            return Err(RenderError::TooManyPixels {
                width: w,
                height: h,
                max,
            });
        }
        let side_max = self.gpu.limits.max_texture_dimension_2d;
        if w.max(h) > side_max {
            return Err(RenderError::TooWide {
                side: w.max(h),
                max: side_max,
            });
        }
        match &options.cut {
            Cut::View { pixel_error, .. } if !(pixel_error.is_finite() && *pixel_error >= 0.0) => {
                return Err(RenderError::BadOption(format!(
                    "pixel error must be finite and >= 0, got {pixel_error}"
                )));
            }
            Cut::Uniform { max_error, .. } if !(max_error.is_finite() && *max_error >= 0.0) => {
                return Err(RenderError::BadOption(format!(
                    "max error must be finite and >= 0, got {max_error}"
                )));
            }
            _ => {}
        }
        let o = options.outputs;
        if !(o.color || o.normal || o.depth || o.ids) {
            return Err(RenderError::BadOption("no output requested".into()));
        }
        if !(options.ambient.is_finite() && (0.0..=1.0).contains(&options.ambient)) {
            return Err(RenderError::BadOption(format!(
                "ambient must be within [0, 1], got {}",
                options.ambient
            )));
        }
        if let Some([x, y, ww, wh]) = options.window
            && (ww == 0
                || wh == 0
                || x.checked_add(ww).is_none_or(|e| e > w)
                || y.checked_add(wh).is_none_or(|e| e > h))
        {
            return Err(RenderError::BadOption(format!(
                "window {x},{y} {ww}x{wh} is not a non-empty rectangle of the {w}x{h} view"
            )));
        }
        if options.outline_width > MAX_OUTLINE_WIDTH {
            return Err(RenderError::BadOption(format!(
                "outline width must be at most {MAX_OUTLINE_WIDTH}, got {}",
                options.outline_width
            )));
        }
        Ok(())
    }

    /// The nodes a render draws, front to back.
    pub fn cut_nodes(
        &self,
        model: &RenderModel,
        camera: &Camera,
        cut_spec: &Cut,
    ) -> Result<Vec<u32>, RenderError> {
        let nodes = model.lod.nodes();
        let mut list = match cut_spec {
            Cut::View {
                pixel_error,
                culling,
            } => crate::lod::cut_view(nodes, camera, *pixel_error, *culling),
            Cut::Uniform { max_error, frustum } => {
                let c = Culling {
                    frustum: *frustum,
                    backface: false,
                };
                crate::lod::cut_uniform(nodes, *max_error)
                    .into_iter()
                    .filter(|&i| cut::visible(camera, &nodes[i as usize], c))
                    .collect()
            }
            Cut::Nodes(list) => {
                if let Some(&bad) = list.iter().find(|&&i| i as usize >= nodes.len()) {
                    return Err(RenderError::BadNode(bad));
                }
                list.clone()
            }
        };
        let f = camera.forward();
        let key = |i: u32| {
            let b = nodes[i as usize].bounds;
            (Vec3::new(b[0], b[1], b[2]) - camera.eye).dot(f) - b[3]
        };
        list.sort_by(|&a, &b| key(a).total_cmp(&key(b)));
        Ok(list)
    }

    /// Renders `model` from `camera`: the cut of `options.cut`, parts shown as `highlights`,
    /// reading back `options.outputs`.
    pub fn render(
        &self,
        model: &RenderModel,
        camera: &Camera,
        options: &RenderOptions,
        highlights: &[Highlight<'_>],
    ) -> Result<Frame, RenderError> {
        let t0 = Instant::now();
        self.validate(camera, options)?;
        let prepared = Prepared::new(highlights).ok_or(RenderError::TooManyTints {
            count: highlights.iter().filter(|h| h.tint.is_some()).count(),
            max: highlight::MAX_TINTS,
        })?;
        let nodes = self.cut_nodes(model, camera, &options.cut)?;
        let cut_ms = t0.elapsed().as_secs_f64() * 1e3;
        let records = model.lod.nodes();
        let f = camera.forward();
        let closest = nodes
            .first()
            .map(|&i| {
                let b = records[i as usize].bounds;
                (Vec3::new(b[0], b[1], b[2]) - camera.eye).dot(f) - b[3]
            })
            .unwrap_or(model.radius);
        let near = (closest * 0.5)
            .max(model.radius * 1e-5)
            .max(f32::MIN_POSITIVE * 1e6);

        let device = &self.gpu.device;
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let result = self.draw(model, camera, options, &prepared, &nodes, near);
        let oom_err = pollster::block_on(oom.pop());
        let val_err = pollster::block_on(validation.pop());
        if let Some(e) = oom_err.or(val_err) {
            tracing::error!(error = %e, "render failed on the GPU");
            return Err(gpu_err(e));
        }
        let mut frame = result?;
        frame.stats.cut_ms = cut_ms;
        frame.stats.near = near;
        frame.stats.total_ms = t0.elapsed().as_secs_f64() * 1e3;
        frame.stats.cache = self.cache.stats();
        tracing::debug!(
            nodes = frame.stats.nodes,
            triangles = frame.stats.triangles,
            loaded = frame.stats.loaded,
            ms = frame.stats.total_ms,
            "rendered"
        );
        Ok(frame)
    }

    /// Loads (decoding in parallel) and pins the patches of one batch.
    fn acquire(
        &self,
        model: &RenderModel,
        batch: &[u32],
        stats: &mut RenderStats,
    ) -> Result<Vec<Arc<GpuPatch>>, RenderError> {
        let keys: Vec<Key> = batch.iter().map(|&n| (model.id, n)).collect();
        let mut found = self.cache.lookup(&keys);
        let misses: Vec<usize> = (0..found.len()).filter(|&i| found[i].is_none()).collect();
        stats.hits += found.len() - misses.len();
        // Decode (in parallel) and upload a chunk at a time, so decoded copies stay few.
        for chunk in misses.chunks(UPLOAD_CHUNK) {
            let decoded: Vec<_> = chunk
                .par_iter()
                .map(|&i| {
                    let node = batch[i];
                    model
                        .lod
                        .patch(node)
                        .map_err(|source| RenderError::Patch { node, source })
                })
                .collect::<Result<_, _>>()?;
            let scope = self
                .gpu
                .device
                .push_error_scope(wgpu::ErrorFilter::OutOfMemory);
            let uploaded: Vec<(Key, GpuPatch)> = chunk
                .iter()
                .zip(decoded)
                .map(|(&i, p)| {
                    let patch = self.cache.upload(
                        &self.gpu.device,
                        &self.gpu.queue,
                        &self.pipelines,
                        batch[i],
                        &p,
                        model.lod.has_colors(),
                        self.gpu.shared_memory,
                    );
                    (keys[i], patch)
                })
                .collect();
            if let Some(e) = pollster::block_on(scope.pop()) {
                tracing::error!(error = %e, "patch upload failed");
                return Err(gpu_err(e));
            }
            stats.loaded += uploaded.len();
            for (&i, p) in chunk.iter().zip(self.cache.insert(uploaded)) {
                found[i] = Some(p);
            }
        }
        Ok(found.into_iter().flatten().collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renderer_is_send_sync() {
        fn check<T: Send + Sync>() {}
        check::<Renderer>();
        check::<RenderModel>();
    }
}
