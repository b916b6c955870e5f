//! Concurrent content edits through the API (issue 16, item 1): a save based on a stale
//! revision answers 409 with the three versions (base, theirs, yours) and their three-way
//! merge; a clean merge saved on the current revision keeps both edits; an overlap is marked,
//! and text still holding markers is refused.

use serde_json::json;

use crate::harness::{ADMIN_PASSWORD, Server, create_content, create_user, data_dir_with_admin};

const BODY: &str =
    "# The apse\n\nThe apse was rebuilt in 1420.\n\nIts vault is painted.\n\nThe altar is lost.\n";

#[test]
fn a_stale_save_gets_the_three_versions_and_their_merge() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let alice = create_user(&server, &admin, "alice", "editor");
    let bob = create_user(&server, &admin, "bob", "editor");
    let id = create_content(&admin, "Apse", BODY)["id"].as_i64().unwrap();
    let path = format!("/api/v1/contents/{id}");

    let theirs = BODY.replace("in 1420.", "in 1420, as recorded during the May survey.");
    let r = alice.put(
        &path,
        &json!({"base_revision": 1, "title": "Apse", "body": theirs}),
    );
    assert_eq!(r.status, 200, "{}", r.text());

    // Bob, still on revision 1, changes another line.
    let yours = BODY.replace("is painted.", "is painted with stars.");
    let r = bob.put(
        &path,
        &json!({"base_revision": 1, "title": "Apse", "caption": "East end", "body": yours, "comment": "vault"}),
    );
    assert_eq!(r.status, 409, "{}", r.text());
    let c = r.json();
    assert_eq!(
        (c["base_revision"].as_i64(), c["current_revision"].as_i64()),
        (Some(1), Some(2))
    );
    assert_eq!(c["base"]["number"], 1);
    assert_eq!(c["base"]["body"], BODY);
    assert_eq!(c["current"]["body"], theirs.as_str());
    assert_eq!(c["current"]["author"], "alice");
    assert_eq!(c["yours"]["body"], yours.as_str());
    let merged = &c["merged"];
    assert_eq!(merged["conflicts"], 0);
    let body = merged["body"].as_str().unwrap();
    assert!(body.contains("during the May survey") && body.contains("painted with stars"));
    // Only Bob changed the caption: the merge takes his.
    assert_eq!(merged["caption"], "East end");

    // The clean merge, saved on the current revision, keeps both edits.
    let r = bob.put(
        &path,
        &json!({"base_revision": 2, "title": merged["title"], "caption": merged["caption"], "body": body, "comment": "vault, merged"}),
    );
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json()["current_revision"], 3);

    // An overlap: both change the last line.
    let r = alice.put(
        &path,
        &json!({"base_revision": 3, "title": "Apse", "caption": "East end", "body": body.replace("The altar is lost.", "The altar was moved to the museum.")}),
    );
    assert_eq!(r.status, 200, "{}", r.text());
    let r = bob.put(
        &path,
        &json!({"base_revision": 3, "title": "The apse", "caption": "East end", "body": body.replace("The altar is lost.", "The altar burnt in 1944.")}),
    );
    assert_eq!(r.status, 409);
    let c = r.json();
    let merged = &c["merged"];
    assert_eq!(merged["conflicts"], 1, "{c}");
    let marked = merged["body"].as_str().unwrap();
    assert!(
        marked.contains("<<<<<<< yours\nThe altar burnt in 1944.\n=======\nThe altar was moved to the museum.\n>>>>>>> theirs\n"),
        "{marked}"
    );
    // Bob's title change is his alone: merged cleanly even here.
    assert_eq!(merged["title"], "The apse");
    // Text still holding markers is refused, with a message.
    let r = bob.put(
        &path,
        &json!({"base_revision": 4, "title": "The apse", "caption": "East end", "body": marked}),
    );
    let msg = r.assert_error(400);
    assert!(msg.contains("still holds an edit conflict"), "{msg}");
    assert_eq!(admin.get(&path).json()["current_revision"], 4);

    // A revert on a stale base: a 409 with the versions, nothing to merge.
    let r = admin.post(
        &format!("{path}/revert"),
        &json!({"revision": 1, "base_revision": 2}),
    );
    assert_eq!(r.status, 409);
    let c = r.json();
    assert!(c["yours"].is_null() && c["merged"].is_null());
    assert_eq!(c["current_revision"], 4);
}
