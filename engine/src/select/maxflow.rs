//! Min-cut/max-flow by Boykov–Kolmogorov (Boykov & Kolmogorov, "An Experimental Comparison of
//! Min-Cut/Max-Flow Algorithms for Energy Minimization in Vision", PAMI 2004, §3), the solver
//! behind the selection graph cut (system paper §4.1.1).
//!
//! Two search trees, S from the source and T from the sink, grow until they touch (§3.2
//! "growth"), the path found is saturated ("augmentation") and the nodes cut off from their
//! tree are re-attached or freed ("adoption"). The practical refinements of the authors'
//! implementation are kept: a FIFO of active nodes, the node being grown stays current after
//! an augmentation, timestamps and distances to the terminal make origin checks cheap and
//! keep the trees shallow, terminal capacities are folded into one signed residual
//! (`tcap = source − sink`, `min(source, sink)` counted as flow up front), and the trees can
//! be reused after terminal capacities change (Kohli & Torr's dynamic cuts) — the system
//! paper re-solves as users add and remove markers.
//!
//! Capacities are `f32` (at most [`MAX_CAPACITY`]), the flow is accumulated in `f64`. Hard
//! constraints are expressed as large capacities (1e9): they behave as infinite, since the
//! residual of such an arc never gets near zero, and every pushed amount is added to the flow
//! exactly, so they change neither the cut nor the soft part of the flow value.
//!
//! The solver core is shared with the grid-specialised graph in
//! [`super::maxflow_grid`]: only the storage and the way arcs are enumerated differ (an
//! internal trait), so both are monomorphised into tight loops.

use std::collections::VecDeque;
use std::ops::Range;

/// Invalid graph input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraphError {
    /// An array does not have the length the graph needs.
    #[error("{what}: expected {expected} values, got {got}")]
    SizeMismatch {
        /// Which array.
        what: &'static str,
        /// Length required.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// A capacity is negative, NaN, infinite or above [`MAX_CAPACITY`].
    #[error("{what}[{index}] = {value} is not a capacity in [0, 1e30]")]
    InvalidCapacity {
        /// Which array.
        what: &'static str,
        /// Position in that array.
        index: usize,
        /// The offending value.
        value: f32,
    },
    /// A node index is outside the graph.
    #[error("{what}: node {node} is out of range (the graph has {nodes} nodes)")]
    NodeOutOfRange {
        /// Where the index came from.
        what: &'static str,
        /// The offending index.
        node: u64,
        /// Number of nodes in the graph.
        nodes: usize,
    },
    /// CSR offsets that are not non-decreasing or do not end at the number of arcs.
    #[error("CSR offsets are not non-decreasing from 0 to the number of arcs (at node {node})")]
    BadOffsets {
        /// First node whose offsets are wrong.
        node: usize,
    },
    /// More nodes or arcs than the solver's 32-bit indices can address.
    #[error("graph too large: {what} = {count} exceeds {max}")]
    TooLarge {
        /// What overflowed.
        what: &'static str,
        /// How many there are.
        count: usize,
        /// The limit.
        max: usize,
    },
}

/// Largest capacity accepted: far above any hard constraint (1e9), far below `f32::MAX`, so
/// residuals cannot overflow.
pub const MAX_CAPACITY: f32 = 1e30;

/// Arc/node index sentinels (parents and queue links).
pub(crate) const NONE: u32 = u32::MAX;
const TERMINAL: u32 = u32::MAX - 1;
const ORPHAN: u32 = u32::MAX - 2;
/// Largest number of arcs: arc ids must stay below the sentinels.
pub(crate) const MAX_ARCS: usize = (u32::MAX - 3) as usize;
/// Largest number of nodes: distances share their word with the tree flag.
pub(crate) const MAX_NODES: usize = (1 << 30) - 1;

const SINK_BIT: u32 = 1 << 31;
const DIST_MASK: u32 = (1 << 30) - 1;
const INFINITE_D: u32 = u32::MAX;

/// Per-node search state (16 bytes).
#[derive(Clone, Copy)]
#[repr(C)]
pub(crate) struct Node {
    /// Arc to the parent (`TERMINAL` for roots, `ORPHAN`, `NONE` when free).
    parent: u32,
    /// Next active node (`NONE` when not active, itself when last).
    next: u32,
    /// Time the distance was last known to be exact.
    ts: u32,
    /// Distance to the terminal in the low bits, tree flag (sink) in the top bit.
    dist_tree: u32,
}

impl Node {
    pub(crate) const FREE: Node = Node {
        parent: NONE,
        next: NONE,
        ts: 0,
        dist_tree: 0,
    };

    #[inline(always)]
    fn is_sink(&self) -> bool {
        self.dist_tree & SINK_BIT != 0
    }

    #[inline(always)]
    fn dist(&self) -> u32 {
        self.dist_tree & DIST_MASK
    }

    #[inline(always)]
    fn set_dist(&mut self, d: u32) {
        self.dist_tree = (self.dist_tree & SINK_BIT) | (d & DIST_MASK);
    }

    #[inline(always)]
    fn set_tree_dist(&mut self, sink: bool, d: u32) {
        self.dist_tree = if sink { SINK_BIT } else { 0 } | (d & DIST_MASK);
    }
}

/// Storage of a graph for the solver: how arcs are enumerated and where the residual
/// capacities and node states live. Arc ids are `u32`; the arcs leaving node `v` are
/// `arcs(v)`, `head(a)` is the node arc `a` points to and `sister(a)` the reverse arc.
/// Implementations guarantee that every id they hand out indexes their own arrays.
pub(crate) trait Store {
    fn len(&self) -> usize;
    fn arcs(&self, v: u32) -> Range<u32>;
    fn head(&self, a: u32) -> u32;
    fn sister(&self, a: u32) -> u32;
    fn rcap(&self, a: u32) -> f32;
    fn rcap_mut(&mut self, a: u32) -> &mut f32;
    /// Residual terminal capacity: > 0 towards the source, < 0 towards the sink.
    fn tcap(&self, v: u32) -> f32;
    fn tcap_mut(&mut self, v: u32) -> &mut f32;
    fn node(&self, v: u32) -> &Node;
    fn node_mut(&mut self, v: u32) -> &mut Node;
}

/// The Boykov–Kolmogorov solver over any [`Store`].
pub(crate) struct Core<S> {
    pub(crate) g: S,
    flow: f64,
    time: u32,
    q_first: u32,
    q_last: u32,
    orphans: VecDeque<u32>,
    /// Arcs of the augmenting path (scratch).
    path: Vec<u32>,
    solved: bool,
    /// Nodes whose terminal capacities changed since the last solve (for tree reuse).
    changed: Vec<u32>,
    /// Membership flags for `changed` (allocated on first use).
    is_changed: Vec<bool>,
}

impl<S: Store> Core<S> {
    /// Wraps a store whose nodes are all free; `flow` is the flow already counted when
    /// folding terminal capacities (`Σ min(source, sink)`).
    pub(crate) fn new(g: S, flow: f64) -> Self {
        Core {
            g,
            flow,
            time: 0,
            q_first: NONE,
            q_last: NONE,
            orphans: VecDeque::new(),
            path: Vec::new(),
            solved: false,
            changed: Vec::new(),
            is_changed: Vec::new(),
        }
    }

    pub(crate) fn flow(&self) -> f64 {
        self.flow
    }

    /// Source side of the cut: in the S tree or free (free nodes can go either way; like the
    /// reference implementation they go to the source).
    #[inline]
    pub(crate) fn is_source(&self, v: u32) -> bool {
        let n = self.g.node(v);
        n.parent == NONE || !n.is_sink()
    }

    /// Adds terminal capacities to node `v` (deltas may be negative as long as the
    /// resulting capacities are not); after a solve the node is remembered for
    /// [`Core::maxflow`] with tree reuse.
    pub(crate) fn add_tweights(&mut self, v: u32, source: f32, sink: f32) {
        let t = self.g.tcap(v) as f64;
        let s = source as f64 + t.max(0.0);
        let k = sink as f64 + (-t).max(0.0);
        self.flow += s.min(k);
        // Many large deltas could leave the f32 range; stay finite.
        *self.g.tcap_mut(v) = (s - k).clamp(-1e36, 1e36) as f32;
        if self.solved {
            let n = self.g.len();
            if self.is_changed.len() != n {
                self.is_changed = vec![false; n];
            }
            if !self.is_changed[v as usize] {
                self.is_changed[v as usize] = true;
                self.changed.push(v);
            }
        }
    }

    /// Runs the algorithm to completion and returns the total flow. With `reuse`, the
    /// search trees of the previous solve are kept and only repaired around the nodes whose
    /// terminal capacities changed.
    pub(crate) fn maxflow(&mut self, reuse: bool) -> f64 {
        if reuse && self.solved {
            self.reuse_trees_init();
        } else {
            self.init();
        }
        let mut current = NONE;
        loop {
            let mut i = NONE;
            if current != NONE {
                let n = self.g.node_mut(current);
                n.next = NONE;
                if n.parent != NONE {
                    i = current;
                }
            }
            if i == NONE {
                i = self.next_active();
                if i == NONE {
                    break;
                }
            }
            let middle = if self.g.node(i).is_sink() {
                self.grow::<true>(i)
            } else {
                self.grow::<false>(i)
            };
            self.tick();
            if middle != NONE {
                // Keep `i` current: it may still touch the other tree. `next == self`
                // marks it active without queueing it.
                self.g.node_mut(i).next = i;
                current = i;
                self.augment(middle);
                self.adopt();
            } else {
                current = NONE;
            }
        }
        self.solved = true;
        self.flow
    }

    fn tick(&mut self) {
        self.time += 1;
        if self.time == u32::MAX {
            for v in 0..self.g.len() as u32 {
                self.g.node_mut(v).ts = 0;
            }
            self.time = 1;
        }
    }

    /// Fresh trees: every node with terminal capacity is a root, active in index order.
    fn init(&mut self) {
        self.q_first = NONE;
        self.q_last = NONE;
        self.orphans.clear();
        for &v in &self.changed {
            self.is_changed[v as usize] = false;
        }
        self.changed.clear();
        for v in 0..self.g.len() as u32 {
            let t = self.g.tcap(v);
            let n = self.g.node_mut(v);
            *n = Node::FREE;
            if t != 0.0 {
                n.parent = TERMINAL;
                n.set_tree_dist(t < 0.0, 1);
                self.set_active(v);
            }
        }
        self.time = 0;
    }

    /// Repairs the previous trees around the nodes whose terminal capacities changed
    /// (the reference implementation's `maxflow_reuse_trees_init`).
    fn reuse_trees_init(&mut self) {
        self.q_first = NONE;
        self.q_last = NONE;
        self.orphans.clear();
        self.tick();
        let mut changed = std::mem::take(&mut self.changed);
        for &v in &changed {
            self.is_changed[v as usize] = false;
            self.set_active(v);
            let t = self.g.tcap(v);
            let n = *self.g.node(v);
            if t == 0.0 {
                if n.parent != NONE {
                    self.set_orphan_rear(v);
                }
                continue;
            }
            let sink = t < 0.0;
            if n.parent == NONE || n.is_sink() != sink {
                // `v` changes tree: its children lose their parent, the other tree's
                // neighbours may now reach it.
                for a in self.g.arcs(v) {
                    let j = self.g.head(a);
                    if self.is_changed[j as usize] {
                        continue;
                    }
                    let nj = *self.g.node(j);
                    if nj.parent == self.g.sister(a) {
                        self.set_orphan_rear(j);
                    }
                    // Residual arc from the source-side node to the sink-side one.
                    let toward = if sink { self.g.sister(a) } else { a };
                    if nj.parent != NONE && nj.is_sink() != sink && self.g.rcap(toward) > 0.0 {
                        self.set_active(j);
                    }
                }
            }
            let time = self.time;
            let n = self.g.node_mut(v);
            n.parent = TERMINAL;
            n.ts = time;
            n.set_tree_dist(sink, 1);
        }
        changed.clear();
        self.changed = changed;
        self.adopt();
    }

    #[inline(always)]
    fn set_active(&mut self, j: u32) {
        if self.g.node(j).next == NONE {
            if self.q_last != NONE {
                self.g.node_mut(self.q_last).next = j;
            } else {
                self.q_first = j;
            }
            self.q_last = j;
            self.g.node_mut(j).next = j;
        }
    }

    fn next_active(&mut self) -> u32 {
        loop {
            let i = self.q_first;
            if i == NONE {
                return NONE;
            }
            let n = self.g.node_mut(i);
            if n.next == i {
                self.q_first = NONE;
                self.q_last = NONE;
            } else {
                self.q_first = n.next;
            }
            n.next = NONE;
            if n.parent != NONE {
                return i;
            }
        }
    }

    /// Grows the tree of `i` (the T tree if `SINK`) over its residual arcs; returns the
    /// arc (S side → T side) where the trees touch, or `NONE`.
    #[inline(always)]
    fn grow<const SINK: bool>(&mut self, i: u32) -> u32 {
        let ni = *self.g.node(i);
        let (ts, d) = (ni.ts, ni.dist());
        for a in self.g.arcs(i) {
            // Residual capacity in the direction the tree grows.
            let r = if SINK {
                self.g.rcap(self.g.sister(a))
            } else {
                self.g.rcap(a)
            };
            if r == 0.0 {
                continue;
            }
            let j = self.g.head(a);
            let s = self.g.sister(a);
            let nj = self.g.node_mut(j);
            if nj.parent == NONE {
                nj.parent = s;
                nj.ts = ts;
                nj.set_tree_dist(SINK, d + 1);
                self.set_active(j);
            } else if nj.is_sink() != SINK {
                return if SINK { s } else { a };
            } else if nj.ts <= ts && nj.dist() > d {
                nj.parent = s;
                nj.ts = ts;
                nj.set_dist(d + 1);
            }
        }
        NONE
    }

    #[inline(always)]
    fn set_orphan_front(&mut self, i: u32) {
        self.g.node_mut(i).parent = ORPHAN;
        self.orphans.push_front(i);
    }

    #[inline(always)]
    fn set_orphan_rear(&mut self, i: u32) {
        self.g.node_mut(i).parent = ORPHAN;
        self.orphans.push_back(i);
    }

    /// Pushes the bottleneck along source → S path → `middle` → T path → sink. The first
    /// walk up the trees records the path, so the second one is not a chain of dependent
    /// loads.
    fn augment(&mut self, middle: u32) {
        let mut path = std::mem::take(&mut self.path);
        path.clear();
        let g = &self.g;
        // Bottleneck, recording the S-side arcs, then the T-side arcs after `split`.
        let mut b = g.rcap(middle);
        let mut i = g.head(g.sister(middle));
        loop {
            let a = g.node(i).parent;
            if a == TERMINAL {
                break;
            }
            b = b.min(g.rcap(g.sister(a)));
            path.push(a);
            i = g.head(a);
        }
        let s_root = i;
        b = b.min(g.tcap(s_root));
        let split = path.len();
        i = g.head(middle);
        loop {
            let a = g.node(i).parent;
            if a == TERMINAL {
                break;
            }
            b = b.min(g.rcap(a));
            path.push(a);
            i = g.head(a);
        }
        let t_root = i;
        b = b.min(-g.tcap(t_root));

        // Push; nodes whose parent arc (or terminal arc) saturates become orphans.
        let s = self.g.sister(middle);
        *self.g.rcap_mut(s) += b;
        *self.g.rcap_mut(middle) -= b;
        let mut i = self.g.head(s);
        for &a in &path[..split] {
            let s = self.g.sister(a);
            *self.g.rcap_mut(a) += b;
            let r = self.g.rcap_mut(s);
            *r -= b;
            if *r == 0.0 {
                self.set_orphan_front(i);
            }
            i = self.g.head(a);
        }
        let t = self.g.tcap_mut(s_root);
        *t -= b;
        if *t == 0.0 {
            self.set_orphan_front(s_root);
        }
        let mut i = self.g.head(middle);
        for &a in &path[split..] {
            let s = self.g.sister(a);
            *self.g.rcap_mut(s) += b;
            let r = self.g.rcap_mut(a);
            *r -= b;
            if *r == 0.0 {
                self.set_orphan_front(i);
            }
            i = self.g.head(a);
        }
        let t = self.g.tcap_mut(t_root);
        *t += b;
        if *t == 0.0 {
            self.set_orphan_front(t_root);
        }
        self.flow += b as f64;
        self.path = path;
    }

    fn adopt(&mut self) {
        while let Some(i) = self.orphans.pop_front() {
            if self.g.node(i).is_sink() {
                self.process_orphan::<true>(i);
            } else {
                self.process_orphan::<false>(i);
            }
        }
    }

    /// Finds a new parent for orphan `i` in its own tree (one whose chain still reaches the
    /// terminal, the closest by the distance heuristic), or frees it.
    fn process_orphan<const SINK: bool>(&mut self, i: u32) {
        let time = self.time;
        let mut d_min = INFINITE_D;
        let mut a0_min = NONE;
        for a0 in self.g.arcs(i) {
            // Residual capacity from the candidate parent's side towards `i`'s terminal.
            let r = if SINK {
                self.g.rcap(a0)
            } else {
                self.g.rcap(self.g.sister(a0))
            };
            if r == 0.0 {
                continue;
            }
            let j0 = self.g.head(a0);
            let n0 = self.g.node(j0);
            if n0.is_sink() != SINK || n0.parent == NONE {
                continue;
            }
            // Origin check: walk up until a terminal, an orphan or a fresh node.
            let mut j = j0;
            let mut d: u32 = 0;
            loop {
                let nj = self.g.node_mut(j);
                if nj.ts == time {
                    d += nj.dist();
                    break;
                }
                let a = nj.parent;
                d += 1;
                if a == TERMINAL {
                    nj.ts = time;
                    nj.set_dist(1);
                    break;
                }
                if a == ORPHAN {
                    d = INFINITE_D;
                    break;
                }
                j = self.g.head(a);
            }
            if d == INFINITE_D {
                continue;
            }
            if d < d_min {
                a0_min = a0;
                d_min = d;
            }
            // Mark the path with exact distances.
            let mut j = j0;
            loop {
                let nj = self.g.node_mut(j);
                if nj.ts == time {
                    break;
                }
                nj.ts = time;
                nj.set_dist(d);
                d -= 1;
                let a = nj.parent;
                j = self.g.head(a);
            }
        }

        if a0_min != NONE {
            let n = self.g.node_mut(i);
            n.parent = a0_min;
            n.ts = time;
            n.set_dist(d_min + 1);
            return;
        }
        // No parent: `i` becomes free; neighbours that could re-grow into it become
        // active, its children become orphans.
        self.g.node_mut(i).parent = NONE;
        for a0 in self.g.arcs(i) {
            let j = self.g.head(a0);
            let nj = *self.g.node(j);
            if nj.is_sink() != SINK || nj.parent == NONE {
                continue;
            }
            let r = if SINK {
                self.g.rcap(a0)
            } else {
                self.g.rcap(self.g.sister(a0))
            };
            if r != 0.0 {
                self.set_active(j);
            }
            let a = nj.parent;
            if a != TERMINAL && a != ORPHAN && self.g.head(a) == i {
                self.set_orphan_rear(j);
            }
        }
    }
}

/// A general graph's storage: arcs in compressed rows (the arcs leaving `v` are
/// `first[v]..first[v + 1]`), arrays per field.
pub(crate) struct Csr {
    first: Vec<u32>,
    head: Vec<u32>,
    sister: Vec<u32>,
    rcap: Vec<f32>,
    tcap: Vec<f32>,
    nodes: Vec<Node>,
}

impl Store for Csr {
    #[inline(always)]
    fn len(&self) -> usize {
        self.nodes.len()
    }
    #[inline(always)]
    fn arcs(&self, v: u32) -> Range<u32> {
        self.first[v as usize]..self.first[v as usize + 1]
    }
    #[inline(always)]
    fn head(&self, a: u32) -> u32 {
        self.head[a as usize]
    }
    #[inline(always)]
    fn sister(&self, a: u32) -> u32 {
        self.sister[a as usize]
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

/// Checks that every value is in `[0, MAX_CAPACITY]` (which excludes NaN).
pub(crate) fn check_caps(what: &'static str, caps: &[f32]) -> Result<(), GraphError> {
    let valid = |c: &f32| (0.0..=MAX_CAPACITY).contains(c);
    match caps.iter().position(|c| !valid(c)) {
        Some(index) => Err(GraphError::InvalidCapacity {
            what,
            index,
            value: caps[index],
        }),
        None => Ok(()),
    }
}

/// Checks a t-link delta for [`Core::add_tweights`]: at most `MAX_CAPACITY` in magnitude.
pub(crate) fn check_delta(what: &'static str, index: usize, c: f32) -> Result<(), GraphError> {
    if (-MAX_CAPACITY..=MAX_CAPACITY).contains(&c) {
        Ok(())
    } else {
        Err(GraphError::InvalidCapacity {
            what,
            index,
            value: c,
        })
    }
}

pub(crate) fn check_len(what: &'static str, got: usize, expected: usize) -> Result<(), GraphError> {
    if got == expected {
        Ok(())
    } else {
        Err(GraphError::SizeMismatch {
            what,
            expected,
            got,
        })
    }
}

/// Folds terminal capacities: returns `tcap = source − sink` and `Σ min(source, sink)`.
pub(crate) fn fold_terminals(source: &[f32], sink: &[f32], tcap: &mut [f32]) -> f64 {
    let mut flow = 0.0f64;
    for ((t, &s), &k) in tcap.iter_mut().zip(source).zip(sink) {
        let (s, k) = (s as f64, k as f64);
        flow += s.min(k);
        *t = (s - k) as f32;
    }
    flow
}

/// A general graph for min-cut/max-flow: nodes `0..n` with terminal capacities, undirected
/// edges each carrying a capacity in both directions.
pub struct Graph {
    core: Core<Csr>,
    edges: usize,
}

impl Graph {
    /// Builds a graph from an edge list (PAMI 2004 §2: n-links and t-links): `edges[e] = [u, v]` with
    /// capacity `cap[e]` from `u` to `v` and `rev_cap[e]` from `v` to `u` (pass the same slice
    /// twice for symmetric edges); `source[i]`/`sink[i]` are the t-link capacities. Self-loops
    /// and edges of zero capacity both ways are dropped; parallel edges are allowed.
    pub fn from_edges(
        source: &[f32],
        sink: &[f32],
        edges: &[[u32; 2]],
        cap: &[f32],
        rev_cap: &[f32],
    ) -> Result<Self, GraphError> {
        let n = source.len();
        check_len("sink", sink.len(), n)?;
        check_len("cap", cap.len(), edges.len())?;
        check_len("rev_cap", rev_cap.len(), edges.len())?;
        if n > MAX_NODES {
            return Err(GraphError::TooLarge {
                what: "nodes",
                count: n,
                max: MAX_NODES,
            });
        }
        check_caps("source", source)?;
        check_caps("sink", sink)?;
        check_caps("cap", cap)?;
        check_caps("rev_cap", rev_cap)?;

        // Degrees, then compressed rows.
        let mut first = vec![0u32; n + 1];
        let mut m = 0usize;
        for (&[u, v], (&c, &r)) in edges.iter().zip(cap.iter().zip(rev_cap)) {
            for w in [u, v] {
                if w as usize >= n {
                    return Err(GraphError::NodeOutOfRange {
                        what: "edges",
                        node: w as u64,
                        nodes: n,
                    });
                }
            }
            if u == v || (c == 0.0 && r == 0.0) {
                continue;
            }
            first[u as usize + 1] += 1;
            first[v as usize + 1] += 1;
            m += 2;
            if m > MAX_ARCS {
                return Err(GraphError::TooLarge {
                    what: "arcs",
                    count: m,
                    max: MAX_ARCS,
                });
            }
        }
        for v in 0..n {
            first[v + 1] += first[v];
        }
        let mut pos = first.clone();
        let mut head = vec![0u32; m];
        let mut sister = vec![0u32; m];
        let mut rcap = vec![0f32; m];
        for (&[u, v], (&c, &r)) in edges.iter().zip(cap.iter().zip(rev_cap)) {
            if u == v || (c == 0.0 && r == 0.0) {
                continue;
            }
            let a = pos[u as usize];
            pos[u as usize] += 1;
            let b = pos[v as usize];
            pos[v as usize] += 1;
            head[a as usize] = v;
            head[b as usize] = u;
            sister[a as usize] = b;
            sister[b as usize] = a;
            rcap[a as usize] = c;
            rcap[b as usize] = r;
        }
        let mut tcap = vec![0f32; n];
        let flow = fold_terminals(source, sink, &mut tcap);
        let store = Csr {
            first,
            head,
            sister,
            rcap,
            tcap,
            nodes: vec![Node::FREE; n],
        };
        Ok(Graph {
            core: Core::new(store, flow),
            edges: m / 2,
        })
    }

    /// Builds a graph from compressed rows (PAMI 2004 §2: n-links and t-links): the arcs leaving node
    /// `v` are `targets[offsets[v]..offsets[v + 1]]` with capacities `caps[..]` in the same
    /// positions. An arc `u → v` and an arc `v → u` become one edge with a capacity each way
    /// (parallel arcs are summed), so both symmetric and one-way adjacencies work.
    pub fn from_csr(
        source: &[f32],
        sink: &[f32],
        offsets: &[u32],
        targets: &[u32],
        caps: &[f32],
    ) -> Result<Self, GraphError> {
        let n = source.len();
        check_len("offsets", offsets.len(), n + 1)?;
        check_len("caps", caps.len(), targets.len())?;
        check_caps("caps", caps)?;
        if offsets.first() != Some(&0) {
            return Err(GraphError::BadOffsets { node: 0 });
        }
        for v in 0..n {
            if offsets[v] > offsets[v + 1] {
                return Err(GraphError::BadOffsets { node: v });
            }
        }
        if offsets[n] as usize != targets.len() {
            return Err(GraphError::BadOffsets { node: n });
        }
        // Key each arc by its unordered node pair, then merge equal pairs.
        let mut keyed: Vec<(u64, f32, f32)> = Vec::with_capacity(targets.len());
        for u in 0..n {
            for k in offsets[u] as usize..offsets[u + 1] as usize {
                let v = targets[k] as usize;
                if v >= n {
                    return Err(GraphError::NodeOutOfRange {
                        what: "targets",
                        node: v as u64,
                        nodes: n,
                    });
                }
                let c = caps[k];
                if u == v || c == 0.0 {
                    continue;
                }
                let (lo, hi, fwd, bwd) = if u < v {
                    (u, v, c, 0.0)
                } else {
                    (v, u, 0.0, c)
                };
                keyed.push((((lo as u64) << 32) | hi as u64, fwd, bwd));
            }
        }
        keyed.sort_unstable_by_key(|k| k.0);
        let mut edges: Vec<[u32; 2]> = Vec::new();
        let mut fwd: Vec<f32> = Vec::new();
        let mut bwd: Vec<f32> = Vec::new();
        for (key, f, b) in keyed {
            let pair = [(key >> 32) as u32, key as u32];
            if edges.last() == Some(&pair) {
                let last = fwd.len() - 1;
                fwd[last] += f;
                bwd[last] += b;
            } else {
                edges.push(pair);
                fwd.push(f);
                bwd.push(b);
            }
        }
        Self::from_edges(source, sink, &edges, &fwd, &bwd)
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.core.g.len()
    }

    /// Number of edges kept (each a pair of arcs).
    pub fn edge_count(&self) -> usize {
        self.edges
    }

    /// Computes the maximum flow from scratch (PAMI 2004 §3.1–3.2: growth, augmentation,
    /// adoption) and returns its value; the minimum cut is then read with
    /// [`Graph::labels`]. Calling it again after [`Graph::add_tweights`] continues from the
    /// current residual graph and returns the new total.
    pub fn maxflow(&mut self) -> f64 {
        self.core.maxflow(false)
    }

    /// Like [`Graph::maxflow`], but reuses the search trees of the previous solve and
    /// repairs them only around nodes changed by [`Graph::add_tweights`] (dynamic cuts,
    /// Kohli & Torr, as in the reference implementation's `maxflow(reuse_trees)`).
    pub fn maxflow_reuse_trees(&mut self) -> f64 {
        self.core.maxflow(true)
    }

    /// Adds capacities to the t-links of `node` (PAMI 2004 §2 t-links, folded as
    /// source − sink; each at most [`MAX_CAPACITY`] in magnitude). Deltas may be negative as
    /// long as the resulting capacities are not.
    pub fn add_tweights(&mut self, node: u32, source: f32, sink: f32) -> Result<(), GraphError> {
        let n = self.node_count();
        if node as usize >= n {
            return Err(GraphError::NodeOutOfRange {
                what: "add_tweights",
                node: node as u64,
                nodes: n,
            });
        }
        check_delta("source", node as usize, source)?;
        check_delta("sink", node as usize, sink)?;
        self.core.add_tweights(node, source, sink);
        Ok(())
    }

    /// Value of the flow found so far.
    pub fn flow(&self) -> f64 {
        self.core.flow()
    }

    /// Minimum-cut side of `node` after a solve (PAMI 2004 §3.1: S tree, and free nodes, on
    /// the source side); `None` if out of range.
    pub fn is_source(&self, node: u32) -> Option<bool> {
        ((node as usize) < self.node_count()).then(|| self.core.is_source(node))
    }

    /// Minimum-cut labelling after a solve: 1 = source side, 0 = sink side, per node.
    pub fn labels(&self) -> Vec<u8> {
        (0..self.node_count() as u32)
            .map(|v| self.core.is_source(v) as u8)
            .collect()
    }
}
