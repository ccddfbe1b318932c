//! OGC API – Processes – Part 1 under `/ogc` (issue 22) and the STAC Item of a snow-terrain
//! result (`/v1/jobs/{id}/stac.json`): every JSON answer is validated against `openapi.yaml`.
//!
//! The STAC Item is checked field by field (the STAC and extension JSON schemas are not
//! available offline, and third-party files are not committed): its bbox against the DEM's
//! known extent — exact for a geographic grid, and GDAL's reprojection (`gdalinfo -json`,
//! `wgs84Extent`) for a UTM one.

use std::time::Duration;

use serde_json::{json, Value};

use crate::common::Server;
use crate::openapi::{checked, spec};

const OGC_EXCEPTIONS: &str = "http://www.opengis.net/def/exceptions/ogcapi-processes-1/1.0/";

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

fn dem(name: &str) -> Vec<u8> {
    std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/dem")
            .join(name),
    )
    .unwrap()
}

async fn execute(s: &Server, process: &str, body: Value) -> reqwest::Response {
    s.client
        .post(s.url(&format!("/ogc/processes/{process}/execution")))
        .header("Prefer", "respond-async")
        .json(&body)
        .send()
        .await
        .unwrap()
}

/// Asserts a problem+json answer with this status and full `type` URI; returns the body.
async fn problem_uri(resp: reqwest::Response, status: u16, uri: &str) -> Value {
    assert_eq!(resp.status().as_u16(), status);
    assert_eq!(
        resp.headers()["content-type"].to_str().unwrap(),
        "application/problem+json"
    );
    let body: Value = resp.json().await.unwrap();
    assert_eq!(body["type"], json!(uri), "{body}");
    assert_eq!(body["status"], json!(status));
    body
}

async fn ogc_problem(resp: reqwest::Response, status: u16, kind: &str) -> Value {
    problem_uri(resp, status, &format!("{OGC_EXCEPTIONS}{kind}")).await
}

async fn phen_problem(resp: reqwest::Response, status: u16, kind: &str) -> Value {
    problem_uri(
        resp,
        status,
        &format!("https://phenomena.dev/problems/{kind}"),
    )
    .await
}

/// Polls `/ogc/jobs/{id}` until the status is final (60 s at most); every answer is checked
/// against the spec.
async fn wait_final(s: &Server, id: &str) -> Value {
    let spec = spec();
    for _ in 0..600 {
        let r = s
            .client
            .get(s.url(&format!("/ogc/jobs/{id}")))
            .send()
            .await
            .unwrap();
        let v = checked(&spec, "get", "/ogc/jobs/{id}", r).await;
        if ["successful", "failed", "dismissed"].contains(&v["status"].as_str().unwrap()) {
            return v;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("job {id} did not finish");
}

fn rels(links: &Value) -> Vec<&str> {
    links
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["rel"].as_str().unwrap())
        .collect()
}

fn has_ref(v: &Value) -> bool {
    match v {
        Value::Object(m) => m.contains_key("$ref") || m.values().any(has_ref),
        Value::Array(a) => a.iter().any(has_ref),
        _ => false,
    }
}

#[tokio::test]
async fn landing_conformance_and_process_descriptions() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    let get = |p: &str| s.client.get(s.url(p)).send();

    let landing = checked(&spec, "get", "/ogc", get("/ogc").await.unwrap()).await;
    let r = rels(&landing["links"]);
    for rel in [
        "service-desc",
        "http://www.opengis.net/def/rel/ogc/1.0/conformance",
        "http://www.opengis.net/def/rel/ogc/1.0/processes",
        "http://www.opengis.net/def/rel/ogc/1.0/job-list",
    ] {
        assert!(r.contains(&rel), "{rel} missing: {landing}");
    }

    let conf = checked(
        &spec,
        "get",
        "/ogc/conformance",
        get("/ogc/conformance").await.unwrap(),
    )
    .await;
    let classes: Vec<&str> = conf["conformsTo"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap())
        .collect();
    for c in ["core", "ogc-process-description", "json", "dismiss"] {
        let uri = format!("http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/{c}");
        assert!(classes.contains(&uri.as_str()), "{c}: {conf}");
    }
    assert!(!classes.iter().any(|c| c.ends_with("/job-list")));

    let list = checked(
        &spec,
        "get",
        "/ogc/processes",
        get("/ogc/processes").await.unwrap(),
    )
    .await;
    let ids: Vec<&str> = list["processes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["id"].as_str().unwrap())
        .collect();
    for p in ["snow-terrain", "snow-cover", "cloud", "dust"] {
        assert!(ids.contains(&p), "{p} missing: {ids:?}");
    }
    // Paging: two per page, the next page's link gives the rest.
    let page = checked(
        &spec,
        "get",
        "/ogc/processes",
        get("/ogc/processes?limit=2").await.unwrap(),
    )
    .await;
    assert_eq!(page["processes"].as_array().unwrap().len(), 2);
    let next = page["links"]
        .as_array()
        .unwrap()
        .iter()
        .find(|l| l["rel"] == "next")
        .unwrap()["href"]
        .as_str()
        .unwrap()
        .to_string();
    let rest = get(&next).await.unwrap().json::<Value>().await.unwrap();
    assert_eq!(rest["processes"][0]["id"], json!(ids[2]));
    phen_problem(
        get("/ogc/processes?limit=0").await.unwrap(),
        400,
        "bad-request",
    )
    .await;

    let d = checked(
        &spec,
        "get",
        "/ogc/processes/{processId}",
        get("/ogc/processes/snow-terrain").await.unwrap(),
    )
    .await;
    assert_eq!(d["id"], "snow-terrain");
    assert!(d["jobControlOptions"]
        .as_array()
        .unwrap()
        .contains(&json!("async-execute")));
    assert!(!d["jobControlOptions"]
        .as_array()
        .unwrap()
        .contains(&json!("sync-execute")));
    // The inputs are openapi.yaml's SnowTerrainParams, property for property, with the bounds.
    let inputs = d["inputs"].as_object().unwrap();
    let width = &inputs["width"];
    assert_eq!(width["schema"]["type"], "integer");
    assert_eq!(width["schema"]["minimum"], 16);
    assert_eq!(width["schema"]["maximum"], 8192);
    assert_eq!(width["schema"]["default"], 900);
    assert_eq!(width["minOccurs"], 0);
    let params = spec["components"]["schemas"]["SnowTerrainParams"]["properties"]
        .as_object()
        .unwrap();
    for (name, schema) in params {
        let input = inputs
            .get(name)
            .unwrap_or_else(|| panic!("parameter {name} is not an input"));
        assert_eq!(input["description"], schema["description"], "{name}");
    }
    assert_eq!(inputs.len(), params.len() + 2, "params + dem + ortho");
    assert_eq!(inputs["dem"]["minOccurs"], 1);
    assert_eq!(inputs["ortho"]["minOccurs"], 0);
    let dem_types: Vec<&str> = inputs["dem"]["schema"]["oneOf"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["contentMediaType"].as_str().unwrap())
        .collect();
    assert!(dem_types.contains(&"image/tiff"), "{dem_types:?}");
    // References are resolved: the camera input stands alone.
    assert!(!has_ref(&d), "a $ref is left in {d}");
    assert!(inputs["camera"]["schema"]["properties"].is_object());
    let outputs = d["outputs"].as_object().unwrap();
    assert_eq!(
        outputs["snow_cover.tif"]["schema"]["contentMediaType"],
        "image/tiff"
    );
    assert!(outputs.contains_key("render.png"));

    // Another pipeline's inputs come from its own schema.
    let dust = get("/ogc/processes/dust")
        .await
        .unwrap()
        .json::<Value>()
        .await
        .unwrap();
    assert_eq!(dust["inputs"]["mesh"]["minOccurs"], 1);
    assert!(dust["inputs"].get("dem").is_none());
    assert!(dust["inputs"].get("width").is_some());

    ogc_problem(
        get("/ogc/processes/avalanche").await.unwrap(),
        404,
        "no-such-process",
    )
    .await;
    ogc_problem(
        get(&format!("/ogc/jobs/{}", "0".repeat(32))).await.unwrap(),
        404,
        "no-such-job",
    )
    .await;
    s.stop().await;
}

#[tokio::test]
async fn async_execution_runs_a_real_dem_to_results_and_a_stac_item() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    // Central Andes, ETOPO5: 72 × 144 cells of 5′ from 70.541667° W, 24.041667° S (EPSG:4326).
    let asset = upload(&s, dem("central_andes_aconcagua_etopo5.tif"), "andes.tif").await;
    let params = json!({"width": 64, "height": 48, "mesh_max_vertices": 2000});
    let mut inputs = params.clone();
    // An absolute href on any host: only its path is read.
    inputs["dem"] = json!({"href": format!("http://example.invalid/v1/assets/{asset}")});
    let resp = execute(&s, "snow-terrain", json!({"inputs": inputs})).await;
    assert_eq!(resp.status(), 201);
    assert_eq!(resp.headers()["preference-applied"], "respond-async");
    let location = resp.headers()["location"].to_str().unwrap().to_string();
    let created = checked(&spec, "post", "/ogc/processes/{processId}/execution", resp).await;
    let id = created["jobID"].as_str().unwrap().to_string();
    assert_eq!(location, format!("/ogc/jobs/{id}"));
    assert_eq!(created["processID"], "snow-terrain");

    let done = wait_final(&s, &id).await;
    assert_eq!(done["status"], "successful", "{done}");
    assert_eq!(done["progress"], 100);
    assert!(done["finished"].is_string() && done["started"].is_string());
    let r = rels(&done["links"]);
    assert!(r.contains(&"http://www.opengis.net/def/rel/ogc/1.0/results"));
    assert!(r.contains(&"describedby"), "{done}");

    // The same request through the service's own route is the same job (one submit path).
    let own = s
        .client
        .post(s.url("/v1/snow-terrain"))
        .json(&json!({"asset": asset, "params": params}))
        .send()
        .await
        .unwrap()
        .json::<Value>()
        .await
        .unwrap();
    assert_eq!(own["id"], json!(id));

    let results = checked(
        &spec,
        "get",
        "/ogc/jobs/{id}/results",
        s.client
            .get(s.url(&format!("/ogc/jobs/{id}/results")))
            .send()
            .await
            .unwrap(),
    )
    .await;
    let job = s.job(&id).await;
    let outputs = job["outputs"].as_array().unwrap();
    assert_eq!(results.as_object().unwrap().len(), outputs.len());
    // Every output the run made is one the process description names, with its media type.
    let described = s.get_json("/ogc/processes/snow-terrain").await;
    for o in outputs {
        let name = o["name"].as_str().unwrap();
        assert_eq!(
            described["outputs"][name]["schema"]["contentMediaType"], o["media_type"],
            "{name} is not described"
        );
    }
    for o in outputs {
        let name = o["name"].as_str().unwrap();
        let link = &results[name];
        assert_eq!(link["type"], o["media_type"]);
        let got = s
            .client
            .get(s.url(link["href"].as_str().unwrap()))
            .send()
            .await
            .unwrap();
        assert_eq!(got.status(), 200, "{name}");
        let bytes = got.bytes().await.unwrap();
        assert_eq!(bytes.len() as u64, o["size"].as_u64().unwrap(), "{name}");
        if name == "snow_cover.tif" {
            assert_eq!(&bytes[..4], b"II*\0", "a little-endian TIFF");
        }
        if name == "render.png" {
            assert_eq!(&bytes[1..4], b"PNG");
        }
    }

    // The STAC Item, before any map of this DEM exists: a link says how to make one.
    let stac_url = format!("/v1/jobs/{id}/stac.json");
    let resp = s.client.get(s.url(&stac_url)).send().await.unwrap();
    assert_eq!(resp.headers()["content-type"], "application/geo+json");
    let item = checked(&spec, "get", "/v1/jobs/{id}/stac.json", resp).await;
    assert_eq!(item["stac_version"], "1.0.0");
    assert_eq!(item["id"], json!(id));
    let b: Vec<f64> = item["bbox"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let cell = 5.0 / 60.0;
    let west = -70.541667;
    let north = -24.041667;
    let want = [west, north - 144.0 * cell, west + 72.0 * cell, north];
    for (got, want) in b.iter().zip(want) {
        assert!((got - want).abs() < 1e-5, "bbox {b:?}, want {want:?}");
    }
    let ring = item["geometry"]["coordinates"][0].as_array().unwrap();
    assert_eq!(ring.first(), ring.last(), "a closed ring");
    // Counter-clockwise (RFC 7946): the shoelace area is positive.
    let area: f64 = ring
        .windows(2)
        .map(|w| {
            let (x0, y0) = (w[0][0].as_f64().unwrap(), w[0][1].as_f64().unwrap());
            let (x1, y1) = (w[1][0].as_f64().unwrap(), w[1][1].as_f64().unwrap());
            x0 * y1 - x1 * y0
        })
        .sum::<f64>()
        / 2.0;
    assert!((area - 72.0 * 144.0 * cell * cell).abs() < 1e-3, "{area}");
    let p = &item["properties"];
    assert_eq!(p["proj:code"], "EPSG:4326");
    assert_eq!(p["proj:shape"], json!([144, 72]));
    let t: Vec<f64> = p["proj:transform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(
        (t[0] - cell).abs() < 1e-9 && (t[4] + cell).abs() < 1e-9,
        "{t:?}"
    );
    assert!(
        (t[2] - west).abs() < 1e-5 && (t[5] - north).abs() < 1e-5,
        "{t:?}"
    );
    let cog = &item["assets"]["snow_cover"];
    // Every href is absolute, on the host the request named (STAC wants an absolute `self`).
    assert_eq!(
        cog["href"],
        json!(s.url(&format!("/v1/jobs/{id}/outputs/snow_cover.tif")))
    );
    let self_link = item["links"]
        .as_array()
        .unwrap()
        .iter()
        .find(|l| l["rel"] == "self")
        .unwrap_or_else(|| panic!("no self link: {item}"));
    assert_eq!(self_link["href"], json!(s.url(&stac_url)));
    assert!(cog["type"]
        .as_str()
        .unwrap()
        .contains("profile=cloud-optimized"));
    let band = &cog["raster:bands"][0];
    assert_eq!(band["data_type"], "float32");
    let st = &band["statistics"];
    let (min, max, mean) = (
        st["minimum"].as_f64().unwrap(),
        st["maximum"].as_f64().unwrap(),
        st["mean"].as_f64().unwrap(),
    );
    assert!((0.0..=1.0).contains(&min) && min <= mean && mean <= max && max <= 1.0);
    assert!(max > min, "snow cover varies over 5.6 km of relief");
    assert!((st["valid_percent"].as_f64().unwrap() - 100.0).abs() < 1e-9);
    // The report's snow-covered fraction is the mean of s where it is counted; at least the
    // Item's mean is the COG's own (its statistics are of the downloaded file's values).
    assert!(item["assets"]["render"]["href"]
        .as_str()
        .unwrap()
        .ends_with("/outputs/render.png"));
    let create = item["links"]
        .as_array()
        .unwrap()
        .iter()
        .find(|l| l["method"] == "POST")
        .unwrap_or_else(|| panic!("no create-map link: {item}"))
        .clone();
    assert!(!rels(&item["links"]).contains(&"tilejson"));

    // Make the map the link describes: the Item then links its TileJSON and tiles.
    let map = s
        .client
        .post(create["href"].as_str().unwrap())
        .json(&create["body"])
        .send()
        .await
        .unwrap();
    let status = map.status();
    let map: Value = map.json().await.unwrap();
    assert!(status.is_success(), "{status} {map}");
    let item = s.get_json(&stac_url).await;
    let tilejson = item["links"]
        .as_array()
        .unwrap()
        .iter()
        .find(|l| l["rel"] == "tilejson")
        .unwrap_or_else(|| panic!("no tilejson link after the map was made: {item}"));
    assert_eq!(
        tilejson["href"],
        json!(s.url(map["tilejson_url"].as_str().unwrap()))
    );
    let tj = s
        .client
        .get(tilejson["href"].as_str().unwrap())
        .send()
        .await
        .unwrap();
    assert_eq!(tj.status(), 200);
    let xyz: Vec<&Value> = item["links"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|l| l["rel"] == "xyz")
        .collect();
    assert!(!xyz.is_empty());
    let z = map["maxzoom"].as_u64().unwrap();
    let c = &map["center"];
    let (lon, lat) = (c[0].as_f64().unwrap(), c[1].as_f64().unwrap());
    let n = 2f64.powi(z as i32);
    let x = ((lon + 180.0) / 360.0 * n).floor();
    let y = ((1.0 - lat.to_radians().tan().asinh() / std::f64::consts::PI) / 2.0 * n).floor();
    let tile = xyz[0]["href"]
        .as_str()
        .unwrap()
        .replace("{z}", &z.to_string())
        .replace("{x}", &x.to_string())
        .replace("{y}", &y.to_string());
    let got = s.client.get(&tile).send().await.unwrap();
    assert_eq!(got.status(), 200, "{tile}");
    s.stop().await;
}

#[tokio::test]
async fn stac_item_of_a_projected_dem_matches_gdal() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    // Kagwene, UTM 32N (EPSG:32632), 181 × 149 cells of 30.7095 m; −9999 on 5,927 cells.
    let asset = upload(
        &s,
        dem("kagwene_cameroon_elev_30m_utm32n.tif"),
        "kagwene.tif",
    )
    .await;
    let resp = execute(
        &s,
        "snow-terrain",
        json!({"inputs": {"dem": {"href": format!("/v1/assets/{asset}")}, "width": 48, "height": 32,
               "outputs": ["snow_cover.tif"]}}),
    )
    .await;
    assert_eq!(resp.status(), 201);
    let id = resp.json::<Value>().await.unwrap()["jobID"]
        .as_str()
        .unwrap()
        .to_string();
    assert_eq!(wait_final(&s, &id).await["status"], "successful");
    let item = checked(
        &spec,
        "get",
        "/v1/jobs/{id}/stac.json",
        s.client
            .get(s.url(&format!("/v1/jobs/{id}/stac.json")))
            .send()
            .await
            .unwrap(),
    )
    .await;
    // `gdalinfo -json tests/data/dem/kagwene_cameroon_elev_30m_utm32n.tif`, wgs84Extent
    // (GDAL 3.6, PROJ): corners (9.7270212, 6.1399741), (9.7269652, 6.0985842),
    // (9.7771955, 6.098514), (9.7772553, 6.1399035).
    let want = [9.7269652, 6.098514, 9.7772553, 6.1399741];
    let b: Vec<f64> = item["bbox"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for (got, want) in b.iter().zip(want) {
        assert!((got - want).abs() < 2e-6, "bbox {b:?}, want {want:?}");
    }
    let p = &item["properties"];
    assert_eq!(p["proj:code"], "EPSG:32632");
    assert_eq!(p["proj:shape"], json!([149, 181]));
    let pb: Vec<f64> = p["proj:bbox"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let cell = 30.709549771388993;
    let want = [
        580440.38505253,
        678732.2343805945 - 149.0 * cell,
        580440.38505253 + 181.0 * cell,
        678732.2343805945,
    ];
    for (got, want) in pb.iter().zip(want) {
        assert!((got - want).abs() < 1e-3, "proj:bbox {pb:?}");
    }
    let band = &item["assets"]["snow_cover"]["raster:bands"][0];
    assert_eq!(band["nodata"], json!(-9999.0));
    let valid = band["statistics"]["valid_percent"].as_f64().unwrap();
    let want = 100.0 * (181.0 * 149.0 - 5927.0) / (181.0 * 149.0);
    assert!(
        (valid - want).abs() < 0.01,
        "valid {valid} %, want {want} %"
    );
    // The band statistics are the downloaded file's own: GDAL computes the same from the COG
    // (`gdalinfo -json -stats`, installed by `.ci/run` for the COG validator).
    let cog = s
        .client
        .get(item["assets"]["snow_cover"]["href"].as_str().unwrap())
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("snow_cover.tif");
    std::fs::write(&path, &cog).unwrap();
    let out = std::process::Command::new("gdalinfo")
        .args(["-json", "-stats"])
        .arg(&path)
        .output()
        .expect("gdalinfo is needed (apt-get install gdal-bin; .ci/run does)");
    assert!(out.status.success());
    let gdal: Value = serde_json::from_slice(&out.stdout).unwrap();
    let md = &gdal["bands"][0]["metadata"][""];
    for (ours, theirs) in [
        ("minimum", "STATISTICS_MINIMUM"),
        ("maximum", "STATISTICS_MAXIMUM"),
        ("mean", "STATISTICS_MEAN"),
        ("stddev", "STATISTICS_STDDEV"),
    ] {
        let a = band["statistics"][ours].as_f64().unwrap();
        let b: f64 = md[theirs].as_str().unwrap().parse().unwrap();
        assert!((a - b).abs() < 1e-9, "{ours}: {a} here, {b} by GDAL");
    }
    assert_eq!(gdal["bands"][0]["noDataValue"], json!(-9999.0));
    // Only the asked output (and the report, always written) was made: the assets are those.
    let assets = item["assets"].as_object().unwrap();
    assert!(assets.contains_key("snow_cover") && !assets.contains_key("render"));
    s.stop().await;
}

#[tokio::test]
async fn bad_execute_requests_are_problems() {
    let s = Server::start(|_| {}).await;
    let asset = upload(&s, dem("central_andes_aconcagua_etopo5.tif"), "andes.tif").await;
    let href = json!({"href": format!("/v1/assets/{asset}")});

    // No input file: 422 naming it.
    let b = phen_problem(
        execute(&s, "snow-terrain", json!({"inputs": {"width": 64}})).await,
        422,
        "invalid-input",
    )
    .await;
    assert_eq!(b["field"], "inputs.dem");
    // An out-of-range parameter: the pipeline's own validation, named by the parameter.
    let b = phen_problem(
        execute(
            &s,
            "snow-terrain",
            json!({"inputs": {"dem": href, "width": 5}}),
        )
        .await,
        422,
        "invalid-parameter",
    )
    .await;
    assert_eq!(b["field"], "width");
    // An unknown parameter.
    let b = phen_problem(
        execute(
            &s,
            "snow-terrain",
            json!({"inputs": {"dem": href, "avalanche": 1}}),
        )
        .await,
        422,
        "invalid-parameter",
    )
    .await;
    assert_eq!(b["field"], "avalanche");
    // Not a reference to this server's assets.
    let b = phen_problem(
        execute(
            &s,
            "snow-terrain",
            json!({"inputs": {"dem": {"href": "https://example.com/dem.tif"}}}),
        )
        .await,
        400,
        "bad-request",
    )
    .await;
    assert_eq!(b["field"], "inputs.dem");
    phen_problem(
        execute(
            &s,
            "snow-terrain",
            json!({"inputs": {"dem": {"value": "AAAA", "encoding": "base64"}}}),
        )
        .await,
        400,
        "bad-request",
    )
    .await;
    // An asset that does not exist.
    phen_problem(
        execute(
            &s,
            "snow-terrain",
            json!({"inputs": {"dem": {"href": format!("/v1/assets/{}", "a".repeat(64))}}}),
        )
        .await,
        404,
        "not-found",
    )
    .await;
    // Output selection, raw responses and callbacks are not supported.
    for extra in [
        json!({"outputs": {"render.png": {}}}),
        json!({"response": "raw"}),
        json!({"subscriber": {"successUri": "http://example.com/"}}),
    ] {
        let mut body = json!({"inputs": {"dem": href}});
        let (k, v) = extra.as_object().unwrap().iter().next().unwrap();
        body[k] = v.clone();
        let b = phen_problem(execute(&s, "snow-terrain", body).await, 400, "bad-request").await;
        assert_eq!(b["field"], json!(k));
    }
    // A DEM that is not one: the input check before any job exists.
    let junk = upload(&s, b"not a dem at all".to_vec(), "junk.tif").await;
    let resp = execute(
        &s,
        "snow-terrain",
        json!({"inputs": {"dem": {"href": format!("/v1/assets/{junk}")}}}),
    )
    .await;
    assert!(
        resp.status().is_client_error(),
        "a corrupt DEM: {}",
        resp.status()
    );
    assert_eq!(resp.headers()["content-type"], "application/problem+json");
    // Not JSON.
    let resp = s
        .client
        .post(s.url("/ogc/processes/snow-terrain/execution"))
        .body("inputs=1")
        .send()
        .await
        .unwrap();
    phen_problem(resp, 415, "unsupported-format").await;
    ogc_problem(
        execute(&s, "avalanche", json!({"inputs": {}})).await,
        404,
        "no-such-process",
    )
    .await;
    // No job was made by any of these.
    let jobs = s.get_json("/ogc/jobs").await;
    assert_eq!(jobs["jobs"].as_array().unwrap().len(), 0, "{jobs}");
    s.stop().await;
}

#[tokio::test]
async fn dismiss_cancels_and_results_wait() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    let asset = upload(&s, b"some bytes".to_vec(), "x.bin").await;
    let resp = execute(
        &s,
        "sleepy",
        json!({"inputs": {"data": {"href": format!("/v1/assets/{asset}")}, "stages": 100, "ms": 100}}),
    )
    .await;
    assert_eq!(resp.status(), 201);
    let id = resp.json::<Value>().await.unwrap()["jobID"]
        .as_str()
        .unwrap()
        .to_string();
    s.wait_running(&id).await;
    let running = s.get_json(&format!("/ogc/jobs/{id}")).await;
    assert_eq!(running["status"], "running");
    ogc_problem(
        s.client
            .get(s.url(&format!("/ogc/jobs/{id}/results")))
            .send()
            .await
            .unwrap(),
        404,
        "result-not-ready",
    )
    .await;
    // The job list shows it.
    let list = checked(
        &spec,
        "get",
        "/ogc/jobs",
        s.client.get(s.url("/ogc/jobs")).send().await.unwrap(),
    )
    .await;
    assert_eq!(list["jobs"][0]["jobID"], json!(id));

    let resp = s
        .client
        .delete(s.url(&format!("/ogc/jobs/{id}")))
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status(), 200);
    checked(&spec, "delete", "/ogc/jobs/{id}", resp).await;
    let done = wait_final(&s, &id).await;
    assert_eq!(done["status"], "dismissed");
    assert_eq!(s.job(&id).await["status"], "canceled");
    ogc_problem(
        s.client
            .get(s.url(&format!("/ogc/jobs/{id}/results")))
            .send()
            .await
            .unwrap(),
        404,
        "result-not-ready",
    )
    .await;
    phen_problem(
        s.client
            .delete(s.url(&format!("/ogc/jobs/{id}")))
            .send()
            .await
            .unwrap(),
        409,
        "conflict",
    )
    .await;
    ogc_problem(
        s.client
            .delete(s.url(&format!("/ogc/jobs/{}", "f".repeat(32))))
            .send()
            .await
            .unwrap(),
        404,
        "no-such-job",
    )
    .await;
    s.stop().await;
}

#[tokio::test]
async fn ogc_routes_need_the_token_when_auth_is_on() {
    let s = Server::start(|c| c.auth_tokens = vec!["sesame".into()]).await;
    for path in ["/ogc", "/ogc/processes", "/ogc/jobs"] {
        let r = s.client.get(s.url(path)).send().await.unwrap();
        assert_eq!(r.status(), 401, "{path}");
        let r = s
            .client
            .get(s.url(path))
            .bearer_auth("sesame")
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200, "{path}");
    }
    s.stop().await;
}
