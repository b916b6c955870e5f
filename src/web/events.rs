//! Live co-editing: `GET /api/v1/models/{id}/events`, a server-sent event stream telling every
//! open viewer of a model that a part, its assigned information or a content changed, so it
//! can refetch what it shows within seconds without reloading.
//!
//! Handlers publish an [`Event`] on the [`Events`] broadcast channel (in `AppState`) after
//! their transaction has committed. Events carry only kinds and ids, never data: a viewer
//! fetches what changed through the ordinary API with its own session. A subscriber that falls
//! behind the channel receives `resync` and reloads everything.

use std::time::Duration;

use actix_web::{HttpResponse, http::header, web};
use futures_util::stream;
use serde::Serialize;
use tokio::sync::broadcast;

use super::auth::Auth;
use super::{ApiError, AppState};
use crate::store::models;

/// Events buffered per subscriber before it is told to resync.
const CAPACITY: usize = 256;
/// Interval of the keep-alive comments (proxies close idle connections).
const KEEP_ALIVE: Duration = Duration::from_secs(15);
/// Reconnection delay suggested to the browser, in milliseconds.
const RETRY_MS: u32 = 2000;

/// What changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum EventKind {
    /// A part was created.
    #[serde(rename = "part.created")]
    PartCreated,
    /// A part's geometry, camera or thumbnail changed.
    #[serde(rename = "part.updated")]
    PartUpdated,
    /// A part was deleted.
    #[serde(rename = "part.deleted")]
    PartDeleted,
    /// The contents assigned to a part (or their order) changed.
    #[serde(rename = "part.contents")]
    PartContents,
    /// A content was saved, reverted or had its attachments changed.
    #[serde(rename = "content.updated")]
    ContentUpdated,
    /// A content was deleted.
    #[serde(rename = "content.deleted")]
    ContentDeleted,
}

/// One change, as sent to viewers (JSON in the `data` field of an SSE message whose `event`
/// is `change`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Event {
    /// What changed.
    #[serde(rename = "type")]
    pub kind: EventKind,
    /// Model concerned; `None` for contents, which may be assigned to parts of any model.
    pub model_id: Option<i64>,
    /// Part concerned.
    pub part_id: Option<i64>,
    /// Content concerned.
    pub content_id: Option<i64>,
}

impl Event {
    /// A part event.
    pub fn part(kind: EventKind, model_id: i64, part_id: i64) -> Event {
        Event {
            kind,
            model_id: Some(model_id),
            part_id: Some(part_id),
            content_id: None,
        }
    }

    /// A content event (relevant to every model).
    pub fn content(kind: EventKind, content_id: i64) -> Event {
        Event {
            kind,
            model_id: None,
            part_id: None,
            content_id: Some(content_id),
        }
    }

    fn concerns(&self, model_id: i64) -> bool {
        self.model_id.is_none_or(|m| m == model_id)
    }
}

/// The broadcast channel of change events.
#[derive(Debug, Clone)]
pub struct Events {
    tx: broadcast::Sender<Event>,
}

impl Default for Events {
    fn default() -> Self {
        Events::new()
    }
}

impl Events {
    /// A channel with no subscribers.
    pub fn new() -> Events {
        Events {
            tx: broadcast::channel(CAPACITY).0,
        }
    }

    /// Sends `event` to every open stream (dropped when nobody listens).
    pub fn publish(&self, event: Event) {
        tracing::debug!(?event, "publish");
        let _ = self.tx.send(event);
    }

    /// A new subscription.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.tx.subscribe()
    }
}

/// Mounts the route.
pub fn configure(cfg: &mut web::ServiceConfig) {
    cfg.service(super::resource("/api/v1/models/{id}/events").route(web::get().to(events)));
}

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

/// `GET /api/v1/models/{id}/events`: `text/event-stream` of `change` messages for the model.
async fn events(
    state: web::Data<AppState>,
    _auth: Auth,
    model_id: web::Path<i64>,
) -> Result<HttpResponse, ApiError> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn content_events_concern_every_model_and_part_events_one() {
        let p = Event::part(EventKind::PartCreated, 3, 9);
        assert!(p.concerns(3) && !p.concerns(4));
        let c = Event::content(EventKind::ContentUpdated, 5);
        assert!(c.concerns(3) && c.concerns(4));
        let json = serde_json::to_value(&p).expect("json");
        assert_eq!(json["type"], "part.created");
        assert_eq!(json["part_id"], 9);
    }

    #[tokio::test]
    async fn subscribers_receive_published_events() {
        let events = Events::new();
        let mut rx = events.subscribe();
        events.publish(Event::content(EventKind::ContentDeleted, 1));
        assert_eq!(
            rx.recv().await.expect("event"),
            Event::content(EventKind::ContentDeleted, 1)
        );
    }
}
