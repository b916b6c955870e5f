//! WebP atlases at JPEG's error (issue 11: output per texel no larger than the source JPEG's,
//! at the fragment quality the TexMesh paper's rule chooses, `004_28b2044bb56fb245.txt` §3).
//!
//! [`super::fragment_quality`] gives every fragment a quality on JPEG's scale. WebP's scale is
//! not JPEG's, and how the two relate depends on the texture: on atlas-like crops
//! (`scripts/atlas-codecs.py`, WebP at the build's method 2) JPEG q85 is matched by WebP q89
//! on the Bali mask's photograph (0.73× JPEG's bytes) and by WebP q83 on the generated
//! relief's noisy texture (0.66×). So the build measures it on the
//! scan itself: for a sample of its atlases it finds the smallest offset `o` such that WebP at
//! each sampled fragment's quality `q + o` has, summed over the samples' chart texels, no more
//! squared error than JPEG at `q`. Every fragment is then encoded at `q + o`, which keeps the
//! spread between featured and plain fragments. Where WebP cannot reach JPEG's error, or
//! reaches it only with more bytes on the samples, the build keeps JPEG.
//!
//! The offset is searched within [`OFFSET_RANGE`] to [`RESOLUTION`]: stepped out from 0 by
//! [`STEP`] until the error crosses JPEG's, then bisected, five or six encodings of the sample
//! (at most [`MAX_SAMPLES`] atlases) where the offset is within a few units of 0, as on every
//! texture measured (a bisection of the whole range took nine). Everything is deterministic:
//! the samples are chosen by position in the build's node order, and libwebp runs
//! single-threaded per image.

use rayon::prelude::*;

use super::atlas::{encode_jpeg, encode_webp};
use super::fragment_quality::rgb_squared_error;
use super::jpegtables;
use crate::mesh::Texture;

/// Offsets (WebP quality minus the fragment's JPEG quality) searched.
pub const OFFSET_RANGE: (f32, f32) = (-30.0, 15.0);
/// Bisection ends when the bracket is this narrow (WebP quality units).
pub const RESOLUTION: f32 = 0.5;
/// The bracket's steps out from offset 0.
pub const STEP: f32 = 4.0;
/// Atlases sampled at most.
pub const MAX_SAMPLES: usize = 48;

/// One sampled atlas.
pub struct Sample<'a> {
    pub image: &'a Texture,
    /// Texels inside the atlas' triangles (row-major, `width × height`).
    pub covered: &'a [bool],
    /// The fragment's quality, on JPEG's scale.
    pub quality: u8,
}

/// What the match found.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Match {
    /// WebP quality minus JPEG quality (None: the build keeps JPEG).
    pub offset: Option<f32>,
    /// Atlases sampled.
    pub samples: usize,
    /// The samples' bytes as JPEG (as stored: without tables and headers) and as WebP at
    /// the offset found (at the top of the range where none was).
    pub jpeg_bytes: u64,
    pub webp_bytes: u64,
    /// The samples' squared error over their chart texels, JPEG and WebP.
    pub jpeg_error: f64,
    pub webp_error: f64,
}

/// Which of `count` atlases (in build order) to sample: evenly spaced, at most
/// [`MAX_SAMPLES`].
pub fn sample_indices(count: usize) -> Vec<usize> {
    if count == 0 {
        return Vec::new();
    }
    let n = count.min(MAX_SAMPLES);
    (0..n).map(|k| k * count / n).collect()
}

/// The WebP quality offset that matches JPEG's error on `samples` ([module docs](self)).
pub fn match_jpeg(samples: &[Sample]) -> Match {
    let mut found = Match {
        offset: None,
        samples: samples.len(),
        jpeg_bytes: 0,
        webp_bytes: 0,
        jpeg_error: 0.0,
        webp_error: 0.0,
    };
    if samples.is_empty() {
        return found;
    }
    let jpeg: Vec<(u64, f64)> = samples
        .par_iter()
        .map(|s| {
            let encoded = encode_jpeg(s.image, s.quality);
            let error = squared_error(s, &encoded);
            let stored = jpegtables::strip_standard_huffman(&encoded)
                .map(|h| jpegtables::strip_headers(&h).unwrap_or(h))
                .map_or(encoded.len(), |b| b.len());
            (stored as u64, error)
        })
        .collect();
    found.jpeg_bytes = jpeg.iter().map(|j| j.0).sum();
    found.jpeg_error = jpeg.iter().map(|j| j.1).sum();
    let jpeg_error = found.jpeg_error;
    let webp_at = |offset: f32| -> (u64, f64) {
        samples
            .par_iter()
            .map(|s| {
                let encoded = encode_webp(s.image, f32::from(s.quality) + offset);
                (encoded.len() as u64, squared_error(s, &encoded))
            })
            .reduce(|| (0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
    };
    // A bracket [lo, hi] around the least offset that reaches JPEG's error: stepped out from
    // 0 (where the offset is found on every texture measured, within a few units), then
    // bisected. Invariant after the bracket: WebP at `hi` reaches JPEG's error (`best` is its
    // figures), at `lo` it does not, or `lo` is the range's bottom and `hi` equals it.
    let (bottom, top) = OFFSET_RANGE;
    let start = 0f32.clamp(bottom, top);
    let at_start = webp_at(start);
    let (mut lo, mut hi, mut best);
    if at_start.1 <= jpeg_error {
        (hi, best) = (start, at_start);
        lo = hi;
        while lo > bottom {
            let next = (hi - STEP).max(bottom);
            let at = webp_at(next);
            if at.1 <= jpeg_error {
                (hi, best) = (next, at);
                lo = hi;
            } else {
                lo = next;
                break;
            }
        }
    } else {
        let mut last = at_start;
        lo = start;
        loop {
            if lo >= top {
                (found.webp_bytes, found.webp_error) = last;
                return found;
            }
            let next = (lo + STEP).min(top);
            let at = webp_at(next);
            if at.1 <= jpeg_error {
                (hi, best) = (next, at);
                break;
            }
            (lo, last) = (next, at);
        }
    }
    while hi - lo > RESOLUTION {
        let mid = 0.5 * (lo + hi);
        let at = webp_at(mid);
        if at.1 <= jpeg_error {
            hi = mid;
            best = at;
        } else {
            lo = mid;
        }
    }
    (found.webp_bytes, found.webp_error) = best;
    found.offset = (best.0 < found.jpeg_bytes).then_some(hi);
    found
}

/// Squared error (8-bit RGB) of `encoded` decoded against the sample's texels, over its chart
/// texels; infinite where it does not decode to the same size (an image the encoder refused).
fn squared_error(sample: &Sample, encoded: &[u8]) -> f64 {
    let Ok(back) = Texture::decode(encoded) else {
        return f64::INFINITY;
    };
    if back.width() != sample.image.width() || back.height() != sample.image.height() {
        return f64::INFINITY;
    }
    sample
        .image
        .texels()
        .iter()
        .zip(back.texels())
        .zip(sample.covered)
        .filter(|(_, c)| **c)
        .map(|((a, b), _)| rgb_squared_error(*a, *b))
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A detailed texture with a disc of chart texels and the rest a flat fill, as the
    /// build's atlases look.
    fn atlas(side: u32, seed: u32) -> (Texture, Vec<bool>) {
        let hash = |x: u32, y: u32| {
            let mut h = x.wrapping_mul(0x9E37_79B1) ^ y.wrapping_mul(0x85EB_CA77) ^ seed;
            h ^= h >> 15;
            h = h.wrapping_mul(0x2C1B_3C6D);
            h ^= h >> 12;
            (h & 0xFF) as f32
        };
        let c = side as f32 / 2.0;
        let mut covered = Vec::new();
        let mut texels = Vec::new();
        for y in 0..side {
            for x in 0..side {
                let inside = (x as f32 - c).hypot(y as f32 - c) < c * 0.8;
                covered.push(inside);
                // Smooth shading with a little grain, as photographs of a surface have.
                let (fx, fy) = (x as f32, y as f32);
                let v = if inside {
                    128.0 + 60.0 * (fx / 5.0).sin() * (fy / 7.0).cos() + 0.1 * (hash(x, y) - 128.0)
                } else {
                    120.0
                };
                let v = v.clamp(0.0, 255.0) as u8;
                texels.push([v, v / 2 + 40, 255 - v, 255]);
            }
        }
        (
            Texture::from_texels(side, side, texels).expect("a whole texture"),
            covered,
        )
    }

    #[test]
    fn the_offset_found_matches_jpegs_error_and_one_step_less_does_not() {
        let atlases: Vec<(Texture, Vec<bool>)> = (0..4).map(|s| atlas(96, s)).collect();
        let samples: Vec<Sample> = atlases
            .iter()
            .map(|(image, covered)| Sample {
                image,
                covered,
                quality: 85,
            })
            .collect();
        let m = match_jpeg(&samples);
        let offset = m
            .offset
            .expect("WebP matches JPEG on a detailed atlas with a fill");
        assert!(m.webp_error <= m.jpeg_error, "{m:?}");
        assert!(m.webp_bytes < m.jpeg_bytes, "{m:?}");
        // Three qualities lower WebP no longer reaches JPEG's error: the offset is (about) the
        // least one that does, not just any one.
        let below: f64 = samples
            .iter()
            .map(|s| {
                let e = encode_webp(s.image, f32::from(s.quality) + offset - 3.0);
                squared_error(s, &e)
            })
            .sum();
        assert!(below > m.jpeg_error, "{offset} {below} {m:?}");
    }

    #[test]
    fn no_samples_keep_jpeg() {
        let none = match_jpeg(&[]);
        assert_eq!((none.offset, none.samples, none.webp_bytes), (None, 0, 0));
        assert!(sample_indices(0).is_empty());
        assert_eq!(sample_indices(3), vec![0, 1, 2]);
        let many = sample_indices(1000);
        assert_eq!(many.len(), MAX_SAMPLES);
        assert!(many.windows(2).all(|w| w[0] < w[1]) && many[MAX_SAMPLES - 1] < 1000);
    }
}
