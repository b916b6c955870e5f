//! Image encoding of rendered frames (PNG, JPEG, WebP) for the render API and thumbnails
//! (system paper §2.2 display; §5 sends images instead of geometry to weak clients).

use image::ImageEncoder;
use image::codecs::{jpeg::JpegEncoder, png::PngEncoder, webp::WebPEncoder};

/// Output image format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageFormat {
    #[default]
    Png,
    Jpeg,
    /// Lossless WebP.
    Webp,
}

impl ImageFormat {
    /// Parses `png`, `jpeg`/`jpg` or `webp` (case-insensitive).
    pub fn parse(s: &str) -> Option<ImageFormat> {
        match s.trim().to_ascii_lowercase().as_str() {
            "png" => Some(ImageFormat::Png),
            "jpeg" | "jpg" => Some(ImageFormat::Jpeg),
            "webp" => Some(ImageFormat::Webp),
            _ => None,
        }
    }

    pub fn mime(self) -> &'static str {
        match self {
            ImageFormat::Png => "image/png",
            ImageFormat::Jpeg => "image/jpeg",
            ImageFormat::Webp => "image/webp",
        }
    }

    pub fn extension(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Jpeg => "jpg",
            ImageFormat::Webp => "webp",
        }
    }
}

/// Why an image could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    #[error("pixel count {len} does not match {width}x{height}")]
    Size { width: u32, height: u32, len: usize },
    #[error("JPEG quality must be within 1..=100, got {0}")]
    Quality(u8),
    #[error("encoding failed: {0}")]
    Image(#[from] image::ImageError),
}

/// Encodes RGBA8 pixels (row-major, top row first). `quality` applies to JPEG (1–100), whose
/// output has no alpha: transparent pixels are composited over `matte`.
pub fn encode(
    pixels: &[[u8; 4]],
    width: u32,
    height: u32,
    format: ImageFormat,
    quality: u8,
    matte: [u8; 3],
) -> Result<Vec<u8>, EncodeError> {
    if width == 0 || height == 0 || pixels.len() as u64 != width as u64 * height as u64 {
        return Err(EncodeError::Size {
            width,
            height,
            len: pixels.len(),
        });
    }
    let mut out = Vec::new();
    let rgba: &[u8] = bytemuck::cast_slice(pixels);
    match format {
        ImageFormat::Png => {
            PngEncoder::new(&mut out).write_image(
                rgba,
                width,
                height,
                image::ExtendedColorType::Rgba8,
            )?;
        }
        ImageFormat::Webp => {
            WebPEncoder::new_lossless(&mut out).write_image(
                rgba,
                width,
                height,
                image::ExtendedColorType::Rgba8,
            )?;
        }
        ImageFormat::Jpeg => {
            if !(1..=100).contains(&quality) {
                return Err(EncodeError::Quality(quality));
            }
            let rgb: Vec<u8> = pixels
                .iter()
                .flat_map(|p| {
                    let a = p[3] as u32;
                    [0, 1, 2].map(|k| {
                        ((p[k] as u32 * a + matte[k] as u32 * (255 - a) + 127) / 255) as u8
                    })
                })
                .collect();
            JpegEncoder::new_with_quality(&mut out, quality).write_image(
                &rgb,
                width,
                height,
                image::ExtendedColorType::Rgb8,
            )?;
        }
    }
    Ok(out)
}

/// Decodes a PNG/JPEG/WebP image into RGBA8 pixels (for tests and golden images).
pub fn decode(bytes: &[u8]) -> Result<(u32, u32, Vec<[u8; 4]>), EncodeError> {
    let img = image::load_from_memory(bytes)?.to_rgba8();
    let (w, h) = img.dimensions();
    let pixels = img
        .into_raw()
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    Ok((w, h, pixels))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_rejects_bad_sizes() {
        let px: Vec<[u8; 4]> = (0..12).map(|i| [i as u8 * 20, 100, 200, 255]).collect();
        for f in [ImageFormat::Png, ImageFormat::Webp] {
            let bytes = encode(&px, 4, 3, f, 90, [0; 3]).expect("encode");
            let (w, h, back) = decode(&bytes).expect("decode");
            assert_eq!((w, h), (4, 3));
            assert_eq!(back, px, "{f:?} is lossless");
        }
        let jpg = encode(&px, 4, 3, ImageFormat::Jpeg, 90, [255; 3]).expect("jpeg");
        assert_eq!(&jpg[..2], &[0xFF, 0xD8]);
        assert!(encode(&px, 5, 3, ImageFormat::Png, 90, [0; 3]).is_err());
        assert!(encode(&px, 4, 3, ImageFormat::Jpeg, 0, [0; 3]).is_err());
        assert_eq!(ImageFormat::parse("JPG"), Some(ImageFormat::Jpeg));
        assert_eq!(ImageFormat::parse("gif"), None);
    }
}
