//! `snow-terrain` end to end over HTTP on real DEMs: the served bytes equal the CLI's, the GeoTIFF
//! lines up with the input, and the report describes the run.

use std::process::Command;

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use serde_json::{json, Value};

use crate::common::{data, Server};

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
            "render",
            "encode"
        ]
    );
    let f = report["snow_covered_fraction"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&f));
}
