//! Surface segments (mesh-segmentation paper, §3.1, made multi-scale): the scan's surface
//! cut into segments of similar normals at the finest scale, merged into coarser scales whose
//! boundaries follow concave creases. Computed out of core during the LOD build and stored
//! beside the hierarchy (`.mwseg`), so every pixel of the id buffer names its segment at any
//! scale; the selection's graph cut uses them ([`crate::select`]).
//!
//! - [`grow`]: fine segments of one bucket by region growing (eq. 1);
//! - [`merge`]: the coarser scales by hierarchical merging;
//! - [`collect`]: both during the build, joined across buckets;
//! - [`file`](mod@file): the `.mwseg` file.

pub mod collect;
pub mod file;
pub mod grow;
pub mod merge;

pub use collect::Collector;
pub use file::{SegmentFile, SegmentFileError, path_for};
pub use grow::{Boundary, GrowParams, SegmentSums};
pub use merge::{Hierarchy, MergeParams};
