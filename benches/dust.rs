//! Criterion benches of the `dust` pipeline (SPEC §4), one per stage (STYLE habit 10).
//!
//! - `dust/fibers_1024_20000`: one 1024² fibre texture with 20,000 fibres (issue 6 target ≤ 50 ms),
//!   default fibre parameters (48 steps, 2 bends); the tileable noise field is built outside the
//!   timed loop, and timed on its own as `dust/noise_1024`.
//! - `dust/exposure_100k_64`: the dust amount D with the exposure term, 64 rays per vertex, on
//!   ≥ 100,000 vertices (issue 6 target ≤ 1 s): copies of the Stanford armadillo
//!   (`../shared/data/mesh/armadillo.stl`) side by side on a grid until the vertex count reaches
//!   100,000 (the copies shade each other as well as themselves). Includes the BVH build.
//!
//! Run: `cargo bench --bench dust`.
#![allow(clippy::unwrap_used, clippy::expect_used)] // benches may unwrap (STYLE habit 4)

use std::path::PathBuf;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use phenomena_engine::dust::amount::{dust_amount, AmountModel};
use phenomena_engine::dust::fibers::{fiber_texture, FiberParams};
use phenomena_engine::dust::noise::TileableNoise;
use phenomena_engine::formats::mesh::{decode_mesh, MeshOptions};
use phenomena_engine::geom::mesh::Mesh;

fn armadillo_grid(min_vertices: usize) -> Mesh {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mesh/armadillo.stl");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let one = decode_mesh(&bytes, Some("armadillo.stl"), &MeshOptions::default()).unwrap();
    let (lo, hi) = one.bounds().unwrap();
    let step = [(hi[0] - lo[0]) * 1.1, (hi[2] - lo[2]) * 1.1];
    let copies = min_vertices.div_ceil(one.positions.len());
    let side = (copies as f64).sqrt().ceil() as usize;
    let mut m = Mesh::default();
    for c in 0..copies {
        let (i, j) = (c % side, c / side);
        let base = m.positions.len() as u32;
        m.positions.extend(
            one.positions
                .iter()
                .map(|p| [p[0] + i as f32 * step[0], p[1], p[2] + j as f32 * step[1]]),
        );
        m.triangles.extend(
            one.triangles
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }
    m
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("dust");
    g.sample_size(10).measurement_time(Duration::from_secs(8));

    let noise = TileableNoise::new(1, 4.0, 5);
    g.bench_function("noise_1024", |b| b.iter(|| noise.texture(1024, 1024)));
    let field = noise.texture(1024, 1024);
    let params = FiberParams::default();
    g.bench_function("fibers_1024_20000", |b| {
        b.iter(|| fiber_texture(&params, &field, 1024, 1024, 1, 0, 20_000))
    });

    let mesh = armadillo_grid(100_000);
    eprintln!(
        "exposure mesh: {} vertices, {} triangles",
        mesh.positions.len(),
        mesh.triangles.len()
    );
    let model = AmountModel::default();
    g.bench_function("exposure_100k_64", |b| {
        b.iter(|| dust_amount(&mesh, &model))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
