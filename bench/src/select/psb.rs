//! The Princeton Mesh Segmentation Benchmark (Chen, Golovinskiy and Funkhouser, SIGGRAPH
//! 2009), laid out as `../shared/data/README.md` describes: ASCII `data/off/<id>.off` meshes and
//! `data/seg/Benchmark/<id>/<id>_<k>.seg` human segmentations (line `i` = segment of face
//! `i`), in a `.tar.zst` archive or unpacked (the small `sample/`): finding the data, choosing
//! models over its categories, unpacking only those. [`super::truth`] reads the files.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{Context, Result, bail};

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
    Archive {
        archive: PathBuf,
        members: Vec<String>,
    },
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
            let Some(id) = name
                .strip_suffix(".off")
                .and_then(|s| s.parse::<u32>().ok())
            else {
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
                let members: Vec<&String> = wanted.iter().flat_map(|(o, s)| [o, s]).collect();
                crate::untar::untar_zstd(archive, scratch, &members)?;
                Ok(wanted
                    .into_iter()
                    .map(|(o, s)| (scratch.join(o), scratch.join(s)))
                    .collect())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_categories() {
        assert_eq!(category(305), "Bust");
        assert_eq!(category(270), "?");
        assert_eq!(seg_name("12_3.seg"), Some((12, 3)));
        assert_eq!(seg_name("12.seg"), None);
    }
}
