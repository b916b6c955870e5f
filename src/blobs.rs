//! The content-addressed file store: `attachments/ab/cdef...` named by the SHA-256 of the
//! bytes. Files are written to a temporary name in `uploads/`, synced, then renamed, so a
//! file under its final name is always complete.

use std::io::Write;

use crate::config::Settings;
use crate::uploads::TempUpload;

/// Moves a complete temporary file to its content address (or drops it when that file is
/// already there), then syncs the directory so the rename survives a crash.
pub fn commit_temp(settings: &Settings, tmp: TempUpload, sha256: &str) -> std::io::Result<()> {
    let dest = settings.attachment_path(sha256).ok_or_else(|| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, "malformed SHA-256")
    })?;
    if dest.exists() {
        return tmp.remove();
    }
    let dir = dest
        .parent()
        .ok_or_else(|| std::io::Error::other("attachment path without parent"))?;
    std::fs::create_dir_all(dir)?;
    tmp.persist(&dest)?;
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Stores `bytes`; returns their SHA-256 (hex).
pub fn write_bytes(settings: &Settings, bytes: &[u8]) -> std::io::Result<String> {
    let sha256 = crate::sha256_hex(bytes);
    std::fs::create_dir_all(settings.uploads_dir())?;
    let tmp = TempUpload::new(&settings.uploads_dir());
    let mut f = std::fs::File::create(tmp.path())?;
    f.write_all(bytes)?;
    f.sync_all()?;
    drop(f);
    commit_temp(settings, tmp, &sha256)?;
    Ok(sha256)
}
