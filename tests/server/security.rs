//! CSRF, role checks on every route family, attachment headers and limits, bad input,
//! security headers and the OpenAPI document.

use serde_json::{Value, json};

use crate::harness::*;

struct Setup {
    _dir: tempfile::TempDir,
    server: Server,
    admin: Client,
    editor: Client,
    viewer: Client,
}

fn setup(extra: &[&str]) -> Setup {
    let dir = data_dir_with_admin();
    let server = Server::start_with(dir.path(), extra);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let editor = create_user(&server, &admin, "ed", "editor");
    let viewer = create_user(&server, &admin, "vi", "viewer");
    Setup {
        _dir: dir,
        server,
        admin,
        editor,
        viewer,
    }
}

#[test]
fn csrf_is_required_on_state_changes() {
    let s = setup(&[]);
    let content = create_content(&s.editor, "Csrf", "body");
    let id = content["id"].as_i64().unwrap();
    let no_csrf = s.editor.without_csrf();
    no_csrf
        .post("/api/v1/contents", &json!({"title": "x"}))
        .assert_error(403);
    no_csrf
        .put(
            &format!("/api/v1/contents/{id}"),
            &json!({"base_revision": 1, "title": "x"}),
        )
        .assert_error(403);
    no_csrf.delete("/api/v1/session").assert_error(403);
    let mut wrong = s.editor.clone();
    wrong.csrf = Some("0".repeat(64));
    wrong
        .post("/api/v1/contents", &json!({"title": "x"}))
        .assert_error(403);
    // Reads need no token.
    assert_eq!(no_csrf.get(&format!("/api/v1/contents/{id}")).status, 200);
    // A foreign Origin is refused even with the token; the own origin is fine.
    let origin = s.editor.base.clone();
    let r = s.editor.request_with(
        "POST",
        "/api/v1/contents",
        Some("application/json"),
        br#"{"title":"same origin"}"#.to_vec(),
        true,
        &[("Origin", origin.as_str())],
    );
    assert_eq!(r.status, 201, "{}", r.text());
    s.editor
        .request_with(
            "POST",
            "/api/v1/contents",
            Some("application/json"),
            br#"{"title":"x"}"#.to_vec(),
            true,
            &[("Origin", "https://evil.example")],
        )
        .assert_error(403);
    // HTML forms need the hidden field.
    let r = s.editor.post_form(
        &format!("/contents/{id}/edit"),
        &[
            ("base_revision", "1"),
            ("title", "t"),
            ("body", "b"),
            ("action", "save"),
        ],
    );
    assert_eq!(r.status, 403, "{}", r.text());
    let r = s.editor.post_form("/logout", &[]);
    assert_eq!(r.status, 403);
    // The session still works.
    assert_eq!(s.editor.get("/api/v1/session").status, 200);
    // Logging out (with the token) ends the session.
    assert_eq!(s.editor.delete("/api/v1/session").status, 204);
    s.editor.get("/api/v1/session").assert_error(401);
}

#[test]
fn roles_are_checked_on_every_route_family() {
    let s = setup(&[]);
    let anon = s.server.client();

    // Fixtures: a model, a part, a content, an assignment, an attachment.
    let model = s.admin.post(
        "/api/v1/models",
        &json!({"title": "Lion", "description": "A bronze lion"}),
    );
    assert_eq!(model.status, 201, "{}", model.text());
    let model = model.json();
    assert_eq!(model["status"], "pending");
    let mid = model["id"].as_i64().unwrap();
    let part = s.editor.post(
        &format!("/api/v1/models/{mid}/parts"),
        &json!({"kind": "region", "center": [1.0, 2.0, 3.0], "vertex_ids": [5, 3, 9, 3],
                "camera": {"eye": [0.0, 0.0, 5.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fovy": 45.0}}),
    );
    assert_eq!(part.status, 201, "{}", part.text());
    let part = part.json();
    assert_eq!(part["vertex_count"], 3);
    let pid = part["id"].as_i64().unwrap();
    let content = create_content(&s.editor, "Mane", "curly mane");
    let cid = content["id"].as_i64().unwrap();
    let r = s.editor.post(
        &format!("/api/v1/parts/{pid}/contents"),
        &json!({"content_id": cid}),
    );
    assert_eq!(r.status, 201, "{}", r.text());
    assert_eq!(r.json()[0]["id"], cid);
    // The model title is searchable through the assignment, and the model filter works.
    assert_eq!(s.viewer.get("/api/v1/search?q=lion").json()[0]["id"], cid);
    assert_eq!(
        s.viewer
            .get(&format!("/api/v1/search?q=mane&model={mid}"))
            .json()[0]["id"],
        cid
    );
    assert_eq!(
        s.viewer
            .get(&format!("/api/v1/search?q=mane&model={}", mid + 1))
            .json(),
        json!([])
    );

    // The vertex set comes back as a portable roaring bitmap.
    let v = s.viewer.get(&format!("/api/v1/parts/{pid}/vertices"));
    assert_eq!(v.status, 200);
    assert_eq!(v.header("content-type"), Some("application/octet-stream"));
    let bitmap = roaring::RoaringBitmap::deserialize_from(&v.body[..]).unwrap();
    assert_eq!(bitmap.iter().collect::<Vec<u32>>(), [3, 5, 9]);

    // Reads: everyone logged in; nobody without a session.
    let reads = [
        "/api/v1/models".to_string(),
        format!("/api/v1/models/{mid}"),
        format!("/api/v1/models/{mid}/parts"),
        format!("/api/v1/parts/{pid}"),
        format!("/api/v1/parts/{pid}/vertices"),
        format!("/api/v1/parts/{pid}/contents"),
        "/api/v1/contents".to_string(),
        format!("/api/v1/contents/{cid}"),
        format!("/api/v1/contents/{cid}/revisions"),
        format!("/api/v1/contents/{cid}/revisions/1"),
        format!("/api/v1/contents/{cid}/diff?from=1&to=1"),
        format!("/api/v1/contents/{cid}/parts"),
        format!("/api/v1/contents/{cid}/attachments"),
        "/api/v1/search?q=mane".to_string(),
        "/api/v1/session".to_string(),
    ];
    for path in &reads {
        assert_eq!(s.viewer.get(path).status, 200, "viewer GET {path}");
        anon.get(path).assert_error(401);
    }
    for path in ["/api/v1/users", "/api/v1/audit"] {
        s.viewer.get(path).assert_error(403);
        s.editor.get(path).assert_error(403);
        assert_eq!(s.admin.get(path).status, 200);
        anon.get(path).assert_error(401);
    }
    // Lists are arrays of objects with an id.
    for path in [
        "/api/v1/models",
        "/api/v1/contents",
        "/api/v1/users",
        "/api/v1/audit",
    ] {
        let list = s.admin.get(path).json();
        let list = list
            .as_array()
            .unwrap_or_else(|| panic!("{path} is not an array"));
        assert!(
            !list.is_empty() && list.iter().all(|o| o["id"].is_i64()),
            "{path}"
        );
    }

    // Writes by a viewer: 403 on every family.
    let viewer_writes: Vec<(&str, String, Value)> = vec![
        ("POST", "/api/v1/contents".into(), json!({"title": "v"})),
        (
            "PUT",
            format!("/api/v1/contents/{cid}"),
            json!({"base_revision": 1, "title": "v"}),
        ),
        (
            "POST",
            format!("/api/v1/contents/{cid}/revert"),
            json!({"revision": 1}),
        ),
        ("DELETE", format!("/api/v1/contents/{cid}"), json!(null)),
        ("POST", "/api/v1/models".into(), json!({"title": "v"})),
        (
            "PATCH",
            format!("/api/v1/models/{mid}"),
            json!({"title": "v"}),
        ),
        ("DELETE", format!("/api/v1/models/{mid}"), json!(null)),
        (
            "POST",
            format!("/api/v1/models/{mid}/parts"),
            json!({"kind": "point", "center": [0, 0, 0]}),
        ),
        (
            "PATCH",
            format!("/api/v1/parts/{pid}"),
            json!({"center": [0, 0, 0]}),
        ),
        ("DELETE", format!("/api/v1/parts/{pid}"), json!(null)),
        (
            "POST",
            format!("/api/v1/parts/{pid}/contents"),
            json!({"content_id": cid}),
        ),
        (
            "PUT",
            format!("/api/v1/parts/{pid}/contents"),
            json!({"content_ids": [cid]}),
        ),
        (
            "DELETE",
            format!("/api/v1/parts/{pid}/contents/{cid}"),
            json!(null),
        ),
        (
            "POST",
            "/api/v1/users".into(),
            json!({"username": "x", "password": "12345678", "role": "admin"}),
        ),
        ("PATCH", "/api/v1/users/1".into(), json!({"role": "viewer"})),
    ];
    for (method, path, body) in &viewer_writes {
        let r = if body.is_null() {
            s.viewer.delete(path)
        } else {
            s.viewer.send_json(method, path, body)
        };
        assert_eq!(r.status, 403, "viewer {method} {path}: {}", r.text());
        let r = if body.is_null() {
            anon.delete(path)
        } else {
            anon.send_json(method, path, body)
        };
        assert_eq!(r.status, 401, "anonymous {method} {path}");
    }
    let r = s.viewer.upload(
        "/api/v1/attachments",
        &[],
        "a.txt",
        "text/plain",
        b"hi",
        true,
    );
    r.assert_error(403);

    // Editors edit contents, parts and assignments, but do not manage models or users.
    assert_eq!(
        s.editor
            .patch(
                &format!("/api/v1/models/{mid}"),
                &json!({"description": "edited"})
            )
            .status,
        200
    );
    assert_eq!(
        s.editor
            .put(
                &format!("/api/v1/parts/{pid}/contents"),
                &json!({"content_ids": [cid]})
            )
            .status,
        200
    );
    assert_eq!(
        s.editor
            .patch(&format!("/api/v1/parts/{pid}"), &json!({"camera": null}))
            .json()["camera"],
        Value::Null
    );
    s.editor
        .post("/api/v1/models", &json!({"title": "e"}))
        .assert_error(403);
    s.editor
        .delete(&format!("/api/v1/models/{mid}"))
        .assert_error(403);
    s.editor
        .delete(&format!("/api/v1/contents/{cid}"))
        .assert_error(403);
    s.editor
        .post(
            "/api/v1/users",
            &json!({"username": "x", "password": "12345678", "role": "admin"}),
        )
        .assert_error(403);
    assert_eq!(
        s.editor
            .delete(&format!("/api/v1/parts/{pid}/contents/{cid}"))
            .status,
        204
    );
    assert_eq!(s.editor.delete(&format!("/api/v1/parts/{pid}")).status, 204);

    // Admins manage users and models; they cannot lock themselves out.
    let me = s.admin.get("/api/v1/session").json()["user"]["id"]
        .as_i64()
        .unwrap();
    s.admin
        .patch(&format!("/api/v1/users/{me}"), &json!({"role": "viewer"}))
        .assert_error(409);
    let vid = s.viewer.get("/api/v1/session").json()["user"]["id"]
        .as_i64()
        .unwrap();
    let r = s.admin.delete(&format!("/api/v1/users/{vid}"));
    assert_eq!(r.status, 200);
    assert_eq!(r.json()["disabled"], true);
    s.viewer.get("/api/v1/models").assert_error(401);
    assert_eq!(s.admin.delete(&format!("/api/v1/models/{mid}")).status, 204);
    s.admin
        .get(&format!("/api/v1/models/{mid}"))
        .assert_error(404);
    // The content stays, no longer found through the deleted model's title.
    assert_eq!(s.admin.get(&format!("/api/v1/contents/{cid}")).status, 200);
    assert_eq!(s.admin.get("/api/v1/search?q=lion").json(), json!([]));
    assert_eq!(
        s.admin.delete(&format!("/api/v1/contents/{cid}")).status,
        204
    );
    s.admin
        .get(&format!("/api/v1/contents/{cid}"))
        .assert_error(404);
    assert_eq!(s.admin.get("/api/v1/search?q=mane").json(), json!([]));
    // Every state change is in the audit log.
    let audit = s.admin.get("/api/v1/audit?limit=1000").json();
    let actions: Vec<&str> = audit
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["action"].as_str().unwrap())
        .collect();
    for a in [
        "user.create",
        "model.create",
        "part.create",
        "content.create",
        "assignment.create",
        "assignment.reorder",
        "part.update",
        "model.delete",
        "content.delete",
        "user.update",
    ] {
        assert!(actions.contains(&a), "audit lacks {a}: {actions:?}");
    }
}

#[test]
fn attachments_upload_download_headers_and_limits() {
    let s = setup(&["--max-upload-mb", "1"]);
    let content = create_content(&s.editor, "With files", "see attachments");
    let cid = content["id"].as_i64().unwrap();

    // An HTML file, with a path in its name: stored content-addressed, served as a download.
    let html = b"<html><script>alert(1)</script></html>";
    let r = s.editor.upload(
        &format!("/api/v1/contents/{cid}/attachments"),
        &[],
        "../../etc/evil page.html",
        "text/html",
        html,
        true,
    );
    assert_eq!(r.status, 201, "{}", r.text());
    let a = r.json();
    assert_eq!(a["original_name"], "evil page.html");
    assert_eq!(a["media_type"], "text/html");
    assert_eq!(a["size"], html.len());
    let sha = a["sha256"].as_str().unwrap().to_string();
    let stored = s
        .server
        .data_dir
        .join("attachments")
        .join(&sha[..2])
        .join(&sha[2..]);
    assert_eq!(std::fs::read(&stored).unwrap(), html);
    assert!(!s.server.data_dir.join("etc").exists());
    let d = s
        .viewer
        .get(&format!("/api/v1/attachments/{}/download", a["id"]));
    assert_eq!(d.status, 200);
    assert_eq!(d.body, html);
    assert_eq!(d.header("x-content-type-options"), Some("nosniff"));
    let disp = d.header("content-disposition").unwrap();
    assert!(disp.starts_with("attachment;"), "{disp}");
    assert!(disp.contains("evil page.html"), "{disp}");
    assert!(
        d.header("content-security-policy")
            .unwrap()
            .contains("sandbox")
    );

    // SVG and PDF download too; PNG and plain text are shown inline.
    for (name, media, inline) in [
        ("pic.svg", "image/svg+xml", false),
        ("doc.pdf", "application/pdf", false),
        ("script.js", "application/javascript", false),
        ("pic.png", "image/png", true),
        ("notes.txt", "text/plain", true),
    ] {
        let r = s.editor.upload(
            "/api/v1/attachments",
            &[("content_id", &cid.to_string())],
            name,
            media,
            name.as_bytes(),
            true,
        );
        assert_eq!(r.status, 201, "{name}: {}", r.text());
        let d = s
            .viewer
            .get(&format!("/api/v1/attachments/{}/download", r.json()["id"]));
        let disp = d.header("content-disposition").unwrap();
        assert_eq!(disp.starts_with("inline"), inline, "{name}: {disp}");
        assert_eq!(d.header("x-content-type-options"), Some("nosniff"));
    }
    // A file without a declared type gets one from its name.
    let r = s.editor.upload(
        "/api/v1/attachments",
        &[],
        "guess.png",
        "application/octet-stream",
        b"x",
        true,
    );
    assert_eq!(r.json()["media_type"], "image/png");

    // The same bytes twice share one file.
    let r = s.editor.upload(
        "/api/v1/attachments",
        &[],
        "copy.html",
        "text/html",
        html,
        true,
    );
    assert_eq!(r.json()["sha256"], sha);

    // Attachment names are searchable; the content lists its attachments in order.
    assert_eq!(s.viewer.get("/api/v1/search?q=evil").json()[0]["id"], cid);
    let list = s
        .viewer
        .get(&format!("/api/v1/contents/{cid}/attachments"))
        .json();
    assert_eq!(list.as_array().unwrap().len(), 6);
    assert_eq!(list[0]["original_name"], "evil page.html");

    // Over the limit: 413 with a message, and no file left behind.
    let big = vec![b'a'; 1024 * 1024 + 10];
    let r = s.editor.upload(
        "/api/v1/attachments",
        &[],
        "big.bin",
        "application/octet-stream",
        &big,
        true,
    );
    r.assert_error(413);
    let uploads: Vec<_> = std::fs::read_dir(s.server.data_dir.join("uploads"))
        .unwrap()
        .collect();
    assert!(uploads.is_empty(), "temporary files left: {uploads:?}");

    // Not multipart, no file: 4xx with a message.
    s.editor
        .request(
            "POST",
            "/api/v1/attachments",
            Some("text/plain"),
            b"x".to_vec(),
            true,
        )
        .assert_error(400);
    s.editor
        .upload(
            "/api/v1/attachments",
            &[("content_id", "abc")],
            "a.txt",
            "text/plain",
            b"x",
            true,
        )
        .assert_error(400);
    // Without CSRF: 403.
    s.editor
        .upload(
            "/api/v1/attachments",
            &[],
            "a.txt",
            "text/plain",
            b"x",
            false,
        )
        .assert_error(403);
    // Unlink.
    let aid = a["id"].as_i64().unwrap();
    assert_eq!(
        s.editor
            .delete(&format!("/api/v1/contents/{cid}/attachments/{aid}"))
            .status,
        204
    );
    assert_eq!(s.viewer.get("/api/v1/search?q=evil").json(), json!([]));
    assert_eq!(
        s.editor
            .request(
                "PUT",
                &format!("/api/v1/contents/{cid}/attachments/{aid}"),
                None,
                vec![],
                true
            )
            .status,
        200
    );
}

#[test]
fn bad_input_gets_4xx_json_with_a_message() {
    let s = setup(&[]);
    let e = &s.editor;
    let content = create_content(e, "Valid", "x");
    let cid = content["id"].as_i64().unwrap();
    // Malformed JSON, wrong types, missing and unknown fields.
    e.request(
        "POST",
        "/api/v1/contents",
        Some("application/json"),
        b"{not json".to_vec(),
        true,
    )
    .assert_error(400);
    e.post("/api/v1/contents", &json!({"title": 5}))
        .assert_error(400);
    e.post("/api/v1/contents", &json!({"caption": "no title"}))
        .assert_error(400);
    e.post("/api/v1/contents", &json!({"title": "t", "bogus": 1}))
        .assert_error(400);
    e.post("/api/v1/contents", &json!({"title": "   "}))
        .assert_error(400);
    e.post("/api/v1/contents", &json!({"title": "x".repeat(400)}))
        .assert_error(400);
    e.put(
        &format!("/api/v1/contents/{cid}"),
        &json!({"title": "no base"}),
    )
    .assert_error(400);
    // Wrong content type and oversized bodies.
    e.request(
        "POST",
        "/api/v1/contents",
        Some("text/plain"),
        b"{}".to_vec(),
        true,
    )
    .assert_error(415);
    let huge = json!({"title": "big", "body": "x".repeat(3 * 1024 * 1024)});
    e.post("/api/v1/contents", &huge).assert_error(413);
    // Bad path and query parameters.
    e.get("/api/v1/contents/abc").assert_error(400);
    e.get("/api/v1/contents/99999999999999999999")
        .assert_error(400);
    e.get("/api/v1/contents?limit=abc").assert_error(400);
    e.get(&format!("/api/v1/contents/{cid}/diff?from=x"))
        .assert_error(400);
    e.get("/api/v1/search?q=a&model=x").assert_error(400);
    // Missing things: 404; unknown routes: 404; wrong method: 405.
    e.get("/api/v1/contents/424242").assert_error(404);
    e.get(&format!("/api/v1/contents/{cid}/revisions/9"))
        .assert_error(404);
    e.get("/api/v1/nope").assert_error(404);
    e.send_json("PATCH", "/api/v1/contents", &json!({}))
        .assert_error(405);
    // Invalid references and values.
    e.post("/api/v1/parts/424242/contents", &json!({"content_id": cid}))
        .assert_error(404);
    e.post(
        "/api/v1/contents",
        &json!({"title": "t", "thumbnail_attachment_id": 777}),
    )
    .assert_error(400);
    let m = s
        .admin
        .post("/api/v1/models", &json!({"title": "M"}))
        .json();
    let mid = m["id"].as_i64().unwrap();
    e.post(
        &format!("/api/v1/models/{mid}/parts"),
        &json!({"kind": "region", "center": [0, 0, 0]}),
    )
    .assert_error(400);
    e.post(
        &format!("/api/v1/models/{mid}/parts"),
        &json!({"kind": "blob", "center": [0, 0, 0]}),
    )
    .assert_error(400);
    e.post(
        &format!("/api/v1/models/{mid}/parts"),
        &json!({"kind": "point", "center": [0, 0]}),
    )
    .assert_error(400);
    e.post(&format!("/api/v1/models/{mid}/parts"),
        &json!({"kind": "point", "center": [0, 0, 0], "camera": {"eye": [0,0,1], "target": [0,0,0], "up": [0,1,0], "fovy": 500}}))
        .assert_error(400);
    let p = e
        .post(
            &format!("/api/v1/models/{mid}/parts"),
            &json!({"kind": "point", "center": [0, 0, 0]}),
        )
        .json();
    let pid = p["id"].as_i64().unwrap();
    e.post(
        &format!("/api/v1/parts/{pid}/contents"),
        &json!({"content_id": 424242}),
    )
    .assert_error(400);
    assert_eq!(
        e.post(
            &format!("/api/v1/parts/{pid}/contents"),
            &json!({"content_id": cid})
        )
        .status,
        201
    );
    e.post(
        &format!("/api/v1/parts/{pid}/contents"),
        &json!({"content_id": cid}),
    )
    .assert_error(409);
    e.put(
        &format!("/api/v1/parts/{pid}/contents"),
        &json!({"content_ids": [1, 2]}),
    )
    .assert_error(400);
    s.admin
        .post(
            "/api/v1/users",
            &json!({"username": "ed", "password": "long-enough", "role": "viewer"}),
        )
        .assert_error(409);
    s.admin
        .post(
            "/api/v1/users",
            &json!({"username": "new", "password": "short", "role": "viewer"}),
        )
        .assert_error(400);
    s.admin
        .post(
            "/api/v1/users",
            &json!({"username": "bad name!", "password": "long-enough", "role": "viewer"}),
        )
        .assert_error(400);
    s.admin
        .post(
            "/api/v1/users",
            &json!({"username": "n", "password": "long-enough", "role": "root"}),
        )
        .assert_error(400);
    // Wrong login: 401 with a message; search syntax errors are not errors.
    s.server
        .client()
        .post(
            "/api/v1/session",
            &json!({"username": "admin", "password": "wrong-password"}),
        )
        .assert_error(401);
    assert_eq!(e.get("/api/v1/search?q=%22unbalanced%20(%5B").status, 200);
    assert_eq!(e.get("/api/v1/search?q=").json(), json!([]));
}

#[test]
fn security_headers_and_openapi() {
    let s = setup(&[]);
    let r = s.viewer.get("/models");
    assert_eq!(r.status, 200);
    for (h, v) in [
        ("x-content-type-options", "nosniff"),
        ("x-frame-options", "DENY"),
        ("referrer-policy", "same-origin"),
    ] {
        assert_eq!(r.header(h), Some(v), "{h}");
    }
    assert!(
        r.header("content-security-policy")
            .unwrap()
            .contains("default-src 'self'")
    );
    // The session cookie is HttpOnly and SameSite.
    let login = s.server.client().post(
        "/api/v1/session",
        &json!({"username": "admin", "password": ADMIN_PASSWORD}),
    );
    let cookie = login.header("set-cookie").unwrap().to_string();
    assert!(cookie.contains("HttpOnly"), "{cookie}");
    assert!(cookie.contains("SameSite=Lax"), "{cookie}");
    assert!(cookie.contains("Path=/"), "{cookie}");

    // OpenAPI: public (its coverage of the mounted routes is tests/server/openapi.rs).
    let doc = s.server.client().get("/api/v1/openapi.json");
    assert_eq!(doc.status, 200);
    assert!(doc.json()["openapi"].as_str().unwrap().starts_with("3."));
}
