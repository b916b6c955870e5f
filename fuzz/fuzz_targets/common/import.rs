//! Shared body of the importer targets: `bytes` written as `case.<ext>` (with `companions`,
//! files the scan refers to, beside it) and imported. Any result but a panic (or a hang, or
//! an allocation past libFuzzer's -rss_limit_mb) is fine; an accepted mesh must be well formed.

use meshwiki_engine::mesh;

/// Imports `bytes` as a scan with extension `ext`.
pub fn import(ext: &str, bytes: &[u8], companions: &[(&str, &[u8])]) {
    let dir = std::env::temp_dir().join(format!("meshwiki-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    for (name, data) in companions {
        if std::fs::write(dir.join(name), data).is_err() {
            return;
        }
    }
    let path = dir.join(format!("case.{ext}"));
    if std::fs::write(&path, bytes).is_err() {
        return;
    }
    if let Ok((m, _)) = mesh::load(&path) {
        let n = m.positions.len() as u32;
        assert!(
            m.indices.iter().all(|&i| i < n),
            "index out of range accepted"
        );
        assert!(m.indices.len() % 3 == 0);
        assert!(m.positions.iter().flatten().all(|c| c.is_finite()));
    }
}
