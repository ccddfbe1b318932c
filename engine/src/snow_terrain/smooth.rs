//! Smoothing with the L1 diamond (paper §4.1 lines 1–3 and line 9, Fig. 8; SPEC §1 steps 1 and 5).
//!
//! One pass replaces every valid cell by `(own + mean of the valid neighbours in the diamond
//! 1 ≤ |di| + |dj| ≤ n) / 2`. The diamond holds `4n + 2n(n − 1)` points (paper Fig. 8). The paper
//! averages the whole neighbourhood; at the grid's edges and next to nodata we average over the
//! neighbours that exist and hold data (SPEC §1 step 1), so a constant field stays constant with
//! holes present. Nodata stays nodata; a valid cell with no valid neighbour keeps its value.
//!
//! Implementation: the validity mask never changes between passes, so the neighbour count of each
//! cell is computed once and every pass only sums values, with nodata stored as 0. Each cell's sum
//! is accumulated term by term in a fixed order (rows north to south, columns west to east),
//! 32 columns at a time in registers, from a per-band copy of the source rows padded with zeros
//! (adding +0.0 for an offset outside the grid leaves the sum bit-identical to skipping it), and
//! the pass finishes each chunk (`(own + sum/count)/2`) while it is in registers: one read of the
//! grid and one write per pass. Rows are independent, so rayon splits the grid into bands of rows
//! and the result does not depend on the number of threads.
//!
//! Measured (4096², 1 thread, CPU time, 5 passes + counts): 500 ms for the first version, which
//! added one shifted row slice per offset into a stored accumulator (a load and a store per term)
//! and finished in a second pass, 350 ms for this one, with bit-identical results.
//!
//! Rejected: per-row prefix sums or sliding sums (O(n) or O(1) per cell) — in `f32` a prefix over a
//! 4096-wide row of 4000 m heights loses whole metres to cancellation, and in `f64` it does not
//! vectorise as well. A separable form without subtractions (vertical sums `V_k` per row, then
//! `Σ V_{n−|dj|}(c + dj)`, ~5n adds per cell instead of 2n² + 2n) re-associates the sums: results
//! move by an ulp, and TSA, a second-order quantity, amplifies that to visible changes of t
//! (up to 0.1 on 4096² Tanzawa) — not worth it at n = 3.
//!
//! Cost: `O(width · height · n² · iterations)`; allocates two `width × height` `f32` grids and a
//! validity grid (with nodata also the counts' grid and a mask), and per band `(16 + 2n)`
//! padded rows of scratch. Without nodata the counts depend on the position only (the offsets
//! inside the grid) and rows at least `n` from the edges share theirs: `2n + 1` rows of counts,
//! written directly, without the mask, its summing pass or a grid of counts to read per pass.

use multiversion::multiversion;
use rayon::prelude::*;

/// Rows per rayon task. Big enough to amortise the scratch row, small enough to balance 2–64 cores.
const BAND_ROWS: usize = 16;

/// Number of points in the L1 diamond `1 ≤ |di| + |dj| ≤ n` (paper Fig. 8: `4n + 2n(n − 1)`).
pub fn diamond_len(n: usize) -> usize {
    4 * n + 2 * n * n.saturating_sub(1)
}

/// The `(d_row, d_col)` offsets of the L1 diamond `1 ≤ |di| + |dj| ≤ n`, rows from north to south,
/// columns west to east. Yields [`diamond_len`]`(n)` items.
pub fn diamond_offsets(n: usize) -> impl Iterator<Item = (isize, isize)> {
    let n = n as isize;
    (-n..=n).flat_map(move |di| {
        let w = n - di.abs();
        (-w..=w)
            .filter(move |&dj| di != 0 || dj != 0)
            .map(move |dj| (di, dj))
    })
}

/// Smooths a `width × height` row-major grid (NaN = nodata) with the diamond of radius `radius`,
/// `iterations` times, and returns the new grid (NaN where the input is NaN).
///
/// `radius == 0` or `iterations == 0` returns a copy. Allocates three grids.
///
/// # Panics
/// If `field.len() != width * height`.
pub fn smooth_diamond(
    field: &[f32],
    width: usize,
    height: usize,
    radius: usize,
    iterations: usize,
) -> Vec<f32> {
    let mut s = Smoother::new(field, width, height, radius);
    for _ in 0..iterations {
        s.step();
    }
    s.finish()
}

/// Step-by-step form of [`smooth_diamond`], so that a pipeline can report progress and poll for
/// cancellation between passes.
pub struct Smoother {
    width: usize,
    height: usize,
    radius: usize,
    /// Current values, nodata stored as 0.
    cur: Vec<f32>,
    /// Next values (ping-pong buffer).
    next: Vec<f32>,
    /// Number of valid diamond neighbours of valid cells; 0 for nodata cells.
    count: Counts,
    /// True where the input holds data.
    valid: Vec<bool>,
}

impl Smoother {
    /// Prepares the buffers and the per-cell neighbour counts (one pass of work).
    ///
    /// # Panics
    /// If `field.len() != width * height`.
    pub fn new(field: &[f32], width: usize, height: usize, radius: usize) -> Self {
        assert_eq!(field.len(), width * height, "grid size mismatch");
        let valid: Vec<bool> = field.par_iter().map(|v| !v.is_nan()).collect();
        let cur: Vec<f32> = field
            .par_iter()
            .map(|&v| if v.is_nan() { 0.0 } else { v })
            .collect();
        let count = if radius == 0 || width == 0 {
            Counts::grid(Vec::new(), 0)
        } else if valid.par_iter().all(|&v| v) {
            // No nodata: a cell's count is the number of diamond offsets inside the grid, an
            // integer (exact in f32, so the same bits as the mask's sum), the same for every row
            // at least `radius` rows from the top and bottom edges.
            Counts::without_nodata(width, height, radius)
        } else {
            let mut count = vec![0.0f32; field.len()];
            let mask: Vec<f32> = valid.par_iter().map(|&v| f32::from(u8::from(v))).collect();
            // Neighbour counts of valid cells, 0 at nodata, in one pass.
            for_each_row_sum(
                &mask,
                width,
                height,
                radius,
                &mut count,
                |r, c0, out, sums| {
                    let ok = &valid[r * width + c0..r * width + c0 + out.len()];
                    for ((o, &s), &ok) in out.iter_mut().zip(sums).zip(ok) {
                        *o = if ok { s } else { 0.0 };
                    }
                },
            );
            Counts::grid(count, height)
        };
        let next = vec![0.0f32; field.len()];
        Self {
            width,
            height,
            radius,
            cur,
            next,
            count,
            valid,
        }
    }

    /// One smoothing pass.
    pub fn step(&mut self) {
        if self.radius == 0 || self.width == 0 {
            return;
        }
        let (w, h, n) = (self.width, self.height, self.radius);
        let (cur, count) = (&self.cur, &self.count);
        // Sum and finish each tile while it is in L1 (one pass over the grid).
        for_each_row_sum(cur, w, h, n, &mut self.next, |r, t0, next, sums| {
            let o = r * w + t0;
            let cur = &cur[o..o + next.len()];
            let count = count.at(r, w, t0, next.len());
            for (((n, &s), &c), &k) in next.iter_mut().zip(sums).zip(cur).zip(count) {
                // Valid with neighbours: (own + sum/count)/2 (a constant field stays exactly
                // constant). Isolated or nodata (k = 0): keep own (nodata is stored as 0).
                *n = if k > 0.0 { 0.5 * (c + s / k) } else { c };
            }
        });
        std::mem::swap(&mut self.cur, &mut self.next);
    }

    /// Starts over on a new field with the same nodata cells as the one this smoother was made
    /// for, reusing its buffers and neighbour counts (no allocation, no counting pass).
    ///
    /// # Panics
    /// If `field` has a different length or NaN pattern.
    pub fn reload(&mut self, field: &[f32]) {
        assert_eq!(field.len(), self.cur.len(), "grid size mismatch");
        self.cur
            .par_iter_mut()
            .zip(field.par_iter())
            .zip(self.valid.par_iter())
            .for_each(|((c, &v), &ok)| {
                assert_eq!(ok, !v.is_nan(), "nodata pattern differs");
                *c = if ok { v } else { 0.0 };
            });
    }

    /// Like [`Smoother::reload`] with the new field computed on the fly, cell by cell, as
    /// `f(a[i], b[i])` at valid cells (nodata cells are not evaluated), so a pipeline can fuse a
    /// per-cell stage into the reload without allocating the field. `f` must return a number
    /// (not NaN) at valid cells.
    ///
    /// # Panics
    /// If `a` or `b` has a different length.
    pub fn reload_with<F>(&mut self, a: &[f32], b: &[f32], f: F)
    where
        F: Fn(f32, f32) -> f32 + Sync,
    {
        assert_eq!(a.len(), self.cur.len(), "grid size mismatch");
        assert_eq!(b.len(), self.cur.len(), "grid size mismatch");
        let band = self.width.max(1) * BAND_ROWS;
        self.cur
            .par_chunks_mut(band)
            .zip(a.par_chunks(band))
            .zip(b.par_chunks(band))
            .zip(self.valid.par_chunks(band))
            .for_each(|(((c, a), b), v)| {
                for (((c, &a), &b), &ok) in c.iter_mut().zip(a).zip(b).zip(v) {
                    *c = if ok { f(a, b) } else { 0.0 };
                }
            });
    }

    /// A copy of the current grid with NaN at nodata (allocates one grid).
    pub fn current(&self) -> Vec<f32> {
        let mut out = vec![0.0f32; self.cur.len()];
        out.par_iter_mut()
            .zip(self.cur.par_iter())
            .zip(self.valid.par_iter())
            .for_each(|((o, &c), &ok)| *o = if ok { c } else { f32::NAN });
        out
    }

    /// The smoothed grid with NaN restored at nodata.
    pub fn finish(self) -> Vec<f32> {
        let mut out = self.cur;
        out.par_iter_mut()
            .zip(self.valid.par_iter())
            .for_each(|(v, &ok)| {
                if !ok {
                    *v = f32::NAN;
                }
            });
        out
    }
}

/// The neighbour count of every cell ([`Smoother`]): 0 at nodata, else the valid diamond
/// neighbours. Rows of counts `width` long and, per grid row, which of them it uses: one row
/// per grid row with nodata (and on grids of at most `2n` rows); without nodata the counts
/// depend on the position only and rows at least `n` from both edges share one, so `2n + 1`
/// rows (rows 0..n, that interior row, rows `height − n`..`height`) instead of a grid: no 4
/// bytes per cell to allocate and to read in every pass.
struct Counts {
    rows: Vec<f32>,
    /// Index into `rows` (in rows) of each grid row's counts.
    of_row: Vec<usize>,
}

impl Counts {
    /// One row of counts per grid row.
    fn grid(rows: Vec<f32>, height: usize) -> Self {
        Counts {
            rows,
            of_row: (0..height).collect(),
        }
    }

    /// The counts of a grid without nodata ([`diamond_count_row`] for each row class).
    fn without_nodata(width: usize, height: usize, n: usize) -> Self {
        if height > 2 * n {
            let mut t = vec![0.0f32; (2 * n + 1) * width];
            for (k, row) in t.chunks_mut(width).enumerate() {
                let r = if k <= n { k } else { height - n + (k - n - 1) };
                diamond_count_row(r, width, height, n, row);
            }
            let of_row = (0..height)
                .map(|r| {
                    if r < n {
                        r
                    } else if r + n < height {
                        n
                    } else {
                        n + 1 + (r - (height - n))
                    }
                })
                .collect();
            Counts { rows: t, of_row }
        } else {
            let mut g = vec![0.0f32; width * height];
            g.par_chunks_mut(width)
                .enumerate()
                .for_each(|(r, row)| diamond_count_row(r, width, height, n, row));
            Counts::grid(g, height)
        }
    }

    /// The counts of grid row `r`, columns `c0..c0 + len`, on a grid `width` wide.
    #[inline]
    fn at(&self, r: usize, width: usize, c0: usize, len: usize) -> &[f32] {
        let o = self.of_row[r] * width + c0;
        &self.rows[o..o + len]
    }
}

/// The neighbour counts of row `r` of a `width × height` grid without nodata: for each cell,
/// the offsets of the diamond `1 ≤ |di| + |dj| ≤ n` that stay inside the grid (what the
/// neighbour sum of an all-ones mask gives).
fn diamond_count_row(r: usize, width: usize, height: usize, n: usize, row: &mut [f32]) {
    for (c, o) in row.iter_mut().enumerate() {
        let mut k = 0usize;
        for rr in r.saturating_sub(n)..=(r + n).min(height - 1) {
            let m = n - rr.abs_diff(r);
            k += (c + m).min(width - 1) - c.saturating_sub(m) + 1;
        }
        *o = (k - 1) as f32;
    }
}

/// Columns summed at once in registers (8 SSE / 4 AVX vectors: enough independent add chains
/// to hide the add latency).
const LANES: usize = 16;

/// Per-worker scratch: the band's source rows, each padded with `n` zero columns on the left and
/// `n + LANES` on the right, so that every chunk reads in bounds without a border case.
#[derive(Default)]
struct Scratch {
    padded: Vec<f32>,
}

/// Calls `f(row, first column, out chunk, diamond sums of the chunk)` for every chunk of
/// [`LANES`] columns of every row, where the sums are `Σ src[cell + offset]` over the diamond
/// offsets that fall inside the grid (the centre excluded); `src` must not hold NaN. Rows are
/// split into bands over rayon (disjoint outputs: independent of the thread count).
///
/// Each cell's sum is accumulated in the fixed order rows north to south, columns west to east,
/// starting from 0, in registers for a chunk of columns (one load and one add per term; the
/// first version stored the accumulator after every term). Offsets outside the grid add the
/// padding's +0.0, which leaves any sum unchanged, so the result is bit-identical to skipping
/// them.
fn for_each_row_sum<F>(src: &[f32], width: usize, height: usize, n: usize, out: &mut [f32], f: F)
where
    F: Fn(usize, usize, &mut [f32], &[f32]) + Sync,
{
    let pw = width + 2 * n + 2 * LANES;
    out.par_chunks_mut(width * BAND_ROWS)
        .enumerate()
        .for_each_init(Scratch::default, |s, (band, rows)| {
            band_row_sums(src, width, height, n, pw, band, rows, s, &f);
        });
}

/// One band of [`for_each_row_sum`] (output rows `rows`, band number `band`). Compiled for AVX2
/// too and chosen at run time (the same additions in the same order in wider registers: the
/// same bits).
#[multiversion(targets("x86_64+avx2"))]
#[allow(clippy::too_many_arguments)]
fn band_row_sums<F>(
    src: &[f32],
    width: usize,
    height: usize,
    n: usize,
    pw: usize,
    band: usize,
    rows: &mut [f32],
    s: &mut Scratch,
    f: &F,
) where
    F: Fn(usize, usize, &mut [f32], &[f32]) + Sync,
{
    let r0 = band * BAND_ROWS;
    let r1 = r0 + rows.len() / width;
    let lo = r0.saturating_sub(n);
    let hi = (r1 + n).min(height);
    s.padded.clear();
    s.padded.resize((hi - lo) * pw, 0.0);
    for rr in lo..hi {
        let o = (rr - lo) * pw + n;
        s.padded[o..o + width].copy_from_slice(&src[rr * width..(rr + 1) * width]);
    }
    let pad = &s.padded;
    let mut offs = Vec::with_capacity(diamond_len(n));
    for (k, out_row) in rows.chunks_mut(width).enumerate() {
        let r = r0 + k;
        // Padded index of (rr, c0 + dj) minus c0, in summation order.
        offs.clear();
        for rr in r.saturating_sub(n)..=(r + n).min(height - 1) {
            let di = rr.abs_diff(r);
            let base = (rr - lo) * pw + n;
            for j in base - (n - di)..=base + (n - di) {
                if di != 0 || j != base {
                    offs.push(j);
                }
            }
        }
        // Two chunks at a time: eight independent add chains hide the add latency.
        for c0 in (0..width).step_by(2 * LANES) {
            let mut a = [0.0f32; LANES];
            let mut b = [0.0f32; LANES];
            for &o in &offs {
                let o = o + c0;
                if let Some(Ok(s)) = pad.get(o..o + 2 * LANES).map(<&[f32; 2 * LANES]>::try_from) {
                    for k in 0..LANES {
                        a[k] += s[k];
                        b[k] += s[LANES + k];
                    }
                }
            }
            let m = LANES.min(width - c0);
            f(r, c0, &mut out_row[c0..c0 + m], &a[..m]);
            if c0 + LANES < width {
                let m = LANES.min(width - c0 - LANES);
                f(
                    r,
                    c0 + LANES,
                    &mut out_row[c0 + LANES..c0 + LANES + m],
                    &b[..m],
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct per-cell reference of one pass.
    fn reference_pass(f: &[f32], w: usize, h: usize, n: usize) -> Vec<f32> {
        let mut out = f.to_vec();
        for r in 0..h {
            for c in 0..w {
                let v = f[r * w + c];
                if v.is_nan() {
                    continue;
                }
                let (mut s, mut k) = (0.0f64, 0usize);
                for (di, dj) in diamond_offsets(n) {
                    let (rr, cc) = (r as isize + di, c as isize + dj);
                    if rr < 0 || cc < 0 || rr >= h as isize || cc >= w as isize {
                        continue;
                    }
                    let u = f[rr as usize * w + cc as usize];
                    if !u.is_nan() {
                        s += f64::from(u);
                        k += 1;
                    }
                }
                if k > 0 {
                    out[r * w + c] = ((f64::from(v) + s / k as f64) / 2.0) as f32;
                }
            }
        }
        out
    }

    #[test]
    fn diamond_count_matches_fig8() {
        for n in 0..=7 {
            assert_eq!(diamond_offsets(n).count(), diamond_len(n), "n = {n}");
            assert_eq!(diamond_len(n), 4 * n + 2 * n * n.saturating_sub(1));
        }
        assert_eq!(diamond_len(1), 4);
        assert_eq!(diamond_len(2), 12);
        assert_eq!(diamond_len(3), 24);
    }

    #[test]
    fn matches_reference_with_holes_and_borders() {
        let (w, h) = (37, 23);
        let mut f: Vec<f32> = (0..w * h)
            .map(|i| ((i * 7919) % 101) as f32 * 1.5 + 100.0)
            .collect();
        for i in [0, 5, 40, 41, 42, 77, 300, 301, w * h - 1] {
            f[i] = f32::NAN;
        }
        // An isolated valid cell surrounded by holes (n = 1).
        for i in [w * 10 + 9, w * 10 + 11, w * 9 + 10, w * 11 + 10] {
            f[i] = f32::NAN;
        }
        for n in 1..=4 {
            let mut expect = f.clone();
            for _ in 0..3 {
                expect = reference_pass(&expect, w, h, n);
            }
            let got = smooth_diamond(&f, w, h, n, 3);
            for (i, (a, b)) in got.iter().zip(&expect).enumerate() {
                if b.is_nan() {
                    assert!(a.is_nan(), "n={n} cell {i}");
                } else {
                    assert!((a - b).abs() < 1e-3, "n={n} cell {i}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn counts_without_nodata_match_the_mask_sums() {
        for (w, h) in [
            (1, 1),
            (2, 9),
            (9, 2),
            (5, 7),
            (37, 23),
            (40, 6),
            (3, 11),
            (8, 10),
        ] {
            for n in 1..=5 {
                let ones = vec![1.0f32; w * h];
                let mut summed = vec![0.0f32; w * h];
                for_each_row_sum(&ones, w, h, n, &mut summed, |_, _, out, sums| {
                    out.copy_from_slice(sums);
                });
                let counts = Counts::without_nodata(w, h, n);
                let table = if h > 2 * n { 2 * n + 1 } else { h };
                assert_eq!(counts.rows.len(), table * w, "{w}×{h}, n = {n}");
                for r in 0..h {
                    assert_eq!(
                        counts
                            .at(r, w, 0, w)
                            .iter()
                            .map(|v| v.to_bits())
                            .collect::<Vec<_>>(),
                        summed[r * w..(r + 1) * w]
                            .iter()
                            .map(|v| v.to_bits())
                            .collect::<Vec<_>>(),
                        "{w}×{h}, n = {n}, row {r}"
                    );
                }
            }
        }
    }

    #[test]
    fn constant_field_with_holes_stays_constant() {
        let (w, h) = (20, 15);
        let mut f = vec![1234.5f32; w * h];
        for i in (0..w * h).step_by(7) {
            f[i] = f32::NAN;
        }
        let got = smooth_diamond(&f, w, h, 3, 5);
        for (a, b) in got.iter().zip(&f) {
            if b.is_nan() {
                assert!(a.is_nan());
            } else {
                assert_eq!(*a, 1234.5);
            }
        }
    }

    #[test]
    fn zero_radius_or_iterations_is_identity() {
        let f = vec![1.0, 2.0, f32::NAN, 4.0];
        let a = smooth_diamond(&f, 2, 2, 0, 3);
        let b = smooth_diamond(&f, 2, 2, 2, 0);
        for g in [a, b] {
            assert_eq!(g[0], 1.0);
            assert!(g[2].is_nan());
            assert_eq!(g[3], 4.0);
        }
    }
}
