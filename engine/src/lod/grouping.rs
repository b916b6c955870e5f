//! Grouping of neighbouring patches for the next DAG step (Nanite-style: groups are re-formed
//! at every level, so the borders locked at one level end up inside groups at the next).
//!
//! meshoptimizer's cluster partitioner does the work: it merges clusters that share the most
//! border vertices, and spatially close ones when nothing is shared (disconnected pieces of a
//! scan, so they still coarsen together).

use meshopt::VertexDataAdapter;
use rustc_hash::FxHashMap as HashMap;

/// What grouping needs to know about one patch of the current level.
pub struct PatchOutline {
    /// Original IDs and positions of the patch's border vertices (or a few sample vertices
    /// when the patch has no border, e.g. a closed component).
    pub points: Vec<(u32, [f32; 3])>,
}

/// Partitions patches into groups of about `group_size`. Returns lists of patch indices.
pub fn group_patches(outlines: &[PatchOutline], group_size: usize) -> Vec<Vec<usize>> {
    let n = outlines.len();
    if n == 0 {
        return Vec::new();
    }
    if n <= group_size {
        return vec![(0..n).collect()];
    }
    let mut compact: HashMap<u32, u32> = HashMap::default();
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut indices: Vec<u32> = Vec::new();
    let mut counts: Vec<u32> = Vec::with_capacity(n);
    for outline in outlines {
        let start = indices.len();
        for &(id, p) in &outline.points {
            let c = *compact.entry(id).or_insert_with(|| {
                positions.push(p);
                (positions.len() - 1) as u32
            });
            indices.push(c);
        }
        if indices.len() == start {
            // The partitioner needs at least one vertex per cluster; a patch without points
            // cannot happen (every patch has vertices) but stay safe with a private point.
            positions.push([0.0; 3]);
            indices.push((positions.len() - 1) as u32);
        }
        counts.push((indices.len() - start) as u32);
    }
    let bytes: &[u8] = bytemuck::cast_slice(&positions);
    let Ok(adapter) = VertexDataAdapter::new(bytes, 12, 0) else {
        return (0..n)
            .collect::<Vec<_>>()
            .chunks(group_size)
            .map(|c| c.to_vec())
            .collect();
    };
    let mut destination = vec![0u32; n];
    let groups = meshopt::partition_clusters_with_positions(
        &mut destination,
        &indices,
        &counts,
        &adapter,
        group_size,
    );
    let mut out: Vec<Vec<usize>> = vec![Vec::new(); groups];
    for (patch, &g) in destination.iter().enumerate() {
        out[g as usize].push(patch);
    }
    out.retain(|g| !g.is_empty());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbours_group_together() {
        // A row of 16 patches, each sharing an edge vertex pair with the next.
        let outlines: Vec<PatchOutline> = (0..16u32)
            .map(|i| PatchOutline {
                points: vec![
                    (i * 2, [i as f32, 0.0, 0.0]),
                    (i * 2 + 1, [i as f32, 1.0, 0.0]),
                    (i * 2 + 2, [i as f32 + 1.0, 0.0, 0.0]),
                    (i * 2 + 3, [i as f32 + 1.0, 1.0, 0.0]),
                ],
            })
            .collect();
        let groups = group_patches(&outlines, 4);
        let total: usize = groups.iter().map(|g| g.len()).sum();
        assert_eq!(total, 16);
        assert!(groups.len() >= 3 && groups.len() <= 6, "{groups:?}");
        for g in &groups {
            let (lo, hi) = (
                g.iter().min().copied().unwrap_or(0),
                g.iter().max().copied().unwrap_or(0),
            );
            assert!(hi - lo < g.len() + 2, "group {g:?} is not contiguous");
        }
    }
}
