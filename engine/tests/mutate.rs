//! Deterministic mutation testing of every parser that takes outside bytes (issue 14 §8): PLY
//! (binary and ASCII), OBJ and its MTL, glTF (JSON with external buffer and texture), GLB, STL
//! (binary and ASCII), OFF, the stroke-mask PNG and the `.mwlod` reader (with damaged files as
//! they come off a disk, and with damage whose checksums were re-sealed so the tables and the
//! patch decoder see it).
//!
//! The seeds are cut from a real scan (`../shared/data/meshes/gargoyle_50k_vcolor.ply`: its first
//! triangles, with colour, normals and texture coordinates), or from the generated relief when
//! the shared data is absent. Each case mutates a seed (truncation, bit flips, byte values,
//! header numbers set to huge or negative values, deleted, duplicated and inserted ranges) and
//! runs the parser on it. A case passes when the parser returns (an error or a mesh), without a
//! panic, within the watchdog, and without allocating beyond a bound set by the input's size;
//! an accepted mesh must also be well formed (indices in range, finite positions). Every
//! figure is printed per parser. The stable-toolchain counterpart of the cargo-fuzz targets in
//! `fuzz/`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use meshwiki_engine::lod::format::Header;
use meshwiki_engine::lod::{self, BuildOptions, LodFile, NodeRecord};
use meshwiki_engine::mesh::{self, Mesh};
use meshwiki_engine::progress::NoProgress;
use meshwiki_engine::select::mask::StrokeMask;

// ---- allocation accounting ---------------------------------------------------------------------

struct Counting;

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
            let now = CURRENT.fetch_add(new_size, Ordering::Relaxed) + new_size;
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Runs `f`, returning its result and the most memory it held at once beyond what was held
/// before.
fn measured<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = CURRENT.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let out = f();
    (out, PEAK.load(Ordering::Relaxed).saturating_sub(base))
}

// ---- deterministic randomness ------------------------------------------------------------------

/// SplitMix64.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
}

const HUGE_TEXT: &[&str] = &[
    "0",
    "-1",
    "1",
    "2147483647",
    "2147483648",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "99999999999999999999999999",
    "-99999999999",
    "1e39",
    "1e309",
    "nan",
    "inf",
    "-0",
    "0x10",
    "",
];

const HUGE_U32: &[u32] = &[
    0,
    1,
    0x7FFF_FFFF,
    0x8000_0000,
    0xFFFF_FFFF,
    0xFFFF_FFFE,
    0x0100_0000,
    0x1000_0000,
    255,
    256,
    65535,
    65536,
];

/// One mutation of `seed`: one to three operations.
fn mutate(seed: &[u8], rng: &mut Rng, text: bool) -> Vec<u8> {
    let mut b = seed.to_vec();
    let ops = 1 + rng.below(3);
    for _ in 0..ops {
        if b.is_empty() {
            b.push(rng.next() as u8);
            continue;
        }
        // Half of the positional edits land in the first 512 bytes (the header).
        let pos = |rng: &mut Rng, len: usize| {
            if rng.below(2) == 0 {
                rng.below(len.min(512))
            } else {
                rng.below(len)
            }
        };
        match rng.below(9) {
            0 => {
                let at = rng.below(b.len());
                b.truncate(at);
            }
            1 => {
                for _ in 0..1 + rng.below(8) {
                    let at = pos(rng, b.len());
                    b[at] ^= 1 << rng.below(8);
                }
            }
            2 => {
                let at = pos(rng, b.len());
                b[at] = *[
                    0u8, 0xFF, 0x7F, 0x80, b'-', b'9', b' ', b'\n', b'\r', b'"', b'{', b'/',
                ]
                .get(rng.below(12))
                .unwrap_or(&0);
            }
            3 | 4 if text => {
                // A number of the text set to a huge, negative or malformed value.
                let starts: Vec<usize> = (0..b.len())
                    .filter(|&i| b[i].is_ascii_digit() && (i == 0 || !b[i - 1].is_ascii_digit()))
                    .collect();
                if starts.is_empty() {
                    continue;
                }
                let in_header: Vec<usize> = starts.iter().copied().filter(|&i| i < 512).collect();
                let pick = if !in_header.is_empty() && rng.below(2) == 0 {
                    in_header[rng.below(in_header.len())]
                } else {
                    starts[rng.below(starts.len())]
                };
                let mut end = pick;
                while end < b.len() && (b[end].is_ascii_digit() || b[end] == b'.') {
                    end += 1;
                }
                let value = HUGE_TEXT[rng.below(HUGE_TEXT.len())].as_bytes();
                b.splice(pick..end, value.iter().copied());
            }
            3 | 4 => {
                // A 32-bit field set to a huge or boundary value.
                if b.len() < 4 {
                    continue;
                }
                let at = pos(rng, b.len() - 3) & !if rng.below(2) == 0 { 3 } else { 0 };
                let at = at.min(b.len() - 4);
                let v = HUGE_U32[rng.below(HUGE_U32.len())];
                b[at..at + 4].copy_from_slice(&v.to_le_bytes());
            }
            5 => {
                let at = rng.below(b.len());
                let len = 1 + rng.below((b.len() - at).min(256));
                b.drain(at..at + len);
            }
            6 => {
                let at = rng.below(b.len());
                let len = 1 + rng.below((b.len() - at).min(256));
                let copy: Vec<u8> = b[at..at + len].to_vec();
                let to = rng.below(b.len() + 1);
                b.splice(to..to, copy);
            }
            7 => {
                let to = pos(rng, b.len() + 1);
                let n = 1 + rng.below(16);
                let bytes: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
                b.splice(to..to, bytes);
            }
            _ => {
                // A line (text) or a 64-byte block (binary) repeated many times.
                let at = rng.below(b.len());
                let end = if text {
                    b[at..]
                        .iter()
                        .position(|&c| c == b'\n')
                        .map_or(b.len(), |p| at + p + 1)
                } else {
                    (at + 64).min(b.len())
                };
                let chunk: Vec<u8> = b[at..end].to_vec();
                for _ in 0..1 + rng.below(40) {
                    b.splice(at..at, chunk.iter().copied());
                }
            }
        }
    }
    b
}

// ---- seeds from a real scan --------------------------------------------------------------------

/// The first triangles of the real scan (or the relief), reindexed, with colours, normals and
/// texture coordinates (from x, y).
struct Seed {
    mesh: Mesh,
    uvs: Vec<[f32; 2]>,
    source: String,
}

fn seed_mesh(triangles: usize) -> Seed {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/meshes/gargoyle_50k_vcolor.ply");
    let (full, source) = if path.exists() {
        (
            mesh::load(&path).expect("scan loads").0,
            "gargoyle_50k_vcolor.ply".to_string(),
        )
    } else {
        eprintln!(
            "note: {} not found: seeds come from the generated relief",
            path.display()
        );
        let mut m = Mesh::default();
        mesh::synth::Relief::new(4_000, 7)
            .stream(&mut m)
            .expect("relief");
        (m, "generated relief".to_string())
    };
    let mut map = std::collections::HashMap::new();
    let mut m = Mesh::default();
    for &i in full.indices.iter().take(triangles * 3) {
        let next = m.positions.len() as u32;
        let j = *map.entry(i).or_insert_with(|| {
            m.positions.push(full.positions[i as usize]);
            m.colors.push(
                full.colors
                    .get(i as usize)
                    .copied()
                    .unwrap_or([200, 180, 160, 255]),
            );
            m.normals.push(
                full.normals
                    .get(i as usize)
                    .copied()
                    .unwrap_or([0.0, 0.0, 1.0]),
            );
            next
        });
        m.indices.push(j);
    }
    let (lo, hi) = m
        .positions
        .iter()
        .fold(([f32::MAX; 2], [f32::MIN; 2]), |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1])],
                [hi[0].max(p[0]), hi[1].max(p[1])],
            )
        });
    let uvs = m
        .positions
        .iter()
        .map(|p| {
            [
                (p[0] - lo[0]) / (hi[0] - lo[0]).max(1e-6),
                (p[1] - lo[1]) / (hi[1] - lo[1]).max(1e-6),
            ]
        })
        .collect();
    Seed {
        mesh: m,
        uvs,
        source,
    }
}

fn ascii_ply(s: &Seed) -> Vec<u8> {
    let m = &s.mesh;
    let mut out = format!(
        "ply\nformat ascii 1.0\ncomment seed\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nproperty float nx\nproperty float ny\nproperty float nz\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        m.positions.len(),
        m.triangle_count()
    );
    for (i, p) in m.positions.iter().enumerate() {
        let (c, n) = (m.colors[i], m.normals[i]);
        out += &format!(
            "{} {} {} {} {} {} {} {} {}\n",
            p[0], p[1], p[2], c[0], c[1], c[2], n[0], n[1], n[2]
        );
    }
    for t in m.indices.chunks(3) {
        out += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    out.into_bytes()
}

fn obj(s: &Seed) -> Vec<u8> {
    let m = &s.mesh;
    let mut out = String::from("# seed\nmtllib seed.mtl\no seed\n");
    for (i, p) in m.positions.iter().enumerate() {
        out += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        out += &format!("vt {} {}\n", s.uvs[i][0], s.uvs[i][1]);
        let n = m.normals[i];
        out += &format!("vn {} {} {}\n", n[0], n[1], n[2]);
    }
    out += "usemtl skin\n";
    for (k, t) in m.indices.chunks(3).enumerate() {
        let [a, b, c] = [t[0] + 1, t[1] + 1, t[2] + 1];
        if k % 7 == 0 {
            // Some negative (relative) indices, as exporters write them.
            let n = m.positions.len() as i64;
            let r = |x: u32| x as i64 - 1 - n;
            out += &format!("f {} {} {}\n", r(a), r(b), r(c));
        } else {
            out += &format!("f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}\n");
        }
    }
    out.into_bytes()
}

const MTL: &str = "newmtl skin\nKd 0.8 0.7 0.6\nmap_Kd tex.png\n";

fn texture_png() -> Vec<u8> {
    let mut img = image::RgbaImage::new(16, 16);
    for (x, y, p) in img.enumerate_pixels_mut() {
        *p = image::Rgba([(x * 16) as u8, (y * 16) as u8, 128, 255]);
    }
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("png");
    out.into_inner()
}

fn off(s: &Seed) -> Vec<u8> {
    let m = &s.mesh;
    let mut out = format!("OFF\n{} {} 0\n", m.positions.len(), m.triangle_count());
    for p in &m.positions {
        out += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    for t in m.indices.chunks(3) {
        out += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    out.into_bytes()
}

fn stl_binary(s: &Seed) -> Vec<u8> {
    let m = &s.mesh;
    let mut out = vec![0u8; 80];
    out.extend_from_slice(&(m.triangle_count() as u32).to_le_bytes());
    for t in m.indices.chunks(3) {
        out.extend_from_slice(&[0u8; 12]);
        for &i in t {
            for c in m.positions[i as usize] {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        out.extend_from_slice(&[0, 0]);
    }
    out
}

fn stl_ascii(s: &Seed) -> Vec<u8> {
    let m = &s.mesh;
    let mut out = String::from("solid seed\n");
    for t in m.indices.chunks(3) {
        out += "facet normal 0 0 1\n outer loop\n";
        for &i in t {
            let p = m.positions[i as usize];
            out += &format!("  vertex {} {} {}\n", p[0], p[1], p[2]);
        }
        out += " endloop\nendfacet\n";
    }
    out += "endsolid seed\n";
    out.into_bytes()
}

/// The buffer of the glTF seeds (positions, normals, colours, uvs, indices, texture PNG) and
/// the JSON that describes it; `embedded` puts the texture in the buffer (GLB).
fn gltf_parts(s: &Seed, embedded: bool) -> (String, Vec<u8>) {
    let m = &s.mesh;
    let n = m.positions.len();
    let mut bin = Vec::new();
    let mut views = Vec::new();
    let mut push = |bin: &mut Vec<u8>, bytes: &[u8]| {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push((bin.len(), bytes.len()));
        bin.extend_from_slice(bytes);
    };
    let f32s = |v: &mut Vec<u8>, x: f32| v.extend_from_slice(&x.to_le_bytes());
    let mut pos = Vec::new();
    let mut nrm = Vec::new();
    let mut col = Vec::new();
    let mut uv = Vec::new();
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for i in 0..n {
        for k in 0..3 {
            f32s(&mut pos, m.positions[i][k]);
            f32s(&mut nrm, m.normals[i][k]);
            lo[k] = lo[k].min(m.positions[i][k]);
            hi[k] = hi[k].max(m.positions[i][k]);
        }
        col.extend_from_slice(&m.colors[i]);
        f32s(&mut uv, s.uvs[i][0]);
        f32s(&mut uv, s.uvs[i][1]);
    }
    let idx: Vec<u8> = m.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    push(&mut bin, &pos);
    push(&mut bin, &nrm);
    push(&mut bin, &col);
    push(&mut bin, &uv);
    push(&mut bin, &idx);
    let png = texture_png();
    if embedded {
        push(&mut bin, &png);
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let view_json: Vec<String> = views
        .iter()
        .map(|(o, l)| format!(r#"{{"buffer":0,"byteOffset":{o},"byteLength":{l}}}"#))
        .collect();
    let image = if embedded {
        r#"{"bufferView":5,"mimeType":"image/png"}"#.to_string()
    } else {
        r#"{"uri":"tex.png"}"#.to_string()
    };
    let buffer = if embedded {
        format!(r#"{{"byteLength":{}}}"#, bin.len())
    } else {
        format!(r#"{{"uri":"seed.bin","byteLength":{}}}"#, bin.len())
    };
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
"nodes":[{{"mesh":0,"translation":[0.5,0,0],"scale":[2,2,2]}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1,"COLOR_0":2,"TEXCOORD_0":3}},"indices":4,"material":0}}]}}],
"materials":[{{"pbrMetallicRoughness":{{"baseColorTexture":{{"index":0}}}}}}],
"textures":[{{"source":0,"sampler":0}}],"samplers":[{{}}],"images":[{image}],
"accessors":[
{{"bufferView":0,"componentType":5126,"count":{n},"type":"VEC3","min":[{},{},{}],"max":[{},{},{}]}},
{{"bufferView":1,"componentType":5126,"count":{n},"type":"VEC3"}},
{{"bufferView":2,"componentType":5121,"normalized":true,"count":{n},"type":"VEC4"}},
{{"bufferView":3,"componentType":5126,"count":{n},"type":"VEC2"}},
{{"bufferView":4,"componentType":5125,"count":{},"type":"SCALAR"}}],
"bufferViews":[{}],"buffers":[{buffer}]}}"#,
        lo[0],
        lo[1],
        lo[2],
        hi[0],
        hi[1],
        hi[2],
        m.indices.len(),
        view_json.join(",")
    );
    (json, bin)
}

fn glb(s: &Seed) -> Vec<u8> {
    let (json, bin) = gltf_parts(s, true);
    let mut json = json.into_bytes();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// Recomputes every checksum of a (damaged) `.mwlod` image where its layout still allows, so the
/// damage reaches the table checks and the patch decoder instead of stopping at a checksum.
fn reseal(b: &mut [u8]) {
    if b.len() < 256 {
        return;
    }
    let h: Header = bytemuck::pod_read_unaligned(&b[..256]);
    let size = b.len() as u64;
    let table = |off: u64, len: u64| -> Option<std::ops::Range<usize>> {
        let end = off.checked_add(len)?;
        (end <= size).then_some(off as usize..end as usize)
    };
    let mut h2 = h;
    if let Some(r) = table(h.nodes_offset, h.node_count as u64 * 128) {
        for k in 0..h.node_count as usize {
            let at = r.start + k * 128;
            let mut node: NodeRecord = bytemuck::pod_read_unaligned(&b[at..at + 128]);
            if let Some(blob) = table(node.blob_offset, node.blob_len as u64) {
                node.blob_crc = crc32fast::hash(&b[blob]);
                b[at..at + 128].copy_from_slice(bytemuck::bytes_of(&node));
            }
        }
        h2.nodes_crc = crc32fast::hash(&b[r]);
    }
    if let Some(r) = table(h.groups_offset, h.group_count as u64 * 48) {
        h2.groups_crc = crc32fast::hash(&b[r]);
    }
    if let Some(r) = table(h.links_offset, h.link_count as u64 * 4) {
        h2.links_crc = crc32fast::hash(&b[r]);
    }
    b[..256].copy_from_slice(bytemuck::bytes_of(&h2));
    let crc = crc32fast::hash(&b[..252]);
    b[252..256].copy_from_slice(&crc.to_le_bytes());
}

/// Recomputes the CRC of every PNG chunk whose length still fits, so the damage reaches the
/// decoder (and the mask's own checks) instead of stopping at a checksum.
fn reseal_png(b: &mut [u8]) {
    let mut at = 8;
    while at + 12 <= b.len() {
        let len = u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]) as usize;
        let Some(end) = (at + 8).checked_add(len).filter(|&e| e + 4 <= b.len()) else {
            break;
        };
        let crc = crc32fast::hash(&b[at + 4..end]);
        b[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        at = end + 4;
    }
}

// ---- the run -----------------------------------------------------------------------------------

/// What one parser did with its cases.
#[derive(Default)]
struct Tally {
    cases: u64,
    accepted: u64,
    rejected: u64,
    peak_bytes: usize,
    slowest: Duration,
    errors: std::collections::BTreeMap<String, u64>,
}

/// Kind of an error message: its words before the first digit or quote, for the summary.
fn kind_of(msg: &str) -> String {
    let cut = msg.find(['\'', '"', '(']).unwrap_or(msg.len());
    let mut kind = String::new();
    for c in msg[..cut].chars() {
        if c.is_ascii_digit() {
            if !kind.ends_with('N') {
                kind.push('N');
            }
        } else {
            kind.push(c);
        }
    }
    kind.trim_start_matches([':', ' '])
        .chars()
        .take(60)
        .collect::<String>()
        .trim()
        .to_string()
}

/// Watchdog: the case in flight, and when it started (ms since the run began; 0: none).
static CASE: AtomicU64 = AtomicU64::new(0);
static CASE_START_MS: AtomicU64 = AtomicU64::new(0);
const WATCHDOG: Duration = Duration::from_secs(60);

fn check_mesh(m: &Mesh) -> Result<(), String> {
    let n = m.positions.len() as u32;
    if let Some(i) = m.indices.iter().find(|&&i| i >= n) {
        return Err(format!("index {i} of {n} vertices"));
    }
    if !m.indices.len().is_multiple_of(3) {
        return Err("indices not a multiple of 3".into());
    }
    if m.positions.iter().flatten().any(|c| !c.is_finite()) {
        return Err("non-finite position".into());
    }
    if !m.colors.is_empty() && m.colors.len() != m.positions.len() {
        return Err("colour count differs".into());
    }
    Ok(())
}

struct Runner {
    dir: PathBuf,
    started: Instant,
    case_id: u64,
}

impl Runner {
    /// Runs `cases` mutations of `seed` through `parse` (which reads the file at the path it
    /// gets and returns an error message or `Ok`); `prepare` may rewrite a mutated image.
    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        name: &str,
        file_name: &str,
        seed: &[u8],
        text: bool,
        cases: u64,
        seed_value: u64,
        prepare: &dyn Fn(&mut Vec<u8>, &mut Rng),
        parse: &dyn Fn(&Path) -> Result<(), String>,
    ) -> Tally {
        let path = self.dir.join(file_name);
        // The seed itself parses.
        std::fs::write(&path, seed).expect("write seed");
        if let Err(e) = parse(&path) {
            panic!("{name}: the unmutated seed fails: {e}");
        }
        let mut rng = Rng(seed_value);
        let mut t = Tally::default();
        let allowance = |len: usize| (64usize << 20).max(len.saturating_mul(256));
        for _ in 0..cases {
            self.case_id += 1;
            let mut bytes = mutate(seed, &mut rng, text);
            prepare(&mut bytes, &mut rng);
            std::fs::write(&path, &bytes).expect("write case");
            CASE.store(self.case_id, Ordering::SeqCst);
            CASE_START_MS.store(
                self.started.elapsed().as_millis() as u64 + 1,
                Ordering::SeqCst,
            );
            let began = Instant::now();
            let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                measured(|| parse(&path))
            }));
            let took = began.elapsed();
            CASE_START_MS.store(0, Ordering::SeqCst);
            t.cases += 1;
            t.slowest = t.slowest.max(took);
            match caught {
                Err(_) => {
                    let keep = self.dir.join(format!("panic-{name}-{}", self.case_id));
                    let _ = std::fs::write(&keep, &bytes);
                    panic!(
                        "{name}: case {} panicked (input kept at {})",
                        self.case_id,
                        keep.display()
                    );
                }
                Ok((result, peak)) => {
                    t.peak_bytes = t.peak_bytes.max(peak);
                    if peak > allowance(bytes.len()) {
                        let keep = self.dir.join(format!("alloc-{name}-{}", self.case_id));
                        let _ = std::fs::write(&keep, &bytes);
                        panic!(
                            "{name}: case {} allocated {peak} bytes for a {}-byte input \
                             (input kept at {})",
                            self.case_id,
                            bytes.len(),
                            keep.display()
                        );
                    }
                    match result {
                        Ok(()) => t.accepted += 1,
                        Err(e) => {
                            if e.starts_with(DEFECT) {
                                let keep = self.dir.join(format!("defect-{name}-{}", self.case_id));
                                let _ = std::fs::write(&keep, &bytes);
                                panic!(
                                    "{name}: case {}: {e} (input kept at {})",
                                    self.case_id,
                                    keep.display()
                                );
                            }
                            assert!(!e.trim().is_empty(), "{name}: an empty error message");
                            t.rejected += 1;
                            let shown = e.replace(&*path.to_string_lossy(), "");
                            *t.errors.entry(kind_of(&shown)).or_default() += 1;
                        }
                    }
                }
            }
        }
        println!(
            "{name:<18} {:>6} cases  {:>6} rejected  {:>6} accepted  0 panics  peak {:>6.1} MB  \
             slowest {:>6.1} ms  ({} kinds of error)",
            t.cases,
            t.rejected,
            t.accepted,
            t.peak_bytes as f64 / 1048576.0,
            t.slowest.as_secs_f64() * 1000.0,
            t.errors.len()
        );
        if std::env::var_os("MESHWIKI_MUTATION_VERBOSE").is_some() {
            for (kind, count) in &t.errors {
                println!("    {count:>6}  {kind}");
            }
        }
        t
    }
}

/// Prefix of a parse result that is a defect (an accepted malformed result), not a rejection.
const DEFECT: &str = "DEFECT: ";

fn parse_mesh(path: &Path) -> Result<(), String> {
    match mesh::load(path) {
        Ok((m, _)) => check_mesh(&m).map_err(|e| format!("{DEFECT}accepted a malformed mesh: {e}")),
        Err(e) => Err(e.to_string()),
    }
}

/// Cases per parser: at least 10,000 (`MESHWIKI_MUTATION_CASES` raises it).
fn cases() -> u64 {
    std::env::var("MESHWIKI_MUTATION_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000u64)
        .max(10_000)
}

#[test]
fn parsers_survive_mutated_real_inputs() {
    let started = Instant::now();
    // Watchdog: a case that runs past WATCHDOG is a hang.
    std::thread::spawn(move || {
        loop {
            std::thread::sleep(Duration::from_secs(1));
            let s = CASE_START_MS.load(Ordering::SeqCst);
            if s > 0 {
                let now = started.elapsed().as_millis() as u64;
                if now.saturating_sub(s) > WATCHDOG.as_millis() as u64 {
                    eprintln!(
                        "mutation case {} hangs (over {WATCHDOG:?})",
                        CASE.load(Ordering::SeqCst)
                    );
                    std::process::abort();
                }
            }
        }
    });
    let dir = std::env::temp_dir().join(format!("mw-mutate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let seed = seed_mesh(600);
    println!(
        "seeds: {} triangles, {} vertices of {}",
        seed.mesh.triangle_count(),
        seed.mesh.positions.len(),
        seed.source
    );
    let n = cases();
    let mut r = Runner {
        dir: dir.clone(),
        started,
        case_id: 0,
    };
    let none = |_: &mut Vec<u8>, _: &mut Rng| {};
    let mut total = 0u64;

    // PLY, binary (colour, normals) and ASCII.
    let bin_path = dir.join("seed-bin.ply");
    mesh::write_ply(
        &bin_path,
        &seed.mesh.positions,
        Some(&seed.mesh.colors),
        Some(&seed.mesh.normals),
        &seed.mesh.indices,
        None,
    )
    .expect("write binary ply");
    let bin_ply = std::fs::read(&bin_path).expect("read");
    total += r
        .run(
            "ply (binary)",
            "case.ply",
            &bin_ply,
            false,
            n,
            1,
            &none,
            &parse_mesh,
        )
        .cases;
    total += r
        .run(
            "ply (ascii)",
            "case.ply",
            &ascii_ply(&seed),
            true,
            n,
            2,
            &none,
            &parse_mesh,
        )
        .cases;

    // OBJ with its MTL and texture; then the MTL mutated under a fixed OBJ.
    std::fs::write(dir.join("tex.png"), texture_png()).expect("texture");
    std::fs::write(dir.join("seed.mtl"), MTL).expect("mtl");
    let obj_seed = obj(&seed);
    total += r
        .run("obj", "case.obj", &obj_seed, true, n, 3, &none, &parse_mesh)
        .cases;
    std::fs::write(dir.join("fixed.obj"), &obj_seed).expect("obj");
    let fixed_obj = dir.join("fixed.obj");
    total += r
        .run(
            "mtl",
            "seed.mtl",
            MTL.as_bytes(),
            true,
            n,
            4,
            &none,
            &|_| parse_mesh(&fixed_obj),
        )
        .cases;
    std::fs::write(dir.join("seed.mtl"), MTL).expect("mtl");

    // glTF: the JSON mutated (external buffer and texture), and GLB.
    let (json, bin) = gltf_parts(&seed, false);
    std::fs::write(dir.join("seed.bin"), &bin).expect("bin");
    total += r
        .run(
            "gltf (json)",
            "case.gltf",
            json.as_bytes(),
            true,
            n,
            5,
            &none,
            &parse_mesh,
        )
        .cases;
    total += r
        .run(
            "glb",
            "case.glb",
            &glb(&seed),
            false,
            n,
            6,
            &none,
            &parse_mesh,
        )
        .cases;

    // STL, binary and ASCII; OFF.
    total += r
        .run(
            "stl (binary)",
            "case.stl",
            &stl_binary(&seed),
            false,
            n,
            7,
            &none,
            &parse_mesh,
        )
        .cases;
    total += r
        .run(
            "stl (ascii)",
            "case.stl",
            &stl_ascii(&seed),
            true,
            n,
            8,
            &none,
            &parse_mesh,
        )
        .cases;
    total += r
        .run(
            "off",
            "case.off",
            &off(&seed),
            true,
            n,
            9,
            &none,
            &parse_mesh,
        )
        .cases;

    // The stroke-mask PNG (as the viewer uploads it: labels 0 to 4).
    let (w, h) = (96u32, 64u32);
    let labels: Vec<u8> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            match (x / 12 + y / 16) % 6 {
                k @ 1..=4 => k as u8,
                _ => 0,
            }
        })
        .collect();
    let mask_png = StrokeMask::new(w, h, labels).expect("mask").encode_png();
    let read_mask = |p: &Path| -> Result<(), String> {
        let bytes = std::fs::read(p).map_err(|e| e.to_string())?;
        match StrokeMask::decode_png(&bytes) {
            Ok(m) => {
                if (0..=4).map(|l| m.count(l)).sum::<usize>() != m.labels.len() {
                    return Err(format!("{DEFECT}a mask with a pixel that is no label"));
                }
                Ok(())
            }
            Err(e) => Err(e.to_string()),
        }
    };
    total += r
        .run(
            "mask png", "case.png", &mask_png, false, n, 10, &none, &read_mask,
        )
        .cases;
    total += r
        .run(
            "mask png (resealed)",
            "case.png",
            &mask_png,
            false,
            n,
            13,
            &|b, _| reseal_png(b),
            &read_mask,
        )
        .cases;

    // .mwlod: a small hierarchy of the seed (several levels), damaged as on disk, and damaged
    // with its checksums re-sealed.
    let big_seed = seed_mesh(3000);
    let lod_path = dir.join("seed.mwlod");
    lod::build_mesh(
        &big_seed.mesh,
        &lod_path,
        &BuildOptions {
            max_patch_triangles: 128,
            threads: Some(1),
            scratch_dir: Some(dir.clone()),
            ..BuildOptions::default()
        },
        &NoProgress,
    )
    .expect("build seed lod");
    let lod_seed = std::fs::read(&lod_path).expect("read lod");
    let read_lod = |p: &Path| -> Result<(), String> {
        let file = LodFile::open(p).map_err(|e| e.to_string())?;
        for node in 0..file.nodes().len() as u32 {
            let patch = file.patch(node).map_err(|e| e.to_string())?;
            let nv = patch.positions.len() as u32;
            if patch.indices.iter().any(|&i| i >= nv)
                || patch.original_ids.len() != patch.positions.len()
            {
                return Err(format!("{DEFECT}accepted a malformed patch {node}"));
            }
        }
        for e in [0.0f32, 1e-3, 1e-2, f32::INFINITY] {
            let cut = lod::cut_uniform(file.nodes(), e);
            lod::export_cut(&file, &cut).map_err(|e| e.to_string())?;
        }
        Ok(())
    };
    total += r
        .run(
            "mwlod (on disk)",
            "case.mwlod",
            &lod_seed,
            false,
            n,
            11,
            &none,
            &read_lod,
        )
        .cases;
    total += r
        .run(
            "mwlod (resealed)",
            "case.mwlod",
            &lod_seed,
            false,
            n,
            12,
            &|b, _| reseal(b),
            &read_lod,
        )
        .cases;
    println!(
        "{total} mutated inputs, 0 panics, in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let _ = std::fs::remove_dir_all(&dir);
}
