//! Seeds of the three tools (system paper §4.1.1, §4.2):
//!
//! - **markup** (Lazy Snapping): foreground strokes are foreground seeds, background strokes
//!   background seeds; everything else is decided by the cut.
//! - **heavy lasso** (§4.2): one thick closed stroke along the boundary. "Our system
//!   automatically sets a foreground seed and a background seed ... The foreground marker is
//!   drawn along the inside of the heavy marker, and the background marker is drawn along the
//!   outside": band pixels touching the enclosed area become foreground seeds, band pixels
//!   touching the outer area background seeds. What the loop encloses is foreground and what
//!   lies outside background (the markers' own sides: the user traced the boundary there), so
//!   the cut only decides the band. The seed models of the data term are fitted on the two
//!   markers. Each band pixel also gets its position across the band (0 at the inner marker, 1
//!   at the outer) for the band prior ([`super::EnergyParams::band_prior`]).
//! - **lasso**: the conventional tool; the polygon's inside is the selection, no cut.
//!
//! Pixels off the model are left out of the graph.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use super::SelectError;
use super::buffers::Buffers;
use super::mask::{self, StrokeMask};

/// Role of a pixel: decided by the cut.
pub const UNKNOWN: u8 = 0;
/// Role of a pixel: hard foreground.
pub const FG: u8 = 1;
/// Role of a pixel: hard background.
pub const BG: u8 = 2;
/// Role of a pixel: not in the graph (no surface there).
pub const OFF: u8 = 3;

/// Seeds for a cut.
#[derive(Debug, Clone, PartialEq)]
pub struct Seeds {
    pub width: u32,
    pub height: u32,
    /// [`UNKNOWN`], [`FG`], [`BG`] or [`OFF`] per pixel.
    pub role: Vec<u8>,
    /// Marker pixels the foreground / background seed models are fitted on.
    pub fg_samples: Vec<u32>,
    pub bg_samples: Vec<u32>,
    /// Heavy lasso: position across the band per pixel (0 inner marker … 1 outer marker),
    /// NaN outside the band.
    pub band_position: Option<Vec<f32>>,
    /// Markup: relative geodesic distance to the strokes per pixel, `D^F / (D^F + D^B)`
    /// (0 on a foreground stroke … 1 on a background stroke; see [`geodesic_from`]).
    pub stroke_position: Option<Vec<f32>>,
    /// Markup: geodesic distance to the nearest stroke of either side per pixel,
    /// `min(D^F, D^B)` (see [`geodesic_from`]).
    pub stroke_distance: Option<Vec<f32>>,
    /// The stroke segments, when the model has surface segments ([`super::segments`]).
    pub segments: Option<super::segments::SegmentPrior>,
}

impl Seeds {
    /// Pixels the cut decides.
    pub fn unknown_count(&self) -> usize {
        self.role.iter().filter(|&&r| r == UNKNOWN).count()
    }
}

fn check(mask: &StrokeMask, buffers: &Buffers<'_>) -> Result<(), SelectError> {
    if mask.width != buffers.width || mask.height != buffers.height {
        return Err(SelectError::SizeMismatch {
            what: "the stroke mask",
            got_w: mask.width,
            got_h: mask.height,
            width: buffers.width,
            height: buffers.height,
        });
    }
    Ok(())
}

/// How much longer a step across a full normal crease or depth discontinuity is than a step
/// on smooth surface (geodesic stroke distance of markup).
const CREASE_COST: f32 = 120.0;

/// Scale, in pixels, at which normal creases are measured for the stroke distance: a rounded
/// crease spreads its turn over several pixels, each of which changes little.
const CREASE_SCALE: usize = 4;

/// Offsets `(dx, dy)` of the four "forward" neighbours whose step costs a pixel holds in
/// [`StepCosts`]: right, down-left, down, down-right. The other four neighbours' steps are the
/// forward steps of those neighbours (every cost is symmetric).
const FORWARD: [(isize, isize); 4] = [(1, 0), (-1, 1), (0, 1), (1, 1)];

/// The cost of every step of the covered 8-connected pixel graph for the stroke distance,
/// computed once per view and shared by the foreground and background searches. A step
/// costs its length in pixels (1 or √2) times `1 + CREASE_COST · c`, where
/// `c = max(1 − g(E), 1 − g(D_ij))` is how much of a geometric edge lies between the two
/// pixels: `E` is the larger normal change across either pixel measured at `CREASE_SCALE`
/// pixels (`normal_edges`), `D_ij` their relative depth difference, and `g(x) = exp(−β x²)`
/// with the contrast normalisation of the smoothness term (eq. 4,
/// [`super::energy::Smoothness`]), so a crease is measured against the view's own typical
/// change. Steps to or from an uncovered pixel are `INFINITY`.
pub struct StepCosts {
    width: usize,
    height: usize,
    /// Per pixel, the cost of its [`FORWARD`] steps.
    forward: Vec<[f32; 4]>,
}

impl StepCosts {
    pub fn new(buffers: &Buffers<'_>) -> StepCosts {
        use super::energy::{EnergyParams, Smoothness, differences};
        let (w, h) = (buffers.width as usize, buffers.height as usize);
        let smooth = Smoothness::estimate(buffers, &EnergyParams::default(), false);
        let edge = normal_edges(buffers, CREASE_SCALE);
        // Normal change between the two pixels where no scaled edge map, and depth.
        let cues = if edge.is_some() { 2..3 } else { 1..3 };
        let cost = |i: usize, j: usize, length: f32| {
            let diff = differences(buffers, i, j);
            let mut crease = 0.0f32;
            if let Some((e, beta)) = &edge {
                let x = e[i].max(e[j]);
                crease = 1.0 - (-beta * x * x).exp();
            }
            for ((&weight, &beta), &x) in smooth.weight[cues.clone()]
                .iter()
                .zip(&smooth.beta[cues.clone()])
                .zip(&diff[cues.clone()])
            {
                if weight > 0.0 {
                    crease = crease.max(1.0 - (-beta * x * x).exp());
                }
            }
            length * (1.0 + CREASE_COST * crease)
        };
        let mut forward = vec![[f32::INFINITY; 4]; w * h];
        // Rows are independent: one per core at a time.
        forward
            .par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(y, row)| {
                for (x, out) in row.iter_mut().enumerate() {
                    let i = y * w + x;
                    if !buffers.covered(i) {
                        continue;
                    }
                    for (k, &(dx, dy)) in FORWARD.iter().enumerate() {
                        let (nx, ny) = (x as isize + dx, y as isize + dy);
                        if nx < 0 || nx as usize >= w || ny as usize >= h {
                            continue;
                        }
                        let j = ny as usize * w + nx as usize;
                        if buffers.covered(j) {
                            let length = if dx != 0 && dy != 0 {
                                std::f32::consts::SQRT_2
                            } else {
                                1.0
                            };
                            out[k] = cost(i, j, length);
                        }
                    }
                }
            });
        StepCosts {
            width: w,
            height: h,
            forward,
        }
    }

    /// The eight steps out of pixel `i`: `(neighbour, cost)`, uncovered ones left out (the
    /// plain form of the walk [`geodesic_from`] inlines; its test reference).
    #[cfg(test)]
    fn steps(&self, i: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let (w, h) = (self.width, self.height);
        let (x, y) = ((i % w) as isize, (i / w) as isize);
        // Forward steps are held by `i`, backward ones by the neighbour they lead to.
        let own = FORWARD
            .iter()
            .enumerate()
            .map(move |(k, &(dx, dy))| (dx, dy, i, k));
        let theirs = FORWARD
            .iter()
            .enumerate()
            .map(move |(k, &(dx, dy))| (-dx, -dy, usize::MAX, k));
        own.chain(theirs).filter_map(move |(dx, dy, holder, k)| {
            let (nx, ny) = (x + dx, y + dy);
            if nx < 0 || ny < 0 || nx as usize >= w || ny as usize >= h {
                return None;
            }
            let j = ny as usize * w + nx as usize;
            let c = self.forward[if holder == usize::MAX { j } else { holder }][k];
            c.is_finite().then_some((j, c))
        })
    }
}

/// Geodesic distance from the pixels `sources` over the covered 8-connected pixel graph with
/// the step costs of [`StepCosts`] (multi-source Dijkstra). Pixels not reachable (or not
/// covered) are `INFINITY`.
pub fn geodesic_from(costs: &StepCosts, buffers: &Buffers<'_>, sources: &[u32]) -> Vec<f32> {
    let mut dist = vec![f32::INFINITY; costs.width * costs.height];
    // Non-negative f32 distances order like their bit patterns, and Dijkstra's keys only grow:
    // a radix heap holds them.
    let mut heap = RadixHeap::default();
    for &s in sources {
        let s = s as usize;
        if s < dist.len() && buffers.covered(s) {
            dist[s] = 0.0;
            heap.push(0, s as u32);
        }
    }
    // Index offsets of the forward steps. A forward step leaving the image is INFINITY (see
    // `StepCosts::new`), so neither a forward step nor a backward one (the forward step of
    // the pixel it leads from) can wrap around a row: only the index range is checked.
    let w = costs.width as isize;
    let offsets: [isize; 4] = FORWARD.map(|(dx, dy)| dy * w + dx);
    let n = dist.len();
    while let Some((d, i)) = heap.pop() {
        let d = f32::from_bits(d);
        let i = i as usize;
        if d > dist[i] {
            continue;
        }
        let mut relax = |j: usize, step: f32| {
            let nd = d + step;
            if nd < dist[j] {
                dist[j] = nd;
                heap.push(nd.to_bits(), j as u32);
            }
        };
        let forward = costs.forward[i];
        for (k, &off) in offsets.iter().enumerate() {
            if forward[k].is_finite() {
                relax((i as isize + off) as usize, forward[k]);
            }
            let j = i as isize - off;
            if j >= 0 && (j as usize) < n {
                let step = costs.forward[j as usize][k];
                if step.is_finite() {
                    relax(j as usize, step);
                }
            }
        }
    }
    dist
}

/// A monotone priority queue of `u32` keys (Ahuja, Mehlhorn, Orlin and Tarjan's radix heap):
/// every key pushed is at least the last key popped, as in Dijkstra's algorithm. Bucket `b`
/// holds the keys whose highest bit differing from the last popped key is bit `b − 1`
/// (bucket 0: equal to it), so a pop redistributes one bucket at most: O(log C) amortised per
/// item, with no comparisons between items.
struct RadixHeap {
    last: u32,
    len: usize,
    buckets: [Vec<(u32, u32)>; 33],
}

impl Default for RadixHeap {
    fn default() -> Self {
        RadixHeap {
            last: 0,
            len: 0,
            buckets: std::array::from_fn(|_| Vec::new()),
        }
    }
}

impl RadixHeap {
    fn bucket(last: u32, key: u32) -> usize {
        32 - (key ^ last).leading_zeros() as usize
    }

    fn push(&mut self, key: u32, value: u32) {
        debug_assert!(key >= self.last, "radix heap keys must not decrease");
        let key = key.max(self.last);
        self.buckets[Self::bucket(self.last, key)].push((key, value));
        self.len += 1;
    }

    /// The item of the smallest key (any of them on ties).
    fn pop(&mut self) -> Option<(u32, u32)> {
        if self.len == 0 {
            return None;
        }
        if self.buckets[0].is_empty() {
            let b = (1..33).find(|&b| !self.buckets[b].is_empty())?;
            let items = std::mem::take(&mut self.buckets[b]);
            self.last = items.iter().map(|&(k, _)| k).min()?;
            for (k, v) in &items {
                self.buckets[Self::bucket(self.last, *k)].push((*k, *v));
            }
            // Keep the emptied bucket's allocation for later redistributions.
            let mut spare = items;
            spare.clear();
            if self.buckets[b].is_empty() {
                self.buckets[b] = spare;
            }
        }
        self.len -= 1;
        self.buckets[0].pop()
    }
}

/// Normal change across each pixel at `scale` pixels: `max(1 − N(x−r)·N(x+r), 1 − N(y−r)·N(y+r))`
/// over covered pixels, with its contrast normalisation `β = 1 / (2⟨e²⟩)`. `None` for a scale
/// of 1 or below, or a view without normal change.
fn normal_edges(buffers: &Buffers<'_>, scale: usize) -> Option<(Vec<f32>, f32)> {
    if scale <= 1 {
        return None;
    }
    let (w, h) = (buffers.width as usize, buffers.height as usize);
    let r = scale;
    let mut e = vec![0f32; w * h];
    let (mut sum, mut count) = (0f64, 0u64);
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if !buffers.covered(i) {
                continue;
            }
            let mut v = 0f32;
            if x >= r && x + r < w {
                let (a, b) = (i - r, i + r);
                if buffers.covered(a) && buffers.covered(b) {
                    v = v.max(1.0 - dot(buffers.normal[a], buffers.normal[b]));
                }
            }
            if y >= r && y + r < h {
                let (a, b) = (i - r * w, i + r * w);
                if buffers.covered(a) && buffers.covered(b) {
                    v = v.max(1.0 - dot(buffers.normal[a], buffers.normal[b]));
                }
            }
            let v = v.max(0.0);
            e[i] = v;
            sum += (v as f64) * (v as f64);
            count += 1;
        }
    }
    let mean = if count > 0 { sum / count as f64 } else { 0.0 };
    (mean > 1e-12).then(|| (e, (1.0 / (2.0 * mean)) as f32))
}

/// `D^F / (D^F + D^B)` per pixel: 0 where only the foreground is reachable, 1 where only the
/// background is, 0.5 where neither.
fn relative_distance(d_fg: &[f32], d_bg: &[f32]) -> Vec<f32> {
    d_fg.iter()
        .zip(d_bg)
        .map(|(&a, &b)| match (a.is_finite(), b.is_finite()) {
            (true, true) if a + b > 0.0 => a / (a + b),
            (true, true) => 0.5,
            (true, false) => 0.0,
            (false, true) => 1.0,
            _ => 0.5,
        })
        .collect()
}

/// Markup seeds (Lazy Snapping's foreground and background strokes), with the relative
/// geodesic distance to the strokes for the stroke-distance data term
/// ([`super::EnergyParams::w_geo`]).
pub fn markup(mask: &StrokeMask, buffers: &Buffers<'_>) -> Result<Seeds, SelectError> {
    check(mask, buffers)?;
    let n = buffers.len();
    let mut role = vec![UNKNOWN; n];
    let (mut fg, mut bg) = (Vec::new(), Vec::new());
    let (mut fg_drawn, mut bg_drawn) = (false, false);
    for (i, &label) in mask.labels.iter().enumerate().take(n) {
        fg_drawn |= label == mask::FOREGROUND;
        bg_drawn |= label == mask::BACKGROUND;
        if !buffers.covered(i) {
            role[i] = OFF;
            continue;
        }
        match label {
            mask::FOREGROUND => {
                role[i] = FG;
                fg.push(i as u32);
            }
            mask::BACKGROUND => {
                role[i] = BG;
                bg.push(i as u32);
            }
            _ => {}
        }
    }
    if fg.is_empty() {
        return Err(SelectError::EmptyStrokes(if fg_drawn {
            "the foreground strokes miss the model: draw them on the region to select".into()
        } else {
            "markup needs foreground strokes (label 1) on the region to select".into()
        }));
    }
    if bg.is_empty() {
        return Err(SelectError::EmptyStrokes(if bg_drawn {
            "the background strokes miss the model: draw them on the surface around the region"
                .into()
        } else {
            "markup needs background strokes (label 2) on the surface around the region".into()
        }));
    }
    let costs = StepCosts::new(buffers);
    // The two searches are independent: one per core.
    let (d_fg, d_bg) = rayon::join(
        || geodesic_from(&costs, buffers, &fg),
        || geodesic_from(&costs, buffers, &bg),
    );
    Ok(Seeds {
        width: buffers.width,
        height: buffers.height,
        role,
        stroke_position: Some(relative_distance(&d_fg, &d_bg)),
        fg_samples: fg,
        bg_samples: bg,
        band_position: None,
        stroke_distance: Some(d_fg.iter().zip(&d_bg).map(|(&f, &b)| f.min(b)).collect()),
        segments: None,
    })
}

/// Pixels not in `wall` that are 4-connected to the image border (a flood fill).
pub fn outside_of(wall: &[bool], width: usize, height: usize) -> Vec<bool> {
    let mut out = vec![false; wall.len()];
    let mut stack: Vec<usize> = Vec::new();
    let push = |i: usize, out: &mut Vec<bool>, stack: &mut Vec<usize>| {
        if !wall[i] && !out[i] {
            out[i] = true;
            stack.push(i);
        }
    };
    for x in 0..width {
        push(x, &mut out, &mut stack);
        push((height - 1) * width + x, &mut out, &mut stack);
    }
    for y in 0..height {
        push(y * width, &mut out, &mut stack);
        push(y * width + width - 1, &mut out, &mut stack);
    }
    while let Some(i) = stack.pop() {
        let (x, y) = (i % width, i / width);
        if x > 0 {
            push(i - 1, &mut out, &mut stack);
        }
        if x + 1 < width {
            push(i + 1, &mut out, &mut stack);
        }
        if y > 0 {
            push(i - width, &mut out, &mut stack);
        }
        if y + 1 < height {
            push(i + width, &mut out, &mut stack);
        }
    }
    out
}

/// 8-neighbours of pixel `i` inside the image.
#[inline]
fn neighbours8(i: usize, width: usize, height: usize) -> impl Iterator<Item = usize> {
    let (x, y) = ((i % width) as isize, (i / width) as isize);
    const D: [(isize, isize); 8] = [
        (-1, -1),
        (0, -1),
        (1, -1),
        (-1, 0),
        (1, 0),
        (-1, 1),
        (0, 1),
        (1, 1),
    ];
    D.iter().filter_map(move |&(dx, dy)| {
        let (nx, ny) = (x + dx, y + dy);
        (nx >= 0 && ny >= 0 && (nx as usize) < width && (ny as usize) < height)
            .then(|| ny as usize * width + nx as usize)
    })
}

/// Chamfer distance (1, √2) within `region` from the `sources` (multi-source Dijkstra).
fn distance_within(region: &[bool], sources: &[usize], width: usize, height: usize) -> Vec<f32> {
    let mut dist = vec![f32::INFINITY; region.len()];
    // Distances in 1/1024 px as integers keep the heap ordering total.
    let mut heap: BinaryHeap<Reverse<(u32, u32)>> = BinaryHeap::new();
    for &s in sources {
        dist[s] = 0.0;
        heap.push(Reverse((0, s as u32)));
    }
    const STRAIGHT: u32 = 1024;
    const DIAGONAL: u32 = 1448;
    while let Some(Reverse((d, i))) = heap.pop() {
        let i = i as usize;
        if (d as f32 / 1024.0) > dist[i] {
            continue;
        }
        for j in neighbours8(i, width, height) {
            if !region[j] {
                continue;
            }
            let diagonal = (j % width != i % width) && (j / width != i / width);
            let nd = d + if diagonal { DIAGONAL } else { STRAIGHT };
            let ndf = nd as f32 / 1024.0;
            if ndf < dist[j] {
                dist[j] = ndf;
                heap.push(Reverse((nd, j as u32)));
            }
        }
    }
    dist
}

/// Heavy-lasso seeds (§4.2; see the module documentation).
pub fn heavy_lasso(mask: &StrokeMask, buffers: &Buffers<'_>) -> Result<Seeds, SelectError> {
    check(mask, buffers)?;
    let (w, h) = (buffers.width as usize, buffers.height as usize);
    let n = w * h;
    let band: Vec<bool> = mask.labels.iter().map(|&l| l == mask::HEAVY).collect();
    if !band.iter().any(|&b| b) {
        return Err(SelectError::EmptyStrokes(
            "the heavy lasso needs one thick closed stroke (label 3) along the region's boundary"
                .into(),
        ));
    }
    let outside = outside_of(&band, w, h);
    let inside: Vec<bool> = (0..n).map(|i| !band[i] && !outside[i]).collect();
    if !inside.iter().any(|&b| b) {
        return Err(SelectError::NotEnclosed);
    }
    let mut role = vec![UNKNOWN; n];
    let (mut inner, mut outer) = (Vec::new(), Vec::new());
    let (mut fg, mut bg) = (Vec::new(), Vec::new());
    for i in 0..n {
        if band[i] {
            let mut touches_in = false;
            let mut touches_out = false;
            for j in neighbours8(i, w, h) {
                touches_in |= inside[j];
                touches_out |= outside[j];
            }
            // A band pixel at the image border borders the outside beyond the view.
            let (x, y) = (i % w, i / w);
            touches_out |= x == 0 || y == 0 || x + 1 == w || y + 1 == h;
            match (touches_in, touches_out) {
                (true, false) => {
                    inner.push(i);
                    role[i] = FG;
                }
                (false, true) => {
                    outer.push(i);
                    role[i] = BG;
                }
                _ => {}
            }
        } else {
            role[i] = if inside[i] { FG } else { BG };
        }
    }
    let mut any_surface = false;
    for i in 0..n {
        if !buffers.covered(i) {
            role[i] = OFF;
            continue;
        }
        any_surface |= band[i] || inside[i];
    }
    if !any_surface {
        return Err(SelectError::EmptyStrokes(
            "the heavy lasso encloses no surface of the model".into(),
        ));
    }
    for &i in &inner {
        if role[i] == FG {
            fg.push(i as u32);
        }
    }
    for &i in &outer {
        if role[i] == BG {
            bg.push(i as u32);
        }
    }
    // Position across the band: d_in / (d_in + d_out), distances measured inside the band.
    let d_in = distance_within(&band, &inner, w, h);
    let d_out = distance_within(&band, &outer, w, h);
    let position: Vec<f32> = (0..n)
        .map(|i| {
            if !band[i] {
                return f32::NAN;
            }
            let (a, b) = (d_in[i], d_out[i]);
            match (a.is_finite(), b.is_finite()) {
                (true, true) if a + b > 0.0 => a / (a + b),
                (true, false) => 0.0,
                (false, true) => 1.0,
                _ => 0.5,
            }
        })
        .collect();
    Ok(Seeds {
        width: buffers.width,
        height: buffers.height,
        role,
        fg_samples: fg,
        bg_samples: bg,
        band_position: Some(position),
        stroke_position: None,
        stroke_distance: None,
        segments: None,
    })
}

/// The plain lasso: covered pixels inside the polygon (label 4).
pub fn lasso(mask: &StrokeMask, buffers: &Buffers<'_>) -> Result<Vec<bool>, SelectError> {
    check(mask, buffers)?;
    if !mask.labels.contains(&mask::LASSO) {
        return Err(SelectError::EmptyStrokes(
            "the lasso needs its polygon's inside filled with label 4".into(),
        ));
    }
    let selected: Vec<bool> = (0..buffers.len())
        .map(|i| mask.labels[i] == mask::LASSO && buffers.covered(i))
        .collect();
    if !selected.iter().any(|&s| s) {
        return Err(SelectError::EmptyStrokes(
            "the lasso encloses no surface of the model".into(),
        ));
    }
    Ok(selected)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::select::buffers::OwnedBuffers;
    use crate::testing::xorshift;

    /// The radix heap pops what a binary heap pops, for Dijkstra-like (never decreasing)
    /// pushes: keys spread over every bucket, ties and repeats.
    #[test]
    fn radix_heap_pops_in_key_order() {
        let mut radix = RadixHeap::default();
        let mut binary = BinaryHeap::new();
        let mut next = xorshift(0x9e37_79b9);
        for k in 0..50u32 {
            let key = next() >> 8;
            radix.push(key, k);
            binary.push(Reverse(key));
        }
        let mut popped = 0;
        while let Some((key, _)) = radix.pop() {
            let Some(Reverse(expected)) = binary.pop() else {
                panic!("radix heap has more")
            };
            assert_eq!(key, expected);
            popped += 1;
            // Pushes at or above the key just popped, as Dijkstra's relaxations are.
            if popped < 400 {
                for _ in 0..(next() % 3) {
                    let later = key.saturating_add(match next() % 4 {
                        0 => 0,
                        1 => next() % 16,
                        2 => next() % 70_000,
                        _ => next() >> 4,
                    });
                    radix.push(later, popped);
                    binary.push(Reverse(later));
                }
            }
        }
        assert!(binary.is_empty() && popped > 400);
    }

    /// The inlined walk of `geodesic_from` finds the distances of a plain Dijkstra over
    /// `StepCosts::steps`, on a view with holes, creases and depth steps.
    #[test]
    fn geodesic_distances_match_a_plain_dijkstra() {
        let (w, h) = (37u32, 23u32);
        let mut b = OwnedBuffers::flat(w, h);
        let mut next = xorshift(0x2545_f491);
        for i in 0..(w * h) as usize {
            match next() % 10 {
                0 => {
                    b.node[i] = crate::render::NO_NODE;
                    b.depth[i] = f32::INFINITY;
                }
                1 => b.normal[i] = [0.0, 1.0, 0.0],
                2 => b.depth[i] *= 1.5,
                _ => {}
            }
        }
        let v = b.view();
        let costs = StepCosts::new(&v);
        let sources: Vec<u32> = (0..6).map(|_| next() % (w * h)).collect();
        let got = geodesic_from(&costs, &v, &sources);
        let n = (w * h) as usize;
        let mut want = vec![f32::INFINITY; n];
        let mut heap = BinaryHeap::new();
        for &s in &sources {
            if v.covered(s as usize) {
                want[s as usize] = 0.0;
                heap.push(Reverse((0u32, s as usize)));
            }
        }
        while let Some(Reverse((d, i))) = heap.pop() {
            let d = f32::from_bits(d);
            if d > want[i] {
                continue;
            }
            for (j, step) in costs.steps(i) {
                if d + step < want[j] {
                    want[j] = d + step;
                    heap.push(Reverse(((d + step).to_bits(), j)));
                }
            }
        }
        assert!(want.iter().filter(|d| d.is_finite()).count() > n / 2);
        for i in 0..n {
            assert!(
                got[i] == want[i] || (got[i] - want[i]).abs() <= 1e-5 * want[i].max(1.0),
                "pixel {i}: {} against {}",
                got[i],
                want[i]
            );
        }
    }

    /// A square ring of width `t` between squares [a, b) (outer) on a `size`² mask.
    fn ring(size: u32, a: u32, b: u32, t: u32) -> StrokeMask {
        let mut m = StrokeMask::empty(size, size).unwrap();
        for y in a..b {
            for x in a..b {
                let inner = x >= a + t && x < b - t && y >= a + t && y < b - t;
                if !inner {
                    m.labels[(y * size + x) as usize] = mask::HEAVY;
                }
            }
        }
        m
    }

    #[test]
    fn heavy_lasso_seeds_the_inner_and_outer_edges() {
        let b = OwnedBuffers::flat(40, 40);
        let v = b.view();
        let s = heavy_lasso(&ring(40, 10, 30, 6), &v).unwrap();
        let at = |x: usize, y: usize| s.role[y * 40 + x];
        // Inside and the inner marker: foreground; outside and the outer marker: background.
        assert_eq!(at(20, 20), FG);
        assert_eq!(at(15, 20), FG); // inner edge of the band (x = 10..16 is band)
        assert_eq!(at(14, 20), UNKNOWN);
        assert_eq!(at(11, 20), UNKNOWN);
        assert_eq!(at(10, 20), BG); // outer edge of the band
        assert_eq!(at(5, 5), BG);
        // The markers run all around: 4 sides of the inner square (8 x 8) and the outer (20 x 20).
        assert_eq!(s.fg_samples.len(), 8 * 4 + 4);
        assert_eq!(s.bg_samples.len(), 20 * 4 - 4);
        // Position across the band grows from the inner to the outer marker.
        let p = s.band_position.as_ref().unwrap();
        let pos = |x: usize| p[20 * 40 + x];
        assert!(pos(15) < pos(13) && pos(13) < pos(11) && pos(11) < pos(10));
        assert!((pos(15) - 0.0).abs() < 1e-6 && (pos(10) - 1.0).abs() < 1e-6);
        assert!(pos(20).is_nan());
    }

    #[test]
    fn heavy_lasso_needs_a_closed_loop() {
        let b = OwnedBuffers::flat(40, 40);
        let v = b.view();
        let mut m = ring(40, 10, 30, 4);
        // Cut the ring open.
        for y in 10..14 {
            for x in 18..22 {
                m.labels[y * 40 + x] = mask::NONE;
            }
        }
        assert_eq!(heavy_lasso(&m, &v), Err(SelectError::NotEnclosed));
        let empty = StrokeMask::empty(40, 40).unwrap();
        assert!(matches!(
            heavy_lasso(&empty, &v),
            Err(SelectError::EmptyStrokes(_))
        ));
        let small = StrokeMask::empty(20, 40).unwrap();
        assert!(matches!(
            heavy_lasso(&small, &v),
            Err(SelectError::SizeMismatch { .. })
        ));
    }

    #[test]
    fn markup_needs_both_markers_on_the_surface() {
        let mut b = OwnedBuffers::flat(10, 10);
        for i in 50..100 {
            b.node[i] = crate::render::NO_NODE;
            b.depth[i] = f32::INFINITY;
        }
        let v = b.view();
        let mut m = StrokeMask::empty(10, 10).unwrap();
        m.labels[5] = mask::FOREGROUND;
        assert!(matches!(markup(&m, &v), Err(SelectError::EmptyStrokes(_))));
        m.labels[80] = mask::BACKGROUND; // off the model
        let e = markup(&m, &v).unwrap_err().to_string();
        assert!(e.contains("miss the model"), "{e}");
        m.labels[30] = mask::BACKGROUND;
        let s = markup(&m, &v).unwrap();
        assert_eq!(
            (s.role[5], s.role[30], s.role[80], s.role[6]),
            (FG, BG, OFF, UNKNOWN)
        );
    }

    #[test]
    fn stroke_distance_is_long_across_a_crease() {
        let (w, h) = (40u32, 10u32);
        let b = OwnedBuffers::creased(w, h, 10);
        let v = b.view();
        let mut m = StrokeMask::empty(w, h).unwrap();
        for y in 1..h - 1 {
            m.labels[(y * w + 2) as usize] = mask::FOREGROUND;
            m.labels[(y * w + 30) as usize] = mask::BACKGROUND;
        }
        let s = markup(&m, &v).unwrap();
        let p = s.stroke_position.as_ref().unwrap();
        let at = |x: u32| p[(5 * w + x) as usize];
        // Without the crease the two strokes would meet at x = 16; with it, at the crease.
        assert!(at(2) == 0.0 && at(30) == 1.0);
        assert!(at(7) < 0.5 && at(13) > 0.5, "{} {}", at(7), at(13));
    }

    #[test]
    fn lasso_keeps_covered_inside_pixels() {
        let mut b = OwnedBuffers::flat(4, 1);
        b.node[3] = crate::render::NO_NODE;
        let v = b.view();
        let m = StrokeMask::new(4, 1, vec![0, 4, 4, 4]).unwrap();
        assert_eq!(lasso(&m, &v).unwrap(), vec![false, true, true, false]);
        let m = StrokeMask::new(4, 1, vec![0, 0, 0, 4]).unwrap();
        assert!(lasso(&m, &v).is_err());
    }
}
