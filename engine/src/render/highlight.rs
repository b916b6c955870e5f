//! Highlighted parts (system paper §2.2: regions with information are shown on the model, the
//! hovered one with bold boundary lines). Parts are sets of original vertex ids, so the marks
//! are exact at every level of the hierarchy: a patch vertex is marked iff its original id is in
//! the part. Masks are computed on the CPU for the patches drawn and uploaded with each draw.

use roaring::RoaringBitmap;

/// Mask bit of vertices of an outlined (hovered) part. Masks use 9 bits (the shader packs
/// three per triangle).
pub const OUTLINE_BIT: u32 = 1 << 8;
/// Mask bits holding the tint index (1-based; 0 = not tinted).
pub const TINT_MASK: u32 = 0xFF;
/// Most tinted parts in one render.
pub const MAX_TINTS: usize = 255;

/// A part to show: its original vertex ids, an optional tint (`[r, g, b, strength]`) and
/// whether it gets the bold outline (the hovered part).
#[derive(Debug, Clone, Copy)]
pub struct Highlight<'a> {
    pub vertices: &'a RoaringBitmap,
    pub tint: Option<[u8; 4]>,
    pub outline: bool,
}

/// Default tint colours, cycled over parts (strength ~55%).
pub const TINTS: [[u8; 4]; 8] = [
    [255, 176, 0, 140],
    [0, 160, 255, 140],
    [230, 40, 120, 140],
    [60, 200, 80, 140],
    [150, 90, 255, 140],
    [255, 90, 40, 140],
    [0, 200, 190, 140],
    [200, 200, 40, 140],
];

/// Parts prepared for one render: each with its mask code, and the tint palette.
pub(crate) struct Prepared<'a> {
    parts: Vec<(&'a RoaringBitmap, u32, u32, u32)>,
    pub palette: Vec<[f32; 4]>,
    pub any_outline: bool,
}

impl<'a> Prepared<'a> {
    /// Assigns tint indices in order; `None` when more than [`MAX_TINTS`] parts are tinted.
    pub fn new(highlights: &[Highlight<'a>]) -> Option<Prepared<'a>> {
        let mut palette = vec![[0f32; 4]; 256];
        let mut parts = Vec::new();
        let mut next = 1usize;
        for h in highlights {
            let mut code = 0u32;
            if let Some(t) = h.tint {
                if next > MAX_TINTS {
                    return None;
                }
                palette[next] = t.map(|c| c as f32 / 255.0);
                code |= next as u32;
                next += 1;
            }
            if h.outline {
                code |= OUTLINE_BIT;
            }
            if code != 0 && !h.vertices.is_empty() {
                let (lo, hi) = (h.vertices.min().unwrap_or(0), h.vertices.max().unwrap_or(0));
                parts.push((h.vertices, code, lo, hi));
            }
        }
        let any_outline = parts.iter().any(|p| p.1 & OUTLINE_BIT != 0);
        Some(Prepared {
            parts,
            palette,
            any_outline,
        })
    }

    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }

    /// Per-vertex masks of a patch (tint index of the first tinted part holding the vertex,
    /// `OUTLINE_BIT` if an outlined part holds it); `None` when no vertex is marked.
    pub fn masks(&self, ids: &[u32], range: (u32, u32)) -> Option<Vec<u32>> {
        let relevant: Vec<(&RoaringBitmap, u32)> = self
            .parts
            .iter()
            .filter(|(b, _, lo, hi)| {
                *lo <= range.1 && *hi >= range.0 && b.range_cardinality(range.0..=range.1) > 0
            })
            .map(|(b, c, _, _)| (*b, *c))
            .collect();
        if relevant.is_empty() {
            return None;
        }
        let mut any = false;
        let masks = ids
            .iter()
            .map(|&id| {
                let mut m = 0u32;
                for (b, code) in &relevant {
                    if (m & TINT_MASK != 0 || code & TINT_MASK == 0)
                        && (m & OUTLINE_BIT != 0 || code & OUTLINE_BIT == 0)
                    {
                        continue;
                    }
                    if b.contains(id) {
                        if m & TINT_MASK == 0 {
                            m |= code & TINT_MASK;
                        }
                        m |= code & OUTLINE_BIT;
                    }
                }
                any |= m != 0;
                m
            })
            .collect();
        any.then_some(masks)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_tint_wins_and_outline_accumulates() {
        let a: RoaringBitmap = [1u32, 2, 3].into_iter().collect();
        let b: RoaringBitmap = [3u32, 4].into_iter().collect();
        let c: RoaringBitmap = [4u32, 9].into_iter().collect();
        let hs = [
            Highlight {
                vertices: &a,
                tint: Some([255, 0, 0, 128]),
                outline: false,
            },
            Highlight {
                vertices: &b,
                tint: Some([0, 255, 0, 128]),
                outline: false,
            },
            Highlight {
                vertices: &c,
                tint: None,
                outline: true,
            },
        ];
        let p = Prepared::new(&hs).expect("palette");
        let m = p.masks(&[0, 1, 3, 4, 9, 100], (0, 100)).expect("marked");
        assert_eq!(m, vec![0, 1, 1, 2 | OUTLINE_BIT, OUTLINE_BIT, 0]);
        assert!(p.masks(&[50, 60], (50, 60)).is_none());
        assert!(p.any_outline);
    }

    #[test]
    fn too_many_tints() {
        let a: RoaringBitmap = [1u32].into_iter().collect();
        let hs: Vec<Highlight> = (0..256)
            .map(|_| Highlight {
                vertices: &a,
                tint: Some([1, 2, 3, 4]),
                outline: false,
            })
            .collect();
        assert!(Prepared::new(&hs).is_none());
        assert!(Prepared::new(&hs[..255]).is_some());
    }
}
