//! Triangle set-up: project a mesh triangle, clip it against the near plane and the guard band
//! (Sutherland–Hodgman in camera space, then a fan), snap it to 1/256 pixel and build its integer
//! edge functions with the top-left fill rule.

use super::projection::Projection;

/// Fixed-point sub-pixel precision: vertices and sample positions snap to 1/256 pixel.
pub(super) const SUB: f64 = 256.0;
/// "No triangle" in a visibility buffer.
pub const NO_TRI: u32 = u32::MAX;

/// A projected, clipped and snapped triangle: vertices in 1/256 pixel, counter-clockwise on
/// screen in the y-down sense (positive edge functions inside).
#[derive(Debug, Clone, Copy)]
pub(super) struct ScreenTri {
    pub(super) v: [[i32; 2]; 3],
    /// 1/z per vertex.
    pub(super) w: [f64; 3],
    pub(super) src: u32,
    /// Index into `Rasterizer::clipped` (barycentrics of the vertices in the source triangle),
    /// or `NO_TRI` when the vertices are the source's own, in order `perm`.
    pub(super) clip: u32,
    pub(super) perm: [u8; 3],
    /// Pixel bounding box (inclusive), x0, x1, y0, y1.
    pub(super) bb: [i32; 4],
}

/// Per-vertex projection.
#[derive(Debug, Clone, Copy)]
pub(super) struct PVert {
    pub(super) c: [f64; 3],
    /// Bit k set when the vertex is outside clip plane k; 0xFF when non-finite.
    pub(super) out: u8,
    /// Snapped screen position (valid when `out == 0`).
    pub(super) s: [i32; 2],
}

#[inline]
pub(super) fn plane(p: &[f64; 4], c: [f64; 3]) -> f64 {
    p[0] * c[0] + p[1] * c[1] + p[2] * c[2] + p[3]
}

#[inline]
pub(super) fn snap((x, y): (f64, f64)) -> [i32; 2] {
    [(x * SUB).round() as i32, (y * SUB).round() as i32]
}

#[inline]
pub(super) fn snap1(o: f64) -> i64 {
    ((o * SUB).round() as i64).clamp(0, SUB as i64 - 1)
}

/// Integer edge functions `E_k = a·x + b·y + c` (edge k opposite vertex k), top-left bias
/// folded into `c` (`E ≥ 0` inside), and `bias` to undo it for interpolation.
pub(super) struct Edges {
    pub(super) a: [i64; 3],
    pub(super) b: [i64; 3],
    pub(super) c: [i64; 3],
    pub(super) bias: [i64; 3],
    pub(super) area2: i64,
}

#[inline]
pub(super) fn edges(t: &ScreenTri) -> Edges {
    let v = |k: usize| (i64::from(t.v[k][0]), i64::from(t.v[k][1]));
    let mut e = Edges {
        a: [0; 3],
        b: [0; 3],
        c: [0; 3],
        bias: [0; 3],
        area2: 0,
    };
    for k in 0..3 {
        let (ax, ay) = v((k + 1) % 3);
        let (bx, by) = v((k + 2) % 3);
        let (dx, dy) = (bx - ax, by - ay);
        // E(p) = dx·(py − ay) − dy·(px − ax)
        e.a[k] = -dy;
        e.b[k] = dx;
        e.c[k] = dy * ax - dx * ay;
        // Top edge (horizontal, pointing right) or left edge (pointing up, y down).
        let top_left = (dy == 0 && dx > 0) || dy < 0;
        if !top_left {
            e.c[k] -= 1;
            e.bias[k] = 1;
        }
    }
    let (x0, y0) = v(0);
    e.area2 = e.a[0] * x0 + e.b[0] * y0 + e.c[0] + e.bias[0];
    e
}

/// A clip-space polygon vertex: camera-space position and barycentrics in the source triangle.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct CVert {
    pub(super) c: [f64; 3],
    pub(super) b: [f64; 3],
}

/// Project, clip and snap mesh triangle `t` (index `src`), appending 0..=7 screen triangles.
#[allow(clippy::too_many_arguments)]
pub(super) fn setup(
    proj: &Projection,
    planes: &[[f64; 4]; 5],
    pv: &[PVert],
    t: &[u32; 3],
    src: u32,
    tris: &mut Vec<ScreenTri>,
    clipped: &mut Vec<[[f64; 3]; 3]>,
) {
    let (Some(a), Some(b), Some(c)) = (
        pv.get(t[0] as usize),
        pv.get(t[1] as usize),
        pv.get(t[2] as usize),
    ) else {
        return;
    };
    if (a.out | b.out | c.out) == 0xFF || a.out == 0xFF || b.out == 0xFF || c.out == 0xFF {
        return;
    }
    if a.out & b.out & c.out != 0 {
        return; // all outside one plane
    }
    if a.out | b.out | c.out == 0 {
        push_tri(
            [a.s, b.s, c.s],
            [a.c[2], b.c[2], c.c[2]],
            src,
            None,
            tris,
            clipped,
        );
        return;
    }
    // Sutherland–Hodgman against the planes a vertex violates.
    let mut poly = [CVert::default(); 9];
    let mut tmp = [CVert::default(); 9];
    poly[0] = CVert {
        c: a.c,
        b: [1.0, 0.0, 0.0],
    };
    poly[1] = CVert {
        c: b.c,
        b: [0.0, 1.0, 0.0],
    };
    poly[2] = CVert {
        c: c.c,
        b: [0.0, 0.0, 1.0],
    };
    let mut n = 3;
    let any = a.out | b.out | c.out;
    for (k, pl) in planes.iter().enumerate() {
        if any & (1 << k) == 0 {
            continue;
        }
        let mut m = 0;
        for i in 0..n {
            let (p, q) = (poly[i], poly[(i + 1) % n]);
            let (dp, dq) = (plane(pl, p.c), plane(pl, q.c));
            if dp >= 0.0 {
                tmp[m] = p;
                m += 1;
            }
            if (dp >= 0.0) != (dq >= 0.0) {
                let s = dp / (dp - dq);
                let lerp = |u: [f64; 3], v: [f64; 3]| {
                    [
                        u[0] + (v[0] - u[0]) * s,
                        u[1] + (v[1] - u[1]) * s,
                        u[2] + (v[2] - u[2]) * s,
                    ]
                };
                tmp[m] = CVert {
                    c: lerp(p.c, q.c),
                    b: lerp(p.b, q.b),
                };
                m += 1;
            }
        }
        n = m;
        poly[..n].copy_from_slice(&tmp[..n]);
        if n < 3 {
            return;
        }
    }
    for i in 1..n - 1 {
        let vs = [poly[0], poly[i], poly[i + 1]];
        let s = vs.map(|v| snap(proj.screen(v.c)));
        push_tri(
            s,
            vs.map(|v| v.c[2]),
            src,
            Some(vs.map(|v| v.b)),
            tris,
            clipped,
        );
    }
}

pub(super) fn push_tri(
    mut s: [[i32; 2]; 3],
    z: [f64; 3],
    src: u32,
    bary: Option<[[f64; 3]; 3]>,
    tris: &mut Vec<ScreenTri>,
    clipped: &mut Vec<[[f64; 3]; 3]>,
) {
    let area = |s: &[[i32; 2]; 3]| {
        let (x0, y0) = (i64::from(s[0][0]), i64::from(s[0][1]));
        (i64::from(s[1][0]) - x0) * (i64::from(s[2][1]) - y0)
            - (i64::from(s[1][1]) - y0) * (i64::from(s[2][0]) - x0)
    };
    let a2 = area(&s);
    if a2 == 0 {
        return;
    }
    let mut perm = [0u8, 1, 2];
    let mut w = [1.0 / z[0], 1.0 / z[1], 1.0 / z[2]];
    let mut bary = bary;
    if a2 < 0 {
        s.swap(1, 2);
        perm.swap(1, 2);
        w.swap(1, 2);
        if let Some(b) = bary.as_mut() {
            b.swap(1, 2);
        }
    }
    let clip = match bary {
        Some(b) => {
            clipped.push(b);
            (clipped.len() - 1) as u32
        }
        None => NO_TRI,
    };
    let bb = [
        s[0][0].min(s[1][0]).min(s[2][0]) >> 8,
        s[0][0].max(s[1][0]).max(s[2][0]) >> 8,
        s[0][1].min(s[1][1]).min(s[2][1]) >> 8,
        s[0][1].max(s[1][1]).max(s[2][1]) >> 8,
    ];
    tris.push(ScreenTri {
        v: s,
        w,
        src,
        clip,
        perm,
        bb,
    });
}
