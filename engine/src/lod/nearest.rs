//! Closest point on a triangle set: a bounding-volume hierarchy of axis-aligned boxes (median
//! split along the widest axis, four triangles a leaf), queried depth-first with the nearer
//! child first and subtrees pruned by their box distance. The closest point on one triangle is
//! Ericson's region test (*Real-Time Collision Detection*, §5.1.5).
//!
//! Used to resample a finer surface's attributes (texture) onto a coarser one: a query may ask
//! for triangles whose normal agrees with the coarse surface, so a thin sheet (an ear, a leaf)
//! resamples its own side and not the one behind it.

use glam::Vec3;
use smallvec::SmallVec;

const LEAF: usize = 4;

#[derive(Debug, Clone, Copy)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first triangle in `slots` and count; inner: `first` is the left child (the right
    /// one follows its subtree), count 0.
    first: u32,
    count: u32,
    right: u32,
}

/// A BVH over triangles given as corner positions.
pub struct Nearest {
    /// The triangles in leaf order (a leaf's are side by side), each with its box: a leaf's
    /// triangles farther than the best so far by their boxes skip the exact test.
    slots: Vec<Slot>,
    nodes: Vec<Node>,
    /// Each node's parent (the root's is itself), for walks that start at a leaf.
    parent: Vec<u32>,
    /// Per triangle (as given to [`Nearest::new`]): its slot and the leaf holding it.
    slot_of: Vec<u32>,
    leaf_of: Vec<u32>,
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
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let centroids: Vec<Vec3> = tris.iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
        // Each triangle's box once, not its three corners again at every level of the build.
        let boxes: Vec<(Vec3, Vec3)> = tris
            .iter()
            .map(|t| (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])))
            .collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF + 1);
        if !tris.is_empty() {
            build(&boxes, &centroids, &mut order, 0, &mut nodes);
        }
        let mut parent = vec![0u32; nodes.len()];
        let mut leaf_of = vec![0u32; tris.len()];
        for (i, node) in nodes.iter().enumerate() {
            if node.count > 0 {
                let range = node.first as usize..(node.first + node.count) as usize;
                for &t in &order[range] {
                    leaf_of[t as usize] = i as u32;
                }
            } else {
                parent[node.first as usize] = i as u32;
                parent[node.right as usize] = i as u32;
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
            parent,
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
        let filter = facing != Vec3::ZERO;
        let mut best = Best {
            hit: None,
            d: f32::INFINITY,
        };
        let hint = hint.filter(|&t| {
            self.slot_of
                .get(t as usize)
                .is_some_and(|&s| !filter || self.slots[s as usize].normal.dot(facing) >= min_dot)
        });
        let Some(t) = hint else {
            if !self.nodes.is_empty() {
                self.descend(0, p, facing, min_dot, &mut best);
            }
            return best.hit;
        };
        let slot = &self.slots[self.slot_of[t as usize] as usize];
        self.consider(slot, p, &mut best);
        let mut node = self.leaf_of[t as usize];
        self.descend(node, p, facing, min_dot, &mut best);
        while node != 0 {
            let up = self.parent[node as usize];
            let parent = &self.nodes[up as usize];
            let sibling = if parent.first == node {
                parent.right
            } else {
                parent.first
            };
            let s = &self.nodes[sibling as usize];
            if box_distance_sq(p, s.lo, s.hi) < best.d {
                self.descend(sibling, p, facing, min_dot, &mut best);
            }
            node = up;
        }
        best.hit
    }

    /// Tests the triangle in `slot`, keeping it where it is nearer than the best so far.
    #[inline]
    fn consider(&self, slot: &Slot, p: Vec3, best: &mut Best) {
        let (q, bary) = closest_on_triangle(p, &slot.corners);
        let d = (q - p).length_squared();
        if d < best.d {
            best.d = d;
            best.hit = Some(Hit {
                triangle: slot.id,
                bary,
                distance_sq: d,
            });
        }
    }

    /// Searches the subtree at `root` depth-first, the nearer child first, pruning subtrees
    /// no nearer than the best so far.
    fn descend(&self, root: u32, p: Vec3, facing: Vec3, min_dot: f32, best: &mut Best) {
        let filter = facing != Vec3::ZERO;
        // The walk holds about one entry a level of a median-split tree: on the stack, with
        // no allocation per query.
        let mut stack: SmallVec<[u32; 64]> = SmallVec::new();
        stack.push(root);
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i as usize];
            if box_distance_sq(p, node.lo, node.hi) >= best.d {
                continue;
            }
            if node.count > 0 {
                let range = node.first as usize..(node.first + node.count) as usize;
                for slot in &self.slots[range] {
                    if filter && slot.normal.dot(facing) < min_dot
                        || box_distance_sq(p, slot.lo, slot.hi) >= best.d
                    {
                        continue;
                    }
                    self.consider(slot, p, best);
                }
                continue;
            }
            let (l, r) = (node.first, node.right);
            let dl = box_distance_sq(p, self.nodes[l as usize].lo, self.nodes[l as usize].hi);
            let dr = box_distance_sq(p, self.nodes[r as usize].lo, self.nodes[r as usize].hi);
            // Nearer child popped first; a child no nearer than the best is not pushed.
            let (near, far, dn, df) = if dl <= dr {
                (l, r, dl, dr)
            } else {
                (r, l, dr, dl)
            };
            if df < best.d {
                stack.push(far);
            }
            if dn < best.d {
                stack.push(near);
            }
        }
    }
}

/// The nearest hit so far and its squared distance.
struct Best {
    hit: Option<Hit>,
    d: f32,
}

fn build(
    boxes: &[(Vec3, Vec3)],
    centroids: &[Vec3],
    order: &mut [u32],
    first: u32,
    nodes: &mut Vec<Node>,
) -> u32 {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for &t in order.iter() {
        let (l, h) = boxes[t as usize];
        lo = lo.min(l);
        hi = hi.max(h);
    }
    let id = nodes.len() as u32;
    nodes.push(Node {
        lo,
        hi,
        first,
        count: order.len() as u32,
        right: 0,
    });
    if order.len() <= LEAF {
        return id;
    }
    let extent = hi - lo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mid = order.len() / 2;
    order.select_nth_unstable_by(mid, |&a, &b| {
        centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
    });
    let (left, right) = order.split_at_mut(mid);
    let l = build(boxes, centroids, left, first, nodes);
    let r = build(boxes, centroids, right, first + mid as u32, nodes);
    nodes[id as usize].first = l;
    nodes[id as usize].count = 0;
    nodes[id as usize].right = r;
    id
}

fn box_distance_sq(p: Vec3, lo: Vec3, hi: Vec3) -> f32 {
    let d = (lo - p).max(p - hi).max(Vec3::ZERO);
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
