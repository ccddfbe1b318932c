//! `POST /v1/{pipeline}`: validate, store the input as an asset, reuse an identical request's
//! result, or queue a new job.
//!
//! Two body forms:
//! - `multipart/form-data` with a `params` part (JSON; optional, `{}` when absent) and the input
//!   part named for the pipeline (`dem`, `mesh`, `volume`), whose file name guides format detection;
//! - `application/json`: `{"asset": "<sha256>", "params": {…}}` naming an uploaded asset.
//!
//! A pipeline may take auxiliary files besides its input (snow-terrain's orthophoto `ortho`):
//! a multipart part of that name, or `"{name}_asset": "<sha256>"` in the JSON form. They are
//! stored as assets too, checked with the input before the job is queued (a 4xx naming the
//! part), and part of the request key.

use axum::extract::{FromRequest, Multipart, Request, State};
use axum::http::header;
use axum::response::Response;
use serde::Deserialize;
use sha2::{Digest, Sha256};

use super::admission;
use super::jobs::{job_response, prefer_wait};
use super::strict_json::{self, StrictJsonError};
use super::AppState;
use crate::error::ApiError;
use crate::jobs::{InputRef, SubmitError, Submitted};
use crate::pipeline_set::{Admitted, Validated};
use phenomena_engine::{InputError, ParamError};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonSubmit {
    asset: String,
    #[serde(default = "empty_object")]
    params: serde_json::Value,
    /// snow-terrain's orthophoto, an uploaded asset.
    #[serde(default)]
    ortho_asset: Option<String>,
}

fn empty_object() -> serde_json::Value {
    serde_json::Value::Object(Default::default())
}

/// The input as received: new bytes to store, an upload already streamed to the store, or the
/// id of an uploaded asset.
pub enum Input {
    /// Bytes held in memory (only [`parse_submission`] without a store, for the fuzz target).
    Upload {
        bytes: bytes::Bytes,
        filename: Option<String>,
    },
    /// A multipart part streamed to the store and recorded as an asset while it arrived.
    Stored(crate::store::assets::AssetRecord),
    Named(String),
}

/// The request key: identical pipeline, input bytes and resolved params give the same key.
pub(crate) fn request_key(pipeline: &str, asset: &str, params: &serde_json::Value) -> String {
    let mut h = Sha256::new();
    h.update(pipeline.as_bytes());
    h.update(b"\n");
    h.update(asset.as_bytes());
    h.update(b"\n");
    // serde_json's default map is a BTreeMap, so this serialisation has sorted keys: canonical.
    h.update(params.to_string().as_bytes());
    hex::encode(h.finalize())
}

pub(super) fn blocking_err(e: tokio::task::JoinError) -> ApiError {
    ApiError::internal(e)
}

pub async fn submit(
    pipeline: &'static str,
    State(st): State<AppState>,
    req: Request,
) -> Result<Response, ApiError> {
    if !st.jobs.accepting() {
        return Err(ApiError::Unavailable("the service is shutting down".into()));
    }
    let part = st
        .jobs
        .pipelines()
        .input_part(pipeline)
        .ok_or_else(|| ApiError::NotFound(format!("no pipeline {pipeline}")))?;
    let wait = prefer_wait(req.headers(), st.cfg.max_wait_secs);
    let aux_parts = st.jobs.pipelines().aux_parts(pipeline);
    let (raw_params, input, aux_inputs) = read_streamed(&st, req, part, aux_parts).await?;
    let rec = submit_inputs(&st, pipeline, raw_params, input, aux_inputs).await?;
    respond(&st, rec, wait).await
}

/// The submit path after the body is read: validates the parameters, stores the input (and
/// the auxiliary inputs), answers an identical request with its job, admits the input (queue
/// room, decode within the memory budget) and queues the job. `POST /v1/{pipeline}` and the
/// OGC API – Processes execution (`api::ogc`) both come here.
pub(super) async fn submit_inputs(
    st: &AppState,
    pipeline: &'static str,
    raw_params: serde_json::Value,
    input: Input,
    aux_inputs: Vec<(&'static str, Input)>,
) -> Result<crate::jobs::JobRecord, ApiError> {
    if !st.jobs.accepting() {
        return Err(ApiError::Unavailable("the service is shutting down".into()));
    }
    let part = st
        .jobs
        .pipelines()
        .input_part(pipeline)
        .ok_or_else(|| ApiError::NotFound(format!("no pipeline {pipeline}")))?;
    reject_nulls(&raw_params, "")?;
    let pipelines = st.jobs.pipelines().clone();
    let params = pipelines.params(pipeline, &raw_params)?;
    if !aux_inputs.is_empty() {
        return submit_with_named_inputs(st, pipeline, part, input, aux_inputs, params).await;
    }

    // A JSON body names its asset: an identical request already queued, running or done is
    // answered before any file I/O or thread hop (the cached-submit hot path).
    if let Input::Named(id) = &input {
        if let Some(rec) = st
            .jobs
            .find_by_key(&request_key(pipeline, id, params.canonical()))
            .await?
        {
            return Ok(rec);
        }
    }

    let asset = store_input(st, input).await?;
    let key = request_key(pipeline, &asset.id, params.canonical());

    // An identical request already queued, running or done: no decode, no new job.
    if let Some(rec) = st.jobs.find_by_key(&key).await? {
        return Ok(rec);
    }

    // Admission before work: a full queue is refused before the input is decoded.
    admission::ensure_queue_room(st).await?;
    // Reject corrupt, unsupported or oversize inputs now, with a 4xx, rather than as a failed
    // job; the decode runs within the memory budget, and a job too large for it is a 413.
    let admitted = admit_input(st, pipeline, &params, &asset, &[], part).await?;
    admission::ensure_fits(&st.memory, admitted.run_bytes)?;
    touch_asset(st, &asset).await?;

    let input = InputRef {
        asset: asset.id,
        filename: asset.filename,
        aux: Vec::new(),
        memory: admitted.run_bytes,
    };
    queue_job(st, pipeline, input, params.into_canonical(), key).await
}

/// [`submit_inputs`] with auxiliary inputs: each is stored as an asset, the request key covers
/// them, and the input is decoded with them (a 4xx naming the part at fault) before the job is
/// queued.
async fn submit_with_named_inputs(
    st: &AppState,
    pipeline: &'static str,
    part: &'static str,
    input: Input,
    aux_inputs: Vec<(&'static str, Input)>,
    params: Validated,
) -> Result<crate::jobs::JobRecord, ApiError> {
    let asset = store_input(st, input).await?;
    let mut key_input = asset.id.clone();
    let mut aux_assets = Vec::with_capacity(aux_inputs.len());
    for (name, inp) in aux_inputs {
        let rec = store_input(st, inp)
            .await
            .map_err(|e| rename_asset_field(e, name))?;
        key_input.push_str(&format!("+{name}:{}", rec.id));
        aux_assets.push((name, rec));
    }
    let key = request_key(pipeline, &key_input, params.canonical());
    if let Some(rec) = st.jobs.find_by_key(&key).await? {
        return Ok(rec);
    }
    admission::ensure_queue_room(st).await?;
    let admitted = admit_input(st, pipeline, &params, &asset, &aux_assets, part).await?;
    admission::ensure_fits(&st.memory, admitted.run_bytes)?;
    touch_asset(st, &asset).await?;
    let mut aux = Vec::with_capacity(aux_assets.len());
    for (name, rec) in aux_assets {
        touch_asset(st, &rec).await?;
        aux.push(crate::jobs::AuxInput {
            name: name.to_string(),
            blob: rec.id,
        });
    }
    let input = InputRef {
        asset: asset.id,
        filename: asset.filename,
        aux,
        memory: admitted.run_bytes,
    };
    queue_job(st, pipeline, input, params.into_canonical(), key).await
}

/// An unknown asset named for an auxiliary part is named by that part's field (`ortho_asset`).
fn rename_asset_field(e: ApiError, name: &str) -> ApiError {
    match e {
        ApiError::NotFound(detail) => ApiError::NotFound(detail.replacen(
            "asset: no asset",
            &format!("{name}_asset: no asset"),
            1,
        )),
        other => other,
    }
}

/// Queues a job (or joins an identical one), mapping a full queue to 429.
pub(super) async fn queue_job(
    st: &AppState,
    pipeline: &str,
    input: InputRef,
    params: serde_json::Value,
    key: String,
) -> Result<crate::jobs::JobRecord, ApiError> {
    match st.jobs.submit(pipeline, input, params, key).await {
        Ok(Submitted::Queued(rec) | Submitted::Reused(rec)) => Ok(rec),
        Err(SubmitError::QueueFull { capacity }) => Err(ApiError::QueueFull {
            detail: format!("the queue is full ({capacity} jobs waiting); retry later"),
            retry_after: 5,
        }),
        Err(SubmitError::ShuttingDown) => {
            Err(ApiError::Unavailable("the service is shutting down".into()))
        }
        Err(SubmitError::Backend(e)) => Err(e.into()),
    }
}

/// Reads a submission body: multipart (a `params` part and the `part` file part, streamed to
/// the store) or JSON naming an uploaded asset.
pub(super) async fn read_body(
    st: &AppState,
    req: Request,
    part: &'static str,
) -> Result<(serde_json::Value, Input), ApiError> {
    read_streamed(st, req, part, &[])
        .await
        .map(|(p, i, _)| (p, i))
}

/// [`parse_submission_aux`] with the file parts streamed to the store as they arrive (as
/// `POST /v1/assets` does): a request never holds an upload whole.
#[allow(clippy::type_complexity)]
async fn read_streamed(
    st: &AppState,
    req: Request,
    part: &'static str,
    aux: &'static [&'static str],
) -> Result<(serde_json::Value, Input, Vec<(&'static str, Input)>), ApiError> {
    parse_body(req, part, aux, st.cfg.max_body_bytes, Some(st.jobs.store())).await
}

/// Parses a job submission: a multipart body (`params` JSON part, the `part` file part) or a
/// JSON body naming an asset, read up to `max_body` bytes. Public for the `multipart` fuzz
/// target (`fuzz/`); the server calls it through `read_body`.
pub async fn parse_submission(
    req: Request,
    part: &'static str,
    max_body: usize,
) -> Result<(serde_json::Value, Input), ApiError> {
    parse_submission_aux(req, part, &[], max_body)
        .await
        .map(|(p, i, _)| (p, i))
}

/// [`parse_submission`] that also accepts the auxiliary file parts `aux` (multipart parts of
/// those names, or `"{name}_asset"` in a JSON body) and returns them.
#[allow(clippy::type_complexity)]
pub async fn parse_submission_aux(
    req: Request,
    part: &'static str,
    aux: &'static [&'static str],
    max_body: usize,
) -> Result<(serde_json::Value, Input, Vec<(&'static str, Input)>), ApiError> {
    parse_body(req, part, aux, max_body, None).await
}

/// [`parse_submission_aux`]; with a `sink`, file parts stream into it ([`Input::Stored`]),
/// else they are read into memory ([`Input::Upload`]).
#[allow(clippy::type_complexity)]
async fn parse_body(
    req: Request,
    part: &'static str,
    aux: &'static [&'static str],
    max_body: usize,
    sink: Option<&crate::store::Store>,
) -> Result<(serde_json::Value, Input, Vec<(&'static str, Input)>), ApiError> {
    let ctype = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    if ctype.starts_with("multipart/form-data") {
        read_multipart(req, part, aux, sink.map(|st| (st, max_body as u64))).await
    } else if ctype.starts_with("application/json") {
        read_json(req, aux, max_body).await
    } else {
        Err(ApiError::UnsupportedMediaType(format!(
            "send multipart/form-data (a `params` part and a `{part}` file part) or application/json \
             naming an uploaded asset; got {:?}",
            if ctype.is_empty() { "no Content-Type" } else { ctype.as_str() }
        )))
    }
}

/// The asset of an input: an upload stored as one (content-addressed, so a retry or a later job
/// can name it), or a named asset looked up.
pub(super) async fn store_input(
    st: &AppState,
    input: Input,
) -> Result<crate::store::assets::AssetRecord, ApiError> {
    let store = st.jobs.store();
    Ok(match input {
        Input::Upload { bytes, filename } => store.put_asset(bytes, filename.as_deref()).await?.0,
        Input::Stored(rec) => rec,
        // A well-formed id naming no asset: 404, like `GET /v1/assets/{id}` (the request is
        // well-formed; the resource it names is missing).
        Input::Named(id) => match store.get_asset(&id).await {
            Some(rec) => rec,
            None => {
                return Err(ApiError::NotFound(format!(
                    "asset: no asset {id:?}; upload it with POST /v1/assets"
                )))
            }
        },
    })
}

/// Decodes the stored input (with its auxiliary inputs `aux`) on the blocking pool within the
/// memory budget (see `admission`), mapping a corrupt, unsupported or oversize file to its 4xx
/// (named after the input `part`, or the auxiliary part at fault), and describes it with the
/// job's estimated peak memory (see `PipelineSet::admit`). The bytes are read from the store
/// only once the memory is reserved.
pub(super) async fn admit_input(
    st: &AppState,
    pipeline: &'static str,
    params: &Validated,
    asset: &crate::store::assets::AssetRecord,
    aux: &[(&'static str, crate::store::assets::AssetRecord)],
    part: &'static str,
) -> Result<Admitted, ApiError> {
    let pipelines = st.jobs.pipelines().clone();
    // The auxiliary bytes are held twice (as read and as the owned copy the decode takes).
    let input_bytes = aux.iter().fold(asset.size, |n, (_, r)| {
        n.saturating_add(r.size.saturating_mul(2))
    });
    let worst = input_bytes.saturating_add(pipelines.decode_cost(pipeline, !aux.is_empty()));
    let mut first = admission::check_memory(&st.memory, worst, input_bytes);
    loop {
        let (reservation, decode_bytes) = match first.take() {
            Some(r) => r,
            None => (admission::reserve_worst(&st.memory, worst).await?, None),
        };
        let bytes = st.jobs.store().read_blob(&asset.id).await?;
        let mut aux_bytes = Vec::with_capacity(aux.len());
        for (name, rec) in aux {
            let b = st.jobs.store().read_blob(&rec.id).await?;
            aux_bytes.push((name.to_string(), b.to_vec()));
        }
        let p = params.clone();
        let filename = asset.filename.clone();
        let pipelines = pipelines.clone();
        // The reservation moves into the decode: it ends when the decode does, even if the
        // client goes away and this request is dropped meanwhile.
        let result = tokio::task::spawn_blocking(move || {
            let _reservation = reservation;
            pipelines.admit(
                pipeline,
                &p,
                &bytes,
                filename.as_deref(),
                &aux_bytes,
                decode_bytes,
            )
        })
        .await
        .map_err(blocking_err)?;
        match result {
            Ok(admitted) => return Ok(admitted),
            // Larger than what was free: refused from its header, nothing allocated; now wait
            // for the worst case and decode with the configured limits.
            Err((_, InputError::TooLarge { .. })) if decode_bytes.is_some() => continue,
            Err((which, e)) => return Err(ApiError::from_input(e, which.unwrap_or(part))),
        }
    }
}

/// Refreshes the asset's retention clock.
pub(super) async fn touch_asset(
    st: &AppState,
    asset: &crate::store::assets::AssetRecord,
) -> Result<(), ApiError> {
    st.jobs.store().touch_asset(asset).await?;
    Ok(())
}

pub(super) async fn respond(
    st: &AppState,
    rec: crate::jobs::JobRecord,
    wait: Option<std::time::Duration>,
) -> Result<Response, ApiError> {
    let rec = match wait {
        Some(w) if !rec.status.is_terminal() => st.jobs.wait(&rec.id, w).await.unwrap_or(rec),
        _ => rec,
    };
    Ok(job_response(rec, wait))
}

fn multipart_err(e: axum::extract::multipart::MultipartError) -> ApiError {
    if e.status() == axum::http::StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::PayloadTooLarge(format!("request body too large: {}", e.body_text()))
    } else {
        ApiError::bad_request(format!("malformed multipart body: {}", e.body_text()))
    }
}

/// A file part: streamed into the store and recorded as an asset when there is a `sink` (store,
/// most bytes), else read into memory. An empty part is a 400 naming it.
async fn file_part(
    field: axum::extract::multipart::Field<'_>,
    name: &'static str,
    sink: Option<(&crate::store::Store, u64)>,
) -> Result<Input, ApiError> {
    use axum::http::StatusCode;
    use futures_util::StreamExt;
    let filename = field.file_name().map(sanitize_filename);
    let empty = || ApiError::bad_field(name, format!("the {name} part is empty"));
    let Some((store, max)) = sink else {
        let bytes = field.bytes().await.map_err(multipart_err)?;
        if bytes.is_empty() {
            return Err(empty());
        }
        return Ok(Input::Upload { bytes, filename });
    };
    let chunks = field.map(|r| {
        r.map_err(|e| {
            if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
                crate::store::StoreError::TooLarge { max }
            } else {
                crate::store::StoreError::Upload(e.body_text())
            }
        })
    });
    let (sha, size) = store.put_blob_stream(chunks, max).await?;
    if size == 0 {
        return Err(empty());
    }
    let (rec, _) = store.record_asset(&sha, size, filename.as_deref()).await?;
    Ok(Input::Stored(rec))
}

#[allow(clippy::type_complexity)]
async fn read_multipart(
    req: Request,
    part: &'static str,
    aux: &'static [&'static str],
    sink: Option<(&crate::store::Store, u64)>,
) -> Result<(serde_json::Value, Input, Vec<(&'static str, Input)>), ApiError> {
    let mut mp = Multipart::from_request(req, &()).await.map_err(|e| {
        ApiError::bad_request(format!("malformed multipart body: {}", e.body_text()))
    })?;
    let mut params = None;
    let mut input = None;
    let mut aux_inputs: Vec<(&'static str, Input)> = Vec::new();
    while let Some(field) = mp.next_field().await.map_err(multipart_err)? {
        let name = field.name().unwrap_or("").to_string();
        if name == "params" {
            let text = field.bytes().await.map_err(multipart_err)?;
            // An empty params field (a form left blank) means no params, as when it is absent.
            if text.trim_ascii().is_empty() {
                continue;
            }
            let v = strict_json::from_slice(&text).map_err(|e| match e {
                StrictJsonError::Syntax(e) => {
                    ApiError::bad_field("params", format!("the params part is not valid JSON: {e}"))
                }
                StrictJsonError::Duplicate(path) => strict_json::duplicate_problem(path, true),
            })?;
            if !v.is_object() {
                return Err(ApiError::bad_field(
                    "params",
                    "params must be a JSON object",
                ));
            }
            params = Some(v);
        } else if name == part {
            if input.is_some() {
                return Err(ApiError::bad_field(
                    part,
                    format!("the {part} part is given twice"),
                ));
            }
            input = Some(file_part(field, part, sink).await?);
        } else if let Some(&a) = aux.iter().find(|a| **a == name) {
            if aux_inputs.iter().any(|(n, _)| *n == a) {
                return Err(ApiError::bad_field(
                    a,
                    format!("the {a} part is given twice"),
                ));
            }
            aux_inputs.push((a, file_part(field, a, sink).await?));
        } else {
            let extra: String = aux.iter().map(|a| format!(", `{a}`")).collect();
            return Err(ApiError::bad_field(
                name.clone(),
                format!("unexpected part {name:?}; expected `params`, `{part}`{extra}"),
            ));
        }
    }
    let input = input
        .ok_or_else(|| ApiError::bad_field(part, format!("missing the `{part}` file part")))?;
    Ok((params.unwrap_or_else(empty_object), input, aux_inputs))
}

#[allow(clippy::type_complexity)]
async fn read_json(
    req: Request,
    aux: &'static [&'static str],
    max_body: usize,
) -> Result<(serde_json::Value, Input, Vec<(&'static str, Input)>), ApiError> {
    let body = axum::body::to_bytes(req.into_body(), max_body)
        .await
        .map_err(|_| ApiError::PayloadTooLarge("request body too large".into()))?;
    let v = strict_json::from_slice(&body).map_err(|e| match e {
        StrictJsonError::Syntax(e) => ApiError::bad_request(format!("invalid JSON body: {e}")),
        StrictJsonError::Duplicate(path) => match path.strip_prefix("params.") {
            Some(p) => strict_json::duplicate_problem(p.to_string(), true),
            None => strict_json::duplicate_problem(path, false),
        },
    })?;
    let j: JsonSubmit = serde_json::from_value(v)
        .map_err(|e| ApiError::bad_request(format!("invalid JSON body: {e}")))?;
    if !j.params.is_object() {
        return Err(ApiError::bad_field(
            "params",
            "params must be a JSON object",
        ));
    }
    if !crate::store::is_sha256_hex(&j.asset) {
        return Err(ApiError::InvalidInput {
            detail: format!("{:?} is not an asset id (64 lowercase hex digits)", j.asset),
            field: Some("asset".into()),
        });
    }
    let mut aux_inputs = Vec::new();
    if let Some(o) = j.ortho_asset {
        let Some(&name) = aux.iter().find(|a| **a == "ortho") else {
            return Err(ApiError::bad_field(
                "ortho_asset",
                "this pipeline takes no orthophoto",
            ));
        };
        if !crate::store::is_sha256_hex(&o) {
            return Err(ApiError::InvalidInput {
                detail: format!("{o:?} is not an asset id (64 lowercase hex digits)"),
                field: Some("ortho_asset".into()),
            });
        }
        aux_inputs.push((name, Input::Named(o)));
    }
    Ok((j.params, Input::Named(j.asset), aux_inputs))
}

/// Keeps only the last path component of a client-supplied file name (no traversal, no control
/// characters), at most 255 bytes.
pub(crate) fn sanitize_filename(name: &str) -> String {
    let base = name.rsplit(['/', '\\']).next().unwrap_or("");
    base.chars()
        .filter(|c| !c.is_control() && *c != '"')
        .take(255)
        .collect()
}

/// Fields where `null` is a value of its own ("none"), as `openapi.yaml` declares them: the cloud
/// state's transparent background and the decoder options "from the file".
const NULLABLE: &[&str] = &["background", "bounds", "dims", "kappa"];

/// Refuses `null` anywhere in request parameters except the [`NULLABLE`] fields: the schema
/// does not allow it, and "null means the default" would make two spellings of one request.
pub(crate) fn reject_nulls(v: &serde_json::Value, path: &str) -> Result<(), ApiError> {
    use serde_json::Value;
    let field = |k: &str| {
        if path.is_empty() {
            k.to_string()
        } else {
            format!("{path}.{k}")
        }
    };
    match v {
        Value::Object(m) => m.iter().try_for_each(|(k, x)| {
            if x.is_null() && !NULLABLE.contains(&k.as_str()) {
                Err(ParamError::new(
                    field(k),
                    "null is not a value here; leave the field out for its default",
                )
                .into())
            } else {
                reject_nulls(x, &field(k))
            }
        }),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .try_for_each(|(i, x)| reject_nulls(x, &field(&i.to_string()))),
        _ => Ok(()),
    }
}
