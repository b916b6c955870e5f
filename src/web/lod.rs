//! Serving a model's LOD hierarchy (`docs/FORMAT.md`, "HTTP"): the DAG as JSON or as the
//! file's header and tables, one patch blob, or the whole file, with `ETag`, `If-None-Match`
//! (304) and single byte ranges (206; 416 when unsatisfiable; a malformed or multiple range is
//! ignored: 200). Anyone logged in reads; of a model that keeps its geometry on the server
//! (`geometry_access` = `sparse`), only admins read patches finer than its sparse mesh and the
//! whole file (403 for everyone else).
//!
//! Files are opened through the application's model registry ([`crate::app::models`]), shared
//! with rendering and selection: a rebuilt model is reopened; memory maps of replaced files
//! stay valid until dropped.

use std::sync::Arc;

use actix_web::body::SizedStream;
use actix_web::http::{StatusCode, header};
use actix_web::{HttpRequest, HttpResponse, web};
use meshwiki_engine::lod::{FormatError, LodFile, NO_GROUP, VertexOrder};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

use super::auth::Reader;
use super::{ApiError, AppState};
use crate::app::lumigraph::{GeometryGrant, sparse_refusal};
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

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(hierarchy, patch, file))]
pub(super) struct Api;

fn lod_error(e: FormatError) -> ApiError {
    ApiError::internal(format!("LOD file unreadable: {e}"))
}

// ---- JSON encoding -------------------------------------------------------------------------

/// Axis-aligned bounding box of the model (from the file's header).
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = LodBBox)]
pub struct BBoxJson {
    /// Minimum corner x, y, z.
    pub min: [f32; 3],
    /// Maximum corner x, y, z.
    pub max: [f32; 3],
}

/// The quantisation grid: world = `origin` + `step` × grid coordinate.
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = LodGrid)]
pub struct GridJson {
    /// Grid origin x, y, z.
    pub origin: [f64; 3],
    /// Grid step (world units).
    pub step: f64,
}

/// One node (patch) of the DAG. Spheres and bounds are `[x, y, z, r]`.
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = LodNode)]
pub struct NodeJson {
    /// Node id (its index; patches are in locality order, coarse levels first).
    pub id: u32,
    /// Level (0 = leaf).
    pub level: u32,
    /// Triangle count.
    pub triangles: u32,
    /// Vertex count.
    pub vertices: u32,
    /// Tight bounding sphere x, y, z, radius (culling).
    pub bounds: [f32; 4],
    /// Normal cone: axis x, y, z, cutoff (cutoff 1 = never back-facing).
    pub cone: [f32; 4],
    /// Sphere of the group that produced the node.
    pub lod_sphere: [f32; 4],
    /// Error of the group that produced the node (0 for leaves).
    pub lod_error: f32,
    /// Sphere of the group the node is a member of.
    pub parent_sphere: [f32; 4],
    /// Error of the group the node is a member of; `null` for roots (+∞).
    pub parent_error: Option<f32>,
    /// Group that produced the node; `null` for leaves.
    pub producer: Option<u32>,
    /// Group the node is a member of; `null` for roots.
    pub member_of: Option<u32>,
    /// Offset of its patch blob, absolute in the file.
    pub offset: u64,
    /// Length of its patch blob in bytes.
    pub length: u32,
    /// Unsigned CRC-32 (IEEE) of the blob's `length` bytes (also its ETag).
    pub crc32: u32,
}

/// One group: neighbouring patches (`members`) merged, simplified and split again into
/// `products` one level up.
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = LodGroup)]
pub struct GroupJson {
    /// Group id (its index).
    pub id: u32,
    /// Level of its members.
    pub level: u32,
    /// Bounding sphere x, y, z, r (the members' `parent_sphere`, the products' `lod_sphere`).
    pub sphere: [f32; 4],
    /// Error (the members' `parent_error`, the products' `lod_error`).
    pub error: f32,
    /// Node ids of its members.
    pub members: Vec<u32>,
    /// Node ids of its products.
    pub products: Vec<u32>,
}

/// A model's LOD hierarchy as JSON (`docs/FORMAT.md`, "HTTP"): the file's header, its nodes
/// and its groups. Cut rule: for a threshold τ a node is drawn iff
/// `lod_error <= τ < parent_error`.
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = LodHierarchy)]
pub struct HierarchyJson {
    /// Format version (1).
    pub version: u32,
    /// Number of nodes (patches).
    pub node_count: u32,
    /// Number of groups.
    pub group_count: u32,
    /// Number of levels.
    pub level_count: u32,
    /// Number of roots.
    pub root_count: u32,
    /// Most triangles in one patch.
    pub max_patch_triangles: u32,
    /// Vertices of the input scan.
    pub input_vertices: u64,
    /// Triangles of the input scan.
    pub input_triangles: u64,
    /// Bounding box.
    pub bbox: BBoxJson,
    /// Quantisation grid.
    pub grid: GridJson,
    /// Whether patches carry vertex colours.
    pub has_colors: bool,
    /// Whether patches carry normals.
    pub has_normals: bool,
    /// Every patch carries a texture atlas (`docs/FORMAT.md`, patch blob).
    pub has_texture: bool,
    /// Every coarse patch carries a normal map (`docs/FORMAT.md`, "Normal maps").
    pub has_normal_maps: bool,
    /// How the vertex ids number the scan's vertices: `morton` (by the Morton code of their
    /// positions, `docs/FORMAT.md`, "Vertex ids") or `source` (the scan file's indices).
    pub vertex_order: VertexOrder,
    /// Size of the whole file in bytes.
    pub file_bytes: u64,
    /// Nodes, by id.
    pub nodes: Vec<NodeJson>,
    /// Groups, by id.
    pub groups: Vec<GroupJson>,
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
            members: lod.members(g).to_vec(),
            products: lod.products(g).to_vec(),
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
        has_texture: lod.has_texture(),
        has_normal_maps: lod.has_normal_maps(),
        vertex_order: lod.vertex_order(),
        file_bytes: lod.bytes().len() as u64,
        nodes,
        groups,
    })
}

// ---- conditional and range requests -----------------------------------------------------

/// Whether `If-None-Match` names `etag` (or `*`).
pub(super) fn not_modified(req: &HttpRequest, etag: &str) -> bool {
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

/// [`parse_range`] with its contract checked (the oracle of the mutation test and of the fuzz
/// target): a range served lies inside the body, and only a well-formed single range is
/// refused, with a message. Panics on a violation.
#[doc(hidden)]
pub fn checked_range(value: &str, len: u64) -> Result<Option<ByteRange>, BadRange> {
    let r = parse_range(Some(value), len);
    match &r {
        Ok(Some(b)) => assert!(
            b.start < b.end && b.end <= len,
            "{value:?} over {len}: {b:?}"
        ),
        Err(BadRange(msg)) => assert!(!msg.is_empty() && !value.contains(','), "{value:?}: {msg}"),
        Ok(None) => {}
    }
    r
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
                .json(super::openapi::ErrorBody { error: msg });
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
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct FormatQuery {
    /// `json` (default) or `binary` (the file's header and tables as
    /// `application/octet-stream`).
    pub format: Option<String>,
}

/// The model's LOD hierarchy
///
/// The DAG of `docs/FORMAT.md` ("HTTP") as JSON, or with `format=binary` the file's header
/// and tables exactly as in the file (its first `blobs_offset` bytes) as
/// `application/octet-stream`. `ETag` (the file's tag, with `-json` added for the JSON);
/// `If-None-Match` with a matching tag (or `*`) answers 304; `Cache-Control: private,
/// no-cache`. The binary form also takes one byte range, as `/lod/file` does.
#[utoipa::path(get, path = "/api/v1/models/{id}/lod", tag = "lod",
    params(
        ("id" = i64, Path, description = "model id"),
        FormatQuery,
        ("Range" = Option<String>, Header,
            description = "`format=binary` only: bytes=a-b, bytes=a- or bytes=-n"),
        ("If-Range" = Option<String>, Header,
            description = "`format=binary` only: serve the range only while the ETag is this one"),
        ("If-None-Match" = Option<String>, Header, description = "an ETag seen before, or `*`"),
    ),
    responses(
        (status = 200, description = "The hierarchy (JSON), or its binary header and tables",
            content(
                (HierarchyJson = "application/json"),
                (super::openapi::Binary = "application/octet-stream"),
            ),
            headers(
                ("ETag" = String, description = "strong tag of the file (`\"<crc>-<len hex>\"`), `-json` added for the JSON"),
                ("Cache-Control" = String, description = "`private, no-cache`"),
            )),
        (status = 206, description = "`format=binary`: a range of the header and tables (Content-Range)",
            body = super::openapi::Binary, content_type = "application/octet-stream",
            headers(("Content-Range" = String, description = "bytes a-b/length"))),
        (status = 304, description = "Not modified (If-None-Match)",
            headers(("ETag" = String, description = "the current tag"))),
        (status = 409, description = "The model is not ready (pending, building or failed)",
            body = super::openapi::ErrorBody),
        (status = 416, description = "`format=binary`: the range starts beyond the end (Content-Range: bytes */length)",
            body = super::openapi::ErrorBody,
            headers(("Content-Range" = String, description = "bytes */length"))),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn hierarchy(
    state: web::Data<AppState>,
    reader: Reader,
    req: HttpRequest,
    id: web::Path<i64>,
    q: web::Query<FormatQuery>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *id).await?;
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

/// One patch blob
///
/// The conditional and range request headers of the byte-serving routes (patch blobs, the
/// whole file), for the OpenAPI document.
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Header)]
#[allow(dead_code)] // described, never constructed: the handlers read the headers themselves
struct RangeHeaders {
    /// bytes=a-b, bytes=a- or bytes=-n
    #[param(rename = "Range")]
    range: Option<String>,
    /// serve the range only while the ETag is this one
    #[param(rename = "If-Range")]
    if_range: Option<String>,
    /// an ETag seen before, or `*`
    #[param(rename = "If-None-Match")]
    if_none_match: Option<String>,
}

/// The blob of node `node` (`docs/FORMAT.md`, "Patch blob"), `application/octet-stream`,
/// `Content-Encoding: identity` (blobs are compressed already). `ETag` = its CRC-32 as 8
/// lower-case hex digits; `Cache-Control: public, max-age=31536000, immutable` (a node's
/// blob never changes for a model); `If-None-Match` gives 304. One byte range per request
/// (206; 416 when it starts beyond the end; a malformed or multiple range is ignored: 200);
/// `If-Range` with another tag serves the whole blob.
#[utoipa::path(get, path = "/api/v1/models/{id}/lod/patches/{node}", tag = "lod",
    params(
        ("id" = i64, Path, description = "model id"),
        ("node" = u32, Path, description = "node (patch) id, 0 to node_count - 1"),
        RangeHeaders,
    ),
    responses(
        (status = 200, description = "The blob", body = super::openapi::Binary,
            content_type = "application/octet-stream",
            headers(
                ("ETag" = String, description = "the blob's CRC-32, 8 lower-case hex digits, quoted"),
                ("Cache-Control" = String, description = "`public, max-age=31536000, immutable`"),
                ("Accept-Ranges" = String, description = "`bytes`"),
            )),
        (status = 206, description = "A range of the blob (Content-Range)",
            body = super::openapi::Binary, content_type = "application/octet-stream",
            headers(("Content-Range" = String, description = "bytes a-b/length"))),
        (status = 304, description = "Not modified (If-None-Match)",
            headers(("ETag" = String, description = "the blob's tag"))),
        (status = 409, description = "The model is not ready (pending, building or failed)",
            body = super::openapi::ErrorBody),
        (status = 416, description = "Bad range: it starts beyond the end (Content-Range: bytes */length)",
            body = super::openapi::ErrorBody,
            headers(("Content-Range" = String, description = "bytes */length"))),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn patch(
    state: web::Data<AppState>,
    reader: Reader,
    req: HttpRequest,
    path: web::Path<(i64, u32)>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, path.0).await?;
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
    if let GeometryGrant::Sparse(_) = state.geometry_grant(reader.user(), id).await?
        && !open.within_sparse(node)
    {
        return Err(
            sparse_refusal(id, &format!("patch {node}, finer than the sparse mesh,")).into(),
        );
    }
    let etag = format!("\"{:08x}\"", record.blob_crc);
    let start = record.blob_offset as usize;
    let end = start + record.blob_len as usize;
    Ok(serve_bytes(&req, open, start, end, &etag, IMMUTABLE))
}

/// The whole .mwlod file
///
/// The file as built, with one byte range per request (neighbouring patches are contiguous
/// in locality order, so one range fetches several); `ETag` (the header's CRC and the file
/// length), `If-None-Match` (304), `If-Range`; `Cache-Control: private, no-cache`;
/// `Content-Encoding: identity`, so ranges count stored bytes.
#[utoipa::path(get, path = "/api/v1/models/{id}/lod/file", tag = "lod",
    params(
        ("id" = i64, Path, description = "model id"),
        RangeHeaders,
    ),
    responses(
        (status = 200, description = "The file", body = super::openapi::Binary,
            content_type = "application/octet-stream",
            headers(
                ("ETag" = String, description = "strong tag: `\"<crc>-<len hex>\"`"),
                ("Cache-Control" = String, description = "`private, no-cache`"),
                ("Accept-Ranges" = String, description = "`bytes`"),
            )),
        (status = 206, description = "A range of the file (Content-Range)",
            body = super::openapi::Binary, content_type = "application/octet-stream",
            headers(("Content-Range" = String, description = "bytes a-b/length"))),
        (status = 304, description = "Not modified (If-None-Match)",
            headers(("ETag" = String, description = "the file's tag"))),
        (status = 409, description = "The model is not ready (pending, building or failed)",
            body = super::openapi::ErrorBody),
        (status = 416, description = "Bad range: it starts beyond the end (Content-Range: bytes */length)",
            body = super::openapi::ErrorBody,
            headers(("Content-Range" = String, description = "bytes */length"))),
    ),
    security((), ("sessionCookie" = ["viewer"])))]
async fn file(
    state: web::Data<AppState>,
    reader: Reader,
    req: HttpRequest,
    id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *id).await?;
    state
        .require_full_geometry(reader.user(), *id, "the LOD file")
        .await?;
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
            match checked_range(&v, len) {
                Ok(Some(_)) => served += 1,
                Ok(None) => whole += 1,
                Err(_) => refused += 1,
            }
        }
        println!("ranges: 10000 cases, {served} served, {whole} whole body, {refused} refused");
        assert!(served > 0 && whole > 0 && refused > 0);
    }
}
