//! `meshwiki-bench maxflow`: the engine's Boykov–Kolmogorov solver on the reference
//! 8-connected grid instances of `../shared/data/maxflow`, against the flow values,
//! labellings and PyMaxflow timings stored with them. Each instance is solved through both
//! entry points: the grid graph (`grid` rows) and the general graph built from an edge list
//! (`graph` rows; making the edge list is not timed).
//!
//! Depends only on std, `anyhow` and the engine.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use meshwiki_engine::select::maxflow::Graph;
use meshwiki_engine::select::maxflow_grid::{GridEdges, GridGraph};

/// Default location of the instances, relative to the repository root.
const DEFAULT_DIR: &str = "../shared/data/maxflow";
const ARCHIVE: &str = "grid_default.tar.zst";
/// Runs per measurement; the minimum is reported (as for the reference times).
const RUNS: usize = 3;
/// Largest accepted relative difference from the reference flow value.
const FLOW_TOLERANCE: f64 = 1e-5;

/// Runs the benchmark. `dir` holds either the unpacked instances (`meta_*.json`, …) or
/// `grid_default.tar.zst`, or is the archive itself; default `../shared/data/maxflow`.
pub fn run(dir: Option<&Path>) -> Result<()> {
    let given = dir.map_or_else(|| PathBuf::from(DEFAULT_DIR), Path::to_path_buf);
    let mut unpacked = None;
    let data = if given.is_file() {
        unpacked.insert(Unpacked::new(&given)?).dir.clone()
    } else if has_instances(&given)? {
        given.clone()
    } else if given.join(ARCHIVE).is_file() {
        unpacked
            .insert(Unpacked::new(&given.join(ARCHIVE))?)
            .dir
            .clone()
    } else {
        bail!(
            "no max-flow instances in {} (expected meta_*.json or {ARCHIVE})",
            given.display()
        );
    };

    let mut names = instance_names(&data)?;
    names.sort_by_key(|n| (n.len(), n.clone()));
    if names.is_empty() {
        bail!("no meta_*.json in {}", data.display());
    }
    println!(
        "max-flow (Boykov–Kolmogorov, 8-connected grids), min of {RUNS} runs; \
         ref = PyMaxflow 1.3.2 from meta_*.json; speed-up = ref / ours"
    );
    println!(
        "{:<16} {:>9} {:>9} | {:>9} {:>9} {:>7} | {:>9} {:>9} {:>7} | {:>16} {:>9} | {:>9}",
        "instance",
        "nodes",
        "edges",
        "build ms",
        "ref ms",
        "speedup",
        "flow ms",
        "ref ms",
        "speedup",
        "flow",
        "rel diff",
        "px != ref"
    );
    let mut failures = Vec::new();
    for name in &names {
        let rows = bench_instance(&data, name).with_context(|| format!("instance {name}"))?;
        for r in rows {
            report(&r, &format!("{name} {}", r.solver), &mut failures);
        }
    }
    drop(unpacked);
    if !failures.is_empty() {
        bail!("{}", failures.join("; "));
    }
    Ok(())
}

/// Prints one row; records a failure if the flow or the cut is off.
fn report(r: &Report, name: &str, failures: &mut Vec<String>) {
    let rel = (r.flow - r.ref_flow) / r.ref_flow;
    println!(
        "{:<16} {:>9} {:>9} | {:>9.2} {:>9.2} {:>6.1}x | {:>9.2} {:>9.2} {:>6.1}x | {:>16.6} {:>9.1e} | {:>9}",
        name,
        r.nodes,
        r.edges,
        ms(r.build),
        r.ref_build * 1e3,
        r.ref_build / r.build.as_secs_f64(),
        ms(r.solve),
        r.ref_solve * 1e3,
        r.ref_solve / r.solve.as_secs_f64(),
        r.flow,
        rel,
        r.differ,
    );
    if rel.is_nan() || rel.abs() > FLOW_TOLERANCE {
        failures.push(format!(
            "{name}: flow {} differs from the reference {}",
            r.flow, r.ref_flow
        ));
    }
    if (r.cut - r.flow).abs() > FLOW_TOLERANCE * r.flow.abs().max(1.0) {
        failures.push(format!(
            "{name}: the labelling cuts {} but the flow is {}",
            r.cut, r.flow
        ));
    }
}

struct Report {
    solver: &'static str,
    nodes: usize,
    edges: usize,
    build: Duration,
    solve: Duration,
    flow: f64,
    cut: f64,
    differ: usize,
    ref_flow: f64,
    ref_build: f64,
    ref_solve: f64,
}

/// Reads one instance and solves it through the grid and the general entry points.
fn bench_instance(dir: &Path, name: &str) -> Result<Vec<Report>> {
    let meta_path = dir.join(format!("meta_{name}.json"));
    let meta = std::fs::read_to_string(&meta_path)
        .with_context(|| format!("reading {}", meta_path.display()))?;
    let w = json_number(&meta, "w")? as usize;
    let h = json_number(&meta, "h")? as usize;
    for (key, want) in [
        ("right", (0, 1)),
        ("down", (1, 0)),
        ("downright", (1, 1)),
        ("downleft", (1, -1)),
    ] {
        let got = json_pair(&meta, key)?;
        if got != want {
            bail!("edge {key} has offsets {got:?}, expected {want:?}");
        }
    }
    let read = |prefix: &str| read_f32(&dir.join(format!("{prefix}_{name}.f32")), w * h);
    let source = read("src")?;
    let sink = read("sink")?;
    let caps = [
        read("e_right")?,
        read("e_down")?,
        read("e_downright")?,
        read("e_downleft")?,
    ];
    let seg_path = dir.join(format!("seg_{name}.u8"));
    let reference =
        std::fs::read(&seg_path).with_context(|| format!("reading {}", seg_path.display()))?;
    if reference.len() != w * h {
        bail!(
            "{} has {} bytes, expected {}",
            seg_path.display(),
            reference.len(),
            w * h
        );
    }
    let edges = GridEdges {
        right: &caps[0],
        down: &caps[1],
        down_right: &caps[2],
        down_left: &caps[3],
    };

    let ref_flow = json_number(&meta, "flow")?;
    let ref_build = json_number(&meta, "graph_build_s_min")?;
    let ref_solve = json_number(&meta, "maxflow_s_min")?;
    // The reference files mark one side with 1; which one is read off the hard seeds
    // (PyMaxflow's get_grid_segments gives 1 for the sink side).
    let hard_source_ones = source
        .iter()
        .zip(&reference)
        .filter(|&(&s, &r)| s >= 1e9 && r == 1)
        .count();
    let hard_source = source.iter().filter(|&&s| s >= 1e9).count();
    let one_is_source = hard_source_ones * 2 > hard_source;
    let row = |solver, edges, (build, solve): (Duration, Duration), flow, labels: Vec<u8>| Report {
        solver,
        nodes: w * h,
        edges,
        build,
        solve,
        flow,
        cut: cut_value(w, h, &source, &sink, &caps, &labels),
        differ: labels
            .iter()
            .zip(&reference)
            .filter(|&(&ours, &r)| (ours == 1) != ((r == 1) == one_is_source))
            .count(),
        ref_flow,
        ref_build,
        ref_solve,
    };
    let mut rows = Vec::new();

    // Grid entry point.
    let (mut times, mut last) = ((Duration::MAX, Duration::MAX), None);
    for _ in 0..RUNS {
        let t = Instant::now();
        let mut g = GridGraph::symmetric(w, h, &source, &sink, &edges)?;
        times.0 = times.0.min(t.elapsed());
        let t = Instant::now();
        let flow = g.maxflow();
        times.1 = times.1.min(t.elapsed());
        last = Some((g, flow));
    }
    let Some((g, flow)) = last else {
        bail!("no run");
    };
    rows.push(row("grid", g.edge_count(), times, flow, g.labels()));
    drop(g);

    // General entry point, from the same edges as a list.
    let mut list = Vec::new();
    let mut list_caps = Vec::new();
    for r in 0..h {
        for c in 0..w {
            for (d, &(dr, dc)) in OFFSETS.iter().enumerate() {
                let (qr, qc) = (r + dr, c as isize + dc);
                if qr < h && qc >= 0 && (qc as usize) < w {
                    list.push([(r * w + c) as u32, (qr * w + qc as usize) as u32]);
                    list_caps.push(caps[d][r * w + c]);
                }
            }
        }
    }
    let (mut times, mut last) = ((Duration::MAX, Duration::MAX), None);
    for _ in 0..RUNS {
        let t = Instant::now();
        let mut g = Graph::from_edges(&source, &sink, &list, &list_caps, &list_caps)?;
        times.0 = times.0.min(t.elapsed());
        let t = Instant::now();
        let flow = g.maxflow();
        times.1 = times.1.min(t.elapsed());
        last = Some((g, flow));
    }
    let Some((g, flow)) = last else {
        bail!("no run");
    };
    rows.push(row("graph", g.edge_count(), times, flow, g.labels()));
    Ok(rows)
}

/// Forward neighbour offsets (row, column) in the order right, down, down-right, down-left.
const OFFSETS: [(usize, isize); 4] = [(0, 1), (1, 0), (1, 1), (1, -1)];

/// Capacity of the cut `labels` (1 = source side) in f64.
fn cut_value(
    w: usize,
    h: usize,
    source: &[f32],
    sink: &[f32],
    caps: &[Vec<f32>; 4],
    labels: &[u8],
) -> f64 {
    let mut cut = 0.0f64;
    for r in 0..h {
        for c in 0..w {
            let p = r * w + c;
            let lp = labels[p] == 1;
            cut += if lp { sink[p] } else { source[p] } as f64;
            for (d, &(dr, dc)) in OFFSETS.iter().enumerate() {
                let (qr, qc) = (r + dr, c as isize + dc);
                if qr >= h || qc < 0 || qc as usize >= w {
                    continue;
                }
                if lp != (labels[qr * w + qc as usize] == 1) {
                    cut += caps[d][p] as f64;
                }
            }
        }
    }
    cut
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn has_instances(dir: &Path) -> Result<bool> {
    Ok(dir.is_dir() && !instance_names(dir)?.is_empty())
}

/// `WxH` names of the `meta_WxH.json` files in `dir`.
fn instance_names(dir: &Path) -> Result<Vec<String>> {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let file = entry?.file_name();
        if let Some(name) = file
            .to_str()
            .and_then(|f| f.strip_prefix("meta_"))
            .and_then(|f| f.strip_suffix(".json"))
        {
            names.push(name.to_owned());
        }
    }
    Ok(names)
}

fn read_f32(path: &Path, count: usize) -> Result<Vec<f32>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    if bytes.len() != count * 4 {
        bail!(
            "{} has {} bytes, expected {}",
            path.display(),
            bytes.len(),
            count * 4
        );
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect())
}

/// The text right after `"key":` in a flat JSON document.
fn json_value<'a>(text: &'a str, key: &str) -> Result<&'a str> {
    let quoted = format!("\"{key}\"");
    let at = text
        .find(&quoted)
        .with_context(|| format!("meta has no \"{key}\""))?;
    let rest = text[at + quoted.len()..].trim_start();
    let rest = rest
        .strip_prefix(':')
        .with_context(|| format!("meta: no value for \"{key}\""))?;
    Ok(rest.trim_start())
}

fn json_number(text: &str, key: &str) -> Result<f64> {
    let rest = json_value(text, key)?;
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || "+-.eE".contains(c)))
        .unwrap_or(rest.len());
    rest[..end]
        .parse()
        .with_context(|| format!("meta: \"{key}\" is not a number"))
}

fn json_pair(text: &str, key: &str) -> Result<(i64, i64)> {
    let rest = json_value(text, key)?;
    let inner = rest
        .strip_prefix('[')
        .and_then(|r| r.split_once(']'))
        .map(|(inner, _)| inner)
        .with_context(|| format!("meta: \"{key}\" is not a pair"))?;
    let mut it = inner.split(',').map(|s| s.trim().parse::<i64>());
    match (it.next(), it.next(), it.next()) {
        (Some(Ok(a)), Some(Ok(b)), None) => Ok((a, b)),
        _ => bail!("meta: \"{key}\" is not a pair of integers"),
    }
}

/// Instances unpacked into a temporary directory, removed on drop.
struct Unpacked {
    dir: PathBuf,
}

impl Unpacked {
    fn new(archive: &Path) -> Result<Self> {
        let stamp = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let dir = std::env::temp_dir().join(format!(
            "meshwiki-bench-maxflow-{}-{stamp}",
            std::process::id()
        ));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let unpacked = Unpacked { dir };
        crate::untar::untar_zstd::<&str>(archive, &unpacked.dir, &[])?;
        Ok(unpacked)
    }
}

impl Drop for Unpacked {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}
