//! The whole `snow-terrain` pipeline on real DEMs: reference images, determinism across thread
//! counts, nodata, sweeps and cancellation.

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::params::Limits;
use phenomena_engine::render::image::RgbaImage;
use phenomena_engine::snow_terrain::{run, SnowTerrainParams};
use phenomena_engine::{Canceled, Control, NoControl, Output};
use serde_json::json;

use crate::support::golden::assert_golden;

fn dem(name: &str) -> phenomena_engine::geom::Dem {
    let path = format!(
        "{}/../../shared/data/dem/{name}",
        env!("CARGO_MANIFEST_DIR")
    );
    decode_dem(
        &std::fs::read(path).unwrap(),
        Some(name),
        &DemOptions::default(),
    )
    .unwrap()
}

fn params(v: serde_json::Value) -> SnowTerrainParams {
    SnowTerrainParams::from_json(&v, &Limits::default()).unwrap()
}

fn output<'a>(outs: &'a [Output], name: &str) -> &'a [u8] {
    &outs.iter().find(|o| o.name == name).unwrap().bytes
}

fn decode_rgba(bytes: &[u8]) -> RgbaImage {
    let mut dec = png::Decoder::new(std::io::Cursor::new(bytes));
    dec.set_transformations(png::Transformations::EXPAND);
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size()];
    let info = r.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    RgbaImage {
        width: info.width,
        height: info.height,
        data: buf,
    }
}

/// Golden cases of the paper's look (`"preset": "paper"`, the defaults before issue 17; the
/// images are unchanged): per-channel tolerance 3/255 on at least 99.5 % of pixels (silhouette pixels may
/// flip between CPUs).
#[test]
fn golden_renders() {
    let cases = [
        (
            "volcano_default",
            "maunga_whau_volcano.asc",
            json!({"preset": "paper", "width": 300, "height": 200}),
        ),
        (
            "luxembourg_nodata",
            "luxembourg_elev.tif",
            json!({"preset": "paper", "width": 300, "height": 200, "camera": {"azimuth_deg": 180, "elevation_deg": 50}}),
        ),
        (
            "jacksboro_flat_paper_style",
            "jacksboro_fault_dem_f32.tif",
            json!({"preset": "paper", "width": 300, "height": 200, "shading": false, "vertical_exaggeration": 3, "probe_radius": 8000}),
        ),
    ];
    for (case, file, p) in cases {
        let outs = run(&dem(file), &params(p), &NoControl).unwrap();
        assert_golden(
            "snow-terrain",
            case,
            &decode_rgba(output(&outs, "render.png")),
            3,
            0.005,
        );
    }
}

#[test]
fn same_bytes_on_one_thread_and_two() {
    let d = dem("jacksboro_fault_dem_f32.tif");
    let p = params(json!({"width": 200, "height": 120}));
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| run(&d, &p, &NoControl).unwrap());
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| run(&d, &p, &NoControl).unwrap());
    for (a, b) in one.iter().zip(&two) {
        assert_eq!(a.name, b.name);
        if a.name != "report.json" {
            assert!(
                a.bytes == b.bytes,
                "{} differs between thread counts",
                a.name
            );
        }
    }
}

#[test]
fn nodata_is_transparent_in_the_render_and_descriptor() {
    let d = dem("luxembourg_elev.tif");
    let outs = run(&d, &params(json!({"width": 200, "height": 200, "camera": {"azimuth_deg": 180, "elevation_deg": 89}})), &NoControl).unwrap();
    let img = decode_rgba(output(&outs, "render.png"));
    let transparent = img.data.chunks(4).filter(|p| p[3] == 0).count();
    assert!(
        transparent > 100,
        "holes seen from above are transparent ({transparent} px)"
    );
    let desc = decode_rgba(output(&outs, "descriptor.png"));
    assert_eq!(
        (desc.width as usize, desc.height as usize),
        (d.width, d.height)
    );
    let holes = desc.data.chunks(4).filter(|p| p[3] == 0).count();
    assert_eq!(holes, 3942, "every nodata cell and only those");
}

#[test]
fn sweep_adds_a_contact_sheet() {
    let d = dem("maunga_whau_volcano.asc");
    let p = params(
        json!({"width": 240, "height": 160, "sweep": {"param": "probe_radius", "values": [200, 800, 3200]}}),
    );
    assert_eq!(p.sweep_runs.len(), 3);
    assert_eq!(p.sweep_runs[1].descriptor.probe_radius, 800.0);
    let outs = run(&d, &p, &NoControl).unwrap();
    let sheet = decode_rgba(output(&outs, "sweep.png"));
    // Three 160-wide tiles in one row with 12 px gaps.
    assert_eq!(sheet.width, 3 * (160 + 12) + 12);
    // More probe radius, more snow (SPEC §1 step 3): compare the descriptors of the runs.
    let snow = |r: f32| {
        let outs = run(
            &d,
            &params(json!({"width": 32, "height": 32, "probe_radius": r})),
            &NoControl,
        )
        .unwrap();
        let rep: serde_json::Value = serde_json::from_slice(output(&outs, "report.json")).unwrap();
        rep["mean_snow"].as_f64().unwrap()
    };
    let (a, b, c) = (snow(200.0), snow(800.0), snow(3200.0));
    assert!(a < b && b < c, "{a} {b} {c}");
}

#[test]
fn bad_sweeps_and_params_name_the_field() {
    let l = Limits::default();
    for (v, field) in [
        (
            json!({"sweep": {"param": "width", "values": [1, 2]}}),
            "sweep.param",
        ),
        (
            json!({"sweep": {"param": "b", "values": [0.5]}}),
            "sweep.values",
        ),
        (
            json!({"sweep": {"param": "b", "values": [0.5, 2.0]}}),
            "sweep.values[1]",
        ),
        (json!({"camera": {"eye": [0, 0, 0]}}), "camera.target"),
        (json!({"camera": {"fov_deg": 0}}), "camera.fov_deg"),
        (json!({"camera": {"fovdeg": 30}}), "camera.fovdeg"),
        (json!({"rock_color": "red"}), "rock_color"),
        (json!({"width": 8000, "height": 8000}), "width"),
        (json!({"probe_radius": null, "b": 1.5}), "b"),
        (json!({"outputs": ["render.png", "mesh.obj"]}), "outputs[1]"),
        (
            json!({"outputs": ["terrain.glb", "terrain.glb"]}),
            "outputs[1]",
        ),
        (json!({"outputs": "render.png"}), "outputs"),
    ] {
        let e = SnowTerrainParams::from_json(&v, &l).unwrap_err();
        assert_eq!(e.field, field, "{v}: {e}");
    }
}

/// `outputs` picks files, and a file is the same bytes whether or not the others were made.
#[test]
fn outputs_choose_the_files_and_leave_them_unchanged() {
    let d = dem("maunga_whau_volcano.asc");
    let base = json!({"width": 120, "height": 80, "samples": 2});
    let all = run(&d, &params(base.clone()), &NoControl).unwrap();
    let names = |outs: &[Output]| outs.iter().map(|o| o.name.clone()).collect::<Vec<_>>();
    assert_eq!(
        names(&all),
        [
            "render.png",
            "snow_cover.tif",
            "descriptor.png",
            "terrain.glb",
            "report.json"
        ]
    );
    let stages = |outs: &[Output]| -> Vec<String> {
        let r: serde_json::Value = serde_json::from_slice(output(outs, "report.json")).unwrap();
        r["timings"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["stage"].as_str().unwrap().to_string())
            .collect()
    };
    for (want, expect) in [
        (json!(["render.png"]), vec!["render.png", "report.json"]),
        (
            json!(["snow_cover.tif"]),
            vec!["snow_cover.tif", "report.json"],
        ),
        (
            json!(["terrain.glb", "descriptor.png"]),
            vec!["descriptor.png", "terrain.glb", "report.json"],
        ),
        (json!([]), vec!["report.json"]),
    ] {
        let mut v = base.clone();
        v["outputs"] = want.clone();
        let outs = run(&d, &params(v), &NoControl).unwrap();
        assert_eq!(names(&outs), expect, "{want}");
        for o in &outs[..outs.len() - 1] {
            assert!(
                o.bytes == output(&all, &o.name),
                "{} differs when made alone",
                o.name
            );
        }
        // No render without render.png.
        assert_eq!(
            stages(&outs).contains(&"render".to_string()),
            want.as_array().unwrap().contains(&json!("render.png")),
            "{want}"
        );
    }
}

struct CancelAfter(std::sync::atomic::AtomicUsize);
impl Control for CancelAfter {
    fn progress(&self, _: &str, _: f32) {}
    fn is_canceled(&self) -> bool {
        self.0.fetch_add(1, std::sync::atomic::Ordering::Relaxed) > 3
    }
}

#[test]
fn cancellation_stops_the_pipeline() {
    let d = dem("tanzawa_sagami_aster_gdem2.tif");
    let r = run(&d, &params(json!({})), &CancelAfter(0.into()));
    assert!(matches!(r, Err(Canceled)));
}

/// `w × h` window of `src` tiled by mirroring (as `benches/snow_terrain.rs` builds its inputs).
fn mirrored(src: &phenomena_engine::geom::Dem, w: usize, h: usize) -> phenomena_engine::geom::Dem {
    let fold = |i: usize, n: usize| {
        let p = i % (2 * n);
        if p < n {
            p
        } else {
            2 * n - 1 - p
        }
    };
    let mut heights = Vec::with_capacity(w * h);
    for r in 0..h {
        for c in 0..w {
            heights.push(src.heights[fold(r, src.height) * src.width + fold(c, src.width)]);
        }
    }
    phenomena_engine::geom::Dem {
        width: w,
        height: h,
        heights,
        dx: src.dx,
        dy: src.dy,
        georef: Default::default(),
    }
}

/// CPU time of this process (all threads), ms, from /proc (10 ms ticks).
fn cpu_ms() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks: f64 = f.get(11).and_then(|v| v.parse().ok()).unwrap_or(0.0)
        + f.get(12).and_then(|v| v.parse().ok()).unwrap_or(0.0);
    ticks * 10.0
}

/// The 4096² target's work on `dem`: descriptor (default parameters), colour, 1920×1080 render
/// (the bench's camera and sun) and PNG. Returns the PNG and the wall-clock ms at the end of
/// each of the four stages (cumulative).
fn descriptor_render_png(dem: &phenomena_engine::geom::Dem) -> (Vec<u8>, [f64; 4]) {
    use phenomena_engine::formats::png_write::encode_rgba;
    use phenomena_engine::snow_terrain::color::albedo;
    use phenomena_engine::snow_terrain::descriptor::{compute, DescriptorParams};
    use phenomena_engine::snow_terrain::overview_render;
    let t = std::time::Instant::now();
    let ms = || t.elapsed().as_secs_f64() * 1e3;
    let d = compute(dem, &DescriptorParams::default(), &NoControl, (0.0, 1.0)).unwrap();
    let t1 = ms();
    let color = albedo(&d.t, [110, 102, 92], [244, 247, 251]);
    let t2 = ms();
    let img = overview_render(dem, &color, 1920, 1080).unwrap();
    let t3 = ms();
    let png = encode_rgba(&img);
    (png, [t1, t2, t3, ms()])
}

/// Peak resident set of this process so far (`VmHWM`), MiB.
fn peak_rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// Least-squares slope of `ln y` on `ln x`: the exponent `b` of `y ∝ x^b`.
fn loglog_slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let (lx, ly): (Vec<f64>, Vec<f64>) = points.iter().map(|&(x, y)| (x.ln(), y.ln())).unzip();
    let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
    let sxy: f64 = lx.iter().zip(&ly).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = lx.iter().map(|x| (x - mx) * (x - mx)).sum();
    sxy / sxx
}

/// The scaling target ("cost per cell roughly constant from 1024² to 8192²"):
/// `cargo test --release -p phenomena-engine --test it -- --ignored --nocapture snow_terrain::run::scaling`.
/// For N = 1024, 2048, 4096, 8192 (`SNOW_SCALING_SIZES=1024,2048` to choose) on mirrored
/// Tanzawa (as the 4096² case): the descriptor alone, and the descriptor with colour, the
/// 1920×1080 render and the PNG ([`descriptor_render_png`]); the median of `SNOW_SCALING_REPS` runs (default 3, one
/// warm-up first) in wall and process-CPU time, ns per cell, the peak RSS so far (sizes run in
/// increasing order, so it is the peak of the largest size run), and the least-squares exponent
/// b of t ∝ cells^b over the sizes run.
#[test]
#[ignore]
fn scaling() {
    let src = dem("tanzawa_sagami_aster_gdem2.tif");
    let sizes: Vec<usize> = std::env::var("SNOW_SCALING_SIZES")
        .ok()
        .map(|v| v.split(',').filter_map(|s| s.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![1024, 2048, 4096, 8192]);
    let reps: usize = std::env::var("SNOW_SCALING_REPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3)
        .max(1);
    println!(
        "rayon threads: {}, reps {reps}",
        rayon::current_num_threads()
    );
    let median = |mut v: Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    // Per size: cells, descriptor (wall, cpu), all (wall, cpu), ms.
    let mut rows: Vec<(f64, [f64; 4])> = Vec::new();
    for &n in &sizes {
        let dem_n = mirrored(&src, n, n);
        let cells = (n * n) as f64;
        let (mut dw, mut dc, mut aw, mut ac) = (vec![], vec![], vec![], vec![]);
        for i in 0..=reps {
            let c0 = cpu_ms();
            let (_, s) = descriptor_render_png(&dem_n);
            let cpu_all = cpu_ms() - c0;
            let c0 = cpu_ms();
            let t = std::time::Instant::now();
            let d = phenomena_engine::snow_terrain::descriptor::compute(
                &dem_n,
                &Default::default(),
                &NoControl,
                (0.0, 1.0),
            )
            .unwrap();
            let desc_wall = t.elapsed().as_secs_f64() * 1e3;
            let cpu_desc = cpu_ms() - c0;
            assert_eq!(d.t.len(), n * n);
            drop(d);
            if i == 0 {
                continue; // warm-up
            }
            dw.push(desc_wall);
            dc.push(cpu_desc);
            aw.push(s[3]);
            ac.push(cpu_all);
        }
        let m = [median(dw), median(dc), median(aw), median(ac)];
        println!(
            "{n}^2 ({cells:.0} cells): descriptor {:.0} ms wall ({:.1} ns/cell), {:.0} ms cpu; \
             descriptor+render+png {:.0} ms wall ({:.1} ns/cell), {:.0} ms cpu; peak RSS {:.0} MiB; \
             load {}",
            m[0],
            m[0] * 1e6 / cells,
            m[1],
            m[2],
            m[2] * 1e6 / cells,
            m[3],
            peak_rss_mib(),
            std::fs::read_to_string("/proc/loadavg").unwrap_or_default().trim()
        );
        rows.push((cells, m));
    }
    if rows.len() >= 2 {
        let fit = |k: usize| loglog_slope(&rows.iter().map(|r| (r.0, r.1[k])).collect::<Vec<_>>());
        println!(
            "exponent b (t ∝ cells^b): descriptor {:.3} wall, {:.3} cpu; \
             descriptor+render+png {:.3} wall, {:.3} cpu",
            fit(0),
            fit(1),
            fit(2),
            fit(3)
        );
        // The fit itself: exact on a synthetic power law.
        let synth: Vec<(f64, f64)> = rows.iter().map(|r| (r.0, 3.0 * r.0.powf(0.9))).collect();
        assert!((loglog_slope(&synth) - 0.9).abs() < 1e-9);
    }
}

/// The two speed targets, in process (release):
/// `cargo test --release -p phenomena-engine --test it -- --ignored --nocapture snow_terrain::run::timings`.
/// Paper case: `run` (descriptor, colour, render, every default output) on Tanzawa cropped to
/// 400×200 at 900×600; 4096²: descriptor + colour + 1920×1080 render + PNG as the bench's
/// `descriptor_render_png_4096` (`SNOW_TIMINGS_4096=0` skips it). Prints the median wall time,
/// the mean process CPU per run and the median of each report stage. `SNOW_TIMINGS_FULL=0` times
/// the image-only case alone, `SNOW_TIMINGS_PNG=path` writes its `render.png` there.
#[test]
#[ignore]
fn timings() {
    use std::time::Instant;
    let src = dem("tanzawa_sagami_aster_gdem2.tif");
    println!("rayon threads: {}", rayon::current_num_threads());
    let paper = mirrored(&src, 400, 200);
    let p = params(json!({"width": 900, "height": 600}));
    run(&paper, &p, &NoControl).unwrap();
    // SNOW_TIMINGS_REPS: fewer runs under callgrind (default 30).
    let reps: u32 = std::env::var("SNOW_TIMINGS_REPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(30)
        .max(1);
    let mut walls = Vec::new();
    let mut stages: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    // SNOW_TIMINGS_FULL=0: the image-only case alone (A/B runs of the render).
    let full_reps = if std::env::var("SNOW_TIMINGS_FULL").is_ok_and(|v| v == "0") {
        0
    } else {
        reps
    };
    let c0 = cpu_ms();
    for _ in 0..full_reps {
        let t = Instant::now();
        let outs = run(&paper, &p, &NoControl).unwrap();
        walls.push(t.elapsed().as_secs_f64() * 1e3);
        let r: serde_json::Value = serde_json::from_slice(output(&outs, "report.json")).unwrap();
        for s in r["timings"].as_array().unwrap() {
            let name = s["stage"].as_str().unwrap().to_string();
            stages
                .entry(name)
                .or_default()
                .push(s["ms"].as_f64().unwrap());
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    if full_reps > 0 {
        let cpu = (cpu_ms() - c0) / f64::from(full_reps);
        println!(
            "paper 400x200 -> 900x600, run(): median {:.1} ms wall, min {:.1}, {cpu:.1} ms cpu/run",
            median(&mut walls),
            walls[0]
        );
    }
    for (name, v) in &mut stages {
        println!("  {name:<10} {:7.2} ms (median)", median(v));
    }
    // The same DEM to the 900×600 image alone (`outputs: ["render.png"]`: descriptor, colour,
    // render, PNG; what a preview asks for, and the paper's measurement).
    let p_img = params(json!({"width": 900, "height": 600, "outputs": ["render.png"]}));
    let mut walls = Vec::new();
    let c0 = cpu_ms();
    for _ in 0..reps {
        let t = Instant::now();
        let outs = run(&paper, &p_img, &NoControl).unwrap();
        walls.push(t.elapsed().as_secs_f64() * 1e3);
        assert_eq!(outs.len(), 2);
        // SNOW_TIMINGS_PNG=path: keep the picture (byte-for-byte A/B of render changes).
        if let Some(path) = std::env::var_os("SNOW_TIMINGS_PNG") {
            std::fs::write(path, output(&outs, "render.png")).unwrap();
        }
    }
    let cpu = (cpu_ms() - c0) / f64::from(reps);
    println!(
        "paper 400x200 -> 900x600 image only (outputs: [render.png]): median {:.1} ms wall, {cpu:.1} ms cpu/run",
        median(&mut walls)
    );
    if std::env::var("SNOW_TIMINGS_4096").is_ok_and(|v| v == "0") {
        return;
    }
    let big = mirrored(&src, 4096, 4096);
    let mut walls = Vec::new();
    let c0 = cpu_ms();
    let reps = 5;
    for i in 0..=reps {
        let (png, s) = descriptor_render_png(&big);
        if i == 0 {
            std::fs::write(
                std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("tanzawa_4096_1080p.png"),
                &png,
            )
            .unwrap();
            continue; // warm-up run, not counted
        }
        walls.push(s[3]);
        println!(
            "4096^2: descriptor {:.0}, colour {:.0}, render {:.0}, png {:.0}, total {:.0} ms",
            s[0],
            s[1] - s[0],
            s[2] - s[1],
            s[3] - s[2],
            s[3]
        );
    }
    let cpu = (cpu_ms() - c0) / f64::from(reps + 1);
    println!(
        "4096^2 descriptor + 1920x1080 render + png: median {:.0} ms wall, {cpu:.0} ms cpu/run",
        median(&mut walls)
    );
}

/// `render.png` is streamed while the render draws (`RgbaPngStream`): its bytes must be those of
/// `encode_rgba` on the finished image, on the raster path (fewer cells than pixels, with and
/// without holes) and on the ray caster (more cells than pixels).
#[test]
fn streamed_render_png_is_encode_rgba_of_the_image() {
    use phenomena_engine::formats::png_write::encode_rgba;
    for (name, w, h) in [
        ("maunga_whau_volcano.asc", 240, 160),
        ("maunga_whau_volcano.asc", 60, 40),
        ("luxembourg_elev.tif", 320, 200),
    ] {
        let d = dem(name);
        let p = params(json!({"width": w, "height": h, "outputs": ["render.png"]}));
        let outs = run(&d, &p, &NoControl).unwrap();
        let png = output(&outs, "render.png");
        let img = decode_rgba(png);
        assert_eq!((img.width, img.height), (w, h));
        assert!(encode_rgba(&img) == png, "{name} {w}×{h}");
    }
}
