//! Pixel-mask geometry for the simulated users ([`super::strokes`]): exact Euclidean distance
//! transforms (Felzenszwalb & Huttenlocher, "Distance Transforms of Sampled Functions", 2012),
//! signed distance to an outline, connected components and hole filling.

use meshwiki_engine::select::seeds::outside_of;

/// One-dimensional squared distance transform (Felzenszwalb & Huttenlocher 2012): the lower
/// envelope of the parabolas rooted at the finite samples of `f`.
fn edt_1d(f: &[f64], out: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let mut k: Option<usize> = None;
    for (q, &fq) in f.iter().enumerate() {
        if !fq.is_finite() {
            continue;
        }
        loop {
            let Some(top) = k else {
                k = Some(0);
                v[0] = q;
                z[0] = f64::NEG_INFINITY;
                z[1] = f64::INFINITY;
                break;
            };
            let p = v[top];
            let s = ((fq + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q - p) as f64);
            if s <= z[top] {
                k = top.checked_sub(1);
                continue;
            }
            v[top + 1] = q;
            z[top + 1] = s;
            z[top + 2] = f64::INFINITY;
            k = Some(top + 1);
            break;
        }
    }
    if k.is_none() {
        out.fill(f64::INFINITY);
        return;
    }
    let mut j = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[j + 1] < q as f64 {
            j += 1;
        }
        let d = q as f64 - v[j] as f64;
        *o = d * d + f[v[j]];
    }
}

/// Squared Euclidean distance from every pixel to the nearest pixel where `feature` holds
/// (infinite when there is none).
pub fn distance_sq(feature: &[bool], w: usize, h: usize) -> Vec<f32> {
    let mut d: Vec<f64> = feature
        .iter()
        .map(|&f| if f { 0.0 } else { f64::INFINITY })
        .collect();
    let n = w.max(h);
    let (mut f, mut out) = (vec![0f64; n], vec![0f64; n]);
    let (mut v, mut z) = (vec![0usize; n + 1], vec![0f64; n + 2]);
    for x in 0..w {
        for y in 0..h {
            f[y] = d[y * w + x];
        }
        edt_1d(&f[..h], &mut out[..h], &mut v, &mut z);
        for y in 0..h {
            d[y * w + x] = out[y];
        }
    }
    for y in 0..h {
        f[..w].copy_from_slice(&d[y * w..(y + 1) * w]);
        edt_1d(&f[..w], &mut out[..w], &mut v, &mut z);
        d[y * w..(y + 1) * w].copy_from_slice(&out[..w]);
    }
    d.into_iter().map(|x| x as f32).collect()
}

/// Signed distance to the outline of `inside`: positive inside, negative outside, the
/// outline (between pixel centres) at 0.
pub fn signed_distance(inside: &[bool], w: usize, h: usize) -> Vec<f32> {
    let outside: Vec<bool> = inside.iter().map(|&b| !b).collect();
    let to_out = distance_sq(&outside, w, h);
    let to_in = distance_sq(inside, w, h);
    inside
        .iter()
        .enumerate()
        .map(|(i, &b)| {
            if b {
                to_out[i].sqrt() - 0.5
            } else {
                -(to_in[i].sqrt() - 0.5)
            }
        })
        .collect()
}

/// 8-connected components of `mask`: a label per pixel (`u32::MAX` outside) and the sizes.
pub fn components(mask: &[bool], w: usize, h: usize) -> (Vec<u32>, Vec<usize>) {
    let mut label = vec![u32::MAX; mask.len()];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    for s in 0..mask.len() {
        if !mask[s] || label[s] != u32::MAX {
            continue;
        }
        let c = sizes.len() as u32;
        let mut size = 0usize;
        label[s] = c;
        stack.push(s);
        while let Some(i) = stack.pop() {
            size += 1;
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                        continue;
                    }
                    let j = ny as usize * w + nx as usize;
                    if mask[j] && label[j] == u32::MAX {
                        label[j] = c;
                        stack.push(j);
                    }
                }
            }
        }
        sizes.push(size);
    }
    (label, sizes)
}

/// `region` with its holes filled: every pixel the image border cannot reach (4-connected)
/// through pixels outside `region`.
pub fn fill_holes(region: &[bool], w: usize, h: usize) -> Vec<bool> {
    outside_of(region, w, h).iter().map(|&r| !r).collect()
}

/// The components of `mask` holding at least `keep` pixels of `count`.
pub fn large_components(
    mask: &[bool],
    count: &[bool],
    keep: usize,
    w: usize,
    h: usize,
) -> Vec<bool> {
    let (label, sizes) = components(mask, w, h);
    let mut weight = vec![0usize; sizes.len()];
    for (i, &l) in label.iter().enumerate() {
        if l != u32::MAX && count[i] {
            weight[l as usize] += 1;
        }
    }
    label
        .iter()
        .map(|&l| l != u32::MAX && weight[l as usize] >= keep)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_transform_is_euclidean() {
        let (w, h) = (9, 7);
        let mut f = vec![false; w * h];
        f[3 * w + 4] = true;
        let d = distance_sq(&f, w, h);
        for y in 0..h {
            for x in 0..w {
                let e = (x as f32 - 4.0).powi(2) + (y as f32 - 3.0).powi(2);
                assert_eq!(d[y * w + x], e, "({x}, {y})");
            }
        }
    }
}
