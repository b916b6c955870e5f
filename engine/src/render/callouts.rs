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
//! labels hiding the model rather than the background.

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
pub struct Rect {
    pub x: f32,
    pub y: f32,
    pub w: f32,
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

/// Where a label went.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Placement {
    Around,
    Left,
    Right,
    Top,
    Bottom,
}

/// One placed callout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Callout {
    pub part: i64,
    pub title: String,
    /// The text drawn in the label (cut to `max_chars`).
    pub text: String,
    /// Anchor in pixels and its view depth.
    pub anchor: [f32; 2],
    pub depth: f32,
    pub label: Rect,
    /// Leader line from the anchor to the label's nearest point.
    pub leader: [[f32; 2]; 2],
    pub placement: Placement,
}

/// Why a part got no callout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
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

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct HiddenCallout {
    pub part: i64,
    pub reason: HiddenReason,
}

/// A callout layout for one image.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CalloutLayout {
    pub width: u32,
    pub height: u32,
    pub callouts: Vec<Callout>,
    pub hidden: Vec<HiddenCallout>,
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
/// frame's linear depth buffer (`None`: no occlusion test).
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
    let scale = opts.font_scale.max(1);
    let pad = opts.padding as f32;
    let gap = opts.margin as f32;
    let anchors: Vec<Vec2> = visible.iter().map(|v| v.1).collect();
    let mut placed: Vec<Callout> = Vec::new();
    for (k, (p, a, d)) in visible.iter().enumerate() {
        let text = cut_title(&p.title, opts.max_chars);
        let lw = font::text_width(&text, scale) as f32 + 2.0 * pad;
        let lh = (font::LINE_H * scale) as f32 + 2.0 * pad;
        let mut candidates: Vec<(Rect, Placement, f32)> = Vec::new();
        let dirs = [
            Vec2::new(1.0, -1.0),
            Vec2::new(-1.0, -1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(-1.0, 1.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(-1.0, 0.0),
            Vec2::new(0.0, -1.0),
            Vec2::new(0.0, 1.0),
        ];
        for dist in [16.0f32, 32.0, 56.0, 88.0, 128.0] {
            for dir in dirs {
                let c = *a + Vec2::new(dir.x * (dist + lw * 0.5), dir.y * (dist * 0.75 + lh * 0.5));
                candidates.push((
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
        for i in 0..((h as f32 / step) as i32 + 1) {
            for sign in [1.0f32, -1.0] {
                let y = (a.y - lh * 0.5 + sign * i as f32 * step).round();
                for (x, place) in [
                    (gap, Placement::Left),
                    (w as f32 - gap - lw, Placement::Right),
                ] {
                    candidates.push((Rect { x, y, w: lw, h: lh }, place, 40.0));
                }
            }
        }
        let hstep = lw * 0.5 + gap;
        for i in 0..((w as f32 / hstep) as i32 + 1) {
            for sign in [1.0f32, -1.0] {
                let x = (a.x - lw * 0.5 + sign * i as f32 * hstep).round();
                for (y, place) in [
                    (gap, Placement::Top),
                    (h as f32 - gap - lh, Placement::Bottom),
                ] {
                    candidates.push((Rect { x, y, w: lw, h: lh }, place, 40.0));
                }
            }
        }
        let mut best: Option<(f32, Rect, Placement, Vec2)> = None;
        for (r, place, base) in candidates {
            if r.x < gap || r.y < gap || r.x + r.w > w as f32 - gap || r.y + r.h > h as f32 - gap {
                continue;
            }
            if placed.iter().any(|c| c.label.overlaps(&r, gap)) {
                continue;
            }
            let end = r.closest(*a);
            let mut cost = base + a.distance(end);
            if let Some(buf) = depth {
                cost += COVER_PENALTY * surface_share(buf, w, &r);
            }
            for c in &placed {
                let (s0, s1) = (Vec2::from(c.leader[0]), Vec2::from(c.leader[1]));
                if segments_cross(*a, end, s0, s1) {
                    cost += 1000.0;
                }
                if c.label.segment_crosses(*a, end) {
                    cost += 500.0;
                }
                if r.segment_crosses(s0, s1) {
                    cost += 500.0;
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
                        4.0,
                    )
                {
                    cost += 300.0;
                }
            }
            if best.as_ref().is_none_or(|b| cost < b.0) {
                best = Some((cost, r, place, end));
            }
        }
        match best {
            Some((_, r, place, end)) => placed.push(Callout {
                part: p.part,
                title: p.title.clone(),
                text,
                anchor: [a.x, a.y],
                depth: *d,
                label: r,
                leader: [[a.x, a.y], [end.x, end.y]],
                placement: place,
            }),
            None => out.hidden.push(HiddenCallout {
                part: p.part,
                reason: HiddenReason::NoRoom,
            }),
        }
    }
    out.callouts = placed;
    Ok(out)
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
