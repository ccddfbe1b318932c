//! Hostile and careless input at the edges of the API (issue 20): absurd geometry is a 422
//! naming the problem before any pipeline runs, and every refusal is `application/problem+json`
//! (path-decoding failures, over-size declarations, duplicate JSON keys).

use serde_json::{json, Value};

use crate::common::{problem, Server};
use crate::openapi::{checked, spec};

/// A one-triangle OBJ with one vertex at `(x, 0, 0)`.
fn obj_with(x: &str) -> Vec<u8> {
    format!("v 0 0 0\nv {x} 0 0\nv 0 1 0\nf 1 2 3\n").into_bytes()
}

/// A one-triangle ASCII PLY (Z up) with one vertex at `(0, 0, z)`.
fn ply_with(z: &str) -> Vec<u8> {
    format!(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
         property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
         0 0 0\n1 0 0\n0 1 {z}\n3 0 1 2\n"
    )
    .into_bytes()
}

#[tokio::test]
async fn meshes_with_absurd_or_non_finite_coordinates_are_422_naming_the_vertex() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    // 1e20 made dust's BVH builder panic (an `internal` failure) before the bound existed.
    for (pipeline, input, filename, needle) in [
        ("dust", obj_with("1e20"), "a.obj", "vertex 1"),
        ("snow-cover", obj_with("1e20"), "a.obj", "vertex 1"),
        ("dust", obj_with("-3e9"), "a.obj", "vertex 1"),
        ("dust", ply_with("1e25"), "a.ply", "vertex 2"),
    ] {
        let r = s.submit(pipeline, "mesh", json!({}), input, filename).await;
        assert_eq!(r.status().as_u16(), 422, "{pipeline} {filename}");
        let body: Value = checked(&spec, "post", &format!("/v1/{pipeline}"), r).await;
        assert_eq!(
            body["type"], "https://phenomena.dev/problems/invalid-input",
            "{body}"
        );
        assert_eq!(body["field"], "mesh", "{body}");
        let detail = body["detail"].as_str().unwrap();
        assert!(
            detail.contains(needle) && detail.contains("1e9"),
            "{pipeline}: {detail}"
        );
    }
    // Non-finite positions were already refused; still a 422 naming the vertex.
    let r = s
        .submit("dust", "mesh", json!({}), obj_with("inf"), "a.obj")
        .await;
    let body = problem(r, 422, "invalid-input").await;
    assert!(
        body["detail"].as_str().unwrap().contains("vertex 1"),
        "{body}"
    );
    // Geo-referenced coordinates (UTM, ~1e7 m) are within the range: accepted (and canceled).
    let r = s
        .submit(
            "dust",
            "mesh",
            json!({"width": 64, "height": 48, "shells": 2, "texture_size": 64}),
            b"v 5e6 4e6 0\nv 5000001 4e6 0\nv 5e6 4000001 0\nf 1 2 3\n".to_vec(),
            "utm.obj",
        )
        .await;
    let job: Value = r.json().await.unwrap();
    assert!(
        job["status"] == "queued" || job["status"] == "running",
        "{job}"
    );
    let id = job["id"].as_str().unwrap();
    s.client
        .delete(s.url(&format!("/v1/jobs/{id}")))
        .send()
        .await
        .unwrap();
}

#[tokio::test]
async fn volume_bounds_outside_the_coordinate_range_or_too_thin_are_422_naming_the_axis() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    let volume = crate::common::npy_f32(&[2, 2, 2], vec![0.5; 8]);
    for (bounds, axis) in [
        (json!([[0, 0, 0], [1, 1e12, 1]]), "y:"),
        (json!([[-1e20, 0, 0], [1, 1, 1]]), "x:"),
        (json!([[0, 0, 0], [1, 1, 1e-9]]), "z:"),
        // 1 m wide at 1e8 m from the origin: both faces are the same f32.
        (json!([[1e8, 0, 0], [100000001.0, 1, 1]]), "x:"),
        (json!([[0, 0, 0], [1, 0, 1]]), "y:"),
    ] {
        let params = json!({"bounds": bounds, "width": 64, "height": 48});
        let r = s
            .submit("cloud", "volume", params, volume.clone(), "v.npy")
            .await;
        assert_eq!(r.status().as_u16(), 422, "{bounds}");
        let body: Value = checked(&spec, "post", "/v1/cloud", r).await;
        assert_eq!(
            body["type"], "https://phenomena.dev/problems/invalid-parameter",
            "{body}"
        );
        assert_eq!(body["field"], "bounds", "{body}");
        assert!(
            body["detail"]
                .as_str()
                .unwrap()
                .starts_with(&format!("bounds: {axis}")),
            "{bounds}: {body}"
        );
        // The scene resource validates the same options.
        let r = s
            .submit(
                "clouds",
                "volume",
                json!({"bounds": bounds}),
                volume.clone(),
                "v.npy",
            )
            .await;
        let body = problem(r, 422, "invalid-parameter").await;
        assert_eq!(body["field"], "bounds", "{body}");
    }
}

/// Sends `head` (request line and headers, no body) on a raw connection and returns what the
/// server answers within 5 s, without sending a byte of body.
async fn raw_exchange(addr: std::net::SocketAddr, head: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut c = tokio::net::TcpStream::connect(addr).await.unwrap();
    c.write_all(head.as_bytes()).await.unwrap();
    let mut out = Vec::new();
    let read = tokio::time::timeout(std::time::Duration::from_secs(5), async {
        let mut buf = [0u8; 4096];
        loop {
            match c.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => out.extend_from_slice(&buf[..n]),
            }
            let text = String::from_utf8_lossy(&out);
            if let Some((head, body)) = text.split_once("\r\n\r\n") {
                let len = head.lines().find_map(|l| {
                    l.to_ascii_lowercase()
                        .strip_prefix("content-length:")
                        .map(|v| v.trim().parse::<usize>().unwrap())
                });
                if len.is_some_and(|n| body.len() >= n) {
                    break;
                }
            }
        }
    })
    .await;
    assert!(
        read.is_ok(),
        "no answer within 5 s: {:?}",
        String::from_utf8_lossy(&out)
    );
    String::from_utf8(out).unwrap()
}

#[tokio::test]
async fn a_declared_content_length_over_the_cap_is_413_at_once() {
    let s = Server::start(|c| c.max_body_bytes = 1 << 20).await;
    for path in ["/v1/assets", "/v1/snow-terrain", "/v1/clouds"] {
        let answer = raw_exchange(
            s.addr,
            &format!(
                "POST {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/octet-stream\r\n\
                 Content-Length: 10000000\r\n\r\n"
            ),
        )
        .await;
        let (head, body) = answer.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 413"), "{path}: {head}");
        let head = head.to_ascii_lowercase();
        assert!(
            head.contains("content-type: application/problem+json"),
            "{path}: {head}"
        );
        assert!(head.contains("connection: close"), "{path}: {head}");
        let body: Value = serde_json::from_str(body).unwrap();
        assert_eq!(body["type"], "https://phenomena.dev/problems/too-large");
        let detail = body["detail"].as_str().unwrap();
        assert!(
            detail.contains("10000000") && detail.contains("1048576"),
            "{detail}"
        );
    }
    // At the cap is not refused up front (the body is read; this one is not a DEM).
    let r = s
        .client
        .post(s.url("/v1/assets"))
        .body(vec![7u8; 1 << 20])
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
}

#[tokio::test]
async fn a_path_that_does_not_decode_is_400_problem_json() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    for path in [
        "/v1/jobs/%FF",
        "/v1/assets/%C3%28",
        "/v1/jobs/%FF/outputs/render.png",
        "/v1/clouds/%FE",
        "/web/%FF",
    ] {
        let r = s.client.get(s.url(path)).send().await.unwrap();
        assert_eq!(r.status().as_u16(), 400, "{path}");
        let body = problem(r, 400, "bad-request").await;
        assert!(
            body["detail"].as_str().unwrap().contains("cannot be read"),
            "{body}"
        );
    }
    let r = s.client.get(s.url("/v1/jobs/%FF")).send().await.unwrap();
    checked(&spec, "get", "/v1/jobs/{id}", r).await;
}

/// A `.npy` header (v1) declaring `shape` for little-endian float32, and no data.
fn npy_header(shape: &str) -> Vec<u8> {
    let mut dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + dict.len() + 1) % 64 != 0 {
        dict.push(' ');
    }
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

#[tokio::test]
async fn a_shape_that_overflows_names_the_configured_limit_not_u64_max() {
    let s = Server::start(|_| {}).await;
    let r = s
        .submit(
            "snow-terrain",
            "dem",
            json!({"cell_size": 10}),
            npy_header("(4294967296, 4294967296, 16)"),
            "dem.npy",
        )
        .await;
    let body = problem(r, 413, "too-large").await;
    let detail = body["detail"].as_str().unwrap();
    assert!(!detail.contains("18446744073709551615"), "{detail}");
    assert!(
        detail.contains("more than 2^64") && detail.contains("the limit is 67108864"),
        "{detail}"
    );
}

#[tokio::test]
async fn duplicate_json_keys_are_refused_naming_the_key() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    let dem = b"ncols 4\nnrows 4\nxllcorner 0\nyllcorner 0\ncellsize 10\n\
                1 2 3 4\n1 2 3 4\n1 2 3 4\n1 2 3 4\n"
        .to_vec();
    // In the multipart params part: 422 naming the parameter.
    let form = reqwest::multipart::Form::new()
        .text(
            "params",
            r#"{"seed": 1, "camera": {"fov_deg": 30, "fov_deg": 60}}"#,
        )
        .part(
            "dem",
            reqwest::multipart::Part::bytes(dem.clone()).file_name("dem.asc"),
        );
    let r = s
        .client
        .post(s.url("/v1/snow-terrain"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let body: Value = checked(&spec, "post", "/v1/snow-terrain", r).await;
    assert_eq!(
        body["type"],
        "https://phenomena.dev/problems/invalid-parameter"
    );
    assert_eq!(body["field"], "camera.fov_deg", "{body}");
    assert!(body["detail"].as_str().unwrap().contains("twice"), "{body}");

    // In a JSON body: inside params, 422 naming the parameter; at the top, 400 naming the field.
    let id = "a".repeat(64);
    for (text, status, field) in [
        (
            format!(r#"{{"asset": "{id}", "params": {{"seed": 1, "seed": 2}}}}"#),
            422,
            "seed",
        ),
        (
            format!(r#"{{"asset": "{id}", "asset": "{id}"}}"#),
            400,
            "asset",
        ),
    ] {
        let r = s
            .client
            .post(s.url("/v1/snow-terrain"))
            .header("content-type", "application/json")
            .body(text.clone())
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), status, "{text}");
        let body: Value = checked(&spec, "post", "/v1/snow-terrain", r).await;
        assert_eq!(body["field"], field, "{text}: {body}");
    }

    // A cloud render's body: the duplicate is found before the scene is looked up.
    let r = s
        .client
        .post(s.url("/v1/clouds/00000000000000000000000000000000/renders"))
        .header("content-type", "application/json")
        .body(r#"{"width": 64, "width": 4096}"#)
        .send()
        .await
        .unwrap();
    let body = problem(r, 422, "invalid-parameter").await;
    assert_eq!(body["field"], "width", "{body}");
}

#[tokio::test]
async fn a_full_queue_is_answered_before_the_input_is_decoded() {
    let s = Server::start(|c| {
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
    s.wait_running(a["id"].as_str().unwrap()).await;
    let b: Value = s
        .sleepy(json!({"stages": 100, "ms": 20}), b"2")
        .await
        .json()
        .await
        .unwrap();
    // A corrupt input would be 422 once decoded; with the queue full it is 429 without a decode.
    let r = s.sleepy(json!({}), b"corrupt bytes").await;
    assert_eq!(r.headers()["retry-after"], "5");
    problem(r, 429, "queue-full").await;
    for j in [&a, &b] {
        s.client
            .delete(s.url(&format!("/v1/jobs/{}", j["id"].as_str().unwrap())))
            .send()
            .await
            .unwrap();
    }
    // With room again the same submission is decoded and refused for what it is.
    let id = a["id"].as_str().unwrap();
    assert_eq!(s.wait_done(id).await["status"], "canceled");
    let r = s.sleepy(json!({}), b"corrupt bytes").await;
    problem(r, 422, "invalid-input").await;
}

#[tokio::test]
async fn a_multipart_input_is_streamed_to_the_store_as_an_asset() {
    let s = Server::start(|_| {}).await;
    let bytes = b"streamed input".to_vec();
    let r = s.sleepy(json!({}), &bytes).await;
    assert_eq!(r.status().as_u16(), 202);
    let sha = phenomena::store::sha256_hex(&bytes);
    let asset = s.get_json(&format!("/v1/assets/{sha}")).await;
    assert_eq!(asset["size"], json!(bytes.len()), "{asset}");
    assert_eq!(asset["filename"], "x.bin", "{asset}");
    // An empty part is still a 400 naming it.
    let r = s.sleepy(json!({}), b"").await;
    let body = problem(r, 400, "bad-request").await;
    assert_eq!(body["field"], "data", "{body}");
}

/// One memory budget per process (issue 20): a job's estimated peak memory is recorded on the job
/// (`input.memory`), within the budget; a job estimated above the whole budget is 413 at
/// submission, naming the budget, and is never queued.
#[tokio::test]
async fn a_job_larger_than_the_memory_budget_is_413_and_one_within_it_runs() {
    const BUDGET: u64 = 48 << 20;
    let s = Server::start(|c| c.memory_budget_bytes = BUDGET).await;
    let dem = s
        .client
        .get(s.url("/v1/examples/dem.asc"))
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap()
        .to_vec();
    let small = json!({"width": 320, "height": 240, "samples": 2});
    let r = s
        .submit("snow-terrain", "dem", small, dem.clone(), "dem.asc")
        .await;
    assert_eq!(r.status().as_u16(), 202);
    let job: Value = r.json().await.unwrap();
    let memory = job["input"]["memory"].as_u64().expect("an estimate");
    // At least the output image's pixels at 32 B each, at most the budget.
    assert!((320 * 240 * 32..=BUDGET).contains(&memory), "{job}");
    let done = s.wait_done(job["id"].as_str().unwrap()).await;
    assert_eq!(done["status"], "succeeded", "{done}");

    // 4096² pixels at 32 B each is 512 MiB: over the budget whatever the DEM.
    let big = json!({"width": 4096, "height": 4096});
    let r = s.submit("snow-terrain", "dem", big, dem, "dem.asc").await;
    let body = problem(r, 413, "too-large").await;
    let detail = body["detail"].as_str().unwrap();
    assert!(detail.contains("memory budget of 48 MiB"), "{detail}");
    let list = s.get_json("/v1/jobs").await;
    assert_eq!(list["jobs"].as_array().unwrap().len(), 1, "{list}");
}
