//! Test harness: runs the real `meshwiki` binary on a temporary data directory and an
//! ephemeral port, and talks to it over real HTTP.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use serde_json::{Value, json};

pub const BIN: &str = env!("CARGO_BIN_EXE_meshwiki");
pub const ADMIN_PASSWORD: &str = "admin-password-1";

/// A running server process.
pub struct Server {
    pub child: Child,
    pub base: String,
    pub data_dir: PathBuf,
}

impl Server {
    /// Starts `meshwiki serve` on `data_dir` with extra arguments and waits until it listens.
    pub fn start_with(data_dir: &Path, extra: &[&str]) -> Server {
        Server::spawn(data_dir, extra, &[], Stdio::inherit())
    }

    /// [`Server::start_with`], with extra environment variables.
    pub fn start_env(data_dir: &Path, extra: &[&str], env: &[(&str, &Path)]) -> Server {
        Server::spawn(data_dir, extra, env, Stdio::inherit())
    }

    /// [`Server::start_with`], the server's log (stderr, warnings and errors) written to `log`.
    pub fn start_logging(data_dir: &Path, extra: &[&str], log: &Path) -> Server {
        let file = std::fs::File::create(log).expect("log file");
        Server::spawn(data_dir, extra, &[], Stdio::from(file))
    }

    fn spawn(data_dir: &Path, extra: &[&str], env: &[(&str, &Path)], stderr: Stdio) -> Server {
        let mut child = Command::new(BIN)
            .arg("serve")
            .arg("--data-dir")
            .arg(data_dir)
            .args(["--bind", "127.0.0.1:0", "--workers", "2"])
            .args(extra)
            .env("MESHWIKI_LOG", "warn")
            .envs(env.iter().copied())
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .expect("spawn meshwiki serve");
        let stdout = child.stdout.take().expect("stdout");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut tx = Some(tx);
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if let Some(addr) = line.strip_prefix("meshwiki listening on ")
                    && let Some(tx) = tx.take()
                {
                    let _ = tx.send(addr.to_string());
                }
            }
        });
        let base = match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(base) => base,
            Err(_) => {
                let _ = child.kill();
                panic!("server did not start within 60 s");
            }
        };
        Server {
            child,
            base,
            data_dir: data_dir.to_path_buf(),
        }
    }

    /// Starts `meshwiki serve` on `data_dir`.
    pub fn start(data_dir: &Path) -> Server {
        Server::start_with(data_dir, &[])
    }

    /// `kill -9` the server and wait for it to die.
    pub fn kill9(mut self) {
        self.child.kill().expect("kill -9");
        let _ = self.child.wait();
    }

    /// A new client without a session.
    pub fn client(&self) -> Client {
        Client::new(&self.base)
    }

    /// A client logged in as `user`.
    pub fn login(&self, user: &str, password: &str) -> Client {
        let mut c = self.client();
        let r = c.login(user, password);
        assert_eq!(r.status, 200, "login as {user}: {}", r.text());
        c
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs `meshwiki user add NAME --role ROLE` with the password on stdin.
pub fn add_user(data_dir: &Path, name: &str, role: &str, password: &str) -> std::process::Output {
    let mut child = Command::new(BIN)
        .args(["user", "add", name, "--role", role, "--data-dir"])
        .arg(data_dir)
        .env("MESHWIKI_LOG", "warn")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn user add");
    // The command may reject its arguments and exit before reading stdin: a broken pipe
    // here is expected then, and the exit status tells the rest.
    if let Err(e) = child
        .stdin
        .take()
        .expect("stdin")
        .write_all(format!("{password}\n").as_bytes())
    {
        assert_eq!(
            e.kind(),
            std::io::ErrorKind::BrokenPipe,
            "write password: {e}"
        );
    }
    child.wait_with_output().expect("user add output")
}

/// A temporary data directory with an admin `admin` created through the CLI.
pub fn data_dir_with_admin() -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = add_user(dir.path(), "admin", "admin", ADMIN_PASSWORD);
    assert!(
        out.status.success(),
        "user add failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir
}

/// An HTTP response.
#[derive(Debug)]
pub struct Resp {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Resp {
    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| {
            panic!(
                "response ({}) is not JSON: {e}: {}",
                self.status,
                self.text()
            )
        })
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    /// Asserts a 4xx JSON error with a non-empty message.
    pub fn assert_error(&self, status: u16) -> String {
        assert_eq!(self.status, status, "body: {}", self.text());
        let msg = self.json()["error"]
            .as_str()
            .unwrap_or_else(|| panic!("no error message: {}", self.text()))
            .to_string();
        assert!(!msg.is_empty());
        msg
    }
}

/// A minimal cookie-keeping HTTP client.
#[derive(Clone)]
pub struct Client {
    agent: ureq::Agent,
    pub base: String,
    pub cookie: Option<String>,
    pub csrf: Option<String>,
}

impl Client {
    pub fn new(base: &str) -> Client {
        let config = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .max_redirects(0)
            .max_redirects_will_error(false)
            .timeout_global(Some(Duration::from_secs(120)))
            .build();
        Client {
            agent: ureq::Agent::new_with_config(config),
            base: format!("http://{}", base.trim_start_matches("http://")),
            cookie: None,
            csrf: None,
        }
    }

    /// Sends a request; `csrf` adds the X-CSRF-Token header when the client has a token.
    pub fn request(
        &self,
        method: &str,
        path: &str,
        content_type: Option<&str>,
        body: Vec<u8>,
        csrf: bool,
    ) -> Resp {
        self.request_with(method, path, content_type, body, csrf, &[])
    }

    /// [`Client::request`] with extra headers.
    pub fn request_with(
        &self,
        method: &str,
        path: &str,
        content_type: Option<&str>,
        body: Vec<u8>,
        csrf: bool,
        extra: &[(&str, &str)],
    ) -> Resp {
        let mut b = ureq::http::Request::builder()
            .method(method)
            .uri(format!("{}{}", self.base, path));
        if let Some(c) = &self.cookie {
            b = b.header("Cookie", c.as_str());
        }
        if let (true, Some(t)) = (csrf, &self.csrf) {
            b = b.header("X-CSRF-Token", t.as_str());
        }
        if let Some(ct) = content_type {
            b = b.header("Content-Type", ct);
        }
        for (k, v) in extra {
            b = b.header(*k, *v);
        }
        let req = b.body(body).expect("request");
        let resp = self
            .agent
            .run(req)
            .unwrap_or_else(|e| panic!("{method} {path}: {e}"));
        let status = resp.status().as_u16();
        let headers = resp
            .headers()
            .iter()
            .map(|(k, v)| (k.as_str().to_string(), v.to_str().unwrap_or("").to_string()))
            .collect();
        let body = resp
            .into_body()
            .with_config()
            .limit(200 * 1024 * 1024)
            .read_to_vec()
            .unwrap_or_default();
        Resp {
            status,
            headers,
            body,
        }
    }

    pub fn get(&self, path: &str) -> Resp {
        self.request("GET", path, None, Vec::new(), false)
    }

    pub fn send_json(&self, method: &str, path: &str, body: &Value) -> Resp {
        self.request(
            method,
            path,
            Some("application/json"),
            serde_json::to_vec(body).expect("json"),
            true,
        )
    }

    pub fn post(&self, path: &str, body: &Value) -> Resp {
        self.send_json("POST", path, body)
    }

    pub fn put(&self, path: &str, body: &Value) -> Resp {
        self.send_json("PUT", path, body)
    }

    pub fn patch(&self, path: &str, body: &Value) -> Resp {
        self.send_json("PATCH", path, body)
    }

    pub fn delete(&self, path: &str) -> Resp {
        self.request("DELETE", path, None, Vec::new(), true)
    }

    /// A URL-encoded form post (pages); no CSRF header.
    pub fn post_form(&self, path: &str, fields: &[(&str, &str)]) -> Resp {
        let body = fields
            .iter()
            .map(|(k, v)| format!("{}={}", encode(k), encode(v)))
            .collect::<Vec<_>>()
            .join("&");
        self.request(
            "POST",
            path,
            Some("application/x-www-form-urlencoded"),
            body.into_bytes(),
            false,
        )
    }

    /// A multipart upload of one file (plus text fields, sent first).
    pub fn upload(
        &self,
        path: &str,
        fields: &[(&str, &str)],
        filename: &str,
        media_type: &str,
        data: &[u8],
        csrf: bool,
    ) -> Resp {
        self.multipart(path, fields, &[(filename, media_type, data)], csrf)
    }

    /// A multipart upload of several `file` fields `(filename, media type, bytes)` (text
    /// fields sent first).
    pub fn upload_files(
        &self,
        path: &str,
        fields: &[(&str, &str)],
        files: &[(&str, &str, &[u8])],
    ) -> Resp {
        self.multipart(path, fields, files, false)
    }

    /// A multipart POST: text fields, then one `file` field per file.
    fn multipart(
        &self,
        path: &str,
        fields: &[(&str, &str)],
        files: &[(&str, &str, &[u8])],
        csrf: bool,
    ) -> Resp {
        let boundary = "----meshwikitestboundary7d93";
        let mut body = Vec::new();
        for (k, v) in fields {
            body.extend_from_slice(
                format!(
                    "--{boundary}\r\nContent-Disposition: form-data; name=\"{k}\"\r\n\r\n{v}\r\n"
                )
                .as_bytes(),
            );
        }
        for (filename, media_type, data) in files {
            body.extend_from_slice(
                format!(
                    "--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"{filename}\"\r\nContent-Type: {media_type}\r\n\r\n"
                )
                .as_bytes(),
            );
            body.extend_from_slice(data);
            body.extend_from_slice(b"\r\n");
        }
        body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
        self.request(
            "POST",
            path,
            Some(&format!("multipart/form-data; boundary={boundary}")),
            body,
            csrf,
        )
    }

    /// Logs in through the API, keeping the cookie and CSRF token.
    pub fn login(&mut self, user: &str, password: &str) -> Resp {
        let r = self.post(
            "/api/v1/session",
            &json!({"username": user, "password": password}),
        );
        if r.status == 200 {
            let set = r
                .headers
                .iter()
                .find(|(k, v)| {
                    k.eq_ignore_ascii_case("set-cookie") && v.starts_with("meshwiki_session=")
                })
                .map(|(_, v)| v.clone())
                .expect("session cookie");
            self.cookie = Some(set.split(';').next().unwrap_or("").to_string());
            self.csrf = Some(r.json()["csrf_token"].as_str().expect("csrf").to_string());
        }
        r
    }

    /// The same session without the CSRF token.
    pub fn without_csrf(&self) -> Client {
        let mut c = self.clone();
        c.csrf = None;
        c
    }
}

/// Percent-encodes a form value.
pub fn encode(s: &str) -> String {
    let mut out = String::new();
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.' | b'~') {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Creates a user through the API as `admin`; returns a client logged in as that user.
pub fn create_user(server: &Server, admin: &Client, name: &str, role: &str) -> Client {
    let password = format!("{name}-password-1");
    let r = admin.post(
        "/api/v1/users",
        &json!({"username": name, "password": password, "role": role}),
    );
    assert_eq!(r.status, 201, "create {name}: {}", r.text());
    assert_eq!(r.json()["role"], role);
    server.login(name, &password)
}

/// Creates a content; returns its JSON.
pub fn create_content(c: &Client, title: &str, body: &str) -> Value {
    let r = c.post(
        "/api/v1/contents",
        &json!({"title": title, "caption": "", "body": body, "comment": "created"}),
    );
    assert_eq!(r.status, 201, "create content: {}", r.text());
    r.json()
}
