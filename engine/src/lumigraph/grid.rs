//! The sampling grid of the image repository (system paper §5.2.2, Fig. 16).
//!
//! The paper's viewing space is "a box twice as large as the input 3D model"; here it is the
//! cube centred on the model's bounding box whose side is twice the box's longest side, so a
//! thin scan (a relief, a slab) still gets viewpoints at a distance from its surface instead
//! of a box as flat as the scan. `n` points per axis span the cube corner to corner, and each
//! point records six images along ±x, ±y, ±z with a square 90° view, which together hold every
//! ray through the point. Images are keyed by `(x, y, z, d)`, the paper's hash key.
//!
//! **Refinement levels.** A uniform grid holds images as fine as its spacing allows: a view
//! closer to the surface than the nearest grid point sees the images' texels magnified (on the
//! 5M relief of the network bench a 6³ grid left close views at 21–24 dB). Level `l` halves the
//! spacing `l` times (level 0 is the paper's grid; its points are those of every finer level
//! with even indices, so a key is named by its coarsest level, [`Grid::canonical`]). Finer
//! levels are kept to the model's bounding box widened by [`REFINE_MARGIN`] of their spacing
//! ([`Grid::refines`]), where views come close to the surface; their images are rendered when
//! first asked for and then stored like the others, so the repository grows only where viewers
//! look, and stays bounded.

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

/// Finest refinement level (spacing / 2^`MAX_LEVEL`).
pub const MAX_LEVEL: u32 = 3;
/// A refined point lies within this many of its level's spacings of the model's bounding box.
pub const REFINE_MARGIN: f32 = 2.0;

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
    #[error("refinement level {0} is beyond the finest, {MAX_LEVEL}")]
    Level(u32),
    #[error(
        "point ({1}, {2}, {3}) of level {0} is not refined: finer levels are kept near the model"
    )]
    NotRefined(u32, u32, u32, u32),
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

/// Points per axis of level `level` of a grid of `points` per axis.
pub fn level_points(points: u32, level: u32) -> u32 {
    (points - 1) * (1 << level.min(MAX_LEVEL)) + 1
}

/// Checks a key `(x, y, z, d)` of level `level` of a grid of `points` per axis.
pub fn check_key(points: u32, level: u32, [x, y, z, d]: [u32; 4]) -> Result<(), GridError> {
    if level > MAX_LEVEL {
        return Err(GridError::Level(level));
    }
    let n = level_points(points, level);
    if x >= n || y >= n || z >= n || d >= 6 {
        return Err(GridError::Key(x, y, z, d, n));
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
    /// The model's bounding box, minimum and maximum corner (where finer levels are kept).
    pub model: [Vec3; 2],
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
            model: [lo, hi],
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

    /// Distance between neighbouring points of level `level`.
    pub fn level_spacing(&self, level: u32) -> f32 {
        self.spacing() / (1u32 << level.min(MAX_LEVEL)) as f32
    }

    /// Position of point `p` of level `level`.
    pub fn level_point(&self, level: u32, p: [u32; 3]) -> Vec3 {
        self.min + Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) * self.level_spacing(level)
    }

    /// The same point named by its coarsest level (a point of level `l` with even indices is
    /// the point of level `l - 1` with half of them).
    pub fn canonical(level: u32, mut p: [u32; 3]) -> (u32, [u32; 3]) {
        let mut level = level;
        while level > 0 && p.iter().all(|v| v % 2 == 0) {
            p = p.map(|v| v / 2);
            level -= 1;
        }
        (level, p)
    }

    /// Whether point `p` of level `level` is kept: every point of level 0; a finer one if it
    /// lies within [`REFINE_MARGIN`] of its spacing of the model's bounding box.
    pub fn refines(&self, level: u32, p: [u32; 3]) -> bool {
        if level == 0 {
            return true;
        }
        let q = self.level_point(level, p);
        // (A thousandth of a spacing more: the lattice often lands exactly on the margin, and
        // such a point is then kept whatever the rounding, here and in the viewer.)
        let margin = Vec3::splat((REFINE_MARGIN + 1e-3) * self.level_spacing(level));
        q.cmpge(self.model[0] - margin).all() && q.cmple(self.model[1] + margin).all()
    }

    /// Checks key `(x, y, z, d)` of level `level`: within the level and kept by it.
    pub fn check_level_key(&self, level: u32, key: [u32; 4]) -> Result<(), GridError> {
        check_key(self.points, level, key)?;
        let [x, y, z, _] = key;
        if !self.refines(level, [x, y, z]) {
            return Err(GridError::NotRefined(level, x, y, z));
        }
        Ok(())
    }

    /// Every grid point, x fastest, then y, then z.
    pub fn keys(&self) -> impl Iterator<Item = [u32; 3]> + '_ {
        let n = self.points;
        (0..n).flat_map(move |z| (0..n).flat_map(move |y| (0..n).map(move |x| [x, y, z])))
    }

    /// The camera of image `(x, y, z, d)`: at the grid point, looking along direction `d`,
    /// square, 90° field of view.
    pub fn camera(&self, x: u32, y: u32, z: u32, d: u32) -> Camera {
        self.level_camera(0, [x, y, z], d)
    }

    /// The camera of image `d` of point `p` of level `level`.
    pub fn level_camera(&self, level: u32, p: [u32; 3], d: u32) -> Camera {
        let eye = self.level_point(level, p);
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
        assert!(check_key(4, 0, [3, 3, 3, 5]).is_ok());
        assert!(check_key(4, 0, [4, 0, 0, 0]).is_err() && check_key(4, 0, [0, 0, 0, 6]).is_err());
        assert!(
            check_key(4, 2, [12, 12, 12, 5]).is_ok() && check_key(4, 2, [13, 0, 0, 0]).is_err()
        );
        assert_eq!(
            check_key(4, MAX_LEVEL + 1, [0, 0, 0, 0]),
            Err(GridError::Level(MAX_LEVEL + 1))
        );
        assert!(enclosed([1.0; 6]) && !enclosed([1.0, 1.0, 1.0, 1.0, 1.0, 0.99]));
    }

    #[test]
    fn finer_levels_halve_the_spacing_and_stay_near_the_model() {
        // A flat model: 4 x 4 x 0.5, so the viewing cube's side is 8.
        let g = Grid::new(Vec3::ZERO, Vec3::new(4.0, 4.0, 0.5), 5, 64).unwrap();
        assert_eq!(level_points(5, 2), 17);
        assert_eq!(g.level_spacing(2), 0.5);
        // Level 2's point (8, 8, 8) is level 0's (2, 2, 2), the cube's centre.
        assert_eq!(g.level_point(2, [8, 8, 8]), g.point(2, 2, 2));
        assert_eq!(Grid::canonical(2, [8, 8, 8]), (0, [2, 2, 2]));
        assert_eq!(Grid::canonical(2, [8, 6, 8]), (1, [4, 3, 4]));
        assert_eq!(Grid::canonical(2, [1, 2, 3]), (2, [1, 2, 3]));
        // The model spans z 0..0.5 and the cube z -3.75..4.25: level 2 (spacing 0.5, margin 1)
        // keeps z -1..1.5, i.e. indices 6..10; every level-0 point is kept.
        let z = |k: u32| g.level_point(2, [8, 8, k]).z;
        assert_eq!((z(5), z(10)), (-1.25, 1.25));
        assert!(g.refines(2, [8, 8, 6]) && g.refines(2, [8, 8, 10]));
        assert!(!g.refines(2, [8, 8, 5]) && !g.refines(2, [8, 8, 11]));
        assert!(!g.refines(2, [0, 8, 8]) && g.refines(0, [0, 0, 0]));
        assert_eq!(
            g.check_level_key(2, [8, 8, 11, 0]),
            Err(GridError::NotRefined(2, 8, 8, 11))
        );
        assert!(g.check_level_key(2, [8, 8, 10, 5]).is_ok());
        // A camera of a refined point sits at that point.
        assert_eq!(
            g.level_camera(2, [8, 8, 10], 5).eye,
            g.level_point(2, [8, 8, 10])
        );
    }
}
