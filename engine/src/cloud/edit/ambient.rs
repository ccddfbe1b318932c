//! Ambient from paint (SPEC §3.2, paper Fig. 2).
//!
//! For every painted pixel the camera ray is walked voxel by voxel (3-D DDA) and the painted
//! colour (linear) is pinned on every voxel with ρ > 0 that it crosses — through the whole
//! cloud, as the paper does; a voxel crossed by several painted rays takes the mean of their
//! colours. The pins are propagated to the cloud voxels they reach through the cloud by
//! colourization by optimization with the direct light (sun transmittance) as the guide, solved
//! by multigrid ([`crate::cloud::multigrid`]) to a relative residual of 10⁻⁶. The field holds
//! I_m itself; `ambient_scale` multiplies it at render time. Each ambient edit propagates its
//! own strokes: the result replaces the base version's field (earlier versions keep theirs —
//! undo is choosing a version).
//!
//! Cloud voxels, for the propagation: ρ ≥ 1 % of the volume's maximum density, the reading of
//! "with density" of the sun-direction edit ([`super::sun_direction::DENSITY_THRESHOLD`]):
//! simulated volumes carry an invisible haze (the smoke sample: 10⁻⁵ in 38 % of its box, ρ ≥
//! 1 % in 12 %) that would otherwise triple the system and tie every puff to every other.
//!
//! Our reading for the voxels the paint cannot reach (a separate puff with no painted pixel on
//! it, the haze, and empty space, where the value never shows): they keep the ambient they showed in the
//! base version — its field, or its uniform `ambient` — expressed under the new version's
//! `ambient_scale`. An edit changes what the strokes reach and nothing else.

use rayon::prelude::*;

use super::sun_direction::DENSITY_THRESHOLD;
use super::{AmbientEdit, EditError};
use crate::cloud::grid::GridFrame;
use crate::cloud::light::SunLight;
use crate::cloud::multigrid::{propagate, SolveOptions, SolveStats};
use crate::cloud::state::{AmbientField, CloudState};
use crate::geom::Volume;
use crate::Control;

/// The pins of the painted strokes: (flat voxel index, linear colour), in index order.
/// Allocates 16 bytes per voxel of scratch.
pub fn pins(volume: &Volume, edit: &AmbientEdit) -> Vec<(usize, [f32; 3])> {
    let g = GridFrame::of(volume);
    let camera = edit.view.camera(volume.bounds);
    let rg = camera.ray_gen(edit.view.width, edit.view.height);
    let mut sum = vec![[0f32; 3]; volume.len()];
    let mut count = vec![0u32; volume.len()];
    for s in &edit.strokes {
        for p in &s.pixels {
            let d = rg.dir(f64::from(p[0]) + 0.5, f64::from(p[1]) + 0.5);
            g.walk(rg.eye, d, |_, i, _| {
                if volume.density[i] > 0.0 {
                    for (a, c) in sum[i].iter_mut().zip(s.color) {
                        *a += c;
                    }
                    count[i] += 1;
                }
                true
            });
        }
    }
    count
        .iter()
        .enumerate()
        .filter(|(_, &c)| c > 0)
        .map(|(i, &c)| (i, sum[i].map(|v| v / c as f32)))
        .collect()
}

/// Pins the paint and propagates it (see the module doc) on the version (`base`,
/// `base_field`).
pub fn propagate_paint(
    volume: &Volume,
    light: &SunLight,
    edit: &AmbientEdit,
    base: &CloudState,
    base_field: Option<&AmbientField>,
    ctl: &dyn Control,
) -> Result<(AmbientField, SolveStats), EditError> {
    let pins = pins(volume, edit);
    if pins.is_empty() {
        return Err(EditError::NoCover);
    }
    // The base version's visible ambient as I_m under the new scale (module doc).
    let scale = edit.ambient_scale.unwrap_or(base.ambient_scale);
    let per = if scale > 0.0 { 1.0 / scale } else { 1.0 };
    let field = base_field.filter(|f| f.rgb.len() == volume.len());
    let fill = |i: usize| -> [f32; 3] {
        match field {
            Some(f) => f.rgb[i].map(|v| (f64::from(v) * base.ambient_scale * per) as f32),
            None => base.ambient.map(|v| (v * per) as f32),
        }
    };
    let cloud = cloud_voxels(volume);
    let (rgb, stats) = propagate(
        volume.dims,
        &light.transmittance,
        Some(&cloud),
        &pins,
        &fill,
        SolveOptions::default(),
        ctl,
    )?;
    Ok((AmbientField { rgb }, stats))
}

/// The voxels that count as cloud for the propagation (module doc).
pub fn cloud_voxels(volume: &Volume) -> Vec<bool> {
    let max = volume.density.par_iter().copied().reduce(|| 0.0, f32::max);
    let min = DENSITY_THRESHOLD * max;
    volume
        .density
        .par_iter()
        .map(|&r| r > 0.0 && r >= min)
        .collect()
}
