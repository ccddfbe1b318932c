//! Snow movement after landing (journal §2.4, Fig. 6 and 12; workshop §2.1(3); SPEC §2 steps 4–5):
//! stabilization by the angle of repose, and falling.
//!
//! **Stabilization** (§2.4.1). A cell compares its snow surface (base + snow) with the surfaces its
//! 4 neighbours link to ([`Layer::links`], see [`super::region`]). With `T = cell · tan(repose)`,
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
//! **Edges.** A [`LINK_LOST`] neighbour acts as a bare surface at the cell's own base that never
//! fills: snow deeper than `T` spills over the edge of the scene and is reported as lost.
//! [`LINK_WALL`] neighbours take nothing.
//!
//! **Scheme: Jacobi, in integers.** Each iteration first computes every cell's outflows from the
//! current state into a separate buffer (four `u32` per cell), then applies them: each cell
//! subtracts its own outflows and gathers its neighbours' in a fixed order. Snow amounts are
//! integers ([`super::maps::SNOW_UNIT_M`]), so mass is conserved exactly and the result does not
//! depend on the number of threads (rayon over rows). Only *active* 32 × 32 tiles are processed: a
//! tile is active when a cell in it or in a neighbouring tile changed in the previous iteration,
//! so a pile settling in one corner costs nothing elsewhere. Convergence = an iteration that moves
//! nothing. Rejected: Gauss–Seidel sweeps (order- and so thread-dependent), red–black ordering
//! (the cross-layer links connect cells of the same colour), `f32` amounts (mass drifts).
//!
//! Cost per iteration: ~2 passes over the active tiles × layers, a few ns per cell. Allocates the
//! outflow buffers once per [`Settler`].

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
/// Tile side (cells) of the active-set bookkeeping.
const TILE: usize = 32;

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
    nx: usize,
    nz: usize,
    out: Vec<Vec<[u32; 4]>>,
    tx: usize,
    tz: usize,
    /// Tiles to compute outflows in.
    active: Vec<bool>,
    /// Tiles to apply in (active dilated by one tile).
    apply: Vec<bool>,
    /// Per row, per tile column: changed in this iteration.
    row_changed: Vec<u8>,
    /// Per row: (moved, lost) units in this iteration's current layer.
    row_sums: Vec<(u64, u64)>,
}

impl Settler {
    /// A workspace for `maps` (allocates one outflow buffer per layer).
    pub fn new(maps: &SnowMaps) -> Self {
        let (nx, nz) = (maps.nx, maps.nz);
        let (tx, tz) = (nx.div_ceil(TILE), nz.div_ceil(TILE));
        Self {
            tolerance: SLOPE_TOLERANCE,
            relaxation: DEFAULT_RELAXATION,
            nx,
            nz,
            out: (0..maps.layers.len())
                .map(|_| vec![[0u32; 4]; nx * nz])
                .collect(),
            tx,
            tz,
            active: vec![true; tx * tz],
            apply: vec![true; tx * tz],
            row_changed: vec![0; nz * tx],
            row_sums: vec![(0, 0); nz],
        }
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
        assert!(maps.nx == self.nx && maps.nz == self.nz && maps.layers.len() == self.out.len());
        let t_drop = maps.cell * repose_deg.clamp(0.0, 89.9).to_radians().tan();
        let tol = self.tolerance * maps.cell;
        let mut rep = SettleReport::default();
        self.active.iter_mut().for_each(|a| *a = true);
        for o in &mut self.out {
            o.iter_mut().for_each(|v| *v = [0; 4]);
        }
        while rep.iterations < max_iterations {
            ctl.checkpoint()?;
            rep.iterations += 1;
            let (moved, lost) = self.iterate(maps, t_drop, tol, self.relaxation);
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

    /// One Jacobi iteration; returns (moved, lost) units.
    #[allow(clippy::needless_range_loop)] // `i` addresses several grids and the tile spans
    fn iterate(&mut self, maps: &mut SnowMaps, t_drop: f32, tol: f32, omega: f32) -> (u64, u64) {
        let (nx, nz, tx, tz) = (self.nx, self.nz, self.tx, self.tz);
        // Apply set = active dilated by one tile.
        for tj in 0..tz {
            for ti in 0..tx {
                let mut any = false;
                for (dj, di) in [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)] {
                    let (a, b) = (tj as isize + dj, ti as isize + di);
                    if a >= 0 && b >= 0 && (a as usize) < tz && (b as usize) < tx {
                        any |= self.active[a as usize * tx + b as usize];
                    }
                }
                self.apply[tj * tx + ti] = any;
            }
        }

        // 1. Outflows of every layer from the current state.
        let (mut moved, mut lost) = (0u64, 0u64);
        let maps_ref: &SnowMaps = maps;
        let active = &self.active;
        for (k, out) in self.out.iter_mut().enumerate() {
            // Rayon over bands of TILE rows; bands without an active tile are skipped.
            out.par_chunks_mut(nx * TILE)
                .zip(self.row_sums.par_chunks_mut(TILE))
                .enumerate()
                .for_each(|(tj, (out_rows, sums_rows))| {
                    sums_rows.iter_mut().for_each(|v| *v = (0, 0));
                    if !active[tj * tx..(tj + 1) * tx].iter().any(|&a| a) {
                        return;
                    }
                    for (r, (out_row, sums)) in out_rows.chunks_mut(nx).zip(sums_rows).enumerate() {
                        let j = tj * TILE + r;
                        for ti in 0..tx {
                            if !active[tj * tx + ti] {
                                continue;
                            }
                            let i1 = ((ti + 1) * TILE).min(nx);
                            for i in ti * TILE..i1 {
                                let (o, l) = outflow(maps_ref, k, i, j, t_drop, tol, omega);
                                out_row[i] = o;
                                let s: u64 = o.iter().map(|&v| u64::from(v)).sum();
                                sums.0 += s;
                                sums.1 += l;
                            }
                        }
                    }
                });
            for &(m, l) in &self.row_sums {
                moved += m;
                lost += l;
            }
        }
        if moved == 0 {
            return (0, 0);
        }

        // 2. Apply: every cell loses its outflows and gathers its neighbours'.
        let n_layers = maps.layers.len();
        let out = &self.out;
        let apply = &self.apply;
        self.row_changed.iter_mut().for_each(|v| *v = 0);
        for k in 0..n_layers {
            // Links of all layers are read; split the borrow: take this layer's snow out.
            let mut snow = std::mem::take(&mut maps.layers[k].snow);
            let maps_ref: &SnowMaps = maps;
            snow.par_chunks_mut(nx * TILE)
                .zip(self.row_changed.par_chunks_mut(tx * TILE))
                .enumerate()
                .for_each(|(tj, (rows, changed_rows))| {
                    if !apply[tj * tx..(tj + 1) * tx].iter().any(|&a| a) {
                        return;
                    }
                    for (r, (row, changed)) in rows
                        .chunks_mut(nx)
                        .zip(changed_rows.chunks_mut(tx))
                        .enumerate()
                    {
                        let j = tj * TILE + r;
                        for ti in 0..tx {
                            if !apply[tj * tx + ti] {
                                continue;
                            }
                            let i1 = ((ti + 1) * TILE).min(nx);
                            for i in ti * TILE..i1 {
                                let c = j * nx + i;
                                let o = out[k][c];
                                let gone = o[0] + o[1] + o[2] + o[3];
                                let mut got = 0u32;
                                for d in 0..4 {
                                    let Some(c2) = maps_ref.neighbour(i, j, d) else {
                                        continue;
                                    };
                                    let back = opposite(d);
                                    for (k2, l2) in maps_ref.layers.iter().enumerate() {
                                        let v = out[k2][c2][back];
                                        if v != 0 && usize::from(l2.links[c2][back]) == k {
                                            got += v;
                                        }
                                    }
                                }
                                if got != gone {
                                    row[i] = row[i] - gone + got;
                                    changed[ti] = 1;
                                }
                            }
                        }
                    }
                });
            maps.layers[k].snow = snow;
        }
        let _ = nz;

        // 3. Next active set: tiles with a change, dilated by one tile.
        for tj in 0..tz {
            for ti in 0..tx {
                let r0 = tj * TILE;
                let r1 = (r0 + TILE).min(nz);
                let ch = (r0..r1).any(|j| self.row_changed[j * tx + ti] != 0);
                self.apply[tj * tx + ti] = ch; // reuse as scratch
            }
        }
        for tj in 0..tz {
            for ti in 0..tx {
                let mut any = false;
                for (dj, di) in [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)] {
                    let (a, b) = (tj as isize + dj, ti as isize + di);
                    if a >= 0 && b >= 0 && (a as usize) < tz && (b as usize) < tx {
                        any |= self.apply[a as usize * tx + b as usize];
                    }
                }
                // A tile leaving the active set keeps zero outflows (it computed none, or its
                // cells changed and it stays active): zero them to be safe when it was active.
                if !any && self.active[tj * tx + ti] {
                    let r0 = tj * TILE;
                    let r1 = (r0 + TILE).min(nz);
                    let i1 = ((ti + 1) * TILE).min(nx);
                    for o in self.out.iter_mut() {
                        for j in r0..r1 {
                            o[j * nx + ti * TILE..j * nx + i1]
                                .iter_mut()
                                .for_each(|v| *v = [0; 4]);
                        }
                    }
                }
                self.active[tj * tx + ti] = any;
            }
        }
        (moved, lost)
    }
}

/// Outflows of cell (i, j) of layer k toward its 4 neighbours, and how much of it is lost.
#[inline]
fn outflow(
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
    let mut e = [0f32; 4];
    let mut n = 0u32;
    let mut sum = 0f32;
    for d in 0..4 {
        let drop = match links[d] {
            LINK_WALL => continue,
            LINK_LOST => s as f32 * unit,
            k2 => {
                let (di, dj) = NEIGHBOURS[d];
                let c2 = (j as isize + dj) as usize * nx + (i as isize + di) as usize;
                let l2 = &maps.layers[usize::from(k2)];
                (b - l2.base[c2]) + (i64::from(s) - i64::from(l2.snow[c2])) as f32 * unit
            }
        };
        let ex = drop - t_drop;
        if ex > tol {
            e[d] = ex;
            n += 1;
            sum += ex;
        }
    }
    if n == 0 {
        return ([0; 4], 0);
    }
    let share = omega * sum / (n * (n + 1)) as f32;
    let mut o = [0u32; 4];
    let mut total = 0u64;
    for d in 0..4 {
        if e[d] > 0.0 {
            // At least one unit, so a drop past the tolerance always moves something.
            let a = (share.min(0.5 * omega * e[d]) / unit).max(1.0);
            let a = if a >= u32::MAX as f32 {
                u32::MAX
            } else {
                a as u32
            };
            o[d] = a;
            total += u64::from(a);
        }
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
