//! A worker slot of the Redis backend: take a dead worker's job (`XAUTOCLAIM`) or a new one
//! (`XREADGROUP`), run it with the shared [`execute`], heartbeat while it runs, forward its
//! progress to pub/sub, and record the end with a compare-and-set.

use std::sync::Arc;
use std::time::Duration;

use chrono::Utc;
use redis::Value;
use tokio_util::sync::CancellationToken;
use tracing::Instrument;

use super::{backend_err, json_err, scripts, ProgressMsg, RedisJobs, GROUP};
use crate::jobs::exec::{execute, poison};
use crate::jobs::{CancelReason, JobBackend, JobRecord, JobsError, Live, Status};

/// How long an idle slot waits before looking again when no new-work notice arrives (covers
/// missed notices and dead workers' jobs, whose lease expiry sends none).
const POLL: Duration = Duration::from_millis(500);

/// A stream entry handed to this worker: (entry id, job id, whether it was taken over).
struct Claim {
    entry: String,
    job: String,
    reclaimed: bool,
}

/// `(entry id, job id)` pairs anywhere in an `XAUTOCLAIM` or `XREADGROUP` reply (entries deleted
/// since they were delivered come back as nil and are skipped).
fn entries(v: &Value, out: &mut Vec<(String, String)>) {
    let Value::Array(items) = v else { return };
    if let [Value::BulkString(id), Value::Array(fields)] = items.as_slice() {
        if let [Value::BulkString(k), Value::BulkString(job)] = fields.as_slice() {
            if k == b"job" {
                out.push((
                    String::from_utf8_lossy(id).into_owned(),
                    String::from_utf8_lossy(job).into_owned(),
                ));
                return;
            }
        }
    }
    for i in items {
        entries(i, out);
    }
}

impl RedisJobs {
    /// The next entry for this replica: a job whose worker stopped heartbeating first, else new
    /// work.
    async fn claim(&self) -> Result<Option<Claim>, redis::RedisError> {
        let queue = self.inner.keys.named("queue");
        let consumer = &self.inner.settings.replica;
        let lease_ms = u64::try_from(self.inner.settings.lease.as_millis()).unwrap_or(u64::MAX);
        let mut con = self.con();
        let reply: Value = redis::cmd("XAUTOCLAIM")
            .arg(&queue)
            .arg(GROUP)
            .arg(consumer)
            .arg(lease_ms)
            .arg("0-0")
            .arg("COUNT")
            .arg(1)
            .query_async(&mut con)
            .await?;
        let mut found = Vec::new();
        if let Value::Array(parts) = &reply {
            if let Some(claimed) = parts.get(1) {
                entries(claimed, &mut found);
            }
        }
        if let Some((entry, job)) = found.pop() {
            return Ok(Some(Claim {
                entry,
                job,
                reclaimed: true,
            }));
        }
        let reply: Value = redis::cmd("XREADGROUP")
            .arg("GROUP")
            .arg(GROUP)
            .arg(consumer)
            .arg("COUNT")
            .arg(1)
            .arg("STREAMS")
            .arg(&queue)
            .arg(">")
            .query_async(&mut con)
            .await?;
        entries(&reply, &mut found);
        Ok(found.pop().map(|(entry, job)| Claim {
            entry,
            job,
            reclaimed: false,
        }))
    }

    /// Acknowledges and deletes an entry whose job needs no run (canceled while queued, finished
    /// by a previous owner, expired).
    async fn drop_entry(&self, entry: &str) -> Result<(), JobsError> {
        let queue = self.inner.keys.named("queue");
        redis::pipe()
            .cmd("XACK")
            .arg(&queue)
            .arg(GROUP)
            .arg(entry)
            .ignore()
            .cmd("XDEL")
            .arg(&queue)
            .arg(entry)
            .ignore()
            .query_async::<()>(&mut self.con())
            .await
            .map_err(backend_err)
    }

    /// Marks the claimed job running under this worker; `None` when it needs no run.
    async fn start_claimed(&self, c: &Claim) -> Result<Option<(String, JobRecord)>, JobsError> {
        for _ in 0..5 {
            let Some((raw, rec)) = self.load_raw(&c.job).await? else {
                self.drop_entry(&c.entry).await?;
                return Ok(None);
            };
            // A running job reaches us only through XAUTOCLAIM: its worker died.
            if !matches!(rec.status, Status::Queued | Status::Running) {
                self.drop_entry(&c.entry).await?;
                return Ok(None);
            }
            if rec.failed_attempts() >= self.inner.cfg.max_attempts {
                let mut dead = rec.clone();
                poison(&mut dead, self.inner.cfg.max_attempts);
                let dead_raw = serde_json::to_string(&dead).map_err(json_err)?;
                let ok: i64 = scripts::POISON
                    .arg(self.inner.keys.prefix())
                    .arg(&c.job)
                    .arg(&raw)
                    .arg(&dead_raw)
                    .arg(&c.entry)
                    .arg(&dead.key)
                    .arg(dead.finished_at.map_or(0, |t| t.timestamp_millis()))
                    .invoke_async(&mut self.con())
                    .await
                    .map_err(backend_err)?;
                if ok != 1 {
                    continue;
                }
                tracing::error!(job = %c.job, attempts = dead.attempts, "job poisoned: no attempt reached an end (panics or a dead worker); moved to the dead-letter list");
                let m = &self.inner.exec.metrics;
                m.jobs_finished
                    .with_label_values(&[dead.pipeline.as_str(), dead.status.as_str()])
                    .inc();
                m.jobs_poisoned
                    .with_label_values(&[dead.pipeline.as_str()])
                    .inc();
                self.inner.hooks.finished(&dead).await;
                self.publish(&dead.id, &dead.snapshot()).await?;
                return Ok(None);
            }
            let mut new = rec.clone();
            new.status = Status::Running;
            new.started_at = Some(Utc::now());
            new.attempts += 1;
            new.progress = 0.0;
            new.stage = None;
            new.worker = Some(self.inner.settings.replica.clone());
            let new_raw = serde_json::to_string(&new).map_err(json_err)?;
            let ok: i64 = scripts::START
                .arg(self.inner.keys.prefix())
                .arg(&c.job)
                .arg(raw)
                .arg(&new_raw)
                .arg(self.owner(&new))
                .invoke_async(&mut self.con())
                .await
                .map_err(backend_err)?;
            if ok == 1 {
                if c.reclaimed {
                    tracing::warn!(job = %c.job, attempt = new.attempts, "took over a job whose worker stopped heartbeating");
                }
                self.inner
                    .exec
                    .metrics
                    .jobs_started
                    .with_label_values(&[if c.reclaimed { "reclaimed" } else { "new" }])
                    .inc();
                return Ok(Some((new_raw, new)));
            }
        }
        Err(JobsError::Backend(
            "the job kept changing while starting it".into(),
        ))
    }

    fn owner(&self, rec: &JobRecord) -> String {
        format!("{}#{}", self.inner.settings.replica, rec.attempts)
    }

    /// Runs a claimed job to its recorded end.
    async fn run_claimed(&self, c: Claim) -> Result<(), JobsError> {
        let Some((raw, rec)) = self.start_claimed(&c).await? else {
            return Ok(());
        };
        let id = rec.id.clone();
        let owner = self.owner(&rec);
        let live = Live::new(rec.snapshot());
        {
            let mut local = self.local();
            local.insert(id.clone(), live.clone());
            self.inner.exec.metrics.jobs_running.set(local.len() as i64);
        }
        self.fetch_and_publish_start(&rec).await;

        let stop = CancellationToken::new();
        let beat = tokio::spawn(heartbeat(
            self.clone(),
            id.clone(),
            owner.clone(),
            c.entry.clone(),
            live.clone(),
            stop.clone(),
        ));
        let fwd = tokio::spawn(forward(
            self.clone(),
            id.clone(),
            live.clone(),
            stop.clone(),
        ));
        let canceled_before: bool = redis::cmd("EXISTS")
            .arg(self.inner.keys.cancel(&id))
            .query_async(&mut self.con())
            .await
            .unwrap_or(false);
        let done = if canceled_before {
            let mut r = rec.clone();
            r.status = Status::Canceled;
            r
        } else {
            execute(&self.inner.exec, rec.clone(), live.clone()).await
        };
        stop.cancel();
        let _ = beat.await;
        let _ = fwd.await;
        let lost = live.reason() == CancelReason::Shutdown && self.accepting();
        let result = if lost {
            tracing::warn!(job = %id, "another replica took this job over; this run's result is dropped");
            Ok(())
        } else {
            self.record_end(&raw, done, &owner, &c.entry).await
        };
        {
            let mut local = self.local();
            local.remove(&id);
            self.inner.exec.metrics.jobs_running.set(local.len() as i64);
        }
        self.inner.idle.notify_waiters();
        result
    }

    /// Announces the start (status `running`, attempt n) to every replica's watchers.
    async fn fetch_and_publish_start(&self, rec: &JobRecord) {
        if let Err(e) = self.publish(&rec.id, &rec.snapshot()).await {
            tracing::debug!(error = %e, "could not announce a job start");
        }
    }

    /// Stores the run's result: terminal (then hooks, then the announcement) or back to the queue
    /// after a shutdown interrupted it or its attempt failed (a panic).
    async fn record_end(
        &self,
        raw: &str,
        mut done: JobRecord,
        owner: &str,
        entry: &str,
    ) -> Result<(), JobsError> {
        let p = self.inner.keys.prefix();
        if done.status == Status::Queued {
            let new_raw = serde_json::to_string(&done).map_err(json_err)?;
            let _: i64 = scripts::REQUEUE
                .arg(p)
                .arg(&done.id)
                .arg(raw)
                .arg(new_raw)
                .arg(owner)
                .arg(entry)
                .invoke_async(&mut self.con())
                .await
                .map_err(backend_err)?;
            return Ok(());
        }
        done.finished_at = Some(Utc::now());
        if done.status == Status::Succeeded {
            done.progress = 1.0;
        }
        let new_raw = serde_json::to_string(&done).map_err(json_err)?;
        let ok: i64 = scripts::FINISH
            .arg(p)
            .arg(&done.id)
            .arg(raw)
            .arg(new_raw)
            .arg(owner)
            .arg(entry)
            .arg(done.status.as_str())
            .arg(&done.key)
            .arg(done.finished_at.map_or(0, |t| t.timestamp_millis()))
            .invoke_async(&mut self.con())
            .await
            .map_err(backend_err)?;
        if ok != 1 {
            tracing::warn!(job = %done.id, "the job changed hands while it ran; this run's result is dropped");
            return Ok(());
        }
        self.inner
            .exec
            .metrics
            .jobs_finished
            .with_label_values(&[done.pipeline.as_str(), done.status.as_str()])
            .inc();
        // Hooks run before waiters wake, so a client woken by the job's end sees what the hook
        // built from it (a cloud scene's new version).
        self.inner.hooks.finished(&done).await;
        self.publish(&done.id, &done.snapshot()).await
    }
}

/// Keeps the job's entry ours while it runs; learns of cancel requests and of losing the job.
async fn heartbeat(
    jobs: RedisJobs,
    id: String,
    owner: String,
    entry: String,
    live: Arc<Live>,
    stop: CancellationToken,
) {
    let every = jobs.inner.settings.lease / 3;
    loop {
        tokio::select! {
            () = stop.cancelled() => return,
            () = tokio::time::sleep(every) => {}
        }
        let r: Result<i64, _> = scripts::HEARTBEAT
            .arg(jobs.inner.keys.prefix())
            .arg(&id)
            .arg(&owner)
            .arg(&entry)
            .arg(&jobs.inner.settings.replica)
            .invoke_async(&mut jobs.con())
            .await;
        match r {
            Ok(1) => live.raise(CancelReason::User),
            Ok(-1) => {
                // Another replica owns the job now (we were silent past the lease): stop.
                live.raise(CancelReason::Shutdown);
                return;
            }
            Ok(_) => {}
            Err(e) => tracing::warn!(job = %id, error = %e, "heartbeat failed"),
        }
    }
}

/// Forwards the run's progress snapshots to Redis (the stored snapshot and pub/sub).
async fn forward(jobs: RedisJobs, id: String, live: Arc<Live>, stop: CancellationToken) {
    let mut rx = live.tx.subscribe();
    loop {
        tokio::select! {
            () = stop.cancelled() => return,
            r = rx.changed() => if r.is_err() { return; },
        }
        let snap = rx.borrow_and_update().clone();
        let msg = match serde_json::to_string(&ProgressMsg {
            id: id.clone(),
            snap: snap.clone(),
        }) {
            Ok(m) => m,
            Err(_) => continue,
        };
        let snap_json = serde_json::to_string(&snap).unwrap_or_default();
        let r: Result<(), _> = redis::pipe()
            .cmd("SET")
            .arg(jobs.inner.keys.snap(&id))
            .arg(snap_json)
            .arg("EX")
            .arg(86_400)
            .ignore()
            .cmd("PUBLISH")
            .arg(jobs.inner.keys.named("progress"))
            .arg(msg)
            .ignore()
            .query_async(&mut jobs.con())
            .await;
        if let Err(e) = r {
            tracing::debug!(job = %id, error = %e, "could not forward progress");
        }
    }
}

/// One worker slot: runs jobs until the backend stops accepting work.
pub(super) async fn slot(jobs: RedisJobs, index: usize) {
    let mut failing = false;
    loop {
        if !jobs.accepting() {
            return;
        }
        let notified = jobs.inner.hub.work.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        match jobs.claim().await {
            Ok(Some(c)) => {
                failing = false;
                let span = tracing::info_span!("job", job = %c.job, slot = index);
                let id = c.job.clone();
                if let Err(e) = jobs.run_claimed(c).instrument(span).await {
                    tracing::error!(job = %id, error = %e, "could not run a job; it stays in the queue");
                    tokio::time::sleep(Duration::from_secs(1)).await;
                }
            }
            Ok(None) => {
                failing = false;
                tokio::select! {
                    () = &mut notified => {}
                    () = tokio::time::sleep(POLL) => {}
                }
            }
            Err(e) => {
                if e.code() == Some("NOGROUP") {
                    // Redis lost its data (restarted without persistence): recreate the group.
                    let _ = jobs.ensure_group().await;
                } else if !failing {
                    tracing::warn!(error = %e, "cannot read the Redis queue; retrying");
                    failing = true;
                }
                tokio::time::sleep(Duration::from_millis(500)).await;
            }
        }
    }
}
