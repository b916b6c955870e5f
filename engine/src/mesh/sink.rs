//! The streaming interface between readers and consumers, and the in-memory consumer.

use super::ImportError;
use super::texture::SourceTexture;

/// The texture of a triangle that has none ([`TexturedFace::texture`]).
pub const NO_TEXTURE: u32 = u32::MAX;

/// Where one triangle's corners lie in one of the scan's textures: `uv[k]` for corner `k`
/// (glTF convention, `v = 0` at the top), `texture` the index of a texture the reader handed
/// to [`MeshSink::texture`], or [`NO_TEXTURE`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TexturedFace {
    pub uv: [[f32; 2]; 3],
    pub texture: u32,
}

impl TexturedFace {
    pub const NONE: TexturedFace = TexturedFace {
        uv: [[0.0; 2]; 3],
        texture: NO_TEXTURE,
    };
}

/// What a reader knows before it streams the data (from a header, when the format has one).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SourceInfo {
    pub vertex_count: Option<u64>,
    pub triangle_count_hint: Option<u64>,
    pub has_colors: bool,
    pub has_normals: bool,
}

/// A run of consecutive vertices. Optional streams are present for every batch or for none,
/// as announced in [`SourceInfo`]. Normals need not be unit length; colours are sRGB RGBA.
#[derive(Debug, Clone, Copy)]
pub struct VertexBatch<'a> {
    pub positions: &'a [[f32; 3]],
    pub colors: Option<&'a [[u8; 4]]>,
    pub normals: Option<&'a [[f32; 3]]>,
}

/// Consumer of a streamed mesh. Readers call `begin` once, then `vertices` and `triangles`
/// in any interleaving where a triangle only names vertices already delivered.
/// Readers guarantee: positions are finite, indices are in range, no triangle repeats a vertex.
///
/// Textured scans: the reader hands over its textures after `begin` and before any triangle
/// (indices in call order from 0), then delivers every triangle through `textured_triangles`.
/// Sinks that keep no textures use the defaults: textures are dropped and triangles go to
/// `triangles` (the vertex colours carry the texture sampled at each vertex).
pub trait MeshSink {
    fn begin(&mut self, info: &SourceInfo) -> Result<(), ImportError>;
    fn vertices(&mut self, batch: VertexBatch<'_>) -> Result<(), ImportError>;
    fn triangles(&mut self, triangles: &[[u32; 3]]) -> Result<(), ImportError>;

    fn texture(&mut self, _texture: SourceTexture) -> Result<(), ImportError> {
        Ok(())
    }

    /// Triangles with their corners' texture coordinates (`faces[i]` belongs to
    /// `triangles[i]`).
    fn textured_triangles(
        &mut self,
        triangles: &[[u32; 3]],
        _faces: &[TexturedFace],
    ) -> Result<(), ImportError> {
        self.triangles(triangles)
    }
}

/// An indexed triangle mesh in flat arrays (meshoptimizer style). Vertex `i` has original ID `i`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    /// Empty when the source has no colour.
    pub colors: Vec<[u8; 4]>,
    /// Empty when the source has no normals.
    pub normals: Vec<[f32; 3]>,
    /// Three indices per triangle.
    pub indices: Vec<u32>,
}

impl Mesh {
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Streams this mesh into another sink (the LOD builder, a writer), in batches.
    pub fn stream_into(&self, sink: &mut dyn MeshSink) -> Result<(), ImportError> {
        sink.begin(&SourceInfo {
            vertex_count: Some(self.positions.len() as u64),
            triangle_count_hint: Some(self.triangle_count() as u64),
            has_colors: !self.colors.is_empty(),
            has_normals: !self.normals.is_empty(),
        })?;
        const BATCH: usize = 1 << 16;
        for start in (0..self.positions.len()).step_by(BATCH) {
            let end = (start + BATCH).min(self.positions.len());
            sink.vertices(VertexBatch {
                positions: &self.positions[start..end],
                colors: (!self.colors.is_empty()).then(|| &self.colors[start..end]),
                normals: (!self.normals.is_empty()).then(|| &self.normals[start..end]),
            })?;
        }
        let triangles: &[[u32; 3]] = bytemuck::cast_slice(&self.indices);
        for chunk in triangles.chunks(BATCH) {
            sink.triangles(chunk)?;
        }
        Ok(())
    }
}

impl MeshSink for Mesh {
    fn begin(&mut self, info: &SourceInfo) -> Result<(), ImportError> {
        *self = Mesh::default();
        if let Some(n) = info.vertex_count {
            // Only a hint: a lying header must not make us allocate terabytes.
            self.positions.reserve((n as usize).min(1 << 24));
        }
        Ok(())
    }

    fn vertices(&mut self, batch: VertexBatch<'_>) -> Result<(), ImportError> {
        self.positions.extend_from_slice(batch.positions);
        if let Some(c) = batch.colors {
            self.colors.extend_from_slice(c);
        }
        if let Some(n) = batch.normals {
            self.normals.extend_from_slice(n);
        }
        Ok(())
    }

    fn triangles(&mut self, triangles: &[[u32; 3]]) -> Result<(), ImportError> {
        self.indices.extend(triangles.iter().flatten());
        Ok(())
    }
}
