//! The error of a use case: what went wrong, in terms a caller (an HTTP handler, the CLI, a
//! test) can map to its own answer (a status code, an exit code), without knowing which
//! service failed.

use crate::render::RenderServiceError;
use crate::store::StoreError;

/// Why a use case failed.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// No such thing.
    #[error("{0}")]
    NotFound(String),
    /// The input is not valid.
    #[error("{0}")]
    Invalid(String),
    /// The caller may not do or read this (a role short of it, geometry kept on the server).
    #[error("{0}")]
    Forbidden(String),
    /// The input conflicts with the current state (a model not ready, a part changed since).
    #[error("{0}")]
    Conflict(String),
    /// The input is of a type not understood (a mask that is not a PNG).
    #[error("{0}")]
    UnsupportedMedia(String),
    /// The input is larger than allowed.
    #[error("{0}")]
    TooLarge(String),
    /// A content edit based on a stale revision that did not merge cleanly (or was not to be
    /// saved merged): the three versions and the merge.
    #[error("edit conflict: your edit is based on revision {} but the current revision is {}", .0.base_number, .0.theirs.number)]
    EditConflict(Box<super::contents::EditConflict>),
    /// The store refused or failed (keeps its stale-revision details).
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The render service refused or failed (busy, no adapter, bad options).
    #[error(transparent)]
    Render(#[from] RenderServiceError),
    /// The server will not do this now (a storage cap reached); retrying later does not help
    /// until an admin acts.
    #[error("{0}")]
    Unavailable(String),
    /// A server fault (logged where it happens).
    #[error("{0}")]
    Internal(String),
}

impl From<crate::jobs::JobError> for AppError {
    fn from(e: crate::jobs::JobError) -> AppError {
        match e {
            crate::jobs::JobError::Store(s) => AppError::Store(s),
            crate::jobs::JobError::Invalid(m) => AppError::Invalid(m),
            crate::jobs::JobError::TooLarge(m) => AppError::TooLarge(m),
            crate::jobs::JobError::Io(e) => AppError::internal(e),
        }
    }
}

impl AppError {
    /// Invalid input, with a message.
    pub fn invalid(msg: impl Into<String>) -> AppError {
        AppError::Invalid(msg.into())
    }

    /// A server fault, logged.
    pub fn internal(err: impl std::fmt::Display) -> AppError {
        tracing::error!(error = %err, "internal error");
        AppError::Internal(err.to_string())
    }
}
