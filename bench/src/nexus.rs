//! Nexus' builder run side by side: `nxsbuild INPUT -o OUT.nxs` then `nxscompress OUT.nxs -o
//! OUT.nxz`, each as a child process whose wall time, CPU time (user + system) and peak
//! resident memory come from the kernel (`wait4`'s resource usage), as `/usr/bin/time -v`
//! reports them. The binaries are looked for in `../shared/tools/nexus/` (beside the checkout
//! or the working directory) unless a path is given; see that folder's README for the build.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use anyhow::{Context, bail};

/// What one child process cost.
#[derive(Debug, Clone, Copy, Default)]
pub struct Cost {
    pub wall: f64,
    pub cpu: f64,
    pub peak_bytes: u64,
}

/// The two Nexus steps and what they wrote.
#[derive(Debug, Clone)]
pub struct Run {
    pub build: Cost,
    pub compress: Option<Cost>,
    pub nxs_bytes: u64,
    pub nxz_bytes: Option<u64>,
}

impl Run {
    /// Build and compression together (wall and CPU add up; memory is the larger peak).
    pub fn total(&self) -> Cost {
        let c = self.compress.unwrap_or_default();
        Cost {
            wall: self.build.wall + c.wall,
            cpu: self.build.cpu + c.cpu,
            peak_bytes: self.build.peak_bytes.max(c.peak_bytes),
        }
    }
}

/// The folder holding `nxsbuild`: `explicit`, else `../shared/tools/nexus` beside the working
/// directory or beside the workspace.
pub fn locate(explicit: Option<&Path>) -> Option<PathBuf> {
    if let Some(p) = explicit {
        let dir = if p.is_dir() {
            p.to_path_buf()
        } else {
            p.parent()?.to_path_buf()
        };
        return dir.join("nxsbuild").is_file().then_some(dir);
    }
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    [Path::new(".."), workspace.as_path(), &workspace.join("..")]
        .iter()
        .map(|base| base.join("shared/tools/nexus"))
        .find(|dir| dir.join("nxsbuild").is_file())
}

/// Whether nxsbuild reads this input (it takes PLY, OBJ and STL).
pub fn reads(input: &Path) -> bool {
    input
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "ply" | "obj" | "stl"))
}

/// Runs nxsbuild (and nxscompress when it is there) on `input`, writing into `scratch`.
pub fn run(dir: &Path, input: &Path, scratch: &Path) -> anyhow::Result<Run> {
    let nxs = scratch.join("nexus.nxs");
    let nxz = scratch.join("nexus.nxz");
    let build = measure(
        Command::new(dir.join("nxsbuild"))
            .arg(input)
            .arg("-o")
            .arg(&nxs),
    )
    .context("nxsbuild")?;
    let nxs_bytes = std::fs::metadata(&nxs)
        .with_context(|| format!("nxsbuild wrote no {}", nxs.display()))?
        .len();
    let (compress, nxz_bytes) = if dir.join("nxscompress").is_file() {
        let cost = measure(
            Command::new(dir.join("nxscompress"))
                .arg(&nxs)
                .arg("-o")
                .arg(&nxz),
        )
        .context("nxscompress")?;
        let bytes = std::fs::metadata(&nxz)
            .with_context(|| format!("nxscompress wrote no {}", nxz.display()))?
            .len();
        (Some(cost), Some(bytes))
    } else {
        (None, None)
    };
    Ok(Run {
        build,
        compress,
        nxs_bytes,
        nxz_bytes,
    })
}

/// Runs `cmd` to its end (its output discarded) and returns what it cost.
fn measure(cmd: &mut Command) -> anyhow::Result<Cost> {
    let started = Instant::now();
    let child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .context("cannot start (is Qt 5 installed? apt-get install libqt5gui5)")?;
    let pid = child.id() as libc::pid_t;
    // The child's stderr is read on a thread so that a chatty child never blocks on a full pipe.
    let mut stderr = child.stderr;
    let tail = std::thread::spawn(move || {
        let mut text = String::new();
        if let Some(s) = stderr.as_mut() {
            let _ = std::io::Read::read_to_string(s, &mut text);
        }
        text
    });
    let mut status: libc::c_int = 0;
    // SAFETY: `rusage` is plain old data, zero is a valid value of it.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `pid` is our own child, not yet waited for (`Child` never waited); the pointers
    // are to live locals.
    let waited = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    let wall = started.elapsed().as_secs_f64();
    if waited != pid {
        bail!("wait4 failed: {}", std::io::Error::last_os_error());
    }
    let text = tail.join().unwrap_or_default();
    if !(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0) {
        let last: Vec<&str> = text.lines().rev().take(5).collect();
        bail!(
            "failed (status {status}): {}",
            last.into_iter().rev().collect::<Vec<_>>().join(" / ")
        );
    }
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 / 1e6;
    Ok(Cost {
        wall,
        cpu: seconds(usage.ru_utime) + seconds(usage.ru_stime),
        // Linux reports ru_maxrss in KiB.
        peak_bytes: usage.ru_maxrss.max(0) as u64 * 1024,
    })
}

/// CPU time (user + system) this process has used so far, in seconds.
pub fn own_cpu_seconds() -> f64 {
    // SAFETY: as above; RUSAGE_SELF with a pointer to a live local.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return 0.0;
    }
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 / 1e6;
    seconds(usage.ru_utime) + seconds(usage.ru_stime)
}
