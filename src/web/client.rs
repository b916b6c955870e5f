//! `GET /api/v1/config`: the limits and settings clients size their requests to
//! ([`crate::app::client::ClientConfig`]; the model page embeds the same object).

use actix_web::{HttpResponse, web};

use super::auth::Reader;
use super::{ApiError, AppState};
use crate::app::client::ClientConfig;

/// Mounts the route.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/config").route(web::get().to(get)));
}

/// This module's operations in the OpenAPI document ([`super::openapi`]).
#[derive(utoipa::OpenApi)]
#[openapi(paths(get))]
pub(super) struct Api;

/// The server's limits for clients
///
/// The largest view it renders (selection masks must fit it), upload and text limits, and
/// how long draft selections are kept.
#[utoipa::path(get, path = "/api/v1/config", tag = "meta",
    responses((status = 200, description = "The limits", body = ClientConfig)),
    security((), ("sessionCookie" = ["viewer"])))]
async fn get(state: web::Data<AppState>, _reader: Reader) -> Result<HttpResponse, ApiError> {
    Ok(HttpResponse::Ok().json(state.client_config()))
}
