//! Surface segments in the graph cut (issue 13; Lazy Snapping's pre-segmentation, with the
//! mesh-segmentation paper's surface segments in place of image superpixels): a second level
//! above the pixels.
//!
//! Each pixel names an original vertex (the id buffer), hence its segment at every scale of
//! the model's hierarchy ([`crate::segment`]). The strokes then claim whole segments: going
//! up the hierarchy from each fine segment a stroke touches, through the segments that hold
//! strokes of that side only, the stroke claims a part **by the strength of its boundary**
//! (its saliency: it was merged last relative to what it holds, see
//! [`crate::segment::merge::Hierarchy::strengths`]): the largest of them whose boundary is
//! at least half as strong as the strongest — not simply the largest, which with few
//! strokes would be half the model, nor strictly the strongest, which took a piece of a
//! part whenever noise made its boundary a little stronger than the part's. Segments no
//! stroke claims stay undecided. These *stroke segments* act on the cut in four ways:
//!
//! - a **segment prior** in the data term: a pixel in a foreground stroke segment costs
//!   `w_seg` more to put in the background, and the converse — so a stroke claims the
//!   surface up to the nearest segment boundary that separates it from the other side's
//!   strokes, instead of leaking across a smooth join;
//! - **cheap cuts on segment boundaries**: between two pixels of different stroke segments
//!   the smoothness term is multiplied by `seg_edge` (< 1), so the cut snaps to them; the
//!   pixel graph still refines the boundary where the image says otherwise;
//! - for markup, **surface apart from the claim**: an unclaimed segment (the largest
//!   stroke-free one) that shows more pixels than all the foreground claims together leans
//!   to the background by `w_seg_apart` more. Markup's geodesic term gives any surface to
//!   the nearer side's strokes, so with few background strokes a whole torso went to a
//!   foreground stroke on a leg, only because the one background stroke lay on another leg.
//!   A piece of surface larger than everything the foreground strokes claim is taken for
//!   another part that no stroke spoke for; smaller stroke-free pieces (the rest of the
//!   claimed part, as a rule) still go to the nearer side. The rule errs where a short
//!   stroke claims a small piece of a large smooth part: the rest of that part then counts
//!   as apart too (`meshwiki-bench select --sweep`, setting 5, measures it).
//! - for markup, **surface far from every stroke**: an unclaimed pixel whose geodesic
//!   distance to the nearest stroke, of either side, exceeds `seg_far` claim radii (`√` of
//!   the pixels the foreground strokes claim) leans to the background by `w_seg_far` per
//!   radius beyond. With one background stroke, the relative stroke distance gave the
//!   foreground everything nearer its strokes than that one stroke — half a model for two
//!   strokes on an arm; the apart rule only catches it where the stroke-free surface forms
//!   one segment larger than the claims.
//!
//! The seeds' foreground and background pixels are the strokes: markup's strokes, and the
//! heavy lasso's inner and outer sides.

use rustc_hash::FxHashMap;

use super::buffers::Buffers;
use super::seeds::{BG, FG, OFF, Seeds};
use crate::segment::SegmentFile;

/// No segment (off the model, or a vertex the file does not know).
pub const NONE: u32 = u32::MAX;

/// The segments of one view's pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSegments {
    pub width: u32,
    pub height: u32,
    /// Per pixel, its fine segment numbered locally (`0..ladders.len()`), or [`NONE`].
    pub local: Vec<u32>,
    /// Per local fine segment, its segment at every scale, fine (0) to coarsest.
    pub ladders: Vec<Vec<u32>>,
    /// Per local fine segment, the strength of each of those segments.
    pub strengths: Vec<Vec<f32>>,
}

impl ViewSegments {
    /// Looks up every pixel's segments in `file`.
    pub fn of(file: &SegmentFile, buffers: &Buffers<'_>) -> ViewSegments {
        let scales = file.scales();
        let mut index: FxHashMap<u32, u32> = FxHashMap::default();
        let mut ladders = Vec::new();
        let mut strengths = Vec::new();
        let local = (0..buffers.len())
            .map(|i| {
                if !buffers.covered(i) {
                    return NONE;
                }
                let Some(fine) = file.fine_of(buffers.vertex[i]) else {
                    return NONE;
                };
                *index.entry(fine).or_insert_with(|| {
                    let ladder: Vec<u32> = (0..scales)
                        .map(|s| file.at_scale(s, fine).unwrap_or(NONE))
                        .collect();
                    strengths.push(
                        ladder
                            .iter()
                            .enumerate()
                            .map(|(s, &seg)| file.strength(s, seg))
                            .collect(),
                    );
                    ladders.push(ladder);
                    (ladders.len() - 1) as u32
                })
            })
            .collect();
        ViewSegments {
            width: buffers.width,
            height: buffers.height,
            local,
            ladders,
            strengths,
        }
    }
}

/// The stroke segments of a view ([`stroke_segments`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentPrior {
    /// Per pixel: +1 in a foreground stroke segment, −1 in a background one, 0 otherwise.
    pub side: Vec<i8>,
    /// Per pixel, the stroke segment (or the largest stroke-free segment) it lies in, as
    /// `scale << 32 | segment`; `u64::MAX` where none.
    pub region: Vec<u64>,
    /// Per pixel: in no claimed segment, and in a stroke-free segment that shows more pixels
    /// than the foreground claims ([`StrokeClaims::of`]).
    pub apart: Vec<bool>,
    /// `√` of the pixels the foreground strokes claim (0 when they claim none), in the
    /// pixels of the level the claims were made on.
    pub fg_radius: f32,
}

/// What the strokes claim (the first half of [`stroke_segments`]): per `scale << 32 | segment`
/// key, the side of the segments the strokes claim, and the segments holding any stroke.
/// Keys name segments of the model, not pixels, so claims made on one rendering of a view
/// hold on another of the same view (the coarse and fine levels of
/// [`super::multilevel`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StrokeClaims {
    claimed: FxHashMap<u64, i8>,
    touched: rustc_hash::FxHashSet<u64>,
    /// Stroke-free segments showing more pixels than the foreground claims (none when the
    /// foreground strokes claim nothing).
    apart: rustc_hash::FxHashSet<u64>,
    /// Pixels the foreground strokes claim.
    claimed_fg: u64,
}

fn key(s: usize, seg: u32) -> u64 {
    (s as u64) << 32 | seg as u64
}

impl StrokeClaims {
    /// The segments claimed by the seeds' foreground and background pixels: from each fine
    /// segment with strokes, up through the segments of its side only, the largest whose
    /// boundary is at least half as strong as the strongest (`claim`). Then the
    /// stroke-free segments that show more of the view's pixels (those not [`OFF`]) than all
    /// the foreground claims.
    pub fn of(view: &ViewSegments, seeds: &Seeds) -> StrokeClaims {
        let n = view.local.len();
        let scales = view.ladders.first().map_or(0, Vec::len);
        // Stroke pixels per (scale, segment): (foreground, background).
        let mut count: FxHashMap<u64, (u32, u32)> = FxHashMap::default();
        let mut local_count: Vec<(u32, u32)> = vec![(0, 0); view.ladders.len()];
        for i in 0..n.min(seeds.role.len()) {
            let l = view.local[i];
            if l == NONE {
                continue;
            }
            match seeds.role[i] {
                FG => local_count[l as usize].0 += 1,
                BG => local_count[l as usize].1 += 1,
                _ => {}
            }
        }
        for (l, &(f, b)) in local_count.iter().enumerate() {
            if f == 0 && b == 0 {
                continue;
            }
            for (s, &seg) in view.ladders[l].iter().enumerate() {
                let c = count.entry(key(s, seg)).or_default();
                c.0 += f;
                c.1 += b;
            }
        }
        let mut claimed: FxHashMap<u64, i8> = FxHashMap::default();
        for (l, ladder) in view.ladders.iter().enumerate() {
            let (f, b) = local_count[l];
            if (f > 0) == (b > 0) {
                continue;
            }
            let side: i8 = if f > 0 { 1 } else { -1 };
            // The segments above it holding strokes of this side only, fine to coarse.
            let single: Vec<(f32, u64)> = ladder
                .iter()
                .enumerate()
                .take(scales)
                .take_while(|&(s, &seg)| {
                    seg != NONE
                        && count
                            .get(&key(s, seg))
                            .is_none_or(|&(f, b)| f == 0 || b == 0)
                })
                .map(|(s, &seg)| {
                    let strength = view.strengths[l].get(s).copied().unwrap_or(f32::INFINITY);
                    (strength, key(s, seg))
                })
                .collect();
            if let Some(k) = claim(&single) {
                claimed.insert(k, side);
            }
        }
        let mut claims = StrokeClaims {
            claimed,
            touched: count.into_keys().collect(),
            apart: Default::default(),
            claimed_fg: 0,
        };
        // Pixels per local fine segment, then per decision.
        let mut pixels = vec![0u64; view.ladders.len()];
        for (i, &l) in view.local.iter().enumerate() {
            if l != NONE && seeds.role.get(i) != Some(&OFF) {
                pixels[l as usize] += 1;
            }
        }
        let mut claimed_fg = 0u64;
        let mut free: FxHashMap<u64, u64> = FxHashMap::default();
        for (l, (side, region)) in claims.decide(view).into_iter().enumerate() {
            match side {
                1 => claimed_fg += pixels[l],
                0 if region != u64::MAX => *free.entry(region).or_default() += pixels[l],
                _ => {}
            }
        }
        claims.claimed_fg = claimed_fg;
        claims.apart = free
            .into_iter()
            .filter(|&(_, n)| claimed_fg > 0 && n > claimed_fg)
            .map(|(k, _)| k)
            .collect();
        claims
    }

    /// Per local fine segment: the side and key of its claimed segment, or 0 and its largest
    /// stroke-free segment (`u64::MAX` if none).
    fn decide(&self, view: &ViewSegments) -> Vec<(i8, u64)> {
        let scales = view.ladders.first().map_or(0, Vec::len);
        view.ladders
            .iter()
            .map(|ladder| {
                let mut free = u64::MAX;
                for (s, &seg) in ladder.iter().enumerate().take(scales) {
                    if seg == NONE {
                        break;
                    }
                    if let Some(&side) = self.claimed.get(&key(s, seg)) {
                        return (side, key(s, seg));
                    }
                    if !self.touched.contains(&key(s, seg)) {
                        free = key(s, seg);
                    }
                }
                (0, free)
            })
            .collect()
    }

    /// The prior of `view`'s pixels (`role`: the seeds' roles, [`OFF`] pixels get none): per
    /// local fine segment, its claimed segment, or else its largest segment without strokes
    /// (for the boundaries) and whether that one is apart from the claims.
    pub fn prior(&self, view: &ViewSegments, role: &[u8]) -> SegmentPrior {
        let n = view.local.len();
        let decided = self.decide(view);
        let mut side = vec![0i8; n];
        let mut region = vec![u64::MAX; n];
        let mut apart = vec![false; n];
        for i in 0..n {
            let l = view.local[i];
            if l == NONE || role.get(i) == Some(&OFF) {
                continue;
            }
            (side[i], region[i]) = decided[l as usize];
            apart[i] = side[i] == 0 && self.apart.contains(&region[i]);
        }
        SegmentPrior {
            side,
            region,
            apart,
            fg_radius: (self.claimed_fg as f32).sqrt(),
        }
    }
}

/// Share of the strongest boundary that a larger segment's boundary must reach for the
/// stroke to claim that larger segment instead ([`claim`]).
const CLAIM_SHARE: f32 = 0.5;

/// Which of a stroke's single-sided segments (`(strength, key)`, fine to coarse) it claims:
/// the largest whose boundary is at least [`CLAIM_SHARE`] of the strongest one's. Strengths
/// are persistences measured on the mesh, so two nested segments of one part often differ by
/// less than their noise; taking strictly the strongest then claimed a piece of a part (the
/// end of a teddy's arm without the rest of the arm) and left the rest to the background.
/// A boundary under half the strongest is a weaker part boundary, not noise: the stroke
/// keeps to the stronger part inside it. Without a finite positive maximum (a segment never
/// merged, or persistences all ≤ 0), the strongest, the larger on a tie.
fn claim(single: &[(f32, u64)]) -> Option<u64> {
    let best = single
        .iter()
        .map(|&(strength, _)| strength)
        .fold(f32::NEG_INFINITY, f32::max);
    let threshold = if best.is_finite() && best > 0.0 {
        best * CLAIM_SHARE
    } else {
        best
    };
    single
        .iter()
        .rev()
        .find(|&&(strength, _)| strength >= threshold)
        .map(|&(_, k)| k)
}

/// The largest segments holding strokes of one side only, from the seeds' foreground and
/// background pixels ([`StrokeClaims::of`], then [`StrokeClaims::prior`]).
pub fn stroke_segments(view: &ViewSegments, seeds: &Seeds) -> SegmentPrior {
    StrokeClaims::of(view, seeds).prior(view, &seeds.role)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::select::seeds::UNKNOWN;

    /// A 12 × 1 view of four fine segments (three pixels each), merged pairwise at scale 1
    /// and into one at scale 2.
    fn view() -> ViewSegments {
        ViewSegments {
            width: 12,
            height: 1,
            local: (0..12).map(|i| i / 3).collect(),
            ladders: vec![
                vec![10, 0, 0],
                vec![11, 0, 0],
                vec![12, 1, 0],
                vec![13, 1, 0],
            ],
            strengths: vec![vec![0.1, 1.0, f32::INFINITY]; 4],
        }
    }

    fn seeds(role: Vec<u8>) -> Seeds {
        Seeds {
            width: role.len() as u32,
            height: 1,
            role,
            fg_samples: Vec::new(),
            bg_samples: Vec::new(),
            band_position: None,
            stroke_position: None,
            stroke_distance: None,
            segments: None,
        }
    }

    #[test]
    fn a_stroke_claims_its_most_salient_segment_without_the_other_side() {
        let mut role = vec![UNKNOWN; 12];
        role[0] = FG;
        role[11] = BG;
        let p = stroke_segments(&view(), &seeds(role));
        // Scale 2 holds both; scale 1 splits them: two halves, one per side.
        assert_eq!(&p.side[..6], &[1; 6]);
        assert_eq!(&p.side[6..], &[-1; 6]);
        assert_eq!(p.region[0], 1 << 32);
        assert_eq!(p.region[5], 1 << 32);
        assert_eq!(p.region[6], (1 << 32) | 1);
    }

    #[test]
    fn stroke_free_segments_larger_than_the_foreground_claim_are_apart() {
        // 20 × 1: fine segments A (3 px, a foreground stroke), B (2 px), C (10 px), D (5 px,
        // a background stroke). A and B merge at scale 1, everything at scale 2; A's own
        // boundary is the strongest, so the stroke claims A alone.
        let sizes = [3, 2, 10, 5];
        let local: Vec<u32> = (0..4u32)
            .flat_map(|l| std::iter::repeat_n(l, sizes[l as usize]))
            .collect();
        let view = ViewSegments {
            width: 20,
            height: 1,
            local,
            ladders: vec![
                vec![10, 0, 0],
                vec![11, 0, 0],
                vec![12, 1, 0],
                vec![13, 2, 0],
            ],
            strengths: vec![
                vec![1.0, 0.1, f32::INFINITY],
                vec![0.1, 0.1, f32::INFINITY],
                vec![0.1, 0.1, f32::INFINITY],
                vec![0.1, 0.1, f32::INFINITY],
            ],
        };
        let mut role = vec![UNKNOWN; 20];
        role[1] = FG;
        role[17] = BG;
        let p = stroke_segments(&view, &seeds(role.clone()));
        assert_eq!(&p.side[..3], &[1; 3]);
        assert_eq!(p.region[0], 10);
        // B (its own stroke-free segment, 2 px) is smaller than the claim (3 px): not apart;
        // C's largest stroke-free segment (scale 1, 10 px) is larger: apart.
        assert_eq!(&p.side[3..15], &[0; 12]);
        assert_eq!(&p.apart[3..5], &[false; 2]);
        assert_eq!(p.region[5], (1 << 32) | 1);
        assert_eq!(&p.apart[5..15], &[true; 10]);
        // Claimed pixels are never apart.
        assert!(p.apart[..3].iter().chain(&p.apart[15..]).all(|&a| !a));
        // With C's pixels off the view, nothing is larger than the claim.
        for r in &mut role[7..15] {
            *r = OFF;
        }
        let p = stroke_segments(&view, &seeds(role));
        assert!(p.apart.iter().all(|&a| !a));
        // Strokes of both sides in one fine segment claim nothing: then nothing is apart
        // either (there is no claim to be apart from).
        let mut role = vec![UNKNOWN; 20];
        role[16] = FG;
        role[17] = BG;
        let p = stroke_segments(&view, &seeds(role));
        assert!(p.side.iter().all(|&s| s == 0));
        assert!(p.apart.iter().all(|&a| !a));
    }

    #[test]
    fn a_stroke_claims_the_largest_segment_nearly_as_salient_as_the_most() {
        // Fine segment 0 (a foreground stroke) lies in scale-1 segment 0 with fine segment 1;
        // scale 2 holds everything, with the background stroke in fine segment 3.
        let claimed = |inner: f32, outer: f32| {
            let mut view = view();
            view.strengths = vec![vec![inner, outer, f32::INFINITY]; 4];
            let mut role = vec![UNKNOWN; 12];
            role[0] = FG;
            role[11] = BG;
            let p = stroke_segments(&view, &seeds(role));
            p.side.iter().take_while(|&&s| s == 1).count()
        };
        // The pair's boundary at least half the fine segment's: the pair (6 pixels).
        assert_eq!(claimed(1.0, 0.6), 6);
        assert_eq!(claimed(1.0, 0.5), 6);
        assert_eq!(claimed(0.6, 1.0), 6);
        // Under half: the fine segment alone (3 pixels).
        assert_eq!(claimed(1.0, 0.4), 3);
        // Persistences at or below zero: the strongest, the larger on a tie.
        assert_eq!(claimed(-0.2, -0.5), 3);
        assert_eq!(claimed(-0.5, -0.5), 6);
        assert_eq!(claim(&[]), None);
    }

    #[test]
    fn segments_without_strokes_stay_undecided() {
        let mut role = vec![UNKNOWN; 12];
        role[0] = FG;
        role[4] = BG;
        let p = stroke_segments(&view(), &seeds(role));
        // Fine segments 0 and 1 are separated at scale 0 only; 2 and 3 have no strokes and
        // their scale-1 segment none either.
        assert_eq!(&p.side[..3], &[1; 3]);
        assert_eq!(&p.side[3..6], &[-1; 3]);
        assert_eq!(&p.side[6..], &[0; 6]);
        assert_eq!(p.region[0], 10);
        assert_eq!(p.region[6], (1 << 32) | 1);
    }
}
