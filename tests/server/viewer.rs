//! The 3D viewer's server side: its modules and vendor files (allow-listed, no traversal), the
//! CSP that lets them run, the page without the front-end packages, and the live event stream.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::json;

use crate::harness::{ADMIN_PASSWORD, BIN, Server, data_dir_with_admin};

/// Starts `meshwiki serve` with an extra environment variable.
fn start_with_env(data_dir: &Path, key: &str, value: &str) -> Server {
    let mut child = Command::new(BIN)
        .args([
            "serve",
            "--bind",
            "127.0.0.1:0",
            "--workers",
            "2",
            "--data-dir",
        ])
        .arg(data_dir)
        .env("MESHWIKI_LOG", "warn")
        .env(key, value)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn meshwiki serve");
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if let Some(addr) = line.strip_prefix("meshwiki listening on ") {
                let _ = tx.send(addr.to_string());
            }
        }
    });
    let base = rx
        .recv_timeout(Duration::from_secs(60))
        .expect("server started");
    Server {
        child,
        base,
        data_dir: data_dir.to_path_buf(),
    }
}

#[test]
fn viewer_modules_and_vendor_files_are_served_from_allow_lists() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let c = server.login("admin", ADMIN_PASSWORD);
    let main = c.get("/static/js/viewer/main.js");
    assert_eq!(main.status, 200);
    assert!(
        main.header("content-type")
            .unwrap_or("")
            .starts_with("text/javascript")
    );
    assert!(main.text().contains("meshwikiViewer"));
    assert_eq!(c.get("/static/js/lod/decode.js").status, 200);
    assert_eq!(c.get("/static/js/nope.js").status, 404);
    let csp = main
        .header("content-security-policy")
        .unwrap_or("")
        .to_string();
    assert!(
        csp.contains("'wasm-unsafe-eval'") && csp.contains("'sha256-"),
        "{csp}"
    );
    assert!(
        !csp.contains("'unsafe-inline'") && !csp.contains("'unsafe-eval'"),
        "{csp}"
    );
    let installed = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("static/node_modules/three/build/three.module.js")
        .is_file();
    let three = c.get("/static/vendor/three/build/three.module.js");
    if installed {
        assert_eq!(three.status, 200);
        assert!(three.text().contains("REVISION"));
    } else {
        eprintln!("static/node_modules is not installed: vendor file contents not checked");
        assert_eq!(three.status, 404);
    }
    for path in [
        "/static/vendor/three/package.json",
        "/static/vendor/three/build/../../../../Cargo.toml",
        "/static/vendor/%2e%2e/%2e%2e/Cargo.toml",
        "/static/vendor/three%2Fbuild%2F..%2F..%2Fpackage.json",
        "/static/vendor//etc/passwd",
        "/static/js/../../Cargo.toml",
    ] {
        let r = c.get(path);
        assert_eq!(r.status, 404, "{path} must not be served");
    }
}

#[test]
fn without_front_end_packages_the_server_runs_and_the_page_says_so() {
    let dir = data_dir_with_admin();
    let empty = tempfile::tempdir().expect("tempdir");
    let server = start_with_env(
        dir.path(),
        "MESHWIKI_NODE_MODULES",
        &empty.path().display().to_string(),
    );
    let c = server.login("admin", ADMIN_PASSWORD);
    let r = c.send_json("POST", "/api/v1/models", &json!({"title": "Lion"}));
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_i64().expect("id");
    let page = c.get(&format!("/models/{id}"));
    assert_eq!(page.status, 200);
    let html = page.text();
    assert!(
        html.contains("The 3D viewer is unavailable on this server"),
        "{html}"
    );
    assert!(
        !html.contains("/static/js/viewer/main.js"),
        "no viewer script without its packages"
    );
    assert!(!html.contains("importmap"));
    assert!(
        html.contains("No parts have been identified"),
        "page still readable"
    );
    assert_eq!(
        c.get("/static/vendor/three/build/three.module.js").status,
        404
    );
}

/// Reads from an event stream until `needle` appears (or panics after `secs`).
fn read_until(stream: &mut TcpStream, seen: &mut String, needle: &str, secs: u64) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    let mut buf = [0u8; 4096];
    while !seen.contains(needle) {
        assert!(Instant::now() < deadline, "no {needle:?} in {seen:?}");
        match stream.read(&mut buf) {
            Ok(0) => panic!("stream closed before {needle:?}: {seen:?}"),
            Ok(n) => seen.push_str(&String::from_utf8_lossy(&buf[..n])),
            Err(e)
                if e.kind() == std::io::ErrorKind::WouldBlock
                    || e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("read: {e}"),
        }
    }
}

#[test]
fn live_events_reach_viewers_of_the_model_uncompressed() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let c = server.login("admin", ADMIN_PASSWORD);
    let model = c
        .send_json("POST", "/api/v1/models", &json!({"title": "Stele"}))
        .json();
    let other = c
        .send_json("POST", "/api/v1/models", &json!({"title": "Other"}))
        .json();
    let id = model["id"].as_i64().expect("id");
    let other_id = other["id"].as_i64().expect("id");
    assert_eq!(
        server
            .client()
            .get(&format!("/api/v1/models/{id}/events"))
            .status,
        401,
        "events need a session"
    );
    assert_eq!(c.get("/api/v1/models/999999/events").status, 404);

    let addr = server.base.trim_start_matches("http://").to_string();
    let mut stream = TcpStream::connect(&addr).expect("connect");
    stream
        .set_read_timeout(Some(Duration::from_millis(200)))
        .expect("timeout");
    let cookie = c.cookie.clone().expect("cookie");
    write!(
        stream,
        "GET /api/v1/models/{id}/events HTTP/1.1\r\nHost: {addr}\r\nCookie: {cookie}\r\nAccept: text/event-stream\r\nAccept-Encoding: gzip, br\r\n\r\n"
    )
    .expect("request");
    let mut seen = String::new();
    read_until(&mut stream, &mut seen, "event: hello", 10);
    let head = seen.to_ascii_lowercase();
    assert!(head.contains("content-type: text/event-stream"), "{seen}");
    assert!(
        !head.contains("content-encoding: gzip") && !head.contains("content-encoding: br"),
        "{seen}"
    );

    // A part on another model is not sent; one on this model is, within a second.
    let r = c.send_json(
        "POST",
        &format!("/api/v1/models/{other_id}/parts"),
        &json!({"kind": "point", "center": [0, 0, 0]}),
    );
    assert_eq!(r.status, 201);
    let r = c.send_json(
        "POST",
        &format!("/api/v1/models/{id}/parts"),
        &json!({"kind": "point", "center": [1, 2, 3]}),
    );
    assert_eq!(r.status, 201);
    let part = r.json()["id"].as_i64().expect("part id");
    read_until(&mut stream, &mut seen, &format!("\"part_id\":{part}"), 5);
    assert!(
        seen.contains("event: change") && seen.contains("\"type\":\"part.created\""),
        "{seen}"
    );
    assert!(
        !seen.contains(&format!("\"model_id\":{other_id}")),
        "other model's event leaked: {seen}"
    );

    // Assigning a content and saving it are announced too.
    let content = c
        .send_json("POST", "/api/v1/contents", &json!({"title": "Dedication"}))
        .json();
    let cid = content["id"].as_i64().expect("content id");
    let r = c.send_json(
        "POST",
        &format!("/api/v1/parts/{part}/contents"),
        &json!({"content_id": cid}),
    );
    assert_eq!(r.status, 201, "{}", r.text());
    read_until(&mut stream, &mut seen, "\"type\":\"part.contents\"", 5);
    let r = c.send_json(
        "PUT",
        &format!("/api/v1/contents/{cid}"),
        &json!({"base_revision": 1, "title": "Dedication to Hathor"}),
    );
    assert_eq!(r.status, 200, "{}", r.text());
    read_until(
        &mut stream,
        &mut seen,
        &format!(
            "\"type\":\"content.updated\",\"model_id\":null,\"part_id\":null,\"content_id\":{cid}"
        ),
        5,
    );
    let r = c.request(
        "DELETE",
        &format!("/api/v1/parts/{part}"),
        None,
        Vec::new(),
        true,
    );
    assert_eq!(r.status, 204);
    read_until(&mut stream, &mut seen, "\"type\":\"part.deleted\"", 5);
}
