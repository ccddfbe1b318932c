//! The camera parameter every pipeline shares (SPEC §5): orbit fields or eye/target on the wire,
//! validated into a [`CameraSpec`] that places a [`Camera`] for a scene's bounds.

use serde::{Deserialize, Serialize};

use super::wire::range;
use crate::geom::camera::Camera;
use crate::ParamError;

/// How the camera is placed (SPEC §5, shared by every pipeline).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum CameraSpec {
    /// Orbit around the DEM's centre.
    Orbit {
        /// Compass direction from the centre to the camera, degrees: 0 = north (looking south),
        /// 180 = south (looking north). Default 200.
        azimuth_deg: f64,
        /// Angle above the horizon, degrees, -89–89. Default 30.
        elevation_deg: f64,
        /// Distance from the centre in metres; `null` frames the whole DEM. Default null.
        distance: Option<f64>,
        /// Vertical field of view, degrees, 1–150. Default 40.
        fov_deg: f64,
    },
    /// Explicit eye and target in the DEM's world frame (metres; X east, Y up, Z south, origin at
    /// the grid's horizontal centre and elevation 0).
    LookAt {
        eye: [f64; 3],
        target: [f64; 3],
        fov_deg: f64,
    },
}

/// Wire form of the camera: either orbit fields or eye/target.
#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WireCamera {
    pub azimuth_deg: Option<f64>,
    pub elevation_deg: Option<f64>,
    pub distance: Option<f64>,
    pub fov_deg: Option<f64>,
    pub eye: Option<[f64; 3]>,
    pub target: Option<[f64; 3]>,
}

fn finite3(field: &str, v: [f64; 3]) -> Result<[f64; 3], ParamError> {
    if v.iter().all(|x| x.is_finite() && x.abs() < 1e9) {
        Ok(v)
    } else {
        Err(ParamError::new(field, "must be three finite numbers"))
    }
}

/// A pipeline's default orbit (each pipeline picks the view that shows its phenomenon best).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbitDefaults {
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    pub fov_deg: f64,
}

/// Validates the camera: orbit fields or eye/target, not a mix; absent orbit fields take `d`.
pub fn camera_spec(c: WireCamera, d: OrbitDefaults) -> Result<CameraSpec, ParamError> {
    let fov_deg = range("camera.fov_deg", c.fov_deg, d.fov_deg, 1.0, 150.0)?;
    match (c.eye, c.target) {
        (Some(eye), Some(target)) => {
            if c.azimuth_deg.is_some() || c.elevation_deg.is_some() || c.distance.is_some() {
                return Err(ParamError::new(
                    "camera",
                    "give either eye/target or azimuth_deg/elevation_deg/distance, not both",
                ));
            }
            let eye = finite3("camera.eye", eye)?;
            let target = finite3("camera.target", target)?;
            if eye == target {
                return Err(ParamError::new(
                    "camera.target",
                    "must differ from camera.eye",
                ));
            }
            Ok(CameraSpec::LookAt {
                eye,
                target,
                fov_deg,
            })
        }
        (Some(_), None) => Err(ParamError::new("camera.target", "required with camera.eye")),
        (None, Some(_)) => Err(ParamError::new("camera.eye", "required with camera.target")),
        (None, None) => Ok(CameraSpec::Orbit {
            azimuth_deg: range(
                "camera.azimuth_deg",
                c.azimuth_deg,
                d.azimuth_deg,
                -360.0,
                360.0,
            )?,
            elevation_deg: range(
                "camera.elevation_deg",
                c.elevation_deg,
                d.elevation_deg,
                -89.0,
                89.0,
            )?,
            distance: match c.distance {
                Some(d) => Some(range("camera.distance", Some(d), 1.0, 1e-3, 1e9)?),
                None => None,
            },
            fov_deg,
        }),
    }
}

impl CameraSpec {
    /// The camera for a scene whose bounding box is `bounds` (world frame), rendered at `aspect`
    /// (width / height). An orbit without `distance` frames the box's 8 corners within 92 % of
    /// the image (far tighter than a bounding sphere for wide, flat scenes); with no bounds (an
    /// empty scene) it orbits the origin.
    pub fn camera(&self, bounds: Option<([f64; 3], [f64; 3])>, aspect: f64) -> Camera {
        match *self {
            CameraSpec::Orbit {
                azimuth_deg,
                elevation_deg,
                distance,
                fov_deg,
            } => match (distance, bounds) {
                (None, Some((lo, hi))) => {
                    Camera::frame_box(lo, hi, azimuth_deg, elevation_deg, fov_deg, aspect)
                }
                (d, b) => {
                    let center = b.map_or([0.0; 3], |(lo, hi)| {
                        [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]))
                    });
                    let d = d.unwrap_or_else(|| Camera::auto_distance(1.0, fov_deg));
                    Camera::orbit(center, azimuth_deg, elevation_deg, d, fov_deg)
                }
            },
            CameraSpec::LookAt {
                eye,
                target,
                fov_deg,
            } => Camera {
                eye,
                target,
                up: [0.0, 1.0, 0.0],
                fov_deg,
            },
        }
    }
}
