//! Smoothed aggregation (Vaněk, Mandel and Brezina 1996): the coarse points are aggregates of
//! strongly coupled points, and the prolongation is the aggregates' indicator smoothed by one
//! damped Jacobi step of the *filtered* operator.
//!
//! - *Strength*: j is strongly coupled to i when `c_ij ≥ θ·√(d_i d_j)` (d the diagonal), θ =
//!   0.08 on the fine level and halved per level (the usual SA choice for 3-D). On the LLW
//!   system this is what matters: where the guide's gradient is near an axis its weights are
//!   ~300:1 anisotropic (1-voxel sheets coupled within the plane, barely across it — see the
//!   module doc of [`super`]), and only coarsening along the strong couplings reaches those
//!   sheets' smooth errors.
//! - *Aggregation* (in index order, so deterministic): (1) a point whose strong neighbours are
//!   all free becomes a root and takes them; (2) a leftover point joins the aggregate of its
//!   strongest neighbour aggregated in (1); (3) the rest form aggregates with their free strong
//!   neighbours (or alone).
//! - *Prolongation*: `P = (I − ω D_F⁻¹ A_F) P_tent`, `A_F` the operator with weak couplings
//!   dropped and lumped into its diagonal (`D_F = s + Σ_strong c`: row sums kept), ω = 2/3
//!   (= 4/3 over the Gershgorin bound 2 of `ρ(D_F⁻¹A_F)`). Row i: `1 − ω` on its own
//!   aggregate plus `ω·c_ij/D_F,i` on each strong neighbour's; it sums to `1 − ω s_i/D_F,i`: 1
//!   away from the pins, less next to one (the pin's affinity is in `s`), so corrections fade
//!   towards the pins. A point with no strong coupling is scaled by its full diagonal instead
//!   (row `1 − ω s_i/d_i`, ≈ 1): with `D_F = s ≈ 0` on a coarse level the formula above gives
//!   it `1 − ω`, a third of a constant, and the cycle diverged (measured: 32³, θ not halved).
//!   Scaling every row by the full diagonal was measured too and converged more slowly (64³:
//!   3.3× against 4× per iteration).

use rayon::prelude::*;

use super::graph::Adjacency;
use super::graph::Rgb;

const NONE: u32 = u32::MAX;
/// The damping of the prolongation smoother.
const OMEGA: f32 = 2.0 / 3.0;

/// A sparse matrix in compressed rows.
pub(super) struct Csr {
    pub ptr: Vec<usize>,
    pub idx: Vec<u32>,
    pub w: Vec<f32>,
}

impl Csr {
    #[inline]
    pub fn row(&self, i: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let r = self.ptr[i]..self.ptr[i + 1];
        self.idx[r.clone()]
            .iter()
            .zip(&self.w[r])
            .map(|(&j, &w)| (j as usize, w))
    }

    /// The transpose, with `n` rows (counting sort: rows keep ascending column order).
    fn transpose(&self, n: usize) -> Csr {
        let mut ptr = vec![0usize; n + 1];
        for &j in &self.idx {
            ptr[j as usize + 1] += 1;
        }
        for k in 0..n {
            ptr[k + 1] += ptr[k];
        }
        let mut next = ptr.clone();
        let mut idx = vec![0u32; self.idx.len()];
        let mut w = vec![0f32; self.idx.len()];
        for i in 0..self.ptr.len() - 1 {
            for p in self.ptr[i]..self.ptr[i + 1] {
                let j = self.idx[p] as usize;
                idx[next[j]] = i as u32;
                w[next[j]] = self.w[p];
                next[j] += 1;
            }
        }
        Csr { ptr, idx, w }
    }
}

/// The prolongation from a level to the next coarser: fine rows and their transpose.
pub(super) struct Prolongation {
    pub rows: Csr,
    pub cols: Csr,
}

/// Rows per parallel task.
const CHUNK: usize = 1024;

/// Whether `c` (between points of diagonals `di`, `dj`) is a strong coupling at threshold θ.
#[inline]
fn strong(c: f32, di: f32, dj: f32, theta: f32) -> bool {
    c > 0.0 && c * c >= theta * theta * di * dj
}

/// The points `0..n`, or `order` (a permutation of them).
fn visit(n: usize, order: Option<&[u32]>) -> impl Iterator<Item = usize> + '_ {
    let (all, given) = match order {
        Some(o) => (0..0, o),
        None => (0..n, &[][..]),
    };
    all.chain(given.iter().map(|&i| i as usize))
}

/// Aggregates of the points of `a` (module doc) met in `order` (index order if None): the
/// aggregate of every point and their number.
fn aggregates<A: Adjacency>(
    a: &A,
    diag: &[f32],
    theta: f32,
    order: Option<&[u32]>,
) -> (Vec<u32>, usize) {
    let n = a.len();
    let mut agg = vec![NONE; n];
    let mut count = 0u32;
    let mut nb: Vec<(usize, f32)> = Vec::with_capacity(32);
    let strong_of = |i: usize, nb: &mut Vec<(usize, f32)>| {
        nb.clear();
        a.each(i, |j, c| {
            if strong(c, diag[i], diag[j], theta) {
                nb.push((j, c));
            }
        });
    };
    // (1) Roots with all strong neighbours free.
    for i in visit(n, order) {
        if agg[i] != NONE {
            continue;
        }
        strong_of(i, &mut nb);
        if nb.is_empty() || nb.iter().any(|&(j, _)| agg[j] != NONE) {
            continue;
        }
        agg[i] = count;
        for &(j, _) in &nb {
            agg[j] = count;
        }
        count += 1;
    }
    // (2) Leftovers join their strongest aggregated neighbour's aggregate (of phase 1).
    let phase1 = agg.clone();
    for i in visit(n, order) {
        if agg[i] != NONE {
            continue;
        }
        strong_of(i, &mut nb);
        let best = nb.iter().filter(|&&(j, _)| phase1[j] != NONE).fold(
            None,
            |best: Option<(usize, f32)>, &(j, c)| match best {
                Some((_, cb)) if cb >= c => best,
                _ => Some((j, c)),
            },
        );
        if let Some((j, _)) = best {
            agg[i] = phase1[j];
        }
    }
    // (3) The rest: new aggregates with their free strong neighbours, or alone.
    for i in visit(n, order) {
        if agg[i] != NONE {
            continue;
        }
        strong_of(i, &mut nb);
        agg[i] = count;
        for &(j, _) in &nb {
            if agg[j] == NONE {
                agg[j] = count;
            }
        }
        count += 1;
    }
    (agg, count as usize)
}

impl Prolongation {
    /// Aggregates `a`'s points at strength threshold `theta`, meeting them in `order` (index
    /// order if None), and builds the smoothed prolongation (module doc); returns it and the
    /// number of coarse points. `diag` is `a`'s diagonal.
    pub fn build<A: Adjacency>(
        a: &A,
        diag: &[f32],
        theta: f32,
        order: Option<&[u32]>,
    ) -> (Self, usize) {
        let n = a.len();
        let (agg, nc) = aggregates(a, diag, theta, order);
        let parts: Vec<(Vec<usize>, Vec<u32>, Vec<f32>)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|t| {
                let mut lens = Vec::with_capacity(CHUNK);
                let mut idx = Vec::with_capacity(4 * CHUNK);
                let mut w = Vec::with_capacity(4 * CHUNK);
                let mut row: Vec<(u32, f32)> = Vec::with_capacity(32);
                for i in t * CHUNK..((t + 1) * CHUNK).min(n) {
                    row.clear();
                    if agg[i] != NONE && diag[i] > 0.0 {
                        let s = a.excess(i);
                        let mut sc = 0.0;
                        a.each(i, |j, c| {
                            if strong(c, diag[i], diag[j], theta) {
                                sc += c;
                            }
                        });
                        // The Jacobi scaling: the filtered diagonal, or the full one for a point
                        // without strong couplings (module doc).
                        let df = if sc > 0.0 { s + sc } else { diag[i] };
                        row.push((agg[i], 1.0 - OMEGA * (s + sc) / df));
                        a.each(i, |j, c| {
                            if agg[j] != NONE && strong(c, diag[i], diag[j], theta) {
                                let v = OMEGA * c / df;
                                match row.iter_mut().find(|e| e.0 == agg[j]) {
                                    Some(e) => e.1 += v,
                                    None => row.push((agg[j], v)),
                                }
                            }
                        });
                        row.sort_unstable_by_key(|e| e.0);
                    }
                    lens.push(row.len());
                    for &(j, v) in &row {
                        idx.push(j);
                        w.push(v);
                    }
                }
                (lens, idx, w)
            })
            .collect();
        let mut ptr = Vec::with_capacity(n + 1);
        ptr.push(0);
        let total: usize = parts.iter().map(|p| p.1.len()).sum();
        let mut idx = Vec::with_capacity(total);
        let mut w = Vec::with_capacity(total);
        for (lens, i, v) in parts {
            for l in lens {
                ptr.push(ptr[ptr.len() - 1] + l);
            }
            idx.extend(i);
            w.extend(v);
        }
        let rows = Csr { ptr, idx, w };
        let cols = rows.transpose(nc);
        (Self { rows, cols }, nc)
    }

    /// Renumbers the coarse points: coarse point `I` becomes `perm[I]`.
    pub fn renumber(&mut self, perm: &[u32]) {
        for j in &mut self.rows.idx {
            *j = perm[*j as usize];
        }
        self.cols = self.rows.transpose(perm.len());
    }

    /// `out = Pᵀ r`.
    pub fn restrict(&self, r: &[Rgb], out: &mut [Rgb]) {
        out.par_chunks_mut(CHUNK).enumerate().for_each(|(t, o)| {
            for (m, v) in o.iter_mut().enumerate() {
                let mut acc = [0f32; 3];
                for (i, w) in self.cols.row(t * CHUNK + m) {
                    for q in 0..3 {
                        acc[q] += w * r[i][q];
                    }
                }
                *v = acc;
            }
        });
    }

    /// `e += P ec`.
    pub fn prolong_add(&self, ec: &[Rgb], e: &mut [Rgb]) {
        e.par_chunks_mut(CHUNK).enumerate().for_each(|(t, o)| {
            for (m, v) in o.iter_mut().enumerate() {
                for (j, w) in self.rows.row(t * CHUNK + m) {
                    for q in 0..3 {
                        v[q] += w * ec[j][q];
                    }
                }
            }
        });
    }
}
