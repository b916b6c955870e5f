//! Surface segments during the out-of-core build: each bucket's fine segments
//! ([`super::grow`]) are gathered as the leaves are made, numbered in bucket order, joined
//! across bucket borders and merged into scales ([`super::merge`]), then written as the
//! model's `.mwseg` ([`super::file`]).
//!
//! Memory: per vertex, the segment map lives in a memory-mapped scratch file (8 bytes a
//! vertex, in the page cache); in memory are only per-segment sums, boundaries and the
//! buckets' border vertices. A vertex on a bucket border keeps the segment of the lowest
//! bucket, so the file is the same whatever the order in which buckets finish.

use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use memmap2::MmapMut;

use super::grow::{Boundary, BucketSegments, GrowParams, SegmentSums, grow};
use super::merge::{MergeParams, coarsen, merge};
use crate::lod::patch::BuildPatch;

/// What a bucket keeps until the end of the build.
#[derive(Debug, Default)]
struct Summary {
    sums: Vec<SegmentSums>,
    /// Per segment, the strongest boundary merged inside it by the bucket's own merge
    /// (empty when there was none).
    inner: Vec<f64>,
    boundaries: Vec<(u32, u32, Boundary)>,
    border: Vec<(u32, u32)>,
}

/// Gathers the buckets' segments during a build.
pub struct Collector {
    path: PathBuf,
    vertices: usize,
    /// Per vertex `bucket << 32 | local segment`, `u64::MAX` when not seen yet.
    map: Mutex<Option<MmapMut>>,
    summaries: Mutex<Vec<Summary>>,
    params: GrowParams,
    /// Fine segments the global merge's working set holds.
    fit: usize,
}

const UNSEEN: u64 = u64::MAX;

/// Bytes of the merge's working set per fine segment (sums, adjacency, heap entries).
const BYTES_PER_SEGMENT: usize = 512;

/// Most bytes of the global merge's working set, whatever the memory budget: 131k fine
/// segments. A model seen whole covers a few hundred thousand pixels, a few pixels a fine
/// segment at that count, and the pixel graph refines every boundary below segment size;
/// finer segments only cost build time and memory. A bucket whose grown segments exceed its
/// share of that count (in proportion to its vertices) merges them itself first
/// ([`coarsen`]), so the bound holds whatever the growing yields: on a rough surface the
/// normal rule stops the growing at a few vertices, far below the size cap (the 5M relief:
/// 2.5M vertices, 377k grown segments of 6.6 vertices at a cap of 20).
const MERGE_BYTES: usize = 64 << 20;

/// The most vertices of a fine segment: [`GrowParams::default`]'s (small superpixels, so
/// the hierarchy, not the region growing, decides where parts meet), larger on scans whose
/// fine segments would not fit the global merge's working set: a quarter of
/// `memory_budget`, at most [`MERGE_BYTES`].
fn fine_size(vertices: usize, memory_budget: usize) -> usize {
    GrowParams::default()
        .max_vertices
        .max(vertices.div_ceil(merge_fit(memory_budget)))
}

/// Fine segments the global merge may hold: its working set within a quarter of
/// `memory_budget`, at most [`MERGE_BYTES`].
fn merge_fit(memory_budget: usize) -> usize {
    ((memory_budget / 4).min(MERGE_BYTES) / BYTES_PER_SEGMENT).max(1)
}

impl Collector {
    /// A collector for `vertices` original vertices and `buckets` buckets, its scratch file
    /// in `scratch`, the merge's working set within a quarter of `memory_budget` bytes (at
    /// most `MERGE_BYTES`).
    pub fn new(
        scratch: &Path,
        vertices: usize,
        buckets: usize,
        memory_budget: usize,
    ) -> io::Result<Collector> {
        let path = scratch.join("segments.map");
        let map = if vertices == 0 {
            None
        } else {
            let file = File::options()
                .create(true)
                .truncate(true)
                .read(true)
                .write(true)
                .open(&path)?;
            file.set_len(vertices as u64 * 8)?;
            // SAFETY: the scratch file is private to this build and never truncated while
            // mapped.
            let mut map = unsafe { MmapMut::map_mut(&file)? };
            map.fill(0xFF);
            Some(map)
        };
        Ok(Collector {
            path,
            vertices,
            map: Mutex::new(map),
            summaries: Mutex::new((0..buckets).map(|_| Summary::default()).collect()),
            params: GrowParams {
                max_vertices: fine_size(vertices, memory_budget),
                ..GrowParams::default()
            },
            fit: merge_fit(memory_budget),
        })
    }

    /// Segments bucket number `bucket`, whose mesh is `mesh` (original ids in `mesh.ids`).
    pub fn add(&self, bucket: usize, mesh: &BuildPatch) -> io::Result<()> {
        let BucketSegments {
            mut vertex_segment,
            mut sums,
            mut boundaries,
            mut border,
        } = grow(mesh, &self.params);
        // The bucket's share of the global merge's working set.
        let share = ((self.fit as u128 * vertex_segment.len() as u128)
            .div_ceil(self.vertices.max(1) as u128) as usize)
            .max(1);
        let mut inner = Vec::new();
        if sums.len() > share {
            let c = coarsen(sums, boundaries, &MergeParams::default(), share);
            for s in vertex_segment
                .iter_mut()
                .chain(border.iter_mut().map(|(_, s)| s))
            {
                *s = c.labels[*s as usize];
            }
            border.sort_unstable();
            border.dedup();
            sums = c.sums;
            boundaries = c.boundaries;
            inner = c.inner;
        }
        {
            let mut guard = self
                .map
                .lock()
                .map_err(|_| io::Error::other("segment map lock poisoned"))?;
            if let Some(map) = guard.as_mut() {
                let slots: &mut [u64] = bytemuck::cast_slice_mut(&mut map[..]);
                for (&id, &s) in mesh.ids.iter().zip(&vertex_segment) {
                    let packed = (bucket as u64) << 32 | s as u64;
                    if let Some(slot) = slots.get_mut(id as usize)
                        && (*slot == UNSEEN || packed < *slot)
                    {
                        *slot = packed;
                    }
                }
            }
        }
        let mut summaries = self
            .summaries
            .lock()
            .map_err(|_| io::Error::other("segment summaries lock poisoned"))?;
        if let Some(s) = summaries.get_mut(bucket) {
            *s = Summary {
                sums,
                inner,
                boundaries,
                border,
            };
        }
        Ok(())
    }

    /// Numbers, joins and merges the segments and writes the `.mwseg` file to `out`; returns
    /// the segments per scale, fine first.
    pub fn finish(self, out: &Path) -> io::Result<Vec<u32>> {
        let summaries = self
            .summaries
            .into_inner()
            .map_err(|_| io::Error::other("segment summaries lock poisoned"))?;
        let map = self
            .map
            .into_inner()
            .map_err(|_| io::Error::other("segment map lock poisoned"))?;
        // Global numbers: buckets in order.
        let mut base = Vec::with_capacity(summaries.len());
        let mut total = 0u32;
        for s in &summaries {
            base.push(total);
            total = total.saturating_add(s.sums.len() as u32);
        }
        let mut sums = Vec::with_capacity(total as usize);
        let mut inner = Vec::new();
        let mut boundaries = Vec::new();
        let mut border = Vec::new();
        for (b, s) in summaries.into_iter().enumerate() {
            if !s.inner.is_empty() {
                inner.resize(sums.len(), 0.0);
                inner.extend(&s.inner);
            }
            sums.extend(s.sums);
            boundaries.extend(
                s.boundaries
                    .into_iter()
                    .map(|(x, y, bd)| (x + base[b], y + base[b], bd)),
            );
            border.extend(s.border.into_iter().map(|(id, x)| (id, x + base[b])));
        }
        // Joins: one vertex in several buckets (a boundary without edges of its own).
        border.sort_unstable();
        for w in border.windows(2) {
            if w[0].0 == w[1].0 && w[0].1 != w[1].1 {
                boundaries.push((w[0].1, w[1].1, Boundary::default()));
            }
        }
        drop(border);
        let hierarchy = merge(sums, inner, boundaries, &MergeParams::default());
        let fine_of = |packed: u64| {
            if packed == UNSEEN {
                super::file::NONE
            } else {
                base.get((packed >> 32) as usize)
                    .map_or(super::file::NONE, |&b| b + packed as u32)
            }
        };
        match &map {
            Some(m) => {
                let slots: &[u64] = bytemuck::cast_slice(&m[..]);
                super::file::write(
                    out,
                    &hierarchy,
                    self.vertices as u64,
                    slots.iter().map(|&p| fine_of(p)),
                )?;
            }
            None => super::file::write(out, &hierarchy, 0, std::iter::empty())?,
        }
        drop(map);
        let _ = std::fs::remove_file(&self.path);
        let mut counts = vec![hierarchy.fine];
        counts.extend(&hierarchy.counts);
        Ok(counts)
    }
}
