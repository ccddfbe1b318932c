//! The coarsest level, solved exactly: its operator as a dense matrix, Cholesky-factored once.
//!
//! A semidefinite pivot (≤ 10⁻¹² of its original diagonal: a part of the grid no pin reaches)
//! is dropped, which solves that part with a zero correction — the residual there is zero
//! anyway, as no pin's contribution reaches it.

use super::graph::Adjacency;
use super::graph::Rgb;

/// The Cholesky factor `L` (lower, row-major) of the coarsest operator.
pub(super) struct Dense {
    n: usize,
    l: Vec<f64>,
    /// Pivots kept (false = dropped, see the module doc).
    keep: Vec<bool>,
}

impl Dense {
    /// Factors `a` (allocates `8·n²` bytes; the coarsest level has at most a few hundred
    /// points).
    pub fn factor<A: Adjacency>(a: &A) -> Self {
        let n = a.len();
        let mut l = vec![0f64; n * n];
        for i in 0..n {
            let mut d = f64::from(a.excess(i));
            a.each(i, |j, c| {
                d += f64::from(c);
                l[i * n + j] = -f64::from(c);
            });
            l[i * n + i] = d;
        }
        let mut keep = vec![true; n];
        for j in 0..n {
            let orig = l[j * n + j];
            let mut d = orig;
            for k in 0..j {
                d -= l[j * n + k] * l[j * n + k];
            }
            // Also catches a NaN pivot.
            if d.partial_cmp(&(1e-12 * orig)) != Some(std::cmp::Ordering::Greater) {
                keep[j] = false;
                for i in j..n {
                    l[i * n + j] = 0.0;
                }
                continue;
            }
            let d = d.sqrt();
            l[j * n + j] = d;
            for i in j + 1..n {
                let mut v = l[i * n + j];
                for k in 0..j {
                    v -= l[i * n + k] * l[j * n + k];
                }
                l[i * n + j] = v / d;
            }
        }
        Self { n, l, keep }
    }

    /// `e = A⁻¹ b` on the coarsest level (per channel, in f64).
    pub fn solve(&self, b: &[Rgb], e: &mut [Rgb]) {
        let n = self.n;
        let mut y = vec![[0f64; 3]; n];
        for i in 0..n {
            if !self.keep[i] {
                continue;
            }
            let mut v = b[i].map(f64::from);
            for k in 0..i {
                let lik = self.l[i * n + k];
                for q in 0..3 {
                    v[q] -= lik * y[k][q];
                }
            }
            y[i] = v.map(|c| c / self.l[i * n + i]);
        }
        for i in (0..n).rev() {
            if !self.keep[i] {
                y[i] = [0.0; 3];
                continue;
            }
            let mut v = y[i];
            for k in i + 1..n {
                let lki = self.l[k * n + i];
                for q in 0..3 {
                    v[q] -= lki * y[k][q];
                }
            }
            y[i] = v.map(|c| c / self.l[i * n + i]);
        }
        for (o, v) in e.iter_mut().zip(&y) {
            *o = v.map(|c| c as f32);
        }
    }
}
