//! Scan import: streaming readers that push vertices and triangles into a [`MeshSink`].
//!
//! One reader per format: `ply` (ASCII and binary, memory-mapped), `obj` (+ MTL textures),
//! `gltf` (.gltf/.glb), `stl`, `off`. Readers never hold the whole scan unless the format
//! forces it (glTF buffers, the STL/glTF welding tables, OBJ's per-vertex first-corner table);
//! the LOD builder is a sink that spills to disk, so inputs larger than memory import fine.
//! Original vertex IDs are the order in which vertices reach the sink: for PLY, OBJ and OFF
//! that is the vertex's index in the input file; for glTF the welded vertex order; for STL
//! the order of first appearance after welding.
//!
//! Every reader validates what it reads (truncation, counts against the file size, NaN/inf,
//! index ranges, unsupported types) and reports an [`ImportError`] naming the file, the line or
//! byte offset and the problem; no input makes a reader panic. Progress is reported in bytes
//! (OBJ: twice the file size, two passes; glTF: accessor elements), and a cancelled
//! [`Progress`] ends the import with [`ImportErrorKind::Cancelled`].
//!
//! Also here: [`write_ply`]/[`PlyWriter`] (binary PLY output) and [`synth`] (the demo relief).

mod common;
mod error;
mod gltf;
mod obj;
mod off;
mod ply;
pub mod ply_write;
mod sink;
mod stl;
pub mod synth;
mod texture;

pub use error::{ImportError, ImportErrorKind, Location};
pub use ply_write::{PlyLayout, PlyWriter, write_ply};
pub use sink::{
    Mesh, MeshSink, NO_TEXTURE, SourceInfo, TexturedFace, TexturedMesh, VertexBatch,
    check_textured_faces,
};
pub use synth::{Relief, generate_relief, write_relief_ply};
pub use texture::{
    SourceTexture, Texture, Wrap, encode_rgba, is_webp, linear_to_srgb, srgb_to_linear,
};

use crate::progress::Progress;
use std::path::Path;

/// What an import saw, for summaries and job reports.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct ImportStats {
    /// Vertices delivered to the sink.
    pub vertices: u64,
    /// Triangles delivered to the sink (after triangulating polygons).
    pub triangles: u64,
    /// Triangles dropped because two of their corners were the same vertex (counted after
    /// fan-triangulation; faces with fewer than three corners count once). The turns that
    /// triangle strips encode as degenerate triangles are not counted.
    pub degenerate_faces: u64,
    /// Polygons with more than three corners that were fan-triangulated.
    pub polygons_triangulated: u64,
    /// Whether vertex colours (from the file or sampled from a texture) were delivered.
    pub has_colors: bool,
    /// Whether vertex normals from the file were delivered.
    pub has_normals: bool,
    /// Textures handed to the sink with the triangles' texture coordinates.
    pub textures: u32,
}

/// Input formats the importer understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Ply,
    Obj,
    Gltf,
    Glb,
    Stl,
    /// Object File Format (the Princeton segmentation benchmark uses it).
    Off,
}

impl Format {
    /// Guesses the format from the file extension (case-insensitive).
    pub fn from_path(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "ply" => Format::Ply,
            "obj" => Format::Obj,
            "gltf" => Format::Gltf,
            "glb" => Format::Glb,
            "stl" => Format::Stl,
            "off" => Format::Off,
            _ => return None,
        })
    }
}

/// Reads the scan at `path` (format from its extension) into `sink`.
pub fn import(
    path: &Path,
    sink: &mut dyn MeshSink,
    progress: &dyn Progress,
) -> Result<ImportStats, ImportError> {
    let format = Format::from_path(path).ok_or_else(|| {
        ImportError::new(
            path,
            Location::File,
            ImportErrorKind::Unsupported(
                "unknown file extension (expected .ply, .obj, .gltf, .glb, .stl or .off)".into(),
            ),
        )
    })?;
    import_as(path, format, sink, progress)
}

/// Reads the scan at `path` as `format` into `sink`.
pub fn import_as(
    path: &Path,
    format: Format,
    sink: &mut dyn MeshSink,
    progress: &dyn Progress,
) -> Result<ImportStats, ImportError> {
    let started = std::time::Instant::now();
    let stats = match format {
        Format::Ply => ply::read(path, sink, progress)?,
        Format::Obj => obj::read(path, sink, progress)?,
        Format::Gltf | Format::Glb => self::gltf::read(path, sink, progress)?,
        Format::Stl => stl::read(path, sink, progress)?,
        Format::Off => off::read(path, sink, progress)?,
    };
    let secs = started.elapsed().as_secs_f64();
    tracing::info!(
        path = %path.display(),
        vertices = stats.vertices,
        triangles = stats.triangles,
        degenerate = stats.degenerate_faces,
        seconds = secs,
        "imported {format:?}"
    );
    Ok(stats)
}

/// Reads a whole scan into memory. For tests, small models and tools; the LOD builder streams.
pub fn load(path: &Path) -> Result<(Mesh, ImportStats), ImportError> {
    let mut mesh = Mesh::default();
    let stats = import(path, &mut mesh, &crate::progress::NoProgress)?;
    Ok((mesh, stats))
}
