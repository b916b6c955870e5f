//! Out-of-core spatial split: a kd-tree over a reservoir sample of the vertices cuts space into
//! buckets of at most B triangles (B from the memory budget), and one streaming pass over the
//! face file writes each face to the bucket holding its centroid. Buckets are then partitioned
//! into leaf patches independently and in parallel (the system paper's over-partitioning into
//! voxels, §3.1.1, with balanced cells instead of a regular grid).

use glam::Vec3;
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
/// `indexed`: each face followed by its index in the face file (textured scans look up their
/// texture coordinates by it).
pub fn write_buckets(
    faces_path: &Path,
    positions: &[[f32; 3]],
    split: &KdSplit,
    dir: &Path,
    buffer_budget: usize,
    indexed: bool,
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
    let mut chunk = vec![[0u32; 3]; 1 << 16];
    let mut face_index = 0u32;
    loop {
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut chunk);
        let got = read_full(&mut reader, bytes)?;
        let faces = &chunk[..got / 12];
        if faces.is_empty() {
            break;
        }
        for f in faces {
            let c = f
                .iter()
                .map(|&i| Vec3::from(positions[i as usize]))
                .sum::<Vec3>()
                / 3.0;
            let b = split.bucket_of(c) as usize;
            writers[b].write_all(bytemuck::bytes_of(f))?;
            if indexed {
                writers[b].write_all(&face_index.to_ne_bytes())?;
            }
            face_index = face_index.wrapping_add(1);
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

/// Loads a bucket's faces, and their face-file indices if it was written `indexed`.
pub fn read_bucket(bucket: &Bucket, indexed: bool) -> io::Result<(Vec<[u32; 3]>, Vec<u32>)> {
    let bytes = std::fs::read(&bucket.path)?;
    if !indexed {
        return Ok((
            bytemuck::pod_collect_to_vec(&bytes[..bytes.len() / 12 * 12]),
            Vec::new(),
        ));
    }
    let records: Vec<[u32; 4]> = bytemuck::pod_collect_to_vec(&bytes[..bytes.len() / 16 * 16]);
    Ok((
        records.iter().map(|r| [r[0], r[1], r[2]]).collect(),
        records.iter().map(|r| r[3]).collect(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

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
