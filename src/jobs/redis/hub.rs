//! One pub/sub subscriber per replica: progress snapshots go to local watchers (SSE streams,
//! `Prefer: wait` waiters), cancel requests to jobs running here, new-work notices to the worker
//! slots.
//!
//! Messages published while the subscriber is disconnected are lost (pub/sub has no memory), so
//! watchers are also refreshed from the job records after every reconnect and every
//! [`REFRESH`]; the terminal state is always in the record before it is announced.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::Duration;

use futures_util::StreamExt;
use tokio::sync::{watch, Notify};

use super::{ProgressMsg, RedisJobs};
use crate::jobs::{CancelReason, JobsError, Snapshot};

/// How often watched jobs are re-read from Redis, in case a message was missed.
const REFRESH: Duration = Duration::from_secs(2);

/// Local fan-out state.
#[derive(Default)]
pub(super) struct Hub {
    watchers: Mutex<HashMap<String, watch::Sender<Snapshot>>>,
    /// Woken when a job is queued anywhere (or the subscriber reconnected).
    pub work: Notify,
    /// Whether the subscriber is connected now.
    pub connected: AtomicBool,
}

impl Hub {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, watch::Sender<Snapshot>>> {
        self.watchers
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// A receiver of `id`'s snapshots, starting from its record; `None` if there is no such job.
    pub async fn watch(
        &self,
        jobs: &RedisJobs,
        id: &str,
    ) -> Result<Option<watch::Receiver<Snapshot>>, JobsError> {
        // Register first, then read: a message that arrives in between is older than the read.
        let rx = {
            let mut map = self.lock();
            map.retain(|_, tx| tx.receiver_count() > 0);
            match map.get(id) {
                Some(tx) => tx.subscribe(),
                None => {
                    let (tx, rx) = watch::channel(Snapshot {
                        status: crate::jobs::Status::Queued,
                        progress: 0.0,
                        stage: None,
                    });
                    map.insert(id.to_string(), tx);
                    rx
                }
            }
        };
        match jobs.fetch(id).await? {
            Some(rec) => {
                self.deliver(id, rec.snapshot());
                Ok(Some(rx))
            }
            None => Ok(None),
        }
    }

    /// Updates `id`'s watchers, if any. A terminal snapshot is never replaced by a live one (a
    /// late progress message after the end).
    fn deliver(&self, id: &str, snap: Snapshot) {
        if let Some(tx) = self.lock().get(id) {
            tx.send_if_modified(|cur| {
                if cur.status.is_terminal() || *cur == snap {
                    return false;
                }
                *cur = snap;
                true
            });
        }
    }

    fn watched(&self) -> Vec<String> {
        let mut map = self.lock();
        map.retain(|_, tx| tx.receiver_count() > 0);
        map.iter()
            .filter(|(_, tx)| !tx.borrow().status.is_terminal())
            .map(|(id, _)| id.clone())
            .collect()
    }
}

/// Re-reads every watched, unfinished job.
async fn refresh(jobs: &RedisJobs) {
    let ids = jobs.inner.hub.watched();
    if ids.is_empty() {
        return;
    }
    match jobs.load_many(&ids).await {
        Ok(recs) => {
            for r in recs {
                jobs.inner.hub.deliver(&r.id, r.snapshot());
            }
        }
        Err(e) => tracing::debug!(error = %e, "could not refresh watched jobs"),
    }
}

fn handle(jobs: &RedisJobs, channel: &str, payload: &str) {
    let keys = &jobs.inner.keys;
    if channel == keys.named("progress") {
        match serde_json::from_str::<ProgressMsg>(payload) {
            Ok(m) => jobs.inner.hub.deliver(&m.id, m.snap),
            Err(e) => tracing::warn!(error = %e, "malformed progress message"),
        }
    } else if channel == keys.named("cancel") {
        if let Some(live) = jobs.local().get(payload) {
            live.raise(CancelReason::User);
        }
    } else if channel == keys.named("work") {
        jobs.inner.hub.work.notify_waiters();
    }
}

/// The subscriber loop: connect, subscribe, resynchronise, forward; reconnect with back-off.
pub(super) async fn listen(jobs: RedisJobs) {
    let keys = jobs.inner.keys.clone();
    let channels = [
        keys.named("progress"),
        keys.named("cancel"),
        keys.named("work"),
    ];
    let mut backoff = Duration::from_millis(100);
    loop {
        match jobs.inner.client.get_async_pubsub().await {
            Ok(mut ps) => {
                let mut ok = true;
                for c in &channels {
                    if let Err(e) = ps.subscribe(c).await {
                        tracing::warn!(error = %e, "cannot subscribe to Redis channels");
                        ok = false;
                        break;
                    }
                }
                if ok {
                    if !jobs.inner.hub.connected.swap(true, Ordering::AcqRel) {
                        tracing::info!("subscribed to Redis job events");
                    }
                    backoff = Duration::from_millis(100);
                    // Whatever happened while we were away: a lost group, missed messages.
                    if let Err(e) = jobs.ensure_group().await {
                        tracing::warn!(error = %e, "cannot ensure the consumer group");
                    }
                    refresh(&jobs).await;
                    jobs.inner.hub.work.notify_waiters();
                    let mut stream = ps.into_on_message();
                    let mut tick = tokio::time::interval(REFRESH);
                    loop {
                        tokio::select! {
                            m = stream.next() => match m {
                                Some(msg) => {
                                    let channel = msg.get_channel_name().to_string();
                                    let payload: String = msg.get_payload().unwrap_or_default();
                                    handle(&jobs, &channel, &payload);
                                }
                                None => break,
                            },
                            _ = tick.tick() => refresh(&jobs).await,
                        }
                    }
                }
                tracing::warn!("lost the Redis subscription; reconnecting");
            }
            Err(e) => tracing::debug!(error = %e, "cannot connect the Redis subscriber"),
        }
        jobs.inner.hub.connected.store(false, Ordering::Release);
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(Duration::from_secs(2));
    }
}
