//! Colour textures of a scan (OBJ `map_Kd`, glTF base colour): sampled into vertex colours at
//! import, and handed to the sink whole ([`SourceTexture`]) so the LOD build can re-pack them
//! per patch (`lod::atlas`).
//!
//! Texels are sRGB; sampling is bilinear in linear light, and callers encode back to sRGB.

use std::path::Path;
use std::sync::LazyLock;

/// Largest texture accepted, in pixels per side (decoding is also bounded by `image`'s limits).
const MAX_SIDE: u32 = 32768;
/// Most bytes a decoded image may take (RGBA8): `image`'s default allocation limit, which the
/// other formats decode under.
const MAX_DECODED_BYTES: u64 = 512 << 20;

/// Whether `bytes` is a WebP file (RIFF container of form `WEBP`).
pub fn is_webp(bytes: &[u8]) -> bool {
    bytes.len() >= 12 && &bytes[..4] == b"RIFF" && &bytes[8..12] == b"WEBP"
}

/// How texture coordinates outside [0, 1] map onto the image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Wrap {
    Repeat,
    Clamp,
    Mirror,
}

/// A decoded RGBA8 (sRGB) image.
pub struct Texture {
    width: u32,
    height: u32,
    texels: Vec<[u8; 4]>,
}

static SRGB_TO_LINEAR: LazyLock<[f32; 256]> = LazyLock::new(|| {
    let mut t = [0.0; 256];
    for (i, v) in t.iter_mut().enumerate() {
        let c = i as f32 / 255.0;
        *v = if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        };
    }
    t
});

/// A texture of the scan as a reader hands it to a sink: the image and how coordinates outside
/// [0, 1] map onto it. Texture coordinates use the glTF convention (`v = 0` is the top row).
#[derive(Clone)]
pub struct SourceTexture {
    pub image: std::sync::Arc<Texture>,
    pub wrap_s: Wrap,
    pub wrap_t: Wrap,
}

impl SourceTexture {
    /// Bilinear sample in linear light, with this texture's wrap modes.
    pub fn sample(&self, uv: [f32; 2]) -> [f32; 4] {
        self.image.sample(uv[0], uv[1], self.wrap_s, self.wrap_t)
    }
}

impl std::fmt::Debug for SourceTexture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "SourceTexture({}x{}, {:?}/{:?})",
            self.image.width, self.image.height, self.wrap_s, self.wrap_t
        )
    }
}

/// sRGB byte to linear light in [0, 1].
#[inline]
pub fn srgb_to_linear(c: u8) -> f32 {
    SRGB_TO_LINEAR[c as usize]
}

/// Linear light (clamped to [0, 1]) to an sRGB byte: the byte `linear_to_srgb_curve` gives,
/// found among the 255 thresholds where that byte changes instead of through `powf` (a few per
/// cent of a textured build, which encodes every atlas texel).
#[inline]
pub fn linear_to_srgb(l: f32) -> u8 {
    let l = if l.is_nan() { 0.0 } else { l.clamp(0.0, 1.0) };
    let (thresholds, buckets) = &*SRGB_THRESHOLDS;
    let mut b = buckets[(l * SRGB_BUCKETS as f32) as usize] as usize;
    while b > 0 && l < thresholds[b] {
        b -= 1;
    }
    while b < 255 && l >= thresholds[b + 1] {
        b += 1;
    }
    b as u8
}

/// The sRGB curve (IEC 61966-2-1) of linear light in [0, 1], rounded to a byte.
fn linear_to_srgb_curve(l: f32) -> u8 {
    let c = if l <= 0.003_130_8 {
        l * 12.92
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    };
    (c * 255.0 + 0.5) as u8
}

/// Buckets of [`SRGB_THRESHOLDS`]' start table over [0, 1].
const SRGB_BUCKETS: usize = 4096;

/// For each byte `k`, the least `l` in [0, 1] that [`linear_to_srgb_curve`] takes to `k` or
/// more (bisected over the bit patterns of positive floats, which order as the floats do); and
/// the byte at the start of each of [`SRGB_BUCKETS`] equal buckets of [0, 1] (one more for 1).
#[allow(clippy::type_complexity)]
static SRGB_THRESHOLDS: LazyLock<([f32; 256], [u8; SRGB_BUCKETS + 1])> = LazyLock::new(|| {
    let mut thresholds = [0f32; 256];
    for (k, t) in thresholds.iter_mut().enumerate().skip(1) {
        let (mut lo, mut hi) = (0u32, 1f32.to_bits());
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if usize::from(linear_to_srgb_curve(f32::from_bits(mid))) >= k {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        *t = f32::from_bits(lo);
    }
    let mut buckets = [0u8; SRGB_BUCKETS + 1];
    for (i, b) in buckets.iter_mut().enumerate() {
        *b = linear_to_srgb_curve((i as f32 / SRGB_BUCKETS as f32).min(1.0));
    }
    (thresholds, buckets)
});

/// Linear RGBA (alpha linear too) to sRGB RGBA bytes.
pub fn encode_rgba(l: [f32; 4]) -> [u8; 4] {
    let a = if l[3].is_nan() {
        1.0
    } else {
        l[3].clamp(0.0, 1.0)
    };
    [
        linear_to_srgb(l[0]),
        linear_to_srgb(l[1]),
        linear_to_srgb(l[2]),
        (a * 255.0 + 0.5) as u8,
    ]
}

impl Texture {
    /// Decodes an image in any enabled format (PNG, JPEG, WebP).
    pub fn decode(bytes: &[u8]) -> Result<Texture, String> {
        if is_webp(bytes) {
            return Self::decode_webp(bytes);
        }
        let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| e.to_string())?;
        Self::from_reader(reader)
    }

    /// A WebP through libwebp, the decoder browsers use: the build's atlases decode to the
    /// texels the viewer sees, in about half the time `image`'s decoder takes (a cold render
    /// of a textured model decodes every atlas it draws). Sizes over [`MAX_SIDE`] or
    /// [`MAX_DECODED_BYTES`] are refused before anything is decoded.
    fn decode_webp(bytes: &[u8]) -> Result<Texture, String> {
        let features = webp::BitstreamFeatures::new(bytes).ok_or("not a decodable WebP image")?;
        let (width, height) = (features.width(), features.height());
        if width == 0 || height == 0 {
            return Err("the image is empty".into());
        }
        if width > MAX_SIDE
            || height > MAX_SIDE
            || u64::from(width) * u64::from(height) * 4 > MAX_DECODED_BYTES
        {
            return Err(format!(
                "the image is {width}x{height}, over the decoder's limits"
            ));
        }
        let image = webp::Decoder::new(bytes)
            .decode()
            .ok_or("the WebP image does not decode")?;
        let texels: Vec<[u8; 4]> = if image.is_alpha() {
            bytemuck::cast_slice::<u8, [u8; 4]>(&image).to_vec()
        } else {
            image
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2], 255])
                .collect()
        };
        Texture::from_texels(image.width(), image.height(), texels)
            .ok_or_else(|| "the WebP image decodes to the wrong size".into())
    }

    /// Reads and decodes an image file.
    pub fn open(path: &Path) -> Result<Texture, String> {
        let reader = image::ImageReader::open(path)
            .map_err(|e| e.to_string())?
            .with_guessed_format()
            .map_err(|e| e.to_string())?;
        Self::from_reader(reader)
    }

    fn from_reader<R: std::io::BufRead + std::io::Seek>(
        mut reader: image::ImageReader<R>,
    ) -> Result<Texture, String> {
        let mut limits = image::Limits::default();
        limits.max_image_width = Some(MAX_SIDE);
        limits.max_image_height = Some(MAX_SIDE);
        reader.limits(limits);
        let img = reader.decode().map_err(|e| e.to_string())?.into_rgba8();
        let (width, height) = img.dimensions();
        if width == 0 || height == 0 {
            return Err("the image is empty".into());
        }
        let texels = bytemuck::cast_slice::<u8, [u8; 4]>(img.as_raw()).to_vec();
        Ok(Texture {
            width,
            height,
            texels,
        })
    }

    /// An image from its texels, row by row from the top; `None` when the sizes disagree or
    /// the image is empty.
    pub fn from_texels(width: u32, height: u32, texels: Vec<[u8; 4]>) -> Option<Texture> {
        (width > 0 && height > 0 && texels.len() as u64 == width as u64 * height as u64).then_some(
            Texture {
                width,
                height,
                texels,
            },
        )
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// Texels, row by row from the top.
    pub fn texels(&self) -> &[[u8; 4]] {
        &self.texels
    }

    /// Decoded size in bytes.
    pub fn bytes(&self) -> u64 {
        self.texels.len() as u64 * 4
    }

    /// Bilinear sample in linear light. `(u, v)` use the glTF convention: `v = 0` is the top
    /// row of the image (OBJ callers pass `1 - v`). Non-finite coordinates sample (0, 0).
    pub fn sample(&self, u: f32, v: f32, wrap_s: Wrap, wrap_t: Wrap) -> [f32; 4] {
        self.bilinear(u, v, wrap_s, wrap_t, |t| {
            [
                srgb_to_linear(t[0]),
                srgb_to_linear(t[1]),
                srgb_to_linear(t[2]),
                t[3] as f32 / 255.0,
            ]
        })
    }

    /// Bilinear sample of the bytes as they are (`byte / 255`, no sRGB curve): for images
    /// that hold data rather than colour (normal maps).
    pub fn sample_unorm(&self, u: f32, v: f32, wrap_s: Wrap, wrap_t: Wrap) -> [f32; 4] {
        self.bilinear(u, v, wrap_s, wrap_t, |t| t.map(|c| c as f32 / 255.0))
    }

    fn bilinear(
        &self,
        u: f32,
        v: f32,
        wrap_s: Wrap,
        wrap_t: Wrap,
        value: impl Fn([u8; 4]) -> [f32; 4],
    ) -> [f32; 4] {
        let (x0, x1, fx) = axis(u, self.width, wrap_s);
        let (y0, y1, fy) = axis(v, self.height, wrap_t);
        let w = self.width as usize;
        let texel = |x: usize, y: usize| {
            let t = self
                .texels
                .get(y * w + x)
                .copied()
                .unwrap_or([0, 0, 0, 255]);
            value(t)
        };
        let (a, b, c, d) = (texel(x0, y0), texel(x1, y0), texel(x0, y1), texel(x1, y1));
        let mut out = [0.0; 4];
        for i in 0..4 {
            let top = a[i] + (b[i] - a[i]) * fx;
            let bottom = c[i] + (d[i] - c[i]) * fx;
            out[i] = top + (bottom - top) * fy;
        }
        out
    }
}

/// The two texel indices along one axis and the weight of the second.
fn axis(t: f32, size: u32, wrap: Wrap) -> (usize, usize, f32) {
    let t = if t.is_finite() { t as f64 } else { 0.0 };
    let t = match wrap {
        // Coordinates are mostly within [0, 1) already: `floor` is a libm call here.
        Wrap::Repeat if (0.0..1.0).contains(&t) => t,
        Wrap::Repeat => t - t.floor(),
        Wrap::Clamp => t.clamp(0.0, 1.0),
        Wrap::Mirror => {
            let m = t.rem_euclid(2.0);
            if m > 1.0 { 2.0 - m } else { m }
        }
    };
    let n = size as i64;
    let x = t * size as f64 - 0.5;
    // `floor(x)` for x >= -0.5 (t is in [0, 1] after the wrap): truncation of x + 1, less 1.
    let x0 = (x + 1.0) as i64 - 1;
    let f = (x - x0 as f64) as f32;
    let fix = |i: i64| -> usize {
        match wrap {
            // After the wrap above, i is within -1..=n: one step back in, not the integer
            // division of `rem_euclid` (kept for what rounding might leave outside).
            Wrap::Repeat => {
                let j = if i < 0 {
                    i + n
                } else if i >= n {
                    i - n
                } else {
                    i
                };
                if (0..n).contains(&j) {
                    j as usize
                } else {
                    i.rem_euclid(n) as usize
                }
            }
            _ => i.clamp(0, n - 1) as usize,
        }
    };
    (fix(x0), fix(x0 + 1), f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn webp_decodes_through_libwebp_and_damage_is_an_error() {
        let texels: Vec<[u8; 4]> = (0..24 * 16)
            .map(|i| [(i * 7 % 256) as u8, 90, (i % 24 * 10) as u8, 255])
            .collect();
        let image = Texture::from_texels(24, 16, texels).expect("an image");
        let webp = crate::lod::atlas::encode_webp(&image, 90.0);
        let back = Texture::decode(&webp).expect("decodes");
        assert_eq!((back.width(), back.height()), (24, 16));
        // The same texels as `image`'s own WebP decoder gives, within a level or two (both
        // upsample chroma; rounding may differ).
        let other = image::load_from_memory(&webp)
            .expect("image decodes")
            .into_rgba8();
        let most = back
            .texels()
            .iter()
            .zip(other.pixels())
            .map(|(a, b)| (0..3).map(|k| a[k].abs_diff(b.0[k])).max().unwrap_or(0))
            .max()
            .unwrap_or(0);
        assert!(most <= 8, "{most}");
        // Truncated or garbled: an error, never a panic.
        for cut in [0, 12, 20, 30, webp.len() / 2] {
            assert!(Texture::decode(&webp[..cut]).is_err(), "{cut}");
        }
        let mut garbled = webp.clone();
        for b in garbled.iter_mut().skip(30) {
            *b = 0xA5;
        }
        assert!(Texture::decode(&garbled).is_err());
        // A lossy header declaring 16383 x 16383 texels is within the side limit but over the
        // decoded-bytes limit: refused before decoding.
        let mut huge = webp.clone();
        huge[26..28].copy_from_slice(&0x3fffu16.to_le_bytes());
        huge[28..30].copy_from_slice(&0x3fffu16.to_le_bytes());
        match Texture::decode(&huge) {
            Err(e) => assert!(e.contains("limits"), "{e}"),
            Ok(_) => panic!("a 16383² WebP header is refused"),
        }
    }

    #[test]
    fn srgb_roundtrip() {
        for c in 0..=255u8 {
            assert_eq!(linear_to_srgb(srgb_to_linear(c)), c);
        }
    }

    #[test]
    fn srgb_encoding_by_thresholds_is_the_curve() {
        // Every 251st float in [0, 1], each threshold and its neighbours, and out of range.
        let one = 1f32.to_bits();
        let thresholds = SRGB_THRESHOLDS.0;
        let near = thresholds[1..]
            .iter()
            .flat_map(|t| [t.to_bits() - 1, t.to_bits(), t.to_bits() + 1]);
        for bits in (0..=one).step_by(251).chain(near).chain([one]) {
            let l = f32::from_bits(bits);
            assert_eq!(linear_to_srgb(l), linear_to_srgb_curve(l), "{l:e}");
        }
        assert_eq!(linear_to_srgb(-0.5), 0);
        assert_eq!(linear_to_srgb(7.0), 255);
        assert_eq!(linear_to_srgb(f32::NAN), 0);
    }

    #[test]
    fn bilinear_centre_and_wrap() {
        let t = Texture::from_texels(2, 1, vec![[0, 0, 0, 255], [255, 255, 255, 255]])
            .expect("sizes agree");
        // Texel centres.
        assert_eq!(
            encode_rgba(t.sample(0.25, 0.5, Wrap::Clamp, Wrap::Clamp))[0],
            0
        );
        assert_eq!(
            encode_rgba(t.sample(0.75, 0.5, Wrap::Clamp, Wrap::Clamp))[0],
            255
        );
        // Halfway is half in linear light, not half in sRGB.
        let mid = t.sample(0.5, 0.5, Wrap::Clamp, Wrap::Clamp);
        assert!((mid[0] - 0.5).abs() < 1e-6);
        assert_eq!(encode_rgba(mid)[0], 188);
        // Repeat wraps to the other side; NaN does not panic.
        let r = t.sample(1.25, 0.5, Wrap::Repeat, Wrap::Repeat);
        assert_eq!(encode_rgba(r)[0], 0);
        let _ = t.sample(f32::NAN, f32::INFINITY, Wrap::Mirror, Wrap::Repeat);
        let _ = t.sample(-1e30, 1e30, Wrap::Repeat, Wrap::Mirror);
    }
}
