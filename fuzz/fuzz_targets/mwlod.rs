//! The `.mwlod` reader on arbitrary files: open (header, tables, links), decode every patch,
//! cut and export at a few errors.
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshwiki_engine::lod::{self, LodFile};

fuzz_target!(|data: &[u8]| {
    let dir = std::env::temp_dir().join(format!("meshwiki-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("case.mwlod");
    if std::fs::write(&path, data).is_err() {
        return;
    }
    let Ok(file) = LodFile::open(&path) else {
        return;
    };
    for node in 0..file.nodes().len() as u32 {
        if let Ok(p) = file.patch(node) {
            let n = p.positions.len() as u32;
            assert!(p.indices.iter().all(|&i| i < n));
        }
    }
    for e in [0.0f32, 1e-3, f32::INFINITY] {
        let cut = lod::cut_uniform(file.nodes(), e);
        let _ = lod::export_cut(&file, &cut);
    }
});
