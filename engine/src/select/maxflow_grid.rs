//! Boykov–Kolmogorov max-flow (PAMI 2004 §3) specialised to 8-connected pixel grids, for the
//! pixel graphs of the selection (system paper §4.1.1).
//!
//! Neighbours are implicit: the grid is stored with a one-pixel frame of dummy nodes (whose
//! arcs all have zero capacity) so that the eight neighbour offsets need no bounds checks,
//! and the eight residual capacities of a node sit together in one 32-byte block. Arc
//! `8·v + d` leaves node `v` in direction `d`; its reverse is `8·(v + off[d]) + (7 − d)`.
//! The search itself is the shared solver of [`super::maxflow`].

use std::ops::Range;

use super::maxflow::{
    Core, GraphError, MAX_ARCS, MAX_NODES, Node, Store, check_caps, check_delta, check_len,
};

/// Capacities of the four forward directions of an 8-connected grid, one value per pixel in
/// row-major order: the edge from pixel (row r, column c) to (r, c+1), (r+1, c), (r+1, c+1)
/// and (r+1, c−1) respectively. Values on edges that leave the image are ignored.
#[derive(Clone, Copy, Debug)]
pub struct GridEdges<'a> {
    /// Edge to (r, c+1).
    pub right: &'a [f32],
    /// Edge to (r+1, c).
    pub down: &'a [f32],
    /// Edge to (r+1, c+1).
    pub down_right: &'a [f32],
    /// Edge to (r+1, c−1).
    pub down_left: &'a [f32],
}

/// Forward directions as (row, column) offsets, in the order of [`GridEdges`].
const FORWARD: [(isize, isize); 4] = [(0, 1), (1, 0), (1, 1), (1, -1)];

/// Implicit arcs of the framed grid: arc `8·v + d` leaves `v` in direction `d`; directions
/// 0–3 are [`FORWARD`], 7 − d is the opposite of d. The eight residual capacities of a node
/// are contiguous (32 bytes).
pub(crate) struct Grid8 {
    off: [u32; 8],
    nodes: Vec<Node>,
    tcap: Vec<f32>,
    rcap: Vec<f32>,
}

impl Grid8 {
    fn offsets(stride: usize) -> [u32; 8] {
        let mut off = [0u32; 8];
        for (d, &(dr, dc)) in FORWARD.iter().enumerate() {
            let o = dr * stride as isize + dc;
            off[d] = o as u32;
            off[7 - d] = (-o) as u32;
        }
        off
    }
}

impl Store for Grid8 {
    #[inline(always)]
    fn len(&self) -> usize {
        self.nodes.len()
    }
    #[inline(always)]
    fn arcs(&self, v: u32) -> Range<u32> {
        v * 8..v * 8 + 8
    }
    #[inline(always)]
    fn head(&self, a: u32) -> u32 {
        (a >> 3).wrapping_add(self.off[(a & 7) as usize])
    }
    #[inline(always)]
    fn sister(&self, a: u32) -> u32 {
        (self.head(a) << 3) | (7 - (a & 7))
    }
    #[inline(always)]
    fn rcap(&self, a: u32) -> f32 {
        self.rcap[a as usize]
    }
    #[inline(always)]
    fn rcap_mut(&mut self, a: u32) -> &mut f32 {
        &mut self.rcap[a as usize]
    }
    #[inline(always)]
    fn tcap(&self, v: u32) -> f32 {
        self.tcap[v as usize]
    }
    #[inline(always)]
    fn tcap_mut(&mut self, v: u32) -> &mut f32 {
        &mut self.tcap[v as usize]
    }
    #[inline(always)]
    fn node(&self, v: u32) -> &Node {
        &self.nodes[v as usize]
    }
    #[inline(always)]
    fn node_mut(&mut self, v: u32) -> &mut Node {
        &mut self.nodes[v as usize]
    }
}

/// An 8-connected grid graph for min-cut/max-flow (one node per pixel).
pub struct GridGraph {
    core: Core<Grid8>,
    width: usize,
    height: usize,
}

impl GridGraph {
    /// Builds an 8-connected grid graph (PAMI 2004 §2: n-links and t-links):
    /// `width × height` pixels in row-major order with t-link capacities `source`/`sink`;
    /// `forward` gives the capacity of each edge from a pixel to its neighbour in the four
    /// directions of [`GridEdges`], `backward` the capacity from that neighbour back.
    pub fn new(
        width: usize,
        height: usize,
        source: &[f32],
        sink: &[f32],
        forward: &GridEdges<'_>,
        backward: &GridEdges<'_>,
    ) -> Result<Self, GraphError> {
        let pixels = width.checked_mul(height).ok_or(GraphError::TooLarge {
            what: "pixels",
            count: usize::MAX,
            max: MAX_NODES,
        })?;
        check_len("source", source.len(), pixels)?;
        check_len("sink", sink.len(), pixels)?;
        let fwd = [
            forward.right,
            forward.down,
            forward.down_right,
            forward.down_left,
        ];
        let bwd = [
            backward.right,
            backward.down,
            backward.down_right,
            backward.down_left,
        ];
        const NAMES: [[&str; 4]; 2] = [
            [
                "forward.right",
                "forward.down",
                "forward.down_right",
                "forward.down_left",
            ],
            [
                "backward.right",
                "backward.down",
                "backward.down_right",
                "backward.down_left",
            ],
        ];
        for (names, arrays) in NAMES.iter().zip([&fwd, &bwd]) {
            for (&name, arr) in names.iter().zip(arrays.iter()) {
                check_len(name, arr.len(), pixels)?;
            }
        }
        let stride = width + 1;
        let nodes = (height + 2)
            .checked_mul(stride)
            .and_then(|x| x.checked_add(1))
            .unwrap_or(usize::MAX);
        if nodes > MAX_NODES || nodes.saturating_mul(8) > MAX_ARCS {
            return Err(GraphError::TooLarge {
                what: "grid nodes",
                count: nodes,
                max: MAX_NODES.min(MAX_ARCS / 8),
            });
        }
        check_caps("source", source)?;
        check_caps("sink", sink)?;
        for (names, arrays) in NAMES.iter().zip([&fwd, &bwd]) {
            for (&name, arr) in names.iter().zip(arrays.iter()) {
                check_caps(name, arr)?;
            }
        }

        let mut tcap = vec![0f32; nodes];
        let mut rcap = vec![0f32; nodes * 8];
        let mut flow = 0.0f64;
        for r in 0..height {
            let row = r * width;
            let base = (r + 1) * stride + 1;
            let t_row = &mut tcap[base..base + width];
            let r_row = &mut rcap[base * 8..(base + width) * 8];
            for (c, (t, out)) in t_row.iter_mut().zip(r_row.chunks_exact_mut(8)).enumerate() {
                let p = row + c;
                let (s, k) = (source[p] as f64, sink[p] as f64);
                flow += s.min(k);
                *t = (s - k) as f32;
                for (d, &(dr, dc)) in FORWARD.iter().enumerate() {
                    // Forward arc to (r + dr, c + dc).
                    let (tr, tc) = (r as isize + dr, c as isize + dc);
                    if (tr as usize) < height && (tc as usize) < width {
                        out[d] = fwd[d][p];
                    }
                    // Reverse arc to (r − dr, c − dc): the backward capacity of that pixel's edge.
                    let (qr, qc) = (r as isize - dr, c as isize - dc);
                    if (qr as usize) < height && (qc as usize) < width {
                        out[7 - d] = bwd[d][qr as usize * width + qc as usize];
                    }
                }
            }
        }
        let store = Grid8 {
            off: Grid8::offsets(stride),
            nodes: vec![Node::FREE; nodes],
            tcap,
            rcap,
        };
        Ok(GridGraph {
            core: Core::new(store, flow),
            width,
            height,
        })
    }

    /// [`GridGraph::new`] with the same capacity in both directions of every edge.
    pub fn symmetric(
        width: usize,
        height: usize,
        source: &[f32],
        sink: &[f32],
        edges: &GridEdges<'_>,
    ) -> Result<Self, GraphError> {
        Self::new(width, height, source, sink, edges, edges)
    }

    /// Image width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of n-link edges of the 8-connected grid (pairs of neighbouring pixels).
    pub fn edge_count(&self) -> usize {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return 0;
        }
        (w - 1) * h + w * (h - 1) + 2 * (w - 1) * (h - 1)
    }

    #[inline]
    fn node(&self, x: usize, y: usize) -> usize {
        (y + 1) * (self.width + 1) + x + 1
    }

    /// Computes the maximum flow from scratch (PAMI 2004 §3.1–3.2) and returns its value; the
    /// minimum cut is then read with [`GridGraph::labels`].
    pub fn maxflow(&mut self) -> f64 {
        self.core.maxflow(false)
    }

    /// Like [`GridGraph::maxflow`], reusing the previous search trees around pixels changed
    /// by [`GridGraph::add_tweights`] (dynamic cuts, as the reference `maxflow(true)`).
    pub fn maxflow_reuse_trees(&mut self) -> f64 {
        self.core.maxflow(true)
    }

    /// Adds capacities to the t-links of pixel (`x`, `y`) (PAMI 2004 §2 t-links; each at most
    /// [`super::maxflow::MAX_CAPACITY`] in magnitude). Deltas may be negative as long as the
    /// resulting capacities are not.
    pub fn add_tweights(
        &mut self,
        x: usize,
        y: usize,
        source: f32,
        sink: f32,
    ) -> Result<(), GraphError> {
        if x >= self.width || y >= self.height {
            return Err(GraphError::NodeOutOfRange {
                what: "add_tweights",
                node: (y as u64).saturating_mul(self.width as u64) + x as u64,
                nodes: self.width * self.height,
            });
        }
        check_delta("source", y * self.width + x, source)?;
        check_delta("sink", y * self.width + x, sink)?;
        let v = self.node(x, y);
        self.core.add_tweights(v as u32, source, sink);
        Ok(())
    }

    /// Value of the flow found so far.
    pub fn flow(&self) -> f64 {
        self.core.flow()
    }

    /// Minimum-cut side of pixel (`x`, `y`) after a solve; `None` if outside the image.
    pub fn is_source(&self, x: usize, y: usize) -> Option<bool> {
        (x < self.width && y < self.height).then(|| self.core.is_source(self.node(x, y) as u32))
    }

    /// Minimum-cut labelling after a solve, row-major: 1 = source side, 0 = sink side.
    pub fn labels(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.width * self.height);
        for y in 0..self.height {
            let base = self.node(0, y);
            out.extend((base..base + self.width).map(|v| self.core.is_source(v as u32) as u8));
        }
        out
    }
}
