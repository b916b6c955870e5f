//! Progress reporting and cancellation for long engine work (imports, builds, benchmarks).
//!
//! The engine reports through this trait; the CLI draws a progress bar, background jobs
//! write the figures to the database. Both live outside the engine.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Receives progress of a long operation. Implementations must be cheap and thread-safe:
/// `advance` is called from worker threads in the hot path (batched, not per item).
pub trait Progress: Sync {
    /// A new stage begins; `total` is in the stage's own unit (bytes, triangles, patches).
    fn stage(&self, name: &str, total: u64);
    /// `done` more units of the current stage are finished.
    fn advance(&self, done: u64);
    /// Whether the operation should stop as soon as it safely can.
    fn cancelled(&self) -> bool {
        false
    }
}

/// Progress sink that ignores everything (tests, library use).
pub struct NoProgress;

impl Progress for NoProgress {
    fn stage(&self, _name: &str, _total: u64) {}
    fn advance(&self, _done: u64) {}
}

/// Progress that only counts, with a cancellation flag; handy for tests and simple callers.
#[derive(Default)]
pub struct CountingProgress {
    pub total: AtomicU64,
    pub done: AtomicU64,
    pub cancel: AtomicBool,
}

impl Progress for CountingProgress {
    fn stage(&self, _name: &str, total: u64) {
        self.total.store(total, Ordering::Relaxed);
        self.done.store(0, Ordering::Relaxed);
    }
    fn advance(&self, done: u64) {
        self.done.fetch_add(done, Ordering::Relaxed);
    }
    fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }
}
