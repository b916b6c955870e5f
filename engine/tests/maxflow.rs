//! Boykov–Kolmogorov max-flow: hand-checked graphs, random graphs against an Edmonds–Karp
//! oracle, the grid variant against the general one, tree reuse, input errors, and the
//! reference grid instances of `../shared/data/maxflow` (skipped when absent).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use meshwiki_engine::select::maxflow::{Graph, GraphError};
use meshwiki_engine::select::maxflow_grid::{GridEdges, GridGraph};

/// splitmix64: deterministic randomness without a dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// A capacity: often zero, small integers (exact in f32) or reals, sometimes a hard 1e9.
    fn cap(&mut self, integer: bool, hard: bool) -> f32 {
        match self.below(10) {
            0..=2 => 0.0,
            9 if hard => 1e9,
            _ if integer => (1 + self.below(20)) as f32,
            _ => 0.01 + 10.0 * self.unit(),
        }
    }
}

/// A problem in plain form: t-links per node and directed-pair edges.
#[derive(Clone)]
struct Problem {
    source: Vec<f32>,
    sink: Vec<f32>,
    edges: Vec<[u32; 2]>,
    cap: Vec<f32>,
    rev: Vec<f32>,
}

impl Problem {
    fn random(rng: &mut Rng, n: usize, m: usize, integer: bool, hard: bool) -> Self {
        let mut p = Problem {
            source: Vec::new(),
            sink: Vec::new(),
            edges: Vec::new(),
            cap: Vec::new(),
            rev: Vec::new(),
        };
        for _ in 0..n {
            p.source.push(rng.cap(integer, hard));
            p.sink.push(rng.cap(integer, hard));
        }
        for _ in 0..m {
            let u = rng.below(n as u64) as u32;
            let v = rng.below(n as u64) as u32;
            let c = rng.cap(integer, false);
            let r = if rng.below(2) == 0 {
                c
            } else {
                rng.cap(integer, false)
            };
            p.edges.push([u, v]);
            p.cap.push(c);
            p.rev.push(r);
        }
        p
    }

    fn graph(&self) -> Graph {
        match Graph::from_edges(&self.source, &self.sink, &self.edges, &self.cap, &self.rev) {
            Ok(g) => g,
            Err(e) => panic!("valid graph rejected: {e}"),
        }
    }

    /// Capacity of the cut given by `labels` (1 = source side).
    fn cut(&self, labels: &[u8]) -> f64 {
        let mut c = 0.0;
        for (v, &l) in labels.iter().enumerate() {
            c += if l == 1 {
                self.sink[v] as f64
            } else {
                self.source[v] as f64
            };
        }
        for (e, &[u, v]) in self.edges.iter().enumerate() {
            let (lu, lv) = (labels[u as usize], labels[v as usize]);
            if lu == 1 && lv == 0 {
                c += self.cap[e] as f64;
            } else if lu == 0 && lv == 1 {
                c += self.rev[e] as f64;
            }
        }
        c
    }

    /// Edmonds–Karp on a dense matrix (source = n, sink = n + 1), in f64.
    fn oracle(&self) -> f64 {
        let n = self.source.len();
        let (s, t, size) = (n, n + 1, n + 2);
        let mut c = vec![0.0f64; size * size];
        for v in 0..n {
            c[s * size + v] += self.source[v] as f64;
            c[v * size + t] += self.sink[v] as f64;
        }
        for (e, &[u, v]) in self.edges.iter().enumerate() {
            if u != v {
                c[u as usize * size + v as usize] += self.cap[e] as f64;
                c[v as usize * size + u as usize] += self.rev[e] as f64;
            }
        }
        let mut flow = 0.0;
        loop {
            let mut prev = vec![usize::MAX; size];
            prev[s] = s;
            let mut queue = std::collections::VecDeque::from([s]);
            while let Some(u) = queue.pop_front() {
                for v in 0..size {
                    if prev[v] == usize::MAX && c[u * size + v] > 0.0 {
                        prev[v] = u;
                        queue.push_back(v);
                    }
                }
            }
            if prev[t] == usize::MAX {
                return flow;
            }
            let mut b = f64::INFINITY;
            let mut v = t;
            while v != s {
                b = b.min(c[prev[v] * size + v]);
                v = prev[v];
            }
            let mut v = t;
            while v != s {
                c[prev[v] * size + v] -= b;
                c[v * size + prev[v]] += b;
                v = prev[v];
            }
            flow += b;
        }
    }
}

fn assert_close(got: f64, want: f64, rel: f64, what: &str) {
    let tol = rel * want.abs().max(1.0);
    assert!(
        (got - want).abs() <= tol,
        "{what}: got {got}, want {want} (tolerance {tol})"
    );
}

#[test]
fn maxflow_hand_checked_chain() {
    // s -3-> 0 -2-> 1 -4-> t: bottleneck 2 in the middle; 0 stays with the source.
    let mut g = Graph::from_edges(&[3.0, 0.0], &[0.0, 4.0], &[[0, 1]], &[2.0], &[0.0]).unwrap();
    assert_eq!(g.maxflow(), 2.0);
    assert_eq!(g.labels(), vec![1, 0]);
    assert_eq!(g.is_source(2), None);
}

#[test]
fn maxflow_hand_checked_folded_terminals_and_reverse_capacity() {
    // Node 0: source 5, sink 3 → 3 folded up front, 2 left towards the source.
    // Edge 0 → 1 has capacity 1 forward, 10 backward; node 1 has sink 7.
    // Max flow = 3 + min(2, 1) = 4; cut: {0} | {1}.
    let mut g = Graph::from_edges(&[5.0, 0.0], &[3.0, 7.0], &[[0, 1]], &[1.0], &[10.0]).unwrap();
    assert_eq!(g.flow(), 3.0);
    assert_eq!(g.maxflow(), 4.0);
    assert_eq!(g.labels(), vec![1, 0]);
    // The same edge given the other way round.
    let mut g = Graph::from_edges(&[5.0, 0.0], &[3.0, 7.0], &[[1, 0]], &[10.0], &[1.0]).unwrap();
    assert_eq!(g.maxflow(), 4.0);
}

#[test]
fn maxflow_hand_checked_textbook_network() {
    // CLRS figure 26.1 with s → {0: 16, 1: 13} and {2: 20, 3: 4} → t; max flow 23.
    let source = [16.0, 13.0, 0.0, 0.0];
    let sink = [0.0, 0.0, 20.0, 4.0];
    let edges = [[0, 1], [1, 0], [0, 2], [2, 1], [1, 3], [3, 2]];
    let cap = [10.0, 4.0, 12.0, 9.0, 14.0, 7.0];
    let rev = [0.0; 6];
    let mut g = Graph::from_edges(&source, &sink, &edges, &cap, &rev).unwrap();
    assert_eq!(g.maxflow(), 23.0);
    let p = Problem {
        source: source.to_vec(),
        sink: sink.to_vec(),
        edges: edges.to_vec(),
        cap: cap.to_vec(),
        rev: rev.to_vec(),
    };
    assert_eq!(p.cut(&g.labels()), 23.0);
    assert_eq!(p.oracle(), 23.0);
}

#[test]
fn maxflow_hard_seeds_do_not_disturb_the_cut() {
    // Hard seeds (1e9) on both ends of a chain with small, non-representable n-links.
    let source = [1e9, 0.0, 0.0, 0.0];
    let sink = [0.3, 0.0, 0.0, 1e9];
    let edges = [[0, 1], [1, 2], [2, 3]];
    let cap = [0.7, 0.1, 0.9];
    let mut g = Graph::from_edges(&source, &sink, &edges, &cap, &cap).unwrap();
    let f = g.maxflow();
    assert_close(f, 0.3 + 0.1, 1e-7, "flow");
    assert_eq!(g.labels(), vec![1, 1, 0, 0]);
    // Conflicting hard seeds on one node count 1e9 exactly, the rest is unchanged.
    let mut g = Graph::from_edges(&[1e9, 1e9], &[1e9, 0.0], &[[0, 1]], &[0.5], &[0.5]).unwrap();
    assert_eq!(g.maxflow(), 1e9);
}

#[test]
fn maxflow_random_graphs_match_oracle() {
    let mut rng = Rng(7);
    for case in 0..600 {
        let n = 1 + rng.below(30) as usize;
        let m = rng.below(4 * n as u64 + 1) as usize;
        let integer = case % 2 == 0;
        let hard = case % 3 == 0;
        let p = Problem::random(&mut rng, n, m, integer, hard);
        let want = p.oracle();
        let mut g = p.graph();
        let got = g.maxflow();
        let rel = if integer { 0.0 } else { 1e-6 };
        assert_close(got, want, rel, &format!("case {case} flow"));
        assert_close(p.cut(&g.labels()), got, rel, &format!("case {case} cut"));
    }
}

#[test]
fn maxflow_csr_input_matches_edge_list() {
    let mut rng = Rng(11);
    for case in 0..200 {
        let n = 1 + rng.below(25) as usize;
        let m = rng.below(3 * n as u64 + 1) as usize;
        let p = Problem::random(&mut rng, n, m, true, false);
        // One arc per direction of each edge, in compressed rows.
        let mut arcs: Vec<(u32, u32, f32)> = Vec::new();
        for (e, &[u, v]) in p.edges.iter().enumerate() {
            arcs.push((u, v, p.cap[e]));
            arcs.push((v, u, p.rev[e]));
        }
        arcs.sort_by_key(|a| a.0);
        let mut offsets = vec![0u32; n + 1];
        for a in &arcs {
            offsets[a.0 as usize + 1] += 1;
        }
        for v in 0..n {
            offsets[v + 1] += offsets[v];
        }
        let targets: Vec<u32> = arcs.iter().map(|a| a.1).collect();
        let caps: Vec<f32> = arcs.iter().map(|a| a.2).collect();
        let mut g = Graph::from_csr(&p.source, &p.sink, &offsets, &targets, &caps).unwrap();
        let got = g.maxflow();
        assert_eq!(got, p.oracle(), "case {case}");
        assert_eq!(p.cut(&g.labels()), got, "case {case} cut");
    }
}

#[test]
fn maxflow_tree_reuse_after_tweight_changes() {
    let mut rng = Rng(23);
    for case in 0..300 {
        let n = 2 + rng.below(30) as usize;
        let m = rng.below(4 * n as u64) as usize;
        let mut p = Problem::random(&mut rng, n, m, true, case % 4 == 0);
        let mut reused = p.graph();
        let mut fresh = p.graph();
        reused.maxflow();
        fresh.maxflow();
        for round in 0..3 {
            for _ in 0..1 + rng.below(5) {
                let v = rng.below(n as u64) as usize;
                let (mut ds, dt) = (rng.cap(true, case % 5 == 0), rng.cap(true, false));
                if rng.below(3) == 0 {
                    // Taking capacity away (the result stays non-negative).
                    ds = -(p.source[v] / 2.0).floor();
                }
                p.source[v] += ds;
                p.sink[v] += dt;
                reused.add_tweights(v as u32, ds, dt).unwrap();
                fresh.add_tweights(v as u32, ds, dt).unwrap();
            }
            // Exact with small integers; with conflicting hard seeds (flow ~1e9) the sums of
            // f32 t-links round differently here and in the folded solver.
            let want = p.oracle();
            let rel = if want < 1e8 { 0.0 } else { 1e-7 };
            let what = format!("case {case} round {round}");
            let got = reused.maxflow_reuse_trees();
            assert_close(got, want, rel, &format!("{what} (reused trees)"));
            assert_close(p.cut(&reused.labels()), want, rel, &format!("{what} cut"));
            assert_close(fresh.maxflow(), want, rel, &format!("{what} (fresh)"));
        }
    }
}

/// A random grid problem: per-pixel arrays plus the same problem as an edge list.
struct GridProblem {
    w: usize,
    h: usize,
    source: Vec<f32>,
    sink: Vec<f32>,
    fwd: [Vec<f32>; 4],
    bwd: [Vec<f32>; 4],
}

const OFFSETS: [(isize, isize); 4] = [(0, 1), (1, 0), (1, 1), (1, -1)];

impl GridProblem {
    fn random(rng: &mut Rng, w: usize, h: usize, integer: bool, symmetric: bool) -> Self {
        let n = w * h;
        let arr = |rng: &mut Rng| (0..n).map(|_| rng.cap(integer, false)).collect::<Vec<_>>();
        let source = (0..n).map(|_| rng.cap(integer, true)).collect();
        let sink = (0..n).map(|_| rng.cap(integer, true)).collect();
        let fwd = [arr(rng), arr(rng), arr(rng), arr(rng)];
        let bwd = if symmetric {
            fwd.clone()
        } else {
            [arr(rng), arr(rng), arr(rng), arr(rng)]
        };
        GridProblem {
            w,
            h,
            source,
            sink,
            fwd,
            bwd,
        }
    }

    fn edges(e: &[Vec<f32>; 4]) -> GridEdges<'_> {
        GridEdges {
            right: &e[0],
            down: &e[1],
            down_right: &e[2],
            down_left: &e[3],
        }
    }

    fn grid(&self) -> GridGraph {
        GridGraph::new(
            self.w,
            self.h,
            &self.source,
            &self.sink,
            &Self::edges(&self.fwd),
            &Self::edges(&self.bwd),
        )
        .unwrap()
    }

    /// The same graph as an edge list (edges leaving the image dropped).
    fn problem(&self) -> Problem {
        let mut p = Problem {
            source: self.source.clone(),
            sink: self.sink.clone(),
            edges: Vec::new(),
            cap: Vec::new(),
            rev: Vec::new(),
        };
        for r in 0..self.h {
            for c in 0..self.w {
                for (d, &(dr, dc)) in OFFSETS.iter().enumerate() {
                    let (tr, tc) = (r as isize + dr, c as isize + dc);
                    if tr < 0 || tc < 0 || tr as usize >= self.h || tc as usize >= self.w {
                        continue;
                    }
                    let p0 = r * self.w + c;
                    p.edges
                        .push([p0 as u32, (tr as usize * self.w + tc as usize) as u32]);
                    p.cap.push(self.fwd[d][p0]);
                    p.rev.push(self.bwd[d][p0]);
                }
            }
        }
        p
    }
}

#[test]
fn maxflow_grid_matches_general_graph_and_oracle() {
    let mut rng = Rng(5);
    for case in 0..300 {
        let w = 1 + rng.below(8) as usize;
        let h = 1 + rng.below(8) as usize;
        let integer = case % 2 == 0;
        let gp = GridProblem::random(&mut rng, w, h, integer, case % 3 != 0);
        let p = gp.problem();
        let want = p.oracle();
        let mut grid = gp.grid();
        let got = grid.maxflow();
        let rel = if integer { 0.0 } else { 1e-6 };
        assert_close(got, want, rel, &format!("case {case} grid flow"));
        let labels = grid.labels();
        assert_close(p.cut(&labels), got, rel, &format!("case {case} grid cut"));
        // The general solver finds the same (maximal source side) cut.
        let mut g = p.graph();
        assert_close(g.maxflow(), want, rel, &format!("case {case} graph flow"));
        if integer {
            assert_eq!(g.labels(), labels, "case {case} labels");
        }
    }
}

#[test]
fn maxflow_grid_tree_reuse() {
    let mut rng = Rng(99);
    for case in 0..100 {
        let (w, h) = (2 + rng.below(6) as usize, 2 + rng.below(6) as usize);
        let mut gp = GridProblem::random(&mut rng, w, h, true, true);
        let mut grid = gp.grid();
        grid.maxflow();
        for _ in 0..3 {
            for _ in 0..3 {
                let (x, y) = (rng.below(w as u64) as usize, rng.below(h as u64) as usize);
                let (ds, dt) = (rng.cap(true, true), rng.cap(true, false));
                gp.source[y * w + x] += ds;
                gp.sink[y * w + x] += dt;
                grid.add_tweights(x, y, ds, dt).unwrap();
            }
            let p = gp.problem();
            let want = p.oracle();
            let rel = if want < 1e8 { 0.0 } else { 1e-7 };
            assert_close(
                grid.maxflow_reuse_trees(),
                want,
                rel,
                &format!("case {case}"),
            );
            assert_close(
                p.cut(&grid.labels()),
                want,
                rel,
                &format!("case {case} cut"),
            );
        }
    }
}

#[test]
fn maxflow_rejects_invalid_graphs() {
    let e = [[0u32, 1u32]];
    assert!(matches!(
        Graph::from_edges(&[1.0, 1.0], &[1.0], &e, &[1.0], &[1.0]),
        Err(GraphError::SizeMismatch { what: "sink", .. })
    ));
    assert!(matches!(
        Graph::from_edges(&[1.0, 1.0], &[1.0, 1.0], &e, &[1.0], &[]),
        Err(GraphError::SizeMismatch { .. })
    ));
    assert!(matches!(
        Graph::from_edges(&[1.0, -1.0], &[1.0, 1.0], &e, &[1.0], &[1.0]),
        Err(GraphError::InvalidCapacity {
            what: "source",
            index: 1,
            ..
        })
    ));
    assert!(matches!(
        Graph::from_edges(&[1.0, 1.0], &[1.0, 1.0], &e, &[f32::NAN], &[1.0]),
        Err(GraphError::InvalidCapacity { what: "cap", .. })
    ));
    assert!(matches!(
        Graph::from_edges(&[1.0, 1.0], &[1.0, 1.0], &e, &[1.0], &[f32::INFINITY]),
        Err(GraphError::InvalidCapacity {
            what: "rev_cap",
            ..
        })
    ));
    assert!(matches!(
        Graph::from_edges(&[1.0, 1e31], &[1.0, 1.0], &e, &[1.0], &[1.0]),
        Err(GraphError::InvalidCapacity {
            what: "source",
            index: 1,
            ..
        })
    ));
    assert!(matches!(
        Graph::from_edges(&[1.0, 1.0], &[1.0, 1.0], &[[0, 2]], &[1.0], &[1.0]),
        Err(GraphError::NodeOutOfRange { node: 2, .. })
    ));
    assert!(matches!(
        Graph::from_csr(&[1.0, 1.0], &[1.0, 1.0], &[0, 2, 1], &[1, 0], &[1.0, 1.0]),
        Err(GraphError::BadOffsets { .. })
    ));
    assert!(matches!(
        Graph::from_csr(&[1.0, 1.0], &[1.0, 1.0], &[0, 1, 2], &[1, 5], &[1.0, 1.0]),
        Err(GraphError::NodeOutOfRange { node: 5, .. })
    ));
    let mut g = Graph::from_edges(&[1.0, 1.0], &[1.0, 1.0], &e, &[1.0], &[1.0]).unwrap();
    assert!(g.add_tweights(2, 1.0, 0.0).is_err());
    assert!(g.add_tweights(0, f32::NAN, 0.0).is_err());
    assert!(g.add_tweights(0, 0.0, f32::MAX).is_err());
    assert!(g.add_tweights(0, -2.0, 0.0).is_ok());

    let z = vec![0.0f32; 6];
    let short = vec![0.0f32; 5];
    let ok = GridEdges {
        right: &z,
        down: &z,
        down_right: &z,
        down_left: &z,
    };
    let bad = GridEdges {
        down_left: &short,
        ..ok
    };
    assert!(matches!(
        GridGraph::symmetric(3, 2, &z, &z, &bad),
        Err(GraphError::SizeMismatch {
            what: "forward.down_left",
            ..
        })
    ));
    let mut neg = z.clone();
    neg[4] = -0.5;
    let bad = GridEdges { down: &neg, ..ok };
    assert!(matches!(
        GridGraph::new(3, 2, &z, &z, &ok, &bad),
        Err(GraphError::InvalidCapacity {
            what: "backward.down",
            index: 4,
            ..
        })
    ));
    assert!(GridGraph::symmetric(usize::MAX, 2, &z, &z, &ok).is_err());
    let mut g = GridGraph::symmetric(3, 2, &z, &z, &ok).unwrap();
    assert_eq!(g.maxflow(), 0.0);
    assert!(g.add_tweights(3, 0, 1.0, 0.0).is_err());
    assert_eq!(g.is_source(0, 2), None);
    // An empty graph is fine.
    let mut g = Graph::from_edges(&[], &[], &[], &[], &[]).unwrap();
    assert_eq!(g.maxflow(), 0.0);
    assert!(g.labels().is_empty());
}

/// Unpacks the reference instances into a fresh temporary directory.
fn unpack_reference() -> Option<PathBuf> {
    let archive = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/maxflow/grid_default.tar.zst");
    if !archive.exists() {
        return None;
    }
    let dir = std::env::temp_dir().join(format!("meshwiki-maxflow-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut zstd = Command::new("zstd")
        .arg("-dc")
        .arg(&archive)
        .stdout(Stdio::piped())
        .spawn()
        .expect("zstd");
    let tar = Command::new("tar")
        .arg("-x")
        .arg("-C")
        .arg(&dir)
        .stdin(zstd.stdout.take().unwrap())
        .status()
        .expect("tar");
    assert!(
        zstd.wait().unwrap().success() && tar.success(),
        "unpacking failed"
    );
    Some(dir)
}

fn read_f32(path: &Path) -> Vec<f32> {
    let bytes = std::fs::read(path).unwrap();
    bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

fn json_number(text: &str, key: &str) -> f64 {
    let at = text.find(&format!("\"{key}\"")).unwrap() + key.len() + 2;
    let rest = text[at..].trim_start().trim_start_matches(':').trim_start();
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || "+-.eE".contains(c)))
        .unwrap_or(rest.len());
    rest[..end].parse().unwrap()
}

#[test]
fn maxflow_reference_grid_instances() {
    let Some(dir) = unpack_reference() else {
        eprintln!("skipping: ../shared/data/maxflow/grid_default.tar.zst not found");
        return;
    };
    for name in ["512x512", "1024x1024"] {
        let meta = std::fs::read_to_string(dir.join(format!("meta_{name}.json"))).unwrap();
        let (w, h) = (
            json_number(&meta, "w") as usize,
            json_number(&meta, "h") as usize,
        );
        let want = json_number(&meta, "flow");
        let f = |p: &str| read_f32(&dir.join(format!("{p}_{name}.f32")));
        let (source, sink) = (f("src"), f("sink"));
        let fwd = [f("e_right"), f("e_down"), f("e_downright"), f("e_downleft")];
        let reference = std::fs::read(dir.join(format!("seg_{name}.u8"))).unwrap();
        let gp = GridProblem {
            w,
            h,
            source,
            sink,
            bwd: fwd.clone(),
            fwd,
        };
        let mut grid = gp.grid();
        let got = grid.maxflow();
        let labels = grid.labels();
        let p = gp.problem();
        let cut = p.cut(&labels);
        // Which side the reference marks with 1 is read off the hard source seeds (the
        // files follow PyMaxflow's get_grid_segments: 1 = sink side).
        let hard: Vec<usize> = (0..w * h).filter(|&p| gp.source[p] >= 1e9).collect();
        let ones = hard.iter().filter(|&&p| reference[p] == 1).count();
        let one_is_source = ones * 2 > hard.len();
        let differ = labels
            .iter()
            .zip(&reference)
            .filter(|&(&l, &r)| (l == 1) != ((r == 1) == one_is_source))
            .count();
        eprintln!(
            "{name}: flow {got:.6} (reference {want:.6}, relative {:.2e}), cut {cut:.6}, \
             {differ} pixels differ from the reference labelling (1 = {} side there)",
            (got - want) / want,
            if one_is_source { "source" } else { "sink" }
        );
        assert_close(got, want, 1e-5, &format!("{name} flow"));
        assert_close(cut, got, 1e-5, &format!("{name} cut"));
        // The general-graph solver agrees.
        let mut g = p.graph();
        assert_close(g.maxflow(), want, 1e-5, &format!("{name} general flow"));
        assert_close(
            p.cut(&g.labels()),
            want,
            1e-5,
            &format!("{name} general cut"),
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Larger graphs than the oracle handles: the cut of the labelling must equal the flow (a
/// certificate of optimality), the grid and general solvers must agree, and re-solving with
/// reused trees must agree with solving afresh.
#[test]
fn maxflow_larger_graphs_certify_themselves() {
    let cases: usize = std::env::var("MAXFLOW_STRESS_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(40);
    let mut rng = Rng(31);
    for case in 0..cases {
        let w = 10 + rng.below(50) as usize;
        let h = 10 + rng.below(50) as usize;
        let gp = GridProblem::random(&mut rng, w, h, true, case % 2 == 0);
        let p = gp.problem();
        let mut grid = gp.grid();
        let flow = grid.maxflow();
        assert_eq!(p.cut(&grid.labels()), flow, "grid case {case}");
        let mut g = p.graph();
        assert_eq!(g.maxflow(), flow, "graph case {case}");
        assert_eq!(g.labels(), grid.labels(), "labels case {case}");

        // Random sparse general graph with some hubs, then t-link changes.
        let n = 50 + rng.below(500) as usize;
        let m = rng.below(6 * n as u64) as usize;
        let mut p = Problem::random(&mut rng, n, m, true, false);
        for _ in 0..n / 10 {
            let hub = rng.below(n as u64) as u32;
            let other = rng.below(n as u64) as u32;
            p.edges.push([hub, other]);
            p.cap.push(rng.cap(true, false));
            p.rev.push(rng.cap(true, false));
        }
        let mut reused = p.graph();
        let flow = reused.maxflow();
        assert_eq!(p.cut(&reused.labels()), flow, "general case {case}");
        for _ in 0..n / 20 + 1 {
            let v = rng.below(n as u64) as usize;
            let (ds, dt) = (rng.cap(true, false), rng.cap(true, false));
            p.source[v] += ds;
            p.sink[v] += dt;
            reused.add_tweights(v as u32, ds, dt).unwrap();
        }
        let flow = reused.maxflow_reuse_trees();
        assert_eq!(p.cut(&reused.labels()), flow, "reuse case {case}");
        assert_eq!(p.graph().maxflow(), flow, "fresh case {case}");
    }
}
