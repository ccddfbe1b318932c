//! Parameters of the `dust` pipeline (SPEC §4, §5): the wire form (JSON, unknown names rejected)
//! and the validated form. The backticked names of SPEC §4 keep their names; the model's K, s and
//! U, which the SPEC writes as symbols, are `stickiness`, `slipperiness` and `dust_source`.
//! The view (size, camera, up axis, sun, fog, shadows) is the one `snow-cover` has
//! ([`MeshView`]). Every field says its unit, range and default.

use serde::{Deserialize, Serialize};

use super::amount::AmountModel;
use super::fibers::FiberParams;
use crate::geom::mesh::UpAxis;
use crate::params::{range, Color, Limits, MeshView, MeshViewDefaults, WireCamera, WireMeshView};
use crate::render::image::srgb8_to_linear;
use crate::ParamError;

/// Largest `shells` × `texture_size`²: the shell textures and their atlas hold ~5 bytes per texel
/// (2^26 texels ≈ 0.35 GB), e.g. 32 shells of 1448², 128 of 724², 4 of 4096².
pub const MAX_TEXELS: u64 = 1 << 26;

/// Largest `fibers` × (`fiber_length` + 1): the trail buffer of one texture holds 16 bytes per
/// trail texel (2^25 ≈ 0.5 GB), e.g. 680,000 fibres of 48 steps.
pub const MAX_TRAIL: u64 = 1 << 25;

/// Default `dust_color`: a light grey-beige.
const DEFAULT_DUST_COLOR: &str = "#e7e2da";

/// Wire parameters (all optional; unknown names are rejected).
#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WireParams {
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub camera: Option<WireCamera>,
    pub seed: Option<u64>,
    pub up_axis: Option<UpAxis>,
    pub sun_azimuth_deg: Option<f64>,
    pub sun_elevation_deg: Option<f64>,
    pub fog: Option<f32>,
    pub shadows: Option<bool>,
    pub stickiness: Option<f32>,
    pub slipperiness: Option<f32>,
    pub dust_source: Option<[f64; 3]>,
    pub exposure: Option<bool>,
    pub exposure_rays: Option<u32>,
    pub shells: Option<u32>,
    pub max_thickness: Option<f32>,
    pub noise_scale: Option<f64>,
    pub noise_octaves: Option<usize>,
    pub texture_size: Option<u32>,
    pub fiber_tile: Option<f32>,
    pub fibers: Option<u32>,
    pub fiber_length: Option<u32>,
    pub bends: Option<u32>,
    pub bend_angle_deg: Option<f32>,
    pub fiber_decay: Option<f32>,
    pub fiber_opacity: Option<f32>,
    pub dust_color: Option<String>,
    pub close_up: Option<bool>,
}

/// Validated parameters of one `dust` run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DustParams {
    /// Output size, camera, up axis, sun, fog (default 0: dust is an indoor, close-up
    /// phenomenon) and shadows, shared with `snow-cover`.
    #[serde(flatten)]
    pub view: MeshView,
    /// Seed of the noise and the fibres. Default 0.
    pub seed: u64,
    /// K, the dust's stickiness: D on a horizontal, fully exposed face, 0–4. Default 1.
    pub stickiness: f32,
    /// s, the surface's slipperiness (exponent of N·U), 0–64. Default 2.
    pub slipperiness: f32,
    /// U, direction toward the dust source (normalised here), world space Y up. Default
    /// `[0, 1, 0]`.
    pub dust_source: [f32; 3],
    /// Exposure term E(P) on (ambient occlusion around U). Default true.
    pub exposure: bool,
    /// Hemisphere rays per vertex for E(P), 1–1024. Default 64.
    pub exposure_rays: u32,
    /// Shell layers, 1–128. Default 32 (Lengyel et al. use 16–32).
    pub shells: u32,
    /// Thickness of the dust where D = 1, metres, > 0; null = 1 % of the mesh's bounding-box
    /// diagonal (the meshes we ship range from 0.2 m to 20 m across). Default null.
    pub max_thickness: Option<f32>,
    /// Base-octave noise cells across one fibre texture (see [`super::noise`]), 0.5–256.
    /// Default 4.
    pub noise_scale: f64,
    /// fBm octaves, 1–12. Default 5.
    pub noise_octaves: usize,
    /// Fibre texture side, texels, 64–4096. Default 512 (one tile covers `fiber_tile`; 512 keeps
    /// a texel at most about a pixel in a close-up of a tenth of the object, and the 32 textures
    /// of `fibers.png` and `dusty.glb` near 10 MB each).
    pub texture_size: u32,
    /// Surface covered by one fibre texture tile, metres, > 0; null = 1/8 of the mesh's
    /// bounding-box diagonal (see [`super::mapping`]). Default null.
    pub fiber_tile: Option<f32>,
    /// Fibres in the bottom shell's texture, 0–1,000,000. Default 5,000 (at 512²; the issue's
    /// benchmark case, 20,000 at 1024², has the same density).
    pub fibers: u32,
    /// Steps per fibre, 1–4096. Default 48.
    pub fiber_length: u32,
    /// Bends per fibre, 0–64 (and < `fiber_length`). Default 2.
    pub bends: u32,
    /// Largest heading change at a bend, degrees, 0–180. Default 60.
    pub bend_angle_deg: f32,
    /// Brightness lost per step, fraction, 0–1. Default 0.02.
    pub fiber_decay: f32,
    /// Opacity of a fibre texel, 0–1. Default 0.35.
    pub fiber_opacity: f32,
    /// Dust colour, sRGB hex. Default `#e7e2da` (light grey-beige house dust; the fibres'
    /// brightness darkens it, see [`super::render::DEPTH_SHADE`]).
    pub dust_color: Color,
    /// Close-up: the orbit camera circles the middle of the dustiest patch of the surface the
    /// default view sees (see [`super::run::close_up_target`]) instead of the mesh's centre, at
    /// `camera.distance` from it (default: 1/10 of the mesh's bounding-box diagonal), so single
    /// fibres show; with `stickiness: 0` the place dust would lie (D per unit stickiness), so a
    /// request without dust frames the same patch. Needs the orbit camera (not eye/target).
    /// Default false.
    pub close_up: bool,
}

fn unit3(field: &str, v: Option<[f64; 3]>, default: [f32; 3]) -> Result<[f32; 3], ParamError> {
    match v {
        Some(v) => Ok(crate::params::unit_vector(field, v)?.map(|x| x as f32)),
        None => Ok(default),
    }
}

impl DustParams {
    /// Validates wire JSON: unknown names, wrong types and out-of-range values are errors naming
    /// the field.
    pub fn from_json(v: &serde_json::Value, limits: &Limits) -> Result<Self, ParamError> {
        let w: WireParams = crate::params::deserialize_params(v)?;
        let view = MeshView::from_wire(
            WireMeshView {
                width: w.width,
                height: w.height,
                camera: w.camera.clone(),
                up_axis: w.up_axis,
                sun_azimuth_deg: w.sun_azimuth_deg,
                sun_elevation_deg: w.sun_elevation_deg,
                fog: w.fog,
                shadows: w.shadows,
            },
            MeshViewDefaults {
                fog: 0.0,
                ..MeshViewDefaults::default()
            },
            limits,
        )?;
        let max_thickness = match w.max_thickness {
            Some(t) => Some(range("max_thickness", Some(t), 0.01, 1e-6, 1e4)?),
            None => None,
        };
        let fiber_length = range("fiber_length", w.fiber_length, 48, 1, 4096)?;
        let bends = range("bends", w.bends, 2, 0, 64)?;
        if bends >= fiber_length {
            return Err(ParamError::new(
                "bends",
                format!("must be less than fiber_length ({fiber_length})"),
            ));
        }
        let dust_color = Color::parse(
            "dust_color",
            w.dust_color.as_deref().unwrap_or(DEFAULT_DUST_COLOR),
        )?;
        let shells = range("shells", w.shells, 32, 1, 128)?;
        let texture_size = range("texture_size", w.texture_size, 512, 64, 4096)?;
        let texels = u64::from(shells) * u64::from(texture_size) * u64::from(texture_size);
        if texels > MAX_TEXELS {
            return Err(ParamError::new(
                "texture_size",
                format!(
                    "{shells} shells of {texture_size}² texels exceed the budget of {MAX_TEXELS} \
                     texels; lower texture_size or shells"
                ),
            ));
        }
        let fibers = range("fibers", w.fibers, 5_000, 0, 1_000_000)?;
        if u64::from(fibers) * (u64::from(fiber_length) + 1) > MAX_TRAIL {
            return Err(ParamError::new(
                "fibers",
                format!(
                    "{fibers} fibres of {fiber_length} steps exceed the budget of {MAX_TRAIL} \
                     trail texels per texture"
                ),
            ));
        }
        let fiber_tile = match w.fiber_tile {
            Some(t) => Some(range("fiber_tile", Some(t), 1.0, 1e-6, 1e6)?),
            None => None,
        };
        let close_up = w.close_up.unwrap_or(false);
        if close_up && matches!(view.camera, crate::params::CameraSpec::LookAt { .. }) {
            return Err(ParamError::new(
                "close_up",
                "needs the orbit camera (azimuth_deg/elevation_deg/distance), not eye/target",
            ));
        }
        Ok(DustParams {
            view,
            seed: w.seed.unwrap_or(0),
            stickiness: range("stickiness", w.stickiness, 1.0, 0.0, 4.0)?,
            slipperiness: range("slipperiness", w.slipperiness, 2.0, 0.0, 64.0)?,
            dust_source: unit3("dust_source", w.dust_source, [0.0, 1.0, 0.0])?,
            exposure: w.exposure.unwrap_or(true),
            exposure_rays: range("exposure_rays", w.exposure_rays, 64, 1, 1024)?,
            shells,
            max_thickness,
            noise_scale: range("noise_scale", w.noise_scale, 4.0, 0.5, 256.0)?,
            noise_octaves: range("noise_octaves", w.noise_octaves, 5, 1, 12)?,
            texture_size,
            fiber_tile,
            fibers,
            fiber_length,
            bends,
            bend_angle_deg: range("bend_angle_deg", w.bend_angle_deg, 60.0, 0.0, 180.0)?,
            fiber_decay: range("fiber_decay", w.fiber_decay, 0.02, 0.0, 1.0)?,
            fiber_opacity: range("fiber_opacity", w.fiber_opacity, 0.35, 0.0, 1.0)?,
            dust_color,
            close_up,
        })
    }

    /// The dust-amount model (SPEC §4 step 1).
    pub fn amount_model(&self) -> AmountModel {
        AmountModel {
            stickiness: self.stickiness,
            slipperiness: self.slipperiness,
            source: self.dust_source,
            exposure: self.exposure,
            exposure_rays: self.exposure_rays,
        }
    }

    /// The dust colour, linear RGB.
    pub fn dust_color_linear(&self) -> [f32; 3] {
        self.dust_color.srgb8().map(srgb8_to_linear)
    }

    /// The fibre parameters (SPEC §4 step 3).
    pub fn fiber_params(&self) -> FiberParams {
        FiberParams {
            fibers: self.fibers,
            fiber_length: self.fiber_length,
            bends: self.bends,
            bend_angle_deg: self.bend_angle_deg,
            fiber_decay: self.fiber_decay,
            fiber_opacity: self.fiber_opacity,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn defaults_match_the_model_defaults() {
        let p = DustParams::from_json(&json!({}), &Limits::default()).unwrap();
        assert_eq!(p.amount_model(), AmountModel::default());
        assert_eq!(p.fiber_params(), FiberParams::default());
        // The canonical form round-trips through the wire form.
        let v = serde_json::to_value(&p).unwrap();
        let q = DustParams::from_json(&v, &Limits::default()).unwrap();
        assert_eq!(p, q);
    }

    #[test]
    fn errors_name_the_field() {
        let l = Limits::default();
        for (v, field) in [
            (json!({"shells": 0}), "shells"),
            (json!({"bends": 48}), "bends"),
            (json!({"fiber_opacity": 1.5}), "fiber_opacity"),
            (json!({"dust_source": [0, 0, 0]}), "dust_source"),
            (json!({"dust_color": "#12345g"}), "dust_color"),
            (json!({"dust_color": [0.5, 0.5, 0.5]}), "dust_color"),
            (json!({"up_axis": "x"}), "up_axis"),
            (json!({"fiber_tile": 0}), "fiber_tile"),
            (json!({"texture_size": 4096, "shells": 8}), "texture_size"),
            (json!({"fibers": 1_000_000, "fiber_length": 100}), "fibers"),
            (json!({"fibres": 3}), "fibres"),
            (
                json!({"close_up": true, "camera": {"eye": [0, 1, 2], "target": [0, 0, 0]}}),
                "close_up",
            ),
        ] {
            let e = DustParams::from_json(&v, &l).unwrap_err();
            assert_eq!(e.field, field, "{v}: {e}");
        }
    }
}
