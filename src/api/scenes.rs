//! `/v1/clouds`: cloud scenes (SPEC §3 "Editing"). Upload a volume once, then render any version
//! from any camera and edit it with the three modes of the paper; every edit is a new version.
//!
//! The handlers only shuffle JSON: a scene version's state, the scene's decoder options (`bounds`,
//! `dims`) and the request's view (`width`, `height`, `camera`, `layers`, `seed`) are merged into the
//! parameters of a `cloud` render job or a `cloud-edit` job, which the engine validates and runs.

use std::time::Duration;

use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use serde_json::{Map, Value};

use super::extract::ApiPath;
use super::jobs::prefer_wait;
use super::strict_json::{self, StrictJsonError};
use super::submit::{
    admit_input, queue_job, read_body, reject_nulls, request_key, respond, store_input, touch_asset,
};
use super::AppState;
use crate::error::ApiError;
use crate::jobs::{AuxInput, InputRef};
use crate::scenes::{is_scene_id, SceneRecord, VersionRecord, VersionStatus};
use phenomena_engine::ParamError;

/// The one-shot pipeline that renders a scene version, and the internal one that applies edits.
const RENDER: &str = "cloud";
const EDIT: &str = "cloud-edit";
/// Parameters that describe a view, given per render or edit, never stored in a version.
const VIEW_KEYS: &[&str] = &["width", "height", "camera", "layers", "seed"];
/// Parameters that tell the decoder how to read the volume, fixed at upload.
const INPUT_KEYS: &[&str] = &["bounds", "dims"];
/// The render layer a scene render always adds, and its output: the linear layers a later
/// sun-colour edit at that view reads (`phenomena_engine::cloud::layers`).
const LINEAR: &str = "linear";
const LAYERS_BIN: &str = phenomena_engine::registry::LAYERS;
/// How long an edit on a still-pending base version waits for it before answering 409 (at most
/// the server's `max_wait_secs`).
const BASE_WAIT: Duration = Duration::from_secs(30);

/// A version as the API shows it.
#[derive(Debug, Serialize)]
pub struct VersionView {
    #[serde(flatten)]
    pub record: VersionRecord,
    /// The job that computed the version (edits only), and its render once ready.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub job_url: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub render_url: Option<String>,
}

impl From<VersionRecord> for VersionView {
    fn from(v: VersionRecord) -> Self {
        let job_url = v.job.as_ref().map(|j| format!("/v1/jobs/{j}"));
        let render_url = job_url
            .as_ref()
            .filter(|_| v.status == VersionStatus::Ready)
            .map(|u| format!("{u}/outputs/render.png"));
        Self {
            record: v,
            job_url,
            render_url,
        }
    }
}

/// A scene as the API shows it.
#[derive(Debug, Serialize)]
pub struct SceneView {
    pub id: String,
    pub url: String,
    pub created_at: String,
    pub volume: InputRef,
    pub input: Map<String, Value>,
    pub info: Value,
    /// The newest ready version.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub latest_version: Option<u32>,
    pub versions: Vec<VersionView>,
}

impl From<SceneRecord> for SceneView {
    fn from(s: SceneRecord) -> Self {
        SceneView {
            url: format!("/v1/clouds/{}", s.id),
            created_at: s
                .created_at
                .to_rfc3339_opts(chrono::SecondsFormat::Millis, true),
            latest_version: s.latest_ready().map(|v| v.version),
            id: s.id,
            volume: s.volume,
            input: s.input,
            info: s.info,
            versions: s.versions.into_iter().map(VersionView::from).collect(),
        }
    }
}

fn object(v: &Value, field: &str) -> Result<Map<String, Value>, ApiError> {
    v.as_object()
        .cloned()
        .ok_or_else(|| ApiError::bad_field(field, format!("{field} must be a JSON object")))
}

/// `POST /v1/clouds`: upload a volume (or name an asset) with optional initial state and decoder
/// options; answers 201 with the scene and its version 1.
pub async fn create(State(st): State<AppState>, req: Request) -> Result<Response, ApiError> {
    if !st.jobs.accepting() {
        return Err(ApiError::Unavailable("the service is shutting down".into()));
    }
    let (raw, input) = read_body(&st, req, "volume").await?;
    reject_nulls(&raw, "")?;
    let raw = object(&raw, "params")?;
    if let Some(k) = VIEW_KEYS.iter().find(|k| raw.contains_key(**k)) {
        return Err(ParamError::new(
            *k,
            "is a view parameter: give it per render (POST /v1/clouds/{id}/renders) or edit",
        )
        .into());
    }
    let pipelines = st.jobs.pipelines().clone();
    let validated = pipelines.params(RENDER, &Value::Object(raw))?;
    let canonical = object(validated.canonical(), "params")?;
    let asset = store_input(&st, input).await?;
    let info = admit_input(&st, RENDER, &validated, &asset, &[], "volume")
        .await?
        .info;
    touch_asset(&st, &asset).await?;
    let mut state = Map::new();
    let mut input_opts = Map::new();
    for (k, v) in canonical {
        if INPUT_KEYS.contains(&k.as_str()) {
            if !v.is_null() {
                input_opts.insert(k, v);
            }
        } else if !VIEW_KEYS.contains(&k.as_str()) {
            state.insert(k, v);
        }
    }
    // The density floor left open: the one the decoder chose and took out
    // ([`phenomena_engine::cloud::floor`]), stated with its rule, so that every version renders
    // the same volume (and a version's `layers.bin` identity, which holds the floor, matches
    // its edits' base).
    if state.get("density_floor").is_none_or(Value::is_null) {
        if let Some(f) = info.get("density_floor").filter(|f| f.is_number()) {
            state.insert("density_floor".into(), f.clone());
            if let Some(c) = info.get("density_floor_auto") {
                state.insert("density_floor_auto".into(), c.clone());
            }
        }
    }
    // The sun left open: the one chosen from the volume's shape ([`describe_input`]), stated
    // with its rule, so every version of the scene renders with it.
    if state.get("sun_direction").is_none_or(Value::is_null) {
        if let Some(d) = info.get("sun_direction").filter(|d| d.is_array()) {
            state.insert("sun_direction".into(), d.clone());
            if let Some(c) = info.get("sun_auto") {
                state.insert("sun_auto".into(), c.clone());
            }
        }
    }
    // κ left open: the one the decoder chose from the volume ([`describe_input`]), stated with
    // its rule, so every version of the scene renders with it.
    if state.get("kappa").is_none_or(Value::is_null) {
        if let Some(k) = info.get("kappa").filter(|k| k.is_number()) {
            state.insert("kappa".into(), k.clone());
            if let Some(c) = info.get("kappa_auto") {
                state.insert("kappa_auto".into(), c.clone());
            }
        }
    }
    // The scene's volume; each render's and edit's job gets its own memory estimate
    // ([`version_input`]).
    let volume = InputRef {
        asset: asset.id,
        filename: asset.filename,
        aux: Vec::new(),
        memory: 0,
    };
    let scene = st
        .scenes
        .create(volume, input_opts, info, Value::Object(state))
        .await?;
    let view = SceneView::from(scene);
    let mut resp = (StatusCode::CREATED, Json(&view)).into_response();
    if let Ok(v) = HeaderValue::from_str(&view.url) {
        resp.headers_mut().insert(header::LOCATION, v);
    }
    Ok(resp)
}

/// The scene with every version whose job has ended settled (ready or failed).
async fn settled(st: &AppState, id: &str) -> Result<SceneRecord, ApiError> {
    if !is_scene_id(id) || st.scenes.get(id).await?.is_none() {
        return Err(ApiError::NotFound(format!("no cloud scene {id}")));
    }
    for job in st.scenes.pending_jobs(Some(id)).await? {
        if let Some(rec) = st.jobs.get(&job).await? {
            if rec.status.is_terminal() {
                st.scenes.resolve(&rec).await?;
            }
        }
    }
    st.scenes
        .get(id)
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("no cloud scene {id}")))
}

/// `GET /v1/clouds/{id}`.
pub async fn get(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<SceneView>, ApiError> {
    Ok(Json(SceneView::from(settled(&st, &id).await?)))
}

/// `DELETE /v1/clouds/{id}`: forgets the scene; its blobs go at the next retention sweep.
pub async fn delete(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<StatusCode, ApiError> {
    if !is_scene_id(&id) {
        return Err(ApiError::NotFound(format!("no cloud scene {id}")));
    }
    st.scenes.delete(&id).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Parses the optional `field` (a version number) out of a request body.
fn take_version(body: &mut Map<String, Value>, field: &str) -> Result<Option<u32>, ApiError> {
    match body.remove(field) {
        None | Some(Value::Null) => Ok(None),
        // JSON Schema counts 2.0 as an integer, so an integral float is a version number too.
        Some(v) => v
            .as_u64()
            .or_else(|| {
                v.as_f64()
                    .filter(|f| f.fract() == 0.0 && (1.0..=f64::from(u32::MAX)).contains(f))
                    .map(|f| f as u64)
            })
            .and_then(|n| u32::try_from(n).ok())
            .filter(|n| *n >= 1)
            .map(Some)
            .ok_or_else(|| ParamError::new(field, "must be a version number (1, 2, …)").into()),
    }
}

/// The version to use: `n`, or the newest one that has not failed; a pending version is waited
/// for (up to [`BASE_WAIT`], at most `max_wait_secs`) and a failed one refused.
async fn ready_version(
    st: &AppState,
    id: &str,
    n: Option<u32>,
    field: &str,
) -> Result<(SceneRecord, VersionRecord), ApiError> {
    let scene = settled(st, id).await?;
    let pick = |s: &SceneRecord| match n {
        Some(n) => s.version(n).cloned(),
        None => s.latest().cloned(),
    };
    // A version number naming no version is a missing resource (404, like an unknown scene);
    // a scene with no version left to start from is a parameter problem (422).
    let mut v = pick(&scene).ok_or_else(|| match n {
        Some(n) => ApiError::NotFound(format!("{field}: scene {id} has no version {n}")),
        None => ApiError::InvalidParameter(ParamError::new(
            field,
            format!("scene {id} has no ready version"),
        )),
    })?;
    let mut scene = scene;
    if v.status == VersionStatus::Pending {
        if let Some(job) = &v.job {
            let wait = BASE_WAIT.min(Duration::from_secs(st.cfg.max_wait_secs));
            st.jobs.wait(job, wait).await;
        }
        scene = settled(st, id).await?;
        v = pick(&scene).unwrap_or(v);
    }
    match v.status {
        VersionStatus::Ready => Ok((scene, v)),
        VersionStatus::Pending => Err(ApiError::Conflict(format!(
            "version {} of scene {id} is still being computed; retry when it is ready",
            v.version
        ))),
        VersionStatus::Failed => Err(ApiError::Conflict(format!(
            "version {} of scene {id} failed{}; use another version",
            v.version,
            v.error
                .as_ref()
                .map_or(String::new(), |e| format!(": {}", e.detail))
        ))),
    }
}

/// A scene job's estimated peak memory (see `PipelineSet::run_cost`): the scene's volume (its
/// `info.dims`) and the job's pixels (`width` × `height` of its canonical parameters; none for
/// an edit, which solves on the volume). 413 when it exceeds the whole memory budget.
fn scene_job_memory(
    st: &AppState,
    pipeline: &str,
    scene: &SceneRecord,
    params: &Value,
) -> Result<u64, ApiError> {
    let voxels = scene
        .info
        .get("dims")
        .and_then(Value::as_array)
        .map_or(0, |d| d.iter().filter_map(Value::as_u64).product());
    let px = |k: &str| params.get(k).and_then(Value::as_u64).unwrap_or(0);
    let bytes = st.jobs.pipelines().run_cost(
        pipeline,
        voxels,
        px("width").saturating_mul(px("height")),
        pipeline == EDIT,
    );
    super::admission::ensure_fits(&st.memory, bytes)?;
    Ok(bytes)
}

/// The job input of a scene version: the volume plus its ambient field, if any; and the key part
/// that identifies both.
fn version_input(scene: &SceneRecord, v: &VersionRecord) -> (InputRef, String) {
    let mut input = scene.volume.clone();
    let mut key = input.asset.clone();
    if let Some(f) = &v.ambient_field {
        input.aux = vec![AuxInput {
            name: "ambient.bin".into(),
            blob: f.clone(),
        }];
        key = format!("{key}+{f}");
    }
    (input, key)
}

fn json_body(body: &[u8]) -> Result<Map<String, Value>, ApiError> {
    if body.is_empty() {
        return Ok(Map::new());
    }
    let v = strict_json::from_slice(body).map_err(|e| match e {
        StrictJsonError::Syntax(e) => ApiError::bad_request(format!("invalid JSON body: {e}")),
        StrictJsonError::Duplicate(path) => strict_json::duplicate_problem(path, true),
    })?;
    object(&v, "body")
}

async fn read_json(st: &AppState, req: Request) -> Result<Map<String, Value>, ApiError> {
    let ctype = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    let body = axum::body::to_bytes(req.into_body(), st.cfg.max_body_bytes)
        .await
        .map_err(|_| ApiError::PayloadTooLarge("request body too large".into()))?;
    if !body.is_empty() && !ctype.starts_with("application/json") {
        return Err(ApiError::UnsupportedMediaType(format!(
            "send application/json; got {:?}",
            if ctype.is_empty() {
                "no Content-Type"
            } else {
                ctype.as_str()
            }
        )));
    }
    json_body(&body)
}

/// `POST /v1/clouds/{id}/renders`: renders a version (default: the newest one) with a view
/// (`width`, `height`, `camera`, `layers`) as a `cloud` job.
pub async fn render(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    headers: HeaderMap,
    req: Request,
) -> Result<Response, ApiError> {
    let wait = prefer_wait(&headers, st.cfg.max_wait_secs);
    let mut body = read_json(&st, req).await?;
    reject_nulls(&Value::Object(body.clone()), "")?;
    let n = take_version(&mut body, "version")?;
    if let Some(k) = body.keys().find(|k| !VIEW_KEYS.contains(&k.as_str())) {
        return Err(ParamError::new(
            k.clone(),
            format!(
                "unknown render parameter; expected version, {}",
                VIEW_KEYS.join(", ")
            ),
        )
        .into());
    }
    let (scene, v) = ready_version(&st, &id, n, "version").await?;
    let params = render_params(&scene, &v, body);
    let params = st
        .jobs
        .pipelines()
        .params(RENDER, &Value::Object(params))?
        .into_canonical();
    let (mut input, key_input) = version_input(&scene, &v);
    input.memory = scene_job_memory(&st, RENDER, &scene, &params)?;
    let key = request_key(RENDER, &key_input, &params);
    let rec = match st.jobs.find_by_key(&key).await? {
        Some(rec) => rec,
        None => queue_job(&st, RENDER, input, params, key).await?,
    };
    respond(&st, rec, wait).await
}

/// The parameters of a render of version `v` with the view in `body`: the version's state, the
/// scene's decoder options, the view, and the `linear` layer (`layers.bin`) added to the
/// requested layers so that a later sun-colour edit at this view can read it.
fn render_params(
    scene: &SceneRecord,
    v: &VersionRecord,
    body: Map<String, Value>,
) -> Map<String, Value> {
    let mut params = state_of(v);
    params.extend(scene.input.clone());
    params.extend(body);
    let multiple = params.get("scattering").and_then(Value::as_str) == Some("multiple");
    let layers = match params.remove("layers") {
        None | Some(Value::Bool(false)) => Value::Array(vec![]),
        Some(Value::Bool(true)) if multiple => serde_json::json!(["direct", "multiple", "ambient"]),
        Some(Value::Bool(true)) => serde_json::json!(["direct", "ambient"]),
        Some(other) => other,
    };
    let layers = match layers {
        Value::Array(mut l) => {
            if !l.iter().any(|x| x == LINEAR) {
                l.push(Value::String(LINEAR.into()));
            }
            Value::Array(l)
        }
        // Not a list: left for the pipeline to refuse.
        other => other,
    };
    params.insert("layers".into(), layers);
    params
}

/// The view keys of an edit or render body, as sent.
fn view_of(body: &Map<String, Value>) -> Vec<Option<&Value>> {
    ["width", "height", "camera"]
        .iter()
        .map(|k| body.get(*k))
        .collect()
}

/// The `layers.bin` blob of a finished render of version `v` at the view of the edit `body`,
/// if one exists: the render made by the edit that produced `v` when it was made at the same
/// view (as sent), else a scene render of `v` at that view (found by its request key, for each
/// set of image layers it may have asked for). The engine checks the blob's identity against the
/// edit and marches instead when it differs, so a wrong guess costs time, never correctness.
async fn layers_of(
    st: &AppState,
    scene: &SceneRecord,
    v: &VersionRecord,
    body: &Map<String, Value>,
) -> Option<String> {
    let blob_of = |job: &crate::jobs::JobRecord| {
        (job.status == crate::jobs::Status::Succeeded)
            .then(|| job.outputs.iter().find(|o| o.name == LAYERS_BIN))
            .flatten()
            .map(|o| o.sha256.clone())
    };
    let same_view = v
        .edit
        .as_ref()
        .and_then(Value::as_object)
        .is_some_and(|e| view_of(e) == view_of(body));
    if same_view {
        if let Some(j) = &v.job {
            if let Some(b) = st
                .jobs
                .get(j)
                .await
                .ok()
                .flatten()
                .and_then(|j| blob_of(&j))
            {
                return Some(b);
            }
        }
    }
    let (_, key_input) = version_input(scene, v);
    let view: Map<String, Value> = body
        .iter()
        .filter(|(k, _)| ["width", "height", "camera"].contains(&k.as_str()))
        .map(|(k, x)| (k.clone(), x.clone()))
        .collect();
    for layers in [
        Value::Bool(false),
        serde_json::json!(["direct"]),
        serde_json::json!(["multiple"]),
        serde_json::json!(["ambient"]),
        Value::Bool(true),
    ] {
        let mut b = view.clone();
        b.insert("layers".into(), layers);
        let Ok(params) = st
            .jobs
            .pipelines()
            .params(RENDER, &Value::Object(render_params(scene, v, b)))
        else {
            continue;
        };
        let key = request_key(RENDER, &key_input, params.canonical());
        if let Some(b) = st
            .jobs
            .find_by_key(&key)
            .await
            .ok()
            .flatten()
            .and_then(|j| blob_of(&j))
        {
            return Some(b);
        }
    }
    None
}

fn state_of(v: &VersionRecord) -> Map<String, Value> {
    v.state
        .as_ref()
        .and_then(Value::as_object)
        .cloned()
        .unwrap_or_default()
}

/// Maps an edit's parameter error back to the request's own field names (`edit.strokes[0]` →
/// `strokes[0]`).
fn edit_field(e: ParamError) -> ApiError {
    let field = e
        .field
        .strip_prefix("edit.")
        .map(str::to_string)
        .unwrap_or(e.field);
    ApiError::InvalidParameter(ParamError::new(field, e.detail))
}

/// `POST /v1/clouds/{id}/edits/sun-color`: see [`edit`].
pub async fn edit_sun_color(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    headers: HeaderMap,
    req: Request,
) -> Result<Response, ApiError> {
    edit(st, id, "sun-color", headers, req).await
}

/// `POST /v1/clouds/{id}/edits/ambient`: see [`edit`].
pub async fn edit_ambient(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    headers: HeaderMap,
    req: Request,
) -> Result<Response, ApiError> {
    edit(st, id, "ambient", headers, req).await
}

/// `POST /v1/clouds/{id}/edits/sun-direction`: see [`edit`].
pub async fn edit_sun_direction(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    headers: HeaderMap,
    req: Request,
) -> Result<Response, ApiError> {
    edit(st, id, "sun-direction", headers, req).await
}

/// `POST /v1/clouds/{id}/edits/set`: see [`edit`].
pub async fn edit_set(
    State(st): State<AppState>,
    ApiPath(id): ApiPath<String>,
    headers: HeaderMap,
    req: Request,
) -> Result<Response, ApiError> {
    edit(st, id, "set", headers, req).await
}

/// `POST /v1/clouds/{id}/edits/{kind}` (one route per edit mode, each with its own body schema
/// in `openapi.yaml`; any other mode is the router's 404): applies an edit to `base_version` (default: the newest
/// version that has not failed) as a `cloud-edit` job; answers 202 with the new, pending version (200 when
/// `Prefer: wait` saw it settle).
async fn edit(
    st: AppState,
    id: String,
    kind: &'static str,
    headers: HeaderMap,
    req: Request,
) -> Result<Response, ApiError> {
    if !st.jobs.accepting() {
        return Err(ApiError::Unavailable("the service is shutting down".into()));
    }
    let wait = prefer_wait(&headers, st.cfg.max_wait_secs);
    let mut body = read_json(&st, req).await?;
    reject_nulls(&Value::Object(body.clone()), "")?;
    let n = take_version(&mut body, "base_version")?;
    let (scene, base) = ready_version(&st, &id, n, "base_version").await?;
    let mut params = Map::new();
    params.insert("kind".into(), Value::String(kind.into()));
    params.insert("base".into(), Value::Object(state_of(&base)));
    params.insert("edit".into(), Value::Object(body.clone()));
    params.extend(scene.input.clone());
    let params = st
        .jobs
        .pipelines()
        .params(EDIT, &Value::Object(params))
        .map_err(edit_field)?
        .into_canonical();
    let (mut input, key_input) = version_input(&scene, &base);
    input.memory = scene_job_memory(&st, EDIT, &scene, &params)?;
    // (Not in the key: the blob only saves time, the version is the same with or without it.)
    if kind == "sun-color" {
        if let Some(blob) = layers_of(&st, &scene, &base, &body).await {
            input.aux.push(AuxInput {
                name: LAYERS_BIN.into(),
                blob,
            });
        }
    }
    let key = request_key(EDIT, &key_input, &params);
    let job = match st.jobs.find_by_key(&key).await? {
        Some(rec) => rec,
        None => queue_job(&st, EDIT, input, params, key).await?,
    };
    let version = st
        .scenes
        .add_version(&id, base.version, kind, Value::Object(body), &job)
        .await?;
    // The job may have ended between its submission and the version's creation.
    if let Some(wait) = wait {
        st.jobs.wait(&job.id, wait).await;
    }
    let scene = settled(&st, &id).await?;
    let v = scene.version(version.version).cloned().unwrap_or(version);
    let status = if v.status == VersionStatus::Pending {
        StatusCode::ACCEPTED
    } else {
        StatusCode::OK
    };
    let view = VersionView::from(v);
    let mut resp = (status, Json(&view)).into_response();
    if let Some(u) = view
        .job_url
        .as_ref()
        .and_then(|u| HeaderValue::from_str(u).ok())
    {
        resp.headers_mut().insert(header::LOCATION, u);
    }
    Ok(resp)
}
