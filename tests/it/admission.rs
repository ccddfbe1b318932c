//! Admission before work (issue 20), measured against the real binary (a child process, so its
//! memory is its own): 16 concurrent submits of a small, highly compressed DEM that decodes to
//! the largest grid the limits accept, and 16 concurrent 200 MB multipart uploads. Every answer
//! must be one the API documents for an overloaded service or a refused file (202, 429 with
//! `Retry-After`, 413, and 415 for the uploads, whose bytes are no DEM), none may be lost, and the
//! server's peak RSS (`VmHWM`) must stay under 1 GiB.
//!
//! Big-data cases, so `#[ignore]`d; the figures are in RELIABILITY.md ("Admission"):
//!
//! ```text
//! cargo test --test it admission -- --ignored --nocapture --test-threads 1
//! ```
//! The Redis variants need a `redis-server` on `PHENOMENA_TEST_REDIS_URL` (default
//! `redis://127.0.0.1:6379/`) and measure an `api` replica, which runs no jobs.

use std::process::Child;
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use crate::restart::spawn_server_with;

/// Concurrent clients, as the issue's "done when" asks.
const CLIENTS: usize = 16;
/// The RSS bound of the issue, in kB.
const RSS_LIMIT_KB: u64 = 1 << 20;

struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn status_kb(pid: u32, field: &str) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// An 8192² float32 GeoTIFF (deflate) of a gentle ramp: 67 M cells, the default
/// `max_input_cells`, in a file of a few hundred KB.
fn compressed_dem() -> Vec<u8> {
    let n = 8192;
    let mut values = vec![0f32; n * n];
    for (r, row) in values.chunks_mut(n).enumerate() {
        row.fill(100.0 + (r / 64) as f32);
    }
    phenomena_engine::formats::geotiff_write::write_float32_geotiff(
        n,
        n,
        &values,
        &phenomena_engine::geom::GeoRef::default(),
    )
}

/// What the flood saw.
#[derive(Debug, Default)]
struct Tally {
    by_status: std::collections::BTreeMap<u16, u64>,
    without_retry_after: u64,
    transport_errors: Vec<String>,
    accepted: Vec<String>,
}

/// Starts the server (`extra` flags), sends `CLIENTS` submissions at once (each made by `form`
/// from its index) and returns the tally and the peak RSS in kB.
async fn flood(
    extra: &[&str],
    path: &str,
    form: impl Fn(usize) -> reqwest::multipart::Form,
) -> (Tally, u64, String, Proc) {
    let dir = tempfile::tempdir().unwrap();
    let (child, addr) = spawn_server_with(dir.path(), extra);
    let pid = child.id();
    let proc = Proc(child);
    let base = format!("http://{addr}");
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(300))
        .build()
        .unwrap();
    let idle_kb = status_kb(pid, "VmRSS:").unwrap_or(0);
    let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let sampler = {
        let done = done.clone();
        tokio::spawn(async move {
            let mut peak = 0;
            while !done.load(std::sync::atomic::Ordering::Relaxed) {
                peak = peak.max(status_kb(pid, "VmRSS:").unwrap_or(0));
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            peak
        })
    };
    let t0 = Instant::now();
    let mut tasks = Vec::new();
    for i in 0..CLIENTS {
        let (client, url) = (client.clone(), format!("{base}{path}"));
        let form = form(i);
        tasks.push(tokio::spawn(async move {
            client.post(url).multipart(form).send().await
        }));
    }
    let mut tally = Tally::default();
    for t in tasks {
        match t.await.unwrap() {
            Ok(r) => {
                let status = r.status().as_u16();
                *tally.by_status.entry(status).or_default() += 1;
                if status == 429 && r.headers().get("retry-after").is_none() {
                    tally.without_retry_after += 1;
                }
                let body: Value = r.json().await.unwrap_or(Value::Null);
                if status == 202 {
                    tally
                        .accepted
                        .push(body["id"].as_str().unwrap_or_default().to_string());
                }
            }
            Err(e) => tally.transport_errors.push(e.to_string()),
        }
    }
    let took = t0.elapsed();
    // Jobs accepted must not be lost: each is on its status URL. Cancel them (their run is
    // not what is measured here), then read the peak.
    for id in &tally.accepted {
        let r = client
            .get(format!("{base}/v1/jobs/{id}"))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 200, "accepted job {id} is lost");
        let _ = client.delete(format!("{base}/v1/jobs/{id}")).send().await;
    }
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    let sampled = sampler.await.unwrap();
    let peak = status_kb(pid, "VmHWM:").unwrap_or(0).max(sampled);
    println!(
        "flood {path} {extra:?}: {tally:?}; idle RSS {} MiB, peak RSS {} MiB, {:.1} s",
        idle_kb >> 10,
        peak >> 10,
        took.as_secs_f64()
    );
    drop(dir);
    (tally, peak, base, proc)
}

fn assert_only(tally: &Tally, allowed: &[u16]) {
    assert!(tally.transport_errors.is_empty(), "{tally:?}");
    assert!(
        tally.by_status.keys().all(|s| allowed.contains(s)),
        "unexpected answers: {tally:?}"
    );
    assert_eq!(
        tally.by_status.values().sum::<u64>(),
        CLIENTS as u64,
        "{tally:?}"
    );
    assert_eq!(tally.without_retry_after, 0, "{tally:?}");
}

/// Submissions of the compressed DEM, each with its own parameters (so no two share a job).
fn dem_form(dem: Arc<Vec<u8>>) -> impl Fn(usize) -> reqwest::multipart::Form {
    move |i| {
        reqwest::multipart::Form::new()
            .text(
                "params",
                json!({"width": 64 + i, "height": 48, "cell_size": 30}).to_string(),
            )
            .part(
                "dem",
                reqwest::multipart::Part::bytes(dem.to_vec()).file_name("big.tif"),
            )
    }
}

/// 200 MB of bytes that are no DEM (incompressible, so nothing is small on the wire either).
fn upload_form(blob: Arc<Vec<u8>>) -> impl Fn(usize) -> reqwest::multipart::Form {
    move |i| {
        let mut b = blob.to_vec();
        b[0] = i as u8;
        reqwest::multipart::Form::new()
            .text("params", "{}")
            .part("dem", reqwest::multipart::Part::bytes(b).file_name("x.bin"))
    }
}

fn noise(len: usize) -> Vec<u8> {
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 24) as u8
        })
        .collect()
}

const MB200: usize = 200_000_000;

fn redis_flags() -> Vec<String> {
    vec![
        "--role".into(),
        "api".into(),
        "--redis-url".into(),
        crate::common::redis_url(),
        "--redis-prefix".into(),
        format!("admission-{}", std::process::id()),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "big data: 16 × 8192² decodes; run with --ignored (see the module doc)"]
async fn sixteen_compressed_dems_near_the_cell_limit_stay_under_1_gib() {
    let dem = Arc::new(compressed_dem());
    println!("compressed DEM: {} bytes", dem.len());
    let (tally, peak, _, _p) = flood(
        &["--threads", "2", "--concurrency", "1"],
        "/v1/snow-terrain",
        dem_form(dem),
    )
    .await;
    assert_only(&tally, &[202, 429, 413]);
    // The jobs share the checks' memory budget: snow-terrain on 8192² cells is estimated at
    // ~2 GiB, more than the whole default budget (768 MiB), so it is refused 413 rather than
    // run; what is admitted runs within the budget.
    assert!(peak < RSS_LIMIT_KB, "peak RSS {peak} kB");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "big data: 16 × 8192² decodes on an api replica; needs Redis"]
async fn sixteen_compressed_dems_on_a_redis_api_replica_stay_under_1_gib() {
    let dem = Arc::new(compressed_dem());
    let flags = redis_flags();
    let flags: Vec<&str> = flags.iter().map(String::as_str).collect();
    let (tally, peak, _, _p) = flood(&flags, "/v1/snow-terrain", dem_form(dem)).await;
    assert_only(&tally, &[202, 429, 413]);
    assert!(peak < RSS_LIMIT_KB, "peak RSS {peak} kB");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "big data: 16 × 200 MB uploads (3.2 GB through the store); run with --ignored"]
async fn sixteen_200_mb_multipart_uploads_stream_and_stay_under_1_gib() {
    let blob = Arc::new(noise(MB200));
    let (tally, peak, _, _p) = flood(
        &["--threads", "2", "--concurrency", "1"],
        "/v1/snow-terrain",
        upload_form(blob),
    )
    .await;
    // The bytes are no DEM: 415 once checked, or 429 when the memory budget stayed in use.
    assert_only(&tally, &[415, 429, 413]);
    assert!(peak < RSS_LIMIT_KB, "peak RSS {peak} kB");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "big data: 16 × 200 MB uploads on an api replica; needs Redis"]
async fn sixteen_200_mb_multipart_uploads_on_a_redis_api_replica_stay_under_1_gib() {
    let blob = Arc::new(noise(MB200));
    let flags = redis_flags();
    let flags: Vec<&str> = flags.iter().map(String::as_str).collect();
    let (tally, peak, _, _p) = flood(&flags, "/v1/snow-terrain", upload_form(blob)).await;
    assert_only(&tally, &[415, 429, 413]);
    assert!(peak < RSS_LIMIT_KB, "peak RSS {peak} kB");
}
