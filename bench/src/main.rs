//! `meshwiki-bench`: the benchmarks of meshwiki, outside the product binary. Figures are
//! printed (with ratios to a reference where one runs on the same machine), never asserted.
//! The selection bench drives the real `meshwiki` binary over HTTP; the others call the
//! server crate and the engine directly.

mod build;
mod build_bytes;
mod maxflow;
mod nexus;
mod normals;
mod render;
mod search;
mod select;
mod simplify;
mod textures;
mod untar;

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, Parser, Subcommand};

/// meshwiki's benchmarks (figures are printed, never asserted).
#[derive(Debug, Parser)]
#[command(name = "meshwiki-bench", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Index generated contents and measure query latency.
    Search(search::Args),
    /// Build a scan's LOD hierarchy: throughput, peak memory, output size vs nxsbuild.
    Build(build::Args),
    /// The max-flow solver on the reference grid instances (`../shared/data/maxflow`).
    Maxflow {
        /// Directory of the instances or their archive (default `../shared/data/maxflow`).
        dir: Option<PathBuf>,
    },
    /// Server-side rendering of a camera path at 1280x720 and 1 px on the software adapter
    /// (`.mwlod`, a scan, or `synth:N`): frame time p50/p95, triangles, patches, memory.
    Render {
        /// The model: a `.mwlod` file, a scan file or `synth:N` (e.g. `synth:10000000`).
        model: PathBuf,
        /// Write a few frames and a JSON summary here.
        #[arg(long = "out", value_name = "DIR")]
        out_dir: Option<PathBuf>,
    },
    /// The selection tools (heavy lasso, markup, lasso) through the real server against the
    /// Princeton segmentation benchmark: error vs ground truth and latency per tool.
    Select(select::Args),
    /// Quadric collapses against the mesh-segmentation paper's segment-driven simplification
    /// on real scans: distance at equal triangles, triangles at equal distance.
    Simplify(simplify::Args),
    /// Textured scans: fragment JPEG quality by feature density against uniform quality at
    /// equal bytes (texel PSNR of featured and plain fragments).
    Textures(textures::Args),
    /// Normal maps for coarse patches and silhouette-first refinement: bytes to a given
    /// image quality along a camera path, with and without.
    Normals(normals::Args),
}

/// The data directory.
#[derive(Debug, Clone, Args)]
pub struct DataDirArgs {
    /// Data directory (the bench works in a scratch sub-directory it removes afterwards).
    #[arg(long, env = "MESHWIKI_DATA_DIR", default_value = meshwiki::config::DEFAULT_DATA_DIR)]
    pub data_dir: PathBuf,
}

/// The `meshwiki` binary the selection bench runs: `MESHWIKI_BIN`, else the one beside this
/// executable (both are built into the same target directory).
pub fn meshwiki_binary() -> anyhow::Result<PathBuf> {
    if let Some(p) = std::env::var_os("MESHWIKI_BIN") {
        return Ok(PathBuf::from(p));
    }
    let me = std::env::current_exe().context("locating this executable")?;
    let dir = me.parent().context("this executable has no directory")?;
    let candidate = dir.join(format!("meshwiki{}", std::env::consts::EXE_SUFFIX));
    if !candidate.is_file() {
        bail!(
            "no meshwiki binary at {}: build it (`cargo build --release -p meshwiki`) or set \
             MESHWIKI_BIN",
            candidate.display()
        );
    }
    Ok(candidate)
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    meshwiki::terminal::init_logging();
    let result = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the runtime")
        .and_then(|rt| rt.block_on(run(cli)));
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

async fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Search(args) => search::run(args).await,
        Command::Build(args) => build::run(args).await,
        Command::Maxflow { dir } => {
            tokio::task::spawn_blocking(move || maxflow::run(dir.as_deref())).await?
        }
        Command::Render { model, out_dir } => {
            tokio::task::spawn_blocking(move || render::run(&model, out_dir.as_deref())).await?
        }
        Command::Select(args) => tokio::task::spawn_blocking(move || select::run(args)).await?,
        Command::Simplify(args) => tokio::task::spawn_blocking(move || simplify::run(args)).await?,
        Command::Textures(args) => tokio::task::spawn_blocking(move || textures::run(args)).await?,
        Command::Normals(args) => tokio::task::spawn_blocking(move || normals::run(args)).await?,
    }
}
