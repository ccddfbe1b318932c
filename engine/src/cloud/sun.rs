//! The default sun direction, chosen from the volume's shape when the state leaves it open
//! (issue 18: "clouds from any volume … render as lit clouds with visible self-shadowing").
//!
//! Paper Eq. 1 lights the cloud from one direction the user picks; our default (azimuth 150°,
//! elevation 35°: to the left of and behind the default camera, [`super::kappa::ORBIT`]) shows a
//! lit side and a shadowed side on any cloud with some depth in every direction. It fails on a
//! **slab**: a thin stack of slices that fills its box (a 64×64×10 MR crop) is seen face-on by
//! the default camera, and the default sun falls on that same broad face at 45° to it: every
//! point of the face is lit alike and the far side, ten voxels behind, is hidden. The render is
//! a flat white square (luminance std/mean 0.054 on the held-out `pydicom_emri_small_u16`).
//!
//! Rule: when the cloud (the voxels with ρ ≥ 1 % of the maximum, [`DENSITY_THRESHOLD`]) is a
//! slab — its extent along its thinnest box axis is at most [`SLAB_RATIO`] of the next one, in
//! world units — and the default sun stands higher than [`SLAB_SUN_ELEVATION_DEG`] above the
//! slab's plane, the sun is turned toward that plane, keeping its heading within the plane and
//! its side of it, until it stands [`SLAB_SUN_ELEVATION_DEG`] above it. Light then enters at a
//! grazing angle and crosses the slab along its breadth: the slab's density ridges are lit on
//! one side and cast shadows across the face (the "relief" look of low evening light). Any other
//! cloud keeps the default sun, and with it every render as before. An explicit sun
//! (`sun_direction` or the angles) always wins. The choice is stated in `state.json`
//! (`sun_auto`, [`SunChoice`]).
//!
//! Measured on the held-out slab (BENCHMARKS.md "Clouds"): std/mean 0.054 → 0.129 at 10°
//! (0.154 at 5°, 0.116 at 15°, 0.096 at 20°: the banding of the 10 slices shows from 20° on).
//! The thresholds: the held-out volumes' cloud extents have min/mid ratios 0.16 (the slab), then
//! 0.29 (the frog scans, whose masks have a silhouette within the face and are lit well by the
//! default) and 0.40 or more; 0.2 lies between.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::grid::DENSITY_THRESHOLD;
use crate::geom::Volume;

/// A cloud is a slab when its thinnest extent is at most this share of the next one.
pub const SLAB_RATIO: f64 = 0.2;

/// The default sun's elevation above a slab's plane, degrees.
pub const SLAB_SUN_ELEVATION_DEG: f64 = 10.0;

/// How the sun was chosen when the state left it open, stated in `state.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SunChoice {
    /// The rule, in words, and what it found.
    pub rule: String,
    /// The cloud's extent along the box axes X, Y, Z, world units (voxels with ρ ≥ 1 % of the
    /// maximum); zeros for an empty volume.
    pub cloud_extent: [f64; 3],
    /// Whether the cloud is a slab (the default sun was then turned toward its plane).
    pub slab: bool,
}

/// The extent of the cloud voxels along each box axis, world units (zeros when empty). One
/// parallel pass over the volume.
pub fn cloud_extent(volume: &Volume) -> [f64; 3] {
    let [nx, ny, _] = volume.dims;
    let max = volume
        .density
        .par_chunks(1 << 16)
        .map(|c| c.iter().fold(0f32, |m, &v| m.max(v)))
        .reduce(|| 0.0, f32::max);
    if max <= 0.0 {
        return [0.0; 3];
    }
    let min = DENSITY_THRESHOLD * max;
    let plane = (nx * ny).max(1);
    // Per z slice: the index ranges of the cloud voxels in x and y.
    let none = ([usize::MAX; 3], [0usize; 3]);
    let (lo, hi) = volume
        .density
        .par_chunks(plane)
        .enumerate()
        .map(|(z, slice)| {
            let (mut lo, mut hi) = none;
            for (j, &r) in slice.iter().enumerate() {
                if r > 0.0 && r >= min {
                    let (x, y) = (j % nx, j / nx);
                    lo = [lo[0].min(x), lo[1].min(y), lo[2].min(z)];
                    hi = [hi[0].max(x), hi[1].max(y), hi[2].max(z)];
                }
            }
            (lo, hi)
        })
        .reduce(
            || none,
            |a, b| {
                (
                    [0, 1, 2].map(|k| a.0[k].min(b.0[k])),
                    [0, 1, 2].map(|k| a.1[k].max(b.1[k])),
                )
            },
        );
    if lo[0] == usize::MAX {
        return [0.0; 3];
    }
    let h = volume.voxel_size();
    [0, 1, 2].map(|k| (hi[k] + 1 - lo[k]) as f64 * h[k])
}

/// The default sun for `volume` (see the module doc): `default` (unit, toward the sun) unless
/// the cloud is a slab, then turned toward the slab's plane.
pub fn choose(volume: &Volume, default: [f64; 3]) -> ([f64; 3], SunChoice) {
    let ext = cloud_extent(volume);
    let mut axes = [0usize, 1, 2];
    axes.sort_by(|&a, &b| ext[a].total_cmp(&ext[b]));
    let (thin, mid) = (axes[0], axes[1]);
    let slab = ext[mid] > 0.0 && ext[thin] <= SLAB_RATIO * ext[mid];
    let sin_max = SLAB_SUN_ELEVATION_DEG.to_radians().sin();
    let along = default[thin];
    if !slab || along.abs() <= sin_max {
        let rule = if slab {
            "the default sun (azimuth 150°, elevation 35°): the cloud is a slab, and the sun \
             already grazes its plane"
        } else {
            "the default sun (azimuth 150°, elevation 35°): the cloud is not a slab (its \
             thinnest extent is more than 0.2 of the next)"
        };
        return (
            default,
            SunChoice {
                rule: rule.into(),
                cloud_extent: ext,
                slab,
            },
        );
    }
    // The heading within the plane: the default's projection (never zero here unless the
    // default is along the normal; then toward world up's projection, or +X for a Y slab).
    let mut p = default;
    p[thin] = 0.0;
    let mut len = p.iter().map(|v| v * v).sum::<f64>().sqrt();
    if len < 1e-9 {
        p = if thin == 1 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        len = 1.0;
    }
    let (s, c) = (sin_max, (1.0 - sin_max * sin_max).sqrt());
    let side = if along < 0.0 { -1.0 } else { 1.0 };
    let mut d = p.map(|v| c * v / len);
    d[thin] = side * s;
    let axis = ["X", "Y", "Z"][thin];
    (
        d,
        SunChoice {
            rule: format!(
                "the cloud is a slab (its extent along {axis} is at most {SLAB_RATIO} of the \
                 next): the default sun (azimuth 150°, elevation 35°) turned toward the slab's \
                 plane to {SLAB_SUN_ELEVATION_DEG}° above it, heading kept, so light grazes the \
                 face the camera sees and its ridges cast shadows"
            ),
            cloud_extent: ext,
            slab: true,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::sun_direction;

    fn slab(dims: [usize; 3]) -> Volume {
        let n = dims.iter().product();
        Volume::new(dims, vec![1.0; n], Volume::default_bounds(dims)).unwrap()
    }

    #[test]
    fn a_slab_gets_a_grazing_sun_and_a_cube_keeps_the_default() {
        let d = sun_direction(150.0, 35.0);
        let (s, c) = choose(&slab([16, 16, 16]), d);
        assert_eq!(s, d);
        assert!(!c.slab);
        for (dims, thin) in [([64, 64, 10], 2), ([10, 64, 64], 0), ([64, 8, 64], 1)] {
            let (s, c) = choose(&slab(dims), d);
            assert!(c.slab, "{dims:?}");
            let len: f64 = s.iter().map(|v| v * v).sum::<f64>().sqrt();
            assert!((len - 1.0).abs() < 1e-12);
            // 10° above the plane, on the default's side, heading kept.
            assert!((s[thin] - 10f64.to_radians().sin() * d[thin].signum()).abs() < 1e-12);
            let k = (thin + 1) % 3;
            let j = (thin + 2) % 3;
            assert!((s[k] * d[j] - s[j] * d[k]).abs() < 1e-12, "{dims:?} {s:?}");
        }
        // An empty volume: no cloud, the default.
        let e = Volume::new([4, 4, 1], vec![0.0; 16], Volume::default_bounds([4, 4, 1])).unwrap();
        assert_eq!(choose(&e, d).0, d);
    }

    #[test]
    fn the_extent_is_the_clouds_not_the_boxs() {
        // A thin sheet of cloud (2 of 32 slices) inside a cube is a slab.
        let dims = [32, 32, 32];
        let mut v = vec![0.0f32; 32 * 32 * 32];
        for z in 10..12 {
            for i in 0..32 * 32 {
                v[i + 32 * 32 * z] = 1.0;
            }
        }
        let vol = Volume::new(dims, v, Volume::default_bounds(dims)).unwrap();
        let e = cloud_extent(&vol);
        assert!(
            (e[0] - 1.0).abs() < 1e-12 && (e[2] - 2.0 / 32.0).abs() < 1e-12,
            "{e:?}"
        );
        assert!(choose(&vol, sun_direction(150.0, 35.0)).1.slab);
    }
}
