//! The pipeline registry: names, parameter validation, input decoding and the run, for every
//! pipeline the service offers. The server and the CLI go through these functions only.

use crate::formats::dem::{decode_dem, DemOptions};
use crate::geom::Dem;
use crate::geom::Mesh;
use crate::{snow_cover, snow_terrain, Canceled, Control, InputError, Output, ParamError};

/// Input and output size limits (configured by the server; the CLI uses the defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest input grid, cells. Checked from the file header before the grid is allocated.
    pub max_input_cells: u64,
    /// Largest output image, pixels.
    pub max_output_pixels: u64,
    /// Largest input mesh, triangles (vertices: 3×). Checked from the file's counts before the
    /// mesh is allocated.
    pub max_input_triangles: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_input_cells: 8192 * 8192,
            max_output_pixels: 7680 * 4320,
            max_input_triangles: 4_000_000,
        }
    }
}

/// The pipelines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PipelineKind {
    /// Snow on terrain (SPEC §1).
    SnowTerrain,
    /// Snow cover on meshes (SPEC §2).
    SnowCover,
}

impl PipelineKind {
    pub const ALL: &'static [PipelineKind] = &[PipelineKind::SnowTerrain, PipelineKind::SnowCover];

    /// The API name (`snow-terrain`).
    pub fn name(self) -> &'static str {
        match self {
            PipelineKind::SnowTerrain => "snow-terrain",
            PipelineKind::SnowCover => "snow-cover",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|k| k.name() == name)
    }

    /// The multipart part that carries the input (`dem`, `mesh`, `volume`).
    pub fn input_part(self) -> &'static str {
        match self {
            PipelineKind::SnowTerrain => "dem",
            PipelineKind::SnowCover => "mesh",
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
    SnowCover(Box<snow_cover::Params>),
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
            PipelineKind::SnowCover => Ok(Params::SnowCover(Box::new(
                snow_cover::Params::from_json(v, limits)?,
            ))),
        }
    }

    /// The resolved parameters (defaults filled in) as JSON: the canonical form used for request
    /// keys and `report.json`. Parsing it again gives the same parameters.
    pub fn canonical(&self) -> serde_json::Value {
        let v = match self {
            Params::SnowTerrain(p) => serde_json::to_value(p),
            Params::SnowCover(p) => serde_json::to_value(p),
        };
        // Serialising plain structs of numbers, strings and options cannot fail.
        v.unwrap_or(serde_json::Value::Null)
    }
}

/// A pipeline's validated parameters with its decoded input: ready to run.
#[derive(Debug, Clone)]
pub enum Job {
    SnowTerrain {
        params: Box<snow_terrain::Params>,
        dem: Dem,
    },
    SnowCover {
        params: Box<snow_cover::Params>,
        mesh: Mesh,
    },
}

/// Decodes `bytes` as the input of the pipeline `params` belongs to.
pub fn decode(
    params: Params,
    bytes: &[u8],
    filename: Option<&str>,
    limits: &Limits,
) -> Result<Job, InputError> {
    match params {
        Params::SnowTerrain(p) => {
            let opts = DemOptions {
                max_cells: limits.max_input_cells,
                cell_size: p.cell_size,
                vertical_scale: p.vertical_scale,
            };
            let dem = decode_dem(bytes, filename, &opts)?;
            Ok(Job::SnowTerrain { params: p, dem })
        }
        Params::SnowCover(p) => {
            let mesh = snow_cover::run::decode(bytes, filename, &p, limits)?;
            Ok(Job::SnowCover { params: p, mesh })
        }
    }
}

/// Runs the pipeline to its named outputs.
pub fn run(job: &Job, ctl: &dyn Control) -> Result<Vec<Output>, Canceled> {
    match job {
        Job::SnowTerrain { params, dem } => snow_terrain::run(dem, params, ctl),
        Job::SnowCover { params, mesh } => snow_cover::run(mesh, params, ctl),
    }
}
