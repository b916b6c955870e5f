//! First build pass: a [`MeshSink`] that takes the streamed scan apart into flat vertex arrays
//! (spilling to disk beyond the memory budget), a face file and, for a textured scan, a file of
//! the faces' texture coordinates in the same order, accumulating what later passes
//! need: bounds, a reservoir sample of positions for the spatial split, area-weighted vertex
//! normals when the scan has none, and the mean edge length for the quantisation step.

use super::spill::SpillVec;
use crate::mesh::{
    ImportError, MeshSink, SourceInfo, SourceTexture, TexturedFace, VertexBatch,
    check_textured_faces,
};
use glam::Vec3;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Positions kept for the spatial split.
const SAMPLE_SIZE: usize = 1 << 18;

/// Everything the ingest pass collected.
pub struct Ingested {
    pub positions: SpillVec<[f32; 3]>,
    pub colors: Option<SpillVec<[u8; 4]>>,
    /// Unit normals (from the scan, or computed here).
    pub normals: SpillVec<[f32; 3]>,
    pub faces_path: PathBuf,
    pub triangle_count: u64,
    /// The scan's textures, and a file of every face's texture coordinates
    /// ([`TexturedFace`] records in face order), when the reader handed over textures: read
    /// once, in order, by the partition, never held in memory (28 bytes a face).
    pub textures: Vec<SourceTexture>,
    pub face_uvs_path: Option<PathBuf>,
    pub bbox: (Vec3, Vec3),
    pub sample: Vec<[f32; 3]>,
    pub mean_edge: f64,
}

/// The ingest sink. Create with [`Ingest::new`], feed it, then [`Ingest::finish`].
pub struct Ingest {
    positions: SpillVec<[f32; 3]>,
    colors: Option<SpillVec<[u8; 4]>>,
    normals: SpillVec<[f32; 3]>,
    normals_from_input: bool,
    faces: BufWriter<File>,
    faces_path: PathBuf,
    textures: Vec<SourceTexture>,
    face_uvs: Option<BufWriter<File>>,
    memory_limit: usize,
    triangle_count: u64,
    lo: Vec3,
    hi: Vec3,
    sample: Vec<[f32; 3]>,
    seen: u64,
    rng: u64,
    edge_sum: f64,
    edge_count: u64,
    /// Triangles since the spilled arrays last gave their pages back.
    since_release: u64,
}

/// Spilled arrays hand their resident pages back after this many triangles.
const RELEASE_EVERY: u64 = 1 << 21;

impl Ingest {
    /// Arrays stay in memory up to `memory_limit` bytes each, then spill into `dir`.
    pub fn new(dir: &Path, memory_limit: usize) -> std::io::Result<Ingest> {
        let faces_path = dir.join("faces.bin");
        Ok(Ingest {
            positions: SpillVec::new(dir.join("positions.bin"), memory_limit),
            colors: None,
            normals: SpillVec::new(dir.join("normals.bin"), memory_limit),
            normals_from_input: false,
            faces: BufWriter::with_capacity(1 << 20, File::create(&faces_path)?),
            faces_path,
            textures: Vec::new(),
            face_uvs: None,
            memory_limit,
            triangle_count: 0,
            lo: Vec3::splat(f32::MAX),
            hi: Vec3::splat(f32::MIN),
            sample: Vec::with_capacity(SAMPLE_SIZE),
            seen: 0,
            rng: 0x9E37_79B9_7F4A_7C15,
            edge_sum: 0.0,
            edge_count: 0,
            since_release: 0,
        })
    }

    fn uvs_path(&self) -> PathBuf {
        self.faces_path.with_file_name("face_uvs.bin")
    }

    fn next_random(&mut self) -> u64 {
        // xorshift64*: deterministic, so builds are reproducible.
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        self.rng.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Normalises the normals and closes the face file.
    pub fn finish(mut self) -> std::io::Result<Ingested> {
        self.faces.flush()?;
        if let Some(uvs) = self.face_uvs.as_mut() {
            uvs.flush()?;
        }
        if !self.normals_from_input {
            for n in self.normals.as_mut_slice() {
                let v = Vec3::from(*n);
                let len = v.length();
                *n = if len > 0.0 {
                    (v / len).into()
                } else {
                    [0.0, 0.0, 1.0]
                };
            }
        }
        let bbox = if self.positions.is_empty() {
            (Vec3::ZERO, Vec3::ZERO)
        } else {
            (self.lo, self.hi)
        };
        let face_uvs_path = self.face_uvs.is_some().then(|| self.uvs_path());
        Ok(Ingested {
            positions: self.positions,
            colors: self.colors,
            normals: self.normals,
            faces_path: self.faces_path,
            triangle_count: self.triangle_count,
            face_uvs_path,
            textures: self.textures,
            bbox,
            sample: self.sample,
            mean_edge: if self.edge_count > 0 {
                self.edge_sum / self.edge_count as f64
            } else {
                0.0
            },
        })
    }
}

fn io_error(e: std::io::Error) -> ImportError {
    ImportError::sink(format!("scratch storage failed: {e}"))
}

impl MeshSink for Ingest {
    fn begin(&mut self, info: &SourceInfo) -> Result<(), ImportError> {
        if info.has_colors {
            self.colors = Some(SpillVec::new(
                self.faces_path.with_file_name("colors.bin"),
                self.memory_limit,
            ));
        }
        self.normals_from_input = info.has_normals;
        Ok(())
    }

    fn vertices(&mut self, batch: VertexBatch<'_>) -> Result<(), ImportError> {
        for p in batch.positions {
            let v = Vec3::from(*p);
            self.lo = self.lo.min(v);
            self.hi = self.hi.max(v);
            // Reservoir sampling (Vitter's algorithm R).
            self.seen += 1;
            if self.sample.len() < SAMPLE_SIZE {
                self.sample.push(*p);
            } else {
                let r = self.next_random() % self.seen;
                if (r as usize) < SAMPLE_SIZE {
                    self.sample[r as usize] = *p;
                }
            }
        }
        self.positions
            .extend_from_slice(batch.positions)
            .map_err(io_error)?;
        if let Some(colors) = self.colors.as_mut() {
            match batch.colors {
                Some(c) => colors.extend_from_slice(c).map_err(io_error)?,
                None => {
                    let len = colors.len() + batch.positions.len();
                    colors.resize(len, [255; 4]).map_err(io_error)?
                }
            }
        }
        match (self.normals_from_input, batch.normals) {
            (true, Some(n)) => {
                let unit: Vec<[f32; 3]> = n
                    .iter()
                    .map(|v| Vec3::from(*v).try_normalize().unwrap_or(Vec3::Z).into())
                    .collect();
                self.normals.extend_from_slice(&unit).map_err(io_error)?
            }
            _ => {
                let len = self.normals.len() + batch.positions.len();
                self.normals.resize(len, [0.0; 3]).map_err(io_error)?
            }
        }
        Ok(())
    }

    fn texture(&mut self, texture: SourceTexture) -> Result<(), ImportError> {
        let decoded: u64 =
            self.textures.iter().map(|t| t.image.bytes()).sum::<u64>() + texture.image.bytes();
        // Textures stay decoded for the leaf stage: they must fit the memory budget.
        if decoded > (self.memory_limit as u64) * 2 {
            return Err(ImportError::sink(format!(
                "the scan's textures take {} MiB decoded, more than the build's memory budget \
                 allows; raise the budget (--memory-budget)",
                decoded >> 20
            )));
        }
        if self.triangle_count > 0 {
            return Err(ImportError::sink(
                "a texture arrived after the first triangle",
            ));
        }
        self.textures.push(texture);
        if self.face_uvs.is_none() {
            let file = File::create(self.uvs_path()).map_err(io_error)?;
            self.face_uvs = Some(BufWriter::with_capacity(1 << 20, file));
        }
        Ok(())
    }

    fn textured_triangles(
        &mut self,
        triangles: &[[u32; 3]],
        faces: &[TexturedFace],
    ) -> Result<(), ImportError> {
        check_textured_faces(triangles, faces)?;
        self.push_triangles(triangles)?;
        if let Some(uvs) = self.face_uvs.as_mut() {
            // `push_triangles` took all of them: faces and coordinates stay aligned.
            uvs.write_all(bytemuck::cast_slice(faces))
                .map_err(io_error)?;
        }
        Ok(())
    }

    /// In a textured scan, triangles delivered without coordinates get
    /// [`TexturedFace::NONE`], as [`crate::mesh::TexturedMesh`] gives them.
    fn triangles(&mut self, triangles: &[[u32; 3]]) -> Result<(), ImportError> {
        self.push_triangles(triangles)?;
        if let Some(uvs) = self.face_uvs.as_mut() {
            for _ in triangles {
                uvs.write_all(bytemuck::bytes_of(&TexturedFace::NONE))
                    .map_err(io_error)?;
            }
        }
        Ok(())
    }
}

impl Ingest {
    /// Takes a batch of triangles into the face file, the normals and the edge statistics;
    /// nothing is written where one names a vertex not yet delivered.
    fn push_triangles(&mut self, triangles: &[[u32; 3]]) -> Result<(), ImportError> {
        let positions = self.positions.as_slice();
        let count = positions.len();
        let mut edge_sum = 0.0f64;
        for t in triangles {
            if t.iter().any(|&i| i as usize >= count) {
                return Err(ImportError::sink(
                    "triangle names a vertex not yet delivered",
                ));
            }
            let [a, b, c] = t.map(|i| Vec3::from(positions[i as usize]));
            if self.edge_count < 1 << 20 {
                edge_sum += ((b - a).length() + (c - b).length() + (a - c).length()) as f64;
            }
        }
        if self.edge_count < 1 << 20 {
            self.edge_sum += edge_sum;
            self.edge_count += triangles.len() as u64 * 3;
        }
        if !self.normals_from_input {
            let normals = self.normals.as_mut_slice();
            for t in triangles {
                let [a, b, c] = t.map(|i| Vec3::from(positions[i as usize]));
                // Area-weighted: the cross product's length is twice the area.
                let n = (b - a).cross(c - a);
                for &i in t {
                    let acc = &mut normals[i as usize];
                    acc[0] += n.x;
                    acc[1] += n.y;
                    acc[2] += n.z;
                }
            }
        }
        self.faces
            .write_all(bytemuck::cast_slice(triangles))
            .map_err(io_error)?;
        self.triangle_count += triangles.len() as u64;
        self.since_release += triangles.len() as u64;
        if self.since_release >= RELEASE_EVERY {
            self.since_release = 0;
            self.positions.release();
            self.normals.release();
            if let Some(c) = &self.colors {
                c.release();
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Texture, Wrap};

    #[test]
    fn a_textured_scans_coordinates_follow_its_faces_with_none_where_a_batch_had_none() {
        let dir = std::env::temp_dir().join(format!("mw-ingest-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let mut ingest = Ingest::new(&dir, 1 << 20).expect("ingest");
        ingest
            .begin(&SourceInfo {
                vertex_count: Some(4),
                triangle_count_hint: Some(3),
                has_colors: false,
                has_normals: false,
            })
            .expect("begin");
        let image = Texture::from_texels(2, 2, vec![[200; 4]; 4]).expect("an image");
        ingest
            .texture(SourceTexture {
                image: std::sync::Arc::new(image),
                wrap_s: Wrap::Repeat,
                wrap_t: Wrap::Repeat,
            })
            .expect("a texture");
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.0],
        ];
        ingest
            .vertices(VertexBatch {
                positions: &positions,
                colors: None,
                normals: None,
            })
            .expect("vertices");
        let face = TexturedFace {
            uv: [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            texture: 0,
        };
        ingest
            .textured_triangles(&[[0, 1, 2]], &[face])
            .expect("textured");
        // Untextured triangles, in the middle and last: coordinates NONE, no error.
        ingest.triangles(&[[1, 3, 2]]).expect("untextured");
        ingest
            .textured_triangles(&[[0, 1, 3]], &[face])
            .expect("textured");
        ingest.triangles(&[[0, 3, 2]]).expect("untextured, last");
        // A triangle naming an undelivered vertex writes neither a face nor coordinates.
        assert!(ingest.textured_triangles(&[[0, 1, 9]], &[face]).is_err());
        let done = ingest.finish().expect("finish");
        let path = done.face_uvs_path.as_ref().expect("a textured scan");
        let uvs: Vec<TexturedFace> =
            bytemuck::pod_collect_to_vec(&std::fs::read(path).expect("the coordinates"));
        assert_eq!(done.triangle_count, 4);
        assert_eq!(
            uvs,
            vec![face, TexturedFace::NONE, face, TexturedFace::NONE]
        );
        let faces = std::fs::read(&done.faces_path).expect("the faces");
        assert_eq!(faces.len(), 4 * 12);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
