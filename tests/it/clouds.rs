//! Cloud scenes over HTTP (issue 5): a whole edit session — upload, the three edits, undo to
//! version 2, a render from a new camera — plus the one-shot `cloud` pipeline, the errors, and a
//! scene surviving a restart. Every JSON response is validated against `openapi.yaml`.

use serde_json::{json, Value};

use crate::common::{npy_f32, problem, Server};
use crate::openapi::{checked, spec};

/// A 32³ cumulus-like blob: a dense round core with a smaller bump on top, as NumPy `.npy`
/// (C order z, y, x).
pub(crate) fn blob_npy() -> Vec<u8> {
    let n = 32usize;
    let mut data = Vec::with_capacity(n * n * n);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = [x, y, z].map(|c| (c as f32 + 0.5) / n as f32 - 0.5);
                let core = (p[0] * p[0] + (p[1] + 0.08).powi(2) + p[2] * p[2]).sqrt();
                let bump = ((p[0] - 0.1).powi(2) + (p[1] - 0.22).powi(2) + p[2] * p[2]).sqrt();
                let d = (1.0 - core / 0.3).max(0.0) + 0.8 * (1.0 - bump / 0.14).max(0.0);
                data.push(d.min(1.0));
            }
        }
    }
    npy_f32(&[n as u64; 3], data)
}

const VIEW: (u32, u32) = (96, 72);

fn view() -> Value {
    json!({"width": VIEW.0, "height": VIEW.1, "camera": {"azimuth_deg": 180, "elevation_deg": 5}})
}

/// `view()` merged with `extra`.
fn with_view(extra: Value) -> Value {
    let mut v = view();
    v.as_object_mut()
        .unwrap()
        .extend(extra.as_object().unwrap().clone());
    v
}

/// A 3×3 block of pixels around (x, y).
fn block(x: i64, y: i64) -> Value {
    let mut px = Vec::new();
    for dy in -1..=1 {
        for dx in -1..=1 {
            px.push(json!([x + dx, y + dy]));
        }
    }
    Value::Array(px)
}

async fn create(s: &Server, params: Value) -> reqwest::Response {
    let form = reqwest::multipart::Form::new()
        .text("params", params.to_string())
        .part(
            "volume",
            reqwest::multipart::Part::bytes(blob_npy()).file_name("blob.npy"),
        );
    s.client
        .post(s.url("/v1/clouds"))
        .multipart(form)
        .send()
        .await
        .unwrap()
}

async fn post_json(s: &Server, path: &str, body: Value) -> reqwest::Response {
    s.client
        .post(s.url(path))
        .header("prefer", "wait=60")
        .json(&body)
        .send()
        .await
        .unwrap()
}

async fn bytes(s: &Server, url: &str) -> Vec<u8> {
    let r = s.client.get(s.url(url)).send().await.unwrap();
    assert_eq!(r.status(), 200, "{url}");
    r.bytes().await.unwrap().to_vec()
}

/// The render.png of a finished job.
async fn render_of(s: &Server, job: &Value) -> Vec<u8> {
    assert_eq!(job["status"], "succeeded", "{job}");
    let url = job["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["name"] == "render.png")
        .unwrap()["url"]
        .as_str()
        .unwrap()
        .to_string();
    bytes(s, &url).await
}

async fn edit(s: &Server, spec: &Value, scene: &str, kind: &str, body: Value) -> Value {
    let r = post_json(s, &format!("/v1/clouds/{scene}/edits/{kind}"), body).await;
    let status = r.status().as_u16();
    let v = checked(spec, "post", &format!("/v1/clouds/{{id}}/edits/{kind}"), r).await;
    assert_eq!(status, 200, "{v}");
    v
}

crate::on_each_backend! {

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_whole_edit_session_over_http() {
    let spec = spec();
    let s = start(|_| {}).await;

    // Upload: version 1 with the given state, the volume described.
    let r = create(&s, json!({"kappa": 40, "background": "#000000"})).await;
    assert_eq!(r.status(), 201);
    let location = r.headers()["location"].to_str().unwrap().to_string();
    let scene = checked(&spec, "post", "/v1/clouds", r).await;
    let id = scene["id"].as_str().unwrap().to_string();
    assert_eq!(location, format!("/v1/clouds/{id}"));
    assert_eq!(scene["info"]["dims"], json!([32, 32, 32]));
    assert_eq!(scene["latest_version"], 1);
    assert_eq!(scene["versions"][0]["state"]["kappa"], json!(40.0));
    let v1 = scene["versions"][0]["state"].clone();

    // A render of version 1 at the edit view: it carries the linear layers the sun-colour edit
    // below reads instead of marching.
    let mut body = view();
    body["version"] = json!(1);
    let r = post_json(&s, &format!("/v1/clouds/{id}/renders"), body).await;
    let job = checked(&spec, "post", "/v1/clouds/{id}/renders", r).await;
    let v1_layers = output_blob(&job, "layers.bin");

    // Sun colour: paint the lit core red; the least-squares sun turns red.
    let (cx, cy) = (VIEW.0 as i64 / 2, VIEW.1 as i64 / 2);
    let v = edit(
        &s,
        &spec,
        &id,
        "sun-color",
        with_view(json!({"strokes": [{"color": "#ff4020", "pixels": block(cx, cy)}]})),
    )
    .await;
    assert_eq!(v["version"], 2);
    assert_eq!(v["parent"], 1);
    assert_eq!(v["status"], "ready", "{v}");
    let sun = v["state"]["sun_color"].as_array().unwrap().clone();
    let sun: Vec<f64> = sun.iter().map(|c| c.as_f64().unwrap()).collect();
    assert!(sun[0] > 2.0 * sun[2], "the sun should turn red: {sun:?}");
    let v2_state = v["state"].clone();
    assert!(v["render_url"].is_string());
    let v2_job = job_of(&s, &v).await;
    assert_eq!(layers_input(&v2_job), Some(v1_layers.clone()), "{v2_job}");
    assert!(stages(&v2_job).contains(&"recolor".to_string()), "{v2_job}");
    // A sun-colour change leaves Ī, A and α alone: the new version's layers are the same blob.
    assert_eq!(output_blob(&v2_job, "layers.bin"), v1_layers);

    // Ambient: paint blue into the cloud; the version gets its own field.
    let v = edit(
        &s,
        &spec,
        &id,
        "ambient",
        with_view(json!({"strokes": [{"color": "#2040ff", "pixels": block(cx, cy + 6)}]})),
    )
    .await;
    assert_eq!(v["version"], 3);
    assert_eq!(v["status"], "ready", "{v}");
    let field = v["ambient_field"].as_str().unwrap().to_string();

    // Sun direction: drag from the core to its edge; the sun moves, the field is inherited.
    let v = edit(
        &s,
        &spec,
        &id,
        "sun-direction",
        with_view(json!({"from": [cx, cy], "to": [cx + 8, cy + 4]})),
    )
    .await;
    assert_eq!(v["version"], 4);
    assert_eq!(v["status"], "ready", "{v}");
    assert_ne!(v["state"]["sun_direction"], v2_state["sun_direction"]);
    assert_eq!(v["ambient_field"].as_str(), Some(field.as_str()));

    // The scene lists the four versions, all ready.
    let r = s
        .client
        .get(s.url(&format!("/v1/clouds/{id}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let scene = checked(&spec, "get", "/v1/clouds/{id}", r).await;
    let kinds: Vec<&str> = scene["versions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["kind"].as_str().unwrap())
        .collect();
    assert_eq!(kinds, ["upload", "sun-color", "ambient", "sun-direction"]);
    assert_eq!(scene["latest_version"], 4);
    assert_eq!(scene["versions"][0]["state"], v1);

    // Undo to version 2 and render it from a new camera; the same state through the one-shot
    // pipeline gives the same bytes, and version 4 looks different.
    let new_view =
        json!({"width": 80, "height": 64, "camera": {"azimuth_deg": 120, "elevation_deg": 25}});
    let mut body = new_view.clone();
    body["version"] = json!(2);
    let r = post_json(&s, &format!("/v1/clouds/{id}/renders"), body).await;
    let job = checked(&spec, "post", "/v1/clouds/{id}/renders", r).await;
    let v2_render = render_of(&s, &job).await;

    // (A different seed, which the renderer does not use, keeps the request from simply
    // joining the scene's job.)
    let mut one_shot = v2_state.clone();
    one_shot
        .as_object_mut()
        .unwrap()
        .extend(new_view.as_object().unwrap().clone());
    one_shot["seed"] = json!(7);
    let r = s
        .submit("cloud", "volume", one_shot, blob_npy(), "blob.npy")
        .await;
    let job = s
        .wait_done(r.json::<Value>().await.unwrap()["id"].as_str().unwrap())
        .await;
    assert_eq!(render_of(&s, &job).await, v2_render);

    let mut body = new_view.clone();
    body["version"] = json!(4);
    let r = post_json(&s, &format!("/v1/clouds/{id}/renders"), body).await;
    let job = checked(&spec, "post", "/v1/clouds/{id}/renders", r).await;
    assert_ne!(render_of(&s, &job).await, v2_render);

    // Editing an older version branches from it.
    let mut body = with_view(json!({"strokes": [{"color": "#ffffff", "pixels": block(cx, cy)}]}));
    body["base_version"] = json!(2);
    let v = edit(&s, &spec, &id, "sun-color", body).await;
    assert_eq!(
        (v["version"].as_u64(), v["parent"].as_u64()),
        (Some(5), Some(2))
    );
    assert!(
        v.get("ambient_field").is_none(),
        "version 2 had no field: {v}"
    );
    // Made at the view of version 2's own edit: that edit's render layers were read.
    let v5_job = job_of(&s, &v).await;
    assert_eq!(
        layers_input(&v5_job),
        Some(output_blob(&v2_job, "layers.bin"))
    );
    assert!(stages(&v5_job).contains(&"recolor".to_string()), "{v5_job}");

    // At a view no render of version 4 has: marched, no layers input.
    let mut body = with_view(json!({"strokes": [{"color": "#ffffff", "pixels": block(cx, cy)}]}));
    body["width"] = json!(VIEW.0 + 2);
    body["base_version"] = json!(4);
    let v = edit(&s, &spec, &id, "sun-color", body).await;
    assert_eq!(v["status"], "ready", "{v}");
    let v6_job = job_of(&s, &v).await;
    assert_eq!(layers_input(&v6_job), None, "{v6_job}");
    assert!(
        !stages(&v6_job).contains(&"recolor".to_string()),
        "{v6_job}"
    );
}

/// The job that computed a version.
async fn job_of(s: &Server, version: &Value) -> Value {
    let url = version["job_url"].as_str().unwrap();
    s.client
        .get(s.url(url))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap()
}

/// The blob of a finished job's output `name`.
fn output_blob(job: &Value, name: &str) -> String {
    assert_eq!(job["status"], "succeeded", "{job}");
    job["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["name"] == name)
        .unwrap_or_else(|| panic!("no {name} in {job}"))["sha256"]
        .as_str()
        .unwrap()
        .to_string()
}

/// The `layers.bin` auxiliary input of a job, if any.
fn layers_input(job: &Value) -> Option<String> {
    job["input"]["aux"]
        .as_array()?
        .iter()
        .find(|a| a["name"] == "layers.bin")
        .map(|a| a["blob"].as_str().unwrap().to_string())
}

/// The stages a job reported timings for.
fn stages(job: &Value) -> Vec<String> {
    job["timings"]
        .as_array()
        .map(|t| {
            t.iter()
                .map(|x| x["stage"].as_str().unwrap().to_string())
                .collect()
        })
        .unwrap_or_default()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_edits_and_scenes_are_clear_errors() {
    let spec = spec();
    let s = start(|_| {}).await;
    // View parameters belong to renders, not scenes.
    let r = create(&s, json!({"width": 100})).await;
    let p = problem(r, 422, "invalid-parameter").await;
    assert_eq!(p["field"], "width");
    let r = create(&s, json!({"kappa": -1})).await;
    assert_eq!(problem(r, 422, "invalid-parameter").await["field"], "kappa");

    let r = create(&s, json!({})).await;
    let id = checked(&spec, "post", "/v1/clouds", r).await["id"]
        .as_str()
        .unwrap()
        .to_string();

    // Unknown scene, unknown mode, unknown version, bad stroke.
    let r = post_json(
        &s,
        &format!("/v1/clouds/{}/renders", "0".repeat(32)),
        json!({}),
    )
    .await;
    problem(r, 404, "not-found").await;
    let r = post_json(&s, &format!("/v1/clouds/{id}/edits/wind"), json!({})).await;
    problem(r, 404, "not-found").await;
    let r = post_json(
        &s,
        &format!("/v1/clouds/{id}/renders"),
        json!({"version": 9}),
    )
    .await;
    // A version number naming no version is a missing resource, like an unknown scene.
    let p = problem(r, 404, "not-found").await;
    assert!(
        p["detail"].as_str().unwrap().contains("has no version 9"),
        "{p}"
    );
    let r = post_json(&s, &format!("/v1/clouds/{id}/renders"), json!({"kappa": 3})).await;
    assert_eq!(problem(r, 422, "invalid-parameter").await["field"], "kappa");
    let r = post_json(
        &s,
        &format!("/v1/clouds/{id}/edits/sun-color"),
        with_view(json!({"strokes": [{"color": "#zzzzzz", "pixels": [[1, 1]]}]})),
    )
    .await;
    let p = checked(&spec, "post", "/v1/clouds/{id}/edits/sun-color", r).await;
    assert!(p["field"].as_str().unwrap().starts_with("strokes"), "{p}");

    // A drag that starts on empty sky: the version fails with the reason.
    let r = post_json(
        &s,
        &format!("/v1/clouds/{id}/edits/sun-direction"),
        with_view(json!({"from": [1, 1], "to": [VIEW.0 / 2, VIEW.1 / 2]})),
    )
    .await;
    let v = checked(&spec, "post", "/v1/clouds/{id}/edits/sun-direction", r).await;
    assert_eq!(v["status"], "failed", "{v}");
    assert!(v["error"]["detail"].as_str().unwrap().len() > 10, "{v}");
    // Editing the failed version is a conflict; the default base skips it.
    let r = post_json(
        &s,
        &format!("/v1/clouds/{id}/edits/sun-color"),
        with_view(
            json!({"base_version": 2, "strokes": [{"color": "#ffffff", "pixels": [[48, 36]]}]}),
        ),
    )
    .await;
    problem(r, 409, "conflict").await;
    let r = post_json(
        &s,
        &format!("/v1/clouds/{id}/edits/sun-color"),
        with_view(json!({"strokes": [{"color": "#ffffff", "pixels": block(48, 36)}]})),
    )
    .await;
    let v = checked(&spec, "post", "/v1/clouds/{id}/edits/sun-color", r).await;
    assert_eq!(
        (v["version"].as_u64(), v["parent"].as_u64()),
        (Some(3), Some(1)),
        "{v}"
    );

    // Delete.
    let r = s
        .client
        .delete(s.url(&format!("/v1/clouds/{id}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    let r = s
        .client
        .get(s.url(&format!("/v1/clouds/{id}")))
        .send()
        .await
        .unwrap();
    problem(r, 404, "not-found").await;
}

/// Issue 18 over HTTP: a real 0/255 mask (the frog, 4× reduced; `tests/data/volume`) uploaded with
/// no parameters gets a κ chosen from it, stated in version 1's state; the `set` edit gives κ
/// and the sun directly; a stroke on empty sky and a stroke on unlit cloud fail with their own
/// problem types.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mask_scene_chooses_its_kappa_and_tells_its_refusals_apart() {
    let spec = spec();
    let s = start(|_| {}).await;
    let mask = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/volume/frog_body_mask_4x.nrrd"
    ))
    .unwrap();
    let form = reqwest::multipart::Form::new()
        .text("params", "{}")
        .part(
            "volume",
            reqwest::multipart::Part::bytes(mask).file_name("frog.nrrd"),
        );
    let r = s
        .client
        .post(s.url("/v1/clouds"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let scene = checked(&spec, "post", "/v1/clouds", r).await;
    let id = scene["id"].as_str().unwrap().to_string();
    let v1 = &scene["versions"][0]["state"];
    let kappa = v1["kappa"].as_f64().unwrap();
    // 0/255 densities: κ far below the former fixed default of 120.
    assert!(kappa > 0.0 && kappa < 1.0, "{v1}");
    assert_eq!(scene["info"]["kappa"], v1["kappa"]);
    assert_eq!(v1["kappa_auto"]["optical_depth"], json!(4.0));
    // The density floor the decoder chose (a mask's empty background: 0) is the version's too,
    // so its renders' layers.bin identity matches its edits' base.
    assert_eq!(v1["density_floor"], json!(0.0), "{v1}");
    assert_eq!(scene["info"]["density_floor"], v1["density_floor"]);
    assert!(v1["density_floor_auto"]["rule"].is_string(), "{v1}");

    // Paint on the sky: "misses the cloud".
    let v = edit(
        &s,
        &spec,
        &id,
        "sun-color",
        with_view(json!({"strokes": [{"color": "#ffffff", "pixels": block(1, 1)}]})),
    )
    .await;
    assert_eq!(v["status"], "failed", "{v}");
    assert_eq!(
        v["error"]["type"],
        "https://phenomena.dev/problems/stroke-misses-cloud"
    );
    // κ 500× and the sun below: the cloud seen from above is not lit.
    let v = edit(
        &s,
        &spec,
        &id,
        "set",
        json!({"base_version": 1, "width": VIEW.0, "height": VIEW.1,
               "camera": {"azimuth_deg": 180, "elevation_deg": 70},
               "kappa": kappa * 500.0, "sun_azimuth_deg": 0, "sun_elevation_deg": -90}),
    )
    .await;
    assert_eq!(v["status"], "ready", "{v}");
    assert_eq!(v["kind"], "set");
    assert_eq!(v["state"]["kappa"], json!(kappa * 500.0));
    assert!(v["state"].get("kappa_auto").is_none(), "{v}");
    let dark = v["version"].as_u64().unwrap();
    let (cx, cy) = (VIEW.0 as i64 / 2, VIEW.1 as i64 / 2);
    let v = edit(
        &s,
        &spec,
        &id,
        "sun-color",
        json!({"base_version": dark, "width": VIEW.0, "height": VIEW.1,
               "camera": {"azimuth_deg": 180, "elevation_deg": 70},
               "strokes": [{"color": "#ffffff", "pixels": block(cx, cy)}]}),
    )
    .await;
    assert_eq!(v["status"], "failed", "{v}");
    assert_eq!(
        v["error"]["type"],
        "https://phenomena.dev/problems/stroke-not-lit"
    );
    assert_eq!(
        v["error"]["detail"],
        "nothing under the stroke is lit by the sun: move the sun or lower κ"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenes_survive_a_restart() {
    let s = start(|_| {}).await;
    let r = create(&s, json!({"kappa": 33})).await;
    let scene: Value = r.json().await.unwrap();
    let id = scene["id"].as_str().unwrap().to_string();
    let (cx, cy) = (VIEW.0 as i64 / 2, VIEW.1 as i64 / 2);
    let r = post_json(
        &s,
        &format!("/v1/clouds/{id}/edits/ambient"),
        with_view(json!({"strokes": [{"color": "#80ff80", "pixels": block(cx, cy)}]})),
    )
    .await;
    let v: Value = r.json().await.unwrap();
    assert_eq!(v["status"], "ready", "{v}");
    let dir = s.stop().await;

    let s = Server::start_in(dir, |_| {}).await;
    let scene = s.get_json(&format!("/v1/clouds/{id}")).await;
    assert_eq!(scene["versions"].as_array().unwrap().len(), 2);
    assert_eq!(scene["versions"][1]["ambient_field"], v["ambient_field"]);
    // The stored field still renders.
    let r = post_json(&s, &format!("/v1/clouds/{id}/renders"), view()).await;
    let job: Value = r.json().await.unwrap();
    assert!(!render_of(&s, &job).await.is_empty());
}


#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn multiple_scattering_over_http() {
    let spec = spec();
    let s = start(|_| {}).await;
    // One shot: the three layers on request, state.json records the mode and the albedo.
    let params = json!({"width": 64, "height": 48, "kappa": 40, "scattering": "multiple",
                        "albedo": 0.95, "layers": true});
    let r = s.submit("cloud", "volume", params, blob_npy(), "blob.npy").await;
    let job = s
        .wait_done(r.json::<Value>().await.unwrap()["id"].as_str().unwrap())
        .await;
    assert_eq!(job["status"], "succeeded", "{job}");
    let url_of = |name: &str| {
        job["outputs"]
            .as_array()
            .unwrap()
            .iter()
            .find(|o| o["name"] == name)
            .unwrap_or_else(|| panic!("no {name} in {job}"))["url"]
            .as_str()
            .unwrap()
            .to_string()
    };
    let state: Value = serde_json::from_slice(&bytes(&s, &url_of("state.json")).await).unwrap();
    assert_eq!(state["scattering"], "multiple", "{state}");
    assert_eq!(state["albedo"], json!(0.95), "{state}");
    let direct = bytes(&s, &url_of("direct.png")).await;
    let multiple = bytes(&s, &url_of("multiple.png")).await;
    assert!(!multiple.is_empty() && multiple != direct);
    assert!(!bytes(&s, &url_of("ambient.png")).await.is_empty());

    // Bad values are 422s naming the field.
    for (bad, field) in [
        (json!({"scattering": "triple"}), "scattering"),
        (json!({"albedo": 1.5}), "albedo"),
    ] {
        let r = s.submit("cloud", "volume", bad, blob_npy(), "blob.npy").await;
        assert_eq!(problem(r, 422, "invalid-parameter").await["field"], field);
    }

    // A scene switched to multiple scattering by the `set` edit; the sun-colour edit works in
    // that mode, and a render with `layers: true` carries multiple.png.
    let r = create(&s, json!({"kappa": 40, "background": "#000000"})).await;
    assert_eq!(r.status(), 201);
    let scene = checked(&spec, "post", "/v1/clouds", r).await;
    let id = scene["id"].as_str().unwrap().to_string();
    assert_eq!(scene["versions"][0]["state"]["scattering"], "single");
    let v = edit(&s, &spec, &id, "set", with_view(json!({"scattering": "multiple"}))).await;
    assert_eq!(v["status"], "ready", "{v}");
    assert_eq!(v["state"]["scattering"], "multiple");
    let (cx, cy) = (VIEW.0 as i64 / 2, VIEW.1 as i64 / 2);
    let v = edit(
        &s,
        &spec,
        &id,
        "sun-color",
        with_view(json!({"strokes": [{"color": "#ff4020", "pixels": block(cx, cy)}]})),
    )
    .await;
    assert_eq!(v["status"], "ready", "{v}");
    assert_eq!(v["state"]["scattering"], "multiple");
    let sun: Vec<f64> = v["state"]["sun_color"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_f64().unwrap())
        .collect();
    assert!(sun[0] > 2.0 * sun[2], "the sun should turn red: {sun:?}");
    let mut body = view();
    body["layers"] = json!(true);
    let r = post_json(&s, &format!("/v1/clouds/{id}/renders"), body).await;
    let job = checked(&spec, "post", "/v1/clouds/{id}/renders", r).await;
    output_blob(&job, "multiple.png");
    output_blob(&job, "layers.bin");
    let r = post_json(
        &s,
        &format!("/v1/clouds/{id}/edits/set"),
        with_view(json!({"albedo": 2})),
    )
    .await;
    let p = checked(&spec, "post", "/v1/clouds/{id}/edits/set", r).await;
    assert!(p["field"].as_str().unwrap().ends_with("albedo"), "{p}");
}

}
