//! The default density floor: a scan's noisy background taken out before anything else
//! (issue 18: "clouds from MR scans with noisy background").
//!
//! A magnitude MR scan has no empty space: the air around the head holds Rician noise a few
//! percent of the tissue's brightness, in every voxel of the box. Rendered as density, that
//! noise integrates over the whole box into a fog that hides the object (a "foggy cube"), and κ
//! chosen from the median column ([`super::kappa`]) cannot help: the fog is in every column.
//! Segmentation masks, skull-stripped templates, fog VDBs and simulated clouds have an empty
//! background (exactly zero) and need nothing.
//!
//! Rule ([`choose`]): the background is what the box's six faces show. Let m be the median of
//! the densities on the faces and s their robust spread (1.4826 × the median absolute
//! deviation from m, σ for Gaussian noise). The object is the upper class of Otsu's threshold t
//! over the whole volume's histogram (256 bins between its minimum and maximum), μ its mean.
//!
//! - m ≥ [`CROP_RATIO`] · μ: the faces are not darker than the object by much: the box cuts
//!   through the object (a crop of tissue, a slab) and there is no background to take out:
//!   floor 0.
//! - otherwise floor = min(m + [`NOISE_SIGMAS`] · s, t): above the background's noise (for
//!   Rayleigh noise, the magnitude MR background, m + 3s leaves about 0.5 % of the noise
//!   voxels), never above Otsu's split between background and object. An empty background
//!   (m = s = 0) gives floor 0, so masks, templates and fog volumes are unchanged.
//!
//! The floor is then subtracted ([`apply`]: ρ ← max(0, ρ − floor)), not used as a hard cut, so
//! the object's edges keep their soft fall-off. An explicit `density_floor` wins (0: none).
//! Cost: one pass for the extremes, one for the histogram (parallel), a sort-free median of the
//! faces (O(face voxels)); allocates the face values only.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::geom::Volume;

/// Robust standard deviations of the faces' noise above their median that the floor sits at.
pub const NOISE_SIGMAS: f64 = 3.0;

/// The faces' median over the object's mean above which the box is taken to cut through the
/// object (no background). Measured: MR heads with air around them 0.02–0.04 (VolPack
/// brainsmall, dipy's T1); crops inside tissue 0.4–0.8 (pydicom's enhanced MR slab, nibabel's
/// anatomical cut).
pub const CROP_RATIO: f64 = 0.1;

/// Histogram bins of Otsu's threshold.
const BINS: usize = 256;

/// How the floor was chosen, stated in `state.json` beside it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FloorChoice {
    /// The rule and the case that applied, in words.
    pub rule: String,
    /// m: the median density on the box's six faces.
    pub face_median: f64,
    /// s: 1.4826 × the faces' median absolute deviation from m.
    pub face_spread: f64,
    /// t: Otsu's threshold over the volume's histogram.
    pub otsu: f64,
    /// μ: the mean density above t (the object's).
    pub object_mean: f64,
}

/// The densities on the six faces of the grid (a voxel on an edge or corner counted once per
/// face it is on).
fn faces(v: &Volume) -> Vec<f32> {
    let [nx, ny, nz] = v.dims;
    let mut out = Vec::with_capacity(2 * (nx * ny + ny * nz + nx * nz));
    for z in [0, nz - 1] {
        for y in 0..ny {
            for x in 0..nx {
                out.push(v.density[v.index(x, y, z)]);
            }
        }
    }
    for y in [0, ny - 1] {
        for z in 0..nz {
            for x in 0..nx {
                out.push(v.density[v.index(x, y, z)]);
            }
        }
    }
    for x in [0, nx - 1] {
        for z in 0..nz {
            for y in 0..ny {
                out.push(v.density[v.index(x, y, z)]);
            }
        }
    }
    out
}

/// The median of `values` (reorders them); 0 for none.
fn median(values: &mut [f32]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*m)
}

/// Otsu's threshold over a `BINS`-bin histogram of the densities between `lo` and `hi`, and
/// the mean above it. `None` when the volume is constant.
fn otsu(density: &[f32], lo: f32, hi: f32) -> Option<(f64, f64)> {
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let (lo, hi) = (f64::from(lo), f64::from(hi));
    let width = (hi - lo) / BINS as f64;
    let bin = |v: f32| (((f64::from(v) - lo) / width) as usize).min(BINS - 1);
    let hist = density
        .par_chunks(1 << 16)
        .map(|c| {
            let mut h = [0u64; BINS];
            for &v in c {
                h[bin(v)] += 1;
            }
            h
        })
        .reduce(
            || [0u64; BINS],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x += y;
                }
                a
            },
        );
    let centre = |i: usize| lo + (i as f64 + 0.5) * width;
    let total: f64 = hist.iter().map(|&n| n as f64).sum();
    let total_mass: f64 = hist
        .iter()
        .enumerate()
        .map(|(i, &n)| n as f64 * centre(i))
        .sum();
    let (mut w0, mut m0) = (0f64, 0f64);
    let mut best = (f64::NEG_INFINITY, 0usize);
    for (i, &n) in hist.iter().enumerate().take(BINS - 1) {
        w0 += n as f64;
        m0 += n as f64 * centre(i);
        let w1 = total - w0;
        if w0 == 0.0 || w1 == 0.0 {
            continue;
        }
        let d = m0 / w0 - (total_mass - m0) / w1;
        let between = w0 * w1 * d * d;
        if between > best.0 {
            best = (between, i);
        }
    }
    // The split lies between bin i and i + 1; the object is what lies above it.
    let t = lo + (best.1 + 1) as f64 * width;
    let (sum, n) = density
        .par_iter()
        .filter(|&&v| f64::from(v) >= t)
        .map(|&v| (f64::from(v), 1u64))
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    Some((t, if n > 0 { sum / n as f64 } else { hi }))
}

/// Chooses the floor for `volume` (module doc): the value, in the volume's density units, and
/// how it was chosen.
pub fn choose(volume: &Volume) -> (f64, FloorChoice) {
    let mut f = faces(volume);
    let m = median(&mut f);
    for v in f.iter_mut() {
        *v = (f64::from(*v) - m).abs() as f32;
    }
    let s = 1.4826 * median(&mut f);
    drop(f);
    let (lo, hi) = volume
        .density
        .par_chunks(1 << 16)
        .map(|c| {
            c.iter()
                .fold((f32::INFINITY, 0f32), |(a, b), &v| (a.min(v), b.max(v)))
        })
        .reduce(|| (f32::INFINITY, 0.0), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    let Some((t, mu)) = otsu(&volume.density, lo, hi) else {
        return (
            0.0,
            FloorChoice {
                rule: "the volume is constant: no floor".into(),
                face_median: m,
                face_spread: s,
                otsu: f64::from(hi),
                object_mean: f64::from(hi),
            },
        );
    };
    let choice = |rule: String| FloorChoice {
        rule,
        face_median: m,
        face_spread: s,
        otsu: t,
        object_mean: mu,
    };
    if m + s <= 0.0 {
        return (
            0.0,
            choice(
                "the box's faces are empty (density 0): no background to take out, no floor".into(),
            ),
        );
    }
    if m >= CROP_RATIO * mu {
        return (
            0.0,
            choice(format!(
                "the faces' median density m is at least {CROP_RATIO} of the object's mean μ \
                 (above Otsu's threshold): the box cuts through the object, no floor"
            )),
        );
    }
    let floor = (m + NOISE_SIGMAS * s).min(t);
    (
        floor,
        choice(format!(
            "a scan's background: floor = min(m + {NOISE_SIGMAS}·s, Otsu's threshold) from the \
             median m and robust spread s of the box's six faces, subtracted from every voxel \
             (ρ ← max(0, ρ − floor))"
        )),
    )
}

/// Takes `floor` out of every voxel: ρ ← max(0, ρ − floor). Nothing for a floor ≤ 0.
pub fn apply(volume: &mut Volume, floor: f64) {
    if floor <= 0.0 || !floor.is_finite() {
        return;
    }
    let f = floor as f32;
    volume
        .density
        .par_iter_mut()
        .for_each(|v| *v = (*v - f).max(0.0));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn volume(dims: [usize; 3], f: impl Fn(usize, usize, usize) -> f32) -> Volume {
        let mut d = Vec::new();
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    d.push(f(x, y, z));
                }
            }
        }
        Volume::new(dims, d, ([0.0; 3], [1.0; 3])).unwrap()
    }

    /// A deterministic noise in [0, 1).
    fn noise(x: usize, y: usize, z: usize) -> f32 {
        let mut h = (x as u64 * 73_856_093) ^ (y as u64 * 19_349_663) ^ (z as u64 * 83_492_791);
        h = h.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        (h >> 40) as f32 / (1u64 << 24) as f32
    }

    fn ball(x: usize, y: usize, z: usize, n: usize) -> bool {
        let c = n as f32 / 2.0;
        let r2 = (x as f32 - c).powi(2) + (y as f32 - c).powi(2) + (z as f32 - c).powi(2);
        r2 < (0.3 * n as f32).powi(2)
    }

    #[test]
    fn a_noisy_background_is_taken_out_and_an_empty_one_or_a_crop_is_kept() {
        let n = 32;
        // A ball of 100 in noise of 0–10 (mean 5, σ ≈ 2.9).
        let noisy = volume([n; 3], |x, y, z| {
            10.0 * noise(x, y, z) + if ball(x, y, z, n) { 100.0 } else { 0.0 }
        });
        let (f, c) = choose(&noisy);
        assert!((9.0..=20.0).contains(&f), "{f} {c:?}");
        let mut v = noisy.clone();
        apply(&mut v, f);
        let outside_left = (0..v.len())
            .filter(|&i| {
                let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
                !ball(x, y, z, n) && v.density[i] > 0.0
            })
            .count();
        assert_eq!(outside_left, 0, "the noise is gone");
        assert!(v.density.iter().any(|&d| d > 80.0), "the ball stays");

        // The same ball on an empty background: nothing to take out.
        let clean = volume([n; 3], |x, y, z| if ball(x, y, z, n) { 255.0 } else { 0.0 });
        assert_eq!(choose(&clean).0, 0.0);

        // A crop through the object (no background on the faces): kept.
        let crop = volume([n; 3], |x, y, z| 50.0 + 50.0 * noise(x, y, z));
        let (f, c) = choose(&crop);
        assert_eq!(f, 0.0, "{c:?}");

        // Constant: no floor.
        assert_eq!(choose(&volume([4; 3], |_, _, _| 3.0)).0, 0.0);
    }
}
