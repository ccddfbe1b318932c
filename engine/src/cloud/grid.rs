//! Sampling the voxel grid: trilinear interpolation between voxel centres (clamped to the edge
//! values inside the box, zero outside it), ray/box clipping and a voxel walk (Amanatides–Woo
//! DDA) that the edits use to find the voxels a ray crosses.

use crate::geom::Volume;

/// Fraction of the maximum density that counts as cloud: for the sun-direction drag's P, Q and R
/// (SPEC §3.3), the ambient edit's pinned voxels and κ's column rays.
pub const DENSITY_THRESHOLD: f32 = 0.01;

/// At most this many samples per voxel crossed along a ray ([`GridFrame::samples`]).
pub const MAX_SAMPLES_PER_CROSSING: f64 = 8.0;

/// The grid's placement in the world: voxel `i` along axis `k` has its centre at
/// `lo[k] + (i + 0.5)·h[k]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridFrame {
    pub dims: [usize; 3],
    pub lo: [f64; 3],
    pub hi: [f64; 3],
    pub h: [f64; 3],
}

/// The 8 corner indices and weights of one trilinear sample.
#[derive(Debug, Clone, Copy)]
pub struct Trilinear {
    pub idx: [usize; 8],
    pub w: [f32; 8],
}

impl GridFrame {
    pub fn of(v: &Volume) -> Self {
        let (lo, hi) = v.bounds;
        Self {
            dims: v.dims,
            lo,
            hi,
            h: v.voxel_size(),
        }
    }

    /// Smallest voxel edge, world units.
    pub fn min_h(&self) -> f64 {
        self.h[0].min(self.h[1]).min(self.h[2])
    }

    /// How many equal samples a ray segment of length `len` along unit `d` takes at about
    /// `step` smallest voxel edges apart: ⌈len / (step · min h)⌉, the renderer's reading of
    /// Eqs. 1–3's step, but at most [`MAX_SAMPLES_PER_CROSSING`] samples per voxel the segment
    /// crosses (Σₖ len·|dₖ| / hₖ crossings, ÷ `step`). On grids whose voxel sides differ by
    /// 8× or less (every real volume we read) the first term is the smaller and nothing
    /// changes; on a box 10⁸ units long with voxels 1 unit across, the smallest side alone would
    /// ask for billions of samples per ray while the ray crosses at most Σ dims voxels: the
    /// count stays bounded by the grid, as the sun sweep's is ([`super::light`]).
    #[inline]
    pub fn samples(&self, len: f64, d: [f64; 3], step: f64) -> usize {
        let by_edge = len / (step * self.min_h());
        let crossings: f64 = (0..3).map(|k| len * d[k].abs() / self.h[k]).sum();
        let cap = MAX_SAMPLES_PER_CROSSING * crossings / step;
        by_edge.min(cap).ceil().max(1.0) as usize
    }

    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    /// World centre of voxel `(x, y, z)`.
    #[inline]
    pub fn center(&self, c: [usize; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| self.lo[k] + (c[k] as f64 + 0.5) * self.h[k])
    }

    /// The voxel containing `p` (clamped into the grid).
    #[inline]
    pub fn voxel_of(&self, p: [f64; 3]) -> [usize; 3] {
        [0, 1, 2].map(|k| {
            let u = ((p[k] - self.lo[k]) / self.h[k]).floor();
            (u.max(0.0) as usize).min(self.dims[k] - 1)
        })
    }

    /// Trilinear corners of world point `p` (assumed inside the box): coordinates are clamped to
    /// the outermost voxel centres, so the half voxel along each face takes the face's values.
    #[inline]
    pub fn trilinear(&self, p: [f64; 3]) -> Trilinear {
        let mut i0 = [0usize; 3];
        let mut i1 = [0usize; 3];
        let mut f = [0f32; 3];
        for k in 0..3 {
            let n = self.dims[k];
            let u = ((p[k] - self.lo[k]) / self.h[k] - 0.5).clamp(0.0, (n - 1) as f64);
            let a = (u.floor() as usize).min(n - 1);
            i0[k] = a;
            i1[k] = (a + 1).min(n - 1);
            f[k] = (u - a as f64) as f32;
        }
        let (nx, nxy) = (self.dims[0], self.dims[0] * self.dims[1]);
        let mut idx = [0usize; 8];
        let mut w = [0f32; 8];
        for c in 0..8 {
            let (bx, by, bz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let x = if bx == 0 { i0[0] } else { i1[0] };
            let y = if by == 0 { i0[1] } else { i1[1] };
            let z = if bz == 0 { i0[2] } else { i1[2] };
            idx[c] = x + nx * y + nxy * z;
            let wx = if bx == 0 { 1.0 - f[0] } else { f[0] };
            let wy = if by == 0 { 1.0 - f[1] } else { f[1] };
            let wz = if bz == 0 { 1.0 - f[2] } else { f[2] };
            w[c] = wx * wy * wz;
        }
        Trilinear { idx, w }
    }

    /// Density at `p`: trilinear inside the box, 0 outside.
    pub fn density_at(&self, density: &[f32], p: [f64; 3]) -> f32 {
        if (0..3).any(|k| p[k] < self.lo[k] || p[k] > self.hi[k]) {
            return 0.0;
        }
        let t = self.trilinear(p);
        (0..8).map(|c| t.w[c] * density[t.idx[c]]).sum()
    }

    /// The parameter interval `[t0, t1]` (t0 ≥ 0) where the ray `o + t·d` is inside the box, or
    /// `None` when it misses.
    pub fn clip(&self, o: [f64; 3], d: [f64; 3]) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            if d[k].abs() < 1e-300 {
                if o[k] < self.lo[k] || o[k] > self.hi[k] {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / d[k];
            let (a, b) = ((self.lo[k] - o[k]) * inv, (self.hi[k] - o[k]) * inv);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        (t1 > t0).then_some((t0, t1))
    }

    /// Walks the voxels the ray `o + t·d` (unit `d`) crosses inside the box, nearest first,
    /// calling `visit(voxel, flat index, t_enter)`; stops when `visit` returns false. No
    /// allocation.
    pub fn walk(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        mut visit: impl FnMut([usize; 3], usize, f64) -> bool,
    ) {
        let Some((t0, t1)) = self.clip(o, d) else {
            return;
        };
        // Start just inside the box so the first voxel is the entry voxel.
        let eps = 1e-9 * self.min_h();
        let p = [0, 1, 2].map(|k| o[k] + (t0 + eps) * d[k]);
        let mut c = self.voxel_of(p);
        let mut step = [0i64; 3];
        let mut t_max = [f64::INFINITY; 3];
        let mut t_delta = [f64::INFINITY; 3];
        for k in 0..3 {
            if d[k] > 0.0 {
                step[k] = 1;
                let next = self.lo[k] + (c[k] as f64 + 1.0) * self.h[k];
                t_max[k] = (next - o[k]) / d[k];
                t_delta[k] = self.h[k] / d[k];
            } else if d[k] < 0.0 {
                step[k] = -1;
                let next = self.lo[k] + c[k] as f64 * self.h[k];
                t_max[k] = (next - o[k]) / d[k];
                t_delta[k] = -self.h[k] / d[k];
            }
        }
        let mut t = t0;
        loop {
            if !visit(c, self.index(c[0], c[1], c[2]), t) {
                return;
            }
            let k = if t_max[0] <= t_max[1] && t_max[0] <= t_max[2] {
                0
            } else if t_max[1] <= t_max[2] {
                1
            } else {
                2
            };
            t = t_max[k];
            if t > t1 {
                return;
            }
            let next = c[k] as i64 + step[k];
            if next < 0 || next >= self.dims[k] as i64 {
                return;
            }
            c[k] = next as usize;
            t_max[k] += t_delta[k];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn walk_visits_a_diagonal_in_order_and_clip_matches_the_box() {
        let v = Volume::new([4, 4, 4], vec![0.0; 64], ([0.0; 3], [4.0; 3])).unwrap();
        let g = GridFrame::of(&v);
        let mut seen = Vec::new();
        g.walk([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], |c, _, _| {
            seen.push(c);
            true
        });
        assert_eq!(seen, vec![[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]);
        assert_eq!(g.clip([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0]), Some((1.0, 5.0)));
        assert!(g.clip([-1.0, 5.5, 0.5], [1.0, 0.0, 0.0]).is_none());
        let mut n = 0;
        g.walk(
            [4.5, 4.5, 4.5],
            [-1.0, -1.0, -1.0].map(|x: f64| x / 3f64.sqrt()),
            |_, _, _| {
                n += 1;
                true
            },
        );
        assert!((4..=10).contains(&n), "{n}");
    }
}
