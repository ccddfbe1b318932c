//! DEMs built from real ones for the benchmarks and profiling drivers.

use crate::geom::Dem;

/// `w × h` window of `src` tiled by mirroring (row 0 / column 0 at the source's north-west): a
/// real terrain's texture at any size, with no seams (the benchmarks' 2048² and 4096² inputs).
pub fn mirrored(src: &Dem, w: usize, h: usize) -> Dem {
    let fold = |i: usize, n: usize| {
        let p = i % (2 * n);
        if p < n {
            p
        } else {
            2 * n - 1 - p
        }
    };
    let mut heights = Vec::with_capacity(w * h);
    for r in 0..h {
        let sr = fold(r, src.height);
        for c in 0..w {
            heights.push(src.heights[sr * src.width + fold(c, src.width)]);
        }
    }
    Dem {
        width: w,
        height: h,
        heights,
        dx: src.dx,
        dy: src.dy,
        georef: Default::default(),
    }
}
