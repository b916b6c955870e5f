//! `meshwiki import FILE --title T`: create a model and build its LOD hierarchy here, with a
//! progress bar and a summary. The build runs as a job of this process (visible, with its
//! progress, in the web UI of a server on the same data directory, and cancellable there or
//! with Ctrl-C); on any error the model is marked failed with the message, nothing else is
//! left, and the command exits non-zero.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, bail};
use clap::Args as ClapArgs;
use meshwiki::Settings;
use meshwiki::jobs::{JobEnd, JobProgress, Jobs, parse_size};
use meshwiki::store::Db;
use meshwiki::store::jobs::{self, JobKind, JobOptions, NewJob};
use meshwiki::store::models::NewModel;
use meshwiki::store::users::{self, Role, User};
use meshwiki::terminal::{Bar, check_input, print_summary};
use meshwiki_engine::lod::VertexOrder;
use meshwiki_engine::lod::segsimplify::Simplifier;

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
    #[arg(long, default_value_t = meshwiki_engine::lod::build::DEFAULT_MAX_PATCH_TRIANGLES)]
    pub max_patch_triangles: u32,
    /// Build threads (default: all cores).
    #[arg(long)]
    pub threads: Option<u32>,
    /// How the levels are simplified: `quadric` (edge collapses, the default) or `segments`
    /// (the mesh-segmentation paper's segment-driven vertex removal; `meshwiki-bench
    /// simplify` compares the two).
    #[arg(long)]
    pub simplifier: Option<Simplifier>,
    /// JPEG quality of a textured scan's atlases: the mean over each level's (default 85).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub texture_quality: Option<u8>,
    /// How far an atlas' JPEG quality moves with the density of surface and texture features
    /// of its patch (the TexMesh paper's ΔQ; 0: every atlas the same quality; default 10;
    /// `meshwiki-bench textures` compares them at equal bytes).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=100))]
    pub texture_spread: Option<u8>,
    /// Bake a normal map into every coarse patch (`meshwiki-bench normals` measures what
    /// they cost and bring).
    #[arg(long)]
    pub normal_maps: bool,
    /// How the model's vertices are numbered: `morton` (the default: by the Morton code of
    /// their positions, smaller files) or `source` (ids are the file's vertex indices).
    #[arg(long)]
    pub vertex_order: Option<VertexOrder>,
    /// Account that owns the model (default: the first admin).
    #[arg(long)]
    pub owner: Option<String>,
    /// Data directory.
    #[command(flatten)]
    pub data: DataDirArgs,
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

/// Runs `import`.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let bytes = check_input(&args.file).map_err(anyhow::Error::msg)?;
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
            simplifier: args.simplifier,
            texture_quality: args.texture_quality,
            texture_spread: args.texture_spread,
            normal_maps: args.normal_maps.then_some(true),
            vertex_order: args.vertex_order,
            ..JobOptions::default()
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
        JobEnd::Rendered(_) => bail!("the import ran an image repository job"),
    }
}
