//! Model upload → background build → LOD serving (`/lod` JSON and binary, patches with ETag,
//! 304, byte ranges, 416, the whole file), roles, thumbnails and the admin jobs page.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use meshwiki_engine::lod::LodFile;
use meshwiki_engine::mesh::synth::Relief;
use serde_json::Value;

use crate::harness::*;

/// Writes the generated relief of about `triangles` triangles as binary PLY.
pub fn relief_ply(dir: &Path, name: &str, triangles: u64) -> PathBuf {
    let path = dir.join(name);
    Relief::new(triangles, 7)
        .write_ply(&path)
        .expect("write relief");
    path
}

/// Uploads `data` as a scan through the raw API.
pub fn upload_scan(c: &Client, title: &str, filename: &str, data: Vec<u8>) -> Resp {
    c.request(
        "POST",
        &format!(
            "/api/v1/models/upload?title={}&filename={}",
            encode(title),
            encode(filename)
        ),
        Some("application/octet-stream"),
        data,
        true,
    )
}

/// Polls a job until `done(job)` holds (panics after `secs`).
pub fn wait_job(c: &Client, id: i64, secs: u64, done: impl Fn(&Value) -> bool) -> Value {
    let start = Instant::now();
    loop {
        let r = c.get(&format!("/api/v1/jobs/{id}"));
        assert_eq!(r.status, 200, "{}", r.text());
        let job = r.json();
        if done(&job) {
            return job;
        }
        assert!(
            start.elapsed() < Duration::from_secs(secs),
            "job {id} not there after {secs} s: {job}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Polls a job until it has ended.
pub fn wait_finished(c: &Client, id: i64, secs: u64) -> Value {
    wait_job(c, id, secs, |j| {
        matches!(j["status"].as_str(), Some("done" | "failed" | "cancelled"))
    })
}

/// Names in a directory that `keep` keeps, once none are left or ten seconds have passed. A job
/// ends (`done`, `failed`, `cancelled`) in the database first and removes its uploaded input
/// right after, so a test that has seen the end waits for the removal (a crash in between leaves
/// the input to the sweep at the next start, never an ended job without its output).
pub fn names_left(dir: &Path, keep: impl Fn(&str) -> bool) -> Vec<String> {
    let left = || -> Vec<String> { names(dir).into_iter().filter(|n| keep(n)).collect() };
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    let mut now = left();
    while !now.is_empty() && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(50));
        now = left();
    }
    now
}

/// Names in a directory (empty when it does not exist).
pub fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

#[test]
fn upload_build_and_serve_lod() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let editor = create_user(&server, &admin, "ed", "editor");
    let viewer = create_user(&server, &admin, "vi", "viewer");
    let scans = tempfile::tempdir().unwrap();
    let ply = relief_ply(scans.path(), "relief.ply", 6_000);
    let data = std::fs::read(&ply).unwrap();

    // Roles, CSRF and bad parameters.
    upload_scan(&editor, "x", "a.ply", data.clone()).assert_error(403);
    upload_scan(&server.client(), "x", "a.ply", data.clone()).assert_error(401);
    upload_scan(&admin.without_csrf(), "x", "a.ply", data.clone()).assert_error(403);
    let msg = upload_scan(&admin, "x", "notes.txt", data.clone()).assert_error(400);
    assert!(msg.contains(".ply"), "{msg}");
    upload_scan(&admin, "", "a.ply", data.clone()).assert_error(400);
    upload_scan(&admin, "x", "a.ply", Vec::new()).assert_error(400);
    assert_eq!(
        admin.get("/api/v1/models").json().as_array().unwrap().len(),
        0
    );

    // Upload, with a path in the name: only the extension (and a display name) is used.
    let r = upload_scan(&admin, "Relief", "../../etc/relief.PLY", data.clone());
    assert_eq!(r.status, 202, "{}", r.text());
    let body = r.json();
    let (model_id, job_id) = (
        body["model"]["id"].as_i64().unwrap(),
        body["job"]["id"].as_i64().unwrap(),
    );
    assert_eq!(
        r.header("location"),
        Some(format!("/api/v1/jobs/{job_id}").as_str())
    );
    assert_eq!(body["job"]["source_name"], "relief.PLY");
    let job = wait_finished(&admin, job_id, 120);
    assert_eq!(job["status"], "done", "{job}");
    assert_eq!(job["percent"], 100.0);
    assert_eq!(job["model_id"], model_id);
    assert!(job["finished_at"].is_string());
    let relief = Relief::new(6_000, 7);
    assert_eq!(
        job["report"]["import"]["triangles"].as_u64(),
        Some(relief.triangle_count())
    );

    let model = admin.get(&format!("/api/v1/models/{model_id}")).json();
    assert_eq!(model["status"], "ready", "{model}");
    assert_eq!(
        model["triangle_count"].as_u64(),
        Some(relief.triangle_count())
    );
    assert_eq!(model["vertex_count"].as_u64(), Some(relief.vertex_count()));
    let bbox_min = model["bbox"]["min"][0].as_f64().unwrap();
    assert!((-1.01..=-0.98).contains(&bbox_min), "{model}");
    let lod_path = dir.path().join(model["lod_path"].as_str().unwrap());
    assert_eq!(
        lod_path,
        dir.path().join("models").join(format!("{model_id}.mwlod"))
    );
    // The thumbnail is an attachment anyone logged in can see.
    let thumb = model["thumbnail_attachment_id"]
        .as_i64()
        .expect("thumbnail");
    let img = viewer.get(&format!("/api/v1/attachments/{thumb}/download"));
    assert_eq!(img.status, 200);
    assert_eq!(img.header("content-type"), Some("image/png"));
    assert!(img.body.starts_with(b"\x89PNG"));
    let list = viewer.get("/models");
    assert!(
        list.text()
            .contains(&format!("/api/v1/attachments/{thumb}/download")),
        "thumbnail in the models list"
    );

    // The hierarchy as JSON matches the file.
    let lod = LodFile::open(&lod_path).unwrap();
    let r = viewer.get(&format!("/api/v1/models/{model_id}/lod"));
    assert_eq!(r.status, 200, "{}", r.text());
    let etag = r.header("etag").unwrap().to_string();
    let h = r.json();
    assert_eq!(h["version"], 1);
    assert_eq!(h["node_count"].as_u64(), Some(lod.nodes().len() as u64));
    assert_eq!(h["group_count"].as_u64(), Some(lod.groups().len() as u64));
    assert_eq!(h["file_bytes"].as_u64(), Some(lod.bytes().len() as u64));
    assert_eq!(h["input_triangles"].as_u64(), Some(relief.triangle_count()));
    let nodes = h["nodes"].as_array().unwrap();
    assert_eq!(nodes.len(), lod.nodes().len());
    for (i, (j, n)) in nodes.iter().zip(lod.nodes()).enumerate() {
        assert_eq!(j["id"].as_u64(), Some(i as u64));
        assert_eq!(j["length"].as_u64(), Some(n.blob_len as u64));
        assert_eq!(j["crc32"].as_u64(), Some(n.blob_crc as u64));
        assert_eq!(j["offset"].as_u64(), Some(n.blob_offset));
        assert_eq!(j["triangles"].as_u64(), Some(n.triangle_count as u64));
        assert_eq!(j["parent_error"].is_null(), !n.parent_error.is_finite());
    }
    let roots = nodes.iter().filter(|n| n["member_of"].is_null()).count();
    assert_eq!(h["root_count"].as_u64(), Some(roots as u64));
    let groups = h["groups"].as_array().unwrap();
    for (j, g) in groups.iter().zip(lod.groups()) {
        let members: Vec<u32> = serde_json::from_value(j["members"].clone()).unwrap();
        assert_eq!(members, lod.members(g));
    }
    let r = viewer.request_with(
        "GET",
        &format!("/api/v1/models/{model_id}/lod"),
        None,
        Vec::new(),
        false,
        &[("If-None-Match", &etag)],
    );
    assert_eq!(r.status, 304);
    // Binary: header and tables exactly.
    let r = viewer.get(&format!("/api/v1/models/{model_id}/lod?format=binary"));
    assert_eq!(r.status, 200);
    let blobs_offset = lod.header().blobs_offset as usize;
    assert_eq!(r.body, lod.bytes()[..blobs_offset]);
    viewer
        .get(&format!("/api/v1/models/{model_id}/lod?format=xml"))
        .assert_error(400);

    // A patch: the blob, immutable, with its CRC as ETag; 304; ranges; 416.
    let last = lod.nodes().len() as u32 - 1;
    let blob = lod.blob(last).unwrap().to_vec();
    let path = format!("/api/v1/models/{model_id}/lod/patches/{last}");
    let r = viewer.get(&path);
    assert_eq!(r.status, 200);
    assert_eq!(r.body, blob);
    let crc = format!("\"{:08x}\"", lod.nodes()[last as usize].blob_crc);
    assert_eq!(r.header("etag"), Some(crc.as_str()));
    assert_eq!(
        r.header("cache-control"),
        Some("public, max-age=31536000, immutable")
    );
    assert_eq!(r.header("content-type"), Some("application/octet-stream"));
    let get_with = |p: &str, headers: &[(&str, &str)]| {
        viewer.request_with("GET", p, None, Vec::new(), false, headers)
    };
    let r = get_with(&path, &[("If-None-Match", &crc)]);
    assert_eq!(r.status, 304);
    assert!(r.body.is_empty());
    let r = get_with(&path, &[("Range", "bytes=4-13")]);
    assert_eq!(r.status, 206);
    assert_eq!(r.body, blob[4..14]);
    assert_eq!(
        r.header("content-range"),
        Some(format!("bytes 4-13/{}", blob.len()).as_str())
    );
    let r = get_with(&path, &[("Range", "bytes=-8")]);
    assert_eq!(r.status, 206);
    assert_eq!(r.body, blob[blob.len() - 8..]);
    // A stale If-Range gets the whole blob.
    let r = get_with(
        &path,
        &[("Range", "bytes=0-3"), ("If-Range", "\"00000000\"")],
    );
    assert_eq!(r.status, 200);
    assert_eq!(r.body, blob);
    // A malformed or multiple range is ignored (RFC 9110 §14.2): the whole blob.
    for ignored in ["bytes=9-2", "bytes=x-y", "bytes=abc", "bytes=0-1,4-5"] {
        let r = get_with(&path, &[("Range", ignored)]);
        assert_eq!(r.status, 200, "{ignored}");
        assert_eq!(r.body, blob, "{ignored}");
    }
    for bad in [format!("bytes={}-", blob.len()), "bytes=-0".to_string()] {
        let r = get_with(&path, &[("Range", &bad)]);
        r.assert_error(416);
        assert_eq!(
            r.header("content-range"),
            Some(format!("bytes */{}", blob.len()).as_str())
        );
    }
    viewer
        .get(&format!(
            "/api/v1/models/{model_id}/lod/patches/{}",
            last + 1
        ))
        .assert_error(404);
    viewer
        .get(&format!("/api/v1/models/{model_id}/lod/patches/abc"))
        .assert_error(400);
    // The whole file, and a range of it (neighbouring patches in one request).
    let r = viewer.get(&format!("/api/v1/models/{model_id}/lod/file"));
    assert_eq!(r.status, 200);
    assert_eq!(r.body, lod.bytes());
    let first = &lod.nodes()[0];
    let range = format!(
        "bytes={}-{}",
        first.blob_offset,
        first.blob_offset + first.blob_len as u64 - 1
    );
    let r = get_with(
        &format!("/api/v1/models/{model_id}/lod/file"),
        &[("Range", &range)],
    );
    assert_eq!(r.status, 206);
    assert_eq!(r.body, lod.blob(0).unwrap());

    // Access: viewers read, nobody without a session, unknown models 404.
    server
        .client()
        .get(&format!("/api/v1/models/{model_id}/lod"))
        .assert_error(401);
    server.client().get(&path).assert_error(401);
    viewer.get("/api/v1/models/9999/lod").assert_error(404);
    viewer
        .get("/api/v1/models/9999/lod/patches/0")
        .assert_error(404);
    assert_eq!(viewer.get(&format!("/api/v1/jobs/{job_id}")).status, 200);
    viewer.get("/api/v1/jobs").assert_error(403);
    viewer
        .post(
            &format!("/api/v1/jobs/{job_id}/cancel"),
            &serde_json::json!({}),
        )
        .assert_error(403);
    admin
        .post(
            &format!("/api/v1/jobs/{job_id}/cancel"),
            &serde_json::json!({}),
        )
        .assert_error(409);
    let all = admin.get("/api/v1/jobs?status=done").json();
    assert_eq!(all.as_array().unwrap().len(), 1);
    admin.get("/api/v1/jobs?status=nope").assert_error(400);
    viewer.get("/api/v1/jobs/4242").assert_error(404);

    // The admin page's multipart form builds too (and refuses a missing CSRF token).
    assert_eq!(viewer.get("/admin/jobs").status, 403);
    let page = admin.get("/admin/jobs");
    assert_eq!(page.status, 200);
    assert!(page.text().contains(&format!("job-{job_id}")));
    let csrf = admin.csrf.clone().unwrap();
    let r = admin.upload(
        "/admin/jobs/upload",
        &[("csrf_token", "wrong"), ("title", "Form upload")],
        "form.ply",
        "application/octet-stream",
        &data,
        false,
    );
    assert_eq!(r.status, 403);
    let r = admin.upload(
        "/admin/jobs/upload",
        &[("csrf_token", &csrf), ("title", "Form upload")],
        "form.ply",
        "application/octet-stream",
        &data,
        false,
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let location = r.header("location").unwrap().to_string();
    let form_model: i64 = location.trim_start_matches("/models/").parse().unwrap();
    let jobs = admin.get("/api/v1/jobs").json();
    let form_job = jobs
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["model_id"] == form_model)
        .expect("job of the form upload")["id"]
        .as_i64()
        .unwrap();
    assert_eq!(wait_finished(&admin, form_job, 120)["status"], "done");
    let page = viewer.get(&location);
    assert_eq!(page.status, 200);
    assert!(page.text().contains("ready"));

    // Nothing is left in uploads/; models/ holds the two LOD files and their surface
    // segments only.
    let left = names_left(&dir.path().join("uploads"), |_| true);
    assert!(left.is_empty(), "uploads: {left:?}");
    let mut files = vec![
        format!("{model_id}.mwlod"),
        format!("{model_id}.mwseg"),
        format!("{form_model}.mwlod"),
        format!("{form_model}.mwseg"),
    ];
    files.sort();
    assert_eq!(names(&dir.path().join("models")), files);
    // Deleting a model removes its files; its hierarchy is gone.
    assert_eq!(
        admin.delete(&format!("/api/v1/models/{form_model}")).status,
        204
    );
    viewer
        .get(&format!("/api/v1/models/{form_model}/lod"))
        .assert_error(404);
    assert_eq!(
        names(&dir.path().join("models")),
        vec![format!("{model_id}.mwlod"), format!("{model_id}.mwseg")]
    );
}
