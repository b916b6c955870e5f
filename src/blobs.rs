//! The content-addressed file stores: `attachments/ab/cdef...` (attachments) and
//! `lumigraph/ab/cdef...` (image repositories), each file named by the SHA-256 of its bytes.
//! Files are written to a temporary name in `uploads/`, synced, then renamed, so a file under
//! its final name is always complete. A later object-store backend takes the same
//! `(bucket, SHA-256)` keys.

use std::collections::HashSet;
use std::io::Write;
use std::path::PathBuf;

use crate::config::Settings;
use crate::uploads::TempUpload;

/// Moves a complete temporary file to its content address (or drops it when that file is
/// already there), then syncs the directory so the rename survives a crash.
pub fn commit_temp(settings: &Settings, tmp: TempUpload, sha256: &str) -> std::io::Result<()> {
    commit_temp_to(settings, Bucket::Attachments, tmp, sha256)
}

/// Which store a blob lives in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Bucket {
    /// Attachments (files, images, thumbnails).
    Attachments,
    /// Images of the Grid-Lumigraph repositories.
    Lumigraph,
}

/// Where blob `sha256` of `bucket` lives (`None` for a malformed SHA-256).
pub fn path(settings: &Settings, bucket: Bucket, sha256: &str) -> Option<PathBuf> {
    match bucket {
        Bucket::Attachments => settings.attachment_path(sha256),
        Bucket::Lumigraph => settings.lumigraph_path(sha256),
    }
}

/// [`commit_temp`] into `bucket`.
fn commit_temp_to(
    settings: &Settings,
    bucket: Bucket,
    tmp: TempUpload,
    sha256: &str,
) -> std::io::Result<()> {
    let dest = path(settings, bucket, sha256).ok_or_else(|| {
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

/// Stores `bytes` as an attachment; returns their SHA-256 (hex).
pub fn write_bytes(settings: &Settings, bytes: &[u8]) -> std::io::Result<String> {
    write_bytes_to(settings, Bucket::Attachments, bytes)
}

/// Removes the blobs of `bucket` whose SHA-256 is not in `used` (what a deleted or rebuilt
/// repository left), and stray files of its tree; returns what was removed.
pub fn remove_unused(
    settings: &Settings,
    bucket: Bucket,
    used: &HashSet<String>,
) -> std::io::Result<Vec<PathBuf>> {
    let root = match bucket {
        Bucket::Attachments => settings.attachments_dir(),
        Bucket::Lumigraph => settings.lumigraph_dir(),
    };
    let mut removed = Vec::new();
    let Ok(dirs) = std::fs::read_dir(&root) else {
        return Ok(removed);
    };
    for dir in dirs.flatten() {
        let prefix = dir.file_name().to_string_lossy().into_owned();
        let Ok(files) = std::fs::read_dir(dir.path()) else {
            continue;
        };
        for f in files.flatten() {
            let sha = format!("{prefix}{}", f.file_name().to_string_lossy());
            if !used.contains(&sha) && f.file_type().is_ok_and(|t| t.is_file()) {
                std::fs::remove_file(f.path())?;
                removed.push(f.path());
            }
        }
    }
    Ok(removed)
}

/// Stores `bytes` in `bucket`; returns their SHA-256 (hex).
pub fn write_bytes_to(
    settings: &Settings,
    bucket: Bucket,
    bytes: &[u8],
) -> std::io::Result<String> {
    let sha256 = crate::sha256_hex(bytes);
    std::fs::create_dir_all(settings.uploads_dir())?;
    let tmp = TempUpload::new(&settings.uploads_dir());
    let mut f = std::fs::File::create(tmp.path())?;
    f.write_all(bytes)?;
    f.sync_all()?;
    drop(f);
    commit_temp_to(settings, bucket, tmp, &sha256)?;
    Ok(sha256)
}

/// Removes blobs `shas` of `bucket` (those the caller found no longer used).
pub fn remove(settings: &Settings, bucket: Bucket, shas: &[String]) {
    for sha in shas {
        if let Some(p) = path(settings, bucket, sha) {
            let _ = std::fs::remove_file(p);
        }
    }
}
