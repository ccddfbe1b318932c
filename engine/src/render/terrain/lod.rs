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
}

/// Means of the `2 × 2` blocks of a `w × h` grid of `N`-channel values `get(k)`, over the
/// points whose `valid` height is not NaN (the partial blocks at odd edges average what they
/// have), stored as `make(mean)`; `make(empty)` where a block has no valid point. Parallel over
/// output rows, no allocation inside.
fn halve<const N: usize, T: Send + Copy + Default>(
    w: usize,
    h: usize,
    valid: &[f32],
    get: impl Fn(usize) -> [f32; N] + Sync,
    make: impl Fn([f32; N]) -> T + Sync,
    empty: [f32; N],
) -> Vec<T> {
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![T::default(); nw * nh];
    out.par_chunks_mut(nw).enumerate().for_each(|(j, row)| {
        // The block's source rows (the last one repeated at an odd bottom edge: its points
        // count once, see `second`).
        let r0 = 2 * j;
        let second = r0 + 1 < h;
        let r1 = if second { r0 + 1 } else { r0 };
        let (v0, v1) = (&valid[r0 * w..r0 * w + w], &valid[r1 * w..r1 * w + w]);
        for (i, o) in row.iter_mut().enumerate() {
            let c0 = 2 * i;
            let c1 = (c0 + 1).min(w - 1);
            // Whole blocks of valid points (nearly all): the same sums in the same order,
            // without the per-point tests.
            if second && c1 != c0 && !(v0[c0] + v0[c1] + v1[c0] + v1[c1]).is_nan() {
                let k = r0 * w + c0;
                let (a, b, c, d) = (get(k), get(k + 1), get(k + w), get(k + w + 1));
                let mut acc = [0.0f32; N];
                for (ch, x) in acc.iter_mut().enumerate() {
                    *x = 0.0 + a[ch] + b[ch] + c[ch] + d[ch];
                }
                *o = make(acc.map(|a| a * 0.25));
                continue;
            }
            let mut acc = [0.0f32; N];
            let mut n = 0u32;
            let mut add = |ok: bool, k: usize| {
                if ok {
                    let v = get(k);
                    for (a, x) in acc.iter_mut().zip(v) {
                        *a += x;
                    }
                    n += 1;
                }
            };
            add(!v0[c0].is_nan(), r0 * w + c0);
            add(c1 != c0 && !v0[c1].is_nan(), r0 * w + c1);
            add(second && !v1[c0].is_nan(), r1 * w + c0);
            add(second && c1 != c0 && !v1[c1].is_nan(), r1 * w + c1);
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
    #[allow(clippy::too_many_arguments)]
    pub(super) fn new(
        heights: &[f32],
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
            let height_next = halve(w, h, hs, |k| [hs[k]], |[v]| v, [f32::NAN]);
            // Visibility 0/1 per grid point (level 0) or its means; 0 where all is nodata.
            let sun_next = match (levels.last(), sun_map) {
                (None, Some(m)) => halve(w, h, hs, |k| [f32::from(m[k])], |[v]| v, [0.0]),
                (Some(l), _) if !l.sun.is_empty() => {
                    let sun = &l.sun;
                    halve(w, h, hs, |k| [sun[k]], |[v]| v, [0.0])
                }
                _ => Vec::new(),
            };
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            // The level's gradients once (every hit reads four of them).
            let l = levels.len() + 1;
            let mut grad = vec![[0.0f32; 2]; nw * nh];
            grad.par_chunks_mut(nw).enumerate().for_each(|(r, row)| {
                for (c, g) in row.iter_mut().enumerate() {
                    *g = level_gradient(&height_next, nw, nh, l, dx, dy, c, r);
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
                halve(w, h, hs, |k| src[k], |v| v, [0.0; 3])
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
        (f.log2() as usize).min(self.levels.len())
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
