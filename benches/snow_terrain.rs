//! Criterion benches of the `snow-terrain` pipeline, one per stage (STYLE habit 10), on real data.
//!
//! Input: the Tanzawa–Sagami ASTER GDEM2 tile in `../shared/data/dem` (884 × 868, ~25–31 m cells).
//! The paper's case crops it to 400 × 200; the N² cases (N = 1024…8192) tile it by mirroring
//! (so the terrain stays continuous across the seams), because no real DEM we ship is that large.
//!
//! Group `terrain_render` times the terrain renderer's two paths (`render::terrain`, "Two
//! paths") on the paper's case and across the crossover, and the pyramid of a 4096² DEM.
//!
//! Run: `cargo bench --bench snow_terrain` (a few minutes on 2 cores). `SNOW_BENCH_8192=0` skips
//! the 8192² descriptor and descriptor + render (needs ~3.5 GB).
#![allow(clippy::unwrap_used, clippy::expect_used)] // benches may unwrap (STYLE habit 4)

use std::path::PathBuf;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::formats::geotiff_write::write_float32_geotiff;
use phenomena_engine::formats::glb::terrain_glb;
use phenomena_engine::formats::png_write::encode_rgba;
use phenomena_engine::geom::camera::Camera;
use phenomena_engine::geom::{sun_direction, Dem};
use phenomena_engine::params::Limits;
use phenomena_engine::render::terrain::{
    render_accel_on_path, Lighting, RenderPath, TerrainAccel, TerrainScene,
};
use phenomena_engine::snow_terrain::altitude::apply_altitude;
use phenomena_engine::snow_terrain::color::albedo;
use phenomena_engine::snow_terrain::descriptor::{compute, DescriptorParams};
use phenomena_engine::snow_terrain::smooth::smooth_diamond;
use phenomena_engine::snow_terrain::sun::{apply_sun, Sun};
use phenomena_engine::snow_terrain::transfer::transfer_grid;
use phenomena_engine::snow_terrain::tsa::{tangent_sphere_accessibility, TsaGrid};
use phenomena_engine::snow_terrain::{overview_render, run, SnowTerrainParams};
use phenomena_engine::testkit::dems::mirrored;
use phenomena_engine::NoControl;

fn tanzawa() -> Dem {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/dem/tanzawa_sagami_aster_gdem2.tif");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    decode_dem(&bytes, Some("tanzawa.tif"), &DemOptions::default()).expect("decodes")
}

fn params(width: u32, height: u32) -> SnowTerrainParams {
    let v = serde_json::json!({ "width": width, "height": height });
    SnowTerrainParams::from_json(&v, &Limits::default()).expect("valid params")
}

/// `run`'s parameters for `preset` at `width × height`, `outputs: ["render.png"]`.
fn preset_params(preset: &str, width: u32, height: u32) -> SnowTerrainParams {
    let v = serde_json::json!({
        "preset": preset, "width": width, "height": height, "outputs": ["render.png"],
    });
    SnowTerrainParams::from_json(&v, &Limits::default()).expect("valid params")
}

/// The render of `run` with default parameters (camera and lighting as `run` builds them).
fn render(dem: &Dem, color: &[[f32; 3]], w: u32, h: u32) -> phenomena_engine::render::RgbaImage {
    overview_render(dem, color, w, h).expect("not canceled")
}

fn stages(c: &mut Criterion) {
    let src = tanzawa();
    let p = DescriptorParams::default();
    let src_d = compute(&src, &p, &NoControl, (0.0, 1.0)).expect("not canceled");
    let (radius, passes) = (
        src_d.resolved.smooth_radius,
        src_d.resolved.smooth_iterations,
    );
    let az = src_d.resolved.sun_azimuth_deg;
    let t_passes = src_d.resolved.descriptor_smooth_iterations;
    let line = src_d.resolved.snowline_m.unwrap_or(0.0);
    drop(src_d);
    let mut g = c.benchmark_group("snow_terrain");
    g.sample_size(10).warm_up_time(Duration::from_secs(1));

    // The paper's case end to end (descriptor, colour, render, all outputs).
    let paper = mirrored(&src, 400, 200);
    let pp = params(900, 600);
    g.measurement_time(Duration::from_secs(5));
    g.bench_function("paper_400x200_900x600", |b| {
        b.iter(|| run(&paper, &pp, &NoControl).expect("not canceled"))
    });
    // The same with `outputs: ["render.png"]` (descriptor, colour, render, PNG): the issue's
    // ≤ 30 ms figure.
    let pp_img = SnowTerrainParams::from_json(
        &serde_json::json!({"width": 900, "height": 600, "outputs": ["render.png"]}),
        &Limits::default(),
    )
    .expect("valid params");
    g.bench_function("paper_400x200_900x600_image", |b| {
        b.iter(|| run(&paper, &pp_img, &NoControl).expect("not canceled"))
    });
    // The issue-17 speed criterion, per preset: `run` with `outputs: ["render.png"]` and no other
    // parameter but the size (`winter`, the default) or `preset: paper` (the paper's look).
    for preset in ["winter", "paper"] {
        let pp = preset_params(preset, 900, 600);
        g.bench_function(BenchmarkId::new("paper_400x200_900x600_run", preset), |b| {
            b.iter(|| run(&paper, &pp, &NoControl).expect("not canceled"))
        });
    }

    // Stages at 4096².
    let n = 4096;
    let dem = mirrored(&src, n, n);
    let d = compute(&dem, &p, &NoControl, (0.0, 1.0)).expect("not canceled");
    g.measurement_time(Duration::from_secs(8));
    g.bench_function(format!("smooth_{n}"), |b| {
        b.iter(|| smooth_diamond(&dem.heights, n, n, radius, passes))
    });
    let grid = TsaGrid {
        heights: &d.smoothed,
        width: n,
        height: n,
        dx: dem.dx as f32,
        dy: dem.dy as f32,
    };
    g.bench_function(format!("tsa_{n}"), |b| {
        b.iter(|| tangent_sphere_accessibility(grid, p.tsa_window, p.tsa_max))
    });
    g.bench_function(format!("transfer_altitude_{n}"), |b| {
        b.iter(|| {
            let mut t = d.tsa.clone();
            transfer_grid(&mut t, p.probe_radius, p.b);
            apply_altitude(&mut t, &dem.heights, line, p.altitude_exponent);
            t
        })
    });
    g.bench_function(format!("smooth_t_{n}"), |b| {
        b.iter(|| smooth_diamond(&d.t, n, n, radius, t_passes))
    });
    let sun = Sun {
        azimuth_deg: az,
        spread_deg: p.sun_spread_deg,
        min_slope_deg: p.sun_min_slope_deg,
        strength: p.sun_strength,
    };
    g.bench_function(format!("sun_{n}"), |b| {
        b.iter(|| {
            let mut t = d.t.clone();
            apply_sun(&mut t, &d.smoothed, n, n, dem.dx as f32, dem.dy as f32, sun);
            t
        })
    });
    let color = albedo(&d.t, [110, 102, 92], [244, 247, 251]);
    g.bench_function(format!("colour_{n}"), |b| {
        b.iter(|| albedo(&d.t, [110, 102, 92], [244, 247, 251]))
    });
    g.bench_function(format!("render_1080p_{n}"), |b| {
        b.iter(|| render(&dem, &color, 1920, 1080))
    });
    let image = render(&dem, &color, 1920, 1080);
    g.bench_function("encode_png_1080p", |b| b.iter(|| encode_rgba(&image)));
    // The other outputs `run` writes in its "encode" stage (in parallel with the PNG).
    let snow: Vec<f32> = d.t.iter().map(|&t| 1.0 - t).collect();
    g.bench_function(format!("encode_snow_cover_tif_{n}"), |b| {
        b.iter(|| write_float32_geotiff(n, n, &snow, &dem.georef))
    });
    g.bench_function(format!("encode_glb_{n}"), |b| {
        b.iter(|| terrain_glb(&dem.heights, n, n, dem.dx, dem.dy, &color, 262_144))
    });
    g.bench_function(format!("descriptor_render_png_{n}"), |b| {
        b.iter(|| {
            let d = compute(&dem, &p, &NoControl, (0.0, 1.0)).expect("not canceled");
            let color = albedo(&d.t, [110, 102, 92], [244, 247, 251]);
            encode_rgba(&render(&dem, &color, 1920, 1080))
        })
    });
    // The 4096² target through `run` (descriptor, colour, the view's set-up, render, PNG) per
    // preset: what `phenomena render snow-terrain --set 'outputs=["render.png"]'` does after
    // decoding the DEM.
    g.measurement_time(Duration::from_secs(20));
    for preset in ["winter", "paper"] {
        let pp = preset_params(preset, 1920, 1080);
        g.bench_function(BenchmarkId::new("run_4096_1080p_image", preset), |b| {
            b.iter(|| run(&dem, &pp, &NoControl).expect("not canceled"))
        });
    }
    drop((d, color, image, dem, snow));

    // Scaling with the number of cells: the descriptor alone, and descriptor + colour + 1080p
    // render + PNG (the 4096² target's work; BENCHMARKS.md fits the exponent of t ∝ cells^b).
    let mut sizes = vec![1024, 2048, 4096];
    if std::env::var("SNOW_BENCH_8192").map_or(true, |v| v != "0") {
        sizes.push(8192);
    }
    for n in sizes {
        let dem = mirrored(&src, n, n);
        g.measurement_time(Duration::from_secs(if n >= 8192 { 20 } else { 5 }));
        g.bench_with_input(BenchmarkId::new("descriptor", n), &dem, |b, dem| {
            b.iter(|| compute(dem, &p, &NoControl, (0.0, 1.0)).expect("not canceled"))
        });
        g.bench_with_input(
            BenchmarkId::new("descriptor_render_png", n),
            &dem,
            |b, dem| {
                b.iter(|| {
                    let d = compute(dem, &p, &NoControl, (0.0, 1.0)).expect("not canceled");
                    let color = albedo(&d.t, [110, 102, 92], [244, 247, 251]);
                    encode_rgba(&render(dem, &color, 1920, 1080))
                })
            },
        );
    }
    g.finish();
}

/// The render scene of `dem` with per-cell `albedo`.
fn terrain_scene<'a>(dem: &'a Dem, albedo: &'a [[f32; 3]]) -> TerrainScene<'a> {
    TerrainScene {
        width: dem.width,
        height: dem.height,
        dx: dem.dx,
        dy: dem.dy,
        heights: &dem.heights,
        albedo,
    }
}

/// The terrain renderer alone, grey albedo, sun at azimuth 230°, 35° up, an orbit from the
/// south 30° up: the paper's case (400 × 200 cells) to 900 × 600 on the path `Auto` picks (the
/// rasteriser), forced through the ray caster, with one sample per pixel and unshaded; the two
/// paths at 0.25, 1 and 4 cells per pixel (the crossover of "Two paths"); the pyramid of 4096².
fn render_paths(c: &mut Criterion) {
    let src = tanzawa();
    let mut g = c.benchmark_group("terrain_render");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5));
    let light = Lighting {
        sun_dir: sun_direction(230.0, 35.0),
        ..Lighting::default()
    };
    let orbit = |scene: &TerrainScene| {
        let (c, r) = scene.bounding_sphere();
        Camera::orbit(c, 180.0, 30.0, Camera::auto_distance(r, 35.0) * 0.75, 35.0)
    };
    let paper = mirrored(&src, 400, 200);
    let grey = vec![[0.6f32; 3]; paper.heights.len()];
    let scene = terrain_scene(&paper, &grey);
    let accel = TerrainAccel::new(&scene);
    let cam = orbit(&scene);
    for (name, path, l) in [
        ("paper_900x600_auto", RenderPath::Auto, light),
        ("paper_900x600_raycast", RenderPath::RayCast, light),
        (
            "paper_900x600_auto_1spp",
            RenderPath::Auto,
            Lighting {
                samples: 1,
                ..light
            },
        ),
        (
            "paper_900x600_auto_unshaded",
            RenderPath::Auto,
            Lighting {
                shading: false,
                ..light
            },
        ),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                render_accel_on_path(&accel, &cam, &l, 900, 600, path, &NoControl, (0.0, 1.0))
                    .expect("not canceled")
            })
        });
    }
    for ratio in [0.25f64, 1.0, 4.0] {
        // cells ≈ ratio × 540,000 with the paper's 2:1 aspect.
        let nh = ((ratio * 540_000.0 / 2.0).sqrt()) as usize + 1;
        let dem = mirrored(&src, 2 * nh, nh);
        let grey = vec![[0.6f32; 3]; dem.heights.len()];
        let scene = terrain_scene(&dem, &grey);
        let accel = TerrainAccel::new(&scene);
        let cam = orbit(&scene);
        for path in [RenderPath::RayCast, RenderPath::Raster] {
            g.bench_with_input(
                BenchmarkId::new(format!("crossover_{path:?}"), ratio),
                &ratio,
                |b, _| {
                    b.iter(|| {
                        render_accel_on_path(
                            &accel,
                            &cam,
                            &light,
                            900,
                            600,
                            path,
                            &NoControl,
                            (0.0, 1.0),
                        )
                        .expect("not canceled")
                    })
                },
            );
        }
    }
    let big = mirrored(&src, 4096, 4096);
    let scene = terrain_scene(&big, &[]);
    g.bench_function("pyramid_4096", |b| {
        b.iter(|| TerrainAccel::new_geometry(&scene))
    });
    g.finish();
}

criterion_group!(benches, stages, render_paths);
criterion_main!(benches);
