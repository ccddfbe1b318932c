//! Empty-space skipping for the camera-ray march ([`super::march`]): a coarse grid of blocks
//! over the renderer's padded cell grid, each holding its Chebyshev (L∞) distance, in blocks, to
//! the nearest block that holds density. A ray standing in a block at distance d ≥ 1 may leap to
//! the exit of the cube of (2d − 1)³ blocks around it: every sample it passes reads only zero
//! densities, so skipping is exact (the bytes are those of a march that visits every sample).
//!
//! A block covers the cells whose *floor* lies in `[B·b, B·b + B)` (B = [`BLOCK`]) along each
//! axis; a trilinear sample there reads cells up to `B·b + B`, so a block is occupied when any
//! cell in `[B·b, B·b + B]³` has ρ > 0. The distance transform is separable for L∞
//! (`d = min over y of max(|x₀ − y₀|, |x₁ − y₁|, |x₂ − y₂|)` nests axis by axis) and capped at
//! [`MAX_LEAP`] blocks, so each axis pass looks at most that far. Cost: one pass over the cells
//! (row flags), then O(blocks · [`MAX_LEAP`]).
//!
//! Rejected: the former fixed 8³ bricks (a ray crossed empty air one brick at a time, 32 bricks
//! through a 256³ box, and each test cost a division per sample) and a min/max mip pyramid
//! (a tree walk per leap; the distance grid answers with one byte).

use rayon::prelude::*;

use crate::geom::Volume;

/// Edge of a block, cells.
pub const BLOCK: usize = 4;
/// Largest distance stored (blocks): the longest single leap is 2·`MAX_LEAP` − 1 blocks.
pub const MAX_LEAP: u8 = 16;

/// One pass over the densities: which rows hold density. The renderer's transmittance sweep
/// skips the rest ([`super::light`]) and [`EmptySpace`] is built from it.
#[derive(Debug, Clone)]
pub struct DensityRows {
    dims: [usize; 3],
    /// Any ρ > 0 in the x-row (y, z), at `y + ny·z`.
    rows: Vec<bool>,
    /// Any ρ > 0 in the y-column (x, z), at `x + nx·z`.
    cols: Vec<bool>,
    /// Per x-row and block column `bx` of the padded grid (cells `[B·bx, B·bx + B]`, the
    /// border cells repeating the end voxels): any ρ > 0, at `(y + ny·z)·nbx + bx`.
    blocks: Vec<bool>,
    nbx: usize,
}

impl DensityRows {
    /// Reads every density once (in parallel over z). Allocates about `(2 + nx/4)` bytes per
    /// x-row.
    pub fn of(volume: &Volume) -> Self {
        let [nx, ny, nz] = volume.dims;
        let nbx = blocks_for(nx + 2);
        let mut rows = vec![false; ny * nz];
        let mut cols = vec![false; nx * nz];
        let mut blocks = vec![false; ny * nz * nbx];
        rows.par_chunks_mut(ny)
            .zip(cols.par_chunks_mut(nx))
            .zip(blocks.par_chunks_mut(ny * nbx))
            .enumerate()
            .for_each(|(z, ((rows, cols), blocks))| {
                for (y, (any, bl)) in rows.iter_mut().zip(blocks.chunks_mut(nbx)).enumerate() {
                    let row = &volume.density[nx * (y + ny * z)..][..nx];
                    for (x, (&r, col)) in row.iter().zip(cols.iter_mut()).enumerate() {
                        if r > 0.0 {
                            *any = true;
                            *col = true;
                            // Padded cell x + 1, and the border cells that repeat the ends.
                            let mut mark = |c: usize| {
                                bl[(c / BLOCK).min(nbx - 1)] = true;
                                if c % BLOCK == 0 && c >= BLOCK {
                                    bl[c / BLOCK - 1] = true;
                                }
                            };
                            mark(x + 1);
                            if x == 0 {
                                mark(0);
                            }
                            if x + 1 == nx {
                                mark(nx + 1);
                            }
                        }
                    }
                }
            });
        Self {
            dims: volume.dims,
            rows,
            cols,
            blocks,
            nbx,
        }
    }

    /// Whether row `ib` of slice `ik` across axis `k` holds density, for the slices of
    /// [`super::light`]: (a, b) = (y, z) for k = x, (x, z) for k = y, (x, y) for k = z.
    #[inline]
    pub fn slice_row(&self, k: usize, ik: usize, ib: usize) -> bool {
        let [nx, ny, _] = self.dims;
        match k {
            0 => self.cols[ik + nx * ib],
            1 => self.rows[ik + ny * ib],
            _ => self.rows[ib + ny * ik],
        }
    }
}

/// Blocks along an axis of `pad` padded cells: over floor positions 0 ..= pad − 2 (the last
/// cell is only ever read as "+1").
fn blocks_for(pad: usize) -> usize {
    pad.saturating_sub(2) / BLOCK + 1
}

/// The block distance grid.
#[derive(Debug, Clone)]
pub struct EmptySpace {
    /// Blocks per axis.
    pub nb: [usize; 3],
    /// Distance to the nearest occupied block, blocks, capped at [`MAX_LEAP`] (0 = occupied).
    pub dist: Vec<u8>,
    /// The box `[lo, hi)` of cells, as floor positions, that holds every occupied block; `None`
    /// when no cell has density. Samples outside it read only zeros.
    pub occupied: Option<([usize; 3], [usize; 3])>,
}

impl EmptySpace {
    /// Builds the grid over the padded cell grid (`dims + 2`, the border repeating the faces)
    /// of the volume that `rows` describes. Allocates one byte per block.
    pub fn build(rows: &DensityRows) -> Self {
        let [nx, ny, nz] = rows.dims;
        let pad = [nx + 2, ny + 2, nz + 2];
        let nb = pad.map(blocks_for);
        debug_assert_eq!(nb[0], rows.nbx);
        // Padded row (py, pz) repeats voxel row (py − 1, pz − 1), clamped.
        let voxel_row = |py: usize, pz: usize| {
            let y = py.saturating_sub(1).min(ny - 1);
            let z = pz.saturating_sub(1).min(nz - 1);
            &rows.blocks[(y + ny * z) * nb[0]..][..nb[0]]
        };
        let block_range = |b: usize, n: usize| (b * BLOCK)..((b * BLOCK + BLOCK + 1).min(n));
        let mut occ = vec![false; nb[0] * nb[1] * nb[2]];
        occ.par_chunks_mut(nb[0] * nb[1])
            .enumerate()
            .for_each(|(bz, layer)| {
                for pz in block_range(bz, pad[2]) {
                    for by in 0..nb[1] {
                        for py in block_range(by, pad[1]) {
                            let r = voxel_row(py, pz);
                            for (o, &f) in layer[nb[0] * by..][..nb[0]].iter_mut().zip(r) {
                                *o |= f;
                            }
                        }
                    }
                }
            });
        let mut dist: Vec<u8> = occ.iter().map(|&o| if o { 0 } else { MAX_LEAP }).collect();
        for axis in 0..3 {
            chebyshev_pass(&mut dist, nb, axis);
        }
        // Bounding box of the occupied blocks, in cells.
        let mut bounds: Option<([usize; 3], [usize; 3])> = None;
        for (i, _) in occ.iter().enumerate().filter(|(_, &o)| o) {
            let b = [i % nb[0], (i / nb[0]) % nb[1], i / (nb[0] * nb[1])];
            let (lo, hi) = bounds.get_or_insert((b, b));
            for k in 0..3 {
                lo[k] = lo[k].min(b[k]);
                hi[k] = hi[k].max(b[k]);
            }
        }
        let occupied = bounds.map(|(lo, hi)| (lo.map(|b| b * BLOCK), hi.map(|b| (b + 1) * BLOCK)));
        Self { nb, dist, occupied }
    }

    /// Distance of the block holding the cell whose floor is `(x, y, z)`.
    #[inline]
    pub fn at(&self, x: usize, y: usize, z: usize) -> u8 {
        let (bx, by, bz) = (x / BLOCK, y / BLOCK, z / BLOCK);
        self.dist[bx + self.nb[0] * (by + self.nb[1] * bz)]
    }
}

/// One axis of the separable L∞ distance: `d'(i) = min over |j − i| < cap of max(|j − i|, d(j))`.
fn chebyshev_pass(dist: &mut [u8], nb: [usize; 3], axis: usize) {
    let stride = [1, nb[0], nb[0] * nb[1]][axis];
    let n = nb[axis];
    let cap = usize::from(MAX_LEAP);
    let lines: Vec<usize> = (0..dist.len()).filter(|&i| (i / stride) % n == 0).collect();
    let src = dist.to_vec();
    let out: Vec<Vec<u8>> = lines
        .par_iter()
        .map(|&start| {
            let line: Vec<u8> = (0..n).map(|i| src[start + i * stride]).collect();
            (0..n)
                .map(|i| {
                    let lo = i.saturating_sub(cap - 1);
                    let hi = (i + cap).min(n);
                    (lo..hi)
                        .map(|j| (i.abs_diff(j) as u8).max(line[j]))
                        .min()
                        .unwrap_or(MAX_LEAP)
                })
                .collect()
        })
        .collect();
    for (&start, line) in lines.iter().zip(&out) {
        for (i, &v) in line.iter().enumerate() {
            dist[start + i * stride] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against brute force on a small volume with two dense voxels (one on a face, so the
    /// padded border counts).
    #[test]
    fn distances_are_chebyshev_in_blocks() {
        let dims = [30, 23, 41];
        let voxels = [(5usize, 5usize, 5usize), (29, 2, 33)];
        let mut d = vec![0f32; dims[0] * dims[1] * dims[2]];
        for &(x, y, z) in &voxels {
            d[x + dims[0] * (y + dims[1] * z)] = 1.0;
        }
        let v = Volume::new(dims, d, ([0.0; 3], [1.0; 3])).unwrap();
        let e = EmptySpace::build(&DensityRows::of(&v));
        // Padded cell c repeats voxel clamp(c − 1).
        let occupied = |c: [usize; 3]| {
            let vox: [usize; 3] = std::array::from_fn(|k| c[k].saturating_sub(1).min(dims[k] - 1));
            voxels.contains(&(vox[0], vox[1], vox[2]))
        };
        let occ_block = |b: [usize; 3]| {
            let r = |k: usize| (b[k] * BLOCK)..=((b[k] * BLOCK + BLOCK).min(dims[k] + 1));
            r(2).any(|z| r(1).any(|y| r(0).any(|x| occupied([x, y, z]))))
        };
        let mut occ_list = vec![];
        for bz in 0..e.nb[2] {
            for by in 0..e.nb[1] {
                for bx in 0..e.nb[0] {
                    if occ_block([bx, by, bz]) {
                        occ_list.push([bx, by, bz]);
                    }
                }
            }
        }
        assert!(occ_list.len() >= 2);
        for bz in 0..e.nb[2] {
            for by in 0..e.nb[1] {
                for bx in 0..e.nb[0] {
                    let want = occ_list
                        .iter()
                        .map(|o| {
                            bx.abs_diff(o[0])
                                .max(by.abs_diff(o[1]))
                                .max(bz.abs_diff(o[2]))
                        })
                        .min()
                        .unwrap()
                        .min(usize::from(MAX_LEAP));
                    let got = e.dist[bx + e.nb[0] * (by + e.nb[1] * bz)];
                    assert_eq!(usize::from(got), want, "block {bx} {by} {bz}");
                }
            }
        }
    }

    #[test]
    fn slice_rows_name_the_dense_rows() {
        let dims = [5, 6, 7];
        let mut d = vec![0f32; 5 * 6 * 7];
        d[2 + 5 * (3 + 6 * 4)] = 0.5; // (2, 3, 4)
        let v = Volume::new(dims, d, ([0.0; 3], [1.0; 3])).unwrap();
        let r = DensityRows::of(&v);
        // Across x: slice x = 2, row (y, z) = column z = 4. Across y: slice 3, row z = 4.
        // Across z: slice 4, row y = 3.
        for (k, ik, ib) in [(0, 2, 4), (1, 3, 4), (2, 4, 3)] {
            assert!(r.slice_row(k, ik, ib));
            assert!(!r.slice_row(k, ik, ib - 1));
            assert!(!r.slice_row(k, ik - 1, ib));
        }
    }
}
