// Main pass of the headless renderer (system paper §3.3; buffers for selection §4.1.1, §4.1.2).
//
// Patches are drawn non-indexed from storage buffers: `vertex_index` gives the triangle and its
// corner, `instance_index` (the draw's first instance) the draw record. Every corner outputs the
// triangle's three original vertex ids (flat) and a one-hot barycentric; the fragment keeps the
// id of the corner with the largest barycentric, so a pixel's id is always a vertex of the
// triangle drawn there. Depth is reversed-Z with an infinite far plane: depth = near / view depth.

struct Frame {
    view_proj: mat4x4<f32>,
    eye: vec4<f32>,
    // x: ambient, y: diffuse, z: 1 when the model has colours, w: unused
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
    positions: u32,
    normals: u32,
    colors: u32,
    ids: u32,
    indices: u32,
    // offset of the per-vertex highlight masks in `masks`, 0xFFFFFFFF when none
    masks: u32,
    // offset of the texture coordinates (unorm16 pairs), 0xFFFFFFFF when the patch has none
    uvs: u32,
}

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<storage, read> draws: array<Draw>;
@group(0) @binding(2) var<storage, read> masks: array<u32>;
// tint colours: rgb, a = strength; index 0 unused
@group(0) @binding(3) var<uniform> palette: array<vec4<f32>, 256>;
// one patch: f32 positions and normals (3 per vertex), RGBA8 colours, original ids, indices
@group(1) @binding(0) var<storage, read> patch_data: array<u32>;
// the patch's texture atlas (a white texel when it has none), sampled bilinearly
@group(1) @binding(1) var atlas: texture_2d<f32>;
@group(1) @binding(2) var atlas_sampler: sampler;

// Few varyings: a software rasteriser bins every triangle with its interpolants.
struct VOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    @location(1) color: vec3<f32>,
    // barycentrics of corners 0 and 1
    @location(2) bary: vec2<f32>,
    @location(3) @interpolate(flat) ids: vec3<u32>,
    // the corners' highlight masks, 9 bits each
    @location(4) @interpolate(flat) masks: u32,
    // node id, triangle index within the patch
    @location(5) @interpolate(flat) node_tri: vec2<u32>,
    // texture coordinates in the patch's atlas; x < 0 when untextured
    @location(6) uv: vec2<f32>,
}

fn load_vec3(offset: u32, v: u32) -> vec3<f32> {
    let o = offset + v * 3u;
    return vec3<f32>(bitcast<f32>(patch_data[o]), bitcast<f32>(patch_data[o + 1u]), bitcast<f32>(patch_data[o + 2u]));
}

fn vertex_mask(d: Draw, v: u32) -> u32 {
    if (d.masks == 0xFFFFFFFFu) {
        return 0u;
    }
    return masks[d.masks + v];
}

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VOut {
    let d = draws[ii];
    let tri = vi / 3u;
    let corner = vi % 3u;
    let base = d.indices + tri * 3u;
    let t = vec3<u32>(patch_data[base], patch_data[base + 1u], patch_data[base + 2u]);
    let v = t[corner];
    let p = load_vec3(d.positions, v);
    var out: VOut;
    out.clip = frame.view_proj * vec4<f32>(p, 1.0);
    out.normal = load_vec3(d.normals, v);
    if (frame.light.z > 0.5) {
        out.color = unpack4x8unorm(patch_data[d.colors + v]).rgb;
    } else {
        out.color = frame.base_color.rgb;
    }
    out.bary = vec2<f32>(select(0.0, 1.0, corner == 0u), select(0.0, 1.0, corner == 1u));
    out.ids = vec3<u32>(patch_data[d.ids + t.x], patch_data[d.ids + t.y], patch_data[d.ids + t.z]);
    out.masks = vertex_mask(d, t.x) | (vertex_mask(d, t.y) << 9u) | (vertex_mask(d, t.z) << 18u);
    out.node_tri = vec2<u32>(d.node, tri);
    if (d.uvs != 0xFFFFFFFFu) {
        out.uv = unpack2x16unorm(patch_data[d.uvs + v]);
    } else {
        out.uv = vec2<f32>(-1.0, -1.0);
    }
    return out;
}

// Corner with the largest barycentric coordinate (ties: lowest corner).
fn nearest_corner(b2: vec2<f32>) -> u32 {
    let b = vec3<f32>(b2, 1.0 - b2.x - b2.y);
    if (b.x >= b.y && b.x >= b.z) {
        return 0u;
    }
    if (b.y >= b.z) {
        return 1u;
    }
    return 2u;
}

// Highlight mask of corner `k`.
fn corner_mask(in: VOut, k: u32) -> u32 {
    return (in.masks >> (9u * k)) & 0x1FFu;
}

// Unit vector from the surface at pixel `frag` towards the eye.
fn to_eye(frag: vec4<f32>) -> vec3<f32> {
    let ray = frame.forward.xyz + frame.right.xyz * (frag.x - frame.center.x) - frame.up.xyz * (frag.y - frame.center.y);
    return -normalize(ray);
}

// Unit normal facing the viewer.
fn facing_normal(in: VOut, front: bool) -> vec3<f32> {
    var n = in.normal;
    let l = length(n);
    if (l > 1e-20) {
        n = n / l;
    } else {
        n = to_eye(in.clip);
    }
    if (!front) {
        n = -n;
    }
    return n;
}

// Surface colour: the patch's texture, else the vertex colour. Texels, like vertex colours, are
// sRGB bytes taken as they are.
fn albedo(in: VOut) -> vec3<f32> {
    if (in.uv.x >= 0.0) {
        return textureSampleLevel(atlas, atlas_sampler, in.uv, 0.0).rgb;
    }
    return in.color.rgb;
}

// Headlight plus ambient, then the part tint.
fn shade(in: VOut, n: vec3<f32>, mask: u32) -> vec4<f32> {
    let v = to_eye(in.clip);
    let ndl = abs(dot(n, v));
    var rgb = albedo(in) * (frame.light.x + frame.light.y * ndl);
    let tint = mask & 0xFFu;
    if (tint != 0u) {
        let c = palette[tint];
        rgb = mix(rgb, c.rgb, c.a);
    }
    return vec4<f32>(clamp(rgb, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
}

struct ImageOut {
    @location(0) color: vec4<f32>,
    @location(1) mask: u32,
}

@fragment
fn fs_image(in: VOut, @builtin(front_facing) front: bool) -> ImageOut {
    let k = nearest_corner(in.bary);
    let mask = corner_mask(in, k);
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
fn fs_buffers(in: VOut, @builtin(front_facing) front: bool) -> BuffersOut {
    let k = nearest_corner(in.bary);
    let mask = corner_mask(in, k);
    let n = facing_normal(in, front);
    var out: BuffersOut;
    out.color = shade(in, n, mask);
    out.normal = oct_encode(n);
    out.ids = vec4<u32>(in.node_tri.x, in.ids[k], in.node_tri.y, mask);
    return out;
}
