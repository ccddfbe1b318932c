//! Perlin noise for the dust (SPEC §4 steps 2–3; paper §2.2 and §2.3.1–2.3.3): fBm of the `noise`
//! crate's improved Perlin noise, seeded, with `noise_scale` and `noise_octaves`, tileable over a
//! texture.
//!
//! The paper uses one Perlin field for three things: the bumps of the dust layer (§2.2), the
//! probability of placing a fibre's start point (§2.3.1) and a fibre's starting brightness
//! (§2.3.3). All three need values in [0, 1]; we map the fBm output f ∈ [−1, 1] to
//! clamp(0.5 + 0.5·f·[`CONTRAST`], 0, 1) — `CONTRAST` stretches 4-D Perlin fBm, whose values
//! rarely leave ±0.5, to use the whole range.
//!
//! **Tiling** (the paper's textures tile across the mesh, SPEC §4 step 3): texture coordinates
//! (u, v) ∈ [0, 1)² are mapped onto two circles, (R cos 2πu, R sin 2πu, R cos 2πv, R sin 2πv), and
//! the 4-D fBm is sampled there, so u = 0 and u = 1 are the same point and the texture wraps
//! seamlessly for any octave count and lacunarity. R = `noise_scale` / 2π: `noise_scale` is the
//! number of base-octave noise cells around the texture (cycles per texture width). Rejected: the
//! crate's 2-D noise with mirrored or blended edges (visible symmetry or a soft seam).
//!
//! Cost: one 4-D Perlin evaluation per octave per sample; [`TileableNoise::texture`] is parallel
//! over rows and allocates the result.

use noise::{Fbm, MultiFractal, NoiseFn, Perlin};
use rayon::prelude::*;

/// Stretch of the fBm output before clamping to [0, 1] (module doc).
pub const CONTRAST: f64 = 1.6;

/// Seeded, tileable Perlin fBm on the unit square (period 1 in u and v).
#[derive(Debug, Clone)]
pub struct TileableNoise {
    fbm: Fbm<Perlin>,
    radius: f64,
}

impl TileableNoise {
    /// `seed`: any u64 (folded to the crate's u32 seed); `noise_scale` > 0: base-octave cells per
    /// texture width; `octaves` ≥ 1 (clamped to the crate's 32).
    pub fn new(seed: u64, noise_scale: f64, octaves: usize) -> Self {
        let seed32 = (seed ^ (seed >> 32)) as u32;
        let fbm = Fbm::<Perlin>::new(seed32)
            .set_octaves(octaves.clamp(1, Fbm::<Perlin>::MAX_OCTAVES))
            .set_frequency(1.0)
            .set_lacunarity(2.0)
            .set_persistence(0.5);
        Self {
            fbm,
            radius: noise_scale.max(1e-6) / std::f64::consts::TAU,
        }
    }

    /// The noise at texture coordinates (u, v), period 1 in both, in [0, 1].
    #[inline]
    pub fn sample(&self, u: f64, v: f64) -> f32 {
        let (a, b) = (u * std::f64::consts::TAU, v * std::f64::consts::TAU);
        let r = self.radius;
        let f = self
            .fbm
            .get([r * a.cos(), r * a.sin(), r * b.cos(), r * b.sin()]);
        (0.5 + 0.5 * f * CONTRAST).clamp(0.0, 1.0) as f32
    }

    /// The noise at texel centres of a `width` × `height` texture, row-major, in [0, 1]. Parallel
    /// over rows; the same values for any thread count. Allocates.
    pub fn texture(&self, width: u32, height: u32) -> Vec<f32> {
        let (w, h) = (width as usize, height as usize);
        let mut out = vec![0.0f32; w * h];
        if w == 0 {
            return out;
        }
        out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let v = (y as f64 + 0.5) / h as f64;
            for (x, o) in row.iter_mut().enumerate() {
                *o = self.sample((x as f64 + 0.5) / w as f64, v);
            }
        });
        out
    }
}
