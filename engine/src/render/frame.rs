//! One frame of the renderer, pass by pass: the render targets, the frame's uniforms, the main
//! pass over the cut in memory-bounded batches (patches decoded and uploaded on demand, pinned
//! while their batch draws), the outline post pass of hovered parts, and the read-back of the
//! requested buffers (colour, normals, linear depth, ids).

use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{Mat4, Vec3, Vec4};
use wgpu::util::DeviceExt;

use super::cache::{GpuPatch, node_bytes};
use super::highlight::{self, Prepared};
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
    uvs: u32,
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

/// The frame's uniforms on the GPU: camera and lighting, and the highlight palette.
struct Globals {
    frame: wgpu::Buffer,
    palette: wgpu::Buffer,
}

impl Targets {
    /// The targets of a `w`×`h` frame: buffers mode (normals and ids) or image mode (mask).
    fn new(device: &wgpu::Device, w: u32, h: u32, buffers_mode: bool) -> Targets {
        Targets {
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
        }
    }

    fn views(&self) -> TargetViews {
        TargetViews {
            color: self.color.create_view(&Default::default()),
            second: self.second.create_view(&Default::default()),
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
    second: wgpu::TextureView,
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
        let (w, h) = (camera.width, camera.height);
        let outputs = options.outputs;
        let targets = Targets::new(device, w, h, outputs.normal || outputs.ids);
        let views = targets.views();
        let globals = self.globals(model, camera, options, prepared, near);
        let mut stats = RenderStats::default();
        let load_time = self.main_pass(
            model, options, prepared, nodes, &views, &globals, &mut stats,
        )?;
        stats.load_ms = load_time.as_secs_f64() * 1e3;

        let mut encoder = device.create_command_encoder(&Default::default());
        let outlined = (outputs.color && prepared.any_outline && options.outline_width > 0)
            .then(|| self.outline_pass(&mut encoder, &views, options, w, h));
        let color = outlined.as_ref().unwrap_or(&targets.color);
        let reads = record_reads(device, &mut encoder, &targets, color, outputs, w, h);
        let index = self.gpu.queue.submit([encoder.finish()]);
        let data = read_all(device, &reads.buffers, index, w, h)?;
        stats.draw_ms = draw_start.elapsed().saturating_sub(load_time).as_secs_f64() * 1e3;
        Ok(decode_frame(&reads, &data, outputs, near, w, h, stats))
    }

    /// The frame's uniforms: view-projection (reversed Z, `near`), eye, lighting, the pixel
    /// basis of point sprites, and the highlight palette.
    fn globals(
        &self,
        model: &RenderModel,
        camera: &Camera,
        options: &RenderOptions,
        prepared: &Prepared<'_>,
        near: f32,
    ) -> Globals {
        let device = &self.gpu.device;
        let (w, h) = (camera.width, camera.height);
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
    /// next is pinned. The first batch clears the targets. Returns the time spent loading.
    #[allow(clippy::too_many_arguments)]
    fn main_pass(
        &self,
        model: &RenderModel,
        options: &RenderOptions,
        prepared: &Prepared<'_>,
        nodes: &[u32],
        views: &TargetViews,
        globals: &Globals,
        stats: &mut RenderStats,
    ) -> Result<Duration, RenderError> {
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
        let buffers_mode = options.outputs.normal || options.outputs.ids;
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
            let t_load = Instant::now();
            let patches = self.acquire(model, &nodes[start..end], stats)?;
            load_time += t_load.elapsed();
            let bind = self.batch_bindings(&patches, prepared, globals, stats);
            let mut encoder = device.create_command_encoder(&Default::default());
            encode_batch(
                &mut encoder,
                views,
                options,
                first,
                if buffers_mode {
                    &self.pipelines.buffers
                } else {
                    &self.pipelines.image
                },
                &bind,
                &patches,
            );
            let index = self.gpu.queue.submit([encoder.finish()]);
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
        Ok(load_time)
    }

    /// The bind group of one batch: the frame's uniforms, one draw record per patch (where its
    /// streams lie, and its highlight masks) and the masks themselves.
    fn batch_bindings(
        &self,
        patches: &[Arc<GpuPatch>],
        prepared: &Prepared<'_>,
        globals: &Globals,
        stats: &mut RenderStats,
    ) -> wgpu::BindGroup {
        let device = &self.gpu.device;
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
                    uvs: p.layout.uvs,
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
        device.create_bind_group(&wgpu::BindGroupDescriptor {
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
        })
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
        let (mask_view, channel) = match &views.ids {
            Some(ids) => (ids, 3u32),
            None => (&views.second, 0u32),
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

/// Encodes one batch of the main pass: clears the targets when `first`, else loads them.
fn encode_batch(
    encoder: &mut wgpu::CommandEncoder,
    views: &TargetViews,
    options: &RenderOptions,
    first: bool,
    pipeline: &wgpu::RenderPipeline,
    bind: &wgpu::BindGroup,
    patches: &[Arc<GpuPatch>],
) {
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
    let mut attachments = vec![
        Some(wgpu::RenderPassColorAttachment {
            view: &views.color,
            depth_slice: None,
            resolve_target: None,
            ops: ops(clear_color),
        }),
        Some(wgpu::RenderPassColorAttachment {
            view: &views.second,
            depth_slice: None,
            resolve_target: None,
            ops: ops(wgpu::Color::TRANSPARENT),
        }),
    ];
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
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bind, &[]);
    for (i, p) in patches.iter().enumerate() {
        if p.triangles == 0 {
            continue;
        }
        pass.set_bind_group(1, &p.bind_group, &[]);
        pass.draw(0..p.triangles * 3, i as u32..i as u32 + 1);
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
    let normal = outputs.normal.then(|| add(&targets.second, 4, all));
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

/// The frame from the read-back words: colours as bytes, normals decoded (zero off the model),
/// depth linear (`near / z`, ∞ off the model), ids split per channel.
fn decode_frame(
    reads: &Reads,
    data: &[Vec<u32>],
    outputs: Outputs,
    near: f32,
    w: u32,
    h: u32,
    stats: RenderStats,
) -> Frame {
    let n = (w as usize) * (h as usize);
    let ids_words: Option<&Vec<u32>> = reads.ids.map(|i| &data[i]);
    let covered = |i: usize| ids_words.is_none_or(|d| d[i * 4] != NO_NODE);
    let color = reads
        .color
        .map(|i| data[i].iter().map(|v| v.to_le_bytes()).collect());
    let normal = reads.normal.map(|i| {
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
    let depth = reads.depth.map(|i| {
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
    Frame {
        width: w,
        height: h,
        color,
        normal,
        depth,
        ids,
        stats,
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
