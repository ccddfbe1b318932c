//! The Redis job backend: many replicas share one queue, one job state and one progress feed.
//!
//! Layout (every key under the `--redis-prefix`, `P`):
//! ```text
//! P:job:<id>      job record (JSON, the same as the embedded backend's jobs/<id>.json)
//! P:snap:<id>     live progress of a running job (JSON snapshot; expires after a day)
//! P:key:<key>     request key → the live job with that key (result reuse)
//! P:jobs          sorted set: every job by creation time (µs) — listing
//! P:done          sorted set: finished jobs by finish time (ms) — retention
//! P:queued        set of queued job ids — queue depth and the queue limit
//! P:running       hash: running job id → owner (`replica#attempt`)
//! P:queue         stream of job ids, consumer group `workers` — the work queue
//! P:cancel:<id>   a cancel request for a running job
//! P:dead          list: dead letters, ids of jobs failed as poisoned (started `max_attempts`
//!                 times, none reached an end: a panic or a dead worker); an id leaves it when its job expires
//! P:progress, P:cancel, P:work   pub/sub channels (progress snapshots, cancel requests, new work)
//! ```
//!
//! Delivery is at least once: a worker reads an entry with `XREADGROUP`, owns it while it
//! heartbeats (`XCLAIM … JUSTID` every lease/3 resets the entry's idle time), and acknowledges it
//! when the job ends. An entry idle for longer than the lease (its worker died) is taken over by
//! another replica with `XAUTOCLAIM`, which runs the job again (`attempts` + 1), unless it has
//! already been started `max_attempts` times: then it ends `failed` as poisoned. Every transition
//! is a compare-and-set on the record ([`scripts`]), so a slow worker that lost its job cannot
//! overwrite the new owner's result; outputs are content-addressed blobs, so a run done twice
//! writes the same bytes under the same names.
//!
//! Progress goes to pub/sub; each replica keeps one subscriber connection ([`hub`]) and fans
//! messages out to local SSE streams and waiters, so `GET /v1/jobs/{id}/events` works on any
//! replica. Redis restarts are survived: the connection manager and the subscriber reconnect, the
//! consumer group is recreated when missing, and watchers re-read their jobs. Durability across a
//! Redis restart needs Redis persistence (AOF), as any Redis-backed queue does.

mod hub;
mod scripts;
mod worker;

use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use async_trait::async_trait;
use chrono::Utc;
use redis::aio::ConnectionManager;
use serde::{Deserialize, Serialize};
use tokio::sync::{watch, Notify};

use super::exec::Executor;
use super::{
    build_pool, CancelError, InputRef, JobBackend, JobHooks, JobRecord, JobsConfig, JobsError,
    Live, Load, Snapshot, StartError, Status, SubmitError, Submitted,
};
use crate::metrics::Metrics;
use crate::pipeline_set::PipelineSet;
use crate::store::Store;

/// Settings of the Redis backend.
#[derive(Debug, Clone)]
pub struct RedisSettings {
    /// `redis://[user:password@]host:port/db`.
    pub url: String,
    /// Prefix of every key and channel.
    pub prefix: String,
    /// A worker silent for this long loses its job to another replica.
    pub lease: Duration,
    /// This replica's name (the consumer name in the group, `worker` in job records).
    pub replica: String,
}

/// The consumer group every replica's workers join.
const GROUP: &str = "workers";

/// Key names under one prefix.
#[derive(Debug, Clone)]
pub(crate) struct Keys {
    p: String,
}

impl Keys {
    pub fn new(prefix: &str) -> Self {
        Self {
            p: prefix.to_string(),
        }
    }
    pub fn prefix(&self) -> &str {
        &self.p
    }
    fn job(&self, id: &str) -> String {
        format!("{}:job:{id}", self.p)
    }
    fn snap(&self, id: &str) -> String {
        format!("{}:snap:{id}", self.p)
    }
    fn key(&self, key: &str) -> String {
        format!("{}:key:{key}", self.p)
    }
    fn cancel(&self, id: &str) -> String {
        format!("{}:cancel:{id}", self.p)
    }
    fn named(&self, name: &str) -> String {
        format!("{}:{name}", self.p)
    }
}

/// A progress message on `P:progress`.
#[derive(Debug, Serialize, Deserialize)]
struct ProgressMsg {
    id: String,
    #[serde(flatten)]
    snap: Snapshot,
}

pub(crate) fn backend_err(e: redis::RedisError) -> JobsError {
    JobsError::Backend(e.to_string())
}

fn json_err(e: serde_json::Error) -> JobsError {
    JobsError::Backend(format!("a job record in Redis is not valid JSON: {e}"))
}

/// Opens a connection manager (reconnects by itself) with bounded waits.
pub(crate) async fn connect(
    client: &redis::Client,
) -> Result<ConnectionManager, redis::RedisError> {
    let cfg = redis::aio::ConnectionManagerConfig::new()
        .set_connection_timeout(Some(Duration::from_secs(2)))
        .set_response_timeout(Some(Duration::from_secs(5)))
        .set_number_of_retries(3)
        .set_max_delay(Duration::from_secs(2));
    ConnectionManager::new_with_config(client.clone(), cfg).await
}

struct Inner {
    con: ConnectionManager,
    client: redis::Client,
    keys: Keys,
    settings: RedisSettings,
    cfg: JobsConfig,
    exec: Executor,
    hooks: Arc<dyn JobHooks>,
    hub: hub::Hub,
    accepting: AtomicBool,
    /// Jobs running in this process.
    local: Mutex<HashMap<String, Arc<Live>>>,
    idle: Notify,
}

/// The Redis backend; cheap to clone.
#[derive(Clone)]
pub struct RedisJobs {
    inner: Arc<Inner>,
}

impl RedisJobs {
    /// Connects, makes sure the consumer group exists, and starts the subscriber and
    /// `cfg.concurrency` worker slots on the current runtime.
    pub async fn start(
        settings: RedisSettings,
        store: Store,
        pipelines: Arc<dyn PipelineSet>,
        hooks: Arc<dyn JobHooks>,
        cfg: JobsConfig,
        metrics: Metrics,
    ) -> Result<Self, StartError> {
        let client = redis::Client::open(settings.url.as_str())
            .map_err(|e| StartError::Backend(format!("invalid Redis URL: {e}")))?;
        let con = connect(&client)
            .await
            .map_err(|e| StartError::Backend(format!("cannot reach Redis: {e}")))?;
        let pool = build_pool(cfg.threads)?;
        metrics
            .workers
            .set(i64::try_from(cfg.concurrency).unwrap_or(0));
        let jobs = RedisJobs {
            inner: Arc::new(Inner {
                con,
                client,
                keys: Keys::new(&settings.prefix),
                exec: Executor {
                    store,
                    pipelines,
                    pool,
                    timeout: cfg.job_timeout,
                    metrics,
                    memory: cfg.memory.clone(),
                },
                settings,
                cfg,
                hooks,
                hub: hub::Hub::default(),
                accepting: AtomicBool::new(true),
                local: Mutex::new(HashMap::new()),
                idle: Notify::new(),
            }),
        };
        jobs.ensure_group()
            .await
            .map_err(|e| StartError::Backend(format!("cannot create the consumer group: {e}")))?;
        tokio::spawn(hub::listen(jobs.clone()));
        for i in 0..jobs.inner.cfg.concurrency {
            tokio::spawn(worker::slot(jobs.clone(), i));
        }
        tracing::info!(
            prefix = %jobs.inner.keys.prefix(),
            replica = %jobs.inner.settings.replica,
            workers = jobs.inner.cfg.concurrency,
            "Redis job backend started"
        );
        Ok(jobs)
    }

    fn con(&self) -> ConnectionManager {
        self.inner.con.clone()
    }

    fn local(&self) -> MutexGuard<'_, HashMap<String, Arc<Live>>> {
        // No code that can panic runs under this lock.
        self.inner
            .local
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Creates the stream and its consumer group if missing (first start, or after Redis lost
    /// its data).
    async fn ensure_group(&self) -> Result<(), redis::RedisError> {
        let r: Result<(), redis::RedisError> = redis::cmd("XGROUP")
            .arg("CREATE")
            .arg(self.inner.keys.named("queue"))
            .arg(GROUP)
            .arg("0")
            .arg("MKSTREAM")
            .query_async(&mut self.con())
            .await;
        match r {
            Err(e) if e.code() == Some("BUSYGROUP") => Ok(()),
            other => other,
        }
    }

    /// The stored record (raw JSON and parsed), without live progress.
    async fn load_raw(&self, id: &str) -> Result<Option<(String, JobRecord)>, JobsError> {
        let raw: Option<String> = redis::cmd("GET")
            .arg(self.inner.keys.job(id))
            .query_async(&mut self.con())
            .await
            .map_err(backend_err)?;
        match raw {
            Some(raw) => {
                let rec = serde_json::from_str(&raw).map_err(json_err)?;
                Ok(Some((raw, rec)))
            }
            None => Ok(None),
        }
    }

    /// Records by id (missing ones skipped), running ones with their live progress.
    async fn load_many(&self, ids: &[String]) -> Result<Vec<JobRecord>, JobsError> {
        if ids.is_empty() {
            return Ok(Vec::new());
        }
        let keys = &self.inner.keys;
        let mut pipe = redis::pipe();
        for id in ids {
            pipe.get(keys.job(id)).get(keys.snap(id));
        }
        let raw: Vec<Option<String>> = pipe
            .query_async(&mut self.con())
            .await
            .map_err(backend_err)?;
        let mut out = Vec::with_capacity(ids.len());
        for pair in raw.chunks(2) {
            let [rec, snap] = pair else { continue };
            let Some(rec) = rec else { continue };
            let mut rec: JobRecord = serde_json::from_str(rec).map_err(json_err)?;
            if rec.status == Status::Running {
                if let Some(s) = snap
                    .as_deref()
                    .and_then(|s| serde_json::from_str::<Snapshot>(s).ok())
                {
                    rec.progress = s.progress;
                    rec.stage = s.stage;
                }
            }
            out.push(rec);
        }
        Ok(out)
    }

    async fn fetch(&self, id: &str) -> Result<Option<JobRecord>, JobsError> {
        Ok(self.load_many(&[id.to_string()]).await?.pop())
    }

    /// Publishes a job's snapshot to every replica's watchers.
    async fn publish(&self, id: &str, snap: &Snapshot) -> Result<(), JobsError> {
        let msg = serde_json::to_string(&ProgressMsg {
            id: id.to_string(),
            snap: snap.clone(),
        })
        .map_err(json_err)?;
        redis::cmd("PUBLISH")
            .arg(self.inner.keys.named("progress"))
            .arg(msg)
            .query_async::<()>(&mut self.con())
            .await
            .map_err(backend_err)
    }

    async fn wait_idle(&self, deadline: tokio::time::Instant) -> bool {
        loop {
            let notified = self.inner.idle.notified();
            if self.local().is_empty() {
                return true;
            }
            if tokio::time::timeout_at(deadline, notified).await.is_err() {
                return self.local().is_empty();
            }
        }
    }
}

fn millis(t: chrono::DateTime<Utc>) -> i64 {
    t.timestamp_millis()
}

#[async_trait]
impl JobBackend for RedisJobs {
    fn kind(&self) -> &'static str {
        "redis"
    }

    fn accepting(&self) -> bool {
        self.inner.accepting.load(Ordering::Acquire)
    }

    async fn find_by_key(&self, key: &str) -> Result<Option<JobRecord>, JobsError> {
        let id: Option<String> = redis::cmd("GET")
            .arg(self.inner.keys.key(key))
            .query_async(&mut self.con())
            .await
            .map_err(backend_err)?;
        match id {
            Some(id) => self.fetch(&id).await,
            None => Ok(None),
        }
    }

    async fn submit(
        &self,
        pipeline: &str,
        input: InputRef,
        params: serde_json::Value,
        key: String,
    ) -> Result<Submitted, SubmitError> {
        if !self.accepting() {
            return Err(SubmitError::ShuttingDown);
        }
        let rec = JobRecord {
            id: super::record::new_job_id(),
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
        let raw = serde_json::to_string(&rec).map_err(json_err)?;
        let reply: Vec<String> = scripts::SUBMIT
            .arg(self.inner.keys.prefix())
            .arg(&key)
            .arg(&rec.id)
            .arg(raw)
            .arg(self.inner.cfg.queue_capacity)
            .arg(rec.created_at.timestamp_micros())
            .invoke_async(&mut self.con())
            .await
            .map_err(backend_err)?;
        match reply.as_slice() {
            [s, id] if s == "reused" => match self.fetch(id).await? {
                Some(r) => Ok(Submitted::Reused(r)),
                // Expired between the two reads: the next submission queues it afresh.
                None => Err(JobsError::Backend("a reused job vanished; retry".into()).into()),
            },
            [s] if s == "full" => Err(SubmitError::QueueFull {
                capacity: self.inner.cfg.queue_capacity,
            }),
            _ => Ok(Submitted::Queued(rec)),
        }
    }

    async fn get(&self, id: &str) -> Result<Option<JobRecord>, JobsError> {
        self.fetch(id).await
    }

    async fn subscribe(&self, id: &str) -> Result<Option<watch::Receiver<Snapshot>>, JobsError> {
        self.inner.hub.watch(self, id).await
    }

    async fn list(
        &self,
        limit: usize,
        after: Option<&str>,
    ) -> Result<(Vec<JobRecord>, Option<String>), JobsError> {
        let jobs = self.inner.keys.named("jobs");
        let mut con = self.con();
        let total: usize = redis::cmd("ZCARD")
            .arg(&jobs)
            .query_async(&mut con)
            .await
            .map_err(backend_err)?;
        let start = match after {
            Some(c) => {
                let rank: Option<usize> = redis::cmd("ZREVRANK")
                    .arg(&jobs)
                    .arg(c)
                    .query_async(&mut con)
                    .await
                    .map_err(backend_err)?;
                rank.map_or(total, |r| r + 1)
            }
            None => 0,
        };
        if start >= total || limit == 0 {
            return Ok((Vec::new(), None));
        }
        // Equal scores come back in reverse id order: newest first, then id descending, as in
        // the embedded backend.
        let ids: Vec<String> = redis::cmd("ZREVRANGE")
            .arg(&jobs)
            .arg(start)
            .arg(start + limit - 1)
            .query_async(&mut con)
            .await
            .map_err(backend_err)?;
        let page = self.load_many(&ids).await?;
        let next = (start + ids.len() < total)
            .then(|| ids.last().cloned())
            .flatten();
        Ok((page, next))
    }

    async fn cancel(&self, id: &str) -> Result<JobRecord, CancelError> {
        // A queued job's record may change under us (a worker starts it): retry the CAS.
        for _ in 0..5 {
            let Some((raw, rec)) = self.load_raw(id).await? else {
                return Err(CancelError::NotFound(id.to_string()));
            };
            match rec.status {
                Status::Queued => {
                    let mut new = rec.clone();
                    new.status = Status::Canceled;
                    new.finished_at = Some(Utc::now());
                    let new_raw = serde_json::to_string(&new).map_err(json_err)?;
                    let msg = serde_json::to_string(&ProgressMsg {
                        id: id.to_string(),
                        snap: new.snapshot(),
                    })
                    .map_err(json_err)?;
                    let done: i64 = scripts::CANCEL_QUEUED
                        .arg(self.inner.keys.prefix())
                        .arg(id)
                        .arg(raw)
                        .arg(new_raw)
                        .arg(&new.key)
                        .arg(new.finished_at.map_or(0, millis))
                        .arg(msg)
                        .invoke_async(&mut self.con())
                        .await
                        .map_err(backend_err)?;
                    if done == 1 {
                        self.inner
                            .exec
                            .metrics
                            .jobs_finished
                            .with_label_values(&[new.pipeline.as_str(), "canceled"])
                            .inc();
                        return Ok(new);
                    }
                }
                Status::Running => {
                    // The owner sees the request at once over pub/sub, or at its next heartbeat.
                    let mut con = self.con();
                    redis::pipe()
                        .cmd("SET")
                        .arg(self.inner.keys.cancel(id))
                        .arg(1)
                        .arg("EX")
                        .arg(86_400)
                        .ignore()
                        .cmd("PUBLISH")
                        .arg(self.inner.keys.named("cancel"))
                        .arg(id)
                        .ignore()
                        .query_async::<()>(&mut con)
                        .await
                        .map_err(backend_err)?;
                    if let Some(live) = self.local().get(id) {
                        live.raise(super::CancelReason::User);
                    }
                    return Ok(self.fetch(id).await?.unwrap_or(rec));
                }
                s => {
                    return Err(CancelError::Finished {
                        id: id.to_string(),
                        status: s.as_str(),
                    })
                }
            }
        }
        Err(JobsError::Backend("the job kept changing; retry the cancel".into()).into())
    }

    async fn load(&self) -> Result<Load, JobsError> {
        let (queued, running): (usize, usize) = redis::pipe()
            .cmd("SCARD")
            .arg(self.inner.keys.named("queued"))
            .cmd("HLEN")
            .arg(self.inner.keys.named("running"))
            .query_async(&mut self.con())
            .await
            .map_err(backend_err)?;
        self.inner
            .exec
            .metrics
            .queue_depth
            .set(i64::try_from(queued).unwrap_or(i64::MAX));
        Ok(Load {
            queued,
            running,
            running_here: self.local().len(),
            workers: self.inner.cfg.concurrency,
        })
    }

    async fn check(&self) -> Result<(), JobsError> {
        redis::cmd("PING")
            .query_async::<()>(&mut self.con())
            .await
            .map_err(backend_err)
    }

    async fn shutdown(&self, grace: Duration) {
        self.inner.accepting.store(false, Ordering::Release);
        self.inner.hub.work.notify_waiters();
        let deadline = tokio::time::Instant::now() + grace;
        if self.wait_idle(deadline).await {
            return;
        }
        let lives: Vec<Arc<Live>> = self.local().values().cloned().collect();
        tracing::warn!(
            jobs = lives.len(),
            "grace period over: interrupting running jobs (they go back to the queue)"
        );
        for l in &lives {
            l.raise(super::CancelReason::Shutdown);
        }
        self.wait_idle(tokio::time::Instant::now() + Duration::from_secs(5))
            .await;
    }

    async fn expire(&self, older_than: chrono::DateTime<Utc>) -> Result<usize, JobsError> {
        let ids: Vec<String> = redis::cmd("ZRANGEBYSCORE")
            .arg(self.inner.keys.named("done"))
            .arg("-inf")
            .arg(format!("({}", millis(older_than)))
            .arg("LIMIT")
            .arg(0)
            .arg(1000)
            .query_async(&mut self.con())
            .await
            .map_err(backend_err)?;
        let recs = self.load_many(&ids).await?;
        let keys: HashMap<&str, &str> = recs
            .iter()
            .map(|r| (r.id.as_str(), r.key.as_str()))
            .collect();
        for id in &ids {
            scripts::EXPIRE
                .arg(self.inner.keys.prefix())
                .arg(id)
                .arg(keys.get(id.as_str()).copied().unwrap_or(""))
                .invoke_async::<()>(&mut self.con())
                .await
                .map_err(backend_err)?;
        }
        Ok(ids.len())
    }

    async fn referenced_blobs(&self) -> Result<HashSet<String>, JobsError> {
        let ids: Vec<String> = redis::cmd("ZRANGE")
            .arg(self.inner.keys.named("jobs"))
            .arg(0)
            .arg(-1)
            .query_async(&mut self.con())
            .await
            .map_err(backend_err)?;
        let mut keep = HashSet::new();
        for chunk in ids.chunks(500) {
            for r in self.load_many(chunk).await? {
                keep.insert(r.input.asset);
                keep.extend(r.input.aux.into_iter().map(|a| a.blob));
                keep.extend(r.outputs.into_iter().map(|o| o.sha256));
            }
        }
        Ok(keep)
    }

    async fn sweep_turn(&self, interval: Duration) -> bool {
        // One replica per interval: the first to set the marker sweeps.
        let ms = u64::try_from(interval.as_millis()).unwrap_or(u64::MAX) * 9 / 10;
        let won: Result<Option<String>, _> = redis::cmd("SET")
            .arg(self.inner.keys.named("sweep"))
            .arg(&self.inner.settings.replica)
            .arg("NX")
            .arg("PX")
            .arg(ms.max(1))
            .query_async(&mut self.con())
            .await;
        matches!(won, Ok(Some(_)))
    }
}
