//! Entry points of the coverage-guided fuzz targets (`fuzz/`): the server's parsers of request
//! headers and query strings on arbitrary bytes, with the same oracles as their mutation tests
//! (a violated contract panics, which libFuzzer reports).

use crate::config::RenderSettings;

/// `Range` against a body length: the first 8 bytes (little-endian) are the length, the rest
/// the header value.
pub fn range(data: &[u8]) {
    let Some((len, value)) = data.split_first_chunk::<8>() else {
        return;
    };
    let _ = super::lod::checked_range(&String::from_utf8_lossy(value), u64::from_le_bytes(*len));
}

/// A render query string, parsed for every render route under the default limits.
pub fn render_query(data: &[u8]) {
    let _ =
        super::render::checked_query(&String::from_utf8_lossy(data), &RenderSettings::default());
}
