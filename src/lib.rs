//! `phenomena`: the HTTP service and CLI around `phenomena-engine`.
//!
//! Data flows one way: [`api`] (HTTP, validation, problem errors) → [`jobs`] (queue, workers,
//! progress, cancel) → an engine pipeline → [`store`] (assets and outputs).

pub mod api;
pub mod budget;
pub mod cli;
pub mod config;
pub mod error;
pub mod jobs;
pub mod maps;
pub mod metrics;
pub mod pipeline_set;
pub mod scenes;
pub mod serve;
pub mod store;

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

pub use api::{app, AppState};
use tokio_util::sync::CancellationToken;

use crate::config::Config;
use crate::jobs::embedded::Embedded;
use crate::jobs::redis::{RedisJobs, RedisSettings};
use crate::jobs::{JobBackend, Jobs};
use crate::metrics::Metrics;
use crate::pipeline_set::{EnginePipelines, PipelineSet};
use crate::scenes::files::FileScenes;
use crate::scenes::redis::RedisScenes;
use crate::scenes::Scenes;
use crate::store::Store;

/// Start-up failures.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("cannot open the data directory: {0}")]
    Store(#[from] store::StoreError),
    #[error("cannot start the job system: {0}")]
    Jobs(#[from] jobs::StartError),
    #[error("job backend: {0}")]
    Backend(String),
    #[error("metrics: {0}")]
    Metrics(#[from] prometheus::Error),
    #[error("cannot load the cloud scenes: {0}")]
    Scenes(#[from] scenes::SceneError),
    #[error("cannot start the map pool: {0}")]
    MapPool(#[from] rayon::ThreadPoolBuildError),
}

/// Opens the store and starts the job system with the engine's pipelines.
pub async fn state(cfg: Config) -> Result<AppState, StartError> {
    let limits = cfg.limits();
    state_with(cfg, Arc::new(EnginePipelines { limits })).await
}

/// Like [`state`] with another pipeline set (tests use a pipeline that sleeps in stages).
pub async fn state_with(
    cfg: Config,
    pipelines: Arc<dyn PipelineSet>,
) -> Result<AppState, StartError> {
    let mut cfg = cfg;
    if cfg.replica_id.is_empty() {
        cfg.replica_id = format!(
            "{}-{}",
            config::default_replica_id(),
            hex::encode(rand::random::<[u8; 2]>())
        );
    }
    let store = Store::open_with(&cfg.data_dir, cfg.store_url.as_deref())?;
    tracing::info!(blobs = %store.blob_url(), "blob store");
    let metrics = Metrics::new()?;
    let jcfg = cfg.jobs();
    let (backend, scenes): (Arc<dyn JobBackend>, Scenes) = match &cfg.redis_url {
        None => {
            let scenes = Scenes::new(Arc::new(FileScenes::open(store.clone())?), store.clone());
            let backend = Embedded::start(
                store.clone(),
                pipelines.clone(),
                Arc::new(scenes.clone()),
                jcfg.clone(),
                metrics.clone(),
            )?;
            (Arc::new(backend), scenes)
        }
        Some(url) => {
            let client = ::redis::Client::open(url.as_str())
                .map_err(|e| StartError::Backend(format!("invalid Redis URL: {e}")))?;
            let con = jobs::redis::connect(&client)
                .await
                .map_err(|e| StartError::Backend(format!("cannot reach Redis: {e}")))?;
            let scenes = Scenes::new(
                Arc::new(RedisScenes::new(con, &cfg.redis_prefix)),
                store.clone(),
            );
            let settings = RedisSettings {
                url: url.clone(),
                prefix: cfg.redis_prefix.clone(),
                lease: Duration::from_secs(cfg.redis_lease_secs),
                replica: cfg.replica_id.clone(),
            };
            let backend = RedisJobs::start(
                settings,
                store.clone(),
                pipelines.clone(),
                Arc::new(scenes.clone()),
                jcfg.clone(),
                metrics.clone(),
            )
            .await?;
            (Arc::new(backend), scenes)
        }
    };
    let hooks = Arc::new(scenes.clone());
    metrics
        .replica_info
        .with_label_values(&[cfg.replica_id.as_str(), cfg.role.as_str(), backend.kind()])
        .set(1);
    let jobs = Jobs::new(backend, store, pipelines, hooks, &jcfg, metrics.clone());
    // Versions whose job ended while the process was down (or just before a crash).
    for id in scenes.pending_jobs(None).await? {
        if let Some(rec) = jobs
            .get(&id)
            .await
            .map_err(|e| StartError::Backend(e.to_string()))?
        {
            scenes.resolve(&rec).await?;
        }
    }
    // Fill the store-size gauge once at start; the sweeper refreshes it.
    metrics
        .store_bytes
        .set(i64::try_from(jobs.store().blob_bytes().await).unwrap_or(i64::MAX));
    let maps = maps::Maps::new(
        jobs.store().clone(),
        jcfg.threads,
        cfg.limits(),
        cfg.map_whole_max_cells,
    )?;
    Ok(AppState {
        memory: jcfg.memory.clone(),
        maps,
        cfg: Arc::new(cfg),
        jobs,
        scenes,
        metrics,
        shutdown: CancellationToken::new(),
    })
}

/// Serves `state` on `listener` until `shutdown` resolves, then stops taking work, lets running
/// jobs finish within the grace period (the rest stay queued on disk) and closes connections.
pub async fn run(
    listener: tokio::net::TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let token = state.shutdown.clone();
    let jobs = state.jobs.clone();
    let grace = Duration::from_secs(state.cfg.shutdown_grace_secs);
    let limits = serve::ConnLimits::from_config(&state.cfg);
    let router = app(state);
    let drained = CancellationToken::new();
    let drained2 = drained.clone();
    tokio::spawn(async move {
        shutdown.await;
        // Stop taking work before anything else (even logging) can fail.
        token.cancel();
        tracing::info!("shutting down: no new jobs; waiting for running jobs");
        jobs.shutdown(grace).await;
        drained2.cancel();
    });
    // Connections keep being served while jobs drain (readiness and submissions answer 503).
    serve::serve(listener, router, limits, drained).await
}

/// Resolves on SIGINT or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        if let Err(e) = tokio::signal::ctrl_c().await {
            tracing::error!(error = %e, "cannot listen for Ctrl-C");
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(e) => {
                tracing::error!(error = %e, "cannot listen for SIGTERM");
                std::future::pending::<()>().await;
            }
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {},
        () = term => {},
    }
}
