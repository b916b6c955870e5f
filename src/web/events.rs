//! Live co-editing: `GET /api/v1/models/{id}/events`, a server-sent event stream telling every
//! open viewer of a model that a part, its assigned information or a content changed, so it
//! can refetch what it shows within seconds without reloading.
//!
//! The events come from the application's bus ([`crate::app::events`]). A subscriber that
//! falls behind the channel receives `resync` and reloads everything.

use std::time::Duration;

use actix_web::{HttpResponse, http::header, web};
use futures_util::stream;
use tokio::sync::broadcast;

use super::auth::Reader;
use super::{ApiError, AppState};
use crate::app::events::Event;
use crate::store::models;

/// Interval of the keep-alive comments (proxies close idle connections).
const KEEP_ALIVE: Duration = Duration::from_secs(15);
/// Reconnection delay suggested to the browser, in milliseconds.
const RETRY_MS: u32 = 2000;

/// Mounts the route.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/models/{id}/events").route(web::get().to(events)));
}

/// This module's operations in the OpenAPI document ([`super::openapi`]), with the
/// `ChangeEvent` schema of the `change` messages' data (a stream has no JSON body to
/// collect it from).
#[derive(utoipa::OpenApi)]
#[openapi(paths(events), components(schemas(Event)))]
pub(super) struct Api;

struct StreamState {
    rx: broadcast::Receiver<Event>,
    model_id: i64,
    keep_alive: tokio::time::Interval,
    greeted: bool,
}

fn message(event: &str, data: &str) -> web::Bytes {
    web::Bytes::from(format!("event: {event}\ndata: {data}\n\n"))
}

async fn next_chunk(
    mut s: StreamState,
) -> Option<(Result<web::Bytes, std::convert::Infallible>, StreamState)> {
    if !s.greeted {
        s.greeted = true;
        let hello = format!(
            "retry: {RETRY_MS}\nevent: hello\ndata: {{\"model_id\":{}}}\n\n",
            s.model_id
        );
        return Some((Ok(web::Bytes::from(hello)), s));
    }
    loop {
        tokio::select! {
            received = s.rx.recv() => match received {
                Ok(event) if event.concerns(s.model_id) => {
                    let data = serde_json::to_string(&event).unwrap_or_default();
                    return Some((Ok(message("change", &data)), s));
                }
                Ok(_) => continue,
                Err(broadcast::error::RecvError::Lagged(missed)) => {
                    let data = format!("{{\"missed\":{missed}}}");
                    return Some((Ok(message("resync", &data)), s));
                }
                Err(broadcast::error::RecvError::Closed) => return None,
            },
            _ = s.keep_alive.tick() => {
                return Some((Ok(web::Bytes::from_static(b": keep-alive\n\n")), s));
            }
        }
    }
}

/// Live changes of a model's parts and their information
///
/// A `text/event-stream` (server-sent events) telling an open viewer that a part, its assigned
/// information or a content changed, so it can refetch what it shows:
///
/// - `hello` first, with data `{"model_id": N}` (and `retry: 2000`, the reconnection delay in
///   milliseconds);
/// - `change` messages whose data is a `ChangeEvent` (JSON; see the schema of that name):
///   the model's part events and every content event (contents may be assigned to parts of
///   any model);
/// - `resync` with data `{"missed": N}` when the client fell behind and must reload
///   everything;
/// - keep-alive comments (`: keep-alive`) every 15 s.
#[utoipa::path(get, path = "/api/v1/models/{id}/events", tag = "models",
    params(("id" = i64, Path, description = "model id")),
    responses((status = 200,
        description = "Event stream: `hello`, then `change` messages with a ChangeEvent as \
            data, `resync` and keep-alive comments",
        body = String, content_type = "text/event-stream")),
    security((), ("sessionCookie" = ["viewer"])))]
async fn events(
    state: web::Data<AppState>,
    reader: Reader,
    model_id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
    reader.model(&state.db, *model_id).await?;
    let model = models::get(&state.db, *model_id).await?;
    let mut keep_alive = tokio::time::interval(KEEP_ALIVE);
    keep_alive.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    keep_alive.reset();
    let start = StreamState {
        rx: state.events.subscribe(),
        model_id: model.id,
        keep_alive,
        greeted: false,
    };
    Ok(HttpResponse::Ok()
        .insert_header((header::CONTENT_TYPE, "text/event-stream"))
        .insert_header((header::CACHE_CONTROL, "no-cache, no-transform"))
        // The compression middleware leaves encoded bodies alone: events go out unbuffered.
        .insert_header((header::CONTENT_ENCODING, "identity"))
        .insert_header(("X-Accel-Buffering", "no"))
        .streaming(stream::unfold(start, next_chunk)))
}
