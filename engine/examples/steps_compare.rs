//! How much the snow cover model's step count changes its result (BENCHMARKS.md, "Snow cover,
//! session 21"): `steps_compare MESH [STEPS…]` runs `snow_cover::simulate` with the pipeline's
//! defaults for each step count (default list 48 24 16 12 8 6) and compares each final snow depth
//! with the first one's, cell by cell over every layer: resting and lost snow, the mean absolute
//! depth difference over the cells that hold snow in either run (also as a share of their mean
//! depth), the 99th percentile of the difference, the share of those cells whose depth differs by
//! more than 5 mm or 20 %, the repose residual, the snowfall stage's time, and each step's
//! stabilization iterations.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::print_stdout)]

use std::time::Instant;

use phenomena_engine::formats::mesh::decode_upright;
use phenomena_engine::params::Limits;
use phenomena_engine::snow_cover::{simulate, SnowCoverParams, SNOW_UNIT_M};
use phenomena_engine::NoControl;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).expect("usage: steps_compare MESH [STEPS…]");
    let mut list: Vec<usize> = args[2..].iter().map(|s| s.parse().unwrap()).collect();
    if list.is_empty() {
        list = vec![48, 24, 16, 12, 8, 6];
    }
    let bytes = std::fs::read(path).unwrap();
    // Upright as the pipeline decodes it (session 21's driver decoded with the reader's default
    // axis: `wuson.ply` lay on its side there).
    let mesh = decode_upright(&bytes, Some(path), &[], None, &Limits::default()).expect("decodes");
    let height = mesh
        .bounds()
        .map_or(0.0, |(lo, hi)| f64::from(hi[1] - lo[1]));
    let mut reference: Option<Vec<Vec<u32>>> = None;
    println!(
        "steps | resting m³ | lost m³ | mean |Δd| mm | share of mean d | p99 |Δd| mm | cells off > max(5 mm, 20 %) | residual tan | snowfall ms"
    );
    for &steps in &list {
        let p =
            SnowCoverParams::from_json(&serde_json::json!({ "steps": steps }), &Limits::default())
                .expect("valid params");
        let model = p.model(height);
        let t0 = Instant::now();
        let (maps, rep) = simulate(&mesh, &model, &NoControl, |_, _| {}).expect("runs");
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let snowfall_ms = rep
            .timings
            .iter()
            .find(|t| t.0 == "snowfall")
            .map_or(ms, |t| t.1);
        let snow: Vec<Vec<u32>> = maps.layers.iter().map(|l| l.snow.clone()).collect();
        let reference = reference.get_or_insert_with(|| snow.clone());
        let (mut n, mut sum_d, mut sum_ref, mut off) = (0usize, 0.0f64, 0.0f64, 0usize);
        let mut diffs = Vec::new();
        for (a, b) in snow.iter().zip(reference.iter()) {
            for (&x, &y) in a.iter().zip(b.iter()) {
                if x == 0 && y == 0 {
                    continue;
                }
                let (dx, dy) = (f64::from(x) * SNOW_UNIT_M, f64::from(y) * SNOW_UNIT_M);
                let d = (dx - dy).abs();
                n += 1;
                sum_d += d;
                sum_ref += dy.max(dx);
                if d > 0.005f64.max(0.2 * dy.max(dx)) {
                    off += 1;
                }
                diffs.push(d);
            }
        }
        diffs.sort_unstable_by(f64::total_cmp);
        let p99 = diffs.get(diffs.len() * 99 / 100).copied().unwrap_or(0.0);
        let b = &rep.balance;
        println!(
            "{steps} | {:.6} | {:.6} | {:.3} | {:.1} % | {:.3} | {:.2} % | {:.4} | {snowfall_ms:.0}",
            b.resting_m3.iter().sum::<f64>(),
            b.lost_m3,
            1e3 * sum_d / n.max(1) as f64,
            100.0 * sum_d / sum_ref.max(1e-12),
            1e3 * p99,
            100.0 * off as f64 / n.max(1) as f64,
            rep.residual_tan,
        );
        println!("  iterations per step: {:?}", rep.step_iterations);
    }
}
