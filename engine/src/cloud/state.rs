//! A cloud scene version's parameters (SPEC §3 "Editing": κ, sun direction, sun colour I_l,
//! ambient) and the per-voxel ambient field I_m that the ambient edit (§3.2) produces.
//!
//! `CloudState` is what `state.json` holds; the ambient field is stored beside it as a blob
//! ([`AmbientField::to_bytes`]). Colours are linear RGB; the background is an sRGB hex colour
//! because it is what the user picks on screen.

use serde::{Deserialize, Serialize};

use super::floor::{self, FloorChoice};
use super::kappa::{self, KappaChoice};
use super::multiple::Scattering;
use super::sun::{self, SunChoice};
use crate::geom::sun_direction as sun_from_angles;
use crate::geom::Volume;
use crate::params::{range, Color};
use crate::{InputError, ParamError};

/// The parameters of the rendering equation (paper Eqs. 1–3) for one version of a cloud scene.
///
/// Serialised by [`StateOut`] (`sun_direction` left out while the sun is open, so that the
/// canonical parameters keep it open), deserialised by [`CloudState::from_json`]'s rules.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(try_from = "WireState")]
pub struct CloudState {
    /// Extinction κ per unit density per world unit (the box's longest side is 1 world unit by
    /// default), 0–10,000. Default null: chosen from the volume so that the median optical depth
    /// through the cloud along the sun and view rays is 4 ([`super::kappa`]); the chosen value
    /// is written here and the rule in `kappa_auto`. An explicit κ wins.
    pub kappa: Option<f64>,
    /// How κ was chosen when it was chosen from the volume ([`KappaChoice`]: the rule, the
    /// optical depth aimed at, the median column density, the rays); null when κ was given.
    /// Informational: carried with `kappa`, dropped when κ is given anew. Default null.
    pub kappa_auto: Option<KappaChoice>,
    /// Density floor taken out of every voxel before rendering (ρ ← max(0, ρ − floor)), in the
    /// volume's own density units, ≥ 0; 0 = none. Default null (left out): chosen from the
    /// volume ([`super::floor`]): a scan's noisy background (the level on the box's faces, if
    /// well below the object) is taken out, an empty background or a crop gives 0; the chosen
    /// value is written here and the rule in `density_floor_auto`. An explicit value wins.
    pub density_floor: Option<f64>,
    /// How the floor was chosen when it was chosen from the volume ([`FloorChoice`]: the rule,
    /// the faces' median and spread, Otsu's threshold, the object's mean); informational, carried
    /// with `density_floor`, dropped when the floor is given anew. Default null (left out).
    pub density_floor_auto: Option<FloorChoice>,
    /// Unit vector toward the sun, world frame (X east, Y up, Z south). Default (left out):
    /// chosen from the volume ([`super::sun`]): azimuth 150°, elevation 35°, turned toward a
    /// slab's plane to 10° above it when the cloud is a slab; the chosen value is written here
    /// and the rule in `sun_auto` (`sun_azimuth_deg`/`sun_elevation_deg` are accepted on the
    /// wire instead). An explicit sun wins.
    pub sun_direction: [f64; 3],
    /// True while the sun is left open: `sun_direction` then holds the default (azimuth 150°,
    /// elevation 35°) until [`CloudState::resolved`] chooses it from the volume. Not on the wire
    /// (an open sun is a state without `sun_direction`).
    pub sun_open: bool,
    /// How the sun was chosen when it was chosen from the volume ([`SunChoice`]); informational,
    /// carried with `sun_direction`, dropped when the sun is given anew. Default null (left out).
    pub sun_auto: Option<SunChoice>,
    /// Sun colour I_l, linear RGB, each 0–100. Default `[1.0, 0.97, 0.92]` (warm white).
    pub sun_color: [f64; 3],
    /// Uniform ambient I_m, linear RGB, each 0–100, used wherever no ambient field exists.
    /// Default `[0.25, 0.30, 0.40]` (blue sky light).
    pub ambient: [f64; 3],
    /// The user coefficient on the propagated ambient field (§3.2), 0–100. Multiplies the field
    /// only, not the uniform `ambient`. Default 1.
    pub ambient_scale: f64,
    /// Henyey–Greenstein asymmetry g of the sun term, −0.99–0.99; 0 = isotropic (the paper).
    /// Default 0.
    pub anisotropy: f64,
    /// Background colour `#rrggbb` (sRGB, lower case) to composite over; `null` keeps
    /// transparent sky. Default null.
    pub background: Option<Color>,
    /// Ray-march step in voxels (of the smallest voxel edge), 0.1–4. Default 1: one trilinear
    /// sample per voxel crossed; against the brute-force integrator (test
    /// `cloud::renderer_matches_a_brute_force_integrator`) it stays within 1 % RMS, and it
    /// halves the samples of the former default 0.5.
    pub step: f64,
    /// `single` (paper Eq. 1: the sun scattered once, plus the ambient) or `multiple` (plus
    /// the light scattered more than once, [`super::multiple`]). Default `single`: the look,
    /// speed and stored versions of existing scenes stay as they were, and a multiple-scattering
    /// render of the same state is up to several times brighter (its sun colour means
    /// something else); choose `multiple` for thick, bright clouds.
    pub scattering: Scattering,
    /// Single-scattering albedo α = σ_s/σ_t, 0–1: the share of extinction that is scattering
    /// (the rest is absorbed). Scales the sun term and the multiple-scattering term, not the
    /// painted ambient. Default 1 (cloud droplets absorb almost nothing in the visible; the
    /// paper's model).
    pub albedo: f64,
}

/// The default sun before the volume is seen: azimuth 150°, elevation 35°.
pub const DEFAULT_SUN: [f64; 3] = [0.40957602214449584, 0.573576436351046, 0.7094064799162225];

/// The serialised form of a [`CloudState`]: its fields in order, `sun_direction` left out while
/// the sun is open, the `*_auto` statements and the floor only when present.
#[derive(Serialize)]
struct StateOut<'a> {
    kappa: &'a Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    kappa_auto: Option<&'a KappaChoice>,
    #[serde(skip_serializing_if = "Option::is_none")]
    density_floor: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    density_floor_auto: Option<&'a FloorChoice>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sun_direction: Option<&'a [f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sun_auto: Option<&'a SunChoice>,
    sun_color: &'a [f64; 3],
    ambient: &'a [f64; 3],
    ambient_scale: f64,
    anisotropy: f64,
    background: &'a Option<Color>,
    step: f64,
    scattering: Scattering,
    albedo: f64,
}

impl Serialize for CloudState {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        StateOut {
            kappa: &self.kappa,
            kappa_auto: self.kappa_auto.as_ref(),
            density_floor: self.density_floor,
            density_floor_auto: self.density_floor_auto.as_ref(),
            sun_direction: (!self.sun_open).then_some(&self.sun_direction),
            sun_auto: self.sun_auto.as_ref(),
            sun_color: &self.sun_color,
            ambient: &self.ambient,
            ambient_scale: self.ambient_scale,
            anisotropy: self.anisotropy,
            background: &self.background,
            step: self.step,
            scattering: self.scattering,
            albedo: self.albedo,
        }
        .serialize(s)
    }
}

impl TryFrom<WireState> for CloudState {
    type Error = String;
    fn try_from(w: WireState) -> Result<Self, String> {
        Self::from_wire(w).map_err(|e| format!("{}: {}", e.field, e.detail))
    }
}

impl Default for CloudState {
    fn default() -> Self {
        Self {
            kappa: None,
            kappa_auto: None,
            density_floor: None,
            density_floor_auto: None,
            sun_direction: DEFAULT_SUN,
            sun_open: true,
            sun_auto: None,
            sun_color: [1.0, 0.97, 0.92],
            ambient: [0.25, 0.30, 0.40],
            ambient_scale: 1.0,
            anisotropy: 0.0,
            background: None,
            step: 1.0,
            scattering: Scattering::Single,
            albedo: 1.0,
        }
    }
}

/// Wire form: every field optional; the sun may be given as angles instead of a vector.
#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct WireState {
    pub kappa: Option<f64>,
    pub kappa_auto: Option<KappaChoice>,
    pub density_floor: Option<f64>,
    pub density_floor_auto: Option<FloorChoice>,
    pub sun_direction: Option<[f64; 3]>,
    pub sun_auto: Option<SunChoice>,
    pub sun_azimuth_deg: Option<f64>,
    pub sun_elevation_deg: Option<f64>,
    pub sun_color: Option<[f64; 3]>,
    pub ambient: Option<[f64; 3]>,
    pub ambient_scale: Option<f64>,
    pub anisotropy: Option<f64>,
    pub background: Option<String>,
    pub step: Option<f64>,
    pub scattering: Option<Scattering>,
    pub albedo: Option<f64>,
}

/// The wire names [`CloudState::from_json`] accepts (the one-shot pipeline splits its
/// parameters on these).
pub(crate) const STATE_FIELDS: &[&str] = &[
    "kappa",
    "kappa_auto",
    "density_floor",
    "density_floor_auto",
    "sun_direction",
    "sun_auto",
    "sun_azimuth_deg",
    "sun_elevation_deg",
    "sun_color",
    "ambient",
    "ambient_scale",
    "anisotropy",
    "background",
    "step",
    "scattering",
    "albedo",
];

fn color3(field: &str, v: Option<[f64; 3]>, d: [f64; 3]) -> Result<[f64; 3], ParamError> {
    let c = v.unwrap_or(d);
    for (i, x) in c.iter().enumerate() {
        range(&format!("{field}[{i}]"), Some(*x), 0.0, 0.0, 100.0)?;
    }
    Ok(c)
}

impl CloudState {
    /// Validates partial wire JSON: missing fields take the defaults, unknown names, NaN and
    /// out-of-range values are errors naming the field. `sun_direction` is normalised; it may be
    /// replaced by `sun_azimuth_deg` (compass, 0–360) and `sun_elevation_deg` (−90–90), both
    /// required together and not mixed with `sun_direction`.
    pub fn from_json(v: &serde_json::Value) -> Result<Self, ParamError> {
        let w: WireState = crate::params::deserialize_params(v)?;
        Self::from_wire(w)
    }

    pub(crate) fn from_wire(w: WireState) -> Result<Self, ParamError> {
        let d = Self::default();
        let sun_open = w.sun_direction.is_none()
            && w.sun_azimuth_deg.is_none()
            && w.sun_elevation_deg.is_none();
        let sun_direction = match (w.sun_direction, w.sun_azimuth_deg, w.sun_elevation_deg) {
            (Some(s), None, None) => crate::params::unit_vector("sun_direction", s)?,
            (None, None, None) => d.sun_direction,
            (None, Some(az), Some(el)) => {
                let az = range("sun_azimuth_deg", Some(az), 0.0, 0.0, 360.0)?;
                let el = range("sun_elevation_deg", Some(el), 0.0, -90.0, 90.0)?;
                sun_from_angles(az, el)
            }
            (Some(_), _, _) => {
                return Err(ParamError::new(
                    "sun_direction",
                    "give either sun_direction or sun_azimuth_deg/sun_elevation_deg, not both",
                ))
            }
            (None, None, Some(_)) => {
                return Err(ParamError::new(
                    "sun_azimuth_deg",
                    "required with sun_elevation_deg",
                ))
            }
            (None, Some(_), None) => {
                return Err(ParamError::new(
                    "sun_elevation_deg",
                    "required with sun_azimuth_deg",
                ))
            }
        };
        let background = match w.background {
            Some(s) => Some(Color::parse("background", &s)?.lowercase()),
            None => None,
        };
        let kappa = match w.kappa {
            Some(k) => Some(range("kappa", Some(k), k, 0.0, 10_000.0)?),
            None => None,
        };
        let density_floor = match w.density_floor {
            Some(f) => Some(range("density_floor", Some(f), f, 0.0, 1e30)?),
            None => None,
        };
        Ok(Self {
            kappa,
            // A statement about a κ that was chosen: meaningless without that κ.
            kappa_auto: w.kappa_auto.filter(|_| kappa.is_some()),
            density_floor,
            density_floor_auto: w.density_floor_auto.filter(|_| density_floor.is_some()),
            sun_direction,
            sun_open,
            // A statement about a sun that was chosen: meaningless without that sun.
            sun_auto: w.sun_auto.filter(|_| !sun_open),
            sun_color: color3("sun_color", w.sun_color, d.sun_color)?,
            ambient: color3("ambient", w.ambient, d.ambient)?,
            ambient_scale: range(
                "ambient_scale",
                w.ambient_scale,
                d.ambient_scale,
                0.0,
                100.0,
            )?,
            anisotropy: range("anisotropy", w.anisotropy, d.anisotropy, -0.99, 0.99)?,
            background,
            step: range("step", w.step, d.step, 0.1, 4.0)?,
            scattering: w.scattering.unwrap_or_default(),
            albedo: range("albedo", w.albedo, d.albedo, 0.0, 1.0)?,
        })
    }

    /// Takes the density floor out of `volume` (chosen from it when the state leaves it open,
    /// [`super::floor`]) and returns the state with the floor resolved and, when chosen, the
    /// choice stated. Call once, on the decoded volume, before κ is chosen or anything rendered.
    pub fn with_floor_applied(&self, volume: &mut Volume) -> Self {
        let (f, choice) = match self.density_floor {
            Some(f) => (f, self.density_floor_auto.clone()),
            None => {
                let (f, c) = floor::choose(volume);
                (f, Some(c))
            }
        };
        floor::apply(volume, f);
        Self {
            density_floor: Some(f),
            density_floor_auto: choice,
            ..self.clone()
        }
    }

    /// κ, chosen from `volume` when the state leaves it open ([`super::kappa::choose`], along
    /// the sun [`CloudState::resolved`] gives).
    pub fn kappa_for(&self, volume: &Volume) -> f64 {
        match self.kappa {
            Some(k) => k,
            None => kappa::choose(volume, self.sun_for(volume).0).0,
        }
    }

    /// The sun, chosen from `volume` when the state leaves it open ([`super::sun::choose`]),
    /// and the statement of that choice.
    fn sun_for(&self, volume: &Volume) -> ([f64; 3], Option<SunChoice>) {
        if self.sun_open {
            let (d, c) = sun::choose(volume, self.sun_direction);
            (d, Some(c))
        } else {
            (self.sun_direction, self.sun_auto.clone())
        }
    }

    /// The state with the sun and κ resolved: each unchanged when given, else chosen from
    /// `volume` (the sun first, κ along it) and the choice stated in `sun_auto` / `kappa_auto`.
    pub fn resolved(&self, volume: &Volume) -> Self {
        if self.kappa.is_some() && !self.sun_open {
            return self.clone();
        }
        let (sun_direction, sun_auto) = self.sun_for(volume);
        let s = Self {
            sun_direction,
            sun_open: false,
            sun_auto,
            ..self.clone()
        };
        if s.kappa.is_some() {
            return s;
        }
        let (k, choice) = kappa::choose(volume, s.sun_direction);
        Self {
            kappa: Some(k),
            kappa_auto: Some(choice),
            ..s
        }
    }

    /// The background as sRGB bytes (`None` if absent).
    pub fn background_srgb(&self) -> Option<[u8; 3]> {
        self.background.as_ref().map(Color::srgb8)
    }

    /// `state.json`: pretty JSON of the resolved state.
    pub fn to_json_bytes(&self) -> Vec<u8> {
        // Plain numbers and strings: serialisation cannot fail.
        serde_json::to_vec_pretty(self).unwrap_or_default()
    }
}

/// The per-voxel ambient colour I_m (SPEC §3.2): linear RGB, one entry per voxel in the
/// volume's layout (x fastest). Produced by the ambient edit; the renderer multiplies it by
/// [`CloudState::ambient_scale`].
#[derive(Debug, Clone, PartialEq)]
pub struct AmbientField {
    pub rgb: Vec<[f32; 3]>,
}

/// `PHAMB1\0\0` — the blob's magic.
const AMBIENT_MAGIC: &[u8; 8] = b"PHAMB1\0\0";

impl AmbientField {
    /// The blob: 8-byte magic `PHAMB1\0\0`, the voxel count as little-endian u64, then
    /// `3 × count` little-endian f32 (r, g, b per voxel). Allocates `16 + 12·count` bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(16 + 12 * self.rgb.len());
        out.extend_from_slice(AMBIENT_MAGIC);
        out.extend_from_slice(&(self.rgb.len() as u64).to_le_bytes());
        for c in &self.rgb {
            for v in c {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }

    /// Reads a blob written by [`AmbientField::to_bytes`] for a volume of `voxels` voxels;
    /// refuses a wrong magic, a count that differs from `voxels`, a wrong length and non-finite
    /// or negative values.
    pub fn from_bytes(bytes: &[u8], voxels: usize) -> Result<Self, InputError> {
        let corrupt = |detail: String| InputError::Corrupt {
            format: "ambient field",
            detail,
        };
        if bytes.len() < 16 || &bytes[..8] != AMBIENT_MAGIC {
            return Err(corrupt("missing the PHAMB1 header".into()));
        }
        let mut n8 = [0u8; 8];
        n8.copy_from_slice(&bytes[8..16]);
        let count = u64::from_le_bytes(n8);
        if count != voxels as u64 {
            return Err(InputError::Unusable(format!(
                "the ambient field holds {count} voxels, the volume has {voxels}"
            )));
        }
        let want = (voxels as u64)
            .checked_mul(12)
            .and_then(|b| b.checked_add(16))
            .ok_or_else(|| corrupt("voxel count overflows".into()))?;
        if bytes.len() as u64 != want {
            return Err(corrupt(format!(
                "{} bytes, {voxels} voxels need {want}",
                bytes.len()
            )));
        }
        let mut rgb = Vec::with_capacity(voxels);
        for (i, ch) in bytes[16..].chunks_exact(12).enumerate() {
            let f = |k: usize| f32::from_le_bytes([ch[k], ch[k + 1], ch[k + 2], ch[k + 3]]);
            let c = [f(0), f(4), f(8)];
            if c.iter().any(|v| !v.is_finite() || *v < 0.0) {
                return Err(corrupt(format!("voxel {i} has colour {c:?}")));
            }
            rgb.push(c);
        }
        Ok(Self { rgb })
    }

    /// A field of one colour.
    pub fn uniform(voxels: usize, c: [f32; 3]) -> Self {
        Self {
            rgb: vec![c; voxels],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn state_defaults_round_trip_and_errors() {
        let s = CloudState::from_json(&json!({})).unwrap();
        assert_eq!(s, CloudState::default());
        assert_eq!(DEFAULT_SUN, sun_from_angles(150.0, 35.0));
        assert!(s.sun_open);
        // An open sun stays open through the wire form; a given one is given.
        assert!(serde_json::to_value(&s)
            .unwrap()
            .get("sun_direction")
            .is_none());
        let given = CloudState::from_json(&json!({"sun_direction": DEFAULT_SUN})).unwrap();
        assert!(!given.sun_open);
        let v = serde_json::to_value(&given).unwrap();
        assert_eq!(CloudState::from_json(&v).unwrap(), given);
        let back = CloudState::from_json(&serde_json::to_value(&s).unwrap()).unwrap();
        assert_eq!(back, s);
        for (v, field) in [
            (json!({"kappa": -1}), "kappa"),
            (json!({"kapa": 1}), "kapa"),
            (json!({"sun_direction": [0, 0, 0]}), "sun_direction"),
            (json!({"sun_color": [1, -1, 0]}), "sun_color[1]"),
            (json!({"anisotropy": 1.0}), "anisotropy"),
            (json!({"background": "red"}), "background"),
            (json!({"sun_azimuth_deg": 10}), "sun_elevation_deg"),
            (json!({"albedo": 1.5}), "albedo"),
            (json!({"scattering": "double"}), "scattering"),
        ] {
            assert_eq!(CloudState::from_json(&v).unwrap_err().field, field, "{v}");
        }
        let a =
            CloudState::from_json(&json!({"sun_azimuth_deg": 90, "sun_elevation_deg": 0})).unwrap();
        assert!((a.sun_direction[0] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ambient_blob_round_trip_and_refusals() {
        let f = AmbientField {
            rgb: vec![[0.1, 0.2, 0.3], [1.0, 0.0, 2.5]],
        };
        let b = f.to_bytes();
        assert_eq!(AmbientField::from_bytes(&b, 2).unwrap(), f);
        assert!(AmbientField::from_bytes(&b, 3).is_err());
        assert!(AmbientField::from_bytes(&b[..b.len() - 1], 2).is_err());
        assert!(AmbientField::from_bytes(b"nonsense", 2).is_err());
    }
}
