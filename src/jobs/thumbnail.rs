//! Model thumbnails, rendered once a build ends: the process's render service
//! ([`crate::render::RenderService`], `MESHWIKI_RENDER_ADAPTER`) draws the 1-pixel cut from
//! the model's mean facing direction through [`crate::render::thumbnail_png`], the code path
//! of part thumbnails too, as background work of the render pool. Where no GPU adapter opens
//! (not even Mesa's lavapipe), a small CPU rasteriser draws a coarse uniform cut instead, so
//! every model still gets a picture.

use std::sync::Arc;

use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::{LodFile, NO_GROUP, cut_uniform};
use meshwiki_engine::render::RenderModel;
use meshwiki_engine::render::best_view::{BestViewOptions, framing_camera};
use meshwiki_engine::render::encode::{self, ImageFormat};

use crate::config::RenderSettings;
use crate::render::{RenderService, RenderServiceError};

/// Thumbnail width in pixels.
pub const WIDTH: u32 = 320;
/// Thumbnail height in pixels.
pub const HEIGHT: u32 = 240;
/// Triangles the CPU fallback draws at most.
const CPU_TRIANGLES: u64 = 150_000;

/// Why a thumbnail could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ThumbnailError {
    /// Rendering failed.
    #[error("render failed: {0}")]
    Render(String),
    /// Encoding failed.
    #[error("cannot encode thumbnail: {0}")]
    Encode(#[from] encode::EncodeError),
}

/// The camera of a thumbnail: the model's mean facing direction (roots' normal cones
/// weighted by triangles), tilted a little for relief, framing the bounding sphere.
pub fn camera(lod: &LodFile) -> Camera {
    let h = lod.header();
    let (lo, hi) = (Vec3::from(h.bbox_min), Vec3::from(h.bbox_max));
    let mut center = (lo + hi) * 0.5;
    let mut radius = (hi - lo).length() * 0.5;
    if !center.is_finite() || !radius.is_finite() || radius <= 0.0 {
        center = Vec3::ZERO;
        radius = 1.0;
    }
    let mut normal = Vec3::ZERO;
    for n in lod.nodes().iter().filter(|n| n.member_of == NO_GROUP) {
        let axis = Vec3::new(n.cone[0], n.cone[1], n.cone[2]);
        if axis.is_finite() {
            normal += axis * n.triangle_count as f32;
        }
    }
    let dir = if normal.length_squared() > 1e-12 {
        let n = normal.normalize();
        let side = if n.cross(Vec3::Y).length() > 0.2 {
            Vec3::Y
        } else {
            Vec3::X
        };
        (n - side * 0.35).normalize()
    } else {
        Vec3::new(1.0, 0.8, 1.2).normalize()
    };
    let opts = BestViewOptions {
        fovy_deg: 35.0,
        margin: 1.05,
        ..BestViewOptions::default()
    };
    framing_camera(center, dir, radius, &opts, WIDTH, HEIGHT)
}

/// Renders the thumbnail of `lod` as PNG.
pub fn render_png(settings: &RenderSettings, lod: Arc<LodFile>) -> Result<Vec<u8>, ThumbnailError> {
    let cam = camera(&lod);
    let service = RenderService::shared(settings);
    if service.available() {
        let model = RenderModel::new(lod.clone());
        let bytes = crate::render::thumbnail_bytes(WIDTH, HEIGHT);
        let png = service.run_blocking(bytes, |r| {
            let png = crate::render::thumbnail_png(r, &model, &cam, &[]);
            r.forget(&model);
            png
        });
        match png {
            Ok(Ok(png)) => return Ok(png),
            Ok(Err(RenderServiceError::Encode(e))) => return Err(e.into()),
            Ok(Err(e)) | Err(e) => return Err(ThumbnailError::Render(e.to_string())),
        }
    }
    let pixels = rasterize(&lod, &cam)?;
    Ok(encode::encode(
        &pixels,
        WIDTH,
        HEIGHT,
        ImageFormat::Png,
        90,
        [255, 255, 255],
    )?)
}

/// CPU fallback: a uniform cut of at most [`CPU_TRIANGLES`] triangles, z-buffered, flat
/// shaded with a headlight.
fn rasterize(lod: &LodFile, cam: &Camera) -> Result<Vec<[u8; 4]>, ThumbnailError> {
    let nodes = lod.nodes();
    let mut errors: Vec<f32> = nodes
        .iter()
        .map(|n| n.lod_error)
        .filter(|e| e.is_finite())
        .collect();
    errors.sort_by(f32::total_cmp);
    errors.dedup();
    let tris = |e: f32| -> u64 {
        cut_uniform(nodes, e)
            .iter()
            .map(|&i| nodes[i as usize].triangle_count as u64)
            .sum()
    };
    let (mut lo, mut hi) = (0usize, errors.len().saturating_sub(1));
    while lo < hi {
        let mid = (lo + hi) / 2;
        if tris(errors[mid]) <= CPU_TRIANGLES {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    let threshold = errors.get(lo).copied().unwrap_or(0.0);
    let (w, h) = (WIDTH as usize, HEIGHT as usize);
    let mut color = vec![[0u8; 4]; w * h];
    let mut depth = vec![f32::INFINITY; w * h];
    let (forward, _, _) = cam.basis();
    for node in cut_uniform(nodes, threshold) {
        let p = lod
            .patch(node)
            .map_err(|e| ThumbnailError::Render(e.to_string()))?;
        let projected: Vec<Option<(f32, f32, f32)>> = p
            .positions
            .iter()
            .map(|&q| cam.project(Vec3::from(q)))
            .collect();
        for t in p.indices.chunks_exact(3) {
            let ix = [t[0] as usize, t[1] as usize, t[2] as usize];
            let (Some(a), Some(b), Some(c)) = (
                projected.get(ix[0]).copied().flatten(),
                projected.get(ix[1]).copied().flatten(),
                projected.get(ix[2]).copied().flatten(),
            ) else {
                continue;
            };
            let world = ix.map(|i| Vec3::from(p.positions[i]));
            let n = (world[1] - world[0])
                .cross(world[2] - world[0])
                .normalize_or_zero();
            let shade = 0.25 + 0.75 * n.dot(-forward).abs();
            let base = if p.colors.is_empty() {
                [209.0, 204.0, 194.0]
            } else {
                let c = ix.map(|i| p.colors[i]);
                std::array::from_fn(|k| (c[0][k] as f32 + c[1][k] as f32 + c[2][k] as f32) / 3.0)
            };
            let rgba = [
                (base[0] * shade) as u8,
                (base[1] * shade) as u8,
                (base[2] * shade) as u8,
                255,
            ];
            fill(&mut color, &mut depth, w, h, [a, b, c], rgba);
        }
    }
    Ok(color)
}

fn fill(
    color: &mut [[u8; 4]],
    depth: &mut [f32],
    w: usize,
    h: usize,
    v: [(f32, f32, f32); 3],
    rgba: [u8; 4],
) {
    let area = (v[1].0 - v[0].0) * (v[2].1 - v[0].1) - (v[2].0 - v[0].0) * (v[1].1 - v[0].1);
    if area.abs() < 1e-12 || !area.is_finite() {
        return;
    }
    let min_x = v.iter().map(|p| p.0).fold(f32::INFINITY, f32::min).max(0.0) as usize;
    let max_x = v
        .iter()
        .map(|p| p.0)
        .fold(f32::NEG_INFINITY, f32::max)
        .min(w as f32 - 1.0);
    let min_y = v.iter().map(|p| p.1).fold(f32::INFINITY, f32::min).max(0.0) as usize;
    let max_y = v
        .iter()
        .map(|p| p.1)
        .fold(f32::NEG_INFINITY, f32::max)
        .min(h as f32 - 1.0);
    if max_x < 0.0 || max_y < 0.0 {
        return;
    }
    for y in min_y..=max_y as usize {
        for x in min_x..=max_x as usize {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            let edge = |a: (f32, f32, f32), b: (f32, f32, f32)| {
                (b.0 - a.0) * (py - a.1) - (px - a.0) * (b.1 - a.1)
            };
            let w0 = edge(v[1], v[2]) / area;
            let w1 = edge(v[2], v[0]) / area;
            let w2 = edge(v[0], v[1]) / area;
            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                continue;
            }
            let z = w0 * v[0].2 + w1 * v[1].2 + w2 * v[2].2;
            let i = y * w + x;
            if z < depth[i] {
                depth[i] = z;
                color[i] = rgba;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meshwiki_engine::lod::{BuildOptions, build_mesh};
    use meshwiki_engine::mesh::{Mesh, synth::Relief};
    use meshwiki_engine::progress::NoProgress;

    #[test]
    fn cpu_fallback_draws_the_model() {
        let mut mesh = Mesh::default();
        Relief::new(5_000, 1).stream(&mut mesh).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.mwlod");
        let options = BuildOptions {
            max_patch_triangles: 256,
            memory_budget: 64 << 20,
            threads: Some(1),
            ..BuildOptions::default()
        };
        build_mesh(&mesh, &path, &options, &NoProgress).unwrap();
        let lod = LodFile::open(&path).unwrap();
        let cam = camera(&lod);
        let px = rasterize(&lod, &cam).unwrap();
        let covered = px.iter().filter(|p| p[3] == 255).count();
        assert!(covered > px.len() / 10, "covered {covered}");
    }
}
