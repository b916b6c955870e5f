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

/// An indexed triangle mesh in flat arrays (meshoptimizer style), vertices in the file's order
/// (a build numbers them by `lod::BuildOptions::vertex_order`).
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

/// The in-memory consumer of a textured scan: the mesh, the textures in the order handed over,
/// and every triangle's corner coordinates aligned with `mesh.indices`
/// ([`TexturedFace::NONE`] for triangles delivered without). It holds readers to the
/// [`MeshSink`] contract: a texture after the first triangle, or faces not one per triangle,
/// are refused.
#[derive(Debug, Default)]
pub struct TexturedMesh {
    pub mesh: Mesh,
    pub textures: Vec<SourceTexture>,
    pub faces: Vec<TexturedFace>,
}

impl MeshSink for TexturedMesh {
    fn begin(&mut self, info: &SourceInfo) -> Result<(), ImportError> {
        self.textures.clear();
        self.faces.clear();
        self.mesh.begin(info)
    }

    fn vertices(&mut self, batch: VertexBatch<'_>) -> Result<(), ImportError> {
        self.mesh.vertices(batch)
    }

    fn triangles(&mut self, triangles: &[[u32; 3]]) -> Result<(), ImportError> {
        self.faces
            .extend(std::iter::repeat_n(TexturedFace::NONE, triangles.len()));
        self.mesh.triangles(triangles)
    }

    fn texture(&mut self, texture: SourceTexture) -> Result<(), ImportError> {
        if !self.mesh.indices.is_empty() {
            return Err(ImportError::sink("a texture after the first triangle"));
        }
        self.textures.push(texture);
        Ok(())
    }

    fn textured_triangles(
        &mut self,
        triangles: &[[u32; 3]],
        faces: &[TexturedFace],
    ) -> Result<(), ImportError> {
        check_textured_faces(triangles, faces)?;
        self.faces.extend_from_slice(faces);
        self.mesh.triangles(triangles)
    }
}

/// A sink's check of [`MeshSink::textured_triangles`]: one texture face per triangle.
pub fn check_textured_faces(
    triangles: &[[u32; 3]],
    faces: &[TexturedFace],
) -> Result<(), ImportError> {
    if faces.len() == triangles.len() {
        return Ok(());
    }
    Err(ImportError::sink(format!(
        "{} texture faces for {} triangles",
        faces.len(),
        triangles.len()
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Texture;

    #[test]
    fn textured_mesh_keeps_faces_aligned_and_holds_readers_to_the_contract() {
        let texture = || SourceTexture {
            image: std::sync::Arc::new(Texture::from_texels(1, 1, vec![[9; 4]]).expect("1x1")),
            wrap_s: crate::mesh::Wrap::Clamp,
            wrap_t: crate::mesh::Wrap::Clamp,
        };
        let mut m = TexturedMesh::default();
        m.begin(&SourceInfo::default()).unwrap();
        m.texture(texture()).unwrap();
        m.vertices(VertexBatch {
            positions: &[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0; 3]],
            colors: None,
            normals: None,
        })
        .unwrap();
        let face = TexturedFace {
            uv: [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            texture: 0,
        };
        m.textured_triangles(&[[0, 1, 2]], &[face]).unwrap();
        m.triangles(&[[1, 3, 2]]).unwrap();
        assert_eq!(m.faces, vec![face, TexturedFace::NONE]);
        assert_eq!(m.mesh.triangle_count(), 2);
        // A texture after a triangle, or faces not one a triangle, are refused.
        assert!(m.texture(texture()).is_err());
        assert!(m.textured_triangles(&[[0, 1, 2]], &[]).is_err());
        assert_eq!(m.mesh.triangle_count(), 2);
        // A new stream starts afresh.
        m.begin(&SourceInfo::default()).unwrap();
        assert!(m.faces.is_empty() && m.textures.is_empty() && m.mesh.indices.is_empty());
    }
}
