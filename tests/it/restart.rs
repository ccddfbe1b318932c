//! Crash recovery: `kill -9` the real server binary mid-job, start it again on the same data
//! directory, and the job completes with the same bytes the CLI produces for the same request.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

pub const BIN: &str = env!("CARGO_BIN_EXE_phenomena");

/// Starts `phenomena serve` on an ephemeral port; returns the child and its address (read from
/// the JSON log line "listening").
fn spawn_server(data_dir: &std::path::Path) -> (Child, String) {
    spawn_server_with(data_dir, &["--threads", "2"])
}

/// Like [`spawn_server`] with more flags.
pub fn spawn_server_with(data_dir: &std::path::Path, extra: &[&str]) -> (Child, String) {
    spawn_server_env(data_dir, extra, &[])
}

/// Like [`spawn_server_with`] with environment variables.
pub fn spawn_server_env(
    data_dir: &std::path::Path,
    extra: &[&str],
    env: &[(&str, &str)],
) -> (Child, String) {
    let mut child = Command::new(BIN)
        .args(["serve", "--bind", "127.0.0.1:0", "--log-format", "json"])
        .args(extra)
        .arg("--data-dir")
        .arg(data_dir)
        .env("PHENOMENA_LOG", "info")
        .envs(env.iter().copied())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut sent = false;
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            if !sent {
                if let Ok(v) = serde_json::from_str::<Value>(&line) {
                    if v["fields"]["message"] == "listening" {
                        let _ = tx.send(v["fields"]["addr"].as_str().unwrap().to_string());
                        sent = true;
                    }
                }
            }
        }
    });
    let addr = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("server did not start");
    (child, addr)
}

/// A 1536² synthetic terrain (sums of sines), big enough that a job runs for a while.
pub fn synthetic_npy() -> Vec<u8> {
    synthetic_npy_of(1536)
}

/// A synthetic terrain of n² cells.
pub fn synthetic_npy_of(n: usize) -> Vec<u8> {
    let mut data = Vec::with_capacity(n * n);
    for r in 0..n {
        for c in 0..n {
            let (x, y) = (c as f32 / n as f32, r as f32 / n as f32);
            let h = 800.0 * (x * 7.0).sin() * (y * 5.0).cos()
                + 300.0 * (x * 23.0 + y * 17.0).sin()
                + 90.0 * (x * 71.0).cos() * (y * 59.0).sin()
                + 1200.0;
            data.push(h);
        }
    }
    crate::common::npy_f32(&[n as u64, n as u64], data)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kill_9_mid_job_then_restart_completes_the_job() {
    let dir = tempfile::tempdir().unwrap();
    let input = synthetic_npy();
    let params = json!({"width": 1280, "height": 720, "samples": 16, "cell_size": 30.0, "mesh_max_vertices": 20000});
    let client = reqwest::Client::new();

    let (mut child, addr) = spawn_server(dir.path());
    let form = reqwest::multipart::Form::new()
        .text("params", params.to_string())
        .part(
            "dem",
            reqwest::multipart::Part::bytes(input.clone()).file_name("terrain.npy"),
        );
    let resp = client
        .post(format!("http://{addr}/v1/snow-terrain"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 202);
    let job: Value = resp.json().await.unwrap();
    let id = job["id"].as_str().unwrap().to_string();

    // Wait until the job is running and has made progress, then kill the process outright.
    let t0 = Instant::now();
    loop {
        let j: Value = client
            .get(format!("http://{addr}/v1/jobs/{id}"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if j["status"] == "running" && j["progress"].as_f64().unwrap() > 0.0 {
            break;
        }
        assert_ne!(
            j["status"], "succeeded",
            "the job finished before it could be killed; make it bigger"
        );
        assert!(t0.elapsed() < Duration::from_secs(60));
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();

    let (mut child, addr) = spawn_server(dir.path());
    let done: Value = loop {
        let j: Value = client
            .get(format!("http://{addr}/v1/jobs/{id}"))
            .header("prefer", "wait=30")
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if j["status"] != "queued" && j["status"] != "running" {
            break j;
        }
        assert!(t0.elapsed() < Duration::from_secs(300));
    };
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(
        done["attempts"],
        json!(2),
        "the job ran again after the crash"
    );

    assert_same_as_cli(&client, &addr, &id, dir.path(), &input, &params).await;
    child.kill().unwrap();
    child.wait().unwrap();
}

/// Waits until job `id` is running with progress (on attempt `attempt`), then `kill -9`s the
/// server: the worker dies mid-job.
async fn kill_while_running(
    client: &reqwest::Client,
    addr: &str,
    id: &str,
    attempt: u64,
    child: &mut Child,
) {
    let t0 = Instant::now();
    loop {
        let j: Value = client
            .get(format!("http://{addr}/v1/jobs/{id}"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if j["status"] == "running" && j["progress"].as_f64().unwrap() > 0.0 {
            assert_eq!(j["attempts"], json!(attempt), "{j}");
            break;
        }
        assert!(
            j["status"] == "queued" || j["status"] == "running",
            "the job ended before it could be killed: {j}"
        );
        assert!(t0.elapsed() < Duration::from_secs(120), "{j}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
}

/// Poison jobs (issue 20): a job whose worker dies in every attempt is started `--max-attempts`
/// times, then ends `failed` with the `poisoned` problem type instead of being retried forever;
/// the metric counts it, the same request is a new job, and the server keeps running others.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_whose_worker_dies_in_every_attempt_ends_poisoned() {
    let dir = tempfile::tempdir().unwrap();
    let input = synthetic_npy();
    let params = json!({"width": 1280, "height": 720, "samples": 16, "cell_size": 30.0, "mesh_max_vertices": 20000});
    let flags = ["--threads", "2", "--max-attempts", "2"];
    let client = reqwest::Client::new();
    let submit = |addr: String| {
        let client = client.clone();
        let input = input.clone();
        let params = params.clone();
        async move {
            let form = reqwest::multipart::Form::new()
                .text("params", params.to_string())
                .part(
                    "dem",
                    reqwest::multipart::Part::bytes(input).file_name("terrain.npy"),
                );
            let resp = client
                .post(format!("http://{addr}/v1/snow-terrain"))
                .multipart(form)
                .send()
                .await
                .unwrap();
            assert_eq!(resp.status().as_u16(), 202);
            let job: Value = resp.json().await.unwrap();
            job["id"].as_str().unwrap().to_string()
        }
    };

    let (mut child, addr) = spawn_server_with(dir.path(), &flags);
    let id = submit(addr.clone()).await;
    kill_while_running(&client, &addr, &id, 1, &mut child).await;
    // The restarted server re-queues it and runs it a second time; its worker dies again.
    let (mut child, addr) = spawn_server_with(dir.path(), &flags);
    kill_while_running(&client, &addr, &id, 2, &mut child).await;

    // The third start would be over the limit: the job is given up.
    let (mut child, addr) = spawn_server_with(dir.path(), &flags);
    let done = wait_ended(&client, &addr, &id, 10, 60).await;
    assert_eq!(done["status"], "failed", "{done}");
    assert_eq!(
        done["error"]["type"], "https://phenomena.dev/problems/poisoned",
        "{done}"
    );
    assert_eq!(
        done["attempts"],
        json!(2),
        "not started a third time: {done}"
    );
    assert!(
        done["outputs"].as_array().is_none_or(|o| o.is_empty()),
        "{done}"
    );
    let metrics = client
        .get(format!("http://{addr}/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        metrics.contains("phenomena_jobs_poisoned_total{pipeline=\"snow-terrain\"} 1"),
        "{metrics}"
    );

    // The server still runs work: the same request is a new job (the poisoned one is not
    // reused), and it succeeds when nothing kills its worker.
    let again = submit(addr.clone()).await;
    assert_ne!(again, id);
    let j = wait_ended(&client, &addr, &again, 30, 300).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    assert_eq!(j["attempts"], json!(1), "{j}");
    child.kill().unwrap();
    child.wait().unwrap();
}

/// The job's outputs equal an offline CLI run of the same snow-terrain request.
pub async fn assert_same_as_cli(
    client: &reqwest::Client,
    addr: &str,
    id: &str,
    scratch: &std::path::Path,
    input: &[u8],
    params: &Value,
) {
    let cli_in = scratch.join("cli-input.npy");
    std::fs::write(&cli_in, input).unwrap();
    let params_file = scratch.join("params.json");
    std::fs::write(&params_file, params.to_string()).unwrap();
    let out_dir = scratch.join("cli-out");
    let status = Command::new(BIN)
        .args(["render", "snow-terrain", "--quiet", "--input"])
        .arg(&cli_in)
        .arg("--params")
        .arg(&params_file)
        .arg("--out")
        .arg(&out_dir)
        .status()
        .unwrap();
    assert!(status.success());
    for name in [
        "render.png",
        "snow_cover.tif",
        "descriptor.png",
        "terrain.glb",
    ] {
        let served = client
            .get(format!("http://{addr}/v1/jobs/{id}/outputs/{name}"))
            .send()
            .await
            .unwrap()
            .bytes()
            .await
            .unwrap();
        let offline = std::fs::read(out_dir.join(name)).unwrap();
        assert!(
            served.as_ref() == offline.as_slice(),
            "{name} differs between the served job and the CLI"
        );
    }
}

/// Polls `GET /v1/jobs/{id}` (long-polling `wait` seconds a request) until the job is neither
/// queued nor running, and returns its record; fails after `limit` seconds.
async fn wait_ended(
    client: &reqwest::Client,
    addr: &str,
    id: &str,
    wait: u64,
    limit: u64,
) -> Value {
    let t0 = Instant::now();
    loop {
        let j: Value = client
            .get(format!("http://{addr}/v1/jobs/{id}"))
            .header("prefer", format!("wait={wait}"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if j["status"] != "queued" && j["status"] != "running" {
            return j;
        }
        assert!(t0.elapsed() < Duration::from_secs(limit), "{j}");
    }
}
