//! `meshwiki-bench render MODEL`: server-side rendering of a fixed camera path (60 frames
//! orbiting and zooming in and out) at 1280×720 and a 1-pixel error threshold on the software
//! adapter (system paper §3.3). Prints frame time (p50/p95), triangles and patches drawn,
//! patches loaded, cache bytes and peak memory; a few frames of selection buffers are timed too.
//! Every frame is also drawn by the bare-draw reference ([`bare`]: the same triangles, the
//! smallest pipeline, the same targets read back) in the same run, and the ratio printed; the
//! renderer's own profile says where its time goes (targets, encoding, GPU, read-back, decode).
//! Then every selection tool runs on a few views of the path, its time printed per stage
//! ([`select`]).
//!
//! `MODEL` is a `.mwlod` file, a mesh file (its LOD is built into a temporary directory first),
//! or `synth:N` for the generated relief of about N triangles (e.g. `synth:10000000`).
//! With `--out DIR`, the first, middle and last frames are written there as PNG, with a JSON
//! summary. `MESHWIKI_RENDER_CACHE` sets the patch cache budget (e.g. `256M`; default 512M).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::{self, BuildOptions};
use meshwiki_engine::mesh::{ImportStats, synth};
use meshwiki_engine::progress::NoProgress;
use meshwiki_engine::render::encode::{self, ImageFormat};
use meshwiki_engine::render::{
    AdapterChoice, Cut, FrameProfile, GpuDevice, NO_NODE, Outputs, RenderModel, RenderOptions,
    Renderer, RendererOptions,
};

mod bare;
mod select;

const FRAMES: usize = 60;
const WIDTH: u32 = 1280;
const HEIGHT: u32 = 720;
const PIXEL_ERROR: f32 = 1.0;
const FOVY: f32 = 45.0;
/// Frames of the path also rendered with every buffer (selection).
const BUFFER_FRAMES: usize = 10;

/// Temporary directory removed on drop.
pub(crate) struct TempDir(pub(crate) PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn rss_line(key: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(key))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

fn mb(bytes: u64) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// Prints the mean of each stage of `profiles`.
fn print_profile(label: &str, profiles: &[FrameProfile]) {
    let n = profiles.len().max(1) as f64;
    let mean = |f: fn(&FrameProfile) -> f64| profiles.iter().map(f).sum::<f64>() / n;
    println!(
        "{label}: targets {:.1} ms, encode {:.1} ms, submit {:.1} ms, GPU {:.1} ms, read-back and decode {:.1} ms ({:.1} MB)",
        mean(|p| p.targets_ms),
        mean(|p| p.encode_ms),
        mean(|p| p.submit_ms),
        mean(|p| p.gpu_ms),
        mean(|p| p.read_ms),
        mean(|p| p.read_bytes as f64) / 1e6,
    );
}

/// Opens `model`, building its LOD file first when it is a mesh or `synth:N`.
fn open_model(model: &Path, temp: &mut Option<TempDir>) -> Result<(RenderModel, Option<f64>)> {
    let name = model.to_string_lossy();
    if model.extension().is_some_and(|e| e == "mwlod") {
        let m = RenderModel::open(model).with_context(|| format!("opening {}", model.display()))?;
        return Ok((m, None));
    }
    let dir = std::env::temp_dir().join(format!("meshwiki-bench-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let dir = temp.insert(TempDir(dir)).0.clone();
    let out = dir.join("model.mwlod");
    let options = BuildOptions {
        scratch_dir: Some(dir.clone()),
        ..BuildOptions::default()
    };
    let started = Instant::now();
    let report = if let Some(n) = name.strip_prefix("synth:") {
        let tris: u64 = n
            .trim()
            .replace('_', "")
            .parse()
            .with_context(|| format!("bad triangle count in {name}"))?;
        if tris == 0 {
            bail!("synth: needs a positive triangle count");
        }
        println!("generating and building a relief of about {tris} triangles ...");
        let relief = synth::Relief::new(tris, synth::DEFAULT_SEED);
        let stats = ImportStats {
            vertices: relief.vertex_count(),
            triangles: relief.triangle_count(),
            has_colors: true,
            ..Default::default()
        };
        lod::build_from(
            |sink| relief.stream(sink).map(|_| stats.clone()),
            &out,
            &options,
            &NoProgress,
        )
    } else {
        if !model.is_file() {
            bail!(
                "{} is not a file (expected .mwlod, a mesh file or synth:N)",
                model.display()
            );
        }
        println!("building the LOD of {} ...", model.display());
        lod::build_file(model, &out, &options, &NoProgress)
    }
    .context("building the LOD file")?;
    let seconds = started.elapsed().as_secs_f64();
    println!(
        "built {} triangles into {} nodes ({} levels, {:.1} MB) in {seconds:.1} s",
        report.import.triangles,
        report.nodes,
        report.levels,
        report.output_bytes as f64 / 1e6
    );
    Ok((
        RenderModel::open(&out).context("opening the built LOD file")?,
        Some(seconds),
    ))
}

/// The camera path: an orbit that zooms from 2.4 to 0.5 model radii and back. Flat models
/// (reliefs) are orbited around their thin axis at a 25° tilt, others around +Y at 15°.
fn camera_path(model: &RenderModel) -> Vec<Camera> {
    let ext = model.extents();
    let centre = model.center();
    let radius = model.radius().max(1e-6);
    let thin = model.thin_axis();
    let largest = ext.iter().copied().fold(0.0, f32::max);
    let flat = ext[thin] < 0.35 * largest;
    let axis = |k: usize| glam::Vec3::AXES[k];
    let (base, up) = if flat {
        (axis(thin), axis(if thin == 1 { 2 } else { 1 }))
    } else {
        (glam::Vec3::Z, glam::Vec3::Y)
    };
    (0..FRAMES)
        .map(|i| {
            let t = i as f32 / (FRAMES - 1) as f32;
            let az = std::f32::consts::TAU * t;
            let dir = if flat {
                let tilt =
                    glam::Quat::from_axis_angle(base.cross(up).normalize(), 25f32.to_radians());
                glam::Quat::from_axis_angle(base, az) * (tilt * base)
            } else {
                let elev =
                    glam::Quat::from_axis_angle(base.cross(up).normalize(), -15f32.to_radians());
                glam::Quat::from_axis_angle(up, az) * (elev * base)
            };
            let distance = radius * (2.4 - 1.9 * (std::f32::consts::PI * t).sin());
            Camera {
                eye: centre + dir.normalize() * distance,
                target: centre,
                up,
                fovy_deg: FOVY,
                width: WIDTH,
                height: HEIGHT,
            }
        })
        .collect()
}

/// Runs the benchmark on `model` (see the module documentation).
pub fn run(model: &Path, out_dir: Option<&Path>) -> Result<()> {
    let mut temp = None;
    let (model, build_seconds) = open_model(model, &mut temp)?;
    if let Some(dir) = out_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut settings = RendererOptions::default();
    if let Ok(v) = std::env::var("MESHWIKI_RENDER_CACHE") {
        settings.cache_bytes = meshwiki::jobs::parse_size(&v)
            .map_err(anyhow::Error::msg)
            .context("MESHWIKI_RENDER_CACHE")?
            .max(1 << 20);
    }
    // The software adapter unless `MESHWIKI_RENDER_ADAPTER` asks for another (as the server).
    let choice = match std::env::var("MESHWIKI_RENDER_ADAPTER") {
        Ok(name) => AdapterChoice::parse(name.trim()).with_context(|| {
            format!("MESHWIKI_RENDER_ADAPTER={name:?}: auto, software or hardware")
        })?,
        Err(_) => AdapterChoice::Software,
    };
    let gpu = GpuDevice::new(choice).with_context(|| format!("opening the {choice:?} adapter"))?;
    let renderer = Renderer::new(gpu.clone(), settings);
    let mut reference = bare::Bare::new(gpu).context("the bare-draw reference")?;
    let lod = model.lod();
    let h = lod.header();
    println!("device: {}", renderer.device().describe());
    println!(
        "model: {} input triangles, {} nodes, {} levels, {} KB of tables + {:.1} MB of patches",
        h.input_triangle_count,
        h.node_count,
        h.level_count,
        h.blobs_offset / 1024,
        h.blobs_len as f64 / 1e6
    );
    // Peak memory of the rendering alone: reset the high-water mark after the build.
    let reset = std::fs::write("/proc/self/clear_refs", "5").is_ok();
    let rss_before = rss_line("VmRSS:");
    let cams = camera_path(&model);
    let options = RenderOptions {
        cut: Cut::View {
            pixel_error: PIXEL_ERROR,
            culling: lod::Culling::ALL,
        },
        outputs: Outputs::IMAGE,
        background: [0, 0, 0, 255],
        ..RenderOptions::default()
    };
    let mut times = Vec::with_capacity(FRAMES);
    let mut bare_times = Vec::with_capacity(FRAMES);
    let mut profiles = Vec::with_capacity(FRAMES);
    let (mut tris, mut nodes, mut loaded, mut max_loaded) =
        (Vec::new(), Vec::new(), 0usize, 0usize);
    let mut max_cache = 0u64;
    let (mut cut_ms, mut load_ms, mut draw_ms) = (0f64, 0f64, 0f64);
    let started = Instant::now();
    for (i, cam) in cams.iter().enumerate() {
        let t = Instant::now();
        let frame = renderer
            .render(&model, cam, &options, &[])
            .with_context(|| format!("frame {i}"))?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
        profiles.push(frame.stats.profile);
        // The same cut by the bare reference (its patches uploaded first, untimed: the
        // renderer's cache is warm after its first frames too).
        let cut_nodes = renderer.cut_nodes(&model, cam, &options.cut)?;
        reference.load(&model, &cut_nodes)?;
        bare_times.push(
            reference
                .frame(&cut_nodes, cam, frame.stats.near, false)?
                .as_secs_f64()
                * 1e3,
        );
        cut_ms += frame.stats.cut_ms;
        load_ms += frame.stats.load_ms;
        draw_ms += frame.stats.draw_ms;
        tris.push(frame.stats.triangles);
        nodes.push(frame.stats.nodes);
        loaded += frame.stats.loaded;
        max_loaded = max_loaded.max(frame.stats.loaded);
        max_cache = max_cache.max(frame.stats.cache.live_bytes);
        if let (Some(dir), true) = (out_dir, [0, FRAMES / 2, FRAMES - 1].contains(&i)) {
            let color = frame.color.as_ref().context("no colour")?;
            let png = encode::encode(color, WIDTH, HEIGHT, ImageFormat::Png, 90, [0; 3])?;
            std::fs::write(dir.join(format!("frame_{i:03}.png")), png)?;
        }
    }
    let wall = started.elapsed().as_secs_f64();
    let first = times[0];
    let mut sorted = times.clone();
    sorted.sort_by(f64::total_cmp);
    let mean = |v: &[u64]| v.iter().sum::<u64>() as f64 / v.len().max(1) as f64;
    let mean_tris = mean(&tris);
    let mean_nodes = nodes.iter().sum::<usize>() as f64 / nodes.len().max(1) as f64;

    // Selection buffers on a subset of the path, with a warm cache.
    let buffers = RenderOptions {
        outputs: Outputs::ALL,
        ..options.clone()
    };
    let mut buffer_times = Vec::new();
    let mut bare_buffer_times = Vec::new();
    let mut buffer_profiles = Vec::new();
    let (mut covered, mut covered_tris) = (0u64, 0u64);
    for cam in cams.iter().step_by(FRAMES / BUFFER_FRAMES) {
        let t = Instant::now();
        let frame = renderer
            .render(&model, cam, &buffers, &[])
            .context("buffers frame")?;
        buffer_times.push(t.elapsed().as_secs_f64() * 1e3);
        buffer_profiles.push(frame.stats.profile);
        if let Some(ids) = &frame.ids {
            covered += ids.node.iter().filter(|&&n| n != NO_NODE).count() as u64;
            covered_tris += frame.stats.triangles;
        }
        let cut_nodes = renderer.cut_nodes(&model, cam, &buffers.cut)?;
        reference.load(&model, &cut_nodes)?;
        bare_buffer_times.push(
            reference
                .frame(&cut_nodes, cam, frame.stats.near, true)?
                .as_secs_f64()
                * 1e3,
        );
    }
    buffer_times.sort_by(f64::total_cmp);
    bare_buffer_times.sort_by(f64::total_cmp);
    let mut bare_sorted = bare_times.clone();
    bare_sorted.sort_by(f64::total_cmp);
    let cache = renderer.cache_stats();
    let peak = lod::peak_rss_bytes();

    println!(
        "camera path: {FRAMES} frames at {WIDTH}x{HEIGHT}, {PIXEL_ERROR} px error, orbit + zoom (2.4 -> 0.5 -> 2.4 radii)"
    );
    println!(
        "frame time: p50 {:.1} ms, p95 {:.1} ms, first (cold cache) {first:.1} ms, mean {:.1} ms ({:.1} fps over {wall:.1} s)",
        percentile(&sorted, 0.5),
        percentile(&sorted, 0.95),
        times.iter().sum::<f64>() / times.len() as f64,
        FRAMES as f64 / wall
    );
    println!(
        "  per frame: cut {:.1} ms, patch loads {:.1} ms, encode + draw + read-back {:.1} ms (means)",
        cut_ms / FRAMES as f64,
        load_ms / FRAMES as f64,
        draw_ms / FRAMES as f64
    );
    print_profile("  profile (means)", &profiles);
    let ratio = percentile(&sorted, 0.5) / percentile(&bare_sorted, 0.5).max(1e-9);
    println!(
        "bare-draw reference (same cut, positions only, one colour, colour read back): p50 {:.1} ms, p95 {:.1} ms; meshwiki / bare = {ratio:.2}x (p50)",
        percentile(&bare_sorted, 0.5),
        percentile(&bare_sorted, 0.95),
    );
    println!(
        "triangles drawn: mean {:.0}, max {} ({:.1}% of the input at most); patches drawn: mean {mean_nodes:.0}, max {}",
        mean_tris,
        tris.iter().max().copied().unwrap_or(0),
        100.0 * tris.iter().max().copied().unwrap_or(0) as f64
            / h.input_triangle_count.max(1) as f64,
        nodes.iter().max().copied().unwrap_or(0)
    );
    println!(
        "patches loaded: {loaded} over the path (max {max_loaded} in one frame) of {} nodes; evictions {}",
        h.node_count, cache.evictions
    );
    println!(
        "cache: {:.1} MB resident (peak {:.1} MB alive) of a {:.0} MB budget, {} entries",
        mb(cache.resident_bytes),
        mb(max_cache),
        mb(cache.budget_bytes),
        cache.entries
    );
    println!(
        "selection buffers (colour, normal, depth, ids): p50 {:.1} ms, p95 {:.1} ms over {} frames",
        percentile(&buffer_times, 0.5),
        percentile(&buffer_times, 0.95),
        buffer_times.len()
    );
    print_profile("  profile (means)", &buffer_profiles);
    println!(
        "  bare-draw reference (colour + node/primitive ids, both read back): p50 {:.1} ms; meshwiki / bare = {:.2}x (p50)",
        percentile(&bare_buffer_times, 0.5),
        percentile(&buffer_times, 0.5) / percentile(&bare_buffer_times, 0.5).max(1e-9)
    );
    println!(
        "  triangles per covered pixel: {:.2} ({covered_tris} triangles over {covered} covered pixels)",
        covered_tris as f64 / covered.max(1) as f64
    );
    let selection_cams: Vec<Camera> = cams
        .iter()
        .step_by(FRAMES / BUFFER_FRAMES)
        .copied()
        .collect();
    select::run(&renderer, &model, &selection_cams)?;
    match (peak, rss_before) {
        (Some(p), Some(b)) => println!(
            "memory: peak RSS {:.0} MB{} (RSS before rendering {:.0} MB)",
            mb(p),
            if reset {
                " while rendering"
            } else {
                " (includes the build)"
            },
            mb(b)
        ),
        _ => println!("memory: peak RSS not reported on this platform"),
    }
    if let Some(dir) = out_dir {
        let json = format!(
            "{{\"frames\":{FRAMES},\"width\":{WIDTH},\"height\":{HEIGHT},\"pixel_error\":{PIXEL_ERROR},\"device\":{:?},\"input_triangles\":{},\"nodes\":{},\"build_seconds\":{},\"p50_ms\":{:.2},\"p95_ms\":{:.2},\"first_ms\":{first:.2},\"mean_triangles\":{mean_tris:.0},\"max_triangles\":{},\"patches_loaded\":{loaded},\"cache_resident_bytes\":{},\"cache_peak_bytes\":{max_cache},\"buffers_p50_ms\":{:.2},\"peak_rss_bytes\":{}}}\n",
            renderer.device().describe(),
            h.input_triangle_count,
            h.node_count,
            build_seconds.map_or("null".to_string(), |s| format!("{s:.2}")),
            percentile(&sorted, 0.5),
            percentile(&sorted, 0.95),
            tris.iter().max().copied().unwrap_or(0),
            cache.resident_bytes,
            percentile(&buffer_times, 0.5),
            peak.map_or("null".to_string(), |p| p.to_string())
        );
        std::fs::write(dir.join("bench_render.json"), json)?;
        println!("frames and summary written to {}", dir.display());
    }
    Ok(())
}
