//! Graph-cut region selection (system paper §4): rough strokes on a rendered view in, the exact
//! set of full-resolution vertices of the region out.
//!
//! - [`mask`]: the stroke mask a client sends (one label per pixel: foreground and background
//!   markers, the heavy band, the lasso's inside) and the result mask image.
//! - [`buffers`]: the rendered colour, normal, depth and id buffers the cut runs on.
//! - [`seeds`]: seeds of each tool — markup strokes (Lazy Snapping), the heavy lasso's inner and
//!   outer markers (§4.2), the plain lasso's polygon.
//! - [`segments`]: the model's surface segments in the cut (stroke segments: a prior and
//!   cheap cuts on segment boundaries).
//! - [`energy`]: the data term (eq. 2–3) and the smoothness term (eq. 4).
//! - [`graph_cut`]: the graph over covered pixels, 8-connected, solved by Boykov–Kolmogorov max-flow
//!   ([`maxflow_grid`]) (eq. 1).
//! - [`multilevel`]: markup coarse to fine on large views (a banded multilevel graph cut).
//! - [`pipeline`]: one call from strokes and buffers to selected pixels, per tool.
//! - [`backproject`]: selected pixels to original vertex ids through the id and depth buffers
//!   and the patch DAG down to the leaves (§4.1.2); occluded surfaces are never selected.
//! - [`modes`]: replace / add / subtract against an existing vertex set.
//! - [`point`]: a single click to a point part.
//! - [`on_view`]: all of it in one call — render a view's buffers, select, back-project.

pub mod backproject;
pub mod buffers;
pub mod energy;
pub mod graph_cut;
pub mod mask;
pub mod maxflow;
pub mod maxflow_grid;
pub mod modes;
pub mod multilevel;
pub mod on_view;
pub mod pipeline;
pub mod point;
pub mod seeds;
pub mod segments;
pub mod suggest;

pub use backproject::{BackProjectOptions, BackProjection, back_project};
pub use buffers::Buffers;
pub use energy::EnergyParams;
pub use mask::StrokeMask;
pub use modes::Mode;
pub use on_view::{Input, ViewSelectError, ViewSelection, select_on_view};
pub use pipeline::{PixelSelection, Tool, select_pixels};

/// Why a selection cannot be made. Every variant is a problem with the input (strokes,
/// camera, buffers) except [`SelectError::Graph`] and [`SelectError::Patch`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SelectError {
    /// The stroke mask is unusable (see [`mask::MaskError`]).
    #[error("{0}")]
    Mask(#[from] mask::MaskError),
    /// Buffers of different sizes, or a mask that does not match them.
    #[error("{what} is {got_w}x{got_h} but the view is {width}x{height}")]
    SizeMismatch {
        what: &'static str,
        got_w: u32,
        got_h: u32,
        width: u32,
        height: u32,
    },
    /// A buffer the selection needs was not rendered.
    #[error("the {0} buffer is missing")]
    MissingBuffer(&'static str),
    /// The camera sees no surface of the model.
    #[error("the camera sees nothing of the model")]
    NothingVisible,
    /// The strokes the tool needs are absent (or lie only off the model).
    #[error("{0}")]
    EmptyStrokes(String),
    /// The heavy lasso's band does not enclose any pixel.
    #[error(
        "the heavy lasso does not enclose anything: draw one closed thick stroke around the region"
    )]
    NotEnclosed,
    /// A point outside the view or on the background.
    #[error("{0}")]
    BadPoint(String),
    /// Parameters out of range.
    #[error("invalid selection parameter: {0}")]
    BadParams(String),
    /// The max-flow solver rejected the graph (a bug: capacities are built finite).
    #[error("graph cut failed: {0}")]
    Graph(#[from] maxflow::GraphError),
    /// A segment click on a model built without surface segments.
    #[error("this model has no surface segments (it was built before them): rebuild it")]
    NoSegments,
    /// A patch of the model cannot be read.
    #[error("patch {node} cannot be read: {message}")]
    Patch { node: u32, message: String },
}

impl SelectError {
    /// Whether the error is the caller's (bad strokes, camera or parameters) rather than the
    /// server's.
    pub fn is_input_error(&self) -> bool {
        !matches!(self, SelectError::Graph(_) | SelectError::Patch { .. })
    }
}
