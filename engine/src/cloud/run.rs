//! The one-shot `cloud` pipeline (SPEC §3): volume → sun transmittance sweep
//! ([`super::light`], fused into [`Prepared::lit`]) → camera-ray march ([`super::march`]) → `render.png` (RGBA, sRGB),
//! `state.json`, and `direct.png`/`multiple.png`/`ambient.png`/`layers.bin` on request. In
//! multiple mode the preparation also solves the multiple-scattering source term
//! ([`super::multiple`]).

use super::layers::{identity, layers_bin};
use super::march::{render_layers, Layers, Prepared, Show};
use super::params::{CloudParams, LayerOutput, View};
use super::state::{AmbientField, CloudState};
use crate::formats::png_write::encode_rgba;
use crate::geom::Volume;
use crate::{Canceled, Control, Output};

/// Renders `state` (with the optional per-voxel ambient `field`) from `view`: the linear layers.
/// Cost: one transmittance sweep (O(voxels)) and one march per pixel.
pub fn render(
    volume: &Volume,
    state: &CloudState,
    ambient: Option<&AmbientField>,
    view: &View,
    ctl: &dyn Control,
) -> Result<Layers, Canceled> {
    ctl.progress("light", 0.0);
    let prepared = Prepared::lit(volume, state, ambient, ctl)?;
    ctl.progress("march", 0.3);
    let camera = view.camera(volume.bounds);
    let layers = render_layers(&prepared, &camera, view.width, view.height, ctl)?;
    ctl.progress("encode", 0.95);
    Ok(layers)
}

/// The sun colour as the renderer's `f32`.
pub(crate) fn sun_f32(state: &CloudState) -> [f32; 3] {
    state.sun_color.map(|v| v as f32)
}

/// `render.png` of the layers, composited over the state's background if any.
pub fn render_png(layers: &Layers, state: &CloudState) -> Output {
    let img = layers.to_image(sun_f32(state), state.background_srgb(), Show::All);
    Output::new("render.png", "image/png", encode_rgba(&img))
}

/// `state.json`.
pub fn state_json(state: &CloudState) -> Output {
    Output::new("state.json", "application/json", state.to_json_bytes())
}

/// Runs the pipeline. `ambient` is the version's field (a field whose length is not the
/// volume's voxel count is ignored: uniform ambient). A κ left open is chosen from the volume
/// ([`super::kappa`]) and `state.json` states the value and the rule.
pub fn run(
    volume: &Volume,
    params: &CloudParams,
    ambient: Option<&AmbientField>,
    ctl: &dyn Control,
) -> Result<Vec<Output>, Canceled> {
    let state = params.state.resolved(volume);
    let layers = render(volume, &state, ambient, &params.view(), ctl)?;
    let mut out = vec![render_png(&layers, &state), state_json(&state)];
    let sun = sun_f32(&state);
    for l in &params.layers {
        // Layers are for compositing: straight alpha, no background.
        let (name, show) = match l {
            LayerOutput::Direct => ("direct.png", Show::Direct),
            LayerOutput::Multiple => ("multiple.png", Show::Multiple),
            LayerOutput::Ambient => ("ambient.png", Show::Ambient),
            LayerOutput::Linear => {
                let id = identity(&params.view(), &state);
                out.push(layers_bin(layers.to_bytes(&id)));
                continue;
            }
        };
        let img = layers.to_image(sun, None, show);
        out.push(Output::new(name, "image/png", encode_rgba(&img)));
    }
    ctl.progress("done", 1.0);
    Ok(out)
}
