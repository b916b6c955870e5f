//! Out-of-core spatial split: a kd-tree over a reservoir sample of the vertices cuts space into
//! buckets of at most B triangles (B from the memory budget), and one streaming pass over the
//! face file writes each face to the bucket holding its centroid. Buckets are then partitioned
//! into leaf patches independently and in parallel (the system paper's over-partitioning into
//! voxels, §3.1.1, with balanced cells instead of a regular grid).

use crate::mesh::TexturedFace;
use glam::Vec3;
use rayon::prelude::*;
use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Copy)]
enum KdNode {
    Leaf(u32),
    Split {
        axis: u8,
        at: f32,
        left: u32,
        right: u32,
    },
}

/// A kd-tree whose leaves are buckets.
#[derive(Debug, Clone)]
pub struct KdSplit {
    nodes: Vec<KdNode>,
    buckets: u32,
}

impl KdSplit {
    /// Splits at sample medians along the widest axis until each leaf is expected to hold at
    /// most `max_triangles`, given `triangles_per_sample` triangles per sampled point.
    pub fn build(
        sample: &mut [[f32; 3]],
        triangles_per_sample: f64,
        max_triangles: usize,
    ) -> KdSplit {
        let mut split = KdSplit {
            nodes: Vec::new(),
            buckets: 0,
        };
        split.build_node(sample, triangles_per_sample, max_triangles.max(1) as f64, 0);
        split
    }

    fn build_node(
        &mut self,
        sample: &mut [[f32; 3]],
        per_sample: f64,
        max: f64,
        depth: u32,
    ) -> u32 {
        let id = self.nodes.len() as u32;
        if sample.len() as f64 * per_sample <= max || sample.len() < 2 || depth > 40 {
            self.nodes.push(KdNode::Leaf(self.buckets));
            self.buckets += 1;
            return id;
        }
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for p in sample.iter() {
            lo = lo.min(Vec3::from(*p));
            hi = hi.max(Vec3::from(*p));
        }
        let extent = hi - lo;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        if extent[axis] <= 0.0 {
            self.nodes.push(KdNode::Leaf(self.buckets));
            self.buckets += 1;
            return id;
        }
        let mid = sample.len() / 2;
        sample.select_nth_unstable_by(mid, |a, b| a[axis].total_cmp(&b[axis]));
        let at = sample[mid][axis];
        self.nodes.push(KdNode::Leaf(0)); // placeholder, replaced below
        let (left_half, right_half) = sample.split_at_mut(mid);
        let left = self.build_node(left_half, per_sample, max, depth + 1);
        let right = self.build_node(right_half, per_sample, max, depth + 1);
        self.nodes[id as usize] = KdNode::Split {
            axis: axis as u8,
            at,
            left,
            right,
        };
        id
    }

    pub fn bucket_count(&self) -> usize {
        self.buckets as usize
    }

    /// The bucket containing point `p`.
    pub fn bucket_of(&self, p: Vec3) -> u32 {
        let mut node = 0usize;
        loop {
            match self.nodes[node] {
                KdNode::Leaf(b) => return b,
                KdNode::Split {
                    axis,
                    at,
                    left,
                    right,
                } => {
                    node = if p[axis as usize] < at { left } else { right } as usize;
                }
            }
        }
    }
}

/// One bucket's face file.
pub struct Bucket {
    pub path: PathBuf,
    pub triangles: u64,
}

/// Streams `faces_path` (u32 triples) and writes every face to its centroid's bucket file;
/// with `uvs_path` (a textured scan: [`TexturedFace`] records in face order), each face is
/// followed by its texture coordinates, so a bucket carries what its leaves bake from and no
/// array of every face's coordinates is held while the leaves are built.
pub fn write_buckets(
    faces_path: &Path,
    uvs_path: Option<&Path>,
    positions: &[[f32; 3]],
    split: &KdSplit,
    dir: &Path,
    buffer_budget: usize,
) -> io::Result<Vec<Bucket>> {
    let n = split.bucket_count();
    let capacity = (buffer_budget / n.max(1)).clamp(4096, 1 << 16);
    let mut writers = Vec::with_capacity(n);
    let mut buckets = Vec::with_capacity(n);
    for b in 0..n {
        let path = dir.join(format!("bucket-{b}.bin"));
        writers.push(BufWriter::with_capacity(capacity, File::create(&path)?));
        buckets.push(Bucket { path, triangles: 0 });
    }
    let mut reader = BufReader::with_capacity(1 << 20, File::open(faces_path)?);
    let mut uvs_reader = match uvs_path {
        Some(path) => Some(BufReader::with_capacity(1 << 20, File::open(path)?)),
        None => None,
    };
    let mut chunk = vec![[0u32; 3]; 1 << 16];
    let mut uvs = vec![TexturedFace::NONE; if uvs_path.is_some() { chunk.len() } else { 0 }];
    let mut face_buckets: Vec<u32> = Vec::with_capacity(chunk.len());
    loop {
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut chunk);
        let got = read_full(&mut reader, bytes)?;
        let faces = &chunk[..got / 12];
        if faces.is_empty() {
            break;
        }
        if let Some(r) = uvs_reader.as_mut() {
            let want = faces.len() * std::mem::size_of::<TexturedFace>();
            let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut uvs[..faces.len()]);
            if read_full(r, bytes)? < want {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidData,
                    "fewer texture coordinates than faces in the scratch files",
                ));
            }
        }
        // Each face's bucket, on every core of the build's pool (reading three scattered
        // vertices a face is most of this pass), then the faces to their files in order.
        faces
            .par_iter()
            .map(|f| {
                let c = f
                    .iter()
                    .map(|&i| Vec3::from(positions[i as usize]))
                    .sum::<Vec3>()
                    / 3.0;
                split.bucket_of(c)
            })
            .collect_into_vec(&mut face_buckets);
        for (i, (f, &b)) in faces.iter().zip(&face_buckets).enumerate() {
            let b = b as usize;
            writers[b].write_all(bytemuck::bytes_of(f))?;
            if let Some(uv) = uvs.get(i) {
                writers[b].write_all(bytemuck::bytes_of(uv))?;
            }
            buckets[b].triangles += 1;
        }
        if got < std::mem::size_of_val(chunk.as_slice()) {
            break;
        }
    }
    for w in writers {
        w.into_inner().map_err(|e| e.into_error())?;
    }
    Ok(buckets)
}

/// Reads until `buf` is full or the stream ends; returns the bytes read.
fn read_full(reader: &mut impl Read, buf: &mut [u8]) -> io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match reader.read(&mut buf[got..])? {
            0 => break,
            n => got += n,
        }
    }
    Ok(got)
}

/// Loads a bucket's faces, and their texture coordinates if it was written `textured`
/// ([`write_buckets`]).
pub fn read_bucket(
    bucket: &Bucket,
    textured: bool,
) -> io::Result<(Vec<[u32; 3]>, Vec<TexturedFace>)> {
    let bytes = std::fs::read(&bucket.path)?;
    if !textured {
        return Ok((
            bytemuck::pod_collect_to_vec(&bytes[..bytes.len() / 12 * 12]),
            Vec::new(),
        ));
    }
    const UV: usize = std::mem::size_of::<TexturedFace>();
    let records = bytes.chunks_exact(12 + UV);
    Ok((
        records
            .clone()
            .map(|r| bytemuck::pod_read_unaligned(&r[..12]))
            .collect(),
        records
            .map(|r| bytemuck::pod_read_unaligned(&r[12..]))
            .collect(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_carry_each_face_with_its_texture_coordinates() {
        let dir = std::env::temp_dir().join(format!("mw-buckets-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        // A strip of triangles along x, each face's coordinates naming the face.
        let n = 5000u32;
        let positions: Vec<[f32; 3]> = (0..n + 2)
            .map(|i| [i as f32, (i % 2) as f32, 0.0])
            .collect();
        let faces: Vec<[u32; 3]> = (0..n).map(|i| [i, i + 1, i + 2]).collect();
        let uvs: Vec<TexturedFace> = (0..n)
            .map(|i| TexturedFace {
                uv: [[i as f32, 0.5], [i as f32, 1.5], [i as f32, 2.5]],
                texture: i % 3,
            })
            .collect();
        let (faces_path, uvs_path) = (dir.join("faces.bin"), dir.join("uvs.bin"));
        std::fs::write(&faces_path, bytemuck::cast_slice(&faces)).expect("write");
        std::fs::write(&uvs_path, bytemuck::cast_slice(&uvs)).expect("write");
        let mut sample = positions.clone();
        let split = KdSplit::build(&mut sample, 1.0, 700);
        assert!(split.bucket_count() > 4);
        let buckets = write_buckets(
            &faces_path,
            Some(&uvs_path),
            &positions,
            &split,
            &dir,
            1 << 20,
        )
        .expect("buckets");
        let mut seen = 0;
        for bucket in &buckets {
            let (got, got_uvs) = read_bucket(bucket, true).expect("read");
            assert_eq!(got.len(), got_uvs.len());
            for (f, uv) in got.iter().zip(&got_uvs) {
                assert_eq!(uv, &uvs[f[0] as usize]);
            }
            seen += got.len();
        }
        assert_eq!(seen, n as usize);
        // Fewer coordinates than faces is an error, not a misaligned bucket.
        std::fs::write(&uvs_path, bytemuck::cast_slice(&uvs[..10])).expect("write");
        assert!(
            write_buckets(
                &faces_path,
                Some(&uvs_path),
                &positions,
                &split,
                &dir,
                1 << 20
            )
            .is_err()
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn kd_leaves_balance_the_sample() {
        let mut sample: Vec<[f32; 3]> = (0..10_000)
            .map(|i| {
                let t = i as f32;
                [
                    (t * 0.37).sin() * 10.0,
                    (t * 0.11).cos(),
                    (t * 0.013).sin() * 3.0,
                ]
            })
            .collect();
        let pts = sample.clone();
        let split = KdSplit::build(&mut sample, 2.0, 2500);
        assert!(split.bucket_count() >= 8);
        let mut counts = vec![0usize; split.bucket_count()];
        for p in &pts {
            counts[split.bucket_of(Vec3::from(*p)) as usize] += 1;
        }
        assert!(counts.iter().all(|&c| c * 2 <= 2500 + 2), "{counts:?}");
    }
}
