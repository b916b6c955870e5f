//! Resumable uploads (the core of the tus protocol, in this API's own terms): an upload
//! session names its files and their sizes up front; each file is then sent in chunks, each
//! appended at the offset the server holds and synced to disk before it is acknowledged, so an
//! interrupted transfer (a dropped connection, a laptop closed, a server restarted or killed)
//! resumes from the last acknowledged byte instead of from zero. A complete session is taken
//! by the build as one scan with the files it refers to ([`Sessions::take`]).
//!
//! On disk, under `uploads/sessions/<id>/`: `manifest.json` (owner, files, creation time;
//! written under a temporary name and renamed) and `<index>.part` per file. A session idle for
//! longer than its lifetime is removed on start-up and by the periodic sweep ([`Sessions::sweep`]).
//! Within one process, a file takes one writer at a time (a second gets [`SessionError::Busy`]).

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime};

use futures_util::{Stream, StreamExt};
use serde::{Deserialize, Serialize};
use tokio::io::AsyncWriteExt;

/// How long a session may stay idle (no chunk received) before it is removed.
pub const SESSION_LIFETIME: Duration = Duration::from_secs(24 * 3600);
/// Sessions one user may have open at a time.
pub const MAX_SESSIONS_PER_USER: usize = 8;
/// Folder of the sessions inside the uploads directory.
const SESSIONS_DIR: &str = "sessions";
const MANIFEST: &str = "manifest.json";

/// One file of a session: its relative path (as the scan refers to it) and its size.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SessionFile {
    /// Relative path (already checked by the caller, e.g. `jobs::companion_path`).
    pub path: String,
    /// Size in bytes.
    pub size: u64,
}

/// What is kept of a session on disk.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Manifest {
    owner: i64,
    created_at: String,
    files: Vec<SessionFile>,
}

/// A file's state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileState {
    /// Relative path.
    pub path: String,
    /// Declared size.
    pub size: u64,
    /// Bytes received and synced.
    pub received: u64,
}

/// A session's state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionState {
    /// The session id (32 hex digits).
    pub id: String,
    /// When it was created (RFC 3339).
    pub created_at: String,
    /// Its files, in the order declared.
    pub files: Vec<FileState>,
    /// When it is removed if nothing more arrives (RFC 3339).
    pub expires_at: String,
}

impl SessionState {
    /// Whether every file is complete.
    pub fn complete(&self) -> bool {
        self.files.iter().all(|f| f.received == f.size)
    }
}

/// A complete session taken for a build: its files on disk. The session folder is removed
/// when this is dropped (the caller moves the files out first).
#[derive(Debug)]
pub struct Taken {
    dir: PathBuf,
    /// (relative path, file on disk, size), in the order declared.
    pub files: Vec<(String, PathBuf, u64)>,
    _lock: FileLock,
}

impl Drop for Taken {
    fn drop(&mut self) {
        if let Err(e) = crate::remove_file_or_dir(&self.dir)
            && e.kind() != std::io::ErrorKind::NotFound
        {
            tracing::warn!(path = %self.dir.display(), error = %e, "cannot remove an upload session");
        }
    }
}

/// Why a session request failed.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// No such session (or not the caller's).
    #[error("no upload session {0}")]
    NotFound(String),
    /// Bad input.
    #[error("{0}")]
    Invalid(String),
    /// A chunk at another offset than the server holds.
    #[error("file {index} of the upload holds {offset} bytes: send from there")]
    Offset {
        /// The file.
        index: usize,
        /// Bytes the server holds.
        offset: u64,
    },
    /// More bytes than declared, or beyond a limit.
    #[error("{0}")]
    TooLarge(String),
    /// Another request writes this file (or takes the session) now.
    #[error("another request is writing to this upload now: retry when it has ended")]
    Busy,
    /// Taking a session whose files are not all complete.
    #[error("the upload is not complete: {0}")]
    Incomplete(String),
    /// A file operation failed.
    #[error("upload storage: {0}")]
    Io(#[from] std::io::Error),
}

/// (session, file) pairs in use: `None` for the whole session.
type Held = Arc<Mutex<HashSet<(String, Option<usize>)>>>;

/// Exclusive use of a session's file (`Some(index)`) or of the whole session (`None`).
#[derive(Debug)]
struct FileLock {
    held: Held,
    key: (String, Option<usize>),
}

impl Drop for FileLock {
    fn drop(&mut self) {
        lock(&self.held).remove(&self.key);
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The upload sessions of a data directory.
#[derive(Debug, Clone)]
pub struct Sessions {
    root: PathBuf,
    lifetime: Duration,
    held: Held,
}

/// Whether `id` has the shape of a session id (so it can name a folder).
fn valid_id(id: &str) -> bool {
    id.len() == 32 && id.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

fn rfc3339(t: SystemTime) -> String {
    let t = time::OffsetDateTime::from(t);
    let format = time::macros::format_description!(
        "[year]-[month]-[day]T[hour]:[minute]:[second].[subsecond digits:3]Z"
    );
    t.format(&format).unwrap_or_default()
}

impl Sessions {
    /// The sessions kept under `uploads_dir`, removed after `lifetime` without a chunk.
    pub fn new(uploads_dir: &Path, lifetime: Duration) -> Sessions {
        Sessions {
            root: uploads_dir.join(SESSIONS_DIR),
            lifetime,
            held: Arc::default(),
        }
    }

    fn dir(&self, id: &str) -> PathBuf {
        self.root.join(id)
    }

    fn part(&self, id: &str, index: usize) -> PathBuf {
        self.dir(id).join(format!("{index}.part"))
    }

    fn acquire(&self, id: &str, index: Option<usize>) -> Result<FileLock, SessionError> {
        let mut held = lock(&self.held);
        // The whole session conflicts with each of its files, and the other way round.
        let busy = held
            .iter()
            .any(|(s, i)| s == id && (index.is_none() || i.is_none() || *i == index));
        if busy {
            return Err(SessionError::Busy);
        }
        let key = (id.to_string(), index);
        held.insert(key.clone());
        Ok(FileLock {
            held: self.held.clone(),
            key,
        })
    }

    /// Reads a session's manifest, checking its owner (another user's session is not found).
    async fn manifest(&self, id: &str, owner: i64) -> Result<Manifest, SessionError> {
        let not_found = || SessionError::NotFound(id.chars().take(40).collect());
        if !valid_id(id) {
            return Err(not_found());
        }
        let text = match tokio::fs::read(self.dir(id).join(MANIFEST)).await {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err(not_found()),
            Err(e) => return Err(e.into()),
        };
        let m: Manifest = serde_json::from_slice(&text)
            .map_err(|e| std::io::Error::other(format!("damaged upload manifest: {e}")))?;
        if m.owner != owner {
            return Err(not_found());
        }
        Ok(m)
    }

    /// Opens a session for `files` (at least one, sizes summing to at most `limit`) owned by
    /// `owner`.
    pub async fn create(
        &self,
        owner: i64,
        files: Vec<SessionFile>,
        limit: u64,
    ) -> Result<SessionState, SessionError> {
        if files.is_empty() {
            return Err(SessionError::Invalid(
                "an upload needs at least one file".into(),
            ));
        }
        let mut seen = HashSet::new();
        for f in &files {
            if !seen.insert(f.path.as_str()) {
                return Err(SessionError::Invalid(format!("{} is listed twice", f.path)));
            }
        }
        let total = files
            .iter()
            .try_fold(0u64, |acc, f| acc.checked_add(f.size))
            .unwrap_or(u64::MAX);
        if total > limit {
            return Err(SessionError::TooLarge(format!(
                "the files hold {total} bytes, more than the limit of {limit} bytes"
            )));
        }
        if self.count_owned(owner).await? >= MAX_SESSIONS_PER_USER {
            return Err(SessionError::Invalid(format!(
                "at most {MAX_SESSIONS_PER_USER} uploads may be open at a time: finish or cancel one"
            )));
        }
        let id = crate::random_hex(16);
        let dir = self.dir(&id);
        tokio::fs::create_dir_all(&dir).await?;
        let manifest = Manifest {
            owner,
            created_at: crate::now_rfc3339(),
            files,
        };
        let written = async {
            for index in 0..manifest.files.len() {
                tokio::fs::File::create(self.part(&id, index)).await?;
            }
            let tmp = dir.join(format!("{MANIFEST}.tmp"));
            let json = serde_json::to_vec(&manifest).map_err(std::io::Error::other)?;
            let mut f = tokio::fs::File::create(&tmp).await?;
            f.write_all(&json).await?;
            f.sync_all().await?;
            tokio::fs::rename(&tmp, dir.join(MANIFEST)).await
        }
        .await;
        if let Err(e) = written {
            let _ = tokio::fs::remove_dir_all(&dir).await;
            return Err(e.into());
        }
        tracing::info!(session = %id, owner, files = manifest.files.len(), bytes = total, "upload session opened");
        self.state(&id, &manifest).await
    }

    async fn count_owned(&self, owner: i64) -> Result<usize, SessionError> {
        let mut n = 0;
        let mut entries = match tokio::fs::read_dir(&self.root).await {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
            Err(e) => return Err(e.into()),
        };
        while let Some(entry) = entries.next_entry().await? {
            let name = entry.file_name().to_string_lossy().into_owned();
            if valid_id(&name) && self.manifest(&name, owner).await.is_ok() {
                n += 1;
            }
        }
        Ok(n)
    }

    /// The state of the session as the files on disk tell.
    async fn state(&self, id: &str, m: &Manifest) -> Result<SessionState, SessionError> {
        let mut files = Vec::with_capacity(m.files.len());
        let mut last = None::<SystemTime>;
        for (index, f) in m.files.iter().enumerate() {
            let meta = tokio::fs::metadata(self.part(id, index)).await?;
            last = last.max(meta.modified().ok());
            files.push(FileState {
                path: f.path.clone(),
                size: f.size,
                received: meta.len().min(f.size),
            });
        }
        let touched = last.unwrap_or_else(SystemTime::now);
        Ok(SessionState {
            id: id.to_string(),
            created_at: m.created_at.clone(),
            files,
            expires_at: rfc3339(touched + self.lifetime),
        })
    }

    /// The session's state (what to resume from).
    pub async fn status(&self, id: &str, owner: i64) -> Result<SessionState, SessionError> {
        let m = self.manifest(id, owner).await?;
        self.state(id, &m).await
    }

    /// Appends `body` to file `index` of session `id`, which must hold exactly `offset` bytes
    /// now; returns the bytes held after. What arrives before the body breaks off is kept
    /// (synced), so the client resumes from there; a body that would run past the declared
    /// size is refused whole.
    pub async fn append<S, E>(
        &self,
        id: &str,
        owner: i64,
        index: usize,
        offset: u64,
        mut body: S,
    ) -> Result<u64, SessionError>
    where
        S: Stream<Item = Result<bytes::Bytes, E>> + Unpin,
        E: std::fmt::Display,
    {
        let m = self.manifest(id, owner).await?;
        let Some(file) = m.files.get(index) else {
            return Err(SessionError::NotFound(format!("{id}, file {index}")));
        };
        let _lock = self.acquire(id, Some(index))?;
        let path = self.part(id, index);
        let held = match tokio::fs::metadata(&path).await {
            Ok(meta) => meta.len(),
            // Taken (or removed) meanwhile.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(SessionError::NotFound(id.to_string()));
            }
            Err(e) => return Err(e.into()),
        };
        if held != offset {
            return Err(SessionError::Offset {
                index,
                offset: held,
            });
        }
        let out = tokio::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .await?;
        let mut out = tokio::io::BufWriter::with_capacity(1 << 20, out);
        let mut at = held;
        let mut broke = None;
        while let Some(chunk) = body.next().await {
            let chunk = match chunk {
                Ok(c) => c,
                Err(e) => {
                    broke = Some(e.to_string());
                    break;
                }
            };
            if at + chunk.len() as u64 > file.size {
                drop(out);
                // Refused whole: back to what was held before this request.
                let f = tokio::fs::OpenOptions::new()
                    .write(true)
                    .open(&path)
                    .await?;
                f.set_len(held).await?;
                f.sync_all().await?;
                return Err(SessionError::TooLarge(format!(
                    "{} is declared as {} bytes: this chunk goes beyond",
                    file.path, file.size
                )));
            }
            out.write_all(&chunk).await?;
            at += chunk.len() as u64;
        }
        out.flush().await?;
        out.get_mut().sync_data().await?;
        if let Some(why) = broke {
            tracing::info!(session = %id, index, kept = at, "upload chunk broke off: {why}");
            return Err(SessionError::Invalid(format!(
                "the chunk broke off after {} bytes ({why}): resume from offset {at}",
                at - held
            )));
        }
        Ok(at)
    }

    /// Takes a complete session for its build: its files stay on disk until the returned
    /// [`Taken`] is dropped (move them out before); no chunk is accepted meanwhile.
    pub async fn take(&self, id: &str, owner: i64) -> Result<Taken, SessionError> {
        let m = self.manifest(id, owner).await?;
        let lock = self.acquire(id, None)?;
        let state = self.state(id, &m).await?;
        if let Some(f) = state.files.iter().find(|f| f.received != f.size) {
            return Err(SessionError::Incomplete(format!(
                "{} holds {} of {} bytes",
                f.path, f.received, f.size
            )));
        }
        Ok(Taken {
            dir: self.dir(id),
            files: m
                .files
                .iter()
                .enumerate()
                .map(|(i, f)| (f.path.clone(), self.part(id, i), f.size))
                .collect(),
            _lock: lock,
        })
    }

    /// Cancels a session: its files are removed.
    pub async fn remove(&self, id: &str, owner: i64) -> Result<(), SessionError> {
        self.manifest(id, owner).await?;
        let _lock = self.acquire(id, None)?;
        let dir = self.dir(id);
        tokio::task::spawn_blocking(move || crate::remove_file_or_dir(&dir))
            .await
            .map_err(std::io::Error::other)??;
        tracing::info!(session = %id, "upload session cancelled");
        Ok(())
    }

    /// Removes the sessions idle for longer than the lifetime (and folders that are no
    /// session: a crash between creating the folder and writing its manifest); returns them.
    pub fn sweep(&self) -> Vec<PathBuf> {
        let mut removed = Vec::new();
        let Ok(entries) = std::fs::read_dir(&self.root) else {
            return removed;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            let name = entry.file_name().to_string_lossy().into_owned();
            if valid_id(&name) && lock(&self.held).iter().any(|(s, _)| *s == name) {
                continue;
            }
            // The newest modification inside (a chunk written), else the folder's.
            let newest = std::fs::read_dir(&path)
                .into_iter()
                .flatten()
                .flatten()
                .filter_map(|e| e.metadata().ok()?.modified().ok())
                .chain(entry.metadata().ok().and_then(|m| m.modified().ok()))
                .max();
            let idle = newest
                .and_then(|t| t.elapsed().ok())
                .is_some_and(|age| age > self.lifetime);
            let has_manifest = path.join(MANIFEST).is_file();
            let broken = !valid_id(&name) || !has_manifest;
            // A folder without manifest may be one being created right now: give it a minute.
            let stale = idle
                || (broken
                    && newest
                        .and_then(|t| t.elapsed().ok())
                        .is_some_and(|age| age > Duration::from_secs(60)));
            if !stale {
                continue;
            }
            match crate::remove_file_or_dir(&path) {
                Ok(()) => removed.push(path),
                Err(e) => tracing::warn!(path = %path.display(), error = %e, "cannot remove"),
            }
        }
        removed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(chunks: &[&[u8]]) -> impl Stream<Item = Result<bytes::Bytes, String>> + Unpin {
        futures_util::stream::iter(
            chunks
                .iter()
                .map(|c| Ok(bytes::Bytes::copy_from_slice(c)))
                .collect::<Vec<_>>(),
        )
    }

    fn files() -> Vec<SessionFile> {
        vec![
            SessionFile {
                path: "scan.gltf".into(),
                size: 10,
            },
            SessionFile {
                path: "scan.bin".into(),
                size: 4,
            },
        ]
    }

    #[tokio::test]
    async fn chunks_resume_from_what_is_held() {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = Sessions::new(dir.path(), SESSION_LIFETIME);
        let st = s.create(7, files(), 100).await.expect("create");
        assert_eq!(st.files.iter().map(|f| f.received).sum::<u64>(), 0);
        assert!(!st.complete());
        // Another user does not see it.
        assert!(matches!(
            s.status(&st.id, 8).await,
            Err(SessionError::NotFound(_))
        ));
        assert_eq!(
            s.append(&st.id, 7, 0, 0, body(&[b"0123", b"45"]))
                .await
                .expect("append"),
            6
        );
        // A chunk sent again from an old offset is refused with the held offset.
        match s.append(&st.id, 7, 0, 0, body(&[b"0123"])).await {
            Err(SessionError::Offset {
                index: 0,
                offset: 6,
            }) => {}
            other => panic!("{other:?}"),
        }
        // Past the declared size: refused whole, nothing of it kept.
        assert!(matches!(
            s.append(&st.id, 7, 0, 6, body(&[b"67", b"89abc"])).await,
            Err(SessionError::TooLarge(_))
        ));
        assert_eq!(
            s.status(&st.id, 7).await.expect("status").files[0].received,
            6
        );
        // A body that breaks off keeps what arrived.
        let broken = futures_util::stream::iter(vec![
            Ok(bytes::Bytes::from_static(b"67")),
            Err("connection reset".to_string()),
        ]);
        assert!(matches!(
            s.append(&st.id, 7, 0, 6, broken).await,
            Err(SessionError::Invalid(_))
        ));
        assert_eq!(
            s.status(&st.id, 7).await.expect("status").files[0].received,
            8
        );
        assert!(matches!(
            s.take(&st.id, 7).await,
            Err(SessionError::Incomplete(_))
        ));
        s.append(&st.id, 7, 0, 8, body(&[b"89"]))
            .await
            .expect("append");
        s.append(&st.id, 7, 1, 0, body(&[b"bin!"]))
            .await
            .expect("append");
        assert!(s.status(&st.id, 7).await.expect("status").complete());
        let taken = s.take(&st.id, 7).await.expect("take");
        assert_eq!(
            std::fs::read(&taken.files[0].1).expect("read"),
            b"0123456789"
        );
        assert_eq!(std::fs::read(&taken.files[1].1).expect("read"), b"bin!");
        // While taken, no chunk is accepted.
        assert!(matches!(
            s.append(&st.id, 7, 1, 4, body(&[])).await,
            Err(SessionError::Busy)
        ));
        drop(taken);
        assert!(matches!(
            s.status(&st.id, 7).await,
            Err(SessionError::NotFound(_))
        ));
    }

    #[tokio::test]
    async fn bad_sessions_are_refused_and_idle_ones_swept() {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = Sessions::new(dir.path(), SESSION_LIFETIME);
        assert!(matches!(
            s.create(1, vec![], 100).await,
            Err(SessionError::Invalid(_))
        ));
        let mut twice = files();
        twice[1].path = "scan.gltf".into();
        assert!(matches!(
            s.create(1, twice, 100).await,
            Err(SessionError::Invalid(_))
        ));
        assert!(matches!(
            s.create(1, files(), 13).await,
            Err(SessionError::TooLarge(_))
        ));
        for bad in ["../../etc", "abc", &"g".repeat(32)] {
            assert!(matches!(
                s.status(bad, 1).await,
                Err(SessionError::NotFound(_))
            ));
        }
        let kept = s.create(1, files(), 100).await.expect("create");
        let gone = Sessions::new(dir.path(), Duration::ZERO);
        std::thread::sleep(Duration::from_millis(20));
        let removed = gone.sweep();
        assert_eq!(removed.len(), 1);
        assert!(matches!(
            s.status(&kept.id, 1).await,
            Err(SessionError::NotFound(_))
        ));
        let fresh = s.create(1, files(), 100).await.expect("create");
        assert!(s.sweep().is_empty());
        s.remove(&fresh.id, 1).await.expect("remove");
        assert!(matches!(
            s.status(&fresh.id, 1).await,
            Err(SessionError::NotFound(_))
        ));
    }
}
