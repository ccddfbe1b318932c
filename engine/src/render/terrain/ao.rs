//! Ambient occlusion of the terrain's sky light from the height field: the **sky-view factor**
//! of Zakšek, Oštir and Kokalj ("Sky-View Factor as a Relief Visualization Technique", Remote
//! Sensing 3(2), 2011, 398–415), the horizon-based estimate of how much of the sky a point sees
//! (in the spirit of Bavoil, Sainz and Dimitrov's horizon-based AO, SIGGRAPH 2008 talk, but on the
//! DEM grid instead of a depth buffer, so it is computed once per DEM and view-independent).
//!
//! **What is computed.** At each grid point, in `n = 8` azimuths (the grid axes and diagonals, so
//! every sample is a grid point: no interpolation), the horizon elevation angle γ is the largest
//! `atan(Δh / distance)` over samples at distances `1, 2, 3, 4, 6, 8, 11, 16, 23, …` cells (≈ √2
//! apart) up to the search `radius`, and not below the tangent plane's elevation τ in that
//! azimuth (from the central-difference gradient). As in horizon-based AO, a direction occludes
//! by `sin γ − sin τ`, the part of the sky above the tangent plane that the horizon hides, and
//! the factor is `1 − (1/n) Σ (sin γ − sin τ)`: 1 on any plane, peak or ridge (the shader's own
//! `(1 + n_y)/2` term already accounts for a slope facing part of the ground), ≈ 0.65 at the
//! floor of a valley with 20° horizons all round. On flat ground (τ = 0) this is Zakšek et al.'s
//! sky-view factor `1 − (1/n) Σ sin γ`. Samples beyond the grid end a direction; nodata samples
//! are skipped. The geometric distance sequence reaches far horizons (whole valleys) with ~12
//! samples per direction, where unit steps would need the radius in cells.
//!
//! **Big grids.** Above [`MAX_POINTS`] grid points the heights are first box-averaged over
//! `stride × stride` blocks (the smallest stride that brings the grid under the limit) and the SVF
//! is computed on that coarser grid; the shader interpolates it bilinearly at the hit's position
//! ([`AoMap::at`]). The SVF is a broad, smooth quantity at the search radii used here (a tenth of
//! the DEM's extent), so a 4096² DEM loses nothing visible at 1080p, and the cost stays
//! ~`MAX_POINTS × 8 × 12` lookups whatever the DEM size (measured in BENCHMARKS.md).
//!
//! Stored as one byte per (coarse) point, `round(255 · SVF)`: 1/255 steps of the sky light are far
//! below what shows, and 4096² would otherwise take 67 MB of floats. Deterministic and independent
//! of the thread count (each point is computed alone).

use multiversion::multiversion;
use rayon::prelude::*;

use crate::control::{Canceled, Control};

/// Largest grid the SVF is computed on directly; bigger grids are box-averaged first.
pub const MAX_POINTS: usize = 1 << 17;

/// The eight azimuths (column step, row step).
const DIRS: [(isize, isize); 8] = [
    (1, 0),
    (1, 1),
    (0, 1),
    (-1, 1),
    (-1, 0),
    (-1, -1),
    (0, -1),
    (1, -1),
];

/// Sample distances in cells along a direction (≈ √2 apart), cut at the search radius.
const STEPS: [usize; 20] = [
    1, 2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, 90, 128, 181, 256, 362, 512, 724, 1024,
];

/// The sky-view factor of a terrain, on the grid or a box-averaged coarser one.
#[derive(Debug, Clone)]
pub struct AoMap {
    /// Grid points per coarse point along each axis (1 = the terrain's own grid).
    pub stride: usize,
    /// Coarse grid size.
    pub width: usize,
    pub height: usize,
    /// `round(255 · SVF)` per coarse point, row-major (255 for nodata).
    pub data: Vec<u8>,
}

impl AoMap {
    /// The SVF (0–1) at grid position (`col + fx`, `row + fz`) of the terrain's grid, bilinear
    /// on the coarse grid (coarse point `i` sits at the centre of its block).
    #[inline]
    pub fn at(&self, col: usize, row: usize, fx: f32, fz: f32) -> f32 {
        let w = self.width;
        if self.stride == 1 {
            let k = row * w + col;
            let v = |i: usize| f32::from(self.data[i]);
            let (c1, r1) = (
                usize::from(col + 1 < w),
                if row + 1 < self.height { w } else { 0 },
            );
            return ((1.0 - fx) * (1.0 - fz) * v(k)
                + fx * (1.0 - fz) * v(k + c1)
                + (1.0 - fx) * fz * v(k + r1)
                + fx * fz * v(k + r1 + c1))
                * (1.0 / 255.0);
        }
        let s = self.stride as f32;
        let u = ((col as f32 + fx + 0.5) / s - 0.5).clamp(0.0, (w - 1) as f32);
        let v = ((row as f32 + fz + 0.5) / s - 0.5).clamp(0.0, (self.height - 1) as f32);
        let (i, j) = (u as usize, v as usize);
        let (i1, j1) = ((i + 1).min(w - 1), (j + 1).min(self.height - 1));
        let (a, b) = (u - i as f32, v - j as f32);
        let d = |i: usize, j: usize| f32::from(self.data[j * w + i]);
        ((1.0 - a) * (1.0 - b) * d(i, j)
            + a * (1.0 - b) * d(i1, j)
            + (1.0 - a) * b * d(i, j1)
            + a * b * d(i1, j1))
            * (1.0 / 255.0)
    }
}

/// The sky-view factor of the `width × height` grid `heights` (world units; NaN = nodata) with
/// cell sizes `dx`, `dy` (world units) and search `radius` (world units). Parallel over rows,
/// `checkpoint` per row band; allocates the map (and the coarse heights for big grids).
pub fn sky_view_factor(
    heights: &[f32],
    width: usize,
    height: usize,
    dx: f64,
    dy: f64,
    radius: f64,
    ctl: &dyn Control,
) -> Result<AoMap, Canceled> {
    let n = width * height;
    let stride = if n > MAX_POINTS {
        ((n as f64 / MAX_POINTS as f64).sqrt().ceil() as usize).max(2)
    } else {
        1
    };
    let coarse;
    let (w, h, hs) = if stride == 1 {
        (width, height, heights)
    } else {
        let (w, h) = (width.div_ceil(stride), height.div_ceil(stride));
        let mut c = vec![f32::NAN; w * h];
        c.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
            for (i, v) in row.iter_mut().enumerate() {
                let (mut sum, mut k) = (0.0f64, 0u32);
                for r in j * stride..((j + 1) * stride).min(height) {
                    for &x in
                        &heights[r * width + i * stride..r * width + ((i + 1) * stride).min(width)]
                    {
                        if !x.is_nan() {
                            sum += f64::from(x);
                            k += 1;
                        }
                    }
                }
                if k > 0 {
                    *v = (sum / f64::from(k)) as f32;
                }
            }
        });
        coarse = c;
        (w, h, coarse.as_slice())
    };
    let (cdx, cdy) = (dx * stride as f64, dy * stride as f64);
    // Per direction: the horizontal length of one step and the number of steps within the radius.
    let dirs: Vec<(isize, isize, f64, usize)> = DIRS
        .iter()
        .map(|&(di, dj)| {
            let len = ((di as f64 * cdx).powi(2) + (dj as f64 * cdy).powi(2)).sqrt();
            let n = STEPS
                .iter()
                .take_while(|&&k| k as f64 * len <= radius)
                .count()
                .max(1);
            (di, dj, len, n)
        })
        .collect();
    let mut data = vec![255u8; w * h];
    // Row by row, direction by direction and step by step: for one (direction, step) the samples
    // of a row's points are one contiguous run of a single row of the grid, so the inner loop is
    // a plain loop over slices that the compiler vectorises. Each point's order of
    // accumulation over the directions is the per-point loop's. The horizon search runs in
    // `f32` (the heights' own precision; twice the lanes of `f64`): a horizon's tangent moves
    // by ~10⁻⁷ relative, below the byte's 1/255 step but for the rare value on a rounding
    // edge; the tangent plane's and the sines' arithmetic stays `f64`, and a direction with no
    // sample above the tangent plane adds exactly 0 as before. A
    // direction's march ends at its first sample off the grid, and the points for which a step
    // stays on the grid are a range that only shrinks as the step grows. Scratch: four `f64`
    // and two `f32` rows per rayon task (`try_for_each_init`), nothing per row.
    let g = Grid { hs, w, h, cdx, cdy };
    data.par_chunks_mut(w.max(1))
        .enumerate()
        .try_for_each_init(
            || (vec![0.0f64; 4 * w], vec![0.0f32; 2 * w]),
            |(scratch, scratch32), (j, row)| {
                if j % 16 == 0 {
                    ctl.checkpoint()?;
                }
                svf_row(&g, &dirs, j, row, scratch, scratch32);
                Ok(())
            },
        )?;
    Ok(AoMap {
        stride,
        width: w,
        height: h,
        data,
    })
}

/// The (coarse) grid the SVF is computed on.
struct Grid<'a> {
    hs: &'a [f32],
    w: usize,
    h: usize,
    /// Cell sizes, world units.
    cdx: f64,
    cdy: f64,
}

/// One-sided or central difference (the gradient rule of the module doc): `c` the point's
/// height, `lo`/`hi` its neighbours (`None` off the grid, NaN = nodata), `step` the spacing.
#[inline]
fn diff(c: f64, lo: Option<f64>, hi: Option<f64>, step: f64) -> f64 {
    match (lo.filter(|v| !v.is_nan()), hi.filter(|v| !v.is_nan())) {
        (Some(a), Some(b)) => (b - a) / (2.0 * step),
        (Some(a), None) => (c - a) / step,
        (None, Some(b)) => (b - c) / step,
        (None, None) => 0.0,
    }
}

/// Row `j` of the map into `row` (see `sky_view_factor`); `scratch` holds four `f64` rows and
/// `scratch32` two `f32` rows of the grid's width. Compiled for AVX2 too and chosen at run time
/// (the same floating-point operations in wider registers, no FMA: the same bits).
#[multiversion(targets("x86_64+avx2"))]
fn svf_row<'a>(
    g: &Grid<'a>,
    dirs: &[(isize, isize, f64, usize)],
    j: usize,
    row: &mut [u8],
    scratch: &mut [f64],
    scratch32: &mut [f32],
) {
    let Grid { hs, w, h, cdx, cdy } = *g;
    let (gx, rest) = scratch.split_at_mut(w);
    let (gz, rest) = rest.split_at_mut(w);
    let (tan, sum_sin) = rest.split_at_mut(w);
    let (best, tan32) = scratch32.split_at_mut(w);
    let h_row = &hs[j * w..(j + 1) * w];
    // Central-difference gradient (one-sided at borders and next to nodata): interior points
    // straight from the three rows; a NaN neighbour makes the difference NaN, and those points
    // (and the borders) take `diff`.
    let at = |ci: usize, cj: usize| f64::from(hs[cj * w + ci]);
    let interior = j > 0 && j + 1 < h && w >= 3;
    if interior {
        let (up, dn) = (
            &hs[(j - 1) * w + 1..j * w - 1],
            &hs[(j + 1) * w + 1..(j + 2) * w - 1],
        );
        for ((((gx, gz), (&a, &b)), &u), &d) in gx[1..w - 1]
            .iter_mut()
            .zip(gz[1..w - 1].iter_mut())
            .zip(h_row[..w - 2].iter().zip(&h_row[2..]))
            .zip(up)
            .zip(dn)
        {
            *gx = (f64::from(b) - f64::from(a)) / (2.0 * cdx);
            *gz = (f64::from(d) - f64::from(u)) / (2.0 * cdy);
        }
    }
    for i in 0..w {
        if interior && i > 0 && i + 1 < w && !gx[i].is_nan() && !gz[i].is_nan() {
            continue;
        }
        let c = f64::from(h_row[i]);
        gx[i] = diff(
            c,
            (i > 0).then(|| at(i - 1, j)),
            (i + 1 < w).then(|| at(i + 1, j)),
            cdx,
        );
        gz[i] = diff(
            c,
            (j > 0).then(|| at(i, j - 1)),
            (j + 1 < h).then(|| at(i, j + 1)),
            cdy,
        );
    }
    sum_sin.fill(0.0);
    let sin = |t: f64| t / (1.0 + t * t).sqrt();
    for &(di, dj, len, steps) in dirs {
        // tan τ of the tangent plane along this azimuth.
        for (((t, t32), b), (&gx, &gz)) in tan
            .iter_mut()
            .zip(tan32.iter_mut())
            .zip(best.iter_mut())
            .zip(gx.iter().zip(gz.iter()))
        {
            *t = (gx * di as f64 * cdx + gz * dj as f64 * cdy) / len;
            *t32 = *t as f32;
            *b = *t32;
        }
        for &k in &STEPS[..steps] {
            let cj = j as isize + dj * k as isize;
            if cj < 0 || cj >= h as isize {
                break;
            }
            // Points i with 0 ≤ i + di·k < w.
            let off = di * k as isize;
            let (i0, i1) = (
                (-off).clamp(0, w as isize) as usize,
                (w as isize - off).clamp(0, w as isize) as usize,
            );
            if i0 >= i1 {
                break;
            }
            let src = &hs[cj as usize * w..(cj as usize + 1) * w];
            let src = &src[(i0 as isize + off) as usize..(i1 as isize + off) as usize];
            let dist = (k as f64 * len) as f32;
            for ((b, &h0), &hk) in best[i0..i1].iter_mut().zip(&h_row[i0..i1]).zip(src) {
                let t = (hk - h0) / dist;
                // NaN (nodata) fails the compare. A select, not a branch, so that the loop
                // vectorises (the branch's conditional store kept it scalar).
                *b = if t > *b { t } else { *b };
            }
        }
        for (((acc, &b), &t32), &t) in sum_sin
            .iter_mut()
            .zip(best.iter())
            .zip(tan32.iter())
            .zip(tan.iter())
        {
            // Unoccluded (no sample above the tangent plane): nothing, as a select of 0 so
            // that the loop vectorises (`acc + 0.0` is `acc` up to the sign of a zero sum,
            // which the factor below does not see).
            let occluded = sin(f64::from(b)) - sin(t);
            *acc += if b > t32 { occluded } else { 0.0 };
        }
    }
    for ((out, &h0), &s) in row.iter_mut().zip(h_row).zip(sum_sin.iter()) {
        if !h0.is_nan() {
            let svf = 1.0 - s / DIRS.len() as f64;
            *out = (255.0 * svf.clamp(0.0, 1.0)).round() as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::NoControl;

    /// A plane, flat or tilted: every horizon is the tangent plane itself, nothing occludes.
    #[test]
    fn a_plane_is_not_occluded() {
        let (w, h) = (40, 30);
        for (a, b) in [(0.0f32, 0.0f32), (3.0, 0.5), (-1.0, 2.0)] {
            let hs: Vec<f32> = (0..w * h)
                .map(|k| a * (k % w) as f32 + b * (k / w) as f32)
                .collect();
            let m = sky_view_factor(&hs, w, h, 10.0, 10.0, 200.0, &NoControl).unwrap();
            assert!(m.data.iter().all(|&v| v == 255), "plane {a} {b}");
        }
    }

    /// The floor of a V-shaped valley along the columns, walls at 45°: the tangent plane is flat
    /// (central differences), the two cross-valley azimuths see γ = 45°, the four diagonals rise
    /// one cell's height per √2 cells (tan γ = 1/√2), along the valley γ = 0:
    /// SVF = 1 − (2·sin 45° + 4·sin(atan(1/√2))) / 8.
    #[test]
    fn valley_floor_matches_the_analytic_horizons() {
        let (w, h) = (101, 21);
        let hs: Vec<f32> = (0..w * h)
            .map(|k| 10.0 * ((k % w) as f32 - 50.0).abs())
            .collect();
        let m = sky_view_factor(&hs, w, h, 10.0, 10.0, 300.0, &NoControl).unwrap();
        let g_diag = (1.0f64 / 2f64.sqrt()).atan();
        let want = 1.0 - (2.0 * 45f64.to_radians().sin() + 4.0 * g_diag.sin()) / 8.0;
        let got = f64::from(m.data[10 * w + 50]) / 255.0;
        assert!((got - want).abs() < 1.0 / 255.0, "{got} vs {want}");
    }

    /// Big grids are box-averaged: the coarse map still finds the valley.
    #[test]
    fn big_grids_use_a_coarse_map() {
        let (w, h) = (1100, 600);
        let hs: Vec<f32> = (0..w * h)
            .map(|k| 2.0 * ((k % w) as f32 - 550.0).abs())
            .collect();
        let m = sky_view_factor(&hs, w, h, 1.0, 1.0, 100.0, &NoControl).unwrap();
        assert!(m.stride >= 2 && m.width * m.height <= MAX_POINTS);
        let floor = m.at(550, 300, 0.0, 0.0);
        let slope = m.at(100, 300, 0.0, 0.0);
        assert!(floor < 0.7 && slope > 0.95, "{floor} {slope}");
    }
}
