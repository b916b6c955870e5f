//! Multiresolution patch DAG: out-of-core build, file format, cuts (system paper §3).
//!
//! Entry points: [`build_file`] / [`build_mesh`] write a `.mwlod` file; [`LodFile::open`] maps
//! one; [`cut_uniform`] / [`cut_view`] choose the patches to draw; [`LodFile::patch`] decodes one;
//! [`export_cut`] welds a cut into one mesh.

pub mod atlas;
pub mod bounds;
mod buckets;
pub mod build;
pub mod codec;
pub mod cut;
pub mod export;
pub mod format;
pub mod frontcoder;
mod grouping;
pub mod hausdorff;
mod ingest;
pub mod nearest;
pub mod parallelogram;
pub mod partition;
pub mod patch;
pub mod rangecoder;
pub mod segsimplify;
pub mod simplify;
pub mod sparse;
mod spill;

pub use build::{
    BuildError, BuildOptions, BuildReport, build_file, build_from, build_mesh, peak_rss_bytes,
};
pub use codec::{Grid, Patch};
pub use cut::{Culling, cut_uniform, cut_view, projected_error};
pub use export::{CutMesh, export_cut};
pub use format::{FormatError, GroupRecord, LodFile, NO_GROUP, NodeRecord};
