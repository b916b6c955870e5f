//! Cuts through the DAG: which patches to draw for a uniform error or for a camera
//! (system paper §3.3: frustum and normal-cone culling, refinement until the projected error
//! is at most a pixel threshold).
//!
//! A node is in the cut iff its own error is acceptable and its group's is not. Siblings share
//! sphere and error for both tests, so a group is always replaced as a whole and every cut is
//! crack-free; errors and spheres grow towards the roots, so exactly one node per surface region
//! qualifies.

use super::bounds::{Sphere, back_facing};
use super::format::{NO_GROUP, NodeRecord};
use crate::camera::Camera;
use glam::Vec3;

/// Which culling tests a view-dependent cut applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Culling {
    pub frustum: bool,
    pub backface: bool,
}

impl Culling {
    pub const ALL: Culling = Culling {
        frustum: true,
        backface: true,
    };
    pub const NONE: Culling = Culling {
        frustum: false,
        backface: false,
    };
}

/// Nodes of the cut where every patch is within `max_error` (object space) of the scan.
pub fn cut_uniform(nodes: &[NodeRecord], max_error: f32) -> Vec<u32> {
    (0..nodes.len() as u32)
        .filter(|&i| {
            let n = &nodes[i as usize];
            n.lod_error <= max_error && n.parent_error > max_error
        })
        .collect()
}

/// Screen-space size in pixels of an object-space `error` at the sphere's nearest point.
/// Infinite when the camera is inside the sphere.
pub fn projected_error(camera: &Camera, sphere: Sphere, error: f32) -> f32 {
    if error <= 0.0 {
        return 0.0;
    }
    if !error.is_finite() {
        return f32::INFINITY;
    }
    let center = Vec3::new(sphere[0], sphere[1], sphere[2]);
    let distance = camera.eye.distance(center) - sphere[3];
    if distance <= f32::EPSILON * camera.eye.length().max(1.0) {
        return f32::INFINITY;
    }
    error * camera.pixel_scale() / distance
}

/// Whether the tight bounds of a node can be seen by the camera.
pub fn visible(camera: &Camera, node: &NodeRecord, culling: Culling) -> bool {
    let b = node.bounds;
    let center = Vec3::new(b[0], b[1], b[2]);
    if culling.frustum {
        if (center - camera.eye).dot(camera.forward()) < -b[3] {
            return false;
        }
        for plane in camera.side_planes() {
            if plane.truncate().dot(center) + plane.w < -b[3] {
                return false;
            }
        }
    }
    !(culling.backface && back_facing(node.cone, b, camera.eye))
}

/// Nodes of the view-dependent cut: visible, and refined until each covers at most
/// `pixel_error` pixels of error.
pub fn cut_view(
    nodes: &[NodeRecord],
    camera: &Camera,
    pixel_error: f32,
    culling: Culling,
) -> Vec<u32> {
    (0..nodes.len() as u32)
        .filter(|&i| {
            let n = &nodes[i as usize];
            projected_error(camera, n.lod_sphere, n.lod_error) <= pixel_error
                && projected_error(camera, n.parent_sphere, n.parent_error) > pixel_error
                && visible(camera, n, culling)
        })
        .collect()
}

/// Silhouette-first refinement (issue 11 item 4, the progressive-transmission paper §4.1):
/// where normal maps carry a coarse patch's shading, only its outline shows its geometric
/// error, so a group whose coarse surface wholly faces the camera (every product's normal
/// cone front-facing from all of its bounds) refines at `interior_factor` times the pixel
/// threshold, and the others (the silhouette, back faces seen through holes, products whose
/// normals spread too far to bound) at the threshold itself.
///
/// That score is not monotone along the DAG (a group that faces the camera can sit over one
/// that does not), so the cut is made top-down, as the viewer's (`static/js/lod/cut.js`):
/// from the roots, groups are taken coarsest first and one refines (its members replace its
/// products) only when all its products are in the cut. Every cut is then a set of whole
/// groups' products: crack-free, one patch per surface region. With a factor of 1 it is
/// [`cut_view`]'s cut.
pub struct Silhouette {
    /// Groups, coarsest first: (products, members).
    groups: Vec<(Vec<u32>, Vec<u32>)>,
    roots: Vec<u32>,
    pub interior_factor: f32,
}

impl Silhouette {
    pub fn new(nodes: &[NodeRecord], interior_factor: f32) -> Silhouette {
        let count = nodes
            .iter()
            .flat_map(|n| [n.producer, n.member_of])
            .filter(|&g| g != NO_GROUP)
            .map(|g| g as usize + 1)
            .max()
            .unwrap_or(0);
        let mut groups = vec![(Vec::new(), Vec::new()); count];
        let mut level = vec![0u32; count];
        let mut roots = Vec::new();
        for (i, n) in nodes.iter().enumerate() {
            if let Some(g) = groups.get_mut(n.producer as usize) {
                g.0.push(i as u32);
                level[n.producer as usize] = level[n.producer as usize].max(n.level);
            }
            match groups.get_mut(n.member_of as usize) {
                Some(g) => g.1.push(i as u32),
                None => roots.push(i as u32),
            }
        }
        let mut order: Vec<usize> = (0..count).collect();
        order.sort_by_key(|&g| std::cmp::Reverse(level[g]));
        let groups = order
            .into_iter()
            .map(|g| std::mem::take(&mut groups[g]))
            .collect();
        Silhouette {
            groups,
            roots,
            interior_factor,
        }
    }

    /// Whether every product of a group faces the camera: its normal cone, or where its
    /// normals spread wider than [`INTERIOR_SPREAD`] (a rough surface: the bumps of a relief
    /// face every way), a cone of that spread around its mean normal. A bump's own outline is
    /// within the patch's error, which the factor lets grow to `interior_factor` pixels.
    fn interior(nodes: &[NodeRecord], products: &[u32], eye: Vec3) -> bool {
        products.iter().all(|&p| {
            let n = &nodes[p as usize];
            let mut cone = n.cone;
            cone[3] = cone[3].min(INTERIOR_SPREAD);
            front_facing(cone, n.bounds, eye)
        })
    }
}

/// Sine of the widest normal spread [`Silhouette`] takes into account (30°).
pub const INTERIOR_SPREAD: f32 = 0.5;

/// Whether every normal of `cone` faces a camera at `eye` from every point of `sphere`.
pub fn front_facing(cone: [f32; 4], sphere: Sphere, eye: Vec3) -> bool {
    back_facing([-cone[0], -cone[1], -cone[2], cone[3]], sphere, eye)
}

/// [`cut_view`] with silhouette-first refinement ([`Silhouette`]).
pub fn cut_view_silhouette(
    nodes: &[NodeRecord],
    camera: &Camera,
    pixel_error: f32,
    culling: Culling,
    silhouette: &Silhouette,
) -> Vec<u32> {
    let mut in_cut = vec![false; nodes.len()];
    for &r in &silhouette.roots {
        in_cut[r as usize] = true;
    }
    for (products, members) in &silhouette.groups {
        let Some(&first) = products.first() else {
            continue;
        };
        if !products.iter().all(|&p| in_cut[p as usize]) {
            continue;
        }
        let n = &nodes[first as usize];
        let mut score = projected_error(camera, n.lod_sphere, n.lod_error);
        if silhouette.interior_factor != 1.0 && Silhouette::interior(nodes, products, camera.eye) {
            score /= silhouette.interior_factor;
        }
        if score > pixel_error {
            for &p in products {
                in_cut[p as usize] = false;
            }
            for &m in members {
                in_cut[m as usize] = true;
            }
        }
    }
    (0..nodes.len() as u32)
        .filter(|&i| in_cut[i as usize] && visible(camera, &nodes[i as usize], culling))
        .collect()
}
