//! Dust (SPEC §4): the dust-amount properties of step 1, the tileable Perlin fBm, and the fibre
//! walks and textures of step 3 (allowed neighbours, length, bends, wrapping, decreasing counts per
//! shell, an independent serial re-composite, determinism across thread counts, a golden texture);
//! the coarse noise field, the crease split, the texture mapping and the mip pyramid.

use phenomena_engine::dust::amount::{
    directional, dust_amount, hemisphere_directions, vertex_normals, AmountModel,
};
use phenomena_engine::dust::fibers::{
    fiber_texture, fiber_walk, motion_map, shell_fiber_count, shell_textures, FiberParams,
    NEIGHBOURS,
};
use phenomena_engine::dust::mapping::{box_uvs, triplanar, Mapping};
use phenomena_engine::dust::noise::TileableNoise;
use phenomena_engine::dust::surface::{crease_split, refine};
use phenomena_engine::dust::texture::ShellTexture;
use phenomena_engine::geom::mesh::Mesh;
use phenomena_engine::render::image::RgbaImage;

use crate::support::golden::assert_golden;

// ---------------------------------------------------------------------------------------------
// Meshes

fn push_quad(m: &mut Mesh, c: [[f32; 3]; 4]) {
    let base = m.positions.len() as u32;
    m.positions.extend_from_slice(&c);
    m.triangles.push([base, base + 1, base + 2]);
    m.triangles.push([base, base + 2, base + 3]);
}

/// A unit square through the origin whose (outward, counter-clockwise) normal is up tilted by
/// `theta` about the z axis.
fn tilted_square(theta: f32) -> Mesh {
    let (s, c) = theta.sin_cos();
    // In-plane axes: a = (c, s, 0) (tilted x), b = (0, 0, -1); normal a × b = (-s, c, 0).
    let p = |u: f32, v: f32| [u * c, u * s, -v];
    let mut m = Mesh::default();
    push_quad(
        &mut m,
        [p(-0.5, -0.5), p(0.5, -0.5), p(0.5, 0.5), p(-0.5, 0.5)],
    );
    m
}

/// A grid floor over [−2, 2]² at y = 0 (spacing 0.2, normal up) and an axis-aligned unit-high box
/// [−0.5, 0.5] × [0, 1] × [−0.5, 0.5] with its own vertices per face (normals outward).
pub(crate) fn box_on_floor() -> Mesh {
    let mut m = Mesh::default();
    let n = 20;
    for i in 0..n {
        for j in 0..n {
            let x0 = -2.0 + 0.2 * i as f32;
            let z0 = -2.0 + 0.2 * j as f32;
            let (x1, z1) = (x0 + 0.2, z0 + 0.2);
            // Counter-clockwise seen from above (+y): normal up.
            push_quad(
                &mut m,
                [[x0, 0.0, z0], [x0, 0.0, z1], [x1, 0.0, z1], [x1, 0.0, z0]],
            );
        }
    }
    let (a, b) = (-0.5f32, 0.5f32);
    // top (+y)
    push_quad(&mut m, [[a, 1.0, a], [a, 1.0, b], [b, 1.0, b], [b, 1.0, a]]);
    // +x
    push_quad(&mut m, [[b, 0.0, a], [b, 1.0, a], [b, 1.0, b], [b, 0.0, b]]);
    // −x
    push_quad(&mut m, [[a, 0.0, a], [a, 0.0, b], [a, 1.0, b], [a, 1.0, a]]);
    // +z
    push_quad(&mut m, [[a, 0.0, b], [b, 0.0, b], [b, 1.0, b], [a, 1.0, b]]);
    // −z
    push_quad(&mut m, [[a, 0.0, a], [a, 1.0, a], [b, 1.0, a], [b, 0.0, a]]);
    m
}

fn model(k: f32, s: f32) -> AmountModel {
    AmountModel {
        stickiness: k,
        slipperiness: s,
        ..AmountModel::default()
    }
}

// ---------------------------------------------------------------------------------------------
// Dust amount (SPEC §4 step 1)

#[test]
fn a_horizontal_exposed_face_gets_exactly_k() {
    let m = tilted_square(0.0);
    let n = vertex_normals(&m);
    for v in &n {
        assert!((v[1] - 1.0).abs() < 1e-6, "normal {v:?}");
    }
    for k in [0.3f32, 1.0, 2.5] {
        let d = dust_amount(&m, &model(k, 3.0));
        for x in &d {
            assert!((x - k).abs() < 1e-6, "D = {x}, K = {k}");
        }
    }
}

#[test]
fn faces_turned_away_from_the_source_get_none() {
    // Facing down (θ = 180°), past vertical (θ = 120°) and exactly vertical (θ = 90°).
    for deg in [90.0f32, 120.0, 180.0] {
        let d = dust_amount(&tilted_square(deg.to_radians()), &model(1.0, 1.0));
        for x in &d {
            assert!(*x <= 1e-6, "θ = {deg}°: D = {x}");
            assert!(*x >= 0.0);
        }
    }
    // The box's sides and a downward source: nothing on the top.
    let m = box_on_floor();
    let mut down = model(1.0, 1.0);
    down.source = [0.0, -1.0, 0.0];
    let d = dust_amount(&m, &down);
    let n = vertex_normals(&m);
    for (x, nv) in d.iter().zip(&n) {
        if nv[1] >= 0.0 {
            assert_eq!(*x, 0.0, "normal {nv:?}");
        }
    }
}

#[test]
fn dust_falls_monotonically_with_theta_as_k_cos_theta_to_the_s() {
    let (k, s) = (0.8f32, 2.5f32);
    let mut prev = f32::INFINITY;
    for step in 0..=17 {
        let theta = (5.0 * step as f32).to_radians();
        let d = dust_amount(&tilted_square(theta), &model(k, s));
        let expect = k * theta.cos().powf(s);
        for x in &d {
            // A lone plane is fully exposed: D is the directional term alone.
            assert!((x - expect).abs() < 1e-5, "θ = {step}·5°: {x} vs {expect}");
        }
        assert!(d[0] < prev, "not decreasing at θ = {}°", 5 * step);
        prev = d[0];
    }
}

#[test]
fn larger_slipperiness_leaves_less_dust_on_tilted_faces() {
    let tilted = tilted_square(35f32.to_radians());
    let flat = tilted_square(0.0);
    let mut prev = f32::INFINITY;
    for s in [0.25f32, 0.5, 1.0, 2.0, 4.0, 8.0] {
        let d = dust_amount(&tilted, &model(1.0, s))[0];
        assert!(d < prev, "s = {s}: {d} ≥ {prev}");
        prev = d;
        // …while a horizontal face keeps K whatever s.
        let f = dust_amount(&flat, &model(1.0, s))[0];
        assert!((f - 1.0).abs() < 1e-6);
    }
}

#[test]
fn an_occluded_corner_gets_less_dust_than_the_open_top() {
    let m = box_on_floor();
    let d = dust_amount(&m, &model(1.0, 2.0));
    let find = |p: [f32; 3]| {
        m.positions
            .iter()
            .position(|q| (0..3).all(|k| (q[k] - p[k]).abs() < 1e-4))
            .unwrap()
    };
    let top = d[find([0.5, 1.0, 0.5])];
    assert!((top - 1.0).abs() < 1e-6, "open top: {top}");
    // Floor vertices 0.1 m from the middle of the box's +x wall (the crevice between floor and
    // wall), and 0.1 m diagonally off the box's +x/+z edge (sees past the edge: more sky).
    let wall = d[find([0.6, 0.0, 0.0])];
    let corner = d[find([0.6, 0.0, 0.6])];
    // The floor's far corner sees the box only near the horizon.
    let open = d[find([-2.0, 0.0, -2.0])];
    assert!(open > 0.95, "open floor: {open}");
    assert!(wall < 0.8 * open, "beside the wall {wall}, top {top}");
    assert!(
        corner > wall && corner < open,
        "corner {corner}, wall {wall}, open {open}"
    );
    assert!(corner > 0.0);
    // Exposure grows with the distance from the wall along the floor.
    let far = d[find([1.4, 0.0, 0.0])];
    assert!(far > wall, "far {far}, near {wall}");
    // Without the exposure term the same vertex gets K (flat floor).
    let mut off = model(1.0, 2.0);
    off.exposure = false;
    assert_eq!(dust_amount(&m, &off)[find([0.6, 0.0, 0.0])], 1.0);
}

#[test]
fn hemisphere_directions_are_unit_and_around_the_source() {
    let u = [0.0f32, 0.6, 0.8];
    let dirs = hemisphere_directions(u, 64);
    assert_eq!(dirs.len(), 64);
    let mut mean = 0.0;
    for d in &dirs {
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((l - 1.0).abs() < 1e-5);
        let c = d[0] * u[0] + d[1] * u[1] + d[2] * u[2];
        assert!(c > 0.0);
        mean += c;
    }
    // Cosine-weighted hemisphere: E[cos] = 2/3.
    assert!((mean / 64.0 - 2.0 / 3.0).abs() < 0.01, "{}", mean / 64.0);
    assert!((directional(&model(2.0, 1.0), u, u) - 2.0).abs() < 1e-6);
}

#[test]
fn dust_amount_is_the_same_across_thread_counts() {
    let m = box_on_floor();
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| dust_amount(&m, &model(1.0, 2.0)))
    };
    let one = run(1);
    let three = run(3);
    assert_eq!(
        one.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
        three.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
    );
}

// ---------------------------------------------------------------------------------------------
// Perlin fBm

#[test]
fn noise_is_seeded_in_range_and_tiles_seamlessly() {
    let n = TileableNoise::new(7, 4.0, 5);
    let (w, h) = (128u32, 96u32);
    let t = n.texture(w, h);
    assert_eq!(t, n.texture(w, h));
    assert_ne!(t, TileableNoise::new(8, 4.0, 5).texture(w, h));
    let (lo, hi) = t
        .iter()
        .fold((1.0f32, 0.0f32), |(a, b), &x| (a.min(x), b.max(x)));
    assert!((0.0..=1.0).contains(&lo) && (0.0..=1.0).contains(&hi));
    assert!(lo < 0.3 && hi > 0.7, "range [{lo}, {hi}] too narrow");
    // Period 1 in u and v.
    for (u, v) in [(0.0, 0.0), (0.13, 0.71), (0.5, 0.999)] {
        let a = n.sample(u, v);
        assert!((a - n.sample(u + 1.0, v)).abs() < 1e-5);
        assert!((a - n.sample(u, v + 1.0)).abs() < 1e-5);
        assert!((a - n.sample(u - 2.0, v + 3.0)).abs() < 1e-5);
    }
    // The seam (last column → first, last row → first) is no rougher than the interior.
    let (wu, hu) = (w as usize, h as usize);
    let at = |x: usize, y: usize| t[y * wu + x];
    let mut interior = 0.0f32;
    let mut worst_interior = 0.0f32;
    for y in 0..hu {
        for x in 0..wu - 1 {
            let d = (at(x + 1, y) - at(x, y)).abs();
            interior += d;
            worst_interior = worst_interior.max(d);
        }
    }
    interior /= (hu * (wu - 1)) as f32;
    let seam_x: Vec<f32> = (0..hu).map(|y| (at(0, y) - at(wu - 1, y)).abs()).collect();
    let seam_y: Vec<f32> = (0..wu).map(|x| (at(x, 0) - at(x, hu - 1)).abs()).collect();
    for seam in [&seam_x, &seam_y] {
        let mean = seam.iter().sum::<f32>() / seam.len() as f32;
        let worst = seam.iter().cloned().fold(0.0, f32::max);
        assert!(
            mean < 2.0 * interior,
            "seam mean {mean}, interior {interior}"
        );
        assert!(
            worst <= worst_interior * 1.5,
            "seam {worst}, interior {worst_interior}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Fibres (SPEC §4 step 3)

fn params() -> FiberParams {
    FiberParams {
        fibers: 400,
        fiber_length: 40,
        bends: 3,
        bend_angle_deg: 50.0,
        fiber_decay: 0.03,
        fiber_opacity: 0.4,
    }
}

fn angle_diff(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(std::f32::consts::TAU);
    d.min(std::f32::consts::TAU - d)
}

#[test]
fn walks_stay_within_the_three_neighbours_nearest_the_heading() {
    let p = params();
    let noise = TileableNoise::new(3, 4.0, 4).texture(64, 64);
    let mut walks = 0;
    for j in 0..300 {
        let Some(w) = fiber_walk(&p, &noise, 64, 64, 11, 0, j) else {
            continue;
        };
        walks += 1;
        assert_eq!(
            w.moves.len(),
            p.fiber_length as usize,
            "exactly fiber_length steps"
        );
        assert_eq!(w.bends.len(), p.bends as usize);
        let mut prev = w.heading;
        let mut last_step = 0;
        for b in &w.bends {
            assert!(
                b.step > last_step && b.step < p.fiber_length,
                "bend at {}",
                b.step
            );
            last_step = b.step;
            assert!(
                angle_diff(b.heading, prev) <= p.bend_angle_deg.to_radians() + 1e-4,
                "bend turns {}° > {}°",
                angle_diff(b.heading, prev).to_degrees(),
                p.bend_angle_deg
            );
            prev = b.heading;
        }
        for (t, &k) in w.moves.iter().enumerate() {
            let h = w.heading_at(t as u32);
            // Independent check: a neighbour at most 67.5° from the heading (the 3 nearest).
            let (dx, dy) = NEIGHBOURS[k as usize];
            let a = (dy as f32).atan2(dx as f32);
            assert!(
                angle_diff(a, h) <= 67.5f32.to_radians() + 1e-4,
                "step {t}: move {k} is {}° from the heading",
                angle_diff(a, h).to_degrees()
            );
            assert!(motion_map(h).0.contains(&k));
        }
        // Trail texels: consecutive ones are 8-neighbours on the torus.
        let tx = w.texels(64, 64);
        assert_eq!(tx.len(), p.fiber_length as usize + 1);
    }
    assert!(walks > 250, "only {walks} fibres started");
}

#[test]
fn motion_map_is_a_distribution_over_three_adjacent_neighbours() {
    for i in 0..720 {
        let h = (i as f32 * 0.5).to_radians();
        let (ks, w) = motion_map(h);
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        assert!(w.iter().all(|&x| x > 0.0));
        assert_eq!((ks[0] + 1) % 8, ks[1]);
        assert_eq!((ks[1] + 1) % 8, ks[2]);
        // The middle one is the nearest to the heading.
        let ang = |k: u8| {
            let (dx, dy) = NEIGHBOURS[k as usize];
            (dy as f32).atan2(dx as f32)
        };
        assert!(angle_diff(ang(ks[1]), h) <= 22.5f32.to_radians() + 1e-5);
        // The mean step points along the heading.
        let (mut mx, mut my) = (0.0f32, 0.0f32);
        for (k, p) in ks.iter().zip(&w) {
            mx += p * NEIGHBOURS[*k as usize].0 as f32;
            my += p * NEIGHBOURS[*k as usize].1 as f32;
        }
        assert!(
            angle_diff(my.atan2(mx), h) < 1e-4,
            "h = {}°",
            i as f32 * 0.5
        );
    }
}

#[test]
fn an_unbent_walk_keeps_its_heading_on_average() {
    let p = FiberParams {
        fiber_length: 4000,
        bends: 0,
        ..params()
    };
    let noise = vec![1.0f32; 32 * 32];
    for j in 0..8 {
        let w = fiber_walk(&p, &noise, 32, 32, 5, 0, j).unwrap();
        let (mut sx, mut sy) = (0.0f32, 0.0f32);
        for &k in &w.moves {
            sx += NEIGHBOURS[k as usize].0 as f32;
            sy += NEIGHBOURS[k as usize].1 as f32;
        }
        let a = sy.atan2(sx);
        assert!(
            angle_diff(a, w.heading) < 8f32.to_radians(),
            "mean direction {}° vs heading {}°",
            a.to_degrees(),
            w.heading.to_degrees()
        );
    }
}

#[test]
fn start_points_are_accepted_with_the_noise_probability() {
    // Noise 0 on the left half, 1 on the right: every start lies on the right.
    let (w, h) = (32u32, 16u32);
    let noise: Vec<f32> = (0..w * h)
        .map(|i| if i % w >= w / 2 { 1.0 } else { 0.0 })
        .collect();
    let p = params();
    for j in 0..200 {
        let walk = fiber_walk(&p, &noise, w, h, 9, 0, j).unwrap();
        assert!(walk.start.0 >= w / 2, "start {:?}", walk.start);
        assert_eq!(walk.brightness, 1.0);
    }
    // Noise 0.25 on the left, 0.75 on the right: about 3× as many starts on the right.
    let noise: Vec<f32> = (0..w * h)
        .map(|i| if i % w >= w / 2 { 0.75 } else { 0.25 })
        .collect();
    let right = (0..4000)
        .filter(|&j| fiber_walk(&p, &noise, w, h, 9, 0, j).unwrap().start.0 >= w / 2)
        .count() as f32;
    let share = right / 4000.0;
    assert!((share - 0.75).abs() < 0.03, "share on the right {share}");
    // No start possible: the fibre is left out.
    assert!(fiber_walk(&p, &vec![0.0; (w * h) as usize], w, h, 9, 0, 0).is_none());
}

/// Serial reference: composite the walks' trails in fibre order, straight from the definition.
fn reference_texture(
    p: &FiberParams,
    noise: &[f32],
    w: u32,
    h: u32,
    seed: u64,
    shell: u32,
    count: u32,
) -> (Vec<f32>, Vec<f32>) {
    let mut lum = vec![0.0f32; (w * h) as usize];
    let mut alp = vec![0.0f32; (w * h) as usize];
    let a = p.fiber_opacity;
    for j in 0..count {
        let Some(walk) = fiber_walk(p, noise, w, h, seed, shell, j) else {
            continue;
        };
        let mut b = walk.brightness;
        for (t, (x, y)) in walk.texels(w, h).into_iter().enumerate() {
            if t > 0 {
                b *= 1.0 - p.fiber_decay;
            }
            let i = (y * w + x) as usize;
            lum[i] = a * b + (1.0 - a) * lum[i];
            alp[i] = a + (1.0 - a) * alp[i];
        }
    }
    (lum, alp)
}

#[test]
fn fiber_texture_matches_a_serial_composite_of_the_walks_and_wraps() {
    let (w, h) = (48u32, 200u32); // > one 64-row band, and fibres long enough to wrap
    let p = FiberParams {
        fiber_length: 120,
        ..params()
    };
    let noise = TileableNoise::new(1, 3.0, 3).texture(w, h);
    let tex = fiber_texture(&p, &noise, w, h, 21, 2, 150);
    let (lum, alp) = reference_texture(&p, &noise, w, h, 21, 2, 150);
    assert_eq!(tex.luminance, lum);
    assert_eq!(tex.alpha, alp);
    // Some walk crossed an edge (torus step) and the texture has ink on both sides of it.
    let mut wrapped = 0;
    for j in 0..150 {
        let walk = fiber_walk(&p, &noise, w, h, 21, 2, j).unwrap();
        let tx = walk.texels(w, h);
        for pair in tx.windows(2) {
            let (dx, dy) = (
                pair[1].0 as i64 - pair[0].0 as i64,
                pair[1].1 as i64 - pair[0].1 as i64,
            );
            let dx = if dx.abs() == w as i64 - 1 {
                -dx.signum()
            } else {
                dx
            };
            let dy = if dy.abs() == h as i64 - 1 {
                -dy.signum()
            } else {
                dy
            };
            assert!(
                dx.abs() <= 1 && dy.abs() <= 1 && (dx, dy) != (0, 0),
                "{pair:?}"
            );
            if (pair[1].0 as i64 - pair[0].0 as i64).abs() > 1
                || (pair[1].1 as i64 - pair[0].1 as i64).abs() > 1
            {
                wrapped += 1;
                for &(x, y) in pair {
                    assert!(tex.alpha[(y * w + x) as usize] > 0.0);
                }
            }
        }
    }
    assert!(wrapped > 10, "only {wrapped} wrapping steps");
}

#[test]
fn fibre_counts_decrease_upward_across_shells() {
    for (fibers, shells) in [(20_000u32, 32u32), (100, 7), (16, 16)] {
        let counts: Vec<u32> = (0..shells)
            .map(|i| shell_fiber_count(fibers, i, shells))
            .collect();
        assert_eq!(counts[0], fibers, "bottom shell is the densest");
        assert!(counts.windows(2).all(|c| c[1] < c[0]), "{counts:?}");
        assert!(*counts.last().unwrap() >= 1);
    }
    let p = params();
    let noise = TileableNoise::new(2, 4.0, 4).texture(64, 64);
    let texs = shell_textures(&p, &noise, 64, 64, 4, 6);
    assert_eq!(texs.len(), 6);
    let cover: Vec<f32> = texs.iter().map(|t| t.alpha.iter().sum()).collect();
    assert!(cover.windows(2).all(|c| c[1] < c[0]), "{cover:?}");
}

#[test]
fn fiber_textures_are_the_same_bytes_across_thread_counts() {
    let p = FiberParams {
        fibers: 3000,
        ..params()
    };
    let noise = TileableNoise::new(5, 4.0, 5).texture(256, 256);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let n = TileableNoise::new(5, 4.0, 5).texture(256, 256);
                let t = shell_textures(&p, &n, 256, 256, 77, 3);
                (n, t)
            })
    };
    let (n1, t1) = run(1);
    let (n3, t3) = run(3);
    assert_eq!(n1, noise);
    assert_eq!(n1, n3);
    for (a, b) in t1.iter().zip(&t3) {
        assert_eq!(a.to_rgba8([255; 3]), b.to_rgba8([255; 3]));
        assert_eq!(a, b);
    }
}

#[test]
fn golden_fiber_texture() {
    let (w, h) = (256u32, 256u32);
    let p = FiberParams {
        fibers: 1500,
        ..FiberParams::default()
    };
    let noise = TileableNoise::new(42, 4.0, 5).texture(w, h);
    let tex = fiber_texture(&p, &noise, w, h, 42, 0, p.fibers);
    let img = RgbaImage {
        width: w,
        height: h,
        data: tex.to_rgba8([232, 224, 210]),
    };
    assert_golden("dust", "fibers", &img, 2, 0.002);
}

// ---------------------------------------------------------------------------------------------
// The noise field on a coarse grid, the surface, the mapping and the texture pyramid

#[test]
fn the_coarse_noise_field_matches_direct_evaluation() {
    // 512² at scale 4 with 5 octaves: a 256² grid, interpolated.
    let n = TileableNoise::new(5, 4.0, 5);
    let t = n.texture(512, 512);
    let (mut worst, mut sum, mut count) = (0.0f32, 0.0f32, 0);
    for y in (0..512).step_by(7) {
        for x in (0..512).step_by(5) {
            let direct = n.sample((x as f64 + 0.5) / 512.0, (y as f64 + 0.5) / 512.0);
            let d = (t[y * 512 + x] - direct).abs();
            worst = worst.max(d);
            sum += d;
            count += 1;
        }
    }
    let mean = sum / count as f32;
    assert!(worst < 0.03 && mean < 0.005, "worst {worst}, mean {mean}");
    // Where the grid would be as fine as the texture, it is the direct evaluation exactly.
    let small = n.texture(64, 64);
    assert_eq!(small[10 * 64 + 3], n.sample(3.5 / 64.0, 10.5 / 64.0));
}

/// A unit cube with 8 shared corners (no normals), counter-clockwise from outside.
fn shared_cube() -> Mesh {
    let mut m = Mesh::default();
    for i in 0..8u32 {
        m.positions
            .push([(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32]);
    }
    // (x, y, z) bit order: 1 = x, 2 = y, 4 = z.
    for q in [
        [0u32, 2, 3, 1], // z = 0, normal −z
        [4, 5, 7, 6],    // z = 1, +z
        [0, 1, 5, 4],    // y = 0, −y
        [2, 6, 7, 3],    // y = 1, +y
        [0, 4, 6, 2],    // x = 0, −x
        [1, 3, 7, 5],    // x = 1, +x
    ] {
        m.triangles.push([q[0], q[1], q[2]]);
        m.triangles.push([q[0], q[2], q[3]]);
    }
    m
}

#[test]
fn creases_split_vertices_and_smooth_surfaces_keep_them() {
    let cube = shared_cube();
    let (m, n) = crease_split(&cube, [0.0, 1.0, 0.0]);
    assert_eq!(m.positions.len(), 24, "each corner once per face");
    for (t, tri) in m.triangles.iter().enumerate() {
        let f = cube.face_normal(t);
        let l = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        for (c, &v) in tri.iter().enumerate() {
            for k in 0..3 {
                assert!((n[v as usize][k] - f[k] / l).abs() < 1e-6);
            }
            // Same place as the corner it was split from.
            let orig = cube.triangles[t][c] as usize;
            assert_eq!(m.positions[v as usize], cube.positions[orig]);
        }
    }
    // The top's D is exactly K (its corners' normals are the top's own, not 45° off).
    let d = dust_amount(&m, &model(1.0, 2.0));
    for (v, p) in m.positions.iter().enumerate() {
        if p[1] == 1.0 && n[v][1] > 0.5 {
            assert!((d[v] - 1.0).abs() < 1e-6, "top corner D = {}", d[v]);
        }
    }
    // A floor wound facing down (as in the Inventor scenes) is a sheet: dust lies on its upper
    // side. A closed piece wound inside out is turned back; its underside stays dust-free.
    let up = [0.0, 1.0, 0.0];
    let (_, n) = crease_split(&tilted_square(std::f32::consts::PI), up);
    assert!(n.iter().all(|v| (v[1] - 1.0).abs() < 1e-5), "{n:?}");
    let mut inside_out = shared_cube();
    for t in &mut inside_out.triangles {
        t.swap(1, 2);
    }
    let (m, n) = crease_split(&inside_out, up);
    for (p, v) in m.positions.iter().zip(&n) {
        if v[1].abs() > 0.5 {
            assert_eq!(v[1] > 0.0, p[1] == 1.0, "{p:?} {v:?}");
        }
    }
    // An open cylinder of 36 facets (10° apart) is one smooth surface: no vertex is split, and
    // the normals point away from the axis.
    let mut cyl = Mesh::default();
    for i in 0..36 {
        let a = (i as f32 * 10.0).to_radians();
        cyl.positions.push([a.cos(), 0.0, a.sin()]);
        cyl.positions.push([a.cos(), 1.0, a.sin()]);
    }
    for i in 0..36u32 {
        let (b0, t0, b1, t1) = (2 * i, 2 * i + 1, (2 * i + 2) % 72, (2 * i + 3) % 72);
        cyl.triangles.push([b0, t0, t1]);
        cyl.triangles.push([b0, t1, b1]);
    }
    let (m, n) = crease_split(&cyl, [0.0, 1.0, 0.0]);
    assert_eq!(m.positions.len(), 72);
    for (p, nv) in m.positions.iter().zip(&n) {
        let radial = p[0] * nv[0] + p[2] * nv[2];
        assert!(radial.abs() > 0.999 && nv[1].abs() < 1e-5, "{p:?} {nv:?}");
    }
}

#[test]
fn mapping_rescales_uvs_and_blends_three_planes() {
    // A 2 m square with UVs 0–1: 2 m per UV unit; tiles of 0.5 m → UVs × 4.
    let mut sq = tilted_square(0.0);
    for p in &mut sq.positions {
        *p = p.map(|c| c * 2.0);
    }
    sq.uvs = Some(vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]);
    match Mapping::new(&sq, 0.5) {
        Mapping::Uv { uvs } => {
            assert!((uvs[2][0] - 4.0).abs() < 1e-4 && (uvs[2][1] - 4.0).abs() < 1e-4);
        }
        m => panic!("expected UV mapping, got {m:?}"),
    }
    // Collapsed UVs carry no texture: tri-planar.
    sq.uvs = Some(vec![[0.5, 0.5]; 4]);
    assert!(matches!(Mapping::new(&sq, 0.5), Mapping::Triplanar { .. }));
    // Tri-planar: weights sum to 1; an axis-aligned normal takes its own plane alone.
    let l = triplanar([0.3, 0.7, 0.1], [0.0, 1.0, 0.0]);
    assert_eq!(l.count, 1);
    assert_eq!(l.st[0], [0.3, 0.1]);
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let l = triplanar([0.3, 0.7, 0.1], [s, s, 0.0]);
    assert_eq!(l.count, 2);
    assert!((l.weight[0] - 0.5).abs() < 1e-6 && (l.weight[1] - 0.5).abs() < 1e-6);
    // Box UVs: every cube corner is split once per face plane (3 planes × 8 corners).
    let cube = shared_cube();
    let (src, uvs, tris) = box_uvs(&cube.positions, &cube.triangles, [0.0; 3], 1.0);
    assert_eq!(src.len(), 24);
    assert_eq!(uvs.len(), 24);
    assert_eq!(tris.len(), 12);
    for (t, tri) in tris.iter().enumerate() {
        for (c, &v) in tri.iter().enumerate() {
            assert_eq!(src[v as usize], cube.triangles[t][c]);
        }
    }
}

#[test]
fn the_mip_pyramid_keeps_the_mean_and_sampling_wraps() {
    let p = FiberParams {
        fibers: 800,
        ..params()
    };
    let noise = TileableNoise::new(4, 4.0, 4).texture(96, 96);
    let tex = fiber_texture(&p, &noise, 96, 96, 1, 0, p.fibers);
    let st = ShellTexture::new(&tex);
    // 96 → 48 → 24 → 12 → 6 → 3 → 2 → 1.
    assert_eq!(st.levels(), 8);
    let mean = tex.alpha.iter().sum::<f32>() / tex.alpha.len() as f32;
    let (_, top) = st.sample(0.3, 0.6, 7.0);
    // Rounding per level and the odd sizes' wrapped pairs: within 2 %.
    assert!(
        (top - mean).abs() < 0.02 + 0.02 * mean,
        "top {top}, mean {mean}"
    );
    // At a texel centre of level 0, the sample is the texel (quantised to 8 bits).
    let (x, y) = (17usize, 40usize);
    let (l, a) = st.sample((x as f32 + 0.5) / 96.0, (y as f32 + 0.5) / 96.0, 0.0);
    assert!((a - tex.alpha[y * 96 + x]).abs() <= 0.5 / 255.0 + 1e-6);
    assert!((l - tex.luminance[y * 96 + x]).abs() <= 0.5 / 255.0 + 1e-6);
    // Period 1 in both coordinates, at every level.
    for level in [0.0, 1.5, 3.0] {
        let a = st.sample(0.123, 0.877, level);
        let b = st.sample(2.123, -1.123, level);
        assert!((a.0 - b.0).abs() < 1e-4 && (a.1 - b.1).abs() < 1e-4);
    }
}

#[test]
fn refining_splits_long_edges_and_lets_d_vary_under_an_overhang() {
    // A 4 m floor of two triangles with a 1 m roof slab above its middle: unrefined, the floor
    // has D at its 4 open corners only; refined, the floor under the roof gets less.
    let mut m = Mesh::default();
    push_quad(
        &mut m,
        [
            [-2.0, 0.0, -2.0],
            [-2.0, 0.0, 2.0],
            [2.0, 0.0, 2.0],
            [2.0, 0.0, -2.0],
        ],
    );
    push_quad(
        &mut m,
        [
            [-0.5, 0.3, -0.5],
            [-0.5, 0.3, 0.5],
            [0.5, 0.3, 0.5],
            [0.5, 0.3, -0.5],
        ],
    );
    m.uvs = Some([[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]].repeat(2));
    m.parts = vec![
        phenomena_engine::geom::mesh::MeshPart {
            name: "floor".into(),
            first_triangle: 0,
            triangle_count: 2,
            base_color: [0.5, 0.5, 0.5, 1.0],
            texture: None,
        },
        phenomena_engine::geom::mesh::MeshPart {
            name: "roof".into(),
            first_triangle: 2,
            triangle_count: 2,
            base_color: [0.5, 0.5, 0.5, 1.0],
            texture: None,
        },
    ];
    let (mut r, mut n) = crease_split(&m, [0.0, 1.0, 0.0]);
    refine(&mut r, &mut n);
    let (lo, hi) = r.bounds().unwrap();
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt();
    for t in &r.triangles {
        for e in 0..3 {
            let (a, b) = (
                r.positions[t[e] as usize],
                r.positions[t[(e + 1) % 3] as usize],
            );
            let l = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f32>().sqrt();
            assert!(l <= diag / 48.0 + 1e-5, "edge {l}");
        }
    }
    assert_eq!(n.len(), r.positions.len());
    assert_eq!(r.uvs.as_ref().unwrap().len(), r.positions.len());
    // UVs interpolate: a floor vertex at (x, z) has uv ((x + 2)/4, (z + 2)/4); check the one
    // made at the floor's centre (the midpoint of its diagonal).
    let uv = r.uvs.as_ref().unwrap();
    let k = r
        .positions
        .iter()
        .position(|p| p[1] == 0.0 && (p[0] - 0.0).abs() < 1e-6 && (p[2] - 0.0).abs() < 1e-6)
        .expect("a vertex at the floor's centre");
    assert!((uv[k][0] - 0.5).abs() < 1e-6 && (uv[k][1] - 0.5).abs() < 1e-6);
    let d = dust_amount(&r, &model(1.0, 2.0));
    let at = |x: f32, z: f32| {
        let i = r
            .positions
            .iter()
            .enumerate()
            .filter(|(_, p)| p[1] == 0.0)
            .min_by(|a, b| {
                let da = (a.1[0] - x).powi(2) + (a.1[2] - z).powi(2);
                let db = (b.1[0] - x).powi(2) + (b.1[2] - z).powi(2);
                da.total_cmp(&db)
            })
            .unwrap()
            .0;
        d[i]
    };
    assert!(
        at(0.0, 0.0) < 0.5 * at(-1.9, -1.9),
        "under {} open {}",
        at(0.0, 0.0),
        at(-1.9, -1.9)
    );
    // Parts still tile the triangles.
    assert_eq!(
        r.parts.iter().map(|p| p.triangle_count).sum::<usize>(),
        r.triangles.len()
    );
}
