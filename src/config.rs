//! One `Config` for the server, from (highest precedence first) command-line flags, `PHENOMENA_*`
//! environment variables, an optional TOML file (`--config`), and defaults. Logged at start-up.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Log output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    Text,
    Json,
}

/// What a process does in a scaled deployment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Serves the API and runs no jobs (submissions go to the shared queue).
    Api,
    /// Runs jobs from the shared queue; serves only `/healthz`, `/readyz` and `/metrics`.
    Worker,
    /// Both (the default; the only role without Redis).
    Both,
}

impl Role {
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Api => "api",
            Role::Worker => "worker",
            Role::Both => "both",
        }
    }
}

/// Settings given on the command line, the environment or the config file. Every field is optional
/// here; [`Config::resolve`] fills in the defaults.
#[derive(Debug, Clone, Default, Deserialize, clap::Args)]
#[serde(deny_unknown_fields)]
pub struct ServeArgs {
    /// TOML file with any of the settings below (snake_case keys).
    #[arg(long, env = "PHENOMENA_CONFIG")]
    #[serde(skip)]
    pub config: Option<PathBuf>,
    /// Address to listen on. Default 127.0.0.1:8080; use 0.0.0.0:8080 in containers.
    #[arg(long, env = "PHENOMENA_BIND")]
    pub bind: Option<SocketAddr>,
    /// Directory for jobs, assets and outputs. Default ./phenomena-data.
    #[arg(long, env = "PHENOMENA_DATA_DIR")]
    pub data_dir: Option<PathBuf>,
    /// Largest request body in bytes (uploads). Default 268435456 (256 MiB).
    #[arg(long, env = "PHENOMENA_MAX_BODY_BYTES")]
    pub max_body_bytes: Option<usize>,
    /// Largest input grid in cells (DEM width × height). Default 67108864 (8192²).
    #[arg(long, env = "PHENOMENA_MAX_INPUT_CELLS")]
    pub max_input_cells: Option<u64>,
    /// Largest output image in pixels (width × height). Default 33177600 (7680×4320).
    #[arg(long, env = "PHENOMENA_MAX_OUTPUT_PIXELS")]
    pub max_output_pixels: Option<u64>,
    /// Largest input mesh in triangles. Default 4000000.
    #[arg(long, env = "PHENOMENA_MAX_INPUT_TRIANGLES")]
    pub max_input_triangles: Option<u64>,
    /// Maps (`POST /v1/maps`): a tiled GeoTIFF DEM (a Cloud-Optimized GeoTIFF) with more cells
    /// than this is read by ranges — its header, a bounded overview and the internal tiles each
    /// map tile needs — instead of whole; then it may be far larger than `max_input_cells` (up
    /// to 2^32 cells) and is held in bounded memory. Default 4194304 (2048²).
    #[arg(long, env = "PHENOMENA_MAP_WHOLE_MAX_CELLS")]
    pub map_whole_max_cells: Option<u64>,
    /// Memory, in bytes, that this process's up-front input checks and running jobs may hold at
    /// once (see RELIABILITY.md, "Admission"). A check reserves its input's size plus the most
    /// its decode can allocate under the input limits (a DEM: 12 bytes per cell of
    /// `max_input_cells`), or decodes within what is free with the limits scaled to it; a
    /// submission that cannot reserve within 10 s is answered 429 with `Retry-After`, before any
    /// large allocation. A worker reserves a job's estimated peak memory before it starts it; a
    /// job estimated larger than the whole budget is refused 413. Default 805306368 (768 MiB),
    /// so a process answering a flood of large inputs stays under 1 GiB.
    #[arg(long, env = "PHENOMENA_MEMORY_BUDGET_BYTES")]
    pub memory_budget_bytes: Option<u64>,
    /// Jobs running at once. Default 1 (each job uses every core).
    #[arg(long, env = "PHENOMENA_CONCURRENCY")]
    pub concurrency: Option<usize>,
    /// Jobs allowed to wait in the queue; beyond it submissions get 429. Default 64.
    #[arg(long, env = "PHENOMENA_QUEUE_CAPACITY")]
    pub queue_capacity: Option<usize>,
    /// Per-job time limit in seconds. Default 600.
    #[arg(long, env = "PHENOMENA_JOB_TIMEOUT_SECS")]
    pub job_timeout_secs: Option<u64>,
    /// Finished jobs, outputs and unused assets are kept this many seconds. Default 604800 (7 days).
    #[arg(long, env = "PHENOMENA_RETENTION_SECS")]
    pub retention_secs: Option<u64>,
    /// Seconds between retention sweeps. Default 300.
    #[arg(long, env = "PHENOMENA_SWEEP_INTERVAL_SECS")]
    pub sweep_interval_secs: Option<u64>,
    /// Most times a job is started before it is given up as poisoned (no attempt reached an end:
    /// the pipeline panicked, or its worker died — a crash, an OOM kill). Default 3: one crash of an unlucky moment and one retry
    /// after it are forgiven; a job that takes its worker down three times would keep doing so.
    #[arg(long, env = "PHENOMENA_MAX_ATTEMPTS")]
    pub max_attempts: Option<u32>,
    /// Pipeline threads (0 = one per core). Default 0.
    #[arg(long, env = "PHENOMENA_THREADS")]
    pub threads: Option<usize>,
    /// Longest `Prefer: wait=N` honoured, in seconds. Default 60.
    #[arg(long, env = "PHENOMENA_MAX_WAIT_SECS")]
    pub max_wait_secs: Option<u64>,
    /// Seconds running jobs get to finish on shutdown before they are re-queued. Default 30.
    #[arg(long, env = "PHENOMENA_SHUTDOWN_GRACE_SECS")]
    pub shutdown_grace_secs: Option<u64>,
    /// Seconds a client gets to send a request's line and headers (also how long an idle
    /// keep-alive connection stays open); past it the connection is closed without a response.
    /// Default 10: a real client sends its headers in one packet within milliseconds, 10 s covers
    /// a slow mobile link with retransmissions, and a slow-header ("slowloris") client holds a
    /// connection for no longer than that.
    #[arg(long, env = "PHENOMENA_HEADER_READ_TIMEOUT_SECS")]
    pub header_read_timeout_secs: Option<u64>,
    /// Longest pause, in seconds, between two pieces of a request body; past it the request ends
    /// with 408. An idle timeout, not a total: a big upload that keeps flowing is never cut.
    /// Default 30: TCP retransmission back-off on a bad link stays well under it, and a client
    /// trickling its body is cut within 30 s.
    #[arg(long, env = "PHENOMENA_BODY_READ_TIMEOUT_SECS")]
    pub body_read_timeout_secs: Option<u64>,
    /// Slowest average rate, in bytes per second, a request body may arrive at after a first
    /// `body_read_timeout_secs`; slower gets 408 (0 = no floor). Default 1024: a tenth of a
    /// 1990s modem, so no real link is cut, while a client trickling a byte at a time to hold a
    /// connection is cut within about `body_read_timeout_secs`.
    #[arg(long, env = "PHENOMENA_BODY_MIN_BYTES_PER_SEC")]
    pub body_min_bytes_per_sec: Option<u64>,
    /// Most header fields in one request; more get 431. Default 64: browsers send about 15, and
    /// proxies add a few `X-Forwarded-*`/`Via` fields.
    #[arg(long, env = "PHENOMENA_MAX_HEADER_COUNT")]
    pub max_header_count: Option<usize>,
    /// Most bytes of request line plus headers; more get 431. Default 16384 (16 KiB): this API
    /// uses no cookies, so real requests stay under 2 KiB; 16 KiB matches common proxy defaults
    /// (nginx reads headers in 8 KiB buffers) and bounds what each connection can make us hold.
    #[arg(long, env = "PHENOMENA_MAX_HEADER_BYTES")]
    pub max_header_bytes: Option<usize>,
    /// Log format. Default text.
    #[arg(long, env = "PHENOMENA_LOG_FORMAT", value_enum)]
    pub log_format: Option<LogFormat>,
    /// Bearer tokens accepted on every `/v1` and `/ogc` route (comma-separated in the flag and the
    /// environment). Default none: no authentication. Never logged.
    #[arg(long, env = "PHENOMENA_AUTH_TOKENS", value_delimiter = ',')]
    pub auth_tokens: Option<Vec<String>>,
    /// Origins allowed to call the API from a browser (CORS), comma-separated; `*` for any.
    /// Default none: CORS off (the page at `/` is same-origin and needs none).
    #[arg(long, env = "PHENOMENA_CORS_ORIGINS", value_delimiter = ',')]
    pub cors_origins: Option<Vec<String>>,
    /// Object store for blobs and asset records: `file:///path` (a directory, possibly shared by
    /// replicas) or `s3://bucket/prefix` (S3-compatible; credentials, region and endpoint from
    /// the `AWS_*` environment variables). Default: the data directory.
    #[arg(long, env = "PHENOMENA_STORE_URL")]
    pub store_url: Option<String>,
    /// Redis URL (`redis://host:6379/0`): share the queue, job state and progress with other
    /// replicas. Default: none (the embedded job system).
    #[arg(long, env = "PHENOMENA_REDIS_URL")]
    pub redis_url: Option<String>,
    /// Prefix of every Redis key and channel, so deployments can share one Redis. Default
    /// `phenomena`.
    #[arg(long, env = "PHENOMENA_REDIS_PREFIX")]
    pub redis_prefix: Option<String>,
    /// Seconds a worker may go without a heartbeat before another replica takes its job over.
    /// Default 30.
    #[arg(long, env = "PHENOMENA_REDIS_LEASE_SECS")]
    pub redis_lease_secs: Option<u64>,
    /// `api`, `worker` or `both` (needs `--redis-url` unless `both`). Default both.
    #[arg(long, env = "PHENOMENA_ROLE", value_enum)]
    pub role: Option<Role>,
    /// This replica's name in logs, metrics and job records. Default: host name and process id.
    #[arg(long, env = "PHENOMENA_REPLICA_ID")]
    pub replica_id: Option<String>,
}

/// The resolved configuration.
#[derive(Debug, Clone, Serialize)]
pub struct Config {
    pub bind: SocketAddr,
    pub data_dir: PathBuf,
    pub max_body_bytes: usize,
    pub max_input_cells: u64,
    pub max_output_pixels: u64,
    pub max_input_triangles: u64,
    pub map_whole_max_cells: u64,
    pub memory_budget_bytes: u64,
    pub concurrency: usize,
    pub queue_capacity: usize,
    pub job_timeout_secs: u64,
    pub retention_secs: u64,
    pub sweep_interval_secs: u64,
    pub max_attempts: u32,
    pub threads: usize,
    pub max_wait_secs: u64,
    pub shutdown_grace_secs: u64,
    pub header_read_timeout_secs: u64,
    pub body_read_timeout_secs: u64,
    pub body_min_bytes_per_sec: u64,
    pub max_header_count: usize,
    pub max_header_bytes: usize,
    pub log_format: LogFormat,
    /// Accepted bearer tokens; empty = authentication off. Logged as a count only.
    #[serde(serialize_with = "redact_tokens")]
    pub auth_tokens: Vec<String>,
    /// CORS origins; empty = CORS off.
    pub cors_origins: Vec<String>,
    /// Logged without its password (see [`redact_url`]).
    #[serde(serialize_with = "redacted")]
    pub redis_url: Option<String>,
    pub store_url: Option<String>,
    pub redis_prefix: String,
    pub redis_lease_secs: u64,
    pub role: Role,
    pub replica_id: String,
}

/// Serialises a URL without its password (the config is logged at start-up).
fn redacted<S: serde::Serializer>(url: &Option<String>, s: S) -> Result<S::Ok, S::Error> {
    match url {
        Some(u) => s.serialize_some(&redact_url(u)),
        None => s.serialize_none(),
    }
}

/// `redis://user:secret@host/0` → `redis://user:***@host/0`.
pub fn redact_url(u: &str) -> String {
    match (u.find("://"), u.rfind('@')) {
        (Some(scheme), Some(at)) if at > scheme => {
            let userinfo = &u[scheme + 3..at];
            let user = userinfo.split(':').next().unwrap_or("");
            format!("{}{user}:***{}", &u[..scheme + 3], &u[at..])
        }
        _ => u.to_string(),
    }
}

/// The default replica name: host name and process id.
pub fn default_replica_id() -> String {
    let host = std::fs::read_to_string("/etc/hostname")
        .ok()
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "replica".into());
    format!("{host}-{}", std::process::id())
}

/// Serializes the token list as its length: the config is logged at start-up and secrets must
/// never reach the log.
fn redact_tokens<S: serde::Serializer>(t: &[String], s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&format!("<{} token(s) redacted>", t.len()))
}

/// Configuration errors (reported by `main`).
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("config file {path}: {source}")]
    Parse {
        path: PathBuf,
        source: toml::de::Error,
    },
    #[error("{0} must be at least 1")]
    Zero(&'static str),
    #[error("{0}")]
    Invalid(String),
    #[error("--role {0} needs --redis-url (only `both` runs without Redis)")]
    RoleNeedsRedis(&'static str),
}

impl Default for Config {
    fn default() -> Self {
        Self {
            bind: SocketAddr::from(([127, 0, 0, 1], 8080)),
            data_dir: PathBuf::from("./phenomena-data"),
            max_body_bytes: 256 << 20,
            max_input_cells: 8192 * 8192,
            max_output_pixels: 7680 * 4320,
            max_input_triangles: 4_000_000,
            map_whole_max_cells: 2048 * 2048,
            memory_budget_bytes: 768 << 20,
            concurrency: 1,
            queue_capacity: 64,
            job_timeout_secs: 600,
            retention_secs: 7 * 24 * 3600,
            sweep_interval_secs: 300,
            max_attempts: 3,
            threads: 0,
            max_wait_secs: 60,
            shutdown_grace_secs: 30,
            header_read_timeout_secs: 10,
            body_read_timeout_secs: 30,
            body_min_bytes_per_sec: 1024,
            max_header_count: 64,
            max_header_bytes: 16 << 10,
            log_format: LogFormat::Text,
            auth_tokens: Vec::new(),
            cors_origins: Vec::new(),
            redis_url: None,
            store_url: None,
            redis_prefix: "phenomena".into(),
            redis_lease_secs: 30,
            role: Role::Both,
            replica_id: String::new(),
        }
    }
}

impl Config {
    /// Flags/env over the config file over defaults.
    pub fn resolve(args: ServeArgs) -> Result<Self, ConfigError> {
        let file = match &args.config {
            Some(path) => {
                let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
                    path: path.clone(),
                    source,
                })?;
                toml::from_str::<ServeArgs>(&text).map_err(|source| ConfigError::Parse {
                    path: path.clone(),
                    source,
                })?
            }
            None => ServeArgs::default(),
        };
        let d = Config::default();
        macro_rules! pick {
            ($f:ident) => {
                args.$f.or(file.$f).unwrap_or(d.$f)
            };
        }
        let cfg = Config {
            bind: pick!(bind),
            data_dir: args
                .data_dir
                .clone()
                .or(file.data_dir.clone())
                .unwrap_or(d.data_dir.clone()),
            max_body_bytes: pick!(max_body_bytes),
            max_input_cells: pick!(max_input_cells),
            max_output_pixels: pick!(max_output_pixels),
            max_input_triangles: pick!(max_input_triangles),
            map_whole_max_cells: pick!(map_whole_max_cells),
            memory_budget_bytes: pick!(memory_budget_bytes),
            concurrency: pick!(concurrency),
            queue_capacity: pick!(queue_capacity),
            job_timeout_secs: pick!(job_timeout_secs),
            retention_secs: pick!(retention_secs),
            sweep_interval_secs: pick!(sweep_interval_secs),
            max_attempts: pick!(max_attempts),
            threads: pick!(threads),
            max_wait_secs: pick!(max_wait_secs),
            shutdown_grace_secs: pick!(shutdown_grace_secs),
            header_read_timeout_secs: pick!(header_read_timeout_secs),
            body_read_timeout_secs: pick!(body_read_timeout_secs),
            body_min_bytes_per_sec: pick!(body_min_bytes_per_sec),
            max_header_count: pick!(max_header_count),
            max_header_bytes: pick!(max_header_bytes),
            log_format: pick!(log_format),
            auth_tokens: args
                .auth_tokens
                .clone()
                .or(file.auth_tokens.clone())
                .unwrap_or_default(),
            cors_origins: args
                .cors_origins
                .clone()
                .or(file.cors_origins.clone())
                .unwrap_or_default(),
            redis_url: args.redis_url.clone().or(file.redis_url.clone()),
            store_url: args.store_url.clone().or(file.store_url.clone()),
            redis_prefix: args
                .redis_prefix
                .clone()
                .or(file.redis_prefix.clone())
                .unwrap_or(d.redis_prefix.clone()),
            redis_lease_secs: pick!(redis_lease_secs),
            role: pick!(role),
            replica_id: args
                .replica_id
                .clone()
                .or(file.replica_id.clone())
                .unwrap_or_else(default_replica_id),
        };
        if cfg.role != Role::Both && cfg.redis_url.is_none() {
            return Err(ConfigError::RoleNeedsRedis(cfg.role.as_str()));
        }
        if cfg.redis_lease_secs == 0 {
            return Err(ConfigError::Zero("redis_lease_secs"));
        }
        // A short token is guessable; 16 characters is the least a random token should have.
        if cfg
            .auth_tokens
            .iter()
            .any(|t| t.len() < 16 || t.contains(char::is_whitespace))
        {
            return Err(ConfigError::Invalid(
                "auth_tokens: each token needs at least 16 characters and no whitespace".into(),
            ));
        }
        for o in &cfg.cors_origins {
            if o != "*" && axum::http::HeaderValue::from_str(o).is_err() {
                return Err(ConfigError::Invalid(format!(
                    "cors_origins: {o:?} is not an origin"
                )));
            }
        }
        if cfg.concurrency == 0 {
            return Err(ConfigError::Zero("concurrency"));
        }
        // Below 1 MiB no real input could be checked.
        if cfg.memory_budget_bytes < 1 << 20 {
            return Err(ConfigError::Invalid(
                "memory_budget_bytes must be at least 1048576 (1 MiB)".into(),
            ));
        }
        if cfg.max_attempts == 0 {
            return Err(ConfigError::Zero("max_attempts"));
        }
        if cfg.sweep_interval_secs == 0 {
            return Err(ConfigError::Zero("sweep_interval_secs"));
        }
        if cfg.header_read_timeout_secs == 0 {
            return Err(ConfigError::Zero("header_read_timeout_secs"));
        }
        if cfg.body_read_timeout_secs == 0 {
            return Err(ConfigError::Zero("body_read_timeout_secs"));
        }
        if cfg.max_header_count == 0 {
            return Err(ConfigError::Zero("max_header_count"));
        }
        // Below 1 KiB an ordinary request with a bearer token would not fit.
        if cfg.max_header_bytes < 1024 {
            return Err(ConfigError::Invalid(
                "max_header_bytes must be at least 1024".into(),
            ));
        }
        Ok(cfg)
    }

    pub fn jobs(&self) -> crate::jobs::JobsConfig {
        crate::jobs::JobsConfig {
            // An API-only replica runs no jobs.
            concurrency: if self.role == Role::Api {
                0
            } else {
                self.concurrency
            },
            queue_capacity: self.queue_capacity,
            job_timeout: Duration::from_secs(self.job_timeout_secs),
            retention: Duration::from_secs(self.retention_secs),
            sweep_interval: Duration::from_secs(self.sweep_interval_secs),
            max_attempts: self.max_attempts,
            threads: self.threads,
            memory: crate::budget::MemoryBudget::new(self.memory_budget_bytes),
        }
    }

    pub fn limits(&self) -> phenomena_engine::params::Limits {
        phenomena_engine::params::Limits {
            max_input_cells: self.max_input_cells,
            max_output_pixels: self.max_output_pixels,
            max_input_triangles: self.max_input_triangles,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_win_over_file_over_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        std::fs::write(&path, "queue_capacity = 5\nconcurrency = 3\n").unwrap();
        let args = ServeArgs {
            config: Some(path),
            concurrency: Some(2),
            ..Default::default()
        };
        let c = Config::resolve(args).unwrap();
        assert_eq!(c.concurrency, 2);
        assert_eq!(c.queue_capacity, 5);
        assert_eq!(c.job_timeout_secs, 600);
        assert_eq!(c.role, Role::Both);
        assert!(!c.replica_id.is_empty());
    }

    #[test]
    fn roles_other_than_both_need_redis() {
        let args = ServeArgs {
            role: Some(Role::Worker),
            ..Default::default()
        };
        assert!(matches!(
            Config::resolve(args),
            Err(ConfigError::RoleNeedsRedis("worker"))
        ));
        let args = ServeArgs {
            role: Some(Role::Api),
            redis_url: Some("redis://127.0.0.1/".into()),
            ..Default::default()
        };
        let c = Config::resolve(args).unwrap();
        assert_eq!(c.jobs().concurrency, 0);
    }

    #[test]
    fn connection_limits_have_floors() {
        let c = Config::resolve(ServeArgs::default()).unwrap();
        assert_eq!(
            (
                c.header_read_timeout_secs,
                c.body_read_timeout_secs,
                c.max_header_count
            ),
            (10, 30, 64)
        );
        for args in [
            ServeArgs {
                header_read_timeout_secs: Some(0),
                ..Default::default()
            },
            ServeArgs {
                body_read_timeout_secs: Some(0),
                ..Default::default()
            },
            ServeArgs {
                max_header_count: Some(0),
                ..Default::default()
            },
            ServeArgs {
                max_header_bytes: Some(512),
                ..Default::default()
            },
        ] {
            assert!(Config::resolve(args).is_err());
        }
    }

    #[test]
    fn redis_passwords_are_not_logged() {
        assert_eq!(
            redact_url("redis://u:secret@h:6379/2"),
            "redis://u:***@h:6379/2"
        );
        assert_eq!(redact_url("redis://h:6379/2"), "redis://h:6379/2");
    }

    #[test]
    fn unknown_file_keys_are_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        std::fs::write(&path, "queue_capasity = 5\n").unwrap();
        let args = ServeArgs {
            config: Some(path),
            ..Default::default()
        };
        assert!(matches!(
            Config::resolve(args),
            Err(ConfigError::Parse { .. })
        ));
    }
}
