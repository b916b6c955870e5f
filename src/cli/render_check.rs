//! `meshwiki render-check`: the renderer's self-test. Opens the adapter the server would use,
//! builds a small generated relief into a temporary `.mwlod`, renders it and checks that the
//! surface covers the image. Prints the adapter; exit code 1 (with the reason) when no adapter
//! opens or the image is wrong. The container image runs it at build time, and
//! `scripts/check-image` runs it in a clean root holding exactly the image's packages.

use anyhow::{Context, Result, bail};
use clap::Args as ClapArgs;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::{self, BuildOptions};
use meshwiki_engine::mesh::synth;
use meshwiki_engine::progress::NoProgress;
use meshwiki_engine::render::{AdapterChoice, RenderModel, Renderer, RendererOptions};

/// Options of `render-check`.
#[derive(Debug, Clone, ClapArgs)]
pub struct Args {
    /// Adapter to test: auto (a GPU, else the software adapter), software or hardware.
    #[arg(long, env = "MESHWIKI_RENDER_ADAPTER", default_value = "auto")]
    pub adapter: String,
}

/// Side of the test image.
const SIDE: u32 = 128;

/// Runs the self-test.
pub fn run(args: &Args) -> Result<()> {
    let choice = AdapterChoice::parse(args.adapter.trim()).with_context(|| {
        format!(
            "unknown render adapter {:?} (expected auto, software or hardware)",
            args.adapter
        )
    })?;
    let renderer = Renderer::open(choice, RendererOptions::default()).context(
        "no render adapter opens (is a Vulkan driver, e.g. Mesa's lavapipe, installed?)",
    )?;
    println!("adapter: {}", renderer.device().describe());

    let dir = tempfile_dir()?;
    let out = dir.0.join("check.mwlod");
    let relief = synth::Relief::new(20_000, synth::DEFAULT_SEED);
    let stats = relief.stats(false);
    let options = BuildOptions {
        scratch_dir: Some(dir.0.clone()),
        ..BuildOptions::default()
    };
    lod::build_from(
        |sink| relief.stream(sink).map(|_| stats.clone()),
        &out,
        &options,
        &NoProgress,
    )
    .context("building the test relief")?;
    let model = RenderModel::open(&out).context("opening the test relief")?;
    // Look along the relief's thin axis (it faces that way), from 2.5 radii.
    let thin = model.thin_axis();
    let axis = glam::Vec3::AXES[thin];
    let camera = Camera {
        eye: model.center() + axis * model.radius().max(1e-6) * 2.5,
        target: model.center(),
        up: glam::Vec3::AXES[if thin == 1 { 2 } else { 1 }],
        fovy_deg: 45.0,
        width: SIDE,
        height: SIDE,
    };
    let frame = renderer
        .render_image(&model, &camera, &[])
        .context("rendering the test relief")?;
    let color = frame.color.unwrap_or_default();
    let covered = color.iter().filter(|c| c[3] == 255).count();
    let lit = color
        .iter()
        .filter(|c| c[3] == 255 && (c[0] as u32 + c[1] as u32 + c[2] as u32) > 30)
        .count();
    let total = (SIDE * SIDE) as usize;
    println!(
        "rendered {} triangles at {SIDE}x{SIDE}: {covered} of {total} pixels covered, {lit} lit",
        frame.stats.triangles
    );
    if covered < total / 10 || lit < covered / 2 {
        bail!("the test image is wrong: {covered} of {total} pixels covered, {lit} lit");
    }
    println!("render self-test passed");
    Ok(())
}

struct TempDir(std::path::PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn tempfile_dir() -> Result<TempDir> {
    let dir = std::env::temp_dir().join(format!(
        "meshwiki-render-check-{}-{}",
        std::process::id(),
        meshwiki::random_hex(4)
    ));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(TempDir(dir))
}
