//! Scale-out with real processes: `phenomena serve` replicas sharing one Redis and one store
//! directory. An API replica takes the jobs, two worker replicas run them; one worker is killed
//! with SIGKILL mid-job and the other finishes its job with the CLI's bytes; SSE on the API
//! replica follows the job throughout; a Redis restart during idle time is survived.
//!
//! Needs a Redis (`PHENOMENA_TEST_REDIS_URL`, default `redis://127.0.0.1:6379/`; `.ci/run` starts
//! one) and, for the restart test, the `redis-server` binary.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use serde_json::{json, Value};

use crate::common::{redis_url, RedisPrefix};
use crate::restart::{
    assert_same_as_cli, spawn_server_env, spawn_server_with, synthetic_npy, synthetic_npy_of,
};

/// One replica process; killed when dropped.
pub struct Replica {
    pub child: Child,
    pub addr: String,
    pub name: String,
}

impl Replica {
    pub fn spawn(dir: &std::path::Path, redis: &str, prefix: &str, role: &str, name: &str) -> Self {
        Self::spawn_env(dir, redis, prefix, role, name, &[], &[])
    }

    /// Like [`Replica::spawn`] with more flags and environment variables.
    pub fn spawn_env(
        dir: &std::path::Path,
        redis: &str,
        prefix: &str,
        role: &str,
        name: &str,
        extra: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let mut args = vec![
            "--threads",
            "1",
            "--redis-url",
            redis,
            "--redis-prefix",
            prefix,
            "--redis-lease-secs",
            "3",
            "--role",
            role,
            "--replica-id",
            name,
            "--sweep-interval-secs",
            "3600",
        ];
        args.extend_from_slice(extra);
        let (child, addr) = spawn_server_env(dir, &args, env);
        Replica {
            child,
            addr,
            name: name.to_string(),
        }
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }
}

impl Drop for Replica {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub async fn submit(c: &reqwest::Client, r: &Replica, input: &[u8], params: &Value) -> Value {
    submit_to(c, &r.url("/v1/snow-terrain"), input, params).await
}

/// Submits a snow-terrain job (multipart, `dem` part) to `url`; asserts 202; returns the job.
pub async fn submit_to(c: &reqwest::Client, url: &str, input: &[u8], params: &Value) -> Value {
    let form = reqwest::multipart::Form::new()
        .text("params", params.to_string())
        .part(
            "dem",
            reqwest::multipart::Part::bytes(input.to_vec()).file_name("terrain.npy"),
        );
    let resp = c.post(url).multipart(form).send().await.unwrap();
    assert_eq!(resp.status().as_u16(), 202);
    resp.json().await.unwrap()
}

async fn job(c: &reqwest::Client, r: &Replica, id: &str) -> Value {
    c.get(r.url(&format!("/v1/jobs/{id}")))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap()
}

/// Waits (bounded) until the job has ended; returns it.
pub async fn wait_done(c: &reqwest::Client, r: &Replica, id: &str, limit: Duration) -> Value {
    let t0 = Instant::now();
    loop {
        let j: Value = c
            .get(r.url(&format!("/v1/jobs/{id}")))
            .header("prefer", "wait=10")
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if j["status"] != "queued" && j["status"] != "running" {
            return j;
        }
        assert!(t0.elapsed() < limit, "job {id} did not finish: {j}");
    }
}

/// Reads a job's SSE stream to its end; returns (event, data) pairs.
pub async fn sse(c: reqwest::Client, url: String) -> Vec<(String, Value)> {
    let resp = c.get(url).send().await.unwrap();
    assert_eq!(resp.status().as_u16(), 200);
    let mut body = resp.bytes_stream();
    let mut buf = String::new();
    let mut events = Vec::new();
    while let Some(chunk) = body.next().await {
        buf.push_str(&String::from_utf8_lossy(&chunk.unwrap()));
        while let Some(end) = buf.find("\n\n") {
            let block: String = buf.drain(..end + 2).collect();
            let mut event = String::new();
            let mut data = String::new();
            for line in block.lines() {
                if let Some(e) = line.strip_prefix("event:") {
                    event = e.trim().to_string();
                } else if let Some(d) = line.strip_prefix("data:") {
                    data.push_str(d.trim());
                }
            }
            if !event.is_empty() {
                let done = event == "done";
                events.push((event, serde_json::from_str(&data).unwrap_or(Value::Null)));
                if done {
                    return events;
                }
            }
        }
    }
    events
}

fn metric(text: &str, name: &str) -> f64 {
    text.lines()
        .find(|l| l.starts_with(name))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.0)
}

/// Poison jobs on Redis (issue 20): a worker dies mid-job; the replica that takes the job over
/// finds it already started `--max-attempts` (here 1) times, so the job ends `failed` as
/// poisoned, its id goes on the dead-letter list, and that replica goes on running other jobs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_whose_worker_dies_is_poisoned_and_dead_lettered() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = RedisPrefix::new();
    let redis = redis_url();
    let max = ["--max-attempts", "1"];
    let api = Replica::spawn_env(dir.path(), &redis, &prefix.0, "api", "api-1", &max, &[]);
    let mut first = Replica::spawn_env(
        dir.path(),
        &redis,
        &prefix.0,
        "worker",
        "worker-1",
        &max,
        &[],
    );
    let c = reqwest::Client::new();

    let input = synthetic_npy();
    let params = json!({"width": 1280, "height": 720, "samples": 16, "cell_size": 30.0, "mesh_max_vertices": 20000});
    let long = submit(&c, &api, &input, &params).await;
    let id = long["id"].as_str().unwrap().to_string();
    let t0 = Instant::now();
    loop {
        let j = job(&c, &api, &id).await;
        if j["status"] == "running" && j["progress"].as_f64().unwrap() > 0.0 {
            break;
        }
        assert!(
            j["status"] == "queued" || j["status"] == "running",
            "the job ended before the kill: {j}"
        );
        assert!(t0.elapsed() < Duration::from_secs(120), "{j}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    first.child.kill().unwrap(); // SIGKILL
    first.child.wait().unwrap();

    // A second worker takes the orphaned entry over once its lease (3 s) runs out.
    let second = Replica::spawn_env(
        dir.path(),
        &redis,
        &prefix.0,
        "worker",
        "worker-2",
        &max,
        &[],
    );
    let done = wait_done(&c, &api, &id, Duration::from_secs(120)).await;
    assert_eq!(done["status"], "failed", "{done}");
    assert_eq!(
        done["error"]["type"], "https://phenomena.dev/problems/poisoned",
        "{done}"
    );
    assert_eq!(done["attempts"], json!(1), "{done}");
    let m = c
        .get(second.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert_eq!(
        metric(
            &m,
            "phenomena_jobs_poisoned_total{pipeline=\"snow-terrain\"}"
        ),
        1.0,
        "{m}"
    );
    let client = redis::Client::open(redis.as_str()).unwrap();
    let mut con = client.get_connection().unwrap();
    let dead: Vec<String> = redis::cmd("LRANGE")
        .arg(format!("{}:dead", prefix.0))
        .arg(0)
        .arg(-1)
        .query(&mut con)
        .unwrap();
    assert_eq!(dead, vec![id.clone()]);
    let running: usize = redis::cmd("HLEN")
        .arg(format!("{}:running", prefix.0))
        .query(&mut con)
        .unwrap();
    assert_eq!(running, 0, "the poisoned job holds no running slot");

    // The replica that poisoned it runs other work.
    let small = synthetic_npy_of(96);
    let p = json!({"width": 64, "height": 48, "samples": 1, "cell_size": 30.0});
    let ok = submit(&c, &api, &small, &p).await;
    let ok = wait_done(
        &c,
        &api,
        ok["id"].as_str().unwrap(),
        Duration::from_secs(120),
    )
    .await;
    assert_eq!(ok["status"], "succeeded", "{ok}");
    assert_eq!(ok["worker"], "worker-2", "{ok}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replicas_share_the_queue_and_a_killed_worker_loses_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = RedisPrefix::new();
    let redis = redis_url();
    let api = Replica::spawn(dir.path(), &redis, &prefix.0, "api", "api-1");
    let mut workers = vec![
        Replica::spawn(dir.path(), &redis, &prefix.0, "worker", "worker-1"),
        Replica::spawn(dir.path(), &redis, &prefix.0, "worker", "worker-2"),
    ];
    let c = reqwest::Client::new();

    // Every replica is ready and says what it is.
    let ready: Value = c
        .get(api.url("/readyz"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(ready["backend"], "redis");
    assert_eq!(ready["role"], "api");
    assert_eq!(ready["workers"], json!(0));
    // A worker replica serves no API.
    let resp = c.get(workers[0].url("/v1/jobs")).send().await.unwrap();
    assert_eq!(resp.status().as_u16(), 404);

    // One long job, and small ones queued behind it: all go through the API replica.
    let long_input = synthetic_npy();
    let long_params = json!({"width": 1280, "height": 720, "samples": 16, "cell_size": 30.0, "mesh_max_vertices": 20000});
    let long = submit(&c, &api, &long_input, &long_params).await;
    let long_id = long["id"].as_str().unwrap().to_string();
    let small_input = synthetic_npy_of(96);
    let mut small = Vec::new();
    for w in [64, 72, 80, 88] {
        let p = json!({"width": w, "height": 48, "samples": 1, "cell_size": 30.0});
        small.push((submit(&c, &api, &small_input, &p).await, p));
    }

    // SSE on the API replica, which runs nothing.
    let events = tokio::spawn(sse(
        c.clone(),
        api.url(&format!("/v1/jobs/{long_id}/events")),
    ));

    // Kill the long job's worker once it has made progress.
    let t0 = Instant::now();
    let victim = loop {
        let j = job(&c, &api, &long_id).await;
        if j["status"] == "running" && j["progress"].as_f64().unwrap() > 0.0 {
            break j["worker"].as_str().unwrap().to_string();
        }
        assert_ne!(j["status"], "succeeded", "the job ended before the kill");
        assert!(t0.elapsed() < Duration::from_secs(120), "{j}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    let i = workers.iter().position(|w| w.name == victim).unwrap();
    let mut dead = workers.remove(i);
    dead.child.kill().unwrap(); // SIGKILL
    dead.child.wait().unwrap();
    let survivor = &workers[0];

    let done = wait_done(&c, &api, &long_id, Duration::from_secs(600)).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    eprintln!(
        "long job: killed {victim}, finished by {} after {} attempts, timings {}",
        done["worker"], done["attempts"], done["timings"]
    );
    assert_eq!(done["worker"].as_str(), Some(survivor.name.as_str()));
    assert!(done["attempts"].as_u64().unwrap() >= 2, "{done}");
    assert_same_as_cli(
        &c,
        &api.addr,
        &long_id,
        dir.path(),
        &long_input,
        &long_params,
    )
    .await;

    // Every small job was accepted and completed, by a worker replica, with the CLI's bytes.
    for (j, _) in &small {
        let id = j["id"].as_str().unwrap();
        let d = wait_done(&c, &api, id, Duration::from_secs(300)).await;
        assert_eq!(d["status"], "succeeded", "{d}");
        let w = d["worker"].as_str().unwrap();
        assert!(w.starts_with("worker-"), "{d}");
    }
    let (j, p) = &small[0];
    let scratch = dir.path().join("small");
    std::fs::create_dir_all(&scratch).unwrap();
    let id = j["id"].as_str().unwrap();
    assert_same_as_cli(&c, &api.addr, id, &scratch, &small_input, p).await;

    // The SSE stream on the API replica saw the job run and end.
    let events = tokio::time::timeout(Duration::from_secs(60), events)
        .await
        .unwrap()
        .unwrap();
    assert!(
        events.iter().any(|(e, d)| e == "progress"
            && d["status"] == "running"
            && d["progress"].as_f64().unwrap() > 0.0),
        "{events:?}"
    );
    let (last, data) = events.last().unwrap();
    assert_eq!(last, "done");
    assert_eq!(data["status"], "succeeded");

    // The survivor counts the job it took over.
    let m = c
        .get(survivor.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        metric(&m, "phenomena_jobs_started_total{how=\"reclaimed\"}") >= 1.0,
        "{m}"
    );
    assert_eq!(metric(&m, "phenomena_workers"), 1.0);
}

/// A private `redis-server` with an append-only file (a restart keeps what it acknowledged).
struct PrivateRedis {
    child: Child,
    port: u16,
    dir: std::path::PathBuf,
}

impl PrivateRedis {
    fn start(port: u16, dir: &std::path::Path) -> Self {
        let child = Command::new("redis-server")
            .args([
                "--port",
                &port.to_string(),
                "--bind",
                "127.0.0.1",
                "--save",
                "",
            ])
            .args(["--appendonly", "yes", "--appendfsync", "always"])
            .arg("--dir")
            .arg(dir)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("redis-server is installed");
        crate::common::wait_for_port(port, Duration::from_secs(10), "redis");
        PrivateRedis {
            child,
            port,
            dir: dir.to_path_buf(),
        }
    }

    /// SIGTERM (Redis flushes and exits), then start again on the same port and directory.
    fn restart(&mut self) {
        let _ = Command::new("kill")
            .arg(self.child.id().to_string())
            .status();
        self.child.wait().unwrap();
        *self = PrivateRedis::start(self.port, &self.dir.clone());
    }
}

impl Drop for PrivateRedis {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_redis_restart_during_idle_time_is_survived() {
    let dir = tempfile::tempdir().unwrap();
    let port = crate::common::free_port();
    let redis_dir = dir.path().join("redis");
    std::fs::create_dir_all(&redis_dir).unwrap();
    let mut redis = PrivateRedis::start(port, &redis_dir);
    let url = format!("redis://127.0.0.1:{port}/");
    let data = dir.path().join("data");
    let r = Replica::spawn(&data, &url, "phenomena", "both", "solo");
    let c = reqwest::Client::new();
    let input = synthetic_npy_of(96);
    let params = json!({"width": 64, "height": 48, "samples": 1, "cell_size": 30.0});
    let before = submit(&c, &r, &input, &params).await;
    let before_id = before["id"].as_str().unwrap();
    let d = wait_done(&c, &r, before_id, Duration::from_secs(120)).await;
    assert_eq!(d["status"], "succeeded");

    redis.restart();

    // Reconnects by itself: ready again, the finished job is still there, new jobs run.
    let t0 = Instant::now();
    loop {
        let s = c.get(r.url("/readyz")).send().await.unwrap().status();
        if s.as_u16() == 200 {
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "not ready again");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let j = job(&c, &r, before_id).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    let params2 = json!({"width": 72, "height": 48, "samples": 1, "cell_size": 30.0});
    let t0 = Instant::now();
    let after = loop {
        // The first request after the restart may meet a connection being re-established (503).
        let form = reqwest::multipart::Form::new()
            .text("params", params2.to_string())
            .part(
                "dem",
                reqwest::multipart::Part::bytes(input.clone()).file_name("terrain.npy"),
            );
        let resp = c
            .post(r.url("/v1/snow-terrain"))
            .multipart(form)
            .send()
            .await
            .unwrap();
        if resp.status().as_u16() == 202 {
            break resp.json::<Value>().await.unwrap();
        }
        assert_eq!(resp.status().as_u16(), 503);
        assert!(t0.elapsed() < Duration::from_secs(30));
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    let after_id = after["id"].as_str().unwrap().to_string();
    // Progress reaches this replica's waiters again (pub/sub resubscribed).
    let events = tokio::time::timeout(
        Duration::from_secs(120),
        sse(c.clone(), r.url(&format!("/v1/jobs/{after_id}/events"))),
    )
    .await
    .unwrap();
    assert_eq!(
        events.last().unwrap().1["status"],
        "succeeded",
        "{events:?}"
    );
    let scratch = dir.path().join("cli");
    std::fs::create_dir_all(&scratch).unwrap();
    assert_same_as_cli(&c, &r.addr, &after_id, &scratch, &input, &params2).await;
}

/// Submits `n` distinct small snow-terrain jobs to `api` and waits for all; returns seconds.
async fn run_batch(c: &reqwest::Client, api: &Replica, input: &[u8], n: usize, salt: u32) -> f64 {
    let t0 = Instant::now();
    let mut ids = Vec::new();
    for i in 0..n {
        // Distinct parameters: no result reuse.
        let p = json!({"width": 64 + i, "height": 48, "samples": 1, "cell_size": 30.0 + f64::from(salt)});
        ids.push(
            submit(c, api, input, &p).await["id"]
                .as_str()
                .unwrap()
                .to_string(),
        );
    }
    for id in &ids {
        let d = wait_done(c, api, id, Duration::from_secs(600)).await;
        assert_eq!(d["status"], "succeeded", "{d}");
    }
    t0.elapsed().as_secs_f64()
}

/// Round trips of one tiny job submitted with `Prefer: wait`, sequentially; returns the median
/// in milliseconds.
async fn median_round_trip(c: &reqwest::Client, r: &Replica, input: &[u8], n: usize) -> f64 {
    let mut ms = Vec::new();
    for i in 0..n {
        let p = json!({"width": 16 + i, "height": 16, "samples": 1, "cell_size": 30.0});
        let form = reqwest::multipart::Form::new()
            .text("params", p.to_string())
            .part(
                "dem",
                reqwest::multipart::Part::bytes(input.to_vec()).file_name("t.npy"),
            );
        let t0 = Instant::now();
        let resp = c
            .post(r.url("/v1/snow-terrain"))
            .header("prefer", "wait=30")
            .multipart(form)
            .send()
            .await
            .unwrap();
        let j: Value = resp.json().await.unwrap();
        ms.push(t0.elapsed().as_secs_f64() * 1e3);
        assert_eq!(j["status"], "succeeded", "{j}");
    }
    ms.sort_by(f64::total_cmp);
    ms[ms.len() / 2]
}

/// BENCHMARKS.md "Scale-out": throughput of small jobs with 1, 2 and 3 worker processes (one
/// pipeline thread each) behind one API replica, and the round trip of a tiny job on the embedded
/// backend and on the Redis backend (one `both` process each).
/// `cargo test --test it scale::scale_out_figures -- --ignored --nocapture`
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore]
async fn scale_out_figures() {
    let c = reqwest::Client::new();
    let redis = redis_url();
    let input = synthetic_npy_of(128);
    let n = 60;
    for k in 1..=3u32 {
        let dir = tempfile::tempdir().unwrap();
        let prefix = RedisPrefix::new();
        let api = Replica::spawn(dir.path(), &redis, &prefix.0, "api", "api");
        let _workers: Vec<Replica> = (0..k)
            .map(|i| Replica::spawn(dir.path(), &redis, &prefix.0, "worker", &format!("w{i}")))
            .collect();
        run_batch(&c, &api, &input, 4, 99).await; // warm-up
        let secs = run_batch(&c, &api, &input, n, k).await;
        eprintln!(
            "workers={k}: {n} jobs in {secs:.2} s = {:.1} jobs/s",
            n as f64 / secs
        );
    }
    let tiny = synthetic_npy_of(32);
    // The data directory on disk (the embedded backend fsyncs each job record) and in memory.
    for base in [std::env::temp_dir(), std::path::PathBuf::from("/dev/shm")] {
        let dir = tempfile::tempdir_in(&base).unwrap();
        let (child, addr) = spawn_server_with(dir.path(), &["--threads", "1"]);
        let embedded = Replica {
            child,
            addr,
            name: "embedded".into(),
        };
        median_round_trip(&c, &embedded, &tiny, 5).await;
        let e = median_round_trip(&c, &embedded, &tiny, 41).await;
        drop(embedded);
        let dir = tempfile::tempdir_in(&base).unwrap();
        let prefix = RedisPrefix::new();
        let both = Replica::spawn(dir.path(), &redis, &prefix.0, "both", "both");
        median_round_trip(&c, &both, &tiny, 5).await;
        let r = median_round_trip(&c, &both, &tiny, 41).await;
        eprintln!(
            "data dir under {}: tiny job round trip (Prefer: wait), median of 41: embedded {e:.2} ms, redis {r:.2} ms, redis - embedded {:.2} ms",
            base.display(),
            r - e
        );
    }
}

/// A worker whose memory budget is smaller than the API replica's (issue 20): a job the API
/// admitted (its estimate fits the API's budget) but that is larger than the worker's whole
/// budget ends `failed` as `too-large`, with the estimate and the worker's budget in the detail,
/// instead of taking the worker's whole budget; the worker goes on running jobs that fit.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_refuses_a_job_larger_than_its_whole_budget() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = RedisPrefix::new();
    let redis = redis_url();
    let api = Replica::spawn(dir.path(), &redis, &prefix.0, "api", "api-1");
    // 2 MiB: less than a 256² DEM's job (32 B per cell and per output pixel, ~4.5 MiB).
    let _worker = Replica::spawn_env(
        dir.path(),
        &redis,
        &prefix.0,
        "worker",
        "small-worker",
        &["--memory-budget-bytes", "2097152"],
        &[],
    );
    let c = reqwest::Client::new();
    let big = submit(
        &c,
        &api,
        &synthetic_npy_of(256),
        &json!({"width": 320, "height": 240, "cell_size": 30.0}),
    )
    .await;
    let done = wait_done(
        &c,
        &api,
        big["id"].as_str().unwrap(),
        Duration::from_secs(60),
    )
    .await;
    assert_eq!(done["status"], "failed", "{done}");
    assert_eq!(
        done["error"]["type"], "https://phenomena.dev/problems/too-large",
        "{done}"
    );
    let detail = done["error"]["detail"].as_str().unwrap();
    assert!(
        detail.contains("memory budget of 2 MiB"),
        "the detail names the worker's budget: {detail}"
    );
    assert_eq!(done["attempts"], json!(1), "not retried: {done}");

    let small = submit(
        &c,
        &api,
        &synthetic_npy_of(64),
        &json!({"width": 64, "height": 48, "cell_size": 30.0}),
    )
    .await;
    let done = wait_done(
        &c,
        &api,
        small["id"].as_str().unwrap(),
        Duration::from_secs(60),
    )
    .await;
    assert_eq!(done["status"], "succeeded", "{done}");
}
