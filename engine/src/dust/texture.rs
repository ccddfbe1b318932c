//! The shell textures as the renderer samples them: each fibre texture ([`super::fibers`]) as
//! 8-bit premultiplied grey and alpha with a mip pyramid, sampled trilinearly with wrap-around
//! (the textures tile).
//!
//! **Mip levels** halve each side (rounding up) down to 1×1; a texel of level l+1 is the box mean
//! of the 2×2 texels under it (premultiplied, so coverage and brightness average correctly), the
//! pair wrapping to the first row/column when a side is odd. Far views sample coarse levels and
//! the fibres blend into a soft layer instead of flickering.
//!
//! Cost: 2 bytes per texel, 4/3 of that with the pyramid (0.7 MB at 512²); building it is one
//! pass per level. Sampling is 8 texel reads.

use super::fibers::FiberTexture;

/// One mip level: `side`², texels (premultiplied grey, alpha) as bytes.
#[derive(Debug, Clone, PartialEq)]
struct Level {
    side: usize,
    texels: Vec<[u8; 2]>,
}

/// A shell texture with its mip pyramid (square).
#[derive(Debug, Clone, PartialEq)]
pub struct ShellTexture {
    levels: Vec<Level>,
}

impl ShellTexture {
    /// Quantises `tex` (square) to bytes and builds the pyramid. Allocates.
    pub fn new(tex: &FiberTexture) -> Self {
        let side = tex.width as usize;
        let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
        let base: Vec<[u8; 2]> = tex
            .luminance
            .iter()
            .zip(&tex.alpha)
            .map(|(l, a)| [q(*l), q(*a)])
            .collect();
        let mut levels = vec![Level { side, texels: base }];
        while let Some(prev) = levels.last().filter(|l| l.side > 1) {
            let (s, n) = (prev.side, prev.side.div_ceil(2));
            let at = |x: usize, y: usize| prev.texels[(y % s) * s + (x % s)];
            let mut texels = Vec::with_capacity(n * n);
            for y in 0..n {
                for x in 0..n {
                    let c = [
                        at(2 * x, 2 * y),
                        at(2 * x + 1, 2 * y),
                        at(2 * x, 2 * y + 1),
                        at(2 * x + 1, 2 * y + 1),
                    ];
                    let avg =
                        |k: usize| ((c.iter().map(|t| u32::from(t[k])).sum::<u32>() + 2) / 4) as u8;
                    texels.push([avg(0), avg(1)]);
                }
            }
            levels.push(Level { side: n, texels });
        }
        Self { levels }
    }

    /// Side of level 0, texels.
    pub fn side(&self) -> usize {
        self.levels[0].side
    }

    /// Mean coverage (alpha) of level 0, 0–1: the share of light the layer stops, on average.
    pub fn mean_alpha(&self) -> f32 {
        let lv = &self.levels[0];
        let sum: u64 = lv.texels.iter().map(|t| u64::from(t[1])).sum();
        (sum as f64 / (lv.texels.len().max(1) as f64 * 255.0)) as f32
    }

    /// Number of levels.
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// Trilinear sample at (s, t) in tiles (any real; wraps) and fractional mip `level` (≥ 0,
    /// clamped to the pyramid): (premultiplied grey, alpha), each 0–1.
    #[inline]
    pub fn sample(&self, s: f32, t: f32, level: f32) -> (f32, f32) {
        let top = (self.levels.len() - 1) as f32;
        let level = level.clamp(0.0, top);
        let l0 = floor(level);
        let f = level - l0;
        let a = self.bilinear(l0 as usize, s, t);
        if f < 1.0 / 64.0 {
            return a;
        }
        let b = self.bilinear(l0 as usize + 1, s, t);
        (a.0 + (b.0 - a.0) * f, a.1 + (b.1 - a.1) * f)
    }

    #[inline]
    fn bilinear(&self, l: usize, s: f32, t: f32) -> (f32, f32) {
        let lv = &self.levels[l.min(self.levels.len() - 1)];
        let n = lv.side;
        let x = (s - floor(s)) * n as f32 - 0.5;
        let y = (t - floor(t)) * n as f32 - 0.5;
        let (xf, yf) = (floor(x), floor(y));
        let (fx, fy) = (x - xf, y - yf);
        let wrap = |v: f32| (v as i64).rem_euclid(n as i64) as usize;
        let (x0, y0) = (wrap(xf), wrap(yf));
        let (x1, y1) = ((x0 + 1) % n, (y0 + 1) % n);
        let tx = |x: usize, y: usize| lv.texels[y * n + x];
        let (a, b, c, d) = (tx(x0, y0), tx(x1, y0), tx(x0, y1), tx(x1, y1));
        let mix = |k: usize| {
            let top = f32::from(a[k]) + (f32::from(b[k]) - f32::from(a[k])) * fx;
            let bottom = f32::from(c[k]) + (f32::from(d[k]) - f32::from(c[k])) * fx;
            (top + (bottom - top) * fy) * (1.0 / 255.0)
        };
        (mix(0), mix(1))
    }
}

/// The noise field at texel resolution (square, row-major), read at the nearest texel of (s, t)
/// in tiles (wraps).
#[inline]
pub fn noise_at(noise: &[f32], side: usize, s: f32, t: f32) -> f32 {
    let x = (((s - floor(s)) * side as f32) as usize).min(side - 1);
    let y = (((t - floor(t)) * side as f32) as usize).min(side - 1);
    noise[y * side + x]
}

/// `x.floor()` without the libm call the x86-64 baseline makes of it (no SSE4.1 `roundss`); exact
/// for |x| < 2³¹, which texture coordinates in tiles stay far below. Measured: `floorf` was 2.6 %
/// of a dust render's profile.
#[inline]
fn floor(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t > x {
        t - 1.0
    } else {
        t
    }
}
