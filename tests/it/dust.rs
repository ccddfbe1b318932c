//! `dust` over HTTP on a real mesh: the job answers as the spec says, every output downloads,
//! the CLI writes the same bytes, and bad input is refused with the field or format named.

use std::process::Command;

use serde_json::{json, Value};

use crate::common::{data, Server};
use crate::openapi::{checked, spec};

const BIN: &str = env!("CARGO_BIN_EXE_phenomena");

/// Small enough to run in a second: 8 shells of 128² textures.
fn params() -> Value {
    json!({"width": 200, "height": 150, "shells": 8, "texture_size": 128, "fibers": 400,
           "exposure_rays": 16, "seed": 5})
}

#[tokio::test]
async fn bunny_over_http_and_the_cli_give_the_same_bytes() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    let mesh = std::fs::read(data("mesh/bunny_npm.obj")).unwrap();
    let form = reqwest::multipart::Form::new()
        .text("params", params().to_string())
        .part(
            "mesh",
            reqwest::multipart::Part::bytes(mesh).file_name("bunny_npm.obj"),
        );
    let r = s
        .client
        .post(s.url("/v1/dust"))
        .header("prefer", "wait=120")
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let job = checked(&spec, "post", "/v1/dust", r).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["pipeline"], "dust");
    // Resolved defaults come back in the job's params.
    assert_eq!(job["params"]["stickiness"], json!(1.0));
    assert_eq!(job["params"]["dust_color"], "#e7e2da");
    let outputs = job["outputs"].as_array().unwrap();
    let names: Vec<&str> = outputs
        .iter()
        .map(|o| o["name"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        [
            "render.png",
            "fibers.png",
            "dust_amount.png",
            "dusty.glb",
            "report.json"
        ]
    );
    let mut served = Vec::new();
    for o in outputs {
        let r = s
            .client
            .get(s.url(o["url"].as_str().unwrap()))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 200);
        assert_eq!(
            r.headers()["content-type"].to_str().unwrap(),
            o["media_type"].as_str().unwrap()
        );
        let b = r.bytes().await.unwrap().to_vec();
        assert_eq!(b.len() as u64, o["size"].as_u64().unwrap());
        served.push((o["name"].as_str().unwrap().to_string(), b));
    }
    assert_eq!(&served[3].1[0..4], b"glTF");

    // The CLI, same parameters: the same bytes (report.json: the same but for timings).
    let dir = tempfile::tempdir().unwrap();
    let pfile = dir.path().join("p.json");
    std::fs::write(&pfile, params().to_string()).unwrap();
    let status = Command::new(BIN)
        .args(["render", "dust", "--quiet", "--input"])
        .arg(data("mesh/bunny_npm.obj"))
        .arg("--params")
        .arg(&pfile)
        .arg("--out")
        .arg(dir.path())
        .status()
        .unwrap();
    assert!(status.success());
    for (name, bytes) in &served {
        let offline = std::fs::read(dir.path().join(name)).unwrap();
        if name == "report.json" {
            let mut a: Value = serde_json::from_slice(bytes).unwrap();
            let mut b: Value = serde_json::from_slice(&offline).unwrap();
            for v in [&mut a, &mut b] {
                v.as_object_mut().unwrap().remove("timings");
                v.as_object_mut().unwrap().remove("total_ms");
            }
            assert_eq!(a, b);
        } else {
            assert!(bytes == &offline, "{name} differs between HTTP and CLI");
        }
    }

    // Not a mesh: 415; a bad parameter: 422 naming it.
    let form = reqwest::multipart::Form::new().text("params", "{}").part(
        "mesh",
        reqwest::multipart::Part::bytes(b"hello".to_vec()).file_name("x.bin"),
    );
    let r = s
        .client
        .post(s.url("/v1/dust"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 415);
    checked(&spec, "post", "/v1/dust", r).await;
    for (p, field) in [
        (json!({"bends": 48}), "bends"),
        (json!({"dust_color": "beige"}), "dust_color"),
        (json!({"fibres": 10}), "fibres"),
    ] {
        let form = reqwest::multipart::Form::new()
            .text("params", p.to_string())
            .part(
                "mesh",
                reqwest::multipart::Part::bytes(b"x".to_vec()).file_name("x.obj"),
            );
        let r = s
            .client
            .post(s.url("/v1/dust"))
            .multipart(form)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 422, "{p}");
        let body: Value = checked(&spec, "post", "/v1/dust", r).await;
        assert_eq!(body["field"], field, "{body}");
    }
}
