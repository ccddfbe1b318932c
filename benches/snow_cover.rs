//! Criterion benches of the `snow-cover` model (issue 4's figures), on the scenes of
//! `phenomena_engine::testkit::snow_scenes` (the engine's tests use the same ones).
//!
//! - `probability/paper`: the journal's scale, 5,114 triangles, K = 5, 128² maps (target ≤ 5 ms);
//! - `probability/1m_k64_1024`: 999,890 triangles, K = 64, 1024² maps (target ≤ 1.5 s); about 2 s
//!   an iteration, so only with `SNOW_COVER_BENCH_BIG=1`;
//! - `stabilize/pile_1024`: a 1 m pile (disc r = 0.5 m) on a 1024² map to convergence (≤ 0.5 s);
//! - `animation/step_12646_200`: one step (accumulate + stabilize) of the 12,646-triangle table
//!   scene with two 200² maps, K = 32, 300 steps of 0.05 m/h over 12 h cycled (≥ 100 steps/s);
//! - `baseline/upward_rays_paper_vertices` and `…_cells`: upward ray casting through `obvhs`'s
//!   CWBVH at the journal's scale, per mesh vertex and per map cell, K = 5 (the honest baseline).
//!
//! - `stabilize/table_1024_everywhere`: 1 m of snow everywhere on the 1024² table scene to
//!   convergence (minutes: the coarse levels treat the table's edge as a wall), only with
//!   `SNOW_COVER_BENCH_BIG=1`;
//! - `shape/snow_meshes_512` and `shape/displace_2cm`: the snow meshes of a fully covered 512²
//!   layer (the default resolution) and a plane displaced by it to 2 cm edges.
//!
//! Run: `cargo bench --bench snow_cover` (about a minute on 2 cores after the build).
#![allow(clippy::unwrap_used, clippy::expect_used)] // benches may unwrap (STYLE habit 4)

use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};
use phenomena_engine::snow_cover::shape::{displace, snow_meshes, DEFAULT_MIN_DEPTH_M};
use phenomena_engine::snow_cover::snowfall::{accumulate, accumulate_between};
use phenomena_engine::snow_cover::{
    build_snow_maps, snow_probability, snowfall_directions, Receiver, Settler, Snowfall,
};
use phenomena_engine::testkit::snow_scenes::{
    animation_scene, map_points, million_scene, obvhs_scene, paper_scene, pile_plane, put_pile,
    table_scene, upward_ray_casting, SceneBuilder,
};
use phenomena_engine::NoControl;

fn probability(c: &mut Criterion) {
    let mut g = c.benchmark_group("probability");
    let mesh = paper_scene();
    let mut maps = build_snow_maps(&mesh, 128, &NoControl).unwrap();
    let dirs = snowfall_directions(5, 10.0, None, 1);
    g.bench_function("paper_5114_k5_128", |b| {
        b.iter(|| {
            snow_probability(&mesh, &mut maps, &dirs, None, Receiver::Base, &NoControl).unwrap()
        })
    });
    if std::env::var("SNOW_COVER_BENCH_BIG").as_deref() == Ok("1") {
        let mesh = million_scene();
        let mut maps = build_snow_maps(&mesh, 1024, &NoControl).unwrap();
        let dirs = snowfall_directions(64, 10.0, None, 1);
        g.sample_size(10).measurement_time(Duration::from_secs(30));
        g.bench_function("1m_k64_1024", |b| {
            b.iter(|| {
                snow_probability(&mesh, &mut maps, &dirs, None, Receiver::Base, &NoControl).unwrap()
            })
        });
    }
    g.finish();
}

fn stabilize(c: &mut Criterion) {
    let mut g = c.benchmark_group("stabilize");
    g.sample_size(10);
    let plane = pile_plane();
    let mut maps = build_snow_maps(&plane, 1024, &NoControl).unwrap();
    put_pile(&mut maps);
    let mut settler = Settler::new(&maps);
    g.bench_function("pile_1024", |b| {
        b.iter_batched_ref(
            || maps.clone(),
            |m| {
                let rep = settler.stabilize(m, 45.0, 1_000_000, &NoControl).unwrap();
                assert!(rep.converged);
            },
            criterion::BatchSize::LargeInput,
        )
    });
    if std::env::var("SNOW_COVER_BENCH_BIG").as_deref() == Ok("1") {
        let mesh = table_scene();
        let mut maps = build_snow_maps(&mesh, 1024, &NoControl).unwrap();
        maps.layers[0].probability.iter_mut().for_each(|p| *p = 1.0);
        accumulate(&mut maps, 1.0);
        let mut settler = Settler::new(&maps);
        g.bench_function("table_1024_everywhere", |b| {
            b.iter_batched_ref(
                || maps.clone(),
                |m| settler.stabilize(m, 45.0, 1_000_000, &NoControl).unwrap(),
                criterion::BatchSize::LargeInput,
            )
        });
    }
    g.finish();
}

/// The snow meshes of a fully covered 512² layer (the default resolution) over a waved 10 m
/// grid, and a 10 m plane of 4 × 4 quads displaced by them to edges of at most 2 cm.
fn shape(c: &mut Criterion) {
    let mut g = c.benchmark_group("shape");
    g.sample_size(10);
    let mut b = SceneBuilder::default();
    b.grid([0.0, 10.0], [0.0, 10.0], 64, 64, |x, z| {
        0.2 * (x * 0.9).sin() * (z * 0.7).cos()
    });
    let mut maps = build_snow_maps(&b.build(), 512, &NoControl).unwrap();
    maps.layers[0]
        .snow
        .iter_mut()
        .enumerate()
        .for_each(|(c, s)| *s = 100_000 + (c % 7) as u32 * 1000);
    g.bench_function("snow_meshes_512", |bch| {
        bch.iter(|| snow_meshes(&maps, DEFAULT_MIN_DEPTH_M))
    });
    let mut p = SceneBuilder::default();
    p.grid([0.0, 10.0], [0.0, 10.0], 4, 4, |_, _| 0.0);
    let plane = p.build();
    g.bench_function("displace_2cm", |bch| {
        bch.iter(|| displace(&plane, &maps, Some(0.02)))
    });
    g.finish();
}

fn animation(c: &mut Criterion) {
    let mut g = c.benchmark_group("animation");
    let mesh = animation_scene();
    let mut maps = build_snow_maps(&mesh, 200, &NoControl).unwrap();
    let dirs = snowfall_directions(32, 10.0, None, 0);
    snow_probability(&mesh, &mut maps, &dirs, None, Receiver::Base, &NoControl).unwrap();
    let mut settler = Settler::new(&maps);
    let (steps, hours) = (300usize, 12.0);
    let fall = Snowfall::Constant(0.05);
    let mut n = 0usize;
    g.bench_function("step_12646_200", |b| {
        b.iter_custom(|iters| {
            let mut spent = Duration::ZERO;
            for _ in 0..iters {
                if n == steps {
                    maps.clear_snow();
                    n = 0;
                }
                n += 1;
                let before = fall.cumulative(hours * (n - 1) as f64 / steps as f64);
                let after = fall.cumulative(hours * n as f64 / steps as f64);
                let t0 = Instant::now();
                accumulate_between(&mut maps, before, after);
                settler.stabilize(&mut maps, 50.0, 500, &NoControl).unwrap();
                spent += t0.elapsed();
            }
            spent
        })
    });
    g.finish();
}

fn baseline(c: &mut Criterion) {
    let mut g = c.benchmark_group("baseline");
    g.sample_size(10);
    let mesh = paper_scene();
    let maps = build_snow_maps(&mesh, 128, &NoControl).unwrap();
    let dirs = snowfall_directions(5, 10.0, None, 1);
    let (bvh, tris) = obvhs_scene(&mesh);
    let eps = 1e-4 * maps.extent;
    g.bench_function("upward_rays_paper_vertices", |b| {
        b.iter(|| upward_ray_casting(&bvh, &tris, &mesh.positions, &dirs, eps))
    });
    let cells = map_points(&maps, 1);
    g.bench_function("upward_rays_paper_cells", |b| {
        b.iter(|| upward_ray_casting(&bvh, &tris, &cells, &dirs, eps))
    });
    g.finish();
}

criterion_group!(benches, probability, stabilize, shape, animation, baseline);
criterion_main!(benches);
