//! OFF reader (ASCII), as used by the Princeton segmentation benchmark.
//!
//! Header keyword `[ST][C][N]OFF` (counts may follow on the same line), `#` comments,
//! `nv nf ne`, one vertex per line (`x y z [nx ny nz] [r g b [a]] [u v]`), one face per line
//! (`n i0 .. in-1` then optional colour, ignored). Polygons are fan-triangulated.

use super::common::{
    BATCH, Emitter, Line, LineReader, Tokens, check_finite, check_fits, err, open, parse_f32,
    parse_i64, show,
};
use super::{ImportError, ImportErrorKind as K, ImportStats, Location, MeshSink, SourceInfo};
use crate::progress::Progress;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// Reads an OFF file into `sink`.
pub(crate) fn read(
    path: &Path,
    sink: &mut dyn MeshSink,
    progress: &dyn Progress,
) -> Result<ImportStats, ImportError> {
    let (file, len) = open(path)?;
    let mut lines = LineReader::from_file(file);
    let mut em = Emitter::new(path, sink, progress, "import", len);
    let herr = |line: u64, msg: String| err(path, Location::Line(line), K::Header(msg));

    let Some((first, no, _)) = next(&mut lines, path)? else {
        return Err(herr(1, "not an OFF file (empty)".into()));
    };
    let mut t = Tokens::new(first);
    let key = t.next().unwrap_or(b"");
    let Some(flags) = key.strip_suffix(b"OFF") else {
        return Err(herr(
            no,
            format!("not an OFF file (starts with '{}')", show(key)),
        ));
    };
    let (mut tex, mut color, mut normals) = (false, false, false);
    let mut rest = flags;
    if let Some(r) = rest.strip_prefix(b"ST") {
        tex = true;
        rest = r;
    }
    if let Some(r) = rest.strip_prefix(b"C") {
        color = true;
        rest = r;
    }
    if let Some(r) = rest.strip_prefix(b"N") {
        normals = true;
        rest = r;
    }
    if !rest.is_empty() {
        return Err(err(
            path,
            Location::Line(no),
            K::Unsupported(format!("OFF variant '{}'", show(key))),
        ));
    }
    let mut counts: Vec<&[u8]> = t.collect();
    if counts.first() == Some(&&b"BINARY"[..]) {
        return Err(err(
            path,
            Location::Line(no),
            K::Unsupported("binary OFF".into()),
        ));
    }
    let owned;
    let mut counts_line = no;
    if counts.is_empty() {
        let Some((l, n, _)) = next(&mut lines, path)? else {
            return Err(err(
                path,
                Location::Line(no + 1),
                K::Truncated("no vertex and face counts".into()),
            ));
        };
        owned = l.to_vec();
        counts = Tokens::new(&owned).collect();
        counts_line = n;
    }
    let count = |i: usize| counts.get(i).and_then(|c| parse_i64(c)).filter(|&c| c >= 0);
    let (Some(nv), Some(nf)) = (count(0), count(1)) else {
        return Err(herr(
            counts_line,
            "expected non-negative vertex and face counts".into(),
        ));
    };
    let (nv, nf) = (nv as u64, nf as u64);
    // "x y z\n" is at least 6 bytes, "3 a b c\n" at least 8.
    let loc = Location::Line(counts_line);
    check_fits(path, loc.clone(), "vertices", nv, 6, len)?;
    check_fits(path, loc.clone(), "faces", nf, 8, len)?;
    check_fits(path, loc, "vertices and faces", 1, nv * 6 + nf * 8, len)?;
    if nv > u32::MAX as u64 {
        return Err(err(
            path,
            Location::Line(counts_line),
            K::Unsupported(format!("{nv} vertices (at most 2^32 - 1)")),
        ));
    }

    em.begin(&SourceInfo {
        vertex_count: Some(nv),
        triangle_count_hint: Some(nf),
        has_colors: color,
        has_normals: normals,
    })?;
    let truncated =
        |line: u64, what: String| err(path, Location::Line(line + 1), K::Truncated(what));
    let mut vals: Vec<f32> = Vec::new();
    for i in 0..nv {
        let last = lines.line;
        let Some((l, no, at)) = next(&mut lines, path)? else {
            return Err(truncated(
                last,
                format!("the file ends after {i} of {nv} vertices"),
            ));
        };
        if i.is_multiple_of(BATCH as u64) {
            em.tick(at)?;
        }
        vals.clear();
        for tok in Tokens::new(l) {
            vals.push(parse_f32(tok).ok_or_else(|| {
                err(
                    path,
                    Location::Line(no),
                    K::Syntax(format!("'{}' is not a number (vertex {i})", show(tok))),
                )
            })?);
        }
        let need = 3 + 3 * normals as usize + 3 * color as usize + 2 * tex as usize;
        if vals.len() < need {
            return Err(err(
                path,
                Location::Line(no),
                K::Syntax(format!(
                    "vertex {i} has {} values, expected at least {need}",
                    vals.len()
                )),
            ));
        }
        let p = [vals[0], vals[1], vals[2]];
        if let Some(what) = check_finite(p) {
            return Err(err(path, Location::Line(no), K::NonFinite(what, i)));
        }
        let mut k = 3;
        let mut n = [0.0; 3];
        if normals {
            n = [vals[3], vals[4], vals[5]];
            if !n.iter().all(|c| c.is_finite()) {
                n = [0.0; 3];
            }
            k = 6;
        }
        let mut c = [255u8; 4];
        if color {
            let cs = &vals[k..];
            // Integers 0..255, or floats 0..1 when every channel is at most 1.
            let channels = if cs.len() >= 4 && !tex || cs.len() >= 6 {
                4
            } else {
                3
            };
            let float = cs[..channels].iter().all(|&v| v <= 1.0);
            for (slot, &v) in c.iter_mut().zip(&cs[..channels]) {
                let v = if float { v * 255.0 } else { v };
                *slot = v.round().clamp(0.0, 255.0) as u8;
            }
        }
        em.vertex(p, c, n)?;
    }
    let mut corners: Vec<u32> = Vec::new();
    for f in 0..nf {
        let last = lines.line;
        let Some((l, no, at)) = next(&mut lines, path)? else {
            return Err(truncated(
                last,
                format!("the file ends after {f} of {nf} faces"),
            ));
        };
        if f.is_multiple_of(BATCH as u64) {
            em.tick(at)?;
        }
        let mut t = Tokens::new(l);
        let syntax = |msg: String| err(path, Location::Line(no), K::Syntax(msg));
        let n_tok = t.next().unwrap_or(b"");
        let Some(n) = parse_i64(n_tok).filter(|&n| n >= 0) else {
            return Err(syntax(format!(
                "face {f}: bad corner count '{}'",
                show(n_tok)
            )));
        };
        corners.clear();
        for _ in 0..n {
            let Some(tok) = t.next() else {
                return Err(syntax(format!(
                    "face {f} has fewer than {n} vertex indices"
                )));
            };
            let Some(v) = parse_i64(tok) else {
                return Err(syntax(format!(
                    "face {f}: bad vertex index '{}'",
                    show(tok)
                )));
            };
            if v < 0 || v as u64 >= nv {
                return Err(err(
                    path,
                    Location::Line(no),
                    K::IndexOutOfRange {
                        index: v,
                        count: nv,
                        face: f,
                    },
                ));
            }
            corners.push(v as u32);
        }
        // What follows the indices is an optional face colour, ignored.
        em.polygon(&corners)?;
    }
    if let Some((_, no, _)) = next(&mut lines, path)? {
        return Err(err(
            path,
            Location::Line(no),
            K::Syntax(format!(
                "data after the last of {nf} faces (wrong face count in the header?)"
            )),
        ));
    }
    em.finish(len)
}

/// The next line with content, comments (`#`) removed.
fn next<'l>(
    lines: &'l mut LineReader<BufReader<File>>,
    path: &Path,
) -> Result<Option<Line<'l>>, ImportError> {
    lines.next_content(path, b'#')
}
