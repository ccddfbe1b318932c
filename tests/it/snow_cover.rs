//! `snow-cover` over HTTP on a real mesh: the job runs, answers as the spec says, and every output
//! downloads.

use serde_json::{json, Value};

use crate::common::{data, Server};
use crate::openapi::{checked, spec};

#[tokio::test]
async fn table_over_http() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    let mesh = std::fs::read(data("mesh/inventor_table.glb")).unwrap();
    let params = json!({"up_axis": "z", "resolution": 64, "directions": 4, "steps": 4,
                        "width": 128, "height": 96});
    let form = reqwest::multipart::Form::new()
        .text("params", params.to_string())
        .part(
            "mesh",
            reqwest::multipart::Part::bytes(mesh).file_name("inventor_table.glb"),
        );
    let r = s
        .client
        .post(s.url("/v1/snow-cover"))
        .header("prefer", "wait=60")
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let job = checked(&spec, "post", "/v1/snow-cover", r).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["params"]["repose_angle_deg"], json!(50.0));
    let names: Vec<&str> = job["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o["name"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        [
            "render.png",
            "snow.glb",
            "scene.glb",
            "displaced.glb",
            "report.json"
        ]
    );
    for o in job["outputs"].as_array().unwrap() {
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
    }
    // A mesh that is not one: 415; a bad parameter: 422 naming it.
    let form = reqwest::multipart::Form::new().text("params", "{}").part(
        "mesh",
        reqwest::multipart::Part::bytes(b"hello".to_vec()).file_name("x.bin"),
    );
    let r = s
        .client
        .post(s.url("/v1/snow-cover"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 415);
    checked(&spec, "post", "/v1/snow-cover", r).await;
    let form = reqwest::multipart::Form::new()
        .text(
            "params",
            json!({"wind": {"azimuth_deg": 10, "tilt_deg": 99}}).to_string(),
        )
        .part(
            "mesh",
            reqwest::multipart::Part::bytes(b"x".to_vec()).file_name("x.obj"),
        );
    let r = s
        .client
        .post(s.url("/v1/snow-cover"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let p: Value = checked(&spec, "post", "/v1/snow-cover", r).await;
    assert_eq!(p["field"], "wind.tilt_deg");
}
