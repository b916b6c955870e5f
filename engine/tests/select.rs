//! Selection on real renders (software adapter): back-projection to exactly the visible
//! full-resolution vertices inside the mask (occluded vertices never selected), the heavy
//! lasso snapping to a depth edge, markup, modes across two views, and a point pick.
//!
//! Without any Vulkan adapter the tests print a message and pass, unless
//! `MESHWIKI_REQUIRE_GPU_TESTS=1`.

use std::path::PathBuf;
use std::sync::OnceLock;

use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::{self, BuildOptions};
use meshwiki_engine::mesh::Mesh;
use meshwiki_engine::progress::NoProgress;
use meshwiki_engine::render::{
    AdapterChoice, Frame, GpuDevice, RenderModel, Renderer, RendererOptions,
};
use meshwiki_engine::select::mask::{self, StrokeMask};
use meshwiki_engine::select::modes::{self, Mode, VertexSet};
use meshwiki_engine::select::{
    BackProjectOptions, BackProjection, Buffers, EnergyParams, Tool, back_project, point,
    select_pixels,
};
use roaring::RoaringBitmap;

fn renderer() -> Option<&'static Renderer> {
    static RENDERER: OnceLock<Option<Renderer>> = OnceLock::new();
    RENDERER
        .get_or_init(|| match GpuDevice::new(AdapterChoice::Software) {
            Ok(d) => Some(Renderer::new(d, RendererOptions::default())),
            Err(e) => {
                if std::env::var("MESHWIKI_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1") {
                    panic!("no adapter for selection tests: {e}");
                }
                eprintln!("SKIPPED: selection tests need a Vulkan adapter (lavapipe): {e}");
                None
            }
        })
        .as_ref()
}

/// Grid spacing of both planes.
const STEP: f32 = 0.05;
/// The back plane: z = 0, x and y in [-1, 1]. The front plane: z = FRONT_Z, x in
/// [FX0, FX1], y in [FY0, FY1]. Vertex ids: back plane first, then front.
const FRONT_Z: f32 = 0.5;
const FX0: f32 = -0.4;
const FX1: f32 = 0.3;
const FY0: f32 = -0.35;
const FY1: f32 = 0.45;

fn grid(mesh: &mut Mesh, x0: f32, x1: f32, y0: f32, y1: f32, z: f32) {
    let nx = ((x1 - x0) / STEP).round() as u32 + 1;
    let ny = ((y1 - y0) / STEP).round() as u32 + 1;
    let base = mesh.positions.len() as u32;
    for j in 0..ny {
        for i in 0..nx {
            // A tiny deterministic offset keeps projections off exact pixel boundaries.
            let jitter = ((i * 7 + j * 13) % 5) as f32 * 1e-4;
            mesh.positions
                .push([x0 + i as f32 * STEP + jitter, y0 + j as f32 * STEP, z]);
        }
    }
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            let a = base + j * nx + i;
            mesh.indices
                .extend_from_slice(&[a, a + 1, a + nx + 1, a, a + nx + 1, a + nx]);
        }
    }
}

struct Planes {
    model: RenderModel,
    mesh: Mesh,
    back_vertices: u32,
}

fn planes() -> &'static Planes {
    static P: OnceLock<Planes> = OnceLock::new();
    P.get_or_init(|| {
        let mut mesh = Mesh::default();
        grid(&mut mesh, -1.0, 1.0, -1.0, 1.0, 0.0);
        let back_vertices = mesh.positions.len() as u32;
        grid(&mut mesh, FX0, FX1, FY0, FY1, FRONT_Z);
        let dir = std::env::temp_dir().join(format!("mw-select-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out: PathBuf = dir.join("planes.mwlod");
        let options = BuildOptions {
            max_patch_triangles: 128,
            memory_budget: 128 << 20,
            threads: Some(2),
            ..Default::default()
        };
        lod::build_mesh(&mesh, &out, &options, &NoProgress).expect("build");
        let model = RenderModel::open(&out).expect("open");
        let _ = std::fs::remove_dir_all(&dir);
        assert!(
            model.lod().header().level_count > 1,
            "want a DAG with several levels"
        );
        Planes {
            model,
            mesh,
            back_vertices,
        }
    })
}

/// Every original vertex's position as stored in the leaves (level 0).
fn leaf_positions(model: &RenderModel) -> Vec<[f32; 3]> {
    let lod = model.lod();
    let mut out = vec![[f32::NAN; 3]; lod.header().input_vertex_count as usize];
    for (n, rec) in lod.nodes().iter().enumerate() {
        if rec.level == 0 {
            let patch = lod.patch(n as u32).unwrap();
            for (v, &id) in patch.original_ids.iter().enumerate() {
                out[id as usize] = patch.positions[v];
            }
        }
    }
    out
}

fn camera(eye: Vec3, width: u32, height: u32) -> Camera {
    Camera {
        eye,
        target: Vec3::new(0.0, 0.0, 0.0),
        up: Vec3::Y,
        fovy_deg: 40.0,
        width,
        height,
    }
}

fn render(r: &Renderer, m: &RenderModel, c: &Camera) -> Frame {
    r.render_buffers(m, c, &[]).expect("render")
}

/// Pixels of a rectangle `[x0, x1) × [y0, y1)`.
fn rect(w: u32, h: u32, x0: u32, y0: u32, x1: u32, y1: u32) -> Vec<bool> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            x >= x0 && x < x1 && y >= y0 && y < y1
        })
        .collect()
}

/// The front plane's outline in pixels, seen from `c`, and whether a ray from the eye to `p`
/// crosses the front plane (with the distance in pixels from its crossing to the plane's
/// edges).
/// Runs `tool` on the strokes over a view's buffers and back-projects the selected pixels
/// (default energy and options), relative to `base` when given.
fn select_vertices(
    p: &Planes,
    c: &Camera,
    buffers: &Buffers<'_>,
    tool: Tool,
    strokes: &StrokeMask,
    base: Option<&RoaringBitmap>,
) -> BackProjection {
    // With the model's surface segments, as the server uses them.
    let sel = select_pixels(
        tool,
        strokes,
        buffers,
        &EnergyParams::default(),
        false,
        p.model.segments(),
    )
    .unwrap();
    back_project(
        p.model.lod(),
        c,
        buffers,
        &sel.selected,
        base,
        &BackProjectOptions::default(),
    )
    .unwrap()
}

fn occlusion(c: &Camera, p: Vec3) -> (bool, f32) {
    let eye = c.eye;
    let t = (FRONT_Z - eye.z) / (p.z - eye.z);
    if !(0.0..1.0).contains(&t) || p.z >= FRONT_Z - 1e-6 {
        return (false, f32::INFINITY);
    }
    let q = eye + (p - eye) * t;
    let inside = q.x > FX0 && q.x < FX1 && q.y > FY0 && q.y < FY1;
    let edge = (q.x - FX0)
        .abs()
        .min((q.x - FX1).abs())
        .min((q.y - FY0).abs())
        .min((q.y - FY1).abs());
    // Pixels per world unit at the front plane.
    let px = c.pixel_scale() / (eye.z - FRONT_Z);
    (inside, edge * px)
}

#[test]
fn back_projection_selects_exactly_the_visible_vertices_inside_the_mask() {
    let Some(r) = renderer() else { return };
    let p = planes();
    for eye in [Vec3::new(0.0, 0.0, 4.0), Vec3::new(1.2, -0.8, 3.6)] {
        let c = camera(eye, 320, 240);
        let frame = render(r, &p.model, &c);
        let buffers = Buffers::from_frame(&frame).unwrap();
        let selected = rect(320, 240, 90, 50, 250, 200);
        let bp = back_project(
            p.model.lod(),
            &c,
            &buffers,
            &selected,
            None,
            &BackProjectOptions::default(),
        )
        .unwrap();
        assert!(bp.leaves > 0 && bp.drawn_nodes > 0);
        let (mut ok, mut skipped, mut occluded_in_mask) = (0, 0, 0);
        for (id, pos) in leaf_positions(&p.model).iter().enumerate() {
            // The stored full-resolution position (quantised on the model's grid).
            let v = Vec3::from(*pos);
            let Some((x, y, _)) = c.project(v) else {
                continue;
            };
            let in_view = x >= 0.0 && y >= 0.0 && x < 320.0 && y < 240.0;
            let in_mask = in_view && selected[y as usize * 320 + x as usize];
            let (occluded, edge_px) = if (id as u32) < p.back_vertices {
                occlusion(&c, v)
            } else {
                (false, f32::INFINITY)
            };
            let got = bp.vertices.contains(id as u32);
            // Ambiguous: near the occluder's outline, or on the back plane's own outline (a
            // silhouette: the pixel centre may miss the plane).
            let on_outline =
                (id as u32) < p.back_vertices && (v.x.abs() > 0.99 || v.y.abs() > 0.99);
            if edge_px < 2.5 || on_outline {
                skipped += in_mask as usize;
                continue;
            }
            if in_mask && occluded {
                occluded_in_mask += 1;
                assert!(!got, "occluded vertex {id} at ({x}, {y}) selected");
            }
            if got != (in_mask && !occluded) {
                let i = y as usize * 320 + x as usize;
                eprintln!(
                    "eye {eye}: vertex {id} {v} depth {:?} buffer {} node {} covered {}",
                    c.project(v).map(|p| p.2),
                    buffers.depth[i],
                    buffers.node[i],
                    buffers.covered(i)
                );
            }
            assert_eq!(
                got,
                in_mask && !occluded,
                "vertex {id} at ({x:.2}, {y:.2}) in mask {in_mask}, occluded {occluded}"
            );
            ok += 1;
        }
        assert!(occluded_in_mask > 50, "the test must see occluded vertices");
        assert!(skipped < ok / 5, "{skipped} ambiguous of {ok}");
        // The selection holds vertices of both planes.
        assert!(bp.vertices.iter().any(|v| v < p.back_vertices));
        assert!(bp.vertices.iter().any(|v| v >= p.back_vertices));
    }
}

#[test]
fn heavy_lasso_around_the_front_plane_selects_it_and_nothing_behind() {
    let Some(r) = renderer() else { return };
    let p = planes();
    let c = camera(Vec3::new(0.3, 0.2, 4.0), 320, 240);
    let frame = render(r, &p.model, &c);
    let buffers = Buffers::from_frame(&frame).unwrap();
    // The front plane's screen rectangle, and a 14-pixel band drawn off-centre around it.
    let corners = [(FX0, FY0), (FX1, FY0), (FX1, FY1), (FX0, FY1)]
        .map(|(x, y)| c.project(Vec3::new(x, y, FRONT_Z)).unwrap());
    let (x0, x1) = (
        corners.iter().map(|c| c.0).fold(f32::INFINITY, f32::min),
        corners.iter().map(|c| c.0).fold(0.0, f32::max),
    );
    let (y0, y1) = (
        corners.iter().map(|c| c.1).fold(f32::INFINITY, f32::min),
        corners.iter().map(|c| c.1).fold(0.0, f32::max),
    );
    let mut m = StrokeMask::empty(320, 240).unwrap();
    for y in 0..240u32 {
        for x in 0..320u32 {
            let (fx, fy) = (x as f32 + 0.5 - 3.0, y as f32 + 0.5 + 2.0);
            let outside_in = fx > x0 - 9.0 && fx < x1 + 9.0 && fy > y0 - 9.0 && fy < y1 + 9.0;
            let inside_in = fx > x0 + 5.0 && fx < x1 - 5.0 && fy > y0 + 5.0 && fy < y1 - 5.0;
            if outside_in && !inside_in {
                m.labels[(y * 320 + x) as usize] = mask::HEAVY;
            }
        }
    }
    let bp = select_vertices(p, &c, &buffers, Tool::HeavyLasso, &m, None);
    let back: Vec<u32> = bp
        .vertices
        .iter()
        .filter(|&v| v < p.back_vertices)
        .collect();
    assert!(
        back.is_empty(),
        "back-plane vertices selected: {}",
        back.len()
    );
    // Every front vertex at least 1.5 pixels inside the plane's outline is selected.
    let mut checked = 0;
    for id in p.back_vertices..p.mesh.positions.len() as u32 {
        let (x, y, _) = c
            .project(Vec3::from(p.mesh.positions[id as usize]))
            .unwrap();
        if x > x0 + 1.5 && x < x1 - 1.5 && y > y0 + 1.5 && y < y1 - 1.5 {
            assert!(bp.vertices.contains(id), "front vertex {id} missing");
            checked += 1;
        }
    }
    assert!(checked > 100);
    let g = bp.geometry.unwrap();
    assert!((g.center.z - FRONT_Z).abs() < 1e-3);
    assert!(bp.anchor.is_some());
}

#[test]
fn markup_and_modes_across_two_views() {
    let Some(r) = renderer() else { return };
    let p = planes();
    let c = camera(Vec3::new(0.0, 0.0, 4.0), 320, 240);
    let frame = render(r, &p.model, &c);
    let buffers = Buffers::from_frame(&frame).unwrap();
    // Markup: a foreground stroke across the front plane, background strokes around it.
    let centre = c
        .project(Vec3::new((FX0 + FX1) / 2.0, (FY0 + FY1) / 2.0, FRONT_Z))
        .unwrap();
    let mut m = StrokeMask::empty(320, 240).unwrap();
    for dx in -20i32..20 {
        let (x, y) = (centre.0 as i32 + dx, centre.1 as i32);
        m.labels[(y * 320 + x) as usize] = mask::FOREGROUND;
    }
    // The back plane covers about x 78..242, y 38..202; the front plane x 122..188, y 78..153.
    for x in 85..236 {
        m.labels[(45 * 320 + x) as usize] = mask::BACKGROUND;
        m.labels[(195 * 320 + x) as usize] = mask::BACKGROUND;
    }
    for y in 45..196 {
        m.labels[(y * 320 + 85) as usize] = mask::BACKGROUND;
        m.labels[(y * 320 + 235) as usize] = mask::BACKGROUND;
    }
    let bp = select_vertices(p, &c, &buffers, Tool::Markup, &m, None);
    let front: RoaringBitmap = (p.back_vertices..p.mesh.positions.len() as u32).collect();
    let found = bp.vertices.intersection_len(&front);
    // The whole front plane, its outline (silhouette vertices) included.
    assert!(
        found as f64 > front.len() as f64 * 0.97,
        "{found} of {}",
        front.len()
    );
    assert!(
        bp.vertices.len() - found < 20,
        "{} back vertices",
        bp.vertices.len() - found
    );

    // Subtract a lasso from another viewpoint, then add it back.
    let base = VertexSet::of(&bp);
    let c2 = camera(Vec3::new(-0.6, 0.5, 3.8), 320, 240);
    let frame2 = render(r, &p.model, &c2);
    let b2 = Buffers::from_frame(&frame2).unwrap();
    let lasso = StrokeMask::new(
        320,
        240,
        rect(320, 240, 0, 0, 160, 240)
            .into_iter()
            .map(|s| if s { mask::LASSO } else { mask::NONE })
            .collect(),
    )
    .unwrap();
    let bp2 = select_vertices(p, &c2, &b2, Tool::Lasso, &lasso, Some(&base.vertices));
    let trimmed = modes::combine(&base, &bp2, Mode::Subtract);
    assert!(trimmed.vertices.len() < base.vertices.len());
    assert!(trimmed.vertices.is_subset(&base.vertices));
    assert!(trimmed.vertices.is_disjoint(&bp2.vertices));
    // Sums stay exact: the centroid equals the mean of the remaining positions.
    let mean = trimmed
        .vertices
        .iter()
        .map(|v| Vec3::from(p.mesh.positions[v as usize]))
        .sum::<Vec3>()
        / trimmed.vertices.len() as f32;
    let c3 = trimmed.centroid().unwrap();
    let err = Vec3::new(c3[0] as f32, c3[1] as f32, c3[2] as f32).distance(mean);
    assert!(err < 1e-3, "centroid off by {err}");
    let back = modes::combine(&trimmed, &bp2, Mode::Add);
    assert!(base.vertices.is_subset(&back.vertices));
}

/// On a view large enough, markup runs coarse to fine (`select::multilevel`): only a window
/// around the selection is rendered at full resolution, and the vertices it selects are those
/// the one-level cut of the whole view selects, up to the band's refinement.
#[test]
fn markup_coarse_to_fine_selects_what_the_one_level_cut_selects() {
    use meshwiki_engine::select::{Input, multilevel, select_on_view};
    let Some(r) = renderer() else { return };
    let p = planes();
    let (w, h) = (640u32, 480u32);
    let c = camera(Vec3::new(0.1, -0.05, 4.0), w, h);
    assert!(multilevel::applies(&c));
    // A short foreground stroke on the front plane; background strokes on the back plane
    // around it, a few pixels inside its outline.
    let at = |x: f32, y: f32, z: f32| {
        let (px, py, _) = c.project(Vec3::new(x, y, z)).expect("in view");
        (px as i32, py as i32)
    };
    let mut m = StrokeMask::empty(w, h).unwrap();
    let mut line = |from: (i32, i32), to: (i32, i32), label: u8| {
        let n = (to.0 - from.0).abs().max((to.1 - from.1).abs()).max(1);
        for k in 0..=n {
            let x = from.0 + (to.0 - from.0) * k / n;
            let y = from.1 + (to.1 - from.1) * k / n;
            for d in -1..=1 {
                m.labels[((y + d) as u32 * w + x as u32) as usize] = label;
            }
        }
    };
    let (cx, cy) = ((FX0 + FX1) / 2.0, (FY0 + FY1) / 2.0);
    line(
        at(cx - 0.1, cy, FRONT_Z),
        at(cx + 0.1, cy, FRONT_Z),
        mask::FOREGROUND,
    );
    let corners = [(-0.9, -0.9), (0.9, -0.9), (0.9, 0.9), (-0.9, 0.9)];
    for k in 0..4 {
        let (a, b) = (corners[k], corners[(k + 1) % 4]);
        line(at(a.0, a.1, 0.0), at(b.0, b.1, 0.0), mask::BACKGROUND);
    }
    let params = EnergyParams::default();
    let input = Input::Strokes {
        tool: Tool::Markup,
        mask: &m,
        params: &params,
    };
    let two_level = select_on_view(r, &p.model, &c, input, 1.0, None).expect("select");
    let front: RoaringBitmap = (p.back_vertices..p.mesh.positions.len() as u32).collect();
    let found = two_level.backprojection.vertices.intersection_len(&front);
    assert!(
        found as f64 > front.len() as f64 * 0.97,
        "{found} of {} front vertices",
        front.len()
    );
    let back = two_level.backprojection.vertices.len() - found;
    assert!(back < 20, "{back} back vertices");

    // The one-level cut of the whole view.
    let frame = render(r, &p.model, &c);
    let buffers = Buffers::from_frame(&frame).unwrap();
    let one_level = select_vertices(p, &c, &buffers, Tool::Markup, &m, None);
    let a = &two_level.backprojection.vertices;
    let b = &one_level.vertices;
    let differ = a.symmetric_difference_len(b);
    assert!(
        differ * 100 <= a.union_len(b),
        "{differ} vertices differ of {}",
        a.union_len(b)
    );

    // Only the window around the selection was drawn at full resolution.
    let (fine, _, _) = multilevel::markup_on_view(
        r,
        &p.model,
        &c,
        &m,
        &params,
        &meshwiki_engine::render::RenderOptions {
            cut: meshwiki_engine::render::Cut::View {
                pixel_error: 1.0,
                culling: meshwiki_engine::lod::Culling::ALL,
            },
            outputs: meshwiki_engine::render::Outputs::ALL,
            ..Default::default()
        },
    )
    .expect("coarse to fine");
    let drawn = Buffers::from_frame(&fine).unwrap().covered_count();
    assert!(
        drawn * 2 < buffers.covered_count(),
        "{drawn} pixels drawn at full resolution of {} covered",
        buffers.covered_count()
    );
}

#[test]
fn a_click_picks_the_surface_point_and_its_vertex() {
    let Some(r) = renderer() else { return };
    let p = planes();
    let c = camera(Vec3::new(0.0, 0.0, 4.0), 320, 240);
    let frame = render(r, &p.model, &c);
    let b = Buffers::from_frame(&frame).unwrap();
    let target = Vec3::new(0.02, 0.03, FRONT_Z);
    let (x, y, _) = c.project(target).unwrap();
    let picked = point::pick(p.model.lod(), &c, &b, x, y).unwrap();
    assert!(Vec3::from(picked.position).distance(target) < 0.02);
    let v = Vec3::from(p.mesh.positions[picked.vertex as usize]);
    // The nearest full-resolution vertex (the drawn patch may be a coarse one).
    assert!(v.distance(target) < STEP * 0.75, "{v} vs {target}");
    assert!(point::pick(p.model.lod(), &c, &b, 1.0, 1.0).is_err()); // background in the corner
    assert!(point::pick(p.model.lod(), &c, &b, 500.0, 1.0).is_err());
}
