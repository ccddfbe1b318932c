//! Wire types of the API responses.

use serde::Serialize;

use crate::jobs::{JobError, JobRecord, StageTiming};

/// One output of a finished job, with its download URL.
#[derive(Debug, Serialize)]
pub struct OutputView {
    pub name: String,
    pub media_type: String,
    pub size: u64,
    pub sha256: String,
    pub url: String,
}

/// A job as the API shows it.
#[derive(Debug, Serialize)]
pub struct JobView {
    pub id: String,
    pub pipeline: String,
    pub status: &'static str,
    pub progress: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage: Option<String>,
    pub created_at: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub started_at: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub finished_at: Option<String>,
    pub attempts: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub worker: Option<String>,
    pub input: crate::jobs::InputRef,
    pub params: serde_json::Value,
    pub timings: Vec<StageTiming>,
    pub outputs: Vec<OutputView>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<JobError>,
    pub url: String,
    pub events_url: String,
}

fn ts(t: chrono::DateTime<chrono::Utc>) -> String {
    t.to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

impl From<JobRecord> for JobView {
    fn from(r: JobRecord) -> Self {
        let url = format!("/v1/jobs/{}", r.id);
        JobView {
            outputs: r
                .outputs
                .into_iter()
                .map(|o| OutputView {
                    url: format!("{url}/outputs/{}", o.name),
                    name: o.name,
                    media_type: o.media_type,
                    size: o.size,
                    sha256: o.sha256,
                })
                .collect(),
            events_url: format!("{url}/events"),
            id: r.id,
            pipeline: r.pipeline,
            status: r.status.as_str(),
            progress: r.progress,
            stage: r.stage,
            created_at: ts(r.created_at),
            started_at: r.started_at.map(ts),
            finished_at: r.finished_at.map(ts),
            attempts: r.attempts,
            worker: r.worker,
            input: r.input,
            params: r.params,
            timings: r.timings,
            error: r.error,
            url,
        }
    }
}

/// A page of jobs.
#[derive(Debug, Serialize)]
pub struct JobList {
    pub jobs: Vec<JobView>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub next_cursor: Option<String>,
}
