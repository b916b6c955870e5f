//! The `.mwseg` file: a model's surface segments at every scale, beside its `.mwlod` (same
//! name, other extension). Little-endian, every field 4-byte aligned (docs/FORMAT.md):
//!
//! ```text
//! magic        8 bytes  "MWSEG\0\0\x01"
//! vertices     u64      original vertices of the scan
//! fine         u32      fine segments (scale 0)
//! scales       u32      K coarser scales
//! counts       u32 × K  segments per coarser scale, finest first
//! labels       u32 × K × fine   per coarser scale, each fine segment's segment there
//! strengths    f32 × (fine + Σ counts)  per scale, fine first, each segment's boundary
//!                               strength when it was merged (+∞: never)
//! vertex       u32 × vertices   each original vertex's fine segment (u32::MAX: in no face)
//! ```
//!
//! A pixel of the id buffer names an original vertex, so its segment at any scale is two
//! lookups: `labels[k][vertex[v]]`.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use memmap2::Mmap;
use roaring::RoaringBitmap;

use super::merge::Hierarchy;

/// First bytes of a `.mwseg` file.
pub const MAGIC: [u8; 8] = *b"MWSEG\0\0\x01";
/// A vertex in no segment.
pub const NONE: u32 = u32::MAX;
/// Segments at the scale first offered for picking whole segments
/// ([`SegmentFile::suggested_scale`]): about as many as a user tells apart at a glance.
pub const SUGGESTED_SEGMENTS: u32 = 48;

/// Why a segment file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum SegmentFileError {
    #[error("segment file I/O failed: {0}")]
    Io(#[from] io::Error),
    #[error("not a valid segment file: {0}")]
    Invalid(&'static str),
}

/// The segment file of the LOD file at `lod`.
pub fn path_for(lod: &Path) -> PathBuf {
    lod.with_extension("mwseg")
}

/// An open (mapped) segment file.
pub struct SegmentFile {
    map: Mmap,
    vertices: u64,
    fine: u32,
    counts: Vec<u32>,
    labels_at: usize,
    /// Per scale, where its strengths start.
    strengths_at: Vec<usize>,
    vertex_at: usize,
}

impl std::fmt::Debug for SegmentFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SegmentFile")
            .field("vertices", &self.vertices)
            .field("fine", &self.fine)
            .field("counts", &self.counts)
            .finish()
    }
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    let mut b = [0u8; 4];
    b.copy_from_slice(&bytes[at..at + 4]);
    u32::from_le_bytes(b)
}

impl SegmentFile {
    /// Maps and checks the file at `path`.
    pub fn open(path: &Path) -> Result<SegmentFile, SegmentFileError> {
        let file = File::open(path)?;
        // SAFETY: segment files are immutable once renamed into place (written under a
        // temporary name, like LOD files); nothing truncates them while mapped.
        let map = unsafe { Mmap::map(&file)? };
        Self::from_map(map)
    }

    fn from_map(map: Mmap) -> Result<SegmentFile, SegmentFileError> {
        let b = &map[..];
        if b.len() < 24 || b[..8] != MAGIC {
            return Err(SegmentFileError::Invalid("bad magic"));
        }
        let mut v = [0u8; 8];
        v.copy_from_slice(&b[8..16]);
        let vertices = u64::from_le_bytes(v);
        let fine = u32_at(b, 16);
        let k = u32_at(b, 20) as usize;
        if k > 64 {
            return Err(SegmentFileError::Invalid("too many scales"));
        }
        let labels_at = 24 + 4 * k;
        if b.len() < labels_at {
            return Err(SegmentFileError::Invalid("truncated header"));
        }
        let counts: Vec<u32> = (0..k).map(|i| u32_at(b, 24 + 4 * i)).collect();
        let mut at = (fine as u64)
            .checked_mul(4 * k as u64)
            .and_then(|x| x.checked_add(labels_at as u64))
            .ok_or(SegmentFileError::Invalid("sizes overflow"))?;
        let mut strengths_at = Vec::with_capacity(k + 1);
        for c in std::iter::once(fine).chain(counts.iter().copied()) {
            strengths_at.push(at as usize);
            at += 4 * c as u64;
        }
        let vertex_at = at;
        let end = vertices
            .checked_mul(4)
            .and_then(|x| x.checked_add(vertex_at))
            .ok_or(SegmentFileError::Invalid("sizes overflow"))?;
        if b.len() as u64 != end {
            return Err(SegmentFileError::Invalid("size does not match the header"));
        }
        let f = SegmentFile {
            vertices,
            fine,
            counts,
            labels_at,
            strengths_at,
            vertex_at: vertex_at as usize,
            map,
        };
        // Every label names a segment of its scale.
        for s in 0..k {
            let count = f.counts[s];
            if (0..fine).any(|x| f.coarse(s, x) >= count) {
                return Err(SegmentFileError::Invalid("a label beyond its scale"));
            }
        }
        Ok(f)
    }

    /// Original vertices covered.
    pub fn vertices(&self) -> u64 {
        self.vertices
    }

    /// Scales, the fine one (0) included.
    pub fn scales(&self) -> usize {
        self.counts.len() + 1
    }

    /// Segments at `scale` (0: fine).
    pub fn count(&self, scale: usize) -> u32 {
        match scale {
            0 => self.fine,
            s => self.counts.get(s - 1).copied().unwrap_or(0),
        }
    }

    fn coarse(&self, s: usize, fine: u32) -> u32 {
        u32_at(
            &self.map,
            self.labels_at + 4 * (s * self.fine as usize + fine as usize),
        )
    }

    /// The fine segment of original vertex `vertex`.
    pub fn fine_of(&self, vertex: u32) -> Option<u32> {
        if vertex as u64 >= self.vertices {
            return None;
        }
        let f = u32_at(&self.map, self.vertex_at + 4 * vertex as usize);
        (f != NONE && f < self.fine).then_some(f)
    }

    /// The segment at `scale` of fine segment `fine` (itself at scale 0).
    pub fn at_scale(&self, scale: usize, fine: u32) -> Option<u32> {
        if fine >= self.fine || scale >= self.scales() {
            return None;
        }
        Some(if scale == 0 {
            fine
        } else {
            self.coarse(scale - 1, fine)
        })
    }

    /// The segment at `scale` of original vertex `vertex` (`None`: a vertex in no face, or
    /// beyond the file, or a scale it does not have).
    pub fn segment_of(&self, vertex: u32, scale: usize) -> Option<u32> {
        self.at_scale(scale, self.fine_of(vertex)?)
    }

    /// The original vertices of segment `segment` at `scale` (`None`: no such segment): its
    /// fine segments are marked, then the per-vertex array is read once in id order.
    pub fn members(&self, scale: usize, segment: u32) -> Option<RoaringBitmap> {
        if scale >= self.scales() || segment >= self.count(scale) {
            return None;
        }
        let inside: Vec<bool> = (0..self.fine)
            .map(|f| self.at_scale(scale, f) == Some(segment))
            .collect();
        let bytes = &self.map[self.vertex_at..self.vertex_at + 4 * self.vertices as usize];
        let ids = bytes.chunks_exact(4).enumerate().filter_map(|(v, b)| {
            let f = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            inside
                .get(f as usize)
                .copied()
                .unwrap_or(false)
                .then_some(v as u32)
        });
        // Ids come in increasing order, so this cannot fail.
        RoaringBitmap::from_sorted_iter(ids).ok()
    }

    /// The scale a viewer offers first for picking whole segments: the finest with at most
    /// [`SUGGESTED_SEGMENTS`] segments (the coarsest when none has so few).
    pub fn suggested_scale(&self) -> usize {
        (0..self.scales())
            .find(|&s| self.count(s) <= SUGGESTED_SEGMENTS)
            .unwrap_or(self.scales() - 1)
    }

    /// The boundary strength of segment `segment` at `scale` when it was merged into a
    /// larger one (+∞: never; see [`super::merge::Hierarchy::strengths`]).
    pub fn strength(&self, scale: usize, segment: u32) -> f32 {
        match self.strengths_at.get(scale) {
            Some(&at) if segment < self.count(scale) => {
                f32::from_bits(u32_at(&self.map, at + 4 * segment as usize))
            }
            _ => f32::INFINITY,
        }
    }
}

/// Writes a segment file to `path`: the hierarchy and, for each original vertex in order, its
/// fine segment ([`NONE`] for none).
pub fn write(
    path: &Path,
    hierarchy: &Hierarchy,
    vertices: u64,
    vertex_fine: impl Iterator<Item = u32>,
) -> io::Result<()> {
    let mut w = BufWriter::with_capacity(1 << 20, File::create(path)?);
    w.write_all(&MAGIC)?;
    w.write_all(&vertices.to_le_bytes())?;
    w.write_all(&hierarchy.fine.to_le_bytes())?;
    w.write_all(&(hierarchy.counts.len() as u32).to_le_bytes())?;
    for c in &hierarchy.counts {
        w.write_all(&c.to_le_bytes())?;
    }
    for scale in &hierarchy.scales {
        for x in scale {
            w.write_all(&x.to_le_bytes())?;
        }
    }
    let counts = std::iter::once(hierarchy.fine).chain(hierarchy.counts.iter().copied());
    for (k, count) in counts.enumerate() {
        for i in 0..count as usize {
            let s = hierarchy
                .strengths
                .get(k)
                .and_then(|v| v.get(i))
                .copied()
                .unwrap_or(f32::INFINITY);
            w.write_all(&s.to_le_bytes())?;
        }
    }
    let mut written = 0u64;
    for f in vertex_fine.take(vertices as usize) {
        w.write_all(&f.to_le_bytes())?;
        written += 1;
    }
    for _ in written..vertices {
        w.write_all(&NONE.to_le_bytes())?;
    }
    w.into_inner().map_err(|e| e.into_error())?.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hierarchy() -> Hierarchy {
        Hierarchy {
            fine: 4,
            scales: vec![vec![0, 0, 1, 1], vec![0, 0, 0, 0]],
            counts: vec![2, 1],
            strengths: vec![vec![0.5; 4], vec![2.0, 3.0], vec![f32::INFINITY]],
        }
    }

    #[test]
    fn a_written_file_reads_back() {
        let dir = std::env::temp_dir().join(format!("mw-segfile-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mwseg");
        write(&path, &hierarchy(), 6, [0, 1, NONE, 2, 3].into_iter()).unwrap();
        let f = SegmentFile::open(&path).unwrap();
        assert_eq!((f.vertices(), f.scales()), (6, 3));
        assert_eq!(
            (f.count(0), f.count(1), f.count(2), f.count(3)),
            (4, 2, 1, 0)
        );
        assert_eq!(f.fine_of(1), Some(1));
        assert_eq!(f.fine_of(2), None);
        // Vertices past the iterator are in no segment; ids past the file are none.
        assert_eq!((f.fine_of(5), f.fine_of(6)), (None, None));
        assert_eq!(f.at_scale(1, 3), Some(1));
        assert_eq!(f.at_scale(0, 3), Some(3));
        assert_eq!(f.at_scale(3, 0), None);
        let scale_1: Vec<_> = (0..4).map(|x| f.at_scale(1, x)).collect();
        assert_eq!(scale_1, [Some(0), Some(0), Some(1), Some(1)]);
        assert_eq!(f.strength(1, 1), 3.0);
        assert_eq!(f.strength(2, 0), f32::INFINITY);
        assert_eq!(f.strength(1, 2), f32::INFINITY);
        // A segment's vertices at each scale; vertices in no face belong to none.
        let members = |scale, seg| f.members(scale, seg).map(|b| b.iter().collect::<Vec<_>>());
        assert_eq!(members(0, 2), Some(vec![3]));
        assert_eq!(members(1, 0), Some(vec![0, 1]));
        assert_eq!(members(1, 1), Some(vec![3, 4]));
        assert_eq!(members(2, 0), Some(vec![0, 1, 3, 4]));
        assert_eq!((members(1, 2), members(3, 0)), (None, None));
        assert_eq!((f.segment_of(4, 1), f.segment_of(2, 1)), (Some(1), None));
        assert_eq!(f.segment_of(4, 3), None);
        // Every scale has at most SUGGESTED_SEGMENTS here: the finest is offered.
        assert_eq!(f.suggested_scale(), 0);

        // Truncated, wrong magic, a label beyond its scale: errors, never a panic.
        let bytes = std::fs::read(&path).unwrap();
        for cut in [0, 7, 23, 30, bytes.len() - 1] {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            assert!(SegmentFile::open(&path).is_err(), "cut at {cut}");
        }
        let mut bad = bytes.clone();
        bad[0] = b'X';
        std::fs::write(&path, &bad).unwrap();
        assert!(SegmentFile::open(&path).is_err());
        let mut bad = bytes.clone();
        let labels_at = 24 + 4 * 2;
        bad[labels_at..labels_at + 4].copy_from_slice(&9u32.to_le_bytes());
        std::fs::write(&path, &bad).unwrap();
        assert!(matches!(
            SegmentFile::open(&path),
            Err(SegmentFileError::Invalid(_))
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
