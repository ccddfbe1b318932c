//! `snow-terrain` end to end over HTTP on real DEMs: the served bytes equal the CLI's, the GeoTIFF
//! lines up with the input, and the report describes the run.

use std::process::Command;

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use serde_json::{json, Value};

use crate::common::{data, problem, Server};

const BIN: &str = env!("CARGO_BIN_EXE_phenomena");

async fn run_http(s: &Server, file: &str, params: &Value) -> (Value, Vec<(String, Vec<u8>)>) {
    let bytes = std::fs::read(data(file)).unwrap();
    let name = std::path::Path::new(file)
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let resp = s
        .submit("snow-terrain", "dem", params.clone(), bytes, &name)
        .await;
    assert_eq!(resp.status().as_u16(), 202);
    let job: Value = resp.json().await.unwrap();
    let done = s.wait_done(job["id"].as_str().unwrap()).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let mut outs = Vec::new();
    for o in done["outputs"].as_array().unwrap() {
        let b = s
            .client
            .get(s.url(o["url"].as_str().unwrap()))
            .send()
            .await
            .unwrap()
            .bytes()
            .await
            .unwrap();
        assert_eq!(b.len() as u64, o["size"].as_u64().unwrap());
        outs.push((o["name"].as_str().unwrap().to_string(), b.to_vec()));
    }
    (done, outs)
}

#[tokio::test]
async fn http_and_cli_give_the_same_bytes_on_a_real_dem() {
    let s = Server::start(|_| {}).await;
    let params =
        json!({"width": 320, "height": 200, "camera": {"azimuth_deg": 160, "elevation_deg": 35}});
    let (done, outs) = run_http(&s, "dem/jacksboro_fault_dem_f32.tif", &params).await;
    let names: Vec<&str> = outs.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "render.png",
            "snow_cover.tif",
            "descriptor.png",
            "terrain.glb",
            "report.json"
        ]
    );
    let media: Vec<&str> = done["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o["media_type"].as_str().unwrap())
        .collect();
    assert_eq!(
        media,
        [
            "image/png",
            "image/tiff",
            "image/png",
            "model/gltf-binary",
            "application/json"
        ]
    );

    let dir = tempfile::tempdir().unwrap();
    let pfile = dir.path().join("p.json");
    std::fs::write(&pfile, params.to_string()).unwrap();
    let status = Command::new(BIN)
        .args(["render", "snow-terrain", "--quiet", "--input"])
        .arg(data("dem/jacksboro_fault_dem_f32.tif"))
        .arg("--params")
        .arg(&pfile)
        .arg("--out")
        .arg(dir.path())
        .status()
        .unwrap();
    assert!(status.success());
    for (name, served) in &outs {
        let offline = std::fs::read(dir.path().join(name)).unwrap();
        if name == "report.json" {
            // Timings differ run to run; everything else is identical.
            let mut a: Value = serde_json::from_slice(served).unwrap();
            let mut b: Value = serde_json::from_slice(&offline).unwrap();
            for v in [&mut a, &mut b] {
                v.as_object_mut().unwrap().remove("timings");
                v.as_object_mut().unwrap().remove("total_ms");
            }
            assert_eq!(a, b);
        } else {
            assert!(served == &offline, "{name} differs between HTTP and CLI");
        }
    }
}

#[tokio::test]
async fn snow_cover_geotiff_lines_up_with_the_input() {
    let s = Server::start(|_| {}).await;
    for file in ["dem/luxembourg_elev.tif", "dem/olinda_dem_utm25s.tif"] {
        let (_, outs) = run_http(&s, file, &json!({"width": 64, "height": 48})).await;
        let tif = &outs.iter().find(|(n, _)| n == "snow_cover.tif").unwrap().1;
        let input = decode_dem(
            &std::fs::read(data(file)).unwrap(),
            Some(file),
            &DemOptions::default(),
        )
        .unwrap();
        let output = decode_dem(tif, Some("snow_cover.tif"), &DemOptions::default()).unwrap();
        assert_eq!(
            (output.width, output.height),
            (input.width, input.height),
            "{file}"
        );
        assert_eq!(output.georef.transform, input.georef.transform, "{file}");
        assert_eq!(output.georef.epsg, input.georef.epsg, "{file}");
        assert_eq!(
            output.georef.tags.geo_key_directory, input.georef.tags.geo_key_directory,
            "{file}"
        );
        assert_eq!(
            output.georef.tags.tiepoint, input.georef.tags.tiepoint,
            "{file}"
        );
        assert_eq!(
            output.georef.tags.pixel_scale, input.georef.tags.pixel_scale,
            "{file}"
        );
        assert_eq!(output.georef.nodata, input.georef.nodata, "{file}");
        for (i, (a, b)) in input.heights.iter().zip(&output.heights).enumerate() {
            assert_eq!(a.is_nan(), b.is_nan(), "{file}: nodata differs at cell {i}");
            if !b.is_nan() {
                assert!((0.0..=1.0).contains(b), "{file}: snow {b} out of [0, 1]");
            }
        }
    }
}

#[tokio::test]
async fn report_describes_input_params_and_stages() {
    let s = Server::start(|_| {}).await;
    let (_, outs) = run_http(
        &s,
        "dem/maunga_whau_volcano.asc",
        &json!({"width": 64, "height": 48, "probe_radius": 800}),
    )
    .await;
    let report: Value =
        serde_json::from_slice(&outs.iter().find(|(n, _)| n == "report.json").unwrap().1).unwrap();
    assert_eq!(report["input"]["width"], json!(87));
    assert_eq!(report["input"]["height"], json!(61));
    assert_eq!(report["input"]["elevation_min"], json!(94.0));
    assert_eq!(report["input"]["elevation_max"], json!(195.0));
    assert_eq!(report["params"]["probe_radius"], json!(800.0));
    let stages: Vec<&str> = report["timings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["stage"].as_str().unwrap())
        .collect();
    assert_eq!(
        stages,
        [
            "smooth",
            "tsa",
            "transfer",
            "altitude",
            "smooth_t",
            "sun",
            "slope",
            "colour",
            "render_setup",
            "ambient_occlusion",
            "render",
            "encode"
        ]
    );
    let f = report["snow_covered_fraction"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&f));
}

// ---- Orthophoto (SPEC §1 step 7; issue 17) ----

fn ortho_file(name: &str) -> Vec<u8> {
    std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/ortho")
            .join(name),
    )
    .unwrap()
}

/// Multipart with an `ortho` part.
async fn submit_with_ortho(
    s: &Server,
    dem: &str,
    ortho: Vec<u8>,
    ortho_name: &str,
    params: &Value,
) -> reqwest::Response {
    let bytes = std::fs::read(data(dem)).unwrap();
    let name = std::path::Path::new(dem)
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let form = reqwest::multipart::Form::new()
        .text("params", params.to_string())
        .part(
            "dem",
            reqwest::multipart::Part::bytes(bytes).file_name(name),
        )
        .part(
            "ortho",
            reqwest::multipart::Part::bytes(ortho).file_name(ortho_name.to_string()),
        );
    s.client
        .post(s.url("/v1/snow-terrain"))
        .multipart(form)
        .send()
        .await
        .unwrap()
}

async fn outputs_of(s: &Server, done: &Value) -> Vec<(String, Vec<u8>)> {
    let mut outs = Vec::new();
    for o in done["outputs"].as_array().unwrap() {
        let b = s
            .client
            .get(s.url(o["url"].as_str().unwrap()))
            .send()
            .await
            .unwrap()
            .bytes()
            .await
            .unwrap();
        outs.push((o["name"].as_str().unwrap().to_string(), b.to_vec()));
    }
    outs
}

/// The Landsat ortho over the Olinda DEM (same ground, same package): served bytes equal the
/// CLI's `--ortho` run, the report says how it was placed, and the JSON form naming two assets
/// is the same request (same job).
#[tokio::test]
async fn ortho_over_http_equals_the_cli_and_the_asset_form() {
    let s = Server::start(|_| {}).await;
    let params = json!({"width": 240, "height": 160});
    let ortho = ortho_file("olinda_l7_rgb_utm25s.tif");
    let resp = submit_with_ortho(
        &s,
        "dem/olinda_dem_utm25s.tif",
        ortho.clone(),
        "o.tif",
        &params,
    )
    .await;
    assert_eq!(resp.status().as_u16(), 202);
    let job: Value = resp.json().await.unwrap();
    let done = s.wait_done(job["id"].as_str().unwrap()).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let outs = outputs_of(&s, &done).await;
    let report: Value =
        serde_json::from_slice(&outs.iter().find(|(n, _)| n == "report.json").unwrap().1).unwrap();
    assert_eq!(report["ortho"]["placement"], "georeferenced");
    assert!(
        report["ortho"]["coverage"].as_f64().unwrap() > 0.98,
        "{report}"
    );

    let dir = tempfile::tempdir().unwrap();
    let pfile = dir.path().join("p.json");
    std::fs::write(&pfile, params.to_string()).unwrap();
    let ofile = dir.path().join("o.tif");
    std::fs::write(&ofile, &ortho).unwrap();
    let out = dir.path().join("out");
    let status = Command::new(BIN)
        .args(["render", "snow-terrain", "--quiet", "--input"])
        .arg(data("dem/olinda_dem_utm25s.tif"))
        .arg("--ortho")
        .arg(&ofile)
        .arg("--params")
        .arg(&pfile)
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    for (name, served) in &outs {
        if name != "report.json" {
            let offline = std::fs::read(out.join(name)).unwrap();
            assert!(served == &offline, "{name} differs between HTTP and CLI");
        }
    }

    // The same DEM and ortho as uploaded assets, named in a JSON body: the same request.
    let mut ids = Vec::new();
    for (bytes, name) in [
        (
            std::fs::read(data("dem/olinda_dem_utm25s.tif")).unwrap(),
            "olinda_dem_utm25s.tif",
        ),
        (ortho.clone(), "o.tif"),
    ] {
        let r = s
            .client
            .post(s.url(&format!("/v1/assets?filename={name}")))
            .header("content-type", "application/octet-stream")
            .body(bytes)
            .send()
            .await
            .unwrap();
        assert!(r.status().is_success(), "{}", r.status());
        let a: Value = r.json().await.unwrap();
        ids.push(a["id"].as_str().unwrap().to_string());
    }
    let r = s
        .client
        .post(s.url("/v1/snow-terrain"))
        .json(&json!({"asset": ids[0], "ortho_asset": ids[1], "params": params}))
        .send()
        .await
        .unwrap();
    assert!(r.status().is_success(), "{}", r.status());
    let again: Value = r.json().await.unwrap();
    assert_eq!(
        again["id"], job["id"],
        "the ortho is part of the request key"
    );
    // Without the ortho it is another request.
    let r = s
        .client
        .post(s.url("/v1/snow-terrain"))
        .json(&json!({"asset": ids[0], "params": params}))
        .send()
        .await
        .unwrap();
    let plain: Value = r.json().await.unwrap();
    assert_ne!(plain["id"], job["id"]);
    // An unknown ortho asset names its field.
    let r = s
        .client
        .post(s.url("/v1/snow-terrain"))
        .json(&json!({"asset": ids[0], "ortho_asset": "0".repeat(64), "params": params}))
        .send()
        .await
        .unwrap();
    let body = problem(r, 404, "not-found").await;
    assert!(
        body["detail"]
            .as_str()
            .unwrap()
            .starts_with("ortho_asset: no asset"),
        "{body}"
    );
}

/// A plain PNG and a JPEG are stretched over the DEM; they run.
#[tokio::test]
async fn plain_png_and_jpeg_orthos_are_stretched() {
    let s = Server::start(|_| {}).await;
    for name in ["olinda_l7_rgb.png", "olinda_l7_rgb.jpg"] {
        let resp = submit_with_ortho(
            &s,
            "dem/olinda_dem_utm25s.tif",
            ortho_file(name),
            name,
            &json!({"width": 64, "height": 48, "outputs": ["render.png"]}),
        )
        .await;
        assert_eq!(resp.status().as_u16(), 202, "{name}");
        let job: Value = resp.json().await.unwrap();
        let done = s.wait_done(job["id"].as_str().unwrap()).await;
        assert_eq!(done["status"], "succeeded", "{done}");
        let outs = outputs_of(&s, &done).await;
        let report: Value =
            serde_json::from_slice(&outs.iter().find(|(n, _)| n == "report.json").unwrap().1)
                .unwrap();
        assert_eq!(report["ortho"]["placement"], "stretched", "{name}");
        assert_eq!(report["ortho"]["coverage"], json!(1.0), "{name}");
    }
}

/// An ortho in another CRS than the DEM: 422 naming both CRSs, field `ortho`; a file that is no
/// image: 415; an ortho over the pixel limit: 413 before decoding it.
#[tokio::test]
async fn bad_orthos_get_problem_responses() {
    let s = Server::start(|_| {}).await;
    let p = json!({"width": 64, "height": 48});
    let resp = submit_with_ortho(
        &s,
        "dem/tanzawa_sagami_aster_gdem2.tif",
        ortho_file("olinda_l7_rgb_utm25s.tif"),
        "o.tif",
        &p,
    )
    .await;
    let body = problem(resp, 422, "invalid-input").await;
    let detail = body["detail"].as_str().unwrap();
    assert!(
        detail.contains("EPSG:31985") && detail.contains("EPSG:4326"),
        "{detail}"
    );
    assert_eq!(body["field"], "ortho");

    let resp = submit_with_ortho(
        &s,
        "dem/olinda_dem_utm25s.tif",
        b"not an image at all".to_vec(),
        "o.png",
        &p,
    )
    .await;
    let body = problem(resp, 415, "unsupported-format").await;
    assert!(
        body["detail"].as_str().unwrap().starts_with("ortho:"),
        "{body}"
    );

    // The DEM (111 × 111 = 12,321 cells) fits a 20,000 limit, the ortho (349 × 352) does not.
    let small = Server::start(|c| c.max_input_cells = 20_000).await;
    let resp = submit_with_ortho(
        &small,
        "dem/olinda_dem_utm25s.tif",
        ortho_file("olinda_l7_rgb_utm25s.tif"),
        "o.tif",
        &p,
    )
    .await;
    let body = problem(resp, 413, "too-large").await;
    assert!(
        body["detail"]
            .as_str()
            .unwrap()
            .contains("orthophoto pixels"),
        "{body}"
    );

    // Other pipelines take no ortho part.
    let form = reqwest::multipart::Form::new()
        .part(
            "mesh",
            reqwest::multipart::Part::bytes(b"x".to_vec()).file_name("m.obj"),
        )
        .part(
            "ortho",
            reqwest::multipart::Part::bytes(b"x".to_vec()).file_name("o.png"),
        );
    let r = s
        .client
        .post(s.url("/v1/snow-cover"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    let body = problem(r, 400, "bad-request").await;
    assert_eq!(body["field"], "ortho");
}
