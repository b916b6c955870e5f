//! Ground truth from the benchmark's files: an ASCII OFF mesh and a `.seg` segmentation (one
//! segment per face) become regions — the vertices of one segment's faces, with the centroid,
//! mean normal and extent that frame them (as `engine::render::best_view` frames a part).
//! Vertex ids are the OFF file's vertex indices; [`renumbered`] maps them to the ids of a model
//! built in the default Morton vertex order (`docs/FORMAT.md`, "Vertex ids").

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result, bail};
use glam::Vec3;
use meshwiki_engine::render::best_view::PartGeometry;
use roaring::RoaringBitmap;

/// A triangle mesh of the benchmark, as its OFF file has it.
#[derive(Debug, Clone)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Faces (fan-triangulated polygons keep their face's index in `face_of`).
    pub triangles: Vec<[u32; 3]>,
    pub face_of: Vec<u32>,
    pub faces: usize,
}

/// Reads an ASCII OFF file (the benchmark's: `OFF`, counts, vertices, faces).
pub fn read_off(path: &Path) -> Result<Mesh> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut tokens = text
        .lines()
        .enumerate()
        .map(|(n, l)| (n + 1, l.split('#').next().unwrap_or("")))
        .flat_map(|(n, l)| l.split_whitespace().map(move |t| (n, t)));
    let bad = |line: usize, what: &str| anyhow::anyhow!("{}:{line}: {what}", path.display());
    let (line, key) = tokens.next().ok_or_else(|| bad(1, "empty file"))?;
    if key != "OFF" {
        return Err(bad(line, "not an ASCII OFF file"));
    }
    let mut number = |what: &str| -> Result<(usize, f64)> {
        let (line, t) = tokens
            .next()
            .ok_or_else(|| bad(0, &format!("file ends before the {what}")))?;
        let v: f64 = t
            .parse()
            .map_err(|_| bad(line, &format!("{what} {t:?} is not a number")))?;
        Ok((line, v))
    };
    let count = |(line, v): (usize, f64), what: &str| -> Result<usize> {
        if v < 0.0 || v.fract() != 0.0 || v > 1e9 {
            return Err(bad(line, &format!("bad {what} {v}")));
        }
        Ok(v as usize)
    };
    let nv = count(number("vertex count")?, "vertex count")?;
    let nf = count(number("face count")?, "face count")?;
    number("edge count")?;
    let mut positions = Vec::with_capacity(nv);
    for _ in 0..nv {
        let x = number("vertex")?.1 as f32;
        let y = number("vertex")?.1 as f32;
        let z = number("vertex")?.1 as f32;
        positions.push(Vec3::new(x, y, z));
    }
    let mut triangles = Vec::with_capacity(nf);
    let mut face_of = Vec::with_capacity(nf);
    for f in 0..nf {
        let n = count(number("face size")?, "face size")?;
        let mut idx = Vec::with_capacity(n);
        for _ in 0..n {
            let (line, v) = number("face index")?;
            let i = count((line, v), "vertex index")?;
            if i >= nv {
                return Err(bad(line, &format!("vertex index {i} of {nv}")));
            }
            idx.push(i as u32);
        }
        for k in 2..n {
            triangles.push([idx[0], idx[k - 1], idx[k]]);
            face_of.push(f as u32);
        }
    }
    Ok(Mesh {
        positions,
        triangles,
        face_of,
        faces: nf,
    })
}

/// `mesh` with its vertices in the order `order` (`order[new] = old`, a permutation of its
/// vertices, as `lod::vertex_order::morton_order` gives it); faces keep their order.
pub fn renumbered(mesh: &Mesh, order: &[u32]) -> Result<Mesh> {
    if order.len() != mesh.positions.len() {
        bail!(
            "the order has {} vertices, the mesh {}",
            order.len(),
            mesh.positions.len()
        );
    }
    let mut new_of = vec![u32::MAX; order.len()];
    for (new, &old) in order.iter().enumerate() {
        match new_of.get_mut(old as usize) {
            Some(slot) if *slot == u32::MAX => *slot = new as u32,
            _ => bail!("the order is not a permutation (vertex {old})"),
        }
    }
    Ok(Mesh {
        positions: order
            .iter()
            .map(|&old| mesh.positions[old as usize])
            .collect(),
        triangles: mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| new_of[i as usize]))
            .collect(),
        face_of: mesh.face_of.clone(),
        faces: mesh.faces,
    })
}

/// Reads a `.seg` file: one segment number per face.
pub fn read_seg(path: &Path, faces: usize) -> Result<Vec<u32>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let labels = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(n, l)| {
            l.trim()
                .parse::<u32>()
                .with_context(|| format!("{}:{}: {l:?} is not a segment", path.display(), n + 1))
        })
        .collect::<Result<Vec<u32>>>()?;
    if labels.len() != faces {
        bail!(
            "{} has {} labels for {faces} faces",
            path.display(),
            labels.len()
        );
    }
    Ok(labels)
}

/// A ground-truth region: one segment's vertices and the geometry that frames it.
#[derive(Debug, Clone)]
pub struct Region {
    pub segment: u32,
    pub vertices: RoaringBitmap,
    /// Its vertices on the segment boundary (they also belong to a neighbouring segment).
    pub shared: RoaringBitmap,
    pub center: Vec3,
    /// Area-weighted mean normal (zero when it cancels out).
    pub normal: Vec3,
    pub extent: f32,
}

/// The segmentation of a mesh: its regions and, per vertex, the segment most of its faces
/// belong to (the label of the pixels that show it).
#[derive(Debug, Clone)]
pub struct Segmentation {
    pub regions: Vec<Region>,
    pub vertex_segment: Vec<u32>,
    /// Segments left out for being under the size threshold.
    pub tiny: usize,
}

/// Regions of `labels` over `mesh` holding at least `min_share` of its vertices.
pub fn segment(mesh: &Mesh, labels: &[u32], min_share: f64) -> Segmentation {
    let mut per_segment: BTreeMap<u32, (RoaringBitmap, Vec3)> = BTreeMap::new();
    let mut counts: Vec<BTreeMap<u32, u32>> = vec![BTreeMap::new(); mesh.positions.len()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let seg = labels[mesh.face_of[t] as usize];
        let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
        let e = per_segment.entry(seg).or_default();
        e.0.extend(tri.iter().copied());
        e.1 += (b - a).cross(c - a);
        for &v in tri {
            *counts[v as usize].entry(seg).or_default() += 1;
        }
    }
    let vertex_segment: Vec<u32> = counts
        .iter()
        .map(|c| {
            c.iter()
                .max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0)))
                .map_or(u32::MAX, |(s, _)| *s)
        })
        .collect();
    let used = counts.iter().filter(|c| !c.is_empty()).count() as u64;
    let shared: RoaringBitmap = (0..counts.len() as u32)
        .filter(|&v| counts[v as usize].len() > 1)
        .collect();
    let mut tiny = 0;
    let mut regions = Vec::new();
    for (segment, (vertices, normal)) in per_segment {
        if (vertices.len() as f64) < min_share * used as f64 {
            tiny += 1;
            continue;
        }
        let points: Vec<[f32; 3]> = vertices
            .iter()
            .map(|v| mesh.positions[v as usize].to_array())
            .collect();
        // Centre and extent as parts get them; the normal is the segment's area-weighted one.
        let Some(PartGeometry { center, extent, .. }) = PartGeometry::from_points(&points, &[])
        else {
            continue;
        };
        regions.push(Region {
            segment,
            shared: &vertices & &shared,
            vertices,
            center,
            normal: normal.normalize_or_zero(),
            extent,
        });
    }
    Segmentation {
        regions,
        vertex_segment,
        tiny,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn off_and_seg_give_regions() {
        let dir = std::env::temp_dir().join(format!("meshwiki-psb-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let off = dir.join("1.off");
        // Two triangles of a square (segment 0) and a quad split into two (segment 1).
        std::fs::write(
            &off,
            "OFF\n6 3 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n2 1 0\n3 0 1 2\n3 0 2 3\n4 1 4 5 2\n",
        )
        .unwrap();
        let seg = dir.join("1_0.seg");
        std::fs::write(&seg, "0\n0\n1\n").unwrap();
        let mesh = read_off(&off).unwrap();
        assert_eq!((mesh.triangles.len(), mesh.faces), (4, 3));
        let labels = read_seg(&seg, mesh.faces).unwrap();
        let s = segment(&mesh, &labels, 0.0);
        assert_eq!(s.regions.len(), 2);
        assert_eq!(
            s.regions[0].vertices.iter().collect::<Vec<_>>(),
            [0, 1, 2, 3]
        );
        assert_eq!(
            s.regions[1].vertices.iter().collect::<Vec<_>>(),
            [1, 2, 4, 5]
        );
        assert!((s.regions[0].normal - Vec3::Z).length() < 1e-6);
        assert_eq!(s.regions[0].shared.iter().collect::<Vec<_>>(), [1, 2]);
        assert_eq!(s.vertex_segment[4], 1);
        assert_eq!(s.vertex_segment[0], 0);
        assert!(read_seg(&seg, 4).is_err());
        std::fs::write(&off, "PLY\n").unwrap();
        assert!(read_off(&off).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
