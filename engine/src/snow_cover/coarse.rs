//! Coarse-to-fine stabilization: the speed-up of [`super::settle`] for large maps (our addition;
//! the paper's maps are 100–200 cells wide and it settles once per frame, journal §2.4.1).
//!
//! Levelling by the angle of repose behaves like diffusion: a pile R cells wide needs ~R²
//! iterations to spread (7,602 Jacobi iterations for a 1 m pile on a 1024² map). So before
//! iterating on the fine map, [`Settler::stabilize`](super::settle::Settler::stabilize) restricts
//! it to a map of 2 × 2 blocks, stabilizes that (recursively, down to [`COARSE_MIN_SIDE`](super::settle::COARSE_MIN_SIDE)), and
//! prolongs the result back; the fine iterations then only smooth the block structure.
//!
//! **Restriction.** A block carries layer k when its four cells all have layer k, the links
//! inside the block join layer k to layer k, and no base step inside the block exceeds
//! `cell · tan(repose)` (a *gentle* patch: a table's edge or a steep roof stays fine-only). Its base
//! is the mean of the four, its snow `⌊S / 4⌋` units of the coarse cell (S = the four cells' sum;
//! the remainder stays on the fine cells). A coarse link joins two blocks when both fine links
//! across that block side lead to the same layer and the neighbouring block carries it; both
//! fine links lost (the scene's edge) makes it lost; anything else is a wall, so snow never
//! crosses, at the coarse level, a place the fine map treats differently. A block under a ceiling
//! gets a ceiling that lets it gain no more than the fullest of its cells can take (less
//! [`CEILING_MARGIN_UNITS`]); a block with less room than that stays fine-only.
//!
//! **Prolongation.** A block whose coarse snow went from D to D' adds `D' − D` units to each of its
//! four cells (keeping the fine relief inside the block); a cell that would go negative gives what
//! it has and the rest is taken from its block mates (fixed order). Snow is integer throughout:
//! the four cells change by exactly `4 (D' − D)`, and a coarse unit lost over the edge is 4 fine
//! units, so the mass balance stays exact. Everything is per block, so the result does not depend
//! on the thread count.
//!
//! The fine iterations that follow restore the fine repose bound everywhere (the coarse pass only
//! moves snow sooner; it never decides the final slopes). Rejected: Gauss–Seidel sweeps alone
//! (halve the iterations, still ~R²), over-relaxation (ripples).
//!
//! Cost: two passes over the fine cells and the coarse map's own stabilization. Allocates the
//! coarse maps and their [`Settler`] once per fine [`Settler`].

use super::maps::{MapLayer, SnowMaps, LINK_LOST, LINK_WALL, SNOW_UNIT_M};
use super::settle::{Coarse, SettleReport, Settler, COARSE_MIN_SIDE};
use crate::{Canceled, Control};

/// Safety margin (snow units, 0.1 mm) between a coarse block's ceiling and the least room any of
/// its cells has: covers the `f32` rounding of the coarse base, so a prolonged change never lifts
/// a fine cell past its own ceiling. Blocks with less room stay fine-only.
const CEILING_MARGIN_UNITS: u32 = 100;

/// The four cells of block (bi, bj): (2bi, 2bj), (2bi+1, 2bj), (2bi, 2bj+1), (2bi+1, 2bj+1).
#[inline]
fn block_cells(nx: usize, bi: usize, bj: usize) -> [usize; 4] {
    let c = 2 * bj * nx + 2 * bi;
    [c, c + 1, c + nx, c + nx + 1]
}

impl Coarse {
    /// The coarse level for `fine` (allocates).
    pub(super) fn new(fine: &SnowMaps) -> Self {
        let (nx, nz) = (fine.nx / 2, fine.nz / 2);
        let n = nx * nz;
        let maps = SnowMaps {
            nx,
            nz,
            cell: fine.cell * 2.0,
            origin: fine.origin,
            layers: (0..fine.layers.len()).map(|_| MapLayer::empty(n)).collect(),
            extent: fine.extent,
        };
        let settler = Settler::new(&maps);
        Self {
            before: vec![vec![0; n]; fine.layers.len()],
            maps,
            settler,
        }
    }

    /// Restrict `fine` (geometry for this repose drop `t_drop`, and snow), stabilize the coarse
    /// maps, prolong the change back. Returns the coarse report in *fine* units.
    pub(super) fn run(
        &mut self,
        fine: &mut SnowMaps,
        fine_settler: &Settler,
        repose_deg: f32,
        t_drop: f32,
        max_iterations: usize,
        ctl: &dyn Control,
    ) -> Result<SettleReport, Canceled> {
        self.restrict(fine, t_drop);
        if self.maps.total_units() == 0 {
            return Ok(SettleReport::default());
        }
        self.settler.tolerance = fine_settler.tolerance;
        self.settler.relaxation = fine_settler.relaxation;
        self.settler.sweep_relaxation = fine_settler.sweep_relaxation;
        self.settler.jacobi_iterations = fine_settler.jacobi_iterations;
        // Deeper levels go on down to 64–127 cells: once a map is large enough to coarsen, the
        // coarser levels pay off (measured: 1 m pile at 1024², 140 instead of 198 iterations).
        self.settler.coarse_min_side = fine_settler.coarse_min_side.min(COARSE_MIN_SIDE / 2);
        let mut rep = self
            .settler
            .stabilize(&mut self.maps, repose_deg, max_iterations, ctl)?;
        self.prolong(fine);
        rep.moved_units *= 4;
        rep.lost_units *= 4;
        Ok(rep)
    }

    fn restrict(&mut self, fine: &SnowMaps, t_drop: f32) {
        let (cnx, cnz, fnx) = (self.maps.nx, self.maps.nz, fine.nx);
        let n_layers = fine.layers.len();
        // Pass 1: which blocks carry which layer; base and snow.
        for k in 0..n_layers {
            let fl = &fine.layers[k];
            let cl = &mut self.maps.layers[k];
            for bj in 0..cnz {
                for bi in 0..cnx {
                    let b = bj * cnx + bi;
                    let cells = block_cells(fnx, bi, bj);
                    let ku = k as u8;
                    let [a, r, u, ru] = cells;
                    // Internal links (+X of the left cells, −X of the right, +Z/−Z likewise).
                    let inside = [(a, 1, r), (r, 0, a), (u, 1, ru), (ru, 0, u)]
                        .into_iter()
                        .chain([(a, 3, u), (u, 2, a), (r, 3, ru), (ru, 2, r)])
                        .all(|(c, d, c2)| {
                            fl.links[c][d] == ku && (fl.base[c] - fl.base[c2]).abs() <= t_drop
                        });
                    let valid = inside && cells.iter().all(|&c| !fl.base[c].is_nan());
                    // Room under the ceiling: the least any of the four cells has left (units).
                    let room = cells
                        .iter()
                        .map(|&c| fl.capacity(c).saturating_sub(fl.snow[c]))
                        .min()
                        .unwrap_or(0);
                    let valid = valid && room > CEILING_MARGIN_UNITS;
                    if valid {
                        let base = cells.iter().map(|&c| fl.base[c]).sum::<f32>() * 0.25;
                        let s: u64 = cells.iter().map(|&c| u64::from(fl.snow[c])).sum();
                        cl.base[b] = base;
                        cl.snow[b] = (s / 4) as u32;
                        // A coarse ceiling that lets the block gain at most `room` less a margin
                        // (f32 rounding of base + snow), so the prolonged change fits every cell.
                        cl.ceiling[b] = if room == u32::MAX {
                            f32::INFINITY
                        } else {
                            let gain = f64::from(cl.snow[b]) + f64::from(room)
                                - f64::from(CEILING_MARGIN_UNITS);
                            let top = f64::from(base) + gain * SNOW_UNIT_M;
                            top as f32
                        };
                    } else {
                        cl.base[b] = f32::NAN;
                        cl.snow[b] = 0;
                        cl.ceiling[b] = f32::INFINITY;
                    }
                    cl.normal[b] = [0.0, 1.0, 0.0];
                }
            }
            self.before[k].copy_from_slice(&cl.snow);
        }
        // Pass 2: coarse links. Side d of block (bi, bj): its two fine cells on that side.
        for k in 0..n_layers {
            for bj in 0..cnz {
                for bi in 0..cnx {
                    let b = bj * cnx + bi;
                    if self.maps.layers[k].base[b].is_nan() {
                        continue;
                    }
                    let [a, r, u, ru] = block_cells(fnx, bi, bj);
                    let sides = [(a, u), (r, ru), (a, r), (u, ru)];
                    let nb = [
                        (bi > 0).then(|| b - 1),
                        (bi + 1 < cnx).then_some(b + 1),
                        (bj > 0).then(|| b - cnx),
                        (bj + 1 < cnz).then_some(b + cnx),
                    ];
                    let mut links = [LINK_WALL; 4];
                    for d in 0..4 {
                        let (c1, c2) = sides[d];
                        let (l1, l2) = (fine.layers[k].links[c1][d], fine.layers[k].links[c2][d]);
                        links[d] = if l1 != l2 || l1 == LINK_WALL {
                            LINK_WALL
                        } else if l1 == LINK_LOST {
                            LINK_LOST
                        } else {
                            match nb[d] {
                                Some(b2)
                                    if !self.maps.layers[usize::from(l1)].base[b2].is_nan() =>
                                {
                                    l1
                                }
                                _ => LINK_WALL,
                            }
                        };
                    }
                    self.maps.layers[k].links[b] = links;
                }
            }
        }
    }

    fn prolong(&self, fine: &mut SnowMaps) {
        let (cnx, fnx) = (self.maps.nx, fine.nx);
        for (k, cl) in self.maps.layers.iter().enumerate() {
            let fl = &mut fine.layers[k];
            for (b, (&after, &before)) in cl.snow.iter().zip(&self.before[k]).enumerate() {
                if after == before {
                    continue;
                }
                let cells = block_cells(fnx, b % cnx, b / cnx);
                let delta = i64::from(after) - i64::from(before);
                let mut deficit = 0i64;
                for &c in &cells {
                    let v = i64::from(fl.snow[c]) + delta;
                    if v < 0 {
                        deficit -= v;
                        fl.snow[c] = 0;
                    } else {
                        fl.snow[c] = v as u32;
                    }
                }
                for &c in &cells {
                    if deficit == 0 {
                        break;
                    }
                    let take = deficit.min(i64::from(fl.snow[c]));
                    fl.snow[c] -= take as u32;
                    deficit -= take;
                }
                debug_assert_eq!(deficit, 0, "a block cannot give more than it has");
            }
        }
    }
}
