//! Fine surface segments of one bucket of the build by region growing (mesh-segmentation
//! paper, §3.1, eq. 1): starting from a seed, linked elements whose normal lies within
//! `δ_Seg` of the seed's join its segment, `max_i ang(T_j, T_i) ≤ δ_Seg`.
//!
//! The elements are the bucket's vertices (each pixel of the id buffer names one, so a
//! segment per vertex is what selection needs) linked by the mesh's edges, with the
//! scan's per-vertex normals. A segment is also capped in size, so that the finest scale is
//! a set of small, compact superpixels of the surface (Lazy Snapping's pre-segmentation)
//! and [`super::merge`] builds every coarser scale from them.
//!
//! Besides the segments, a bucket reports the boundaries between them (length and
//! convexity, for the merge's cost) and the vertices on its own border, where a segment of
//! the neighbouring bucket continues (they are joined across the bucket border by
//! [`super::merge`]).

use std::collections::VecDeque;

use rustc_hash::FxHashMap;

use crate::lod::patch::{BuildPatch, EdgeUses, edge_ends, edge_runs};

/// Settings of the region growing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GrowParams {
    /// `δ_Seg`: the largest angle between a member's normal and its seed's, degrees.
    pub angle_deg: f32,
    /// The most vertices a fine segment holds.
    pub max_vertices: usize,
}

impl Default for GrowParams {
    fn default() -> Self {
        GrowParams {
            angle_deg: 30.0,
            max_vertices: 8,
        }
    }
}

/// What a segment is made of: sums, so segments add up when they merge.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SegmentSums {
    /// Vertices.
    pub vertices: u64,
    /// Sum of the members' unit normals.
    pub normal: [f64; 3],
}

impl SegmentSums {
    /// Adds `other`'s members.
    pub fn add(&mut self, other: &SegmentSums) {
        self.vertices += other.vertices;
        for (sum, x) in self.normal.iter_mut().zip(other.normal) {
            *sum += x;
        }
    }

    /// The mean unit normal (zero when the normals cancel).
    pub fn mean_normal(&self) -> [f64; 3] {
        let n = self.normal;
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if l > 1e-12 {
            [n[0] / l, n[1] / l, n[2] / l]
        } else {
            [0.0; 3]
        }
    }
}

/// The shared boundary of two segments: the mesh edges between them.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Boundary {
    /// Total length of the edges.
    pub length: f64,
    /// `Σ len · max(0, −s)` with `s = (n_b − n_a)·(p_b − p_a)/|p_b − p_a|` per edge: how much
    /// the surface folds inwards across the boundary (a concave crease, where the minima rule
    /// puts part boundaries).
    pub concave: f64,
    /// `Σ len · max(0, s)`: how much it folds outwards (a convex ridge).
    pub convex: f64,
}

impl Boundary {
    /// Adds `other`'s edges.
    pub fn add(&mut self, other: &Boundary) {
        self.length += other.length;
        self.concave += other.concave;
        self.convex += other.convex;
    }
}

/// The fine segments of one bucket.
#[derive(Debug, Clone, Default)]
pub struct BucketSegments {
    /// Per vertex of the bucket mesh, its segment (local number).
    pub vertex_segment: Vec<u32>,
    /// Per segment, its sums.
    pub sums: Vec<SegmentSums>,
    /// Boundaries between two segments `(a, b)`, `a < b`, local numbers.
    pub boundaries: Vec<(u32, u32, Boundary)>,
    /// Vertices on the bucket's border (original id, local segment), sorted by id.
    pub border: Vec<(u32, u32)>,
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn unit(n: [f32; 3]) -> Option<[f32; 3]> {
    let l = dot(n, n).sqrt();
    (l.is_finite() && l > 1e-20).then(|| [n[0] / l, n[1] / l, n[2] / l])
}

/// Grows the fine segments of `mesh` (its `ids`, `positions`, `normals` and `indices`).
pub fn grow(mesh: &BuildPatch, params: &GrowParams) -> BucketSegments {
    let n = mesh.positions.len();
    if n == 0 {
        return BucketSegments::default();
    }
    // Unique edges with their use counts (the hierarchy's border rule: used once, border),
    // counting-sorted on the local indices when they are all in range (a build's buckets).
    let counts: Vec<(u64, usize)> = if mesh.indices.iter().all(|&i| (i as usize) < n) {
        edge_runs(&mesh.indices, n, false)
            .into_iter()
            .map(|(key, uses)| (key, uses as usize))
            .collect()
    } else {
        EdgeUses::of(mesh.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]))
            .counts()
            .collect()
    };
    let edges: Vec<(u32, u32, usize)> = counts
        .into_iter()
        .map(|(key, uses)| {
            let (a, b) = edge_ends(key);
            (a, b, uses)
        })
        .filter(|&(a, b, _)| a != b && (a as usize) < n && (b as usize) < n)
        .collect();
    // Vertex adjacency (CSR).
    let mut start = vec![0u32; n + 1];
    for &(a, b, _) in &edges {
        start[a as usize + 1] += 1;
        start[b as usize + 1] += 1;
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut adjacent = vec![0u32; start[n] as usize];
    for &(a, b, _) in &edges {
        adjacent[fill[a as usize] as usize] = b;
        fill[a as usize] += 1;
        adjacent[fill[b as usize] as usize] = a;
        fill[b as usize] += 1;
    }
    drop(fill);

    let normals: Vec<Option<[f32; 3]>> = (0..n)
        .map(|i| mesh.normals.get(i).and_then(|&v| unit(v)))
        .collect();
    let cos_max = params.angle_deg.clamp(0.0, 180.0).to_radians().cos();
    let cap = params.max_vertices.max(1);
    const NONE: u32 = u32::MAX;
    let mut segment = vec![NONE; n];
    let mut sums: Vec<SegmentSums> = Vec::new();
    let mut queue = VecDeque::new();
    for seed in 0..n {
        if segment[seed] != NONE {
            continue;
        }
        let id = sums.len() as u32;
        let seed_normal = normals[seed];
        let mut s = SegmentSums::default();
        segment[seed] = id;
        queue.clear();
        queue.push_back(seed as u32);
        let mut members = 1usize;
        while let Some(v) = queue.pop_front() {
            let v = v as usize;
            s.vertices += 1;
            if let Some(nv) = normals[v] {
                for (sum, x) in s.normal.iter_mut().zip(nv) {
                    *sum += x as f64;
                }
            }
            for &u in &adjacent[start[v] as usize..start[v + 1] as usize] {
                let u = u as usize;
                if segment[u] != NONE || members >= cap {
                    continue;
                }
                // Eq. 1 against the seed; a vertex without a normal joins its neighbour.
                let within = match (seed_normal, normals[u]) {
                    (Some(a), Some(b)) => dot(a, b) >= cos_max,
                    _ => true,
                };
                if within {
                    segment[u] = id;
                    members += 1;
                    queue.push_back(u as u32);
                }
            }
        }
        sums.push(s);
    }

    // Boundaries, and the bucket's border (edges used by one triangle).
    let mut between: FxHashMap<(u32, u32), Boundary> = FxHashMap::default();
    let mut border: Vec<(u32, u32)> = Vec::new();
    for &(a, b, uses) in &edges {
        let (a, b) = (a as usize, b as usize);
        if uses == 1 {
            border.push((mesh.ids[a], segment[a]));
            border.push((mesh.ids[b], segment[b]));
        }
        let (sa, sb) = (segment[a], segment[b]);
        if sa == sb {
            continue;
        }
        let (pa, pb) = (mesh.positions[a], mesh.positions[b]);
        let d = [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]];
        let len = dot(d, d).sqrt();
        if !len.is_finite() {
            continue;
        }
        let s = match (normals[a], normals[b]) {
            (Some(na), Some(nb)) if len > 0.0 => {
                dot([nb[0] - na[0], nb[1] - na[1], nb[2] - na[2]], d) / len
            }
            _ => 0.0,
        };
        let e = between.entry((sa.min(sb), sa.max(sb))).or_default();
        e.length += len as f64;
        e.concave += (len * (-s).max(0.0)) as f64;
        e.convex += (len * s.max(0.0)) as f64;
    }
    border.sort_unstable();
    border.dedup();
    let mut boundaries: Vec<(u32, u32, Boundary)> =
        between.into_iter().map(|((a, b), v)| (a, b, v)).collect();
    boundaries.sort_unstable_by_key(|&(a, b, _)| (a, b));
    BucketSegments {
        vertex_segment: segment,
        sums,
        boundaries,
        border,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A folded strip: two flat squares of `k × k` vertices meeting at a right angle.
    fn fold(k: usize) -> BuildPatch {
        let mut m = BuildPatch::default();
        for side in 0..2 {
            for j in 0..k {
                for i in 0..k {
                    let (u, v) = (i as f32, j as f32);
                    if side == 0 {
                        m.positions.push([u, v, 0.0]);
                        m.normals.push([0.0, 0.0, 1.0]);
                    } else {
                        m.positions.push([u, (k - 1) as f32, v]);
                        m.normals.push([0.0, -1.0, 0.0]);
                    }
                }
            }
        }
        let id = |side: usize, i: usize, j: usize| (side * k * k + j * k + i) as u32;
        for side in 0..2 {
            for j in 0..k - 1 {
                for i in 0..k - 1 {
                    let (a, b, c, d) = (
                        id(side, i, j),
                        id(side, i + 1, j),
                        id(side, i + 1, j + 1),
                        id(side, i, j + 1),
                    );
                    m.indices.extend_from_slice(&[a, b, c, a, c, d]);
                }
            }
        }
        m.ids = (0..m.positions.len() as u32).map(|i| i + 1000).collect();
        m
    }

    #[test]
    fn a_fold_splits_into_its_two_faces() {
        let m = fold(6);
        let s = grow(
            &m,
            &GrowParams {
                angle_deg: 30.0,
                max_vertices: 1000,
            },
        );
        assert_eq!(s.sums.len(), 2);
        assert!(
            s.vertex_segment[..36]
                .iter()
                .all(|&x| x == s.vertex_segment[0])
        );
        assert!(
            s.vertex_segment[36..]
                .iter()
                .all(|&x| x == s.vertex_segment[36])
        );
        assert_eq!(s.sums[0].vertices + s.sums[1].vertices, 72);
        // The two faces are not joined by edges (separate sheets): no boundary, and every
        // sheet's rim is border.
        assert!(s.boundaries.is_empty());
        assert_eq!(s.border.len(), 2 * 20);
        assert!(s.border.iter().all(|&(id, _)| id >= 1000));
    }

    #[test]
    fn the_size_cap_makes_superpixels_with_boundaries() {
        let m = fold(10);
        let s = grow(
            &m,
            &GrowParams {
                angle_deg: 30.0,
                max_vertices: 10,
            },
        );
        assert!(s.sums.len() >= 20, "{}", s.sums.len());
        assert!(s.sums.iter().all(|x| x.vertices <= 10));
        assert_eq!(s.sums.iter().map(|x| x.vertices).sum::<u64>(), 200);
        // Flat sheets: boundaries with length and no fold.
        assert!(!s.boundaries.is_empty());
        for (a, b, bd) in &s.boundaries {
            assert!(a < b && bd.length > 0.0 && bd.concave < 1e-6 && bd.convex < 1e-6);
        }
    }
}
