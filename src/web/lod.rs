//! Serving a model's LOD hierarchy (`docs/FORMAT.md`, "HTTP"): the DAG as JSON or as the
//! file's header and tables, one patch blob, or the whole file, with `ETag`, `If-None-Match`
//! (304) and single byte ranges (206; 416 when unsatisfiable; a malformed or multiple range is
//! ignored: 200). Anyone logged in reads.
//!
//! Files are opened through the application's model registry ([`crate::app::models`]), shared
//! with rendering and selection: a rebuilt model is reopened; memory maps of replaced files
//! stay valid until dropped.

use std::sync::Arc;

use actix_web::body::SizedStream;
use actix_web::http::{StatusCode, header};
use actix_web::{HttpRequest, HttpResponse, web};
use meshwiki_engine::lod::{FormatError, LodFile, NO_GROUP};
use serde::{Deserialize, Serialize};

use super::auth::Auth;
use super::{ApiError, AppState};
use crate::app::models::{OpenModel, Purpose};

/// Bodies up to this size are copied in one piece; larger ones stream.
const SMALL_BODY: usize = 1 << 20;
/// Chunk of a streamed body.
const CHUNK: usize = 256 << 10;
/// `Cache-Control` of patch blobs (immutable: a node's blob never changes for a model).
pub const IMMUTABLE: &str = "public, max-age=31536000, immutable";
/// `Cache-Control` of the hierarchy and the whole file (revalidated with the ETag).
const REVALIDATE: &str = "private, no-cache";

/// Mounts the routes.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/models/{id}/lod").route(web::get().to(hierarchy)))
        .service(
            super::resource("/api/v1/models/{id}/lod/patches/{node}").route(web::get().to(patch)),
        )
        .service(super::resource("/api/v1/models/{id}/lod/file").route(web::get().to(file)));
}

fn lod_error(e: FormatError) -> ApiError {
    ApiError::internal(format!("LOD file unreadable: {e}"))
}

// ---- JSON encoding -------------------------------------------------------------------------

#[derive(Serialize)]
struct BBoxJson {
    min: [f32; 3],
    max: [f32; 3],
}

#[derive(Serialize)]
struct GridJson {
    origin: [f64; 3],
    step: f64,
}

#[derive(Serialize)]
struct NodeJson {
    id: u32,
    level: u32,
    triangles: u32,
    vertices: u32,
    bounds: [f32; 4],
    cone: [f32; 4],
    lod_sphere: [f32; 4],
    lod_error: f32,
    parent_sphere: [f32; 4],
    parent_error: Option<f32>,
    producer: Option<u32>,
    member_of: Option<u32>,
    offset: u64,
    length: u32,
    crc32: u32,
}

#[derive(Serialize)]
struct GroupJson<'a> {
    id: u32,
    level: u32,
    sphere: [f32; 4],
    error: f32,
    members: &'a [u32],
    products: &'a [u32],
}

#[derive(Serialize)]
struct HierarchyJson<'a> {
    version: u32,
    node_count: u32,
    group_count: u32,
    level_count: u32,
    root_count: u32,
    max_patch_triangles: u32,
    input_vertices: u64,
    input_triangles: u64,
    bbox: BBoxJson,
    grid: GridJson,
    has_colors: bool,
    has_normals: bool,
    file_bytes: u64,
    nodes: Vec<NodeJson>,
    groups: Vec<GroupJson<'a>>,
}

fn group_ref(g: u32) -> Option<u32> {
    (g != NO_GROUP).then_some(g)
}

/// The hierarchy of `lod` as the JSON of `docs/FORMAT.md`.
pub fn hierarchy_json(lod: &LodFile) -> Result<Vec<u8>, serde_json::Error> {
    let h = lod.header();
    let nodes = lod
        .nodes()
        .iter()
        .enumerate()
        .map(|(i, n)| NodeJson {
            id: i as u32,
            level: n.level,
            triangles: n.triangle_count,
            vertices: n.vertex_count,
            bounds: n.bounds,
            cone: n.cone,
            lod_sphere: n.lod_sphere,
            lod_error: n.lod_error,
            parent_sphere: n.parent_sphere,
            parent_error: n.parent_error.is_finite().then_some(n.parent_error),
            producer: group_ref(n.producer),
            member_of: group_ref(n.member_of),
            offset: n.blob_offset,
            length: n.blob_len,
            crc32: n.blob_crc,
        })
        .collect();
    let groups = lod
        .groups()
        .iter()
        .enumerate()
        .map(|(i, g)| GroupJson {
            id: i as u32,
            level: g.level,
            sphere: g.sphere,
            error: g.error,
            members: lod.members(g),
            products: lod.products(g),
        })
        .collect();
    serde_json::to_vec(&HierarchyJson {
        version: h.version,
        node_count: h.node_count,
        group_count: h.group_count,
        level_count: h.level_count,
        root_count: h.root_count,
        max_patch_triangles: h.max_patch_triangles,
        input_vertices: h.input_vertex_count,
        input_triangles: h.input_triangle_count,
        bbox: BBoxJson {
            min: h.bbox_min,
            max: h.bbox_max,
        },
        grid: GridJson {
            origin: h.grid_origin,
            step: h.grid_step,
        },
        has_colors: lod.has_colors(),
        has_normals: lod.has_normals(),
        file_bytes: lod.bytes().len() as u64,
        nodes,
        groups,
    })
}

// ---- conditional and range requests -----------------------------------------------------

/// Whether `If-None-Match` names `etag` (or `*`).
fn not_modified(req: &HttpRequest, etag: &str) -> bool {
    let Some(v) = req
        .headers()
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
    else {
        return false;
    };
    v.split(',').any(|t| {
        let t = t.trim();
        t == "*" || t.trim_start_matches("W/") == etag
    })
}

/// A requested byte range, `[start, end)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ByteRange {
    /// First byte.
    pub start: u64,
    /// One past the last byte.
    pub end: u64,
}

/// Why a `Range` header cannot be served.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BadRange(pub String);

/// Parses a `Range` header against a body of `len` bytes (RFC 9110 §14.2): `None` to serve the
/// whole body (no header; a unit other than bytes; a malformed header, or several ranges, which
/// this server does not combine: the RFC lets a server ignore those), a range, or why a
/// well-formed single range cannot be satisfied (it starts beyond the end; an empty suffix).
pub fn parse_range(value: Option<&str>, len: u64) -> Result<Option<ByteRange>, BadRange> {
    let Some(v) = value else { return Ok(None) };
    let v = v.trim();
    let Some((unit, spec)) = v.split_once('=') else {
        return Ok(None);
    };
    if !unit.trim().eq_ignore_ascii_case("bytes") {
        return Ok(None);
    }
    let spec = spec.trim();
    if spec.contains(',') {
        return Ok(None);
    }
    let Some((a, b)) = spec.split_once('-') else {
        return Ok(None);
    };
    let (a, b) = (a.trim(), b.trim());
    let num = |s: &str| {
        if !s.is_empty() && s.bytes().all(|c| c.is_ascii_digit()) {
            s.parse::<u64>().ok()
        } else {
            None
        }
    };
    let range = if a.is_empty() {
        let Some(n) = num(b) else { return Ok(None) };
        if n == 0 || len == 0 {
            return Err(BadRange(format!(
                "range {spec:?} is empty or beyond the {len} bytes"
            )));
        }
        ByteRange {
            start: len.saturating_sub(n),
            end: len,
        }
    } else {
        let Some(start) = num(a) else { return Ok(None) };
        let end = if b.is_empty() {
            len
        } else {
            match num(b) {
                Some(last) if last >= start => last.saturating_add(1).min(len),
                // Not a valid range-spec (a last position before the first, or no number).
                _ => return Ok(None),
            }
        };
        if start >= len {
            return Err(BadRange(format!(
                "range {spec:?} starts beyond the {len} bytes"
            )));
        }
        ByteRange { start, end }
    };
    Ok(Some(range))
}

/// Serves `body` (a slice of an open file) with caching headers, `If-None-Match`, `If-Range`
/// and `Range`.
fn serve_bytes(
    req: &HttpRequest,
    open: Arc<OpenModel>,
    start: usize,
    end: usize,
    etag: &str,
    cache: &str,
) -> HttpResponse {
    let len = (end - start) as u64;
    if not_modified(req, etag) {
        return HttpResponse::NotModified()
            .insert_header((header::ETAG, etag.to_string()))
            .insert_header((header::CACHE_CONTROL, cache.to_string()))
            .finish();
    }
    let if_range_ok = req
        .headers()
        .get(header::IF_RANGE)
        .and_then(|v| v.to_str().ok())
        .is_none_or(|v| v.trim() == etag);
    let range_header = req
        .headers()
        .get(header::RANGE)
        .and_then(|v| v.to_str().ok())
        .filter(|_| if_range_ok);
    let (status, from, to) = match parse_range(range_header, len) {
        Ok(None) => (StatusCode::OK, 0, len),
        Ok(Some(r)) => (StatusCode::PARTIAL_CONTENT, r.start, r.end),
        Err(BadRange(msg)) => {
            return HttpResponse::RangeNotSatisfiable()
                .insert_header((header::CONTENT_RANGE, format!("bytes */{len}")))
                .insert_header((header::CACHE_CONTROL, "no-store"))
                .json(serde_json::json!({ "error": msg }));
        }
    };
    let mut resp = HttpResponse::build(status);
    resp.insert_header((header::CONTENT_TYPE, "application/octet-stream"))
        .insert_header((header::ETAG, etag.to_string()))
        .insert_header((header::CACHE_CONTROL, cache.to_string()))
        .insert_header((header::ACCEPT_RANGES, "bytes"))
        // Patches are compressed already; never gzip (it would also break byte ranges).
        .insert_header((header::CONTENT_ENCODING, "identity"));
    if status == StatusCode::PARTIAL_CONTENT {
        resp.insert_header((
            header::CONTENT_RANGE,
            format!("bytes {from}-{}/{len}", to - 1),
        ));
    }
    let (a, b) = (start + from as usize, start + to as usize);
    if b - a <= SMALL_BODY {
        return resp.body(web::Bytes::copy_from_slice(&open.lod.bytes()[a..b]));
    }
    let stream = futures_util::stream::unfold(a, move |pos| {
        let open = open.clone();
        async move {
            if pos >= b {
                return None;
            }
            let next = (pos + CHUNK).min(b);
            let chunk = web::Bytes::copy_from_slice(&open.lod.bytes()[pos..next]);
            Some((Ok::<_, std::io::Error>(chunk), next))
        }
    });
    resp.body(SizedStream::new((b - a) as u64, Box::pin(stream)))
}

// ---- handlers ------------------------------------------------------------------------------

/// `?format=` of the hierarchy route.
#[derive(Debug, Deserialize)]
pub struct FormatQuery {
    /// `json` (default) or `binary`.
    pub format: Option<String>,
}

async fn hierarchy(
    state: web::Data<AppState>,
    _auth: Auth,
    req: HttpRequest,
    id: web::Path<i64>,
    q: web::Query<FormatQuery>,
) -> Result<HttpResponse, ApiError> {
    let binary = match q.format.as_deref().map(str::trim) {
        None | Some("") | Some("json") => false,
        Some("binary") => true,
        Some(other) => {
            return Err(ApiError::bad(format!(
                "unknown format {other:?}: use json or binary"
            )));
        }
    };
    let open = state.models.open(&state.db, *id, Purpose::Serve).await?;
    if binary {
        let end = open.lod.header().blobs_offset as usize;
        let etag = open.etag.clone();
        return Ok(serve_bytes(&req, open, 0, end, &etag, REVALIDATE));
    }
    let etag = format!("\"{}-json\"", open.etag.trim_matches('"'));
    if not_modified(&req, &etag) {
        return Ok(HttpResponse::NotModified()
            .insert_header((header::ETAG, etag))
            .insert_header((header::CACHE_CONTROL, REVALIDATE))
            .finish());
    }
    let body = match open.json.get() {
        Some(b) => b.clone(),
        None => {
            let o = open.clone();
            let bytes = web::block(move || hierarchy_json(&o.lod))
                .await
                .map_err(ApiError::internal)?
                .map_err(ApiError::internal)?;
            open.json.get_or_init(|| web::Bytes::from(bytes)).clone()
        }
    };
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "application/json"))
        .insert_header((header::ETAG, etag))
        .insert_header((header::CACHE_CONTROL, REVALIDATE))
        .body(body))
}

async fn patch(
    state: web::Data<AppState>,
    _auth: Auth,
    req: HttpRequest,
    path: web::Path<(i64, u32)>,
) -> Result<HttpResponse, ApiError> {
    let (id, node) = path.into_inner();
    let open = state.models.open(&state.db, id, Purpose::Serve).await?;
    let count = open.lod.header().node_count;
    let record = *open.lod.node(node).map_err(|_| {
        ApiError::NotFound(format!(
            "patch {node} not found: model {id} has {count} patches (0 to {})",
            count.saturating_sub(1)
        ))
    })?;
    open.lod.blob(node).map_err(lod_error)?;
    let etag = format!("\"{:08x}\"", record.blob_crc);
    let start = record.blob_offset as usize;
    let end = start + record.blob_len as usize;
    Ok(serve_bytes(&req, open, start, end, &etag, IMMUTABLE))
}

async fn file(
    state: web::Data<AppState>,
    _auth: Auth,
    req: HttpRequest,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    let open = state.models.open(&state.db, *id, Purpose::Serve).await?;
    let end = open.lod.bytes().len();
    let etag = open.etag.clone();
    Ok(serve_bytes(&req, open, 0, end, &etag, REVALIDATE))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges() {
        let r = |s: &str| parse_range(Some(s), 100);
        assert_eq!(r("bytes=0-9"), Ok(Some(ByteRange { start: 0, end: 10 })));
        assert_eq!(
            r("bytes=90-"),
            Ok(Some(ByteRange {
                start: 90,
                end: 100
            }))
        );
        assert_eq!(
            r("bytes=-10"),
            Ok(Some(ByteRange {
                start: 90,
                end: 100
            }))
        );
        assert_eq!(r("bytes=-1000"), Ok(Some(ByteRange { start: 0, end: 100 })));
        assert_eq!(
            r("bytes=50-5000"),
            Ok(Some(ByteRange {
                start: 50,
                end: 100
            }))
        );
        assert_eq!(parse_range(None, 100), Ok(None));
        assert_eq!(r("items=0-1"), Ok(None));
        // Malformed or several ranges: ignored, the whole body is served.
        for ignored in [
            "bytes=9-1",
            "bytes=a-b",
            "bytes=abc",
            "bytes=0-1,5-6",
            "bytes",
            "bytes=--1",
            "bytes=+1-2",
            "bytes=1-x",
        ] {
            assert_eq!(r(ignored), Ok(None), "{ignored}");
        }
        // Well-formed but unsatisfiable: 416.
        for bad in ["bytes=100-", "bytes=200-300", "bytes=-0"] {
            assert!(r(bad).is_err(), "{bad}");
        }
        assert!(parse_range(Some("bytes=-5"), 0).is_err());
    }

    /// Deterministic mutation of real `Range` headers (issue 14 §8): no panic, every range
    /// served lies inside the body, and only well-formed single ranges are ever refused.
    #[test]
    fn mutated_ranges_stay_inside_the_body() {
        let seeds = [
            "bytes=0-9",
            "bytes=4-13",
            "bytes=-8",
            "bytes=100-",
            "bytes=0-1,4-5",
        ];
        let pieces = [
            "",
            "0",
            "-",
            ",",
            " ",
            "=",
            "bytes",
            "99999999999999999999",
            "18446744073709551615",
            "18446744073709551616",
            "+",
            "abc",
            "\t",
        ];
        let mut rng = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = |n: usize| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng % n as u64) as usize
        };
        let (mut served, mut whole, mut refused) = (0u32, 0u32, 0u32);
        for case in 0..10_000 {
            let mut v = seeds[case % seeds.len()].to_string();
            for _ in 0..1 + next(3) {
                let at = next(v.len() + 1);
                if next(2) == 0 {
                    v.insert_str(at, pieces[next(pieces.len())]);
                } else {
                    let end = (at + next(4)).min(v.len());
                    v.replace_range(at..end, "");
                }
            }
            let len = [0u64, 1, 10, 100, u64::MAX][next(5)];
            match parse_range(Some(&v), len) {
                Ok(Some(r)) => {
                    served += 1;
                    assert!(r.start < r.end && r.end <= len, "{v:?} over {len}: {r:?}");
                }
                Ok(None) => whole += 1,
                Err(BadRange(msg)) => {
                    refused += 1;
                    assert!(!msg.is_empty() && !v.contains(','), "{v:?}: {msg}");
                }
            }
        }
        println!("ranges: 10000 cases, {served} served, {whole} whole body, {refused} refused");
        assert!(served > 0 && whole > 0 && refused > 0);
    }
}
