//! Eight clients saving concurrently to the same 50 pages, 1,000 saves in all: every
//! accepted save is in the history, every rejected one got 409, nothing answered 5xx.

use std::collections::HashMap;
use std::sync::Arc;

use serde_json::json;

use crate::harness::*;

const CLIENTS: usize = 8;
const PAGES: usize = 50;
const SAVES: usize = 1000;

#[test]
fn concurrent_saves_are_never_lost() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let mut pages = Vec::new();
    for i in 0..PAGES {
        pages.push(
            create_content(&admin, &format!("Page {i}"), "initial")["id"]
                .as_i64()
                .unwrap(),
        );
    }
    let pages = Arc::new(pages);
    let mut editors = Vec::new();
    for i in 0..CLIENTS {
        editors.push(create_user(&server, &admin, &format!("ed{i}"), "editor"));
    }

    let handles: Vec<_> = editors
        .into_iter()
        .enumerate()
        .map(|(ci, client)| {
            let pages = pages.clone();
            std::thread::spawn(move || {
                // Each client remembers the revision it last saw per page, so it often saves
                // on a stale base when other clients got there first.
                let mut known: HashMap<i64, i64> = pages.iter().map(|p| (*p, 1)).collect();
                let mut accepted = Vec::new();
                let mut rejected = 0usize;
                let mut statuses = Vec::new();
                for k in 0..SAVES / CLIENTS {
                    let page = pages[(k * 7 + ci * 13) % PAGES];
                    let marker = format!("c{ci}-s{k}");
                    if k % 2 == 0 {
                        // Half of the saves start from a fresh read, racing the others.
                        let c = client.get(&format!("/api/v1/contents/{page}"));
                        assert_eq!(c.status, 200);
                        known.insert(page, c.json()["current_revision"].as_i64().unwrap());
                    }
                    let r = client.put(
                        &format!("/api/v1/contents/{page}"),
                        &json!({
                            "base_revision": known[&page],
                            "title": format!("Page {page}"),
                            "body": format!("saved by {marker}"),
                            "comment": marker,
                        }),
                    );
                    statuses.push(r.status);
                    match r.status {
                        200 => {
                            let rev = r.json()["current_revision"].as_i64().unwrap();
                            known.insert(page, rev);
                            accepted.push((page, rev, marker));
                        }
                        409 => {
                            rejected += 1;
                            let body = r.json();
                            assert!(body["error"].is_string());
                            known.insert(page, body["current_revision"].as_i64().unwrap());
                        }
                        _ => {}
                    }
                }
                (accepted, rejected, statuses)
            })
        })
        .collect();

    let mut accepted = Vec::new();
    let mut rejected = 0;
    let mut statuses = Vec::new();
    for h in handles {
        let (a, r, s) = h.join().expect("client thread");
        accepted.extend(a);
        rejected += r;
        statuses.extend(s);
    }
    assert_eq!(statuses.len(), SAVES);
    let odd: Vec<u16> = statuses
        .iter()
        .copied()
        .filter(|s| *s != 200 && *s != 409)
        .collect();
    assert!(odd.is_empty(), "unexpected statuses: {odd:?}");
    assert_eq!(accepted.len() + rejected, SAVES);
    assert!(
        !accepted.is_empty() && rejected > 0,
        "expected both outcomes"
    );

    // Every accepted save is in the history, with its own revision number and comment.
    let mut per_page: HashMap<i64, usize> = HashMap::new();
    for (page, _, _) in &accepted {
        *per_page.entry(*page).or_default() += 1;
    }
    for page in pages.iter() {
        let history = admin
            .get(&format!("/api/v1/contents/{page}/revisions"))
            .json();
        let history = history.as_array().unwrap();
        let expected = 1 + per_page.get(page).copied().unwrap_or(0);
        assert_eq!(history.len(), expected, "page {page}");
        let by_number: HashMap<i64, &str> = history
            .iter()
            .map(|r| {
                (
                    r["number"].as_i64().unwrap(),
                    r["comment"].as_str().unwrap(),
                )
            })
            .collect();
        for (p, rev, marker) in accepted.iter().filter(|(p, _, _)| p == page) {
            assert_eq!(
                by_number.get(rev),
                Some(&marker.as_str()),
                "page {p} revision {rev}"
            );
        }
        // Revisions are numbered 1..=n without gaps.
        let mut numbers: Vec<i64> = by_number.keys().copied().collect();
        numbers.sort_unstable();
        assert_eq!(numbers, (1..=expected as i64).collect::<Vec<_>>());
    }
    eprintln!(
        "concurrency: {} accepted, {} rejected with 409",
        accepted.len(),
        rejected
    );

    // The last accepted save of a page is its current text and is searchable.
    let (page, rev, marker) = accepted
        .iter()
        .max_by_key(|(_, rev, _)| *rev)
        .unwrap()
        .clone();
    let c = admin.get(&format!("/api/v1/contents/{page}")).json();
    assert_eq!(c["current_revision"], rev);
    assert_eq!(c["body"], format!("saved by {marker}"));
    let hits = admin
        .get(&format!("/api/v1/search?q=%22{marker}%22"))
        .json();
    assert_eq!(hits[0]["id"], page, "{hits}");
}
