//! The pipeline registry: names, parameter validation, input decoding and the run, for every
//! pipeline the service offers. The server and the CLI go through these functions only.

use crate::cloud::{self, AmbientField};
use crate::formats::dem::{decode_dem, DemOptions};
use crate::formats::volume::{decode_volume, VolumeOptions};
use crate::geom::{Dem, Mesh, Volume};
use crate::{dust, snow_cover, snow_terrain, Canceled, Control, InputError, Output, ParamError};

/// Input and output size limits (configured by the server; the CLI uses the defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest input grid, cells (DEM) or voxels (volume). Checked from the file header before
    /// the grid is allocated.
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

/// The most memory, in bytes, that decoding one input of `kind` can allocate under `limits`
/// (besides the input's own bytes), with an auxiliary input (`with_aux`: snow-terrain's
/// orthophoto) or without. The server reserves it from its decode budget before it checks an
/// input, so concurrent checks cannot add up to more than the budget. Worst cases:
/// - **DEM**: 12 B per cell of `max_input_cells`: a sample buffer of up to 8 B per cell
///   (float64 GeoTIFF strips) and the `f32` grid; an orthophoto adds 16 B per cell (its RGBA8
///   decode and the linear RGB rock colours on the DEM's grid).
/// - **Mesh**: 160 B per triangle of `max_input_triangles` (indices, 12 B, and up to three
///   vertices of position, normal, UV and colour, 144 B, plus parser slack) and 4 B per pixel of
///   the texture budget (`MeshOptions::max_texture_pixels`).
/// - **Volume**: 12 B per voxel of `max_input_cells` (a float64 sample buffer and the `f32`
///   grid); a cloud version's ambient field adds 12 B per voxel.
///
/// An upper bound from the limits alone, not from the file: a 262 KB deflate GeoTIFF can decode
/// to 8192² cells, so nothing short of its header says how much a file needs. Rejected: a
/// header reader per format (ten formats) to refine it; the budget is what bounds memory, and
/// small inputs decode in milliseconds, so reserving the worst case costs them little time.
pub fn decode_cost(kind: PipelineKind, limits: &Limits, with_aux: bool) -> u64 {
    let cells = limits.max_input_cells;
    let aux = u64::from(with_aux);
    match kind {
        PipelineKind::SnowTerrain => cells.saturating_mul(12 + 16 * aux),
        PipelineKind::SnowCover | PipelineKind::Dust => limits
            .max_input_triangles
            .saturating_mul(160)
            .saturating_add(crate::formats::mesh::MeshOptions::default().max_texture_pixels * 4),
        PipelineKind::Cloud | PipelineKind::CloudEdit => cells.saturating_mul(12 + 12 * aux),
    }
}

/// The pipelines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PipelineKind {
    /// Snow on terrain (SPEC §1).
    SnowTerrain,
    /// Snow cover on meshes (SPEC §2).
    SnowCover,
    /// Cloud rendering, one shot: a volume and a full renderer state to images (SPEC §3).
    Cloud,
    /// One edit of a cloud scene version (SPEC §3.1–3.3). Internal: the cloud scene resource
    /// submits it; it has no `POST /v1/{pipeline}` route of its own.
    CloudEdit,
    /// Dust with fibre shells (SPEC §4).
    Dust,
}

impl PipelineKind {
    /// Every pipeline, internal ones included.
    pub const ALL: &'static [PipelineKind] = &[
        PipelineKind::SnowTerrain,
        PipelineKind::SnowCover,
        PipelineKind::Cloud,
        PipelineKind::CloudEdit,
        PipelineKind::Dust,
    ];

    /// The pipelines with a public `POST /v1/{name}` route.
    pub fn public() -> impl Iterator<Item = PipelineKind> {
        Self::ALL
            .iter()
            .copied()
            .filter(|k| *k != PipelineKind::CloudEdit)
    }

    /// The API name (`snow-terrain`).
    pub fn name(self) -> &'static str {
        match self {
            PipelineKind::SnowTerrain => "snow-terrain",
            PipelineKind::SnowCover => "snow-cover",
            PipelineKind::Cloud => "cloud",
            PipelineKind::CloudEdit => "cloud-edit",
            PipelineKind::Dust => "dust",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|k| k.name() == name)
    }

    /// The multipart part that carries the input (`dem`, `mesh`, `volume`).
    pub fn input_part(self) -> &'static str {
        match self {
            PipelineKind::SnowTerrain => "dem",
            PipelineKind::SnowCover | PipelineKind::Dust => "mesh",
            PipelineKind::Cloud | PipelineKind::CloudEdit => "volume",
        }
    }
}

/// Parameters of one cloud edit job: the edit, the state of the version it starts from, and the
/// scene's decoder options.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudEditParams {
    /// `sun-color`, `ambient` or `sun-direction`.
    pub kind: String,
    /// The base version's state.
    pub base: cloud::CloudState,
    pub edit: cloud::Edit,
    /// The edit as sent, kept for the canonical form (request keys).
    pub raw_edit: serde_json::Value,
    pub bounds: Option<[[f64; 3]; 2]>,
    pub dims: Option<[usize; 3]>,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct WireCloudEdit {
    kind: String,
    base: serde_json::Value,
    edit: serde_json::Value,
    #[serde(default)]
    bounds: Option<serde_json::Value>,
    #[serde(default)]
    dims: Option<serde_json::Value>,
}

impl CloudEditParams {
    /// Validates `{"kind", "base", "edit", "bounds"?, "dims"?}`; errors inside the edit are named
    /// `edit.<field>`.
    pub fn from_json(v: &serde_json::Value, limits: &Limits) -> Result<Self, ParamError> {
        let w: WireCloudEdit = deserialize_params(v)?;
        let base = cloud::CloudState::from_json(&w.base)
            .map_err(|e| ParamError::new(format!("base.{}", e.field), e.detail))?;
        let edit = cloud::Edit::from_json(&w.kind, &w.edit, limits)
            .map_err(|e| ParamError::new(format!("edit.{}", e.field), e.detail))?;
        // The decoder options are validated by the cloud pipeline's own rules.
        let mut opts = serde_json::Map::new();
        for (k, val) in [("bounds", w.bounds), ("dims", w.dims)] {
            if let Some(val) = val {
                opts.insert(k.to_string(), val);
            }
        }
        let p = cloud::Params::from_json(&serde_json::Value::Object(opts), limits)?;
        Ok(Self {
            kind: w.kind,
            base,
            edit,
            raw_edit: w.edit,
            bounds: p.bounds().map(|(lo, hi)| [lo, hi]),
            dims: p.dims(),
        })
    }

    fn canonical(&self) -> serde_json::Value {
        serde_json::json!({
            "kind": self.kind,
            "base": self.base,
            "edit": self.raw_edit,
            "bounds": self.bounds,
            "dims": self.dims,
        })
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
    Cloud(Box<cloud::Params>),
    CloudEdit(Box<CloudEditParams>),
    Dust(Box<dust::Params>),
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
            PipelineKind::Cloud => Ok(Params::Cloud(Box::new(cloud::Params::from_json(
                v, limits,
            )?))),
            PipelineKind::CloudEdit => Ok(Params::CloudEdit(Box::new(CloudEditParams::from_json(
                v, limits,
            )?))),
            PipelineKind::Dust => Ok(Params::Dust(Box::new(dust::Params::from_json(v, limits)?))),
        }
    }

    /// The resolved parameters (defaults filled in) as JSON: the canonical form used for request
    /// keys and `report.json`. Parsing it again gives the same parameters.
    pub fn canonical(&self) -> serde_json::Value {
        let v = match self {
            Params::SnowTerrain(p) => serde_json::to_value(p),
            Params::SnowCover(p) => serde_json::to_value(p),
            Params::Cloud(p) => serde_json::to_value(p),
            Params::CloudEdit(p) => Ok(p.canonical()),
            Params::Dust(p) => serde_json::to_value(p),
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
        /// The rock colours from an orthophoto ([`ORTHO`]), placed on the DEM's grid.
        rock: Option<Box<snow_terrain::ortho::RockColours>>,
    },
    SnowCover {
        params: Box<snow_cover::Params>,
        mesh: Mesh,
    },
    Cloud {
        params: Box<cloud::Params>,
        volume: Volume,
        ambient: Option<AmbientField>,
    },
    CloudEdit {
        params: Box<CloudEditParams>,
        volume: Volume,
        ambient: Option<AmbientField>,
    },
    /// A sun-colour edit answered from the layers of the base version's render at the edit's
    /// view ([`cloud::edit::recolor`]): the volume is not decoded.
    CloudRecolor {
        params: Box<CloudEditParams>,
        layers: Box<cloud::layers::Layers>,
        /// The `layers.bin` blob they were read from (the new version's `layers.bin`).
        blob: Vec<u8>,
    },
    Dust {
        params: Box<dust::Params>,
        mesh: Mesh,
    },
}

/// Why a run produced no outputs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RunFailure {
    #[error("canceled")]
    Canceled,
    /// The request cannot be carried out on this input (a cloud edit dragged from empty sky);
    /// the message is for the user.
    #[error("{0}")]
    Unprocessable(String),
    /// Like `Unprocessable`, with a problem type of its own (a stroke that misses the cloud vs
    /// one on cloud that no sunlight reaches).
    #[error("{detail}")]
    Refused {
        /// The problem type: the last part of its URI (`stroke-misses-cloud`, …).
        problem: &'static str,
        title: &'static str,
        detail: String,
    },
}

impl From<Canceled> for RunFailure {
    fn from(_: Canceled) -> Self {
        RunFailure::Canceled
    }
}

/// The name of snow-terrain's optional auxiliary input: an orthophoto (RGB or RGBA GeoTIFF, PNG
/// or JPEG) whose colours replace `rock_color` (SPEC §1 step 7). Also its multipart part's name.
pub const ORTHO: &str = "ortho";

/// The name of the auxiliary input holding a cloud scene version's ambient field.
pub const AMBIENT_FIELD: &str = "ambient.bin";

/// The name of a cloud edit's optional auxiliary input holding the layers of the base
/// version's render at the edit's view (`layers.bin` of that render): a sun-colour edit then
/// reads them instead of decoding the volume and marching.
pub const LAYERS: &str = cloud::layers::LAYERS_FILE;

fn volume_options(
    bounds: Option<[[f64; 3]; 2]>,
    dims: Option<[usize; 3]>,
    limits: &Limits,
) -> VolumeOptions {
    VolumeOptions {
        max_voxels: limits.max_input_cells,
        dims,
        bounds: bounds.map(|[lo, hi]| (lo, hi)),
    }
}

/// Decodes a cloud volume. Its world box is the user's `bounds` or SPEC §3's default, the unit
/// cube scaled to the grid's aspect — not the box the file's own geometry implies (an NRRD's
/// spacings, an OpenVDB transform): κ is per world unit, so a file in centimetres or in voxel
/// units would otherwise make the same κ mean wildly different clouds. The file's box is still
/// reported by the decoders for those who pass it as `bounds`.
fn cloud_volume(
    bytes: &[u8],
    filename: Option<&str>,
    opts: &VolumeOptions,
) -> Result<Volume, InputError> {
    let mut volume = decode_volume(bytes, filename, opts)?;
    if opts.bounds.is_none() {
        volume.bounds = Volume::default_bounds(volume.dims);
    }
    Ok(volume)
}

fn ambient_field(
    aux: &[(String, Vec<u8>)],
    volume: &Volume,
) -> Result<Option<AmbientField>, InputError> {
    aux.iter()
        .find(|(name, _)| name == AMBIENT_FIELD)
        .map(|(_, bytes)| AmbientField::from_bytes(bytes, volume.len()))
        .transpose()
}

/// Decodes `bytes` as the input of the pipeline `params` belongs to.
pub fn decode(
    params: Params,
    bytes: &[u8],
    filename: Option<&str>,
    limits: &Limits,
) -> Result<Job, InputError> {
    decode_with_aux(params, bytes, filename, &[], limits)
}

/// Like [`decode`], with the job's named auxiliary inputs (a cloud version's
/// [`AMBIENT_FIELD`], snow-terrain's [`ORTHO`]).
pub fn decode_with_aux(
    params: Params,
    bytes: &[u8],
    filename: Option<&str>,
    aux: &[(String, Vec<u8>)],
    limits: &Limits,
) -> Result<Job, InputError> {
    decode_parts(params, bytes, filename, aux, limits).map_err(|(_, e)| e)
}

/// [`decode_with_aux`] that also says which input an error is about: `None` for the main
/// input, `Some(name)` for the auxiliary input `name` (an orthophoto that is corrupt, too large,
/// in another CRS than the DEM or elsewhere on Earth).
pub fn decode_parts(
    params: Params,
    bytes: &[u8],
    filename: Option<&str>,
    aux: &[(String, Vec<u8>)],
    limits: &Limits,
) -> Result<Job, (Option<&'static str>, InputError)> {
    let main = |e: InputError| (None, e);
    match params {
        Params::SnowTerrain(p) => {
            let opts = DemOptions {
                max_cells: limits.max_input_cells,
                cell_size: p.cell_size,
                vertical_scale: p.vertical_scale,
            };
            let dem = decode_dem(bytes, filename, &opts).map_err(main)?;
            let rock = match aux.iter().find(|(name, _)| name == ORTHO) {
                Some((_, b)) => {
                    let ortho = crate::formats::ortho::decode_ortho(b, limits.max_input_cells)
                        .map_err(|e| (Some(ORTHO), e))?;
                    let fallback = snow_terrain::run::rock_linear(&p);
                    Some(Box::new(
                        snow_terrain::ortho::rock_colours(&dem, &ortho, fallback)
                            .map_err(|e| (Some(ORTHO), e))?,
                    ))
                }
                None => None,
            };
            Ok(Job::SnowTerrain {
                params: p,
                dem,
                rock,
            })
        }
        Params::SnowCover(p) => {
            // snow_cover::run::decode, with the sidecar files the CLI passes as aux inputs.
            let mesh = p
                .view
                .decode_with(bytes, filename, aux, limits)
                .map_err(main)?;
            Ok(Job::SnowCover { params: p, mesh })
        }
        Params::Cloud(p) => {
            let opts = volume_options(p.bounds().map(|(lo, hi)| [lo, hi]), p.dims(), limits);
            let volume = cloud_volume(bytes, filename, &opts).map_err(main)?;
            let ambient = ambient_field(aux, &volume).map_err(main)?;
            Ok(Job::Cloud {
                params: p,
                volume,
                ambient,
            })
        }
        Params::CloudEdit(p) => {
            if let cloud::Edit::SunColor(e) = &p.edit {
                if let Some((_, blob)) = aux.iter().find(|(name, _)| name == LAYERS) {
                    let (id, layers) =
                        cloud::layers::Layers::from_bytes(blob, limits.max_output_pixels)
                            .map_err(main)?;
                    // Layers of another view or state are not these: march instead.
                    if id == cloud::layers::identity(&e.view, &p.base) {
                        return Ok(Job::CloudRecolor {
                            params: p,
                            layers: Box::new(layers),
                            blob: blob.clone(),
                        });
                    }
                }
            }
            let volume = cloud_volume(bytes, filename, &volume_options(p.bounds, p.dims, limits))
                .map_err(main)?;
            let ambient = ambient_field(aux, &volume).map_err(main)?;
            Ok(Job::CloudEdit {
                params: p,
                volume,
                ambient,
            })
        }
        Params::Dust(p) => {
            let mesh = dust::run::decode_with(bytes, filename, aux, &p, limits).map_err(main)?;
            Ok(Job::Dust { params: p, mesh })
        }
    }
}

/// A short description of a decoded input (a volume's grid, box and density range), for
/// resources that keep the input such as cloud scenes. Null for inputs without one.
pub fn describe(job: &Job) -> serde_json::Value {
    match job {
        Job::Cloud { volume, .. } | Job::CloudEdit { volume, .. } => {
            let (min, max, mean) = volume.stats();
            let mut info = serde_json::json!({
                "dims": volume.dims,
                "bounds": [volume.bounds.0, volume.bounds.1],
                "voxel_size": volume.voxel_size(),
                "density": {"min": min, "max": max, "mean": mean},
            });
            // κ as the render's state resolves it (chosen from the volume when not given).
            if let Job::Cloud { params, .. } = job {
                let s = params.state.resolved(volume);
                info["kappa"] = serde_json::json!(s.kappa);
                if let Some(c) = s.kappa_auto {
                    info["kappa_auto"] = serde_json::to_value(c).unwrap_or_default();
                }
            }
            info
        }
        _ => serde_json::Value::Null,
    }
}

/// A cloud edit that could not be done is the user's to fix (422), unless it was canceled.
fn edit_failure(e: cloud::EditError) -> RunFailure {
    match e {
        cloud::EditError::Canceled => RunFailure::Canceled,
        other => match other.problem() {
            Some((problem, title)) => RunFailure::Refused {
                problem,
                title,
                detail: other.to_string(),
            },
            None => RunFailure::Unprocessable(other.to_string()),
        },
    }
}

/// Runs the pipeline to its named outputs.
pub fn run(job: &Job, ctl: &dyn Control) -> Result<Vec<Output>, RunFailure> {
    match job {
        Job::SnowTerrain { params, dem, rock } => Ok(snow_terrain::run_with_rock(
            dem,
            rock.as_deref(),
            params,
            ctl,
        )?),
        Job::SnowCover { params, mesh } => Ok(snow_cover::run(mesh, params, ctl)?),
        Job::Dust { params, mesh } => Ok(dust::run(mesh, params, ctl)?),
        Job::Cloud {
            params,
            volume,
            ambient,
        } => Ok(cloud::run(volume, params, ambient.as_ref(), ctl)?),
        Job::CloudEdit {
            params,
            volume,
            ambient,
        } => {
            let outcome =
                cloud::apply_edit(volume, &params.base, ambient.as_ref(), &params.edit, ctl)
                    .map_err(edit_failure)?;
            Ok(cloud::edit_outputs_with(
                volume,
                &outcome,
                ambient.as_ref(),
                &params.edit,
                ctl,
            )?)
        }
        Job::CloudRecolor {
            params,
            layers,
            blob,
        } => {
            let cloud::Edit::SunColor(e) = &params.edit else {
                return Err(RunFailure::Unprocessable(
                    "only a sun-colour edit reads render layers".into(),
                ));
            };
            cloud::edit::recolor(&params.base, e, layers, blob, ctl).map_err(edit_failure)
        }
    }
}
