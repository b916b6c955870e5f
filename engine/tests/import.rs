//! Import tests: real scans from `../shared/data` (skipped when absent), small files of every
//! format and variant written here, a corpus of broken files with the errors they must give,
//! random byte mutations (no panics), and the synth -> PLY -> import roundtrip.

use meshwiki_engine::mesh::{
    self, ImportError, ImportErrorKind, ImportStats, Location, Mesh, Relief, write_ply,
};
use meshwiki_engine::progress::{CountingProgress, NoProgress};
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};

// ---------------------------------------------------------------------------------------
// helpers

/// A directory removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        static N: AtomicU64 = AtomicU64::new(0);
        let d = std::env::temp_dir().join(format!(
            "meshwiki-import-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        TempDir(d)
    }

    fn file(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.0.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn data_dir() -> Option<PathBuf> {
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    if d.join("README.md").is_file() {
        Some(d)
    } else {
        eprintln!("skipping: ../shared/data is absent");
        None
    }
}

/// Decompresses `src` into `dir` with `zstd` or `gunzip`; `None` (and a message) if the tool
/// is missing.
fn decompress(src: &Path, dir: &TempDir) -> Option<PathBuf> {
    let name = src.file_name()?.to_str()?;
    let (tool, args, out) = if let Some(base) = name.strip_suffix(".zst") {
        ("zstd", vec!["-d", "-c", "-q"], base)
    } else if let Some(base) = name.strip_suffix(".gz") {
        ("gunzip", vec!["-c"], base)
    } else {
        return None;
    };
    let dst = dir.0.join(out);
    let file = std::fs::File::create(&dst).ok()?;
    match Command::new(tool)
        .args(&args)
        .arg(src)
        .stdout(file)
        .status()
    {
        Ok(s) if s.success() => Some(dst),
        _ => {
            eprintln!("skipping {name}: '{tool}' is not available");
            None
        }
    }
}

fn load(path: &Path) -> (Mesh, ImportStats) {
    mesh::load(path).unwrap_or_else(|e| panic!("{e}"))
}

fn check(path: &Path, vertices: usize, triangles: usize) -> (Mesh, ImportStats) {
    let (m, s) = load(path);
    let name = path.display();
    assert_eq!(m.vertex_count(), vertices, "{name}");
    assert_eq!(m.triangle_count(), triangles, "{name}");
    assert_eq!(s.vertices as usize, vertices, "{name}");
    assert_eq!(s.triangles as usize, triangles, "{name}");
    assert!(m.indices.iter().all(|&i| (i as usize) < vertices));
    assert!(m.positions.iter().flatten().all(|c| c.is_finite()));
    for t in m.indices.chunks(3) {
        assert!(
            t[0] != t[1] && t[1] != t[2] && t[0] != t[2],
            "{name}: degenerate {t:?}"
        );
    }
    (m, s)
}

fn unreferenced(m: &Mesh) -> usize {
    let used: HashSet<u32> = m.indices.iter().copied().collect();
    m.vertex_count() - used.len()
}

fn import_err(path: &Path) -> ImportError {
    match mesh::load(path) {
        Ok((m, _)) => panic!(
            "{} imported ({} triangles) but should fail",
            path.display(),
            m.triangle_count()
        ),
        Err(e) => e,
    }
}

/// Binary little-endian PLY bytes from a header body and data.
fn ply_bin(header: &str, data: &[u8]) -> Vec<u8> {
    let mut v = format!("ply\nformat binary_little_endian 1.0\n{header}end_header\n").into_bytes();
    v.extend_from_slice(data);
    v
}

fn le(vals: &[f32]) -> Vec<u8> {
    vals.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// A GLB from a JSON document and a binary chunk.
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut js = json.as_bytes().to_vec();
    while !js.len().is_multiple_of(4) {
        js.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let total = 12 + 8 + js.len() + 8 + b.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(js.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x4E4F534Au32.to_le_bytes());
    out.extend_from_slice(&js);
    out.extend_from_slice(&(b.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x004E4942u32.to_le_bytes());
    out.extend_from_slice(&b);
    out
}

// ---------------------------------------------------------------------------------------
// real data

#[test]
fn real_ply_meshes() {
    let Some(d) = data_dir() else { return };
    let m = d.join("meshes");
    let (g, s) = check(&m.join("gargoyle_50k_vcolor.ply"), 25_002, 50_000);
    assert!(s.has_colors && s.has_normals);
    assert_eq!(g.colors.len(), g.positions.len());
    assert_eq!(g.normals.len(), g.positions.len());
    assert!(
        g.colors.iter().all(|c| c[0] == c[1] && c[1] == c[2]),
        "grey"
    );
    assert!(g.colors.iter().map(|c| c[0]).collect::<HashSet<_>>().len() > 200);
    check(&m.join("laurana_bust_50k_vcolor.ply"), 25_160, 50_000);
    check(&m.join("nefertiti_100k.ply"), 49_971, 99_938);
    check(&m.join("igea_269k.ply"), 134_345, 268_686);
    check(&m.join("stanford_armadillo_346k.ply"), 172_974, 345_944);
    let (_, s) = check(&m.join("stanford_dragon_vrip_871k.ply"), 437_645, 871_414);
    assert!(!s.has_colors && !s.has_normals);
}

#[test]
fn real_originals() {
    let Some(d) = data_dir() else { return };
    let o = d.join("originals");
    let m = d.join("meshes");
    let tmp = TempDir::new("orig");

    // Big-endian, uchar intensity before the index list, obj_info: same mesh as the LE copy.
    if let Some(p) = decompress(&o.join("Armadillo.ply.zst"), &tmp) {
        let (a, _) = check(&p, 172_974, 345_944);
        let (b, _) = load(&m.join("stanford_armadillo_346k.ply"));
        assert_eq!(a, b, "Armadillo big-endian vs little-endian copy");
    }
    // One tristrips element; expansion with parity flips equals the converted triangle list.
    if let Some(p) = decompress(&o.join("igea_tristrips.ply.zst"), &tmp) {
        let (a, _) = check(&p, 134_345, 268_686);
        let (b, _) = load(&m.join("igea_269k.ply"));
        assert_eq!(a, b, "igea strips vs triangles");
    }
    // Plain OBJ: same as the converted PLY (which rounded to float32).
    if let Some(p) = decompress(&o.join("nefertiti.obj.zst"), &tmp) {
        let (a, _) = check(&p, 49_971, 99_938);
        let (b, _) = load(&m.join("nefertiti_100k.ply"));
        assert_eq!(a.indices, b.indices);
        assert_eq!(a.positions, b.positions);
    }
    // ASCII with extra vertex properties and unreferenced vertices.
    if let Some(p) = decompress(&o.join("bun_zipper.ply.zst"), &tmp) {
        let (a, _) = check(&p, 35_947, 69_451);
        assert_eq!(unreferenced(&a), 1_113);
    }
    // Large ASCII: same as the binary conversion.
    if let Some(p) = decompress(&o.join("dragon_vrip.ply.gz"), &tmp) {
        let (a, _) = check(&p, 437_645, 871_414);
        let (b, _) = load(&m.join("stanford_dragon_vrip_871k.ply"));
        assert_eq!(a, b, "dragon ASCII vs binary");
    }
    for (name, v, t) in [
        ("dragon_vrip_res2.ply.gz", 100_250, 202_520),
        ("dragon_vrip_res3.ply.gz", 22_998, 47_794),
        ("dragon_vrip_res4.ply.gz", 5_205, 11_102),
    ] {
        if let Some(p) = decompress(&o.join(name), &tmp) {
            let (a, s) = check(&p, v, t);
            assert_eq!(s.degenerate_faces, 0);
            if name.contains("res2") {
                assert_eq!(unreferenced(&a), 43);
            }
        }
    }
}

#[test]
fn real_textured_gltf_is_welded_and_coloured() {
    let Some(d) = data_dir() else { return };
    let p = d.join("meshes/mask_bali_100k_textured_gltf/mask-gltf-2.0_separated-valid.gltf");
    let (m, s) = check(&p, 49_947, 100_000);
    assert!(s.has_colors && s.has_normals);
    assert_eq!(s.degenerate_faces, 0);
    // Colour sampled from the JPEG: many colours, not white.
    let distinct: HashSet<_> = m.colors.iter().collect();
    assert!(distinct.len() > 5_000, "{} colours", distinct.len());
    let mean: f64 = m.colors.iter().map(|c| c[0] as f64).sum::<f64>() / m.colors.len() as f64;
    assert!(mean > 20.0 && mean < 235.0, "mean red {mean}");
    // The sampling convention is right: where glTF splits a position at a UV seam, the texture
    // at the other copies' UVs shows the colour the welded vertex got (flipping v would not).
    let dir = p.parent().unwrap();
    let bin = std::fs::read(dir.join("mask-gltf-2.0_separated-valid.bin")).unwrap();
    let tex = image::open(dir.join("Image_0.jpg")).unwrap().into_rgb8();
    let f = |o: usize| f32::from_le_bytes(bin[o..o + 4].try_into().unwrap());
    let mut first = std::collections::HashMap::new();
    let (mut same, mut flipped, mut n) = (0.0, 0.0, 0.0);
    for i in 0..62_383 {
        let pos = [f(12 * i), f(12 * i + 4), f(12 * i + 8)].map(f32::to_bits);
        let next = first.len() as u32;
        let w = *first.entry(pos).or_insert(next);
        if w == next {
            continue; // first copy: its UV gave the colour
        }
        let (u, v) = (f(1_497_192 + 8 * i), f(1_497_192 + 8 * i + 4));
        let texel = |u: f32, v: f32| {
            let x = ((u * tex.width() as f32) as u32).min(tex.width() - 1);
            let y = ((v * tex.height() as f32) as u32).min(tex.height() - 1);
            tex.get_pixel(x, y).0
        };
        let diff = |t: [u8; 3]| -> f64 {
            (0..3)
                .map(|k| (t[k] as f64 - m.colors[w as usize][k] as f64).abs())
                .sum::<f64>()
                / 3.0
        };
        same += diff(texel(u, v));
        flipped += diff(texel(u, 1.0 - v));
        n += 1.0;
    }
    assert_eq!(first.len(), 49_947);
    let (same, flipped) = (same / n, flipped / n);
    assert!(
        same < 12.0 && flipped > 2.0 * same,
        "seam colour difference {same} vs {flipped} flipped"
    );
    // Welded: every edge shared by exactly two triangles (closed manifold).
    let mut edges = std::collections::HashMap::new();
    for t in m.indices.chunks(3) {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    assert!(edges.values().all(|&n| n == 2), "closed after welding");
}

#[test]
fn real_psb_off() {
    let Some(d) = data_dir() else { return };
    for (id, faces) in [(1, 9_408), (281, 50_542), (301, 18_500)] {
        let p = d.join(format!("psb/sample/off/{id}.off"));
        let text = std::fs::read_to_string(&p).unwrap();
        let counts: Vec<usize> = text
            .lines()
            .nth(1)
            .unwrap()
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        check(&p, counts[0], faces);
    }
}

// ---------------------------------------------------------------------------------------
// format variants

#[test]
fn ply_variants() {
    let t = TempDir::new("plyvar");
    // Faces before vertices, an unknown element with lists, double positions, ushort colour,
    // `vertex_index`, a quad, a degenerate triangle, an extra face property.
    let header = "element face 3\nproperty uchar flags\nproperty list ushort uint vertex_index\n\
                  element junk 2\nproperty list int double stuff\nproperty short s\n\
                  element vertex 4\nproperty double x\nproperty double y\nproperty double z\n\
                  property ushort red\nproperty ushort green\nproperty ushort blue\n";
    let mut data = Vec::new();
    for (flags, idx) in [
        (1u8, vec![0u32, 1, 2, 3]),
        (2, vec![0, 1, 1]),
        (3, vec![3, 2, 1]),
    ] {
        data.push(flags);
        data.extend_from_slice(&(idx.len() as u16).to_le_bytes());
        for i in idx {
            data.extend_from_slice(&i.to_le_bytes());
        }
    }
    for n in [1i32, 0] {
        data.extend_from_slice(&n.to_le_bytes());
        for _ in 0..n {
            data.extend_from_slice(&1.5f64.to_le_bytes());
        }
        data.extend_from_slice(&7i16.to_le_bytes());
    }
    for (i, p) in [
        [0.0f64, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.5],
    ]
    .iter()
    .enumerate()
    {
        for c in p {
            data.extend_from_slice(&c.to_le_bytes());
        }
        for c in [65535u16, 0, (i as u16) * 257] {
            data.extend_from_slice(&c.to_le_bytes());
        }
    }
    let p = t.file("var.ply", &ply_bin(header, &data));
    let (m, s) = load(&p);
    assert_eq!(m.positions[3], [0.0, 1.0, 0.5]);
    assert_eq!(m.colors[2], [255, 0, 2, 255]);
    assert_eq!(m.indices, vec![0, 1, 2, 0, 2, 3, 3, 2, 1]);
    assert_eq!((s.degenerate_faces, s.polygons_triangulated), (1, 1));

    // The same as ASCII (faces first too), with float colours and normals.
    let ascii = "ply\nformat ascii 1.0\ncomment c\nobj_info o\nelement face 3\n\
                 property uchar flags\nproperty list uchar int vertex_indices\n\
                 element vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
                 property float nx\nproperty float ny\nproperty float nz\n\
                 property float red\nproperty float green\nproperty float blue\nproperty float alpha\n\
                 end_header\n\
                 1 4 0 1 2 3\n2 3 0 1 1\n3 3 3 2 1\n\n\
                 0 0 0 0 0 1 1 0 0 1\n1 0 0 0 0 1 0 1 0 1\n1 1 0 0 0 1 0 0 1 0.5\n0 1 0.5 0 0 1 1 1 1 1\n";
    let p = t.file("var_ascii.ply", ascii.as_bytes());
    let (a, s) = load(&p);
    assert_eq!(a.indices, m.indices);
    assert_eq!(a.colors[2], [0, 0, 255, 128]);
    assert_eq!(a.normals[0], [0.0, 0.0, 1.0]);
    assert!(s.has_normals && s.has_colors);

    // Big-endian tristrips with a restart.
    let mut data = Vec::new();
    for p in [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [2.0, 0.0, 0.0],
    ] {
        for c in p {
            data.extend_from_slice(&c.to_be_bytes());
        }
    }
    let strip = [0i32, 1, 2, 3, -1, 1, 4, 3];
    data.extend_from_slice(&(strip.len() as i32).to_be_bytes());
    for i in strip {
        data.extend_from_slice(&i.to_be_bytes());
    }
    let mut bytes = b"ply\nformat binary_big_endian 1.0\nelement vertex 5\nproperty float x\n\
                      property float y\nproperty float z\nelement tristrips 1\n\
                      property list int int vertex_indices\nend_header\n"
        .to_vec();
    bytes.extend_from_slice(&data);
    let p = t.file("strip.ply", &bytes);
    let (m, _) = load(&p);
    assert_eq!(m.indices, vec![0, 1, 2, 2, 1, 3, 1, 4, 3]);
    // The same strip in ASCII, with `uint` indices (restart = 4294967295).
    let ascii = "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n\
                 property float z\nelement tristrips 1\nproperty list int uint vertex_indices\n\
                 end_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n2 0 0\n8 0 1 2 3 4294967295 1 4 3\n";
    let (a, _) = load(&t.file("strip_ascii.ply", ascii.as_bytes()));
    assert_eq!(a, m);

    // Binary vertices with a list property between the coordinates, uchar RGB after it.
    let header = "element vertex 3\nproperty float x\nproperty list uchar float junk\n\
                  property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n\
                  property uchar blue\nelement face 1\nproperty list uchar int vertex_indices\n";
    let mut data = Vec::new();
    for k in 0..3u8 {
        data.extend_from_slice(&le(&[k as f32]));
        data.push(k);
        data.extend_from_slice(&le(&vec![9.0; k as usize]));
        data.extend_from_slice(&le(&[1.0, 2.0]));
        data.extend_from_slice(&[k, 2 * k, 3 * k]);
    }
    data.push(3);
    for i in [0i32, 1, 2] {
        data.extend_from_slice(&i.to_le_bytes());
    }
    let (m, _) = load(&t.file("vlist.ply", &ply_bin(header, &data)));
    assert_eq!(
        m.positions,
        vec![[0.0, 1.0, 2.0], [1.0, 1.0, 2.0], [2.0, 1.0, 2.0]]
    );
    assert_eq!(m.colors[2], [2, 4, 6, 255]);
}

#[test]
fn obj_variants_and_texture() {
    let t = TempDir::new("obj");
    // 2x1 texture: left red, right blue.
    let img = image::RgbaImage::from_fn(2, 1, |x, _| {
        if x == 0 {
            image::Rgba([255, 0, 0, 255])
        } else {
            image::Rgba([0, 0, 255, 255])
        }
    });
    img.save(t.0.join("tex.png")).unwrap();
    t.file(
        "m.mtl",
        b"newmtl red\nKd 1 0 0\nmap_Kd -s 1 1 1 tex.png\nnewmtl plain\nKd 0 1 0\n",
    );
    let obj = "# test\nmtllib m.mtl\n\
               v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0 0.5 0.5 0.5\n\
               vt 0.25 0.5\nvt 0.75 0.5\nvn 0 0 1\n\
               usemtl red\nf 1/1/1 2/2/1 3/2/1 4/1/1\n\
               usemtl plain\nf -4//1 -1//1 -3//1\nf 1 1 2\n";
    let p = t.file("t.obj", obj.as_bytes());
    let (m, s) = load(&p);
    assert_eq!(m.vertex_count(), 5);
    assert_eq!(m.indices, vec![0, 1, 2, 0, 2, 3, 1, 4, 2]);
    assert_eq!((s.degenerate_faces, s.polygons_triangulated), (1, 1));
    assert!(s.has_colors && s.has_normals);
    assert_eq!(
        m.colors[0],
        [255, 0, 0, 255],
        "texel centre of the red half"
    );
    assert_eq!(m.colors[1], [0, 0, 255, 255]);
    assert_eq!(m.colors[4], [128, 128, 128, 255], "v-line colour");
    assert_eq!(m.normals[0], [0.0, 0.0, 1.0]);
    // A missing texture is not fatal; `v` colours in 0..255 are recognised.
    let p = t.file(
        "c.obj",
        b"mtllib nothere.mtl\nv 0 0 0 255 0 0\nv 1 0 0 0 255 0\nv 0 1 0 0 0 255\nf 1 2 3\n",
    );
    let (m, _) = load(&p);
    assert_eq!(
        m.colors,
        vec![[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]]
    );
}

#[test]
fn stl_variants_weld() {
    let t = TempDir::new("stl");
    // A tetrahedron, binary with a header that starts with "solid".
    let v = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let tris = [[0usize, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let mut bin = b"solid binary file header".to_vec();
    bin.resize(80, b' ');
    bin.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    let mut ascii = String::from("solid tet\n");
    for t in tris {
        bin.extend_from_slice(&le(&[0.0, 0.0, 0.0]));
        ascii += "facet normal 0 0 0\n outer loop\n";
        for i in t {
            bin.extend_from_slice(&le(&v[i]));
            ascii += &format!("  vertex {} {} {}\n", v[i][0], v[i][1], v[i][2]);
        }
        bin.extend_from_slice(&[0, 0]);
        ascii += " endloop\nendfacet\n";
    }
    ascii += "endsolid tet\n";
    let (a, _) = check(&t.file("b.stl", &bin), 4, 4);
    let (b, _) = check(&t.file("a.stl", ascii.as_bytes()), 4, 4);
    assert_eq!(a, b);
    assert_eq!(
        a.positions,
        vec![v[0], v[2], v[1], v[3]],
        "order of first appearance"
    );
}

fn gltf_json(extra_nodes: &str, mode: u32, index_count: usize) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
        "nodes":[{{"children":[1]{extra_nodes}}},{{"mesh":0,"translation":[10,0,0]}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"COLOR_0":1}},"indices":2,"mode":{mode},"material":0}}]}}],
        "materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":[1,1,1,1]}}}}],
        "buffers":[{{"byteLength":76}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":16}},{{"buffer":0,"byteOffset":64,"byteLength":12}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3"}},
                     {{"bufferView":1,"componentType":5121,"normalized":true,"count":4,"type":"VEC4"}},
                     {{"bufferView":2,"componentType":5123,"count":{index_count},"type":"SCALAR"}}]}}"#
    )
}

fn gltf_bin(indices: &[u16]) -> Vec<u8> {
    let mut bin = le(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0]);
    bin.extend_from_slice(&[
        255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 255, 255, 255, 255,
    ]);
    for i in indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    bin.resize(76, 0);
    bin
}

#[test]
fn gltf_variants() {
    let t = TempDir::new("gltf");
    // GLB, triangle strip, parent scale 2 and translation applied, COLOR_0 u8.
    let json = gltf_json(r#","scale":[2,2,2]"#, 5, 4);
    let p = t.file("s.glb", &glb(&json, &gltf_bin(&[0, 1, 2, 3])));
    let (m, s) = check(&p, 4, 2);
    assert!(s.has_colors);
    assert_eq!(m.positions[1], [22.0, 0.0, 0.0]);
    assert_eq!(m.indices, vec![0, 1, 2, 1, 3, 2]);
    assert_eq!(m.colors[0], [255, 0, 0, 255]);
    // Mirroring transform flips the winding; a .gltf with a base64 data URI buffer.
    let json = gltf_json(r#","scale":[-1,1,1]"#, 4, 6);
    let data = gltf_bin(&[0, 1, 2, 2, 1, 3]);
    let b64 = base64(&data);
    let json = json.replace(
        r#""buffers":[{"byteLength":76}]"#,
        &format!(
            r#""buffers":[{{"byteLength":76,"uri":"data:application/octet-stream;base64,{b64}"}}]"#
        ),
    );
    let p = t.file("m.gltf", json.as_bytes());
    let (m, _) = check(&p, 4, 2);
    assert_eq!(m.positions[1], [-11.0, 0.0, 0.0]);
    assert_eq!(m.indices, vec![0, 2, 1, 2, 3, 1]);
}

fn base64(b: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in b.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

#[test]
fn off_variants() {
    let t = TempDir::new("off");
    let p = t.file(
        "c.off",
        b"COFF\n# comment\n4 2 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n1 1 0 0 0 255 255\n0 1 0 1 1 1 1\n\
          4 0 1 2 3 0.5 0.5 0.5\n3 0 0 1\n",
    );
    let (m, s) = load(&p);
    assert_eq!(m.indices, vec![0, 1, 2, 0, 2, 3]);
    assert_eq!(m.colors[1], [0, 255, 0, 255]);
    assert_eq!((s.degenerate_faces, s.polygons_triangulated), (1, 1));
}

// ---------------------------------------------------------------------------------------
// broken files: each must fail with a message naming the file, the place and the problem

const PLY_HDR: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                       property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";

fn tri_bin(idx: [i32; 3], verts: usize) -> Vec<u8> {
    let mut d = le(&vec![0.5; 3 * verts]);
    d.push(3);
    for i in idx {
        d.extend_from_slice(&i.to_le_bytes());
    }
    d
}

const BIN_HDR: &str = "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                       element face 1\nproperty list uchar int vertex_indices\n";

#[test]
fn broken_corpus() {
    let t = TempDir::new("broken");
    let nan_bin = {
        let mut d = tri_bin([0, 1, 2], 3);
        d[16..20].copy_from_slice(&f32::NAN.to_le_bytes());
        d
    };
    let mut stl_nan = vec![b' '; 80];
    stl_nan.extend_from_slice(&1u32.to_le_bytes());
    stl_nan.extend_from_slice(&le(&[
        0.0,
        0.0,
        0.0,
        f32::INFINITY,
        0.0,
        0.0,
        1.0,
        0.0,
        0.0,
        0.0,
        1.0,
        0.0,
    ]));
    stl_nan.extend_from_slice(&[0, 0]);
    let mut stl_short = stl_nan.clone();
    stl_short.truncate(100);
    let glb_ok = glb(&gltf_json("", 4, 3), &gltf_bin(&[0, 1, 2]));
    let mut glb_trunc = glb_ok.clone();
    glb_trunc.truncate(glb_ok.len() - 40);
    let glb_badidx = glb(&gltf_json("", 4, 3), &gltf_bin(&[0, 1, 9]));
    let glb_overrun = glb(
        &gltf_json("", 4, 3).replace(r#""count":4,"type":"VEC3""#, r#""count":400,"type":"VEC3""#),
        &gltf_bin(&[0, 1, 2]),
    );
    let glb_nan = {
        let mut b = gltf_bin(&[0, 1, 2]);
        b[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
        glb(&gltf_json("", 4, 3), &b)
    };

    let cases: Vec<(&str, Vec<u8>, Location, &[&str])> = vec![
        // PLY
        ("garbage.ply", b"\x7fELF\x02\x01\x01 garbage".to_vec(), Location::Line(1), &["not a PLY file"]),
        ("noend.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n".to_vec(), Location::Line(3), &["end_header"]),
        ("badtype.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty int128 x\nend_header\n".to_vec(), Location::Line(4), &["unsupported", "int128"]),
        ("badformat.ply", b"ply\nformat binary_middle_endian 1.0\nend_header\n".to_vec(), Location::Line(2), &["binary_middle_endian"]),
        ("huge.ply", ply_bin("element vertex 1000000000000\nproperty float x\nproperty float y\nproperty float z\n", &[0; 64]), Location::Line(3), &["1000000000000", "truncated"]),
        ("trunc_bin.ply", { let mut d = ply_bin(BIN_HDR, &tri_bin([0, 1, 2], 3)); d.truncate(d.len() - 5); d }, Location::Byte(205), &["truncated", "'face' 0 of 1"]),
        ("trunc_face.ply", ply_bin("element vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\n", &{ let mut d = tri_bin([0, 1, 2], 3); d.extend_from_slice(&[3, 0, 0]); d }), Location::Byte(218), &["truncated", "'face' 1 of 2"]),
        ("extra.ply", { let mut d = ply_bin(BIN_HDR, &tri_bin([0, 1, 2], 3)); d.extend_from_slice(&[1, 2, 3, 4]); d }, Location::Byte(218), &["4 bytes after the last element"]),
        ("nan_bin.ply", ply_bin(BIN_HDR, &nan_bin), Location::Byte(181), &["NaN", "vertex 1"]),
        ("index_bin.ply", ply_bin(BIN_HDR, &tri_bin([0, 1, 7], 3)), Location::Byte(205), &["index 7", "only 3 vertices", "face 0"]),
        ("negidx_bin.ply", ply_bin(BIN_HDR, &tri_bin([0, -5, 1], 3)), Location::Byte(205), &["index -5"]),
        ("nan.ply", format!("{PLY_HDR}0 0 0\nnan 1 0\n0 1 0\n3 0 1 2\n").into_bytes(), Location::Line(11), &["NaN", "vertex 1"]),
        ("inf.ply", format!("{PLY_HDR}0 0 0\n1 1e39 0\n0 1 0\n3 0 1 2\n").into_bytes(), Location::Line(11), &["inf", "vertex 1"]),
        ("index.ply", format!("{PLY_HDR}0 0 0\n1 0 0\n0 1 0\n3 0 1 99\n").into_bytes(), Location::Line(13), &["index 99", "face 0"]),
        ("fewvals.ply", format!("{PLY_HDR}0 0 0\n1 0\n0 1 0\n3 0 1 2\n").into_bytes(), Location::Line(11), &["too few"]),
        ("word.ply", format!("{PLY_HDR}0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n").into_bytes(), Location::Line(11), &["'zero'", "'y'"]),
        ("short.ply", format!("{PLY_HDR}0 0 0\n1 0 0\n").into_bytes(), Location::Line(3), &["truncated", "3 'vertex' elements"]),
        ("eof.ply", format!("{PLY_HDR}0.000000 0.000000 0.000000\n1.000000 0.000000 0.000000\n0.000000 1.000000 0.000000\n").into_bytes(), Location::Line(13), &["truncated", "after 0 of 1 'face'"]),
        ("wrongcount.ply", format!("{PLY_HDR}0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 2 1\n").into_bytes(), Location::Line(14), &["after the last element"]),
        // Cut off inside the header: the cause, not the half word ("property type 'flo'").
        ("cut_header.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty flo".to_vec(), Location::Line(4), &["truncated", "ends inside its header"]),
        ("cut_header2.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty ".to_vec(), Location::Line(4), &["truncated", "ends inside its header"]),
        // A vertex count smaller than the vertex data: named as such.
        ("fewverts.ply", format!("{}0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1.0 0.0\n3 0 1 2\n", PLY_HDR.replace("vertex 3", "vertex 2")).into_bytes(), Location::Line(12), &["vertex data", "vertex count (2, line 3)"]),
        ("fewverts_bin.ply", ply_bin(&BIN_HDR.replace("vertex 3", "vertex 1"), &{ let mut d = tri_bin([0, 1, 2], 3); d.truncate(12); d.extend_from_slice(&[3, 0, 0, 0, 0, 0, 0, 0, 0, 2, 0, 0, 0]); d }), Location::Byte(181), &["index 2", "declares only 1 vertices", "smaller than the vertex data"]),
        ("novertex.ply", b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n".to_vec(), Location::Line(5), &["no 'vertex' element"]),
        ("empty.ply", Vec::new(), Location::File, &["empty"]),
        ("points.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n".to_vec(), Location::File, &["no triangles"]),
        // OBJ
        ("nan.obj", b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n".to_vec(), Location::Line(3), &["NaN", "vertex 2"]),
        ("index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n".to_vec(), Location::Line(5), &["index 4", "only 3 vertices", "face 1"]),
        ("rel.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n".to_vec(), Location::Line(4), &["index -4"]),
        ("zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n".to_vec(), Location::Line(4), &["index 0"]),
        ("word.obj", b"v 0 0 0\nv 1 x 0\n".to_vec(), Location::Line(2), &["'x' is not a number"]),
        ("short.obj", b"v 0 0 0\nv 1 0\n".to_vec(), Location::Line(2), &["2 coordinates"]),
        ("corner.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/a 2 3\n".to_vec(), Location::Line(4), &["texture coordinate index 'a'"]),
        ("binary.obj", vec![0u8, 159, 146, 150, 10, 200, 201], Location::File, &["no triangles"]),
        // STL
        ("trunc.stl", stl_short, Location::Byte(80), &["declares 1 triangles", "134"]),
        ("nan.stl", stl_nan, Location::Byte(96), &["inf", "vertex 0"]),
        ("tiny.stl", b"hello".to_vec(), Location::File, &["not an STL file"]),
        ("ascii_bad.stl", b"solid x\nfacet normal 0 0 0\nouter loop\nvertex 0 0 zz\n".to_vec(), Location::Line(4), &["'zz'"]),
        ("ascii_trunc.stl", b"solid x\nfacet normal 0 0 0\nouter loop\nvertex 0 0 0\n".to_vec(), Location::Line(4), &["truncated", "inside a facet"]),
        ("ascii_nan.stl", b"solid x\nfacet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex NaN 0 0\n".to_vec(), Location::Line(5), &["NaN", "vertex 1"]),
        // OFF
        ("garbage.off", b"PLY\n3 1 0\n".to_vec(), Location::Line(1), &["not an OFF file"]),
        ("huge.off", b"OFF\n99999999999 1 0\n0 0 0\n".to_vec(), Location::Line(2), &["99999999999", "truncated"]),
        ("index.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n".to_vec(), Location::Line(6), &["index 3", "only 3 vertices", "face 0"]),
        ("nan.off", b"OFF\n3 1 0\n0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n".to_vec(), Location::Line(4), &["inf", "vertex 1"]),
        ("trunc.off", b"OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n".to_vec(), Location::Line(7), &["truncated", "1 of 2 faces"]),
        ("extra.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 2 1\n".to_vec(), Location::Line(7), &["after the last of 1 faces"]),
        ("binary.off", b"OFF BINARY\n".to_vec(), Location::Line(1), &["binary OFF"]),
        // glTF
        ("syntax.gltf", b"{\"asset\": {\"version\": \"2.0\"},\n  \"nodes\": [ oops ]}".to_vec(), Location::Line(2), &["invalid glTF JSON"]),
        ("invalid.gltf", br#"{"asset":{"version":"2.0"},"scenes":[{"nodes":[5]}]}"#.to_vec(), Location::File, &["invalid glTF"]),
        ("escape.gltf", br#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":4,"uri":"../../etc/passwd"}]}"#.to_vec(), Location::File, &["outside the glTF's directory"]),
        ("missing.gltf", br#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":4,"uri":"nothere.bin"}]}"#.to_vec(), Location::File, &["nothere.bin"]),
        ("trunc.glb", glb_trunc, Location::Byte(8), &["truncated", "GLB header declares"]),
        ("index.glb", glb_badidx, Location::File, &["index 9", "only 4 vertices"]),
        ("overrun.glb", glb_overrun, Location::File, &["accessor 0 needs 400 elements"]),
        ("nan.glb", glb_nan, Location::File, &["NaN", "vertex 0"]),
        ("version.glb", { let mut g = glb_ok.clone(); g[4] = 1; g }, Location::Byte(4), &["GLB version 1"]),
        ("unknown.xyz", b"1 2 3".to_vec(), Location::File, &["unknown file extension"]),
    ];
    let mut failures = Vec::new();
    for (name, bytes, location, needles) in &cases {
        let p = t.file(name, bytes);
        let e = import_err(&p);
        let msg = e.to_string();
        let ok = msg.starts_with(&format!("{name}: "))
            && e.location == *location
            && needles
                .iter()
                .all(|n| msg.to_lowercase().contains(&n.to_lowercase()));
        if !ok {
            failures.push(format!(
                "{name}: got {:?} / \"{msg}\", want {location:?} and {needles:?}",
                e.location
            ));
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

#[test]
fn cancellation_stops_the_import() {
    let t = TempDir::new("cancel");
    let p = t.file("c.ply", &ply_bin(BIN_HDR, &tri_bin([0, 1, 2], 3)));
    let progress = CountingProgress::default();
    progress.cancel.store(true, Ordering::Relaxed);
    let e = mesh::import(&p, &mut Mesh::default(), &progress).unwrap_err();
    assert_eq!(e.kind, ImportErrorKind::Cancelled);
    // Progress is reported in bytes of the file.
    let progress = CountingProgress::default();
    mesh::import(&p, &mut Mesh::default(), &progress).unwrap();
    assert_eq!(
        progress.done.load(Ordering::Relaxed),
        std::fs::metadata(&p).unwrap().len()
    );
}

// ---------------------------------------------------------------------------------------
// fuzz: random mutations of small valid files never panic

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn mutate(rng: &mut Rng, src: &[u8]) -> Vec<u8> {
    let mut v = src.to_vec();
    for _ in 0..1 + rng.below(4) {
        let i = rng.below(v.len());
        match rng.below(7) {
            0 => v.truncate(i),
            1 if !v.is_empty() => v[i] = rng.next() as u8,
            2 if !v.is_empty() => v[i] ^= 1 << rng.below(8),
            3 => v.insert(i.min(v.len()), rng.next() as u8),
            4 if !v.is_empty() => {
                v.remove(i);
            }
            5 if !v.is_empty() => v[i] = b"0123456789-. \n/eE+#"[rng.below(19)],
            _ => {
                // Overwrite four bytes with an extreme value.
                let x = [u32::MAX, 0x7fff_ffff, 0x8000_0000, 0x7fc0_0000, 1 << 30][rng.below(5)];
                for (k, b) in x.to_le_bytes().into_iter().enumerate() {
                    if let Some(s) = v.get_mut(i + k) {
                        *s = b;
                    }
                }
            }
        }
    }
    v
}

#[test]
fn fuzz_mutations_never_panic() {
    let t = TempDir::new("fuzz");
    let tex = image::RgbaImage::from_pixel(2, 2, image::Rgba([10, 20, 30, 255]));
    tex.save(t.0.join("tex.png")).unwrap();
    t.file("m.mtl", b"newmtl a\nKd 1 0 0\nmap_Kd tex.png\n");
    let mut ascii_ply = PLY_HDR
        .replace("element face 1", "element face 2")
        .into_bytes();
    ascii_ply.extend_from_slice(b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n4 0 1 2 0\n");
    let mut big_ply = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\n\
        property double y\nproperty double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
        element face 1\nproperty uchar i\nproperty list uchar short vertex_indices\nend_header\n"
        .to_vec();
    for k in 0..3 {
        for c in [k as f64, 0.5, 1.0] {
            big_ply.extend_from_slice(&c.to_be_bytes());
        }
        big_ply.extend_from_slice(&[1, 2, 3]);
    }
    big_ply.extend_from_slice(&[9, 3, 0, 0, 0, 1, 0, 2]);
    let mut stl = vec![b's'; 80];
    stl.extend_from_slice(&1u32.to_le_bytes());
    stl.extend_from_slice(&le(&[
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0,
    ]));
    stl.extend_from_slice(&[0, 0]);
    let seeds: Vec<(&str, Vec<u8>)> = vec![
        ("a.ply", ascii_ply),
        ("b.ply", ply_bin(BIN_HDR, &tri_bin([0, 1, 2], 3))),
        ("c.ply", big_ply),
        ("d.obj", b"mtllib m.mtl\nv 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 1\nvn 0 0 1\nusemtl a\nf 1/1/1 2/2/1 3//1\nf -1 -2 -3 1\n".to_vec()),
        ("e.stl", stl),
        ("f.stl", b"solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid s\n".to_vec()),
        ("g.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2 255 0 0\n".to_vec()),
        ("h.glb", glb(&gltf_json(r#","rotation":[0,0,0.7071,0.7071]"#, 4, 3), &gltf_bin(&[0, 1, 2]))),
        ("i.gltf", gltf_json("", 5, 4).replace(r#""byteLength":76}]"#, &format!(r#""byteLength":76,"uri":"data:application/octet-stream;base64,{}"}}]"#, base64(&gltf_bin(&[0, 1, 2, 3])))).into_bytes()),
    ];
    // MESHWIKI_FUZZ_ITERS=20000 for a longer run; MESHWIKI_FUZZ_SEED to vary it.
    let iterations: usize = std::env::var("MESHWIKI_FUZZ_ITERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(300);
    let seed: u64 = std::env::var("MESHWIKI_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x9E37_79B9_7F4A_7C15);
    let mut rng = Rng(seed | 1);
    let mut oks = 0;
    for (name, seed) in &seeds {
        load(&t.file(name, seed)); // the seeds themselves are valid
        for k in 0..iterations {
            let bytes = mutate(&mut rng, seed);
            let p = t.file(name, &bytes);
            let r = std::panic::catch_unwind(|| mesh::load(&p));
            match r {
                Ok(Ok(_)) => oks += 1,
                Ok(Err(e)) => assert!(e.to_string().starts_with(name), "{e}"),
                Err(_) => {
                    let keep = std::env::temp_dir().join(format!("meshwiki-fuzz-panic-{k}-{name}"));
                    std::fs::write(&keep, &bytes).unwrap();
                    panic!(
                        "{name}: panic on mutation {k}, input saved to {}",
                        keep.display()
                    );
                }
            }
        }
    }
    assert!(oks > 0);
}

// ---------------------------------------------------------------------------------------
// writer and synth

#[test]
fn synth_write_import_roundtrip() {
    let t = TempDir::new("synth");
    let relief = Relief::new(60_000, 3);
    let mut a = Mesh::default();
    relief.stream(&mut a).unwrap();
    assert_eq!(a.triangle_count() as u64, relief.triangle_count());
    assert_eq!(a.vertex_count() as u64, relief.vertex_count());
    let p = t.0.join("r.ply");
    write_ply(&p, &a.positions, Some(&a.colors), None, &a.indices, None).unwrap();
    let (b, _) = load(&p);
    assert_eq!(a, b);
    // The streamed PLY writer gives the same file content.
    let q = t.0.join("r2.ply");
    relief.write_ply(&q).unwrap();
    let (c, _) = load(&q);
    assert_eq!(a, c);
    // Only the final files remain: temporaries were renamed.
    let names: Vec<_> = std::fs::read_dir(&t.0)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");

    // Normals, alpha and an extra property.
    let ids: Vec<u32> = (0..a.vertex_count() as u32).map(|i| i * 7).collect();
    let mut colors = a.colors.clone();
    colors[5][3] = 9;
    let normals: Vec<[f32; 3]> = a.positions.iter().map(|p| [p[2], p[1], 1.0]).collect();
    write_ply(
        &p,
        &a.positions,
        Some(&colors),
        Some(&normals),
        &a.indices,
        Some(("original_id", &ids)),
    )
    .unwrap();
    let (d, s) = load(&p);
    assert!(s.has_normals);
    assert_eq!(
        (d.colors, d.normals, d.indices),
        (colors, normals, a.indices.clone())
    );
    let head = std::fs::read(&p).unwrap();
    assert!(String::from_utf8_lossy(&head[..400]).contains("property uint original_id"));
    // Bad input to the writer leaves nothing behind.
    assert!(
        write_ply(
            &t.0.join("bad.ply"),
            &a.positions,
            None,
            None,
            &[0, 1, 999_999],
            None
        )
        .is_err()
    );
    assert!(!t.0.join("bad.ply").exists());
    assert_eq!(std::fs::read_dir(&t.0).unwrap().count(), 2);
}

#[test]
fn streaming_import_progress_and_sink() {
    // A sink that only counts: the importer never needs the mesh in memory.
    struct Count(u64, u64);
    impl mesh::MeshSink for Count {
        fn begin(&mut self, _: &mesh::SourceInfo) -> Result<(), ImportError> {
            Ok(())
        }
        fn vertices(&mut self, b: mesh::VertexBatch<'_>) -> Result<(), ImportError> {
            assert!(b.positions.len() <= 1 << 16);
            self.0 += b.positions.len() as u64;
            Ok(())
        }
        fn triangles(&mut self, t: &[[u32; 3]]) -> Result<(), ImportError> {
            assert!(
                t.iter().flatten().all(|&i| (i as u64) < self.0),
                "vertices first"
            );
            self.1 += t.len() as u64;
            Ok(())
        }
    }
    let t = TempDir::new("stream");
    let p = t.0.join("r.ply");
    let (nv, nt) = mesh::write_relief_ply(&p, 300_000).unwrap();
    let mut c = Count(0, 0);
    let s = mesh::import(&p, &mut c, &NoProgress).unwrap();
    assert_eq!((c.0, c.1), (nv, nt));
    assert_eq!((s.vertices, s.triangles), (nv, nt));
}
