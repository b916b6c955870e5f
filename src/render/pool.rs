//! The bounded render pool: at most `workers` renders run at once, at most `queue` more wait,
//! and the renders in flight hold at most `memory` bytes together (each asks for its estimate,
//! [`meshwiki_engine::render::Outputs::frame_bytes`] plus its response, before it starts).
//!
//! Requests from HTTP handlers are *foreground*: beyond `workers + queue` admitted requests, or
//! after waiting `wait` for a worker, they are refused with [`PoolError::Busy`] (503 with
//! `Retry-After`). Background work (thumbnails, best views) waits as long as it takes without
//! taking a queue place, but shares the workers and the memory budget.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// Granularity of the memory budget (semaphore permits are KiB).
const UNIT: u64 = 1024;

/// Why work was not admitted.
#[derive(Debug, Clone, thiserror::Error)]
pub enum PoolError {
    /// The queue is full or the wait timed out; retry after about this many seconds.
    #[error(
        "the render queue is full ({busy} renders running or waiting); retry in {retry_after} s"
    )]
    Busy {
        /// Admitted requests at the time.
        busy: usize,
        /// Suggested delay in seconds.
        retry_after: u64,
    },
    /// The work alone needs more memory than the whole budget.
    #[error(
        "this render needs about {need_mb} MiB, more than the render memory budget of \
         {budget_mb} MiB: ask for a smaller image"
    )]
    TooLarge {
        /// Estimate, in MiB.
        need_mb: u64,
        /// Budget, in MiB.
        budget_mb: u64,
    },
}

/// Admission state shared by every render of the process.
#[derive(Debug)]
pub struct Pool {
    workers: usize,
    capacity: usize,
    run: Arc<Semaphore>,
    memory: Arc<Semaphore>,
    memory_units: u64,
    admitted: Arc<AtomicUsize>,
    wait: Duration,
    /// Moving average of a render's duration, in milliseconds.
    average_ms: AtomicU64,
}

/// Held while a render runs (or holds its response): releases its worker, memory and queue
/// place on drop.
#[derive(Debug)]
pub struct Ticket {
    _run: Option<OwnedSemaphorePermit>,
    memory: Option<OwnedSemaphorePermit>,
    _slot: Option<Slot>,
}

impl Ticket {
    /// Releases the worker (and queue place) but keeps the memory, e.g. while a response body
    /// is being sent.
    pub fn into_memory(self) -> MemoryHold {
        MemoryHold {
            _memory: self.memory,
        }
    }
}

/// Memory still held by a finished render (its response).
#[derive(Debug)]
pub struct MemoryHold {
    _memory: Option<OwnedSemaphorePermit>,
}

#[derive(Debug)]
struct Slot(Arc<AtomicUsize>);

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

impl Pool {
    /// A pool of `workers` (at least 1) with `queue` waiting places and a memory budget.
    pub fn new(workers: usize, queue: usize, memory_bytes: u64, wait: Duration) -> Pool {
        let workers = workers.clamp(1, 256);
        let memory_units = (memory_bytes / UNIT).clamp(1, Semaphore::MAX_PERMITS as u64 / 2);
        Pool {
            workers,
            capacity: workers + queue.min(100_000),
            run: Arc::new(Semaphore::new(workers)),
            memory: Arc::new(Semaphore::new(memory_units as usize)),
            memory_units,
            admitted: Arc::new(AtomicUsize::new(0)),
            wait,
            average_ms: AtomicU64::new(500),
        }
    }

    /// The memory budget in bytes.
    pub fn memory_budget(&self) -> u64 {
        self.memory_units * UNIT
    }

    /// Foreground requests admitted now (running or waiting).
    pub fn admitted(&self) -> usize {
        self.admitted.load(Ordering::Acquire)
    }

    /// Records how long a render took (for `Retry-After`).
    pub fn record(&self, took: Duration) {
        let ms = took.as_millis().min(600_000) as u64;
        let old = self.average_ms.load(Ordering::Relaxed);
        self.average_ms
            .store((old * 7 + ms).div_ceil(8), Ordering::Relaxed);
    }

    fn retry_after(&self, busy: usize) -> u64 {
        let ms = self.average_ms.load(Ordering::Relaxed).max(1);
        (busy as u64 * ms / self.workers as u64 / 1000).clamp(1, 60)
    }

    fn units(&self, bytes: u64) -> Result<u32, PoolError> {
        let units = bytes.div_ceil(UNIT).max(1);
        if units > self.memory_units {
            return Err(PoolError::TooLarge {
                need_mb: bytes.div_ceil(1 << 20),
                budget_mb: self.memory_budget() >> 20,
            });
        }
        Ok(units as u32)
    }

    /// Admits a foreground request that will hold `bytes`: refuses at once when the queue is
    /// full, else waits (at most the pool's wait) for the memory and a worker.
    pub async fn admit(&self, bytes: u64) -> Result<Ticket, PoolError> {
        let units = self.units(bytes)?;
        let mut n = self.admitted.load(Ordering::Acquire);
        loop {
            if n >= self.capacity {
                return Err(PoolError::Busy {
                    busy: n,
                    retry_after: self.retry_after(n),
                });
            }
            match self
                .admitted
                .compare_exchange_weak(n, n + 1, Ordering::AcqRel, Ordering::Acquire)
            {
                Ok(_) => break,
                Err(now) => n = now,
            }
        }
        let slot = Slot(self.admitted.clone());
        let started = Instant::now();
        let acquired = tokio::time::timeout(self.wait, self.acquire(units)).await;
        match acquired {
            Ok(Some((memory, run))) => Ok(Ticket {
                _run: Some(run),
                memory: Some(memory),
                _slot: Some(slot),
            }),
            _ => {
                let busy = self.admitted();
                tracing::warn!(
                    waited_ms = started.elapsed().as_millis() as u64,
                    busy,
                    "render request timed out in the queue"
                );
                Err(PoolError::Busy {
                    busy,
                    retry_after: self.retry_after(busy),
                })
            }
        }
    }

    /// Admits background work holding `bytes`: waits for the memory and a worker, without a
    /// queue place or time limit.
    pub async fn admit_background(&self, bytes: u64) -> Result<Ticket, PoolError> {
        let units = self.units(bytes)?;
        let (memory, run) = self.acquire(units).await.ok_or(PoolError::Busy {
            busy: 0,
            retry_after: 1,
        })?;
        Ok(Ticket {
            _run: Some(run),
            memory: Some(memory),
            _slot: None,
        })
    }

    async fn acquire(&self, units: u32) -> Option<(OwnedSemaphorePermit, OwnedSemaphorePermit)> {
        let memory = self.memory.clone().acquire_many_owned(units).await.ok()?;
        let run = self.run.clone().acquire_owned().await.ok()?;
        Some((memory, run))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn queue_and_memory_bounds() {
        let pool = Pool::new(1, 1, 10 * UNIT, Duration::from_millis(50));
        assert!(matches!(
            pool.admit(11 * UNIT).await,
            Err(PoolError::TooLarge { .. })
        ));
        let a = pool.admit(UNIT).await.expect("first runs");
        assert_eq!(pool.admitted(), 1);
        // The second waits for the worker and times out; the third finds the queue full.
        let b = pool.admit(UNIT);
        let c = async {
            tokio::time::sleep(Duration::from_millis(10)).await;
            pool.admit(UNIT).await
        };
        let (b, c) = tokio::join!(b, c);
        assert!(matches!(b, Err(PoolError::Busy { .. })));
        assert!(matches!(c, Err(PoolError::Busy { busy: 2, .. })));
        drop(a);
        assert_eq!(pool.admitted(), 0);
        // Memory: a ticket turned into a memory hold keeps its bytes but frees the worker.
        let big = pool.admit(8 * UNIT).await.expect("fits");
        let hold = big.into_memory();
        assert!(matches!(
            pool.admit(4 * UNIT).await,
            Err(PoolError::Busy { .. })
        ));
        let small = pool.admit(2 * UNIT).await.expect("fits beside the hold");
        drop((hold, small));
        let bg = pool.admit_background(10 * UNIT).await.expect("background");
        drop(bg);
    }
}
