//! Renderer tests: camera geometry, the ray caster against analytic surfaces and a brute-force
//! reference, shading, alpha for holes, determinism, the contact sheet, PNG and GLB writers.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may unwrap (STYLE habit 4)

use phenomena_engine::formats::{glb, png_write};
use phenomena_engine::geom::camera::Camera;
use phenomena_engine::geom::sun_direction;
use phenomena_engine::render::{
    contact_sheet, render_terrain, Lighting, RgbaImage, TerrainAccel, TerrainScene,
};
use phenomena_engine::NoControl;

/// Tiny ESRI ASCII grid reader for test data (nodata → NaN).
pub(crate) fn load_asc(path: &str) -> (usize, usize, f64, Vec<f32>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let (mut w, mut h, mut cell, mut nodata) = (0usize, 0usize, 1.0f64, f32::NAN);
    let mut values = Vec::new();
    for line in lines.by_ref() {
        let mut it = line.split_whitespace();
        let key = it.next().unwrap_or("").to_ascii_lowercase();
        let val = it.next().unwrap_or("");
        match key.as_str() {
            "ncols" => w = val.parse().unwrap(),
            "nrows" => h = val.parse().unwrap(),
            "cellsize" => cell = val.parse().unwrap(),
            "nodata_value" => nodata = val.parse().unwrap(),
            "xllcorner" | "yllcorner" | "xllcenter" | "yllcenter" => {}
            _ => {
                values.extend(line.split_whitespace().map(|v| v.parse::<f32>().unwrap()));
                break;
            }
        }
    }
    for line in lines {
        values.extend(line.split_whitespace().map(|v| v.parse::<f32>().unwrap()));
    }
    assert_eq!(values.len(), w * h);
    for v in &mut values {
        if *v == nodata {
            *v = f32::NAN;
        }
    }
    (w, h, cell, values)
}

/// Deterministic pseudo-random numbers in [0, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn flat_lighting() -> Lighting {
    Lighting {
        haze: 0.0,
        samples: 1,
        shadows: false,
        ..Lighting::default()
    }
}

#[test]
fn orbit_azimuth_180_is_south_of_centre() {
    let c = [5.0, 100.0, -7.0];
    let cam = Camera::orbit(c, 180.0, 25.0, 1000.0, 40.0);
    assert!(cam.eye[2] > c[2]);
    assert!(cam.eye[0].abs() - c[0].abs() < 1e-6);
    assert!(cam.eye[1] > c[1]);
    let d =
        ((cam.eye[0] - c[0]).powi(2) + (cam.eye[1] - c[1]).powi(2) + (cam.eye[2] - c[2]).powi(2))
            .sqrt();
    assert!((d - 1000.0).abs() < 1e-6);
    // A sphere of radius r at auto distance fits: r / d = sin(fov/2) / 1.05.
    let dist = Camera::auto_distance(100.0, 40.0);
    assert!((100.0 / dist - 20f64.to_radians().sin() / 1.05).abs() < 1e-12);
}

#[test]
fn flat_plane_lit_from_above_is_uniform_lambert() {
    let (w, h) = (33, 21);
    let heights = vec![50.0f32; w * h];
    let albedo_c = [0.5f32, 0.4, 0.3];
    let albedo = vec![albedo_c; w * h];
    let scene = TerrainScene {
        width: w,
        height: h,
        dx: 10.0,
        dy: 10.0,
        heights: &heights,
        albedo: &albedo,
    };
    let light = Lighting {
        sun_dir: [0.0, 1.0, 0.0],
        sun_color: [0.6, 0.6, 0.6],
        ambient: 0.3,
        shadows: true,
        ..flat_lighting()
    };
    // Straight down at the middle: the whole image sees the plane.
    let cam = Camera {
        eye: [0.0, 200.0, 0.0],
        target: [0.0, 50.0, 0.0],
        up: [0.0, 0.0, -1.0],
        fov_deg: 30.0,
    };
    let img = render_terrain(&scene, &cam, &light, 64, 48, &NoControl, (0.0, 1.0)).unwrap();
    for y in 0..48 {
        for x in 0..64 {
            let p = img.pixel(x, y);
            assert_eq!(p[3], 255);
            for c in 0..3 {
                let want =
                    phenomena_engine::render::image::linear_to_srgb(albedo_c[c] * 0.9) * 255.0;
                assert!(
                    (f32::from(p[c]) - want).abs() <= 1.0,
                    "({x},{y}) ch {c}: {} vs {want}",
                    p[c]
                );
            }
        }
    }
}

#[test]
fn intersection_matches_analytic_planes() {
    // Plane y = a·x + b·z + c sampled on a grid: the triangles reproduce it exactly.
    let (w, h, dx, dy) = (40, 30, 7.0, 5.0);
    let albedo = vec![[0.5f32; 3]; w * h];
    let mut rng = Lcg(7);
    for (a, b, c) in [(0.0, 0.0, 12.0), (0.3, -0.2, 40.0), (-0.7, 0.45, 100.0)] {
        let hx = (w - 1) as f64 * dx / 2.0;
        let hz = (h - 1) as f64 * dy / 2.0;
        let heights: Vec<f32> = (0..w * h)
            .map(|k| {
                let (col, row) = ((k % w) as f64, (k / w) as f64);
                (a * (col * dx - hx) + b * (row * dy - hz) + c) as f32
            })
            .collect();
        let scene = TerrainScene {
            width: w,
            height: h,
            dx,
            dy,
            heights: &heights,
            albedo: &albedo,
        };
        let acc = TerrainAccel::new(&scene);
        for _ in 0..200 {
            // Aim at a random point of the plane from a random eye above it.
            let (px, pz) = ((rng.next() - 0.5) * 1.8 * hx, (rng.next() - 0.5) * 1.8 * hz);
            let py = a * px + b * pz + c;
            let eye = [
                (rng.next() - 0.5) * 600.0,
                250.0 + rng.next() * 100.0,
                (rng.next() - 0.5) * 600.0,
            ];
            let v = [px - eye[0], py - eye[1], pz - eye[2]];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let d = [v[0] / len, v[1] / len, v[2] / len];
            // Analytic ray/plane distance: n·(o + t d) = c with n = (-a, 1, -b).
            let t_plane = (c - (eye[1] - a * eye[0] - b * eye[2])) / (d[1] - a * d[0] - b * d[2]);
            assert!((t_plane - len).abs() < 1e-6 * len);
            let hit = acc
                .intersect(eye, d, 0.0, f64::INFINITY)
                .expect("ray aimed at the plane hits");
            assert!(
                (hit.t - t_plane).abs() < 1e-6 * len,
                "t {} vs {}",
                hit.t,
                t_plane
            );
            let p = acc.hit_position(&hit);
            assert!((p[0] - px).abs() < 1e-6 * len && (p[2] - pz).abs() < 1e-6 * len);
            let n = acc.hit_normal(&hit);
            let nl = (a * a + 1.0 + b * b).sqrt();
            assert!(
                (n[0] + a / nl).abs() < 1e-5
                    && (n[1] - 1.0 / nl).abs() < 1e-5
                    && (n[2] + b / nl).abs() < 1e-5
            );
        }
    }
}

fn random_terrain(w: usize, h: usize, seed: u64, holes: bool) -> Vec<f32> {
    let mut rng = Lcg(seed);
    let phase: Vec<f64> = (0..6).map(|_| rng.next() * std::f64::consts::TAU).collect();
    (0..w * h)
        .map(|k| {
            let (x, z) = ((k % w) as f64, (k / w) as f64);
            let v = 20.0 * (x * 0.21 + phase[0]).sin() * (z * 0.17 + phase[1]).cos()
                + 8.0 * (x * 0.7 + z * 0.5 + phase[2]).sin()
                + 15.0 * rng.next();
            if holes && rng.next() < 0.05 {
                f32::NAN
            } else {
                v as f32
            }
        })
        .collect()
}

#[test]
fn pyramid_caster_equals_brute_force() {
    for (w, h, seed, holes) in [
        (37, 23, 1, false),
        (64, 64, 2, true),
        (5, 70, 3, false),
        (2, 2, 4, false),
        (129, 17, 5, true),
    ] {
        let heights = random_terrain(w, h, seed, holes);
        let albedo = vec![[0.5f32; 3]; w * h];
        let scene = TerrainScene {
            width: w,
            height: h,
            dx: 3.0,
            dy: 4.0,
            heights: &heights,
            albedo: &albedo,
        };
        let acc = TerrainAccel::new(&scene);
        let mut rng = Lcg(seed * 77);
        let (mut hits, mut total) = (0, 0);
        for _ in 0..3000 {
            let eye = [
                (rng.next() - 0.5) * 500.0,
                rng.next() * 120.0 - 10.0,
                (rng.next() - 0.5) * 500.0,
            ];
            let tgt = [
                (rng.next() - 0.5) * w as f64 * 3.0,
                rng.next() * 40.0 - 10.0,
                (rng.next() - 0.5) * h as f64 * 4.0,
            ];
            let v = [tgt[0] - eye[0], tgt[1] - eye[1], tgt[2] - eye[2]];
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let d = [v[0] / l, v[1] / l, v[2] / l];
            let fast = acc.intersect(eye, d, 0.0, f64::INFINITY);
            let slow = acc.intersect_brute(eye, d, 0.0, f64::INFINITY);
            total += 1;
            match (fast, slow) {
                (Some(a), Some(b)) => {
                    hits += 1;
                    assert!(
                        (a.t - b.t).abs() < 1e-6 * b.t.max(1.0),
                        "{w}x{h}: {} vs {}",
                        a.t,
                        b.t
                    );
                }
                (None, None) => {}
                (a, b) => panic!("{w}x{h}: pyramid {a:?} vs brute {b:?} for eye {eye:?} dir {d:?}"),
            }
        }
        assert!(
            hits > total / 10 || (w * h < 10 && hits > 0),
            "{w}x{h}: too few hits ({hits}) to mean anything"
        );
    }
}

#[test]
fn holes_are_transparent_and_the_sky_is_opaque() {
    let (w, h) = (40, 40);
    let mut heights = vec![10.0f32; w * h];
    for r in 15..25 {
        for c in 15..25 {
            heights[r * w + c] = f32::NAN;
        }
    }
    let albedo = vec![[0.5f32; 3]; w * h];
    let scene = TerrainScene {
        width: w,
        height: h,
        dx: 1.0,
        dy: 1.0,
        heights: &heights,
        albedo: &albedo,
    };
    // Straight down on the hole: the centre is transparent, the rim opaque.
    let cam = Camera {
        eye: [0.0, 60.0, 0.0],
        target: [0.0, 10.0, 0.0],
        up: [0.0, 0.0, -1.0],
        fov_deg: 50.0,
    };
    let img = render_terrain(
        &scene,
        &cam,
        &flat_lighting(),
        40,
        40,
        &NoControl,
        (0.0, 1.0),
    )
    .unwrap();
    assert_eq!(img.pixel(20, 20)[3], 0);
    assert_eq!(img.pixel(1, 1)[3], 255);
    // Looking at the horizon: sky above is opaque.
    let cam = Camera::orbit([0.0, 10.0, 0.0], 180.0, 5.0, 80.0, 40.0);
    let img = render_terrain(
        &scene,
        &cam,
        &flat_lighting(),
        40,
        40,
        &NoControl,
        (0.0, 1.0),
    )
    .unwrap();
    assert_eq!(img.pixel(20, 0)[3], 255);
    let top = img.pixel(20, 0);
    assert!(top[2] > top[0], "sky is blue: {top:?}");
}

fn volcano_scene_data() -> (usize, usize, f64, Vec<f32>, Vec<[f32; 3]>) {
    let (w, h, cell, heights) = load_asc("/work/shared/data/dem/maunga_whau_volcano.asc");
    let heights: Vec<f32> = heights.iter().map(|v| v * 1.5).collect();
    let (lo, hi) = heights
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    let albedo = heights
        .iter()
        .map(|&v| height_color((v - lo) / (hi - lo)))
        .collect();
    (w, h, cell, heights, albedo)
}

/// Green lowland → brown → grey rock → snow, linear RGB.
fn height_color(t: f32) -> [f32; 3] {
    let stops = [
        (0.0, [0.10, 0.22, 0.06]),
        (0.45, [0.22, 0.28, 0.10]),
        (0.7, [0.30, 0.24, 0.16]),
        (0.88, [0.40, 0.38, 0.36]),
        (1.0, [0.85, 0.86, 0.88]),
    ];
    for win in stops.windows(2) {
        let ((a, ca), (b, cb)) = (win[0], win[1]);
        if t <= b {
            let s = ((t - a) / (b - a)).clamp(0.0, 1.0);
            return [
                ca[0] + (cb[0] - ca[0]) * s,
                ca[1] + (cb[1] - ca[1]) * s,
                ca[2] + (cb[2] - ca[2]) * s,
            ];
        }
    }
    stops[4].1
}

#[test]
fn volcano_render_is_deterministic_across_thread_counts() {
    let (w, h, cell, heights, albedo) = volcano_scene_data();
    let scene = TerrainScene {
        width: w,
        height: h,
        dx: cell,
        dy: cell,
        heights: &heights,
        albedo: &albedo,
    };
    let (c, r) = scene.bounding_sphere();
    let cam = Camera::orbit(c, 200.0, 28.0, Camera::auto_distance(r, 35.0) * 0.8, 35.0);
    let light = Lighting {
        sun_dir: sun_direction(250.0, 35.0),
        ..Lighting::default()
    };
    let render = || render_terrain(&scene, &cam, &light, 900, 600, &NoControl, (0.0, 1.0)).unwrap();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(render);
    let many = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap()
        .install(render);
    assert!(one == many, "1-thread and 4-thread renders differ");
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"));
    std::fs::write(dir.join("volcano.png"), png_write::encode_rgba(&one)).unwrap();
    // Sky at the top, terrain in the middle.
    let top = one.pixel(450, 2);
    assert!(top[2] > top[0] && top[3] == 255);
    let mid = one.pixel(450, 400);
    assert!(mid != top);
}

#[test]
fn contact_sheet_dimensions_and_labels() {
    let tiles: Vec<(RgbaImage, String)> = (0..5)
        .map(|k| {
            (
                RgbaImage::new_filled(100 + k * 10, 60, [200, 30, 30, 255]),
                format!("b = {k}"),
            )
        })
        .collect();
    let sheet = contact_sheet(&tiles, 3);
    // 3 columns of the widest tile (140), 2 rows of 60 + 28 caption, 12 px gaps.
    assert_eq!(
        (sheet.width, sheet.height),
        (3 * (140 + 12) + 12, 2 * (60 + 28 + 12) + 12)
    );
    // Some caption ink under the first tile.
    let dark = (12..152)
        .flat_map(|x| (72..100).map(move |y| (x, y)))
        .filter(|&(x, y)| sheet.pixel(x, y)[0] < 0x40)
        .count();
    assert!(dark > 20, "caption drawn ({dark} dark pixels)");
    assert!(sheet.data.chunks(4).all(|p| p[3] == 255));
}

#[test]
fn glb_structure_and_vertex_budget() {
    let (w, h) = (101, 67);
    let heights = random_terrain(w, h, 9, true);
    let colors = vec![[0.2f32, 0.5, 0.9]; w * h];
    for budget in [usize::MAX, 2000, 100, 4] {
        let bytes = glb::terrain_glb(&heights, w, h, 10.0, 20.0, &colors, budget);
        let doc = check_glb(&bytes);
        let acc = &doc["accessors"];
        let pos = &acc[doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
            .as_u64()
            .unwrap() as usize];
        let count = pos["count"].as_u64().unwrap() as usize;
        assert!(
            count <= budget.max(4),
            "{count} vertices over budget {budget}"
        );
        assert!(count > 0);
        let min = pos["min"].as_array().unwrap();
        let max = pos["max"].as_array().unwrap();
        // Centred like the renderer.
        assert!(
            min[0].as_f64().unwrap() >= -500.0 - 1e-3 && max[0].as_f64().unwrap() <= 500.0 + 1e-3
        );
        assert!(
            min[2].as_f64().unwrap() >= -660.0 - 1e-3 && max[2].as_f64().unwrap() <= 660.0 + 1e-3
        );
        if budget == usize::MAX {
            // Full resolution: every valid point is kept and no triangle touches a hole.
            let valid = heights.iter().filter(|v| !v.is_nan()).count();
            assert!(count <= valid);
            assert!(min[0].as_f64().unwrap() < -499.0 && max[0].as_f64().unwrap() > 499.0);
        }
    }
}

/// Parse a GLB, check header, chunk and bufferView alignment and sizes, and return its JSON.
pub(crate) fn check_glb(bytes: &[u8]) -> serde_json::Value {
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()) as usize;
    assert_eq!(&bytes[0..4], b"glTF");
    assert_eq!(u32_at(4), 2);
    assert_eq!(u32_at(8), bytes.len());
    let json_len = u32_at(12);
    assert_eq!(&bytes[16..20], b"JSON");
    assert_eq!(json_len % 4, 0);
    let json = &bytes[20..20 + json_len];
    let doc: serde_json::Value = serde_json::from_slice(json).unwrap();
    let bin_at = 20 + json_len;
    let bin_len = u32_at(bin_at);
    assert_eq!(&bytes[bin_at + 4..bin_at + 8], b"BIN\0");
    assert_eq!(bin_len % 4, 0);
    assert_eq!(bin_at + 8 + bin_len, bytes.len());
    assert_eq!(doc["asset"]["version"], "2.0");
    let buf_len = doc["buffers"][0]["byteLength"].as_u64().unwrap() as usize;
    assert!(buf_len <= bin_len && bin_len - buf_len < 4);
    for v in doc["bufferViews"].as_array().unwrap() {
        let off = v["byteOffset"].as_u64().unwrap_or(0) as usize;
        assert_eq!(off % 4, 0);
        assert!(off + v["byteLength"].as_u64().unwrap() as usize <= buf_len);
    }
    let prim = &doc["meshes"][0]["primitives"][0];
    let count = |k: &serde_json::Value| {
        doc["accessors"][k.as_u64().unwrap() as usize]["count"]
            .as_u64()
            .unwrap()
    };
    let n = count(&prim["attributes"]["POSITION"]);
    assert_eq!(count(&prim["attributes"]["NORMAL"]), n);
    assert_eq!(count(&prim["attributes"]["COLOR_0"]), n);
    assert_eq!(count(&prim["indices"]) % 3, 0);
    // Every index points at a vertex; every position is finite and inside min/max.
    let view = |acc: &serde_json::Value| {
        let a = &doc["accessors"][acc.as_u64().unwrap() as usize];
        let v = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        let off = bin_at + 8 + v["byteOffset"].as_u64().unwrap_or(0) as usize;
        &bytes[off..off + v["byteLength"].as_u64().unwrap() as usize]
    };
    for c in view(&prim["indices"]).chunks_exact(4) {
        assert!((u32::from_le_bytes(c.try_into().unwrap()) as u64) < n);
    }
    let pos_acc = &doc["accessors"][prim["attributes"]["POSITION"].as_u64().unwrap() as usize];
    for (k, c) in view(&prim["attributes"]["POSITION"])
        .chunks_exact(4)
        .enumerate()
    {
        let v = f64::from(f32::from_le_bytes(c.try_into().unwrap()));
        assert!(v.is_finite());
        assert!(
            v >= pos_acc["min"][k % 3].as_f64().unwrap()
                && v <= pos_acc["max"][k % 3].as_f64().unwrap()
        );
    }
    doc
}

fn ramp_albedo(heights: &[f32]) -> Vec<[f32; 3]> {
    let (lo, hi) = heights
        .iter()
        .filter(|v| !v.is_nan())
        .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    heights
        .iter()
        .map(|&v| height_color((v - lo) / (hi - lo).max(1e-6)))
        .collect()
}

#[test]
fn a_ridge_casts_a_shadow_and_cancel_stops_the_render() {
    // Flat ground at 0 with a 50 m north–south ridge at column 40; sun in the east, 30° up:
    // the shadow reaches 50 / tan 30° ≈ 87 m west of the ridge.
    let (w, h) = (64, 64);
    let heights: Vec<f32> = (0..w * h)
        .map(|k| if k % w == 40 { 50.0 } else { 0.0 })
        .collect();
    let albedo = vec![[0.5f32; 3]; w * h];
    let scene = TerrainScene {
        width: w,
        height: h,
        dx: 1.0,
        dy: 1.0,
        heights: &heights,
        albedo: &albedo,
    };
    let acc = TerrainAccel::new(&scene);
    let sun = sun_direction(90.0, 30.0);
    let x = |col: f64| col - 31.5;
    assert!(!acc.sunlit([x(30.0), 0.0, 0.0], sun, 1e-3));
    assert!(acc.sunlit([x(50.0), 0.0, 0.0], sun, 1e-3));
    // Rendered from above, every shadow mode: the sun due east takes the per-point map (swept);
    // 10° south of east, 64² grid points < 128² pixels the per-point map (shadow rays), and
    // > 32² pixels a shadow ray per hit.
    let cam = Camera {
        eye: [0.0, 300.0, 0.0],
        target: [0.0, 0.0, 0.0],
        up: [0.0, 0.0, -1.0],
        fov_deg: 14.0,
    };
    let mut light = Lighting {
        sun_dir: sun,
        shadows: true,
        ..flat_lighting()
    };
    for (size, az) in [(128u32, 90.0), (32, 90.0), (128, 100.0), (32, 100.0)] {
        light.sun_dir = sun_direction(az, 30.0);
        let img = render_terrain(&scene, &cam, &light, size, size, &NoControl, (0.0, 1.0)).unwrap();
        // Image x runs east; the ridge is at 8.5 m east of the centre.
        let px = |metres_east: f64| {
            ((0.5 + metres_east / (2.0 * 300.0 * 7f64.to_radians().tan())) * f64::from(size)) as u32
        };
        let shadow = img.pixel(px(-10.0), size / 2)[0];
        let lit = img.pixel(px(20.0), size / 2)[0];
        assert!(
            shadow + 40 < lit,
            "{size}px, sun {az}°: shadow {shadow} vs lit {lit}"
        );
    }

    struct CancelAfter(std::sync::atomic::AtomicUsize);
    impl phenomena_engine::Control for CancelAfter {
        fn progress(&self, _stage: &str, fraction: f32) {
            assert!((0.2..=0.6).contains(&fraction));
        }
        fn is_canceled(&self) -> bool {
            self.0.fetch_add(1, std::sync::atomic::Ordering::Relaxed) > 3
        }
    }
    let ctl = CancelAfter(0.into());
    let res = render_terrain(&scene, &cam, &light, 200, 200, &ctl, (0.2, 0.6));
    assert_eq!(res, Err(phenomena_engine::Canceled));
}

/// The horizon sweep gives the shadow rays' answer for suns along the four grid axes, with and
/// without holes and with unequal cell sizes, except where a shadow ray grazes the boundary of
/// the surface or starts on a slope that climbs toward the sun faster than the sun (see below);
/// other azimuths are not swept.
#[test]
fn sun_sweep_matches_shadow_rays() {
    let (vw, vh, vcell, vheights, _) = volcano_scene_data();
    let cases = [
        (vw, vh, vcell, vcell, vheights),
        (120, 90, 3.0, 4.0, random_terrain(120, 90, 5, true)),
        (97, 61, 2.0, 1.5, random_terrain(97, 61, 9, false)),
    ];
    for (w, h, dx, dy, heights) in &cases {
        let albedo = vec![[0.5f32; 3]; w * h];
        let scene = TerrainScene {
            width: *w,
            height: *h,
            dx: *dx,
            dy: *dy,
            heights,
            albedo: &albedo,
        };
        let acc = TerrainAccel::new(&scene);
        let eps = 1e-3 * dx.min(*dy);
        let n = w * h;
        for az in [0.0, 90.0, 180.0, 270.0] {
            for el in [8.0, 25.0, 60.0, 90.0] {
                let sun = sun_direction(az, el);
                assert!(acc.sweeps(sun));
                let sweep = acc
                    .sun_visibility_sweep(sun, eps, &NoControl)
                    .unwrap()
                    .unwrap();
                let rays = acc.sun_visibility_rays(sun, eps, &NoControl).unwrap();
                // Where the shadow ray's grid line toward the sun has a segment without a valid
                // cell on both sides, the two may differ: along a hole's or the DEM's edge the
                // sweep counts the edge as surface while the pyramid walk tests the cells on one
                // side (chosen by the rounding of the sun vector, sin 180° = 1.2e-16); and a ray
                // that crosses a hole below the far side's edge is blocked by the sweep (the
                // ground is solid) but passes under the surface sheet in the pyramid walk.
                let cell = |ci: usize, cj: usize, di: isize, dj: isize| -> bool {
                    let (ci, cj) = (ci as isize + di, cj as isize + dj);
                    if ci < 0 || cj < 0 || ci + 1 >= *w as isize || cj + 1 >= *h as isize {
                        return false;
                    }
                    let k = cj as usize * w + ci as usize;
                    !(heights[k] + heights[k + 1] + heights[k + w] + heights[k + w + 1]).is_nan()
                };
                let grazes = |k: usize| -> bool {
                    let (c, r) = (k % w, k / w);
                    let col = |j: usize| !(cell(c, j, -1, 0) && cell(c, j, 0, 0));
                    let row = |i: usize| !(cell(i, r, 0, -1) && cell(i, r, 0, 0));
                    match az as u32 {
                        0 => (0..r).any(col),
                        180 => (r..*h).any(col),
                        90 => (c..*w).any(row),
                        _ => (0..c).any(row),
                    }
                };
                // And where the terrain climbs toward the sun faster than the sun (the next grid
                // point toward it already stands above the ray: a slope facing away from the
                // sun), the shadow ray crosses the surface within a few `eps` of its start, where
                // the pyramid walk's `tmin` guard against self-intersection may drop the hit;
                // the sweep says shadowed, which is what the geometry says.
                let tan = f64::to_radians(el).tan();
                let climbs = |k: usize| -> bool {
                    let (c, r) = (k % w, k / w);
                    let next = match az as u32 {
                        0 => (r > 0).then(|| (k - w, *dy)),
                        180 => (r + 1 < *h).then(|| (k + w, *dy)),
                        90 => (c + 1 < *w).then(|| (k + 1, *dx)),
                        _ => (c > 0).then(|| (k - 1, *dx)),
                    };
                    next.is_some_and(|(j, step)| {
                        f64::from(heights[j]) >= f64::from(heights[k]) + eps + step * tan
                    })
                };
                let differ = (0..n).filter(|&k| sweep[k] != rays[k]).count();
                let unexplained = (0..n)
                    .filter(|&k| sweep[k] != rays[k] && !grazes(k) && !climbs(k))
                    .count();
                let shadowed = rays.iter().filter(|&&v| v == 0).count();
                println!(
                    "{w}×{h} sun {az}°/{el}°: {shadowed} shadowed, {differ} differ (explained)"
                );
                if el < 30.0 {
                    assert!(shadowed > n / 50, "{w}×{h} {az}/{el}: {shadowed} shadowed");
                }
                if el == 90.0 {
                    assert_eq!(shadowed, 0);
                }
                assert!(
                    differ <= n / 10,
                    "{w}×{h} sun {az}°/{el}°: {differ} grazing"
                );
                assert_eq!(
                    unexplained, 0,
                    "{w}×{h} sun {az}°/{el}°: {unexplained} of {n} points differ"
                );
                // Off the DEM's edge lines, the real (smooth) volcano agrees everywhere.
                if *w == vw {
                    let inner = (0..n).filter(|&k| {
                        let (c, r) = (k % w, k / w);
                        sweep[k] != rays[k] && c > 0 && c + 1 < *w && r > 0 && r + 1 < *h
                    });
                    assert_eq!(inner.count(), 0, "{w}×{h} sun {az}°/{el}°");
                }
            }
        }
        let oblique = sun_direction(135.0, 30.0);
        assert!(!acc.sweeps(oblique));
        assert!(acc
            .sun_visibility_sweep(oblique, eps, &NoControl)
            .unwrap()
            .is_none());
    }
}

/// Per-pixel agreement of two images: (share of pixels within `tol` in every channel incl.
/// alpha, worst channel difference).
fn agreement(a: &RgbaImage, b: &RgbaImage, tol: u8) -> (f64, u8) {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let (mut ok, mut worst) = (0usize, 0u8);
    for (p, q) in a.data.chunks_exact(4).zip(b.data.chunks_exact(4)) {
        let d = p.iter().zip(q).map(|(x, y)| x.abs_diff(*y)).max().unwrap();
        worst = worst.max(d);
        ok += usize::from(d <= tol);
    }
    (ok as f64 / (a.data.len() / 4) as f64, worst)
}

#[test]
fn raster_path_matches_the_ray_caster() {
    use phenomena_engine::render::{render_accel_on_path, RenderPath};
    // (name, w, h, cell, heights, albedo, camera, image size)
    let (vw, vh, vcell, vheights, valbedo) = volcano_scene_data();
    let rw = 120;
    let rh = 90;
    let rheights = random_terrain(rw, rh, 11, true);
    let ralbedo = ramp_albedo(&rheights);
    type Case<'a> = (
        &'a str,
        usize,
        usize,
        f64,
        &'a [f32],
        &'a [[f32; 3]],
        f64,
        f64,
        u32,
        u32,
    );
    let cases: [Case; 3] = [
        (
            "volcano", vw, vh, vcell, &vheights, &valbedo, 200.0, 28.0, 900, 600,
        ),
        (
            "volcano-low",
            vw,
            vh,
            vcell,
            &vheights,
            &valbedo,
            20.0,
            8.0,
            640,
            360,
        ),
        (
            "random-holes",
            rw,
            rh,
            3.0,
            &rheights,
            &ralbedo,
            150.0,
            35.0,
            480,
            360,
        ),
    ];
    for (name, w, h, cell, heights, albedo, az, el, iw, ih) in cases {
        let scene = TerrainScene {
            width: w,
            height: h,
            dx: cell,
            dy: cell,
            heights,
            albedo,
        };
        let (c, r) = scene.bounding_sphere();
        let cam = Camera::orbit(c, az, el, Camera::auto_distance(r, 35.0) * 0.8, 35.0);
        let light = Lighting {
            sun_dir: sun_direction(250.0, 35.0),
            ..Lighting::default()
        };
        let acc = TerrainAccel::new(&scene);
        let render =
            |p| render_accel_on_path(&acc, &cam, &light, iw, ih, p, &NoControl, (0.0, 1.0));
        let ray = render(RenderPath::RayCast).unwrap();
        let ras = render(RenderPath::Raster).unwrap();
        let (share, worst) = agreement(&ray, &ras, 3);
        let (share8, _) = agreement(&ray, &ras, 8);
        println!(
            "{name}: {:.3} % within 3/255, {:.3} % within 8/255, worst {worst}",
            share * 100.0,
            share8 * 100.0
        );
        let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"));
        std::fs::write(
            dir.join(format!("{name}_ray.png")),
            png_write::encode_rgba(&ray),
        )
        .unwrap();
        std::fs::write(
            dir.join(format!("{name}_raster.png")),
            png_write::encode_rgba(&ras),
        )
        .unwrap();
        // Shading is identical; only silhouette and hole-edge pixels may differ (visibility of
        // a sample right on an edge, f32 depth).
        assert!(
            share >= 0.99,
            "{name}: only {:.3} % of pixels within 3/255",
            share * 100.0
        );
        // Transparent pixels (holes) agree too.
        let transparent = |i: &RgbaImage| i.data.chunks_exact(4).filter(|p| p[3] == 0).count();
        let (ta, tb) = (transparent(&ray), transparent(&ras));
        assert!(
            ta.abs_diff(tb) <= ta / 50 + 20,
            "{name}: transparent {ta} vs {tb}"
        );
        if name == "random-holes" {
            assert!(ta > 100, "holes visible: {ta}");
        }
        // Raster path: the same bytes with 1 and 2 threads.
        let pool = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
        };
        let one = pool(1).install(|| render(RenderPath::Raster).unwrap());
        let two = pool(2).install(|| render(RenderPath::Raster).unwrap());
        assert!(
            one == two && one == ras,
            "{name}: raster bytes depend on the thread count"
        );
    }
}

/// A flat plane with a grid-point checkerboard albedo (0.1 / 0.7) under `light`, seen straight
/// down from `height` above it, ray cast at 64 × 48.
fn checkerboard_from_above(n: usize, height: f64, light: &Lighting, uniform: bool) -> RgbaImage {
    let heights = vec![0.0f32; n * n];
    let albedo: Vec<[f32; 3]> = (0..n * n)
        .map(|k| {
            if uniform {
                [0.4; 3]
            } else if (k % n + k / n) % 2 == 0 {
                [0.1; 3]
            } else {
                [0.7; 3]
            }
        })
        .collect();
    let scene = TerrainScene {
        width: n,
        height: n,
        dx: 1.0,
        dy: 1.0,
        heights: &heights,
        albedo: &albedo,
    };
    let cam = Camera {
        eye: [0.0, height, 0.0],
        target: [0.0, 0.0, 0.0],
        up: [0.0, 0.0, -1.0],
        fov_deg: 30.0,
    };
    let acc = TerrainAccel::new(&scene);
    phenomena_engine::render::render_accel_on_path(
        &acc,
        &cam,
        light,
        64,
        48,
        phenomena_engine::render::RenderPath::RayCast,
        &NoControl,
        (0.0, 1.0),
    )
    .unwrap()
}

/// Texture level of detail (`render/terrain/lod.rs`): a checkerboard far smaller than a pixel is
/// shaded as its mean (the filtered level of a 2 × 2 checkerboard is exactly 0.4), so the image
/// equals that of a uniform 0.4 plane within rounding, where point sampling aliases it into
/// black and white pixels; and where a pixel spans less than two cells (level 0) the filtered
/// render is the unfiltered one, byte for byte.
#[test]
fn texture_lod_filters_sub_pixel_albedo_and_keeps_level_0_exact() {
    let light = Lighting {
        sun_dir: [0.0, 1.0, 0.0],
        ambient: 0.3,
        ..flat_lighting()
    };
    let lod = Lighting {
        texture_lod: true,
        ..light
    };
    // 1024 cells seen from 3000 above with a 30° field: a pixel spans ~33 cells (level 5).
    let far_lod = checkerboard_from_above(1024, 3000.0, &lod, false);
    let far_uniform = checkerboard_from_above(1024, 3000.0, &light, true);
    let (share, worst) = agreement(&far_lod, &far_uniform, 1);
    assert!(
        share == 1.0,
        "filtered checkerboard vs uniform mean: {share} within 1/255, worst {worst}"
    );
    // Point sampling of the same view (with its adaptive anti-aliasing, 5 samples of a
    // 33-cell footprint) leaves visible aliasing: pixels off the mean by more than 8/255
    // (measured: 72 % within 8/255, worst 33/255).
    let far_point = checkerboard_from_above(1024, 3000.0, &light, false);
    let (share, worst) = agreement(&far_point, &far_uniform, 8);
    assert!(
        share < 1.0 && worst > 8,
        "unfiltered checkerboard should alias: {share} within 8/255, worst {worst}"
    );
    // Close: a pixel spans ~0.3 cells (level 0), the filter changes nothing.
    let near_lod = checkerboard_from_above(1024, 30.0, &lod, false);
    let near_point = checkerboard_from_above(1024, 30.0, &light, false);
    assert_eq!(near_lod.data, near_point.data);
}
