//! OGC API – Processes – Part 1: Core 1.0 (OGC 18-062r2) as a thin façade over the jobs
//! (issue 22), mounted under [`PREFIX`] (`/ogc`): the service's own page already answers `/`.
//!
//! Nothing here runs or stores anything of its own. A process is a pipeline of the
//! [`crate::pipeline_set::PipelineSet`]; its description's inputs are the pipeline's parameters
//! as `openapi.yaml` describes them (the schema of `POST /v1/{pipeline}`'s `params`, the same
//! schema the studio's form is built from), plus its input file and auxiliary files given by
//! reference to an uploaded asset; its outputs are the pipeline's
//! (`registry::PipelineKind::outputs`). An execution is a submission through the one submit
//! path (`submit::submit_inputs`: the same validation, admission and request key, so an
//! identical request joins the identical job), and a job is the job system's record shown as
//! OGC `statusInfo`. Dismissal is the job's cancellation.
//!
//! Conformance classes implemented (§7.4): `core`, `ogc-process-description`, `json` and
//! `dismiss`. Not implemented: synchronous execution (every process is `async-execute` only, so
//! per `/req/core/process-execute-default-execution-mode` the job is created whatever the
//! `Prefer` header says), `outputs` selection and `response: raw` (all outputs are returned by
//! reference, as a results document), `subscriber` callbacks, `job-list` filters (`/ogc/jobs`
//! pages by `limit` and `cursor` only), `html` and `oas30` (the API document is OpenAPI 3.1).

use std::sync::LazyLock;

use axum::extract::{Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;
use serde_json::{json, Map, Value};

use super::extract::ApiPath;
use super::jobs::ListQuery;
use super::strict_json::{self, StrictJsonError};
use super::submit::{submit_inputs, Input};
use super::AppState;
use crate::error::{ApiError, Problem};
use crate::jobs::record::is_job_id;
use crate::jobs::{CancelError, JobRecord, Status};

/// Where the OGC API is mounted.
pub const PREFIX: &str = "/ogc";

/// The conformance classes this façade implements (OGC 18-062r2 Annex A).
pub const CONFORMANCE: &[&str] = &[
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/ogc-process-description",
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/json",
    "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/dismiss",
];

/// Link relations of OGC API – Processes (§7.2, §7.12).
const REL_CONFORMANCE: &str = "http://www.opengis.net/def/rel/ogc/1.0/conformance";
const REL_PROCESSES: &str = "http://www.opengis.net/def/rel/ogc/1.0/processes";
const REL_JOB_LIST: &str = "http://www.opengis.net/def/rel/ogc/1.0/job-list";
const REL_EXECUTE: &str = "http://www.opengis.net/def/rel/ogc/1.0/execute";
const REL_RESULTS: &str = "http://www.opengis.net/def/rel/ogc/1.0/results";

/// The version every process description states: the service's.
const PROCESS_VERSION: &str = env!("CARGO_PKG_VERSION");

/// `openapi.yaml` as JSON, parsed once: where the processes' inputs are described.
static SPEC: LazyLock<Result<Value, String>> = LazyLock::new(|| {
    serde_yaml::from_str::<Value>(super::system::OPENAPI_YAML).map_err(|e| e.to_string())
});

fn link(href: String, rel: &str, media_type: &str, title: &str) -> Value {
    json!({"href": href, "rel": rel, "type": media_type, "title": title})
}

/// `GET /ogc`: the landing page (§7.2).
pub async fn landing() -> Json<Value> {
    Json(json!({
        "title": "phenomena: OGC API – Processes",
        "description": "The rendering pipelines (snow on terrain, snow cover, clouds, dust) as OGC API – Processes – Part 1: Core 1.0 processes, executed asynchronously as the service's own jobs.",
        "links": [
            link(PREFIX.to_string(), "self", "application/json", "This document"),
            link("/openapi.yaml".into(), "service-desc", "application/vnd.oai.openapi;version=3.1", "The API definition (OpenAPI 3.1, YAML)"),
            link("/".into(), "service-doc", "text/html", "The studio page"),
            link(format!("{PREFIX}/conformance"), REL_CONFORMANCE, "application/json", "Conformance classes implemented"),
            link(format!("{PREFIX}/processes"), REL_PROCESSES, "application/json", "The processes"),
            link(format!("{PREFIX}/jobs"), REL_JOB_LIST, "application/json", "The jobs"),
        ],
    }))
}

/// `GET /ogc/conformance` (§7.4).
pub async fn conformance() -> Json<Value> {
    Json(json!({ "conformsTo": CONFORMANCE }))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProcessListQuery {
    /// Processes per page, 1–10 000 (default 10; `/req/core/pl-limit-definition`).
    limit: Option<u32>,
    /// Processes skipped (the `next` link's).
    offset: Option<u32>,
}

/// `GET /ogc/processes` (§7.9): the pipelines' summaries.
pub async fn processes(
    State(st): State<AppState>,
    q: Result<Query<ProcessListQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<Value>, ApiError> {
    let Query(q) = q.map_err(|e| ApiError::bad_request(e.body_text()))?;
    let limit = q.limit.unwrap_or(10);
    if !(1..=10_000).contains(&limit) {
        return Err(ApiError::bad_field(
            "limit",
            "limit must be between 1 and 10000",
        ));
    }
    let offset = q.offset.unwrap_or(0) as usize;
    let names = st.jobs.pipelines().names();
    let page: Vec<Value> = names
        .iter()
        .skip(offset)
        .take(limit as usize)
        .map(|name| Ok(summary(name)?.0))
        .collect::<Result<_, ApiError>>()?;
    let mut links = vec![link(
        format!("{PREFIX}/processes?limit={limit}&offset={offset}"),
        "self",
        "application/json",
        "This page",
    )];
    if offset + (limit as usize) < names.len() {
        links.push(link(
            format!(
                "{PREFIX}/processes?limit={limit}&offset={}",
                offset + limit as usize
            ),
            "next",
            "application/json",
            "The next page",
        ));
    }
    Ok(Json(json!({ "processes": page, "links": links })))
}

/// The pipeline named `id` (its `&'static` name), or `no-such-process`.
fn process_name(st: &AppState, id: &str) -> Result<&'static str, ApiError> {
    st.jobs
        .pipelines()
        .names()
        .into_iter()
        .find(|n| *n == id)
        .ok_or_else(|| {
            ApiError::NoSuchProcess(format!(
                "no process {id:?}; processes: {}",
                st.jobs.pipelines().names().join(", ")
            ))
        })
}

/// A process summary (§7.9, `processSummary`) and the pipeline's operation in `openapi.yaml`.
fn summary(name: &str) -> Result<(Value, Value), ApiError> {
    let spec = SPEC.as_ref().map_err(ApiError::internal)?;
    let op = spec
        .pointer(&format!("/paths/~1v1~1{name}/post"))
        .cloned()
        .unwrap_or(Value::Null);
    let title = op.get("summary").cloned().unwrap_or_else(|| json!(name));
    let description = op.get("description").cloned().unwrap_or_else(|| json!(""));
    let url = format!("{PREFIX}/processes/{name}");
    Ok((
        json!({
            "id": name,
            "title": title,
            "description": description,
            "version": PROCESS_VERSION,
            "jobControlOptions": ["async-execute", "dismiss"],
            "outputTransmission": ["reference"],
            "links": [
                link(url.clone(), "self", "application/json", "The process description"),
                link(format!("{url}/execution"), REL_EXECUTE, "application/json", "Execute the process (POST)"),
            ],
        }),
        op,
    ))
}

/// `$ref`s to `#/…` replaced by what they name (recursively, a reference's sibling keywords
/// kept over the target's), so a schema stands alone outside `openapi.yaml`.
fn resolve(spec: &Value, v: &Value, depth: u32) -> Value {
    if depth > 32 {
        return v.clone();
    }
    match v {
        Value::Object(m) => {
            let mut out = match m.get("$ref").and_then(Value::as_str) {
                Some(r) => match r.strip_prefix('#').and_then(|p| spec.pointer(p)) {
                    Some(Value::Object(target)) => {
                        match resolve(spec, &Value::Object(target.clone()), depth + 1) {
                            Value::Object(t) => t,
                            _ => Map::new(),
                        }
                    }
                    _ => Map::new(),
                },
                None => Map::new(),
            };
            for (k, x) in m {
                if k != "$ref" {
                    out.insert(k.clone(), resolve(spec, x, depth + 1));
                }
            }
            Value::Object(out)
        }
        Value::Array(a) => Value::Array(a.iter().map(|x| resolve(spec, x, depth + 1)).collect()),
        other => other.clone(),
    }
}

/// The schema of a file input given by reference: a binary string of one of the media types
/// `openapi.yaml`'s multipart `encoding` lists for the part.
fn file_schema(op: &Value, part: &str) -> Value {
    let types: Vec<Value> = op
        .pointer(&format!(
            "/requestBody/content/multipart~1form-data/encoding/{part}/contentType"
        ))
        .and_then(Value::as_str)
        .unwrap_or("application/octet-stream")
        .split(',')
        .map(|t| json!({"type": "string", "contentEncoding": "binary", "contentMediaType": t.trim()}))
        .collect();
    json!({ "oneOf": types })
}

/// `GET /ogc/processes/{processId}` (§7.10): the process description; its inputs come from
/// `openapi.yaml` (see the module doc).
pub async fn process(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Value>, ApiError> {
    let name = process_name(&st, &id)?;
    describe(&st, name).map(Json)
}

/// The process description of the pipeline `name`.
pub fn describe(st: &AppState, name: &str) -> Result<Value, ApiError> {
    let spec = SPEC.as_ref().map_err(ApiError::internal)?;
    let (mut desc, op) = summary(name)?;
    let pipelines = st.jobs.pipelines();
    let mut inputs = Map::new();
    let parts = pipelines.input_part(name).into_iter().map(|p| (p, 1));
    let aux = pipelines.aux_parts(name).iter().map(|p| (*p, 0));
    for (part, min) in parts.chain(aux) {
        let text = op
            .pointer(&format!(
                "/requestBody/content/multipart~1form-data/schema/properties/{part}/description"
            ))
            .and_then(Value::as_str)
            .unwrap_or("The input file.");
        inputs.insert(
            part.to_string(),
            json!({
                "title": part,
                "description": format!(
                    "{text} Given by reference to an uploaded asset: \
                     `{{\"href\": \"/v1/assets/<sha256>\"}}` (upload it first with `POST /v1/assets`)."
                ),
                "schema": file_schema(&op, part),
                "minOccurs": min,
                "maxOccurs": 1,
            }),
        );
    }
    let params = op
        .pointer("/requestBody/content/application~1json/schema/properties/params")
        .map(|p| resolve(spec, p, 0))
        .unwrap_or_else(|| json!({}));
    let required: Vec<&str> = params
        .get("required")
        .and_then(Value::as_array)
        .map(|r| r.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    if let Some(props) = params.get("properties").and_then(Value::as_object) {
        for (k, schema) in props {
            let mut schema = schema.clone();
            let description = schema
                .as_object_mut()
                .and_then(|m| m.remove("description"))
                .unwrap_or_else(|| json!(""));
            inputs.insert(
                k.clone(),
                json!({
                    "title": k,
                    "description": description,
                    "schema": schema,
                    "minOccurs": u8::from(required.contains(&k.as_str())),
                    "maxOccurs": 1,
                }),
            );
        }
    }
    let outputs: Map<String, Value> = pipelines
        .outputs(name)
        .iter()
        .map(|o| {
            (
                o.name.to_string(),
                json!({
                    "title": o.title,
                    "schema": {"type": "string", "contentEncoding": "binary", "contentMediaType": o.media_type},
                }),
            )
        })
        .collect();
    if let Some(m) = desc.as_object_mut() {
        m.insert("inputs".into(), Value::Object(inputs));
        m.insert("outputs".into(), Value::Object(outputs));
    }
    Ok(desc)
}

/// The asset a file input names: `{"href": "…/v1/assets/<sha256>"}` (relative, or absolute on
/// any host: only the path is read, and only this server's assets are ever used, so no URL is
/// fetched).
fn asset_ref(name: &str, v: &Value) -> Result<String, ApiError> {
    let field = format!("inputs.{name}");
    let bad = |why: &str| {
        ApiError::bad_field(
            field.clone(),
            format!(
                "{why}; give the file by reference to an uploaded asset: \
                 {{\"href\": \"/v1/assets/<sha256>\"}} (upload it with POST /v1/assets)"
            ),
        )
    };
    let Some(m) = v.as_object() else {
        return Err(bad("not a link object"));
    };
    if let Some(k) = m
        .keys()
        .find(|k| !["href", "rel", "type", "title", "hreflang"].contains(&k.as_str()))
    {
        return Err(bad(&format!(
            "unexpected key {k:?} (inline values are not accepted)"
        )));
    }
    let href = m
        .get("href")
        .and_then(Value::as_str)
        .ok_or_else(|| bad("no `href` string"))?;
    let path = match href.split_once("://") {
        Some((_, rest)) => rest.find('/').map_or("", |i| &rest[i..]),
        None => href,
    };
    let id = path
        .strip_prefix("/v1/assets/")
        .ok_or_else(|| bad(&format!("{href:?} does not name an asset of this server")))?;
    if !crate::store::is_sha256_hex(id) {
        return Err(bad(&format!(
            "{id:?} is not an asset id (64 lowercase hex digits)"
        )));
    }
    Ok(id.to_string())
}

/// Whether `Prefer` asks for `respond-async` (RFC 7240).
fn prefers_async(headers: &HeaderMap) -> bool {
    headers
        .get_all("prefer")
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split([',', ';']))
        .any(|p| p.trim().eq_ignore_ascii_case("respond-async"))
}

/// `POST /ogc/processes/{processId}/execution` (§7.11): `{"inputs": {…}}` with the input file
/// by reference and the parameters as plain values → a job through the one submit path; 201
/// with `Location` at the job's status. Asynchronous whatever `Prefer` says (the processes are
/// `async-execute` only); `Preference-Applied: respond-async` when it asked for that.
pub async fn execute(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    req: Request,
) -> Result<Response, ApiError> {
    let name = process_name(&st, &id)?;
    let wants_async = prefers_async(req.headers());
    let ctype = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    if !ctype.starts_with("application/json") {
        return Err(ApiError::UnsupportedMediaType(format!(
            "send an application/json execute request ({{\"inputs\": {{…}}}}); got {:?}",
            if ctype.is_empty() {
                "no Content-Type"
            } else {
                ctype.as_str()
            }
        )));
    }
    let body = axum::body::to_bytes(req.into_body(), st.cfg.max_body_bytes)
        .await
        .map_err(|_| ApiError::PayloadTooLarge("request body too large".into()))?;
    let v = strict_json::from_slice(&body).map_err(|e| match e {
        StrictJsonError::Syntax(e) => ApiError::bad_request(format!("invalid JSON body: {e}")),
        StrictJsonError::Duplicate(path) => match path.strip_prefix("inputs.") {
            Some(p) => strict_json::duplicate_problem(p.to_string(), true),
            None => strict_json::duplicate_problem(path, false),
        },
    })?;
    let Value::Object(mut body) = v else {
        return Err(ApiError::bad_request(
            "the execute request must be a JSON object",
        ));
    };
    if let Some(r) = body.remove("response") {
        if r != json!("document") {
            return Err(ApiError::bad_field(
                "response",
                "only \"document\" is supported: the results are a document of links",
            ));
        }
    }
    if let Some(k) = body.keys().find(|k| *k != "inputs") {
        let why = match k.as_str() {
            "outputs" => "output selection is not supported: every output is returned by reference",
            "subscriber" => "callbacks are not supported: poll the job's status",
            _ => "unknown member; an execute request has `inputs` (and `response`)",
        };
        return Err(ApiError::bad_field(k.clone(), why));
    }
    let inputs = match body.remove("inputs") {
        Some(Value::Object(m)) => m,
        Some(_) => return Err(ApiError::bad_field("inputs", "inputs must be an object")),
        None => Map::new(),
    };
    let pipelines = st.jobs.pipelines();
    let part = pipelines
        .input_part(name)
        .ok_or_else(|| ApiError::NoSuchProcess(format!("no process {name:?}")))?;
    let aux_parts = pipelines.aux_parts(name);
    let mut params = Map::new();
    let mut input = None;
    let mut aux = Vec::new();
    for (k, v) in inputs {
        if k == part {
            input = Some(Input::Named(asset_ref(&k, &v)?));
        } else if let Some(&a) = aux_parts.iter().find(|a| **a == k) {
            aux.push((a, Input::Named(asset_ref(&k, &v)?)));
        } else {
            params.insert(k, v);
        }
    }
    // 422, not 400: which input is required depends on the process, which a request schema
    // common to every process cannot state.
    let input = input.ok_or_else(|| ApiError::InvalidInput {
        detail: format!("the {part} input is required: {{\"href\": \"/v1/assets/<sha256>\"}}"),
        field: Some(format!("inputs.{part}")),
    })?;
    let rec = submit_inputs(&st, name, Value::Object(params), input, aux).await?;
    let location = format!("{PREFIX}/jobs/{}", rec.id);
    let mut resp = (StatusCode::CREATED, Json(status_info(&rec))).into_response();
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&location) {
        h.insert(header::LOCATION, v);
    }
    if wants_async {
        h.insert(
            "preference-applied",
            HeaderValue::from_static("respond-async"),
        );
    }
    Ok(resp)
}

/// The OGC status of a job status (§7.12, `statusCode`).
fn ogc_status(s: Status) -> &'static str {
    match s {
        Status::Queued => "accepted",
        Status::Running => "running",
        Status::Succeeded => "successful",
        Status::Failed => "failed",
        Status::Canceled => "dismissed",
    }
}

fn ts(t: chrono::DateTime<chrono::Utc>) -> String {
    t.to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

/// A job record as OGC `statusInfo` (§7.12).
pub fn status_info(rec: &JobRecord) -> Value {
    let url = format!("{PREFIX}/jobs/{}", rec.id);
    let mut links = vec![
        link(url.clone(), "self", "application/json", "The job's status"),
        link(
            format!("/v1/jobs/{}", rec.id),
            "alternate",
            "application/json",
            "The job in the service's own API",
        ),
    ];
    if rec.pipeline != "cloud-edit" {
        links.push(link(
            format!("{PREFIX}/processes/{}", rec.pipeline),
            "related",
            "application/json",
            "The process description",
        ));
    }
    if rec.status == Status::Succeeded {
        links.push(link(
            format!("{url}/results"),
            REL_RESULTS,
            "application/json",
            "The results",
        ));
        if super::stac::describes(rec) {
            links.push(link(
                format!("/v1/jobs/{}/stac.json", rec.id),
                "describedby",
                "application/geo+json",
                "The result as a STAC Item",
            ));
        }
    }
    let message = match (&rec.error, &rec.stage) {
        (Some(e), _) => Some(e.detail.clone()),
        (None, Some(s)) => Some(s.clone()),
        (None, None) => None,
    };
    let updated = rec.finished_at.or(rec.started_at).unwrap_or(rec.created_at);
    let mut v = json!({
        "processID": rec.pipeline,
        "type": "process",
        "jobID": rec.id,
        "status": ogc_status(rec.status),
        "created": ts(rec.created_at),
        "updated": ts(updated),
        "progress": (rec.progress.clamp(0.0, 1.0) * 100.0).round() as u8,
        "links": links,
    });
    if let Some(m) = v.as_object_mut() {
        if let Some(msg) = message {
            m.insert("message".into(), json!(msg));
        }
        if let Some(t) = rec.started_at {
            m.insert("started".into(), json!(ts(t)));
        }
        if let Some(t) = rec.finished_at {
            m.insert("finished".into(), json!(ts(t)));
        }
    }
    v
}

async fn find(st: &AppState, id: &str) -> Result<JobRecord, ApiError> {
    let found = if is_job_id(id) {
        st.jobs.get(id).await?
    } else {
        None
    };
    found.ok_or_else(|| ApiError::NoSuchJob(format!("no job {id}")))
}

/// `GET /ogc/jobs/{id}` (§7.12).
pub async fn job(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Value>, ApiError> {
    Ok(Json(status_info(&find(&st, &id).await?)))
}

/// `GET /ogc/jobs`: recent jobs as `statusInfo`, newest first (the landing page's `job-list`
/// link; the `job-list` class's filters are not implemented). Paged as `GET /v1/jobs`.
pub async fn jobs(
    State(st): State<AppState>,
    q: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<Value>, ApiError> {
    let (limit, cursor) = ListQuery::page(q)?;
    let (jobs, next) = st.jobs.list(limit, cursor.as_deref()).await?;
    let mut links = vec![link(
        format!("{PREFIX}/jobs?limit={limit}"),
        "self",
        "application/json",
        "This page",
    )];
    if let Some(c) = next {
        links.push(link(
            format!("{PREFIX}/jobs?limit={limit}&cursor={c}"),
            "next",
            "application/json",
            "The next page",
        ));
    }
    Ok(Json(json!({
        "jobs": jobs.iter().map(status_info).collect::<Vec<_>>(),
        "links": links,
    })))
}

/// `GET /ogc/jobs/{id}/results` (§7.13): a document of links to the outputs once the job is
/// `successful`; `result-not-ready` (404) before; the job's own problem when it failed
/// (`/req/core/job-results-failed`), with 422 for a failure the request caused and 500 else.
pub async fn results(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Value>, ApiError> {
    let rec = find(&st, &id).await?;
    match rec.status {
        Status::Succeeded => {}
        Status::Queued | Status::Running => {
            return Err(ApiError::ResultNotReady(format!(
                "job {id} is {}; its results appear when it is successful",
                ogc_status(rec.status)
            )))
        }
        Status::Canceled => {
            return Err(ApiError::ResultNotReady(format!(
                "job {id} was dismissed; it has no results"
            )))
        }
        Status::Failed => {
            let error = rec
                .error
                .unwrap_or_else(|| crate::jobs::JobError::new(Problem::Internal, "the job failed"));
            let status = match Problem::from_type_uri(&error.kind) {
                Some(
                    Problem::InvalidInput
                    | Problem::InvalidParameter
                    | Problem::Unprocessable
                    | Problem::StrokeMissesCloud
                    | Problem::StrokeNotLit,
                ) => StatusCode::UNPROCESSABLE_ENTITY,
                _ => StatusCode::INTERNAL_SERVER_ERROR,
            };
            return Err(ApiError::JobFailed { status, error });
        }
    }
    let doc: Map<String, Value> = rec
        .outputs
        .iter()
        .map(|o| {
            (
                o.name.clone(),
                json!({
                    "href": format!("/v1/jobs/{}/outputs/{}", rec.id, o.name),
                    "type": o.media_type,
                }),
            )
        })
        .collect();
    Ok(Json(Value::Object(doc)))
}

/// `DELETE /ogc/jobs/{id}` (`dismiss`, §13): cancels a queued or running job (the job
/// system's cancellation: a queued job at once, a running one at its next checkpoint) and
/// answers its status; a finished job cannot be dismissed (409: its results are
/// content-addressed and shared with identical requests, so they are not deleted).
pub async fn dismiss(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Value>, ApiError> {
    find(&st, &id).await?;
    match st.jobs.cancel(&id).await {
        Ok(rec) => Ok(Json(status_info(&rec))),
        Err(CancelError::NotFound(_)) => Err(ApiError::NoSuchJob(format!("no job {id}"))),
        Err(e @ CancelError::Finished { .. }) => Err(ApiError::Conflict(e.to_string())),
        Err(CancelError::Backend(e)) => Err(e.into()),
    }
}
