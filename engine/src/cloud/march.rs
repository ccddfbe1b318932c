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

use super::fastexp::exp_neg;
use super::grid::GridFrame;
pub use super::layers::{Layers, Show};
use super::light::{sweep, SunLight, SweepOut};
use super::multiple::{solve, Medium, MsField, MsOptions};
use super::skip::{DensityRows, EmptySpace};
use super::state::{AmbientField, CloudState};
use crate::geom::camera::Camera;
use crate::geom::Volume;
use crate::{Canceled, Control};

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
#[derive(Debug, Clone, Copy, PartialEq)]
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

/// The medium of `state` at extinction `kappa`.
fn medium_of(state: &CloudState, kappa: f64) -> Medium {
    Medium {
        kappa,
        albedo: state.albedo,
        anisotropy: state.anisotropy,
    }
}

/// The march's weights for a solved field.
fn ms_march(medium: &Medium, f: &MsField) -> MsMarch {
    let ext = medium.extinction_scale();
    MsMarch {
        albedo: medium.scaled_albedo() as f32,
        kappa: (medium.kappa * ext) as f32,
        scaled: ext != 1.0,
        orders: f.orders,
        ratio: f.ratio,
    }
}

/// Writes ρ·J into channel [`MS`] of every voxel's padded cell (then the border again).
fn put_ms<const N: usize>(src: &mut [[f32; N]], pad: [usize; 3], f: &MsField) {
    let dims = f.dims;
    let (px, pxy) = (pad[0], pad[0] * pad[1]);
    src.par_chunks_mut(pxy)
        .enumerate()
        .skip(1)
        .take(dims[2])
        .for_each(|(pz, slab)| {
            let z = pz - 1;
            for y in 0..dims[1] {
                let row = &mut slab[px * (y + 1) + 1..][..dims[0]];
                for (x, c) in row.iter_mut().enumerate() {
                    if c[0] > 0.0 {
                        c[MS] = c[0] * f.at_voxel(x, y, z);
                    }
                }
            }
        });
    fill_border(src, pad);
}

/// Copies `cell(voxel index)` into the padded layout (border cells repeat the face voxels).
fn padded<T: Copy + Default + Send + Sync>(
    dims: [usize; 3],
    cell: impl Fn(usize) -> T + Sync,
) -> Vec<T> {
    let pad = dims.map(|n| n + 2);
    let clamp = |c: usize, n: usize| c.saturating_sub(1).min(n - 1);
    let mut out = vec![T::default(); pad[0] * pad[1] * pad[2]];
    out.par_chunks_mut(pad[0] * pad[1])
        .enumerate()
        .for_each(|(pz, slab)| {
            let z = clamp(pz, dims[2]);
            for (py, row) in slab.chunks_mut(pad[0]).enumerate() {
                let y = clamp(py, dims[1]);
                let base = dims[0] * (y + dims[1] * z);
                row[0] = cell(base);
                for (x, o) in row[1..=dims[0]].iter_mut().enumerate() {
                    *o = cell(base + x);
                }
                row[dims[0] + 1] = cell(base + dims[0] - 1);
            }
        });
    out
}

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

/// The ambient field, if it fits the volume.
fn field_of<'a>(volume: &Volume, ambient: Option<&'a AmbientField>) -> Option<&'a [[f32; 3]]> {
    ambient
        .filter(|f| f.rgb.len() == volume.len())
        .map(|f| f.rgb.as_slice())
}

/// The sources of a voxel with a field: `(ρ, ρ·T_sun, ρ·scale·I_m)`.
#[inline]
fn field_source(rho: f32, t: f32, c: [f32; 3], scale: f32) -> [f32; 5] {
    [
        rho,
        rho * t,
        rho * c[0] * scale,
        rho * c[1] * scale,
        rho * c[2] * scale,
    ]
}

/// Fills the one-cell border of a padded grid of `pad` cells with copies of the faces inside
/// it (x faces, then y, then z, so edges and corners repeat the corner voxels).
fn fill_border<T: Copy + Send + Sync>(cells: &mut [T], pad: [usize; 3]) {
    let [px, py, pz] = pad;
    let pxy = px * py;
    cells.par_chunks_mut(pxy).for_each(|slab| {
        for row in slab.chunks_mut(px) {
            row[0] = row[1];
            row[px - 1] = row[px - 2];
        }
        slab.copy_within(px..2 * px, 0);
        slab.copy_within((py - 2) * px..(py - 1) * px, (py - 1) * px);
    });
    cells.copy_within(pxy..2 * pxy, 0);
    cells.copy_within((pz - 2) * pxy..(pz - 1) * pxy, (pz - 1) * pxy);
}

/// A ray in padded-cell coordinates: sample `i` is at `origin + (i + ½)·step`.
struct GridRay {
    origin: [f32; 3],
    step: [f32; 3],
    inv_step: [f32; 3],
    /// Highest floor cell per axis (`dims`), for clamping.
    max: [f32; 3],
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
    /// Prepares `volume` lit by `light` (which must be for `state`'s sun and κ) with `state`'s
    /// ambient; a field whose length differs from the volume's is ignored (uniform ambient).
    pub fn new(
        volume: &Volume,
        light: &SunLight,
        state: &CloudState,
        ambient: Option<&AmbientField>,
    ) -> Self {
        let dims = volume.dims;
        let (rho, tsun) = (&volume.density, &light.transmittance);
        let scale = state.ambient_scale as f32;
        let field = field_of(volume, ambient);
        if state.scattering.is_single() {
            let sources = match field {
                Some(f) => {
                    Sources::Field(padded(dims, |i| field_source(rho[i], tsun[i], f[i], scale)))
                }
                None => Sources::Uniform(padded(dims, |i| [rho[i], rho[i] * tsun[i]])),
            };
            return Self::with_sources(
                volume,
                &DensityRows::of(volume),
                sources,
                state,
                light.kappa,
                None,
            );
        }
        let g = GridFrame::of(volume);
        let medium = medium_of(state, light.kappa);
        let voxel = |x: usize, y: usize, z: usize| {
            let i = g.index(x, y, z);
            (rho[i], rho[i] * tsun[i])
        };
        // Cannot be canceled: no control here.
        let Ok(msf) = solve(
            dims,
            g.h,
            &medium,
            &MsOptions::default(),
            voxel,
            &crate::NoControl,
        ) else {
            unreachable!("NoControl never cancels")
        };
        let pad = dims.map(|n| n + 2);
        let sources = match field {
            Some(f) => {
                let mut src = padded(dims, |i| {
                    let c = field_source(rho[i], tsun[i], f[i], scale);
                    [c[0], c[1], 0.0, c[2], c[3], c[4]]
                });
                put_ms(&mut src, pad, &msf);
                Sources::FieldMs(src)
            }
            None => {
                let mut src = padded(dims, |i| [rho[i], rho[i] * tsun[i], 0.0]);
                put_ms(&mut src, pad, &msf);
                Sources::UniformMs(src)
            }
        };
        let ms = ms_march(&medium, &msf);
        Self::with_sources(
            volume,
            &DensityRows::of(volume),
            sources,
            state,
            light.kappa,
            Some(ms),
        )
    }

    /// [`SunLight::compute`] and [`Prepared::new`] in one: the sweep writes ρ·T_sun straight
    /// into the padded sources and only for the slice rows that hold density (elsewhere
    /// ρ·T_sun = 0), so neither the transmittance grid nor the empty rows' work exists.
    /// Gives the same sources as the two steps.
    pub fn lit(
        volume: &Volume,
        state: &CloudState,
        ambient: Option<&AmbientField>,
        ctl: &dyn Control,
    ) -> Result<Self, Canceled> {
        let dims = volume.dims;
        let pad = dims.map(|n| n + 2);
        let cells = pad[0] * pad[1] * pad[2];
        let rows = DensityRows::of(volume);
        let kappa = state.kappa_for(volume);
        let (dir, rho) = (state.sun_direction, &volume.density);
        let scale = state.ambient_scale as f32;
        if !state.scattering.is_single() {
            return Self::lit_multiple(volume, state, ambient, &rows, kappa, ctl);
        }
        let sources = match field_of(volume, ambient) {
            Some(f) => {
                let mut src = vec![[0f32; 5]; cells];
                let out = SweepOut {
                    cells: &mut src,
                    dims: pad,
                    border: 1,
                };
                let put = |c: &mut [f32; 5], i: usize, t: f32| {
                    *c = field_source(rho[i], t, f[i], scale);
                };
                sweep(volume, dir, kappa, Some(&rows), out, put, ctl)?;
                fill_border(&mut src, pad);
                Sources::Field(src)
            }
            None => {
                let mut src = vec![[0f32; 2]; cells];
                let out = SweepOut {
                    cells: &mut src,
                    dims: pad,
                    border: 1,
                };
                let put = |c: &mut [f32; 2], i: usize, t: f32| *c = [rho[i], rho[i] * t];
                sweep(volume, dir, kappa, Some(&rows), out, put, ctl)?;
                fill_border(&mut src, pad);
                Sources::Uniform(src)
            }
        };
        Ok(Self::with_sources(
            volume, &rows, sources, state, kappa, None,
        ))
    }

    /// [`Prepared::lit`] in multiple mode: the fused sweep writes `(ρ, ρ·T_sun, 0, …)`, the
    /// source term J is solved from those cells ([`super::multiple::solve`]) and ρ·J written
    /// into the third channel.
    fn lit_multiple(
        volume: &Volume,
        state: &CloudState,
        ambient: Option<&AmbientField>,
        rows: &DensityRows,
        kappa: f64,
        ctl: &dyn Control,
    ) -> Result<Self, Canceled> {
        let dims = volume.dims;
        let pad = dims.map(|n| n + 2);
        let cells = pad[0] * pad[1] * pad[2];
        let (dir, rho) = (state.sun_direction, &volume.density);
        let scale = state.ambient_scale as f32;
        let medium = medium_of(state, kappa);
        let h = GridFrame::of(volume).h;
        let opts = MsOptions::default();
        let (px, pxy) = (pad[0], pad[0] * pad[1]);
        let at = move |x: usize, y: usize, z: usize| (x + 1) + px * (y + 1) + pxy * (z + 1);
        let (sources, msf) = match field_of(volume, ambient) {
            Some(f) => {
                let mut src = vec![[0f32; 6]; cells];
                let out = SweepOut {
                    cells: &mut src,
                    dims: pad,
                    border: 1,
                };
                let put = |c: &mut [f32; 6], i: usize, t: f32| {
                    let s = field_source(rho[i], t, f[i], scale);
                    *c = [s[0], s[1], 0.0, s[2], s[3], s[4]];
                };
                sweep(volume, dir, kappa, Some(rows), out, put, ctl)?;
                ctl.progress("multiple", 0.1);
                let msf = solve(
                    dims,
                    h,
                    &medium,
                    &opts,
                    |x, y, z| {
                        let c = &src[at(x, y, z)];
                        (c[0], c[1])
                    },
                    ctl,
                )?;
                put_ms(&mut src, pad, &msf);
                (Sources::FieldMs(src), msf)
            }
            None => {
                let mut src = vec![[0f32; 3]; cells];
                let out = SweepOut {
                    cells: &mut src,
                    dims: pad,
                    border: 1,
                };
                let put = |c: &mut [f32; 3], i: usize, t: f32| *c = [rho[i], rho[i] * t, 0.0];
                sweep(volume, dir, kappa, Some(rows), out, put, ctl)?;
                ctl.progress("multiple", 0.1);
                let msf = solve(
                    dims,
                    h,
                    &medium,
                    &opts,
                    |x, y, z| {
                        let c = &src[at(x, y, z)];
                        (c[0], c[1])
                    },
                    ctl,
                )?;
                put_ms(&mut src, pad, &msf);
                (Sources::UniformMs(src), msf)
            }
        };
        let ms = ms_march(&medium, &msf);
        Ok(Self::with_sources(
            volume,
            rows,
            sources,
            state,
            kappa,
            Some(ms),
        ))
    }

    /// The multiple-scattering weights of this preparation (None in single mode).
    pub fn multiple(&self) -> Option<MsMarch> {
        self.ms
    }

    fn with_sources(
        volume: &Volume,
        rows: &DensityRows,
        sources: Sources,
        state: &CloudState,
        kappa: f64,
        ms: Option<MsMarch>,
    ) -> Self {
        let frame = GridFrame::of(volume);
        let empty = EmptySpace::build(rows);
        // Floor position c is padded coordinate c, i.e. world lo + (c − ½)·h; one cell margin.
        let occupied = empty.occupied.map(|(clo, chi)| {
            let w = |c: f64, k: usize| frame.lo[k] + (c - 0.5) * frame.h[k];
            (
                std::array::from_fn(|k| w(clo[k] as f64 - 1.0, k)),
                std::array::from_fn(|k| w(chi[k] as f64 + 1.0, k)),
            )
        });
        Self {
            frame,
            pad: volume.dims.map(|n| n + 2),
            sources,
            occupied,
            ambient_uniform: state.ambient.map(|v| v as f32),
            empty,
            kappa: kappa as f32,
            step: state.step,
            sun: state.sun_direction,
            anisotropy: state.anisotropy,
            albedo: state.albedo as f32,
            ms,
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

    /// Marches one ray from `o` along unit `d`. No allocation.
    ///
    /// The samples are those of the whole box (n equal segments of about `step` voxels between
    /// the box's entry and exit), but only those inside the box of occupied blocks are visited.
    pub fn march(&self, o: [f64; 3], d: [f64; 3]) -> PixelSample {
        let mut out = PixelSample {
            transmittance: 1.0,
            ..PixelSample::default()
        };
        let f = &self.frame;
        let Some((t0, t1)) = f.clip(o, d) else {
            return out;
        };
        let Some((lo, hi)) = self.occupied else {
            return out;
        };
        let Some((ta, tb)) = clip_box(o, d, lo, hi) else {
            return out;
        };
        let len = t1 - t0;
        let n = (len / (self.step * f.min_h())).ceil().max(1.0) as usize;
        let dt = len / n as f64;
        // Samples i with t0 + (i + ½)·dt in [ta, tb], widened by one.
        let first = ((ta - t0) / dt - 1.5).max(0.0) as usize;
        let last = (((tb - t0) / dt + 0.5).max(0.0) as usize + 1).min(n);
        if first >= last {
            return out;
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
        let (direct, ambient, g) = match &self.sources {
            Sources::Uniform(s) => {
                self.integrate(s, &ray, span, dtf, |c, wgt, amb| uniform(c, wgt, amb))
            }
            Sources::Field(s) => self.integrate(s, &ray, span, dtf, |c, wgt, amb| {
                for (m, x) in amb.iter_mut().zip(&c[2..5]) {
                    *m += wgt * x;
                }
            }),
            Sources::UniformMs(s) => {
                let (dr, ms, amb, g) =
                    self.integrate_ms(s, &ray, span, dtf, |c, wgt, amb| uniform(c, wgt, amb));
                out.multiple = ms;
                (dr, amb, g)
            }
            Sources::FieldMs(s) => {
                let (dr, ms, amb, g) = self.integrate_ms(s, &ray, span, dtf, |c, wgt, amb| {
                    for (m, x) in amb.iter_mut().zip(&c[3..6]) {
                        *m += wgt * x;
                    }
                });
                out.multiple = ms;
                (dr, amb, g)
            }
        };
        out.direct = direct * self.phase(d);
        if self.albedo != 1.0 {
            out.direct *= self.albedo;
        }
        out.ambient = ambient;
        out.transmittance = g;
        out
    }

    /// The sample loop of [`Prepared::march`] over sources of `N` channels (ρ and ρ·T_sun
    /// first); `ambient(c, wgt, acc)` adds a segment's ambient. Returns (Ī before the phase, A,
    /// g).
    #[inline]
    fn integrate<const N: usize>(
        &self,
        src: &[[f32; N]],
        ray: &GridRay,
        span: std::ops::Range<usize>,
        dt: f32,
        ambient: impl Fn(&[f32; N], f32, &mut [f32; 3]),
    ) -> (f32, [f32; 3], f32) {
        let (px, pxy) = (self.pad[0], self.pad[0] * self.pad[1]);
        let mut g = 1.0f32;
        let mut direct = 0.0f32;
        let mut amb = [0.0f32; 3];
        let (mut i, n) = (span.start, span.end);
        while i < n {
            let p = ray.at(i);
            // Non-negative: truncation is the floor (and avoids a libm call).
            let c = [p[0] as usize, p[1] as usize, p[2] as usize];
            let dist = self.empty.at(c[0], c[1], c[2]);
            if dist > 0 {
                let r = usize::from(dist) - 1;
                let b = c.map(|v| v / super::skip::BLOCK);
                let bs = super::skip::BLOCK as f32;
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
                if g < MIN_TRANSMITTANCE {
                    break;
                }
            }
            i += 1;
        }
        (direct, amb, g)
    }

    /// [`Prepared::integrate`] with the multiple-scattering channel ρ·J ([`MS`]): returns (Ī
    /// before the phase, the multiple part for a unit sun, A, g). With the similarity scaling
    /// (αg ≠ 0) the multiple part is seen through its own, scaled view transmittance, and the
    /// march stops when both transmittances are below [`MIN_TRANSMITTANCE`].
    #[inline]
    fn integrate_ms<const N: usize>(
        &self,
        src: &[[f32; N]],
        ray: &GridRay,
        span: std::ops::Range<usize>,
        dt: f32,
        ambient: impl Fn(&[f32; N], f32, &mut [f32; 3]),
    ) -> (f32, f32, [f32; 3], f32) {
        let Some(ms) = self.ms else {
            return (0.0, 0.0, [0.0; 3], 1.0);
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
            let c = [p[0] as usize, p[1] as usize, p[2] as usize];
            let dist = self.empty.at(c[0], c[1], c[2]);
            if dist > 0 {
                let r = usize::from(dist) - 1;
                let b = c.map(|v| v / super::skip::BLOCK);
                let bs = super::skip::BLOCK as f32;
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
                if ms.scaled {
                    let a_s = exp_neg(-ms.kappa * rho * dt);
                    multiple += gs * (1.0 - a_s) / rho * s[MS];
                    gs *= a_s;
                } else {
                    multiple += wgt * s[MS];
                    gs = g;
                }
                if g < MIN_TRANSMITTANCE && gs < MIN_TRANSMITTANCE {
                    break;
                }
            }
            i += 1;
        }
        (direct, multiple * ms.albedo, amb, g)
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
