//! Public read-only access per model (issue 16, item 5): an admin opens a model to anonymous
//! visitors, who may then view it (its page, hierarchy, patches, renders, parts), search and
//! read the information on its parts — and nothing else: every other model and content stays
//! behind the login, and every write answers 401.

use serde_json::{Value, json};

use crate::harness::*;
use crate::lod::{relief_ply, upload_scan, wait_finished};

/// Uploads and builds a relief; returns the model id.
fn built_model(admin: &Client, title: &str, dir: &std::path::Path) -> i64 {
    let data = std::fs::read(relief_ply(dir, &format!("{title}.ply"), 3_000)).unwrap();
    let r = upload_scan(admin, title, "scan.ply", data);
    assert_eq!(r.status, 202, "{}", r.text());
    let job = r.json()["job"]["id"].as_i64().unwrap();
    assert_eq!(wait_finished(admin, job, 120)["status"], "done");
    r.json()["model"]["id"].as_i64().unwrap()
}

/// A region part on `model` with a content (and an attached image) about `word`.
fn part_with_content(admin: &Client, model: i64, word: &str) -> (i64, i64, i64) {
    let part = admin.post(
        &format!("/api/v1/models/{model}/parts"),
        &json!({"kind": "region", "center": [0.0, 0.0, 0.0], "vertex_ids": [0, 1, 2]}),
    );
    assert_eq!(part.status, 201, "{}", part.text());
    let part = part.json()["id"].as_i64().unwrap();
    let content = create_content(admin, &format!("The {word}"), &format!("About the {word}."));
    let content = content["id"].as_i64().unwrap();
    let r = admin.post(
        &format!("/api/v1/parts/{part}/contents"),
        &json!({"content_id": content}),
    );
    assert_eq!(r.status, 201, "{}", r.text());
    let r = admin.upload(
        &format!("/api/v1/contents/{content}/attachments"),
        &[],
        "note.txt",
        "text/plain",
        word.as_bytes(),
        true,
    );
    assert_eq!(r.status, 201, "{}", r.text());
    (part, content, r.json()["id"].as_i64().unwrap())
}

#[test]
fn anonymous_visitors_read_public_models_only_and_never_write() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let editor = create_user(&server, &admin, "ed", "editor");
    let scans = tempfile::tempdir().unwrap();
    let open = built_model(&admin, "Open", scans.path());
    let closed = built_model(&admin, "Closed", scans.path());
    let (op, oc, oa) = part_with_content(&admin, open, "rosette");
    let (cp, cc, ca) = part_with_content(&admin, closed, "gargoyle");
    let anon = server.client();

    // Nothing is public yet.
    anon.get("/api/v1/models").assert_error(401);
    anon.get("/api/v1/search?q=rosette").assert_error(401);
    anon.get(&format!("/api/v1/models/{open}"))
        .assert_error(401);
    let r = anon.get("/models");
    assert_eq!(r.status, 303);
    assert!(r.header("location").unwrap().starts_with("/login"));

    // Only an admin opens a model.
    let r = editor.patch(&format!("/api/v1/models/{open}"), &json!({"public": true}));
    assert_eq!(r.status, 403, "{}", r.text());
    let r = admin.patch(&format!("/api/v1/models/{open}"), &json!({"public": true}));
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["public"], true);

    // The public model and what hangs on it are readable without an account.
    let list = anon.get("/api/v1/models").json();
    let ids: Vec<i64> = list
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["id"].as_i64().unwrap())
        .collect();
    assert_eq!(ids, vec![open]);
    for path in [
        format!("/api/v1/models/{open}"),
        format!("/api/v1/models/{open}/lod"),
        format!("/api/v1/models/{open}/lod/patches/0"),
        format!("/api/v1/models/{open}/parts"),
        format!("/api/v1/parts/{op}"),
        format!("/api/v1/parts/{op}/vertices"),
        format!("/api/v1/parts/{op}/contents"),
        format!("/api/v1/contents/{oc}"),
        format!("/api/v1/attachments/{oa}"),
        format!("/api/v1/attachments/{oa}/download"),
        "/api/v1/config".to_string(),
    ] {
        assert_eq!(anon.get(&path).status, 200, "{path}");
    }
    let render = anon
        .get(&format!("/api/v1/models/{open}/render?w=32&h=24"))
        .status;
    assert!(render == 200 || render == 503, "render: {render}");
    // Everything else stays behind the login.
    for path in [
        format!("/api/v1/models/{closed}"),
        format!("/api/v1/models/{closed}/lod"),
        format!("/api/v1/models/{closed}/lod/patches/0"),
        format!("/api/v1/models/{closed}/render?w=32&h=24"),
        format!("/api/v1/models/{closed}/parts"),
        format!("/api/v1/parts/{cp}"),
        format!("/api/v1/parts/{cp}/vertices"),
        format!("/api/v1/parts/{cp}/contents"),
        format!("/api/v1/contents/{cc}"),
        format!("/api/v1/attachments/{ca}/download"),
        format!("/api/v1/parts/{op}/revisions"),
        "/api/v1/contents".to_string(),
        "/api/v1/users".to_string(),
        "/api/v1/jobs".to_string(),
        format!("/api/v1/search?q=gargoyle&model={closed}"),
    ] {
        assert_eq!(anon.get(&path).status, 401, "{path}");
    }
    // Search finds the public model's information only, and links its parts only.
    let hits = anon.get("/api/v1/search?q=rosette").json();
    assert_eq!(hits.as_array().unwrap().len(), 1, "{hits}");
    assert_eq!(hits[0]["id"], oc);
    assert_eq!(hits[0]["parts"][0]["model_id"], open);
    assert_eq!(anon.get("/api/v1/search?q=gargoyle").json(), json!([]));
    assert_eq!(admin.get("/api/v1/search?q=gargoyle").json()[0]["id"], cc);

    // The pages: the public model, its information and search; the rest asks for a login.
    let page = anon.get("/models");
    assert_eq!(page.status, 200);
    assert!(page.text().contains("Open") && !page.text().contains("Closed"));
    let page = anon.get(&format!("/models/{open}"));
    assert_eq!(page.status, 200);
    assert!(page.text().contains("You are visiting a public model"));
    assert!(!page.text().contains("action=\"/models/"), "no admin forms");
    assert_eq!(anon.get(&format!("/contents/{oc}")).status, 200);
    let search = anon.get("/search?q=rosette");
    assert_eq!(search.status, 200);
    assert!(
        search.text().contains(&format!("/contents/{oc}")),
        "the hit links its content"
    );
    let other = anon.get("/search?q=gargoyle").text();
    assert!(!other.contains(&format!("/contents/{cc}")));
    for page in [
        format!("/models/{closed}"),
        format!("/contents/{cc}"),
        format!("/contents/{oc}/edit"),
    ] {
        let r = anon.get(&page);
        assert_eq!(r.status, 303, "{page}");
        assert!(
            r.header("location").unwrap().starts_with("/login?next="),
            "{page}"
        );
    }

    // Every write of the API answers 401 without a session.
    let doc = anon.get("/api/v1/openapi.json").json();
    let concrete = |p: &str| {
        p.replace("{id}", &open.to_string())
            .replace("{node}", "0")
            .replace("{content_id}", &oc.to_string())
            .replace("{attachment_id}", &oa.to_string())
            .replace("{number}", "1")
            .replace("{draft}", "nodraft")
    };
    let mut writes = 0;
    for (path, item) in doc["paths"].as_object().unwrap() {
        for method in ["post", "put", "patch", "delete"] {
            let Some(op) = item.get(method) else { continue };
            if op["security"] == Value::Array(vec![]) {
                continue; // logging in
            }
            let r = anon.request(
                &method.to_uppercase(),
                &concrete(path),
                Some("application/json"),
                b"{}".to_vec(),
                false,
            );
            assert_eq!(r.status, 401, "{method} {path}: {}", r.text());
            writes += 1;
        }
    }
    assert!(writes > 25, "{writes} writes probed");
    // And nothing changed.
    assert_eq!(
        admin.get(&format!("/api/v1/models/{open}")).json()["title"],
        "Open"
    );
    assert_eq!(
        admin.get(&format!("/api/v1/contents/{oc}")).json()["current_revision"],
        1
    );

    // Closed again: back behind the login.
    let r = admin.patch(&format!("/api/v1/models/{open}"), &json!({"public": false}));
    assert_eq!(r.status, 200);
    anon.get(&format!("/api/v1/models/{open}/lod"))
        .assert_error(401);
}
