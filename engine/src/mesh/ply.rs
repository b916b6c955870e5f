//! PLY reader: ASCII, binary little and big endian.
//!
//! Binary files are memory-mapped and decoded in place (fast paths for `float x y z` with
//! optional `uchar` colour and for `list uchar int` triangles); ASCII files are streamed
//! line by line. Elements may come in any order: a face or `tristrips` element that precedes
//! the vertices is skipped and read again afterwards (a second look at the map, or a seek).
//! Unknown elements and properties of any type are skipped. Polygons are fan-triangulated,
//! triangle strips expanded (`-1` restarts, odd triangles flipped). Original ID = vertex index.

use super::common::{
    BATCH, Emitter, LineReader, Tokens, check_finite, check_fits, err, map, non_finite, open,
    parse_f32, parse_f64, parse_i64, show,
};
use super::{ImportError, ImportErrorKind as K, ImportStats, Location, MeshSink, SourceInfo};
use crate::progress::Progress;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// Reads a PLY file into `sink`.
pub(crate) fn read(
    path: &Path,
    sink: &mut dyn MeshSink,
    progress: &dyn Progress,
) -> Result<ImportStats, ImportError> {
    let (file, len) = open(path)?;
    let mut lines = LineReader::from_file(file);
    let header = Header::parse(path, &mut lines, len)?;
    let plan = Plan::new(path, &header)?;
    let mut em = Emitter::new(path, sink, progress, "import", len);
    em.begin(&SourceInfo {
        vertex_count: Some(header.elements[plan.vertex].count),
        triangle_count_hint: plan
            .faces
            .filter(|&f| !plan.is_strip(f))
            .map(|f| header.elements[f].count),
        has_colors: plan.color.is_some(),
        has_normals: plan.normal.is_some(),
    })?;
    match header.encoding {
        Encoding::Ascii => {
            let mut r = AsciiReader {
                path,
                header: &header,
                plan: &plan,
                lines,
            };
            r.read(&mut em)?;
        }
        Encoding::Binary { big_endian } => {
            drop(lines);
            let file =
                File::open(path).map_err(|e| err(path, Location::File, K::Io(e.to_string())))?;
            let data = std::sync::Arc::new(map(path, &file)?);
            if (data.len() as u64) != len {
                return Err(err(
                    path,
                    Location::File,
                    K::Io("the file changed while it was read".into()),
                ));
            }
            let r = BinaryReader {
                path,
                header: &header,
                plan: &plan,
                data: &data,
                big: big_endian,
            };
            em.release_consumed(data.clone());
            r.read(&mut em)?;
        }
    }
    em.finish(len)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &[u8]) -> Option<Scalar> {
        Some(match name {
            b"char" | b"int8" => Scalar::I8,
            b"uchar" | b"uint8" => Scalar::U8,
            b"short" | b"int16" => Scalar::I16,
            b"ushort" | b"uint16" => Scalar::U16,
            b"int" | b"int32" => Scalar::I32,
            b"uint" | b"uint32" => Scalar::U32,
            b"float" | b"float32" => Scalar::F32,
            b"double" | b"float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_int(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// The value at `b[o..]`; the caller guarantees `o + size <= b.len()`.
    #[inline]
    fn read(self, b: &[u8], o: usize, big: bool) -> f64 {
        match self {
            Scalar::I8 => b[o] as i8 as f64,
            Scalar::U8 => b[o] as f64,
            Scalar::I16 => i16::from_ne_bytes(bytes2(b, o, big)) as f64,
            Scalar::U16 => u16::from_ne_bytes(bytes2(b, o, big)) as f64,
            Scalar::I32 => i32::from_ne_bytes(bytes4(b, o, big)) as f64,
            Scalar::U32 => u32::from_ne_bytes(bytes4(b, o, big)) as f64,
            Scalar::F32 => f32::from_ne_bytes(bytes4(b, o, big)) as f64,
            Scalar::F64 => f64::from_ne_bytes(bytes8(b, o, big)),
        }
    }

    /// An integer value at `b[o..]` (integer types only).
    #[inline]
    fn read_int(self, b: &[u8], o: usize, big: bool) -> i64 {
        match self {
            Scalar::I8 => b[o] as i8 as i64,
            Scalar::U8 => b[o] as i64,
            Scalar::I16 => i16::from_ne_bytes(bytes2(b, o, big)) as i64,
            Scalar::U16 => u16::from_ne_bytes(bytes2(b, o, big)) as i64,
            Scalar::I32 => i32::from_ne_bytes(bytes4(b, o, big)) as i64,
            Scalar::U32 => u32::from_ne_bytes(bytes4(b, o, big)) as i64,
            // Not reachable: index and count types are checked to be integers.
            Scalar::F32 | Scalar::F64 => -1,
        }
    }

    /// Converts a colour channel of this type to 8 bits: floats are 0..1, 16-bit 0..65535,
    /// other integers 0..255.
    #[inline]
    fn to_u8(self, v: f64) -> u8 {
        match self {
            Scalar::F32 | Scalar::F64 => (v * 255.0).round().clamp(0.0, 255.0) as u8,
            Scalar::U16 | Scalar::I16 => (v / 257.0).round().clamp(0.0, 255.0) as u8,
            _ => v.clamp(0.0, 255.0) as u8,
        }
    }
}

#[inline(always)]
fn bytes2(b: &[u8], o: usize, big: bool) -> [u8; 2] {
    let a = [b[o], b[o + 1]];
    if big == cfg!(target_endian = "big") {
        a
    } else {
        [a[1], a[0]]
    }
}

#[inline(always)]
fn bytes4(b: &[u8], o: usize, big: bool) -> [u8; 4] {
    let a = [b[o], b[o + 1], b[o + 2], b[o + 3]];
    if big == cfg!(target_endian = "big") {
        a
    } else {
        [a[3], a[2], a[1], a[0]]
    }
}

#[inline(always)]
fn bytes8(b: &[u8], o: usize, big: bool) -> [u8; 8] {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[o..o + 8]);
    if big != cfg!(target_endian = "big") {
        a.reverse();
    }
    a
}

#[inline(always)]
fn le_f32(b: &[u8], o: usize) -> f32 {
    f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}

#[inline(always)]
fn le_u32(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
    /// Header line declaring it, for messages.
    line: u64,
}

impl Element {
    /// Record size in bytes if every property is a scalar.
    fn fixed_size(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => Some(s.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }

    /// Smallest record in bytes (lists empty).
    fn min_binary_size(&self) -> u64 {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) | Kind::List { count: s, .. } => s.size() as u64,
            })
            .sum()
    }

    fn prop(&self, names: &[&str]) -> Option<usize> {
        names
            .iter()
            .find_map(|n| self.props.iter().position(|p| p.name == *n))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Binary { big_endian: bool },
}

struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    /// Bytes of the header, `end_header` line included.
    len: u64,
    /// Lines of the header.
    lines: u64,
}

/// Longest header accepted.
const MAX_HEADER: u64 = 1 << 20;

impl Header {
    fn parse(
        path: &Path,
        lines: &mut LineReader<BufReader<File>>,
        file_len: u64,
    ) -> Result<Header, ImportError> {
        let herr = |line: u64, msg: String| err(path, Location::Line(line), K::Header(msg));
        let first = lines.next_line(path)?.map(|l| l.to_vec());
        if first.as_deref().map(|l| l.trim_ascii_end()) != Some(b"ply") {
            return Err(herr(
                1,
                "not a PLY file (the first line must be 'ply')".into(),
            ));
        }
        let mut encoding = None;
        let mut elements: Vec<Element> = Vec::new();
        loop {
            if lines.offset > MAX_HEADER {
                return Err(herr(
                    lines.line,
                    "no 'end_header' in the first 1 MiB".into(),
                ));
            }
            let Some(line) = lines.next_line(path)?.map(<[u8]>::to_vec) else {
                return Err(err(
                    path,
                    Location::Line(lines.line),
                    K::Truncated("the header has no 'end_header' line".into()),
                ));
            };
            let n = lines.line;
            if !lines.terminated {
                // The file ends inside the header: whatever this last line says is cut off.
                return Err(err(
                    path,
                    Location::Line(n),
                    K::Truncated(format!(
                        "the file ends inside its header (line {n}, before 'end_header')"
                    )),
                ));
            }
            let mut t = Tokens::new(&line);
            let Some(key) = t.next() else { continue };
            match key {
                b"comment" | b"obj_info" => {}
                b"format" => {
                    let enc = match t.next() {
                        Some(b"ascii") => Encoding::Ascii,
                        Some(b"binary_little_endian") => Encoding::Binary { big_endian: false },
                        Some(b"binary_big_endian") => Encoding::Binary { big_endian: true },
                        other => {
                            return Err(herr(
                                n,
                                format!("unknown format '{}'", show(other.unwrap_or(b""))),
                            ));
                        }
                    };
                    match t.next() {
                        Some(v) if v == b"1.0" || v == b"1" => {}
                        other => {
                            return Err(err(
                                path,
                                Location::Line(n),
                                K::Unsupported(format!(
                                    "PLY version '{}' (only 1.0)",
                                    show(other.unwrap_or(b""))
                                )),
                            ));
                        }
                    }
                    encoding = Some(enc);
                }
                b"element" => {
                    let name = t.next();
                    let count = t
                        .next()
                        .and_then(|c| std::str::from_utf8(c).ok()?.parse().ok());
                    let (Some(name), Some(count)) = (name, count) else {
                        return Err(herr(
                            n,
                            "expected 'element <name> <count>' with a non-negative count".into(),
                        ));
                    };
                    elements.push(Element {
                        name: String::from_utf8_lossy(name).into_owned(),
                        count,
                        props: Vec::new(),
                        line: n,
                    });
                }
                b"property" => {
                    let Some(el) = elements.last_mut() else {
                        return Err(herr(n, "'property' before any 'element'".into()));
                    };
                    let scalar = |tok: Option<&[u8]>| -> Result<Scalar, ImportError> {
                        let tok = tok.unwrap_or(b"");
                        Scalar::parse(tok).ok_or_else(|| {
                            err(
                                path,
                                Location::Line(n),
                                K::Unsupported(format!("property type '{}'", show(tok))),
                            )
                        })
                    };
                    let ty = t.next();
                    let kind = if ty == Some(b"list") {
                        let count = scalar(t.next())?;
                        let item = scalar(t.next())?;
                        if !count.is_int() {
                            return Err(err(
                                path,
                                Location::Line(n),
                                K::Unsupported(format!("list count of type {count:?}")),
                            ));
                        }
                        Kind::List { count, item }
                    } else {
                        Kind::Scalar(scalar(ty)?)
                    };
                    let Some(name) = t.next() else {
                        return Err(herr(n, "property without a name".into()));
                    };
                    el.props.push(Property {
                        name: String::from_utf8_lossy(name).into_owned(),
                        kind,
                    });
                }
                b"end_header" => break,
                other => {
                    return Err(herr(n, format!("unknown header keyword '{}'", show(other))));
                }
            }
        }
        let Some(encoding) = encoding else {
            return Err(herr(lines.line, "no 'format' line".into()));
        };
        let header = Header {
            encoding,
            elements,
            len: lines.offset,
            lines: lines.line,
        };
        // Counts must fit in the file: a header claiming 10^12 vertices fails here.
        // The last line of an ASCII file may lack its newline.
        let available = file_len - header.len + u64::from(encoding == Encoding::Ascii);
        let mut need: u64 = 0;
        for el in &header.elements {
            let each = match encoding {
                Encoding::Binary { .. } => el.min_binary_size(),
                // A value and a separator per property.
                Encoding::Ascii => 2 * el.props.len() as u64,
            };
            let what = format!("'{}' elements", el.name);
            let loc = Location::Line(el.line);
            check_fits(path, loc.clone(), &what, el.count, each, available)?;
            need = need.saturating_add(el.count * each);
            if need > available {
                return Err(err(
                    path,
                    loc,
                    K::Truncated(format!(
                        "the header's element counts need at least {need} bytes, \
                         but only {available} bytes follow the header"
                    )),
                ));
            }
        }
        Ok(header)
    }
}

/// Where the reader finds what it needs in the header.
struct Plan {
    vertex: usize,
    pos: [usize; 3],
    normal: Option<[usize; 3]>,
    /// red, green, blue, optional alpha.
    color: Option<([usize; 3], Option<usize>)>,
    /// The face element, if any.
    faces: Option<usize>,
    /// The index list of each face / tristrips element, by element index.
    index_prop: Vec<Option<usize>>,
    strips: Option<usize>,
}

impl Plan {
    fn new(path: &Path, h: &Header) -> Result<Plan, ImportError> {
        let herr = |line: u64, msg: String| err(path, Location::Line(line), K::Header(msg));
        let Some(vertex) = h.elements.iter().position(|e| e.name == "vertex") else {
            return Err(herr(h.lines, "no 'vertex' element".into()));
        };
        let v = &h.elements[vertex];
        if v.count > u32::MAX as u64 {
            return Err(err(
                path,
                Location::Line(v.line),
                K::Unsupported(format!("{} vertices (at most 2^32 - 1)", v.count)),
            ));
        }
        let scalar = |names: &[&str]| -> Result<Option<usize>, ImportError> {
            match v.prop(names) {
                Some(i) if matches!(v.props[i].kind, Kind::List { .. }) => Err(err(
                    path,
                    Location::Line(v.line),
                    K::Unsupported(format!("vertex property '{}' is a list", v.props[i].name)),
                )),
                other => Ok(other),
            }
        };
        let (Some(x), Some(y), Some(z)) = (scalar(&["x"])?, scalar(&["y"])?, scalar(&["z"])?)
        else {
            return Err(herr(
                v.line,
                "the vertex element lacks an 'x', 'y' or 'z' property".into(),
            ));
        };
        let normal = match (scalar(&["nx"])?, scalar(&["ny"])?, scalar(&["nz"])?) {
            (Some(a), Some(b), Some(c)) => Some([a, b, c]),
            _ => None,
        };
        let color = match (
            scalar(&["red", "r", "diffuse_red"])?,
            scalar(&["green", "g", "diffuse_green"])?,
            scalar(&["blue", "b", "diffuse_blue"])?,
        ) {
            (Some(r), Some(g), Some(b)) => Some(([r, g, b], scalar(&["alpha", "a"])?)),
            _ => None,
        };
        let mut index_prop = vec![None; h.elements.len()];
        let mut faces = None;
        let mut strips = None;
        for (i, el) in h.elements.iter().enumerate() {
            let is_face = el.name == "face";
            let is_strip = el.name == "tristrips";
            if !(is_face || is_strip) {
                continue;
            }
            let Some(p) = el.prop(&["vertex_indices", "vertex_index"]) else {
                return Err(herr(
                    el.line,
                    format!("the '{}' element has no 'vertex_indices' list", el.name),
                ));
            };
            match el.props[p].kind {
                Kind::List { item, .. } if item.is_int() => {}
                Kind::List { item, .. } => {
                    return Err(err(
                        path,
                        Location::Line(el.line),
                        K::Unsupported(format!("vertex indices of type {item:?}")),
                    ));
                }
                Kind::Scalar(_) => {
                    return Err(herr(el.line, "'vertex_indices' is not a list".into()));
                }
            }
            index_prop[i] = Some(p);
            if is_face && faces.is_none() {
                faces = Some(i);
            }
            if is_strip && strips.is_none() {
                strips = Some(i);
            }
        }
        Ok(Plan {
            vertex,
            pos: [x, y, z],
            normal,
            color,
            faces: faces.or(strips),
            index_prop,
            strips,
        })
    }

    fn is_strip(&self, el: usize) -> bool {
        self.strips == Some(el)
    }
}

/// Expands triangle strips; `-1` (or `u32::MAX` for unsigned lists) restarts.
#[derive(Default)]
struct Strip {
    a: u32,
    b: u32,
    k: u32,
}

impl Strip {
    #[inline]
    fn restart(&mut self) {
        self.k = 0;
    }

    #[inline]
    fn push(&mut self, c: u32, em: &mut Emitter) -> Result<(), ImportError> {
        match self.k {
            0 => self.a = c,
            1 => self.b = c,
            k => {
                // Odd triangles are flipped to keep a consistent orientation.
                let t = if k % 2 == 0 {
                    [self.a, self.b, c]
                } else {
                    [self.b, self.a, c]
                };
                em.strip_triangle(t)?;
                self.a = self.b;
                self.b = c;
            }
        }
        self.k = self.k.saturating_add(1);
        Ok(())
    }
}

struct BinaryReader<'a> {
    path: &'a Path,
    header: &'a Header,
    plan: &'a Plan,
    data: &'a [u8],
    big: bool,
}

impl BinaryReader<'_> {
    fn truncated(&self, at: usize, what: String) -> ImportError {
        err(self.path, Location::Byte(at as u64), K::Truncated(what))
    }

    fn read(&self, em: &mut Emitter) -> Result<(), ImportError> {
        let mut pos = self.header.len as usize;
        let mut deferred = Vec::new();
        let mut have_vertices = false;
        for (i, el) in self.header.elements.iter().enumerate() {
            let start = pos;
            if i == self.plan.vertex {
                pos = self.vertices(el, pos, em)?;
                have_vertices = true;
            } else if let Some(ip) = self.plan.index_prop[i] {
                if have_vertices {
                    pos = self.faces(i, el, ip, pos, em)?;
                } else {
                    deferred.push((i, ip, start));
                    pos = self.skip(el, pos)?;
                }
            } else {
                pos = self.skip(el, pos)?;
            }
        }
        if pos != self.data.len() {
            return Err(err(
                self.path,
                Location::Byte(pos as u64),
                K::Syntax(format!(
                    "{} bytes after the last element (wrong element count in the header?)",
                    self.data.len() - pos
                )),
            ));
        }
        for (i, ip, start) in deferred {
            self.faces(i, &self.header.elements[i], ip, start, em)?;
        }
        Ok(())
    }

    /// Skips an element, returning the offset after it.
    fn skip(&self, el: &Element, pos: usize) -> Result<usize, ImportError> {
        if let Some(size) = el.fixed_size() {
            let bytes = (el.count as usize).checked_mul(size);
            return match bytes.and_then(|b| pos.checked_add(b)) {
                Some(end) if end <= self.data.len() => Ok(end),
                _ => Err(self.truncated(
                    pos,
                    format!(
                        "the file ends inside the {} '{}' elements",
                        el.count, el.name
                    ),
                )),
            };
        }
        let mut p = pos;
        for n in 0..el.count {
            p = self.walk(el, p, n, |_, _, _| Ok(()))?;
        }
        Ok(p)
    }

    /// Walks one record at `p`, calling `list(prop, first_item_offset, len)` for each list;
    /// returns the offset after the record.
    #[inline]
    fn walk(
        &self,
        el: &Element,
        mut p: usize,
        n: u64,
        mut list: impl FnMut(usize, usize, usize) -> Result<(), ImportError>,
    ) -> Result<usize, ImportError> {
        let start = p;
        for (k, prop) in el.props.iter().enumerate() {
            match prop.kind {
                Kind::Scalar(s) => p += s.size(),
                Kind::List { count, item } => {
                    if p + count.size() > self.data.len() {
                        p = usize::MAX;
                        break;
                    }
                    let len = count.read_int(self.data, p, self.big);
                    p += count.size();
                    let Some(bytes) = usize::try_from(len)
                        .ok()
                        .and_then(|l| l.checked_mul(item.size()))
                    else {
                        return Err(err(
                            self.path,
                            Location::Byte(start as u64),
                            K::Syntax(format!(
                                "'{}' {n} has a list '{}' of negative length {len}",
                                el.name, prop.name
                            )),
                        ));
                    };
                    if bytes > self.data.len().saturating_sub(p) {
                        p = usize::MAX;
                        break;
                    }
                    list(k, p, len as usize)?;
                    p += bytes;
                }
            }
        }
        if p > self.data.len() {
            return Err(self.truncated(
                start,
                format!("the file ends inside '{}' {n} of {}", el.name, el.count),
            ));
        }
        Ok(p)
    }

    fn vertices(&self, el: &Element, pos: usize, em: &mut Emitter) -> Result<usize, ImportError> {
        let plan = self.plan;
        let ty = |i: usize| match el.props[i].kind {
            Kind::Scalar(s) => s,
            Kind::List { .. } => Scalar::U8, // Not reachable: checked in the plan.
        };
        let Some(stride) = el.fixed_size() else {
            return self.vertices_with_lists(el, pos, em);
        };
        let count = el.count as usize;
        let end = count
            .checked_mul(stride)
            .and_then(|b| pos.checked_add(b))
            .filter(|&e| e <= self.data.len())
            .ok_or_else(|| {
                self.truncated(pos, format!("the file ends inside the {count} vertices"))
            })?;
        let offsets: Vec<usize> = el
            .props
            .iter()
            .scan(0, |o, p| {
                let here = *o;
                if let Kind::Scalar(s) = p.kind {
                    *o += s.size();
                }
                Some(here)
            })
            .collect();
        let off = |i: usize| offsets[i];
        let data = &self.data[pos..end];

        let [px, py, pz] = plan.pos;
        let fast = !self.big
            && plan.pos.iter().all(|&i| ty(i) == Scalar::F32)
            && plan
                .normal
                .is_none_or(|n| n.iter().all(|&i| ty(i) == Scalar::F32))
            && plan
                .color
                .is_none_or(|(c, a)| c.iter().chain(a.iter()).all(|&i| ty(i) == Scalar::U8));
        let bad = |i: usize, p: [f32; 3]| -> Option<ImportError> {
            check_finite(p).map(|what| {
                err(
                    self.path,
                    Location::Byte((pos + i * stride) as u64),
                    K::NonFinite(what, i as u64),
                )
            })
        };
        if fast {
            let (ox, oy, oz) = (off(px), off(py), off(pz));
            let on = plan.normal.map(|n| n.map(off));
            let oc = plan.color.map(|(c, a)| (c.map(off), a.map(off)));
            for (i, rec) in data.chunks_exact(stride.max(1)).take(count).enumerate() {
                let p = [le_f32(rec, ox), le_f32(rec, oy), le_f32(rec, oz)];
                if let Some(e) = bad(i, p) {
                    return Err(e);
                }
                let c = match oc {
                    Some((c, a)) => [rec[c[0]], rec[c[1]], rec[c[2]], a.map_or(255, |a| rec[a])],
                    None => [255; 4],
                };
                let n = match on {
                    Some(o) => normal([le_f32(rec, o[0]), le_f32(rec, o[1]), le_f32(rec, o[2])]),
                    None => [0.0; 3],
                };
                em.vertex(p, c, n)?;
                if i % BATCH == BATCH - 1 {
                    em.tick((pos + i * stride) as u64)?;
                }
            }
        } else {
            let big = self.big;
            for (i, rec) in data.chunks_exact(stride.max(1)).take(count).enumerate() {
                let get = |k: usize| ty(k).read(rec, off(k), big);
                let p64 = [get(px), get(py), get(pz)];
                let p = p64.map(|c| c as f32);
                if let Some(e) = bad(i, p) {
                    return Err(e);
                }
                let c = match plan.color {
                    Some((c, a)) => [
                        ty(c[0]).to_u8(get(c[0])),
                        ty(c[1]).to_u8(get(c[1])),
                        ty(c[2]).to_u8(get(c[2])),
                        a.map_or(255, |a| ty(a).to_u8(get(a))),
                    ],
                    None => [255; 4],
                };
                let n = match plan.normal {
                    Some(o) => normal(o.map(|k| get(k) as f32)),
                    None => [0.0; 3],
                };
                em.vertex(p, c, n)?;
                if i % BATCH == BATCH - 1 {
                    em.tick((pos + i * stride) as u64)?;
                }
            }
        }
        Ok(end)
    }

    /// Vertices whose element also has list properties: walk each record.
    fn vertices_with_lists(
        &self,
        el: &Element,
        pos: usize,
        em: &mut Emitter,
    ) -> Result<usize, ImportError> {
        let plan = self.plan;
        let mut offsets = vec![0usize; el.props.len()];
        let mut p = pos;
        for i in 0..el.count {
            let start = p;
            // Scalar offsets of this record.
            let mut o = p;
            for (k, prop) in el.props.iter().enumerate() {
                offsets[k] = o;
                match prop.kind {
                    Kind::Scalar(s) => o += s.size(),
                    Kind::List { count, item } => {
                        if o + count.size() > self.data.len() {
                            break;
                        }
                        let len = count.read_int(self.data, o, self.big).max(0) as u64;
                        o = o.saturating_add(count.size());
                        o = o.saturating_add(len.saturating_mul(item.size() as u64) as usize);
                    }
                }
            }
            p = self.walk(el, p, i, |_, _, _| Ok(()))?;
            let get = |k: usize| match el.props[k].kind {
                Kind::Scalar(s) => s.read(self.data, offsets[k], self.big),
                Kind::List { .. } => 0.0,
            };
            let ty = |k: usize| match el.props[k].kind {
                Kind::Scalar(s) => s,
                Kind::List { .. } => Scalar::U8,
            };
            let p64 = plan.pos.map(get);
            let pf = p64.map(|c| c as f32);
            if let Some(what) = check_finite(pf) {
                return Err(err(
                    self.path,
                    Location::Byte(start as u64),
                    K::NonFinite(what, i),
                ));
            }
            let c = match plan.color {
                Some((c, a)) => [
                    ty(c[0]).to_u8(get(c[0])),
                    ty(c[1]).to_u8(get(c[1])),
                    ty(c[2]).to_u8(get(c[2])),
                    a.map_or(255, |a| ty(a).to_u8(get(a))),
                ],
                None => [255; 4],
            };
            let n = plan
                .normal
                .map_or([0.0; 3], |o| normal(o.map(|k| get(k) as f32)));
            em.vertex(pf, c, n)?;
            if i.is_multiple_of(BATCH as u64) {
                em.tick(start as u64)?;
            }
        }
        Ok(p)
    }

    /// Reads a face or tristrips element at `pos`, returning the offset after it.
    fn faces(
        &self,
        el_index: usize,
        el: &Element,
        index_prop: usize,
        pos: usize,
        em: &mut Emitter,
    ) -> Result<usize, ImportError> {
        let nv = self.header.elements[self.plan.vertex].count;
        let data = self.data;
        let big = self.big;
        let strip = self.plan.is_strip(el_index);
        let out_of_range = |index: i64, face: u64, at: usize| {
            err(
                self.path,
                Location::Byte(at as u64),
                out_of_range_kind(index, nv, face, self.header.elements[self.plan.vertex].line),
            )
        };
        let Kind::List { item, .. } = el.props[index_prop].kind else {
            return Ok(pos); // Not reachable: checked in the plan.
        };
        let fast = !big
            && !strip
            && el.props.len() == 1
            && matches!(
                el.props[0].kind,
                Kind::List {
                    count: Scalar::U8,
                    item: Scalar::I32 | Scalar::U32
                }
            );
        // Signed 32-bit indices cannot name vertices beyond 2^31.
        let limit = if item == Scalar::I32 {
            nv.min(1 << 31)
        } else {
            nv
        };
        let mut p = pos;
        let mut corners: Vec<u32> = Vec::new();
        let mut strip_state = Strip::default();
        for f in 0..el.count {
            if f.is_multiple_of(BATCH as u64) {
                em.tick(p as u64)?;
            }
            // Common case: a triangle as `uchar 3` + three 32-bit indices.
            if fast && p + 13 <= data.len() && data[p] == 3 {
                let t = [
                    le_u32(data, p + 1),
                    le_u32(data, p + 5),
                    le_u32(data, p + 9),
                ];
                if t.iter().any(|&i| i as u64 >= limit) {
                    let bad = t.iter().copied().find(|&i| i as u64 >= limit).unwrap_or(0);
                    let index = if item == Scalar::I32 {
                        bad as i32 as i64
                    } else {
                        bad as i64
                    };
                    return Err(out_of_range(index, f, p));
                }
                em.triangle(t)?;
                p += 13;
                continue;
            }
            let start = p;
            corners.clear();
            p = self.walk(el, p, f, |k, first, len| {
                if k != index_prop {
                    return Ok(());
                }
                let size = item.size();
                for j in 0..len {
                    let v = item.read_int(data, first + j * size, big);
                    if strip && (v == -1 || (item == Scalar::U32 && v == u32::MAX as i64)) {
                        strip_state.restart();
                        continue;
                    }
                    if v < 0 || v as u64 >= nv {
                        return Err(out_of_range(v, f, start));
                    }
                    if strip {
                        strip_state.push(v as u32, em)?;
                    } else {
                        corners.push(v as u32);
                    }
                }
                Ok(())
            })?;
            if strip {
                // Each tristrips record is its own strip.
                strip_state.restart();
            } else {
                em.polygon(&corners)?;
            }
        }
        Ok(p)
    }
}

/// A normal from the file; non-finite ones become zero (unknown).
#[inline]
fn normal(n: [f32; 3]) -> [f32; 3] {
    if n.iter().all(|c| c.is_finite()) {
        n
    } else {
        [0.0; 3]
    }
}

struct AsciiReader<'a> {
    path: &'a Path,
    header: &'a Header,
    plan: &'a Plan,
    lines: LineReader<BufReader<File>>,
}

/// The line of element `n` of `el` and its number, or a truncation error.
fn record<'l>(
    lines: &'l mut LineReader<BufReader<File>>,
    path: &Path,
    el: &Element,
    n: u64,
) -> Result<(&'l [u8], u64), ImportError> {
    let before = lines.line;
    lines.next_numbered(path)?.ok_or_else(|| {
        err(
            path,
            Location::Line(before + 1),
            K::Truncated(format!(
                "the file ends after {n} of {} '{}' elements",
                el.count, el.name
            )),
        )
    })
}

impl AsciiReader<'_> {
    fn read(&mut self, em: &mut Emitter) -> Result<(), ImportError> {
        let mut deferred = Vec::new();
        let mut have_vertices = false;
        let header = self.header;
        for (i, el) in header.elements.iter().enumerate() {
            if el.props.is_empty() {
                continue;
            }
            if i == self.plan.vertex {
                self.vertices(el, em)?;
                have_vertices = true;
            } else if let Some(ip) = self.plan.index_prop[i] {
                if have_vertices {
                    self.faces(i, el, ip, em)?;
                } else {
                    deferred.push((i, ip, self.lines.offset, self.lines.line));
                    self.skip(el, em)?;
                }
            } else {
                self.skip(el, em)?;
            }
        }
        if self.lines.next_nonblank(self.path)?.is_some() {
            return Err(err(
                self.path,
                Location::Line(self.lines.line),
                K::Syntax(
                    "data after the last element (wrong element count in the header?)".into(),
                ),
            ));
        }
        for (i, ip, offset, line) in deferred {
            self.lines.seek(self.path, offset, line)?;
            self.faces(i, &header.elements[i], ip, em)?;
        }
        Ok(())
    }

    fn skip(&mut self, el: &Element, em: &mut Emitter) -> Result<(), ImportError> {
        for n in 0..el.count {
            if n.is_multiple_of(BATCH as u64) {
                em.tick(self.lines.offset)?;
            }
            record(&mut self.lines, self.path, el, n)?;
        }
        Ok(())
    }

    fn vertices(&mut self, el: &Element, em: &mut Emitter) -> Result<(), ImportError> {
        // What each property is used for: 0 = skip, 1..=3 position, 4..=6 normal, 7..=10 colour.
        let mut role = vec![0u8; el.props.len()];
        for (k, &p) in self.plan.pos.iter().enumerate() {
            role[p] = 1 + k as u8;
        }
        if let Some(n) = self.plan.normal {
            for (k, &p) in n.iter().enumerate() {
                role[p] = 4 + k as u8;
            }
        }
        if let Some((c, a)) = self.plan.color {
            for (k, &p) in c.iter().chain(a.iter()).enumerate() {
                role[p] = 7 + k as u8;
            }
        }
        let path = self.path;
        for n in 0..el.count {
            if n.is_multiple_of(BATCH as u64) {
                em.tick(self.lines.offset)?;
            }
            let (line, line_no) = record(&mut self.lines, path, el, n)?;
            // Slot = role - 1: x y z, nx ny nz, r g b a (alpha opaque unless given).
            let mut vals = [0f64; 10];
            let mut types = [Scalar::U8; 10];
            vals[9] = 255.0;
            let mut toks = Tokens::new(line);
            for (k, prop) in el.props.iter().enumerate() {
                match prop.kind {
                    Kind::Scalar(s) => {
                        let Some(tok) = toks.next() else {
                            return Err(too_few(path, line_no, el, n, &prop.name));
                        };
                        let r = role[k] as usize;
                        if r != 0 {
                            vals[r - 1] = parse_value(s, tok)
                                .ok_or_else(|| bad_value(path, line_no, tok, &prop.name, s))?;
                            types[r - 1] = s;
                        }
                    }
                    Kind::List { .. } => {
                        let Some(len) = toks.next().and_then(parse_i64).filter(|&l| l >= 0) else {
                            return Err(too_few(path, line_no, el, n, &prop.name));
                        };
                        for _ in 0..len {
                            if toks.next().is_none() {
                                return Err(too_few(path, line_no, el, n, &prop.name));
                            }
                        }
                    }
                }
            }
            if toks.next().is_some() {
                return Err(too_many(path, line_no, el, n));
            }
            let p = [vals[0] as f32, vals[1] as f32, vals[2] as f32];
            if check_finite(p).is_some() {
                let bad = vals[..3]
                    .iter()
                    .copied()
                    .find(|&v| !(v as f32).is_finite())
                    .unwrap_or(f64::NAN);
                return Err(err(
                    path,
                    Location::Line(line_no),
                    K::NonFinite(non_finite(bad), n),
                ));
            }
            let c = [6, 7, 8, 9].map(|r| types[r].to_u8(vals[r]));
            let nrm = normal([vals[3] as f32, vals[4] as f32, vals[5] as f32]);
            em.vertex(p, c, nrm)?;
        }
        Ok(())
    }

    fn faces(
        &mut self,
        el_index: usize,
        el: &Element,
        index_prop: usize,
        em: &mut Emitter,
    ) -> Result<(), ImportError> {
        let nv = self.header.elements[self.plan.vertex].count;
        let strip = self.plan.is_strip(el_index);
        let path = self.path;
        let mut corners: Vec<u32> = Vec::new();
        let mut strip_state = Strip::default();
        for n in 0..el.count {
            if n.is_multiple_of(BATCH as u64) {
                em.tick(self.lines.offset)?;
            }
            let (line, line_no) = record(&mut self.lines, path, el, n)?;
            let mut toks = Tokens::new(line);
            corners.clear();
            for (k, prop) in el.props.iter().enumerate() {
                match prop.kind {
                    Kind::Scalar(_) => {
                        if toks.next().is_none() {
                            return Err(too_few(path, line_no, el, n, &prop.name));
                        }
                    }
                    Kind::List { item, .. } => {
                        let Some(len_tok) = toks.next() else {
                            return Err(too_few(path, line_no, el, n, &prop.name));
                        };
                        let Some(len) = parse_i64(len_tok).filter(|&l| l >= 0) else {
                            // A coordinate where a face was expected: the header declared
                            // fewer vertices than the file holds.
                            let hint = if n == 0 && parse_f64(len_tok).is_some() {
                                format!(
                                    ": this looks like vertex data, so the header's vertex count \
                                     ({nv}, line {}) is probably smaller than the vertex data",
                                    self.header.elements[self.plan.vertex].line
                                )
                            } else {
                                String::new()
                            };
                            return Err(err(
                                path,
                                Location::Line(line_no),
                                K::Syntax(format!(
                                    "bad list length '{}' in '{}' {n}{hint}",
                                    show(len_tok),
                                    el.name
                                )),
                            ));
                        };
                        for _ in 0..len {
                            let Some(tok) = toks.next() else {
                                return Err(too_few(path, line_no, el, n, &prop.name));
                            };
                            if k != index_prop {
                                continue;
                            }
                            let Some(v) = parse_i64(tok) else {
                                return Err(bad_value(path, line_no, tok, &prop.name, item));
                            };
                            if strip && (v == -1 || (item == Scalar::U32 && v == u32::MAX as i64)) {
                                strip_state.restart();
                                continue;
                            }
                            if v < 0 || v as u64 >= nv {
                                return Err(err(
                                    path,
                                    Location::Line(line_no),
                                    out_of_range_kind(
                                        v,
                                        nv,
                                        n,
                                        self.header.elements[self.plan.vertex].line,
                                    ),
                                ));
                            }
                            if strip {
                                strip_state.push(v as u32, em)?;
                            } else {
                                corners.push(v as u32);
                            }
                        }
                    }
                }
            }
            if toks.next().is_some() {
                return Err(too_many(path, line_no, el, n));
            }
            if strip {
                strip_state.restart();
            } else {
                em.polygon(&corners)?;
            }
        }
        Ok(())
    }
}

/// Parses a token as a value of type `s` (floats exactly as `f32` when the type is float).
fn parse_value(s: Scalar, tok: &[u8]) -> Option<f64> {
    match s {
        Scalar::F32 => parse_f32(tok).map(f64::from),
        Scalar::F64 => parse_f64(tok),
        _ => parse_i64(tok)
            .map(|v| v as f64)
            .or_else(|| parse_f64(tok).filter(|v| v.fract() == 0.0)),
    }
}

/// A face index outside the vertices: past the header's count (most often that count is too
/// small for the data), or negative.
fn out_of_range_kind(index: i64, count: u64, face: u64, line: u64) -> K {
    if index >= 0 {
        K::BeyondDeclaredVertices {
            index,
            count,
            face,
            line,
        }
    } else {
        K::IndexOutOfRange { index, count, face }
    }
}

fn too_few(path: &Path, line: u64, el: &Element, n: u64, prop: &str) -> ImportError {
    err(
        path,
        Location::Line(line),
        K::Syntax(format!(
            "'{}' {n} ends before its property '{prop}' (too few values)",
            el.name
        )),
    )
}

fn too_many(path: &Path, line: u64, el: &Element, n: u64) -> ImportError {
    err(
        path,
        Location::Line(line),
        K::Syntax(format!(
            "'{}' {n} has more values than its {} properties",
            el.name,
            el.props.len()
        )),
    )
}

fn bad_value(path: &Path, line: u64, tok: &[u8], prop: &str, s: Scalar) -> ImportError {
    err(
        path,
        Location::Line(line),
        K::Syntax(format!(
            "'{}' is not a valid {s:?} value for '{prop}'",
            show(tok)
        )),
    )
}
