//! Profiling driver for the snow-terrain pipeline (BENCHMARKS.md, "Snow on terrain"):
//! `terrain_prof SIZE PRESET REPS [OUTDIR] [all]`. SIZE: `paper` (Tanzawa cropped to 400 × 200,
//! rendered 900 × 600), N (Tanzawa mirrored to N², rendered 1920 × 1080, or 960 × 540 when
//! N ≤ 2048), or a DEM path (rendered 1920 × 1080). Runs `snow_terrain::run` REPS times with
//! `outputs: ["render.png"]` (all outputs with `all`), prints the wall time of each run, and
//! writes the outputs of the last run to OUTDIR when given. REPS 0: decode only (for callgrind).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::print_stdout)]

use std::path::PathBuf;
use std::time::Instant;

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::geom::Dem;
use phenomena_engine::params::Limits;
use phenomena_engine::snow_terrain::{run, SnowTerrainParams};
use phenomena_engine::testkit::dems::mirrored;
use phenomena_engine::NoControl;

fn load(path: &std::path::Path) -> Dem {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("dem.tif");
    decode_dem(&bytes, Some(name), &DemOptions::default()).expect("decodes")
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let size = args.get(1).map_or("paper", String::as_str);
    let preset = args.get(2).map_or("winter", String::as_str);
    let reps: usize = args.get(3).map_or(1, |s| s.parse().unwrap());
    let outdir = args.get(4).filter(|s| s.as_str() != "-").map(PathBuf::from);
    let all = args.get(5).is_some_and(|s| s == "all");
    let tanzawa = || {
        load(
            &PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../../shared/data/dem/tanzawa_sagami_aster_gdem2.tif"),
        )
    };
    let (dem, w, h) = match size {
        "paper" => (mirrored(&tanzawa(), 400, 200), 900, 600),
        s => match s.parse::<usize>() {
            Ok(n) if n <= 2048 => (mirrored(&tanzawa(), n, n), 960, 540),
            Ok(n) => (mirrored(&tanzawa(), n, n), 1920, 1080),
            Err(_) => (load(&PathBuf::from(s)), 1920, 1080),
        },
    };
    let mut v = serde_json::json!({ "preset": preset, "width": w, "height": h });
    if !all {
        v["outputs"] = serde_json::json!(["render.png"]);
    }
    let p = SnowTerrainParams::from_json(&v, &Limits::default()).expect("valid params");
    let mut last = Vec::new();
    for _ in 0..reps {
        let t0 = Instant::now();
        last = run(&dem, &p, &NoControl).expect("not canceled");
        println!("{:.2} ms", t0.elapsed().as_secs_f64() * 1e3);
    }
    if let Some(dir) = outdir {
        std::fs::create_dir_all(&dir).unwrap();
        for o in &last {
            std::fs::write(dir.join(&o.name), &o.bytes).unwrap();
        }
    }
}
