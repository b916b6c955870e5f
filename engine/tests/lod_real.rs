//! The hierarchy on real scans (`../shared/data/meshes`): a cut at error E stays within E of the
//! scan, measured independently of the builder (dense area-weighted surface samples both ways,
//! nearest triangle through a BVH written here), the top level is a few patches, and every
//! cut is crack-free. Skips with a message when the shared data is absent.

use glam::Vec3;
use meshwiki_engine::lod::{self, BuildOptions, LodFile, NO_GROUP};
use meshwiki_engine::mesh::{self, Mesh};
use meshwiki_engine::progress::NoProgress;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

fn shared_mesh(name: &str) -> Option<PathBuf> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/meshes")
        .join(name);
    if path.exists() {
        Some(path)
    } else {
        eprintln!(
            "skipping: {} not found (the shared data set is not beside the repo)",
            path.display()
        );
        None
    }
}

/// Bounding-volume hierarchy over triangles for exact nearest-surface distances.
struct Bvh {
    tris: Vec<[Vec3; 3]>,
    nodes: Vec<BvhNode>,
}

struct BvhNode {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first triangle and count (count > 0); inner: left child index in `nodes`, right = left + 1.
    first: u32,
    count: u32,
}

impl Bvh {
    fn new(mut tris: Vec<[Vec3; 3]>) -> Bvh {
        let mut nodes = Vec::new();
        let n = tris.len();
        nodes.push(BvhNode {
            lo: Vec3::ZERO,
            hi: Vec3::ZERO,
            first: 0,
            count: 0,
        });
        Self::build(&mut tris, &mut nodes, 0, 0, n);
        Bvh { tris, nodes }
    }

    fn build(
        tris: &mut [[Vec3; 3]],
        nodes: &mut Vec<BvhNode>,
        at: usize,
        start: usize,
        end: usize,
    ) {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for t in &tris[start..end] {
            for p in t {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
        }
        nodes[at].lo = lo;
        nodes[at].hi = hi;
        if end - start <= 4 {
            nodes[at].first = start as u32;
            nodes[at].count = (end - start) as u32;
            return;
        }
        let axis = (hi - lo).max_position();
        let mid = (start + end) / 2;
        tris[start..end].select_nth_unstable_by(mid - start, |a, b| {
            let ca = a[0][axis] + a[1][axis] + a[2][axis];
            let cb = b[0][axis] + b[1][axis] + b[2][axis];
            ca.total_cmp(&cb)
        });
        let left = nodes.len();
        nodes.push(BvhNode {
            lo,
            hi,
            first: 0,
            count: 0,
        });
        nodes.push(BvhNode {
            lo,
            hi,
            first: 0,
            count: 0,
        });
        nodes[at].first = left as u32;
        Self::build(tris, nodes, left, start, mid);
        Self::build(tris, nodes, left + 1, mid, end);
    }

    fn distance(&self, p: Vec3) -> f32 {
        let box_sq = |n: &BvhNode| (n.lo - p).max(p - n.hi).max(Vec3::ZERO).length_squared();
        let mut best = f32::MAX;
        let mut stack = vec![(0usize, box_sq(&self.nodes[0]))];
        while let Some((i, d)) = stack.pop() {
            if d >= best {
                continue;
            }
            let n = &self.nodes[i];
            if n.count > 0 {
                for t in &self.tris[n.first as usize..(n.first + n.count) as usize] {
                    best = best.min(closest_sq(p, t[0], t[1], t[2]));
                }
            } else {
                // Nearer child last, so it is popped (searched) first.
                let (l, r) = (n.first as usize, n.first as usize + 1);
                let (dl, dr) = (box_sq(&self.nodes[l]), box_sq(&self.nodes[r]));
                if dl < dr {
                    stack.push((r, dr));
                    stack.push((l, dl));
                } else {
                    stack.push((l, dl));
                    stack.push((r, dr));
                }
            }
        }
        best.sqrt()
    }
}

/// Squared distance from p to triangle abc by projection onto the plane and, when the
/// projection falls outside, the nearest of the three edges (a different formulation from
/// the builder's Voronoi-region test).
fn closest_sq(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> f32 {
    let n = (b - a).cross(c - a);
    let nn = n.length_squared();
    if nn > 0.0 {
        let q = p - n * ((p - a).dot(n) / nn);
        let inside = (b - a).cross(q - a).dot(n) >= 0.0
            && (c - b).cross(q - b).dot(n) >= 0.0
            && (a - c).cross(q - c).dot(n) >= 0.0;
        if inside {
            return (p - q).length_squared();
        }
    }
    let seg = |u: Vec3, v: Vec3| {
        let d = v - u;
        let t = if d.length_squared() > 0.0 {
            ((p - u).dot(d) / d.length_squared()).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (p - (u + d * t)).length_squared()
    };
    seg(a, b).min(seg(b, c)).min(seg(c, a))
}

/// Deterministic area-weighted samples on a triangle set, plus every vertex.
fn samples(tris: &[[Vec3; 3]], count: usize) -> Vec<Vec3> {
    let areas: Vec<f32> = tris
        .iter()
        .map(|t| (t[1] - t[0]).cross(t[2] - t[0]).length() * 0.5)
        .collect();
    let total: f64 = areas.iter().map(|&a| a as f64).sum();
    let mut out: Vec<Vec3> = tris.iter().flat_map(|t| t.iter().copied()).collect();
    let mut state = 0x1234_5678_9abc_def0u64;
    let mut rand = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut acc = 0.0f64;
    let step = total / count as f64;
    let mut next = rand() * step;
    for (t, &a) in tris.iter().zip(&areas) {
        acc += a as f64;
        while next < acc {
            let (mut u, mut v) = (rand() as f32, rand() as f32);
            if u + v > 1.0 {
                u = 1.0 - u;
                v = 1.0 - v;
            }
            out.push(t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v);
            next += step;
        }
    }
    out
}

fn two_sided(a: &[[Vec3; 3]], b: &[[Vec3; 3]], per_side: usize) -> f32 {
    let (bvh_a, bvh_b) = (Bvh::new(a.to_vec()), Bvh::new(b.to_vec()));
    let ab = samples(a, per_side)
        .into_iter()
        .map(|p| bvh_b.distance(p))
        .fold(0.0f32, f32::max);
    let ba = samples(b, per_side)
        .into_iter()
        .map(|p| bvh_a.distance(p))
        .fold(0.0f32, f32::max);
    ab.max(ba)
}

fn cut_triangles(file: &LodFile, cut: &[u32]) -> Vec<[Vec3; 3]> {
    let mut out = Vec::new();
    for &n in cut {
        let p = file.patch(n).expect("patch decodes");
        for t in p.indices.chunks(3) {
            out.push([t[0], t[1], t[2]].map(|i| Vec3::from(p.positions[i as usize])));
        }
    }
    out
}

fn check_scan(name: &str, per_side: usize) {
    let Some(path) = shared_mesh(name) else {
        return;
    };
    let (input, _) = mesh::load(&path).expect("scan loads");
    let dir = std::env::temp_dir().join(format!("mw-lodreal-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let out = dir.join("scan.mwlod");
    // In the server's vertex order (Morton): the checks below run on the scan so numbered.
    let options = BuildOptions {
        vertex_order: lod::VertexOrder::Morton,
        ..BuildOptions::default()
    };
    let report = lod::build_file(&path, &out, &options, &NoProgress).expect("build");
    let file = LodFile::open(&out).expect("open");
    // The scan as the build numbered it (the default Morton order): ids index it.
    let input = lod::vertex_order::as_built(&input, file.vertex_order(), &file.grid());

    let roots = file
        .nodes()
        .iter()
        .filter(|n| n.member_of == NO_GROUP)
        .count();
    println!(
        "{name}: {} triangles, {} levels, {} nodes, {roots} roots, {} bytes",
        report.import.triangles, report.levels, report.nodes, report.output_bytes
    );
    assert!(roots <= 8, "{name}: {roots} roots");

    let original: Vec<[Vec3; 3]> = input
        .indices
        .chunks(3)
        .map(|t| [t[0], t[1], t[2]].map(|i| Vec3::from(input.positions[i as usize])))
        .collect();
    // Errors of the groups, from fine to coarse: cut between consecutive distinct values.
    let mut errors: Vec<f32> = file.groups().iter().map(|g| g.error).collect();
    errors.sort_by(f32::total_cmp);
    errors.dedup();
    let picks: Vec<f32> = [0.05, 0.3, 0.6, 0.9, 1.0]
        .iter()
        .map(|f| errors[((errors.len() - 1) as f32 * f) as usize])
        .collect();
    for e in picks {
        let cut = lod::cut_uniform(file.nodes(), e);
        let tris = cut_triangles(&file, &cut);
        let d = two_sided(&tris, &original, per_side);
        println!(
            "{name}: cut at E = {e:.6}: {} triangles, Hausdorff {d:.6} ({:.0}% of E)",
            tris.len(),
            100.0 * d / e
        );
        assert!(
            d <= e,
            "{name}: Hausdorff {d} of the decoded cut exceeds E {e}"
        );
    }
    // Crack-free at every cut: boundary edges by original id equal the input's.
    let boundary = |tris: &mut dyn Iterator<Item = [u32; 3]>| {
        let mut count: HashMap<(u32, u32), u32> = HashMap::new();
        for t in tris {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *count.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        let mut b: Vec<(u32, u32)> = count
            .into_iter()
            .filter(|&(_, c)| c == 1)
            .map(|(e, _)| e)
            .collect();
        b.sort_unstable();
        b
    };
    let input_tris: Vec<[u32; 3]> = input
        .indices
        .chunks(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let in_b = boundary(&mut input_tris.clone().into_iter());
    let input_defects = Defects::of(&input_tris);
    let mut thresholds = vec![0.0f32];
    thresholds.extend(errors.iter().map(|e| e * 1.0001));
    for e in thresholds {
        let cut = lod::cut_uniform(file.nodes(), e);
        let mut welded = Vec::new();
        for &n in &cut {
            let p = file.patch(n).expect("patch");
            for t in p.indices.chunks(3) {
                welded.push([t[0], t[1], t[2]].map(|i| p.original_ids[i as usize]));
            }
        }
        // Sound output: no non-manifold edge or duplicate triangle the scan lacks.
        let d = Defects::of(&welded);
        let new_edges: Vec<_> = d
            .non_manifold
            .iter()
            .filter(|x| input_defects.non_manifold.binary_search(x).is_err())
            .collect();
        let new_dups: Vec<_> = d
            .duplicates
            .iter()
            .filter(|x| input_defects.duplicates.binary_search(x).is_err())
            .collect();
        let (n_edges, n_dups) = (new_edges.len(), new_dups.len());
        assert!(
            new_edges.is_empty() && new_dups.is_empty(),
            "{name}: cut at {e} ({} triangles) has {n_edges} non-manifold edges and {n_dups} \
             duplicate triangles the scan lacks: {:?} {:?}",
            welded.len(),
            &new_edges[..n_edges.min(8)],
            &new_dups[..n_dups.min(8)]
        );
        let cut_b = boundary(&mut welded.into_iter());
        let extra: Vec<_> = cut_b
            .iter()
            .filter(|x| in_b.binary_search(x).is_err())
            .take(12)
            .collect();
        let missing: Vec<_> = in_b
            .iter()
            .filter(|x| cut_b.binary_search(x).is_err())
            .take(12)
            .collect();
        assert!(
            extra.is_empty() && missing.is_empty(),
            "{name}: cut at {e} has cracks: {} boundary edges vs {}; extra {extra:?}, missing {missing:?}",
            cut_b.len(),
            in_b.len()
        );
    }
    println!(
        "{name}: every cut: 0 non-manifold edges and 0 duplicate triangles beyond the scan's \
         ({} and {})",
        input_defects.non_manifold.len(),
        input_defects.duplicates.len()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Edges used by more than two triangles and triangles repeated (same three vertices, either
/// orientation), by original id, sorted: written here, independently of the builder.
struct Defects {
    non_manifold: Vec<(u32, u32)>,
    duplicates: Vec<[u32; 3]>,
}

impl Defects {
    fn of(tris: &[[u32; 3]]) -> Defects {
        let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
        let mut seen: HashMap<[u32; 3], u32> = HashMap::new();
        for t in tris {
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                continue;
            }
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_default() += 1;
            }
            let mut key = *t;
            key.sort_unstable();
            *seen.entry(key).or_default() += 1;
        }
        let mut non_manifold: Vec<(u32, u32)> = edges
            .into_iter()
            .filter(|&(_, c)| c > 2)
            .map(|(e, _)| e)
            .collect();
        non_manifold.sort_unstable();
        let mut duplicates: Vec<[u32; 3]> = seen
            .into_iter()
            .filter(|&(_, c)| c > 1)
            .map(|(t, _)| t)
            .collect();
        duplicates.sort_unstable();
        Defects {
            non_manifold,
            duplicates,
        }
    }
}

fn input_mesh_ok(m: &Mesh) -> bool {
    !m.indices.is_empty()
}

#[test]
fn gargoyle_with_colour_and_normals() {
    check_scan("gargoyle_50k_vcolor.ply", 100_000);
}

#[test]
fn igea_closed_scan() {
    check_scan("igea_269k.ply", 150_000);
}

#[test]
fn dragon_with_holes_and_many_components() {
    check_scan("stanford_dragon_vrip_871k.ply", 150_000);
}

#[test]
fn laurana_with_colour() {
    check_scan("laurana_bust_50k_vcolor.ply", 100_000);
}

#[test]
fn nefertiti() {
    check_scan("nefertiti_100k.ply", 100_000);
}

#[test]
fn armadillo() {
    check_scan("stanford_armadillo_346k.ply", 150_000);
}

#[test]
fn textured_mask() {
    check_scan(
        "mask_bali_100k_textured_gltf/mask-gltf-2.0_separated-valid.gltf",
        100_000,
    );
}

#[test]
fn bvh_distance_agrees_with_brute_force() {
    let mut m = Mesh::default();
    mesh::synth::Relief::new(2_000, 3)
        .stream(&mut m)
        .expect("relief");
    assert!(input_mesh_ok(&m));
    let tris: Vec<[Vec3; 3]> = m
        .indices
        .chunks(3)
        .map(|t| [t[0], t[1], t[2]].map(|i| Vec3::from(m.positions[i as usize])))
        .collect();
    let bvh = Bvh::new(tris.clone());
    for k in 0..100 {
        let f = k as f32 * 0.1;
        let p = Vec3::new(f.sin(), (f * 1.7).cos(), (f * 0.3).sin() * 0.5);
        let brute = tris
            .iter()
            .map(|t| closest_sq(p, t[0], t[1], t[2]))
            .fold(f32::MAX, f32::min)
            .sqrt();
        assert!((bvh.distance(p) - brute).abs() < 1e-6);
    }
}
