//! The default extinction κ, chosen from the volume itself (issue 18: "clouds from any volume").
//!
//! Paper Eqs. 1–3 leave κ to the user, and one fixed number cannot suit every volume: a
//! segmentation mask stored as 0/255, a CT scan in Hounsfield-like units and a fog volume in
//! 0–1 differ in density scale by 10³ or more, and a κ that makes one translucent makes another
//! a black (or, with the κρ emission of [`super::march`], flat grey) silhouette whose interior
//! no sunlight reaches. What makes a cloud read as lit with visible self-shadowing is its
//! *optical depth* along the light and view paths: around 1–10, the lit side is bright, light
//! fades over a visible distance inside, and the far side is in shadow.
//!
//! Rule: κ = [`TARGET_OPTICAL_DEPTH`] / (the median column density ∫ρ dl of the rays that cross
//! the cloud), the rays being two parallel bundles ([`RAYS_PER_SIDE`]² each) covering the box
//! seen along the sun direction and along the default view direction
//! ([`ORBIT`]); a ray crosses the cloud when it passes through a voxel with
//! ρ ≥ 1 % of the maximum (the edits' reading of "with density",
//! [`DENSITY_THRESHOLD`]). So the median optical depth through the
//! cloud along those rays is exactly [`TARGET_OPTICAL_DEPTH`], whatever the volume's units, grid
//! size or box. Columns are integrated with the renderer's trilinear samples, one per smallest
//! voxel edge (as the renderer's default `step`, bounded the same way by the voxels crossed:
//! [`GridFrame::samples`]). An explicit κ always wins; an empty volume keeps [`FALLBACK_KAPPA`].

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::grid::{GridFrame, DENSITY_THRESHOLD};
use crate::geom::sun_direction as sun_from_angles;
use crate::geom::vec::DVec3;
use crate::geom::Volume;
use crate::params::OrbitDefaults;

/// The cloud pipeline's default orbit: a little above the horizon, the sun (azimuth 150°) to
/// the camera's left and behind. κ is chosen along its rays when not given.
pub const ORBIT: OrbitDefaults = OrbitDefaults {
    azimuth_deg: 200.0,
    elevation_deg: 12.0,
    fov_deg: 40.0,
};

/// The median optical depth the chosen κ gives the cloud along the sun and view rays.
/// 4: the lit face is bright, the median path keeps e⁻⁴ ≈ 2 % of the light, so the far side is
/// visibly in shadow while thin parts stay translucent (measured on the real volumes of
/// `tests/data/volume` and the held-out set; see the module doc).
pub const TARGET_OPTICAL_DEPTH: f64 = 4.0;

/// Rays per side of each bundle (64² = 4,096 per direction).
pub const RAYS_PER_SIDE: usize = 64;

/// κ when the volume holds no density (any κ renders it the same: empty).
pub const FALLBACK_KAPPA: f64 = 120.0;

/// How κ was chosen, stated in `state.json` beside it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KappaChoice {
    /// The rule, in words.
    pub rule: String,
    /// The optical depth aimed at: [`TARGET_OPTICAL_DEPTH`].
    pub optical_depth: f64,
    /// The median column density ∫ρ dl (density × world units) of the rays through the cloud.
    pub median_column: f64,
    /// How many of the bundles' rays crossed the cloud.
    pub rays: u64,
}

/// Column densities ∫ρ dl of a bundle of parallel rays along `d` covering the box, only for the
/// rays that cross a voxel with ρ ≥ `min_rho`.
fn columns(volume: &Volume, g: &GridFrame, d: [f64; 3], min_rho: f32) -> Vec<f64> {
    let d = DVec3::from(d);
    let len = d.length();
    if !(len.is_finite() && len > 0.0) {
        return Vec::new();
    }
    let n = d / len;
    // An orthonormal basis (u, v) across the rays.
    let helper = if n.y.abs() < 0.9 { DVec3::Y } else { DVec3::X };
    let u = n.cross(helper);
    let u = u / u.length();
    let v = n.cross(u);
    let centre = [0, 1, 2].map(|k| 0.5 * (g.lo[k] + g.hi[k]));
    let half = [0, 1, 2].map(|k| 0.5 * (g.hi[k] - g.lo[k]));
    let radius = DVec3::from(half).length();
    // The box's extent across the rays.
    let (mut ue, mut ve) = (0f64, 0f64);
    for c in 0..8 {
        let p = DVec3::from([0, 1, 2].map(|k| if (c >> k) & 1 == 1 { half[k] } else { -half[k] }));
        ue = ue.max(p.dot(u).abs());
        ve = ve.max(p.dot(v).abs());
    }
    let n = n.to_array();
    let m = RAYS_PER_SIDE;
    (0..m * m)
        .into_par_iter()
        .filter_map(|r| {
            let (a, b) = ((r % m) as f64, (r / m) as f64);
            let su = ue * (2.0 * (a + 0.5) / m as f64 - 1.0);
            let sv = ve * (2.0 * (b + 0.5) / m as f64 - 1.0);
            let o = [0, 1, 2].map(|k| centre[k] + su * u[k] + sv * v[k] - 2.0 * radius * n[k]);
            let (t0, t1) = g.clip(o, n)?;
            let steps = g.samples(t1 - t0, n, 1.0);
            let h = (t1 - t0) / steps as f64;
            let (mut sum, mut peak) = (0f64, 0f32);
            for s in 0..steps {
                let t = t0 + (s as f64 + 0.5) * h;
                let p = [0, 1, 2].map(|k| o[k] + t * n[k]);
                let rho = g.density_at(&volume.density, p);
                peak = peak.max(rho);
                sum += f64::from(rho) * h;
            }
            (peak >= min_rho && peak > 0.0 && sum > 0.0).then_some(sum)
        })
        .collect()
}

/// The unit vector from the default camera toward the volume (the default orbit's view).
pub fn default_view_direction() -> [f64; 3] {
    let toward_camera = sun_from_angles(ORBIT.azimuth_deg, ORBIT.elevation_deg);
    toward_camera.map(|x| -x)
}

/// Chooses κ for `volume` lit from `sun` (unit vector toward the sun): see the module doc.
/// Cost: 2 × 4,096 rays of trilinear samples a voxel apart (≈ 3·10⁶ samples at 256³) and one
/// pass for the maximum density.
pub fn choose(volume: &Volume, sun: [f64; 3]) -> (f64, KappaChoice) {
    let g = GridFrame::of(volume);
    let max = volume
        .density
        .par_chunks(1 << 16)
        .map(|c| c.iter().fold(0f32, |m, &v| m.max(v)))
        .reduce(|| 0.0, f32::max);
    let min_rho = DENSITY_THRESHOLD * max;
    let mut all = columns(volume, &g, sun, min_rho);
    all.extend(columns(volume, &g, default_view_direction(), min_rho));
    let rule = format!(
        "chosen from the volume: κ = {TARGET_OPTICAL_DEPTH} / the median column density ∫ρ dl of \
         the rays through the cloud (ρ ≥ 1 % of the maximum) along the sun and the default view, \
         so the median optical depth through the cloud is {TARGET_OPTICAL_DEPTH}"
    );
    if all.is_empty() {
        return (
            FALLBACK_KAPPA,
            KappaChoice {
                rule: format!("the volume holds no density: κ = {FALLBACK_KAPPA}"),
                optical_depth: TARGET_OPTICAL_DEPTH,
                median_column: 0.0,
                rays: 0,
            },
        );
    }
    let mid = all.len() / 2;
    let (_, median, _) = all.select_nth_unstable_by(mid, f64::total_cmp);
    let median = *median;
    // Within the state's range (0–10,000); a column below 4·10⁻⁴ would ask for more.
    let kappa = (TARGET_OPTICAL_DEPTH / median).clamp(1e-6, 10_000.0);
    (
        kappa,
        KappaChoice {
            rule,
            optical_depth: TARGET_OPTICAL_DEPTH,
            median_column: median,
            rays: all.len() as u64,
        },
    )
}
