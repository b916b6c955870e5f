//! Render pipelines of the headless renderer (system paper §3.3 drawing; §4.1.1/§4.1.2 the
//! normal, depth and index images selection runs on; §2.2 the bold outline of a hovered part).
//!
//! The main pass has one pipeline per [`Variant`] (what it writes) and [`Albedo`] (where the
//! patch's colour comes from), made on first use: `image` (colour alone) for pictures,
//! `image_marked` / `image_unmarked` (colour + highlight mask, on patches with and without
//! marked vertices) for pictures with parts, `buffers` (colour, packed normal, ids) for
//! selection; all share one vertex shader (indexed, from the patch's buffer). Depth is a
//! `Depth32Float` attachment with reversed Z (cleared to 0, test `Greater`), read back as linear
//! view depth.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use wgpu::util::DeviceExt;
use wgpu::{
    BindGroupLayout, BindGroupLayoutEntry, BindingType, BufferBindingType, ColorTargetState,
    Device, RenderPipeline, ShaderStages, TextureFormat,
};

pub const COLOR_FORMAT: TextureFormat = TextureFormat::Rgba8Unorm;
pub const MASK_FORMAT: TextureFormat = TextureFormat::R32Uint;
pub const NORMAL_FORMAT: TextureFormat = TextureFormat::R32Uint;
pub const IDS_FORMAT: TextureFormat = TextureFormat::Rgba32Uint;
pub const DEPTH_FORMAT: TextureFormat = TextureFormat::Depth32Float;
/// Patch atlases: sRGB bytes sampled as they are, like vertex colours.
pub const ATLAS_FORMAT: TextureFormat = TextureFormat::Rgba8Unorm;

const RENDER_WGSL: &str = include_str!("../../../shaders/render.wgsl");
const OUTLINE_WGSL: &str = include_str!("../../../shaders/outline.wgsl");

/// Pipelines and layouts, created once per renderer.
pub struct Pipelines {
    pub frame_layout: BindGroupLayout,
    pub patch_layout: BindGroupLayout,
    /// Bilinear, clamped: how every patch samples its atlas.
    pub atlas_sampler: wgpu::Sampler,
    /// A white texel, bound for patches without atlas.
    pub no_atlas: wgpu::TextureView,
    pub outline_layout: BindGroupLayout,
    pub outline: RenderPipeline,
    main_layout: wgpu::PipelineLayout,
    render_module: wgpu::ShaderModule,
    main: Mutex<HashMap<MainKey, Arc<RenderPipeline>>>,
}

/// What a main-pass pipeline writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Variant {
    /// Colour alone.
    Image,
    /// Colour and mask, on patches holding marked vertices (nearest corner resolved).
    ImageMarked,
    /// Colour and mask ("covered"), on patches holding none.
    ImageUnmarked,
    /// Colour, packed normal and ids (nearest corner resolved).
    Buffers,
}

impl Variant {
    fn entry(self) -> &'static str {
        match self {
            Variant::Image => "fs_image",
            Variant::ImageMarked => "fs_image_marked",
            Variant::ImageUnmarked => "fs_image_unmarked",
            Variant::Buffers => "fs_buffers",
        }
    }

    /// Whether its fragment shader reads the patch's buffer (and so needs its bind group).
    pub fn reads_patch(self) -> bool {
        matches!(self, Variant::ImageMarked | Variant::Buffers)
    }
}

/// A main-pass pipeline: what it writes, where colour comes from, and whether the patch has
/// a normal map (`NORMAL_MAP` in `render.wgsl`).
pub type MainKey = (Variant, Albedo, bool);

/// Where a patch's colour comes from (`ALBEDO` in `render.wgsl`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Albedo {
    /// The frame's base colour (a model without colours).
    Base = 0,
    /// Its vertex colours.
    Vertex = 1,
    /// Its texture atlas.
    Texture = 2,
}

/// The vertex buffers of a patch's draw: positions and normals (f32 × 3), colours (RGBA8) and
/// texture coordinates (unorm16 × 2), each a slice of the patch's buffer.
const VERTEX_BUFFERS: [Option<wgpu::VertexBufferLayout<'static>>; 4] =
    [POSITIONS, NORMALS, COLORS, UVS];

const POSITIONS: Option<wgpu::VertexBufferLayout<'static>> =
    vertex_buffer(12, &wgpu::vertex_attr_array![0 => Float32x3]);
const NORMALS: Option<wgpu::VertexBufferLayout<'static>> =
    vertex_buffer(12, &wgpu::vertex_attr_array![1 => Float32x3]);
const COLORS: Option<wgpu::VertexBufferLayout<'static>> =
    vertex_buffer(4, &wgpu::vertex_attr_array![2 => Unorm8x4]);
const UVS: Option<wgpu::VertexBufferLayout<'static>> =
    vertex_buffer(4, &wgpu::vertex_attr_array![3 => Unorm16x2]);

/// A per-vertex buffer of `array_stride` bytes a vertex holding `attributes`.
const fn vertex_buffer(
    array_stride: u64,
    attributes: &'static [wgpu::VertexAttribute],
) -> Option<wgpu::VertexBufferLayout<'static>> {
    Some(wgpu::VertexBufferLayout {
        array_stride,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes,
    })
}

/// The vertex buffers of the per-vertex lit images (`vs_lit_*` in `render.wgsl`): positions
/// and normals, and the colours (vertex albedo) or texture coordinates (atlas) only where
/// read, so the rasteriser fetches nothing else.
const LIT_BUFFERS: [[Option<wgpu::VertexBufferLayout<'static>>; 4]; 3] = [
    [POSITIONS, NORMALS, None, None],
    [POSITIONS, NORMALS, COLORS, None],
    [POSITIONS, NORMALS, None, UVS],
];

fn storage(binding: u32, visibility: ShaderStages) -> BindGroupLayoutEntry {
    BindGroupLayoutEntry {
        binding,
        visibility,
        ty: BindingType::Buffer {
            ty: BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform(binding: u32, visibility: ShaderStages) -> BindGroupLayoutEntry {
    BindGroupLayoutEntry {
        binding,
        visibility,
        ty: BindingType::Buffer {
            ty: BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn texture(binding: u32, sample_type: wgpu::TextureSampleType) -> BindGroupLayoutEntry {
    BindGroupLayoutEntry {
        binding,
        visibility: ShaderStages::FRAGMENT,
        ty: BindingType::Texture {
            sample_type,
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

fn target(format: TextureFormat) -> Option<ColorTargetState> {
    Some(ColorTargetState {
        format,
        blend: None,
        write_mask: wgpu::ColorWrites::ALL,
    })
}

/// A patch atlas on the GPU: `texels` RGBA8, row by row from the top.
pub fn atlas_texture(
    device: &Device,
    queue: &wgpu::Queue,
    width: u32,
    height: u32,
    texels: &[u8],
) -> wgpu::Texture {
    device.create_texture_with_data(
        queue,
        &wgpu::TextureDescriptor {
            label: Some("atlas"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: ATLAS_FORMAT,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        texels,
    )
}

impl Pipelines {
    pub fn new(device: &Device, queue: &wgpu::Queue) -> Pipelines {
        let vf = ShaderStages::VERTEX | ShaderStages::FRAGMENT;
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame"),
            entries: &[
                uniform(0, vf),
                storage(1, vf),
                storage(2, ShaderStages::FRAGMENT),
                uniform(3, ShaderStages::FRAGMENT),
            ],
        });
        let patch_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("patch"),
            entries: &[
                storage(0, ShaderStages::FRAGMENT),
                texture(1, wgpu::TextureSampleType::Float { filterable: true }),
                BindGroupLayoutEntry {
                    binding: 2,
                    visibility: ShaderStages::FRAGMENT,
                    ty: BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                texture(3, wgpu::TextureSampleType::Float { filterable: true }),
            ],
        });
        let atlas_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("atlas"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let white = atlas_texture(device, queue, 1, 1, &[255; 4]);
        let no_atlas = white.create_view(&Default::default());
        let outline_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("outline"),
            entries: &[
                texture(0, wgpu::TextureSampleType::Float { filterable: false }),
                texture(1, wgpu::TextureSampleType::Uint),
                uniform(2, ShaderStages::FRAGMENT),
            ],
        });
        let render_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("render.wgsl"),
            source: wgpu::ShaderSource::Wgsl(RENDER_WGSL.into()),
        });
        let outline_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("outline.wgsl"),
            source: wgpu::ShaderSource::Wgsl(OUTLINE_WGSL.into()),
        });
        let main_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("main"),
            bind_group_layouts: &[Some(&frame_layout), Some(&patch_layout)],
            immediate_size: 0,
        });

        let post_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("outline"),
            bind_group_layouts: &[Some(&outline_layout)],
            immediate_size: 0,
        });
        let outline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("outline"),
            layout: Some(&post_layout),
            vertex: wgpu::VertexState {
                module: &outline_module,
                entry_point: Some("vs_full"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &outline_module,
                entry_point: Some("fs_outline"),
                compilation_options: Default::default(),
                targets: &[target(COLOR_FORMAT)],
            }),
            multiview_mask: None,
            cache: None,
        });
        Pipelines {
            frame_layout,
            patch_layout,
            atlas_sampler,
            no_atlas,
            outline_layout,
            outline,
            main_layout,
            render_module,
            main: Mutex::new(HashMap::new()),
        }
    }

    /// The main-pass pipeline of `key` (made on first use: a software adapter compiles each in
    /// tens of milliseconds).
    pub fn main(&self, device: &Device, key: MainKey) -> Arc<RenderPipeline> {
        let mut cache = self.main.lock().unwrap_or_else(|e| e.into_inner());
        cache
            .entry(key)
            .or_insert_with(|| Arc::new(self.make_main(device, key)))
            .clone()
    }

    fn make_main(&self, device: &Device, (variant, albedo, normal_map): MainKey) -> RenderPipeline {
        let targets: &[Option<ColorTargetState>] = match variant {
            Variant::Image => &[target(COLOR_FORMAT)],
            Variant::ImageMarked | Variant::ImageUnmarked => {
                &[target(COLOR_FORMAT), target(MASK_FORMAT)]
            }
            Variant::Buffers => &[
                target(COLOR_FORMAT),
                target(NORMAL_FORMAT),
                target(IDS_FORMAT),
            ],
        };
        let constants = [
            ("ALBEDO", albedo as u32 as f64),
            ("NORMAL_MAP", f64::from(u8::from(normal_map))),
        ];
        let options = wgpu::PipelineCompilationOptions {
            constants: &constants,
            ..Default::default()
        };
        // Plain images without normal map: an entry point per albedo that fetches only what it
        // reads (`vs_lit_*` in render.wgsl).
        let (vertex, fragment, buffers) = match (variant, normal_map, albedo) {
            (Variant::Image, false, Albedo::Base) => ("vs_lit_base", "fs_lit", &LIT_BUFFERS[0]),
            (Variant::Image, false, Albedo::Vertex) => ("vs_lit_vertex", "fs_lit", &LIT_BUFFERS[1]),
            (Variant::Image, false, Albedo::Texture) => {
                ("vs_lit_texture", "fs_lit_texture", &LIT_BUFFERS[2])
            }
            _ => ("vs_main", variant.entry(), &VERTEX_BUFFERS),
        };
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(fragment),
            layout: Some(&self.main_layout),
            vertex: wgpu::VertexState {
                module: &self.render_module,
                entry_point: Some(vertex),
                compilation_options: options.clone(),
                buffers,
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                front_face: wgpu::FrontFace::Ccw,
                // Scans are not reliably oriented; back faces are shaded two-sided.
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &self.render_module,
                entry_point: Some(fragment),
                compilation_options: options,
                targets,
            }),
            multiview_mask: None,
            cache: None,
        })
    }
}
