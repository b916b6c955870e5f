//! `meshwiki-bench select`: the selection tools against human ground truth (issue 6; system
//! paper §4.1–4.2 for the tools, §4.3 for the measure: mis-selected vertices over the
//! region's vertices). Figures are printed, never asserted.
//!
//! On the Princeton segmentation benchmark ([`psb`], [`truth`]) it runs the real system: a
//! scratch data directory, every chosen OFF model imported by `meshwiki import` (the real
//! LOD pipeline), the real server started on an ephemeral port, an admin logged in over HTTP
//! ([`process`], [`client`]). For each region of each model's first human segmentation
//! ([`eval`]): a camera framing it (centroid, mean normal, extent; the most visible of a few
//! directions), its visible ground truth (the vertices a lasso over the whole view selects,
//! within the region) and its on-screen mask (the render API's id buffer); then simulated
//! users ([`strokes`]) draw a heavy lasso, a markup and a plain lasso with the same jitter,
//! each submitted to `POST /api/v1/models/{id}/selections`, the draft's vertices fetched and
//! compared. The exact on-screen mask, submitted as a lasso, is the reference (the floor of
//! back-projection). Prints, per tool, mean / p50 / p90 error and the POST's p50/p95 latency.

mod client;
mod eval;
mod process;
mod psb;
mod raster;
mod strokes;
mod suggested;
mod truth;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args as ClapArgs;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use meshwiki_engine::lod::VertexOrder;
use meshwiki_engine::lod::vertex_order::morton_order;
use serde_json::json;

use client::Api;
use eval::{RegionResult, Skip, TOOLS};
use process::Meshwiki;
use strokes::UserModel;

/// Default location of the benchmark, relative to the repository root.
const DEFAULT_PSB: &str = "../shared/data/psb";
/// Regions under this share of a model's vertices are left out.
const MIN_REGION_SHARE: f64 = 0.01;

/// Options of `bench select`.
#[derive(Debug, Clone, ClapArgs)]
pub struct Args {
    /// The benchmark: a folder with MeshsegBenchmark-1.0_data.tar.zst or off/ and seg/, or
    /// the archive itself.
    #[arg(long, default_value = DEFAULT_PSB)]
    pub psb: PathBuf,
    /// Models, spread over the categories.
    #[arg(long, default_value_t = 8)]
    pub models: usize,
    /// Amplitude of the strokes' smooth jitter, pixels.
    #[arg(long, default_value_t = 3.0)]
    pub jitter: f32,
    /// Width of the heavy lasso's band, pixels.
    #[arg(long, default_value_t = 12.0)]
    pub band: f32,
    /// Seed of the simulated users.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// View width, pixels.
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    /// View height, pixels.
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Write every figure here as JSON.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write a picture of every selection into this folder (region green, selection blue,
    /// strokes red/yellow/magenta).
    #[arg(long, value_name = "DIR")]
    pub dump: Option<PathBuf>,
    /// Instead of one protocol, sweep the stroke model ([`sweep`]: view sizes, bands,
    /// jitters, markup stroke counts, lengths and reach) and print every tool's worst setting.
    #[arg(long)]
    pub sweep: bool,
    /// Energy parameters (JSON, as the selections API's `params`) sent with the heavy lasso
    /// and markup, e.g. `{"w_seg": 3}`.
    #[arg(long, value_parser = parse_params)]
    pub params: Option<serde_json::Value>,
    /// With `--sweep`: only these settings (1-based, comma-separated).
    #[arg(long, value_delimiter = ',', requires = "sweep")]
    pub settings: Vec<usize>,
    /// How the models number their vertices (`meshwiki import --vertex-order`): `morton`,
    /// the default, or `source`; the ground truth follows.
    #[arg(long, default_value_t = VertexOrder::Morton)]
    pub vertex_order: VertexOrder,
}

/// One protocol: the view size and the simulated user.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Setting {
    pub width: u32,
    pub height: u32,
    pub user: UserModel,
}

/// The sweep over the stroke model (issue 13, item 5): views from 640×480 to 1920×1080,
/// heavy bands of 8–24 px, jitter of 2–6 px, 1–5 markup strokes a side, strokes that stop
/// short (a third of the default length) or run long, background strokes close to the region
/// or far from it. The default protocol is the third.
pub fn sweep() -> Vec<Setting> {
    /// (width, height, band, jitter, fg strokes, bg strokes, length, bg reach)
    type Row = (u32, u32, f32, f32, usize, usize, f32, f32);
    let table: [Row; 6] = [
        (640, 480, 8.0, 2.0, 1, 1, 0.5, 40.0),
        (960, 640, 16.0, 4.0, 2, 2, 1.0, 80.0),
        (1280, 720, 12.0, 3.0, 3, 6, 1.0, 80.0),
        (1920, 1080, 24.0, 6.0, 5, 5, 1.5, 160.0),
        (960, 640, 16.0, 4.0, 1, 3, 0.3, 120.0),
        (1280, 720, 20.0, 5.0, 2, 1, 0.6, 200.0),
    ];
    table
        .iter()
        .map(
            |&(width, height, band, jitter, fg, bg, length, reach)| Setting {
                width,
                height,
                user: UserModel {
                    fg_strokes: fg,
                    bg_strokes: bg,
                    stroke_length: length,
                    bg_reach: reach,
                    ..UserModel::new(jitter, band)
                },
            },
        )
        .collect()
}

fn parse_params(s: &str) -> std::result::Result<serde_json::Value, String> {
    let v: serde_json::Value = serde_json::from_str(s).map_err(|e| e.to_string())?;
    if !v.is_object() {
        return Err("a JSON object of energy parameters".into());
    }
    Ok(v)
}

/// Scratch directory removed on drop.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} {prefix:>8} [{bar:30}] {pos}/{len} {msg} ({elapsed})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_prefix(what.to_string());
    bar.enable_steady_tick(Duration::from_millis(200));
    bar
}

fn percentile(values: &[f64], p: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[(((v.len() - 1) as f64) * p).round() as usize]
}

fn mean(values: &[f64]) -> f64 {
    if values.is_empty() {
        f64::NAN
    } else {
        values.iter().sum::<f64>() / values.len() as f64
    }
}

fn check(args: &Args) -> Result<()> {
    if args.models == 0 {
        bail!("--models must be at least 1");
    }
    if !(0.0..=50.0).contains(&args.jitter) {
        bail!("--jitter must be within 0 to 50 pixels");
    }
    if !(2.0..=200.0).contains(&args.band) {
        bail!("--band must be within 2 to 200 pixels");
    }
    if !(64..=4096).contains(&args.width) || !(64..=4096).contains(&args.height) {
        bail!("--width and --height must be within 64 to 4096 pixels");
    }
    Ok(())
}

/// One imported model.
struct Model {
    psb_id: u32,
    model_id: i64,
    seg: truth::Segmentation,
    faces: usize,
}

/// Runs the benchmark (blocking: it drives subprocesses and HTTP).
pub fn run(args: Args) -> Result<()> {
    check(&args)?;
    let started = Instant::now();
    let data = psb::Psb::open(&args.psb)?;
    let ids = data.pick(args.models);
    if ids.len() < args.models {
        eprintln!(
            "note: only {} of the {} models asked for are in {} ({} available)",
            ids.len(),
            args.models,
            args.psb.display(),
            data.models_available()
        );
    }
    let exe = crate::meshwiki_binary()?;
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    let scratch = Scratch(std::env::temp_dir().join(format!(
        "meshwiki-bench-select-{}-{stamp}",
        std::process::id()
    )));
    let data_dir = scratch.0.join("data");
    std::fs::create_dir_all(&data_dir)
        .with_context(|| format!("creating {}", data_dir.display()))?;
    let mw = Meshwiki {
        exe,
        data_dir,
        log: scratch.0.join("meshwiki.log"),
    };
    if let Some(d) = &args.dump {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    let password = format!("bench-{:016x}", stamp as u64 ^ 0x5eed_5eed);
    mw.add_admin("bench", &password)?;

    // Imports, then the ground truth (numbered as the models are, which takes their grids).
    let files = data.files(&ids, &scratch.0.join("psb"))?;
    let imports = bar(ids.len() as u64, "import");
    let mut imported = Vec::new();
    for (&id, (off, seg)) in ids.iter().zip(&files) {
        let category = psb::category(id);
        imports.set_message(format!("{id} ({category})"));
        let t = Instant::now();
        let model_id = mw.import(off, &format!("PSB {id} ({category})"), args.vertex_order)?;
        tracing::info!(
            psb = id,
            model_id,
            seconds = t.elapsed().as_secs_f64(),
            "imported"
        );
        imported.push((id, model_id, off, seg));
        imports.inc(1);
    }
    imports.finish_and_clear();
    let import_s = started.elapsed().as_secs_f64();

    let running = mw.serve()?;
    let api = Api::login(&running.base, "bench", &password)?;
    let mut models = Vec::new();
    for (id, model_id, off, seg) in imported {
        let mesh = truth::read_off(off)?;
        // The model numbers its vertices in the Morton order of their points on its grid
        // (docs/FORMAT.md, "Vertex ids"; the engine's reader gives the positions): the ground
        // truth follows it.
        let mesh = match args.vertex_order {
            VertexOrder::Source => mesh,
            VertexOrder::Morton => {
                let (scan, _) = meshwiki_engine::mesh::load(off)
                    .with_context(|| format!("reading {}", off.display()))?;
                let grid = api.lod_grid(model_id)?;
                truth::renumbered(&mesh, &morton_order(&scan.positions, &grid))?
            }
        };
        let labels = truth::read_seg(seg, mesh.faces)?;
        let seg = truth::segment(&mesh, &labels, MIN_REGION_SHARE);
        tracing::info!(
            psb = id,
            faces = mesh.faces,
            regions = seg.regions.len(),
            "truth"
        );
        models.push(Model {
            psb_id: id,
            model_id,
            seg,
            faces: mesh.faces,
        });
    }
    tracing::info!(base = %running.base, "server started");
    let settings = if args.sweep {
        let all = sweep();
        if args.settings.is_empty() {
            all
        } else {
            let mut picked = Vec::new();
            for &k in &args.settings {
                match all.get(k.wrapping_sub(1)) {
                    Some(s) => picked.push(*s),
                    None => bail!("--settings: there are settings 1 to {}", all.len()),
                }
            }
            picked
        }
    } else {
        vec![Setting {
            width: args.width,
            height: args.height,
            user: UserModel::new(args.jitter, args.band),
        }]
    };
    let mut runs = Vec::new();
    let mut worst: Vec<Option<Worst>> = vec![None; TOOLS.len()];
    for (k, setting) in settings.iter().enumerate() {
        if args.sweep {
            println!("setting {} of {}", k + 1, settings.len());
        }
        let (results, skipped, eval_s) = evaluate(&args, &api, &mw, &models, setting)?;
        let summary = report(
            setting, args.seed, &models, &results, &skipped, import_s, eval_s,
        );
        for (t, (name, _)) in TOOLS.iter().enumerate() {
            let m = summary[*name]["mean_error"].as_f64().unwrap_or(f64::NAN);
            let figure = |key: &str| summary[*name][key].as_f64().unwrap_or(f64::NAN);
            let (p90, missed, extra) = (
                figure("p90_error"),
                figure("mean_missed"),
                figure("mean_extra"),
            );
            if worst[t].is_none_or(|w| m > w.mean) {
                worst[t] = Some(Worst {
                    setting: k,
                    mean: m,
                    p90,
                    missed,
                    extra,
                });
            }
        }
        runs.push(json!({
            "setting": setting,
            "summary": summary,
            "regions": results,
            "skipped": skipped.iter().map(|(m, s, why)| json!({"model": m, "segment": s, "why": why}))
                .collect::<Vec<_>>(),
            "seconds": {"evaluate": eval_s},
        }));
    }
    let suggested = suggested_regions(&api, &models)?;
    drop(running);
    if args.sweep {
        println!("worst setting per tool (by mean error):");
        for (t, (_, label)) in TOOLS.iter().enumerate() {
            if let Some(Worst {
                setting: k,
                mean: m,
                p90,
                missed,
                extra,
            }) = worst[t]
            {
                let s = &settings[k];
                println!(
                    "  {label:<20} setting {}: {}x{}, band {} px, jitter {} px, markup {}+{} \
                     strokes ×{} long, reach {} px: mean {:.2}% (missed {:.2}%, extra {:.2}%), \
                     p90 {:.2}%",
                    k + 1,
                    s.width,
                    s.height,
                    s.user.band,
                    s.user.jitter,
                    s.user.fg_strokes,
                    s.user.bg_strokes,
                    s.user.stroke_length,
                    s.user.bg_reach,
                    m * 100.0,
                    missed * 100.0,
                    extra * 100.0,
                    p90 * 100.0
                );
            }
        }
    }
    println!("  total time   {:.1} s", started.elapsed().as_secs_f64());
    if let Some(out) = &args.out {
        let doc = json!({
            "settings": {"psb": args.psb, "models": ids, "seed": args.seed,
                          "min_region_share": MIN_REGION_SHARE,
                          "min_pixels": eval::MIN_PIXELS},
            "runs": runs,
            "suggested_regions": suggested,
            "seconds": {"import": import_s, "total": started.elapsed().as_secs_f64()},
        });
        write_json(out, &doc)?;
        println!("  figures      {}", out.display());
    }
    Ok(())
}

/// Regions evaluated, regions skipped.
type Evaluated = (Vec<RegionResult>, Vec<(u32, u32, Skip)>, f64);

/// Every region of every model under one setting.
fn evaluate(
    args: &Args,
    api: &Api,
    mw: &Meshwiki,
    models: &[Model],
    setting: &Setting,
) -> Result<Evaluated> {
    let total: usize = models.iter().map(|m| m.seg.regions.len()).sum();
    let regions_bar = bar(total as u64, "select");
    let eval_started = Instant::now();
    let mut results: Vec<RegionResult> = Vec::new();
    let mut skipped = Vec::new();
    for m in models {
        for region in &m.seg.regions {
            regions_bar.set_message(format!(
                "{} ({}) segment {}",
                m.psb_id,
                psb::category(m.psb_id),
                region.segment
            ));
            let case = eval::Case {
                api,
                model_id: m.model_id,
                psb_id: m.psb_id,
                seg: &m.seg,
                region,
                width: setting.width,
                height: setting.height,
                user: setting.user,
                seed: args.seed,
                dump: args.dump.as_deref(),
                params: args.params.as_ref(),
            };
            let outcome = eval::region(&case).with_context(|| {
                format!(
                    "model {} segment {} (server log: {})",
                    m.psb_id,
                    region.segment,
                    process::log_tail(&mw.log)
                )
            })?;
            match outcome {
                Ok(r) => results.push(r),
                Err(s) => skipped.push((m.psb_id, region.segment, s)),
            }
            regions_bar.inc(1);
        }
    }
    regions_bar.finish_and_clear();
    Ok((results, skipped, eval_started.elapsed().as_secs_f64()))
}

/// The Segments tool on every region ([`suggested`]): prints, per scale around the
/// suggested one and for the best scale of each region, the error and clicks; returns the
/// figures as JSON.
fn suggested_regions(api: &Api, models: &[Model]) -> Result<serde_json::Value> {
    let total: usize = models.iter().map(|m| m.seg.regions.len()).sum();
    let regions_bar = bar(total as u64, "segments");
    let started = Instant::now();
    let mut results = Vec::new();
    for m in models {
        let (counts, scale) = api.segment_scales(m.model_id)?;
        for region in &m.seg.regions {
            regions_bar.set_message(format!("{} segment {}", m.psb_id, region.segment));
            results.push(suggested::region(
                api, m.model_id, m.psb_id, region, &counts, scale,
            )?);
            regions_bar.inc(1);
        }
    }
    regions_bar.finish_and_clear();
    println!(
        "suggested regions: {} regions, a click on every segment mostly inside the region \
         (the Segments tool); error = |clicked Δ region| / |region| over all its vertices, \
         hidden side included; {:.1} s",
        results.len(),
        started.elapsed().as_secs_f64()
    );
    println!(
        "  {:<18} {:>7} {:>9} {:>9} {:>9} {:>8} {:>10} {:>10}",
        "scale", "regions", "mean err", "p50 err", "p90 err", "clicks", "previews", "segments"
    );
    let row = |label: &str, picked: Vec<suggested::AtScale>| {
        let errors: Vec<f64> = picked.iter().map(|a| a.error).collect();
        let clicks: Vec<f64> = picked.iter().map(|a| a.clicks as f64).collect();
        let looked: Vec<f64> = picked.iter().map(|a| a.looked_at as f64).collect();
        let segments: Vec<f64> = picked.iter().map(|a| a.segments as f64).collect();
        println!(
            "  {label:<18} {:>7} {:>8.2}% {:>8.2}% {:>8.2}% {:>8.1} {:>10.1} {:>10.0}",
            picked.len(),
            mean(&errors) * 100.0,
            percentile(&errors, 0.5) * 100.0,
            percentile(&errors, 0.9) * 100.0,
            mean(&clicks),
            mean(&looked),
            mean(&segments)
        );
        json!({"regions": picked.len(), "mean_error": mean(&errors),
               "p50_error": percentile(&errors, 0.5), "p90_error": percentile(&errors, 0.9),
               "mean_clicks": mean(&clicks), "mean_previews": mean(&looked)})
    };
    let mut summary = serde_json::Map::new();
    for (k, offset) in suggested::OFFSETS.enumerate() {
        let label = match offset {
            0 => "suggested".to_string(),
            o => format!("suggested {o:+}"),
        };
        let picked: Vec<_> = results.iter().filter_map(|r| r.scales[k]).collect();
        summary.insert(label.clone(), row(&label, picked));
    }
    let best: Vec<_> = results.iter().filter_map(|r| r.best()).collect();
    summary.insert("best per region".into(), row("best per region", best));
    Ok(json!({"summary": summary, "regions": results}))
}

/// Writes `doc` to a temporary name beside `path`, then renames it.
fn write_json(path: &Path, doc: &serde_json::Value) -> Result<()> {
    let tmp = path.with_extension("json.tmp");
    let text = serde_json::to_string_pretty(doc)?;
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(())
}

/// Prints the figures; returns them as JSON.
/// A tool's worst setting of a sweep (by mean error) and its figures there.
#[derive(Debug, Clone, Copy)]
struct Worst {
    setting: usize,
    mean: f64,
    p90: f64,
    /// The mean error's two sides: visible truth left out, surface selected outside.
    missed: f64,
    extra: f64,
}

fn report(
    setting: &Setting,
    seed: u64,
    models: &[Model],
    results: &[RegionResult],
    skipped: &[(u32, u32, Skip)],
    import_s: f64,
    eval_s: f64,
) -> serde_json::Value {
    let names: Vec<String> = models
        .iter()
        .map(|m| {
            format!(
                "{} {} ({} faces)",
                psb::category(m.psb_id),
                m.psb_id,
                m.faces
            )
        })
        .collect();
    let tiny: usize = models.iter().map(|m| m.seg.tiny).sum();
    println!(
        "bench select: {} models, {} regions evaluated ({} barely visible, {} under {:.0} % of \
         the vertices left out); {}x{}, jitter {} px, heavy band {} px, markup {} + {} strokes \
         ×{} long within {} px, seed {}",
        models.len(),
        results.len(),
        skipped.len(),
        tiny,
        MIN_REGION_SHARE * 100.0,
        setting.width,
        setting.height,
        setting.user.jitter,
        setting.user.band,
        setting.user.fg_strokes,
        setting.user.bg_strokes,
        setting.user.stroke_length,
        setting.user.bg_reach,
        seed
    );
    println!("  models       {}", names.join(", "));
    println!(
        "  error = |selected Δ visible truth| / |visible truth| in vertices, those on the \
         segment boundary (in two regions) counted right either way; strict = counting them; \
         latency = POST /selections wall time"
    );
    println!(
        "  missed / extra = the mean error's two sides: visible truth left out, and surface \
         selected outside the region (both per |visible truth|); flooded = regions with more \
         extra surface than the region itself"
    );
    println!(
        "  {:<18} {:>7} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>8} {:>8} {:>12} {:>12}",
        "tool",
        "regions",
        "mean err",
        "p50 err",
        "p90 err",
        "strict",
        "missed",
        "extra",
        "flooded",
        "refused",
        "latency p50",
        "latency p95"
    );
    let mut summary = serde_json::Map::new();
    for (k, (name, label)) in TOOLS.iter().enumerate() {
        let errors: Vec<f64> = results.iter().map(|r| r.tools[k].error).collect();
        let strict: Vec<f64> = results.iter().map(|r| r.tools[k].strict_error).collect();
        let latency: Vec<f64> = results
            .iter()
            .flat_map(|r| r.tools[k].latency_ms.iter().copied())
            .collect();
        let refused = results
            .iter()
            .filter(|r| r.tools[k].refused.is_some())
            .count();
        let (m, p50, p90) = (
            mean(&errors),
            percentile(&errors, 0.5),
            percentile(&errors, 0.9),
        );
        let (l50, l95) = (percentile(&latency, 0.5), percentile(&latency, 0.95));
        // The error split into its two sides, per region's visible truth (as `error`).
        let share = |count: fn(&eval::ToolResult) -> u64| -> Vec<f64> {
            results
                .iter()
                .map(|r| count(&r.tools[k]) as f64 / r.visible_truth.max(1) as f64)
                .collect()
        };
        let (missed, extra) = (share(|t| t.false_negatives), share(|t| t.false_positives));
        let flooded = extra.iter().filter(|&&e| e > 1.0).count();
        println!(
            "  {:<18} {:>7} {:>8.2}% {:>8.2}% {:>8.2}% {:>8.2}% {:>7.2}% {:>7.2}% {:>8} {:>8} \
             {:>9.0} ms {:>9.0} ms",
            label,
            errors.len(),
            m * 100.0,
            p50 * 100.0,
            p90 * 100.0,
            mean(&strict) * 100.0,
            mean(&missed) * 100.0,
            mean(&extra) * 100.0,
            flooded,
            refused,
            l50,
            l95
        );
        summary.insert(
            name.to_string(),
            json!({"regions": errors.len(), "mean_error": m, "p50_error": p50, "p90_error": p90,
                   "mean_strict_error": mean(&strict), "mean_missed": mean(&missed),
                   "mean_extra": mean(&extra), "flooded": flooded, "refused": refused,
                   "latency_p50_ms": l50, "latency_p95_ms": l95}),
        );
    }
    // Where the server's time goes, per tool (p50 of each stage over every POST).
    let names: Vec<&str> = client::Stages::named(&client::Stages {
        render: 0.0,
        seeds: 0.0,
        graph: 0.0,
        maxflow: 0.0,
        backproject: 0.0,
        total: 0.0,
    })
    .iter()
    .map(|(n, _)| *n)
    .collect();
    print!("  {:<18}", "server p50, ms");
    for n in &names {
        print!(" {n:>10}");
    }
    println!();
    for (k, (name, label)) in TOOLS.iter().enumerate() {
        let stages: Vec<client::Stages> = results
            .iter()
            .flat_map(|r| r.tools[k].stages.iter().copied())
            .collect();
        print!("  {label:<18}");
        let mut per_stage = serde_json::Map::new();
        for (i, n) in names.iter().enumerate() {
            let v: Vec<f64> = stages.iter().map(|s| s.named()[i].1).collect();
            let p50 = percentile(&v, 0.5);
            print!(" {p50:>10.1}");
            per_stage.insert((*n).to_string(), json!(p50));
        }
        println!();
        if let Some(serde_json::Value::Object(o)) = summary.get_mut(*name) {
            o.insert("stages_p50_ms".into(), serde_json::Value::Object(per_stage));
        }
    }
    let wins = results
        .iter()
        .filter(|r| r.tools[0].error < r.tools[2].error)
        .count();
    let ties = results
        .iter()
        .filter(|r| r.tools[0].error == r.tools[2].error)
        .count();
    println!(
        "  heavy lasso better than lasso on {wins} of {} regions ({ties} ties)",
        results.len()
    );
    println!("  time         imports {import_s:.1} s, selections {eval_s:.1} s");
    summary.insert(
        "heavy_lasso_beats_lasso".into(),
        json!({"wins": wins, "ties": ties, "regions": results.len()}),
    );
    serde_json::Value::Object(summary)
}
