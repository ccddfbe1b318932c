//! Admission before work: nothing expensive happens inside a request before it is admitted.
//!
//! A submission's up-front check decodes its input (so a corrupt, unsupported or oversize file is
//! a 4xx rather than a failed job). Decoding is where a request's memory goes: a 262 KB deflate
//! GeoTIFF decodes to an 8192² grid, hundreds of MiB. So, in this order:
//! 1. the body streams to the store (multipart input parts as `POST /v1/assets` does), never
//!    held whole;
//! 2. an identical request already queued, running or done is answered from its record;
//! 3. a full queue is answered 429 ([`ensure_queue_room`]) before anything is decoded;
//! 4. the check reserves memory from the process's [`MemoryBudget`] (`memory_budget_bytes`,
//!    shared with the running jobs) before the input's bytes are read from the store
//!    ([`check_memory`]): the input's size plus the most its decode can allocate under the
//!    limits ([`crate::pipeline_set::PipelineSet::decode_cost`]) when that much is free; else,
//!    when at least [`MIN_PARTIAL`] is free, what is free, and the decode runs with the input
//!    limits scaled down to it, so the decoders' header checks (sizes a file declares, checked
//!    before any allocation) admit a small file at once and refuse a large one having allocated
//!    nothing; a large one then waits for its worst case, at most [`CHECK_WAIT`], and is
//!    answered 429 with `Retry-After` otherwise. The decode runs on the blocking pool and the
//!    reservation ends with it;
//! 5. the decoded job's estimated peak memory ([`crate::pipeline_set::Admitted::run_bytes`]) is
//!    recorded on the job, for the worker to reserve before it starts it; a job estimated larger
//!    than the whole budget is refused `413` ([`ensure_fits`]).
//!
//! Concurrent checks and running jobs therefore never hold more than the budget, whatever the
//! clients send. The job's own decode runs later inside the worker pool's bounded concurrency.

use std::time::Duration;

use crate::budget::{MemoryBudget, Reservation};
use crate::error::ApiError;

use super::AppState;

/// How long a check waits for memory before the submission is answered 429: a few worst-case
/// decodes (one to three seconds each at 8192²) may finish in that time, and no client is held
/// longer than that.
pub const CHECK_WAIT: Duration = Duration::from_secs(10);

/// The least free memory a check decodes in with scaled-down limits (rather than waiting for its
/// worst case): below it no input worth the try fits.
pub const MIN_PARTIAL: u64 = 8 << 20;

/// Seconds a client is told to wait (`Retry-After`) when the budget stayed taken.
const RETRY_AFTER_SECS: u64 = 5;

/// Memory for one check: the worst case (`None`: decode with the configured limits) or part of
/// it (`Some(bytes)`: decode with the limits scaled to `bytes`; a `TooLarge` then means "wait
/// for the worst case", [`reserve_worst`]).
pub fn check_memory(
    budget: &MemoryBudget,
    worst: u64,
    input_bytes: u64,
) -> Option<(Reservation, Option<u64>)> {
    if let Some(r) = budget.try_reserve(worst) {
        return Some((r, None));
    }
    let free = budget.free_bytes();
    if free >= input_bytes.saturating_add(MIN_PARTIAL) {
        if let Some(r) = budget.try_reserve(free) {
            let decode = r.bytes().saturating_sub(input_bytes);
            return Some((r, Some(decode)));
        }
    }
    None
}

/// Reserves a check's worst case, waiting at most [`CHECK_WAIT`]; a 429 with `Retry-After`
/// when the budget stayed taken.
pub async fn reserve_worst(budget: &MemoryBudget, worst: u64) -> Result<Reservation, ApiError> {
    budget
        .reserve_within(worst, CHECK_WAIT)
        .await
        .ok_or_else(|| ApiError::Overloaded {
            detail: format!(
                "the server is busy with other inputs and jobs (its memory budget of {} MiB is in \
                 use and checking this input needs {} MiB of it); retry later",
                budget.total_bytes() >> 20,
                worst.min(budget.total_bytes()).div_ceil(1 << 20)
            ),
            retry_after: RETRY_AFTER_SECS,
        })
}

/// 413 when a job's estimated peak memory exceeds the whole budget: no worker of this process
/// could ever start it.
pub fn ensure_fits(budget: &MemoryBudget, run_bytes: u64) -> Result<(), ApiError> {
    if run_bytes > budget.total_bytes() {
        return Err(ApiError::PayloadTooLarge(format!(
            "running this job would take about {} MiB of memory, more than the server's memory \
             budget of {} MiB (memory_budget_bytes); send a smaller input or output size",
            run_bytes.div_ceil(1 << 20),
            budget.total_bytes() >> 20
        )));
    }
    Ok(())
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

    #[test]
    fn a_check_takes_its_worst_case_or_what_is_free_or_nothing() {
        let b = MemoryBudget::new(100 << 20);
        // Free: the worst case, with the configured limits.
        let (r, scaled) = check_memory(&b, 60 << 20, 1 << 20).unwrap();
        assert_eq!((r.bytes(), scaled), (60 << 20, None));
        // 40 MiB free: all of it, limits scaled to what is left after the input's bytes.
        let (r2, scaled) = check_memory(&b, 60 << 20, 1 << 20).unwrap();
        assert_eq!((r2.bytes(), scaled), (40 << 20, Some(39 << 20)));
        drop(r2);
        // Less than MIN_PARTIAL above the input free: nothing now.
        let r3 = b.try_reserve(35 << 20).unwrap();
        assert!(check_memory(&b, 60 << 20, 1 << 20).is_none());
        drop((r, r3));
    }

    #[test]
    fn a_job_larger_than_the_budget_is_413() {
        let b = MemoryBudget::new(100 << 20);
        assert!(ensure_fits(&b, 100 << 20).is_ok());
        let e = ensure_fits(&b, (100 << 20) + 1).unwrap_err();
        assert!(matches!(e, ApiError::PayloadTooLarge(_)), "{e:?}");
    }
}
