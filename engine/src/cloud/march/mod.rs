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
pub use super::layers::{Layers, Show};
use super::skip::EmptySpace;
use crate::geom::camera::Camera;
use crate::{Canceled, Control};

mod prepare;
mod ray;

/// The march stops when the view transmittance falls below this.
pub const MIN_TRANSMITTANCE: f32 = 1e-3;

/// Rows of pixels per parallel task: 8-row bands walked in 8×8 tiles, so that neighbouring rays
/// (which read the same voxels) run back to back.
const TILE: usize = 8;

/// The per-cell sources, interleaved so that one trilinear gather fetches them all.
#[derive(Debug, Clone)]
enum Sources {
    /// `(ρ, ρ·T_sun)`: uniform ambient.
    Uniform(Vec<[f32; 2]>),
    /// `(ρ, ρ·T_sun, ρ·ambient_scale·I_m)`: a per-voxel ambient field.
    Field(Vec<[f32; 5]>),
    /// `(ρ, ρ·T_sun, ρ·J)`: uniform ambient, multiple scattering ([`super::multiple`]).
    UniformMs(Vec<[f32; 3]>),
    /// `(ρ, ρ·T_sun, ρ·J, ρ·ambient_scale·I_m)`: a field and multiple scattering.
    FieldMs(Vec<[f32; 6]>),
}

/// Index of ρ·J in the multiple-scattering sources.
const MS: usize = 2;

/// How the march weighs the multiple-scattering channel ([`super::multiple`]'s similarity
/// scaling): emission α*·J per unit *scaled* extinction κ(1 − αg)ρ, seen through the scaled
/// view transmittance.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MsMarch {
    /// α* = α(1 − g)/(1 − αg).
    pub albedo: f32,
    /// κ(1 − αg).
    pub kappa: f32,
    /// Whether κ(1 − αg) differs from κ (g ≠ 0 and α ≠ 0): a second transmittance is kept.
    pub scaled: bool,
    /// Orders swept and the tail ratio (for the report).
    pub orders: usize,
    pub ratio: f64,
}

/// Everything a ray needs, prepared once per render: the sources per cell of the *padded* grid
/// (the voxels plus a one-cell border repeating the faces, which is exactly the edge clamping of
/// [`GridFrame::trilinear`], so a gather needs no clamping) and the empty-space grid
/// ([`EmptySpace`]). Allocates 8 bytes per padded cell (20 with an ambient field).
#[derive(Debug, Clone)]
pub struct Prepared {
    pub frame: GridFrame,
    /// Padded grid size: `dims + 2`.
    pad: [usize; 3],
    sources: Sources,
    /// Uniform I_m when there is no field.
    ambient_uniform: [f32; 3],
    empty: EmptySpace,
    /// World box holding every sample that can read a density (from
    /// [`EmptySpace::occupied`], widened by a cell); `None` for an empty volume.
    occupied: Option<([f64; 3], [f64; 3])>,
    kappa: f32,
    step: f64,
    sun: [f64; 3],
    anisotropy: f64,
    /// Single-scattering albedo α (multiplies the sun term).
    albedo: f32,
    /// The multiple-scattering weights when the sources carry ρ·J.
    ms: Option<MsMarch>,
}

/// One pixel's march: Ī (direct light for a unit sun, phase included), A (ambient, linear RGB)
/// and the view transmittance g(T) (alpha = 1 − g).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PixelSample {
    pub direct: f32,
    /// The multiple-scattering part for a unit sun (0 in single mode).
    pub multiple: f32,
    pub ambient: [f32; 3],
    pub transmittance: f32,
}

impl Prepared {
    /// The multiple-scattering weights of this preparation (None in single mode).
    pub fn multiple(&self) -> Option<MsMarch> {
        self.ms
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
    let ms = prepared.ms.is_some();
    let mut direct = vec![0f32; w * h];
    let mut multiple = vec![0f32; if ms { w * h } else { 0 }];
    let mut ambient = vec![[0f32; 3]; w * h];
    let mut alpha = vec![0f32; w * h];
    // In single mode `multiple` is empty: its chunks are then empty too (one per band).
    let ms_chunk = if ms { w * TILE } else { 1 };
    let mut none = vec![0f32; if ms { 0 } else { h.div_ceil(TILE) }];
    let ms_rows = if ms { &mut multiple } else { &mut none };
    direct
        .par_chunks_mut(w * TILE)
        .zip(ms_rows.par_chunks_mut(ms_chunk))
        .zip(ambient.par_chunks_mut(w * TILE))
        .zip(alpha.par_chunks_mut(w * TILE))
        .enumerate()
        .for_each(|(band, (((dr, mr), ar), al))| {
            if ctl.is_canceled() {
                return;
            }
            let rows = dr.len() / w;
            for x0 in (0..w).step_by(TILE) {
                for r in 0..rows {
                    let y = band * TILE + r;
                    for x in x0..(x0 + TILE).min(w) {
                        let s = prepared.march(rg.eye, rg.dir(x as f64 + 0.5, y as f64 + 0.5));
                        let i = r * w + x;
                        dr[i] = s.direct;
                        if ms {
                            mr[i] = s.multiple;
                        }
                        ar[i] = s.ambient;
                        al[i] = 1.0 - s.transmittance;
                    }
                }
            }
        });
    ctl.checkpoint()?;
    Ok(Layers {
        width,
        height,
        direct,
        multiple,
        ambient,
        alpha,
    })
}
