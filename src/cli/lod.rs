//! `meshwiki lod build|dump|cut`: developer tools for `.mwlod` files. `build` writes a LOD
//! file from a scan; `dump` prints the tables and decoded patches (the reference decoder) as
//! JSON, which the browser decoder's tests compare against; `cut` prints the view-dependent
//! cut (the engine's cut rule, `meshwiki_engine::lod::cut_view`) for a list of cameras, which
//! the browser's cut (`static/js/lod/cut.js`) is tested against.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::atlas::AtlasCodec;
use meshwiki_engine::lod::{self, BuildOptions, LodFile, VertexOrder};
use meshwiki_engine::mesh::Texture;
use meshwiki_engine::progress::NoProgress;
use serde::Deserialize;
use serde_json::json;

/// `lod` subcommands.
#[derive(Debug, Subcommand)]
pub enum LodCommand {
    /// Build a `.mwlod` file from a scan (PLY, OBJ, OFF, STL, glTF/GLB).
    Build(BuildArgs),
    /// Print a `.mwlod` file's header and decoded patches as JSON.
    Dump(DumpArgs),
    /// Print the view-dependent cut of a `.mwlod` file for each camera of a JSON list.
    Cut(CutArgs),
}

/// Arguments of `lod cut`.
#[derive(Debug, Args)]
pub struct CutArgs {
    /// The LOD file.
    pub file: PathBuf,
    /// JSON array of views: `{"eye", "target", "up", "fovy" (degrees), "width", "height",
    /// "pixel_error"}`.
    #[arg(long)]
    pub views: PathBuf,
}

/// One view of `lod cut`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CutView {
    eye: [f32; 3],
    target: [f32; 3],
    up: [f32; 3],
    fovy: f32,
    width: u32,
    height: u32,
    pixel_error: f32,
}

/// Arguments of `lod build`.
#[derive(Debug, Args)]
pub struct BuildArgs {
    /// The scan.
    pub input: PathBuf,
    /// The LOD file to write.
    pub output: PathBuf,
    /// Bake a normal map into every coarse patch.
    #[arg(long)]
    pub normal_maps: bool,
    /// How the vertices are numbered: `morton` (the default) or `source` (ids are the
    /// file's vertex indices).
    #[arg(long, default_value_t = VertexOrder::Morton)]
    pub vertex_order: VertexOrder,
    /// The colour atlases' image format (textured scans): `webp` (the default: at the error
    /// JPEG would have, where that takes fewer bytes) or `jpeg`.
    #[arg(long, default_value_t = AtlasCodec::default())]
    pub atlas_codec: AtlasCodec,
}

/// Arguments of `lod dump`.
#[derive(Debug, Args)]
pub struct DumpArgs {
    /// The LOD file.
    pub file: PathBuf,
    /// Comma-separated node ids to decode (default: every node).
    #[arg(long, value_delimiter = ',')]
    pub nodes: Vec<u32>,
    /// Write the JSON here instead of standard output.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Runs a `lod` subcommand.
pub fn run(command: LodCommand) -> anyhow::Result<()> {
    match command {
        LodCommand::Build(args) => {
            let report = lod::build_file(
                &args.input,
                &args.output,
                &BuildOptions {
                    normal_maps: args.normal_maps,
                    vertex_order: args.vertex_order,
                    atlas_codec: args.atlas_codec,
                    ..BuildOptions::default()
                },
                &NoProgress,
            )
            .with_context(|| format!("cannot build {}", args.input.display()))?;
            println!(
                "{}: {} nodes, {} levels, {} bytes",
                args.output.display(),
                report.nodes,
                report.levels,
                report.output_bytes
            );
            Ok(())
        }
        LodCommand::Dump(args) => dump(args),
        LodCommand::Cut(args) => cut(args),
    }
}

/// Prints `[[node, …], …]`: the cut of each view (frustum and back-face culling on), in node
/// order.
fn cut(args: CutArgs) -> anyhow::Result<()> {
    let file = LodFile::open(&args.file)
        .with_context(|| format!("cannot open {}", args.file.display()))?;
    let text = std::fs::read_to_string(&args.views)
        .with_context(|| format!("cannot read {}", args.views.display()))?;
    let views: Vec<CutView> = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a JSON array of views", args.views.display()))?;
    let mut cuts = Vec::with_capacity(views.len());
    for (k, v) in views.iter().enumerate() {
        let camera = Camera {
            eye: Vec3::from(v.eye),
            target: Vec3::from(v.target),
            up: Vec3::from(v.up),
            fovy_deg: v.fovy,
            width: v.width,
            height: v.height,
        };
        camera
            .validate()
            .with_context(|| format!("view {k} is not a valid camera"))?;
        if !(v.pixel_error.is_finite() && v.pixel_error > 0.0) {
            anyhow::bail!("view {k}: pixel_error must be a positive number");
        }
        cuts.push(lod::cut_view(
            file.nodes(),
            &camera,
            v.pixel_error,
            lod::Culling::ALL,
        ));
    }
    println!("{}", serde_json::to_string(&cuts)?);
    Ok(())
}

fn dump(args: DumpArgs) -> anyhow::Result<()> {
    let file = LodFile::open(&args.file)
        .with_context(|| format!("cannot open {}", args.file.display()))?;
    let header = file.header();
    let nodes: Vec<u32> = if args.nodes.is_empty() {
        (0..header.node_count).collect()
    } else {
        args.nodes.clone()
    };
    let mut patches = Vec::with_capacity(nodes.len());
    for id in nodes {
        let patch = file.patch(id)?;
        let record = file.node(id)?;
        patches.push(json!({
            "node": id,
            "offset": record.blob_offset,
            "length": record.blob_len,
            "original_ids": patch.original_ids,
            "grid_positions": patch.grid_positions,
            "positions": patch.positions,
            "indices": patch.indices,
            "colors": patch.colors,
            "normals": patch.normals,
            // Textured models: coordinates per vertex, and the atlas image's size and CRC-32.
            "uvs": patch.uvs,
            "image_length": patch.image.as_ref().map(|i| i.len()),
            "image_crc32": patch.image.as_ref().map(|i| crc32fast::hash(i)),
            // The image's size as the engine's decoder reads it (null where it does not).
            "image_size": patch
                .image
                .as_ref()
                .and_then(|i| Texture::decode(i).ok())
                .map(|t| [t.width(), t.height()]),
            "normal_map_length": patch.normal_map.as_ref().map(|i| i.len()),
            "normal_map_crc32": patch.normal_map.as_ref().map(|i| crc32fast::hash(i)),
        }));
    }
    let grid = file.grid();
    let out = json!({
        "node_count": header.node_count,
        "group_count": header.group_count,
        "grid": {"origin": grid.origin, "step": grid.step},
        "has_colors": file.has_colors(),
        "has_normals": file.has_normals(),
        "has_texture": file.has_texture(),
        "has_normal_maps": file.has_normal_maps(),
        "vertex_order": file.vertex_order().as_str(),
        "patches": patches,
    });
    let text = serde_json::to_string(&out)?;
    match args.out {
        Some(path) => std::fs::write(&path, text)
            .with_context(|| format!("cannot write {}", path.display()))?,
        None => {
            let mut stdout = std::io::stdout().lock();
            stdout.write_all(text.as_bytes())?;
            stdout.write_all(b"\n")?;
        }
    }
    Ok(())
}
