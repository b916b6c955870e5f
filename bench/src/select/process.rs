//! The real system, started from outside: this binary's own `user add`, `import` (the real
//! LOD pipeline) and `serve` subcommands on a scratch data directory, as the server tests do
//! (`tests/server/harness.rs`); their logs go to one file.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use meshwiki_engine::lod::VertexOrder;

/// Log filter of the spawned processes (their output goes to a log file).
fn log_filter() -> String {
    std::env::var("MESHWIKI_LOG").unwrap_or_else(|_| "warn".into())
}

fn log_file(path: &Path) -> Result<std::fs::File> {
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .with_context(|| format!("opening {}", path.display()))
}

/// The last lines of the log, for error messages.
pub fn log_tail(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(15)..].join("\n")
}

/// This binary's subcommands on one data directory.
#[derive(Debug, Clone)]
pub struct Meshwiki {
    pub exe: PathBuf,
    pub data_dir: PathBuf,
    pub log: PathBuf,
}

impl Meshwiki {
    fn command(&self, args: &[&str]) -> Result<Command> {
        let mut c = Command::new(&self.exe);
        c.args(args)
            .arg("--data-dir")
            .arg(&self.data_dir)
            .env("MESHWIKI_LOG", log_filter())
            .stderr(log_file(&self.log)?);
        Ok(c)
    }

    /// `user add NAME --role admin`, the password on standard input.
    pub fn add_admin(&self, name: &str, password: &str) -> Result<()> {
        let mut child = self
            .command(&["user", "add", name, "--role", "admin"])?
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .spawn()
            .context("running meshwiki user add")?;
        if let Some(mut stdin) = child.stdin.take() {
            // A closed pipe means the command failed early: its status says why.
            let _ = stdin.write_all(format!("{password}\n").as_bytes());
        }
        let status = child.wait().context("waiting for meshwiki user add")?;
        if !status.success() {
            bail!("meshwiki user add failed:\n{}", log_tail(&self.log));
        }
        Ok(())
    }

    /// `import FILE --title T --vertex-order O`: builds the model through the real pipeline
    /// (the order named, so the ground truth's map stays right); returns its id.
    pub fn import(&self, file: &Path, title: &str, order: VertexOrder) -> Result<i64> {
        let file = file.to_string_lossy();
        let out = self
            .command(&[
                "import",
                &*file,
                "--title",
                title,
                "--vertex-order",
                order.as_str(),
            ])?
            .stdin(Stdio::null())
            .output()
            .context("running meshwiki import")?;
        let stdout = String::from_utf8_lossy(&out.stdout);
        if !out.status.success() {
            bail!("meshwiki import {file} failed:\n{}", log_tail(&self.log));
        }
        stdout
            .lines()
            .find_map(|l| {
                let rest = l.split(" as model ").nth(1)?;
                rest.split_whitespace().next()?.parse().ok()
            })
            .with_context(|| format!("meshwiki import printed no model id: {stdout}"))
    }

    /// `serve --bind 127.0.0.1:0`, waiting until it listens.
    pub fn serve(&self) -> Result<Running> {
        let mut child = self
            .command(&["serve", "--bind", "127.0.0.1:0", "--workers", "2"])?
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .spawn()
            .context("running meshwiki serve")?;
        let stdout = child.stdout.take().context("server output")?;
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut tx = Some(tx);
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if let Some(addr) = line.strip_prefix(meshwiki::config::LISTENING)
                    && let Some(tx) = tx.take()
                {
                    let _ = tx.send(addr.trim().to_string());
                }
            }
        });
        let server = Server { child };
        match rx.recv_timeout(Duration::from_secs(120)) {
            Ok(base) => Ok(server.with_base(base)),
            Err(_) => bail!(
                "the server did not start within 120 s:\n{}",
                log_tail(&self.log)
            ),
        }
    }
}

/// A running server, stopped on drop.
#[derive(Debug)]
pub struct Server {
    child: Child,
}

/// A running server and its address.
#[derive(Debug)]
pub struct Running {
    /// Kept for its drop, which stops the server.
    _server: Server,
    pub base: String,
}

impl Server {
    fn with_base(self, base: String) -> Running {
        let base = if base.starts_with("http://") {
            base
        } else {
            format!("http://{base}")
        };
        Running {
            _server: self,
            base,
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
