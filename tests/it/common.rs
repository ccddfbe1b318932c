//! Test harness: a server on an ephemeral port over a temporary data directory, and a test-only
//! pipeline (`sleepy`) that sleeps in stages so job mechanics can be observed. `sleepy` exists
//! only in this test binary; it never ships.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use phenomena::config::Config;
use phenomena::pipeline_set::{Admitted, EnginePipelines, PipelineSet, RunError, Validated};
use phenomena_engine::{Control, InputError, Output, ParamError};
use serde_json::{json, Value};

/// Sleeps `stages` × `ms` milliseconds, checking for cancellation every 5 ms; outputs
/// `echo.txt` (the input bytes) and `params.json`. Inputs starting with `corrupt` are rejected as
/// corrupt, `panic: true` panics inside the pipeline.
pub struct Sleepy;

#[derive(serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct SleepyParams {
    #[serde(default = "one")]
    stages: u32,
    #[serde(default)]
    ms: u64,
    #[serde(default)]
    panic: bool,
}
fn one() -> u32 {
    1
}

impl PipelineSet for Sleepy {
    fn names(&self) -> Vec<&'static str> {
        vec!["sleepy"]
    }
    fn input_part(&self, name: &str) -> Option<&'static str> {
        (name == "sleepy").then_some("data")
    }
    fn params(&self, _: &str, raw: &Value) -> Result<Validated, ParamError> {
        let p: SleepyParams = phenomena_engine::params::deserialize_params(raw)?;
        if p.stages > 100 {
            return Err(ParamError::new("stages", "must be at most 100"));
        }
        Ok(Validated::json(serde_json::to_value(p).unwrap()))
    }
    fn check_input(
        &self,
        _: &str,
        _: &Validated,
        input: &[u8],
        _: Option<&str>,
    ) -> Result<(), InputError> {
        if input.starts_with(b"corrupt") {
            return Err(InputError::Corrupt {
                format: "sleepy",
                detail: "the bytes say so".into(),
            });
        }
        Ok(())
    }
    fn run(
        &self,
        _: &str,
        params: &Value,
        input: &[u8],
        _: Option<&str>,
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError> {
        let p: SleepyParams = serde_json::from_value(params.clone()).unwrap();
        if p.panic {
            panic!("sleepy was asked to panic");
        }
        for s in 0..p.stages {
            let name = format!("stage{s}");
            ctl.progress(&name, s as f32 / p.stages as f32);
            let mut left = p.ms;
            while left > 0 {
                ctl.checkpoint()?;
                let step = left.min(5);
                std::thread::sleep(Duration::from_millis(step));
                left -= step;
            }
        }
        Ok(vec![
            Output::new("echo.txt", "text/plain", input.to_vec()),
            Output::new(
                "params.json",
                "application/json",
                params.to_string().into_bytes(),
            ),
        ])
    }
}

/// Both the engine's pipelines and `sleepy`.
pub struct WithSleepy(pub EnginePipelines);

impl PipelineSet for WithSleepy {
    fn names(&self) -> Vec<&'static str> {
        let mut n = self.0.names();
        n.push("sleepy");
        n
    }
    fn input_part(&self, name: &str) -> Option<&'static str> {
        Sleepy.input_part(name).or_else(|| self.0.input_part(name))
    }
    fn params(&self, name: &str, raw: &Value) -> Result<Validated, ParamError> {
        if name == "sleepy" {
            Sleepy.params(name, raw)
        } else {
            self.0.params(name, raw)
        }
    }
    fn check_input(
        &self,
        name: &str,
        p: &Validated,
        input: &[u8],
        f: Option<&str>,
    ) -> Result<(), InputError> {
        if name == "sleepy" {
            Sleepy.check_input(name, p, input, f)
        } else {
            self.0.check_input(name, p, input, f)
        }
    }
    fn run(
        &self,
        name: &str,
        p: &Value,
        input: &[u8],
        f: Option<&str>,
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError> {
        if name == "sleepy" {
            Sleepy.run(name, p, input, f, ctl)
        } else {
            self.0.run(name, p, input, f, ctl)
        }
    }
    fn run_with_named_inputs(
        &self,
        name: &str,
        p: &Value,
        input: &[u8],
        f: Option<&str>,
        aux: &[(String, Vec<u8>)],
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError> {
        if name == "sleepy" {
            Sleepy.run(name, p, input, f, ctl)
        } else {
            self.0.run_with_named_inputs(name, p, input, f, aux, ctl)
        }
    }
    fn describe_input(
        &self,
        name: &str,
        p: &Validated,
        input: &[u8],
        f: Option<&str>,
    ) -> Result<Value, InputError> {
        if name == "sleepy" {
            Sleepy.describe_input(name, p, input, f)
        } else {
            self.0.describe_input(name, p, input, f)
        }
    }
    fn aux_parts(&self, name: &str) -> &'static [&'static str] {
        self.0.aux_parts(name)
    }
    fn outputs(&self, name: &str) -> &'static [phenomena_engine::registry::OutputKind] {
        self.0.outputs(name)
    }
    fn admit(
        &self,
        name: &str,
        p: &Validated,
        input: &[u8],
        f: Option<&str>,
        aux: &[(String, Vec<u8>)],
        decode_bytes: Option<u64>,
    ) -> Result<Admitted, (Option<&'static str>, InputError)> {
        if name == "sleepy" {
            Sleepy.admit(name, p, input, f, aux, decode_bytes)
        } else {
            self.0.admit(name, p, input, f, aux, decode_bytes)
        }
    }
    fn run_cost(&self, name: &str, units: u64, pixels: u64, with_aux: bool) -> u64 {
        self.0.run_cost(name, units, pixels, with_aux)
    }
    fn decode_cost(&self, name: &str, with_extra_input: bool) -> u64 {
        self.0.decode_cost(name, with_extra_input)
    }
    fn check_with_named_inputs(
        &self,
        name: &str,
        p: &Validated,
        input: &[u8],
        f: Option<&str>,
        aux: &[(String, Vec<u8>)],
    ) -> Result<(), (Option<&'static str>, InputError)> {
        if name == "sleepy" {
            Sleepy.check_input(name, p, input, f).map_err(|e| (None, e))
        } else {
            self.0.check_with_named_inputs(name, p, input, f, aux)
        }
    }
}

/// Which job system a test server runs on. The job suites run on both.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    Embedded,
    /// The Redis at `PHENOMENA_TEST_REDIS_URL` (default `redis://127.0.0.1:6379/`), under a key
    /// prefix of its own, deleted when the test ends.
    Redis,
}

/// The Redis the tests use.
pub fn redis_url() -> String {
    std::env::var("PHENOMENA_TEST_REDIS_URL").unwrap_or_else(|_| "redis://127.0.0.1:6379/".into())
}

/// A unique Redis key prefix; its keys are deleted when the guard drops.
pub struct RedisPrefix(pub String);

impl RedisPrefix {
    pub fn new() -> Self {
        RedisPrefix(format!(
            "phenomena-test-{}",
            hex::encode(rand::random::<[u8; 6]>())
        ))
    }
}

impl Drop for RedisPrefix {
    fn drop(&mut self) {
        let Ok(client) = redis::Client::open(redis_url()) else {
            return;
        };
        let Ok(mut con) = client.get_connection() else {
            return;
        };
        let keys: Vec<String> = redis::cmd("KEYS")
            .arg(format!("{}:*", self.0))
            .query(&mut con)
            .unwrap_or_default();
        if !keys.is_empty() {
            let _: Result<(), _> = redis::cmd("DEL").arg(keys).query(&mut con);
        }
    }
}

/// What a stopped server leaves for the next one: its data directory and, with Redis, its keys.
pub struct Stopped {
    pub dir: tempfile::TempDir,
    backend: Backend,
    redis: Option<RedisPrefix>,
}

/// A running server; dropped at the end of the test (the runtime ends with the test).
pub struct Server {
    pub addr: SocketAddr,
    pub client: reqwest::Client,
    pub dir: tempfile::TempDir,
    pub shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    pub handle: Option<tokio::task::JoinHandle<std::io::Result<()>>>,
    pub backend: Backend,
    redis: Option<RedisPrefix>,
}

pub fn test_config(dir: &std::path::Path) -> Config {
    Config {
        data_dir: dir.to_path_buf(),
        threads: 2,
        max_wait_secs: 30,
        shutdown_grace_secs: 5,
        ..Config::default()
    }
}

impl Server {
    /// Starts a server with `sleepy` and the engine's pipelines on the embedded job system;
    /// `tweak` adjusts the config.
    pub async fn start(tweak: impl FnOnce(&mut Config)) -> Server {
        Self::start_on(Backend::Embedded, tweak).await
    }

    /// Like [`Server::start`] on the given job system.
    pub async fn start_on(backend: Backend, tweak: impl FnOnce(&mut Config)) -> Server {
        let dir = tempfile::tempdir().unwrap();
        let redis = (backend == Backend::Redis).then(RedisPrefix::new);
        Self::start_in(
            Stopped {
                dir,
                backend,
                redis,
            },
            tweak,
        )
        .await
    }

    /// Starts a server on what a stopped one left (a restart).
    pub async fn start_in(left: Stopped, tweak: impl FnOnce(&mut Config)) -> Server {
        let Stopped {
            dir,
            backend,
            redis,
        } = left;
        let mut cfg = test_config(dir.path());
        if let Some(p) = &redis {
            cfg.redis_url = Some(redis_url());
            cfg.redis_prefix = p.0.clone();
        }
        tweak(&mut cfg);
        let limits = cfg.limits();
        let state = phenomena::state_with(cfg, Arc::new(WithSleepy(EnginePipelines { limits })))
            .await
            .unwrap();
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let handle = tokio::spawn(phenomena::run(listener, state, async move {
            let _ = rx.await;
        }));
        Server {
            addr,
            client: reqwest::Client::new(),
            dir,
            shutdown: Some(tx),
            handle: Some(handle),
            backend,
            redis,
        }
    }

    /// The ids on the Redis backend's dead-letter list (empty on the embedded backend).
    pub fn dead_letters(&self) -> Vec<String> {
        let Some(p) = &self.redis else {
            return Vec::new();
        };
        let client = redis::Client::open(redis_url()).unwrap();
        let mut con = client.get_connection().unwrap();
        redis::cmd("LRANGE")
            .arg(format!("{}:dead", p.0))
            .arg(0)
            .arg(-1)
            .query(&mut con)
            .unwrap()
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{}", self.addr, path)
    }

    /// Stops the server gracefully and returns what it leaves for a restart.
    pub async fn stop(mut self) -> Stopped {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if let Some(h) = self.handle.take() {
            let _ = tokio::time::timeout(Duration::from_secs(20), h).await;
        }
        Stopped {
            dir: self.dir,
            backend: self.backend,
            redis: self.redis,
        }
    }

    /// Submits a multipart job.
    pub async fn submit(
        &self,
        pipeline: &str,
        part: &str,
        params: Value,
        input: Vec<u8>,
        filename: &str,
    ) -> reqwest::Response {
        let form = reqwest::multipart::Form::new()
            .text("params", params.to_string())
            .part(
                part.to_string(),
                reqwest::multipart::Part::bytes(input).file_name(filename.to_string()),
            );
        self.client
            .post(self.url(&format!("/v1/{pipeline}")))
            .multipart(form)
            .send()
            .await
            .unwrap()
    }

    pub async fn sleepy(&self, params: Value, input: &[u8]) -> reqwest::Response {
        self.submit("sleepy", "data", params, input.to_vec(), "x.bin")
            .await
    }

    pub async fn job(&self, id: &str) -> Value {
        self.get_json(&format!("/v1/jobs/{id}")).await
    }

    /// `GET path` as JSON (any status).
    pub async fn get_json(&self, path: &str) -> Value {
        self.client
            .get(self.url(path))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap()
    }

    /// Polls until the job is running (5 s at most).
    pub async fn wait_running(&self, id: &str) {
        for _ in 0..500 {
            if self.job(id).await["status"] == "running" {
                return;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        panic!("job {id} did not start");
    }

    /// Polls until the job is finished (30 s at most).
    pub async fn wait_done(&self, id: &str) -> Value {
        for _ in 0..3000 {
            let j = self.job(id).await;
            if ["succeeded", "failed", "canceled"].contains(&j["status"].as_str().unwrap()) {
                return j;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        panic!("job {id} did not finish");
    }
}

/// Asserts a problem+json response with this status and `type` suffix; returns the body.
pub async fn problem(resp: reqwest::Response, status: u16, kind: &str) -> Value {
    assert_eq!(resp.status().as_u16(), status, "status");
    assert_eq!(
        resp.headers()["content-type"].to_str().unwrap(),
        "application/problem+json"
    );
    let body: Value = resp.json().await.unwrap();
    assert_eq!(
        body["type"],
        json!(format!("https://phenomena.dev/problems/{kind}")),
        "{body}"
    );
    assert_eq!(body["status"], json!(status));
    assert!(!body["detail"].as_str().unwrap().is_empty());
    body
}

/// Path of a file in the shared real-data directory.
pub fn data(rel: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(rel)
}

/// A float32 NumPy `.npy` file of `shape` (C order).
pub fn npy_f32(shape: &[u64], data: Vec<f32>) -> Vec<u8> {
    use npyz::WriterBuilder;
    let mut out = Vec::new();
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(shape)
        .writer(&mut out)
        .begin_nd()
        .unwrap();
    w.extend(data).unwrap();
    w.finish().unwrap();
    out
}

/// Runs the enclosed tests once per job backend, as `mod embedded` and `mod on_redis`; in each,
/// `start(tweak)` starts a server on that backend. The same assertions hold for both.
#[macro_export]
macro_rules! on_each_backend {
    ($($item:item)*) => {
        mod embedded {
            #[allow(unused_imports)]
            use super::*;
            #[allow(dead_code)]
            async fn start(
                tweak: impl FnOnce(&mut phenomena::config::Config),
            ) -> $crate::common::Server {
                $crate::common::Server::start_on($crate::common::Backend::Embedded, tweak).await
            }
            $($item)*
        }
        mod on_redis {
            #[allow(unused_imports)]
            use super::*;
            #[allow(dead_code)]
            async fn start(
                tweak: impl FnOnce(&mut phenomena::config::Config),
            ) -> $crate::common::Server {
                $crate::common::Server::start_on($crate::common::Backend::Redis, tweak).await
            }
            $($item)*
        }
    };
}

/// A loopback port free at the time of asking (for a helper process to listen on).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// Waits until something accepts connections on loopback `port`; panics naming `what` after
/// `limit`.
pub fn wait_for_port(port: u16, limit: std::time::Duration, what: &str) {
    let t0 = std::time::Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(t0.elapsed() < limit, "{what} did not start");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// Files below `dir`, recursively (0 if it does not exist).
pub fn count_files(dir: &std::path::Path) -> usize {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| {
                    if e.path().is_dir() {
                        count_files(&e.path())
                    } else {
                        1
                    }
                })
                .sum()
        })
        .unwrap_or(0)
}
