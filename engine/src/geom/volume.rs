//! A density volume as the cloud pipeline sees it (SPEC §3 input): a dense grid of densities ρ ≥ 0
//! with its box in the world frame.
//!
//! Layout: `density[x + nx·(y + ny·z)]`, x fastest — the C order `(z, y, x)` of NumPy arrays and the
//! x-fastest order of NRRD and OpenVDB dense copies. World frame as everywhere in the engine: X east,
//! Y up, Z south (glTF's Y-up frame); grid axis y maps to world Y, so OpenVDB's Y-up smoke stands
//! upright. Voxel `(x, y, z)` covers the cell `[min + i·h, min + (i+1)·h)` per axis, `h = (max − min)/n`,
//! and its value sits at the cell centre.

use crate::InputError;

/// A decoded, validated density volume.
#[derive(Debug, Clone, PartialEq)]
pub struct Volume {
    /// Grid size `[nx, ny, nz]`, each ≥ 1.
    pub dims: [usize; 3],
    /// `nx·ny·nz` densities, finite and ≥ 0, x fastest.
    pub density: Vec<f32>,
    /// World box `(min, max)`, `min < max` on every axis.
    pub bounds: ([f64; 3], [f64; 3]),
}

impl Volume {
    /// Checks the invariants above; negative or non-finite densities and inconsistent sizes are
    /// refused with the first offending voxel named.
    pub fn new(
        dims: [usize; 3],
        density: Vec<f32>,
        bounds: ([f64; 3], [f64; 3]),
    ) -> Result<Self, InputError> {
        let n = dims
            .iter()
            .try_fold(1usize, |acc, &d| acc.checked_mul(d))
            .filter(|&n| n > 0)
            .ok_or_else(|| InputError::Unusable(format!("volume dimensions {dims:?} are empty")))?;
        if density.len() != n {
            return Err(InputError::Unusable(format!(
                "volume holds {} values, dimensions {dims:?} need {n}",
                density.len()
            )));
        }
        if let Some(i) = density.iter().position(|v| !v.is_finite() || *v < 0.0) {
            let x = i % dims[0];
            let y = (i / dims[0]) % dims[1];
            let z = i / (dims[0] * dims[1]);
            return Err(InputError::Unusable(format!(
                "density at voxel ({x}, {y}, {z}) is {}; densities must be finite and ≥ 0",
                density[i]
            )));
        }
        let (lo, hi) = bounds;
        if (0..3).any(|k| !(lo[k].is_finite() && hi[k].is_finite() && lo[k] < hi[k])) {
            return Err(InputError::Unusable(format!(
                "volume bounds {lo:?}..{hi:?} must be finite with min < max on every axis"
            )));
        }
        Ok(Self {
            dims,
            density,
            bounds,
        })
    }

    /// SPEC §3's default box: the unit cube scaled to the grid's aspect — the longest axis spans
    /// 1 world unit — centred on the origin horizontally with its base at Y = 0.
    pub fn default_bounds(dims: [usize; 3]) -> ([f64; 3], [f64; 3]) {
        let longest = dims.iter().copied().max().unwrap_or(1).max(1) as f64;
        let ext = dims.map(|d| d.max(1) as f64 / longest);
        (
            [-0.5 * ext[0], 0.0, -0.5 * ext[2]],
            [0.5 * ext[0], ext[1], 0.5 * ext[2]],
        )
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.density.len()
    }

    /// Always false for a validated volume (kept for clippy's `len_without_is_empty`).
    pub fn is_empty(&self) -> bool {
        self.density.is_empty()
    }

    /// Flat index of voxel `(x, y, z)`.
    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    /// Voxel edge lengths `(max − min) / n` per axis, world units.
    pub fn voxel_size(&self) -> [f64; 3] {
        let (lo, hi) = self.bounds;
        [0, 1, 2].map(|k| (hi[k] - lo[k]) / self.dims[k] as f64)
    }

    /// (min, max, mean) of the densities.
    pub fn stats(&self) -> (f32, f32, f64) {
        let mut min = f32::INFINITY;
        let mut max = f32::NEG_INFINITY;
        let mut sum = 0.0f64;
        for &v in &self.density {
            min = min.min(v);
            max = max.max(v);
            sum += f64::from(v);
        }
        (min, max, sum / self.density.len().max(1) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_nan_negative_and_size_mismatch() {
        let b = Volume::default_bounds([2, 2, 2]);
        assert!(Volume::new([2, 2, 2], vec![0.0; 8], b).is_ok());
        assert!(Volume::new([2, 2, 2], vec![0.0; 7], b).is_err());
        let mut d = vec![0.0; 8];
        d[5] = f32::NAN;
        let e = Volume::new([2, 2, 2], d, b).unwrap_err().to_string();
        assert!(e.contains("(1, 0, 1)"), "{e}");
        let mut d = vec![0.0; 8];
        d[1] = -1.0;
        assert!(Volume::new([2, 2, 2], d, b).is_err());
        assert!(Volume::new([0, 2, 2], vec![], b).is_err());
    }

    #[test]
    fn default_bounds_keep_the_aspect() {
        let (lo, hi) = Volume::default_bounds([100, 200, 50]);
        assert_eq!(hi[1] - lo[1], 1.0);
        assert_eq!(hi[0] - lo[0], 0.5);
        assert_eq!(hi[2] - lo[2], 0.25);
        assert_eq!(lo[1], 0.0);
    }
}
