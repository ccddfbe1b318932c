//! The three editing modes of the paper (SPEC §3.1–3.3): each turns a gesture on a render into
//! new rendering parameters, giving a new version of the cloud scene.
//!
//! - [`sun_color`]: paint → the least-squares sun colour I_l (§3.1, Eq. 6 generalised).
//! - [`ambient`]: paint → pinned voxels → a propagated per-voxel ambient field (§3.2).
//! - [`sun_direction`]: drag a shadow from P' to Q' → a new sun direction (§3.3).
//! - `set` ([`SetEdit`]): κ, the sun direction, the sun colour, the scattering mode or the
//!   albedo given directly (not a mode of the paper: the way out when κ or the sun leaves
//!   nothing lit to paint on, and the switch between single and multiple scattering).
//!
//! In multiple mode (issue 24, [`crate::cloud::multiple`]) the three modes of the paper work as
//! follows: the sun-colour least squares uses Ī + M (single plus multiple scattering, both per
//! unit sun: radiance stays linear in I_l); the ambient field is added on top of both, and its
//! propagation keeps the sun transmittance as the guide (the multiply scattered light is smooth
//! and carries no edges to guide by); the shadow drag is geometry (P, Q, R by voxel walks) and
//! is unchanged — after it Q lies in R's shadow, so its direct light drops, and the multiple
//! part, which comes from the whole lit cloud, drops less: shadows are softer.
//!
//! Every edit carries the view it was made in (image size and camera, the same wire shape as
//! the pipeline's), and pixel coordinates are `[x, y]` integers from the top-left, checked to
//! lie inside that image.

pub mod ambient;
pub mod job;
pub mod sun_color;
pub mod sun_direction;

use serde::Deserialize;

use super::layers::{identity, layers_bin, Layers};
use super::light::SunLight;
use super::multiple::Scattering;
use super::params::View;
use super::run::{render, render_png, state_json};
use super::state::{AmbientField, CloudState};
use crate::geom::Volume;
use crate::params::Limits;
use crate::params::{Color, WireCamera};
use crate::render::image::srgb_to_linear;
use crate::{Canceled, Control, Output, ParamError, Refusal};

/// Most painted pixels one edit may carry: a full-HD stroke set is far below this, and marching
/// 100,000 rays stays well under a second.
pub const MAX_STROKE_PIXELS: usize = 100_000;

/// One stroke: a colour (linear RGB, converted from the sRGB the user picked) and its pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Stroke {
    pub color: [f32; 3],
    pub pixels: Vec<[u32; 2]>,
}

/// Sun colour from paint (§3.1).
#[derive(Debug, Clone, PartialEq)]
pub struct SunColorEdit {
    pub view: View,
    pub strokes: Vec<Stroke>,
}

/// Ambient from paint (§3.2).
#[derive(Debug, Clone, PartialEq)]
pub struct AmbientEdit {
    pub view: View,
    pub strokes: Vec<Stroke>,
    /// New `ambient_scale` for the version, 0–100; absent = keep the base's.
    pub ambient_scale: Option<f64>,
    /// How far the painted change spreads from the painted voxels, as a fraction of the box's
    /// longest side, 0.01–100 ([`ambient`]'s screening). Default 0.25; large values give LLW's
    /// unbounded propagation (paint of one colour then fills the whole connected cloud).
    pub reach: f64,
}

/// Sun direction by dragging a shadow (§3.3): from P' to Q'.
#[derive(Debug, Clone, PartialEq)]
pub struct SunDirectionEdit {
    pub view: View,
    pub from: [u32; 2],
    pub to: [u32; 2],
}

/// Direct settings (issue 18: κ, sun direction and sun colour settable in the editor): a new
/// version with the given values replacing the base's; at least one is given.
#[derive(Debug, Clone, PartialEq)]
pub struct SetEdit {
    pub view: View,
    /// New κ, 0–10,000 (the choice from the volume, `kappa_auto`, is dropped).
    pub kappa: Option<f64>,
    /// New unit vector toward the sun.
    pub sun_direction: Option<[f64; 3]>,
    /// New sun colour, linear RGB, each 0–100.
    pub sun_color: Option<[f64; 3]>,
    /// New render mode (issue 24).
    pub scattering: Option<Scattering>,
    /// New single-scattering albedo, 0–1.
    pub albedo: Option<f64>,
}

/// An edit of a cloud scene version.
#[derive(Debug, Clone, PartialEq)]
pub enum Edit {
    SunColor(SunColorEdit),
    Ambient(AmbientEdit),
    SunDirection(SunDirectionEdit),
    Set(SetEdit),
}

/// The new version an edit produced.
#[derive(Debug, Clone, PartialEq)]
pub struct EditOutcome {
    pub state: CloudState,
    /// Some when the edit produced a new ambient field (the ambient edit); None keeps the base's.
    pub ambient: Option<AmbientField>,
}

/// Why an edit could not be applied.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EditError {
    #[error("canceled")]
    Canceled,
    /// The drag's start pixel sees no cloud.
    #[error("the drag starts on empty sky: no cloud under pixel ({0}, {1})")]
    DragStartsOnSky(u32, u32),
    /// The drag's end pixel sees no cloud.
    #[error("the drag ends on empty sky: no cloud under pixel ({0}, {1})")]
    DragEndsOnSky(u32, u32),
    /// R and Q are the same voxel: no direction.
    #[error("the drag does not move the shadow: the occluder and the target are the same voxel")]
    DragTooShort,
    /// No painted pixel sees the cloud: the stroke is on empty sky. Problem type
    /// `stroke-misses-cloud`.
    #[error("the stroke misses the cloud: no painted pixel covers it")]
    MissesCloud,
    /// The sun-colour stroke covers the cloud, but the cloud under it receives (almost) no
    /// sunlight — the direct light Ī of the painted pixels is below 1 % of full sunlight in the
    /// RMS ([`sun_color::LIT_MIN`]), so no sun colour can give the painted colour there. Problem
    /// type `stroke-not-lit`.
    #[error("nothing under the stroke is lit by the sun: move the sun or lower κ")]
    NotLit,
    /// The stored ambient field does not fit the volume.
    #[error("{0}")]
    Unusable(String),
}

impl EditError {
    /// The problem type (the last part of its URI) and title of a refused edit, when the
    /// refusal has one of its own (the two stroke cases); None for the rest, which are plain
    /// `unprocessable`.
    pub fn refusal(&self) -> Refusal {
        match self {
            EditError::MissesCloud => Refusal::StrokeMissesCloud,
            EditError::NotLit => Refusal::StrokeNotLit,
            _ => Refusal::Unprocessable,
        }
    }
}

impl From<Canceled> for EditError {
    fn from(_: Canceled) -> Self {
        EditError::Canceled
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum WireColor {
    Hex(String),
    Rgb([f64; 3]),
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct WireStroke {
    color: WireColor,
    pixels: Vec<[u32; 2]>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct WirePaint {
    width: Option<u32>,
    height: Option<u32>,
    camera: Option<WireCamera>,
    strokes: Vec<WireStroke>,
    ambient_scale: Option<f64>,
    reach: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct WireDrag {
    width: Option<u32>,
    height: Option<u32>,
    camera: Option<WireCamera>,
    from: [u32; 2],
    to: [u32; 2],
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct WireSet {
    width: Option<u32>,
    height: Option<u32>,
    camera: Option<WireCamera>,
    kappa: Option<f64>,
    sun_direction: Option<[f64; 3]>,
    sun_azimuth_deg: Option<f64>,
    sun_elevation_deg: Option<f64>,
    sun_color: Option<WireColor>,
    scattering: Option<Scattering>,
    albedo: Option<f64>,
}

fn pixel_inside(field: &str, p: [u32; 2], view: &View) -> Result<(), ParamError> {
    if p[0] >= view.width || p[1] >= view.height {
        return Err(ParamError::new(
            field,
            format!(
                "pixel ({}, {}) is outside the {}×{} image",
                p[0], p[1], view.width, view.height
            ),
        ));
    }
    Ok(())
}

/// Strokes: colours `"#rrggbb"` or `[r, g, b]` sRGB components in 0–1 (as a colour picker
/// gives them), converted to linear; at most [`MAX_STROKE_PIXELS`] pixels in all, at least one.
fn strokes(w: Vec<WireStroke>, view: &View) -> Result<Vec<Stroke>, ParamError> {
    let total: usize = w.iter().map(|s| s.pixels.len()).sum();
    if total == 0 {
        return Err(ParamError::new("strokes", "paint at least one pixel"));
    }
    if total > MAX_STROKE_PIXELS {
        return Err(ParamError::new(
            "strokes",
            format!("{total} painted pixels, at most {MAX_STROKE_PIXELS}"),
        ));
    }
    let mut out = Vec::with_capacity(w.len());
    for (i, s) in w.into_iter().enumerate() {
        let field = format!("strokes[{i}].color");
        let srgb: [f32; 3] = match &s.color {
            WireColor::Hex(h) => Color::parse(&field, h)?
                .srgb8()
                .map(|b| f32::from(b) / 255.0),
            WireColor::Rgb(c) => {
                let mut o = [0f32; 3];
                for (k, v) in c.iter().enumerate() {
                    o[k] = crate::params::range(&format!("{field}[{k}]"), Some(*v), 0.0, 0.0, 1.0)?
                        as f32;
                }
                o
            }
        };
        for (j, p) in s.pixels.iter().enumerate() {
            pixel_inside(&format!("strokes[{i}].pixels[{j}]"), *p, view)?;
        }
        out.push(Stroke {
            color: srgb.map(srgb_to_linear),
            pixels: s.pixels,
        });
    }
    Ok(out)
}

impl Edit {
    /// Validates an edit's wire JSON; `kind` is `"sun-color"`, `"ambient"` or `"sun-direction"`.
    pub fn from_json(
        kind: &str,
        v: &serde_json::Value,
        limits: &Limits,
    ) -> Result<Self, ParamError> {
        match kind {
            "sun-color" | "ambient" => {
                let w: WirePaint = crate::params::deserialize_params(v)?;
                let view = View::from_wire(w.width, w.height, w.camera, limits)?;
                let strokes = strokes(w.strokes, &view)?;
                if kind == "sun-color" {
                    if w.ambient_scale.is_some() {
                        return Err(ParamError::new(
                            "ambient_scale",
                            "only the ambient edit takes ambient_scale",
                        ));
                    }
                    if w.reach.is_some() {
                        return Err(ParamError::new(
                            "reach",
                            "only the ambient edit takes reach",
                        ));
                    }
                    Ok(Edit::SunColor(SunColorEdit { view, strokes }))
                } else {
                    let ambient_scale = match w.ambient_scale {
                        Some(s) => Some(crate::params::range(
                            "ambient_scale",
                            Some(s),
                            1.0,
                            0.0,
                            100.0,
                        )?),
                        None => None,
                    };
                    let reach = crate::params::range(
                        "reach",
                        w.reach,
                        ambient::DEFAULT_REACH,
                        0.01,
                        100.0,
                    )?;
                    Ok(Edit::Ambient(AmbientEdit {
                        view,
                        strokes,
                        ambient_scale,
                        reach,
                    }))
                }
            }
            "sun-direction" => {
                let w: WireDrag = crate::params::deserialize_params(v)?;
                let view = View::from_wire(w.width, w.height, w.camera, limits)?;
                pixel_inside("from", w.from, &view)?;
                pixel_inside("to", w.to, &view)?;
                Ok(Edit::SunDirection(SunDirectionEdit {
                    view,
                    from: w.from,
                    to: w.to,
                }))
            }
            "set" => {
                // `kappa: null` reads as "absent" to serde; the schema (and the edit's intent: a
                // value to set) says a number, so an explicit null is refused by name.
                if v.get("kappa").is_some_and(serde_json::Value::is_null) {
                    return Err(crate::ParamError::new(
                        "kappa",
                        "must be a number from 0 to 10000 (null is not a value to set)",
                    ));
                }
                let w: WireSet = crate::params::deserialize_params(v)?;
                let view = View::from_wire(w.width, w.height, w.camera, limits)?;
                let kappa = match w.kappa {
                    Some(k) => Some(crate::params::range("kappa", Some(k), k, 0.0, 10_000.0)?),
                    None => None,
                };
                let sun_given = w.sun_direction.is_some()
                    || w.sun_azimuth_deg.is_some()
                    || w.sun_elevation_deg.is_some();
                let sun_direction = if sun_given {
                    let ws = super::state::WireState {
                        sun_direction: w.sun_direction,
                        sun_azimuth_deg: w.sun_azimuth_deg,
                        sun_elevation_deg: w.sun_elevation_deg,
                        ..Default::default()
                    };
                    Some(CloudState::from_wire(ws)?.sun_direction)
                } else {
                    None
                };
                let sun_color = match w.sun_color {
                    None => None,
                    Some(WireColor::Hex(h)) => Some(
                        Color::parse("sun_color", &h)?
                            .srgb8()
                            .map(|b| f64::from(srgb_to_linear(f32::from(b) / 255.0))),
                    ),
                    Some(WireColor::Rgb(c)) => {
                        for (k, x) in c.iter().enumerate() {
                            crate::params::range(
                                &format!("sun_color[{k}]"),
                                Some(*x),
                                0.0,
                                0.0,
                                100.0,
                            )?;
                        }
                        Some(c)
                    }
                };
                let albedo = match w.albedo {
                    Some(a) => Some(crate::params::range("albedo", Some(a), a, 0.0, 1.0)?),
                    None => None,
                };
                if kappa.is_none()
                    && sun_direction.is_none()
                    && sun_color.is_none()
                    && w.scattering.is_none()
                    && albedo.is_none()
                {
                    return Err(ParamError::new(
                        "kappa",
                        "give at least one of kappa, sun_direction (or sun_azimuth_deg and \
                         sun_elevation_deg), sun_color, scattering, albedo",
                    ));
                }
                Ok(Edit::Set(SetEdit {
                    view,
                    kappa,
                    sun_direction,
                    sun_color,
                    scattering: w.scattering,
                    albedo,
                }))
            }
            other => Err(ParamError::new(
                "kind",
                format!(
                    "unknown edit {other:?}; expected sun-color, ambient, sun-direction or set"
                ),
            )),
        }
    }

    /// The view the edit was made in.
    pub fn view(&self) -> &View {
        match self {
            Edit::SunColor(e) => &e.view,
            Edit::Ambient(e) => &e.view,
            Edit::SunDirection(e) => &e.view,
            Edit::Set(e) => &e.view,
        }
    }
}

/// Applies `edit` to the version (`base`, `ambient`) of the scene on `volume`.
pub fn apply_edit(
    volume: &Volume,
    base: &CloudState,
    ambient: Option<&AmbientField>,
    edit: &Edit,
    ctl: &dyn Control,
) -> Result<EditOutcome, EditError> {
    // A κ left open is chosen from the volume once, here, and kept by the new version.
    let base = &base.resolved(volume);
    if let Some(f) = ambient {
        if f.rgb.len() != volume.len() {
            return Err(EditError::Unusable(format!(
                "the ambient field holds {} voxels, the volume has {}",
                f.rgb.len(),
                volume.len()
            )));
        }
    }
    match edit {
        Edit::SunColor(e) => {
            ctl.progress("sun-color", 0.0);
            let sun = sun_color::estimate(volume, base, ambient, e, ctl)?;
            Ok(EditOutcome {
                state: CloudState {
                    sun_color: sun,
                    ..base.clone()
                },
                ambient: None,
            })
        }
        Edit::SunDirection(e) => {
            let dir = sun_direction::drag(volume, base, e)?;
            Ok(EditOutcome {
                state: CloudState {
                    sun_direction: dir.direction,
                    ..base.clone()
                },
                ambient: None,
            })
        }
        Edit::Set(e) => Ok(EditOutcome {
            state: CloudState {
                kappa: e.kappa.or(base.kappa),
                kappa_auto: if e.kappa.is_some() {
                    None
                } else {
                    base.kappa_auto.clone()
                },
                sun_direction: e.sun_direction.unwrap_or(base.sun_direction),
                sun_color: e.sun_color.unwrap_or(base.sun_color),
                scattering: e.scattering.unwrap_or(base.scattering),
                albedo: e.albedo.unwrap_or(base.albedo),
                ..base.clone()
            },
            ambient: None,
        }),
        Edit::Ambient(e) => {
            ctl.progress("light", 0.0);
            let light = SunLight::compute(volume, base.sun_direction, base.kappa_for(volume), ctl)?;
            ctl.progress("ambient", 0.2);
            let (field, _) = ambient::propagate_paint(volume, &light, e, base, ambient, ctl)?;
            Ok(EditOutcome {
                state: CloudState {
                    ambient_scale: e.ambient_scale.unwrap_or(base.ambient_scale),
                    ..base.clone()
                },
                ambient: Some(field),
            })
        }
    }
}

/// The new version's outputs: `state.json`, `ambient.bin` (when the edit made a new field),
/// `render.png` at the edit's view and its linear layers `layers.bin` (for a later sun-colour
/// edit at that view, [`recolor`]). The render uses the outcome's field only; when the edit kept
/// the base version's field (sun colour, sun direction) call [`edit_outputs_with`] and pass it,
/// or the render shows uniform ambient.
pub fn edit_outputs(
    volume: &Volume,
    outcome: &EditOutcome,
    edit: &Edit,
    ctl: &dyn Control,
) -> Result<Vec<Output>, Canceled> {
    edit_outputs_with(volume, outcome, None, edit, ctl)
}

/// [`edit_outputs`] with the base version's ambient field, used for the render when the edit
/// did not make a new one.
pub fn edit_outputs_with(
    volume: &Volume,
    outcome: &EditOutcome,
    base_ambient: Option<&AmbientField>,
    edit: &Edit,
    ctl: &dyn Control,
) -> Result<Vec<Output>, Canceled> {
    let field = outcome.ambient.as_ref().or(base_ambient);
    let layers = render(volume, &outcome.state, field, edit.view(), ctl)?;
    let mut out = vec![state_json(&outcome.state)];
    if let Some(f) = &outcome.ambient {
        out.push(Output::new(
            "ambient.bin",
            "application/octet-stream",
            f.to_bytes(),
        ));
    }
    out.push(render_png(&layers, &outcome.state));
    let id = identity(edit.view(), &outcome.state);
    out.push(layers_bin(layers.to_bytes(&id)));
    Ok(out)
}

/// The sun-colour edit from the layers of the base version's render at the edit's view
/// (`layers` as read from `blob`, whose identity the caller checked against
/// [`identity`]`(edit view, base)`): the least-squares sun colour from the painted pixels'
/// stored Ī and A, and the new version's render is the same layers with the new sun — nothing
/// is marched. The outputs are those [`apply_edit`] and [`edit_outputs_with`] give (the same
/// bytes: the blob is lossless), `layers.bin` being `blob` itself (the layers do not depend on
/// the sun colour).
pub fn recolor(
    base: &CloudState,
    edit: &SunColorEdit,
    layers: &Layers,
    blob: &[u8],
    ctl: &dyn Control,
) -> Result<Vec<Output>, EditError> {
    ctl.progress("recolor", 0.0);
    let state = CloudState {
        sun_color: sun_color::estimate_from_layers(layers, base, edit)?,
        ..base.clone()
    };
    ctl.checkpoint()?;
    ctl.progress("encode", 0.5);
    Ok(vec![
        state_json(&state),
        render_png(layers, &state),
        layers_bin(blob.to_vec()),
    ])
}
