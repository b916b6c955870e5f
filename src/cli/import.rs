//! `meshwiki import FILE --title T`: create a model and build its LOD hierarchy here, with a
//! progress bar and a summary. The build runs as a job of this process (visible, with its
//! progress, in the web UI of a server on the same data directory, and cancellable there or
//! with Ctrl-C); on any error the model is marked failed with the message, nothing else is
//! left, and the command exits non-zero.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, bail};
use clap::Args as ClapArgs;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use meshwiki::Settings;
use meshwiki::jobs::{JobEnd, JobProgress, Jobs, SCAN_EXTENSIONS, parse_size};
use meshwiki::store::Db;
use meshwiki::store::jobs::{self, JobKind, JobOptions, NewJob};
use meshwiki::store::models::NewModel;
use meshwiki::store::users::{self, Role, User};
use meshwiki_engine::lod::BuildReport;
use meshwiki_engine::progress::Progress;

use super::DataDirArgs;

/// Options of `import`.
#[derive(Debug, Clone, ClapArgs)]
pub struct Args {
    /// The scan (.ply, .obj, .gltf, .glb, .stl or .off).
    pub file: PathBuf,
    /// Title of the new model.
    #[arg(long)]
    pub title: String,
    /// Description (Markdown).
    #[arg(long, default_value = "")]
    pub description: String,
    /// Memory budget of the build (e.g. 512M, 1G).
    #[arg(long, env = "MESHWIKI_BUILD_MEMORY", default_value = "1G", value_parser = parse_size)]
    pub memory: u64,
    /// Triangle budget of every patch.
    #[arg(long, default_value_t = 4096)]
    pub max_patch_triangles: u32,
    /// Build threads (default: all cores).
    #[arg(long)]
    pub threads: Option<u32>,
    /// Account that owns the model (default: the first admin).
    #[arg(long)]
    pub owner: Option<String>,
    /// Data directory.
    #[command(flatten)]
    pub data: DataDirArgs,
}

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

/// The owner: `name`, or the first enabled admin.
pub async fn owner(db: &Db, name: Option<&str>) -> anyhow::Result<User> {
    if let Some(name) = name {
        return users::by_name(db, name)
            .await?
            .with_context(|| format!("no user named {name:?}"));
    }
    users::list(db, meshwiki::store::Page::all())
        .await?
        .into_iter()
        .filter(|u| u.role == Role::Admin && !u.disabled)
        .min_by_key(|u| u.id)
        .context(
            "no admin account to own the model: create one with \
             `meshwiki user add NAME --role admin` or pass --owner NAME",
        )
}

/// Checks that `path` is a readable file of a known format.
pub fn check_input(path: &Path) -> anyhow::Result<u64> {
    let meta =
        std::fs::metadata(path).with_context(|| format!("cannot read {}", path.display()))?;
    if !meta.is_file() {
        bail!("{} is not a file", path.display());
    }
    if meshwiki_engine::mesh::Format::from_path(path).is_none() {
        bail!(
            "{}: unknown file extension (expected {SCAN_EXTENSIONS})",
            path.display()
        );
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
}

/// Runs `import`.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let bytes = check_input(&args.file)?;
    let settings = Settings::new(&args.data.data_dir);
    settings.ensure_dirs().with_context(|| {
        format!(
            "cannot prepare data directory {}",
            settings.data_dir.display()
        )
    })?;
    let db = Db::open(&settings.db_path()).await?;
    let result = import(&db, settings, &args, bytes).await;
    db.close().await;
    result
}

async fn import(db: &Db, settings: Settings, args: &Args, bytes: u64) -> anyhow::Result<()> {
    let owner = owner(db, args.owner.as_deref()).await?;
    let source = std::fs::canonicalize(&args.file)
        .with_context(|| format!("cannot resolve {}", args.file.display()))?;
    let name = source
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let model = NewModel {
        title: args.title.clone(),
        description: args.description.clone(),
        source_name: name.clone(),
    };
    let job = NewJob {
        kind: JobKind::File,
        source_path: Some(source.to_string_lossy().into_owned()),
        source_name: name,
        source_bytes: bytes.min(i64::MAX as u64) as i64,
        options: JobOptions {
            memory_budget: Some(args.memory),
            max_patch_triangles: Some(args.max_patch_triangles),
            threads: args.threads,
            triangles: None,
        },
        running_pid: Some(std::process::id() as i64),
    };
    let (model, job) = jobs::create_with_model(db, &model, &job, owner.id).await?;
    eprintln!(
        "importing {} as model {} (job {})",
        args.file.display(),
        model.id,
        job.id
    );
    let bar = Bar::new();
    let handle = bar.0.clone();
    let progress = Arc::new(JobProgress::new(Some(Box::new(bar))));
    let on_signal = {
        let p = progress.clone();
        tokio::spawn(async move {
            if tokio::signal::ctrl_c().await.is_ok() {
                eprintln!("\ncancelling…");
                p.cancel();
            }
        })
    };
    let runner = Jobs::new(db.clone(), Arc::new(settings), None);
    let started = std::time::Instant::now();
    let end = runner.execute(job, progress).await;
    on_signal.abort();
    handle.finish_and_clear();
    match end {
        JobEnd::Done(report) => {
            println!(
                "imported {:?} as model {} ({})",
                model.title,
                model.id,
                meshwiki::jobs::lod_relative_path(model.id)
            );
            print_summary(&report);
            println!(
                "  total        {:.1} s with the thumbnail",
                started.elapsed().as_secs_f64()
            );
            Ok(())
        }
        JobEnd::Failed(msg) => bail!("import failed: {msg}"),
        JobEnd::Cancelled => bail!("import cancelled"),
        JobEnd::Requeued => bail!("import interrupted"),
    }
}
