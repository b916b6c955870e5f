//! Callouts (system paper §2.2): each visible part's anchor is projected, labels with the part's
//! title are laid out around it without overlap and joined to it by leader lines, as data for
//! the browser to draw as HTML or drawn into a rendered image.
//!
//! Visibility: the anchor must project inside the image and not lie behind the surface seen
//! there (depth buffer, with a relative tolerance plus the part's own radius, over a small
//! neighbourhood so anchors on silhouettes survive). Layout is greedy in input order (priority):
//! candidate label positions around the anchor at growing distances, then along the image
//! sides; overlaps with placed labels are forbidden, and the cost is the leader
//! length plus penalties for leaders crossing leaders or labels, labels covering anchors, and
//! labels hiding the model rather than the background ([`place`]; the browser's overlay runs
//! the same rule, `static/js/parts/place.js`).

use crate::camera::Camera;
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::font;

/// A part to label: id, anchor (e.g. the part's centre) and title.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalloutPart {
    pub part: i64,
    pub anchor: Vec3,
    pub title: String,
    /// Slack for the occlusion test in world units (e.g. the part's extent when the anchor is
    /// its centroid rather than a surface point).
    #[serde(default)]
    pub radius: f32,
}

/// Layout settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LayoutOptions {
    /// Font pixel size (1 = 5×7 glyphs).
    pub font_scale: u32,
    /// Space between text and label border.
    pub padding: u32,
    /// Smallest gap between labels and from the image border.
    pub margin: u32,
    /// Longer titles are cut with "...".
    pub max_chars: usize,
    /// Relative depth tolerance of the occlusion test.
    pub depth_tolerance: f32,
    /// Half size of the neighbourhood searched for the surface at the anchor.
    pub depth_window: u32,
}

impl Default for LayoutOptions {
    fn default() -> Self {
        LayoutOptions {
            font_scale: 2,
            padding: 4,
            margin: 4,
            max_chars: 40,
            depth_tolerance: 0.02,
            depth_window: 2,
        }
    }
}

impl LayoutOptions {
    /// Options scaled to an image height (font scale 1 below 400 pixels).
    pub fn for_height(height: u32) -> LayoutOptions {
        LayoutOptions {
            font_scale: if height < 400 { 1 } else { 2 },
            ..LayoutOptions::default()
        }
    }
}

/// Axis-aligned rectangle in pixels (x right, y down).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[cfg_attr(feature = "openapi", schema(as = CalloutRect))]
pub struct Rect {
    /// Left edge.
    pub x: f32,
    /// Top edge.
    pub y: f32,
    /// Width.
    pub w: f32,
    /// Height.
    pub h: f32,
}

impl Rect {
    fn overlaps(&self, o: &Rect, gap: f32) -> bool {
        self.x < o.x + o.w + gap
            && o.x < self.x + self.w + gap
            && self.y < o.y + o.h + gap
            && o.y < self.y + self.h + gap
    }

    fn contains(&self, p: Vec2) -> bool {
        p.x >= self.x && p.x <= self.x + self.w && p.y >= self.y && p.y <= self.y + self.h
    }

    /// Closest point of the rectangle to `p`.
    fn closest(&self, p: Vec2) -> Vec2 {
        Vec2::new(
            p.x.clamp(self.x, self.x + self.w),
            p.y.clamp(self.y, self.y + self.h),
        )
    }

    fn segment_crosses(&self, a: Vec2, b: Vec2) -> bool {
        if self.contains(a) || self.contains(b) {
            return true;
        }
        let c = [
            Vec2::new(self.x, self.y),
            Vec2::new(self.x + self.w, self.y),
            Vec2::new(self.x + self.w, self.y + self.h),
            Vec2::new(self.x, self.y + self.h),
        ];
        (0..4).any(|i| segments_cross(a, b, c[i], c[(i + 1) % 4]))
    }
}

/// Where a label went: around its anchor, or along an image side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum Placement {
    /// Near the anchor.
    Around,
    /// Along the left side of the image.
    Left,
    /// Along the right side.
    Right,
    /// Along the top.
    Top,
    /// Along the bottom.
    Bottom,
}

/// One placed callout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Callout {
    /// Part id.
    pub part: i64,
    /// The part's title.
    pub title: String,
    /// The text drawn in the label (long titles cut with "...").
    pub text: String,
    /// Anchor in pixels: x, y (y down).
    pub anchor: [f32; 2],
    /// View depth of the anchor.
    pub depth: f32,
    /// The label's rectangle in pixels.
    pub label: Rect,
    /// Leader line from the anchor to the label's nearest point: two pixel points x, y.
    pub leader: [[f32; 2]; 2],
    /// Where the label went.
    pub placement: Placement,
}

/// Why a part got no callout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum HiddenReason {
    /// Behind the camera.
    Behind,
    /// Projects outside the image.
    Outside,
    /// Hidden by the surface.
    Occluded,
    /// No free place for the label.
    NoRoom,
}

/// A part that got no callout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct HiddenCallout {
    /// Part id.
    pub part: i64,
    /// Why.
    pub reason: HiddenReason,
}

/// A label to place ([`place`]): its anchor and its size, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LabelBox {
    /// Anchor x, y (y down).
    pub anchor: [f32; 2],
    /// Label width and height.
    pub size: [f32; 2],
}

/// A part's label as [`place`] got it: the part, its anchor and its label size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct CalloutLabel {
    /// Part id.
    pub part: i64,
    /// Anchor in pixels: x, y (y down).
    pub anchor: [f32; 2],
    /// Label width and height in pixels (text in the 5×7 font plus padding).
    pub size: [f32; 2],
}

impl CalloutLabel {
    /// The placement input of this label.
    pub fn label_box(&self) -> LabelBox {
        LabelBox {
            anchor: self.anchor,
            size: self.size,
        }
    }
}

/// Where [`place`] put a label.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Placed {
    /// The label's rectangle.
    pub label: Rect,
    /// End of the leader line from the anchor: the label's point nearest to the anchor.
    pub end: [f32; 2],
    /// Where the label went.
    pub placement: Placement,
}

/// A callout layout for one image.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CalloutLayout {
    pub width: u32,
    pub height: u32,
    pub callouts: Vec<Callout>,
    pub hidden: Vec<HiddenCallout>,
    /// The input of the placement ([`place`]): every part whose anchor is visible, in
    /// priority order, with its label size. `callouts` and the `no_room` entries of `hidden`
    /// are these parts.
    #[serde(default)]
    pub labels: Vec<CalloutLabel>,
}

/// Why a layout could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalloutError {
    #[error("depth buffer has {len} values, image has {width}x{height} pixels")]
    DepthSize { width: u32, height: u32, len: usize },
    #[error("invalid camera: {0}")]
    Camera(#[from] crate::camera::CameraError),
}

fn orient(a: Vec2, b: Vec2, c: Vec2) -> f32 {
    (b - a).perp_dot(c - a)
}

/// Whether segments `ab` and `cd` properly cross (shared endpoints do not count).
fn segments_cross(a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> bool {
    let (o1, o2, o3, o4) = (
        orient(a, b, c),
        orient(a, b, d),
        orient(c, d, a),
        orient(c, d, b),
    );
    o1 * o2 < 0.0 && o3 * o4 < 0.0
}

fn cut_title(title: &str, max_chars: usize) -> String {
    let t: String = title
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    let t = t.trim();
    if t.chars().count() <= max_chars.max(4) {
        return t.to_string();
    }
    let keep: String = t.chars().take(max_chars.max(4) - 3).collect();
    format!("{}...", keep.trim_end())
}

/// Whether the anchor at pixel `(x, y)` and depth `d` is in front of (or on) the surface.
fn anchor_visible(
    depth: &[f32],
    size: (u32, u32),
    at: (f32, f32, f32),
    slack: f32,
    opts: &LayoutOptions,
) -> bool {
    let ((width, height), (x, y, d)) = (size, at);
    let (cx, cy) = (x.floor() as i64, y.floor() as i64);
    let r = opts.depth_window as i64;
    let limit = d * (1.0 - opts.depth_tolerance.max(0.0)) - slack.max(0.0);
    for py in (cy - r).max(0)..=(cy + r).min(height as i64 - 1) {
        for px in (cx - r).max(0)..=(cx + r).min(width as i64 - 1) {
            let s = depth[py as usize * width as usize + px as usize];
            if s >= limit || s.is_nan() {
                return true;
            }
        }
    }
    false
}

/// Cost of a label lying entirely over the model rather than the background.
const COVER_PENALTY: f32 = 150.0;

/// Share of a label's area over the surface (sampled every few pixels).
fn surface_share(depth: &[f32], width: u32, r: &Rect) -> f32 {
    let (mut n, mut over) = (0u32, 0u32);
    let mut y = r.y + 1.0;
    while y < r.y + r.h {
        let mut x = r.x + 1.0;
        while x < r.x + r.w {
            let i = y as usize * width as usize + x as usize;
            if let Some(d) = depth.get(i) {
                n += 1;
                over += d.is_finite() as u32;
            }
            x += 4.0;
        }
        y += 4.0;
    }
    if n == 0 { 0.0 } else { over as f32 / n as f32 }
}

/// Lays out callouts for `parts` seen by `camera` (image size from the camera). `depth` is the
/// frame's linear depth buffer (`None`: no occlusion test, no cover penalty).
///
/// The visible parts (in input order, which is their priority) get their titles cut to
/// `max_chars` and a label of the 5×7 font's size plus padding; [`place`] then places the
/// labels (§2.2), with `depth` for its cover penalty.
pub fn layout(
    parts: &[CalloutPart],
    camera: &Camera,
    depth: Option<&[f32]>,
    opts: &LayoutOptions,
) -> Result<CalloutLayout, CalloutError> {
    camera.validate()?;
    let (w, h) = (camera.width, camera.height);
    if let Some(d) = depth
        && d.len() as u64 != w as u64 * h as u64
    {
        return Err(CalloutError::DepthSize {
            width: w,
            height: h,
            len: d.len(),
        });
    }
    let mut out = CalloutLayout {
        width: w,
        height: h,
        ..Default::default()
    };
    // Visible anchors.
    let mut visible = Vec::new();
    for p in parts {
        let reason = if !p.anchor.is_finite() {
            Some(HiddenReason::Behind)
        } else {
            match camera.project(p.anchor) {
                None => Some(HiddenReason::Behind),
                Some((x, y, _)) if !(x >= 0.0 && y >= 0.0 && x < w as f32 && y < h as f32) => {
                    Some(HiddenReason::Outside)
                }
                Some((x, y, d)) => match depth {
                    Some(buf) if !anchor_visible(buf, (w, h), (x, y, d), p.radius, opts) => {
                        Some(HiddenReason::Occluded)
                    }
                    _ => {
                        visible.push((p, Vec2::new(x, y), d));
                        None
                    }
                },
            }
        };
        if let Some(reason) = reason {
            out.hidden.push(HiddenCallout {
                part: p.part,
                reason,
            });
        }
    }
    // Texts and label sizes.
    let scale = opts.font_scale.max(1);
    let pad = opts.padding as f32;
    let mut texts = Vec::with_capacity(visible.len());
    for (p, a, _) in &visible {
        let text = cut_title(&p.title, opts.max_chars);
        let lw = font::text_width(&text, scale) as f32 + 2.0 * pad;
        let lh = (font::LINE_H * scale) as f32 + 2.0 * pad;
        out.labels.push(CalloutLabel {
            part: p.part,
            anchor: [a.x, a.y],
            size: [lw, lh],
        });
        texts.push(text);
    }
    let boxes: Vec<LabelBox> = out.labels.iter().map(CalloutLabel::label_box).collect();
    let spots = place(&boxes, w, h, opts.margin as f32, depth);
    for (((p, a, d), text), spot) in visible.iter().zip(texts).zip(spots) {
        match spot {
            Some(s) => out.callouts.push(Callout {
                part: p.part,
                title: p.title.clone(),
                text,
                anchor: [a.x, a.y],
                depth: *d,
                label: s.label,
                leader: [[a.x, a.y], s.end],
                placement: s.placement,
            }),
            None => out.hidden.push(HiddenCallout {
                part: p.part,
                reason: HiddenReason::NoRoom,
            }),
        }
    }
    Ok(out)
}

/// Directions of the candidates around an anchor, in the order they are tried.
const AROUND_DIRECTIONS: [[f32; 2]; 8] = [
    [1.0, -1.0],
    [-1.0, -1.0],
    [1.0, 1.0],
    [-1.0, 1.0],
    [1.0, 0.0],
    [-1.0, 0.0],
    [0.0, -1.0],
    [0.0, 1.0],
];

/// Distances (pixels) of the candidates around an anchor, nearest first.
const AROUND_DISTANCES: [f32; 5] = [16.0, 32.0, 56.0, 88.0, 128.0];

/// Cost added to candidates along an image side.
const SIDE_COST: f32 = 40.0;
/// Cost of a leader crossing a placed leader.
const CROSS_LEADER_PENALTY: f32 = 1000.0;
/// Cost of a leader crossing a placed label, or of a label crossing a placed leader.
const CROSS_LABEL_PENALTY: f32 = 500.0;
/// Cost of a label covering (or coming within [`ANCHOR_GAP`] of) another part's anchor.
const ANCHOR_PENALTY: f32 = 300.0;
/// Gap around other anchors for [`ANCHOR_PENALTY`].
const ANCHOR_GAP: f32 = 4.0;

/// The candidate rectangles of a `size` label for `anchor` in a `width`×`height` image, in
/// the order [`place`] tries them, with their kind and base cost: around the anchor (each
/// distance of [`AROUND_DISTANCES`] in every direction of [`AROUND_DIRECTIONS`], the label's
/// centre offset by the distance plus half the label horizontally and by ¾ of the distance
/// plus half the label vertically), then along the left and right sides (rows `margin`
/// apart from the anchor's outwards, alternately below and above), then along the top and
/// bottom (columns half a label plus `margin` apart, alternately right and left). Positions
/// are rounded to whole pixels; candidates may lie outside the image (`place` skips them).
fn candidates(
    anchor: Vec2,
    size: Vec2,
    width: u32,
    height: u32,
    margin: f32,
) -> Vec<(Rect, Placement, f32)> {
    let (a, lw, lh, gap) = (anchor, size.x, size.y, margin);
    let (w, h) = (width as f32, height as f32);
    let mut out = Vec::new();
    for dist in AROUND_DISTANCES {
        for [dx, dy] in AROUND_DIRECTIONS {
            let c = a + Vec2::new(dx * (dist + lw * 0.5), dy * (dist * 0.75 + lh * 0.5));
            out.push((
                Rect {
                    x: (c.x - lw * 0.5).round(),
                    y: (c.y - lh * 0.5).round(),
                    w: lw,
                    h: lh,
                },
                Placement::Around,
                0.0,
            ));
        }
    }
    let step = lh + gap;
    for i in 0..((h / step) as i32 + 1) {
        for sign in [1.0f32, -1.0] {
            let y = (a.y - lh * 0.5 + sign * i as f32 * step).round();
            for (x, place) in [(gap, Placement::Left), (w - gap - lw, Placement::Right)] {
                out.push((Rect { x, y, w: lw, h: lh }, place, SIDE_COST));
            }
        }
    }
    let hstep = lw * 0.5 + gap;
    for i in 0..((w / hstep) as i32 + 1) {
        for sign in [1.0f32, -1.0] {
            let x = (a.x - lw * 0.5 + sign * i as f32 * hstep).round();
            for (y, place) in [(gap, Placement::Top), (h - gap - lh, Placement::Bottom)] {
                out.push((Rect { x, y, w: lw, h: lh }, place, SIDE_COST));
            }
        }
    }
    out
}

/// Places labels (system paper §2.2) in a `width`×`height` image: greedily, in the order of
/// `items` (their priority), each label at the cheapest of its candidates (see
/// `candidates`: around the anchor at growing distances, then along the image sides) that
/// lies at least `margin` inside the image and at least `margin` away from every label placed
/// before. The cost is the leader's length (anchor to the label's nearest point), plus
/// `SIDE_COST` along the sides, `CROSS_LEADER_PENALTY` for each placed leader the leader
/// crosses, `CROSS_LABEL_PENALTY` for each placed label the leader crosses and each placed
/// leader the label crosses, `ANCHOR_PENALTY` for each other item's anchor the label covers,
/// and, with a `cover` depth buffer (row-major, `width`×`height`, finite on the model),
/// `COVER_PENALTY` times the share of the label hiding the model rather than the background.
/// The first candidate of strictly lowest cost wins. `None` where no candidate is free.
///
/// The browser's overlay runs the same rule (`static/js/parts/place.js`, `placeLabels`,
/// checked against this one by `tests/browser/callouts.test.mjs`).
pub fn place(
    items: &[LabelBox],
    width: u32,
    height: u32,
    margin: f32,
    cover: Option<&[f32]>,
) -> Vec<Option<Placed>> {
    let (w, h, gap) = (width as f32, height as f32, margin);
    let anchors: Vec<Vec2> = items.iter().map(|it| Vec2::from(it.anchor)).collect();
    // Placed labels and their leaders.
    let mut placed: Vec<(Rect, Vec2, Vec2)> = Vec::new();
    let mut out = Vec::with_capacity(items.len());
    for (k, item) in items.iter().enumerate() {
        let a = anchors[k];
        let mut best: Option<(f32, Rect, Placement, Vec2)> = None;
        for (r, kind, base) in candidates(a, Vec2::from(item.size), width, height, gap) {
            if r.x < gap || r.y < gap || r.x + r.w > w - gap || r.y + r.h > h - gap {
                continue;
            }
            if placed.iter().any(|(l, _, _)| l.overlaps(&r, gap)) {
                continue;
            }
            let end = r.closest(a);
            let mut cost = base + a.distance(end);
            // Penalties are never negative: a candidate already as dear as the best loses.
            if best.as_ref().is_some_and(|b| cost >= b.0) {
                continue;
            }
            if let Some(buf) = cover {
                cost += COVER_PENALTY * surface_share(buf, width, &r);
            }
            for (l, s0, s1) in &placed {
                let (s0, s1) = (*s0, *s1);
                if segments_cross(a, end, s0, s1) {
                    cost += CROSS_LEADER_PENALTY;
                }
                if l.segment_crosses(a, end) {
                    cost += CROSS_LABEL_PENALTY;
                }
                if r.segment_crosses(s0, s1) {
                    cost += CROSS_LABEL_PENALTY;
                }
            }
            for (j, other) in anchors.iter().enumerate() {
                if j != k
                    && r.overlaps(
                        &Rect {
                            x: other.x,
                            y: other.y,
                            w: 0.0,
                            h: 0.0,
                        },
                        ANCHOR_GAP,
                    )
                {
                    cost += ANCHOR_PENALTY;
                }
            }
            if best.as_ref().is_none_or(|b| cost < b.0) {
                best = Some((cost, r, kind, end));
            }
        }
        out.push(best.map(|(_, r, kind, end)| {
            placed.push((r, a, end));
            Placed {
                label: r,
                end: [end.x, end.y],
                placement: kind,
            }
        }));
    }
    out
}

/// Colours of drawn callouts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalloutStyle {
    pub line: [u8; 4],
    pub halo: [u8; 4],
    pub fill: [u8; 4],
    pub border: [u8; 4],
    pub text: [u8; 4],
    pub font_scale: u32,
}

impl Default for CalloutStyle {
    fn default() -> Self {
        CalloutStyle {
            line: [24, 24, 24, 255],
            halo: [255, 255, 255, 200],
            fill: [255, 255, 255, 225],
            border: [24, 24, 24, 255],
            text: [16, 16, 16, 255],
            font_scale: 2,
        }
    }
}

fn blend(dst: &mut [u8; 4], src: [u8; 4]) {
    let a = src[3] as u32;
    for k in 0..3 {
        dst[k] = ((src[k] as u32 * a + dst[k] as u32 * (255 - a) + 127) / 255) as u8;
    }
    dst[3] = (a + dst[3] as u32 * (255 - a) / 255).min(255) as u8;
}

struct Canvas<'a> {
    img: &'a mut [[u8; 4]],
    w: i64,
    h: i64,
}

impl Canvas<'_> {
    fn put(&mut self, x: i64, y: i64, c: [u8; 4]) {
        if x >= 0 && y >= 0 && x < self.w && y < self.h {
            blend(&mut self.img[(y * self.w + x) as usize], c);
        }
    }

    fn fill(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 4]) {
        for y in y0.max(0)..y1.min(self.h) {
            for x in x0.max(0)..x1.min(self.w) {
                blend(&mut self.img[(y * self.w + x) as usize], c);
            }
        }
    }

    /// A line `thickness` pixels wide (squares stamped along a DDA walk).
    fn line(&mut self, a: Vec2, b: Vec2, thickness: i64, c: [u8; 4]) {
        let steps = (b - a).abs().max_element().ceil().max(1.0) as i64;
        let mut last = None;
        for i in 0..=steps {
            let p = a + (b - a) * (i as f32 / steps as f32);
            let (x, y) = (p.x.floor() as i64, p.y.floor() as i64);
            if last == Some((x, y)) {
                continue;
            }
            last = Some((x, y));
            let o = thickness / 2;
            for dy in 0..thickness {
                for dx in 0..thickness {
                    let (px, py) = (x + dx - o, y + dy - o);
                    if px >= 0 && py >= 0 && px < self.w && py < self.h {
                        self.img[(py * self.w + px) as usize] = c;
                    }
                }
            }
        }
    }

    fn disc(&mut self, cx: f32, cy: f32, r: f32, c: [u8; 4]) {
        let ri = r.ceil() as i64 + 1;
        let (x0, y0) = (cx.floor() as i64, cy.floor() as i64);
        for y in y0 - ri..=y0 + ri {
            for x in x0 - ri..=x0 + ri {
                let d = Vec2::new(x as f32 + 0.5 - cx, y as f32 + 0.5 - cy).length();
                if d <= r {
                    self.put(x, y, c);
                }
            }
        }
    }
}

/// Draws a layout into an RGBA8 image of the layout's size (leaders, anchor dots, boxed
/// labels); does nothing if the image size does not match.
pub fn draw(img: &mut [[u8; 4]], layout: &CalloutLayout, style: &CalloutStyle) {
    let (w, h) = (layout.width as i64, layout.height as i64);
    if img.len() as i64 != w * h {
        return;
    }
    let mut cv = Canvas { img, w, h };
    for c in &layout.callouts {
        let (a, b) = (Vec2::from(c.leader[0]), Vec2::from(c.leader[1]));
        cv.line(a, b, 4, style.halo);
    }
    for c in &layout.callouts {
        let (a, b) = (Vec2::from(c.leader[0]), Vec2::from(c.leader[1]));
        cv.line(a, b, 2, style.line);
        cv.disc(a.x, a.y, 4.5, style.halo);
        cv.disc(a.x, a.y, 3.0, style.line);
    }
    for c in &layout.callouts {
        let r = c.label;
        let (x0, y0) = (r.x.round() as i64, r.y.round() as i64);
        let (x1, y1) = (x0 + r.w.round() as i64, y0 + r.h.round() as i64);
        cv.fill(x0, y0, x1, y1, style.fill);
        cv.fill(x0, y0, x1, y0 + 1, style.border);
        cv.fill(x0, y1 - 1, x1, y1, style.border);
        cv.fill(x0, y0, x0 + 1, y1, style.border);
        cv.fill(x1 - 1, y0, x1, y1, style.border);
        let scale = style.font_scale.max(1);
        let th = (font::LINE_H * scale) as i64;
        let tw = font::text_width(&c.text, scale) as i64;
        let tx = x0 + ((x1 - x0) - tw) / 2;
        let ty = y0 + ((y1 - y0) - th) / 2;
        font::draw_text(
            cv.img,
            (layout.width, layout.height),
            (tx as i32, ty as i32),
            &c.text,
            scale,
            style.text,
        );
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
            width: 400,
            height: 300,
        }
    }

    fn part(id: i64, x: f32, y: f32, z: f32, title: &str) -> CalloutPart {
        CalloutPart {
            part: id,
            anchor: Vec3::new(x, y, z),
            title: title.into(),
            radius: 0.0,
        }
    }

    #[test]
    fn hides_behind_outside_and_occluded() {
        let c = cam();
        // A wall at depth 4 covering the left half of the image.
        let depth: Vec<f32> = (0..400 * 300)
            .map(|i| if i % 400 < 200 { 4.0 } else { f32::INFINITY })
            .collect();
        let parts = [
            part(1, 0.0, 0.0, 10.0, "behind"),
            part(2, 50.0, 0.0, 0.0, "outside"),
            part(3, -0.5, 0.0, 0.0, "occluded"),
            part(4, 0.5, 0.0, 0.0, "visible"),
            part(5, -0.5, 0.2, 1.1, "in front of the wall"),
        ];
        let l = layout(&parts, &c, Some(&depth), &LayoutOptions::default()).expect("layout");
        let hidden: Vec<(i64, HiddenReason)> =
            l.hidden.iter().map(|h| (h.part, h.reason)).collect();
        assert_eq!(
            hidden,
            vec![
                (1, HiddenReason::Behind),
                (2, HiddenReason::Outside),
                (3, HiddenReason::Occluded)
            ]
        );
        let shown: Vec<i64> = l.callouts.iter().map(|c| c.part).collect();
        assert_eq!(shown, vec![4, 5]);
        assert!(layout(&parts, &c, Some(&depth[1..]), &LayoutOptions::default()).is_err());
    }

    #[test]
    fn labels_do_not_overlap_and_stay_inside() {
        let c = cam();
        let parts: Vec<CalloutPart> = (0..12)
            .map(|i| {
                let t = i as f32 * 0.5;
                part(
                    i,
                    0.3 * t.cos(),
                    0.3 * t.sin(),
                    0.0,
                    &format!("Part number {i} with a long title"),
                )
            })
            .collect();
        let l = layout(&parts, &c, None, &LayoutOptions::for_height(300)).expect("layout");
        assert!(l.callouts.len() >= 8, "{} placed", l.callouts.len());
        for (i, a) in l.callouts.iter().enumerate() {
            let r = a.label;
            assert!(r.x >= 0.0 && r.y >= 0.0 && r.x + r.w <= 400.0 && r.y + r.h <= 300.0);
            for b in &l.callouts[i + 1..] {
                assert!(!a.label.overlaps(&b.label, 0.0), "{a:?} overlaps {b:?}");
            }
        }
        let mut img = vec![[90u8, 90, 90, 255]; 400 * 300];
        draw(&mut img, &l, &CalloutStyle::default());
        assert!(img.contains(&[16, 16, 16, 255]), "text drawn");
    }

    #[test]
    fn place_is_the_layouts_placement() {
        let c = cam();
        let parts: Vec<CalloutPart> = (0..30)
            .map(|i| {
                let t = i as f32 * 0.7;
                let title = "Carving ".repeat(1 + i as usize % 5);
                part(i, 0.5 * t.cos(), 0.4 * t.sin(), 0.0, &title)
            })
            .collect();
        // Background on the left, model on the right: the cover penalty matters.
        let depth: Vec<f32> = (0..200 * 150)
            .map(|i| if i % 200 < 100 { f32::INFINITY } else { 6.0 })
            .collect();
        let c = Camera {
            width: 200,
            height: 150,
            ..c
        };
        let opts = LayoutOptions::for_height(150);
        let l = layout(&parts, &c, Some(&depth), &opts).expect("layout");
        assert_eq!(l.labels.len(), 30);
        let boxes: Vec<LabelBox> = l.labels.iter().map(CalloutLabel::label_box).collect();
        let spots = place(&boxes, 200, 150, opts.margin as f32, Some(&depth));
        let mut shown = l.callouts.iter();
        let mut no_room = l.hidden.iter().filter(|h| h.reason == HiddenReason::NoRoom);
        for (label, spot) in l.labels.iter().zip(&spots) {
            match spot {
                Some(s) => {
                    let c = shown.next().expect("a callout");
                    assert_eq!(c.part, label.part);
                    assert_eq!(
                        (c.label, c.leader[1], c.placement),
                        (s.label, s.end, s.placement)
                    );
                    assert_eq!([c.label.w, c.label.h], label.size);
                }
                None => assert_eq!(no_room.next().map(|h| h.part), Some(label.part)),
            }
        }
        assert!(shown.next().is_none() && no_room.next().is_none());
        assert!(
            spots.iter().any(Option::is_none),
            "crowded: some labels find no room"
        );
        let without = place(&boxes, 200, 150, opts.margin as f32, None);
        assert_ne!(spots, without, "the cover penalty changes the layout");
        // One label alone: the shortest leader, straight up (not the first candidate, up
        // and to the right).
        let one = place(
            &[LabelBox {
                anchor: [100.5, 75.5],
                size: [40.0, 15.0],
            }],
            200,
            150,
            4.0,
            None,
        );
        let s = one[0].expect("placed");
        assert_eq!(s.placement, Placement::Around);
        assert_eq!((s.label.x, s.label.y), (81.0, 49.0));
        assert_eq!(s.end, [100.5, 64.0]);
        assert!(place(&[], 10, 10, 4.0, None).is_empty());
    }

    #[test]
    fn segment_crossing() {
        let v = |x: f32, y: f32| Vec2::new(x, y);
        assert!(segments_cross(
            v(0.0, 0.0),
            v(2.0, 2.0),
            v(0.0, 2.0),
            v(2.0, 0.0)
        ));
        assert!(!segments_cross(
            v(0.0, 0.0),
            v(1.0, 0.0),
            v(0.0, 1.0),
            v(1.0, 1.0)
        ));
        assert_eq!(cut_title("abcdefghij", 6), "abc...");
        assert_eq!(cut_title("  short\n", 40), "short");
    }
}
