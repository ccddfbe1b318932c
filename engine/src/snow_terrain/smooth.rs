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
//! Cost: `O(width · height · n² · iterations)`; allocates three `width × height` `f32` grids, a
//! mask and a validity grid, and per band `(16 + 2n)` padded rows of scratch.

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
    count: Vec<f32>,
    /// True where the input holds data.
    valid: Vec<bool>,
    /// Sum the diamonds with [`for_each_row_sum_exact`] (radius ≥ [`EXACT_FROM`]).
    exact: bool,
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
        let exact = radius >= EXACT_FROM;
        let mut count = vec![0.0f32; field.len()];
        if exact && width > 0 && height > 0 {
            let mask: Vec<f32> = valid.par_iter().map(|&v| f32::from(u8::from(v))).collect();
            // Counts are small integers: the f64 sums are exact.
            for_each_row_sum_exact(&mask, width, height, radius, &mut count, |r, out, sums| {
                let ok = &valid[r * width..(r + 1) * width];
                for ((o, &s), &ok) in out.iter_mut().zip(sums).zip(ok) {
                    *o = if ok { s as f32 } else { 0.0 };
                }
            });
        } else if radius > 0 && width > 0 {
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
        }
        let next = vec![0.0f32; field.len()];
        Self {
            width,
            height,
            radius,
            cur,
            next,
            count,
            valid,
            exact,
        }
    }

    /// One smoothing pass.
    pub fn step(&mut self) {
        if self.radius == 0 || self.width == 0 || self.height == 0 {
            return;
        }
        let (w, cur, count) = (self.width, &self.cur, &self.count);
        if self.exact {
            for_each_row_sum_exact(
                cur,
                w,
                self.height,
                self.radius,
                &mut self.next,
                |r, next, sums| {
                    let o = r * w;
                    let (cur, count) = (&cur[o..o + w], &count[o..o + w]);
                    for (((n, &s), &c), &k) in next.iter_mut().zip(sums).zip(cur).zip(count) {
                        // As below, in f64 from the exact sum: a constant field stays exactly
                        // constant (s = k·c exactly).
                        *n = if k > 0.0 {
                            (0.5 * (f64::from(c) + s / f64::from(k))) as f32
                        } else {
                            c
                        };
                    }
                },
            );
            std::mem::swap(&mut self.cur, &mut self.next);
            return;
        }
        // Sum and finish each tile while it is in L1 (one pass over the grid).
        for_each_row_sum(
            cur,
            w,
            self.height,
            self.radius,
            &mut self.next,
            |r, t0, next, sums| {
                let o = r * w + t0;
                let (cur, count) = (&cur[o..o + next.len()], &count[o..o + next.len()]);
                for (((n, &s), &c), &k) in next.iter_mut().zip(sums).zip(cur).zip(count) {
                    // Valid with neighbours: (own + sum/count)/2 (a constant field stays exactly
                    // constant). Isolated or nodata (k = 0): keep own (nodata is stored as 0).
                    *n = if k > 0.0 { 0.5 * (c + s / k) } else { c };
                }
            },
        );
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
                        if let Some(Ok(s)) =
                            pad.get(o..o + 2 * LANES).map(<&[f32; 2 * LANES]>::try_from)
                        {
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
        });
}

/// Radius from which [`Smoother`] sums the diamonds with [`for_each_row_sum_exact`] (O(1) per
/// cell) instead of [`for_each_row_sum`] (O(n²) per cell, vectorised). Below it the direct sum
/// is as fast or faster and keeps the paper preset's radius 3 bit-identical to the first
/// versions; from it (metre-based smoothing on fine DEMs: 70 m over 10–13 m cells gives
/// n = 6–7) the exact sums are faster. Measured on the 4,096² Colorado grid, 5 passes + counts,
/// one thread, load ≈ 12 (session 17, `engine/examples`-style driver around
/// [`smooth_diamond`]): direct n = 5 0.94–1.09 s vs exact 1.14–1.72 s; direct n = 7
/// 1.53–2.26 s vs exact 1.18–1.31 s.
pub const EXACT_FROM: usize = 6;

/// Rows per rayon task of [`for_each_row_sum_exact`]: each task first builds `2n + 1` rows of
/// prefix sums above its rows, so tasks are taller than [`BAND_ROWS`].
const EXACT_BAND_ROWS: usize = 128;

/// Per-worker scratch of [`for_each_row_sum_exact`]: ring buffers of diagonal prefix rows and
/// one row of sums.
#[derive(Default)]
struct ExactScratch {
    q1: Vec<f64>,
    q2: Vec<f64>,
    delta: Vec<f64>,
    sums: Vec<f64>,
}

/// Calls `f(row, out row, diamond sums of the row)` for every row, where the sums are
/// `Σ src[cell + offset]` over the diamond offsets `1 ≤ |di| + |dj| ≤ n` that fall inside the
/// grid, in `f64`; `src` must not hold NaN. The same sums as [`for_each_row_sum`], in O(1)
/// per cell whatever `n`:
///
/// * prefix sums along both diagonals, `Q1(r, c) = src(r, c) + Q1(r − 1, c − 1)` and
///   `Q2(r, c) = src(r, c) + Q2(r − 1, c + 1)` (zero outside the grid), give the sum over any
///   diagonal segment as one difference;
/// * the diamond `|a| + |b| ≤ n` around `(i, j)` differs from the one around `(i, j − 1)` by its
///   right boundary (two diagonal segments meeting at `(i, j + n)`) added and the left boundary
///   of the old one (meeting at `(i, j − 1 − n)`) removed, so along a row the full diamond sum
///   is a running sum of four segment differences per side, started at `j = −n − 1` where the
///   diamond lies wholly outside the grid (sum 0); the centre is subtracted at the end.
///
/// Everything is in `f64`: a sum of `f32` heights of one magnitude is exact there (53 bits hold
/// the 24 of each value and the ≤ 2²⁶ terms along a diagonal), so these sums are at least as
/// accurate as the direct `f32` accumulation, though not bit-identical to it. Rows are split
/// into bands over rayon; each band builds its prefix rows from `2n + 1` rows above it (the
/// differences cancel whatever lies above), so the result does not depend on the thread count.
/// The prefix rows live in rings of `2n + 2` rows per worker (≈ 1 MB at n = 7 on 4,096 columns).
fn for_each_row_sum_exact<F>(
    src: &[f32],
    width: usize,
    height: usize,
    n: usize,
    out: &mut [f32],
    f: F,
) where
    F: Fn(usize, &mut [f32], &[f64]) + Sync,
{
    // Padded columns: 2n + 1 zero columns on the left (the running sum starts at j = −n − 1 and
    // reads down to column j − 1 − n), n on the right.
    let left = 2 * n + 1;
    let pw = left + width + n;
    let ring = 2 * n + 2;
    let h = height as isize;
    let ni = n as isize;
    out.par_chunks_mut(width * EXACT_BAND_ROWS)
        .enumerate()
        .for_each_init(ExactScratch::default, |s, (band, rows)| {
            let r0 = (band * EXACT_BAND_ROWS) as isize;
            let r1 = r0 + (rows.len() / width) as isize;
            s.q1.clear();
            s.q1.resize(ring * pw, 0.0);
            s.q2.clear();
            s.q2.resize(ring * pw, 0.0);
            s.sums.resize(width, 0.0);
            s.delta.resize(width + n, 0.0);
            let slot = |r: isize| (r.rem_euclid(ring as isize)) as usize * pw;
            // Prefix row `r` from row `r − 1` (already in the ring) and the source row `r`.
            let build = |q1: &mut [f64], q2: &mut [f64], r: isize| {
                let row = (0..h)
                    .contains(&r)
                    .then(|| &src[r as usize * width..][..width]);
                // Q1(r, c) = src(r, c) + Q1(r − 1, c − 1).
                let (cur, prev) = rows_of(q1, slot(r), slot(r - 1), pw);
                cur[0] = 0.0;
                shifted_add(&mut cur[1..], &prev[..pw - 1], row, left - 1);
                // Q2(r, c) = src(r, c) + Q2(r − 1, c + 1).
                let (cur, prev) = rows_of(q2, slot(r), slot(r - 1), pw);
                cur[pw - 1] = 0.0;
                shifted_add(&mut cur[..pw - 1], &prev[1..], row, left);
            };
            // The baseline row r0 − n − 1 is all zeros (the ring starts zeroed); build up to
            // r0 + n − 1 before the first output row.
            let base = r0 - ni - 1;
            {
                let (q1, q2) = (&mut s.q1, &mut s.q2);
                let z = slot(base);
                q1[z..z + pw].fill(0.0);
                q2[z..z + pw].fill(0.0);
                for r in base + 1..r0 + ni {
                    build(q1, q2, r);
                }
            }
            for (i, out_row) in (r0..r1).zip(rows.chunks_mut(width)) {
                build(&mut s.q1, &mut s.q2, i + ni);
                let (q1, q2) = (&s.q1, &s.q2);
                let (t, m, b) = (slot(i - ni - 1), slot(i), slot(i + ni));
                let (t1, m1, b1) = (&q1[t..t + pw], &q1[m..m + pw], &q1[b..b + pw]);
                let (t2, m2, b2) = (&q2[t..t + pw], &q2[m..m + pw], &q2[b..b + pw]);
                // Column j of the grid is padded column j + left. The running sum starts at
                // padded column j0 = left − n (j = −n, the first diamond reaching the grid):
                // first every step's change (independent: vectorised), then the running sum.
                let j0 = left - n;
                let len = width + n;
                let d = &mut s.delta[..len];
                // Right boundary of the diamond at jj, left boundary of the one at jj − 1.
                let (r1, r1t) = (&m1[j0 + n..][..len], &t1[j0 - 1..][..len]);
                let (r2b, r2m) = (&b2[j0..][..len], &m2[j0 + n..][..len]);
                let (l2m, l2t) = (&m2[j0 - 1 - n..][..len], &t2[j0..][..len]);
                let (l1b, l1m) = (&b1[j0 - 1..][..len], &m1[j0 - 1 - n..][..len]);
                for k in 0..len {
                    let right = (r1[k] - r1t[k]) + (r2b[k] - r2m[k]);
                    let gone = (l2m[k] - l2t[k]) + (l1b[k] - l1m[k]);
                    d[k] = right - gone;
                }
                let mut sum: f64 = d[..n].iter().sum();
                let src_row = &src[i as usize * width..][..width];
                for ((o, &dk), &v) in s.sums.iter_mut().zip(&d[n..]).zip(src_row) {
                    sum += dk;
                    *o = sum - f64::from(v);
                }
                f(i as usize, out_row, &s.sums);
            }
        });
}

/// Rows `a` (mutable) and `b` of a ring of `pw`-long rows (`a ≠ b`).
fn rows_of(q: &mut [f64], a: usize, b: usize, pw: usize) -> (&mut [f64], &[f64]) {
    if a < b {
        let (lo, hi) = q.split_at_mut(b);
        (&mut lo[a..a + pw], &hi[..pw])
    } else {
        let (lo, hi) = q.split_at_mut(a);
        (&mut hi[..pw], &lo[b..b + pw])
    }
}

/// `cur[k] = prev[k] + v(k)` where `v(k)` is `row[k − at]` inside the row, 0 outside
/// (`cur` and `prev` of one length).
fn shifted_add(cur: &mut [f64], prev: &[f64], row: Option<&[f32]>, at: usize) {
    match row {
        Some(row) => {
            let end = at + row.len();
            cur[..at].copy_from_slice(&prev[..at]);
            for ((q, &p), &v) in cur[at..end].iter_mut().zip(&prev[at..end]).zip(row) {
                *q = p + f64::from(v);
            }
            cur[end..].copy_from_slice(&prev[end..]);
        }
        None => cur.copy_from_slice(prev),
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
        for n in 1..=9 {
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

    /// The exact (diagonal prefix) sums equal the direct ones, for radii on both sides of
    /// [`EXACT_FROM`], on a grid narrower and shorter than the diamond too.
    #[test]
    fn exact_sums_match_direct_sums() {
        for (w, h) in [(37usize, 23usize), (5, 300), (200, 3), (1, 1)] {
            let f: Vec<f32> = (0..w * h)
                .map(|i| ((i * 7919) % 101) as f32 * 1.5 + 100.0)
                .collect();
            for n in 1..=9 {
                let mut direct = vec![0.0f32; w * h];
                for_each_row_sum(&f, w, h, n, &mut direct, |r, c0, out, sums| {
                    let _ = (r, c0);
                    out.copy_from_slice(sums);
                });
                let mut exact = vec![0.0f32; w * h];
                for_each_row_sum_exact(&f, w, h, n, &mut exact, |_, out, sums| {
                    for (o, &s) in out.iter_mut().zip(sums) {
                        *o = s as f32;
                    }
                });
                for (i, (a, b)) in exact.iter().zip(&direct).enumerate() {
                    assert!(
                        (a - b).abs() <= 1e-6 * b.abs().max(1.0),
                        "{w}×{h} n={n} cell {i}: exact {a} vs direct {b}"
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
        for n in [3, 7] {
            let got = smooth_diamond(&f, w, h, n, 5);
            for (a, b) in got.iter().zip(&f) {
                if b.is_nan() {
                    assert!(a.is_nan());
                } else {
                    assert_eq!(*a, 1234.5, "n = {n}");
                }
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
