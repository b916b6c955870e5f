//! `meshwiki-bench normals`: normal maps for coarse patches and silhouette-first refinement
//! (issue 11 item 4; the progressive-transmission paper, `003_a45e3c21566e682e.txt` §4–5),
//! measured as bytes to a given image quality along a camera path, not assumed.
//!
//! The scan is built twice, without and with normal maps. For every view of the path the
//! reference is the full-resolution scan (every leaf) rendered at twice the size and scaled
//! down 2:1 in linear light; each variant (no normal maps; normal maps with silhouette-first
//! factors `F`, 1 meaning off) is rendered at each pixel threshold, by the server's renderer
//! with its default headlight. A view's bytes are the blobs of its cut: what a client that
//! starts at that view downloads. Printed per variant and threshold: bytes over the path and
//! mean PSNR; then, per target PSNR (by default what vertex normals reach at each threshold),
//! the bytes each variant needs (interpolated in PSNR between thresholds). Figures are
//! printed, never asserted.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::render::TempDir;
use anyhow::{Context, Result, bail};
use clap::Args as ClapArgs;
use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::{self, BuildOptions, Culling, Silhouette};
use meshwiki_engine::mesh::{self, Relief, encode_rgba, srgb_to_linear};
use meshwiki_engine::progress::NoProgress;
use meshwiki_engine::render::{
    AdapterChoice, Cut, GpuDevice, RenderModel, RenderOptions, Renderer, RendererOptions,
};

/// Options of `bench normals`.
#[derive(Debug, Clone, ClapArgs)]
pub struct Args {
    /// A scan file, or `synth:N` for the generated relief of N triangles.
    #[arg(default_value = "synth:1000000")]
    pub scan: String,
    /// Image size (width; height is 3/4 of it).
    #[arg(long, default_value_t = 640)]
    pub size: u32,
    /// Views along the path.
    #[arg(long, default_value_t = 6)]
    pub views: usize,
    /// Pixel thresholds of the cut.
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 2.0, 4.0, 8.0])]
    pub thresholds: Vec<f32>,
    /// Normal map densities to build: texels along a coarse patch's mean triangle edge
    /// (`BuildOptions::normal_map_density`).
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 2.0, 4.0])]
    pub densities: Vec<f32>,
    /// Silhouette-first factors measured with normal maps (1: off).
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 2.0, 4.0])]
    pub factors: Vec<f32>,
    /// Target PSNRs for the bytes-to-quality summary (default: what vertex normals reach at
    /// each threshold).
    #[arg(long, value_delimiter = ',')]
    pub targets: Vec<f64>,
    /// Write the first view's reference and each variant's images (PNG) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

fn build(scan: &str, out: &Path, density: Option<f32>) -> Result<lod::BuildReport> {
    let options = BuildOptions {
        normal_maps: density.is_some(),
        normal_map_density: density.unwrap_or(1.0),
        vertex_order: lod::VertexOrder::Morton,
        ..BuildOptions::default()
    };
    let report = if let Some(n) = scan.strip_prefix("synth:") {
        let tris: u64 = n
            .trim()
            .replace('_', "")
            .parse()
            .with_context(|| format!("bad triangle count in {scan}"))?;
        if tris == 0 {
            bail!("synth: needs a positive triangle count");
        }
        let relief = Relief::new(tris, mesh::synth::DEFAULT_SEED);
        lod::build_from(
            |sink| {
                relief.stream(sink)?;
                Ok(relief.stats(false))
            },
            out,
            &options,
            &NoProgress,
        )
    } else {
        lod::build_file(Path::new(scan), out, &options, &NoProgress)
    };
    report.with_context(|| format!("building {scan}"))
}

/// An orbit that zooms from 2.2 to 0.6 model radii, at 30° over the model's widest plane.
fn cameras(model: &RenderModel, views: usize, width: u32, height: u32) -> Vec<Camera> {
    let thin = model.thin_axis();
    let base = Vec3::AXES[thin];
    let up = Vec3::AXES[if thin == 1 { 2 } else { 1 }];
    let centre = model.center();
    let radius = model.radius().max(1e-6);
    (0..views)
        .map(|i| {
            let t = i as f32 / views.max(2).saturating_sub(1) as f32;
            let az = std::f32::consts::PI * 0.8 * (t - 0.5);
            let tilt = glam::Quat::from_axis_angle(base.cross(up).normalize(), 30f32.to_radians());
            let dir = glam::Quat::from_axis_angle(base, az) * (tilt * base);
            let distance = radius * (2.2 - 1.6 * t);
            Camera {
                eye: centre + dir.normalize() * distance,
                target: centre + up * radius * 0.15 * t,
                up,
                fovy_deg: 40.0,
                width,
                height,
            }
        })
        .collect()
}

fn psnr(a: &[[u8; 4]], b: &[[u8; 4]]) -> f64 {
    let mut se = 0f64;
    for (p, q) in a.iter().zip(b) {
        for k in 0..3 {
            let d = p[k] as f64 - q[k] as f64;
            se += d * d;
        }
    }
    let mse = se / (3 * a.len().max(1)) as f64;
    if mse == 0.0 {
        return 99.0;
    }
    10.0 * (255.0f64 * 255.0 / mse).log10()
}

/// `image` (`w`×`h`, twice the target) scaled down 2:1 in linear light.
pub(crate) fn half(image: &[[u8; 4]], w: usize, h: usize) -> Vec<[u8; 4]> {
    let (hw, hh) = (w / 2, h / 2);
    (0..hw * hh)
        .map(|i| {
            let (x, y) = (i % hw, i / hw);
            let mut acc = [0f32; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let c = image[(2 * y + dy) * w + 2 * x + dx];
                for k in 0..3 {
                    acc[k] += srgb_to_linear(c[k]) / 4.0;
                }
            }
            encode_rgba([acc[0], acc[1], acc[2], 1.0])
        })
        .collect()
}

/// One variant at one threshold: bytes over the path and mean PSNR.
struct Point {
    threshold: f32,
    bytes: u64,
    psnr: f64,
    triangles: u64,
}

/// Runs `bench normals`.
pub fn run(args: Args) -> Result<()> {
    let dir = std::env::temp_dir().join(format!("meshwiki-bench-normals-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let dir = TempDir(dir);
    let mut models = Vec::new();
    let builds: Vec<Option<f32>> = std::iter::once(None)
        .chain(args.densities.iter().map(|&t| Some(t)))
        .collect();
    for (k, &texel) in builds.iter().enumerate() {
        let out = dir.0.join(format!("normals-{k}.mwlod"));
        let t = Instant::now();
        let report = build(&args.scan, &out, texel)?;
        println!(
            "{}: built {} triangles in {:.1} s, {:.2} MB ({} normal maps, {:.2} MB)",
            texel.map_or("without normal maps".to_string(), |t| format!(
                "normal maps, {t} texels an edge"
            )),
            report.import.triangles,
            t.elapsed().as_secs_f64(),
            report.output_bytes as f64 / 1e6,
            report.normal_maps.maps,
            report.normal_maps.jpeg_bytes as f64 / 1e6,
        );
        models.push(RenderModel::open(&out).context("opening the built file")?);
    }
    let device = GpuDevice::new(AdapterChoice::Software).context("a software adapter")?;
    let renderer = Renderer::new(device, RendererOptions::default());
    let (w, h) = (args.size, args.size * 3 / 4);
    let path = cameras(&models[0], args.views, w, h);
    let options = RenderOptions {
        background: [0, 0, 0, 255],
        ..RenderOptions::default()
    };
    let mut references = Vec::new();
    for cam in &path {
        let big = Camera {
            width: 2 * w,
            height: 2 * h,
            ..*cam
        };
        let o = RenderOptions {
            cut: Cut::Uniform {
                max_error: 0.0,
                frustum: true,
            },
            ..options.clone()
        };
        let frame = renderer.render(&models[0], &big, &o, &[])?;
        let color = frame.color.context("a colour image")?;
        references.push(half(&color, 2 * w as usize, 2 * h as usize));
    }
    let save = |name: &str, pixels: &[[u8; 4]]| -> Result<()> {
        if let Some(out) = &args.out {
            std::fs::create_dir_all(out)?;
            let img = image::RgbaImage::from_raw(w, h, pixels.iter().flatten().copied().collect())
                .context("image size")?;
            img.save(out.join(format!("{name}.png")))?;
        }
        Ok(())
    };
    save("reference", &references[0])?;
    // Variants: (label, model, factor).
    let mut variants: Vec<(String, usize, f32)> = vec![("vertex normals".into(), 0, 1.0)];
    for (k, &texel) in args.densities.iter().enumerate() {
        for &f in &args.factors {
            let label = if f == 1.0 {
                format!("maps {texel}/edge")
            } else {
                format!("maps {texel}/edge, silhouette ×{f}")
            };
            variants.push((label, k + 1, f));
        }
    }
    println!(
        "\n{} views at {w}x{h} (reference: every leaf at {}x{}, scaled 2:1)",
        path.len(),
        2 * w,
        2 * h
    );
    println!(
        "{:<34} {:>6} {:>10} {:>9} {:>11}",
        "variant", "px", "MB", "PSNR dB", "triangles"
    );
    let mut curves: Vec<(String, Vec<Point>)> = Vec::new();
    for (label, m, factor) in &variants {
        let model = &models[*m];
        let nodes = model.lod().nodes();
        let silhouette = Silhouette::new(nodes, *factor);
        let mut points = Vec::new();
        for &threshold in &args.thresholds {
            let (mut bytes, mut sum, mut triangles) = (0u64, 0f64, 0u64);
            for (v, (cam, want)) in path.iter().zip(&references).enumerate() {
                let cut =
                    lod::cut_view_silhouette(nodes, cam, threshold, Culling::ALL, &silhouette);
                bytes += cut
                    .iter()
                    .map(|&n| nodes[n as usize].blob_len as u64)
                    .sum::<u64>();
                let o = RenderOptions {
                    cut: Cut::Nodes(cut),
                    ..options.clone()
                };
                let frame = renderer.render(model, cam, &o, &[])?;
                triangles += frame.stats.triangles;
                let color = frame.color.context("a colour image")?;
                if v == 0 {
                    save(
                        &format!("{}-{threshold}px", label.replace([' ', ',', '×'], "_")),
                        &color,
                    )?;
                }
                sum += psnr(&color, want);
            }
            let p = Point {
                threshold,
                bytes,
                psnr: sum / path.len() as f64,
                triangles,
            };
            println!(
                "{label:<34} {:>6.1} {:>10.3} {:>9.2} {:>11}",
                p.threshold,
                p.bytes as f64 / 1e6,
                p.psnr,
                p.triangles
            );
            points.push(p);
        }
        curves.push((label.clone(), points));
    }
    println!("\nbytes over the path to reach a mean PSNR (interpolated between thresholds):");
    let targets: Vec<f64> = if args.targets.is_empty() {
        curves[0]
            .1
            .iter()
            .map(|p| (p.psnr * 100.0).floor() / 100.0)
            .collect()
    } else {
        args.targets.clone()
    };
    for &target in &targets {
        let base = bytes_at(&curves[0].1, target);
        for (label, points) in &curves {
            match (bytes_at(points, target), base) {
                (Some(b), Some(base)) => println!(
                    "  {target:>5.1} dB  {label:<34} {:>8.3} MB  ({:.2}× vertex normals)",
                    b / 1e6,
                    b / base
                ),
                (Some(b), None) => println!("  {target:>5.1} dB  {label:<34} {:>8.3} MB", b / 1e6),
                (None, _) => println!("  {target:>5.1} dB  {label:<34}   not reached"),
            }
        }
    }
    Ok(())
}

/// Bytes at which the curve reaches `target` dB: interpolated between the thresholds around
/// it (PSNR falls as the threshold grows); the finest point's bytes where even the coarsest
/// reaches it; `None` where the finest does not.
fn bytes_at(points: &[Point], target: f64) -> Option<f64> {
    let mut sorted: Vec<&Point> = points.iter().collect();
    sorted.sort_by_key(|p| p.bytes);
    // From the fewest bytes up: the first point at or above the target.
    for (i, p) in sorted.iter().enumerate() {
        if p.psnr >= target {
            if i == 0 {
                return Some(p.bytes as f64);
            }
            let q = sorted[i - 1];
            let t = ((target - q.psnr) / (p.psnr - q.psnr)).clamp(0.0, 1.0);
            return Some(q.bytes as f64 + t * (p.bytes as f64 - q.bytes as f64));
        }
    }
    None
}
