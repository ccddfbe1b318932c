//! Snowfall (journal §2.3 "降雪処理", Eq. 1; SPEC §2 step 3) and the model's time loop.
//!
//! A cell's snow after time T is `S(T) = P · ∫₀ᵀ M(t) dt` (Eq. 1), M the snowfall rate in metres of
//! fresh snow per hour on open ground. M is a constant or a schedule `[[hour, rate], …]`, read as
//! piecewise constant: each rate holds from its hour until the next entry's hour (the last until
//! the end; zero before the first). The `duration_h` hours are cut into `steps` equal increments;
//! each step deposits `P · ΔM` on every cell and stabilizes (erosion and routing,
//! [`super::route`], then [`super::settle`]'s sweeps where needed), as the paper does per animation
//! frame.
//!
//! Deposits are integers ([`SNOW_UNIT_M`]): step n gives a cell `round(P·C(tₙ)/u) −
//! round(P·C(tₙ₋₁)/u)` units (C = ∫M), so while P is fixed the rounding telescopes and the total is
//! `round(P·C(T)/u)` however many steps. "Fallen" is the sum of the deposits, so the mass balance
//! `fallen = resting + lost` holds to the unit.
//!
//! The paper holds P fixed while the snow grows; `reproject_every = n > 0` recomputes P on the snow
//! surface before every n-th step (snow filling a gap under an overhang then sees less sky).

use std::time::Instant;

use rayon::prelude::*;

use super::maps::{capacity_units, SnowMaps, SNOW_UNIT_M};
use super::probability::{angle_weights, snow_probability, snowfall_directions, Receiver, Wind};
use super::region::build_snow_maps;
use super::route::{Clock, Router};
use super::settle::{repose_residual, Settler, MODEL_JACOBI_ITERATIONS, MODEL_SWEEP_RELAXATION};
use crate::geom::mesh::Mesh;
use crate::{Canceled, Control};

/// The snowfall rate M(t).
#[derive(Debug, Clone, PartialEq)]
pub enum Snowfall {
    /// Metres of fresh snow per hour on open ground.
    Constant(f64),
    /// `(hour, rate m/h)` pairs, hours increasing; piecewise constant (module doc).
    Schedule(Vec<(f64, f64)>),
}

impl Snowfall {
    /// ∫₀ᵗ M, metres (t in hours).
    pub fn cumulative(&self, t: f64) -> f64 {
        match self {
            Snowfall::Constant(r) => r.max(0.0) * t.max(0.0),
            Snowfall::Schedule(s) => {
                let mut acc = 0.0;
                for (k, &(h, r)) in s.iter().enumerate() {
                    if t <= h {
                        break;
                    }
                    let end = s.get(k + 1).map_or(t, |n| n.0.min(t));
                    acc += r.max(0.0) * (end - h).max(0.0);
                }
                acc
            }
        }
    }
}

/// The default snowfall rate, m/h: 12 h of it (the default `duration_h`) is 0.24 m, a heavy
/// day's snow on open ground.
pub const DEFAULT_RATE_M_PER_H: f64 = 0.02;

/// Accumulation increments when none are given (see the `steps` parameter's doc for why 12).
pub const DEFAULT_STEPS: usize = 12;

/// Everything the model (SPEC §2 steps 1–5) needs. See [`ModelParams::default`] for defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelParams {
    /// Cells across the scene's longer horizontal side. Default 512; paper 100–200.
    pub resolution: usize,
    /// Snowfall directions K. Default 32; paper 5.
    pub directions: usize,
    /// Angular std of the directions, degrees. Default 10.
    pub spread_deg: f32,
    /// Tilt of the main direction by wind; `None` = vertical. Default `None`.
    pub wind: Option<Wind>,
    /// Weight directions by their angle (workshop). Default false.
    pub angle_weighting: bool,
    /// Seed of the directions. Default 0.
    pub seed: u64,
    /// Snowfall rate. Default 0.02 m/h.
    pub snowfall: Snowfall,
    /// Hours of snowfall. Default 12.
    pub duration_h: f64,
    /// Increments. Default [`DEFAULT_STEPS`].
    pub steps: usize,
    /// Recompute P on the snow surface every n steps; 0 = never (paper). Default 0.
    pub reproject_every: usize,
    /// Angle of repose, degrees (paper 45–60). Default 50.
    pub repose_angle_deg: f32,
    /// Stabilization iterations per step at most. Default 500.
    pub max_stabilize_iterations: usize,
}

impl Default for ModelParams {
    fn default() -> Self {
        Self {
            resolution: 512,
            directions: 32,
            spread_deg: 10.0,
            wind: None,
            angle_weighting: false,
            seed: 0,
            snowfall: Snowfall::Constant(DEFAULT_RATE_M_PER_H),
            duration_h: 12.0,
            steps: DEFAULT_STEPS,
            reproject_every: 0,
            repose_angle_deg: 50.0,
            max_stabilize_iterations: 500,
        }
    }
}

/// Mass balance of a run (m³ and exact units).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MassBalance {
    pub fallen_units: u64,
    pub lost_units: u64,
    /// Per layer, units.
    pub resting_units: Vec<u64>,
    pub fallen_m3: f64,
    pub lost_m3: f64,
    pub resting_m3: Vec<f64>,
}

/// What [`simulate`] reports besides the maps.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelReport {
    pub balance: MassBalance,
    /// Stabilization iterations over all steps.
    pub stabilize_iterations: usize,
    /// Steps whose stabilization stopped at `max_stabilize_iterations`.
    pub unconverged_steps: usize,
    /// Steps whose routing ran past its safety net ([`super::route`], step 3) and left the
    /// rest to the sweep (none on any mesh measured since the pit levelling was fixed).
    pub routing_over_budget_steps: usize,
    /// Stabilization iterations of each step (fine level; in step order).
    pub step_iterations: Vec<u32>,
    /// The final state's repose residual ([`super::settle::repose_residual`]): the steepest
    /// slope from a cell with snow above `tan(repose)`, tan units (0: none).
    pub residual_tan: f32,
    /// (stage, milliseconds): "regions", "probability", "snowfall" (accumulate + stabilize).
    pub timings: Vec<(&'static str, f64)>,
}

/// Deposit `P · (after_m − before_m)` on every cell (module doc for the rounding), `before_m` and
/// `after_m` being cumulative snowfall on open ground (metres), but no more than fits under the
/// cell's ceiling ([`super::maps::MapLayer::capacity`]; what does not fit is not deposited, as snow
/// on a wall is not, so it is not counted as fallen either). Returns the units deposited.
pub fn accumulate_between(maps: &mut SnowMaps, before_m: f64, after_m: f64) -> u64 {
    let (a, b) = (before_m / SNOW_UNIT_M, after_m / SNOW_UNIT_M);
    let mut total = 0u64;
    for layer in &mut maps.layers {
        total += layer
            .snow
            .par_iter_mut()
            .zip(layer.probability.par_iter())
            .zip(layer.base.par_iter().zip(layer.ceiling.par_iter()))
            .map(|((s, &p), (&base, &ceiling))| {
                // No probability (also every cell without this layer): nothing lands. Most cells
                // of the deeper layers; the two roundings below were 22 % of a default run's
                // instructions on the 4,960-triangle table (callgrind, session 16).
                if p <= 0.0 {
                    return 0;
                }
                let p = f64::from(p);
                let d = (round(p * b) - round(p * a)).max(0.0) as u64;
                // Not past the ceiling: snow that does not fit lands on what is above instead.
                let cap = capacity_units(base, ceiling);
                let d = d.min(u64::from(cap.saturating_sub(*s)));
                *s += d as u32;
                d
            })
            .sum::<u64>();
    }
    total
}

/// `x.round()` (half away from zero), without the library call it compiles to on the baseline
/// x86-64 target (no SSE4.1 `roundsd`): for `0 ≤ x < 2⁵²` the integer part is exact as a cast
/// and the fraction `x − ⌊x⌋` exactly representable, so this is the same value (`-0.0` gives
/// `0.0`); any other `x` goes to `f64::round`.
#[inline]
fn round(x: f64) -> f64 {
    if (0.0..4_503_599_627_370_496.0).contains(&x) {
        let t = x as u64 as f64;
        if x - t >= 0.5 {
            t + 1.0
        } else {
            t
        }
    } else {
        x.round()
    }
}

/// [`accumulate_between`] for the model's time loop, the same deposits bit for bit, at half the
/// roundings: step n's `round(P · C(tₙ₋₁) / u)` is step n − 1's `round(P · C(tₙ) / u)`, kept per
/// cell (valid while P and the cumulative amount it was taken at are unchanged), and the
/// capacities are computed once.
struct Deposit {
    /// Per layer and cell: `round(P · after / unit)` of the last call.
    prev: Vec<Vec<f64>>,
    /// Per layer and cell: [`capacity_units`].
    cap: Vec<Vec<u32>>,
    /// The `after / unit` (bits) of the last call, while `prev` holds for it.
    at: Option<u64>,
}

impl Deposit {
    fn new(maps: &SnowMaps) -> Self {
        Self {
            prev: maps
                .layers
                .iter()
                .map(|l| vec![0.0; l.snow.len()])
                .collect(),
            cap: maps
                .layers
                .iter()
                .map(|l| {
                    l.base
                        .par_iter()
                        .zip(l.ceiling.par_iter())
                        .map(|(&b, &c)| capacity_units(b, c))
                        .collect()
                })
                .collect(),
            at: None,
        }
    }

    /// P changed: the kept roundings no longer hold.
    fn invalidate(&mut self) {
        self.at = None;
    }

    /// As [`accumulate_between`].
    fn run(&mut self, maps: &mut SnowMaps, before_m: f64, after_m: f64) -> u64 {
        let (a, b) = (before_m / SNOW_UNIT_M, after_m / SNOW_UNIT_M);
        let kept = self.at == Some(a.to_bits());
        let mut total = 0u64;
        for ((layer, prev), cap) in maps
            .layers
            .iter_mut()
            .zip(self.prev.iter_mut())
            .zip(self.cap.iter())
        {
            total += layer
                .snow
                .par_iter_mut()
                .zip(layer.probability.par_iter())
                .zip(prev.par_iter_mut().zip(cap.par_iter()))
                .map(|((s, &p), (prev, &cap))| {
                    if p <= 0.0 {
                        return 0;
                    }
                    let p = f64::from(p);
                    let ra = if kept { *prev } else { round(p * a) };
                    let rb = round(p * b);
                    *prev = rb;
                    let d = (rb - ra).max(0.0) as u64;
                    let d = d.min(u64::from(cap.saturating_sub(*s)));
                    *s += d as u32;
                    d
                })
                .sum::<u64>();
        }
        self.at = Some(b.to_bits());
        total
    }
}

/// Deposit `P · amount_m` on every cell; returns the units deposited.
pub fn accumulate(maps: &mut SnowMaps, amount_m: f64) -> u64 {
    accumulate_between(maps, 0.0, amount_m)
}

/// Run the model: snow maps, probability, then `steps` increments of snowfall each followed by
/// stabilization; `on_frame(maps, step)` after every step (1-based). Progress stages "regions",
/// "probability", "snowfall" over the whole [0, 1].
pub fn simulate(
    mesh: &Mesh,
    p: &ModelParams,
    ctl: &dyn Control,
    mut on_frame: impl FnMut(&SnowMaps, usize),
) -> Result<(SnowMaps, ModelReport), Canceled> {
    let mut report = ModelReport::default();
    ctl.progress("regions", 0.0);
    let t0 = Instant::now();
    let mut maps = build_snow_maps(mesh, p.resolution, ctl)?;
    report.timings.push(("regions", ms(t0)));

    ctl.progress("probability", 0.1);
    let t0 = Instant::now();
    let dirs = snowfall_directions(p.directions, p.spread_deg, p.wind, p.seed);
    let weights = p
        .angle_weighting
        .then(|| angle_weights(&dirs, p.spread_deg, p.wind));
    snow_probability(
        mesh,
        &mut maps,
        &dirs,
        weights.as_deref(),
        Receiver::Base,
        ctl,
    )?;
    report.timings.push(("probability", ms(t0)));

    let t0 = Instant::now();
    let mut settler = Settler::new(&maps);
    settler.jacobi_iterations = MODEL_JACOBI_ITERATIONS;
    settler.sweep_relaxation = MODEL_SWEEP_RELAXATION;
    let mut router = Router::new(&maps);
    let mut deposit = Deposit::new(&maps);
    let steps = p.steps.max(1);
    let at = |n: usize| {
        p.snowfall
            .cumulative(p.duration_h * n as f64 / steps as f64)
    };
    // Each step's cumulative snowfall `after`, in units, as the deposit computes it.
    let cum: Vec<f64> = (1..=steps).map(|n| at(n) / SNOW_UNIT_M).collect();
    let mut fallen = 0u64;
    let mut lost = 0u64;
    for n in 1..=steps {
        ctl.progress("snowfall", 0.3 + 0.7 * (n - 1) as f32 / steps as f32);
        ctl.checkpoint()?;
        if p.reproject_every > 0 && n > 1 && (n - 1) % p.reproject_every == 0 {
            snow_probability(
                mesh,
                &mut maps,
                &dirs,
                weights.as_deref(),
                Receiver::SnowSurface,
                ctl,
            )?;
            deposit.invalidate();
            router.reschedule();
        }
        fallen += deposit.run(&mut maps, at(n - 1), at(n));
        // Erosion and routing (one pass, `super::route`), then the height-ordered sweeps from
        // the cells it could not settle, if any.
        let (t_drop, tol) = settler.drops(&maps, p.repose_angle_deg);
        let routed = router.route(&mut maps, t_drop, tol, &Clock { cum: &cum, step: n });
        lost += routed.lost_units;
        report.routing_over_budget_steps += usize::from(routed.over_budget);
        let (iterations, converged) = if routed.unsettled.is_empty() {
            (1, true)
        } else if p.max_stabilize_iterations <= 1 {
            (1, false)
        } else {
            let rep = settler.stabilize_from(
                &mut maps,
                p.repose_angle_deg,
                &routed.unsettled,
                p.max_stabilize_iterations - 1,
                ctl,
            )?;
            lost += rep.lost_units;
            // The sweep moved snow anywhere from its seeds: the next seed search tests every
            // cell (logging the sweep's moves cost more than that on the bunny).
            router.reschedule();
            (1 + rep.iterations, rep.converged)
        };
        report.stabilize_iterations += iterations;
        report.step_iterations.push(iterations as u32);
        if !converged {
            report.unconverged_steps += 1;
        }
        on_frame(&maps, n);
    }
    report.residual_tan = repose_residual(&maps, p.repose_angle_deg);
    report.timings.push(("snowfall", ms(t0)));
    ctl.progress("snowfall", 1.0);

    let v = maps.unit_volume_m3();
    let resting_units: Vec<u64> = maps.layers.iter().map(|l| l.total_units()).collect();
    report.balance = MassBalance {
        fallen_units: fallen,
        lost_units: lost,
        resting_m3: resting_units.iter().map(|&u| u as f64 * v).collect(),
        resting_units,
        fallen_m3: fallen as f64 * v,
        lost_m3: lost as f64 * v,
    };
    Ok((maps, report))
}

fn ms(t0: Instant) -> f64 {
    t0.elapsed().as_secs_f64() * 1e3
}
