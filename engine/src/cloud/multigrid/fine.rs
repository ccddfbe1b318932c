//! The fine level: the LLW system on the cloud voxels that a pin reaches, as a [`Graph`] (see
//! [`super::graph`]) in red–black order, with its right-hand side.
//!
//! Every level is held as *conductances* `c_ij = −A_ij` (i ≠ j) and an *excess*
//! `s_i = Σ_j A_ij` (the row sum; on the fine level the affinities to pinned voxels), so
//! `(A e)_i = s_i e_i + Σ_j c_ij (e_i − e_j)`. Residuals are taken in that difference form,
//! which keeps the near-null space (almost constant fields far from the pins, whose
//! eigenvalues are tiny next to the diagonal) exact in f32 where `diag·e_i − Σ c e_j` would
//! lose it to cancellation.
//!
//! *The unknowns* are the free (unpinned) cloud voxels connected to a pin through cloud voxels
//! (SPEC §3.2: "propagate the pins to all cloud voxels"). Empty voxels are not unknowns — the
//! renderer weights the ambient by ρ (see [`crate::cloud::march`]), so their values never show
//! — and a puff no pin reaches has no equation that fixes its colour (the LLW system there is
//! singular); its voxels are left to the caller ([`super::propagate`]'s `fill`). The edges are
//! the LLW affinities between face neighbours, both in the cloud.
//!
//! *Numbering*: the unknowns with `x + y + z` even first (red), then the odd ones (black), each
//! in grid order. The 7-point stencil only couples red with black, so the two colour ranges make
//! the multicolour Gauss–Seidel of [`Graph::smooth`] a red–black sweep, and the aggregation still
//! meets each colour in grid order.

use rayon::prelude::*;

use super::graph::Graph;

/// Not an unknown.
pub(super) const NONE: u32 = u32::MAX;

/// The fine level of a propagation problem.
pub(super) struct FineLevel {
    /// The LLW operator on the unknowns.
    pub op: Graph,
    /// The right-hand side: `Σ a_ij X_j` over each unknown's pinned neighbours j (colours X).
    pub b: Vec<[f64; 3]>,
    /// The voxel of each unknown.
    pub voxel: Vec<u32>,
    /// The unknowns in grid order (red and black interleaved as in the grid): the order the
    /// fine level's aggregation meets them in, so that aggregates grow as on the grid and not
    /// colour by colour (measured on the full-box cumulus at 128³: the colour order gave a
    /// 4.7× iteration where grid order keeps every one ≥ 5×).
    pub grid_order: Vec<u32>,
    /// Whether each voxel is a pin or connected to one through cloud voxels.
    pub reached: Vec<bool>,
}

/// Calls `edge(a, neighbour)` for each of voxel `i`'s grid neighbours (at `[x, y, z]` in a grid
/// of `dims`) in the order −x, +x, −y, +y, −z, +z, with the affinity of the link between them
/// (`a[min(i, n)][axis]`). The fixed order keeps sums bit-identical.
#[inline(always)]
fn for_each_edge(
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

/// The voxels reached from the pins (`pin_at` ≠ [`NONE`]) through edges of non-zero affinity
/// between cloud voxels, by a flood fill.
fn reach(dims: [usize; 3], a: &[[f32; 3]], cloud: &[bool], pin_at: &[u32]) -> Vec<bool> {
    let [nx, ny, _] = dims;
    let mut reached: Vec<bool> = pin_at.par_iter().map(|&p| p != NONE).collect();
    let mut stack: Vec<u32> = (0..pin_at.len())
        .filter(|&i| reached[i])
        .map(|i| i as u32)
        .collect();
    while let Some(i) = stack.pop() {
        let i = i as usize;
        let at = [i % nx, (i / nx) % ny, i / (nx * ny)];
        for_each_edge(a, dims, at, i, &mut |w, j| {
            if w > 0.0 && !reached[j] && cloud[j] {
                reached[j] = true;
                stack.push(j as u32);
            }
        });
    }
    reached
}

/// Rows per parallel task.
const CHUNK: usize = 2048;

/// Builds the fine level of the LLW system with affinities `a` (see [`super::llw_weights`]) on
/// the grid of `dims`: `cloud` marks the cloud voxels, `pin_at` each voxel's pin (an index into
/// `colours`, or [`NONE`]); `screening` (λ ≥ 0) is added to every unknown's excess
/// ([`super::SolveOptions::screening`]).
pub(super) fn fine_level(
    dims: [usize; 3],
    a: &[[f32; 3]],
    cloud: &[bool],
    pin_at: &[u32],
    colors: &[[f32; 3]],
    screening: f32,
) -> FineLevel {
    let [nx, ny, _] = dims;
    let n = a.len();
    let reached = reach(dims, a, cloud, pin_at);
    let free = |i: usize| reached[i] && pin_at[i] == NONE;
    let red = |i: usize| (i % nx + (i / nx) % ny + i / (nx * ny)) % 2 == 0;
    // Red unknowns, then black ones, each in grid order.
    let of_color = |color: bool| -> Vec<u32> {
        (0..n)
            .into_par_iter()
            .filter(|&i| free(i) && red(i) == color)
            .map(|i| i as u32)
            .collect()
    };
    let mut voxel = of_color(true);
    let red_count = voxel.len();
    voxel.extend(of_color(false));
    let mut index = vec![NONE; n];
    for (u, &i) in voxel.iter().enumerate() {
        index[i as usize] = u as u32;
    }
    let grid_order: Vec<u32> = index.iter().copied().filter(|&u| u != NONE).collect();
    type Part = (Vec<usize>, Vec<u32>, Vec<f32>, Vec<f32>, Vec<[f64; 3]>);
    let parts: Vec<Part> = voxel
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut lens = Vec::with_capacity(chunk.len());
            let mut col = Vec::with_capacity(6 * chunk.len());
            let mut c = Vec::with_capacity(6 * chunk.len());
            let mut excess = Vec::with_capacity(chunk.len());
            let mut b = Vec::with_capacity(chunk.len());
            for &i in chunk {
                let i = i as usize;
                let at = [i % nx, (i / nx) % ny, i / (nx * ny)];
                let (mut len, mut s, mut rhs) = (0, 0f32, [0f64; 3]);
                for_each_edge(a, dims, at, i, &mut |w, j| {
                    if w <= 0.0 {
                        return;
                    }
                    if pin_at[j] != NONE {
                        let x = colors[pin_at[j] as usize];
                        s += w;
                        for q in 0..3 {
                            rhs[q] += f64::from(w) * f64::from(x[q]);
                        }
                    } else if index[j] != NONE {
                        col.push(index[j]);
                        c.push(w);
                        len += 1;
                    }
                });
                lens.push(len);
                excess.push(s + screening);
                b.push(rhs);
            }
            (lens, col, c, excess, b)
        })
        .collect();
    let mut ptr = Vec::with_capacity(voxel.len() + 1);
    ptr.push(0);
    let (mut col, mut c) = (Vec::new(), Vec::new());
    let (mut excess, mut b) = (
        Vec::with_capacity(voxel.len()),
        Vec::with_capacity(voxel.len()),
    );
    for (lens, co, cv, ex, bv) in parts {
        for l in lens {
            ptr.push(ptr[ptr.len() - 1] + l);
        }
        col.extend(co);
        c.extend(cv);
        excess.extend(ex);
        b.extend(bv);
    }
    let colors = if red_count == 0 || red_count == voxel.len() {
        vec![0, voxel.len()]
    } else {
        vec![0, red_count, voxel.len()]
    };
    FineLevel {
        op: Graph {
            ptr,
            col,
            c,
            excess,
            colors,
        },
        b,
        voxel,
        grid_order,
        reached,
    }
}
