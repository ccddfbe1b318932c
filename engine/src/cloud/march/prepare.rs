//! Preparing a render ([`Prepared`]): the per-cell sources of the padded grid — ρ, ρ·T_sun from
//! the sun sweep ([`super::super::light`]), ρ·J from the multiple-scattering solver
//! ([`super::super::multiple`]) and ρ·I_m from the ambient field — and the empty-space grid.

use rayon::prelude::*;

use super::{MsMarch, Prepared, Sources, MS};
use crate::cloud::grid::GridFrame;
use crate::cloud::light::{sweep, SunLight, SweepOut};
use crate::cloud::multiple::{solve, Medium, MsField, MsOptions};
use crate::cloud::skip::{DensityRows, EmptySpace};
use crate::cloud::state::{AmbientField, CloudState};
use crate::geom::Volume;
use crate::{Canceled, Control};

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

/// Sweeps the sun through `volume` ([`sweep`], only the slice rows of `rows` that hold density)
/// into a fresh padded grid, calling `put(cell, voxel index, T_sun)`; the border is left at 0.
fn swept<const N: usize>(
    volume: &Volume,
    state: &CloudState,
    kappa: f64,
    rows: &DensityRows,
    put: impl Fn(&mut [f32; N], usize, f32) + Sync,
    ctl: &dyn Control,
) -> Result<Vec<[f32; N]>, Canceled> {
    let pad = volume.dims.map(|n| n + 2);
    let mut src = vec![[0f32; N]; pad[0] * pad[1] * pad[2]];
    let out = SweepOut {
        cells: &mut src,
        dims: pad,
        border: 1,
    };
    sweep(
        volume,
        state.sun_direction,
        kappa,
        Some(rows),
        out,
        put,
        ctl,
    )?;
    Ok(src)
}

/// [`swept`] in multiple mode: sweeps `(ρ, ρ·T_sun, 0, …)` into the cells, solves the source
/// term J of `medium` from them ([`solve`]) and writes ρ·J into channel [`MS`] ([`put_ms`], which
/// also fills the border).
fn swept_multiple<const N: usize>(
    volume: &Volume,
    state: &CloudState,
    medium: &Medium,
    rows: &DensityRows,
    put: impl Fn(&mut [f32; N], usize, f32) + Sync,
    ctl: &dyn Control,
) -> Result<(Vec<[f32; N]>, MsField), Canceled> {
    let dims = volume.dims;
    let pad = dims.map(|n| n + 2);
    let (px, pxy) = (pad[0], pad[0] * pad[1]);
    let at = move |x: usize, y: usize, z: usize| (x + 1) + px * (y + 1) + pxy * (z + 1);
    let mut src = swept(volume, state, medium.kappa, rows, put, ctl)?;
    ctl.progress("multiple", 0.1);
    let h = GridFrame::of(volume).h;
    let voxel = |x, y, z| {
        let c: &[f32; N] = &src[at(x, y, z)];
        (c[0], c[1])
    };
    let msf = solve(dims, h, medium, &MsOptions::default(), voxel, ctl)?;
    put_ms(&mut src, pad, &msf);
    Ok((src, msf))
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
        let pad = volume.dims.map(|n| n + 2);
        let rows = DensityRows::of(volume);
        let kappa = state.kappa_for(volume);
        let rho = &volume.density;
        let scale = state.ambient_scale as f32;
        if !state.scattering.is_single() {
            return Self::lit_multiple(volume, state, ambient, &rows, kappa, ctl);
        }
        let sources = match field_of(volume, ambient) {
            Some(f) => {
                let put = |c: &mut [f32; 5], i: usize, t: f32| {
                    *c = field_source(rho[i], t, f[i], scale);
                };
                let mut src = swept(volume, state, kappa, &rows, put, ctl)?;
                fill_border(&mut src, pad);
                Sources::Field(src)
            }
            None => {
                let put = |c: &mut [f32; 2], i: usize, t: f32| *c = [rho[i], rho[i] * t];
                let mut src = swept(volume, state, kappa, &rows, put, ctl)?;
                fill_border(&mut src, pad);
                Sources::Uniform(src)
            }
        };
        Ok(Self::with_sources(
            volume, &rows, sources, state, kappa, None,
        ))
    }

    /// [`Prepared::lit`] in multiple mode: the fused sweep writes `(ρ, ρ·T_sun, 0, …)`, the
    /// source term J is solved from those cells ([`super::super::multiple::solve`]) and ρ·J
    /// written into the third channel.
    fn lit_multiple(
        volume: &Volume,
        state: &CloudState,
        ambient: Option<&AmbientField>,
        rows: &DensityRows,
        kappa: f64,
        ctl: &dyn Control,
    ) -> Result<Self, Canceled> {
        let rho = &volume.density;
        let scale = state.ambient_scale as f32;
        let medium = medium_of(state, kappa);
        let (sources, msf) = match field_of(volume, ambient) {
            Some(f) => {
                let put = |c: &mut [f32; 6], i: usize, t: f32| {
                    let s = field_source(rho[i], t, f[i], scale);
                    *c = [s[0], s[1], 0.0, s[2], s[3], s[4]];
                };
                let (src, msf) = swept_multiple(volume, state, &medium, rows, put, ctl)?;
                (Sources::FieldMs(src), msf)
            }
            None => {
                let put = |c: &mut [f32; 3], i: usize, t: f32| *c = [rho[i], rho[i] * t, 0.0];
                let (src, msf) = swept_multiple(volume, state, &medium, rows, put, ctl)?;
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
}
