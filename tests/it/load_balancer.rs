//! The compose scaled profile's load balancer, for real: nginx runs `deploy/nginx.conf` unchanged
//! except for the addresses (its `upstream` points at two local API replicas instead of Docker's
//! `api` service, and it listens on a loopback port), in front of two `--role api` replicas and
//! a worker on one Redis. A job is submitted through nginx, its SSE stream followed through nginx
//! (unbuffered: progress arrives before the end), its outputs downloaded through nginx equal the
//! CLI's, and a 20 MB asset upload passes the proxy (request buffering off, body limit 256m).
//!
//! Needs nginx (`apt-get install nginx-light`; `.ci/run` installs it) and a Redis.

use std::process::{Child, Command, Stdio};
use std::time::Duration;

use serde_json::{json, Value};

use crate::common::{redis_url, RedisPrefix};
use crate::restart::{assert_same_as_cli, synthetic_npy, synthetic_npy_of};
use crate::scale::{sse, submit_to, wait_done, Replica};

/// nginx with the repository's `deploy/nginx.conf`; stopped when dropped.
struct Nginx {
    child: Child,
    port: u16,
}

impl Nginx {
    fn start(dir: &std::path::Path, upstreams: &[&str]) -> Self {
        let port = crate::common::free_port();
        let conf =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/deploy/nginx.conf"))
                .unwrap();
        // Only the addresses change: the compose file's service name and container port.
        assert!(conf.contains("server api:8080;") && conf.contains("listen 8080;"));
        let servers: String = upstreams
            .iter()
            .map(|a| format!("server {a};\n    "))
            .collect();
        let site = conf
            .replace("server api:8080;", servers.trim_end())
            .replace("listen 8080;", &format!("listen 127.0.0.1:{port};"));
        std::fs::create_dir_all(dir.join("logs")).unwrap();
        std::fs::write(dir.join("site.conf"), site).unwrap();
        // The parts of a main nginx.conf that the Docker image provides.
        let main = format!(
            "pid {d}/nginx.pid;\nerror_log {d}/logs/error.log;\nevents {{}}\nhttp {{\n  \
             access_log off;\n  client_body_temp_path {d}/body;\n  proxy_temp_path {d}/proxy;\n  \
             include {d}/site.conf;\n}}\n",
            d = dir.display()
        );
        std::fs::write(dir.join("main.conf"), main).unwrap();
        let child = Command::new("nginx")
            .args(["-p"])
            .arg(dir)
            .args(["-c"])
            .arg(dir.join("main.conf"))
            .args(["-g", "daemon off;"])
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("nginx is installed (apt-get install nginx-light; .ci/run does)");
        crate::common::wait_for_port(port, Duration::from_secs(10), "nginx");
        Nginx { child, port }
    }

    fn url(&self, path: &str) -> String {
        format!("http://127.0.0.1:{}{path}", self.port)
    }
}

impl Drop for Nginx {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_compose_load_balancer_config_serves_jobs_sse_and_uploads() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = RedisPrefix::new();
    let redis = redis_url();
    let data = dir.path().join("data");
    let api1 = Replica::spawn(&data, &redis, &prefix.0, "api", "api-1");
    let api2 = Replica::spawn(&data, &redis, &prefix.0, "api", "api-2");
    let _worker = Replica::spawn(&data, &redis, &prefix.0, "worker", "worker-1");
    let lb = Nginx::start(
        &dir.path().join("nginx"),
        &[api1.addr.as_str(), api2.addr.as_str()],
    );
    let c = reqwest::Client::new();

    // Round robin: the readiness answers come from both replicas.
    let mut seen = std::collections::BTreeSet::new();
    for _ in 0..6 {
        let r: Value = c
            .get(lb.url("/readyz"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        seen.insert(r["replica"].as_str().unwrap().to_string());
    }
    assert_eq!(
        seen.into_iter().collect::<Vec<_>>(),
        ["api-1", "api-2"],
        "nginx did not balance over both replicas"
    );

    // A job long enough to report progress, submitted and followed through nginx.
    let input = synthetic_npy();
    let params = json!({"width": 960, "height": 540, "samples": 4, "cell_size": 30.0, "mesh_max_vertices": 20000});
    let job = submit_to(&c, &lb.url("/v1/snow-terrain"), &input, &params).await;
    let id = job["id"].as_str().unwrap().to_string();
    let events = tokio::time::timeout(
        Duration::from_secs(300),
        sse(c.clone(), lb.url(&format!("/v1/jobs/{id}/events"))),
    )
    .await
    .unwrap();
    assert!(
        events.iter().any(|(e, d)| e == "progress"
            && d["status"] == "running"
            && d["progress"].as_f64().unwrap() > 0.0
            && d["progress"].as_f64().unwrap() < 1.0),
        "no progress before the end came through nginx: {events:?}"
    );
    assert_eq!(events.last().unwrap().1["status"], "succeeded");
    let done = wait_done(&c, &api1, &id, Duration::from_secs(60)).await;
    assert_eq!(done["worker"], "worker-1");
    let scratch = dir.path().join("cli");
    std::fs::create_dir_all(&scratch).unwrap();
    let lb_addr = format!("127.0.0.1:{}", lb.port);
    assert_same_as_cli(&c, &lb_addr, &id, &scratch, &input, &params).await;

    // A 20 MB upload through the proxy.
    let big = synthetic_npy_of(2240);
    let resp = c
        .post(lb.url("/v1/assets?filename=big.npy"))
        .header("content-type", "application/octet-stream")
        .body(big.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status().as_u16(), 201);
    let rec: Value = resp.json().await.unwrap();
    assert_eq!(rec["size"], json!(big.len()));
}
