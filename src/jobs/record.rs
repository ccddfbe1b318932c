//! The persisted job record and the public view of it.

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use crate::error::Problem;

/// Lifecycle of a job. `queued → running → succeeded | failed | canceled`; a job found `running`
/// at start-up (the process died mid-job) goes back to `queued`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Queued,
    Running,
    Succeeded,
    Failed,
    Canceled,
}

impl Status {
    pub fn is_terminal(self) -> bool {
        matches!(self, Status::Succeeded | Status::Failed | Status::Canceled)
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Status::Queued => "queued",
            Status::Running => "running",
            Status::Succeeded => "succeeded",
            Status::Failed => "failed",
            Status::Canceled => "canceled",
        }
    }
}

/// One stored output of a finished job.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OutputRecord {
    pub name: String,
    pub media_type: String,
    pub size: u64,
    pub sha256: String,
}

/// Time spent in one pipeline stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageTiming {
    pub stage: String,
    pub ms: f64,
}

/// Why a job failed (an RFC 9457 problem without the HTTP framing).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct JobError {
    #[serde(rename = "type")]
    pub kind: String,
    pub title: String,
    pub detail: String,
}

impl JobError {
    /// The record of a failure of kind `problem` (its `type` URI and title, as
    /// [`crate::error`] names them).
    pub fn new(problem: Problem, detail: impl Into<String>) -> Self {
        Self {
            kind: problem.type_uri(),
            title: problem.job_title().to_string(),
            detail: detail.into(),
        }
    }
}

/// The input a job reads: a stored asset, plus named auxiliary blobs some pipelines need besides
/// their main input (a cloud scene version's ambient field, `ambient.bin`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InputRef {
    pub asset: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub filename: Option<String>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub aux: Vec<AuxInput>,
    /// The run's estimated peak memory in bytes, estimated when the input was admitted: what
    /// a worker reserves from its process's memory budget before it starts the job (0: none).
    #[serde(default, skip_serializing_if = "is_zero_u64")]
    pub memory: u64,
}

fn is_zero_u64(n: &u64) -> bool {
    *n == 0
}

/// A named auxiliary input blob.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AuxInput {
    pub name: String,
    /// SHA-256 of the blob in the store.
    pub blob: String,
}

/// Everything known about a job; persisted as `jobs/<id>.json` at each status change.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    pub id: String,
    pub pipeline: String,
    pub status: Status,
    pub progress: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage: Option<String>,
    pub created_at: DateTime<Utc>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub started_at: Option<DateTime<Utc>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub finished_at: Option<DateTime<Utc>>,
    pub input: InputRef,
    /// Resolved parameters (defaults filled in), canonical JSON.
    pub params: serde_json::Value,
    /// SHA-256 over pipeline, input digest and canonical params: identical requests share it.
    pub key: String,
    #[serde(default)]
    pub timings: Vec<StageTiming>,
    #[serde(default)]
    pub outputs: Vec<OutputRecord>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<JobError>,
    /// How many times a worker started this job (more than 1 after a crash and restart, or after
    /// another replica took over a dead worker's job).
    #[serde(default)]
    pub attempts: u32,
    /// How many of those starts a graceful shutdown cut short (the job went back to the queue).
    /// They are not held against the job: only [`JobRecord::failed_attempts`] count towards
    /// `max_attempts`.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub interrupted: u32,
    /// The replica running (or that ran) the job's latest attempt.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub worker: Option<String>,
}

/// Live progress of a job, broadcast to SSE listeners and waiters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    pub status: Status,
    pub progress: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage: Option<String>,
}

fn is_zero(n: &u32) -> bool {
    *n == 0
}

impl JobRecord {
    /// Starts that ended neither in a result nor in a graceful re-queue: the pipeline panicked or
    /// the worker died.
    pub fn failed_attempts(&self) -> u32 {
        self.attempts.saturating_sub(self.interrupted)
    }

    pub fn snapshot(&self) -> Snapshot {
        Snapshot {
            status: self.status,
            progress: self.progress,
            stage: self.stage.clone(),
        }
    }
}

/// Fresh random 128-bit job id, 32 hex characters (unguessable).
pub fn new_job_id() -> String {
    hex::encode(rand::random::<[u8; 16]>())
}

/// True for a well-formed job id (guards every path built from a client-supplied id).
pub fn is_job_id(s: &str) -> bool {
    s.len() == 32
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}
