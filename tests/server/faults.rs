//! Fault injection into the store (issue 14 §9): the data directory on a small tmpfs that is
//! filled up under a running server, so that database commits and attachment writes fail in
//! the middle (SQLite's "database or disk is full", ENOSPC half-way through an upload).
//! Writes that fail answer 5xx for that request only, other requests go on, nothing half
//! written is left (no row without its file, no file without its row, no partial upload), every
//! acknowledged write survives, and once space is back the same requests succeed. Needs root (to
//! mount); skips with a message otherwise. And a disk that fails with I/O errors: an
//! `LD_PRELOAD` shim (`eio_shim.c`, built with the system's C compiler) makes every write and
//! sync under the data directory fail with EIO while a trigger file exists, with the same
//! checks; it needs no root.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::json;

use crate::harness::*;

/// A tmpfs mounted for the test, unmounted on drop.
struct Tmpfs {
    dir: tempfile::TempDir,
}

impl Tmpfs {
    fn mount(size_mb: u32) -> Option<Tmpfs> {
        let dir = tempfile::tempdir().expect("tempdir");
        let ok = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size_mb}m"), "tmpfs"])
            .arg(dir.path())
            .status()
            .is_ok_and(|s| s.success());
        if !ok {
            eprintln!("skipping: cannot mount a tmpfs (needs root): fault injection not run");
            return None;
        }
        Some(Tmpfs { dir })
    }

    fn path(&self) -> &Path {
        self.dir.path()
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount")
            .arg("-l")
            .arg(self.dir.path())
            .status();
    }
}

/// Fills the file system of `dir` to the last byte; returns the filler file.
fn fill(dir: &Path) -> PathBuf {
    use std::io::Write;
    let path = dir.join("filler");
    let mut f = std::fs::File::create(&path).expect("filler");
    for chunk in [1 << 20, 64 << 10, 4 << 10, 512, 1] {
        let buf = vec![0u8; chunk];
        while f.write_all(&buf).is_ok() {}
    }
    let _ = f.sync_all();
    path
}

fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(files_under(&p));
            } else {
                out.push(p);
            }
        }
    }
    out
}

/// Uploads `bytes` as a standalone attachment (with the CSRF token).
fn upload(c: &Client, name: &str, mime: &str, bytes: &[u8]) -> Resp {
    c.upload("/api/v1/attachments", &[], name, mime, bytes, true)
}

/// What a test writes while the disk works: a content titled `title` (its id) and an
/// attachment (its id and bytes).
fn before_the_fault(c: &Client, title: &str) -> (i64, Vec<(i64, Vec<u8>)>) {
    let first = create_content(c, title, "Written while the disk worked.");
    let bytes = format!("attachment: {title}").into_bytes();
    let r = upload(c, "a.txt", "text/plain", &bytes);
    assert_eq!(r.status, 201, "{}", r.text());
    (
        first["id"].as_i64().unwrap(),
        vec![(r.json()["id"].as_i64().unwrap(), bytes)],
    )
}

/// The titles of every content, in the server's order.
fn titles(c: &Client) -> Vec<String> {
    let list = c.get("/api/v1/contents?limit=1000").json();
    list.as_array()
        .unwrap_or_else(|| panic!("{list}"))
        .iter()
        .map(|c| c["title"].as_str().unwrap_or_default().to_string())
        .collect()
}

/// Integrity of the database file, by SQLite itself.
fn integrity(db: &Path) -> String {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        use sqlx::ConnectOptions;
        let mut conn = sqlx::sqlite::SqliteConnectOptions::new()
            .filename(db)
            .read_only(true)
            .connect()
            .await
            .expect("open db");
        let row: (String,) = sqlx::query_as("PRAGMA integrity_check")
            .fetch_one(&mut conn)
            .await
            .expect("integrity_check");
        row.0
    })
}

/// Every attachment row has its file with the right bytes, and every file has a row.
fn check_attachments(data: &Path, c: &Client, ids: &[(i64, Vec<u8>)]) {
    for (id, bytes) in ids {
        let r = c.get(&format!("/api/v1/attachments/{id}/download"));
        assert_eq!(r.status, 200, "attachment {id}");
        assert_eq!(&r.body, bytes, "attachment {id} bytes");
    }
    let stored = files_under(&data.join("attachments"));
    assert_eq!(
        stored.len(),
        ids.iter()
            .map(|(_, b)| b)
            .collect::<std::collections::HashSet<_>>()
            .len(),
        "files in attachments/: {stored:?}"
    );
    let partial: Vec<_> = files_under(&data.join("uploads"));
    assert!(partial.is_empty(), "left in uploads/: {partial:?}");
}

#[test]
fn full_and_failing_disks_lose_nothing_and_recover() {
    let Some(fs) = Tmpfs::mount(48) else { return };
    let data = fs.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    let out = add_user(&data, "admin", "admin", ADMIN_PASSWORD);
    assert!(out.status.success());
    let server = Server::start(&data);
    let admin = server.login("admin", ADMIN_PASSWORD);

    // Before the fault: a content and an attachment.
    let (first_id, mut attachments) = before_the_fault(&admin, "Before the fault");

    // Disk full.
    let filler = fill(fs.path());
    let big_body = "word ".repeat(180_000);
    let (mut acknowledged, mut failed) = (Vec::new(), 0);
    for k in 0..6 {
        let title = format!("During the fault {k}");
        let r = admin.post(
            "/api/v1/contents",
            &json!({"title": title, "caption": "", "body": big_body, "comment": "full disk"}),
        );
        match r.status {
            201 => acknowledged.push((r.json()["id"].as_i64().unwrap(), title)),
            s if s >= 500 => failed += 1,
            s => panic!("a full disk answered {s}: {}", r.text()),
        }
    }
    assert!(failed > 0, "some write hit the full disk");
    let big_file = vec![42u8; 2 << 20];
    let r = upload(&admin, "big.bin", "application/octet-stream", &big_file);
    assert!(
        r.status >= 500,
        "an upload to a full disk: {} {}",
        r.status,
        r.text()
    );
    let r = admin.put(
        &format!("/api/v1/contents/{first_id}"),
        &json!({"base_revision": 1, "title": "Edited during the fault", "body": big_body}),
    );
    assert!(
        r.status >= 500 || r.status == 200,
        "{} {}",
        r.status,
        r.text()
    );
    let edit_acknowledged = r.status == 200;
    // Reads go on.
    let r = admin.get(&format!("/api/v1/contents/{first_id}"));
    assert_eq!(r.status, 200, "reads during a full disk");

    // Space back: the same requests succeed.
    std::fs::remove_file(&filler).unwrap();
    let r = upload(&admin, "big.bin", "application/octet-stream", &big_file);
    assert_eq!(r.status, 201, "after the fault: {}", r.text());
    attachments.push((r.json()["id"].as_i64().unwrap(), big_file.clone()));
    let after = create_content(&admin, "After the fault", "The disk has room again.");
    let after_id = after["id"].as_i64().unwrap();

    // A disk that runs full in the middle of an upload (1 MB left, 3 MB sent): the upload
    // fails, its partial file is removed, and the next write works once space is back.
    let filler = fill(fs.path());
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(&filler)
        .unwrap();
    let len = f.metadata().unwrap().len();
    f.set_len(len.saturating_sub(1 << 20)).unwrap();
    drop(f);
    let r = upload(
        &admin,
        "mid.bin",
        "application/octet-stream",
        &vec![7u8; 3 << 20],
    );
    assert!(
        r.status >= 500,
        "an upload that runs out of space: {} {}",
        r.status,
        r.text()
    );
    assert!(
        files_under(&data.join("uploads")).is_empty(),
        "no partial upload left"
    );
    std::fs::remove_file(&filler).unwrap();
    let r = admin.post(
        "/api/v1/contents",
        &json!({"title": "Writable again", "body": "y", "comment": ""}),
    );
    assert_eq!(r.status, 201, "after the second fault: {}", r.text());
    let writable_id = r.json()["id"].as_i64().unwrap();

    // Consistent now and after a restart: every acknowledged write is there, nothing else.
    check_attachments(&data, &admin, &attachments);
    drop(admin);
    drop(server);
    assert_eq!(integrity(&data.join("meshwiki.db")), "ok");
    let server = Server::start(&data);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let titles = titles(&admin);
    for (id, title) in &acknowledged {
        assert!(
            titles.contains(title),
            "acknowledged {id} {title} lost: {titles:?}"
        );
    }
    let during = titles
        .iter()
        .filter(|t| t.starts_with("During the fault"))
        .count();
    assert_eq!(
        during,
        acknowledged.len(),
        "only acknowledged writes exist: {titles:?}"
    );
    assert!(
        titles.iter().any(|t| t == "After the fault")
            && titles.iter().any(|t| t == "Writable again")
    );
    let first = admin.get(&format!("/api/v1/contents/{first_id}")).json();
    let want = if edit_acknowledged {
        "Edited during the fault"
    } else {
        "Before the fault"
    };
    assert_eq!(first["title"], want);
    for id in [after_id, writable_id] {
        assert_eq!(admin.get(&format!("/api/v1/contents/{id}")).status, 200);
    }
    check_attachments(&data, &admin, &attachments);
    // Search caught up with everything that was committed.
    let hits = admin.get("/api/v1/search?q=writable").json();
    assert!(
        hits.as_array()
            .is_some_and(|h| h.iter().any(|x| x["id"] == writable_id)),
        "{hits}"
    );
    println!(
        "full disk: {failed} of 6 large saves refused with 5xx, {} acknowledged and kept; \
         uploads refused (also mid-stream) and nothing left; writes recover at once",
        acknowledged.len()
    );
}

/// Builds `eio_shim.c` (beside this file) into a preloadable library under the target
/// directory (not the temporary directory, which may be mounted `noexec`); `None` with a
/// message when no C compiler is at hand.
fn eio_shim() -> Option<PathBuf> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/server/eio_shim.c");
    let lib = Path::new(env!("CARGO_TARGET_TMPDIR")).join("libeio_shim.so");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".to_string());
    let ok = Command::new(&cc)
        .args(["-shared", "-fPIC", "-O1", "-o"])
        .arg(&lib)
        .arg(&src)
        .arg("-ldl")
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        eprintln!("skipping: no C compiler ({cc}) to build the I/O-error shim");
        return None;
    }
    Some(lib)
}

/// A disk that fails with I/O errors (EIO on every write and sync under the data directory,
/// injected by an `LD_PRELOAD` shim, no root needed): saves, edits and uploads get 5xx while it
/// lasts, reads go on, nothing half-written stays, and once the disk works again the same
/// requests succeed at once; after a restart the database passes SQLite's integrity check and
/// holds exactly the acknowledged writes.
#[test]
fn io_errors_lose_nothing_and_recover() {
    let work = tempfile::tempdir().expect("tempdir");
    let Some(shim) = eio_shim() else {
        return;
    };
    let data = work.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    let data = std::fs::canonicalize(&data).unwrap();
    let trigger = work.path().join("eio-on");
    let out = add_user(&data, "admin", "admin", ADMIN_PASSWORD);
    assert!(out.status.success());
    let env = [
        ("LD_PRELOAD", shim.as_path()),
        ("MESHWIKI_EIO_DIR", data.as_path()),
        ("MESHWIKI_EIO_TRIGGER", trigger.as_path()),
    ];
    let server = Server::start_env(&data, &[], &env);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let (first_id, mut attachments) = before_the_fault(&admin, "Before the errors");

    // The disk fails.
    std::fs::write(&trigger, b"").unwrap();
    for k in 0..4 {
        let r = admin.post(
            "/api/v1/contents",
            &json!({"title": format!("During the errors {k}"), "body": "x", "comment": ""}),
        );
        assert!(
            r.status >= 500,
            "a save on a failing disk answered {}: {}",
            r.status,
            r.text()
        );
    }
    let r = admin.put(
        &format!("/api/v1/contents/{first_id}"),
        &json!({"base_revision": 1, "title": "Edited during the errors", "body": "y"}),
    );
    assert!(r.status >= 500, "an edit: {} {}", r.status, r.text());
    let r = upload(
        &admin,
        "b.bin",
        "application/octet-stream",
        &vec![9u8; 1 << 20],
    );
    assert!(r.status >= 500, "an upload: {} {}", r.status, r.text());
    assert!(
        files_under(&data.join("uploads")).is_empty(),
        "no partial upload left"
    );
    let r = admin.get(&format!("/api/v1/contents/{first_id}"));
    assert_eq!(r.status, 200, "reads on a failing disk");
    assert_eq!(r.json()["title"], "Before the errors");

    // The disk works again: the same requests succeed at once.
    std::fs::remove_file(&trigger).unwrap();
    let r = admin.put(
        &format!("/api/v1/contents/{first_id}"),
        &json!({"base_revision": 1, "title": "Edited after the errors", "body": "y"}),
    );
    assert_eq!(r.status, 200, "an edit after the errors: {}", r.text());
    let after = create_content(&admin, "After the errors", "The disk works again.");
    let after_id = after["id"].as_i64().unwrap();
    let bytes_b = vec![9u8; 1 << 20];
    let r = upload(&admin, "b.bin", "application/octet-stream", &bytes_b);
    assert_eq!(r.status, 201, "an upload after the errors: {}", r.text());
    attachments.push((r.json()["id"].as_i64().unwrap(), bytes_b));
    check_attachments(&data, &admin, &attachments);

    // After a restart (without the shim): consistent, and exactly what was acknowledged.
    drop(admin);
    drop(server);
    assert_eq!(integrity(&data.join("meshwiki.db")), "ok");
    let server = Server::start(&data);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let mut titles = titles(&admin);
    titles.sort_unstable();
    assert_eq!(titles, ["After the errors", "Edited after the errors"]);
    assert_eq!(
        admin.get(&format!("/api/v1/contents/{after_id}")).status,
        200
    );
    check_attachments(&data, &admin, &attachments);
    let hits = admin.get("/api/v1/search?q=works").json();
    assert!(
        hits.as_array()
            .is_some_and(|h| h.iter().any(|x| x["id"] == after_id)),
        "{hits}"
    );
    println!(
        "I/O errors: saves, an edit and an upload refused with 5xx; reads went on; writes recovered at once"
    );
}
