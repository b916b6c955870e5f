//! Textured scans at every level (issue 11): importers hand over textures and per-corner
//! texture coordinates; the build gives every patch its own atlas; the renderer draws it.
//! On the Bali mask (`../shared/data`), a 1 px render of a close-up is compared with a
//! reference rasterised here from the source glTF (its own texture, full resolution), next to
//! the vertex-colour build of the same scan.
//!
//! Without a Vulkan adapter the render checks print a message and pass.

mod common;

use common::psnr;
use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::{self, BuildOptions, LodFile};
use meshwiki_engine::mesh::{self, MeshSink, NO_TEXTURE, TexturedMesh, encode_rgba};
use meshwiki_engine::progress::NoProgress;
use meshwiki_engine::render::{
    AdapterChoice, Cut, GpuDevice, Outputs, RenderModel, RenderOptions, Renderer, RendererOptions,
};
use std::path::{Path, PathBuf};

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mw-texture-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// A 4×4 grid OBJ in the unit square with a 64×64 gradient texture mapped onto it (red
/// along x, green down the rows, so a flipped or swapped coordinate shows).
fn write_textured_obj(dir: &Path) -> PathBuf {
    let mut img = image::RgbaImage::new(64, 64);
    for (x, y, p) in img.enumerate_pixels_mut() {
        *p = image::Rgba([(x * 4) as u8, (y * 4) as u8, 128, 255]);
    }
    img.save(dir.join("checker.png")).expect("png");
    std::fs::write(
        dir.join("grid.mtl"),
        "newmtl checker\nKd 1 1 1\nmap_Kd checker.png\n",
    )
    .expect("mtl");
    let mut obj = String::from("mtllib grid.mtl\n");
    let n = 4;
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
            obj += &format!("v {x} {y} 0\nvt {x} {y}\n");
        }
    }
    obj += "usemtl checker\n";
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i + 1;
            let (b, c, d) = (a + 1, a + n + 2, a + n + 1);
            obj += &format!("f {a}/{a} {b}/{b} {c}/{c} {d}/{d}\n");
        }
    }
    let path = dir.join("grid.obj");
    std::fs::write(&path, obj).expect("obj");
    path
}

#[test]
fn obj_textures_reach_the_sink_and_every_patch_gets_an_atlas() {
    let dir = temp_dir("obj");
    let path = write_textured_obj(&dir);
    let mut sink = TexturedMesh::default();
    let stats = mesh::import(&path, &mut sink, &NoProgress).expect("import");
    assert_eq!(stats.textures, 1);
    assert_eq!(sink.textures.len(), 1);
    assert_eq!(sink.faces.len(), sink.mesh.triangle_count());
    assert_eq!(sink.mesh.triangle_count(), 32);
    // OBJ's v = 0 is the bottom row: handed over in the glTF convention (1 - v).
    for (t, f) in sink.mesh.indices.chunks_exact(3).zip(&sink.faces) {
        assert_eq!(f.texture, 0);
        for (&v, uv) in t.iter().zip(&f.uv) {
            let p = sink.mesh.positions[v as usize];
            assert!((uv[0] - p[0]).abs() < 1e-6);
            assert!((uv[1] - (1.0 - p[1])).abs() < 1e-6);
        }
    }

    let out = dir.join("grid.mwlod");
    let options = BuildOptions {
        max_patch_triangles: 16,
        memory_budget: 128 << 20,
        threads: Some(2),
        ..Default::default()
    };
    lod::build_file(&path, &out, &options, &NoProgress).expect("build");
    let lod = LodFile::open(&out).expect("open");
    assert!(lod.has_texture());
    for node in 0..lod.nodes().len() as u32 {
        let p = lod.patch(node).expect("decodes");
        let img = p.image.as_deref().expect("every patch has an atlas");
        let atlas = mesh::Texture::decode(img).expect("the atlas is an image");
        assert_eq!(p.uvs.len(), p.positions.len());
        // At every triangle's centroid the atlas has the texture's colour at that point (the
        // grid is flat, so every level lies on the same square).
        for t in p.indices.chunks_exact(3) {
            let c = t
                .iter()
                .map(|&v| Vec3::from(p.positions[v as usize]))
                .sum::<Vec3>()
                / 3.0;
            let uv = t
                .iter()
                .map(|&v| glam::Vec2::from(p.uvs[v as usize]))
                .sum::<glam::Vec2>()
                / 3.0;
            let got = encode_rgba(atlas.sample(uv.x, uv.y, mesh::Wrap::Clamp, mesh::Wrap::Clamp));
            let want = encode_rgba(sink.textures[0].sample([c.x, 1.0 - c.y]));
            for k in 0..3 {
                assert!(
                    (got[k] as i32 - want[k] as i32).abs() <= 12,
                    "node {node} at {c:?}: atlas {got:?}, texture {want:?}"
                );
            }
        }
    }
}

/// Fragment quality by feature density (issue 11, item 3): on the generated textured relief,
/// the same fragments are featured or plain in every build; with a spread, the featured ones
/// get higher JPEG quality (closer to their raw atlases) and the plain ones cost fewer bytes
/// than at uniform quality; every patch still decodes with a valid atlas.
#[test]
fn fragment_quality_follows_feature_density() {
    let dir = temp_dir("fragments");
    let relief = mesh::Relief::new(60_000, mesh::synth::DEFAULT_SEED);
    let build = |spread: u8| {
        let out = dir.join(format!("relief-{spread}.mwlod"));
        let options = BuildOptions {
            max_patch_triangles: 2048,
            memory_budget: 128 << 20,
            threads: Some(2),
            texture_quality: 70,
            texture_spread: spread,
            measure_textures: true,
            ..Default::default()
        };
        let report = lod::build_from(
            |sink: &mut dyn MeshSink| {
                relief.stream_textured(769, sink)?;
                Ok(relief.stats(true))
            },
            &out,
            &options,
            &NoProgress,
        )
        .expect("build");
        (
            out,
            report
                .textures
                .expect("a textured build reports its atlases"),
        )
    };
    let (_, uniform) = build(0);
    let (out, by_features) = build(30);
    assert_eq!(uniform.quality, (70, 70.0, 70));
    let (lo, mean, hi) = by_features.quality;
    assert!(
        lo < 70 && hi > 70 && (mean - 70.0).abs() < 3.0,
        "{:?}",
        by_features.quality
    );
    for (u, f) in [
        (uniform.featured, by_features.featured),
        (uniform.plain, by_features.plain),
    ] {
        assert_eq!(u.fragments, f.fragments);
        assert_eq!(u.covered_texels, f.covered_texels);
        assert!(u.fragments > 0 && u.samples == 3 * u.covered_texels);
    }
    let (uf, ff) = (uniform.featured, by_features.featured);
    let (up, fp) = (uniform.plain, by_features.plain);
    assert!(
        ff.psnr() > uf.psnr() + 0.2,
        "featured: {:.2} vs {:.2} dB",
        ff.psnr(),
        uf.psnr()
    );
    assert!(ff.image_bytes > uf.image_bytes);
    assert!(
        fp.psnr() < up.psnr(),
        "plain: {:.2} vs {:.2} dB",
        fp.psnr(),
        up.psnr()
    );
    assert!(fp.image_bytes < up.image_bytes);
    eprintln!(
        "featured fragments {:.2} -> {:.2} dB, plain {:.2} -> {:.2} dB; bytes {} -> {}",
        uf.psnr(),
        ff.psnr(),
        up.psnr(),
        fp.psnr(),
        uf.image_bytes + up.image_bytes,
        ff.image_bytes + fp.image_bytes
    );
    // The images went into the blobs as the report counts them: WebP (the default codec,
    // which on this texture reaches JPEG's error in fewer bytes) stored whole, and every patch
    // decodes with its atlas.
    let webp = by_features
        .webp
        .expect("the default codec matched WebP to JPEG");
    assert!(webp.offset.is_some(), "{webp:?}");
    assert!(webp.webp_error <= webp.jpeg_error && webp.webp_bytes < webp.jpeg_bytes);
    let lod = LodFile::open(&out).expect("open");
    let mut bytes = 0u64;
    for node in 0..lod.nodes().len() as u32 {
        let p = lod.patch(node).expect("decodes");
        let img = p.image.as_deref().expect("every patch has an atlas");
        mesh::Texture::decode(img).expect("the atlas is an image");
        let blob = lod.blob(node).expect("a blob");
        assert!(lod::codec::image_is_webp(blob) && mesh::is_webp(img));
        let stored = lod::codec::blob_bytes(blob).expect("frames").0.image;
        assert_eq!(stored, img.len());
        bytes += stored as u64;
    }
    assert_eq!(bytes, ff.image_bytes + fp.image_bytes);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_texture_is_a_documented_fallback_not_an_error() {
    let dir = temp_dir("missing");
    let path = write_textured_obj(&dir);
    std::fs::remove_file(dir.join("checker.png")).expect("remove");
    let mut sink = TexturedMesh::default();
    let stats = mesh::import(&path, &mut sink, &NoProgress).expect("import without texture");
    assert_eq!(stats.textures, 0);
    assert!(sink.textures.is_empty());
    // A corrupt image is ignored the same way.
    std::fs::write(dir.join("checker.png"), b"\x89PNG\r\n\x1a\nnot really").expect("write");
    let stats = mesh::import(&path, &mut TexturedMesh::default(), &NoProgress).expect("import");
    assert_eq!(stats.textures, 0);
    let out = dir.join("plain.mwlod");
    lod::build_file(&path, &out, &BuildOptions::default(), &NoProgress).expect("build");
    assert!(!LodFile::open(&out).expect("open").has_texture());
}

fn bali() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(
        "../../shared/data/meshes/mask_bali_100k_textured_gltf/mask-gltf-2.0_separated-valid.gltf",
    );
    if p.is_file() {
        Some(p)
    } else {
        eprintln!("SKIPPED: the textured Bali mask is not under ../shared/data");
        None
    }
}

/// Reference: the source mesh rasterised with its own texture (perspective-correct texture
/// coordinates, bilinear in linear light, unlit), pixel centres, nearest depth wins.
fn reference(src: &TexturedMesh, cam: &Camera) -> Vec<[u8; 4]> {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut depth = vec![f32::INFINITY; w * h];
    let mut out = vec![[0u8, 0, 0, 255]; w * h];
    for (t, face) in src.mesh.indices.chunks_exact(3).zip(&src.faces) {
        let proj: Vec<(f32, f32, f32)> = t
            .iter()
            .filter_map(|&v| cam.project(Vec3::from(src.mesh.positions[v as usize])))
            .collect();
        if proj.len() < 3 {
            continue;
        }
        let (a, b, c) = (proj[0], proj[1], proj[2]);
        let d = (b.1 - c.1) * (a.0 - c.0) + (c.0 - b.0) * (a.1 - c.1);
        if d.abs() < 1e-12 {
            continue;
        }
        let x0 = a.0.min(b.0).min(c.0).floor().max(0.0) as usize;
        let y0 = a.1.min(b.1).min(c.1).floor().max(0.0) as usize;
        let x1 = (a.0.max(b.0).max(c.0).ceil().max(0.0) as usize).min(w);
        let y1 = (a.1.max(b.1).max(c.1).ceil().max(0.0) as usize).min(h);
        for y in y0..y1 {
            for x in x0..x1 {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let b0 = ((b.1 - c.1) * (px - c.0) + (c.0 - b.0) * (py - c.1)) / d;
                let b1 = ((c.1 - a.1) * (px - c.0) + (a.0 - c.0) * (py - c.1)) / d;
                let b2 = 1.0 - b0 - b1;
                if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                    continue;
                }
                // Perspective-correct weights.
                let (w0, w1, w2) = (b0 / a.2, b1 / b.2, b2 / c.2);
                let inv = w0 + w1 + w2;
                let z = 1.0 / inv;
                let i = y * w + x;
                if z >= depth[i] {
                    continue;
                }
                depth[i] = z;
                let (w0, w1, w2) = (w0 / inv, w1 / inv, w2 / inv);
                out[i] = match src.textures.get(face.texture as usize) {
                    Some(tex) if face.texture != NO_TEXTURE => {
                        let uv = [
                            face.uv[0][0] * w0 + face.uv[1][0] * w1 + face.uv[2][0] * w2,
                            face.uv[0][1] * w0 + face.uv[1][1] * w1 + face.uv[2][1] * w2,
                        ];
                        let mut c = encode_rgba(tex.sample(uv));
                        c[3] = 255;
                        c
                    }
                    _ => [255; 4],
                };
            }
        }
    }
    out
}

#[test]
fn bali_mask_close_up_at_one_pixel_matches_the_source_texture() {
    let Some(path) = bali() else { return };
    let mut src = TexturedMesh::default();
    mesh::import(&path, &mut src, &NoProgress).expect("import");
    assert_eq!(src.textures.len(), 1);
    assert!(src.faces.iter().all(|f| f.texture == 0));

    let dir = temp_dir("bali");
    let options = BuildOptions {
        threads: Some(2),
        memory_budget: 512 << 20,
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let textured = dir.join("textured.mwlod");
    let report = lod::build_file(&path, &textured, &options, &NoProgress).expect("build");
    let textured_secs = t.elapsed().as_secs_f64();
    // Today's build: the same scan through a sink that keeps vertex colours only.
    let t = std::time::Instant::now();
    let plain = dir.join("vertex-colours.mwlod");
    lod::build_mesh(&src.mesh, &plain, &options, &NoProgress).expect("build");
    let plain_secs = t.elapsed().as_secs_f64();

    let lod_file = LodFile::open(&textured).expect("open");
    assert!(lod_file.has_texture());
    let (mut image_bytes, mut texels) = (0u64, 0u64);
    for node in 0..lod_file.nodes().len() as u32 {
        let p = lod_file.patch(node).expect("decodes");
        let img = p.image.expect("atlas");
        let t = mesh::Texture::decode(&img).expect("jpeg");
        // As stored (without the standard Huffman tables, which decoding puts back).
        let blob = lod_file.blob(node).expect("a blob");
        image_bytes += lod::codec::blob_bytes(blob).expect("frames").0.image as u64;
        texels += t.width() as u64 * t.height() as u64;
    }
    let source_jpeg = std::fs::metadata(path.with_file_name("Image_0.jpg"))
        .map(|m| m.len())
        .unwrap_or(0);
    let source_texels =
        src.textures[0].image.width() as u64 * src.textures[0].image.height() as u64;
    eprintln!(
        "Bali mask: textured build {textured_secs:.1}s ({} nodes, {} bytes), vertex-colour build \
         {plain_secs:.1}s; atlases {texels} texels in {image_bytes} bytes = {:.3} bytes/texel \
         (source JPEG {:.3} bytes/texel)",
        report.nodes,
        report.output_bytes,
        image_bytes as f64 / texels.max(1) as f64,
        source_jpeg as f64 / source_texels.max(1) as f64,
    );

    let device = match GpuDevice::new(AdapterChoice::Software) {
        Ok(d) => d,
        Err(e) => {
            eprintln!("SKIPPED: render checks need a Vulkan adapter (lavapipe): {e}");
            return;
        }
    };
    let r = Renderer::new(device, RendererOptions::default());
    let tex_model = RenderModel::open(&textured).expect("open");
    let plain_model = RenderModel::open(&plain).expect("open");
    let centre = tex_model.center();
    let radius = tex_model.radius();
    // Close-ups along the mask's front and from the side: the nearest surface point of a ray
    // from far out towards the centre, seen from a short distance along that ray.
    let (w, h) = (384u32, 384u32);
    let opts = RenderOptions {
        outputs: Outputs::IMAGE,
        cut: Cut::default(),
        background: [0, 0, 0, 255],
        ambient: 1.0,
        ..RenderOptions::default()
    };
    let mut worst = f64::INFINITY;
    for dir in [
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(0.3, 0.2, 1.0),
        Vec3::new(-0.4, -0.1, 1.0),
    ] {
        let dir = dir.normalize();
        // The surface point most along `dir` among the vertices near the line.
        let target = src
            .mesh
            .positions
            .iter()
            .map(|&p| Vec3::from(p))
            .filter(|p| (*p - centre).reject_from(dir).length() < radius * 0.15)
            .max_by(|a, b| (*a - centre).dot(dir).total_cmp(&(*b - centre).dot(dir)))
            .unwrap_or(centre);
        let cam = Camera {
            eye: target + dir * radius * 0.45,
            target,
            up: Vec3::Y,
            fovy_deg: 40.0,
            width: w,
            height: h,
        };
        let want = reference(&src, &cam);
        let got = r.render(&tex_model, &cam, &opts, &[]).expect("render");
        let old = r.render(&plain_model, &cam, &opts, &[]).expect("render");
        let p_tex = psnr(got.color.as_ref().expect("colour"), &want);
        let p_old = psnr(old.color.as_ref().expect("colour"), &want);
        eprintln!(
            "close-up {dir:?}: PSNR against the source texture: atlases {p_tex:.2} dB, vertex \
             colours {p_old:.2} dB ({} vs {} triangles drawn)",
            got.stats.triangles, old.stats.triangles
        );
        assert!(
            p_tex > p_old + 3.0,
            "atlases {p_tex:.2} dB, vertex colours {p_old:.2} dB"
        );
        worst = worst.min(p_tex);
    }
    assert!(worst >= 32.0, "worst close-up {worst:.2} dB");

    // The whole mask, small: coarse patches, whose atlases are resampled from the finer
    // levels (not the source), against the source supersampled 4×4.
    let (w, h, ss) = (128u32, 128u32, 4u32);
    let cam = |scale: u32| Camera {
        eye: centre + Vec3::new(0.1, 0.1, 1.0).normalize() * radius * 2.6,
        target: centre,
        up: Vec3::Y,
        fovy_deg: 40.0,
        width: w * scale,
        height: h * scale,
    };
    let fine = reference(&src, &cam(ss));
    let want: Vec<[u8; 4]> = (0..(w * h) as usize)
        .map(|i| {
            let (x, y) = (i % w as usize, i / w as usize);
            let mut acc = [0f32; 3];
            for dy in 0..ss as usize {
                for dx in 0..ss as usize {
                    let c = fine[(y * ss as usize + dy) * (w * ss) as usize + x * ss as usize + dx];
                    for k in 0..3 {
                        acc[k] += mesh::srgb_to_linear(c[k]);
                    }
                }
            }
            let n = (ss * ss) as f32;
            encode_rgba([acc[0] / n, acc[1] / n, acc[2] / n, 1.0])
        })
        .collect();
    let got = r.render(&tex_model, &cam(1), &opts, &[]).expect("render");
    let old = r.render(&plain_model, &cam(1), &opts, &[]).expect("render");
    let p_tex = psnr(got.color.as_ref().expect("colour"), &want);
    let p_old = psnr(old.color.as_ref().expect("colour"), &want);
    eprintln!(
        "whole mask at {w}x{h}: PSNR against the source texture (4x4 supersampled): atlases \
         {p_tex:.2} dB, vertex colours {p_old:.2} dB ({} vs {} triangles drawn)",
        got.stats.triangles, old.stats.triangles
    );
    assert!(
        got.stats.triangles < src.mesh.triangle_count() as u64 / 2,
        "the far view draws coarse patches"
    );
    // Triangles are about pixel-sized here, so vertex colours are nearly as good; resampled
    // atlases that lost their colour (white, or another chart's) fall far below both.
    assert!(
        p_tex >= 28.0 && p_tex + 0.5 >= p_old,
        "atlases {p_tex:.2} dB, vertex colours {p_old:.2} dB"
    );
}
