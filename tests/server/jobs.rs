//! Build jobs: malformed uploads fail with the importer's message and leave nothing behind,
//! a running build is cancelled cleanly, a queued one at once, and a build interrupted by a
//! crash (kill -9) restarts and completes on the next start.

use std::path::Path;

use serde_json::json;

use crate::harness::*;
use crate::lod::{names, names_left, relief_ply, upload_scan, wait_finished, wait_job};

/// Triangles of the input of the cancel and crash tests: a build that takes seconds on one
/// thread, so it can be caught running.
const LARGE: u64 = 700_000;

fn no_leftovers(data: &Path) {
    let left = names_left(&data.join("uploads"), |_| true);
    assert!(left.is_empty(), "uploads: {left:?}");
    let models = names(&data.join("models"));
    assert!(
        models
            .iter()
            .all(|n| !n.contains(".build-") && !n.contains(".tmp")),
        "models: {models:?}"
    );
}

#[test]
fn malformed_uploads_fail_with_the_importers_message() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let scans = tempfile::tempdir().unwrap();
    let good = std::fs::read(relief_ply(scans.path(), "r.ply", 4_000)).unwrap();
    let mut garbage = vec![0u8; 4096];
    for (i, b) in garbage.iter_mut().enumerate() {
        *b = (i * 7919 % 251) as u8;
    }
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "truncated.ply",
            good[..good.len() / 2].to_vec(),
            "truncated",
        ),
        ("garbage.ply", garbage.clone(), "garbage.ply"),
        (
            "nan.obj",
            b"v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n".to_vec(),
            "line 2",
        ),
        (
            "index.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n".to_vec(),
            "out of range",
        ),
        ("empty.stl", b"solid x\nendsolid x\n".to_vec(), "empty.stl"),
    ];
    for (name, data, expect) in cases {
        let r = upload_scan(&admin, name, name, data);
        assert_eq!(r.status, 202, "{name}: {}", r.text());
        let j = r.json();
        let (job, model) = (
            j["job"]["id"].as_i64().unwrap(),
            j["model"]["id"].as_i64().unwrap(),
        );
        let job = wait_finished(&admin, job, 60);
        assert_eq!(job["status"], "failed", "{name}: {job}");
        let msg = job["message"].as_str().unwrap();
        assert!(
            msg.contains(name),
            "{name}: the message names the file: {msg}"
        );
        assert!(msg.contains(expect), "{name}: {msg}");
        assert!(!msg.contains("src-"), "internal upload name leaked: {msg}");
        let m = admin.get(&format!("/api/v1/models/{model}")).json();
        assert_eq!(m["status"], "failed");
        assert_eq!(m["error"].as_str(), Some(msg));
        let e = admin
            .get(&format!("/api/v1/models/{model}/lod"))
            .assert_error(409);
        assert!(e.contains("failed"), "{e}");
        // The model page shows the error (no JavaScript needed).
        assert!(
            admin
                .get(&format!("/models/{model}"))
                .text()
                .contains("failed")
        );
    }
    no_leftovers(dir.path());
    assert!(names(&dir.path().join("models")).is_empty());
}

#[test]
fn cancelling_running_and_queued_builds() {
    let dir = data_dir_with_admin();
    let server = Server::start_with(dir.path(), &["--build-threads", "1"]);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let scans = tempfile::tempdir().unwrap();
    let big = std::fs::read(relief_ply(scans.path(), "big.ply", LARGE)).unwrap();
    let small = std::fs::read(relief_ply(scans.path(), "small.ply", 2_000)).unwrap();

    let r = upload_scan(&admin, "Big", "big.ply", big);
    assert_eq!(r.status, 202, "{}", r.text());
    let (job, model) = (
        r.json()["job"]["id"].as_i64().unwrap(),
        r.json()["model"]["id"].as_i64().unwrap(),
    );
    // One build at a time: the next upload waits in the queue.
    let r = upload_scan(&admin, "Small", "small.ply", small);
    let (queued, queued_model) = (
        r.json()["job"]["id"].as_i64().unwrap(),
        r.json()["model"]["id"].as_i64().unwrap(),
    );
    let running = wait_job(&admin, job, 60, |j| j["status"] == "running");
    assert_eq!(
        admin.get(&format!("/api/v1/jobs/{queued}")).json()["status"],
        "queued"
    );
    let e = admin
        .get(&format!("/api/v1/models/{model}/lod"))
        .assert_error(409);
    assert!(
        e.contains("building") || e.contains("pending"),
        "{e}: {running}"
    );

    // Cancel the queued job: at once.
    let r = admin.post(&format!("/api/v1/jobs/{queued}/cancel"), &json!({}));
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["status"], "cancelled");
    let m = admin.get(&format!("/api/v1/models/{queued_model}")).json();
    assert_eq!(m["status"], "failed");

    // Cancel the running one: it stops soon and leaves nothing.
    let r = admin.post(&format!("/api/v1/jobs/{job}/cancel"), &json!({}));
    assert_eq!(r.status, 202, "{}", r.text());
    let j = wait_finished(&admin, job, 60);
    assert_eq!(j["status"], "cancelled", "{j}");
    let m = admin.get(&format!("/api/v1/models/{model}")).json();
    assert_eq!(m["status"], "failed");
    assert_eq!(m["error"], "build cancelled");
    // The pages say "cancelled", not "failed".
    let list = admin.get("/models").text();
    assert!(list.contains("status-cancelled\">cancelled"), "models page");
    let page = admin.get(&format!("/models/{model}")).text();
    assert!(page.contains("status-cancelled\">cancelled"), "model page");
    no_leftovers(dir.path());
    assert!(names(&dir.path().join("models")).is_empty());
}

#[test]
fn a_build_interrupted_by_a_crash_restarts() {
    let dir = data_dir_with_admin();
    let server = Server::start_with(dir.path(), &["--build-threads", "1"]);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let scans = tempfile::tempdir().unwrap();
    let big = std::fs::read(relief_ply(scans.path(), "big.ply", LARGE)).unwrap();
    let r = upload_scan(&admin, "Crash", "big.ply", big);
    assert_eq!(r.status, 202, "{}", r.text());
    let (job, model) = (
        r.json()["job"]["id"].as_i64().unwrap(),
        r.json()["model"]["id"].as_i64().unwrap(),
    );
    // Wait until the build has scratch files on disk, then kill -9.
    wait_job(&admin, job, 60, |j| {
        j["status"] == "running" && j["stage"] != "" && j["stage"] != "import"
    });
    let models_dir = dir.path().join("models");
    let scratch: Vec<String> = names(&models_dir)
        .into_iter()
        .filter(|n| n.contains(".build-"))
        .collect();
    assert_eq!(scratch.len(), 1, "{:?}", names(&models_dir));
    server.kill9();
    assert!(models_dir.join(&scratch[0]).exists());
    // An unclaimed upload and a stale temporary file are leftovers too.
    std::fs::write(dir.path().join("uploads/src-deadbeef.ply"), b"x").unwrap();

    let server = Server::start_with(dir.path(), &["--build-threads", "2"]);
    let admin = server.login("admin", ADMIN_PASSWORD);
    assert!(!models_dir.join(&scratch[0]).exists(), "leftover removed");
    let j = wait_finished(&admin, job, 180);
    assert_eq!(j["status"], "done", "{j}");
    assert_eq!(j["attempts"], 2);
    let m = admin.get(&format!("/api/v1/models/{model}")).json();
    assert_eq!(m["status"], "ready");
    assert_eq!(
        admin.get(&format!("/api/v1/models/{model}/lod")).status,
        200
    );
    no_leftovers(dir.path());
    assert_eq!(
        names(&models_dir),
        vec![format!("{model}.mwlod"), format!("{model}.mwseg")]
    );
}

#[test]
fn a_failed_or_cancelled_build_is_retried_with_a_new_scan_or_its_model_deleted() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let csrf = admin.csrf.clone().unwrap();
    let scans = tempfile::tempdir().unwrap();
    let good = std::fs::read(relief_ply(scans.path(), "r.ply", 4_000)).unwrap();

    // A broken scan fails; the jobs page offers to retry it or delete its model.
    let r = admin.request(
        "POST",
        "/api/v1/models/upload?title=Gate&filename=gate.ply&patch_triangles=512&texture_quality=60",
        Some("application/octet-stream"),
        good[..good.len() / 2].to_vec(),
        true,
    );
    assert_eq!(r.status, 202, "{}", r.text());
    let (job, model) = (
        r.json()["job"]["id"].as_i64().unwrap(),
        r.json()["model"]["id"].as_i64().unwrap(),
    );
    assert_eq!(wait_finished(&admin, job, 60)["status"], "failed");
    let page = admin.get("/admin/jobs").text();
    assert!(
        page.contains("Retry the build")
            && page.contains(&format!("name=\"model\" value=\"{model}\""))
    );
    assert!(page.contains(&format!("action=\"/admin/models/{model}/delete\"")));
    // The retry form offers the failed build's options again, unfolded.
    let retry_form = page
        .split("class=\"stack small retry\"")
        .nth(1)
        .and_then(|f| f.split("</form>").next())
        .unwrap_or_default();
    assert!(
        retry_form.contains("data-build-options open")
            && retry_form.contains("name=\"patch_triangles\" type=\"number\" min=\"256\" max=\"65536\" placeholder=\"4096\" value=\"512\"")
            && retry_form.contains("placeholder=\"85\" value=\"60\""),
        "{retry_form}"
    );

    // Retried through the API with the whole scan: the same model, now ready.
    let r = admin.request(
        "POST",
        &format!("/api/v1/models/upload?model={model}&filename=gate.ply"),
        Some("application/octet-stream"),
        good.clone(),
        true,
    );
    assert_eq!(r.status, 202, "{}", r.text());
    assert_eq!(r.json()["model"]["id"], model);
    assert_eq!(r.json()["model"]["status"], "pending");
    let retry = r.json()["job"]["id"].as_i64().unwrap();
    assert_eq!(wait_finished(&admin, retry, 120)["status"], "done");
    let m = admin.get(&format!("/api/v1/models/{model}")).json();
    assert_eq!(
        (m["status"].as_str(), m["title"].as_str()),
        (Some("ready"), Some("Gate"))
    );
    assert!(m["error"].is_null());
    assert_eq!(
        admin.get(&format!("/api/v1/models/{model}/lod")).status,
        200
    );
    // A ready model keeps its scan (its parts name that scan's vertices): 409, before the
    // body is read, and nothing is left behind.
    let r = admin.request(
        "POST",
        &format!("/api/v1/models/upload?model={model}&filename=gate.ply"),
        Some("application/octet-stream"),
        good.clone(),
        true,
    );
    assert!(r.assert_error(409).contains("ready"));
    assert!(!admin.get("/admin/jobs").text().contains("Retry the build"));

    // A second failure, retried through the page's form; a refused upload keeps what was
    // typed; the model deleted from the page.
    let r = upload_scan(&admin, "Beam", "beam.ply", good[..100].to_vec());
    let (job, model) = (
        r.json()["job"]["id"].as_i64().unwrap(),
        r.json()["model"]["id"].as_i64().unwrap(),
    );
    assert_eq!(wait_finished(&admin, job, 60)["status"], "failed");
    let r = admin.upload(
        "/admin/jobs/upload",
        &[
            ("csrf_token", &csrf),
            ("title", "Roof beam"),
            ("description", "kept *text*"),
        ],
        "beam.txt",
        "text/plain",
        b"not a scan",
        false,
    );
    assert_eq!(r.status, 400, "{}", r.text());
    let page = r.text();
    assert!(
        page.contains("value=\"Roof beam\"") && page.contains("kept *text*"),
        "the form keeps what was typed"
    );
    let r = admin.upload(
        "/admin/jobs/upload",
        &[("csrf_token", &csrf), ("model", &model.to_string())],
        "beam.ply",
        "application/octet-stream",
        &good,
        false,
    );
    assert_eq!(r.status, 303, "{}", r.text());
    assert_eq!(
        r.header("location"),
        Some(format!("/models/{model}").as_str())
    );
    let jobs = admin.get("/api/v1/jobs?limit=1").json();
    let latest = jobs[0]["id"].as_i64().unwrap();
    assert_eq!(jobs[0]["model_id"], model);
    assert_eq!(wait_finished(&admin, latest, 120)["status"], "done");
    let r = admin.post_form(
        &format!("/admin/models/{model}/delete"),
        &[("csrf_token", &csrf)],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    assert_eq!(admin.get(&format!("/api/v1/models/{model}")).status, 404);
    // An editor may do neither.
    let editor = create_user(&server, &admin, "ed", "editor");
    let r = editor.request(
        "POST",
        &format!("/api/v1/models/upload?model={model}&filename=gate.ply"),
        Some("application/octet-stream"),
        good[..10].to_vec(),
        true,
    );
    assert_eq!(r.status, 403);
    no_leftovers(dir.path());
}

/// A glTF grid of `n`×`n` vertices whose buffer is the separate file `bin_name`.
fn gltf_with_bin(n: u32, bin_name: &str) -> (Vec<u8>, Vec<u8>) {
    let mut bin = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let (u, v) = (x as f32 / (n - 1) as f32, y as f32 / (n - 1) as f32);
            let z = 0.1 * (u * 9.0).sin() * (v * 7.0).cos();
            for c in [u, v, z] {
                bin.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    let positions = bin.len();
    let mut triangles = 0;
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            let i = y * n + x;
            for k in [i, i + 1, i + n + 1, i, i + n + 1, i + n] {
                bin.extend_from_slice(&k.to_le_bytes());
            }
            triangles += 2;
        }
    }
    let gltf = json!({
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"uri": bin_name, "byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": positions},
            {"buffer": 0, "byteOffset": positions, "byteLength": bin.len() - positions}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n * n, "type": "VEC3",
             "min": [0.0, 0.0, -0.1], "max": [1.0, 1.0, 0.1]},
            {"bufferView": 1, "componentType": 5125, "count": triangles * 3, "type": "SCALAR"}
        ]
    });
    (serde_json::to_vec(&gltf).unwrap(), bin)
}

#[test]
fn a_scan_uploads_with_the_files_it_refers_to() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let csrf = admin.csrf.clone().unwrap();
    let (gltf, bin) = gltf_with_bin(40, "grid.bin");
    let octet = "application/octet-stream";
    let form = |title: &str, files: &[(&str, &str, &[u8])]| {
        admin.upload_files(
            "/admin/jobs/upload",
            &[("csrf_token", &csrf), ("title", title)],
            files,
        )
    };

    // Refused at once, with a message: two scans, no scan, a name that climbs out.
    let r = form("Two", &[("a.gltf", octet, &gltf), ("b.ply", octet, b"ply")]);
    assert_eq!(r.status, 400);
    assert!(r.text().contains("one scan at a time"));
    let r = form("None", &[("grid.bin", octet, &bin)]);
    assert!(r.status == 400 && r.text().contains("none of the files is a scan"));
    let r = form(
        "Climb",
        &[("grid.gltf", octet, &gltf), ("../grid.bin", octet, &bin)],
    );
    assert!(
        r.status == 400 && r.text().contains("not a plain file name"),
        "{}",
        r.text()
    );
    assert!(
        names(&dir.path().join("uploads")).is_empty(),
        "refused uploads leave nothing"
    );

    // Without its buffer, the build fails and names the missing file.
    let r = form("Alone", &[("grid.gltf", "model/gltf+json", &gltf)]);
    assert_eq!(r.status, 303, "{}", r.text());
    let jobs = admin.get("/api/v1/jobs?limit=1").json();
    let job = wait_finished(&admin, jobs[0]["id"].as_i64().unwrap(), 60);
    assert_eq!(job["status"], "failed");
    assert!(
        job["message"]
            .as_str()
            .unwrap()
            .contains("cannot find 'grid.bin'"),
        "{job}"
    );

    // Picked together, or as their folder (the browser sends the folder in the names).
    for (title, files) in [
        ("Together", vec![("grid.gltf", &gltf), ("grid.bin", &bin)]),
        (
            "Folder",
            vec![
                ("scan/grid.bin", &bin),
                ("scan/grid.gltf", &gltf),
                ("scan/LICENSE.md", &b"CC BY".to_vec()),
            ],
        ),
    ] {
        let files: Vec<(&str, &str, &[u8])> = files
            .iter()
            .map(|(n, d)| (*n, octet, d.as_slice()))
            .collect();
        let r = form(title, &files);
        assert_eq!(r.status, 303, "{title}: {}", r.text());
        let model: i64 = r
            .header("location")
            .unwrap()
            .trim_start_matches("/models/")
            .parse()
            .unwrap();
        let jobs = admin.get("/api/v1/jobs?limit=1").json();
        assert_eq!(jobs[0]["model_id"], model);
        assert_eq!(jobs[0]["source_name"], "grid.gltf", "{title}");
        let bytes: usize = files.iter().map(|f| f.2.len()).sum();
        assert_eq!(jobs[0]["source_bytes"], bytes as i64);
        let job = wait_finished(&admin, jobs[0]["id"].as_i64().unwrap(), 120);
        assert_eq!(job["status"], "done", "{title}: {job}");
        let m = admin.get(&format!("/api/v1/models/{model}")).json();
        assert_eq!(
            (m["status"].as_str(), m["vertex_count"].as_i64()),
            (Some("ready"), Some(1600))
        );
    }
    // The inputs (files and folders) are gone once built or failed.
    no_leftovers(dir.path());
}
