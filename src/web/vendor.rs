//! Front-end dependencies of the 3D viewer (three.js, meshoptimizer's decoder, fzstd), served
//! as ES modules at `/static/vendor/{package}/{file}` straight from `static/node_modules`
//! (installed by `npm ci --prefix static`, pinned by `static/package-lock.json`).
//!
//! Only the files of [`ALLOWED`] are served: the request path is compared with that list and
//! never joined onto a directory, so no request can reach another file. When the packages are
//! not installed the server still runs; the model page then says the viewer is unavailable.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use actix_web::{HttpResponse, http::header, web};
use sha2::Digest;

use super::ApiError;

/// Files served, relative to `node_modules`.
pub const ALLOWED: &[&str] = &[
    "three/build/three.module.js",
    "three/build/three.core.js",
    "three/examples/jsm/controls/OrbitControls.js",
    "meshoptimizer/meshopt_decoder.mjs",
    "fzstd/esm/index.mjs",
];

/// The import map of the viewer page: bare specifiers of the vendor modules.
pub const IMPORT_MAP: &str = r#"{"imports":{"three":"/static/vendor/three/build/three.module.js","three/addons/":"/static/vendor/three/examples/jsm/","meshoptimizer/decoder":"/static/vendor/meshoptimizer/meshopt_decoder.mjs","fzstd":"/static/vendor/fzstd/esm/index.mjs"}}"#;

/// Environment variable naming the `node_modules` directory to serve from.
pub const DIR_ENV: &str = "MESHWIKI_NODE_MODULES";

/// The `node_modules` directory holding every allowed file, if any: `$MESHWIKI_NODE_MODULES`
/// when set (and only it), else `static/node_modules` under the working directory, else under
/// the source tree the binary was built from. Looked up once.
pub fn dir() -> Option<&'static Path> {
    static DIR: OnceLock<Option<PathBuf>> = OnceLock::new();
    DIR.get_or_init(|| {
        let candidates = match std::env::var_os(DIR_ENV) {
            Some(d) => vec![PathBuf::from(d)],
            None => vec![
                PathBuf::from("static/node_modules"),
                Path::new(env!("CARGO_MANIFEST_DIR")).join("static/node_modules"),
            ],
        };
        let found = candidates
            .into_iter()
            .find(|d| ALLOWED.iter().all(|f| d.join(f).is_file()));
        match &found {
            Some(d) => tracing::debug!(dir = %d.display(), "viewer dependencies found"),
            None => tracing::warn!(
                "3D viewer disabled: front-end dependencies are missing (run `npm ci --prefix static`)"
            ),
        }
        found
    })
    .as_deref()
}

/// Whether the viewer's dependencies are installed.
pub fn available() -> bool {
    dir().is_some()
}

/// `'sha256-…'` source of the inline import map, for the Content-Security-Policy.
pub fn import_map_csp_hash() -> String {
    format!(
        "'sha256-{}'",
        base64(&sha2::Sha256::digest(IMPORT_MAP.as_bytes()))
    )
}

/// Standard base64 with padding.
fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for (i, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if i <= chunk.len() {
                out.push(ALPHABET[((n >> shift) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Mounts `/static/vendor/{path}`.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/static/vendor/{path:.*}").route(web::get().to(get)));
}

async fn get(path: web::Path<String>) -> Result<HttpResponse, ApiError> {
    let not_found = || ApiError::NotFound(format!("no vendor file {:?}", path.as_str()));
    let name = ALLOWED
        .iter()
        .find(|f| **f == path.as_str())
        .ok_or_else(not_found)?;
    let dir = dir().ok_or_else(|| {
        ApiError::NotFound("the viewer's dependencies are not installed".to_string())
    })?;
    let body = tokio::fs::read(dir.join(name))
        .await
        .map_err(|_| not_found())?;
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "text/javascript; charset=utf-8"))
        .insert_header((header::CACHE_CONTROL, "public, max-age=86400"))
        .body(body))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_the_standard_alphabet() {
        assert_eq!(base64(b""), "");
        assert_eq!(base64(b"f"), "Zg==");
        assert_eq!(base64(b"fo"), "Zm8=");
        assert_eq!(base64(b"foo"), "Zm9v");
        assert_eq!(base64(b"foobar"), "Zm9vYmFy");
    }

    #[test]
    fn the_import_map_only_names_allowed_files() {
        let map: serde_json::Value = serde_json::from_str(IMPORT_MAP).expect("json");
        for (_, url) in map["imports"].as_object().expect("imports") {
            let url = url.as_str().expect("string");
            let rel = url.strip_prefix("/static/vendor/").expect("vendor url");
            assert!(
                rel.ends_with('/') || ALLOWED.contains(&rel),
                "{rel} is not allowed"
            );
        }
    }
}
