//! The sparse mesh of the network mode (system paper §5.3): "only sparse meshes to correct
//! the image-based rendering result". It is the uniform cut at the object-space error
//! [`sparse_error`], the smallest error whose cut holds at most a budget of triangles; a node
//! belongs to the sparse mesh or is coarser than it exactly when its parent's error exceeds
//! that error ([`within_sparse`]), which is what a model whose geometry stays on the server
//! serves to everyone but admins.

use super::cut::cut_uniform;
use super::format::NodeRecord;

/// Share of the scan's triangles the sparse mesh holds at most (1/32: on the bench's dragon
/// path, against 1/16, 12 % fewer bytes for 0.7 dB less PSNR; docs/FORMAT.md).
pub const SPARSE_SHARE: u64 = 32;
/// Triangles of the sparse mesh at most, whatever the scan's size.
pub const SPARSE_MAX_TRIANGLES: u64 = 100_000;

/// Triangles the sparse mesh of a hierarchy whose leaves hold `leaf_triangles` may hold.
pub fn sparse_budget(leaf_triangles: u64) -> u64 {
    (leaf_triangles / SPARSE_SHARE).min(SPARSE_MAX_TRIANGLES)
}

/// The smallest object-space error whose uniform cut holds at most `budget` triangles (the
/// roots' cut when even that holds more). `f32::INFINITY` for an empty hierarchy.
pub fn sparse_error(nodes: &[NodeRecord], budget: u64) -> f32 {
    let triangles = |e: f32| -> u64 {
        cut_uniform(nodes, e)
            .iter()
            .map(|&i| nodes[i as usize].triangle_count as u64)
            .sum()
    };
    let mut errors: Vec<f32> = nodes
        .iter()
        .map(|n| n.lod_error)
        .filter(|e| e.is_finite())
        .collect();
    if errors.is_empty() {
        return f32::INFINITY;
    }
    errors.sort_by(f32::total_cmp);
    errors.dedup();
    // Triangles of the cut fall as the error grows: the first error within budget.
    let (mut lo, mut hi) = (0usize, errors.len() - 1);
    if triangles(errors[hi]) > budget {
        return errors[hi];
    }
    while lo < hi {
        let mid = (lo + hi) / 2;
        if triangles(errors[mid]) <= budget {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    errors[lo]
}

/// Whether `node` is in the sparse mesh of error `sparse` or coarser than it.
pub fn within_sparse(node: &NodeRecord, sparse: f32) -> bool {
    node.parent_error > sparse
}
