//! Maps over HTTP (issue 22): a real DEM as a web map — the map resource, TileJSON 3.0.0
//! (validated against the TileJSON 3.0.0 JSON schema), PNG tiles of every layer with their
//! cache headers (a second request answered from the cache, 304 on `If-None-Match`), the
//! elevation encodings decoding back to the DEM's elevations, and the refusals. Every JSON
//! response is validated against `openapi.yaml`.

use phenomena_engine::geom::mercator::{lonlat_to_mercator, mercator_to_pixel};
use phenomena_engine::snow_terrain::tiles::{decode_terrain_rgb, decode_terrarium};
use serde_json::{json, Value};

use crate::common::{data, problem, Server};
use crate::openapi::{checked, spec};

/// The TileJSON 3.0.0 JSON schema, written here from the specification
/// (github.com/mapbox/tilejson-spec, `3.0.0/README.md` and its `schema.json`): every field the
/// spec defines with its type and range, `tilejson` and `tiles` required.
fn tilejson_schema() -> Value {
    let zoom = json!({"type": "integer", "minimum": 0, "maximum": 30});
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "type": "object",
        "required": ["tilejson", "tiles"],
        "properties": {
            "tilejson": {"type": "string", "pattern": "^3\\.[0-9]+\\.[0-9]+$"},
            "tiles": {"type": "array", "minItems": 1, "items": {"type": "string"}},
            "vector_layers": {
                "type": "array",
                "items": {
                    "type": "object",
                    "required": ["id", "fields"],
                    "properties": {
                        "id": {"type": "string"},
                        "fields": {"type": "object", "additionalProperties": {"type": "string"}},
                        "description": {"type": "string"},
                        "minzoom": zoom,
                        "maxzoom": zoom
                    }
                }
            },
            "attribution": {"type": "string"},
            "bounds": {
                "type": "array",
                "prefixItems": [
                    {"type": "number", "minimum": -180, "maximum": 180},
                    {"type": "number", "minimum": -90, "maximum": 90},
                    {"type": "number", "minimum": -180, "maximum": 180},
                    {"type": "number", "minimum": -90, "maximum": 90}
                ],
                "minItems": 4,
                "maxItems": 4
            },
            "center": {
                "type": "array",
                "prefixItems": [
                    {"type": "number", "minimum": -180, "maximum": 180},
                    {"type": "number", "minimum": -90, "maximum": 90},
                    zoom
                ],
                "minItems": 3,
                "maxItems": 3
            },
            "data": {"type": "array", "items": {"type": "string"}},
            "description": {"type": "string"},
            "fillzoom": zoom,
            "grids": {"type": "array", "items": {"type": "string"}},
            "legend": {"type": "string"},
            "maxzoom": zoom,
            "minzoom": zoom,
            "name": {"type": "string"},
            "scheme": {"enum": ["xyz", "tms"]},
            "template": {"type": "string"},
            "version": {"type": "string", "pattern": "^[0-9]+\\.[0-9]+\\.[0-9]+"}
        }
    })
}

async fn upload(s: &Server, rel: &str) -> String {
    let path = data(rel);
    let name = path.file_name().unwrap().to_string_lossy().into_owned();
    let r = s
        .client
        .post(s.url(&format!("/v1/assets?filename={name}")))
        .body(std::fs::read(&path).unwrap())
        .send()
        .await
        .unwrap();
    assert!(r.status().is_success(), "{}", r.status());
    r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string()
}

/// `GET url` on the server.
async fn get(s: &Server, url: impl reqwest::IntoUrl) -> reqwest::Response {
    s.client.get(url).send().await.unwrap()
}

/// `POST /v1/maps` with the JSON `body`.
async fn post_map(s: &Server, body: Value) -> reqwest::Response {
    s.client
        .post(s.url("/v1/maps"))
        .json(&body)
        .send()
        .await
        .unwrap()
}

/// The tile (x, y) at zoom z holding the map's centre.
fn centre_tile(tj: &Value, z: u8) -> (u64, u64) {
    let (lon, lat) = (
        tj["center"][0].as_f64().unwrap(),
        tj["center"][1].as_f64().unwrap(),
    );
    let (mx, my) = lonlat_to_mercator(lon, lat);
    let (px, py) = mercator_to_pixel(z, 256, mx, my);
    ((px / 256.0) as u64, (py / 256.0) as u64)
}

fn decode(png: &[u8]) -> image::RgbaImage {
    image::load_from_memory_with_format(png, image::ImageFormat::Png)
        .unwrap()
        .to_rgba8()
}

#[tokio::test]
async fn a_dem_is_served_as_a_web_map() {
    let spec = spec();
    let s = Server::start(|_| {}).await;
    let asset = upload(&s, "dem/olinda_dem_utm25s.tif").await;

    // Create: 201 with Location; the same request again names the same map (200).
    let r = post_map(&s, json!({"asset": asset})).await;
    assert_eq!(r.status(), 201);
    let location = r.headers()["location"].to_str().unwrap().to_string();
    let map = checked(&spec, "post", "/v1/maps", r).await;
    let id = map["id"].as_str().unwrap().to_string();
    assert_eq!(location, format!("/v1/maps/{id}"));
    assert_eq!(map["crs"], "EPSG:32725");
    let r = post_map(&s, json!({"asset": asset, "params": {}})).await;
    assert_eq!(r.status(), 200);
    assert_eq!(checked(&spec, "post", "/v1/maps", r).await["id"], json!(id));
    // Other parameters are another map.
    let r = post_map(&s, json!({"asset": asset, "params": {"preset": "paper"}})).await;
    assert_eq!(r.status(), 201);
    assert_ne!(r.json::<Value>().await.unwrap()["id"], json!(id));
    let r = s.client.get(s.url(&location)).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(
        checked(&spec, "get", "/v1/maps/{id}", r).await["id"],
        json!(id)
    );

    // TileJSON 3.0.0, for the default layer and an elevation layer.
    let validator = jsonschema::validator_for(&tilejson_schema()).unwrap();
    let tj_path = format!("/v1/maps/{id}/tilejson.json");
    let r = s.client.get(s.url(&tj_path)).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert!(r.headers()["cache-control"]
        .to_str()
        .unwrap()
        .contains("max-age"));
    let tj = checked(&spec, "get", "/v1/maps/{id}/tilejson.json", r).await;
    let errors: Vec<String> = validator.iter_errors(&tj).map(|e| e.to_string()).collect();
    assert!(errors.is_empty(), "{errors:?}\n{tj}");
    assert_eq!(tj["tilejson"], "3.0.0");
    assert!(tj.get("encoding").is_none());
    let template = tj["tiles"][0].as_str().unwrap();
    assert_eq!(
        template,
        s.url(&format!("/v1/maps/{id}/tiles/relief/{{z}}/{{x}}/{{y}}.png"))
    );
    let b: Vec<f64> = tj["bounds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    // Olinda, Pernambuco: about 34.9° W, 8.0° S; 111 cells of 90 m ≈ 0.09°.
    assert!(b[0] < b[2] && b[1] < b[3], "{b:?}");
    assert!(
        (b[0] + 34.9).abs() < 0.2 && (b[3] + 7.95).abs() < 0.2,
        "{b:?}"
    );
    assert!((b[2] - b[0] - 0.09).abs() < 0.02, "{b:?}");
    let (minzoom, maxzoom) = (
        tj["minzoom"].as_u64().unwrap(),
        tj["maxzoom"].as_u64().unwrap(),
    );
    // 90 m cells: zoom 11 has 75 m pixels at 8° S, zoom 10 150 m.
    assert_eq!(maxzoom, 11);
    assert!(minzoom <= maxzoom && minzoom >= 5, "{minzoom}");
    let r = get(
        &s,
        s.url(&format!("{tj_path}?layer=terrain-rgb&tile_size=512")),
    )
    .await;
    let tjr = checked(&spec, "get", "/v1/maps/{id}/tilejson.json", r).await;
    assert!(validator.is_valid(&tjr), "{tjr}");
    assert_eq!(tjr["encoding"], "mapbox");
    assert!(tjr["tiles"][0]
        .as_str()
        .unwrap()
        .ends_with("terrain-rgb/{z}/{x}/{y}.png?tile_size=512"));
    let r = get(&s, s.url(&format!("{tj_path}?layer=terrarium"))).await;
    assert_eq!(r.json::<Value>().await.unwrap()["encoding"], "terrarium");

    // Tiles of every layer at the DEM's zoom, one zoom deeper, and at 512 px.
    let z = maxzoom as u8 + 1;
    let (x, y) = centre_tile(&tj, z);
    let tile = |layer: &str, z: u8, x: u64, y: u64, q: &str| {
        s.url(&format!("/v1/maps/{id}/tiles/{layer}/{z}/{x}/{y}.png{q}"))
    };
    for layer in ["snow", "relief", "hillshade", "terrain-rgb", "terrarium"] {
        let r = s.client.get(tile(layer, z, x, y, "")).send().await.unwrap();
        assert_eq!(r.status(), 200, "{layer}");
        assert_eq!(r.headers()["content-type"], "image/png");
        let img = decode(&r.bytes().await.unwrap());
        assert_eq!(img.dimensions(), (256, 256));
        let opaque = img.pixels().filter(|p| p[3] > 0).count();
        assert!(opaque > 0, "{layer}: nothing drawn");
    }
    let r = get(&s, tile("relief", z, x, y, "?tile_size=512")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(decode(&r.bytes().await.unwrap()).dimensions(), (512, 512));

    // The elevation encodings decode to the same elevations within their steps, in the DEM's
    // range (−1 … 88 m).
    let rgb = decode(
        &get(&s, tile("terrain-rgb", z, x, y, ""))
            .await
            .bytes()
            .await
            .unwrap(),
    );
    let ter = decode(
        &get(&s, tile("terrarium", z, x, y, ""))
            .await
            .bytes()
            .await
            .unwrap(),
    );
    let mut n = 0;
    for (a, b) in rgb.pixels().zip(ter.pixels()) {
        assert_eq!(a[3], b[3]);
        if a[3] == 0 {
            continue;
        }
        let ha = decode_terrain_rgb([a[0], a[1], a[2]]);
        let hb = decode_terrarium([b[0], b[1], b[2]]);
        assert!((ha - hb).abs() <= 0.05 + 0.5 / 256.0 + 1e-3, "{ha} {hb}");
        assert!((-1.05..=88.05).contains(&ha), "{ha}");
        n += 1;
    }
    assert!(n > 1000, "{n}");

    // Cached: the tile is in the store, the second answer has the same ETag, and
    // If-None-Match gets 304 with no body.
    let r = get(&s, tile("snow", z, x, y, "")).await;
    let etag = r.headers()["etag"].to_str().unwrap().to_string();
    assert!(r.headers()["cache-control"]
        .to_str()
        .unwrap()
        .contains("max-age"));
    let body = r.bytes().await.unwrap();
    assert_eq!(etag, format!("\"{}\"", phenomena::store::sha256_hex(&body)));
    let cached = s.dir.path().join(format!(
        "tiles/v{}/{id}/snow/{z}/{x}/{y}@256.png",
        phenomena::store::maps::TILE_VERSION
    ));
    assert_eq!(std::fs::read(&cached).unwrap(), body.to_vec());
    let r = s
        .client
        .get(tile("snow", z, x, y, ""))
        .header("If-None-Match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 304);
    assert_eq!(r.headers()["etag"].to_str().unwrap(), etag);
    assert!(r.bytes().await.unwrap().is_empty());
    let r = s
        .client
        .get(tile("snow", z, x, y, ""))
        .header("If-None-Match", "\"something-else\"")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);

    // Off the DEM: 204. Outside the tile matrix, an unknown layer or map: 404.
    let r = get(&s, tile("snow", z, x + 50, y, "")).await;
    assert_eq!(r.status(), 204);
    assert!(r.bytes().await.unwrap().is_empty());
    let r = get(&s, tile("snow", 3, 8, 0, "")).await;
    problem(r, 404, "not-found").await;
    let r = get(&s, tile("snowy", z, x, y, "")).await;
    problem(r, 404, "not-found").await;
    let r = get(&s, tile("snow", 25, 0, 0, "")).await;
    problem(r, 404, "not-found").await;
    let r = s
        .client
        .get(s.url(&format!("/v1/maps/{}/tiles/snow/1/0/0.png", "a".repeat(64))))
        .send()
        .await
        .unwrap();
    problem(r, 404, "not-found").await;
    let r = get(&s, tile("snow", z, x, y, "?tile_size=300")).await;
    problem(r, 400, "bad-request").await;
    let r = get(&s, tile("snow", z, x, y, "?zoom=3")).await;
    problem(r, 400, "bad-request").await;
    let r = get(
        &s,
        s.url(&format!("/v1/maps/{id}/tiles/snow/{z}/{x}/abc.png")),
    )
    .await;
    problem(r, 404, "not-found").await;
}

#[tokio::test]
async fn maps_refuse_what_they_cannot_place() {
    // An output limit below the default render size: a map renders no `render.png`, so its
    // parameters are not held to it.
    let s = Server::start(|c| c.max_output_pixels = 64 * 64).await;
    // The studio's example DEM has no CRS (metre coordinates from 0, 0): no place on Earth.
    let ex = s
        .client
        .get(s.url("/v1/examples/dem.asc"))
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    let r = s
        .client
        .post(s.url("/v1/assets?filename=dem.asc"))
        .body(ex)
        .send()
        .await
        .unwrap();
    let asset = r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    let r = post_map(&s, json!({"asset": asset})).await;
    let p = problem(r, 422, "invalid-input").await;
    assert!(p["detail"].as_str().unwrap().contains("EPSG"), "{p}");
    // Unknown parameters, unknown assets.
    let geo = upload(&s, "dem/jacksboro_fault_dem_f32.tif").await;
    let r = post_map(&s, json!({"asset": geo, "params": {"snowiness": 1}})).await;
    problem(r, 422, "invalid-parameter").await;
    let r = post_map(&s, json!({"asset": "b".repeat(64)})).await;
    problem(r, 404, "not-found").await;
    let r = s
        .client
        .get(s.url(&format!("/v1/maps/{}", "c".repeat(64))))
        .send()
        .await
        .unwrap();
    problem(r, 404, "not-found").await;
    // A geographic DEM makes a map whose TileJSON is in degrees as given.
    let r = post_map(&s, json!({"asset": geo})).await;
    assert_eq!(r.status(), 201);
    let map: Value = r.json().await.unwrap();
    let b = &map["bounds"];
    // Jacksboro: west −84.41375, north 36.44625, 403 × 344 cells of 3″.
    assert!((b[0].as_f64().unwrap() + 84.41375).abs() < 1e-9, "{b}");
    assert!((b[3].as_f64().unwrap() - 36.44625).abs() < 1e-9, "{b}");
    assert!(
        (b[2].as_f64().unwrap() - (-84.41375 + 403.0 * 3.0 / 3600.0)).abs() < 1e-9,
        "{b}"
    );
}

/// Retention (issue 22): a map lives as long as its DEM asset. With a 6 s retention and a sweep
/// every second, the asset (uploaded, then not used again) expires, and the sweep deletes the
/// map's record and every tile cached for it; the map then answers 404.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn maps_are_swept_with_their_dem_asset() {
    let s = Server::start(|c| {
        c.retention_secs = 6;
        c.sweep_interval_secs = 1;
    })
    .await;
    let asset = upload(&s, "dem/olinda_dem_utm25s.tif").await;
    let r = post_map(&s, json!({"asset": asset})).await;
    assert_eq!(r.status(), 201);
    let map: Value = r.json().await.unwrap();
    let id = map["id"].as_str().unwrap().to_string();
    let z = map["maxzoom"].as_u64().unwrap() as u8;
    let (x, y) = centre_tile(&map, z);
    let r = get(
        &s,
        s.url(&format!("/v1/maps/{id}/tiles/snow/{z}/{x}/{y}.png")),
    )
    .await;
    assert_eq!(r.status(), 200);
    let tiles = s.dir.path().join("tiles");
    let record = s.dir.path().join(format!("maps/{id}.json"));
    assert!(crate::common::count_files(&tiles) >= 1);
    assert!(record.is_file());
    let t0 = std::time::Instant::now();
    loop {
        let r = get(&s, s.url(&format!("/v1/maps/{id}"))).await;
        if r.status() == 404 {
            problem(r, 404, "not-found").await;
            break;
        }
        assert_eq!(r.status(), 200);
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(40),
            "the map was not swept"
        );
        tokio::time::sleep(std::time::Duration::from_millis(250)).await;
    }
    assert!(!record.exists(), "the record is deleted");
    assert_eq!(crate::common::count_files(&tiles), 0, "and its tiles");
    let r = get(
        &s,
        s.url(&format!("/v1/maps/{id}/tiles/snow/{z}/{x}/{y}.png")),
    )
    .await;
    problem(r, 404, "not-found").await;
}

/// A map whose DEM asset is no longer stored (deleted while the server was down) answers 410
/// with the reason, for the map, its TileJSON and its tiles.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_map_without_its_dem_answers_410() {
    let s = Server::start(|_| {}).await;
    let asset = upload(&s, "dem/jacksboro_fault_dem_f32.tif").await;
    let r = post_map(&s, json!({"asset": asset})).await;
    assert_eq!(r.status(), 201);
    let map: Value = r.json().await.unwrap();
    let id = map["id"].as_str().unwrap().to_string();
    let z = map["maxzoom"].as_u64().unwrap() as u8;
    let (x, y) = centre_tile(&map, z);
    let left = s.stop().await;
    let blob = left
        .dir
        .path()
        .join(format!("blobs/sha256/{}/{asset}", &asset[..2]));
    std::fs::remove_file(&blob).unwrap();
    let s = Server::start_in(left, |_| {}).await;
    for path in [
        format!("/v1/maps/{id}/tiles/relief/{z}/{x}/{y}.png"),
        format!("/v1/maps/{id}"),
        format!("/v1/maps/{id}/tilejson.json"),
    ] {
        let r = get(&s, s.url(&path)).await;
        let p = problem(r, 410, "input-missing").await;
        assert!(
            p["detail"].as_str().unwrap().contains(&asset),
            "{path}: {p}"
        );
    }
}

/// `dem` as a float32 COG written by the engine's COG writer.
fn cog_of(dem: &phenomena_engine::geom::Dem) -> Vec<u8> {
    let mut g = dem.georef.clone();
    g.tags = Default::default();
    phenomena_engine::formats::geotiff_write::write_float32_geotiff(
        dem.width,
        dem.height,
        &dem.heights,
        &g,
    )
}

/// Tanzawa with `k`² cells per cell (bilinear), a COG large enough that a tile is a small part.
fn upsampled_tanzawa(k: usize) -> phenomena_engine::geom::Dem {
    use phenomena_engine::formats::dem::{decode_dem, DemOptions};
    let path = data("dem/tanzawa_sagami_aster_gdem2.tif");
    let dem = decode_dem(
        &std::fs::read(&path).unwrap(),
        Some("tanzawa.tif"),
        &DemOptions::default(),
    )
    .unwrap();
    let (w, h) = (dem.width * k, dem.height * k);
    let mut heights = vec![0f32; w * h];
    for r in 0..h {
        let y = ((r as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (dem.height - 1) as f64);
        let (r0, fy) = (y.floor() as usize, (y - y.floor()) as f32);
        let r1 = (r0 + 1).min(dem.height - 1);
        for c in 0..w {
            let x = ((c as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (dem.width - 1) as f64);
            let (c0, fx) = (x.floor() as usize, (x - x.floor()) as f32);
            let c1 = (c0 + 1).min(dem.width - 1);
            let top = dem.at(c0, r0) * (1.0 - fx) + dem.at(c1, r0) * fx;
            let bottom = dem.at(c0, r1) * (1.0 - fx) + dem.at(c1, r1) * fx;
            heights[r * w + c] = top * (1.0 - fy) + bottom * fy;
        }
    }
    let mut georef = dem.georef.clone();
    if let Some(t) = georef.transform.as_mut() {
        t[1] /= k as f64;
        t[5] /= k as f64;
    }
    phenomena_engine::geom::Dem {
        width: w,
        height: h,
        heights,
        dx: dem.dx / k as f64,
        dy: dem.dy / k as f64,
        georef,
    }
}

/// `phenomena_map_dem_bytes_read_total` of the server at `base`.
async fn dem_bytes_read(c: &reqwest::Client, base: &str) -> u64 {
    counter(c, base, "phenomena_map_dem_bytes_read_total").await
}

/// The Prometheus counter `name` of the server at `base`.
async fn counter(c: &reqwest::Client, base: &str, name: &str) -> u64 {
    let text = c
        .get(format!("{base}/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' '))
        .and_then(|v| v.trim().parse::<f64>().ok())
        .unwrap_or_else(|| panic!("no {name} in {text}")) as u64
}

/// Many API replicas serve one map and share its tile cache (issue 22, "Caching and scale"):
/// two `--role api` replicas on one Redis and one store directory. The map made on the first is
/// served by the second; a tile computed by one is read from the shared cache by the other
/// (same bytes and ETag; its `phenomena_map_tiles_computed_total` does not move), and each
/// replica computes only the tiles nobody computed before.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn api_replicas_share_a_map_and_its_tile_cache() {
    use crate::common::{redis_url, RedisPrefix};
    use crate::scale::Replica;
    let dir = tempfile::tempdir().unwrap();
    let prefix = RedisPrefix::new();
    let redis = redis_url();
    let a = Replica::spawn(dir.path(), &redis, &prefix.0, "api", "api-a");
    let b = Replica::spawn(dir.path(), &redis, &prefix.0, "api", "api-b");
    let c = reqwest::Client::new();
    let (base_a, base_b) = (a.url(""), b.url(""));

    let path = data("dem/olinda_dem_utm25s.tif");
    let asset: Value = c
        .post(a.url("/v1/assets?filename=olinda_dem_utm25s.tif"))
        .body(std::fs::read(&path).unwrap())
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let r = c
        .post(a.url("/v1/maps"))
        .json(&json!({"asset": asset["id"]}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let map: Value = r.json().await.unwrap();
    let id = map["id"].as_str().unwrap().to_string();
    // The other replica knows the map: its record is in the shared store.
    let r = c
        .get(b.url(&format!("/v1/maps/{id}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let on_b: Value = r.json().await.unwrap();
    assert_eq!(on_b["id"], map["id"]);

    let z = map["maxzoom"].as_u64().unwrap() as u8;
    let (x, y) = centre_tile(&map, z);
    let tile =
        |r: &Replica, layer: &str| r.url(&format!("/v1/maps/{id}/tiles/{layer}/{z}/{x}/{y}.png"));
    let fetch = |url: String| {
        let c = c.clone();
        async move {
            let r = c.get(url).send().await.unwrap();
            assert_eq!(r.status(), 200);
            let etag = r.headers()["etag"].to_str().unwrap().to_string();
            (etag, r.bytes().await.unwrap())
        }
    };
    assert_eq!(
        counter(&c, &base_a, "phenomena_map_tiles_computed_total").await,
        0
    );
    let (etag_a, png_a) = fetch(tile(&a, "snow")).await;
    assert_eq!(
        counter(&c, &base_a, "phenomena_map_tiles_computed_total").await,
        1
    );
    let (etag_b, png_b) = fetch(tile(&b, "snow")).await;
    assert_eq!(etag_a, etag_b);
    assert_eq!(png_a, png_b);
    assert_eq!(
        counter(&c, &base_b, "phenomena_map_tiles_computed_total").await,
        0,
        "the second replica read the first one's tile from the shared cache"
    );
    // The other way round: a tile the second replica computes is a cache read for the first.
    let (etag_b2, png_b2) = fetch(tile(&b, "relief")).await;
    assert_eq!(
        counter(&c, &base_b, "phenomena_map_tiles_computed_total").await,
        1
    );
    let (etag_a2, png_a2) = fetch(tile(&a, "relief")).await;
    assert_ne!(etag_a, etag_a2, "two different tiles");
    assert_eq!((etag_a2, png_a2), (etag_b2, png_b2));
    assert_eq!(
        counter(&c, &base_a, "phenomena_map_tiles_computed_total").await,
        1
    );
}

/// A COG DEM in S3-compatible storage (moto) is never downloaded whole: with
/// `--map-whole-max-cells 500000`, a 2652 × 2604-cell COG makes a map from its header and a
/// bounded overview, and a tile at the DEM's own zoom reads a few of its internal tiles by
/// ranged GETs (counted by `phenomena_map_dem_bytes_read_total`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cog_dem_in_s3_is_read_by_ranges() {
    let moto = crate::shared_store::Moto::start();
    let endpoint = format!("http://127.0.0.1:{}", moto.port);
    let c = reqwest::Client::new();
    let resp = c
        .put(format!("{endpoint}/phenomena-maps"))
        .send()
        .await
        .unwrap();
    assert!(resp.status().is_success(), "{}", resp.status());
    let env = [
        ("AWS_ACCESS_KEY_ID", "test"),
        ("AWS_SECRET_ACCESS_KEY", "test"),
        ("AWS_REGION", "us-east-1"),
        ("AWS_ENDPOINT", endpoint.as_str()),
        ("AWS_ALLOW_HTTP", "true"),
    ];
    let dir = tempfile::tempdir().unwrap();
    let (mut child, addr) = crate::restart::spawn_server_env(
        dir.path(),
        &[
            "--store-url",
            "s3://phenomena-maps/svc",
            "--map-whole-max-cells",
            "500000",
        ],
        &env,
    );
    let base = format!("http://{addr}");
    let cog = cog_of(&upsampled_tanzawa(3));
    let size = cog.len() as u64;
    let asset: Value = c
        .post(format!("{base}/v1/assets?filename=tanzawa_cog.tif"))
        .body(cog)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let r = c
        .post(format!("{base}/v1/maps"))
        .json(&json!({"asset": asset["id"]}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let map: Value = r.json().await.unwrap();
    assert_eq!(map["width"], 2652);
    let opened = dem_bytes_read(&c, &base).await;
    assert!(
        opened > 0 && opened * 4 < size,
        "making the map read {opened} of {size} bytes"
    );
    let z = map["maxzoom"].as_u64().unwrap() as u8;
    let (x, y) = centre_tile(&map, z);
    let id = map["id"].as_str().unwrap();
    let r = c
        .get(format!("{base}/v1/maps/{id}/tiles/snow/{z}/{x}/{y}.png"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let png = decode(&r.bytes().await.unwrap());
    assert!(png.pixels().filter(|p| p[3] > 0).count() > 256 * 100);
    let tile = dem_bytes_read(&c, &base).await - opened;
    assert!(
        tile > 0 && tile * 6 < size,
        "one tile read {tile} of {size} bytes"
    );
    let _ = child.kill();
    let _ = child.wait();
}
