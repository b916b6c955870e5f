//! Connectivity of `MWP3` patch blobs: a front-based traversal coder (`docs/FORMAT.md`
//! "Connectivity"), in the family of Rossignac's Edgebreaker and of Corto, Nexus' codec.
//!
//! Triangles are visited by growing a front of directed edges from a start triangle. Each
//! front edge `(a, b)` (taken oldest first, so the front grows in rings as Corto's does) is
//! answered by one symbol naming what lies across it:
//!
//! - `VERTEX`: a triangle `(b, a, c)` with a vertex `c` not seen yet (Edgebreaker's *C*);
//!   `c` is predicted by the parallelogram `a + b - o` of the front edge's own triangle
//!   `(a, b, o)` (Touma–Gotsman), so every such vertex gets the best prediction;
//! - `LEFT` / `RIGHT`: `c` is the far end of the previous / next front edge (*L*, *R*);
//! - `END`: both (*E*); `SPLIT`: `c` is another known vertex, coded by its index (*S*);
//! - `BOUNDARY`: no triangle across (the patch border, or a non-manifold or inconsistently
//!   oriented neighbour, which a later start triangle picks up).
//!
//! When the front is exhausted and triangles remain, a start triangle follows with each
//! corner new or an index. Any triangle soup with distinct corners encodes, orientation kept;
//! vertex and triangle order are the traversal's (vertices in order of first use). Symbols
//! are range-coded ([`super::rangecoder`]) in the context of how many triangles already
//! surround the edge's ends and whether its front neighbours are open, as valence coders
//! (Touma–Gotsman) exploit that fans close at about six: on the dragon 2.2 bits a
//! triangle with the patch borders, against 7 for meshoptimizer's index codec after zstd.

use super::rangecoder::{Bit, Channel, Decoder, Encoder, Symbols};

const VERTEX: u32 = 0;
const LEFT: u32 = 1;
const RIGHT: u32 = 2;
const END: u32 = 3;
const SPLIT: u32 = 4;
const BOUNDARY: u32 = 5;
const SYMBOL_BITS: u32 = 3;
/// Triangles already around a gate's ends are counted up to this.
const DEGREE_CAP: u32 = 5;
const CONTEXTS: usize = ((DEGREE_CAP as usize + 1) * (DEGREE_CAP as usize + 1)) << 2;

/// How a vertex's values are predicted from vertices decoded before it (vertex indices are
/// in decoding order, so they are always smaller than the vertex's own).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Prediction {
    /// `a + b - c`
    Parallelogram(u32, u32, u32),
    /// `(a + b) / 2`, floored
    Midpoint(u32, u32),
    Copy(u32),
    /// The first vertex: predicted as zero (positions relative to the patch minimum).
    Zero,
}

/// Why a connectivity stream does not decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrontError;

/// An encoded patch connectivity.
pub struct Encoded {
    pub bytes: Vec<u8>,
    /// Triangles in decoding order, on the new vertex numbering.
    pub indices: Vec<u32>,
    /// `order[new] = old`: the input vertex of each decoded vertex.
    pub order: Vec<u32>,
    /// Each new vertex's prediction.
    pub predictions: Vec<Prediction>,
}

/// The front: directed edges with the third corner of their triangle, in a doubly linked
/// list per loop. Encoder and decoder update it identically.
struct Front {
    edges: Vec<FrontEdge>,
    /// Edges before this one have been taken.
    head: usize,
    /// Triangles output so far around each vertex.
    degree: Vec<u32>,
}

/// A front edge `(a, b)` of the triangle `(a, b, o)`, with its loop neighbours (one record
/// per edge: the traversal reads and writes an edge's fields together).
#[derive(Clone, Copy)]
struct FrontEdge {
    a: u32,
    b: u32,
    o: u32,
    prev: u32,
    next: u32,
    active: bool,
}

impl Front {
    fn new(n: usize) -> Self {
        Front {
            // About one edge per triangle and one per vertex (two triangles a vertex), up to
            // what a patch holds: a hostile count reserves no more.
            edges: Vec::with_capacity((3 * n + 3).min(1 << 16)),
            head: 0,
            degree: vec![0; n],
        }
    }

    /// Counts an output triangle around its corners.
    fn emit(&mut self, t: [u32; 3], out: &mut Vec<u32>) {
        for v in t {
            if let Some(d) = self.degree.get_mut(v as usize) {
                *d += 1;
            }
        }
        out.extend_from_slice(&t);
    }

    /// The symbol context of the edge `e`: how many triangles are already around each of its
    /// ends (a vertex of a regular mesh closes its fan at six, so a high count foretells
    /// `LEFT`, `RIGHT` or `END`), and whether its neighbours on the front are still open.
    fn context(&self, e: u32) -> usize {
        let ei = e as usize;
        let d = |v: u32| self.degree[v as usize].min(DEGREE_CAP) as usize;
        let open = |x: u32| self.edges[x as usize].active as usize;
        let ends = d(self.edges[ei].a) * (DEGREE_CAP as usize + 1) + d(self.edges[ei].b);
        (ends << 2) | (open(self.edges[ei].prev) << 1) | open(self.edges[ei].next)
    }

    fn push(&mut self, a: u32, b: u32, o: u32) -> u32 {
        let e = self.edges.len() as u32;
        self.edges.push(FrontEdge {
            a,
            b,
            o,
            prev: e,
            next: e,
            active: true,
        });
        e
    }

    fn link(&mut self, x: u32, y: u32) {
        self.edges[x as usize].next = y;
        self.edges[y as usize].prev = x;
    }

    /// A start triangle's three edges as one loop.
    fn start(&mut self, t: [u32; 3]) {
        let e0 = self.push(t[0], t[1], t[2]);
        let e1 = self.push(t[1], t[2], t[0]);
        let e2 = self.push(t[2], t[0], t[1]);
        self.link(e0, e1);
        self.link(e1, e2);
        self.link(e2, e0);
    }

    /// The oldest active edge not taken yet (first in, first out: the front grows in rings,
    /// as Corto's does, which on regular meshes makes long runs of one symbol).
    fn pop(&mut self) -> Option<u32> {
        while self.head < self.edges.len() {
            let e = self.head as u32;
            self.head += 1;
            if self.edges[e as usize].active {
                return Some(e);
            }
        }
        None
    }

    /// Whether the previous edge of `e` ends at `e`'s start and begins at `c`.
    fn left_is(&self, e: u32, c: u32) -> bool {
        let p = self.edges[e as usize].prev as usize;
        p != e as usize
            && self.edges[p].active
            && self.edges[p].b == self.edges[e as usize].a
            && self.edges[p].a == c
    }

    fn right_is(&self, e: u32, c: u32) -> bool {
        let q = self.edges[e as usize].next as usize;
        q != e as usize
            && self.edges[q].active
            && self.edges[q].a == self.edges[e as usize].b
            && self.edges[q].b == c
    }

    /// Applies the triangle `(b, a, c)` across the active edge `e` with the given symbol
    /// (not `BOUNDARY`); returns the triangle as it is output.
    fn apply(&mut self, e: u32, symbol: u32, c: u32) -> [u32; 3] {
        let ei = e as usize;
        let (a, b) = (self.edges[ei].a, self.edges[ei].b);
        let (p, q) = (self.edges[ei].prev, self.edges[ei].next);
        self.edges[ei].active = false;
        match symbol {
            LEFT => {
                self.edges[p as usize].active = false;
                let pp = self.edges[p as usize].prev;
                let n = self.push(c, b, a);
                self.link(pp, n);
                self.link(n, q);
            }
            RIGHT => {
                self.edges[q as usize].active = false;
                let qq = self.edges[q as usize].next;
                let n = self.push(a, c, b);
                self.link(p, n);
                self.link(n, qq);
            }
            END => {
                self.edges[p as usize].active = false;
                self.edges[q as usize].active = false;
                let (pp, qq) = (self.edges[p as usize].prev, self.edges[q as usize].next);
                self.link(pp, qq);
            }
            _ => {
                // VERTEX or SPLIT: the edge becomes two.
                let e1 = self.push(a, c, b);
                let e2 = self.push(c, b, a);
                self.link(p, e1);
                self.link(e1, e2);
                self.link(e2, q);
            }
        }
        [a, c, b]
    }
}

struct Contexts {
    symbols: Symbols,
    old: Bit,
    index: Channel,
}

impl Contexts {
    fn new() -> Self {
        Contexts {
            symbols: Symbols::new(SYMBOL_BITS, CONTEXTS),
            old: Bit::default(),
            index: Channel::new(),
        }
    }

    /// Codes the known vertex `v` of `known` ones, counted back from the newest.
    fn put_index(&mut self, enc: &mut Encoder, known: usize, v: u32) {
        self.index.put(enc, known as i64 - 1 - v as i64);
    }

    /// [`Contexts::put_index`]'s vertex; an error unless it is one of the `known`.
    fn get_index(&mut self, dec: &mut Decoder<'_>, known: usize) -> Result<u32, FrontError> {
        let back = self.index.get(dec).ok_or(FrontError)?;
        let v = known as i64 - 1 - back;
        if back < 0 || v < 0 {
            return Err(FrontError);
        }
        Ok(v as u32)
    }
}

/// The prediction of the `k`-th corner of a start triangle whose earlier corners are `t`.
fn start_prediction(k: usize, t: [u32; 3], last: Option<u32>) -> Prediction {
    match k {
        0 => last.map_or(Prediction::Zero, Prediction::Copy),
        1 => Prediction::Copy(t[0]),
        _ => Prediction::Midpoint(t[0], t[1]),
    }
}

/// Encodes a triangle list over `n` vertices; `None` when a triangle repeats a corner or
/// names a vertex beyond `n` (such patches are written in the older layout).
pub fn encode(indices: &[u32], n: usize) -> Option<Encoded> {
    let tris: Vec<[u32; 3]> = indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    if tris
        .iter()
        .any(|t| t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || t.iter().any(|&v| v as usize >= n))
    {
        return None;
    }
    // Directed edges `(a, b)` with their triangle, grouped by `a` (a counting sort, which
    // leaves each group in triangle order): the triangles across `(a, b)` are the entries
    // `(a, f)` of vertex `b`, in triangle order.
    let mut start = vec![0u32; n + 1];
    for t in &tris {
        for &v in t {
            start[v as usize + 1] += 1;
        }
    }
    for v in 0..n {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    let mut edges: Vec<(u32, u32)> = vec![(0, 0); tris.len() * 3];
    for (f, t) in tris.iter().enumerate() {
        for k in 0..3 {
            let slot = &mut fill[t[k] as usize];
            edges[*slot as usize] = (t[(k + 1) % 3], f as u32);
            *slot += 1;
        }
    }
    let mut visited = vec![false; tris.len()];
    let mut new_of = vec![u32::MAX; n];
    let mut order: Vec<u32> = Vec::with_capacity(n);
    let mut predictions: Vec<Prediction> = Vec::with_capacity(n);
    let mut out: Vec<u32> = Vec::with_capacity(indices.len());
    let mut front = Front::new(n);
    let mut ctx = Contexts::new();
    let mut enc = Encoder::new();
    let mut next_start = 0usize;
    let mut done = 0usize;
    while done < tris.len() {
        // A start triangle (old vertex numbering in `t`, new in `s`).
        while visited[next_start] {
            next_start += 1;
        }
        let t = tris[next_start];
        visited[next_start] = true;
        done += 1;
        let mut s = [0u32; 3];
        for k in 0..3 {
            let v = t[k] as usize;
            if new_of[v] == u32::MAX {
                enc.bit(&mut ctx.old, false);
                let prediction = start_prediction(k, s, (order.len() as u32).checked_sub(1));
                new_of[v] = order.len() as u32;
                order.push(v as u32);
                predictions.push(prediction);
            } else {
                enc.bit(&mut ctx.old, true);
                ctx.put_index(&mut enc, order.len(), new_of[v]);
            }
            s[k] = new_of[v];
        }
        front.emit(s, &mut out);
        front.start(s);
        while done < tris.len() {
            let Some(e) = front.pop() else { break };
            let (a, b) = (front.edges[e as usize].a, front.edges[e as usize].b);
            let (oa, ob) = (order[a as usize], order[b as usize]);
            let face = edges[start[ob as usize] as usize..start[ob as usize + 1] as usize]
                .iter()
                .filter(|&&(x, _)| x == oa)
                .map(|&(_, f)| f)
                .find(|&f| !visited[f as usize]);
            let Some(f) = face else {
                ctx.symbols.put(&mut enc, front.context(e), BOUNDARY);
                front.edges[e as usize].active = false;
                continue;
            };
            visited[f as usize] = true;
            done += 1;
            let ft = tris[f as usize];
            let oc = ft
                .into_iter()
                .find(|&v| v != oa && v != ob)
                .unwrap_or(ft[0]);
            let symbol;
            let c;
            if new_of[oc as usize] == u32::MAX {
                symbol = VERTEX;
                c = order.len() as u32;
                new_of[oc as usize] = c;
                order.push(oc);
                predictions.push(Prediction::Parallelogram(a, b, front.edges[e as usize].o));
            } else {
                c = new_of[oc as usize];
                symbol = match (front.left_is(e, c), front.right_is(e, c)) {
                    (true, true) => END,
                    (true, false) => LEFT,
                    (false, true) => RIGHT,
                    (false, false) => SPLIT,
                };
            }
            ctx.symbols.put(&mut enc, front.context(e), symbol);
            if symbol == SPLIT {
                ctx.put_index(&mut enc, order.len(), c);
            }
            let tri = front.apply(e, symbol, c);
            front.emit(tri, &mut out);
        }
    }
    Some(Encoded {
        bytes: enc.finish(),
        indices: out,
        order,
        predictions,
    })
}

/// Decodes `t` triangles over `n` vertices: the triangles and each vertex's prediction.
pub fn decode(bytes: &[u8], n: usize, t: usize) -> Result<(Vec<u32>, Vec<Prediction>), FrontError> {
    let mut dec = Decoder::new(bytes);
    let mut ctx = Contexts::new();
    let mut front = Front::new(n);
    let mut out: Vec<u32> = Vec::with_capacity(3 * t);
    let mut predictions: Vec<Prediction> = Vec::with_capacity(n);
    while out.len() < 3 * t {
        let mut s = [0u32; 3];
        for k in 0..3 {
            if dec.bit(&mut ctx.old) {
                s[k] = ctx.get_index(&mut dec, predictions.len())?;
            } else {
                if predictions.len() >= n {
                    return Err(FrontError);
                }
                let last = (predictions.len() as u32).checked_sub(1);
                predictions.push(start_prediction(k, s, last));
                s[k] = (predictions.len() - 1) as u32;
            }
        }
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            return Err(FrontError);
        }
        front.emit(s, &mut out);
        front.start(s);
        while out.len() < 3 * t {
            let Some(e) = front.pop() else { break };
            let symbol = ctx.symbols.get(&mut dec, front.context(e));
            let ei = e as usize;
            let c = match symbol {
                BOUNDARY => {
                    front.edges[ei].active = false;
                    continue;
                }
                VERTEX => {
                    if predictions.len() >= n {
                        return Err(FrontError);
                    }
                    let (a, b, o) = (front.edges[ei].a, front.edges[ei].b, front.edges[ei].o);
                    predictions.push(Prediction::Parallelogram(a, b, o));
                    (predictions.len() - 1) as u32
                }
                LEFT | END => {
                    let p = front.edges[ei].prev;
                    let c = front.edges[p as usize].a;
                    let ok = front.left_is(e, c) && (symbol == LEFT || front.right_is(e, c));
                    if !ok {
                        return Err(FrontError);
                    }
                    c
                }
                RIGHT => {
                    let q = front.edges[ei].next;
                    let c = front.edges[q as usize].b;
                    if !front.right_is(e, c) {
                        return Err(FrontError);
                    }
                    c
                }
                SPLIT => {
                    let c = ctx.get_index(&mut dec, predictions.len())?;
                    if c == front.edges[ei].a || c == front.edges[ei].b {
                        return Err(FrontError);
                    }
                    c
                }
                _ => return Err(FrontError),
            };
            let tri = front.apply(e, symbol, c);
            front.emit(tri, &mut out);
        }
        if dec.overrun() {
            return Err(FrontError);
        }
    }
    if predictions.len() != n || dec.overrun() {
        return Err(FrontError);
    }
    Ok((out, predictions))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w` x `h` grid of quads split into triangles, with the vertex order scrambled.
    fn grid(w: u32, h: u32) -> (Vec<u32>, usize) {
        let n = ((w + 1) * (h + 1)) as usize;
        let scramble = |v: u32| (v * 7919) % n as u32;
        let mut idx = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let v = y * (w + 1) + x;
                let (a, b, c, d) = (v, v + 1, v + w + 1, v + w + 2);
                idx.extend([a, b, d, a, d, c].map(scramble));
            }
        }
        (idx, n)
    }

    fn canon(idx: &[u32], map: impl Fn(u32) -> u32) -> Vec<[u32; 3]> {
        let mut v: Vec<[u32; 3]> = idx
            .chunks_exact(3)
            .map(|t| {
                let t = [map(t[0]), map(t[1]), map(t[2])];
                let r = (0..3).min_by_key(|&k| t[k]).unwrap_or(0);
                [t[r], t[(r + 1) % 3], t[(r + 2) % 3]]
            })
            .collect();
        v.sort_unstable();
        v
    }

    fn roundtrip(idx: &[u32], n: usize) -> usize {
        let enc = encode(idx, n).expect("encodes");
        let (out, preds) = decode(&enc.bytes, enc.order.len(), idx.len() / 3).expect("decodes");
        assert_eq!(out, enc.indices);
        assert_eq!(preds, enc.predictions);
        // Same triangles, same orientation, in the input's numbering.
        assert_eq!(canon(&out, |v| enc.order[v as usize]), canon(idx, |v| v));
        for (v, p) in preds.iter().enumerate() {
            let below = |x: u32| (x as usize) < v;
            assert!(match *p {
                Prediction::Parallelogram(a, b, c) => below(a) && below(b) && below(c),
                Prediction::Midpoint(a, b) => below(a) && below(b),
                Prediction::Copy(a) => below(a),
                Prediction::Zero => v == 0,
            });
        }
        enc.bytes.len()
    }

    #[test]
    fn grids_soups_and_odd_topology_roundtrip() {
        let (idx, n) = grid(40, 30);
        let bytes = roundtrip(&idx, n);
        // A regular grid costs under a bit a triangle.
        assert!(bytes * 8 < idx.len() / 3, "{bytes} bytes");
        // Closed surface: an octahedron.
        let oct = [
            0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5,
        ];
        roundtrip(&oct, 6);
        // Three triangles on one edge (non-manifold), a flipped neighbour, a lone triangle
        // sharing only a vertex, and an unused vertex (7).
        let odd = [0, 1, 2, 1, 0, 3, 1, 0, 4, 0, 1, 5, 2, 1, 6, 0, 8, 9];
        roundtrip(&odd, 10);
        // Triangle soup: no shared edges at all.
        let soup: Vec<u32> = (0..300).collect();
        roundtrip(&soup, 300);
        // Degenerate triangles are refused.
        assert!(encode(&[0, 0, 1], 2).is_none());
        assert!(encode(&[0, 1, 5], 2).is_none());
    }

    #[test]
    fn corrupt_streams_are_errors() {
        let (idx, n) = grid(12, 9);
        let enc = encode(&idx, n).expect("encodes");
        let t = idx.len() / 3;
        for cut in 0..enc.bytes.len() {
            let _ = decode(&enc.bytes[..cut], n, t);
        }
        let mut bytes = enc.bytes.clone();
        for i in 0..bytes.len() {
            bytes[i] ^= 0x5A;
            if let Ok((out, preds)) = decode(&bytes, n, t) {
                assert_eq!(out.len(), 3 * t);
                assert_eq!(preds.len(), n);
                assert!(out.iter().all(|&v| (v as usize) < n));
            }
            bytes[i] ^= 0x5A;
        }
        assert!(decode(&[0xFF; 8], n, t).is_err());
    }
}
