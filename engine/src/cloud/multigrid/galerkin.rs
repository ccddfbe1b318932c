//! The Galerkin coarse operator `A_c = Pᵀ A P`, as conductances and excess (see
//! [`super::fine`]), numbered by colour ([`super::graph`]).
//!
//! `−A_c(I, J) = Σ_i P(i,I) [Σ_j c_ij P(j,J) − d_i P(i,J)]` over the fine points i of I's
//! column and their neighbours j (`d_i` the diagonal). The excess — the row sum — is taken
//! separately as `Pᵀ (A u)` with `u = P·1` and `A u` in difference form, so the coarse operator
//! keeps the fine one's near-null space to f64 accuracy rather than as a small difference of
//! f32 diagonals. Sums are f64 (a dense accumulator per thread), results f32.

use rayon::prelude::*;

use super::aggregate::Prolongation;
use super::graph::{color_order, Adjacency, Graph};

/// Coarse rows per parallel task: at least this many, in at most [`BLOCKS`] tasks.
const CHUNK: usize = 256;
const BLOCKS: usize = 32;

/// `Pᵀ A P` for `a` (diagonal `diag`) and the prolongation `p` onto `nc` points; renumbers
/// `p`'s coarse points by colour to match the result.
pub(super) fn galerkin<A: Adjacency>(
    a: &A,
    diag: &[f32],
    p: &mut Prolongation,
    nc: usize,
) -> Graph {
    let n = a.len();
    // u = P·1 and A u (difference form).
    let u: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| p.rows.row(i).map(|(_, w)| f64::from(w)).sum())
        .collect();
    let au: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut v = f64::from(a.excess(i)) * u[i];
            a.each(i, |j, c| v += f64::from(c) * (u[i] - u[j]));
            v
        })
        .collect();
    // Fixed blocks (not per thread, so the result does not depend on the thread count), each
    // with its own dense accumulator.
    let block = nc.div_ceil(BLOCKS).max(CHUNK);
    let parts: Vec<RowsPart> = (0..nc.div_ceil(block))
        .into_par_iter()
        .map(|t| {
            let acc = &mut Acc {
                val: vec![0.0; nc],
                seen: vec![false; nc],
                touched: Vec::new(),
            };
            let mut lens = Vec::with_capacity(CHUNK);
            let mut col = Vec::new();
            let mut c = Vec::new();
            let mut excess = Vec::with_capacity(CHUNK);
            for ci in t * block..((t + 1) * block).min(nc) {
                let mut s = 0f64;
                for (i, wi) in p.cols.row(ci) {
                    let wi = f64::from(wi);
                    s += wi * au[i];
                    let di = f64::from(diag[i]);
                    for (j, wj) in p.rows.row(i) {
                        add(acc, j, -wi * di * f64::from(wj));
                    }
                    a.each(i, |j, cij| {
                        let f = wi * f64::from(cij);
                        for (jj, wj) in p.rows.row(j) {
                            add(acc, jj, f * f64::from(wj));
                        }
                    });
                }
                acc.touched.sort_unstable();
                let mut len = 0;
                for &j in &acc.touched {
                    let v = acc.val[j];
                    acc.val[j] = 0.0;
                    acc.seen[j] = false;
                    if j != ci && v != 0.0 {
                        col.push(j as u32);
                        c.push(v as f32);
                        len += 1;
                    }
                }
                acc.touched.clear();
                lens.push(len);
                excess.push(s as f32);
            }
            (lens, col, c, excess)
        })
        .collect();
    let mut ptr = Vec::with_capacity(nc + 1);
    ptr.push(0);
    let (mut col, mut c, mut excess) = (Vec::new(), Vec::new(), Vec::with_capacity(nc));
    for (lens, co, cv, ex) in parts {
        for l in lens {
            ptr.push(ptr[ptr.len() - 1] + l);
        }
        col.extend(co);
        c.extend(cv);
        excess.extend(ex);
    }
    let g = Graph {
        ptr,
        col,
        c,
        excess,
        colors: vec![0, nc],
    };
    let (perm, colors) = color_order(&g);
    p.renumber(&perm);
    permute(&g, &perm, colors)
}

/// `g` with point `i` renumbered `perm[i]`.
fn permute(g: &Graph, perm: &[u32], colors: Vec<usize>) -> Graph {
    let n = g.excess.len();
    let mut inv = vec![0usize; n];
    for (i, &p) in perm.iter().enumerate() {
        inv[p as usize] = i;
    }
    let mut ptr = Vec::with_capacity(n + 1);
    ptr.push(0);
    let mut col = Vec::with_capacity(g.col.len());
    let mut c = Vec::with_capacity(g.c.len());
    let mut excess = Vec::with_capacity(n);
    for &old in &inv {
        for q in g.ptr[old]..g.ptr[old + 1] {
            col.push(perm[g.col[q] as usize]);
            c.push(g.c[q]);
        }
        ptr.push(col.len());
        excess.push(g.excess[old]);
    }
    Graph {
        ptr,
        col,
        c,
        excess,
        colors,
    }
}

/// One block of coarse rows: row lengths, columns, conductances, excesses.
type RowsPart = (Vec<usize>, Vec<u32>, Vec<f32>, Vec<f32>);

/// A dense accumulator of one coarse row.
struct Acc {
    val: Vec<f64>,
    seen: Vec<bool>,
    touched: Vec<usize>,
}

#[inline]
fn add(acc: &mut Acc, j: usize, v: f64) {
    if !acc.seen[j] {
        acc.seen[j] = true;
        acc.touched.push(j);
    }
    acc.val[j] += v;
}
