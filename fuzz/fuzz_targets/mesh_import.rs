//! The scan importers on arbitrary bytes: the first byte picks the format (PLY, OBJ, glTF, GLB,
//! STL, OFF), the rest is the file. Any result but a panic (or a hang, or an allocation past
//! libFuzzer's -rss_limit_mb) is fine; an accepted mesh must be well formed.
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshwiki_engine::mesh;
use std::io::Write;

const EXTENSIONS: [&str; 6] = ["ply", "obj", "gltf", "glb", "stl", "off"];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let ext = EXTENSIONS[pick as usize % EXTENSIONS.len()];
    let dir = std::env::temp_dir().join(format!("meshwiki-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(format!("case.{ext}"));
    let Ok(mut f) = std::fs::File::create(&path) else {
        return;
    };
    if f.write_all(bytes).is_err() {
        return;
    }
    drop(f);
    if let Ok((m, _)) = mesh::load(&path) {
        let n = m.positions.len() as u32;
        assert!(
            m.indices.iter().all(|&i| i < n),
            "index out of range accepted"
        );
        assert!(m.indices.len() % 3 == 0);
        assert!(m.positions.iter().flatten().all(|c| c.is_finite()));
    }
});
