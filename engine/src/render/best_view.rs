//! Best view of a part (system paper §2.2: search results and links jump to a region, so each
//! part needs a camera that frames it and sees it unoccluded).
//!
//! The camera looks at the part's centre from a distance that fits its extent in the field of
//! view. The mean-normal direction is tried first, then directions tilted away from it at a
//! few azimuths. Each candidate is rendered at a small size with the part marked, and scored by
//! the part's distinct original ids visible in the id buffer, relative to the most part
//! vertices any candidate drew: low when the part is occluded or seen edge-on or from behind
//! (its patches are then back-face culled). The first candidate is kept when it already sees
//! most of what it draws.

use super::{Cut, Highlight, Outputs, RenderError, RenderModel, RenderOptions, Renderer};
use crate::camera::Camera;
use crate::lod::{Culling, FormatError, LodFile};
use glam::{Quat, Vec3};
use rayon::prelude::*;
use roaring::RoaringBitmap;

/// Centre, mean normal and extent of a part.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PartGeometry {
    pub center: Vec3,
    /// Unit mean normal (zero when undefined).
    pub normal: Vec3,
    /// Largest distance of a part vertex from the centre.
    pub extent: f32,
    pub vertices: u64,
}

impl PartGeometry {
    /// From the part's vertex positions and normals.
    pub fn from_points(positions: &[[f32; 3]], normals: &[[f32; 3]]) -> Option<PartGeometry> {
        if positions.is_empty() {
            return None;
        }
        let n = positions.len() as f64;
        let sum = positions.iter().fold([0f64; 3], |a, p| {
            [a[0] + p[0] as f64, a[1] + p[1] as f64, a[2] + p[2] as f64]
        });
        let center = Vec3::new(
            (sum[0] / n) as f32,
            (sum[1] / n) as f32,
            (sum[2] / n) as f32,
        );
        let extent = positions
            .iter()
            .map(|p| Vec3::from(*p).distance(center))
            .fold(0.0, f32::max);
        let normal = normals
            .iter()
            .map(|v| Vec3::from(*v))
            .sum::<Vec3>()
            .normalize_or_zero();
        Some(PartGeometry {
            center,
            normal,
            extent,
            vertices: positions.len() as u64,
        })
    }
}

/// Computes a part's geometry from the full-resolution patches (the leaves) of a model. Decodes
/// every leaf: a one-off cost per part, proportional to the model size.
pub fn part_geometry(
    lod: &LodFile,
    part: &RoaringBitmap,
) -> Result<Option<PartGeometry>, FormatError> {
    if part.is_empty() {
        return Ok(None);
    }
    let leaves: Vec<u32> = (0..lod.nodes().len() as u32)
        .filter(|&i| lod.nodes()[i as usize].level == 0)
        .collect();
    type Points = (Vec<[f32; 3]>, Vec<[f32; 3]>);
    let chunks: Vec<Points> = leaves
        .par_iter()
        .map(|&i| {
            let p = lod.patch(i)?;
            let mut pos = Vec::new();
            let mut nrm = Vec::new();
            for (v, id) in p.original_ids.iter().enumerate() {
                if part.contains(*id) {
                    pos.push(p.positions[v]);
                    if let Some(n) = p.normals.get(v) {
                        nrm.push(*n);
                    }
                }
            }
            Ok((pos, nrm))
        })
        .collect::<Result<_, FormatError>>()?;
    let (pos, nrm): (Vec<_>, Vec<_>) = chunks.into_iter().unzip();
    let pos: Vec<[f32; 3]> = pos.into_iter().flatten().collect();
    let nrm: Vec<[f32; 3]> = nrm.into_iter().flatten().collect();
    Ok(PartGeometry::from_points(&pos, &nrm))
}

/// Settings of the search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BestViewOptions {
    pub fovy_deg: f32,
    pub width: u32,
    pub height: u32,
    /// Preferred up direction of the returned camera.
    pub up: Vec3,
    /// Distance factor over a tight fit of the part's extent.
    pub margin: f32,
    /// Longest side of the probe renders.
    pub probe_side: u32,
    /// Tilts (degrees) of the alternatives from the mean normal, each at `azimuths` angles.
    pub tilts: [f32; 2],
    pub azimuths: u32,
    /// Keep the first candidate when its visible share of drawn part vertices reaches this.
    pub accept: f32,
}

impl Default for BestViewOptions {
    fn default() -> Self {
        BestViewOptions {
            fovy_deg: 40.0,
            width: 640,
            height: 480,
            up: Vec3::Y,
            margin: 1.3,
            probe_side: 160,
            tilts: [35.0, 65.0],
            azimuths: 6,
            accept: 0.85,
        }
    }
}

/// One scored direction.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Candidate {
    pub direction: Vec3,
    /// Distinct part ids visible in the probe's id buffer.
    pub visible: u64,
    /// Part vertices in the patches the probe drew.
    pub drawn: u64,
    pub score: f32,
}

/// The chosen camera and how the candidates scored.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BestView {
    pub camera: Camera,
    pub score: f32,
    pub chosen: usize,
    pub candidates: Vec<Candidate>,
}

fn up_for(dir: Vec3, up: Vec3) -> Vec3 {
    for u in [up, Vec3::Z, Vec3::Y, Vec3::X] {
        let u = u.normalize_or_zero();
        if u != Vec3::ZERO && dir.cross(u).length() > 0.2 {
            return u;
        }
    }
    Vec3::Y
}

/// A camera looking at `center` from direction `dir` (unit, from the centre towards the eye)
/// that fits a sphere of radius `extent`.
pub fn framing_camera(
    center: Vec3,
    dir: Vec3,
    extent: f32,
    opts: &BestViewOptions,
    width: u32,
    height: u32,
) -> Camera {
    let half_v = (opts.fovy_deg.to_radians() * 0.5).clamp(1e-3, 1.5);
    let aspect = width as f32 / height.max(1) as f32;
    let half_h = (half_v.tan() * aspect).atan();
    let half = half_v.min(half_h);
    let r = extent.max(1e-6) * opts.margin.max(1.0);
    let d = r / half.sin();
    Camera {
        eye: center + dir * d,
        target: center,
        up: up_for(dir, opts.up),
        fovy_deg: opts.fovy_deg,
        width,
        height,
    }
}

/// Candidate directions: the mean normal, then tilted alternatives around it.
fn directions(normal: Vec3, opts: &BestViewOptions) -> Vec<Vec3> {
    let n = if normal.length_squared() > 1e-12 {
        normal.normalize()
    } else {
        Vec3::Z
    };
    let side = n.any_orthonormal_vector();
    let mut out = vec![n];
    for tilt in opts.tilts {
        for k in 0..opts.azimuths.max(1) {
            let az = k as f32 * std::f32::consts::TAU / opts.azimuths.max(1) as f32;
            let axis = Quat::from_axis_angle(n, az) * side;
            out.push((Quat::from_axis_angle(axis, tilt.to_radians()) * n).normalize());
        }
    }
    out
}

/// Finds a camera that frames `part` (its original vertex ids and geometry) unoccluded.
pub fn best_view(
    renderer: &Renderer,
    model: &RenderModel,
    part: &RoaringBitmap,
    geometry: &PartGeometry,
    opts: &BestViewOptions,
) -> Result<BestView, RenderError> {
    if !(geometry.center.is_finite() && geometry.normal.is_finite() && geometry.extent.is_finite())
    {
        return Err(RenderError::BadOption(
            "part geometry must be finite".into(),
        ));
    }
    let (w, h) = (opts.width, opts.height);
    let check = framing_camera(geometry.center, Vec3::Z, geometry.extent, opts, w, h);
    check.validate()?;
    let long = w.max(h).max(1) as f32;
    let s = opts.probe_side.clamp(16, 1024) as f32 / long;
    let (pw, ph) = (
        ((w as f32 * s).round() as u32).max(8),
        ((h as f32 * s).round() as u32).max(8),
    );
    let render_opts = RenderOptions {
        cut: Cut::View {
            pixel_error: 1.0,
            culling: Culling::ALL,
        },
        outputs: Outputs {
            color: false,
            normal: false,
            depth: false,
            ids: true,
        },
        ..RenderOptions::default()
    };
    let marks = [Highlight {
        vertices: part,
        tint: None,
        outline: true,
    }];
    let mut candidates = Vec::new();
    for (k, dir) in directions(geometry.normal, opts).into_iter().enumerate() {
        let probe = framing_camera(geometry.center, dir, geometry.extent, opts, pw, ph);
        let frame = renderer.render(model, &probe, &render_opts, &marks)?;
        let mut seen = RoaringBitmap::new();
        if let Some(ids) = &frame.ids {
            for (v, m) in ids.vertex.iter().zip(&ids.highlight) {
                if m & super::highlight::OUTLINE_BIT != 0 {
                    seen.insert(*v);
                }
            }
        }
        let c = Candidate {
            direction: dir,
            visible: seen.len(),
            drawn: frame.stats.highlighted_vertices,
            score: 0.0,
        };
        tracing::debug!(
            candidate = k,
            visible = c.visible,
            drawn = c.drawn,
            "best view probe"
        );
        let early = k == 0 && c.drawn > 0 && c.visible as f32 >= opts.accept * c.drawn as f32;
        candidates.push(c);
        if early {
            break;
        }
    }
    let max_drawn = candidates.iter().map(|c| c.drawn).max().unwrap_or(0).max(1) as f32;
    for c in &mut candidates {
        c.score = c.visible as f32 / max_drawn;
    }
    let mut chosen = 0;
    for (i, c) in candidates.iter().enumerate() {
        // Strictly better only: ties keep the earlier (closer to the mean normal) direction.
        if c.score > candidates[chosen].score + 1e-6 {
            chosen = i;
        }
    }
    let dir = candidates[chosen].direction;
    Ok(BestView {
        camera: framing_camera(geometry.center, dir, geometry.extent, opts, w, h),
        score: candidates[chosen].score,
        chosen,
        candidates,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_start_with_the_normal_and_tilt() {
        let o = BestViewOptions::default();
        let d = directions(Vec3::new(0.0, 0.0, 2.0), &o);
        assert_eq!(d.len(), 1 + 2 * 6);
        assert!(d[0].distance(Vec3::Z) < 1e-6);
        for v in &d[1..7] {
            assert!((v.dot(Vec3::Z) - 35f32.to_radians().cos()).abs() < 1e-4);
        }
    }

    #[test]
    fn framing_fits_the_extent() {
        let o = BestViewOptions::default();
        let c = framing_camera(Vec3::ONE, Vec3::X, 2.0, &o, 640, 480);
        assert!(c.validate().is_ok());
        // A point on the sphere perpendicular to the view lands inside the image.
        for p in [Vec3::ONE + Vec3::Y * 2.0, Vec3::ONE - Vec3::Z * 2.0] {
            let (x, y, _) = c.project(p).expect("in front");
            assert!(
                (0.0..640.0).contains(&x) && (0.0..480.0).contains(&y),
                "{x},{y}"
            );
        }
        let g =
            PartGeometry::from_points(&[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]], &[[0.0, 0.0, 1.0]; 2])
                .expect("part");
        assert_eq!(g.center, Vec3::new(1.0, 0.0, 0.0));
        assert_eq!(g.extent, 1.0);
        assert_eq!(g.normal, Vec3::Z);
    }
}
