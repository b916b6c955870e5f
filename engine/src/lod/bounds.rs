//! Bounding spheres and normal cones for culling and error projection (system paper §3.3:
//! "bounding sphere ... and the cone of normals of the patch against the current view direction").

use glam::Vec3;

/// A bounding sphere as `[x, y, z, radius]`.
pub type Sphere = [f32; 4];

/// A bounding sphere of points (Ritter's algorithm: start from the most separated pair of
/// axis-extreme points, grow to include outliers). Within ~5% of the minimum in practice.
pub fn sphere_of_points<'a>(points: impl Iterator<Item = &'a [f32; 3]> + Clone) -> Sphere {
    let mut min_pts = [Vec3::splat(f32::MAX); 3];
    let mut max_pts = [Vec3::splat(f32::MIN); 3];
    let mut any = false;
    for p in points.clone() {
        let p = Vec3::from(*p);
        any = true;
        for axis in 0..3 {
            if p[axis] < min_pts[axis][axis] {
                min_pts[axis] = p;
            }
            if p[axis] > max_pts[axis][axis] {
                max_pts[axis] = p;
            }
        }
    }
    if !any {
        return [0.0; 4];
    }
    let axis = (0..3)
        .max_by(|&a, &b| {
            let da = min_pts[a].distance_squared(max_pts[a]);
            let db = min_pts[b].distance_squared(max_pts[b]);
            da.total_cmp(&db)
        })
        .unwrap_or(0);
    let mut center = (min_pts[axis] + max_pts[axis]) * 0.5;
    let mut radius = min_pts[axis].distance(max_pts[axis]) * 0.5;
    for p in points {
        let p = Vec3::from(*p);
        let d = p.distance(center);
        if d > radius {
            let new_radius = (radius + d) * 0.5;
            center += (p - center) * ((new_radius - radius) / d);
            radius = new_radius;
        }
    }
    // Guard against float rounding leaving a point a hair outside.
    let radius = radius * (1.0 + 1e-6) + f32::EPSILON;
    [center.x, center.y, center.z, radius]
}

/// The smallest sphere containing both spheres.
pub fn merge_spheres(a: Sphere, b: Sphere) -> Sphere {
    let (ca, cb) = (Vec3::new(a[0], a[1], a[2]), Vec3::new(b[0], b[1], b[2]));
    let d = ca.distance(cb);
    if d + b[3] <= a[3] {
        return a;
    }
    if d + a[3] <= b[3] {
        return b;
    }
    let radius = (d + a[3] + b[3]) * 0.5;
    let center = if d > 0.0 {
        ca + (cb - ca) * ((radius - a[3]) / d)
    } else {
        ca
    };
    [center.x, center.y, center.z, radius * (1.0 + 1e-6)]
}

/// Normal cone `[axis xyz, cutoff]` of a triangle set, in meshoptimizer's convention: a patch
/// with bounding sphere (c, r) is entirely back-facing for a camera at `eye` when
/// `dot(c - eye, axis) >= cutoff * |c - eye| + r`. A cutoff of 1 disables the test
/// (normals spread too wide).
pub fn normal_cone(positions: &[[f32; 3]], indices: &[u32]) -> [f32; 4] {
    let normals: Vec<Vec3> = indices
        .chunks_exact(3)
        .filter_map(|t| {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| Vec3::from(positions[i as usize]));
            let n = (b - a).cross(c - a);
            (n.length_squared() > 0.0).then(|| n.normalize())
        })
        .collect();
    let axis = normals.iter().copied().sum::<Vec3>();
    if normals.is_empty() || axis.length_squared() <= f32::MIN_POSITIVE {
        return [0.0, 0.0, 1.0, 1.0];
    }
    let axis = axis.normalize();
    let min_dot = normals.iter().map(|n| n.dot(axis)).fold(1.0f32, f32::min);
    if min_dot <= 0.1 {
        return [axis.x, axis.y, axis.z, 1.0];
    }
    // sin of the cone half-angle complement, as meshoptimizer's cone_cutoff.
    let cutoff = (1.0 - min_dot * min_dot).max(0.0).sqrt();
    [axis.x, axis.y, axis.z, cutoff]
}

/// Whether a patch is certainly facing away from a camera at `eye`.
pub fn back_facing(cone: [f32; 4], sphere: Sphere, eye: Vec3) -> bool {
    if cone[3] >= 1.0 {
        return false;
    }
    let center = Vec3::new(sphere[0], sphere[1], sphere[2]);
    let axis = Vec3::new(cone[0], cone[1], cone[2]);
    let to_center = center - eye;
    to_center.dot(axis) >= cone[3] * to_center.length() + sphere[3]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_contains_points() {
        let pts: Vec<[f32; 3]> = (0..100)
            .map(|i| {
                let t = i as f32 * 0.37;
                [t.sin() * 3.0, (t * 1.3).cos(), t * 0.01]
            })
            .collect();
        let s = sphere_of_points(pts.iter());
        for p in &pts {
            let d = Vec3::from(*p).distance(Vec3::new(s[0], s[1], s[2]));
            assert!(d <= s[3], "{d} > {}", s[3]);
        }
    }

    #[test]
    fn merged_sphere_contains_both() {
        let a = [0.0, 0.0, 0.0, 1.0];
        let b = [3.0, 0.0, 0.0, 0.5];
        let m = merge_spheres(a, b);
        assert!((m[0] - 1.25).abs() < 1e-5 && (m[3] - 2.25).abs() < 1e-4);
        assert_eq!(merge_spheres(a, [0.1, 0.0, 0.0, 0.2]), a);
    }

    #[test]
    fn flat_patch_is_culled_from_behind_only() {
        let pos = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let cone = normal_cone(&pos, &[0, 1, 2]);
        let sphere = sphere_of_points(pos.iter());
        assert!(back_facing(cone, sphere, Vec3::new(0.3, 0.3, -5.0)));
        assert!(!back_facing(cone, sphere, Vec3::new(0.3, 0.3, 5.0)));
    }
}
