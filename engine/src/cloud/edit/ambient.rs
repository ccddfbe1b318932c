//! Ambient from paint (SPEC §3.2, paper Fig. 2).
//!
//! For every painted pixel the camera ray is walked voxel by voxel (3-D DDA) and the painted
//! colour (linear) is pinned on every voxel with ρ > 0 that it crosses — through the whole
//! cloud, as the paper does; a voxel crossed by several painted rays takes the mean of their
//! colours. The pins are propagated to the cloud voxels they reach through the cloud by
//! colourization by optimization with the direct light (sun transmittance) as the guide, solved
//! by multigrid ([`crate::cloud::multigrid`]) to a relative residual of 10⁻⁶. The field holds
//! I_m itself; `ambient_scale` multiplies it at render time. Each ambient edit propagates its
//! own strokes: the result replaces the base version's field (earlier versions keep theirs —
//! undo is choosing a version).
//!
//! Cloud voxels, for the propagation: ρ ≥ 1 % of the volume's maximum density, the reading of
//! "with density" of the sun-direction edit ([`super::sun_direction::DENSITY_THRESHOLD`]):
//! simulated volumes carry an invisible haze (the smoke sample: 10⁻⁵ in 38 % of its box, ρ ≥
//! 1 % in 12 %) that would otherwise triple the system and tie every puff to every other.
//!
//! *Locality* (our reading, issue 18): the edit propagates the **change** the paint asks for,
//! not the colour. With F the ambient the base version showed (its field, or its uniform
//! `ambient`, expressed under the new version's `ambient_scale`), the pins carry D = P − F
//! (P the painted colour) and D is propagated by the LLW system *screened* with λ = 1/ℓ²
//! ([`crate::cloud::multigrid::SolveOptions::screening`]), ℓ = `reach` × the solve grid's
//! longest side in voxels: each voxel is tied to "no change" with weight λ, so the change decays
//! over about ℓ from the painted voxels (faster across the guide's edges, where the LLW
//! affinities are small), and the new field is F + D (clamped at 0). Pure LLW (λ = 0, the
//! former reading) makes the field harmonic with the pins as the only boundary values, so paint
//! of one colour turned the whole connected cloud that colour — on a segmentation mask, whose
//! cloud is one piece, the whole silhouette. With `reach` large the edit tends to that
//! unbounded propagation; with F uniform and λ = 0 it is exactly LLW's system. Voxels the paint
//! cannot reach (another puff, the haze, empty space) keep F.
//!
//! *Speed* (issue 18: ≤ 2 s at 25 M voxels, ≤ 0.5 s at 128³): D is smooth by construction (a
//! screened, guide-weighted average of the pins' changes), so a volume of more than
//! [`MAX_SOLVE_VOXELS`] voxels is solved on a grid coarser by the smallest integer factor k that
//! brings it under that count: per k³ block, the guide is the mean direct light of its cloud
//! voxels, the block is cloud when any voxel is, and its pin is the mean change of its pinned
//! voxels. D is brought back to the voxels by joint bilateral upsampling (Kopf et al. 2007) with
//! the direct light as the guide: the trilinear weights of the 8 nearest block centres, each
//! times `exp(−(Y − Y_block)²/2σ²)`, σ = [`UPSAMPLE_SIGMA`], over the blocks that are cloud.
//! Where those bilateral factors of a run of voxels all lie within a ratio of e^τ of each other
//! (τ = [`FLAT_LOG_RATIO`] = 0.01: a guide flat around the voxels and their blocks, e.g. deep in
//! the shadow or in thin haze), the plain trilinear weights are taken instead: both weightings
//! are convex combinations of the same 8 changes, and they differ by at most tanh(τ/2) ≈ 0.5 %
//! of the spread of those changes (the total-variation distance of the two weight vectors).
//! Measured on the dense 292³ box of the bench: 27 % of the voxels take it, the field moves by
//! 6·10⁻⁵ relative RMS of the change (session 17, BENCHMARKS.md "Clouds"); the accuracy test's
//! figures did not move at three decimals.
//! The pinned voxels then take their painted colour exactly. The loss against the full-resolution
//! solve is measured by `cloud_edit::coarse_ambient_solve_is_close_to_the_full_one` (see
//! BENCHMARKS.md "Clouds").

use rayon::prelude::*;

use super::sun_direction::DENSITY_THRESHOLD;
use super::{AmbientEdit, EditError};
use crate::cloud::fastexp::exp_neg;
use crate::cloud::grid::GridFrame;
use crate::cloud::light::SunLight;
use crate::cloud::multigrid::{propagate, SolveOptions, SolveStats};
use crate::cloud::state::{AmbientField, CloudState};
use crate::geom::Volume;
use crate::Control;

/// The default `reach` of an ambient edit (fraction of the box's longest side).
pub const DEFAULT_REACH: f64 = 0.25;

/// Volumes of more voxels than this are solved on a coarser grid (module doc).
pub const MAX_SOLVE_VOXELS: usize = 1 << 16;

/// σ of the joint bilateral upsampling, in units of the guide (the direct light, 0–1).
pub const UPSAMPLE_SIGMA: f32 = 0.1;

/// The pins of the painted strokes: (flat voxel index, linear colour), in index order; a voxel
/// crossed by several painted rays takes the mean of their colours. Allocates 16 bytes per
/// (ray, voxel with density) crossing.
pub fn pins(volume: &Volume, edit: &AmbientEdit) -> Vec<(usize, [f32; 3])> {
    let g = GridFrame::of(volume);
    let camera = edit.view.camera(volume.bounds);
    let rg = camera.ray_gen(edit.view.width, edit.view.height);
    let rays: Vec<([f32; 3], [u32; 2])> = edit
        .strokes
        .iter()
        .flat_map(|s| s.pixels.iter().map(move |p| (s.color, *p)))
        .collect();
    let mut hits: Vec<(usize, [f32; 3])> = rays
        .par_iter()
        .flat_map_iter(|(c, p)| {
            let d = rg.dir(f64::from(p[0]) + 0.5, f64::from(p[1]) + 0.5);
            let mut out = Vec::new();
            g.walk(rg.eye, d, |_, i, _| {
                if volume.density[i] > 0.0 {
                    out.push((i, *c));
                }
                true
            });
            out
        })
        .collect();
    hits.par_sort_by_key(|h| h.0);
    let mut out: Vec<(usize, [f32; 3])> = Vec::new();
    let mut k = 0;
    while k < hits.len() {
        let i = hits[k].0;
        let (mut sum, mut n) = ([0f32; 3], 0u32);
        while k < hits.len() && hits[k].0 == i {
            for (a, c) in sum.iter_mut().zip(hits[k].1) {
                *a += c;
            }
            n += 1;
            k += 1;
        }
        out.push((i, sum.map(|v| v / n as f32)));
    }
    out
}

/// Pins the paint and propagates it (see the module doc) on the version (`base`,
/// `base_field`), solving on at most [`MAX_SOLVE_VOXELS`] voxels.
pub fn propagate_paint(
    volume: &Volume,
    light: &SunLight,
    edit: &AmbientEdit,
    base: &CloudState,
    base_field: Option<&AmbientField>,
    ctl: &dyn Control,
) -> Result<(AmbientField, SolveStats), EditError> {
    propagate_paint_with(volume, light, edit, base, base_field, MAX_SOLVE_VOXELS, ctl)
}

/// The smallest integer factor k such that the grid of `dims` coarsened by k (each size
/// rounded up) has at most `max` voxels.
pub fn coarsening(dims: [usize; 3], max: usize) -> usize {
    let count = |k: usize| dims.iter().map(|n| n.div_ceil(k)).product::<usize>();
    let mut k = 1;
    while count(k) > max.max(1) && k < dims.iter().copied().max().unwrap_or(1) {
        k += 1;
    }
    k
}

/// [`propagate_paint`] solving on at most `max_solve_voxels` voxels (`usize::MAX`: always at
/// full resolution, the reference the coarse solve is measured against).
pub fn propagate_paint_with(
    volume: &Volume,
    light: &SunLight,
    edit: &AmbientEdit,
    base: &CloudState,
    base_field: Option<&AmbientField>,
    max_solve_voxels: usize,
    ctl: &dyn Control,
) -> Result<(AmbientField, SolveStats), EditError> {
    let pins = pins(volume, edit);
    if pins.is_empty() {
        return Err(EditError::MissesCloud);
    }
    ctl.checkpoint()?;
    // The base version's visible ambient as I_m under the new scale (module doc).
    let scale = edit.ambient_scale.unwrap_or(base.ambient_scale);
    let per = if scale > 0.0 { 1.0 / scale } else { 1.0 };
    let field = base_field.filter(|f| f.rgb.len() == volume.len());
    let uniform = base.ambient.map(|v| (v * per) as f32);
    let fill = |i: usize| -> [f32; 3] {
        match field {
            Some(f) => f.rgb[i].map(|v| (f64::from(v) * base.ambient_scale * per) as f32),
            None => uniform,
        }
    };
    let change: Vec<(usize, [f32; 3])> = pins
        .iter()
        .map(|&(i, c)| {
            let f = fill(i);
            (i, [c[0] - f[0], c[1] - f[1], c[2] - f[2]])
        })
        .collect();
    let cloud = cloud_voxels(volume);
    let dims = volume.dims;
    let k = coarsening(dims, max_solve_voxels);
    let cdims = dims.map(|n| n.div_ceil(k));
    let reach = (edit.reach * cdims.iter().copied().max().unwrap_or(1) as f64).max(1e-3);
    let opts = SolveOptions {
        screening: (1.0 / (reach * reach)) as f32,
        ..SolveOptions::default()
    };
    let add = |i: usize, d: [f32; 3]| -> [f32; 3] {
        let f = fill(i);
        [0, 1, 2].map(|q| (f[q] + d[q]).max(0.0))
    };
    let zero = |_: usize| [0f32; 3];
    let mut rgb: Vec<[f32; 3]>;
    let stats;
    if k == 1 {
        let (d, s) = propagate(
            dims,
            &light.transmittance,
            Some(&cloud),
            &change,
            &zero,
            opts,
            ctl,
        )?;
        stats = s;
        rgb = d
            .into_par_iter()
            .enumerate()
            .map(|(i, d)| add(i, d))
            .collect();
    } else {
        let coarse = Coarse::of(dims, k, &light.transmittance, &cloud, &change);
        ctl.checkpoint()?;
        let (d, s) = propagate(
            cdims,
            &coarse.guide,
            Some(&coarse.cloud),
            &coarse.pins,
            &zero,
            opts,
            ctl,
        )?;
        stats = s;
        ctl.checkpoint()?;
        rgb = upsample(dims, k, &light.transmittance, &cloud, &coarse, &d, &add);
    }
    for &(i, c) in &pins {
        rgb[i] = c.map(|v| v.max(0.0));
    }
    Ok((AmbientField { rgb }, stats))
}

/// The coarse problem: per k³ block the guide, whether it is cloud, and the pins.
struct Coarse {
    dims: [usize; 3],
    guide: Vec<f32>,
    cloud: Vec<bool>,
    pins: Vec<(usize, [f32; 3])>,
}

impl Coarse {
    /// Block means (module doc). One pass over the voxels, blocks in parallel.
    fn of(
        dims: [usize; 3],
        k: usize,
        guide: &[f32],
        cloud: &[bool],
        change: &[(usize, [f32; 3])],
    ) -> Self {
        let [nx, ny, nz] = dims;
        let cd = dims.map(|n| n.div_ceil(k));
        let nc = cd[0] * cd[1] * cd[2];
        let plane = nx * ny;
        let cells: Vec<(f32, bool)> = (0..nc)
            .into_par_iter()
            .map(|c| {
                let (cx, cy, cz) = (c % cd[0], (c / cd[0]) % cd[1], c / (cd[0] * cd[1]));
                let (mut sc, mut nc_, mut sa, mut na) = (0f64, 0u32, 0f64, 0u32);
                for z in cz * k..((cz + 1) * k).min(nz) {
                    for y in cy * k..((cy + 1) * k).min(ny) {
                        let row = y * nx + z * plane;
                        for x in cx * k..((cx + 1) * k).min(nx) {
                            let i = row + x;
                            let t = f64::from(guide[i]);
                            sa += t;
                            na += 1;
                            if cloud[i] {
                                sc += t;
                                nc_ += 1;
                            }
                        }
                    }
                }
                if nc_ > 0 {
                    ((sc / f64::from(nc_)) as f32, true)
                } else {
                    ((sa / f64::from(na.max(1))) as f32, false)
                }
            })
            .collect();
        let (guide, cloud): (Vec<f32>, Vec<bool>) = cells.into_iter().unzip();
        let block = |i: usize| {
            let (x, y, z) = (i % nx, (i / nx) % ny, i / plane);
            x / k + cd[0] * (y / k + cd[1] * (z / k))
        };
        let mut sums: Vec<(usize, [f32; 3], u32)> = Vec::new();
        let mut by_block: Vec<(usize, [f32; 3])> =
            change.iter().map(|&(i, d)| (block(i), d)).collect();
        by_block.par_sort_by_key(|p| p.0);
        for (b, d) in by_block {
            match sums.last_mut() {
                Some((lb, s, n)) if *lb == b => {
                    for (a, c) in s.iter_mut().zip(d) {
                        *a += c;
                    }
                    *n += 1;
                }
                _ => sums.push((b, d, 1)),
            }
        }
        let pins = sums
            .into_iter()
            .map(|(b, s, n)| (b, s.map(|v| v / n as f32)))
            .collect();
        Self {
            dims: cd,
            guide,
            cloud,
            pins,
        }
    }
}

/// Where the bilateral factors of a voxel's blocks all lie within this factor's log of each other
/// (`exp(−(Y − Y_block)²/2σ²)`, the largest over the smallest), [`upsample`] takes the plain
/// trilinear weights: the two weightings then differ by at most tanh(τ/2) ≈ 0.5 % of the spread
/// of the blocks' changes (module doc).
const FLAT_LOG_RATIO: f32 = 0.01;

/// Voxels of a row upsampled together: the lanes of the vectorised inner loop of [`upsample`].
const LANES: usize = 8;

/// Joint bilateral upsampling of the coarse change `d` to every voxel (module doc), added to
/// the fill by `add`; voxels outside the cloud keep the fill.
///
/// Layout of the work (the arithmetic per voxel is the module doc's, operation for operation):
/// a row of voxels splits into runs that share their 8 surrounding block centres; per run the
/// blocks' guide, change and cloud flag are read once, and its voxels are taken [`LANES`] at a
/// time with the 8 blocks as the outer loop, so each voxel still sums its blocks in the same
/// order while the weights (`exp_neg` included) are computed for the lanes side by side.
fn upsample<F>(
    dims: [usize; 3],
    k: usize,
    guide: &[f32],
    cloud: &[bool],
    coarse: &Coarse,
    d: &[[f32; 3]],
    add: &F,
) -> Vec<[f32; 3]>
where
    F: Fn(usize, [f32; 3]) -> [f32; 3] + Sync,
{
    let [nx, ny, _] = dims;
    let cd = coarse.dims;
    let plane = nx * ny;
    let inv2s2 = 1.0 / (2.0 * UPSAMPLE_SIGMA * UPSAMPLE_SIGMA);
    // Per axis: the two block centres around fine coordinate x and the weight of the second.
    let axis = |x: usize, n: usize| -> (usize, usize, f32) {
        let u = ((x as f32 + 0.5) / k as f32 - 0.5).max(0.0);
        let j0 = (u as usize).min(n - 1);
        let j1 = (j0 + 1).min(n - 1);
        (j0, j1, (u - j0 as f32).clamp(0.0, 1.0))
    };
    let ax: Vec<(usize, usize, f32)> = (0..nx).map(|x| axis(x, cd[0])).collect();
    // Runs [xa, xb) of a row with the same two block centres along x.
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for x in 0..nx {
        match runs.last_mut() {
            Some((xa, xb)) if ax[*xa].0 == ax[x].0 && ax[*xa].1 == ax[x].1 => *xb = x + 1,
            _ => runs.push((x, x + 1)),
        }
    }
    // The change is a convex combination of the 8 blocks' changes, so where every one of them
    // is below `negligible` the voxel's change is too: such blocks count as no change, and a
    // row of voxels whose four surrounding rows of blocks hold none above it takes the fill
    // without the bilateral weights. The screened solve makes the change local (module doc),
    // so on a large volume most rows are skipped; the error this makes is below
    // `negligible` = 1e-4 × the largest change (linear ambient units, far below one 8-bit code).
    let largest = d
        .iter()
        .flat_map(|c| c.iter())
        .fold(0f32, |m, v| m.max(v.abs()));
    let negligible = 1e-4 * largest;
    let row_active: Vec<bool> = (0..cd[1] * cd[2])
        .map(|r| {
            (0..cd[0]).any(|cx| {
                let j = cx + cd[0] * r;
                coarse.cloud[j] && d[j].iter().any(|v| v.abs() > negligible)
            })
        })
        .collect();
    let mut out = vec![[0f32; 3]; guide.len()];
    out.par_chunks_mut(plane.max(1))
        .enumerate()
        .for_each(|(z, slab)| {
            let (z0, z1, tz) = axis(z, cd[2]);
            for (y, row) in slab.chunks_mut(nx.max(1)).enumerate() {
                let (y0, y1, ty) = axis(y, cd[1]);
                let first = nx * y + plane * z;
                let active = [(y0, z0), (y1, z0), (y0, z1), (y1, z1)]
                    .iter()
                    .any(|&(cy, cz)| row_active[cy + cd[1] * cz]);
                if !active {
                    for (x, o) in row.iter_mut().enumerate() {
                        *o = add(first + x, [0.0; 3]);
                    }
                    continue;
                }
                for &(xa, xb) in &runs {
                    let (x0, x1, _) = ax[xa];
                    // The run's 8 blocks, c = x bit | y bit << 1 | z bit << 2.
                    let mut on = [false; 8];
                    let mut wyz = [(0f32, 0f32); 8];
                    let mut g = [0f32; 8];
                    let mut dc = [[0f32; 3]; 8];
                    for c in 0..8 {
                        let (cx, cy, cz) = (
                            if c & 1 == 0 { x0 } else { x1 },
                            if c & 2 == 0 { y0 } else { y1 },
                            if c & 4 == 0 { z0 } else { z1 },
                        );
                        let j = cx + cd[0] * (cy + cd[1] * cz);
                        on[c] = coarse.cloud[j];
                        wyz[c] = (
                            if c & 2 == 0 { 1.0 - ty } else { ty },
                            if c & 4 == 0 { 1.0 - tz } else { tz },
                        );
                        g[c] = coarse.guide[j];
                        dc[c] = d[j];
                    }
                    let (mut gmin, mut gmax) = (f32::INFINITY, f32::NEG_INFINITY);
                    for c in (0..8).filter(|&c| on[c]) {
                        gmin = gmin.min(g[c]);
                        gmax = gmax.max(g[c]);
                    }
                    for start in (xa..xb).step_by(LANES) {
                        let n = (xb - start).min(LANES);
                        // Lanes past the run repeat its first voxel (computed, not stored).
                        let (mut yi, mut tx) = ([guide[first + start]; LANES], [0f32; LANES]);
                        for l in 0..n {
                            yi[l] = guide[first + start + l];
                            tx[l] = ax[start + l].2;
                        }
                        let (mut ylo, mut yhi) = (yi[0], yi[0]);
                        for &y in &yi {
                            ylo = if y < ylo { y } else { ylo };
                            yhi = if y > yhi { y } else { yhi };
                        }
                        let far = (yhi - gmin).max(gmax - ylo);
                        let near = (ylo - gmax).max(gmin - yhi).max(0.0);
                        let flat = inv2s2 * (far * far - near * near) <= FLAT_LOG_RATIO;
                        let mut acc = [[0f32; LANES]; 3];
                        let mut wsum = [0f32; LANES];
                        if flat {
                            for c in 0..8 {
                                if !on[c] {
                                    continue;
                                }
                                let ((wy, wz), [d0, d1, d2]) = (wyz[c], dc[c]);
                                let odd = c & 1 == 1;
                                for l in 0..LANES {
                                    let wx = if odd { tx[l] } else { 1.0 - tx[l] };
                                    let tri = wx * wy * wz;
                                    acc[0][l] += tri * d0;
                                    acc[1][l] += tri * d1;
                                    acc[2][l] += tri * d2;
                                    wsum[l] += tri;
                                }
                            }
                            for l in 0..n {
                                let i = first + start + l;
                                row[start + l] = if !cloud[i] || wsum[l] <= 0.0 {
                                    add(i, [0.0; 3])
                                } else {
                                    add(i, [0, 1, 2].map(|q| acc[q][l] / wsum[l]))
                                };
                            }
                            continue;
                        }
                        for c in 0..8 {
                            if !on[c] {
                                continue;
                            }
                            let ((wy, wz), gc, [d0, d1, d2]) = (wyz[c], g[c], dc[c]);
                            let odd = c & 1 == 1;
                            for l in 0..LANES {
                                let wx = if odd { tx[l] } else { 1.0 - tx[l] };
                                let tri = wx * wy * wz;
                                let dy = yi[l] - gc;
                                let w = tri * exp_neg(-dy * dy * inv2s2);
                                acc[0][l] += w * d0;
                                acc[1][l] += w * d1;
                                acc[2][l] += w * d2;
                                wsum[l] += w;
                            }
                        }
                        for l in 0..n {
                            let x = start + l;
                            let i = first + x;
                            if !cloud[i] {
                                row[x] = add(i, [0.0; 3]);
                                continue;
                            }
                            let change = if wsum[l] > 1e-6 {
                                [0, 1, 2].map(|q| acc[q][l] / wsum[l])
                            } else {
                                // Every bilateral weight vanished: the plain trilinear weights.
                                let (mut plain, mut psum) = ([0f32; 3], 0f32);
                                for c in (0..8).filter(|&c| on[c]) {
                                    let wx = if c & 1 == 0 { 1.0 - tx[l] } else { tx[l] };
                                    let tri = wx * wyz[c].0 * wyz[c].1;
                                    for q in 0..3 {
                                        plain[q] += tri * dc[c][q];
                                    }
                                    psum += tri;
                                }
                                if psum > 0.0 {
                                    plain.map(|v| v / psum)
                                } else {
                                    [0.0; 3]
                                }
                            };
                            row[x] = add(i, change);
                        }
                    }
                }
            }
        });
    out
}

/// The voxels that count as cloud for the propagation (module doc).
pub fn cloud_voxels(volume: &Volume) -> Vec<bool> {
    let max = volume.density.par_iter().copied().reduce(|| 0.0, f32::max);
    let min = DENSITY_THRESHOLD * max;
    volume
        .density
        .par_iter()
        .map(|&r| r > 0.0 && r >= min)
        .collect()
}
