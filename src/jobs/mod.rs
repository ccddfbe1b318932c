//! The job system behind one trait, [`JobBackend`], so the API never knows which engine runs it:
//!
//! - [`embedded`]: one process — a bounded in-memory queue, records persisted under the data
//!   directory, crash recovery at start-up (the default);
//! - `redis`: many replicas sharing one Redis (queue on a stream with a consumer group, job state,
//!   progress over pub/sub), switched on by `--redis-url`.
//!
//! Both run jobs with the same [`exec::Executor`] (pipelines on a dedicated rayon pool, progress,
//! cancellation, time limit, content-addressed outputs) and share one retention sweep
//! ([`sweep`]). The integration tests run the same job suite against both.

pub mod embedded;
pub(crate) mod exec;
pub mod record;
pub mod redis;
pub(crate) mod sweep;

use std::collections::HashSet;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;
use std::time::Duration;

use async_trait::async_trait;
use tokio::sync::watch;

use crate::pipeline_set::PipelineSet;
use crate::store::{Store, StoreError};
pub use record::{
    AuxInput, InputRef, JobError, JobRecord, OutputRecord, Snapshot, StageTiming, Status,
};

/// What other parts of the service need to know about jobs: resources built from job outputs
/// (cloud scene versions) learn when a job finishes and keep their blobs from the sweeper.
#[async_trait]
pub trait JobHooks: Send + Sync + 'static {
    /// Called after a job reached a terminal status and was recorded, before waiters wake (on a
    /// worker task; keep it short).
    async fn finished(&self, _rec: &JobRecord) {}
    /// Blobs that must survive retention although no live job or asset references them.
    async fn pinned_blobs(&self) -> Result<HashSet<String>, JobsError> {
        Ok(HashSet::new())
    }
}

/// No hooks.
pub struct NoHooks;
impl JobHooks for NoHooks {}

/// Job-system settings (from [`crate::config::Config`]).
#[derive(Debug, Clone)]
pub struct JobsConfig {
    /// Jobs running at once in this process. Default 1: each job already uses every core through
    /// rayon. 0 runs no jobs here (the `api` role of a scaled deployment).
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
    /// Starts after which a job that never finished is failed as poisoned. Default 3.
    pub max_attempts: u32,
    /// The process's memory budget, shared with the API's input checks: a worker reserves a
    /// job's estimated peak memory ([`InputRef::memory`]) before it starts it.
    pub memory: crate::budget::MemoryBudget,
}

/// A backend that cannot answer (Redis unreachable, the data directory unwritable). The API maps
/// it to 503.
#[derive(Debug, thiserror::Error)]
pub enum JobsError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("job backend unavailable: {0}")]
    Backend(String),
}

/// Submission failures the API maps to status codes.
#[derive(Debug, thiserror::Error)]
pub enum SubmitError {
    #[error("the queue is full ({capacity} jobs waiting)")]
    QueueFull { capacity: usize },
    #[error("the service is shutting down")]
    ShuttingDown,
    #[error(transparent)]
    Backend(#[from] JobsError),
}

impl From<StoreError> for SubmitError {
    fn from(e: StoreError) -> Self {
        SubmitError::Backend(e.into())
    }
}

/// Cancellation failures.
#[derive(Debug, thiserror::Error)]
pub enum CancelError {
    #[error("no job {0}")]
    NotFound(String),
    #[error("job {id} already {status}")]
    Finished { id: String, status: &'static str },
    #[error(transparent)]
    Backend(#[from] JobsError),
}

impl From<StoreError> for CancelError {
    fn from(e: StoreError) -> Self {
        CancelError::Backend(e.into())
    }
}

/// What a submission turned into.
#[derive(Debug, Clone)]
pub enum Submitted {
    /// A new job was queued.
    Queued(JobRecord),
    /// An identical request is queued, running or finished: its job is returned.
    Reused(JobRecord),
}

/// Queue and worker figures: the shared queue, and what this process runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Load {
    /// Jobs waiting (in the whole deployment).
    pub queued: usize,
    /// Jobs running (in the whole deployment).
    pub running: usize,
    /// Jobs running in this process.
    pub running_here: usize,
    /// Worker slots of this process (0 for an API-only replica).
    pub workers: usize,
}

/// A job engine: queue, state, progress, cancellation, retention. Implemented by the embedded
/// backend and the Redis backend; identical requests, limits and statuses behave the same in both.
#[async_trait]
pub trait JobBackend: Send + Sync + 'static {
    /// `embedded` or `redis` (shown by `/readyz`).
    fn kind(&self) -> &'static str;
    /// Whether new work is being accepted (false during shutdown).
    fn accepting(&self) -> bool;
    /// The queued or running job with this request key, or a finished successful one.
    async fn find_by_key(&self, key: &str) -> Result<Option<JobRecord>, JobsError>;
    /// Queues a job unless an identical request (same `key`) is queued, running or succeeded;
    /// the job is recorded before this returns, so an acknowledged job survives a crash.
    async fn submit(
        &self,
        pipeline: &str,
        input: InputRef,
        params: serde_json::Value,
        key: String,
    ) -> Result<Submitted, SubmitError>;
    /// The job with this id, with live progress.
    async fn get(&self, id: &str) -> Result<Option<JobRecord>, JobsError>;
    /// A receiver of the job's progress snapshots (for SSE and waiters), starting at its current
    /// state; it sees the terminal snapshot after the job's record holds the final state.
    async fn subscribe(&self, id: &str) -> Result<Option<watch::Receiver<Snapshot>>, JobsError>;
    /// Jobs newest first, `limit` per page, starting after the job `after` (a cursor).
    async fn list(
        &self,
        limit: usize,
        after: Option<&str>,
    ) -> Result<(Vec<JobRecord>, Option<String>), JobsError>;
    /// Cancels a job: a queued job is canceled at once, a running one at its next checkpoint.
    async fn cancel(&self, id: &str) -> Result<JobRecord, CancelError>;
    /// Queue and worker figures.
    async fn load(&self) -> Result<Load, JobsError>;
    /// Readiness of the backend itself (Redis reachable); `Ok` for the embedded one.
    async fn check(&self) -> Result<(), JobsError>;
    /// Stops taking new work, lets running jobs finish within `grace`, then interrupts the rest,
    /// which go back to the queue.
    async fn shutdown(&self, grace: Duration);
    /// Removes finished jobs that ended before `older_than`; returns how many (retention).
    async fn expire(&self, older_than: chrono::DateTime<chrono::Utc>) -> Result<usize, JobsError>;
    /// Every blob an existing job reads or produced (retention keeps them).
    async fn referenced_blobs(&self) -> Result<HashSet<String>, JobsError>;
    /// Whether this process should run the retention sweep now (one replica at a time).
    async fn sweep_turn(&self, _interval: Duration) -> bool {
        true
    }
}

/// A handle to the job system; cheap to clone. Derefs to the backend.
#[derive(Clone)]
pub struct Jobs {
    backend: Arc<dyn JobBackend>,
    store: Store,
    pipelines: Arc<dyn PipelineSet>,
    hooks: Arc<dyn JobHooks>,
}

impl std::ops::Deref for Jobs {
    type Target = dyn JobBackend;
    fn deref(&self) -> &Self::Target {
        self.backend.as_ref()
    }
}

impl Jobs {
    /// Wraps a started backend and starts the retention sweeper on the current runtime.
    pub fn new(
        backend: Arc<dyn JobBackend>,
        store: Store,
        pipelines: Arc<dyn PipelineSet>,
        hooks: Arc<dyn JobHooks>,
        cfg: &JobsConfig,
        metrics: crate::metrics::Metrics,
    ) -> Self {
        let jobs = Jobs {
            backend,
            store,
            pipelines,
            hooks,
        };
        tokio::spawn(sweep::sweeper(
            jobs.clone(),
            cfg.retention,
            cfg.sweep_interval,
            metrics,
        ));
        jobs
    }

    pub fn store(&self) -> &Store {
        &self.store
    }

    pub fn pipelines(&self) -> &Arc<dyn PipelineSet> {
        &self.pipelines
    }

    pub(crate) fn hooks(&self) -> &Arc<dyn JobHooks> {
        &self.hooks
    }

    /// Waits until the job is finished or `timeout` passes; returns the job as it is then
    /// (`None` if there is no such job or the backend cannot answer).
    pub async fn wait(&self, id: &str, timeout: Duration) -> Option<JobRecord> {
        let mut rx = self.subscribe(id).await.ok()??;
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
        self.get(id).await.ok().flatten()
    }
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

/// The live, shared part of a running job: its progress channel and cancel flag.
pub(crate) struct Live {
    pub tx: watch::Sender<Snapshot>,
    pub cancel: AtomicU8,
}

impl Live {
    pub fn new(snapshot: Snapshot) -> Arc<Self> {
        let (tx, _) = watch::channel(snapshot);
        Arc::new(Live {
            tx,
            cancel: AtomicU8::new(0),
        })
    }
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

/// Errors starting the job system.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("cannot build the pipeline thread pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
    #[error("{0}")]
    Backend(String),
}

/// Builds the pipeline thread pool.
pub(crate) fn build_pool(threads: usize) -> Result<rayon::ThreadPool, rayon::ThreadPoolBuildError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("pipeline-{i}"))
        .build()
}

impl From<JobsError> for crate::error::ApiError {
    fn from(e: JobsError) -> Self {
        use crate::error::ApiError;
        match e {
            JobsError::Store(e) => e.into(),
            JobsError::Backend(msg) => {
                tracing::error!(error = %msg, "job backend failure");
                ApiError::Unavailable("the job system is unavailable; try again later".into())
            }
        }
    }
}
