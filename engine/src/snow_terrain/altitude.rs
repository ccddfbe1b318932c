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
/// valid cells when `None`), `None` when no cell counts: [`ElevationHistogram::quantiles`] of
/// [`ElevationHistogram::new`].
pub fn elevation_quantiles(heights: &[f32], floor: Option<f32>, qs: &[f64]) -> Option<Vec<f32>> {
    ElevationHistogram::new(heights, floor).map(|h| h.quantiles(qs))
}

/// Bins of [`ElevationHistogram`].
const BINS: usize = 4096;
/// Cells whose bins are computed together ([`ElevationHistogram::bins`]).
const BLOCK: usize = 64;

/// The distribution of a DEM's elevations: the valid cells above a `floor` (all valid cells
/// when `None`) counted in 4096 equal bins over [lowest, highest] of those cells. Quantiles
/// ([`Self::quantiles`]) interpolate linearly inside the bin: within (max − min)/4096 of the
/// exact order statistic (≈ 1 m on a 4 km relief), where a sort of a 4096² DEM would take
/// most of a second. Integer counts: independent of the thread count. Built once per run and
/// shared by the altitude band (step 4) and the report's deciles when their cells are the same
/// ([`Self::is_of`]).
#[derive(Debug, Clone)]
pub struct ElevationHistogram {
    lo: f32,
    hi: f32,
    /// Cells counted.
    n: usize,
    /// The floor the cells were taken above.
    floor: Option<f32>,
    /// Bins per metre (0 when every counted cell has the same elevation).
    scale: f64,
    counts: Vec<u64>,
}

impl ElevationHistogram {
    /// The histogram of the valid cells of `heights` above `floor`: two parallel passes (the
    /// range, then the counts); `None` when no cell counts.
    pub fn new(heights: &[f32], floor: Option<f32>) -> Option<Self> {
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
        Self::with_range(heights, floor, (lo, hi, n))
    }

    /// [`Self::new`] from the valid cells' range already known (`(lowest, highest, count)` of
    /// every valid cell, e.g. [`crate::geom::Dem::valid_stats`]): one pass. When `floor` leaves
    /// out a cell (it is at or above the lowest) the range is not that of the counted cells,
    /// and this falls back to [`Self::new`].
    pub fn of_valid(
        heights: &[f32],
        floor: Option<f32>,
        valid: Option<(f32, f32, usize)>,
    ) -> Option<Self> {
        let (lo, hi, n) = valid?;
        if floor.is_some_and(|f| lo <= f) {
            return Self::new(heights, floor);
        }
        Self::with_range(heights, floor, (lo, hi, n))
    }

    /// [`Self::new`] from the range of the counted cells already known: `(lowest, highest,
    /// count)` of the valid cells above `floor` (e.g. the second figures of
    /// [`crate::geom::Dem::valid_stats_above`]), so one pass (the counts); `None` when no cell
    /// counts. The same histogram as [`Self::new`]'s when the range is that of those cells.
    pub fn of_range(
        heights: &[f32],
        floor: Option<f32>,
        range: Option<(f32, f32, usize)>,
    ) -> Option<Self> {
        Self::with_range(heights, floor, range?)
    }

    fn with_range(
        heights: &[f32],
        floor: Option<f32>,
        (lo, hi, n): (f32, f32, usize),
    ) -> Option<Self> {
        if n == 0 {
            return None;
        }
        let span = f64::from(hi) - f64::from(lo);
        let scale = if span > 0.0 { BINS as f64 / span } else { 0.0 };
        let mut me = Self {
            lo,
            hi,
            n,
            floor,
            scale,
            counts: vec![0; BINS],
        };
        if scale == 0.0 {
            me.counts[0] = n as u64;
            return Some(me);
        }
        // Counted per block: the block's bins first (a loop the compiler vectorises; cells not
        // counted go to the spare bin `BINS`), then the increments.
        let this = &me;
        let counts = heights
            .par_chunks(1 << 16)
            .fold(
                || vec![0u64; BINS + 1],
                |mut acc, c| {
                    let mut bins = [0u32; BLOCK];
                    for block in c.chunks(BLOCK) {
                        this.bins(block, floor, &mut bins);
                        for &b in &bins[..block.len()] {
                            acc[b as usize] += 1;
                        }
                    }
                    acc
                },
            )
            .reduce(
                || vec![0u64; BINS + 1],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        me.counts = counts;
        me.counts.truncate(BINS);
        Some(me)
    }

    /// Whether these are the counts of the valid cells above `floor`: built with that floor, or
    /// with none and every valid cell is above it.
    pub fn is_of(&self, floor: Option<f32>) -> bool {
        match (self.floor, floor) {
            (a, b) if a == b => true,
            (None, Some(f)) => self.lo > f,
            _ => false,
        }
    }

    /// The bin of a counted elevation `h` (in [lowest, highest]); non-decreasing in `h`.
    #[inline]
    fn bin(&self, h: f32) -> usize {
        (((f64::from(h) - f64::from(self.lo)) * self.scale) as usize).min(BINS - 1)
    }

    /// [`Self::bin`] of each of `hs` (at most [`BLOCK`]) into `out`, and `BINS` for the cells
    /// not counted (nodata, at or below `floor`). Branch-free, so the compiler vectorises it:
    /// `x = (h − lowest)·scale` is ≥ 0 for a counted cell, so clamping it to [0, BINS − 1]
    /// before the truncation gives `bin`'s value.
    #[inline]
    fn bins(&self, hs: &[f32], floor: Option<f32>, out: &mut [u32; BLOCK]) {
        let (lo, scale) = (f64::from(self.lo), self.scale);
        let top = (BINS - 1) as f64;
        let f = floor.unwrap_or(f32::NEG_INFINITY);
        for (o, &h) in out.iter_mut().zip(hs) {
            let x = ((f64::from(h) - lo) * scale).max(0.0).min(top);
            // `h > f` is false for NaN: nodata is not counted.
            *o = if h > f { x as u32 } else { BINS as u32 };
        }
    }

    /// Elevations at the quantiles `qs` (each clamped to [0, 1]). Quantile 0 is the lowest
    /// counted cell and 1 the highest, exactly; in between, linear inside the bin that holds
    /// the rank `q·(n − 1)`.
    pub fn quantiles(&self, qs: &[f64]) -> Vec<f32> {
        let (lo, hi, n) = (self.lo, self.hi, self.n);
        qs.iter()
            .map(|&q| {
                let q = q.clamp(0.0, 1.0);
                if q <= 0.0 || self.scale == 0.0 {
                    return lo;
                }
                if q >= 1.0 {
                    return hi;
                }
                // Rank of the quantile among n cells, then the bin holding it.
                let rank = q * (n - 1) as f64;
                let mut below = 0u64;
                for (k, &c) in self.counts.iter().enumerate() {
                    if c > 0 && (below + c) as f64 > rank {
                        let f = ((rank - below as f64) + 0.5) / c as f64;
                        let v = f64::from(lo) + (k as f64 + f.clamp(0.0, 1.0)) / self.scale;
                        return (v as f32).clamp(lo, hi);
                    }
                    below += c;
                }
                hi
            })
            .collect()
    }
}

/// Mean snow per elevation decile of the valid cells: ten `(lowest elevation, highest
/// elevation, cells, mean snow)` rows, lowest decile first, `None` for a decile that holds no
/// cell (ties: a flat sea at 0 m fills one decile, not three). Decile edges from
/// [`elevation_quantiles`]; a cell at an edge belongs to the decile below it. For the report
/// and the tests of issue 17 ("mean snow rises with elevation").
pub fn snow_by_elevation_decile(heights: &[f32], snow: &[f32]) -> Vec<Option<DecileStat>> {
    match ElevationHistogram::new(heights, None) {
        Some(hist) => deciles(&hist, heights, snow, |s| s),
        None => vec![None; 10],
    }
}

/// [`snow_by_elevation_decile`] from the descriptor t (snow s = 1 − t, the same bits as
/// `1.0 - t` stored) and the histogram of every valid cell (`hist.is_of(None)`), which the
/// pipeline has already built for the altitude band.
///
/// # Panics
/// If `hist` is not the histogram of every valid cell (a caller bug).
pub fn snow_by_elevation_decile_of_t(
    hist: &ElevationHistogram,
    heights: &[f32],
    t: &[f32],
) -> Vec<Option<DecileStat>> {
    assert!(hist.is_of(None), "the deciles need every valid cell");
    deciles(hist, heights, t, |t| 1.0 - t)
}

/// The deciles of `snow(v)` for the values `vs`. Each cell's decile is the number of edges
/// below its elevation; the bin → decile table gives it for every bin that holds no edge (the
/// bin is non-decreasing in the elevation, so a cell in a bin below an edge's bin is below the
/// edge, and above it in a bin above), and the cells of the ≤ 9 bins that hold an edge are
/// compared with the edges one by one: the same decile as the comparison everywhere. The sums
/// run per 2¹⁶-cell chunk in cell order and the chunks are added in order: the same figures
/// whatever the thread count.
fn deciles(
    hist: &ElevationHistogram,
    heights: &[f32],
    vs: &[f32],
    snow: impl Fn(f32) -> f32 + Sync,
) -> Vec<Option<DecileStat>> {
    const EDGE: u8 = u8::MAX;
    let qs: Vec<f64> = (1..10).map(|k| f64::from(k) / 10.0).collect();
    let edges = hist.quantiles(&qs);
    let edge_bins: Vec<usize> = edges.iter().map(|&e| hist.bin(e)).collect();
    let table: Vec<u8> = (0..BINS)
        .map(|k| {
            if edge_bins.contains(&k) {
                EDGE
            } else {
                edge_bins.iter().filter(|&&b| b < k).count() as u8
            }
        })
        .collect();
    let acc = heights
        .par_chunks(1 << 16)
        .zip(vs.par_chunks(1 << 16))
        .map(|(h, v)| {
            let mut a = [(f32::INFINITY, f32::NEG_INFINITY, 0usize, 0.0f64); 10];
            let mut bins = [0u32; BLOCK];
            for (h, v) in h.chunks(BLOCK).zip(v.chunks(BLOCK)) {
                hist.bins(h, None, &mut bins);
                for ((&h, &v), &b) in h.iter().zip(v).zip(&bins) {
                    let s = snow(v);
                    if h.is_nan() || s.is_nan() {
                        continue;
                    }
                    let mut k = table[b as usize];
                    if k == EDGE {
                        k = edges.partition_point(|&e| e < h) as u8;
                    }
                    let d = &mut a[usize::from(k)];
                    *d = (d.0.min(h), d.1.max(h), d.2 + 1, d.3 + f64::from(s));
                }
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

    /// The bin → decile table gives every cell the decile the comparison with the edges gives
    /// (the definition), on rough, tied elevations with nodata, and the sums in the same order.
    #[test]
    fn decile_table_matches_the_edge_comparison() {
        let mut h: Vec<f32> = (0..200_000u32)
            .map(|k| {
                let x = k.wrapping_mul(2_654_435_761) >> 8;
                if k % 97 == 0 {
                    f32::NAN
                } else if k % 5 == 0 {
                    (x % 50) as f32 // many ties
                } else {
                    (x % 1_000_000) as f32 * 0.0037 - 12.5
                }
            })
            .collect();
        h[7] = -12.5;
        let s: Vec<f32> = (0..h.len()).map(|k| (k % 13) as f32 / 13.0).collect();
        let got = snow_by_elevation_decile(&h, &s);
        let edges = elevation_quantiles(
            &h,
            None,
            &(1..10).map(|k| f64::from(k) / 10.0).collect::<Vec<_>>(),
        )
        .unwrap();
        let mut want = [(f32::INFINITY, f32::NEG_INFINITY, 0usize, 0.0f64); 10];
        let mut parts = Vec::new();
        for (hc, sc) in h.chunks(1 << 16).zip(s.chunks(1 << 16)) {
            let mut a = [(f32::INFINITY, f32::NEG_INFINITY, 0usize, 0.0f64); 10];
            for (&h, &s) in hc.iter().zip(sc) {
                if h.is_nan() {
                    continue;
                }
                let d = &mut a[edges.partition_point(|&e| e < h)];
                *d = (d.0.min(h), d.1.max(h), d.2 + 1, d.3 + f64::from(s));
            }
            parts.push(a);
        }
        for (k, w) in want.iter_mut().enumerate() {
            for a in &parts {
                *w = (w.0.min(a[k].0), w.1.max(a[k].1), w.2 + a[k].2, w.3 + a[k].3);
            }
            let g = got[k].unwrap();
            assert_eq!(
                (g.elevation_min, g.elevation_max, g.cells, g.mean_snow),
                (w.0, w.1, w.2, w.3 / w.2 as f64),
                "decile {k}"
            );
        }
        // The pipeline's path (from t, with the histogram of the valid range) is the same.
        let t: Vec<f32> = s.iter().map(|s| 1.0 - s).collect();
        let valid = h
            .iter()
            .filter(|v| !v.is_nan())
            .fold((f32::INFINITY, f32::NEG_INFINITY, 0), |a, &v| {
                (a.0.min(v), a.1.max(v), a.2 + 1)
            });
        let hist = ElevationHistogram::of_valid(&h, None, Some(valid)).unwrap();
        let from_t = snow_by_elevation_decile_of_t(&hist, &h, &t);
        for (a, b) in from_t.iter().zip(&got) {
            let (a, b) = (a.unwrap(), b.unwrap());
            assert_eq!(
                (a.elevation_min, a.elevation_max, a.cells),
                (b.elevation_min, b.elevation_max, b.cells)
            );
            assert!((a.mean_snow - b.mean_snow).abs() < 1e-6);
        }
        // A land floor below every cell: the same histogram as none.
        assert!(hist.is_of(Some(-20.0)) && !hist.is_of(Some(0.0)));
        assert_eq!(
            ElevationHistogram::of_valid(&h, Some(0.0), Some(valid))
                .unwrap()
                .quantiles(&[0.3, 0.7]),
            elevation_quantiles(&h, Some(0.0), &[0.3, 0.7]).unwrap()
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
