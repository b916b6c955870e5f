//! The HTML pages: login, model and content pages, editing with preview, the 409 merge
//! page, history, diff, revert, search, admin users; all readable without JavaScript.

use serde_json::json;

use crate::harness::*;

/// Value of the hidden CSRF field in a page.
fn csrf_of(html: &str) -> String {
    let marker = "name=\"csrf_token\" value=\"";
    let start = html.find(marker).expect("csrf field") + marker.len();
    html[start..start + 64].to_string()
}

/// Logs in through the HTML form; returns a client with the session cookie.
fn form_login(server: &Server, user: &str, password: &str) -> Client {
    let mut c = server.client();
    let r = c.post_form(
        "/login",
        &[
            ("username", user),
            ("password", password),
            ("next", "/contents"),
        ],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    assert_eq!(r.header("location"), Some("/contents"));
    let cookie = r.header("set-cookie").unwrap();
    assert!(cookie.contains("HttpOnly"));
    c.cookie = Some(cookie.split(';').next().unwrap().to_string());
    c
}

#[test]
fn pages_work_without_javascript() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let anon = server.client();

    // Pages redirect to the login page; the login page renders; a wrong password is refused.
    let r = anon.get("/contents/1/edit");
    assert_eq!(r.status, 303);
    assert_eq!(r.header("location"), Some("/login?next=/contents/1/edit"));
    let r = anon.get("/login");
    assert_eq!(r.status, 200);
    assert!(r.text().contains("<form method=\"post\" action=\"/login\""));
    let r = anon.post_form(
        "/login",
        &[("username", "admin"), ("password", "nope-nope")],
    );
    assert_eq!(r.status, 401);
    assert!(r.text().contains("Invalid user name or password"));
    // An open redirect through `next` is refused.
    let mut c = server.client();
    let r = c.post_form(
        "/login",
        &[
            ("username", "admin"),
            ("password", ADMIN_PASSWORD),
            ("next", "//evil.example/"),
        ],
    );
    assert_eq!(r.header("location"), Some("/"));
    c.cookie = None;

    let admin = form_login(&server, "admin", ADMIN_PASSWORD);

    // Admin pages: create an editor through the form.
    let page = admin.get("/admin/users");
    assert_eq!(page.status, 200);
    let csrf = csrf_of(&page.text());
    let r = admin.post_form(
        "/admin/users",
        &[
            ("csrf_token", &csrf),
            ("username", "edna"),
            ("password", "edna-password"),
            ("role", "editor"),
        ],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    // The page after the change says what was done.
    let after = admin.get(r.header("location").unwrap()).text();
    assert!(
        after.contains("User edna was created, role editor."),
        "{after}"
    );
    let edna = after
        .split("action=\"/admin/users/")
        .filter_map(|s| s.split('"').next())
        .last()
        .unwrap()
        .to_string();
    let r = admin.post_form(
        &format!("/admin/users/{edna}"),
        &[("csrf_token", &csrf), ("role", "viewer")],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let after = admin.get(r.header("location").unwrap()).text();
    assert!(
        after.contains("User edna was saved: role viewer."),
        "{after}"
    );
    let r = admin.post_form(
        &format!("/admin/users/{edna}"),
        &[("csrf_token", &csrf), ("role", "editor")],
    );
    assert_eq!(r.status, 303);
    assert!(
        !admin.get("/admin/users").text().contains("was saved"),
        "a notice without a change"
    );
    // Demoting yourself is refused.
    let r = admin.post_form(
        "/admin/users/1",
        &[("csrf_token", &csrf), ("role", "viewer")],
    );
    assert_eq!(r.status, 409);

    // A model record and its page with the viewer placeholder.
    let r = admin.post_form(
        "/models",
        &[
            ("csrf_token", &csrf),
            ("title", "Temple gate"),
            ("description", "A *wooden* gate"),
        ],
    );
    assert_eq!(r.status, 303);
    let model_url = r.header("location").unwrap().to_string();
    let model_id: i64 = model_url.rsplit('/').next().unwrap().parse().unwrap();
    let model_page = admin.get(&model_url).text();
    assert!(model_page.contains(&format!("<div id=\"viewer\" data-model-id=\"{model_id}\"")));
    assert!(model_page.contains("<em>wooden</em>"));
    assert!(admin.get("/models").text().contains("Temple gate"));
    // Its title and description are edited on its page.
    assert!(model_page.contains(&format!("action=\"/models/{model_id}/edit\"")));
    let r = admin.post_form(
        &format!("/models/{model_id}/edit"),
        &[
            ("csrf_token", &csrf),
            ("title", "Temple gate (east)"),
            ("description", "A *carved* gate"),
        ],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let model_page = admin.get(&model_url).text();
    assert!(model_page.contains("Temple gate (east)") && model_page.contains("<em>carved</em>"));
    let r = admin.post_form(
        &format!("/models/{model_id}/edit"),
        &[("csrf_token", &csrf), ("title", "  "), ("description", "")],
    );
    assert_eq!(r.status, 400, "a blank title is refused");
    assert!(admin.get(&model_url).text().contains("Temple gate (east)"));

    let editor = form_login(&server, "edna", "edna-password");
    // Editors cannot open admin pages; the refusal keeps the site's navigation and says who
    // is logged in.
    let r = editor.get("/admin/users");
    assert_eq!(r.status, 403);
    let html = r.text();
    assert!(
        html.contains("<nav aria-label=\"Main\">") && html.contains("edna"),
        "{html}"
    );
    assert!(
        html.contains("403 Forbidden") && !html.contains("href=\"/admin/jobs\""),
        "{html}"
    );

    // New content with preview, then save.
    let page = editor.get("/contents/new");
    assert_eq!(page.status, 200);
    let csrf = csrf_of(&page.text());
    let r = editor.post_form(
        "/contents/new",
        &[
            ("csrf_token", &csrf),
            ("title", "Gate <b>beam</b>"),
            ("caption", "cap"),
            ("body", "**bold** <script>x()</script>"),
            ("comment", "c"),
            ("action", "preview"),
        ],
    );
    assert_eq!(r.status, 200);
    let text = r.text();
    assert!(text.contains("<strong>bold</strong>"));
    assert!(!text.contains("<script>x()"));
    assert!(
        text.contains("beam") && !text.contains("<b>beam"),
        "titles are escaped"
    );
    let r = editor.post_form(
        "/contents/new",
        &[
            ("csrf_token", &csrf),
            ("title", "Gate beam"),
            ("caption", "cap"),
            ("body", "Line one\r\nLine two"),
            ("comment", "first"),
            ("action", "save"),
        ],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let url = r.header("location").unwrap().to_string();
    let id: i64 = url.rsplit('/').next().unwrap().parse().unwrap();
    let view = editor.get(&url).text();
    assert!(view.contains("Gate beam") && view.contains("Line one\nLine two"));

    // Two editors open the edit page on revision 1; the first save wins, the second gets
    // the 409 merge page showing both versions.
    let edit_page = editor.get(&format!("/contents/{id}/edit")).text();
    assert!(edit_page.contains("name=\"base_revision\" value=\"1\""));
    let r = editor.post_form(
        &format!("/contents/{id}/edit"),
        &[
            ("csrf_token", &csrf),
            ("base_revision", "1"),
            ("title", "Gate beam"),
            ("caption", "cap"),
            ("body", "Theirs: carved dragons"),
            ("comment", "theirs"),
            ("action", "save"),
        ],
    );
    assert_eq!(r.status, 303);
    let r = editor.post_form(
        &format!("/contents/{id}/edit"),
        &[
            ("csrf_token", &csrf),
            ("base_revision", "1"),
            ("title", "Gate beam"),
            ("caption", "cap"),
            ("body", "Mine: painted phoenixes"),
            ("comment", "mine"),
            ("action", "save"),
        ],
    );
    assert_eq!(r.status, 409);
    let merge = r.text();
    assert!(merge.contains("Edit conflict"));
    // A blank title is refused; the breadcrumb keeps the saved title.
    let r = editor.post_form(
        &format!("/contents/{id}/edit"),
        &[
            ("csrf_token", &csrf),
            ("base_revision", "2"),
            ("title", "   "),
            ("caption", "cap"),
            ("body", "x"),
            ("action", "save"),
        ],
    );
    assert_eq!(r.status, 400);
    assert!(
        r.text()
            .contains(&format!("<a href=\"/contents/{id}\">Gate beam</a> ›")),
        "{}",
        r.text()
    );
    assert!(merge.contains("carved dragons"), "theirs shown");
    assert!(merge.contains("painted phoenixes"), "yours shown");
    assert!(
        merge.contains("name=\"base_revision\" value=\"2\""),
        "merge form based on theirs"
    );
    // Saving the merged text from the merge page works.
    let r = editor.post_form(
        &format!("/contents/{id}/edit"),
        &[
            ("csrf_token", &csrf),
            ("base_revision", "2"),
            ("title", "Gate beam"),
            ("caption", "cap"),
            ("body", "Carved dragons and painted phoenixes"),
            ("comment", "merged"),
            ("action", "save"),
        ],
    );
    assert_eq!(r.status, 303);

    // History, diff between any two revisions, an old revision, revert.
    let history = editor.get(&format!("/contents/{id}/history")).text();
    for n in ["merged", "theirs", "first"] {
        assert!(history.contains(n), "{n} in history");
    }
    // Reverting is never one click from the history: it leads to the revision, which says
    // what a revert does and asks why.
    assert!(!history.contains(&format!("action=\"/contents/{id}/revert\"")));
    assert!(history.contains(&format!("href=\"/contents/{id}/revisions/2#revert\"")));
    let diff = editor
        .get(&format!("/contents/{id}/diff?from=1&to=3"))
        .text();
    assert!(diff.contains("Revision 1 → 3"));
    assert!(diff.contains("diff-del") && diff.contains("diff-ins"));
    let old = editor.get(&format!("/contents/{id}/revisions/2")).text();
    assert!(old.contains("carved dragons") && old.contains("Revert to this revision"));
    assert!(old.contains("nothing is lost") && old.contains("name=\"comment\""));
    let r = editor.post_form(
        &format!("/contents/{id}/revert"),
        &[
            ("csrf_token", &csrf),
            ("revision", "2"),
            ("base_revision", "3"),
            ("comment", "back to the dragons"),
        ],
    );
    assert_eq!(r.status, 303);
    let view = editor.get(&format!("/contents/{id}")).text();
    assert!(view.contains("Theirs: carved dragons") && view.contains("Revision 4"));
    let history = editor.get(&format!("/contents/{id}/history")).text();
    assert!(
        history.contains("back to the dragons"),
        "the revert's comment"
    );

    // Upload an attachment from the edit page (CSRF field first), then see it listed.
    let r = editor.upload(
        &format!("/contents/{id}/attachments"),
        &[("csrf_token", &csrf)],
        "gate.png",
        "image/png",
        b"png",
        false,
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let r = editor.upload(
        &format!("/contents/{id}/attachments"),
        &[],
        "gate2.png",
        "image/png",
        b"png",
        false,
    );
    assert_eq!(r.status, 403);
    assert!(
        editor
            .get(&format!("/contents/{id}/edit"))
            .text()
            .contains("gate.png")
    );

    // Assign the content to a part of the model from the model page.
    let mut api_admin = server.client();
    api_admin.login("admin", ADMIN_PASSWORD);
    let part = api_admin
        .post(
            &format!("/api/v1/models/{model_id}/parts"),
            &json!({"kind": "point", "center": [0, 1, 2]}),
        )
        .json();
    let pid = part["id"].as_i64().unwrap();
    let r = editor.post_form(
        &format!("/parts/{pid}/contents"),
        &[("csrf_token", &csrf), ("content_id", &id.to_string())],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let model_page = editor.get(&model_url).text();
    assert!(model_page.contains(&format!("href=\"/contents/{id}\"")));
    // The form takes a title too; a wrong number or an unknown title leads back to the part on
    // the model page with a message, never to a bare 404.
    let other = api_admin
        .post(
            "/api/v1/contents",
            &json!({"title": "Lintel crack", "body": "A crack."}),
        )
        .json();
    let r = editor.post_form(
        &format!("/parts/{pid}/contents"),
        &[("csrf_token", &csrf), ("content", "lintel CRACK")],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    assert!(
        editor
            .get(&model_url)
            .text()
            .contains(&format!("href=\"/contents/{}\"", other["id"]))
    );
    for (typed, code, says) in [
        ("#987654", "missing", "There is no content"),
        ("no such words", "none", "No content matches"),
        (" ", "empty", "Type the title of a content"),
    ] {
        let r = editor.post_form(
            &format!("/parts/{pid}/contents"),
            &[("csrf_token", &csrf), ("content", typed)],
        );
        assert_eq!(r.status, 303, "{typed}: {}", r.text());
        let to = r.header("location").unwrap_or_default().to_string();
        assert!(
            to.starts_with(&format!(
                "{model_url}?assign_part={pid}&assign_error={code}"
            )),
            "{typed}: {to}"
        );
        let page = editor.get(&to);
        assert_eq!(page.status, 200);
        assert!(page.text().contains(says), "{typed}: {}", page.text());
    }
    assert!(
        editor
            .get(&format!("/contents/{id}"))
            .text()
            .contains("Temple gate")
    );

    // Search page: ranked hits with highlighted snippets, model filter.
    let r = editor.get("/search?q=dragons&model=");
    assert_eq!(r.status, 200);
    let text = r.text();
    assert!(text.contains("<b>dragons</b>"), "{text}");
    assert!(text.contains(&format!("href=\"/contents/{id}\"")));
    let text = editor
        .get(&format!("/search?q=temple&model={model_id}"))
        .text();
    assert!(text.contains(&format!("href=\"/contents/{id}\"")));
    assert!(
        editor
            .get("/search?q=%3Cscript%3E")
            .text()
            .contains("0 results")
    );

    // Unknown pages: HTML 404; static CSS served.
    let r = editor.get("/contents/99999");
    assert_eq!(r.status, 404);
    let html = r.text();
    assert!(
        html.contains("<html") && html.contains("<nav aria-label=\"Main\">"),
        "{html}"
    );
    let r = editor.get("/no/such/page");
    assert_eq!(r.status, 404);
    assert!(r.text().contains("<nav aria-label=\"Main\">"));
    // Without a session: the page, without anyone's navigation.
    let r = server.client().get("/no/such/page");
    assert_eq!(r.status, 404);
    assert!(r.text().contains("404 Not Found") && !r.text().contains("<nav aria-label=\"Main\">"));
    let css = editor.get("/static/style.css");
    assert_eq!(css.status, 200);
    assert!(css.header("content-type").unwrap().starts_with("text/css"));

    // Log out through the form.
    let r = editor.post_form("/logout", &[("csrf_token", &csrf)]);
    assert_eq!(r.status, 303);
    assert_eq!(editor.get("/contents").status, 303);
}

/// A picture dropped onto a region becomes a content whose body shows the picture and whose
/// thumbnail is the same picture: the page and the API say to show it once, not twice; a
/// thumbnail the body does not show stays beside it.
#[test]
fn a_picture_in_the_body_is_not_shown_again_as_thumbnail() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let mut ids = Vec::new();
    for name in ["dropped.png", "other.png"] {
        let r = admin.upload(
            "/api/v1/attachments",
            &[],
            name,
            "image/png",
            name.as_bytes(),
            true,
        );
        assert_eq!(r.status, 201, "{}", r.text());
        ids.push(r.json()["id"].as_i64().unwrap());
    }
    let (pic, other) = (ids[0], ids[1]);
    let dropped = admin.post(
        "/api/v1/contents",
        &serde_json::json!({"title": "Dropped", "body": format!("![dropped.png](/api/v1/attachments/{pic}/download)\n"),
            "thumbnail_attachment_id": pic}),
    );
    assert_eq!(dropped.status, 201, "{}", dropped.text());
    let written = admin.post(
        "/api/v1/contents",
        &serde_json::json!({"title": "Written", "body": "Words only.", "thumbnail_attachment_id": other}),
    );
    for (r, shown, src) in [(dropped, false, pic), (written, true, other)] {
        let id = r.json()["id"].as_i64().unwrap();
        let api = admin.get(&format!("/api/v1/contents/{id}")).json();
        assert_eq!(api["show_thumbnail"], shown, "{api}");
        let page = admin.get(&format!("/contents/{id}")).text();
        let n = page
            .matches(&format!("src=\"/api/v1/attachments/{src}/download\""))
            .count();
        assert_eq!(n, 1, "content {id} shows its picture once: {page}");
    }
}
