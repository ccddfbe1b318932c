#![allow(clippy::unwrap_used)]

use super::*;
use crate::geom::camera::Camera;

/// Eye at the origin looking down −Z, 90° fov, 200 × 200: world (x, y, −1) lands on pixel
/// (100·(x + 1), 100·(1 − y)).
fn proj() -> Projection {
    let cam = Camera {
        eye: [0.0; 3],
        target: [0.0, 0.0, -1.0],
        up: [0.0, 1.0, 0.0],
        fov_deg: 90.0,
    };
    Projection::new(&cam, 200, 200, 1e-3)
}

/// Centre-sample visibility of the whole image: screen-triangle id per pixel.
fn coverage(pos: &[[f64; 3]], tris: &[[u32; 3]]) -> (Rasterizer, Vec<u32>) {
    let r = Rasterizer::new(
        &Mesh {
            positions: pos,
            triangles: tris,
        },
        &proj(),
    );
    let mut out = Vec::new();
    let mut buf = VisBuffer::default();
    for b in 0..r.bands() {
        let (y0, y1) = (b * BAND, ((b + 1) * BAND).min(200));
        r.rasterize_band(b, y0, y1, &[(0.5, 0.5)], &mut buf);
        for y in y0..y1 {
            out.extend((0..200).map(|x| buf.at(0, x, y)));
        }
    }
    (r, out)
}

fn to_world(px: f64, py: f64) -> [f64; 3] {
    [px / 100.0 - 1.0, 1.0 - py / 100.0, -1.0]
}

#[test]
fn covered_pixels_match_area_and_shared_edges_are_watertight() {
    let mut seed = 12345u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 * 180.0 + 10.0
    };
    for _ in 0..50 {
        let q: Vec<(f64, f64)> = (0..4).map(|_| (rnd(), rnd())).collect();
        let pos: Vec<[f64; 3]> = q.iter().map(|&(x, y)| to_world(x, y)).collect();
        let area = |a: (f64, f64), b: (f64, f64), c: (f64, f64)| {
            ((b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)).abs() * 0.5
        };
        let per = |a: (f64, f64), b: (f64, f64), c: (f64, f64)| {
            let d =
                |p: (f64, f64), q: (f64, f64)| ((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt();
            d(a, b) + d(b, c) + d(c, a)
        };
        // Two triangles sharing the edge 0–2 (a quad that may be non-convex: then they overlap
        // and the check below is only on the area, so keep convex-or-not generic).
        let (_, a) = coverage(&pos, &[[0, 1, 2]]);
        let (_, b) = coverage(&pos, &[[2, 3, 0]]);
        let na = a.iter().filter(|&&t| t != NO_TRI).count() as f64;
        let nb = b.iter().filter(|&&t| t != NO_TRI).count() as f64;
        // Pixel-count error is bounded by about half the perimeter (+ 1 for rounding).
        let (ta, tb) = ((q[0], q[1], q[2]), (q[2], q[3], q[0]));
        assert!((na - area(ta.0, ta.1, ta.2)).abs() <= 0.5 * per(ta.0, ta.1, ta.2) + 1.0);
        assert!((nb - area(tb.0, tb.1, tb.2)).abs() <= 0.5 * per(tb.0, tb.1, tb.2) + 1.0);
        // The two triangles lie on opposite sides of the diagonal when the quad is convex:
        // then no pixel is covered twice and none on the diagonal is lost.
        let s =
            |p: (f64, f64)| (q[2].0 - q[0].0) * (p.1 - q[0].1) - (q[2].1 - q[0].1) * (p.0 - q[0].0);
        if s(q[1]) * s(q[3]) < 0.0 {
            let both = a
                .iter()
                .zip(&b)
                .filter(|(x, y)| **x != NO_TRI && **y != NO_TRI);
            assert_eq!(both.count(), 0, "a shared-edge pixel drawn twice");
            let (_, ab) = coverage(&pos, &[[0, 1, 2], [2, 3, 0]]);
            let nab = ab.iter().filter(|&&t| t != NO_TRI).count() as f64;
            assert_eq!(nab, na + nb, "a shared-edge pixel lost");
        }
    }
    // An axis-aligned 40 × 30 rectangle on pixel boundaries: exactly 1200 centres.
    let pos: Vec<[f64; 3]> = [(20.0, 50.0), (60.0, 50.0), (60.0, 80.0), (20.0, 80.0)]
        .iter()
        .map(|&(x, y)| to_world(x, y))
        .collect();
    let (_, c) = coverage(&pos, &[[0, 1, 2], [0, 2, 3]]);
    assert_eq!(c.iter().filter(|&&t| t != NO_TRI).count(), 1200);
}

#[test]
fn nearer_triangle_wins_in_either_order() {
    // Two overlapping triangles at z = −2 (far) and z = −1 (near).
    let pos = vec![
        [-1.0, -1.0, -2.0],
        [1.0, -1.0, -2.0],
        [0.0, 1.0, -2.0],
        [-0.25, -0.25, -1.0],
        [0.25, -0.25, -1.0],
        [0.0, 0.25, -1.0],
    ];
    for tris in [[[0, 1, 2], [3, 4, 5]], [[3, 4, 5], [0, 1, 2]]] {
        let (r, c) = coverage(&pos, &tris);
        let id = c[100 * 200 + 100];
        let f = r.fragment(id, 100.5, 100.5);
        assert_eq!(tris[f.triangle as usize], [3, 4, 5]);
        assert!((f.z - 1.0).abs() < 1e-9, "{}", f.z);
        // Outside the near one but inside the far one.
        let id = c[140 * 200 + 100];
        let f = r.fragment(id, 100.5, 140.5);
        assert_eq!(tris[f.triangle as usize], [0, 1, 2]);
        assert!((f.z - 2.0).abs() < 1e-9);
    }
}

#[test]
fn attributes_are_perspective_correct_on_a_tilted_quad() {
    // A quad from z = −1 (bottom) to z = −5 (top), partly behind the near plane's guard: the
    // interpolated world position must be the exact ray/plane intersection.
    let pos = vec![
        [-1.0, -0.5, -1.0],
        [1.0, -0.5, -1.0],
        [1.0, 1.5, -5.0],
        [-1.0, 1.5, -5.0],
    ];
    let tris = [[0u32, 1, 2], [0, 2, 3]];
    let (r, c) = coverage(&pos, &tris);
    let mut checked = 0;
    for py in (0..200).step_by(7) {
        for px in (0..200).step_by(5) {
            let id = c[py * 200 + px];
            if id == NO_TRI {
                continue;
            }
            let (x, y) = (px as f64 + 0.5, py as f64 + 0.5);
            let f = r.fragment(id, x, y);
            let t = tris[f.triangle as usize].map(|k| {
                let p = pos[k as usize];
                [p[0] as f32, p[1] as f32, p[2] as f32]
            });
            let p = f.interpolate(t);
            // Camera ray through (x, y): direction (x/100 − 1, 1 − y/100, −1). Plane of the
            // quad: y = −0.5 + (−1 − z)/2 ⇔ 2y + z + 2 = 0.
            let d = [x / 100.0 - 1.0, 1.0 - y / 100.0, -1.0];
            let s = -2.0 / (2.0 * d[1] + d[2]);
            for k in 0..3 {
                assert!(
                    (f64::from(p[k]) - s * d[k]).abs() < 1e-4,
                    "{p:?} vs {:?}",
                    d.map(|v| v * s)
                );
            }
            assert!((f.z - s).abs() < 1e-9);
            checked += 1;
        }
    }
    assert!(checked > 200, "{checked}");
}

#[test]
fn triangles_behind_the_eye_are_clipped() {
    // One vertex behind the camera: the visible part still interpolates correctly.
    let pos = vec![[-1.0, -0.5, -2.0], [1.0, -0.5, -2.0], [0.0, -0.5, 3.0]];
    let (r, c) = coverage(&pos, &[[0, 1, 2]]);
    let n = c.iter().filter(|&&t| t != NO_TRI).count();
    assert!(n > 1000, "{n}");
    let id = c[190 * 200 + 100];
    let f = r.fragment(id, 100.5, 190.5);
    let p = f.interpolate([[-1.0f32, -0.5, -2.0], [1.0, -0.5, -2.0], [0.0, -0.5, 3.0]]);
    // Ray through (100.5, 190.5) meets y = −0.5 at z = −0.5 / (1 − 1.905)·(−1)…
    let d = [0.005, 1.0 - 1.905, -1.0];
    let s = -0.5 / d[1];
    assert!((f64::from(p[2]) - s * d[2]).abs() < 1e-4, "{p:?}");
}
