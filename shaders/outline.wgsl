// Bold outline of the hovered part (system paper §2.2: "the boundaries of those regions are
// highlighted with bold lines"): a post pass over the per-pixel highlight mask. A pixel outside
// the part within `width` pixels of it takes the outline colour (soft by a pixel at the rim).

struct Params {
    color: vec4<f32>,
    // x: width in pixels, y: channel of the mask texture (0 = x, 3 = w), z: bit tested
    args: vec4<u32>,
}

@group(0) @binding(0) var color_tex: texture_2d<f32>;
@group(0) @binding(1) var mask_tex: texture_2d<u32>;
@group(0) @binding(2) var<uniform> params: Params;

@vertex
fn vs_full(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

fn marked(p: vec2<i32>, size: vec2<i32>) -> bool {
    if (p.x < 0 || p.y < 0 || p.x >= size.x || p.y >= size.y) {
        return false;
    }
    let m = textureLoad(mask_tex, p, 0)[params.args.y];
    return (m & params.args.z) != 0u;
}

@fragment
fn fs_outline(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let p = vec2<i32>(pos.xy);
    let size = vec2<i32>(textureDimensions(color_tex));
    let c = textureLoad(color_tex, p, 0);
    if (marked(p, size)) {
        return c;
    }
    let r = i32(params.args.x);
    var best = 1e9;
    for (var dy = -r; dy <= r; dy++) {
        for (var dx = -r; dx <= r; dx++) {
            let d2 = f32(dx * dx + dy * dy);
            if (d2 < best && marked(p + vec2<i32>(dx, dy), size)) {
                best = d2;
            }
        }
    }
    let d = sqrt(best);
    let w = f32(r);
    if (d > w + 0.5) {
        return c;
    }
    let a = params.color.a * clamp(w + 0.5 - d, 0.0, 1.0);
    return vec4<f32>(mix(c.rgb, params.color.rgb, a), 1.0);
}
