//! JPEG images of patches without their Huffman tables (issue 11: atlas bytes). Every atlas
//! and normal map is a baseline JPEG with the standard Huffman tables of ITU-T T.81 Annex K.3
//! (the build does not optimise them: see [`super::atlas::encode_jpeg`]), the same 432 bytes
//! in each image: 7–18% of a small atlas' bytes on the generated relief. As in Motion JPEG
//! (which omits them and names these tables), a blob stores its images without those DHT
//! segments and says so (blob flag bit 2, `docs/FORMAT.md`); a decoder puts
//! [`STANDARD_DHT`] back right before the image's SOS marker, where the encoder wrote it,
//! which gives back the image as encoded, byte for byte.
//!
//! The same holds for the rest of the header but the frame and scan headers: the JFIF APP0
//! segment is the same in every image, and the quantisation tables are Annex K.1's scaled by
//! the image's quality (the IJG formula the encoder uses), so a blob with flag bit 3 stores
//! one byte, the quality, for those 156 ([`strip_headers`], [`with_headers`]): with the
//! Huffman tables, 587 bytes of an image of a few kilobytes.

/// The four DHT segments of Annex K.3 as the encoder writes them, in its order: DC luminance
/// (class 0, table 0), AC luminance (class 1, table 0), DC chrominance (class 0, table 1), AC
/// chrominance (class 1, table 1).
pub const STANDARD_DHT: [u8; 432] = [
    0xff, 0xc4, 0x00, 0x1f, 0x00, 0x00, 0x01, 0x05, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0a,
    0x0b, 0xff, 0xc4, 0x00, 0xb5, 0x10, 0x00, 0x02, 0x01, 0x03, 0x03, 0x02, 0x04, 0x03, 0x05, 0x05,
    0x04, 0x04, 0x00, 0x00, 0x01, 0x7d, 0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31,
    0x41, 0x06, 0x13, 0x51, 0x61, 0x07, 0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xa1, 0x08, 0x23, 0x42,
    0xb1, 0xc1, 0x15, 0x52, 0xd1, 0xf0, 0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0a, 0x16, 0x17, 0x18,
    0x19, 0x1a, 0x25, 0x26, 0x27, 0x28, 0x29, 0x2a, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43,
    0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63,
    0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x83,
    0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9a,
    0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8,
    0xb9, 0xba, 0xc2, 0xc3, 0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4, 0xd5, 0xd6,
    0xd7, 0xd8, 0xd9, 0xda, 0xe1, 0xe2, 0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf1, 0xf2,
    0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8, 0xf9, 0xfa, 0xff, 0xc4, 0x00, 0x1f, 0x01, 0x00, 0x03, 0x01,
    0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x01, 0x02,
    0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0a, 0x0b, 0xff, 0xc4, 0x00, 0xb5, 0x11, 0x00, 0x02,
    0x01, 0x02, 0x04, 0x04, 0x03, 0x04, 0x07, 0x05, 0x04, 0x04, 0x00, 0x01, 0x02, 0x77, 0x00, 0x01,
    0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61, 0x71, 0x13, 0x22,
    0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xa1, 0xb1, 0xc1, 0x09, 0x23, 0x33, 0x52, 0xf0, 0x15, 0x62,
    0x72, 0xd1, 0x0a, 0x16, 0x24, 0x34, 0xe1, 0x25, 0xf1, 0x17, 0x18, 0x19, 0x1a, 0x26, 0x27, 0x28,
    0x29, 0x2a, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4a,
    0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6a,
    0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89,
    0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9a, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7,
    0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3, 0xc4, 0xc5,
    0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda, 0xe2, 0xe3,
    0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8, 0xf9, 0xfa,
];

/// The JFIF APP0 segment the encoder writes in every image (version 1.2, no density units,
/// 1:1, no thumbnail): blobs with flag bit 3 store their JPEGs without it ([`strip_headers`]).
pub const JFIF_APP0: [u8; 18] = [
    0xff, 0xe0, 0x00, 0x10, b'J', b'F', b'I', b'F', 0x00, 0x01, 0x02, 0x00, 0x00, 0x01, 0x00, 0x01,
    0x00, 0x00,
];

/// The quantisation tables of ITU-T T.81 Annex K.1 (luminance, chrominance) in the zigzag
/// order of a DQT segment: the values at quality 50, which the encoder scales.
const ANNEX_K1: [[u8; 64]; 2] = [
    [
        16, 11, 12, 14, 12, 10, 16, 14, 13, 14, 18, 17, 16, 19, 24, 40, 26, 24, 22, 22, 24, 49, 35,
        37, 29, 40, 58, 51, 61, 60, 57, 51, 56, 55, 64, 72, 92, 78, 64, 68, 87, 69, 55, 56, 80,
        109, 81, 87, 95, 98, 103, 104, 103, 62, 77, 113, 121, 112, 100, 120, 92, 101, 103, 99,
    ],
    [
        17, 18, 18, 24, 21, 24, 47, 26, 26, 47, 99, 66, 56, 66, 99, 99, 99, 99, 99, 99, 99, 99, 99,
        99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99,
        99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99, 99,
    ],
];

/// Bytes of one DQT segment of [`standard_dqt`]: marker, length, table id, 64 values.
const DQT_SEGMENT: usize = 5 + 64;

/// Bytes of the two DQT segments of [`standard_dqt`].
pub const DQT_LEN: usize = 2 * DQT_SEGMENT;

/// The two DQT segments (luminance as table 0, chrominance as table 1) the encoder writes at
/// `quality` (1–100): each Annex K.1 value `b` scaled as the IJG library does, `(b·s + 50) /
/// 100` clamped to 1–255, with `s = 5000 / q` below quality 50 and `200 − 2q` from 50 on.
pub fn standard_dqt(quality: u8) -> [u8; DQT_LEN] {
    let q = u32::from(quality.clamp(1, 100));
    let scale = if q < 50 { 5000 / q } else { 200 - 2 * q };
    let mut out = [0u8; DQT_LEN];
    for (t, table) in ANNEX_K1.iter().enumerate() {
        let seg = &mut out[t * DQT_SEGMENT..(t + 1) * DQT_SEGMENT];
        seg[..5].copy_from_slice(&[0xff, 0xdb, 0x00, 0x43, t as u8]);
        for (o, &b) in seg[5..].iter_mut().zip(table) {
            *o = ((u32::from(b) * scale + 50) / 100).clamp(1, 255) as u8;
        }
    }
    out
}

/// `jpeg` (with or without its Huffman tables) without its JFIF APP0 segment and its
/// quantisation tables, when they are exactly [`JFIF_APP0`] right after SOI and
/// [`standard_dqt`] of some quality right after the frame header (SOF0), as the encoder
/// writes them: one byte, the quality, then SOI and the rest. `None` otherwise (the image is
/// then stored with them): 155 bytes less an image.
pub fn strip_headers(jpeg: &[u8]) -> Option<Vec<u8>> {
    if jpeg.get(..2)? != [0xFF, 0xD8] || jpeg.get(2..20)? != JFIF_APP0 {
        return None;
    }
    if jpeg.get(20..22)? != [0xFF, 0xC0] {
        return None;
    }
    let sof_end = 22 + usize::from(u16::from_be_bytes([*jpeg.get(22)?, *jpeg.get(23)?]));
    let tables = jpeg.get(sof_end..sof_end + DQT_LEN)?;
    let quality = (1..=100u8).find(|&q| standard_dqt(q)[..] == *tables)?;
    Some(
        [
            &[quality][..],
            &jpeg[..2],
            &jpeg[20..sof_end],
            &jpeg[sof_end + DQT_LEN..],
        ]
        .concat(),
    )
}

/// An image stored by [`strip_headers`] made whole again: SOI, [`JFIF_APP0`], the frame
/// header, [`standard_dqt`] of the stored quality, the rest (the bytes after the quality as
/// they are where they do not start with SOI and a frame header, or the quality is not 1–100:
/// a decoder then refuses them as it would have).
pub fn with_headers(stripped: &[u8]) -> Vec<u8> {
    let rest = stripped.get(1..).unwrap_or_default();
    let whole = || -> Option<Vec<u8>> {
        let quality = *stripped.first().filter(|q| (1..=100).contains(*q))?;
        if rest.get(..4)? != [0xFF, 0xD8, 0xFF, 0xC0] {
            return None;
        }
        let sof_end = 2 + 2 + usize::from(u16::from_be_bytes([*rest.get(4)?, *rest.get(5)?]));
        rest.get(sof_end..)?;
        Some(
            [
                &rest[..2],
                &JFIF_APP0[..],
                &rest[2..sof_end],
                &standard_dqt(quality)[..],
                &rest[sof_end..],
            ]
            .concat(),
        )
    };
    whole().unwrap_or_else(|| rest.to_vec())
}

/// `jpeg` without its DHT segments, when they are exactly [`STANDARD_DHT`], right before its
/// first scan header (SOS); `None` otherwise (the image is then stored whole).
pub fn strip_standard_huffman(jpeg: &[u8]) -> Option<Vec<u8>> {
    if jpeg.get(..2) != Some(&[0xFF, 0xD8][..]) {
        return None;
    }
    let sos = sos_offset(jpeg)?;
    let start = sos.checked_sub(STANDARD_DHT.len())?;
    if jpeg.get(start..sos)? != STANDARD_DHT {
        return None;
    }
    // No other DHT segment before the scan.
    if has_dht(&jpeg[..start]) {
        return None;
    }
    Some([&jpeg[..start], &jpeg[sos..]].concat())
}

/// Bytes of a JPEG before its entropy-coded data: up to the end of its first scan header (the
/// whole stream where it has none).
pub fn header_len(jpeg: &[u8]) -> usize {
    sos_offset(jpeg)
        .and_then(|at| {
            let len = usize::from(u16::from_be_bytes([*jpeg.get(at + 2)?, *jpeg.get(at + 3)?]));
            Some((at + 2 + len).min(jpeg.len()))
        })
        .unwrap_or(jpeg.len())
}

/// Where the first SOS marker of a JPEG starts (walking its marker segments from SOI).
fn sos_offset(jpeg: &[u8]) -> Option<usize> {
    if jpeg.get(..2) != Some(&[0xFF, 0xD8][..]) {
        return None;
    }
    let mut at = 2;
    loop {
        if *jpeg.get(at)? != 0xFF || at + 4 > jpeg.len() {
            return None;
        }
        if jpeg[at + 1] == 0xDA {
            return Some(at);
        }
        let len = usize::from(u16::from_be_bytes([jpeg[at + 2], jpeg[at + 3]]));
        at = at.checked_add(2 + len).filter(|&e| e <= jpeg.len())?;
    }
}

/// Whether the marker segments from SOI in `head` include a DHT.
fn has_dht(head: &[u8]) -> bool {
    segments(head.get(2..).unwrap_or_default()).any(|s| s.get(1) == Some(&0xC4))
}

/// A stripped image made whole: [`STANDARD_DHT`] right before its first SOS marker (the bytes
/// as they are where they have none: a decoder then refuses them as it would have).
pub fn with_standard_huffman(stripped: &[u8]) -> Vec<u8> {
    let Some(sos) = sos_offset(stripped) else {
        return stripped.to_vec();
    };
    [&stripped[..sos], &STANDARD_DHT[..], &stripped[sos..]].concat()
}

/// The marker segments of a run of them.
fn segments(bytes: &[u8]) -> impl Iterator<Item = &[u8]> {
    let mut at = 0;
    std::iter::from_fn(move || {
        let len = usize::from(u16::from_be_bytes([
            *bytes.get(at + 2)?,
            *bytes.get(at + 3)?,
        ]));
        let segment = bytes.get(at..at + 2 + len)?;
        at += 2 + len;
        Some(segment)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::atlas::{encode_jpeg, encode_normal_jpeg};
    use crate::mesh::Texture;

    #[test]
    fn the_tables_are_annex_k_and_strip_and_restore_exactly() {
        // Annex K.3.3.1/2: the code length counts of the DC and AC luminance tables.
        let segs: Vec<&[u8]> = segments(&STANDARD_DHT).collect();
        assert_eq!(segs.len(), 4);
        assert_eq!(
            &segs[0][5..21],
            &[0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            &segs[1][5..21],
            &[0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7d]
        );
        assert_eq!(
            &segs[2][5..21],
            &[0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            &segs[3][5..21],
            &[0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77]
        );
        let texels: Vec<[u8; 4]> = (0..40 * 24)
            .map(|i| {
                [
                    (i * 7 % 251) as u8,
                    (i % 40 * 6) as u8,
                    (i / 40 * 10) as u8,
                    255,
                ]
            })
            .collect();
        let image = Texture::from_texels(40, 24, texels).expect("an image");
        for jpeg in [encode_jpeg(&image, 85), encode_normal_jpeg(&image, 90)] {
            let stripped = strip_standard_huffman(&jpeg).expect("standard tables");
            assert_eq!(stripped.len() + STANDARD_DHT.len(), jpeg.len());
            assert_eq!(with_standard_huffman(&stripped), jpeg);
            assert!(Texture::decode(&with_standard_huffman(&stripped)).is_ok());
            // The header ends where the scan's data starts.
            let header = header_len(&jpeg);
            assert!(header > STANDARD_DHT.len() && header < jpeg.len());
            assert_eq!(header_len(&stripped), header - STANDARD_DHT.len());
            // Stripped twice: no tables left to strip.
            assert!(strip_standard_huffman(&stripped).is_none());
        }
        // Other tables, or not a JPEG: kept whole.
        let mut other = encode_jpeg(&image, 85);
        let at = other
            .windows(2)
            .position(|w| w == [0xFF, 0xC4])
            .expect("a DHT")
            + 6;
        other[at] ^= 1;
        assert!(strip_standard_huffman(&other).is_none());
        assert!(strip_standard_huffman(b"not a jpeg").is_none());
        assert!(strip_standard_huffman(&[0xFF, 0xD8, 0xFF]).is_none());
        assert_eq!(with_standard_huffman(b"xy"), b"xy");
    }

    #[test]
    fn headers_strip_and_restore_exactly_at_every_quality() {
        let texels: Vec<[u8; 4]> = (0..24 * 16)
            .map(|i| [(i * 13 % 256) as u8, (i % 24 * 9) as u8, 40, 255])
            .collect();
        let image = Texture::from_texels(24, 16, texels).expect("an image");
        let saved = JFIF_APP0.len() + DQT_LEN - 1;
        for quality in 1..=100u8 {
            for jpeg in [
                encode_jpeg(&image, quality),
                encode_normal_jpeg(&image, quality),
            ] {
                // Whole, and after the Huffman tables went: the quality is found, and the
                // bytes come back as encoded.
                let huffman = strip_standard_huffman(&jpeg).expect("standard tables");
                for bytes in [&jpeg, &huffman] {
                    let stripped = strip_headers(bytes).expect("standard headers");
                    assert_eq!(stripped[0], quality);
                    assert_eq!(stripped.len() + saved, bytes.len());
                    assert_eq!(&with_headers(&stripped), bytes);
                    assert!(strip_headers(&stripped[1..]).is_none());
                }
                let both = with_standard_huffman(&with_headers(
                    &strip_headers(&huffman).expect("standard headers"),
                ));
                assert_eq!(both, jpeg);
                assert!(Texture::decode(&both).is_ok());
            }
        }
        // Tables other than the standard ones at some quality, or no JFIF segment: kept.
        let jpeg = encode_jpeg(&image, 85);
        let sof_end = 22 + usize::from(u16::from_be_bytes([jpeg[22], jpeg[23]]));
        let mut other = jpeg.clone();
        other[sof_end + 5 + 10] ^= 1;
        assert!(strip_headers(&other).is_none());
        let mut no_jfif = jpeg.clone();
        no_jfif[6] = b'X';
        assert!(strip_headers(&no_jfif).is_none());
        assert!(strip_headers(b"not a jpeg").is_none());
        assert!(strip_headers(&jpeg[..30]).is_none());
        // What does not restore is given back as it is (the image decoder refuses it).
        assert_eq!(with_headers(&[0, 0xFF, 0xD8]), [0xFF, 0xD8]);
        assert_eq!(with_headers(&[85, 1, 2]), [1, 2]);
        assert!(with_headers(&[]).is_empty());
    }
}
