//! One DAG step for a group of neighbouring patches (system paper §3.2): merge the patches,
//! lock the group's outer border, simplify with quadric error metrics (Garland–Heckbert, via
//! meshoptimizer) to about half the triangles, measure the result, split it into patches.
//!
//! Locked: every vertex the group shares with patches outside it (so neighbours still fit, even
//! at non-manifold "pinch" vertices that share no edge), and the whole topological border of the
//! merged group (so every cut keeps exactly the scan's boundary edges). Collapses only ever keep
//! input vertices, so every product vertex still carries its original ID.
//!
//! Sound output: simplification creates no non-manifold edge and no duplicate triangle, inside
//! the group or against a neighbour simplified in the same round. The one-ring of the shared
//! vertices is locked as well (no edge at a shared vertex changes, so two groups cannot both
//! join the same pair of shared vertices), the result is checked for edges used more than
//! twice and repeated triangles the input lacked, faces folded onto each other are dropped,
//! and any other defect gets its neighbourhood locked and the group simplified again
//! (`sound_simplification`).

use super::hausdorff::simplification_distance;
use super::partition::{Triangles, partition};
#[cfg(test)]
use super::patch::edge_key;
use super::patch::{BuildPatch, degenerate, edge_runs};
use super::segsimplify::{self, SegmentParams, Simplifier};
use meshopt::{SimplifyOptions, SimplifyVertex, VertexDataAdapter};
use rustc_hash::FxHashMap as HashMap;

/// A group step fails (members stay for the next level) above this triangle ratio.
pub const MIN_REDUCTION: f32 = 0.85;
/// Weight of colour in the quadric, relative to (normalised) geometric error.
const COLOR_WEIGHT: f32 = 0.5;

/// The result of simplifying a group.
pub struct GroupStep {
    /// New patches, each within the triangle budget, together covering the group's surface.
    pub products: Vec<BuildPatch>,
    /// Measured two-sided distance between the simplification and the merged members.
    pub distance: f32,
}

/// The members merged into one indexed mesh (vertices deduplicated by original ID).
pub struct Merged {
    pub patch: BuildPatch,
    /// Per vertex of `patch`, how many members hold it (saturating).
    pub holders: Vec<u8>,
}

/// Concatenates member patches, welding shared vertices by original ID.
pub fn merge(members: &[&BuildPatch]) -> Merged {
    let vertex_hint: usize = members.iter().map(|m| m.ids.len()).sum();
    let mut local: HashMap<u32, u32> =
        HashMap::with_capacity_and_hasher(vertex_hint, Default::default());
    let has_colors = members.iter().all(|m| !m.colors.is_empty());
    let has_normals = members.iter().all(|m| !m.normals.is_empty());
    let mut out = BuildPatch::default();
    let mut holders: Vec<u8> = Vec::with_capacity(vertex_hint);
    for m in members {
        let remap: Vec<u32> = m
            .ids
            .iter()
            .enumerate()
            .map(|(i, &id)| {
                let v = *local.entry(id).or_insert_with(|| {
                    holders.push(0);
                    out.ids.push(id);
                    out.positions.push(m.positions[i]);
                    if has_colors {
                        out.colors.push(m.colors[i]);
                    }
                    if has_normals {
                        out.normals.push(m.normals[i]);
                    }
                    (out.ids.len() - 1) as u32
                });
                holders[v as usize] = holders[v as usize].saturating_add(1);
                v
            })
            .collect();
        out.indices
            .extend(m.indices.iter().map(|&i| remap[i as usize]));
    }
    Merged {
        patch: out,
        holders,
    }
}

/// Simplifies merged group geometry to about half its triangles and splits the result into
/// patches of at most `max_triangles`. `shared_outside[v]` tells whether vertex `v` of the
/// merged patch also belongs to a patch outside the group. `None` when the group cannot be
/// reduced enough (its members then move on to the next level unchanged).
pub fn simplify_group(
    merged: &Merged,
    shared_outside: &[bool],
    max_triangles: usize,
    simplifier: Simplifier,
) -> Option<GroupStep> {
    let mesh = &merged.patch;
    let tri_count = mesh.triangle_count();
    if tri_count < 2 {
        return None;
    }
    let (positions, coincident) = distinct_positions(&mesh.positions);
    let input = Census::of(mesh, &mesh.indices);
    let mut locks = border_locks(mesh, &input.border);
    for (v, lock) in locks.iter_mut().enumerate() {
        // Coincident twins (scanner "zipper" seams) are locked too: collapsing one onto the
        // other would glue two boundary sheets together and change the scan's boundary.
        if coincident[v] || shared_outside[v] {
            *lock = SimplifyVertex::Lock;
        }
    }
    let vertex_bytes: &[u8] = bytemuck::cast_slice(&positions);
    let adapter = VertexDataAdapter::new(vertex_bytes, 12, 0).ok()?;
    let target = (tri_count / 2) * 3;
    let attributes: Vec<f32> = mesh
        .colors
        .iter()
        .flat_map(|c| {
            [
                c[0] as f32 / 255.0,
                c[1] as f32 / 255.0,
                c[2] as f32 / 255.0,
            ]
        })
        .collect();
    let run = |locks: &[SimplifyVertex]| {
        if simplifier == Simplifier::Segments {
            let locked: Vec<bool> = locks.iter().map(|l| *l == SimplifyVertex::Lock).collect();
            return segsimplify::simplify(
                &positions,
                &mesh.indices,
                &locked,
                target,
                &SegmentParams::default(),
            );
        }
        // No `Prune`: it removes small components even through locked vertices, which would
        // tear a group from its neighbours.
        let options = SimplifyOptions::ErrorAbsolute;
        let mut result_error = 0.0f32;
        if attributes.is_empty() {
            meshopt::simplify_with_locks(
                &mesh.indices,
                &adapter,
                locks,
                target,
                f32::MAX,
                options,
                Some(&mut result_error),
            )
        } else {
            meshopt::simplify_with_attributes_and_locks(
                &mesh.indices,
                &adapter,
                &attributes,
                &[COLOR_WEIGHT; 3],
                12,
                locks,
                target,
                f32::MAX,
                options,
                Some(&mut result_error),
            )
        }
    };
    let reduced = |tris: &[u32]| {
        let n = tris.len() / 3;
        n > 0 && n as f32 <= tri_count as f32 * MIN_REDUCTION
    };
    // First with the one-ring of every shared vertex locked too: then no edge at a vertex shared
    // with a neighbour ever changes, so no collapse can join two shared vertices by an edge that
    // the neighbour, simplified at the same time, creates too (a non-manifold edge or a
    // duplicate triangle in the cut holding both), nor change the border through a
    // non-manifold configuration; the strip is simplified at the next level, inside a larger
    // group. Where the strip is too much of a (small, coarse) group for it to halve, again
    // without the ring, every new edge between shared vertices then counting as a defect.
    let simplified = [true, false].into_iter().find_map(|ring| {
        sound_simplification(mesh, locks.clone(), ring, &input, shared_outside, &run)
            .filter(|s| reduced(s))
    })?;
    let mut kept = vec![false; mesh.ids.len()];
    for &i in &simplified {
        kept[i as usize] = true;
    }
    let distance = simplification_distance(&mesh.positions, &mesh.indices, &simplified, &kept);
    if !distance.is_finite() || distance == f32::MAX {
        return None;
    }
    Some(GroupStep {
        products: split(mesh, &simplified, max_triangles),
        distance,
    })
}

/// Simplifies `mesh` under `locks` (plus the one-ring of shared vertices with `ring`), keeping
/// the border of the input (whose census is `input`), until the result has no defect
/// [`new_defects`] finds: a fold of two faces onto each other is dropped, anything else gets
/// the input one-ring of its vertices locked and another run. `None` when the border changes
/// or defects remain after a few rounds.
fn sound_simplification(
    mesh: &BuildPatch,
    mut locks: Vec<SimplifyVertex>,
    ring: bool,
    input: &Census,
    shared_outside: &[bool],
    run: &dyn Fn(&[SimplifyVertex]) -> Vec<u32>,
) -> Option<Vec<u32>> {
    if ring {
        lock_shared_ring(mesh, shared_outside, &mut locks);
    }
    let mut simplified = run(&locks);
    let mut census = Census::of(mesh, &simplified);
    if census.border != input.border {
        // The simplifier changed the border through some non-manifold configuration: lock the
        // one-ring of every locked vertex as well and try again.
        lock_one_ring(mesh, &mut locks);
        simplified = run(&locks);
        census = Census::of(mesh, &simplified);
        if census.border != input.border {
            return None;
        }
    }
    // The input's topology is only needed when the output may have a defect: with the ring
    // locked only an edge used more than twice or a repeated triangle can be one. (On the 5M
    // relief three groups in four have one: a collapse that folds two faces onto each other.)
    let mut before: Option<Topology> = None;
    for _ in 0..=MAX_REPAIR_ROUNDS {
        let overused = census.overused;
        let now = Topology::of(mesh, &simplified, census.edges);
        if ring && !overused && !now.repeats() {
            return Some(simplified);
        }
        let before =
            before.get_or_insert_with(|| Topology::of(mesh, &mesh.indices, input.edges.clone()));
        let mut bad = new_defects(before, &now, shared_outside);
        if bad.is_empty() {
            return Some(simplified);
        }
        // The usual defect is a collapse that folds two faces onto each other (the same three
        // vertices twice): both copies cover no surface, so dropping them repairs it, as long as
        // the border stays and nothing else is wrong.
        if let Some(repaired) = drop_repeated(before, &now, &simplified) {
            let counted = Census::of(mesh, &repaired);
            if counted.border == input.border {
                let after = Topology::of(mesh, &repaired, counted.edges);
                bad = new_defects(before, &after, shared_outside);
                if bad.is_empty() {
                    return Some(repaired);
                }
            }
        }
        lock_around(mesh, &bad, &mut locks);
        simplified = run(&locks);
        census = Census::of(mesh, &simplified);
        if census.border != input.border {
            return None;
        }
    }
    None
}

/// Positions with exact duplicates moved apart by a few ulps, and which vertices had a
/// coincident twin. meshoptimizer derives its topology from positions (it welds coincident
/// vertices); scans contain coincident vertices with distinct IDs, and the topology must be
/// the IDs' or the simplifier opens holes.
fn distinct_positions(positions: &[[f32; 3]]) -> (Vec<[f32; 3]>, Vec<bool>) {
    let mut first: HashMap<[u32; 3], usize> =
        HashMap::with_capacity_and_hasher(positions.len(), Default::default());
    let mut coincident = vec![false; positions.len()];
    let mut out = Vec::with_capacity(positions.len());
    for (i, p) in positions.iter().enumerate() {
        let original = p.map(f32::to_bits);
        // One lookup for the usual distinct point.
        let twin = match first.entry(original) {
            std::collections::hash_map::Entry::Vacant(slot) => {
                slot.insert(i);
                out.push(*p);
                continue;
            }
            std::collections::hash_map::Entry::Occupied(slot) => *slot.get(),
        };
        coincident[twin] = true;
        coincident[i] = true;
        let mut key = original;
        while first.contains_key(&key) {
            key[0] = f32::from_bits(key[0]).next_up().to_bits();
        }
        first.insert(key, i);
        out.push(key.map(f32::from_bits));
    }
    (out, coincident)
}

/// The edge uses of a triangle set over `mesh`'s vertices ([`edge_runs`], every triangle
/// counted), with its border (edges used by exactly one triangle, as sorted keys of local
/// indices) and whether some edge is used by more than two. A merged group has one vertex per
/// original id, so its local topology is the ids' topology. Counted once per triangle set:
/// [`Topology::of`] reuses the uses.
struct Census {
    edges: Vec<(u64, u32)>,
    border: Vec<u64>,
    overused: bool,
}

impl Census {
    fn of(mesh: &BuildPatch, indices: &[u32]) -> Census {
        let edges = edge_runs(indices, mesh.ids.len(), false);
        let mut border = Vec::new();
        let mut overused = false;
        for &(key, uses) in &edges {
            match uses {
                1 => border.push(key),
                2 => {}
                _ => overused = true,
            }
        }
        Census {
            edges,
            border,
            overused,
        }
    }
}

/// Simplification rounds with more locks before a group with defects is left unsimplified.
const MAX_REPAIR_ROUNDS: usize = 4;

/// Edge use counts and repeated triangles of a triangle set, over the group's local indices.
struct Topology {
    /// (edge key, triangles using it), sorted by key.
    edges: Vec<(u64, u32)>,
    /// Triangles (sorted corners) that occur more than once, with their count, sorted.
    repeated: Vec<([u32; 3], u32)>,
}

/// Each distinct triangle of `indices` (corners sorted, below `n`) with its number of
/// occurrences (either orientation), sorted; triangles repeating a corner are left out with
/// `skip_degenerate`. Counting-sorted by the smallest corner, as [`edge_runs`].
fn triangle_runs(indices: &[u32], n: usize, skip_degenerate: bool) -> Vec<([u32; 3], u32)> {
    let sorted = || {
        indices
            .chunks_exact(3)
            .filter(move |t| !(skip_degenerate && degenerate(t)))
            .map(|t| {
                let mut k = [t[0], t[1], t[2]];
                k.sort_unstable();
                k
            })
    };
    let mut start = vec![0u32; n + 1];
    for k in sorted() {
        start[k[0] as usize + 1] += 1;
    }
    for v in 0..n {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    let mut rest = vec![[0u32; 2]; start[n] as usize];
    for k in sorted() {
        let slot = &mut fill[k[0] as usize];
        rest[*slot as usize] = [k[1], k[2]];
        *slot += 1;
    }
    let mut out: Vec<([u32; 3], u32)> = Vec::with_capacity(rest.len());
    for lo in 0..n {
        let others = &mut rest[start[lo] as usize..start[lo + 1] as usize];
        others.sort_unstable();
        for &[b, c] in others.iter() {
            let key = [lo as u32, b, c];
            match out.last_mut() {
                Some((k, count)) if *k == key => *count += 1,
                _ => out.push((key, 1)),
            }
        }
    }
    out
}

impl Topology {
    /// The topology of `indices`, whose [`Census`] counted the edge uses `counted` (these are
    /// the topology's when no triangle is degenerate, as a simplifier's output never is).
    fn of(mesh: &BuildPatch, indices: &[u32], counted: Vec<(u64, u32)>) -> Topology {
        let n = mesh.ids.len();
        let mut repeated = triangle_runs(indices, n, true);
        repeated.retain(|&(_, c)| c > 1);
        let edges = if indices.chunks_exact(3).any(degenerate) {
            edge_runs(indices, n, true)
        } else {
            counted
        };
        Topology { edges, repeated }
    }

    /// Whether a triangle occurs more than once.
    fn repeats(&self) -> bool {
        !self.repeated.is_empty()
    }

    fn edge_count(&self, e: u64) -> u32 {
        self.edges
            .binary_search_by_key(&e, |&(k, _)| k)
            .map_or(0, |i| self.edges[i].1)
    }

    fn repeat_count(&self, t: &[u32; 3]) -> u32 {
        self.repeated
            .binary_search_by_key(t, |&(k, _)| k)
            .map_or(1, |i| self.repeated[i].1)
    }
}

/// Local indices of the vertices of every defect the simplification (topology `now`) created
/// that the input (`before`) did not have:
/// * an edge used by more than two triangles, or a triangle repeated (either orientation);
/// * a new edge between two vertices both shared with patches outside the group: a neighbour
///   simplified in the same round may create the same edge (or the same triangle) on its side,
///   which would make the edge non-manifold (or the triangle duplicate) in the cut that holds
///   both. (The locked one-ring of shared vertices makes this impossible; checked all the same.)
fn new_defects(before: &Topology, now: &Topology, shared_outside: &[bool]) -> Vec<u32> {
    let mut bad = Vec::new();
    for &(e, count) in &now.edges {
        let (a, b) = super::patch::edge_ends(e);
        // Cheap tests first: most edges are used twice and join an interior vertex.
        let suspicious = count > 2 || (shared_outside[a as usize] && shared_outside[b as usize]);
        if !suspicious {
            continue;
        }
        let had = before.edge_count(e);
        if (count > 2 && count > had) || had == 0 {
            bad.extend([a, b]);
        }
    }
    for (t, count) in &now.repeated {
        if *count > before.repeat_count(t) {
            bad.extend_from_slice(t);
        }
    }
    bad.sort_unstable();
    bad.dedup();
    bad
}

/// `after` (topology `now`) without the triangles it repeats (every copy) that `before` did
/// not repeat; `None` when there are none.
fn drop_repeated(before: &Topology, now: &Topology, after: &[u32]) -> Option<Vec<u32>> {
    let extra: Vec<[u32; 3]> = now
        .repeated
        .iter()
        .filter(|(t, c)| *c > before.repeat_count(t))
        .map(|(t, _)| *t)
        .collect();
    if extra.is_empty() {
        return None;
    }
    let mut out = Vec::with_capacity(after.len());
    for tri in after.chunks_exact(3) {
        let mut key = [tri[0], tri[1], tri[2]];
        key.sort_unstable();
        if extra.binary_search(&key).is_err() {
            out.extend_from_slice(tri);
        }
    }
    Some(out)
}

/// Locks the vertices with the given local indices and every vertex of the input triangles
/// around them, so no collapse near them can happen again.
fn lock_around(mesh: &BuildPatch, vertices: &[u32], locks: &mut [SimplifyVertex]) {
    let mut marked = vec![false; mesh.ids.len()];
    for &v in vertices {
        marked[v as usize] = true;
    }
    for t in mesh.indices.chunks_exact(3) {
        if t.iter().any(|&v| marked[v as usize]) {
            for &v in t {
                locks[v as usize] = SimplifyVertex::Lock;
            }
        }
    }
}

/// Locks every vertex adjacent to a vertex shared with a patch outside the group.
fn lock_shared_ring(mesh: &BuildPatch, shared_outside: &[bool], locks: &mut [SimplifyVertex]) {
    for t in mesh.indices.chunks_exact(3) {
        if t.iter().any(|&v| shared_outside[v as usize]) {
            for &v in t {
                locks[v as usize] = SimplifyVertex::Lock;
            }
        }
    }
}

/// Also locks every vertex adjacent to a locked vertex.
fn lock_one_ring(mesh: &BuildPatch, locks: &mut [SimplifyVertex]) {
    let locked: Vec<bool> = locks.iter().map(|l| *l == SimplifyVertex::Lock).collect();
    for t in mesh.indices.chunks_exact(3) {
        if t.iter().any(|&v| locked[v as usize]) {
            for &v in t {
                locks[v as usize] = SimplifyVertex::Lock;
            }
        }
    }
}

/// Lock flags: the vertices of the group's border edges (local keys, [`Census::border`]).
fn border_locks(mesh: &BuildPatch, border: &[u64]) -> Vec<SimplifyVertex> {
    let mut locks = vec![SimplifyVertex::None; mesh.ids.len()];
    for &e in border {
        let (a, b) = super::patch::edge_ends(e);
        locks[a as usize] = SimplifyVertex::Lock;
        locks[b as usize] = SimplifyVertex::Lock;
    }
    locks
}

/// Splits simplified triangles (indexing `mesh`'s vertices) into compact patches.
pub fn split(mesh: &BuildPatch, indices: &[u32], max_triangles: usize) -> Vec<BuildPatch> {
    split_tracked(mesh, indices, max_triangles)
        .into_iter()
        .map(|(p, _)| p)
        .collect()
}

/// [`split`], with each patch's triangles' indices in `indices` (in the patch's order).
pub fn split_tracked(
    mesh: &BuildPatch,
    indices: &[u32],
    max_triangles: usize,
) -> Vec<(BuildPatch, Vec<u32>)> {
    let (parts, count) = partition(
        &Triangles {
            positions: &mesh.positions,
            colors: &mesh.colors,
            indices,
        },
        max_triangles,
    );
    // Each part's triangles in order; its vertices numbered in order of first use, through
    // one slot per group vertex stamped with the part that numbered it last.
    let mut sources: Vec<Vec<u32>> = vec![Vec::new(); count];
    for (t, &p) in parts.iter().enumerate() {
        sources[p as usize].push(t as u32);
    }
    let n = mesh.ids.len();
    let mut stamp = vec![u32::MAX; n];
    let mut slot = vec![0u32; n];
    sources
        .into_iter()
        .enumerate()
        .map(|(p, tris)| {
            let mut patch = BuildPatch::default();
            for &t in &tris {
                for &v in &indices[t as usize * 3..t as usize * 3 + 3] {
                    let v = v as usize;
                    if stamp[v] != p as u32 {
                        stamp[v] = p as u32;
                        slot[v] = patch.ids.len() as u32;
                        patch.ids.push(mesh.ids[v]);
                        patch.positions.push(mesh.positions[v]);
                        if !mesh.colors.is_empty() {
                            patch.colors.push(mesh.colors[v]);
                        }
                        if !mesh.normals.is_empty() {
                            patch.normals.push(mesh.normals[v]);
                        }
                    }
                    patch.indices.push(slot[v]);
                }
            }
            (patch, tris)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::patch::{edge_corners, next_corner};

    fn sheet(n: u32, id_base: u32, x0: f32) -> BuildPatch {
        let mut p = BuildPatch::default();
        for y in 0..=n {
            for x in 0..=n {
                p.ids.push(id_base + y * 1000 + x);
                let fx = x0 + x as f32 / n as f32;
                let fy = y as f32 / n as f32;
                p.positions
                    .push([fx, fy, (fx * 3.0).sin() * (fy * 2.0).cos() * 0.05]);
                p.normals.push([0.0, 0.0, 1.0]);
            }
        }
        for y in 0..n {
            for x in 0..n {
                let i = y * (n + 1) + x;
                p.indices
                    .extend_from_slice(&[i, i + 1, i + n + 2, i, i + n + 2, i + n + 1]);
            }
        }
        p
    }

    #[test]
    fn locked_border_survives_and_vertices_are_original() {
        let a = sheet(30, 0, 0.0);
        let merged = merge(&[&a]);
        let border: std::collections::HashSet<u64> = a.border_edges().into_iter().collect();
        let alone = vec![false; merged.patch.ids.len()];
        let step = simplify_group(&merged, &alone, 4096, Simplifier::Quadric).expect("reduces");
        let product_tris: usize = step.products.iter().map(|p| p.triangle_count()).sum();
        assert!(product_tris <= a.triangle_count() * 6 / 10);
        let mut out_border: Vec<u64> = {
            let mut all = BuildPatch::default();
            for p in &step.products {
                let base = all.ids.len() as u32;
                all.ids.extend(&p.ids);
                all.positions.extend(&p.positions);
                all.indices.extend(p.indices.iter().map(|i| i + base));
            }
            all.border_edges()
        };
        out_border.sort_unstable();
        let mut in_border: Vec<u64> = border.into_iter().collect();
        in_border.sort_unstable();
        assert_eq!(out_border, in_border, "outer border must be kept exactly");
        let ids: std::collections::HashSet<u32> = a.ids.iter().copied().collect();
        assert!(
            step.products
                .iter()
                .flat_map(|p| &p.ids)
                .all(|id| ids.contains(id))
        );
        assert!(step.distance > 0.0 && step.distance < 0.05);
    }

    /// The counting sorts give what sorting every key gives, on a soup with a repeated
    /// triangle (both orientations), a non-manifold edge, a degenerate triangle and an unused
    /// vertex.
    #[test]
    fn counted_runs_equal_sorted_runs() {
        let indices: Vec<u32> = vec![
            0, 1, 2, 2, 1, 3, 1, 0, 2, // (0, 1, 2) twice, once reversed
            1, 3, 4, 3, 1, 5, // edge (1, 3) used three times
            4, 4, 6, // a degenerate triangle
            6, 2, 3, 7, 3, 6, 4, 7, 6,
        ];
        let n = 9;
        let sorted_runs = |mut keys: Vec<u64>| {
            keys.sort_unstable();
            let mut out: Vec<(u64, u32)> = Vec::new();
            for k in keys {
                match out.last_mut() {
                    Some((last, c)) if *last == k => *c += 1,
                    _ => out.push((k, 1)),
                }
            }
            out
        };
        for skip in [false, true] {
            let keys: Vec<u64> = indices
                .chunks_exact(3)
                .filter(|t| !(skip && degenerate(t)))
                .flat_map(|t| {
                    [
                        edge_key(t[0], t[1]),
                        edge_key(t[1], t[2]),
                        edge_key(t[2], t[0]),
                    ]
                })
                .collect();
            assert_eq!(edge_runs(&indices, n, skip), sorted_runs(keys));
            // The same edges corner by corner: the counting sort gives what sorting all
            // (key, corner) pairs gives.
            let keep = |f: usize| !(skip && degenerate(&indices[3 * f..3 * f + 3]));
            let mut pairs: Vec<(u64, u32)> = (0..indices.len())
                .filter(|&c| keep(c / 3))
                .map(|c| (edge_key(indices[c], indices[next_corner(c)]), c as u32))
                .collect();
            pairs.sort_unstable();
            assert_eq!(edge_corners(&indices, n, keep), pairs);
            let mut tris: Vec<[u32; 3]> = indices
                .chunks_exact(3)
                .filter(|t| !(skip && degenerate(t)))
                .map(|t| {
                    let mut k = [t[0], t[1], t[2]];
                    k.sort_unstable();
                    k
                })
                .collect();
            tris.sort_unstable();
            let mut expected: Vec<([u32; 3], u32)> = Vec::new();
            for t in tris {
                match expected.last_mut() {
                    Some((last, c)) if *last == t => *c += 1,
                    _ => expected.push((t, 1)),
                }
            }
            assert_eq!(triangle_runs(&indices, n, skip), expected);
        }
        let runs = edge_runs(&indices, n, true);
        assert_eq!(
            runs.iter().find(|r| r.0 == edge_key(1, 3)).map(|r| r.1),
            Some(3)
        );
        assert!(runs.iter().all(|r| r.0 != edge_key(4, 4)));
        let repeated = triangle_runs(&indices, n, true);
        assert!(repeated.contains(&([0, 1, 2], 2)));
    }
}
