//! The stroke-mask PNG decoder on arbitrary bytes (PNG bombs included).
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshwiki_engine::select::mask::StrokeMask;

fuzz_target!(|data: &[u8]| {
    if let Ok(m) = StrokeMask::decode_png(data) {
        assert!((0..=4).map(|l| m.count(l)).sum::<usize>() == m.labels.len());
    }
});
