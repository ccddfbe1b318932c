//! Altitude (paper §3.4.1 and §4.1 line 7; SPEC §1 step 4, which overrides the paper here).
//!
//! The paper multiplies t by a quadratic in elevation that is 1 at the highest point and 0 at
//! elevation 0. Since t = 1 is bare rock, that literal form would bare the summits and cover the
//! lowlands, against the paper's own intent (higher = colder = more snow). SPEC §1 settles it: the
//! *snow* s = 1 − t is multiplied by
//!
//! ```text
//! a(h) = clamp((h − snowline) / (h_max − snowline), 0, 1) ^ altitude_exponent
//! ```
//!
//! and t = 1 − s. With the `paper` preset (snowline 0 m, exponent 2) this is the paper's quadratic.
//!
//! **The transition band (the default).** The paper's ramp runs from the snowline to the highest
//! point, so on a real DEM only the last few hundred metres below the summit get much snow. The
//! default look (issue 17, "winter on any DEM") ramps over a band instead:
//!
//! ```text
//! a(h) = clamp((h − z₀) / (z₁ − z₀), 0, 1) ^ altitude_exponent
//! ```
//!
//! with z₀ the snowline and z₁ the elevation above which the full snow lies. Both come from the
//! DEM's own elevation distribution when not given ([`elevation_quantiles`]): z₀ = the
//! `snowline_quantile` (0.3) and z₁ = the `full_snow_quantile` (0.7) of the land cells. The
//! paper's form is the special case z₁ = h_max (`full_snow_quantile` = 1).
//!
//! **Sea.** Cells at or below `sea_level` (default 0 m) hold no snow and are left out of the
//! quantiles, so that bathymetry neither gets snow nor pulls the snowline down.
//!
//! **Which height.** h is the ORIGINAL elevation in metres (not smoothed, not exaggerated), and h_max
//! is the highest valid cell of the original DEM: the snowline is a real-world elevation a user reads
//! off a map, and smoothing would lower the peaks below it and raise the valleys. The term varies
//! slowly, and step 5 smooths t afterwards, so the small-scale roughness this lets in is invisible.
//! If no cell rises above the snowline, a = 0 everywhere (no snow).

use rayon::prelude::*;

/// Highest valid value of `heights`, `None` if all are nodata. Parallel; the maximum does not
/// depend on the order, so neither does the result.
pub fn max_height(heights: &[f32]) -> Option<f32> {
    heights
        .par_chunks(1 << 16)
        .filter_map(|c| c.iter().copied().filter(|h| !h.is_nan()).reduce(f32::max))
        .reduce_with(f32::max)
}

/// Elevations at the quantiles `qs` (each in [0, 1]) of the valid cells above `floor` (all
/// valid cells when `None`), `None` when no cell counts. Quantile 0 is the lowest such cell and
/// 1 the highest, exactly. In between, from a 4096-bin histogram over [min, max] with linear
/// interpolation inside the bin: within (max − min)/4096 of the exact order statistic (≈ 1 m on
/// a 4 km relief), in two parallel passes and O(bins) memory per thread, where a sort of a
/// 4096² DEM would take most of a second. Integer counts: independent of the thread count.
pub fn elevation_quantiles(heights: &[f32], floor: Option<f32>, qs: &[f64]) -> Option<Vec<f32>> {
    const BINS: usize = 4096;
    let keep = |h: f32| !h.is_nan() && floor.is_none_or(|f| h > f);
    let (lo, hi, n) = heights
        .par_chunks(1 << 16)
        .map(|c| {
            c.iter().filter(|&&h| keep(h)).fold(
                (f32::INFINITY, f32::NEG_INFINITY, 0usize),
                |(a, b, n), &h| (a.min(h), b.max(h), n + 1),
            )
        })
        .reduce(
            || (f32::INFINITY, f32::NEG_INFINITY, 0),
            |x, y| (x.0.min(y.0), x.1.max(y.1), x.2 + y.2),
        );
    if n == 0 {
        return None;
    }
    let span = f64::from(hi) - f64::from(lo);
    if span <= 0.0 {
        return Some(qs.iter().map(|_| lo).collect());
    }
    let scale = BINS as f64 / span;
    let bin = |h: f32| (((f64::from(h) - f64::from(lo)) * scale) as usize).min(BINS - 1);
    let hist = heights
        .par_chunks(1 << 16)
        .fold(
            || vec![0u64; BINS],
            |mut acc, c| {
                for &h in c.iter().filter(|&&h| keep(h)) {
                    acc[bin(h)] += 1;
                }
                acc
            },
        )
        .reduce(
            || vec![0u64; BINS],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    let out = qs
        .iter()
        .map(|&q| {
            let q = q.clamp(0.0, 1.0);
            if q <= 0.0 {
                return lo;
            }
            if q >= 1.0 {
                return hi;
            }
            // Rank of the quantile among n cells, then the bin holding it.
            let rank = q * (n - 1) as f64;
            let mut below = 0u64;
            for (k, &c) in hist.iter().enumerate() {
                if c > 0 && (below + c) as f64 > rank {
                    let f = ((rank - below as f64) + 0.5) / c as f64;
                    let v = f64::from(lo) + (k as f64 + f.clamp(0.0, 1.0)) / scale;
                    return (v as f32).clamp(lo, hi);
                }
                below += c;
            }
            hi
        })
        .collect();
    Some(out)
}

/// Mean snow per elevation decile of the valid cells: ten `(lowest elevation, highest
/// elevation, cells, mean snow)` rows, lowest decile first, `None` for a decile that holds no
/// cell (ties: a flat sea at 0 m fills one decile, not three). Decile edges from
/// [`elevation_quantiles`]; a cell at an edge belongs to the decile below it. For the report
/// and the tests of issue 17 ("mean snow rises with elevation").
pub fn snow_by_elevation_decile(heights: &[f32], snow: &[f32]) -> Vec<Option<DecileStat>> {
    let qs: Vec<f64> = (1..10).map(|k| f64::from(k) / 10.0).collect();
    let Some(edges) = elevation_quantiles(heights, None, &qs) else {
        return vec![None; 10];
    };
    let acc = heights
        .par_chunks(1 << 16)
        .zip(snow.par_chunks(1 << 16))
        .map(|(h, s)| {
            let mut a = [(f32::INFINITY, f32::NEG_INFINITY, 0usize, 0.0f64); 10];
            for (&h, &s) in h.iter().zip(s) {
                if h.is_nan() || s.is_nan() {
                    continue;
                }
                let k = edges.partition_point(|&e| e < h);
                let d = &mut a[k];
                *d = (d.0.min(h), d.1.max(h), d.2 + 1, d.3 + f64::from(s));
            }
            a
        })
        .collect::<Vec<_>>();
    (0..10)
        .map(|k| {
            let (lo, hi, n, sum) = acc.iter().fold(
                (f32::INFINITY, f32::NEG_INFINITY, 0usize, 0.0f64),
                |t, a| (t.0.min(a[k].0), t.1.max(a[k].1), t.2 + a[k].2, t.3 + a[k].3),
            );
            (n > 0).then(|| DecileStat {
                elevation_min: lo,
                elevation_max: hi,
                cells: n,
                mean_snow: sum / n as f64,
            })
        })
        .collect()
}

/// One row of [`snow_by_elevation_decile`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct DecileStat {
    /// Lowest and highest elevation in the decile, metres.
    pub elevation_min: f32,
    pub elevation_max: f32,
    /// Valid cells in the decile.
    pub cells: usize,
    /// Mean snow s = 1 − t over them.
    pub mean_snow: f64,
}

/// a(h) above, in [0, 1]. `h_max` is the highest elevation (metres); `exponent` > 0.
#[inline]
pub fn altitude_factor(h: f32, snowline: f32, h_max: f32, exponent: f32) -> f32 {
    let span = h_max - snowline;
    if span <= 0.0 || h.is_nan() {
        return 0.0;
    }
    let x = ((h - snowline) / span).clamp(0.0, 1.0);
    if exponent == 2.0 {
        x * x
    } else if exponent == 1.0 {
        x
    } else {
        x.powf(exponent)
    }
}

/// Applies the altitude term in place: `t ← 1 − (1 − t) · a(h)` with `heights` the original
/// elevations (same grid as `t`). NaN in `t` stays NaN.
///
/// # Panics
/// If the grids differ in length.
pub fn apply_altitude(t: &mut [f32], heights: &[f32], snowline: f32, exponent: f32) {
    assert_eq!(t.len(), heights.len(), "grid size mismatch");
    let Some(h_max) = max_height(heights) else {
        return;
    };
    t.par_iter_mut()
        .zip(heights.par_iter())
        .for_each(|(t, &h)| *t = altitude(*t, h, snowline, h_max, exponent));
}

/// The altitude term for one cell: `1 − (1 − t) · a(h)`, NaN for NaN `t`. `h_max` from
/// [`max_height`]. Used by [`apply_altitude`] and by the descriptor's fused transfer pass.
#[inline]
pub fn altitude(t: f32, h: f32, snowline: f32, h_max: f32, exponent: f32) -> f32 {
    if t.is_nan() {
        t
    } else {
        let s = (1.0 - t) * altitude_factor(h, snowline, h_max, exponent);
        1.0 - s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn more_snow_higher_up() {
        let heights: Vec<f32> = (0..=10).map(|k| k as f32 * 100.0).collect();
        let mut t = vec![0.0f32; heights.len()]; // fully snow-covered before the altitude term
        apply_altitude(&mut t, &heights, 0.0, 2.0);
        for k in 1..t.len() {
            assert!(t[k] < t[k - 1], "snow must grow with height");
        }
        assert_eq!(t[10], 0.0); // highest point keeps all its snow
        assert_eq!(t[0], 1.0); // elevation 0: bare
        assert!((t[5] - 0.75).abs() < 1e-6); // quadratic: s = 0.5² at mid height
    }

    #[test]
    fn snowline_and_bare_rock() {
        let heights = vec![500.0, 1000.0, 1500.0, 2000.0, f32::NAN];
        let mut t = vec![0.2, 0.2, 0.2, 0.2, f32::NAN];
        apply_altitude(&mut t, &heights, 1000.0, 1.0);
        assert_eq!(t[0], 1.0);
        assert_eq!(t[1], 1.0);
        assert!((t[2] - (1.0 - 0.8 * 0.5)).abs() < 1e-6);
        assert!((t[3] - 0.2).abs() < 1e-6);
        assert!(t[4].is_nan());
        // Bare rock stays bare whatever the height.
        let mut t = vec![1.0; 4];
        apply_altitude(&mut t, &heights[..4], 0.0, 2.0);
        assert!(t.iter().all(|&v| v == 1.0));
        // Snowline above everything: no snow.
        let mut t = vec![0.0; 4];
        apply_altitude(&mut t, &heights[..4], 3000.0, 2.0);
        assert!(t.iter().all(|&v| v == 1.0));
    }

    #[test]
    fn quantiles_match_the_order_statistics() {
        // 0, 1, …, 9999 m shuffled by a stride, with nodata and "sea" cells.
        let mut h: Vec<f32> = (0..10_000).map(|k| ((k * 7919) % 10_000) as f32).collect();
        h.extend([f32::NAN, -5.0, -300.0]);
        let q = elevation_quantiles(&h, Some(0.0), &[0.0, 0.1, 0.3, 0.5, 0.7, 1.0]).unwrap();
        // Floor 0 excludes the cells at and below 0 m: 1 … 9999.
        assert_eq!(q[0], 1.0);
        assert_eq!(q[5], 9999.0);
        for (got, want) in q[1..5].iter().zip([1000.8, 3000.4, 5000.0, 6999.6]) {
            assert!(
                (got - want).abs() <= 9999.0 / 4096.0 + 1e-3,
                "{got} vs {want}"
            );
        }
        let all = elevation_quantiles(&h, None, &[0.0]).unwrap();
        assert_eq!(all[0], -300.0);
        assert!(elevation_quantiles(&[f32::NAN, -1.0], Some(0.0), &[0.5]).is_none());
        assert_eq!(
            elevation_quantiles(&[7.0; 5], None, &[0.2, 0.9]).unwrap(),
            vec![7.0, 7.0]
        );
    }

    #[test]
    fn deciles_sort_cells_by_elevation() {
        let h: Vec<f32> = (0..1000).map(|k| k as f32).collect();
        let s: Vec<f32> = (0..1000).map(|k| if k < 500 { 0.0 } else { 1.0 }).collect();
        let d = snow_by_elevation_decile(&h, &s);
        for (k, row) in d.iter().enumerate() {
            let row = row.unwrap();
            assert!((row.cells as i64 - 100).abs() <= 1, "{k}: {row:?}");
            assert_eq!(row.mean_snow, if k < 5 { 0.0 } else { 1.0 }, "{k}");
        }
        // Ties: 70 % of the cells at 0 m fill one decile; the empty ones are None.
        let mut h = vec![0.0f32; 700];
        h.extend((1..=300).map(|k| k as f32));
        let d = snow_by_elevation_decile(&h, &vec![0.5; 1000]);
        assert_eq!(d.iter().filter(|r| r.is_none()).count(), 6);
        assert_eq!(d.iter().flatten().map(|r| r.cells).sum::<usize>(), 1000);
    }
}
