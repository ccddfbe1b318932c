//! The embedded job system: a bounded in-process queue, a fixed number of workers that run
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

pub mod record;
mod worker;

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use chrono::Utc;
use tokio::sync::{watch, Notify};

use crate::metrics::Metrics;
use crate::pipelines::PipelineSet;
use crate::store::{Store, StoreError};
pub use record::{
    AuxInput, InputRef, JobError, JobRecord, OutputRecord, Snapshot, StageTiming, Status,
};

/// What other parts of the service need to know about jobs: resources built from job outputs
/// (cloud scene versions) learn when a job finishes and keep their blobs from the sweeper.
pub trait JobHooks: Send + Sync + 'static {
    /// Called after a job reached a terminal status and was persisted (on a worker task; keep it
    /// short and non-blocking apart from small file writes).
    fn finished(&self, _rec: &JobRecord) {}
    /// Blobs that must survive retention although no live job or asset references them.
    fn pinned_blobs(&self) -> HashSet<String> {
        HashSet::new()
    }
}

/// No hooks.
pub struct NoHooks;
impl JobHooks for NoHooks {}

/// Job-system settings (from [`crate::config::Config`]).
#[derive(Debug, Clone)]
pub struct JobsConfig {
    /// Jobs running at once. Default 1: each job already uses every core through rayon.
    pub concurrency: usize,
    /// Jobs allowed to wait. Default 64.
    pub queue_capacity: usize,
    /// Wall-clock limit of one run.
    pub job_timeout: Duration,
    /// Finished jobs, their outputs and unused assets are deleted this long after they finish.
    pub retention: Duration,
    /// How often the retention sweeper runs.
    pub sweep_interval: Duration,
    /// Threads of the pipeline rayon pool (0 = one per core).
    pub threads: usize,
}

/// Submission failures the API maps to status codes.
#[derive(Debug, thiserror::Error)]
pub enum SubmitError {
    #[error("the queue is full ({capacity} jobs waiting)")]
    QueueFull { capacity: usize },
    #[error("the service is shutting down")]
    ShuttingDown,
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// Cancellation failures.
#[derive(Debug, thiserror::Error)]
pub enum CancelError {
    #[error("no job {0}")]
    NotFound(String),
    #[error("job {id} already {status}")]
    Finished { id: String, status: &'static str },
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// Why a running job's cancel flag was raised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub(crate) enum CancelReason {
    None = 0,
    User = 1,
    Timeout = 2,
    Shutdown = 3,
}

/// The live, shared part of a job: its progress channel and cancel flag.
pub(crate) struct Live {
    pub tx: watch::Sender<Snapshot>,
    pub cancel: AtomicU8,
}

impl Live {
    pub fn reason(&self) -> CancelReason {
        match self.cancel.load(Ordering::Acquire) {
            1 => CancelReason::User,
            2 => CancelReason::Timeout,
            3 => CancelReason::Shutdown,
            _ => CancelReason::None,
        }
    }
    pub fn raise(&self, r: CancelReason) {
        // The first reason wins: a user cancel is not turned into a timeout.
        let _ = self
            .cancel
            .compare_exchange(0, r as u8, Ordering::AcqRel, Ordering::Acquire);
    }
}

struct Entry {
    record: JobRecord,
    live: Arc<Live>,
}

#[derive(Default)]
pub(crate) struct State {
    jobs: HashMap<String, Entry>,
    queue: VecDeque<String>,
    /// Request key → the newest job with that key that has not failed or been canceled.
    by_key: HashMap<String, String>,
    running: usize,
}

pub(crate) struct Inner {
    pub store: Store,
    pub pipelines: Arc<dyn PipelineSet>,
    pub hooks: Arc<dyn JobHooks>,
    pub cfg: JobsConfig,
    pub metrics: Metrics,
    pub pool: rayon::ThreadPool,
    state: Mutex<State>,
    pub work: Notify,
    pub accepting: AtomicBool,
    pub idle: Notify,
}

/// A handle to the job system; cheap to clone.
#[derive(Clone)]
pub struct Jobs {
    pub(crate) inner: Arc<Inner>,
}

/// What a submission turned into.
#[derive(Debug, Clone)]
pub enum Submitted {
    /// A new job was queued.
    Queued(JobRecord),
    /// An identical request is queued, running or finished: its job is returned.
    Reused(JobRecord),
}

/// Builds the pipeline thread pool.
fn build_pool(threads: usize) -> Result<rayon::ThreadPool, rayon::ThreadPoolBuildError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("pipeline-{i}"))
        .build()
}

/// Errors starting the job system.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("cannot build the pipeline thread pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
}

impl Jobs {
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
            let (tx, _) = watch::channel(rec.snapshot());
            let live = Arc::new(Live {
                tx,
                cancel: AtomicU8::new(0),
            });
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
        let inner = Arc::new(Inner {
            store,
            pipelines,
            hooks,
            cfg,
            metrics,
            pool,
            state: Mutex::new(state),
            work: Notify::new(),
            accepting: AtomicBool::new(true),
            idle: Notify::new(),
        });
        let jobs = Jobs { inner };
        for i in 0..jobs.inner.cfg.concurrency.max(1) {
            tokio::spawn(worker::run(jobs.clone(), i));
        }
        tokio::spawn(worker::sweeper(jobs.clone()));
        Ok(jobs)
    }

    pub fn store(&self) -> &Store {
        &self.inner.store
    }

    pub fn pipelines(&self) -> &Arc<dyn PipelineSet> {
        &self.inner.pipelines
    }

    pub(crate) fn state(&self) -> MutexGuard<'_, State> {
        // A panic while holding this lock would be a bug in this module (no pipeline code runs
        // under it); recover the data rather than poisoning every later request.
        self.inner
            .state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    pub(crate) fn job_path(&self, id: &str) -> std::path::PathBuf {
        self.inner
            .store
            .root()
            .join("jobs")
            .join(format!("{id}.json"))
    }

    /// Whether new work is being accepted (false during shutdown).
    pub fn accepting(&self) -> bool {
        self.inner.accepting.load(Ordering::Acquire)
    }

    /// The running job with this request key, or a finished successful one, if any.
    pub fn find_by_key(&self, key: &str) -> Option<JobRecord> {
        let st = self.state();
        let id = st.by_key.get(key)?;
        st.jobs.get(id).map(view)
    }

    /// Queues a job unless an identical request (same `key`) is queued, running or succeeded.
    pub fn submit(
        &self,
        pipeline: &str,
        input: InputRef,
        params: serde_json::Value,
        key: String,
    ) -> Result<Submitted, SubmitError> {
        if !self.accepting() {
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
        };
        // Persist before acknowledging: an accepted job survives a crash right after the 202.
        self.inner.store.put_json(&self.job_path(&rec.id), &rec)?;
        let (tx, _) = watch::channel(rec.snapshot());
        let live = Arc::new(Live {
            tx,
            cancel: AtomicU8::new(0),
        });
        st.by_key.insert(key, rec.id.clone());
        st.queue.push_back(rec.id.clone());
        st.jobs.insert(
            rec.id.clone(),
            Entry {
                record: rec.clone(),
                live,
            },
        );
        self.inner.metrics.queue_depth.set(st.queue.len() as i64);
        drop(st);
        self.inner.work.notify_one();
        Ok(Submitted::Queued(rec))
    }

    /// The job with this id, with live progress.
    pub fn get(&self, id: &str) -> Option<JobRecord> {
        let st = self.state();
        st.jobs.get(id).map(view)
    }

    /// A receiver of the job's progress snapshots.
    pub fn subscribe(&self, id: &str) -> Option<watch::Receiver<Snapshot>> {
        self.state().jobs.get(id).map(|e| e.live.tx.subscribe())
    }

    /// Waits until the job is finished or `timeout` passes; returns the job as it is then.
    pub async fn wait(&self, id: &str, timeout: Duration) -> Option<JobRecord> {
        let mut rx = self.subscribe(id)?;
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            if rx.borrow_and_update().status.is_terminal() {
                break;
            }
            match tokio::time::timeout_at(deadline, rx.changed()).await {
                Ok(Ok(())) => continue,
                _ => break,
            }
        }
        self.get(id)
    }

    /// Jobs newest first, `limit` per page, starting after the job `after` (a cursor).
    pub fn list(&self, limit: usize, after: Option<&str>) -> (Vec<JobRecord>, Option<String>) {
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

    /// Cancels a job: a queued job is canceled at once, a running one at its next checkpoint.
    pub fn cancel(&self, id: &str) -> Result<JobRecord, CancelError> {
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
                self.inner.store.put_json(&self.job_path(id), &rec)?;
                st.queue.retain(|q| q != id);
                if st.by_key.get(&rec.key).is_some_and(|j| j == id) {
                    st.by_key.remove(&rec.key);
                }
                self.inner.metrics.queue_depth.set(st.queue.len() as i64);
                self.inner
                    .metrics
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

    /// Number of queued and running jobs.
    pub fn load(&self) -> (usize, usize) {
        let st = self.state();
        (st.queue.len(), st.running)
    }

    /// Stops taking new work, lets running jobs finish within `grace`, then cancels the rest; jobs
    /// interrupted this way stay queued on disk for the next start.
    pub async fn shutdown(&self, grace: Duration) {
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

    /// Every blob still referenced by a job or a live asset.
    pub(crate) fn referenced_blobs(&self, assets: &HashSet<String>) -> HashSet<String> {
        let st = self.state();
        let mut keep: HashSet<String> = assets.clone();
        for e in st.jobs.values() {
            keep.insert(e.record.input.asset.clone());
            keep.extend(e.record.input.aux.iter().map(|a| a.blob.clone()));
            keep.extend(e.record.outputs.iter().map(|o| o.sha256.clone()));
        }
        drop(st);
        keep.extend(self.inner.hooks.pinned_blobs());
        keep
    }

    // ---- used by the workers ----

    /// Takes the next queued job and marks it running (persisted).
    pub(crate) fn take_next(&self) -> Result<Option<(JobRecord, Arc<Live>)>, StoreError> {
        let mut st = self.state();
        while let Some(id) = st.queue.pop_front() {
            let Some(entry) = st.jobs.get_mut(&id) else {
                continue;
            };
            if entry.record.status != Status::Queued {
                continue;
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
            self.inner.metrics.queue_depth.set(st.queue.len() as i64);
            self.inner.metrics.jobs_running.set(st.running as i64);
            drop(st);
            self.inner.store.put_json(&self.job_path(&rec.id), &rec)?;
            return Ok(Some((rec, live)));
        }
        Ok(None)
    }

    /// Records the end of a run: `rec` carries the final status, outputs, timings or error.
    /// A job interrupted by shutdown is stored as queued again.
    pub(crate) fn finish(&self, mut rec: JobRecord) -> Result<(), StoreError> {
        if rec.status.is_terminal() {
            rec.finished_at = Some(Utc::now());
        }
        if rec.status == Status::Succeeded {
            rec.progress = 1.0;
        }
        let persisted = self.inner.store.put_json(&self.job_path(&rec.id), &rec);
        let mut st = self.state();
        st.running = st.running.saturating_sub(1);
        self.inner.metrics.jobs_running.set(st.running as i64);
        if matches!(rec.status, Status::Failed | Status::Canceled)
            && st.by_key.get(&rec.key).is_some_and(|j| *j == rec.id)
        {
            st.by_key.remove(&rec.key);
        }
        if rec.status.is_terminal() {
            self.inner
                .metrics
                .jobs_finished
                .with_label_values(&[rec.pipeline.as_str(), rec.status.as_str()])
                .inc();
        }
        let id = rec.id.clone();
        let terminal = rec.status.is_terminal().then(|| rec.clone());
        if let Some(entry) = st.jobs.get_mut(&id) {
            entry.record = rec;
        }
        drop(st);
        // Hooks run before waiters wake, so a client woken by the job's end sees what the hook
        // built from it (a cloud scene's new version).
        if let Some(rec) = &terminal {
            self.inner.hooks.finished(rec);
        }
        if let Some(entry) = self.state().jobs.get(&id) {
            entry.live.tx.send_replace(entry.record.snapshot());
        }
        self.inner.idle.notify_waiters();
        persisted
    }

    /// Removes finished jobs older than the retention period; returns the removed count.
    pub(crate) fn expire(&self, older_than: chrono::DateTime<Utc>) -> usize {
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
                if let Err(err) = self.inner.store.remove(&self.job_path(id)) {
                    tracing::warn!(error = %err, job = %id, "could not delete an expired job record");
                }
            }
        }
        old.len()
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
