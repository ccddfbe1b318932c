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

use multiversion::multiversion;
use rayon::prelude::*;

use super::maps::SnowMaps;
use super::shadow::{ShadowMap, MAX_BIAS_TAN};
use crate::geom::mesh::Mesh;
use crate::geom::vec::{unit_f64, DVec3};
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
    let (a, mv) = (DVec3::from(a), DVec3::from(m));
    let e1 = unit_f64(a - mv * a.dot(mv));
    let e2 = mv.cross(e1).to_array();
    let e1 = e1.to_array();
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
            unit_f64(DVec3::from(d)).as_vec3().to_array()
        })
        .collect()
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

/// Compute [`MapLayer::probability`](super::maps::MapLayer::probability) of every layer cell from the
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

    // Receiver points and normals are direction-independent: gather them once (structure of
    // arrays, so the per-direction test vectorises), with each layer's non-empty span per row.
    let recv = Receivers::new(maps, receiver);
    let threads = rayon::current_num_threads().max(1);
    let chunk = dirs.len().div_ceil(threads);
    let maps_ref: &SnowMaps = maps;
    let partial: Vec<Result<Vec<Vec<u32>>, Canceled>> = dirs
        .par_chunks(chunk)
        .zip(wq.par_chunks(chunk))
        .map(|(ds, ws)| {
            let mut sm = ShadowMap::default();
            let mut lit: Vec<Vec<u32>> = vec![vec![0u32; n]; n_layers];
            let mut row = RowScratch::new(maps_ref.nx);
            for (d, &w) in ds.iter().zip(ws) {
                ctl.checkpoint()?;
                if w == 0 {
                    continue;
                }
                sm.render(mesh, *d, bounds, maps_ref.cell);
                for (k, l) in lit.iter_mut().enumerate() {
                    lit_cells(&recv, k, &sm, maps_ref.extent, w, l, &mut row);
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

/// Snow probability at arbitrary surface points (workshop §2.1(4) / §2.3(5): the sparse flakes
/// of walls and undersides, which the snow maps do not hold): the weighted share of `dirs` along
/// which the point `points[v]`, moved off its surface by one texel along `normals[v]` (unit, or
/// zero), is not in shadow. Shadow maps as [`snow_probability`]'s, `texel` metres a texel (the
/// maps' cell). So a wall under an eave (in the eave's shadow for every near-vertical direction)
/// gets less than an open wall, which the directions leaning toward it reach. Rayon over chunks
/// of directions, integer weights: bit-identical for any thread count. Allocates one shadow map
/// and one counter per point per chunk.
pub fn point_probability(
    mesh: &Mesh,
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    dirs: &[[f32; 3]],
    weights: Option<&[f32]>,
    texel: f32,
    ctl: &dyn Control,
) -> Result<Vec<f32>, Canceled> {
    let Some(bounds) = mesh.bounds() else {
        return Ok(vec![0.0; points.len()]);
    };
    let wq: Vec<u32> = (0..dirs.len())
        .map(|i| {
            let w = weights.and_then(|w| w.get(i)).copied().unwrap_or(1.0);
            (f64::from(w.max(0.0)) * WEIGHT_ONE).round() as u32
        })
        .collect();
    let total: u64 = wq.iter().map(|&w| u64::from(w)).sum();
    if dirs.is_empty() || total == 0 {
        return Ok(vec![1.0; points.len()]);
    }
    let (lo, hi) = bounds;
    let extent = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt();
    let threads = rayon::current_num_threads().max(1);
    let chunk = dirs.len().div_ceil(threads);
    let partial: Vec<Result<Vec<u64>, Canceled>> = dirs
        .par_chunks(chunk)
        .zip(wq.par_chunks(chunk))
        .map(|(ds, ws)| {
            let mut sm = ShadowMap::default();
            let mut lit = vec![0u64; points.len()];
            for (d, &w) in ds.iter().zip(ws) {
                ctl.checkpoint()?;
                if w == 0 {
                    continue;
                }
                sm.render(mesh, *d, bounds, texel);
                for ((l, p), n) in lit.iter_mut().zip(points).zip(normals) {
                    let q = [0, 1, 2].map(|k| p[k] + n[k] * sm.texel);
                    if !sm.occluded(q, sm.bias(*n, extent)) {
                        *l += u64::from(w);
                    }
                }
            }
            Ok(lit)
        })
        .collect();
    let mut sum = vec![0u64; points.len()];
    for p in partial {
        for (s, l) in sum.iter_mut().zip(p?) {
            *s += l;
        }
    }
    let inv = 1.0 / total as f64;
    Ok(sum.iter().map(|&v| (v as f64 * inv) as f32).collect())
}

/// The receiver points of every layer, gathered once per [`snow_probability`] call: cell-centre
/// x per column and z per row, and per layer the receiver height (base, or base + snow) and the
/// normal as separate arrays, plus per row the span of cells that have the layer (empty rows and
/// the empty ends of rows are skipped).
struct Receivers {
    nx: usize,
    xs: Vec<f32>,
    zs: Vec<f32>,
    layers: Vec<ReceiverLayer>,
}

struct ReceiverLayer {
    ys: Vec<f32>,
    nx: Vec<f32>,
    ny: Vec<f32>,
    nz: Vec<f32>,
    /// Per row, `[first, end)` of the cells with a surface (`first == end`: none).
    spans: Vec<(usize, usize)>,
}

impl Receivers {
    fn new(maps: &SnowMaps, receiver: Receiver) -> Self {
        let xs = (0..maps.nx).map(|i| maps.centre(i, 0)[0]).collect();
        let zs = (0..maps.nz).map(|j| maps.centre(0, j)[1]).collect();
        let layers = maps
            .layers
            .iter()
            .map(|layer| {
                let ys = (0..maps.len())
                    .map(|c| match receiver {
                        Receiver::Base => layer.base[c],
                        Receiver::SnowSurface => layer.base[c] + layer.depth_m(c),
                    })
                    .collect();
                let spans = layer
                    .base
                    .chunks(maps.nx.max(1))
                    .map(|r| {
                        let first = r.iter().position(|b| !b.is_nan()).unwrap_or(r.len());
                        let end = r.iter().rposition(|b| !b.is_nan()).map_or(first, |e| e + 1);
                        (first, end)
                    })
                    .collect();
                ReceiverLayer {
                    ys,
                    nx: layer.normal.iter().map(|n| n[0]).collect(),
                    ny: layer.normal.iter().map(|n| n[1]).collect(),
                    nz: layer.normal.iter().map(|n| n[2]).collect(),
                    spans,
                }
            })
            .collect();
        Self {
            nx: maps.nx,
            xs,
            zs,
            layers,
        }
    }
}

/// Per-row scratch of [`lit_cells`]: the shadow-map texel of each cell (−1: off the map) and the
/// depth it must exceed to shadow the cell.
struct RowScratch {
    idx: Vec<i32>,
    thr: Vec<f32>,
}

impl RowScratch {
    fn new(nx: usize) -> Self {
        Self {
            idx: vec![-1; nx],
            thr: vec![0.0; nx],
        }
    }
}

/// Add `w` to `lit[c]` for every cell of layer `k` that is lit in `sm`.
///
/// The same test as [`ShadowMap::bias`] and [`ShadowMap::occluded`], expression for expression
/// (so the same bits), split in two passes per row: a branch-free pass computing each cell's texel
/// and threshold (vectorised by the compiler: the square root and division of the bias four cells
/// at a time), then the lookups. Cells without a surface inside a row's span get a meaningless
/// count; [`snow_probability`] sets their P to 0. Compiled for AVX2 too and chosen at run time
/// (no FMA: the same bits).
#[multiversion(targets("x86_64+avx2"))]
fn lit_cells(
    recv: &Receivers,
    k: usize,
    sm: &ShadowMap,
    extent: f32,
    w: u32,
    lit: &mut [u32],
    row: &mut RowScratch,
) {
    let layer = &recv.layers[k];
    let nx = recv.nx;
    let inv = 1.0 / sm.texel;
    let (u, t, wv) = (sm.u, sm.t, sm.w);
    let (u0, t0) = (sm.u0, sm.t0);
    let (wf, hf) = (sm.width as f32, sm.height as f32);
    let width = sm.width as i32;
    let texel = sm.texel;
    let eps = 1e-5 * extent;
    for (j, &(first, end)) in layer.spans.iter().enumerate() {
        if first >= end {
            continue;
        }
        let z = recv.zs[j];
        let (a, b) = (j * nx + first, j * nx + end);
        let len = end - first;
        let (idx, thr) = (&mut row.idx[..len], &mut row.thr[..len]);
        let xs = &recv.xs[first..end];
        let ys = &layer.ys[a..b];
        let (nxs, nys, nzs) = (&layer.nx[a..b], &layer.ny[a..b], &layer.nz[a..b]);
        for q in 0..len {
            let (x, y) = (xs[q], ys[q]);
            // ShadowMap::bias.
            let c = (nxs[q] * wv[0] + nys[q] * wv[1] + nzs[q] * wv[2])
                .abs()
                .max(1e-3);
            let tan = ((1.0 - c * c).max(0.0).sqrt() / c).min(MAX_BIAS_TAN);
            let bias = texel * (0.71 * tan + 0.1) + eps;
            // ShadowMap::occluded.
            let gx = ((x * u[0] + y * u[1] + z * u[2]) - u0) * inv - 0.5;
            let gy = ((x * t[0] + y * t[1] + z * t[2]) - t0) * inv - 0.5;
            let (px, py) = (gx + 0.5, gy + 0.5);
            let on = (gx >= -0.5) & (gy >= -0.5) & (px < wf) & (py < hf);
            idx[q] = if on {
                py as i32 * width + px as i32
            } else {
                -1
            };
            thr[q] = (x * wv[0] + y * wv[1] + z * wv[2]) + bias;
        }
        for ((l, &i), &th) in lit[a..b].iter_mut().zip(idx.iter()).zip(thr.iter()) {
            let d = sm
                .depth
                .get(i as usize)
                .copied()
                .unwrap_or(f32::NEG_INFINITY);
            *l += if d > th { 0 } else { w };
        }
    }
}
