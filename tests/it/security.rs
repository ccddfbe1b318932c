//! Security basics (issue 9): bearer-token authentication on `/v1`, CORS off by default and
//! configurable, no path traversal through any id or name, no secrets in the logged config.

use serde_json::{json, Value};

use crate::common::{problem, Server};

const TOKEN: &str = "s3cr3t-token-0123456789abcdef";

#[tokio::test]
async fn bearer_tokens_guard_every_v1_route_and_only_those() {
    let s = Server::start(|c| {
        c.auth_tokens = vec![TOKEN.into(), "another-token-fedcba9876543210".into()]
    })
    .await;
    for path in [
        "/v1/jobs",
        "/v1/jobs/0123456789abcdef0123456789abcdef",
        "/v1/examples/dem.asc",
        "/v1/nope",
    ] {
        let resp = s.client.get(s.url(path)).send().await.unwrap();
        assert_eq!(
            resp.headers()["www-authenticate"].to_str().unwrap(),
            "Bearer realm=\"phenomena\"",
            "{path}"
        );
        problem(resp, 401, "unauthorized").await;
        let wrong = s
            .client
            .get(s.url(path))
            .bearer_auth("s3cr3t-token-0123456789abcdeX")
            .send()
            .await
            .unwrap();
        problem(wrong, 401, "unauthorized").await;
    }
    // Either configured token opens the API.
    for t in [TOKEN, "another-token-fedcba9876543210"] {
        let ok = s
            .client
            .get(s.url("/v1/jobs"))
            .bearer_auth(t)
            .send()
            .await
            .unwrap();
        assert_eq!(ok.status(), 200);
    }
    // A submission without the token is refused before its body is read.
    let resp = s
        .client
        .post(s.url("/v1/snow-terrain"))
        .json(&json!({"asset": "0".repeat(64)}))
        .send()
        .await
        .unwrap();
    problem(resp, 401, "unauthorized").await;
    // Probes, the page and the API description stay open.
    for path in ["/healthz", "/readyz", "/metrics", "/openapi.yaml", "/"] {
        let resp = s.client.get(s.url(path)).send().await.unwrap();
        assert_eq!(resp.status(), 200, "{path}");
    }
    s.stop().await;
}

#[tokio::test]
async fn cors_is_off_by_default_and_follows_the_configured_origins() {
    let s = Server::start(|_| {}).await;
    let resp = s
        .client
        .get(s.url("/v1/jobs"))
        .header("Origin", "https://example.org")
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status(), 200);
    assert!(resp.headers().get("access-control-allow-origin").is_none());
    s.stop().await;

    let s = Server::start(|c| c.cors_origins = vec!["https://studio.example".into()]).await;
    let pre = s
        .client
        .request(reqwest::Method::OPTIONS, s.url("/v1/snow-terrain"))
        .header("Origin", "https://studio.example")
        .header("Access-Control-Request-Method", "POST")
        .header("Access-Control-Request-Headers", "content-type,prefer")
        .send()
        .await
        .unwrap();
    assert!(pre.status().is_success(), "{}", pre.status());
    assert_eq!(
        pre.headers()["access-control-allow-origin"]
            .to_str()
            .unwrap(),
        "https://studio.example"
    );
    let methods = pre.headers()["access-control-allow-methods"]
        .to_str()
        .unwrap()
        .to_string();
    assert!(methods.contains("POST"), "{methods}");
    // Another origin gets no grant.
    let other = s
        .client
        .get(s.url("/v1/jobs"))
        .header("Origin", "https://evil.example")
        .send()
        .await
        .unwrap();
    assert!(other.headers().get("access-control-allow-origin").is_none());
    s.stop().await;
}

#[tokio::test]
async fn no_path_traversal_through_ids_or_names() {
    let s = Server::start(|_| {}).await;
    // A real job, so that output names are looked up under an existing job directory.
    let resp = s.sleepy(json!({"ms": 1}), b"x").await;
    let job: Value = resp.json().await.unwrap();
    let id = job["id"].as_str().unwrap().to_string();
    s.wait_done(&id).await;
    let probes = [
        "/v1/jobs/..%2F..%2F..%2Fetc%2Fpasswd".to_string(),
        "/v1/jobs/..%2Fjobs/events".to_string(),
        format!("/v1/jobs/{id}/outputs/..%2Fjob.json"),
        format!("/v1/jobs/{id}/outputs/..%2F..%2F..%2FCargo.toml"),
        format!("/v1/jobs/{id}/outputs/%2Fetc%2Fpasswd"),
        "/v1/assets/..%2F..%2Fconfig".to_string(),
        "/v1/clouds/..%2F..%2Fclouds".to_string(),
        "/web/..%2F..%2FCargo.toml".to_string(),
        "/web/..%5C..%5CCargo.toml".to_string(),
        "/v1/examples/..%2F..%2FCargo.toml".to_string(),
    ];
    for p in probes {
        let resp = s.client.get(s.url(&p)).send().await.unwrap();
        assert_eq!(resp.status(), 404, "{p}");
        let body = resp.text().await.unwrap();
        assert!(
            !body.contains("[package]") && !body.contains("root:"),
            "{p}: {body}"
        );
    }
    s.stop().await;
}

#[test]
fn tokens_never_reach_the_logged_config() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = crate::common::test_config(dir.path());
    cfg.auth_tokens = vec![TOKEN.into()];
    let logged = serde_json::to_string(&cfg).unwrap();
    assert!(!logged.contains(TOKEN), "{logged}");
    assert!(logged.contains("1 token(s) redacted"), "{logged}");
}
