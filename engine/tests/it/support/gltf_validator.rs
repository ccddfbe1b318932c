//! Every GLB the engine writes passes the Khronos glTF validator (the `gltf-validator` npm
//! package) with no errors. The package is installed on first use into
//! `target/gltf-validator/` (npm's registry is reachable on every machine of this project).

use std::path::PathBuf;
use std::process::Command;

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::params::Limits;
use phenomena_engine::snow_terrain::{run, SnowTerrainParams};
use phenomena_engine::NoControl;
use serde_json::{json, Value};

/// Pinned validator version.
const VALIDATOR: &str = "gltf-validator@2.0.0-dev.3.10";

fn validator_dir() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/gltf-validator");
    let module = dir.join("node_modules/gltf-validator");
    if !module.exists() {
        std::fs::create_dir_all(&dir).unwrap();
        let status = Command::new("npm")
            .args(["install", "--no-audit", "--no-fund", "--silent", "--prefix"])
            .arg(&dir)
            .arg(VALIDATOR)
            .status()
            .expect("npm is needed to install the glTF validator");
        assert!(status.success(), "npm install {VALIDATOR} failed");
    }
    dir
}

/// Runs the validator on `glb`; returns its report.
pub fn validate_glb(name: &str, glb: &[u8]) -> Value {
    let dir = validator_dir();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join(name);
    std::fs::write(&path, glb).unwrap();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/support/validate-gltf.js");
    let out = Command::new("node")
        .arg(script)
        .arg(&path)
        .env("NODE_PATH", dir.join("node_modules"))
        .output()
        .expect("node is needed to run the glTF validator");
    assert!(
        out.status.success(),
        "validator failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

pub(crate) fn assert_valid(name: &str, glb: &[u8]) {
    let report = validate_glb(name, glb);
    let errors = report["issues"]["numErrors"].as_u64().unwrap();
    assert_eq!(
        errors,
        0,
        "{name}: {}",
        serde_json::to_string_pretty(&report["issues"]).unwrap()
    );
}

#[test]
fn terrain_glb_is_valid() {
    for (file, p) in [
        (
            "maunga_whau_volcano.asc",
            json!({"width": 32, "height": 32}),
        ),
        // Nodata holes drop triangles; a tight budget decimates.
        (
            "luxembourg_elev.tif",
            json!({"width": 32, "height": 32, "mesh_max_vertices": 500}),
        ),
    ] {
        let path = format!(
            "{}/../../shared/data/dem/{file}",
            env!("CARGO_MANIFEST_DIR")
        );
        let dem = decode_dem(
            &std::fs::read(path).unwrap(),
            Some(file),
            &DemOptions::default(),
        )
        .unwrap();
        let params = SnowTerrainParams::from_json(&p, &Limits::default()).unwrap();
        let outs = run(&dem, &params, &NoControl).unwrap();
        let glb = &outs.iter().find(|o| o.name == "terrain.glb").unwrap().bytes;
        assert_valid(file, glb);
    }
}
