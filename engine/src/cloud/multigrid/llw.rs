//! The LLW affinities of the fine grid (Levin, Lischinski and Weiss 2004, `getColorExact.m`,
//! read as in the module doc of [`super`]).

use rayon::prelude::*;

/// LLW's per-voxel `c_r = max(0.6·var_r, min_s (Y_r − Y_s)²/ln 100, 2·10⁻⁶)` over the voxel and
/// its (up to 6) face neighbours; only at the voxels of `mask` (0 elsewhere) when given.
fn llw_c(dims: [usize; 3], guide: &[f32], mask: Option<&[bool]>) -> Vec<f32> {
    let [nx, ny, nz] = dims;
    let plane = nx * ny;
    let ln100 = 100f32.ln();
    let mut c = vec![0f32; guide.len()];
    c.par_chunks_mut(plane.max(1))
        .enumerate()
        .for_each(|(z, out)| {
            for y in 0..ny {
                for x in 0..nx {
                    let i = x + nx * y + plane * z;
                    if mask.is_some_and(|m| !m[i]) {
                        continue;
                    }
                    let yr = guide[i];
                    let (mut sum, mut sum2, mut cnt) = (yr, yr * yr, 1.0f32);
                    let mut min_d2 = f32::INFINITY;
                    let mut add = |v: f32| {
                        sum += v;
                        sum2 += v * v;
                        cnt += 1.0;
                        min_d2 = min_d2.min((v - yr) * (v - yr));
                    };
                    if x > 0 {
                        add(guide[i - 1]);
                    }
                    if x + 1 < nx {
                        add(guide[i + 1]);
                    }
                    if y > 0 {
                        add(guide[i - nx]);
                    }
                    if y + 1 < ny {
                        add(guide[i + nx]);
                    }
                    if z > 0 {
                        add(guide[i - plane]);
                    }
                    if z + 1 < nz {
                        add(guide[i + plane]);
                    }
                    let mean = sum / cnt;
                    let var = (sum2 / cnt - mean * mean).max(0.0);
                    let mut cr = 0.6 * var;
                    if min_d2.is_finite() {
                        cr = cr.max(min_d2 / ln100);
                    }
                    out[x + nx * y] = cr.max(2e-6);
                }
            }
        });
    c
}

/// Symmetric LLW affinities of every voxel's +x, +y and +z edges,
/// `a_rs = exp(−(Y_r − Y_s)²/½(c_r + c_s))`, 0 where the neighbour is outside the grid. The
/// guide is one value per voxel (x fastest). Allocates 16 bytes per voxel.
pub fn llw_weights(dims: [usize; 3], guide: &[f32]) -> Vec<[f32; 3]> {
    llw_weights_in(dims, guide, None)
}

/// [`llw_weights`] on the edges between voxels of `mask` only (0 elsewhere), computed only
/// there.
pub(super) fn llw_weights_in(
    dims: [usize; 3],
    guide: &[f32],
    mask: Option<&[bool]>,
) -> Vec<[f32; 3]> {
    let c = llw_c(dims, guide, mask);
    let inside = |i: usize| mask.is_none_or(|m| m[i]);
    let [nx, ny, nz] = dims;
    let plane = nx * ny;
    let mut a = vec![[0f32; 3]; guide.len()];
    a.par_chunks_mut(plane.max(1))
        .enumerate()
        .for_each(|(z, out)| {
            for y in 0..ny {
                for x in 0..nx {
                    let i = x + nx * y + plane * z;
                    if !inside(i) {
                        continue;
                    }
                    let edge = |j: usize| {
                        if !inside(j) {
                            return 0.0;
                        }
                        let d = guide[j] - guide[i];
                        (-d * d / (0.5 * (c[i] + c[j]))).exp()
                    };
                    out[x + nx * y] = [
                        if x + 1 < nx { edge(i + 1) } else { 0.0 },
                        if y + 1 < ny { edge(i + nx) } else { 0.0 },
                        if z + 1 < nz { edge(i + plane) } else { 0.0 },
                    ];
                }
            }
        });
    a
}
