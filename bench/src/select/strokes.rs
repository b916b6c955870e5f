//! Simulated users of the three selection tools (system paper §4.2 and §4.3's usability
//! study, replayed by a program): from the on-screen mask of a ground-truth region they draw
//!
//! - a **heavy lasso**: a band of fixed width centred on the region's outline, displaced by a
//!   smooth random jitter (the hand's wobble);
//! - a **lasso**: the polygon following the same jittered outline, its inside filled;
//! - a **markup**: a few foreground strokes well inside the region and a few background
//!   strokes on the surface around it (Lazy Snapping's markers), kept away from the outline.
//!
//! Where the region borders the background (a silhouette) the strokes pass a little outside
//! it, as a user does where nothing else could be caught; holes in the outline (other
//! surface seen through the region) get a second, subtracting stroke of the same tool.
//! The outline is the zero level of the region's signed distance field; the jitter is a sum of
//! plane waves (wavelengths 60–240 px), so the outline is displaced along its normal by a
//! smooth function of position whose RMS is `jitter / √2` — a sine of amplitude `jitter`.
//! The lasso and the heavy lasso of a region share one jitter, so their errors are paired.
//! Everything is deterministic given the seed.

use meshwiki_engine::select::mask;

use super::raster::{distance_sq, fill_holes, large_components, signed_distance};

/// SplitMix64: a small, seedable, deterministic generator.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator for `seed` and a stream number (a region, a tool).
    pub fn new(seed: u64, stream: u64) -> Rng {
        let mut r = Rng(seed ^ stream.wrapping_mul(0xA24B_AED4_963E_E407));
        r.next_u64();
        r
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[a, b)`.
    pub fn range(&mut self, a: f32, b: f32) -> f32 {
        a + (b - a) * self.unit()
    }

    /// Uniform index below `n` (`n > 0`).
    pub fn index(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

/// A smooth random displacement field over the image.
#[derive(Debug, Clone)]
pub struct Jitter {
    /// `(kx, ky, phase)` of each plane wave.
    waves: Vec<(f32, f32, f32)>,
    scale: f32,
}

impl Jitter {
    /// Plane waves of the hand's wobble.
    const WAVES: usize = 8;

    /// A field of amplitude `amplitude` pixels (0: no jitter).
    pub fn new(rng: &mut Rng, amplitude: f32) -> Jitter {
        let waves = (0..Self::WAVES)
            .map(|_| {
                let lambda = rng.range(60.0, 240.0);
                let angle = rng.range(0.0, std::f32::consts::TAU);
                let k = std::f32::consts::TAU / lambda;
                (
                    k * angle.cos(),
                    k * angle.sin(),
                    rng.range(0.0, std::f32::consts::TAU),
                )
            })
            .collect();
        Jitter {
            waves,
            scale: amplitude / (Self::WAVES as f32).sqrt(),
        }
    }

    /// Displacement at pixel centre `(x, y)`, in pixels.
    pub fn at(&self, x: f32, y: f32) -> f32 {
        self.scale
            * self
                .waves
                .iter()
                .map(|&(kx, ky, p)| (kx * x + ky * y + p).sin())
                .sum::<f32>()
    }
}

/// What a user traces: the region's on-screen mask with its holes filled (one stroke follows
/// an outer outline) and without specks (components under 2 % of it, or under 50 pixels,
/// that no one would circle); and the holes worth a second, subtracting stroke (those with as
/// many pixels of surface).
pub fn traced_outline(
    region: &[bool],
    covered: &[bool],
    w: usize,
    h: usize,
) -> (Vec<bool>, Vec<bool>) {
    let filled = fill_holes(region, w, h);
    let total = region.iter().filter(|&&b| b).count();
    let keep = (total / 50).max(50);
    let outline = large_components(&filled, &filled, keep, w, h);
    let holes: Vec<bool> = (0..w * h).map(|i| outline[i] && !region[i]).collect();
    let holes = large_components(&holes, covered, keep, w, h);
    (outline, holes)
}

/// The strokes of one region, ready to be sent (one label per pixel).
#[derive(Debug, Clone)]
pub struct Strokes {
    pub heavy_lasso: Vec<u8>,
    pub lasso: Vec<u8>,
    /// Second strokes around the holes (subtracted), when there are any.
    pub heavy_lasso_holes: Option<Vec<u8>>,
    pub lasso_holes: Option<Vec<u8>>,
    pub markup: Vec<u8>,
    /// Width of the heavy band drawn (narrower than asked around thin regions).
    pub band_px: f32,
    /// Foreground and background pixels of the markup.
    pub markup_fg: usize,
    pub markup_bg: usize,
}

/// Settings of the simulated user.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct UserModel {
    /// Amplitude of the outline's jitter, pixels.
    pub jitter: f32,
    /// Width of the heavy lasso's band, pixels.
    pub band: f32,
    /// Markup: foreground strokes.
    pub fg_strokes: usize,
    /// Markup: background strokes.
    pub bg_strokes: usize,
    /// Markup: stroke length, relative to the default (the square root of the area they are
    /// drawn in, times 0.8, within 20–300 px); under 1, strokes that stop short.
    pub stroke_length: f32,
    /// Markup: how far beyond the region (and the heavy band's outer edge) the background
    /// strokes may lie, pixels.
    pub bg_reach: f32,
}

impl UserModel {
    /// The default user: the given jitter and band, 3 foreground and 6 background strokes of
    /// the default length within 80 px of the region.
    pub fn new(jitter: f32, band: f32) -> UserModel {
        UserModel {
            jitter,
            band,
            fg_strokes: 3,
            bg_strokes: 6,
            stroke_length: 1.0,
            bg_reach: 80.0,
        }
    }
}

/// The heavy band and the lasso along the jittered outline of `inside`, and the band's width.
fn along_outline(
    inside: &[bool],
    jitter: &Jitter,
    user: UserModel,
    w: usize,
    h: usize,
) -> (Vec<u8>, Vec<u8>, f32) {
    let sd = signed_distance(inside, w, h);
    let offset: Vec<f32> = (0..w * h)
        .map(|i| sd[i] + jitter.at((i % w) as f32 + 0.5, (i / w) as f32 + 0.5))
        .collect();
    // A thin part gets a thinner stroke: the band must leave some of the inside enclosed.
    let half_thickness = sd.iter().copied().fold(0.0f32, f32::max);
    let band = user.band.min((half_thickness - user.jitter).max(4.0));
    let heavy = offset
        .iter()
        .map(|&o| {
            if o.abs() < band * 0.5 {
                mask::HEAVY
            } else {
                mask::NONE
            }
        })
        .collect();
    let lasso = offset
        .iter()
        .map(|&o| if o > 0.0 { mask::LASSO } else { mask::NONE })
        .collect();
    (heavy, lasso, band)
}

/// Draws the three tools' strokes for the region mask `region` on a view whose pixels showing
/// the model are `covered`.
pub fn draw(
    region: &[bool],
    covered: &[bool],
    w: usize,
    h: usize,
    user: UserModel,
    rng: &mut Rng,
) -> Strokes {
    // Where the region borders empty background there is nothing to miss: users sweep a
    // little outside the silhouette there (but not onto other surface across a narrow gap).
    let margin = user.band * 0.5 + 2.0 * user.jitter;
    let other: Vec<bool> = (0..w * h).map(|i| covered[i] && !region[i]).collect();
    let to_region = distance_sq(region, w, h);
    let to_other = distance_sq(&other, w, h);
    let swept: Vec<bool> = (0..w * h)
        .map(|i| {
            region[i]
                || (!covered[i] && to_region[i] <= margin * margin && to_other[i] > margin * margin)
        })
        .collect();
    let (traced, holes) = traced_outline(&swept, covered, w, h);
    let jitter = Jitter::new(rng, user.jitter);
    let (heavy_lasso, lasso, band) = along_outline(&traced, &jitter, user, w, h);
    let (heavy_lasso_holes, lasso_holes) = if holes.iter().any(|&b| b) {
        let (hh, lh, _) = along_outline(&holes, &jitter, user, w, h);
        (Some(hh), Some(lh))
    } else {
        (None, None)
    };

    // Markup: keep as far from the outline as the heavy band's inner and outer edges; spread
    // the strokes around the region.
    let away = band * 0.5 + user.jitter;
    let region_sd = signed_distance(region, w, h);
    let mut fg_area: Vec<bool> = region_sd.iter().map(|&d| d > away).collect();
    if !fg_area.iter().any(|&b| b) {
        let deepest = region_sd.iter().copied().fold(0.0f32, f32::max);
        fg_area = region_sd
            .iter()
            .map(|&d| d >= deepest * 0.6 && d > 0.0)
            .collect();
    }
    let near = |d: f32| d < -away && d > -(away + user.bg_reach);
    let mut bg_area: Vec<bool> = (0..w * h)
        .map(|i| covered[i] && near(region_sd[i]))
        .collect();
    if !bg_area.iter().any(|&b| b) {
        bg_area = (0..w * h)
            .map(|i| covered[i] && region_sd[i] < -away)
            .collect();
    }
    let (mut cx, mut cy, mut n) = (0.0f64, 0.0f64, 0usize);
    for (i, _) in region.iter().enumerate().filter(|(_, b)| **b) {
        cx += (i % w) as f64;
        cy += (i / w) as f64;
        n += 1;
    }
    let centre = ((cx / n.max(1) as f64) as f32, (cy / n.max(1) as f64) as f32);
    let mut markup = vec![mask::NONE; w * h];
    let len = |a: &[bool]| {
        ((a.iter().filter(|&&b| b).count() as f32).sqrt() * 0.8).clamp(20.0, 300.0)
            * user.stroke_length
    };
    let (fg_len, bg_len) = (len(&fg_area), len(&bg_area));
    let mut paint = |area: &[bool], label, count, length, rng: &mut Rng| {
        strokes(&mut markup, area, label, count, length, centre, (w, h), rng)
    };
    let markup_fg = paint(
        &fg_area,
        mask::FOREGROUND,
        user.fg_strokes.max(1),
        fg_len,
        rng,
    );
    let markup_bg = paint(
        &bg_area,
        mask::BACKGROUND,
        user.bg_strokes.max(1),
        bg_len,
        rng,
    );
    Strokes {
        heavy_lasso,
        lasso,
        heavy_lasso_holes,
        lasso_holes,
        markup,
        band_px: band,
        markup_fg,
        markup_bg,
    }
}

/// Paints `count` smooth random strokes of about `length` pixels within `area` with `label`
/// (brush radius 2 px), starting in successive angular sectors around `centre`; returns the
/// pixels painted.
#[allow(clippy::too_many_arguments)]
fn strokes(
    out: &mut [u8],
    area: &[bool],
    label: u8,
    count: usize,
    length: f32,
    centre: (f32, f32),
    (w, h): (usize, usize),
    rng: &mut Rng,
) -> usize {
    let pixels: Vec<usize> = (0..area.len()).filter(|&i| area[i]).collect();
    if pixels.is_empty() {
        return 0;
    }
    let sector = |i: usize| {
        let a = ((i / w) as f32 - centre.1).atan2((i % w) as f32 - centre.0);
        let t = (a + std::f32::consts::PI) / std::f32::consts::TAU;
        ((t * count as f32) as usize).min(count - 1)
    };
    let inside = |x: f32, y: f32| {
        x >= 0.0
            && y >= 0.0
            && (x as usize) < w
            && (y as usize) < h
            && area[y as usize * w + x as usize]
    };
    let mut painted = 0;
    let mut paint = |x: f32, y: f32, out: &mut [u8]| {
        for dy in -2i32..=2 {
            for dx in -2i32..=2 {
                if dx * dx + dy * dy > 4 {
                    continue;
                }
                let (px, py) = (x as i32 + dx, y as i32 + dy);
                if px < 0 || py < 0 || px as usize >= w || py as usize >= h {
                    continue;
                }
                let i = py as usize * w + px as usize;
                if area[i] && out[i] != label {
                    out[i] = label;
                    painted += 1;
                }
            }
        }
    };
    const STEP: f32 = 1.5;
    for k in 0..count {
        let in_sector: Vec<usize> = pixels.iter().copied().filter(|&i| sector(i) == k).collect();
        let from = if in_sector.is_empty() {
            &pixels
        } else {
            &in_sector
        };
        let start = from[rng.index(from.len())];
        let (mut x, mut y) = ((start % w) as f32 + 0.5, (start / w) as f32 + 0.5);
        let mut heading = rng.range(0.0, std::f32::consts::TAU);
        let mut travelled = 0.0;
        paint(x, y, out);
        while travelled < length {
            heading += rng.range(-0.25, 0.25);
            let mut moved = false;
            for _ in 0..8 {
                let (nx, ny) = (x + STEP * heading.cos(), y + STEP * heading.sin());
                if inside(nx, ny) {
                    (x, y) = (nx, ny);
                    moved = true;
                    break;
                }
                heading += rng.range(-std::f32::consts::PI, std::f32::consts::PI);
            }
            if !moved {
                break;
            }
            travelled += STEP;
            paint(x, y, out);
        }
    }
    painted
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc(w: usize, h: usize, cx: f32, cy: f32, r: f32) -> Vec<bool> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                (x - cx).powi(2) + (y - cy).powi(2) < r * r
            })
            .collect()
    }

    #[test]
    fn strokes_follow_the_outline() {
        let (w, h) = (200, 160);
        let region = disc(w, h, 100.0, 80.0, 50.0);
        let covered = vec![true; w * h];
        let user = UserModel::new(3.0, 12.0);
        let s = draw(&region, &covered, w, h, user, &mut Rng::new(7, 1));
        assert_eq!(s.band_px, 12.0);
        // The lasso is the disc within the jitter.
        let wrong = (0..w * h)
            .filter(|&i| (s.lasso[i] == mask::LASSO) != region[i])
            .count();
        let perimeter = std::f32::consts::TAU * 50.0;
        assert!((wrong as f32) < perimeter * 4.0, "{wrong}");
        assert!(wrong > 0);
        // The band's centre and the disc's outline agree; the markup stays off the outline.
        let band = s.heavy_lasso.iter().filter(|&&l| l == mask::HEAVY).count() as f32;
        assert!((band - perimeter * 12.0).abs() < perimeter * 3.0, "{band}");
        let sd = signed_distance(&region, w, h);
        for (&label, &d) in s.markup.iter().zip(&sd) {
            match label {
                mask::FOREGROUND => assert!(d > 6.0),
                mask::BACKGROUND => assert!(d < -6.0),
                _ => {}
            }
        }
        assert!(s.markup_fg > 50 && s.markup_bg > 50);
        // Deterministic.
        let again = draw(&region, &covered, w, h, user, &mut Rng::new(7, 1));
        assert_eq!(again.markup, s.markup);
        assert_eq!(again.lasso, s.lasso);
    }

    #[test]
    fn specks_are_not_traced_and_holes_are_filled() {
        let (w, h) = (120, 100);
        let mut region = disc(w, h, 60.0, 50.0, 30.0);
        let hole = disc(w, h, 60.0, 50.0, 8.0);
        for i in 0..w * h {
            region[i] &= !hole[i];
        }
        region[5 * w + 5] = true;
        let covered = vec![true; w * h];
        let (t, holes) = traced_outline(&region, &covered, w, h);
        assert!(t[50 * w + 60] && !t[5 * w + 5]);
        assert!(holes[50 * w + 60] && !holes[50 * w + 40]);
    }
}
