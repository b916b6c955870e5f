//! Multi-way parallelogram prediction of `MWP3` positions, ids and colours
//! (`docs/FORMAT.md` "Prediction"), after Cohen-Or et al.'s multi-way prediction and Draco's
//! `MESH_PREDICTION_MULTI_PARALLELOGRAM`.
//!
//! The connectivity is decoded before any position ([`super::frontcoder`]), so a vertex `v`
//! can be predicted from every triangle around it whose two other corners `x`, `y` come
//! before it, not only from the one triangle that introduced it: each such triangle whose
//! edge `(x, y)` has, in an earlier triangle of the patch, a third corner `o` before `v`
//! gives the parallelogram `x + y - o`. Positions take the mean of those parallelograms
//! (floored), ids the median of their clamped values (LOCO-I's median edge detector per
//! parallelogram: scans number vertices in rows or slices, so a neighbour's id is often right
//! where the parallelogram overshoots). On the dragon, 5% fewer position bytes and 3% fewer
//! id bytes than the introducing triangle's parallelogram alone.
//!
//! Colours take the mean over the same triangles' `x` and `y` corners (the vertex's earlier
//! neighbours). Vertices without any such triangle keep their traversal prediction (a start
//! triangle's corners). The edge table also gives the patch's border vertices, so a decoder
//! need not build a second one.

use super::frontcoder::Prediction;
use super::patch::{edge_users, sort_small};

/// Every vertex's parallelograms `(x, y, o)`, in a compressed row layout.
pub struct Parallelograms {
    start: Vec<u32>,
    triples: Vec<[u32; 3]>,
    /// Vertices on an edge used by exactly one triangle (as `codec::border_vertices` finds
    /// them), from the same edge table.
    pub border: Vec<bool>,
}

impl Parallelograms {
    /// The parallelograms of the `n` vertices of `indices` (corners all below `n`): for each
    /// triangle in order, each corner `v` whose two others are below it, with the first
    /// other triangle on the edge of those two (in triangle order) whose third corner is
    /// below `v`.
    pub fn of(indices: &[u32], n: usize) -> Self {
        // The users of each edge, each a run in triangle order (a hash map of edges did the
        // same in 3.7% of a build).
        let (bucket, half) = edge_users(indices);
        let corners = bucket.len() - 1;
        let mut border = vec![false; n];
        for lo in 0..corners {
            let around = &half[bucket[lo] as usize..bucket[lo + 1] as usize];
            for users in around.chunk_by(|p, q| p >> 32 == q >> 32) {
                if users.len() == 1 {
                    for end in [lo, (users[0] >> 32) as usize] {
                        if let Some(b) = border.get_mut(end) {
                            *b = true;
                        }
                    }
                }
            }
        }
        // The triangles on edge `(x, y)`, in order.
        let users = |x: u32, y: u32| {
            let (lo, hi) = (x.min(y), x.max(y));
            half[bucket[lo as usize] as usize..bucket[lo as usize + 1] as usize]
                .iter()
                .filter(move |&&e| e >> 32 == hi as u64)
                .map(|&e| e as u32)
        };
        let mut thirds = vec![u32::MAX; indices.len()];
        let mut start = vec![0u32; n + 1];
        for (f, t) in indices.chunks_exact(3).enumerate() {
            for k in 0..3 {
                let (v, x, y) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                if x >= v || y >= v || v as usize >= n {
                    continue;
                }
                let third = users(x, y)
                    .filter(|&g| g as usize != f)
                    .filter_map(|g| {
                        let u = &indices[3 * g as usize..3 * g as usize + 3];
                        u.iter().copied().find(|&o| o != x && o != y)
                    })
                    .find(|&o| o < v);
                if let Some(o) = third {
                    thirds[3 * f + k] = o;
                    start[v as usize + 1] += 1;
                }
            }
        }
        for v in 0..n {
            start[v + 1] += start[v];
        }
        let mut fill: Vec<u32> = start[..n].to_vec();
        let mut triples = vec![[0u32; 3]; start[n] as usize];
        for (c, &o) in thirds.iter().enumerate() {
            if o == u32::MAX {
                continue;
            }
            let (f, k) = (c / 3, c % 3);
            let t = &indices[3 * f..3 * f + 3];
            let v = t[k] as usize;
            triples[fill[v] as usize] = [t[(k + 1) % 3], t[(k + 2) % 3], o];
            fill[v] += 1;
        }
        Parallelograms {
            start,
            triples,
            border,
        }
    }

    /// The parallelograms of vertex `v`.
    pub fn of_vertex(&self, v: usize) -> &[[u32; 3]] {
        &self.triples[self.start[v] as usize..self.start[v + 1] as usize]
    }

    /// The prediction of `v`'s position (floored mean of its parallelograms; `fallback`'s
    /// when it has none).
    pub fn position(&self, pos: &[[i64; 3]], v: usize, fallback: &Prediction) -> [i64; 3] {
        let list = self.of_vertex(v);
        if list.is_empty() {
            return predict(pos, fallback);
        }
        let m = list.len() as i64;
        std::array::from_fn(|k| {
            let sum = list.iter().fold(0i64, |s, &[x, y, o]| {
                s.wrapping_add(
                    pos[x as usize][k]
                        .wrapping_add(pos[y as usize][k])
                        .wrapping_sub(pos[o as usize][k]),
                )
            });
            sum.div_euclid(m)
        })
    }

    /// The prediction of `v`'s id: the median (the upper one of an even count) of its
    /// parallelograms each clamped between its `x` and `y`; `fallback`'s when it has none.
    pub fn id(&self, ids: &[[i64; 1]], v: usize, fallback: &Prediction) -> i64 {
        let list = self.of_vertex(v);
        if list.is_empty() {
            return predict(ids, fallback)[0];
        }
        let clamped = |&[x, y, o]: &[u32; 3]| {
            let (a, b, c) = (ids[x as usize][0], ids[y as usize][0], ids[o as usize][0]);
            a.wrapping_add(b).wrapping_sub(c).clamp(a.min(b), a.max(b))
        };
        // A vertex has a few parallelograms (one per earlier triangle around it): sorted on
        // the stack, not in a vector of their own.
        let mut few = [0i64; 16];
        let mut many = Vec::new();
        let values: &mut [i64] = if list.len() <= few.len() {
            for (slot, p) in few.iter_mut().zip(list) {
                *slot = clamped(p);
            }
            &mut few[..list.len()]
        } else {
            many.extend(list.iter().map(clamped));
            &mut many
        };
        sort_small(values);
        values[values.len() / 2]
    }

    /// The prediction of `v`'s colour (`MWP3`, the four bytes of meshoptimizer's YCoCg
    /// filter, the chroma ones signed): the floored mean over its parallelograms' `x` and `y`
    /// corners, its earlier neighbours (colour varies too irregularly for parallelograms);
    /// without any, the mean of the traversal prediction's first two vertices (its one
    /// vertex for a copy; zero for the very first).
    pub fn colour(&self, values: &[[i64; 4]], v: usize, fallback: &Prediction) -> [i64; 4] {
        let list = self.of_vertex(v);
        let mean = |vs: &mut dyn Iterator<Item = u32>| -> [i64; 4] {
            let (mut sum, mut m) = ([0i64; 4], 0i64);
            for u in vs {
                for k in 0..4 {
                    sum[k] += values[u as usize][k];
                }
                m += 1;
            }
            if m == 0 {
                return [0; 4];
            }
            sum.map(|x| x.div_euclid(m))
        };
        if !list.is_empty() {
            return mean(&mut list.iter().flat_map(|&[x, y, _]| [x, y]));
        }
        match *fallback {
            Prediction::Parallelogram(a, b, _) | Prediction::Midpoint(a, b) => {
                mean(&mut [a, b].into_iter())
            }
            Prediction::Copy(a) => values[a as usize],
            Prediction::Zero => [0; 4],
        }
    }
}

/// The value of a traversal prediction (`frontcoder::Prediction`) over `values`.
pub fn predict<const N: usize>(values: &[[i64; N]], prediction: &Prediction) -> [i64; N] {
    match *prediction {
        // Wrapping: a corrupt blob may hold absurd residuals; the result is range-checked later.
        Prediction::Parallelogram(a, b, c) => std::array::from_fn(|k| {
            values[a as usize][k]
                .wrapping_add(values[b as usize][k])
                .wrapping_sub(values[c as usize][k])
        }),
        Prediction::Midpoint(a, b) => {
            std::array::from_fn(|k| values[a as usize][k].wrapping_add(values[b as usize][k]) >> 1)
        }
        Prediction::Copy(a) => values[a as usize],
        Prediction::Zero => [0; N],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fan_vertex_averages_its_parallelograms_and_medians_its_ids() {
        // A square 0-1-2-3 split in two, then vertex 4 with the triangles (1, 4, 2) and
        // (2, 4, 3) on the square's two triangles.
        let pos: Vec<[i64; 3]> = vec![[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0], [20, 10, 3]];
        let idx = [0, 1, 2, 0, 2, 3, 1, 4, 2, 2, 4, 3];
        let p = Parallelograms::of(&idx, 5);
        assert!(p.of_vertex(0).is_empty() && p.of_vertex(1).is_empty());
        // Vertex 2: triangle (0, 1, 2) has no earlier other triangle on (0, 1).
        assert!(p.of_vertex(2).is_empty());
        // Vertex 3: triangle (0, 2, 3), edge (2, 0) also in triangle 0 with third corner 1.
        assert_eq!(p.of_vertex(3), &[[0, 2, 1]]);
        // Vertex 4: (1, 2) across from 0, and (2, 3) across from 0 as well.
        assert_eq!(p.of_vertex(4), &[[2, 1, 0], [3, 2, 0]]);
        // Mean of (20, 10, 0) and (10, 20, 0).
        assert_eq!(p.position(&pos, 4, &Prediction::Zero), [15, 15, 0]);
        let ids: Vec<[i64; 1]> = vec![[100], [101], [111], [110], [112]];
        // Clamped parallelograms 112 (in [101, 111] -> 111) and 121 (in [110, 111] -> 111).
        assert_eq!(p.id(&ids, 4, &Prediction::Zero), 111);
        assert_eq!(p.position(&pos, 1, &Prediction::Copy(0)), [0, 0, 0]);
    }
}
