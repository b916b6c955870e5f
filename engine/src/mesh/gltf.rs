//! glTF 2.0 reader (`.gltf` with `.bin`/data URIs/images, and `.glb`).
//!
//! Reads every mesh primitive of the default scene (or the first scene, or all root nodes)
//! with node transforms applied (normals by the inverse transpose; mirroring transforms flip
//! the winding), in TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN modes (points and lines are
//! skipped). Vertices are **welded by position** across the scene: glTF splits vertices at UV
//! seams, and surface adjacency needs them joined. A welded vertex keeps the attributes of its
//! first occurrence. Colour = baseColorFactor × COLOR_0 × base-colour texture sampled
//! (bilinear, linear light) at the vertex UV, encoded to sRGB.
//!
//! Buffers and images are read from the glTF's own directory only (no absolute paths, no
//! `..`), or from data URIs and the GLB binary chunk. Accessors are bounds-checked here
//! rather than by the `gltf` crate's readers, so malformed files give errors, not panics.

use super::common::{BATCH, Emitter, Welder, err, map, open};
use super::texture::{Texture, Wrap, encode_rgba};
use super::{
    ImportError, ImportErrorKind as K, ImportStats, Location, MeshSink, SourceInfo, SourceTexture,
    TexturedFace,
};
use crate::progress::Progress;
use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::mesh::{Mode, Semantic};
use ::gltf::texture::WrappingMode;
use glam::{Mat3, Mat4, Vec3};
use std::collections::HashMap;
use std::ops::Range;
use std::path::{Component, Path, PathBuf};
use std::sync::Arc;

/// Reads a glTF or GLB file into `sink`.
pub(crate) fn read(
    path: &Path,
    sink: &mut dyn MeshSink,
    progress: &dyn Progress,
) -> Result<ImportStats, ImportError> {
    let (file, _) = open(path)?;
    let main = map(path, &file)?;
    let main: &[u8] = &main;
    let (json, bin) = if main.starts_with(b"glTF") {
        glb_chunks(path, main)?
    } else {
        (0..main.len(), None)
    };
    let json = &main[json];
    let mut root = ::gltf::json::Root::from_slice(json).map_err(|e| {
        err(
            path,
            Location::Line(e.line() as u64),
            K::Syntax(format!("invalid glTF JSON: {e}")),
        )
    })?;
    fill_missing_bounds(&mut root).map_err(|m| {
        err(
            path,
            Location::File,
            K::Header(format!("invalid glTF: {m}")),
        )
    })?;
    let doc = ::gltf::Document::from_json(root).map_err(|e| {
        err(
            path,
            Location::File,
            K::Header(format!("invalid glTF: {e}")),
        )
    })?;
    let dir = path.parent().unwrap_or(Path::new("."));

    let mut owned: Vec<Buf> = Vec::new();
    for buffer in doc.buffers() {
        owned.push(load_buffer(path, dir, &buffer, bin.clone())?);
    }
    let buffers: Vec<&[u8]> = owned.iter().map(|b| b.bytes(main)).collect();
    let ctx = Ctx {
        path,
        buffers: &buffers,
    };

    // The primitives to read, with their world transforms.
    let mut draws: Vec<(::gltf::Primitive, Mat4)> = Vec::new();
    for (node, m) in scene_nodes(&doc) {
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                match prim.mode() {
                    Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan => {
                        draws.push((prim, m));
                    }
                    other => tracing::warn!(path = %path.display(), mesh = mesh.index(),
                        "skipping a primitive of mode {other:?} (not triangles)"),
                }
            }
        }
    }

    // Textures, decoded once each; what the sink will get; the amount of work.
    let mut textures: HashMap<usize, Option<Arc<Texture>>> = HashMap::new();
    let (mut has_colors, mut has_normals) = (false, false);
    let mut total: u64 = 0;
    for (prim, _) in &draws {
        let pbr = prim.material().pbr_metallic_roughness();
        if let Some(info) = pbr.base_color_texture() {
            let tex = info.texture();
            let image = tex.source().index();
            let loaded = textures
                .entry(image)
                .or_insert_with(|| load_image(&ctx, &doc, dir, image).map(Arc::new));
            has_colors |= loaded.is_some();
        }
        has_colors |=
            prim.get(&Semantic::Colors(0)).is_some() || pbr.base_color_factor() != [1.0; 4];
        has_normals |= prim.get(&Semantic::Normals).is_some();
        let n = prim.get(&Semantic::Positions).map_or(0, |a| a.count());
        let idx = prim.indices().map_or(n, |a| a.count());
        // Counts come from the file: they are checked against the buffers when read.
        total = total.saturating_add((n as u64).saturating_add(idx as u64));
    }

    // Progress is reported in bytes (main file and external buffers), in proportion to the
    // accessor elements processed.
    let bytes = owned.iter().fold(main.len() as u64, |b, buf| match buf {
        Buf::Range(_) => b,
        other => b + other.bytes(main).len() as u64,
    });
    let work = Work {
        elements: total,
        bytes,
    };
    let mut em = Emitter::new(path, sink, progress, "import", bytes);
    em.begin(&SourceInfo {
        vertex_count: None,
        triangle_count_hint: Some(
            draws
                .iter()
                .map(|(p, _)| p.indices().map_or(0, |a| a.count() as u64 / 3))
                .sum(),
        ),
        has_colors,
        has_normals,
    })?;
    // Each (image, wrap modes) pair the primitives use is one texture of the sink, all handed
    // over before the first triangle.
    let mut handed: HashMap<(usize, Wrap, Wrap), u32> = HashMap::new();
    let mut prim_textures = Vec::with_capacity(draws.len());
    for (prim, _) in &draws {
        let texture = prim
            .material()
            .pbr_metallic_roughness()
            .base_color_texture()
            .and_then(|info| {
                let tex = info.texture();
                let image = tex.source().index();
                let t = textures.get(&image)?.as_ref()?;
                let s = tex.sampler();
                Some((
                    t,
                    info.tex_coord(),
                    wrap(s.wrap_s()),
                    wrap(s.wrap_t()),
                    image,
                ))
            });
        prim_textures.push(match texture {
            None => None,
            Some((t, set, ws, wt, image)) => {
                let id = match handed.get(&(image, ws, wt)) {
                    Some(&id) => id,
                    None => {
                        let id = handed.len() as u32;
                        em.texture(SourceTexture {
                            image: t.clone(),
                            wrap_s: ws,
                            wrap_t: wt,
                        })?;
                        handed.insert((image, ws, wt), id);
                        id
                    }
                };
                Some((&**t, set, ws, wt, id))
            }
        });
    }
    let mut welder = Welder::default();
    let mut done: u64 = 0;
    let mut remap: Vec<u32> = Vec::new();
    for ((prim, m), texture) in draws.iter().zip(prim_textures) {
        let p = Prim {
            work: &work,
            ctx: &ctx,
            prim,
            m: *m,
            texture,
            has_colors,
        };
        done = p.read(&mut em, &mut welder, &mut remap, done)?;
    }
    em.finish(bytes)
}

/// Converts accessor elements processed into bytes for progress.
struct Work {
    elements: u64,
    bytes: u64,
}

impl Work {
    fn at(&self, elements: u64) -> u64 {
        (elements as u128 * self.bytes as u128 / self.elements.max(1) as u128) as u64
    }
}

/// Gives POSITION accessors without `min`/`max` placeholder bounds: the spec requires them
/// and the `gltf` crate's validation rejects their absence, but some exporters omit them and
/// the reader does not use them. Also checks the POSITION accessor indices, which the crate's
/// validation would otherwise index out of bounds.
fn fill_missing_bounds(root: &mut ::gltf::json::Root) -> Result<(), String> {
    use ::gltf::json::Value;
    use ::gltf::json::validation::Checked;
    let mut positions = Vec::new();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &prim.attributes {
                if let Checked::Valid(::gltf::json::mesh::Semantic::Positions) = semantic {
                    if index.value() >= root.accessors.len() {
                        return Err(format!(
                            "mesh {m} primitive {p}: POSITION refers to accessor {}, \
                             which does not exist",
                            index.value()
                        ));
                    }
                    positions.push(index.value());
                }
            }
        }
    }
    for i in positions {
        if let Some(a) = root.accessors.get_mut(i) {
            let zeros = || Some(Value::Array(vec![Value::from(0.0); 3]));
            if a.min.is_none() {
                a.min = zeros();
            }
            if a.max.is_none() {
                a.max = zeros();
            }
        }
    }
    Ok(())
}

/// Byte ranges of a GLB's JSON chunk and optional binary chunk.
fn glb_chunks(path: &Path, d: &[u8]) -> Result<(Range<usize>, Option<Range<usize>>), ImportError> {
    let u32_at = |o: usize| {
        d.get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    let trunc =
        |at: usize, what: &str| err(path, Location::Byte(at as u64), K::Truncated(what.into()));
    let version = u32_at(4).ok_or_else(|| trunc(4, "GLB header shorter than 12 bytes"))?;
    if version != 2 {
        return Err(err(
            path,
            Location::Byte(4),
            K::Unsupported(format!("GLB version {version} (only 2)")),
        ));
    }
    let length = u32_at(8).ok_or_else(|| trunc(8, "GLB header shorter than 12 bytes"))?;
    if length > d.len() {
        return Err(trunc(
            8,
            &format!(
                "GLB header declares {length} bytes, the file has {}",
                d.len()
            ),
        ));
    }
    let d = &d[..length];
    let chunk = |at: usize| -> Result<Option<(usize, Range<usize>)>, ImportError> {
        if at >= d.len() {
            return Ok(None);
        }
        let (Some(len), Some(kind)) = (u32_at(at), u32_at(at + 4)) else {
            return Err(trunc(at, "GLB chunk header cut short"));
        };
        let body = at + 8..at + 8 + len;
        if body.end > d.len() {
            return Err(trunc(
                at,
                &format!("GLB chunk declares {len} bytes, fewer remain"),
            ));
        }
        Ok(Some((kind, body)))
    };
    let Some((0x4E4F_534A, json)) = chunk(12)? else {
        return Err(err(
            path,
            Location::Byte(12),
            K::Header("the first GLB chunk is not JSON".into()),
        ));
    };
    let next = json.end.next_multiple_of(4);
    let bin = match chunk(next)? {
        Some((0x004E_4942, b)) => Some(b),
        _ => None,
    };
    Ok((json, bin))
}

/// A buffer's bytes: part of the main file (GLB), decoded from a data URI, or a mapped file.
enum Buf {
    Range(Range<usize>),
    Owned(Vec<u8>),
    Mapped(memmap2::Mmap),
}

impl Buf {
    fn bytes<'a>(&'a self, main: &'a [u8]) -> &'a [u8] {
        match self {
            Buf::Range(r) => main.get(r.clone()).unwrap_or(&[]),
            Buf::Owned(v) => v,
            Buf::Mapped(m) => m,
        }
    }
}

fn load_buffer(
    path: &Path,
    dir: &Path,
    buffer: &::gltf::Buffer,
    bin: Option<Range<usize>>,
) -> Result<Buf, ImportError> {
    let i = buffer.index();
    let (buf, size, name) = match buffer.source() {
        ::gltf::buffer::Source::Bin => {
            let Some(bin) = bin else {
                return Err(err(
                    path,
                    Location::File,
                    K::Header(format!(
                        "buffer {i} has no URI and there is no GLB binary chunk"
                    )),
                ));
            };
            let n = bin.len();
            (Buf::Range(bin), n, "the GLB binary chunk".to_string())
        }
        ::gltf::buffer::Source::Uri(uri) => {
            if uri.starts_with("data:") {
                let bytes = data_uri(uri).ok_or_else(|| {
                    err(
                        path,
                        Location::File,
                        K::Syntax(format!("buffer {i}: malformed data URI")),
                    )
                })?;
                let n = bytes.len();
                (Buf::Owned(bytes), n, format!("buffer {i}'s data URI"))
            } else {
                let file = local(path, dir, uri, &format!("buffer {i}"))?;
                let (f, len) = open(&file)?;
                let m = map(&file, &f)?;
                (Buf::Mapped(m), len as usize, format!("'{uri}'"))
            }
        }
    };
    if size < buffer.length() {
        return Err(err(
            path,
            Location::File,
            K::Truncated(format!(
                "buffer {i} ({name}) has {size} bytes, the glTF declares {}",
                buffer.length()
            )),
        ));
    }
    Ok(buf)
}

/// Decodes a `data:[mime];base64,...` URI.
fn data_uri(uri: &str) -> Option<Vec<u8>> {
    let (meta, payload) = uri.strip_prefix("data:")?.split_once(',')?;
    if !meta.ends_with(";base64") {
        return Some(percent_decode(payload).into_bytes());
    }
    base64(payload.as_bytes())
}

fn base64(s: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3);
    let mut acc: u32 = 0;
    let mut bits = 0;
    for &c in s {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => break,
            c if c.is_ascii_whitespace() => continue,
            _ => return None,
        };
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Some(out)
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    let hex = |c: u8| (c as char).to_digit(16);
    while i < b.len() {
        if b[i] == b'%'
            && i + 2 < b.len()
            && let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2]))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// A file referenced by the glTF, inside its directory.
fn local(path: &Path, dir: &Path, uri: &str, what: &str) -> Result<PathBuf, ImportError> {
    let name = percent_decode(uri);
    let rel = Path::new(&name);
    let inside = !name.contains(':')
        && rel
            .components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    if !inside {
        return Err(err(
            path,
            Location::File,
            K::Unsupported(format!(
                "{what} refers to '{uri}', outside the glTF's directory"
            )),
        ));
    }
    let file = dir.join(rel);
    if !file.is_file() {
        return Err(err(
            path,
            Location::File,
            K::Io(format!("{what}: cannot find '{uri}' next to the glTF")),
        ));
    }
    Ok(file)
}

/// Decodes image `index`; failures are logged and the texture ignored.
fn load_image(ctx: &Ctx, doc: &::gltf::Document, dir: &Path, index: usize) -> Option<Texture> {
    let path = ctx.path;
    let json = doc.as_json().images.get(index)?;
    let result = if let Some(view) = json.buffer_view {
        doc.views()
            .nth(view.value())
            .and_then(|v| view_bytes(ctx, &v))
            .ok_or_else(|| "its buffer view lies outside its buffer".to_string())
            .and_then(Texture::decode)
    } else if let Some(uri) = json.uri.as_deref() {
        if uri.starts_with("data:") {
            data_uri(uri)
                .ok_or_else(|| "malformed data URI".to_string())
                .and_then(|b| Texture::decode(&b))
        } else {
            local(path, dir, uri, &format!("image {index}"))
                .map_err(|e| e.kind.to_string())
                .and_then(|f| Texture::open(&f))
        }
    } else {
        Err("no uri and no bufferView".into())
    };
    match result {
        Ok(t) => Some(t),
        Err(e) => {
            tracing::warn!(path = %path.display(), "ignoring base colour image {index}: {e}");
            None
        }
    }
}

fn view_bytes<'a>(ctx: &Ctx<'a>, view: &::gltf::buffer::View) -> Option<&'a [u8]> {
    let buf = ctx.buffers.get(view.buffer().index())?;
    let end = view.offset().checked_add(view.length())?;
    buf.get(view.offset()..end)
}

fn wrap(m: WrappingMode) -> Wrap {
    match m {
        WrappingMode::ClampToEdge => Wrap::Clamp,
        WrappingMode::MirroredRepeat => Wrap::Mirror,
        WrappingMode::Repeat => Wrap::Repeat,
    }
}

/// Nodes of the default scene with their world transforms (depth first, each node once).
fn scene_nodes(doc: &::gltf::Document) -> Vec<(::gltf::Node<'_>, Mat4)> {
    let roots: Vec<::gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => scene.nodes().collect(),
        None => {
            let mut child = vec![false; doc.nodes().len()];
            for n in doc.nodes() {
                for c in n.children() {
                    child[c.index()] = true;
                }
            }
            doc.nodes().filter(|n| !child[n.index()]).collect()
        }
    };
    let mut seen = vec![false; doc.nodes().len()];
    let mut out = Vec::new();
    let mut stack: Vec<(::gltf::Node, Mat4)> = roots
        .into_iter()
        .rev()
        .map(|n| (n, Mat4::IDENTITY))
        .collect();
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            continue; // A cycle or a node shared by two parents: invalid glTF, read once.
        }
        let m = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        let children: Vec<_> = node.children().collect();
        for c in children.into_iter().rev() {
            stack.push((c, m));
        }
        out.push((node, m));
    }
    out
}

struct Ctx<'a> {
    path: &'a Path,
    buffers: &'a [&'a [u8]],
}

/// A bounds-checked view of an accessor's elements.
struct Acc<'a> {
    data: &'a [u8],
    stride: usize,
    count: usize,
    comp: DataType,
    dims: usize,
    normalized: bool,
}

impl Ctx<'_> {
    fn fail(&self, msg: String) -> ImportError {
        err(self.path, Location::File, K::Syntax(msg))
    }

    fn accessor(
        &self,
        a: &::gltf::Accessor,
        allowed_dims: &[usize],
    ) -> Result<Acc<'_>, ImportError> {
        let i = a.index();
        if a.sparse().is_some() {
            return Err(err(
                self.path,
                Location::File,
                K::Unsupported(format!("sparse accessor {i}")),
            ));
        }
        let dims = match a.dimensions() {
            Dimensions::Scalar => 1,
            Dimensions::Vec2 => 2,
            Dimensions::Vec3 => 3,
            Dimensions::Vec4 => 4,
            other => {
                return Err(self.fail(format!("accessor {i} has unexpected type {other:?}")));
            }
        };
        if !allowed_dims.contains(&dims) {
            return Err(self.fail(format!(
                "accessor {i} has {dims} components, expected {allowed_dims:?}"
            )));
        }
        let comp = a.data_type();
        let elem = comp.size() * dims;
        let count = a.count();
        let Some(view) = a.view() else {
            return Err(err(
                self.path,
                Location::File,
                K::Unsupported(format!("accessor {i} without a buffer view")),
            ));
        };
        let Some(bytes) = view_bytes(self, &view) else {
            return Err(err(
                self.path,
                Location::File,
                K::Truncated(format!(
                    "buffer view {} (bytes {}..+{}) lies outside buffer {}",
                    view.index(),
                    view.offset(),
                    view.length(),
                    view.buffer().index()
                )),
            ));
        };
        let stride = view.stride().unwrap_or(elem);
        if stride < elem {
            return Err(self.fail(format!(
                "buffer view {} stride {stride} is smaller than accessor {i}'s element of {elem} bytes",
                view.index()
            )));
        }
        let need = match count {
            0 => Some(0),
            n => (n - 1)
                .checked_mul(stride)
                .and_then(|b| b.checked_add(elem))
                .and_then(|b| b.checked_add(a.offset())),
        };
        if need.is_none_or(|n| n > bytes.len()) {
            return Err(err(
                self.path,
                Location::File,
                K::Truncated(format!(
                    "accessor {i} needs {count} elements of {elem} bytes (stride {stride}) from \
                     offset {} but buffer view {} has {} bytes",
                    a.offset(),
                    view.index(),
                    bytes.len()
                )),
            ));
        }
        Ok(Acc {
            data: bytes.get(a.offset()..).unwrap_or(&[]),
            stride,
            count,
            comp,
            dims,
            normalized: a.normalized(),
        })
    }
}

impl Acc<'_> {
    /// Component `c` of element `i` as a float (normalised integers mapped to [0, 1]/[-1, 1]).
    #[inline]
    fn f(&self, i: usize, c: usize) -> f32 {
        if c >= self.dims || i >= self.count {
            return 0.0;
        }
        let o = i * self.stride + c * self.comp.size();
        let d = self.data;
        let n = self.normalized;
        match self.comp {
            DataType::F32 => f32::from_le_bytes([d[o], d[o + 1], d[o + 2], d[o + 3]]),
            DataType::U8 if n => d[o] as f32 / 255.0,
            DataType::U8 => d[o] as f32,
            DataType::I8 if n => (d[o] as i8 as f32 / 127.0).max(-1.0),
            DataType::I8 => d[o] as i8 as f32,
            DataType::U16 => {
                let v = u16::from_le_bytes([d[o], d[o + 1]]) as f32;
                if n { v / 65535.0 } else { v }
            }
            DataType::I16 => {
                let v = i16::from_le_bytes([d[o], d[o + 1]]) as f32;
                if n { (v / 32767.0).max(-1.0) } else { v }
            }
            DataType::U32 => u32::from_le_bytes([d[o], d[o + 1], d[o + 2], d[o + 3]]) as f32,
        }
    }

    /// An index (unsigned integer types); `None` for other types.
    #[inline]
    fn index(&self, i: usize) -> Option<u32> {
        let o = i * self.stride;
        let d = self.data;
        match self.comp {
            DataType::U8 => Some(d[o] as u32),
            DataType::U16 => Some(u16::from_le_bytes([d[o], d[o + 1]]) as u32),
            DataType::U32 => Some(u32::from_le_bytes([d[o], d[o + 1], d[o + 2], d[o + 3]])),
            _ => None,
        }
    }

    fn vec3(&self, i: usize) -> Vec3 {
        Vec3::new(self.f(i, 0), self.f(i, 1), self.f(i, 2))
    }
}

struct Prim<'a, 'd> {
    work: &'a Work,
    ctx: &'a Ctx<'a>,
    prim: &'a ::gltf::Primitive<'d>,
    m: Mat4,
    /// Base colour texture: image, coordinate set, wrap modes, the sink's texture index.
    texture: Option<(&'a Texture, u32, Wrap, Wrap, u32)>,
    has_colors: bool,
}

impl Prim<'_, '_> {
    /// Welds and delivers this primitive's vertices, then its triangles; returns work done.
    fn read(
        &self,
        em: &mut Emitter,
        welder: &mut Welder,
        remap: &mut Vec<u32>,
        mut done: u64,
    ) -> Result<u64, ImportError> {
        let ctx = self.ctx;
        let prim = self.prim;
        let where_ = format!("mesh primitive {}", prim.index());
        let Some(pos) = prim.get(&Semantic::Positions) else {
            return Err(ctx.fail(format!("{where_} has no POSITION")));
        };
        let pos = ctx.accessor(&pos, &[3])?;
        let normals = match prim.get(&Semantic::Normals) {
            Some(a) => Some(ctx.accessor(&a, &[3])?),
            None => None,
        };
        let colors = match prim.get(&Semantic::Colors(0)) {
            Some(a) => Some(ctx.accessor(&a, &[3, 4])?),
            None => None,
        };
        let uvs = match self.texture {
            Some((_, set, ..)) => match prim.get(&Semantic::TexCoords(set)) {
                Some(a) => Some(ctx.accessor(&a, &[2])?),
                None => None,
            },
            None => None,
        };
        let factor = prim.material().pbr_metallic_roughness().base_color_factor();
        let normal_m = {
            let m3 = Mat3::from_mat4(self.m);
            let det = m3.determinant();
            if det.is_finite() && det != 0.0 {
                m3.inverse().transpose()
            } else {
                Mat3::IDENTITY
            }
        };
        let flip = Mat3::from_mat4(self.m).determinant() < 0.0;

        remap.clear();
        for i in 0..pos.count {
            if i.is_multiple_of(BATCH) {
                em.tick(self.work.at(done + i as u64))?;
            }
            let p = self.m.transform_point3(pos.vec3(i)).to_array();
            if let Some(what) = super::common::check_finite(p) {
                return Err(err(
                    ctx.path,
                    Location::File,
                    K::NonFinite(format!("{what}, POSITION of {where_}"), i as u64),
                ));
            }
            let next = em.vertex_count();
            if next >= u32::MAX as u64 {
                return Err(err(
                    ctx.path,
                    Location::File,
                    K::Unsupported("more than 2^32 - 1 distinct vertices".into()),
                ));
            }
            let (w, new) = welder.weld(p, next as u32);
            remap.push(w);
            if !new {
                continue;
            }
            let n = match &normals {
                Some(a) => {
                    let n = (normal_m * a.vec3(i)).normalize_or_zero();
                    if n.is_finite() {
                        n.to_array()
                    } else {
                        [0.0; 3]
                    }
                }
                None => [0.0; 3],
            };
            let c = if self.has_colors {
                let mut c = factor;
                if let Some(a) = &colors {
                    for (k, ck) in c.iter_mut().enumerate() {
                        *ck *= if k < a.dims { a.f(i, k) } else { 1.0 };
                    }
                }
                if let (Some((tex, _, ws, wt, _)), Some(uv)) = (self.texture, &uvs) {
                    let t = tex.sample(uv.f(i, 0), uv.f(i, 1), ws, wt);
                    for k in 0..4 {
                        c[k] *= t[k];
                    }
                }
                encode_rgba(c)
            } else {
                [255; 4]
            };
            em.vertex(p, c, n)?;
        }
        done += pos.count as u64;

        let nv = pos.count;
        let indices = match prim.indices() {
            Some(a) => Some(ctx.accessor(&a, &[1])?),
            None => None,
        };
        let n_idx = indices.as_ref().map_or(nv, |a| a.count);
        // The welded vertex of corner `k`, and its texture coordinates.
        let corner = |k: usize, tri: usize| -> Result<(u32, [f32; 2]), ImportError> {
            let v = match &indices {
                Some(a) => a.index(k).ok_or_else(|| {
                    ctx.fail(format!("{where_}: indices are not unsigned integers"))
                })?,
                None => k as u32,
            };
            let uv = match &uvs {
                Some(a) if (v as usize) < a.count => [a.f(v as usize, 0), a.f(v as usize, 1)],
                _ => [0.0; 2],
            };
            let w = remap.get(v as usize).copied().ok_or_else(|| {
                err(
                    ctx.path,
                    Location::File,
                    K::IndexOutOfRange {
                        index: v as i64,
                        count: nv as u64,
                        face: tri as u64,
                    },
                )
            })?;
            Ok((w, uv))
        };
        let triangles = match prim.mode() {
            Mode::Triangles => n_idx / 3,
            _ => n_idx.saturating_sub(2),
        };
        for t in 0..triangles {
            if t.is_multiple_of(BATCH) {
                em.tick(self.work.at(done + t as u64))?;
            }
            let (a, b, c) = match prim.mode() {
                Mode::Triangles => (3 * t, 3 * t + 1, 3 * t + 2),
                Mode::TriangleStrip if t % 2 == 0 => (t, t + 1, t + 2),
                Mode::TriangleStrip => (t, t + 2, t + 1),
                _ => (t + 1, t + 2, 0), // fan
            };
            let (a, b, c) = (corner(a, t)?, corner(b, t)?, corner(c, t)?);
            let (a, b, c) = if flip { (a, c, b) } else { (a, b, c) };
            match (self.texture, &uvs) {
                (Some((.., id)), Some(_)) => {
                    let uv =
                        [a.1, b.1, c.1].map(|q| q.map(|x| if x.is_finite() { x } else { 0.0 }));
                    em.textured_triangle([a.0, b.0, c.0], TexturedFace { uv, texture: id })?
                }
                _ => em.triangle([a.0, b.0, c.0])?,
            }
        }
        Ok(done + n_idx as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_and_data_uris() {
        assert_eq!(base64(b"aGVsbG8=").unwrap(), b"hello");
        assert_eq!(base64(b"aGVsbG8").unwrap(), b"hello");
        assert!(base64(b"a*b").is_none());
        assert_eq!(
            data_uri("data:application/octet-stream;base64,AAEC").unwrap(),
            vec![0, 1, 2]
        );
        assert_eq!(percent_decode("a%20b%2"), "a b%2");
    }
}
