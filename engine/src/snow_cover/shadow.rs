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

use multiversion::multiversion;

use crate::geom::mesh::Mesh;
use crate::geom::vec::{unit, Vec3};

#[inline]
fn dot(a: [f32; 3], b: Vec3) -> f32 {
    Vec3::from(a).dot(b)
}

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

impl ShadowMap {
    /// Render `mesh` along snowfall direction `dir` (unit vector pointing where the snow goes,
    /// downward) with texels of `texel` metres, over `bounds` (the mesh's bounding box).
    pub fn render(&mut self, mesh: &Mesh, dir: [f32; 3], bounds: ([f32; 3], [f32; 3]), texel: f32) {
        let w = Vec3::from(unit([-dir[0], -dir[1], -dir[2]]));
        let a = if w.x.abs() < 0.9 { Vec3::X } else { Vec3::Z };
        let u = Vec3::from(unit((a - w * a.dot(w)).to_array()));
        let t = w.cross(u);
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
        self.u = u.to_array();
        self.t = t.to_array();
        self.w = w.to_array();
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
        let (su, st) = (u * inv, t * inv);
        self.proj.clear();
        self.proj.extend(
            mesh.positions
                .iter()
                .map(|&p| [dot(p, su) - gu0, dot(p, st) - gt0, dot(p, w)]),
        );
        draw_triangles(
            &mut self.depth,
            self.width,
            self.height,
            &self.proj,
            &mesh.triangles,
        );
    }

    /// Bias (metres) for a receiver with unit surface normal `n` (module doc); `extent` is the
    /// scene's diagonal.
    #[inline]
    pub fn bias(&self, n: [f32; 3], extent: f32) -> f32 {
        let c = dot(n, self.w.into()).abs().max(1e-3);
        let tan = ((1.0 - c * c).max(0.0).sqrt() / c).min(MAX_BIAS_TAN);
        self.texel * (0.71 * tan + 0.1) + 1e-5 * extent
    }

    /// True when world point `p` is in shadow (something lies more than `bias` above it along
    /// `w`). Points outside the map are lit.
    #[inline]
    pub fn occluded(&self, p: [f32; 3], bias: f32) -> bool {
        let inv = 1.0 / self.texel;
        let gx = (dot(p, self.u.into()) - self.u0) * inv - 0.5;
        let gy = (dot(p, self.t.into()) - self.t0) * inv - 0.5;
        // Nearest texel; anything left of −0.5 is off the map (truncation would fold it onto 0).
        if gx < -0.5 || gy < -0.5 {
            return false;
        }
        let (x, y) = ((gx + 0.5) as usize as f32, (gy + 0.5) as usize as f32);
        if x >= self.width as f32 || y >= self.height as f32 {
            return false;
        }
        self.depth[y as usize * self.width + x as usize] > dot(p, self.w.into()) + bias
    }
}

/// Draws `triangles` (vertex indices into `proj`, the projected vertices) into the `wd × ht`
/// max-depth buffer, [`LANES`] at a time ([`raster_batch`]). Compiled for AVX2 too and chosen at
/// run time (the same operations in wider registers: the same bits).
#[multiversion(targets("x86_64+avx2"))]
fn draw_triangles(
    depth: &mut [f32],
    wd: usize,
    ht: usize,
    proj: &[[f32; 3]],
    triangles: &[[u32; 3]],
) {
    for tris in triangles.chunks(LANES) {
        let mut v = [[[0f32; LANES]; 3]; 3];
        for (q, tri) in tris.iter().enumerate() {
            for (k, &i) in tri.iter().enumerate() {
                let p = proj[i as usize];
                v[k][0][q] = p[0];
                v[k][1][q] = p[1];
                v[k][2][q] = p[2];
            }
        }
        raster_batch(depth, wd, ht, &v, tris.len());
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

/// Triangles set up together in [`raster_batch`].
const LANES: usize = 8;

/// Draw up to [`LANES`] projected triangles (`v[corner][axis][lane]`: grid x, grid y, depth;
/// texel centres at integers; the first `n` lanes used) into the `wd × ht` max-depth buffer
/// `depth` (module doc).
///
/// Most triangles of a fine mesh cover a texel or two (1 M triangles on a 1024² map: about one
/// texel each), so their cost is the setup and the branches, not the texels. The setup (bounding
/// box, edge functions, depth plane) and the tests of each triangle's 2 × 2 candidate texel
/// centres run lane-wise over the batch without branches, which the compiler turns into SIMD;
/// then the candidates inside their triangle and box are written, one lane at a time. A triangle
/// whose box holds more than 2 × 2 centres takes the texel loop instead. Every texel sees the same
/// expressions either way, and a max does not depend on the order of the triangles, so the depths
/// are the same bits as drawing the triangles one by one.
#[inline(always)]
fn raster_batch(depth: &mut [f32], wd: usize, ht: usize, v: &[[[f32; LANES]; 3]; 3], n: usize) {
    // Texel range of the bounding box, in integers (grid coordinates lie in [0, MAX_SHADOW_DIM],
    // the vertices being inside the bounds the map was fitted to).
    let (xmax, ymax) = ((wd as f32 - 1.0).max(0.0), (ht as f32 - 1.0).max(0.0));
    let wdf = wd as f32;
    let [a, b, c] = v;
    let mut x0 = [0f32; LANES];
    let mut x1 = [0f32; LANES];
    let mut y0 = [0f32; LANES];
    let mut y1 = [0f32; LANES];
    let mut ok = [false; LANES];
    // Edge-function and depth-plane coefficients per lane.
    let mut k = [[0f32; LANES]; 12];
    for q in 0..LANES {
        let (ax, ay, az) = (a[0][q], a[1][q], a[2][q]);
        let (bx, by, bz) = (b[0][q], b[1][q], b[2][q]);
        let (cx, cy, cz) = (c[0][q], c[1][q], c[2][q]);
        x0[q] = ceil_small(min3(ax, bx, cx)).max(0.0);
        x1[q] = floor_small(max3(ax, bx, cx)).min(xmax);
        y0[q] = ceil_small(min3(ay, by, cy)).max(0.0);
        y1[q] = floor_small(max3(ay, by, cy)).min(ymax);
        let area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax);
        ok[q] = area.abs() >= 1e-12;
        let ia = 1.0 / area;
        // Normalised edge functions e_k(x, y) = A_k x + B_k y + C_k, ≥ 0 inside.
        let (a0, b0, c0) = ((by - cy) * ia, (cx - bx) * ia, (bx * cy - by * cx) * ia); // weight of a
        let (a1, b1, c1) = ((cy - ay) * ia, (ax - cx) * ia, (cx * ay - cy * ax) * ia); // weight of b
        let (a2, b2, c2) = ((ay - by) * ia, (bx - ax) * ia, (ax * by - ay * bx) * ia); // weight of c
                                                                                       // Depth plane: z = a.z w0 + b.z w1 + c.z w2.
        let dzx = az * a0 + bz * a1 + cz * a2;
        let dzy = az * b0 + bz * b1 + cz * b2;
        let dzc = az * c0 + bz * c1 + cz * c2;
        for (kk, val) in k
            .iter_mut()
            .zip([a0, b0, c0, a1, b1, c1, a2, b2, c2, dzx, dzy, dzc])
        {
            kk[q] = val;
        }
    }
    // The 2 × 2 candidate centres (x0 + dx, y0 + dy) of every lane; texel indices as floats
    // (exact: below 4096² = 2²⁴).
    let mut z = [[0f32; LANES]; 4];
    let mut idx = [[0f32; LANES]; 4];
    // Per lane, bit `cand` set when that candidate is inside its triangle and box.
    let mut mask = [0u32; LANES];
    for cand in 0..4 {
        let (dx, dy) = ((cand & 1) as f32, (cand >> 1) as f32);
        for q in 0..LANES {
            let (xf, yf) = (x0[q] + dx, y0[q] + dy);
            let e0 = k[0][q] * xf + (k[1][q] * yf + k[2][q]);
            let e1 = k[3][q] * xf + (k[4][q] * yf + k[5][q]);
            let e2 = k[6][q] * xf + (k[7][q] * yf + k[8][q]);
            z[cand][q] = k[9][q] * xf + (k[10][q] * yf + k[11][q]);
            let inside = ok[q]
                & (xf <= x1[q])
                & (yf <= y1[q])
                & (e0 >= EDGE_EPS)
                & (e1 >= EDGE_EPS)
                & (e2 >= EDGE_EPS);
            mask[q] |= u32::from(inside) << cand;
            let (xc, yc) = (
                if xf < xmax { xf } else { xmax },
                if yf < ymax { yf } else { ymax },
            );
            idx[cand][q] = yc * wdf + xc;
        }
    }
    for q in 0..n {
        if x1[q] <= x0[q] + 1.0 && y1[q] <= y0[q] + 1.0 {
            // Only the candidates inside (most of a fine mesh's triangles cover one texel or
            // none): the same writes as testing all four.
            let mut m = mask[q];
            while m != 0 {
                let cand = m.trailing_zeros() as usize;
                m &= m - 1;
                if let Some(d) = depth.get_mut(idx[cand][q] as usize) {
                    let zq = z[cand][q];
                    if zq > *d {
                        *d = zq;
                    }
                }
            }
            continue;
        }
        if x0[q] > x1[q] || y0[q] > y1[q] || !ok[q] {
            continue;
        }
        let (xa, xb) = (x0[q] as usize, x1[q] as usize);
        let kq: [f32; 12] = std::array::from_fn(|i| k[i][q]);
        let [a0, b0, c0, a1, b1, c1, a2, b2, c2, dzx, dzy, dzc] = kq;
        for y in y0[q] as usize..=y1[q] as usize {
            let yf = y as f32;
            let (r0, r1, r2) = (b0 * yf + c0, b1 * yf + c1, b2 * yf + c2);
            let rz = dzy * yf + dzc;
            let Some(row) = depth.get_mut(y * wd + xa..=y * wd + xb) else {
                break;
            };
            for (kx, d) in row.iter_mut().enumerate() {
                let xf = (xa + kx) as f32;
                if a0 * xf + r0 >= EDGE_EPS && a1 * xf + r1 >= EDGE_EPS && a2 * xf + r2 >= EDGE_EPS
                {
                    let z = dzx * xf + rz;
                    if z > *d {
                        *d = z;
                    }
                }
            }
        }
    }
}

/// Round to nearest (ties to even) without a libm call or an integer conversion (so it
/// vectorises on plain x86-64): exact for |x| < 2²².
#[inline(always)]
fn round_small(x: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5 · 2²³
    (x + MAGIC) - MAGIC
}

/// `⌈x⌉` for |x| < 2²² (grid coordinates are within [−1, 4097]).
#[inline(always)]
fn ceil_small(x: f32) -> f32 {
    let r = round_small(x);
    if r < x {
        r + 1.0
    } else {
        r
    }
}

/// `⌊x⌋` for |x| < 2²².
#[inline(always)]
fn floor_small(x: f32) -> f32 {
    let r = round_small(x);
    if r > x {
        r - 1.0
    } else {
        r
    }
}
