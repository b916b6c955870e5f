//! `meshwiki-bench build FILE`: builds the LOD hierarchy of a scan (or of `synth:N`, the
//! generated relief of about N triangles, written as PLY first and not timed) into a scratch
//! directory and prints throughput (input triangles/s), wall and CPU time, peak memory, output
//! bytes per input triangle and output size. Then, when Nexus' tools are found (`nexus.rs`),
//! `nxsbuild` and `nxscompress` run on the same input one after the other in the same run, and
//! the ratios are printed side by side; without them the fixed figures of an earlier
//! `nxsbuild` run on the same machine kind stand in, labelled as such.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args as ClapArgs;
use meshwiki::jobs::{Source, parse_size, run_build};
use meshwiki_engine::lod::{BuildOptions, VertexOrder};
use meshwiki_engine::mesh::write_relief_ply;

use meshwiki::terminal::{Bar, check_input, print_summary};

use crate::nexus;

/// Options of `bench build`.
#[derive(Debug, Clone, ClapArgs)]
pub struct Args {
    /// The scan, or `synth:N` for the generated relief of about N triangles.
    pub file: String,
    /// Memory budget of the build (e.g. 512M, 1G).
    #[arg(long, default_value = "1G", value_parser = parse_size)]
    pub memory: u64,
    /// Triangle budget of every patch.
    #[arg(long, default_value_t = meshwiki_engine::lod::build::DEFAULT_MAX_PATCH_TRIANGLES)]
    pub max_patch_triangles: u32,
    /// Build threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Keep the LOD file here (default: a scratch directory, removed afterwards).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// zstd level of the patch blobs (default: the build's; 0 stores them uncompressed).
    #[arg(long, value_parser = clap::value_parser!(i32).range(0..=22))]
    pub zstd_level: Option<i32>,
    /// Nexus' tools (the folder or the `nxsbuild` binary; default: `../shared/tools/nexus`).
    #[arg(long)]
    pub nexus: Option<PathBuf>,
    /// Do not run Nexus' builder (the fixed reference figures are printed instead).
    #[arg(long)]
    pub no_nexus: bool,
    /// How the build numbers the scan's vertices: `morton` (the product's default, by the
    /// Morton code of their positions) or `source` (as the file lists them), to measure what
    /// the order costs the format.
    #[arg(long, default_value_t = VertexOrder::Morton)]
    pub vertex_order: VertexOrder,
    /// Alternating rounds of both builds (meshwiki, nxsbuild, meshwiki, ...): with more than
    /// one, the ratios of every round and their median are printed as well, since other work
    /// on a shared machine moves either build's times by 10% or more from one run to the next.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=20))]
    pub rounds: u32,
}

/// One reference measurement of `nxsbuild`.
struct Reference {
    triangles: u64,
    seconds: (f64, f64),
    peak_bytes: f64,
    output_bytes: f64,
}

/// `nxsbuild` on the relief of `make_mesh.py --tris N`, on this machine kind.
const REFERENCES: [Reference; 2] = [
    Reference {
        triangles: 1_000_000,
        seconds: (19.0, 19.0),
        peak_bytes: 244e6,
        output_bytes: 5.6e6,
    },
    Reference {
        triangles: 5_000_000,
        seconds: (110.0, 125.0),
        peak_bytes: 719e6,
        output_bytes: 28.3e6,
    },
];

struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The fallback when nxsbuild does not run here: fixed figures from an earlier run.
fn compare_fixed(triangles: u64, seconds: f64, peak: Option<u64>, output: u64) {
    let Some(r) = REFERENCES.iter().min_by(|a, b| {
        let d = |x: &Reference| (x.triangles as f64 / triangles.max(1) as f64).ln().abs();
        d(a).total_cmp(&d(b))
    }) else {
        return;
    };
    let (lo, hi) = r.seconds;
    let time = if lo == hi {
        format!("{lo:.0} s")
    } else {
        format!("{lo:.0}–{hi:.0} s")
    };
    println!(
        "reference (FALLBACK: fixed figures of an earlier run, not measured now): nxsbuild on \
         the {:.0}M-triangle relief (make_mesh.py, same machine kind): {time}, {:.0} MB peak, \
         {:.1} MB .nxz",
        r.triangles as f64 / 1e6,
        r.peak_bytes / 1e6,
        r.output_bytes / 1e6
    );
    let scale = triangles as f64 / r.triangles as f64;
    if (scale - 1.0).abs() > 0.1 {
        println!(
            "  (this input has {triangles} triangles: throughput and bytes per triangle are \
             compared per triangle, memory as measured)"
        );
    }
    let ours = triangles as f64 / seconds.max(1e-9);
    let (fast, slow) = (r.triangles as f64 / lo, r.triangles as f64 / hi);
    if lo == hi {
        println!("  throughput   {:.2}× nxsbuild's", ours / fast);
    } else {
        println!(
            "  throughput   {:.2}× nxsbuild's ({:.2}–{:.2}× over its range)",
            ours / ((fast + slow) / 2.0),
            ours / fast,
            ours / slow
        );
    }
    if let Some(p) = peak {
        println!("  peak memory  {:.2}× nxsbuild's", p as f64 / r.peak_bytes);
    }
    let per_tri = output as f64 / triangles.max(1) as f64;
    println!(
        "  output size  {:.2}× the .nxz ({:.2} vs {:.2} bytes per triangle)",
        per_tri / (r.output_bytes / r.triangles as f64),
        per_tri,
        r.output_bytes / r.triangles as f64
    );
}

/// Runs `bench build`.
pub async fn run(args: Args) -> anyhow::Result<()> {
    tokio::task::spawn_blocking(move || bench(&args))
        .await
        .context("benchmark crashed")?
}

fn bench(args: &Args) -> anyhow::Result<()> {
    let dir = std::env::temp_dir().join(format!("meshwiki-bench-build-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let _scratch = Scratch(dir.clone());
    let input = match args.file.strip_prefix("synth:") {
        Some(n) => {
            let n: u64 =
                n.trim().replace('_', "").parse().with_context(|| {
                    format!("synth:N needs a triangle count, got {:?}", args.file)
                })?;
            let path = dir.join("relief.ply");
            let t = std::time::Instant::now();
            let (v, tris) = write_relief_ply(&path, n).context("cannot write the relief")?;
            eprintln!(
                "generated relief: {tris} triangles, {v} vertices in {:.1} s (not timed)",
                t.elapsed().as_secs_f64()
            );
            path
        }
        None => {
            let path = PathBuf::from(&args.file);
            check_input(&path).map_err(anyhow::Error::msg)?;
            path
        }
    };
    let source = input.clone();
    let output = match &args.out {
        Some(p) => p.clone(),
        None => dir.join("bench.mwlod"),
    };
    let options = BuildOptions {
        max_patch_triangles: args.max_patch_triangles as usize,
        memory_budget: args.memory.min(usize::MAX as u64) as usize,
        threads: args.threads,
        zstd_level: args
            .zstd_level
            .unwrap_or(BuildOptions::default().zstd_level),
        vertex_order: args.vertex_order,
        ..BuildOptions::default()
    };
    let bytes = std::fs::metadata(&source).map(|m| m.len()).unwrap_or(0);
    println!(
        "bench build: {}{} ({:.1} MB), memory budget {:.0} MB, {} threads",
        display(&source),
        match args.vertex_order {
            VertexOrder::Source => ", vertices in the file's order",
            VertexOrder::Morton => "",
        },
        bytes as f64 / 1e6,
        args.memory as f64 / 1e6,
        args.threads
            .map(|t| t.to_string())
            .unwrap_or_else(|| format!(
                "{}",
                std::thread::available_parallelism().map_or(1, |n| n.get())
            ))
    );
    if let Some(load) = load_average() {
        // Other work on the cores (a compile, a browser) slows the build 2x or more.
        println!(
            "  machine load (1-minute average) at start: {load:.2}{}",
            if load > 0.5 {
                " (other work on the cores now or just before: if it is still running, figures are not comparable)"
            } else {
                ""
            }
        );
    }
    let bar = Bar::new();
    let cpu_before = nexus::own_cpu_seconds();
    let report = run_build(&Source::File(input.clone()), &output, &options, &bar);
    let cpu = nexus::own_cpu_seconds() - cpu_before;
    bar.0.finish_and_clear();
    let report = match report {
        Ok(r) => r.report,
        Err(e) => bail!("build failed: {e}"),
    };
    print_summary(&report);
    if !report.segments.is_empty() {
        println!(
            "  segments     {} fine ({:.1} vertices each), {} scales",
            report.segments[0],
            report.import.vertices as f64 / report.segments[0].max(1) as f64,
            report.segments.len()
        );
    }
    println!(
        "  CPU time {cpu:.1} s for {:.1} s wall: {:.2} cores busy on average",
        report.seconds,
        cpu / report.seconds.max(1e-9)
    );
    let ours = Measured {
        wall: report.seconds,
        cpu,
        peak: report.peak_rss_bytes,
        output: report.output_bytes,
    };
    if let Err(e) = crate::build_bytes::print(&output, options.zstd_level) {
        println!("  (no breakdown of the format: {e:#})");
    }
    let tools = if args.no_nexus {
        None
    } else {
        nexus::locate(args.nexus.as_deref())
    };
    match tools {
        Some(tools) if nexus::reads(&input) => {
            println!(
                "\nnxsbuild + nxscompress ({}) on the same input, after meshwiki's build:",
                tools.display()
            );
            match nexus::run(&tools, &input, &dir) {
                Ok(nx) => {
                    side_by_side(&ours, &nx);
                    if args.rounds > 1 {
                        rounds(args, &input, &output, &options, &tools, &dir, (ours, nx))?;
                    }
                }
                Err(e) => {
                    println!("  nxsbuild did not run: {e:#}");
                    compare_fixed(
                        report.import.triangles,
                        report.seconds,
                        report.peak_rss_bytes,
                        report.output_bytes,
                    );
                }
            }
        }
        Some(_) => {
            println!("\nnxsbuild reads PLY, OBJ and STL only: not run on this input");
            compare_fixed(
                report.import.triangles,
                report.seconds,
                report.peak_rss_bytes,
                report.output_bytes,
            );
        }
        None => {
            if !args.no_nexus {
                println!(
                    "\nNexus' tools not found (../shared/tools/nexus/nxsbuild, or --nexus DIR)"
                );
            }
            compare_fixed(
                report.import.triangles,
                report.seconds,
                report.peak_rss_bytes,
                report.output_bytes,
            );
        }
    }
    if args.out.is_some() {
        println!("LOD file kept at {}", output.display());
    }
    Ok(())
}

/// Rounds 2.. of `--rounds`: each builds with meshwiki, then with nxsbuild (+ nxscompress), as
/// the first did; prints every round's times and ratios, then the medians.
fn rounds(
    args: &Args,
    input: &Path,
    output: &Path,
    options: &BuildOptions,
    tools: &Path,
    dir: &Path,
    first: (Measured, nexus::Run),
) -> anyhow::Result<()> {
    let mut all = vec![first];
    for _ in 1..args.rounds {
        let bar = Bar::new();
        bar.0
            .set_draw_target(indicatif::ProgressDrawTarget::hidden());
        let cpu_before = nexus::own_cpu_seconds();
        let report = run_build(&Source::File(input.to_path_buf()), output, options, &bar)
            .map_err(|e| anyhow::anyhow!("build failed: {e}"))?
            .report;
        let cpu = nexus::own_cpu_seconds() - cpu_before;
        let ours = Measured {
            wall: report.seconds,
            cpu,
            peak: report.peak_rss_bytes,
            output: report.output_bytes,
        };
        let nx = nexus::run(tools, input, dir)?;
        all.push((ours, nx));
    }
    println!(
        "\n{} alternating rounds (meshwiki, then nxsbuild + nxscompress):",
        all.len()
    );
    println!(
        "  {:<6} {:>14} {:>14} {:>11} {:>14} {:>14} {:>11}",
        "round", "nxs wall s", "ours wall s", "wall ratio", "nxs CPU s", "ours CPU s", "CPU ratio"
    );
    let mut ratios = (Vec::new(), Vec::new());
    for (i, (ours, nx)) in all.iter().enumerate() {
        let total = nx.total();
        let (w, c) = (
            total.wall / ours.wall.max(1e-9),
            total.cpu / ours.cpu.max(1e-9),
        );
        println!(
            "  {:<6} {:>14.1} {:>14.1} {:>10.2}× {:>14.1} {:>14.1} {:>10.2}×",
            i + 1,
            total.wall,
            ours.wall,
            w,
            total.cpu,
            ours.cpu,
            c
        );
        ratios.0.push(w);
        ratios.1.push(c);
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            (v[n / 2 - 1] + v[n / 2]) / 2.0
        }
    };
    println!(
        "  median ratio: wall {:.2}×, CPU {:.2}× (range {:.2}-{:.2}× and {:.2}-{:.2}×)",
        median(&mut ratios.0),
        median(&mut ratios.1),
        ratios.0[0],
        ratios.0[ratios.0.len() - 1],
        ratios.1[0],
        ratios.1[ratios.1.len() - 1]
    );
    Ok(())
}

/// meshwiki's build as measured in this run.
struct Measured {
    wall: f64,
    cpu: f64,
    peak: Option<u64>,
    output: u64,
}

/// Prints both builds of this run side by side, with ratios (how many times nxsbuild's cost
/// meshwiki's is: above 1 means meshwiki is ahead, for time, memory and size alike).
fn side_by_side(ours: &Measured, nx: &nexus::Run) {
    let total = nx.total();
    let mb = |b: u64| format!("{:.2} MB", b as f64 / 1e6);
    println!(
        "  {:<12} {:>22} {:>14} {:>10}",
        "", "nxsbuild (+ compress)", "meshwiki", "ratio"
    );
    let compress = |f: fn(&nexus::Cost) -> f64| {
        nx.compress
            .as_ref()
            .map(|c| format!(" (+{:.1})", f(c)))
            .unwrap_or_default()
    };
    println!(
        "  {:<12} {:>22} {:>14} {:>9.2}×",
        "wall s",
        format!("{:.1}{}", nx.build.wall, compress(|c| c.wall)),
        format!("{:.1}", ours.wall),
        total.wall / ours.wall.max(1e-9)
    );
    println!(
        "  {:<12} {:>22} {:>14} {:>9.2}×",
        "CPU s",
        format!("{:.1}{}", nx.build.cpu, compress(|c| c.cpu)),
        format!("{:.1}", ours.cpu),
        total.cpu / ours.cpu.max(1e-9)
    );
    if let Some(peak) = ours.peak {
        println!(
            "  {:<12} {:>22} {:>14} {:>9.2}×",
            "peak memory",
            mb(total.peak_bytes),
            mb(peak),
            total.peak_bytes as f64 / peak.max(1) as f64
        );
    }
    let (label, theirs) = match nx.nxz_bytes {
        Some(b) => (".nxz", b),
        None => (".nxs", nx.nxs_bytes),
    };
    println!(
        "  {:<12} {:>22} {:>14} {:>9.2}×",
        "output",
        format!("{} {label}", mb(theirs)),
        mb(ours.output),
        theirs as f64 / ours.output.max(1) as f64
    );
    println!(
        "  (ratios are nxsbuild's figure over meshwiki's: above 1 means meshwiki is ahead; \
         wall and CPU count nxscompress too)"
    );
}

fn display(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.display().to_string())
}

/// The 1-minute load average (Linux `/proc/loadavg`).
fn load_average() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    text.split_whitespace().next()?.parse().ok()
}
