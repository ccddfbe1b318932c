//! A band's buffers: the visibility buffer of sample keys and the mask of pixels to refine.

/// A band's visibility buffer for rows `y0..y0 + rows` of the image, `ns` samples per pixel:
/// [`Rasterizer::rasterize_band`] stores `ns` sample planes of `width × rows` (its span loop
/// walks one plane's row), [`Rasterizer::rasterize_masked`] a pixel's `ns` samples side by side
/// (it visits scattered pixels, all samples of each: one cache line per pixel instead of `ns`,
/// and the shading pass reads them in the same order). Each sample holds one `u64` key,
/// `(1/z as f32 bits) << 32 | !triangle id` (0 = empty): for positive `f32` the bit patterns
/// order like the values, so the nearer triangle is the larger key, and on equal depth the
/// earlier triangle (smaller id, larger `!id`) wins — one compare-and-select per sample instead
/// of two arrays.
#[derive(Debug, Default, Clone)]
pub struct VisBuffer {
    pub y0: usize,
    pub rows: usize,
    pub width: usize,
    pub ns: usize,
    /// Samples of a pixel side by side (`rasterize_masked`) rather than in planes.
    pub(super) interleaved: bool,
    pub(super) key: Vec<u64>,
    /// Scratch: per sample offset, the three edge functions' offsets of the current triangle.
    pub(super) delta: Vec<[i64; 3]>,
    /// Scratch: per sample offset, the current triangle's 1/z plane at the pixel's origin.
    pub(super) depth_at: Vec<f64>,
}

impl VisBuffer {
    /// Screen-triangle id at sample `s` of pixel (`x`, `y`) (`NO_TRI` = empty); resolve with
    /// [`Rasterizer::fragment`].
    #[inline]
    pub fn at(&self, s: usize, x: usize, y: usize) -> u32 {
        !(self.key[self.index(s, x, y)] as u32)
    }

    /// 1/z at sample `s` of pixel (`x`, `y`) (0 = empty).
    #[inline]
    pub fn depth(&self, s: usize, x: usize, y: usize) -> f32 {
        f32::from_bits((self.key[self.index(s, x, y)] >> 32) as u32)
    }

    #[inline]
    pub(super) fn index(&self, s: usize, x: usize, y: usize) -> usize {
        if self.interleaved {
            ((y - self.y0) * self.width + x) * self.ns + s
        } else {
            (s * self.rows + (y - self.y0)) * self.width + x
        }
    }

    /// Shape the buffer for `ns` samples per pixel of rows `y0..y0 + rows`, `width` wide, in
    /// planes or `interleaved`; the contents are left as they were (the caller clears what it
    /// reads).
    pub(super) fn shape(
        &mut self,
        y0: usize,
        rows: usize,
        width: usize,
        ns: usize,
        interleaved: bool,
    ) {
        self.interleaved = interleaved;
        self.y0 = y0;
        self.rows = rows;
        self.width = width;
        self.ns = ns;
        let n = ns * rows * width;
        if self.key.len() < n {
            self.key.resize(n, 0);
        }
    }
}

/// One bit per pixel for rows `0..rows` of a band: the pixels whose pattern samples
/// [`Rasterizer::rasterize_masked`] rasterises.
#[derive(Debug, Default, Clone)]
pub struct RowMask {
    pub(super) rows: usize,
    pub(super) words: usize,
    pub(super) bits: Vec<u64>,
}

impl RowMask {
    /// All clear, `rows × width`.
    pub fn reset(&mut self, rows: usize, width: usize) {
        self.rows = rows;
        self.words = width.div_ceil(64);
        self.bits.clear();
        self.bits.resize(rows * self.words, 0);
    }

    #[inline]
    pub fn set(&mut self, r: usize, x: usize) {
        self.bits[r * self.words + x / 64] |= 1 << (x % 64);
    }

    #[inline]
    pub fn get(&self, r: usize, x: usize) -> bool {
        self.bits[r * self.words + x / 64] >> (x % 64) & 1 != 0
    }

    /// Row `r`'s words.
    #[inline]
    pub(super) fn row(&self, r: usize) -> &[u64] {
        &self.bits[r * self.words..(r + 1) * self.words]
    }

    /// Calls `f(x)` for every marked pixel of row `r` in `x0..=x1`, left to right.
    #[inline]
    pub(super) fn for_each(&self, r: usize, x0: usize, x1: usize, mut f: impl FnMut(usize)) {
        let row = self.row(r);
        let (w0, w1) = (x0 / 64, x1 / 64);
        for (wi, &word) in row.iter().enumerate().take(w1 + 1).skip(w0) {
            let lo = if wi == w0 { x0 % 64 } else { 0 };
            let hi = if wi == w1 { x1 % 64 } else { 63 };
            let mut m = word & (!0u64 << lo) & (!0u64 >> (63 - hi));
            while m != 0 {
                f(wi * 64 + m.trailing_zeros() as usize);
                m &= m - 1;
            }
        }
    }

    /// True when a pixel of rows `r0..=r1`, columns `x0..=x1` is marked.
    #[inline]
    pub(super) fn any(&self, r0: usize, r1: usize, x0: usize, x1: usize) -> bool {
        let (w0, w1) = (x0 / 64, x1 / 64);
        (w0..=w1).any(|wi| {
            let lo = if wi == w0 { x0 % 64 } else { 0 };
            let hi = if wi == w1 { x1 % 64 } else { 63 };
            let m = (!0u64 << lo) & (!0u64 >> (63 - hi));
            (r0..=r1).any(|r| self.bits[r * self.words + wi] & m != 0)
        })
    }
}
