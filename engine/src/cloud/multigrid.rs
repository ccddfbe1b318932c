//! Colourization by optimization (Levin, Lischinski and Weiss 2004) on the 3-D voxel grid,
//! solved by multigrid (SPEC §3.2; the paper: "the method of ref. 4 on the GPU, accelerated by
//! the multigrid method of ref. 5").
//!
//! The system, per RGB channel: every free voxel r satisfies `U(r) − Σ_s w_rs U(s) = 0` over its
//! 6-neighbourhood, pinned voxels keep their colour (Dirichlet). The weights follow LLW's code
//! (`getColorExact.m`): with the guide Y (here each voxel's direct light, the sun transmittance),
//! `w_rs ∝ exp(−(Y_r − Y_s)²/c)`, `c_r = max(0.6·var_r, min_s (Y_r − Y_s)²/ln 100, 2·10⁻⁶)` where
//! var_r is the variance of Y over r and its neighbours, normalised to sum 1 over s.
//!
//! Readings chosen:
//! - `c` is symmetrised per edge, `c_rs = ½(c_r + c_s)`, so the affinities
//!   `a_rs = exp(−(Y_r − Y_s)²/c_rs)` are symmetric. LLW's equation `U_r = Σ_s a_rs U_s / Σ_s
//!   a_rs` is then the graph-Laplacian system `Σ_s a_rs (U_r − U_s) = 0` — symmetric positive
//!   definite with the pins as Dirichlet values — which conjugate gradients can accelerate.
//! - *Unknowns*: the cloud voxels connected to a pin through the cloud — SPEC §3.2 propagates
//!   "to all cloud voxels" (which voxels are cloud is the caller's: the ambient edit takes ρ ≥
//!   1 % of the maximum, as the sun-direction edit does). Empty voxels never show (the renderer weights the field
//!   by ρ), and a puff no pin reaches has no equation fixing its colour; both keep a value the
//!   caller gives (the ambient edit: what the base version showed there). Earlier sessions took
//!   every voxel of the box as an unknown, so that lit air (T ≈ 1, like lit cloud tops) carried
//!   colour between puffs; that made a typical cloud's system ~10× larger than its cloud (the
//!   128³ cumulus: 10 % of the box) and let paint leak through the air into puffs it never
//!   touched. A volume with density everywhere (smoke with a faint haze) is still a full box.
//! - The three channels share the matrix and are solved in one pass (RGB triples per voxel);
//!   conjugate gradients keep one step length per channel.
//!
//! # The solver
//!
//! Conjugate gradients preconditioned by one multigrid cycle per iteration:
//! - *Fine level*: the 7-point LLW Laplacian on the unknowns in compressed rows, numbered red
//!   then black so that the multicolour Gauss–Seidel of every level is red–black there
//!   ([`fine`]), the iterate in f64 and its true residual recomputed every iteration (so the reported figures
//!   are the residuals of the returned field, not of a recurrence), the cycle in f32.
//! - *Coarse levels*: smoothed aggregation ([`aggregate`]) — aggregates of strongly coupled
//!   points, the prolongation their indicator smoothed by a damped Jacobi step of the filtered
//!   operator — with Galerkin coarse operators `PᵀAP` ([`galerkin`]): the weights of every
//!   level are recomputed from the level below, as the product, not re-derived from a coarsened
//!   guide. Coarse points are numbered by colour and smoothed by multicolour Gauss–Seidel
//!   ([`graph`]); coarsening stops at ≤ 700 points, solved by a dense Cholesky factorisation.
//! - *Cycle*: ν = 2 sweeps before and after each coarse correction (colours reversed after),
//!   restriction `Pᵀ`; below level 1 each coarse problem gets two cycles (a W-cycle there; the
//!   fine level and level 1 are visited once). Symmetric, so a valid CG preconditioner.
//!
//! Measured (cumulus tests, default sun, κ = 40; `cloud_edit::multigrid_reaches_1e_6_*`, on
//! the cloud voxels and on the whole box): 1e-6 in 7–8 iterations at 32³, 64³ and 128³, every
//! iteration cutting the residual by at least 5× (the figures are per preconditioned CG
//! iteration = per cycle).
//!
//! # Rejected designs (measured)
//!
//! - *Rediscretised geometric multigrid* (cell-centred, the guide averaged and the weights
//!   recomputed per level, pins restricted as "any child pinned"): stalled at 0.92 per cycle or
//!   diverged; as a CG preconditioner 2.4–3.2× per iteration.
//! - *Galerkin geometric multigrid* (vertex-centred, Dendy's operator-dependent "black box"
//!   prolongation, 27-point `PᵀAP`, 8-colour Gauss–Seidel): 25–34× per CG iteration with a
//!   uniform guide, but only 2–3× on the cumulus, whatever the smoothing (8 sweeps: 5–10×) and
//!   whatever the sun direction. The slow error sits on 1-voxel sheets where the guide's
//!   gradient is near an axis: LLW's local normalisation (`c ≈ 0.6·var`, the variance taken
//!   over the same 7 voxels) makes the weights across such a sheet `exp(−d²/0.17·d²) ≈ 0.003`
//!   against ~1 within it — ~300:1 anisotropy whose direction changes from voxel to voxel.
//!   Point smoothers with full coarsening cannot reach those errors; coarsening along the
//!   strong couplings (aggregation) can.
//! - *A pure V-cycle* below level 1 (one cycle per coarse problem): 3.5–4.8× per iteration at
//!   64³ and 128³ (the level-2 aggregates get large: ~20 points of level 1 each); more sweeps
//!   on the coarse levels (4 or 8) reached 4.2–6.4×, the W below level 1 more cheaply 5.2–8×.
//! - *Point pins alone* are the other hard case for any hierarchy: a single pinned voxel in 3-D
//!   has a capacitance that halves per level, so its "far-field" mode converges at ~2× per
//!   stationary cycle; conjugate gradients remove those few modes, one reason CG stays.

// Index loops over the 3 channels, the 3 axes and the 27 stencil entries read clearer than zips.
#![allow(clippy::needless_range_loop)]

mod aggregate;
mod dense;
mod fine;
mod galerkin;
mod graph;
mod llw;

use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::{Canceled, Control};
use aggregate::Prolongation;
use dense::Dense;
use fine::fine_level;
use fine::FineLevel;
use graph::{dot3, Adjacency, Graph, Rgb};
pub use llw::llw_weights;

/// Coarsening stops once a level has at most this many points; that level is solved by a
/// dense Cholesky factorisation (n³/3 ≈ 0.1 G flops at most, once; n² per solve).
const COARSEST_POINTS: usize = 700;
/// The largest coarsest level factored densely (8·n² bytes); past it (coarsening stalled,
/// which the LLW weights do not cause) the coarsest level is smoothed instead.
const DENSE_MAX: usize = 3000;
/// Symmetric sweep pairs on a coarsest level too large to factor.
const FALLBACK_SWEEPS: usize = 20;
/// Strength threshold of the fine level's aggregation (halved per level; see [`aggregate`]).
const THETA: f32 = 0.08;
/// Cycles on each coarse problem below level 1 (2: a W-cycle there; see the module doc).
const COARSE_CYCLES: usize = 2;

/// What the solve did.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveStats {
    /// The relative residual `‖b − L·U‖ / ‖b‖` (of the iterate itself, in f64) before the
    /// first iteration (1) and after each.
    pub residuals: Vec<f64>,
    /// Levels of the hierarchy, the fine grid included.
    pub levels: usize,
    /// Time spent on the LLW weights and the hierarchy (prolongations, Galerkin products, the
    /// coarsest factorisation).
    pub setup: Duration,
    /// Time spent in the iterations.
    pub solve: Duration,
}

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveOptions {
    /// Stop at this relative residual. Default 1e-6.
    pub tolerance: f64,
    /// At most this many conjugate-gradient iterations (one multigrid cycle each). Default 30
    /// (the cumulus tests need 7–8).
    pub max_iterations: usize,
    /// Gauss–Seidel sweeps before and after the coarse correction on every level. Default 2
    /// (1 sweep: 5.3–6.4× per iteration on the 32³ cumulus but the first iterations of larger
    /// grids below 5×; 3: no better per unit of work).
    pub smoothing: usize,
    /// Screening λ ≥ 0 added to every unknown's diagonal: the system becomes
    /// `Σ_s a_rs (U_r − U_s) + λ U_r = (pins' terms)`, each unknown tied to 0 with weight λ, so
    /// what the pins impose decays with the distance from them, over about 1/√λ voxels where
    /// the affinities are ≈ 1 (the ambient edit propagates a *change* this way: see
    /// [`crate::cloud::edit::ambient`]). Default 0: LLW's system as it is.
    pub screening: f32,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-6,
            max_iterations: 30,
            smoothing: 2,
            screening: 0.0,
        }
    }
}

/// Per-level vectors of the V-cycle: the correction, the right-hand side, the residual.
struct Work {
    e: Vec<Rgb>,
    b: Vec<Rgb>,
    r: Vec<Rgb>,
}

impl Work {
    fn new(n: usize) -> Self {
        Self {
            e: vec![[0.0; 3]; n],
            b: vec![[0.0; 3]; n],
            r: vec![[0.0; 3]; n],
        }
    }
}

/// The multigrid hierarchy: the operators of every level (the fine one first), the
/// prolongations between them and the factored coarsest level.
struct Hierarchy {
    ops: Vec<Graph>,
    transfers: Vec<Prolongation>,
    /// The factored coarsest level (None if coarsening stalled above [`DENSE_MAX`] points).
    dense: Option<Dense>,
    work: Vec<Work>,
    /// Scratch of the repeated coarse cycles.
    keep: Vec<Rgb>,
}

impl Hierarchy {
    /// `grid_order`: the fine points in grid order (aggregation meets them so; see
    /// [`fine::FineLevel::grid_order`]).
    fn build(fine: Graph, grid_order: &[u32], ctl: &dyn Control) -> Result<Self, Canceled> {
        let mut work = vec![Work::new(fine.len())];
        let mut ops = vec![fine];
        let mut transfers = Vec::new();
        let mut theta = THETA;
        loop {
            ctl.checkpoint()?;
            let a = &ops[ops.len() - 1];
            let n = a.len();
            if n <= COARSEST_POINTS {
                break;
            }
            let order = (ops.len() == 1).then_some(grid_order);
            let (t, c) = coarsen(a, theta, order);
            // Aggregation that no longer shrinks the level (every coupling weak) would only
            // add cost; the smoother is then left to do the work on this level.
            if c.len() * 10 > n * 9 {
                break;
            }
            work.push(Work::new(c.len()));
            transfers.push(t);
            ops.push(c);
            theta *= 0.5;
        }
        ctl.checkpoint()?;
        let last = &ops[ops.len() - 1];
        let dense = (last.len() <= DENSE_MAX).then(|| Dense::factor(last));
        Ok(Self {
            ops,
            transfers,
            dense,
            work,
            keep: Vec::new(),
        })
    }

    fn levels(&self) -> usize {
        self.ops.len()
    }

    /// One cycle on level `l`: `work[l].e ≈ A⁻¹ work[l].b`, starting from zero. Pre-smoothing,
    /// the coarse correction, post-smoothing in the reverse colour order; below level 1 the
    /// coarse problem gets [`COARSE_CYCLES`] cycles (a W-cycle there). Symmetric (the
    /// post-smoother is the pre-smoother's adjoint, restriction is `Pᵀ`, the coarsest solve
    /// exact, repeated coarse cycles are a symmetric stationary iteration), so it is a valid
    /// conjugate-gradient preconditioner.
    fn cycle(&mut self, l: usize, nu: usize) {
        if l + 1 == self.levels() {
            let w = &mut self.work[l];
            match &self.dense {
                Some(d) => d.solve(&w.b, &mut w.e),
                None => {
                    // Coarsening stalled on a large level: symmetric sweeps instead.
                    w.e.par_iter_mut().for_each(|v| *v = [0.0; 3]);
                    for _ in 0..FALLBACK_SWEEPS {
                        self.ops[l].smooth(&mut w.e, &w.b, false);
                        self.ops[l].smooth(&mut w.e, &w.b, true);
                    }
                }
            }
            return;
        }
        let op = &self.ops[l];
        {
            let w = &mut self.work[l];
            w.e.par_iter_mut().for_each(|v| *v = [0.0; 3]);
            for _ in 0..nu {
                op.smooth(&mut w.e, &w.b, false);
            }
        }
        {
            let (head, tail) = self.work.split_at_mut(l + 1);
            let w = &mut head[l];
            op.residual(&w.e, &w.b, &mut w.r);
            self.transfers[l].restrict(&w.r, &mut tail[0].b);
        }
        self.cycle(l + 1, nu);
        if l > 0 && l + 2 < self.levels() {
            for _ in 1..COARSE_CYCLES {
                // Another cycle on the coarse problem, from its residual: e += M (b − A e).
                let mut keep = std::mem::take(&mut self.keep);
                let c = &mut self.work[l + 1];
                self.ops[l + 1].residual(&c.e, &c.b, &mut c.r);
                keep.clear();
                keep.extend_from_slice(&c.e);
                std::mem::swap(&mut c.b, &mut c.r);
                self.cycle(l + 1, nu);
                let c = &mut self.work[l + 1];
                for (e, k) in c.e.iter_mut().zip(&keep) {
                    for q in 0..3 {
                        e[q] += k[q];
                    }
                }
                self.keep = keep;
            }
        }
        let (head, tail) = self.work.split_at_mut(l + 1);
        let w = &mut head[l];
        self.transfers[l].prolong_add(&tail[0].e, &mut w.e);
        for _ in 0..nu {
            self.ops[l].smooth(&mut w.e, &w.b, true);
        }
    }
}

/// One coarsening step: aggregation, smoothed prolongation, Galerkin product.
/// `order`: the order in which aggregation meets the points (index order if None).
fn coarsen<A: Adjacency>(a: &A, theta: f32, order: Option<&[u32]>) -> (Prolongation, Graph) {
    let diag: Vec<f32> = (0..a.len())
        .into_par_iter()
        .map(|i| a.diagonal(i))
        .collect();
    let (mut p, nc) = Prolongation::build(a, &diag, theta, order);
    let g = galerkin::galerkin(a, &diag, &mut p, nc);
    (p, g)
}

/// Propagates `pins` (flat index, linear RGB) over the cloud of the grid of `dims` (x fastest)
/// guided by `guide` (one value per voxel) and returns every voxel's colour, the LLW system
/// solved by multigrid-preconditioned conjugate gradients to `opts.tolerance` (module doc).
///
/// The cloud is the voxels marked in `cloud` (every voxel when None); pins are part of it
/// whatever the mask says. The unknowns are the cloud voxels connected to a pin
/// through the cloud (see [`fine`]); every other voxel — empty space, and puffs no pin
/// reaches — gets `fill(voxel)`. A voxel pinned twice takes the later colour; pins outside the
/// grid are ignored. `guide` (and `cloud`) must hold `dims[0]·dims[1]·dims[2]` values.
/// Allocates about 40 bytes per voxel and 150 per unknown.
pub fn propagate(
    dims: [usize; 3],
    guide: &[f32],
    cloud: Option<&[bool]>,
    pins: &[(usize, [f32; 3])],
    fill: &(dyn Fn(usize) -> [f32; 3] + Sync),
    opts: SolveOptions,
    ctl: &dyn Control,
) -> Result<(Vec<[f32; 3]>, SolveStats), Canceled> {
    let start = Instant::now();
    let n = guide.len();
    let mut stats = SolveStats {
        residuals: vec![1.0],
        levels: 0,
        setup: Duration::ZERO,
        solve: Duration::ZERO,
    };
    let Some(Setup {
        fine,
        pin_at,
        colors,
    }) = set_up(dims, guide, cloud, pins, opts.screening)
    else {
        return Ok(((0..n).into_par_iter().map(fill).collect(), stats));
    };
    let m = fine.voxel.len();
    let mut x = vec![[0f64; 3]; m];
    if m > 0 {
        let mut h = Hierarchy::build(fine.op, &fine.grid_order, ctl)?;
        stats.levels = h.levels();
        stats.setup = start.elapsed();
        let start = Instant::now();
        let fine_op = &h.ops[0];
        let norm0 = fine_op.residual_f64(&x, &fine.b, &mut h.work[0].b).sqrt();
        if norm0 > 0.0 {
            cg(&mut h, &fine.b, &mut x, norm0, opts, &mut stats, ctl)?;
        }
        stats.solve = start.elapsed();
    }
    let mut out: Vec<[f32; 3]> = (0..n)
        .into_par_iter()
        .map(|i| match pin_at[i] {
            fine::NONE if fine.reached[i] => [0.0; 3],
            fine::NONE => fill(i),
            p => colors[p as usize],
        })
        .collect();
    for (u, &i) in fine.voxel.iter().enumerate() {
        out[i as usize] = x[u].map(|v| v as f32);
    }
    Ok((out, stats))
}

/// A propagation problem set up: the fine level, each voxel's pin (index into `colours`, or
/// [`fine::NONE`]) and the pins' colours.
struct Setup {
    fine: FineLevel,
    pin_at: Vec<u32>,
    colors: Vec<[f32; 3]>,
}

/// The fine level of [`propagate`]'s problem; None when there is nothing to solve (sizes that
/// do not match `dims`, no pin inside the grid).
fn set_up(
    dims: [usize; 3],
    guide: &[f32],
    cloud: Option<&[bool]>,
    pins: &[(usize, [f32; 3])],
    screening: f32,
) -> Option<Setup> {
    let n = guide.len();
    if n == 0 || n != dims[0] * dims[1] * dims[2] || cloud.is_some_and(|d| d.len() != n) {
        return None;
    }
    let mut pin_at = vec![fine::NONE; n];
    let mut colors = Vec::with_capacity(pins.len());
    for &(i, c) in pins {
        if i < n {
            pin_at[i] = colors.len() as u32;
            colors.push(c);
        }
    }
    if colors.is_empty() {
        return None;
    }
    // The cloud, pins included; the LLW weights only between its voxels.
    let mask = cloud.is_some();
    let cloud: Vec<bool> = match cloud {
        Some(c) => c
            .par_iter()
            .zip(&pin_at)
            .map(|(&c, &p)| c || p != fine::NONE)
            .collect(),
        None => vec![true; n],
    };
    let a = llw::llw_weights_in(dims, guide, mask.then_some(&cloud[..]));
    let fine = fine_level(dims, &a, &cloud, &pin_at, &colors, screening);
    Some(Setup {
        fine,
        pin_at,
        colors,
    })
}

/// [`propagate`]'s linear system on its unknowns, for a general solver to be compared with
/// ours (the benchmarks' baseline): row `k`'s off-diagonal entries are `−conductance[p]` at
/// columns `col[p]`, `p` in `ptr[k]..ptr[k + 1]`; its diagonal is `excess[k] + Σ_p
/// conductance[p]`; `b[k]` its right-hand side per channel. Empty when there is nothing to
/// solve.
#[derive(Debug, Clone, Default)]
pub struct LlwSystem {
    pub ptr: Vec<usize>,
    pub col: Vec<u32>,
    pub conductance: Vec<f32>,
    pub excess: Vec<f32>,
    pub b: Vec<[f64; 3]>,
}

/// The system [`propagate`] solves (see [`LlwSystem`]).
pub fn llw_system(
    dims: [usize; 3],
    guide: &[f32],
    cloud: Option<&[bool]>,
    pins: &[(usize, [f32; 3])],
) -> LlwSystem {
    match set_up(dims, guide, cloud, pins, 0.0) {
        Some(Setup { fine, .. }) => LlwSystem {
            ptr: fine.op.ptr,
            col: fine.op.col,
            conductance: fine.op.c,
            excess: fine.op.excess,
            b: fine.b,
        },
        None => LlwSystem::default(),
    }
}

/// Conjugate gradients per channel on the fine level of `h` (right-hand side `b`, iterate `x`
/// from zero), preconditioned by one multigrid cycle: z = M r in `work[0].e` (r in
/// `work[0].b`), q = A p in `work[0].r` (free between cycles). The residual of `x` is recomputed
/// in f64 every iteration (not the recurrence), so the reported figures are exact.
fn cg(
    h: &mut Hierarchy,
    b: &[[f64; 3]],
    x: &mut [[f64; 3]],
    norm0: f64,
    opts: SolveOptions,
    stats: &mut SolveStats,
    ctl: &dyn Control,
) -> Result<(), Canceled> {
    let mut p = vec![[0f32; 3]; x.len()];
    let mut rz_old = [0f64; 3];
    for k in 0..opts.max_iterations {
        ctl.checkpoint()?;
        h.cycle(0, opts.smoothing.max(1));
        let op = &h.ops[0];
        let w = &mut h.work[0];
        let rz = dot3(&w.b, &w.e);
        let beta: [f64; 3] = std::array::from_fn(|c| {
            if k > 0 && rz_old[c] > 0.0 {
                rz[c] / rz_old[c]
            } else {
                0.0
            }
        });
        rz_old = rz;
        p.par_iter_mut().zip(w.e.par_iter()).for_each(|(pv, zv)| {
            for c in 0..3 {
                pv[c] = (f64::from(zv[c]) + beta[c] * f64::from(pv[c])) as f32;
            }
        });
        op.apply(&p, &mut w.r);
        let pq = dot3(&p, &w.r);
        let alpha: [f64; 3] =
            std::array::from_fn(|c| if pq[c] > 0.0 { rz[c] / pq[c] } else { 0.0 });
        x.par_iter_mut().zip(p.par_iter()).for_each(|(xv, pv)| {
            for c in 0..3 {
                xv[c] += alpha[c] * f64::from(pv[c]);
            }
        });
        let rel = op.residual_f64(x, b, &mut w.b).sqrt() / norm0;
        stats.residuals.push(rel);
        if rel <= opts.tolerance {
            break;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
