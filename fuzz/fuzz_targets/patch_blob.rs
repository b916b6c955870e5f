//! The patch codec on arbitrary blobs (no checksum in the way), with a patch budget as files
//! declare it.
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshwiki_engine::lod::codec::{Grid, decode_limited};

fuzz_target!(|data: &[u8]| {
    let grid = Grid {
        origin: [0.0; 3],
        step: 1e-3,
    };
    if let Ok(p) = decode_limited(data, &grid, 4096) {
        let n = p.positions.len() as u32;
        assert!(p.indices.iter().all(|&i| i < n));
        assert!(p.original_ids.len() == p.positions.len());
    }
});
