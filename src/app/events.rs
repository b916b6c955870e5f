//! The live-update bus: every use case that changes a part, its assigned information or a
//! content publishes an [`Event`] on [`Events`] after its transaction has committed; the web
//! layer streams them to open viewers (`GET /api/v1/models/{id}/events`), the part views
//! (best views, thumbnails) listen for new and changed parts. Events carry only kinds and ids,
//! never data: a viewer fetches what changed through the ordinary API with its own session.

use serde::Serialize;
use tokio::sync::broadcast;
use utoipa::ToSchema;

/// Events buffered per subscriber before it is told to resync.
const CAPACITY: usize = 256;

/// What changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[schema(as = ChangeEventKind)]
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
/// is `change`). Events carry only kinds and ids: a viewer fetches what changed through the
/// ordinary API.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, ToSchema)]
#[schema(as = ChangeEvent)]
pub struct Event {
    /// What changed.
    #[serde(rename = "type")]
    pub kind: EventKind,
    /// Model concerned; `null` for contents, which may be assigned to parts of any model
    /// (content events concern every model).
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

    pub fn concerns(&self, model_id: i64) -> bool {
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
