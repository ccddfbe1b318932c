//! Parameters of the `snow-terrain` pipeline: the wire form (JSON, unknown names rejected) and the
//! validated form the pipeline runs on. Names follow SPEC §1; every field says its unit, range and
//! default.

use std::collections::BTreeSet;

use serde::{Deserialize, Serialize};

use super::descriptor::DescriptorParams;
use crate::params::Limits;
use crate::params::{camera_spec, image_size, range, CameraSpec, Color, OrbitDefaults, WireCamera};
use crate::ParamError;

/// A parameter sweep: the same DEM rendered once per value of one parameter, laid out as a
/// labelled contact sheet (`sweep.png`), like the paper's Figs. 11–12.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Sweep {
    /// Name of a numeric parameter (`probe_radius`, `b`, `smooth_radius`, …).
    pub param: String,
    /// 2–12 values.
    pub values: Vec<f64>,
}

/// Wire parameters (all optional; unknown names are rejected).
#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WireParams {
    pub preset: Option<String>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub camera: Option<WireCamera>,
    pub seed: Option<u64>,
    pub smooth_radius: Option<usize>,
    pub smooth_iterations: Option<usize>,
    pub smooth_length: Option<f32>,
    pub tsa_window: Option<usize>,
    pub tsa_max: Option<f32>,
    pub probe_radius: Option<f32>,
    pub b: Option<f32>,
    pub swept_snow: Option<f32>,
    pub vertical_exaggeration: Option<f32>,
    pub snowline: Option<f32>,
    pub snowline_quantile: Option<f32>,
    pub snow_band: Option<f32>,
    pub full_snow_quantile: Option<f32>,
    pub sea_level: Option<f32>,
    pub altitude_exponent: Option<f32>,
    pub descriptor_smooth_iterations: Option<usize>,
    pub sun_azimuth_deg: Option<f32>,
    pub sun_spread_deg: Option<f32>,
    pub sun_min_slope_deg: Option<f32>,
    pub sun_strength: Option<f32>,
    pub slope_start_deg: Option<f32>,
    pub slope_end_deg: Option<f32>,
    pub sun_elevation_deg: Option<f64>,
    pub rock_color: Option<String>,
    pub snow_color: Option<String>,
    pub sea_color: Option<String>,
    pub shading: Option<bool>,
    pub shadows: Option<bool>,
    pub ambient: Option<f32>,
    pub haze: Option<f32>,
    pub samples: Option<u32>,
    pub mesh_max_vertices: Option<usize>,
    pub cell_size: Option<f64>,
    pub vertical_scale: Option<f64>,
    pub sweep: Option<Sweep>,
    pub outputs: Option<Vec<String>>,
    // View (issue 17): see `View`.
    pub ambient_occlusion: Option<f32>,
    pub sky_tint: Option<f32>,
    pub auto_exaggeration: Option<bool>,
}

/// A file a run can produce besides `report.json` (always) and `sweep.png` (with `sweep`); the
/// order of the variants is the order of the outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub enum TerrainOutput {
    /// `render.png`: the 3-D view (SPEC §1 "Rendering").
    #[serde(rename = "render.png")]
    Render,
    /// `snow_cover.tif`: the descriptor as a float GeoTIFF.
    #[serde(rename = "snow_cover.tif")]
    SnowCover,
    /// `descriptor.png`: the descriptor as a grey preview.
    #[serde(rename = "descriptor.png")]
    Descriptor,
    /// `terrain.glb`: the snowy terrain as a glTF mesh.
    #[serde(rename = "terrain.glb")]
    Glb,
}

impl TerrainOutput {
    /// Every output, in output order.
    pub const ALL: [TerrainOutput; 4] = [
        TerrainOutput::Render,
        TerrainOutput::SnowCover,
        TerrainOutput::Descriptor,
        TerrainOutput::Glb,
    ];

    /// The output's file name.
    pub fn name(self) -> &'static str {
        match self {
            TerrainOutput::Render => "render.png",
            TerrainOutput::SnowCover => "snow_cover.tif",
            TerrainOutput::Descriptor => "descriptor.png",
            TerrainOutput::Glb => "terrain.glb",
        }
    }

    /// The output named `name`, if any.
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|o| o.name() == name)
    }
}

/// The files a run can produce besides `report.json` (always) and `sweep.png` (with `sweep`).
pub const OUTPUT_NAMES: &[&str] = &[
    "render.png",
    "snow_cover.tif",
    "descriptor.png",
    "terrain.glb",
];

/// The default rock colour (`rock_color`).
pub const DEFAULT_ROCK_COLOR: &str = "#6e665c";
/// The default snow colour (`snow_color`).
pub const DEFAULT_SNOW_COLOR: &str = "#f4f7fb";
/// The default sea colour (`sea_color`, when `sea_level` is set).
pub const DEFAULT_SEA_COLOR: &str = "#2a4a63";

/// The named parameter sets (`preset`).
pub const PRESETS: &[&str] = &["winter", "paper"];

/// Validated parameters of one `snow-terrain` run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SnowTerrainParams {
    /// Named starting values of the descriptor, one of [`PRESETS`]; parameters given explicitly
    /// override the preset's. `"winter"`: [`DescriptorParams::default`], snow on the upper part
    /// of any DEM (issue 17). `"paper"`: [`DescriptorParams::paper`], the paper's literal
    /// settings (snowline 0 m, quadratic to the summit, open ground bare, full sun correction,
    /// no slope term, cell-based smoothing) — byte-identical to the outputs before the winter
    /// default. Default: `"winter"`.
    pub preset: String,
    /// Output image width, pixels, 16–8192. Default 900 (the paper's figures).
    pub width: u32,
    /// Output image height, pixels, 16–8192. Default 600.
    pub height: u32,
    pub camera: CameraSpec,
    /// Accepted for API uniformity; this pipeline has no randomness. Default 0.
    pub seed: u64,
    /// Descriptor stages 1–6 (see [`DescriptorParams`]).
    #[serde(flatten)]
    pub descriptor: DescriptorParams,
    /// Sun elevation above the horizon for shading and shadows, degrees, 1–90. The sun's azimuth
    /// is `sun_azimuth_deg`, the same as the descriptor's sun correction. Default 35.
    pub sun_elevation_deg: f64,
    /// Bare-rock colour, sRGB hex. Default `#6e665c`.
    pub rock_color: Color,
    /// Snow colour, sRGB hex. Default `#f4f7fb`.
    pub snow_color: Color,
    /// Colour of the sea: grid points at or below `sea_level` (which hold no snow) are drawn in
    /// it instead of `rock_color` (or the orthophoto), so a coast reads as a coast and not as a
    /// grey rock plain. sRGB hex. Default `#2a4a63`; there is no sea (and no sea colour) when
    /// `sea_level` is unset, as under the `paper` preset.
    pub sea_color: Option<Color>,
    /// Lambert shading from the sun plus sky ambient; false draws flat colours like the paper.
    /// Default true.
    pub shading: bool,
    /// Cast shadows. Default true.
    pub shadows: bool,
    /// Sky ambient, fraction of albedo on flat ground, 0–1. Default 0.35.
    pub ambient: f32,
    /// Aerial perspective strength (SPEC §1 step 8), 0–1. Default 0.5.
    pub haze: f32,
    /// Anti-aliasing rays per pixel, 1–16. Default 4.
    pub samples: u32,
    /// Vertex budget of `terrain.glb`, 4–4194304. Default 262144.
    pub mesh_max_vertices: usize,
    /// Metres per cell for inputs without georeferencing (16-bit PNG, `.npy`). Default null.
    pub cell_size: Option<f64>,
    /// Metres per stored unit for 16-bit PNG and integer `.npy`. Default null (= 1).
    pub vertical_scale: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sweep: Option<Sweep>,
    /// Which of [`OUTPUT_NAMES`] to produce, in that order whatever the order given; `report.json`
    /// always comes too. A stage no requested output needs is skipped: without `render.png` there
    /// is no render (a GIS user asking for `snow_cover.tif` alone pays for the descriptor only),
    /// and an interactive preview asking for `render.png` alone skips the GeoTIFF, preview and
    /// glTF encoders. Default: all four.
    pub outputs: BTreeSet<TerrainOutput>,
    /// One validated parameter set per sweep value (derived from `sweep`).
    #[serde(skip)]
    pub sweep_runs: Vec<SnowTerrainParams>,
    /// How the terrain is shown (issue 17).
    #[serde(flatten)]
    pub view: View,
}

// ---- View (issue 17, the view half): preset-dependent shading, framing and exaggeration. ----

/// How the terrain is shown. Each field's default depends on `preset`; a value given wins.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct View {
    /// Ambient occlusion of the sky light, 0–1: the sky light is multiplied by `1 − w + w·SVF`,
    /// SVF the horizon-based sky-view factor of the rendered height field
    /// ([`crate::render::terrain::sky_view_factor`]), so hollows and valley floors are darker
    /// than ridges. Default 1 (`paper`: 0).
    pub ambient_occlusion: f32,
    /// How much the sky light and the haze take the sky's colour, 0–1: 1 gives shade on snow a
    /// cool blue (the clear sky lights it) and an aerial perspective that fades distant
    /// terrain toward the horizon sky; 0 is a neutral sky light and the paper's grey haze.
    /// Default 1 (`paper`: 0).
    pub sky_tint: f32,
    /// Choose the view's vertical exaggeration from the DEM when the relief is small against
    /// its extent: `e = clamp(0.08 / (relief / extent), 1, 8)` rounded to 0.1, relief = highest
    /// − lowest valid elevation, extent = the longer horizontal side, both in metres (a 150 km
    /// DEM with 3 km of relief is drawn ×4; a 10 km DEM with 1 km of relief ×1). The chosen
    /// value is in `report.json` (`view.vertical_exaggeration`). It applies to the render only
    /// (`render.png`, `sweep.png`): the descriptor and `terrain.glb` keep
    /// `vertical_exaggeration`. False: the view uses `vertical_exaggeration`. Default: true
    /// unless `vertical_exaggeration` is given (`paper`: false).
    pub auto_exaggeration: bool,
    /// Orbit cameras without a `distance` frame the terrain's own grid points (centred on their
    /// projection, within 95 % of the frame) instead of its bounding box, so the terrain fills
    /// the image. Not a parameter: true unless the preset is `paper`.
    #[serde(skip)]
    pub fill_frame: bool,
    /// Samples whose pixel spans several cells are shaded from the albedo, heights and sun
    /// visibility box-averaged to the pixel's footprint (mipmapping;
    /// [`crate::render::terrain::Lighting::texture_lod`]), so a big DEM drawn small shows its
    /// snow pattern filtered instead of aliased, with far fewer anti-aliasing rays. Not a
    /// parameter: true unless the preset is `paper` (the paper's figures point-sample).
    #[serde(skip)]
    pub texture_lod: bool,
}

impl View {
    /// The view of `preset` (already validated by [`SnowTerrainParams`]): `paper` is the look of the
    /// paper's figures and of this pipeline before issue 17 (flat sky light, grey haze, the
    /// bounding-box camera, exaggeration 1 unless given).
    fn from_wire(w: &WireParams, preset: &str) -> Result<Self, ParamError> {
        let paper = preset == "paper";
        let on = if paper { 0.0 } else { 1.0 };
        Ok(View {
            ambient_occlusion: range("ambient_occlusion", w.ambient_occlusion, on, 0.0, 1.0)?,
            sky_tint: range("sky_tint", w.sky_tint, on, 0.0, 1.0)?,
            auto_exaggeration: w
                .auto_exaggeration
                .unwrap_or(!paper && w.vertical_exaggeration.is_none()),
            fill_frame: !paper,
            texture_lod: !paper,
        })
    }
}

/// Parameters a sweep may vary.
pub const SWEEPABLE: &[&str] = &[
    "probe_radius",
    "b",
    "swept_snow",
    "snowline_quantile",
    "snow_band",
    "full_snow_quantile",
    "sea_level",
    "smooth_length",
    "sun_strength",
    "slope_start_deg",
    "slope_end_deg",
    "smooth_radius",
    "smooth_iterations",
    "tsa_window",
    "vertical_exaggeration",
    "snowline",
    "altitude_exponent",
    "descriptor_smooth_iterations",
    "sun_azimuth_deg",
    "sun_spread_deg",
    "sun_min_slope_deg",
    "haze",
    "ambient_occlusion",
    "sky_tint",
];

/// Validates `outputs`: known names, no repeats; the set of them (all four when not given).
fn output_set(given: Option<&[String]>) -> Result<BTreeSet<TerrainOutput>, ParamError> {
    let Some(given) = given else {
        return Ok(TerrainOutput::ALL.into_iter().collect());
    };
    let mut set = BTreeSet::new();
    for (i, name) in given.iter().enumerate() {
        let Some(output) = TerrainOutput::parse(name) else {
            return Err(ParamError::new(
                format!("outputs[{i}]"),
                format!("no output {name:?}; one of: {}", OUTPUT_NAMES.join(", ")),
            ));
        };
        if !set.insert(output) {
            return Err(ParamError::new(
                format!("outputs[{i}]"),
                format!("{name:?} is listed twice"),
            ));
        }
    }
    Ok(set)
}

impl SnowTerrainParams {
    /// `rock_color` in linear RGB (the fallback where an orthophoto has no pixels).
    pub fn rock_linear(&self) -> [f32; 3] {
        self.rock_color
            .srgb8()
            .map(crate::render::image::srgb8_to_linear)
    }

    /// Whether `output` was asked for.
    pub fn wants(&self, output: TerrainOutput) -> bool {
        self.outputs.contains(&output)
    }

    /// Validates wire JSON: unknown names, wrong types and out-of-range values are errors naming
    /// the field.
    pub fn from_json(v: &serde_json::Value, limits: &Limits) -> Result<Self, ParamError> {
        let wire: WireParams = crate::params::deserialize_params(v)?;
        let mut p = Self::from_wire(&wire, limits)?;
        if let Some(sweep) = &wire.sweep {
            if !SWEEPABLE.contains(&sweep.param.as_str()) {
                return Err(ParamError::new(
                    "sweep.param",
                    format!(
                        "cannot sweep {:?}; one of: {}",
                        sweep.param,
                        SWEEPABLE.join(", ")
                    ),
                ));
            }
            if !(2..=12).contains(&sweep.values.len()) {
                return Err(ParamError::new("sweep.values", "give 2 to 12 values"));
            }
            let mut runs = Vec::with_capacity(sweep.values.len());
            for (i, value) in sweep.values.iter().enumerate() {
                let mut obj = v.clone();
                if let Some(m) = obj.as_object_mut() {
                    m.remove("sweep");
                    // An integral value goes in as an integer, so that integer parameters
                    // (`smooth_iterations`, `tsa_window`, …) can be swept too.
                    let value = if value.fract() == 0.0 && value.abs() < 9.0e15 {
                        serde_json::json!(*value as i64)
                    } else {
                        serde_json::json!(value)
                    };
                    m.insert(sweep.param.clone(), value);
                }
                let w: WireParams = crate::params::deserialize_params(&obj)
                    .map_err(|e| ParamError::new(format!("sweep.values[{i}]"), e.detail))?;
                runs.push(
                    Self::from_wire(&w, limits).map_err(|e| {
                        ParamError::new(format!("sweep.values[{i}]"), e.to_string())
                    })?,
                );
            }
            p.sweep = Some(sweep.clone());
            p.sweep_runs = runs;
        }
        Ok(p)
    }

    fn from_wire(w: &WireParams, limits: &Limits) -> Result<Self, ParamError> {
        let (width, height) = image_size(w.width, w.height, (900, 600), limits)?;
        let camera = camera_spec(
            w.camera.clone().unwrap_or_default(),
            OrbitDefaults {
                azimuth_deg: 200.0,
                elevation_deg: 30.0,
                fov_deg: 40.0,
            },
        )?;
        let preset = w.preset.clone().unwrap_or_else(|| "winter".into());
        let d = match preset.as_str() {
            "winter" => DescriptorParams::default(),
            "paper" => DescriptorParams::paper(),
            other => {
                return Err(ParamError::new(
                    "preset",
                    format!("no preset {other:?}; one of: {}", PRESETS.join(", ")),
                ))
            }
        };
        // An Option field of the preset: the given value (validated) or the preset's.
        fn opt<T: PartialOrd + std::fmt::Display + Copy>(
            name: &str,
            given: Option<T>,
            preset: Option<T>,
            lo: T,
            hi: T,
        ) -> Result<Option<T>, ParamError> {
            match given {
                Some(v) => range(name, Some(v), v, lo, hi).map(Some),
                None => Ok(preset),
            }
        }
        let descriptor = DescriptorParams {
            smooth_radius: opt("smooth_radius", w.smooth_radius, d.smooth_radius, 1, 16)?,
            smooth_iterations: opt(
                "smooth_iterations",
                w.smooth_iterations,
                d.smooth_iterations,
                0,
                50,
            )?,
            smooth_length: range(
                "smooth_length",
                w.smooth_length,
                d.smooth_length,
                0.001,
                100_000.0,
            )?,
            tsa_window: range("tsa_window", w.tsa_window, d.tsa_window, 1, 16)?,
            tsa_max: range("tsa_max", w.tsa_max, d.tsa_max, 1.0, 1.0e7)?,
            probe_radius: range("probe_radius", w.probe_radius, d.probe_radius, 0.001, 1.0e7)?,
            b: range("b", w.b, d.b, 0.0, 1.0)?,
            swept_snow: range("swept_snow", w.swept_snow, d.swept_snow, 0.0, 1.0)?,
            vertical_exaggeration: range(
                "vertical_exaggeration",
                w.vertical_exaggeration,
                d.vertical_exaggeration,
                0.01,
                100.0,
            )?,
            snowline: opt("snowline", w.snowline, d.snowline, -11_000.0, 9000.0)?,
            snowline_quantile: range(
                "snowline_quantile",
                w.snowline_quantile,
                d.snowline_quantile,
                0.0,
                1.0,
            )?,
            snow_band: opt("snow_band", w.snow_band, d.snow_band, 0.001, 20_000.0)?,
            full_snow_quantile: range(
                "full_snow_quantile",
                w.full_snow_quantile,
                d.full_snow_quantile,
                0.0,
                1.0,
            )?,
            sea_level: opt("sea_level", w.sea_level, d.sea_level, -11_000.0, 9000.0)?,
            altitude_exponent: range(
                "altitude_exponent",
                w.altitude_exponent,
                d.altitude_exponent,
                0.0,
                10.0,
            )?,
            descriptor_smooth_iterations: opt(
                "descriptor_smooth_iterations",
                w.descriptor_smooth_iterations,
                d.descriptor_smooth_iterations,
                0,
                50,
            )?,
            sun_azimuth_deg: opt(
                "sun_azimuth_deg",
                w.sun_azimuth_deg,
                d.sun_azimuth_deg,
                0.0,
                360.0,
            )?,
            sun_spread_deg: range(
                "sun_spread_deg",
                w.sun_spread_deg,
                d.sun_spread_deg,
                0.0,
                90.0,
            )?,
            sun_min_slope_deg: range(
                "sun_min_slope_deg",
                w.sun_min_slope_deg,
                d.sun_min_slope_deg,
                0.0,
                89.0,
            )?,
            sun_strength: range("sun_strength", w.sun_strength, d.sun_strength, 0.0, 1.0)?,
            slope_start_deg: range(
                "slope_start_deg",
                w.slope_start_deg,
                d.slope_start_deg,
                0.0,
                90.0,
            )?,
            slope_end_deg: range("slope_end_deg", w.slope_end_deg, d.slope_end_deg, 0.0, 90.0)?,
        };
        if descriptor.slope_end_deg < descriptor.slope_start_deg {
            // Name the one the caller gave (the end if both or neither).
            let field = if w.slope_start_deg.is_some() && w.slope_end_deg.is_none() {
                "slope_start_deg"
            } else {
                "slope_end_deg"
            };
            return Err(ParamError::new(
                field,
                format!(
                    "slope_end_deg ({}) must not be below slope_start_deg ({})",
                    descriptor.slope_end_deg, descriptor.slope_start_deg
                ),
            ));
        }
        if descriptor.full_snow_quantile < descriptor.snowline_quantile {
            let field = if w.snowline_quantile.is_some() && w.full_snow_quantile.is_none() {
                "snowline_quantile"
            } else {
                "full_snow_quantile"
            };
            return Err(ParamError::new(
                field,
                format!(
                    "full_snow_quantile ({}) must not be below snowline_quantile ({})",
                    descriptor.full_snow_quantile, descriptor.snowline_quantile
                ),
            ));
        }
        let color = |field: &str, given: &Option<String>, default: &str| {
            Color::parse(field, given.as_deref().unwrap_or(default))
        };
        let rock_color = color("rock_color", &w.rock_color, DEFAULT_ROCK_COLOR)?;
        let snow_color = color("snow_color", &w.snow_color, DEFAULT_SNOW_COLOR)?;
        let sea_color = match descriptor.sea_level {
            Some(_) => Some(color("sea_color", &w.sea_color, DEFAULT_SEA_COLOR)?),
            None => None,
        };
        let cell_size = match w.cell_size {
            Some(c) => Some(range("cell_size", Some(c), 1.0, 1e-6, 1e6)?),
            None => None,
        };
        let vertical_scale = match w.vertical_scale {
            Some(c) => Some(range("vertical_scale", Some(c), 1.0, 1e-9, 1e6)?),
            None => None,
        };
        let view = View::from_wire(w, &preset)?;
        Ok(SnowTerrainParams {
            preset,
            width,
            height,
            camera,
            seed: w.seed.unwrap_or(0),
            descriptor,
            sun_elevation_deg: range("sun_elevation_deg", w.sun_elevation_deg, 35.0, 1.0, 90.0)?,
            rock_color,
            snow_color,
            sea_color,
            shading: w.shading.unwrap_or(true),
            shadows: w.shadows.unwrap_or(true),
            ambient: range("ambient", w.ambient, 0.35, 0.0, 1.0)?,
            haze: range("haze", w.haze, 0.5, 0.0, 1.0)?,
            samples: range("samples", w.samples, 4, 1, 16)?,
            mesh_max_vertices: range(
                "mesh_max_vertices",
                w.mesh_max_vertices,
                262_144,
                4,
                4_194_304,
            )?,
            cell_size,
            vertical_scale,
            sweep: None,
            outputs: output_set(w.outputs.as_deref())?,
            sweep_runs: Vec::new(),
            view,
        })
    }
}
