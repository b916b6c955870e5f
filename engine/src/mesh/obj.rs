//! Wavefront OBJ reader: `v x y z [r g b]`, `vt`, `vn`, `f` with `v`, `v/vt`, `v//vn`,
//! `v/vt/vn` corners (negative = relative), polygons fan-triangulated, `mtllib`/`usemtl`.
//!
//! Two passes over the text. The first counts vertices and learns, for each vertex, the
//! first face corner that uses it (its material, `vt` and `vn`); the second streams the
//! vertices and faces to the sink. Per-vertex attributes come from that **first corner**:
//! when one position is used with several UVs or normals (texture seams), the first wins.
//! Colour of a vertex: the `map_Kd` texture of its first corner's material sampled
//! (bilinear, in linear light) at that corner's UV; else its `v` line colour; else the
//! material's `Kd`; else white. Original ID = index of the `v` line.

use super::common::{
    BATCH, Emitter, LineReader, Tokens, check_finite, err, open, parse_f32, parse_i64, show,
};
use super::texture::{Texture, Wrap, encode_rgba, linear_to_srgb};
use super::{
    ImportError, ImportErrorKind as K, ImportStats, Location, MeshSink, NO_TEXTURE, SourceInfo,
    SourceTexture,
};
use crate::progress::Progress;
use std::collections::{HashMap, HashSet};
use std::path::{Component, Path, PathBuf};
use std::sync::Arc;

const NONE: u32 = u32::MAX;

/// Reads an OBJ file (and its MTL files and `map_Kd` textures) into `sink`.
pub(crate) fn read(
    path: &Path,
    sink: &mut dyn MeshSink,
    progress: &dyn Progress,
) -> Result<ImportStats, ImportError> {
    let (file, len) = open(path)?;
    let mut em = Emitter::new(path, sink, progress, "import", 2 * len);
    let scan = scan(path, LineReader::from_file(file), &mut em)?;

    let has_texture = scan.materials.iter().any(|m| m.texture.is_some() && m.used);
    let has_colors = scan.vertex_colors || has_texture;
    let has_normals = scan.first_vn.is_some();
    em.begin(&SourceInfo {
        vertex_count: Some(scan.vertices),
        triangle_count_hint: Some(scan.triangles),
        has_colors,
        has_normals,
    })?;

    // Every used material with a texture is one texture of the sink; faces carry their
    // corners' coordinates (OBJ's v = 0 is the bottom row: handed over as 1 - v).
    let mut texture_of: Vec<u32> = vec![NO_TEXTURE; scan.materials.len()];
    for (m, slot) in scan.materials.iter().zip(texture_of.iter_mut()) {
        if let (Some(tex), true) = (&m.texture, m.used) {
            *slot = em.stats.textures;
            em.texture(SourceTexture {
                image: tex.clone(),
                wrap_s: Wrap::Repeat,
                wrap_t: Wrap::Repeat,
            })?;
        }
    }
    let textured = em.textured();
    let mut current = NONE;
    let (mut nvt, mut nvn) = (0u64, 0u64);
    let mut uvs: Vec<[f32; 2]> = Vec::new();

    let (file, _) = open(path)?;
    let mut lines = LineReader::from_file(file);
    let color_scale = if scan.max_color > 1.0 {
        1.0 / 255.0
    } else {
        1.0
    };
    let mut nv: u64 = 0;
    let mut corners: Vec<u32> = Vec::new();
    let mut n_lines: u64 = 0;
    let mut faces: u64 = 0;
    while let Some((line, line_no, at)) = lines.next_pos(path)? {
        n_lines += 1;
        if n_lines.is_multiple_of(BATCH as u64) {
            em.tick(len + at)?;
        }
        let mut t = Tokens::new(line);
        match t.next() {
            Some(b"v") => {
                let mut xyz = [0f32; 3];
                for (k, c) in xyz.iter_mut().enumerate() {
                    let tok = t.next().ok_or_else(|| {
                        syntax(
                            path,
                            line_no,
                            format!("'v' line with {k} coordinates (needs 3)"),
                        )
                    })?;
                    *c = parse_f32(tok).ok_or_else(|| {
                        syntax(path, line_no, format!("'{}' is not a number", show(tok)))
                    })?;
                }
                if let Some(what) = check_finite(xyz) {
                    return Err(err(path, Location::Line(line_no), K::NonFinite(what, nv)));
                }
                let mut rest = [1f32; 3];
                let mut n_rest = 0;
                for (slot, tok) in rest.iter_mut().zip(t) {
                    *slot = parse_f32(tok).unwrap_or(1.0);
                    n_rest += 1;
                }
                let i = nv as usize;
                let color = if has_colors {
                    vertex_color(&scan, i, (n_rest == 3).then_some(rest), color_scale)
                } else {
                    [255; 4]
                };
                let normal = match &scan.first_vn {
                    Some(first) => first
                        .get(i)
                        .and_then(|&k| scan.normals.get(k as usize))
                        .copied()
                        .unwrap_or([0.0; 3]),
                    None => [0.0; 3],
                };
                em.vertex(xyz, color, normal)?;
                nv += 1;
            }
            Some(b"f") if textured => {
                corners.clear();
                uvs.clear();
                let texture = texture_of
                    .get(current as usize)
                    .copied()
                    .unwrap_or(NO_TEXTURE);
                let mut all_vt = true;
                for tok in t {
                    let c = corner(path, line_no, tok, [nv, nvt, nvn], faces)?;
                    corners.push(c.v);
                    match scan.texcoords.get(c.vt as usize) {
                        Some(uv) => uvs.push([uv[0], 1.0 - uv[1]]),
                        None => {
                            all_vt = false;
                            uvs.push([0.0; 2]);
                        }
                    }
                }
                let texture = if all_vt { texture } else { NO_TEXTURE };
                em.textured_polygon(&corners, &uvs, texture)?;
                faces += 1;
            }
            Some(b"f") => {
                corners.clear();
                for tok in t {
                    let mut parts = tok.split(|&b| b == b'/');
                    let v = parts.next().unwrap_or(b"");
                    check_corner_rest(path, line_no, tok, parts)?;
                    corners.push(resolve(path, line_no, v, nv, "vertex", false, faces)?);
                }
                em.polygon(&corners)?;
                faces += 1;
            }
            Some(b"vt") => nvt += 1,
            Some(b"vn") => nvn += 1,
            Some(b"usemtl") if textured => {
                let name = rest_of(line, b"usemtl");
                current = scan.by_name.get(&name).copied().unwrap_or(NONE);
            }
            _ => {}
        }
    }
    em.finish(2 * len)
}

fn syntax(path: &Path, line: u64, msg: String) -> ImportError {
    err(path, Location::Line(line), K::Syntax(msg))
}

/// A face corner: vertex, texture coordinate and normal indices (0-based, `NONE` if absent).
struct Corner {
    v: u32,
    vt: u32,
    vn: u32,
}

/// Parses `v`, `v/vt`, `v//vn` or `v/vt/vn` against the counts so far.
fn corner(
    path: &Path,
    line: u64,
    tok: &[u8],
    counts: [u64; 3],
    face: u64,
) -> Result<Corner, ImportError> {
    let mut parts = tok.split(|&b| b == b'/');
    let mut next = || parts.next().unwrap_or(b"");
    let v = resolve(path, line, next(), counts[0], "vertex", false, face)?;
    let vt = resolve(
        path,
        line,
        next(),
        counts[1],
        "texture coordinate",
        true,
        face,
    )?;
    let vn = resolve(path, line, next(), counts[2], "normal", true, face)?;
    if parts.next().is_some() {
        return Err(syntax(
            path,
            line,
            format!("bad face corner '{}'", show(tok)),
        ));
    }
    Ok(Corner { v, vt, vn })
}

/// Checks the `vt`/`vn` parts of a corner (at most two, empty or integers) without resolving.
fn check_corner_rest<'t>(
    path: &Path,
    line: u64,
    tok: &[u8],
    mut parts: impl Iterator<Item = &'t [u8]>,
) -> Result<(), ImportError> {
    for what in ["texture coordinate", "normal"] {
        match parts.next() {
            Some(p) if !p.is_empty() && parse_i64(p).is_none() => {
                return Err(syntax(
                    path,
                    line,
                    format!("bad {what} index '{}'", show(p)),
                ));
            }
            _ => {}
        }
    }
    if parts.next().is_some() {
        return Err(syntax(
            path,
            line,
            format!("bad face corner '{}'", show(tok)),
        ));
    }
    Ok(())
}

/// A 1-based or negative (relative) OBJ index to a 0-based one.
fn resolve(
    path: &Path,
    line: u64,
    tok: &[u8],
    count: u64,
    what: &str,
    optional: bool,
    face: u64,
) -> Result<u32, ImportError> {
    if tok.is_empty() && optional {
        return Ok(NONE);
    }
    let Some(i) = std::str::from_utf8(tok)
        .ok()
        .and_then(|s| s.parse::<i64>().ok())
    else {
        return Err(syntax(
            path,
            line,
            format!("bad {what} index '{}'", show(tok)),
        ));
    };
    let resolved = if i > 0 { i - 1 } else { count as i64 + i };
    if i == 0 || resolved < 0 || resolved as u64 >= count || resolved >= NONE as i64 {
        if what == "vertex" {
            return Err(err(
                path,
                Location::Line(line),
                K::IndexOutOfRange {
                    index: i,
                    count,
                    face,
                },
            ));
        }
        return Err(syntax(
            path,
            line,
            format!("{what} index {i} out of range (only {count} defined so far)"),
        ));
    }
    Ok(resolved as u32)
}

struct Material {
    name: String,
    kd: Option<[f32; 3]>,
    texture: Option<Arc<Texture>>,
    used: bool,
}

/// What the first pass learns.
struct Scan {
    vertices: u64,
    triangles: u64,
    vertex_colors: bool,
    max_color: f32,
    materials: Vec<Material>,
    by_name: HashMap<String, u32>,
    texcoords: Vec<[f32; 2]>,
    normals: Vec<[f32; 3]>,
    /// Per vertex: material and `vt` of the first corner using it (only if materials exist).
    first_use: Option<Vec<(u32, u32)>>,
    /// Per vertex: `vn` of the first corner using it (only if the file has normals).
    first_vn: Option<Vec<u32>>,
}

fn scan(
    path: &Path,
    mut lines: LineReader<std::io::BufReader<std::fs::File>>,
    em: &mut Emitter,
) -> Result<Scan, ImportError> {
    let mut s = Scan {
        vertices: 0,
        triangles: 0,
        vertex_colors: false,
        max_color: 0.0,
        materials: Vec::new(),
        by_name: HashMap::new(),
        texcoords: Vec::new(),
        normals: Vec::new(),
        first_use: None,
        first_vn: None,
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut by_name = std::mem::take(&mut s.by_name);
    let mut loaded: HashSet<PathBuf> = HashSet::new();
    let mut current = NONE;
    let mut n_lines: u64 = 0;
    let mut faces: u64 = 0;
    while let Some((line, line_no, at)) = lines.next_pos(path)? {
        n_lines += 1;
        if n_lines.is_multiple_of(BATCH as u64) {
            em.tick(at)?;
        }
        let mut t = Tokens::new(line);
        match t.next() {
            Some(b"v") => {
                s.vertices += 1;
                let mut rest = t.skip(3);
                if let (Some(r), Some(g), Some(b)) = (rest.next(), rest.next(), rest.next()) {
                    s.vertex_colors = true;
                    for c in [r, g, b].into_iter().filter_map(parse_f32) {
                        if c.is_finite() {
                            s.max_color = s.max_color.max(c);
                        }
                    }
                }
                if let Some(f) = s.first_use.as_mut() {
                    f.push((NONE, NONE));
                }
                if let Some(f) = s.first_vn.as_mut() {
                    f.push(NONE);
                }
            }
            Some(b"vt") => {
                let u = t.next().and_then(parse_f32);
                let v = t.next().and_then(parse_f32).or(Some(0.0));
                let (Some(u), Some(v)) = (u, v) else {
                    return Err(syntax(path, line_no, "'vt' needs a number".into()));
                };
                s.texcoords.push([u, v]);
            }
            Some(b"vn") => {
                let mut n = [0f32; 3];
                for c in &mut n {
                    *c = t
                        .next()
                        .and_then(parse_f32)
                        .ok_or_else(|| syntax(path, line_no, "'vn' needs three numbers".into()))?;
                }
                s.normals.push(if n.iter().all(|c| c.is_finite()) {
                    n
                } else {
                    [0.0; 3]
                });
                if s.first_vn.is_none() {
                    s.first_vn = Some(vec![NONE; s.vertices as usize]);
                }
            }
            Some(b"f") => {
                let mut n = 0u64;
                let track = s.first_use.is_some() || s.first_vn.is_some();
                for tok in t {
                    n += 1;
                    if !track {
                        continue;
                    }
                    let counts = [s.vertices, s.texcoords.len() as u64, s.normals.len() as u64];
                    let c = corner(path, line_no, tok, counts, faces)?;
                    if let Some(slot) = s.first_use.as_mut().and_then(|f| f.get_mut(c.v as usize))
                        && slot.0 == NONE
                        && current != NONE
                    {
                        *slot = (current, c.vt);
                    }
                    if let Some(slot) = s.first_vn.as_mut().and_then(|f| f.get_mut(c.v as usize))
                        && *slot == NONE
                    {
                        *slot = c.vn;
                    }
                }
                s.triangles += n.saturating_sub(2);
                faces += 1;
            }
            Some(b"mtllib") => {
                let rest = rest_of(line, b"mtllib");
                for file in mtl_files(dir, &rest) {
                    // Each MTL file once, however often it is named.
                    if loaded.insert(file.clone()) {
                        read_mtl(&file, &mut s.materials, &mut by_name);
                    }
                }
                if !s.materials.is_empty() && s.first_use.is_none() {
                    s.first_use = Some(vec![(NONE, NONE); s.vertices as usize]);
                }
            }
            Some(b"usemtl") => {
                let name = rest_of(line, b"usemtl");
                current = by_name.get(&name).copied().unwrap_or(NONE);
                match s.materials.get_mut(current as usize) {
                    Some(m) => m.used = true,
                    None => tracing::warn!(path = %path.display(), line = line_no,
                        "material '{name}' is not defined in any mtllib"),
                }
            }
            _ => {}
        }
    }
    s.by_name = by_name;
    Ok(s)
}

/// The text after a keyword, trimmed (names may contain spaces).
fn rest_of(line: &[u8], key: &[u8]) -> String {
    let l = line.trim_ascii_start();
    let r = l.get(key.len()..).unwrap_or(b"");
    String::from_utf8_lossy(r.trim_ascii()).into_owned()
}

/// The MTL files of an `mtllib` line: the whole rest if that names a file, else its tokens.
fn mtl_files(dir: &Path, rest: &str) -> Vec<PathBuf> {
    if let Some(p) = local_file(dir, rest) {
        return vec![p];
    }
    rest.split_ascii_whitespace()
        .filter_map(|n| local_file(dir, n))
        .collect()
}

/// Resolves a file named in a model (MTL, texture) inside the model's directory. Absolute
/// paths and paths leaving the directory (often left by exporters, or hostile) fall back to
/// the bare file name in the directory.
pub(crate) fn local_file(dir: &Path, name: &str) -> Option<PathBuf> {
    let name = name.replace('\\', "/");
    let rel = Path::new(&name);
    let inside = rel
        .components()
        .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    let candidate = if inside && !name.is_empty() {
        dir.join(rel)
    } else {
        dir.join(rel.file_name()?)
    };
    if candidate.is_file() {
        Some(candidate)
    } else {
        let bare = dir.join(rel.file_name()?);
        bare.is_file().then_some(bare)
    }
}

/// Reads an MTL file's `newmtl`, `Kd` and `map_Kd`; problems are logged, not fatal.
fn read_mtl(path: &Path, materials: &mut Vec<Material>, by_name: &mut HashMap<String, u32>) {
    let text = match std::fs::read(path) {
        Ok(t) => t,
        Err(e) => {
            tracing::warn!(path = %path.display(), "cannot read material file: {e}");
            return;
        }
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut current: Option<usize> = None;
    for line in text.split(|&b| b == b'\n') {
        let mut t = Tokens::new(line);
        match t.next() {
            Some(b"newmtl") => {
                let name = rest_of(line, b"newmtl");
                let idx = materials.len();
                if materials.len() < NONE as usize - 1 {
                    by_name.insert(name.clone(), idx as u32);
                    materials.push(Material {
                        name,
                        kd: None,
                        texture: None,
                        used: false,
                    });
                    current = Some(idx);
                }
            }
            Some(b"Kd") => {
                let v: Vec<f32> = t.filter_map(parse_f32).collect();
                if let (Some(m), [r, g, b, ..]) =
                    (current.and_then(|i| materials.get_mut(i)), &v[..])
                {
                    m.kd = Some([*r, *g, *b]);
                }
            }
            Some(b"map_Kd") => {
                let Some(m) = current.and_then(|i| materials.get_mut(i)) else {
                    continue;
                };
                let name = texture_name(line);
                match local_file(dir, &name) {
                    Some(file) => match Texture::open(&file) {
                        Ok(tex) => m.texture = Some(Arc::new(tex)),
                        Err(e) => tracing::warn!(path = %file.display(),
                            "cannot decode texture of material '{}': {e}", m.name),
                    },
                    None => tracing::warn!(path = %path.display(),
                        "texture '{name}' of material '{}' not found", m.name),
                }
            }
            _ => {}
        }
    }
}

/// The file name of a `map_Kd [options] file` line.
fn texture_name(line: &[u8]) -> String {
    let toks: Vec<&[u8]> = Tokens::new(line).skip(1).collect();
    let mut i = 0;
    while i < toks.len() && toks[i].starts_with(b"-") && parse_f32(toks[i]).is_none() {
        // Options take one argument, except -o/-s/-t (up to three numbers) and -mm (two).
        let max_args = match toks[i] {
            b"-o" | b"-s" | b"-t" => 3,
            b"-mm" => 2,
            _ => 1,
        };
        i += 1;
        let mut taken = 0;
        while taken < max_args && i < toks.len() - 1 {
            let numeric = parse_f32(toks[i]).is_some();
            if taken > 0 && !numeric {
                break;
            }
            i += 1;
            taken += 1;
        }
    }
    let rest: Vec<String> = toks[i.min(toks.len())..]
        .iter()
        .map(|t| String::from_utf8_lossy(t).into_owned())
        .collect();
    rest.join(" ")
}

/// The colour of vertex `i` (see the module documentation).
fn vertex_color(s: &Scan, i: usize, rgb: Option<[f32; 3]>, scale: f32) -> [u8; 4] {
    let (mat, vt) = s
        .first_use
        .as_ref()
        .and_then(|f| f.get(i).copied())
        .unwrap_or((NONE, NONE));
    let material = s.materials.get(mat as usize);
    if let (Some(tex), Some(uv)) = (
        material.and_then(|m| m.texture.as_ref()),
        s.texcoords.get(vt as usize),
    ) {
        // OBJ's v = 0 is the bottom row of the image.
        return encode_rgba(tex.sample(uv[0], 1.0 - uv[1], Wrap::Repeat, Wrap::Repeat));
    }
    let byte = |c: f32| (c * scale * 255.0).round().clamp(0.0, 255.0) as u8;
    if let Some([r, g, b]) = rgb {
        return [byte(r), byte(g), byte(b), 255];
    }
    if let Some(kd) = material.and_then(|m| m.kd) {
        return [
            linear_to_srgb(kd[0]),
            linear_to_srgb(kd[1]),
            linear_to_srgb(kd[2]),
            255,
        ];
    }
    [255; 4]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_kd_options() {
        assert_eq!(texture_name(b"map_Kd tex.png"), "tex.png");
        assert_eq!(
            texture_name(b"map_Kd -s 1 1 1 -clamp on my tex.jpg"),
            "my tex.jpg"
        );
        assert_eq!(texture_name(b"map_Kd -o 0.5 a.png"), "a.png");
    }

    #[test]
    fn relative_and_absolute_indices() {
        let p = Path::new("t.obj");
        assert_eq!(resolve(p, 1, b"3", 5, "vertex", false, 0).unwrap(), 2);
        assert_eq!(resolve(p, 1, b"-1", 5, "vertex", false, 0).unwrap(), 4);
        assert!(resolve(p, 1, b"0", 5, "vertex", false, 0).is_err());
        assert!(resolve(p, 1, b"-6", 5, "vertex", false, 0).is_err());
        assert!(resolve(p, 1, b"6", 5, "vertex", false, 0).is_err());
        assert_eq!(resolve(p, 1, b"", 5, "normal", true, 0).unwrap(), NONE);
    }
}
