//! The API held to `openapi.yaml` by Schemathesis (issues 9 and 20): every operation, every
//! check (`--checks all`: server errors, status codes, content types, response schemas and
//! headers, negative data rejected, positive data accepted, …), a bounded number of examples,
//! zero failures allowed.
//!
//! Needs the `st` command: `pip install schemathesis==4.32.5` (done by `.ci/run`). Alone:
//! `cargo test --workspace --test it conformance -- --nocapture`; more examples with
//! `PHENOMENA_ST_EXAMPLES=200`. The configuration is `tests/conformance/schemathesis.toml`;
//! `tests/conformance/hooks.py` gives positive cases real files and repairs the few rules across
//! fields that OpenAPI 3.1 cannot state (each listed there with its reason, and in RELIABILITY.md
//! "API conformance"). A schema-valid request answered 415 or 422 is a failure.

use std::path::PathBuf;

use serde_json::{json, Value};

use crate::common::Server;

/// Examples per operation and phase in the default run: enough to exercise every schema branch
/// once or twice in about a minute on 2 cores.
const DEFAULT_EXAMPLES: &str = "25";

/// The output pixel budget of the server under test (small: the point is the contract, not
/// rendering 8192² images in the test profile).
const MAX_PIXELS: u64 = 800 * 600;

async fn upload(s: &Server, bytes: Vec<u8>, filename: &str) -> String {
    let resp = s
        .client
        .post(s.url(&format!("/v1/assets?filename={filename}")))
        .body(bytes)
        .send()
        .await
        .unwrap();
    assert!(resp.status().is_success(), "{}", resp.status());
    resp.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string()
}

async fn example(s: &Server, name: &str) -> Vec<u8> {
    let resp = s
        .client
        .get(s.url(&format!("/v1/examples/{name}")))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status(), 200);
    resp.bytes().await.unwrap().to_vec()
}

async fn post_json(s: &Server, path: &str, body: Value) -> Value {
    let resp = s
        .client
        .post(s.url(path))
        .header("Prefer", "wait=30")
        .json(&body)
        .send()
        .await
        .unwrap();
    let status = resp.status();
    let body: Value = resp.json().await.unwrap();
    assert!(status.is_success(), "{path}: {status} {body}");
    body
}

/// `GET url` until `done` says the resource has settled (a job finished, a scene's versions
/// computed): the server under test honours no `Prefer: wait` (`max_wait_secs` 0).
async fn settled(s: &Server, url: &str, done: impl Fn(&Value) -> bool) -> Value {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(300);
    loop {
        let v: Value = s
            .client
            .get(s.url(url))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if done(&v) {
            return v;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "{url} did not settle: {v}"
        );
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
}

fn finished(job: &Value) -> bool {
    !matches!(job["status"].as_str(), Some("queued" | "running"))
}

fn computed(scene: &Value) -> bool {
    scene["versions"]
        .as_array()
        .is_some_and(|vs| vs.iter().all(|v| v["status"] != "pending"))
}

#[test]
fn schemathesis_finds_no_failures() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    // Small output budget (see MAX_PIXELS) and time limit.
    let s = rt.block_on(Server::start(|c| {
        c.max_output_pixels = MAX_PIXELS;
        c.job_timeout_secs = 20;
        // No `Prefer: wait` is honoured (a hint, RFC 7240; the answer is the documented 202
        // instead of 200): the schema's example `wait=10` would otherwise hold thousands of
        // requests while their jobs render. The hooks cancel each accepted job once its answer
        // is in (`after_call` in hooks.py), so what runs behind the checks stays small.
        c.max_wait_secs = 0;
        // Positive cases carry real files (hooks.py), so submissions queue real jobs: a short
        // queue bounds the work running behind the checks (a full queue is a documented 429,
        // answered after the params are validated).
        c.queue_capacity = 16;
    }));
    // The example files, for the hooks' positive multipart cases.
    let files = tempfile::tempdir().unwrap();
    let env = rt.block_on(async {
        let mut bytes = std::collections::HashMap::new();
        for name in ["dem.asc", "mesh.obj", "volume.npy"] {
            let b = example(&s, name).await;
            std::fs::write(files.path().join(name), &b).unwrap();
            bytes.insert(name, b);
        }
        let dem = upload(&s, bytes["dem.asc"].clone(), "dem.asc").await;
        let volume = upload(&s, bytes["volume.npy"].clone(), "volume.npy").await;
        let mesh = upload(&s, bytes["mesh.obj"].clone(), "mesh.obj").await;

        let params = json!({"width": 64, "height": 48});
        let job = post_json(
            &s,
            "/v1/snow-terrain",
            json!({"asset": dem, "params": params}),
        )
        .await;
        let other = json!({"width": 48, "height": 32});
        let cancel = post_json(
            &s,
            "/v1/snow-terrain",
            json!({"asset": dem, "params": other}),
        )
        .await;
        let scene = post_json(&s, "/v1/clouds", json!({"asset": volume})).await;
        let scene = settled(&s, scene["url"].as_str().unwrap(), computed).await;
        // A georeferenced DEM (UTM 32N) for the map routes.
        let utm = std::fs::read(root.join("tests/data/dem/kagwene_cameroon_elev_30m_utm32n.tif"))
            .unwrap();
        let utm = upload(&s, utm, "kagwene.tif").await;
        let map = post_json(&s, "/v1/maps", json!({"asset": utm.clone()})).await;
        let doomed = post_json(&s, "/v1/clouds", json!({"asset": volume})).await;
        let job = settled(&s, job["url"].as_str().unwrap(), finished).await;
        assert_eq!(job["status"], "succeeded", "{job}");
        assert!(
            scene["versions"][0]["status"] == "ready",
            "the scene the edits start from is computed: {scene}"
        );
        vec![
            ("PHENOMENA_JOB_ID", job["id"].as_str().unwrap().to_string()),
            (
                "PHENOMENA_CANCEL_JOB_ID",
                cancel["id"].as_str().unwrap().to_string(),
            ),
            ("PHENOMENA_ASSET_ID", dem.clone()),
            ("PHENOMENA_ST_DEM_ASSET", dem),
            ("PHENOMENA_ST_MESH_ASSET", mesh),
            ("PHENOMENA_ST_VOLUME_ASSET", volume),
            (
                "PHENOMENA_ST_FILES",
                files.path().to_str().unwrap().to_string(),
            ),
            ("PHENOMENA_ST_MAX_PIXELS", MAX_PIXELS.to_string()),
            ("PHENOMENA_ST_BASE", s.url("")),
            ("PHENOMENA_ST_MAP_ASSET", utm),
            ("SCHEMATHESIS_HOOKS", "hooks".to_string()),
            (
                "PYTHONPATH",
                root.join("tests/conformance").to_str().unwrap().to_string(),
            ),
            ("PHENOMENA_MAP_ID", map["id"].as_str().unwrap().to_string()),
            (
                "PHENOMENA_SCENE_ID",
                scene["id"].as_str().unwrap().to_string(),
            ),
            (
                "PHENOMENA_DELETE_SCENE_ID",
                doomed["id"].as_str().unwrap().to_string(),
            ),
        ]
    });
    let examples =
        std::env::var("PHENOMENA_ST_EXAMPLES").unwrap_or_else(|_| DEFAULT_EXAMPLES.to_string());
    let t0 = std::time::Instant::now();
    // Schemathesis' report goes to a file as it runs (`target/conformance-st.log`), so a slow
    // or stuck run can be watched; it is printed below when the run ends.
    let log_path = root.join("target/conformance-st.log");
    let log_file = std::fs::File::create(&log_path).unwrap();
    let status = std::process::Command::new("st")
        .arg("--config-file")
        .arg(root.join("tests/conformance/schemathesis.toml"))
        .args(["run", &s.url("/openapi.yaml")])
        .args(["--max-examples", &examples, "--workers", "1", "--seed", "1"])
        .args(["--checks", "all", "--request-timeout", "60", "--no-color"])
        .envs(env)
        .stdout(log_file.try_clone().unwrap())
        .stderr(log_file)
        .status()
        .expect("schemathesis (`st`) is needed: pip install schemathesis==4.32.5");
    // Reported, not asserted (timings go in RELIABILITY.md, not in assertions).
    println!("schemathesis ran {:.0} s", t0.elapsed().as_secs_f64());
    rt.block_on(s.stop());
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    println!("{log}");
    assert!(status.success(), "schemathesis found failures:\n{log}");
}
