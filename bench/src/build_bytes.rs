//! Where the bytes of a `.mwlod` go (issue 15, item 5): every patch blob split into its parts
//! by the codec's own framing ([`codec::blob_bytes`]), each payload stream also compressed alone
//! at the build's zstd level to attribute the compressed body to the attributes, for all
//! patches and for the full-resolution ones (level 0). The file's tables are what is left.
//! Every patch is also re-encoded in the older `MWP2` layout (meshoptimizer's index codec,
//! varint residuals, zstd), so the gain of `MWP3` is printed from the same run.

use std::path::Path;

use anyhow::{Context, Result};
use meshwiki_engine::lod::LodFile;
use meshwiki_engine::lod::codec::{self, Layout, PatchRef, STREAM_NAMES};

#[derive(Default)]
struct Sums {
    patches: usize,
    stored: usize,
    headers: usize,
    image: usize,
    body: usize,
    raw: [usize; 6],
    alone: [usize; 6],
    payload_headers: usize,
}

impl Sums {
    fn add(&mut self, b: &codec::BlobBytes, payload: &[u8], level: i32) {
        self.patches += 1;
        self.stored += b.stored;
        self.headers += b.header;
        self.image += b.image;
        self.body += b.body;
        self.payload_headers += b.payload_header;
        let mut at = b.payload_header;
        for (k, &len) in b.streams.iter().enumerate() {
            let s = &payload[at..at + len];
            at += len;
            self.raw[k] += len;
            self.alone[k] += if len == 0 {
                0
            } else if level > 0 {
                zstd::bulk::compress(s, level).map_or(len, |c| c.len().min(len))
            } else {
                len
            };
        }
    }
}

/// One level's patches: counts and stream bytes.
#[derive(Default, Clone)]
struct Level {
    patches: usize,
    triangles: usize,
    vertices: usize,
    border: usize,
    shift: usize,
    streams: [usize; 6],
    stored: usize,
}

impl Level {
    fn add(&mut self, b: &codec::BlobBytes, p: &codec::Patch) {
        self.patches += 1;
        self.triangles += p.indices.len() / 3;
        self.vertices += p.original_ids.len();
        self.border += codec::border_vertices(&p.indices, p.original_ids.len())
            .iter()
            .filter(|&&x| x)
            .count();
        self.shift += p.shift as usize;
        for (s, n) in self.streams.iter_mut().zip(b.streams) {
            *s += n;
        }
        self.stored += b.stored;
    }
}

/// A decoded patch re-encoded in the `MWP2` layout (same vertices, ids, precision and
/// attributes).
fn as_v2(p: &codec::Patch, level: i32) -> Vec<u8> {
    let corner_uvs: Vec<[f32; 2]> = p
        .indices
        .iter()
        .map(|&i| p.uvs.get(i as usize).copied().unwrap_or_default())
        .collect();
    let texture = p
        .image
        .as_deref()
        .filter(|_| !p.uvs.is_empty())
        .map(|image| (corner_uvs.as_slice(), image));
    let patch = PatchRef {
        grid_positions: &p.grid_positions,
        colors: (!p.colors.is_empty()).then_some(p.colors.as_slice()),
        normals: (!p.normals.is_empty()).then_some(p.normals.as_slice()),
        original_ids: &p.original_ids,
        indices: &p.indices,
        shift: p.shift,
        texture,
    };
    codec::encode_layout(&patch, level, Layout::Meshopt).0
}

/// Prints the breakdown of the LOD file at `path` (built at zstd `level`).
pub fn print(path: &Path, level: i32) -> Result<()> {
    let lod = LodFile::open(path).with_context(|| format!("opening {}", path.display()))?;
    let grid = lod.grid();
    let (mut all, mut leaves, mut v2) = (Sums::default(), Sums::default(), Sums::default());
    let mut levels: Vec<Level> = Vec::new();
    for (id, node) in lod.nodes().iter().enumerate() {
        let blob = lod.blob(id as u32)?;
        let (b, payload) = codec::blob_bytes(blob).with_context(|| format!("patch {id}"))?;
        all.add(&b, &payload, level);
        let at = node.level as usize;
        if levels.len() <= at {
            levels.resize_with(at + 1, Level::default);
        }
        let patch = codec::decode(blob, &grid).with_context(|| format!("decoding patch {id}"))?;
        levels[at].add(&b, &patch);
        if node.level == 0 {
            leaves.add(&b, &payload, level);
        }
        let old = as_v2(&patch, level);
        let (b, payload) = codec::blob_bytes(&old)?;
        v2.add(&b, &payload, level);
    }
    let file = lod.bytes().len();
    let mb = |b: usize| b as f64 / 1e6;
    println!(
        "where the bytes go: {} patches, {:.2} MB stored of a {:.2} MB file ({:.2} MB of tables); leaves: {} patches, {:.2} MB",
        all.patches,
        mb(all.stored),
        mb(file),
        mb(file.saturating_sub(all.stored)),
        leaves.patches,
        mb(leaves.stored)
    );
    println!(
        "  {:<16} {:>10} {:>14} {:>8} {:>16} {:>12}",
        "part", "raw MB", "zstd alone MB", "share", "leaves: alone MB", "MWP2 MB"
    );
    let alone_total: usize = all.alone.iter().sum::<usize>().max(1);
    // The compressed body attributed to the streams in proportion to their size compressed alone.
    let body_share = |a: usize| a as f64 / alone_total as f64 * all.body as f64;
    for (k, name) in STREAM_NAMES.iter().enumerate() {
        if all.raw[k] == 0 {
            continue;
        }
        println!(
            "  {:<16} {:>10.2} {:>14.2} {:>7.1}% {:>16.2} {:>12.2}",
            name,
            mb(all.raw[k]),
            mb(all.alone[k]),
            100.0 * body_share(all.alone[k]) / all.stored.max(1) as f64,
            mb(leaves.alone[k]),
            mb(v2.alone[k])
        );
    }
    if all.image > 0 {
        println!(
            "  {:<16} {:>10.2} {:>14} {:>7.1}% {:>16.2}",
            "texture (JPEG)",
            mb(all.image),
            "-",
            100.0 * all.image as f64 / all.stored.max(1) as f64,
            mb(leaves.image)
        );
    }
    println!(
        "  {:<16} {:>10.2} {:>14} {:>7.1}%   ({} + {} bytes a patch, before zstd for the second)",
        "headers",
        mb(all.headers + all.payload_headers),
        "-",
        100.0 * all.headers as f64 / all.stored.max(1) as f64,
        all.headers / all.patches.max(1),
        all.payload_headers / all.patches.max(1)
    );
    println!(
        "  (the body is one zstd frame a patch: {:.2} MB for {:.2} MB of streams compressed alone; shares split it by those)",
        mb(all.body),
        mb(alone_total)
    );
    println!(
        "  per level (stream bytes before zstd; border = full precision):\n  {:>5} {:>7} {:>9} {:>9} {:>7} {:>6} {:>9} {:>9} {:>9} {:>8}",
        "level",
        "patches",
        "triangles",
        "vertices",
        "border",
        "shift",
        "idx b/t",
        "pos b/v",
        "id b/v",
        "MB"
    );
    for (l, s) in levels.iter().enumerate() {
        let per = |bytes: usize, n: usize| 8.0 * bytes as f64 / n.max(1) as f64;
        println!(
            "  {:>5} {:>7} {:>9} {:>9} {:>6.1}% {:>6.1} {:>9.2} {:>9.2} {:>9.2} {:>8.3}",
            l,
            s.patches,
            s.triangles,
            s.vertices,
            100.0 * s.border as f64 / s.vertices.max(1) as f64,
            s.shift as f64 / s.patches.max(1) as f64,
            per(s.streams[0], s.triangles),
            per(s.streams[1], s.vertices),
            per(s.streams[2], s.vertices),
            mb(s.stored)
        );
    }
    println!(
        "  the same patches in the MWP2 layout (meshoptimizer indices, varints, zstd): {:.2} MB stored; MWP3: {:.2} MB ({:.2}x smaller)",
        mb(v2.stored),
        mb(all.stored),
        v2.stored as f64 / all.stored.max(1) as f64
    );
    Ok(())
}
