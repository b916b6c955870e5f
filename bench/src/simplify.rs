//! `meshwiki-bench simplify`: the two simplifiers a build can use (issue 13, item 4) on real
//! scans, side by side — quadric edge collapses (meshoptimizer, the build's default) and the
//! mesh-segmentation paper's segment-driven vertex removal
//! ([`meshwiki_engine::lod::segsimplify`], §3.2–3.4). Both run on the whole welded scan with
//! its border locked (as a build locks a group's border) and are measured by the build's own
//! two-sided distance ([`simplification_distance`]: every removed vertex to the simplified
//! surface, every new triangle's centroid and new edges to the scan).
//!
//! Prints, per scan and triangle ratio: each method's distance at the same triangle count
//! (and the ratio of the two), and the triangles the segment method needs to come within the
//! quadric distance (found by bisection on its budget), with the verdict the figures support.
//! Figures are printed, never asserted.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args as ClapArgs;
use meshopt::{SimplifyOptions, SimplifyVertex, VertexDataAdapter};
use meshwiki_engine::lod::hausdorff::simplification_distance;
use meshwiki_engine::lod::segsimplify::{self, SegmentParams};

/// The scans measured when none is named (relative to the repository root).
const DEFAULT_SCANS: [&str; 3] = [
    "../shared/data/meshes/stanford_dragon_vrip_871k.ply",
    "../shared/data/meshes/igea_269k.ply",
    "../shared/data/meshes/stanford_armadillo_346k.ply",
];
/// Bisection steps for "triangles at equal distance".
const BISECTIONS: usize = 8;

/// Options of `bench simplify`.
#[derive(Debug, Clone, ClapArgs)]
pub struct Args {
    /// Scans to simplify (default: the dragon, Igea and the armadillo from `../shared/data`).
    pub scans: Vec<PathBuf>,
    /// Triangle ratios to simplify to.
    #[arg(long, value_delimiter = ',', default_values_t = [0.5, 0.25, 0.1, 0.03])]
    pub ratios: Vec<f64>,
    /// δ_Seg of the segment method, degrees (eq. 1).
    #[arg(long, default_value_t = SegmentParams::default().delta_seg_deg)]
    pub delta_seg: f32,
    /// δ_B of the segment method, degrees (eq. 2).
    #[arg(long, default_value_t = SegmentParams::default().delta_b_deg)]
    pub delta_b: f32,
    /// α of the segment method (eq. 8).
    #[arg(long, default_value_t = SegmentParams::default().alpha, allow_hyphen_values = true)]
    pub alpha: f32,
}

struct Scan {
    positions: Vec<[f32; 3]>,
    indices: Vec<u32>,
    locked: Vec<bool>,
    diagonal: f32,
}

fn load(path: &Path) -> Result<Scan> {
    let (mesh, _) =
        meshwiki_engine::mesh::load(path).with_context(|| format!("reading {}", path.display()))?;
    let positions = mesh.positions;
    let indices = mesh.indices;
    // The topological border (edges used once) is locked, as a build locks a group's.
    let mut uses: rustc_hash::FxHashMap<(u32, u32), u32> = Default::default();
    for t in indices.chunks_exact(3) {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut locked = vec![false; positions.len()];
    for ((a, b), n) in uses {
        if n != 2 {
            locked[a as usize] = true;
            locked[b as usize] = true;
        }
    }
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in &positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt();
    Ok(Scan {
        positions,
        indices,
        locked,
        diagonal,
    })
}

/// One simplification: triangles, distance, seconds.
struct Outcome {
    triangles: usize,
    distance: f32,
    seconds: f64,
}

fn measure(scan: &Scan, simplified: Vec<u32>, seconds: f64) -> Outcome {
    let mut kept = vec![false; scan.positions.len()];
    for &i in &simplified {
        kept[i as usize] = true;
    }
    let distance = simplification_distance(&scan.positions, &scan.indices, &simplified, &kept);
    Outcome {
        triangles: simplified.len() / 3,
        distance,
        seconds,
    }
}

fn quadric(scan: &Scan, target_triangles: usize) -> Result<Outcome> {
    let t = Instant::now();
    let adapter = VertexDataAdapter::new(bytemuck::cast_slice(&scan.positions), 12, 0)
        .context("vertex adapter")?;
    let locks: Vec<SimplifyVertex> = scan
        .locked
        .iter()
        .map(|&l| {
            if l {
                SimplifyVertex::Lock
            } else {
                SimplifyVertex::None
            }
        })
        .collect();
    let out = meshopt::simplify_with_locks(
        &scan.indices,
        &adapter,
        &locks,
        target_triangles * 3,
        f32::MAX,
        SimplifyOptions::ErrorAbsolute,
        None,
    );
    let seconds = t.elapsed().as_secs_f64();
    Ok(measure(scan, out, seconds))
}

fn segments(scan: &Scan, target_triangles: usize, params: &SegmentParams) -> Outcome {
    let t = Instant::now();
    let out = segsimplify::simplify(
        &scan.positions,
        &scan.indices,
        &scan.locked,
        target_triangles * 3,
        params,
    );
    let seconds = t.elapsed().as_secs_f64();
    measure(scan, out, seconds)
}

/// Runs the comparison.
pub fn run(args: Args) -> Result<()> {
    let scans: Vec<PathBuf> = if args.scans.is_empty() {
        DEFAULT_SCANS.iter().map(PathBuf::from).collect()
    } else {
        args.scans.clone()
    };
    if let Some(missing) = scans.iter().find(|p| !p.is_file()) {
        bail!(
            "no scan at {} (the defaults are in ../shared/data/meshes; name others as arguments)",
            missing.display()
        );
    }
    if args.ratios.iter().any(|r| !(*r > 0.0 && *r < 1.0)) {
        bail!("--ratios must lie strictly between 0 and 1");
    }
    let params = SegmentParams {
        delta_seg_deg: args.delta_seg,
        delta_b_deg: args.delta_b,
        alpha: args.alpha,
    };
    let delta_seg_ok = params.delta_seg_deg > 0.0 && params.delta_seg_deg <= 180.0;
    if !delta_seg_ok || !(0.0..=180.0).contains(&params.delta_b_deg) || !params.alpha.is_finite() {
        bail!("--delta-seg must be within (0, 180], --delta-b within [0, 180], --alpha finite");
    }
    println!(
        "bench simplify: quadric edge collapses (meshoptimizer, the build's default) against \
         segment-driven vertex removal (mesh-segmentation paper §3.2–3.4, δ_Seg {}°, δ_B {}°, \
         α {}); border locked; distance = the build's two-sided distance, in ‰ of the bounding \
         box diagonal",
        params.delta_seg_deg, params.delta_b_deg, params.alpha
    );
    let mut wins = [0usize; 2];
    let mut needs: Vec<f64> = Vec::new();
    for path in &scans {
        let scan = load(path)?;
        let n = scan.indices.len() / 3;
        println!(
            "{} ({} triangles)",
            path.file_name().map_or_else(
                || path.display().to_string(),
                |f| f.to_string_lossy().into_owned()
            ),
            n
        );
        println!(
            "  {:>6} {:>10} {:>10} {:>8} {:>10} {:>8} {:>7} {:>14} {:>7}",
            "ratio",
            "quadric",
            "q dist ‰",
            "q s",
            "segments",
            "s dist ‰",
            "s/q",
            "seg tris at q",
            "×"
        );
        let per_mille = |d: f32| d as f64 / scan.diagonal as f64 * 1e3;
        for &r in &args.ratios {
            let target = ((n as f64 * r) as usize).max(1);
            let q = quadric(&scan, target)?;
            let s = segments(&scan, q.triangles, &params);
            // The segment method's triangles to come within the quadric distance.
            let (mut lo, mut hi) = (s.triangles, n);
            if s.distance > q.distance {
                for _ in 0..BISECTIONS {
                    let mid = lo + (hi - lo) / 2;
                    if mid == lo {
                        break;
                    }
                    let m = segments(&scan, mid, &params);
                    if m.distance <= q.distance {
                        hi = m.triangles.max(mid);
                    } else {
                        lo = mid;
                    }
                }
            } else {
                hi = s.triangles;
            }
            let ratio = hi as f64 / q.triangles.max(1) as f64;
            needs.push(ratio);
            wins[usize::from(s.distance < q.distance)] += 1;
            println!(
                "  {:>6.3} {:>10} {:>10.3} {:>8.2} {:>10} {:>8.3} {:>7.2} {:>14} {:>7.2}",
                r,
                q.triangles,
                per_mille(q.distance),
                q.seconds,
                s.triangles,
                per_mille(s.distance),
                s.distance as f64 / q.distance.max(f32::MIN_POSITIVE) as f64,
                hi,
                ratio
            );
            tracing::info!(
                scan = %path.display(), ratio = r, quadric_s = q.seconds, segments_s = s.seconds,
                "simplified"
            );
        }
    }
    let geo = (needs.iter().map(|x| x.ln()).sum::<f64>() / needs.len().max(1) as f64).exp();
    println!(
        "verdict: at equal triangles the quadric distance is smaller in {} of {} cases; the \
         segment method needs {:.2}× the triangles for the same distance (geometric mean): \
         {} stays the build's default",
        wins[0],
        wins[0] + wins[1],
        geo,
        if wins[0] >= wins[1] {
            "quadric"
        } else {
            "segments (change the default!)"
        }
    );
    Ok(())
}
