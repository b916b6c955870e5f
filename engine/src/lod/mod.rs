//! Multiresolution patch DAG: out-of-core build, file format, cuts (system paper §3).
//!
//! Entry points: [`build_file`] / [`build_mesh`] write a `.mwlod` file; [`LodFile::open`] maps
//! one; [`cut_uniform`] / [`cut_view`] choose the patches to draw; [`LodFile::patch`] decodes one;
//! [`export_cut`] welds a cut into one mesh.

pub mod atlas;
pub mod bounds;
mod buckets;
pub mod build;
pub mod chart_uv;
pub mod codec;
pub mod cut;
pub mod export;
pub mod format;
pub mod fragment_quality;
pub mod frontcoder;
mod grouping;
pub mod hausdorff;
mod ingest;
pub mod jpegtables;
pub mod nearest;
pub mod parallelogram;
pub mod partition;
pub mod patch;
pub mod planar_chart;
pub mod rangecoder;
pub mod segsimplify;
pub mod simplify;
pub mod sparse;
mod spill;
pub mod vertex_order;
pub mod webp_match;

pub use build::{
    BuildError, BuildOptions, BuildReport, build_file, build_from, build_mesh, peak_rss_bytes,
};
pub use codec::{Grid, Patch};
pub use cut::{
    Culling, Silhouette, cut_uniform, cut_view, cut_view_silhouette, front_facing, projected_error,
};
pub use export::{CutMesh, export_cut};
pub use format::{FormatError, GroupRecord, LodFile, NO_GROUP, NodeRecord};
pub use vertex_order::VertexOrder;

/// A heightfield test patch: `(n+1)²` vertices at `step` spacing from the origin, `z =
/// height(x, y)`, two triangles a cell (counter-clockwise from +z).
#[cfg(test)]
pub(crate) fn height_grid(
    n: usize,
    step: f32,
    height: impl Fn(f32, f32) -> f32,
) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut positions = Vec::with_capacity((n + 1) * (n + 1));
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 * step, j as f32 * step);
            positions.push([x, y, height(x, y)]);
        }
    }
    let mut indices = Vec::with_capacity(6 * n * n);
    let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    for j in 0..n {
        for i in 0..n {
            indices.extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            indices.extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    (positions, indices)
}
