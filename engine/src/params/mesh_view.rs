//! The view block the mesh pipelines (`snow-cover`, SPEC §2; `dust`, SPEC §4) share: the
//! input's up axis, the output size, the camera, the sun, fog and shadows — their wire fields and
//! validation (each pipeline with its own defaults). One copy for both pipelines; the scene is
//! decoded by [`crate::formats::mesh::decode_upright`] and lit by
//! [`crate::render::mesh::MeshLighting::for_view`].

use serde::Serialize;

use super::camera::{camera_spec, CameraSpec, OrbitDefaults, WireCamera};
use super::wire::{image_size, range, Limits};
use crate::geom::camera::Camera;
use crate::geom::mesh::UpAxis;
use crate::geom::Mesh;
use crate::ParamError;

/// The view fields as they come off the wire (each pipeline's wire struct lists them, since
/// `deny_unknown_fields` does not combine with `flatten`, and hands them over here).
#[derive(Debug, Default, Clone)]
pub struct WireMeshView {
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub camera: Option<WireCamera>,
    pub up_axis: Option<UpAxis>,
    pub sun_azimuth_deg: Option<f64>,
    pub sun_elevation_deg: Option<f64>,
    pub fog: Option<f32>,
    pub shadows: Option<bool>,
}

/// A pipeline's defaults for the view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshViewDefaults {
    pub orbit: OrbitDefaults,
    /// Default `fog` (per scene diagonal).
    pub fog: f32,
}

impl Default for MeshViewDefaults {
    fn default() -> Self {
        Self {
            orbit: OrbitDefaults {
                azimuth_deg: 210.0,
                elevation_deg: 35.0,
                fov_deg: 40.0,
            },
            fog: 0.6,
        }
    }
}

/// The validated view (serialised flat into the pipeline's canonical parameters).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeshView {
    /// Output image width, pixels, 16–8192. Default 960.
    pub width: u32,
    /// Output image height, pixels, 16–8192. Default 640.
    pub height: u32,
    /// Orbit around the scene's centre (defaults azimuth 210°, elevation 35°, fov 40°, distance
    /// framing the scene) or eye/target.
    pub camera: CameraSpec,
    /// Up axis of the input; given, it applies to every format (glTF too). Default (null): the
    /// reader's convention (Z for STL/PLY, Y for OBJ and glTF) unless the other one stands on the
    /// ground at least twice as well or, neither standing clearly better, only the other makes the
    /// model taller than wide ([`crate::formats::mesh::decode_upright`]); a turned model
    /// gets a note in the report.
    pub up_axis: Option<UpAxis>,
    /// Sun for shading, compass azimuth degrees, 0–360. Default 150.
    pub sun_azimuth_deg: f64,
    /// Sun elevation, degrees, 1–90. Default 40.
    pub sun_elevation_deg: f64,
    /// Exponential fog density per scene diagonal, 0–10, counted from the scene's near side (the
    /// front of the model is clear, the back fades). Default: the pipeline's (snow-cover 0.6,
    /// as the paper renders with fog).
    pub fog: f32,
    /// Cast shadows in the render. Default true.
    pub shadows: bool,
}

impl MeshView {
    /// Validates the view fields; errors name the field.
    pub fn from_wire(
        w: WireMeshView,
        d: MeshViewDefaults,
        limits: &Limits,
    ) -> Result<Self, ParamError> {
        let (width, height) = image_size(w.width, w.height, (960, 640), limits)?;
        Ok(Self {
            width,
            height,
            camera: camera_spec(w.camera.unwrap_or_default(), d.orbit)?,
            up_axis: w.up_axis,
            sun_azimuth_deg: range("sun_azimuth_deg", w.sun_azimuth_deg, 150.0, 0.0, 360.0)?,
            sun_elevation_deg: range("sun_elevation_deg", w.sun_elevation_deg, 40.0, 1.0, 90.0)?,
            fog: range("fog", w.fog, d.fog, 0.0, 10.0)?,
            shadows: w.shadows.unwrap_or(true),
        })
    }

    /// The camera for `mesh` at `width × height` (see [`CameraSpec::camera`]).
    pub fn camera_for(&self, mesh: &Mesh, width: u32, height: u32) -> Camera {
        let bounds = mesh
            .bounds()
            .map(|(lo, hi)| (lo.map(f64::from), hi.map(f64::from)));
        self.camera
            .camera(bounds, f64::from(width) / f64::from(height))
    }
}
