//! Prometheus metrics: one registry per server, rendered as text at `GET /metrics`.

use prometheus::{
    Encoder, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGauge, IntGaugeVec, Opts,
    Registry, TextEncoder,
};

/// Every metric the service exports.
#[derive(Clone)]
pub struct Metrics {
    registry: Registry,
    pub http_requests: IntCounterVec,
    pub http_duration: HistogramVec,
    pub job_duration: HistogramVec,
    pub jobs_finished: IntCounterVec,
    /// Jobs given up after `max_attempts` starts none of which reached an end (the pipeline
    /// panicked or the worker died each time; also counted in `jobs_finished_total{status="failed"}`).
    pub jobs_poisoned: IntCounterVec,
    /// Attempts that ended in a pipeline panic in this replica (the job went back to the queue).
    pub jobs_failed_attempts: IntCounterVec,
    pub queue_depth: IntGauge,
    pub jobs_running: IntGauge,
    pub store_bytes: IntGauge,
    /// Worker slots of this replica (0 for an API-only replica).
    pub workers: IntGauge,
    /// Jobs this replica started, `how` = `new` or `reclaimed` (taken over from a dead worker).
    pub jobs_started: IntCounterVec,
    /// Always 1, labelled with this replica's name, role and job backend.
    pub replica_info: IntGaugeVec,
    /// Bytes of DEM assets read from the store for maps (whole, or by ranges for a COG read
    /// tile by tile); brought up to date at each scrape.
    pub map_dem_bytes_read: IntCounter,
    /// Map tiles this replica computed (cold tiles; a tile read from the shared cache is not
    /// counted); brought up to date at each scrape.
    pub map_tiles_computed: IntCounter,
}

impl Metrics {
    /// Builds and registers the metrics (fails only on malformed static definitions).
    pub fn new() -> Result<Self, prometheus::Error> {
        let registry = Registry::new_custom(Some("phenomena".into()), None)?;
        let m = Self {
            http_requests: IntCounterVec::new(
                Opts::new(
                    "http_requests_total",
                    "HTTP requests by route, method and status",
                ),
                &["route", "method", "status"],
            )?,
            http_duration: HistogramVec::new(
                HistogramOpts::new(
                    "http_request_duration_seconds",
                    "HTTP request latency by route",
                )
                .buckets(vec![
                    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0,
                ]),
                &["route", "method"],
            )?,
            job_duration: HistogramVec::new(
                HistogramOpts::new(
                    "job_stage_duration_seconds",
                    "Pipeline time by pipeline and stage (stage=\"total\" for the whole job)",
                )
                .buckets(vec![
                    0.001, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0,
                    120.0,
                ]),
                &["pipeline", "stage"],
            )?,
            jobs_finished: IntCounterVec::new(
                Opts::new("jobs_finished_total", "Jobs by pipeline and final status"),
                &["pipeline", "status"],
            )?,
            jobs_poisoned: IntCounterVec::new(
                Opts::new(
                    "jobs_poisoned_total",
                    "Jobs failed as poisoned: started max_attempts times, no attempt reached an end (a panic or a dead worker)",
                ),
                &["pipeline"],
            )?,
            jobs_failed_attempts: IntCounterVec::new(
                Opts::new(
                    "job_attempts_failed_total",
                    "Attempts whose pipeline panicked in this replica; the job went back to the queue",
                ),
                &["pipeline"],
            )?,
            queue_depth: IntGauge::new(
                "queue_depth",
                "Jobs waiting in the queue (the shared queue with Redis)",
            )?,
            jobs_running: IntGauge::new("jobs_running", "Jobs running in this replica")?,
            workers: IntGauge::new("workers", "Worker slots of this replica")?,
            jobs_started: IntCounterVec::new(
                Opts::new(
                    "jobs_started_total",
                    "Jobs this replica started: new, or reclaimed from a worker that died",
                ),
                &["how"],
            )?,
            replica_info: IntGaugeVec::new(
                Opts::new("replica_info", "This replica: name, role and job backend"),
                &["replica", "role", "backend"],
            )?,
            store_bytes: IntGauge::new("store_bytes", "Bytes held in the blob store")?,
            map_dem_bytes_read: IntCounter::new(
                "map_dem_bytes_read_total",
                "Bytes of DEM assets read from the store for maps",
            )?,
            map_tiles_computed: IntCounter::new(
                "map_tiles_computed_total",
                "Map tiles this replica computed (cold tiles, not read from the tile cache)",
            )?,
            registry,
        };
        m.registry.register(Box::new(m.http_requests.clone()))?;
        m.registry.register(Box::new(m.http_duration.clone()))?;
        m.registry.register(Box::new(m.job_duration.clone()))?;
        m.registry.register(Box::new(m.jobs_finished.clone()))?;
        m.registry.register(Box::new(m.jobs_poisoned.clone()))?;
        m.registry
            .register(Box::new(m.jobs_failed_attempts.clone()))?;
        m.registry.register(Box::new(m.queue_depth.clone()))?;
        m.registry.register(Box::new(m.jobs_running.clone()))?;
        m.registry.register(Box::new(m.store_bytes.clone()))?;
        m.registry.register(Box::new(m.workers.clone()))?;
        m.registry.register(Box::new(m.jobs_started.clone()))?;
        m.registry.register(Box::new(m.replica_info.clone()))?;
        m.registry
            .register(Box::new(m.map_dem_bytes_read.clone()))?;
        m.registry
            .register(Box::new(m.map_tiles_computed.clone()))?;
        Ok(m)
    }

    /// The Prometheus text exposition of every metric.
    pub fn render(&self) -> String {
        let mut buf = Vec::new();
        if let Err(e) = TextEncoder::new().encode(&self.registry.gather(), &mut buf) {
            tracing::error!(error = %e, "metrics encoding failed");
        }
        String::from_utf8(buf).unwrap_or_default()
    }
}
