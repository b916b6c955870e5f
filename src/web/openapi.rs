//! `GET /api/v1/openapi.json`: the OpenAPI 3.1 description of the JSON API, generated
//! (utoipa) from the handlers and the types they read and write, never written by hand.
//!
//! Each resource module annotates its handlers with `#[utoipa::path(...)]` (method, path,
//! parameters, body, responses, role) and lists them in its own `Api`; the types derive
//! `ToSchema`/`IntoParams` next to their serde derives, so a field added to a type is in the
//! document at once. [`document`] merges the modules' parts and applies the conventions that
//! hold for every operation ([`conventions`]):
//!
//! - **Roles.** An operation names its minimum role as the scope of the `sessionCookie`
//!   requirement (`security(("sessionCookie" = ["editor"]))`); a public one has the empty
//!   requirement (`security(())`). The role is repeated in the description, and every
//!   state-changing operation (POST, PUT, PATCH, DELETE) that needs a session also requires
//!   the `csrfToken` header.
//! - **Errors.** Every error is JSON [`ErrorBody`]; an operation lists the errors particular
//!   to it (409, 413, 416, 503…) and gets 400, 404 and, when it needs a session, 401 and 403.
//!
//! `tests/server/openapi.rs` checks that every route mounted on the running app is
//! documented with exactly its methods; `tests/browser/openapi.test.mjs` validates real
//! responses of a running server against these schemas.

use std::sync::OnceLock;

use actix_web::{HttpResponse, http::header, web};
use serde::Serialize;
use serde_json::{Value, json};
use utoipa::{OpenApi, ToSchema};

/// Mounts the route.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/openapi.json").route(web::get().to(get)))
        .service(super::resource("/api/v1/health").route(web::get().to(health)));
}

/// The JSON body of every error response.
#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorBody {
    /// What went wrong, for people.
    pub error: String,
}

/// Raw bytes (a schema for binary bodies).
#[derive(ToSchema)]
#[schema(value_type = String, format = Binary)]
pub struct Binary(pub Vec<u8>);

/// Liveness.
#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    /// Always `ok`.
    pub status: &'static str,
}

/// This document.
#[utoipa::path(get, path = "/api/v1/openapi.json", tag = "meta", security(()),
    responses((status = 200, description = "The OpenAPI 3.1 document", body = Object)))]
async fn get() -> HttpResponse {
    HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "application/json"))
        .body(document_json())
}

/// Liveness check.
#[utoipa::path(get, path = "/api/v1/health", tag = "meta", security(()),
    responses((status = 200, description = "The server answers", body = Health)))]
async fn health() -> HttpResponse {
    HttpResponse::Ok().json(Health { status: "ok" })
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "meshwiki API",
        description = "Wiki information attached to regions of huge 3D scans. Log in with \
            POST /api/v1/session; the session cookie authenticates later requests and every \
            state-changing request (POST, PUT, PATCH, DELETE) must carry the returned \
            csrf_token in the X-CSRF-Token header. Errors are JSON {\"error\": \"...\"}. \
            Lists are JSON arrays."
    ),
    paths(get, health),
    components(schemas(ErrorBody, Binary))
)]
struct Root;

/// The document: every module's operations, with the [`conventions`] applied.
pub fn document() -> Value {
    let mut doc = Root::openapi();
    for part in [
        super::session::Api::openapi(),
        super::users::Api::openapi(),
        super::jobs::Api::openapi(),
        super::uploads::Api::openapi(),
        super::models::Api::openapi(),
        super::lod::Api::openapi(),
        super::lumigraph::Api::openapi(),
        super::parts::Api::openapi(),
        super::selections::Api::openapi(),
        super::segments::Api::openapi(),
        super::render::Api::openapi(),
        super::contents::Api::openapi(),
        super::assignments::Api::openapi(),
        super::attachments::Api::openapi(),
        super::search::Api::openapi(),
        super::events::Api::openapi(),
        super::client::Api::openapi(),
    ] {
        doc.merge(part);
    }
    let mut doc = serde_json::to_value(doc).unwrap_or_else(|e| json!({ "error": e.to_string() }));
    conventions(&mut doc);
    doc
}

/// The document, serialised once.
fn document_json() -> &'static [u8] {
    static DOC: OnceLock<Vec<u8>> = OnceLock::new();
    DOC.get_or_init(|| serde_json::to_vec(&document()).unwrap_or_default())
}

/// Methods that change state (they need the CSRF header as well as the session).
const WRITES: [&str; 4] = ["post", "put", "patch", "delete"];
/// Every HTTP method an OpenAPI path item can hold.
pub const METHODS: [&str; 8] = [
    "get", "put", "post", "delete", "options", "head", "patch", "trace",
];

/// Applies the conventions of the module documentation: roles (description and the CSRF
/// requirement of writes), the security schemes, and the common error responses.
pub fn conventions(doc: &mut Value) {
    doc["servers"] = json!([{ "url": "/" }]);
    doc["info"]["version"] = json!(env!("CARGO_PKG_VERSION"));
    doc["components"]["securitySchemes"] = json!({
        "sessionCookie": { "type": "apiKey", "in": "cookie", "name": super::auth::SESSION_COOKIE,
            "description": "The session cookie set by POST /api/v1/session. Its scope in an operation's requirement is the minimum role (viewer < editor < admin)." },
        "csrfToken": { "type": "apiKey", "in": "header", "name": "X-CSRF-Token",
            "description": "The session's csrf_token, on every state-changing request." }
    });
    let error =
        json!({ "application/json": { "schema": { "$ref": "#/components/schemas/ErrorBody" } } });
    let Some(paths) = doc["paths"].as_object_mut() else {
        return;
    };
    for (path, item) in paths.iter_mut() {
        for method in METHODS {
            let Some(op) = item.get_mut(method) else {
                continue;
            };
            let role = op["security"]
                .as_array()
                .and_then(|reqs| reqs.iter().find_map(|r| r.get("sessionCookie")))
                .and_then(|scopes| scopes.get(0))
                .and_then(Value::as_str)
                .map(str::to_string);
            // `security((), ("sessionCookie" = ["viewer"]))`: anonymous visitors may make this
            // read where the model is public (`store::visibility`).
            let anonymous_too = role.is_some()
                && op["security"].as_array().is_some_and(|reqs| {
                    reqs.iter()
                        .any(|r| r.as_object().is_some_and(|o| o.is_empty()))
                });
            let note = match &role {
                Some(role) if anonymous_too => format!(
                    "Requires the `{role}` role or higher, or none when the model it concerns is public (anonymous visitors read public models)."
                ),
                Some(role) => format!("Requires the `{role}` role or higher."),
                None => "Public.".to_string(),
            };
            let description = match op["description"].as_str() {
                Some(d) if !d.is_empty() => format!("{d}\n\n{note}"),
                _ => note,
            };
            op["description"] = json!(description);
            if let Some(role) = &role {
                let mut req = json!({ "sessionCookie": [role] });
                if WRITES.contains(&method) {
                    req["csrfToken"] = json!([]);
                }
                op["security"] = if anonymous_too {
                    json!([req, {}])
                } else {
                    json!([req])
                };
            } else {
                op["security"] = json!([]);
            }
            if op.get("operationId").is_some() {
                // Handler names repeat across modules (`list`, `get`): make them unique.
                op["operationId"] = json!(operation_id(method, path));
            }
            let mut common = vec![("400", "Invalid input"), ("404", "Not found")];
            if role.is_some() {
                common.push(("401", "No session"));
                common.push(("403", "Role or CSRF check failed"));
            }
            let responses = &mut op["responses"];
            if !responses.is_object() {
                *responses = json!({});
            }
            for (status, what) in common {
                if responses.get(status).is_none() {
                    responses[status] = json!({ "description": what, "content": error.clone() });
                }
            }
        }
    }
}

/// `get /api/v1/parts/{id}/revisions` → `getPartsIdRevisions`.
fn operation_id(method: &str, path: &str) -> String {
    let mut id = method.to_string();
    for word in path
        .trim_start_matches("/api/v1/")
        .split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|w| !w.is_empty())
    {
        let mut chars = word.chars();
        if let Some(first) = chars.next() {
            id.push(first.to_ascii_uppercase());
            id.extend(chars);
        }
    }
    id
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn operation_ids_are_unique_and_every_reference_resolves() {
        let doc = document();
        let mut ids = std::collections::BTreeSet::new();
        for (path, item) in doc["paths"].as_object().expect("paths") {
            for m in METHODS {
                if let Some(op) = item.get(m) {
                    let id = op["operationId"].as_str().expect("operationId").to_string();
                    assert!(ids.insert(id.clone()), "{id} twice ({m} {path})");
                    assert!(op["summary"].is_string(), "{m} {path} has no summary");
                    assert!(op["tags"].is_array(), "{m} {path} has no tag");
                }
            }
        }
        let schemas = doc["components"]["schemas"].as_object().expect("schemas");
        let text = doc.to_string();
        for part in text.split("#/components/schemas/").skip(1) {
            let name: String = part
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == '.')
                .collect();
            assert!(schemas.contains_key(&name), "unresolved $ref {name}");
        }
    }

    #[test]
    fn roles_become_security_requirements() {
        let doc = document();
        let op = &doc["paths"]["/api/v1/parts/{id}"]["patch"];
        assert_eq!(
            op["security"],
            json!([{ "sessionCookie": ["editor"], "csrfToken": [] }])
        );
        assert!(op["description"].as_str().unwrap().contains("`editor`"));
        assert!(op["responses"]["403"].is_object());
        let public = &doc["paths"]["/api/v1/health"]["get"];
        assert_eq!(public["security"], json!([]));
        assert!(public["responses"]["401"].is_null());
    }
}
