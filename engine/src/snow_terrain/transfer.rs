//! Transfer function (paper §3.3, Eq. 4, after Eura and Fujishiro 1996; SPEC §1 step 3).
//!
//! Maps a TSA value t ∈ [0, ∞) (metres) to [0, 1] with a probe ("brush") of radius r (metres):
//!
//! ```text
//! g(t) = 1                     if t ≥ r   (the wind's brush reaches the point: bare rock)
//! g(t) = (1 − b)/r · t + b     if t < r   (snow stays; b is what remains of the rock colour at t = 0)
//! ```
//!
//! Adaptations: r = 0 means every point is reached (g = 1); NaN (nodata) passes through. The paper
//! uses b = 0 for all its results.

use rayon::prelude::*;

/// Eq. 4 for one value. `probe_radius` r ≥ 0 (metres), `b` ∈ [0, 1]. Returns a value in [b, 1]
/// (NaN for NaN).
#[inline]
pub fn transfer(t: f32, probe_radius: f32, b: f32) -> f32 {
    if t.is_nan() {
        f32::NAN
    } else if t >= probe_radius {
        1.0
    } else {
        (1.0 - b) / probe_radius * t.max(0.0) + b
    }
}

/// Applies [`transfer`] to every cell in place.
pub fn transfer_grid(t: &mut [f32], probe_radius: f32, b: f32) {
    t.par_iter_mut()
        .for_each(|v| *v = transfer(*v, probe_radius, b));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_eq4() {
        let (r, b) = (200.0f32, 0.25f32);
        assert_eq!(transfer(0.0, r, b), b);
        assert_eq!(transfer(r, r, b), 1.0);
        assert_eq!(transfer(1.0e9, r, b), 1.0);
        for t in [1.0f32, 50.0, 100.0, 199.0] {
            let expect = (1.0 - b) / r * t + b;
            assert!((transfer(t, r, b) - expect).abs() < 1e-6);
        }
        // Continuous at t = r and monotone.
        assert!((transfer(r - 1e-3, r, b) - 1.0).abs() < 1e-4);
        let mut last = -1.0;
        for k in 0..300 {
            let v = transfer(k as f32, r, b);
            assert!(v >= last);
            last = v;
        }
    }

    #[test]
    fn paper_b_zero_and_edge_cases() {
        assert_eq!(transfer(0.0, 10.0, 0.0), 0.0);
        assert_eq!(transfer(5.0, 10.0, 0.0), 0.5);
        assert_eq!(transfer(0.0, 10.0, 1.0), 1.0);
        assert_eq!(transfer(0.0, 0.0, 0.0), 1.0);
        assert!(transfer(f32::NAN, 10.0, 0.0).is_nan());
        let mut g = vec![0.0, 5.0, 20.0, f32::NAN];
        transfer_grid(&mut g, 10.0, 0.0);
        assert_eq!(&g[..3], &[0.0, 0.5, 1.0]);
        assert!(g[3].is_nan());
    }
}
