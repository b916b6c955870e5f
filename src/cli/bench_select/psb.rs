//! Ground truth from the Princeton Mesh Segmentation Benchmark (Chen, Golovinskiy and
//! Funkhouser, SIGGRAPH 2009), laid out as `../shared/data/README.md` describes: ASCII
//! `data/off/<id>.off` meshes and `data/seg/Benchmark/<id>/<id>_<k>.seg` human segmentations
//! (line `i` = segment of face `i`), in a `.tar.zst` archive or unpacked (the small `sample/`).
//!
//! A region is the set of vertices of the faces of one segment; vertex ids are the OFF file's
//! vertex indices, which are the original ids the LOD hierarchy keeps (engine `mesh::off`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use roaring::RoaringBitmap;

/// The 19 categories (first id of each, 20 models apiece), most heritage-like first.
pub const CATEGORIES: [(&str, u32); 19] = [
    ("Bust", 301),
    ("Vase", 361),
    ("Armadillo", 281),
    ("Human", 1),
    ("Teddy", 161),
    ("Fourleg", 381),
    ("Hand", 181),
    ("Cup", 21),
    ("Chair", 101),
    ("Octopus", 121),
    ("Table", 141),
    ("Airplane", 61),
    ("Ant", 81),
    ("Glasses", 41),
    ("Plier", 201),
    ("Fish", 221),
    ("Bird", 241),
    ("Mech", 321),
    ("Bearing", 341),
];

/// The category of model `id`.
pub fn category(id: u32) -> &'static str {
    CATEGORIES
        .iter()
        .find(|(_, first)| (*first..*first + 20).contains(&id))
        .map_or("?", |(name, _)| name)
}

/// Where the benchmark's files are.
#[derive(Debug)]
enum Layout {
    /// The package archive, with its member names.
    Archive { archive: PathBuf, members: Vec<String> },
    /// Unpacked: `off/<id>.off` and `seg/Benchmark/<id>/` under these folders.
    Dir { off: PathBuf, seg: PathBuf },
}

/// The benchmark's data, found in a folder (or an archive).
#[derive(Debug)]
pub struct Psb {
    layout: Layout,
    /// Ids with a mesh and at least one segmentation, with the first segmentation's `k`.
    available: BTreeMap<u32, u32>,
}

/// `<id>_<k>.seg` → `(id, k)`.
fn seg_name(name: &str) -> Option<(u32, u32)> {
    let stem = name.strip_suffix(".seg")?;
    let (id, k) = stem.split_once('_')?;
    Some((id.parse().ok()?, k.parse().ok()?))
}

fn first_segmentations(names: impl Iterator<Item = String>) -> BTreeMap<u32, u32> {
    let mut first = BTreeMap::new();
    for n in names {
        let file = n.rsplit('/').next().unwrap_or(&n);
        if let Some((id, k)) = seg_name(file) {
            let e = first.entry(id).or_insert(k);
            *e = (*e).min(k);
        }
    }
    first
}

impl Psb {
    /// Finds the data in `dir`: the `.tar.zst` package (preferred), an unpacked package
    /// (`data/off`, `data/seg`), an unpacked subset (`off`, `seg`) or the `sample/` subset.
    pub fn open(dir: &Path) -> Result<Psb> {
        let archive = if dir.is_file() {
            Some(dir.to_path_buf())
        } else {
            std::fs::read_dir(dir)
                .ok()
                .into_iter()
                .flatten()
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.to_string_lossy().ends_with(".tar.zst"))
                .min()
        };
        if let Some(archive) = archive {
            return Psb::from_archive(archive);
        }
        for (off, seg) in [
            (dir.join("data/off"), dir.join("data/seg/Benchmark")),
            (dir.join("off"), dir.join("seg/Benchmark")),
            (dir.join("sample/off"), dir.join("sample/seg/Benchmark")),
        ] {
            if off.is_dir() && seg.is_dir() {
                return Psb::from_dir(off, seg);
            }
        }
        bail!(
            "no Princeton segmentation benchmark in {}: expected MeshsegBenchmark-1.0_data.tar.zst \
             or the folders off/ and seg/Benchmark/ (see ../shared/data/README.md)",
            dir.display()
        )
    }

    fn from_archive(archive: PathBuf) -> Result<Psb> {
        let out = Command::new("sh")
            .arg("-c")
            .arg("zstd -dc -- \"$0\" | tar -t")
            .arg(&archive)
            .stderr(Stdio::inherit())
            .output()
            .context("listing the archive with zstd and tar (are they installed?)")?;
        if !out.status.success() {
            bail!("cannot list {} with zstd and tar", archive.display());
        }
        let members: Vec<String> = String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(str::to_string)
            .collect();
        let meshes: BTreeSet<u32> = members
            .iter()
            .filter_map(|m| m.strip_suffix(".off")?.rsplit('/').next()?.parse().ok())
            .collect();
        let mut available = first_segmentations(members.iter().cloned());
        available.retain(|id, _| meshes.contains(id));
        if available.is_empty() {
            bail!(
                "{} holds no off/<id>.off with a seg/Benchmark/<id>/<id>_<k>.seg",
                archive.display()
            );
        }
        Ok(Psb {
            layout: Layout::Archive { archive, members },
            available,
        })
    }

    fn from_dir(off: PathBuf, seg: PathBuf) -> Result<Psb> {
        let mut available = BTreeMap::new();
        let entries =
            std::fs::read_dir(&off).with_context(|| format!("reading {}", off.display()))?;
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(id) = name.strip_suffix(".off").and_then(|s| s.parse::<u32>().ok()) else {
                continue;
            };
            let segs = std::fs::read_dir(seg.join(id.to_string()))
                .into_iter()
                .flatten()
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned());
            if let Some(&k) = first_segmentations(segs).get(&id) {
                available.insert(id, k);
            }
        }
        if available.is_empty() {
            bail!(
                "{} holds no <id>.off with a segmentation in {}",
                off.display(),
                seg.display()
            );
        }
        Ok(Psb {
            layout: Layout::Dir { off, seg },
            available,
        })
    }

    /// Whether only part of the benchmark is here.
    pub fn models_available(&self) -> usize {
        self.available.len()
    }

    /// `n` models spread over the categories: the first of each category in
    /// [`CATEGORIES`]' order, then the second of each, and so on (those available).
    pub fn pick(&self, n: usize) -> Vec<u32> {
        let mut out = Vec::new();
        for round in 0..20 {
            for (_, first) in CATEGORIES {
                let id = first + round;
                if out.len() < n && self.available.contains_key(&id) {
                    out.push(id);
                }
            }
        }
        out
    }

    /// The mesh and first segmentation of each of `ids`, unpacked into `scratch` when they are
    /// in the archive: `(off path, seg path)` per id.
    pub fn files(&self, ids: &[u32], scratch: &Path) -> Result<Vec<(PathBuf, PathBuf)>> {
        let names: Vec<(String, String)> = ids
            .iter()
            .map(|&id| {
                let k = self.available.get(&id).copied().unwrap_or(0);
                (format!("{id}.off"), format!("{id}/{id}_{k}.seg"))
            })
            .collect();
        match &self.layout {
            Layout::Dir { off, seg } => Ok(names
                .into_iter()
                .map(|(o, s)| (off.join(o), seg.join(s)))
                .collect()),
            Layout::Archive { archive, members } => {
                let find = |suffix: &str| -> Result<String> {
                    members
                        .iter()
                        .find(|m| m.ends_with(&format!("/{suffix}")) || *m == suffix)
                        .cloned()
                        .with_context(|| format!("{} has no {suffix}", archive.display()))
                };
                let mut wanted = Vec::new();
                for (o, s) in &names {
                    wanted.push((find(&format!("off/{o}"))?, find(&format!("Benchmark/{s}"))?));
                }
                std::fs::create_dir_all(scratch)
                    .with_context(|| format!("creating {}", scratch.display()))?;
                let mut zstd = Command::new("zstd")
                    .arg("-dc")
                    .arg(archive)
                    .stdout(Stdio::piped())
                    .spawn()
                    .context("running zstd (is it installed?)")?;
                let pipe = zstd.stdout.take().context("zstd output")?;
                let tar = Command::new("tar")
                    .arg("-x")
                    .arg("-C")
                    .arg(scratch)
                    .arg("--")
                    .args(wanted.iter().flat_map(|(o, s)| [o, s]))
                    .stdin(pipe)
                    .status()
                    .context("running tar")?;
                let z = zstd.wait().context("waiting for zstd")?;
                if !z.success() || !tar.success() {
                    bail!("unpacking {} failed", archive.display());
                }
                Ok(wanted
                    .into_iter()
                    .map(|(o, s)| (scratch.join(o), scratch.join(s)))
                    .collect())
            }
        }
    }
}

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
        let n = vertices.len() as f64;
        let sum = vertices.iter().fold([0f64; 3], |s, v| {
            let p = mesh.positions[v as usize];
            [s[0] + p.x as f64, s[1] + p.y as f64, s[2] + p.z as f64]
        });
        let center = Vec3::new((sum[0] / n) as f32, (sum[1] / n) as f32, (sum[2] / n) as f32);
        let extent = vertices
            .iter()
            .map(|v| mesh.positions[v as usize].distance(center))
            .fold(0.0, f32::max);
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
        assert_eq!(s.regions[0].vertices.iter().collect::<Vec<_>>(), [0, 1, 2, 3]);
        assert_eq!(s.regions[1].vertices.iter().collect::<Vec<_>>(), [1, 2, 4, 5]);
        assert!((s.regions[0].normal - Vec3::Z).length() < 1e-6);
        assert_eq!(s.regions[0].shared.iter().collect::<Vec<_>>(), [1, 2]);
        assert_eq!(s.vertex_segment[4], 1);
        assert_eq!(s.vertex_segment[0], 0);
        assert!(read_seg(&seg, 4).is_err());
        std::fs::write(&off, "PLY\n").unwrap();
        assert!(read_off(&off).is_err());
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(category(305), "Bust");
        assert_eq!(seg_name("12_3.seg"), Some((12, 3)));
    }
}
