//! Temporary files in `uploads/`: uploads being received, attachment bytes before their rename to
//! a content address. Each is named `<random>.tmp-<pid>` and held by a [`TempUpload`] guard that
//! removes it when dropped (a failed or abandoned request) unless it was persisted (renamed to
//! where it belongs). The guard also registers the file as in flight, so [`sweep`] can tell:
//!
//! * files of a process that is no longer running (a crash, `kill -9`, a power cut) are removed
//!   at once, on start-up and periodically while running;
//! * files of this process that no guard holds (none should exist) are removed too;
//! * files being written by a live process (this one or another server on the same data
//!   directory) are never touched.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, OnceLock};
use std::time::Duration;

/// Temporary files of earlier versions (`<random>.tmp`, no pid) are removed past this age.
pub const LEGACY_TMP_AGE: Duration = Duration::from_secs(60);

fn live() -> MutexGuard<'static, HashSet<PathBuf>> {
    static LIVE: OnceLock<Mutex<HashSet<PathBuf>>> = OnceLock::new();
    LIVE.get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|p| p.into_inner())
}

/// A temporary file in an uploads directory, removed on drop unless persisted.
#[derive(Debug)]
pub struct TempUpload {
    path: Option<PathBuf>,
}

impl TempUpload {
    /// Reserves a new temporary name in `dir` (the file itself is created by the caller).
    pub fn new(dir: &Path) -> TempUpload {
        let path = dir.join(format!(
            "{}.tmp-{}",
            crate::random_hex(16),
            std::process::id()
        ));
        live().insert(path.clone());
        TempUpload { path: Some(path) }
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        self.path.as_deref().unwrap_or(Path::new(""))
    }

    /// Renames the file to `dest` (same file system) and lets it go: it is no longer temporary.
    pub fn persist(mut self, dest: &Path) -> std::io::Result<()> {
        let path = self.path.take().unwrap_or_default();
        let result = std::fs::rename(&path, dest);
        if result.is_err() {
            let _ = std::fs::remove_file(&path);
        }
        live().remove(&path);
        result
    }

    /// Removes the file now (as dropping does), reporting a failure other than "not found".
    pub fn remove(mut self) -> std::io::Result<()> {
        let path = self.path.take().unwrap_or_default();
        let result = match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
            _ => Ok(()),
        };
        live().remove(&path);
        result
    }
}

impl Drop for TempUpload {
    fn drop(&mut self) {
        if let Some(p) = self.path.take() {
            let _ = std::fs::remove_file(&p);
            live().remove(&p);
        }
    }
}

/// The pid in a temporary file's name (`<random>.tmp-<pid>`).
pub fn temp_pid(name: &str) -> Option<i64> {
    let (_, pid) = name.rsplit_once(".tmp-")?;
    pid.parse().ok()
}

/// Removes temporary files in `dir` that no running process is writing; returns them.
/// `alive(pid)` tells whether a process runs.
pub fn sweep(dir: &Path, alive: &dyn Fn(i64) -> bool) -> Vec<PathBuf> {
    let mut removed = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return removed;
    };
    let me = std::process::id() as i64;
    for entry in entries.flatten() {
        if !entry.file_type().is_ok_and(|t| t.is_file()) {
            continue;
        }
        let name = entry.file_name().to_string_lossy().into_owned();
        let path = entry.path();
        let stale = match temp_pid(&name) {
            Some(pid) if pid == me => !live().contains(&path),
            Some(pid) => !alive(pid),
            None => {
                name.ends_with(".tmp")
                    && entry
                        .metadata()
                        .and_then(|m| m.modified())
                        .ok()
                        .and_then(|t| t.elapsed().ok())
                        .is_some_and(|age| age > LEGACY_TMP_AGE)
            }
        };
        if !stale {
            continue;
        }
        match std::fs::remove_file(&path) {
            Ok(()) => removed.push(path),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!(path = %path.display(), error = %e, "cannot remove"),
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweep_removes_what_no_live_process_writes() {
        let dir = tempfile::tempdir().expect("tempdir");
        let held = TempUpload::new(dir.path());
        std::fs::write(held.path(), b"in flight").expect("write");
        let dead = dir.path().join("abc.tmp-999999999");
        std::fs::write(&dead, b"left by a crash").expect("write");
        let other_live = dir.path().join("def.tmp-1");
        std::fs::write(&other_live, b"another server").expect("write");
        let unheld = dir.path().join(format!("0123.tmp-{}", std::process::id()));
        std::fs::write(&unheld, b"leaked").expect("write");
        let fresh_legacy = dir.path().join("0123.tmp");
        std::fs::write(&fresh_legacy, b"legacy").expect("write");
        let source = dir.path().join("src-0123.ply");
        std::fs::write(&source, b"queued scan").expect("write");

        let removed = sweep(dir.path(), &|pid| pid == 1);
        let mut removed: Vec<_> = removed.iter().map(|p| p.to_path_buf()).collect();
        removed.sort();
        let mut expected = vec![dead.clone(), unheld.clone()];
        expected.sort();
        assert_eq!(removed, expected);
        assert!(held.path().exists() && other_live.exists());
        assert!(fresh_legacy.exists() && source.exists());

        let kept = dir.path().join("kept.bin");
        let path = held.path().to_path_buf();
        held.persist(&kept).expect("persist");
        assert!(kept.exists() && !path.exists());
        assert!(sweep(dir.path(), &|pid| pid == 1).is_empty());

        let dropped = TempUpload::new(dir.path());
        std::fs::write(dropped.path(), b"abandoned").expect("write");
        let path = dropped.path().to_path_buf();
        drop(dropped);
        assert!(!path.exists());
    }
}
