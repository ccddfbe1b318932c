//! Sun transmittance on the grid (SPEC §3 "Precompute sun transmittance on the grid once per
//! light direction"): for every voxel centre x, `T_sun(x) = exp(−κ ∫ ρ)` along the ray from x
//! toward the sun — the factor of I_s in paper Eq. 1.
//!
//! Method: a *sheared line sweep* instead of marching from every voxel. Slices are taken across
//! the axis k where the sun direction s has its largest component, starting from the slice
//! nearest the sun. A lattice of parallel sun rays ("lines") starts at the voxel positions of
//! that first slice (extended so that lines entering through the side faces exist too); from
//! slice to slice every line moves by the constant in-plane offset `s·h_k/|s_k|` and accumulates
//! the trapezoid `½(ρ_prev + ρ)·L`, `L = h_k/|s_k|`, with ρ bilinear *in the slice plane* where
//! the line crosses it (the line crosses each plane exactly, so no 3-D interpolation). A voxel's
//! optical depth is then the bilinear interpolation of the four lines around it in its slice:
//! one interpolation of τ per voxel, never compounded — the first version resampled τ from the
//! previous slice at every step, and that repeated bilinear resampling blurred a 24³ blob's
//! shadow by ~2 voxels (errors up to 0.1 in T). Cost O(voxels): two bilinear fetches per voxel,
//! against O(voxels · n) for marching. Slices run in sequence, rows in parallel: the result does
//! not depend on the thread count. Tested against [`transmittance_marched`].
//!
//! Rejected: marching from every voxel (256³ × ~300 samples ≈ 5·10⁹ trilinear fetches, tens of
//! seconds) and a shadow map (needs a second resampling of the grid into light space).

use rayon::prelude::*;

use super::fastexp::exp_neg;
use super::grid::GridFrame;
use super::skip::DensityRows;
use crate::geom::Volume;
use crate::{Canceled, Control};

/// The sun transmittance of every voxel for one direction and κ.
#[derive(Debug, Clone, PartialEq)]
pub struct SunLight {
    /// Unit vector toward the sun it was computed for.
    pub direction: [f64; 3],
    pub kappa: f64,
    /// `T_sun` per voxel, in the volume's layout, in `[0, 1]`.
    pub transmittance: Vec<f32>,
}

impl SunLight {
    /// Sweeps the grid (see the module doc). Allocates the result (4 bytes per voxel) and the
    /// line lattice (8 bytes per line).
    pub fn compute(
        volume: &Volume,
        direction: [f64; 3],
        kappa: f64,
        ctl: &dyn Control,
    ) -> Result<Self, Canceled> {
        let mut transmittance = vec![0f32; volume.len()];
        let out = SweepOut {
            cells: &mut transmittance,
            dims: volume.dims,
            border: 0,
        };
        sweep(volume, direction, kappa, None, out, |t, _, v| *t = v, ctl)?;
        Ok(Self {
            direction,
            kappa,
            transmittance,
        })
    }
}

/// Where [`sweep`] writes: a grid of cells in the volume's layout (x fastest), `border` cells
/// larger than the volume on every side (voxel (x, y, z) is cell (x, y, z) + `border`).
pub(crate) struct SweepOut<'a, E> {
    pub cells: &'a mut [E],
    pub dims: [usize; 3],
    pub border: usize,
}

/// Largest lateral shift per slice (in voxels) of the sun sweep on its first choice of axis;
/// beyond it the sweep slices across the axis where the shift is at most 1 (see [`sweep`]).
const MAX_SHIFT: f64 = 8.0;

/// The sheared line sweep of the module doc, calling `put(cell, voxel index, T_sun)` for every
/// voxel — or, when `dense` is given, only for the voxels of slice rows that hold density (the
/// renderer needs ρ·T_sun, which is 0 elsewhere, and lines crossing only empty rows are not
/// advanced: their optical depth does not change). Cost O(voxels) (O(dense rows) with `dense`).
pub(crate) fn sweep<E: Send>(
    volume: &Volume,
    direction: [f64; 3],
    kappa: f64,
    dense: Option<&DensityRows>,
    out: SweepOut<'_, E>,
    put: impl Fn(&mut E, usize, f32) + Sync,
    ctl: &dyn Control,
) -> Result<(), Canceled> {
    let g = GridFrame::of(volume);
    let s = direction;
    // Slices across the axis the sun's direction is most along; on a grid whose voxels are far
    // from cubic that axis can have a tiny voxel side, and the lateral shift per slice (`da`,
    // `db` below, in voxels) grows with the ratio of the sides: the line arrays, sized by it,
    // reached terabytes for `bounds` spanning 1e8 on one axis and 1 on another (found by
    // Schemathesis, issue 20). Then slice across the axis the sun crosses the most voxels of per
    // unit length instead, where the shift is at most one voxel per slice.
    let along =
        |w: &dyn Fn(usize) -> f64| (0..3).max_by(|&a, &b| w(a).total_cmp(&w(b))).unwrap_or(1);
    let mut k = along(&|i| s[i].abs());
    let shift = |k: usize| {
        (0..3)
            .filter(|&i| i != k)
            .map(|i| (s[i] / s[k]).abs() * g.h[k] / g.h[i])
            .fold(0.0f64, f64::max)
    };
    let first = shift(k);
    if first.is_nan() || first > MAX_SHIFT {
        k = along(&|i| s[i].abs() / g.h[i]);
    }
    let (a, b) = match k {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let dims = g.dims;
    let (na, nb, nk) = (dims[a], dims[b], dims[k]);
    let sk = s[k];
    // Segment length to the previous slice and the lateral offset there, in voxels.
    let seg = g.h[k] / sk.abs();
    let da = s[a] * seg / g.h[a];
    let db = s[b] * seg / g.h[b];
    let stride = [1usize, dims[0], dims[0] * dims[1]];
    let (sa, sb) = (stride[a], stride[b]);
    let rho = &volume.density;
    let row_dense = |ik: usize, ib: usize| dense.is_none_or(|d| d.slice_row(k, ik, ib));
    // Sun-ray lines, indexed by their position in the slice nearest the sun; a line is at
    // `(a_lo + la − j·da, b_lo + lb − j·db)` in the j-th slice away from the sun.
    let span = |d: f64| {
        let far = (nk as f64 - 1.0) * d;
        (
            far.min(0.0).floor() as i64 - 2,
            far.max(0.0).ceil() as i64 + 2,
        )
    };
    let (a_lo, a_hi) = span(da);
    let (b_lo, b_hi) = span(db);
    let nla = (na as i64 + a_hi - a_lo) as usize;
    let nlb = (nb as i64 + b_hi - b_lo) as usize;
    // Per line: accumulated optical depth and the density where it crossed the last slice;
    // per row of lines: whether any line in it still carries a density.
    let mut lines = vec![[0f32; 2]; nla * nlb];
    let mut row_live = vec![false; nlb];
    let segf = seg as f32;
    let kf = kappa as f32;
    let (na_i, nb_i) = (na as i64, nb as i64);
    let SweepOut {
        cells,
        dims: odims,
        border: o,
    } = out;
    let oxy = odims[0] * odims[1];
    for j in 0..nk {
        if j % 8 == 0 {
            ctl.checkpoint()?;
        }
        let ik = if sk > 0.0 { nk - 1 - j } else { j };
        let base = ik * stride[k];
        // The lines sit at integer + (qa_i, qb_i) + fraction (fa, fb), the same fraction for
        // every line of the slice.
        let qa = -(j as f64) * da;
        let qb = -(j as f64) * db;
        let (qa_i, qb_i) = (qa.floor(), qb.floor());
        let (fa, fb) = ((qa - qa_i) as f32, (qb - qb_i) as f32);
        let (qa_i, qb_i) = (qa_i as i64, qb_i as i64);
        // In the box (±½ voxel about the outermost centres) at integer position i + f?
        let inside = |i: i64, f: f32, n: i64| {
            i >= -1 && i < n && {
                let p = i as f32 + f;
                (-0.5..=n as f32 - 0.5).contains(&p)
            }
        };
        lines
            .par_chunks_mut(nla)
            .zip(row_live.par_iter_mut())
            .enumerate()
            .for_each(|(lb, (row, live))| {
                let b0 = b_lo + lb as i64 + qb_i;
                let (ib0, ib1) = (
                    b0.clamp(0, nb_i - 1) as usize,
                    (b0 + 1).clamp(0, nb_i - 1) as usize,
                );
                if !inside(b0, fb, nb_i) || !(row_dense(ik, ib0) || row_dense(ik, ib1)) {
                    if *live {
                        // Into ρ = 0: the last half segment.
                        for l in row.iter_mut() {
                            l[0] += 0.5 * l[1] * segf;
                            l[1] = 0.0;
                        }
                        *live = false;
                    }
                    return;
                }
                *live = true;
                let (cb0, cb1) = (base + ib0 * sb, base + ib1 * sb);
                for (la, l) in row.iter_mut().enumerate() {
                    let a0 = a_lo + la as i64 + qa_i;
                    let r = if inside(a0, fa, na_i) {
                        let ca0 = a0.clamp(0, na_i - 1) as usize * sa;
                        let ca1 = (a0 + 1).clamp(0, na_i - 1) as usize * sa;
                        (1.0 - fb) * ((1.0 - fa) * rho[cb0 + ca0] + fa * rho[cb0 + ca1])
                            + fb * ((1.0 - fa) * rho[cb1 + ca0] + fa * rho[cb1 + ca1])
                    } else {
                        0.0
                    };
                    l[0] += 0.5 * (l[1] + r) * segf;
                    l[1] = r;
                }
            });
        // Each voxel: bilinear between the four lines around it (voxel ia is at line
        // coordinate ia − a_lo − qa).
        let (wa, wb) = (-(a_lo as f64) - qa, -(b_lo as f64) - qb);
        let (wa_i, wb_i) = (wa.floor(), wb.floor());
        let (ga, gb) = ((wa - wa_i) as f32, (wb - wb_i) as f32);
        let (wa_i, wb_i) = (wa_i as usize, wb_i as usize);
        let lt = &lines;
        // Row ib of the slice: T_sun of voxels (0..na, ib) into `buf`; false when skipped.
        let voxel_row = |ib: usize, buf: &mut [f32]| {
            if !row_dense(ik, ib) {
                return false;
            }
            let r0 = &lt[nla * (ib + wb_i) + wa_i..][..na + 1];
            let r1 = &lt[nla * (ib + wb_i + 1) + wa_i..][..na + 1];
            for (ia, t) in buf.iter_mut().enumerate() {
                let tau = (1.0 - gb) * ((1.0 - ga) * r0[ia][0] + ga * r0[ia + 1][0])
                    + gb * ((1.0 - ga) * r1[ia][0] + ga * r1[ia + 1][0]);
                *t = exp_neg(-kf * tau);
            }
            true
        };
        let voxel = |ia: usize, ib: usize| base + ia * sa + ib * sb;
        // Written in place; the rows of a slice are disjoint. Row ib of slice ik is a run of
        // cells for k = z (slab ik) and k = y (slab ib), a column of slab ib for k = x.
        let init = || vec![0f32; na];
        match k {
            2 => cells[(ik + o) * oxy..][..oxy]
                .par_chunks_mut(odims[0])
                .skip(o)
                .take(nb)
                .enumerate()
                .for_each_init(init, |buf, (ib, row)| {
                    if voxel_row(ib, buf) {
                        for (ia, (c, t)) in row[o..][..na].iter_mut().zip(buf.iter()).enumerate() {
                            put(c, voxel(ia, ib), *t);
                        }
                    }
                }),
            1 => cells
                .par_chunks_mut(oxy)
                .skip(o)
                .take(nb)
                .enumerate()
                .for_each_init(init, |buf, (ib, slab)| {
                    if voxel_row(ib, buf) {
                        let row = &mut slab[(ik + o) * odims[0] + o..][..na];
                        for (ia, (c, t)) in row.iter_mut().zip(buf.iter()).enumerate() {
                            put(c, voxel(ia, ib), *t);
                        }
                    }
                }),
            _ => cells
                .par_chunks_mut(oxy)
                .skip(o)
                .take(nb)
                .enumerate()
                .for_each_init(init, |buf, (ib, slab)| {
                    if voxel_row(ib, buf) {
                        for (ia, t) in buf.iter().enumerate() {
                            put(&mut slab[(ia + o) * odims[0] + ik + o], voxel(ia, ib), *t);
                        }
                    }
                }),
        }
    }
    Ok(())
}

/// Reference: `T_sun` at world point `p`, marched toward the sun with `steps_per_voxel` midpoint
/// samples per smallest voxel edge of trilinear density. O(path length); for tests and the
/// sun-direction edit's check.
pub fn transmittance_marched(
    volume: &Volume,
    p: [f64; 3],
    direction: [f64; 3],
    kappa: f64,
    steps_per_voxel: f64,
) -> f64 {
    let g = GridFrame::of(volume);
    let Some((_, t1)) = g.clip(p, direction) else {
        return 1.0;
    };
    let dt0 = g.min_h() / steps_per_voxel.max(0.01);
    let n = (t1 / dt0).ceil().max(1.0) as usize;
    let dt = t1 / n as f64;
    let mut tau = 0.0f64;
    for i in 0..n {
        let t = (i as f64 + 0.5) * dt;
        let q = [0, 1, 2].map(|k| p[k] + t * direction[k]);
        tau += f64::from(g.density_at(&volume.density, q)) * dt;
    }
    (-kappa * tau).exp()
}
