//! [`JobProgress`]: the engine's [`Progress`] for jobs. The build threads only touch atomics
//! (and a mutex at stage changes); a ticker task copies a snapshot to the database a few times
//! a second and reads back cancellation requests. An optional observer (the CLI's progress
//! bar) sees every call too.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use meshwiki_engine::progress::Progress;

use crate::store::jobs::ProgressUpdate;

/// Name of the stage that renders the thumbnail (after the engine's stages).
pub const THUMBNAIL_STAGE: &str = "thumbnail";
/// Name of the stage that generates the demo relief.
pub const GENERATE_STAGE: &str = "generating";
/// Stage of an image repository build (its units are grid points).
pub const LUMIGRAPH_STAGE: &str = "rendering images";

/// Progress of one job: stage, units done and in all, and the cancellation flag.
pub struct JobProgress {
    stage: Mutex<(String, u64)>,
    done: AtomicU64,
    cancel: AtomicBool,
    observer: Option<Box<dyn Progress + Send>>,
}

impl std::fmt::Debug for JobProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JobProgress")
            .field("snapshot", &self.snapshot())
            .field("cancelled", &self.is_cancelled())
            .finish()
    }
}

impl Default for JobProgress {
    fn default() -> Self {
        JobProgress::new(None)
    }
}

impl JobProgress {
    /// New progress, forwarding every call to `observer` too.
    pub fn new(observer: Option<Box<dyn Progress + Send>>) -> JobProgress {
        JobProgress {
            stage: Mutex::new((String::new(), 0)),
            done: AtomicU64::new(0),
            cancel: AtomicBool::new(false),
            observer,
        }
    }

    /// Asks the build to stop.
    pub fn cancel(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }

    /// Whether [`JobProgress::cancel`] was called.
    pub fn is_cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }

    /// The current stage, its units and the estimated percentage of the whole job.
    pub fn snapshot(&self) -> ProgressUpdate {
        let (stage, total) = match self.stage.lock() {
            Ok(g) => g.clone(),
            Err(p) => p.into_inner().clone(),
        };
        let done = self.done.load(Ordering::Relaxed).min(total.max(1));
        let fraction = if total == 0 {
            0.0
        } else {
            done as f64 / total as f64
        };
        ProgressUpdate {
            percent: percent(&stage, fraction),
            stage,
            done: done.min(i64::MAX as u64) as i64,
            total: total.min(i64::MAX as u64) as i64,
        }
    }
}

/// Estimated share (0–100) of the whole job at `fraction` of `stage`: reading the input is
/// about a third of a build, partitioning the leaves another third, the coarser levels (each
/// about half the work of the one before) and writing the rest.
pub fn percent(stage: &str, fraction: f64) -> f64 {
    let f = fraction.clamp(0.0, 1.0);
    let (start, end) = if stage == "import" || stage == GENERATE_STAGE {
        (0.0, 35.0)
    } else if stage == "partitioning" {
        (35.0, 70.0)
    } else if let Some(level) = stage
        .strip_prefix("simplifying level ")
        .and_then(|l| l.trim().parse::<i32>().ok())
    {
        let at = |k: i32| 70.0 + 22.0 * (1.0 - 0.5f64.powi(k.max(0)));
        (at(level - 1), at(level))
    } else if stage == meshwiki_engine::lod::build::ATLAS_STAGE {
        (92.0, 95.0)
    } else if stage == "writing" {
        (95.0, 98.0)
    } else if stage == THUMBNAIL_STAGE {
        (98.0, 100.0)
    } else if stage == LUMIGRAPH_STAGE {
        (0.0, 100.0)
    } else {
        (0.0, 0.0)
    };
    let p = start + (end - start) * f;
    (p * 10.0).round() / 10.0
}

impl Progress for JobProgress {
    fn stage(&self, name: &str, total: u64) {
        match self.stage.lock() {
            Ok(mut g) => *g = (name.to_string(), total),
            Err(p) => *p.into_inner() = (name.to_string(), total),
        }
        self.done.store(0, Ordering::Relaxed);
        if let Some(o) = &self.observer {
            o.stage(name, total);
        }
    }

    fn advance(&self, done: u64) {
        self.done.fetch_add(done, Ordering::Relaxed);
        if let Some(o) = &self.observer {
            o.advance(done);
        }
    }

    fn cancelled(&self) -> bool {
        self.is_cancelled() || self.observer.as_ref().is_some_and(|o| o.cancelled())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percent_is_monotone_over_stages() {
        let stages = [
            "import",
            "partitioning",
            "simplifying level 1",
            "simplifying level 2",
            "simplifying level 3",
            meshwiki_engine::lod::build::ATLAS_STAGE,
            "writing",
            THUMBNAIL_STAGE,
        ];
        let mut last = 0.0;
        for s in stages {
            for f in [0.0, 0.5, 1.0] {
                let p = percent(s, f);
                assert!(p >= last, "{s} {f}: {p} < {last}");
                last = p;
            }
        }
        assert_eq!(percent(THUMBNAIL_STAGE, 1.0), 100.0);
        let p = JobProgress::default();
        p.stage("partitioning", 4);
        p.advance(2);
        let s = p.snapshot();
        assert_eq!((s.done, s.total), (2, 4));
        assert_eq!(s.percent, 52.5);
    }
}
