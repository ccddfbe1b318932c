//! The HTTP API: routes, shared state and the request-metrics middleware. Handlers validate and
//! translate; the maths happens in the engine behind the job system.

mod admission;
mod assets;
mod body_timeout;
mod dto;
mod extract;
mod jobs;
mod maps;
pub mod ogc;
mod scenes;
mod stac;
mod strict_json;
mod submit;
mod system;
pub mod web;

pub use admission::CHECK_WAIT;
pub use submit::{parse_submission, parse_submission_aux, Input};

use std::sync::Arc;
use std::time::Instant;

use axum::extract::{DefaultBodyLimit, MatchedPath, Request, State};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use sha2::Digest;
use tokio_util::sync::CancellationToken;
use tower_http::trace::TraceLayer;

use crate::config::Config;
use crate::error::ApiError;
use crate::jobs::Jobs;
use crate::metrics::Metrics;

/// Everything a handler needs; cheap to clone.
#[derive(Clone)]
pub struct AppState {
    pub cfg: Arc<Config>,
    pub jobs: Jobs,
    pub scenes: crate::scenes::Scenes,
    /// Web maps and their tile pool (`/v1/maps`).
    pub maps: crate::maps::Maps,
    pub metrics: Metrics,
    /// The process's memory budget, shared by the up-front input checks (`api::admission`) and
    /// the running jobs.
    pub memory: crate::budget::MemoryBudget,
    /// Cancelled when the server begins shutting down (ends SSE streams, fails readiness).
    pub shutdown: CancellationToken,
}

/// Every route the server serves besides the per-pipeline submit routes (`POST /v1/{pipeline}`),
/// as (method, path) in OpenAPI syntax. A test holds this list, the router and `openapi.yaml`
/// to each other.
pub const ROUTES: &[(&str, &str)] = &[
    ("get", "/healthz"),
    ("get", "/readyz"),
    ("get", "/metrics"),
    ("get", "/openapi.yaml"),
    ("get", "/"),
    ("get", "/web/{file}"),
    ("get", "/web/vendor/{path}"),
    ("get", "/v1/examples/{name}"),
    ("post", "/v1/assets"),
    ("post", "/v1/clouds"),
    ("get", "/v1/clouds/{id}"),
    ("delete", "/v1/clouds/{id}"),
    ("post", "/v1/clouds/{id}/renders"),
    ("post", "/v1/clouds/{id}/edits/sun-color"),
    ("post", "/v1/clouds/{id}/edits/ambient"),
    ("post", "/v1/clouds/{id}/edits/sun-direction"),
    ("post", "/v1/clouds/{id}/edits/set"),
    ("get", "/v1/assets/{id}"),
    ("get", "/v1/jobs"),
    ("get", "/v1/jobs/{id}"),
    ("delete", "/v1/jobs/{id}"),
    ("get", "/v1/jobs/{id}/events"),
    ("get", "/v1/jobs/{id}/outputs/{name}"),
    ("post", "/v1/maps"),
    ("get", "/v1/maps/{id}"),
    ("get", "/v1/maps/{id}/tilejson.json"),
    ("get", "/v1/maps/{id}/tiles/{layer}/{z}/{x}/{y}.png"),
    ("get", "/v1/jobs/{id}/stac.json"),
    ("get", "/ogc"),
    ("get", "/ogc/conformance"),
    ("get", "/ogc/processes"),
    ("get", "/ogc/processes/{processId}"),
    ("post", "/ogc/processes/{processId}/execution"),
    ("get", "/ogc/jobs"),
    ("get", "/ogc/jobs/{id}"),
    ("delete", "/ogc/jobs/{id}"),
    ("get", "/ogc/jobs/{id}/results"),
];

/// The application router (no socket: tests drive it with `tower::ServiceExt::oneshot`).
pub fn app(state: AppState) -> Router {
    if state.cfg.role == crate::config::Role::Worker {
        // A worker replica answers only its probes and metrics; clients talk to `api` replicas.
        return Router::new()
            .route("/healthz", get(system::healthz))
            .route("/readyz", get(system::readyz))
            .route("/metrics", get(system::metrics))
            .fallback(fallback)
            .layer(middleware::from_fn_with_state(state.clone(), track))
            .with_state(state);
    }
    let mut router = Router::new()
        .route("/healthz", get(system::healthz))
        .route("/readyz", get(system::readyz))
        .route("/metrics", get(system::metrics))
        .route("/openapi.yaml", get(system::openapi))
        .route("/", get(web::index))
        .route("/web/{file}", get(web::asset))
        .route("/web/vendor/{*path}", get(web::vendor))
        .route("/v1/examples/{name}", get(web::example))
        .route("/v1/assets", post(assets::upload))
        .route("/v1/assets/{id}", get(assets::get))
        .route("/v1/clouds", post(scenes::create))
        .route("/v1/clouds/{id}", get(scenes::get).delete(scenes::delete))
        .route("/v1/clouds/{id}/renders", post(scenes::render))
        .route(
            "/v1/clouds/{id}/edits/sun-color",
            post(scenes::edit_sun_color),
        )
        .route("/v1/clouds/{id}/edits/ambient", post(scenes::edit_ambient))
        .route(
            "/v1/clouds/{id}/edits/sun-direction",
            post(scenes::edit_sun_direction),
        )
        .route("/v1/clouds/{id}/edits/set", post(scenes::edit_set))
        .route("/v1/jobs", get(jobs::list))
        .route("/v1/jobs/{id}", get(jobs::get).delete(jobs::cancel))
        .route("/v1/jobs/{id}/events", get(jobs::events))
        .route("/v1/jobs/{id}/outputs/{name}", get(jobs::output))
        .route("/v1/jobs/{id}/stac.json", get(stac::item))
        // OGC API – Processes – Part 1 (`api::ogc`), under its own prefix: `/` is the studio.
        .route("/ogc", get(ogc::landing))
        .route("/ogc/conformance", get(ogc::conformance))
        .route("/ogc/processes", get(ogc::processes))
        .route("/ogc/processes/{id}", get(ogc::process))
        .route("/ogc/processes/{id}/execution", post(ogc::execute))
        .route("/ogc/jobs", get(ogc::jobs))
        .route("/ogc/jobs/{id}", get(ogc::job).delete(ogc::dismiss))
        .route("/ogc/jobs/{id}/results", get(ogc::results))
        .route("/v1/maps", post(maps::create))
        .route("/v1/maps/{id}", get(maps::get))
        .route("/v1/maps/{id}/tilejson.json", get(maps::tilejson))
        // `{file}` is `{y}.png` (the router has no parameters with a suffix).
        .route(
            "/v1/maps/{id}/tiles/{layer}/{z}/{x}/{file}",
            get(maps::tile),
        );
    for name in state.jobs.pipelines().names() {
        router = router.route(
            &format!("/v1/{name}"),
            post(move |st: State<AppState>, req: Request| submit::submit(name, st, req)),
        );
    }
    let cors = cors_layer(&state.cfg.cors_origins);
    router
        .fallback(fallback)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(DefaultBodyLimit::max(state.cfg.max_body_bytes))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            body_timeout::body_timeout,
        ))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            refuse_declared_oversize,
        ))
        .layer(middleware::from_fn_with_state(state.clone(), authenticate))
        .layer(middleware::from_fn_with_state(state.clone(), track))
        .layer(TraceLayer::new_for_http())
        .layer(tower::util::option_layer(cors))
        .with_state(state)
}

/// With `auth_tokens` configured, every `/v1` and `/ogc` route needs `Authorization: Bearer <token>`
/// (401 with `WWW-Authenticate` otherwise); `/`, `/web/*`, health, readiness, metrics and the
/// OpenAPI document stay open (probes and the page's shell need no secret). Tokens are compared
/// by their SHA-256 digests, so the time taken does not depend on how much of a guess matched.
async fn authenticate(State(st): State<AppState>, req: Request, next: Next) -> Response {
    let path = req.uri().path();
    let guarded = path.starts_with("/v1/") || path == ogc::PREFIX || path.starts_with("/ogc/");
    if st.cfg.auth_tokens.is_empty() || !guarded {
        return next.run(req).await;
    }
    let given = req
        .headers()
        .get(axum::http::header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| {
            v.strip_prefix("Bearer ")
                .or_else(|| v.strip_prefix("bearer "))
        })
        .map(|t| sha2::Sha256::digest(t.trim().as_bytes()));
    let ok = given.is_some_and(|g| {
        st.cfg.auth_tokens.iter().fold(false, |acc, t| {
            acc | (sha2::Sha256::digest(t.as_bytes()) == g)
        })
    });
    if ok {
        next.run(req).await
    } else {
        ApiError::Unauthorized(
            "send `Authorization: Bearer <token>` with a configured token".into(),
        )
        .into_response()
    }
}

/// A request whose `Content-Length` declares more than `max_body_bytes` is answered `413` at
/// once, before a byte of its body is read (and the connection is closed, since the body is
/// never read): the client learns the limit now instead of after uploading up to it, or after
/// the body timeout. Bodies without a declared length are cut at the limit while they are read
/// (`DefaultBodyLimit`).
async fn refuse_declared_oversize(
    State(st): State<AppState>,
    req: Request,
    next: Next,
) -> Response {
    use axum::http::{header, HeaderValue};
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    let max = st.cfg.max_body_bytes as u64;
    match declared {
        Some(n) if n > max => {
            let mut resp = ApiError::PayloadTooLarge(format!(
                "the request body declares {n} bytes (Content-Length); the limit is {max} bytes"
            ))
            .into_response();
            resp.headers_mut()
                .insert(header::CONNECTION, HeaderValue::from_static("close"));
            resp
        }
        _ => next.run(req).await,
    }
}

/// CORS for browsers on other origins, off unless `cors_origins` is set (`*` = any origin).
fn cors_layer(origins: &[String]) -> Option<tower_http::cors::CorsLayer> {
    use axum::http::{header, HeaderName, HeaderValue, Method};
    use tower_http::cors::{AllowOrigin, CorsLayer};
    if origins.is_empty() {
        return None;
    }
    let allow = if origins.iter().any(|o| o == "*") {
        AllowOrigin::any()
    } else {
        AllowOrigin::list(origins.iter().filter_map(|o| HeaderValue::from_str(o).ok()))
    };
    Some(
        CorsLayer::new()
            .allow_origin(allow)
            .allow_methods([Method::GET, Method::POST, Method::DELETE])
            .allow_headers([
                header::CONTENT_TYPE,
                header::AUTHORIZATION,
                header::IF_NONE_MATCH,
                HeaderName::from_static("prefer"),
            ])
            .expose_headers([
                header::LOCATION,
                header::RETRY_AFTER,
                header::ETAG,
                HeaderName::from_static("preference-applied"),
            ]),
    )
}

async fn fallback(State(st): State<AppState>, req: Request) -> ApiError {
    let path = req.uri().path();
    if let Some(name) = path.strip_prefix("/v1/").filter(|p| !p.contains('/')) {
        return ApiError::NotFound(format!(
            "no pipeline named {name:?}; known pipelines: {}",
            st.jobs.pipelines().names().join(", ")
        ));
    }
    ApiError::NotFound(format!("no route for {path}"))
}

async fn method_not_allowed(req: Request) -> ApiError {
    ApiError::MethodNotAllowed(format!(
        "{} is not allowed on {}",
        req.method(),
        req.uri().path()
    ))
}

/// Counts requests and their latency by matched route.
async fn track(State(st): State<AppState>, req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_string(), |m| m.as_str().to_string());
    let method = req.method().as_str().to_string();
    let t0 = Instant::now();
    let resp = next.run(req).await;
    st.metrics
        .http_requests
        .with_label_values(&[route.as_str(), method.as_str(), resp.status().as_str()])
        .inc();
    st.metrics
        .http_duration
        .with_label_values(&[route.as_str(), method.as_str()])
        .observe(t0.elapsed().as_secs_f64());
    resp
}
