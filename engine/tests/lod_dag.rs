//! Property tests of the patch DAG over generated meshes: structure, and crack-free cuts.
//!
//! Every cut (uniform error or view-dependent, at many thresholds) welded by original ID must
//! have exactly the input's boundary edges, and only input vertices at their input positions
//! (up to the quantisation grid).

use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::segsimplify::Simplifier;
use meshwiki_engine::lod::vertex_order::{self, VertexOrder};
use meshwiki_engine::lod::{self, BuildOptions, Culling, LodFile, NO_GROUP};
use meshwiki_engine::mesh::Mesh;
use meshwiki_engine::progress::NoProgress;
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// A bumpy height field with random holes (boundaries inside) and colour.
fn terrain(n: u32, seed: u64, holes: usize) -> Mesh {
    let mut rng = Rng(seed);
    let mut m = Mesh::default();
    let phase = rng.next() * 6.0;
    for y in 0..=n {
        for x in 0..=n {
            let (fx, fy) = (x as f32 / n as f32, y as f32 / n as f32);
            let h = (fx * 9.0 + phase).sin() * (fy * 7.0).cos() * 0.08
                + (fx * 31.0).sin() * 0.01
                + rng.next() * 0.002;
            m.positions.push([fx, fy, h]);
            m.colors
                .push([(fx * 255.0) as u8, (fy * 255.0) as u8, 128, 255]);
        }
    }
    let hole_centres: Vec<(f32, f32, f32)> = (0..holes)
        .map(|_| (rng.next(), rng.next(), 0.03 + rng.next() * 0.05))
        .collect();
    for y in 0..n {
        for x in 0..n {
            let (cx, cy) = ((x as f32 + 0.5) / n as f32, (y as f32 + 0.5) / n as f32);
            if hole_centres
                .iter()
                .any(|&(hx, hy, r)| (cx - hx).powi(2) + (cy - hy).powi(2) < r * r)
            {
                continue;
            }
            let i = y * (n + 1) + x;
            m.indices
                .extend_from_slice(&[i, i + 1, i + n + 2, i, i + n + 2, i + n + 1]);
        }
    }
    m
}

/// A closed, displaced sphere plus a few small separate blobs (several components).
fn blobs(rings: u32, seed: u64) -> Mesh {
    let mut rng = Rng(seed);
    let mut m = Mesh::default();
    let add_sphere = |m: &mut Mesh, c: Vec3, r: f32, rings: u32, rng: &mut Rng| {
        let base = m.positions.len() as u32;
        let segs = rings * 2;
        m.positions.push((c + Vec3::Z * r).into());
        for i in 1..rings {
            let th = std::f32::consts::PI * i as f32 / rings as f32;
            for j in 0..segs {
                let ph = 2.0 * std::f32::consts::PI * j as f32 / segs as f32;
                let d = Vec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
                let rr = r * (1.0 + 0.05 * (3.0 * ph).sin() * (4.0 * th).cos() + 0.01 * rng.next());
                m.positions.push((c + d * rr).into());
            }
        }
        m.positions.push((c - Vec3::Z * r).into());
        let ring = |i: u32, j: u32| base + 1 + (i - 1) * segs + (j % segs);
        let south = base + 1 + (rings - 1) * segs;
        for j in 0..segs {
            m.indices
                .extend_from_slice(&[base, ring(1, j), ring(1, j + 1)]);
            m.indices
                .extend_from_slice(&[south, ring(rings - 1, j + 1), ring(rings - 1, j)]);
        }
        for i in 1..rings - 1 {
            for j in 0..segs {
                let (a, b, c2, d) = (
                    ring(i, j),
                    ring(i, j + 1),
                    ring(i + 1, j + 1),
                    ring(i + 1, j),
                );
                m.indices.extend_from_slice(&[a, d, c2, a, c2, b]);
            }
        }
    };
    add_sphere(&mut m, Vec3::ZERO, 1.0, rings, &mut rng);
    for k in 0..5 {
        let c = Vec3::new(1.6 + k as f32 * 0.3, rng.next(), rng.next());
        add_sphere(&mut m, c, 0.1, 6, &mut rng);
    }
    m
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mw-lod-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(format!("{name}.mwlod"))
}

fn edge(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// Edges used by exactly one triangle.
fn boundary(tris: &[[u32; 3]]) -> HashSet<(u32, u32)> {
    let mut count: HashMap<(u32, u32), u32> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            *count.entry(edge(t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    count
        .into_iter()
        .filter(|&(_, c)| c == 1)
        .map(|(e, _)| e)
        .collect()
}

/// Welds the patches of a cut by original ID; checks vertices against the input.
fn weld(file: &LodFile, cut: &[u32], input: &Mesh) -> Vec<[u32; 3]> {
    let tol = file.grid().max_error() as f32 * 1.01 + 1e-6;
    let mut tris = Vec::new();
    let mut seen_pos: HashMap<u32, [f32; 3]> = HashMap::new();
    for &n in cut {
        let p = file.patch(n).expect("patch decodes");
        // Interior vertices of coarse patches are quantised within the node's error bound.
        let allowed = tol + file.nodes()[n as usize].lod_error;
        for (i, &id) in p.original_ids.iter().enumerate() {
            let orig = input.positions[id as usize];
            let d = Vec3::from(orig).distance(Vec3::from(p.positions[i]));
            assert!(d <= allowed, "vertex {id} moved by {d} (allowed {allowed})");
            // The same vertex decodes to the same bits in every patch (watertight).
            let prev = seen_pos.entry(id).or_insert(p.positions[i]);
            assert_eq!(*prev, p.positions[i], "vertex {id} differs between patches");
        }
        for t in p.indices.chunks(3) {
            tris.push([t[0], t[1], t[2]].map(|i| p.original_ids[i as usize]));
        }
    }
    tris
}

fn check_structure(file: &LodFile, max_tris: u32, boundary_edges: usize, simplifier: Simplifier) {
    let nodes = file.nodes();
    assert!(!nodes.is_empty());
    let roots: Vec<_> = nodes.iter().filter(|n| n.member_of == NO_GROUP).collect();
    // The scan boundary stays locked, so the coarsest level needs about as many triangles as
    // the boundary has edges; beyond that only a handful of patches may remain. (The
    // segment-driven simplifier keeps every segment corner, so on noisy surfaces it stops
    // earlier: there the levels must only shrink.)
    let allowed = match simplifier {
        Simplifier::Quadric => 4 + 2 * boundary_edges / max_tris as usize,
        Simplifier::Segments => nodes.iter().filter(|n| n.level == 0).count() / 2,
    };
    assert!(
        roots.len() <= allowed,
        "{} roots (allowed {allowed})",
        roots.len()
    );
    assert_eq!(roots.len() as u32, file.header().root_count);
    for n in nodes {
        assert!(n.triangle_count <= max_tris && n.triangle_count > 0);
        assert!(
            n.lod_error <= n.parent_error,
            "error must grow towards the roots"
        );
        if n.member_of != NO_GROUP {
            let g = &file.groups()[n.member_of as usize];
            assert_eq!(g.error, n.parent_error);
            assert_eq!(g.sphere, n.parent_sphere);
            // The group's sphere contains the node's own LOD sphere and bounds.
            for s in [n.lod_sphere, n.bounds] {
                let d = Vec3::new(g.sphere[0], g.sphere[1], g.sphere[2])
                    .distance(Vec3::new(s[0], s[1], s[2]));
                assert!(d + s[3] <= g.sphere[3] * 1.0001 + 1e-6);
            }
        }
    }
    for g in file.groups() {
        for &p in file.products(g) {
            assert_eq!(nodes[p as usize].lod_error, g.error);
        }
    }
}

fn check_cuts(file: &LodFile, input: &Mesh) {
    let input_tris: Vec<[u32; 3]> = input
        .indices
        .chunks(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let input_boundary = boundary(&input_tris);
    let mut errors: Vec<f32> = file.nodes().iter().map(|n| n.lod_error).collect();
    errors.sort_by(f32::total_cmp);
    errors.dedup();
    let mut thresholds = vec![0.0f32];
    for w in errors.windows(2) {
        thresholds.push((w[0] + w[1]) * 0.5);
    }
    thresholds.push(errors.last().copied().unwrap_or(0.0) * 2.0 + 1.0);

    // The finest cut is exactly the input.
    let leaves = lod::cut_uniform(file.nodes(), 0.0);
    let mut welded = weld(file, &leaves, input);
    let canon = |t: &[u32; 3]| {
        let r = (0..3).min_by_key(|&k| t[k]).unwrap_or(0);
        [t[r], t[(r + 1) % 3], t[(r + 2) % 3]]
    };
    let mut a: Vec<[u32; 3]> = welded.iter().map(canon).collect();
    let mut b: Vec<[u32; 3]> = input_tris.iter().map(canon).collect();
    a.sort();
    b.sort();
    assert_eq!(a, b, "leaf cut must reproduce the input triangles");

    for &t in &thresholds {
        let cut = lod::cut_uniform(file.nodes(), t);
        assert!(!cut.is_empty());
        welded = weld(file, &cut, input);
        assert_eq!(
            boundary(&welded),
            input_boundary,
            "uniform cut at {t} has cracks"
        );
    }

    // View-dependent cuts from cameras all around, at several pixel thresholds.
    let h = file.header();
    let lo = Vec3::from(h.bbox_min);
    let hi = Vec3::from(h.bbox_max);
    let centre = (lo + hi) * 0.5;
    let radius = (hi - lo).length() * 0.5;
    let mut rng = Rng(99);
    for k in 0..24 {
        let dir =
            Vec3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5).normalize_or(Vec3::X);
        let dist = radius * (0.3 + 3.0 * rng.next());
        let cam = Camera {
            eye: centre + dir * dist,
            target: centre + Vec3::new(rng.next() - 0.5, rng.next() - 0.5, 0.0) * radius,
            up: if dir.cross(Vec3::Z).length() > 0.1 {
                Vec3::Z
            } else {
                Vec3::Y
            },
            fovy_deg: 50.0,
            width: 640,
            height: 480,
        };
        let px = [0.5f32, 1.0, 4.0, 20.0][k % 4];
        let cut = lod::cut_view(file.nodes(), &cam, px, Culling::NONE);
        welded = weld(file, &cut, input);
        assert_eq!(
            boundary(&welded),
            input_boundary,
            "view cut {k} ({px} px) has cracks"
        );
        // With culling the cut is a subset: its patches are a subset of the unculled cut.
        let culled: HashSet<u32> = lod::cut_view(file.nodes(), &cam, px, Culling::ALL)
            .into_iter()
            .collect();
        assert!(culled.is_subset(&cut.iter().copied().collect()));
    }
}

/// The sparse mesh (network mode): the uniform cut at the smallest error within a triangle
/// budget, every node of it "within sparse", and no smaller error within the budget.
fn check_sparse(file: &LodFile) {
    use meshwiki_engine::lod::sparse::{sparse_error, within_sparse};
    let nodes = file.nodes();
    let tris = |e: f32| -> u64 {
        lod::cut_uniform(nodes, e)
            .iter()
            .map(|&i| nodes[i as usize].triangle_count as u64)
            .sum()
    };
    let leaves = tris(0.0);
    let roots = tris(f32::MAX);
    for budget in [leaves, leaves / 4, leaves / 16, roots, 1] {
        let e = sparse_error(nodes, budget);
        let cut = lod::cut_uniform(nodes, e);
        assert!(!cut.is_empty());
        assert!(cut.iter().all(|&i| within_sparse(&nodes[i as usize], e)));
        if budget >= roots {
            assert!(tris(e) <= budget, "budget {budget}: {} triangles", tris(e));
            // No smaller error of a node keeps within the budget.
            assert!(
                nodes
                    .iter()
                    .map(|n| n.lod_error)
                    .filter(|&x| x < e)
                    .all(|x| tris(x) > budget),
                "budget {budget}: a finer cut fits"
            );
        }
        // Nodes finer than the sparse mesh are exactly those not within it.
        for n in nodes {
            if !within_sparse(n, e) {
                assert!(n.lod_error <= e);
            }
        }
    }
}

fn build_and_check(name: &str, mesh: &Mesh, max_tris: usize) {
    build_and_check_with(
        name,
        mesh,
        max_tris,
        Simplifier::Quadric,
        VertexOrder::Morton,
    );
}

fn build_and_check_with(
    name: &str,
    mesh: &Mesh,
    max_tris: usize,
    simplifier: Simplifier,
    order: VertexOrder,
) {
    let out = temp(name);
    let options = BuildOptions {
        max_patch_triangles: max_tris,
        memory_budget: 256 << 20,
        simplifier,
        vertex_order: order,
        ..Default::default()
    };
    let report = lod::build_mesh(mesh, &out, &options, &NoProgress).expect("build");
    assert_eq!(report.import.triangles, mesh.triangle_count() as u64);
    let file = LodFile::open(&out).expect("open");
    // Ids number the vertices in the order asked for: compare with the mesh so numbered.
    assert_eq!(file.vertex_order(), order);
    let mesh = &vertex_order::as_built(mesh, order, &file.grid());
    let tris: Vec<[u32; 3]> = mesh.indices.chunks(3).map(|t| [t[0], t[1], t[2]]).collect();
    check_structure(&file, max_tris as u32, boundary(&tris).len(), simplifier);
    check_cuts(&file, mesh);
    check_sparse(&file);
    // Nothing but the output and its surface segments is left behind.
    let dir = out.parent().expect("dir");
    let mut leftovers: Vec<_> = std::fs::read_dir(dir)
        .expect("list")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    leftovers.sort();
    let name = |p: &std::path::Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    let expected: Vec<_> = [name(&meshwiki_engine::segment::path_for(&out)), name(&out)]
        .into_iter()
        .flatten()
        .collect();
    let mut expected = expected;
    expected.sort();
    assert_eq!(leftovers, expected);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn terrains_with_holes_cut_without_cracks() {
    for seed in 1..=3u64 {
        let mesh = terrain(60 + seed as u32 * 7, seed, seed as usize * 3);
        build_and_check(&format!("terrain{seed}"), &mesh, 128 + 64 * seed as usize);
    }
}

#[test]
fn closed_multi_component_meshes_cut_without_cracks() {
    for seed in 1..=2u64 {
        let mesh = blobs(40 + seed as u32 * 10, seed);
        build_and_check(&format!("blobs{seed}"), &mesh, 256);
    }
}

#[test]
fn the_segment_driven_simplifier_builds_crack_free_hierarchies_too() {
    let mesh = terrain(74, 2, 4);
    build_and_check_with(
        "segterrain",
        &mesh,
        192,
        Simplifier::Segments,
        VertexOrder::Morton,
    );
    let mesh = blobs(50, 1);
    build_and_check_with(
        "segblobs",
        &mesh,
        256,
        Simplifier::Segments,
        VertexOrder::Morton,
    );
}

#[test]
fn the_files_own_vertex_order_is_kept_when_asked_for() {
    // Ids are then the file's vertex indices: the same checks against the mesh as it is.
    let mesh = terrain(67, 1, 3);
    build_and_check_with(
        "srcterrain",
        &mesh,
        192,
        Simplifier::Quadric,
        VertexOrder::Source,
    );
    let mesh = blobs(50, 2);
    build_and_check_with(
        "srcblobs",
        &mesh,
        256,
        Simplifier::Quadric,
        VertexOrder::Source,
    );
}

#[test]
fn corrupt_files_are_rejected() {
    let mesh = terrain(30, 5, 1);
    let out = temp("corrupt");
    lod::build_mesh(
        &mesh,
        &out,
        &BuildOptions {
            max_patch_triangles: 128,
            ..Default::default()
        },
        &NoProgress,
    )
    .expect("build");
    let bytes = std::fs::read(&out).expect("read");
    let bad = out.with_extension("bad");
    for cut in [0usize, 100, 256, 300, bytes.len() / 2] {
        std::fs::write(&bad, &bytes[..cut]).expect("write");
        assert!(LodFile::open(&bad).is_err(), "truncated at {cut} accepted");
    }
    let mut flipped = bytes.clone();
    flipped[300] ^= 0xff;
    std::fs::write(&bad, &flipped).expect("write");
    assert!(LodFile::open(&bad).is_err());
    // A flipped byte inside a blob is caught by that patch's checksum.
    let file = LodFile::open(&out).expect("open");
    let n = file.nodes()[0];
    let mut flipped = bytes.clone();
    flipped[n.blob_offset as usize + 20] ^= 0x55;
    std::fs::write(&bad, &flipped).expect("write");
    let damaged = LodFile::open(&bad).expect("tables intact");
    assert!(damaged.patch(0).is_err());
    let _ = std::fs::remove_dir_all(out.parent().expect("dir"));
}
