//! `/v1/jobs`: status, listing, cancellation, progress events and output downloads.

use std::convert::Infallible;
use std::time::Duration;

use axum::body::Body;
use axum::extract::{Query, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Json;
use futures_util::stream::{self, Stream};
use serde::Deserialize;

use super::dto::{JobList, JobView};
use super::extract::ApiPath;
use super::AppState;
use crate::error::ApiError;
use crate::jobs::record::is_job_id;
use crate::jobs::{CancelError, JobRecord};

/// Parses `Prefer: wait=N` (RFC 7240), capped at `max` seconds.
pub(super) fn prefer_wait(headers: &HeaderMap, max: u64) -> Option<Duration> {
    headers
        .get_all("prefer")
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split([',', ';']))
        .filter_map(|p| p.trim().strip_prefix("wait="))
        .filter_map(|n| n.trim().parse::<u64>().ok())
        .map(|n| Duration::from_secs(n.min(max)))
        .next()
}

/// The JSON response for a job: 200 when it is finished, 202 while it is queued or running, with
/// `Location` pointing at the job.
pub(super) fn job_response(rec: JobRecord, waited: Option<Duration>) -> Response {
    let status = if rec.status.is_terminal() {
        StatusCode::OK
    } else {
        StatusCode::ACCEPTED
    };
    let view = JobView::from(rec);
    let mut resp = (status, Json(&view)).into_response();
    if let Ok(v) = HeaderValue::from_str(&view.url) {
        resp.headers_mut().insert(header::LOCATION, v);
    }
    if let Some(w) = waited {
        if let Ok(v) = HeaderValue::from_str(&format!("wait={}", w.as_secs())) {
            resp.headers_mut().insert("preference-applied", v);
        }
    }
    resp
}

async fn find(st: &AppState, id: &str) -> Result<JobRecord, ApiError> {
    let found = if is_job_id(id) {
        st.jobs.get(id).await?
    } else {
        None
    };
    found.ok_or_else(|| ApiError::NotFound(format!("no job {id}")))
}

/// `GET /v1/jobs/{id}`; honours `Prefer: wait=N`.
pub async fn get(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let rec = find(&st, &id).await?;
    let wait = prefer_wait(&headers, st.cfg.max_wait_secs);
    let rec = match wait {
        Some(w) if !rec.status.is_terminal() => st.jobs.wait(&id, w).await.unwrap_or(rec),
        _ => rec,
    };
    let mut resp = job_response(rec, wait);
    // A status document is not a new resource: GET answers 200 whatever the job's state.
    *resp.status_mut() = StatusCode::OK;
    Ok(resp)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ListQuery {
    /// Page size, 1–100. Default 20.
    limit: Option<usize>,
    /// The last job id of the previous page.
    cursor: Option<String>,
}

impl ListQuery {
    /// The page asked for, checked: `(limit, cursor)`. Shared by `GET /v1/jobs` and the OGC
    /// façade's `GET /ogc/jobs`.
    pub fn page(
        q: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
    ) -> Result<(usize, Option<String>), ApiError> {
        let Query(q) = q.map_err(|e| ApiError::bad_request(e.body_text()))?;
        let limit = q.limit.unwrap_or(20);
        if !(1..=100).contains(&limit) {
            return Err(ApiError::bad_field(
                "limit",
                "limit must be between 1 and 100",
            ));
        }
        if q.cursor.as_deref().is_some_and(|c| !is_job_id(c)) {
            return Err(ApiError::bad_field("cursor", "cursor must be a job id"));
        }
        Ok((limit, q.cursor))
    }
}

/// `GET /v1/jobs`: recent jobs, newest first.
pub async fn list(
    State(st): State<AppState>,
    q: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<JobList>, ApiError> {
    let (limit, cursor) = ListQuery::page(q)?;
    let (jobs, next_cursor) = st.jobs.list(limit, cursor.as_deref()).await?;
    Ok(Json(JobList {
        jobs: jobs.into_iter().map(JobView::from).collect(),
        next_cursor,
    }))
}

/// `DELETE /v1/jobs/{id}`: cancels a queued or running job.
pub async fn cancel(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, ApiError> {
    find(&st, &id).await?;
    match st.jobs.cancel(&id).await {
        Ok(rec) => Ok(job_response(rec, None)),
        Err(CancelError::NotFound(_)) => Err(ApiError::NotFound(format!("no job {id}"))),
        Err(e @ CancelError::Finished { .. }) => Err(ApiError::Conflict(e.to_string())),
        Err(CancelError::Backend(e)) => Err(e.into()),
    }
}

/// `GET /v1/jobs/{id}/events`: server-sent events. `progress` events carry
/// `{status, progress, stage}`; the last event is `done` with the whole job.
pub async fn events(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    find(&st, &id).await?;
    let rx = st
        .jobs
        .subscribe(&id)
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("no job {id}")))?;
    let jobs = st.jobs.clone();
    let shutdown = st.shutdown.clone();
    // State: (receiver, finished?, first event sent?)
    let s = stream::unfold((rx, false, false), move |(mut rx, finished, started)| {
        let jobs = jobs.clone();
        let id = id.clone();
        let shutdown = shutdown.clone();
        async move {
            if finished {
                return None;
            }
            if started {
                tokio::select! {
                    r = rx.changed() => if r.is_err() { return None; },
                    () = shutdown.cancelled() => return None,
                }
            }
            let snap = rx.borrow_and_update().clone();
            if snap.status.is_terminal() {
                let view = jobs.get(&id).await.ok().flatten().map(JobView::from);
                let data = serde_json::to_string(&view).unwrap_or_else(|_| "null".into());
                return Some((
                    Ok(Event::default().event("done").data(data)),
                    (rx, true, true),
                ));
            }
            let data = serde_json::to_string(&snap).unwrap_or_else(|_| "{}".into());
            Some((
                Ok(Event::default().event("progress").data(data)),
                (rx, false, true),
            ))
        }
    });
    Ok(Sse::new(s).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}

/// `GET /v1/jobs/{id}/outputs/{name}`: the output's bytes with a strong `ETag` (its SHA-256).
pub async fn output(
    State(st): State<AppState>,
    ApiPath((id, name)): ApiPath<(String, String)>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let rec = find(&st, &id).await?;
    if !rec.status.is_terminal() {
        return Err(ApiError::Conflict(format!(
            "job {id} is {}; outputs appear when it succeeds",
            rec.status.as_str()
        )));
    }
    let out = rec
        .outputs
        .iter()
        .find(|o| o.name == name)
        .ok_or_else(|| ApiError::NotFound(format!("job {id} has no output {name:?}")))?;
    let etag = format!("\"{}\"", out.sha256);
    let matches = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|t| t.trim() == etag || t.trim() == "*"));
    let mut builder = Response::builder()
        .header(header::ETAG, &etag)
        .header(header::CACHE_CONTROL, "private, max-age=86400, immutable");
    if matches {
        return builder
            .status(StatusCode::NOT_MODIFIED)
            .body(Body::empty())
            .map_err(ApiError::internal);
    }
    let stream = st
        .jobs
        .store()
        .blob_stream(&out.sha256)
        .await
        .map_err(|e| {
            tracing::error!(error = %e, blob = %out.sha256, "output blob missing");
            ApiError::Unavailable("the output is not available from storage".into())
        })?;
    builder = builder
        .status(StatusCode::OK)
        .header(header::CONTENT_TYPE, &out.media_type)
        .header(header::CONTENT_LENGTH, out.size)
        .header(
            header::CONTENT_DISPOSITION,
            format!("inline; filename=\"{}\"", out.name),
        );
    builder
        .body(Body::from_stream(stream))
        .map_err(ApiError::internal)
}
