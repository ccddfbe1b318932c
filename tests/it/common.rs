//! Test harness: a server on an ephemeral port over a temporary data directory, and a test-only
//! pipeline (`sleepy`) that sleeps in stages so job mechanics can be observed. `sleepy` exists
//! only in this test binary; it never ships.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use phenomena::config::Config;
use phenomena::pipelines::{EnginePipelines, PipelineSet, RunError};
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
    fn params(&self, _: &str, raw: &Value) -> Result<Value, ParamError> {
        let p: SleepyParams = phenomena_engine::pipeline::deserialize_params(raw)?;
        if p.stages > 100 {
            return Err(ParamError::new("stages", "must be at most 100"));
        }
        Ok(serde_json::to_value(p).unwrap())
    }
    fn check_input(
        &self,
        _: &str,
        _: &Value,
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
    fn params(&self, name: &str, raw: &Value) -> Result<Value, ParamError> {
        if name == "sleepy" {
            Sleepy.params(name, raw)
        } else {
            self.0.params(name, raw)
        }
    }
    fn check_input(
        &self,
        name: &str,
        p: &Value,
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
    fn run_with_aux(
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
            self.0.run_with_aux(name, p, input, f, aux, ctl)
        }
    }
    fn describe_input(
        &self,
        name: &str,
        p: &Value,
        input: &[u8],
        f: Option<&str>,
    ) -> Result<Value, InputError> {
        if name == "sleepy" {
            Sleepy.describe_input(name, p, input, f)
        } else {
            self.0.describe_input(name, p, input, f)
        }
    }
}

/// A running server; dropped at the end of the test (the runtime ends with the test).
pub struct Server {
    pub addr: SocketAddr,
    pub client: reqwest::Client,
    pub dir: tempfile::TempDir,
    pub shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    pub handle: Option<tokio::task::JoinHandle<std::io::Result<()>>>,
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
    /// Starts a server with `sleepy` and the engine's pipelines; `tweak` adjusts the config.
    pub async fn start(tweak: impl FnOnce(&mut Config)) -> Server {
        let dir = tempfile::tempdir().unwrap();
        Self::start_in(dir, tweak).await
    }

    pub async fn start_in(dir: tempfile::TempDir, tweak: impl FnOnce(&mut Config)) -> Server {
        let mut cfg = test_config(dir.path());
        tweak(&mut cfg);
        let limits = cfg.limits();
        let state =
            phenomena::state_with(cfg, Arc::new(WithSleepy(EnginePipelines { limits }))).unwrap();
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
        }
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{}", self.addr, path)
    }

    /// Stops the server gracefully and returns its data directory.
    pub async fn stop(mut self) -> tempfile::TempDir {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if let Some(h) = self.handle.take() {
            let _ = tokio::time::timeout(Duration::from_secs(20), h).await;
        }
        self.dir
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
