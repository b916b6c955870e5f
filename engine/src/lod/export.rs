//! Cut export: the patches of a cut ([`super::cut_uniform`], [`super::cut_view`]) gathered into
//! one indexed mesh, welded by original vertex ID (system paper §3.3: a cut is a crack-free mesh
//! at the resolution it was chosen for).
//!
//! Patches of a cut share only border vertices, which decode to identical grid positions in
//! every patch, so welding by original ID closes every seam: the result's boundary edges are
//! exactly the scan's boundary edges (for an unculled cut). Each output vertex keeps its
//! original ID (its index in the input file for PLY/OBJ/OFF).

use super::codec::Patch;
use super::format::{FormatError, LodFile};
use rayon::prelude::*;
use std::collections::HashMap;

/// A cut as one welded mesh, in flat arrays.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CutMesh {
    pub positions: Vec<[f32; 3]>,
    /// Empty when the model has no colour.
    pub colors: Vec<[u8; 4]>,
    /// Unit normals (stored on patch borders, computed inside).
    pub normals: Vec<[f32; 3]>,
    /// Original ID of each vertex.
    pub original_ids: Vec<u32>,
    /// Three indices per triangle.
    pub indices: Vec<u32>,
    /// Patches gathered.
    pub nodes: usize,
}

impl CutMesh {
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }
}

/// Patches decoded at a time (in parallel) before they are welded in order.
const CHUNK: usize = 64;

/// Decodes the patches `nodes` of `lod` and welds them by original ID. The first patch that
/// holds a vertex decides its position, colour and normal (shared vertices are border vertices,
/// identical in every patch). Fails on a node that does not exist or a patch that fails its
/// checksum or does not decode.
pub fn export_cut(lod: &LodFile, nodes: &[u32]) -> Result<CutMesh, FormatError> {
    let with_colors = lod.has_colors();
    let mut out = CutMesh {
        nodes: nodes.len(),
        ..CutMesh::default()
    };
    let expected: u64 = nodes
        .iter()
        .map(|&n| lod.node(n).map(|r| r.triangle_count as u64))
        .sum::<Result<u64, _>>()?;
    out.indices.reserve(expected as usize * 3);
    let mut index_of: HashMap<u32, u32> = HashMap::new();
    for chunk in nodes.chunks(CHUNK) {
        let patches: Vec<Patch> = chunk
            .par_iter()
            .map(|&n| lod.patch(n))
            .collect::<Result<_, _>>()?;
        for patch in &patches {
            let local: Vec<u32> = patch
                .original_ids
                .iter()
                .enumerate()
                .map(|(i, &id)| {
                    *index_of.entry(id).or_insert_with(|| {
                        let new = out.positions.len() as u32;
                        out.positions.push(patch.positions[i]);
                        if with_colors {
                            out.colors
                                .push(patch.colors.get(i).copied().unwrap_or([255; 4]));
                        }
                        out.normals
                            .push(patch.normals.get(i).copied().unwrap_or([0.0; 3]));
                        out.original_ids.push(id);
                        new
                    })
                })
                .collect();
            for &i in &patch.indices {
                let v = local.get(i as usize).copied().ok_or_else(|| {
                    FormatError::Corrupt(format!("patch index {i} beyond its vertices"))
                })?;
                out.indices.push(v);
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::{BuildOptions, build_mesh, cut_uniform};
    use crate::mesh::{Mesh, synth::Relief};
    use crate::progress::NoProgress;

    fn boundary_edges(ids: impl Iterator<Item = [u32; 3]>) -> Vec<(u32, u32)> {
        crate::lod::patch::EdgeUses::of(ids)
            .border()
            .map(crate::lod::patch::edge_ends)
            .collect()
    }

    #[test]
    fn welded_cuts_are_crack_free() {
        let mut mesh = Mesh::default();
        Relief::new(30_000, 3).stream(&mut mesh).unwrap();
        let dir = std::env::temp_dir().join(format!("mw-export-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.mwlod");
        let options = BuildOptions {
            max_patch_triangles: 256,
            memory_budget: 64 << 20,
            threads: Some(2),
            ..BuildOptions::default()
        };
        build_mesh(&mesh, &path, &options, &NoProgress).unwrap();
        let lod = LodFile::open(&path).unwrap();
        let input_boundary =
            boundary_edges(mesh.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
        let max = lod
            .nodes()
            .iter()
            .map(|n| n.lod_error)
            .fold(0.0f32, f32::max);
        for error in [0.0, max * 0.01, max * 0.1, max * 0.5, max * 2.0] {
            let cut = cut_uniform(lod.nodes(), error);
            let m = export_cut(&lod, &cut).unwrap();
            let tris: u64 = cut
                .iter()
                .map(|&n| lod.nodes()[n as usize].triangle_count as u64)
                .sum();
            assert_eq!(m.triangle_count() as u64, tris);
            assert_eq!(m.colors.len(), m.vertex_count());
            let ids = m.indices.chunks_exact(3).map(|t| {
                [
                    m.original_ids[t[0] as usize],
                    m.original_ids[t[1] as usize],
                    m.original_ids[t[2] as usize],
                ]
            });
            assert_eq!(boundary_edges(ids), input_boundary, "error {error}");
            assert!(
                m.original_ids
                    .iter()
                    .all(|&id| (id as usize) < mesh.vertex_count())
            );
        }
        assert!(export_cut(&lod, &[u32::MAX]).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
