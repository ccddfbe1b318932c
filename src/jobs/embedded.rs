//! The embedded job backend: a bounded in-process queue, a fixed number of workers that run
//! pipelines on a dedicated rayon pool, progress and cancellation, per-job time limits, result reuse,
//! persistence under the data directory, crash recovery and retention.
//!
//! Every status change is written to `jobs/<id>.json` (atomically) before it is announced, so a
//! `kill -9` at any point loses nothing that was accepted: at start-up, jobs found `queued` or
//! `running` go back on the queue in creation order, and finished jobs are served from disk.
//!
//! Bounds: `queue_capacity` queued jobs (beyond it submissions get 429 with `Retry-After`),
//! `concurrency` jobs running at once (each uses the whole rayon pool, so more than the core count
//! only adds memory), `job_timeout` per job.

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use async_trait::async_trait;
use chrono::Utc;
use tokio::sync::{watch, Notify};
use tracing::Instrument;

use super::exec::{execute, poison, Executor};
use super::record;
use super::{
    build_pool, CancelError, CancelReason, InputRef, JobBackend, JobHooks, JobRecord, JobsConfig,
    JobsError, Live, Load, Snapshot, StartError, Status, SubmitError, Submitted,
};
use crate::metrics::Metrics;
use crate::pipeline_set::PipelineSet;
use crate::store::{Store, StoreError};

struct Entry {
    record: JobRecord,
    live: Arc<Live>,
}

#[derive(Default)]
struct State {
    jobs: HashMap<String, Entry>,
    queue: VecDeque<String>,
    /// Request key → the newest job with that key that has not failed or been canceled.
    by_key: HashMap<String, String>,
    running: usize,
}

struct Inner {
    exec: Executor,
    hooks: Arc<dyn JobHooks>,
    cfg: JobsConfig,
    state: Mutex<State>,
    work: Notify,
    accepting: AtomicBool,
    idle: Notify,
}

/// What a worker takes from the queue.
enum Next {
    /// A job to run, marked running.
    Run(JobRecord, Arc<Live>),
    /// A job failed as poisoned instead of starting again (already persisted and announced).
    Poisoned(JobRecord),
}

/// The embedded backend; cheap to clone.
#[derive(Clone)]
pub struct Embedded {
    inner: Arc<Inner>,
}

impl Embedded {
    /// Loads persisted jobs (re-queueing unfinished ones) and starts the workers and the sweeper on
    /// the current tokio runtime.
    pub fn start(
        store: Store,
        pipelines: Arc<dyn PipelineSet>,
        hooks: Arc<dyn JobHooks>,
        cfg: JobsConfig,
        metrics: Metrics,
    ) -> Result<Self, StartError> {
        let pool = build_pool(cfg.threads)?;
        let mut state = State::default();
        let mut records: Vec<JobRecord> = store.list_json("jobs")?;
        records.sort_by(|a, b| a.created_at.cmp(&b.created_at).then(a.id.cmp(&b.id)));
        let mut requeued = 0;
        for mut rec in records {
            if !record::is_job_id(&rec.id) {
                continue;
            }
            if !rec.status.is_terminal() {
                if rec.status == Status::Running {
                    rec.status = Status::Queued;
                    rec.progress = 0.0;
                    rec.stage = None;
                    store.put_json(
                        &store.root().join("jobs").join(format!("{}.json", rec.id)),
                        &rec,
                    )?;
                }
                state.queue.push_back(rec.id.clone());
                requeued += 1;
            }
            if matches!(
                rec.status,
                Status::Queued | Status::Running | Status::Succeeded
            ) {
                state.by_key.insert(rec.key.clone(), rec.id.clone());
            }
            let live = Live::new(rec.snapshot());
            state
                .jobs
                .insert(rec.id.clone(), Entry { record: rec, live });
        }
        if requeued > 0 {
            tracing::info!(
                requeued,
                "re-queued unfinished jobs from the data directory"
            );
        }
        metrics.queue_depth.set(state.queue.len() as i64);
        metrics
            .workers
            .set(i64::try_from(cfg.concurrency).unwrap_or(0));
        let inner = Arc::new(Inner {
            exec: Executor {
                store,
                pipelines,
                pool,
                timeout: cfg.job_timeout,
                metrics,
                memory: cfg.memory.clone(),
            },
            hooks,
            cfg,
            state: Mutex::new(state),
            work: Notify::new(),
            accepting: AtomicBool::new(true),
            idle: Notify::new(),
        });
        let jobs = Embedded { inner };
        for i in 0..jobs.inner.cfg.concurrency {
            tokio::spawn(jobs.clone().worker(i));
        }
        Ok(jobs)
    }

    fn store(&self) -> &Store {
        &self.inner.exec.store
    }

    fn metrics(&self) -> &Metrics {
        &self.inner.exec.metrics
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // A panic while holding this lock would be a bug in this module (no pipeline code runs
        // under it); recover the data rather than poisoning every later request.
        self.inner
            .state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn job_path(&self, id: &str) -> std::path::PathBuf {
        self.store().root().join("jobs").join(format!("{id}.json"))
    }

    fn lookup_key(&self, key: &str) -> Option<JobRecord> {
        let st = self.state();
        let id = st.by_key.get(key)?;
        st.jobs.get(id).map(view)
    }

    fn submit_now(
        &self,
        pipeline: &str,
        input: InputRef,
        params: serde_json::Value,
        key: String,
    ) -> Result<Submitted, SubmitError> {
        if !self.inner.accepting.load(Ordering::Acquire) {
            return Err(SubmitError::ShuttingDown);
        }
        let mut st = self.state();
        if let Some(e) = st.by_key.get(&key).and_then(|id| st.jobs.get(id)) {
            return Ok(Submitted::Reused(view(e)));
        }
        if st.queue.len() >= self.inner.cfg.queue_capacity {
            return Err(SubmitError::QueueFull {
                capacity: self.inner.cfg.queue_capacity,
            });
        }
        let rec = JobRecord {
            id: record::new_job_id(),
            pipeline: pipeline.to_string(),
            status: Status::Queued,
            progress: 0.0,
            stage: None,
            created_at: Utc::now(),
            started_at: None,
            finished_at: None,
            input,
            params,
            key: key.clone(),
            timings: Vec::new(),
            outputs: Vec::new(),
            error: None,
            attempts: 0,
            interrupted: 0,
            worker: None,
        };
        // Persist before acknowledging: an accepted job survives a crash right after the 202.
        self.store().put_json(&self.job_path(&rec.id), &rec)?;
        let live = Live::new(rec.snapshot());
        st.by_key.insert(key, rec.id.clone());
        st.queue.push_back(rec.id.clone());
        st.jobs.insert(
            rec.id.clone(),
            Entry {
                record: rec.clone(),
                live,
            },
        );
        self.metrics().queue_depth.set(st.queue.len() as i64);
        drop(st);
        self.inner.work.notify_one();
        Ok(Submitted::Queued(rec))
    }

    fn list_now(&self, limit: usize, after: Option<&str>) -> (Vec<JobRecord>, Option<String>) {
        let st = self.state();
        let mut all: Vec<&Entry> = st.jobs.values().collect();
        all.sort_by(|a, b| {
            b.record
                .created_at
                .cmp(&a.record.created_at)
                .then(b.record.id.cmp(&a.record.id))
        });
        let start = match after {
            Some(c) => all
                .iter()
                .position(|e| e.record.id == c)
                .map_or(all.len(), |p| p + 1),
            None => 0,
        };
        let page: Vec<JobRecord> = all
            .iter()
            .skip(start)
            .take(limit)
            .map(|e| view(e))
            .collect();
        let next = (start + page.len() < all.len())
            .then(|| page.last().map(|r| r.id.clone()))
            .flatten();
        (page, next)
    }

    fn cancel_now(&self, id: &str) -> Result<JobRecord, CancelError> {
        let mut st = self.state();
        let Some(entry) = st.jobs.get_mut(id) else {
            return Err(CancelError::NotFound(id.to_string()));
        };
        match entry.record.status {
            Status::Queued => {
                entry.record.status = Status::Canceled;
                entry.record.finished_at = Some(Utc::now());
                let rec = entry.record.clone();
                entry.live.tx.send_replace(rec.snapshot());
                self.store().put_json(&self.job_path(id), &rec)?;
                st.queue.retain(|q| q != id);
                if st.by_key.get(&rec.key).is_some_and(|j| j == id) {
                    st.by_key.remove(&rec.key);
                }
                self.metrics().queue_depth.set(st.queue.len() as i64);
                self.metrics()
                    .jobs_finished
                    .with_label_values(&[rec.pipeline.as_str(), "canceled"])
                    .inc();
                Ok(rec)
            }
            Status::Running => {
                entry.live.raise(CancelReason::User);
                Ok(view(entry))
            }
            s => Err(CancelError::Finished {
                id: id.to_string(),
                status: s.as_str(),
            }),
        }
    }

    /// Stops taking new work, lets running jobs finish within `grace`, then cancels the rest; jobs
    /// interrupted this way stay queued on disk for the next start.
    async fn drain(&self, grace: Duration) {
        self.inner.accepting.store(false, Ordering::Release);
        self.inner.work.notify_waiters();
        let deadline = Instant::now() + grace;
        loop {
            let notified = self.inner.idle.notified();
            if self.state().running == 0 {
                return;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() || tokio::time::timeout(left, notified).await.is_err() {
                break;
            }
        }
        let lives: Vec<Arc<Live>> = self
            .state()
            .jobs
            .values()
            .filter(|e| e.record.status == Status::Running)
            .map(|e| e.live.clone())
            .collect();
        tracing::warn!(
            jobs = lives.len(),
            "grace period over: interrupting running jobs"
        );
        for l in &lives {
            l.raise(CancelReason::Shutdown);
        }
        // Give the workers a moment to persist the interrupted jobs as queued.
        let _ = tokio::time::timeout(Duration::from_secs(5), async {
            while self.state().running > 0 {
                self.inner.idle.notified().await;
            }
        })
        .await;
    }

    /// Every blob still referenced by a job.
    fn blobs_in_use(&self) -> HashSet<String> {
        let st = self.state();
        let mut keep = HashSet::new();
        for e in st.jobs.values() {
            keep.insert(e.record.input.asset.clone());
            keep.extend(e.record.input.aux.iter().map(|a| a.blob.clone()));
            keep.extend(e.record.outputs.iter().map(|o| o.sha256.clone()));
        }
        keep
    }

    /// One worker: runs jobs until the system stops accepting work.
    async fn worker(self, index: usize) {
        loop {
            if !self.inner.accepting.load(Ordering::Acquire) {
                return;
            }
            let notified = self.inner.work.notified();
            match self.take_next() {
                Ok(Some(Next::Poisoned(rec))) => {
                    // Hooks run before waiters wake, as for a job that ends in a run.
                    self.inner.hooks.finished(&rec).await;
                    self.inner.idle.notify_waiters();
                }
                Ok(Some(Next::Run(rec, live))) => {
                    let span = tracing::info_span!("job", job = %rec.id, pipeline = %rec.pipeline, worker = index);
                    let id = rec.id.clone();
                    let done = execute(&self.inner.exec, rec, live).instrument(span).await;
                    if let Err(e) = self.finish(done).await {
                        tracing::error!(job = %id, error = %e, "could not persist a finished job");
                    }
                }
                Ok(None) => notified.await,
                Err(e) => {
                    tracing::error!(error = %e, "could not start a job; retrying in 1 s");
                    tokio::time::sleep(Duration::from_secs(1)).await;
                }
            }
        }
    }

    /// Takes the next queued job and marks it running (persisted). A job already started
    /// `max_attempts` times (it panicked or its worker died each time) is failed as poisoned
    /// instead.
    fn take_next(&self) -> Result<Option<Next>, StoreError> {
        let mut st = self.state();
        while let Some(id) = st.queue.pop_front() {
            let Some(entry) = st.jobs.get_mut(&id) else {
                continue;
            };
            if entry.record.status != Status::Queued {
                continue;
            }
            if entry.record.failed_attempts() >= self.inner.cfg.max_attempts {
                poison(&mut entry.record, self.inner.cfg.max_attempts);
                let rec = entry.record.clone();
                entry.live.tx.send_replace(rec.snapshot());
                if st.by_key.get(&rec.key).is_some_and(|j| *j == rec.id) {
                    st.by_key.remove(&rec.key);
                }
                self.metrics().queue_depth.set(st.queue.len() as i64);
                self.metrics()
                    .jobs_finished
                    .with_label_values(&[rec.pipeline.as_str(), rec.status.as_str()])
                    .inc();
                self.metrics()
                    .jobs_poisoned
                    .with_label_values(&[rec.pipeline.as_str()])
                    .inc();
                tracing::error!(job = %rec.id, attempts = rec.attempts, "job poisoned: no attempt reached an end (panics or a dead worker); not retried");
                drop(st);
                if let Err(e) = self.store().put_json(&self.job_path(&rec.id), &rec) {
                    tracing::warn!(job = %rec.id, error = %e, "could not record the poisoned job");
                }
                return Ok(Some(Next::Poisoned(rec)));
            }
            entry.record.status = Status::Running;
            entry.record.started_at = Some(Utc::now());
            entry.record.attempts += 1;
            entry.record.progress = 0.0;
            entry.record.stage = None;
            entry
                .live
                .cancel
                .store(CancelReason::None as u8, Ordering::Release);
            let rec = entry.record.clone();
            let live = entry.live.clone();
            live.tx.send_replace(rec.snapshot());
            st.running += 1;
            self.metrics().queue_depth.set(st.queue.len() as i64);
            self.metrics().jobs_running.set(st.running as i64);
            drop(st);
            self.metrics()
                .jobs_started
                .with_label_values(&[if rec.attempts > 1 { "reclaimed" } else { "new" }])
                .inc();
            // A full or read-only data directory must not strand the job as "running" in memory:
            // it runs anyway (its outputs then fail to store and it ends `failed`, or it
            // succeeds), and its record on disk stays `queued`, so a crash re-runs it.
            if let Err(e) = self.store().put_json(&self.job_path(&rec.id), &rec) {
                tracing::warn!(job = %rec.id, error = %e, "could not record the job as running; running it anyway");
            }
            return Ok(Some(Next::Run(rec, live)));
        }
        Ok(None)
    }

    /// Records the end of a run: `rec` carries the final status, outputs, timings or error.
    /// A job interrupted by shutdown is stored as queued again; one whose attempt failed (a
    /// panic) is also queued again, at the back of the queue.
    async fn finish(&self, mut rec: JobRecord) -> Result<(), StoreError> {
        if rec.status.is_terminal() {
            rec.finished_at = Some(Utc::now());
        }
        if rec.status == Status::Succeeded {
            rec.progress = 1.0;
        }
        let persisted = self.store().put_json(&self.job_path(&rec.id), &rec);
        let (id, terminal) = {
            let mut st = self.state();
            st.running = st.running.saturating_sub(1);
            self.metrics().jobs_running.set(st.running as i64);
            if matches!(rec.status, Status::Failed | Status::Canceled)
                && st.by_key.get(&rec.key).is_some_and(|j| *j == rec.id)
            {
                st.by_key.remove(&rec.key);
            }
            if rec.status.is_terminal() {
                self.metrics()
                    .jobs_finished
                    .with_label_values(&[rec.pipeline.as_str(), rec.status.as_str()])
                    .inc();
            }
            let id = rec.id.clone();
            let terminal = rec.status.is_terminal().then(|| rec.clone());
            if let Some(entry) = st.jobs.get_mut(&id) {
                entry.record = rec;
            }
            (id, terminal)
        };
        // Hooks run before waiters wake, so a client woken by the job's end sees what the hook
        // built from it (a cloud scene's new version).
        if let Some(rec) = &terminal {
            self.inner.hooks.finished(rec).await;
        }
        let retry = {
            let mut st = self.state();
            let retry = st.jobs.get(&id).is_some_and(|entry| {
                entry.live.tx.send_replace(entry.record.snapshot());
                entry.record.status == Status::Queued
            }) && self.inner.accepting.load(Ordering::Acquire);
            // A failed attempt (a panic) goes to the back of the queue; a run a shutdown cut
            // short stays queued on disk for the next start.
            if retry {
                st.queue.push_back(id.clone());
                self.metrics().queue_depth.set(st.queue.len() as i64);
            }
            retry
        };
        if retry {
            self.inner.work.notify_one();
        }
        self.inner.idle.notify_waiters();
        persisted
    }

    /// Removes finished jobs older than the retention period; returns the removed count.
    fn expire_now(&self, older_than: chrono::DateTime<Utc>) -> usize {
        let mut st = self.state();
        let old: Vec<String> = st
            .jobs
            .values()
            .filter(|e| e.record.status.is_terminal())
            .filter(|e| e.record.finished_at.is_some_and(|t| t < older_than))
            .map(|e| e.record.id.clone())
            .collect();
        for id in &old {
            if let Some(e) = st.jobs.remove(id) {
                if st.by_key.get(&e.record.key).is_some_and(|j| j == id) {
                    st.by_key.remove(&e.record.key);
                }
                if let Err(err) = self.store().remove(&self.job_path(id)) {
                    tracing::warn!(error = %err, job = %id, "could not delete an expired job record");
                }
            }
        }
        old.len()
    }
}

#[async_trait]
impl JobBackend for Embedded {
    fn kind(&self) -> &'static str {
        "embedded"
    }

    fn accepting(&self) -> bool {
        self.inner.accepting.load(Ordering::Acquire)
    }

    async fn find_by_key(&self, key: &str) -> Result<Option<JobRecord>, JobsError> {
        Ok(self.lookup_key(key))
    }

    async fn submit(
        &self,
        pipeline: &str,
        input: InputRef,
        params: serde_json::Value,
        key: String,
    ) -> Result<Submitted, SubmitError> {
        self.submit_now(pipeline, input, params, key)
    }

    async fn get(&self, id: &str) -> Result<Option<JobRecord>, JobsError> {
        Ok(self.state().jobs.get(id).map(view))
    }

    async fn subscribe(&self, id: &str) -> Result<Option<watch::Receiver<Snapshot>>, JobsError> {
        Ok(self.state().jobs.get(id).map(|e| e.live.tx.subscribe()))
    }

    async fn list(
        &self,
        limit: usize,
        after: Option<&str>,
    ) -> Result<(Vec<JobRecord>, Option<String>), JobsError> {
        Ok(self.list_now(limit, after))
    }

    async fn cancel(&self, id: &str) -> Result<JobRecord, CancelError> {
        self.cancel_now(id)
    }

    async fn load(&self) -> Result<Load, JobsError> {
        let st = self.state();
        Ok(Load {
            queued: st.queue.len(),
            running: st.running,
            running_here: st.running,
            workers: self.inner.cfg.concurrency,
        })
    }

    async fn check(&self) -> Result<(), JobsError> {
        Ok(())
    }

    async fn shutdown(&self, grace: Duration) {
        self.drain(grace).await;
    }

    async fn expire(&self, older_than: chrono::DateTime<Utc>) -> Result<usize, JobsError> {
        Ok(self.expire_now(older_than))
    }

    async fn referenced_blobs(&self) -> Result<HashSet<String>, JobsError> {
        Ok(self.blobs_in_use())
    }
}

/// The record with live progress merged in.
fn view(e: &Entry) -> JobRecord {
    let mut r = e.record.clone();
    if r.status == Status::Running {
        let s = e.live.tx.borrow();
        r.progress = s.progress;
        r.stage = s.stage.clone();
    }
    r
}
