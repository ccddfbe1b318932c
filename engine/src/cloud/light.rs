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

use super::grid::GridFrame;
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
    /// Sweeps the grid (see the module doc). Allocates the optical-depth grid (4 bytes per
    /// voxel) and two slices.
    pub fn compute(
        volume: &Volume,
        direction: [f64; 3],
        kappa: f64,
        ctl: &dyn Control,
    ) -> Result<Self, Canceled> {
        let g = GridFrame::of(volume);
        let s = direction;
        let k = (0..3)
            .max_by(|&a, &b| s[a].abs().total_cmp(&s[b].abs()))
            .unwrap_or(1);
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
        let rho = &volume.density;
        // Sun-ray lines, indexed by their position in the slice nearest the sun; a line is at
        // `(a0 − j·da, b0 − j·db)` in the j-th slice away from the sun.
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
        let mut line_tau = vec![0f32; nla * nlb];
        let mut line_rho = vec![0f32; nla * nlb];
        let mut tau = vec![0f32; volume.len()];
        let mut cur = vec![0f32; na * nb];
        let segf = seg as f32;
        // Slices from the sun side: if the sun is toward +k, the last slice is nearest.
        for j in 0..nk {
            if j % 8 == 0 {
                ctl.checkpoint()?;
            }
            let ik = if sk > 0.0 { nk - 1 - j } else { j };
            let base = ik * stride[k];
            let (sa, sb) = (stride[a], stride[b]);
            // Density in this slice at in-plane voxel coordinates (bilinear, clamped to the
            // edge inside the box, 0 outside).
            let rho_at = |pa: f64, pb: f64| -> f32 {
                if pa < -0.5 || pa > na as f64 - 0.5 || pb < -0.5 || pb > nb as f64 - 0.5 {
                    return 0.0;
                }
                let pa = pa.clamp(0.0, (na - 1) as f64);
                let pb = pb.clamp(0.0, (nb - 1) as f64);
                let a0 = (pa.floor() as usize).min(na - 1);
                let b0 = (pb.floor() as usize).min(nb - 1);
                let a1 = (a0 + 1).min(na - 1);
                let b1 = (b0 + 1).min(nb - 1);
                let fa = (pa - a0 as f64) as f32;
                let fb = (pb - b0 as f64) as f32;
                let r = |x: usize, y: usize| rho[base + x * sa + y * sb];
                (1.0 - fb) * ((1.0 - fa) * r(a0, b0) + fa * r(a1, b0))
                    + fb * ((1.0 - fa) * r(a0, b1) + fa * r(a1, b1))
            };
            let shift_a = j as f64 * da;
            let shift_b = j as f64 * db;
            // Advance the lines that are inside (or next to) the box in this slice.
            line_tau
                .par_chunks_mut(nla)
                .zip(line_rho.par_chunks_mut(nla))
                .enumerate()
                .for_each(|(lb, (lt, lr))| {
                    let pb = (b_lo + lb as i64) as f64 - shift_b;
                    if !(-1.5..=nb as f64 + 0.5).contains(&pb) {
                        return;
                    }
                    for la in 0..nla {
                        let pa = (a_lo + la as i64) as f64 - shift_a;
                        if !(-1.5..=na as f64 + 0.5).contains(&pa) {
                            continue;
                        }
                        let r = rho_at(pa, pb);
                        lt[la] = if j == 0 {
                            // From the box face, half a slice away.
                            0.5 * r * segf
                        } else {
                            lt[la] + 0.5 * (lr[la] + r) * segf
                        };
                        lr[la] = r;
                    }
                });
            // Each voxel: bilinear between the four lines around it.
            let (lt, nla_) = (&line_tau, nla);
            cur.par_chunks_mut(na).enumerate().for_each(|(ib, row)| {
                let fb_pos = ib as f64 + shift_b - b_lo as f64;
                let lb0 = fb_pos.floor();
                let fb = (fb_pos - lb0) as f32;
                let lb0 = lb0 as usize;
                for (ia, out) in row.iter_mut().enumerate() {
                    let fa_pos = ia as f64 + shift_a - a_lo as f64;
                    let la0 = fa_pos.floor();
                    let fa = (fa_pos - la0) as f32;
                    let la0 = la0 as usize;
                    let t = |x: usize, y: usize| lt[x + nla_ * y];
                    *out = (1.0 - fb) * ((1.0 - fa) * t(la0, lb0) + fa * t(la0 + 1, lb0))
                        + fb * ((1.0 - fa) * t(la0, lb0 + 1) + fa * t(la0 + 1, lb0 + 1));
                }
            });
            for ib in 0..nb {
                for ia in 0..na {
                    tau[base + ia * sa + ib * sb] = cur[ia + na * ib];
                }
            }
        }
        let kf = kappa as f32;
        tau.par_chunks_mut(4096).for_each(|c| {
            for t in c {
                *t = (-kf * *t).exp();
            }
        });
        Ok(Self {
            direction,
            kappa,
            transmittance: tau,
        })
    }
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
