//! The command line: `user add`, `reindex`, `demo`, and that benchmarks are not in it.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use serde_json::json;

use crate::harness::*;

#[test]
fn user_add_reads_the_password_from_stdin() {
    let dir = tempfile::tempdir().unwrap();
    let out = add_user(dir.path(), "alice", "editor", "alice-password");
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("created user alice (editor)"));
    // A duplicate, a bad role or a short password fail with a message.
    let out = add_user(dir.path(), "alice", "editor", "alice-password");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("already exists"));
    let out = add_user(dir.path(), "bob", "root", "bob-password");
    assert!(!out.status.success());
    let out = add_user(dir.path(), "bob", "viewer", "short");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("password"));
    // The data directory can also come from the environment.
    let out = Command::new(BIN)
        .args(["user", "add", "carol", "--role", "viewer"])
        .env("MESHWIKI_DATA_DIR", dir.path())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .and_then(|mut c| {
            use std::io::Write;
            c.stdin.take().unwrap().write_all(b"carol-password\n")?;
            c.wait_with_output()
        })
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let server = Server::start(dir.path());
    server.login("carol", "carol-password");
}

#[test]
fn reindex_rebuilds_the_index() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let c = create_content(&admin, "Reindexed", "ossuary");
    // While the server runs, reindex refuses (the index is locked) with a message.
    let out = Command::new(BIN)
        .args(["reindex", "--data-dir"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!out.status.success());
    drop(server);
    std::fs::remove_dir_all(dir.path().join("index")).unwrap();
    let out = Command::new(BIN)
        .args(["reindex", "--data-dir"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("reindexed 1 contents"));
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    assert_eq!(
        admin.get("/api/v1/search?q=ossuary").json()[0]["id"],
        c["id"]
    );
}

#[test]
fn demo_prints_credentials_seeds_and_serves() {
    let dir = tempfile::tempdir().unwrap();
    let run_demo = || {
        let mut child = Command::new(BIN)
            .args(["demo", "--bind", "127.0.0.1:0", "--data-dir"])
            .arg(dir.path())
            .env("MESHWIKI_LOG", "warn")
            .env("MESHWIKI_DEMO_TRIANGLES", "20000")
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
        let (mut password, mut base) = (String::new(), String::new());
        for line in lines.by_ref() {
            let line = line.unwrap();
            if let Some(p) = line.trim().strip_prefix("password: ") {
                password = p.to_string();
            }
            if let Some(b) = line.strip_prefix("meshwiki listening on ") {
                base = b.to_string();
                break;
            }
        }
        assert!(!password.is_empty() && !base.is_empty());
        (child, password, base)
    };
    let (mut child, password, base) = run_demo();
    let mut c = Client::new(&base);
    assert_eq!(c.login("demo", &password).status, 200);
    // The generated demo scan is built through the job pipeline, then seeded with a region
    // part on its sun disk and a content assigned to it.
    let models = c.get("/api/v1/models").json();
    assert_eq!(models.as_array().unwrap().len(), 1, "{models}");
    let model = models[0]["id"].as_i64().unwrap();
    let jobs = c.get("/api/v1/jobs").json();
    assert_eq!(jobs[0]["kind"], "demo", "{jobs}");
    let job = crate::lod::wait_finished(&c, jobs[0]["id"].as_i64().unwrap(), 120);
    assert_eq!(job["status"], "done", "{job}");
    let m = c.get(&format!("/api/v1/models/{model}")).json();
    assert_eq!(m["status"], "ready");
    assert!(m["thumbnail_attachment_id"].is_i64());
    assert_eq!(c.get(&format!("/api/v1/models/{model}/lod")).status, 200);
    let parts = c.get(&format!("/api/v1/models/{model}/parts")).json();
    assert_eq!(parts.as_array().unwrap().len(), 1, "{parts}");
    assert_eq!(parts[0]["kind"], "region");
    assert!(parts[0]["vertex_count"].as_i64() > Some(100), "{parts}");
    let assigned = c
        .get(&format!("/api/v1/parts/{}/contents", parts[0]["id"]))
        .json();
    assert_eq!(assigned[0]["title"], "Sun disk with rays");
    assert!(
        !c.get("/api/v1/search?q=ochre")
            .json()
            .as_array()
            .unwrap()
            .is_empty(),
        "the seeded content is searchable"
    );
    let contents = c.get("/api/v1/contents").json();
    let n = contents.as_array().unwrap().len();
    assert!(n >= 3, "seeded contents: {contents}");
    assert!(
        contents
            .as_array()
            .unwrap()
            .iter()
            .any(|c| c["current_revision"].as_i64() > Some(1))
    );
    assert!(
        !c.get("/api/v1/search?q=inscription")
            .json()
            .as_array()
            .unwrap()
            .is_empty()
    );
    let with_attachment = c.get("/api/v1/search?q=rubbing").json()[0]["id"]
        .as_i64()
        .unwrap();
    let atts = c
        .get(&format!("/api/v1/contents/{with_attachment}/attachments"))
        .json();
    let png = c.get(&format!("/api/v1/attachments/{}/download", atts[0]["id"]));
    assert_eq!(&png.body[1..4], b"PNG");
    child.kill().unwrap();
    let _ = child.wait();

    // A second run resets the password and does not seed again.
    std::thread::sleep(Duration::from_millis(100));
    let (mut child, password2, base) = run_demo();
    assert_ne!(password, password2);
    let mut c = Client::new(&base);
    assert_eq!(c.login("demo", &password).status, 401);
    assert_eq!(c.login("demo", &password2).status, 200);
    assert_eq!(
        c.get("/api/v1/contents").json().as_array().unwrap().len(),
        n
    );
    // The demo scan is not built again.
    assert_eq!(c.get("/api/v1/models").json().as_array().unwrap().len(), 1);
    assert_eq!(c.get("/api/v1/jobs").json().as_array().unwrap().len(), 1);
    assert_eq!(
        c.post("/api/v1/preview", &json!({"body": "*x*"})).json()["html"],
        "<p><em>x</em></p>\n"
    );
    child.kill().unwrap();
    let _ = child.wait();
}

#[test]
fn the_product_binary_has_no_benchmarks() {
    let out = Command::new(BIN)
        .args(["bench", "search"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let help = Command::new(BIN).arg("--help").output().unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(help.contains("serve") && !help.contains("bench"), "{help}");
}
