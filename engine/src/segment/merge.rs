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

/// A candidate pair `(a, b)`, `a < b`, at a cost: one `u128` whose order is the cost's
/// (`f64::total_cmp`'s), then `a`, then `b`, so the queue compares one integer and holds 16
/// bytes an entry (the merge pushes millions; the heap's compares were 3% of a build's CPU time).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct Candidate(u128);

impl Candidate {
    fn new(cost: f64, a: u32, b: u32) -> Candidate {
        // `total_cmp`'s transform, with the sign bit flipped so that unsigned order is its order.
        let bits = cost.to_bits() as i64;
        let ordered = ((bits ^ ((((bits >> 63) as u64) >> 1) as i64)) as u64) ^ (1 << 63);
        Candidate(((ordered as u128) << 64) | ((a as u128) << 32) | b as u128)
    }

    fn a(self) -> u32 {
        (self.0 >> 32) as u32
    }

    fn b(self) -> u32 {
        self.0 as u32
    }
}

/// A min-queue of candidates: a 4-ary heap, half as deep as a binary one, whose four children
/// of a node sit side by side in memory (64 bytes). The merge's queue holds hundreds of
/// thousands of candidates, most of them out of date by the time they surface; popping them
/// is a walk down the heap that misses the cache at each level, which made the heap's compares
/// the merge's largest cost. Any priority queue pops the same sequence here (entries are
/// totally ordered, and equal entries identical), so the merge's result does not change.
#[derive(Default)]
struct Queue {
    items: Vec<Candidate>,
}

impl Queue {
    fn push(&mut self, c: Candidate) {
        let mut i = self.items.len();
        self.items.push(c);
        while i > 0 {
            let parent = (i - 1) / 4;
            if self.items[parent] <= c {
                break;
            }
            self.items[i] = self.items[parent];
            i = parent;
        }
        self.items[i] = c;
    }

    fn pop(&mut self) -> Option<Candidate> {
        let last = self.items.pop()?;
        let Some(&top) = self.items.first() else {
            return Some(last);
        };
        let n = self.items.len();
        let mut i = 0;
        loop {
            let first = 4 * i + 1;
            if first >= n {
                break;
            }
            let mut least = first;
            for k in first + 1..(first + 4).min(n) {
                if self.items[k] < self.items[least] {
                    least = k;
                }
            }
            if self.items[least] >= last {
                break;
            }
            self.items[i] = self.items[least];
            i = least;
        }
        self.items[i] = last;
        Some(top)
    }
}

/// The merge cost of `a` and `b` and the strength of their boundary (the cost without the
/// size factor).
fn cost(a: &SegmentSums, b: &SegmentSums, bd: &Boundary, p: &MergeParams) -> (f64, f64) {
    // The normal term only where it weighs (not by default): two square roots and an arc
    // cosine per cost, and the merge computes millions.
    let angle = if p.normal == 0.0 {
        0.0
    } else {
        let (na, nb) = (a.mean_normal(), b.mean_normal());
        let cos = (na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2]).clamp(-1.0, 1.0);
        if na == [0.0; 3] || nb == [0.0; 3] {
            0.0
        } else {
            cos.acos() / std::f64::consts::PI
        }
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

/// A live segment's neighbours and the boundaries shared with them, in a list: a surface's
/// segments have about six neighbours whatever their scale, so a scan of the list finds one
/// sooner than a hash table does (the merge's lookups, removals and insertions were a fifth
/// of its time with one). Order does not matter: every use sorts or takes one entry.
#[derive(Debug, Clone, Default)]
struct Neighbours(Vec<(u32, Boundary)>);

impl Neighbours {
    fn len(&self) -> usize {
        self.0.len()
    }

    fn position(&self, other: u32) -> Option<usize> {
        self.0.iter().position(|&(o, _)| o == other)
    }

    fn get(&self, other: u32) -> Option<&Boundary> {
        self.position(other).map(|i| &self.0[i].1)
    }

    /// Adds `bd` to the boundary shared with `other` (a new, empty one if there is none).
    fn add(&mut self, other: u32, bd: &Boundary) {
        let i = self.position(other).unwrap_or_else(|| {
            self.0.push((other, Boundary::default()));
            self.0.len() - 1
        });
        self.0[i].1.add(bd);
    }

    fn remove(&mut self, other: u32) {
        if let Some(i) = self.position(other) {
            self.0.swap_remove(i);
        }
    }

    fn iter(&self) -> impl Iterator<Item = (u32, &Boundary)> {
        self.0.iter().map(|(o, bd)| (*o, bd))
    }
}

/// The merging shared by [`merge`] and [`coarsen`]: the live segments' sums and shared
/// boundaries, their union-find, the candidate pairs by cost, and per live segment the
/// strongest boundary merged inside it.
struct Merger<'p> {
    sums: Vec<SegmentSums>,
    adjacency: Vec<Neighbours>,
    parent: Vec<u32>,
    /// Cheapest first.
    heap: Queue,
    inner: Vec<f64>,
    live: usize,
    params: &'p MergeParams,
}

/// One merge: the two segments that ended there, the strongest boundary merged inside each
/// before, and the strength of the boundary between them.
struct Merged {
    ended: [(usize, f64); 2],
    strength: f64,
}

impl<'p> Merger<'p> {
    /// `inner`: per segment, the strongest boundary already merged inside it (empty: none).
    fn new(
        sums: Vec<SegmentSums>,
        inner: Vec<f64>,
        boundaries: impl IntoIterator<Item = (u32, u32, Boundary)>,
        params: &'p MergeParams,
    ) -> Merger<'p> {
        let n = sums.len();
        let mut adjacency: Vec<Neighbours> = vec![Neighbours::default(); n];
        for (a, b, bd) in boundaries {
            if a == b || a as usize >= n || b as usize >= n {
                continue;
            }
            adjacency[a as usize].add(b, &bd);
            adjacency[b as usize].add(a, &bd);
        }
        let mut heap = Queue::default();
        for a in 0..n {
            for (b, bd) in adjacency[a].iter() {
                if (a as u32) < b {
                    heap.push(Candidate::new(
                        cost(&sums[a], &sums[b as usize], bd, params).0,
                        a as u32,
                        b,
                    ));
                }
            }
        }
        let mut inner = inner;
        inner.resize(n, 0.0);
        Merger {
            sums,
            adjacency,
            parent: (0..n as u32).collect(),
            heap,
            inner,
            live: n,
            params,
        }
    }

    /// The live segments numbered in order of their first input segment: per input segment
    /// its number, and per number the live segment (its union-find root).
    fn labels(&mut self) -> (Vec<u32>, Vec<usize>) {
        let n = self.parent.len();
        let mut label = vec![u32::MAX; n];
        let mut labels = Vec::with_capacity(n);
        let mut roots = Vec::with_capacity(self.live);
        for f in 0..n as u32 {
            let r = find(&mut self.parent, f) as usize;
            if label[r] == u32::MAX {
                label[r] = roots.len() as u32;
                roots.push(r);
            }
            labels.push(label[r]);
        }
        debug_assert_eq!(roots.len(), self.live);
        (labels, roots)
    }

    /// Merges the cheapest pair of neighbouring segments; `None` when no pair is left.
    fn step(&mut self) -> Option<Merged> {
        let params = self.params;
        loop {
            let c = self.heap.pop()?;
            let (a, b) = (c.a() as usize, c.b() as usize);
            if self.parent[a] != c.a() || self.parent[b] != c.b() {
                continue;
            }
            // A candidate is current while its cost is. A pair's cost falls only where its
            // boundary changes (or, with mean normals weighing, its normals), and such pairs
            // are pushed again at once; it rises as the smaller side grows, and such a pair's
            // older, lower entry surfaces first and is pushed again here at its cost now: it
            // comes out where pushing it at once would have put it, and most such pairs change
            // again (or end) before that.
            let Some((current, strength)) = self.adjacency[a]
                .get(c.b())
                .map(|bd| cost(&self.sums[a], &self.sums[b], bd, params))
            else {
                continue;
            };
            let now = Candidate::new(current, c.a(), c.b());
            if now != c {
                if now > c {
                    self.heap.push(now);
                }
                continue;
            }
            let ended = [(a, self.inner[a]), (b, self.inner[b])];
            let merged_inner = self.inner[a].max(self.inner[b]).max(strength);
            // Merge the smaller adjacency into the larger.
            let (keep, gone) = if self.adjacency[a].len() >= self.adjacency[b].len() {
                (a, b)
            } else {
                (b, a)
            };
            self.parent[gone] = keep as u32;
            self.inner[keep] = merged_inner;
            let gone_sums = self.sums[gone];
            self.sums[keep].add(&gone_sums);
            let moved = std::mem::take(&mut self.adjacency[gone]);
            let mut changed: Vec<u32> = moved.iter().map(|(o, _)| o).collect();
            self.adjacency[keep].remove(gone as u32);
            for (other, bd) in moved.iter() {
                if other as usize == keep {
                    continue;
                }
                let o = &mut self.adjacency[other as usize];
                o.remove(gone as u32);
                o.add(keep as u32, bd);
                self.adjacency[keep].add(other, bd);
            }
            // New costs: pairs whose boundary changed (the neighbours of `gone`), or every pair
            // of `keep` when mean normals weigh. Those whose smaller side was `keep` cost more
            // now: their entries are pushed again as they surface (above).
            if params.normal != 0.0 {
                changed.extend(self.adjacency[keep].iter().map(|(o, _)| o));
            }
            changed.sort_unstable();
            changed.dedup();
            for other in changed {
                let Some(bd) = self.adjacency[keep].get(other) else {
                    continue;
                };
                let (x, y) = if (keep as u32) < other {
                    (keep as u32, other)
                } else {
                    (other, keep as u32)
                };
                self.heap.push(Candidate::new(
                    cost(&self.sums[x as usize], &self.sums[y as usize], bd, params).0,
                    x,
                    y,
                ));
            }
            self.live -= 1;
            return Some(Merged { ended, strength });
        }
    }
}

/// Merges the fine segments with sums `sums` and shared boundaries `boundaries` (`(a, b)`
/// pairs in any order, repeated pairs added up) into coarser scales: one each time the
/// number of segments halves, while at least two remain. `inner`: per fine segment, the
/// strongest boundary merged inside it already (by [`coarsen`]; empty when none was).
pub fn merge(
    sums: Vec<SegmentSums>,
    inner: Vec<f64>,
    boundaries: impl IntoIterator<Item = (u32, u32, Boundary)>,
    params: &MergeParams,
) -> Hierarchy {
    let n = sums.len();
    let mut m = Merger::new(sums, inner, boundaries, params);
    let mut next_target = n / 2;
    let mut hierarchy = Hierarchy {
        fine: n as u32,
        scales: Vec::new(),
        counts: Vec::new(),
        strengths: vec![vec![f32::INFINITY; n]],
    };
    // Per live segment, the snapshots `(scale, label)` it still is (not merged since).
    let mut open: Vec<Vec<(u32, u32)>> = (0..n as u32).map(|f| vec![(0, f)]).collect();
    let record = |m: &mut Merger<'_>, h: &mut Hierarchy, open: &mut [Vec<(u32, u32)>]| {
        let scale = h.scales.len() as u32 + 1;
        let (labels, roots) = m.labels();
        for (label, &r) in roots.iter().enumerate() {
            open[r].push((scale, label as u32));
        }
        let count = roots.len() as u32;
        h.scales.push(labels);
        h.counts.push(count);
        h.strengths.push(vec![f32::INFINITY; count as usize]);
    };
    // Merging goes on to the end (every segment's strength); scales are recorded while at
    // least two segments remain.
    while m.live > 1 {
        let Some(merged) = m.step() else { break };
        // The two segments end here.
        for (r, inner) in merged.ended {
            for (scale, label) in open[r].drain(..) {
                hierarchy.strengths[scale as usize][label as usize] =
                    (merged.strength - inner) as f32;
            }
        }
        if m.live <= next_target && next_target >= 2 {
            record(&mut m, &mut hierarchy, &mut open);
            next_target = m.live / 2;
        }
    }
    // Merging stopped early (separate surfaces): the components are the coarsest scale.
    let last = hierarchy.counts.last().map_or(n, |&c| c as usize);
    if m.live < last && m.live >= 2 {
        record(&mut m, &mut hierarchy, &mut open);
    }
    hierarchy
}

/// Segments merged by [`coarsen`].
#[derive(Debug, Clone, PartialEq)]
pub struct Coarsened {
    /// Per input segment, its merged segment (numbered in order of first input member).
    pub labels: Vec<u32>,
    /// Per merged segment, its sums.
    pub sums: Vec<SegmentSums>,
    /// Per merged segment, the strongest boundary merged inside it.
    pub inner: Vec<f64>,
    /// Boundaries between merged segments `(a, b)`, `a < b`, sorted.
    pub boundaries: Vec<(u32, u32, Boundary)>,
}

/// Merges as [`merge`] does, cheapest pair first, until at most `target` segments are left
/// (or no neighbours are): the first stage of the merge, run on one bucket of a large scan so
/// that what reaches the global merge fits its working set ([`super::collect`]). Merging a
/// bucket alone is the global merge restricted to pairs inside the bucket: costs depend only
/// on the two segments and their shared boundary.
pub fn coarsen(
    sums: Vec<SegmentSums>,
    boundaries: impl IntoIterator<Item = (u32, u32, Boundary)>,
    params: &MergeParams,
    target: usize,
) -> Coarsened {
    let mut m = Merger::new(sums, Vec::new(), boundaries, params);
    while m.live > target.max(1) {
        if m.step().is_none() {
            break;
        }
    }
    let (labels, roots) = m.labels();
    let mut boundaries = Vec::new();
    for (i, &r) in roots.iter().enumerate() {
        for (o, bd) in m.adjacency[r].iter() {
            // A neighbour is a live segment, so its own root: its label is the set's.
            let j = labels[o as usize];
            if (i as u32) < j {
                boundaries.push((i as u32, j, *bd));
            }
        }
    }
    boundaries.sort_unstable_by_key(|&(a, b, _)| (a, b));
    Coarsened {
        labels,
        sums: roots.iter().map(|&r| m.sums[r]).collect(),
        inner: roots.iter().map(|&r| m.inner[r]).collect(),
        boundaries,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_queue_pops_in_the_order_of_costs_then_pairs() {
        // Costs with many ties (and negative, infinite and NaN ones), pushes interleaved with
        // pops as the merge does them: what comes out is what sorting by (cost, a, b) gives.
        let mut next = crate::testing::xorshift(11);
        let mut queue = Queue::default();
        let mut reference: Vec<(f64, u32, u32)> = Vec::new();
        let mut popped = Vec::new();
        let mut expected = Vec::new();
        for round in 0..4000 {
            let r = next();
            let cost = match r % 16 {
                0 => f64::INFINITY,
                1 => -((r % 7) as f64),
                2 => f64::NAN,
                _ => ((r >> 8) % 50) as f64 * 0.25,
            };
            let (a, b) = (next() % 30, next() % 30);
            queue.push(Candidate::new(cost, a, b));
            reference.push((cost, a, b));
            if round % 3 == 2 {
                popped.push(queue.pop().expect("not empty"));
                reference.sort_by(|x, y| x.0.total_cmp(&y.0).then((x.1, x.2).cmp(&(y.1, y.2))));
                let (cost, a, b) = reference.remove(0);
                expected.push(Candidate::new(cost, a, b));
            }
        }
        while let Some(c) = queue.pop() {
            popped.push(c);
        }
        reference.sort_by(|x, y| x.0.total_cmp(&y.0).then((x.1, x.2).cmp(&(y.1, y.2))));
        expected.extend(
            reference
                .iter()
                .map(|&(cost, a, b)| Candidate::new(cost, a, b)),
        );
        assert_eq!(popped, expected);
    }

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
        let h = merge(s, Vec::new(), b, &MergeParams::default());
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
        let h = merge(s, Vec::new(), b, &MergeParams::default());
        // 6 → 4 live after two merges; no scale at 3 (nothing left to merge).
        assert_eq!(h.counts, vec![4]);
        assert_eq!(h.scales[0][0], h.scales[0][1]);
        assert_ne!(h.scales[0][4], h.scales[0][5]);
    }

    /// Coarsening the chain of eight to two stops at the concave boundary, as the full merge
    /// does; its sums add up, its one boundary is that crease, and each half records the
    /// strongest boundary merged inside it, which the merge then carries on.
    #[test]
    fn coarsening_stops_at_its_target_and_keeps_what_the_merge_needs() {
        let s = vec![sums(50, [0.0, 0.0, 1.0]); 8];
        let mut b: Vec<(u32, u32, Boundary)> =
            (0..7u32).map(|i| (i, i + 1, edge(1.0, 0.0, 0.1))).collect();
        b[3].2 = edge(1.0, 0.9, 0.0);
        let c = coarsen(s.clone(), b.clone(), &MergeParams::default(), 2);
        assert_eq!(c.labels, vec![0, 0, 0, 0, 1, 1, 1, 1]);
        assert_eq!(
            c.sums.iter().map(|s| s.vertices).collect::<Vec<_>>(),
            [200, 200]
        );
        assert_eq!(c.boundaries.len(), 1);
        assert_eq!((c.boundaries[0].0, c.boundaries[0].1), (0, 1));
        assert_eq!(c.boundaries[0].2, edge(1.0, 0.9, 0.0));
        assert!(
            c.inner.iter().all(|&x| x > 0.0 && x < 1e-2),
            "{:?}",
            c.inner
        );
        // Nothing to do below the target: the input, renumbered in order.
        let same = coarsen(s.clone(), b.clone(), &MergeParams::default(), 8);
        assert_eq!(same.labels, (0..8).collect::<Vec<u32>>());
        assert_eq!(same.boundaries.len(), 7);
        // The merge of the coarsened halves ends as the merge of the fine chain does, and
        // the halves' strengths are the crease's less what was merged inside them.
        let h = merge(
            c.sums,
            c.inner.clone(),
            c.boundaries,
            &MergeParams::default(),
        );
        let whole = merge(s, Vec::new(), b, &MergeParams::default());
        let half = whole.counts.iter().position(|&n| n == 2).unwrap() + 1;
        assert_eq!(whole.strengths[half], h.strengths[0]);
        assert!((h.strengths[0][0] as f64 - (1e-3 + 4.0 * 0.9 - c.inner[0])).abs() < 1e-6);
    }
}
