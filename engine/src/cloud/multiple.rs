//! Multiple scattering (issue 24; the cloud paper's §5 names it as the next step): the light a
//! cloud voxel receives after the sunlight has scattered one or more times inside the cloud, as a
//! per-voxel *source term* J solved once per light direction on a coarse grid by a few
//! discrete-ordinates sweeps, then read by the camera march like the sun term
//! ([`super::march`]). The method, its assumptions and what it gets wrong are in
//! `docs/cloud-multiple-scattering.md`; in short:
//!
//! **Model.** Extinction σ_t = κρ, scattering σ_s = α·σ_t (α the `albedo`). The camera march of
//! paper Eq. 1 integrates `σ_t·g(t)·S(t)` with the source function (per unit extinction)
//! `S = α·(I_l·Φ·T_sun + I_l·J) + I_m`: the single-scattering term with the exact
//! Henyey–Greenstein phase Φ, plus the in-scattering α·J of the light that has already
//! scattered at least once — J is the angular mean of that light's radiance per unit sun
//! colour (with the renderer's phase normalisation, isotropic Φ = 1, I_l is the sun irradiance
//! over 4π). J is linear in I_l, so the sun-colour least squares still holds.
//!
//! **Anisotropy by similarity** (van de Hulst; the transport / δ-Eddington approximation): the
//! light scattered at least once is treated as scattering isotropically in a medium with
//! `σ_t* = σ_t·(1 − α·g)` and `σ_s* = σ_s·(1 − g)` (single-scattering albedo
//! `α* = α(1 − g)/(1 − αg)`): the forward peak of the HG lobe is counted as no scattering at all.
//! Exact for g = 0; for g ≠ 0 it keeps the diffusion-limit transport but loses the angular
//! shape of the low orders. The sun term keeps the exact HG phase and σ_t.
//!
//! **Equation** for L, the radiance of the light scattered ≥ 1 times (per unit I_l), in the
//! scaled medium: `ω·∇L = σ_t*·(α*·(T_sun* + J) − L)`, `J = (1/4π)∫ L dω`, with
//! `T_sun* = T_sun^{1−αg}` (the scaled sun transmittance: exact, τ scales linearly) and no
//! diffuse light entering the box (black sky; the painted ambient is a term of its own).
//!
//! **Discretisation.** The grid is averaged onto a coarse grid of at most
//! [`MsOptions::max_cells`] cells (k³ blocks of voxels, the smallest integer k): per cell the
//! mean density and the density-weighted mean of `T_sun*`. Directions: the level-symmetric
//! LQ_N quadrature ([`Quadrature`]: S4 24, S6 48, S8 80 directions, weights from Lewis and
//! Miller, *Computational Methods of Neutron Transport*, 1984, Table 4-1). Space: one upwind
//! sweep per direction over the box of occupied cells with the *step-characteristic* update
//! `L_c = L_in·e^{−Δτ} + S_c·(1 − e^{−Δτ})`, where L_in is the upwind neighbours' radiance
//! weighted by the direction's face projections `|ω_k|/h_k` and `Δτ = σ_t*·ℓ`,
//! `ℓ = 1/Σ_k|ω_k|/h_k` the cell's mean chord along ω: positive and exact for a beam along an
//! axis; numerically diffusive across it (the diffuse field is smooth). Scattering: *source
//! iteration* (each iteration adds one scattering order) until the order's contribution falls
//! below [`MsOptions::tolerance`] of the total or [`MsOptions::max_orders`] is reached, then the
//! remaining orders are summed as a geometric series of the last ratio (a power-iteration
//! estimate of the scattering operator's spectral radius: in a thick conservative cloud many
//! orders contribute alike). J is brought back to the voxels trilinearly.
//!
//! Cost: per order, one sweep per direction over the coarse box (directions in parallel, one
//! accumulator per octant, summed in a fixed order: the result does not depend on the thread
//! count); memory 4 floats per coarse cell plus one per cell per octant.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::fastexp::exp_neg;
use crate::{Canceled, Control};

/// The render mode: the paper's single scattering (plus the painted ambient) or with the
/// multiple-scattering source term of this module.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scattering {
    /// Single scattering: paper Eq. 1 as the renderer always had it.
    #[default]
    Single,
    /// Single scattering plus the multiple-scattering source J.
    Multiple,
}

impl Scattering {
    pub fn is_single(&self) -> bool {
        *self == Scattering::Single
    }
}

/// A level-symmetric angular quadrature.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quadrature {
    /// 24 directions.
    S4,
    /// 48 directions.
    S6,
    /// 80 directions.
    S8,
}

impl Quadrature {
    /// Unit directions with weights summing to 1 (the mean over the sphere), grouped by octant:
    /// octant `o` holds the directions whose component signs are the bits of `o`.
    pub fn directions(self) -> Vec<Vec<([f32; 3], f32)>> {
        // First octant points (μ_a, μ_b, μ_c) and their weights.
        let first: Vec<([f64; 3], f64)> = match self {
            Quadrature::S4 => {
                let (a, b) = (0.350_021_2, 0.868_890_3);
                vec![([a, a, b], 1.0), ([a, b, a], 1.0), ([b, a, a], 1.0)]
            }
            Quadrature::S6 => {
                let (a, b, c) = (0.266_635_5, 0.681_507_6, 0.926_180_8);
                let (w1, w2) = (0.176_126_3, 0.157_207_1);
                vec![
                    ([a, a, c], w1),
                    ([a, c, a], w1),
                    ([c, a, a], w1),
                    ([a, b, b], w2),
                    ([b, a, b], w2),
                    ([b, b, a], w2),
                ]
            }
            Quadrature::S8 => {
                let (a, b, c, d) = (0.218_217_9, 0.577_350_3, 0.786_795_8, 0.951_189_7);
                let (w1, w2, w3) = (0.120_987_7, 0.090_740_7, 0.092_592_6);
                vec![
                    ([a, a, d], w1),
                    ([a, d, a], w1),
                    ([d, a, a], w1),
                    ([a, b, c], w2),
                    ([a, c, b], w2),
                    ([b, a, c], w2),
                    ([b, c, a], w2),
                    ([c, a, b], w2),
                    ([c, b, a], w2),
                    ([b, b, b], w3),
                ]
            }
        };
        let total: f64 = 8.0 * first.iter().map(|p| p.1).sum::<f64>();
        (0..8)
            .map(|o| {
                first
                    .iter()
                    .map(|(m, w)| {
                        let n = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
                        let d: [f32; 3] = std::array::from_fn(|k| {
                            let s = if o & (1 << k) != 0 { -1.0 } else { 1.0 };
                            (s * m[k] / n) as f32
                        });
                        (d, (w / total) as f32)
                    })
                    .collect()
            })
            .collect()
    }
}

/// Solver settings (the defaults are the renderer's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MsOptions {
    /// Most coarse cells (the coarsening factor is the smallest integer that fits). Default
    /// 64³ = 262,144: a 128³ volume is solved on 2³ blocks, 256³ on 4³.
    pub max_cells: usize,
    /// Most scattering orders swept before the tail is extrapolated. Default 16: at the κ
    /// chosen from the volume (median optical depth 4) the result is then within about 1 % of
    /// the converged sum; see [`solve`] for thicker clouds.
    pub max_orders: usize,
    /// Stop when the last order adds less than this fraction of the total (extinction-weighted
    /// sums over the cells). Default 0.01.
    pub tolerance: f64,
    /// Sum the orders not swept as a geometric series of the last ratio. Default true.
    pub extrapolate: bool,
    pub quadrature: Quadrature,
}

impl Default for MsOptions {
    fn default() -> Self {
        Self {
            max_cells: 1 << 18,
            max_orders: 16,
            tolerance: 0.01,
            extrapolate: true,
            quadrature: Quadrature::S6,
        }
    }
}

/// The medium's scattering parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Medium {
    /// κ, extinction per unit density per world unit.
    pub kappa: f64,
    /// Single-scattering albedo α, 0–1.
    pub albedo: f64,
    /// Henyey–Greenstein g.
    pub anisotropy: f64,
}

impl Medium {
    /// `1 − αg`: the similarity scaling of the extinction.
    pub fn extinction_scale(&self) -> f64 {
        1.0 - self.albedo * self.anisotropy
    }

    /// α* = α(1 − g)/(1 − αg), the scaled single-scattering albedo.
    pub fn scaled_albedo(&self) -> f64 {
        let s = self.extinction_scale();
        if s <= 0.0 {
            0.0
        } else {
            self.albedo * (1.0 - self.anisotropy) / s
        }
    }
}

/// The solved source term on the coarse grid.
#[derive(Debug, Clone, PartialEq)]
pub struct MsField {
    /// Fine grid size.
    pub dims: [usize; 3],
    /// Coarsening factor k (coarse cell = k³ voxels).
    pub factor: usize,
    /// Coarse grid size.
    pub coarse: [usize; 3],
    /// J per coarse cell (mean radiance of the light scattered ≥ 1 times, per unit sun), x
    /// fastest.
    pub j: Vec<f32>,
    /// Orders swept.
    pub orders: usize,
    /// The last order's ratio to the one before (the tail's ratio when extrapolated).
    pub ratio: f64,
}

impl MsField {
    /// J at fine voxel (x, y, z): trilinear between the coarse cell centres (clamped at the
    /// grid's faces).
    #[inline]
    pub fn at_voxel(&self, x: usize, y: usize, z: usize) -> f32 {
        let k = self.factor as f32;
        let mut i0 = [0usize; 3];
        let mut i1 = [0usize; 3];
        let mut f = [0f32; 3];
        for (a, v) in [x, y, z].into_iter().enumerate() {
            let n = self.coarse[a];
            let u = ((v as f32 + 0.5) / k - 0.5).clamp(0.0, (n - 1) as f32);
            let lo = (u as usize).min(n - 1);
            i0[a] = lo;
            i1[a] = (lo + 1).min(n - 1);
            f[a] = u - lo as f32;
        }
        let [nx, ny, _] = self.coarse;
        let at = |x: usize, y: usize, z: usize| self.j[x + nx * (y + ny * z)];
        let lerp = |a: f32, b: f32, t: f32| a + t * (b - a);
        let y0 = lerp(
            lerp(at(i0[0], i0[1], i0[2]), at(i1[0], i0[1], i0[2]), f[0]),
            lerp(at(i0[0], i1[1], i0[2]), at(i1[0], i1[1], i0[2]), f[0]),
            f[1],
        );
        let y1 = lerp(
            lerp(at(i0[0], i0[1], i1[2]), at(i1[0], i0[1], i1[2]), f[0]),
            lerp(at(i0[0], i1[1], i1[2]), at(i1[0], i1[1], i1[2]), f[0]),
            f[1],
        );
        lerp(y0, y1, f[2])
    }
}

/// The coarsening factor for a grid of `dims` and a budget of `max_cells`.
pub fn coarsening(dims: [usize; 3], max_cells: usize) -> usize {
    let mut k = 1usize;
    loop {
        let cells: usize = dims.iter().map(|n| n.div_ceil(k)).product();
        if cells <= max_cells.max(1) || k >= dims.iter().copied().max().unwrap_or(1) {
            return k;
        }
        k += 1;
    }
}

/// Solves for J (module doc). `dims` and `h` (voxel size, world units) are the fine grid's;
/// `voxel(x, y, z)` gives the fine voxel's `(ρ, ρ·T_sun)` with the unscaled sun transmittance.
///
/// Limitation (measured, `cloud_multiple::orders_converge_…`): the geometric tail takes the
/// last order's ratio as the spectral radius, but the ratio still grows after
/// [`MsOptions::max_orders`] orders when the cloud is optically thick (the low orders are
/// concentrated near the lit surface, where light escapes more easily). At the κ chosen from
/// the volume the result is within about 1 % of the converged sum; on a cumulus with an optical
/// radius of about 13 (spectral radius 0.98) it is about 24 % low, most of it in the core.
pub fn solve(
    dims: [usize; 3],
    h: [f64; 3],
    medium: &Medium,
    opts: &MsOptions,
    voxel: impl Fn(usize, usize, usize) -> (f32, f32) + Sync,
    ctl: &dyn Control,
) -> Result<MsField, Canceled> {
    let k = coarsening(dims, opts.max_cells);
    let coarse = dims.map(|n| n.div_ceil(k));
    let [cx, cy, cz] = coarse;
    let ncells = cx * cy * cz;
    let ext = medium.extinction_scale().max(0.0) as f32;
    let alpha_s = medium.scaled_albedo() as f32;
    // Per coarse cell: scaled extinction σ_t* (world units) and the first-order source
    // α*·T_sun* (per unit extinction).
    let mut sigma = vec![0f32; ncells];
    let mut first = vec![0f32; ncells];
    let kappa = medium.kappa as f32;
    sigma
        .par_chunks_mut(cx * cy)
        .zip(first.par_chunks_mut(cx * cy))
        .enumerate()
        .for_each(|(z, (sg, fs))| {
            let mut rho_sum = vec![0f64; cx * cy];
            let mut src_sum = vec![0f64; cx * cy];
            let mut count = vec![0u32; cx * cy];
            for fz in z * k..((z + 1) * k).min(dims[2]) {
                for fy in 0..dims[1] {
                    let row = (fy / k) * cx;
                    for fx in 0..dims[0] {
                        let c = row + fx / k;
                        let (rho, rt) = voxel(fx, fy, fz);
                        count[c] += 1;
                        if rho > 0.0 {
                            let t = (rt / rho).clamp(0.0, 1.0);
                            let ts = if ext == 1.0 { t } else { t.powf(ext) };
                            rho_sum[c] += f64::from(rho);
                            src_sum[c] += f64::from(rho * ts);
                        }
                    }
                }
            }
            for c in 0..cx * cy {
                if rho_sum[c] > 0.0 && count[c] > 0 {
                    let mean = rho_sum[c] / f64::from(count[c]);
                    sg[c] = kappa * ext * mean as f32;
                    fs[c] = alpha_s * (src_sum[c] / rho_sum[c]) as f32;
                }
            }
        });
    ctl.checkpoint()?;
    let mut field = MsField {
        dims,
        factor: k,
        coarse,
        j: vec![0f32; ncells],
        orders: 0,
        ratio: 0.0,
    };
    if alpha_s <= 0.0 {
        return Ok(field);
    }
    // The box of occupied cells, widened by one (the trilinear read-back touches neighbours;
    // light leaving the convex box never returns, so the sweep is exact on it).
    let mut lo = coarse;
    let mut hi = [0usize; 3];
    for z in 0..cz {
        for y in 0..cy {
            for x in 0..cx {
                if sigma[x + cx * (y + cy * z)] > 0.0 {
                    for (a, v) in [x, y, z].into_iter().enumerate() {
                        lo[a] = lo[a].min(v);
                        hi[a] = hi[a].max(v + 1);
                    }
                }
            }
        }
    }
    if lo[0] >= hi[0] {
        return Ok(field);
    }
    for a in 0..3 {
        lo[a] = lo[a].saturating_sub(1);
        hi[a] = (hi[a] + 1).min(coarse[a]);
    }
    let bx = Box3 { lo, hi, coarse };
    let hc: [f32; 3] = std::array::from_fn(|a| (h[a] * k as f64) as f32);
    let octants = opts.quadrature.directions();
    let weight = |v: &[f32]| -> f64 {
        v.iter()
            .zip(&sigma)
            .map(|(j, s)| f64::from(*j) * f64::from(*s))
            .sum()
    };
    let mut j = vec![0f32; ncells];
    let mut src = vec![0f32; ncells];
    let mut last_gain = 0f64;
    let mut prev_gain = 0f64;
    let mut last_delta = vec![0f32; ncells];
    for order in 0..opts.max_orders.max(1) {
        ctl.checkpoint()?;
        // S = α*·(T_sun* + J) per unit extinction (α*·T_sun* is `first`).
        src.par_iter_mut()
            .zip(first.par_iter().zip(&j))
            .for_each(|(s, (f, jj))| *s = f + alpha_s * jj);
        // One sweep per direction; an accumulator per octant, summed in octant order.
        let parts: Vec<Vec<f32>> = octants
            .par_iter()
            .map(|dirs| {
                let mut acc = vec![0f32; ncells];
                let mut l = vec![0f32; ncells];
                for (d, w) in dirs {
                    sweep(&bx, &sigma, &src, *d, hc, &mut l);
                    for c in bx.cells() {
                        acc[c] += w * l[c];
                    }
                }
                acc
            })
            .collect();
        let mut next = vec![0f32; ncells];
        for p in &parts {
            for (n, v) in next.iter_mut().zip(p) {
                *n += v;
            }
        }
        for ((d, n), o) in last_delta.iter_mut().zip(&next).zip(&j) {
            *d = (n - o).max(0.0);
        }
        j = next;
        prev_gain = last_gain;
        last_gain = weight(&last_delta);
        field.orders = order + 1;
        let total = weight(&j);
        if total <= 0.0 || last_gain <= opts.tolerance * total {
            break;
        }
    }
    if field.orders >= 2 && prev_gain > 0.0 {
        field.ratio = (last_gain / prev_gain).clamp(0.0, 0.98);
        if opts.extrapolate {
            let f = (field.ratio / (1.0 - field.ratio)) as f32;
            for (jj, d) in j.iter_mut().zip(&last_delta) {
                *jj += f * d;
            }
        }
    }
    field.j = j;
    Ok(field)
}

/// The coarse cells swept: `[lo, hi)` of a grid of `coarse` cells.
struct Box3 {
    lo: [usize; 3],
    hi: [usize; 3],
    coarse: [usize; 3],
}

impl Box3 {
    fn cells(&self) -> impl Iterator<Item = usize> + '_ {
        let [cx, cy, _] = self.coarse;
        (self.lo[2]..self.hi[2]).flat_map(move |z| {
            (self.lo[1]..self.hi[1]).flat_map(move |y| {
                let row = cx * (y + cy * z);
                (self.lo[0]..self.hi[0]).map(move |x| row + x)
            })
        })
    }
}

/// One upwind step-characteristic sweep along `d` (module doc) over the box: `l` gets the
/// radiance of every cell in the box (cells outside are not touched). No allocation.
fn sweep(bx: &Box3, sigma: &[f32], src: &[f32], d: [f32; 3], h: [f32; 3], l: &mut [f32]) {
    let [cx, cy, _] = bx.coarse;
    let a: [f32; 3] = std::array::from_fn(|k| d[k].abs() / h[k]);
    let sum = a[0] + a[1] + a[2];
    let chord = 1.0 / sum;
    let wn = a.map(|v| v / sum);
    let (sx, sy, sz) = (d[0] >= 0.0, d[1] >= 0.0, d[2] >= 0.0);
    // The i-th index along axis k in upwind-first order.
    let nth = |k: usize, up: bool, i: usize| if up { bx.lo[k] + i } else { bx.hi[k] - 1 - i };
    let n: [usize; 3] = std::array::from_fn(|k| bx.hi[k] - bx.lo[k]);
    let sxy = cx * cy;
    for iz in 0..n[2] {
        let z = nth(2, sz, iz);
        let z_in = iz > 0;
        for iy in 0..n[1] {
            let y = nth(1, sy, iy);
            let y_in = iy > 0;
            let row = cx * (y + cy * z);
            let row_y = if sy { row.wrapping_sub(cx) } else { row + cx };
            let row_z = if sz { row.wrapping_sub(sxy) } else { row + sxy };
            let mut prev = 0f32;
            for ix in 0..n[0] {
                let x = nth(0, sx, ix);
                let c = row + x;
                let ly = if y_in { l[row_y + x] } else { 0.0 };
                let lz = if z_in { l[row_z + x] } else { 0.0 };
                let lin = wn[0] * prev + wn[1] * ly + wn[2] * lz;
                let s = sigma[c];
                let v = if s > 0.0 {
                    let e = exp_neg(-s * chord);
                    lin * e + src[c] * (1.0 - e)
                } else {
                    lin
                };
                l[c] = v;
                prev = v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NoControl;

    #[test]
    fn quadratures_are_unit_and_normalised_with_zero_mean() {
        for q in [Quadrature::S4, Quadrature::S6, Quadrature::S8] {
            let o = q.directions();
            let all: Vec<_> = o.iter().flatten().collect();
            let w: f32 = all.iter().map(|d| d.1).sum();
            assert!((w - 1.0).abs() < 1e-5, "{q:?} {w}");
            for (d, _) in &all {
                let n = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                assert!((n - 1.0).abs() < 1e-5, "{q:?} {d:?}");
            }
            // Second moment: the mean of ω_k² over the sphere is 1/3.
            for k in 0..3 {
                let m: f32 = all.iter().map(|(d, w)| w * d[k] * d[k]).sum();
                assert!((m - 1.0 / 3.0).abs() < 1e-4, "{q:?} {m}");
            }
        }
    }

    #[test]
    fn albedo_zero_gives_no_scattered_light_and_coarsening_fits() {
        let dims = [8, 8, 8];
        let m = Medium {
            kappa: 10.0,
            albedo: 0.0,
            anisotropy: 0.0,
        };
        let f = solve(
            dims,
            [0.125; 3],
            &m,
            &MsOptions::default(),
            |_, _, _| (1.0, 0.5),
            &NoControl,
        )
        .unwrap();
        assert!(f.j.iter().all(|&v| v == 0.0));
        assert_eq!(coarsening([128, 128, 128], 1 << 18), 2);
        assert_eq!(coarsening([256, 256, 256], 1 << 18), 4);
        assert_eq!(coarsening([111, 222, 112], 1 << 18), 3);
        assert_eq!(coarsening([8, 8, 8], 1 << 18), 1);
    }
}
