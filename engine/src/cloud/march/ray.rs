//! The camera-ray march of paper Eqs. 1–3 ([`Prepared::march`]): a ray in padded-cell coordinates,
//! the empty-space leaps and the exact per-segment integration, one loop for the single- and
//! the multiple-scattering sources.

use super::{MsMarch, PixelSample, Prepared, Sources, MIN_TRANSMITTANCE, MS};
use crate::cloud::fastexp::exp_neg;
use crate::cloud::skip::BLOCK;
use crate::geom::camera::Camera;

/// The parameter interval where the ray `o + t·d` is inside the box `[lo, hi]` (t ≥ 0).
#[inline]
fn clip_box(o: [f64; 3], d: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[k];
        let (a, b) = ((lo[k] - o[k]) * inv, (hi[k] - o[k]) * inv);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t1 >= t0).then_some((t0, t1))
}

/// A ray in padded-cell coordinates: sample `i` is at `origin + (i + ½)·step`.
struct GridRay {
    pub origin: [f32; 3],
    pub step: [f32; 3],
    pub inv_step: [f32; 3],
    /// Highest floor cell per axis (`dims`), for clamping.
    pub max: [f32; 3],
}

impl GridRay {
    #[inline]
    fn at(&self, i: usize) -> [f32; 3] {
        let u = i as f32 + 0.5;
        std::array::from_fn(|k| (self.origin[k] + u * self.step[k]).clamp(0.0, self.max[k]))
    }

    /// Index of the first sample at or past the exit of the empty cube of blocks
    /// `[lo, hi)` (cell coordinates) that sample `i` is in; at least `i + 1`.
    #[inline]
    fn leap(&self, i: usize, lo: [f32; 3], hi: [f32; 3]) -> usize {
        // Shrunk by a thousandth of a cell so that rounding never leaps past an occupied cell.
        let mut u_exit = f32::INFINITY;
        for k in 0..3 {
            let s = self.step[k];
            if s > 0.0 {
                u_exit = u_exit.min((hi[k] - 1e-3 - self.origin[k]) * self.inv_step[k]);
            } else if s < 0.0 {
                u_exit = u_exit.min((lo[k] + 1e-3 - self.origin[k]) * self.inv_step[k]);
            }
        }
        // ⌈u_exit − ½⌉ without a libm call (positive here); NaN and ∞ fail the test.
        let x = u_exit - 0.5;
        if x > i as f32 + 1.0 && x < 1e9 {
            let n = x as usize;
            n + usize::from((n as f32) < x)
        } else {
            i + 1
        }
    }
}

impl Prepared {
    /// Marches one ray from `o` along unit `d`. No allocation.
    ///
    /// The samples are those of the whole box (n equal segments of about `step` voxels between
    /// the box's entry and exit), but only those inside the box of occupied blocks are visited.
    pub fn march(&self, o: [f64; 3], d: [f64; 3]) -> PixelSample {
        let empty = PixelSample {
            transmittance: 1.0,
            ..PixelSample::default()
        };
        let f = &self.frame;
        let Some((t0, t1)) = f.clip(o, d) else {
            return empty;
        };
        let Some((lo, hi)) = self.occupied else {
            return empty;
        };
        let Some((ta, tb)) = clip_box(o, d, lo, hi) else {
            return empty;
        };
        let len = t1 - t0;
        let n = f.samples(len, d, self.step);
        let dt = len / n as f64;
        // Samples i with t0 + (i + ½)·dt in [ta, tb], widened by one.
        let first = ((ta - t0) / dt - 1.5).max(0.0) as usize;
        let last = (((tb - t0) / dt + 0.5).max(0.0) as usize + 1).min(n);
        if first >= last {
            return empty;
        }
        // Padded cell coordinate of world p along k: (p − lo)/h − ½ + 1.
        let ray = GridRay {
            origin: std::array::from_fn(|k| ((o[k] + t0 * d[k] - f.lo[k]) / f.h[k] + 0.5) as f32),
            step: std::array::from_fn(|k| (dt * d[k] / f.h[k]) as f32),
            inv_step: std::array::from_fn(|k| (f.h[k] / (dt * d[k])) as f32),
            max: std::array::from_fn(|k| f.dims[k] as f32 + 0.999),
        };
        let span = first..last;
        let dtf = dt as f32;
        let uniform = |c: &[f32], wgt: f32, amb: &mut [f32; 3]| {
            for (m, u) in amb.iter_mut().zip(self.ambient_uniform) {
                *m += wgt * c[0] * u;
            }
        };
        let mut out = match &self.sources {
            Sources::Uniform(s) => {
                self.integrate::<2, false>(s, &ray, span, dtf, |c, wgt, amb| uniform(c, wgt, amb))
            }
            Sources::Field(s) => self.integrate::<5, false>(s, &ray, span, dtf, |c, wgt, amb| {
                for (m, x) in amb.iter_mut().zip(&c[2..5]) {
                    *m += wgt * x;
                }
            }),
            Sources::UniformMs(s) => {
                self.integrate::<3, true>(s, &ray, span, dtf, |c, wgt, amb| uniform(c, wgt, amb))
            }
            Sources::FieldMs(s) => self.integrate::<6, true>(s, &ray, span, dtf, |c, wgt, amb| {
                for (m, x) in amb.iter_mut().zip(&c[3..6]) {
                    *m += wgt * x;
                }
            }),
        };
        out.direct *= self.phase(d);
        if self.albedo != 1.0 {
            out.direct *= self.albedo;
        }
        out
    }

    /// Marches the ray through the centre of pixel (`x`, `y`) of a `width × height` view.
    pub fn march_pixel(
        &self,
        camera: &Camera,
        width: u32,
        height: u32,
        x: u32,
        y: u32,
    ) -> PixelSample {
        let rg = camera.ray_gen(width, height);
        self.march(rg.eye, rg.dir(f64::from(x) + 0.5, f64::from(y) + 0.5))
    }

    /// The sample loop of [`Prepared::march`] over sources of `N` channels (ρ and ρ·T_sun
    /// first); `ambient(c, wgt, acc)` adds a segment's ambient. Returns Ī before the phase, the
    /// multiple part for a unit sun, A and g as a [`PixelSample`].
    ///
    /// With `MULTIPLE` the sources carry ρ·J in channel [`MS`]: with the similarity scaling
    /// (αg ≠ 0) the multiple part is seen through its own, scaled view transmittance, and the
    /// march stops when both transmittances are below [`MIN_TRANSMITTANCE`]. Without it the
    /// multiple part is 0 and the march stops on the view transmittance alone.
    #[inline]
    fn integrate<const N: usize, const MULTIPLE: bool>(
        &self,
        src: &[[f32; N]],
        ray: &GridRay,
        span: std::ops::Range<usize>,
        dt: f32,
        ambient: impl Fn(&[f32; N], f32, &mut [f32; 3]),
    ) -> PixelSample {
        let mut out = PixelSample {
            transmittance: 1.0,
            ..PixelSample::default()
        };
        let ms = match self.ms {
            Some(ms) => ms,
            None if MULTIPLE => return out,
            None => MsMarch::default(),
        };
        let (px, pxy) = (self.pad[0], self.pad[0] * self.pad[1]);
        let mut g = 1.0f32;
        let mut gs = 1.0f32;
        let mut direct = 0.0f32;
        let mut multiple = 0.0f32;
        let mut amb = [0.0f32; 3];
        let (mut i, n) = (span.start, span.end);
        while i < n {
            let p = ray.at(i);
            // Non-negative: truncation is the floor (and avoids a libm call).
            let c = [p[0] as usize, p[1] as usize, p[2] as usize];
            let dist = self.empty.at(c[0], c[1], c[2]);
            if dist > 0 {
                let r = usize::from(dist) - 1;
                let b = c.map(|v| v / BLOCK);
                let bs = BLOCK as f32;
                let lo = b.map(|v| (v as f32 - r as f32) * bs);
                let hi = b.map(|v| (v + r + 1) as f32 * bs);
                i = ray.leap(i, lo, hi);
                continue;
            }
            let fx = p[0] - c[0] as f32;
            let fy = p[1] - c[1] as f32;
            let fz = p[2] - c[2] as f32;
            let i0 = c[0] + px * c[1] + pxy * c[2];
            let lerp = |a: &[f32; N], b: &[f32; N], t: f32| -> [f32; N] {
                std::array::from_fn(|q| a[q] + t * (b[q] - a[q]))
            };
            let row = |j: usize| -> [f32; N] {
                let r = &src[j..j + 2];
                lerp(&r[0], &r[1], fx)
            };
            let y0 = lerp(&row(i0), &row(i0 + px), fy);
            let y1 = lerp(&row(i0 + pxy), &row(i0 + pxy + px), fy);
            let s = lerp(&y0, &y1, fz);
            let rho = s[0];
            if rho > 0.0 {
                let a = exp_neg(-self.kappa * rho * dt);
                let wgt = g * (1.0 - a) / rho;
                direct += wgt * s[1];
                ambient(&s, wgt, &mut amb);
                g *= a;
                if MULTIPLE {
                    // N > MS whenever MULTIPLE (the sources carry ρ·J); the min keeps the
                    // index in bounds for the single-scattering instances.
                    let j = s[MS.min(N - 1)];
                    if ms.scaled {
                        let a_s = exp_neg(-ms.kappa * rho * dt);
                        multiple += gs * (1.0 - a_s) / rho * j;
                        gs *= a_s;
                    } else {
                        multiple += wgt * j;
                        gs = g;
                    }
                    if g < MIN_TRANSMITTANCE && gs < MIN_TRANSMITTANCE {
                        break;
                    }
                } else if g < MIN_TRANSMITTANCE {
                    break;
                }
            }
            i += 1;
        }
        out.direct = direct;
        if MULTIPLE {
            out.multiple = multiple * ms.albedo;
        }
        out.ambient = amb;
        out.transmittance = g;
        out
    }
}
