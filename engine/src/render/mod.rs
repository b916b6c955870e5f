//! Headless rendering of hierarchy cuts with wgpu (system paper §3.3, §4.1.1, §4.1.2, §2.2).
//!
//! A [`Renderer`] draws the view-dependent cut of a [`Model`] for a [`Camera`]: frustum and
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
pub mod highlight;
mod pipeline;

pub use cache::CacheStats;
pub use device::{AdapterChoice, DeviceError, GpuDevice};
pub use highlight::Highlight;

use crate::camera::{Camera, CameraError};
use crate::lod::{Culling, FormatError, LodFile, cut};
use cache::{GpuPatch, Key, PatchCache, node_bytes};
use glam::{Mat4, Vec3, Vec4};
use highlight::Prepared;
use pipeline::Pipelines;
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use wgpu::util::DeviceExt;

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

/// A model the renderer can draw: an open LOD file and a process-unique id (its cache key).
#[derive(Clone)]
pub struct Model {
    id: u64,
    lod: Arc<LodFile>,
    radius: f32,
}

static NEXT_MODEL: AtomicU64 = AtomicU64::new(1);

impl Model {
    /// Wraps an open LOD file.
    pub fn new(lod: Arc<LodFile>) -> Model {
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
        Model {
            id: NEXT_MODEL.fetch_add(1, Ordering::Relaxed),
            lod,
            radius,
        }
    }

    /// Opens (maps and validates) a `.mwlod` file.
    pub fn open(path: &Path) -> Result<Model, FormatError> {
        Ok(Model::new(Arc::new(LodFile::open(path)?)))
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
        }
    }
}

/// Largest outline width accepted, in pixels.
pub const MAX_OUTLINE_WIDTH: u32 = 16;

/// The id buffer: per pixel, the node drawn there, the original id of the triangle corner
/// nearest to the pixel centre (always a vertex of that triangle), the triangle's index within
/// the node's patch ([`Model::triangle_ids`] gives its three original ids) and the highlight
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
}

/// A rendered frame; buffers not asked for are `None`. Row-major, top row first.
#[derive(Debug, Clone, Default)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    /// Shaded colour (RGBA8, alpha 255 on the surface, the background colour elsewhere).
    pub color: Option<Vec<[u8; 4]>>,
    /// World-space unit normal facing the viewer; zero on the background.
    pub normal: Option<Vec<[f32; 3]>>,
    /// Linear view depth (distance along the view direction); `f32::INFINITY` on the background.
    pub depth: Option<Vec<f32>>,
    pub ids: Option<IdBuffer>,
    pub stats: RenderStats,
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

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameUniform {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    light: [f32; 4],
    base_color: [f32; 4],
    forward: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    center: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct DrawRecord {
    node: u32,
    positions: u32,
    normals: u32,
    colors: u32,
    ids: u32,
    indices: u32,
    masks: u32,
    _pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct OutlineUniform {
    color: [f32; 4],
    args: [u32; 4],
}

/// Headless renderer: device, pipelines and patch cache.
pub struct Renderer {
    gpu: Arc<GpuDevice>,
    pipelines: Pipelines,
    cache: PatchCache,
    options: RendererOptions,
}

/// Render targets of one frame.
struct Targets {
    color: wgpu::Texture,
    /// Mask (image mode) or packed normal (buffers mode).
    second: wgpu::Texture,
    /// Ids (buffers mode only).
    ids: Option<wgpu::Texture>,
    depth: wgpu::Texture,
}

fn texture(
    device: &wgpu::Device,
    label: &str,
    w: u32,
    h: u32,
    format: wgpu::TextureFormat,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    })
}

fn gpu_err(e: wgpu::Error) -> RenderError {
    match e {
        wgpu::Error::OutOfMemory { .. } => RenderError::OutOfMemory,
        other => RenderError::Gpu(other.to_string()),
    }
}

/// Reversed-Z perspective with an infinite far plane: clip depth = `near / view depth`.
fn projection(camera: &Camera, near: f32) -> Mat4 {
    let f = 1.0 / (camera.fovy_deg.to_radians() * 0.5).tan();
    Mat4::from_cols(
        Vec4::new(f / camera.aspect(), 0.0, 0.0, 0.0),
        Vec4::new(0.0, f, 0.0, 0.0),
        Vec4::new(0.0, 0.0, 0.0, -1.0),
        Vec4::new(0.0, 0.0, near, 0.0),
    )
}

fn rgba(c: [u8; 4]) -> [f32; 4] {
    c.map(|v| v as f32 / 255.0)
}

/// Decodes the octahedral normal written by `render.wgsl`.
fn oct_decode(v: u32) -> [f32; 3] {
    let x = ((v & 0xFFFF) as u16 as i16 as f32 / 32767.0).max(-1.0);
    let y = ((v >> 16) as u16 as i16 as f32 / 32767.0).max(-1.0);
    let mut n = Vec3::new(x, y, 1.0 - x.abs() - y.abs());
    if n.z < 0.0 {
        let sx = if n.x >= 0.0 { 1.0 } else { -1.0 };
        let sy = if n.y >= 0.0 { 1.0 } else { -1.0 };
        let (ox, oy) = (n.x, n.y);
        n.x = (1.0 - oy.abs()) * sx;
        n.y = (1.0 - ox.abs()) * sy;
    }
    n.normalize_or_zero().into()
}

impl Renderer {
    /// A renderer on an open device.
    pub fn new(gpu: Arc<GpuDevice>, options: RendererOptions) -> Renderer {
        let pipelines = Pipelines::new(&gpu.device);
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
    pub fn forget(&self, model: &Model) {
        self.cache.forget_model(model.id);
    }

    /// Drops every cached patch.
    pub fn clear_cache(&self) {
        self.cache.clear();
    }

    /// Colour image (RGBA8, row-major) of the default 1-pixel cut.
    pub fn render_image(
        &self,
        model: &Model,
        camera: &Camera,
        highlights: &[Highlight<'_>],
    ) -> Result<Frame, RenderError> {
        self.render(model, camera, &RenderOptions::default(), highlights)
    }

    /// Every buffer (colour, normal, depth, ids) of the default 1-pixel cut, for selection.
    pub fn render_buffers(
        &self,
        model: &Model,
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
        model: &Model,
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
        model: &Model,
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
        model: &Model,
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
                        &self.pipelines.patch_layout,
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

    fn draw(
        &self,
        model: &Model,
        camera: &Camera,
        options: &RenderOptions,
        prepared: &Prepared<'_>,
        nodes: &[u32],
        near: f32,
    ) -> Result<Frame, RenderError> {
        let draw_start = Instant::now();
        let device = &self.gpu.device;
        let queue = &self.gpu.queue;
        let (w, h) = (camera.width, camera.height);
        let outputs = options.outputs;
        let buffers_mode = outputs.normal || outputs.ids;
        let targets = Targets {
            color: texture(device, "color", w, h, pipeline::COLOR_FORMAT),
            second: texture(
                device,
                if buffers_mode { "normal" } else { "mask" },
                w,
                h,
                if buffers_mode {
                    pipeline::NORMAL_FORMAT
                } else {
                    pipeline::MASK_FORMAT
                },
            ),
            ids: buffers_mode.then(|| texture(device, "ids", w, h, pipeline::IDS_FORMAT)),
            depth: texture(device, "depth", w, h, pipeline::DEPTH_FORMAT),
        };
        let views = (
            targets.color.create_view(&Default::default()),
            targets.second.create_view(&Default::default()),
            targets
                .ids
                .as_ref()
                .map(|t| t.create_view(&Default::default())),
            targets.depth.create_view(&Default::default()),
        );
        let colors = model.lod.has_colors();
        let light = [
            options.ambient,
            1.0 - options.ambient,
            if colors { 1.0 } else { 0.0 },
            0.0,
        ];
        let basis = camera.basis();
        let scale = camera.pixel_scale();
        let frame_uniform = FrameUniform {
            view_proj: (projection(camera, near) * camera.view()).to_cols_array_2d(),
            eye: camera.eye.extend(1.0).into(),
            light,
            base_color: rgba(options.base_color),
            forward: basis.0.extend(0.0).into(),
            right: (basis.1 / scale).extend(0.0).into(),
            up: (basis.2 / scale).extend(0.0).into(),
            center: [w as f32 * 0.5, h as f32 * 0.5, 0.0, 0.0],
        };
        let frame_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("frame"),
            contents: bytemuck::bytes_of(&frame_uniform),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let palette_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("palette"),
            contents: bytemuck::cast_slice(&prepared.palette),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let bg = rgba(options.background);
        let clear_color = wgpu::Color {
            r: bg[0] as f64,
            g: bg[1] as f64,
            b: bg[2] as f64,
            a: bg[3] as f64,
        };
        let no_id = NO_ID as f64;
        let records = model.lod.nodes();
        let max_binding = self.gpu.limits.max_storage_buffer_binding_size;
        let batch_limit = self
            .options
            .batch_bytes
            .min(self.options.cache_bytes)
            .min(max_binding)
            .max(1);

        let mut stats = RenderStats::default();
        let mut start = 0usize;
        let mut first = true;
        let mut load_time = Duration::ZERO;
        while first || start < nodes.len() {
            let mut end = start;
            let mut bytes = 0u64;
            while end < nodes.len() {
                let b = node_bytes(&records[nodes[end] as usize], colors);
                if end > start && bytes + b > batch_limit {
                    break;
                }
                bytes += b;
                end += 1;
            }
            let batch = &nodes[start..end];
            let t_load = Instant::now();
            let patches = self.acquire(model, batch, &mut stats)?;
            load_time += t_load.elapsed();
            let mut masks: Vec<u32> = Vec::new();
            let mut highlighted = 0u64;
            let draws: Vec<DrawRecord> = patches
                .iter()
                .map(|p| {
                    let offset = if prepared.is_empty() {
                        None
                    } else {
                        prepared.masks(&p.original_ids, p.id_range)
                    }
                    .map_or(u32::MAX, |m| {
                        highlighted += m.iter().filter(|&&v| v != 0).count() as u64;
                        let o = masks.len() as u32;
                        masks.extend_from_slice(&m);
                        o
                    });
                    DrawRecord {
                        node: p.node,
                        positions: p.layout.positions,
                        normals: p.layout.normals,
                        colors: p.layout.colors,
                        ids: p.layout.ids,
                        indices: p.layout.indices,
                        masks: offset,
                        _pad: 0,
                    }
                })
                .collect();
            stats.nodes += patches.len();
            stats.triangles += patches.iter().map(|p| p.triangles as u64).sum::<u64>();
            stats.batches += 1;
            stats.highlighted_vertices += highlighted;
            if masks.is_empty() {
                masks.push(0);
            }
            let draws_bytes: &[u8] = if draws.is_empty() {
                &[0u8; std::mem::size_of::<DrawRecord>()]
            } else {
                bytemuck::cast_slice(&draws)
            };
            let draw_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("draws"),
                contents: draws_bytes,
                usage: wgpu::BufferUsages::STORAGE,
            });
            let mask_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("masks"),
                contents: bytemuck::cast_slice(&masks),
                usage: wgpu::BufferUsages::STORAGE,
            });
            let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("frame"),
                layout: &self.pipelines.frame_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: frame_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: draw_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: mask_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: palette_buffer.as_entire_binding(),
                    },
                ],
            });
            let mut encoder = device.create_command_encoder(&Default::default());
            {
                let ops = |clear: wgpu::Color| wgpu::Operations {
                    load: if first {
                        wgpu::LoadOp::Clear(clear)
                    } else {
                        wgpu::LoadOp::Load
                    },
                    store: wgpu::StoreOp::Store,
                };
                let zero = wgpu::Color::TRANSPARENT;
                let mut attachments = vec![
                    Some(wgpu::RenderPassColorAttachment {
                        view: &views.0,
                        depth_slice: None,
                        resolve_target: None,
                        ops: ops(clear_color),
                    }),
                    Some(wgpu::RenderPassColorAttachment {
                        view: &views.1,
                        depth_slice: None,
                        resolve_target: None,
                        ops: ops(zero),
                    }),
                ];
                if let Some(ids) = &views.2 {
                    attachments.push(Some(wgpu::RenderPassColorAttachment {
                        view: ids,
                        depth_slice: None,
                        resolve_target: None,
                        ops: ops(wgpu::Color {
                            r: no_id,
                            g: no_id,
                            b: no_id,
                            a: 0.0,
                        }),
                    }));
                }
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("main"),
                    color_attachments: &attachments,
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view: &views.3,
                        depth_ops: Some(wgpu::Operations {
                            load: if first {
                                wgpu::LoadOp::Clear(0.0)
                            } else {
                                wgpu::LoadOp::Load
                            },
                            store: wgpu::StoreOp::Store,
                        }),
                        stencil_ops: None,
                    }),
                    ..Default::default()
                });
                pass.set_pipeline(if buffers_mode {
                    &self.pipelines.buffers
                } else {
                    &self.pipelines.image
                });
                pass.set_bind_group(0, &bind, &[]);
                for (i, p) in patches.iter().enumerate() {
                    if p.triangles == 0 {
                        continue;
                    }
                    pass.set_bind_group(1, &p.bind_group, &[]);
                    pass.draw(0..p.triangles * 3, i as u32..i as u32 + 1);
                }
            }
            let index = queue.submit([encoder.finish()]);
            start = end;
            first = false;
            if start < nodes.len() {
                // Bound memory: let this batch finish before pinning the next one.
                device
                    .poll(wgpu::PollType::Wait {
                        submission_index: Some(index),
                        timeout: Some(GPU_TIMEOUT),
                    })
                    .map_err(|e| RenderError::Gpu(e.to_string()))?;
            }
            drop(patches);
        }
        stats.load_ms = load_time.as_secs_f64() * 1e3;

        // Outline of hovered parts (post pass into a second colour texture).
        let outline = outputs.color && prepared.any_outline && options.outline_width > 0;
        let mut encoder = device.create_command_encoder(&Default::default());
        let final_color = if outline {
            let out = texture(device, "outlined", w, h, pipeline::COLOR_FORMAT);
            let out_view = out.create_view(&Default::default());
            let (mask_view, channel) = match &views.2 {
                Some(ids) => (ids, 3u32),
                None => (&views.1, 0u32),
            };
            let uniform = OutlineUniform {
                color: rgba(options.outline_color),
                args: [options.outline_width, channel, highlight::OUTLINE_BIT, 0],
            };
            let ubuf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("outline"),
                contents: bytemuck::bytes_of(&uniform),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("outline"),
                layout: &self.pipelines.outline_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(&views.0),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(mask_view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: ubuf.as_entire_binding(),
                    },
                ],
            });
            {
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("outline"),
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &out_view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    ..Default::default()
                });
                pass.set_pipeline(&self.pipelines.outline);
                pass.set_bind_group(0, &bind, &[]);
                pass.draw(0..3, 0..1);
            }
            out
        } else {
            targets.color.clone()
        };

        // Read-back.
        let mut reads: Vec<Readback> = Vec::new();
        let mut add = |tex: &wgpu::Texture, bpp: u32, aspect: wgpu::TextureAspect| {
            let row = (w * bpp).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
                * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
            let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: row as u64 * h as u64,
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: tex,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row),
                        rows_per_image: Some(h),
                    },
                },
                wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: 1,
                },
            );
            reads.push(Readback { buffer, row, bpp });
            reads.len() - 1
        };
        let all = wgpu::TextureAspect::All;
        let color_read = outputs.color.then(|| add(&final_color, 4, all));
        let normal_read = outputs.normal.then(|| add(&targets.second, 4, all));
        let ids_read = match &targets.ids {
            Some(t) if outputs.ids || outputs.normal => Some(add(t, 16, all)),
            _ => None,
        };
        let depth_read = outputs
            .depth
            .then(|| add(&targets.depth, 4, wgpu::TextureAspect::DepthOnly));
        let index = queue.submit([encoder.finish()]);
        let data = read_all(device, &reads, index, w, h)?;
        stats.draw_ms = draw_start.elapsed().saturating_sub(load_time).as_secs_f64() * 1e3;

        let n = (w as usize) * (h as usize);
        let ids_words: Option<&Vec<u32>> = ids_read.map(|i| &data[i]);
        let covered = |i: usize| ids_words.is_none_or(|d| d[i * 4] != NO_NODE);
        let color = color_read.map(|i| data[i].iter().map(|v| v.to_le_bytes()).collect());
        let normal = normal_read.map(|i| {
            (0..n)
                .map(|p| {
                    if covered(p) {
                        oct_decode(data[i][p])
                    } else {
                        [0.0; 3]
                    }
                })
                .collect()
        });
        let depth = depth_read.map(|i| {
            data[i]
                .iter()
                .map(|&bits| {
                    let z = f32::from_bits(bits);
                    if z > 0.0 { near / z } else { f32::INFINITY }
                })
                .collect()
        });
        let ids = match ids_words {
            Some(d) if outputs.ids => {
                let mut b = IdBuffer {
                    node: Vec::with_capacity(n),
                    vertex: Vec::with_capacity(n),
                    triangle: Vec::with_capacity(n),
                    highlight: Vec::with_capacity(n),
                };
                for px in d.chunks_exact(4) {
                    b.node.push(px[0]);
                    b.vertex.push(px[1]);
                    b.triangle.push(px[2]);
                    b.highlight.push(if px[0] == NO_NODE {
                        0
                    } else {
                        px[3] | COVERED_BIT
                    });
                }
                Some(b)
            }
            _ => None,
        };
        Ok(Frame {
            width: w,
            height: h,
            color,
            normal,
            depth,
            ids,
            stats,
        })
    }
}

struct Readback {
    buffer: wgpu::Buffer,
    row: u32,
    bpp: u32,
}

/// Maps the read-back buffers and returns each as tightly packed u32 words.
fn read_all(
    device: &wgpu::Device,
    reads: &[Readback],
    index: wgpu::SubmissionIndex,
    w: u32,
    h: u32,
) -> Result<Vec<Vec<u32>>, RenderError> {
    let (tx, rx) = std::sync::mpsc::channel();
    for (i, r) in reads.iter().enumerate() {
        let tx = tx.clone();
        r.buffer
            .slice(..)
            .map_async(wgpu::MapMode::Read, move |res| {
                let _ = tx.send((i, res));
            });
    }
    device
        .poll(wgpu::PollType::Wait {
            submission_index: Some(index),
            timeout: Some(GPU_TIMEOUT),
        })
        .map_err(|e| RenderError::Gpu(e.to_string()))?;
    let deadline = Instant::now() + GPU_TIMEOUT;
    for _ in 0..reads.len() {
        loop {
            match rx.recv_timeout(Duration::from_millis(50)) {
                Ok((_, Ok(()))) => break,
                Ok((i, Err(e))) => {
                    return Err(RenderError::Gpu(format!("read-back {i} failed: {e}")));
                }
                Err(_) if Instant::now() < deadline => {
                    let _ = device.poll(wgpu::PollType::Poll);
                }
                Err(_) => return Err(RenderError::Gpu("read-back timed out".into())),
            }
        }
    }
    let mut out = Vec::with_capacity(reads.len());
    for r in reads {
        let view = r
            .buffer
            .get_mapped_range(..)
            .map_err(|e| RenderError::Gpu(format!("read-back mapping: {e}")))?;
        let row_bytes = (w * r.bpp) as usize;
        let mut words = Vec::with_capacity(row_bytes / 4 * h as usize);
        for y in 0..h as usize {
            let start = y * r.row as usize;
            words.extend(
                view[start..start + row_bytes]
                    .chunks_exact(4)
                    .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            );
        }
        drop(view);
        r.buffer.unmap();
        out.push(words);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renderer_is_send_sync() {
        fn check<T: Send + Sync>() {}
        check::<Renderer>();
        check::<Model>();
    }

    #[test]
    fn octahedral_round_trip() {
        for n in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.6, -0.8, 0.0],
            [0.3, 0.4, -0.866],
        ] {
            let v = Vec3::from(n).normalize();
            // Encode as the shader does.
            let l1 = v.x.abs() + v.y.abs() + v.z.abs();
            let (mut x, mut y) = (v.x / l1, v.y / l1);
            if v.z < 0.0 {
                let (ox, oy) = (x, y);
                x = (1.0 - oy.abs()) * if ox >= 0.0 { 1.0 } else { -1.0 };
                y = (1.0 - ox.abs()) * if oy >= 0.0 { 1.0 } else { -1.0 };
            }
            let q = |f: f32| ((f.clamp(-1.0, 1.0) * 32767.0).round() as i16) as u16 as u32;
            let d = Vec3::from(oct_decode(q(x) | (q(y) << 16)));
            assert!(d.distance(v) < 1e-3, "{v} -> {d}");
        }
    }

    #[test]
    fn reversed_depth_is_near_over_distance() {
        let c = Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fovy_deg: 50.0,
            width: 64,
            height: 48,
        };
        let near = 0.1;
        let m = projection(&c, near) * c.view();
        let clip = m * Vec3::new(0.3, 0.2, 1.0).extend(1.0);
        let depth = clip.z / clip.w;
        assert!((near / depth - 4.0).abs() < 1e-4);
        let (x, y, _) = c.project(Vec3::new(0.3, 0.2, 1.0)).expect("visible");
        let px = (clip.x / clip.w * 0.5 + 0.5) * 64.0;
        let py = (0.5 - clip.y / clip.w * 0.5) * 48.0;
        assert!((px - x).abs() < 1e-3 && (py - y).abs() < 1e-3);
    }
}
