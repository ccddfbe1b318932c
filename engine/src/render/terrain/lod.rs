//! Prefiltered shading of minified terrain ("Texture level of detail" in [`super`]): when one
//! pixel's footprint on the ground spans several grid cells, the ray caster still finds the
//! exact first hit on the full-resolution surface, but shades it from box-averaged copies of the
//! albedo, the heights (for the normal) and the sun visibility, at the pyramid level whose cells
//! are about as wide as the footprint — the mipmapping of texture filtering (Williams,
//! "Pyramidal Parametrics", SIGGRAPH 1983) applied to everything the terrain's shading reads.
//!
//! Why: at 4096² → 1080p each pixel covers 2–30 cells, so a single shading sample aliases the
//! snow pattern and the sub-pixel relief; the adaptive anti-aliasing then refined 65 % of the
//! pixels with `samples` more rays (72 % of all rays), and still aliased (5 samples of a 16-cell
//! footprint). With the prefiltered attributes the centre sample already is the footprint's
//! average, neighbouring centres differ by the smooth variation of the filtered field, and the
//! refinement test ([`super::shade::Px::differs`]) looks at colour steps only between centres
//! in neither the same nor adjacent filtered cells: silhouettes, depth jumps and real edges still get the
//! extra rays.
//!
//! **Level choice.** The footprint of a sample at distance `t` is `t · θ` with `θ` the angle of
//! a pixel (`2 tan(fov/2) / height`); the level is `L = ⌊log₂(t·θ / cell)⌋` (0 below two cells
//! per pixel: full resolution, the same bytes as without filtering), at most [`MAX_LEVEL`]. The
//! footprint is taken isotropic (its width across the ray): along a grazing ray it is longer,
//! and that direction keeps the (rarer) refinement. Level `L` point `i` is the mean of the
//! level-0 grid points `[i·2^L, (i+1)·2^L)` (nodata points skipped; all nodata = nodata), centred
//! at `i·2^L + (2^L − 1)/2`, interpolated bilinearly like level 0.
//!
//! **Normal** at level `L`: central differences of the mean heights `2^L` cells apart (one-sided
//! at borders and nodata, as at level 0), interpolated bilinearly between the four surrounding
//! level points, then normalised: the normal of the smoothed surface, whose Lambert term is the
//! footprint's average up to the curvature inside it.
//!
//! Used on the ray-casting path only (the rasteriser draws DEMs with fewer cells than pixels,
//! where the level is 0) and only when [`super::Lighting::texture_lod`] is on (the `winter`
//! default; the `paper` preset keeps the single point sample of the paper's figures).

use rayon::prelude::*;

use crate::geom::vec::{normalized, DVec3};

/// Coarsest level (cells of 2^6 = 64 grid cells).
pub const MAX_LEVEL: usize = 6;

/// One level of the shading pyramid.
pub(super) struct LodLevel {
    pub(super) w: usize,
    pub(super) h: usize,
    /// Mean heights (world units; NaN = nodata).
    pub(super) height: Vec<f32>,
    /// Their gradients (dh/dx, dh/dz) per point (see `level_gradient`).
    pub(super) grad: Vec<[f32; 2]>,
    /// Mean sun visibility, 0–1 (empty without a sun map).
    pub(super) sun: Vec<f32>,
    /// Mean linear albedo (empty until [`ShadeLod::with_albedo`]).
    pub(super) albedo: Vec<[f32; 3]>,
}

/// The shading pyramid of a terrain: levels 1..=`levels.len()`.
pub(super) struct ShadeLod {
    pub(super) levels: Vec<LodLevel>,
    /// `θ / cell`: multiplied by the distance `t`, the footprint in cells.
    pub(super) footprint_per_t: f64,
    /// `thresholds[L − 1]`: the smallest footprint (cells) whose `⌊log₂⌋` as computed by
    /// `f64::log2` is `L` or more ([`level_thresholds`]), so that [`Self::level`] compares
    /// instead of taking a logarithm per hit.
    thresholds: [f64; MAX_LEVEL],
    /// No level-0 height is NaN (the DEM has no nodata): whole blocks skip the validity test.
    all_valid: bool,
}

/// `thresholds[L − 1]` = the smallest `f` ≥ 1 with `f.log2() as usize ≥ L`, for `L` in
/// 1..=[`MAX_LEVEL`]: `2^L`, or just below it if `log2` rounds a value a few ulps under `2^L`
/// up to `L` (a correctly rounded `log2` does so above `2^2`). `log2` is monotone, so for
/// `f` ≥ 1, `f.log2() as usize` is the number of thresholds at or below `f` (up to `MAX_LEVEL`).
fn level_thresholds() -> [f64; MAX_LEVEL] {
    let mut t = [0.0; MAX_LEVEL];
    for (l, x) in t.iter_mut().enumerate() {
        let level = l + 1;
        let mut v = (1u64 << level) as f64;
        loop {
            let below = f64::from_bits(v.to_bits() - 1);
            if (below.log2() as usize) < level {
                break;
            }
            v = below;
        }
        *x = v;
    }
    t
}

/// Means of the `2 × 2` blocks of a `w × h` grid of `N`-channel values `chans(src[k])`, over
/// the points whose `valid` height is not NaN (the partial blocks at odd edges average what they
/// have), stored as `make(mean)`; `make(empty)` where a block has no valid point. `all_valid`
/// says that no `valid` height is NaN (the DEM has no nodata: every level then has none), and
/// whole blocks skip the test. Parallel over output rows, no allocation inside.
#[allow(clippy::too_many_arguments)]
fn halve<S: Copy + Sync, const N: usize, T: Send + Copy + Default>(
    w: usize,
    h: usize,
    valid: &[f32],
    all_valid: bool,
    src: &[S],
    chans: impl Fn(S) -> [f32; N] + Sync,
    make: impl Fn([f32; N]) -> T + Sync,
    empty: [f32; N],
) -> Vec<T> {
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![T::default(); nw * nh];
    // A whole block of valid points (nearly all): the sum in the order of the general path
    // below, without the per-point tests.
    let whole = |a: S, b: S, c: S, d: S| -> T {
        let (a, b, c, d) = (chans(a), chans(b), chans(c), chans(d));
        let mut acc = [0.0f32; N];
        for (ch, x) in acc.iter_mut().enumerate() {
            *x = 0.0 + a[ch] + b[ch] + c[ch] + d[ch];
        }
        make(acc.map(|a| a * 0.25))
    };
    out.par_chunks_mut(nw).enumerate().for_each(|(j, row)| {
        // The block's source rows (the last one repeated at an odd bottom edge: its points
        // count once, see `second`).
        let r0 = 2 * j;
        let second = r0 + 1 < h;
        let r1 = if second { r0 + 1 } else { r0 };
        let (v0, v1) = (&valid[r0 * w..r0 * w + w], &valid[r1 * w..r1 * w + w]);
        let (s0, s1) = (&src[r0 * w..r0 * w + w], &src[r1 * w..r1 * w + w]);
        // Blocks 0..full have four points.
        let full = if second { w / 2 } else { 0 };
        if all_valid {
            for ((o, p), q) in row[..full]
                .iter_mut()
                .zip(s0.chunks_exact(2))
                .zip(s1.chunks_exact(2))
            {
                *o = whole(p[0], p[1], q[0], q[1]);
            }
        }
        let first = if all_valid { full } else { 0 };
        for (i, o) in row.iter_mut().enumerate().skip(first) {
            let c0 = 2 * i;
            let c1 = (c0 + 1).min(w - 1);
            if i < full && !(v0[c0] + v0[c1] + v1[c0] + v1[c1]).is_nan() {
                *o = whole(s0[c0], s0[c1], s1[c0], s1[c1]);
                continue;
            }
            let mut acc = [0.0f32; N];
            let mut n = 0u32;
            let mut add = |ok: bool, v: S| {
                if ok {
                    for (a, x) in acc.iter_mut().zip(chans(v)) {
                        *a += x;
                    }
                    n += 1;
                }
            };
            add(!v0[c0].is_nan(), s0[c0]);
            add(c1 != c0 && !v0[c1].is_nan(), s0[c1]);
            add(second && !v1[c0].is_nan(), s1[c0]);
            add(second && c1 != c0 && !v1[c1].is_nan(), s1[c1]);
            *o = make(if n == 0 {
                empty
            } else {
                let inv = 1.0 / n as f32;
                acc.map(|a| a * inv)
            });
        }
    });
    out
}

/// Gradient (dh/dx, dh/dz) of the `w × h` level heights `height` (points `2^l` cells of
/// `dx × dy` apart) at point (`c`, `r`): central differences, one-sided at borders and next to
/// nodata, 0 where neither neighbour holds data.
#[inline]
#[allow(clippy::too_many_arguments)]
fn level_gradient(
    height: &[f32],
    w: usize,
    h: usize,
    l: usize,
    dx: f64,
    dy: f64,
    c: usize,
    r: usize,
) -> [f32; 2] {
    let at = |c: usize, r: usize| height[r * w + c];
    let centre = at(c, r);
    let s = (1u64 << l) as f32;
    let diff = |lo: Option<f32>, hi: Option<f32>, step: f32| -> f32 {
        match (lo.filter(|v| !v.is_nan()), hi.filter(|v| !v.is_nan())) {
            (Some(a), Some(b)) => (b - a) / (2.0 * step),
            (Some(a), None) if !centre.is_nan() => (centre - a) / step,
            (None, Some(b)) if !centre.is_nan() => (b - centre) / step,
            _ => 0.0,
        }
    };
    let gx = diff(
        (c > 0).then(|| at(c - 1, r)),
        (c + 1 < w).then(|| at(c + 1, r)),
        s * dx as f32,
    );
    let gz = diff(
        (r > 0).then(|| at(c, r - 1)),
        (r + 1 < h).then(|| at(c, r + 1)),
        s * dy as f32,
    );
    [gx, gz]
}

impl ShadeLod {
    /// The geometry levels (heights, sun visibility) of a `width × height` grid whose samples
    /// span `footprint_per_t · t` cells at distance `t`; `None` when no sample of the view can
    /// reach level 1 (`max_t · footprint_per_t < 2`) or the grid is too small to halve.
    /// `all_valid`: no height is NaN (the caller knows it: the render's hole test).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn new(
        heights: &[f32],
        all_valid: bool,
        sun_map: Option<&[u8]>,
        width: usize,
        height: usize,
        dx: f64,
        dy: f64,
        footprint_per_t: f64,
        max_t: f64,
    ) -> Option<Self> {
        // (NaN reach counts as too small.)
        let reach = max_t * footprint_per_t;
        if reach.is_nan() || reach < 2.0 || width < 8 || height < 8 {
            return None;
        }
        let top = ((max_t * footprint_per_t).log2().floor() as usize).min(MAX_LEVEL);
        let mut levels: Vec<LodLevel> = Vec::new();
        let (mut w, mut h) = (width, height);
        for _ in 0..top {
            if w < 4 || h < 4 {
                break;
            }
            let hs: &[f32] = levels.last().map_or(heights, |l| &l.height);
            let height_next = halve(w, h, hs, all_valid, hs, |v| [v], |[v]| v, [f32::NAN]);
            // Visibility 0/1 per grid point (level 0) or its means; 0 where all is nodata.
            let sun_next = match (levels.last(), sun_map) {
                (None, Some(m)) => {
                    halve(w, h, hs, all_valid, m, |v| [f32::from(v)], |[v]| v, [0.0])
                }
                (Some(l), _) if !l.sun.is_empty() => {
                    halve(w, h, hs, all_valid, &l.sun, |v| [v], |[v]| v, [0.0])
                }
                _ => Vec::new(),
            };
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            // The level's gradients once (every hit reads four of them).
            let l = levels.len() + 1;
            let mut grad = vec![[0.0f32; 2]; nw * nh];
            let s = (1u64 << l) as f32;
            let (two_sx, two_sz) = (2.0 * (s * dx as f32), 2.0 * (s * dy as f32));
            let hn = &height_next;
            grad.par_chunks_mut(nw).enumerate().for_each(|(r, row)| {
                // Interior points: central differences straight from the three rows; where a
                // neighbour is NaN (nodata) the difference is NaN and `level_gradient` decides.
                if r > 0 && r + 1 < nh && nw >= 3 {
                    let (up, mid, dn) = (
                        &hn[(r - 1) * nw..r * nw],
                        &hn[r * nw..(r + 1) * nw],
                        &hn[(r + 1) * nw..(r + 2) * nw],
                    );
                    for ((((g, &a), &b), &u), &d) in row[1..nw - 1]
                        .iter_mut()
                        .zip(&mid[..nw - 2])
                        .zip(&mid[2..])
                        .zip(&up[1..nw - 1])
                        .zip(&dn[1..nw - 1])
                    {
                        *g = [(b - a) / two_sx, (d - u) / two_sz];
                    }
                    for (c, g) in row.iter_mut().enumerate().take(nw - 1).skip(1) {
                        if g[0].is_nan() || g[1].is_nan() {
                            *g = level_gradient(hn, nw, nh, l, dx, dy, c, r);
                        }
                    }
                    row[0] = level_gradient(hn, nw, nh, l, dx, dy, 0, r);
                    row[nw - 1] = level_gradient(hn, nw, nh, l, dx, dy, nw - 1, r);
                } else {
                    for (c, g) in row.iter_mut().enumerate() {
                        *g = level_gradient(hn, nw, nh, l, dx, dy, c, r);
                    }
                }
            });
            levels.push(LodLevel {
                w: nw,
                h: nh,
                height: height_next,
                grad,
                sun: sun_next,
                albedo: Vec::new(),
            });
            (w, h) = (nw, nh);
        }
        (!levels.is_empty()).then_some(Self {
            levels,
            footprint_per_t,
            thresholds: level_thresholds(),
            all_valid,
        })
    }

    /// The albedo levels from the level-0 albedo (`heights` says which points are valid).
    pub(super) fn with_albedo(
        mut self,
        heights: &[f32],
        albedo: &[[f32; 3]],
        width: usize,
        height: usize,
    ) -> Self {
        let (mut w, mut h) = (width, height);
        let mut prev: Option<usize> = None;
        for li in 0..self.levels.len() {
            let next = {
                let (src, hs): (&[[f32; 3]], &[f32]) = match prev {
                    None => (albedo, heights),
                    Some(p) => (&self.levels[p].albedo, &self.levels[p].height),
                };
                halve(w, h, hs, self.all_valid, src, |v| v, |v| v, [0.0; 3])
            };
            self.levels[li].albedo = next;
            (w, h) = (self.levels[li].w, self.levels[li].h);
            prev = Some(li);
        }
        self
    }

    /// The level for a sample at distance `t` (0 = full resolution).
    #[inline]
    pub(super) fn level(&self, t: f64) -> usize {
        let f = t * self.footprint_per_t;
        if f.is_nan() || f < 2.0 {
            return 0;
        }
        // `(f.log2() as usize).min(levels)`, by comparisons (see `thresholds`).
        self.thresholds[..self.levels.len().min(MAX_LEVEL)]
            .iter()
            .map(|&x| usize::from(f >= x))
            .sum()
    }

    /// Bilinear position on level `l` (≥ 1) of the level-0 grid position (`x0`, `z0`): the
    /// lower-left level point and the weights.
    #[inline]
    fn locate(lv: &LodLevel, l: usize, x0: f64, z0: f64) -> (usize, usize, f32, f32) {
        let s = (1u64 << l) as f64;
        let u = ((x0 + 0.5) / s - 0.5).clamp(0.0, (lv.w - 1) as f64);
        let v = ((z0 + 0.5) / s - 0.5).clamp(0.0, (lv.h - 1) as f64);
        let (i, j) = ((u as usize).min(lv.w - 2), (v as usize).min(lv.h - 2));
        (i, j, (u - i as f64) as f32, (v - j as f64) as f32)
    }

    /// The filtered albedo, unit normal and sun visibility (`None` without a sun map) at level
    /// `l` ≥ 1 of the level-0 grid position (`x0`, `z0`).
    #[inline]
    pub(super) fn shade_inputs(
        &self,
        l: usize,
        x0: f64,
        z0: f64,
    ) -> ([f32; 3], [f64; 3], Option<f32>) {
        let lv = &self.levels[l - 1];
        let (i, j, a, b) = Self::locate(lv, l, x0, z0);
        let wts = [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b];
        let ks = [
            j * lv.w + i,
            j * lv.w + i + 1,
            (j + 1) * lv.w + i,
            (j + 1) * lv.w + i + 1,
        ];
        let mut albedo = [0.0f32; 3];
        for (wk, &k) in wts.iter().zip(&ks) {
            for (a, v) in albedo.iter_mut().zip(lv.albedo[k]) {
                *a += wk * v;
            }
        }
        let pts = [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)];
        let (mut gx, mut gz) = (0.0f32, 0.0f32);
        for (wk, &(c, r)) in wts.iter().zip(&pts) {
            let g = lv.grad[r * lv.w + c];
            gx += wk * g[0];
            gz += wk * g[1];
        }
        let n = normalized(DVec3::new(-f64::from(gx), 1.0, -f64::from(gz))).to_array();
        let sun = (!lv.sun.is_empty()).then(|| {
            wts.iter()
                .zip(&ks)
                .map(|(wk, &k)| wk * lv.sun[k])
                .sum::<f32>()
        });
        (albedo, n, sun)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The comparisons give `⌊log₂⌋` as `f64::log2` does, up to the level count, also within
    /// a few ulps of each power of two.
    #[test]
    fn level_by_thresholds_is_log2() {
        let thr = level_thresholds();
        let by_log = |f: f64, n: usize| (f.log2() as usize).min(n);
        let by_thr =
            |f: f64, n: usize| -> usize { thr[..n].iter().map(|&x| usize::from(f >= x)).sum() };
        let mut fs = vec![2.0, 3.0, 1e3, 1e300, f64::INFINITY, f64::MAX];
        for l in 1..=MAX_LEVEL + 1 {
            let p = (1u64 << l) as f64;
            for d in 0..2000u64 {
                fs.push(f64::from_bits(p.to_bits() - d));
                fs.push(f64::from_bits(p.to_bits() + d));
            }
        }
        let mut x = 2.0f64;
        while x < 300.0 {
            fs.push(x);
            x *= 1.000_37;
        }
        for n in 1..=MAX_LEVEL {
            for &f in &fs {
                assert_eq!(by_thr(f, n), by_log(f, n), "f = {f:e}, {n} levels");
            }
        }
    }

    /// Without nodata, the whole-block path gives the bits of the general one (which is what
    /// it skips: the per-block validity test), odd sizes included.
    #[test]
    fn halving_without_nodata_matches_the_tested_path() {
        for (w, h) in [(9usize, 7usize), (16, 10), (5, 12)] {
            let hs: Vec<f32> = (0..w * h)
                .map(|k| ((k * 7919) % 1013) as f32 * 0.37 - 40.0)
                .collect();
            let rgb: Vec<[f32; 3]> = (0..w * h)
                .map(|k| [k as f32 * 0.01, -(k as f32), 0.5])
                .collect();
            let a = halve(w, h, &hs, true, &hs, |v| [v], |[v]| v, [f32::NAN]);
            let b = halve(w, h, &hs, false, &hs, |v| [v], |[v]| v, [f32::NAN]);
            assert_eq!(
                a.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                b.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            );
            let a = halve(w, h, &hs, true, &rgb, |v| v, |v| v, [0.0; 3]);
            let b = halve(w, h, &hs, false, &rgb, |v| v, |v| v, [0.0; 3]);
            assert_eq!(a, b);
        }
    }

    /// The level gradients: interior central differences as `level_gradient` computes them,
    /// one-sided next to nodata.
    #[test]
    fn level_gradients_match_the_pointwise_rule() {
        let (w, h) = (40usize, 30usize);
        let mut hs: Vec<f32> = (0..w * h)
            .map(|k| (((k % w) as f32 * 0.3).sin() + (k / w) as f32 * 0.2) * 50.0)
            .collect();
        for k in [
            5 * w + 7,
            12 * w + 20,
            12 * w + 21,
            13 * w + 20,
            13 * w + 21,
            29 * w + 39,
        ] {
            hs[k] = f32::NAN;
        }
        let lod = ShadeLod::new(&hs, false, None, w, h, 30.0, 25.0, 1.0, 64.0).unwrap();
        assert!(lod.levels[0].height[6 * lod.levels[0].w + 10].is_nan());
        let (mut lw, mut lh) = (w, h);
        for (i, lv) in lod.levels.iter().enumerate() {
            (lw, lh) = (lw.div_ceil(2), lh.div_ceil(2));
            assert_eq!((lv.w, lv.h), (lw, lh));
            for r in 0..lh {
                for c in 0..lw {
                    let want = level_gradient(&lv.height, lw, lh, i + 1, 30.0, 25.0, c, r);
                    let got = lv.grad[r * lw + c];
                    assert_eq!(
                        (got[0].to_bits(), got[1].to_bits()),
                        (want[0].to_bits(), want[1].to_bits()),
                        "level {} point {c},{r}",
                        i + 1
                    );
                }
            }
        }
    }
}
