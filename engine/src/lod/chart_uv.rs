//! Texture coordinates as one affine map per atlas chart (issue 11: textured patch bytes;
//! `docs/FORMAT.md`, "Patch blob", payload flag bit 4).
//!
//! Every chart of a patch's atlas ([`super::atlas`]) is an orthogonal projection of its
//! triangles onto a plane, turned and moved into the atlas: a vertex's texture coordinates are
//! an affine function of its position, `uv = A · p + t`, the same for every vertex of the chart.
//! Stored per vertex (u16 pairs through meshoptimizer's vertex codec) they were 38% of a
//! textured relief's file, twice its JPEG bytes. A blob can instead store each chart's `A` and
//! `t` (eight f32) and let the decoder compute every vertex's coordinates from its decoded grid
//! position; which vertices form a chart follows from the triangles alone ([`charts`]), since
//! a vertex where charts meet is stored once per chart.
//!
//! The map is applied to the *decoded* position, which for interior vertices of coarse patches
//! is quantised to `2^shift` grid units: the texture then stays where the surface was, in the
//! chart's plane, while the vertex moves by its quantisation (within the node's error), rather
//! than moving with the vertex.
//!
//! Evaluation is specified to the bit so that every decoder gets the same f32 coordinates: in
//! f64, `((a0·x + a1·y) + a2·z) + t` of the f32 coefficients and the integer grid coordinates
//! relative to the patch minimum, then rounded to f32 ([`evaluate`]; `static/js/lod/decode.js`
//! does the same in JavaScript's doubles).

use super::patch::find_root;
use glam::DVec3;

/// A chart's map: `[a0, a1, a2, t]` for `u`, then the same for `v`.
pub type ChartMap = [f32; 8];

/// Each vertex's chart and the number of charts: triangles that share a vertex are one chart;
/// charts are numbered by their first triangle in `indices`. A vertex no triangle uses gets
/// `u32::MAX`.
pub fn charts(indices: &[u32], vertex_count: usize) -> (Vec<u32>, usize) {
    let mut parent: Vec<u32> = (0..vertex_count as u32).collect();
    let valid = |v: u32| (v as usize) < vertex_count;
    for t in indices.chunks_exact(3) {
        if !t.iter().all(|&v| valid(v)) {
            continue;
        }
        for &v in &t[1..] {
            let (a, b) = (find_root(&mut parent, t[0]), find_root(&mut parent, v));
            // The larger root joins the smaller (any rule gives the same sets).
            parent[a.max(b) as usize] = a.min(b);
        }
    }
    let mut label = vec![u32::MAX; vertex_count];
    let mut count = 0usize;
    for t in indices.chunks_exact(3) {
        if !t.iter().all(|&v| valid(v)) {
            continue;
        }
        let r = find_root(&mut parent, t[0]) as usize;
        if label[r] == u32::MAX {
            label[r] = count as u32;
            count += 1;
        }
    }
    let chart = (0..vertex_count as u32)
        .map(|v| {
            let r = find_root(&mut parent, v) as usize;
            label[r]
        })
        .collect();
    (chart, count)
}

/// A vertex's coordinates by its chart's map, from its grid position relative to the patch
/// minimum (bit-exact in every decoder: see the module documentation).
pub fn evaluate(map: &ChartMap, p: [i64; 3]) -> [f32; 2] {
    let one = |m: &[f32]| {
        let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
        ((m[0] as f64 * x + m[1] as f64 * y) + m[2] as f64 * z + m[3] as f64) as f32
    };
    [one(&map[..4]), one(&map[4..])]
}

/// One map per chart that gives every vertex its coordinates, or `None` where some chart is
/// not such a projection (coordinates from elsewhere; the blob then stores them per vertex).
///
/// `exact`: the vertices' grid positions relative to the patch minimum; `decoded`: the same as
/// the decoder will see them (interior vertices quantised to `2^shift` units); `uvs`: their
/// coordinates. A map must reproduce the coordinates at the exact positions within what the
/// grid's rounding of the float positions explains (half a unit on each axis) and at the decoded
/// ones within what their quantisation does.
pub fn fit(
    indices: &[u32],
    exact: &[[i64; 3]],
    decoded: &[[i64; 3]],
    shift: u32,
    uvs: &[[f64; 2]],
) -> Option<Vec<ChartMap>> {
    let n = exact.len();
    if decoded.len() != n || uvs.len() != n {
        return None;
    }
    let (chart, count) = charts(indices, n);
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); count];
    for (v, &c) in chart.iter().enumerate() {
        if let Some(m) = members.get_mut(c as usize) {
            m.push(v as u32);
        }
    }
    let point = |v: u32| vector(exact[v as usize]);
    // Per chart, from its triangles:
    // - its area-weighted normal (the layout projects along its chart's mean normal);
    // - whether any triangle has area as decoded: charts of slivers the grid flattened draw
    //   nothing, any map will do, and none may fit their corners;
    // - how fast each coordinate changes along its edges at most: a projection's row norm
    //   where some edge lies along it, and what bounds the slack a fit is allowed (an
    //   ill-posed fit's large coefficients would otherwise excuse large errors).
    let mut normals = vec![DVec3::ZERO; count];
    let mut drawn = vec![false; count];
    let mut rates = vec![[0f64; 2]; count];
    for t in indices.chunks_exact(3) {
        // `charts` labels every triangle whose corners are all vertices.
        if !t.iter().all(|&v| (v as usize) < n) {
            continue;
        }
        let c = chart[t[0] as usize] as usize;
        let [p0, p1, p2] = [t[0], t[1], t[2]].map(point);
        normals[c] += (p1 - p0).cross(p2 - p0);
        let [d0, d1, d2] = [t[0], t[1], t[2]].map(|v| vector(decoded[v as usize]));
        drawn[c] |= (d1 - d0).cross(d2 - d0) != DVec3::ZERO;
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let length = (point(b) - point(a)).length();
            if length > 0.0 {
                for (r, (ua, ub)) in rates[c]
                    .iter_mut()
                    .zip(uvs[a as usize].iter().zip(&uvs[b as usize]))
                {
                    *r = r.max((ub - ua).abs() / length);
                }
            }
        }
    }
    let quantum = f64::from(1u32 << shift.min(30));
    members
        .iter()
        .zip(&normals)
        .zip(&drawn)
        .zip(&rates)
        .map(|(((vertices, &normal), &drawn), &rate)| {
            if !drawn {
                return finish(vertices, &point, uvs, [[0.0; 3]; 2]);
            }
            // The closer (at the exact positions) of the two fits that both stay within bounds.
            [
                projection(vertices, normal, &point, uvs),
                affine(vertices, &point, uvs),
            ]
            .into_iter()
            .flatten()
            .filter_map(|map| {
                let within = |error: [f64; 2], moved: f64| {
                    let slack = slack(&map, rate, moved);
                    error[0] <= slack[0] && error[1] <= slack[1]
                };
                let error = errors(&map, vertices, exact, uvs);
                (within(error, 0.0) && within(errors(&map, vertices, decoded, uvs), quantum))
                    .then_some((map, error[0].max(error[1])))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(map, _)| map)
        })
        .collect()
}

/// A grid position as a vector.
fn vector(p: [i64; 3]) -> DVec3 {
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// How far `map` may miss each coordinate: the grid's rounding (√3/2 units) plus `moved` units
/// of quantisation, half again for the fit, taken to coordinates by the map's row norms (at
/// most twice the chart's edge `rate`), and a u16 step.
fn slack(map: &ChartMap, rate: [f64; 2], moved: f64) -> [f64; 2] {
    let reach = (0.5 * 3f64.sqrt() * (1.0 + moved)) * 1.5;
    std::array::from_fn(|k| {
        let m = &map[4 * k..4 * k + 3];
        let a = DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64).length();
        a.min(2.0 * rate[k]) * reach + 2.0 / 65535.0
    })
}

/// The largest difference between `map` and each coordinate over the vertices at `at`.
fn errors(map: &ChartMap, vertices: &[u32], at: &[[i64; 3]], uvs: &[[f64; 2]]) -> [f64; 2] {
    vertices.iter().fold([0.0; 2], |worst, &v| {
        let got = evaluate(map, at[v as usize]);
        let want = uvs[v as usize];
        std::array::from_fn(|k| worst[k].max((got[k] as f64 - want[k]).abs()))
    })
}

/// The chart's least-squares map constrained to project along `normal` (`A · normal = 0`):
/// well posed for flat charts, where a free fit would give the direction across the plane
/// whatever the grid's rounding says.
fn projection(
    vertices: &[u32],
    normal: DVec3,
    point: &impl Fn(u32) -> DVec3,
    uvs: &[[f64; 2]],
) -> Option<ChartMap> {
    let n = normal.try_normalize()?;
    let b1 = n.any_orthonormal_vector();
    let b2 = n.cross(b1);
    let plane = |v: u32| {
        let p = point(v);
        [p.dot(b1), p.dot(b2)]
    };
    let coefficients = least_squares::<2>(vertices, &plane, uvs)?;
    let row = |k: usize| (b1 * coefficients[k][0] + b2 * coefficients[k][1]).to_array();
    finish(vertices, point, uvs, [row(0), row(1)])
}

/// The chart's least-squares affine map from its 3D positions (curved charts).
fn affine(vertices: &[u32], point: &impl Fn(u32) -> DVec3, uvs: &[[f64; 2]]) -> Option<ChartMap> {
    let space = |v: u32| point(v).to_array();
    let rows = least_squares::<3>(vertices, &space, uvs)?;
    finish(vertices, point, uvs, rows)
}

/// Rounds the linear part to f32 and sets each offset to the mean residual under the rounded
/// coefficients, evaluated as the decoder will.
fn finish(
    vertices: &[u32],
    point: &impl Fn(u32) -> DVec3,
    uvs: &[[f64; 2]],
    rows: [[f64; 3]; 2],
) -> Option<ChartMap> {
    let mut map = [0f32; 8];
    for (k, row) in rows.iter().enumerate() {
        let a = [row[0] as f32, row[1] as f32, row[2] as f32];
        let mut sum = 0.0;
        for &v in vertices {
            let p = point(v);
            let linear = (a[0] as f64 * p.x + a[1] as f64 * p.y) + a[2] as f64 * p.z;
            sum += uvs[v as usize][k] - linear;
        }
        let t = sum / vertices.len().max(1) as f64;
        map[4 * k..4 * k + 4].copy_from_slice(&[a[0], a[1], a[2], t as f32]);
    }
    map.iter().all(|c| c.is_finite()).then_some(map)
}

/// Least squares of `uv ≈ Σ c_i x_i + t` over the vertices, for both coordinates, with the
/// `D` coordinates `x` given by `coordinates`: `[c_1 … c_D]` per coordinate (the offsets are
/// [`finish`]'s). A tiny ridge keeps directions the vertices do not span at zero.
fn least_squares<const D: usize>(
    vertices: &[u32],
    coordinates: &impl Fn(u32) -> [f64; D],
    uvs: &[[f64; 2]],
) -> Option<[[f64; D]; 2]> {
    if vertices.is_empty() || D > 3 {
        return None;
    }
    let count = vertices.len() as f64;
    let mut mean = [0f64; D];
    let mut mean_uv = [0f64; 2];
    for &v in vertices {
        let x = coordinates(v);
        for i in 0..D {
            mean[i] += x[i] / count;
        }
        for k in 0..2 {
            mean_uv[k] += uvs[v as usize][k] / count;
        }
    }
    // The normal equations, padded to 3×3 with the identity.
    let mut m = [[0f64; 3]; 3];
    let mut b = [[0f64; 3]; 2];
    for &v in vertices {
        let x = coordinates(v);
        let d: [f64; D] = std::array::from_fn(|i| x[i] - mean[i]);
        for i in 0..D {
            for j in 0..D {
                m[i][j] += d[i] * d[j];
            }
            for k in 0..2 {
                b[k][i] += d[i] * (uvs[v as usize][k] - mean_uv[k]);
            }
        }
    }
    let trace: f64 = (0..D).map(|i| m[i][i]).sum();
    for (i, row) in m.iter_mut().enumerate() {
        row[i] += if i < D { 1e-9 * trace + 1e-12 } else { 1.0 };
    }
    let inverse = glam::DMat3::from_cols_array_2d(&m).inverse();
    if !inverse.is_finite() {
        return None;
    }
    let solve = |k: usize| {
        let c = (inverse * DVec3::from_array(b[k])).to_array();
        std::array::from_fn(|i| c[i])
    };
    Some([solve(0), solve(1)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charts_are_the_triangle_sets_that_share_vertices_numbered_by_first_triangle() {
        // Triangles 0 and 2 share vertex 1; triangle 1 stands alone; vertex 9 is unused.
        let indices = [4, 1, 2, 6, 7, 8, 1, 3, 5];
        let (chart, count) = charts(&indices, 10);
        assert_eq!(count, 2);
        assert_eq!(chart[4], 0);
        assert_eq!([chart[1], chart[2], chart[3], chart[5]], [0; 4]);
        assert_eq!([chart[6], chart[7], chart[8]], [1; 3]);
        assert_eq!(chart[9], u32::MAX);
        assert_eq!(chart[0], u32::MAX);
    }

    /// A curved sheet (a cylinder's quarter) projected along +z, in two charts, and a flat
    /// square in a third.
    #[test]
    fn fits_projections_of_curved_and_flat_charts_and_refuses_others() {
        let mut exact = Vec::new();
        let mut uvs = Vec::new();
        let mut indices = Vec::new();
        let mut grid = |offset: u32, f: &dyn Fn(i64, i64) -> ([i64; 3], [f64; 2])| {
            for y in 0..8i64 {
                for x in 0..8i64 {
                    let (p, uv) = f(x, y);
                    exact.push(p);
                    uvs.push(uv);
                }
            }
            for y in 0..7u32 {
                for x in 0..7u32 {
                    let v = offset + y * 8 + x;
                    indices.extend_from_slice(&[v, v + 1, v + 8, v + 1, v + 9, v + 8]);
                }
            }
        };
        // uv = (0.004·x + 0.001·y, 0.004·y − 0.001·x) + offset, along z; z curves with x.
        let curved = |x: i64, y: i64| {
            let p = [x * 40, y * 40, (x * x * 15) / 2];
            let (px, py) = (p[0] as f64, p[1] as f64);
            (
                p,
                [
                    0.004 * px + 0.001 * py + 0.05,
                    0.004 * py - 0.001 * px + 0.5,
                ],
            )
        };
        grid(0, &curved);
        // A flat chart tilted in space, projected along its own normal.
        let flat = |x: i64, y: i64| {
            let p = [1000 + x * 30, 2000 + y * 30, 500 + x * 30];
            (
                p,
                [
                    0.6 + x as f64 * 30.0 * 2f64.sqrt() * 0.002,
                    0.1 + y as f64 * 30.0 * 0.002,
                ],
            )
        };
        grid(64, &flat);
        let maps = fit(&indices, &exact, &exact, 0, &uvs).expect("both are projections");
        assert_eq!(maps.len(), 2);
        for (v, p) in exact.iter().enumerate() {
            let map = &maps[usize::from(v >= 64)];
            let got = evaluate(map, *p);
            for k in 0..2 {
                assert!(
                    (got[k] as f64 - uvs[v][k]).abs() < 1e-5,
                    "vertex {v}: {got:?}"
                );
            }
        }
        // Coordinates that are not an affine function of the position are refused.
        let mut bent = uvs.clone();
        bent[9][0] += 0.05;
        assert!(fit(&indices, &exact, &exact, 0, &bent).is_none());
        // Decoded positions moved by more than their quantisation explains are refused.
        let mut moved = exact.clone();
        moved[9][0] += 40;
        assert!(fit(&indices, &exact, &moved, 1, &uvs).is_none());
        assert!(fit(&indices, &exact, &moved, 6, &uvs).is_some());
        // A chart of triangles the grid flattened draws nothing: it gets a constant map.
        let sliver = [[0, 0, 0], [10, 10, 10], [20, 20, 20]];
        let corners = [[0.1, 0.2], [0.3, 0.1], [0.2, 0.6]];
        let maps = fit(&[0, 1, 2], &sliver, &sliver, 0, &corners).expect("a map");
        assert_eq!(evaluate(&maps[0], sliver[0]), evaluate(&maps[0], sliver[2]));
    }
}
