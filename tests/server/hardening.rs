//! The defects of the outside probe (issue 14), each reproduced against the real server:
//! open redirects and control characters in `next`, unbounded multipart text fields, login
//! throttling and its logging, the Origin check on the attachment form, partial uploads left by
//! a crash, the search title cut after its last match.

use std::io::{Read, Write};
use std::net::{IpAddr, SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

use crate::harness::*;

fn csrf_of(html: &str) -> String {
    let marker = "name=\"csrf_token\" value=\"";
    let start = html.find(marker).expect("csrf field") + marker.len();
    html[start..start + 64].to_string()
}

/// Logs in through the form with a raw `next` (already percent-encoded as a browser would).
fn form_login_next(server: &Server, encoded_next: &str) -> Resp {
    let body = format!(
        "username=admin&password={}&next={encoded_next}",
        encode(ADMIN_PASSWORD)
    );
    server.client().request(
        "POST",
        "/login",
        Some("application/x-www-form-urlencoded"),
        body.into_bytes(),
        false,
    )
}

#[test]
fn login_redirects_only_to_same_origin_paths() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    // Tab, newline, carriage return, vertical tab, backslash, space, scheme-relative, absolute.
    for next in [
        "/%09/evil.example",
        "%2F%09%2Fevil.example",
        "/%0A/evil.example",
        "/%0D/evil.example",
        "/%0B/evil.example",
        "/%0D%0ASet-Cookie:%20x=1",
        "/%5Cevil.example",
        "/%5C/evil.example",
        "/%20/evil.example",
        "//evil.example",
        "https://evil.example/",
        "evil.example",
        "/%C3%A9",
    ] {
        let r = form_login_next(&server, next);
        assert_eq!(r.status, 303, "next={next}: {}", r.text());
        assert_eq!(r.header("location"), Some("/"), "next={next}");
        assert!(r.header("set-cookie").is_some(), "next={next}: logged in");
    }
    // Ordinary local paths pass, query included.
    let r = form_login_next(&server, "/search%3Fq%3Dlion");
    assert_eq!(r.header("location"), Some("/search?q=lion"));
    // The login page with a session redirects at once: the same rule.
    let c = server.login("admin", ADMIN_PASSWORD);
    for (next, want) in [
        ("%2F%09%2Fevil.example", "/"),
        ("%2F%0A%2Fevil.example", "/"),
        ("%2F%5Cevil.example", "/"),
        ("%2Fmodels", "/models"),
    ] {
        let r = c.get(&format!("/login?next={next}"));
        assert_eq!(r.status, 303, "next={next}: {}", r.text());
        assert_eq!(r.header("location"), Some(want), "next={next}");
    }
}

/// A multipart body with `n` text fields of `size` bytes each, then a small file.
fn many_fields(n: usize, size: usize, first: &[(&str, &str)]) -> (String, Vec<u8>) {
    let boundary = "----meshwikihardening1";
    let mut body = Vec::new();
    for (k, v) in first {
        body.extend_from_slice(
            format!("--{boundary}\r\nContent-Disposition: form-data; name=\"{k}\"\r\n\r\n{v}\r\n")
                .as_bytes(),
        );
    }
    let value = "x".repeat(size);
    for i in 0..n {
        body.extend_from_slice(
            format!(
                "--{boundary}\r\nContent-Disposition: form-data; name=\"f{i}\"\r\n\r\n{value}\r\n"
            )
            .as_bytes(),
        );
    }
    body.extend_from_slice(
        format!(
            "--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"a.ply\"\r\nContent-Type: application/octet-stream\r\n\r\nply\r\n--{boundary}--\r\n"
        )
        .as_bytes(),
    );
    (format!("multipart/form-data; boundary={boundary}"), body)
}

#[test]
fn multipart_text_fields_are_bounded() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let content = create_content(&admin, "Fields", "body");
    let id = content["id"].as_i64().unwrap();
    let page = admin.get(&format!("/contents/{id}/edit"));
    let csrf = csrf_of(&page.text());
    let jobs_page = admin.get("/admin/jobs");
    let jobs_csrf = csrf_of(&jobs_page.text());
    let api = [("/api/v1/attachments".to_string(), true, String::new())];
    let pages = [
        (format!("/contents/{id}/attachments"), false, csrf),
        ("/admin/jobs/upload".to_string(), false, jobs_csrf),
    ];
    for (path, with_header, csrf) in api.iter().chain(pages.iter()) {
        let first: Vec<(&str, &str)> = if csrf.is_empty() {
            vec![]
        } else {
            vec![("csrf_token", csrf.as_str())]
        };
        // Too many fields, each small; too many bytes in few fields.
        for (n, size) in [(200, 10), (100, 4000)] {
            let (ct, body) = many_fields(n, size, &first);
            let r = admin.request("POST", path, Some(&ct), body, *with_header);
            assert_eq!(
                r.status,
                413,
                "{path} with {n} fields of {size} B: {}",
                r.text()
            );
        }
        // A form within the budget is not refused for its fields.
        let (ct, body) = many_fields(5, 100, &first);
        let r = admin.request("POST", path, Some(&ct), body, *with_header);
        assert_ne!(r.status, 413, "{path}: {}", r.text());
        assert!(r.status < 500, "{path}: {}", r.status);
    }
    // Nothing of the refused forms is left in uploads/.
    let left: Vec<_> = std::fs::read_dir(dir.path().join("uploads"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .filter(|n| !n.to_string_lossy().starts_with("src-"))
        .collect();
    assert!(left.is_empty(), "left in uploads/: {left:?}");
}

#[test]
fn attachment_form_refuses_a_foreign_origin() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let content = create_content(&admin, "Origin", "body");
    let id = content["id"].as_i64().unwrap();
    let csrf = csrf_of(&admin.get(&format!("/contents/{id}/edit")).text());
    let boundary = "----meshwikiorigin";
    let body = format!(
        "--{boundary}\r\nContent-Disposition: form-data; name=\"csrf_token\"\r\n\r\n{csrf}\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"n.txt\"\r\nContent-Type: text/plain\r\n\r\nhello\r\n--{boundary}--\r\n"
    );
    let ct = format!("multipart/form-data; boundary={boundary}");
    let path = format!("/contents/{id}/attachments");
    let r = admin.request_with(
        "POST",
        &path,
        Some(&ct),
        body.clone().into_bytes(),
        false,
        &[("Origin", "https://evil.example")],
    );
    assert_eq!(r.status, 403, "{}", r.text());
    let list = admin
        .get(&format!("/api/v1/contents/{id}/attachments"))
        .json();
    assert_eq!(list.as_array().unwrap().len(), 0, "nothing attached");
    // The own origin (as a browser sends it) is fine.
    let origin = admin.base.clone();
    let r = admin.request_with(
        "POST",
        &path,
        Some(&ct),
        body.into_bytes(),
        false,
        &[("Origin", origin.as_str())],
    );
    assert_eq!(r.status, 303, "{}", r.text());
    let list = admin
        .get(&format!("/api/v1/contents/{id}/attachments"))
        .json();
    assert_eq!(list.as_array().unwrap().len(), 1);
}

/// One HTTP/1.1 request over a connection from the local address `from`; returns the status,
/// the response head and the body.
fn request_from(from: IpAddr, server: &Server, head: &str, body: &[u8]) -> (u16, String, String) {
    let to: SocketAddr = server
        .base
        .trim_start_matches("http://")
        .parse()
        .expect("addr");
    let socket =
        socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None).expect("socket");
    socket
        .bind(&SocketAddr::new(from, 0).into())
        .expect("bind the client address");
    socket.connect(&to.into()).expect("connect");
    let mut stream: TcpStream = socket.into();
    stream
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    stream.write_all(head.as_bytes()).unwrap();
    stream.write_all(body).unwrap();
    let mut out = Vec::new();
    let _ = stream.read_to_end(&mut out);
    let text = String::from_utf8_lossy(&out).into_owned();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    (status, head.to_string(), body.to_string())
}

fn api_login_from(from: IpAddr, server: &Server, user: &str, password: &str) -> (u16, String) {
    let body = serde_json::to_vec(&json!({"username": user, "password": password})).unwrap();
    let head = format!(
        "POST /api/v1/session HTTP/1.1\r\nHost: {}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        server.base.trim_start_matches("http://"),
        body.len()
    );
    let (status, head, _) = request_from(from, server, &head, &body);
    (status, head)
}

#[test]
fn failed_logins_are_throttled_per_account_and_address_and_logged() {
    let dir = data_dir_with_admin();
    let log = dir.path().join("server.log");
    let server = Server::start_logging(dir.path(), &[], &log);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let _victim = create_user(&server, &admin, "victim", "editor");
    let attacker: IpAddr = "127.0.0.1".parse().unwrap();
    let elsewhere: IpAddr = "127.0.0.2".parse().unwrap();

    let start = Instant::now();
    let (mut unauthorized, mut throttled, mut first_429) = (0, 0, None);
    for k in 0..200 {
        let (status, head) = api_login_from(attacker, &server, "victim", &format!("guess-{k}"));
        match status {
            401 => unauthorized += 1,
            429 => {
                throttled += 1;
                first_429.get_or_insert(k);
                let retry = head
                    .lines()
                    .find_map(|l| {
                        l.strip_prefix("retry-after: ")
                            .or(l.strip_prefix("Retry-After: "))
                    })
                    .and_then(|v| v.trim().parse::<u64>().ok());
                assert!(
                    retry.is_some_and(|s| s >= 1),
                    "429 with Retry-After: {head}"
                );
            }
            other => panic!("attempt {k}: status {other}: {head}"),
        }
    }
    let first_429 = first_429.expect("throttled at some point");
    assert!(
        first_429 <= 10,
        "429 after a few failures, not after {first_429}"
    );
    assert!(
        throttled >= 150,
        "{throttled} of 200 throttled ({unauthorized} checked)"
    );
    println!(
        "200 wrong passwords: {unauthorized} checked, {throttled} refused with 429 in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    // Throttled means no answer: the right password from the attacker's address is refused too.
    let (status, _) = api_login_from(attacker, &server, "victim", "victim-password-1");
    assert_eq!(status, 429);
    // The real user, from another address, logs in.
    let (status, head) = api_login_from(elsewhere, &server, "victim", "victim-password-1");
    assert_eq!(status, 200, "{head}");
    // The HTML form is throttled by the same rule (same account, same address).
    let r = server.client().post_form(
        "/login",
        &[("username", "victim"), ("password", "victim-password-1")],
    );
    assert_eq!(r.status, 429, "{}", r.text());
    assert!(r.header("retry-after").is_some());
    assert!(r.text().contains("Too many failed logins"));

    // Every failure is in the audit log, with the account and the address.
    let victim_id = admin
        .get("/api/v1/users")
        .json()
        .as_array()
        .unwrap()
        .iter()
        .find(|u| u["username"] == "victim")
        .expect("victim")["id"]
        .as_i64()
        .unwrap();
    let audit = admin
        .get(&format!(
            "/api/v1/audit?entity=user&entity_id={victim_id}&limit=1000"
        ))
        .json();
    let entries: Vec<&Value> = audit.as_array().unwrap().iter().collect();
    let failed = entries
        .iter()
        .filter(|e| e["action"] == "session.login_failed")
        .count();
    assert_eq!(failed, unauthorized, "every checked failure audited");
    assert!(entries.iter().any(|e| e["action"] == "session.login_failed"
        && e["details"]["address"] == "127.0.0.1"
        && e["details"]["username"] == "victim"));
    // And in the server log, the refused attempts too.
    let text = std::fs::read_to_string(&log).unwrap();
    let logged_failures = text.lines().filter(|l| l.contains("failed login")).count();
    let logged_refusals = text
        .lines()
        .filter(|l| l.contains("login refused: too many failures"))
        .count();
    assert_eq!(logged_failures, unauthorized, "checked failures logged");
    assert!(
        logged_refusals > throttled,
        "{logged_refusals} refusals logged for {throttled} (+2) refused"
    );
    assert!(text.contains("127.0.0.1") && text.contains("victim"));
    // No password is ever recorded.
    let all = admin.get("/api/v1/audit?limit=1000").json();
    assert!(!all.to_string().contains("guess-") && !text.contains("guess-"));
}

#[test]
fn proxies_name_the_client_only_when_trusted() {
    let dir = data_dir_with_admin();
    // Trusted: the address a proxy names is the client's.
    let server = Server::start_with(dir.path(), &["--trusted-proxies", "127.0.0.1"]);
    let login = |xff: &str, password: &str| {
        let mut c = server.client();
        let body = serde_json::to_vec(&json!({"username": "admin", "password": password})).unwrap();
        let r = c.request_with(
            "POST",
            "/api/v1/session",
            Some("application/json"),
            body,
            false,
            &[("X-Forwarded-For", xff)],
        );
        c.cookie = None;
        r.status
    };
    let statuses: Vec<u16> = (0..8)
        .map(|_| login("203.0.113.7", "wrong-password"))
        .collect();
    assert_eq!(statuses.last(), Some(&429), "{statuses:?}");
    assert_eq!(login("198.51.100.2", ADMIN_PASSWORD), 200);
    // A client claiming to be a proxy in the chain does not pick its own address.
    assert_eq!(login("203.0.113.7, 127.0.0.1", ADMIN_PASSWORD), 429);
    drop(server);

    // Untrusted (the default): the header is ignored, the peer is the client.
    let server = Server::start(dir.path());
    let mut c = server.client();
    for _ in 0..8 {
        let r = c.request_with(
            "POST",
            "/api/v1/session",
            Some("application/json"),
            serde_json::to_vec(&json!({"username": "admin", "password": "nope-nope-nope"}))
                .unwrap(),
            false,
            &[("X-Forwarded-For", "198.51.100.9")],
        );
        assert!(r.status == 401 || r.status == 429);
    }
    let r = c.request_with(
        "POST",
        "/api/v1/session",
        Some("application/json"),
        serde_json::to_vec(&json!({"username": "admin", "password": ADMIN_PASSWORD})).unwrap(),
        false,
        &[("X-Forwarded-For", "198.51.100.10")],
    );
    assert_eq!(
        r.status, 429,
        "a forged header does not escape the throttle"
    );
    c.cookie = None;
}

fn uploads_tmp(dir: &std::path::Path) -> Vec<String> {
    std::fs::read_dir(dir.join("uploads"))
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.contains(".tmp"))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn a_crash_mid_upload_leaves_no_partial_file() {
    let dir = data_dir_with_admin();
    let server = Server::start_with(dir.path(), &["--upload-sweep-secs", "1"]);
    let admin = server.login("admin", ADMIN_PASSWORD);
    // An attachment upload that stops half-way: 4 MB announced, 1 MB sent.
    let to: SocketAddr = server.base.trim_start_matches("http://").parse().unwrap();
    let mut stream = TcpStream::connect(to).unwrap();
    let boundary = "----meshwikicrash";
    let preamble = format!(
        "--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"big.bin\"\r\nContent-Type: application/octet-stream\r\n\r\n"
    );
    let head = format!(
        "POST /api/v1/attachments HTTP/1.1\r\nHost: {}\r\nCookie: {}\r\nX-CSRF-Token: {}\r\nContent-Type: multipart/form-data; boundary={boundary}\r\nContent-Length: {}\r\n\r\n",
        to,
        admin.cookie.as_deref().unwrap(),
        admin.csrf.as_deref().unwrap(),
        preamble.len() + 4 * 1024 * 1024
    );
    stream.write_all(head.as_bytes()).unwrap();
    stream.write_all(preamble.as_bytes()).unwrap();
    stream.write_all(&vec![7u8; 1024 * 1024]).unwrap();
    stream.flush().unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while uploads_tmp(dir.path()).is_empty() {
        assert!(
            Instant::now() < deadline,
            "the upload never reached uploads/"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // The server is killed with the upload in flight: the partial file stays behind...
    server.kill9();
    drop(stream);
    let left = uploads_tmp(dir.path());
    assert_eq!(left.len(), 1, "{left:?}");
    // ...and is gone as soon as the server is back (not a minute later).
    let server = Server::start_with(dir.path(), &["--upload-sweep-secs", "1"]);
    assert!(uploads_tmp(dir.path()).is_empty(), "removed on start-up");

    // While running: a file left by another process that died (here a fake dead pid) goes
    // at the next sweep.
    let orphan = dir
        .path()
        .join("uploads")
        .join("0123456789abcdef.tmp-999999999");
    std::fs::write(&orphan, b"partial").unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while orphan.exists() {
        assert!(
            Instant::now() < deadline,
            "the periodic sweep did not remove {orphan:?}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    // The server still takes uploads.
    let admin = server.login("admin", ADMIN_PASSWORD);
    let r = admin.upload(
        "/api/v1/attachments",
        &[],
        "n.txt",
        "text/plain",
        b"hello",
        true,
    );
    assert_eq!(r.status, 201, "{}", r.text());
    assert!(uploads_tmp(dir.path()).is_empty());
}

#[test]
fn search_titles_are_shown_whole() {
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    create_content(&admin, "Lion paw (north)", "The northern paw of the lion.");
    create_content(&admin, "North & <south> gate", "Gates.");
    let hits = admin.get("/api/v1/search?q=north").json();
    let titles: Vec<&str> = hits
        .as_array()
        .unwrap_or_else(|| panic!("{hits}"))
        .iter()
        .map(|h| h["title_html"].as_str().unwrap())
        .collect();
    assert!(titles.contains(&"Lion paw (<b>north</b>)"), "{titles:?}");
    assert!(
        titles.contains(&"<b>North</b> &amp; &lt;south&gt; gate"),
        "{titles:?}"
    );
    let hits = admin.get("/api/v1/search?q=paw").json();
    assert_eq!(hits[0]["title_html"], "Lion <b>paw</b> (north)");
}
