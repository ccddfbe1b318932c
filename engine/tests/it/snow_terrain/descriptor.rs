//! Surface descriptor (SPEC §1 steps 1–6) end to end: real DEMs, determinism, progress and
//! cancellation (the stages' timings are `benches/snow_terrain.rs`).
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may unwrap (STYLE habit 4)

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::geom::{Dem, GeoRef};
use phenomena_engine::snow_terrain::descriptor::{compute, Descriptor, DescriptorParams};
use phenomena_engine::snow_terrain::smooth::{diamond_len, diamond_offsets, smooth_diamond};
use phenomena_engine::{Canceled, Control, NoControl};

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/dem")
        .join(name)
}

fn load(name: &str) -> Dem {
    let path = data(name);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    decode_dem(&bytes, Some(name), &DemOptions::default()).expect("decodes")
}

fn synthetic(width: usize, height: usize, dx: f64, dy: f64, f: impl Fn(f64, f64) -> f64) -> Dem {
    let mut heights = Vec::with_capacity(width * height);
    for r in 0..height {
        for c in 0..width {
            heights.push(f(c as f64 * dx, r as f64 * dy) as f32);
        }
    }
    Dem {
        width,
        height,
        heights,
        dx,
        dy,
        georef: GeoRef::default(),
    }
}

fn run(dem: &Dem, p: &DescriptorParams) -> Descriptor {
    compute(dem, p, &NoControl, (0.0, 1.0)).expect("not canceled")
}

/// Mean of `t` over the cells selected by `keep`.
fn mean_where(t: &[f32], keep: impl Fn(usize) -> bool) -> f64 {
    let (mut s, mut n) = (0.0f64, 0usize);
    for (i, &v) in t.iter().enumerate() {
        if !v.is_nan() && keep(i) {
            s += f64::from(v);
            n += 1;
        }
    }
    assert!(n > 0, "empty selection");
    s / n as f64
}

fn check_range_and_holes(dem: &Dem, d: &Descriptor) {
    assert_eq!(d.t.len(), dem.heights.len());
    for (i, (&t, &h)) in d.t.iter().zip(&dem.heights).enumerate() {
        if h.is_nan() {
            assert!(
                t.is_nan() && d.tsa[i].is_nan() && d.smoothed[i].is_nan(),
                "cell {i}"
            );
        } else {
            assert!((0.0..=1.0).contains(&t), "cell {i}: t = {t}");
        }
    }
}

#[test]
fn diamond_has_4n_plus_2n_n_minus_1_points() {
    for n in 1..=5 {
        assert_eq!(diamond_len(n), 4 * n + 2 * n * (n - 1));
        let offsets: Vec<_> = diamond_offsets(n).collect();
        assert_eq!(offsets.len(), diamond_len(n));
        for &(di, dj) in &offsets {
            let l1 = di.unsigned_abs() + dj.unsigned_abs();
            assert!((1..=n).contains(&l1));
        }
    }
}

#[test]
fn smoother_keeps_a_constant_field_constant_around_holes_and_borders() {
    let (w, h) = (50, 31);
    let mut f = vec![812.25f32; w * h];
    for (i, v) in f.iter_mut().enumerate() {
        if i % 11 == 0 || (i / w > 10 && i / w < 14 && i % w > 20) {
            *v = f32::NAN;
        }
    }
    for n in 1..=5 {
        let g = smooth_diamond(&f, w, h, n, 5);
        for (a, b) in g.iter().zip(&f) {
            assert_eq!(a.is_nan(), b.is_nan());
            if !b.is_nan() {
                assert_eq!(*a, 812.25, "n = {n}");
            }
        }
    }
}

/// Hollows keep snow and ridges are swept: cells that smoothing raises (concave, paper §3.1 Fig. 1)
/// have a lower mean t than cells it lowers (convex).
#[test]
fn real_terrain_snow_in_hollows_rock_on_ridges() {
    for (name, p) in [
        ("maunga_whau_volcano.asc", DescriptorParams::paper()),
        (
            "tanzawa_sagami_aster_gdem2_f32.tif",
            DescriptorParams::paper(),
        ),
        (
            "colorado_front_range_srtmgl3_f32.tif",
            DescriptorParams::paper(),
        ),
    ] {
        let dem = load(name);
        // Without the sun and altitude terms, to test TSA + transfer alone.
        let flat = DescriptorParams {
            sun_spread_deg: 0.0,
            altitude_exponent: 1e-6,
            snowline: Some(-1e6),
            ..p.clone()
        };
        let d = run(&dem, &flat);
        check_range_and_holes(&dem, &d);
        let diff: Vec<f32> = d
            .smoothed
            .iter()
            .zip(&dem.heights)
            .map(|(s, h)| s - h)
            .collect();
        let mut sorted: Vec<f32> = diff.iter().copied().filter(|v| !v.is_nan()).collect();
        sorted.sort_by(f32::total_cmp);
        let q = |f: f64| sorted[((sorted.len() - 1) as f64 * f) as usize];
        let (lo, hi) = (q(0.2), q(0.8));
        let hollows = mean_where(&d.t, |i| diff[i] >= hi);
        let ridges = mean_where(&d.t, |i| diff[i] <= lo);
        assert!(
            hollows + 0.1 < ridges,
            "{name}: hollows {hollows:.3} ridges {ridges:.3}"
        );

        // The full descriptor stays in range too.
        let d = run(&dem, &p);
        check_range_and_holes(&dem, &d);
        // And the winter default.
        let d = run(&dem, &DescriptorParams::default());
        check_range_and_holes(&dem, &d);
    }
}

#[test]
fn more_snow_higher_up_on_real_terrain() {
    let dem = load("tanzawa_sagami_aster_gdem2_f32.tif");
    let d = run(&dem, &DescriptorParams::paper());
    let (min, max, _) = dem.stats().expect("valid cells");
    let band = |a: f32, b: f32| {
        mean_where(&d.t, |i| {
            let h = dem.heights[i];
            h >= min + a * (max - min) && h < min + b * (max - min)
        })
    };
    let low = band(0.0, 0.25);
    let mid = band(0.25, 0.5);
    let high = band(0.5, 1.01);
    assert!(
        high < mid && mid < low,
        "low {low:.3} mid {mid:.3} high {high:.3}"
    );
}

/// An east–west valley: its north flank faces south (sun) and melts, its south flank keeps snow.
#[test]
fn sunny_flank_is_barer_than_shady_flank() {
    // Parabolic valley along X, 20 m cells, floor at row 40; Z (rows) points south. Radius of
    // curvature 356 m at the floor, ~1.2 km half-way up: snow everywhere before the sun term.
    let dem = synthetic(64, 81, 20.0, 20.0, |_, z| {
        let u = (z - 800.0) / 800.0;
        1500.0 + 900.0 * u * u
    });
    let p = DescriptorParams::paper();
    let d = run(&dem, &p);
    let w = dem.width;
    let north_flank = mean_where(&d.t, |i| (8..32).contains(&(i / w)));
    let south_flank = mean_where(&d.t, |i| (49..73).contains(&(i / w)));
    assert!(
        north_flank > south_flank + 0.2,
        "north flank (faces south) {north_flank:.3}, south flank {south_flank:.3}"
    );
    // With the sun in the north (southern hemisphere) it is the other way round.
    let d = run(
        &dem,
        &DescriptorParams {
            sun_azimuth_deg: Some(0.0),
            ..p
        },
    );
    let north_flank = mean_where(&d.t, |i| (8..32).contains(&(i / w)));
    let south_flank = mean_where(&d.t, |i| (49..73).contains(&(i / w)));
    assert!(south_flank > north_flank + 0.2);
}

#[test]
fn nodata_holes_stay_holes() {
    let dem = load("luxembourg_elev.tif");
    assert!(dem.heights.iter().any(|h| h.is_nan()));
    let d = run(&dem, &DescriptorParams::paper());
    check_range_and_holes(&dem, &d);
    let d = run(&dem, &DescriptorParams::default());
    check_range_and_holes(&dem, &d);
}

#[test]
fn same_bytes_with_one_thread_and_the_default_pool() {
    let dem = load("tanzawa_sagami_aster_gdem2_f32.tif");
    let p = DescriptorParams {
        tsa_window: 2,
        ..DescriptorParams::default()
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let one = pool.install(|| run(&dem, &p));
    let many = run(&dem, &p);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&one.smoothed), bits(&many.smoothed));
    assert_eq!(bits(&one.tsa), bits(&many.tsa));
    assert_eq!(bits(&one.t), bits(&many.t));
    let again = run(&dem, &p);
    assert_eq!(bits(&again.t), bits(&many.t));
}

#[derive(Default)]
struct Recorder {
    seen: Mutex<Vec<(String, f32)>>,
    cancel_at: Option<&'static str>,
    canceled: AtomicBool,
}

impl Control for Recorder {
    fn progress(&self, stage: &str, fraction: f32) {
        if self.cancel_at == Some(stage) {
            self.canceled.store(true, Ordering::SeqCst);
        }
        self.seen
            .lock()
            .expect("lock")
            .push((stage.to_string(), fraction));
    }
    fn is_canceled(&self) -> bool {
        self.canceled.load(Ordering::SeqCst)
    }
}

#[test]
fn progress_is_monotone_within_the_given_range_and_names_the_stages() {
    let dem = load("maunga_whau_volcano.asc");
    let rec = Recorder::default();
    let d = compute(&dem, &DescriptorParams::default(), &rec, (0.2, 0.6)).expect("runs");
    let seen = rec.seen.lock().expect("lock").clone();
    let mut last = 0.2f32;
    for (_, f) in &seen {
        assert!(*f >= last - 1e-6 && *f <= 0.6 + 1e-6, "{seen:?}");
        last = *f;
    }
    assert!((last - 0.6).abs() < 1e-5);
    let mut names: Vec<&str> = seen.iter().map(|(s, _)| s.as_str()).collect();
    names.dedup();
    assert_eq!(
        names,
        ["smooth", "tsa", "transfer", "altitude", "smooth_t", "sun", "slope"]
    );
    let stages: Vec<&str> = d.timings.iter().map(|t| t.0).collect();
    assert_eq!(
        stages,
        ["smooth", "tsa", "transfer", "altitude", "smooth_t", "sun", "slope"]
    );
}

#[test]
fn cancellation_stops_the_computation() {
    let dem = load("maunga_whau_volcano.asc");
    for stage in ["smooth", "tsa", "sun"] {
        let rec = Recorder {
            cancel_at: Some(stage),
            ..Recorder::default()
        };
        let r = compute(&dem, &DescriptorParams::default(), &rec, (0.0, 1.0));
        assert_eq!(r.err(), Some(Canceled), "{stage}");
    }
}

/// Writes t as 8-bit greyscale (white = snow) to `$DESCRIPTOR_PREVIEW_DIR` (default: the system
/// temporary directory) for looking at: `cargo test -p phenomena-engine -- --ignored
/// --nocapture descriptor_previews`.
#[test]
#[ignore = "writes preview images; run by hand"]
fn descriptor_previews() {
    let dir = std::env::var_os("DESCRIPTOR_PREVIEW_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(std::env::temp_dir);
    for name in [
        "maunga_whau_volcano.asc",
        "tanzawa_sagami_aster_gdem2_f32.tif",
        "colorado_front_range_srtmgl3_f32.tif",
        "jacksboro_fault_dem_f32.tif",
    ] {
        let dem = load(name);
        let stem = name.split('.').next().unwrap_or(name);
        // TSA and transfer only (no altitude, no sun), for calibrating the probe.
        let base = DescriptorParams {
            probe_radius: env_f32("PROBE").unwrap_or(DescriptorParams::default().probe_radius),
            smooth_radius: env_f32("SMOOTH_N").map(|v| v as usize),
            tsa_window: env_f32("TSA_WINDOW").map_or(1, |v| v as usize),
            ..DescriptorParams::default()
        };
        let probe_only = DescriptorParams {
            sun_spread_deg: 0.0,
            altitude_exponent: 1e-6,
            snowline: Some(-1e6),
            ..base.clone()
        };
        let d = run(&dem, &probe_only);
        write_gray(
            &dir.join(format!("descriptor_probe_{stem}.png")),
            dem.width,
            dem.height,
            &to_snow(&d.t),
        );
        let d = run(&dem, &base);
        let snow = to_snow(&d.t);
        let path = dir.join(format!("descriptor_{stem}.png"));
        write_gray(&path, dem.width, dem.height, &snow);
        let mut tsa: Vec<f32> = d.tsa.iter().copied().filter(|v| !v.is_nan()).collect();
        tsa.sort_by(f32::total_cmp);
        let q: Vec<String> = [0.01, 0.05, 0.1, 0.25, 0.5, 0.75]
            .iter()
            .map(|f| format!("{f}: {:.0}", tsa[((tsa.len() - 1) as f64 * f) as usize]))
            .collect();
        println!("{name}: TSA quantiles (m) {}", q.join(", "));
        let covered = d.t.iter().filter(|t| **t < 0.5).count() as f64 / dem.valid_cells() as f64;
        println!(
            "{name}: {}x{} dx {:.1} dy {:.1} -> {} (snow-covered {:.0} %) {:?}",
            dem.width,
            dem.height,
            dem.dx,
            dem.dy,
            path.display(),
            covered * 100.0,
            d.timings
        );
    }
}

fn env_f32(name: &str) -> Option<f32> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

fn to_snow(t: &[f32]) -> Vec<u8> {
    t.iter()
        .map(|&t| {
            if t.is_nan() {
                0
            } else {
                ((1.0 - t) * 255.0).round() as u8
            }
        })
        .collect()
}

fn write_gray(path: &std::path::Path, w: usize, h: usize, pixels: &[u8]) {
    let file = std::fs::File::create(path).expect("create");
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w as u32, h as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    enc.write_header()
        .expect("header")
        .write_image_data(pixels)
        .expect("data");
}
