//! Blobs through `object_store` (issue 8): replicas that share nothing on disk — each has its own
//! data directory — share inputs and outputs through `--store-url`, a shared directory
//! (`file:///…`) or S3-compatible storage (`s3://bucket/prefix`, here moto's S3 server on
//! loopback). An asset uploaded to one API replica is seen by another, a job submitted to that one
//! naming it is run by a worker replica, and its outputs, downloaded from the first, are the
//! CLI's bytes. Uploads stream to the store: a 96 MiB upload does not grow the replica's peak
//! memory by anything like its size.
//!
//! Needs a Redis (see `scale.rs`) and, for the S3 case, moto's server (`pip install
//! 'moto[server]'`; `.ci/run` installs it).

use std::process::{Child, Command, Stdio};
use std::time::Duration;

use serde_json::{json, Value};

use crate::common::{redis_url, RedisPrefix};
use crate::restart::{assert_same_as_cli, synthetic_npy_of};
use crate::scale::{wait_done, Replica};

/// Peak resident memory of a process in bytes (`VmHWM`).
fn peak_rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap();
    kb * 1024
}

/// Uploads `bytes` as an asset to `r`; returns its record.
async fn upload(c: &reqwest::Client, r: &Replica, bytes: Vec<u8>, name: &str) -> Value {
    let resp = c
        .post(r.url(&format!("/v1/assets?filename={name}")))
        .header("content-type", "application/octet-stream")
        .body(bytes)
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 201);
    resp.json().await.unwrap()
}

/// The scenario of the module doc, on the store at `store_url` with `env` for every replica.
async fn replicas_share_blobs(store_url: &str, env: &[(&str, &str)], check_streaming: bool) {
    let dir = tempfile::tempdir().unwrap();
    let prefix = RedisPrefix::new();
    let redis = redis_url();
    let spawn = |role: &str, name: &str| {
        Replica::spawn_env(
            &dir.path().join(name),
            &redis,
            &prefix.0,
            role,
            name,
            &["--store-url", store_url],
            env,
        )
    };
    let api1 = spawn("api", "api-1");
    let api2 = spawn("api", "api-2");
    let _worker = spawn("worker", "worker-1");
    let c = reqwest::Client::new();
    for r in [&api1, &api2] {
        let resp = c.get(r.url("/readyz")).send().await.unwrap();
        assert_eq!(
            resp.status().as_u16(),
            200,
            "{}",
            resp.text().await.unwrap()
        );
    }

    // 1600² float32 cells: 10 MB, more than one 5 MiB part of a multipart upload.
    let dem = synthetic_npy_of(1600);
    let asset = upload(&c, &api1, dem.clone(), "terrain.npy").await;
    let id = asset["id"].as_str().unwrap().to_string();
    assert_eq!(asset["size"], json!(dem.len()));
    let seen: Value = c
        .get(api2.url(&format!("/v1/assets/{id}")))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(seen["size"], json!(dem.len()), "{seen}");

    let params = json!({"width": 96, "height": 64, "samples": 1, "cell_size": 30.0});
    let resp = c
        .post(api2.url("/v1/snow-terrain"))
        .json(&json!({"asset": id, "params": params}))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 202);
    let job: Value = resp.json().await.unwrap();
    let job_id = job["id"].as_str().unwrap();
    let done = wait_done(&c, &api1, job_id, Duration::from_secs(300)).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(done["worker"], "worker-1", "{done}");
    let scratch = dir.path().join("cli");
    std::fs::create_dir_all(&scratch).unwrap();
    assert_same_as_cli(&c, &api1.addr, job_id, &scratch, &dem, &params).await;

    // Nothing of it went to a replica's own data directory.
    for name in ["api-1", "api-2", "worker-1"] {
        let blobs = dir.path().join(name).join("blobs");
        assert!(!blobs.exists(), "{} exists", blobs.display());
    }

    if check_streaming {
        let size = 96usize << 20;
        let mut bytes = vec![0u8; size];
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for b in bytes.iter_mut() {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *b = (x >> 24) as u8;
        }
        let before = peak_rss(api1.child.id());
        let big = upload(&c, &api1, bytes, "big.bin").await;
        let after = peak_rss(api1.child.id());
        assert_eq!(big["size"], json!(size));
        let grown = after.saturating_sub(before);
        eprintln!(
            "a {} MiB upload grew the API replica's peak RSS by {:.1} MiB",
            size >> 20,
            grown as f64 / (1 << 20) as f64
        );
        assert!(
            grown < (size as u64) / 3,
            "peak RSS grew by {grown} bytes for a {size}-byte upload"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replicas_with_their_own_data_dirs_share_a_blob_directory() {
    let shared = tempfile::tempdir().unwrap();
    let url = format!("file://{}", shared.path().display());
    replicas_share_blobs(&url, &[], true).await;
    // The blobs are in the shared directory, named by their digests.
    let blobs = shared.path().join("blobs/sha256");
    let n = crate::common::count_files(&blobs);
    assert!(n >= 5, "{n} blobs in {}", blobs.display());
}

/// moto's S3-compatible server on a loopback port; killed when dropped.
pub(crate) struct Moto {
    child: Child,
    pub port: u16,
}

impl Moto {
    pub fn start() -> Self {
        let port = crate::common::free_port();
        let child = Command::new("moto_server")
            .args(["-H", "127.0.0.1", "-p", &port.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("moto_server is installed (pip install 'moto[server]'; .ci/run does)");
        crate::common::wait_for_port(port, Duration::from_secs(30), "moto");
        Moto { child, port }
    }
}

impl Drop for Moto {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replicas_share_blobs_in_s3_compatible_storage() {
    let moto = Moto::start();
    let endpoint = format!("http://127.0.0.1:{}", moto.port);
    // CreateBucket.
    let resp = reqwest::Client::new()
        .put(format!("{endpoint}/phenomena-test"))
        .send()
        .await
        .unwrap();
    assert!(resp.status().is_success(), "{}", resp.status());
    let env = [
        ("AWS_ACCESS_KEY_ID", "test"),
        ("AWS_SECRET_ACCESS_KEY", "test"),
        ("AWS_REGION", "us-east-1"),
        ("AWS_ENDPOINT", endpoint.as_str()),
        ("AWS_ALLOW_HTTP", "true"),
    ];
    replicas_share_blobs("s3://phenomena-test/svc", &env, false).await;
    // The objects are in the bucket under the prefix (ListObjectsV2).
    let listing = reqwest::Client::new()
        .get(format!(
            "{endpoint}/phenomena-test?list-type=2&prefix=svc/blobs/sha256/"
        ))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let n = listing.matches("<Key>svc/blobs/sha256/").count();
    assert!(n >= 5, "{n} blobs listed: {listing}");
}
