//! Patch blob codec (layout in `docs/FORMAT.md`), in two layouts: `MWP3`, which builds write,
//! and the older `MWP2`, still read.
//!
//! - Connectivity: `MWP3` a front-based traversal coder ([`super::frontcoder`]), vertices in
//!   traversal order; `MWP2` meshoptimizer's index codec, vertices in first-use order.
//! - Positions on the model-wide integer grid and original vertex IDs: predicted by
//!   parallelograms (Touma–Gotsman): `MWP3` by the multi-way prediction of
//!   [`super::parallelogram`] (ids by a median-edge rule), residuals range-coded in channels
//!   ([`super::rangecoder`]); `MWP2` by the one parallelogram along the triangle order,
//!   zigzag LEB128 residuals. `MWP3` ids may instead be listed in the Morton order of the
//!   decoded grid points, as gaps (`morton_sequence`; shorter wherever the scan's ids are
//!   in Morton order, as builds number them). Vertices on the patch border keep full grid
//!   precision, so a vertex shared by two patches (possibly at different levels) decodes to
//!   identical coordinates and cuts stay watertight; interior vertices of coarse patches are
//!   stored at a coarser step (`2^shift` grid units) chosen from the node's error, as Nexus
//!   quantises by a fraction of the node error.
//! - Colours: YCoCg with 6 bits (meshoptimizer's colour filter); `MWP3` predicts its bytes
//!   from the vertex's earlier neighbours and range-codes them, `MWP2` uses meshoptimizer's
//!   vertex codec. Decoded by [`decode_ycocg`] in exact integer arithmetic: meshoptimizer's own
//!   SIMD decoder uses an approximate reciprocal, so its results differ by one between
//!   platforms and decoders.
//! - Normals: the decoder computes every normal from the patch's triangles (area-weighted,
//!   exactly in f64 from the integer grid coordinates, so every decoder in every language
//!   gets the same bits); border vertices additionally store the difference between their
//!   scan normal and that prediction in octahedral coordinates (8 bits), so shading matches
//!   across patch borders while interior normals follow the geometry at that level.
//! - Textured patches (issue 11): every vertex has one texture coordinate in the patch's own
//!   atlas, so a vertex where the atlas' charts meet is stored once per chart (the same
//!   original ID and grid position each time: such copies sit on chart-border edges, which
//!   count as patch border, so they keep full precision and stored normals and decode to the
//!   same point). Coordinates are one affine map per chart of the atlas, applied to the
//!   decoded positions ([`super::chart_uv`]), or, where the charts are not projections, u16
//!   pairs through meshoptimizer's vertex codec; the atlas image (JPEG) travels in front of
//!   the compressed payload, as it is compressed already.
//! - The payload is compressed with zstd when that makes it smaller: range-coded streams
//!   do not gain, so `MWP3` payloads without meshoptimizer streams (texture coordinates) are
//!   stored as they are, without trying.

use meshopt::{
    decode_index_buffer, decode_vertex_buffer, encode_index_buffer, encode_vertex_buffer,
};
use rustc_hash::{FxHashMap as HashMap, FxHashSet as HashSet};

use super::chart_uv;
use super::frontcoder::{self, Prediction};
use super::jpegtables;
use super::parallelogram::{Parallelograms, predict};
use super::patch::{EdgeUses, edge_ends};
use super::rangecoder::{self, Channel};

/// Blob magic, first 4 bytes: front-coded connectivity and range-coded positions, ids,
/// colours and normals.
pub const BLOB_MAGIC: [u8; 4] = *b"MWP3";
/// The older layout (meshoptimizer's index codec, varint residuals), still read, and written
/// for patches the front coder refuses (a triangle repeating a corner).
pub const BLOB_MAGIC_V2: [u8; 4] = *b"MWP2";
const COMPRESSION_NONE: u8 = 0;
const COMPRESSION_ZSTD: u8 = 1;
const FLAG_COLORS: u32 = 1;
const FLAG_NORMALS: u32 = 2;
const FLAG_UVS: u32 = 4;
/// `MWP3` payload flag: the ids stream lists the ids in the Morton order of the vertices'
/// decoded grid points ([`morton_sequence`]) instead of predicting them along the traversal.
const FLAG_SORTED_IDS: u32 = 8;
/// Payload flag (with [`FLAG_UVS`]): the texture coordinates stream holds one affine map per
/// atlas chart instead of coordinates per vertex ([`super::chart_uv`]).
const FLAG_CHART_UVS: u32 = 16;
/// Payload flag (with [`FLAG_NORMALS`]): the normals stream holds one normal per original id:
/// a border vertex whose id an earlier border vertex has (a copy where atlas charts meet) takes
/// that vertex's decoded normal instead of reading one.
const FLAG_NORMALS_BY_ID: u32 = 32;
const KNOWN_FLAGS: u32 =
    FLAG_COLORS | FLAG_NORMALS | FLAG_UVS | FLAG_SORTED_IDS | FLAG_CHART_UVS | FLAG_NORMALS_BY_ID;
/// Blob header flag (byte 5): an image section (the colour atlas) follows the 12-byte header.
const BLOB_IMAGE: u8 = 1;
/// Blob header flag (byte 5): a normal-map section follows (after the image section, if any).
const BLOB_NORMALS: u8 = 2;
/// Blob header flag (byte 5): the sections' JPEGs are stored without their Huffman tables,
/// which are the standard ones ([`super::jpegtables`]).
const BLOB_STANDARD_HUFFMAN: u8 = 4;
/// Blob header flag (byte 5), only with [`BLOB_STANDARD_HUFFMAN`]: the sections' JPEGs are
/// also stored without their JFIF APP0 segment and quantisation tables, the standard ones
/// scaled by the quality each section starts with ([`jpegtables::strip_headers`]).
const BLOB_STANDARD_HEADERS: u8 = 8;
/// Blob header flag (byte 5), only with [`BLOB_IMAGE`]: the image section is a WebP
/// ([`super::atlas::AtlasCodec::Webp`]), stored whole; bits 2 and 3 then speak of the
/// normal-map section alone.
const BLOB_IMAGE_WEBP: u8 = 16;
const PAYLOAD_HEADER: usize = 52;
/// Octahedral normal quantisation: components in `-OCT_SCALE..=OCT_SCALE` (8 bits).
pub const OCT_SCALE: f64 = 127.0;
/// Bits per channel of YCoCg colours (meshoptimizer's colour filter).
pub const COLOR_BITS: i32 = 6;

/// Inverts meshoptimizer's colour filter (`meshopt_encodeFilterColor`) in place: YCoCg with
/// the scale in alpha's high bit back to RGBA8, rounding exactly (`docs/FORMAT.md`), so every
/// decoder in every language gets the same bytes.
pub fn decode_ycocg(colors: &mut [[u8; 4]]) {
    for c in colors {
        let a_raw = i32::from(c[3]);
        // The scale is the alpha's highest set bit, smeared down: 2^bits - 1.
        let mut scale = a_raw;
        scale |= scale >> 1;
        scale |= scale >> 2;
        scale |= scale >> 4;
        let y = i32::from(c[0]);
        let co = i32::from(c[1] as i8);
        let cg = i32::from(c[2] as i8);
        let a = ((a_raw << 1) & scale) | (a_raw & 1);
        let expand = |v: i32| -> u8 {
            if scale == 0 || v <= 0 {
                0
            } else {
                ((2 * v * 255 + scale) / (2 * scale)).min(255) as u8
            }
        };
        *c = [
            expand(y + co - cg),
            expand(y + cg),
            expand(y - co - cg),
            expand(a),
        ];
    }
}
/// Octahedral coordinates of a unit vector, rounded with `floor(x + 0.5)` (the same in every
/// language).
pub fn oct_encode(n: [f64; 3]) -> [i64; 2] {
    let l1 = n[0].abs() + n[1].abs() + n[2].abs();
    if l1.is_nan() || l1 <= 0.0 {
        return [0, 0];
    }
    let (mut x, mut y) = (n[0] / l1, n[1] / l1);
    if n[2] < 0.0 {
        let (ax, ay) = (x.abs(), y.abs());
        x = (1.0 - ay) * if x >= 0.0 { 1.0 } else { -1.0 };
        y = (1.0 - ax) * if y >= 0.0 { 1.0 } else { -1.0 };
    }
    [
        (x * OCT_SCALE + 0.5).floor() as i64,
        (y * OCT_SCALE + 0.5).floor() as i64,
    ]
}

/// Unit vector of octahedral coordinates.
pub fn oct_decode(q: [i64; 2]) -> [f32; 3] {
    let (x, y) = (
        q[0].clamp(-127, 127) as f64 / OCT_SCALE,
        q[1].clamp(-127, 127) as f64 / OCT_SCALE,
    );
    let z = 1.0 - x.abs() - y.abs();
    let (x, y) = if z < 0.0 {
        (
            (1.0 - y.abs()) * if x >= 0.0 { 1.0 } else { -1.0 },
            (1.0 - x.abs()) * if y >= 0.0 { 1.0 } else { -1.0 },
        )
    } else {
        (x, y)
    };
    let len = (x * x + y * y + z * z).sqrt();
    [(x / len) as f32, (y / len) as f32, (z / len) as f32]
}

/// Area-weighted vertex normals from integer grid coordinates, in f64. Cross products of
/// integer vectors below 2^26 are exact, and the summation order is the triangle order, so
/// the result is bit-identical in any IEEE-754 implementation that follows this order.
pub fn grid_normals(positions: &[[i64; 3]], indices: &[u32]) -> Vec<[f64; 3]> {
    grid_normals_of(positions, indices, None)
}

/// [`grid_normals`] of the vertices `wanted` marks (the others are left unspecified): the
/// same sums in the same order, over the triangles that touch one. The encoder stores the
/// normals of border vertices only.
fn grid_normals_of(
    positions: &[[i64; 3]],
    indices: &[u32],
    wanted: Option<&[bool]>,
) -> Vec<[f64; 3]> {
    let mut acc = vec![[0f64; 3]; positions.len()];
    let wanted_at = |i: u32| wanted.is_none_or(|w| w.get(i as usize).copied().unwrap_or(false));
    for t in indices.chunks_exact(3) {
        if wanted.is_some() && !t.iter().any(|&i| wanted_at(i)) {
            continue;
        }
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions[i as usize].map(|v| v as f64));
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let w = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            u[1] * w[2] - u[2] * w[1],
            u[2] * w[0] - u[0] * w[2],
            u[0] * w[1] - u[1] * w[0],
        ];
        for &i in t {
            let s = &mut acc[i as usize];
            s[0] += n[0];
            s[1] += n[1];
            s[2] += n[2];
        }
    }
    for (v, n) in acc.iter_mut().enumerate() {
        if !wanted_at(v as u32) {
            continue;
        }
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        *n = if len > 0.0 {
            [n[0] / len, n[1] / len, n[2] / len]
        } else {
            [0.0, 0.0, 1.0]
        };
    }
    acc
}

/// Largest vertex or index count a blob may declare (a patch has at most a few thousand).
const MAX_ELEMENTS: u32 = 1 << 20;
/// Largest interior quantisation shift.
pub const MAX_SHIFT: u32 = 24;

/// Model-wide quantisation grid: `world = origin + step * grid`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub origin: [f64; 3],
    pub step: f64,
}

impl Grid {
    /// Grid coordinate of a world position (clamped to the grid's non-negative range).
    pub fn quantize(&self, p: [f32; 3]) -> [u32; 3] {
        std::array::from_fn(|i| {
            let g = ((p[i] as f64 - self.origin[i]) / self.step).round();
            g.clamp(0.0, (u32::MAX >> 1) as f64) as u32
        })
    }

    /// World position of a grid coordinate.
    pub fn dequantize(&self, g: [u32; 3]) -> [f32; 3] {
        std::array::from_fn(|i| (self.origin[i] + self.step * g[i] as f64) as f32)
    }

    /// Largest distance between a point and its quantised position at `shift`.
    pub fn max_error(&self) -> f64 {
        self.max_error_at(0)
    }

    /// Largest distance between a point and its position quantised at `2^shift` grid units.
    pub fn max_error_at(&self, shift: u32) -> f64 {
        self.step * (1u64 << shift) as f64 * 0.5 * 3f64.sqrt()
    }

    /// The interior quantisation shift for a node whose error bound is `error`: the largest
    /// step of at most a fifth of the error (Nexus uses a tenth of the error per node).
    pub fn shift_for_error(&self, error: f32) -> u32 {
        let ratio = 0.4 * error as f64 / self.step;
        if ratio.is_finite() && ratio >= 2.0 {
            (ratio.log2().floor() as u32).min(MAX_SHIFT)
        } else {
            0
        }
    }
}

/// A decoded patch in flat arrays. `original_ids[i]` is the input-file index of vertex `i`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Patch {
    pub positions: Vec<[f32; 3]>,
    /// Empty when the model has no colour.
    pub colors: Vec<[u8; 4]>,
    /// Unit normals (stored on the border, computed inside).
    pub normals: Vec<[f32; 3]>,
    pub original_ids: Vec<u32>,
    pub indices: Vec<u32>,
    /// Interior vertices are at `2^shift` grid units (0 = full precision; the payload's).
    pub shift: u32,
    /// Grid coordinates of the vertices (exact; `positions` are their world values).
    pub grid_positions: Vec<[u32; 3]>,
    /// Texture coordinates in [`Patch::image`] (empty when the patch has no texture): `v = 0`
    /// is the image's top row.
    pub uvs: Vec<[f32; 2]>,
    /// The patch's atlas (JPEG), when it has one.
    pub image: Option<Vec<u8>>,
    /// The patch's normal map (JPEG, same layout as the atlas), when it has one.
    pub normal_map: Option<Vec<u8>>,
}

/// Input of [`encode`]: a patch with positions already on the grid.
#[derive(Clone, Copy)]
pub struct PatchRef<'a> {
    pub grid_positions: &'a [[u32; 3]],
    pub colors: Option<&'a [[u8; 4]]>,
    pub normals: Option<&'a [[f32; 3]]>,
    pub original_ids: &'a [u32],
    pub indices: &'a [u32],
    /// Interior vertices are stored at `2^shift` grid units (0 = full precision).
    pub shift: u32,
    /// The patch's texture: every corner's coordinates (three per triangle, in [0, 1]) and
    /// the atlas image (JPEG).
    pub texture: Option<(&'a [[f32; 2]], &'a [u8])>,
}

/// Quantised texture coordinate: `round(x × 65535)` of `x` clamped to [0, 1].
fn quantize_uv(uv: [f32; 2]) -> [u16; 2] {
    uv.map(|x| {
        let x = if x.is_finite() {
            x.clamp(0.0, 1.0)
        } else {
            0.0
        };
        (x * 65535.0 + 0.5) as u16
    })
}

/// Splits the vertices of a textured patch into one vertex per (vertex, texture coordinate):
/// new grid positions, colours, normals, ids, indices and coordinates.
#[allow(clippy::type_complexity)]
fn split_wedges(
    patch: &PatchRef<'_>,
    corner_uvs: &[[f32; 2]],
) -> (
    Vec<[u32; 3]>,
    Option<Vec<[u8; 4]>>,
    Option<Vec<[f32; 3]>>,
    Vec<u32>,
    Vec<u32>,
    Vec<[u16; 2]>,
) {
    // Each vertex's wedges as a chain: its latest wedge, and per wedge the one before it (a
    // vertex has one wedge but on a seam: a walk of one or two, where a hash map of
    // (vertex, coordinate) costs a hash a corner).
    const NONE: u32 = u32::MAX;
    let mut latest = vec![NONE; patch.grid_positions.len()];
    let mut before: Vec<u32> = Vec::new();
    let mut from: Vec<u32> = Vec::new();
    let mut uvs: Vec<[u16; 2]> = Vec::new();
    let indices: Vec<u32> = patch
        .indices
        .iter()
        .enumerate()
        .map(|(c, &v)| {
            let q = quantize_uv(corner_uvs.get(c).copied().unwrap_or([0.0; 2]));
            let head = latest.get(v as usize).copied().unwrap_or(NONE);
            let mut w = head;
            while w != NONE && uvs[w as usize] != q {
                w = before[w as usize];
            }
            if w == NONE {
                w = from.len() as u32;
                from.push(v);
                uvs.push(q);
                before.push(head);
                if let Some(l) = latest.get_mut(v as usize) {
                    *l = w;
                }
            }
            w
        })
        .collect();
    let pick = |v: &u32| *v as usize;
    (
        from.iter().map(|v| patch.grid_positions[pick(v)]).collect(),
        patch
            .colors
            .map(|c| from.iter().map(|v| c[pick(v)]).collect()),
        patch
            .normals
            .map(|n| from.iter().map(|v| n[pick(v)]).collect()),
        from.iter().map(|v| patch.original_ids[pick(v)]).collect(),
        indices,
        uvs,
    )
}

/// Whether a vertex stored more than once (`ids`: one per stored vertex) has a copy off the
/// `border` (the rule decoders apply, [`border_vertices`]).
fn copies_off_the_border(ids: &[u32], border: &[bool]) -> bool {
    let mut copies: HashMap<u32, u32> = HashMap::default();
    for &id in ids {
        *copies.entry(id).or_default() += 1;
    }
    ids.iter()
        .zip(border)
        .any(|(id, &on_border)| !on_border && copies.get(id).is_some_and(|&n| n > 1))
}

/// Why a blob does not decode.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CodecError {
    #[error("bad blob magic")]
    Magic,
    #[error("blob truncated")]
    Truncated,
    #[error("unknown compression {0}")]
    Compression(u8),
    #[error("decompression failed: {0}")]
    Zstd(String),
    #[error("stream {0} does not decode")]
    Stream(&'static str),
    #[error("patch declares implausible sizes")]
    Sizes,
    #[error("patch declares unknown flags {0:#x}")]
    Flags(u32),
}

/// Vertices on an edge used by exactly one triangle (the patch border).
pub fn border_vertices(indices: &[u32], vertex_count: usize) -> Vec<bool> {
    let mut border = vec![false; vertex_count];
    let edges = EdgeUses::of(indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
    for key in edges.border() {
        let (a, b) = edge_ends(key);
        if (a as usize) < vertex_count && (b as usize) < vertex_count {
            border[a as usize] = true;
            border[b as usize] = true;
        }
    }
    border
}

/// The parallelogram predictor shared by encoder and decoder. Values are predicted in the
/// order triangles introduce vertices; `value(v)` must return already-known values.
struct Predictor {
    known: Vec<bool>,
    opposite: HashMap<u64, u32>,
    last: Option<u32>,
}

impl Predictor {
    fn new(n: usize) -> Self {
        Predictor {
            known: vec![false; n],
            opposite: HashMap::with_capacity_and_hasher(n * 3, Default::default()),
            last: None,
        }
    }

    fn key(a: u32, b: u32) -> u64 {
        ((a.min(b) as u64) << 32) | a.max(b) as u64
    }

    /// Visits every vertex once, in first-use order, with its prediction.
    fn walk(
        indices: &[u32],
        n: usize,
        mut visit: impl FnMut(u32, Prediction) -> Result<(), CodecError>,
    ) -> Result<(), CodecError> {
        let mut p = Predictor::new(n);
        for t in indices.chunks_exact(3) {
            for k in 0..3 {
                let v = t[k];
                if p.known[v as usize] {
                    continue;
                }
                let (a, b) = (t[(k + 1) % 3], t[(k + 2) % 3]);
                let (ka, kb) = (p.known[a as usize], p.known[b as usize]);
                let prediction = if ka && kb {
                    match p.opposite.get(&Self::key(a, b)) {
                        Some(&c) => Prediction::Parallelogram(a, b, c),
                        None => Prediction::Midpoint(a, b),
                    }
                } else if ka {
                    Prediction::Copy(a)
                } else if kb {
                    Prediction::Copy(b)
                } else {
                    match p.last {
                        Some(l) => Prediction::Copy(l),
                        None => Prediction::Zero,
                    }
                };
                visit(v, prediction)?;
                p.known[v as usize] = true;
                p.last = Some(v);
            }
            for k in 0..3 {
                p.opposite
                    .entry(Self::key(t[k], t[(k + 1) % 3]))
                    .or_insert(t[(k + 2) % 3]);
            }
        }
        Ok(())
    }
}

fn put_varint(out: &mut Vec<u8>, value: i64) {
    let mut z = ((value << 1) ^ (value >> 63)) as u64;
    loop {
        let byte = (z & 0x7f) as u8;
        z >>= 7;
        if z == 0 {
            out.push(byte);
            return;
        }
        out.push(byte | 0x80);
    }
}

fn get_varint(bytes: &[u8], at: &mut usize) -> Result<i64, CodecError> {
    let mut z = 0u64;
    for shift in (0..64).step_by(7) {
        let byte = *bytes.get(*at).ok_or(CodecError::Stream("varint"))?;
        *at += 1;
        z |= ((byte & 0x7f) as u64) << shift;
        if byte & 0x80 == 0 {
            return Ok(((z >> 1) as i64) ^ -((z & 1) as i64));
        }
    }
    Err(CodecError::Stream("varint"))
}

/// Encodes a patch. Reorders vertices and triangles for cache efficiency and compression,
/// which changes nothing a reader relies on: every vertex keeps its original ID.
pub fn encode(patch: &PatchRef<'_>, zstd_level: i32) -> Vec<u8> {
    encode_counted(patch, zstd_level).0
}

/// The layout a blob is written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Layout {
    /// `MWP3`: front-coded connectivity, range-coded residuals (what the build writes).
    #[default]
    Front,
    /// `MWP2`: meshoptimizer's index codec, varint residuals (files built before `MWP3`;
    /// `bench build` prints its size beside the current one).
    Meshopt,
}

/// [`encode`], with the number of vertices the blob holds (more than the patch's where its
/// texture's charts meet: its decoded vertex count).
pub fn encode_counted(patch: &PatchRef<'_>, zstd_level: i32) -> (Vec<u8>, usize) {
    encode_layout(patch, zstd_level, Layout::Front)
}

/// [`encode_counted`], with which of the patch's vertices lie on its border (an edge of one
/// triangle), which the encoder finds anyway; `None` for a textured patch (it encodes one
/// vertex per texture coordinate, whose chart seams are borders too).
pub fn encode_with_border(
    patch: &PatchRef<'_>,
    zstd_level: i32,
) -> (Vec<u8>, usize, Option<Vec<bool>>) {
    if patch.texture.is_some() {
        let (blob, used) = encode_layout(patch, zstd_level, Layout::Front);
        return (blob, used, None);
    }
    let (blob, used, border) = encode_split(patch, None, zstd_level, Layout::Front);
    (blob, used, Some(border))
}

/// [`encode_counted`] in a chosen layout.
pub fn encode_layout(patch: &PatchRef<'_>, zstd_level: i32, layout: Layout) -> (Vec<u8>, usize) {
    let Some((corner_uvs, image)) = patch.texture else {
        let (blob, used, _) = encode_split(patch, None, zstd_level, layout);
        return (blob, used);
    };
    let (grid, colors, normals, ids, indices, uvs) = split_wedges(patch, corner_uvs);
    let (blob, used, _) = encode_split(
        &PatchRef {
            grid_positions: &grid,
            colors: colors.as_deref(),
            normals: normals.as_deref(),
            original_ids: &ids,
            indices: &indices,
            shift: patch.shift,
            texture: None,
        },
        Some((&uvs, image)),
        zstd_level,
        layout,
    );
    (blob, used)
}

/// Residual channels of `MWP3` (`docs/FORMAT.md` "Range coding"): positions by axis, by
/// full or interior precision and by parallelogram or other prediction; ids by prediction;
/// normals by octahedral component.
const POSITION_CHANNELS: usize = 16;
const ID_CHANNELS: usize = 2;
const NORMAL_CHANNELS: usize = 2;
const COLOUR_CHANNELS: usize = 4;

fn position_channel(axis: usize, interior: bool, prediction: &Prediction) -> usize {
    let parallelogram = matches!(prediction, Prediction::Parallelogram(..));
    axis + 3 * interior as usize + 6 * parallelogram as usize
}

/// The axis closest to the normal of a parallelogram prediction's triangle `(a, b, c)`
/// (`MWP3`): the surface is smooth across the gate, so the residual along it is the small
/// one, and it gets its own channel. `None` for other predictions.
fn normal_axis(pos: &[[i64; 3]], prediction: &Prediction) -> Option<usize> {
    let Prediction::Parallelogram(a, b, c) = *prediction else {
        return None;
    };
    let [a, b, c] = [a, b, c].map(|v| pos[v as usize].map(|x| x as f64));
    let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let w = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let n = [
        (u[1] * w[2] - u[2] * w[1]).abs(),
        (u[2] * w[0] - u[0] * w[2]).abs(),
        (u[0] * w[1] - u[1] * w[0]).abs(),
    ];
    Some(if n[0] >= n[1] && n[0] >= n[2] {
        0
    } else if n[1] >= n[2] {
        1
    } else {
        2
    })
}

/// The four bytes of a filtered colour as `MWP3` predicts them: luma and alpha unsigned,
/// the chroma bytes signed (so a grey's chroma is near 0, not near 0 and 255).
fn colour_values(f: [u8; 4]) -> [i64; 4] {
    [
        f[0] as i64,
        f[1] as i8 as i64,
        f[2] as i8 as i64,
        f[3] as i64,
    ]
}

/// The bytes of [`colour_values`]; `None` out of range (a damaged blob).
fn colour_bytes(x: [i64; 4]) -> Option<[u8; 4]> {
    let u = |v: i64| u8::try_from(v).ok();
    let s = |v: i64| i8::try_from(v).ok().map(|b| b as u8);
    Some([u(x[0])?, s(x[1])?, s(x[2])?, u(x[3])?])
}

/// A vertex's position prediction and the axis of its normal (`MWP3`: the multi-way
/// parallelogram, the normal of the first parallelogram's triangle; `MWP2`: the walk's).
fn position_guess(
    multi: Option<&Parallelograms>,
    pos: &[[i64; 3]],
    v: usize,
    prediction: &Prediction,
) -> ([i64; 3], Option<usize>) {
    match multi {
        Some(m) => {
            let first = m
                .of_vertex(v)
                .first()
                .map(|&[x, y, o]| Prediction::Parallelogram(x, y, o))
                .unwrap_or(*prediction);
            (m.position(pos, v, prediction), normal_axis(pos, &first))
        }
        None => (predict(pos, prediction), None),
    }
}

/// A vertex's id prediction (`MWP3`: the multi-way median; `MWP2`: the walk's).
fn id_guess(
    multi: Option<&Parallelograms>,
    ids: &[[i64; 1]],
    v: usize,
    prediction: &Prediction,
) -> i64 {
    match multi {
        Some(m) => m.id(ids, v, prediction),
        None => predict(ids, prediction)[0],
    }
}

/// [`position_channel`] with the axes by role when the prediction gives a normal axis:
/// channel 0 of the block the normal axis, 1 the two others.
fn role_channel(
    axis: usize,
    interior: bool,
    prediction: &Prediction,
    normal: Option<usize>,
) -> usize {
    match normal {
        Some(n) => 12 + (axis != n) as usize + 2 * interior as usize,
        _ => position_channel(axis, interior, prediction),
    }
}

fn id_channel(prediction: &Prediction) -> usize {
    matches!(prediction, Prediction::Parallelogram(..)) as usize
}

/// Where residuals go: varints (`MWP2`) or the range coder (`MWP3`).
enum Sink {
    Varint(Vec<u8>),
    Range(rangecoder::Encoder, Vec<Channel>),
}

impl Sink {
    fn new(range: bool, channels: usize) -> Self {
        if range {
            Sink::Range(rangecoder::Encoder::new(), vec![Channel::new(); channels])
        } else {
            Sink::Varint(Vec::new())
        }
    }

    fn put(&mut self, channel: usize, value: i64) {
        match self {
            Sink::Varint(out) => put_varint(out, value),
            Sink::Range(enc, channels) => channels[channel].put(enc, value),
        }
    }

    fn finish(self) -> Vec<u8> {
        match self {
            Sink::Varint(out) => out,
            Sink::Range(enc, _) => enc.finish(),
        }
    }
}

/// Where residuals come from, mirroring [`Sink`].
enum Source<'a> {
    Varint(&'a [u8], usize),
    Range(rangecoder::Decoder<'a>, Vec<Channel>),
}

impl<'a> Source<'a> {
    fn new(range: bool, bytes: &'a [u8], channels: usize) -> Self {
        if range {
            Source::Range(
                rangecoder::Decoder::new(bytes),
                vec![Channel::new(); channels],
            )
        } else {
            Source::Varint(bytes, 0)
        }
    }

    fn get(&mut self, channel: usize, stream: &'static str) -> Result<i64, CodecError> {
        match self {
            Source::Varint(bytes, at) => get_varint(bytes, at),
            Source::Range(dec, channels) => channels[channel]
                .get(dec)
                .filter(|_| !dec.overrun())
                .ok_or(CodecError::Stream(stream)),
        }
    }
}

/// An estimate of what residuals cost in a range-coded stream: the bit lengths of their
/// zigzag codes, plus one each for the length.
fn residual_bits(residuals: impl Iterator<Item = i64>) -> u64 {
    residuals
        .map(|r| {
            let z = ((r << 1) ^ (r >> 63)) as u64;
            1 + (u64::BITS - z.leading_zeros()) as u64
        })
        .sum()
}

/// A patch's vertices in the Morton order of their grid points, ties by vertex
/// (`vertex_order::morton_cmp`). With the scan's ids in Morton order of the same grid (header
/// flag bit 4) a full-precision patch lists its ids ascending this way, so the sorted ids code
/// only the gaps between them: on the scans about 1 bit a vertex against 6-7 predicted along
/// the traversal. Quantised interiors of coarse patches break the order here and there, which
/// costs a larger gap; the encoder keeps whichever stream is shorter.
///
/// The points of a patch share the high bits of their coordinates: where the bits in which
/// they differ fit [`super::build::MORTON_BITS`] an axis (every leaf, and coarse patches up to
/// 2²¹ grid steps across), those alone are interleaved into a 64-bit code, which orders them
/// as the comparison does (equal high bits decide nothing), and the codes are sorted instead
/// of comparing coordinates (the comparison sort was 1.8% of the 5M relief's build).
fn morton_sequence(points: &[[u32; 3]]) -> Vec<u32> {
    let Some(first) = points.first() else {
        return Vec::new();
    };
    let differ = points.iter().fold(0u32, |d, p| {
        d | (p[0] ^ first[0]) | (p[1] ^ first[1]) | (p[2] ^ first[2])
    });
    let bits = u32::BITS - differ.leading_zeros();
    if bits <= super::build::MORTON_BITS {
        let mask = (1u32 << bits) - 1;
        let mut keyed: Vec<(u64, u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (super::build::morton3(p.map(|c| c & mask)), i as u32))
            .collect();
        keyed.sort_unstable();
        return keyed.into_iter().map(|(_, i)| i).collect();
    }
    let mut sequence: Vec<u32> = (0..points.len() as u32).collect();
    sequence.sort_unstable_by(|&a, &b| {
        super::vertex_order::morton_cmp((points[a as usize], a), (points[b as usize], b))
    });
    sequence
}

/// [`encode`] of a patch whose vertices are already one per texture coordinate (`uvs[v]`);
/// with the blob's vertex count and which of the patch's vertices are on its border.
fn encode_split(
    patch: &PatchRef<'_>,
    texture: Option<(&[[u16; 2]], &[u8])>,
    zstd_level: i32,
    layout: Layout,
) -> (Vec<u8>, usize, Vec<bool>) {
    let vertex_count = patch.grid_positions.len();
    let front = match layout {
        Layout::Front => frontcoder::encode(patch.indices, vertex_count),
        Layout::Meshopt => None,
    };
    let v3 = front.is_some();
    // The new vertex order (`order[new] = old`), the triangles on it, each vertex's prediction
    // and the connectivity stream.
    let (indices, order, predictions, index_stream) = match front {
        Some(f) => (f.indices, f.order, f.predictions, f.bytes),
        None => {
            let mut indices = meshopt::optimize_vertex_cache(patch.indices, vertex_count);
            let remap = meshopt::optimize_vertex_fetch_remap(&indices, vertex_count);
            let used = remap.iter().filter(|&&r| r != u32::MAX).count();
            for i in &mut indices {
                *i = remap[*i as usize];
            }
            let mut order = vec![0u32; used];
            for (old, &new) in remap.iter().enumerate() {
                if new != u32::MAX {
                    order[new as usize] = old as u32;
                }
            }
            // First-use order: the walk visits the vertices as 0, 1, 2, ...
            let mut predictions = vec![Prediction::Zero; used];
            let _ = Predictor::walk(&indices, used, |v, prediction| {
                predictions[v as usize] = prediction;
                Ok(())
            });
            let stream = encode_index_buffer(&indices, used).unwrap_or_default();
            (indices, order, predictions, stream)
        }
    };
    let used = order.len();
    let pick = |o: &u32| *o as usize;
    let grid: Vec<[u32; 3]> = order
        .iter()
        .map(|o| patch.grid_positions[pick(o)])
        .collect();
    let ids: Vec<u32> = order.iter().map(|o| patch.original_ids[pick(o)]).collect();
    let colors: Option<Vec<[f32; 4]>> = patch.colors.map(|src| {
        order
            .iter()
            .map(|o| src[pick(o)].map(|c| c as f32 / 255.0))
            .collect()
    });
    let normals: Option<Vec<[f32; 3]>> = patch
        .normals
        .map(|src| order.iter().map(|o| src[pick(o)]).collect());
    let uvs: Option<Vec<[u16; 2]>> =
        texture.map(|(src, _)| order.iter().map(|o| src[pick(o)]).collect());
    let min = if used == 0 {
        [0; 3]
    } else {
        grid.iter().fold([u32::MAX; 3], |m, g| {
            [m[0].min(g[0]), m[1].min(g[1]), m[2].min(g[2])]
        })
    };
    let shift = patch.shift.min(MAX_SHIFT);
    let multi = v3.then(|| Parallelograms::of(&indices, used));
    let walked_border;
    let border: &[bool] = match &multi {
        Some(m) => &m.border,
        None => {
            walked_border = border_vertices(&indices, used);
            &walked_border
        }
    };
    // Copies of one vertex (a textured patch stores one per chart) must decode to one point.
    // They sit on chart-border edges, which the border keeps at full precision, except where
    // the patch is not manifold at the vertex (fans that touch at one point): there one copy
    // can be interior, quantised to `2^shift`, while another is exact. Such a patch is stored
    // at full precision. (Untextured patches store every vertex once.)
    let shift = if shift > 0 && texture.is_some() && copies_off_the_border(&ids, border) {
        0
    } else {
        shift
    };

    // Positions (relative to the patch minimum) and ids, each from its prediction.
    let mut decoded_pos: Vec<[i64; 3]> = vec![[0; 3]; used];
    let mut id_values: Vec<[i64; 1]> = vec![[0]; used];
    let mut pos_sink = Sink::new(v3, POSITION_CHANNELS);
    let mut id_residuals: Vec<(usize, i64)> = Vec::with_capacity(used);

    for v in 0..used {
        let prediction = predictions[v];
        let actual: [i64; 3] = std::array::from_fn(|k| (grid[v][k] - min[k]) as i64);
        let (guess, normal) = position_guess(multi.as_ref(), &decoded_pos, v, &prediction);
        if border[v] || shift == 0 {
            for k in 0..3 {
                pos_sink.put(
                    role_channel(k, false, &prediction, normal),
                    actual[k] - guess[k],
                );
            }
            decoded_pos[v] = actual;
        } else {
            let half = 1i64 << (shift - 1);
            for k in 0..3 {
                let q = (actual[k] + half) >> shift;
                pos_sink.put(
                    role_channel(k, true, &prediction, normal),
                    q - (guess[k] >> shift),
                );
                decoded_pos[v][k] = q << shift;
            }
        }
        let id_guess = id_guess(multi.as_ref(), &id_values, v, &prediction);
        id_residuals.push((id_channel(&prediction), ids[v] as i64 - id_guess));
        id_values[v] = [ids[v] as i64];
    }
    let pos_stream = pos_sink.finish();
    // Ids predicted along the traversal, or (`MWP3`) sorted in the Morton order of the decoded
    // points as gaps: whichever is shorter. Both are coded only where their residuals' bit
    // lengths ([`residual_bits`]) come within a tenth of each other; elsewhere that estimate
    // names the shorter one. (The gaps are the shorter on every patch of the 5M relief: 4.8x
    // on the leaves, 1.3-2x above; the scans in `../shared/data` build to the same bytes.)
    let predicted = || {
        let mut sink = Sink::new(v3, ID_CHANNELS);
        for &(channel, r) in &id_residuals {
            sink.put(channel, r);
        }
        sink.finish()
    };
    let (id_stream, sorted) = if v3 {
        let points: Vec<[u32; 3]> = decoded_pos
            .iter()
            .map(|p| std::array::from_fn(|k| (p[k] + min[k] as i64) as u32))
            .collect();
        let mut previous = -1i64;
        let gaps: Vec<i64> = morton_sequence(&points)
            .into_iter()
            .map(|v| {
                let id = ids[v as usize] as i64;
                let gap = id - previous - 1;
                previous = id;
                gap
            })
            .collect();
        let gapped = || {
            let mut sink = Sink::new(true, 1);
            for &g in &gaps {
                sink.put(0, g);
            }
            sink.finish()
        };
        let as_predicted = residual_bits(id_residuals.iter().map(|r| r.1));
        let as_gaps = residual_bits(gaps.iter().copied());
        if as_gaps * 10 < as_predicted * 9 {
            (gapped(), true)
        } else if as_predicted * 10 < as_gaps * 9 {
            (predicted(), false)
        } else {
            let (a, b) = (predicted(), gapped());
            if b.len() < a.len() {
                (b, true)
            } else {
                (a, false)
            }
        }
    } else {
        (predicted(), false)
    };

    let color_stream = colors
        .as_ref()
        .map(|c| {
            let filtered: Vec<[u8; 4]> = meshopt::encode_filter_color(c, COLOR_BITS);
            match multi.as_ref() {
                Some(m) => {
                    let values: Vec<[i64; 4]> =
                        filtered.iter().map(|&f| colour_values(f)).collect();
                    let mut sink = Sink::new(true, COLOUR_CHANNELS);
                    for v in 0..used {
                        let guess = m.colour(&values, v, &predictions[v]);
                        for k in 0..4 {
                            sink.put(k, values[v][k] - guess[k]);
                        }
                    }
                    sink.finish()
                }
                None => encode_vertex_buffer(&filtered).unwrap_or_default(),
            }
        })
        .unwrap_or_default();
    let mut normal_stream = Vec::new();
    // Copies of a vertex (textured patches) have one scan normal: stored once.
    let normals_by_id = texture.is_some() && normals.is_some();
    if let Some(n) = normals.as_ref() {
        let predicted = grid_normals_of(&decoded_pos, &indices, Some(border));
        let mut sink = Sink::new(v3, NORMAL_CHANNELS);
        let mut stored: HashSet<u32> = HashSet::default();
        for v in (0..used).filter(|&v| border[v]) {
            if normals_by_id && !stored.insert(ids[v]) {
                continue;
            }
            let actual = oct_encode(n[v].map(|x| x as f64));
            let guess = oct_encode(predicted[v]);
            sink.put(0, actual[0] - guess[0]);
            sink.put(1, actual[1] - guess[1]);
        }
        normal_stream = sink.finish();
    }

    // Texture coordinates: one map per chart where every chart is a projection (the build's
    // atlases), else per vertex.
    let maps = uvs.as_ref().and_then(|u| {
        let exact: Vec<[i64; 3]> = grid
            .iter()
            .map(|g| std::array::from_fn(|k| (g[k] - min[k]) as i64))
            .collect();
        let targets: Vec<[f64; 2]> = u.iter().map(|q| q.map(|x| x as f64 / 65535.0)).collect();
        chart_uv::fit(&indices, &exact, &decoded_pos, shift, &targets)
    });
    let uv_stream = match (&maps, &uvs) {
        (Some(maps), _) => {
            let mut out = Vec::with_capacity(4 + maps.len() * 32);
            out.extend_from_slice(&(maps.len() as u32).to_le_bytes());
            for c in maps.iter().flatten() {
                out.extend_from_slice(&c.to_le_bytes());
            }
            out
        }
        (None, Some(u)) => encode_vertex_buffer(u).unwrap_or_default(),
        (None, None) => Vec::new(),
    };

    let mut flags = 0;
    if colors.is_some() {
        flags |= FLAG_COLORS;
    }
    if uvs.is_some() {
        flags |= FLAG_UVS;
    }
    if maps.is_some() {
        flags |= FLAG_CHART_UVS;
    }
    if normals_by_id {
        flags |= FLAG_NORMALS_BY_ID;
    }

    if normals.is_some() {
        flags |= FLAG_NORMALS;
    }
    if sorted {
        flags |= FLAG_SORTED_IDS;
    }
    let streams = [
        &index_stream,
        &pos_stream,
        &id_stream,
        &color_stream,
        &normal_stream,
        &uv_stream,
    ];
    let mut payload =
        Vec::with_capacity(PAYLOAD_HEADER + streams.iter().map(|s| s.len()).sum::<usize>());
    for v in [
        used as u32,
        (indices.len() / 3) as u32,
        flags,
        shift,
        min[0],
        min[1],
        min[2],
    ] {
        payload.extend_from_slice(&v.to_le_bytes());
    }
    for s in &streams {
        payload.extend_from_slice(&(s.len() as u32).to_le_bytes());
    }
    for s in &streams {
        payload.extend_from_slice(s);
    }

    // Range-coded streams alone leave zstd nothing to find (no `MWP3` blob of the dragon,
    // igea, the gargoyle or the 5M relief gained), so only payloads with meshoptimizer's
    // streams (`MWP2`, texture coordinates) try it: 2-3% of a build's CPU time otherwise.
    let try_zstd = zstd_level > 0 && (!v3 || (uvs.is_some() && maps.is_none()));
    let (compression, body) = match try_zstd.then(|| zstd::bulk::compress(&payload, zstd_level)) {
        Some(Ok(c)) if c.len() < payload.len() => (COMPRESSION_ZSTD, c),
        _ => (COMPRESSION_NONE, payload.clone()),
    };
    let image = texture.map(|(_, image)| image);
    let mut blob = Vec::with_capacity(16 + image.map_or(0, |i| i.len()) + body.len());
    blob.extend_from_slice(if v3 { &BLOB_MAGIC } else { &BLOB_MAGIC_V2 });
    blob.extend_from_slice(&[compression, 0, 0, 0]);
    blob.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    push_sections(&mut blob, image, None);
    blob.extend_from_slice(&body);
    if v3 && !connectivity_reads_back(&index_stream, &indices, &predictions) {
        // Never seen: the front coder and its decoder mirror each other, and tests hold them
        // to it on real scans; should a patch's connectivity ever not read back, the older
        // layout keeps it. The residual streams follow from it: once the decoder has the same
        // triangles and predictions, it makes the same guesses (the same functions on the same
        // decoded values) and the range coder returns the residuals put in. Builds with debug
        // assertions (the tests) still decode every whole patch back and compare.
        tracing::warn!(
            triangles = indices.len() / 3,
            "patch does not decode back in the MWP3 layout; written as MWP2"
        );
        return encode_split(patch, texture, zstd_level, Layout::Meshopt);
    }
    debug_assert!(
        !v3 || decodes_back(&blob, &indices, &decoded_pos, min, &ids),
        "an MWP3 patch whose connectivity reads back does not decode back whole"
    );
    let mut patch_border = vec![false; patch.grid_positions.len()];
    for (&old, &on) in order.iter().zip(border) {
        if on {
            patch_border[old as usize] = true;
        }
    }
    (blob, used, patch_border)
}

/// Appends the image sections to a blob header (12 bytes, flags at byte 5 set here). A WebP
/// colour atlas is stored whole ([`BLOB_IMAGE_WEBP`]). The JPEG sections go without their
/// Huffman tables where every one has the standard ones, and also without their JFIF segment
/// and quantisation tables where every one has the standard ones ([`super::jpegtables`]);
/// whole otherwise. An image is at most [`super::atlas::MAX_SIDE`]² texels: far below 4 GiB.
fn push_sections(blob: &mut Vec<u8>, image: Option<&[u8]>, normals: Option<&[u8]>) {
    let webp = image.is_some_and(crate::mesh::is_webp);
    // The sections the JPEG flags speak of.
    let jpegs = [image.filter(|_| !webp), normals];
    let huffman = jpegs.map(|i| i.and_then(jpegtables::strip_standard_huffman));
    let headers = huffman
        .each_ref()
        .map(|i| i.as_deref().and_then(jpegtables::strip_headers));
    let all = |stripped: &[Option<Vec<u8>>; 2]| {
        jpegs.iter().any(Option::is_some)
            && jpegs
                .iter()
                .zip(stripped)
                .all(|(p, s)| p.is_none() || s.is_some())
    };
    let (flags, stripped) = if all(&headers) {
        (
            BLOB_STANDARD_HUFFMAN | BLOB_STANDARD_HEADERS,
            Some(&headers),
        )
    } else if all(&huffman) {
        (BLOB_STANDARD_HUFFMAN, Some(&huffman))
    } else {
        (0, None)
    };
    blob[5] = flags;
    if webp {
        blob[5] |= BLOB_IMAGE_WEBP;
    }
    for (k, (flag, whole)) in [(BLOB_IMAGE, image), (BLOB_NORMALS, normals)]
        .into_iter()
        .enumerate()
    {
        if let Some(whole) = whole {
            let bytes = match stripped.and_then(|s| s[k].as_deref()) {
                Some(s) => s,
                None => whole,
            };
            blob[5] |= flag;
            blob.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
            blob.extend_from_slice(bytes);
        }
    }
}

/// The image sections of a blob (colour, normal map) and where its body starts.
type Sections<'a> = (Option<&'a [u8]>, Option<&'a [u8]>, usize);

fn sections(blob: &[u8]) -> Result<Sections<'_>, CodecError> {
    let mut at = 12usize;
    let mut section = |flag: u8| -> Result<Option<&[u8]>, CodecError> {
        if blob.get(5).is_none_or(|f| f & flag == 0) {
            return Ok(None);
        }
        let len = u32_at(blob, at)? as usize;
        let start = at + 4;
        let end = start.checked_add(len).ok_or(CodecError::Truncated)?;
        let bytes = blob.get(start..end).ok_or(CodecError::Truncated)?;
        at = end;
        Ok(Some(bytes))
    };
    let image = section(BLOB_IMAGE)?;
    let normals = section(BLOB_NORMALS)?;
    Ok((image, normals, at))
}

/// Whether a blob's JPEG sections are stored without their (standard) Huffman tables.
pub fn images_without_tables(blob: &[u8]) -> bool {
    blob.get(5).is_some_and(|f| f & BLOB_STANDARD_HUFFMAN != 0)
}

/// Whether `blob`'s JPEG sections are also stored without their JFIF segment and
/// quantisation tables ([`jpegtables::strip_headers`]).
pub fn images_without_headers(blob: &[u8]) -> bool {
    blob.get(5).is_some_and(|f| f & BLOB_STANDARD_HEADERS != 0)
}

/// Whether `blob`'s image section (the colour atlas) is a WebP, stored whole.
pub fn image_is_webp(blob: &[u8]) -> bool {
    blob.get(5).is_some_and(|f| f & BLOB_IMAGE_WEBP != 0)
}

/// Bytes of `blob`'s image section as stored (0 where it has none).
pub fn stored_image_len(blob: &[u8]) -> usize {
    match blob.get(5) {
        Some(f) if f & BLOB_IMAGE != 0 => u32_at(blob, 12).map_or(0, |l| l as usize),
        _ => 0,
    }
}

/// `blob` with its image sections holding `image` (the colour atlas) and `normals` (the normal
/// map), each present or not: the build encodes a textured patch before its atlas' quality is
/// known and puts the JPEGs in when writing ([`super::fragment_quality`]).
pub fn with_images(
    blob: &[u8],
    image: Option<&[u8]>,
    normals: Option<&[u8]>,
) -> Result<Vec<u8>, CodecError> {
    if blob.len() < 12 {
        return Err(CodecError::Truncated);
    }
    let (_, _, body) = sections(blob)?;
    let mut out = Vec::with_capacity(
        blob.len() + 8 + image.map_or(0, <[u8]>::len) + normals.map_or(0, <[u8]>::len),
    );
    out.extend_from_slice(&blob[..12]);
    push_sections(&mut out, image, normals);
    out.extend_from_slice(&blob[body..]);
    Ok(out)
}

/// Whether an `MWP3` connectivity stream decodes to the triangles and vertex predictions it
/// was made from (what the build checks of every patch it writes).
fn connectivity_reads_back(stream: &[u8], indices: &[u32], predictions: &[Prediction]) -> bool {
    frontcoder::decode(stream, predictions.len(), indices.len() / 3)
        .is_ok_and(|(i, p)| i == indices && p == predictions)
}

/// Whether `blob` decodes to the triangles, grid positions (relative to `min`) and ids the
/// encoder meant (builds with debug assertions check it of every `MWP3` patch).
fn decodes_back(
    blob: &[u8],
    indices: &[u32],
    pos: &[[i64; 3]],
    min: [u32; 3],
    ids: &[u32],
) -> bool {
    let unit = Grid {
        origin: [0.0; 3],
        step: 1.0,
    };
    decode(blob, &unit).is_ok_and(|p| {
        p.indices == indices
            && p.original_ids == ids
            && p.grid_positions.len() == pos.len()
            && p.grid_positions
                .iter()
                .zip(pos)
                .all(|(g, q)| (0..3).all(|k| g[k] as i64 == q[k] + min[k] as i64))
    })
}

fn u32_at(bytes: &[u8], at: usize) -> Result<u32, CodecError> {
    bytes
        .get(at..at + 4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .ok_or(CodecError::Truncated)
}

/// Most payload bytes a patch of `max_triangles` triangles can take: per triangle at most 16
/// bytes of encoded indices, per vertex (at most three per triangle) at most 96 bytes of
/// positions, ids, colour and normal (varints are at most 10 bytes).
pub fn payload_bound(max_triangles: u32) -> usize {
    let t = max_triangles as usize;
    PAYLOAD_HEADER + 16 * t + 3 * t * 96 + 4096
}

/// Names of a payload's streams, in their order (`docs/FORMAT.md`).
pub const STREAM_NAMES: [&str; 6] = ["indices", "positions", "ids", "colours", "normals", "uvs"];

/// Where one blob's bytes go (`bench build`'s breakdown of the format).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BlobBytes {
    /// The whole blob as stored.
    pub stored: usize,
    /// Blob header (magic, compression, payload length, image length).
    pub header: usize,
    /// The texture atlas image (JPEG), stored as is.
    pub image: usize,
    /// The normal map (JPEG), stored as is.
    pub normal_map: usize,
    /// The payload's own header (counts, flags, grid minimum, stream lengths).
    pub payload_header: usize,
    /// Each stream before compression, in [`STREAM_NAMES`] order.
    pub streams: [usize; 6],
    /// The compressed body (payload header and streams together, zstd).
    pub body: usize,
}

/// The parts of a blob's framing: its image section and its body, with the payload the body
/// decompresses to.
struct Framed<'a> {
    /// `MWP3` (else `MWP2`).
    v3: bool,
    image: Option<&'a [u8]>,
    normals: Option<&'a [u8]>,
    /// Bytes before the body: header and sections.
    head: usize,
    body: &'a [u8],
    payload: Vec<u8>,
}

/// Checks a blob's framing and decompresses its payload, refusing a payload declared larger
/// than `max_payload` bytes before anything is allocated.
fn unframe(blob: &[u8], max_payload: usize) -> Result<Framed<'_>, CodecError> {
    if blob.len() < 12 {
        return Err(CodecError::Truncated);
    }
    let v3 = match &blob[..4] {
        m if m == BLOB_MAGIC => true,
        m if m == BLOB_MAGIC_V2 => false,
        _ => return Err(CodecError::Magic),
    };
    let payload_len = u32_at(blob, 8)? as usize;
    if payload_len > max_payload {
        return Err(CodecError::Sizes);
    }
    let (image, normals, head) = sections(blob)?;
    let body = &blob[head..];
    let payload = match blob[4] {
        COMPRESSION_NONE => body.to_vec(),
        COMPRESSION_ZSTD => zstd::bulk::decompress(body, payload_len)
            .map_err(|e| CodecError::Zstd(e.to_string()))?,
        other => return Err(CodecError::Compression(other)),
    };
    if payload.len() != payload_len || payload.len() < PAYLOAD_HEADER {
        return Err(CodecError::Truncated);
    }
    Ok(Framed {
        v3,
        image,
        normals,
        head,
        body,
        payload,
    })
}

/// Splits a blob into its parts without decoding its streams (the framing of `unframe`, as
/// [`decode_limited`] reads it).
pub fn blob_bytes(blob: &[u8]) -> Result<(BlobBytes, Vec<u8>), CodecError> {
    let framed = unframe(blob, 64 << 20)?;
    let image = framed.image.map_or(0, <[u8]>::len);
    let normal_map = framed.normals.map_or(0, <[u8]>::len);
    let header = framed.head - image - normal_map;
    let (body, payload) = (framed.body, framed.payload);
    let mut streams = [0usize; 6];
    for (i, l) in streams.iter_mut().enumerate() {
        *l = u32_at(&payload, 28 + 4 * i)? as usize;
    }
    if PAYLOAD_HEADER + streams.iter().sum::<usize>() != payload.len() {
        return Err(CodecError::Sizes);
    }
    Ok((
        BlobBytes {
            stored: blob.len(),
            header,
            image,
            normal_map,
            payload_header: PAYLOAD_HEADER,
            streams,
            body: body.len(),
        },
        payload,
    ))
}

/// Decodes a blob into world-space flat arrays.
pub fn decode(blob: &[u8], grid: &Grid) -> Result<Patch, CodecError> {
    decode_limited(blob, grid, MAX_ELEMENTS)
}

/// [`decode`] of a blob from a file whose patches have at most `max_triangles` triangles: every
/// size the blob declares is checked against that budget and against the bytes it holds
/// before anything is allocated, so a damaged (or hostile) blob costs at most a bounded amount
/// of memory (a few times [`payload_bound`]).
pub fn decode_limited(blob: &[u8], grid: &Grid, max_triangles: u32) -> Result<Patch, CodecError> {
    let max_triangles = max_triangles.min(MAX_ELEMENTS);
    let Framed {
        v3,
        image,
        normals: normal_map,
        payload,
        ..
    } = unframe(blob, (64 << 20).min(payload_bound(max_triangles)))?;
    // JPEGs stored without their (standard) tables and headers get them back.
    let whole = |i: &[u8]| {
        let i = if images_without_headers(blob) {
            jpegtables::with_headers(i)
        } else {
            i.to_vec()
        };
        if images_without_tables(blob) {
            jpegtables::with_standard_huffman(&i)
        } else {
            i
        }
    };
    let image = if image_is_webp(blob) {
        image.map(<[u8]>::to_vec)
    } else {
        image.map(whole)
    };
    let normal_map = normal_map.map(whole);
    let vertex_count = u32_at(&payload, 0)?;
    let triangle_count = u32_at(&payload, 4)?;
    let flags = u32_at(&payload, 8)?;
    let shift = u32_at(&payload, 12)?;
    let sorted = flags & FLAG_SORTED_IDS != 0;
    if flags & !KNOWN_FLAGS != 0
        || (sorted && !v3)
        || (flags & FLAG_CHART_UVS != 0 && flags & FLAG_UVS == 0)
        || (flags & FLAG_NORMALS_BY_ID != 0 && flags & FLAG_NORMALS == 0)
    {
        return Err(CodecError::Flags(flags));
    }
    if vertex_count > MAX_ELEMENTS
        || triangle_count > max_triangles
        || vertex_count > triangle_count.saturating_mul(3)
        || shift > MAX_SHIFT
    {
        return Err(CodecError::Sizes);
    }
    let min = [
        u32_at(&payload, 16)?,
        u32_at(&payload, 20)?,
        u32_at(&payload, 24)?,
    ];
    let mut lens = [0usize; 6];
    for (i, l) in lens.iter_mut().enumerate() {
        *l = u32_at(&payload, 28 + 4 * i)? as usize;
    }
    let mut at = PAYLOAD_HEADER;
    let mut next = |len: usize| -> Result<&[u8], CodecError> {
        let s = payload
            .get(at..at.checked_add(len).ok_or(CodecError::Truncated)?)
            .ok_or(CodecError::Truncated)?;
        at += len;
        Ok(s)
    };
    let (idx_s, pos_s, ids_s, col_s, nor_s, uv_s) = (
        next(lens[0])?,
        next(lens[1])?,
        next(lens[2])?,
        next(lens[3])?,
        next(lens[4])?,
        next(lens[5])?,
    );
    let n = vertex_count as usize;
    let t = triangle_count as usize;
    // Necessary for any valid blob, and what bounds the allocations below by the blob's own
    // bytes (`MWP2`: at least one code byte per triangle, one byte per varint; `MWP3`: the
    // range coder's five flush bytes per stream, and the declared sizes within the file's
    // triangle budget, checked above).
    let plausible = if v3 {
        (t == 0 || idx_s.len() >= 5) && (n == 0 || (pos_s.len() >= 5 && ids_s.len() >= 5))
    } else {
        t <= idx_s.len() && 3 * n <= pos_s.len() && n <= ids_s.len()
    };
    if !plausible {
        return Err(CodecError::Sizes);
    }

    // Each vertex with its prediction, in decoding order.
    let (indices, sequence): (Vec<u32>, Vec<(u32, Prediction)>) = if v3 {
        let (indices, predictions) =
            frontcoder::decode(idx_s, n, t).map_err(|_| CodecError::Stream("indices"))?;
        (indices, (0..n as u32).zip(predictions).collect())
    } else {
        let indices: Vec<u32> =
            decode_index_buffer(idx_s, t * 3).map_err(|_| CodecError::Stream("indices"))?;
        if indices.iter().any(|&i| i >= vertex_count) {
            return Err(CodecError::Stream("indices"));
        }
        let mut sequence = Vec::with_capacity(n);
        Predictor::walk(&indices, n, |v, prediction| {
            sequence.push((v, prediction));
            Ok(())
        })?;
        if sequence.len() != n {
            // Vertices no triangle uses cannot be predicted; valid blobs have none.
            return Err(CodecError::Stream("positions"));
        }
        (indices, sequence)
    };
    let multi = v3.then(|| Parallelograms::of(&indices, n));
    let walked_border;
    let border: &[bool] = match &multi {
        Some(m) => &m.border,
        None => {
            walked_border = border_vertices(&indices, n);
            &walked_border
        }
    };
    let mut pos: Vec<[i64; 3]> = vec![[0; 3]; n];
    let mut ids: Vec<[i64; 1]> = vec![[0]; n];
    let mut pos_src = Source::new(v3, pos_s, POSITION_CHANNELS);
    let mut ids_src = Source::new(v3, ids_s, ID_CHANNELS);

    for &(v, prediction) in &sequence {
        let v = v as usize;
        let (guess, normal) = position_guess(multi.as_ref(), &pos, v, &prediction);
        if border[v] || shift == 0 {
            for k in 0..3 {
                let r = pos_src.get(role_channel(k, false, &prediction, normal), "positions")?;
                pos[v][k] = guess[k].wrapping_add(r);
            }
        } else {
            for k in 0..3 {
                let r = pos_src.get(role_channel(k, true, &prediction, normal), "positions")?;
                pos[v][k] = (guess[k] >> shift).wrapping_add(r).wrapping_shl(shift);
            }
        }
        if !sorted {
            let id_guess = id_guess(multi.as_ref(), &ids, v, &prediction);
            let r = ids_src.get(id_channel(&prediction), "original ids")?;
            ids[v] = [id_guess.wrapping_add(r)];
        }
    }
    let mut grid_positions = Vec::with_capacity(n);
    for p in &pos {
        let g: [i64; 3] = std::array::from_fn(|k| p[k].wrapping_add(min[k] as i64));
        if g.iter().any(|&c| c < 0 || c > u32::MAX as i64) {
            return Err(CodecError::Stream("positions"));
        }
        grid_positions.push(g.map(|c| c as u32));
    }
    if sorted {
        let mut src = Source::new(true, ids_s, 1);
        let mut previous = -1i64;
        for v in morton_sequence(&grid_positions) {
            let r = src.get(0, "original ids")?;
            previous = previous.wrapping_add(1).wrapping_add(r);
            ids[v as usize] = [previous];
        }
    }
    let original_ids = ids
        .iter()
        .map(|i| u32::try_from(i[0]).map_err(|_| CodecError::Stream("original ids")))
        .collect::<Result<Vec<u32>, _>>()?;
    let positions: Vec<[f32; 3]> = grid_positions.iter().map(|&g| grid.dequantize(g)).collect();

    let colors = if flags & FLAG_COLORS != 0 {
        let mut c: Vec<[u8; 4]> = match multi.as_ref() {
            Some(m) => {
                let mut values: Vec<[i64; 4]> = vec![[0; 4]; n];
                let mut bytes: Vec<[u8; 4]> = vec![[0; 4]; n];
                let mut src = Source::new(true, col_s, COLOUR_CHANNELS);
                for &(v, prediction) in &sequence {
                    let v = v as usize;
                    let guess = m.colour(&values, v, &prediction);
                    for k in 0..4 {
                        values[v][k] = guess[k].wrapping_add(src.get(k, "colors")?);
                    }
                    bytes[v] = colour_bytes(values[v]).ok_or(CodecError::Stream("colors"))?;
                }
                bytes
            }
            None => decode_vertex_buffer(col_s, n).map_err(|_| CodecError::Stream("colors"))?,
        };
        decode_ycocg(&mut c);
        c
    } else {
        Vec::new()
    };
    let normals = if flags & FLAG_NORMALS != 0 {
        let predicted = grid_normals(&pos, &indices);
        let mut normals: Vec<[f32; 3]> = predicted.iter().map(|n| n.map(|x| x as f32)).collect();
        let mut src = Source::new(v3, nor_s, NORMAL_CHANNELS);
        let by_id = flags & FLAG_NORMALS_BY_ID != 0;
        let mut first: HashMap<u32, usize> = HashMap::default();
        for v in (0..n).filter(|&v| border[v]) {
            if by_id {
                let earlier = *first.entry(original_ids[v]).or_insert(v);
                if earlier != v {
                    normals[v] = normals[earlier];
                    continue;
                }
            }
            let guess = oct_encode(predicted[v]);
            let q = [
                guess[0].wrapping_add(src.get(0, "normals")?),
                guess[1].wrapping_add(src.get(1, "normals")?),
            ];
            normals[v] = oct_decode(q);
        }
        normals
    } else {
        Vec::new()
    };
    let uvs = if flags & FLAG_CHART_UVS != 0 {
        chart_uvs(uv_s, &indices, &pos)?
    } else if flags & FLAG_UVS != 0 {
        let q: Vec<[u16; 2]> =
            decode_vertex_buffer(uv_s, n).map_err(|_| CodecError::Stream("uvs"))?;
        q.iter().map(|q| q.map(|x| x as f32 / 65535.0)).collect()
    } else {
        Vec::new()
    };
    Ok(Patch {
        positions,
        colors,
        normals,
        original_ids,
        indices,
        shift,
        grid_positions,
        uvs,
        image,
        normal_map,
    })
}

/// Texture coordinates from a stream of chart maps (payload flag bit 4): a u32 count, then
/// eight little-endian f32 per chart ([`chart_uv`]). `pos`: decoded grid positions relative to
/// the patch minimum.
fn chart_uvs(
    stream: &[u8],
    indices: &[u32],
    pos: &[[i64; 3]],
) -> Result<Vec<[f32; 2]>, CodecError> {
    let bad = || CodecError::Stream("uvs");
    let count = u32_at(stream, 0).map_err(|_| bad())? as usize;
    if stream.len() != 4 + count.checked_mul(32).ok_or_else(bad)? {
        return Err(bad());
    }
    let maps: Vec<chart_uv::ChartMap> = stream[4..]
        .chunks_exact(32)
        .map(|c| {
            std::array::from_fn(|k| {
                f32::from_le_bytes([c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]])
            })
        })
        .collect();
    let (chart, charts) = chart_uv::charts(indices, pos.len());
    if charts != count {
        return Err(bad());
    }
    Ok(chart
        .iter()
        .zip(pos)
        .map(|(&c, &p)| {
            maps.get(c as usize)
                .map_or([0.0; 2], |m| chart_uv::evaluate(m, p))
        })
        .collect())
}

/// Area-weighted vertex normals of a triangle set in world space (unit length; +Z for
/// isolated vertices).
pub fn computed_normals(positions: &[[f32; 3]], indices: &[u32]) -> Vec<[f32; 3]> {
    let mut acc = vec![[0f32; 3]; positions.len()];
    for t in indices.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions[i as usize]);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let w = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            u[1] * w[2] - u[2] * w[1],
            u[2] * w[0] - u[0] * w[2],
            u[0] * w[1] - u[1] * w[0],
        ];
        for &i in t {
            for k in 0..3 {
                acc[i as usize][k] += n[k];
            }
        }
    }
    acc.iter()
        .map(|n| {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if len > 0.0 {
                [n[0] / len, n[1] / len, n[2] / len]
            } else {
                [0.0, 0.0, 1.0]
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The keyed Morton sort orders as the coordinate comparison does: points sharing high
    /// bits (a patch), points spread over the whole 2²⁴ grid (the comparison's own path),
    /// repeated points (ties by index) and points one step apart across a power of two.
    #[test]
    fn morton_sequence_orders_as_the_comparison() {
        let mut next = crate::testing::xorshift(0x2545_f491);
        let by_comparison = |points: &[[u32; 3]]| {
            let mut s: Vec<u32> = (0..points.len() as u32).collect();
            s.sort_by(|&a, &b| {
                super::super::vertex_order::morton_cmp(
                    (points[a as usize], a),
                    (points[b as usize], b),
                )
            });
            s
        };
        for (base, spread) in [
            (0x00ab_cdefu32, 1u32 << 6),
            (0x0040_0000, 1 << 12),
            (0x007f_fff0, 32),
            (0, 1 << 21),
            (0, 1 << 24),
        ] {
            let mut points: Vec<[u32; 3]> = (0..3000)
                .map(|_| std::array::from_fn(|_| base + next() % spread))
                .collect();
            points.extend_from_within(..200);
            assert_eq!(
                morton_sequence(&points),
                by_comparison(&points),
                "{base:x} {spread}"
            );
        }
        assert!(morton_sequence(&[]).is_empty());
        assert_eq!(morton_sequence(&[[7, 7, 7]; 3]), vec![0, 1, 2]);
    }

    /// `patch` encoded in each layout (`MWP3`, then `MWP2`), each blob's magic checked.
    fn in_both_layouts(patch: &PatchRef<'_>, zstd_level: i32) -> [Vec<u8>; 2] {
        [Layout::Front, Layout::Meshopt].map(|layout| {
            let (blob, _) = encode_layout(patch, zstd_level, layout);
            let magic = match layout {
                Layout::Front => BLOB_MAGIC,
                Layout::Meshopt => BLOB_MAGIC_V2,
            };
            assert_eq!(blob[..4], magic);
            blob
        })
    }

    #[allow(clippy::type_complexity)]
    fn sheet() -> (
        Grid,
        Vec<[u32; 3]>,
        Vec<u32>,
        Vec<[u8; 4]>,
        Vec<[f32; 3]>,
        Vec<u32>,
    ) {
        let grid = Grid {
            origin: [-1.0, -2.0, 0.5],
            step: 1.0 / 4096.0,
        };
        let n = 12u32;
        let mut gp = Vec::new();
        for y in 0..n {
            for x in 0..n {
                gp.push([x * 37 + 5, y * 41 + 9, 1000 + (x * y) % 7]);
            }
        }
        let ids: Vec<u32> = (0..n * n).map(|i| 5000 + i * 3).collect();
        let colors: Vec<[u8; 4]> = (0..n * n).map(|i| [(i * 2) as u8, 100, 200, 255]).collect();
        let normals: Vec<[f32; 3]> = (0..n * n).map(|_| [0.0, 0.6, 0.8]).collect();
        let mut indices = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let i = y * n + x;
                indices.extend_from_slice(&[i, i + 1, i + n + 1, i, i + n + 1, i + n]);
            }
        }
        (grid, gp, ids, colors, normals, indices)
    }

    /// A patch's triangles as triples of original ids, in a canonical order: what a roundtrip
    /// must keep whatever order the encoder puts vertices and triangles in.
    fn triangles_by_id(indices: &[u32], ids: &[u32]) -> Vec<[u32; 3]> {
        let mut t: Vec<[u32; 3]> = indices
            .chunks(3)
            .map(|t| {
                let t = [ids[t[0] as usize], ids[t[1] as usize], ids[t[2] as usize]];
                let r = (0..3).min_by_key(|&k| t[k]).unwrap_or(0);
                [t[r], t[(r + 1) % 3], t[(r + 2) % 3]]
            })
            .collect();
        t.sort();
        t
    }

    #[test]
    fn colour_decoding_rounds_exactly_and_inverts_the_filter() {
        // Every (y, co, cg) the 6-bit filter produces, against the exact rational value.
        let mut all = Vec::new();
        for y in 0..64u8 {
            for co in -32i8..32 {
                for cg in -32i8..32 {
                    all.push([y, co as u8, cg as u8, 0b10_0000 | (y & 31)]);
                }
            }
        }
        let mut decoded = all.clone();
        decode_ycocg(&mut decoded);
        for (raw, out) in all.iter().zip(&decoded) {
            let (y, co, cg) = (raw[0] as f64, raw[1] as i8 as f64, raw[2] as i8 as f64);
            let a = (((raw[3] as i32) << 1) & 63) | (raw[3] as i32 & 1);
            let want = [y + co - cg, y + cg, y - co - cg, a as f64]
                .map(|v| (v * 255.0 / 63.0).round().clamp(0.0, 255.0) as u8);
            assert_eq!(*out, want, "{raw:?}");
        }
        // And the filter's round trip stays within its 6-bit precision.
        let colours: Vec<[u8; 4]> = (0..4096u32)
            .map(|i| [(i * 7) as u8, ((i * 13) >> 2) as u8, (i >> 4) as u8, 255])
            .collect();
        let unit: Vec<[f32; 4]> = colours
            .iter()
            .map(|c| c.map(|x| x as f32 / 255.0))
            .collect();
        let mut back: Vec<[u8; 4]> = meshopt::encode_filter_color(&unit, COLOR_BITS);
        decode_ycocg(&mut back);
        for (c, b) in colours.iter().zip(&back) {
            for k in 0..4 {
                assert!((c[k] as i32 - b[k] as i32).abs() <= 6, "{c:?} -> {b:?}");
            }
        }
    }

    #[test]
    fn textured_roundtrip_splits_vertices_at_chart_borders_only() {
        let (grid, gp, ids, colors, normals, indices) = sheet();
        // Two charts: the left and right halves of the sheet (x < 6 and x >= 6), each with
        // its own coordinates, so the column x = 6 is split.
        let corner_uvs: Vec<[f32; 2]> = indices
            .chunks_exact(3)
            .flat_map(|t| {
                let right = t.iter().map(|&v| v % 12).min().unwrap_or(0) >= 6;
                t.iter()
                    .map(move |&v| {
                        let (x, y) = ((v % 12) as f32, (v / 12) as f32);
                        if right {
                            [0.55 + (x - 6.0) / 12.0, y / 12.0]
                        } else {
                            [x / 12.0, y / 12.0]
                        }
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        let image = vec![0xFFu8, 0xD8, 1, 2, 3];
        let patch = PatchRef {
            grid_positions: &gp,
            colors: Some(&colors),
            normals: Some(&normals),
            original_ids: &ids,
            indices: &indices,
            shift: 3,
            texture: Some((&corner_uvs, &image)),
        };
        let (blob, vertices) = encode_counted(&patch, 3);
        let p = decode(&blob, &grid).expect("decodes");
        assert_eq!(p.image.as_deref(), Some(&image[..]));
        // The image section can be filled in afterwards (the build's fragment qualities),
        // the rest of the blob decoding the same.
        let empty = encode(
            &PatchRef {
                texture: Some((&corner_uvs, &[])),
                ..patch
            },
            3,
        );
        let filled = with_images(&empty, Some(&image), None).expect("a blob");
        assert_eq!(filled, blob);
        // A normal map beside the image, or alone (an untextured scan's coarse patch).
        let refilled = with_images(&filled, Some(&[9, 9]), Some(&[7, 7, 7])).expect("a blob");
        let q = decode(&refilled, &grid).expect("decodes");
        assert_eq!(q.image.as_deref(), Some(&[9u8, 9][..]));
        assert_eq!(q.normal_map.as_deref(), Some(&[7u8, 7, 7][..]));
        assert_eq!(
            (&q.positions, &q.indices, &q.uvs),
            (&p.positions, &p.indices, &p.uvs)
        );
        let (bytes, _) = blob_bytes(&refilled).expect("frames");
        assert_eq!((bytes.header, bytes.image, bytes.normal_map), (20, 2, 3));
        let alone = with_images(&refilled, None, Some(&[5])).expect("a blob");
        let r = decode(&alone, &grid).expect("decodes");
        assert_eq!((r.image, r.normal_map.as_deref()), (None, Some(&[5u8][..])));
        assert_eq!((&r.positions, &r.uvs), (&p.positions, &p.uvs));
        assert_eq!(with_images(&alone, None, None).expect("a blob"), {
            let mut plain = empty[..12].to_vec();
            plain[5] = 0;
            plain.extend_from_slice(&empty[16..]);
            plain
        });
        // Real JPEGs (the standard Huffman tables) are stored without their tables and decode
        // whole, byte for byte.
        let texture = crate::mesh::Texture::from_texels(16, 8, vec![[200, 30, 90, 255]; 128])
            .expect("an image");
        let jpeg = super::super::atlas::encode_jpeg(&texture, 85);
        let normal_jpeg = super::super::atlas::encode_normal_jpeg(&texture, 90);
        let real = with_images(&empty, Some(&jpeg), Some(&normal_jpeg)).expect("a blob");
        assert_eq!(
            real[5],
            BLOB_IMAGE | BLOB_NORMALS | BLOB_STANDARD_HUFFMAN | BLOB_STANDARD_HEADERS
        );
        let (bytes, _) = blob_bytes(&real).expect("frames");
        assert_eq!(stored_image_len(&real), bytes.image);
        // The Huffman tables, the JFIF segment and the quantisation tables, less the quality.
        let tables =
            jpegtables::STANDARD_DHT.len() + jpegtables::JFIF_APP0.len() + jpegtables::DQT_LEN - 1;
        assert_eq!(bytes.image + tables, jpeg.len());
        assert_eq!(bytes.normal_map + tables, normal_jpeg.len());
        let r = decode(&real, &grid).expect("decodes");
        assert_eq!(r.image.as_deref(), Some(&jpeg[..]));
        assert_eq!(r.normal_map.as_deref(), Some(&normal_jpeg[..]));
        // Beside an image that is not such a JPEG, both are stored whole.
        let mixed = with_images(&empty, Some(&jpeg), Some(&[7, 7])).expect("a blob");
        assert_eq!(mixed[5], BLOB_IMAGE | BLOB_NORMALS);
        assert_eq!(
            decode(&mixed, &grid).expect("decodes").image.as_deref(),
            Some(&jpeg[..])
        );
        // A WebP atlas is stored whole and flagged; the JPEG normal map beside it still goes
        // without its tables and headers, and both decode byte for byte.
        let webp = super::super::atlas::encode_webp(&texture, 85.0);
        assert!(crate::mesh::is_webp(&webp));
        let both = with_images(&empty, Some(&webp), Some(&normal_jpeg)).expect("a blob");
        assert_eq!(
            both[5],
            BLOB_IMAGE
                | BLOB_NORMALS
                | BLOB_IMAGE_WEBP
                | BLOB_STANDARD_HUFFMAN
                | BLOB_STANDARD_HEADERS
        );
        assert!(image_is_webp(&both));
        let (bytes, _) = blob_bytes(&both).expect("frames");
        assert_eq!(
            (bytes.image, bytes.normal_map + tables),
            (webp.len(), normal_jpeg.len())
        );
        let w = decode(&both, &grid).expect("decodes");
        assert_eq!(w.image.as_deref(), Some(&webp[..]));
        assert_eq!(w.normal_map.as_deref(), Some(&normal_jpeg[..]));
        let back = crate::mesh::Texture::decode(&webp).expect("the engine decodes its WebP");
        assert_eq!((back.width(), back.height()), (16, 8));
        // A WebP alone sets no JPEG flag.
        let lone = with_images(&empty, Some(&webp), None).expect("a blob");
        assert_eq!(lone[5], BLOB_IMAGE | BLOB_IMAGE_WEBP);
        assert_eq!(
            decode(&lone, &grid).expect("decodes").image.as_deref(),
            Some(&webp[..])
        );
        // A declared normal map longer than the blob is refused.
        let mut bad = alone.clone();
        bad[12..16].copy_from_slice(&(alone.len() as u32).to_le_bytes());
        assert!(decode(&bad, &grid).is_err());
        // One extra vertex per row on the chart border (x = 6 belongs to both halves).
        assert_eq!(p.positions.len(), 12 * 12 + 12);
        assert_eq!(vertices, p.positions.len());
        assert_eq!(p.uvs.len(), p.positions.len());
        let mut moved = false;
        for (k, &v) in p.indices.iter().enumerate() {
            let id = p.original_ids[v as usize];
            let local = ids.iter().position(|&i| i == id).expect("an input id") as u32;
            // Copies of a vertex decode to the same grid position, near the input one.
            let copies: Vec<[u32; 3]> = (0..p.positions.len())
                .filter(|&w| p.original_ids[w] == id)
                .map(|w| p.grid_positions[w])
                .collect();
            assert!(copies.iter().all(|&g| g == copies[0]), "{copies:?}");
            // And to one normal, stored once (payload flag bit 5).
            let first = (0..p.positions.len())
                .find(|&w| p.original_ids[w] == id)
                .expect("a copy");
            assert_eq!(p.normals[v as usize], p.normals[first]);
            for k in 0..3 {
                assert!((copies[0][k] as i64 - gp[local as usize][k] as i64).abs() <= 8);
            }
            // The coordinates are the charts' maps at the decoded position: the texture stays
            // where the surface was while an interior vertex moves by its quantisation.
            let g = p.grid_positions[v as usize];
            let (x, y) = ((g[0] as f32 - 5.0) / 37.0, (g[1] as f32 - 9.0) / 41.0);
            moved |= g != gp[local as usize];
            let tri = &p.indices[k / 3 * 3..k / 3 * 3 + 3];
            let right = tri
                .iter()
                .map(|&w| {
                    ids.iter()
                        .position(|&i| i == p.original_ids[w as usize])
                        .unwrap_or(0)
                        % 12
                })
                .min()
                .unwrap_or(0)
                >= 6;
            let want = if right {
                [0.55 + (x - 6.0) / 12.0, y / 12.0]
            } else {
                [x / 12.0, y / 12.0]
            };
            let got = p.uvs[v as usize];
            // Within the fit of a chart whose heights scatter (a unit is 1/444 across).
            let tolerance = if g == gp[local as usize] { 1e-4 } else { 1e-3 };
            assert!(
                (got[0] - want[0]).abs() < tolerance && (got[1] - want[1]).abs() < tolerance,
                "vertex {v} at {g:?} (input {:?}): {got:?}, want {want:?}",
                gp[local as usize]
            );
        }
        assert!(moved, "some interior vertex is quantised");
        // Coordinates that are no chart's projection are stored per vertex, as given.
        let bent: Vec<[f32; 2]> = corner_uvs
            .iter()
            .map(|&[u, v]| [u, 0.9 * v + 0.03 + 0.02 * (40.0 * u).sin()])
            .collect();
        let (bent_blob, _) = encode_counted(
            &PatchRef {
                texture: Some((&bent, &image)),
                ..patch
            },
            3,
        );
        let q = decode(&bent_blob, &grid).expect("decodes");
        assert!(
            bent_blob.len() > blob.len() + 200,
            "{} {}",
            bent_blob.len(),
            blob.len()
        );
        for (v, got) in q.uvs.iter().enumerate() {
            let id = q.original_ids[v];
            let given = indices.iter().zip(&bent).any(|(&w, want)| {
                ids[w as usize] == id
                    && (got[0] - want[0]).abs() < 1e-4
                    && (got[1] - want[1]).abs() < 1e-4
            });
            assert!(given, "vertex {v}: {got:?}");
        }
        // Untextured blobs have neither.
        let plain = decode(
            &encode(
                &PatchRef {
                    texture: None,
                    ..patch
                },
                3,
            ),
            &grid,
        )
        .expect("decodes");
        assert!(plain.uvs.is_empty() && plain.image.is_none());
        assert_eq!(plain.positions.len(), 144);
        // A declared image longer than the blob is refused.
        let mut bad = blob.clone();
        bad[12..16].copy_from_slice(&(blob.len() as u32).to_le_bytes());
        assert!(decode(&bad, &grid).is_err());
    }

    /// The breakdown of a blob accounts for every byte of it and of its payload, and refuses
    /// what does not frame.
    #[test]
    fn blob_bytes_account_for_every_byte() {
        let (_, gp, ids, colors, normals, indices) = sheet();
        for level in [0, 3] {
            let blob = encode(
                &PatchRef {
                    grid_positions: &gp,
                    colors: Some(&colors),
                    normals: Some(&normals),
                    original_ids: &ids,
                    indices: &indices,
                    shift: 0,
                    texture: None,
                },
                level,
            );
            let (b, payload) = blob_bytes(&blob).expect("frames");
            assert_eq!(b.stored, blob.len());
            assert_eq!(b.header + b.image + b.body, blob.len());
            assert_eq!(
                b.payload_header + b.streams.iter().sum::<usize>(),
                payload.len()
            );
            // Indices, positions, ids and colours are there; normals only for border vertices.
            assert!(b.streams[..4].iter().all(|&n| n > 0), "{b:?}");
            assert_eq!(b.streams[5], 0, "no texture coordinates");
            assert!(blob_bytes(&blob[..blob.len() - 1]).is_err());
            let mut bad = blob.clone();
            bad[0] ^= 1;
            assert!(matches!(blob_bytes(&bad), Err(CodecError::Magic)));
        }
    }

    #[test]
    fn copies_of_a_vertex_off_the_border_decode_to_one_point() {
        // Vertex 0 closes a fan of chart A (its copy there is interior) and touches one more
        // triangle of chart B (that copy is on the border): a patch not manifold at vertex 0,
        // as simplification leaves them. At shift 2 the interior copy would round 5 to 4.
        let grid = Grid {
            origin: [0.0; 3],
            step: 1.0,
        };
        let mut gp: Vec<[u32; 3]> = vec![[5, 5, 1]];
        for k in 0..6 {
            let a = k as f64 * std::f64::consts::PI / 3.0;
            gp.push([
                (9.0 + 4.0 * a.cos()) as u32,
                (9.0 + 4.0 * a.sin()) as u32,
                0,
            ]);
        }
        gp.extend([[21, 5, 1], [21, 13, 1]]);
        let mut indices = Vec::new();
        for k in 0..6u32 {
            indices.extend([0, 1 + k, 1 + (k + 1) % 6]);
        }
        indices.extend([0, 7, 8]);
        let corner_uvs: Vec<[f32; 2]> = indices
            .iter()
            .enumerate()
            .map(|(c, &v)| {
                let chart_b = c >= 18;
                [v as f32 / 10.0 + if chart_b { 0.5 } else { 0.0 }, 0.25]
            })
            .collect();
        let ids: Vec<u32> = (0..gp.len() as u32).collect();
        let patch = PatchRef {
            grid_positions: &gp,
            colors: None,
            normals: None,
            original_ids: &ids,
            indices: &indices,
            shift: 2,
            texture: Some((&corner_uvs, &[])),
        };
        let p = decode(&encode(&patch, 3), &grid).expect("decodes");
        let copies: Vec<[f32; 3]> = p
            .original_ids
            .iter()
            .zip(&p.positions)
            .filter(|(id, _)| **id == 0)
            .map(|(_, &q)| q)
            .collect();
        assert_eq!(copies.len(), 2, "one copy a chart");
        assert_eq!(copies[0], copies[1]);
        assert_eq!(copies[0], [5.0, 5.0, 1.0]);
        // Without the second chart nothing is copied, and the interior stays coarser.
        let p = decode(
            &encode(
                &PatchRef {
                    texture: None,
                    ..patch
                },
                3,
            ),
            &grid,
        )
        .expect("decodes");
        assert_eq!(p.shift, 2);
    }

    #[test]
    fn roundtrip_is_exact_at_full_precision() {
        let (grid, gp, ids, colors, normals, indices) = sheet();
        let patch = PatchRef {
            grid_positions: &gp,
            colors: Some(&colors),
            normals: Some(&normals),
            original_ids: &ids,
            indices: &indices,
            shift: 0,
            texture: None,
        };
        for blob in in_both_layouts(&patch, 3) {
            let p = decode(&blob, &grid).expect("decodes");
            assert_eq!(
                triangles_by_id(&indices, &ids),
                triangles_by_id(&p.indices, &p.original_ids)
            );
            for (i, id) in p.original_ids.iter().enumerate() {
                let old = ids.iter().position(|x| x == id).expect("id kept");
                assert_eq!(p.grid_positions[i], gp[old]);
                assert_eq!(p.positions[i], grid.dequantize(gp[old]));
                for k in 0..3 {
                    assert!(
                        (p.colors[i][k] as i32 - colors[old][k] as i32).abs() <= 6,
                        "{:?} vs {:?}",
                        p.colors[i],
                        colors[old]
                    );
                }
            }
            let border = border_vertices(&p.indices, p.positions.len());
            for (i, b) in border.iter().enumerate() {
                if *b {
                    let d: f32 = (0..3).map(|k| p.normals[i][k] * normals[0][k]).sum();
                    assert!(d > 0.9995, "border normal error {d}");
                }
            }
        }
    }

    #[test]
    fn coarse_interior_moves_at_most_half_a_coarse_step_and_border_is_exact() {
        let (grid, gp, ids, _, _, indices) = sheet();
        let shift = 4;
        let patch = PatchRef {
            grid_positions: &gp,
            colors: None,
            normals: None,
            original_ids: &ids,
            indices: &indices,
            shift,
            texture: None,
        };
        for blob in in_both_layouts(&patch, 3) {
            let p = decode(&blob, &grid).expect("decodes");
            let border = border_vertices(&p.indices, p.positions.len());
            for (i, id) in p.original_ids.iter().enumerate() {
                let old = ids.iter().position(|x| x == id).expect("id kept");
                for (k, &expected) in gp[old].iter().enumerate() {
                    let d = (p.grid_positions[i][k] as i64 - expected as i64).abs();
                    if border[i] {
                        assert_eq!(d, 0);
                    } else {
                        assert!(d <= 1 << (shift - 1), "moved {d}");
                    }
                }
            }
        }
    }

    #[test]
    fn octahedral_roundtrip_is_within_a_degree() {
        for k in 0..2000 {
            let t = k as f64 * 0.37;
            let v = [
                t.sin() * (t * 0.3).cos(),
                (t * 1.7).cos(),
                (t * 0.11).sin() - 0.2,
            ];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let v = v.map(|x| x / len);
            let d = oct_decode(oct_encode(v));
            let dot: f64 = (0..3).map(|i| d[i] as f64 * v[i]).sum();
            assert!(
                dot > 0.9995f64.min(1.0f64.to_radians().cos()),
                "{v:?} -> {d:?}"
            );
        }
    }

    /// The payload flags of an `MWP3` blob.
    fn payload_flags(blob: &[u8]) -> u32 {
        let framed = unframe(blob, 1 << 26).expect("frames");
        assert!(framed.v3);
        u32_at(&framed.payload, 8).expect("flags")
    }

    #[test]
    fn ids_in_morton_order_are_listed_sorted_and_exact() {
        let (grid, gp, raster_ids, _, _, indices) = sheet();
        // Ids numbering the sheet's points in Morton order, with gaps of 1 to 3 (a coarse
        // patch keeps a subset of the scan's vertices).
        let mut morton_ids = vec![0u32; gp.len()];
        let mut next = 40;
        for (rank, v) in morton_sequence(&gp).into_iter().enumerate() {
            morton_ids[v as usize] = next;
            next += 1 + (rank as u32 * 7) % 3;
        }
        for (ids, name) in [(&morton_ids, "Morton"), (&raster_ids, "raster")] {
            for shift in [0, 3] {
                let patch = PatchRef {
                    grid_positions: &gp,
                    colors: None,
                    normals: None,
                    original_ids: ids,
                    indices: &indices,
                    shift,
                    texture: None,
                };
                let blob = encode(&patch, 0);
                let sorted = payload_flags(&blob) & FLAG_SORTED_IDS != 0;
                // At full precision the Morton ids list sorted; raster ids are what the
                // parallelograms predict exactly (a + b - c on a regular grid), so they stay
                // predicted. With quantised interiors the encoder picks either.
                if shift == 0 {
                    assert_eq!(sorted, name == "Morton", "{name} ids at shift 0");
                }
                let p = decode(&blob, &grid).expect("decodes");
                assert_eq!(
                    triangles_by_id(&indices, ids),
                    triangles_by_id(&p.indices, &p.original_ids),
                    "{name} ids at shift {shift}, sorted {sorted}"
                );
                if shift == 0 {
                    for (i, id) in p.original_ids.iter().enumerate() {
                        let old = ids.iter().position(|x| x == id).expect("id kept");
                        assert_eq!(p.grid_positions[i], gp[old]);
                    }
                }
            }
        }
        // The flag is only for `MWP3`, and unknown flags are errors.
        let patch = PatchRef {
            grid_positions: &gp,
            colors: None,
            normals: None,
            original_ids: &morton_ids,
            indices: &indices,
            shift: 0,
            texture: None,
        };
        let blob = encode(&patch, 0);
        let flags_at = blob.len() - unframe(&blob, 1 << 26).expect("frames").payload.len() + 8;
        for bad in [FLAG_SORTED_IDS | 16, 1 << 31] {
            let mut corrupt = blob.clone();
            corrupt[flags_at..flags_at + 4].copy_from_slice(&bad.to_le_bytes());
            assert!(matches!(
                decode(&corrupt, &grid),
                Err(CodecError::Flags(f)) if f == bad
            ));
        }
    }

    #[test]
    fn corrupt_blobs_are_errors_not_panics() {
        let grid = Grid {
            origin: [0.0; 3],
            step: 1.0,
        };
        assert!(decode(b"", &grid).is_err());
        assert!(decode(b"MWP2\x01\0\0\0\xff\xff\xff\x00garbage", &grid).is_err());
        let (_, gp, ids, colors, normals, indices) = sheet();
        let patch = PatchRef {
            grid_positions: &gp,
            colors: Some(&colors),
            normals: Some(&normals),
            original_ids: &ids,
            indices: &indices,
            shift: 2,
            texture: None,
        };
        // Textured too: chart maps (the sheet's two halves) and normals once per id.
        let corner_uvs: Vec<[f32; 2]> = indices
            .iter()
            .enumerate()
            .map(|(c, &v)| {
                let right = indices[c / 3 * 3..c / 3 * 3 + 3]
                    .iter()
                    .all(|&w| w % 12 >= 6);
                let (x, y) = ((v % 12) as f32 / 24.0, (v / 12) as f32 / 12.0);
                [if right { 0.5 + x } else { x }, y]
            })
            .collect();
        let textured = PatchRef {
            texture: Some((&corner_uvs, &[0xFF, 0xD8, 1, 2][..])),
            ..patch
        };
        let mut blobs = in_both_layouts(&patch, 0).to_vec();
        blobs.push(encode(&textured, 0));
        for blob in blobs {
            for cut in (0..blob.len()).step_by(7) {
                let _ = decode(&blob[..cut], &grid);
            }
            let mut flipped = blob.clone();
            for i in 12..flipped.len() {
                flipped[i] ^= 0x5a;
                let _ = decode(&flipped, &grid);
                flipped[i] ^= 0x5a;
            }
        }
        // Flag bits 4 and 5 without the streams they qualify are refused.
        // (Stored uncompressed: the payload is the blob's tail, its flags at byte 8.)
        let blob = encode(&textured, 0);
        let at = blob.len() - u32_at(&blob, 8).expect("payload length") as usize + 8;
        let flags = u32_at(&blob, at).expect("flags");
        assert_eq!(
            flags & (FLAG_CHART_UVS | FLAG_NORMALS_BY_ID),
            FLAG_CHART_UVS | FLAG_NORMALS_BY_ID
        );
        assert!(decode(&blob, &grid).is_ok());
        for (clear, keep) in [
            (FLAG_UVS, FLAG_CHART_UVS),
            (FLAG_NORMALS, FLAG_NORMALS_BY_ID),
        ] {
            let mut bad = blob.clone();
            let flags = flags & !clear | keep;
            bad[at..at + 4].copy_from_slice(&flags.to_le_bytes());
            assert!(matches!(decode(&bad, &grid), Err(CodecError::Flags(_))));
        }
    }
}
