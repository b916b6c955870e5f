//! The bare-draw reference of `meshwiki-bench render`: the same triangles of the same cut drawn
//! by the smallest pipeline that can produce the same kinds of output — positions as the only
//! vertex attribute, indexed, one constant colour, the patch and primitive as the id, a
//! reversed-Z depth test — into targets of the same size, read back as the renderer reads its
//! own. Its frame time is what the software rasteriser itself costs for those triangles; the
//! renderer's time over it is what the renderer adds (shading, attributes, exact ids, tints,
//! bookkeeping).

use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use glam::{Mat4, Vec4};
use meshwiki_engine::camera::Camera;
use meshwiki_engine::render::{GpuDevice, RenderModel};
use wgpu::util::DeviceExt;

const SHADER: &str = r"
struct U { view_proj: mat4x4<f32> }
@group(0) @binding(0) var<uniform> u: U;
struct VOut { @builtin(position) clip: vec4<f32>, @location(0) @interpolate(flat) node: u32 }
@vertex fn vs(@location(0) p: vec3<f32>, @builtin(instance_index) node: u32) -> VOut {
    var o: VOut;
    o.clip = u.view_proj * vec4<f32>(p, 1.0);
    o.node = node;
    return o;
}
struct Out { @location(0) color: vec4<f32>, @location(1) ids: vec2<u32> }
@fragment fn fs_ids(i: VOut, @builtin(primitive_index) prim: u32) -> Out {
    var o: Out;
    o.color = vec4<f32>(0.8, 0.78, 0.75, 1.0);
    o.ids = vec2<u32>(i.node, prim);
    return o;
}
@fragment fn fs_color(i: VOut) -> @location(0) vec4<f32> {
    return vec4<f32>(0.8, 0.78, 0.75, 1.0);
}
";

/// One patch: positions then indices in one buffer.
struct Patch {
    buffer: wgpu::Buffer,
    positions: u64,
    indices: u64,
    index_count: u32,
}

/// The bare reference: its pipelines, and the patches it has uploaded (its own copy).
pub struct Bare {
    gpu: Arc<GpuDevice>,
    layout: wgpu::BindGroupLayout,
    color_only: wgpu::RenderPipeline,
    with_ids: wgpu::RenderPipeline,
    patches: std::collections::HashMap<u32, Patch>,
}

/// Reversed-Z perspective with an infinite far plane, as the renderer's.
fn projection(camera: &Camera, near: f32) -> Mat4 {
    let f = 1.0 / (camera.fovy_deg.to_radians() * 0.5).tan();
    Mat4::from_cols(
        Vec4::new(f / camera.aspect(), 0.0, 0.0, 0.0),
        Vec4::new(0.0, f, 0.0, 0.0),
        Vec4::new(0.0, 0.0, 0.0, -1.0),
        Vec4::new(0.0, 0.0, near, 0.0),
    )
}

fn target(device: &wgpu::Device, w: u32, h: u32, format: wgpu::TextureFormat) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("bare target"),
        size: wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

impl Bare {
    /// The reference on the renderer's device.
    pub fn new(gpu: Arc<GpuDevice>) -> Result<Bare> {
        let device = &gpu.device;
        if !device.features().contains(wgpu::Features::PRIMITIVE_INDEX) {
            bail!("the device has no primitive_index");
        }
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("bare"),
            source: wgpu::ShaderSource::Wgsl(format!("enable primitive_index;\n{SHADER}").into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("bare"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("bare"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let make = |entry: &str, targets: &[Option<wgpu::ColorTargetState>]| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("bare"),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs"),
                    compilation_options: Default::default(),
                    buffers: &[Some(wgpu::VertexBufferLayout {
                        array_stride: 12,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &wgpu::vertex_attr_array![0 => Float32x3],
                    })],
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: wgpu::TextureFormat::Depth32Float,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Greater),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    targets,
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let color = Some(wgpu::ColorTargetState::from(
            wgpu::TextureFormat::Rgba8Unorm,
        ));
        let ids = Some(wgpu::ColorTargetState::from(wgpu::TextureFormat::Rg32Uint));
        let color_only = make("fs_color", std::slice::from_ref(&color));
        let with_ids = make("fs_ids", &[color, ids]);
        Ok(Bare {
            gpu,
            layout,
            color_only,
            with_ids,
            patches: Default::default(),
        })
    }

    /// Uploads the patches of `nodes` not yet uploaded (not timed: the renderer's cache is warm
    /// too when it is compared).
    pub fn load(&mut self, model: &RenderModel, nodes: &[u32]) -> Result<()> {
        for &node in nodes {
            if self.patches.contains_key(&node) {
                continue;
            }
            let p = model
                .lod()
                .patch(node)
                .with_context(|| format!("patch {node}"))?;
            let mut bytes: Vec<u8> = bytemuck::cast_slice(&p.positions).to_vec();
            let indices = bytes.len() as u64;
            bytes.extend_from_slice(bytemuck::cast_slice(&p.indices));
            let buffer = self
                .gpu
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("bare patch"),
                    contents: &bytes,
                    usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::INDEX,
                });
            self.patches.insert(
                node,
                Patch {
                    buffer,
                    positions: 0,
                    indices,
                    index_count: p.indices.len() as u32,
                },
            );
        }
        Ok(())
    }

    /// Draws `nodes` (loaded) for `camera` with `near`, reading back the colour and, with `ids`,
    /// the ids; returns the time taken (encoding, drawing, reading back into memory).
    pub fn frame(&self, nodes: &[u32], camera: &Camera, near: f32, ids: bool) -> Result<Duration> {
        let started = Instant::now();
        let device = &self.gpu.device;
        let (w, h) = (camera.width, camera.height);
        let view_proj = projection(camera, near) * camera.view();
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bare frame"),
            contents: bytemuck::cast_slice(&view_proj.to_cols_array()),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bare"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniform.as_entire_binding(),
            }],
        });
        let color = target(device, w, h, wgpu::TextureFormat::Rgba8Unorm);
        let id_target = ids.then(|| target(device, w, h, wgpu::TextureFormat::Rg32Uint));
        let depth = target(device, w, h, wgpu::TextureFormat::Depth32Float);
        let color_view = color.create_view(&Default::default());
        let id_view = id_target
            .as_ref()
            .map(|t| t.create_view(&Default::default()));
        let depth_view = depth.create_view(&Default::default());
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut attachments = vec![Some(wgpu::RenderPassColorAttachment {
                view: &color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store: wgpu::StoreOp::Store,
                },
            })];
            if let Some(v) = &id_view {
                attachments.push(Some(wgpu::RenderPassColorAttachment {
                    view: v,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                }));
            }
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("bare"),
                color_attachments: &attachments,
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            pass.set_pipeline(if ids {
                &self.with_ids
            } else {
                &self.color_only
            });
            pass.set_bind_group(0, &bind, &[]);
            for &node in nodes {
                let Some(p) = self.patches.get(&node) else {
                    continue;
                };
                if p.index_count == 0 {
                    continue;
                }
                pass.set_vertex_buffer(0, p.buffer.slice(p.positions..p.indices));
                pass.set_index_buffer(p.buffer.slice(p.indices..), wgpu::IndexFormat::Uint32);
                pass.draw_indexed(0..p.index_count, 0, node..node + 1);
            }
        }
        let mut reads = vec![(color, 4u32)];
        if let Some(t) = id_target {
            reads.push((t, 8));
        }
        let mut buffers = Vec::new();
        for (tex, bpp) in &reads {
            let row = (w * bpp).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
                * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
            let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("bare read-back"),
                size: row as u64 * h as u64,
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: tex,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
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
            buffers.push((buffer, row, *bpp));
        }
        let index = self.gpu.queue.submit([encoder.finish()]);
        for (b, _, _) in &buffers {
            b.slice(..).map_async(wgpu::MapMode::Read, |_| {});
        }
        device
            .poll(wgpu::PollType::Wait {
                submission_index: Some(index),
                timeout: Some(Duration::from_secs(120)),
            })
            .map_err(|e| anyhow::anyhow!("bare frame: {e}"))?;
        // The pixels copied out of the mapped rows, as the renderer does.
        let mut sink = 0u64;
        for (b, row, bpp) in &buffers {
            let view = b
                .get_mapped_range(..)
                .map_err(|e| anyhow::anyhow!("bare read-back: {e}"))?;
            let mut out = Vec::with_capacity((w * bpp * h) as usize);
            for y in 0..h as usize {
                let s = y * *row as usize;
                out.extend_from_slice(&view[s..s + (w * bpp) as usize]);
            }
            sink += out.len() as u64;
            drop(view);
            b.unmap();
        }
        std::hint::black_box(sink);
        Ok(started.elapsed())
    }
}
