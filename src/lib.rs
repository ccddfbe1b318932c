//! `phenomena`: the HTTP service and CLI around `phenomena-engine`.
//!
//! Data flows one way: [`api`] (HTTP, validation, problem errors) → [`jobs`] (queue, workers,
//! progress, cancel) → an engine pipeline → [`store`] (assets and outputs).

pub mod api;
pub mod cli;
pub mod clouds;
pub mod config;
pub mod error;
pub mod jobs;
pub mod metrics;
pub mod pipelines;
pub mod store;

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

pub use api::{app, AppState};
use tokio_util::sync::CancellationToken;

use crate::clouds::Scenes;
use crate::config::Config;
use crate::jobs::Jobs;
use crate::metrics::Metrics;
use crate::pipelines::{EnginePipelines, PipelineSet};
use crate::store::Store;

/// Start-up failures.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("cannot open the data directory: {0}")]
    Store(#[from] store::StoreError),
    #[error("cannot start the job system: {0}")]
    Jobs(#[from] jobs::StartError),
    #[error("metrics: {0}")]
    Metrics(#[from] prometheus::Error),
}

/// Opens the store and starts the job system with the engine's pipelines.
pub fn state(cfg: Config) -> Result<AppState, StartError> {
    let limits = cfg.limits();
    state_with(cfg, Arc::new(EnginePipelines { limits }))
}

/// Like [`state`] with another pipeline set (tests use a pipeline that sleeps in stages).
pub fn state_with(cfg: Config, pipelines: Arc<dyn PipelineSet>) -> Result<AppState, StartError> {
    let store = Store::open(&cfg.data_dir)?;
    let metrics = Metrics::new()?;
    let clouds = Scenes::open(store.clone())?;
    let jobs = Jobs::start(
        store,
        pipelines,
        Arc::new(clouds.clone()),
        cfg.jobs(),
        metrics.clone(),
    )?;
    // Versions whose job ended while the process was down (or just before a crash).
    for id in clouds.pending_jobs(None) {
        if let Some(rec) = jobs.get(&id) {
            clouds.resolve(&rec)?;
        }
    }
    // Fill the store-size gauge once at start; the sweeper refreshes it.
    metrics
        .store_bytes
        .set(i64::try_from(jobs.store().blob_bytes()).unwrap_or(i64::MAX));
    Ok(AppState {
        cfg: Arc::new(cfg),
        jobs,
        clouds,
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
    axum::serve(listener, router)
        .with_graceful_shutdown(async move { drained.cancelled().await })
        .await
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
