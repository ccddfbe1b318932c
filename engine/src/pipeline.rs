//! The pipeline registry: names, parameter validation, input decoding and the run, for every
//! pipeline the service offers. The server and the CLI go through these functions only.

use crate::formats::dem::{decode_dem, DemOptions};
use crate::geom::Dem;
use crate::{snow_terrain, Canceled, Control, InputError, Output, ParamError};

/// Input and output size limits (configured by the server; the CLI uses the defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest input grid, cells. Checked from the file header before the grid is allocated.
    pub max_input_cells: u64,
    /// Largest output image, pixels.
    pub max_output_pixels: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_input_cells: 8192 * 8192,
            max_output_pixels: 7680 * 4320,
        }
    }
}

/// The pipelines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PipelineKind {
    /// Snow on terrain (SPEC §1).
    SnowTerrain,
}

impl PipelineKind {
    pub const ALL: &'static [PipelineKind] = &[PipelineKind::SnowTerrain];

    /// The API name (`snow-terrain`).
    pub fn name(self) -> &'static str {
        match self {
            PipelineKind::SnowTerrain => "snow-terrain",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|k| k.name() == name)
    }

    /// The multipart part that carries the input (`dem`, `mesh`, `volume`).
    pub fn input_part(self) -> &'static str {
        match self {
            PipelineKind::SnowTerrain => "dem",
        }
    }
}

/// Deserialises wire parameters, naming the offending field (`camera.fov_deg`) on error.
pub fn deserialize_params<T: serde::de::DeserializeOwned>(
    v: &serde_json::Value,
) -> Result<T, ParamError> {
    if !v.is_object() {
        return Err(ParamError::new("params", "must be a JSON object"));
    }
    serde_path_to_error::deserialize(v).map_err(|e| {
        // The path names the offending field itself, unknown names included (`camera.fovdeg`).
        let path = e.path().to_string();
        let field = if path == "." {
            "params".to_string()
        } else {
            path
        };
        let inner = e.into_inner().to_string();
        ParamError::new(field, inner)
    })
}

/// Validated parameters of one pipeline.
#[derive(Debug, Clone, PartialEq)]
pub enum Params {
    SnowTerrain(Box<snow_terrain::Params>),
}

impl Params {
    /// Validates wire JSON for `kind`.
    pub fn parse(
        kind: PipelineKind,
        v: &serde_json::Value,
        limits: &Limits,
    ) -> Result<Self, ParamError> {
        match kind {
            PipelineKind::SnowTerrain => Ok(Params::SnowTerrain(Box::new(
                snow_terrain::Params::from_json(v, limits)?,
            ))),
        }
    }

    /// The resolved parameters (defaults filled in) as JSON: the canonical form used for request
    /// keys and `report.json`. Parsing it again gives the same parameters.
    pub fn canonical(&self) -> serde_json::Value {
        let v = match self {
            Params::SnowTerrain(p) => serde_json::to_value(p),
        };
        // Serialising plain structs of numbers, strings and options cannot fail.
        v.unwrap_or(serde_json::Value::Null)
    }
}

/// A decoded input.
#[derive(Debug, Clone)]
pub enum Input {
    Dem(Dem),
}

/// Decodes `bytes` as the input of the pipeline `params` belongs to.
pub fn decode(
    params: &Params,
    bytes: &[u8],
    filename: Option<&str>,
    limits: &Limits,
) -> Result<Input, InputError> {
    match params {
        Params::SnowTerrain(p) => {
            let opts = DemOptions {
                max_cells: limits.max_input_cells,
                cell_size: p.cell_size,
                vertical_scale: p.vertical_scale,
            };
            Ok(Input::Dem(decode_dem(bytes, filename, &opts)?))
        }
    }
}

/// Runs the pipeline to its named outputs.
pub fn run(params: &Params, input: &Input, ctl: &dyn Control) -> Result<Vec<Output>, Canceled> {
    match (params, input) {
        (Params::SnowTerrain(p), Input::Dem(dem)) => snow_terrain::run(dem, p, ctl),
    }
}
