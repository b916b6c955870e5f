//! One frame of the renderer, pass by pass: the render targets, the frame's uniforms, the main
//! pass over the cut in memory-bounded batches (patches decoded and uploaded on demand, pinned
//! while their batch draws), the outline post pass of hovered parts, and the read-back of the
//! requested buffers (colour, normals, linear depth, ids).

use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{Mat4, Vec3, Vec4};
use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::cache::{GpuPatch, node_bytes};
use super::highlight::{self, Prepared};
use super::pipeline::{Albedo, MainKey, Variant};
use super::{
    COVERED_BIT, Frame, GPU_TIMEOUT, IdBuffer, NO_ID, NO_NODE, Outputs, RenderError, RenderModel,
    RenderOptions, RenderStats, Renderer, pipeline,
};
use crate::camera::Camera;

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

/// A patch's draw record (`Draw` in `render.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct DrawRecord {
    node: u32,
    positions: u32,
    ids: u32,
    indices: u32,
    masks: u32,
    pad: [u32; 3],
}

/// What the main pass draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Colour alone.
    Plain,
    /// Colour and the highlight mask (parts tinted or outlined).
    Marked,
    /// Colour, normal and ids (selection).
    Buffers,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct OutlineUniform {
    color: [f32; 4],
    args: [u32; 4],
}

/// Render targets of one frame.
struct Targets {
    color: wgpu::Texture,
    /// Mask (marked images) or packed normal (buffers); none for plain images.
    second: Option<wgpu::Texture>,
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

/// The clip-space transform that makes the window `[x, y, width, height]` (pixels, y down) of
/// `camera`'s view fill the targets: an off-centre crop of the same projection, so every pixel
/// of the window samples where the whole view's pixel does.
fn crop(camera: &Camera, [x, y, ww, wh]: [u32; 4]) -> Mat4 {
    let (vw, vh) = (camera.width as f32, camera.height as f32);
    let (x, y, ww, wh) = (x as f32, y as f32, ww as f32, wh as f32);
    let (sx, sy) = (vw / ww, vh / wh);
    let tx = (vw - 2.0 * x - ww) / ww;
    let ty = (2.0 * y + wh - vh) / wh;
    Mat4::from_cols(
        Vec4::new(sx, 0.0, 0.0, 0.0),
        Vec4::new(0.0, sy, 0.0, 0.0),
        Vec4::new(0.0, 0.0, 1.0, 0.0),
        Vec4::new(tx, ty, 0.0, 1.0),
    )
}

/// The four side planes (left, right, bottom, top) of a view-projection's frustum, `(n, d)`
/// with `n·p + d >= 0` inside, `n` of unit length (Gribb and Hartmann's row sums).
fn side_planes(m: &Mat4) -> [Vec4; 4] {
    let (r0, r1, r3) = (m.row(0), m.row(1), m.row(3));
    [r3 + r0, r3 - r0, r3 + r1, r3 - r1].map(|p| p / p.truncate().length().max(f32::MIN_POSITIVE))
}

/// Waits (at most [`GPU_TIMEOUT`]) until the GPU has finished submission `index`.
fn wait(device: &wgpu::Device, index: wgpu::SubmissionIndex) -> Result<(), RenderError> {
    device
        .poll(wgpu::PollType::Wait {
            submission_index: Some(index),
            timeout: Some(GPU_TIMEOUT),
        })
        .map(|_| ())
        .map_err(|e| RenderError::Gpu(e.to_string()))
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

/// The frame's uniforms on the GPU: camera and lighting, and the highlight palette.
struct Globals {
    frame: wgpu::Buffer,
    palette: wgpu::Buffer,
}

impl Targets {
    /// The targets of a `w`×`h` frame of `mode`.
    fn new(device: &wgpu::Device, w: u32, h: u32, mode: Mode) -> Targets {
        let second = match mode {
            Mode::Plain => None,
            Mode::Marked => Some(texture(device, "mask", w, h, pipeline::MASK_FORMAT)),
            Mode::Buffers => Some(texture(device, "normal", w, h, pipeline::NORMAL_FORMAT)),
        };
        Targets {
            color: texture(device, "color", w, h, pipeline::COLOR_FORMAT),
            second,
            ids: (mode == Mode::Buffers)
                .then(|| texture(device, "ids", w, h, pipeline::IDS_FORMAT)),
            depth: texture(device, "depth", w, h, pipeline::DEPTH_FORMAT),
        }
    }

    fn views(&self) -> TargetViews {
        TargetViews {
            color: self.color.create_view(&Default::default()),
            second: self
                .second
                .as_ref()
                .map(|t| t.create_view(&Default::default())),
            ids: self
                .ids
                .as_ref()
                .map(|t| t.create_view(&Default::default())),
            depth: self.depth.create_view(&Default::default()),
        }
    }
}

/// Views of the [`Targets`].
struct TargetViews {
    color: wgpu::TextureView,
    second: Option<wgpu::TextureView>,
    ids: Option<wgpu::TextureView>,
    depth: wgpu::TextureView,
}

/// Which read-back buffer holds which output.
#[derive(Default)]
struct Reads {
    buffers: Vec<Readback>,
    color: Option<usize>,
    normal: Option<usize>,
    ids: Option<usize>,
    depth: Option<usize>,
}

impl Renderer {
    /// Draws `nodes` of `model` seen by `camera` and reads back `options.outputs`.
    pub(super) fn draw(
        &self,
        model: &RenderModel,
        camera: &Camera,
        options: &RenderOptions,
        prepared: &Prepared<'_>,
        nodes: &[u32],
        near: f32,
    ) -> Result<Frame, RenderError> {
        let draw_start = Instant::now();
        let device = &self.gpu.device;
        let window = options
            .window
            .unwrap_or([0, 0, camera.width, camera.height]);
        let (w, h) = (window[2], window[3]);
        let view_proj = crop(camera, window) * projection(camera, near) * camera.view();
        // Patches wholly outside the window draw nothing in it.
        let inside: Vec<u32>;
        let nodes = if options.window.is_some() {
            let planes = side_planes(&view_proj);
            let records = model.lod.nodes();
            inside = nodes
                .iter()
                .copied()
                .filter(|&n| {
                    let b = records[n as usize].bounds;
                    let c = Vec3::new(b[0], b[1], b[2]);
                    planes.iter().all(|p| p.truncate().dot(c) + p.w >= -b[3])
                })
                .collect();
            &inside[..]
        } else {
            nodes
        };
        let outputs = options.outputs;
        let mode = if outputs.normal || outputs.ids {
            Mode::Buffers
        } else if !prepared.is_empty() {
            Mode::Marked
        } else {
            Mode::Plain
        };
        let mut stats = RenderStats::default();
        let t = Instant::now();
        let targets = Targets::new(device, w, h, mode);
        let views = targets.views();
        let globals = self.globals(camera, options, prepared, view_proj, [w, h]);
        stats.profile.targets_ms = ms(t);
        let (load_time, mut encoder, pinned) = self.main_pass(
            model, options, prepared, nodes, &views, &globals, mode, &mut stats,
        )?;
        stats.load_ms = load_time.as_secs_f64() * 1e3;

        // The last batch, the outline and the copies out go in one submission.
        let t = Instant::now();
        let outlined = (outputs.color && prepared.any_outline && options.outline_width > 0)
            .then(|| self.outline_pass(&mut encoder, &views, options, w, h));
        let color = outlined.as_ref().unwrap_or(&targets.color);
        let reads = record_reads(device, &mut encoder, &targets, color, outputs, w, h);
        let commands = encoder.finish();
        stats.profile.encode_ms += ms(t);
        let t = Instant::now();
        let index = self.gpu.queue.submit([commands]);
        stats.profile.submit_ms += ms(t);
        let mut frame = read_frame(device, &reads, index, outputs, near, w, h, stats)?;
        frame.origin = [window[0], window[1]];
        drop(pinned);
        frame.stats.draw_ms = draw_start.elapsed().saturating_sub(load_time).as_secs_f64() * 1e3;
        Ok(frame)
    }

    /// The frame's uniforms: view-projection (reversed Z, `near`), eye, lighting, the pixel
    /// basis of point sprites, and the highlight palette.
    fn globals(
        &self,
        camera: &Camera,
        options: &RenderOptions,
        prepared: &Prepared<'_>,
        view_proj: Mat4,
        [w, h]: [u32; 2],
    ) -> Globals {
        let device = &self.gpu.device;
        let light = [options.ambient, 1.0 - options.ambient, 0.0, 0.0];
        let basis = camera.basis();
        let scale = camera.pixel_scale();
        let frame_uniform = FrameUniform {
            view_proj: view_proj.to_cols_array_2d(),
            eye: camera.eye.extend(1.0).into(),
            light,
            base_color: rgba(options.base_color),
            forward: basis.0.extend(0.0).into(),
            right: (basis.1 / scale).extend(0.0).into(),
            up: (basis.2 / scale).extend(0.0).into(),
            center: [w as f32 * 0.5, h as f32 * 0.5, 0.0, 0.0],
        };
        Globals {
            frame: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("frame"),
                contents: bytemuck::bytes_of(&frame_uniform),
                usage: wgpu::BufferUsages::UNIFORM,
            }),
            palette: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("palette"),
                contents: bytemuck::cast_slice(&prepared.palette),
                usage: wgpu::BufferUsages::UNIFORM,
            }),
        }
    }

    /// The main pass: the cut in batches of at most `batch_bytes` of patches (and of the cache
    /// and the device's largest storage binding), each loaded, drawn and finished before the
    /// next is pinned. The first batch clears the targets. Returns the time spent loading, and
    /// the last batch recorded but not submitted (the frame's last commands join it: a second
    /// submission would wait for the first on some adapters) with its patches, still pinned.
    #[allow(clippy::too_many_arguments)]
    fn main_pass(
        &self,
        model: &RenderModel,
        options: &RenderOptions,
        prepared: &Prepared<'_>,
        nodes: &[u32],
        views: &TargetViews,
        globals: &Globals,
        mode: Mode,
        stats: &mut RenderStats,
    ) -> Result<(Duration, wgpu::CommandEncoder, Vec<Arc<GpuPatch>>), RenderError> {
        let device = &self.gpu.device;
        let colors = model.lod.has_colors();
        let records = model.lod.nodes();
        let max_binding = self.gpu.limits.max_storage_buffer_binding_size;
        let batch_limit = self
            .options
            .batch_bytes
            .min(self.options.cache_bytes)
            .min(max_binding)
            .max(1);
        let mut start = 0usize;
        let mut first = true;
        let mut load_time = Duration::ZERO;
        loop {
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
            let t_load = Instant::now();
            let patches = self.acquire(model, &nodes[start..end], stats)?;
            load_time += t_load.elapsed();
            let t = Instant::now();
            let (bind, marked) = self.batch_bindings(&patches, prepared, globals, stats);
            let mut encoder = device.create_command_encoder(&Default::default());
            encode_batch(
                device,
                &mut encoder,
                views,
                options,
                first,
                &self.pipelines,
                mode,
                &bind,
                &patches,
                &marked,
            );
            stats.profile.encode_ms += ms(t);
            start = end;
            first = false;
            if start >= nodes.len() {
                return Ok((load_time, encoder, patches));
            }
            // Bound memory: let this batch finish before pinning the next one.
            let t = Instant::now();
            let index = self.gpu.queue.submit([encoder.finish()]);
            stats.profile.submit_ms += ms(t);
            let t = Instant::now();
            wait(device, index)?;
            stats.profile.gpu_ms += ms(t);
            drop(patches);
        }
    }

    /// The bind group of one batch: the frame's uniforms, one draw record per patch (where its
    /// streams lie, and its highlight masks) and the masks themselves; and whether each patch
    /// holds marked vertices.
    fn batch_bindings(
        &self,
        patches: &[Arc<GpuPatch>],
        prepared: &Prepared<'_>,
        globals: &Globals,
        stats: &mut RenderStats,
    ) -> (wgpu::BindGroup, Vec<bool>) {
        let device = &self.gpu.device;
        let mut masks: Vec<u32> = Vec::new();
        let mut highlighted = 0u64;
        let mut marked = Vec::with_capacity(patches.len());
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
                marked.push(offset != u32::MAX);
                DrawRecord {
                    node: p.node,
                    positions: p.layout.positions,
                    ids: p.layout.ids,
                    indices: p.layout.indices,
                    masks: offset,
                    pad: [0; 3],
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
                    resource: globals.frame.as_entire_binding(),
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
                    resource: globals.palette.as_entire_binding(),
                },
            ],
        });
        (bind, marked)
    }

    /// The outline post pass: hovered parts (the mask's outline bit) outlined into a second
    /// colour texture, which is returned.
    fn outline_pass(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        views: &TargetViews,
        options: &RenderOptions,
        w: u32,
        h: u32,
    ) -> wgpu::Texture {
        let device = &self.gpu.device;
        let out = texture(device, "outlined", w, h, pipeline::COLOR_FORMAT);
        let out_view = out.create_view(&Default::default());
        let (mask_view, channel) = match (&views.ids, &views.second) {
            (Some(ids), _) => (ids, 3u32),
            (None, Some(mask)) => (mask, 0u32),
            // No mask (a plain image): nothing is outlined, the pass only copies.
            (None, None) => (&views.color, 0u32),
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
                    resource: wgpu::BindingResource::TextureView(&views.color),
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
        drop(pass);
        out
    }
}

/// Where a patch's colour comes from.
fn albedo_of(p: &GpuPatch) -> Albedo {
    if p.color_atlas {
        Albedo::Texture
    } else if p.layout.colors != u32::MAX {
        Albedo::Vertex
    } else {
        Albedo::Base
    }
}

/// Encodes one batch of the main pass: clears the targets when `first`, else loads them. Each
/// patch is one indexed draw from its own buffer, by the pipeline of its variant (in `Marked`
/// mode, patches holding marked vertices resolve their nearest corners and the others do not)
/// and albedo; its bind group is set only where the pipeline reads it.
#[allow(clippy::too_many_arguments)]
fn encode_batch(
    device: &wgpu::Device,
    encoder: &mut wgpu::CommandEncoder,
    views: &TargetViews,
    options: &RenderOptions,
    first: bool,
    pipelines: &pipeline::Pipelines,
    mode: Mode,
    bind: &wgpu::BindGroup,
    patches: &[Arc<GpuPatch>],
    marked: &[bool],
) {
    let variant_of = |marked: bool| match mode {
        Mode::Plain => Variant::Image,
        Mode::Marked if marked => Variant::ImageMarked,
        Mode::Marked => Variant::ImageUnmarked,
        Mode::Buffers => Variant::Buffers,
    };
    // Each patch's pipeline, looked up before the pass records.
    let chosen: Vec<MainKey> = patches
        .iter()
        .enumerate()
        .map(|(i, p)| {
            (
                variant_of(marked.get(i).copied().unwrap_or(false)),
                albedo_of(p),
                p.normal_map,
            )
        })
        .collect();
    let mut used: Vec<MainKey> = chosen.clone();
    used.sort_by_key(|&(v, a, n)| (v as u8, a as u8, n));
    used.dedup();
    let made: Vec<(MainKey, Arc<wgpu::RenderPipeline>)> = used
        .into_iter()
        .map(|k| (k, pipelines.main(device, k)))
        .collect();
    let pipeline_for = |k: MainKey| {
        made.iter()
            .find(|(key, _)| *key == k)
            .map(|(_, p)| p.clone())
    };
    let ops = |clear: wgpu::Color| wgpu::Operations {
        load: if first {
            wgpu::LoadOp::Clear(clear)
        } else {
            wgpu::LoadOp::Load
        },
        store: wgpu::StoreOp::Store,
    };
    let bg = rgba(options.background);
    let clear_color = wgpu::Color {
        r: bg[0] as f64,
        g: bg[1] as f64,
        b: bg[2] as f64,
        a: bg[3] as f64,
    };
    let no_id = NO_ID as f64;
    let mut attachments = vec![Some(wgpu::RenderPassColorAttachment {
        view: &views.color,
        depth_slice: None,
        resolve_target: None,
        ops: ops(clear_color),
    })];
    if let Some(second) = &views.second {
        attachments.push(Some(wgpu::RenderPassColorAttachment {
            view: second,
            depth_slice: None,
            resolve_target: None,
            ops: ops(wgpu::Color::TRANSPARENT),
        }));
    }
    if let Some(ids) = &views.ids {
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
            view: &views.depth,
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
    let mut current: Option<MainKey> = None;
    let mut patch_bound = false;
    pass.set_bind_group(0, bind, &[]);
    for (i, p) in patches.iter().enumerate() {
        if p.triangles == 0 || p.vertices == 0 {
            continue;
        }
        let key = chosen[i];
        if current != Some(key) {
            let Some(pipeline) = pipeline_for(key) else {
                continue;
            };
            pass.set_pipeline(&pipeline);
            current = Some(key);
        }
        let l = &p.layout;
        let n = p.vertices as u64;
        let at = |words: u32| words as u64 * 4;
        let positions = p.buffer.slice(at(l.positions)..at(l.positions) + 12 * n);
        // A pipeline that reads no patch data still needs a group 1: any patch's will do, and
        // setting it once spares the rasteriser a state change per patch.
        if key.0.reads_patch() || key.1 == Albedo::Texture || key.2 || !patch_bound {
            pass.set_bind_group(1, &p.bind_group, &[]);
            patch_bound = true;
        }
        pass.set_vertex_buffer(0, positions);
        pass.set_vertex_buffer(1, p.buffer.slice(at(l.normals)..at(l.normals) + 12 * n));
        // Models without colours and patches without atlas read the positions there: the
        // shader does not use them (its frame and draw flags say so).
        pass.set_vertex_buffer(
            2,
            if l.colors != u32::MAX {
                p.buffer.slice(at(l.colors)..at(l.colors) + 4 * n)
            } else {
                positions
            },
        );
        pass.set_vertex_buffer(
            3,
            if l.uvs != u32::MAX {
                p.buffer.slice(at(l.uvs)..at(l.uvs) + 4 * n)
            } else {
                positions
            },
        );
        pass.set_index_buffer(
            p.buffer
                .slice(at(l.indices)..at(l.indices) + 12 * p.triangles as u64),
            wgpu::IndexFormat::Uint32,
        );
        pass.draw_indexed(0..p.triangles * 3, 0, i as u32..i as u32 + 1);
    }
}

/// Copies the requested outputs (`color`: the final colour texture) into read-back buffers.
fn record_reads(
    device: &wgpu::Device,
    encoder: &mut wgpu::CommandEncoder,
    targets: &Targets,
    color: &wgpu::Texture,
    outputs: Outputs,
    w: u32,
    h: u32,
) -> Reads {
    let mut reads = Reads::default();
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
        reads.buffers.push(Readback { buffer, row, bpp });
        reads.buffers.len() - 1
    };
    let all = wgpu::TextureAspect::All;
    let color = outputs.color.then(|| add(color, 4, all));
    let normal = match (&targets.second, outputs.normal) {
        (Some(t), true) => Some(add(t, 4, all)),
        _ => None,
    };
    let ids = match &targets.ids {
        Some(t) if outputs.ids || outputs.normal => Some(add(t, 16, all)),
        _ => None,
    };
    let depth = outputs
        .depth
        .then(|| add(&targets.depth, 4, wgpu::TextureAspect::DepthOnly));
    Reads {
        color,
        normal,
        ids,
        depth,
        ..reads
    }
}

struct Readback {
    buffer: wgpu::Buffer,
    row: u32,
    bpp: u32,
}

/// The rows of a mapped read-back buffer.
struct Rows<'a> {
    bytes: &'a [u8],
    pitch: usize,
    width: usize,
}

impl Rows<'_> {
    /// Row `y`'s bytes (`width` bytes, the padding to the copy alignment left out).
    fn row(&self, y: usize) -> &[u8] {
        &self.bytes[y * self.pitch..y * self.pitch + self.width]
    }
}

fn word(b: &[u8], k: usize) -> u32 {
    u32::from_le_bytes([b[4 * k], b[4 * k + 1], b[4 * k + 2], b[4 * k + 3]])
}

/// Maps the read-back buffers once the GPU is done and decodes the frame straight from their
/// rows, rows in parallel: colours as bytes, normals decoded (zero off the model), depth
/// linear (`near / z`, ∞ off the model), ids split per channel.
#[allow(clippy::too_many_arguments)]
fn read_frame(
    device: &wgpu::Device,
    reads: &Reads,
    index: wgpu::SubmissionIndex,
    outputs: Outputs,
    near: f32,
    w: u32,
    h: u32,
    mut stats: RenderStats,
) -> Result<Frame, RenderError> {
    let t = Instant::now();
    let (tx, rx) = std::sync::mpsc::channel();
    for (i, r) in reads.buffers.iter().enumerate() {
        let tx = tx.clone();
        r.buffer
            .slice(..)
            .map_async(wgpu::MapMode::Read, move |res| {
                let _ = tx.send((i, res));
            });
    }
    wait(device, index)?;
    stats.profile.gpu_ms += ms(t);
    let t = Instant::now();
    let deadline = Instant::now() + GPU_TIMEOUT;
    for _ in 0..reads.buffers.len() {
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
    let mut views = Vec::with_capacity(reads.buffers.len());
    for r in &reads.buffers {
        views.push(
            r.buffer
                .get_mapped_range(..)
                .map_err(|e| RenderError::Gpu(format!("read-back mapping: {e}")))?,
        );
    }
    let (wu, hu) = (w as usize, h as usize);
    let rows = |i: usize| Rows {
        bytes: &views[i],
        pitch: reads.buffers[i].row as usize,
        width: wu * reads.buffers[i].bpp as usize,
    };
    let n = wu * hu;
    let ids_rows = reads.ids.map(rows);
    let covered = |y: usize, x: usize| {
        ids_rows
            .as_ref()
            .is_none_or(|r| word(r.row(y), 4 * x) != NO_NODE)
    };
    let color = reads.color.map(|i| {
        let r = rows(i);
        let mut out = vec![[0u8; 4]; n];
        out.par_chunks_mut(wu).enumerate().for_each(|(y, line)| {
            for (x, px) in r.row(y).chunks_exact(4).enumerate() {
                line[x] = [px[0], px[1], px[2], px[3]];
            }
        });
        out
    });
    let normal = reads.normal.map(|i| {
        let r = rows(i);
        let mut out = vec![[0f32; 3]; n];
        out.par_chunks_mut(wu).enumerate().for_each(|(y, line)| {
            let src = r.row(y);
            for (x, n) in line.iter_mut().enumerate() {
                if covered(y, x) {
                    *n = oct_decode(word(src, x));
                }
            }
        });
        out
    });
    let depth = reads.depth.map(|i| {
        let r = rows(i);
        let mut out = vec![0f32; n];
        out.par_chunks_mut(wu).enumerate().for_each(|(y, line)| {
            let src = r.row(y);
            for (x, d) in line.iter_mut().enumerate() {
                let z = f32::from_bits(word(src, x));
                *d = if z > 0.0 { near / z } else { f32::INFINITY };
            }
        });
        out
    });
    let ids = match &ids_rows {
        Some(r) if outputs.ids => {
            let mut b = IdBuffer {
                node: vec![0; n],
                vertex: vec![0; n],
                triangle: vec![0; n],
                highlight: vec![0; n],
            };
            b.node
                .par_chunks_mut(wu)
                .zip(b.vertex.par_chunks_mut(wu))
                .zip(b.triangle.par_chunks_mut(wu))
                .zip(b.highlight.par_chunks_mut(wu))
                .enumerate()
                .for_each(|(y, (((node, vertex), triangle), highlight))| {
                    let src = r.row(y);
                    for x in 0..wu {
                        let id = word(src, 4 * x);
                        node[x] = id;
                        vertex[x] = word(src, 4 * x + 1);
                        triangle[x] = word(src, 4 * x + 2);
                        highlight[x] = if id == NO_NODE {
                            0
                        } else {
                            word(src, 4 * x + 3) | COVERED_BIT
                        };
                    }
                });
            Some(b)
        }
        _ => None,
    };
    stats.profile.read_bytes = reads
        .buffers
        .iter()
        .map(|r| (w * r.bpp) as u64 * h as u64)
        .sum();
    drop(views);
    for r in &reads.buffers {
        r.buffer.unmap();
    }
    stats.profile.read_ms = ms(t);
    Ok(Frame {
        width: w,
        height: h,
        origin: [0, 0],
        color,
        normal,
        depth,
        ids,
        stats,
    })
}

/// Milliseconds since `t`.
fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

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
