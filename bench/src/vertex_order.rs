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
use meshwiki_engine::lod::build::{MORTON_BITS, morton3};
use meshwiki_engine::mesh::{Format, load, write_ply};

/// The Morton code ([`morton3`]) of every position, quantised to [`MORTON_BITS`] bits per
/// axis over the bounding box's longest side.
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
        ((1u64 << MORTON_BITS) - 1) as f64 / extent as f64
    } else {
        0.0
    };
    positions
        .iter()
        .map(|p| {
            morton3(std::array::from_fn(|k| {
                ((p[k] - lo[k]) as f64 * scale) as u32
            }))
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
    // Colours and normals are empty when the scan has none.
    fn permuted<T: Copy>(values: &[T], order: &[u32]) -> Vec<T> {
        if values.is_empty() {
            return Vec::new();
        }
        order.iter().map(|&old| values[old as usize]).collect()
    }
    let positions = permuted(&mesh.positions, &order);
    let colors = permuted(&mesh.colors, &order);
    let normals = permuted(&mesh.normals, &order);
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
