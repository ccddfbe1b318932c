//! Parameters of the one-shot `cloud` pipeline (SPEC §3): the view (size, camera), the
//! [`CloudState`] fields at the top level, the extra layers, and the decoder's `bounds`/`dims`.

use serde::{Deserialize, Serialize};

use super::state::{CloudState, WireState, STATE_FIELDS};
use crate::geom::camera::Camera;
use crate::params::Limits;
use crate::params::{camera_spec, image_size, CameraSpec, WireCamera};
use crate::ParamError;

pub use super::kappa::ORBIT;

/// Default image size.
pub const DEFAULT_SIZE: (u32, u32) = (800, 600);

/// An extra output layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LayerOutput {
    /// `direct.png`: I_l·Ī (single scattering).
    Direct,
    /// `multiple.png`: I_l·M, the multiple-scattering layer (zero in single mode).
    Multiple,
    /// `ambient.png`: A.
    Ambient,
    /// `layers.bin`: the linear Ī, A and α of every pixel ([`super::layers`]), which a later
    /// sun-colour edit at the same view reads instead of marching. Cloud scenes ask for it.
    Linear,
}

/// Wire form of `layers`: `true` = the images (`direct`, `ambient`, and `multiple` in multiple
/// mode), `false` = none, or a list of names.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub(crate) enum WireLayers {
    All(bool),
    List(Vec<LayerOutput>),
}

/// A view: the image size and camera an edit was made in (same wire shape as [`CloudParams`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct View {
    /// Image width, pixels, 16–8192. Default 800.
    pub width: u32,
    /// Image height, pixels, 16–8192. Default 600.
    pub height: u32,
    /// Orbit (default azimuth 200°, elevation 12°, fov 40°, framing the volume's box) or
    /// eye/target.
    pub camera: CameraSpec,
}

impl View {
    pub(crate) fn from_wire(
        width: Option<u32>,
        height: Option<u32>,
        camera: Option<WireCamera>,
        limits: &Limits,
    ) -> Result<Self, ParamError> {
        let (width, height) = image_size(width, height, DEFAULT_SIZE, limits)?;
        let camera = camera_spec(camera.unwrap_or_default(), ORBIT)?;
        Ok(Self {
            width,
            height,
            camera,
        })
    }

    /// The camera for a volume whose box is `bounds`.
    pub fn camera(&self, bounds: ([f64; 3], [f64; 3])) -> Camera {
        self.camera
            .camera(Some(bounds), f64::from(self.width) / f64::from(self.height))
    }
}

/// Wire parameters other than the state's.
#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct WireRest {
    width: Option<u32>,
    height: Option<u32>,
    camera: Option<WireCamera>,
    seed: Option<u64>,
    layers: Option<WireLayers>,
    bounds: Option<[[f64; 3]; 2]>,
    dims: Option<[usize; 3]>,
}

/// Validated parameters of one `cloud` run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CloudParams {
    /// Output width, pixels, 16–8192. Default 800.
    pub width: u32,
    /// Output height, pixels, 16–8192. Default 600.
    pub height: u32,
    pub camera: CameraSpec,
    /// Accepted for uniformity with the other pipelines; the renderer is deterministic and uses
    /// no randomness. Default 0.
    pub seed: u64,
    /// The rendering parameters (κ, sun, ambient, …), flattened at the top level.
    #[serde(flatten)]
    pub state: CloudState,
    /// Extra layers to write (`direct.png`, `multiple.png`, `ambient.png`, `layers.bin`).
    /// Default none.
    pub layers: Vec<LayerOutput>,
    /// World box `[[min], [max]]` of the volume; null = SPEC §3's default (unit cube scaled to
    /// the grid's aspect, base at Y = 0). Each min < max, finite, within ±10⁹, each side ≥ 10⁻⁶
    /// and ≥ 10⁻⁶ of its axis' largest |coordinate| ([`crate::geom::sanity::check_box`]).
    pub bounds: Option<[[f64; 3]; 2]>,
    /// Grid size `[nx, ny, nz]` for raw float32 input (each ≥ 1, product within the input cell
    /// limit); ignored by self-describing formats. Default null.
    pub dims: Option<[usize; 3]>,
}

impl CloudParams {
    /// Validates wire JSON: unknown names, wrong types and out-of-range values are errors naming
    /// the field.
    pub fn from_json(v: &serde_json::Value, limits: &Limits) -> Result<Self, ParamError> {
        let obj = v
            .as_object()
            .ok_or_else(|| ParamError::new("params", "must be a JSON object"))?;
        let (mut state_obj, mut rest_obj) = (serde_json::Map::new(), serde_json::Map::new());
        for (k, val) in obj {
            if STATE_FIELDS.contains(&k.as_str()) {
                state_obj.insert(k.clone(), val.clone());
            } else {
                rest_obj.insert(k.clone(), val.clone());
            }
        }
        let ws: WireState =
            crate::params::deserialize_params(&serde_json::Value::Object(state_obj))?;
        let state = CloudState::from_wire(ws)?;
        let w: WireRest = crate::params::deserialize_params(&serde_json::Value::Object(rest_obj))?;
        let view = View::from_wire(w.width, w.height, w.camera, limits)?;
        let layers = match w.layers {
            None | Some(WireLayers::All(false)) => vec![],
            Some(WireLayers::All(true)) if state.scattering.is_single() => {
                vec![LayerOutput::Direct, LayerOutput::Ambient]
            }
            Some(WireLayers::All(true)) => vec![
                LayerOutput::Direct,
                LayerOutput::Multiple,
                LayerOutput::Ambient,
            ],
            Some(WireLayers::List(l)) => {
                let mut out = vec![];
                for x in [
                    LayerOutput::Direct,
                    LayerOutput::Multiple,
                    LayerOutput::Ambient,
                    LayerOutput::Linear,
                ] {
                    if l.contains(&x) {
                        out.push(x);
                    }
                }
                out
            }
        };
        if let Some([lo, hi]) = w.bounds {
            // [[xmin, ymin, zmin], [xmax, ymax, zmax]] within the engine's coordinate range.
            crate::geom::sanity::check_box(lo, hi).map_err(|e| ParamError::new("bounds", e))?;
        }
        if let Some(d) = w.dims {
            let cells = d
                .iter()
                .try_fold(1u64, |acc, &n| acc.checked_mul(n as u64))
                .unwrap_or(u64::MAX);
            if d.contains(&0) || cells > limits.max_input_cells {
                return Err(ParamError::new(
                    "dims",
                    format!(
                        "must be three sizes ≥ 1 with at most {} voxels in all",
                        limits.max_input_cells
                    ),
                ));
            }
        }
        Ok(Self {
            width: view.width,
            height: view.height,
            camera: view.camera,
            seed: w.seed.unwrap_or(0),
            state,
            layers,
            bounds: w.bounds,
            dims: w.dims,
        })
    }

    /// The volume box override, as the `(min, max)` pair [`crate::geom::Volume`] uses.
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        self.bounds.map(|[lo, hi]| (lo, hi))
    }

    /// The raw grid size, if given.
    pub fn dims(&self) -> Option<[usize; 3]> {
        self.dims
    }

    /// The view of this run.
    pub fn view(&self) -> View {
        View {
            width: self.width,
            height: self.height,
            camera: self.camera.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn canonical_form_parses_back_equal() {
        let l = Limits::default();
        for v in [
            json!({}),
            json!({"kappa": 12, "layers": true, "background": "#102030",
                   "bounds": [[0, 0, 0], [1, 2, 1]], "dims": [4, 5, 6],
                   "camera": {"eye": [3, 1, 2], "target": [0, 0.5, 0]}}),
            json!({"layers": ["ambient"], "sun_azimuth_deg": 10, "sun_elevation_deg": 60}),
            json!({"layers": true, "scattering": "multiple", "albedo": 0.9}),
        ] {
            let p = CloudParams::from_json(&v, &l).unwrap();
            let c = serde_json::to_value(&p).unwrap();
            assert_eq!(CloudParams::from_json(&c, &l).unwrap(), p, "{c}");
        }
    }

    #[test]
    fn errors_name_the_field() {
        let l = Limits::default();
        for (v, field) in [
            (json!({"kapa": 1}), "kapa"),
            (json!({"kappa": -1}), "kappa"),
            (json!({"width": 4}), "width"),
            (json!({"dims": [0, 1, 1]}), "dims"),
            (json!({"bounds": [[0, 0, 0], [0, 1, 1]]}), "bounds"),
            (json!({"camera": {"fov_deg": 500}}), "camera.fov_deg"),
        ] {
            assert_eq!(
                CloudParams::from_json(&v, &l).unwrap_err().field,
                field,
                "{v}"
            );
        }
    }
}
