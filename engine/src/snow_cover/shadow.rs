//! Orthographic shadow maps along a snowfall direction (journal §2.2.1 and §2.2.3 (1)–(2),
//! Fig. 3 and 5: "the direction of snowfall is the direction of the light").
//!
//! The scene is projected along the snowfall direction onto a plane perpendicular to it and
//! z-buffered, keeping per texel the *highest* depth along `w` (the unit vector pointing back up
//! the snowfall, toward where the snow comes from): the surface the falling snow meets first. All
//! triangles count, whatever their facing (a roof's underside shades as much as its top). A point
//! is in shadow when the map holds a depth above the point's own by more than a bias.
//!
//! A small depth-only rasteriser (not the general one in `render::raster`): texel centres are
//! sampled with inclusive edge tests (shared edges are drawn twice, which is harmless for a max and
//! leaves no cracks for snow to leak through); depth is interpolated with the triangle's plane
//! equation. Triangles seen edge-on cover nothing (a vertical wall casts no shadow on vertical
//! snowfall). Texel size = the snow maps' cell, so a map covers the scene's bounds projected
//! along the direction (at most [`MAX_SHADOW_DIM`] texels a side; beyond, texels grow).
//!
//! **Bias** (see [`ShadowMap::bias`]): a receiver point lies up to 0.71 texel from the texel centre
//! whose depth stands for it, so its own surface may read up to `0.71 · texel · tan α` above it
//! (α = angle between the surface normal and `w`, capped at 8 ≈ 83°). The bias is that plus a tenth
//! of a texel and `1e-5 ×` the scene's diagonal for rounding.
//!
//! Cost: one projection per vertex and one bounding box per triangle; per covered texel a few
//! multiply-adds. No allocation once the buffers have grown ([`ShadowMap::render`] reuses them).

use crate::geom::mesh::Mesh;

/// Largest shadow-map side, texels.
pub const MAX_SHADOW_DIM: usize = 4096;
/// Cap on `tan α` in the slope-scaled bias.
pub const MAX_BIAS_TAN: f32 = 8.0;

/// A depth-only orthographic shadow map (see the module doc).
#[derive(Debug, Clone, Default)]
pub struct ShadowMap {
    /// Basis: `u`, `t` span the map plane, `w` points up the snowfall (unit vectors).
    pub u: [f32; 3],
    pub t: [f32; 3],
    pub w: [f32; 3],
    /// Texel side, metres.
    pub texel: f32,
    /// Map-plane coordinates of the map's corner.
    pub u0: f32,
    pub t0: f32,
    pub width: usize,
    pub height: usize,
    /// `width × height` highest depths along `w`; `-∞` where nothing was drawn.
    pub depth: Vec<f32>,
    /// Scratch: per-vertex (grid x, grid y, depth).
    proj: Vec<[f32; 3]>,
}

#[inline]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = dot(a, a).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

impl ShadowMap {
    /// Render `mesh` along snowfall direction `dir` (unit vector pointing where the snow goes,
    /// downward) with texels of `texel` metres, over `bounds` (the mesh's bounding box).
    pub fn render(&mut self, mesh: &Mesh, dir: [f32; 3], bounds: ([f32; 3], [f32; 3]), texel: f32) {
        let w = normalize([-dir[0], -dir[1], -dir[2]]);
        let a = if w[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 0.0, 1.0]
        };
        let aw = dot(a, w);
        let u = normalize([a[0] - aw * w[0], a[1] - aw * w[1], a[2] - aw * w[2]]);
        let t = [
            w[1] * u[2] - w[2] * u[1],
            w[2] * u[0] - w[0] * u[2],
            w[0] * u[1] - w[1] * u[0],
        ];
        let (lo, hi) = bounds;
        let (mut umin, mut umax, mut tmin, mut tmax) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
        for k in 0..8 {
            let p = [
                if k & 1 == 0 { lo[0] } else { hi[0] },
                if k & 2 == 0 { lo[1] } else { hi[1] },
                if k & 4 == 0 { lo[2] } else { hi[2] },
            ];
            let (pu, pt) = (dot(p, u), dot(p, t));
            umin = umin.min(pu);
            umax = umax.max(pu);
            tmin = tmin.min(pt);
            tmax = tmax.max(pt);
        }
        let mut texel = texel.max(1e-9);
        let span = (umax - umin).max(tmax - tmin);
        if span / texel + 3.0 > MAX_SHADOW_DIM as f32 {
            texel = span / (MAX_SHADOW_DIM as f32 - 3.0);
        }
        self.u = u;
        self.t = t;
        self.w = w;
        self.texel = texel;
        self.u0 = umin - texel;
        self.t0 = tmin - texel;
        self.width = (((umax - umin) / texel).ceil() as usize + 2).min(MAX_SHADOW_DIM);
        self.height = (((tmax - tmin) / texel).ceil() as usize + 2).min(MAX_SHADOW_DIM);
        self.depth.clear();
        self.depth
            .resize(self.width * self.height, f32::NEG_INFINITY);

        // Project every vertex to grid coordinates (texel centres at integers).
        let inv = 1.0 / texel;
        let (gu0, gt0) = (self.u0 * inv + 0.5, self.t0 * inv + 0.5);
        let su = [u[0] * inv, u[1] * inv, u[2] * inv];
        let st = [t[0] * inv, t[1] * inv, t[2] * inv];
        self.proj.clear();
        self.proj.extend(
            mesh.positions
                .iter()
                .map(|&p| [dot(p, su) - gu0, dot(p, st) - gt0, dot(p, w)]),
        );
        let (wd, ht) = (self.width, self.height);
        let proj = &self.proj;
        let depth = &mut self.depth;
        for tri in &mesh.triangles {
            let a = proj[tri[0] as usize];
            let b = proj[tri[1] as usize];
            let c = proj[tri[2] as usize];
            raster_triangle(depth, wd, ht, a, b, c);
        }
    }

    /// Bias (metres) for a receiver with unit surface normal `n` (module doc); `extent` is the
    /// scene's diagonal.
    #[inline]
    pub fn bias(&self, n: [f32; 3], extent: f32) -> f32 {
        let c = dot(n, self.w).abs().max(1e-3);
        let tan = ((1.0 - c * c).max(0.0).sqrt() / c).min(MAX_BIAS_TAN);
        self.texel * (0.71 * tan + 0.1) + 1e-5 * extent
    }

    /// True when world point `p` is in shadow (something lies more than `bias` above it along
    /// `w`). Points outside the map are lit.
    #[inline]
    pub fn occluded(&self, p: [f32; 3], bias: f32) -> bool {
        let inv = 1.0 / self.texel;
        let gx = (dot(p, self.u) - self.u0) * inv - 0.5;
        let gy = (dot(p, self.t) - self.t0) * inv - 0.5;
        // Nearest texel; anything left of −0.5 is off the map (truncation would fold it onto 0).
        if gx < -0.5 || gy < -0.5 {
            return false;
        }
        let (x, y) = ((gx + 0.5) as usize as f32, (gy + 0.5) as usize as f32);
        if x >= self.width as f32 || y >= self.height as f32 {
            return false;
        }
        self.depth[y as usize * self.width + x as usize] > dot(p, self.w) + bias
    }
}

#[inline(always)]
fn min3(a: f32, b: f32, c: f32) -> f32 {
    let m = if b < a { b } else { a };
    if c < m {
        c
    } else {
        m
    }
}

#[inline(always)]
fn max3(a: f32, b: f32, c: f32) -> f32 {
    let m = if b > a { b } else { a };
    if c > m {
        c
    } else {
        m
    }
}

/// Tolerance of the inclusive edge tests (normalised barycentric units).
const EDGE_EPS: f32 = -1e-5;

/// Draw one projected triangle (grid x, grid y, depth per corner; texel centres at integers) into
/// the `wd × ht` max-depth buffer `depth` (module doc).
///
/// Most triangles of a fine mesh cover a texel or two (1 M triangles on a 1024² map: about one
/// texel each), so their cost is the setup and the branches, not the texels. A triangle whose
/// bounding box holds at most 2 × 2 texel centres is drawn branch-free: the four candidate centres
/// are always tested, the ones outside the box or the triangle masked off (they write back the
/// value they read), which avoids two data-dependent branches per triangle (box empty? centre
/// inside?) that mispredict about half the time. Larger triangles take the loop. Both evaluate
/// the same expressions, so the depths are the same bits either way.
#[inline(always)]
fn raster_triangle(depth: &mut [f32], wd: usize, ht: usize, a: [f32; 3], b: [f32; 3], c: [f32; 3]) {
    // Texel range of the bounding box, in integers (grid coordinates lie in [0, MAX_SHADOW_DIM],
    // the vertices being inside the bounds the map was fitted to).
    let (xmax, ymax) = (wd as i32 - 1, ht as i32 - 1);
    let x0 = iceil(min3(a[0], b[0], c[0])).max(0);
    let x1 = ifloor(max3(a[0], b[0], c[0])).min(xmax);
    let y0 = iceil(min3(a[1], b[1], c[1])).max(0);
    let y1 = ifloor(max3(a[1], b[1], c[1])).min(ymax);
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    let small = x1 <= x0.saturating_add(1) && y1 <= y0.saturating_add(1);
    if !small && (x0 > x1 || y0 > y1 || area.abs() < 1e-12) {
        return;
    }
    let ia = 1.0 / area;
    // Normalised edge functions e_k(x, y) = A_k x + B_k y + C_k, ≥ 0 inside.
    let e = |p: [f32; 3], q: [f32; 3]| {
        let aa = (p[1] - q[1]) * ia;
        let bb = (q[0] - p[0]) * ia;
        let cc = (p[0] * q[1] - p[1] * q[0]) * ia;
        (aa, bb, cc)
    };
    let (a0, b0, c0) = e(b, c); // weight of a
    let (a1, b1, c1) = e(c, a); // weight of b
    let (a2, b2, c2) = e(a, b); // weight of c
    // Depth plane: z = a.z w0 + b.z w1 + c.z w2.
    let dzx = a[2] * a0 + b[2] * a1 + c[2] * a2;
    let dzy = a[2] * b0 + b[2] * b1 + c[2] * b2;
    let dzc = a[2] * c0 + b[2] * c1 + c[2] * c2;
    if small {
        // The 2 × 2 candidate centres (x0 + dx, y0 + dy), evaluated four at a time.
        let ok = area.abs() >= 1e-12;
        let (xf0, yf0) = (x0 as f32, y0 as f32);
        let xs = [xf0, xf0 + 1.0, xf0, xf0 + 1.0];
        let ys = [yf0, yf0, yf0 + 1.0, yf0 + 1.0];
        let mut z = [0f32; 4];
        let mut inside = [false; 4];
        for q in 0..4 {
            let (xf, yf) = (xs[q], ys[q]);
            let e0 = a0 * xf + (b0 * yf + c0);
            let e1 = a1 * xf + (b1 * yf + c1);
            let e2 = a2 * xf + (b2 * yf + c2);
            z[q] = dzx * xf + (dzy * yf + dzc);
            inside[q] = (e0 >= EDGE_EPS) & (e1 >= EDGE_EPS) & (e2 >= EDGE_EPS);
        }
        let xi = [x0.min(xmax), x0.saturating_add(1).min(xmax)];
        let yi = [y0.min(ymax), y0.saturating_add(1).min(ymax)];
        let xin = [x0 <= x1, x0 < x1];
        let yin = [y0 <= y1, y0 < y1];
        for q in 0..4 {
            let (dx, dy) = (q & 1, q >> 1);
            let m = ok & inside[q] & xin[dx] & yin[dy];
            let idx = yi[dy] as usize * wd + xi[dx] as usize;
            if let Some(d) = depth.get_mut(idx) {
                *d = if m & (z[q] > *d) { z[q] } else { *d };
            }
        }
        return;
    }
    let (xa, xb) = (x0 as usize, x1 as usize);
    for y in y0 as usize..=y1 as usize {
        let yf = y as f32;
        let (r0, r1, r2) = (b0 * yf + c0, b1 * yf + c1, b2 * yf + c2);
        let rz = dzy * yf + dzc;
        let Some(row) = depth.get_mut(y * wd + xa..=y * wd + xb) else {
            return;
        };
        for (k, d) in row.iter_mut().enumerate() {
            let xf = (xa + k) as f32;
            if a0 * xf + r0 >= EDGE_EPS && a1 * xf + r1 >= EDGE_EPS && a2 * xf + r2 >= EDGE_EPS {
                let z = dzx * xf + rz;
                if z > *d {
                    *d = z;
                }
            }
        }
    }
}

/// `⌈x⌉` as an integer (exact for |x| < 2³¹; saturates beyond).
#[inline(always)]
fn iceil(x: f32) -> i32 {
    let t = x as i32;
    t.saturating_add(i32::from((t as f32) < x))
}

/// `⌊x⌋` as an integer (exact for |x| < 2³¹; saturates beyond).
#[inline(always)]
fn ifloor(x: f32) -> i32 {
    let t = x as i32;
    t.saturating_sub(i32::from((t as f32) > x))
}
