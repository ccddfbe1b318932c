//! Job mechanics over HTTP, with the test-only `sleepy` pipeline.

use std::time::Duration;

use futures_util::StreamExt;
use serde_json::{json, Value};

use crate::common::{problem, Server};

fn id_of(v: &Value) -> String {
    v["id"].as_str().unwrap().to_string()
}

crate::on_each_backend! {

#[tokio::test]
async fn submit_poll_and_download_with_etag() {
    let s = start(|_| {}).await;
    let resp = s.sleepy(json!({"stages": 3, "ms": 20}), b"hello dem").await;
    assert_eq!(resp.status().as_u16(), 202);
    let loc = resp.headers()["location"].to_str().unwrap().to_string();
    let job: Value = resp.json().await.unwrap();
    assert_eq!(loc, format!("/v1/jobs/{}", id_of(&job)));
    assert!(["queued", "running"].contains(&job["status"].as_str().unwrap()));
    assert_eq!(
        job["params"],
        json!({"stages": 3, "ms": 20, "panic": false})
    );

    let done = s.wait_done(&id_of(&job)).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(done["progress"], json!(1.0));
    let stages: Vec<&str> = done["timings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["stage"].as_str().unwrap())
        .collect();
    assert_eq!(stages, ["stage0", "stage1", "stage2"]);
    assert!(done["timings"][0]["ms"].as_f64().unwrap() >= 15.0);
    let out = done["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["name"] == "echo.txt")
        .unwrap()
        .clone();
    assert_eq!(out["size"], json!(9));

    let resp = s
        .client
        .get(s.url(out["url"].as_str().unwrap()))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 200);
    assert_eq!(resp.headers()["content-type"], "text/plain");
    assert_eq!(resp.headers()["content-length"], "9");
    let etag = resp.headers()["etag"].to_str().unwrap().to_string();
    assert_eq!(etag, format!("\"{}\"", out["sha256"].as_str().unwrap()));
    assert_eq!(resp.bytes().await.unwrap().as_ref(), b"hello dem");

    let resp = s
        .client
        .get(s.url(out["url"].as_str().unwrap()))
        .header("if-none-match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 304);
    let resp = s
        .client
        .get(s.url(&format!("/v1/jobs/{}/outputs/nope.png", id_of(&job))))
        .send()
        .await
        .unwrap();
    problem(resp, 404, "not-found").await;
}

#[tokio::test]
async fn prefer_wait_returns_the_finished_job() {
    let s = start(|_| {}).await;
    let form = reqwest::multipart::Form::new()
        .text("params", json!({"stages": 2, "ms": 30}).to_string())
        .part(
            "data",
            reqwest::multipart::Part::bytes(b"w".to_vec()).file_name("w.bin"),
        );
    let resp = s
        .client
        .post(s.url("/v1/sleepy"))
        .header("prefer", "wait=20")
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 200);
    assert_eq!(resp.headers()["preference-applied"], "wait=20");
    let job: Value = resp.json().await.unwrap();
    assert_eq!(job["status"], "succeeded");

    // GET with a wait on an already-finished job answers at once.
    let resp = s
        .client
        .get(s.url(&format!("/v1/jobs/{}", id_of(&job))))
        .header("prefer", "wait=5")
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 200);
}

#[tokio::test]
async fn events_stream_progress_then_done() {
    let s = start(|_| {}).await;
    let job: Value = s
        .sleepy(json!({"stages": 4, "ms": 60}), b"sse")
        .await
        .json()
        .await
        .unwrap();
    let resp = s
        .client
        .get(s.url(&format!("/v1/jobs/{}/events", id_of(&job))))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 200);
    assert!(resp.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/event-stream"));
    let mut body = String::new();
    let mut stream = resp.bytes_stream();
    let read = tokio::time::timeout(Duration::from_secs(20), async {
        while let Some(chunk) = stream.next().await {
            body.push_str(&String::from_utf8_lossy(&chunk.unwrap()));
        }
    });
    read.await.expect("the stream ends after the done event");
    let events: Vec<(&str, Value)> = body
        .split("\n\n")
        .filter_map(|block| {
            let ev = block.lines().find_map(|l| l.strip_prefix("event: "))?;
            let data = block.lines().find_map(|l| l.strip_prefix("data: "))?;
            Some((ev, serde_json::from_str(data).unwrap()))
        })
        .collect();
    let progress: Vec<&Value> = events
        .iter()
        .filter(|(e, _)| *e == "progress")
        .map(|(_, d)| d)
        .collect();
    assert!(progress.len() >= 2, "{body}");
    let fractions: Vec<f64> = progress
        .iter()
        .map(|p| p["progress"].as_f64().unwrap())
        .collect();
    assert!(
        fractions.windows(2).all(|w| w[0] <= w[1]),
        "progress never goes back: {fractions:?}"
    );
    let (last, data) = events.last().unwrap();
    assert_eq!(*last, "done");
    assert_eq!(data["status"], "succeeded");
    assert_eq!(data["id"], job["id"]);
}

#[tokio::test]
async fn cancel_running_and_queued_jobs() {
    let s = start(|c| c.concurrency = 1).await;
    let a: Value = s
        .sleepy(json!({"stages": 100, "ms": 50}), b"a")
        .await
        .json()
        .await
        .unwrap();
    let b: Value = s
        .sleepy(json!({"stages": 100, "ms": 50}), b"b")
        .await
        .json()
        .await
        .unwrap();
    // Wait until `a` runs.
    s.wait_running(&id_of(&a)).await;
    // The queued one is canceled at once.
    let resp = s
        .client
        .delete(s.url(&format!("/v1/jobs/{}", id_of(&b))))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 200);
    assert_eq!(resp.json::<Value>().await.unwrap()["status"], "canceled");
    // The running one at its next checkpoint.
    let resp = s
        .client
        .delete(s.url(&format!("/v1/jobs/{}", id_of(&a))))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 202);
    let done = s.wait_done(&id_of(&a)).await;
    assert_eq!(done["status"], "canceled");
    assert!(done["outputs"].as_array().unwrap().is_empty());
    // Canceling a finished job conflicts; an unknown id is 404.
    let resp = s
        .client
        .delete(s.url(&format!("/v1/jobs/{}", id_of(&a))))
        .send()
        .await
        .unwrap();
    problem(resp, 409, "conflict").await;
    let resp = s
        .client
        .delete(s.url(&format!("/v1/jobs/{}", "0".repeat(32))))
        .send()
        .await
        .unwrap();
    problem(resp, 404, "not-found").await;
    // A canceled request is not reused: the same request runs again.
    let again: Value = s
        .sleepy(json!({"stages": 100, "ms": 50}), b"b")
        .await
        .json()
        .await
        .unwrap();
    assert_ne!(again["id"], b["id"]);
}

/// What the upload's schema refuses, the server refuses with a problem (the conformance run's
/// negative-data check is off for this operation: see tests/conformance/schemathesis.toml).
#[tokio::test]
async fn asset_uploads_refuse_what_the_schema_refuses() {
    let s = start(|_| {}).await;
    let url = s.url("/v1/assets");
    let long = format!("{}?filename={}", url, "a".repeat(256));
    let part = |name: &str, bytes: &[u8]| {
        reqwest::multipart::Form::new().part(
            name.to_string(),
            reqwest::multipart::Part::bytes(bytes.to_vec()).file_name("f.bin"),
        )
    };
    let cases = vec![
        ("empty body", s.client.post(&url).body(Vec::<u8>::new())),
        ("no file part", s.client.post(&url).multipart(part("data", b"x"))),
        ("empty file part", s.client.post(&url).multipart(part("file", b""))),
        ("filename over 255 characters", s.client.post(&long).body("x")),
    ];
    for (what, req) in cases {
        let resp = req.send().await.unwrap();
        let status = resp.status().as_u16();
        assert!((400..500).contains(&status), "{what}: {status}");
        assert_eq!(
            resp.headers()["content-type"].to_str().unwrap(),
            "application/problem+json",
            "{what}"
        );
    }
}

#[tokio::test]
async fn assets_upload_once_and_jobs_name_them() {
    let s = start(|_| {}).await;
    let resp = s
        .client
        .post(s.url("/v1/assets?filename=a.bin"))
        .body("asset bytes")
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 201);
    let asset: Value = resp.json().await.unwrap();
    let id = asset["id"].as_str().unwrap().to_string();
    assert_eq!(id, phenomena::store::sha256_hex(b"asset bytes"));
    assert_eq!(asset["filename"], "a.bin");
    let resp = s
        .client
        .post(s.url("/v1/assets"))
        .body("asset bytes")
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 200);
    assert_eq!(
        resp.headers()["location"].to_str().unwrap(),
        format!("/v1/assets/{id}")
    );
    let got: Value = s
        .client
        .get(s.url(&format!("/v1/assets/{id}")))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(got["size"], json!(11));

    let resp = s
        .client
        .post(s.url("/v1/sleepy"))
        .header("prefer", "wait=20")
        .json(&json!({"asset": id, "params": {"ms": 1}}))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 200);
    let job: Value = resp.json().await.unwrap();
    assert_eq!(job["status"], "succeeded");
    assert_eq!(job["input"]["asset"], json!(id));
    let echo = s
        .client
        .get(s.url(&format!("/v1/jobs/{}/outputs/echo.txt", id_of(&job))))
        .send()
        .await
        .unwrap();
    assert_eq!(echo.bytes().await.unwrap().as_ref(), b"asset bytes");

    let resp = s
        .client
        .post(s.url("/v1/sleepy"))
        .json(&json!({"asset": "f".repeat(64)}))
        .send()
        .await
        .unwrap();
    // A well-formed id of no asset: 404 naming the field in its detail.
    let p = problem(resp, 404, "not-found").await;
    assert!(p["detail"].as_str().unwrap().starts_with("asset: no asset"), "{p}");
    let resp = s
        .client
        .get(s.url("/v1/assets/..%2F..%2Fetc"))
        .send()
        .await
        .unwrap();
    problem(resp, 404, "not-found").await;
}

#[tokio::test]
async fn identical_requests_reuse_the_job() {
    let s = start(|_| {}).await;
    let a: Value = s
        .sleepy(json!({"stages": 2, "ms": 50}), b"same")
        .await
        .json()
        .await
        .unwrap();
    // Same input and params (spelled differently: defaults explicit) while running: joins it.
    let resp = s
        .sleepy(json!({"ms": 50, "stages": 2, "panic": false}), b"same")
        .await;
    assert_eq!(resp.status().as_u16(), 202);
    assert_eq!(resp.json::<Value>().await.unwrap()["id"], a["id"]);
    s.wait_done(&id_of(&a)).await;
    // After it finished: the finished job, 200.
    let resp = s.sleepy(json!({"stages": 2, "ms": 50}), b"same").await;
    assert_eq!(resp.status().as_u16(), 200);
    let again: Value = resp.json().await.unwrap();
    assert_eq!(again["id"], a["id"]);
    assert_eq!(again["status"], "succeeded");
    // Different params or input: a new job.
    let b: Value = s
        .sleepy(json!({"stages": 2, "ms": 51}), b"same")
        .await
        .json()
        .await
        .unwrap();
    assert_ne!(b["id"], a["id"]);
    let c: Value = s
        .sleepy(json!({"stages": 2, "ms": 50}), b"other")
        .await
        .json()
        .await
        .unwrap();
    assert_ne!(c["id"], a["id"]);
    let list: Value = s
        .client
        .get(s.url("/v1/jobs?limit=2"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(list["jobs"].as_array().unwrap().len(), 2);
    assert_eq!(list["jobs"][0]["id"], c["id"], "newest first");
    let cursor = list["next_cursor"].as_str().unwrap();
    let rest: Value = s
        .client
        .get(s.url(&format!("/v1/jobs?limit=2&cursor={cursor}")))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(rest["jobs"].as_array().unwrap().len(), 1);
    assert_eq!(rest["jobs"][0]["id"], a["id"]);
    assert!(rest.get("next_cursor").is_none());
}

#[tokio::test]
async fn a_full_queue_answers_429_with_retry_after() {
    let s = start(|c| {
        c.concurrency = 1;
        c.queue_capacity = 1;
    })
    .await;
    let a: Value = s
        .sleepy(json!({"stages": 100, "ms": 20}), b"1")
        .await
        .json()
        .await
        .unwrap();
    s.wait_running(&id_of(&a)).await;
    let b = s.sleepy(json!({"stages": 100, "ms": 20}), b"2").await;
    assert_eq!(b.status().as_u16(), 202);
    let resp = s.sleepy(json!({"stages": 100, "ms": 20}), b"3").await;
    assert_eq!(resp.headers()["retry-after"], "5");
    problem(resp, 429, "queue-full").await;
    // Every accepted job still completes (cancel to keep the test short).
    let b: Value = b.json().await.unwrap();
    for j in [&a, &b] {
        s.client
            .delete(s.url(&format!("/v1/jobs/{}", id_of(j))))
            .send()
            .await
            .unwrap();
    }
    assert_eq!(s.wait_done(&id_of(&a)).await["status"], "canceled");
}

#[tokio::test]
async fn bad_requests_get_problem_json() {
    let s = start(|c| c.max_body_bytes = 4096).await;
    // Not multipart or JSON.
    let resp = s
        .client
        .post(s.url("/v1/sleepy"))
        .header("content-type", "text/plain")
        .body("x")
        .send()
        .await
        .unwrap();
    problem(resp, 415, "unsupported-format").await;
    // Missing the input part.
    let form = reqwest::multipart::Form::new().text("params", "{}");
    let resp = s
        .client
        .post(s.url("/v1/sleepy"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(problem(resp, 400, "bad-request").await["field"], "data");
    // Params that are not JSON.
    let form = reqwest::multipart::Form::new()
        .text("params", "{nope")
        .part("data", reqwest::multipart::Part::bytes(b"x".to_vec()));
    let resp = s
        .client
        .post(s.url("/v1/sleepy"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(problem(resp, 400, "bad-request").await["field"], "params");
    // Unknown pipeline.
    let resp = s.sleepy(json!({}), b"x").await;
    assert_eq!(resp.status().as_u16(), 202);
    let resp = s
        .submit("snowy-terrain", "dem", json!({}), b"x".to_vec(), "x.asc")
        .await;
    let p = problem(resp, 404, "not-found").await;
    assert!(
        p["detail"].as_str().unwrap().contains("snow-terrain"),
        "{p}"
    );
    // Unknown and out-of-range parameters.
    let resp = s.sleepy(json!({"stagez": 1}), b"x").await;
    assert_eq!(
        problem(resp, 422, "invalid-parameter").await["field"],
        "stagez"
    );
    let resp = s.sleepy(json!({"stages": 1000}), b"x").await;
    assert_eq!(
        problem(resp, 422, "invalid-parameter").await["field"],
        "stages"
    );
    let resp = s.sleepy(json!({"stages": "two"}), b"x").await;
    assert_eq!(
        problem(resp, 422, "invalid-parameter").await["field"],
        "stages"
    );
    // A corrupt input.
    let resp = s.sleepy(json!({}), b"corrupt bytes").await;
    assert_eq!(problem(resp, 422, "invalid-input").await["field"], "data");
    // An oversize body.
    let resp = s.sleepy(json!({}), &vec![7u8; 10_000]).await;
    problem(resp, 413, "too-large").await;
    let resp = s
        .client
        .post(s.url("/v1/assets"))
        .body(vec![1u8; 10_000])
        .send()
        .await
        .unwrap();
    problem(resp, 413, "too-large").await;
    // Unknown routes and methods.
    let resp = s.client.get(s.url("/v2/whatever")).send().await.unwrap();
    problem(resp, 404, "not-found").await;
    let resp = s
        .client
        .get(s.url("/v1/jobs/not-a-job"))
        .send()
        .await
        .unwrap();
    problem(resp, 404, "not-found").await;
    let resp = s.client.put(s.url("/v1/jobs")).send().await.unwrap();
    problem(resp, 405, "method-not-allowed").await;
    let resp = s
        .client
        .get(s.url("/v1/jobs?limit=0"))
        .send()
        .await
        .unwrap();
    assert_eq!(problem(resp, 400, "bad-request").await["field"], "limit");
}

/// Poison jobs (issue 20): a job whose pipeline panics in every attempt goes back to the queue
/// after each panic (a failed attempt, as if its worker had died), is started `max_attempts`
/// times, then ends `failed` as `poisoned` (on Redis its id goes on the dead-letter list); the
/// worker that caught the panics keeps serving other jobs meanwhile and afterwards.
#[tokio::test]
async fn a_job_that_panics_in_every_attempt_ends_poisoned_and_others_run() {
    let s = start(|c| {
        c.concurrency = 1;
        c.max_attempts = 2;
    })
    .await;
    let bad: Value = s
        .sleepy(json!({"panic": true}), b"p")
        .await
        .json()
        .await
        .unwrap();
    // Queued behind the panicking job's first attempt: it runs between the attempts.
    let good: Value = s.sleepy(json!({"ms": 5}), b"g").await.json().await.unwrap();
    let bad = s.wait_done(&id_of(&bad)).await;
    assert_eq!(bad["status"], "failed", "{bad}");
    assert_eq!(
        bad["error"]["type"],
        "https://phenomena.dev/problems/poisoned",
        "{bad}"
    );
    assert_eq!(bad["attempts"], json!(2), "started max_attempts times: {bad}");
    let detail = bad["error"]["detail"].as_str().unwrap();
    assert!(detail.contains("max_attempts = 2"), "{detail}");
    assert!(!detail.contains("asked to panic"), "no internals leak: {detail}");
    let good = s.wait_done(&id_of(&good)).await;
    assert_eq!(good["status"], "succeeded", "{good}");
    assert_eq!(good["attempts"], json!(1), "{good}");

    let metrics = s
        .client
        .get(s.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        metrics.contains("phenomena_jobs_poisoned_total{pipeline=\"sleepy\"} 1"),
        "{metrics}"
    );
    assert!(
        metrics.contains("phenomena_job_attempts_failed_total{pipeline=\"sleepy\"} 2"),
        "{metrics}"
    );
    if s.backend == crate::common::Backend::Redis {
        assert_eq!(s.dead_letters(), vec![id_of(&bad)], "on the dead-letter list");
    }

    // The worker still runs work after the poisoned job: the same request is a new job.
    let again: Value = s.sleepy(json!({"ms": 5}), b"g2").await.json().await.unwrap();
    assert_eq!(s.wait_done(&id_of(&again)).await["status"], "succeeded");
    let resubmitted: Value = s
        .sleepy(json!({"panic": true}), b"p")
        .await
        .json()
        .await
        .unwrap();
    assert_ne!(id_of(&resubmitted), id_of(&bad), "a poisoned job is not reused");
}

#[tokio::test]
async fn the_time_limit_fails_a_long_job() {
    let s = start(|c| c.job_timeout_secs = 1).await;
    let j: Value = s
        .sleepy(json!({"ms": 10_000}), b"slow")
        .await
        .json()
        .await
        .unwrap();
    let done = s.wait_done(&id_of(&j)).await;
    assert_eq!(done["status"], "failed");
    assert_eq!(
        done["error"]["type"],
        "https://phenomena.dev/problems/time-limit"
    );
}

#[tokio::test]
async fn health_readiness_and_metrics() {
    let s = start(|_| {}).await;
    let h: Value = s
        .client
        .get(s.url("/healthz"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(h, json!({"status": "ok"}));
    let r = s.client.get(s.url("/readyz")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
    s.sleepy(json!({"ms": 1}), b"m").await;
    let job: Value = s.sleepy(json!({"ms": 2}), b"m").await.json().await.unwrap();
    s.wait_done(&id_of(&job)).await;
    let m = s.client.get(s.url("/metrics")).send().await.unwrap();
    assert!(m.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/plain"));
    let text = m.text().await.unwrap();
    for needle in [
        "phenomena_http_requests_total{method=\"POST\",route=\"/v1/sleepy\",status=\"202\"}",
        "phenomena_http_request_duration_seconds_bucket",
        "phenomena_job_stage_duration_seconds_count{pipeline=\"sleepy\",stage=\"total\"}",
        "phenomena_jobs_finished_total{pipeline=\"sleepy\",status=\"succeeded\"}",
        "phenomena_queue_depth",
        "phenomena_jobs_running",
        "phenomena_store_bytes",
    ] {
        assert!(text.contains(needle), "missing {needle} in\n{text}");
    }
    let spec = s.client.get(s.url("/openapi.yaml")).send().await.unwrap();
    assert_eq!(spec.headers()["content-type"], "application/yaml");
    assert_eq!(
        spec.text().await.unwrap(),
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/openapi.yaml")).unwrap()
    );
}

#[tokio::test]
async fn graceful_shutdown_requeues_and_restart_finishes() {
    let s = start(|c| {
        c.shutdown_grace_secs = 0;
        c.concurrency = 1;
    })
    .await;
    let j: Value = s
        .sleepy(json!({"stages": 10, "ms": 100}), b"restart")
        .await
        .json()
        .await
        .unwrap();
    let queued: Value = s
        .sleepy(json!({"ms": 1}), b"second")
        .await
        .json()
        .await
        .unwrap();
    s.wait_running(&id_of(&j)).await;
    let dir = s.stop().await;
    let s = Server::start_in(dir, |_| {}).await;
    let done = s.wait_done(&id_of(&j)).await;
    assert_eq!(done["status"], "succeeded");
    assert_eq!(done["attempts"], json!(2));
    assert_eq!(s.wait_done(&id_of(&queued)).await["status"], "succeeded");
}

#[tokio::test]
async fn retention_expires_finished_jobs_and_reclaims_blobs() {
    let s = start(|c| {
        c.retention_secs = 0;
        c.sweep_interval_secs = 1;
    })
    .await;
    let job: Value = s
        .client
        .post(s.url("/v1/sleepy"))
        .header("prefer", "wait=20")
        .multipart(reqwest::multipart::Form::new().text("params", "{}").part(
            "data",
            reqwest::multipart::Part::bytes(b"expiring".to_vec()),
        ))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(job["status"], "succeeded");
    let blob_count = |dir: &std::path::Path| crate::common::count_files(&dir.join("blobs"));
    assert!(blob_count(s.dir.path()) >= 2);
    let t0 = std::time::Instant::now();
    loop {
        let resp = s
            .client
            .get(s.url(&format!("/v1/jobs/{}", id_of(&job))))
            .send()
            .await
            .unwrap();
        if resp.status().as_u16() == 404 {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "the job was not expired"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(!s
        .dir
        .path()
        .join(format!("jobs/{}.json", id_of(&job)))
        .exists());
    // The sweep that removed the job reclaims its blobs in the same pass or the next.
    let t0 = std::time::Instant::now();
    while blob_count(s.dir.path()) > 0 {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "blobs were not reclaimed"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

}
