//! The real server over HTTP, as the viewer and the tests drive it: session login with its
//! CSRF token, selections as multipart `request` + `mask` (`src/web/selections.rs`), drafts'
//! vertex sets, render buffers in the `MWRB` layout of `src/web/render.rs`.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use meshwiki_engine::camera::Camera;
use meshwiki_engine::lod::Grid;
use roaring::RoaringBitmap;
use serde_json::{Value, json};

/// A logged-in API client.
pub struct Api {
    agent: ureq::Agent,
    base: String,
    cookie: String,
    csrf: String,
}

/// A response: status and body.
struct Resp {
    status: u16,
    retry_after: Option<u64>,
    body: Vec<u8>,
}

impl Resp {
    fn text(&self) -> String {
        let t = String::from_utf8_lossy(&self.body);
        serde_json::from_str::<Value>(&t)
            .ok()
            .and_then(|v| v["error"].as_str().map(str::to_string))
            .unwrap_or_else(|| t.chars().take(300).collect())
    }
}

/// A selection draft the server made.
#[derive(Debug, Clone)]
pub struct Draft {
    pub id: String,
    pub vertex_count: u64,
    /// Wall time of the POST (strokes in, draft out), milliseconds.
    pub latency_ms: f64,
    /// The server's own timings of it.
    pub stages: Stages,
}

/// The server's timings of one selection (its `timings_ms`), milliseconds.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Stages {
    pub render: f64,
    pub seeds: f64,
    pub graph: f64,
    pub maxflow: f64,
    pub backproject: f64,
    pub total: f64,
}

impl Stages {
    /// The stages as `(name, milliseconds)`, in the order they run.
    pub fn named(&self) -> [(&'static str, f64); 6] {
        [
            ("render", self.render),
            ("seeds", self.seeds),
            ("graph", self.graph),
            ("max-flow", self.maxflow),
            ("back-proj.", self.backproject),
            ("server", self.total),
        ]
    }

    fn of(v: &Value) -> Stages {
        let t = &v["timings_ms"];
        let f = |k: &str| t[k].as_f64().unwrap_or(f64::NAN);
        Stages {
            render: f("render"),
            seeds: f("seeds"),
            graph: f("graph"),
            maxflow: f("maxflow"),
            backproject: f("backproject"),
            total: f("total"),
        }
    }
}

/// The camera of a request, as the selection API takes it.
pub fn camera_json(c: &Camera) -> Value {
    json!({"eye": c.eye.to_array(), "target": c.target.to_array(), "up": c.up.to_array(),
           "fovy": c.fovy_deg, "width": c.width, "height": c.height})
}

fn vec3(v: Vec3) -> String {
    format!("{},{},{}", v.x, v.y, v.z)
}

impl Api {
    /// Logs in as `user` (`POST /api/v1/session`).
    pub fn login(base: &str, user: &str, password: &str) -> Result<Api> {
        let config = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .max_redirects(0)
            .timeout_global(Some(Duration::from_secs(300)))
            .build();
        let mut api = Api {
            agent: ureq::Agent::new_with_config(config),
            base: base.to_string(),
            cookie: String::new(),
            csrf: String::new(),
        };
        let body = json!({"username": user, "password": password}).to_string();
        let req = ureq::http::Request::builder()
            .method("POST")
            .uri(format!("{base}/api/v1/session"))
            .header("Content-Type", "application/json")
            .body(body.into_bytes())?;
        let resp = api.agent.run(req).context("POST /api/v1/session")?;
        let status = resp.status().as_u16();
        let cookie = resp
            .headers()
            .get_all("set-cookie")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .find(|v| v.starts_with("meshwiki_session="))
            .map(|v| v.split(';').next().unwrap_or("").to_string());
        let body = resp.into_body().read_to_vec()?;
        if status != 200 {
            bail!(
                "login failed ({status}): {}",
                String::from_utf8_lossy(&body)
            );
        }
        let v: Value = serde_json::from_slice(&body).context("login answer")?;
        api.csrf = v["csrf_token"]
            .as_str()
            .context("no csrf_token in the login answer")?
            .to_string();
        api.cookie = cookie.context("no session cookie in the login answer")?;
        Ok(api)
    }

    fn send(&self, method: &str, path: &str, ct: Option<&str>, body: Vec<u8>) -> Result<Resp> {
        // A full render queue answers 503 with Retry-After: wait and retry a few times.
        let mut attempt = 0;
        loop {
            let mut b = ureq::http::Request::builder()
                .method(method)
                .uri(format!("{}{path}", self.base))
                .header("Cookie", self.cookie.as_str())
                .header("X-CSRF-Token", self.csrf.as_str());
            if let Some(ct) = ct {
                b = b.header("Content-Type", ct);
            }
            let resp = self
                .agent
                .run(b.body(body.clone())?)
                .with_context(|| format!("{method} {path}"))?;
            let status = resp.status().as_u16();
            let retry_after = resp
                .headers()
                .get("retry-after")
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.parse().ok());
            let body = resp
                .into_body()
                .with_config()
                .limit(512 << 20)
                .read_to_vec()
                .with_context(|| format!("{method} {path}: reading the answer"))?;
            let r = Resp {
                status,
                retry_after,
                body,
            };
            if let (503, Some(wait)) = (r.status, r.retry_after)
                && attempt < 5
            {
                attempt += 1;
                std::thread::sleep(Duration::from_secs(wait.clamp(1, 10)));
                continue;
            }
            return Ok(r);
        }
    }

    /// Per pixel, the original vertex id drawn there (`u32::MAX` on the background), from
    /// `GET /api/v1/models/{id}/render/buffers?buffers=ids`.
    pub fn vertex_ids(&self, model: i64, c: &Camera) -> Result<Vec<u32>> {
        let path = format!(
            "/api/v1/models/{model}/render/buffers?eye={}&target={}&up={}&fovy={}&w={}&h={}&buffers=ids",
            vec3(c.eye),
            vec3(c.target),
            vec3(c.up),
            c.fovy_deg,
            c.width,
            c.height
        );
        let r = self.send("GET", &path, None, Vec::new())?;
        if r.status != 200 {
            bail!("GET {path}: {} {}", r.status, r.text());
        }
        parse_vertex_buffer(&r.body, c.width as usize * c.height as usize)
    }

    /// `POST /api/v1/models/{id}/selections` with `tool` and the stroke mask PNG; with `base`
    /// (a previous draft) the strokes are subtracted from it. `Ok(Err)` is the server's
    /// refusal (a 4xx and its message).
    pub fn select(
        &self,
        model: i64,
        tool: &str,
        params: Option<&Value>,
        camera: &Camera,
        mask_png: &[u8],
        base: Option<&str>,
    ) -> Result<std::result::Result<Draft, String>> {
        let boundary = "----meshwikibenchselect4b1d";
        let mut request = json!({"tool": tool, "camera": camera_json(camera)});
        if let Some(p) = params {
            request["params"] = p.clone();
        }
        if let Some(b) = base {
            request["mode"] = json!("subtract");
            request["base"] = json!(b);
        }
        let mut body = format!(
            "--{boundary}\r\nContent-Disposition: form-data; name=\"request\"\r\n\
             Content-Type: application/json\r\n\r\n{request}\r\n--{boundary}\r\n\
             Content-Disposition: form-data; name=\"mask\"; filename=\"mask.png\"\r\n\
             Content-Type: image/png\r\n\r\n"
        )
        .into_bytes();
        body.extend_from_slice(mask_png);
        body.extend_from_slice(format!("\r\n--{boundary}--\r\n").as_bytes());
        let path = format!("/api/v1/models/{model}/selections");
        let started = Instant::now();
        let r = self.send(
            "POST",
            &path,
            Some(&format!("multipart/form-data; boundary={boundary}")),
            body,
        )?;
        let latency_ms = started.elapsed().as_secs_f64() * 1e3;
        match r.status {
            201 => {
                let v: Value = serde_json::from_slice(&r.body).context("selection answer")?;
                Ok(Ok(Draft {
                    id: v["id"].as_str().context("no draft id")?.to_string(),
                    vertex_count: v["vertex_count"].as_u64().unwrap_or(0),
                    latency_ms,
                    stages: Stages::of(&v),
                }))
            }
            400..=499 => Ok(Err(format!("{}: {}", r.status, r.text()))),
            s => bail!("POST {path}: {s} {}", r.text()),
        }
    }

    /// The draft's selected pixels as a PNG (`GET /api/v1/selections/{draft}/mask`).
    pub fn selection_png(&self, draft: &str) -> Result<Vec<u8>> {
        let path = format!("/api/v1/selections/{draft}/mask");
        let r = self.send("GET", &path, None, Vec::new())?;
        if r.status != 200 {
            bail!("GET {path}: {} {}", r.status, r.text());
        }
        Ok(r.body)
    }

    /// The draft's vertex set (`GET /api/v1/selections/{draft}/vertices`).
    pub fn vertices(&self, draft: &str) -> Result<RoaringBitmap> {
        let path = format!("/api/v1/selections/{draft}/vertices");
        let r = self.send("GET", &path, None, Vec::new())?;
        if r.status != 200 {
            bail!("GET {path}: {} {}", r.status, r.text());
        }
        RoaringBitmap::deserialize_from(&r.body[..])
            .with_context(|| format!("GET {path}: not a serialised RoaringBitmap"))
    }

    /// The quantisation grid of the model's LOD file (`GET /api/v1/models/{id}/lod`), which
    /// its vertex numbering is defined on.
    pub fn lod_grid(&self, model: i64) -> Result<Grid> {
        let path = format!("/api/v1/models/{model}/lod");
        let r = self.send("GET", &path, None, Vec::new())?;
        if r.status != 200 {
            bail!("GET {path}: {} {}", r.status, r.text());
        }
        let v: Value = serde_json::from_slice(&r.body).context("lod answer")?;
        let origin: [f64; 3] =
            serde_json::from_value(v["grid"]["origin"].clone()).context("no grid origin")?;
        let step = v["grid"]["step"].as_f64().context("no grid step")?;
        Ok(Grid { origin, step })
    }

    /// The model's segment counts per scale, finest first, and the suggested scale
    /// (`GET /api/v1/models/{id}/segments`).
    pub fn segment_scales(&self, model: i64) -> Result<(Vec<u32>, usize)> {
        let path = format!("/api/v1/models/{model}/segments");
        let r = self.send("GET", &path, None, Vec::new())?;
        if r.status != 200 {
            bail!("GET {path}: {} {}", r.status, r.text());
        }
        let v: Value = serde_json::from_slice(&r.body).context("segments answer")?;
        let counts = v["scales"]
            .as_array()
            .context("no scales")?
            .iter()
            .map(|s| s["segments"].as_u64().map(|n| n as u32))
            .collect::<Option<Vec<u32>>>()
            .context("a scale without a count")?;
        let suggested = v["suggested_scale"]
            .as_u64()
            .context("no suggested scale")? as usize;
        Ok((counts, suggested))
    }

    /// The segment at `scale` holding original vertex `vertex` (`None`: it is in none), from
    /// `GET /api/v1/models/{id}/segments/{scale}/vertices?vertex=V`.
    pub fn segment_of(
        &self,
        model: i64,
        scale: usize,
        vertex: u32,
    ) -> Result<Option<RoaringBitmap>> {
        let path = format!("/api/v1/models/{model}/segments/{scale}/vertices?vertex={vertex}");
        let r = self.send("GET", &path, None, Vec::new())?;
        match r.status {
            200 => RoaringBitmap::deserialize_from(&r.body[..])
                .map(Some)
                .with_context(|| format!("GET {path}: not a serialised RoaringBitmap")),
            404 => Ok(None),
            s => bail!("GET {path}: {s} {}", r.text()),
        }
    }

    /// Discards a draft (`DELETE /api/v1/selections/{draft}`).
    pub fn discard(&self, draft: &str) -> Result<()> {
        let path = format!("/api/v1/selections/{draft}");
        let r = self.send("DELETE", &path, None, Vec::new())?;
        if r.status != 204 {
            tracing::warn!(status = r.status, "DELETE {path}: {}", r.text());
        }
        Ok(())
    }
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// The `vertex` array of a render buffers body (`MWRB`, version 1).
pub fn parse_vertex_buffer(body: &[u8], pixels: usize) -> Result<Vec<u32>> {
    if body.get(0..4) != Some(b"MWRB") || u32_at(body, 4) != Some(1) {
        bail!("the render buffers answer is not MWRB version 1");
    }
    let len = u32_at(body, 8).context("truncated buffers header")? as usize;
    let header = body.get(12..12 + len).context("truncated buffers header")?;
    let header: Value = serde_json::from_slice(header).context("buffers header")?;
    let entry = header["buffers"]
        .as_array()
        .and_then(|l| l.iter().find(|e| e["name"] == "vertex"))
        .context("no vertex buffer in the answer")?;
    let offset = entry["offset"].as_u64().context("vertex buffer offset")? as usize;
    let bytes = entry["bytes"].as_u64().context("vertex buffer size")? as usize;
    if bytes != pixels * 4 {
        bail!("the vertex buffer has {bytes} bytes for {pixels} pixels");
    }
    let data = body
        .get(offset..offset + bytes)
        .context("truncated vertex buffer")?;
    Ok(data
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertex_buffer_layout() {
        let header = json!({"buffers": [
            {"name": "node", "type": "u32", "components": 1, "offset": 1000, "bytes": 8},
            {"name": "vertex", "type": "u32", "components": 1, "offset": 1008, "bytes": 8}]})
        .to_string();
        let mut body = b"MWRB".to_vec();
        body.extend_from_slice(&1u32.to_le_bytes());
        let padded = header.len().div_ceil(4) * 4;
        body.extend_from_slice(&(padded as u32).to_le_bytes());
        body.extend_from_slice(header.as_bytes());
        body.resize(12 + padded, b' ');
        body.resize(1008, 0);
        body.extend_from_slice(&7u32.to_le_bytes());
        body.extend_from_slice(&u32::MAX.to_le_bytes());
        // The fixture's offsets assume a header that fits before byte 1000.
        assert!(12 + padded <= 1000);
        assert_eq!(parse_vertex_buffer(&body, 2).unwrap(), vec![7, u32::MAX]);
        assert!(parse_vertex_buffer(&body, 3).is_err());
        assert!(parse_vertex_buffer(b"MWRX", 2).is_err());
    }
}
