//! The pipeline registry, the engine's top floor: names, parameter validation, input decoding
//! and the run, for every pipeline the service offers, dispatched to the pipelines. The server
//! and the CLI go through these functions only; no pipeline imports this file.

use crate::cloud::{self, AmbientField, CloudEditParams};
use crate::formats::dem::{decode_dem, DemOptions};
use crate::geom::{Dem, Mesh, Volume};
use crate::{
    dust, snow_cover, snow_terrain, Canceled, Control, InputError, Output, ParamError, Refusal,
};

use crate::params::Limits;

/// The most memory, in bytes, that decoding one input of `kind` can allocate under `limits`
/// (besides the input's own bytes), with an auxiliary input (`with_extra_input`: snow-terrain's
/// orthophoto, a cloud version's ambient field) or without. The server reserves it from its decode budget before it checks an
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
pub fn decode_cost(kind: PipelineKind, limits: &Limits, with_extra_input: bool) -> u64 {
    let cells = limits.max_input_cells;
    let extra = u64::from(with_extra_input);
    match kind {
        PipelineKind::SnowTerrain => cells.saturating_mul(12 + 16 * extra),
        PipelineKind::SnowCover | PipelineKind::Dust => limits
            .max_input_triangles
            .saturating_mul(160)
            .saturating_add(crate::formats::mesh::MeshOptions::default().max_texture_pixels * 4),
        PipelineKind::Cloud | PipelineKind::CloudEdit => cells.saturating_mul(12 + 12 * extra),
    }
}

/// `limits` scaled down so that decoding one input of `kind` allocates at most `bytes`
/// ([`decode_cost`] of the result ≤ `bytes`): the input-size limits shrink in proportion, the
/// output limit stays. The server decodes with them when less than the worst case is free: the
/// decoders check the sizes a file declares against the limits before they allocate, so a file
/// that fits decodes at once and a larger one is refused (`TooLarge`) having allocated nothing,
/// and then waits for the whole worst case.
pub fn limits_within(
    kind: PipelineKind,
    limits: &Limits,
    with_extra_input: bool,
    bytes: u64,
) -> Limits {
    let full = decode_cost(kind, limits, with_extra_input);
    if bytes >= full {
        return *limits;
    }
    // A mesh's texture budget does not shrink with its triangles.
    let fixed = match kind {
        PipelineKind::SnowCover | PipelineKind::Dust => {
            crate::formats::mesh::MeshOptions::default().max_texture_pixels * 4
        }
        _ => 0,
    };
    let scale = bytes.saturating_sub(fixed) as f64 / full.saturating_sub(fixed).max(1) as f64;
    let shrink = |n: u64| (n as f64 * scale).floor() as u64;
    Limits {
        max_input_cells: shrink(limits.max_input_cells),
        max_input_triangles: shrink(limits.max_input_triangles),
        ..*limits
    }
}

/// Bytes a run of `kind` takes per unit of its input (a DEM cell, a mesh triangle, a volume
/// voxel) and per output pixel: the per-element sizes behind [`run_cost`].
///
/// - **snow-terrain**: 32 B per cell, measured (an 8192² DEM's job peaked at 2,043 MiB, 31.8 B
///   per cell: the `f32` heights, snow depth, normals, slope/aspect and shading grids and the
///   terrain mesh); an orthophoto adds 16 B per cell (its decode and the rock colours).
/// - **snow-cover, dust**: 480 B per triangle: three times the decoded mesh (160 B, see
///   [`decode_cost`]) for the BVH, the per-triangle attributes and the output mesh.
/// - **cloud, cloud-edit**: 48 B per voxel: the density (4 B), the majorant and shadow grids and
///   the ambient field (12 B each), a second ambient field for an edit (12 B).
/// - **every pipeline**: 32 B per output pixel (linear RGB accumulation, depth, the RGBA8 image
///   and its PNG encoding). Counted from the buffers, not measured (only snow-terrain's per-cell
///   figure is); a 4096² render takes 512 MiB of the default 768 MiB budget.
pub fn run_unit_costs(kind: PipelineKind, with_extra_input: bool) -> (u64, u64) {
    let extra = u64::from(with_extra_input);
    let per_unit = match kind {
        PipelineKind::SnowTerrain => 32 + 16 * extra,
        PipelineKind::SnowCover | PipelineKind::Dust => 480,
        PipelineKind::Cloud | PipelineKind::CloudEdit => 48,
    };
    (per_unit, 32)
}

/// The memory, in bytes, a run of `kind` is estimated to take at its peak on an input of `units`
/// elements (DEM cells, mesh triangles or volume voxels) rendering `pixels` output pixels, with
/// the sizes of [`run_unit_costs`]. A worker reserves it from its process's memory budget before
/// it starts the job, so running jobs cannot add up to more than the budget; the server answers
/// 413 at submission when it exceeds the whole budget.
pub fn run_cost(kind: PipelineKind, units: u64, pixels: u64, with_extra_input: bool) -> u64 {
    let (per_unit, per_pixel) = run_unit_costs(kind, with_extra_input);
    units
        .saturating_mul(per_unit)
        .saturating_add(pixels.saturating_mul(per_pixel))
}

/// The input size of a decoded job in [`run_cost`]'s units, its output pixels, and whether it
/// has an auxiliary input.
pub fn job_size(job: &Job) -> (PipelineKind, u64, u64, bool) {
    let px = |w: u32, h: u32| u64::from(w) * u64::from(h);
    let voxels = |v: &Volume| v.dims.iter().map(|&d| d as u64).product::<u64>();
    match job {
        Job::SnowTerrain { params, dem, rock } => (
            PipelineKind::SnowTerrain,
            (dem.width as u64) * (dem.height as u64),
            px(params.width, params.height),
            rock.is_some(),
        ),
        Job::SnowCover { params, mesh } => (
            PipelineKind::SnowCover,
            mesh.triangles.len() as u64,
            px(params.view.width, params.view.height),
            false,
        ),
        Job::Dust { params, mesh } => (
            PipelineKind::Dust,
            mesh.triangles.len() as u64,
            px(params.view.width, params.view.height),
            false,
        ),
        Job::Cloud { params, volume, .. } => (
            PipelineKind::Cloud,
            voxels(volume),
            px(params.width, params.height),
            false,
        ),
        // An edit solves on the volume; its image is the base version's view, counted in the
        // voxel cost (an edit's second ambient field).
        Job::CloudEdit { volume, .. } => (PipelineKind::CloudEdit, voxels(volume), 0, true),
        // A recolour reads the base render's layers (`layers.bin`, 28–40 B per pixel) and
        // writes an image: counted as one pixel per 16 B of the blob (an over-estimate).
        Job::CloudRecolor { blob, .. } => {
            (PipelineKind::CloudEdit, 0, blob.len() as u64 / 16, false)
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

    /// Every output a run of the pipeline may produce, in the order a run lists them (some only
    /// when a parameter asks for them): what a description of the pipeline (the OGC API –
    /// Processes process description) names. A run never produces an output missing here.
    pub fn outputs(self) -> &'static [OutputKind] {
        const fn o(
            name: &'static str,
            media_type: &'static str,
            title: &'static str,
        ) -> OutputKind {
            OutputKind {
                name,
                media_type,
                title,
            }
        }
        const REPORT: OutputKind = o(
            "report.json",
            "application/json",
            "Resolved parameters, input statistics and stage timings",
        );
        const SNOW_TERRAIN: &[OutputKind] = &[
            o("render.png", "image/png", "The snowy terrain in perspective (RGBA, sRGB)"),
            o(
                "snow_cover.tif",
                "image/tiff",
                "Snow cover s = 1 − t as a float32 Cloud-Optimized GeoTIFF with the DEM's georeferencing",
            ),
            o("descriptor.png", "image/png", "The descriptor t as grey, snow white"),
            o("terrain.glb", "model/gltf-binary", "The terrain mesh with snow vertex colours"),
            REPORT,
            o("sweep.png", "image/png", "Contact sheet of a parameter sweep (only with `sweep`)"),
        ];
        const SNOW_COVER: &[OutputKind] = &[
            o(
                "render.png",
                "image/png",
                "The snow-covered scene (RGBA, sRGB)",
            ),
            o("snow.glb", "model/gltf-binary", "The snow mesh"),
            o("scene.glb", "model/gltf-binary", "The scene with its snow"),
            o(
                "displaced.glb",
                "model/gltf-binary",
                "The input mesh displaced by the snow",
            ),
            o(
                "timelapse.png",
                "image/apng",
                "Snowfall as an animated PNG (only when asked)",
            ),
            REPORT,
        ];
        const CLOUD: &[OutputKind] = &[
            o("render.png", "image/png", "The cloud (RGBA, sRGB)"),
            o(
                "state.json",
                "application/json",
                "The resolved renderer state",
            ),
            o(
                "direct.png",
                "image/png",
                "Single scattering layer (only with `layers`)",
            ),
            o(
                "multiple.png",
                "image/png",
                "Multiple scattering layer (only with `layers`)",
            ),
            o(
                "ambient.png",
                "image/png",
                "Ambient layer (only with `layers`)",
            ),
            o(
                cloud::LAYERS,
                "application/octet-stream",
                "Linear layers for editing (only with `layers`)",
            ),
        ];
        const DUST: &[OutputKind] = &[
            o("render.png", "image/png", "The dusty object (RGBA, sRGB)"),
            o("fibers.png", "image/png", "The fibre layer"),
            o("dust_amount.png", "image/png", "The dust amount as grey"),
            o("dusty.glb", "model/gltf-binary", "The dusty mesh"),
            REPORT,
        ];
        match self {
            PipelineKind::SnowTerrain => SNOW_TERRAIN,
            PipelineKind::SnowCover => SNOW_COVER,
            PipelineKind::Cloud => CLOUD,
            PipelineKind::CloudEdit => &[],
            PipelineKind::Dust => DUST,
        }
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

/// One output a pipeline may produce (see [`PipelineKind::outputs`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputKind {
    /// The output's file name (`render.png`).
    pub name: &'static str,
    /// Its IANA media type.
    pub media_type: &'static str,
    /// What it is, in a few words.
    pub title: &'static str,
}

/// Validated parameters of one pipeline.
#[derive(Debug, Clone, PartialEq)]
pub enum PipelineParams {
    SnowTerrain(Box<snow_terrain::SnowTerrainParams>),
    SnowCover(Box<snow_cover::SnowCoverParams>),
    Cloud(Box<cloud::CloudParams>),
    CloudEdit(Box<CloudEditParams>),
    Dust(Box<dust::DustParams>),
}

impl PipelineParams {
    /// Validates wire JSON for `kind`.
    pub fn parse(
        kind: PipelineKind,
        v: &serde_json::Value,
        limits: &Limits,
    ) -> Result<Self, ParamError> {
        match kind {
            PipelineKind::SnowTerrain => Ok(PipelineParams::SnowTerrain(Box::new(
                snow_terrain::SnowTerrainParams::from_json(v, limits)?,
            ))),
            PipelineKind::SnowCover => Ok(PipelineParams::SnowCover(Box::new(
                snow_cover::SnowCoverParams::from_json(v, limits)?,
            ))),
            PipelineKind::Cloud => Ok(PipelineParams::Cloud(Box::new(
                cloud::CloudParams::from_json(v, limits)?,
            ))),
            PipelineKind::CloudEdit => Ok(PipelineParams::CloudEdit(Box::new(
                CloudEditParams::from_json(v, limits)?,
            ))),
            PipelineKind::Dust => Ok(PipelineParams::Dust(Box::new(dust::DustParams::from_json(
                v, limits,
            )?))),
        }
    }

    /// The resolved parameters (defaults filled in) as JSON: the canonical form used for request
    /// keys and `report.json`. Parsing it again gives the same parameters.
    pub fn canonical(&self) -> serde_json::Value {
        let v = match self {
            PipelineParams::SnowTerrain(p) => serde_json::to_value(p),
            PipelineParams::SnowCover(p) => serde_json::to_value(p),
            PipelineParams::Cloud(p) => serde_json::to_value(p),
            PipelineParams::CloudEdit(p) => Ok(p.canonical()),
            PipelineParams::Dust(p) => serde_json::to_value(p),
        };
        // Serialising plain structs of numbers, strings and options cannot fail.
        v.unwrap_or(serde_json::Value::Null)
    }
}

/// A pipeline's validated parameters with its decoded input: ready to run.
#[derive(Debug, Clone)]
pub enum Job {
    SnowTerrain {
        params: Box<snow_terrain::SnowTerrainParams>,
        dem: Dem,
        /// The rock colours from an orthophoto ([`ORTHO`]), placed on the DEM's grid.
        rock: Option<Box<snow_terrain::ortho::RockColors>>,
    },
    SnowCover {
        params: Box<snow_cover::SnowCoverParams>,
        mesh: Mesh,
    },
    Cloud {
        params: Box<cloud::CloudParams>,
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
        params: Box<dust::DustParams>,
        mesh: Mesh,
    },
}

/// Why a run produced no outputs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RunFailure {
    #[error("canceled")]
    Canceled,
    /// The request cannot be carried out on this input (a cloud edit dragged from empty sky, a
    /// stroke that misses the cloud); the message is for the user.
    #[error("{detail}")]
    Refused { reason: Refusal, detail: String },
}

impl From<Canceled> for RunFailure {
    fn from(_: Canceled) -> Self {
        RunFailure::Canceled
    }
}

/// The name of snow-terrain's optional auxiliary input: an orthophoto (RGB or RGBA GeoTIFF, PNG
/// or JPEG) whose colours replace `rock_color` (SPEC §1 step 7). Also its multipart part's name.
pub const ORTHO: &str = "ortho";

pub use cloud::{AMBIENT_FIELD, LAYERS};

/// An input that could not be decoded, and which one.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{error}")]
pub struct DecodeError {
    /// `None` for the main input, the name of the auxiliary input otherwise (an orthophoto that
    /// is corrupt, too large, in another CRS than the DEM or elsewhere on Earth).
    pub part: Option<&'static str>,
    #[source]
    pub error: InputError,
}

impl From<DecodeError> for InputError {
    fn from(e: DecodeError) -> Self {
        e.error
    }
}

/// Decodes `bytes` as the input of the pipeline `params` belongs to.
pub fn decode(
    params: PipelineParams,
    bytes: &[u8],
    filename: Option<&str>,
    limits: &Limits,
) -> Result<Job, InputError> {
    Ok(decode_parts(params, bytes, filename, &[], limits)?)
}

/// Like [`decode`], with the job's named auxiliary inputs (a cloud version's
/// [`AMBIENT_FIELD`], snow-terrain's [`ORTHO`], a mesh's sidecar files), saying which input an
/// error is about.
pub fn decode_parts(
    params: PipelineParams,
    bytes: &[u8],
    filename: Option<&str>,
    named_inputs: &[(String, Vec<u8>)],
    limits: &Limits,
) -> Result<Job, DecodeError> {
    let main = |error: InputError| DecodeError { part: None, error };
    let in_ortho = |error: InputError| DecodeError {
        part: Some(ORTHO),
        error,
    };
    match params {
        PipelineParams::SnowTerrain(p) => {
            let opts = DemOptions {
                max_cells: limits.max_input_cells,
                cell_size: p.cell_size,
                vertical_scale: p.vertical_scale,
            };
            let dem = decode_dem(bytes, filename, &opts).map_err(main)?;
            let rock = match named_inputs.iter().find(|(name, _)| name == ORTHO) {
                Some((_, b)) => Some(Box::new(
                    snow_terrain::ortho::decode_rock(&dem, b, &p, limits.max_input_cells)
                        .map_err(in_ortho)?,
                )),
                None => None,
            };
            Ok(Job::SnowTerrain {
                params: p,
                dem,
                rock,
            })
        }
        PipelineParams::SnowCover(p) => {
            // The sidecar files the CLI passes as named inputs.
            let mesh =
                snow_cover::run::decode(bytes, filename, named_inputs, &p, limits).map_err(main)?;
            Ok(Job::SnowCover { params: p, mesh })
        }
        PipelineParams::Cloud(mut p) => {
            let bounds = p.bounds().map(|(lo, hi)| [lo, hi]);
            let mut volume =
                cloud::input::decode(bytes, filename, bounds, p.dims(), limits).map_err(main)?;
            // The scan's background out before κ is chosen ([`cloud::floor`]).
            p.state = p.state.with_floor_applied(&mut volume);
            let ambient = cloud::input::ambient_field(named_inputs, &volume).map_err(main)?;
            Ok(Job::Cloud {
                params: p,
                volume,
                ambient,
            })
        }
        PipelineParams::CloudEdit(p) => {
            if let cloud::Edit::SunColor(e) = &p.edit {
                if let Some((_, blob)) = named_inputs.iter().find(|(name, _)| name == LAYERS) {
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
            let mut p = p;
            let mut volume =
                cloud::input::decode(bytes, filename, p.bounds, p.dims, limits).map_err(main)?;
            // The base version's floor (chosen again, identically, when it left it open).
            p.base = p.base.with_floor_applied(&mut volume);
            let ambient = cloud::input::ambient_field(named_inputs, &volume).map_err(main)?;
            Ok(Job::CloudEdit {
                params: p,
                volume,
                ambient,
            })
        }
        PipelineParams::Dust(p) => {
            let mesh =
                dust::run::decode(bytes, filename, named_inputs, &p, limits).map_err(main)?;
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
            // κ as the render's state resolves it (chosen from the volume when not given), and
            // the density floor the decoder took out ([`cloud::floor`]).
            if let Job::Cloud { params, .. } = job {
                info["density_floor"] = serde_json::json!(params.state.density_floor);
                if let Some(c) = &params.state.density_floor_auto {
                    info["density_floor_auto"] = serde_json::to_value(c).unwrap_or_default();
                }
                let s = params.state.resolved(volume);
                info["sun_direction"] = serde_json::json!(s.sun_direction);
                if let Some(c) = &s.sun_auto {
                    info["sun_auto"] = serde_json::to_value(c).unwrap_or_default();
                }
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
        other => RunFailure::Refused {
            reason: other.refusal(),
            detail: other.to_string(),
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
                return Err(RunFailure::Refused {
                    reason: Refusal::Unprocessable,
                    detail: "only a sun-colour edit reads render layers".into(),
                });
            };
            cloud::edit::recolor(&params.base, e, layers, blob, ctl).map_err(edit_failure)
        }
    }
}
