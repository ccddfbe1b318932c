//! Parameters of the `dust` pipeline (SPEC §4, §5): the wire form (JSON, unknown names rejected)
//! and the validated form. The backticked names of SPEC §4 keep their names; the model's K, s and
//! U, which the SPEC writes as symbols, are `stickiness`, `slipperiness` and `dust_source`.
//! Every field says its unit, range and default. Not yet wired into the pipeline (issue 6).

use serde::{Deserialize, Serialize};

use super::amount::AmountModel;
use super::fibers::FiberParams;
use crate::params::{camera_spec, image_size, range, CameraSpec, OrbitDefaults, WireCamera};
use crate::pipeline::Limits;
use crate::ParamError;

/// Wire parameters (all optional; unknown names are rejected).
#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WireParams {
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub camera: Option<WireCamera>,
    pub seed: Option<u64>,
    pub stickiness: Option<f32>,
    pub slipperiness: Option<f32>,
    pub dust_source: Option<[f32; 3]>,
    pub exposure: Option<bool>,
    pub exposure_rays: Option<u32>,
    pub shells: Option<u32>,
    pub max_thickness: Option<f32>,
    pub noise_scale: Option<f64>,
    pub noise_octaves: Option<usize>,
    pub texture_size: Option<u32>,
    pub fibers: Option<u32>,
    pub fiber_length: Option<u32>,
    pub bends: Option<u32>,
    pub bend_angle_deg: Option<f32>,
    pub fiber_decay: Option<f32>,
    pub fiber_opacity: Option<f32>,
    pub dust_color: Option<[f32; 3]>,
}

/// Validated parameters of one `dust` run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Params {
    /// Output image width, pixels, 16–8192. Default 960.
    pub width: u32,
    /// Output image height, pixels, 16–8192. Default 640.
    pub height: u32,
    pub camera: CameraSpec,
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
    /// Fibre texture side, texels, 64–4096. Default 1024.
    pub texture_size: u32,
    /// Fibres in the bottom shell's texture, 0–1,000,000. Default 20,000 (at 1024²).
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
    /// Dust colour, linear RGB 0–1. Default `[0.62, 0.58, 0.52]` (grey-beige house dust).
    pub dust_color: [f32; 3],
}

fn unit3(field: &str, v: Option<[f32; 3]>, default: [f32; 3]) -> Result<[f32; 3], ParamError> {
    let v = v.unwrap_or(default);
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !(l.is_finite() && l > 1e-6) {
        return Err(ParamError::new(field, "must be a finite, non-zero vector"));
    }
    Ok([v[0] / l, v[1] / l, v[2] / l])
}

impl Params {
    /// Validates wire JSON: unknown names, wrong types and out-of-range values are errors naming
    /// the field.
    pub fn from_json(v: &serde_json::Value, limits: &Limits) -> Result<Self, ParamError> {
        let w: WireParams = crate::pipeline::deserialize_params(v)?;
        let (width, height) = image_size(w.width, w.height, (960, 640), limits)?;
        let camera = camera_spec(
            w.camera.clone().unwrap_or_default(),
            OrbitDefaults {
                azimuth_deg: 210.0,
                elevation_deg: 35.0,
                fov_deg: 40.0,
            },
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
        let dust_color = w.dust_color.unwrap_or([0.62, 0.58, 0.52]);
        for (i, c) in dust_color.iter().enumerate() {
            range(&format!("dust_color[{i}]"), Some(*c), 0.0, 0.0, 1.0)?;
        }
        Ok(Params {
            width,
            height,
            camera,
            seed: w.seed.unwrap_or(0),
            stickiness: range("stickiness", w.stickiness, 1.0, 0.0, 4.0)?,
            slipperiness: range("slipperiness", w.slipperiness, 2.0, 0.0, 64.0)?,
            dust_source: unit3("dust_source", w.dust_source, [0.0, 1.0, 0.0])?,
            exposure: w.exposure.unwrap_or(true),
            exposure_rays: range("exposure_rays", w.exposure_rays, 64, 1, 1024)?,
            shells: range("shells", w.shells, 32, 1, 128)?,
            max_thickness,
            noise_scale: range("noise_scale", w.noise_scale, 4.0, 0.5, 256.0)?,
            noise_octaves: range("noise_octaves", w.noise_octaves, 5, 1, 12)?,
            texture_size: range("texture_size", w.texture_size, 1024, 64, 4096)?,
            fibers: range("fibers", w.fibers, 20_000, 0, 1_000_000)?,
            fiber_length,
            bends,
            bend_angle_deg: range("bend_angle_deg", w.bend_angle_deg, 60.0, 0.0, 180.0)?,
            fiber_decay: range("fiber_decay", w.fiber_decay, 0.02, 0.0, 1.0)?,
            fiber_opacity: range("fiber_opacity", w.fiber_opacity, 0.35, 0.0, 1.0)?,
            dust_color,
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
        let p = Params::from_json(&json!({}), &Limits::default()).unwrap();
        assert_eq!(p.amount_model(), AmountModel::default());
        assert_eq!(p.fiber_params(), FiberParams::default());
        // The canonical form round-trips through the wire form.
        let v = serde_json::to_value(&p).unwrap();
        let q = Params::from_json(&v, &Limits::default()).unwrap();
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
            (json!({"dust_color": [0.5, 2, 0.5]}), "dust_color[1]"),
            (json!({"fibres": 3}), "fibres"),
        ] {
            let e = Params::from_json(&v, &l).unwrap_err();
            assert_eq!(e.field, field, "{v}: {e}");
        }
    }
}
