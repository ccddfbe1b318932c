//! The fine level: the LLW graph Laplacian on the voxel grid (a 7-point stencil), its
//! residual and its red–black Gauss–Seidel smoother.
//!
//! Every level is held as *conductances* `c_ij = −A_ij` (i ≠ j) and an *excess*
//! `s_i = Σ_j A_ij` (the row sum; on the fine level the affinities to pinned voxels), so
//! `(A e)_i = s_i e_i + Σ_j c_ij (e_i − e_j)`. Residuals are taken in that difference form,
//! which keeps the near-null space (almost constant fields far from the pins, whose
//! eigenvalues are tiny next to the diagonal) exact in f32 where `diag·e_i − Σ c e_j` would
//! lose it to cancellation. Pinned voxels are identity rows with no conductance: their
//! correction is always 0.
//!
//! Red–black Gauss–Seidel runs in place as four colours (z parity) × ((x + y) parity), taken
//! as (0,0), (1,1) then (0,1), (1,0): exactly red (x + y + z even) then black. A colour only
//! writes planes of one z parity and reads the planes beside them, so each pass runs planes
//! in parallel on disjoint `&mut` slices ([`for_planes`]) and the result does not depend on the
//! thread count.

use rayon::prelude::*;

use super::graph::Adjacency;

pub(super) type Rgb = [f32; 3];

/// The fine level: the LLW graph Laplacian with the pins as Dirichlet values.
pub(super) struct Fine {
    pub dims: [usize; 3],
    /// Affinities of each voxel's +x, +y, +z edges (pins included; 0 past the grid's end).
    pub a: Vec<[f32; 3]>,
    pub pinned: Vec<bool>,
}

impl Fine {
    /// Calls `f(j, a_ij)` for the face neighbours `j` of voxel `i` (pinned ones included)
    /// whose affinity is not 0. No coordinate arithmetic: an edge past the grid's end has
    /// affinity 0 (see [`super::llw_weights`]), and the lower neighbour of a row's, plane's or
    /// grid's first voxel is the previous row's, plane's or grid's last, whose edge along that
    /// axis is such an edge.
    #[inline]
    pub fn each_edge(&self, i: usize, mut f: impl FnMut(usize, f32)) {
        let [nx, ny, _] = self.dims;
        let plane = nx * ny;
        let a = &self.a;
        let mut edge = |j: usize, w: f32| {
            if w != 0.0 {
                f(j, w);
            }
        };
        if i >= 1 {
            edge(i - 1, a[i - 1][0]);
        }
        edge(i + 1, a[i][0]);
        if i >= nx {
            edge(i - nx, a[i - nx][1]);
        }
        edge(i + nx, a[i][1]);
        if i >= plane {
            edge(i - plane, a[i - plane][2]);
        }
        edge(i + plane, a[i][2]);
    }
}

impl Adjacency for Fine {
    fn len(&self) -> usize {
        self.pinned.len()
    }
    fn decoupled(&self, i: usize) -> bool {
        self.pinned[i]
    }
    fn excess(&self, i: usize) -> f32 {
        if self.pinned[i] {
            return 1.0;
        }
        let mut s = 0.0;
        self.each_edge(i, |j, a| {
            if self.pinned[j] {
                s += a;
            }
        });
        s
    }
    fn each(&self, i: usize, mut f: impl FnMut(usize, f32)) {
        if self.pinned[i] {
            return;
        }
        self.each_edge(i, |j, a| {
            if !self.pinned[j] {
                f(j, a);
            }
        });
    }
}

/// Runs `f(z, plane, below, above)` in parallel on every plane `z` of `v` with `z % 2 ==
/// parity`, mutably, with read-only views of the planes beside it (None outside the grid).
pub(super) fn for_planes<T, F>(v: &mut [T], plane: usize, parity: usize, f: F)
where
    T: Send + Sync,
    F: Fn(usize, &mut [T], Option<&[T]>, Option<&[T]>) + Sync,
{
    let mut writable = Vec::new();
    let mut others: Vec<Option<&[T]>> = Vec::new();
    for (z, p) in v.chunks_mut(plane).enumerate() {
        if z % 2 == parity {
            writable.push((z, p));
            others.push(None);
        } else {
            others.push(Some(&*p));
        }
    }
    writable.into_par_iter().for_each(|(z, p)| {
        let below = if z > 0 { others[z - 1] } else { None };
        let above = others.get(z + 1).copied().flatten();
        f(z, p, below, above);
    });
}

#[inline]
fn madd(acc: &mut Rgb, w: f32, v: &Rgb) {
    acc[0] += w * v[0];
    acc[1] += w * v[1];
    acc[2] += w * v[2];
}

/// One red–black Gauss–Seidel sweep on the fine level, `A e = b` (pins keep e = 0): red then
/// black, or black then red when `reverse`.
pub(super) fn smooth_fine(op: &Fine, e: &mut [Rgb], b: &[Rgb], reverse: bool) {
    let order: [(usize, usize); 4] = if reverse {
        [(0, 1), (1, 0), (0, 0), (1, 1)]
    } else {
        [(0, 0), (1, 1), (0, 1), (1, 0)]
    };
    let [nx, ny, _] = op.dims;
    let plane = nx * ny;
    for (zpar, xypar) in order {
        for_planes(e, plane, zpar, |z, cur, below, above| {
            let base = plane * z;
            for y in 0..ny {
                let x0 = (xypar + y) & 1;
                for x in (x0..nx).step_by(2) {
                    let j = x + nx * y;
                    let i = base + j;
                    if op.pinned[i] {
                        continue;
                    }
                    let w = op.a[i];
                    let mut acc = b[i];
                    let mut d = 0.0;
                    if x > 0 {
                        let c = op.a[i - 1][0];
                        d += c;
                        madd(&mut acc, c, &cur[j - 1]);
                    }
                    if x + 1 < nx {
                        d += w[0];
                        madd(&mut acc, w[0], &cur[j + 1]);
                    }
                    if y > 0 {
                        let c = op.a[i - nx][1];
                        d += c;
                        madd(&mut acc, c, &cur[j - nx]);
                    }
                    if y + 1 < ny {
                        d += w[1];
                        madd(&mut acc, w[1], &cur[j + nx]);
                    }
                    if let Some(bl) = below {
                        let c = op.a[i - plane][2];
                        d += c;
                        madd(&mut acc, c, &bl[j]);
                    }
                    if let Some(ab) = above {
                        d += w[2];
                        madd(&mut acc, w[2], &ab[j]);
                    }
                    if d > 0.0 {
                        let inv = 1.0 / d;
                        cur[j] = acc.map(|v| v * inv);
                    }
                }
            }
        });
    }
}

/// `out = b − A e` on the fine level (0 on pins).
pub(super) fn residual_fine(op: &Fine, e: &[Rgb], b: &[Rgb], out: &mut [Rgb]) {
    let [nx, ny, nz] = op.dims;
    let plane = nx * ny;
    out.par_chunks_mut(plane).enumerate().for_each(|(z, o)| {
        let base = plane * z;
        for y in 0..ny {
            for x in 0..nx {
                let j = x + nx * y;
                let i = base + j;
                if op.pinned[i] {
                    o[j] = [0.0; 3];
                    continue;
                }
                let ei = e[i];
                let mut acc = b[i];
                let mut edge = |c: f32, n: usize| {
                    for q in 0..3 {
                        acc[q] -= c * (ei[q] - e[n][q]);
                    }
                };
                for_each_edge(&op.a, [nx, ny, nz], [x, y, z], i, &mut edge);
                o[j] = acc;
            }
        }
    });
}

/// `out = A p` on the fine level (`p` zero on pins; 0 on pins).
pub(super) fn apply_fine(op: &Fine, p: &[Rgb], out: &mut [Rgb]) {
    let zero = [0f32; 3];
    let [nx, ny, nz] = op.dims;
    let plane = nx * ny;
    out.par_chunks_mut(plane).enumerate().for_each(|(z, o)| {
        let base = plane * z;
        for y in 0..ny {
            for x in 0..nx {
                let j = x + nx * y;
                let i = base + j;
                if op.pinned[i] {
                    o[j] = zero;
                    continue;
                }
                let pi = p[i];
                let mut acc = [0f64; 3];
                let mut edge = |c: f32, n: usize| {
                    let c = f64::from(c);
                    for q in 0..3 {
                        acc[q] += c * f64::from(pi[q] - p[n][q]);
                    }
                };
                for_each_edge(&op.a, [nx, ny, nz], [x, y, z], i, &mut edge);
                o[j] = acc.map(|v| v as f32);
            }
        }
    });
}

/// Calls `edge(weight, neighbour)` for each of voxel `i`'s grid neighbours (at `[x, y, z]` in a
/// grid of `dims`), in the order −x, +x, −y, +y, −z, +z, with the weight of the link between
/// them (`a[min(i, n)][axis]`). The fixed order keeps sums bit-identical wherever it is used.
#[inline(always)]
pub(super) fn for_each_edge(
    a: &[[f32; 3]],
    dims: [usize; 3],
    [x, y, z]: [usize; 3],
    i: usize,
    edge: &mut impl FnMut(f32, usize),
) {
    let [nx, ny, nz] = dims;
    let plane = nx * ny;
    if x > 0 {
        edge(a[i - 1][0], i - 1);
    }
    if x + 1 < nx {
        edge(a[i][0], i + 1);
    }
    if y > 0 {
        edge(a[i - nx][1], i - nx);
    }
    if y + 1 < ny {
        edge(a[i][1], i + nx);
    }
    if z > 0 {
        edge(a[i - plane][2], i - plane);
    }
    if z + 1 < nz {
        edge(a[i][2], i + plane);
    }
}
