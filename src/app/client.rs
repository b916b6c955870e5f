//! The limits and settings a client needs, in one place: the model page embeds them for the
//! viewer and `GET /api/v1/config` serves them, so no client learns a limit from an error
//! message or keeps its own copy of a server default.

use serde::Serialize;
use utoipa::ToSchema;

use super::App;
use super::selections::{DRAFT_TTL, MAX_MASK_BYTES};
use crate::store::parts::MAX_COMMENT_CHARS;

/// Limits and settings of this server that clients size their requests to.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ClientConfig {
    /// The largest view the server renders; selection masks and render requests must fit it.
    pub view_limits: ViewLimits,
    /// Largest model upload (`POST /api/v1/models/upload`), in bytes.
    pub model_upload_bytes: u64,
    /// Largest attachment upload, in bytes.
    pub attachment_bytes: u64,
    /// Largest selection mask PNG, in bytes.
    pub mask_bytes: u64,
    /// Longest title, in characters.
    pub title_chars: u64,
    /// Longest content body, in bytes.
    pub body_bytes: u64,
    /// Largest number of vertex ids in a region part.
    pub part_vertices: u64,
    /// Longest revision comment, in characters.
    pub comment_chars: u64,
    /// How long a draft selection is kept, in seconds.
    pub draft_ttl_secs: u64,
}

/// The largest view the server renders (`--render-max-side`, `--render-max-pixels`).
#[derive(Debug, Clone, Copy, Serialize, ToSchema)]
pub struct ViewLimits {
    /// Longest side, in pixels.
    pub max_side: u32,
    /// Most pixels (width × height).
    pub max_pixels: u64,
}

impl App {
    /// This server's [`ClientConfig`].
    pub fn client_config(&self) -> ClientConfig {
        let s = &self.settings;
        ClientConfig {
            view_limits: ViewLimits {
                max_side: s.render.max_side,
                max_pixels: s.render.max_pixels,
            },
            model_upload_bytes: s.build.upload_bytes,
            attachment_bytes: s.limits.upload_bytes,
            mask_bytes: MAX_MASK_BYTES as u64,
            title_chars: s.limits.title_chars as u64,
            body_bytes: s.limits.body_bytes as u64,
            part_vertices: s.limits.part_vertices as u64,
            comment_chars: MAX_COMMENT_CHARS as u64,
            draft_ttl_secs: DRAFT_TTL.as_secs(),
        }
    }
}
