//! Criterion benches of map tiles (issue 22): a cold 256-px tile of the `snow` and `relief`
//! layers at the DEM's native zoom (the TileJSON `maxzoom`), computed as the server computes a
//! tile it has not cached — the descriptor on the tile's window plus its halo, resampling and PNG
//! encoding — on a 2-thread pool. The prepared DEM is kept between tiles (as the server keeps
//! it), so a tile decodes nothing.
//!
//! Input: the Tanzawa–Sagami ASTER GDEM2 tile in `../shared/data/dem` (884 × 868 cells of 1″,
//! EPSG:4326), the tile holding its centre, default (winter) parameters.
//!
//! Also the once-per-map sun-visibility field of `relief`'s cast shadows on the whole DEM.
//!
//! Run: `cargo bench --bench map_tiles`. Targets (issue 22): snow ≤ 60 ms, relief ≤ 120 ms
//! median on 2 cores.
#![allow(clippy::unwrap_used, clippy::expect_used)] // benches may unwrap (STYLE habit 4)

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use phenomena_engine::geom::mercator::{lonlat_to_mercator, mercator_to_pixel};
use phenomena_engine::params::Limits;
use phenomena_engine::snow_terrain::tiles::{open, sun_visibility, tile_png, Layer};

fn bench(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/dem/tanzawa_sagami_aster_gdem2.tif");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let src = open(
        &bytes,
        Some("tanzawa.tif"),
        &serde_json::json!({}),
        &Limits::default(),
    )
    .unwrap();
    let info = src.info().clone();
    let z = info.maxzoom;
    let (mx, my) = lonlat_to_mercator(info.center[0], info.center[1]);
    let (px, py) = mercator_to_pixel(z, 256, mx, my);
    let (x, y) = ((px / 256.0) as u64, (py / 256.0) as u64);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let mut g = c.benchmark_group("map_tile_cold_256");
    g.sample_size(30);
    for layer in [Layer::Snow, Layer::Relief] {
        g.bench_function(format!("{}_z{z}", layer.name()), |b| {
            b.iter(|| pool.install(|| tile_png(&src, layer, z, x, y, 256).unwrap().unwrap()))
        });
    }
    g.finish();
    // The sun-visibility field of cast shadows, computed once per map on its first `relief`
    // tile (the warm-up above paid it; this is its cost alone), on the whole DEM.
    let p = phenomena_engine::snow_terrain::SnowTerrainParams::from_json(
        &serde_json::json!({}),
        &Limits::default(),
    )
    .unwrap();
    let mut g = c.benchmark_group("map_once");
    g.sample_size(10);
    g.bench_function("sun_visibility_884x868", |b| {
        b.iter(|| {
            pool.install(|| sun_visibility(src.dem().unwrap(), 180.0, p.sun_elevation_deg as f32))
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
