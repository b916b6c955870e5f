//! A single click makes a point part: the surface point under the pixel (from the depth
//! buffer) and the full-resolution vertex nearest to it, found like back-projection does
//! (system paper §4.1.2): from the patch drawn there (id buffer) down the DAG to the leaves
//! whose bounds hold the point.

use glam::Vec3;

use super::SelectError;
use super::buffers::Buffers;
use crate::camera::Camera;
use crate::lod::{LodFile, NO_GROUP};

/// A picked point.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct PickedPoint {
    /// The surface point under the pixel centre.
    pub position: [f32; 3],
    /// The original id of the full-resolution vertex nearest to it.
    pub vertex: u32,
    /// Pixel column.
    pub x: u32,
    /// Pixel row (from the top).
    pub y: u32,
}

/// The world point at the centre of pixel (`x`, `y`) at view depth `depth`.
pub fn unproject(camera: &Camera, x: f32, y: f32, depth: f32) -> Vec3 {
    let (f, r, u) = camera.basis();
    let s = camera.pixel_scale();
    let dx = (x - camera.width as f32 * 0.5) / s;
    let dy = (camera.height as f32 * 0.5 - y) / s;
    camera.eye + (f + r * dx + u * dy) * depth
}

/// Picks the surface at pixel (`x`, `y`) of `buffers` rendered from `camera`.
pub fn pick(
    lod: &LodFile,
    camera: &Camera,
    buffers: &Buffers<'_>,
    x: f32,
    y: f32,
) -> Result<PickedPoint, SelectError> {
    buffers.check()?;
    if !(x.is_finite() && y.is_finite() && x >= 0.0 && y >= 0.0)
        || x >= buffers.width as f32
        || y >= buffers.height as f32
    {
        return Err(SelectError::BadPoint(format!(
            "point ({x}, {y}) is outside the {}x{} view",
            buffers.width, buffers.height
        )));
    }
    let (px, py) = (x as u32, y as u32);
    let i = py as usize * buffers.width as usize + px as usize;
    if !buffers.covered(i) {
        return Err(SelectError::BadPoint(format!(
            "there is no surface at ({px}, {py}): click on the model"
        )));
    }
    let p = unproject(camera, px as f32 + 0.5, py as f32 + 0.5, buffers.depth[i]);
    let nodes = lod.nodes();
    let drawn = buffers.node[i];
    let slack = nodes
        .get(drawn as usize)
        .map_or(0.0, |n| n.lod_error.max(0.0))
        + buffers.depth[i] / camera.pixel_scale() * 2.0;
    // Leaves under the drawn patch whose bounds hold the point (within the drawn error).
    let mut best: Option<(f32, u32)> = None;
    let mut stack = vec![drawn];
    let mut seen = std::collections::HashSet::new();
    while let Some(n) = stack.pop() {
        let Some(rec) = nodes.get(n as usize) else {
            continue;
        };
        if !seen.insert(n) {
            continue;
        }
        let b = rec.bounds;
        if Vec3::new(b[0], b[1], b[2]).distance(p) > b[3] + slack {
            continue;
        }
        if rec.level > 0
            && rec.producer != NO_GROUP
            && let Some(g) = lod.groups().get(rec.producer as usize)
        {
            stack.extend_from_slice(lod.members(g));
            continue;
        }
        let patch = lod.patch(n).map_err(|e| SelectError::Patch {
            node: n,
            message: e.to_string(),
        })?;
        for (v, q) in patch.positions.iter().enumerate() {
            let d = Vec3::from(*q).distance_squared(p);
            if best.is_none_or(|(bd, _)| d < bd)
                && let Some(&id) = patch.original_ids.get(v)
            {
                best = Some((d, id));
            }
        }
    }
    Ok(PickedPoint {
        position: p.into(),
        vertex: best.map_or(buffers.vertex[i], |b| b.1),
        x: px,
        y: py,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unproject_inverts_project() {
        let c = Camera {
            eye: Vec3::new(1.0, 2.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fovy_deg: 50.0,
            width: 320,
            height: 200,
        };
        let p = Vec3::new(0.3, -0.2, 0.4);
        let (x, y, d) = c.project(p).unwrap();
        assert!(unproject(&c, x, y, d).distance(p) < 1e-4);
    }
}
