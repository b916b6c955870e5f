//! meshwiki's engine: everything about geometry and images, nothing about HTTP or SQL.
//!
//! - [`mesh`]: streaming import of scans (PLY, OBJ, glTF/GLB, STL).
//! - [`lod`]: out-of-core build of the multiresolution patch DAG, its file format, and cuts.
//! - [`render`]: headless wgpu rendering of cuts (colour, normal, depth, id buffers).
//! - [`lumigraph`]: the image repository of the network mode (Grid-Lumigraph).
//! - [`segment`]: surface segments at several scales, stored beside the hierarchy.
//! - [`select`]: graph-cut region selection on rendered buffers, back-projected to original vertices.
//!
//! The server crate (`meshwiki`) drives these through plain function calls and the
//! [`progress::Progress`] trait; the engine never depends on the server.

pub mod camera;
pub mod lod;
pub mod lumigraph;
pub mod mesh;
pub mod progress;
pub mod render;
pub mod segment;
pub mod select;
#[cfg(test)]
pub(crate) mod testing;
