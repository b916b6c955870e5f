//! Fragment quality by feature density (issue 11, item 3), after the scale-space TexMesh paper
//! (`004_28b2044bb56fb245.txt`, §2–3): "minor variations in texture can be ignored in
//! relatively smooth regions of a 3D surface, without significantly affecting human
//! perception", so each texture fragment gets a JPEG quality that follows the number of
//! feature points it holds.
//!
//! A fragment here is a patch's atlas ([`super::atlas`]); the scale `S_i` is the patch's level,
//! whose texel and edge sizes follow its error, so the viewer's budget, which picks the cut,
//! picks the scale, as §3 has it ("depending on the viewing distance, the corresponding `S_i`
//! and `Q_i` are selected").
//!
//! - **Surface features** ([`surface_features`]): §2's Laplacian-of-Gaussian zero crossings, on
//!   the patch's own surface. The LoG of the surface is the umbrella operator's offset of each
//!   vertex along its normal (in units of the patch's mean edge, so it reads alike at every
//!   level), smoothed once over the one-ring (the Gaussian); a vertex is a feature point where
//!   that response changes sign towards a neighbour by more than [`SURFACE_CONTRAST`] (Marr and
//!   Hildreth's strength test: scanner noise crosses zero too, but weakly). Patch-border
//!   vertices, whose one-ring is cut, are not counted.
//! - **Texture features** ([`texture_features`]): the same on the atlas' luminance, the LoG
//!   approximated by a difference of Gaussians (σ 1 and 1.6 texels, separable), zero crossings
//!   between covered texels stronger than [`TEXTURE_CONTRAST`]. Only texels inside the atlas'
//!   triangles count (the gutter and background are filler).
//! - **Quality** ([`qualities`]): per level, each density is normalised as §3's
//!   `n#F = (#F − #F_min) / (#F_max − #F_min)` (over the 5th–95th percentiles rather than the
//!   extremes, so one odd patch does not flatten the rest), the surface and texture values are
//!   averaged, and `Q = Q_i + (n#F − Γ) ΔQ` with `Γ` the level's mean `n#F`: the mean quality
//!   stays `Q_i` while featured fragments get more and plain ones less. `ΔQ = 0` is uniform
//!   quality. `meshwiki-bench textures` compares the two at equal bytes.

use super::patch::{edge_ends, edge_runs};
use crate::mesh::Texture;
use glam::Vec3;
use std::borrow::Cow;

/// Smallest change of the surface LoG response (in mean edges) across a zero crossing for it
/// to count as a feature point.
pub const SURFACE_CONTRAST: f32 = 0.08;
/// Smallest change of the luminance DoG (in 8-bit levels) across a zero crossing for it to
/// count as a texture feature.
pub const TEXTURE_CONTRAST: f32 = 2.0;

/// A fragment's feature densities.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Features {
    /// Surface feature points per interior vertex.
    pub surface: f32,
    /// Texture zero crossings per covered texel.
    pub texture: f32,
    /// Texels inside the atlas' triangles ([`coverage`]).
    pub covered_texels: u64,
}

/// Both densities of a patch and its atlas, and the atlas' covered texels: `covered` where
/// the bake that made the atlas knows them (its texels sampled from the surface, row by row,
/// [`super::atlas::PatchTexture::covered`]), else found from `uvs` ([`coverage`]).
pub fn features(
    positions: &[[f32; 3]],
    indices: &[u32],
    image: &Texture,
    uvs: &[[f32; 2]],
    covered: Option<&[bool]>,
) -> Features {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let covered = covered_or_found(covered.unwrap_or_default(), w, h, uvs);
    let (texture, covered_texels) = texture_density(image, &covered);
    Features {
        surface: surface_features(positions, indices),
        texture,
        covered_texels,
    }
}

/// Surface feature points per interior vertex (module docs).
pub fn surface_features(positions: &[[f32; 3]], indices: &[u32]) -> f32 {
    let n = positions.len();
    if n == 0 || indices.len() < 3 {
        return 0.0;
    }
    if indices.iter().any(|&i| i as usize >= n) {
        return 0.0;
    }
    let p = |i: u32| Vec3::from(positions[i as usize]);
    let mut normals = vec![Vec3::ZERO; n];
    for t in indices.chunks_exact(3) {
        let face = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
        for &v in t {
            normals[v as usize] += face;
        }
    }
    // Undirected edges with their use counts (one use marks the border), in key order; each
    // vertex's one-ring in that order, packed (`ring[start[v]..start[v + 1]]`).
    let edges: Vec<(u64, u32)> = edge_runs(indices, n, false)
        .into_iter()
        .filter(|&(key, _)| {
            let (a, b) = edge_ends(key);
            a != b
        })
        .collect();
    let mut start = vec![0u32; n + 1];
    for &(key, _) in &edges {
        let (a, b) = edge_ends(key);
        start[a as usize + 1] += 1;
        start[b as usize + 1] += 1;
    }
    for v in 0..n {
        start[v + 1] += start[v];
    }
    let mut ring = vec![0u32; start[n] as usize];
    let mut fill = start.clone();
    let mut border = vec![false; n];
    let mut edge_length = 0.0f64;
    for &(key, uses) in &edges {
        let (a, b) = edge_ends(key);
        if uses == 1 {
            border[a as usize] = true;
            border[b as usize] = true;
        }
        ring[fill[a as usize] as usize] = b;
        fill[a as usize] += 1;
        ring[fill[b as usize] as usize] = a;
        fill[b as usize] += 1;
        edge_length += f64::from(p(a).distance(p(b)));
    }
    let unique = edges.len();
    let adjacency = |v: usize| &ring[start[v] as usize..start[v + 1] as usize];
    let h = (edge_length / unique.max(1) as f64) as f32;
    if h <= 0.0 || !h.is_finite() {
        return 0.0;
    }
    // LoG at the patch's own scale: the umbrella offset along the normal, in mean edges...
    let umbrella: Vec<f32> = (0..n)
        .map(|v| {
            let ring = adjacency(v);
            if ring.is_empty() {
                return 0.0;
            }
            let mean = ring.iter().map(|&u| p(u)).sum::<Vec3>() / ring.len() as f32;
            (mean - Vec3::from(positions[v])).dot(normals[v].normalize_or_zero()) / h
        })
        .collect();
    // ... then Gaussian-smoothed over the one-ring.
    let response: Vec<f32> = (0..n)
        .map(|v| {
            let ring = adjacency(v);
            (umbrella[v] + ring.iter().map(|&u| umbrella[u as usize]).sum::<f32>())
                / (1 + ring.len()) as f32
        })
        .collect();
    let mut interior = 0usize;
    let mut crossings = 0usize;
    for v in 0..n {
        if border[v] || adjacency(v).is_empty() {
            continue;
        }
        interior += 1;
        let r = response[v];
        // One feature point per crossing: the vertex on its stronger side.
        if adjacency(v).iter().any(|&u| {
            let q = response[u as usize];
            r * q < 0.0 && (r - q).abs() > SURFACE_CONTRAST && r.abs() >= q.abs()
        }) {
            crossings += 1;
        }
    }
    crossings as f32 / interior.max(1) as f32
}

/// The covered texels of a `w × h` atlas: `covered` where it is that atlas' record (the
/// bake's, [`super::atlas::PatchTexture::covered`]), else found from the corners' `uvs`
/// ([`coverage`]).
pub fn covered_or_found<'a>(
    covered: &'a [bool],
    w: usize,
    h: usize,
    uvs: &[[f32; 2]],
) -> Cow<'a, [bool]> {
    if covered.len() == w * h {
        Cow::Borrowed(covered)
    } else {
        Cow::Owned(coverage(w, h, uvs))
    }
}

/// Texture zero crossings per covered texel (module docs).
pub fn texture_features(image: &Texture, uvs: &[[f32; 2]]) -> f32 {
    let covered = coverage(image.width() as usize, image.height() as usize, uvs);
    texture_density(image, &covered).0
}

/// [`texture_features`] over the texels `covered`, and their number.
fn texture_density(image: &Texture, covered: &[bool]) -> (f32, u64) {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w == 0 || h == 0 || covered.len() != w * h {
        return (0.0, 0);
    }
    let luma = luminance(image.texels());
    let fine = blur(&luma, w, h, 1.0);
    let coarse = blur(&luma, w, h, 1.6);
    let dog: Vec<f32> = fine.iter().zip(&coarse).map(|(a, b)| a - b).collect();
    let mut count = 0usize;
    let mut crossings = 0usize;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if !covered[i] {
                continue;
            }
            count += 1;
            let r = dog[i];
            let crosses = |j: usize| {
                let q = dog[j];
                covered[j] && r * q < 0.0 && (r - q).abs() > TEXTURE_CONTRAST
            };
            if (x + 1 < w && crosses(i + 1)) || (y + 1 < h && crosses(i + w)) {
                crossings += 1;
            }
        }
    }
    (crossings as f32 / count.max(1) as f32, count as u64)
}

/// Texels whose centre lies in one of the triangles of `uvs` (three corners a triangle, in
/// [0, 1], `v = 0` at the top row), plus each triangle's centroid texel.
pub fn coverage(w: usize, h: usize, uvs: &[[f32; 2]]) -> Vec<bool> {
    let mut covered = vec![false; w * h];
    for t in uvs.chunks_exact(3) {
        let c: [[f32; 2]; 3] = std::array::from_fn(|k| [t[k][0] * w as f32, t[k][1] * h as f32]);
        let centroid = [
            (c[0][0] + c[1][0] + c[2][0]) / 3.0,
            (c[0][1] + c[1][1] + c[2][1]) / 3.0,
        ];
        if let Some(i) = texel_at(centroid, w, h) {
            covered[i] = true;
        }
        let area = edge(c[0], c[1], c[2]);
        if area == 0.0 || !area.is_finite() {
            continue;
        }
        let lo = |k: usize| c.iter().map(|p| p[k]).fold(f32::INFINITY, f32::min);
        let hi = |k: usize| c.iter().map(|p| p[k]).fold(f32::NEG_INFINITY, f32::max);
        let x0 = (lo(0).floor().max(0.0)) as usize;
        let y0 = (lo(1).floor().max(0.0)) as usize;
        let x1 = (hi(0).ceil().max(0.0) as usize).min(w);
        let y1 = (hi(1).ceil().max(0.0) as usize).min(h);
        for y in y0..y1 {
            for x in x0..x1 {
                let q = [x as f32 + 0.5, y as f32 + 0.5];
                let s = area.signum();
                if edge(c[0], c[1], q) * s >= 0.0
                    && edge(c[1], c[2], q) * s >= 0.0
                    && edge(c[2], c[0], q) * s >= 0.0
                {
                    covered[y * w + x] = true;
                }
            }
        }
    }
    covered
}

fn texel_at(p: [f32; 2], w: usize, h: usize) -> Option<usize> {
    (p[0] >= 0.0 && p[1] >= 0.0 && p[0].is_finite() && p[1].is_finite())
        .then(|| (p[0] as usize, p[1] as usize))
        .filter(|&(x, y)| x < w && y < h)
        .map(|(x, y)| y * w + x)
}

fn edge(a: [f32; 2], b: [f32; 2], c: [f32; 2]) -> f32 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Separable Gaussian blur of σ texels, edges clamped (rows through a padded copy, columns
/// as whole-row multiply-adds, so both passes run over contiguous memory).
fn blur(src: &[f32], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as usize;
    let kernel: Vec<f32> = (0..=2 * r)
        .map(|i| {
            let d = i as f32 - r as f32;
            (-(d * d) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let total: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
    let mut rows = vec![0.0f32; w * h];
    let mut padded = vec![0.0f32; w + 2 * r];
    for (line, out) in src.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        padded[..r].fill(line[0]);
        padded[r..r + w].copy_from_slice(line);
        padded[r + w..].fill(line[w - 1]);
        for (x, o) in out.iter_mut().enumerate() {
            *o = padded[x..=x + 2 * r]
                .iter()
                .zip(&kernel)
                .map(|(a, g)| a * g)
                .sum();
        }
    }
    let mut out = vec![0.0f32; w * h];
    for (y, dst) in out.chunks_exact_mut(w).enumerate() {
        for (k, &g) in kernel.iter().enumerate() {
            let sy = (y + k).saturating_sub(r).min(h - 1);
            for (d, s) in dst.iter_mut().zip(&rows[sy * w..(sy + 1) * w]) {
                *d += g * s;
            }
        }
    }
    out
}

/// Luminance of 8-bit RGB texels.
fn luminance(texels: &[[u8; 4]]) -> Vec<f32> {
    texels
        .iter()
        .map(|c| 0.299 * f32::from(c[0]) + 0.587 * f32::from(c[1]) + 0.114 * f32::from(c[2]))
        .collect()
}

/// A texel's squared error over its colour channels (alpha left out): what the build's atlas
/// measure and the WebP match ([`super::webp_match`]) sum over the covered texels.
#[inline]
pub fn rgb_squared_error(a: [u8; 4], b: [u8; 4]) -> f64 {
    (0..3)
        .map(|k| {
            let d = f64::from(a[k]) - f64::from(b[k]);
            d * d
        })
        .sum()
}

/// Structural similarity (Wang et al. 2004: Gaussian window of σ 1.5, `K1 = 0.01`,
/// `K2 = 0.03`) of two images' luminance, per texel: how the build measures what a JPEG
/// quality costs a fragment beside its PSNR. `None` when the sizes differ.
pub fn ssim_map(a: &Texture, b: &Texture) -> Option<Vec<f32>> {
    if (a.width(), a.height()) != (b.width(), b.height()) {
        return None;
    }
    let (w, h) = (a.width() as usize, a.height() as usize);
    let (x, y) = (luminance(a.texels()), luminance(b.texels()));
    let product =
        |p: &[f32], q: &[f32]| -> Vec<f32> { p.iter().zip(q).map(|(u, v)| u * v).collect() };
    let mx = blur(&x, w, h, 1.5);
    let my = blur(&y, w, h, 1.5);
    let sxx = blur(&product(&x, &x), w, h, 1.5);
    let syy = blur(&product(&y, &y), w, h, 1.5);
    let sxy = blur(&product(&x, &y), w, h, 1.5);
    let (c1, c2) = ((0.01f32 * 255.0).powi(2), (0.03f32 * 255.0).powi(2));
    Some(
        (0..w * h)
            .map(|i| {
                let (ux, uy) = (mx[i], my[i]);
                let vx = sxx[i] - ux * ux;
                let vy = syy[i] - uy * uy;
                let cov = sxy[i] - ux * uy;
                ((2.0 * ux * uy + c1) * (2.0 * cov + c2))
                    / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
            })
            .collect(),
    )
}

/// A fragment's normalised feature value `n#F` in [0, 1] among the fragments of its level
/// (module docs), and that level's mean `Γ`.
pub fn normalised(levels: &[u32], features: &[Features]) -> (Vec<f32>, Vec<f32>) {
    let mut n = vec![0.0f32; features.len()];
    let mut gamma = vec![0.0f32; features.len()];
    let top = levels.iter().copied().max().map_or(0, |l| l as usize + 1);
    let mut by_level: Vec<Vec<usize>> = vec![Vec::new(); top];
    for (i, &l) in levels.iter().enumerate() {
        by_level[l as usize].push(i);
    }
    for members in by_level.iter().filter(|m| !m.is_empty()) {
        let spread = |value: fn(&Features) -> f32| {
            let mut v: Vec<f32> = members.iter().map(|&i| value(&features[i])).collect();
            v.sort_unstable_by(f32::total_cmp);
            let at = |q: f32| v[((v.len() - 1) as f32 * q).round() as usize];
            (at(0.05), at(0.95))
        };
        let (s_lo, s_hi) = spread(|f| f.surface);
        let (t_lo, t_hi) = spread(|f| f.texture);
        let unit = |x: f32, lo: f32, hi: f32| {
            if hi > lo {
                ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
            } else {
                0.5
            }
        };
        let mut sum = 0.0f32;
        for &i in members {
            let f = &features[i];
            n[i] = 0.5 * (unit(f.surface, s_lo, s_hi) + unit(f.texture, t_lo, t_hi));
            sum += n[i];
        }
        let mean = sum / members.len() as f32;
        for &i in members {
            gamma[i] = mean;
        }
    }
    (n, gamma)
}

/// A fragment's JPEG quality: `Q = base + (n#F − Γ) · spread` (§3), within 5–100.
pub fn quality(n: f32, gamma: f32, base: u8, spread: u8) -> u8 {
    let q = f32::from(base) + (n - gamma) * f32::from(spread);
    q.round().clamp(5.0, 100.0) as u8
}

/// Every fragment's [`quality`].
pub fn qualities(levels: &[u32], features: &[Features], base: u8, spread: u8) -> Vec<u8> {
    let (n, gamma) = normalised(levels, features);
    n.iter()
        .zip(&gamma)
        .map(|(&n, &g)| quality(n, g, base, spread))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(k: usize, height: impl Fn(f32, f32) -> f32) -> (Vec<[f32; 3]>, Vec<u32>) {
        super::super::height_grid(k, 1.0, height)
    }

    #[test]
    fn a_plane_has_no_surface_features_and_ridges_do() {
        let (p, i) = grid(24, |_, _| 0.0);
        assert_eq!(surface_features(&p, &i), 0.0);
        // A tilted plane neither.
        let (p, i) = grid(24, |x, y| 0.3 * x - 0.2 * y);
        assert_eq!(surface_features(&p, &i), 0.0);
        // Ridges every 4 edges: a zero crossing on each flank.
        let (p, i) = grid(24, |x, _| (x * std::f32::consts::FRAC_PI_2).sin() * 1.5);
        let d = surface_features(&p, &i);
        assert!(d > 0.2, "ridged density {d}");
        // Gentler, wider waves have fewer feature points.
        let (p, i) = grid(24, |x, _| (x * std::f32::consts::PI / 6.0).sin() * 1.5);
        let wide = surface_features(&p, &i);
        assert!(wide < d, "wide waves {wide} against ridges {d}");
    }

    fn quad_uvs() -> Vec<[f32; 2]> {
        vec![
            [0.0, 0.0],
            [1.0, 0.0],
            [1.0, 1.0],
            [0.0, 0.0],
            [1.0, 1.0],
            [0.0, 1.0],
        ]
    }

    #[test]
    fn flat_texture_has_no_features_and_detail_does() {
        let flat = Texture::from_texels(32, 32, vec![[120, 90, 60, 255]; 32 * 32]).expect("size");
        assert_eq!(texture_features(&flat, &quad_uvs()), 0.0);
        let checker: Vec<[u8; 4]> = (0..32 * 32)
            .map(|i| {
                let (x, y) = (i % 32, i / 32);
                if (x / 2 + y / 2) % 2 == 0 {
                    [200, 200, 200, 255]
                } else {
                    [40, 40, 40, 255]
                }
            })
            .collect();
        let checker = Texture::from_texels(32, 32, checker).expect("size");
        let d = texture_features(&checker, &quad_uvs());
        assert!(d > 0.3, "checker density {d}");
        // The same detail outside every triangle does not count.
        let corner = vec![[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]];
        assert!(texture_features(&checker, &corner) < d);
    }

    #[test]
    fn ssim_is_one_for_the_same_image_and_falls_with_noise() {
        let texels: Vec<[u8; 4]> = (0..32 * 32)
            .map(|i| {
                let v = ((i % 32) * 7 + (i / 32) * 3) as u8;
                [v, v / 2, 255 - v, 255]
            })
            .collect();
        let a = Texture::from_texels(32, 32, texels.clone()).expect("size");
        let same = ssim_map(&a, &a).expect("same size");
        assert!(same.iter().all(|&s| (s - 1.0).abs() < 1e-4));
        let noisy: Vec<[u8; 4]> = texels
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let n = if (i * 7919) % 13 < 6 { 20 } else { 0 };
                [c[0].saturating_add(n), c[1].saturating_add(n), c[2], 255]
            })
            .collect();
        let b = Texture::from_texels(32, 32, noisy).expect("size");
        let mean = ssim_map(&a, &b).expect("same size").iter().sum::<f32>() / 1024.0;
        assert!(mean < 0.95 && mean > 0.0, "{mean}");
        let small = Texture::from_texels(16, 16, vec![[0; 4]; 256]).expect("size");
        assert!(ssim_map(&a, &small).is_none());
    }

    #[test]
    fn blur_keeps_constants_and_mass_and_matches_a_direct_convolution() {
        let (w, h) = (13, 9);
        let flat = vec![7.0f32; w * h];
        assert!(
            blur(&flat, w, h, 1.6)
                .iter()
                .all(|&v| (v - 7.0).abs() < 1e-4)
        );
        // A point far from the edges spreads into a normalised Gaussian.
        let mut point = vec![0.0f32; w * h];
        point[4 * w + 6] = 1.0;
        let b = blur(&point, w, h, 1.0);
        assert!((b.iter().sum::<f32>() - 1.0).abs() < 1e-4);
        let g = |d: f32| (-(d * d) / 2.0).exp();
        let norm: f32 = (-3..=3).map(|i| g(i as f32)).sum();
        assert!((b[4 * w + 6] - 1.0 / (norm * norm)).abs() < 1e-5);
        assert!((b[5 * w + 8] - g(1.0) * g(2.0) / (norm * norm)).abs() < 1e-5);
        // Edges clamp: a ramp stays monotonic and inside its range.
        let ramp: Vec<f32> = (0..w * h).map(|i| (i % w) as f32).collect();
        let b = blur(&ramp, w, h, 1.6);
        for row in b.chunks_exact(w) {
            assert!(row.windows(2).all(|p| p[0] <= p[1] + 1e-5));
            assert!(row[0] >= 0.0 && row[w - 1] <= (w - 1) as f32);
        }
    }

    #[test]
    fn coverage_takes_texels_inside_triangles_and_every_centroid() {
        let c = coverage(8, 8, &quad_uvs());
        assert!(c.iter().all(|&b| b));
        let c = coverage(8, 8, &[[0.0, 0.0], [0.5, 0.0], [0.0, 0.5]]);
        assert!(c[0] && c[1] && c[8] && !c[63]);
        // A sliver thinner than a texel still owns its centroid's texel.
        let c = coverage(8, 8, &[[0.5, 0.5], [0.52, 0.5], [0.51, 0.51]]);
        assert_eq!(c.iter().filter(|&&b| b).count(), 1);
        // Degenerate and out-of-range corners never panic.
        let c = coverage(8, 8, &[[f32::NAN, 0.0], [9.0, -3.0], [1e30, 1e30]]);
        assert!(c.iter().all(|&b| !b));
    }

    #[test]
    fn qualities_follow_features_per_level_around_the_base() {
        let f = |s: f32, t: f32| Features {
            surface: s,
            texture: t,
            ..Features::default()
        };
        let levels = [0, 0, 0, 1, 1];
        let features = [
            f(0.0, 0.0),
            f(0.5, 0.5),
            f(1.0, 1.0),
            f(0.2, 0.2),
            f(0.2, 0.2),
        ];
        let q = qualities(&levels, &features, 80, 20);
        assert!(q[0] < q[1] && q[1] < q[2], "{q:?}");
        assert_eq!(q[1], 80);
        assert_eq!((q[0], q[2]), (70, 90));
        // A level whose fragments are alike stays at the base quality.
        assert_eq!((q[3], q[4]), (80, 80));
        // No spread: uniform.
        assert!(
            qualities(&levels, &features, 80, 0)
                .iter()
                .all(|&q| q == 80)
        );
    }
}
