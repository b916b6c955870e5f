//! Graph-cut region selection (system paper §4).

pub mod maxflow;
pub mod maxflow_grid;
