//! The numbering of a model's vertices: renumbered at ingest in the Morton order of their
//! positions (issue 15, "a tighter format"). The server and the CLI build so; the library's
//! default keeps the caller's numbering ([`VertexOrder::Source`]).
//!
//! Every patch stores each vertex's original id, predicted from the ids of its neighbours
//! already decoded (`codec`). How well that works depends on the order the scanner or the last
//! tool wrote the vertices in, which says nothing about the surface: Nefertiti's source order
//! costs 9.8 bits a leaf id. Numbered by Morton code (Morton, "A computer oriented geodetic
//! data base", IBM 1966: the bits of the three quantised coordinates interleaved, so points
//! near each other get near numbers), vertices of one patch get near ids and the same scan's
//! leaf ids cost 6.4 bits (`meshwiki-bench build --vertex-order`).
//!
//! The order is that of the vertices' **grid coordinates** — the file's own quantisation grid
//! (header: origin and step), the integers every decoder has for a leaf vertex — in Morton
//! order, ties (vertices on one grid point) in source order. So the numbering is a function
//! of the scan (the grid is chosen from its bounds and mean edge), the same scan always gets
//! the same ids, and a decoder can rank a patch's full-precision vertices by id from their
//! decoded coordinates alone. It is recorded in the file's header
//! ([`super::format::MORTON_VERTEX_ORDER`]): a model's ids are its identity for parts, segment
//! files and selections, and they are no longer the scan file's vertex indices —
//! [`morton_order`] and [`as_built`] give the map from a scan file and a built file's grid.
//!
//! Morton order is compared without forming the interleaved code (grid coordinates reach 2²⁴
//! a side, 72 bits interleaved): of the axis whose coordinates differ in the highest bit
//! (z before y before x at equal bits: x holds the lowest bit of each triple), the smaller
//! coordinate comes first (Chan's most-significant-bit comparison).
//!
//! Out of core: the vertices are binned by the top `BIN_BITS` (15) bits of their codes (a
//! counting pass and a stable scatter into a spilled index array), and each bin is sorted
//! alone, so memory holds one bin's keys, not the scan's. A bin is one cell of a 2⁵-per-axis
//! split of the grid's power-of-two cube; a surface fills a few hundred to a few thousand.

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Write};
use std::path::Path;

use super::build::morton3;
use super::codec::Grid;
use super::ingest::Ingested;
use super::spill::SpillVec;
use crate::mesh::Mesh;

/// How a build numbers the scan's vertices.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum VertexOrder {
    /// By the Morton order of the positions on the file's grid (smaller files; the server's
    /// and the CLI's choice).
    Morton,
    /// As the scan file lists them: ids are the file's vertex indices (the library's default:
    /// a caller's numbering is kept unless it asks otherwise).
    #[default]
    Source,
}

impl VertexOrder {
    /// The name used by the CLI and in reports.
    pub fn as_str(self) -> &'static str {
        match self {
            VertexOrder::Morton => "morton",
            VertexOrder::Source => "source",
        }
    }
}

impl std::fmt::Display for VertexOrder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for VertexOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "morton" => Ok(VertexOrder::Morton),
            "source" => Ok(VertexOrder::Source),
            other => Err(format!(
                "unknown vertex order {other:?}: `morton` or `source`"
            )),
        }
    }
}

/// Bins of the out-of-core sort: the top bits of the code (a multiple of three).
const BIN_BITS: u32 = 15;

/// Whether grid point `a` comes before `b` in Morton order (x lowest in each bit triple).
fn morton_less(a: [u32; 3], b: [u32; 3]) -> bool {
    /// Whether `x`'s highest set bit is below `y`'s.
    fn msb_below(x: u32, y: u32) -> bool {
        x < y && x < (x ^ y)
    }
    // The axis whose coordinates differ in the highest bit; at an equal bit z, then y.
    let mut axis = 2;
    let mut top = a[2] ^ b[2];
    for k in [1, 0] {
        let d = a[k] ^ b[k];
        if msb_below(top, d) {
            axis = k;
            top = d;
        }
    }
    a[axis] < b[axis]
}

/// The Morton order of grid points, ties by index (also the order in which a patch blob with
/// [`super::codec`]'s sorted ids lists them).
pub(crate) fn morton_cmp(a: ([u32; 3], u32), b: ([u32; 3], u32)) -> std::cmp::Ordering {
    if a.0 == b.0 {
        a.1.cmp(&b.1)
    } else if morton_less(a.0, b.0) {
        std::cmp::Ordering::Less
    } else {
        std::cmp::Ordering::Greater
    }
}

/// Grid coordinates and the bin of each (the top [`BIN_BITS`] bits of its Morton code over
/// the power-of-two cube that holds every coordinate).
struct Binning<'a> {
    positions: &'a [[f32; 3]],
    grid: &'a Grid,
    shift: u32,
}

impl<'a> Binning<'a> {
    fn new(positions: &'a [[f32; 3]], grid: &'a Grid) -> Binning<'a> {
        use rayon::prelude::*;
        let top = positions
            .par_iter()
            .map(|p| grid.quantize(*p).into_iter().max().unwrap_or(0))
            .max()
            .unwrap_or(0);
        let bits = 32 - top.leading_zeros();
        Binning {
            positions,
            grid,
            shift: bits.saturating_sub(BIN_BITS / 3),
        }
    }

    fn point(&self, v: usize) -> [u32; 3] {
        self.grid.quantize(self.positions[v])
    }

    fn bin(&self, q: [u32; 3]) -> usize {
        morton3(q.map(|c| c >> self.shift)) as usize
    }
}

/// The Morton order of `positions` on `grid` (`order[new] = old`), as a build with that grid
/// renumbers them; for positions that fit in memory (benches, tests, tools mapping ids back
/// to a scan file: the grid is the built file's, `LodFile::grid`).
pub fn morton_order(positions: &[[f32; 3]], grid: &Grid) -> Vec<u32> {
    let mut order = vec![0; positions.len()];
    sort_into(positions, grid, &mut order);
    order
}

/// `mesh` with its vertices numbered as a build in `order` on `grid` (the built file's,
/// `LodFile::grid`) numbers them: vertex `i` of the result is the scan vertex with id `i`;
/// faces keep their order. For tests and tools that compare a built file with its scan.
pub fn as_built(mesh: &Mesh, order: VertexOrder, grid: &Grid) -> Mesh {
    if order == VertexOrder::Source {
        return mesh.clone();
    }
    let order = morton_order(&mesh.positions, grid);
    let mut new_of = vec![0u32; order.len()];
    invert_into(&order, &mut new_of);
    // Colours and normals are empty when the scan has none.
    fn permuted<T: Copy>(values: &[T], order: &[u32]) -> Vec<T> {
        if values.is_empty() {
            return Vec::new();
        }
        order.iter().map(|&old| values[old as usize]).collect()
    }
    Mesh {
        positions: permuted(&mesh.positions, &order),
        colors: permuted(&mesh.colors, &order),
        normals: permuted(&mesh.normals, &order),
        indices: mesh.indices.iter().map(|&i| new_of[i as usize]).collect(),
    }
}

/// The Morton order of the `positions` on `grid`, out of core: a spilled index array.
fn spilled_order(
    positions: &[[f32; 3]],
    grid: &Grid,
    dir: &Path,
    memory_limit: usize,
) -> io::Result<SpillVec<u32>> {
    let mut order = SpillVec::new(dir.join("vertex-order.bin"), memory_limit);
    order.resize(positions.len(), 0)?;
    sort_into(positions, grid, order.as_mut_slice());
    order.release();
    Ok(order)
}

/// Writes the Morton order of `positions` on `grid` into `slots` (as long as `positions`): a
/// counting pass, a scatter of the indices into their bins, then each bin sorted alone (on
/// both cores), ties by index. The points of a bin share the bits of their coordinates above
/// the bin's: where the bits below fit [`super::build::MORTON_BITS`] an axis (grids up to 2²⁶
/// a side), those alone are interleaved into a 64-bit code, which orders them as the
/// comparison does, and the codes are sorted instead of comparing coordinates.
fn sort_into(positions: &[[f32; 3]], grid: &Grid, slots: &mut [u32]) {
    use rayon::prelude::*;
    let binning = Binning::new(positions, grid);
    let bin_count = 1usize << BIN_BITS;
    // The counting sort in consecutive runs of vertices, on the pool's threads: each run
    // counts its bins, then scatters into its own share of every bin (the runs' shares in
    // run order), so each bin lists its vertices by index, as one pass over all would.
    let runs = rayon::current_num_threads().clamp(1, 8);
    let run_len = positions.len().div_ceil(runs).max(1);
    let ranges: Vec<std::ops::Range<usize>> = (0..positions.len())
        .step_by(run_len)
        .map(|a| a..(a + run_len).min(positions.len()))
        .collect();
    let counts: Vec<Vec<usize>> = ranges
        .par_iter()
        .map(|r| {
            let mut c = vec![0usize; bin_count];
            for v in r.clone() {
                c[binning.bin(binning.point(v))] += 1;
            }
            c
        })
        .collect();
    // Every run's share of every bin, cut off the slots in bin order, then run order.
    let mut shares: Vec<Vec<&mut [u32]>> = ranges.iter().map(|_| Vec::new()).collect();
    let mut bins: Vec<std::ops::Range<usize>> = Vec::with_capacity(bin_count);
    let mut rest = &mut slots[..];
    let mut at = 0usize;
    for b in 0..bin_count {
        let start = at;
        for (share, count) in shares.iter_mut().zip(counts.iter().map(|c| c[b])) {
            let (mine, after) = std::mem::take(&mut rest).split_at_mut(count);
            share.push(mine);
            rest = after;
            at += count;
        }
        if at - start > 1 {
            bins.push(start..at);
        }
    }
    ranges
        .into_par_iter()
        .zip(shares.into_par_iter())
        .for_each(|(r, mut share)| {
            let mut next = vec![0usize; bin_count];
            for v in r {
                let b = binning.bin(binning.point(v));
                share[b][next[b]] = v as u32;
                next[b] += 1;
            }
        });
    let mut bins_out: Vec<&mut [u32]> = Vec::with_capacity(bins.len());
    let mut rest = slots;
    let mut at = 0usize;
    for r in bins {
        let (_, tail) = rest.split_at_mut(r.start - at);
        let (bin, after) = tail.split_at_mut(r.end - r.start);
        bins_out.push(bin);
        rest = after;
        at = r.end;
    }
    let bins = bins_out;
    if binning.shift <= super::build::MORTON_BITS {
        let mask = (1u32 << binning.shift) - 1;
        sort_bins(
            bins,
            |v| morton3(binning.point(v as usize).map(|c| c & mask)),
            |a, b| a.cmp(b),
        );
    } else {
        sort_bins(
            bins,
            |v| binning.point(v as usize),
            |&a, &b| morton_cmp(a, b),
        );
    }
}

/// Sorts each bin (on the pool's threads) by `order` on the pairs (`key` of an index, index).
fn sort_bins<K: Copy + Send>(
    bins: Vec<&mut [u32]>,
    key: impl Fn(u32) -> K + Sync,
    order: impl Fn(&(K, u32), &(K, u32)) -> std::cmp::Ordering + Sync,
) {
    use rayon::prelude::*;
    bins.into_par_iter()
        .for_each_init(Vec::new, |keyed: &mut Vec<(K, u32)>, bin| {
            keyed.clear();
            keyed.extend(bin.iter().map(|&v| (key(v), v)));
            keyed.sort_unstable_by(&order);
            for (slot, &(_, v)) in bin.iter_mut().zip(keyed.iter()) {
                *slot = v;
            }
        });
}

/// Renumbers the ingested scan in the Morton order of its points on `grid`: positions,
/// normals and colours are permuted and every triangle's indices remapped (the face file is
/// rewritten; faces keep their order, so per-face texture coordinates stay aligned). Arrays
/// beyond `memory_limit` bytes spill into `dir`.
pub(crate) fn renumber(
    ingested: &mut Ingested,
    grid: &Grid,
    dir: &Path,
    memory_limit: usize,
) -> io::Result<()> {
    let n = ingested.positions.len();
    if n < 2 {
        return Ok(());
    }
    let order = spilled_order(ingested.positions.as_slice(), grid, dir, memory_limit)?;
    let order = order.as_slice();
    let mut new_of = SpillVec::new(dir.join("vertex-rank.bin"), memory_limit);
    new_of.resize(n, 0u32)?;
    invert_into(order, new_of.as_mut_slice());
    ingested.positions = permuted(&ingested.positions, order, dir, "positions", memory_limit)?;
    ingested.normals = permuted(&ingested.normals, order, dir, "normals", memory_limit)?;
    if let Some(colors) = &ingested.colors {
        ingested.colors = Some(permuted(colors, order, dir, "colors", memory_limit)?);
    }
    let renumbered = ingested.faces_path.with_file_name("faces-renumbered.bin");
    remap_faces(&ingested.faces_path, &renumbered, new_of.as_slice())?;
    std::fs::rename(&renumbered, &ingested.faces_path)?;
    Ok(())
}

/// The inverse of the permutation `order` (`order[new] = old`) into `new_of` (`new_of[old] =
/// new`, as long as `order`).
fn invert_into(order: &[u32], new_of: &mut [u32]) {
    for (new, &old) in order.iter().enumerate() {
        new_of[old as usize] = new as u32;
    }
}

/// `values` in the new order, in a fresh spilled array.
fn permuted<T: bytemuck::Pod + Send + Sync>(
    values: &SpillVec<T>,
    order: &[u32],
    dir: &Path,
    name: &str,
    memory_limit: usize,
) -> io::Result<SpillVec<T>> {
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 18;
    let source = values.as_slice();
    let mut out = SpillVec::new(dir.join(format!("{name}-renumbered.bin")), memory_limit);
    let mut chunk = Vec::with_capacity(CHUNK);
    for part in order.chunks(CHUNK) {
        // Gathered on the pool's threads (scattered reads), appended in order.
        part.par_iter()
            .map(|&old| source[old as usize])
            .collect_into_vec(&mut chunk);
        out.extend_from_slice(&chunk)?;
    }
    values.release();
    out.release();
    Ok(out)
}

/// Rewrites the face file (`[u32; 3]` a triangle) with every index through `new_of`.
fn remap_faces(from: &Path, to: &Path, new_of: &[u32]) -> io::Result<()> {
    use rayon::prelude::*;
    let mut reader = BufReader::with_capacity(1 << 20, File::open(from)?);
    let mut writer = BufWriter::with_capacity(1 << 20, File::create(to)?);
    let mut buf = vec![0u8; 12 << 14];
    loop {
        let mut filled = 0;
        while filled < buf.len() {
            let got = reader.read(&mut buf[filled..])?;
            if got == 0 {
                break;
            }
            filled += got;
        }
        if filled % 4 != 0 {
            return Err(io::Error::other("the face file ends inside an index"));
        }
        // On the pool's threads, in runs of 4096 indices.
        buf[..filled]
            .par_chunks_mut(4 << 12)
            .try_for_each(|words| {
                for word in words.chunks_exact_mut(4) {
                    let old = u32::from_ne_bytes([word[0], word[1], word[2], word[3]]);
                    let new = new_of.get(old as usize).copied().ok_or_else(|| {
                        io::Error::other("the face file names a vertex out of range")
                    })?;
                    word.copy_from_slice(&new.to_ne_bytes());
                }
                Ok::<(), io::Error>(())
            })?;
        writer.write_all(&buf[..filled])?;
        if filled < buf.len() {
            break;
        }
    }
    writer.flush()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::ingest::Ingest;

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
        let unit = Grid {
            origin: [0.0; 3],
            step: 1.0,
        };
        let order = morton_order(&positions, &unit);
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
        // Ties keep the source order; a flat or single point set is still a permutation.
        assert_eq!(
            morton_order(&[[1.0; 3], [1.0; 3], [0.0; 3]], &unit),
            vec![2, 0, 1]
        );
        assert_eq!(morton_order(&[[2.0; 3]; 3], &unit), vec![0, 1, 2]);
        assert!(morton_order(&[], &unit).is_empty());
    }

    #[test]
    fn the_binned_sort_is_the_comparison_sort_of_the_whole_set() {
        // Points in clusters with repeats, on a grid whose bins leave at most 21 bits an axis
        // below them (sorted by 64-bit codes) and on one 2²⁸ steps a side (more bits below
        // the bins than the codes hold: sorted by the comparison).
        let mut next = crate::testing::xorshift(29);
        let mut positions: Vec<[f32; 3]> = Vec::new();
        for _ in 0..40 {
            let centre = [0, 1, 2].map(|_| (next() % 1000) as f32);
            for _ in 0..60 {
                let p = [0, 1, 2].map(|k| centre[k] + (next() % 200) as f32 * 0.01);
                positions.push(p);
                if next().is_multiple_of(5) {
                    positions.push(p);
                }
            }
        }
        for step in [1e-3, 4e-6] {
            let grid = Grid {
                origin: [0.0; 3],
                step,
            };
            let top = positions
                .iter()
                .flat_map(|&p| grid.quantize(p))
                .max()
                .unwrap_or(0);
            let below_bins = (32 - top.leading_zeros()).saturating_sub(BIN_BITS / 3);
            assert_eq!(
                below_bins <= crate::lod::build::MORTON_BITS,
                step > 1e-4,
                "step {step}: {below_bins} bits below the bins"
            );
            let mut whole: Vec<u32> = (0..positions.len() as u32).collect();
            whole.sort_by(|&a, &b| {
                morton_cmp(
                    (grid.quantize(positions[a as usize]), a),
                    (grid.quantize(positions[b as usize]), b),
                )
            });
            assert_eq!(morton_order(&positions, &grid), whole, "step {step}");
        }
    }

    #[test]
    fn the_comparison_orders_points_as_their_interleaved_codes_do() {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = |bits: u32| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as u32 & ((1 << bits) - 1)
        };
        for k in 0..20_000 {
            // Few bits as well, so equal coordinates and equal top bits are common.
            let bits = [2, 5, 21][k % 3];
            let a = [next(bits), next(bits), next(bits)];
            let b = [next(bits), next(bits), next(bits)];
            assert_eq!(morton_less(a, b), morton3(a) < morton3(b), "{a:?} {b:?}");
        }
    }

    /// Mean |id difference| over the mesh's edges: how far apart neighbours are numbered.
    fn mean_edge_gap(indices: &[u32]) -> f64 {
        let gaps: Vec<f64> = indices
            .chunks_exact(3)
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .map(|(a, b)| (a as f64 - b as f64).abs())
            .collect();
        gaps.iter().sum::<f64>() / gaps.len() as f64
    }

    #[test]
    fn renumbering_spilled_arrays_follows_the_in_memory_order_and_keeps_the_mesh() {
        // A coloured relief whose vertices the file lists scrambled (i ↦ 7919·i mod n).
        let (grid, grid_indices) = crate::lod::height_grid(40, 0.5, |x, y| (x * 0.3).sin() * y);
        let n = grid.len();
        let old_of: Vec<usize> = (0..n).map(|i| i * 7919 % n).collect();
        let mut file_index = vec![0u32; n];
        for (i, &g) in old_of.iter().enumerate() {
            file_index[g] = i as u32;
        }
        let mesh = Mesh {
            positions: old_of.iter().map(|&g| grid[g]).collect(),
            colors: (0..n).map(|i| [i as u8, (i >> 8) as u8, 7, 255]).collect(),
            normals: Vec::new(),
            indices: grid_indices
                .iter()
                .map(|&g| file_index[g as usize])
                .collect(),
        };
        let dir = std::env::temp_dir().join(format!("mw-vertex-order-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch");
        // 4 KiB a array: everything spills to files.
        let mut ingest = Ingest::new(&dir, 4096).expect("ingest");
        mesh.stream_into(&mut ingest).expect("stream");
        let mut ingested = ingest.finish().expect("finish");
        assert!(ingested.positions.is_spilled());
        let normals_before = ingested.normals.as_slice().to_vec();

        let grid = Grid {
            origin: ingested.bbox.0.to_array().map(f64::from),
            step: 0.05,
        };
        renumber(&mut ingested, &grid, &dir, 4096).expect("renumber");
        let order = morton_order(&mesh.positions, &grid);
        let positions = ingested.positions.as_slice();
        let colors = ingested.colors.as_ref().expect("colours").as_slice();
        let normals = ingested.normals.as_slice();
        for (new, &old) in order.iter().enumerate() {
            let old = old as usize;
            assert_eq!(positions[new], mesh.positions[old]);
            assert_eq!(colors[new], mesh.colors[old]);
            assert_eq!(normals[new], normals_before[old]);
        }
        let mut new_of = vec![0u32; n];
        for (new, &old) in order.iter().enumerate() {
            new_of[old as usize] = new as u32;
        }
        let faces = std::fs::read(&ingested.faces_path).expect("faces");
        let faces: Vec<u32> = bytemuck::pod_collect_to_vec(&faces);
        let expected: Vec<u32> = mesh.indices.iter().map(|&i| new_of[i as usize]).collect();
        assert_eq!(faces, expected);
        // Neighbours get nearer numbers than the scrambled file gave them.
        let (before, after) = (mean_edge_gap(&mesh.indices), mean_edge_gap(&faces));
        assert!(after * 4.0 < before, "mean id gap {before} -> {after}");
        drop(ingested);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
