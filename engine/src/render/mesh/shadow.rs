//! The mesh renderer's sun shadows (see "Shadows" in [`super`]): an orthographic depth map along
//! the sun, filled by a scanline max pass, looked up with a 2×2 percentage-closer filter.

use rayon::prelude::*;

use super::scene::Scene;
use crate::control::{Canceled, Control};
use crate::geom::vec::{normalized, DVec3};

/// An orthographic depth map along the sun: texel (i, j) holds the largest `dot(p, sun)` of the
/// scene at its centre (−∞ = empty).
pub(super) struct ShadowMap {
    u: DVec3,
    v: DVec3,
    d: DVec3,
    u0: f64,
    v0: f64,
    /// World units per texel.
    texel: f64,
    size: usize,
    depth: Vec<f32>,
    /// Depths are stored relative to this (f32 precision near the scene).
    d0: f64,
    eps: f64,
}

impl ShadowMap {
    pub(super) fn build(
        s: &Scene,
        sun: [f64; 3],
        size: u32,
        ctl: &dyn Control,
    ) -> Result<Self, Canceled> {
        let d = DVec3::from(sun);
        let helper = if d.y.abs() < 0.9 { DVec3::Y } else { DVec3::X };
        let u = normalized(helper.cross(d));
        let v = d.cross(u);
        let size = size.clamp(16, 8192) as usize;
        let (mut u0, mut u1, mut v0, mut v1) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        let mut d0 = f64::INFINITY;
        for p in &s.positions {
            if p.iter().all(|c| c.is_finite()) {
                let p = DVec3::from(*p);
                let (pu, pv) = (p.dot(u), p.dot(v));
                u0 = u0.min(pu);
                u1 = u1.max(pu);
                v0 = v0.min(pv);
                v1 = v1.max(pv);
                d0 = d0.min(p.dot(d));
            }
        }
        let extent = (u1 - u0).max(v1 - v0).max(1e-9);
        let texel = extent * 1.002 / size as f64;
        let (u0, v0) = (u0 - extent * 0.001, v0 - extent * 0.001);
        let diag = DVec3::from(s.hi).distance(DVec3::from(s.lo));
        let mut map = Self {
            u,
            v,
            d,
            u0,
            v0,
            texel,
            size,
            depth: vec![f32::NEG_INFINITY; size * size],
            d0: if d0.is_finite() { d0 } else { 0.0 },
            eps: 1e-5 * diag.max(1e-9),
        };
        // Map-space triangle corners (texel units, depth relative to d0).
        let to_map = |p: [f64; 3]| -> [f64; 3] {
            let p = DVec3::from(p);
            [
                (p.dot(u) - map.u0) / texel,
                (p.dot(v) - map.v0) / texel,
                p.dot(d) - map.d0,
            ]
        };
        let tris: Vec<[[f64; 3]; 3]> = s
            .triangles
            .par_iter()
            .map(|t| t.map(|i| to_map(s.positions[i as usize])))
            .collect();
        const ROWS: usize = 64;
        // Each band's triangles, in triangle order (a counting sort of the bands each one's
        // rows reach): a band no longer tests every triangle's bounding box.
        let n_bands = size.div_ceil(ROWS);
        let reach: Vec<(u32, u32)> = tris.par_iter().map(|t| band_reach(t, size, ROWS)).collect();
        let mut start = vec![0usize; n_bands + 1];
        for &(b0, b1) in &reach {
            for b in b0..b1 {
                start[b as usize + 1] += 1;
            }
        }
        for b in 0..n_bands {
            start[b + 1] += start[b];
        }
        let mut next = start.clone();
        let mut order = vec![0u32; start[n_bands]];
        for (t, &(b0, b1)) in reach.iter().enumerate() {
            for b in b0..b1 {
                order[next[b as usize]] = t as u32;
                next[b as usize] += 1;
            }
        }
        map.depth
            .par_chunks_mut(size * ROWS)
            .enumerate()
            .try_for_each(|(b, rows)| {
                ctl.checkpoint()?;
                let (r0, r1) = (b * ROWS, b * ROWS + rows.len() / size);
                for &t in &order[start[b]..start[b + 1]] {
                    fill_triangle(&tris[t as usize], r0, r1, size, rows);
                }
                Ok(())
            })?;
        Ok(map)
    }

    /// Fraction of the sun visible at `p` with normal `n` (unit, facing the sun: `ndl > 0`).
    pub(super) fn visibility(&self, p: [f64; 3], ndl: f64) -> f32 {
        let p = DVec3::from(p);
        let x = (p.dot(self.u) - self.u0) / self.texel - 0.5;
        let y = (p.dot(self.v) - self.v0) / self.texel - 0.5;
        let tan = ((1.0 - ndl * ndl).max(0.0).sqrt() / ndl.max(1e-6)).min(8.0);
        let bias = self.texel * (1.0 + 2.0 * tan) + self.eps;
        let depth = p.dot(self.d) - self.d0 + bias;
        let (fx, fy) = (x.floor(), y.floor());
        let (ax, ay) = ((x - fx) as f32, (y - fy) as f32);
        let n = self.size as i64;
        let lit = |i: i64, j: i64| -> f32 {
            if i < 0 || j < 0 || i >= n || j >= n {
                return 1.0;
            }
            let m = self.depth[j as usize * self.size + i as usize];
            if f64::from(m) <= depth {
                1.0
            } else {
                0.0
            }
        };
        let (i, j) = (fx as i64, fy as i64);
        let top = lit(i, j) * (1.0 - ax) + lit(i + 1, j) * ax;
        let bottom = lit(i, j + 1) * (1.0 - ax) + lit(i + 1, j + 1) * ax;
        top * (1.0 - ay) + bottom * ay
    }
}

/// The bands (of `rows` rows) whose rows [`fill_triangle`] can reach for triangle `t`, as a
/// half-open range (empty for a triangle it skips whole): its rows are at most
/// `⌈y_min − ½⌉ ..= ⌊y_max − ½⌋` within the map.
fn band_reach(t: &[[f64; 3]; 3], size: usize, rows: usize) -> (u32, u32) {
    if !t.iter().flatten().all(|v| v.is_finite()) {
        return (0, 0);
    }
    let ymin = t[0][1].min(t[1][1]).min(t[2][1]);
    let ymax = t[0][1].max(t[1][1]).max(t[2][1]);
    let j0 = (ymin - 0.5).ceil().max(0.0);
    let j1 = (ymax - 0.5).floor().min(size as f64 - 1.0);
    if j1 < j0 {
        return (0, 0);
    }
    ((j0 as usize / rows) as u32, (j1 as usize / rows + 1) as u32)
}

/// Rasterise one map-space triangle into rows `r0..r1` (texel centres inside, inclusive edges),
/// keeping the largest depth.
///
/// Each row visits only the texels that may pass the inside test: the test reads the three
/// barycentrics `wₑ = Nₑ(p) / area` with edge functions `Nₑ` linear along the row, evaluated in
/// `f64` with an absolute error far below `δ = 10⁻¹² R²` (R bounds every coordinate: a few
/// products of terms ≤ 2R, and `w₂ = 1 − w₀ − w₁`), so a texel centre where some
/// `sign(area) · Nₑ < −δ` fails the test for certain. The row's interval where every
/// `sign(area) · Nₑ ≥ −δ` (widened by a texel each side) holds every texel that can pass; the
/// test itself is unchanged, so the map is the same bit for bit.
fn fill_triangle(t: &[[f64; 3]; 3], r0: usize, r1: usize, size: usize, rows: &mut [f32]) {
    let [a, b, c] = *t;
    if !t.iter().flatten().all(|v| v.is_finite()) {
        return;
    }
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if area == 0.0 {
        return;
    }
    let ymin = a[1].min(b[1]).min(c[1]);
    let ymax = a[1].max(b[1]).max(c[1]);
    let xmin = a[0].min(b[0]).min(c[0]);
    let xmax = a[0].max(b[0]).max(c[0]);
    let j0 = ((ymin - 0.5).ceil().max(r0 as f64)) as usize;
    let j1 = ((ymax - 0.5).floor().min(r1 as f64 - 1.0)).max(-1.0) as i64;
    let i0 = (xmin - 0.5).ceil().max(0.0) as usize;
    let i1 = (xmax - 0.5).floor().min(size as f64 - 1.0) as i64;
    if (j1 as f64) < j0 as f64 || (i1 as f64) < i0 as f64 {
        return;
    }
    let inv = 1.0 / area;
    let sign = area.signum();
    let r = t
        .iter()
        .flat_map(|v| [v[0].abs(), v[1].abs()])
        .fold(size as f64 + 1.0, f64::max);
    let delta = 1e-12 * r * r;
    let edges = [(b, c), (c, a), (a, b)];
    for j in j0..=j1 as usize {
        let py = j as f64 + 0.5;
        // The texel centres px where every sign · Nₑ(px) ≥ −δ (doc above).
        let (mut lo, mut hi) = (i0 as f64 + 0.5, i1 as f64 + 0.5);
        for (u, v) in edges {
            // Nₑ(px) = (u₀ − px)(v₁ − py) − (u₁ − py)(v₀ − px) = α + β·px.
            let alpha = sign * (u[0] * (v[1] - py) - (u[1] - py) * v[0]);
            let beta = sign * (u[1] - v[1]);
            if beta > 0.0 {
                lo = lo.max((-delta - alpha) / beta);
            } else if beta < 0.0 {
                hi = hi.min((-delta - alpha) / beta);
            } else if alpha < -delta {
                hi = f64::NEG_INFINITY;
            }
        }
        if lo.is_nan() || hi.is_nan() || lo > hi {
            continue;
        }
        // lo ≥ i0 + ½ > 0, so the cast floors; for hi it truncates (≥ the floor): wider.
        let ilo = ((lo - 0.5) as i64 - 1).max(i0 as i64) as usize;
        let ihi = ((hi - 0.5) as i64).saturating_add(1).min(i1);
        if (ihi as f64) < ilo as f64 {
            continue;
        }
        let row = &mut rows[(j - r0) * size..(j - r0 + 1) * size];
        for (i, out) in row.iter_mut().enumerate().take(ihi as usize + 1).skip(ilo) {
            let px = i as f64 + 0.5;
            let w0 = ((b[0] - px) * (c[1] - py) - (b[1] - py) * (c[0] - px)) * inv;
            let w1 = ((c[0] - px) * (a[1] - py) - (c[1] - py) * (a[0] - px)) * inv;
            let w2 = 1.0 - w0 - w1;
            if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
                let z = (w0 * a[2] + w1 * b[2] + w2 * c[2]) as f32;
                if z > *out {
                    *out = z;
                }
            }
        }
    }
}
