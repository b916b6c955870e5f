//! HTTP layer (actix-web): the JSON API under `/api/v1`, server-rendered pages, static
//! files. One module per resource; [`configure`] mounts them all.

pub mod assignments;
pub mod attachments;
pub mod auth;
pub mod client;
pub mod contents;
pub mod error;
pub mod events;
#[doc(hidden)]
pub mod fuzzing;
pub mod jobs;
pub mod layout;
pub mod lod;
pub mod lumigraph;
pub mod models;
pub mod multipart;
pub mod openapi;
pub mod pages;
pub mod parts;
pub mod render;
pub mod search;
pub mod segments;
pub mod selections;
pub mod session;
pub mod static_files;
pub mod uploads;
pub mod users;
pub mod vendor;

use std::net::SocketAddr;
use std::time::Instant;

use actix_web::body::MessageBody;
use actix_web::dev::{ServiceRequest, ServiceResponse};
use actix_web::middleware::{self, DefaultHeaders, Next};
use actix_web::{App, HttpRequest, HttpServer, web};
use serde::Deserialize;

use crate::store::Page;
pub use error::{ApiError, PageError};

/// Shared state of every request: the application (handlers call its use cases).
pub type AppState = crate::app::App;
pub use crate::app::StartError;

/// `limit` / `offset` query parameters of list routes.
#[derive(Debug, Clone, Copy, Default, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct PageQuery {
    /// Rows to return (1–1000, default 100).
    pub limit: Option<i64>,
    /// Rows to skip.
    pub offset: Option<i64>,
}

impl PageQuery {
    /// As a store page.
    pub fn page(&self) -> Page {
        Page::new(self.limit, self.offset)
    }
}

/// A resource whose unknown methods answer 405 JSON. Every route of the app is mounted
/// through here, which records its path ([`mounted_paths`]).
pub fn resource(path: &str) -> actix_web::Resource {
    if let Ok(mut paths) = MOUNTED.lock() {
        paths.insert(path.to_string());
    }
    web::resource(path).default_service(web::to(|| async {
        Err::<actix_web::HttpResponse, _>(ApiError::MethodNotAllowed)
    }))
}

static MOUNTED: std::sync::Mutex<std::collections::BTreeSet<String>> =
    std::sync::Mutex::new(std::collections::BTreeSet::new());

/// The path of every resource mounted so far by [`configure`] in this process (for the test
/// that the OpenAPI document covers the running app; a resource answers 405 to a method it
/// does not mount).
pub fn mounted_paths() -> Vec<String> {
    MOUNTED
        .lock()
        .map(|p| p.iter().cloned().collect())
        .unwrap_or_default()
}

/// Mounts every route.
pub fn configure(cfg: &mut web::ServiceConfig) {
    session::configure(cfg);
    users::configure(cfg);
    jobs::configure(cfg);
    uploads::configure(cfg);
    models::configure(cfg);
    lod::configure(cfg);
    lumigraph::configure(cfg);
    parts::configure(cfg);
    selections::configure(cfg);
    segments::configure(cfg);
    render::configure(cfg);
    contents::configure(cfg);
    assignments::configure(cfg);
    attachments::configure(cfg);
    search::configure(cfg);
    events::configure(cfg);
    client::configure(cfg);
    openapi::configure(cfg);
    vendor::configure(cfg);
    static_files::configure(cfg);
    pages::configure(cfg);
}

async fn not_found(req: HttpRequest) -> Result<actix_web::HttpResponse, actix_web::Error> {
    let err = ApiError::NotFound(format!("no route for {} {}", req.method(), req.path()));
    if req.path().starts_with("/api/") {
        Err(err.into())
    } else {
        Err(PageError::Api(err).into())
    }
}

fn security_headers() -> DefaultHeaders {
    DefaultHeaders::new()
        .add(("X-Content-Type-Options", "nosniff"))
        .add(("X-Frame-Options", "DENY"))
        .add(("Referrer-Policy", "same-origin"))
        .add(("Cross-Origin-Opener-Policy", "same-origin"))
        .add((
            "Permissions-Policy",
            "camera=(), microphone=(), geolocation=()",
        ))
        .add(("Content-Security-Policy", content_security_policy()))
        .add(("Cache-Control", "no-cache, private"))
}

/// The Content-Security-Policy of every response. Scripts: same-origin files, the viewer's
/// inline import map (by hash) and WebAssembly compilation (meshoptimizer's decoder).
fn content_security_policy() -> String {
    format!(
        "default-src 'self'; img-src 'self' data: blob:; style-src 'self'; \
         script-src 'self' 'wasm-unsafe-eval' {}; worker-src 'self'; connect-src 'self'; \
         object-src 'none'; base-uri 'self'; form-action 'self'; frame-ancestors 'none'",
        vendor::import_map_csp_hash()
    )
}

async fn log_requests(
    req: ServiceRequest,
    next: Next<impl MessageBody>,
) -> Result<ServiceResponse<impl MessageBody>, actix_web::Error> {
    let start = Instant::now();
    let method = req.method().clone();
    let path = req.path().to_string();
    let res = next.call(req).await?;
    let status = res.status();
    let ms = start.elapsed().as_secs_f64() * 1000.0;
    if status.is_server_error() {
        tracing::error!(%method, %path, status = status.as_u16(), ms, "request");
    } else {
        tracing::debug!(%method, %path, status = status.as_u16(), ms, "request");
    }
    Ok(res)
}

/// Serves `state` on `state.settings.bind` until SIGINT/SIGTERM, with the background build
/// workers of `state.jobs`. `on_bound` is called with the bound addresses once listening (the
/// port may have been chosen by the OS).
pub async fn run(state: AppState, on_bound: impl FnOnce(&[SocketAddr])) -> std::io::Result<()> {
    let settings = state.settings.clone();
    let data = web::Data::new(state.clone());
    let json_limit = settings.limits.json_body;
    let form_limit = settings.limits.form_body;
    let mut server = HttpServer::new(move || {
        App::new()
            .app_data(data.clone())
            .app_data(
                web::JsonConfig::default()
                    .limit(json_limit)
                    .error_handler(error::json_error),
            )
            .app_data(web::PathConfig::default().error_handler(error::path_error))
            .app_data(web::QueryConfig::default().error_handler(error::query_error))
            .app_data(
                web::FormConfig::default()
                    .limit(form_limit)
                    .error_handler(error::form_error),
            )
            .configure(configure)
            .default_service(web::to(not_found))
            .wrap(middleware::from_fn(pages::error_pages))
            .wrap(middleware::Compress::default())
            .wrap(security_headers())
            .wrap(middleware::from_fn(log_requests))
    });
    if settings.workers > 0 {
        server = server.workers(settings.workers);
    }
    // Event streams never finish on their own: do not wait 30 s for them on shutdown.
    server = server.shutdown_timeout(5);
    let server = server.bind(&settings.bind)?;
    // Background work: crash recovery and the build workers (stopped, and their jobs queued
    // again, when the server stops), best views and thumbnails of parts.
    let _background = state.start().await.map_err(std::io::Error::other)?;
    on_bound(&server.addrs());
    let result = server.run().await;
    state.shutdown().await;
    result
}
