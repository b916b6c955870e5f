//! `bench build --vertex-order morton`: what the scan's vertex order costs the format (issue 15).
//!
//! A patch stores each vertex's original id (its index in the scan), predicted from the ids of
//! its neighbours already decoded. How well that works depends on the order the scanner or
//! the last tool wrote the vertices in, which means nothing for the surface: on Nefertiti the
//! leaf ids cost 9.8 bits a vertex in the source order. Renumbering the vertices by the Morton
//! code of their positions (Morton, "A computer oriented geodetic data base", IBM 1966: the
//! bits of the three quantised coordinates interleaved, so vertices near each other on the
//! surface get near numbers) measures what a model numbered coherently would store, with
//! nothing else changed: the same positions, colours, normals and triangles.
//!
//! The product does not renumber: ids are a model's identity for parts, segment files and
//! selections, so a renumbering must be recorded per model and kept by every rebuild. This
//! module only writes a renumbered copy of the scan for the bench.

use std::path::Path;

use anyhow::{Context, bail};
use meshwiki_engine::mesh::{Format, load, write_ply};

/// Bits per axis of the quantised positions (3 × 21 = 63 bits of code).
const BITS: u32 = 21;

/// Spreads the low 21 bits of `x` to every third bit (bit `i` to bit `3i`).
fn spread(x: u64) -> u64 {
    let mut x = x & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// The Morton code of every position, quantised to [`BITS`] bits per axis over the bounding
/// box's longest side.
fn morton_codes(positions: &[[f32; 3]]) -> Vec<u64> {
    let mut lo = [f32::MAX; 3];
    let mut hi = [f32::MIN; 3];
    for p in positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let extent = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f32, f32::max);
    let scale = if extent > 0.0 {
        ((1u64 << BITS) - 1) as f64 / extent as f64
    } else {
        0.0
    };
    positions
        .iter()
        .map(|p| {
            let q = |k: usize| ((p[k] - lo[k]) as f64 * scale) as u64;
            spread(q(0)) | spread(q(1)) << 1 | spread(q(2)) << 2
        })
        .collect()
}

/// The new order of the vertices (`order[new] = old`): by Morton code, ties in source order.
pub fn morton_order(positions: &[[f32; 3]]) -> Vec<u32> {
    let codes = morton_codes(positions);
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.sort_by_key(|&v| (codes[v as usize], v));
    order
}

/// Writes `input` to `output` (PLY) with its vertices in Morton order; returns the vertex
/// count. Formats that may carry a texture (glTF, OBJ) are refused: the copy would drop it.
pub fn write_reordered(input: &Path, output: &Path) -> anyhow::Result<usize> {
    match Format::from_path(input) {
        Some(Format::Ply | Format::Stl | Format::Off) => {}
        _ => {
            bail!("--vertex-order morton takes a PLY, STL or OFF scan (a copy would drop textures)")
        }
    }
    let (mesh, _) = load(input).with_context(|| format!("cannot read {}", input.display()))?;
    let order = morton_order(&mesh.positions);
    let mut new_of = vec![0u32; order.len()];
    for (new, &old) in order.iter().enumerate() {
        new_of[old as usize] = new as u32;
    }
    let pick = |old: &u32| *old as usize;
    let positions: Vec<[f32; 3]> = order.iter().map(|o| mesh.positions[pick(o)]).collect();
    let colors: Vec<[u8; 4]> = if mesh.colors.is_empty() {
        Vec::new()
    } else {
        order.iter().map(|o| mesh.colors[pick(o)]).collect()
    };
    let normals: Vec<[f32; 3]> = if mesh.normals.is_empty() {
        Vec::new()
    } else {
        order.iter().map(|o| mesh.normals[pick(o)]).collect()
    };
    let indices: Vec<u32> = mesh.indices.iter().map(|&i| new_of[i as usize]).collect();
    write_ply(
        output,
        &positions,
        (!colors.is_empty()).then_some(colors.as_slice()),
        (!normals.is_empty()).then_some(normals.as_slice()),
        &indices,
        None,
    )
    .with_context(|| format!("cannot write {}", output.display()))?;
    Ok(positions.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_interleaves_bits() {
        for x in [0u64, 1, 2, 5, 0x1f_ffff, 0x15_5555] {
            let naive = (0..BITS).fold(0u64, |r, b| r | ((x >> b) & 1) << (3 * b));
            assert_eq!(spread(x), naive, "{x:#x}");
        }
    }

    #[test]
    fn morton_order_keeps_neighbours_together_and_is_a_permutation() {
        // A 4 × 4 grid listed column by column with the columns shuffled: the Morton order
        // visits each 2 × 2 quadrant whole before the next.
        let mut positions = Vec::new();
        for x in [3, 0, 2, 1] {
            for y in 0..4 {
                positions.push([x as f32, y as f32, 0.0]);
            }
        }
        let order = morton_order(&positions);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..16).collect::<Vec<u32>>());
        for quadrant in order.chunks(4) {
            let cells: Vec<(u32, u32)> = quadrant
                .iter()
                .map(|&v| {
                    let p = positions[v as usize];
                    (p[0] as u32 / 2, p[1] as u32 / 2)
                })
                .collect();
            assert!(cells.iter().all(|&c| c == cells[0]), "{cells:?}");
        }
        // Ties keep the source order.
        assert_eq!(morton_order(&[[1.0; 3], [1.0; 3], [0.0; 3]]), vec![2, 0, 1]);
    }
}
