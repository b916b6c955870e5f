//! Suggested regions (issue 13; Lazy Snapping's one-click superpixels, with the surface
//! segments of the mesh-segmentation paper, §3.1, in their place): a click selects the whole
//! surface segment under it at a chosen scale of the model's hierarchy
//! ([`crate::segment`]), not only what the view shows of it.
//!
//! The vertex set is exact by construction: it is the segment's own members, read from the
//! `.mwseg` ([`SegmentFile::members`]). What a selection also carries — the positions of
//! its vertices, for the part's centre, extent and anchor ([`BackProjection`]) — comes from
//! the leaves that hold them. A segment is connected over the surface, and neighbouring
//! leaves share their border vertices (so their bounding spheres meet), hence the leaves
//! holding it are found by a breadth-first walk from the clicked leaf over leaves whose
//! spheres meet, expanding only from leaves that held members, until every member is found:
//! the work follows the segment's size, not the model's. Should the walk end early (a
//! segment joined through a vertex the leaves do not share), the remaining leaves are read.

use glam::Vec3;
use rayon::prelude::*;
use roaring::RoaringBitmap;

use super::SelectError;
use super::backproject::{BackProjection, Hit};
use super::point::PickedPoint;
use crate::lod::{LodFile, NO_GROUP};
use crate::segment::SegmentFile;

/// A whole segment selected by a click.
#[derive(Debug, Clone)]
pub struct SegmentSelection {
    /// The scale it was picked at (0: fine).
    pub scale: usize,
    /// Its number at that scale.
    pub segment: u32,
    /// Its vertices, with their positions (statistics: leaves read, vertices tested).
    pub backprojection: BackProjection,
}

/// Spheres closer than this fraction of their radii still meet (rounding of the bounds).
const MEET_SLACK: f32 = 1e-4;

/// The segment at `scale` holding the vertex of `picked`, as a selection counted against
/// `base`.
pub fn select_segment(
    lod: &LodFile,
    segments: &SegmentFile,
    picked: &PickedPoint,
    scale: usize,
    base: Option<&RoaringBitmap>,
) -> Result<SegmentSelection, SelectError> {
    if scale >= segments.scales() {
        return Err(SelectError::BadParams(format!(
            "scale {scale} does not exist: the model's segments have scales 0 to {}",
            segments.scales() - 1
        )));
    }
    let segment = segments.segment_of(picked.vertex, scale).ok_or_else(|| {
        SelectError::BadPoint(format!(
            "the surface at ({}, {}) lies in no segment",
            picked.x, picked.y
        ))
    })?;
    let members = segments
        .members(scale, segment)
        .ok_or_else(|| SelectError::BadParams(format!("no segment {segment} at scale {scale}")))?;

    let nodes = lod.nodes();
    let leaves: Vec<u32> = (0..nodes.len() as u32)
        .filter(|&n| {
            let r = &nodes[n as usize];
            r.level == 0 || r.producer == NO_GROUP
        })
        .collect();
    let sphere = |n: u32| {
        let b = nodes[n as usize].bounds;
        (Vec3::new(b[0], b[1], b[2]), b[3].max(0.0))
    };
    let meet = |a: u32, b: u32| {
        let ((ca, ra), (cb, rb)) = (sphere(a), sphere(b));
        ca.distance(cb) <= (ra + rb) * (1.0 + MEET_SLACK)
    };
    let p = Vec3::from(picked.position);
    let mut visited = vec![false; nodes.len()];
    let mut frontier: Vec<u32> = leaves
        .iter()
        .copied()
        .filter(|&n| {
            let (c, r) = sphere(n);
            c.distance(p) <= r * (1.0 + MEET_SLACK) + f32::EPSILON
        })
        .collect();
    for &n in &frontier {
        visited[n as usize] = true;
    }

    let mut found = RoaringBitmap::new();
    let mut hits: Vec<Hit> = Vec::new();
    let (mut read, mut tested) = (0usize, 0u64);
    let mut exhaustive = false;
    while found.len() < members.len() {
        if frontier.is_empty() {
            if exhaustive {
                break;
            }
            // The walk lost the segment: read every leaf not read yet.
            exhaustive = true;
            frontier = leaves
                .iter()
                .copied()
                .filter(|&n| !visited[n as usize])
                .collect();
            for &n in &frontier {
                visited[n as usize] = true;
            }
            tracing::debug!(
                scale,
                segment,
                leaves = frontier.len(),
                "segment walk: reading the rest"
            );
            continue;
        }
        let wave: Vec<(u32, Vec<Hit>, u64)> = frontier
            .par_iter()
            .map(|&leaf| {
                let patch = lod.patch(leaf).map_err(|e| SelectError::Patch {
                    node: leaf,
                    message: e.to_string(),
                })?;
                let normals = if patch.normals.len() == patch.positions.len() {
                    patch.normals
                } else {
                    crate::lod::codec::computed_normals(&patch.positions, &patch.indices)
                };
                let own: Vec<Hit> = patch
                    .original_ids
                    .iter()
                    .zip(patch.positions.iter().zip(&normals))
                    .filter(|(id, _)| members.contains(**id))
                    .map(|(&id, (&p, &n))| (id, p, n))
                    .collect();
                Ok((leaf, own, patch.positions.len() as u64))
            })
            .collect::<Result<_, SelectError>>()?;
        read += wave.len();
        let mut next = Vec::new();
        for (leaf, own, t) in wave {
            tested += t;
            if own.is_empty() {
                continue;
            }
            for h in &own {
                found.insert(h.0);
            }
            hits.extend(own);
            if !exhaustive {
                for &m in &leaves {
                    if !visited[m as usize] && meet(leaf, m) {
                        visited[m as usize] = true;
                        next.push(m);
                    }
                }
            }
        }
        frontier = next;
    }
    let mut backprojection = BackProjection::of_hits(hits, base)?;
    // The set is the segment's: a member no leaf holds (none in a valid build) still counts.
    backprojection.vertices = members;
    backprojection.leaves = read;
    backprojection.vertices_tested = tested;
    Ok(SegmentSelection {
        scale,
        segment,
        backprojection,
    })
}
