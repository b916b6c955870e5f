//! Headless rendering on the software adapter (lavapipe): golden image, exact id buffer, 1 px
//! cut against full resolution on a real scan, highlights and outlines, callouts, best view,
//! concurrency, out-of-core batching and parameter validation.
//!
//! Without any Vulkan adapter the tests print a message and pass, unless
//! `MESHWIKI_REQUIRE_GPU_TESTS=1` (then they fail). `MESHWIKI_UPDATE_GOLDEN=1` rewrites the
//! golden images under `engine/tests/golden/`.

mod common;

use common::psnr;
use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::{self, BuildOptions, Culling, LodFile};
use meshwiki_engine::mesh::{self, Mesh, synth::Relief};
use meshwiki_engine::progress::NoProgress;
use meshwiki_engine::render::callouts::{self, CalloutPart, HiddenReason, LayoutOptions};
use meshwiki_engine::render::encode::{self, ImageFormat};
use meshwiki_engine::render::highlight::{OUTLINE_BIT, TINT_MASK};
use meshwiki_engine::render::{
    AdapterChoice, Cut, Frame, GpuDevice, Highlight, NO_NODE, Outputs, RenderError, RenderModel,
    RenderOptions, Renderer, RendererOptions, best_view,
};
use roaring::RoaringBitmap;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

/// Removes what earlier runs of this test binary left behind (their process is gone).
fn remove_stale_dirs() {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = name
            .strip_prefix("mw-render-")
            .and_then(|r| r.split('-').next())
        else {
            continue;
        };
        if pid != std::process::id().to_string() && !Path::new("/proc").join(pid).exists() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

fn temp_dir(name: &str) -> PathBuf {
    static CLEANED: OnceLock<()> = OnceLock::new();
    CLEANED.get_or_init(remove_stale_dirs);
    let dir = std::env::temp_dir().join(format!("mw-render-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// The software device shared by the tests (`None`, after a message, without an adapter).
fn device() -> Option<Arc<GpuDevice>> {
    static DEVICE: OnceLock<Option<Arc<GpuDevice>>> = OnceLock::new();
    DEVICE
        .get_or_init(|| match GpuDevice::new(AdapterChoice::Software) {
            Ok(d) => {
                eprintln!("render tests on {}", d.describe());
                Some(d)
            }
            Err(e) => {
                if std::env::var("MESHWIKI_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1") {
                    panic!("no adapter for render tests: {e}");
                }
                eprintln!("SKIPPED: render tests need a Vulkan adapter (lavapipe): {e}");
                None
            }
        })
        .clone()
}

fn renderer() -> Option<&'static Renderer> {
    static RENDERER: OnceLock<Option<Renderer>> = OnceLock::new();
    RENDERER
        .get_or_init(|| device().map(|d| Renderer::new(d, RendererOptions::default())))
        .as_ref()
}

/// A relief of about `tris` triangles built into a LOD file with small patches.
struct TestModel {
    mesh: Mesh,
    model: RenderModel,
}

fn build(name: &str, mesh: Mesh, max_patch_triangles: usize) -> TestModel {
    let out = temp_dir(name).join(format!("{name}.mwlod"));
    let options = BuildOptions {
        max_patch_triangles,
        memory_budget: 256 << 20,
        threads: Some(2),
        ..Default::default()
    };
    lod::build_mesh(&mesh, &out, &options, &NoProgress).expect("build");
    let model = RenderModel::open(&out).expect("open");
    TestModel { mesh, model }
}

fn relief_mesh(tris: u64) -> Mesh {
    let mut mesh = Mesh::default();
    Relief::new(tris, 7).stream(&mut mesh).expect("relief");
    mesh
}

fn relief() -> &'static TestModel {
    static MODEL: OnceLock<TestModel> = OnceLock::new();
    MODEL.get_or_init(|| build("relief", relief_mesh(20_000), 256))
}

/// An oblique view of the relief (the panel lies in z ≈ 0, facing +z).
fn oblique(width: u32, height: u32) -> Camera {
    Camera {
        eye: Vec3::new(0.9, -1.6, 1.3),
        target: Vec3::new(0.0, 0.0, 0.0),
        up: Vec3::Z,
        fovy_deg: 45.0,
        width,
        height,
    }
}

fn options(outputs: Outputs, cut: Cut) -> RenderOptions {
    RenderOptions {
        outputs,
        cut,
        background: [0, 0, 0, 255],
        ..RenderOptions::default()
    }
}

fn full_res() -> Cut {
    Cut::Uniform {
        max_error: 0.0,
        frustum: true,
    }
}

/// Max channel difference above which a pixel counts as different in golden comparisons.
const GOLDEN_TOLERANCE: u8 = 24;
/// Largest share of differing pixels accepted.
const GOLDEN_MAX_FRACTION: f64 = 0.01;

/// Compares `pixels` with `tests/golden/{name}.png` (rewritten with `MESHWIKI_UPDATE_GOLDEN=1`).
fn check_golden(name: &str, pixels: &[[u8; 4]], width: u32, height: u32) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(format!("{name}.png"));
    let png = encode::encode(pixels, width, height, ImageFormat::Png, 90, [0; 3]).expect("encode");
    let actual = temp_dir("golden").join(format!("{name}.actual.png"));
    std::fs::write(&actual, &png).expect("write actual");
    if std::env::var("MESHWIKI_UPDATE_GOLDEN").is_ok_and(|v| v == "1") {
        std::fs::create_dir_all(path.parent().expect("dir")).expect("golden dir");
        std::fs::write(&path, &png).expect("write golden");
        eprintln!("updated {}", path.display());
        return;
    }
    let bytes = std::fs::read(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (generate it with MESHWIKI_UPDATE_GOLDEN=1)",
            path.display()
        )
    });
    let (w, h, golden) = encode::decode(&bytes).expect("decode golden");
    assert_eq!((w, h), (width, height), "golden {name} size");
    let differing = pixels
        .iter()
        .zip(&golden)
        .filter(|(a, b)| (0..4).any(|k| a[k].abs_diff(b[k]) > GOLDEN_TOLERANCE))
        .count();
    let fraction = differing as f64 / pixels.len() as f64;
    let p = psnr(pixels, &golden);
    eprintln!(
        "golden {name}: {differing} differing pixels ({:.3}%), PSNR {p:.1} dB",
        fraction * 100.0
    );
    assert!(
        fraction <= GOLDEN_MAX_FRACTION,
        "{name}: {:.2}% of pixels differ from {} (see {})",
        fraction * 100.0,
        path.display(),
        actual.display()
    );
}

/// Original ids of the mesh vertices within `radius` of `(x, y)` in the xy plane.
fn disc(mesh: &Mesh, x: f32, y: f32, radius: f32) -> RoaringBitmap {
    (0..mesh.positions.len() as u32)
        .filter(|&i| {
            let p = mesh.positions[i as usize];
            (p[0] - x).powi(2) + (p[1] - y).powi(2) <= radius * radius
        })
        .collect()
}

/// The mesh vertex nearest to `(x, y)` in the xy plane (a point on the relief surface).
fn surface_point(mesh: &Mesh, x: f32, y: f32) -> Vec3 {
    let p = mesh
        .positions
        .iter()
        .min_by(|a, b| {
            let da = (a[0] - x).powi(2) + (a[1] - y).powi(2);
            let db = (b[0] - x).powi(2) + (b[1] - y).powi(2);
            da.total_cmp(&db)
        })
        .expect("vertices");
    Vec3::from(*p)
}

/// Checks that every covered pixel's vertex id is a corner of the triangle drawn there;
/// returns the number of covered pixels.
fn check_ids_exact(lod: &LodFile, frame: &Frame) -> usize {
    let ids = frame.ids.as_ref().expect("ids");
    let mut patches: HashMap<u32, lod::Patch> = HashMap::new();
    let mut covered = 0;
    for i in 0..ids.node.len() {
        let node = ids.node[i];
        if node == NO_NODE {
            continue;
        }
        covered += 1;
        let p = patches
            .entry(node)
            .or_insert_with(|| lod.patch(node).expect("patch"));
        let t = ids.triangle[i] as usize;
        assert!(
            t * 3 + 2 < p.indices.len(),
            "pixel {i}: triangle {t} not in node {node}"
        );
        let corners = [0, 1, 2].map(|k| p.original_ids[p.indices[t * 3 + k] as usize]);
        assert!(
            corners.contains(&ids.vertex[i]),
            "pixel {i}: vertex {} is not a corner of triangle {corners:?} (node {node})",
            ids.vertex[i]
        );
    }
    covered
}

/// Ray through the centre of pixel `(x, y)`.
fn pixel_ray(cam: &Camera, x: u32, y: u32) -> Vec3 {
    let (f, r, u) = cam.basis();
    let s = cam.pixel_scale();
    let dx = (x as f32 + 0.5 - cam.width as f32 * 0.5) / s;
    let dy = (y as f32 + 0.5 - cam.height as f32 * 0.5) / s;
    (f + r * dx - u * dy).normalize()
}

/// Nearest hit of a ray with the mesh: (triangle, distance, barycentrics).
fn ray_cast(mesh: &Mesh, origin: Vec3, dir: Vec3) -> Option<(usize, f32, [f32; 3])> {
    let mut best: Option<(usize, f32, [f32; 3])> = None;
    for (t, tri) in mesh.indices.chunks_exact(3).enumerate() {
        let [a, b, c] = [0, 1, 2].map(|k| Vec3::from(mesh.positions[tri[k] as usize]));
        let (e1, e2) = (b - a, c - a);
        let p = dir.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 {
            continue;
        }
        let inv = 1.0 / det;
        let s = origin - a;
        let u = s.dot(p) * inv;
        if !(-1e-6..=1.0 + 1e-6).contains(&u) {
            continue;
        }
        let q = s.cross(e1);
        let v = dir.dot(q) * inv;
        if v < -1e-6 || u + v > 1.0 + 1e-6 {
            continue;
        }
        let d = e2.dot(q) * inv;
        if d > 0.0 && best.is_none_or(|h| d < h.1) {
            best = Some((t, d, [1.0 - u - v, u, v]));
        }
    }
    best
}

#[test]
fn golden_images_on_the_software_adapter() {
    let Some(r) = renderer() else { return };
    let m = relief();
    let cam = oblique(256, 192);
    // Full resolution: the image then depends on the input triangles only, not on how the
    // (multi-threaded) LOD build grouped and simplified them.
    let plain = r
        .render(&m.model, &cam, &options(Outputs::IMAGE, full_res()), &[])
        .expect("render");
    check_golden("relief", plain.color.as_ref().expect("colour"), 256, 192);

    // Tinted part, hovered part with its outline, callouts drawn in.
    let a = disc(&m.mesh, -0.5, 0.42, 0.22);
    let b = disc(&m.mesh, 0.5, 0.42, 0.2);
    let parts = [
        Highlight {
            vertices: &a,
            tint: Some([0, 160, 255, 150]),
            outline: false,
        },
        Highlight {
            vertices: &b,
            tint: Some([255, 176, 0, 150]),
            outline: true,
        },
    ];
    let frame = r
        .render(
            &m.model,
            &cam,
            &options(Outputs::IMAGE_DEPTH, full_res()),
            &parts,
        )
        .expect("render");
    let mut color = frame.color.clone().expect("colour");
    let anchors = [
        CalloutPart {
            part: 1,
            anchor: surface_point(&m.mesh, -0.5, 0.42),
            title: "Rosette (left)".into(),
            radius: 0.0,
        },
        CalloutPart {
            part: 2,
            anchor: surface_point(&m.mesh, 0.5, 0.42),
            title: "Rosette (right)".into(),
            radius: 0.0,
        },
    ];
    let layout = callouts::layout(
        &anchors,
        &cam,
        frame.depth.as_deref(),
        &LayoutOptions::for_height(192),
    )
    .expect("layout");
    assert_eq!(layout.callouts.len(), 2, "{layout:?}");
    callouts::draw(
        &mut color,
        &layout,
        &callouts::CalloutStyle {
            font_scale: 1,
            ..Default::default()
        },
    );
    check_golden("relief_parts_callouts", &color, 256, 192);
}

#[test]
fn id_buffer_is_exact_and_matches_ray_casts() {
    let Some(r) = renderer() else { return };
    let m = relief();
    let cam = oblique(256, 192);
    for (label, cut) in [
        ("1 px", Cut::default()),
        (
            "8 px",
            Cut::View {
                pixel_error: 8.0,
                culling: Culling::ALL,
            },
        ),
        ("full", full_res()),
    ] {
        let frame = r
            .render(&m.model, &cam, &options(Outputs::ALL, cut), &[])
            .expect("render");
        let covered = check_ids_exact(m.model.lod(), &frame);
        eprintln!(
            "{label}: {covered} covered pixels, all ids exact, {} triangles",
            frame.stats.triangles
        );
        assert!(covered > 10_000);
        if label != "full" {
            continue;
        }
        // Full resolution draws the input triangles: compare with CPU ray casts.
        let ids = frame.ids.as_ref().expect("ids");
        let depth = frame.depth.as_ref().expect("depth");
        let normal = frame.normal.as_ref().expect("normal");
        let (mut samples, mut same_triangle, mut nearest, mut depth_ok) = (0, 0, 0, 0);
        for y in (2..192).step_by(6) {
            for x in (2..256).step_by(6) {
                let i = (y * 256 + x) as usize;
                let dir = pixel_ray(&cam, x, y);
                let hit = ray_cast(&m.mesh, cam.eye, dir);
                assert_eq!(hit.is_some(), ids.node[i] != NO_NODE, "coverage at {x},{y}");
                let Some((t, dist, bary)) = hit else { continue };
                samples += 1;
                let corners = [0, 1, 2].map(|k| m.mesh.indices[t * 3 + k]);
                same_triangle += corners.contains(&ids.vertex[i]) as usize;
                let k = (0..3)
                    .max_by(|&a, &b| bary[a].total_cmp(&bary[b]))
                    .unwrap_or(0);
                nearest += (corners[k] == ids.vertex[i]) as usize;
                let view_depth = dist * dir.dot(cam.forward());
                depth_ok += ((depth[i] - view_depth).abs() <= 1e-3 * view_depth) as usize;
                let n = Vec3::from(normal[i]);
                assert!((n.length() - 1.0).abs() < 1e-3, "unit normal");
                assert!(
                    n.dot(-dir) > -0.05,
                    "normal faces the viewer at {x},{y}: {n}"
                );
            }
        }
        eprintln!(
            "ray casts: {samples} samples, vertex on hit triangle {same_triangle}, nearest corner {nearest}, depth {depth_ok}"
        );
        assert!(same_triangle as f64 >= 0.97 * samples as f64);
        assert!(nearest as f64 >= 0.95 * samples as f64);
        assert!(depth_ok as f64 >= 0.97 * samples as f64);
    }
}

/// A window of the view (the selection tools draw only their strokes' box) holds the whole
/// view's pixels: the same ids, depth and normals, placed at its origin; the rest of the view
/// embeds as background. Patches wholly outside the window are not drawn.
#[test]
fn a_window_of_the_view_holds_the_whole_views_pixels() {
    let Some(r) = renderer() else { return };
    let m = relief();
    let (w, h) = (256u32, 192u32);
    let cam = oblique(w, h);
    let cut = Cut::View {
        pixel_error: 1.0,
        culling: Culling::ALL,
    };
    let whole = r
        .render(&m.model, &cam, &options(Outputs::ALL, cut.clone()), &[])
        .expect("render");
    let wi = whole.ids.as_ref().expect("ids");
    let wd = whole.depth.as_ref().expect("depth");
    let wn = whole.normal.as_ref().expect("normal");
    for window in [
        [37u32, 21u32, 90u32, 61u32],
        [0, 0, 1, 1],
        [200, 150, 56, 42],
        [120, 90, 9, 9],
    ] {
        let [x0, y0, ww, wh] = window;
        let o = RenderOptions {
            window: Some(window),
            ..options(Outputs::ALL, cut.clone())
        };
        let part = r.render(&m.model, &cam, &o, &[]).expect("render window");
        assert_eq!((part.width, part.height, part.origin), (ww, wh, [x0, y0]));
        assert!(part.stats.nodes <= whole.stats.nodes);
        let embedded = part.clone().embed(w, h);
        let (ei, ed) = (
            embedded.ids.as_ref().expect("ids"),
            embedded.depth.as_ref().expect("depth"),
        );
        let (mut covered, mut same_ids, mut depth_ok, mut normal_ok) = (0, 0, 0, 0);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                let inside = (x0..x0 + ww).contains(&x) && (y0..y0 + wh).contains(&y);
                if !inside {
                    assert_eq!(
                        ei.node[i], NO_NODE,
                        "background outside the window at {x},{y}"
                    );
                    assert!(ed[i].is_infinite());
                    continue;
                }
                let j = ((y - y0) * ww + (x - x0)) as usize;
                let pi = part.ids.as_ref().expect("ids");
                assert_eq!(ei.node[i], pi.node[j], "embedding keeps the pixel");
                if wi.node[i] == NO_NODE && pi.node[j] == NO_NODE {
                    continue;
                }
                covered += 1;
                same_ids += (wi.node[i] == pi.node[j]
                    && wi.vertex[i] == pi.vertex[j]
                    && wi.triangle[i] == pi.triangle[j]) as usize;
                let pd = part.depth.as_ref().expect("depth")[j];
                depth_ok += ((pd - wd[i]).abs() <= 1e-4 * wd[i]) as usize;
                let pn = Vec3::from(part.normal.as_ref().expect("normal")[j]);
                normal_ok += (pn.dot(Vec3::from(wn[i])) > 0.999) as usize;
            }
        }
        eprintln!(
            "window {window:?}: {covered} covered, ids equal {same_ids}, depth {depth_ok}, normals {normal_ok}; {} of {} patches drawn",
            part.stats.nodes, whole.stats.nodes
        );
        // An off-centre crop of the same projection samples the same points up to rounding:
        // a pixel centre lying on a triangle edge may go either way.
        let at_least = |n: usize| n as f64 >= 0.99 * covered as f64 - 1.0;
        assert!(at_least(same_ids) && at_least(depth_ok) && at_least(normal_ok));
        if ww * wh >= 4000 {
            assert!(covered > 1000, "the window shows the relief");
            assert!(
                part.stats.nodes < whole.stats.nodes,
                "patches outside the window are not drawn"
            );
        }
    }
    // A window outside the view is refused.
    let o = RenderOptions {
        window: Some([250, 0, 10, 10]),
        ..options(Outputs::ALL, cut)
    };
    assert!(matches!(
        r.render(&m.model, &cam, &o, &[]),
        Err(RenderError::BadOption(_))
    ));
}

#[test]
fn tints_are_exact_and_the_hovered_part_is_outlined() {
    let Some(r) = renderer() else { return };
    let m = relief();
    let cam = oblique(320, 240);
    let (w, h) = (320usize, 240usize);
    let a = disc(&m.mesh, -0.5, 0.42, 0.22);
    let b = disc(&m.mesh, 0.0, 0.42, 0.15);
    let width = 3u32;
    for cut in [
        Cut::default(),
        Cut::View {
            pixel_error: 6.0,
            culling: Culling::ALL,
        },
    ] {
        let opts = RenderOptions {
            outline_width: width,
            ..options(Outputs::ALL, cut)
        };
        let parts = [
            Highlight {
                vertices: &a,
                tint: Some([255, 0, 255, 160]),
                outline: false,
            },
            Highlight {
                vertices: &b,
                tint: None,
                outline: true,
            },
        ];
        let marked = r.render(&m.model, &cam, &opts, &parts).expect("render");
        let plain = r.render(&m.model, &cam, &opts, &[]).expect("render");
        let ids = marked.ids.as_ref().expect("ids");
        assert_eq!(
            ids,
            &plain
                .ids
                .clone()
                .expect("ids")
                .with_highlight(&ids.highlight)
        );
        let (c1, c0) = (
            marked.color.as_ref().expect("c"),
            plain.color.as_ref().expect("c"),
        );
        let in_a: Vec<bool> = (0..w * h)
            .map(|i| ids.node[i] != NO_NODE && a.contains(ids.vertex[i]))
            .collect();
        let in_b: Vec<bool> = (0..w * h)
            .map(|i| ids.node[i] != NO_NODE && b.contains(ids.vertex[i]))
            .collect();
        let (mut tinted, mut tint_changed) = (0, 0);
        for i in 0..w * h {
            assert_eq!(
                ids.highlight[i] & TINT_MASK == 1,
                in_a[i],
                "tint mask at pixel {i}"
            );
            assert_eq!(
                ids.highlight[i] & OUTLINE_BIT != 0,
                in_b[i],
                "outline mask at pixel {i}"
            );
            if in_a[i] {
                tinted += 1;
                tint_changed += (c1[i] != c0[i]) as usize;
            }
        }
        assert!(tinted > 200 && in_b.iter().filter(|&&v| v).count() > 200);
        assert!(
            tint_changed as f64 >= 0.99 * tinted as f64,
            "{tint_changed} of {tinted} tinted pixels changed"
        );
        // Distance (pixels) from each pixel to the hovered part.
        let dist = |x: usize, y: usize| -> f32 {
            let r = width as i64 + 2;
            let mut best = f32::INFINITY;
            for dy in -r..=r {
                for dx in -r..=r {
                    let (px, py) = (x as i64 + dx, y as i64 + dy);
                    if px >= 0
                        && py >= 0
                        && (px as usize) < w
                        && (py as usize) < h
                        && in_b[py as usize * w + px as usize]
                    {
                        best = best.min(((dx * dx + dy * dy) as f32).sqrt());
                    }
                }
            }
            best
        };
        let (mut ring, mut ring_changed) = (0, 0);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if in_a[i] || in_b[i] {
                    // The part itself keeps its shading (and tint).
                    if in_b[i] && !in_a[i] {
                        assert_eq!(c1[i], c0[i], "hovered part pixel {x},{y} unchanged");
                    }
                    continue;
                }
                let d = dist(x, y);
                if c1[i] != c0[i] {
                    assert!(
                        d <= width as f32 + 0.5,
                        "changed pixel {x},{y} at distance {d} from the part"
                    );
                }
                if d <= width as f32 - 0.5 {
                    ring += 1;
                    ring_changed += (c1[i] != c0[i]) as usize;
                }
            }
        }
        eprintln!(
            "tinted {tinted} (changed {tint_changed}), outline ring {ring} (drawn {ring_changed})"
        );
        assert!(ring > 100 && ring_changed as f64 >= 0.98 * ring as f64);
    }
}

trait WithHighlight {
    fn with_highlight(self, h: &[u32]) -> Self;
}

impl WithHighlight for meshwiki_engine::render::IdBuffer {
    /// The same buffer with another highlight channel (ids must not depend on highlights).
    fn with_highlight(mut self, h: &[u32]) -> Self {
        self.highlight = h.to_vec();
        self
    }
}

#[test]
fn callouts_drop_hidden_anchors_and_do_not_overlap() {
    let Some(r) = renderer() else { return };
    let m = relief();
    let cam = oblique(512, 384);
    let frame = r
        .render(
            &m.model,
            &cam,
            &options(Outputs::IMAGE_DEPTH, Cut::default()),
            &[],
        )
        .expect("render");
    let mut parts = vec![
        CalloutPart {
            part: 100,
            anchor: Vec3::new(0.0, 0.0, -0.4),
            title: "Under the panel".into(),
            radius: 0.0,
        },
        CalloutPart {
            part: 101,
            anchor: Vec3::new(6.0, 5.0, 0.0),
            title: "Far away".into(),
            radius: 0.0,
        },
        CalloutPart {
            part: 102,
            anchor: cam.eye - cam.forward(),
            title: "Behind the camera".into(),
            radius: 0.0,
        },
    ];
    let spots = [
        (-0.5, 0.42),
        (0.0, 0.42),
        (0.5, 0.42),
        (-0.52, -0.05),
        (0.52, -0.05),
        (0.1, 0.5),
        (-0.1, 0.35),
    ];
    for (k, &(x, y)) in spots.iter().enumerate() {
        parts.push(CalloutPart {
            part: k as i64 + 1,
            anchor: surface_point(&m.mesh, x, y),
            title: format!("Carving {} of the panel", k + 1),
            radius: 0.0,
        });
    }
    let layout = callouts::layout(
        &parts,
        &cam,
        frame.depth.as_deref(),
        &LayoutOptions::default(),
    )
    .expect("layout");
    let hidden: HashMap<i64, HiddenReason> =
        layout.hidden.iter().map(|h| (h.part, h.reason)).collect();
    assert_eq!(
        hidden.get(&100),
        Some(&HiddenReason::Occluded),
        "{:?}",
        layout.hidden
    );
    assert_eq!(hidden.get(&101), Some(&HiddenReason::Outside));
    assert_eq!(hidden.get(&102), Some(&HiddenReason::Behind));
    let shown: HashSet<i64> = layout.callouts.iter().map(|c| c.part).collect();
    assert!(
        (1..=7).all(|p| shown.contains(&p)),
        "all surface anchors labelled: {shown:?}"
    );
    let mut crossings = 0;
    for (i, a) in layout.callouts.iter().enumerate() {
        let r = a.label;
        assert!(r.x >= 0.0 && r.y >= 0.0 && r.x + r.w <= 512.0 && r.y + r.h <= 384.0);
        for b in &layout.callouts[i + 1..] {
            let s = b.label;
            assert!(
                r.x + r.w <= s.x || s.x + s.w <= r.x || r.y + r.h <= s.y || s.y + s.h <= r.y,
                "labels of {} and {} overlap",
                a.part,
                b.part
            );
            crossings += cross(a.leader, b.leader) as usize;
        }
    }
    eprintln!(
        "{} callouts, {crossings} leader crossings",
        layout.callouts.len()
    );
    assert!(crossings <= 1);
    let json = serde_json::to_string(&layout).expect("json");
    assert!(json.contains("\"leader\"") && json.contains("\"occluded\""));
    let mut img = frame.color.clone().expect("colour");
    callouts::draw(&mut img, &layout, &Default::default());
    let changed = img
        .iter()
        .zip(frame.color.as_ref().expect("c"))
        .filter(|(a, b)| a != b)
        .count();
    assert!(changed > 1000);
    let png = encode::encode(&img, 512, 384, ImageFormat::Png, 90, [0; 3]).expect("png");
    std::fs::write(temp_dir("callouts").join("callouts.png"), png).expect("write");
}

fn cross(a: [[f32; 2]; 2], b: [[f32; 2]; 2]) -> bool {
    let o = |p: [f32; 2], q: [f32; 2], r: [f32; 2]| {
        (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
    };
    o(a[0], a[1], b[0]) * o(a[0], a[1], b[1]) < 0.0
        && o(b[0], b[1], a[0]) * o(b[0], b[1], a[1]) < 0.0
}

#[test]
fn best_view_avoids_an_occluder() {
    let Some(r) = renderer() else { return };
    // The relief with a plate floating above its centre, facing +z.
    let mut mesh = relief_mesh(20_000);
    let base = mesh.positions.len() as u32;
    let (z, s) = (0.3f32, 0.2f32);
    for (x, y) in [(-s, -s), (s, -s), (s, s), (-s, s)] {
        mesh.positions.push([x, y, z]);
        mesh.colors.push([200, 40, 40, 255]);
    }
    mesh.indices
        .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    let m = build("occluded", mesh, 256);
    let part = disc(&m.mesh, 0.0, 0.0, 0.08);
    let geometry = best_view::part_geometry(m.model.lod(), &part)
        .expect("decode")
        .expect("part");
    assert!(
        geometry.normal.z > 0.9 && geometry.extent > 0.05,
        "{geometry:?}"
    );
    let opts = best_view::BestViewOptions {
        up: Vec3::Y,
        ..Default::default()
    };
    let view = best_view::best_view(r, &m.model, &part, &geometry, &opts).expect("best view");
    for c in &view.candidates {
        eprintln!(
            "candidate {:?}: visible {} drawn {} score {:.2}",
            c.direction, c.visible, c.drawn, c.score
        );
    }
    eprintln!(
        "chosen {} score {:.2} camera {:?}",
        view.chosen, view.score, view.camera
    );
    assert!(
        view.candidates[0].score < 0.2,
        "the plate hides the straight view"
    );
    assert!(view.chosen != 0 && view.score > 0.5);
    // From the chosen camera, the part is seen: most of the image centre shows its vertices.
    let frame = r
        .render_buffers(&m.model, &view.camera, &[])
        .expect("render");
    let ids = frame.ids.as_ref().expect("ids");
    let (w, h) = (view.camera.width as usize, view.camera.height as usize);
    let centre = ids.vertex[(h / 2) * w + w / 2];
    assert!(part.contains(centre), "the part is at the image centre");

    // Unoccluded part: the mean normal is kept.
    let free = disc(&m.mesh, 0.6, -0.6, 0.1);
    let g = best_view::part_geometry(m.model.lod(), &free)
        .expect("decode")
        .expect("part");
    let v = best_view::best_view(r, &m.model, &free, &g, &opts).expect("best view");
    assert_eq!(v.chosen, 0, "{:?}", v.candidates);
}

#[test]
fn concurrent_renders_with_a_small_cache_match_sequential_ones() {
    let Some(dev) = device() else { return };
    let m = relief();
    let small = Renderer::new(
        dev.clone(),
        RendererOptions {
            cache_bytes: 160 << 10,
            batch_bytes: 48 << 10,
            ..Default::default()
        },
    );
    let big = Renderer::new(dev, RendererOptions::default());
    let cams: Vec<Camera> = (0..6)
        .map(|k| {
            let a = k as f32 * 0.7;
            Camera {
                eye: Vec3::new(a.cos() * 1.5, a.sin() * 1.5, 0.6 + 0.3 * k as f32),
                target: Vec3::new(0.1 * k as f32 - 0.3, 0.0, 0.0),
                up: Vec3::Z,
                fovy_deg: 40.0,
                width: 200,
                height: 150,
            }
        })
        .collect();
    let opts = options(Outputs::ALL, Cut::default());
    let reference: Vec<Frame> = cams
        .iter()
        .map(|c| big.render(&m.model, c, &opts, &[]).expect("render"))
        .collect();
    let frames: Vec<Vec<Frame>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..8)
            .map(|t| {
                let (small, cams, opts, model) = (&small, &cams, &opts, &m.model);
                s.spawn(move || {
                    (0..cams.len())
                        .map(|k| {
                            small
                                .render(model, &cams[(k + t) % cams.len()], opts, &[])
                                .expect("render")
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("thread"))
            .collect()
    });
    for (t, list) in frames.iter().enumerate() {
        for (k, f) in list.iter().enumerate() {
            let want = &reference[(k + t) % cams.len()];
            assert_eq!(f.ids, want.ids, "thread {t} frame {k}: ids");
            assert_eq!(f.color, want.color, "thread {t} frame {k}: colour");
            assert_eq!(f.depth, want.depth, "thread {t} frame {k}: depth");
            assert!(f.stats.batches > 1, "small batches");
        }
    }
    let stats = small.cache_stats();
    eprintln!("small cache after concurrent renders: {stats:?}");
    assert!(stats.evictions > 0 && stats.resident_bytes <= stats.budget_bytes);
    assert!(
        stats.live_bytes <= stats.budget_bytes,
        "nothing pinned after the renders"
    );
}

#[test]
fn renders_touch_only_the_patches_in_view() {
    let Some(dev) = device() else { return };
    let m = relief();
    let r = Renderer::new(dev, RendererOptions::default());
    let close = Camera {
        eye: Vec3::new(0.55, 0.45, 0.25),
        target: Vec3::new(0.5, 0.42, 0.0),
        up: Vec3::Y,
        fovy_deg: 40.0,
        width: 256,
        height: 256,
    };
    let f = r
        .render(
            &m.model,
            &close,
            &options(Outputs::IMAGE, Cut::default()),
            &[],
        )
        .expect("render");
    let nodes = m.model.lod().nodes().len();
    eprintln!(
        "close-up: {} of {nodes} patches loaded, {} triangles",
        f.stats.loaded, f.stats.triangles
    );
    assert!(f.stats.loaded * 4 < nodes && f.stats.cache.resident_bytes > 0);
    let again = r
        .render(
            &m.model,
            &close,
            &options(Outputs::IMAGE, Cut::default()),
            &[],
        )
        .expect("render");
    assert_eq!(again.stats.loaded, 0, "second render hits the cache");
    assert_eq!(again.color, f.color);
}

#[test]
fn bad_parameters_are_typed_errors() {
    let Some(r) = renderer() else { return };
    let m = relief();
    let good = oblique(64, 48);
    let o = options(Outputs::IMAGE, Cut::default());
    let err =
        |cam: &Camera, o: &RenderOptions| r.render(&m.model, cam, o, &[]).expect_err("must fail");
    assert!(matches!(
        err(&Camera { width: 0, ..good }, &o),
        RenderError::Camera(_)
    ));
    assert!(matches!(
        err(
            &Camera {
                eye: Vec3::new(f32::NAN, 0.0, 0.0),
                ..good
            },
            &o
        ),
        RenderError::Camera(_)
    ));
    assert!(matches!(
        err(
            &Camera {
                width: 8192,
                height: 8192,
                ..good
            },
            &o
        ),
        RenderError::TooManyPixels { .. }
    ));
    let bad_px = options(
        Outputs::IMAGE,
        Cut::View {
            pixel_error: f32::NAN,
            culling: Culling::ALL,
        },
    );
    assert!(matches!(err(&good, &bad_px), RenderError::BadOption(_)));
    assert!(matches!(
        err(&good, &options(Outputs::default(), Cut::default())),
        RenderError::BadOption(_)
    ));
    let wide = RenderOptions {
        outline_width: 1000,
        ..o.clone()
    };
    assert!(matches!(err(&good, &wide), RenderError::BadOption(_)));
    assert!(matches!(
        err(&good, &options(Outputs::IMAGE, Cut::Nodes(vec![u32::MAX]))),
        RenderError::BadNode(_)
    ));
    let part: RoaringBitmap = [1u32].into_iter().collect();
    let many: Vec<Highlight> = (0..300)
        .map(|_| Highlight {
            vertices: &part,
            tint: Some([1, 2, 3, 4]),
            outline: false,
        })
        .collect();
    assert!(matches!(
        r.render(&m.model, &good, &o, &many),
        Err(RenderError::TooManyTints { count: 300, .. })
    ));
    // Empty views render the background.
    let away = Camera {
        eye: Vec3::new(0.0, 0.0, 5.0),
        target: Vec3::new(0.0, 0.0, 10.0),
        up: Vec3::Y,
        ..good
    };
    let f = r
        .render(&m.model, &away, &options(Outputs::ALL, Cut::default()), &[])
        .expect("empty view");
    assert_eq!(f.stats.nodes, 0);
    assert!(
        f.ids
            .as_ref()
            .expect("ids")
            .node
            .iter()
            .all(|&n| n == NO_NODE)
    );
    assert!(
        f.depth
            .as_ref()
            .expect("depth")
            .iter()
            .all(|d| d.is_infinite())
    );
    // Explicit node lists, including an empty one.
    let f = r
        .render(
            &m.model,
            &good,
            &options(Outputs::IMAGE, Cut::Nodes(vec![])),
            &[],
        )
        .expect("no nodes");
    assert_eq!(f.stats.triangles, 0);
}

/// The real-scan check of the issue: 1 px cut against the full-resolution cut.
#[test]
fn one_pixel_cut_matches_full_resolution_on_a_real_scan() {
    let Some(r) = renderer() else { return };
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/meshes");
    let Some(path) = ["stanford_armadillo_346k.ply", "igea_269k.ply"]
        .iter()
        .map(|f| data.join(f))
        .find(|p| p.is_file())
    else {
        eprintln!("SKIPPED: no real scan under {}", data.display());
        return;
    };
    let t = std::time::Instant::now();
    let (mesh, _) = mesh::load(&path).expect("load scan");
    let m = build("scan", mesh, 1024);
    eprintln!(
        "{}: built in {:.1}s",
        path.display(),
        t.elapsed().as_secs_f64()
    );
    let lod = m.model.lod();
    let centre = m.model.center();
    let radius = m.model.radius();
    let mut leaf_of: HashMap<u32, u32> = HashMap::new();
    for (i, n) in lod.nodes().iter().enumerate() {
        if n.level == 0 {
            for &id in &lod.patch(i as u32).expect("leaf").original_ids {
                leaf_of.entry(id).or_insert(i as u32);
            }
        }
    }
    let (w, h) = (512u32, 512u32);
    for (k, dir) in [Vec3::new(0.15, 0.1, 1.0), Vec3::new(-1.0, 0.3, 0.4)]
        .into_iter()
        .enumerate()
    {
        let cam = Camera {
            eye: centre + dir.normalize() * radius * 2.2,
            target: centre,
            up: Vec3::Y,
            fovy_deg: 40.0,
            width: w,
            height: h,
        };
        let one = r
            .render(&m.model, &cam, &options(Outputs::ALL, Cut::default()), &[])
            .expect("1 px");
        let full = r
            .render(&m.model, &cam, &options(Outputs::ALL, full_res()), &[])
            .expect("full");
        check_ids_exact(lod, &one);
        let p = psnr(
            one.color.as_ref().expect("c"),
            full.color.as_ref().expect("c"),
        );
        let (i1, i0) = (
            one.ids.as_ref().expect("ids"),
            full.ids.as_ref().expect("ids"),
        );
        let set = |b: &meshwiki_engine::render::IdBuffer| -> HashSet<u32> {
            b.vertex
                .iter()
                .zip(&b.node)
                .filter(|(_, n)| **n != NO_NODE)
                .map(|(v, _)| *v)
                .collect()
        };
        let (s1, s0) = (set(i1), set(i0));
        let jaccard = |a: &HashSet<u32>, b: &HashSet<u32>| {
            a.intersection(b).count() as f64 / a.union(b).count().max(1) as f64
        };
        let leaves = |s: &HashSet<u32>| -> HashSet<u32> {
            s.iter().filter_map(|v| leaf_of.get(v).copied()).collect()
        };
        let (l1, l0) = (leaves(&s1), leaves(&s0));
        let cov1: HashSet<usize> = (0..i1.node.len())
            .filter(|&i| i1.node[i] != NO_NODE)
            .collect();
        let cov0: HashSet<usize> = (0..i0.node.len())
            .filter(|&i| i0.node[i] != NO_NODE)
            .collect();
        let cover_j =
            cov1.intersection(&cov0).count() as f64 / cov1.union(&cov0).count().max(1) as f64;
        // Every vertex the 1 px id buffer shows is visible at full resolution: it projects
        // onto the full-resolution surface at its own depth.
        let d0 = full.depth.as_ref().expect("depth");
        let mut truly_visible = 0;
        for &v in &s1 {
            let p3 = Vec3::from(m.mesh.positions[v as usize]);
            let Some((x, y, d)) = cam.project(p3) else {
                continue;
            };
            let (cx, cy) = (x.floor() as i64, y.floor() as i64);
            let mut ok = false;
            for py in (cy - 1).max(0)..=(cy + 1).min(h as i64 - 1) {
                for px in (cx - 1).max(0)..=(cx + 1).min(w as i64 - 1) {
                    let s = d0[(py * w as i64 + px) as usize];
                    ok |= (s - d).abs() <= 0.01 * d;
                }
            }
            truly_visible += ok as usize;
        }
        let precision = truly_visible as f64 / s1.len().max(1) as f64;
        eprintln!(
            "view {k}: PSNR {p:.2} dB; triangles {} (1 px) vs {} (full), patches {} vs {}; coverage Jaccard {cover_j:.4}; visible ids {} vs {}, Jaccard {:.3}; visible leaf patches Jaccard {:.3}; 1 px ids visible at full res {:.3}; times {:.0} / {:.0} ms",
            one.stats.triangles,
            full.stats.triangles,
            one.stats.nodes,
            full.stats.nodes,
            s1.len(),
            s0.len(),
            jaccard(&s1, &s0),
            jaccard(&l1, &l0),
            precision,
            one.stats.total_ms,
            full.stats.total_ms
        );
        assert!(p >= 35.0, "PSNR {p:.2} dB below 35");
        assert!(cover_j >= 0.98, "coverage Jaccard {cover_j}");
        assert!(jaccard(&l1, &l0) >= 0.9, "visible leaf patches differ");
        assert!(
            precision >= 0.95,
            "1 px ids visible at full resolution: {precision}"
        );
        assert!(
            one.stats.triangles * 2 < full.stats.triangles,
            "1 px draws far fewer triangles"
        );
    }
    let _ = std::fs::remove_dir_all(temp_dir("scan"));
}
