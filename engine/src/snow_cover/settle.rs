//! Snow movement after landing (journal §2.4, Fig. 6 and 12; workshop §2.1(3); SPEC §2 steps 4–5):
//! stabilization by the angle of repose, and falling.
//!
//! **Stabilization** (§2.4.1). A cell compares its snow surface (base + snow) with the surfaces its
//! 4 neighbours link to ([`MapLayer::links`], see [`super::region`]). With `T = cell · tan(repose)`,
//! a neighbour is *lower* when the drop `d` toward it exceeds `T` by more than the tolerance
//! [`SLOPE_TOLERANCE`]` · cell`; its excess is `e = d − T`. No lower neighbour: nothing moves
//! (Fig. 6 (a)). Otherwise each of the n lower neighbours receives the same share `ē / (n + 1)`
//! (ē = mean excess; Fig. 6 (b)–(e): "split evenly") times an over-relaxation ω
//! ([`DEFAULT_RELAXATION`] = 1, plain levelling; up to 1.9 converges faster but leaves ripples), except that no neighbour receives more than
//! `ω · e / 2` (with ω = 1: what would level that pair); with one neighbour this moves exactly `e / 2`, which
//! brings the pair to the repose angle, and n equal neighbours of an isolated peak are brought to
//! it exactly too (ω > 1 overshoots). A cell never gives more snow than it has (shares are scaled down, in integer
//! arithmetic). After convergence every slope from a cell *that still has snow* to a linked
//! neighbour is at most `tan(repose) + SLOPE_TOLERANCE` (plus one snow unit per cell); slopes of the
//! bare base itself are not limited (a steep roof keeps no snow).
//!
//! **Falling** (§2.4.2). A link that leads to a layer far below (the floor beside a table top) is
//! handled by the same rule: the drop is large, so the cell gives all its snow there, as much as
//! the repose of its other neighbours allows: snow moved off a snow-possible region drops onto the
//! highest lower region at that spot and keeps stabilizing there (Fig. 7: snow under a table
//! arrives by falling off its edge and spreading from the pile below).
//!
//! **Ceiling** (our addition: the paper's groups never overlap). A cell holds at most
//! [`MapLayer::capacity`](super::maps::MapLayer::capacity) units, the snow that fits under the geometry
//! above it (the floor under a table). A neighbour already full to its ceiling takes nothing (a wall
//! for now); shares are capped at the room a neighbour has left; the drop is measured from the snow
//! *surface*, clipped at the ceiling; and snow above a cell's ceiling (none arises from accumulation
//! or movement, but a caller may set it) is split over the neighbours with room, like snow on a wall:
//! it moves on. In a Jacobi iteration several cells may fill one neighbour at once; the serial scatter
//! gives it what fits, in its fixed order, and the rest stays with the giver.
//!
//! **Edges.** A [`LINK_LOST`] neighbour acts as a bare surface at the cell's own base that never
//! fills: snow deeper than `T` spills over the edge of the scene and is reported as lost.
//! [`LINK_WALL`] neighbours take nothing.
//!
//! **Scheme: Jacobi, in integers.** Each iteration first computes every cell's outflows from the
//! current state into a separate buffer (four `u32` per cell and layer; rayon over bands of rows),
//! then applies them by a serial scatter over the cells that have an outflow: the cell loses its
//! outflows, its linked neighbours gain them. Snow amounts are integers
//! ([`super::maps::SNOW_UNIT_M`]) and integer additions commute, so mass is conserved exactly and
//! the result does not depend on the number of threads. Only *active* 16 × 16 tiles are computed: a
//! tile is active when a cell in it or in a neighbouring tile changed in the previous iteration,
//! so a pile settling in one corner costs nothing elsewhere; within them only *dirty* cells (the
//! cell or one of its 4 neighbours changed since its outflow was last found zero) are recomputed.
//! Convergence = an iteration that moves nothing.
//!
//! **Then Gauss–Seidel sweeps in height order, event-driven.** After [`DEFAULT_JACOBI_ITERATIONS`]
//! Jacobi iterations in one call (a small settlement, such as one animation step's, is over long
//! before), the iterations become serial sweeps over a **max-heap keyed by the snow surface**:
//! the dirty cells holding snow go in, the highest comes out, its outflows (the same rule, from
//! the current state) are applied at once, and every cell whose outflow that may have created
//! goes back in: the receivers, the giver (if it still has snow) and the cells whose links lead
//! into the giver (their drop toward it grew; a drop toward a receiver only shrank). So when the
//! heap is empty nothing can move: one sweep settles the step and the next (over the cells it
//! touched) confirms it; a default run takes 2 Jacobi iterations + 2 sweeps per step on every
//! mesh measured (BENCHMARKS.md, "Snow cover, convergence on curved meshes").
//! Since session 15 the model's time loop settles each step with the erosion and routing of
//! `route.rs` first and calls these sweeps only from the cells that leaves unsettled. Termination: a move
//! takes snow from a higher surface to a lower one and less than the drop, so Σ mass × height
//! falls by at least one unit × `T` per move. The sweeps are serial and so thread-count
//! independent (the order is a total order: surface, then cell and layer index).
//!
//! Why: the row-order sweeps used first needed a sweep per cell of every slope that ran against
//! their order (issue 18: 48 of 48 steps capped); sorting the cells that held snow at the start
//! of a sweep fixed roofs and tables but not curved meshes: snow moved onto a *bare* cell waited
//! for the next sweep, so snow spilling down a bare flank steeper than the repose angle (the
//! teapot's body) advanced one cell per sweep, 25 of 48 steps stopped at the 200-sweep cap with a
//! residual of 7 tan units; re-queuing the receivers alone fixed the teapot, but the ant (steep,
//! narrow legs where a share-limited giver keeps an excess) still stopped on all 48 steps, until
//! the giver and the cells above it were re-queued too.
//!
//! **Convergence test and residual.** A step has converged when an iteration moves nothing: then no
//! drop from a cell with snow exceeds `T` by more than the tolerance ([`SLOPE_TOLERANCE`]), up to
//! the unit rounding. [`repose_residual`] measures that independently on any state (the steepest
//! excess slope from a cell with snow, tan units); `report.json` states the iterations of every
//! step, the steps that stopped at the cap, and the final residual.
//!
//! **Coarse-to-fine** ([`super::coarse`]): on maps at least [`COARSE_MIN_SIDE`] cells wide the
//! snow is first stabilized on a 2 × 2-block map (recursively), so the fine iterations only smooth
//! the block structure. Rejected: `f32` amounts (mass drifts); red–black ordering (no faster than
//! the sweeps).
//!
//! Cost per iteration: one pass over the active tiles × layers plus the scatter of the moving
//! cells, a few ns per cell. Allocates the outflow buffer once per [`Settler`].

use rayon::prelude::*;

use super::maps::{opposite, SnowMaps, LINK_LOST, LINK_WALL, NEIGHBOURS, SNOW_UNIT_M};
use crate::{Canceled, Control};

/// Slope tolerance (in tan units) of the stabilized state; drops below `T + SLOPE_TOLERANCE · cell`
/// do not move snow.
pub const SLOPE_TOLERANCE: f32 = 0.01;
/// Default over-relaxation of the moved share: 1, the paper's levelling. 1.5 halves the iterations
/// a pile needs (measured: 472 → 228 on a 1 m pile at 256²) and keeps the repose and mass
/// properties, but leaves ripples (a cone's profile is no longer monotone), so it is opt-in.
pub const DEFAULT_RELAXATION: f32 = 1.0;
/// A map is stabilized coarse-to-fine when its shorter side has at least this many cells (the
/// coarser levels then go on down to 64–127 cells). Smaller maps converge quickly on their own, and in an
/// animation (small increments per step) the coarse pass costs more than it saves (measured on the
/// 200² animation benchmark: 27 instead of 32 steps/s).
pub const COARSE_MIN_SIDE: usize = 256;

/// The coarse level of a [`Settler`]: the restricted maps, their own settler, and the coarse snow
/// before stabilization (per layer).
#[derive(Debug, Clone)]
///
/// Defined here, beside the [`Settler`] that holds it; its methods (restriction, the coarse
/// solve, prolongation) are in [`super::coarse`], which builds on this file and not the other way.
pub(super) struct Coarse {
    pub(super) maps: SnowMaps,
    pub(super) settler: Settler,
    pub(super) before: Vec<Vec<u32>>,
}

/// Default over-relaxation of the height-ordered sweeps of a [`Settler`]: 1, the paper's levelling
/// (the model's time loop uses [`MODEL_SWEEP_RELAXATION`]).
pub const DEFAULT_SWEEP_RELAXATION: f32 = 1.0;
/// Over-relaxation of the height-ordered sweeps in the model's time loop
/// ([`super::snowfall::simulate`]): 2, a cell gives its whole excess `e = d − T` toward a single
/// lower neighbour instead of half of it, when every excess of the cell is at most `T` (then the
/// giver ends at most `T` below any receiver, so no slope turns around and snow never moves
/// back: measured on the teapot, unconditional ω = 2 ping-ponged on steep piles and 22 of 48
/// steps hit the cap); larger excesses are levelled with ω = 1. In height order that drains a slope in one sweep: with
/// ω = 1 a uniform deposit on a ramp W cells long at the repose angle needs O(W²) sweeps to run
/// off (each pair levelled halfway), with ω = 2 one. Where the receiver keeps the snow (the toe of
/// a pile) the pair ends flatter than the repose angle, never steeper (measured on the real meshes
/// of BENCHMARKS.md: 2.4× fewer sweeps, the same residual).
pub const MODEL_SWEEP_RELAXATION: f32 = 2.0;
/// Jacobi iterations per step in the model's time loop: 2 (the height-ordered sweeps do the rest;
/// measured: 1.5–1.9× fewer iterations in all than with [`DEFAULT_JACOBI_ITERATIONS`]).
pub const MODEL_JACOBI_ITERATIONS: usize = 2;
/// Default number of order-free Jacobi iterations before [`Settler::stabilize`] switches to
/// Gauss–Seidel sweeps (module doc, "Scheme").
pub const DEFAULT_JACOBI_ITERATIONS: usize = 16;
/// Active cells × layers below which a Jacobi iteration computes its outflows on one thread
/// (measured on the 200² animation benchmark under load: 60 steps/s on 2 threads, 90 on 1).
const SERIAL_CELLS: usize = 1 << 15;
/// Tile side (cells) of the active-set bookkeeping.
const TILE: usize = 16;

/// What one [`Settler::stabilize`] did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SettleReport {
    /// Iterations run.
    pub iterations: usize,
    /// True when the last iteration moved nothing (false: stopped at `max_iterations`).
    pub converged: bool,
    /// Snow moved between cells (including off the edge), in snow units.
    pub moved_units: u64,
    /// Snow lost over the scene's edge, in snow units.
    pub lost_units: u64,
    /// Iterations run on the coarse levels (all of them; see [`super::coarse`]).
    pub coarse_iterations: usize,
    /// The same two in m³.
    pub moved_m3: f64,
    pub lost_m3: f64,
}

/// Stabilization workspace for maps of one shape (buffers reused across calls).
#[derive(Debug, Clone)]
pub struct Settler {
    /// Slope tolerance (tan units) of this workspace; [`SLOPE_TOLERANCE`] unless changed.
    pub tolerance: f32,
    /// Over-relaxation of the moved share (1 = the paper's levelling); in [0.5, 1.9].
    pub relaxation: f32,
    /// Over-relaxation of the height-ordered sweeps ([`DEFAULT_SWEEP_RELAXATION`]); in [0.5, 2].
    pub sweep_relaxation: f32,
    /// Jacobi iterations per [`Settler::stabilize`] call before the Gauss–Seidel sweeps;
    /// [`DEFAULT_JACOBI_ITERATIONS`] unless changed (`usize::MAX`: Jacobi only).
    pub jacobi_iterations: usize,
    /// Maps whose shorter side has at least this many cells are stabilized coarse-to-fine
    /// ([`super::coarse`]); [`COARSE_MIN_SIDE`] unless changed (`usize::MAX`: never).
    pub coarse_min_side: usize,
    coarse: Option<Box<Coarse>>,
    nx: usize,
    nz: usize,
    n_layers: usize,
    /// Outflows, `[c · layers + k]`.
    out: Vec<[u32; 4]>,
    tx: usize,
    tz: usize,
    /// Tiles to compute outflows in.
    active: Vec<bool>,
    /// Tiles changed in this iteration.
    changed: Vec<bool>,
    /// Per cell: its outflow may have changed since it was last computed (the cell or one of its
    /// 4 neighbours changed); the next iteration's set is built in `dirty_next`.
    dirty: Vec<bool>,
    dirty_next: Vec<bool>,
    /// Per band of TILE rows: the `c · layers + k` with an outflow, and (moved, lost) units.
    bands: Vec<(Vec<u32>, u64, u64)>,
    /// The height-ordered sweep's queue ([`heap_key`]s), kept for its allocation.
    order: Vec<u64>,
    /// The sweep's cells re-queued while it runs (a max-heap; kept for its allocation).
    requeued: std::collections::BinaryHeap<u64>,
    /// Per cell and layer: in the sweep's queue.
    queued: Vec<bool>,
}

impl Settler {
    /// A workspace for `maps` (allocates the outflow buffer, 16 bytes per cell and layer).
    pub fn new(maps: &SnowMaps) -> Self {
        let (nx, nz) = (maps.nx, maps.nz);
        let (tx, tz) = (nx.div_ceil(TILE), nz.div_ceil(TILE));
        Self {
            tolerance: SLOPE_TOLERANCE,
            relaxation: DEFAULT_RELAXATION,
            sweep_relaxation: DEFAULT_SWEEP_RELAXATION,
            jacobi_iterations: DEFAULT_JACOBI_ITERATIONS,
            coarse_min_side: COARSE_MIN_SIDE,
            coarse: None,
            nx,
            nz,
            n_layers: maps.layers.len(),
            out: vec![[0u32; 4]; nx * nz * maps.layers.len()],
            tx,
            tz,
            active: vec![true; tx * tz],
            changed: vec![false; tx * tz],
            dirty: vec![true; nx * nz],
            dirty_next: vec![false; nx * nz],
            bands: vec![(Vec::new(), 0, 0); tz],
            order: Vec::new(),
            requeued: std::collections::BinaryHeap::new(),
            queued: vec![false; nx * nz * maps.layers.len()],
        }
    }

    /// The repose drop `T` and the tolerance (metres) on `maps` for `repose_deg`.
    ///
    /// # Panics
    /// If `maps` does not have the shape this workspace was made for.
    pub(super) fn drops(&self, maps: &SnowMaps, repose_deg: f32) -> (f32, f32) {
        assert!(maps.nx == self.nx && maps.nz == self.nz && maps.layers.len() == self.n_layers);
        (
            repose_drop(maps.cell, repose_deg),
            self.tolerance * maps.cell,
        )
    }

    /// Stabilize `maps` (module doc) with repose angle `repose_deg` (degrees, in (0, 90)) for at
    /// most `max_iterations` iterations, starting with every tile active. Checks for cancellation
    /// once per iteration.
    ///
    /// # Panics
    /// If `maps` does not have the shape this workspace was made for.
    pub fn stabilize(
        &mut self,
        maps: &mut SnowMaps,
        repose_deg: f32,
        max_iterations: usize,
        ctl: &dyn Control,
    ) -> Result<SettleReport, Canceled> {
        let (t_drop, tol) = self.drops(maps, repose_deg);
        let mut rep = SettleReport::default();
        if self.nx.min(self.nz) >= self.coarse_min_side.max(2) {
            let mut coarse = self
                .coarse
                .take()
                .unwrap_or_else(|| Box::new(Coarse::new(maps)));
            let r = coarse.run(maps, self, repose_deg, t_drop, max_iterations, ctl);
            self.coarse = Some(coarse);
            let r = r?;
            rep.coarse_iterations = r.iterations + r.coarse_iterations;
            rep.moved_units += r.moved_units;
            rep.lost_units += r.lost_units;
        }
        self.active.iter_mut().for_each(|a| *a = true);
        self.dirty.iter_mut().for_each(|a| *a = true);
        self.dirty_next.iter_mut().for_each(|a| *a = false);
        self.iterate_until_settled(
            maps,
            (t_drop, tol),
            self.jacobi_iterations,
            max_iterations,
            rep,
            ctl,
        )
    }

    /// The iterations of [`Settler::stabilize`] and [`Settler::stabilize_from`] from the current
    /// active and dirty sets: `jacobi` Jacobi iterations, then a height-ordered sweep, then the
    /// confirming check (a sweep again only where it finds an outflow), until an iteration moves
    /// nothing or `rep.iterations` reaches `max_iterations`. Adds to `rep` and fills its m³.
    fn iterate_until_settled(
        &mut self,
        maps: &mut SnowMaps,
        (t_drop, tol): (f32, f32),
        jacobi: usize,
        max_iterations: usize,
        mut rep: SettleReport,
        ctl: &dyn Control,
    ) -> Result<SettleReport, Canceled> {
        while rep.iterations < max_iterations {
            ctl.checkpoint()?;
            rep.iterations += 1;
            let (moved, lost) = if rep.iterations <= jacobi {
                self.iterate(maps, t_drop, tol, self.relaxation)
            } else if rep.iterations > jacobi + 1
                && !self.any_outflow(maps, t_drop, tol, self.sweep_relaxation)
            {
                // After a sweep the state is settled (see `sweep`): the confirming pass is this
                // read-only check on both cores; a sweep runs only where it finds an outflow.
                (0, 0)
            } else {
                self.sweep(maps, t_drop, tol, self.sweep_relaxation, ctl)?
            };
            rep.moved_units += moved;
            rep.lost_units += lost;
            if moved == 0 {
                rep.converged = true;
                break;
            }
        }
        let v = maps.unit_volume_m3();
        rep.moved_m3 = rep.moved_units as f64 * v;
        rep.lost_m3 = rep.lost_units as f64 * v;
        Ok(rep)
    }

    /// Settle `maps` by the height-ordered sweeps alone (no coarse level, no Jacobi iterations),
    /// starting from the given cells (`j · nx + i`; the cells that may have an outflow: every
    /// other cell must have none), for at most `max_iterations` iterations (a sweep, then the
    /// confirming check). The fallback of the model's routing pass ([`super::route`]).
    pub(super) fn stabilize_from(
        &mut self,
        maps: &mut SnowMaps,
        repose_deg: f32,
        cells: &[u32],
        max_iterations: usize,
        ctl: &dyn Control,
    ) -> Result<SettleReport, Canceled> {
        let (t_drop, tol) = self.drops(maps, repose_deg);
        self.dirty.iter_mut().for_each(|a| *a = false);
        self.dirty_next.iter_mut().for_each(|a| *a = false);
        self.changed.iter_mut().for_each(|a| *a = false);
        for &c in cells {
            let c = c as usize;
            self.dirty[c] = true;
            self.changed[(c / self.nx / TILE) * self.tx + (c % self.nx) / TILE] = true;
        }
        // Active: the tiles holding a seed (the sweep reads dirty cells of active tiles only).
        self.active.copy_from_slice(&self.changed);
        self.iterate_until_settled(
            maps,
            (t_drop, tol),
            0,
            max_iterations,
            SettleReport::default(),
            ctl,
        )
    }

    /// One Jacobi iteration; returns (moved, lost) units. The outflows of every cell of the active
    /// tiles are computed from the current state (rayon over bands of rows), then applied by a
    /// serial scatter over the cells that have one: integer additions commute, so the result is
    /// the same in any order and for any thread count.
    fn iterate(&mut self, maps: &mut SnowMaps, t_drop: f32, tol: f32, omega: f32) -> (u64, u64) {
        let (nx, tx, nl) = (self.nx, self.tx, self.n_layers);
        let maps_ref: &SnowMaps = maps;
        let active = &self.active;
        let dirty = &self.dirty;
        // Small active sets run on this thread: a rayon dispatch costs more than it saves there.
        let cells = active.iter().filter(|&&a| a).count() * TILE * TILE * nl;
        let min_len = if cells < SERIAL_CELLS { self.tz } else { 1 };
        self.out
            .par_chunks_mut(nx * TILE * nl)
            .zip(self.bands.par_iter_mut())
            .enumerate()
            .with_min_len(min_len)
            .for_each(|(tj, (out, band))| {
                band.0.clear();
                band.1 = 0;
                band.2 = 0;
                if !active[tj * tx..(tj + 1) * tx].iter().any(|&a| a) {
                    return;
                }
                let rows = out.len() / (nx * nl);
                for r in 0..rows {
                    let j = tj * TILE + r;
                    for ti in 0..tx {
                        if !active[tj * tx + ti] {
                            continue;
                        }
                        for i in ti * TILE..((ti + 1) * TILE).min(nx) {
                            if !dirty[j * nx + i] {
                                continue;
                            }
                            for k in 0..nl {
                                let (o, l) = outflow(maps_ref, k, i, j, t_drop, tol, omega);
                                let s = o[0] + o[1] + o[2] + o[3];
                                if s != 0 {
                                    let idx = (r * nx + i) * nl + k;
                                    out[idx] = o;
                                    band.0.push(((j * nx + i) * nl + k) as u32);
                                    band.1 += u64::from(s);
                                    band.2 += l;
                                }
                            }
                        }
                    }
                }
            });
        let moved: u64 = self.bands.iter().map(|b| b.1).sum();
        let lost: u64 = self.bands.iter().map(|b| b.2).sum();
        if moved == 0 {
            return (0, 0);
        }

        // Scatter: every moving cell loses its outflows, its linked neighbours gain them.
        self.changed.iter_mut().for_each(|v| *v = false);
        let mut rejected = 0u64;
        for band in &self.bands {
            for &idx in &band.0 {
                let idx = idx as usize;
                let (c, k) = (idx / nl, idx % nl);
                let (i, j) = (c % nx, c / nx);
                let o = self.out[idx];
                let links = maps.layers[k].links[c];
                maps.layers[k].snow[c] -= o[0] + o[1] + o[2] + o[3];
                self.changed[(j / TILE) * tx + i / TILE] = true;
                mark(&mut self.dirty_next, nx, self.nz, i, j);
                for d in 0..4 {
                    if o[d] == 0 || links[d] == LINK_LOST {
                        continue;
                    }
                    let (di, dj) = NEIGHBOURS[d];
                    let (i2, j2) = ((i as isize + di) as usize, (j as isize + dj) as usize);
                    let l2 = &mut maps.layers[usize::from(links[d])];
                    let c2 = j2 * nx + i2;
                    // Several cells may fill the same neighbour in one Jacobi iteration: what no
                    // longer fits under its ceiling stays with the giver (fixed scatter order).
                    let take = o[d].min(l2.capacity(c2).saturating_sub(l2.snow[c2]));
                    l2.snow[c2] += take;
                    maps.layers[k].snow[c] += o[d] - take;
                    rejected += u64::from(o[d] - take);
                    self.changed[(j2 / TILE) * tx + i2 / TILE] = true;
                    mark(&mut self.dirty_next, nx, self.nz, i2, j2);
                }
            }
        }
        self.next_active();
        (moved - rejected, lost)
    }

    /// Whether any dirty cell of the active tiles has an outflow (read-only, rayon over bands
    /// of rows): the cells a [`Settler::sweep`] would visit, so "none" means that sweep would move
    /// nothing.
    fn any_outflow(&self, maps: &SnowMaps, t_drop: f32, tol: f32, omega: f32) -> bool {
        let (nx, nz, tx, nl) = (self.nx, self.nz, self.tx, self.n_layers);
        (0..self.tz).into_par_iter().any(|tj| {
            (0..tx).any(|ti| {
                self.active[tj * tx + ti]
                    && (tj * TILE..((tj + 1) * TILE).min(nz)).any(|j| {
                        (ti * TILE..((ti + 1) * TILE).min(nx)).any(|i| {
                            self.dirty[j * nx + i]
                                && (0..nl).any(|k| {
                                    maps.layers[k].snow[j * nx + i] != 0 && {
                                        let (o, _) = outflow(maps, k, i, j, t_drop, tol, omega);
                                        o[0] + o[1] + o[2] + o[3] != 0
                                    }
                                })
                        })
                    })
            })
        })
    }

    /// Next active set: the changed tiles dilated by one tile; the next dirty cells.
    fn next_active(&mut self) {
        std::mem::swap(&mut self.dirty, &mut self.dirty_next);
        self.dirty_next.iter_mut().for_each(|v| *v = false);
        let (tx, tz) = (self.tx, self.tz);
        for tj in 0..tz {
            for ti in 0..tx {
                let mut any = false;
                for (dj, di) in [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)] {
                    let (a, b) = (tj as isize + dj, ti as isize + di);
                    if a >= 0 && b >= 0 && (a as usize) < tz && (b as usize) < tx {
                        any |= self.changed[a as usize * tx + b as usize];
                    }
                }
                self.active[tj * tx + ti] = any;
            }
        }
    }
}

impl Settler {
    /// One Gauss–Seidel sweep **in height order** (serial), event-driven: the dirty cells of the
    /// active tiles that hold snow go into a max-heap keyed by their snow surface (ties: lower
    /// cell and layer index first); the highest is taken out, its outflows (computed as in
    /// [`Settler::iterate`] from the *current* state) are applied at once, and every cell whose
    /// outflow that may have created is queued in the same heap: the receivers (they hold more
    /// snow now, and snow that lands on a bare cell of a steep flank must run on down it), the
    /// giver itself (a share-limited giver may still have an excess) and the cells whose links
    /// lead into the giver (their drop toward it grew). A drop can only grow toward a giver, so
    /// when the heap is empty no cell has an outflow: one sweep settles the whole state, and the
    /// next one (over the cells it touched) confirms it. Snow only moves down, so a receiver is
    /// lower than its giver and comes later: snow runs down a whole slope, off a roof and down
    /// the pile below in one pass, whatever the slope's direction.
    ///
    /// Why the queue and not a sorted list of the cells that held snow when the sweep began (the
    /// scheme before): snow moved onto a *bare* cell waited for the next sweep, so snow spilling
    /// from a pile down a bare flank steeper than the repose angle (the teapot's body, the ant's
    /// legs and abdomen) advanced one cell per sweep, and a flank 200 cells long stopped every
    /// step at the 200-sweep cap (issue 18: teapot 25 of 48 steps, ant 48 of 48). Termination:
    /// every move takes snow from a higher surface to a lower one by less than the drop (the
    /// shares are at most the excess), so Σ mass × height falls by at least one unit × `T` per
    /// move and is bounded below. Checks `ctl` every [`CHECK_EVERY`] cells.
    ///
    /// Returns (moved, lost) units and updates the active set (tiles with a change, dilated by
    /// one tile).
    fn sweep(
        &mut self,
        maps: &mut SnowMaps,
        t_drop: f32,
        tol: f32,
        omega: f32,
        ctl: &dyn Control,
    ) -> Result<(u64, u64), Canceled> {
        let (nx, nz, tx) = (self.nx, self.nz, self.tx);
        let (mut moved, mut lost) = (0u64, 0u64);
        self.changed.iter_mut().for_each(|v| *v = false);
        let nl = maps.layers.len();
        self.order.clear();
        for tj in 0..self.tz {
            for ti in 0..tx {
                if !self.active[tj * tx + ti] {
                    continue;
                }
                for j in tj * TILE..((tj + 1) * TILE).min(nz) {
                    for i in ti * TILE..((ti + 1) * TILE).min(nx) {
                        let c = j * nx + i;
                        if !self.dirty[c] {
                            continue;
                        }
                        for (k, l) in maps.layers.iter().enumerate() {
                            if l.snow[c] == 0 {
                                continue;
                            }
                            let idx = c * nl + k;
                            self.queued[idx] = true;
                            self.order.push(heap_key(l.surface(c), idx));
                        }
                    }
                }
            }
        }
        // The cells queued at the start are sorted once (in parallel, highest key first); the
        // cells re-queued during the sweep go to a max-heap, and each visit takes the larger key
        // of the two. Keys are unique, so this is the same order as one heap holding all of them
        // (the same result to the unit), without a heap pop per cell.
        let mut order = std::mem::take(&mut self.order);
        order.par_sort_unstable_by(|a, b| b.cmp(a));
        let mut heap = std::mem::take(&mut self.requeued);
        heap.clear();
        let mut next = 0usize;
        let mut visits = 0usize;
        loop {
            let key = match (order.get(next), heap.peek()) {
                (Some(&a), Some(&b)) if a > b => {
                    next += 1;
                    a
                }
                (Some(&a), None) => {
                    next += 1;
                    a
                }
                (_, Some(_)) => heap.pop().unwrap_or_default(),
                (None, None) => break,
            };
            visits += 1;
            if visits % CHECK_EVERY == 0 {
                if let Err(e) = ctl.checkpoint() {
                    for k in heap.drain().chain(order[next..].iter().copied()) {
                        self.queued[key_index(k)] = false;
                    }
                    self.queued[key_index(key)] = false;
                    self.order = order;
                    self.requeued = heap;
                    return Err(e);
                }
            }
            let idx = key_index(key);
            self.queued[idx] = false;
            let (c, k) = (idx / nl, idx % nl);
            let (i, j) = (c % nx, c / nx);
            if maps.layers[k].snow[c] == 0 {
                continue;
            }
            let (o, l) = outflow(maps, k, i, j, t_drop, tol, omega);
            let gone = o[0] + o[1] + o[2] + o[3];
            if gone == 0 {
                continue;
            }
            moved += u64::from(gone);
            lost += l;
            maps.layers[k].snow[c] -= gone;
            self.changed[(j / TILE) * tx + i / TILE] = true;
            mark(&mut self.dirty_next, nx, nz, i, j);
            let links = maps.layers[k].links[c];
            for d in 0..4 {
                let (di, dj) = NEIGHBOURS[d];
                let (i2, j2) = (i as isize + di, j as isize + dj);
                if i2 < 0 || j2 < 0 || i2 as usize >= nx || j2 as usize >= nz {
                    continue;
                }
                let (i2, j2) = (i2 as usize, j2 as usize);
                let c2 = j2 * nx + i2;
                if o[d] != 0 && links[d] != LINK_LOST {
                    let k2 = usize::from(links[d]);
                    let l2 = &mut maps.layers[k2];
                    // The rounding remainder of a scaled-down outflow may not fit.
                    let take = o[d].min(l2.capacity(c2).saturating_sub(l2.snow[c2]));
                    l2.snow[c2] += take;
                    maps.layers[k].snow[c] += o[d] - take;
                    moved -= u64::from(o[d] - take);
                    self.changed[(j2 / TILE) * tx + i2 / TILE] = true;
                    mark(&mut self.dirty_next, nx, nz, i2, j2);
                    let idx2 = c2 * nl + k2;
                    if take > 0 && !self.queued[idx2] {
                        self.queued[idx2] = true;
                        heap.push(heap_key(maps.layers[k2].surface(c2), idx2));
                    }
                }
                // The cells of this neighbour whose link back leads into the giver: their drop
                // toward it grew.
                let back = opposite(d);
                for (k3, l3) in maps.layers.iter().enumerate() {
                    let idx3 = c2 * nl + k3;
                    if l3.snow[c2] != 0
                        && usize::from(l3.links[c2][back]) == k
                        && !self.queued[idx3]
                    {
                        self.queued[idx3] = true;
                        heap.push(heap_key(l3.surface(c2), idx3));
                    }
                }
            }
            if maps.layers[k].snow[c] != 0 && !self.queued[idx] {
                self.queued[idx] = true;
                heap.push(heap_key(maps.layers[k].surface(c), idx));
            }
        }
        self.order = order;
        self.requeued = heap;
        self.next_active();
        Ok((moved, lost))
    }
}

/// Cells a [`Settler`]'s sweep visits between cancellation checks.
const CHECK_EVERY: usize = 1 << 16;

/// The sweep's max-heap key of cell-and-layer `idx` with snow surface `surface`: highest surface
/// first, then the lower index.
#[inline]
pub(super) fn heap_key(surface: f32, idx: usize) -> u64 {
    (u64::from(ordered_bits(surface)) << 32) | u64::from(u32::MAX - idx as u32)
}

/// The cell-and-layer index of a [`heap_key`].
#[inline]
pub(super) fn key_index(key: u64) -> usize {
    (u32::MAX - (key & 0xFFFF_FFFF) as u32) as usize
}

/// The bits of `x` as a `u32` that sorts like `x` (NaN: as the largest).
#[inline]
fn ordered_bits(x: f32) -> u32 {
    let b = x.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// The **repose residual** of `maps`: the largest amount, in tan units (rise over run), by which
/// a slope from a cell that holds snow toward a linked neighbour that has room exceeds
/// `tan(repose_deg)`; 0 when no slope does. The drops are measured as [`Settler::stabilize`]
/// measures them (the snow surface clipped at the ceiling; over the scene's edge, the cell's
/// snow depth), so a converged stabilization leaves at most its tolerance plus one snow unit per
/// cell. Bare base slopes do not count (a steep roof keeps no snow). One pass over the cells
/// (rayon over rows; a max, so the same for any thread count).
pub fn repose_residual(maps: &SnowMaps, repose_deg: f32) -> f32 {
    let t_drop = repose_drop(maps.cell, repose_deg);
    let nx = maps.nx;
    let unit = SNOW_UNIT_M as f32;
    (0..maps.nz)
        .into_par_iter()
        .map(|j| {
            let mut worst = 0f32;
            for i in 0..nx {
                let c = j * nx + i;
                for layer in &maps.layers {
                    let s = layer.snow[c];
                    if s == 0 {
                        continue;
                    }
                    let kept = s.min(layer.capacity(c));
                    for (d, &(di, dj)) in NEIGHBOURS.iter().enumerate() {
                        let drop = match layer.links[c][d] {
                            LINK_WALL => continue,
                            LINK_LOST => kept as f32 * unit,
                            k2 => {
                                let c2 =
                                    (j as isize + dj) as usize * nx + (i as isize + di) as usize;
                                let l2 = &maps.layers[usize::from(k2)];
                                let (s2, cap2) = (l2.snow[c2], l2.capacity(c2));
                                if cap2 <= s2 {
                                    continue;
                                }
                                (layer.base[c] - l2.base[c2])
                                    + (i64::from(kept) - i64::from(s2)) as f32 * unit
                            }
                        };
                        worst = worst.max((drop - t_drop) / maps.cell);
                    }
                }
            }
            worst
        })
        .reduce(|| 0.0, f32::max)
}

/// The repose drop `T = cell · tan(repose)` (metres; the angle clamped to [0°, 89.9°]).
#[inline]
pub(super) fn repose_drop(cell: f32, repose_deg: f32) -> f32 {
    cell * repose_deg.clamp(0.0, 89.9).to_radians().tan()
}

/// Mark cell (i, j) and its 4 neighbours dirty.
#[inline]
fn mark(dirty: &mut [bool], nx: usize, nz: usize, i: usize, j: usize) {
    let c = j * nx + i;
    dirty[c] = true;
    if i > 0 {
        dirty[c - 1] = true;
    }
    if i + 1 < nx {
        dirty[c + 1] = true;
    }
    if j > 0 {
        dirty[c - nx] = true;
    }
    if j + 1 < nz {
        dirty[c + nx] = true;
    }
}

/// Outflows of cell (i, j) of layer k toward its 4 neighbours, and how much of it is lost.
#[inline]
pub(super) fn outflow(
    maps: &SnowMaps,
    k: usize,
    i: usize,
    j: usize,
    t_drop: f32,
    tol: f32,
    omega: f32,
) -> ([u32; 4], u64) {
    let nx = maps.nx;
    let c = j * nx + i;
    let layer = &maps.layers[k];
    let s = layer.snow[c];
    if s == 0 {
        return ([0; 4], 0);
    }
    let unit = SNOW_UNIT_M as f32;
    let b = layer.base[c];
    let links = layer.links[c];
    // Snow above the ceiling is not part of the surface; it must move on (module doc, "Ceiling").
    let cap = layer.capacity(c);
    let kept = s.min(cap);
    let excess = s - kept;
    let mut e = [0f32; 4];
    // Room left in the neighbour each way (`u32::MAX`: over the scene's edge).
    let mut room = [0u32; 4];
    let mut n = 0u32;
    let mut sum = 0f32;
    for d in 0..4 {
        let drop = match links[d] {
            LINK_WALL => continue,
            LINK_LOST => {
                room[d] = u32::MAX;
                kept as f32 * unit
            }
            k2 => {
                let (di, dj) = NEIGHBOURS[d];
                let c2 = (j as isize + dj) as usize * nx + (i as isize + di) as usize;
                let l2 = &maps.layers[usize::from(k2)];
                let (s2, cap2) = (l2.snow[c2], l2.capacity(c2));
                room[d] = cap2.saturating_sub(s2);
                if room[d] == 0 {
                    // Full up to its ceiling: a wall for now.
                    continue;
                }
                (b - l2.base[c2]) + (i64::from(kept) - i64::from(s2.min(cap2))) as f32 * unit
            }
        };
        let ex = drop - t_drop;
        if ex > tol {
            e[d] = ex;
            n += 1;
            sum += ex;
        }
    }
    let mut o = [0u32; 4];
    let mut total = 0u64;
    if n > 0 {
        // Over-relaxation only where it cannot turn a slope around: with every excess at most T
        // the giver never ends more than T below a receiver (module doc, "Then Gauss–Seidel
        // sweeps"); a larger excess (a steep pile) is levelled plainly.
        let omega = if omega > 1.0 && e.iter().any(|&x| x > t_drop) {
            1.0
        } else {
            omega
        };
        let share = omega * sum / (n * (n + 1)) as f32;
        for d in 0..4 {
            if e[d] > 0.0 {
                // At least one unit, so a drop past the tolerance always moves something.
                let a = (share.min(0.5 * omega * e[d]) / unit).max(1.0);
                let a = if a >= u32::MAX as f32 {
                    u32::MAX
                } else {
                    a as u32
                };
                o[d] = a.min(room[d]);
                total += u64::from(o[d]);
            }
        }
    }
    if excess > 0 {
        // Split what does not fit evenly over the neighbours with room (first ones get the
        // remainder), each up to its room.
        let open = (0..4).filter(|&d| room[d] > o[d]).count() as u64;
        if let (Some(each), Some(mut extra)) = (
            u64::from(excess).checked_div(open),
            u64::from(excess).checked_rem(open),
        ) {
            for d in 0..4 {
                if room[d] > o[d] {
                    let want = each + u64::from(extra > 0);
                    extra = extra.saturating_sub(1);
                    let add = want.min(u64::from(room[d] - o[d]));
                    o[d] += add as u32;
                    total += add;
                }
            }
        }
    }
    if total == 0 {
        return ([0; 4], 0);
    }
    if total > u64::from(s) {
        // Scale down to what the cell has, in integers; the remainder of the rounding goes to the
        // largest share (first in direction order), so the cell gives exactly all it has.
        let mut given = 0u64;
        let mut largest = 0;
        for d in 0..4 {
            if o[d] > o[largest] {
                largest = d;
            }
        }
        for v in &mut o {
            *v = (u64::from(*v) * u64::from(s) / total) as u32;
            given += u64::from(*v);
        }
        o[largest] += (u64::from(s) - given) as u32;
    }
    let lost: u64 = (0..4)
        .filter(|&d| links[d] == LINK_LOST)
        .map(|d| u64::from(o[d]))
        .sum();
    (o, lost)
}
