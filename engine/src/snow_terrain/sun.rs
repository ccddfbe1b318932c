//! Sun correction by polygon normals (paper §3.4.2, §4.1 lines 10–15, Figs. 7 and 9; SPEC §1 step 6).
//!
//! Slopes that face the low winter sun melt out. For each triangle containing a grid point — both
//! triangulations of the four quads around it (paper Fig. 9), 3 per quad, 12 in all — take the
//! compass azimuth of the horizontal projection of its normal (0 = north, 90 = east, 180 = south; in
//! our frame Z points south, so north = −Z) and θ = its angle to `sun_azimuth_deg`. If
//! |θ| ≤ θ1 (`sun_spread_deg`) the triangle's correction is `t·a + (1 − a)` with a = |θ|/θ1 (a
//! slope facing the sun straight on is bare, t → 1); otherwise it is the identity, t.
//!
//! Adaptations (SPEC §1 step 6): the paper's loop applies every triangle's correction in turn, which
//! compounds it up to 12 times; we apply the MEAN of the triangles' corrections once. Since each is
//! affine in t, that is `t ← t·A + (1 − A)` with A the mean of the triangles' a (1 outside ±θ1).
//! Triangles flatter than `sun_min_slope_deg` are skipped (their azimuth is noise); a point with no
//! steep-enough triangle is left unchanged, as are triangles with a nodata vertex. θ1 = 0 disables
//! the correction (a = |θ|/θ1 is undefined).
//!
//! The heights are the smoothed field of step 1 in metres, without vertical exaggeration, so that
//! `sun_min_slope_deg` is a real-world slope (exaggeration does not change azimuths).
//!
//! Implementation: rayon over bands of rows; each band walks the quad rows it touches once, computing
//! each quad's four triangle factors and summing them per corner; a point adds the corner sums of its
//! four quads in a fixed order, so results do not depend on the thread count. The angle uses a
//! branch-free polynomial `atan2` (error < 2·10⁻⁵ rad ≈ 0.001°) because the standard one dominated
//! the stage's time. The per-quad corner sums are kept as a struct of arrays (eight rows of
//! `f32`) so that both loops vectorise; the summation order is unchanged, so results are
//! bit-identical to the first version, which kept one 32-byte struct per quad (see BENCHMARKS.md).
//! Cost: 4 triangles per quad, ~60 flops each;
//! allocates per-band scratch.

use multiversion::multiversion;
use rayon::prelude::*;
use std::f32::consts::{FRAC_PI_2, PI};

/// Rows per rayon task.
const BAND_ROWS: usize = 32;

/// Sun-correction parameters (see [`crate::snow_terrain::descriptor::DescriptorParams`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sun {
    /// Compass azimuth of the sun, degrees (0 = north, 180 = south).
    pub azimuth_deg: f32,
    /// θ1, degrees in [0, 90].
    pub spread_deg: f32,
    /// Triangles flatter than this (degrees) are skipped.
    pub min_slope_deg: f32,
    /// k in [0, 1]: the applied factor is 1 − k·(1 − A) (issue 17's default 0.5; paper 1, where
    /// the factor is A itself, bit for bit).
    pub strength: f32,
}

/// Applies the sun correction to `t` in place. `heights` (metres, NaN = nodata) is the smoothed
/// `width × height` field; `dx`, `dy` the cell sizes east and south in metres. NaN in `t` stays NaN.
///
/// # Panics
/// If the grids' lengths differ from `width × height`.
pub fn apply_sun(
    t: &mut [f32],
    heights: &[f32],
    width: usize,
    height: usize,
    dx: f32,
    dy: f32,
    sun: Sun,
) {
    assert_eq!(heights.len(), width * height, "grid size mismatch");
    assert_eq!(t.len(), width * height, "grid size mismatch");
    if width == 0 || height == 0 || sun.spread_deg <= 0.0 {
        return;
    }
    let k = Kernel::new(sun);
    t.par_chunks_mut(width * BAND_ROWS)
        .enumerate()
        .for_each_init(Scratch::default, |s, (band, chunk)| {
            let r0 = band * BAND_ROWS;
            band_sun(&k, heights, width, height, dx, dy, r0, chunk, s);
        });
}

/// The mean factor A of every grid point (1 where no triangle counts); for tests and previews.
pub fn sun_factor(
    heights: &[f32],
    width: usize,
    height: usize,
    dx: f32,
    dy: f32,
    sun: Sun,
) -> Vec<f32> {
    // t = 0 gives t·A + (1 − A) = 1 − A.
    let mut t = vec![0.0f32; width * height];
    apply_sun(&mut t, heights, width, height, dx, dy, sun);
    t.iter().map(|v| 1.0 - v).collect()
}

struct Kernel {
    sin_az: f32,
    cos_az: f32,
    spread: f32,
    inv_spread: f32,
    min_tan2: f32,
    strength: f32,
}

impl Kernel {
    fn new(sun: Sun) -> Self {
        let az = sun.azimuth_deg.to_radians();
        let spread = sun.spread_deg.to_radians();
        let min_tan = sun.min_slope_deg.clamp(0.0, 89.9).to_radians().tan();
        Self {
            sin_az: az.sin(),
            cos_az: az.cos(),
            spread,
            inv_spread: 1.0 / spread,
            min_tan2: min_tan * min_tan,
            strength: sun.strength.clamp(0.0, 1.0),
        }
    }

    /// (a, 1) for a triangle with height gradient (gx east, gz south), (0, 0) if it does not count.
    #[inline]
    fn factor(&self, gx: f32, gz: f32) -> (f32, f32) {
        let slope2 = gx * gx + gz * gz;
        // Downslope (normal's horizontal projection) in compass components.
        let east = -gx;
        let north = gz;
        let u = east * self.sin_az + north * self.cos_az;
        let v = east * self.cos_az - north * self.sin_az;
        let theta = atan2_pos(v.abs(), u);
        let a = if theta <= self.spread {
            theta * self.inv_spread
        } else {
            1.0
        };
        // NaN (nodata vertex) fails this comparison too.
        if slope2 > self.min_tan2 && slope2 > 0.0 {
            (a, 1.0)
        } else {
            (0.0, 0.0)
        }
    }
}

/// Per quad of one quad row (index = the quad's west column; the last entry stays 0): the sums of
/// its triangles' factors `a` and counts `n` at each corner, NW, NE, SE, SW. Struct of arrays, so
/// that the per-quad loop vectorises.
#[derive(Default)]
struct Corners {
    a: [Vec<f32>; 4],
    n: [Vec<f32>; 4],
}

impl Corners {
    /// Sizes the rows for `w` grid columns: zeros when the size changes; otherwise the rows keep
    /// their values, all of which [`quad_row`] writes but the last entry, which stays 0 (only
    /// [`Self::zero`] and the resize write it).
    fn reset(&mut self, w: usize) {
        for v in self.a.iter_mut().chain(self.n.iter_mut()) {
            if v.len() != w {
                v.clear();
                v.resize(w, 0.0);
            }
        }
    }

    /// All sums 0 (a quad row outside the grid).
    fn zero(&mut self) {
        for v in self.a.iter_mut().chain(self.n.iter_mut()) {
            v.fill(0.0);
        }
    }
}

#[derive(Default)]
struct Scratch {
    above: Corners,
    below: Corners,
}

const NW: usize = 0;
const NE: usize = 1;
const SE: usize = 2;
const SW: usize = 3;

/// Corner sums of the quads in quad row `q` (rows q and q + 1), or zeros if `q` is outside.
/// Compiled for AVX2 too and chosen at run time (the same operations in wider registers, no
/// FMA: the same bits).
#[multiversion(targets("x86_64+avx2"))]
#[allow(clippy::too_many_arguments)]
fn quad_row(
    k: &Kernel,
    h: &[f32],
    w: usize,
    rows: usize,
    dx: f32,
    dy: f32,
    q: isize,
    out: &mut Corners,
) {
    out.reset(w);
    if q < 0 || q as usize + 1 >= rows || w < 2 {
        out.zero();
        return;
    }
    let q = q as usize;
    let m = w - 1;
    let (top, bot) = (&h[q * w..(q + 1) * w], &h[(q + 1) * w..(q + 2) * w]);
    let (nw_h, ne_h, sw_h, se_h) = (&top[..m], &top[1..], &bot[..m], &bot[1..]);
    let (idx, idy) = (1.0 / dx, 1.0 / dy);
    let [a_nw, a_ne, a_se, a_sw] = &mut out.a;
    let [n_nw, n_ne, n_se, n_sw] = &mut out.n;
    let (a_nw, a_ne, a_se, a_sw) = (
        &mut a_nw[..m],
        &mut a_ne[..m],
        &mut a_se[..m],
        &mut a_sw[..m],
    );
    let (n_nw, n_ne, n_se, n_sw) = (
        &mut n_nw[..m],
        &mut n_ne[..m],
        &mut n_se[..m],
        &mut n_sw[..m],
    );
    for c in 0..m {
        let (nw, ne, sw, se) = (nw_h[c], ne_h[c], sw_h[c], se_h[c]);
        // Diagonal NW–SE: T1 = (NW, NE, SE), T2 = (NW, SE, SW).
        let t1 = k.factor((ne - nw) * idx, (se - ne) * idy);
        let t2 = k.factor((se - sw) * idx, (sw - nw) * idy);
        // Diagonal NE–SW: T3 = (NW, NE, SW), T4 = (NE, SE, SW).
        let t3 = k.factor((ne - nw) * idx, (sw - nw) * idy);
        let t4 = k.factor((se - sw) * idx, (se - ne) * idy);
        a_nw[c] = t1.0 + t2.0 + t3.0; // NW in T1, T2, T3
        a_ne[c] = t1.0 + t3.0 + t4.0; // NE in T1, T3, T4
        a_se[c] = t1.0 + t2.0 + t4.0; // SE in T1, T2, T4
        a_sw[c] = t2.0 + t3.0 + t4.0; // SW in T2, T3, T4
        n_nw[c] = t1.1 + t2.1 + t3.1;
        n_ne[c] = t1.1 + t3.1 + t4.1;
        n_se[c] = t1.1 + t2.1 + t4.1;
        n_sw[c] = t2.1 + t3.1 + t4.1;
    }
}

#[allow(clippy::too_many_arguments)]
fn band_sun(
    k: &Kernel,
    h: &[f32],
    w: usize,
    rows: usize,
    dx: f32,
    dy: f32,
    r0: usize,
    t: &mut [f32],
    s: &mut Scratch,
) {
    quad_row(k, h, w, rows, dx, dy, r0 as isize - 1, &mut s.above);
    for (i, trow) in t.chunks_mut(w).enumerate() {
        let r = r0 + i;
        if i > 0 {
            std::mem::swap(&mut s.above, &mut s.below);
        }
        quad_row(k, h, w, rows, dx, dy, r as isize, &mut s.below);
        let (up, dn) = (&s.above, &s.below);
        // The four quads around (r, c) and the point's corner in each, in a fixed order: the
        // north-west quad's SE corner, the north-east quad's SW, the south-west quad's NE, the
        // south-east quad's NW (the western quads are missing in column 0).
        let strength = k.strength;
        let apply = |tv: &mut f32, sa: f32, sn: f32| {
            if sn > 0.0 && !tv.is_nan() {
                let mut a = sa / sn;
                if strength != 1.0 {
                    a = 1.0 - strength * (1.0 - a);
                }
                *tv = *tv * a + (1.0 - a);
            }
        };
        let Some((t0, rest)) = trow.split_first_mut() else {
            continue;
        };
        apply(
            t0,
            0.0 + up.a[SW][0] + dn.a[NW][0],
            0.0 + up.n[SW][0] + dn.n[NW][0],
        );
        let m = rest.len();
        let (ua_se, ua_sw, da_ne, da_nw) = (
            &up.a[SE][..m],
            &up.a[SW][1..=m],
            &dn.a[NE][..m],
            &dn.a[NW][1..=m],
        );
        let (un_se, un_sw, dn_ne, dn_nw) = (
            &up.n[SE][..m],
            &up.n[SW][1..=m],
            &dn.n[NE][..m],
            &dn.n[NW][1..=m],
        );
        for (c, tv) in rest.iter_mut().enumerate() {
            let sa = 0.0 + ua_se[c] + ua_sw[c] + da_ne[c] + da_nw[c];
            let sn = 0.0 + un_se[c] + un_sw[c] + dn_ne[c] + dn_nw[c];
            apply(tv, sa, sn);
        }
    }
}

/// atan2(y, x) for y ≥ 0, in [0, π]; polynomial, error < 2·10⁻⁵ rad; (0, 0) gives 0.
#[inline]
fn atan2_pos(y: f32, x: f32) -> f32 {
    let ax = x.abs();
    let swap = y > ax;
    let (num, den) = if swap { (ax, y) } else { (y, ax) };
    let z = if den > 0.0 { num / den } else { 0.0 };
    let z2 = z * z;
    let p = z
        * (0.999_977_26
            + z2 * (-0.332_623_47
                + z2 * (0.193_543_46
                    + z2 * (-0.116_432_87 + z2 * (0.052_653_32 - 0.011_721_2 * z2)))));
    let a = if swap { FRAC_PI_2 - p } else { p };
    if x < 0.0 {
        PI - a
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SUN: Sun = Sun {
        azimuth_deg: 180.0,
        spread_deg: 60.0,
        min_slope_deg: 5.0,
        strength: 1.0,
    };

    /// A plane descending toward compass azimuth `az` with slope `slope` (m/m).
    fn plane(w: usize, h: usize, d: f32, az_deg: f32, slope: f32) -> Vec<f32> {
        let az = az_deg.to_radians();
        let (east, north) = (az.sin(), az.cos());
        let mut v = Vec::new();
        for r in 0..h {
            for c in 0..w {
                let x = c as f32 * d;
                let n = -(r as f32) * d; // north coordinate
                v.push(1000.0 - slope * (x * east + n * north));
            }
        }
        v
    }

    #[test]
    fn polynomial_atan2_is_accurate() {
        for i in 0..=200 {
            for j in -100..=100 {
                let (y, x) = (i as f32 * 0.37, j as f32 * 0.53);
                let e = (atan2_pos(y, x) - y.atan2(x)).abs();
                assert!(e < 2e-5, "({y},{x}): {e}");
            }
        }
        assert_eq!(atan2_pos(0.0, 0.0), 0.0);
    }

    #[test]
    fn south_facing_slope_is_bare() {
        let (w, h) = (8, 8);
        let f = plane(w, h, 10.0, 180.0, 0.5);
        let mut t = vec![0.0f32; w * h];
        apply_sun(&mut t, &f, w, h, 10.0, 10.0, SUN);
        for v in &t {
            assert!((v - 1.0).abs() < 1e-4, "{v}");
        }
    }

    #[test]
    fn north_facing_and_outside_spread_untouched() {
        let (w, h) = (8, 8);
        for az in [0.0f32, 60.0, 110.0, 250.0, 300.0] {
            let f = plane(w, h, 10.0, az, 0.5);
            let mut t = vec![0.3f32; w * h];
            apply_sun(&mut t, &f, w, h, 10.0, 10.0, SUN);
            assert!(t.iter().all(|&v| v == 0.3), "az {az}");
        }
    }

    #[test]
    fn symmetric_about_the_sun_azimuth() {
        let (w, h) = (8, 8);
        for (sun_az, off) in [
            (180.0f32, 20.0f32),
            (180.0, 45.0),
            (90.0, 30.0),
            (0.0, 10.0),
        ] {
            let sun = Sun {
                azimuth_deg: sun_az,
                ..SUN
            };
            let a = sun_factor(&plane(w, h, 10.0, sun_az + off, 0.4), w, h, 10.0, 10.0, sun);
            let b = sun_factor(&plane(w, h, 10.0, sun_az - off, 0.4), w, h, 10.0, 10.0, sun);
            let expect = off / 60.0;
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() < 1e-4, "sun {sun_az} off {off}: {x} vs {y}");
                assert!((x - expect).abs() < 1e-3, "{x} vs {expect}");
            }
        }
    }

    #[test]
    fn flat_ground_and_gentle_slopes_are_skipped() {
        let (w, h) = (6, 5);
        let flat = vec![100.0f32; w * h];
        let gentle = plane(w, h, 10.0, 180.0, 0.05); // 2.9°
        for f in [flat, gentle] {
            let mut t = vec![0.2f32; w * h];
            apply_sun(&mut t, &f, w, h, 10.0, 10.0, SUN);
            assert!(t.iter().all(|&v| v == 0.2));
        }
    }

    #[test]
    fn nodata_stays_nan_and_neighbours_use_remaining_triangles() {
        let (w, h) = (6, 6);
        let mut f = plane(w, h, 10.0, 180.0, 0.5);
        f[2 * w + 2] = f32::NAN;
        let mut t = vec![0.0f32; w * h];
        t[2 * w + 2] = f32::NAN;
        apply_sun(&mut t, &f, w, h, 10.0, 10.0, SUN);
        assert!(t[2 * w + 2].is_nan());
        assert!((t[2 * w + 3] - 1.0).abs() < 1e-4);
    }
}
