//! Snow probability (journal §2.2 "積雪確率分布の算出", Fig. 3–5; workshop §2.1(1)–(2); SPEC §2
//! step 2).
//!
//! K snowfall directions are drawn around the main direction from a 2-D normal distribution of
//! angular offsets (std `spread_deg` per axis of the plane perpendicular to the main direction).
//! The main direction is straight down, or tilted by the wind: `tilt_deg` from vertical, the snow
//! coming *from* compass azimuth `azimuth_deg` (0 = north = −Z, 90 = east = +X; as weather reports
//! and as `sun_azimuth_deg` in snow-terrain), so it travels toward `azimuth_deg + 180` and shadows
//! reach downwind. Directions are clamped to at most 85° from vertical. For each direction the
//! scene is rendered into a [`ShadowMap`], and every snow-map cell's surface point (the base, or
//! base + snow when reprojecting) is tested against it. P = the share of directions from which the
//! point is lit.
//!
//! **Angle weighting** (workshop §2.1(2): the influence of a direction depends on its angle, "the
//! relation drawn from normal random numbers"): optionally each direction counts with weight
//! `exp(−θ²/2σ²)`, θ its angle to the main direction and σ = `spread_deg`, so rare far-off
//! directions count less. Off by default (the journal counts all directions equally).
//!
//! **Determinism.** The random numbers come from SplitMix64 seeded with `seed` (no dependency;
//! integer arithmetic, identical on every platform) turned into normal deviates by Box–Muller in
//! `f64`. Visibility is accumulated as integer weights (`round(weight · 2¹⁶)`), so the sum over
//! directions does not depend on how rayon splits them: results are bit-identical for any number
//! of threads. Rayon runs over chunks of directions, one shadow map and one counter grid per
//! chunk, summed in chunk order.
//!
//! Cost: K × (rasterise the scene + test every layer cell). Allocates one shadow map and one
//! `u32` counter grid per layer per rayon chunk.

use rayon::prelude::*;

use super::maps::SnowMaps;
use super::shadow::ShadowMap;
use crate::geom::mesh::Mesh;
use crate::{Canceled, Control};

/// Largest angle of a snowfall direction from vertical, degrees.
pub const MAX_DIRECTION_TILT_DEG: f32 = 85.0;
/// Fixed-point scale of direction weights.
const WEIGHT_ONE: f64 = 65536.0;

/// Wind tilting the main snowfall direction (module doc for the conventions).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Wind {
    /// Compass azimuth the wind (and snow) comes from, degrees (0 = north = −Z, 90 = east = +X).
    pub azimuth_deg: f32,
    /// Angle of the main snowfall direction from vertical, degrees, in [0, 85].
    pub tilt_deg: f32,
}

/// Where the probability is evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Receiver {
    /// On the base surface (the paper: P fixed while snow grows).
    Base,
    /// On the current snow surface (base + snow; SPEC's `reproject_every`).
    SnowSurface,
}

/// SplitMix64 (Steele, Lea, Flood 2014): tiny, fast, identical on every platform.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1].
    pub fn next_open01(&mut self) -> f64 {
        ((self.next_u64() >> 11) + 1) as f64 / (1u64 << 53) as f64
    }

    /// A pair of independent standard normal deviates (Box–Muller).
    pub fn next_normal_pair(&mut self) -> (f64, f64) {
        let r = (-2.0 * self.next_open01().ln()).sqrt();
        let a = std::f64::consts::TAU * self.next_open01();
        (r * a.cos(), r * a.sin())
    }
}

/// The main snowfall direction (unit, pointing where the snow goes): straight down, or tilted by
/// `wind`.
pub fn main_direction(wind: Option<Wind>) -> [f32; 3] {
    let Some(w) = wind else {
        return [0.0, -1.0, 0.0];
    };
    let tilt = f64::from(w.tilt_deg.clamp(0.0, MAX_DIRECTION_TILT_DEG)).to_radians();
    let az = f64::from(w.azimuth_deg).to_radians();
    // Coming from (sin az, 0, −cos az); travelling the other way and down.
    [
        (-az.sin() * tilt.sin()) as f32,
        (-tilt.cos()) as f32,
        (az.cos() * tilt.sin()) as f32,
    ]
}

/// `k` snowfall directions (unit vectors pointing where the snow goes) drawn around the main
/// direction with angular std `spread_deg` (module doc). `spread_deg = 0` gives `k` copies of the
/// main direction. Deterministic for a given `seed`.
pub fn snowfall_directions(
    k: usize,
    spread_deg: f32,
    wind: Option<Wind>,
    seed: u64,
) -> Vec<[f32; 3]> {
    let m = main_direction(wind).map(f64::from);
    // Orthonormal e1, e2 perpendicular to m.
    let a = if m[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    };
    let am = a[0] * m[0] + a[1] * m[1] + a[2] * m[2];
    let e1 = norm64([a[0] - am * m[0], a[1] - am * m[1], a[2] - am * m[2]]);
    let e2 = [
        m[1] * e1[2] - m[2] * e1[1],
        m[2] * e1[0] - m[0] * e1[2],
        m[0] * e1[1] - m[1] * e1[0],
    ];
    let sigma = f64::from(spread_deg.max(0.0)).to_radians();
    let mut rng = SplitMix64::new(seed);
    let max_tilt = f64::from(MAX_DIRECTION_TILT_DEG).to_radians();
    (0..k)
        .map(|_| {
            let (gx, gy) = rng.next_normal_pair();
            let (ox, oy) = (gx * sigma, gy * sigma);
            let theta = (ox * ox + oy * oy).sqrt();
            let mut d = if theta > 0.0 {
                let (s, c) = (theta.sin() / theta, theta.cos());
                [
                    c * m[0] + s * (ox * e1[0] + oy * e2[0]),
                    c * m[1] + s * (ox * e1[1] + oy * e2[1]),
                    c * m[2] + s * (ox * e1[2] + oy * e2[2]),
                ]
            } else {
                m
            };
            // Clamp to MAX_DIRECTION_TILT_DEG from vertical (and always downward).
            let horiz = (d[0] * d[0] + d[2] * d[2]).sqrt();
            let tilt = horiz.atan2(-d[1]);
            if tilt > max_tilt {
                let (s, c) = (max_tilt.sin(), max_tilt.cos());
                d = [d[0] / horiz * s, -c, d[2] / horiz * s];
            }
            norm64(d).map(|v| v as f32)
        })
        .collect()
}

fn norm64(a: [f64; 3]) -> [f64; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

/// Weights of `dirs` for the workshop's angle weighting: `exp(−θ²/2σ²)` with θ the angle to the
/// main direction and σ = `spread_deg` (all 1 when `spread_deg` is 0).
pub fn angle_weights(dirs: &[[f32; 3]], spread_deg: f32, wind: Option<Wind>) -> Vec<f32> {
    let m = main_direction(wind);
    let sigma = f64::from(spread_deg).to_radians();
    dirs.iter()
        .map(|d| {
            if sigma <= 0.0 {
                return 1.0;
            }
            let c = f64::from(d[0] * m[0] + d[1] * m[1] + d[2] * m[2]).clamp(-1.0, 1.0);
            let th = c.acos();
            (-0.5 * (th / sigma).powi(2)).exp() as f32
        })
        .collect()
}

/// Compute [`Layer::probability`](super::maps::Layer::probability) of every layer cell from the
/// snowfall directions `dirs` (unit, pointing where snow goes), weighted by `weights` (same length,
/// ≥ 0; `None` = equal). `receiver` picks base or snow surface. Checks for cancellation between
/// directions; reports no progress (the caller knows the stage's share).
pub fn snow_probability(
    mesh: &Mesh,
    maps: &mut SnowMaps,
    dirs: &[[f32; 3]],
    weights: Option<&[f32]>,
    receiver: Receiver,
    ctl: &dyn Control,
) -> Result<(), Canceled> {
    let n = maps.len();
    let n_layers = maps.layers.len();
    let Some(bounds) = mesh.bounds() else {
        for l in &mut maps.layers {
            l.probability.iter_mut().for_each(|p| *p = 0.0);
        }
        return Ok(());
    };
    let wq: Vec<u32> = (0..dirs.len())
        .map(|i| {
            let w = weights.and_then(|w| w.get(i)).copied().unwrap_or(1.0);
            (f64::from(w.max(0.0)) * WEIGHT_ONE).round() as u32
        })
        .collect();
    let total: u64 = wq.iter().map(|&w| u64::from(w)).sum();
    if dirs.is_empty() || total == 0 {
        for l in &mut maps.layers {
            l.probability.iter_mut().for_each(|p| *p = 1.0);
        }
        return Ok(());
    }

    // Receiver points (x, y, z) and biases per layer are direction-independent except for the
    // bias's tan α, which needs the normal; keep the maps read-only in the parallel part.
    let threads = rayon::current_num_threads().max(1);
    let chunk = dirs.len().div_ceil(threads);
    let maps_ref: &SnowMaps = maps;
    let partial: Vec<Result<Vec<Vec<u32>>, Canceled>> = dirs
        .par_chunks(chunk)
        .zip(wq.par_chunks(chunk))
        .map(|(ds, ws)| {
            let mut sm = ShadowMap::default();
            let mut lit: Vec<Vec<u32>> = vec![vec![0u32; n]; n_layers];
            for (d, &w) in ds.iter().zip(ws) {
                ctl.checkpoint()?;
                if w == 0 {
                    continue;
                }
                sm.render(mesh, *d, bounds, maps_ref.cell);
                for (k, layer) in maps_ref.layers.iter().enumerate() {
                    lit_cells(maps_ref, k, receiver, &sm, w, &mut lit[k]);
                    let _ = layer;
                }
            }
            Ok(lit)
        })
        .collect();
    // Integer sums: the order does not matter, but keep it fixed anyway.
    let mut sum: Vec<Vec<u64>> = vec![vec![0u64; n]; n_layers];
    for p in partial {
        let p = p?;
        for (s, l) in sum.iter_mut().zip(&p) {
            s.par_iter_mut()
                .zip(l.par_iter())
                .for_each(|(a, &b)| *a += u64::from(b));
        }
    }
    let inv = 1.0 / total as f64;
    for (layer, s) in maps.layers.iter_mut().zip(&sum) {
        layer
            .probability
            .par_iter_mut()
            .zip(s.par_iter())
            .zip(layer.base.par_iter())
            .for_each(|((p, &v), b)| {
                *p = if b.is_nan() {
                    0.0
                } else {
                    (v as f64 * inv) as f32
                };
            });
    }
    Ok(())
}

/// Add `w` to `lit[c]` for every cell of layer `k` that is lit in `sm`.
fn lit_cells(
    maps: &SnowMaps,
    k: usize,
    receiver: Receiver,
    sm: &ShadowMap,
    w: u32,
    lit: &mut [u32],
) {
    let layer = &maps.layers[k];
    for j in 0..maps.nz {
        for i in 0..maps.nx {
            let c = j * maps.nx + i;
            let b = layer.base[c];
            if b.is_nan() {
                continue;
            }
            let y = match receiver {
                Receiver::Base => b,
                Receiver::SnowSurface => b + layer.depth_m(c),
            };
            let [x, z] = maps.centre(i, j);
            let bias = sm.bias(layer.normal[c], maps.extent);
            if !sm.occluded([x, y, z], bias) {
                lit[c] += w;
            }
        }
    }
}
