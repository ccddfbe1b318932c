//! Admission before work: nothing expensive happens inside a request before it is admitted.
//!
//! A submission's up-front check decodes its input (so a corrupt, unsupported or oversize file is
//! a 4xx rather than a failed job). Decoding is where a request's memory goes: a 262 KB deflate
//! GeoTIFF decodes to an 8192² grid, hundreds of MiB. So, in this order:
//! 1. the body streams to the store (multipart input parts as `POST /v1/assets` does), never
//!    held whole;
//! 2. an identical request already queued, running or done is answered from its record;
//! 3. a full queue is answered 429 ([`ensure_queue_room`]) before anything is decoded;
//! 4. the check reserves its input's size plus the most its decode can allocate
//!    ([`crate::pipeline_set::PipelineSet::decode_cost`]) from the process's decode budget
//!    ([`DecodeBudget`], `decode_budget_bytes`), waiting at most [`DECODE_WAIT`] and answering
//!    429 with `Retry-After` otherwise; only then are the input's bytes read from the store and
//!    decoded, on the blocking pool, and the reservation ends with the check.
//!
//! Concurrent checks therefore never hold more than the budget, whatever the clients send. The
//! job's own decode runs later inside the worker pool's bounded concurrency.
//!
//! The budget is a `tokio::sync::Semaphore` counting KiB (a fair queue: a large reservation is
//! not starved by small ones). Rejected: tower's `ConcurrencyLimitLayer` / `LoadShedLayer` on the
//! routes, which count requests, not bytes, and would also hold back cached submits and uploads
//! that decode nothing.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{OwnedSemaphorePermit, Semaphore};

use super::AppState;
use crate::error::ApiError;

/// How long a check waits for decode budget before the submission is answered 429: a few
/// worst-case decodes (one to three seconds each at 8192²) may finish in that time, and no client
/// is held longer than that.
pub const DECODE_WAIT: Duration = Duration::from_secs(10);

/// Seconds a client is told to wait (`Retry-After`) when the budget stayed taken.
const RETRY_AFTER_SECS: u64 = 5;

const KIB: u64 = 1024;

/// The decode budget of one process.
#[derive(Debug, Clone)]
pub struct DecodeBudget {
    permits: Arc<Semaphore>,
    /// The budget in KiB (the semaphore's permits).
    total_kib: u32,
    wait: Duration,
}

/// A reservation of decode budget; returned when dropped.
#[derive(Debug)]
pub struct Reservation {
    _permit: OwnedSemaphorePermit,
}

impl DecodeBudget {
    /// A budget of `bytes` (rounded down to KiB, at least 1 KiB, at most 4 TiB); reservations
    /// wait at most `wait`.
    pub fn new(bytes: u64, wait: Duration) -> Self {
        let total_kib = u32::try_from(bytes / KIB).unwrap_or(u32::MAX).max(1);
        Self {
            permits: Arc::new(Semaphore::new(total_kib as usize)),
            total_kib,
            wait,
        }
    }

    /// The budget in bytes.
    pub fn total_bytes(&self) -> u64 {
        u64::from(self.total_kib) * KIB
    }

    /// Bytes reserved now.
    pub fn in_use_bytes(&self) -> u64 {
        let free = u64::try_from(self.permits.available_permits()).unwrap_or(u64::MAX);
        u64::from(self.total_kib).saturating_sub(free) * KIB
    }

    /// Reserves `bytes` (all of the budget when it is larger), waiting at most the budget's
    /// wait; a 429 with `Retry-After` when the budget stayed taken.
    pub async fn reserve(&self, bytes: u64) -> Result<Reservation, ApiError> {
        let want = u32::try_from(bytes.div_ceil(KIB))
            .unwrap_or(u32::MAX)
            .clamp(1, self.total_kib);
        match tokio::time::timeout(self.wait, self.permits.clone().acquire_many_owned(want)).await {
            Ok(Ok(permit)) => Ok(Reservation { _permit: permit }),
            // Timed out, or the semaphore closed (it never is).
            _ => Err(ApiError::Overloaded {
                detail: format!(
                    "the server is checking other inputs (its decode budget of {} MiB is in use \
                     and this input needs {} MiB of it); retry later",
                    self.total_bytes() >> 20,
                    (u64::from(want) * KIB) >> 20
                ),
                retry_after: RETRY_AFTER_SECS,
            }),
        }
    }
}

/// 429 when the queue is full, so that a submission that would be refused anyway is refused
/// before its input is decoded. (The queue is checked again, atomically, when the job is queued.)
pub async fn ensure_queue_room(st: &AppState) -> Result<(), ApiError> {
    let load = st.jobs.load().await?;
    if load.queued >= st.cfg.queue_capacity {
        return Err(ApiError::QueueFull {
            detail: format!(
                "the queue is full ({} jobs waiting); retry later",
                st.cfg.queue_capacity
            ),
            retry_after: 5,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn reservations_add_up_to_the_budget_and_larger_ones_take_all_of_it() {
        let b = DecodeBudget::new(10 << 20, Duration::from_millis(50));
        let r1 = b.reserve(6 << 20).await.unwrap();
        assert_eq!(b.in_use_bytes(), 6 << 20);
        // 6 + 6 > 10: waits, then 429.
        let e = b.reserve(6 << 20).await.unwrap_err();
        assert!(matches!(e, ApiError::Overloaded { .. }), "{e:?}");
        let r2 = b.reserve(4 << 20).await.unwrap();
        assert_eq!(b.in_use_bytes(), 10 << 20);
        drop((r1, r2));
        assert_eq!(b.in_use_bytes(), 0);
        // Larger than the budget: all of it.
        let all = b.reserve(1 << 40).await.unwrap();
        assert_eq!(b.in_use_bytes(), b.total_bytes());
        assert!(b.reserve(1).await.is_err());
        drop(all);
        assert!(b.reserve(1).await.is_ok());
    }
}
