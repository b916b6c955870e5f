//! Machinery shared by the readers: batched delivery to the sink, progress and cancellation,
//! size checks against the file length, a bounded line reader, tokens and numbers, welding.

use super::{
    ImportError, ImportErrorKind, ImportStats, Location, MeshSink, SourceInfo, SourceTexture,
    TexturedFace, VertexBatch,
};
use crate::progress::Progress;
use std::collections::HashMap;
use std::fs::File;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::Path;

/// Vertices or triangles per sink call.
pub(crate) const BATCH: usize = 1 << 16;

/// Longest text line accepted (a single huge polygon or triangle strip can be long).
pub(crate) const MAX_LINE: usize = 64 << 20;

pub(crate) fn err(path: &Path, location: Location, kind: ImportErrorKind) -> ImportError {
    ImportError::new(path, location, kind)
}

/// Opens `path` as a regular, non-empty file and returns it with its length.
pub(crate) fn open(path: &Path) -> Result<(File, u64), ImportError> {
    let io = |e: std::io::Error| err(path, Location::File, ImportErrorKind::Io(e.to_string()));
    let file = File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(err(
            path,
            Location::File,
            ImportErrorKind::Io("not a regular file".into()),
        ));
    }
    if meta.len() == 0 {
        return Err(err(
            path,
            Location::File,
            ImportErrorKind::Truncated("the file is empty".into()),
        ));
    }
    Ok((file, meta.len()))
}

/// Memory-maps a whole file for reading.
pub(crate) fn map(path: &Path, file: &File) -> Result<memmap2::Mmap, ImportError> {
    // SAFETY: the map is read-only and private to this import; like every mmap reader we
    // rely on nobody truncating the file while it is read (the server imports from its own
    // upload directory).
    let map = unsafe { memmap2::Mmap::map(file) }
        .map_err(|e| err(path, Location::File, ImportErrorKind::Io(e.to_string())))?;
    #[cfg(unix)]
    {
        let _ = map.advise(memmap2::Advice::Sequential);
    }
    Ok(map)
}

/// Describes a coordinate that is not a finite `f32` (NaN, infinity or out of float range).
pub(crate) fn non_finite(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf".into() } else { "-inf".into() }
    } else {
        format!("{v:e} is outside the float range")
    }
}

/// The first non-finite value of a position, if any.
#[inline]
pub(crate) fn check_finite(p: [f32; 3]) -> Option<String> {
    if p[0].is_finite() && p[1].is_finite() && p[2].is_finite() {
        None
    } else {
        let bad = p
            .iter()
            .find(|c| !c.is_finite())
            .copied()
            .unwrap_or(f32::NAN);
        Some(non_finite(bad as f64))
    }
}

/// Batches vertices and triangles towards a sink, keeps the statistics, reports progress.
pub(crate) struct Emitter<'a> {
    path: &'a Path,
    sink: &'a mut dyn MeshSink,
    progress: &'a dyn Progress,
    colors: bool,
    normals: bool,
    pos: Vec<[f32; 3]>,
    col: Vec<[u8; 4]>,
    nrm: Vec<[f32; 3]>,
    tris: Vec<[u32; 3]>,
    /// Texture coordinates of `tris`, once the reader has handed over a texture.
    faces: Vec<TexturedFace>,
    textured: bool,
    reported: u64,
    /// Memory-mapped input whose consumed prefix is released as reading advances, so a
    /// multi-GB input never counts against the process's resident memory all at once.
    map: Option<std::sync::Arc<memmap2::Mmap>>,
    released: u64,
    pub stats: ImportStats,
}

/// Consumed input is handed back to the kernel in steps of this many bytes.
const RELEASE_STEP: u64 = 32 << 20;

impl<'a> Emitter<'a> {
    /// Starts the progress stage `stage` measured in `total` units (bytes of input).
    pub fn new(
        path: &'a Path,
        sink: &'a mut dyn MeshSink,
        progress: &'a dyn Progress,
        stage: &str,
        total: u64,
    ) -> Self {
        progress.stage(stage, total);
        Emitter {
            path,
            sink,
            progress,
            colors: false,
            normals: false,
            pos: Vec::new(),
            col: Vec::new(),
            nrm: Vec::new(),
            tris: Vec::new(),
            faces: Vec::new(),
            textured: false,
            reported: 0,
            map: None,
            released: 0,
            stats: ImportStats::default(),
        }
    }

    /// Releases the pages of `map` that [`Emitter::tick`] reports as consumed.
    pub fn release_consumed(&mut self, map: std::sync::Arc<memmap2::Mmap>) {
        self.map = Some(map);
    }

    pub fn begin(&mut self, info: &SourceInfo) -> Result<(), ImportError> {
        self.colors = info.has_colors;
        self.normals = info.has_normals;
        self.stats.has_colors = info.has_colors;
        self.stats.has_normals = info.has_normals;
        self.pos.reserve(BATCH);
        if self.colors {
            self.col.reserve(BATCH);
        }
        if self.normals {
            self.nrm.reserve(BATCH);
        }
        self.tris.reserve(BATCH);
        self.sink.begin(info).map_err(|e| e.with_path(self.path))
    }

    /// Hands a texture to the sink (before the first triangle); from then on every triangle
    /// carries texture coordinates ([`Emitter::textured_triangle`], or none).
    pub fn texture(&mut self, texture: SourceTexture) -> Result<(), ImportError> {
        self.textured = true;
        self.stats.textures += 1;
        self.sink
            .texture(texture)
            .map_err(|e| e.with_path(self.path))
    }

    /// Whether triangles carry texture coordinates.
    pub fn textured(&self) -> bool {
        self.textured
    }

    /// Queues a triangle with its corners' texture coordinates.
    pub fn textured_triangle(
        &mut self,
        t: [u32; 3],
        face: TexturedFace,
    ) -> Result<(), ImportError> {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            self.stats.degenerate_faces += 1;
            return Ok(());
        }
        self.tris.push(t);
        self.faces.push(face);
        self.stats.triangles += 1;
        if self.tris.len() >= BATCH {
            self.flush_triangles()?;
        }
        Ok(())
    }

    /// [`Emitter::polygon`] with texture coordinates per corner (`uvs[k]` for `idx[k]`).
    pub fn textured_polygon(
        &mut self,
        idx: &[u32],
        uvs: &[[f32; 2]],
        texture: u32,
    ) -> Result<(), ImportError> {
        if idx.len() < 3 || uvs.len() != idx.len() {
            self.stats.degenerate_faces += 1;
            return Ok(());
        }
        if idx.len() > 3 {
            self.stats.polygons_triangulated += 1;
        }
        for k in 1..idx.len() - 1 {
            let face = TexturedFace {
                uv: [uvs[0], uvs[k], uvs[k + 1]],
                texture,
            };
            self.textured_triangle([idx[0], idx[k], idx[k + 1]], face)?;
        }
        Ok(())
    }

    /// Vertices pushed so far (delivered or pending); the next vertex gets this ID.
    #[inline]
    pub fn vertex_count(&self) -> u64 {
        self.stats.vertices
    }

    /// Queues one vertex; colour and normal are ignored unless announced in `begin`.
    #[inline]
    pub fn vertex(&mut self, p: [f32; 3], c: [u8; 4], n: [f32; 3]) -> Result<(), ImportError> {
        self.pos.push(p);
        if self.colors {
            self.col.push(c);
        }
        if self.normals {
            self.nrm.push(n);
        }
        self.stats.vertices += 1;
        if self.pos.len() >= BATCH {
            self.flush_vertices()?;
        }
        Ok(())
    }

    /// Queues a triangle of valid indices, or counts it as degenerate if it repeats a vertex.
    #[inline]
    pub fn triangle(&mut self, t: [u32; 3]) -> Result<(), ImportError> {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            self.stats.degenerate_faces += 1;
            return Ok(());
        }
        self.tris.push(t);
        if self.textured {
            self.faces.push(TexturedFace::NONE);
        }
        self.stats.triangles += 1;
        if self.tris.len() >= BATCH {
            self.flush_triangles()?;
        }
        Ok(())
    }

    /// Queues a triangle known not to be degenerate-by-encoding (strips drop those silently).
    #[inline]
    pub fn strip_triangle(&mut self, t: [u32; 3]) -> Result<(), ImportError> {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            return Ok(());
        }
        self.triangle(t)
    }

    /// Queues a polygon of valid indices, fan-triangulated; fewer than 3 corners is degenerate.
    pub fn polygon(&mut self, idx: &[u32]) -> Result<(), ImportError> {
        match idx {
            [a, b, c] => self.triangle([*a, *b, *c]),
            [first, rest @ ..] if rest.len() >= 3 => {
                self.stats.polygons_triangulated += 1;
                for w in rest.windows(2) {
                    self.triangle([*first, w[0], w[1]])?;
                }
                Ok(())
            }
            _ => {
                self.stats.degenerate_faces += 1;
                Ok(())
            }
        }
    }

    pub fn flush_vertices(&mut self) -> Result<(), ImportError> {
        if self.pos.is_empty() {
            return Ok(());
        }
        let batch = VertexBatch {
            positions: &self.pos,
            colors: self.colors.then_some(&self.col[..]),
            normals: self.normals.then_some(&self.nrm[..]),
        };
        self.sink
            .vertices(batch)
            .map_err(|e| e.with_path(self.path))?;
        self.pos.clear();
        self.col.clear();
        self.nrm.clear();
        Ok(())
    }

    pub fn flush_triangles(&mut self) -> Result<(), ImportError> {
        // A triangle names only vertices already delivered.
        self.flush_vertices()?;
        if self.tris.is_empty() {
            return Ok(());
        }
        if self.textured {
            self.sink
                .textured_triangles(&self.tris, &self.faces)
                .map_err(|e| e.with_path(self.path))?;
        } else {
            self.sink
                .triangles(&self.tris)
                .map_err(|e| e.with_path(self.path))?;
        }
        self.tris.clear();
        self.faces.clear();
        Ok(())
    }

    /// Reports that the reader has consumed `done` units in total; fails if cancelled.
    pub fn tick(&mut self, done: u64) -> Result<(), ImportError> {
        if done > self.reported {
            self.progress.advance(done - self.reported);
            self.reported = done;
        }
        if let Some(map) = self.map.as_ref()
            && done >= self.released + RELEASE_STEP
        {
            let page = 4096u64;
            let end = (done / page * page).min(map.len() as u64);
            if end > self.released {
                // SAFETY: a read-only file mapping: dropped pages are read back from the file
                // (page cache) if touched again, so no data is lost and nothing aliases.
                let _ = unsafe {
                    map.unchecked_advise_range(
                        memmap2::UncheckedAdvice::DontNeed,
                        self.released as usize,
                        (end - self.released) as usize,
                    )
                };
                self.released = end;
            }
        }
        if self.progress.cancelled() {
            return Err(err(self.path, Location::File, ImportErrorKind::Cancelled));
        }
        Ok(())
    }

    /// Delivers what is pending and returns the statistics; a mesh without triangles is an error.
    pub fn finish(mut self, total: u64) -> Result<ImportStats, ImportError> {
        self.flush_triangles()?;
        self.tick(total)?;
        if self.stats.triangles == 0 {
            return Err(err(self.path, Location::File, ImportErrorKind::Empty));
        }
        Ok(self.stats)
    }
}

/// A text line, its 1-based number and the byte offset just after it.
pub(crate) type Line<'a> = (&'a [u8], u64, u64);

/// Reads text lines with a length limit, counting lines (1-based) and byte offsets.
pub(crate) struct LineReader<R> {
    inner: R,
    buf: Vec<u8>,
    /// Number of the line last returned (1-based; 0 before the first).
    pub line: u64,
    /// Byte offset of the start of the line last returned.
    pub line_start: u64,
    /// Byte offset just after the line last returned.
    pub offset: u64,
    /// Whether the line last returned ended with a newline (not cut off by the end of input).
    pub terminated: bool,
}

impl LineReader<BufReader<File>> {
    pub fn from_file(file: File) -> Self {
        LineReader::new(BufReader::with_capacity(1 << 16, file))
    }
}

impl<R: BufRead> LineReader<R> {
    pub fn new(inner: R) -> Self {
        LineReader {
            inner,
            buf: Vec::new(),
            line: 0,
            line_start: 0,
            offset: 0,
            terminated: false,
        }
    }

    /// The next line without its terminator (`\n` or `\r\n`), or `None` at the end.
    pub fn next_line(&mut self, path: &Path) -> Result<Option<&[u8]>, ImportError> {
        self.buf.clear();
        let limit = MAX_LINE as u64 + 1;
        let n = (&mut self.inner)
            .take(limit)
            .read_until(b'\n', &mut self.buf)
            .map_err(|e| {
                err(
                    path,
                    Location::Line(self.line + 1),
                    ImportErrorKind::Io(e.to_string()),
                )
            })?;
        if n == 0 {
            return Ok(None);
        }
        self.line += 1;
        self.line_start = self.offset;
        self.offset += n as u64;
        self.terminated = self.buf.last() == Some(&b'\n');
        if self.terminated {
            self.buf.pop();
        } else if n as u64 >= limit {
            return Err(err(
                path,
                Location::Line(self.line),
                ImportErrorKind::Syntax(format!("line longer than {MAX_LINE} bytes")),
            ));
        }
        if self.buf.last() == Some(&b'\r') {
            self.buf.pop();
        }
        Ok(Some(&self.buf))
    }

    /// The next line that has a token, or `None` at the end.
    pub fn next_nonblank(&mut self, path: &Path) -> Result<Option<&[u8]>, ImportError> {
        loop {
            let has_token = match self.next_line(path)? {
                None => return Ok(None),
                Some(l) => l.iter().any(|b| !b.is_ascii_whitespace()),
            };
            if has_token {
                return Ok(Some(&self.buf));
            }
        }
    }
}

impl<R: BufRead> LineReader<R> {
    /// Like [`Self::next_line`], with the line's number and the byte offset after it.
    pub fn next_pos(&mut self, path: &Path) -> Result<Option<Line<'_>>, ImportError> {
        if self.next_line(path)?.is_none() {
            return Ok(None);
        }
        Ok(Some((&self.buf, self.line, self.offset)))
    }

    /// The next line with a token once a `comment` character and what follows are removed,
    /// with its number and the byte offset after it.
    pub fn next_content(
        &mut self,
        path: &Path,
        comment: u8,
    ) -> Result<Option<Line<'_>>, ImportError> {
        loop {
            let end = match self.next_line(path)? {
                None => return Ok(None),
                Some(l) => {
                    let end = l.iter().position(|&b| b == comment).unwrap_or(l.len());
                    l[..end]
                        .iter()
                        .any(|b| !b.is_ascii_whitespace())
                        .then_some(end)
                }
            };
            if let Some(end) = end {
                return Ok(Some((&self.buf[..end], self.line, self.offset)));
            }
        }
    }

    /// Like [`Self::next_nonblank`], with the line's number.
    pub fn next_numbered(&mut self, path: &Path) -> Result<Option<(&[u8], u64)>, ImportError> {
        let line = match self.next_nonblank(path)? {
            None => return Ok(None),
            Some(_) => self.line,
        };
        Ok(Some((&self.buf, line)))
    }
}

impl<R: BufRead + Seek> LineReader<R> {
    /// Continues reading at byte `offset`, whose line number is `line + 1`.
    pub fn seek(&mut self, path: &Path, offset: u64, line: u64) -> Result<(), ImportError> {
        self.inner.seek(SeekFrom::Start(offset)).map_err(|e| {
            err(
                path,
                Location::Line(line),
                ImportErrorKind::Io(e.to_string()),
            )
        })?;
        self.offset = offset;
        self.line_start = offset;
        self.line = line;
        Ok(())
    }
}

/// Whitespace-separated tokens of a line.
pub(crate) struct Tokens<'a> {
    s: &'a [u8],
    i: usize,
}

impl<'a> Tokens<'a> {
    pub fn new(s: &'a [u8]) -> Self {
        Tokens { s, i: 0 }
    }
}

impl<'a> Iterator for Tokens<'a> {
    type Item = &'a [u8];
    #[inline]
    fn next(&mut self) -> Option<&'a [u8]> {
        let s = self.s;
        let mut i = self.i;
        while i < s.len() && s[i].is_ascii_whitespace() {
            i += 1;
        }
        if i >= s.len() {
            self.i = i;
            return None;
        }
        let start = i;
        while i < s.len() && !s[i].is_ascii_whitespace() {
            i += 1;
        }
        self.i = i;
        Some(&s[start..i])
    }
}

/// A token for messages (lossy, shortened).
pub(crate) fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(&tok[..tok.len().min(40)]).into_owned();
    if tok.len() > 40 { format!("{s}...") } else { s }
}

#[inline]
pub(crate) fn parse_f32(tok: &[u8]) -> Option<f32> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

#[inline]
pub(crate) fn parse_f64(tok: &[u8]) -> Option<f64> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

#[inline]
pub(crate) fn parse_i64(tok: &[u8]) -> Option<i64> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

/// Fails when `count` items of at least `min_bytes` each cannot fit in `available` bytes:
/// a lying header must not make a reader allocate or loop for nothing.
pub(crate) fn check_fits(
    path: &Path,
    location: Location,
    what: &str,
    count: u64,
    min_bytes: u64,
    available: u64,
) -> Result<(), ImportError> {
    let need = count.checked_mul(min_bytes);
    if need.is_none_or(|n| n > available) {
        return Err(err(
            path,
            location,
            ImportErrorKind::Truncated(format!(
                "the header declares {count} {what}, which needs at least {} bytes, \
                 but only {available} bytes follow",
                need.map_or_else(|| "2^64".to_string(), |n| n.to_string())
            )),
        ));
    }
    Ok(())
}

/// FxHash (rustc's hasher): fast for the fixed-size keys of position welding.
#[derive(Default, Clone, Copy)]
pub(crate) struct FxHasher(u64);

impl Hasher for FxHasher {
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut b = [0u8; 8];
            b[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(b));
        }
    }
    #[inline]
    fn write_u32(&mut self, i: u32) {
        self.write_u64(i as u64);
    }
    #[inline]
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }
}

/// Merges vertices with bit-identical positions (after mapping -0.0 to 0.0).
#[derive(Default)]
pub(crate) struct Welder {
    map: HashMap<[u32; 3], u32, BuildHasherDefault<FxHasher>>,
}

impl Welder {
    /// The welded index of `p` and whether it is new; `next` is the index a new vertex gets.
    #[inline]
    pub fn weld(&mut self, p: [f32; 3], next: u32) -> (u32, bool) {
        let key = p.map(|c| if c == 0.0 { 0 } else { c.to_bits() });
        match self.map.entry(key) {
            std::collections::hash_map::Entry::Occupied(e) => (*e.get(), false),
            std::collections::hash_map::Entry::Vacant(e) => {
                e.insert(next);
                (next, true)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_split_on_any_whitespace() {
        let t: Vec<&[u8]> = Tokens::new(b"  a\tbb  c \r").collect();
        assert_eq!(t, vec![&b"a"[..], b"bb", b"c"]);
    }

    #[test]
    fn line_reader_counts_lines_and_offsets() {
        let p = Path::new("x");
        let mut r = LineReader::new(&b"one\r\n\ntwo"[..]);
        assert_eq!(r.next_line(p).unwrap(), Some(&b"one"[..]));
        assert_eq!((r.line, r.line_start, r.offset), (1, 0, 5));
        assert_eq!(r.next_nonblank(p).unwrap(), Some(&b"two"[..]));
        assert_eq!(r.line, 3);
        assert_eq!(r.next_line(p).unwrap(), None);
    }

    #[test]
    fn welder_merges_signed_zero() {
        let mut w = Welder::default();
        assert_eq!(w.weld([0.0, 1.0, 2.0], 0), (0, true));
        assert_eq!(w.weld([-0.0, 1.0, 2.0], 1), (0, false));
        assert_eq!(w.weld([0.0, 1.0, 2.5], 1), (1, true));
    }
}
