//! Suggested regions against the human regions (issue 13, item 3): how close the viewer's
//! *Segments* tool gets to each region of the benchmark with whole-segment clicks alone.
//!
//! A simulated user who sees the previewed segment (and knows the region) clicks every
//! segment that lies mostly (more than half its vertices) inside the region, at one scale.
//! The segments come from the real server (`GET /api/v1/models/{id}/segments/{scale}/
//! vertices?vertex=V`): starting from any region vertex not yet seen, the segment holding it
//! is fetched, judged and taken off, until the region is exhausted. The error is over **all**
//! the region's vertices (a segment click selects the hidden side too, unlike the stroke
//! tools, whose error is over the visible ones): |clicked Δ region| / |region|, vertices on
//! the region's boundary (in two regions) counted right either way.

use anyhow::Result;
use roaring::RoaringBitmap;
use serde::Serialize;

use super::client::Api;
use super::truth::Region;

/// Scales tried, relative to the suggested one.
pub const OFFSETS: std::ops::RangeInclusive<i64> = -5..=2;

/// One region at one scale.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct AtScale {
    pub scale: usize,
    /// Segments at this scale.
    pub segments: u32,
    pub error: f64,
    pub clicks: usize,
    /// Segments touching the region (previews looked at).
    pub looked_at: usize,
}

/// One region at every scale tried (`None`: a scale the model does not have).
#[derive(Debug, Clone, Serialize)]
pub struct SuggestedResult {
    pub model: u32,
    pub segment: u32,
    pub region_vertices: u64,
    pub scales: Vec<Option<AtScale>>,
}

impl SuggestedResult {
    /// The scale with the smallest error.
    pub fn best(&self) -> Option<AtScale> {
        self.scales
            .iter()
            .flatten()
            .copied()
            .min_by(|a, b| a.error.total_cmp(&b.error))
    }
}

/// The user's clicks on `region` of model `model_id` at `scale`.
fn at_scale(
    api: &Api,
    model_id: i64,
    region: &Region,
    scale: usize,
    segments: u32,
) -> Result<AtScale> {
    let mut remaining = region.vertices.clone();
    let mut clicked = RoaringBitmap::new();
    let (mut clicks, mut looked_at) = (0, 0);
    while let Some(v) = remaining.min() {
        let Some(segment) = api.segment_of(model_id, scale, v)? else {
            remaining.remove(v);
            continue;
        };
        looked_at += 1;
        remaining -= &segment;
        remaining.remove(v);
        if segment.intersection_len(&region.vertices) * 2 > segment.len() {
            clicked |= segment;
            clicks += 1;
        }
    }
    let wrong = (&clicked - &region.vertices).difference_len(&region.shared)
        + (&region.vertices - &clicked).difference_len(&region.shared);
    Ok(AtScale {
        scale,
        segments,
        error: wrong as f64 / region.vertices.len().max(1) as f64,
        clicks,
        looked_at,
    })
}

/// `region` at every scale of [`OFFSETS`] around `suggested`.
pub fn region(
    api: &Api,
    model_id: i64,
    psb_id: u32,
    region: &Region,
    counts: &[u32],
    suggested: usize,
) -> Result<SuggestedResult> {
    let mut scales = Vec::new();
    for offset in OFFSETS {
        let s = suggested as i64 + offset;
        scales.push(
            match usize::try_from(s).ok().filter(|&s| s < counts.len()) {
                Some(s) => Some(at_scale(api, model_id, region, s, counts[s])?),
                None => None,
            },
        );
    }
    Ok(SuggestedResult {
        model: psb_id,
        segment: region.segment,
        region_vertices: region.vertices.len(),
        scales,
    })
}
