//! Colourization by optimization (Levin, Lischinski and Weiss 2004) on the 3-D voxel grid,
//! solved by geometric multigrid (SPEC §3.2; the paper: "the method of ref. 4 on the GPU,
//! accelerated by the multigrid method of ref. 5").
//!
//! The system, per RGB channel: every free voxel r satisfies `U(r) − Σ_s w_rs U(s) = 0` over its
//! 6-neighbourhood, pinned voxels keep their colour (Dirichlet). The weights follow LLW's code
//! (`getColorExact.m`): with the guide Y (here each voxel's direct light, the sun transmittance),
//! `w_rs ∝ exp(−(Y_r − Y_s)²/c)`, `c_r = max(0.6·var_r, min_s (Y_r − Y_s)²/ln 100, 2·10⁻⁶)` where
//! var_r is the variance of Y over r and its neighbours, normalised to sum 1 over s.
//!
//! Reading chosen: `c` is symmetrised per edge, `c_rs = ½(c_r + c_s)`, so the edge affinities
//! `a_rs = exp(−(Y_r − Y_s)²/c_rs)` are symmetric. LLW's equation `U_r = Σ_s a_rs U_s / Σ_s a_rs`
//! is then the graph-Laplacian system `Σ_s a_rs (U_r − U_s) = 0` — symmetric positive definite
//! with the pins as Dirichlet values — which conjugate gradients can accelerate (below).
//!
//! Choices (documented readings):
//! - *Unknowns*: every voxel, not only ρ > 0. Empty space then carries the guide too (lit
//!   air has T ≈ 1 like lit cloud tops), disconnected puffs without a pin still get a colour, and
//!   the grid stays a box, which keeps the multigrid geometric. Pins are only set on ρ > 0
//!   voxels by the ambient edit; the renderer weights the field by ρ, so empty voxels' values
//!   never show.
//! - *Multigrid*: cell-centred, coarsening by 2 per axis (odd sizes round up), trilinear
//!   prolongation P and its transpose as restriction, the affinities recomputed on every level
//!   from the restricted (averaged) guide and the coarse operator scaled by 2 per level (the
//!   Galerkin factor of PᵀLP for this P), red–black Gauss–Seidel (red then black before the
//!   coarse correction, black then red after, so the cycle is symmetric), and the coarsest level
//!   (smallest side < 6) smoothed 100 times. *Pins restrict* as "a coarse cell is pinned (zero
//!   correction) when any child is pinned": a pin's error is zero and a coarse cell touching a
//!   pin cannot carry a correction without moving it; the prolonged correction is zeroed on
//!   fine pins.
//! - *Why the V-cycle preconditions conjugate gradients*: as a plain iteration the rediscretised
//!   cycle stalled (0.92 per cycle with two point pins in a uniform guide: a coarse pinned cell
//!   is a bigger pin than the fine one, and that capacitance mismatch is a handful of global
//!   modes no smoother removes) and diverged on the cumulus' guide with its sharp edges. Those
//!   few bad modes are exactly what CG removes, so each iteration is one symmetric V-cycle plus
//!   one operator product and a few dot products (per channel). Measured on the cumulus tests:
//!   1e-6 in 12 (32³) and 16 (64³) iterations, a mean cut of 2.4–3.2× per iteration with the
//!   worst single iteration ~0.63–0.78 — short of the issue's ≥ 5× per V-cycle. What is missing
//!   is a coarse operator that sees the fine affinities (Galerkin PᵀLP, a 125-point stencil for
//!   this P, or operator-dependent interpolation); see BENCHMARKS.md.
//! - Red–black Gauss–Seidel is written as two half-sweeps between two buffers (red from black,
//!   then black from red), which is the same iteration and lets planes run in parallel without
//!   sharing mutable state; sums are taken per plane and added in order, so the result does not
//!   depend on the thread count.
//! - The relative residual is `‖b − L·U‖ / ‖b‖` of the Laplacian system over the free voxels and
//!   the three channels, `b` being the pins' contribution (the residual of U = 0 on the free
//!   voxels).

// Index loops over the 3 channels and the 6 neighbours read clearer than zips here.
#![allow(clippy::needless_range_loop)]

use rayon::prelude::*;

use crate::{Canceled, Control};

type Rgb = [f64; 3];

/// LLW's per-voxel `c_r` (see the module doc).
fn llw_c(dims: [usize; 3], guide: &[f32]) -> Vec<f32> {
    let [nx, ny, _] = dims;
    let mut c = vec![0f32; guide.len()];
    c.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(z, plane)| {
            for y in 0..ny {
                for x in 0..nx {
                    let i = x + nx * (y + ny * z);
                    let yr = guide[i];
                    let (mut sum, mut sum2, mut cnt) = (yr, yr * yr, 1.0f32);
                    let mut min_d2 = f32::INFINITY;
                    for j in neighbours(dims, x, y, z).iter().flatten() {
                        let v = guide[*j];
                        sum += v;
                        sum2 += v * v;
                        cnt += 1.0;
                        min_d2 = min_d2.min((v - yr) * (v - yr));
                    }
                    let mean = sum / cnt;
                    let var = (sum2 / cnt - mean * mean).max(0.0);
                    let mut cr = 0.6 * var;
                    if min_d2.is_finite() {
                        cr = cr.max(min_d2 / 100f32.ln());
                    }
                    plane[x + nx * y] = cr.max(2e-6);
                }
            }
        });
    c
}

/// Symmetric LLW affinities of every voxel's +x, +y and +z edges (0 where the neighbour is
/// outside the grid). Allocates 16 bytes per voxel.
pub fn llw_weights(dims: [usize; 3], guide: &[f32]) -> Vec<[f32; 3]> {
    let c = llw_c(dims, guide);
    let [nx, ny, nz] = dims;
    let mut a = vec![[0f32; 3]; guide.len()];
    a.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(z, plane)| {
            for y in 0..ny {
                for x in 0..nx {
                    let i = x + nx * (y + ny * z);
                    let mut e = [0f32; 3];
                    let nb = [
                        (x + 1 < nx).then(|| i + 1),
                        (y + 1 < ny).then(|| i + nx),
                        (z + 1 < nz).then(|| i + nx * ny),
                    ];
                    for k in 0..3 {
                        if let Some(j) = nb[k] {
                            let d = guide[j] - guide[i];
                            e[k] = (-d * d / (0.5 * (c[i] + c[j]))).exp();
                        }
                    }
                    plane[x + nx * y] = e;
                }
            }
        });
    a
}

/// The flat indices of the 6 neighbours of `(x, y, z)` (−x, +x, −y, +y, −z, +z; None outside).
#[inline]
pub fn neighbours(dims: [usize; 3], x: usize, y: usize, z: usize) -> [Option<usize>; 6] {
    let [nx, ny, nz] = dims;
    let i = x + nx * (y + ny * z);
    [
        (x > 0).then(|| i - 1),
        (x + 1 < nx).then(|| i + 1),
        (y > 0).then(|| i - nx),
        (y + 1 < ny).then(|| i + nx),
        (z > 0).then(|| i - nx * ny),
        (z + 1 < nz).then(|| i + nx * ny),
    ]
}

/// The 6 (neighbour, affinity) pairs of voxel `(x, y, z)` given the edge array.
#[inline]
fn edges(dims: [usize; 3], a: &[[f32; 3]], x: usize, y: usize, z: usize) -> [(usize, f64); 6] {
    let nb = neighbours(dims, x, y, z);
    let i = x + dims[0] * (y + dims[1] * z);
    let mut out = [(i, 0.0f64); 6];
    for k in 0..6 {
        if let Some(j) = nb[k] {
            // Edge k of voxel i is stored on the lower voxel of the pair.
            let (lo, axis) = if k % 2 == 0 { (j, k / 2) } else { (i, k / 2) };
            out[k] = (j, f64::from(a[lo][axis]));
        }
    }
    out
}

struct Level {
    dims: [usize; 3],
    a: Vec<[f32; 3]>,
    pinned: Vec<bool>,
    /// Operator scale of this level (2 per coarsening).
    scale: f64,
    /// The correction.
    e: Vec<Rgb>,
    /// Right-hand side.
    b: Vec<Rgb>,
    tmp: Vec<Rgb>,
}

/// What the solve did: the relative residual before the first iteration (1) and after each.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveStats {
    pub residuals: Vec<f64>,
    pub levels: usize,
}

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveOptions {
    /// Stop at this relative residual. Default 1e-6.
    pub tolerance: f64,
    /// At most this many iterations (one V-cycle each). Default 60.
    pub max_iterations: usize,
    /// Red–black sweeps before and after the coarse correction. Default 4 (2 took 18 and 24
    /// iterations on the 32³/64³ cumulus tests, 4 took 12 and 16 in about the same time).
    pub smoothing: usize,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-6,
            max_iterations: 60,
            smoothing: 4,
        }
    }
}

/// `out = L·u` on the free voxels of level `l` (0 on pins), `u` zero on pins except for the
/// fine level's pinned values: `(L u)_r = scale·Σ_s a_rs (u_r − u_s)`.
fn apply(l: &Level, u: &[Rgb], out: &mut [Rgb]) {
    let [nx, ny, _] = l.dims;
    out.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(z, plane)| {
            for y in 0..ny {
                for x in 0..nx {
                    let j = x + nx * y;
                    let i = j + nx * ny * z;
                    if l.pinned[i] {
                        plane[j] = [0.0; 3];
                        continue;
                    }
                    let mut v = [0.0; 3];
                    for (s, w) in edges(l.dims, &l.a, x, y, z) {
                        for q in 0..3 {
                            v[q] += w * (u[i][q] - u[s][q]);
                        }
                    }
                    plane[j] = v.map(|c| c * l.scale);
                }
            }
        });
}

/// Red–black Gauss–Seidel half-sweep on `L e = b`: voxels of `colour` from `src` into `dst`.
fn half_sweep(l: &Level, src: &[Rgb], dst: &mut [Rgb], colour: usize) {
    let [nx, ny, _] = l.dims;
    dst.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(z, plane)| {
            for y in 0..ny {
                for x in 0..nx {
                    let j = x + nx * y;
                    let i = j + nx * ny * z;
                    plane[j] = if (x + y + z) & 1 == colour && !l.pinned[i] {
                        let mut v = l.b[i].map(|c| c / l.scale);
                        let mut d = 0.0;
                        for (s, w) in edges(l.dims, &l.a, x, y, z) {
                            d += w;
                            for q in 0..3 {
                                v[q] += w * src[s][q];
                            }
                        }
                        if d > 0.0 {
                            v.map(|c| c / d)
                        } else {
                            src[i]
                        }
                    } else {
                        src[i]
                    };
                }
            }
        });
}

fn smooth(l: &mut Level, order: &[usize]) {
    let mut e = std::mem::take(&mut l.e);
    let mut tmp = std::mem::take(&mut l.tmp);
    for &c in order {
        half_sweep(l, &e, &mut tmp, c);
        std::mem::swap(&mut e, &mut tmp);
    }
    l.e = e;
    l.tmp = tmp;
}

/// Trilinear cell-centred prolongation weights along one axis: fine index → two coarse
/// indices and weights.
#[inline]
fn axis_weights(i: usize, nc: usize) -> [(usize, f64); 2] {
    let u = (i as f64 * 0.5 - 0.25).clamp(0.0, (nc - 1) as f64);
    let a = (u.floor() as usize).min(nc - 1);
    let f = u - a as f64;
    [(a, 1.0 - f), ((a + 1).min(nc - 1), f)]
}

/// For each coarse index along an axis: the fine indices and weights that interpolate from it.
fn transpose_axis(nf: usize, nc: usize) -> Vec<Vec<(usize, f64)>> {
    let mut t = vec![Vec::new(); nc];
    for i in 0..nf {
        for (c, w) in axis_weights(i, nc) {
            if w > 0.0 {
                t[c].push((i, w));
            }
        }
    }
    t
}

/// `c.b = Pᵀ·f.tmp` (pins of `c` get 0).
fn restrict(f: &Level, c: &mut Level) {
    let cd = c.dims;
    let tx = transpose_axis(f.dims[0], cd[0]);
    let ty = transpose_axis(f.dims[1], cd[1]);
    let tz = transpose_axis(f.dims[2], cd[2]);
    let (fnx, fny) = (f.dims[0], f.dims[1]);
    let pinned = &c.pinned;
    c.b.par_chunks_mut(cd[0] * cd[1])
        .enumerate()
        .for_each(|(cz, plane)| {
            for cy in 0..cd[1] {
                for cx in 0..cd[0] {
                    let ci = cx + cd[0] * (cy + cd[1] * cz);
                    let mut s = [0.0; 3];
                    if !pinned[ci] {
                        for &(fz, wz) in &tz[cz] {
                            for &(fy, wy) in &ty[cy] {
                                for &(fx, wx) in &tx[cx] {
                                    let w = wz * wy * wx;
                                    let r = f.tmp[fx + fnx * (fy + fny * fz)];
                                    for q in 0..3 {
                                        s[q] += w * r[q];
                                    }
                                }
                            }
                        }
                    }
                    plane[cx + cd[0] * cy] = s;
                }
            }
        });
}

/// `f.e += P·c.e` on free fine voxels.
fn prolong_add(f: &mut Level, c: &Level) {
    let [nx, ny, _] = f.dims;
    let cd = c.dims;
    let pinned = &f.pinned;
    f.e.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(z, plane)| {
            let wz = axis_weights(z, cd[2]);
            for y in 0..ny {
                let wy = axis_weights(y, cd[1]);
                for x in 0..nx {
                    let j = x + nx * y;
                    if pinned[j + nx * ny * z] {
                        continue;
                    }
                    let wx = axis_weights(x, cd[0]);
                    for &(cz, az) in &wz {
                        for &(cy, ay) in &wy {
                            for &(cx, ax) in &wx {
                                let w = az * ay * ax;
                                let v = c.e[cx + cd[0] * (cy + cd[1] * cz)];
                                for q in 0..3 {
                                    plane[j][q] += w * v[q];
                                }
                            }
                        }
                    }
                }
            }
        });
}

/// One symmetric V-cycle on `levels[l]` (`b` set, `e` the result, starting from 0).
fn v_cycle(levels: &mut [Level], l: usize, nu: usize) {
    levels[l].e.iter_mut().for_each(|v| *v = [0.0; 3]);
    if l + 1 == levels.len() {
        let mut order = vec![0];
        for _ in 0..100 {
            order.extend([1, 0]);
        }
        smooth(&mut levels[l], &order);
        return;
    }
    let pre: Vec<usize> = (0..nu).flat_map(|_| [0, 1]).collect();
    let post: Vec<usize> = (0..nu).flat_map(|_| [1, 0]).collect();
    smooth(&mut levels[l], &pre);
    {
        let lv = &mut levels[l];
        let mut tmp = std::mem::take(&mut lv.tmp);
        apply(lv, &lv.e, &mut tmp);
        for (t, b) in tmp.iter_mut().zip(&lv.b) {
            for q in 0..3 {
                t[q] = b[q] - t[q];
            }
        }
        lv.tmp = tmp;
    }
    {
        let (fine, rest) = levels.split_at_mut(l + 1);
        restrict(&fine[l], &mut rest[0]);
    }
    v_cycle(levels, l + 1, nu);
    {
        let (fine, rest) = levels.split_at_mut(l + 1);
        prolong_add(&mut fine[l], &rest[0]);
    }
    smooth(&mut levels[l], &post);
}

fn build_levels(
    dims: [usize; 3],
    guide: Vec<f32>,
    pinned: Vec<bool>,
    ctl: &dyn Control,
) -> Result<Vec<Level>, Canceled> {
    let mut levels = Vec::new();
    let (mut dims, mut guide, mut pinned) = (dims, guide, pinned);
    let mut scale = 1.0;
    loop {
        ctl.checkpoint()?;
        let n = guide.len();
        let a = llw_weights(dims, &guide);
        let next = dims.iter().all(|&d| d >= 6).then(|| {
            let cd = dims.map(|d| d.div_ceil(2));
            let cn = cd[0] * cd[1] * cd[2];
            let mut cg = vec![0f32; cn];
            let mut cp = vec![false; cn];
            for (ci, (g, p)) in cg.iter_mut().zip(cp.iter_mut()).enumerate() {
                let (cx, cy, cz) = (ci % cd[0], (ci / cd[0]) % cd[1], ci / (cd[0] * cd[1]));
                let (mut sum, mut cnt) = (0.0f32, 0.0f32);
                for dz in 0..2 {
                    for dy in 0..2 {
                        for dx in 0..2 {
                            let (x, y, z) = (2 * cx + dx, 2 * cy + dy, 2 * cz + dz);
                            if x < dims[0] && y < dims[1] && z < dims[2] {
                                let fi = x + dims[0] * (y + dims[1] * z);
                                sum += guide[fi];
                                cnt += 1.0;
                                *p |= pinned[fi];
                            }
                        }
                    }
                }
                *g = sum / cnt;
            }
            (cd, cg, cp)
        });
        levels.push(Level {
            dims,
            a,
            pinned,
            scale,
            e: vec![[0.0; 3]; n],
            b: vec![[0.0; 3]; n],
            tmp: vec![[0.0; 3]; n],
        });
        match next {
            Some((cd, cg, cp)) => {
                dims = cd;
                guide = cg;
                pinned = cp;
                scale *= 2.0;
            }
            None => return Ok(levels),
        }
    }
}

fn dot3(a: &[Rgb], b: &[Rgb]) -> Rgb {
    let parts: Vec<Rgb> = a
        .par_chunks(4096)
        .zip(b.par_chunks(4096))
        .map(|(x, y)| {
            let mut s = [0.0; 3];
            for (u, v) in x.iter().zip(y) {
                for q in 0..3 {
                    s[q] += u[q] * v[q];
                }
            }
            s
        })
        .collect();
    parts.iter().fold([0.0; 3], |acc, s| {
        [acc[0] + s[0], acc[1] + s[1], acc[2] + s[2]]
    })
}

/// Propagates `pins` (flat index, linear RGB) over the grid guided by `guide` (one value per
/// voxel) and returns every voxel's colour: multigrid-preconditioned conjugate gradients on the
/// LLW system (module doc). A voxel pinned twice takes the later colour; with no pins the
/// result is all zero. Allocates the level hierarchy and the CG vectors (~190 bytes per fine
/// voxel).
pub fn propagate(
    dims: [usize; 3],
    guide: &[f32],
    pins: &[(usize, [f32; 3])],
    opts: SolveOptions,
    ctl: &dyn Control,
) -> Result<(Vec<[f32; 3]>, SolveStats), Canceled> {
    let n = guide.len();
    let mut pinned = vec![false; n];
    let mut x = vec![[0f64; 3]; n];
    for &(i, c) in pins {
        if i < n {
            pinned[i] = true;
            x[i] = c.map(f64::from);
        }
    }
    let mut levels = build_levels(dims, guide.to_vec(), pinned, ctl)?;
    let mut stats = SolveStats {
        residuals: vec![1.0],
        levels: levels.len(),
    };
    // r = −L·x (b = 0 with the pins in x), zero on pins.
    let mut r = vec![[0f64; 3]; n];
    apply(&levels[0], &x, &mut r);
    r.par_iter_mut().for_each(|v| *v = v.map(|c| -c));
    let r0 = dot3(&r, &r);
    let norm0 = (r0[0] + r0[1] + r0[2]).sqrt();
    if norm0 > 0.0 {
        let precondition = |levels: &mut Vec<Level>, r: &[Rgb]| -> Vec<Rgb> {
            levels[0].b.copy_from_slice(r);
            v_cycle(levels, 0, opts.smoothing);
            levels[0].e.clone()
        };
        let mut z = precondition(&mut levels, &r);
        let mut p = z.clone();
        let mut rz = dot3(&r, &z);
        let mut q = vec![[0f64; 3]; n];
        for _ in 0..opts.max_iterations {
            ctl.checkpoint()?;
            apply(&levels[0], &p, &mut q);
            let pq = dot3(&p, &q);
            let alpha: Rgb = std::array::from_fn(|c| if pq[c] > 0.0 { rz[c] / pq[c] } else { 0.0 });
            x.par_iter_mut()
                .zip(r.par_iter_mut())
                .zip(p.par_iter().zip(q.par_iter()))
                .for_each(|((xv, rv), (pv, qv))| {
                    for c in 0..3 {
                        xv[c] += alpha[c] * pv[c];
                        rv[c] -= alpha[c] * qv[c];
                    }
                });
            let rr = dot3(&r, &r);
            let rel = (rr[0] + rr[1] + rr[2]).sqrt() / norm0;
            stats.residuals.push(rel);
            if rel <= opts.tolerance {
                break;
            }
            z = precondition(&mut levels, &r);
            let rz_new = dot3(&r, &z);
            let beta: Rgb =
                std::array::from_fn(|c| if rz[c] > 0.0 { rz_new[c] / rz[c] } else { 0.0 });
            rz = rz_new;
            p.par_iter_mut().zip(z.par_iter()).for_each(|(pv, zv)| {
                for c in 0..3 {
                    pv[c] = zv[c] + beta[c] * pv[c];
                }
            });
        }
    }
    let out = x.iter().map(|c| c.map(|v| v as f32)).collect();
    Ok((out, stats))
}
