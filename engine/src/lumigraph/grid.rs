//! The sampling grid of the image repository (system paper §5.2.2, Fig. 16).
//!
//! The paper's viewing space is "a box twice as large as the input 3D model"; here it is the
//! cube centred on the model's bounding box whose side is twice the box's longest side, so a
//! thin scan (a relief, a slab) still gets viewpoints at a distance from its surface instead
//! of a box as flat as the scan. `n` points per axis span the cube corner to corner, and each
//! point records six images along ±x, ±y, ±z with a square 90° view, which together hold every
//! ray through the point. Images are keyed by `(x, y, z, d)`, the paper's hash key.

use glam::Vec3;

use crate::camera::Camera;

/// One of the six view directions of a grid point: where the camera looks and its up vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Direction {
    /// Unit view direction.
    pub forward: [f32; 3],
    /// Unit up vector of the image (orthogonal to `forward`).
    pub up: [f32; 3],
}

/// The six directions, indexed by `d`: +x, −x, +y, −y, +z, −z. Clients read them from the
/// repository's description rather than assuming this table.
pub const DIRECTIONS: [Direction; 6] = [
    Direction {
        forward: [1.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
    },
    Direction {
        forward: [-1.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
    },
    Direction {
        forward: [0.0, 1.0, 0.0],
        up: [0.0, 0.0, -1.0],
    },
    Direction {
        forward: [0.0, -1.0, 0.0],
        up: [0.0, 0.0, 1.0],
    },
    Direction {
        forward: [0.0, 0.0, 1.0],
        up: [0.0, 1.0, 0.0],
    },
    Direction {
        forward: [0.0, 0.0, -1.0],
        up: [0.0, 1.0, 0.0],
    },
];

/// Smallest and largest grid resolution per axis.
pub const MIN_POINTS: u32 = 2;
/// Largest grid resolution per axis (the paper used 16 and 32).
pub const MAX_POINTS: u32 = 64;
/// Smallest and largest image side.
pub const MIN_SIZE: u32 = 16;
/// Largest image side.
pub const MAX_SIZE: u32 = 2048;

/// Why a grid cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridError {
    #[error("grid must have {MIN_POINTS} to {MAX_POINTS} points per axis, got {0}")]
    Points(u32),
    #[error("image size must be {MIN_SIZE} to {MAX_SIZE} pixels, got {0}")]
    Size(u32),
    #[error("the model's bounding box is empty or not finite")]
    Bounds,
    #[error("image ({0}, {1}, {2}, {3}) is outside a {4}x{4}x{4} grid of 6 directions")]
    Key(u32, u32, u32, u32, u32),
}

/// Checks a grid's shape: `points` per axis and the image side within bounds.
pub fn check_shape(points: u32, size: u32) -> Result<(), GridError> {
    if !(MIN_POINTS..=MAX_POINTS).contains(&points) {
        return Err(GridError::Points(points));
    }
    if !(MIN_SIZE..=MAX_SIZE).contains(&size) {
        return Err(GridError::Size(size));
    }
    Ok(())
}

/// Checks a key `(x, y, z, d)` of a grid of `points` per axis.
pub fn check_key(points: u32, [x, y, z, d]: [u32; 4]) -> Result<(), GridError> {
    if x >= points || y >= points || z >= points || d >= 6 {
        return Err(GridError::Key(x, y, z, d, points));
    }
    Ok(())
}

/// The viewing box split into `points`³ grid points, each with six `size`² images.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Minimum corner of the viewing box.
    pub min: Vec3,
    /// Side of the (cubic) viewing box.
    pub side: f32,
    /// Points per axis.
    pub points: u32,
    /// Image side in pixels.
    pub size: u32,
}

impl Grid {
    /// The grid around a model with bounding box `[lo, hi]`.
    pub fn new(lo: Vec3, hi: Vec3, points: u32, size: u32) -> Result<Grid, GridError> {
        check_shape(points, size)?;
        let extent = (hi - lo).max_element();
        if !lo.is_finite() || !hi.is_finite() || extent.is_nan() || extent <= 0.0 {
            return Err(GridError::Bounds);
        }
        let side = 2.0 * extent;
        let center = (lo + hi) * 0.5;
        Ok(Grid {
            min: center - Vec3::splat(side * 0.5),
            side,
            points,
            size,
        })
    }

    /// Distance between neighbouring grid points.
    pub fn spacing(&self) -> f32 {
        self.side / (self.points - 1) as f32
    }

    /// Number of grid points.
    pub fn point_count(&self) -> u64 {
        (self.points as u64).pow(3)
    }

    /// Position of grid point `(x, y, z)` (each `0..points`).
    pub fn point(&self, x: u32, y: u32, z: u32) -> Vec3 {
        self.min + Vec3::new(x as f32, y as f32, z as f32) * self.spacing()
    }

    /// Every grid point, x fastest, then y, then z.
    pub fn keys(&self) -> impl Iterator<Item = [u32; 3]> + '_ {
        let n = self.points;
        (0..n).flat_map(move |z| (0..n).flat_map(move |y| (0..n).map(move |x| [x, y, z])))
    }

    /// The camera of image `(x, y, z, d)`: at the grid point, looking along direction `d`,
    /// square, 90° field of view.
    pub fn camera(&self, x: u32, y: u32, z: u32, d: u32) -> Camera {
        let eye = self.point(x, y, z);
        let dir = DIRECTIONS[d as usize % 6];
        Camera {
            eye,
            target: eye + Vec3::from(dir.forward),
            up: Vec3::from(dir.up),
            fovy_deg: 90.0,
            width: self.size,
            height: self.size,
        }
    }
}

/// Whether a grid point lies inside the object, from the coverage of its six images (the
/// fraction of pixels showing surface): a point every one of whose images is covered
/// completely is enclosed by the surface, and no view from outside can use what it sees.
pub fn enclosed(coverage: [f32; 6]) -> bool {
    coverage.iter().all(|&c| c >= 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_viewing_box_is_twice_the_longest_side_around_the_model() {
        let g = Grid::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(4.0, 2.0, 1.0), 5, 64).unwrap();
        assert_eq!(g.side, 8.0);
        assert_eq!(g.point(0, 0, 0), Vec3::new(-2.0, -3.0, -3.5));
        assert_eq!(g.point(4, 4, 4), Vec3::new(6.0, 5.0, 4.5));
        assert_eq!(g.spacing(), 2.0);
        assert_eq!(g.keys().count() as u64, g.point_count());
        assert_eq!(g.keys().nth(1), Some([1, 0, 0]));
    }

    #[test]
    fn six_cameras_cover_every_ray_through_a_point() {
        let g = Grid::new(Vec3::ZERO, Vec3::ONE, 3, 32).unwrap();
        // Each direction is seen by exactly the camera it is most aligned with.
        for v in [
            Vec3::new(0.3, -0.2, 0.9),
            Vec3::new(-1.0, 0.99, 0.1),
            Vec3::new(0.0, -1.0, 0.0),
        ] {
            let eye = g.point(1, 1, 1);
            let seen = (0..6)
                .filter(|&d| {
                    let cam = g.camera(1, 1, 1, d);
                    cam.validate().unwrap();
                    cam.project(eye + v).is_some_and(|(x, y, _)| {
                        (0.0..=32.0).contains(&x) && (0.0..=32.0).contains(&y)
                    })
                })
                .count();
            assert!(seen >= 1, "{v} seen by no camera");
        }
        for d in DIRECTIONS {
            assert!(Vec3::from(d.forward).dot(Vec3::from(d.up)).abs() < 1e-6);
        }
    }

    #[test]
    fn bad_grids_are_refused() {
        assert_eq!(
            Grid::new(Vec3::ZERO, Vec3::ONE, 1, 64),
            Err(GridError::Points(1))
        );
        assert_eq!(
            Grid::new(Vec3::ZERO, Vec3::ONE, 8, 4096),
            Err(GridError::Size(4096))
        );
        assert_eq!(
            Grid::new(Vec3::ONE, Vec3::ONE, 8, 64),
            Err(GridError::Bounds)
        );
        assert!(check_key(4, [3, 3, 3, 5]).is_ok());
        assert!(check_key(4, [4, 0, 0, 0]).is_err() && check_key(4, [0, 0, 0, 6]).is_err());
        assert!(enclosed([1.0; 6]) && !enclosed([1.0, 1.0, 1.0, 1.0, 1.0, 0.99]));
    }
}
