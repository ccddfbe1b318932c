//! The camera-ray march of paper Eqs. 1–3 (SPEC §3 "Rendering"), per RGB channel λ:
//!
//! I(p,λ) = ∫₀^T(p) κρ(t) g(t) (I_l(λ)·Φ·T_sun(t) + I_m(t,λ)) dt,  g(t) = exp(−κτ(t)),
//! τ(t) = ∫₀ᵗ ρ.
//!
//! Reading chosen: the emission factor is the scattering coefficient κρ (single-scattering
//! albedo 1) where Eq. 1 writes ρ; Eq. 1 literally is this divided by κ, which only rescales
//! I_l and I_m, and with κρ an opaque cloud under a white unit sun renders white whatever κ is,
//! so the defaults keep their meaning when κ changes. Φ is the Henyey–Greenstein phase
//! normalised so that the isotropic case is 1 (`anisotropy` = 0 gives the paper's model).
//!
//! Discretisation: the ray is clipped to the box and cut into equal segments of about
//! `step` × the smallest voxel edge; each segment takes the trilinear values at its midpoint
//! and is integrated exactly for constant values (`g·(1 − e^{−κρΔ})·S`), so a homogeneous slab's
//! transmittance is exactly `exp(−κρL)`. The per-voxel emission terms ρ·T_sun and ρ·I_m are what
//! is interpolated (zero-density voxels emit nothing whatever their ambient). Empty 8³ bricks
//! (dilated by one voxel, so skipping is exact) are stepped over; the march stops once the view
//! transmittance falls below 10⁻³ (the alpha is then within 10⁻³ of 1).
//!
//! Two linear layers are kept per pixel — Ī, the direct light for a unit sun colour (grey: the
//! volume is grey), and A, the ambient part — because the sun-colour edit (§3.1) solves for
//! I_l from them. Rows run in parallel and every pixel is computed on its own: the bytes do not
//! depend on the thread count.

use rayon::prelude::*;

use super::grid::GridFrame;
use super::light::SunLight;
use super::state::{AmbientField, CloudState};
use crate::geom::Volume;
use crate::render::camera::Camera;
use crate::render::image::{linear_to_srgb8, srgb8_to_linear, RgbaImage};
use crate::{Canceled, Control};

/// Edge of an occupancy brick, voxels.
const BRICK: usize = 8;
/// The march stops when the view transmittance falls below this.
pub const MIN_TRANSMITTANCE: f32 = 1e-3;

/// Everything a ray needs, prepared once per render: ρ and ρ·T_sun per voxel, ρ·I_m when an
/// ambient field exists, and the brick occupancy. Allocates 8 bytes per voxel (20 with a field).
#[derive(Debug, Clone)]
pub struct Prepared {
    pub frame: GridFrame,
    /// `(ρ, ρ·T_sun)` per voxel.
    source: Vec<[f32; 2]>,
    /// `ρ·ambient_scale·I_m` per voxel, when the state has a field.
    ambient_field: Option<Vec<[f32; 3]>>,
    /// Uniform I_m when there is no field.
    ambient_uniform: [f32; 3],
    occupied: Vec<bool>,
    bricks: [usize; 3],
    kappa: f32,
    step: f64,
    sun: [f64; 3],
    anisotropy: f64,
}

/// One pixel's march: Ī (direct light for a unit sun, phase included), A (ambient, linear RGB)
/// and the view transmittance g(T) (alpha = 1 − g).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PixelSample {
    pub direct: f32,
    pub ambient: [f32; 3],
    pub transmittance: f32,
}

/// The linear layers of a render, row-major, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Layers {
    pub width: u32,
    pub height: u32,
    /// Ī per pixel.
    pub direct: Vec<f32>,
    /// A per pixel, linear RGB.
    pub ambient: Vec<[f32; 3]>,
    /// 1 − g(T) per pixel.
    pub alpha: Vec<f32>,
}

impl Prepared {
    /// Prepares `volume` lit by `light` (which must be for `state`'s sun and κ) with `state`'s
    /// ambient; a field whose length differs from the volume's is ignored (uniform ambient).
    pub fn new(
        volume: &Volume,
        light: &SunLight,
        state: &CloudState,
        ambient: Option<&AmbientField>,
    ) -> Self {
        let frame = GridFrame::of(volume);
        let source: Vec<[f32; 2]> = volume
            .density
            .par_iter()
            .zip(light.transmittance.par_iter())
            .map(|(&r, &t)| [r, r * t])
            .collect();
        let scale = state.ambient_scale as f32;
        let ambient_field = ambient.filter(|f| f.rgb.len() == volume.len()).map(|f| {
            volume
                .density
                .par_iter()
                .zip(f.rgb.par_iter())
                .map(|(&r, c)| c.map(|v| r * v * scale))
                .collect()
        });
        let (occupied, bricks) = occupancy(volume);
        Self {
            frame,
            source,
            ambient_field,
            ambient_uniform: state.ambient.map(|v| v as f32),
            occupied,
            bricks,
            kappa: state.kappa as f32,
            step: state.step,
            sun: state.sun_direction,
            anisotropy: state.anisotropy,
        }
    }

    /// Henyey–Greenstein phase for a view ray `d` (unit, from the eye), normalised so that
    /// g = 0 gives 1.
    #[inline]
    fn phase(&self, d: [f64; 3]) -> f32 {
        let g = self.anisotropy;
        if g == 0.0 {
            return 1.0;
        }
        let cos = d[0] * self.sun[0] + d[1] * self.sun[1] + d[2] * self.sun[2];
        ((1.0 - g * g) / (1.0 + g * g - 2.0 * g * cos).powf(1.5)) as f32
    }

    #[inline]
    fn brick_empty(&self, p: [f64; 3]) -> bool {
        let c = self.frame.voxel_of(p);
        let b = [c[0] / BRICK, c[1] / BRICK, c[2] / BRICK];
        !self.occupied[b[0] + self.bricks[0] * (b[1] + self.bricks[1] * b[2])]
    }

    /// Exit parameter of the ray from the brick containing `p`.
    #[inline]
    fn brick_exit(&self, o: [f64; 3], d: [f64; 3], p: [f64; 3]) -> f64 {
        let c = self.frame.voxel_of(p);
        let mut t = f64::INFINITY;
        for k in 0..3 {
            let b = c[k] / BRICK;
            let lo = self.frame.lo[k] + (b * BRICK) as f64 * self.frame.h[k];
            let hi = self.frame.lo[k] + ((b + 1) * BRICK) as f64 * self.frame.h[k];
            if d[k] > 1e-300 {
                t = t.min((hi - o[k]) / d[k]);
            } else if d[k] < -1e-300 {
                t = t.min((lo - o[k]) / d[k]);
            }
        }
        t
    }

    /// Marches one ray from `o` along unit `d`. No allocation.
    pub fn march(&self, o: [f64; 3], d: [f64; 3]) -> PixelSample {
        let mut out = PixelSample {
            transmittance: 1.0,
            ..PixelSample::default()
        };
        let Some((t0, t1)) = self.frame.clip(o, d) else {
            return out;
        };
        let len = t1 - t0;
        let n = (len / (self.step * self.frame.min_h())).ceil().max(1.0) as usize;
        let dt = len / n as f64;
        let dtf = dt as f32;
        let mut g = 1.0f32;
        let mut direct = 0.0f32;
        let mut amb = [0.0f32; 3];
        let mut i = 0usize;
        while i < n {
            let t = t0 + (i as f64 + 0.5) * dt;
            let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            if self.brick_empty(p) {
                let te = self.brick_exit(o, d, p);
                // First sample at or past the brick's exit.
                let next = ((te - t0) / dt - 0.5).ceil();
                i = if next.is_finite() && next > i as f64 {
                    next as usize
                } else {
                    i + 1
                };
                continue;
            }
            let tl = self.frame.trilinear(p);
            let mut rho = 0.0f32;
            let mut rho_t = 0.0f32;
            for c in 0..8 {
                let s = self.source[tl.idx[c]];
                rho += tl.w[c] * s[0];
                rho_t += tl.w[c] * s[1];
            }
            if rho > 0.0 {
                let a = (-self.kappa * rho * dtf).exp();
                let wgt = g * (1.0 - a) / rho;
                direct += wgt * rho_t;
                match &self.ambient_field {
                    Some(f) => {
                        let mut ra = [0.0f32; 3];
                        for c in 0..8 {
                            let v = f[tl.idx[c]];
                            for (r, x) in ra.iter_mut().zip(v) {
                                *r += tl.w[c] * x;
                            }
                        }
                        for (m, r) in amb.iter_mut().zip(ra) {
                            *m += wgt * r;
                        }
                    }
                    None => {
                        for (m, u) in amb.iter_mut().zip(self.ambient_uniform) {
                            *m += wgt * rho * u;
                        }
                    }
                }
                g *= a;
                if g < MIN_TRANSMITTANCE {
                    break;
                }
            }
            i += 1;
        }
        out.direct = direct * self.phase(d);
        out.ambient = amb;
        out.transmittance = g;
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
}

/// Brick occupancy: a brick is occupied when any voxel within one voxel of it has ρ > 0.
fn occupancy(volume: &Volume) -> (Vec<bool>, [usize; 3]) {
    let d = volume.dims;
    let nb = d.map(|n| n.div_ceil(BRICK));
    let mut occ = vec![false; nb[0] * nb[1] * nb[2]];
    for z in 0..d[2] {
        for y in 0..d[1] {
            let row = &volume.density[volume.index(0, y, z)..volume.index(0, y, z) + d[0]];
            for (x, &r) in row.iter().enumerate() {
                if r > 0.0 {
                    // Mark every brick whose dilated range contains (x, y, z).
                    let range = |c: usize, n: usize| {
                        let lo = c.saturating_sub(1) / BRICK;
                        let hi = ((c + 1) / BRICK).min(n - 1);
                        lo..=hi
                    };
                    for bz in range(z, nb[2]) {
                        for by in range(y, nb[1]) {
                            for bx in range(x, nb[0]) {
                                occ[bx + nb[0] * (by + nb[1] * bz)] = true;
                            }
                        }
                    }
                }
            }
        }
    }
    (occ, nb)
}

/// Renders the linear layers of `prepared` seen by `camera` at `width × height`.
pub fn render_layers(
    prepared: &Prepared,
    camera: &Camera,
    width: u32,
    height: u32,
    ctl: &dyn Control,
) -> Result<Layers, Canceled> {
    let (w, h) = (width as usize, height as usize);
    let rg = camera.ray_gen(width, height);
    let mut direct = vec![0f32; w * h];
    let mut ambient = vec![[0f32; 3]; w * h];
    let mut alpha = vec![0f32; w * h];
    direct
        .par_chunks_mut(w)
        .zip(ambient.par_chunks_mut(w))
        .zip(alpha.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, ((dr, ar), al))| {
            if ctl.is_canceled() {
                return;
            }
            for x in 0..w {
                let s = prepared.march(rg.eye, rg.dir(x as f64 + 0.5, y as f64 + 0.5));
                dr[x] = s.direct;
                ar[x] = s.ambient;
                al[x] = 1.0 - s.transmittance;
            }
        });
    ctl.checkpoint()?;
    Ok(Layers {
        width,
        height,
        direct,
        ambient,
        alpha,
    })
}

/// Which terms of the layers an image shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Show {
    /// I_l·Ī + A: the render.
    All,
    /// I_l·Ī only.
    Direct,
    /// A only.
    Ambient,
}

impl Layers {
    /// Linear radiance I of pixel `i` (premultiplied by alpha: the cloud's own light).
    #[inline]
    pub fn radiance(&self, i: usize, sun: [f32; 3], show: Show) -> [f32; 3] {
        let d = self.direct[i];
        let a = self.ambient[i];
        std::array::from_fn(|q| match show {
            Show::All => sun[q] * d + a[q],
            Show::Direct => sun[q] * d,
            Show::Ambient => a[q],
        })
    }

    /// The sRGB RGBA image: over `background` (opaque: `I + (1 − α)·bg`) when given, else
    /// straight colour `I/α` with alpha α so that compositing over any sky gives `I + (1 − α)·sky`.
    pub fn to_image(&self, sun: [f32; 3], background: Option<[u8; 3]>, show: Show) -> RgbaImage {
        let bg = background.map(|b| b.map(srgb8_to_linear));
        let mut data = vec![0u8; self.direct.len() * 4];
        data.par_chunks_mut(4 * self.width as usize)
            .enumerate()
            .for_each(|(y, row)| {
                for (x, px) in row.chunks_exact_mut(4).enumerate() {
                    let i = y * self.width as usize + x;
                    let c = self.radiance(i, sun, show);
                    let a = self.alpha[i].clamp(0.0, 1.0);
                    let out = match bg {
                        Some(bg) => {
                            let v: [f32; 3] = std::array::from_fn(|q| c[q] + (1.0 - a) * bg[q]);
                            [
                                linear_to_srgb8(v[0]),
                                linear_to_srgb8(v[1]),
                                linear_to_srgb8(v[2]),
                                255,
                            ]
                        }
                        None => {
                            let alpha8 = (a * 255.0 + 0.5) as u8;
                            if alpha8 == 0 {
                                [0, 0, 0, 0]
                            } else {
                                let inv = 1.0 / a;
                                [
                                    linear_to_srgb8(c[0] * inv),
                                    linear_to_srgb8(c[1] * inv),
                                    linear_to_srgb8(c[2] * inv),
                                    alpha8,
                                ]
                            }
                        }
                    };
                    px.copy_from_slice(&out);
                }
            });
        RgbaImage {
            width: self.width,
            height: self.height,
            data,
        }
    }
}
