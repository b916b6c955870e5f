//! Selection modes (system paper §4.1.1: "If users are not satisfied with the result, they can
//! add and remove markers"; issue: a region is grown or trimmed from other viewpoints):
//! **replace** the base set by the new selection, **add** the new selection to it, or
//! **subtract** it. Sets are original vertex ids, so combining views is exact.
//!
//! The centre of a combined set is kept as the sum of its vertex positions: the new view knows
//! the positions of the vertices it selected and which of them were already in the base, and
//! the base's sum is its centre times its count (exact for sets made by selections).

use glam::Vec3;
use roaring::RoaringBitmap;

use super::backproject::{BackProjection, nearest};

/// How a new selection combines with the existing set.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// The new selection replaces the set.
    #[default]
    Replace,
    /// Union.
    Add,
    /// Difference.
    Subtract,
}

impl Mode {
    /// Name as in the API.
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Replace => "replace",
            Mode::Add => "add",
            Mode::Subtract => "subtract",
        }
    }
}

/// A vertex set with the sum of its positions and an anchor on its surface.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VertexSet {
    pub vertices: RoaringBitmap,
    pub sum: [f64; 3],
    pub anchor: Option<[f32; 3]>,
}

impl VertexSet {
    /// Mean position, if not empty.
    pub fn centroid(&self) -> Option<[f64; 3]> {
        let n = self.vertices.len();
        (n > 0).then(|| self.sum.map(|s| s / n as f64))
    }

    /// The set of a back-projection on its own.
    pub fn of(bp: &BackProjection) -> VertexSet {
        VertexSet {
            vertices: bp.vertices.clone(),
            sum: bp.sum,
            anchor: bp.anchor,
        }
    }
}

/// Combines `base` with the new selection `bp` (made with `base` passed to
/// [`super::back_project`]) in `mode`.
pub fn combine(base: &VertexSet, bp: &BackProjection, mode: Mode) -> VertexSet {
    let (vertices, sum) = match mode {
        Mode::Replace => return VertexSet::of(bp),
        Mode::Add => (
            &base.vertices | &bp.vertices,
            std::array::from_fn(|k| base.sum[k] + bp.sum[k] - bp.sum_in_base[k]),
        ),
        Mode::Subtract => (
            &base.vertices - &bp.vertices,
            std::array::from_fn(|k| base.sum[k] - bp.sum_in_base[k]),
        ),
    };
    let mut out = VertexSet {
        vertices,
        sum,
        anchor: None,
    };
    let Some(c) = out.centroid() else {
        return out;
    };
    let c = Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32);
    out.anchor = match mode {
        Mode::Add => nearest(
            bp.positions
                .iter()
                .copied()
                .chain(base.anchor.map(|a| (0, a))),
            c,
        ),
        _ => {
            // The base anchor stays unless this view removed it; else the centroid.
            let removed = base.anchor.is_some_and(|a| {
                bp.positions
                    .iter()
                    .any(|(id, p)| *p == a && base.vertices.contains(*id))
            });
            match base.anchor {
                Some(a) if !removed => Some(a),
                _ => Some(c.into()),
            }
        }
    };
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bp(ids: &[u32], base: &RoaringBitmap) -> BackProjection {
        let mut b = BackProjection::default();
        for &id in ids {
            let p = [id as f32, 0.0, 0.0];
            b.vertices.insert(id);
            b.sum[0] += p[0] as f64;
            if base.contains(id) {
                b.count_in_base += 1;
                b.sum_in_base[0] += p[0] as f64;
            }
            b.positions.push((id, p));
        }
        b.anchor = b.positions.first().map(|p| p.1);
        b
    }

    fn set(ids: &[u32]) -> VertexSet {
        VertexSet {
            vertices: ids.iter().copied().collect(),
            sum: [ids.iter().map(|&i| i as f64).sum(), 0.0, 0.0],
            anchor: ids.first().map(|&i| [i as f32, 0.0, 0.0]),
        }
    }

    #[test]
    fn replace_add_subtract() {
        let base = set(&[1, 2, 3, 4]);
        let new = bp(&[3, 4, 5, 6], &base.vertices);
        let r = combine(&base, &new, Mode::Replace);
        assert_eq!(r.vertices.iter().collect::<Vec<_>>(), vec![3, 4, 5, 6]);
        let a = combine(&base, &new, Mode::Add);
        assert_eq!(
            a.vertices.iter().collect::<Vec<_>>(),
            vec![1, 2, 3, 4, 5, 6]
        );
        assert_eq!(a.sum[0], 21.0);
        assert_eq!(a.centroid().unwrap()[0], 3.5);
        let s = combine(&base, &new, Mode::Subtract);
        assert_eq!(s.vertices.iter().collect::<Vec<_>>(), vec![1, 2]);
        assert_eq!(s.sum[0], 3.0);
        assert_eq!(s.anchor, Some([1.0, 0.0, 0.0]));
        let all = combine(&base, &bp(&[1, 2, 3, 4], &base.vertices), Mode::Subtract);
        assert!(all.vertices.is_empty() && all.anchor.is_none());
    }
}
