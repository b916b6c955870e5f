//! Grid-Lumigraph (system paper §5): the image repository of a model, sampled from the
//! points of a regular grid around it, from which a client reconstructs arbitrary views over a
//! sparse mesh without ever receiving the full-resolution geometry.
//!
//! - [`grid`]: the viewing box, its grid points, the six axis-aligned 90° cameras of each
//!   point (§5.2.2, Fig. 16), the test that tells a point inside the object, and the finer
//!   levels kept near the model for close views.
//! - [`image`]: one repository image as stored and served: albedo, normals and view depth of
//!   the full-resolution surface, so a client can shade it under its own light and project it
//!   only onto surface the image saw (Fig. 15).
//! - [`sample`]: one grid point's six images (or one refined image) rendered from the
//!   hierarchy.

pub mod grid;
pub mod image;
pub mod sample;

pub use grid::{DIRECTIONS, Direction, Grid, GridError};
pub use image::{ImageError, LumigraphImage};
pub use sample::{PointImages, SampleError, sample_image, sample_point};
