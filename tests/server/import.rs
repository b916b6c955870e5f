//! `meshwiki import` (exit code, summary, failures) and `meshwiki export-cut` (a binary PLY
//! whose `original_id`s are input vertex indices and whose triangles weld without cracks,
//! the same cut as the engine's).

use std::collections::HashMap;
use std::path::Path;
use std::process::{Command, Output};

use meshwiki_engine::lod::vertex_order::as_built;
use meshwiki_engine::lod::{Culling, LodFile, VertexOrder, cut_uniform, cut_view};

use crate::harness::*;
use crate::lod::{names, relief_ply};

fn meshwiki(args: &[&str], data: &Path) -> Output {
    Command::new(BIN)
        .args(args)
        .arg("--data-dir")
        .arg(data)
        .env("MESHWIKI_LOG", "warn")
        .output()
        .expect("run meshwiki")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// A binary little-endian PLY as written by `export-cut`.
struct Ply {
    positions: Vec<[f32; 3]>,
    ids: Vec<u32>,
    triangles: Vec<[u32; 3]>,
}

fn read_ply(path: &Path) -> Ply {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("end_header")
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    let (mut nv, mut nf) = (0usize, 0usize);
    let mut props: Vec<(String, usize)> = Vec::new();
    let mut in_vertex = false;
    for line in header.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => {
                nv = n.parse().unwrap();
                in_vertex = true;
            }
            ["element", "face", n] => {
                nf = n.parse().unwrap();
                in_vertex = false;
            }
            ["property", ty, name] if in_vertex => {
                let size = match *ty {
                    "float" | "uint" | "int" => 4,
                    "uchar" => 1,
                    other => panic!("unexpected type {other}"),
                };
                props.push((name.to_string(), size));
            }
            _ => {}
        }
    }
    let stride: usize = props.iter().map(|p| p.1).sum();
    let offset = |name: &str| {
        let mut o = 0;
        for (n, s) in &props {
            if n == name {
                return o;
            }
            o += s;
        }
        panic!("no property {name}: {props:?}")
    };
    let (ox, oid) = (offset("x"), offset("original_id"));
    let f32_at = |p: usize| f32::from_le_bytes(bytes[p..p + 4].try_into().unwrap());
    let u32_at = |p: usize| u32::from_le_bytes(bytes[p..p + 4].try_into().unwrap());
    let mut ply = Ply {
        positions: Vec::new(),
        ids: Vec::new(),
        triangles: Vec::new(),
    };
    for v in 0..nv {
        let base = end + v * stride;
        ply.positions.push([
            f32_at(base + ox),
            f32_at(base + ox + 4),
            f32_at(base + ox + 8),
        ]);
        ply.ids.push(u32_at(base + oid));
    }
    let mut p = end + nv * stride;
    for _ in 0..nf {
        assert_eq!(bytes[p], 3);
        ply.triangles
            .push([u32_at(p + 1), u32_at(p + 5), u32_at(p + 9)]);
        p += 13;
    }
    assert_eq!(p, bytes.len());
    ply
}

fn boundary(tris: impl Iterator<Item = [u32; 3]>) -> Vec<(u32, u32)> {
    let mut count: HashMap<(u32, u32), u32> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut v: Vec<_> = count
        .into_iter()
        .filter(|&(_, c)| c == 1)
        .map(|(e, _)| e)
        .collect();
    v.sort_unstable();
    v
}

#[test]
fn import_then_export_cuts() {
    let dir = data_dir_with_admin();
    let data = dir.path();
    let scans = tempfile::tempdir().unwrap();
    let ply = relief_ply(scans.path(), "panel.ply", 30_000);
    let (input, _) = meshwiki_engine::mesh::load(&ply).unwrap();

    // A good import: exit 0 and the summary.
    let out = meshwiki(
        &[
            "import",
            ply.to_str().unwrap(),
            "--title",
            "Panel",
            "--max-patch-triangles",
            "512",
            "--memory",
            "256M",
        ],
        data,
    );
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}{}", stdout, text(&out.stderr));
    for word in [
        "imported \"Panel\" as model 1",
        "triangles",
        "levels",
        "nodes",
        "throughput",
        "peak memory",
        "bytes per input triangle",
    ] {
        assert!(stdout.contains(word), "{word:?} in {stdout}");
    }
    // Bad input: non-zero exit, the importer's message, a failed model, nothing left.
    let bad = scans.path().join("broken.ply");
    let bytes = std::fs::read(&ply).unwrap();
    std::fs::write(&bad, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let out = meshwiki(
        &["import", bad.to_str().unwrap(), "--title", "Broken"],
        data,
    );
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("broken.ply") && stderr.contains("truncated"),
        "{stderr}"
    );
    let out = meshwiki(&["import", "/nonexistent/x.ply", "--title", "X"], data);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("/nonexistent/x.ply"));
    let notes = scans.path().join("notes.txt");
    std::fs::write(&notes, "hello").unwrap();
    let out = meshwiki(&["import", notes.to_str().unwrap(), "--title", "X"], data);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("unknown file extension"));
    // The LOD file and its surface segments.
    assert_eq!(
        names(&data.join("models")),
        vec!["1.mwlod".to_string(), "1.mwseg".to_string()]
    );

    // Uniform cuts: input vertex ids, input positions, the input's boundary, the engine's cut.
    let lod = LodFile::open(&data.join("models/1.mwlod")).unwrap();
    // Ids number the scan's vertices in the default Morton order on the file's grid.
    assert_eq!(lod.vertex_order(), VertexOrder::Morton);
    let input = as_built(&input, lod.vertex_order(), &lod.grid());
    let input_boundary = boundary(input.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
    let step = lod.header().grid_step as f32;
    let max = lod
        .nodes()
        .iter()
        .map(|n| n.lod_error)
        .fold(0.0f32, f32::max);
    let out_ply = scans.path().join("cut.ply");
    for error in [0.0, max * 0.05, max * 0.3, max * 4.0] {
        let e = format!("{error}");
        let out = meshwiki(
            &[
                "export-cut",
                "1",
                "--max-error",
                &e,
                "--out",
                out_ply.to_str().unwrap(),
            ],
            data,
        );
        assert!(out.status.success(), "{}", text(&out.stderr));
        assert!(text(&out.stdout).contains("wrote"));
        let cut = read_ply(&out_ply);
        let nodes = cut_uniform(lod.nodes(), error);
        let tris: u64 = nodes
            .iter()
            .map(|&n| lod.nodes()[n as usize].triangle_count as u64)
            .sum();
        assert_eq!(cut.triangles.len() as u64, tris, "error {error}");
        for (p, &id) in cut.positions.iter().zip(&cut.ids) {
            let q = input.positions[id as usize];
            let d = (0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f32::max);
            // Border vertices are exact; interior ones of coarse patches are quantised.
            assert!(d <= error.max(step) * 1.01 + 1e-6, "vertex {id}: {d}");
        }
        let mut ids = cut.ids.clone();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(
            ids.len(),
            cut.ids.len(),
            "welded: one vertex per original id"
        );
        let welded = cut.triangles.iter().map(|t| t.map(|i| cut.ids[i as usize]));
        assert_eq!(
            boundary(welded),
            input_boundary,
            "crack-free at error {error}"
        );
    }
    // A view-dependent cut: the same nodes as the engine's.
    let b = lod.header();
    let c = [
        (b.bbox_min[0] + b.bbox_max[0]) / 2.0,
        (b.bbox_min[1] + b.bbox_max[1]) / 2.0,
        (b.bbox_min[2] + b.bbox_max[2]) / 2.0,
    ];
    let cam = format!(
        "{},{},{},{},{},{},0,1,0,40,640,480",
        c[0] + 0.3,
        c[1] - 0.2,
        c[2] + 1.6,
        c[0],
        c[1],
        c[2]
    );
    let out = meshwiki(
        &[
            "export-cut",
            "1",
            "--camera",
            &cam,
            "--pixel-error",
            "2",
            "--out",
            out_ply.to_str().unwrap(),
        ],
        data,
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let cut = read_ply(&out_ply);
    let camera = meshwiki_engine::camera::Camera {
        eye: glam::Vec3::new(c[0] + 0.3, c[1] - 0.2, c[2] + 1.6),
        target: glam::Vec3::from(c),
        up: glam::Vec3::Y,
        fovy_deg: 40.0,
        width: 640,
        height: 480,
    };
    let nodes = cut_view(lod.nodes(), &camera, 2.0, Culling::ALL);
    let tris: u64 = nodes
        .iter()
        .map(|&n| lod.nodes()[n as usize].triangle_count as u64)
        .sum();
    assert!(tris > 0);
    assert_eq!(cut.triangles.len() as u64, tris);
    assert!(
        cut.ids
            .iter()
            .all(|&id| (id as usize) < input.positions.len())
    );
    // Bad arguments and models fail with a message.
    for (args, expect) in [
        (vec!["export-cut", "1", "--out", "x.ply"], "--max-error"),
        (
            vec!["export-cut", "1", "--camera", "1,2,3", "--out", "x.ply"],
            "12 comma-separated",
        ),
        (
            vec!["export-cut", "1", "--max-error", "nan", "--out", "x.ply"],
            "finite",
        ),
        (
            vec!["export-cut", "2", "--max-error", "0", "--out", "x.ply"],
            "failed",
        ),
        (
            vec!["export-cut", "77", "--max-error", "0", "--out", "x.ply"],
            "not found",
        ),
    ] {
        let out = meshwiki(&args, data);
        assert!(!out.status.success(), "{args:?}");
        let err = text(&out.stderr);
        assert!(err.contains(expect), "{args:?}: {err}");
    }

    // The server sees both models: the ready one with its thumbnail, the failed one with the
    // importer's message.
    let server = Server::start(data);
    let admin = server.login("admin", ADMIN_PASSWORD);
    let m = admin.get("/api/v1/models/1").json();
    assert_eq!(m["status"], "ready");
    assert!(m["thumbnail_attachment_id"].is_i64(), "{m}");
    let m = admin.get("/api/v1/models/2").json();
    assert_eq!(m["status"], "failed");
    assert!(m["error"].as_str().unwrap().contains("truncated"));
    let jobs = admin.get("/api/v1/jobs").json();
    assert_eq!(jobs.as_array().unwrap().len(), 2);
    assert!(jobs.as_array().unwrap().iter().all(|j| j["kind"] == "file"));
}
