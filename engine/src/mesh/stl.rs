//! STL reader, ASCII and binary, with vertices welded by exact position.
//!
//! Binary is recognised by its size (84 + 50 × count bytes), whatever its first bytes say:
//! many binary files begin with "solid". Welded vertices reach the sink in order of first
//! appearance (that order is their original ID). Facet normals and attribute bytes are ignored.

use super::common::{
    BATCH, Emitter, LineReader, Tokens, Welder, check_finite, err, map, open, parse_f32, show,
};
use super::{ImportError, ImportErrorKind as K, ImportStats, Location, MeshSink, SourceInfo};
use crate::progress::Progress;
use std::path::Path;

/// Reads an STL file into `sink`.
pub(crate) fn read(
    path: &Path,
    sink: &mut dyn MeshSink,
    progress: &dyn Progress,
) -> Result<ImportStats, ImportError> {
    let (file, len) = open(path)?;
    let data = map(path, &file)?;
    let data: &[u8] = &data;
    let declared = (data.len() >= 84)
        .then(|| u32::from_le_bytes([data[80], data[81], data[82], data[83]]) as u64);
    let binary_size = declared.map(|n| 84 + 50 * n);
    let mut em = Emitter::new(path, sink, progress, "import", len);
    if binary_size == Some(len) {
        binary(path, data, &mut em)?;
    } else if looks_ascii(data) {
        ascii(path, file, len, &mut em)?;
    } else if let Some(n) = declared {
        return Err(err(
            path,
            Location::Byte(80),
            K::Truncated(format!(
                "binary STL header declares {n} triangles ({} bytes) but the file has {len} bytes",
                84 + 50 * n
            )),
        ));
    } else {
        return Err(err(
            path,
            Location::File,
            K::Header("not an STL file (too short for binary, no 'solid' keyword)".into()),
        ));
    }
    em.finish(len)
}

/// Text that starts with `solid` and has no binary bytes early on.
fn looks_ascii(data: &[u8]) -> bool {
    let text = data.trim_ascii_start();
    let head = &data[..data.len().min(4096)];
    text.starts_with(b"solid")
        && head
            .iter()
            .all(|&b| b == b'\n' || b == b'\r' || b == b'\t' || (0x20..0x7f).contains(&b))
}

fn binary(path: &Path, data: &[u8], em: &mut Emitter) -> Result<(), ImportError> {
    let n = (data.len() - 84) / 50;
    em.begin(&SourceInfo {
        vertex_count: None,
        triangle_count_hint: Some(n as u64),
        has_colors: false,
        has_normals: false,
    })?;
    let mut welder = Welder::default();
    let f = |b: &[u8], o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    for (i, rec) in data[84..].chunks_exact(50).enumerate() {
        if i.is_multiple_of(BATCH) {
            em.tick(84 + 50 * i as u64)?;
        }
        let mut t = [0u32; 3];
        for (k, slot) in t.iter_mut().enumerate() {
            let o = 12 + 12 * k;
            let p = [f(rec, o), f(rec, o + 4), f(rec, o + 8)];
            if let Some(what) = check_finite(p) {
                return Err(err(
                    path,
                    Location::Byte((84 + 50 * i + o) as u64),
                    K::NonFinite(what, (3 * i + k) as u64),
                ));
            }
            *slot = weld(&mut welder, p, em, path)?;
        }
        em.triangle(t)?;
    }
    Ok(())
}

/// The welded index of `p`, delivering it if new.
#[inline]
fn weld(w: &mut Welder, p: [f32; 3], em: &mut Emitter, path: &Path) -> Result<u32, ImportError> {
    let next = em.vertex_count();
    if next >= u32::MAX as u64 {
        return Err(err(
            path,
            Location::File,
            K::Unsupported("more than 2^32 - 1 distinct vertices".into()),
        ));
    }
    let (i, new) = w.weld(p, next as u32);
    if new {
        em.vertex(p, [255; 4], [0.0; 3])?;
    }
    Ok(i)
}

fn ascii(path: &Path, file: std::fs::File, len: u64, em: &mut Emitter) -> Result<(), ImportError> {
    em.begin(&SourceInfo {
        vertex_count: None,
        // "facet normal ... endfacet" takes at least ~100 bytes.
        triangle_count_hint: Some(len / 100),
        has_colors: false,
        has_normals: false,
    })?;
    let mut lines = LineReader::from_file(file);
    let mut welder = Welder::default();
    let mut corners: Vec<u32> = Vec::new();
    // Parser state: where we are in "solid > facet > outer loop > vertex".
    let mut in_solid = false;
    let mut in_facet = false;
    let mut in_loop = false;
    let mut facets: u64 = 0;
    let syntax = |line: u64, msg: String| err(path, Location::Line(line), K::Syntax(msg));
    while let Some((line, no, at)) = lines.next_pos(path)? {
        let mut t = Tokens::new(line);
        let Some(key) = t.next() else { continue };
        match key {
            b"solid" if !in_solid => in_solid = true,
            b"endsolid" if in_solid && !in_facet => in_solid = false,
            b"facet" if in_solid && !in_facet => {
                in_facet = true;
                corners.clear();
            }
            b"outer" if in_facet && !in_loop => {
                if t.next() != Some(b"loop") {
                    return Err(syntax(no, "expected 'outer loop'".into()));
                }
                in_loop = true;
            }
            b"vertex" if in_loop => {
                let mut p = [0f32; 3];
                for c in &mut p {
                    let tok = t.next().unwrap_or(b"");
                    *c = parse_f32(tok).ok_or_else(|| {
                        syntax(no, format!("bad vertex coordinate '{}'", show(tok)))
                    })?;
                }
                if let Some(what) = check_finite(p) {
                    let vertex = 3 * facets + corners.len() as u64;
                    return Err(err(path, Location::Line(no), K::NonFinite(what, vertex)));
                }
                if corners.len() >= 1 << 16 {
                    return Err(syntax(no, "a facet with more than 65536 vertices".into()));
                }
                corners.push(weld(&mut welder, p, em, path)?);
            }
            b"endloop" if in_loop => in_loop = false,
            b"endfacet" if in_facet && !in_loop => {
                in_facet = false;
                em.polygon(&corners)?;
                facets += 1;
                if facets.is_multiple_of(BATCH as u64) {
                    em.tick(at)?;
                }
            }
            other => {
                return Err(syntax(no, format!("unexpected '{}'", show(other))));
            }
        }
    }
    if in_facet {
        return Err(err(
            path,
            Location::Line(lines.line),
            K::Truncated("the file ends inside a facet".into()),
        ));
    }
    Ok(())
}
