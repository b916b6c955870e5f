//! One planar chart for a whole patch (issue 11, item 2: charts of the patch's triangles,
//! packed per patch), the alternative the build weighs against charts made by region growing
//! ([`super::atlas::layout`]).
//!
//! Region growing starts a chart wherever the normal turns 60° from the chart's mean, so a
//! rough patch, where the normal turns everywhere, breaks into tens of small charts, and the
//! JPEG pays for every one of them: each has a gutter and a border of blocks that hold both
//! chart and fill, which cost as much as detailed ones. Most patches of a scan (a relief, a
//! façade, a face) are a height field over their mean plane, as a photographer's view of
//! them is: projected orthogonally onto that plane, the whole patch is one chart. A
//! triangle steep to the plane gets fewer texels than its area asks (its projection is
//! `cos θ` of it), as it does in the scan's own photographs; the plane's texels are made
//! smaller so that the patch keeps the texels it would have at `texel_size` everywhere (the
//! same count: the mean density is kept, its spread follows the slope).
//!
//! Triangles that face away from the plane (their projection folds over their neighbours')
//! or are squeezed to a sliver (`SQUEEZE`) take charts made afresh, each in its own
//! rectangle; so does any triangle whose projection still overlaps another's, a few rounds.
//! Overlaps are looked for where the winding number of the chart's border reaches two
//! (`overlap_rows`, the border's crossings of each texel row), and only there by
//! rasterising the triangles over the plane's texel centres. A patch where more than a
//! tenth of the triangles would be charted afresh gets no planar chart.
//!
//! Texture coordinates stay an affine function of position on every chart, so the patch
//! blob stores one map per chart, not coordinates per vertex ([`super::chart_uv`]).

use glam::{Vec2, Vec3};

use super::atlas::{self, BLOCK, GUTTER, Layout, MAX_SIDE, MAX_TEXELS, shelf_pack};
use super::patch::{edge_corners, edge_ends, find_root, next_corner};

/// A triangle whose projected area over its area is below the patch's mean over this much
/// (about 86° from the plane on a flat patch) is charted afresh.
const SQUEEZE: f32 = 16.0;

/// Rounds of overlap search before a patch is refused its planar chart.
const ROUNDS: usize = 4;

/// The cheaper atlas layout of a patch at `texel_size` world units per texel: charts made
/// afresh or the planar chart, by [`Layout::blocks_per_texel`] (an estimate of JPEG bytes a
/// texel of surface). A planar chart of at most `FEW` (40) pieces (its plane and the fresh
/// charts of a few folded triangles) is kept without charting afresh.
pub fn best_layout(positions: &[[f32; 3]], indices: &[u32], texel_size: f32) -> Layout {
    match layout(positions, indices, texel_size) {
        Some(planar) if planar.charts <= FEW => planar,
        planar => {
            let fresh = atlas::layout(positions, indices, texel_size);
            match planar {
                Some(p) if p.blocks_per_texel() <= fresh.blocks_per_texel() => p,
                _ => fresh,
            }
        }
    }
}

/// See [`best_layout`]: on the generated relief's 4M triangles, region growing was cheaper
/// than 15 of the 1,000 planar charts of at most 40 pieces (and than 66 of the 620 with
/// more), so charting afresh is not worth its time there.
const FEW: usize = 40;

/// The planar chart of the patch `(positions, indices)` at `texel_size` world units per
/// texel on average, or `None` (see the module docs).
pub fn layout(positions: &[[f32; 3]], indices: &[u32], texel_size: f32) -> Option<Layout> {
    let t = indices.len() / 3;
    if t == 0 || !texel_size.is_normal() || indices.iter().any(|&v| v as usize >= positions.len()) {
        return None;
    }
    let p = |v: u32| Vec3::from(positions[v as usize]);
    // Each triangle's cross product: twice its area along its normal.
    let crosses: Vec<Vec3> = indices
        .chunks_exact(3)
        .map(|tri| (p(tri[1]) - p(tri[0])).cross(p(tri[2]) - p(tri[0])))
        .collect();
    let axis = crosses
        .iter()
        .fold(Vec3::ZERO, |sum, &c| sum + c)
        .normalize_or_zero();
    if axis == Vec3::ZERO {
        return None;
    }
    let all: Vec<u32> = (0..t as u32).collect();
    let (u, v) = atlas::plane_axes(axis, &all, indices, positions);
    let plane = |i: u32| Vec2::new(p(i).dot(u), p(i).dot(v));
    let (mut plane_area, mut world_area) = (0f64, 0f64);
    let mut signed = Vec::with_capacity(t);
    for (tri, cross) in indices.chunks_exact(3).zip(&crosses) {
        let (a, b, c) = (plane(tri[0]), plane(tri[1]), plane(tri[2]));
        let area = 0.5 * (b - a).perp_dot(c - a);
        let world = 0.5 * cross.length();
        plane_area += f64::from(area);
        world_area += f64::from(world);
        signed.push((area, world));
    }
    if !(world_area > 0.0 && plane_area > 0.0) {
        return None;
    }
    let ratio = (plane_area / world_area) as f32;
    let mut bad: Vec<bool> = signed
        .iter()
        .map(|&(a, w)| a <= 0.0 || a < w * ratio / SQUEEZE)
        .collect();
    // Plane units to texels: as many texels as the surface has at `texel_size`.
    let scale = 1.0 / (texel_size * ratio.sqrt());
    // Every edge by its vertex pair (runs of equal keys share an edge): the same in every
    // round, for the pieces and for the border.
    let edges = edge_corners(indices, positions.len(), |_| true);
    for _ in 0..ROUNDS {
        let at = |i| plane(i) * scale;
        let layout = with_fresh(positions, indices, &edges, &bad, at, texel_size)?;
        let Some(rows) = overlap_rows(&layout, indices, &edges, &bad) else {
            return Some(layout);
        };
        let clashes = overlapping_triangles(&layout, &bad, &rows);
        if clashes.is_empty() {
            return Some(layout);
        }
        for c in clashes {
            bad[c] = true;
        }
    }
    None
}

/// The plane's layout with the `bad` triangles charted afresh (`None` where they are more
/// than a tenth of the patch, or the layout exceeds an atlas).
fn with_fresh(
    positions: &[[f32; 3]],
    indices: &[u32],
    edges: &[(u64, u32)],
    bad: &[bool],
    at: impl Fn(u32) -> Vec2,
    texel_size: f32,
) -> Option<Layout> {
    let t = bad.len();
    let refreshed = bad.iter().filter(|&&b| b).count();
    if refreshed * 10 > t {
        return None;
    }
    let fresh = (refreshed > 0).then(|| {
        let sub: Vec<u32> = indices
            .chunks_exact(3)
            .zip(bad)
            .filter(|(_, b)| **b)
            .flat_map(|(tri, _)| tri.iter().copied())
            .collect();
        atlas::layout(positions, &sub, texel_size)
    });
    let mut texel = Vec::with_capacity(indices.len());
    let mut next_fresh = 0;
    for (tri, &b) in indices.chunks_exact(3).zip(bad) {
        match &fresh {
            Some(f) if b => {
                texel.extend_from_slice(f.corners.get(3 * next_fresh..3 * next_fresh + 3)?);
                next_fresh += 1;
            }
            _ => {
                for &v in tri {
                    let q = at(v);
                    if !q.is_finite() || q.abs().max_element() > 1e7 {
                        return None;
                    }
                    texel.push(q);
                }
            }
        }
    }
    pack(indices, edges, bad, &texel, texel_size)
}

/// Packs the triangles at their corners' texel coordinates `texel`: each connected piece
/// (triangles joined across an edge whose corners have the same coordinates on both sides,
/// planar or `fresh` alike) gets its rectangle, a gutter wide and whole blocks large.
fn pack(
    indices: &[u32],
    edges: &[(u64, u32)],
    fresh: &[bool],
    texel: &[Vec2],
    texel_size: f32,
) -> Option<Layout> {
    let piece = pieces(indices, edges, fresh, texel);
    let count = piece.iter().map(|&p| p as usize + 1).max().unwrap_or(0);
    let mut bounds = vec![(Vec2::splat(f32::MAX), Vec2::splat(f32::MIN)); count];
    for (f, &p) in piece.iter().enumerate() {
        let b = &mut bounds[p as usize];
        for q in &texel[3 * f..3 * f + 3] {
            b.0 = b.0.min(*q);
            b.1 = b.1.max(*q);
        }
    }
    // Each piece's rectangle; `base` is the point at its top-left corner before packing:
    // the piece's least corner lands on a texel centre a gutter in, as in region growing's
    // charts (`atlas::layout`). (Packing the fresh pieces, a folded triangle or two each,
    // side by side in one rectangle instead of a block each made the generated relief's
    // coarse atlases 14% larger: their shared blocks hold every chart's edge.)
    let g = GUTTER as f32;
    let mut rects = Vec::with_capacity(count);
    let mut base = Vec::with_capacity(count);
    let mut area = 0u64;
    for (i, &(lo, hi)) in bounds.iter().enumerate() {
        let ext = (hi - lo).max(Vec2::ZERO);
        let (x0, y0) = (lo.x - g - 0.5, lo.y - g - 0.5);
        let w = (ext.x.ceil() + 2.0 * g + 1.0) as u32;
        let h = (ext.y.ceil() + 2.0 * g + 1.0) as u32;
        let (w, h) = (w.next_multiple_of(BLOCK), h.next_multiple_of(BLOCK));
        if w > MAX_SIDE || h > MAX_SIDE {
            return None;
        }
        area += u64::from(w) * u64::from(h);
        if area > MAX_TEXELS {
            return None;
        }
        base.push(Vec2::new(x0, y0));
        rects.push((w, h, i));
    }
    let (width, height, origin) = shelf_pack(&mut rects);
    if width > MAX_SIDE || height > MAX_SIDE || u64::from(width) * u64::from(height) > MAX_TEXELS {
        return None;
    }
    let mut corners = Vec::with_capacity(texel.len());
    for (f, &p) in piece.iter().enumerate() {
        let (o, b) = (origin[p as usize], base[p as usize]);
        let shift = Vec2::new(o.0 as f32, o.1 as f32) - b;
        corners.extend(texel[3 * f..3 * f + 3].iter().map(|&q| q + shift));
    }
    Some(Layout {
        width,
        height,
        corners,
        texel_size,
        charts: count,
    })
}

/// Each triangle's connected piece (see [`pack`]); `edges` are the triangles' edges by
/// [`edge_corners`].
fn pieces(indices: &[u32], edges: &[(u64, u32)], fresh: &[bool], texel: &[Vec2]) -> Vec<u32> {
    let t = fresh.len();
    let mut parent: Vec<u32> = (0..t as u32).collect();
    // The texel coordinate of vertex `v` in the triangle of corner `c`.
    let at = |c: usize, v: u32| -> Vec2 {
        let f = c / 3;
        let k = (0..3).find(|&k| indices[3 * f + k] == v).unwrap_or(0);
        texel[3 * f + k]
    };
    for run in edges.chunk_by(|a, b| a.0 == b.0) {
        let first = run[0].1 as usize;
        let (a, b) = edge_ends(run[0].0);
        for &(_, c) in &run[1..] {
            let c = c as usize;
            let same = fresh[first / 3] == fresh[c / 3]
                && at(first, a) == at(c, a)
                && at(first, b) == at(c, b);
            if same {
                let x = find_root(&mut parent, (first / 3) as u32);
                let y = find_root(&mut parent, (c / 3) as u32);
                parent[x.max(y) as usize] = x.min(y);
            }
        }
    }
    let mut id = vec![u32::MAX; t];
    let mut next = 0u32;
    (0..t as u32)
        .map(|f| {
            let root = find_root(&mut parent, f) as usize;
            if id[root] == u32::MAX {
                id[root] = next;
                next += 1;
            }
            id[root]
        })
        .collect()
}

/// Where a texel centre may lie strictly inside two of the triangles of `layout` kept (not
/// in `skip`): for each texel row, the span of x it may be in (empty: `(∞, −∞)`), or `None`
/// where no texel centre is, so [`overlapping_triangles`] (a texel rasterisation of the
/// triangles) runs only where a patch folds, and there only over these spans.
///
/// The kept triangles all turn the same way (positive area in the plane), so the number of
/// them holding a point off their edges is the winding number of their border around it:
/// edges used twice, once each way, cancel (Hormann and Agathos, "The point in polygon
/// problem for arbitrary polygons", 2001). With crossings counted half-open (an edge from
/// `lo.y` inclusive to `hi.y` exclusive; a point right of a crossing, not on it), the count
/// at a point is at least the number of triangles holding it strictly. So each row's
/// crossings of the border edges alone (a few hundred edges a patch, against thousands of
/// triangles to rasterise) find every texel centre with a winding of two or more. An edge
/// used twice the same way or by three triangles (a fold the border does not show) gives
/// every row its whole width.
fn overlap_rows(
    layout: &Layout,
    indices: &[u32],
    edges: &[(u64, u32)],
    skip: &[bool],
) -> Option<Vec<(f32, f32)>> {
    const EMPTY: (f32, f32) = (f32::INFINITY, f32::NEG_INFINITY);
    let h = layout.height as usize;
    let everywhere = || Some(vec![(f32::NEG_INFINITY, f32::INFINITY); h]);
    // (row, x, ±1) where a border edge crosses the row's centre line.
    let mut crossings: Vec<(u32, f32, i32)> = Vec::new();
    for run in edges.chunk_by(|a, b| a.0 == b.0) {
        // The corners on this edge of the triangles kept.
        let mut kept = run
            .iter()
            .map(|&(_, c)| c as usize)
            .filter(|&c| !skip.get(c / 3).copied().unwrap_or(false));
        match (kept.next(), kept.next(), kept.next()) {
            (None, ..) => {}
            (Some(c), None, _) => {
                let (p, q) = (layout.corners[c], layout.corners[next_corner(c)]);
                // Endpoints in y order, so an edge's crossings do not depend on its direction.
                let (lo, hi, sign) = if p.y <= q.y { (p, q, 1) } else { (q, p, -1) };
                // Rows whose centre y + 0.5 has lo.y <= y + 0.5 < hi.y, within the layout.
                let mut y = (lo.y - 0.5).ceil().max(0.0);
                while y + 0.5 < hi.y && (y as usize) < h {
                    let py = y + 0.5;
                    let x = lo.x + (py - lo.y) * (hi.x - lo.x) / (hi.y - lo.y);
                    if !x.is_finite() {
                        return everywhere();
                    }
                    crossings.push((y as u32, x, sign));
                    y += 1.0;
                }
            }
            // Two triangles on one edge must run it opposite ways.
            (Some(a), Some(b), None) if indices[a] == indices[next_corner(b)] => {}
            _ => return everywhere(),
        }
    }
    crossings.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let mut rows = vec![EMPTY; h];
    let mut any = false;
    for row in crossings.chunk_by(|a, b| a.0 == b.0) {
        let mut winding = 0;
        for (i, &(y, x, sign)) in row.iter().enumerate() {
            winding += sign;
            // The winding holds right of x up to the next crossing: is a texel centre
            // k + 0.5 there (x < k + 0.5 <= end)?
            let end = row.get(i + 1).map_or(f32::INFINITY, |c| c.1);
            if winding.abs() >= 2 && (x - 0.5).floor() + 1.0 <= end - 0.5 {
                let span = &mut rows[y as usize];
                *span = (span.0.min(x), span.1.max(end));
                any = true;
            }
        }
    }
    any.then_some(rows)
}

/// The triangles of `layout` (but those to `skip`: charted afresh, each chart in its own
/// rectangle) that share a texel centre strictly inside both (a projection folded over
/// itself where no single triangle shows it), looked for in the spans `rows` of
/// [`overlap_rows`].
fn overlapping_triangles(layout: &Layout, skip: &[bool], rows: &[(f32, f32)]) -> Vec<usize> {
    let (w, h) = (layout.width as usize, layout.height as usize);
    let mut claimed = vec![u32::MAX; w * h];
    let mut clashes = Vec::new();
    for (f, c) in layout.corners.chunks_exact(3).enumerate() {
        if skip.get(f).copied().unwrap_or(false) {
            continue;
        }
        // Only the rows and spans where a texel centre may be held twice.
        let (lo, hi) = (
            c[0].y.min(c[1].y).min(c[2].y),
            c[0].y.max(c[1].y).max(c[2].y),
        );
        let first = (lo.max(0.0) as usize).min(h);
        let last = (hi.max(0.0).ceil() as usize).min(h);
        if rows[first..last].iter().all(|r| r.0 > r.1) {
            continue;
        }
        inside_spans(c, w, h, 1e-4, |y, x0, x1| {
            let (from, to) = rows[y];
            // Centres x + 0.5 within [from, to].
            let x0 = x0.max((from - 0.5).ceil().max(0.0) as usize);
            let x1 = x1.min(((to - 0.5).floor() + 1.0).clamp(0.0, w as f32) as usize);
            for x in x0..x1 {
                let i = y * w + x;
                if claimed[i] != u32::MAX {
                    clashes.push(claimed[i] as usize);
                    clashes.push(f);
                }
                claimed[i] = f as u32;
            }
        });
    }
    clashes.sort_unstable();
    clashes.dedup();
    clashes
}

/// Calls `row(y, x0, x1)` for every texel row of a `w × h` grid whose texel centres
/// `x0..x1` lie inside the triangle `c`, at least `margin` (in barycentric units) from each
/// edge: one span a row, from the edges' crossings of the row, instead of a test a texel.
fn inside_spans(
    c: &[Vec2],
    w: usize,
    h: usize,
    margin: f32,
    mut row: impl FnMut(usize, usize, usize),
) {
    let (c0, c1, c2) = (c[0], c[1], c[2]);
    let d = (c1 - c0).perp_dot(c2 - c0);
    if d.abs() < 1e-12 {
        return;
    }
    // Barycentric coordinate k at (x, y) is a_k·x + b_k·y + e_k.
    let edge = |p: Vec2, q: Vec2| {
        let (a, b) = ((p.y - q.y) / d, (q.x - p.x) / d);
        (a, b, -(a * p.x + b * p.y))
    };
    let lines = [edge(c1, c2), edge(c2, c0), edge(c0, c1)];
    let lo = c0.min(c1).min(c2).floor().max(Vec2::ZERO);
    let hi = c0.max(c1).max(c2).ceil();
    for y in lo.y as usize..(hi.y as usize).min(h) {
        let py = y as f32 + 0.5;
        let (mut xmin, mut xmax) = (lo.x, hi.x.min(w as f32));
        for &(a, b, e) in &lines {
            // a·x + (b·py + e) > margin
            let rest = b * py + e - margin;
            if a.abs() < 1e-20 {
                if rest <= 0.0 {
                    xmax = xmin;
                }
            } else if a > 0.0 {
                xmin = xmin.max(-rest / a);
            } else {
                xmax = xmax.min(-rest / a);
            }
        }
        // Texel centres x + 0.5 strictly between xmin and xmax.
        let x0 = (xmin - 0.5).floor() + 1.0;
        let x1 = (xmax - 0.5).ceil();
        if x1 > x0 {
            row(y, x0.max(0.0) as usize, (x1 as usize).min(w));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::height_grid;

    /// Every clash of `l`, searched over its whole width and height.
    fn clashes(l: &Layout) -> Vec<usize> {
        let everywhere = vec![(f32::NEG_INFINITY, f32::INFINITY); l.height as usize];
        overlapping_triangles(l, &[], &everywhere)
    }

    #[test]
    fn overlap_rows_find_every_clash_of_a_folded_layout() {
        // A grid of texel coordinates whose corners are shaken from none to far past their
        // neighbours (so the grid folds over itself more and more), against the search over
        // every texel: the spans hold every clash, and say none where there is none.
        let mut rng = crate::testing::xorshift(0x1234_5678);
        let mut unit = || (rng() % 10_000) as f32 / 10_000.0 - 0.5;
        let (k, step) = (9usize, 6.0f32);
        let mut indices = Vec::new();
        for y in 0..k {
            for x in 0..k {
                let v = (y * (k + 1) + x) as u32;
                let row = (k + 1) as u32;
                indices.extend_from_slice(&[v, v + 1, v + row + 1, v, v + row + 1, v + row]);
            }
        }
        let (mut folded, mut clean) = (0, 0);
        for shake in [0.0f32, 0.5, 1.0, 2.0, 4.0, 8.0] {
            for _ in 0..40 {
                let texel: Vec<Vec2> = (0..(k + 1) * (k + 1))
                    .map(|v| {
                        let (x, y) = ((v % (k + 1)) as f32, (v / (k + 1)) as f32);
                        Vec2::new(x * step + 10.0, y * step + 10.0)
                            + Vec2::new(unit(), unit()) * shake
                    })
                    .collect();
                let corners: Vec<Vec2> = indices.iter().map(|&v| texel[v as usize]).collect();
                // Triangles turned over are left out, as the planar chart charts them afresh.
                let skip: Vec<bool> = corners
                    .chunks_exact(3)
                    .map(|c| (c[1] - c[0]).perp_dot(c[2] - c[0]) <= 0.0)
                    .collect();
                let l = Layout {
                    width: 80,
                    height: 80,
                    corners,
                    texel_size: 1.0,
                    charts: 1,
                };
                let everywhere = vec![(f32::NEG_INFINITY, f32::INFINITY); 80];
                let all = overlapping_triangles(&l, &skip, &everywhere);
                let edges = edge_corners(&indices, texel.len(), |_| true);
                match overlap_rows(&l, &indices, &edges, &skip) {
                    None => {
                        assert!(all.is_empty(), "shake {shake}: clashes {all:?} unflagged");
                        clean += 1;
                    }
                    Some(rows) => {
                        assert_eq!(
                            overlapping_triangles(&l, &skip, &rows),
                            all,
                            "shake {shake}"
                        );
                        folded += usize::from(!all.is_empty());
                    }
                }
            }
        }
        assert!(folded > 20 && clean > 20, "{folded} folded, {clean} clean");
    }

    fn texels(l: &Layout) -> f32 {
        l.corners
            .chunks_exact(3)
            .map(|c| 0.5 * (c[1] - c[0]).perp_dot(c[2] - c[0]).abs())
            .sum()
    }

    fn world(positions: &[[f32; 3]], indices: &[u32]) -> f32 {
        let p = |v: u32| Vec3::from(positions[v as usize]);
        indices
            .chunks_exact(3)
            .map(|t| 0.5 * (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0])).length())
            .sum()
    }

    #[test]
    fn a_rough_height_field_is_one_chart_with_its_texels_kept() {
        // Normals that turn well past 60° from cell to cell: region growing breaks it up.
        let (positions, indices) =
            height_grid(24, 1.0, |x, y| 1.6 * ((1.7 * x).sin() + (1.3 * y).cos()));
        let fresh = atlas::layout(&positions, &indices, 0.25);
        let planar = layout(&positions, &indices, 0.25).expect("a height field has one");
        assert_eq!(planar.charts, 1, "every triangle faces the plane");
        assert!(
            fresh.charts > 4,
            "region growing made {} charts",
            fresh.charts
        );
        // As many texels of surface as at 0.25 everywhere.
        let expected = world(&positions, &indices) / (0.25 * 0.25);
        assert!(
            (texels(&planar) / expected - 1.0).abs() < 1e-3,
            "{} vs {expected}",
            texels(&planar)
        );
        assert!(planar.blocks_per_texel() < fresh.blocks_per_texel());
        // Every corner inside the atlas, a gutter from its edge.
        for c in &planar.corners {
            assert!(c.x >= GUTTER as f32 && c.y >= GUTTER as f32);
            assert!(
                c.x <= (planar.width - GUTTER) as f32 && c.y <= (planar.height - GUTTER) as f32
            );
        }
        assert!(clashes(&planar).is_empty());
        let best = best_layout(&positions, &indices, 0.25);
        assert_eq!(best.charts, 1);
    }

    #[test]
    fn an_overhang_is_charted_afresh_and_never_overlaps() {
        // A flat grid with one cell's far corner pulled back over its neighbours: the
        // triangles there face away from the plane.
        let (mut positions, indices) = height_grid(12, 1.0, |_, _| 0.0);
        positions[6 * 13 + 6] = [4.5, 6.0, 0.8];
        let l = layout(&positions, &indices, 0.1).expect("a few folded triangles");
        assert!(l.charts > 1);
        assert!(clashes(&l).is_empty());
    }

    #[test]
    fn spans_hold_the_texel_centres_inside_a_triangle() {
        // Triangles of every orientation and size, against a test of each texel centre.
        let mut rng = crate::testing::xorshift(0x2545_f491);
        let mut next = || (rng() % 4000) as f32 / 100.0;
        for _ in 0..300 {
            let c = [
                Vec2::new(next(), next()),
                Vec2::new(next(), next()),
                Vec2::new(next(), next()),
            ];
            let (w, h) = (41, 37);
            let mut spans = vec![false; w * h];
            inside_spans(&c, w, h, 1e-4, |y, x0, x1| {
                for x in x0..x1 {
                    assert!(!spans[y * w + x], "a texel twice");
                    spans[y * w + x] = true;
                }
            });
            let d = (c[1] - c[0]).perp_dot(c[2] - c[0]);
            for y in 0..h {
                for x in 0..w {
                    let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    let b1 = (p - c[0]).perp_dot(c[2] - c[0]) / d;
                    let b2 = (c[1] - c[0]).perp_dot(p - c[0]) / d;
                    let b0 = 1.0 - b1 - b2;
                    let inside = d.abs() >= 1e-12 && b0 > 1e-4 && b1 > 1e-4 && b2 > 1e-4;
                    let near = [b0, b1, b2].iter().any(|b| (b - 1e-4).abs() < 1e-5);
                    assert!(
                        near || spans[y * w + x] == inside,
                        "texel ({x}, {y}) of {c:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_ledge_over_a_ledge_never_overlaps() {
        // Two flat grids facing up, one above the other and shifted half across: no triangle
        // folds, yet their projections overlap.
        let (mut positions, mut indices) = height_grid(8, 1.0, |_, _| 0.0);
        let (upper, upper_indices) = height_grid(8, 1.0, |_, _| 3.0);
        let n = positions.len() as u32;
        positions.extend(upper.iter().map(|p| [p[0] + 4.0, p[1], p[2]]));
        indices.extend(upper_indices.iter().map(|&i| i + n));
        if let Some(l) = layout(&positions, &indices, 0.1) {
            assert!(clashes(&l).is_empty());
        }
        assert!(clashes(&best_layout(&positions, &indices, 0.1)).is_empty());
    }

    #[test]
    fn a_closed_surface_gets_no_planar_chart() {
        // A box: half its triangles face away from any plane.
        let positions: Vec<[f32; 3]> = (0..8)
            .map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
            .collect();
        let indices = vec![
            0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4, 2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4,
            6, 1, 3, 5, 3, 7, 5,
        ];
        assert!(layout(&positions, &indices, 0.1).is_none());
        // The build then keeps region growing's charts.
        assert_eq!(
            best_layout(&positions, &indices, 0.1).charts,
            atlas::layout(&positions, &indices, 0.1).charts
        );
        assert!(layout(&positions, &[], 0.1).is_none());
        assert!(layout(&positions, &indices[..3], f32::NAN).is_none());
    }
}
