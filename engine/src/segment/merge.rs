//! Coarser scales of the surface segments by hierarchical merging (the multi-scale form of
//! the mesh-segmentation paper's §3.1, where `δ_Seg` is chosen per model by hand): the fine
//! segments of [`super::grow`] are merged two at a time, cheapest shared boundary first,
//! until one segment per connected surface is left; the labelling is recorded each time the
//! number of segments halves.
//!
//! The cost of merging two neighbouring segments `A` and `B` is
//!
//! `(ε + w_c · concave/length + w_x · convex/length + w_n · ∠(n_A, n_B)/π) · √min(|A|, |B|)`
//!
//! with the boundary's sums of [`Boundary`] (how much the surface folds inwards and outwards
//! across it, per unit length), the angle between the segments' mean normals, and `|·|` their
//! vertices. Concave creases weigh most (the minima rule: parts of an object meet at
//! concave creases), so they are the boundaries that survive to the coarse scales; the size
//! factor merges small segments before large ones, so every scale has segments of similar
//! size. Joins across a bucket border (no edges of their own) cost only the normal term.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rustc_hash::FxHashMap;

use super::grow::{Boundary, SegmentSums};

/// Weights of the merge cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MergeParams {
    /// `w_c`: concave folding per unit length.
    pub concave: f64,
    /// `w_x`: convex folding per unit length.
    pub convex: f64,
    /// `w_n`: angle between mean normals.
    pub normal: f64,
    /// Exponent of the size factor.
    pub size_exp: f64,
}

impl Default for MergeParams {
    fn default() -> Self {
        MergeParams {
            concave: 4.0,
            convex: 0.0,
            normal: 0.0,
            size_exp: 0.7,
        }
    }
}

/// The scales of a segmentation.
#[derive(Debug, Clone, PartialEq)]
pub struct Hierarchy {
    /// Number of fine segments.
    pub fine: u32,
    /// Coarser scales, finest first: per fine segment, its segment at that scale (numbered
    /// `0..count` per scale).
    pub scales: Vec<Vec<u32>>,
    /// Segments per coarser scale.
    pub counts: Vec<u32>,
    /// Per scale, fine (0) first, per segment, its saliency: the strength of the boundary
    /// across which it was merged into a larger segment (the merge cost without its size
    /// factor, `ε + w_c · concave/length + …`) minus the strongest boundary merged inside it
    /// (its persistence); infinite for one never merged. A segment whose own boundary is much
    /// stronger than any inside it is a salient part; selection prefers those
    /// ([`crate::select::segments`]).
    pub strengths: Vec<Vec<f32>>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Candidate {
    cost: f64,
    a: u32,
    b: u32,
}

impl Eq for Candidate {}

impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        // Min-heap on cost; ties broken by ids so the result is deterministic.
        other
            .cost
            .total_cmp(&self.cost)
            .then_with(|| (other.a, other.b).cmp(&(self.a, self.b)))
    }
}

impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// The merge cost of `a` and `b` and the strength of their boundary (the cost without the
/// size factor).
fn cost(a: &SegmentSums, b: &SegmentSums, bd: &Boundary, p: &MergeParams) -> (f64, f64) {
    let (na, nb) = (a.mean_normal(), b.mean_normal());
    let cos = (na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2]).clamp(-1.0, 1.0);
    let angle = if na == [0.0; 3] || nb == [0.0; 3] {
        0.0
    } else {
        cos.acos() / std::f64::consts::PI
    };
    let fold = if bd.length > 0.0 {
        (p.concave * bd.concave + p.convex * bd.convex) / bd.length
    } else {
        0.0
    };
    let strength = 1e-3 + fold + p.normal * angle;
    (
        strength * (a.vertices.min(b.vertices) as f64).powf(p.size_exp),
        strength,
    )
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

/// Merges the fine segments with sums `sums` and shared boundaries `boundaries` (`(a, b)`
/// pairs in any order, repeated pairs added up) into coarser scales: one each time the
/// number of segments halves, while at least two remain.
pub fn merge(
    mut sums: Vec<SegmentSums>,
    boundaries: impl IntoIterator<Item = (u32, u32, Boundary)>,
    params: &MergeParams,
) -> Hierarchy {
    let n = sums.len();
    let mut adjacency: Vec<FxHashMap<u32, Boundary>> = vec![FxHashMap::default(); n];
    for (a, b, bd) in boundaries {
        if a == b || a as usize >= n || b as usize >= n {
            continue;
        }
        adjacency[a as usize].entry(b).or_default().add(&bd);
        adjacency[b as usize].entry(a).or_default().add(&bd);
    }
    let mut parent: Vec<u32> = (0..n as u32).collect();
    let mut heap = BinaryHeap::new();
    for a in 0..n {
        for (&b, bd) in &adjacency[a] {
            if (a as u32) < b {
                heap.push(Candidate {
                    cost: cost(&sums[a], &sums[b as usize], bd, params).0,
                    a: a as u32,
                    b,
                });
            }
        }
    }
    let mut live = n;
    let mut next_target = n / 2;
    let mut hierarchy = Hierarchy {
        fine: n as u32,
        scales: Vec::new(),
        counts: Vec::new(),
        strengths: vec![vec![f32::INFINITY; n]],
    };
    // Per live segment, the snapshots `(scale, label)` it still is (not merged since).
    let mut open: Vec<Vec<(u32, u32)>> = (0..n as u32).map(|f| vec![(0, f)]).collect();
    // Per live segment, the strongest boundary merged inside it.
    let mut inner = vec![0f64; n];
    let record =
        |parent: &mut [u32], live: usize, h: &mut Hierarchy, open: &mut [Vec<(u32, u32)>]| {
            let scale = h.scales.len() as u32 + 1;
            let mut label = vec![u32::MAX; n];
            let mut labels = Vec::with_capacity(n);
            let mut count = 0u32;
            for f in 0..n as u32 {
                let r = find(parent, f) as usize;
                if label[r] == u32::MAX {
                    label[r] = count;
                    open[r].push((scale, count));
                    count += 1;
                }
                labels.push(label[r]);
            }
            debug_assert_eq!(count as usize, live);
            h.scales.push(labels);
            h.counts.push(count);
            h.strengths.push(vec![f32::INFINITY; count as usize]);
        };
    // Merging goes on to the end (every segment's strength); scales are recorded while at
    // least two segments remain.
    while live > 1 {
        let Some(c) = heap.pop() else { break };
        let (a, b) = (c.a as usize, c.b as usize);
        if parent[a] != c.a || parent[b] != c.b {
            continue;
        }
        // A candidate is current while its cost is (a changed pair was pushed again).
        let Some((current, strength)) = adjacency[a]
            .get(&c.b)
            .map(|bd| cost(&sums[a], &sums[b], bd, params))
        else {
            continue;
        };
        if current.to_bits() != c.cost.to_bits() {
            continue;
        }
        // The two segments end here.
        for r in [a, b] {
            for (scale, label) in open[r].drain(..) {
                hierarchy.strengths[scale as usize][label as usize] = (strength - inner[r]) as f32;
            }
        }
        let merged_inner = inner[a].max(inner[b]).max(strength);
        // Merge the smaller adjacency into the larger.
        let (keep, gone) = if adjacency[a].len() >= adjacency[b].len() {
            (a, b)
        } else {
            (b, a)
        };
        parent[gone] = keep as u32;
        inner[keep] = merged_inner;
        let keep_before = sums[keep].vertices;
        let gone_sums = sums[gone];
        sums[keep].add(&gone_sums);
        let moved = std::mem::take(&mut adjacency[gone]);
        let mut changed: Vec<u32> = moved.keys().copied().collect();
        adjacency[keep].remove(&(gone as u32));
        for (other, bd) in moved {
            if other as usize == keep {
                continue;
            }
            let o = &mut adjacency[other as usize];
            o.remove(&(gone as u32));
            o.entry(keep as u32).or_default().add(&bd);
            adjacency[keep].entry(other).or_default().add(&bd);
        }
        // New costs: pairs whose boundary changed (the neighbours of `gone`), and those whose
        // smaller side was `keep` (or all, when mean normals weigh); the others' entries stay
        // current.
        changed.extend(
            adjacency[keep]
                .keys()
                .copied()
                .filter(|&o| params.normal != 0.0 || sums[o as usize].vertices > keep_before),
        );
        changed.sort_unstable();
        changed.dedup();
        for other in changed {
            let Some(bd) = adjacency[keep].get(&other) else {
                continue;
            };
            let (x, y) = if (keep as u32) < other {
                (keep as u32, other)
            } else {
                (other, keep as u32)
            };
            heap.push(Candidate {
                cost: cost(&sums[x as usize], &sums[y as usize], bd, params).0,
                a: x,
                b: y,
            });
        }
        live -= 1;
        if live <= next_target && next_target >= 2 {
            record(&mut parent, live, &mut hierarchy, &mut open);
            next_target = live / 2;
        }
    }
    // Merging stopped early (separate surfaces): the components are the coarsest scale.
    let last = hierarchy.counts.last().map_or(n, |&c| c as usize);
    if live < last && live >= 2 {
        record(&mut parent, live, &mut hierarchy, &mut open);
    }
    hierarchy
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sums(vertices: u64, normal: [f64; 3]) -> SegmentSums {
        SegmentSums {
            vertices,
            normal: normal.map(|x| x * vertices as f64),
        }
    }

    fn edge(length: f64, concave: f64, convex: f64) -> Boundary {
        Boundary {
            length,
            concave,
            convex,
        }
    }

    /// A chain of eight segments whose only concave boundary is between 3 and 4: the last
    /// two segments left are the halves.
    #[test]
    fn concave_creases_survive_to_the_coarsest_scale() {
        let s = vec![sums(50, [0.0, 0.0, 1.0]); 8];
        let mut b: Vec<(u32, u32, Boundary)> =
            (0..7u32).map(|i| (i, i + 1, edge(1.0, 0.0, 0.1))).collect();
        b[3].2 = edge(1.0, 0.9, 0.0);
        let h = merge(s, b, &MergeParams::default());
        assert_eq!(h.fine, 8);
        assert_eq!(h.counts, vec![4, 2]);
        let last = h.scales.last().unwrap();
        assert!(last[..4].iter().all(|&x| x == last[0]));
        assert!(last[4..].iter().all(|&x| x == last[4]));
        assert_ne!(last[0], last[4]);
        // Every scale is a coarsening of the one before.
        for w in h.scales.windows(2) {
            for f in 0..8 {
                for g in 0..8 {
                    if w[0][f] == w[0][g] {
                        assert_eq!(w[1][f], w[1][g]);
                    }
                }
            }
        }
    }

    #[test]
    fn separate_surfaces_are_never_merged() {
        let s = vec![sums(10, [0.0, 0.0, 1.0]); 6];
        let b = vec![(0, 1, edge(1.0, 0.0, 0.0)), (2, 3, edge(1.0, 0.0, 0.0))];
        let h = merge(s, b, &MergeParams::default());
        // 6 → 4 live after two merges; no scale at 3 (nothing left to merge).
        assert_eq!(h.counts, vec![4]);
        assert_eq!(h.scales[0][0], h.scales[0][1]);
        assert_ne!(h.scales[0][4], h.scales[0][5]);
    }
}
