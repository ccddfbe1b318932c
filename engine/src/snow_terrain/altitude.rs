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
//! and t = 1 − s. With the defaults (snowline 0 m, exponent 2) this is the paper's quadratic.
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
}
