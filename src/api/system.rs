//! Liveness, readiness, metrics and the API description.

use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::json;

use super::AppState;
use crate::error::ApiError;

/// The repository's `openapi.yaml`, served as is.
pub const OPENAPI_YAML: &str = include_str!("../../openapi.yaml");

/// `GET /healthz`: the process is up.
pub async fn healthz() -> Json<serde_json::Value> {
    Json(json!({ "status": "ok" }))
}

/// `GET /readyz`: ready to take jobs — not shutting down, and the data directory and the blob
/// store take writes (a full or read-only disk answers 503 until it recovers).
pub async fn readyz(State(st): State<AppState>) -> Result<Json<serde_json::Value>, ApiError> {
    if st.shutdown.is_cancelled() || !st.jobs.accepting() {
        return Err(ApiError::Unavailable("the service is shutting down".into()));
    }
    let store = st.jobs.store().clone();
    let local = tokio::task::spawn_blocking(move || store.probe_local())
        .await
        .unwrap_or(false);
    if !local {
        return Err(ApiError::Unavailable(
            "the data directory is not writable (full or read-only)".into(),
        ));
    }
    if !st.jobs.store().probe().await {
        return Err(ApiError::Unavailable(
            "the blob store is not writable".into(),
        ));
    }
    st.jobs.check().await?;
    let load = st.jobs.load().await?;
    Ok(Json(json!({
        "status": "ready",
        "queued": load.queued,
        "running": load.running,
        "backend": st.jobs.kind(),
        "role": st.cfg.role.as_str(),
        "replica": st.cfg.replica_id,
        "running_here": load.running_here,
        "workers": load.workers,
    })))
}

/// `GET /metrics`: Prometheus text exposition.
pub async fn metrics(State(st): State<AppState>) -> Response {
    let read = st.maps.dem_bytes_read();
    let counted = st.metrics.map_dem_bytes_read.get();
    st.metrics
        .map_dem_bytes_read
        .inc_by(read.saturating_sub(counted));
    let computed = st.maps.tiles_computed();
    let counted = st.metrics.map_tiles_computed.get();
    st.metrics
        .map_tiles_computed
        .inc_by(computed.saturating_sub(counted));
    (
        StatusCode::OK,
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        st.metrics.render(),
    )
        .into_response()
}

/// `GET /openapi.yaml`.
pub async fn openapi() -> Response {
    (
        StatusCode::OK,
        [(header::CONTENT_TYPE, "application/yaml")],
        OPENAPI_YAML,
    )
        .into_response()
}
