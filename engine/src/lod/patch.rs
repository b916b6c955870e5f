//! Patches during the build: flat arrays of original vertices plus local triangles, and the
//! scratch file that holds them out of core between levels.

use std::fs::File;
use std::io::{self, Write};
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::Mutex;

/// A patch while building. Every vertex is an input vertex (`ids` are original vertex IDs).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BuildPatch {
    pub ids: Vec<u32>,
    pub positions: Vec<[f32; 3]>,
    /// Empty when the model has no colour.
    pub colors: Vec<[u8; 4]>,
    pub normals: Vec<[f32; 3]>,
    /// Local indices, three per triangle.
    pub indices: Vec<u32>,
}

/// The root of `v` in the union-find forest `parent` (every root its own parent), halving
/// the path on the way.
pub fn find_root(parent: &mut [u32], mut v: u32) -> u32 {
    while parent[v as usize] != v {
        let up = parent[parent[v as usize] as usize];
        parent[v as usize] = up;
        v = up;
    }
    v
}

/// Undirected edge between two original vertices, as one sortable key.
#[inline]
pub fn edge_key(a: u32, b: u32) -> u64 {
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    ((lo as u64) << 32) | hi as u64
}

/// The edges of a set of triangles, each with the number of triangles that use it: the one
/// border rule of the hierarchy. An edge used by exactly one triangle is on the border; by
/// two, interior; by three or more, non-manifold (counted as interior by [`EdgeUses::border`]).
#[derive(Debug, Clone, Default)]
pub struct EdgeUses {
    /// Every triangle's three edge keys ([`edge_key`]), sorted.
    keys: Vec<u64>,
}

impl EdgeUses {
    /// The edges of `triangles` (three vertex ids each, in whatever id space the caller uses).
    pub fn of(triangles: impl Iterator<Item = [u32; 3]>) -> EdgeUses {
        let mut keys: Vec<u64> = triangles
            .flat_map(|[a, b, c]| [edge_key(a, b), edge_key(b, c), edge_key(c, a)])
            .collect();
        keys.sort_unstable();
        EdgeUses { keys }
    }

    /// Each distinct edge key with its number of uses, in key order.
    pub fn counts(&self) -> impl Iterator<Item = (u64, usize)> + '_ {
        self.keys
            .chunk_by(|a, b| a == b)
            .map(|run| (run[0], run.len()))
    }

    /// The border: edges used by exactly one triangle, in key order.
    pub fn border(&self) -> impl Iterator<Item = u64> + '_ {
        self.counts().filter(|&(_, n)| n == 1).map(|(k, _)| k)
    }
}

/// The two original vertex IDs of an edge key.
#[inline]
pub fn edge_ends(key: u64) -> (u32, u32) {
    ((key >> 32) as u32, key as u32)
}

/// Whether a triangle repeats a corner (covers no surface; the simplifier's topology checks
/// leave such triangles out).
pub fn degenerate(t: &[u32]) -> bool {
    t[0] == t[1] || t[1] == t[2] || t[0] == t[2]
}

/// Each distinct edge of `indices` (corners below `n`) with its number of uses, sorted by
/// the key `lo << 32 | hi` of its two ends (as [`edge_key`]); triangles repeating a corner
/// are left out with `skip_degenerate`. A counting sort by the lower end, then a small sort
/// of each vertex's few higher ends: linear in the triangles, where sorting all `3T` keys
/// took a tenth of a build.
pub fn edge_runs(indices: &[u32], n: usize, skip_degenerate: bool) -> Vec<(u64, u32)> {
    let triangles = || {
        indices
            .chunks_exact(3)
            .filter(move |t| !(skip_degenerate && degenerate(t)))
    };
    let mut start = vec![0u32; n + 1];
    for t in triangles() {
        for k in 0..3 {
            start[t[k].min(t[(k + 1) % 3]) as usize + 1] += 1;
        }
    }
    for v in 0..n {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    let mut higher = vec![0u32; start[n] as usize];
    for t in triangles() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let slot = &mut fill[a.min(b) as usize];
            higher[*slot as usize] = a.max(b);
            *slot += 1;
        }
    }
    let mut out: Vec<(u64, u32)> = Vec::with_capacity(higher.len() / 2 + 1);
    for lo in 0..n {
        let ends = &mut higher[start[lo] as usize..start[lo + 1] as usize];
        sort_small(ends);
        for &hi in ends.iter() {
            let key = edge_key(lo as u32, hi);
            match out.last_mut() {
                Some((k, c)) if *k == key => *c += 1,
                _ => out.push((key, 1)),
            }
        }
    }
    out
}

/// A half-edge's higher end and its triangle as one integer, ordered as the pair
/// `(higher, triangle)`: the small per-vertex sorts compare one integer instead of a tuple.
#[inline]
pub fn half_edge(higher: u32, triangle: u32) -> u64 {
    ((higher as u64) << 32) | triangle as u64
}

/// The users of each edge of `indices`: every triangle's edges as [`half_edge`]`(higher end,
/// triangle)`, grouped by lower end (group `v` is `half[start[v]..start[v + 1]]`, for every
/// `v` up to the largest index) and each group sorted, so an edge's users are a run in
/// triangle order (`group.chunk_by(|p, q| p >> 32 == q >> 32)`). The same runs, in the same
/// order, as sorting every (edge key, triangle) pair, in linear time: a counting sort on the
/// lower end and a small sort of each vertex's few half-edges. Returns `(start, half)`.
pub fn edge_users(indices: &[u32]) -> (Vec<u32>, Vec<u64>) {
    let n = indices.iter().max().map_or(0, |&m| m as usize + 1);
    let mut start = vec![0u32; n + 1];
    for t in indices.chunks_exact(3) {
        for k in 0..3 {
            start[t[k].min(t[(k + 1) % 3]) as usize + 1] += 1;
        }
    }
    for v in 0..n {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    let mut half: Vec<u64> = vec![0; indices.len() / 3 * 3];
    for (f, t) in indices.chunks_exact(3).enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let slot = &mut fill[a.min(b) as usize];
            half[*slot as usize] = half_edge(a.max(b), f as u32);
            *slot += 1;
        }
    }
    for v in 0..n {
        sort_small(&mut half[start[v] as usize..start[v + 1] as usize]);
    }
    (start, half)
}

/// Sorts a short slice (a vertex's few edges) by insertion, inline, and a longer one by the
/// standard sort: the standard sort's call for each of a mesh's vertices cost more than the
/// sorting (1% of a build). For element types whose equal values are identical (integers and
/// tuples of them) the result is the standard sort's.
#[inline]
pub fn sort_small<T: Ord + Copy>(s: &mut [T]) {
    if s.len() > 12 {
        s.sort_unstable();
        return;
    }
    for i in 1..s.len() {
        let x = s[i];
        let mut j = i;
        while j > 0 && s[j - 1] > x {
            s[j] = s[j - 1];
            j -= 1;
        }
        s[j] = x;
    }
}

/// Entries keyed by a vertex (or any key) below `n`, grouped by a counting sort: a membership
/// test reads only its key's few entries (cheaper than hashing every triangle and edge of a
/// group), and each key's entries can be sorted alone.
pub(crate) struct ByVertex<T> {
    start: Vec<u32>,
    items: Vec<T>,
}

impl<T: Copy + Default + PartialEq> ByVertex<T> {
    pub(crate) fn new(n: usize, entries: impl Iterator<Item = (u32, T)> + Clone) -> ByVertex<T> {
        // `for_each` rather than `for`: callers pass flattened iterators (a triangle's
        // neighbours per triangle), which iterate internally as nested loops, where `next`
        // re-enters the flattening at each item (2% of a build, in the partition's links).
        let mut start = vec![0u32; n + 1];
        entries
            .clone()
            .for_each(|(v, _)| start[v as usize + 1] += 1);
        for v in 0..n {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        let mut items = vec![T::default(); start[n] as usize];
        entries.for_each(|(v, item)| {
            let slot = &mut fill[v as usize];
            items[*slot as usize] = item;
            *slot += 1;
        });
        ByVertex { start, items }
    }

    pub(crate) fn of(&self, v: u32) -> &[T] {
        let v = v as usize;
        if v + 1 < self.start.len() {
            &self.items[self.start[v] as usize..self.start[v + 1] as usize]
        } else {
            &[]
        }
    }

    pub(crate) fn of_mut(&mut self, v: u32) -> &mut [T] {
        let v = v as usize;
        if v + 1 < self.start.len() {
            &mut self.items[self.start[v] as usize..self.start[v + 1] as usize]
        } else {
            &mut []
        }
    }
}

/// The corner after corner `c` in its triangle (corners `3f`, `3f + 1`, `3f + 2`).
#[inline]
pub fn next_corner(c: usize) -> usize {
    c - c % 3 + (c + 1) % 3
}

/// Every corner `c` of the triangles of `indices` kept by `keep` (corners below `n`) with the
/// key ([`edge_key`]) of its edge, from `indices[c]` to the next corner of its triangle,
/// sorted by key and then by corner: what sorting all `(key, corner)` pairs gives, by a
/// counting sort on the lower end and a small sort of each vertex's few edges, as in
/// [`edge_runs`]. Runs of equal keys are the triangles that share an edge. (`edge_runs` keeps
/// its own loop: built on this one, with a sort pass apart from its counting, it took a fifth
/// longer, and it is 6% of a build.)
pub fn edge_corners(indices: &[u32], n: usize, keep: impl Fn(usize) -> bool) -> Vec<(u64, u32)> {
    let kept = || (0..indices.len() - indices.len() % 3).filter(|&c| keep(c / 3));
    let mut start = vec![0u32; n + 1];
    for c in kept() {
        start[indices[c].min(indices[next_corner(c)]) as usize + 1] += 1;
    }
    for v in 0..n {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    let mut out = vec![(0u64, 0u32); start[n] as usize];
    for c in kept() {
        let key = edge_key(indices[c], indices[next_corner(c)]);
        let slot = &mut fill[(key >> 32) as usize];
        out[*slot as usize] = (key, c as u32);
        *slot += 1;
    }
    for v in 0..n {
        sort_small(&mut out[start[v] as usize..start[v + 1] as usize]);
    }
    out
}

impl BuildPatch {
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Edges used by exactly one triangle of this patch (its border), as sorted keys of
    /// original IDs. Edges used by three or more triangles (non-manifold) count as interior.
    /// A build's patches have one vertex per original ID (buckets and groups are welded by
    /// ID), so the border is found on local indices ([`edge_runs`], a counting sort) and only
    /// its edges are keyed and sorted by ID.
    pub fn border_edges(&self) -> Vec<u64> {
        debug_assert!(
            {
                let mut ids = self.ids.clone();
                ids.sort_unstable();
                ids.windows(2).all(|w| w[0] != w[1])
            },
            "a patch with two vertices of one original ID"
        );
        let mut border: Vec<u64> = self
            .local_border_edges()
            .map(|(a, b)| edge_key(self.ids[a as usize], self.ids[b as usize]))
            .collect();
        border.sort_unstable();
        border
    }

    /// The border edges ([`Self::border_edges`]) as pairs of local vertex indices, in the
    /// order of their local keys.
    pub fn local_border_edges(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        edge_runs(&self.indices, self.ids.len(), false)
            .into_iter()
            .filter(|&(_, uses)| uses == 1)
            .map(|(key, _)| edge_ends(key))
    }

    /// Byte offset of the original IDs in the scratch record.
    pub const IDS_OFFSET: u64 = 16;

    /// Serialises to the scratch format (native layout; never leaves the build machine).
    pub fn to_bytes(&self) -> Vec<u8> {
        let n = self.ids.len();
        let mut out = Vec::with_capacity(16 + n * 32 + self.indices.len() * 4);
        for v in [
            n as u32,
            self.indices.len() as u32,
            !self.colors.is_empty() as u32,
            !self.normals.is_empty() as u32,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(bytemuck::cast_slice(&self.ids));
        out.extend_from_slice(bytemuck::cast_slice(&self.positions));
        out.extend_from_slice(bytemuck::cast_slice(&self.colors));
        out.extend_from_slice(bytemuck::cast_slice(&self.normals));
        out.extend_from_slice(bytemuck::cast_slice(&self.indices));
        out
    }

    /// Reads back what [`BuildPatch::to_bytes`] wrote.
    pub fn from_bytes(bytes: &[u8]) -> io::Result<BuildPatch> {
        let bad = || io::Error::new(io::ErrorKind::InvalidData, "corrupt scratch patch");
        let word = |i: usize| -> io::Result<usize> {
            let b = bytes.get(i * 4..i * 4 + 4).ok_or_else(bad)?;
            Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        };
        let (n, ni, has_c, has_n) = (word(0)?, word(1)?, word(2)? != 0, word(3)? != 0);
        let mut at = 16;
        let mut take = |len: usize| -> io::Result<&[u8]> {
            let s = bytes.get(at..at + len).ok_or_else(bad)?;
            at += len;
            Ok(s)
        };
        let ids = bytemuck::pod_collect_to_vec(take(n * 4)?);
        let positions = bytemuck::pod_collect_to_vec(take(n * 12)?);
        let colors = if has_c {
            bytemuck::pod_collect_to_vec(take(n * 4)?)
        } else {
            Vec::new()
        };
        let normals = if has_n {
            bytemuck::pod_collect_to_vec(take(n * 12)?)
        } else {
            Vec::new()
        };
        let indices = bytemuck::pod_collect_to_vec(take(ni * 4)?);
        Ok(BuildPatch {
            ids,
            positions,
            colors,
            normals,
            indices,
        })
    }
}

/// An append-only scratch file of byte records, readable concurrently by offset.
pub struct ScratchFile {
    file: File,
    tail: Mutex<(io::BufWriter<File>, u64)>,
}

impl ScratchFile {
    pub fn create(path: &Path) -> io::Result<ScratchFile> {
        let file = File::options()
            .create(true)
            .truncate(true)
            .read(true)
            .write(true)
            .open(path)?;
        let writer = io::BufWriter::with_capacity(1 << 20, file.try_clone()?);
        Ok(ScratchFile {
            file,
            tail: Mutex::new((writer, 0)),
        })
    }

    /// Appends a record; returns its offset.
    pub fn append(&self, bytes: &[u8]) -> io::Result<u64> {
        let mut tail = self
            .tail
            .lock()
            .map_err(|_| io::Error::other("scratch lock poisoned"))?;
        let offset = tail.1;
        tail.0.write_all(bytes)?;
        tail.1 += bytes.len() as u64;
        Ok(offset)
    }

    /// Makes everything appended so far readable.
    pub fn flush(&self) -> io::Result<()> {
        let mut tail = self
            .tail
            .lock()
            .map_err(|_| io::Error::other("scratch lock poisoned"))?;
        tail.0.flush()
    }

    /// Reads a record (after [`ScratchFile::flush`]).
    pub fn read(&self, offset: u64, len: usize) -> io::Result<Vec<u8>> {
        let mut buf = vec![0u8; len];
        self.file.read_exact_at(&mut buf, offset)?;
        Ok(buf)
    }

    /// Bytes appended so far.
    pub fn len(&self) -> u64 {
        self.tail.lock().map(|t| t.1).unwrap_or(0)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_small_sort_is_the_standard_sort() {
        let mut next = crate::testing::xorshift(5);
        for len in 0..40 {
            let values: Vec<(u32, u32)> = (0..len).map(|_| (next() % 9, next() % 4)).collect();
            let mut small = values.clone();
            sort_small(&mut small);
            let mut standard = values;
            standard.sort_unstable();
            assert_eq!(small, standard, "{len} values");
        }
    }

    #[test]
    fn border_of_two_triangles_is_the_quad_outline() {
        let p = BuildPatch {
            ids: vec![10, 11, 12, 13],
            positions: vec![[0.0; 3]; 4],
            indices: vec![0, 1, 2, 0, 2, 3],
            ..Default::default()
        };
        let mut expect = vec![
            edge_key(10, 11),
            edge_key(11, 12),
            edge_key(12, 13),
            edge_key(13, 10),
        ];
        expect.sort_unstable();
        assert_eq!(p.border_edges(), expect);
        assert_eq!(BuildPatch::from_bytes(&p.to_bytes()).expect("roundtrip"), p);
    }
}
