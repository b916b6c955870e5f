//! Static files (CSS, the viewer's JavaScript modules), embedded in the binary and served at
//! `/static/{name}` and `/static/js/{path}`. The viewer's third-party modules are served from
//! disk by [`super::vendor`].

use actix_web::{HttpResponse, http::header, web};

use super::ApiError;

const FILES: &[(&str, &str, &str)] = &[
    (
        "style.css",
        "text/css; charset=utf-8",
        include_str!("../../static/style.css"),
    ),
    (
        "edit.js",
        "text/javascript; charset=utf-8",
        include_str!("../../static/edit.js"),
    ),
    (
        "jobs.js",
        "text/javascript; charset=utf-8",
        include_str!("../../static/jobs.js"),
    ),
    (
        "upload.js",
        "text/javascript; charset=utf-8",
        include_str!("../../static/upload.js"),
    ),
    (
        "login.js",
        "text/javascript; charset=utf-8",
        include_str!("../../static/login.js"),
    ),
];

macro_rules! js_modules {
    ($($path:literal),* $(,)?) => {
        &[$(($path, include_str!(concat!("../../static/js/", $path)))),*]
    };
}

/// The viewer's ES modules (`static/js/`), by path relative to that directory.
pub const JS_MODULES: &[(&str, &str)] = js_modules![
    "lod/budget.js",
    "lod/cache.js",
    "lod/cut.js",
    "lod/decode.js",
    "lod/foveation.js",
    "lod/rangecoder.js",
    "lod/stream.js",
    "lod/table.js",
    "lod/worker.js",
    "lod/workers.js",
    "lumigraph/image.js",
    "lumigraph/repository.js",
    "parts/callouts.js",
    "parts/live.js",
    "parts/match.js",
    "parts/panel.js",
    "parts/parts.js",
    "parts/picker.js",
    "parts/place.js",
    "parts/roaring.js",
    "select/api.js",
    "select/assign.js",
    "select/controller.js",
    "select/draw.js",
    "select/highlight.js",
    "select/png.js",
    "select/raster.js",
    "select/segments.js",
    "select/session.js",
    "select/tools.js",
    "viewer/drawer.js",
    "viewer/main.js",
    "viewer/navigation.js",
    "viewer/outline.js",
    "viewer/picking.js",
    "viewer/scene.js",
    "viewer/toolbar.js",
    "viewer/url.js",
];

/// Mounts `/static/{name}` and `/static/js/{path}`.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/static/js/{path:.*}").route(web::get().to(get_js)))
        .service(super::resource("/static/{name}").route(web::get().to(get)));
}

async fn get(name: web::Path<String>) -> Result<HttpResponse, ApiError> {
    let (_, mime, body) = FILES
        .iter()
        .find(|(n, _, _)| *n == name.as_str())
        .ok_or_else(|| ApiError::NotFound(format!("no static file {name:?}")))?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, *mime))
        .insert_header((header::CACHE_CONTROL, "public, max-age=3600"))
        .body(*body))
}

async fn get_js(path: web::Path<String>) -> Result<HttpResponse, ApiError> {
    let (_, body) = JS_MODULES
        .iter()
        .find(|(p, _)| *p == path.as_str())
        .ok_or_else(|| ApiError::NotFound(format!("no static file {:?}", path.as_str())))?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "text/javascript; charset=utf-8"))
        // Revalidated on each load: the modules change with the binary.
        .insert_header((header::CACHE_CONTROL, "no-cache"))
        .body(*body))
}

#[cfg(test)]
mod tests {
    use super::JS_MODULES;
    use std::path::Path;

    fn walk(dir: &Path, root: &Path, out: &mut Vec<String>) {
        for entry in std::fs::read_dir(dir).expect("read static/js").flatten() {
            let path = entry.path();
            if path.is_dir() {
                walk(&path, root, out);
            } else if path.extension().is_some_and(|e| e == "js") {
                let rel = path.strip_prefix(root).expect("under root");
                out.push(rel.to_string_lossy().replace('\\', "/"));
            }
        }
    }

    #[test]
    fn every_module_in_static_js_is_embedded() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("static/js");
        let mut found = Vec::new();
        walk(&root, &root, &mut found);
        for f in &found {
            assert!(
                JS_MODULES.iter().any(|(p, _)| p == f),
                "static/js/{f} is not listed in JS_MODULES"
            );
        }
    }
}
