//! Terminal output shared by the command line (`meshwiki import`) and the benches
//! (`meshwiki-bench build`): the build's progress bar, the check of an input scan, the
//! summary of a build, the log output.

use std::path::Path;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use meshwiki_engine::lod::BuildReport;
use meshwiki_engine::progress::Progress;

use crate::jobs::SCAN_EXTENSIONS;

/// Draws the engine's progress on a terminal bar.
pub struct Bar(pub ProgressBar);

impl Bar {
    /// A bar on standard error (hidden when it is not a terminal).
    pub fn new() -> Bar {
        let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr());
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} {msg:>20} [{bar:30}] {percent:>3}% {human_pos}/{human_len} ({elapsed})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        bar.enable_steady_tick(Duration::from_millis(200));
        Bar(bar)
    }
}

impl Default for Bar {
    fn default() -> Self {
        Bar::new()
    }
}

impl Progress for Bar {
    fn stage(&self, name: &str, total: u64) {
        self.0.set_length(total);
        self.0.set_position(0);
        self.0.set_message(name.to_string());
    }

    fn advance(&self, done: u64) {
        self.0.inc(done);
    }
}

/// Checks that `path` is a readable file of a known format.
pub fn check_input(path: &Path) -> Result<u64, String> {
    let meta =
        std::fs::metadata(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    if !meta.is_file() {
        return Err(format!("{} is not a file", path.display()));
    }
    if meshwiki_engine::mesh::Format::from_path(path).is_none() {
        return Err(format!(
            "{}: unknown file extension (expected {SCAN_EXTENSIONS})",
            path.display()
        ));
    }
    Ok(meta.len())
}

fn mb(bytes: u64) -> f64 {
    bytes as f64 / 1e6
}

/// Prints the summary of a build.
pub fn print_summary(report: &BuildReport) {
    let seconds = report.seconds;
    let i = &report.import;
    let attrs = match (i.has_colors, i.has_normals) {
        (true, true) => "colours, normals",
        (true, false) => "colours",
        (false, true) => "normals",
        (false, false) => "no colours or normals",
    };
    println!(
        "  input        {} triangles, {} vertices ({attrs}); {} degenerate faces skipped",
        i.triangles, i.vertices, i.degenerate_faces
    );
    println!(
        "  hierarchy    {} levels, {} nodes, {} groups, {} roots ({} triangles at the top)",
        report.levels, report.nodes, report.groups, report.roots, report.root_triangles
    );
    let stages: Vec<String> = report
        .stages
        .iter()
        .map(|(name, s)| format!("{name} {s:.2} s"))
        .collect();
    println!("  time         {seconds:.2} s ({})", stages.join(", "));
    println!(
        "  throughput   {:.0} input triangles/s",
        i.triangles as f64 / seconds.max(1e-9)
    );
    match report.peak_rss_bytes {
        Some(b) => println!("  peak memory  {:.0} MB", mb(b)),
        None => println!("  peak memory  unknown on this platform"),
    }
    println!(
        "  output       {:.2} MB ({:.2} bytes per input triangle)",
        mb(report.output_bytes),
        report.output_bytes as f64 / (i.triangles.max(1)) as f64
    );
    if let Some(t) = &report.textures {
        let all = t.featured.plus(&t.plain);
        println!(
            "  atlases      {} JPEGs, {:.2} MB for {:.1} M texels, quality {}–{} (mean {:.1}; \
             {} of them richer in features than their level's mean)",
            all.fragments,
            mb(all.image_bytes),
            all.covered_texels as f64 / 1e6,
            t.quality.0,
            t.quality.2,
            t.quality.1,
            t.featured.fragments
        );
    }
}

/// Logs to standard error, filtered by `MESHWIKI_LOG` (default `info`, quiet sqlx queries),
/// coloured only on a terminal.
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_env("MESHWIKI_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,sqlx::query=error"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
}
