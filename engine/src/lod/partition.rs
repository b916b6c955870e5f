//! Feature-following partition of a triangle set into patches of at most N triangles.
//!
//! Two steps, as in the system paper §3.1.1 ("over-partitioning ... then graph partitioning
//! with METIS, edge weight = inner product of the parts' mean normals"), with the
//! over-partition made feature-aware:
//! 1. Region growing into small segments of similarly oriented triangles: a triangle joins a
//!    segment when its angle to every triangle already in it is at most δ (Kim, Yun, Lee,
//!    "Multi-Resolution Modeling Technique Using Mesh Segmentation", §3.1, eq. 1; the maximum
//!    angle is bounded through the segment's normal cone).
//! 2. METIS k-way on the segment graph: vertex weight = triangles, edge weight = shared edge
//!    count × normal similarity × colour similarity, so cuts run along creases and colour edges.
//!    Parts still above N are split again; every part ends within the budget.

use glam::Vec3;
use metis::Idx;

use super::patch::{ByVertex, edge_users, sort_small};

/// Largest segment of step 1, in triangles.
const SEGMENT_MAX: usize = 192;
/// Segments below this size grow with twice the angle limit, so noisy scans still coarsen
/// while sharp creases still stop them.
const SEGMENT_MIN: usize = 24;
/// δ of eq. 1.
const SEGMENT_ANGLE_DEG: f32 = 35.0;
/// METIS aims at parts this much below the budget to leave room for imbalance.
const FILL: f64 = 0.88;

/// Geometry to partition: local positions, optional colours, three indices per triangle.
pub struct Triangles<'a> {
    pub positions: &'a [[f32; 3]],
    pub colors: &'a [[u8; 4]],
    pub indices: &'a [u32],
}

/// Assigns each triangle a part in `0..parts`; every part has at most `max_triangles`
/// triangles and at least one. Returns (part per triangle, number of parts).
pub fn partition(tris: &Triangles<'_>, max_triangles: usize) -> (Vec<u32>, usize) {
    let tri_count = tris.indices.len() / 3;
    let max_triangles = max_triangles.max(1);
    if tri_count <= max_triangles {
        return (vec![0; tri_count], usize::from(tri_count > 0));
    }
    let adjacency = triangle_adjacency(tris.indices);
    let normals = triangle_normals(tris);
    let segment_cap = SEGMENT_MAX.min((max_triangles / 4).max(1));
    let (segment_of, segment_count) = grow_segments(&adjacency, &normals, segment_cap);
    let graph = segment_graph(tris, &adjacency, &normals, &segment_of, segment_count);
    let part_of_segment = partition_graph(&graph, max_triangles);
    let mut part: Vec<u32> = segment_of
        .iter()
        .map(|&s| part_of_segment[s as usize])
        .collect();
    let count = compact_labels(&mut part);
    (part, count)
}

/// Triangle neighbours across edges in CSR form (non-manifold edges link consecutive users).
struct Adjacency {
    offsets: Vec<u32>,
    neighbours: Vec<u32>,
}

fn triangle_adjacency(indices: &[u32]) -> Adjacency {
    let tri_count = indices.len() / 3;
    // The users of each edge, each a run in triangle order.
    let (start, half) = edge_users(indices);
    let n = start.len() - 1;
    let mut degree = vec![0u32; tri_count + 1];
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(tri_count * 3 / 2);
    for lo in 0..n {
        let around = &half[start[lo] as usize..start[lo + 1] as usize];
        for users in around.chunk_by(|x, y| x >> 32 == y >> 32) {
            for w in users.windows(2) {
                let (f, g) = (w[0] as u32, w[1] as u32);
                if f != g {
                    pairs.push((f, g));
                    degree[f as usize] += 1;
                    degree[g as usize] += 1;
                }
            }
        }
    }
    let mut offsets = vec![0u32; tri_count + 1];
    for t in 0..tri_count {
        offsets[t + 1] = offsets[t] + degree[t];
    }
    let mut fill = offsets.clone();
    let mut neighbours = vec![0u32; offsets[tri_count] as usize];
    for (a, b) in pairs {
        neighbours[fill[a as usize] as usize] = b;
        fill[a as usize] += 1;
        neighbours[fill[b as usize] as usize] = a;
        fill[b as usize] += 1;
    }
    Adjacency {
        offsets,
        neighbours,
    }
}

impl Adjacency {
    fn of(&self, t: usize) -> &[u32] {
        &self.neighbours[self.offsets[t] as usize..self.offsets[t + 1] as usize]
    }
}

/// Unit normal and area of every triangle.
fn triangle_normals(tris: &Triangles<'_>) -> Vec<(Vec3, f32)> {
    tris.indices
        .chunks_exact(3)
        .map(|t| {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| Vec3::from(tris.positions[i as usize]));
            let n = (b - a).cross(c - a);
            let len = n.length();
            if len > 0.0 {
                (n / len, len * 0.5)
            } else {
                (Vec3::ZERO, 0.0)
            }
        })
        .collect()
}

/// Step 1: breadth-first region growing under Kim et al.'s eq. 1.
fn grow_segments(adjacency: &Adjacency, normals: &[(Vec3, f32)], cap: usize) -> (Vec<u32>, usize) {
    let n = normals.len();
    let angle_limit = SEGMENT_ANGLE_DEG.to_radians();
    let mut segment = vec![u32::MAX; n];
    let mut count = 0u32;
    let mut queue = std::collections::VecDeque::new();
    for seed in 0..n {
        if segment[seed] != u32::MAX {
            continue;
        }
        segment[seed] = count;
        let mut axis = normals[seed].0;
        let mut sum = normals[seed].0 * normals[seed].1.max(f32::MIN_POSITIVE);
        // Half-angle of the cone around `axis` containing every member normal.
        let mut spread = 0.0f32;
        let mut size = 1usize;
        queue.clear();
        queue.push_back(seed as u32);
        'grow: while let Some(t) = queue.pop_front() {
            for &nb in adjacency.of(t as usize) {
                if size >= cap {
                    break 'grow;
                }
                let nb = nb as usize;
                if segment[nb] != u32::MAX {
                    continue;
                }
                let (normal, area) = normals[nb];
                // max_j ang(T_j, T_i) <= ang(T_i, axis) + spread  (eq. 1, conservatively)
                let angle = normal.dot(axis).clamp(-1.0, 1.0).acos();
                let limit = if size < SEGMENT_MIN {
                    2.0 * angle_limit
                } else {
                    angle_limit
                };
                if angle + spread > limit {
                    continue;
                }
                segment[nb] = count;
                size += 1;
                sum += normal * area.max(f32::MIN_POSITIVE);
                // The cone must still hold every member after its axis moves by `shift`.
                let new_axis = sum.normalize_or_zero();
                let shift = if new_axis != Vec3::ZERO {
                    new_axis.dot(axis).clamp(-1.0, 1.0).acos()
                } else {
                    0.0
                };
                spread = spread.max(angle) + shift;
                if new_axis != Vec3::ZERO {
                    axis = new_axis;
                }
                queue.push_back(nb as u32);
            }
        }
        count += 1;
    }
    (segment, count as usize)
}

/// Weighted segment graph in METIS CSR form.
struct Graph {
    xadj: Vec<Idx>,
    adjncy: Vec<Idx>,
    adjwgt: Vec<Idx>,
    vwgt: Vec<Idx>,
    /// Centroids for the spatial fallback.
    centroids: Vec<Vec3>,
}

fn segment_graph(
    tris: &Triangles<'_>,
    adjacency: &Adjacency,
    normals: &[(Vec3, f32)],
    segment_of: &[u32],
    count: usize,
) -> Graph {
    let mut weight = vec![0 as Idx; count];
    let mut normal_sum = vec![Vec3::ZERO; count];
    let mut color_sum = vec![Vec3::ZERO; count];
    let mut centroid_sum = vec![Vec3::ZERO; count];
    let has_colors = !tris.colors.is_empty();
    for (t, tri) in tris.indices.chunks_exact(3).enumerate() {
        let s = segment_of[t] as usize;
        weight[s] += 1;
        normal_sum[s] += normals[t].0 * normals[t].1;
        let mut c = Vec3::ZERO;
        for &i in tri {
            centroid_sum[s] += Vec3::from(tris.positions[i as usize]) / 3.0;
            if has_colors {
                let col = tris.colors[i as usize];
                c += Vec3::new(col[0] as f32, col[1] as f32, col[2] as f32) / (3.0 * 255.0);
            }
        }
        color_sum[s] += c;
    }
    let mean_normal: Vec<Vec3> = normal_sum.iter().map(|n| n.normalize_or_zero()).collect();
    let mean_color: Vec<Vec3> = color_sum
        .iter()
        .zip(&weight)
        .map(|(c, &w)| *c / (w.max(1) as f32))
        .collect();
    let centroids: Vec<Vec3> = centroid_sum
        .iter()
        .zip(&weight)
        .map(|(c, &w)| *c / (w.max(1) as f32))
        .collect();

    // Shared-edge counts between segments: each segment's neighbours across its triangles'
    // edges, grouped by segment and each list sorted alone (the same runs, in the same order,
    // as sorting every (segment, neighbour) pair).
    let links = (0..segment_of.len()).flat_map(|t| {
        let s = segment_of[t];
        adjacency.of(t).iter().filter_map(move |&nb| {
            let o = segment_of[nb as usize];
            (o != s).then_some((s, o))
        })
    });
    let mut across = ByVertex::new(count, links);
    let mut xadj = vec![0 as Idx; count + 1];
    let mut adjncy = Vec::new();
    let mut adjwgt = Vec::new();
    for s in 0..count {
        let neighbours = across.of_mut(s as u32);
        sort_small(neighbours);
        for run in neighbours.chunk_by(|x, y| x == y) {
            let o = run[0] as usize;
            let shared = run.len() as f32;
            // System paper §3.1.1: W_E = n_i · n_j, mapped to positive integers and sharpened
            // so METIS prefers cutting across creases; colour edges are cut preferentially too.
            let similarity = ((1.0 + mean_normal[s].dot(mean_normal[o])) * 0.5).powi(4);
            let color_similarity = if has_colors {
                (-(mean_color[s] - mean_color[o]).length() * 4.0).exp()
            } else {
                1.0
            };
            let w = (shared * (1.0 + 31.0 * similarity * color_similarity))
                .round()
                .max(1.0);
            adjncy.push(o as Idx);
            adjwgt.push(w as Idx);
        }
        xadj[s + 1] = adjncy.len() as Idx;
    }
    Graph {
        xadj,
        adjncy,
        adjwgt,
        vwgt: weight,
        centroids,
    }
}

/// Step 2: METIS k-way, then recursive re-splitting of any part over budget.
fn partition_graph(graph: &Graph, max_triangles: usize) -> Vec<u32> {
    let n = graph.vwgt.len();
    let all: Vec<u32> = (0..n as u32).collect();
    let mut labels = vec![0u32; n];
    let mut next_label = 0u32;
    let mut stack = vec![all];
    while let Some(nodes) = stack.pop() {
        let total: i64 = nodes.iter().map(|&v| graph.vwgt[v as usize] as i64).sum();
        if total as usize <= max_triangles || nodes.len() == 1 {
            for &v in &nodes {
                labels[v as usize] = next_label;
            }
            next_label += 1;
            continue;
        }
        let parts = ((total as f64) / (max_triangles as f64 * FILL))
            .ceil()
            .max(2.0) as usize;
        let assignment = metis_subgraph(graph, &nodes, parts)
            .unwrap_or_else(|| spatial_split(graph, &nodes, parts));
        let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); parts];
        for (k, &v) in nodes.iter().enumerate() {
            buckets[(assignment[k] as usize).min(parts - 1)].push(v);
        }
        let non_empty = buckets.iter().filter(|b| !b.is_empty()).count();
        if non_empty <= 1 {
            // METIS made no progress (e.g. one huge segment set): force a spatial split.
            let assignment = spatial_split(graph, &nodes, parts);
            buckets = vec![Vec::new(); parts];
            for (k, &v) in nodes.iter().enumerate() {
                buckets[assignment[k] as usize].push(v);
            }
        }
        stack.extend(buckets.into_iter().filter(|b| !b.is_empty()));
    }
    labels
}

/// METIS (through GKlib) keeps its random number generator in unsynchronised global state:
/// concurrent calls race on it, which makes results depend on thread timing and can read out
/// of bounds. Every METIS call in the process goes through this lock.
pub static METIS_LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// METIS on the subgraph induced by `nodes`; `None` if METIS refuses.
fn metis_subgraph(graph: &Graph, nodes: &[u32], parts: usize) -> Option<Vec<Idx>> {
    let mut local =
        rustc_hash::FxHashMap::with_capacity_and_hasher(nodes.len(), Default::default());
    for (k, &v) in nodes.iter().enumerate() {
        local.insert(v, k as Idx);
    }
    let mut xadj = Vec::with_capacity(nodes.len() + 1);
    let mut adjncy = Vec::new();
    let mut adjwgt = Vec::new();
    let mut vwgt = Vec::with_capacity(nodes.len());
    xadj.push(0 as Idx);
    for &v in nodes {
        let v = v as usize;
        for e in graph.xadj[v] as usize..graph.xadj[v + 1] as usize {
            if let Some(&o) = local.get(&(graph.adjncy[e] as u32)) {
                adjncy.push(o);
                adjwgt.push(graph.adjwgt[e]);
            }
        }
        xadj.push(adjncy.len() as Idx);
        vwgt.push(graph.vwgt[v].max(1));
    }
    let mut part = vec![0 as Idx; nodes.len()];
    let ubvec = [1.06 as metis::Real];
    let _metis = METIS_LOCK
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    let result = metis::Graph::new(1, parts as Idx, &xadj, &adjncy)
        .ok()?
        .set_vwgt(&vwgt)
        .set_adjwgt(&adjwgt)
        .set_ubvec(&ubvec)
        .set_option(metis::option::Seed(7))
        .part_kway(&mut part);
    result.ok().map(|_| part)
}

/// Fallback: sort by centroid along the widest axis and cut into equal-weight runs.
fn spatial_split(graph: &Graph, nodes: &[u32], parts: usize) -> Vec<Idx> {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for &v in nodes {
        lo = lo.min(graph.centroids[v as usize]);
        hi = hi.max(graph.centroids[v as usize]);
    }
    let extent = hi - lo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mut order: Vec<usize> = (0..nodes.len()).collect();
    order.sort_by(|&a, &b| {
        graph.centroids[nodes[a] as usize][axis]
            .total_cmp(&graph.centroids[nodes[b] as usize][axis])
    });
    let total: i64 = nodes.iter().map(|&v| graph.vwgt[v as usize] as i64).sum();
    let per_part = (total as f64 / parts as f64).max(1.0);
    let mut out = vec![0 as Idx; nodes.len()];
    let mut acc = 0i64;
    for k in order {
        let part = ((acc as f64 / per_part) as usize).min(parts - 1);
        out[k] = part as Idx;
        acc += graph.vwgt[nodes[k] as usize] as i64;
    }
    out
}

/// Renumbers labels densely in order of first appearance; returns the label count.
fn compact_labels(labels: &mut [u32]) -> usize {
    // Labels are parts (a few per thousand triangles): a table indexed by label, where the
    // largest is not far beyond the count, instead of hashing every triangle's.
    let top = labels.iter().copied().max().map_or(0, |m| m as usize + 1);
    if top <= labels.len() + 1024 {
        let mut new_of = vec![u32::MAX; top];
        let mut count = 0u32;
        for l in labels.iter_mut() {
            let slot = &mut new_of[*l as usize];
            if *slot == u32::MAX {
                *slot = count;
                count += 1;
            }
            *l = *slot;
        }
        return count as usize;
    }
    let mut map = rustc_hash::FxHashMap::default();
    for l in labels.iter_mut() {
        let next = map.len() as u32;
        *l = *map.entry(*l).or_insert(next);
    }
    map.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both paths of the relabelling (a table for small labels, a map for spread ones) number
    /// labels densely in order of first appearance.
    #[test]
    fn compact_labels_numbers_by_first_appearance_on_both_paths() {
        let mut next = crate::testing::xorshift(0x9e37_79b9);
        let labels: Vec<u32> = (0..5000).map(|_| next() % 300).collect();
        let mut first_seen: Vec<u32> = Vec::new();
        let expected: Vec<u32> = labels
            .iter()
            .map(|l| match first_seen.iter().position(|x| x == l) {
                Some(k) => k as u32,
                None => {
                    first_seen.push(*l);
                    (first_seen.len() - 1) as u32
                }
            })
            .collect();
        let mut small = labels.clone();
        assert_eq!(compact_labels(&mut small), first_seen.len());
        assert_eq!(small, expected);
        // Spread far beyond the count: the map's path.
        let mut spread: Vec<u32> = labels.iter().map(|&l| l * 10_000_000).collect();
        assert_eq!(compact_labels(&mut spread), first_seen.len());
        assert_eq!(spread, expected);
        assert_eq!(compact_labels(&mut []), 0);
    }

    /// The counting sort links the same neighbours in the same order as sorting every
    /// (edge key, triangle) pair, also across a non-manifold edge and a repeated triangle.
    #[test]
    fn adjacency_equals_the_sorted_pairs() {
        let indices: Vec<u32> = vec![
            0, 1, 2, 2, 1, 3, 1, 0, 2, 1, 3, 4, 3, 1, 5, 6, 2, 3, 7, 3, 6, 4, 7, 6, 2, 6, 8,
        ];
        let tri_count = indices.len() / 3;
        let mut half: Vec<(u64, u32)> = Vec::new();
        for (t, tri) in indices.chunks_exact(3).enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                half.push((((a.min(b) as u64) << 32) | a.max(b) as u64, t as u32));
            }
        }
        half.sort_unstable();
        let mut expected: Vec<Vec<u32>> = vec![Vec::new(); tri_count];
        for run in half.chunk_by(|x, y| x.0 == y.0) {
            for w in run.windows(2) {
                if w[0].1 != w[1].1 {
                    expected[w[0].1 as usize].push(w[1].1);
                    expected[w[1].1 as usize].push(w[0].1);
                }
            }
        }
        let adjacency = triangle_adjacency(&indices);
        for (t, want) in expected.iter().enumerate() {
            assert_eq!(adjacency.of(t), want.as_slice(), "triangle {t}");
        }
        // (1, 3, 4) meets two triangles across the non-manifold edge (1, 3), and no other.
        assert_eq!(adjacency.of(3), &[1, 4]);
    }

    /// A folded sheet: two flat halves meeting at a sharp crease along x = 0.
    fn folded_sheet(n: usize) -> (Vec<[f32; 3]>, Vec<u32>) {
        let mut pos = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                let fx = x as f32 / n as f32 * 2.0 - 1.0;
                pos.push([fx, y as f32 / n as f32 * 2.0, fx.abs()]);
            }
        }
        let row = n as u32 + 1;
        let mut idx = Vec::new();
        for y in 0..n as u32 {
            for x in 0..n as u32 {
                let i = y * row + x;
                idx.extend_from_slice(&[i, i + 1, i + row + 1, i, i + row + 1, i + row]);
            }
        }
        (pos, idx)
    }

    #[test]
    fn parts_respect_budget_and_cover_everything() {
        let (pos, idx) = folded_sheet(80);
        let tris = Triangles {
            positions: &pos,
            colors: &[],
            indices: &idx,
        };
        let (part, count) = partition(&tris, 1000);
        assert_eq!(part.len(), idx.len() / 3);
        let mut sizes = vec![0usize; count];
        for &p in &part {
            sizes[p as usize] += 1;
        }
        assert!(sizes.iter().all(|&s| s > 0 && s <= 1000), "{sizes:?}");
        assert!(count >= 13);
    }

    #[test]
    fn cuts_follow_the_crease() {
        let (pos, idx) = folded_sheet(64);
        let tris = Triangles {
            positions: &pos,
            colors: &[],
            indices: &idx,
        };
        let (part, _) = partition(&tris, 4096);
        // Count parts that straddle the crease (triangles on both sides).
        let mut sides: std::collections::HashMap<u32, (bool, bool)> = Default::default();
        for (t, tri) in idx.chunks(3).enumerate() {
            let cx: f32 = tri.iter().map(|&i| pos[i as usize][0]).sum::<f32>() / 3.0;
            let e = sides.entry(part[t]).or_default();
            if cx < 0.0 {
                e.0 = true;
            } else {
                e.1 = true;
            }
        }
        let straddling = sides.values().filter(|(l, r)| *l && *r).count();
        assert!(
            straddling <= 1,
            "{straddling} of {} parts cross the crease",
            sides.len()
        );
    }
}
