//! The generated OpenAPI document covers the running app: every `/api/v1` resource that the
//! app mounts (read from the app's own configuration, not from a list) is documented with
//! exactly the methods the running server answers (a method a resource does not mount answers
//! 405), and every operation documents its role, summary and responses.

use serde_json::Value;

use crate::harness::{Server, data_dir_with_admin};

/// The `/api/v1` paths that `meshwiki::web::configure` mounts, found by configuring an app.
fn mounted_api_paths() -> Vec<String> {
    let _app = actix_web::App::new().configure(meshwiki::web::configure);
    meshwiki::web::mounted_paths()
        .into_iter()
        .filter(|p| p.starts_with("/api/v1/"))
        .collect()
}

/// `path` with every `{param}` replaced by a value of the right shape.
fn concrete(path: &str) -> String {
    let mut out = String::new();
    let mut rest = path;
    while let Some(open) = rest.find('{') {
        out.push_str(&rest[..open]);
        let close = rest[open..].find('}').map_or(rest.len(), |c| open + c + 1);
        out.push_str(match &rest[open..close] {
            "{draft}" => "nodraft",
            _ => "1",
        });
        rest = &rest[close..];
    }
    out.push_str(rest);
    out
}

#[test]
fn every_mounted_route_is_documented_with_its_methods() {
    let mounted = mounted_api_paths();
    assert!(
        mounted.len() >= 40,
        "only {} /api/v1 resources mounted: {mounted:?}",
        mounted.len()
    );
    let dir = data_dir_with_admin();
    let server = Server::start(dir.path());
    let client = server.client();
    let doc = client.get("/api/v1/openapi.json");
    assert_eq!(doc.status, 200);
    assert_eq!(doc.header("content-type"), Some("application/json"));
    let doc = doc.json();
    assert!(doc["openapi"].as_str().unwrap_or("").starts_with("3.1"));
    let paths = doc["paths"].as_object().expect("paths");

    let mut problems = Vec::new();
    for path in &mounted {
        let Some(item) = paths.get(path) else {
            problems.push(format!("{path}: mounted, not documented"));
            continue;
        };
        let url = concrete(path);
        for method in ["GET", "POST", "PUT", "PATCH", "DELETE", "HEAD", "OPTIONS"] {
            // Without a session: a mounted method answers its own status (401, 403, 404, 200…),
            // an unmounted one 405.
            let status = client.request(method, &url, None, Vec::new(), false).status;
            let documented = item.get(method.to_lowercase()).is_some();
            if (status != 405) != documented {
                problems.push(format!(
                    "{method} {path}: answers {status}, documented: {documented}"
                ));
            }
        }
    }
    for path in paths.keys() {
        if !mounted.contains(path) {
            problems.push(format!("{path}: documented, not mounted"));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));

    // Every operation: a summary, a tag, its role (or public) and JSON errors.
    for (path, item) in paths {
        for (method, op) in item.as_object().expect("path item") {
            let what = format!("{method} {path}");
            assert!(
                op["summary"].as_str().is_some_and(|s| !s.is_empty()),
                "{what}"
            );
            assert!(op["tags"][0].is_string(), "{what}");
            let security = op["security"].as_array().expect("security");
            let description = op["description"].as_str().unwrap_or("");
            match security.first() {
                None => assert!(description.ends_with("Public."), "{what}"),
                Some(req) => {
                    let role = req["sessionCookie"][0].as_str().unwrap_or("");
                    assert!(
                        ["viewer", "editor", "admin"].contains(&role),
                        "{what}: role {role:?}"
                    );
                    assert!(description.contains(&format!("`{role}`")), "{what}");
                    let writes = ["post", "put", "patch", "delete"].contains(&method.as_str());
                    assert_eq!(req.get("csrfToken").is_some(), writes, "{what}: CSRF");
                    assert!(op["responses"]["401"].is_object(), "{what}");
                }
            }
            let responses = op["responses"].as_object().expect("responses");
            assert!(
                responses.keys().any(|s| s.starts_with('2') || s == "304"),
                "{what}: no success response"
            );
            let error = &op["responses"]["404"]["content"]["application/json"]["schema"];
            assert_eq!(error["$ref"], "#/components/schemas/ErrorBody", "{what}");
        }
    }
    // The login route is public; a route's documented role is the one it enforces.
    assert_eq!(
        paths["/api/v1/session"]["post"]["security"],
        Value::Array(vec![])
    );
    assert_eq!(
        paths["/api/v1/users"]["get"]["security"][0]["sessionCookie"][0],
        "admin"
    );
}
