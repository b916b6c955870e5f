//! The network mode (issue 12) over HTTP on the software adapter: a model's Grid-Lumigraph
//! image repository built as a job, described and served image by image (the images hold the
//! depth the server's own renderer sees from the described cameras), rebuilt and deleted
//! without leaving files; a build killed with `kill -9` resumes after restart; bad requests
//! are 4xx; and a model whose geometry stays on the server refuses its fine geometry to all
//! but admins.

use std::path::Path;

use meshwiki_engine::lumigraph::image as lumi_image;
use serde_json::{Value, json};

use crate::harness::*;
use crate::lod::{relief_ply, wait_finished, wait_job};
use crate::render::{Buffers, import, scan};

/// Files under `lumigraph/` (each an image).
fn stored_images(data: &Path) -> usize {
    let Ok(dirs) = std::fs::read_dir(data.join("lumigraph")) else {
        return 0;
    };
    dirs.flatten()
        .map(|d| std::fs::read_dir(d.path()).map_or(0, |f| f.count()))
        .sum()
}

fn start(admin: &Client, model: i64, body: Value) -> i64 {
    let r = admin.post(&format!("/api/v1/models/{model}/lumigraph"), &body);
    assert_eq!(r.status, 202, "{}", r.text());
    // A worker may have claimed the job before the answer was written.
    let status = r.json()["lumigraph"]["status"].clone();
    assert!(status == "queued" || status == "building", "{status}");
    assert_eq!(r.json()["job"]["kind"], "lumigraph");
    r.json()["job"]["id"].as_i64().unwrap()
}

fn v3(v: &Value) -> [f32; 3] {
    let a = v.as_array().expect("array");
    [0, 1, 2].map(|k| a[k].as_f64().unwrap() as f32)
}

/// Asserts that `img`, the image of direction `dd` from `eye`, holds the depth the server's
/// own renderer sees from the camera the description `d` gives (its direction, up, 90°).
fn assert_depth_is_the_renders(
    admin: &Client,
    model: i64,
    d: &Value,
    img: &lumi_image::LumigraphImage,
    eye: [f32; 3],
    dd: u32,
) {
    let side = d["box"]["side"].as_f64().unwrap() as f32;
    let (n, m) = (img.side as usize, img.depth_side as usize);
    let direction = &d["directions"][dd as usize];
    let (f, up) = (v3(&direction["forward"]), v3(&direction["up"]));
    let target: Vec<f32> = (0..3).map(|k| eye[k] + f[k]).collect();
    let csv = |v: &[f32]| {
        v.iter()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(",")
    };
    let buf = Buffers::parse(&admin.get(&format!(
        "/api/v1/models/{model}/render/buffers?eye={}&target={}&up={}&fovy=90&w={n}&h={n}&buffers=depth",
        csv(&eye),
        csv(&target),
        csv(&up)
    )));
    let depth = buf.floats("depth");
    // Within the codes' step (a fraction of a pixel's footprint, lumi_image::depth_codes).
    let step = (img.depth_range[1] - img.depth_range[0]) / (lumi_image::NO_DEPTH - 1) as f32;
    let (mut compared, mut agree) = (0, 0);
    for py in 0..m {
        for px in 0..m {
            let Some(stored) = img.depth_at(py * m + px) else {
                continue;
            };
            // The mean of the block's covered pixels.
            let covered: Vec<f32> = (0..16)
                .map(|k| depth[(4 * py + k / 4) * n + 4 * px + k % 4])
                .filter(|d| d.is_finite())
                .collect();
            if !covered.is_empty() {
                let mean = covered.iter().sum::<f32>() / covered.len() as f32;
                compared += 1;
                if (mean - stored).abs() <= 1e-3 * side + 0.5 * step {
                    agree += 1;
                }
            }
        }
    }
    assert!(compared > 20, "{compared} pixels compared");
    assert!(
        agree as f64 >= 0.95 * compared as f64,
        "{agree} of {compared} depths agree with the server's render"
    );
}

#[test]
fn an_image_repository_is_built_served_rebuilt_and_deleted() {
    let dir = data_dir_with_admin();
    let scans = tempfile::tempdir().unwrap();
    let model = import(dir.path(), &scan(scans.path()), "Lumigraph");
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let viewer = create_user(&server, &admin, "vera", "viewer");
    let base = format!("/api/v1/models/{model}/lumigraph");

    let d = viewer.get(&base).json();
    assert_eq!(d["status"], "none", "{d}");
    assert_eq!(d["directions"].as_array().unwrap().len(), 6);
    let msg = viewer
        .get(&format!("{base}/images/0/0/0/0"))
        .assert_error(404);
    assert!(msg.contains("no image repository"), "{msg}");

    // Bad requests.
    viewer.post(&base, &json!({"grid": 3})).assert_error(403);
    for bad in [
        json!({"grid": 0}),
        json!({"grid": 1000}),
        json!({"size": 100000}),
        json!({"size": 4}),
        json!({"grid": "three"}),
        json!({"points": 3}),
    ] {
        let msg = admin.post(&base, &bad).assert_error(400);
        assert!(!msg.is_empty(), "{bad}");
    }
    admin
        .post("/api/v1/models/999999/lumigraph", &json!({}))
        .assert_error(404);
    let msg = admin
        .post(&base, &json!({"grid": 64, "size": 512}))
        .assert_error(400);
    assert!(msg.contains("fewer grid points"), "{msg}");

    // Build a small repository and wait for it.
    let job = start(&admin, model, json!({"grid": 3, "size": 64}));
    admin.post(&base, &json!({"grid": 3})).assert_error(409);
    let j = wait_finished(&admin, job, 300);
    assert_eq!(j["status"], "done", "{j}");
    let report = &j["report"];
    let d = viewer.get(&base).json();
    assert_eq!(d["status"], "ready", "{d}");
    assert_eq!(
        (d["grid"].as_u64(), d["size"].as_u64()),
        (Some(3), Some(64))
    );
    let c = &d["counts"];
    assert_eq!(c["points"], 27, "{d}");
    let (images, empty, inside) = (
        c["images"].as_i64().unwrap(),
        c["empty"].as_i64().unwrap(),
        c["inside_points"].as_i64().unwrap(),
    );
    assert_eq!(images + empty + 6 * inside, 27 * 6, "{d}");
    assert!(images > 0 && empty > 0, "{d}");
    assert_eq!(report["images"], images);
    assert_eq!(stored_images(dir.path()) as i64, images);

    // Every key: an image of the described size, or nothing.
    let (mut got_images, mut got_empty, mut bytes) = (0, 0, 0);
    let mut best: Option<(usize, [u32; 4], lumi_image::LumigraphImage)> = None;
    for x in 0..3u32 {
        for y in 0..3u32 {
            for z in 0..3u32 {
                for dd in 0..6u32 {
                    let r = viewer.get(&format!("{base}/images/{x}/{y}/{z}/{dd}?v={job}"));
                    match r.status {
                        200 => {
                            assert_eq!(
                                r.header("content-type"),
                                Some("application/vnd.meshwiki.lumigraph-image")
                            );
                            assert!(r.header("cache-control").unwrap().contains("immutable"));
                            let img = lumi_image::decode(&r.body).expect("decodable image");
                            assert_eq!((img.side, img.depth_side), (64, 16));
                            assert_eq!(d["depth_size"], 16);
                            let seen = (0..img.depth.len())
                                .filter(|&i| img.depth_at(i).is_some())
                                .count();
                            assert!(seen > 0, "an image that shows something");
                            if best.as_ref().is_none_or(|b| seen > b.0) {
                                best = Some((seen, [x, y, z, dd], img));
                            }
                            got_images += 1;
                            bytes += r.body.len() as i64;
                            let etag = r.header("etag").unwrap().to_string();
                            let again = viewer.request_with(
                                "GET",
                                &format!("{base}/images/{x}/{y}/{z}/{dd}"),
                                None,
                                Vec::new(),
                                true,
                                &[("If-None-Match", &etag)],
                            );
                            assert_eq!(again.status, 304);
                        }
                        204 => got_empty += 1,
                        s => panic!("({x}, {y}, {z}, {dd}): {s} {}", r.text()),
                    }
                }
            }
        }
    }
    assert_eq!(got_images, images);
    assert_eq!(got_empty, empty + 6 * inside);
    assert_eq!(bytes, c["bytes"].as_i64().unwrap());
    viewer
        .get(&format!("{base}/images/3/0/0/0"))
        .assert_error(404);
    viewer
        .get(&format!("{base}/images/0/0/0/6"))
        .assert_error(404);
    viewer
        .get(&format!("{base}/images/0/0/0/0?v={}", job + 1))
        .assert_error(404);

    // The fullest image holds the depth the server's renderer sees from the camera the
    // description gives (grid point, direction, up, 90°): a client reprojects it exactly.
    let (_, [x, y, z, dd], img) = best.expect("some image");
    let (min, side, spacing) = (
        v3(&d["box"]["min"]),
        d["box"]["side"].as_f64().unwrap() as f32,
        d["spacing"].as_f64().unwrap() as f32,
    );
    assert!((spacing - side / 2.0).abs() < 1e-4 * side);
    let at = |level: u32, p: [u32; 3]| -> [f32; 3] {
        let s = spacing / (1 << level) as f32;
        [0, 1, 2].map(|k| min[k] + p[k] as f32 * s)
    };
    assert_depth_is_the_renders(&admin, model, &d, &img, at(0, [x, y, z]), dd);

    // Refinement levels: a point of level 2 just above the model is rendered when first
    // asked for, stored, and then served like the others; a level-2 name of a level-0 point
    // is that point; a point away from the model, or a level beyond the finest, is 404.
    let levels = d["levels"].as_u64().unwrap() as u32;
    assert!(levels >= 2, "{d}");
    let model_max = v3(&d["model_box"][1]);
    let s2 = spacing / 4.0;
    let above = (model_max[2] - min[2]) / s2;
    let mut kz = above.ceil() as u32;
    if kz.is_multiple_of(2) {
        kz += 1;
    }
    assert!((kz as f32 - above) * s2 <= d["refine_margin"].as_f64().unwrap() as f32 * s2);
    let stored_before = stored_images(dir.path());
    let url = format!("{base}/images/4/4/{kz}/5?level=2&v={job}");
    let r = viewer.get(&url);
    assert_eq!(r.status, 200, "{}", r.text());
    let img = lumi_image::decode(&r.body).expect("decodable image");
    assert!((0..img.depth.len()).any(|i| img.depth_at(i).is_some()));
    assert_depth_is_the_renders(&admin, model, &d, &img, at(2, [4, 4, kz]), 5);
    let etag = r.header("etag").unwrap().to_string();
    let again = viewer.get(&url);
    assert_eq!(
        (again.status, again.header("etag")),
        (200, Some(etag.as_str()))
    );
    assert_eq!(again.body, r.body);
    assert_eq!(stored_images(dir.path()), stored_before + 1);
    let c = viewer.get(&base).json()["counts"].clone();
    assert_eq!(
        (c["refined_images"].as_i64(), c["images"].as_i64()),
        (Some(1), Some(images))
    );
    assert_eq!(c["refined_bytes"].as_i64(), Some(r.body.len() as i64));
    let coarse = viewer.get(&format!("{base}/images/{x}/{y}/{z}/{dd}"));
    let named_finer = viewer.get(&format!(
        "{base}/images/{}/{}/{}/{dd}?level=2",
        4 * x,
        4 * y,
        4 * z
    ));
    assert_eq!((named_finer.status, &named_finer.body), (200, &coarse.body));
    let msg = viewer
        .get(&format!("{base}/images/0/0/1/0?level=2"))
        .assert_error(404);
    assert!(msg.contains("not refined"), "{msg}");
    let msg = viewer
        .get(&format!("{base}/images/0/0/0/0?level={}", levels + 1))
        .assert_error(404);
    assert!(msg.contains("beyond the finest"), "{msg}");
    viewer
        .get(&format!("{base}/images/9/0/0/0?level=2"))
        .assert_error(404);

    // Rebuilt on another grid: the old images go, the new ones are served.
    let job2 = start(&admin, model, json!({"grid": 2, "size": 32}));
    let j = wait_finished(&admin, job2, 300);
    assert_eq!(j["status"], "done", "{j}");
    let d = viewer.get(&base).json();
    assert_eq!(d["counts"]["points"], 8, "{d}");
    assert_eq!(
        stored_images(dir.path()) as i64,
        d["counts"]["images"].as_i64().unwrap()
    );
    viewer
        .get(&format!("{base}/images/0/0/0/0?v={job}"))
        .assert_error(404);

    // Deleting the model removes its images.
    assert_eq!(admin.delete(&format!("/api/v1/models/{model}")).status, 204);
    assert_eq!(stored_images(dir.path()), 0);
    admin.get(&base).assert_error(404);
}

/// Readers have refined images rendered on first request; their storage is capped per
/// model (`--refined-images-cap`): past it a new one is 503 with the reason, while what is
/// stored and the build's own level are still served.
#[test]
fn refined_images_stop_at_their_storage_cap() {
    let dir = data_dir_with_admin();
    let scans = tempfile::tempdir().unwrap();
    let model = import(dir.path(), &scan(scans.path()), "Capped");
    // One byte: the first refined image is rendered, none after it.
    let server = Server::start_with(dir.path(), &["--refined-images-cap", "1"]);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let viewer = create_user(&server, &admin, "vera", "viewer");
    let base = format!("/api/v1/models/{model}/lumigraph");
    let job = start(&admin, model, json!({"grid": 3, "size": 32}));
    let j = wait_finished(&admin, job, 300);
    assert_eq!(j["status"], "done", "{j}");
    let d = viewer.get(&base).json();
    let (min, spacing) = (v3(&d["box"]["min"]), d["spacing"].as_f64().unwrap() as f32);
    // A level-2 point just above the model (as the test above).
    let s2 = spacing / 4.0;
    let above = (v3(&d["model_box"][1])[2] - min[2]) / s2;
    let mut kz = above.ceil() as u32;
    if kz.is_multiple_of(2) {
        kz += 1;
    }
    let stored_before = stored_images(dir.path());
    let first = viewer.get(&format!("{base}/images/4/4/{kz}/5?level=2"));
    assert_eq!(first.status, 200, "{}", first.text());
    assert_eq!(stored_images(dir.path()), stored_before + 1);
    let msg = viewer
        .get(&format!("{base}/images/4/4/{kz}/4?level=2"))
        .assert_error(503);
    assert!(msg.contains("storage cap"), "{msg}");
    assert_eq!(
        stored_images(dir.path()),
        stored_before + 1,
        "nothing stored past the cap"
    );
    let c = viewer.get(&base).json()["counts"].clone();
    assert_eq!(c["refined_images"].as_i64(), Some(1), "{c}");
    // What is stored is served, and so is level 0.
    let again = viewer.get(&format!("{base}/images/4/4/{kz}/5?level=2"));
    assert_eq!((again.status, &again.body), (200, &first.body));
    let coarse = viewer.get(&format!("{base}/images/0/0/0/0"));
    assert!(
        coarse.status == 200 || coarse.status == 204,
        "{}",
        coarse.status
    );
}

#[test]
fn a_repository_build_killed_mid_way_resumes_after_restart() {
    let dir = data_dir_with_admin();
    let scans = tempfile::tempdir().unwrap();
    let model = import(
        dir.path(),
        &relief_ply(scans.path(), "relief.ply", 20_000),
        "Resume",
    );
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let base = format!("/api/v1/models/{model}/lumigraph");
    let job = start(&admin, model, json!({"grid": 7, "size": 32}));
    wait_job(&admin, job, 300, |j| {
        j["status"] == "running" && j["done"].as_i64().unwrap_or(0) >= 40
    });
    let before = admin.get(&base).json()["counts"]["points"]
        .as_i64()
        .unwrap();
    server.kill9();
    assert!(
        (40..343).contains(&before),
        "{before} points before the kill"
    );

    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let j = wait_finished(&admin, job, 600);
    assert_eq!(j["status"], "done", "{j}");
    assert_eq!(j["attempts"], 2, "{j}");
    let d = admin.get(&base).json();
    assert_eq!(d["status"], "ready");
    assert_eq!(d["counts"]["points"], 343, "{d}");
    assert_eq!(
        stored_images(dir.path()) as i64,
        d["counts"]["images"].as_i64().unwrap()
    );
    // The model itself stayed ready throughout.
    assert_eq!(
        admin.get(&format!("/api/v1/models/{model}")).json()["status"],
        "ready"
    );
}

#[test]
fn geometry_kept_on_the_server_is_refused_to_all_but_admins() {
    let dir = data_dir_with_admin();
    let scans = tempfile::tempdir().unwrap();
    let model = import(
        dir.path(),
        &relief_ply(scans.path(), "relief.ply", 60_000),
        "Sparse",
    );
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let editor = create_user(&server, &admin, "eddie", "editor");
    let viewer = create_user(&server, &admin, "vera", "viewer");
    let m = format!("/api/v1/models/{model}");
    assert_eq!(viewer.get(&m).json()["geometry_access"], "full");

    let lod = viewer.get(&format!("{m}/lod")).json();
    let nodes = lod["nodes"].as_array().unwrap();
    let leaf = nodes.iter().find(|n| n["level"] == 0).unwrap()["id"].clone();
    let top = nodes
        .iter()
        .map(|n| n["level"].as_u64().unwrap())
        .max()
        .unwrap();
    let root = nodes.iter().find(|n| n["level"] == top).unwrap()["id"].clone();
    let leaf_url = format!("{m}/lod/patches/{leaf}");
    let root_url = format!("{m}/lod/patches/{root}");
    let depth_url = format!("{m}/render/buffers?w=64&h=48&buffers=depth");
    assert_eq!(viewer.get(&leaf_url).status, 200);

    editor
        .patch(&m, &json!({"geometry_access": "sparse"}))
        .assert_error(403);
    admin
        .patch(&m, &json!({"geometry_access": "partial"}))
        .assert_error(400);
    let r = admin.patch(&m, &json!({"geometry_access": "sparse"}));
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["geometry_access"], "sparse");

    for c in [&viewer, &editor] {
        let msg = c.get(&leaf_url).assert_error(403);
        assert!(msg.contains("geometry_access = sparse"), "{msg}");
        c.get(&format!("{m}/lod/file")).assert_error(403);
        c.get(&depth_url).assert_error(403);
        c.get(&format!("{m}/render/buffers?w=64&h=48&buffers=ids"))
            .assert_error(403);
        // The sparse mesh, the hierarchy and images stay readable.
        assert_eq!(c.get(&root_url).status, 200);
        assert_eq!(c.get(&format!("{m}/lod")).status, 200);
        assert_eq!(c.get(&format!("{m}/render?w=64&h=48")).status, 200);
        assert_eq!(
            c.get(&format!("{m}/render/buffers?w=64&h=48&buffers=color"))
                .status,
            200
        );
    }
    // Every patch the viewer may read is in the sparse mesh or coarser, and that mesh is a
    // fraction of the scan.
    let sparse = viewer.get(&format!("{m}/lumigraph")).json()["sparse"]["error"]
        .as_f64()
        .unwrap();
    let (mut allowed, mut refused) = (0, 0);
    for n in nodes {
        let url = format!("{m}/lod/patches/{}", n["id"]);
        let coarse = n["parent_error"].as_f64().is_none_or(|e| e > sparse);
        let status = viewer.get(&url).status;
        assert_eq!(status, if coarse { 200 } else { 403 }, "node {n}");
        if coarse { allowed += 1 } else { refused += 1 }
    }
    assert!(
        allowed > 0 && refused > allowed,
        "{allowed} allowed, {refused} refused"
    );
    // Admins read everything.
    assert_eq!(admin.get(&leaf_url).status, 200);
    assert_eq!(admin.get(&format!("{m}/lod/file")).status, 200);
    assert_eq!(admin.get(&depth_url).status, 200);

    // Back to full.
    let r = admin.patch(&m, &json!({"geometry_access": "full"}));
    assert_eq!(r.status, 200);
    assert_eq!(viewer.get(&leaf_url).status, 200);
}

#[test]
fn admins_set_the_access_and_build_the_repository_from_the_model_page() {
    let dir = data_dir_with_admin();
    let scans = tempfile::tempdir().unwrap();
    let model = import(
        dir.path(),
        &relief_ply(scans.path(), "relief.ply", 8_000),
        "Page",
    );
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let viewer = create_user(&server, &admin, "vera", "viewer");
    let csrf = admin.csrf.clone().unwrap();
    let page = format!("/models/{model}");

    let html = admin.get(&page).text();
    assert!(
        html.contains("name=\"sparse\""),
        "access form offers the geometry setting"
    );
    assert!(html.contains("Build image repository"), "repository form");
    let seen = viewer.get(&page).text();
    assert!(!seen.contains("lumigraph-form") && !seen.contains("name=\"sparse\""));
    let data = |html: &str| -> Value {
        let start = html.find("id=\"viewer-data\">").unwrap() + "id=\"viewer-data\">".len();
        let end = start + html[start..].find("</script>").unwrap();
        serde_json::from_str(&html[start..end]).unwrap()
    };
    assert_eq!(data(&seen)["geometry"]["full"], true);

    // The access form: geometry kept on the server (the model stays private).
    let r = admin.post_form(
        &format!("{page}/public"),
        &[("csrf_token", &csrf), ("sparse", "1")],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let m = admin.get(&format!("/api/v1/models/{model}")).json();
    assert_eq!(
        (m["geometry_access"].as_str(), m["public"].as_bool()),
        (Some("sparse"), Some(false))
    );
    let seen = data(&viewer.get(&page).text());
    assert_eq!(seen["geometry"]["full"], false, "{seen}");
    assert!(seen["geometry"]["sparse_error"].as_f64().unwrap() > 0.0);
    assert_eq!(data(&admin.get(&page).text())["geometry"]["full"], true);
    // A viewer cannot post it.
    let vcsrf = viewer.csrf.clone().unwrap();
    let r = viewer.post_form(&format!("{page}/public"), &[("csrf_token", &vcsrf)]);
    assert_eq!(r.status, 403);

    // The repository form queues a job; the page then shows its status.
    let r = viewer.post_form(
        &format!("{page}/lumigraph"),
        &[("csrf_token", &vcsrf), ("grid", "2"), ("size", "32")],
    );
    assert_eq!(r.status, 403);
    let r = admin.post_form(
        &format!("{page}/lumigraph"),
        &[("csrf_token", &csrf), ("grid", "2"), ("size", "32")],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let job = admin
        .get(&format!("/api/v1/models/{model}/lumigraph"))
        .json()["job_id"]
        .as_i64()
        .unwrap();
    assert_eq!(wait_finished(&admin, job, 120)["status"], "done");
    let html = admin.get(&page).text();
    assert!(
        html.contains("status-ready"),
        "repository ready on the page"
    );
    assert!(html.contains("Rebuild image repository"));
    let r = admin.post_form(
        &format!("{page}/lumigraph"),
        &[("csrf_token", &csrf), ("grid", "0"), ("size", "32")],
    );
    assert_eq!(r.status, 400, "{}", r.text());
}
