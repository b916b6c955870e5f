//! The main editing scenario of issue 2, end to end, including a crash (`kill -9`) right
//! after an accepted save.

use serde_json::json;

use crate::harness::*;

#[test]
fn wiki_editing_roles_search_and_crash_recovery() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);

    // An admin creates an editor and a viewer.
    let editor = create_user(&server, &admin, "erin", "editor");
    let viewer = create_user(&server, &admin, "victor", "viewer");
    let users = admin.get("/api/v1/users").json();
    let names: Vec<&str> = users
        .as_array()
        .unwrap()
        .iter()
        .map(|u| u["username"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["admin", "erin", "victor"]);
    assert!(users[0].get("password_hash").is_none());

    // The editor creates a content whose body holds script and event-handler payloads.
    let body = "# Lion paw\n\nThe casting seam is visible near the marmoreal toe.\n\n\
                <script>alert('x')</script>\n\n<img src=x onerror=alert(1)>\n\n\
                [click](javascript:alert(2)) <a href=\"#\" onclick=\"steal()\">a</a>\n";
    let created = create_content(&editor, "Lion paw", body);
    let id = created["id"].as_i64().unwrap();
    assert_eq!(created["current_revision"], 1);
    let html = created["html"].as_str().unwrap();
    for bad in ["<script", "onerror", "onclick", "javascript:"] {
        assert!(!html.contains(bad), "{bad} survived sanitising: {html}");
    }
    assert!(html.contains("<h1>Lion paw</h1>"));
    let fetched = viewer.get(&format!("/api/v1/contents/{id}")).json();
    assert_eq!(fetched["html"], created["html"]);
    assert_eq!(
        fetched["body"], body,
        "the Markdown source is kept as written"
    );

    // A save on the current revision succeeds.
    let r = editor.put(
        &format!("/api/v1/contents/{id}"),
        &json!({"base_revision": 1, "title": "Lion paw", "body": "Seam near the toe; patina differs.", "comment": "second"}),
    );
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["current_revision"], 2);

    // A save on a stale revision gets 409 with both versions.
    let r = editor.put(
        &format!("/api/v1/contents/{id}"),
        &json!({"base_revision": 1, "title": "Lion paw", "body": "stale edit", "comment": "stale"}),
    );
    r.assert_error(409);
    let conflict = r.json();
    assert_eq!(conflict["base_revision"], 1);
    assert_eq!(conflict["current_revision"], 2);
    assert_eq!(
        conflict["current"]["body"],
        "Seam near the toe; patina differs."
    );
    assert_eq!(conflict["yours"]["body"], "stale edit");

    // History and diff show both revisions.
    let history = viewer
        .get(&format!("/api/v1/contents/{id}/revisions"))
        .json();
    let numbers: Vec<i64> = history
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["number"].as_i64().unwrap())
        .collect();
    assert_eq!(numbers, [2, 1]);
    assert!(history.as_array().unwrap().iter().all(|r| r["id"].is_i64()));
    assert_eq!(history[0]["author"], "erin");
    let diff = viewer
        .get(&format!("/api/v1/contents/{id}/diff?from=1&to=2"))
        .json();
    assert_eq!(
        (diff["from"].as_i64(), diff["to"].as_i64()),
        (Some(1), Some(2))
    );
    let unified = diff["body"]["unified"].as_str().unwrap();
    assert!(
        unified.contains("-The casting seam is visible"),
        "{unified}"
    );
    assert!(
        unified.contains("+Seam near the toe; patina differs."),
        "{unified}"
    );
    let table = diff["body"]["html"].as_str().unwrap();
    assert!(
        table.contains("diff-del") && table.contains("diff-ins"),
        "{table}"
    );
    assert!(!table.contains("<script"), "diff text is escaped: {table}");
    let rev1 = viewer
        .get(&format!("/api/v1/contents/{id}/revisions/1"))
        .json();
    assert_eq!(rev1["body"], body);
    assert!(!rev1["html"].as_str().unwrap().contains("<script"));

    // The viewer's save gets 403; without a session, 401.
    let r = viewer.put(
        &format!("/api/v1/contents/{id}"),
        &json!({"base_revision": 2, "title": "x", "body": "viewer edit"}),
    );
    r.assert_error(403);
    let anon = server.client();
    anon.get(&format!("/api/v1/contents/{id}"))
        .assert_error(401);
    anon.put(
        &format!("/api/v1/contents/{id}"),
        &json!({"base_revision": 2, "title": "x", "body": "anonymous edit"}),
    )
    .assert_error(401);

    // A word from the body is found by search in the very next request.
    let r = editor.put(
        &format!("/api/v1/contents/{id}"),
        &json!({"base_revision": 2, "title": "Lion paw", "body": "The verdigris is quinquefoliate here.", "comment": "third"}),
    );
    assert_eq!(r.status, 200);
    let hits = viewer.get("/api/v1/search?q=quinquefoliate");
    assert_eq!(hits.status, 200);
    let hits = hits.json();
    assert_eq!(hits.as_array().unwrap().len(), 1, "{hits}");
    assert_eq!(hits[0]["id"], id);
    assert!(
        hits[0]["snippet_html"]
            .as_str()
            .unwrap()
            .contains("<b>quinquefoliate</b>")
    );
    // The old text is no longer found.
    assert_eq!(viewer.get("/api/v1/search?q=marmoreal").json(), json!([]));

    // Revert creates a new revision with the old text.
    let r = editor.post(
        &format!("/api/v1/contents/{id}/revert"),
        &json!({"revision": 2, "base_revision": 3}),
    );
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["current_revision"], 4);
    assert_eq!(r.json()["body"], "Seam near the toe; patina differs.");

    // kill -9 right after an accepted save; after a restart the save is there and found.
    let r = editor.put(
        &format!("/api/v1/contents/{id}"),
        &json!({"base_revision": 4, "title": "Lion paw", "body": "Survives a crash: xylographic marks.", "comment": "before crash"}),
    );
    assert_eq!(r.status, 200);
    server.kill9();
    // Simulate the index losing its last commit: the database alone is the truth.
    let server = Server::start(dir.path());
    let viewer = server.login("victor", "victor-password-1");
    let c = viewer.get(&format!("/api/v1/contents/{id}")).json();
    assert_eq!(c["current_revision"], 5);
    assert_eq!(c["body"], "Survives a crash: xylographic marks.");
    let hits = viewer.get("/api/v1/search?q=xylographic").json();
    assert_eq!(hits[0]["id"], id, "{hits}");
    assert_eq!(
        viewer
            .get(&format!("/api/v1/contents/{id}/revisions"))
            .json()
            .as_array()
            .unwrap()
            .len(),
        5
    );
}

#[test]
fn index_catches_up_after_losing_commits() {
    // Edits committed to the database while the index lags behind (here: the index
    // directory is replaced by an older copy) are re-indexed on start-up.
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let c = create_content(&admin, "Snapshot", "before snapshot: aardvark");
    let id = c["id"].as_i64().unwrap();
    server.kill9();
    let index = dir.path().join("index");
    let snapshot = dir.path().join("index-snapshot");
    copy_dir(&index, &snapshot);

    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let r = admin.put(
        &format!("/api/v1/contents/{id}"),
        &json!({"base_revision": 1, "title": "Snapshot", "body": "after snapshot: bandicoot"}),
    );
    assert_eq!(r.status, 200);
    let other = create_content(&admin, "Added later", "wombat");
    server.kill9();

    std::fs::remove_dir_all(&index).unwrap();
    std::fs::rename(&snapshot, &index).unwrap();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    assert_eq!(admin.get("/api/v1/search?q=bandicoot").json()[0]["id"], id);
    assert_eq!(admin.get("/api/v1/search?q=aardvark").json(), json!([]));
    assert_eq!(
        admin.get("/api/v1/search?q=wombat").json()[0]["id"],
        other["id"]
    );
}

fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}

/// Every change of a part through `/api/v1/parts` is in its history, with its author,
/// comment and state; a deleted part keeps its history.
#[test]
fn parts_edited_through_the_api_keep_their_history() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let erin = create_user(&server, &admin, "erin", "editor");
    let paula = create_user(&server, &admin, "paula", "editor");
    let model = admin
        .post("/api/v1/models", &json!({"title": "Stele"}))
        .json();
    let mid = model["id"].as_i64().unwrap();

    let part = erin.post(
        &format!("/api/v1/models/{mid}/parts"),
        &json!({"kind": "region", "center": [0.5, 0.5, 0.0], "vertex_ids": [1, 2, 3],
                "comment": "the inscription"}),
    );
    assert_eq!(part.status, 201, "{}", part.text());
    let pid = part.json()["id"].as_i64().unwrap();
    let edited = paula.patch(
        &format!("/api/v1/parts/{pid}"),
        &json!({"vertex_ids": [1, 2, 3, 4, 5], "comment": "two more letters"}),
    );
    assert_eq!(edited.status, 200, "{}", edited.text());
    assert_eq!(edited.json()["vertex_count"], 5);
    // A camera-only edit is a revision too (its camera is kept with it).
    let camera = json!({"eye": [0.5, 0.5, 2.0], "target": [0.5, 0.5, 0.0],
                        "up": [0.0, 1.0, 0.0], "fovy": 45.0});
    assert_eq!(
        erin.patch(&format!("/api/v1/parts/{pid}"), &json!({"camera": camera}))
            .status,
        200
    );

    let history = erin.get(&format!("/api/v1/parts/{pid}/revisions")).json();
    let h = history.as_array().unwrap();
    assert_eq!(h.len(), 3, "{history}");
    let field = |i: usize, k: &str| h[i][k].clone();
    assert_eq!(
        (0..3).map(|i| field(i, "number")).collect::<Vec<_>>(),
        [json!(1), json!(2), json!(3)]
    );
    assert_eq!(field(0, "action"), "create");
    assert_eq!(field(0, "author"), "erin");
    assert_eq!(field(0, "comment"), "the inscription");
    assert_eq!(field(0, "vertex_count"), 3);
    assert_eq!(field(0, "tool"), json!(null));
    assert_eq!(field(1, "action"), "edit");
    assert_eq!(field(1, "author"), "paula");
    assert_eq!(field(1, "comment"), "two more letters");
    assert_eq!(field(1, "vertex_count"), 5);
    assert_eq!(field(2, "author"), "erin");
    assert_eq!(field(2, "camera")["fovy"], 45.0);
    assert!(field(2, "created_at").as_str().unwrap().ends_with('Z'));
    // Each revision keeps its own vertex set.
    let v1 = erin.get(&format!("/api/v1/parts/{pid}/revisions/1/vertices"));
    let v2 = erin.get(&format!("/api/v1/parts/{pid}/revisions/2/vertices"));
    assert_eq!(v1.status, 200);
    assert!(!v2.body.is_empty() && v1.body != v2.body);

    // A rejected edit writes no revision.
    let bad = paula.patch(
        &format!("/api/v1/parts/{pid}"),
        &json!({"vertex_ids": [], "comment": "oops"}),
    );
    assert_eq!(bad.status, 400, "{}", bad.text());
    let long = "x".repeat(2001);
    assert_eq!(
        paula
            .patch(&format!("/api/v1/parts/{pid}"), &json!({"comment": long}))
            .status,
        400
    );
    assert_eq!(
        erin.get(&format!("/api/v1/parts/{pid}/revisions"))
            .json()
            .as_array()
            .unwrap()
            .len(),
        3
    );

    // Deleting is the last revision; the history outlives the part.
    assert_eq!(paula.delete(&format!("/api/v1/parts/{pid}")).status, 204);
    assert_eq!(erin.get(&format!("/api/v1/parts/{pid}")).status, 404);
    let history = erin.get(&format!("/api/v1/parts/{pid}/revisions")).json();
    let last = history.as_array().unwrap().last().unwrap().clone();
    assert_eq!(last["action"], "delete");
    assert_eq!(last["author"], "paula");
    assert_eq!(last["vertex_count"], 5);
}
