//! Pinhole camera shared by cuts, rendering and selection.
//!
//! Conventions: right-handed world, `eye` looks at `target`, `up` need not be orthogonal to
//! the view direction; `fovy_deg` is the full vertical field of view; clip depth is [0, 1]
//! (wgpu), with near/far planes derived from the scene bounds by the caller.

use glam::{Mat4, Vec3, Vec4};
use serde::{Deserialize, Serialize};

/// A view of the scene at a given image size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    pub fovy_deg: f32,
    pub width: u32,
    pub height: u32,
}

/// Why a camera cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    #[error("camera values must be finite")]
    NotFinite,
    #[error("eye and target coincide")]
    NoDirection,
    #[error("up vector is zero or parallel to the view direction")]
    BadUp,
    #[error("vertical field of view must be within (0, 179] degrees, got {0}")]
    BadFov(f32),
    #[error("image size must be between 1x1 and {max}x{max}, got {width}x{height}")]
    BadSize { width: u32, height: u32, max: u32 },
}

impl Camera {
    /// Largest image side the engine accepts.
    pub const MAX_SIDE: u32 = 8192;

    /// Checks that the camera defines a proper view.
    pub fn validate(&self) -> Result<(), CameraError> {
        let values = [self.eye, self.target, self.up];
        if values.iter().any(|v| !v.is_finite()) || !self.fovy_deg.is_finite() {
            return Err(CameraError::NotFinite);
        }
        let dir = self.target - self.eye;
        if dir.length_squared() <= f32::MIN_POSITIVE {
            return Err(CameraError::NoDirection);
        }
        if self.up.length_squared() <= f32::MIN_POSITIVE
            || dir.normalize().cross(self.up.normalize()).length() < 1e-6
        {
            return Err(CameraError::BadUp);
        }
        if !(self.fovy_deg > 0.0 && self.fovy_deg <= 179.0) {
            return Err(CameraError::BadFov(self.fovy_deg));
        }
        if self.width == 0
            || self.height == 0
            || self.width > Self::MAX_SIDE
            || self.height > Self::MAX_SIDE
        {
            return Err(CameraError::BadSize {
                width: self.width,
                height: self.height,
                max: Self::MAX_SIDE,
            });
        }
        Ok(())
    }

    /// Unit view direction.
    pub fn forward(&self) -> Vec3 {
        (self.target - self.eye).normalize_or_zero()
    }

    pub fn aspect(&self) -> f32 {
        self.width as f32 / self.height.max(1) as f32
    }

    /// World-to-view matrix (right-handed, looking down -Z).
    pub fn view(&self) -> Mat4 {
        glam::camera::rh::view::look_at_mat4(self.eye, self.target, self.up)
    }

    /// Perspective projection with wgpu's [0, 1] depth range.
    pub fn projection(&self, near: f32, far: f32) -> Mat4 {
        glam::camera::rh::proj::directx::perspective(
            self.fovy_deg.to_radians(),
            self.aspect(),
            near,
            far,
        )
    }

    /// Pixels per unit of world length at unit distance: `height / (2 tan(fovy / 2))`.
    /// A world-space error `e` at distance `d` covers `e * pixel_scale() / d` pixels.
    pub fn pixel_scale(&self) -> f32 {
        self.height as f32 / (2.0 * (self.fovy_deg.to_radians() * 0.5).tan())
    }

    /// Side planes of the view frustum (left, right, bottom, top) as `(n, w)` with inward unit
    /// normals: a point `p` is inside when `n·p + w >= 0` for all four.
    pub fn side_planes(&self) -> [Vec4; 4] {
        let (f, r, u) = self.basis();
        let half_v = (self.fovy_deg.to_radians() * 0.5).tan();
        let half_h = half_v * self.aspect();
        let plane = |n: Vec3| {
            let n = n.normalize_or_zero();
            n.extend(-n.dot(self.eye))
        };
        [
            plane(r + f * half_h),
            plane(-r + f * half_h),
            plane(u + f * half_v),
            plane(-u + f * half_v),
        ]
    }

    /// Orthonormal (forward, right, up) basis of the view.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let f = self.forward();
        let r = f.cross(self.up).normalize_or_zero();
        (f, r, r.cross(f))
    }

    /// Projects a world point to pixel coordinates (x right, y down) and view depth
    /// (distance along the view direction). `None` behind the camera.
    pub fn project(&self, p: Vec3) -> Option<(f32, f32, f32)> {
        let (f, right, up) = self.basis();
        let rel = p - self.eye;
        let depth = rel.dot(f);
        if depth <= 0.0 {
            return None;
        }
        let s = self.pixel_scale() / depth;
        let x = self.width as f32 * 0.5 + rel.dot(right) * s;
        let y = self.height as f32 * 0.5 - rel.dot(up) * s;
        Some((x, y, depth))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fovy_deg: 60.0,
            width: 200,
            height: 100,
        }
    }

    #[test]
    fn planes_contain_visible_points_and_exclude_others() {
        let c = cam();
        let planes = c.side_planes();
        let inside = |p: Vec3| planes.iter().all(|pl| pl.truncate().dot(p) + pl.w >= 0.0);
        assert!(inside(Vec3::ZERO));
        assert!(inside(Vec3::new(0.5, 0.5, 0.0)));
        assert!(!inside(Vec3::new(10.0, 0.0, 0.0)));
        assert!(!inside(Vec3::new(-10.0, 0.0, 0.0)));
        assert!(!inside(Vec3::new(0.0, 10.0, 0.0)));
        assert!(!inside(Vec3::new(0.0, -10.0, 0.0)));
    }

    #[test]
    fn projection_matches_matrices() {
        let c = cam();
        let p = Vec3::new(0.7, -0.4, 0.3);
        let (x, y, depth) = c.project(p).expect("in front");
        let clip = c.projection(0.1, 100.0) * c.view() * p.extend(1.0);
        let ndc = clip.truncate() / clip.w;
        let mx = (ndc.x * 0.5 + 0.5) * c.width as f32;
        let my = (0.5 - ndc.y * 0.5) * c.height as f32;
        assert!(
            (mx - x).abs() < 1e-3 && (my - y).abs() < 1e-3,
            "{mx},{my} vs {x},{y}"
        );
        assert!((depth - 4.7).abs() < 1e-5);
    }

    #[test]
    fn rejects_bad_cameras() {
        let mut c = cam();
        c.up = Vec3::Z;
        assert_eq!(c.validate(), Err(CameraError::BadUp));
        let mut c = cam();
        c.fovy_deg = 0.0;
        assert!(c.validate().is_err());
        let mut c = cam();
        c.width = 0;
        assert!(c.validate().is_err());
        let mut c = cam();
        c.eye.x = f32::NAN;
        assert_eq!(c.validate(), Err(CameraError::NotFinite));
    }
}
