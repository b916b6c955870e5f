// Main pass of the headless renderer (system paper §3.3; buffers for selection §4.1.1, §4.1.2).
//
// Patches are drawn indexed, straight from their buffers: positions, normals, colours and
// texture coordinates are vertex attributes, the patch's triangles the index buffer, so the
// rasteriser transforms each vertex once (a software rasteriser transforms on one thread) and
// interpolates few varyings. `instance_index` (the draw's first instance) names the draw
// record of the patch.
//
// Selection needs, per pixel, an original vertex id: the triangle corner nearest the pixel
// centre, always a vertex of the triangle drawn there; part tints follow the same corner. The
// `*_marked` and `fs_buffers` fragment shaders find it from `primitive_index`: they load the
// triangle's three corners from the patch, and the pixel centre's perspective-correct
// barycentrics are those of homogeneous rasterisation (Olano & Greer 1997: the centre's
// normalised device point p lies on the ray through Σ bᵢ vᵢ, so bᵢ ∝ (vⱼ × vₖ) · p for the
// clip-space (x, y, w) of the corners), valid even for corners behind the eye. The largest
// wins (ties: the lowest corner). Plain images skip all of it. Depth is reversed-Z with an
// infinite far plane: depth = near / view depth.
//
// `ALBEDO` (a pipeline constant) is where a patch's colour comes from: 0 the frame's base
// colour (models without colour), 1 its vertex colours, 2 its texture atlas. Each patch is drawn
// by the pipeline of its own, so no shader carries the others' varyings, loads or branches.
// `NORMAL_MAP` (a pipeline constant): the patch has a normal map (coarse patches, issue 11
// item 4), whose object-space normal of the finest surface replaces the interpolated one.
//
// Light is computed per vertex (`vertex_light`), per pixel only under a normal map. The
// viewer lights per pixel (a GPU's fragments are cheap); at the 1 px cut both agree within
// the browser tests' canvas-to-server tolerance.

enable primitive_index;

override ALBEDO: u32 = 1u;
override NORMAL_MAP: bool = false;

struct Frame {
    view_proj: mat4x4<f32>,
    eye: vec4<f32>,
    // x: ambient, y: diffuse, z, w: unused
    light: vec4<f32>,
    // albedo of models without colour
    base_color: vec4<f32>,
    // view direction, and right/up divided by the pixel scale: the ray through pixel (x, y)
    // is forward + right * (x - cx) - up * (y - cy), with (cx, cy) = xy of `center`
    forward: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    center: vec4<f32>,
}

struct Draw {
    node: u32,
    // word offsets in the patch's buffer
    positions: u32,
    ids: u32,
    indices: u32,
    // offset of the per-vertex highlight masks in `masks`, 0xFFFFFFFF when none
    masks: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<storage, read> draws: array<Draw>;
@group(0) @binding(2) var<storage, read> masks: array<u32>;
// tint colours: rgb, a = strength; index 0 unused
@group(0) @binding(3) var<uniform> palette: array<vec4<f32>, 256>;
// one patch: f32 positions and normals (3 per vertex), RGBA8 colours, original ids, indices,
// texture coordinates
@group(1) @binding(0) var<storage, read> patch_data: array<u32>;
// the patch's texture atlas (a white texel when it has none), sampled bilinearly
@group(1) @binding(1) var atlas: texture_2d<f32>;
@group(1) @binding(2) var atlas_sampler: sampler;
// the patch's normal map (a white texel when it has none): RGB = (n + 1) / 2, no sRGB curve
@group(1) @binding(3) var normal_map: texture_2d<f32>;

struct VIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    // RGBA8 (unorm); unused when the model has no colours
    @location(2) color: vec4<f32>,
    // unorm16 pairs; unused when the patch has no atlas
    @location(3) uv: vec2<f32>,
}

// Few varyings: a software rasteriser bins every triangle with its interpolants.
struct VOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    // lit colour (`vertex_light`): albedo × light (ALBEDO 0, 1) or the light alone, to
    // multiply the texel by (ALBEDO 2); with a normal map, the albedo unlit (ALBEDO 0, 1)
    @location(1) color: vec3<f32>,
    // texture coordinates in the patch's atlas (ALBEDO 2)
    @location(2) uv: vec2<f32>,
    @location(3) @interpolate(flat) draw: u32,
}

// Lighting is per vertex, ambient plus a headlight (the direction to the eye from the vertex
// is the pixel ray's at the vertex; a zero normal faces the eye): at a 1 px cut a triangle
// covers about a pixel, so per-pixel lighting repeats the vertices' work for the same result,
// and a software rasteriser pays per pixel for every instruction, per triangle for every
// varying and per vertex for every attribute fetched (`meshwiki-bench render`). Only a
// normal map, which carries detail finer than the triangles, is lit per pixel. Every
// variant lights a vertex alike, so marking a part changes no other pixel.
fn vertex_light(position: vec3<f32>, normal: vec3<f32>) -> f32 {
    let l = length(normal);
    var ndl = 1.0;
    if (l > 1e-20) {
        ndl = abs(dot(normal / l, normalize(frame.eye.xyz - position)));
    }
    return headlight(ndl);
}

// Ambient plus the headlight at `ndl` = |n·v|.
fn headlight(ndl: f32) -> f32 {
    return frame.light.x + frame.light.y * ndl;
}

fn lit_color(albedo: vec3<f32>, light: f32) -> vec3<f32> {
    return clamp(albedo * light, vec3<f32>(0.0), vec3<f32>(1.0));
}

@vertex
fn vs_main(v: VIn, @builtin(instance_index) ii: u32) -> VOut {
    var out: VOut;
    out.clip = frame.view_proj * vec4<f32>(v.position, 1.0);
    out.normal = v.normal;
    var albedo = frame.base_color.rgb;
    if (ALBEDO == 1u) {
        albedo = v.color.rgb;
    }
    if (NORMAL_MAP) {
        out.color = albedo;
    } else if (ALBEDO == 2u) {
        out.color = vec3<f32>(vertex_light(v.position, v.normal));
    } else {
        out.color = lit_color(albedo, vertex_light(v.position, v.normal));
    }
    if (ALBEDO == 2u || NORMAL_MAP) {
        out.uv = v.uv;
    } else {
        out.uv = vec2<f32>(0.0);
    }
    out.draw = ii;
    return out;
}

// Plain images (no part marked, no normal map): one entry point per albedo, each reading
// only the attributes it uses, with `vs_main`'s lit colour.
struct LitIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
}

struct LitOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) color: vec3<f32>,
}

fn lit(v: LitIn, albedo: vec3<f32>) -> LitOut {
    var out: LitOut;
    out.clip = frame.view_proj * vec4<f32>(v.position, 1.0);
    out.color = lit_color(albedo, vertex_light(v.position, v.normal));
    return out;
}

@vertex
fn vs_lit_base(v: LitIn) -> LitOut {
    return lit(v, frame.base_color.rgb);
}

@vertex
fn vs_lit_vertex(v: LitIn, @location(2) color: vec4<f32>) -> LitOut {
    return lit(v, color.rgb);
}

@fragment
fn fs_lit(in: LitOut) -> @location(0) vec4<f32> {
    return vec4<f32>(in.color, 1.0);
}

struct TexturedOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) light: f32,
    @location(1) uv: vec2<f32>,
}

@vertex
fn vs_lit_texture(v: LitIn, @location(3) uv: vec2<f32>) -> TexturedOut {
    var out: TexturedOut;
    out.clip = frame.view_proj * vec4<f32>(v.position, 1.0);
    out.light = vertex_light(v.position, v.normal);
    out.uv = uv;
    return out;
}

@fragment
fn fs_lit_texture(in: TexturedOut) -> @location(0) vec4<f32> {
    let texel = textureSampleLevel(atlas, atlas_sampler, in.uv, 0.0).rgb;
    return vec4<f32>(lit_color(texel, in.light), 1.0);
}

fn load_vec3(offset: u32, v: u32) -> vec3<f32> {
    let o = offset + v * 3u;
    return vec3<f32>(bitcast<f32>(patch_data[o]), bitcast<f32>(patch_data[o + 1u]), bitcast<f32>(patch_data[o + 2u]));
}

// Clip-space x, y, w of vertex `v` of draw `d`.
fn clip_xyw(d: Draw, v: u32) -> vec3<f32> {
    let c = frame.view_proj * vec4<f32>(load_vec3(d.positions, v), 1.0);
    return vec3<f32>(c.x, c.y, c.w);
}

// The corner of triangle `tri` of draw `d` nearest the pixel centre `frag`, and the triangle.
struct Corner {
    k: u32,
    tri: vec3<u32>,
}

fn nearest_corner(d: Draw, tri_index: u32, frag: vec4<f32>) -> Corner {
    let base = d.indices + tri_index * 3u;
    let t = vec3<u32>(patch_data[base], patch_data[base + 1u], patch_data[base + 2u]);
    let v0 = clip_xyw(d, t.x);
    let v1 = clip_xyw(d, t.y);
    let v2 = clip_xyw(d, t.z);
    // The pixel centre in normalised device coordinates (y up), homogeneous.
    let p = vec3<f32>((frag.x - frame.center.x) / frame.center.x, (frame.center.y - frag.y) / frame.center.y, 1.0);
    var b = vec3<f32>(dot(cross(v1, v2), p), dot(cross(v2, v0), p), dot(cross(v0, v1), p));
    let s = b.x + b.y + b.z;
    if (abs(s) > 0.0) {
        b = b / s;
    }
    var c: Corner;
    c.tri = t;
    if (b.x >= b.y && b.x >= b.z) {
        c.k = 0u;
    } else if (b.y >= b.z) {
        c.k = 1u;
    } else {
        c.k = 2u;
    }
    return c;
}

fn vertex_mask(d: Draw, v: u32) -> u32 {
    if (d.masks == 0xFFFFFFFFu) {
        return 0u;
    }
    return masks[d.masks + v];
}

// Unit vector from the surface at pixel `frag` towards the eye.
fn to_eye(frag: vec4<f32>) -> vec3<f32> {
    let ray = frame.forward.xyz + frame.right.xyz * (frag.x - frame.center.x) - frame.up.xyz * (frag.y - frame.center.y);
    return -normalize(ray);
}

// Unit normal facing the viewer.
// With a normal map, the texel's mean normal as it is: shorter than 1 where the finest surface
// under the texel is rough, which makes the (linear) diffuse light the texel's mean light.
fn facing_normal(in: VOut, front: bool) -> vec3<f32> {
    var n = in.normal;
    if (NORMAL_MAP) {
        n = textureSampleLevel(normal_map, atlas_sampler, in.uv, 0.0).rgb * 2.0 - 1.0;
    }
    let l = length(n);
    if (l <= 1e-20) {
        n = to_eye(in.clip);
    } else if (!NORMAL_MAP) {
        n = n / l;
    }
    if (!front) {
        n = -n;
    }
    return n;
}

// Surface colour (see ALBEDO). Texels, like vertex colours, are sRGB bytes taken as they are.
fn albedo(in: VOut) -> vec3<f32> {
    if (ALBEDO == 2u) {
        return textureSampleLevel(atlas, atlas_sampler, in.uv, 0.0).rgb;
    }
    if (ALBEDO == 1u) {
        return in.color.rgb;
    }
    return frame.base_color.rgb;
}

// The lit colour (per pixel with a normal map, else `vs_main`'s), then the part tint.
fn shade(in: VOut, n: vec3<f32>, mask: u32) -> vec4<f32> {
    var rgb = in.color;
    if (NORMAL_MAP) {
        rgb = lit_color(albedo(in), headlight(abs(dot(n, to_eye(in.clip)))));
    } else if (ALBEDO == 2u) {
        rgb = lit_color(albedo(in), in.color.x);
    }
    let tint = mask & 0xFFu;
    if (tint != 0u) {
        let c = palette[tint];
        rgb = mix(rgb, c.rgb, c.a);
    }
    return vec4<f32>(clamp(rgb, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
}

// A picture without parts marked, on a patch with a normal map (lit per pixel; without one,
// `fs_lit` and `fs_lit_texture` draw it).
@fragment
fn fs_image(in: VOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    return shade(in, facing_normal(in, front), 0u);
}

struct ImageOut {
    @location(0) color: vec4<f32>,
    @location(1) mask: u32,
}

// A picture with parts marked, on a patch that holds none of their vertices: the mask says
// only "covered".
@fragment
fn fs_image_unmarked(in: VOut, @builtin(front_facing) front: bool) -> ImageOut {
    var out: ImageOut;
    out.color = shade(in, facing_normal(in, front), 0u);
    out.mask = 0x80000000u;
    return out;
}

// A picture with parts marked, on a patch holding some of their vertices: tint and outline
// bit of the nearest corner.
@fragment
fn fs_image_marked(in: VOut, @builtin(front_facing) front: bool, @builtin(primitive_index) prim: u32) -> ImageOut {
    let d = draws[in.draw];
    let c = nearest_corner(d, prim, in.clip);
    let mask = vertex_mask(d, c.tri[c.k]);
    var out: ImageOut;
    out.color = shade(in, facing_normal(in, front), mask);
    out.mask = mask | 0x80000000u;
    return out;
}

fn sign_not_zero(v: vec2<f32>) -> vec2<f32> {
    return select(vec2<f32>(-1.0), vec2<f32>(1.0), v >= vec2<f32>(0.0));
}

// Octahedral encoding, 16-bit snorm per component.
fn oct_encode(n: vec3<f32>) -> u32 {
    var p = n.xy / (abs(n.x) + abs(n.y) + abs(n.z));
    if (n.z < 0.0) {
        p = (1.0 - abs(p.yx)) * sign_not_zero(p);
    }
    return pack2x16snorm(p);
}

struct BuffersOut {
    @location(0) color: vec4<f32>,
    @location(1) normal: u32,
    // node, original vertex id, triangle index in the patch, highlight mask
    @location(2) ids: vec4<u32>,
}

@fragment
fn fs_buffers(in: VOut, @builtin(front_facing) front: bool, @builtin(primitive_index) prim: u32) -> BuffersOut {
    let d = draws[in.draw];
    let c = nearest_corner(d, prim, in.clip);
    let v = c.tri[c.k];
    let mask = vertex_mask(d, v);
    let n = facing_normal(in, front);
    var out: BuffersOut;
    out.color = shade(in, n, mask);
    out.normal = oct_encode(n);
    out.ids = vec4<u32>(d.node, patch_data[d.ids + v], prim, mask);
    return out;
}
