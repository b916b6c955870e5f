//! One image of the repository as stored and served (system paper §5.2.2, with what §5.1's
//! reconstruction needs to be correct).
//!
//! The paper stores shaded JPEGs. A shaded image carries the light of the camera that took
//! it, so a view reconstructed from several of them shows their lights, not its own. Each
//! image here carries the surface instead: its *albedo* (omitted for models without colours
//! or texture, whose albedo is the base colour), its *normals* (world space, facing the
//! camera) and its *view depth*. A client shades the reconstructed surface under its own light
//! by the server's rule (`ambient + (1 − ambient)·|n·v|`; per pixel, where the server's
//! renderer lights its vertices: on the 5M relief that difference is worth 0.1 dB of the
//! network bench's close views), and projects an image only
//! onto points at the depth the image saw (Fig. 15's projective texture mapping, with a
//! visibility test). Background pixels take the colour of the nearest surface (a few pixels
//! of dilation) so neither JPEG ringing nor bilinear filtering bleeds background into the
//! silhouette.
//!
//! Layout (little endian; see docs/FORMAT.md, "Lumigraph image"):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `MWLI` |
//! | 4 | 1 | version (1) |
//! | 5 | 1 | flags: bit 0 albedo present; bit 1 normals in face order, bits 2–3 the face's axis |
//! | 6 | 2 | side of the colour images (pixels) |
//! | 8 | 2 | side of the depth image |
//! | 10 | 2 | u16 depth code `m` of `d1` (0 in images of earlier builds: 65534) |
//! | 12 | 4 | f32 nearest depth `d0` |
//! | 16 | 4 | f32 farthest depth `d1` |
//! | 20 | 4 | u32 albedo bytes `a` (0 without albedo) |
//! | 24 | 4 | u32 normal bytes `n` |
//! | 28 | 4 | u32 depth bytes `z` |
//! | 32 | a | albedo: baseline JPEG, RGB |
//! | 32 + a | n | normals: baseline JPEG 4:4:4, `(n + 1) / 2`, in face order: green the component along the face's axis `a`, red `a + 1`'s, blue `a + 2`'s (mod 3); without flag bit 1, `rgb` in x, y, z order |
//! | 32 + a + n | z | depth: PNG, RGB8; `q = 256·r + g`, 65535 = no surface, else depth `d0 + q / m · (d1 − d0)` |
//!
//! The depth image is a quarter of the colour side ([`depth_side`]); each of its pixels holds
//! the mean depth of the covered colour pixels of the 4×4 block it covers. A client
//! interpolates it bilinearly where four neighbours lie on one surface and takes the block's
//! own value across a depth jump (its tolerance covers the block's footprint). The mean, not
//! the nearest, is what lets the client find the very point an image saw: the nearest of a
//! block lies in front of the rest of a rough surface, which moved each image's texels by that
//! roughness times the angle between the image's ray and the view's (on the 5M relief the
//! image-based views gained 1.7 dB on average, at the same bytes). At a quarter, depth is
//! about a tenth of an image's bytes; at the full side it was more than half.
//!
//! The codes step by a pixel's footprint at the nearest depth ([`depth_codes`]): `m` codes
//! span the image's depths, where 65534 did. A texel found through the depth then moves by at
//! most half its footprint times the tangent of the angle between the image's ray and the
//! view's: a quarter of a texel at 25°, where the shader's weight of an image is a fortieth of
//! a head-on one's. The finer low bits were noise to PNG: on the network bench's dragon, the
//! stored images that see most of it spent a third of their bytes on depth at 65534 codes; at
//! quarter-, half- and whole-pixel steps the path's bytes fall from 1.07 to 0.93, 0.90 and
//! 0.87 MB, at the same PSNR (34.3–34.4 dB).

use image::ImageEncoder;
use image::codecs::png::PngEncoder;

/// Magic bytes.
pub const MAGIC: &[u8; 4] = b"MWLI";
/// Format version.
pub const VERSION: u8 = 1;
/// Header bytes.
pub const HEADER: usize = 32;
/// Depth code of a pixel without surface.
pub const NO_DEPTH: u16 = u16::MAX;
/// Pixels of dilation around the surface in the colour images.
const DILATE: usize = 4;

/// Why an image cannot be encoded or decoded.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("lumigraph image: {0}")]
    Malformed(String),
    #[error("lumigraph image: {0}")]
    Codec(#[from] image::ImageError),
}

/// A decoded repository image.
#[derive(Debug, Clone, PartialEq)]
pub struct LumigraphImage {
    /// Side of the colour images.
    pub side: u32,
    /// Albedo (RGB), `side`², or none (the model's base colour).
    pub albedo: Option<Vec<[u8; 3]>>,
    /// Normals encoded as `(n + 1) / 2` bytes, `side`².
    pub normal: Vec<[u8; 3]>,
    /// Side of the depth image.
    pub depth_side: u32,
    /// Depth codes, `depth_side`² ([`NO_DEPTH`] where no surface was seen).
    pub depth: Vec<u16>,
    /// Depth of code 0 and of code 65534.
    pub depth_range: [f32; 2],
}

impl LumigraphImage {
    /// View depth at depth pixel `i` (`None` where no surface was seen).
    pub fn depth_at(&self, i: usize) -> Option<f32> {
        let q = *self.depth.get(i)?;
        (q != NO_DEPTH).then(|| {
            let [d0, d1] = self.depth_range;
            d0 + q as f32 / (NO_DEPTH - 1) as f32 * (d1 - d0)
        })
    }
}

/// Fraction of a frame's pixels that show surface (finite depth).
pub fn coverage(depth: &[f32]) -> f32 {
    if depth.is_empty() {
        return 0.0;
    }
    depth.iter().filter(|d| d.is_finite()).count() as f32 / depth.len() as f32
}

/// How finely an image's JPEG sections are coded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Quality {
    /// The albedo's JPEG quality (standard tables, 4:2:0).
    pub albedo: u8,
    /// The normals' quantiser steps (4:4:4, in face order, every channel alike): `[dc, fine]`,
    /// the step of the DC coefficient and of coefficients of frequency `u + v ≥ 4`, linear in
    /// `u + v` between ([`normal_table`]).
    pub normal_steps: [u8; 2],
}

/// Quantiser steps of the normals' DCT coefficients (natural order, `v · 8 + u`): `dc` at
/// `u + v = 0`, `fine` from `u + v = 4` on, linear between.
///
/// The shading's error is what a view's PSNR counts, and it weighs every frequency alike,
/// where the standard tables, made for the eye, quantise fine detail up to seven times as
/// coarsely as the DC (at quality 80, luma: 6 to 48): a scan's fine relief is what its
/// normals carry. A client resamples an image at another phase than its texels and blends several,
/// which smooths its finest frequencies, so the steps still grow with frequency, three times
/// over. On renders of the dragon and of the 5M relief from outside, shading under views
/// within 25° of the image's ray, both at the images' resolution and smoothed by [1 2 1]²:
/// steps `[8, 24]` in face order against the standard tables at quality 80 in x, y, z order
/// have 1.2 to 1.6 dB less error at full resolution, the same (dragon, −0.3 dB) or less
/// (relief, +1.2 dB) smoothed, with 13 % fewer bytes (dragon) or as many (relief); one step
/// of 24 for all had 24 % fewer bytes on the dragon but 2.3 dB more error smoothed, and the
/// network bench's dragon lost 0.2 dB with it.
pub fn normal_table([dc, fine]: [u8; 2]) -> [u16; 64] {
    std::array::from_fn(|i| {
        let f = ((i % 8 + i / 8) as f32 / 4.0).min(1.0);
        (dc as f32 + (fine as f32 - dc as f32) * f)
            .round()
            .clamp(1.0, 255.0) as u16
    })
}

/// Encodes a square render (`side`², its albedo, facing normals and linear view depth) taken
/// along axis `axis` (0 x, 1 y, 2 z; either sign) as a repository image; `None` when it shows
/// no surface (the repository's "empty" flag). `albedo` is `None` for models without colours
/// or texture.
pub fn encode(
    side: u32,
    albedo: Option<&[[u8; 4]]>,
    normal: &[[f32; 3]],
    depth: &[f32],
    axis: usize,
    quality: Quality,
) -> Result<Option<Vec<u8>>, ImageError> {
    let px = side as usize * side as usize;
    if axis > 2 {
        return Err(ImageError::Malformed(format!("no axis {axis}")));
    }
    if side < 2
        || side > u16::MAX as u32
        || normal.len() != px
        || depth.len() != px
        || albedo.is_some_and(|a| a.len() != px)
    {
        return Err(ImageError::Malformed(format!(
            "buffers do not match a {side}x{side} image"
        )));
    }
    let covered: Vec<bool> = depth.iter().map(|d| d.is_finite()).collect();
    if !covered.iter().any(|&c| c) {
        return Ok(None);
    }
    let normals: Vec<[u8; 3]> = normal
        .iter()
        .map(|n| face_order(*n, axis).map(|c| ((c.clamp(-1.0, 1.0) + 1.0) * 127.5).round() as u8))
        .collect();
    let normals = dilate(&normals, &covered, side as usize);
    let albedo = albedo.map(|a| {
        let rgb: Vec<[u8; 3]> = a.iter().map(|p| [p[0], p[1], p[2]]).collect();
        dilate(&rgb, &covered, side as usize)
    });
    let albedo_jpeg = match &albedo {
        Some(a) => jpeg(
            a,
            side,
            Steps::Standard(quality.albedo),
            jpeg_encoder::SamplingFactor::F_2_2,
        )?,
        None => Vec::new(),
    };
    let normal_jpeg = jpeg(
        &normals,
        side,
        Steps::Table(normal_table(quality.normal_steps)),
        jpeg_encoder::SamplingFactor::F_1_1,
    )?;
    let (depth_side, codes, range, m) = quantise_depth(depth, side as usize);
    let mut rgb = Vec::with_capacity(codes.len() * 3);
    for q in &codes {
        rgb.extend_from_slice(&[(q >> 8) as u8, (q & 0xFF) as u8, 0]);
    }
    let mut depth_png = Vec::new();
    PngEncoder::new_with_quality(
        &mut depth_png,
        image::codecs::png::CompressionType::Best,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(
        &rgb,
        depth_side as u32,
        depth_side as u32,
        image::ExtendedColorType::Rgb8,
    )?;
    let mut out =
        Vec::with_capacity(HEADER + albedo_jpeg.len() + normal_jpeg.len() + depth_png.len());
    out.extend_from_slice(MAGIC);
    out.push(VERSION);
    out.push(u8::from(albedo.is_some()) | FACE_ORDER | ((axis as u8) << 2));
    out.extend_from_slice(&(side as u16).to_le_bytes());
    out.extend_from_slice(&(depth_side as u16).to_le_bytes());
    out.extend_from_slice(&m.to_le_bytes());
    out.extend_from_slice(&range[0].to_le_bytes());
    out.extend_from_slice(&range[1].to_le_bytes());
    for len in [albedo_jpeg.len(), normal_jpeg.len(), depth_png.len()] {
        out.extend_from_slice(&(len as u32).to_le_bytes());
    }
    out.extend_from_slice(&albedo_jpeg);
    out.extend_from_slice(&normal_jpeg);
    out.extend_from_slice(&depth_png);
    Ok(Some(out))
}

/// Decodes a repository image.
pub fn decode(bytes: &[u8]) -> Result<LumigraphImage, ImageError> {
    let bad = |m: &str| ImageError::Malformed(m.to_string());
    if bytes.len() < HEADER || &bytes[0..4] != MAGIC {
        return Err(bad(
            "not a lumigraph image (bad magic or shorter than its header)",
        ));
    }
    if bytes[4] != VERSION {
        return Err(bad(&format!("unsupported version {}", bytes[4])));
    }
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u32_at =
        |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let f32_at = |o: usize| f32::from_bits(u32_at(o));
    let (side, depth_side) = (u16_at(6) as u32, u16_at(8) as u32);
    let [d0, d1] = [f32_at(12), f32_at(16)];
    // Code m is d1 (0: 65534, as images of earlier builds); the decoded range is code 0's and
    // code 65534's depth.
    let m = match u16_at(10) {
        0 => NO_DEPTH - 1,
        m => m.min(NO_DEPTH - 1),
    };
    let range = [d0, d0 + (d1 - d0) * ((NO_DEPTH - 1) as f32 / m as f32)];
    let lens = [
        u32_at(20) as usize,
        u32_at(24) as usize,
        u32_at(28) as usize,
    ];
    let total = lens
        .iter()
        .try_fold(HEADER, |a, &l| a.checked_add(l))
        .ok_or_else(|| bad("section lengths overflow"))?;
    if total != bytes.len() {
        return Err(bad(&format!(
            "sections hold {total} bytes, the image has {}",
            bytes.len()
        )));
    }
    if side < 2 || depth_side == 0 || !range.iter().all(|r| r.is_finite()) {
        return Err(bad("bad sizes or depth range"));
    }
    let has_albedo = bytes[5] & 1 != 0;
    if has_albedo != (lens[0] > 0) {
        return Err(bad("albedo flag and section disagree"));
    }
    let a_end = HEADER + lens[0];
    let n_end = a_end + lens[1];
    let rgb = |data: &[u8], s: u32| -> Result<Vec<[u8; 3]>, ImageError> {
        let img = image::load_from_memory(data)?.to_rgb8();
        if img.dimensions() != (s, s) {
            return Err(bad("a section's size differs from the header's"));
        }
        Ok(img
            .into_raw()
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect())
    };
    let albedo = if has_albedo {
        Some(rgb(&bytes[HEADER..a_end], side)?)
    } else {
        None
    };
    let mut normal = rgb(&bytes[a_end..n_end], side)?;
    if bytes[5] & FACE_ORDER != 0 {
        let axis = ((bytes[5] >> 2) & 3) as usize;
        if axis > 2 {
            return Err(bad("no such face axis"));
        }
        for n in &mut normal {
            *n = world_order(*n, axis);
        }
    }
    let depth = rgb(&bytes[n_end..], depth_side)?
        .into_iter()
        .map(|p| u16::from(p[0]) << 8 | u16::from(p[1]))
        .collect();
    Ok(LumigraphImage {
        side,
        albedo,
        normal,
        depth_side,
        depth,
        depth_range: range,
    })
}

/// A JPEG's quantiser steps.
enum Steps {
    /// The standard tables at this quality.
    Standard(u8),
    /// These steps (natural order, 1 to 255) for every channel.
    Table([u16; 64]),
}

/// Baseline JPEG with the standard Huffman tables (see `lod::atlas::encode_jpeg`).
fn jpeg(
    rgb: &[[u8; 3]],
    side: u32,
    steps: Steps,
    sampling: jpeg_encoder::SamplingFactor,
) -> Result<Vec<u8>, ImageError> {
    let s = u16::try_from(side).map_err(|_| ImageError::Malformed("image too large".into()))?;
    let mut out = Vec::new();
    let mut encoder = match steps {
        Steps::Standard(quality) => jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100)),
        Steps::Table(t) => {
            // (The quality scales the built-in tables only.)
            let mut e = jpeg_encoder::Encoder::new(&mut out, 100);
            let custom = || {
                jpeg_encoder::QuantizationTableType::Custom(Box::new(t.map(|v| v.clamp(1, 255))))
            };
            e.set_quantization_tables(custom(), custom());
            e
        }
    };
    encoder.set_sampling_factor(sampling);
    encoder
        .encode(rgb.as_flattened(), s, s, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| ImageError::Malformed(format!("JPEG encoding failed: {e}")))?;
    Ok(out)
}

/// Grows the covered pixels' values [`DILATE`] pixels into the background (each new pixel the
/// mean of its covered 4-neighbours); farther background keeps the mean surface value.
fn dilate(values: &[[u8; 3]], covered: &[bool], side: usize) -> Vec<[u8; 3]> {
    let mut out = values.to_vec();
    let mut done = covered.to_vec();
    for _ in 0..DILATE {
        let mut next = done.clone();
        for y in 0..side {
            for x in 0..side {
                let i = y * side + x;
                if done[i] {
                    continue;
                }
                let mut sum = [0u32; 3];
                let mut n = 0;
                let mut add = |j: usize| {
                    if done[j] {
                        for k in 0..3 {
                            sum[k] += out[j][k] as u32;
                        }
                        n += 1;
                    }
                };
                if x > 0 {
                    add(i - 1);
                }
                if x + 1 < side {
                    add(i + 1);
                }
                if y > 0 {
                    add(i - side);
                }
                if y + 1 < side {
                    add(i + side);
                }
                if n > 0 {
                    out[i] = sum.map(|s| ((s + n / 2) / n) as u8);
                    next[i] = true;
                }
            }
        }
        done = next;
    }
    let (mut sum, mut n) = ([0u64; 3], 0u64);
    for (v, c) in values.iter().zip(covered) {
        if *c {
            for k in 0..3 {
                sum[k] += v[k] as u64;
            }
            n += 1;
        }
    }
    let mean = sum.map(|s| (s / n.max(1)) as u8);
    for (v, d) in out.iter_mut().zip(&done) {
        if !d {
            *v = mean;
        }
    }
    out
}

/// Flags bit: the normals are stored in face order ([`face_order`]).
const FACE_ORDER: u8 = 2;

/// A normal's components in face order for a face along `axis`: green (which luma weighs most,
/// 0.587) the component along the axis, which the shading of views near the image's ray turns
/// on (|n·v| with v within a few tens of degrees of it); red and blue the two across it. On
/// the renders of [`normal_table`], at one step of 24 for all coefficients, 0.2 to 0.65 dB
/// less shading error than x, y, z order with 3 to 5 % fewer bytes.
pub fn face_order<T: Copy>(n: [T; 3], axis: usize) -> [T; 3] {
    [n[(axis + 1) % 3], n[axis], n[(axis + 2) % 3]]
}

/// Inverse of [`face_order`].
pub fn world_order<T: Copy>(c: [T; 3], axis: usize) -> [T; 3] {
    let mut n = c;
    n[(axis + 1) % 3] = c[0];
    n[axis] = c[1];
    n[(axis + 2) % 3] = c[2];
    n
}

/// Colour pixels per depth pixel, along each axis.
pub const DEPTH_BLOCK: u32 = 4;

/// Side of the depth image of a `side`-pixel image.
pub fn depth_side(side: u32) -> u32 {
    side.div_ceil(DEPTH_BLOCK)
}

/// Depth codes at [`depth_side`] (each the mean of its block's covered pixels), their range
/// and the code of its far end ([`depth_codes`]).
fn quantise_depth(depth: &[f32], side: usize) -> (usize, Vec<u16>, [f32; 2], u16) {
    let block = DEPTH_BLOCK as usize;
    let half = depth_side(side as u32) as usize;
    let mut sum = vec![0f64; half * half];
    let mut cnt = vec![0u32; half * half];
    for y in 0..side {
        for x in 0..side {
            let d = depth[y * side + x];
            if d.is_finite() {
                let i = (y / block) * half + x / block;
                sum[i] += d as f64;
                cnt[i] += 1;
            }
        }
    }
    let means: Vec<f32> = sum
        .iter()
        .zip(&cnt)
        .map(|(&s, &c)| {
            if c > 0 {
                (s / c as f64) as f32
            } else {
                f32::INFINITY
            }
        })
        .collect();
    let finite = means.iter().filter(|d| d.is_finite());
    let d0 = finite.clone().fold(f32::INFINITY, |a, &b| a.min(b));
    let d1 = finite.fold(f32::NEG_INFINITY, |a, &b| a.max(b));
    let (d0, d1) = if d0.is_finite() {
        (d0, d1.max(d0))
    } else {
        (0.0, 0.0)
    };
    let m = depth_codes(d0, d1, side as u32);
    let scale = if d1 > d0 { m as f32 / (d1 - d0) } else { 0.0 };
    let codes = means
        .iter()
        .map(|&d| {
            if d.is_finite() {
                ((d - d0) * scale).round().clamp(0.0, m as f32) as u16
            } else {
                NO_DEPTH
            }
        })
        .collect();
    (half, codes, [d0, d1], m)
}

/// Codes spanning depths `d0` to `d1` of a `side`-pixel image, so that they step by a pixel's
/// footprint at the nearest depth (a 90° image's pixel spans `2 · d / side`); 1 to 65534 (all
/// of them where `d0` is not a positive depth).
pub fn depth_codes(d0: f32, d1: f32, side: u32) -> u16 {
    let steps = (d1 - d0) * 0.5 * side as f32 / d0;
    if d0 > 0.0 && steps.is_finite() {
        steps.ceil().clamp(1.0, (NO_DEPTH - 1) as f32) as u16
    } else {
        NO_DEPTH - 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const Q90: Quality = Quality {
        albedo: 90,
        normal_steps: [4, 8],
    };
    const Q80: Quality = Quality {
        albedo: 80,
        normal_steps: [8, 24],
    };

    /// A sphere of radius 0.5 at distance 2 seen head-on: its depth, normals and a
    /// left/right albedo.
    fn sphere(side: u32) -> (Vec<[u8; 4]>, Vec<[f32; 3]>, Vec<f32>) {
        let s = side as usize;
        let (mut a, mut n, mut d) = (
            vec![[0; 4]; s * s],
            vec![[0.0; 3]; s * s],
            vec![f32::INFINITY; s * s],
        );
        for y in 0..s {
            for x in 0..s {
                let u = (x as f32 + 0.5) / s as f32 * 2.0 - 1.0;
                let v = (y as f32 + 0.5) / s as f32 * 2.0 - 1.0;
                let r2 = u * u + v * v;
                if r2 < 1.0 {
                    let z = (1.0 - r2).sqrt();
                    let i = y * s + x;
                    n[i] = [u, -v, z];
                    d[i] = 2.0 - 0.5 * z;
                    a[i] = if u < 0.0 {
                        [200, 40, 40, 255]
                    } else {
                        [40, 40, 200, 255]
                    };
                }
            }
        }
        (a, n, d)
    }

    #[test]
    fn round_trip_keeps_albedo_normals_and_depth() {
        let side = 64;
        let (a, n, d) = sphere(side);
        let bytes = encode(side, Some(&a), &n, &d, 2, Q90).unwrap().unwrap();
        let img = decode(&bytes).unwrap();
        assert_eq!((img.side, img.depth_side), (64, 16));
        let albedo = img.albedo.as_ref().unwrap();
        // Inside the sphere, away from its rim, colours and normals survive JPEG.
        let centre_left = 32 * 64 + 20;
        assert!(albedo[centre_left][0] > 150 && albedo[centre_left][2] < 90);
        let nz = img.normal[32 * 64 + 32][2] as f32 / 127.5 - 1.0;
        assert!(nz > 0.95, "{nz}");
        // Depth: within half a code's step, the mean of each 4x4 block.
        let [d0, d1] = img.depth_range;
        let step = (d1 - d0) / (NO_DEPTH - 1) as f32;
        let block: Vec<f32> = (32..36)
            .flat_map(|y| (32..36).map(move |x| y * 64 + x))
            .map(|i| d[i])
            .collect();
        let want = block.iter().sum::<f32>() / block.len() as f32;
        let got = img.depth_at(8 * 16 + 8).unwrap();
        assert!((got - want).abs() <= 0.5 * step + 1e-6, "{got} vs {want}");
        // The codes step by at most a pixel's footprint at the nearest depth.
        assert!(step <= 2.0 * d0 / side as f32 + 1e-6, "step {step} at {d0}");
        // A steep ramp (six footprints deeper each pixel): each block's mean,
        // not its nearest pixel.
        let ramp: Vec<f32> = (0..64 * 64).map(|i| 1.0 + 0.2 * (i % 64) as f32).collect();
        let r = decode(&encode(side, None, &n, &ramp, 2, Q90).unwrap().unwrap()).unwrap();
        let step = (r.depth_range[1] - r.depth_range[0]) / (NO_DEPTH - 1) as f32;
        for i in 0..16 * 16 {
            let mean = 1.0 + 0.2 * (4.0 * (i % 16) as f32 + 1.5);
            let got = r.depth_at(i).unwrap();
            assert!((got - mean).abs() <= 0.5 * step + 1e-5, "{got} vs {mean}");
            assert!(
                got - (mean - 0.3) > 0.5 * step,
                "{got}: the block's nearest"
            );
        }
        // On the rim only the covered pixels count.
        let (rim, covered) = (0..16 * 16)
            .map(|i| {
                let (bx, by) = (i % 16, i / 16);
                let covered: Vec<f32> = (0..16)
                    .map(|k| d[(4 * by + k / 4) * 64 + 4 * bx + k % 4])
                    .filter(|x| x.is_finite())
                    .collect();
                (i, covered)
            })
            .find(|(_, covered)| !covered.is_empty() && covered.len() < 16)
            .expect("a block on the sphere's rim");
        let mean = covered.iter().sum::<f32>() / covered.len() as f32;
        let stored = img.depth_at(rim).unwrap();
        assert!(
            (stored - mean).abs() <= 0.5 * step + 1e-6,
            "rim {stored} vs {mean}"
        );
        assert_eq!(img.depth_at(0), None);
        // Without albedo the section is absent and smaller.
        let plain = encode(side, None, &n, &d, 2, Q90).unwrap().unwrap();
        assert!(plain.len() < bytes.len());
        assert!(decode(&plain).unwrap().albedo.is_none());
    }

    #[test]
    fn depth_codes_step_by_a_pixel_at_the_nearest_depth() {
        for (d0, d1, side) in [
            (1.0, 2.0, 512),
            (0.05, 0.3, 512),
            (2.0, 2.0, 64),
            (1.0, 1e6, 512),
        ] {
            let m = depth_codes(d0, d1, side);
            assert!(m >= 1);
            let step = (d1 - d0) / m as f32;
            assert!(
                step <= 2.0 * d0 / side as f32 * 1.0001 || m == NO_DEPTH - 1,
                "{d0}..{d1}: {m}"
            );
        }
        assert_eq!(depth_codes(1.0, 2.0, 512), 256);
        assert_eq!(depth_codes(0.0, 2.0, 512), NO_DEPTH - 1);
        assert_eq!(depth_codes(f32::NAN, 2.0, 512), NO_DEPTH - 1);
        // Images of earlier builds (code field 0) read their codes over 65534 steps.
        let (a, n, d) = sphere(32);
        let mut bytes = encode(32, Some(&a), &n, &d, 2, Q80).unwrap().unwrap();
        let coded = decode(&bytes).unwrap();
        let m = u16::from_le_bytes([bytes[10], bytes[11]]);
        assert!(m > 0 && m < NO_DEPTH - 1, "{m}");
        bytes[10..12].copy_from_slice(&0u16.to_le_bytes());
        let old = decode(&bytes).unwrap();
        let f = |b: &[u8], o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        assert_eq!(old.depth_range, [f(&bytes, 12), f(&bytes, 16)]);
        let i = coded
            .depth
            .iter()
            .position(|&q| q != NO_DEPTH && q > 0)
            .unwrap();
        let [d0, d1] = old.depth_range;
        let want = d0 + coded.depth[i] as f32 / 65534.0 * (d1 - d0);
        assert!((old.depth_at(i).unwrap() - want).abs() < 1e-6);
    }

    #[test]
    fn normals_are_stored_in_face_order_and_read_back_in_world_order() {
        // The sphere's normals (z towards its camera) turned so that each axis faces the
        // camera in turn: stored with that axis in green, decoded in x, y, z order.
        let (_, n, d) = sphere(32);
        for axis in 0..3 {
            let turned: Vec<[f32; 3]> = n
                .iter()
                .map(|&v| world_order([v[0], v[2], v[1]], axis))
                .collect();
            let bytes = encode(32, None, &turned, &d, axis, Q90).unwrap().unwrap();
            assert_eq!(bytes[5], FACE_ORDER | (axis as u8) << 2);
            let img = decode(&bytes).unwrap();
            let centre = 16 * 32 + 16;
            let got = img.normal[centre].map(|c| c as f32 / 127.5 - 1.0);
            assert!(got[axis] > 0.95, "axis {axis}: {got:?}");
            // Everywhere within JPEG's error of the input.
            let worst = (0..32 * 32)
                .filter(|&i| d[i].is_finite())
                .map(|i| {
                    let g = img.normal[i].map(|c| c as f32 / 127.5 - 1.0);
                    (0..3)
                        .map(|k| (g[k] - turned[i][k]).abs())
                        .fold(0f32, f32::max)
                })
                .fold(0f32, f32::max);
            assert!(worst < 0.2, "axis {axis}: {worst}");
            // Its raw JPEG holds the facing component in green.
            let raw = image::load_from_memory(&bytes[HEADER..]).unwrap().to_rgb8();
            assert!(raw.get_pixel(16, 16)[1] > 240);
        }
        for (c, axis) in [([1, 2, 3], 0), ([1, 2, 3], 1), ([1, 2, 3], 2)] {
            assert_eq!(face_order(world_order(c, axis), axis), c);
        }
        // Images without the flag (earlier builds) keep x, y, z order; a fourth axis is refused.
        let bytes = encode(32, None, &n, &d, 2, Q90).unwrap().unwrap();
        let mut old = bytes.clone();
        old[5] = 0;
        let (a, b) = (decode(&bytes).unwrap(), decode(&old).unwrap());
        assert_eq!(b.normal[0], face_order(a.normal[0], 2));
        let mut bad = bytes;
        bad[5] = FACE_ORDER | 3 << 2;
        assert!(decode(&bad).is_err());
        assert!(encode(32, None, &n, &d, 3, Q90).is_err());
    }

    #[test]
    fn normals_are_quantised_by_frequency_with_the_tables_given() {
        let t = normal_table([8, 24]);
        assert_eq!(
            (t[0], t[1], t[8], t[9], t[3], t[4], t[63]),
            (8, 12, 12, 16, 20, 24, 24)
        );
        // The normals' JPEG carries that table for all three channels: in its zigzag order
        // (diagonal by diagonal of u + v) 8, 12 ×2, 16 ×3, 20 ×4, then 24.
        let (_, n, d) = sphere(32);
        let bytes = encode(32, None, &n, &d, 2, Q80).unwrap().unwrap();
        let lens =
            |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
        let jpeg = &bytes[HEADER..HEADER + lens(24) as usize];
        let mut want = vec![8u8, 12, 12, 16, 16, 16, 20, 20, 20, 20];
        want.resize(64, 24);
        let mut tables = 0;
        let mut i = 2;
        while i + 4 < jpeg.len() && jpeg[i] == 0xFF && jpeg[i + 1] != 0xDA {
            let len = u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]) as usize;
            if jpeg[i + 1] == 0xDB {
                let mut t = &jpeg[i + 4..i + 2 + len];
                while !t.is_empty() {
                    assert_eq!(t[0] >> 4, 0, "8-bit steps");
                    assert_eq!(&t[1..65], &want[..]);
                    tables += 1;
                    t = &t[65..];
                }
            }
            i += 2 + len;
        }
        assert_eq!(tables, 2, "luma and chroma tables");
    }

    #[test]
    fn an_image_of_nothing_is_empty_and_bad_input_is_an_error() {
        let s = 16;
        let d = vec![f32::INFINITY; 256];
        assert!(
            encode(s, None, &[[0.0; 3]; 256], &d, 2, Q80)
                .unwrap()
                .is_none()
        );
        assert_eq!(coverage(&d), 0.0);
        assert!(encode(s, None, &[[0.0; 3]; 10], &d, 2, Q80).is_err());
        let (a, n, d) = sphere(32);
        let bytes = encode(32, Some(&a), &n, &d, 2, Q80).unwrap().unwrap();
        assert!(decode(&bytes[..bytes.len() - 1]).is_err());
        assert!(decode(&bytes[..10]).is_err());
        let mut wrong = bytes.clone();
        wrong[0] = b'X';
        assert!(decode(&wrong).is_err());
        let mut flag = bytes.clone();
        flag[5] = 0;
        assert!(decode(&flag).is_err());
        // Every truncation and single-byte flip is an error or an image, never a panic.
        for cut in (0..bytes.len()).step_by(7) {
            let _ = decode(&bytes[..cut]);
        }
        for at in (0..bytes.len()).step_by(13) {
            let mut b = bytes.clone();
            b[at] ^= 0x5A;
            let _ = decode(&b);
        }
    }
}
