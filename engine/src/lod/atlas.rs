//! Per-patch texture atlases (issue 11, item 2): every patch at every level carries its own
//! texture. Leaves cut theirs from the scan's textures through the source texture
//! coordinates; coarse patches resample theirs from the finer patches they replace (the
//! closest point on the finer surface, [`super::nearest`]), so colour stays right whatever
//! the simplification moved, and no UV seam of the source constrains the simplifier (the
//! fragmented photogrammetry atlases that keep Nexus' top levels at millions of triangles do
//! not arise: charts are made afresh for every patch).
//!
//! 1. **Charts**: region growing over the patch's triangle adjacency from the largest
//!    unassigned triangle; a neighbour joins while its normal stays within 60° of the chart's
//!    area-weighted mean normal (70° for triangles no larger than a texel or so). A chart is
//!    projected orthogonally onto the plane of that normal (every triangle keeps its
//!    orientation, so nothing folds) and turned to its principal axes for a tight rectangle. A chart of fewer than `SMALL_CHART_TEXELS`
//!    texels then joins the neighbouring chart it shares most edges with, where it can be
//!    projected along that chart's axis (within 75°). The build weighs these charts against
//!    the whole patch as one chart on its mean plane ([`super::planar_chart`]) and keeps the
//!    layout that costs fewer JPEG blocks a texel ([`Layout::blocks_per_texel`]).
//! 2. **Packing**: rectangles with a gutter of [`GUTTER`] texels on every side, tallest first
//!    on shelves; the texel size shrinks (coarser texels) until the atlas fits
//!    [`MAX_TEXELS`].
//! 3. **Baking**: every texel whose centre lies in a triangle samples the colour source at
//!    its barycentric coordinates (2×2 supersampled when resampling a finer surface, a box
//!    filter for the halved density, with one closest-point query a texel:
//!    [`Resampled::sample_box`]); every triangle owns at least the texel of its
//!    centroid; [`GUTTER`] dilation passes then fill the gutter from the chart itself, so
//!    bilinear filtering never mixes in another chart, and the rest is filled by push-pull,
//!    a smooth continuation of the charts (cheap for JPEG: no step along every chart).
//! 4. **Normal maps** (issue 11 item 4, the progressive-transmission paper; a build option):
//!    the same bake, in the same query, gives every coarse patch's texel the mean normal of
//!    the finer surface ([`FinerPatch`]: its normal map, or a leaf's vertex normals, never
//!    extrapolated, [`Resampled`]'s `reach`), not normalised ([`PatchTexture::normals`]).
//!
//! Texel size follows the patch's error (`build.rs`): a patch is drawn while its error
//! projects to at most a pixel, so texels of that size keep a texel per pixel or better
//! (normal maps: also a few texels a triangle edge, `BuildOptions::normal_map_density`).

use super::nearest::{Hit, Nearest};
use crate::mesh::{
    SourceTexture, Texture, TexturedFace, Wrap, encode_rgba, is_webp, srgb_to_linear,
};
use glam::{Vec2, Vec3};
use rustc_hash::FxHashMap as HashMap;

/// Texels of gutter around each chart.
pub const GUTTER: u32 = 2;
/// Chart rectangles are whole JPEG blocks (8×8 luminance texels), so no block holds two
/// charts' texels: a block that does costs as much as a detailed one, and most of a small
/// chart's blocks are on its edge.
pub(crate) const BLOCK: u32 = 8;
/// Most texels of one patch's atlas (2048²): bounds the build's memory per patch.
pub const MAX_TEXELS: u64 = 1 << 22;
/// Longest atlas side.
pub const MAX_SIDE: u32 = 4096;
/// A triangle joins a chart while its normal is within this cosine (60°) of the chart's mean.
/// Each chart costs a gutter and an edge in the JPEG: against 40°, 60° makes the generated
/// relief's atlases 24% smaller (29 charts a leaf instead of 68) for 0.05–0.2 dB on the Bali
/// mask's close-ups (`engine/tests/texture.rs`); 70° loses 5 dB there (texels stretched).
const CHART_COS: f32 = 0.5;
/// A triangle no longer than [`SMALL_EDGE`] texels joins a chart while its normal is within
/// this cosine (70°) of the chart's mean: its texels are at most that large, so the stretch
/// of a steeper projection costs no detail, and charts of a few texels (each with its own
/// gutter) do not multiply where texels are as large as triangles (coarse levels).
const SMALL_COS: f32 = 0.342;
/// Longest edge, in texels, of a triangle that joins charts by [`SMALL_COS`].
const SMALL_EDGE: f32 = 1.5;

/// A patch's atlas: its images, which share one layout, and every triangle corner's
/// coordinates in it.
pub struct PatchTexture {
    /// Colour, sRGB RGBA8 (textured scans; `None` where the atlas holds a normal map alone).
    pub image: Option<Texture>,
    /// The normal map (coarse patches, issue 11 item 4): the mean object-space normal of the
    /// finest surface over each texel, `(n + 1) / 2 × 255` in RGB, bytes without sRGB curve.
    /// The mean is not normalised: its length falls where the surface under the texel is
    /// rough, and diffuse light, linear in the normal, is then exactly the texel's mean light
    /// (a normalised mean shades rough surfaces as if they were smooth: too bright).
    pub normals: Option<Texture>,
    /// Per corner (three per triangle of the patch), in [0, 1], `v = 0` at the top row.
    pub uvs: Vec<[f32; 2]>,
    /// World units per texel.
    pub texel_size: f32,
    /// The texels [`bake`] sampled from the surface (inside a triangle, or a triangle's
    /// centroid texel), row by row; empty where not known (an atlas read back from scratch).
    pub covered: Vec<bool>,
}

impl PatchTexture {
    fn uv(&self, tri: usize, bary: [f32; 3]) -> [f32; 2] {
        interpolate2(&self.uvs[tri * 3..tri * 3 + 3], bary)
    }

    /// Linear RGBA at barycentric `bary` of triangle `tri` (white without colour).
    pub fn sample(&self, tri: usize, bary: [f32; 3]) -> [f32; 4] {
        let uv = self.uv(tri, bary);
        self.image.as_ref().map_or([1.0; 4], |i| {
            i.sample(uv[0], uv[1], Wrap::Clamp, Wrap::Clamp)
        })
    }

    /// The normal map's (mean) normal at barycentric `bary` of triangle `tri`, if it has one.
    pub fn normal(&self, tri: usize, bary: [f32; 3]) -> Option<Vec3> {
        let uv = self.uv(tri, bary);
        let t = self
            .normals
            .as_ref()?
            .sample_unorm(uv[0], uv[1], Wrap::Clamp, Wrap::Clamp);
        Some(decode_normal(t))
    }
}

/// A surface sample: linear RGBA in 0..4, then a normal in 4..7 (any length: a mean of unit
/// normals; zero where the source has none).
pub type Sample = [f32; 7];

/// A sample of colour `c` without normal.
pub fn color_sample(c: [f32; 4]) -> Sample {
    [c[0], c[1], c[2], c[3], 0.0, 0.0, 0.0]
}

/// A normal map texel's (mean) normal: bytes `(n + 1) / 2 × 255` read as `byte / 255`.
pub fn decode_normal(t: [f32; 4]) -> Vec3 {
    Vec3::new(t[0], t[1], t[2]).mul_add(Vec3::splat(2.0), Vec3::splat(-1.0))
}

/// A mean normal as normal map bytes (at most unit length; `+z` for a zero normal, where no
/// surface was found).
pub fn encode_normal(n: [f32; 3]) -> [u8; 4] {
    let v = Vec3::from(n);
    let v = if !v.is_finite() || v.length_squared() < 1e-12 {
        Vec3::Z
    } else {
        v.clamp_length_max(1.0)
    };
    let b = |c: f32| ((c * 0.5 + 0.5).clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [b(v.x), b(v.y), b(v.z), 255]
}

/// Where a baked texel's colour and normal come from.
pub trait SurfaceSource {
    /// The surface at barycentric `bary` of triangle `tri` of the patch baked.
    fn sample(&self, tri: usize, bary: [f32; 3]) -> Sample;

    /// Mean over the points `points` of triangle `tri`, all within a texel of `centre` (a
    /// texel's supersamples): by default, one [`SurfaceSource::sample`] each.
    fn sample_box(&self, tri: usize, _centre: [f32; 3], points: &[[f32; 3]]) -> Sample {
        mean(points.iter().map(|&b| self.sample(tri, b)))
    }
}

fn mean<const N: usize>(samples: impl Iterator<Item = [f32; N]>) -> [f32; N] {
    let (mut acc, mut n) = ([0f32; N], 0usize);
    for s in samples {
        for k in 0..N {
            acc[k] += s[k];
        }
        n += 1;
    }
    acc.map(|a| a / n.max(1) as f32)
}

/// Which images [`bake`] makes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Maps {
    pub color: bool,
    pub normals: bool,
}

/// Charts packed into an atlas: its size and every corner's position in texels.
#[derive(Debug, Clone)]
pub struct Layout {
    pub width: u32,
    pub height: u32,
    /// Per corner, in texels from the top-left corner of the atlas.
    pub corners: Vec<Vec2>,
    pub texel_size: f32,
    pub charts: usize,
}

/// Weight of an 8×8 block no triangle touches against one a triangle does, in
/// [`Layout::blocks_per_texel`]: push-pull fills it smoothly, and the JPEG codes it in a few bytes.
const EMPTY_BLOCK: f64 = 0.1;

impl Layout {
    /// An estimate of the atlas' JPEG bytes a texel of surface, in blocks: the 8×8 blocks
    /// under a triangle's bounding box, and `EMPTY_BLOCK` (0.1) of each other block, over the
    /// texels of the triangles' area. The build keeps the cheaper of two layouts by it
    /// ([`super::planar_chart::best_layout`]): texels alone would count the empty corners of
    /// one chart's rectangle as dearly as the edges of twenty small charts, and a layout that
    /// stretches texels over slopes holds fewer of them (less of the surface's detail) for its
    /// bytes.
    pub fn blocks_per_texel(&self) -> f64 {
        let b = BLOCK as f32;
        let (bw, bh) = (
            self.width.div_ceil(BLOCK) as usize,
            self.height.div_ceil(BLOCK) as usize,
        );
        let mut touched = vec![false; bw * bh];
        let mut texels = 0f64;
        for c in self.corners.chunks_exact(3) {
            let (c0, c1, c2) = (c[0], c[1], c[2]);
            texels += f64::from((c1 - c0).perp_dot(c2 - c0).abs() * 0.5);
            let lo = (c0.min(c1).min(c2) / b).floor().max(Vec2::ZERO);
            let hi = (c0.max(c1).max(c2) / b).ceil();
            for y in lo.y as usize..(hi.y as usize).min(bh) {
                for x in lo.x as usize..(hi.x as usize).min(bw) {
                    touched[y * bw + x] = true;
                }
            }
        }
        let hit = touched.iter().filter(|&&t| t).count() as f64;
        (hit + EMPTY_BLOCK * (touched.len() as f64 - hit)) / texels.max(1.0)
    }
}

/// Charts and packs the triangles `indices` over `positions` at `texel_size` world units per
/// texel (made coarser if the atlas would exceed [`MAX_TEXELS`] or [`MAX_SIDE`]).
pub fn layout(positions: &[[f32; 3]], indices: &[u32], texel_size: f32) -> Layout {
    let charts = make_charts(positions, indices, texel_size);
    let mut size = if texel_size.is_finite() && texel_size > 0.0 {
        texel_size
    } else {
        1.0
    };
    loop {
        let packed = pack(positions, indices, &charts, size);
        let texels = packed.width as u64 * packed.height as u64;
        if (texels <= MAX_TEXELS && packed.width.max(packed.height) <= MAX_SIDE) || size > 1e30 {
            return packed;
        }
        let over = (texels as f64 / MAX_TEXELS as f64)
            .max(packed.width.max(packed.height) as f64 / MAX_SIDE as f64)
            .max(1.01);
        size *= (over.sqrt() * 1.02) as f32;
    }
}

/// A chart: its triangles and the plane it is projected onto.
struct Chart {
    triangles: Vec<u32>,
    /// In-plane axes (unit, orthogonal).
    u: Vec3,
    v: Vec3,
    /// The direction it is projected along.
    axis: Vec3,
}

/// A chart of fewer texels than this is merged into a neighbour it can be projected with
/// (every triangle within [`MERGE_COS`] of the neighbour's axis): a chart of a few blocks is
/// mostly edge, and every edge block costs as much as a detailed one.
const SMALL_CHART_TEXELS: f32 = 256.0;
/// A small chart's triangles may face this far (75°) from the axis of the chart it joins:
/// their texels stretch up to 1/cos along the slope, on a few texels only.
const MERGE_COS: f32 = 0.26;

fn make_charts(positions: &[[f32; 3]], indices: &[u32], texel_size: f32) -> Vec<Chart> {
    let t = indices.len() / 3;
    let p = |i: u32| Vec3::from(positions[i as usize]);
    let mut normals = Vec::with_capacity(t);
    let mut areas = Vec::with_capacity(t);
    let mut small = Vec::with_capacity(t);
    let small_edge = SMALL_EDGE * texel_size;
    for tri in indices.chunks_exact(3) {
        let (a, b, c) = (p(tri[0]), p(tri[1]), p(tri[2]));
        let cross = (b - a).cross(c - a);
        areas.push(cross.length() * 0.5);
        normals.push(cross.normalize_or_zero());
        let longest = a.distance(b).max(b.distance(c)).max(c.distance(a));
        small.push(longest <= small_edge);
    }
    // Manifold edges (used by exactly two triangles) join those two.
    let mut edges: HashMap<(u32, u32), [u32; 3]> = HashMap::default();
    for (k, tri) in indices.chunks_exact(3).enumerate() {
        for e in 0..3 {
            let (a, b) = (tri[e], tri[(e + 1) % 3]);
            let slot = edges.entry((a.min(b), a.max(b))).or_insert([u32::MAX; 3]);
            match slot[2] {
                u32::MAX => *slot = [k as u32, u32::MAX, 1],
                1 => *slot = [slot[0], k as u32, 2],
                n => slot[2] = n + 1,
            }
        }
    }
    let mut neighbours: Vec<[u32; 3]> = vec![[u32::MAX; 3]; t];
    for (k, tri) in indices.chunks_exact(3).enumerate() {
        for e in 0..3 {
            let (a, b) = (tri[e], tri[(e + 1) % 3]);
            if let Some(&[first, second, 2]) = edges.get(&(a.min(b), a.max(b))) {
                neighbours[k][e] = if first == k as u32 { second } else { first };
            }
        }
    }
    let mut order: Vec<u32> = (0..t as u32).collect();
    order.sort_by(|&a, &b| areas[b as usize].total_cmp(&areas[a as usize]));
    let mut chart_of = vec![u32::MAX; t];
    let mut charts = Vec::new();
    let mut queue = std::collections::VecDeque::new();
    for &seed in &order {
        if chart_of[seed as usize] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let mut sum = normals[seed as usize] * areas[seed as usize].max(1e-30);
        let mut members = vec![seed];
        chart_of[seed as usize] = id;
        queue.clear();
        queue.push_back(seed);
        while let Some(f) = queue.pop_front() {
            for &nb in &neighbours[f as usize] {
                if nb == u32::MAX || chart_of[nb as usize] != u32::MAX {
                    continue;
                }
                let mean = sum.normalize_or_zero();
                let n = normals[nb as usize];
                // Degenerate triangles join anything next to them.
                let limit = if small[nb as usize] {
                    SMALL_COS
                } else {
                    CHART_COS
                };
                if n != Vec3::ZERO && n.dot(mean) < limit {
                    continue;
                }
                chart_of[nb as usize] = id;
                sum += n * areas[nb as usize];
                members.push(nb);
                queue.push_back(nb);
            }
        }
        let mut axis = sum.normalize_or_zero();
        if axis == Vec3::ZERO {
            axis = Vec3::Z;
        }
        // Triangles that drifted to face away from the final axis start charts of their own.
        let (kept, dropped): (Vec<u32>, Vec<u32>) = members
            .into_iter()
            .partition(|&f| f == seed || normals[f as usize].dot(axis) > 0.2);
        for f in dropped {
            chart_of[f as usize] = u32::MAX;
        }
        let (u, v) = plane_axes(axis, &kept, indices, positions);
        charts.push(Chart {
            triangles: kept,
            u,
            v,
            axis,
        });
    }
    // Triangles dropped from a chart after its growth: one chart each, or with neighbours.
    for f in 0..t as u32 {
        if chart_of[f as usize] == u32::MAX {
            let n = normals[f as usize];
            let axis = if n == Vec3::ZERO { Vec3::Z } else { n };
            chart_of[f as usize] = charts.len() as u32;
            let (u, v) = plane_axes(axis, &[f], indices, positions);
            charts.push(Chart {
                triangles: vec![f],
                u,
                v,
                axis,
            });
        }
    }
    merge_small_charts(
        charts,
        &mut chart_of,
        &neighbours,
        &normals,
        &areas,
        texel_size,
        indices,
        positions,
    )
}

/// Merges every chart smaller than [`SMALL_CHART_TEXELS`] into the neighbouring chart it
/// shares most edges with, where all its triangles face within [`MERGE_COS`] of that
/// chart's axis (smallest first; a merged chart keeps its axis, its in-plane axes follow
/// its new triangles).
#[allow(clippy::too_many_arguments)]
fn merge_small_charts(
    mut charts: Vec<Chart>,
    chart_of: &mut [u32],
    neighbours: &[[u32; 3]],
    normals: &[Vec3],
    areas: &[f32],
    texel_size: f32,
    indices: &[u32],
    positions: &[[f32; 3]],
) -> Vec<Chart> {
    let texel_area = texel_size * texel_size;
    if !texel_area.is_normal() {
        return charts;
    }
    let texels =
        |c: &Chart| c.triangles.iter().map(|&f| areas[f as usize]).sum::<f32>() / texel_area;
    let mut order: Vec<(f32, u32)> = charts
        .iter()
        .enumerate()
        .map(|(i, c)| (texels(c), i as u32))
        .filter(|&(n, _)| n < SMALL_CHART_TEXELS)
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut changed = vec![false; charts.len()];
    for (_, small) in order {
        let members = &charts[small as usize].triangles;
        if members.is_empty() || texels(&charts[small as usize]) >= SMALL_CHART_TEXELS {
            continue;
        }
        let mut shared: HashMap<u32, u32> = HashMap::default();
        for &f in members {
            for &nb in &neighbours[f as usize] {
                if nb != u32::MAX && chart_of[nb as usize] != small {
                    *shared.entry(chart_of[nb as usize]).or_default() += 1;
                }
            }
        }
        let mut candidates: Vec<(u32, u32)> = shared.into_iter().collect();
        candidates.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let Some(&(target, _)) = candidates.iter().find(|&&(c, _)| {
            let axis = charts[c as usize].axis;
            members.iter().all(|&f| {
                normals[f as usize] == Vec3::ZERO || normals[f as usize].dot(axis) >= MERGE_COS
            })
        }) else {
            continue;
        };
        let moved = std::mem::take(&mut charts[small as usize].triangles);
        for &f in &moved {
            chart_of[f as usize] = target;
        }
        charts[target as usize].triangles.extend(moved);
        changed[target as usize] = true;
    }
    for (c, changed) in charts.iter_mut().zip(changed) {
        if changed {
            (c.u, c.v) = plane_axes(c.axis, &c.triangles, indices, positions);
        }
    }
    charts.retain(|c| !c.triangles.is_empty());
    charts
}

/// In-plane axes for a chart projected along `axis`: the principal axes of its vertices.
pub(crate) fn plane_axes(
    axis: Vec3,
    tris: &[u32],
    indices: &[u32],
    positions: &[[f32; 3]],
) -> (Vec3, Vec3) {
    let (u0, v0) = axis.any_orthonormal_pair();
    let mut pts: Vec<Vec2> = Vec::with_capacity(tris.len() * 3);
    for &f in tris {
        for k in 0..3 {
            let q = Vec3::from(positions[indices[f as usize * 3 + k] as usize]);
            pts.push(Vec2::new(q.dot(u0), q.dot(v0)));
        }
    }
    let n = pts.len().max(1) as f32;
    let mean = pts.iter().copied().sum::<Vec2>() / n;
    let (mut cxx, mut cyy, mut cxy) = (0.0f32, 0.0f32, 0.0f32);
    for q in &pts {
        let d = *q - mean;
        cxx += d.x * d.x;
        cyy += d.y * d.y;
        cxy += d.x * d.y;
    }
    let angle = 0.5 * (2.0 * cxy).atan2(cxx - cyy);
    let (s, c) = angle.sin_cos();
    let u = (u0 * c + v0 * s).normalize_or_zero();
    let v = axis.cross(u).normalize_or_zero();
    if u == Vec3::ZERO || v == Vec3::ZERO {
        (u0, v0)
    } else {
        (u, v)
    }
}

fn pack(positions: &[[f32; 3]], indices: &[u32], charts: &[Chart], texel_size: f32) -> Layout {
    let scale = 1.0 / texel_size;
    let mut corners = vec![Vec2::ZERO; indices.len()];
    // Chart-local texel coordinates and rectangle sizes.
    let mut rects: Vec<(u32, u32, usize)> = Vec::with_capacity(charts.len());
    for (ci, chart) in charts.iter().enumerate() {
        let (mut lo, mut hi) = (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN));
        for &f in &chart.triangles {
            for k in 0..3 {
                let c = f as usize * 3 + k;
                let q = Vec3::from(positions[indices[c] as usize]);
                let uv = Vec2::new(q.dot(chart.u), q.dot(chart.v)) * scale;
                corners[c] = uv;
                lo = lo.min(uv);
                hi = hi.max(uv);
            }
        }
        let offset = Vec2::splat(GUTTER as f32 + 0.5) - lo;
        for &f in &chart.triangles {
            for k in 0..3 {
                corners[f as usize * 3 + k] += offset;
            }
        }
        let ext = (hi - lo).max(Vec2::ZERO);
        let w = (ext.x.ceil() as u32).saturating_add(2 * GUTTER + 1);
        let h = (ext.y.ceil() as u32).saturating_add(2 * GUTTER + 1);
        rects.push((w.next_multiple_of(BLOCK), h.next_multiple_of(BLOCK), ci));
    }
    let (width, height, origin) = shelf_pack(&mut rects);
    for (ci, chart) in charts.iter().enumerate() {
        let o = Vec2::new(origin[ci].0 as f32, origin[ci].1 as f32);
        for &f in &chart.triangles {
            for k in 0..3 {
                corners[f as usize * 3 + k] += o;
            }
        }
    }
    Layout {
        width,
        height,
        corners,
        texel_size,
        charts: charts.len(),
    }
}

/// Places rectangles `(width, height, id)` on shelves, tallest first, in an atlas about
/// square: its width and height (the extent the rectangles reach) and each id's top-left
/// corner. Rectangles whose sides are multiples of [`BLOCK`] keep every corner on the block
/// grid.
pub(crate) fn shelf_pack(rects: &mut [(u32, u32, usize)]) -> (u32, u32, Vec<(u32, u32)>) {
    rects.sort_by(|a, b| b.1.cmp(&a.1).then(b.0.cmp(&a.0)));
    let area: f64 = rects.iter().map(|r| r.0 as f64 * r.1 as f64).sum();
    let widest = rects.iter().map(|r| r.0).max().unwrap_or(1);
    let limit = ((area.sqrt() * 1.1).ceil() as u32).max(widest).max(1);
    let (mut x, mut y, mut shelf, mut width) = (0u32, 0u32, 0u32, 1u32);
    let ids = rects.iter().map(|r| r.2 + 1).max().unwrap_or(0);
    let mut origin = vec![(0u32, 0u32); ids];
    for &(w, h, id) in rects.iter() {
        if x.saturating_add(w) > limit {
            y = y.saturating_add(shelf);
            x = 0;
            shelf = 0;
        }
        origin[id] = (x, y);
        x = x.saturating_add(w);
        width = width.max(x);
        shelf = shelf.max(h);
    }
    (width, y.saturating_add(shelf).max(1), origin)
}

/// Bakes `source` into the images `maps` of the atlas `layout` (corner order as in the
/// layout). `supersample`: average 2×2 samples per texel.
pub fn bake(
    layout: &Layout,
    source: &dyn SurfaceSource,
    supersample: bool,
    maps: Maps,
) -> PatchTexture {
    let (w, h) = (layout.width as usize, layout.height as usize);
    // One plane a map: the colour plane alone (four floats a texel, not seven) is what every
    // whole-atlas pass below reads and writes unless normals are baked.
    let mut colour = vec![[0f32; 4]; if maps.color { w * h } else { 0 }];
    let mut normal = vec![[0f32; 3]; if maps.normals { w * h } else { 0 }];
    let mut filled = vec![false; w * h];
    let mut put = |i: usize, s: Sample| {
        if let Some(c) = colour.get_mut(i) {
            *c = [s[0], s[1], s[2], s[3]];
        }
        if let Some(n) = normal.get_mut(i) {
            *n = [s[4], s[5], s[6]];
        }
    };
    let offsets: &[Vec2; 4] = &[
        Vec2::new(-0.25, -0.25),
        Vec2::new(0.25, -0.25),
        Vec2::new(-0.25, 0.25),
        Vec2::new(0.25, 0.25),
    ];
    for (tri, c) in layout.corners.chunks_exact(3).enumerate() {
        let (c0, c1, c2) = (c[0], c[1], c[2]);
        let d = (c1.y - c2.y) * (c0.x - c2.x) + (c2.x - c1.x) * (c0.y - c2.y);
        let bary = |p: Vec2| -> [f32; 3] {
            if d.abs() < 1e-12 {
                return [1.0 / 3.0; 3];
            }
            let b0 = ((c1.y - c2.y) * (p.x - c2.x) + (c2.x - c1.x) * (p.y - c2.y)) / d;
            let b1 = ((c2.y - c0.y) * (p.x - c2.x) + (c0.x - c2.x) * (p.y - c2.y)) / d;
            [b0, b1, 1.0 - b0 - b1]
        };
        let value = |p: Vec2| {
            if !supersample {
                return source.sample(tri, bary(p));
            }
            let points = [0, 1, 2, 3].map(|k| bary(p + offsets[k]));
            source.sample_box(tri, bary(p), &points)
        };
        let lo = c0.min(c1).min(c2).floor().max(Vec2::ZERO);
        let hi = c0.max(c1).max(c2).ceil();
        let (x0, y0) = (lo.x as usize, lo.y as usize);
        let (x1, y1) = ((hi.x as usize).min(w), (hi.y as usize).min(h));
        for y in y0..y1 {
            for x in x0..x1 {
                if filled[y * w + x] || d.abs() < 1e-12 {
                    continue;
                }
                let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let b = bary(p);
                if b.iter().all(|&v| v >= -1e-5) {
                    put(y * w + x, value(p));
                    filled[y * w + x] = true;
                }
            }
        }
        // Every triangle owns at least the texel of its centroid.
        let centroid = (c0 + c1 + c2) / 3.0;
        let (x, y) = (
            (centroid.x.max(0.0) as usize).min(w - 1),
            (centroid.y.max(0.0) as usize).min(h - 1),
        );
        if !filled[y * w + x] {
            put(y * w + x, value(centroid));
            filled[y * w + x] = true;
        }
    }
    let image = |texels: Vec<[u8; 4]>| {
        Texture::from_texels(layout.width, layout.height, texels).unwrap_or_else(|| {
            Texture::from_texels(1, 1, vec![[255; 4]]).expect("a 1x1 image is valid")
        })
    };
    let gutters = dilation(&filled, w, h, GUTTER as usize);
    let (fw, fh) = (layout.width as f32, layout.height as f32);
    PatchTexture {
        image: maps.color.then(|| {
            fill(&mut colour, &filled, &gutters, w, h);
            image(colour.iter().map(|&t| encode_rgba(t)).collect())
        }),
        normals: maps.normals.then(|| {
            fill(&mut normal, &filled, &gutters, w, h);
            image(normal.iter().map(|&t| encode_normal(t)).collect())
        }),
        uvs: layout
            .corners
            .iter()
            .map(|c| [c.x / fw, c.y / fh])
            .collect(),
        texel_size: layout.texel_size,
        covered: filled,
    }
}

/// The texels each of `passes` dilation rounds fills, in order: round `k` takes the empty
/// texels with a filled 8-neighbour after rounds `0..k` (found on bit rows, 64 texels a word,
/// so the empty space of an atlas costs a few word operations a row).
fn dilation(filled: &[bool], w: usize, h: usize, passes: usize) -> Vec<Vec<usize>> {
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let words = w.div_ceil(64);
    // Bit `x % 64` of word `x / 64` of row `y` is texel `(x, y)`.
    let mut bits = vec![0u64; words * h];
    for y in 0..h {
        for x in 0..w {
            if filled[y * w + x] {
                bits[y * words + x / 64] |= 1 << (x % 64);
            }
        }
    }
    let mut rounds = Vec::with_capacity(passes);
    for _ in 0..passes {
        // Each row's filled texels spread one texel left and right (a word's end bits carry
        // into its neighbours in the row).
        let spreads: Vec<u64> = bits
            .chunks_exact(words)
            .flat_map(|row| {
                (0..words).map(move |k| {
                    let left = (row[k] << 1) | if k > 0 { row[k - 1] >> 63 } else { 0 };
                    let right = (row[k] >> 1) | row.get(k + 1).map_or(0, |&n| n << 63);
                    row[k] | left | right
                })
            })
            .collect();
        let mut round = Vec::new();
        for y in 0..h {
            for k in 0..words {
                let mut near = spreads[y * words + k];
                if y > 0 {
                    near |= spreads[(y - 1) * words + k];
                }
                if y + 1 < h {
                    near |= spreads[(y + 1) * words + k];
                }
                let mut new = near & !bits[y * words + k];
                if k + 1 == words && !w.is_multiple_of(64) {
                    new &= (1u64 << (w % 64)) - 1;
                }
                while new != 0 {
                    let b = new.trailing_zeros() as usize;
                    round.push(y * w + k * 64 + b);
                    new &= new - 1;
                }
            }
        }
        if round.is_empty() {
            break;
        }
        for &i in &round {
            bits[(i / w) * words + (i % w) / 64] |= 1 << (i % w % 64);
        }
        rounds.push(round);
    }
    rounds
}

/// Fills a plane's empty texels: the dilation rounds of [`dilation`] (each texel the mean of
/// its 8-neighbours filled before its round), then [`push_pull`] everywhere still empty.
fn fill<const N: usize>(
    texels: &mut [[f32; N]],
    filled: &[bool],
    rounds: &[Vec<usize>],
    w: usize,
    h: usize,
) {
    let mut done = filled.to_vec();
    for round in rounds {
        let means: Vec<[f32; N]> = round
            .iter()
            .map(|&i| {
                let (x, y) = ((i % w) as i64, (i / w) as i64);
                let mut acc = [0f32; N];
                let mut n = 0;
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                            continue;
                        }
                        let j = ny as usize * w + nx as usize;
                        if done[j] {
                            for k in 0..N {
                                acc[k] += texels[j][k];
                            }
                            n += 1;
                        }
                    }
                }
                acc.map(|a| a / n.max(1) as f32)
            })
            .collect();
        for (&i, m) in round.iter().zip(means) {
            texels[i] = m;
            done[i] = true;
        }
    }
    push_pull(texels, &done, w, h);
}

/// Fills the texels no chart and no gutter reaches by push-pull (Gortler et al., *The
/// Lumigraph*, 1996, §3.3): the filled texels are averaged down a pyramid of halved sizes, then
/// every empty texel takes the colour of the level above, so the empty space continues the
/// charts' colours. A flat fill met every chart's gutter in a step that each 8×8 JPEG block
/// along a chart paid for: push-pull makes the atlases 13% smaller on the Bali mask and 9% on
/// the generated relief, with the same close-ups.
fn push_pull<const N: usize>(texels: &mut [[f32; N]], filled: &[bool], w: usize, h: usize) {
    if filled.iter().all(|&f| f) {
        return;
    }
    if !filled.iter().any(|&f| f) {
        texels.fill([1.0; N]);
        return;
    }
    // Push: per level above the atlas, colour premultiplied by a weight capped at 1. The
    // atlas itself is level 0 as it is (its empty texels are zero, weight 0), not a copy.
    struct Level<const N: usize> {
        w: usize,
        h: usize,
        colour: Vec<[f32; N]>,
        weight: Vec<f32>,
    }
    let mut levels: Vec<Level<N>> = Vec::new();
    loop {
        let (bw, bh) = levels.last().map_or((w, h), |l| (l.w, l.h));
        if bw == 1 && bh == 1 {
            break;
        }
        let (nw, nh) = (bw.div_ceil(2), bh.div_ceil(2));
        let mut colour = vec![[0f32; N]; nw * nh];
        let mut weight = vec![0f32; nw * nh];
        for y in 0..bh {
            for x in 0..bw {
                let (i, j) = (y * bw + x, (y / 2) * nw + x / 2);
                let (b, bwt) = match levels.last() {
                    Some(below) => (below.colour[i], below.weight[i]),
                    None if filled[i] => (texels[i], 1.0),
                    None => ([0.0; N], 0.0),
                };
                for (c, b) in colour[j].iter_mut().zip(b) {
                    *c += b;
                }
                weight[j] += bwt;
            }
        }
        for (c, wt) in colour.iter_mut().zip(weight.iter_mut()) {
            if *wt > 0.0 {
                let capped = wt.min(1.0);
                let scale = capped / *wt;
                *c = c.map(|v| v * scale);
                *wt = capped;
            }
        }
        levels.push(Level {
            w: nw,
            h: nh,
            colour,
            weight,
        });
    }
    // Pull: from the top (one texel, filled: some texel was), every level's missing weight
    // is made up by the level above, now complete.
    for l in (0..levels.len().saturating_sub(1)).rev() {
        let (lower, upper) = levels.split_at_mut(l + 1);
        let (level, above) = (&mut lower[l], &upper[0]);
        for y in 0..level.h {
            for x in 0..level.w {
                let i = y * level.w + x;
                let missing = 1.0 - level.weight[i];
                if missing > 0.0 {
                    // The texel above, not an interpolation: at 2^k texels from the charts the
                    // fill is flat over whole aligned blocks, which JPEG codes as one DC value
                    // (a bilinear pull made the Bali mask's atlases 12% larger).
                    let p = above.colour[(y / 2) * above.w + x / 2];
                    for (c, a) in level.colour[i].iter_mut().zip(p) {
                        *c += missing * a;
                    }
                    level.weight[i] = 1.0;
                }
            }
        }
    }
    // Level 0: every empty texel (weight 0) takes the texel above whole.
    let above = &levels[0];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if !filled[i] {
                texels[i] = above.colour[(y / 2) * above.w + x / 2];
            }
        }
    }
}

fn interpolate2(c: &[[f32; 2]], b: [f32; 3]) -> [f32; 2] {
    [
        c[0][0] * b[0] + c[1][0] * b[1] + c[2][0] * b[2],
        c[0][1] * b[0] + c[1][1] * b[1] + c[2][1] * b[2],
    ]
}

/// World units per texel of a leaf that keeps its source texture's resolution: the square root
/// of its surface area over its area in source texels (`None` without textured triangles).
pub fn source_texel_size(
    positions: &[[f32; 3]],
    indices: &[u32],
    faces: &[TexturedFace],
    textures: &[SourceTexture],
) -> Option<f32> {
    let (mut world, mut texels) = (0f64, 0f64);
    for (tri, face) in indices.chunks_exact(3).zip(faces) {
        let Some(tex) = textures.get(face.texture as usize) else {
            continue;
        };
        let p = |k: usize| Vec3::from(positions[tri[k] as usize]);
        world += ((p(1) - p(0)).cross(p(2) - p(0)).length() * 0.5) as f64;
        let (tw, th) = (tex.image.width() as f64, tex.image.height() as f64);
        let q = |k: usize| (face.uv[k][0] as f64 * tw, face.uv[k][1] as f64 * th);
        let (a, b, c) = (q(0), q(1), q(2));
        let area = ((b.0 - a.0) * (c.1 - a.1) - (c.0 - a.0) * (b.1 - a.1)).abs() * 0.5;
        if area.is_finite() {
            texels += area;
        }
    }
    (world > 0.0 && texels > 0.0).then(|| (world / texels).sqrt() as f32)
}

/// Colour of a leaf: the scan's textures at the corners' source coordinates, or the vertex
/// colours for triangles without texture.
pub struct SourceColors<'a> {
    pub indices: &'a [u32],
    /// sRGB vertex colours (empty: white).
    pub colors: &'a [[u8; 4]],
    pub faces: &'a [TexturedFace],
    pub textures: &'a [SourceTexture],
}

impl SurfaceSource for SourceColors<'_> {
    fn sample(&self, tri: usize, bary: [f32; 3]) -> Sample {
        if let Some(face) = self.faces.get(tri)
            && let Some(tex) = self.textures.get(face.texture as usize)
        {
            return color_sample(tex.sample(interpolate2(&face.uv, bary)));
        }
        let mut acc = [0f32; 4];
        for (k, &weight) in bary.iter().enumerate() {
            let c = self
                .indices
                .get(tri * 3 + k)
                .and_then(|&v| self.colors.get(v as usize))
                .copied()
                .unwrap_or([255; 4]);
            let l = [
                srgb_to_linear(c[0]),
                srgb_to_linear(c[1]),
                srgb_to_linear(c[2]),
                c[3] as f32 / 255.0,
            ];
            for i in 0..4 {
                acc[i] += l[i] * weight;
            }
        }
        color_sample(acc)
    }
}

/// One of the finer patches a coarse patch is resampled from.
pub struct FinerPatch<'a> {
    pub positions: &'a [[f32; 3]],
    pub indices: &'a [u32],
    /// Its vertex normals: the normal where it has no normal map (leaves).
    pub normals: &'a [[f32; 3]],
    pub atlas: Option<&'a PatchTexture>,
}

impl FinerPatch<'_> {
    /// Colour (white without atlas colour) and normal at `bary` of triangle `t`.
    fn sample(&self, t: usize, bary: [f32; 3]) -> Sample {
        let c = self.atlas.map_or([1.0; 4], |a| a.sample(t, bary));
        let n = self
            .atlas
            .and_then(|a| a.normal(t, bary))
            .unwrap_or_else(|| {
                let v = |k: usize| {
                    self.indices
                        .get(t * 3 + k)
                        .and_then(|&i| self.normals.get(i as usize))
                        .map_or(Vec3::ZERO, |&n| Vec3::from(n).normalize_or_zero())
                };
                (v(0) * bary[0] + v(1) * bary[1] + v(2) * bary[2]).normalize_or_zero()
            });
        [c[0], c[1], c[2], c[3], n.x, n.y, n.z]
    }
}

/// The finer patches a group's products replace, with their atlases, indexed once for all
/// the products' closest-point queries.
pub struct FinerSurface<'a> {
    /// Per finer triangle (as indexed by `nearest`): its patch and its index there.
    owners: Vec<(u32, u32)>,
    finer: &'a [FinerPatch<'a>],
    nearest: Nearest,
}

impl<'a> FinerSurface<'a> {
    pub fn new(finer: &'a [FinerPatch<'a>]) -> FinerSurface<'a> {
        let mut tris = Vec::new();
        let mut owners = Vec::new();
        for (m, f) in finer.iter().enumerate() {
            for (t, tri) in f.indices.chunks_exact(3).enumerate() {
                tris.push([0, 1, 2].map(|k| Vec3::from(f.positions[tri[k] as usize])));
                owners.push((m as u32, t as u32));
            }
        }
        FinerSurface {
            owners,
            finer,
            nearest: Nearest::new(tris),
        }
    }
}

/// Colour of a coarse patch `(positions, indices)`: the finer surface it replaces, at the
/// closest point that faces the same way.
pub struct Resampled<'a> {
    pub positions: &'a [[f32; 3]],
    pub indices: &'a [u32],
    pub finer: &'a FinerSurface<'a>,
    /// The finer triangle of the previous sample: texels are baked in scan order, so it is
    /// usually the answer or close to it ([`Nearest::closest_near`]).
    pub last: std::cell::Cell<Option<u32>>,
    /// Whether normals are baked (a normal map): supersamples then never extrapolate a finer
    /// patch's vertex normals beyond its triangle ([`SurfaceSource::sample_box`]).
    pub normals: bool,
}

impl Resampled<'_> {
    /// The coarse triangle `tri`'s corners and unit normal.
    fn corners(&self, tri: usize) -> ([Vec3; 3], Vec3) {
        let p = |k: usize| Vec3::from(self.positions[self.indices[tri * 3 + k] as usize]);
        let c = [p(0), p(1), p(2)];
        (c, (c[1] - c[0]).cross(c[2] - c[0]).normalize_or_zero())
    }

    /// The closest finer point to `q` facing like `n` (any, where none faces that way).
    fn closest(&self, q: Vec3, n: Vec3) -> Option<Hit> {
        let nearest = &self.finer.nearest;
        let hit = nearest
            .closest_near(q, n, 0.0, self.last.get())
            .or_else(|| nearest.closest(q, Vec3::ZERO, 0.0))?;
        self.last.set(Some(hit.triangle));
        Some(hit)
    }

    fn finer_sample(&self, triangle: u32, bary: [f32; 3]) -> Sample {
        let (m, t) = self.finer.owners[triangle as usize];
        self.finer.finer[m as usize].sample(t as usize, bary)
    }

    /// How far outside finer triangle `triangle` a supersample may land and still be read
    /// from it: [`EXTRAPOLATE`] where its patch's maps continue beyond it (an atlas chart), 0
    /// where a baked normal would come from its vertex normals (a leaf's: extrapolated, they
    /// overshoot on a rough surface).
    fn reach(&self, triangle: u32) -> f32 {
        let (m, _) = self.finer.owners[triangle as usize];
        let mapped = self.finer.finer[m as usize]
            .atlas
            .is_some_and(|a| a.normals.is_some());
        if self.normals && !mapped {
            1e-4
        } else {
            EXTRAPOLATE
        }
    }
}

fn at(c: &[Vec3; 3], b: [f32; 3]) -> Vec3 {
    c[0] * b[0] + c[1] * b[1] + c[2] * b[2]
}

/// Barycentric coordinates of `p` projected onto the plane of triangle `t` (outside it where
/// `p` is); `None` for a degenerate triangle.
fn plane_bary(p: Vec3, t: &[Vec3; 3]) -> Option<[f32; 3]> {
    let (e0, e1, e2) = (t[1] - t[0], t[2] - t[0], p - t[0]);
    let (d00, d01, d11) = (e0.dot(e0), e0.dot(e1), e1.dot(e1));
    let (d20, d21) = (e2.dot(e0), e2.dot(e1));
    let denom = d00 * d11 - d01 * d01;
    if denom <= f32::EPSILON * d00 * d11 || denom <= 0.0 {
        return None;
    }
    let v = (d11 * d20 - d01 * d21) / denom;
    let w = (d00 * d21 - d01 * d20) / denom;
    Some([1.0 - v - w, v, w])
}

/// A supersample lands this far outside the finer triangle of the texel's centre (in
/// barycentric units) before it gets a closest-point query of its own.
const EXTRAPOLATE: f32 = 0.5;

/// What a texel the finer surface does not reach gets.
const NO_SAMPLE: Sample = [1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0];

impl SurfaceSource for Resampled<'_> {
    fn sample(&self, tri: usize, bary: [f32; 3]) -> Sample {
        let (c, n) = self.corners(tri);
        match self.closest(at(&c, bary), n) {
            Some(h) => self.finer_sample(h.triangle, h.bary),
            None => NO_SAMPLE,
        }
    }

    /// One closest-point query for the texel's centre; each supersample is that point moved
    /// by the supersample's offset on the coarse surface, in the plane of the finer triangle
    /// found. The finer atlas is an orthogonal projection of each chart, so the triangle's
    /// texture coordinates carry on across its neighbours in the chart, and into the chart's
    /// gutter beyond it. A supersample that would land far outside the triangle (a sliver,
    /// or a fold of the finer surface) gets its own query instead: a quarter of the queries
    /// of four independent samples, and the same colours where the finer surface is smooth.
    fn sample_box(&self, tri: usize, centre: [f32; 3], points: &[[f32; 3]]) -> Sample {
        let (c, n) = self.corners(tri);
        let q = at(&c, centre);
        let Some(hit) = self.closest(q, n) else {
            return NO_SAMPLE;
        };
        let Some(ft) = self.finer.nearest.triangle(hit.triangle) else {
            return self.finer_sample(hit.triangle, hit.bary);
        };
        let x = at(ft, hit.bary);
        let reach = self.reach(hit.triangle);
        mean(points.iter().map(|&b| {
            let p = at(&c, b);
            match plane_bary(x + (p - q), ft) {
                Some(fb) if fb.iter().all(|&v| v >= -reach) => self.finer_sample(hit.triangle, fb),
                _ => match self.closest(p, n) {
                    Some(h) => self.finer_sample(h.triangle, h.bary),
                    None => NO_SAMPLE,
                },
            }
        }))
    }
}

/// JPEG (baseline, 4:2:0, standard Huffman tables) of an atlas.
pub fn encode_jpeg(image: &Texture, quality: u8) -> Vec<u8> {
    jpeg(image, quality, jpeg_encoder::SamplingFactor::F_2_2)
}

/// JPEG of a normal map: as [`encode_jpeg`] but without chroma subsampling (4:4:4), as a
/// normal's components all carry detail (4:2:0 halves the resolution of two of the three).
pub fn encode_normal_jpeg(image: &Texture, quality: u8) -> Vec<u8> {
    jpeg(image, quality, jpeg_encoder::SamplingFactor::F_1_1)
}

/// The image format of the colour atlases (`BuildOptions::atlas_codec`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AtlasCodec {
    /// Baseline JPEG (4:2:0, standard tables), stored without its tables and headers.
    Jpeg,
    /// Lossy WebP (VP8, 4:2:0) at the error JPEG would have at the fragment's quality
    /// ([`super::webp_match`]), where that takes fewer bytes than JPEG; else JPEG. VP8 predicts
    /// each block from its decoded neighbours, so the smooth fill between an atlas' charts and
    /// the chart borders, which cost a JPEG block as much as detail does, cost it little.
    #[default]
    Webp,
}

impl AtlasCodec {
    pub fn as_str(self) -> &'static str {
        match self {
            AtlasCodec::Jpeg => "jpeg",
            AtlasCodec::Webp => "webp",
        }
    }
}

impl std::fmt::Display for AtlasCodec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for AtlasCodec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "jpeg" => Ok(AtlasCodec::Jpeg),
            "webp" => Ok(AtlasCodec::Webp),
            other => Err(format!("unknown atlas codec {other:?}: `webp` or `jpeg`")),
        }
    }
}

/// Bytes of an atlas image before its entropy-coded data: a JPEG's marker segments up to and
/// with its scan header, a WebP's RIFF container and `VP8 ` chunk headers (20 bytes).
pub fn header_len(image: &[u8]) -> usize {
    if is_webp(image) {
        WEBP_HEADER.min(image.len())
    } else {
        super::jpegtables::header_len(image)
    }
}

/// RIFF header (12 bytes) and the first chunk's header (8) of a WebP file.
const WEBP_HEADER: usize = 20;

/// libwebp's effort (`method`, 0–6) for the atlases: 2 takes about half the time of the
/// default 4 for 5–10% more bytes at equal error (`scripts/atlas-codecs.py` with each), and
/// the atlases' encoding is a share of a textured build's time, which issue 11 bounds.
pub const WEBP_METHOD: i32 = 2;

/// Lossy WebP (VP8, 4:2:0) of an atlas at `quality` (0–100, WebP's scale) and
/// [`WEBP_METHOD`]; empty where libwebp refuses it (a side over 16383 texels: atlases are at
/// most [`MAX_SIDE`]).
pub fn encode_webp(image: &Texture, quality: f32) -> Vec<u8> {
    let rgb = rgb_bytes(image);
    let Ok(mut config) = webp::WebPConfig::new() else {
        return Vec::new();
    };
    config.lossless = 0;
    config.quality = quality.clamp(0.0, 100.0);
    config.method = WEBP_METHOD;
    let encoder = webp::Encoder::from_rgb(&rgb, image.width(), image.height());
    match encoder.encode_advanced(&config) {
        Ok(bytes) => bytes.to_vec(),
        Err(_) => Vec::new(),
    }
}

/// The texels' RGB bytes, row by row (what both encoders take).
fn rgb_bytes(image: &Texture) -> Vec<u8> {
    image
        .texels()
        .iter()
        .flat_map(|t| [t[0], t[1], t[2]])
        .collect()
}

fn jpeg(image: &Texture, quality: u8, sampling: jpeg_encoder::SamplingFactor) -> Vec<u8> {
    let rgb = rgb_bytes(image);
    let mut out = Vec::new();
    let mut encoder = jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100));
    encoder.set_sampling_factor(sampling);
    // Optimised Huffman tables (jpeg-encoder 0.6) come back garbled through `image`'s decoder
    // (checked in the tests below): the standard tables cost a few per cent and decode.
    let (w, h) = (image.width(), image.height());
    match (u16::try_from(w), u16::try_from(h)) {
        (Ok(w), Ok(h)) => {
            if encoder
                .encode(&rgb, w, h, jpeg_encoder::ColorType::Rgb)
                .is_err()
            {
                out.clear();
            }
        }
        _ => out.clear(),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_rounds_match_a_texel_by_texel_scan() {
        // The rounds found on bit rows against the plain definition (every empty texel with
        // a filled 8-neighbour, from the texels filled before the round), on widths either
        // side of a word and masks from sparse to dense.
        let mut next = crate::testing::xorshift(0x9e37_79b9);
        for (w, h) in [
            (1, 1),
            (5, 3),
            (63, 9),
            (64, 4),
            (65, 7),
            (130, 11),
            (200, 2),
        ] {
            for density in [0u32, 2, 10, 40, 90, 100] {
                let filled: Vec<bool> = (0..w * h).map(|_| next() % 100 < density).collect();
                let rounds = dilation(&filled, w, h, GUTTER as usize);
                let mut done = filled.clone();
                let mut expected = Vec::new();
                for _ in 0..GUTTER {
                    let round: Vec<usize> = (0..w * h)
                        .filter(|&i| {
                            let (x, y) = ((i % w) as i64, (i / w) as i64);
                            !done[i]
                                && (-1..=1).any(|dy| {
                                    (-1..=1).any(|dx| {
                                        let (nx, ny) = (x + dx, y + dy);
                                        nx >= 0
                                            && ny >= 0
                                            && nx < w as i64
                                            && ny < h as i64
                                            && done[ny as usize * w + nx as usize]
                                    })
                                })
                        })
                        .collect();
                    if round.is_empty() {
                        break;
                    }
                    for &i in &round {
                        done[i] = true;
                    }
                    expected.push(round);
                }
                assert_eq!(rounds, expected, "{w}x{h}, {density}% filled");
                // Filling takes each round's texels from the texels before it: every
                // filled texel keeps its value, and a texel of the first round is the mean of
                // its filled neighbours.
                let mut texels: Vec<[f32; 1]> = (0..w * h)
                    .map(|i| [if filled[i] { (i % 7) as f32 } else { 0.0 }])
                    .collect();
                let before = texels.clone();
                fill(&mut texels, &filled, &rounds, w, h);
                for i in (0..w * h).filter(|&i| filled[i]) {
                    assert_eq!(texels[i], before[i]);
                }
                if let Some(&i) = rounds.first().and_then(|r| r.first()) {
                    let (x, y) = (i % w, i / w);
                    let near: Vec<f32> = (y.saturating_sub(1)..(y + 2).min(h))
                        .flat_map(|ny| {
                            (x.saturating_sub(1)..(x + 2).min(w)).map(move |nx| ny * w + nx)
                        })
                        .filter(|&j| filled[j])
                        .map(|j| before[j][0])
                        .collect();
                    let mean = near.iter().sum::<f32>() / near.len() as f32;
                    assert!((texels[i][0] - mean).abs() < 1e-5, "{w}x{h}: {i}");
                }
            }
        }
    }

    #[test]
    fn push_pull_continues_the_filled_texels_in_flat_blocks() {
        // A red block on the left and a blue one on the right of a 32×8 image, empty between.
        let (w, h) = (32, 8);
        let mut texels = vec![[0f32; 4]; w * h];
        let mut filled = vec![false; w * h];
        for y in 0..h {
            for x in (0..6).chain(26..32) {
                texels[y * w + x] = if x < 6 {
                    [1.0, 0.0, 0.0, 1.0]
                } else {
                    [0.0, 0.0, 1.0, 1.0]
                };
                filled[y * w + x] = true;
            }
        }
        let before = texels.clone();
        push_pull(&mut texels, &filled, w, h);
        for i in 0..w * h {
            if filled[i] {
                assert_eq!(texels[i], before[i], "a filled texel changed");
            }
        }
        // The gap continues its neighbours: within the filled colours, red beside the red
        // block and blue beside the blue one.
        for t in &texels {
            assert!(t.iter().all(|&c| (0.0..=1.0).contains(&c)), "{t:?}");
        }
        let row: Vec<[f32; 4]> = texels[3 * w..4 * w].to_vec();
        assert!(row[6][0] > row[6][2] && row[25][2] > row[25][0], "{row:?}");
        // Far from both, whole aligned 8×8 blocks are flat (one DC value for JPEG).
        let (mut tall, mut tall_filled) = (vec![[0f32; 4]; 64 * 64], vec![false; 64 * 64]);
        for (i, t) in tall.iter_mut().enumerate().take(64 * 4) {
            *t = [(i % 64) as f32 / 64.0, 0.5, 0.5, 1.0];
            tall_filled[i] = true;
        }
        push_pull(&mut tall, &tall_filled, 64, 64);
        for by in 4..8 {
            for bx in 0..8 {
                let first = tall[by * 8 * 64 + bx * 8];
                for y in by * 8..by * 8 + 8 {
                    for x in bx * 8..bx * 8 + 8 {
                        assert_eq!(tall[y * 64 + x], first, "block ({bx}, {by})");
                    }
                }
            }
        }
        // Nothing filled: white; everything filled: unchanged.
        let mut none = vec![[0.5f32; 4]; 4];
        push_pull(&mut none, &[false; 4], 2, 2);
        assert!(none.iter().all(|t| *t == [1.0; 4]));
        let mut all = vec![[0.25f32; 4]; 4];
        push_pull(&mut all, &[true; 4], 2, 2);
        assert!(all.iter().all(|t| *t == [0.25; 4]));
    }

    /// A bumpy grid patch: positions and indices.
    fn grid(n: usize) -> (Vec<[f32; 3]>, Vec<u32>) {
        super::super::height_grid(n, 1.0 / n as f32, |x, y| {
            0.3 * (x * 9.0).sin() * (y * 7.0).cos()
        })
    }

    /// Colour as a function of position, to compare bakes against.
    struct Field<'a>(&'a [[f32; 3]], &'a [u32]);
    impl SurfaceSource for Field<'_> {
        fn sample(&self, tri: usize, b: [f32; 3]) -> Sample {
            let q = (0..3)
                .map(|k| Vec3::from(self.0[self.1[tri * 3 + k] as usize]) * b[k])
                .sum::<Vec3>();
            // A normal that turns with position.
            let n = Vec3::new(q.x.sin(), q.y.cos(), 1.0).normalize();
            [
                q.x.fract().abs(),
                q.y.fract().abs(),
                (q.z + 0.5).clamp(0.0, 1.0),
                1.0,
                n.x,
                n.y,
                n.z,
            ]
        }
    }

    #[test]
    fn charts_cover_every_triangle_without_overlap_and_keep_orientation() {
        let (pos, idx) = grid(24);
        let l = layout(&pos, &idx, 0.004);
        assert!(
            l.charts > 1 && l.charts < idx.len() / 3,
            "{} charts",
            l.charts
        );
        // Rasterise every triangle's texel centres: no texel in two triangles.
        let mut owner = vec![u32::MAX; (l.width * l.height) as usize];
        for (t, c) in l.corners.chunks_exact(3).enumerate() {
            let area = (c[1] - c[0]).perp_dot(c[2] - c[0]);
            assert!(area >= 0.0, "triangle {t} flipped in the atlas");
            for y in 0..l.height {
                for x in 0..l.width {
                    let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    let e = |a: Vec2, b: Vec2| (b - a).perp_dot(p - a);
                    if e(c[0], c[1]) > 1e-3 && e(c[1], c[2]) > 1e-3 && e(c[2], c[0]) > 1e-3 {
                        let o = &mut owner[(y * l.width + x) as usize];
                        assert_eq!(*o, u32::MAX, "texel ({x}, {y}) in two triangles");
                        *o = t as u32;
                    }
                }
            }
            for q in c {
                assert!(q.x >= GUTTER as f32 && q.y >= GUTTER as f32);
                assert!(q.x <= (l.width - GUTTER) as f32 && q.y <= (l.height - GUTTER) as f32);
            }
        }
    }

    #[test]
    fn baked_atlas_reproduces_the_source_and_respects_the_budget() {
        let (pos, idx) = grid(16);
        let field = Field(&pos, &idx);
        let l = layout(&pos, &idx, 0.005);
        let both = Maps {
            color: true,
            normals: true,
        };
        let tex = bake(&l, &field, false, both);
        // Sampling the atlas at triangle interiors gives back the field (to 8-bit rounding and
        // bilinear interpolation of a smooth field), colour and normal.
        let (mut worst, mut worst_angle) = (0f32, 0f32);
        for t in 0..idx.len() / 3 {
            for b in [[0.6, 0.2, 0.2], [0.2, 0.6, 0.2], [1.0 / 3.0; 3]] {
                let (a, e) = (tex.sample(t, b), field.sample(t, b));
                for k in 0..3 {
                    worst = worst.max((a[k] - e[k]).abs());
                }
                let n = tex.normal(t, b).expect("a normal map").normalize();
                let m = Vec3::new(e[4], e[5], e[6]);
                worst_angle = worst_angle.max(n.dot(m).clamp(-1.0, 1.0).acos().to_degrees());
            }
        }
        assert!(worst < 0.06, "worst channel error {worst}");
        assert!(worst_angle < 1.5, "worst normal error {worst_angle}°");
        // A normal map alone.
        let alone = bake(
            &l,
            &field,
            false,
            Maps {
                color: false,
                normals: true,
            },
        );
        let texels = |t: &PatchTexture| t.normals.as_ref().map(|n| n.texels().to_vec());
        assert!(alone.image.is_none() && texels(&alone) == texels(&tex));
        // A tiny texel size is capped by the budget.
        let big = layout(&pos, &idx, 1e-6);
        assert!(big.width as u64 * big.height as u64 <= MAX_TEXELS);
        assert!(big.texel_size > 1e-6);
        let image = tex.image.as_ref().expect("colour");
        let jpeg = encode_jpeg(image, 85);
        let back = Texture::decode(&jpeg).expect("decodes");
        assert_eq!((back.width(), back.height()), (l.width, l.height));
        // The JPEG keeps the colours (mean channel error of a few levels).
        let err: f64 = back
            .texels()
            .iter()
            .zip(image.texels())
            .map(|(a, b)| {
                (0..3)
                    .map(|k| (a[k] as f64 - b[k] as f64).abs())
                    .sum::<f64>()
            })
            .sum::<f64>()
            / (3 * back.texels().len()) as f64;
        assert!(err < 4.0, "mean JPEG error {err:.2} levels");
    }
}
