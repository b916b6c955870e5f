//! One DAG step for a group of neighbouring patches (system paper §3.2): merge the patches,
//! lock the group's outer border, simplify with quadric error metrics (Garland–Heckbert, via
//! meshoptimizer) to about half the triangles, measure the result, split it into patches.
//!
//! Locked: every vertex the group shares with patches outside it (so neighbours still fit, even
//! at non-manifold "pinch" vertices that share no edge), and the whole topological border of the
//! merged group (so every cut keeps exactly the scan's boundary edges). Collapses only ever keep
//! input vertices, so every product vertex still carries its original ID.

use super::hausdorff::simplification_distance;
use super::partition::{Triangles, partition};
use super::patch::{BuildPatch, edge_key};
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
}

/// Concatenates member patches, welding shared vertices by original ID.
pub fn merge(members: &[&BuildPatch]) -> Merged {
    let vertex_hint: usize = members.iter().map(|m| m.ids.len()).sum();
    let mut local: HashMap<u32, u32> =
        HashMap::with_capacity_and_hasher(vertex_hint, Default::default());
    let has_colors = members.iter().all(|m| !m.colors.is_empty());
    let has_normals = members.iter().all(|m| !m.normals.is_empty());
    let mut out = BuildPatch::default();
    for m in members {
        let remap: Vec<u32> = m
            .ids
            .iter()
            .enumerate()
            .map(|(i, &id)| {
                *local.entry(id).or_insert_with(|| {
                    out.ids.push(id);
                    out.positions.push(m.positions[i]);
                    if has_colors {
                        out.colors.push(m.colors[i]);
                    }
                    if has_normals {
                        out.normals.push(m.normals[i]);
                    }
                    (out.ids.len() - 1) as u32
                })
            })
            .collect();
        out.indices
            .extend(m.indices.iter().map(|&i| remap[i as usize]));
    }
    Merged { patch: out }
}

/// Simplifies merged group geometry to about half its triangles and splits the result into
/// patches of at most `max_triangles`. `shared_outside(id)` tells whether the vertex with that
/// original ID also belongs to a patch outside the group. `None` when the group cannot be
/// reduced enough (its members then move on to the next level unchanged).
pub fn simplify_group(
    merged: &Merged,
    shared_outside: &dyn Fn(u32) -> bool,
    max_triangles: usize,
) -> Option<GroupStep> {
    let mesh = &merged.patch;
    let tri_count = mesh.triangle_count();
    if tri_count < 2 {
        return None;
    }
    let (positions, coincident) = distinct_positions(&mesh.positions);
    let border = id_border(mesh, &mesh.indices);
    let mut locks = border_locks(mesh, &border);
    for (v, lock) in locks.iter_mut().enumerate() {
        // Coincident twins (scanner "zipper" seams) are locked too: collapsing one onto the
        // other would glue two boundary sheets together and change the scan's boundary.
        if coincident[v] || shared_outside(mesh.ids[v]) {
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
    let mut simplified = run(&locks);
    if id_border(mesh, &simplified) != border {
        // The simplifier changed the border through some non-manifold configuration: lock the
        // border's one-ring as well and try again; give up on this group if that fails too.
        lock_one_ring(mesh, &mut locks);
        simplified = run(&locks);
        if id_border(mesh, &simplified) != border {
            return None;
        }
    }
    let new_tris = simplified.len() / 3;
    if new_tris == 0 || new_tris as f32 > tri_count as f32 * MIN_REDUCTION {
        return None;
    }
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
        if let Some(&twin) = first.get(&original) {
            coincident[twin] = true;
            coincident[i] = true;
        }
        let mut key = original;
        while first.contains_key(&key) {
            key[0] = f32::from_bits(key[0]).next_up().to_bits();
        }
        first.insert(key, i);
        out.push(key.map(f32::from_bits));
    }
    (out, coincident)
}

/// Border edges (used by exactly one triangle) of `indices` over `mesh`'s vertices, as
/// sorted original-ID keys.
fn id_border(mesh: &BuildPatch, indices: &[u32]) -> Vec<u64> {
    let mut keys: Vec<u64> = indices
        .chunks_exact(3)
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| edge_key(mesh.ids[a as usize], mesh.ids[b as usize]))
        .collect();
    keys.sort_unstable();
    let mut border = Vec::new();
    let mut i = 0;
    while i < keys.len() {
        let mut j = i + 1;
        while j < keys.len() && keys[j] == keys[i] {
            j += 1;
        }
        if j - i == 1 {
            border.push(keys[i]);
        }
        i = j;
    }
    border
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

/// Lock flags: the vertices of the group's border edges (original-ID keys from [`id_border`]).
fn border_locks(mesh: &BuildPatch, border: &[u64]) -> Vec<SimplifyVertex> {
    let on_border: rustc_hash::FxHashSet<u32> = border
        .iter()
        .flat_map(|&e| {
            let (a, b) = super::patch::edge_ends(e);
            [a, b]
        })
        .collect();
    mesh.ids
        .iter()
        .map(|id| {
            if on_border.contains(id) {
                SimplifyVertex::Lock
            } else {
                SimplifyVertex::None
            }
        })
        .collect()
}

/// Splits simplified triangles (indexing `mesh`'s vertices) into compact patches.
pub fn split(mesh: &BuildPatch, indices: &[u32], max_triangles: usize) -> Vec<BuildPatch> {
    let (parts, count) = partition(
        &Triangles {
            positions: &mesh.positions,
            colors: &mesh.colors,
            indices,
        },
        max_triangles,
    );
    let mut products: Vec<BuildPatch> = (0..count).map(|_| BuildPatch::default()).collect();
    let mut local: Vec<HashMap<u32, u32>> = vec![HashMap::default(); count];
    for (t, tri) in indices.chunks_exact(3).enumerate() {
        let p = parts[t] as usize;
        let (patch, map) = (&mut products[p], &mut local[p]);
        for &v in tri {
            let li = *map.entry(v).or_insert_with(|| {
                let v = v as usize;
                patch.ids.push(mesh.ids[v]);
                patch.positions.push(mesh.positions[v]);
                if !mesh.colors.is_empty() {
                    patch.colors.push(mesh.colors[v]);
                }
                if !mesh.normals.is_empty() {
                    patch.normals.push(mesh.normals[v]);
                }
                (patch.ids.len() - 1) as u32
            });
            patch.indices.push(li);
        }
    }
    products
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let step = simplify_group(&merged, &|_| false, 4096).expect("reduces");
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
}
