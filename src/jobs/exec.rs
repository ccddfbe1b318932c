//! Running one job, the same for every backend: read its input from the store, run the pipeline
//! on the rayon pool (never on the async runtime), wait for it with the job's time limit, store the
//! outputs as content-addressed blobs (so a job run twice after a crash writes the same blobs) and
//! return the final record. A panic inside a pipeline fails only that attempt: the job goes back
//! to the queue (a failed attempt, as if its worker had died) until it has been started
//! `max_attempts` times, then the backend ends it `failed` as poisoned.

use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use phenomena_engine::Control;

use super::{CancelReason, JobError, JobRecord, Live, OutputRecord, StageTiming, Status};
use crate::budget::{MemoryBudget, Reservation};
use crate::error::Problem;
use crate::metrics::Metrics;
use crate::pipeline_set::{PipelineSet, RunError};
use crate::store::Store;

/// What running a job needs; shared by a backend's workers.
pub(crate) struct Executor {
    pub store: Store,
    pub pipelines: Arc<dyn PipelineSet>,
    pub pool: rayon::ThreadPool,
    pub timeout: Duration,
    pub metrics: Metrics,
    /// The process's memory budget: a job's estimated peak is reserved before it starts.
    pub memory: MemoryBudget,
}

/// The pipeline's view of its job: forwards progress to the watch channel, measures each stage's
/// time, and reports cancellation.
struct JobControl {
    live: Arc<Live>,
    stages: Mutex<StageClock>,
}

struct StageClock {
    current: Option<(String, Instant)>,
    done: Vec<StageTiming>,
}

impl StageClock {
    fn close(&mut self) {
        if let Some((name, t0)) = self.current.take() {
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            match self.done.iter_mut().find(|s| s.stage == name) {
                Some(s) => s.ms += ms,
                None => self.done.push(StageTiming { stage: name, ms }),
            }
        }
    }
}

impl Control for JobControl {
    fn progress(&self, stage: &str, fraction: f32) {
        if let Ok(mut clock) = self.stages.lock() {
            if clock.current.as_ref().is_none_or(|(s, _)| s != stage) {
                clock.close();
                clock.current = Some((stage.to_string(), Instant::now()));
            }
        }
        let fraction = fraction.clamp(0.0, 1.0);
        self.live.tx.send_if_modified(|s| {
            // Publish stage changes and every half per cent of progress, not every row.
            let changed =
                s.stage.as_deref() != Some(stage) || (fraction - s.progress).abs() >= 0.005;
            if changed {
                s.progress = fraction;
                if s.stage.as_deref() != Some(stage) {
                    s.stage = Some(stage.to_string());
                }
            }
            changed
        });
    }

    fn is_canceled(&self) -> bool {
        self.live.cancel.load(Ordering::Relaxed) != 0
    }
}

/// Ends a job that was started `max_attempts` times and never reached an end (its pipeline
/// panicked, or its worker process died — a crash, an out-of-memory kill — in every attempt):
/// `failed` with the `poisoned` problem type, and never run again. Both backends call it when
/// they are about to start such a job once more. Sets `finished_at`.
pub(crate) fn poison(rec: &mut JobRecord, max_attempts: u32) {
    rec.status = Status::Failed;
    rec.progress = 0.0;
    rec.stage = None;
    rec.finished_at = Some(chrono::Utc::now());
    rec.error = Some(JobError::new(
        Problem::Poisoned,
        format!(
            "the job was started {} times and no attempt reached an end (the pipeline failed \
             unexpectedly, or its worker stopped: a crash or an out-of-memory kill); it is not \
             retried again (max_attempts = {max_attempts})",
            rec.failed_attempts()
        ),
    ));
}

/// An attempt that ended in a panic (or whose pipeline task vanished): not a result, so the job
/// goes back to the queue like one whose worker died. The attempt counts towards `max_attempts`
/// (it is not an interruption), so the backend poisons the job instead of starting it again once
/// it has been started that many times ([`poison`]).
fn failed_attempt(rec: &mut JobRecord, metrics: &Metrics) {
    rec.status = Status::Queued;
    rec.progress = 0.0;
    rec.stage = None;
    rec.outputs.clear();
    rec.error = None;
    metrics
        .jobs_failed_attempts
        .with_label_values(&[rec.pipeline.as_str()])
        .inc();
}

/// Reserves the job's estimated peak memory ([`super::InputRef::memory`]) from the process's
/// budget, waiting while other jobs and input checks hold it (a job larger than the whole budget
/// was refused at submission, or by [`execute`] on a worker with a smaller budget). `None`
/// when the job is canceled, or the process shuts down, while it waits.
async fn reserve_memory(ex: &Executor, rec: &JobRecord, live: &Live) -> Option<Reservation> {
    let bytes = rec.input.memory;
    if let Some(r) = ex.memory.try_reserve(bytes) {
        return Some(r);
    }
    tracing::info!(job = %rec.id, mib = bytes >> 20, "job waits for memory");
    let wait = ex.memory.reserve(bytes);
    tokio::pin!(wait);
    loop {
        tokio::select! {
            r = &mut wait => return r,
            () = tokio::time::sleep(Duration::from_millis(100)) => {
                if live.cancel.load(Ordering::Relaxed) != 0 {
                    return None;
                }
            }
        }
    }
}

/// A run that stopped at a cancellation: by its time limit (failed), by a graceful shutdown
/// (back to the queue) or by the user (canceled).
fn end_canceled(rec: &mut JobRecord, live: &Live, timeout: Duration) {
    match live.reason() {
        CancelReason::Timeout => {
            rec.status = Status::Failed;
            rec.error = Some(JobError::new(
                Problem::TimeLimit,
                format!(
                    "the job ran longer than the limit of {} s",
                    timeout.as_secs()
                ),
            ));
            tracing::warn!(job = %rec.id, "job exceeded its time limit");
        }
        CancelReason::Shutdown => {
            // A run cut short by a graceful shutdown is not held against the job: only
            // attempts whose worker died count towards `max_attempts`.
            rec.interrupted += 1;
            rec.status = Status::Queued;
            rec.progress = 0.0;
            rec.stage = None;
            tracing::info!(job = %rec.id, "job interrupted by shutdown; it stays queued");
        }
        CancelReason::User | CancelReason::None => {
            rec.status = Status::Canceled;
            tracing::info!(job = %rec.id, "job canceled");
        }
    }
}

/// Runs one job to its final record.
pub(crate) async fn execute(ex: &Executor, mut rec: JobRecord, live: Arc<Live>) -> JobRecord {
    let t0 = Instant::now();
    tracing::info!(job = %rec.id, pipeline = %rec.pipeline, attempt = rec.attempts, "job started");
    // A job whose estimated peak is more than this worker's whole budget (a Redis worker
    // configured with a smaller budget than the API replica that admitted it) is refused rather
    // than run on the whole budget and beyond.
    let total = ex.memory.total_bytes();
    if rec.input.memory > total {
        tracing::warn!(job = %rec.id, mib = rec.input.memory >> 20, budget_mib = total >> 20, "job larger than this worker's memory budget; refused");
        rec.status = Status::Failed;
        rec.error = Some(JobError::new(
            Problem::TooLarge,
            format!(
                "the job needs an estimated {} MiB of memory, more than this worker's whole \
                 memory budget of {} MiB (--memory-budget-bytes); run it on workers with a larger \
                 budget, or make it smaller (a smaller input or output)",
                rec.input.memory.div_ceil(1 << 20),
                total >> 20
            ),
        ));
        return rec;
    }
    // The run's estimated peak memory, reserved from the process's budget (shared with the
    // API's input checks) before the input is read; held until the outputs are stored.
    let _memory = match reserve_memory(ex, &rec, &live).await {
        Some(r) => r,
        None => {
            end_canceled(&mut rec, &live, ex.timeout);
            return rec;
        }
    };
    let read = async {
        let input = ex.store.read_blob(&rec.input.asset).await?;
        let mut aux = Vec::with_capacity(rec.input.aux.len());
        for a in &rec.input.aux {
            aux.push((a.name.clone(), ex.store.read_blob(&a.blob).await?.to_vec()));
        }
        Ok::<_, crate::store::StoreError>((input, aux))
    };
    let (input, aux) = match read.await {
        Ok(bytes) => bytes,
        Err(e) => {
            tracing::error!(job = %rec.id, error = %e, "input blob unreadable");
            rec.status = Status::Failed;
            rec.error = Some(JobError::new(
                Problem::InputMissing,
                "the job's input could not be read from the store",
            ));
            return rec;
        }
    };

    let ctl = Arc::new(JobControl {
        live: live.clone(),
        stages: Mutex::new(StageClock {
            current: None,
            done: Vec::new(),
        }),
    });
    let (tx, rx) = tokio::sync::oneshot::channel();
    {
        let pipelines = ex.pipelines.clone();
        let ctl = ctl.clone();
        let name = rec.pipeline.clone();
        let params = rec.params.clone();
        let filename = rec.input.filename.clone();
        let job_id = rec.id.clone();
        ex.pool.spawn(move || {
            let span = tracing::info_span!("job", job = %job_id, pipeline = %name);
            let _e = span.enter();
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                pipelines.run_with_named_inputs(
                    &name,
                    &params,
                    &input,
                    filename.as_deref(),
                    &aux,
                    ctl.as_ref(),
                )
            }));
            let _ = tx.send(result);
        });
    }
    let timeout = ex.timeout;
    let mut rx = rx;
    let result = match tokio::time::timeout(timeout, &mut rx).await {
        Ok(r) => r,
        Err(_) => {
            live.raise(CancelReason::Timeout);
            rx.await
        }
    };
    if let Ok(mut clock) = ctl.stages.lock() {
        clock.close();
        rec.timings = std::mem::take(&mut clock.done);
    }
    let total = t0.elapsed().as_secs_f64();
    let metrics = &ex.metrics;
    for s in &rec.timings {
        metrics
            .job_duration
            .with_label_values(&[rec.pipeline.as_str(), s.stage.as_str()])
            .observe(s.ms / 1e3);
    }
    metrics
        .job_duration
        .with_label_values(&[rec.pipeline.as_str(), "total"])
        .observe(total);

    match result {
        Ok(Ok(Ok(outputs))) => {
            let stored = async {
                let mut outs = Vec::with_capacity(outputs.len());
                for o in outputs {
                    let size = o.bytes.len() as u64;
                    let sha = ex.store.put_blob(bytes::Bytes::from(o.bytes)).await?;
                    outs.push(OutputRecord {
                        name: o.name,
                        media_type: o.media_type.to_string(),
                        size,
                        sha256: sha,
                    });
                }
                Ok::<_, crate::store::StoreError>(outs)
            }
            .await;
            match stored {
                Ok(outs) => {
                    rec.outputs = outs;
                    rec.status = Status::Succeeded;
                    tracing::info!(job = %rec.id, seconds = total, "job succeeded");
                }
                Err(e) => {
                    tracing::error!(job = %rec.id, error = %e, "could not store outputs");
                    rec.status = Status::Failed;
                    rec.error = Some(JobError::new(
                        Problem::Storage,
                        "the outputs could not be stored (the data directory or blob store is \
                         full or read-only); submit the request again once storage recovers",
                    ));
                }
            }
        }
        Ok(Ok(Err(RunError::Canceled))) => end_canceled(&mut rec, &live, timeout),
        Ok(Ok(Err(RunError::Input(e)))) => {
            rec.status = Status::Failed;
            rec.error = Some(JobError::new(Problem::InvalidInput, e.to_string()));
        }
        Ok(Ok(Err(RunError::Refused { reason, detail }))) => {
            rec.status = Status::Failed;
            rec.error = Some(JobError::new(reason.into(), detail));
        }
        Ok(Ok(Err(RunError::Param(e)))) => {
            rec.status = Status::Failed;
            rec.error = Some(JobError::new(Problem::InvalidParameter, e.to_string()));
        }
        Ok(Err(panic)) => {
            let msg = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            tracing::error!(job = %rec.id, attempt = rec.attempts, panic = %msg, "pipeline panicked; the attempt failed and the job goes back to the queue");
            failed_attempt(&mut rec, metrics);
        }
        Err(_) => {
            tracing::error!(job = %rec.id, attempt = rec.attempts, "pipeline task vanished; the attempt failed and the job goes back to the queue");
            failed_attempt(&mut rec, metrics);
        }
    }
    rec
}
