//! `GET /api/v1/openapi.json`: the OpenAPI 3 description of the whole JSON API, written by
//! hand and kept here in one place.

use actix_web::{HttpResponse, web};
use serde_json::{Value, json};

/// Mounts the route.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/openapi.json").route(web::get().to(get)))
        .service(super::resource("/api/v1/health").route(web::get().to(health)));
}

async fn get() -> HttpResponse {
    HttpResponse::Ok().json(document())
}

async fn health() -> HttpResponse {
    HttpResponse::Ok().json(json!({"status": "ok"}))
}

fn r(name: &str) -> Value {
    json!({ "$ref": format!("#/components/schemas/{name}") })
}

fn array(of: Value) -> Value {
    json!({ "type": "array", "items": of })
}

fn id_param(name: &str, what: &str) -> Value {
    json!({ "name": name, "in": "path", "required": true,
            "description": what, "schema": { "type": "integer", "format": "int64" } })
}

fn query_param(name: &str, ty: &str, what: &str) -> Value {
    json!({ "name": name, "in": "query", "required": false,
            "description": what, "schema": { "type": ty } })
}

fn paging() -> Vec<Value> {
    vec![
        query_param("limit", "integer", "rows to return (1-1000, default 100)"),
        query_param("offset", "integer", "rows to skip"),
    ]
}

fn json_body(schema: Value) -> Value {
    json!({ "required": true, "content": { "application/json": { "schema": schema } } })
}

fn ok(status: &str, description: &str, schema: Option<Value>) -> (String, Value) {
    let mut resp = json!({ "description": description });
    if let Some(s) = schema {
        resp["content"] = json!({ "application/json": { "schema": s } });
    }
    (status.to_string(), resp)
}

/// Describes one operation. `role`: minimum role (`"none"` for public routes);
/// state-changing operations also list the CSRF header requirement.
fn op(
    tag: &str,
    summary: &str,
    role: &str,
    params: Vec<Value>,
    body: Option<Value>,
    responses: Vec<(String, Value)>,
) -> Value {
    let mut o = json!({
        "tags": [tag],
        "summary": summary,
        "description": if role == "none" { "Public.".to_string() }
                       else { format!("Requires the `{role}` role or higher.") },
        "parameters": params,
    });
    if role == "none" {
        o["security"] = json!([]);
    }
    if let Some(b) = body {
        o["requestBody"] = b;
    }
    let mut rs = serde_json::Map::new();
    for (status, resp) in responses {
        rs.insert(status, resp);
    }
    for (status, what) in [
        ("400", "Invalid input"),
        ("401", "No session"),
        ("403", "Role or CSRF check failed"),
        ("404", "Not found"),
    ] {
        rs.entry(status.to_string())
            .or_insert_with(|| json!({ "description": what, "content": { "application/json": { "schema": r("Error") } } }));
    }
    o["responses"] = Value::Object(rs);
    o
}

/// The OpenAPI document.
pub fn document() -> Value {
    let content_id = || id_param("id", "content id");
    let part_id = || id_param("id", "part id");
    let model_id = || id_param("id", "model id");
    let mut paths = serde_json::Map::new();
    let mut add = |path: &str, methods: Vec<(&str, Value)>| {
        let mut m = serde_json::Map::new();
        for (method, o) in methods {
            m.insert(method.to_string(), o);
        }
        paths.insert(path.to_string(), Value::Object(m));
    };

    add(
        "/api/v1/session",
        vec![
            (
                "post",
                op(
                    "session",
                    "Log in: sets the HttpOnly session cookie and returns the CSRF token",
                    "none",
                    vec![],
                    Some(json_body(r("LoginRequest"))),
                    vec![
                        ok("200", "Logged in", Some(r("Session"))),
                        ok("401", "Wrong user name or password", Some(r("Error"))),
                    ],
                ),
            ),
            (
                "get",
                op(
                    "session",
                    "The current session and user",
                    "viewer",
                    vec![],
                    None,
                    vec![ok("200", "Session", Some(r("Session")))],
                ),
            ),
            (
                "delete",
                op(
                    "session",
                    "Log out",
                    "viewer",
                    vec![],
                    None,
                    vec![ok("204", "Logged out", None)],
                ),
            ),
        ],
    );
    add(
        "/api/v1/users",
        vec![
            (
                "get",
                op(
                    "users",
                    "List users",
                    "admin",
                    paging(),
                    None,
                    vec![ok("200", "Users", Some(array(r("User"))))],
                ),
            ),
            (
                "post",
                op(
                    "users",
                    "Create a user",
                    "admin",
                    vec![],
                    Some(json_body(r("NewUser"))),
                    vec![
                        ok("201", "Created", Some(r("User"))),
                        ok("409", "User name taken", Some(r("Error"))),
                    ],
                ),
            ),
        ],
    );
    add(
        "/api/v1/users/{id}",
        vec![
            (
                "get",
                op(
                    "users",
                    "Get a user",
                    "admin",
                    vec![id_param("id", "user id")],
                    None,
                    vec![ok("200", "User", Some(r("User")))],
                ),
            ),
            (
                "patch",
                op(
                    "users",
                    "Change role, password or disabled flag (changing the password or disabling ends the user's sessions)",
                    "admin",
                    vec![id_param("id", "user id")],
                    Some(json_body(r("UserPatch"))),
                    vec![
                        ok("200", "Updated", Some(r("User"))),
                        ok("409", "Would lock out the acting admin", Some(r("Error"))),
                    ],
                ),
            ),
            (
                "delete",
                op(
                    "users",
                    "Disable a user (accounts are never erased: their revisions keep their author)",
                    "admin",
                    vec![id_param("id", "user id")],
                    None,
                    vec![ok("200", "Disabled", Some(r("User")))],
                ),
            ),
        ],
    );
    add(
        "/api/v1/audit",
        vec![(
            "get",
            op(
                "users",
                "Audit log, newest first",
                "admin",
                {
                    let mut p = paging();
                    p.push(query_param("entity", "string", "entity kind, e.g. content"));
                    p.push(query_param("entity_id", "integer", "entity id"));
                    p
                },
                None,
                vec![ok("200", "Entries", Some(array(r("AuditEntry"))))],
            ),
        )],
    );
    add(
        "/api/v1/models",
        vec![
            (
                "get",
                op(
                    "models",
                    "List models, newest first",
                    "viewer",
                    paging(),
                    None,
                    vec![ok("200", "Models", Some(array(r("Model"))))],
                ),
            ),
            (
                "post",
                op(
                    "models",
                    "Create an empty model record (status pending)",
                    "admin",
                    vec![],
                    Some(json_body(r("NewModel"))),
                    vec![ok("201", "Created", Some(r("Model")))],
                ),
            ),
        ],
    );
    add(
        "/api/v1/models/{id}",
        vec![
            (
                "get",
                op(
                    "models",
                    "Get a model",
                    "viewer",
                    vec![model_id()],
                    None,
                    vec![ok("200", "Model", Some(r("Model")))],
                ),
            ),
            (
                "patch",
                op(
                    "models",
                    "Change title, description or thumbnail",
                    "editor",
                    vec![model_id()],
                    Some(json_body(r("ModelPatch"))),
                    vec![ok("200", "Updated", Some(r("Model")))],
                ),
            ),
            (
                "delete",
                op(
                    "models",
                    "Delete a model with its parts and assignments (contents stay)",
                    "admin",
                    vec![model_id()],
                    None,
                    vec![ok("204", "Deleted", None)],
                ),
            ),
        ],
    );
    add(
        "/api/v1/models/upload",
        vec![(
            "post",
            op(
                "jobs",
                "Upload a scan (the raw request body, streamed to disk) and queue its LOD build: creates a model (status pending) and its job",
                "admin",
                vec![
                    json!({ "name": "title", "in": "query", "required": true, "description": "title of the new model (1-300 characters)", "schema": { "type": "string" } }),
                    json!({ "name": "filename", "in": "query", "required": true, "description": "the scan's file name: only its extension (.ply, .obj, .gltf, .glb, .stl, .off) is used, to pick the format", "schema": { "type": "string" } }),
                    query_param("description", "string", "description (Markdown)"),
                ],
                Some(
                    json!({ "required": true, "content": { "application/octet-stream": { "schema": { "type": "string", "format": "binary" } } } }),
                ),
                vec![
                    ok(
                        "202",
                        "Queued (Location: the job)",
                        Some(obj(
                            &["model", "job"],
                            json!({"model": r("Model"), "job": r("Job")}),
                        )),
                    ),
                    ok("413", "Larger than --max-model-upload-mb", Some(r("Error"))),
                ],
            ),
        )],
    );
    add(
        "/api/v1/models/{id}/lod",
        vec![(
            "get",
            op(
                "lod",
                "The model's LOD hierarchy (docs/FORMAT.md, HTTP): JSON, or with format=binary the file's header and tables as application/octet-stream. ETag; If-None-Match gives 304",
                "viewer",
                vec![
                    model_id(),
                    query_param("format", "string", "json (default) or binary"),
                ],
                None,
                vec![
                    ok("200", "The hierarchy", Some(r("LodHierarchy"))),
                    ok("304", "Not modified", None),
                    ok(
                        "409",
                        "The model is not ready (pending, building or failed)",
                        Some(r("Error")),
                    ),
                ],
            ),
        )],
    );
    add(
        "/api/v1/models/{id}/lod/patches/{node}",
        vec![(
            "get",
            op(
                "lod",
                "One patch blob (docs/FORMAT.md, Patch blob): ETag = its CRC-32, Cache-Control public, max-age=31536000, immutable; If-None-Match (304); one byte range (206; 416 when unsatisfiable; a malformed or multiple range is ignored: 200)",
                "viewer",
                vec![
                    model_id(),
                    json!({ "name": "node", "in": "path", "required": true, "description": "node id", "schema": { "type": "integer", "minimum": 0 } }),
                    json!({ "name": "Range", "in": "header", "required": false, "description": "bytes=a-b, bytes=a- or bytes=-n", "schema": { "type": "string" } }),
                ],
                None,
                vec![
                    binary("200", "The blob"),
                    binary("206", "A range of the blob (Content-Range)"),
                    ok("304", "Not modified", None),
                    ok("409", "The model is not ready", Some(r("Error"))),
                    ok(
                        "416",
                        "Bad range (Content-Range: bytes */length)",
                        Some(r("Error")),
                    ),
                ],
            ),
        )],
    );
    add(
        "/api/v1/models/{id}/lod/file",
        vec![(
            "get",
            op(
                "lod",
                "The whole .mwlod file, with one byte range per request (neighbouring patches are contiguous); ETag, If-None-Match, If-Range",
                "viewer",
                vec![
                    model_id(),
                    json!({ "name": "Range", "in": "header", "required": false, "description": "bytes=a-b, bytes=a- or bytes=-n", "schema": { "type": "string" } }),
                ],
                None,
                vec![
                    binary("200", "The file"),
                    binary("206", "A range of the file (Content-Range)"),
                    ok("304", "Not modified", None),
                    ok("409", "The model is not ready", Some(r("Error"))),
                    ok("416", "Bad range", Some(r("Error"))),
                ],
            ),
        )],
    );
    {
        // Server-side rendering (src/web/render.rs).
        let common = vec![
            model_id(),
            query_param(
                "eye",
                "string",
                "camera position x,y,z (default: the model's overview camera)",
            ),
            query_param(
                "target",
                "string",
                "point looked at x,y,z (default: the model's centre; needs eye)",
            ),
            query_param(
                "up",
                "string",
                "up vector x,y,z (default +Y; not parallel to the view direction)",
            ),
            query_param(
                "fovy",
                "number",
                "vertical field of view in degrees, 1-170 (default 45)",
            ),
            query_param(
                "w",
                "integer",
                "image width, 1 to MESHWIKI_RENDER_MAX_SIDE (default 640); w*h at most MESHWIKI_RENDER_MAX_PIXELS",
            ),
            query_param("h", "integer", "image height (default 480)"),
            query_param(
                "parts",
                "string",
                "comma-separated part ids of this model to tint, in order (at most 64)",
            ),
            query_param(
                "hover",
                "string",
                "a part id of this model to outline (the hovered part)",
            ),
            query_param(
                "px",
                "number",
                "pixel error of the view-dependent cut, 0.25-64 (default 1)",
            ),
        ];
        let busy = || {
            let mut r = json!({ "description": "Render queue full (with Retry-After, seconds) or no GPU adapter on the server", "content": { "application/json": { "schema": r("Error") } } });
            r["headers"] = json!({"Retry-After": {"schema": {"type": "integer"}, "description": "seconds; absent when rendering is unavailable"}});
            ("503".to_string(), r)
        };
        let not_ready = || {
            ok(
                "409",
                "The model is not ready (pending, building or failed)",
                Some(r("Error")),
            )
        };
        let mut image_params = common.clone();
        image_params.extend([
            query_param("format", "string", "png (default), jpeg or webp (lossless)"),
            query_param("quality", "integer", "JPEG quality 1-100 (default 90)"),
            query_param("callouts", "integer", "1: draw labels (the first assigned content's title) with leader lines for the parts named in parts/hover, or for every part of the model when none is named"),
        ]);
        add(
            "/api/v1/models/{id}/render",
            vec![(
                "get",
                op(
                    "render",
                    "Render the model's hierarchy (1-pixel cut) from a camera: parts tinted, the hovered part outlined, callouts on request. Runs on a bounded worker pool (MESHWIKI_RENDER_WORKERS, MESHWIKI_RENDER_QUEUE); every parameter is checked (400)",
                    "viewer",
                    image_params,
                    None,
                    vec![
                        (
                            "200".to_string(),
                            json!({ "description": "The image (X-Render-Triangles, X-Render-Patches, X-Render-Ms headers)", "content": {
                                "image/png": { "schema": { "type": "string", "format": "binary" } },
                                "image/jpeg": { "schema": { "type": "string", "format": "binary" } },
                                "image/webp": { "schema": { "type": "string", "format": "binary" } } } }),
                        ),
                        not_ready(),
                        busy(),
                    ],
                ),
            )],
        );
        let mut buffer_params = common.clone();
        buffer_params.push(query_param(
            "buffers",
            "string",
            "comma-separated subset of color, normal, depth, ids (default normal,depth,ids)",
        ));
        add(
            "/api/v1/models/{id}/render/buffers",
            vec![(
                "get",
                op(
                    "render",
                    "Per-pixel buffers for tools. Body (little endian): \"MWRB\", u32 version 1, u32 J, J bytes of JSON header (width, height, camera, stats, buffers: [{name, type, components, offset, bytes}]), then the arrays at their offsets, row-major, top row first: color u8x4, normal f32x3 (0 on the background), depth f32 (linear view depth, +inf on the background), node u32, vertex u32 (original vertex id of the model), triangle u32, highlight u32 (bits 0-7: 1-based index in parts, bit 8: hover, bit 31: covered); ids 0xFFFFFFFF on the background",
                    "viewer",
                    buffer_params,
                    None,
                    vec![binary("200", "The buffers"), not_ready(), busy()],
                ),
            )],
        );
        add(
            "/api/v1/models/{id}/render/callouts",
            vec![(
                "get",
                op(
                    "render",
                    "The callout layout for a view, for the browser to draw as HTML: each visible part's anchor (its centre) projected, labels placed without overlap, leader lines; parts hidden (behind, outside, occluded, no room) are listed with the reason",
                    "viewer",
                    common,
                    None,
                    vec![
                        ok("200", "The layout", Some(r("CalloutLayout"))),
                        not_ready(),
                        busy(),
                    ],
                ),
            )],
        );
    }
    add(
        "/api/v1/jobs",
        vec![(
            "get",
            op(
                "jobs",
                "List build jobs, newest first",
                "admin",
                {
                    let mut p = paging();
                    p.push(query_param(
                        "status",
                        "string",
                        "only jobs in this state (queued, running, done, failed, cancelled)",
                    ));
                    p
                },
                None,
                vec![ok("200", "Jobs", Some(array(r("Job"))))],
            ),
        )],
    );
    add(
        "/api/v1/jobs/{id}",
        vec![(
            "get",
            op(
                "jobs",
                "A build job with its progress (poll it while it runs)",
                "viewer",
                vec![id_param("id", "job id")],
                None,
                vec![ok("200", "Job", Some(r("Job")))],
            ),
        )],
    );
    add(
        "/api/v1/jobs/{id}/cancel",
        vec![(
            "post",
            op(
                "jobs",
                "Cancel a job: a queued job is cancelled at once (200), a running one stops within about a second (202); its model becomes failed and nothing is left on disk",
                "admin",
                vec![id_param("id", "job id")],
                None,
                vec![
                    ok("200", "Cancelled", Some(r("Job"))),
                    ok("202", "Cancellation requested", Some(r("Job"))),
                    ok("409", "The job has already ended", Some(r("Error"))),
                ],
            ),
        )],
    );
    add(
        "/api/v1/models/{id}/parts",
        vec![
            (
                "get",
                op(
                    "parts",
                    "Parts of a model",
                    "viewer",
                    vec![model_id()],
                    None,
                    vec![ok("200", "Parts", Some(array(r("Part"))))],
                ),
            ),
            (
                "post",
                op(
                    "parts",
                    "Create a point or region part",
                    "editor",
                    vec![model_id()],
                    Some(json_body(r("NewPart"))),
                    vec![ok("201", "Created", Some(r("Part")))],
                ),
            ),
        ],
    );
    add(
        "/api/v1/parts/{id}",
        vec![
            (
                "get",
                op(
                    "parts",
                    "Get a part",
                    "viewer",
                    vec![part_id()],
                    None,
                    vec![ok("200", "Part", Some(r("Part")))],
                ),
            ),
            (
                "patch",
                op(
                    "parts",
                    "Change a part",
                    "editor",
                    vec![part_id()],
                    Some(json_body(r("PartPatch"))),
                    vec![ok("200", "Updated", Some(r("Part")))],
                ),
            ),
            (
                "delete",
                op(
                    "parts",
                    "Delete a part and its assignments",
                    "editor",
                    vec![part_id()],
                    None,
                    vec![ok("204", "Deleted", None)],
                ),
            ),
        ],
    );
    add(
        "/api/v1/parts/{id}/vertices",
        vec![(
            "get",
            op(
                "parts",
                "The part's vertex set: a serialised RoaringBitmap (portable format) of original vertex ids",
                "viewer",
                vec![part_id()],
                None,
                vec![(
                    "200".into(),
                    json!({"description": "Bitmap", "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}}),
                )],
            ),
        )],
    );
    add(
        "/api/v1/parts/{id}/contents",
        vec![
            (
                "get",
                op(
                    "assignments",
                    "Contents assigned to a part, in order",
                    "viewer",
                    vec![part_id()],
                    None,
                    vec![ok(
                        "200",
                        "Assigned contents",
                        Some(array(r("AssignedContent"))),
                    )],
                ),
            ),
            (
                "post",
                op(
                    "assignments",
                    "Assign a content to a part",
                    "editor",
                    vec![part_id()],
                    Some(json_body(r("AssignRequest"))),
                    vec![
                        ok(
                            "201",
                            "The part's contents",
                            Some(array(r("AssignedContent"))),
                        ),
                        ok("409", "Already assigned", Some(r("Error"))),
                    ],
                ),
            ),
            (
                "put",
                op(
                    "assignments",
                    "Reorder a part's contents",
                    "editor",
                    vec![part_id()],
                    Some(json_body(r("ReorderRequest"))),
                    vec![ok(
                        "200",
                        "The part's contents",
                        Some(array(r("AssignedContent"))),
                    )],
                ),
            ),
        ],
    );
    add(
        "/api/v1/parts/{id}/contents/{content_id}",
        vec![(
            "delete",
            op(
                "assignments",
                "Remove a content from a part",
                "editor",
                vec![part_id(), id_param("content_id", "content id")],
                None,
                vec![ok("204", "Removed", None)],
            ),
        )],
    );
    add(
        "/api/v1/contents",
        vec![
            (
                "get",
                op(
                    "contents",
                    "List contents, most recently changed first",
                    "viewer",
                    paging(),
                    None,
                    vec![ok("200", "Contents", Some(array(r("Content"))))],
                ),
            ),
            (
                "post",
                op(
                    "contents",
                    "Create a content (revision 1)",
                    "editor",
                    vec![],
                    Some(json_body(r("NewContent"))),
                    vec![ok("201", "Created", Some(r("Content")))],
                ),
            ),
        ],
    );
    add(
        "/api/v1/contents/{id}",
        vec![
            (
                "get",
                op(
                    "contents",
                    "Get a content with its rendered HTML and attachments",
                    "viewer",
                    vec![content_id()],
                    None,
                    vec![ok("200", "Content", Some(r("Content")))],
                ),
            ),
            (
                "put",
                op(
                    "contents",
                    "Save a new revision based on base_revision; a stale base gets 409 with both versions",
                    "editor",
                    vec![content_id()],
                    Some(json_body(r("SaveContent"))),
                    vec![
                        ok("200", "Saved", Some(r("Content"))),
                        ok("409", "Edit conflict", Some(r("EditConflict"))),
                    ],
                ),
            ),
            (
                "delete",
                op(
                    "contents",
                    "Delete a content with its history",
                    "admin",
                    vec![content_id()],
                    None,
                    vec![ok("204", "Deleted", None)],
                ),
            ),
        ],
    );
    add(
        "/api/v1/contents/{id}/revisions",
        vec![(
            "get",
            op(
                "contents",
                "History, newest first",
                "viewer",
                vec![content_id()],
                None,
                vec![ok("200", "Revisions", Some(array(r("RevisionSummary"))))],
            ),
        )],
    );
    add(
        "/api/v1/contents/{id}/revisions/{number}",
        vec![(
            "get",
            op(
                "contents",
                "One revision in full, with rendered HTML",
                "viewer",
                vec![content_id(), id_param("number", "revision number")],
                None,
                vec![ok("200", "Revision", Some(r("Revision")))],
            ),
        )],
    );
    add(
        "/api/v1/contents/{id}/diff",
        vec![(
            "get",
            op(
                "contents",
                "Diff between two revisions (default: previous to current)",
                "viewer",
                vec![
                    content_id(),
                    query_param("from", "integer", "older revision"),
                    query_param("to", "integer", "newer revision"),
                ],
                None,
                vec![ok("200", "Diff", Some(r("RevisionDiff")))],
            ),
        )],
    );
    add(
        "/api/v1/contents/{id}/revert",
        vec![(
            "post",
            op(
                "contents",
                "Save a copy of an old revision as a new revision",
                "editor",
                vec![content_id()],
                Some(json_body(r("RevertRequest"))),
                vec![
                    ok("200", "Reverted", Some(r("Content"))),
                    ok("409", "Edit conflict", Some(r("EditConflict"))),
                ],
            ),
        )],
    );
    add(
        "/api/v1/contents/{id}/parts",
        vec![(
            "get",
            op(
                "assignments",
                "Parts a content is assigned to",
                "viewer",
                vec![content_id()],
                None,
                vec![ok("200", "Parts", Some(array(r("AssignedPart"))))],
            ),
        )],
    );
    add(
        "/api/v1/contents/{id}/attachments",
        vec![
            (
                "get",
                op(
                    "attachments",
                    "Attachments of a content, in order",
                    "viewer",
                    vec![content_id()],
                    None,
                    vec![ok("200", "Attachments", Some(array(r("Attachment"))))],
                ),
            ),
            (
                "post",
                op(
                    "attachments",
                    "Upload a file (multipart field `file`) and attach it",
                    "editor",
                    vec![content_id()],
                    Some(multipart_body()),
                    vec![
                        ok("201", "Uploaded", Some(r("Attachment"))),
                        ok("413", "File too large", Some(r("Error"))),
                    ],
                ),
            ),
        ],
    );
    add(
        "/api/v1/contents/{id}/attachments/{attachment_id}",
        vec![
            (
                "put",
                op(
                    "attachments",
                    "Attach an existing attachment",
                    "editor",
                    vec![content_id(), id_param("attachment_id", "attachment id")],
                    None,
                    vec![
                        ok(
                            "200",
                            "Attachments of the content",
                            Some(array(r("Attachment"))),
                        ),
                        ok("409", "Already attached", Some(r("Error"))),
                    ],
                ),
            ),
            (
                "delete",
                op(
                    "attachments",
                    "Detach an attachment",
                    "editor",
                    vec![content_id(), id_param("attachment_id", "attachment id")],
                    None,
                    vec![ok("204", "Detached", None)],
                ),
            ),
        ],
    );
    add(
        "/api/v1/attachments",
        vec![(
            "post",
            op(
                "attachments",
                "Upload a file (multipart field `file`, optional field `content_id`)",
                "editor",
                vec![],
                Some(multipart_body()),
                vec![
                    ok("201", "Uploaded", Some(r("Attachment"))),
                    ok("413", "File too large", Some(r("Error"))),
                ],
            ),
        )],
    );
    add(
        "/api/v1/attachments/{id}",
        vec![(
            "get",
            op(
                "attachments",
                "Attachment metadata",
                "viewer",
                vec![id_param("id", "attachment id")],
                None,
                vec![ok("200", "Attachment", Some(r("Attachment")))],
            ),
        )],
    );
    add(
        "/api/v1/attachments/{id}/download",
        vec![(
            "get",
            op(
                "attachments",
                "The file. Sent with X-Content-Type-Options: nosniff; active types (HTML, SVG, JS, PDF, ...) with Content-Disposition: attachment",
                "viewer",
                vec![id_param("id", "attachment id")],
                None,
                vec![(
                    "200".into(),
                    json!({"description": "File", "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}}),
                )],
            ),
        )],
    );
    add(
        "/api/v1/models/{id}/events",
        vec![(
            "get",
            op(
                "models",
                "Live changes of a model's parts and their information, as server-sent events: `change` messages whose data is a ChangeEvent (content events concern every model), `resync` when the client fell behind and must reload, keep-alive comments every 15 s",
                "viewer",
                vec![model_id()],
                None,
                vec![(
                    "200".into(),
                    json!({"description": "Event stream", "content": {"text/event-stream": {"schema": r("ChangeEvent")}}}),
                )],
            ),
        )],
    );
    add(
        "/api/v1/search",
        vec![(
            "get",
            op(
                "search",
                "Full-text search over contents (title, caption, body, attachment names, model titles); total in X-Total-Count",
                "viewer",
                vec![
                    json!({"name": "q", "in": "query", "required": true, "description": "query; words are ANDed, \"phrases\" and -exclusions work", "schema": {"type": "string"}}),
                    query_param("model", "integer", "only contents assigned to this model"),
                    query_param("limit", "integer", "hits per page (1-100, default 20)"),
                    query_param("offset", "integer", "hits to skip"),
                ],
                None,
                vec![ok("200", "Hits, best first", Some(array(r("SearchHit"))))],
            ),
        )],
    );
    add(
        "/api/v1/preview",
        vec![(
            "post",
            op(
                "contents",
                "Render Markdown to sanitised HTML",
                "viewer",
                vec![],
                Some(json_body(
                    json!({"type": "object", "required": ["body"], "properties": {"body": {"type": "string"}}}),
                )),
                vec![ok(
                    "200",
                    "HTML",
                    Some(json!({"type": "object", "properties": {"html": {"type": "string"}}})),
                )],
            ),
        )],
    );
    add(
        "/api/v1/openapi.json",
        vec![(
            "get",
            op(
                "meta",
                "This document",
                "none",
                vec![],
                None,
                vec![ok(
                    "200",
                    "OpenAPI 3 document",
                    Some(json!({"type": "object"})),
                )],
            ),
        )],
    );
    add(
        "/api/v1/health",
        vec![(
            "get",
            op(
                "meta",
                "Liveness check",
                "none",
                vec![],
                None,
                vec![ok("200", "OK", Some(json!({"type": "object"})))],
            ),
        )],
    );

    json!({
        "openapi": "3.0.3",
        "info": {
            "title": "meshwiki API",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "Wiki information attached to regions of huge 3D scans. Log in with POST /api/v1/session; the session cookie authenticates later requests and every state-changing request (POST, PUT, PATCH, DELETE) must carry the returned csrf_token in the X-CSRF-Token header. Errors are JSON {\"error\": \"...\"}. Lists are JSON arrays of objects with an id."
        },
        "servers": [{ "url": "/" }],
        "security": [{ "sessionCookie": [], "csrfToken": [] }],
        "paths": Value::Object(paths),
        "components": {
            "securitySchemes": {
                "sessionCookie": { "type": "apiKey", "in": "cookie", "name": super::auth::SESSION_COOKIE },
                "csrfToken": { "type": "apiKey", "in": "header", "name": "X-CSRF-Token" }
            },
            "schemas": schemas()
        }
    })
}

fn multipart_body() -> Value {
    json!({ "required": true, "content": { "multipart/form-data": { "schema": {
        "type": "object", "required": ["file"],
        "properties": {
            "file": { "type": "string", "format": "binary" },
            "content_id": { "type": "integer", "description": "attach to this content" }
        }
    }}}})
}

fn binary(status: &str, description: &str) -> (String, Value) {
    (
        status.to_string(),
        json!({ "description": description, "content": { "application/octet-stream": { "schema": { "type": "string", "format": "binary" } } } }),
    )
}

fn obj(required: &[&str], props: Value) -> Value {
    json!({ "type": "object", "required": required, "properties": props })
}

fn schemas() -> Value {
    let int = json!({"type": "integer", "format": "int64"});
    let str_ = json!({"type": "string"});
    let time = json!({"type": "string", "format": "date-time"});
    let nint = json!({"type": "integer", "format": "int64", "nullable": true});
    let vec3 = json!({"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3});
    let role = json!({"type": "string", "enum": ["admin", "editor", "viewer"]});
    let mut all = json!({
        "Error": obj(&["error"], json!({"error": str_})),
        "LoginRequest": obj(&["username", "password"], json!({"username": str_, "password": str_})),
        "Session": obj(&["csrf_token", "user"], json!({"csrf_token": str_, "expires_at": int, "user": r("User")})),
        "User": obj(&["id", "username", "role"], json!({"id": int, "username": str_, "role": role, "disabled": {"type": "boolean"}, "created_at": time, "updated_at": time})),
        "NewUser": obj(&["username", "password", "role"], json!({"username": str_, "password": {"type": "string", "minLength": 8}, "role": role})),
        "UserPatch": obj(&[], json!({"role": role, "password": str_, "disabled": {"type": "boolean"}})),
        "AuditEntry": obj(&["id", "action"], json!({"id": int, "user_id": nint, "action": str_, "entity": str_, "entity_id": nint, "details": {"type": "object"}, "created_at": time})),
        "BBox": obj(&["min", "max"], json!({"min": vec3, "max": vec3})),
        "Model": obj(&["id", "title", "status"], json!({
            "id": int, "title": str_, "description": str_, "source_name": str_,
            "status": {"type": "string", "enum": ["pending", "building", "ready", "failed"]},
            "vertex_count": int, "triangle_count": int,
            "bbox": {"allOf": [r("BBox")], "nullable": true},
            "lod_path": {"type": "string", "nullable": true}, "error": {"type": "string", "nullable": true},
            "thumbnail_attachment_id": nint, "created_by": int, "created_at": time, "updated_at": time})),
        "NewModel": obj(&["title"], json!({"title": str_, "description": str_, "source_name": str_})),
        "ModelPatch": obj(&[], json!({"title": str_, "description": str_, "thumbnail_attachment_id": nint})),
        "Camera": obj(&["eye", "target", "up", "fovy"], json!({"eye": vec3, "target": vec3, "up": vec3, "fovy": {"type": "number", "description": "degrees"}})),
        "Part": obj(&["id", "model_id", "kind", "center"], json!({
            "id": int, "model_id": int, "kind": {"type": "string", "enum": ["point", "region"]},
            "center": vec3, "vertex_count": int, "camera": {"allOf": [r("Camera")], "nullable": true},
            "thumbnail_attachment_id": nint, "created_by": int, "created_at": time, "updated_at": time})),
        "NewPart": obj(&["kind", "center"], json!({
            "kind": {"type": "string", "enum": ["point", "region"]}, "center": vec3, "camera": r("Camera"),
            "vertex_ids": {"type": "array", "items": {"type": "integer", "minimum": 0}, "description": "original vertex ids; required for regions"},
            "thumbnail_attachment_id": nint})),
        "PartPatch": obj(&[], json!({
            "kind": {"type": "string", "enum": ["point", "region"]}, "center": vec3,
            "camera": {"allOf": [r("Camera")], "nullable": true},
            "vertex_ids": {"type": "array", "items": {"type": "integer", "minimum": 0}},
            "thumbnail_attachment_id": nint})),
        "Content": obj(&["id", "title", "current_revision"], json!({
            "id": int, "title": str_, "caption": str_, "body": {"type": "string", "description": "Markdown"},
            "html": {"type": "string", "description": "sanitised HTML of the body"},
            "thumbnail_attachment_id": nint, "current_revision": int, "created_by": int,
            "created_at": time, "updated_at": time,
            "attachments": array(r("Attachment"))})),
        "NewContent": obj(&["title"], json!({"title": str_, "caption": str_, "body": str_, "comment": str_, "thumbnail_attachment_id": nint})),
        "SaveContent": obj(&["base_revision", "title"], json!({"base_revision": int, "title": str_, "caption": str_, "body": str_, "comment": str_, "thumbnail_attachment_id": nint})),
        "EditConflict": obj(&["error", "base_revision", "current_revision", "current"], json!({
            "error": str_, "base_revision": int, "current_revision": int,
            "current": r("Revision"),
            "yours": obj(&[], json!({"title": str_, "caption": str_, "body": str_, "comment": str_}))})),
        "Revision": obj(&["id", "number", "title", "body"], json!({
            "id": int, "content_id": int, "number": int, "title": str_, "caption": str_, "body": str_,
            "html": str_, "author_id": int, "author": str_, "comment": str_, "created_at": time})),
        "RevisionSummary": obj(&["id", "number"], json!({
            "id": int, "number": int, "title": str_, "author_id": int, "author": str_, "comment": str_,
            "body_bytes": int, "created_at": time})),
        "RevisionDiff": obj(&["from", "to", "body"], json!({
            "content_id": int, "from": int, "to": int,
            "title": obj(&[], json!({"from": str_, "to": str_, "changed": {"type": "boolean"}})),
            "caption": obj(&[], json!({"from": str_, "to": str_, "changed": {"type": "boolean"}})),
            "body": obj(&[], json!({"html": str_, "unified": str_, "added": int, "removed": int}))})),
        "RevertRequest": obj(&["revision"], json!({"revision": int, "base_revision": int, "comment": str_})),
        "AssignedContent": obj(&["id", "part_id", "position"], json!({
            "id": int, "assignment_id": int, "part_id": int, "position": int, "title": str_, "caption": str_,
            "thumbnail_attachment_id": nint, "current_revision": int, "updated_at": time})),
        "AssignedPart": obj(&["id", "model_id"], json!({
            "id": int, "assignment_id": int, "model_id": int, "model_title": str_, "kind": str_, "position": int})),
        "AssignRequest": obj(&["content_id"], json!({"content_id": int, "position": int})),
        "ReorderRequest": obj(&["content_ids"], json!({"content_ids": array(int.clone())})),
        "Attachment": obj(&["id", "sha256", "media_type", "size"], json!({
            "id": int, "sha256": str_, "media_type": str_, "size": int, "original_name": str_,
            "uploaded_by": int, "created_at": time})),
        "SearchHit": obj(&["id", "title", "score"], json!({
            "id": int, "title": str_, "title_html": str_, "caption": str_,
            "snippet_html": {"type": "string", "description": "escaped excerpt with matches in <b>"},
            "score": {"type": "number"},
            "parts": array(r("PartLink"))})),
        "PartLink": obj(&["id", "model_id", "url"], json!({
            "id": int, "model_id": int, "model_title": str_, "kind": str_,
            "url": {"type": "string", "description": "page opening the viewer on the part's best view: framed, highlighted, its information open"}})),
        "ChangeEvent": obj(&["type"], json!({
            "type": {"type": "string", "enum": ["part.created", "part.updated", "part.deleted", "part.contents", "content.updated", "content.deleted"]},
            "model_id": nint, "part_id": nint, "content_id": nint})),
    });
    all["Job"] = job_schema();
    all["LodHierarchy"] = lod_schema();
    render_schemas(&mut all);
    all
}

/// Schema of a build job.
fn job_schema() -> Value {
    let int = json!({"type": "integer", "format": "int64"});
    let str_ = json!({"type": "string"});
    let time = json!({"type": "string", "format": "date-time"});
    let nint = json!({"type": "integer", "format": "int64", "nullable": true});
    obj(
        &["id", "kind", "status", "percent"],
        json!({
            "id": int, "kind": {"type": "string", "enum": ["upload", "file", "demo"]},
            "model_id": nint,
            "status": {"type": "string", "enum": ["queued", "running", "done", "failed", "cancelled"]},
            "source_name": str_, "source_bytes": int,
            "options": {"type": "object", "description": "build options (memory_budget, max_patch_triangles, threads, triangles)"},
            "stage": {"type": "string", "description": "import, generating, partitioning, simplifying level N, writing, thumbnail, done"},
            "done": {"type": "integer", "description": "units of the stage done"},
            "total": {"type": "integer", "description": "units of the stage in all"},
            "percent": {"type": "number", "description": "estimate for the whole job, 0-100"},
            "message": {"type": "string", "nullable": true, "description": "why it failed"},
            "report": {"type": "object", "nullable": true, "description": "the engine's build report once done"},
            "attempts": int, "cancel_requested": {"type": "boolean"}, "created_by": nint,
            "created_at": time, "started_at": {"type": "string", "format": "date-time", "nullable": true},
            "finished_at": {"type": "string", "format": "date-time", "nullable": true}, "updated_at": time}),
    )
}

/// Schema of the JSON LOD hierarchy (docs/FORMAT.md, HTTP).
fn lod_schema() -> Value {
    let int = json!({"type": "integer", "format": "int64"});
    let nint = json!({"type": "integer", "format": "int64", "nullable": true});
    let vec3 = json!({"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3});
    obj(
        &["version", "node_count", "nodes", "groups"],
        json!({
            "version": int, "node_count": int, "group_count": int, "level_count": int, "root_count": int,
            "max_patch_triangles": int, "input_vertices": int, "input_triangles": int,
            "bbox": r("BBox"),
            "grid": obj(&["origin", "step"], json!({"origin": vec3, "step": {"type": "number"}})),
            "has_colors": {"type": "boolean"}, "has_normals": {"type": "boolean"}, "file_bytes": int,
            "nodes": array(obj(&["id", "level", "offset", "length", "crc32"], json!({
                "id": int, "level": int, "triangles": int, "vertices": int,
                "bounds": {"type": "array", "items": {"type": "number"}, "description": "x, y, z, radius"},
                "cone": {"type": "array", "items": {"type": "number"}, "description": "axis x, y, z, cutoff"},
                "lod_sphere": {"type": "array", "items": {"type": "number"}}, "lod_error": {"type": "number"},
                "parent_sphere": {"type": "array", "items": {"type": "number"}},
                "parent_error": {"type": "number", "nullable": true, "description": "null for roots"},
                "producer": nint, "member_of": nint,
                "offset": int, "length": int, "crc32": int}))),
            "groups": array(obj(&["id", "members", "products"], json!({
                "id": int, "level": int, "sphere": {"type": "array", "items": {"type": "number"}},
                "error": {"type": "number"}, "members": array(int.clone()), "products": array(int.clone())})))}),
    )
}

/// Schemas of server-side rendering (`web::render`, `render::views`) and its additions to
/// parts, assignments and search links.
fn render_schemas(all: &mut Value) {
    let int = json!({"type": "integer", "format": "int64"});
    let nint = json!({"type": "integer", "format": "int64", "nullable": true});
    let num = json!({"type": "number"});
    all["Camera"]["properties"]["auto"] = json!({"type": "boolean", "description":
        "true: the server's best view of the part (computed when the part is created without a \
         camera, and again whenever its vertex set changes); absent or false: given by a client \
         and kept. A patch with camera null hands the part back to the server's best view"});
    all["Part"]["properties"]["camera"]["description"] =
        json!("best view (auto) or the client's camera; null until the server has computed it");
    all["Part"]["properties"]["thumbnail_attachment_id"]["description"] = json!(
        "rendered by the server (320x240, the part tinted) when the part is created without one \
         and whenever its vertex set changes (unless the same request sets one)"
    );
    all["AssignedPart"]["properties"]["thumbnail_attachment_id"] = nint.clone();
    let link = &mut all["PartLink"]["properties"];
    link["thumbnail_attachment_id"] = nint;
    link["camera"] =
        json!({"allOf": [r("Camera")], "nullable": true, "description": "the part's best view"});
    link["image_url"] = json!({"type": "string", "nullable": true,
        "description": "GET /api/v1/models/{id}/render of the best view with the part tinted"});
    let rect = obj(
        &["x", "y", "w", "h"],
        json!({"x": num, "y": num, "w": num, "h": num}),
    );
    let point = json!({"type": "array", "items": num, "description": "pixel x, y (y down)"});
    all["CalloutLayout"] = obj(
        &["width", "height", "callouts", "hidden"],
        json!({
            "width": int, "height": int, "font_scale": int,
            "camera": {"type": "object", "description": "eye, target, up, fovy, width, height used"},
            "callouts": array(obj(&["part", "title", "anchor", "label", "leader"], json!({
                "part": int, "title": {"type": "string"},
                "text": {"type": "string", "description": "the label's text (long titles cut)"},
                "anchor": point, "depth": num, "label": rect,
                "leader": {"type": "array", "items": point, "description": "from the anchor to the label"},
                "placement": {"type": "string", "enum": ["around", "left", "right", "top", "bottom"]}}))),
            "hidden": array(obj(&["part", "reason"], json!({"part": int,
                "reason": {"type": "string", "enum": ["behind", "outside", "occluded", "no_room"]}})))}),
    );
}
