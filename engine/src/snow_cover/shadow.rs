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
const MAX_BIAS_TAN: f32 = 8.0;

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

/// `floor` without a libm call (x86-64 without SSE4.1 has no rounding instruction); exact for
/// |x| < 2³¹.
#[inline]
fn ffloor(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

#[inline]
fn fceil(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t < x {
        t + 1.0
    } else {
        t
    }
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
        let (xmax_f, ymax_f) = (wd as f32 - 1.0, ht as f32 - 1.0);
        let proj = &self.proj;
        let depth = &mut self.depth;
        for tri in &mesh.triangles {
            let a = proj[tri[0] as usize];
            let b = proj[tri[1] as usize];
            let c = proj[tri[2] as usize];
            let x0 = fceil(a[0].min(b[0]).min(c[0])).max(0.0);
            let x1 = ffloor(a[0].max(b[0]).max(c[0])).min(xmax_f);
            if x0 > x1 {
                continue;
            }
            let y0 = fceil(a[1].min(b[1]).min(c[1])).max(0.0);
            let y1 = ffloor(a[1].max(b[1]).max(c[1])).min(ymax_f);
            if y0 > y1 {
                continue;
            }
            let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            if area.abs() < 1e-12 {
                continue;
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
            const E: f32 = -1e-5;
            for y in y0 as usize..=y1 as usize {
                let yf = y as f32;
                let (r0, r1, r2) = (b0 * yf + c0, b1 * yf + c1, b2 * yf + c2);
                let rz = dzy * yf + dzc;
                let row = &mut depth[y * wd..(y + 1) * wd];
                for (x, d) in row
                    .iter_mut()
                    .enumerate()
                    .take(x1 as usize + 1)
                    .skip(x0 as usize)
                {
                    let xf = x as f32;
                    if a0 * xf + r0 >= E && a1 * xf + r1 >= E && a2 * xf + r2 >= E {
                        let z = dzx * xf + rz;
                        if z > *d {
                            *d = z;
                        }
                    }
                }
            }
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
