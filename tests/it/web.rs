//! The studio page (issue 7): its files are served with the right types, unknown files are a
//! problem+json 404, the example inputs are deterministic and real inputs of their pipelines, and
//! the page itself works in headless Chromium (`tests/browser/studio.mjs`).

use std::path::PathBuf;
use std::process::Command;

use serde_json::{json, Value};

use crate::common::Server;

#[tokio::test]
async fn page_files_are_served_with_their_types() {
    let s = Server::start(|_| {}).await;
    let r = s.client.get(s.url("/")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "text/html; charset=utf-8");
    assert_eq!(r.headers()["cache-control"], "no-cache");
    let html = r.text().await.unwrap();
    assert!(html.contains(r#"<script type="module" src="/web/app.js">"#));
    // Nothing but the server: no http(s) URLs to load (links to docs are not loads, and there are none).
    assert!(!html.contains("http://") && !html.contains("https://"));

    for (file, media) in [
        ("index.html", "text/html; charset=utf-8"),
        ("app.js", "text/javascript; charset=utf-8"),
        ("yaml.js", "text/javascript; charset=utf-8"),
        ("cloud.js", "text/javascript; charset=utf-8"),
        ("form.js", "text/javascript; charset=utf-8"),
        ("viewer.js", "text/javascript; charset=utf-8"),
        ("map.js", "text/javascript; charset=utf-8"),
        ("labels.js", "text/javascript; charset=utf-8"),
        ("style.css", "text/css; charset=utf-8"),
    ] {
        let r = s
            .client
            .get(s.url(&format!("/web/{file}")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200, "{file}");
        assert_eq!(r.headers()["content-type"], media, "{file}");
        let on_disk = std::fs::read(
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("web")
                .join(file),
        )
        .unwrap();
        assert_eq!(r.bytes().await.unwrap().as_ref(), &on_disk[..], "{file}");
    }
    for bad in [
        "/web/nope.js",
        "/web/..%2FCargo.toml",
        "/web/vendor/three/package.json",
        "/web/vendor/../Cargo.toml",
        "/web/vendor/three/..%2F..%2FCargo.toml",
        "/v1/examples/nope.npy",
    ] {
        let r = s.client.get(s.url(bad)).send().await.unwrap();
        assert_eq!(r.status(), 404, "{bad}");
        assert_eq!(
            r.headers()["content-type"],
            "application/problem+json",
            "{bad}"
        );
    }
    s.stop().await;
}

/// The third-party files (issue 23): `/web/vendor.json` names what the build installed from
/// `web/package-lock.json`, and each file `web/vendor.txt` lists is served under `/web/vendor/`
/// with its type, byte for byte what `npm ci` installed (the lock's version of three.js). Built
/// without npm (`PHENOMENA_NPM=off`), the list is empty and says why and how to install.
#[tokio::test]
async fn vendor_files_are_served_from_the_lock_file() {
    let s = Server::start(|_| {}).await;
    let r = s
        .client
        .get(s.url("/web/vendor.json"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "application/json");
    let v: Value = r.json().await.unwrap();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let listed: Vec<String> = std::fs::read_to_string(root.join("web/vendor.txt"))
        .unwrap()
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(String::from)
        .collect();
    if v["installed"] == false {
        // A build without npm: nothing served, and the reason and the remedy in words.
        assert_eq!(v["files"], json!([]), "{v}");
        assert!(v["reason"].as_str().is_some_and(|r| !r.is_empty()), "{v}");
        assert!(v["install"].as_str().unwrap().contains("npm"), "{v}");
        let r = s
            .client
            .get(s.url(&format!("/web/vendor/{}", listed[0])))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 404);
        s.stop().await;
        return;
    }
    let lock: Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("web/package-lock.json")).unwrap())
            .unwrap();
    for pkg in ["three", "maplibre-gl"] {
        assert_eq!(
            v["packages"][pkg],
            lock["packages"][format!("node_modules/{pkg}")]["version"],
            "{pkg}: {v}"
        );
    }
    assert_eq!(v["files"], json!(listed));
    let modules = playwright_dir().join("node_modules");
    for f in &listed {
        let r = s
            .client
            .get(s.url(&format!("/web/vendor/{f}")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200, "{f}");
        let media = if f.ends_with(".js") || f.ends_with(".mjs") {
            "text/javascript; charset=utf-8"
        } else if f.ends_with(".css") {
            "text/css; charset=utf-8"
        } else {
            "text/plain; charset=utf-8"
        };
        assert_eq!(r.headers()["content-type"], media, "{f}");
        assert_eq!(r.headers()["x-content-type-options"], "nosniff", "{f}");
        let on_disk = std::fs::read(modules.join(f)).unwrap();
        assert_eq!(r.bytes().await.unwrap().as_ref(), &on_disk[..], "{f}");
    }
    // The import map of the page names files that are served.
    let html = s
        .client
        .get(s.url("/"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    for path in [
        "/web/vendor/three/build/three.module.min.js",
        "/web/vendor/three/examples/jsm/",
        "/web/vendor/maplibre-gl/dist/maplibre-gl.mjs",
    ] {
        assert!(html.contains(path), "{path}");
    }
    s.stop().await;
}

#[tokio::test]
async fn examples_are_deterministic() {
    let s = Server::start(|_| {}).await;
    for name in ["dem.asc", "dem.tif", "mesh.obj", "volume.npy"] {
        let get = || async {
            let r = s
                .client
                .get(s.url(&format!("/v1/examples/{name}")))
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 200, "{name}");
            r.bytes().await.unwrap()
        };
        assert_eq!(get().await, get().await, "{name} differs between requests");
    }
    let npy = phenomena::api::web::example_volume();
    let header_len = u16::from_le_bytes([npy[8], npy[9]]) as usize;
    assert_eq!((10 + header_len) % 64, 0, "npy header is not 64-aligned");
    assert_eq!(npy.len(), 10 + header_len + 40 * 32 * 40 * 4);
    let dem = phenomena::api::web::example_dem();
    assert_eq!(dem.lines().count(), 6 + 96);
    assert_eq!(dem.lines().nth(6).unwrap().split(' ').count(), 96);
    s.stop().await;
}

/// `dem.tif` (issue 22) is a georeferenced GeoTIFF the Map tab's "Try the example" uses: it makes
/// a map (`POST /v1/maps`) placed where its EPSG:32632 corner says, in the Valais Alps, with the
/// example terrain's cells.
#[tokio::test]
async fn the_georeferenced_example_makes_a_map() {
    let s = Server::start(|_| {}).await;
    let r = s
        .client
        .get(s.url("/v1/examples/dem.tif"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "image/tiff");
    let bytes = r.bytes().await.unwrap();
    assert_eq!(&bytes[..4], b"II*\0", "a little-endian TIFF");
    let asset: Value = s
        .client
        .post(s.url("/v1/assets?filename=dem.tif"))
        .body(bytes)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let r = s
        .client
        .post(s.url("/v1/maps"))
        .json(&json!({"asset": asset["id"], "params": {}}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let map: Value = r.json().await.unwrap();
    let n = phenomena::api::web::EXAMPLE_TIF_SIDE as u64;
    assert_eq!(
        (map["width"].as_u64(), map["height"].as_u64()),
        (Some(n), Some(n)),
        "{map}"
    );
    assert!(map["crs"].as_str().unwrap().contains("32632"), "{map}");
    // 390 000 m E, 5 110 000 m N in UTM 32N, 30.7 km a side: 7.576–7.979° E, 45.858–46.139° N
    // (the corners by GDAL's gdaltransform).
    let b: Vec<f64> = map["bounds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(
        (7.57..7.58).contains(&b[0]) && (7.975..7.985).contains(&b[2]),
        "longitudes {b:?}"
    );
    assert!(
        (45.855..45.86).contains(&b[1]) && (46.135..46.145).contains(&b[3]),
        "latitudes {b:?}"
    );
    s.stop().await;
}

/// Uploads an example and runs its pipeline on it: each example is a valid input.
#[tokio::test]
async fn examples_run_through_their_pipelines() {
    let s = Server::start(|_| {}).await;
    for (name, pipeline, params) in [
        (
            "dem.asc",
            "snow-terrain",
            json!({"width": 64, "height": 48, "samples": 1}),
        ),
        (
            "mesh.obj",
            "snow-cover",
            json!({"width": 64, "height": 48, "resolution": 48, "directions": 4, "steps": 4}),
        ),
        ("volume.npy", "cloud", json!({"width": 64, "height": 48})),
        (
            "mesh.obj",
            "dust",
            json!({"width": 64, "height": 48, "shells": 4, "texture_size": 64, "fibers": 100,
                   "exposure_rays": 8}),
        ),
    ] {
        let bytes = s
            .client
            .get(s.url(&format!("/v1/examples/{name}")))
            .send()
            .await
            .unwrap()
            .bytes()
            .await
            .unwrap();
        let asset: Value = s
            .client
            .post(s.url(&format!("/v1/assets?filename={name}")))
            .body(bytes)
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let job: Value = s
            .client
            .post(s.url(&format!("/v1/{pipeline}")))
            .header("prefer", "wait=60")
            .json(&json!({"asset": asset["id"], "params": params}))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        assert_eq!(job["status"], "succeeded", "{name}: {job}");
        let outputs: Vec<&str> = job["outputs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["name"].as_str().unwrap())
            .collect();
        assert!(outputs.contains(&"render.png"), "{name}: {outputs:?}");
    }
    s.stop().await;
}

/// The browser tests' Node packages (playwright-core, three.js, axe-core): `npm ci` of the page's
/// own `web/package.json` and lock file, dev dependencies included, into `target/browser-node/`
/// (again whenever the lock file changes).
fn playwright_dir() -> PathBuf {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("target/browser-node");
    let lock = std::fs::read(root.join("web/package-lock.json")).unwrap();
    let stamp = dir.join("installed.lock.json");
    // One process at a time: the studio and viewer tests run in parallel.
    static INSTALL: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = INSTALL.lock().unwrap_or_else(|e| e.into_inner());
    if std::fs::read(&stamp).ok().as_deref() != Some(&lock[..]) {
        std::fs::create_dir_all(&dir).unwrap();
        let _ = std::fs::remove_file(&stamp);
        std::fs::copy(root.join("web/package.json"), dir.join("package.json")).unwrap();
        std::fs::copy(
            root.join("web/package-lock.json"),
            dir.join("package-lock.json"),
        )
        .unwrap();
        let status = Command::new("npm")
            .current_dir(&dir)
            .args([
                "ci",
                "--no-audit",
                "--no-fund",
                "--ignore-scripts",
                "--loglevel=error",
            ])
            .status()
            .expect("npm is needed to install playwright-core, three and axe-core");
        assert!(status.success(), "npm ci in {} failed", dir.display());
        std::fs::write(&stamp, &lock).unwrap();
    }
    dir
}

/// The page in headless Chromium: upload a DEM and re-render on a parameter change, keyboard
/// and mouse orbit, the sweep sheet, a readable 422, structured parameters (schedule, wind,
/// layers, colours, bounds), the snow-cover progress bar, the cloud editor's sun-colour and
/// ambient strokes, shadow drag, undo and redo, the dust close-up, phone and laptop layouts, a
/// download; and (issue 23) the empty states, the 3-D viewers (load, drag, pan, reset, layer
/// toggles), the looks, Cancel, no layout shift on a re-render, the editor's thumbnails, state
/// table and before/after slider, axe-core on every tab, the viewer's words without npm — no
/// console errors, no request beyond the server. Screenshots of every tab go to
/// `target/browser/`. Needs Debian's `chromium` (`apt-get install -y chromium`, done by `.ci/run`)
/// and npm (playwright-core, three.js and axe-core are installed from `web/package-lock.json` into
/// `target/browser-node/` on first use).
/// Alone: `cargo test --test it web::studio_in_headless_chromium -- --nocapture`.
#[test]
fn studio_in_headless_chromium() {
    browser_script("studio.mjs");
}

/// The Map tab (issue 22) in headless Chromium (`tests/browser/map.mjs`): the example DEM makes
/// a map, MapLibre GL JS (from npm at build time) loads our hillshade, relief and terrain-rgb
/// tiles through our TileJSON with no console error, the 3-D terrain is on
/// (`map.getTerrain()`), the cursor's coordinates and ground height read back inside the map,
/// panning fetches new tiles, a parameter change makes a new map whose picture has less snow,
/// the snow overlay and legend, axe-core, a phone's width, and the words without npm.
/// Screenshots: `target/browser/map-*.png`. Alone:
/// `cargo test --test it web::map_tab_in_headless_chromium -- --nocapture`.
#[test]
fn map_tab_in_headless_chromium() {
    browser_script("map.mjs");
}

/// Runs `tests/browser/{script}` with node against a server started here.
fn browser_script(script: &str) {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let pw = playwright_dir();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    let s = rt.block_on(Server::start(|_| {}));
    let url = s.url("");
    let out = std::process::Command::new("node")
        .arg(root.join("tests/browser").join(script))
        .env("STUDIO_URL", &url)
        .env("PLAYWRIGHT_DIR", &pw)
        .env("SCREENSHOT_DIR", root.join("target/browser"))
        .output()
        .expect("node is needed for the browser test");
    rt.block_on(s.stop());
    let log = format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{log}");
    assert!(
        out.status.success(),
        "the browser test {script} failed:\n{log}"
    );
}

/// `displaced.glb` in a real glTF viewer: three.js's `GLTFLoader` in headless Chromium
/// (`tests/browser/gltf_viewer.mjs`) loads the snow-covered teapot with no error, makes the
/// input's part an opaque mesh with the `_SNOW_*` attributes, the snow layer a blended
/// vertex-coloured one and the flake overlay a transparent textured one, and the blended layers
/// show: drawn over the surface they change a share of the model's pixels (where snow lies, not
/// the whole model: no z-fighting) and brighten nearly all of those (white snow on grey). Screenshot:
/// `target/browser/displaced_flakes.png`. Alone: `cargo test --test it web::displaced_glb`.
#[test]
fn displaced_glb_shows_its_flakes_in_three_js() {
    use phenomena_engine::params::Limits;
    use phenomena_engine::registry::{self, PipelineKind, PipelineParams};
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let pw = playwright_dir();
    let file = "teapot_npm.obj";
    let bytes = std::fs::read(root.join("../shared/data/mesh").join(file)).unwrap();
    let l = Limits::default();
    let params = json!({"resolution": 128, "directions": 8, "steps": 6, "width": 64, "height": 48});
    let p = PipelineParams::parse(PipelineKind::SnowCover, &params, &l).unwrap();
    let job = registry::decode(p, &bytes, Some(file), &l).unwrap();
    let outs = registry::run(&job, &phenomena_engine::NoControl).unwrap();
    let glb = &outs
        .iter()
        .find(|o| o.name == "displaced.glb")
        .unwrap()
        .bytes;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("displaced.glb");
    std::fs::write(&path, glb).unwrap();

    let out = Command::new("node")
        .arg(root.join("tests/browser/gltf_viewer.mjs"))
        .env("GLB", &path)
        .env("PLAYWRIGHT_DIR", &pw)
        .env(
            "SCREENSHOT",
            root.join("target/browser/displaced_flakes.png"),
        )
        .output()
        .expect("node is needed for the browser test");
    let log = format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "the viewer failed:\n{log}");
    let r: Value = serde_json::from_str(log.lines().next().unwrap_or_default())
        .unwrap_or_else(|e| panic!("{e}: {log}"));
    assert_eq!(r["problems"], json!([]), "{r}");
    assert_eq!(r["error"], Value::Null, "{r}");
    // The input's part (its own material, no vertex colours: the teapot OBJ has none) with the
    // snow attributes, the snow as a blended vertex-coloured layer over it (alpha = the snow
    // amount; issue 18), and the flake overlay.
    let meshes = r["meshes"].as_array().unwrap();
    assert_eq!(meshes.len(), 3, "surface + snow layer + flake overlay: {r}");
    let (surface, layer, flakes) = (&meshes[0], &meshes[1], &meshes[2]);
    assert_eq!(surface["material"], "part0");
    assert_eq!(surface["transparent"], false);
    for a in [
        "_snow_coverage",
        "_snow_depth",
        "_snow_probability",
        "normal",
    ] {
        assert!(
            surface["attributes"]
                .as_array()
                .unwrap()
                .contains(&json!(a)),
            "{a}: {r}"
        );
    }
    assert_eq!(layer["material"], "snow_layer");
    assert_eq!(layer["transparent"], true);
    assert_eq!(layer["vertexColors"], true);
    assert_eq!(flakes["material"], "snow_flakes");
    assert_eq!(flakes["transparent"], true);
    assert_eq!(flakes["texture"], true);
    assert_eq!(flakes["vertexColors"], true);
    assert!(flakes["attributes"]
        .as_array()
        .unwrap()
        .contains(&json!("uv")));
    let n = |k: &str| r[k].as_f64().unwrap();
    let (model, changed, brighter) = (n("model"), n("changed"), n("brighter"));
    assert!(
        model > 0.2 * 640.0 * 480.0,
        "the camera frames the model: {r}"
    );
    assert!(
        changed > 0.005 * model && changed < 0.5 * model,
        "snow and flakes on part of the model: {r}"
    );
    assert!(brighter >= 0.95 * changed, "white snow on grey: {r}");
}
