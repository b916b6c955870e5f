//! Unpacking the `.tar.zst` archives of `../shared/data` for the benches, with the `zstd` and
//! `tar` commands (no archive crates in the binary for a developer tool).

use std::ffi::OsStr;
use std::path::Path;
use std::process::{Command, Stdio};

use anyhow::{Context, Result, bail};

/// Extracts `members` of `archive` (all of it when empty) into the existing directory `dest`.
pub fn untar_zstd<S: AsRef<OsStr>>(archive: &Path, dest: &Path, members: &[S]) -> Result<()> {
    let mut zstd = Command::new("zstd")
        .arg("-dc")
        .arg(archive)
        .stdout(Stdio::piped())
        .spawn()
        .context("running zstd (is it installed?)")?;
    let pipe = zstd.stdout.take().context("zstd output")?;
    let mut tar = Command::new("tar");
    tar.arg("-x").arg("-C").arg(dest);
    if !members.is_empty() {
        tar.arg("--").args(members);
    }
    let tar = tar.stdin(pipe).status().context("running tar")?;
    let z = zstd.wait().context("waiting for zstd")?;
    if !z.success() || !tar.success() {
        bail!("unpacking {} failed", archive.display());
    }
    Ok(())
}
