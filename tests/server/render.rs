//! Server-side rendering over HTTP (issue 4) on the software adapter: images with tinted and
//! outlined parts and callouts, the buffers layout (ids are original vertex ids of the scan),
//! callouts as JSON, parameter checks (400), 404/409/401, part best views and thumbnails,
//! and twenty concurrent renders against a bounded pool (image or 503, memory bounded).

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use meshwiki_engine::camera::Camera;
use meshwiki_engine::render::encode;
use serde_json::{Value, json};

use crate::harness::*;
use crate::lod::relief_ply;

/// A real scan with vertex colours, or a generated relief when the shared data is absent.
pub fn scan(dir: &Path) -> PathBuf {
    let real =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes/gargoyle_50k_vcolor.ply");
    if real.is_file() {
        return real;
    }
    eprintln!(
        "{} absent: rendering a generated relief instead",
        real.display()
    );
    relief_ply(dir, "relief.ply", 40_000)
}

/// `meshwiki import FILE --title TITLE` before the server starts; returns the model id.
pub fn import(data: &Path, file: &Path, title: &str) -> i64 {
    let out = Command::new(BIN)
        .args(["import"])
        .arg(file)
        .args(["--title", title, "--data-dir"])
        .arg(data)
        .env("MESHWIKI_LOG", "warn")
        .output()
        .expect("run meshwiki import");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rest = stdout
        .split(" as model ")
        .nth(1)
        .unwrap_or_else(|| panic!("no model id in {stdout}"));
    rest.trim_start()
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no model id in {stdout}"))
}

fn png(r: &Resp) -> (u32, u32, Vec<[u8; 4]>) {
    assert_eq!(r.status, 200, "{}", r.text());
    encode::decode(&r.body).expect("decodable image")
}

fn covered(px: &[[u8; 4]]) -> usize {
    px.iter().filter(|p| p[3] == 255).count()
}

fn differing(a: &[[u8; 4]], b: &[[u8; 4]]) -> usize {
    a.iter().zip(b).filter(|(x, y)| x != y).count()
}

/// A decoded buffers body.
pub struct Buffers {
    header: Value,
    body: Vec<u8>,
}

impl Buffers {
    pub fn parse(r: &Resp) -> Buffers {
        assert_eq!(r.status, 200, "{}", r.text());
        assert_eq!(r.header("content-type"), Some("application/octet-stream"));
        let b = &r.body;
        assert_eq!(&b[..4], b"MWRB");
        assert_eq!(u32::from_le_bytes(b[4..8].try_into().unwrap()), 1);
        let len = u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize;
        assert_eq!(len % 4, 0);
        let header: Value = serde_json::from_slice(&b[12..12 + len]).expect("JSON header");
        let total: u64 = header["buffers"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| e["bytes"].as_u64().unwrap())
            .sum();
        assert_eq!(b.len() as u64, 12 + len as u64 + total, "{header}");
        Buffers {
            header,
            body: b.clone(),
        }
    }

    fn entry(&self, name: &str) -> &Value {
        self.header["buffers"]
            .as_array()
            .unwrap()
            .iter()
            .find(|e| e["name"] == name)
            .unwrap_or_else(|| panic!("no {name} buffer in {}", self.header))
    }

    fn words(&self, name: &str) -> Vec<u32> {
        let e = self.entry(name);
        let (o, n) = (
            e["offset"].as_u64().unwrap() as usize,
            e["bytes"].as_u64().unwrap() as usize,
        );
        assert_eq!(o % 4, 0);
        self.body[o..o + n]
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }

    pub fn floats(&self, name: &str) -> Vec<f32> {
        self.words(name).into_iter().map(f32::from_bits).collect()
    }

    fn camera(&self) -> Camera {
        serde_json::from_value(json!({
            "eye": self.header["camera"]["eye"],
            "target": self.header["camera"]["target"],
            "up": self.header["camera"]["up"],
            "fovy_deg": self.header["camera"]["fovy"],
            "width": self.header["width"],
            "height": self.header["height"],
        }))
        .expect("camera")
    }
}

fn wait_part(c: &Client, id: i64, done: impl Fn(&Value) -> bool) -> Value {
    let start = Instant::now();
    loop {
        let p = c.get(&format!("/api/v1/parts/{id}")).json();
        if done(&p) {
            return p;
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "part {id} got no views: {p}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn camera_query(cam: &Value) -> String {
    let v = |k: &str| {
        cam[k]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap().to_string())
            .collect::<Vec<_>>()
            .join(",")
    };
    format!(
        "eye={}&target={}&up={}&fovy={}",
        v("eye"),
        v("target"),
        v("up"),
        cam["fovy"]
    )
}

fn vm_rss_kb(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    s.lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

#[test]
fn render_images_buffers_callouts_and_part_views() {
    const W: usize = 400;
    const H: usize = 300;
    let dir = data_dir_with_admin();
    let scans = tempfile::tempdir().unwrap();
    let file = scan(scans.path());
    let (mesh, _) = meshwiki_engine::mesh::load(&file).expect("load the scan");
    let model_id = import(dir.path(), &file, "Gargoyle");
    // Ids number the scan's vertices as its LOD file says (by default in Morton order).
    let lod =
        meshwiki_engine::lod::LodFile::open(&dir.path().join(format!("models/{model_id}.mwlod")))
            .expect("the model's LOD file");
    let mesh = meshwiki_engine::lod::vertex_order::as_built(&mesh, lod.vertex_order(), &lod.grid());
    let server = Server::start(dir.path());
    let admin = server.login("admin", ADMIN_PASSWORD);
    let editor = create_user(&server, &admin, "ed", "editor");
    let viewer = create_user(&server, &admin, "vi", "viewer");
    let base = format!("/api/v1/models/{model_id}/render");
    let model = viewer.get(&format!("/api/v1/models/{model_id}")).json();
    assert_eq!(model["status"], "ready", "{model}");
    let vertex_count = model["vertex_count"].as_u64().unwrap();
    assert_eq!(vertex_count, mesh.positions.len() as u64);

    // The overview image: the requested size, a covered, non-uniform surface.
    let r = viewer.get(&format!("{base}?w={W}&h={H}"));
    assert_eq!(r.header("content-type"), Some("image/png"));
    assert!(r.header("x-render-triangles").is_some());
    let (w, h, plain) = png(&r);
    assert_eq!((w, h), (W as u32, H as u32));
    let cov = covered(&plain);
    assert!(cov > W * H / 20, "covered {cov}");
    let shades: HashSet<[u8; 4]> = plain.iter().filter(|p| p[3] == 255).copied().collect();
    assert!(shades.len() > 50, "{} shades", shades.len());
    for (format, mime) in [("jpeg", "image/jpeg"), ("webp", "image/webp")] {
        let r = viewer.get(&format!("{base}?w=120&h=90&format={format}&quality=80"));
        assert_eq!(r.header("content-type"), Some(mime));
        let (w, h, _) = png(&r);
        assert_eq!((w, h), (120, 90));
    }

    // Buffers of the same view: the layout, exact background codes, original vertex ids.
    let buf = Buffers::parse(&viewer.get(&format!("{base}/buffers?w={W}&h={H}")));
    assert_eq!(buf.header["width"], W);
    assert_eq!(buf.header["height"], H);
    let (nodes, vertex, depth) = (buf.words("node"), buf.words("vertex"), buf.floats("depth"));
    let normal = buf.floats("normal");
    assert_eq!(normal.len(), 3 * W * H);
    let cam = buf.camera();
    let mut hits = 0;
    let mut near = 0;
    let (mut x0, mut x1, mut y0, mut y1) = (W, 0, H, 0);
    for i in 0..W * H {
        let on = nodes[i] != u32::MAX;
        assert_eq!(on, depth[i].is_finite(), "pixel {i}");
        assert_eq!(on, vertex[i] != u32::MAX, "pixel {i}");
        assert_eq!(on, plain[i][3] == 255, "pixel {i}: image and buffers agree");
        if !on {
            continue;
        }
        hits += 1;
        let (x, y) = (i % W, i / W);
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
        assert!((vertex[i] as u64) < vertex_count, "id {}", vertex[i]);
        let n = &normal[3 * i..3 * i + 3];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-2, "normal {n:?}");
        // The scan's vertex with that id projects next to the pixel.
        let p = glam::Vec3::from(mesh.positions[vertex[i] as usize]);
        if let Some((sx, sy, _)) = cam.project(p) {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            if (sx - px).hypot(sy - py) <= 4.0 {
                near += 1;
            }
        }
    }
    assert_eq!(hits, cov);
    assert!(
        near as f64 >= 0.97 * hits as f64,
        "{near} of {hits} ids project next to their pixel"
    );

    // A region part from the ids seen in a window at the centre of the model's image.
    let (cx, cy) = ((x0 + x1) / 2, (y0 + y1) / 2);
    let (rx, ry) = ((x1 - x0) / 8, (y1 - y0) / 10);
    let window = (cx - rx..cx + rx, cy - ry..cy + ry);
    let mut ids: Vec<u32> = Vec::new();
    let mut centre = [0f64; 3];
    for y in window.1.clone() {
        for x in window.0.clone() {
            let v = vertex[y * W + x];
            if v != u32::MAX && !ids.contains(&v) {
                ids.push(v);
                for (c, p) in centre.iter_mut().zip(mesh.positions[v as usize]) {
                    *c += p as f64;
                }
            }
        }
    }
    assert!(ids.len() > 50, "{} ids at the centre", ids.len());
    let centre = centre.map(|c| c / ids.len() as f64);
    let msg = editor
        .post(
            &format!("/api/v1/models/{model_id}/parts"),
            &json!({"kind": "region", "center": centre, "vertex_ids": [vertex_count]}),
        )
        .assert_error(400);
    assert!(msg.contains("out of range"), "{msg}");
    let r = editor.post(
        &format!("/api/v1/models/{model_id}/parts"),
        &json!({"kind": "region", "center": centre, "vertex_ids": ids}),
    );
    assert_eq!(r.status, 201, "{}", r.text());
    let part = r.json();
    let pid = part["id"].as_i64().unwrap();
    // A part with the client's own camera keeps it.
    let own = json!({"eye": [0.0, 0.0, 5.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fovy": 30.0});
    let r = editor.post(
        &format!("/api/v1/models/{model_id}/parts"),
        &json!({"kind": "point", "center": centre, "camera": own}),
    );
    assert_eq!(r.status, 201, "{}", r.text());
    let point = r.json()["id"].as_i64().unwrap();

    // Parts tinted and the hovered part outlined change the image where the part is.
    let (_, _, tinted) = png(&viewer.get(&format!("{base}?w={W}&h={H}&parts={pid}")));
    let (_, _, hovered) = png(&viewer.get(&format!("{base}?w={W}&h={H}&hover={pid}")));
    let (_, _, both) = png(&viewer.get(&format!(
        "{base}?w={W}&h={H}&parts={pid},{point}&hover={pid}"
    )));
    let d_tint = differing(&plain, &tinted);
    let d_hover = differing(&plain, &hovered);
    assert!(d_tint > 200, "tint changed {d_tint} pixels");
    assert!(d_hover > 50, "outline changed {d_hover} pixels");
    assert!(differing(&tinted, &both) > 50);
    // The tint lies on the part: inside the centre window, nothing far outside it.
    let changed_outside = (0..W * H)
        .filter(|&i| plain[i] != tinted[i])
        .filter(|&i| {
            let (x, y) = (i % W, i / W);
            let near = |v: usize, r: &std::ops::Range<usize>| v + 8 >= r.start && v < r.end + 8;
            !near(x, &window.0) || !near(y, &window.1)
        })
        .count();
    assert!(
        changed_outside * 20 < d_tint,
        "{changed_outside} of {d_tint} tinted pixels off the part"
    );
    // The highlight buffer marks the part (tint index 1) and the hovered part (bit 8).
    let buf = Buffers::parse(&viewer.get(&format!(
        "{base}/buffers?w={W}&h={H}&parts={pid}&hover={pid}&buffers=ids,color"
    )));
    assert!(buf.header["buffers"].as_array().unwrap().len() == 5);
    let (hl, vx) = (buf.words("highlight"), buf.words("vertex"));
    let set: HashSet<u32> = ids.iter().copied().collect();
    let (mut in_part, mut marked) = (0, 0);
    for (m, v) in hl.iter().zip(&vx) {
        if set.contains(v) {
            in_part += 1;
            if m & 0xFF == 1 && m & (1 << 8) != 0 {
                marked += 1;
            }
        }
    }
    assert!(
        in_part > 200 && marked * 10 >= in_part * 9,
        "{marked}/{in_part}"
    );

    // Callouts: the part's title (its first content) as JSON, and drawn into the image.
    let content = create_content(&editor, "Left paw", "A *casting seam*.");
    let r = editor.post(
        &format!("/api/v1/parts/{pid}/contents"),
        &json!({"content_id": content["id"]}),
    );
    assert!(r.status == 200 || r.status == 201, "{}", r.text());
    let r = viewer.get(&format!("{base}/callouts?w=400&h=300&parts={pid}"));
    assert_eq!(r.status, 200, "{}", r.text());
    let layout = r.json();
    assert_eq!(layout["width"], 400);
    let callouts = layout["callouts"].as_array().unwrap();
    assert_eq!(callouts.len(), 1, "{layout}");
    assert_eq!(callouts[0]["part"], pid);
    assert_eq!(callouts[0]["title"], "Left paw");
    let label = &callouts[0]["label"];
    assert!(label["x"].as_f64().unwrap() >= 0.0 && label["w"].as_f64().unwrap() > 10.0);
    let all = viewer.get(&format!("{base}/callouts?w=400&h=300")).json();
    let n = all["callouts"].as_array().unwrap().len() + all["hidden"].as_array().unwrap().len();
    assert_eq!(n, 2, "every part of the model: {all}");
    let (_, _, no_labels) = png(&viewer.get(&format!("{base}?w=400&h=300&parts={pid}")));
    let (_, _, labels) = png(&viewer.get(&format!("{base}?w=400&h=300&parts={pid}&callouts=1")));
    assert!(differing(&no_labels, &labels) > 300, "callouts drawn");
    let r = viewer.get(&format!("{base}?w=400&h=300&parts={pid}&callouts=true"));
    assert_eq!(
        r.status,
        200,
        "callouts=true is a boolean too: {}",
        r.text()
    );

    // The best view and the thumbnail arrive in the background; the camera sees the part.
    let part = wait_part(&viewer, pid, |p| {
        p["camera"]["auto"] == true && p["thumbnail_attachment_id"].is_i64()
    });
    let thumb = part["thumbnail_attachment_id"].as_i64().unwrap();
    let img = viewer.get(&format!("/api/v1/attachments/{thumb}/download"));
    eprintln!("part: {part}");
    let (tw, th, tpx) = png(&img);
    assert_eq!((tw, th), (320, 240));
    assert!(covered(&tpx) > 320 * 240 / 10);
    let view = camera_query(&part["camera"]);
    let buf = Buffers::parse(&viewer.get(&format!(
        "{base}/buffers?{view}&w=160&h=120&parts={pid}&buffers=ids"
    )));
    let tint = buf
        .words("highlight")
        .iter()
        .filter(|m| *m & 0xFF == 1)
        .count();
    assert!(
        tint > 160 * 120 / 20,
        "the part covers {tint} pixels of its best view"
    );
    // The point part kept its camera and got a thumbnail.
    let p = wait_part(&viewer, point, |p| p["thumbnail_attachment_id"].is_i64());
    assert_eq!(p["camera"], own, "the client's camera is kept");
    // A new vertex set gives a new best view and thumbnail.
    let fewer: Vec<u32> = ids[..ids.len() / 2].to_vec();
    let r = editor.patch(
        &format!("/api/v1/parts/{pid}"),
        &json!({"vertex_ids": fewer}),
    );
    assert_eq!(r.status, 200, "{}", r.text());
    assert!(r.json()["thumbnail_attachment_id"].is_null());
    let again = wait_part(&viewer, pid, |p| {
        p["camera"]["auto"] == true
            && p["thumbnail_attachment_id"].is_i64()
            && p["thumbnail_attachment_id"] != thumb
    });
    assert_eq!(again["vertex_count"].as_u64(), Some(fewer.len() as u64));

    // Thumbnails on the pages: model list, model page, search results, content page.
    let mthumb = model["thumbnail_attachment_id"]
        .as_i64()
        .expect("model thumbnail");
    let list = viewer.get("/models").text();
    assert!(list.contains(&format!("/api/v1/attachments/{mthumb}/download")));
    let pthumb = again["thumbnail_attachment_id"].as_i64().unwrap();
    let page = viewer.get(&format!("/models/{model_id}")).text();
    assert!(
        page.contains(&format!("/api/v1/attachments/{pthumb}/download")),
        "part thumbnail on the model page"
    );
    let found = viewer.get("/search?q=paw").text();
    assert!(
        found.contains(&format!("/api/v1/attachments/{pthumb}/download")),
        "part thumbnail in search results"
    );
    let hits = viewer.get("/api/v1/search?q=paw").json();
    let link = &hits[0]["parts"][0];
    assert_eq!(link["thumbnail_attachment_id"], pthumb);
    assert_eq!(link["camera"], again["camera"]);

    // Bad parameters: 400 with a message naming the problem.
    for (query, word) in [
        ("w=0", "w"),
        ("w=100000", "w"),
        ("w=4096&h=4096", "pixels"),
        ("h=abc", "h"),
        ("eye=1,2", "eye"),
        ("eye=nan,0,0", "eye"),
        ("eye=1,2,inf", "eye"),
        ("eye=1,1,1&target=1,1,1", "differ"),
        ("target=0,0,0", "eye"),
        ("eye=0,0,5&target=0,0,0&up=0,0,1", "up"),
        ("up=0,0,0", "up"),
        ("fovy=0", "fovy"),
        ("fovy=179.5", "fovy"),
        ("fovy=NaN", "fovy"),
        ("format=gif", "format"),
        ("quality=0", "quality"),
        ("parts=abc", "parts"),
        ("parts=999999", "unknown part"),
        ("hover=-3", "hover"),
        ("hover=999999", "unknown part"),
        ("px=0", "px"),
        ("callouts=maybe", "callouts"),
        // One rule for booleans: 1/0/true/false, as `callouts=2` and `yes` alike are refused.
        ("callouts=yes", "callouts"),
        ("callouts=2", "callouts"),
        ("buffers=normal", "buffers"),
        ("colour=red", "unknown field"),
    ] {
        let msg = viewer.get(&format!("{base}?{query}")).assert_error(400);
        assert!(msg.contains(word), "{query}: {msg}");
    }
    for (query, word) in [("buffers=normal,rgb", "buffers"), ("format=png", "format")] {
        let msg = viewer
            .get(&format!("{base}/buffers?{query}"))
            .assert_error(400);
        assert!(msg.contains(word), "{query}: {msg}");
    }
    let many: Vec<String> = (1..=70).map(|i| i.to_string()).collect();
    viewer
        .get(&format!("{base}?parts={}", many.join(",")))
        .assert_error(400);
    // Another model's part.
    let other = admin.post(
        "/api/v1/models",
        &json!({"title": "Empty", "description": ""}),
    );
    assert_eq!(other.status, 201, "{}", other.text());
    let other_id = other.json()["id"].as_i64().unwrap();
    // Unknown model 404, model not built 409, no session 401.
    viewer.get("/api/v1/models/999999/render").assert_error(404);
    viewer
        .get("/api/v1/models/999999/render/buffers")
        .assert_error(404);
    let msg = viewer
        .get(&format!("/api/v1/models/{other_id}/render"))
        .assert_error(409);
    assert!(msg.contains("pending"), "{msg}");
    viewer
        .get(&format!("/api/v1/models/{other_id}/render/callouts"))
        .assert_error(409);
    server.client().get(&base).assert_error(401);
    server
        .client()
        .get(&format!("{base}/buffers"))
        .assert_error(401);
    server
        .client()
        .get(&format!("{base}/callouts"))
        .assert_error(401);
}

#[test]
fn twenty_concurrent_renders_are_answered_within_bounds() {
    let dir = data_dir_with_admin();
    let scans = tempfile::tempdir().unwrap();
    let file = scan(scans.path());
    let model_id = import(dir.path(), &file, "Scan");
    let server = Server::start_with(
        dir.path(),
        &["--render-workers", "2", "--render-queue", "4"],
    );
    let pid = server.child.id();
    let viewer = server.login("admin", ADMIN_PASSWORD);
    let url = format!("/api/v1/models/{model_id}/render?w=1024&h=768");
    // Warm up: device, model, cache.
    png(&viewer.get(&url));
    let before = vm_rss_kb(pid);
    let mut peak = before;
    for wave in 0..2 {
        let barrier = std::sync::Arc::new(std::sync::Barrier::new(20));
        let handles: Vec<_> = (0..20)
            .map(|i| {
                let (c, b) = (viewer.clone(), barrier.clone());
                let url = format!("{url}&px={}", 1.0 + (i % 3) as f32 * 0.5);
                std::thread::spawn(move || {
                    b.wait();
                    c.get(&url)
                })
            })
            .collect();
        let (mut ok, mut busy) = (0, 0);
        for h in handles {
            let r = h.join().expect("client thread");
            match r.status {
                200 => {
                    let (w, h, _) = png(&r);
                    assert_eq!((w, h), (1024, 768));
                    ok += 1;
                }
                503 => {
                    let msg = r.assert_error(503);
                    assert!(msg.contains("queue"), "{msg}");
                    let retry: u64 = r
                        .header("retry-after")
                        .expect("Retry-After")
                        .parse()
                        .expect("seconds");
                    assert!((1..=60).contains(&retry));
                    busy += 1;
                }
                s => panic!("status {s}: {}", r.text()),
            }
            peak = peak.max(vm_rss_kb(pid));
        }
        let rss = vm_rss_kb(pid);
        eprintln!(
            "wave {wave}: {ok} images, {busy} busy; VmRSS {} MB before, {} MB after",
            before / 1024,
            rss / 1024
        );
        assert_eq!(ok + busy, 20);
        assert!(ok >= 2, "the workers rendered");
        assert!(
            busy >= 1,
            "a queue of 4 behind 2 workers turns some of 20 away"
        );
    }
    // Still serving, memory bounded by the pool's budget (768 MiB) and the cache (256 MiB).
    png(&viewer.get(&url));
    assert_eq!(viewer.get("/api/v1/health").status, 200);
    let after = vm_rss_kb(pid);
    eprintln!(
        "VmRSS before {} MB, peak {} MB, after {} MB",
        before / 1024,
        peak / 1024,
        after / 1024
    );
    assert!(
        after < before + 1024 * 1024,
        "RSS grew from {before} kB to {after} kB"
    );
}

#[test]
fn without_an_adapter_renders_answer_503_and_the_rest_works() {
    let dir = data_dir_with_admin();
    let scans = tempfile::tempdir().unwrap();
    let ply = relief_ply(scans.path(), "small.ply", 2_000);
    let model_id = import(dir.path(), &ply, "Small");
    let server = Server::start_with(dir.path(), &["--render-adapter", "none"]);
    let c = server.login("admin", ADMIN_PASSWORD);
    for route in ["render", "render/buffers", "render/callouts"] {
        let r = c.get(&format!("/api/v1/models/{model_id}/{route}"));
        let msg = r.assert_error(503);
        assert!(msg.contains("rendering is unavailable"), "{msg}");
    }
    // Bad parameters are still 400, and everything else is served.
    c.get(&format!("/api/v1/models/{model_id}/render?w=0"))
        .assert_error(400);
    assert_eq!(c.get(&format!("/api/v1/models/{model_id}/lod")).status, 200);
    assert_eq!(c.get("/models").status, 200);
}
