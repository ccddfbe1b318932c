//! Criterion benches of the `dust` pipeline (SPEC §4), one per stage (STYLE habit 10).
//!
//! - `dust/fibers_1024_20000`: one 1024² fibre texture with 20,000 fibres (issue 6 target ≤ 50 ms),
//!   default fibre parameters (48 steps, 2 bends); the tileable noise field is built outside the
//!   timed loop, and timed on its own as `dust/noise_1024`.
//! - `dust/exposure_100k_64`: the dust amount D with the exposure term, 64 rays per vertex, on
//!   ≥ 100,000 vertices (issue 6 target ≤ 1 s): copies of the Stanford armadillo
//!   (`../shared/data/mesh/armadillo.stl`, Y-up) side by side on a grid until the vertex count
//!   reaches 100,000 (the copies shade each other as well as themselves). Includes the BVH build.
//! - `dust/render_100k_32_1080p`: the render of ≥ 100,000 triangles (two armadillos) with 32
//!   shells at 1920×1080 (issue 6 target ≤ 1.5 s), default view and textures (512²): the base
//!   setup (merge, shadow map, rasteriser), the shell overlay and the anti-aliased base render
//!   with the overlay — what `run` times as `shells` + `render`. D, the textures and the crease
//!   split are built outside the timed loop.
//!
//! Run: `cargo bench --bench dust`.
#![allow(clippy::unwrap_used, clippy::expect_used)] // benches may unwrap (STYLE habit 4)

use std::path::PathBuf;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use phenomena_engine::dust::amount::{dust_amount, AmountModel};
use phenomena_engine::dust::fibers::{fiber_texture, shell_fiber_count, FiberParams};
use phenomena_engine::dust::mapping::Mapping;
use phenomena_engine::dust::noise::TileableNoise;
use phenomena_engine::dust::render::{shell_overlay, Shells};
use phenomena_engine::dust::surface::{crease_split, refine};
use phenomena_engine::dust::texture::ShellTexture;
use phenomena_engine::dust::DustParams;
use phenomena_engine::formats::mesh::{decode_mesh, MeshOptions, UpAxis};
use phenomena_engine::geom::mesh::{Mesh, MeshPart};
use phenomena_engine::params::Limits;
use phenomena_engine::render::mesh::{MeshColors, MeshInstance, MeshLighting, MeshRenderer};
use phenomena_engine::NoControl;

/// Copies of the armadillo until there are at least `min_vertices` vertices and
/// `min_triangles` triangles.
fn armadillo_grid(min_vertices: usize, min_triangles: usize) -> Mesh {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mesh/armadillo.stl");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let opts = MeshOptions {
        up_axis: Some(UpAxis::Y),
        ..MeshOptions::default()
    };
    let one = decode_mesh(&bytes, Some("armadillo.stl"), &opts).unwrap();
    let (lo, hi) = one.bounds().unwrap();
    let step = [(hi[0] - lo[0]) * 1.1, (hi[2] - lo[2]) * 1.1];
    let copies = min_vertices
        .div_ceil(one.positions.len())
        .max(min_triangles.div_ceil(one.triangles.len()));
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
    m.parts = vec![MeshPart {
        name: "armadillos".into(),
        first_triangle: 0,
        triangle_count: m.triangles.len(),
        base_color: [0.5, 0.5, 0.5, 1.0],
        texture: None,
    }];
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

    let mesh = armadillo_grid(100_000, 0);
    eprintln!(
        "exposure mesh: {} vertices, {} triangles",
        mesh.positions.len(),
        mesh.triangles.len()
    );
    let model = AmountModel::default();
    g.bench_function("exposure_100k_64", |b| {
        b.iter(|| dust_amount(&mesh, &model))
    });

    // The render: ≥ 100,000 triangles, 32 shells, 1920×1080, the pipeline's defaults.
    let mesh = armadillo_grid(0, 100_000);
    let p = DustParams::from_json(
        &serde_json::json!({"width": 1920, "height": 1080, "shells": 32}),
        &Limits::default(),
    )
    .unwrap();
    let (mut m, mut normals) = crease_split(&mesh, p.dust_source);
    refine(&mut m, &mut normals);
    let amount = dust_amount(&m, &p.amount_model());
    let side = p.texture_size;
    let noise = TileableNoise::new(p.seed, p.noise_scale, p.noise_octaves).texture(side, side);
    let textures: Vec<ShellTexture> = (0..p.shells)
        .map(|k| {
            let n = shell_fiber_count(p.fibers, k, p.shells);
            ShellTexture::new(&fiber_texture(
                &p.fiber_params(),
                &noise,
                side,
                side,
                p.seed,
                k,
                n,
            ))
        })
        .collect();
    let (lo, hi) = m.bounds().unwrap();
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt();
    let tile = diag / 8.0;
    let mapping = Mapping::new(&m, tile);
    let sh = Shells {
        mesh: &m,
        normals: &normals,
        amount: &amount,
        thickness: 0.01 * diag,
        shells: p.shells,
        mapping: &mapping,
        texels_per_metre: side as f32 / tile,
        textures: &textures,
        noise: &noise,
        noise_side: side as usize,
        dust_color: p.dust_color_linear(),
    };
    let light = MeshLighting::for_view(&p.view, &m);
    let cam = p.view.camera_for(&m, 1920, 1080);
    eprintln!("render mesh: {} triangles", m.triangles.len());
    g.bench_function("render_100k_32_1080p", |b| {
        b.iter(|| {
            let base = MeshInstance {
                positions: &m.positions,
                normals: Some(&normals),
                triangles: &m.triangles,
                colors: MeshColors::PerPart(&m.parts),
            };
            let view =
                MeshRenderer::new(&[base], &cam, &light, 1920, 1080, sh.bounds(), &NoControl)
                    .unwrap();
            let overlay = shell_overlay(&view, &cam, &sh, &NoControl, (0.0, 1.0)).unwrap();
            view.render(Some(&overlay), &NoControl, (0.0, 1.0)).unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
