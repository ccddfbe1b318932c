//! The maximum-height pyramid over a height field and the ray queries on it (see
//! "Acceleration" in [`super`]): exact ray/cell intersection, smooth normals, bilinear lookups
//! and the fall-through test for holes.

use rayon::prelude::*;

use super::scene::{height_range, Hit, TerrainScene};
use crate::geom::vec::{normalized, DVec3};

/// Pyramid level at which rays start (nodes of 2^4 = 16 cells).
const START_LEVEL: usize = 4;

pub(super) struct Level {
    pub w: usize,
    pub h: usize,
    pub max: Vec<f32>,
}

/// The maximum-height pyramid over a [`TerrainScene`] and the ray queries on it. Building costs one
/// pass over the heights (parallel) and n/3 floats; queries are read-only and thread-safe.
pub struct TerrainAccel<'a> {
    pub(super) scene: TerrainScene<'a>,
    /// Cells along X and Z (grid points − 1).
    pub(super) cw: usize,
    pub(super) ch: usize,
    /// `levels[k]` has nodes of `2^(k+1)` cells; the last one is a single node.
    pub(super) levels: Vec<Level>,
    /// Node counts (x, z) per level, level 0 = cells; `dims[level]`.
    pub(super) dims: Vec<(usize, usize)>,
    pub(super) hmin: f64,
    pub(super) hmax: f64,
    pub(super) half_x: f64,
    pub(super) half_z: f64,
    /// Smallest cell size, for epsilons.
    pub(super) cell: f64,
    /// Slack on height comparisons (rounding of `o + t·d`), world units.
    pub(super) eps_y: f64,
}

impl<'a> TerrainAccel<'a> {
    /// Build the pyramid. Panics when `heights` or `albedo` is not `width × height` long or a cell
    /// size is not positive (caller bugs, not input errors).
    pub fn new(scene: &TerrainScene<'a>) -> Self {
        let n = scene.width * scene.height;
        assert_eq!(scene.albedo.len(), n, "albedo must be width × height");
        Self::new_geometry(scene)
    }

    /// [`Self::new`] for a scene whose `albedo` is not known yet (it may be empty): enough for
    /// [`prepare_view`], which reads the heights only. Give it the colours with
    /// [`Self::with_albedo`] before drawing.
    pub fn new_geometry(scene: &TerrainScene<'a>) -> Self {
        let n = scene.width * scene.height;
        assert_eq!(scene.heights.len(), n, "heights must be width × height");
        assert!(
            scene.dx > 0.0 && scene.dy > 0.0,
            "cell sizes must be positive"
        );
        let cw = scene.width.saturating_sub(1);
        let ch = scene.height.saturating_sub(1);
        let (hmin, hmax) =
            height_range(scene.heights).map_or((0.0, -1.0), |(a, b)| (f64::from(a), f64::from(b)));
        let mut levels: Vec<Level> = Vec::new();
        if cw > 0 && ch > 0 && hmax >= hmin {
            // Level 1 straight from the grid points: node (i, j) covers points [2i, 2i+2]².
            let (w, h) = (cw.div_ceil(2), ch.div_ceil(2));
            let mut max = vec![f32::NEG_INFINITY; w * h];
            let (gw, gh) = (scene.width, scene.height);
            // Per node row: the column maxima of its (up to) three grid rows first, then the
            // maxima of three adjacent columns, both branch-free loops the compiler vectorises.
            // `max` ignores NaN operands (all NaN: −∞), and the maximum does not depend on the
            // order.
            max.par_chunks_mut(w)
                .enumerate()
                .for_each_init(Vec::new, |col, (j, row)| {
                    let r1 = (2 * j + 2).min(gh - 1);
                    col.clear();
                    col.resize(gw, f32::NEG_INFINITY);
                    for r in 2 * j..=r1 {
                        for (m, &v) in col.iter_mut().zip(&scene.heights[r * gw..(r + 1) * gw]) {
                            *m = m.max(v);
                        }
                    }
                    // Node i covers grid columns 2i ..= min(2i + 2, gw − 1).
                    let whole = (gw - 1) / 2;
                    for (i, m) in row.iter_mut().enumerate().take(whole) {
                        *m = col[2 * i].max(col[2 * i + 1]).max(col[2 * i + 2]);
                    }
                    for (i, m) in row.iter_mut().enumerate().skip(whole) {
                        let c1 = (2 * i + 2).min(gw - 1);
                        *m = col[2 * i..=c1]
                            .iter()
                            .fold(f32::NEG_INFINITY, |a, &v| a.max(v));
                    }
                });
            levels.push(Level { w, h, max });
            while levels.last().is_some_and(|l| l.w > 1 || l.h > 1) {
                let Some(prev) = levels.last() else { break };
                let (w, h) = (prev.w.div_ceil(2), prev.h.div_ceil(2));
                let mut max = vec![f32::NEG_INFINITY; w * h];
                max.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
                    for (i, m) in row.iter_mut().enumerate() {
                        let mut acc = f32::NEG_INFINITY;
                        for cj in 2 * j..(2 * j + 2).min(prev.h) {
                            for ci in 2 * i..(2 * i + 2).min(prev.w) {
                                acc = acc.max(prev.max[cj * prev.w + ci]);
                            }
                        }
                        *m = acc;
                    }
                });
                levels.push(Level { w, h, max });
            }
        }
        let dims = std::iter::once((cw, ch))
            .chain(levels.iter().map(|l| (l.w, l.h)))
            .collect();
        Self {
            scene: *scene,
            cw,
            ch,
            levels,
            dims,
            hmin,
            hmax,
            half_x: cw as f64 * scene.dx * 0.5,
            half_z: ch as f64 * scene.dy * 0.5,
            cell: scene.dx.min(scene.dy),
            eps_y: 1e-9 * (hmin.abs().max(hmax.abs()) + scene.dx.max(scene.dy)),
        }
    }

    /// This pyramid (heights unchanged) over the scene with `albedo` (the pyramid does not depend
    /// on it). Panics when `albedo` is not `width × height` long (a caller bug).
    pub fn with_albedo<'b>(self, albedo: &'b [[f32; 3]]) -> TerrainAccel<'b>
    where
        'a: 'b,
    {
        let this: TerrainAccel<'b> = self;
        assert_eq!(
            albedo.len(),
            this.scene.width * this.scene.height,
            "albedo must be width × height"
        );
        TerrainAccel {
            scene: TerrainScene {
                albedo,
                ..this.scene
            },
            ..this
        }
    }

    /// The scene this pyramid was built over.
    pub fn scene(&self) -> &TerrainScene<'a> {
        &self.scene
    }

    /// First intersection of the ray `origin + t·dir` (`dir` unit length) with `t` in
    /// `[tmin, tmax]`. O(log n) node visits on typical terrain; no allocation.
    pub fn intersect(&self, origin: [f64; 3], dir: [f64; 3], tmin: f64, tmax: f64) -> Option<Hit> {
        if self.levels.is_empty() {
            return None;
        }
        let r = self.grid_ray(origin, dir);
        let (t0, t1) = self.clip(&r, tmin, tmax)?;
        let top = self.levels.len();
        // Start at 16-cell nodes rather than the root: from the root every ray first spends
        // ~log2(n) visits descending; the ascent rule climbs again where the ray is high.
        // Measured: 19 → 15 node visits per ray on the paper case.
        let mut level = top.min(START_LEVEL);
        let (lw, lh) = self.dims(level);
        let s0 = (1u64 << level) as f64;
        let mut ci = (((r.ou + r.du * t0) / s0).floor().max(0.0) as usize).min(lw - 1);
        let mut cj = (((r.ov + r.dv * t0) / s0).floor().max(0.0) as usize).min(lh - 1);
        // Rays oblique to both grid axes (all but a few) take the walk specialised to their
        // direction (`walk`): the same node visits and the same values, fewer instructions.
        const BIG: f64 = 1e290;
        if r.inv_du.abs() < BIG && r.inv_dv.abs() < BIG && r.du != 0.0 && r.dv != 0.0 {
            let start = (level, ci, cj, t0, t1);
            return match (r.du > 0.0, r.dv > 0.0) {
                (true, true) => self.walk::<true, true>(&r, start, tmin, tmax),
                (true, false) => self.walk::<true, false>(&r, start, tmin, tmax),
                (false, true) => self.walk::<false, true>(&r, start, tmin, tmax),
                (false, false) => self.walk::<false, false>(&r, start, tmin, tmax),
            };
        }
        let mut t = t0;
        loop {
            let s = (1u64 << level) as f64;
            let tx = exit_t(ci, s, r.ou, r.du, r.inv_du);
            let tz = exit_t(cj, s, r.ov, r.dv, r.inv_dv);
            let texit = tx.min(tz);
            let tend = texit.min(t1);
            if level == 0 {
                let (ya, yb) = (r.oy + r.dy * t, r.oy + r.dy * tend);
                if let Some(hit) = self.cell_hit(ci, cj, &r, ya.min(yb), ya.max(yb), tmin, tmax) {
                    return Some(hit);
                }
            } else {
                let lv = &self.levels[level - 1];
                let m = f64::from(lv.max[cj * lv.w + ci]);
                let ylo = (r.oy + r.dy * t).min(r.oy + r.dy * tend);
                if ylo <= m + self.eps_y {
                    // Descend into the child holding the ray at `t`.
                    level -= 1;
                    let (cw, ch) = self.dims(level);
                    ci = child(ci, s, r.ou + r.du * t, r.du).min(cw - 1);
                    cj = child(cj, s, r.ov + r.dv * t, r.dv).min(ch - 1);
                    continue;
                }
            }
            if texit >= t1 {
                return None;
            }
            t = texit;
            let (w, h) = self.dims(level);
            let mut new_parent = false;
            if tx <= tz {
                new_parent |= step_axis(&mut ci, r.du > 0.0, w)?;
            }
            if tz <= tx {
                new_parent |= step_axis(&mut cj, r.dv > 0.0, h)?;
            }
            if new_parent && level < top {
                level += 1;
                ci >>= 1;
                cj >>= 1;
            }
        }
    }

    /// The pyramid walk of [`Self::intersect`] for a ray with `du`, `dv` non-zero and finite
    /// reciprocals, `XP`/`ZP` = `du > 0` / `dv > 0`, from `(level, ci, cj, t0, t1)`: the same
    /// node visits and the same floating-point values as the general loop there, with the
    /// direction's branches resolved at compile time, the node size `s` kept (halved and
    /// doubled: exact) instead of converted from the level per visit, the ray's height at the
    /// entry `t` kept between visits, and plain comparisons for `min`/`max` (no operand is NaN:
    /// every `t` is finite).
    #[inline]
    fn walk<const XP: bool, const ZP: bool>(
        &self,
        r: &GridRay,
        (mut level, mut ci, mut cj, t0, t1): (usize, usize, usize, f64, f64),
        tmin: f64,
        tmax: f64,
    ) -> Option<Hit> {
        let top = self.levels.len();
        let min = |a: f64, b: f64| if b < a { b } else { a };
        let max = |a: f64, b: f64| if b > a { b } else { a };
        let (ox, oz) = (u32::from(XP), u32::from(ZP));
        let mut s = (1u64 << level) as f64;
        let (mut w, mut h) = self.dims(level);
        let mut t = t0;
        let mut yt = r.oy + r.dy * t;
        // Climb gate: the ray's clearance over the last node it skipped (∞ after a cell) must
        // exceed twice its drop across a node of that size (`climb * s`) for it to climb on
        // entering a new parent; a ray that skims the node's maximum usually fails the parent's
        // test too and comes straight back down (one wasted visit).
        let climb = 2.0 * r.dy.abs() / max(r.du.abs(), r.dv.abs());
        let mut margin: f64;
        loop {
            // exit_t: the node's far side along each axis.
            let tx = (f64::from(ci as u32 + ox) * s - r.ou) * r.inv_du;
            let tz = (f64::from(cj as u32 + oz) * s - r.ov) * r.inv_dv;
            let texit = min(tx, tz);
            let tend = min(texit, t1);
            let yend = r.oy + r.dy * tend;
            if level == 0 {
                if let Some(hit) =
                    self.cell_hit(ci, cj, r, min(yt, yend), max(yt, yend), tmin, tmax)
                {
                    return Some(hit);
                }
                margin = f64::INFINITY;
            } else {
                let lv = &self.levels[level - 1];
                let m = f64::from(lv.max[cj * lv.w + ci]);
                margin = min(yt, yend) - m;
                if min(yt, yend) <= m + self.eps_y {
                    // Descend into the child holding the ray at `t` (`child`, ties toward the
                    // direction of travel).
                    level -= 1;
                    (w, h) = self.dims(level);
                    let half = s * 0.5;
                    let (pu, pv) = (r.ou + r.du * t, r.ov + r.dv * t);
                    let (mu, mv) = (
                        f64::from(2 * ci as u32 + 1) * half,
                        f64::from(2 * cj as u32 + 1) * half,
                    );
                    ci = (2 * ci + usize::from(pu > mu || (pu == mu && XP))).min(w - 1);
                    cj = (2 * cj + usize::from(pv > mv || (pv == mv && ZP))).min(h - 1);
                    s = half;
                    continue;
                }
            }
            if texit >= t1 {
                return None;
            }
            t = texit;
            yt = yend;
            let mut new_parent = false;
            if tx <= tz {
                new_parent |= step_axis(&mut ci, XP, w)?;
            }
            if tz <= tx {
                new_parent |= step_axis(&mut cj, ZP, h)?;
            }
            if new_parent && level < top && margin > climb * s {
                level += 1;
                ci >>= 1;
                cj >>= 1;
                s *= 2.0;
                (w, h) = self.dims(level);
            }
        }
    }

    /// Reference for tests: the nearest hit over *every* cell, O(n) per ray.
    pub fn intersect_brute(
        &self,
        origin: [f64; 3],
        dir: [f64; 3],
        tmin: f64,
        tmax: f64,
    ) -> Option<Hit> {
        let r = self.grid_ray(origin, dir);
        let mut best: Option<Hit> = None;
        for j in 0..self.ch {
            for i in 0..self.cw {
                if let Some(h) = self.cell_hit(i, j, &r, f64::MIN, f64::MAX, tmin, tmax) {
                    if best.is_none_or(|b| h.t < b.t) {
                        best = Some(h);
                    }
                }
            }
        }
        best
    }

    /// World position of a hit's surface point.
    pub fn hit_position(&self, hit: &Hit) -> [f64; 3] {
        let s = &self.scene;
        let k = hit.row * s.width + hit.col;
        let (h00, h10, h01, h11) = (
            f64::from(s.heights[k]),
            f64::from(s.heights[k + 1]),
            f64::from(s.heights[k + s.width]),
            f64::from(s.heights[k + s.width + 1]),
        );
        let (fx, fz) = (hit.fx, hit.fz);
        let y = if fx >= fz {
            h00 + (h10 - h00) * fx + (h11 - h10) * fz
        } else {
            h00 + (h11 - h01) * fx + (h01 - h00) * fz
        };
        [
            (hit.col as f64 + fx) * s.dx - self.half_x,
            y,
            (hit.row as f64 + fz) * s.dy - self.half_z,
        ]
    }

    /// Smooth unit normal at a hit: corner gradients (central differences, one-sided at borders
    /// and next to holes) interpolated bilinearly.
    pub fn hit_normal(&self, hit: &Hit) -> [f64; 3] {
        let (c, r) = (hit.col, hit.row);
        let g00 = self.gradient(c, r);
        let g10 = self.gradient(c + 1, r);
        let g01 = self.gradient(c, r + 1);
        let g11 = self.gradient(c + 1, r + 1);
        let (fx, fz) = (hit.fx, hit.fz);
        let w = [
            (1.0 - fx) * (1.0 - fz),
            fx * (1.0 - fz),
            (1.0 - fx) * fz,
            fx * fz,
        ];
        let gx = w[0] * g00.0 + w[1] * g10.0 + w[2] * g01.0 + w[3] * g11.0;
        let gz = w[0] * g00.1 + w[1] * g10.1 + w[2] * g01.1 + w[3] * g11.1;
        normalized(DVec3::new(-gx, 1.0, -gz)).to_array()
    }

    /// [`Self::gradient`] at every grid point, parallel over rows. Allocates 16 B per point.
    pub(super) fn gradients(&self) -> Vec<[f64; 2]> {
        let s = &self.scene;
        let mut g = vec![[0.0; 2]; s.width * s.height];
        g.par_chunks_mut(s.width.max(1))
            .enumerate()
            .for_each(|(r, row)| {
                for (c, v) in row.iter_mut().enumerate() {
                    let (gx, gz) = self.gradient(c, r);
                    *v = [gx, gz];
                }
            });
        g
    }

    /// [`Self::hit_bilinear`] of a 0/1 byte map (the sun visibility: a quarter of the memory of
    /// floats, so 4096² fits 16 MB and the per-hit lookups miss the cache less).
    #[inline]
    pub(super) fn hit_bilinear_u8(&self, hit: &Hit, values: &[u8]) -> f32 {
        let w = self.scene.width;
        let k = hit.row * w + hit.col;
        let (fx, fz) = (hit.fx as f32, hit.fz as f32);
        let v = |i: usize| f32::from(values[i]);
        (1.0 - fx) * (1.0 - fz) * v(k)
            + fx * (1.0 - fz) * v(k + 1)
            + (1.0 - fx) * fz * v(k + w)
            + fx * fz * v(k + w + 1)
    }

    /// Bilinear interpolation of a per-grid-point scalar at a hit.
    pub fn hit_bilinear(&self, hit: &Hit, values: &[f32]) -> f32 {
        let w = self.scene.width;
        let k = hit.row * w + hit.col;
        let (fx, fz) = (hit.fx as f32, hit.fz as f32);
        (1.0 - fx) * (1.0 - fz) * values[k]
            + fx * (1.0 - fz) * values[k + 1]
            + (1.0 - fx) * fz * values[k + w]
            + fx * fz * values[k + w + 1]
    }

    /// Bilinear albedo at a hit, linear RGB.
    pub fn hit_albedo(&self, hit: &Hit) -> [f32; 3] {
        let s = &self.scene;
        let k = hit.row * s.width + hit.col;
        let (fx, fz) = (hit.fx as f32, hit.fz as f32);
        let w = [
            (1.0 - fx) * (1.0 - fz),
            fx * (1.0 - fz),
            (1.0 - fx) * fz,
            fx * fz,
        ];
        let a = [
            s.albedo[k],
            s.albedo[k + 1],
            s.albedo[k + s.width],
            s.albedo[k + s.width + 1],
        ];
        let mut out = [0.0f32; 3];
        for (ch, o) in out.iter_mut().enumerate() {
            *o = w[0] * a[0][ch] + w[1] * a[1][ch] + w[2] * a[2][ch] + w[3] * a[3][ch];
        }
        out
    }

    /// True when a ray that hit nothing fell through a hole: it enters the DEM's footprint
    /// (the `x`, `z` rectangle) above the terrain's edge — or over a nodata stretch of the edge, or
    /// starts inside the footprint — and then crosses the plane of the lowest valid height inside
    /// the footprint at `t ≥ tmin`. Rays that pass *under* a valid edge see the cut face of the
    /// DEM and get the sky instead of a transparent sliver.
    pub fn through_footprint(&self, origin: [f64; 3], dir: [f64; 3], tmin: f64) -> bool {
        if self.levels.is_empty() || dir[1] == 0.0 {
            return false;
        }
        let t = (self.hmin - origin[1]) / dir[1];
        if t.is_nan() || t < tmin {
            return false;
        }
        let x = origin[0] + dir[0] * t;
        let z = origin[2] + dir[2] * t;
        if x.abs() > self.half_x || z.abs() > self.half_z {
            return false;
        }
        // Horizontal entry into the footprint: the later of the two slab entries.
        let r = self.grid_ray(origin, dir);
        let entry = |o: f64, d: f64, hi: f64| -> f64 {
            if d > 0.0 {
                -o / d
            } else if d < 0.0 {
                (hi - o) / d
            } else {
                f64::NEG_INFINITY
            }
        };
        let tu = entry(r.ou, r.du, self.cw as f64);
        let tv = entry(r.ov, r.dv, self.ch as f64);
        let te = tu.max(tv);
        if te <= tmin {
            return true; // starts inside the footprint
        }
        let s = &self.scene;
        let (u, v) = (r.ou + r.du * te, r.ov + r.dv * te);
        // Height of the edge line at the entry point (linear between its grid points).
        let edge = |along: f64, n: usize, at: &dyn Fn(usize) -> f32| -> f64 {
            let a = along.clamp(0.0, n as f64);
            let i = (a.floor() as usize).min(n.saturating_sub(1));
            let f = a - i as f64;
            let (h0, h1) = (f64::from(at(i)), f64::from(at((i + 1).min(n))));
            h0 + (h1 - h0) * f
        };
        let h_edge = if tu >= tv {
            let col = if r.du > 0.0 { 0 } else { self.cw };
            edge(v, self.ch, &|j| s.heights[j * s.width + col])
        } else {
            let row = if r.dv > 0.0 { 0 } else { self.ch };
            edge(u, self.cw, &|i| s.heights[row * s.width + i])
        };
        // A NaN edge (nodata margin) counts as falling through.
        h_edge.is_nan() || r.oy + r.dy * te >= h_edge - self.eps_y
    }

    /// Distances from `eye` to the nearest and farthest points of the bounding box.
    pub(super) fn depth_range(&self, eye: [f64; 3]) -> (f64, f64) {
        let lo = [-self.half_x, self.hmin, -self.half_z];
        let hi = [self.half_x, self.hmax.max(self.hmin), self.half_z];
        let mut near2 = 0.0;
        let mut far2 = 0.0;
        for a in 0..3 {
            let d = if eye[a] < lo[a] {
                lo[a] - eye[a]
            } else if eye[a] > hi[a] {
                eye[a] - hi[a]
            } else {
                0.0
            };
            near2 += d * d;
            let f = (eye[a] - lo[a]).abs().max((eye[a] - hi[a]).abs());
            far2 += f * f;
        }
        (near2.sqrt(), far2.sqrt())
    }

    #[inline]
    pub(super) fn dims(&self, level: usize) -> (usize, usize) {
        self.dims[level]
    }

    #[inline]
    pub(super) fn grid_ray(&self, o: [f64; 3], d: [f64; 3]) -> GridRay {
        let s = &self.scene;
        let du = d[0] / s.dx;
        let dv = d[2] / s.dy;
        GridRay {
            ou: (o[0] + self.half_x) / s.dx,
            ov: (o[2] + self.half_z) / s.dy,
            oy: o[1],
            du,
            dv,
            dy: d[1],
            inv_du: 1.0 / du,
            inv_dv: 1.0 / dv,
        }
    }

    /// Clip the ray to the bounding box: `(t0, t1)` or `None` when it misses.
    #[inline]
    pub(super) fn clip(&self, r: &GridRay, tmin: f64, tmax: f64) -> Option<(f64, f64)> {
        let mut t0 = tmin;
        let mut t1 = tmax;
        for (o, d, inv, lo, hi) in [
            (r.ou, r.du, r.inv_du, 0.0, self.cw as f64),
            (r.ov, r.dv, r.inv_dv, 0.0, self.ch as f64),
            (
                r.oy,
                r.dy,
                1.0 / r.dy,
                self.hmin - self.eps_y,
                self.hmax + self.eps_y,
            ),
        ] {
            if d == 0.0 {
                if o < lo || o > hi {
                    return None;
                }
            } else {
                let (a, b) = ((lo - o) * inv, (hi - o) * inv);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        (t0 <= t1).then_some((t0, t1))
    }

    /// Exact intersection with the two triangles of cell (`i`, `j`), `t` in `[tmin, tmax]`.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn cell_hit(
        &self,
        i: usize,
        j: usize,
        r: &GridRay,
        ylo: f64,
        yhi: f64,
        tmin: f64,
        tmax: f64,
    ) -> Option<Hit> {
        const EPS: f64 = 1e-9;
        let w = self.scene.width;
        let k = j * w + i;
        let hs = self.scene.heights;
        let (h00, h10, h01, h11) = (
            f64::from(hs[k]),
            f64::from(hs[k + 1]),
            f64::from(hs[k + w]),
            f64::from(hs[k + w + 1]),
        );
        // Quick reject on the ray's height range over the cell (NaN corners fail both tests).
        let (hlo, hhi) = (
            h00.min(h10).min(h01.min(h11)),
            h00.max(h10).max(h01.max(h11)),
        );
        if ylo > hhi + self.eps_y || yhi < hlo - self.eps_y || (h00 + h10 + h01 + h11).is_nan() {
            return None;
        }
        let a = r.ou - i as f64;
        let c = r.ov - j as f64;
        let mut best: Option<Hit> = None;
        // Triangle A (fx ≥ fz): points 00, 10, 11. Triangle B (fx < fz): points 00, 01, 11.
        for (ga, gb, upper) in [(h10 - h00, h11 - h10, true), (h11 - h01, h01 - h00, false)] {
            let denom = r.dy - ga * r.du - gb * r.dv;
            if denom == 0.0 {
                continue;
            }
            let t = (h00 + ga * a + gb * c - r.oy) / denom;
            if !(t >= tmin && t <= tmax) {
                continue;
            }
            let fx = a + r.du * t;
            let fz = c + r.dv * t;
            let inside = (-EPS..=1.0 + EPS).contains(&fx) && (-EPS..=1.0 + EPS).contains(&fz);
            let side = if upper {
                fx - fz >= -EPS
            } else {
                fz - fx >= -EPS
            };
            if inside && side && best.is_none_or(|b| t < b.t) {
                best = Some(Hit {
                    t,
                    col: i,
                    row: j,
                    fx: fx.clamp(0.0, 1.0),
                    fz: fz.clamp(0.0, 1.0),
                });
            }
        }
        best
    }

    /// (dh/dx, dh/dz) at grid point (`c`, `r`), world units.
    #[inline]
    pub(super) fn gradient(&self, c: usize, r: usize) -> (f64, f64) {
        let s = &self.scene;
        let w = s.width;
        let h = |c: usize, r: usize| f64::from(s.heights[r * w + c]);
        let centre = h(c, r);
        let diff = |lo: Option<f64>, hi: Option<f64>, step: f64| -> f64 {
            match (lo.filter(|v| !v.is_nan()), hi.filter(|v| !v.is_nan())) {
                (Some(a), Some(b)) => (b - a) / (2.0 * step),
                (Some(a), None) => (centre - a) / step,
                (None, Some(b)) => (b - centre) / step,
                (None, None) => 0.0,
            }
        };
        let gx = diff(
            (c > 0).then(|| h(c - 1, r)),
            (c + 1 < w).then(|| h(c + 1, r)),
            s.dx,
        );
        let gz = diff(
            (r > 0).then(|| h(c, r - 1)),
            (r + 1 < s.height).then(|| h(c, r + 1)),
            s.dy,
        );
        (gx, gz)
    }
}

/// A ray in grid coordinates: u = column (east), v = row (south), y = world height; the parameter
/// t is still the world distance.
pub(super) struct GridRay {
    pub(super) ou: f64,
    pub(super) ov: f64,
    pub(super) oy: f64,
    pub(super) du: f64,
    pub(super) dv: f64,
    pub(super) dy: f64,
    pub(super) inv_du: f64,
    pub(super) inv_dv: f64,
}

/// Where a ray leaves node `c` (of `s` cells) along one axis; +∞ when parallel to it.
#[inline]
fn exit_t(c: usize, s: f64, o: f64, d: f64, inv: f64) -> f64 {
    if d > 0.0 {
        ((c + 1) as f64 * s - o) * inv
    } else if d < 0.0 {
        (c as f64 * s - o) * inv
    } else {
        f64::INFINITY
    }
}

/// The child (at half size) of node `c` of size `s` that holds coordinate `p`, ties broken toward
/// the direction of travel.
#[inline]
fn child(c: usize, s: f64, p: f64, d: f64) -> usize {
    let mid = (2 * c + 1) as f64 * (s * 0.5);
    2 * c + usize::from(p > mid || (p == mid && d >= 0.0))
}

/// Steps a node index one node along the ray (`forward` = increasing index) on a level `n` nodes
/// wide. `None` when the ray leaves the grid; otherwise whether it crossed into a new parent node.
#[inline]
fn step_axis(c: &mut usize, forward: bool, n: usize) -> Option<bool> {
    if forward {
        *c += 1;
        if *c >= n {
            return None;
        }
        Some(*c & 1 == 0)
    } else {
        if *c == 0 {
            return None;
        }
        *c -= 1;
        Some(*c & 1 == 1)
    }
}
