//! Cuts through the DAG: which patches to draw for a uniform error or for a camera
//! (system paper §3.3: frustum and normal-cone culling, refinement until the projected error
//! is at most a pixel threshold).
//!
//! A node is in the cut iff its own error is acceptable and its group's is not. Siblings share
//! sphere and error for both tests, so a group is always replaced as a whole and every cut is
//! crack-free; errors and spheres grow towards the roots, so exactly one node per surface region
//! qualifies.

use super::bounds::{Sphere, back_facing};
use super::format::NodeRecord;
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
