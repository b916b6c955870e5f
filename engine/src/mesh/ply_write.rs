//! Binary little-endian PLY writer: positions, optional RGB(A) colours and normals, extra
//! `uint` vertex properties (e.g. `original_id`), `list uchar int vertex_indices` triangles.
//!
//! Written to a temporary name in the destination's directory and renamed when complete, so
//! a reader never sees a half-written file. [`PlyWriter`] streams (vertices first, then
//! triangles); [`write_ply`] writes arrays in one call.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// What the file will hold; counts must match what is written.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PlyLayout {
    pub vertices: u64,
    pub triangles: u64,
    /// Write `uchar red green blue`.
    pub colors: bool,
    /// Also write `uchar alpha` (only with `colors`).
    pub alpha: bool,
    /// Write `float nx ny nz`.
    pub normals: bool,
    /// Names of extra `uint` vertex properties, written in this order after the others.
    pub extras: Vec<String>,
}

/// A binary PLY being written. Dropping it before [`PlyWriter::finish`] removes the
/// temporary file.
pub struct PlyWriter {
    out: Option<BufWriter<File>>,
    tmp: PathBuf,
    dst: PathBuf,
    layout: PlyLayout,
    written_vertices: u64,
    written_triangles: u64,
    record: Vec<u8>,
}

fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}

impl PlyWriter {
    /// Creates the temporary file next to `path` and writes the header.
    pub fn create(path: &Path, layout: PlyLayout) -> io::Result<PlyWriter> {
        if layout.vertices > i32::MAX as u64 {
            return Err(invalid(format!(
                "{} vertices do not fit 'int' indices",
                layout.vertices
            )));
        }
        let name = path
            .file_name()
            .ok_or_else(|| invalid(format!("'{}' is not a file path", path.display())))?;
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let tmp = dir.join(format!(
            ".{}.{}.tmp",
            name.to_string_lossy(),
            std::process::id()
        ));
        let file = File::create(&tmp)?;
        let mut w = PlyWriter {
            out: Some(BufWriter::with_capacity(1 << 20, file)),
            tmp,
            dst: path.to_path_buf(),
            layout,
            written_vertices: 0,
            written_triangles: 0,
            record: Vec::new(),
        };
        w.header()?;
        Ok(w)
    }

    fn out(&mut self) -> io::Result<&mut BufWriter<File>> {
        self.out
            .as_mut()
            .ok_or_else(|| io::Error::other("the PLY writer is closed"))
    }

    fn header(&mut self) -> io::Result<()> {
        let l = &self.layout;
        let mut h = String::from("ply\nformat binary_little_endian 1.0\ncomment meshwiki\n");
        h += &format!("element vertex {}\n", l.vertices);
        h += "property float x\nproperty float y\nproperty float z\n";
        if l.normals {
            h += "property float nx\nproperty float ny\nproperty float nz\n";
        }
        if l.colors {
            h += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
            if l.alpha {
                h += "property uchar alpha\n";
            }
        }
        for e in &l.extras {
            if e.is_empty() || e.bytes().any(|b| b.is_ascii_whitespace() || !b.is_ascii()) {
                return Err(invalid(format!("bad property name '{e}'")));
            }
            h += &format!("property uint {e}\n");
        }
        h += &format!(
            "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            l.triangles
        );
        self.out()?.write_all(h.as_bytes())
    }

    /// Appends vertices. Colours, normals and extras must be given exactly when the layout
    /// has them, each as long as `positions`.
    pub fn write_vertices(
        &mut self,
        positions: &[[f32; 3]],
        colors: Option<&[[u8; 4]]>,
        normals: Option<&[[f32; 3]]>,
        extras: &[&[u32]],
    ) -> io::Result<()> {
        let n = positions.len();
        let l = &self.layout;
        if colors.is_some() != l.colors
            || normals.is_some() != l.normals
            || extras.len() != l.extras.len()
        {
            return Err(invalid("vertex attributes differ from the layout".into()));
        }
        if colors.is_some_and(|c| c.len() != n)
            || normals.is_some_and(|c| c.len() != n)
            || extras.iter().any(|e| e.len() != n)
        {
            return Err(invalid("vertex attribute arrays differ in length".into()));
        }
        if self.written_vertices + n as u64 > l.vertices {
            return Err(invalid(format!(
                "more vertices than the {} declared",
                l.vertices
            )));
        }
        let (do_alpha, do_colors) = (l.alpha, l.colors);
        let mut rec = std::mem::take(&mut self.record);
        const CHUNK: usize = 1 << 14;
        for start in (0..n).step_by(CHUNK) {
            let end = (start + CHUNK).min(n);
            rec.clear();
            for i in start..end {
                for c in positions[i] {
                    rec.extend_from_slice(&c.to_le_bytes());
                }
                if let Some(nrm) = normals {
                    for c in nrm[i] {
                        rec.extend_from_slice(&c.to_le_bytes());
                    }
                }
                if let (true, Some(col)) = (do_colors, colors) {
                    let c = col[i];
                    rec.extend_from_slice(if do_alpha { &c[..] } else { &c[..3] });
                }
                for e in extras {
                    rec.extend_from_slice(&e[i].to_le_bytes());
                }
            }
            self.out()?.write_all(&rec)?;
        }
        self.record = rec;
        self.written_vertices += n as u64;
        Ok(())
    }

    /// Appends triangles; all vertices must have been written first.
    pub fn write_triangles(&mut self, triangles: &[[u32; 3]]) -> io::Result<()> {
        let nv = self.layout.vertices;
        if self.written_vertices != nv {
            return Err(invalid("triangles before all vertices were written".into()));
        }
        if self.written_triangles + triangles.len() as u64 > self.layout.triangles {
            return Err(invalid(format!(
                "more triangles than the {} declared",
                self.layout.triangles
            )));
        }
        let mut rec = std::mem::take(&mut self.record);
        for chunk in triangles.chunks(1 << 14) {
            rec.clear();
            for t in chunk {
                if t.iter().any(|&i| i as u64 >= nv) {
                    return Err(invalid(format!(
                        "triangle {t:?} names a vertex beyond the {nv} written"
                    )));
                }
                rec.push(3);
                for i in t {
                    rec.extend_from_slice(&i.to_le_bytes());
                }
            }
            self.out()?.write_all(&rec)?;
        }
        self.record = rec;
        self.written_triangles += triangles.len() as u64;
        Ok(())
    }

    /// Checks the counts, flushes, syncs and renames the file into place.
    pub fn finish(mut self) -> io::Result<()> {
        let l = &self.layout;
        if self.written_vertices != l.vertices || self.written_triangles != l.triangles {
            return Err(invalid(format!(
                "wrote {} vertices and {} triangles, declared {} and {}",
                self.written_vertices, self.written_triangles, l.vertices, l.triangles
            )));
        }
        let out = self
            .out
            .take()
            .ok_or_else(|| io::Error::other("the PLY writer is closed"))?;
        let file = out.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&self.tmp, &self.dst)?;
        self.tmp = PathBuf::new();
        Ok(())
    }
}

impl Drop for PlyWriter {
    fn drop(&mut self) {
        if !self.tmp.as_os_str().is_empty() {
            self.out = None;
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Writes a triangle mesh as binary little-endian PLY (temporary file, then rename).
/// `indices` holds three per triangle; `extra` is an optional per-vertex `uint` property
/// such as `("original_id", ids)`. Alpha is written only if some colour is not opaque.
pub fn write_ply(
    path: &Path,
    positions: &[[f32; 3]],
    colors: Option<&[[u8; 4]]>,
    normals: Option<&[[f32; 3]]>,
    indices: &[u32],
    extra: Option<(&str, &[u32])>,
) -> io::Result<()> {
    if !indices.len().is_multiple_of(3) {
        return Err(invalid(format!(
            "{} indices is not a multiple of 3",
            indices.len()
        )));
    }
    let layout = PlyLayout {
        vertices: positions.len() as u64,
        triangles: (indices.len() / 3) as u64,
        colors: colors.is_some(),
        alpha: colors.is_some_and(|c| c.iter().any(|c| c[3] != 255)),
        normals: normals.is_some(),
        extras: extra.iter().map(|(n, _)| n.to_string()).collect(),
    };
    let mut w = PlyWriter::create(path, layout)?;
    let extras: Vec<&[u32]> = extra.iter().map(|(_, v)| *v).collect();
    w.write_vertices(positions, colors, normals, &extras)?;
    w.write_triangles(bytemuck::cast_slice(indices))?;
    w.finish()
}
