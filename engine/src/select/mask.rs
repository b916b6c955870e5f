//! Stroke masks: what the user drew on the view, one label per pixel (system paper §4.1.1:
//! foreground and background markers; §4.2: the heavy marker; the conventional lasso's
//! polygon), and the selection mask image sent back.
//!
//! On the wire a stroke mask is a PNG of the view's size whose grey level is the label:
//!
//! | value | label | tool |
//! |---|---|---|
//! | 0 | nothing drawn | all |
//! | 1 | foreground marker | markup |
//! | 2 | background marker | markup |
//! | 3 | heavy band (one closed thick stroke along the boundary) | heavy lasso |
//! | 4 | inside of the lasso polygon | lasso |
//!
//! 8-bit greyscale PNGs are the canonical form; 8-bit grey+alpha (alpha ignored), RGB and RGBA
//! PNGs are accepted when their red, green and blue are equal. Any other value is refused, so
//! an anti-aliased or colour-coded image cannot be misread.

use std::io::Cursor;

/// Nothing drawn.
pub const NONE: u8 = 0;
/// Foreground marker (markup).
pub const FOREGROUND: u8 = 1;
/// Background marker (markup).
pub const BACKGROUND: u8 = 2;
/// The heavy band (heavy lasso).
pub const HEAVY: u8 = 3;
/// Inside of the lasso polygon.
pub const LASSO: u8 = 4;
/// Largest label value.
pub const MAX_LABEL: u8 = LASSO;
/// Largest mask side accepted (the engine's largest view).
pub const MAX_SIDE: u32 = crate::camera::Camera::MAX_SIDE;

/// Why a mask cannot be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MaskError {
    /// Not a PNG file.
    #[error("the stroke mask is not a PNG image")]
    NotPng,
    /// A PNG that does not decode.
    #[error("the stroke mask PNG does not decode: {0}")]
    Decode(String),
    /// A PNG of an unsupported pixel type (16-bit, or colours that are not grey).
    #[error("unsupported stroke mask: {0}")]
    Unsupported(String),
    /// A value that is no label.
    #[error(
        "stroke mask pixel ({x}, {y}) has value {value}; labels are 0 none, 1 foreground, \
         2 background, 3 heavy band, 4 lasso inside"
    )]
    BadLabel { x: u32, y: u32, value: u8 },
    /// Dimensions out of range or inconsistent with the data.
    #[error("stroke mask size {width}x{height} is invalid (1 to {MAX_SIDE} pixels a side)")]
    BadSize { width: u32, height: u32 },
}

/// One label per pixel, row-major, top row first.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StrokeMask {
    pub width: u32,
    pub height: u32,
    pub labels: Vec<u8>,
}

impl StrokeMask {
    /// A mask with nothing drawn.
    pub fn empty(width: u32, height: u32) -> Result<StrokeMask, MaskError> {
        check_size(width, height)?;
        Ok(StrokeMask {
            width,
            height,
            labels: vec![NONE; width as usize * height as usize],
        })
    }

    /// Wraps labels, checking the size and every value.
    pub fn new(width: u32, height: u32, labels: Vec<u8>) -> Result<StrokeMask, MaskError> {
        check_size(width, height)?;
        if labels.len() != width as usize * height as usize {
            return Err(MaskError::BadSize { width, height });
        }
        if let Some(i) = labels.iter().position(|&v| v > MAX_LABEL) {
            return Err(MaskError::BadLabel {
                x: (i % width as usize) as u32,
                y: (i / width as usize) as u32,
                value: labels[i],
            });
        }
        Ok(StrokeMask {
            width,
            height,
            labels,
        })
    }

    /// Decodes a stroke mask PNG (see the module documentation for the accepted forms).
    pub fn decode_png(bytes: &[u8]) -> Result<StrokeMask, MaskError> {
        const MAGIC: &[u8] = b"\x89PNG\r\n\x1a\n";
        if !bytes.starts_with(MAGIC) {
            return Err(MaskError::NotPng);
        }
        let mut reader =
            image::ImageReader::with_format(Cursor::new(bytes), image::ImageFormat::Png);
        let mut limits = image::Limits::default();
        limits.max_image_width = Some(MAX_SIDE);
        limits.max_image_height = Some(MAX_SIDE);
        limits.max_alloc = Some(512 << 20);
        reader.limits(limits);
        let img = reader.decode().map_err(|e| match e {
            image::ImageError::Limits(_) => MaskError::Unsupported(format!(
                "the image is larger than {MAX_SIDE}x{MAX_SIDE} pixels"
            )),
            other => MaskError::Decode(other.to_string()),
        })?;
        let (width, height) = (img.width(), img.height());
        check_size(width, height)?;
        let labels: Vec<u8> = match img {
            image::DynamicImage::ImageLuma8(g) => g.into_raw(),
            image::DynamicImage::ImageLumaA8(g) => g.pixels().map(|p| p.0[0]).collect(),
            image::DynamicImage::ImageRgb8(g) => {
                grey(g.pixels().map(|p| [p.0[0], p.0[1], p.0[2]]))?
            }
            image::DynamicImage::ImageRgba8(g) => {
                grey(g.pixels().map(|p| [p.0[0], p.0[1], p.0[2]]))?
            }
            other => {
                return Err(MaskError::Unsupported(format!(
                    "{:?} pixels; send an 8-bit greyscale PNG",
                    other.color()
                )));
            }
        };
        StrokeMask::new(width, height, labels)
    }

    /// Encodes the mask as an 8-bit greyscale PNG (tests and tools).
    pub fn encode_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let enc = image::codecs::png::PngEncoder::new(&mut out);
        // Writing a valid buffer into a Vec cannot fail.
        let _ = image::ImageEncoder::write_image(
            enc,
            &self.labels,
            self.width,
            self.height,
            image::ExtendedColorType::L8,
        );
        out
    }

    /// Pixels holding `label`.
    pub fn count(&self, label: u8) -> usize {
        self.labels.iter().filter(|&&v| v == label).count()
    }
}

fn check_size(width: u32, height: u32) -> Result<(), MaskError> {
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(MaskError::BadSize { width, height });
    }
    Ok(())
}

fn grey(pixels: impl Iterator<Item = [u8; 3]>) -> Result<Vec<u8>, MaskError> {
    pixels
        .map(|[r, g, b]| {
            if r == g && g == b {
                Ok(r)
            } else {
                Err(MaskError::Unsupported(
                    "colour pixels: labels are grey levels 0 to 4 (send an 8-bit greyscale PNG)"
                        .into(),
                ))
            }
        })
        .collect()
}

/// Colour of selected pixels in the result mask image.
pub const SELECTED_RGBA: [u8; 4] = [0, 160, 255, 255];

/// Bounding box `[x0, y0, x1, y1)` (ends exclusive) of the pixels whose flag is set, in a
/// row-major view `width` pixels wide; `None` when none is.
pub fn bounding_box(flags: impl IntoIterator<Item = bool>, width: usize) -> Option<[usize; 4]> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (i, _) in flags.into_iter().enumerate().filter(|(_, f)| *f) {
        let (x, y) = (i % width, i / width);
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x + 1);
        y1 = y1.max(y + 1);
    }
    (x0 != usize::MAX).then_some([x0, y0, x1, y1])
}

/// The result mask as an RGBA PNG: selected pixels [`SELECTED_RGBA`], the rest transparent
/// (alpha 255 = selected), ready to overlay on the view.
pub fn selection_png(width: u32, height: u32, selected: &[bool]) -> Vec<u8> {
    let mut rgba = Vec::with_capacity(selected.len() * 4);
    for &s in selected {
        rgba.extend_from_slice(if s { &SELECTED_RGBA } else { &[0, 0, 0, 0] });
    }
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    );
    // A buffer of exactly width × height × 4 bytes encodes; any other size would be a bug.
    let _ = image::ImageEncoder::write_image(
        enc,
        &rgba,
        width,
        height,
        image::ExtendedColorType::Rgba8,
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounding_box_ends_are_exclusive() {
        // 5 wide: pixels (1, 1) and (3, 2) set.
        let mut flags = [false; 15];
        flags[6] = true;
        flags[13] = true;
        assert_eq!(bounding_box(flags.iter().copied(), 5), Some([1, 1, 4, 3]));
        assert_eq!(bounding_box([false; 15], 5), None);
    }

    #[test]
    fn png_round_trip() {
        let mut m = StrokeMask::empty(7, 5).unwrap();
        m.labels[3] = FOREGROUND;
        m.labels[10] = BACKGROUND;
        m.labels[20] = HEAVY;
        m.labels[34] = LASSO;
        let png = m.encode_png();
        assert_eq!(StrokeMask::decode_png(&png).unwrap(), m);
    }

    #[test]
    fn refuses_bad_masks() {
        assert_eq!(StrokeMask::decode_png(b"GIF89a"), Err(MaskError::NotPng));
        assert!(matches!(
            StrokeMask::decode_png(b"\x89PNG\r\n\x1a\nrubbish"),
            Err(MaskError::Decode(_))
        ));
        let bad = StrokeMask {
            width: 2,
            height: 1,
            labels: vec![0, 9],
        };
        assert_eq!(
            StrokeMask::decode_png(&bad.encode_png()),
            Err(MaskError::BadLabel {
                x: 1,
                y: 0,
                value: 9
            })
        );
        // Colour pixels.
        let mut out = Vec::new();
        image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(&mut out),
            &[1, 2, 3],
            1,
            1,
            image::ExtendedColorType::Rgb8,
        )
        .unwrap();
        assert!(matches!(
            StrokeMask::decode_png(&out),
            Err(MaskError::Unsupported(_))
        ));
        // Grey RGBA is fine.
        let mut out = Vec::new();
        image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(&mut out),
            &[3, 3, 3, 255],
            1,
            1,
            image::ExtendedColorType::Rgba8,
        )
        .unwrap();
        assert_eq!(StrokeMask::decode_png(&out).unwrap().labels, vec![HEAVY]);
    }

    #[test]
    fn selection_png_has_alpha_where_selected() {
        let png = selection_png(2, 1, &[true, false]);
        let img = image::load_from_memory(&png).unwrap().to_rgba8();
        assert_eq!(img.get_pixel(0, 0).0, SELECTED_RGBA);
        assert_eq!(img.get_pixel(1, 0).0[3], 0);
    }
}
