//! Resumable scan uploads and `.zip` scans: a session's acknowledged bytes survive `kill -9`
//! and the upload resumes from them; a scan with the files it refers to arrives as one `.zip`
//! through every upload route; bad sessions, chunks and archives are refused with their cause
//! and leave nothing behind.

use std::io::Write;
use std::path::Path;

use serde_json::{Value, json};

use crate::harness::*;
use crate::lod::{names_left, relief_ply, wait_finished};

/// An OBJ relief with a material library (`scan.mtl`): a scan that refers to another file.
fn obj_with_mtl(n: usize) -> (Vec<u8>, Vec<u8>) {
    let mut obj = String::from("mtllib scan.mtl\nusemtl clay\n");
    for y in 0..=n {
        for x in 0..=n {
            let z = ((x * 7 + y * 13) % 11) as f32 * 0.01;
            obj.push_str(&format!(
                "v {} {} {z}\n",
                x as f32 / n as f32,
                y as f32 / n as f32
            ));
        }
    }
    let v = |x: usize, y: usize| y * (n + 1) + x + 1;
    for y in 0..n {
        for x in 0..n {
            obj.push_str(&format!(
                "f {} {} {}\n",
                v(x, y),
                v(x + 1, y),
                v(x + 1, y + 1)
            ));
            obj.push_str(&format!(
                "f {} {} {}\n",
                v(x, y),
                v(x + 1, y + 1),
                v(x, y + 1)
            ));
        }
    }
    (obj.into_bytes(), b"newmtl clay\nKd 0.8 0.4 0.2\n".to_vec())
}

fn zip_of(entries: &[(&str, &[u8])]) -> Vec<u8> {
    let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    for (name, data) in entries {
        w.start_file(*name, opts).unwrap();
        w.write_all(data).unwrap();
    }
    w.finish().unwrap().into_inner()
}

fn open(c: &Client, files: &[(&str, usize)]) -> Resp {
    let files: Vec<Value> = files
        .iter()
        .map(|(p, n)| json!({"path": p, "size": n}))
        .collect();
    c.post("/api/v1/uploads", &json!({ "files": files }))
}

fn chunk(c: &Client, id: &str, index: usize, offset: usize, data: &[u8]) -> Resp {
    c.request_with(
        "PATCH",
        &format!("/api/v1/uploads/{id}/files/{index}"),
        Some("application/offset+octet-stream"),
        data.to_vec(),
        true,
        &[("Upload-Offset", &offset.to_string())],
    )
}

fn received(c: &Client, id: &str) -> Vec<u64> {
    let r = c.get(&format!("/api/v1/uploads/{id}"));
    assert_eq!(r.status, 200, "{}", r.text());
    r.json()["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["received"].as_u64().unwrap())
        .collect()
}

/// Sends the headers of a chunk of `declared` bytes and only `sent` of them, leaving the
/// connection open (a transfer cut mid-way).
fn half_chunk(
    c: &Client,
    id: &str,
    offset: usize,
    declared: usize,
    data: &[u8],
) -> std::net::TcpStream {
    let addr = c.base.trim_start_matches("http://");
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    let head = format!(
        "PATCH /api/v1/uploads/{id}/files/0 HTTP/1.1\r\nHost: {addr}\r\nCookie: {}\r\nX-CSRF-Token: {}\r\nUpload-Offset: {offset}\r\nContent-Type: application/offset+octet-stream\r\nContent-Length: {declared}\r\n\r\n",
        c.cookie.as_deref().unwrap(),
        c.csrf.as_deref().unwrap()
    );
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(data).unwrap();
    s.flush().unwrap();
    s
}

/// Only the (empty) folder of upload sessions is left in `uploads/` (see [`names_left`]).
fn nothing_left(data: &Path) {
    let uploads = data.join("uploads");
    let left = names_left(&uploads, |n| n != "sessions");
    assert!(left.is_empty(), "uploads: {left:?}");
    let sessions = names_left(&uploads.join("sessions"), |_| true);
    assert!(sessions.is_empty(), "sessions: {sessions:?}");
}

#[test]
fn a_resumable_upload_survives_a_crash_and_builds() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let (obj, mtl) = obj_with_mtl(60);
    let r = open(
        &admin,
        &[
            ("relief/scan.obj", obj.len()),
            ("relief/scan.mtl", mtl.len()),
        ],
    );
    assert_eq!(r.status, 201, "{}", r.text());
    let s = r.json();
    let id = s["id"].as_str().unwrap().to_string();
    assert_eq!(s["complete"], false);
    assert!(s["chunk_size"].as_u64().unwrap() > 0);
    assert_eq!(
        r.header("location"),
        Some(format!("/api/v1/uploads/{id}").as_str())
    );

    // Two acknowledged chunks, then a third cut off mid-way by a crash of the server.
    let third = obj.len() / 3;
    let r = chunk(&admin, &id, 0, 0, &obj[..third]);
    assert_eq!(r.status, 204, "{}", r.text());
    assert_eq!(r.header("upload-offset"), Some(third.to_string().as_str()));
    let r = chunk(&admin, &id, 0, third, &obj[third..2 * third]);
    assert_eq!(r.status, 204, "{}", r.text());
    let acknowledged = 2 * third;
    let _cut = half_chunk(
        &admin,
        &id,
        acknowledged,
        obj.len() - acknowledged,
        &obj[acknowledged..acknowledged + 100],
    );
    std::thread::sleep(std::time::Duration::from_millis(300));
    server.kill9();

    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let held = received(&admin, &id)[0] as usize;
    assert!(
        (acknowledged..=acknowledged + 100).contains(&held),
        "acknowledged {acknowledged}, held {held}"
    );
    // Resuming from a stale offset is refused with the held one.
    let r = chunk(&admin, &id, 0, 0, &obj[..10]);
    assert_eq!(r.status, 409, "{}", r.text());
    assert_eq!(r.header("upload-offset"), Some(held.to_string().as_str()));
    // Finishing early names what is missing.
    let e = admin
        .post(
            &format!("/api/v1/uploads/{id}/finish"),
            &json!({"title": "Early"}),
        )
        .assert_error(400);
    assert!(
        e.contains("relief/scan.obj") && e.contains("not complete"),
        "{e}"
    );
    let r = chunk(&admin, &id, 0, held, &obj[held..]);
    assert_eq!(r.status, 204, "{}", r.text());
    let r = chunk(&admin, &id, 1, 0, &mtl);
    assert_eq!(r.status, 204, "{}", r.text());
    assert_eq!(
        received(&admin, &id),
        vec![obj.len() as u64, mtl.len() as u64]
    );

    let r = admin.post(
        &format!("/api/v1/uploads/{id}/finish"),
        &json!({"title": "Resumed relief", "description": "sent in pieces"}),
    );
    assert_eq!(r.status, 202, "{}", r.text());
    let j = r.json();
    assert_eq!(j["model"]["source_name"], "scan.obj");
    let job = wait_finished(&admin, j["job"]["id"].as_i64().unwrap(), 120);
    assert_eq!(job["status"], "done", "{job}");
    let m = admin
        .get(&format!("/api/v1/models/{}", j["model"]["id"]))
        .json();
    assert_eq!(m["status"], "ready");
    assert_eq!(m["triangle_count"], 2 * 60 * 60);
    // The session is gone with its bytes.
    admin
        .get(&format!("/api/v1/uploads/{id}"))
        .assert_error(404);
    nothing_left(dir.path());
}

#[test]
fn a_zip_of_a_scan_and_its_files_builds_through_every_route() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let (obj, mtl) = obj_with_mtl(20);
    let archive = zip_of(&[
        ("relief/scan.obj", &obj),
        ("relief/scan.mtl", &mtl),
        ("__MACOSX/relief/._scan.obj", b"resource fork"),
    ]);
    let mut models = Vec::new();

    // A resumable session of one .zip.
    let r = open(&admin, &[("relief.zip", archive.len())]);
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    assert_eq!(chunk(&admin, &id, 0, 0, &archive).status, 204);
    // Build options out of range are refused with their name, and the session stays.
    let e = admin
        .post(
            &format!("/api/v1/uploads/{id}/finish"),
            &json!({"title": "Zip session", "build": {"patch_triangles": 10}}),
        )
        .assert_error(400);
    assert!(e.contains("patch_triangles"), "{e}");
    let e = admin
        .post(
            &format!("/api/v1/uploads/{id}/finish"),
            &json!({"title": "Zip session", "build": {"vertex_order": "random"}}),
        )
        .assert_error(400);
    assert!(e.contains("`random`") && e.contains("`morton`"), "{e}");
    let r = admin.post(
        &format!("/api/v1/uploads/{id}/finish"),
        &json!({"title": "Zip session", "build": {"patch_triangles": 256, "simplifier": "quadric", "normal_maps": true, "vertex_order": "source"}}),
    );
    assert_eq!(r.status, 202, "{}", r.text());
    models.push((r.json(), Some(256), true, "source"));

    // The raw API: options are query parameters, refused before the body is read.
    let e = admin
        .request(
            "POST",
            "/api/v1/models/upload?title=Zip%20raw&filename=relief.zip&texture_quality=0",
            Some("application/zip"),
            archive.clone(),
            true,
        )
        .assert_error(400);
    assert!(e.contains("texture_quality"), "{e}");
    let r = admin.request(
        "POST",
        "/api/v1/models/upload?title=Zip%20raw&filename=relief.zip&patch_triangles=300&texture_quality=70",
        Some("application/zip"),
        archive.clone(),
        true,
    );
    assert_eq!(r.status, 202, "{}", r.text());
    models.push((r.json(), Some(300), false, "morton"));

    // The page's form.
    let page = admin.get("/admin/jobs").text();
    let csrf = page
        .split("name=\"csrf_token\" value=\"")
        .nth(1)
        .and_then(|s| s.split('"').next())
        .unwrap()
        .to_string();
    // A refused option comes back in the form with what was typed.
    let r = admin.upload_files(
        "/admin/jobs/upload",
        &[
            ("csrf_token", &csrf),
            ("title", "Zip form"),
            ("texture_spread", "99"),
        ],
        &[("relief.zip", "application/zip", &archive)],
    );
    assert_eq!(r.status, 400, "{}", r.text());
    let page = r.text();
    assert!(page.contains("texture_spread must be 0 to 50"), "{page}");
    assert!(page.contains("value=\"99\"") && page.contains("value=\"Zip form\""));
    let r = admin.upload_files(
        "/admin/jobs/upload",
        &[
            ("csrf_token", &csrf),
            ("title", "Zip form"),
            ("simplifier", "segments"),
            ("patch_triangles", "256"),
            ("normal_maps", "on"),
            ("vertex_order", "source"),
        ],
        &[("relief.zip", "application/zip", &archive)],
    );
    assert_eq!(r.status, 303, "{}", r.text());

    for (j, patch, normal_maps, order) in &models {
        assert_eq!(j["model"]["source_name"], "scan.obj", "{j}");
        let job = wait_finished(&admin, j["job"]["id"].as_i64().unwrap(), 120);
        assert_eq!(job["status"], "done", "{job}");
        // The options reached the build: 800 triangles make several patches of at most 300.
        assert_eq!(job["options"]["max_patch_triangles"], json!(patch), "{job}");
        let nodes = job["report"]["nodes"].as_u64().unwrap_or(0);
        assert!(nodes > 2, "{nodes} nodes: {job}");
        // Normal maps where asked for (off by default).
        let lod = admin
            .get(&format!("/api/v1/models/{}/lod", j["model"]["id"]))
            .json();
        assert_eq!(lod["has_normal_maps"], json!(normal_maps), "{j}");
        // Vertex ids in Morton order unless the upload asked for the file's own.
        assert_eq!(lod["vertex_order"], *order, "{j}");
    }
    let list = admin.get("/api/v1/models").json();
    let titles: Vec<&str> = list
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["status"] == "ready")
        .map(|m| m["title"].as_str().unwrap())
        .collect();
    for t in ["Zip session", "Zip raw"] {
        assert!(titles.contains(&t), "{titles:?}");
    }
    // The form's model builds too.
    let form_model = list
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["title"] == "Zip form")
        .unwrap()["id"]
        .as_i64()
        .unwrap();
    let jobs = admin.get("/api/v1/jobs").json();
    let job = jobs
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["model_id"] == form_model)
        .unwrap()["id"]
        .as_i64()
        .unwrap();
    let job = wait_finished(&admin, job, 120);
    assert_eq!(job["status"], "done");
    assert_eq!(job["options"]["simplifier"], "segments", "{job}");
    assert_eq!(job["options"]["normal_maps"], true, "{job}");
    // (Patches of 256 triangles: the 800-triangle relief has coarse patches to carry them.)
    let lod = admin
        .get(&format!("/api/v1/models/{form_model}/lod"))
        .json();
    assert_eq!(lod["has_normal_maps"], true);
    assert_eq!(lod["vertex_order"], "source");
    assert_eq!(job["options"]["vertex_order"], "source", "{job}");
    nothing_left(dir.path());
}

#[test]
fn bad_sessions_chunks_and_archives_are_refused_and_leave_nothing() {
    let dir = data_dir_with_admin();
    let server = Server::start_with(dir.path(), &["--max-model-upload-mb", "1"]);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let editor = create_user(&server, &admin, "ed", "editor");
    let other = create_user(&server, &admin, "root2", "admin");
    let scans = tempfile::tempdir().unwrap();
    let ply = std::fs::read(relief_ply(scans.path(), "r.ply", 2_000)).unwrap();

    // Roles and CSRF.
    open(&editor, &[("r.ply", ply.len())]).assert_error(403);
    let r = admin.without_csrf().post(
        "/api/v1/uploads",
        &json!({"files": [{"path": "r.ply", "size": 10}]}),
    );
    assert_eq!(r.status, 403, "{}", r.text());
    server
        .client()
        .post("/api/v1/uploads", &json!({"files": []}))
        .assert_error(401);

    // Lists that cannot make a scan, or are too large: refused before any byte is sent.
    for (files, status, words) in [
        (vec![("../r.ply", 10)], 400, "plain relative"),
        (vec![("/etc/r.ply", 10)], 400, "plain relative"),
        (vec![("notes.txt", 10)], 400, "none of the files is a scan"),
        (
            vec![("a.ply", 10), ("b.obj", 10)],
            400,
            "one scan at a time",
        ),
        (vec![("a.ply", 10), ("a.ply", 10)], 400, "twice"),
        (vec![], 400, "none of the files"),
        (vec![("a.ply", 2 << 20)], 413, "limit"),
    ] {
        let e = open(&admin, &files).assert_error(status);
        assert!(e.contains(words), "{files:?}: {e}");
    }

    let r = open(&admin, &[("r.ply", ply.len())]);
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    // Another admin's session does not exist for them.
    other
        .get(&format!("/api/v1/uploads/{id}"))
        .assert_error(404);
    chunk(&other, &id, 0, 0, &ply[..10]).assert_error(404);
    // Chunks: no offset, a file that is not there, past the declared size.
    let e = admin
        .request(
            "PATCH",
            &format!("/api/v1/uploads/{id}/files/0"),
            None,
            ply[..10].to_vec(),
            true,
        )
        .assert_error(400);
    assert!(e.contains("Upload-Offset"), "{e}");
    chunk(&admin, &id, 3, 0, &ply[..10]).assert_error(404);
    let mut long = ply.clone();
    long.extend_from_slice(b"one byte too many");
    let e = chunk(&admin, &id, 0, 0, &long).assert_error(413);
    assert!(e.contains("r.ply"), "{e}");
    assert_eq!(received(&admin, &id), vec![0]);
    admin.get("/api/v1/uploads/not-a-session").assert_error(404);
    admin
        .get("/api/v1/uploads/..%2F..%2Fmeshwiki.db")
        .assert_error(404);
    // Cancelled: gone with its bytes.
    assert_eq!(chunk(&admin, &id, 0, 0, &ply[..100]).status, 204);
    assert_eq!(admin.delete(&format!("/api/v1/uploads/{id}")).status, 204);
    admin
        .get(&format!("/api/v1/uploads/{id}"))
        .assert_error(404);

    // Archives that are no scan archive: refused at the finish, nothing left.
    for (entries, words) in [
        (vec![("../../evil.ply", &ply[..])], "plain relative path"),
        (
            vec![("a.ply", &ply[..]), ("b.ply", &ply[..])],
            "one scan at a time",
        ),
        (
            vec![("readme.txt", &b"hello"[..])],
            "none of the files is a scan",
        ),
    ] {
        let archive = zip_of(&entries);
        let r = open(&admin, &[("x.zip", archive.len())]);
        assert_eq!(r.status, 201, "{}", r.text());
        let id = r.json()["id"].as_str().unwrap().to_string();
        assert_eq!(chunk(&admin, &id, 0, 0, &archive).status, 204);
        let e = admin
            .post(
                &format!("/api/v1/uploads/{id}/finish"),
                &json!({"title": "Bad zip"}),
            )
            .assert_error(400);
        assert!(e.contains(words), "{e}");
    }
    let e = admin
        .request(
            "POST",
            "/api/v1/models/upload?title=x&filename=x.zip",
            Some("application/zip"),
            b"PK\x03\x04 this is no archive".to_vec(),
            true,
        )
        .assert_error(400);
    assert!(e.contains(".zip cannot be read"), "{e}");
    // A finish without a title makes no model.
    let r = open(&admin, &[("r.ply", ply.len())]);
    let id = r.json()["id"].as_str().unwrap().to_string();
    assert_eq!(chunk(&admin, &id, 0, 0, &ply).status, 204);
    let e = admin
        .post(
            &format!("/api/v1/uploads/{id}/finish"),
            &json!({"title": "  "}),
        )
        .assert_error(400);
    assert!(e.contains("title"), "{e}");
    // The session is still there for a better request.
    assert_eq!(received(&admin, &id), vec![ply.len() as u64]);
    let r = admin.post(
        &format!("/api/v1/uploads/{id}/finish"),
        &json!({"title": "Fine"}),
    );
    assert_eq!(r.status, 202, "{}", r.text());
    let j = r.json();
    let job = wait_finished(&admin, j["job"]["id"].as_i64().unwrap(), 120);
    assert_eq!(job["status"], "done", "{job}");
    // A ready model takes no new scan: 409 before the session is touched.
    let r = open(&admin, &[("r.ply", ply.len())]);
    let id = r.json()["id"].as_str().unwrap().to_string();
    assert_eq!(chunk(&admin, &id, 0, 0, &ply).status, 204);
    admin
        .post(
            &format!("/api/v1/uploads/{id}/finish"),
            &json!({"model": j["model"]["id"]}),
        )
        .assert_error(409);
    assert_eq!(received(&admin, &id), vec![ply.len() as u64]);
    assert_eq!(admin.delete(&format!("/api/v1/uploads/{id}")).status, 204);
    let models = admin.get("/api/v1/models").json();
    assert_eq!(models.as_array().unwrap().len(), 1, "{models}");
    nothing_left(dir.path());
}
