//! Sun colour from paint (SPEC §3.1, paper Eqs. 4–6).
//!
//! The user paints pixels k with colours I_user(k) on a render. The cloud's radiance is linear in
//! the sun colour, I(k,λ) = I_l(λ)·Ī(k) + A(k,λ), so the least-squares sun colour is
//! `I_l(λ) = Σ_k Ī(k)(I_target(k,λ) − A(k,λ)) / Σ_k Ī(k)²` — the paper's Eq. 6 when there is one
//! colour and no ambient. In multiple mode Ī is the sum of the single- and multiple-scattering
//! parts for a unit sun (both are linear in I_l: the source term J is solved per unit sun), so
//! the same formula holds unchanged. Only the painted pixels' rays are marched — or, when the render of
//! the base version at the edit's view exists, its layers (`layers.bin`,
//! [`crate::cloud::layers`]) are read and nothing is marched.
//!
//! Reading chosen for alpha and background: the user paints the colour they *see*. With a
//! `background` the displayed colour is `I + (1 − α)·bg`, so the target for I is
//! `I_user − (1 − α)·bg` (with a black background this is I_user and Eq. 6 holds exactly).
//! Without one the PNG holds the straight colour I/α, so the target is `α·I_user`: the residual
//! is measured on premultiplied radiance and thin, barely visible pixels weigh little. Paint
//! colours are sRGB converted to linear. The result is clamped to the state's range 0–100 per
//! channel (a negative least-squares solution means the paint is darker than the ambient alone).

use rayon::prelude::*;

use super::{EditError, SunColorEdit};
use crate::cloud::layers::Layers;
use crate::cloud::march::{PixelSample, Prepared};
use crate::cloud::state::{AmbientField, CloudState};
use crate::geom::Volume;
use crate::render::image::srgb8_to_linear;
use crate::Control;

/// The painted samples' marches, in stroke order: (colour, Ī, A, α).
pub fn painted_samples(
    prepared: &Prepared,
    volume: &Volume,
    edit: &SunColorEdit,
) -> Vec<([f32; 3], PixelSample)> {
    let camera = edit.view.camera(volume.bounds);
    let rg = camera.ray_gen(edit.view.width, edit.view.height);
    let jobs: Vec<([f32; 3], [u32; 2])> = edit
        .strokes
        .iter()
        .flat_map(|s| s.pixels.iter().map(move |p| (s.color, *p)))
        .collect();
    jobs.par_iter()
        .map(|(c, p)| {
            let d = rg.dir(f64::from(p[0]) + 0.5, f64::from(p[1]) + 0.5);
            (*c, prepared.march(rg.eye, d))
        })
        .collect()
}

/// The painted samples read from the layers of a render at the edit's view (the cached path:
/// no march), in stroke order as [`painted_samples`] gives them. The layers must be
/// `edit.view`'s size (pixels are checked against it when the edit is parsed).
pub fn samples_from_layers(layers: &Layers, edit: &SunColorEdit) -> Vec<([f32; 3], PixelSample)> {
    let w = layers.width as usize;
    edit.strokes
        .iter()
        .flat_map(|s| s.pixels.iter().map(move |p| (s.color, *p)))
        .filter_map(|(c, p)| {
            let i = p[1] as usize * w + p[0] as usize;
            let sample = PixelSample {
                direct: *layers.direct.get(i)?,
                multiple: layers.multiple.get(i).copied().unwrap_or(0.0),
                ambient: *layers.ambient.get(i)?,
                transmittance: 1.0 - *layers.alpha.get(i)?,
            };
            Some((c, sample))
        })
        .collect()
}

/// A painted pixel covers the cloud when its alpha is at least this.
pub const COVER_MIN: f32 = 0.01;

/// The RMS of the direct light Ī (for a unit sun) over the covered painted pixels below which
/// the cloud under the stroke counts as not lit: 1 % of full sunlight. Below it the least
/// squares would divide the paint by a vanishing Ī and clamp the sun colour to its range.
pub const LIT_MIN: f64 = 0.01;

/// Least-squares I_l from the painted samples (see the module doc). [`EditError::MissesCloud`]
/// when no painted pixel covers the cloud (α < [`COVER_MIN`] everywhere under the stroke);
/// [`EditError::NotLit`] when the covered ones receive no sunlight to speak of (RMS Ī <
/// [`LIT_MIN`]): the first is fixed by painting on the cloud, the second by moving the sun or
/// lowering κ.
pub fn solve(
    samples: &[([f32; 3], PixelSample)],
    background: Option<[u8; 3]>,
) -> Result<[f64; 3], EditError> {
    let bg = background.map(|b| b.map(srgb8_to_linear));
    let mut num = [0f64; 3];
    let mut den = 0f64;
    let mut covered = 0usize;
    let mut covered_sq = 0f64;
    for (c, s) in samples {
        let alpha = f64::from(1.0 - s.transmittance);
        // Single and multiple scattering are both linear in I_l: Ī + M per unit sun.
        let d = f64::from(s.direct) + f64::from(s.multiple);
        if 1.0 - s.transmittance >= COVER_MIN {
            covered += 1;
            covered_sq += d * d;
        }
        for q in 0..3 {
            let target = match bg {
                Some(bg) => f64::from(c[q]) - (1.0 - alpha) * f64::from(bg[q]),
                None => alpha * f64::from(c[q]),
            };
            num[q] += d * (target - f64::from(s.ambient[q]));
        }
        den += d * d;
    }
    if covered == 0 {
        return Err(EditError::MissesCloud);
    }
    if (covered_sq / covered as f64).sqrt() < LIT_MIN || den <= 1e-20 {
        return Err(EditError::NotLit);
    }
    Ok(num.map(|n| (n / den).clamp(0.0, 100.0)))
}

/// Marches the painted pixels and solves for the sun colour. Cost: the fused transmittance
/// sweep ([`Prepared::lit`]) and one march per painted pixel.
pub fn estimate(
    volume: &Volume,
    base: &CloudState,
    ambient: Option<&AmbientField>,
    edit: &SunColorEdit,
    ctl: &dyn Control,
) -> Result<[f64; 3], EditError> {
    let prepared = Prepared::lit(volume, base, ambient, ctl)?;
    let samples = painted_samples(&prepared, volume, edit);
    solve(&samples, base.background_srgb())
}

/// [`estimate`] from the layers of the base version's render at the edit's view.
pub fn estimate_from_layers(
    layers: &Layers,
    base: &CloudState,
    edit: &SunColorEdit,
) -> Result<[f64; 3], EditError> {
    solve(&samples_from_layers(layers, edit), base.background_srgb())
}
