//! Closest point on a triangle set: a bounding-volume hierarchy of axis-aligned boxes, queried
//! depth-first with the nearer child first and subtrees pruned by their box distance. The
//! closest point on one triangle is Ericson's region test (*Real-Time Collision Detection*,
//! §5.1.5).
//!
//! The tree is built on the Z curve (Karras, *Maximizing Parallelism in the Construction of
//! BVHs, Octrees, and k-d Trees*, HPG 2012): the triangles sorted by the Morton codes of their
//! boxes' centres, each node split where its codes first differ, eight triangles a leaf. One
//! sort of integers replaces a median selection at every level (the build runs once per group
//! of every level of a textured build, over its finer patches). Each inner node holds both
//! children's boxes, one cache line, so a walk reads one node to choose between them; the
//! walk's stack carries each entry's box distance. On the generated relief of 4M triangles
//! (`meshwiki-bench textures synth:4000000` under `perf`), this module's functions took 14.0%
//! of a textured build's CPU samples with a tree split at the median centroid along the
//! widest axis, four triangles a leaf, each node holding its own box (and its median
//! selections, counted apart, about 2% more); 11.1% with this one.
//!
//! Used to resample a finer surface's attributes (texture) onto a coarser one: a query may ask
//! for triangles whose normal agrees with the coarse surface, so a thin sheet (an ear, a leaf)
//! resamples its own side and not the one behind it.

use glam::{Vec3, Vec3A};
use smallvec::SmallVec;

const LEAF: usize = 8;

/// An inner node: both children's boxes (a walk reads one node to choose between them, one
/// cache line) and references to them.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
struct Node {
    lo: [Vec3; 2],
    hi: [Vec3; 2],
    child: [Child; 2],
}

/// A child: an inner node's index, or a leaf's first slot and triangle count.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Child {
    index: u32,
    /// [`INNER`] for an inner node.
    count: u32,
}

const INNER: u32 = u32::MAX;

impl Child {
    fn inner(index: u32) -> Child {
        Child {
            index,
            count: INNER,
        }
    }

    fn leaf(first: u32, count: u32) -> Child {
        Child {
            index: first,
            count,
        }
    }

    /// The leaf's slot range, or `None` for an inner node.
    #[inline]
    fn slots(self) -> Option<std::ops::Range<usize>> {
        (self.count != INNER).then(|| self.index as usize..(self.index + self.count) as usize)
    }
}

/// A BVH over triangles given as corner positions.
pub struct Nearest {
    /// The triangles in leaf order (a leaf's are side by side), each with its box: a leaf's
    /// triangles farther than the best so far by their boxes skip the exact test.
    slots: Vec<Slot>,
    /// Inner nodes, the root first (a set of at most [`LEAF`] triangles has one, its second
    /// child an empty leaf).
    nodes: Vec<Node>,
    /// Each inner node's parent and which child of it the node is (the root's: itself, 0),
    /// for walks that start at a leaf.
    up: Vec<(u32, u8)>,
    /// Per triangle (as given to [`Nearest::new`]): its slot, and the inner node holding its
    /// leaf with the leaf's side there.
    slot_of: Vec<u32>,
    leaf_of: Vec<(u32, u8)>,
}

#[derive(Debug, Clone, Copy)]
struct Slot {
    corners: [Vec3; 3],
    normal: Vec3,
    lo: Vec3,
    hi: Vec3,
    /// The triangle's index as given to [`Nearest::new`].
    id: u32,
}

/// The closest point found: triangle index (as given to [`Nearest::new`]), its barycentric
/// coordinates and the squared distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub triangle: u32,
    pub bary: [f32; 3],
    pub distance_sq: f32,
}

impl Nearest {
    /// Corner positions of triangle `t` (as given to [`Nearest::new`]).
    pub fn triangle(&self, t: u32) -> Option<&[Vec3; 3]> {
        let slot = *self.slot_of.get(t as usize)?;
        Some(&self.slots[slot as usize].corners)
    }

    pub fn new(tris: Vec<[Vec3; 3]>) -> Nearest {
        let normals: Vec<Vec3> = tris
            .iter()
            .map(|t| (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero())
            .collect();
        let boxes: Vec<(Vec3, Vec3)> = tris
            .iter()
            .map(|t| (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])))
            .collect();
        let mut nodes = Vec::with_capacity(tris.len() / LEAF + 1);
        let mut order: Vec<u32> = Vec::new();
        if !boxes.is_empty() {
            let all = union(boxes.iter().copied());
            let keys = morton_keys(&boxes, all);
            order = keys.iter().map(|&k| k as u32).collect();
            if order.len() <= LEAF {
                nodes.push(Node {
                    lo: [all.0, EMPTY_BOX.0],
                    hi: [all.1, EMPTY_BOX.1],
                    child: [Child::leaf(0, order.len() as u32), Child::leaf(0, 0)],
                });
            } else {
                let tree = Tree {
                    boxes: &boxes,
                    keys: &keys,
                };
                tree.build(0, keys.len(), &mut nodes);
            }
        }
        let mut up = vec![(0u32, 0u8); nodes.len()];
        let mut leaf_of = vec![(0u32, 0u8); tris.len()];
        for (i, node) in nodes.iter().enumerate() {
            for (side, &c) in node.child.iter().enumerate() {
                match c.slots() {
                    Some(range) => {
                        for &t in &order[range] {
                            leaf_of[t as usize] = (i as u32, side as u8);
                        }
                    }
                    None => up[c.index as usize] = (i as u32, side as u8),
                }
            }
        }
        let mut slot_of = vec![0u32; tris.len()];
        for (i, &t) in order.iter().enumerate() {
            slot_of[t as usize] = i as u32;
        }
        let slots = order
            .iter()
            .map(|&t| Slot {
                corners: tris[t as usize],
                normal: normals[t as usize],
                lo: boxes[t as usize].0,
                hi: boxes[t as usize].1,
                id: t,
            })
            .collect();
        Nearest {
            slots,
            nodes,
            up,
            slot_of,
            leaf_of,
        }
    }

    /// The closest point to `p` on a triangle whose unit normal `n_t` has `n_t · facing >=
    /// min_dot` (any triangle when `facing` is zero). `None` when no triangle qualifies.
    pub fn closest(&self, p: Vec3, facing: Vec3, min_dot: f32) -> Option<Hit> {
        self.closest_near(p, facing, min_dot, None)
    }

    /// [`Nearest::closest`], first trying triangle `hint` (the previous query's, when queries
    /// come in coherent order as a texel scan's do). The walk then starts at the hint's leaf
    /// and climbs to the root, searching each sibling subtree whose box is nearer than the
    /// best so far: with the hint's distance as the bound from the start, that is about one
    /// box a level, where a walk down from the root tests both children of every node on the
    /// way. The same distance as without the hint; between triangles exactly as close, the
    /// hint is kept (which of several other equally close triangles wins may differ from a
    /// walk down from the root).
    pub fn closest_near(
        &self,
        p: Vec3,
        facing: Vec3,
        min_dot: f32,
        hint: Option<u32>,
    ) -> Option<Hit> {
        let query = Query {
            p: Vec3A::from(p),
            facing,
            min_dot,
            filter: facing != Vec3::ZERO,
        };
        let mut best = Best {
            hit: None,
            d: f32::INFINITY,
        };
        if self.nodes.is_empty() {
            return None;
        }
        let hint = hint.filter(|&t| {
            self.slot_of.get(t as usize).is_some_and(|&s| {
                !query.filter || self.slots[s as usize].normal.dot(facing) >= min_dot
            })
        });
        let Some(t) = hint else {
            self.descend(Child::inner(0), &query, &mut best);
            return best.hit;
        };
        let slot = &self.slots[self.slot_of[t as usize] as usize];
        self.consider(slot, query.p, &mut best);
        let (mut node, mut side) = self.leaf_of[t as usize];
        let leaf = self.nodes[node as usize].child[side as usize];
        self.descend(leaf, &query, &mut best);
        loop {
            let n = &self.nodes[node as usize];
            let other = 1 - side as usize;
            if box_distance_sq(query.p, n.lo[other], n.hi[other]) < best.d {
                self.descend(n.child[other], &query, &mut best);
            }
            if node == 0 {
                break;
            }
            (node, side) = self.up[node as usize];
        }
        best.hit
    }

    /// Tests the triangle in `slot`, keeping it where it is nearer than the best so far.
    #[inline]
    fn consider(&self, slot: &Slot, p: Vec3A, best: &mut Best) {
        let (q, bary) = closest_on_triangle(Vec3::from(p), &slot.corners);
        let d = (Vec3A::from(q) - p).length_squared();
        if d < best.d {
            best.d = d;
            best.hit = Some(Hit {
                triangle: slot.id,
                bary,
                distance_sq: d,
            });
        }
    }

    /// Searches the subtree `root` depth-first, the nearer child first, pruning subtrees no
    /// nearer than the best so far. Each entry of the walk carries its box distance, so a
    /// node is read only to go below it.
    fn descend(&self, root: Child, q: &Query, best: &mut Best) {
        // The walk holds about one entry a level: on the stack, with no allocation per query.
        let mut stack: SmallVec<[(Child, f32); 64]> = SmallVec::new();
        stack.push((root, 0.0));
        while let Some((c, d)) = stack.pop() {
            if d >= best.d {
                continue;
            }
            if let Some(range) = c.slots() {
                for slot in &self.slots[range] {
                    if q.filter && slot.normal.dot(q.facing) < q.min_dot
                        || box_distance_sq(q.p, slot.lo, slot.hi) >= best.d
                    {
                        continue;
                    }
                    self.consider(slot, q.p, best);
                }
                continue;
            }
            let node = &self.nodes[c.index as usize];
            let dl = box_distance_sq(q.p, node.lo[0], node.hi[0]);
            let dr = box_distance_sq(q.p, node.lo[1], node.hi[1]);
            // Nearer child popped first; a child no nearer than the best is not pushed.
            let (near, far) = if dl <= dr {
                ((node.child[0], dl), (node.child[1], dr))
            } else {
                ((node.child[1], dr), (node.child[0], dl))
            };
            if far.1 < best.d {
                stack.push(far);
            }
            if near.1 < best.d {
                stack.push(near);
            }
        }
    }
}

/// A query's point and facing filter.
struct Query {
    p: Vec3A,
    facing: Vec3,
    min_dot: f32,
    filter: bool,
}

/// The nearest hit so far and its squared distance.
struct Best {
    hit: Option<Hit>,
    d: f32,
}

/// Per triangle, the Morton code of its box's centre (10 bits an axis, over the cube of the
/// set's box' largest side) over its index, sorted: the order of a Z curve through the set.
fn morton_keys(boxes: &[(Vec3, Vec3)], (lo, hi): (Vec3, Vec3)) -> Vec<u64> {
    let side = (hi - lo).max_element();
    let scale = if side > 0.0 { 1023.0 / side } else { 0.0 };
    let mut keys: Vec<u64> = boxes
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let c = ((b.0 + b.1) * 0.5 - lo) * scale;
            let q = |v: f32| spread(v.clamp(0.0, 1023.0) as u32);
            let code = q(c.x) | q(c.y) << 1 | q(c.z) << 2;
            u64::from(code) << 32 | i as u64
        })
        .collect();
    keys.sort_unstable();
    keys
}

/// The low 10 bits of `v`, two zero bits between each.
fn spread(v: u32) -> u32 {
    let mut v = v & 0x3ff;
    v = (v | v << 16) & 0x0300_00ff;
    v = (v | v << 8) & 0x0300_f00f;
    v = (v | v << 4) & 0x030c_30c3;
    (v | v << 2) & 0x0924_9249
}

/// The triangles' boxes and sorted Morton keys, while the tree is built.
struct Tree<'a> {
    boxes: &'a [(Vec3, Vec3)],
    keys: &'a [u64],
}

impl Tree<'_> {
    /// Builds the subtree over keys `from..to` (more than [`LEAF`] triangles; slots are in
    /// key order), splitting where the range's codes first differ in their highest bit (the
    /// Z curve's own octree split, Karras 2012), at the middle where they are all equal.
    /// Returns the inner node's index and the range's box.
    fn build(&self, from: usize, to: usize, nodes: &mut Vec<Node>) -> (u32, (Vec3, Vec3)) {
        let code = |k: u64| (k >> 32) as u32;
        let range = &self.keys[from..to];
        let (first, last) = (code(range[0]), code(range[range.len() - 1]));
        let mid = if first == last {
            range.len() / 2
        } else {
            let bit = 31 - (first ^ last).leading_zeros();
            range.partition_point(|&k| code(k) >> bit & 1 == 0)
        };
        let id = nodes.len() as u32;
        let empty = Child::leaf(0, 0);
        nodes.push(Node {
            lo: [Vec3::ZERO; 2],
            hi: [Vec3::ZERO; 2],
            child: [empty; 2],
        });
        let mut all = EMPTY_BOX;
        for (side, (a, b)) in [(from, from + mid), (from + mid, to)]
            .into_iter()
            .enumerate()
        {
            let (child, bounds) = if b - a <= LEAF {
                let bounds = union(
                    self.keys[a..b]
                        .iter()
                        .map(|&k| self.boxes[k as u32 as usize]),
                );
                (Child::leaf(a as u32, (b - a) as u32), bounds)
            } else {
                let (node, bounds) = self.build(a, b, nodes);
                (Child::inner(node), bounds)
            };
            let node = &mut nodes[id as usize];
            node.lo[side] = bounds.0;
            node.hi[side] = bounds.1;
            node.child[side] = child;
            all = union([all, bounds]);
        }
        (id, all)
    }
}

/// The box no point is in (the union's identity; at infinite distance from every point).
const EMPTY_BOX: (Vec3, Vec3) = (Vec3::MAX, Vec3::MIN);

/// The smallest box holding `boxes`.
fn union(boxes: impl IntoIterator<Item = (Vec3, Vec3)>) -> (Vec3, Vec3) {
    boxes
        .into_iter()
        .fold(EMPTY_BOX, |(lo, hi), b| (lo.min(b.0), hi.max(b.1)))
}

#[inline]
fn box_distance_sq(p: Vec3A, lo: Vec3, hi: Vec3) -> f32 {
    let d = (Vec3A::from(lo) - p)
        .max(p - Vec3A::from(hi))
        .max(Vec3A::ZERO);
    d.length_squared()
}

/// Closest point on triangle `t` to `p`, with its barycentric coordinates.
pub fn closest_on_triangle(p: Vec3, t: &[Vec3; 3]) -> (Vec3, [f32; 3]) {
    let [a, b, c] = *t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, [1.0, 0.0, 0.0]);
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (b, [0.0, 1.0, 0.0]);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (a + ab * v, [1.0 - v, v, 0.0]);
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (c, [0.0, 0.0, 1.0]);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (a + ac * w, [1.0 - w, 0.0, w]);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + (c - b) * w, [0.0, 1.0 - w, w]);
    }
    let denom = va + vb + vc;
    if denom.abs() <= f32::MIN_POSITIVE || !denom.is_finite() {
        // Degenerate triangle: its first corner.
        return (a, [1.0, 0.0, 0.0]);
    }
    let (v, w) = (vb / denom, vc / denom);
    (a + ab * v + ac * w, [1.0 - v - w, v, w])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(tris: &[[Vec3; 3]], p: Vec3) -> f32 {
        tris.iter()
            .map(|t| (closest_on_triangle(p, t).0 - p).length_squared())
            .fold(f32::INFINITY, f32::min)
    }

    #[test]
    fn agrees_with_brute_force_on_a_wavy_grid() {
        let n = 30;
        let h = |x: f32, y: f32| (x * 0.7).sin() * (y * 0.4).cos();
        let mut tris = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (x, y) = (i as f32, j as f32);
                let q = |dx: f32, dy: f32| Vec3::new(x + dx, y + dy, h(x + dx, y + dy));
                tris.push([q(0.0, 0.0), q(1.0, 0.0), q(1.0, 1.0)]);
                tris.push([q(0.0, 0.0), q(1.0, 1.0), q(0.0, 1.0)]);
            }
        }
        let bvh = Nearest::new(tris.clone());
        let mut rng = crate::testing::xorshift(12345);
        let mut next = || rng() as f32 / u32::MAX as f32;
        for _ in 0..500 {
            let p = Vec3::new(next() * 34.0 - 2.0, next() * 34.0 - 2.0, next() * 6.0 - 3.0);
            let hit = bvh.closest(p, Vec3::ZERO, 0.0).expect("a hit");
            assert!((hit.distance_sq - brute(&tris, p)).abs() < 1e-4);
            let t = tris[hit.triangle as usize];
            let q = t[0] * hit.bary[0] + t[1] * hit.bary[1] + t[2] * hit.bary[2];
            assert!(((q - p).length_squared() - hit.distance_sq).abs() < 1e-3);
            // Any hint, near or far (or out of range), finds the same distance.
            for hint in [hit.triangle, (next() * 1800.0) as u32, 99_999] {
                let near = bvh
                    .closest_near(p, Vec3::ZERO, 0.0, Some(hint))
                    .expect("a hit");
                assert!((near.distance_sq - hit.distance_sq).abs() < 1e-5);
            }
            // A hint facing the wrong way is not taken.
            let up = bvh.closest_near(p, Vec3::Z, 0.5, Some(hit.triangle));
            if let Some(up) = up {
                let t = bvh.triangle(up.triangle).expect("a triangle");
                assert!((t[1] - t[0]).cross(t[2] - t[0]).normalize().z >= 0.5);
                assert_eq!(t, &tris[up.triangle as usize]);
            }
        }
    }

    #[test]
    fn agrees_with_brute_force_on_small_sets_and_mixed_sizes() {
        // Sets of every size around a leaf's (the root alone is a leaf up to LEAF), and
        // triangles from slivers to large ones, in a cluster and far apart, with points
        // repeating one place (equal Morton codes).
        let mut rng = crate::testing::xorshift(777);
        let mut next = || rng() as f32 / u32::MAX as f32;
        for n in 1..=3 * LEAF + 1 {
            let mut tris = Vec::new();
            for k in 0..n {
                let c = if k % 5 == 4 {
                    Vec3::splat(1.0)
                } else {
                    Vec3::new(next(), next(), next()) * 10.0
                };
                let size = [0.01, 0.5, 4.0][k % 3];
                let v = |r: &mut dyn FnMut() -> f32| {
                    c + Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5) * size
                };
                tris.push([v(&mut next), v(&mut next), v(&mut next)]);
            }
            let bvh = Nearest::new(tris.clone());
            for _ in 0..60 {
                let p = Vec3::new(next(), next(), next()) * 14.0 - Vec3::splat(2.0);
                let hit = bvh.closest(p, Vec3::ZERO, 0.0).expect("a hit");
                assert!(
                    (hit.distance_sq - brute(&tris, p)).abs() < 1e-4,
                    "{n} triangles"
                );
                for hint in 0..n as u32 {
                    let near = bvh
                        .closest_near(p, Vec3::ZERO, 0.0, Some(hint))
                        .expect("a hit");
                    assert!((near.distance_sq - hit.distance_sq).abs() < 1e-5);
                }
            }
        }
    }

    #[test]
    fn facing_filter_picks_the_near_side_of_a_thin_sheet() {
        // Two parallel sheets 0.01 apart, facing away from each other.
        let front = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let back = [front[0], front[2], front[1]].map(|v| v - Vec3::Z * 0.01);
        let bvh = Nearest::new(vec![front, back]);
        // Slightly behind the back sheet, but asking for the side facing +Z.
        let p = Vec3::new(0.2, 0.2, -0.011);
        assert_eq!(bvh.closest(p, Vec3::ZERO, 0.0).map(|h| h.triangle), Some(1));
        assert_eq!(bvh.closest(p, Vec3::Z, 0.0).map(|h| h.triangle), Some(0));
        assert!(
            Nearest::new(Vec::new())
                .closest(p, Vec3::ZERO, 0.0)
                .is_none()
        );
    }
}
