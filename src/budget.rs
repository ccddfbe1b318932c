//! One memory budget per process (issue 20): the bytes that the up-front input checks of
//! submissions and the running jobs may hold at once. `--memory-budget-bytes` (env
//! `PHENOMENA_MEMORY_BUDGET_BYTES`), default 768 MiB.
//!
//! A `tokio::sync::Semaphore` counting KiB: a fair queue, so a large reservation is not starved
//! by small ones. Checks reserve what their decode may allocate (`api::admission`) and give up
//! after a bounded wait (429 with `Retry-After`); a worker reserves its job's estimated peak
//! ([`phenomena_engine::registry::run_cost`], recorded on the job at submission) before it
//! starts the job and waits for it as long as it takes (the job stays queued-in-hand, its
//! cancellation still honoured). A job estimated larger than the whole budget is refused at
//! submission (413), so every reservation can be met.
//!
//! Rejected: tower's `ConcurrencyLimitLayer` / `LoadShedLayer` on the routes, which count
//! requests, not bytes, and would also hold back cached submits and uploads that decode nothing.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{OwnedSemaphorePermit, Semaphore};

const KIB: u64 = 1024;

/// The memory budget of one process; cheap to clone (shared).
#[derive(Debug, Clone)]
pub struct MemoryBudget {
    permits: Arc<Semaphore>,
    /// The budget in KiB (the semaphore's permits).
    total_kib: u32,
}

/// A reservation of budget; returned when dropped.
#[derive(Debug)]
pub struct Reservation {
    permit: OwnedSemaphorePermit,
}

impl Reservation {
    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        u64::try_from(self.permit.num_permits()).unwrap_or(u64::MAX) * KIB
    }
}

impl MemoryBudget {
    /// A budget of `bytes` (rounded down to KiB, at least 1 KiB, at most 4 TiB).
    pub fn new(bytes: u64) -> Self {
        let total_kib = u32::try_from(bytes / KIB).unwrap_or(u32::MAX).max(1);
        Self {
            permits: Arc::new(Semaphore::new(total_kib as usize)),
            total_kib,
        }
    }

    /// The budget in bytes.
    pub fn total_bytes(&self) -> u64 {
        u64::from(self.total_kib) * KIB
    }

    /// Bytes free now.
    pub fn free_bytes(&self) -> u64 {
        u64::try_from(self.permits.available_permits()).unwrap_or(u64::MAX) * KIB
    }

    /// Bytes reserved now.
    pub fn in_use_bytes(&self) -> u64 {
        self.total_bytes().saturating_sub(self.free_bytes())
    }

    /// Permits for `bytes`: rounded up to KiB, at least 1, at most the whole budget.
    fn kib(&self, bytes: u64) -> u32 {
        u32::try_from(bytes.div_ceil(KIB))
            .unwrap_or(u32::MAX)
            .clamp(1, self.total_kib)
    }

    /// `bytes` (all of the budget when it is larger) if they are free now.
    pub fn try_reserve(&self, bytes: u64) -> Option<Reservation> {
        self.permits
            .clone()
            .try_acquire_many_owned(self.kib(bytes))
            .ok()
            .map(|permit| Reservation { permit })
    }

    /// Reserves `bytes` (all of the budget when it is larger), waiting at most `wait`; `None`
    /// when the budget stayed taken.
    pub async fn reserve_within(&self, bytes: u64, wait: Duration) -> Option<Reservation> {
        let want = self.kib(bytes);
        match tokio::time::timeout(wait, self.permits.clone().acquire_many_owned(want)).await {
            Ok(Ok(permit)) => Some(Reservation { permit }),
            // Timed out, or the semaphore closed (it never is).
            _ => None,
        }
    }

    /// Reserves `bytes` (all of the budget when it is larger), waiting as long as it takes
    /// (`None` only if the semaphore were closed; it never is).
    pub async fn reserve(&self, bytes: u64) -> Option<Reservation> {
        let want = self.kib(bytes);
        let permit = self.permits.clone().acquire_many_owned(want).await.ok()?;
        Some(Reservation { permit })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn reservations_add_up_to_the_budget_and_larger_ones_take_all_of_it() {
        let b = MemoryBudget::new(10 << 20);
        let wait = Duration::from_millis(50);
        let r1 = b.reserve_within(6 << 20, wait).await.unwrap();
        assert_eq!(b.in_use_bytes(), 6 << 20);
        assert_eq!(r1.bytes(), 6 << 20);
        // 6 + 6 > 10: waits, then gives up.
        assert!(b.reserve_within(6 << 20, wait).await.is_none());
        assert!(b.try_reserve(6 << 20).is_none());
        let r2 = b.try_reserve(4 << 20).unwrap();
        assert_eq!(b.in_use_bytes(), 10 << 20);
        assert_eq!(b.free_bytes(), 0);
        drop((r1, r2));
        assert_eq!(b.in_use_bytes(), 0);
        // Larger than the budget: all of it.
        let all = b.reserve(1 << 40).await.unwrap();
        assert_eq!(b.in_use_bytes(), b.total_bytes());
        assert!(b.reserve_within(1, wait).await.is_none());
        drop(all);
        assert!(b.reserve_within(1, wait).await.is_some());
    }

    #[tokio::test]
    async fn a_waiting_reservation_gets_the_budget_when_it_is_returned() {
        let b = MemoryBudget::new(8 << 20);
        let held = b.reserve(8 << 20).await.unwrap();
        let b2 = b.clone();
        let waiter = tokio::spawn(async move { b2.reserve(5 << 20).await.unwrap().bytes() });
        tokio::task::yield_now().await;
        assert!(!waiter.is_finished());
        drop(held);
        assert_eq!(waiter.await.unwrap(), 5 << 20);
    }
}
