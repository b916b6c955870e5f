//! `meshwiki export-cut MODEL --max-error E --out FILE` and
//! `meshwiki export-cut MODEL --camera eye,target,up,fovy_deg,width,height --pixel-error P
//! --out FILE`: the mesh of one cut through a model's hierarchy, welded by original vertex ID
//! (`meshwiki_engine::lod::export_cut`), as binary PLY with each vertex's original ID in a
//! `uint original_id` property (its index in the input file for PLY/OBJ/OFF scans).
//!
//! `MODEL` is a model id in the data directory or the path of a `.mwlod` file.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args as ClapArgs;
use glam::Vec3;
use meshwiki::Settings;
use meshwiki::store::Db;
use meshwiki::store::models::{self, ModelStatus};
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::{Culling, LodFile, cut_uniform, cut_view, export_cut};
use meshwiki_engine::mesh::write_ply;

use super::DataDirArgs;

/// Options of `export-cut`.
#[derive(Debug, Clone, ClapArgs)]
#[command(group(clap::ArgGroup::new("cut").required(true).args(["max_error", "camera"])))]
pub struct Args {
    /// Model id, or the path of a `.mwlod` file.
    pub model: String,
    /// Uniform cut: every patch within this object-space error of the scan (0: full
    /// resolution).
    #[arg(long)]
    pub max_error: Option<f32>,
    /// View-dependent cut for this camera: `ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy_deg,width,height`
    /// (eye, target, up, vertical field of view in degrees, image size in pixels).
    #[arg(long, allow_hyphen_values = true)]
    pub camera: Option<String>,
    /// Largest projected error of the view-dependent cut, in pixels.
    #[arg(long, default_value_t = 1.0)]
    pub pixel_error: f32,
    /// Keep patches outside the view frustum or facing away (view-dependent cut).
    #[arg(long)]
    pub no_culling: bool,
    /// The PLY file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Data directory (for a model id).
    #[command(flatten)]
    pub data: DataDirArgs,
}

/// Parses `ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy_deg,width,height`.
pub fn parse_camera(s: &str) -> anyhow::Result<Camera> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 12 {
        bail!(
            "--camera needs 12 comma-separated numbers (eye x,y,z, target x,y,z, up x,y,z, \
             fovy_deg, width, height), got {}",
            parts.len()
        );
    }
    let mut f = [0f32; 10];
    for (k, v) in parts[..10].iter().enumerate() {
        f[k] = v
            .parse()
            .with_context(|| format!("--camera value {v:?} is not a number"))?;
    }
    let size = |v: &str| -> anyhow::Result<u32> {
        v.parse()
            .with_context(|| format!("--camera image size {v:?} is not a positive integer"))
    };
    let camera = Camera {
        eye: Vec3::new(f[0], f[1], f[2]),
        target: Vec3::new(f[3], f[4], f[5]),
        up: Vec3::new(f[6], f[7], f[8]),
        fovy_deg: f[9],
        width: size(parts[10])?,
        height: size(parts[11])?,
    };
    camera.validate().context("invalid --camera")?;
    Ok(camera)
}

/// The LOD file of `model`: a ready model's file in the data directory, or a path.
async fn lod_path(args: &Args) -> anyhow::Result<PathBuf> {
    let Ok(id) = args.model.trim().parse::<i64>() else {
        let path = PathBuf::from(&args.model);
        if !path.is_file() {
            bail!("{} is neither a model id nor a .mwlod file", args.model);
        }
        return Ok(path);
    };
    let settings = Settings::new(&args.data.data_dir);
    if !settings.db_path().is_file() {
        bail!(
            "no database in {} (pass --data-dir)",
            settings.data_dir.display()
        );
    }
    let db = Db::open(&settings.db_path()).await?;
    let model = models::get(&db, id).await;
    db.close().await;
    let model = model.with_context(|| format!("model {id}"))?;
    if model.status != ModelStatus::Ready {
        bail!(
            "model {id} is {}{}: only ready models can be exported",
            model.status.as_str(),
            model
                .error
                .as_deref()
                .map(|e| format!(" ({e})"))
                .unwrap_or_default()
        );
    }
    let rel = model
        .lod_path
        .with_context(|| format!("model {id} has no LOD file"))?;
    Ok(settings.data_dir.join(rel))
}

/// Runs `export-cut`.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let camera = args.camera.as_deref().map(parse_camera).transpose()?;
    if let Some(e) = args.max_error
        && !(e.is_finite() && e >= 0.0)
    {
        bail!("--max-error must be a finite number >= 0, got {e}");
    }
    if !(args.pixel_error.is_finite() && args.pixel_error >= 0.0) {
        bail!(
            "--pixel-error must be a finite number >= 0, got {}",
            args.pixel_error
        );
    }
    let path = lod_path(&args).await?;
    let out = args.out.clone();
    let (max_error, pixel_error, no_culling) = (args.max_error, args.pixel_error, args.no_culling);
    let summary = tokio::task::spawn_blocking(move || -> anyhow::Result<String> {
        let lod =
            LodFile::open(&path).with_context(|| format!("cannot open {}", path.display()))?;
        let (nodes, what) = match (max_error, camera) {
            (Some(e), _) => (
                cut_uniform(lod.nodes(), e),
                format!("uniform cut at error {e}"),
            ),
            (None, Some(cam)) => {
                let culling = if no_culling {
                    Culling::NONE
                } else {
                    Culling::ALL
                };
                (
                    cut_view(lod.nodes(), &cam, pixel_error, culling),
                    format!("view-dependent cut at {pixel_error} px"),
                )
            }
            (None, None) => bail!("give --max-error or --camera"),
        };
        let mesh = export_cut(&lod, &nodes).context("cannot read the cut's patches")?;
        write_ply(
            &out,
            &mesh.positions,
            lod.has_colors().then_some(&mesh.colors[..]),
            Some(&mesh.normals),
            &mesh.indices,
            Some(("original_id", &mesh.original_ids)),
        )
        .with_context(|| format!("cannot write {}", out.display()))?;
        Ok(format!(
            "wrote {} triangles, {} vertices from {} patches ({what}) to {}",
            mesh.triangle_count(),
            mesh.vertex_count(),
            mesh.nodes,
            out.display()
        ))
    })
    .await
    .context("export crashed")??;
    println!("{summary}");
    Ok(())
}
