//! Back-projection of selected pixels to the exact full-resolution vertices (system paper
//! §4.1.2): "we back-project the selected 2D region onto the index image in which each pixel
//! represents the ID of rendered small regions, and specify the IDs of the selected 3D
//! regions from the index image. Next, we back-project the 2D region onto the meshes that
//! belong to the regions selected on the index image. We test whether each vertex in the 3D
//! regions is included in the selected 2D regions on the screen."
//!
//! 1. The id buffer names the patch drawn under every selected pixel.
//! 2. Those patches are followed down the DAG (a node's producing group's members, level by
//!    level) to the leaves — level 0, the full-resolution scan ("we also select vertices of the
//!    ancestors' and children's patches"). Subtrees whose bounding sphere covers no selected
//!    pixel on screen are skipped.
//! 3. Every vertex of those leaves is projected: it is selected iff it falls in a selected
//!    pixel **and is visible there**: its view depth is not behind the depth buffer's by more
//!    than a tolerance (one pixel footprint by default, plus the depth slope across the pixel,
//!    plus the object-space error of the coarser patch that was drawn) and its normal does not
//!    face away. Occluded surfaces, whose depth lies behind the drawn one, are never selected.
//!    A vertex on a silhouette (in front of its pixel's surface, or over the background: its
//!    triangles miss the pixel centre) is selected when it lies on the surface of a selected
//!    neighbouring pixel, so regions keep their outline vertices.
//!
//! The result is a [`RoaringBitmap`] of original vertex ids, exact at every level of detail.

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use roaring::RoaringBitmap;

use super::SelectError;
use super::buffers::Buffers;
use crate::camera::Camera;
use crate::lod::{LodFile, NO_GROUP};
use crate::render::best_view::PartGeometry;

/// Visibility tolerances.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BackProjectOptions {
    /// Depth tolerance in pixel footprints (the world size of one pixel at the vertex's
    /// depth), added to the depth slope across the pixel and to the drawn patch's error.
    pub depth_tolerance_px: f32,
    /// Smallest cosine between a vertex normal and the direction to the eye (vertices facing
    /// further away are on the far side of a thin sheet); `-1` disables the test.
    pub min_facing: f32,
}

impl Default for BackProjectOptions {
    fn default() -> Self {
        BackProjectOptions {
            depth_tolerance_px: 1.5,
            min_facing: -0.3,
        }
    }
}

/// The selected full-resolution vertices.
#[derive(Debug, Clone, Default)]
pub struct BackProjection {
    /// Original vertex ids.
    pub vertices: RoaringBitmap,
    /// Sum of the selected vertices' positions, and of those already in the base set.
    pub sum: [f64; 3],
    pub sum_in_base: [f64; 3],
    pub count_in_base: u64,
    /// Centre, mean normal and extent of the selected vertices.
    pub geometry: Option<PartGeometry>,
    /// The selected vertex nearest to their mean: an anchor on the surface.
    pub anchor: Option<[f32; 3]>,
    /// Selected vertices sorted by id, with their positions (for anchors of combined sets).
    pub positions: Vec<(u32, [f32; 3])>,
    /// Patches drawn under the selection, leaves reached, vertices tested.
    pub drawn_nodes: usize,
    pub leaves: usize,
    pub vertices_tested: u64,
    pub ms: f64,
}

impl BackProjection {
    /// The selection of one picked point (the point tool), counted against `base`.
    pub fn of_point(picked: &super::point::PickedPoint, base: Option<&RoaringBitmap>) -> Self {
        let mut bp = BackProjection::default();
        bp.vertices.insert(picked.vertex);
        bp.sum = picked.position.map(f64::from);
        bp.anchor = Some(picked.position);
        bp.positions = vec![(picked.vertex, picked.position)];
        if base.is_some_and(|b| b.contains(picked.vertex)) {
            bp.count_in_base = 1;
            bp.sum_in_base = bp.sum;
        }
        bp
    }
}

/// A selected full-resolution vertex: original id, position, normal.
pub type Hit = (u32, [f32; 3], [f32; 3]);

impl BackProjection {
    /// The selection of the vertices `hits` (in any order; a vertex shared by neighbouring
    /// leaves may come more than once), counted against `base`: the id set, the position
    /// sums, the centre, normal and extent, and the anchor (statistics left at zero).
    pub fn of_hits(mut hits: Vec<Hit>, base: Option<&RoaringBitmap>) -> Result<Self, SelectError> {
        hits.sort_unstable_by_key(|h| h.0);
        hits.dedup_by_key(|h| h.0);
        let mut out = BackProjection {
            vertices: RoaringBitmap::from_sorted_iter(hits.iter().map(|h| h.0))
                .map_err(|e| SelectError::BadParams(format!("unsorted ids: {e}")))?,
            ..BackProjection::default()
        };
        for &(id, p, _) in &hits {
            for (s, &c) in out.sum.iter_mut().zip(&p) {
                *s += c as f64;
            }
            if base.is_some_and(|b| b.contains(id)) {
                out.count_in_base += 1;
                for (s, &c) in out.sum_in_base.iter_mut().zip(&p) {
                    *s += c as f64;
                }
            }
        }
        let positions: Vec<[f32; 3]> = hits.iter().map(|h| h.1).collect();
        let normals: Vec<[f32; 3]> = hits.iter().map(|h| h.2).collect();
        out.geometry = PartGeometry::from_points(&positions, &normals);
        out.anchor = out
            .geometry
            .and_then(|g| nearest(hits.iter().map(|h| (h.0, h.1)), g.center));
        out.positions = hits.into_iter().map(|h| (h.0, h.1)).collect();
        Ok(out)
    }
}

/// Summed-area table of the selected pixels.
struct Integral {
    w: usize,
    h: usize,
    t: Vec<u32>,
}

impl Integral {
    fn new(selected: &[bool], w: usize, h: usize) -> Integral {
        let mut t = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += selected[y * w + x] as u32;
                t[(y + 1) * (w + 1) + x + 1] = t[y * (w + 1) + x + 1] + row;
            }
        }
        Integral { w, h, t }
    }

    /// Selected pixels in `[x0, x1) × [y0, y1)` (clamped).
    fn count(&self, x0: f32, y0: f32, x1: f32, y1: f32) -> u32 {
        let cx = |v: f32| (v.max(0.0) as usize).min(self.w);
        let cy = |v: f32| (v.max(0.0) as usize).min(self.h);
        let (x0, x1) = (cx(x0.floor()), cx(x1.ceil()));
        let (y0, y1) = (cy(y0.floor()), cy(y1.ceil()));
        if x0 >= x1 || y0 >= y1 {
            return 0;
        }
        let s = self.w + 1;
        self.t[y1 * s + x1] + self.t[y0 * s + x0] - self.t[y0 * s + x1] - self.t[y1 * s + x0]
    }
}

/// Whether a node's bounding sphere may cover a selected pixel.
fn may_cover(camera: &Camera, sphere: [f32; 4], integral: &Integral) -> bool {
    let c = Vec3::new(sphere[0], sphere[1], sphere[2]);
    let r = sphere[3].max(0.0);
    let depth = (c - camera.eye).dot(camera.forward());
    if depth + r <= 0.0 {
        return false;
    }
    if depth - r <= depth.abs() * 1e-3 {
        return true; // the eye is in or near the sphere: no useful screen bound
    }
    let Some((x, y, _)) = camera.project(c) else {
        return true;
    };
    let rp = r * camera.pixel_scale() / (depth - r) + 1.0;
    integral.count(x - rp, y - rp, x + rp + 1.0, y + rp + 1.0) > 0
}

/// Selects the original vertices under `selected` (one flag per pixel of `buffers`, rendered
/// from `camera`) that are visible there. With `base`, also sums the positions of selected
/// vertices already in it (for the centres of combined sets, see [`super::modes`]).
pub fn back_project(
    lod: &LodFile,
    camera: &Camera,
    buffers: &Buffers<'_>,
    selected: &[bool],
    base: Option<&RoaringBitmap>,
    options: &BackProjectOptions,
) -> Result<BackProjection, SelectError> {
    let t0 = Instant::now();
    buffers.check()?;
    camera
        .validate()
        .map_err(|e| SelectError::BadParams(e.to_string()))?;
    if camera.width != buffers.width || camera.height != buffers.height {
        return Err(SelectError::SizeMismatch {
            what: "the camera's viewport",
            got_w: camera.width,
            got_h: camera.height,
            width: buffers.width,
            height: buffers.height,
        });
    }
    if selected.len() != buffers.len() {
        return Err(SelectError::SizeMismatch {
            what: "the selection",
            got_w: selected.len() as u32,
            got_h: 1,
            width: buffers.width,
            height: buffers.height,
        });
    }
    let tolerance_ok = options.depth_tolerance_px.is_finite() && options.depth_tolerance_px >= 0.0;
    if !tolerance_ok || !(-1.0..=1.0).contains(&options.min_facing) {
        return Err(SelectError::BadParams(
            "depth_tolerance_px must be >= 0 and min_facing within [-1, 1]".into(),
        ));
    }
    let nodes = lod.nodes();
    let (w, h) = (buffers.width as usize, buffers.height as usize);

    // 1. Patches drawn under the selection (the index image).
    let mut drawn = vec![false; nodes.len()];
    let mut any = false;
    for (i, &sel) in selected.iter().enumerate() {
        if sel && buffers.covered(i) {
            let n = buffers.node[i] as usize;
            if n < nodes.len() {
                drawn[n] = true;
                any = true;
            }
        }
    }
    let mut out = BackProjection::default();
    if !any {
        out.ms = t0.elapsed().as_secs_f64() * 1e3;
        return Ok(out);
    }
    out.drawn_nodes = drawn.iter().filter(|&&d| d).count();

    // 2. Down the DAG to the leaves.
    let integral = Integral::new(selected, w, h);
    let mut visited = vec![false; nodes.len()];
    let mut stack: Vec<u32> = (0..nodes.len() as u32)
        .filter(|&n| drawn[n as usize])
        .collect();
    for &n in &stack {
        visited[n as usize] = true;
    }
    let mut leaves: Vec<u32> = Vec::new();
    while let Some(n) = stack.pop() {
        let rec = &nodes[n as usize];
        if !may_cover(camera, rec.bounds, &integral) {
            continue;
        }
        if rec.level == 0 || rec.producer == NO_GROUP {
            leaves.push(n);
            continue;
        }
        let Some(group) = lod.groups().get(rec.producer as usize) else {
            leaves.push(n);
            continue;
        };
        for &m in lod.members(group) {
            if (m as usize) < nodes.len() && !visited[m as usize] {
                visited[m as usize] = true;
                stack.push(m);
            }
        }
    }
    leaves.sort_unstable();
    out.leaves = leaves.len();

    // 3. Every vertex of those leaves: in a selected pixel and visible there.
    let scale = camera.pixel_scale();
    let eye = camera.eye;
    let slope = |i: usize| -> f32 {
        let d = buffers.depth[i];
        let (x, y) = (i % w, i / w);
        let side = |j: Option<usize>| {
            j.filter(|&j| buffers.covered(j))
                .map_or(f32::INFINITY, |j| (buffers.depth[j] - d).abs())
        };
        let sx = side((x > 0).then(|| i - 1)).min(side((x + 1 < w).then(|| i + 1)));
        let sy = side((y > 0).then(|| i - w)).min(side((y + 1 < h).then(|| i + w)));
        let f = |s: f32| if s.is_finite() { s } else { 0.0 };
        f(sx) + f(sy)
    };
    type Found = (Vec<Hit>, u64);
    let found: Vec<Found> = leaves
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
            let mut hits = Vec::new();
            for (v, &p) in patch.positions.iter().enumerate() {
                let pv = Vec3::from(p);
                let Some((x, y, depth)) = camera.project(pv) else {
                    continue;
                };
                if !(x >= 0.0 && y >= 0.0 && x < w as f32 && y < h as f32) {
                    continue;
                }
                let i = y as usize * w + x as usize;
                let tolerance = |j: usize| {
                    let drawn_error = nodes
                        .get(buffers.node[j] as usize)
                        .map_or(0.0, |n| n.lod_error.max(0.0));
                    options.depth_tolerance_px * depth / scale + slope(j) + drawn_error
                };
                let own = buffers.covered(i);
                if selected[i] && own {
                    // Behind what is drawn there: occluded. (In front is fine: a vertex at a
                    // silhouette whose triangles miss the pixel centre.)
                    if depth - buffers.depth[i] > tolerance(i) {
                        continue;
                    }
                } else {
                    // A silhouette vertex (in front of its pixel's surface, or over the
                    // background) belongs to the selection when it lies on the surface of a
                    // selected neighbouring pixel.
                    let silhouette = !own || buffers.depth[i] - depth > tolerance(i);
                    if !silhouette
                        || !neighbours(i, w, h).any(|j| {
                            selected[j]
                                && buffers.covered(j)
                                && (depth - buffers.depth[j]).abs() <= tolerance(j)
                        })
                    {
                        continue;
                    }
                }
                let n = Vec3::from(normals[v]);
                if options.min_facing > -1.0 && n.length_squared() > 0.5 {
                    let to_eye = (eye - pv).normalize_or_zero();
                    if n.dot(to_eye) < options.min_facing {
                        continue;
                    }
                }
                if let Some(&id) = patch.original_ids.get(v) {
                    hits.push((id, p, normals[v]));
                }
            }
            Ok((hits, patch.positions.len() as u64))
        })
        .collect::<Result<_, SelectError>>()?;
    let mut hits: Vec<Hit> = Vec::new();
    let mut tested = 0;
    for (h, t) in found {
        tested += t;
        hits.extend(h);
    }
    let drawn_nodes = out.drawn_nodes;
    let leaves_reached = out.leaves;
    out = BackProjection::of_hits(hits, base)?;
    out.drawn_nodes = drawn_nodes;
    out.leaves = leaves_reached;
    out.vertices_tested = tested;
    out.ms = t0.elapsed().as_secs_f64() * 1e3;
    Ok(out)
}

/// The 8-neighbours of pixel `i`.
fn neighbours(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = ((i % w) as isize, (i / w) as isize);
    (-1isize..=1)
        .flat_map(move |dy| (-1isize..=1).map(move |dx| (x + dx, y + dy)))
        .filter(move |&(nx, ny)| {
            (nx, ny) != (x, y) && nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h
        })
        .map(move |(nx, ny)| ny as usize * w + nx as usize)
}

/// The point of `points` nearest to `to`.
pub fn nearest(points: impl Iterator<Item = (u32, [f32; 3])>, to: Vec3) -> Option<[f32; 3]> {
    points
        .map(|(_, p)| (Vec3::from(p).distance_squared(to), p))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, p)| p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integral_counts_rectangles() {
        let mut sel = vec![false; 20];
        sel[6] = true; // (1, 1) in a 5 x 4 image
        sel[13] = true; // (3, 2)
        let t = Integral::new(&sel, 5, 4);
        assert_eq!(t.count(0.0, 0.0, 5.0, 4.0), 2);
        assert_eq!(t.count(0.0, 0.0, 2.0, 2.0), 1);
        assert_eq!(t.count(2.0, 0.0, 5.0, 2.0), 0);
        assert_eq!(t.count(-10.0, -10.0, 100.0, 100.0), 2);
        assert_eq!(t.count(3.2, 2.5, 3.4, 2.6), 1);
    }
}
