//! The coarse levels: a weighted graph in compressed rows (conductances and excess, as on the
//! fine level — see [`super::fine`]), its residual and its multicolour Gauss–Seidel smoother.
//!
//! The points of a coarse level are numbered colour by colour (a greedy colouring: no two
//! neighbours share a colour), so one colour is a contiguous range: a smoothing pass writes
//! that range in parallel while reading the rest, on disjoint slices, and the result does not
//! depend on the thread count.

use rayon::prelude::*;

/// A linear RGB value per point (ambient excess, unknowns).
pub(super) type Rgb = [f32; 3];

/// What the setup (aggregation, prolongation, Galerkin product, coarsest factorisation) needs
/// of a level's operator.
pub(super) trait Adjacency: Sync {
    fn len(&self) -> usize;
    /// The excess `s_i`.
    fn excess(&self, i: usize) -> f32;
    /// Calls `f(j, c_ij)` for every non-zero conductance of row `i`.
    fn each(&self, i: usize, f: impl FnMut(usize, f32));
    /// The diagonal `s_i + Σ_j c_ij`.
    fn diagonal(&self, i: usize) -> f32 {
        let mut d = self.excess(i);
        self.each(i, |_, c| d += c);
        d
    }
}

/// A coarse level's operator.
pub(super) struct Graph {
    /// Row `i`'s entries are `ptr[i]..ptr[i + 1]` of `col` and `c`.
    pub ptr: Vec<usize>,
    pub col: Vec<u32>,
    /// Conductances (may be negative: a Galerkin operator need not be an M-matrix).
    pub c: Vec<f32>,
    pub excess: Vec<f32>,
    /// Colour `k` is the points `colours[k]..colours[k + 1]`.
    pub colors: Vec<usize>,
}

impl Adjacency for Graph {
    fn len(&self) -> usize {
        self.excess.len()
    }
    fn excess(&self, i: usize) -> f32 {
        self.excess[i]
    }
    #[inline]
    fn each(&self, i: usize, mut f: impl FnMut(usize, f32)) {
        for p in self.ptr[i]..self.ptr[i + 1] {
            f(self.col[p] as usize, self.c[p]);
        }
    }
}

/// Rows per parallel task in the coarse-level loops.
const CHUNK: usize = 512;

impl Graph {
    /// One multicolour Gauss–Seidel sweep of `A e = b` (colours in order, or reversed).
    pub fn smooth(&self, e: &mut [Rgb], b: &[Rgb], reverse: bool) {
        let k = self.colors.len() - 1;
        for step in 0..k {
            let color = if reverse { k - 1 - step } else { step };
            let (lo, hi) = (self.colors[color], self.colors[color + 1]);
            let (before, rest) = e.split_at_mut(lo);
            let (mine, after) = rest.split_at_mut(hi - lo);
            let before: &[Rgb] = before;
            let after: &[Rgb] = after;
            mine.par_chunks_mut(CHUNK).enumerate().for_each(|(t, out)| {
                for (m, v) in out.iter_mut().enumerate() {
                    let i = lo + t * CHUNK + m;
                    let mut acc = b[i];
                    let mut d = self.excess[i];
                    for p in self.ptr[i]..self.ptr[i + 1] {
                        let j = self.col[p] as usize;
                        // Neighbours never share the colour (module doc).
                        let ej = if j < lo { before[j] } else { after[j - hi] };
                        let c = self.c[p];
                        d += c;
                        for q in 0..3 {
                            acc[q] += c * ej[q];
                        }
                    }
                    if d > 0.0 {
                        let inv = 1.0 / d;
                        *v = acc.map(|x| x * inv);
                    }
                }
            });
        }
    }

    /// `out = b − A e`.
    pub fn residual(&self, e: &[Rgb], b: &[Rgb], out: &mut [Rgb]) {
        out.par_chunks_mut(CHUNK).enumerate().for_each(|(t, o)| {
            for (m, v) in o.iter_mut().enumerate() {
                let i = t * CHUNK + m;
                let ei = e[i];
                let s = self.excess[i];
                let mut acc = [0f32; 3];
                for q in 0..3 {
                    acc[q] = b[i][q] - s * ei[q];
                }
                for p in self.ptr[i]..self.ptr[i + 1] {
                    let ej = e[self.col[p] as usize];
                    let c = self.c[p];
                    for q in 0..3 {
                        acc[q] -= c * (ei[q] - ej[q]);
                    }
                }
                *v = acc;
            }
        });
    }
}

impl Graph {
    /// `out = b − A x` in f64 (stored f32); returns `‖out‖²` (summed per fixed chunk, in order:
    /// independent of the thread count).
    pub fn residual_f64(&self, x: &[[f64; 3]], b: &[[f64; 3]], out: &mut [Rgb]) -> f64 {
        let parts: Vec<f64> = out
            .par_chunks_mut(CHUNK)
            .enumerate()
            .map(|(t, o)| {
                let mut sq = 0.0;
                for (m, v) in o.iter_mut().enumerate() {
                    let i = t * CHUNK + m;
                    let xi = x[i];
                    let s = f64::from(self.excess[i]);
                    let mut acc: [f64; 3] = std::array::from_fn(|q| b[i][q] - s * xi[q]);
                    for p in self.ptr[i]..self.ptr[i + 1] {
                        let xj = x[self.col[p] as usize];
                        let c = f64::from(self.c[p]);
                        for q in 0..3 {
                            acc[q] -= c * (xi[q] - xj[q]);
                        }
                    }
                    sq += acc.iter().map(|v| v * v).sum::<f64>();
                    *v = acc.map(|v| v as f32);
                }
                sq
            })
            .collect();
        parts.iter().sum()
    }

    /// `out = A p` (accumulated in f64).
    pub fn apply(&self, p: &[Rgb], out: &mut [Rgb]) {
        out.par_chunks_mut(CHUNK).enumerate().for_each(|(t, o)| {
            for (m, v) in o.iter_mut().enumerate() {
                let i = t * CHUNK + m;
                let pi = p[i];
                let s = f64::from(self.excess[i]);
                let mut acc: [f64; 3] = std::array::from_fn(|q| s * f64::from(pi[q]));
                for k in self.ptr[i]..self.ptr[i + 1] {
                    let pj = p[self.col[k] as usize];
                    let c = f64::from(self.c[k]);
                    for q in 0..3 {
                        acc[q] += c * f64::from(pi[q] - pj[q]);
                    }
                }
                *v = acc.map(|v| v as f32);
            }
        });
    }
}

/// Per-channel dot products (f64, summed per fixed chunk in order: thread-count independent).
pub(super) fn dot3(a: &[Rgb], b: &[Rgb]) -> [f64; 3] {
    let parts: Vec<[f64; 3]> = a
        .par_chunks(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .map(|(x, y)| {
            let mut s = [0f64; 3];
            for (u, v) in x.iter().zip(y) {
                for q in 0..3 {
                    s[q] += f64::from(u[q]) * f64::from(v[q]);
                }
            }
            s
        })
        .collect();
    parts.iter().fold([0.0; 3], |acc, s| {
        [acc[0] + s[0], acc[1] + s[1], acc[2] + s[2]]
    })
}

/// A greedy colouring of a symmetric graph in index order and the numbering that puts the
/// colours in contiguous ranges: returns (`new index of old i`, colour boundaries).
pub(super) fn color_order<A: Adjacency>(g: &A) -> (Vec<u32>, Vec<usize>) {
    let n = g.len();
    let mut color = vec![u32::MAX; n];
    let mut used: Vec<usize> = Vec::new();
    let mut ncol = 0usize;
    for i in 0..n {
        used.clear();
        g.each(i, |j, _| {
            if color[j] != u32::MAX {
                used.push(color[j] as usize);
            }
        });
        used.sort_unstable();
        let mut k = 0;
        for &u in &used {
            if u == k {
                k += 1;
            } else if u > k {
                break;
            }
        }
        color[i] = k as u32;
        ncol = ncol.max(k + 1);
    }
    let mut bounds = vec![0usize; ncol + 1];
    for &c in &color {
        bounds[c as usize + 1] += 1;
    }
    for k in 0..ncol {
        bounds[k + 1] += bounds[k];
    }
    let mut next = bounds.clone();
    let perm = color
        .iter()
        .map(|&c| {
            let p = next[c as usize];
            next[c as usize] += 1;
            p as u32
        })
        .collect();
    (perm, bounds)
}
