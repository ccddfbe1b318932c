//! Web-map tiles of snow on terrain (issue 22): the surface descriptor t of paper §4.1 (SPEC §1
//! steps 1–6, [`super::descriptor`]) and the colour blend of §4.2 ([`super::color`]) drawn into
//! WebMercatorQuad tiles ([`crate::geom::mercator`]), plus the elevation encodings map clients
//! read (`terrain-rgb`, `terrarium`) and a plain hillshade.
//!
//! **Seam-free by construction.** A tile is computed on the DEM's own grid, over the window of
//! cells its pixels fall on grown by the descriptor's reach ([`descriptor::reach`]: smoothing,
//! TSA window, step-5 smoothing, sun correction and slope term, plus one cell for the shading's
//! differences and one for the bilinear resampling), with every parameter that depends on the
//! whole DEM resolved once per map ([`descriptor::resolve`]: the altitude band's quantiles, the
//! sun's azimuth, the smoothing passes). Each stage is a local, fixed-order computation (zeros
//! outside the grid add nothing, see [`super::smooth`]), so the window's values away from its cut
//! edges are those of the whole-DEM descriptor, and the tile equals the same pixels resampled from
//! the whole-DEM result ([`render_region`] with [`Window::Whole`]): neighbouring tiles agree along
//! their common edge.
//!
//! **Cast shadows** (`relief`, with `shading` and `shadows` on) come from a sun-visibility field
//! over the whole DEM ([`sun_visibility`]), computed once per map on its first `relief` tile and
//! kept with the map: a tile reads the field at its own cells, so a shadow longer than a tile (or
//! than the halo) continues into the next tile exactly as in the whole-DEM result.
//!
//! **Resampling.** Pixel centres are mapped to the DEM's grid through nodes every
//! [`NODE_PX`] pixels (Web Mercator → WGS 84 → the DEM's CRS → fractional column and row), and
//! bilinearly between nodes: a node grid is aligned to the global pixel grid, so a tile and any
//! region containing it use the same nodes. Values are bilinear between grid points (cell
//! centres); a pixel whose nearest grid point is nodata, or that falls outside the DEM's extent,
//! is transparent.

use rayon::prelude::*;

use std::sync::Arc;

use super::descriptor::{self, DescriptorParams};
use super::params::SnowTerrainParams;
use crate::error::{InputError, ParamError};
use crate::formats::dem::cog::{self, ByteSource, CogDem, CogError};
use crate::formats::dem::{decode_dem, sniff, DemFormat, DemOptions};
use crate::geom::mercator::{self, CrsError, CrsTransform};
use crate::geom::Dem;
use crate::params::Limits;
use crate::render::image::{linear_to_srgb8, srgb8_to_linear, RgbaImage};

/// Pixels between the nodes at which pixel positions are reprojected exactly.
pub const NODE_PX: u32 = 16;

/// Deepest zoom served: 2^24 tiles a side (≈ 2 cm pixels at the equator).
pub const MAX_ZOOM: u8 = 24;

/// A map layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Layer {
    /// Snow cover s = 1 − t as white with alpha s (paper §4.1's descriptor).
    Snow,
    /// The snowy landscape from above: rock/snow colour blend of §4.2, lit by the sun.
    Relief,
    /// Grey hillshade of the heights (sun from the north-west at 45°, the GIS convention).
    Hillshade,
    /// Mapbox Terrain-RGB: h = −10000 + (R·65536 + G·256 + B)·0.1.
    TerrainRgb,
    /// Terrarium: h = R·256 + G + B/256 − 32768.
    Terrarium,
}

impl Layer {
    pub const ALL: [Layer; 5] = [
        Layer::Snow,
        Layer::Relief,
        Layer::Hillshade,
        Layer::TerrainRgb,
        Layer::Terrarium,
    ];

    /// The name in URLs.
    pub fn name(self) -> &'static str {
        match self {
            Layer::Snow => "snow",
            Layer::Relief => "relief",
            Layer::Hillshade => "hillshade",
            Layer::TerrainRgb => "terrain-rgb",
            Layer::Terrarium => "terrarium",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.name() == name)
    }

    /// TileJSON `encoding` of an elevation layer (`mapbox` or `terrarium`).
    pub fn encoding(self) -> Option<&'static str> {
        match self {
            Layer::TerrainRgb => Some("mapbox"),
            Layer::Terrarium => Some("terrarium"),
            _ => None,
        }
    }

    fn needs_descriptor(self) -> bool {
        matches!(self, Layer::Snow | Layer::Relief)
    }
}

/// What a map client needs to know of a map (TileJSON's fields).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MapInfo {
    /// West, south, east, north, degrees (WGS 84).
    pub bounds: [f64; 4],
    /// Longitude, latitude, zoom.
    pub center: [f64; 3],
    /// The zoom at which the whole DEM spans about one tile.
    pub minzoom: u8,
    /// The first zoom whose pixels are no larger than the DEM's cells.
    pub maxzoom: u8,
    /// The DEM grid, cells.
    pub width: usize,
    pub height: usize,
    /// Cell size, metres (east, south).
    pub cell_m: [f64; 2],
    /// The DEM's CRS (`EPSG:32725`, `EPSG:4326`).
    pub crs: String,
}

/// A DEM prepared for tiles: the heights (whole, or read by ranges from a COG), the CRS
/// transformation and the parameters with every whole-DEM value resolved. Built once per map.
#[derive(Debug)]
pub struct MapSource {
    grid: Grid,
    crs: CrsTransform,
    /// The parameters; their descriptor part resolved for level 0 (the whole DEM's grid).
    params: SnowTerrainParams,
    info: MapInfo,
}

/// Where a map's heights come from.
#[derive(Debug)]
#[allow(clippy::large_enum_variant)] // one per map: boxing the common case buys nothing
enum Grid {
    /// The whole DEM in memory (every DEM that fits the decode limits), and its sun-visibility
    /// field, made by the first `relief` tile.
    Whole {
        dem: Dem,
        level: Level,
        sun: std::sync::OnceLock<Vec<f32>>,
    },
    /// A tiled GeoTIFF read by ranges, level by level (see [`open_source`]).
    Tiled(Box<Tiled>),
}

/// A grid tiles are computed on: level 0 of a whole DEM, or one level of a COG.
#[derive(Debug, Clone)]
struct Level {
    width: usize,
    height: usize,
    /// Cell size, metres (east, south).
    dx: f64,
    dy: f64,
    /// x = x0 + col·a, y = y0 + row·e (cell corners, CRS units).
    transform: [f64; 4],
    /// The descriptor parameters resolved for this level: the global values (snowline band,
    /// sun azimuth) of the map, the smoothing for this level's cells.
    descriptor: DescriptorParams,
}

/// A DEM far larger than memory, served from a tiled GeoTIFF (a Cloud-Optimized GeoTIFF) read
/// by ranges (issue 22).
///
/// - **Levels.** The COG's full resolution and its overviews are the levels; the tiles of zoom
///   `z` are computed on [`Tiled::level_for`]`(z)`, the coarsest level whose cells are no
///   larger than the zoom's pixels at the map's centre latitude, so a tile reads about as many
///   cells as it has pixels (plus the halo) at every zoom. The level depends on the zoom only,
///   so neighbouring tiles of one zoom are computed on one grid and agree along their edges, as
///   whole-DEM tiles do.
/// - **Global values** — the snowline band's elevation quantiles and the sun's azimuth
///   ([`descriptor::resolve`]) — come from the *overview*: the finest level of at most
///   [`OVERVIEW_CELLS`] cells, read whole once when the map is opened. The smoothing is
///   resolved per level for its cell size ([`descriptor::resolve_smoothing`]).
/// - **Cast shadows** are near field plus far field, each a function of the cell's position
///   only (seam-free): the shadow surface of the terrain within [`NEAR_STEPS`] steps toward the
///   sun, read on the level's own heights, and beyond that the shadow surface of the overview
///   ([`shadow_top`], one sweep when the map's first `relief` tile needs it) taken
///   [`NEAR_STEPS`] steps toward the sun and lowered by the sun's drop over them
///   ([`Tiled::sun`]).
///
/// Memory: the overview and its shadow field (at most 8 bytes × [`OVERVIEW_CELLS`]), the COG's
/// tile offsets and its decoded-tile cache ([`cog::TILE_CACHE_BYTES`]); see
/// [`MapSource::held_bytes`].
struct Tiled {
    cog: CogDem,
    levels: Vec<Level>,
    overview: Dem,
    /// max(shadow surface, height) of every overview cell, made by the first `relief` tile.
    far: std::sync::OnceLock<Vec<f32>>,
    /// Latitude at which zooms are matched to levels (the map's centre).
    lat: f64,
}

impl std::fmt::Debug for Tiled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tiled")
            .field("cog", &self.cog)
            .field("levels", &self.levels.len())
            .finish_non_exhaustive()
    }
}

/// Cells of the overview a tiled map reads whole, at most (2048², 16 MiB of heights).
pub const OVERVIEW_CELLS: u64 = 2048 * 2048;

/// Halo, in cells, above which a tiled map's `snow` and `relief` tiles are computed on a coarser
/// level (see [`Tiled::level_for`]).
pub const MAX_DESCRIPTOR_HALO: usize = 160;

/// Steps toward the sun over which a tiled map's cast shadows are read on the tile's own
/// level (the near field); beyond, the overview's (the far field).
pub const NEAR_STEPS: usize = 48;

/// Which cells a region is computed on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Window {
    /// The cells under the region grown by the descriptor's reach (how tiles are made).
    Halo,
    /// The whole DEM (the reference the tiles are held to).
    Whole,
}

/// A rectangle of the global pixel grid at zoom `z` with `tile_size`-pixel tiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Region {
    pub z: u8,
    pub tile_size: u32,
    /// Top-left pixel, a multiple of [`NODE_PX`].
    pub x0: u64,
    pub y0: u64,
    /// Size, pixels, multiples of [`NODE_PX`].
    pub width: u32,
    pub height: u32,
}

impl Region {
    /// Tile (`x`, `y`) of zoom `z`; `None` when it does not exist (z > [`MAX_ZOOM`], x or y ≥ 2^z)
    /// or `size` is not 256 or 512.
    pub fn tile(z: u8, x: u64, y: u64, size: u32) -> Option<Region> {
        let n = 1u64 << z.min(MAX_ZOOM);
        (z <= MAX_ZOOM && x < n && y < n && (size == 256 || size == 512)).then_some(Region {
            z,
            tile_size: size,
            x0: x * u64::from(size),
            y0: y * u64::from(size),
            width: size,
            height: size,
        })
    }

    /// A block of `nx × ny` tiles from tile (`x`, `y`).
    pub fn tiles(z: u8, x: u64, y: u64, nx: u32, ny: u32, size: u32) -> Option<Region> {
        let r = Region::tile(z, x, y, size)?;
        Region::tile(z, x + u64::from(nx) - 1, y + u64::from(ny) - 1, size)?;
        Some(Region {
            width: size * nx,
            height: size * ny,
            ..r
        })
    }
}

/// Why a DEM and parameters make no map.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error(transparent)]
    Input(#[from] InputError),
    #[error(transparent)]
    Crs(#[from] CrsError),
    /// Reading the DEM's bytes failed (the store is unavailable): not the client's fault.
    #[error("reading the DEM: {0}")]
    Source(String),
}

impl From<CogError> for MapError {
    fn from(e: CogError) -> Self {
        match e {
            CogError::Input(i) => MapError::Input(i),
            CogError::Source(s) => MapError::Source(s.to_string()),
        }
    }
}

/// Decodes a DEM (`bytes`, named `filename`) within `limits` and prepares it with the
/// snow-terrain parameters `params` (wire JSON, validated here).
pub fn open(
    bytes: &[u8],
    filename: Option<&str>,
    params: &serde_json::Value,
    limits: &Limits,
) -> Result<MapSource, MapError> {
    let p = SnowTerrainParams::from_json(params, limits)?;
    let opts = dem_options(&p, limits);
    let dem = decode_dem(bytes, filename, &opts)?;
    Ok(MapSource::new(dem, &p)?)
}

fn dem_options(p: &SnowTerrainParams, limits: &Limits) -> DemOptions {
    DemOptions {
        max_cells: limits.max_input_cells,
        cell_size: p.cell_size,
        vertical_scale: p.vertical_scale,
    }
}

/// How [`open_source`] will read a DEM: whole, or by ranges (a tiled GeoTIFF of more than the
/// caller's `whole_max_cells`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceKind {
    Whole,
    /// By ranges: the map holds about `held_bytes` (see [`MapSource::held_bytes`]).
    Tiled {
        held_bytes: u64,
    },
}

/// Reads only the header of the DEM in `src` (a few kilobytes) to tell how [`open_source`]
/// will read it: a tiled GeoTIFF whose full resolution has more than `whole_max_cells` cells is
/// read by ranges, everything else whole.
pub fn source_kind(
    src: &Arc<dyn ByteSource>,
    params: &serde_json::Value,
    limits: &Limits,
    whole_max_cells: u64,
) -> Result<SourceKind, MapError> {
    Ok(probe(src, params, limits, whole_max_cells)?.0)
}

/// [`source_kind`], with the opened COG when it is read by ranges.
fn probe(
    src: &Arc<dyn ByteSource>,
    params: &serde_json::Value,
    limits: &Limits,
    whole_max_cells: u64,
) -> Result<(SourceKind, Option<CogDem>), MapError> {
    let mut magic = [0u8; 4];
    if src.size() < 8 || src.read_at(0, &mut magic).is_err() {
        return Ok((SourceKind::Whole, None));
    }
    if sniff(&magic, None) != Some(DemFormat::GeoTiff) {
        return Ok((SourceKind::Whole, None));
    }
    let p = SnowTerrainParams::from_json(params, limits)?;
    let cog = match CogDem::open(src.clone(), &dem_options(&p, limits)) {
        Ok(c) => c,
        // Transient: say so; anything else the whole decode reports in its own words.
        Err(CogError::Source(e)) => return Err(MapError::Source(e.to_string())),
        Err(CogError::Input(_)) => return Ok((SourceKind::Whole, None)),
    };
    let l0 = &cog.levels()[0];
    if (l0.width as u64) * (l0.height as u64) <= whole_max_cells {
        return Ok((SourceKind::Whole, None));
    }
    let ov = overview_level(&cog, whole_max_cells).map_or(OVERVIEW_CELLS, |l| {
        let lv = &cog.levels()[l];
        (lv.width * lv.height) as u64
    });
    Ok((
        SourceKind::Tiled {
            held_bytes: held_tiled(ov),
        },
        Some(cog),
    ))
}

/// Bytes a tiled map holds: the overview's heights and shadow field, and the tile cache.
fn held_tiled(overview_cells: u64) -> u64 {
    overview_cells * 8 + cog::TILE_CACHE_BYTES as u64
}

/// The finest level of at most [`OVERVIEW_CELLS`] cells and at most `whole_max_cells` (no
/// more than the caller would hold of a DEM read whole).
fn overview_level(cog: &CogDem, whole_max_cells: u64) -> Option<usize> {
    let max = OVERVIEW_CELLS.min(whole_max_cells);
    cog.levels()
        .iter()
        .position(|l| (l.width as u64) * (l.height as u64) <= max)
}

/// Prepares the DEM in `src` (named `filename`) with the snow-terrain parameters `params`: read
/// whole and decoded as [`open`] does, unless [`source_kind`] says it is a tiled GeoTIFF larger
/// than `whole_max_cells`, which is then read by ranges: its header and IFDs now, its bounded
/// overview (see [`Tiled`]) now, its tiles when map tiles need them.
pub fn open_source(
    src: Arc<dyn ByteSource>,
    filename: Option<&str>,
    params: &serde_json::Value,
    limits: &Limits,
    whole_max_cells: u64,
) -> Result<MapSource, MapError> {
    match probe(&src, params, limits, whole_max_cells)? {
        (_, Some(cog)) => {
            let p = SnowTerrainParams::from_json(params, limits)?;
            MapSource::tiled(cog, &p, whole_max_cells)
        }
        (_, None) => {
            let n = usize::try_from(src.size()).map_err(|_| InputError::TooLarge {
                what: "DEM bytes",
                actual: src.size(),
                max: usize::MAX as u64,
            })?;
            let mut bytes = vec![0u8; n];
            src.read_at(0, &mut bytes)
                .map_err(|e| MapError::Source(e.to_string()))?;
            open(&bytes, filename, params, limits)
        }
    }
}

impl MapSource {
    /// Prepares `dem` with the snow-terrain parameters `p` (validated): refuses a DEM that cannot
    /// be placed on the Earth.
    pub fn new(dem: Dem, p: &SnowTerrainParams) -> Result<Self, CrsError> {
        let g = &dem.georef;
        let t = g.transform.ok_or(CrsError::NoGeoreference)?;
        if t[2] != 0.0 || t[4] != 0.0 {
            return Err(CrsError::Rotated);
        }
        let crs = CrsTransform::new(g.epsg, g.geographic)?;
        let transform = [t[0], t[1], t[3], t[5]];
        let mut params = p.clone();
        params.descriptor = descriptor::resolve(&dem, &p.descriptor);
        let info = map_info(
            &crs,
            transform,
            (dem.width, dem.height),
            (dem.dx, dem.dy),
            g.epsg,
        )?;
        let level = Level {
            width: dem.width,
            height: dem.height,
            dx: dem.dx,
            dy: dem.dy,
            transform,
            descriptor: params.descriptor.clone(),
        };
        Ok(Self {
            grid: Grid::Whole {
                dem,
                level,
                sun: std::sync::OnceLock::new(),
            },
            crs,
            params,
            info,
        })
    }

    /// Prepares a COG read by ranges (see [`Tiled`]): reads its overview whole.
    fn tiled(cog: CogDem, p: &SnowTerrainParams, whole_max_cells: u64) -> Result<Self, MapError> {
        let g = cog.georef().clone();
        let t = g.transform.ok_or(CrsError::NoGeoreference)?;
        if t[2] != 0.0 || t[4] != 0.0 {
            return Err(CrsError::Rotated.into());
        }
        let crs = CrsTransform::new(g.epsg, g.geographic)?;
        let ov = overview_level(&cog, whole_max_cells).ok_or_else(|| {
            let last = cog.levels().last().map_or((0, 0), |l| (l.width, l.height));
            InputError::Unusable(format!(
                "a DEM this large is served from its overviews, and its smallest is {}×{} cells \
                 (at most {} cells are needed): add overviews (gdal_translate -of COG, or \
                 gdaladdo)",
                last.0,
                last.1,
                OVERVIEW_CELLS.min(whole_max_cells)
            ))
        })?;
        let overview = cog.read_level(ov)?;
        // The global values from the overview; the smoothing per level below.
        let global = descriptor::resolve(&overview, &p.descriptor);
        let levels: Vec<Level> = (0..cog.levels().len())
            .map(|l| {
                let (dx, dy, lt) = cog.level_grid(l);
                let lt = lt.unwrap_or([t[0], t[1], t[2], t[3], t[4], t[5]]);
                let mut d = descriptor::resolve_smoothing(&p.descriptor, (dx * dy).abs().sqrt());
                d.snowline = global.snowline;
                d.snow_band = global.snow_band;
                d.sun_azimuth_deg = global.sun_azimuth_deg;
                Level {
                    width: cog.levels()[l].width,
                    height: cog.levels()[l].height,
                    dx,
                    dy,
                    transform: [lt[0], lt[1], lt[3], lt[5]],
                    descriptor: d,
                }
            })
            .collect();
        let l0 = &levels[0];
        let info = map_info(
            &crs,
            l0.transform,
            (l0.width, l0.height),
            (l0.dx, l0.dy),
            g.epsg,
        )?;
        let mut params = p.clone();
        params.descriptor = l0.descriptor.clone();
        Ok(Self {
            grid: Grid::Tiled(Box::new(Tiled {
                cog,
                levels,
                overview,
                far: std::sync::OnceLock::new(),
                lat: info.center[1],
            })),
            crs,
            params,
            info,
        })
    }

    /// Whether `relief` draws cast shadows (`shading` and `shadows` both on).
    fn casts_shadows(&self) -> bool {
        self.params.shading && self.params.shadows
    }

    fn sun_angles(&self) -> (f32, f32) {
        (
            self.params.descriptor.sun_azimuth_deg.unwrap_or(180.0),
            self.params.sun_elevation_deg as f32,
        )
    }

    pub fn info(&self) -> &MapInfo {
        &self.info
    }

    /// The whole DEM, when the map holds it (not for a COG read by ranges).
    pub fn dem(&self) -> Option<&Dem> {
        match &self.grid {
            Grid::Whole { dem, .. } => Some(dem),
            Grid::Tiled(_) => None,
        }
    }

    /// Whether the DEM is read by ranges.
    pub fn is_tiled(&self) -> bool {
        matches!(self.grid, Grid::Tiled(_))
    }

    /// Bytes read from the DEM's source so far (0 for a whole DEM, which was read by the
    /// caller).
    pub fn bytes_fetched(&self) -> u64 {
        match &self.grid {
            Grid::Whole { .. } => 0,
            Grid::Tiled(t) => t.cog.bytes_fetched(),
        }
    }

    /// Bytes this map holds in memory at most: a whole DEM's heights and sun field, or a tiled
    /// one's overview, shadow field and tile cache.
    pub fn held_bytes(&self) -> u64 {
        match &self.grid {
            Grid::Whole { dem, .. } => dem.heights.len() as u64 * 8,
            Grid::Tiled(t) => held_tiled(t.overview.heights.len() as u64),
        }
    }

    /// The descriptor parameters with the whole DEM's values resolved (level 0).
    pub fn descriptor_params(&self) -> &DescriptorParams {
        &self.params.descriptor
    }

    /// Cells a tile's window is grown by on each side (level 0).
    pub fn halo(&self) -> usize {
        descriptor::reach(&self.params.descriptor) + 2
    }

    /// The index of the level the tiles of zoom `z` (`tile_size` pixels) are computed on: 0 for
    /// a whole DEM, the COG's level (0 the full resolution, then its overviews) for a tiled one.
    pub fn level_of_zoom(&self, z: u8, tile_size: u32, layer: Layer) -> usize {
        self.level(z, tile_size, layer).0
    }

    /// The level the tiles of `layer` at zoom `z` (`tile_size` pixels) are computed on.
    fn level(&self, z: u8, tile_size: u32, layer: Layer) -> (usize, &Level) {
        match &self.grid {
            Grid::Whole { level, .. } => (0, level),
            Grid::Tiled(t) => {
                let l = t.level_for(z, tile_size, layer);
                (l, &t.levels[l])
            }
        }
    }

    /// Heights of `cells` of level `l`.
    fn heights(&self, l: usize, cells: Cells) -> Result<Vec<f32>, CogError> {
        match &self.grid {
            Grid::Whole { dem, .. } => {
                let mut v = Vec::with_capacity(cells.width() * (cells.r1 - cells.r0));
                for r in cells.r0..cells.r1 {
                    v.extend_from_slice(&dem.heights[r * dem.width + cells.c0..][..cells.width()]);
                }
                Ok(v)
            }
            Grid::Tiled(t) => t.cog.read_window(l, cells.c0, cells.r0, cells.c1, cells.r1),
        }
    }

    /// Sun visibility of `cells` of level `l` (see [`sun_visibility`] and [`Tiled::sun`]).
    fn sun(&self, l: usize, cells: Cells) -> Result<Vec<f32>, CogError> {
        let (azimuth, elevation) = self.sun_angles();
        match &self.grid {
            Grid::Whole { dem, sun, .. } => {
                let field = sun.get_or_init(|| sun_visibility(dem, azimuth, elevation));
                let mut v = Vec::with_capacity(cells.width() * (cells.r1 - cells.r0));
                for r in cells.r0..cells.r1 {
                    v.extend_from_slice(&field[r * dem.width + cells.c0..][..cells.width()]);
                }
                Ok(v)
            }
            Grid::Tiled(t) => t.sun(l, cells, azimuth, elevation),
        }
    }
}

impl Level {
    /// Fractional (column, row) of cell-centre coordinates (grid point (c, r) at (c, r)) of a
    /// longitude/latitude; `None` where the CRS has no value.
    fn grid_position(&self, crs: &CrsTransform, lon: f64, lat: f64) -> Option<(f64, f64)> {
        let (x, y) = crs.from_lonlat(lon, lat)?;
        let [x0, a, y0, e] = self.transform;
        Some(((x - x0) / a - 0.5, (y - y0) / e - 0.5))
    }

    /// Cells a tile's window is grown by on each side.
    fn halo(&self) -> usize {
        descriptor::reach(&self.descriptor) + 2
    }
}

impl Tiled {
    /// The coarsest level whose cells are no larger than a pixel of zoom `z` at the map's
    /// centre latitude (level 0 when even its cells are larger); for the descriptor's layers
    /// (`snow`, `relief`) no finer than the first level whose halo is at most
    /// [`MAX_DESCRIPTOR_HALO`] cells.
    ///
    /// Why the second rule: the descriptor's smoothing is a length in metres (70 m by default),
    /// so on cells far finer than it the halo (the diamond's radius times the passes of steps
    /// 1 and 5) reaches ≈ 900 cells at 0.5 m cells: a 256-px tile would be computed on a window
    /// of 2000² cells, 60 times its own, seconds per tile. The smoothed field holds no detail finer than
    /// that length, so the descriptor's layers of the deepest zooms are computed on the level
    /// whose cells are a fraction of it and resampled; the elevation layers and `hillshade`
    /// keep the finest level. The rule depends on the zoom and layer only: tiles stay seam-free.
    fn level_for(&self, z: u8, tile_size: u32, layer: Layer) -> usize {
        let px = mercator::ground_resolution(z, self.lat) * 256.0 / f64::from(tile_size);
        let by_pixel = self
            .levels
            .iter()
            .rposition(|l| (l.dx * l.dy).abs().sqrt() <= px * (1.0 + 1e-9))
            .unwrap_or(0);
        if !layer.needs_descriptor() {
            return by_pixel;
        }
        let by_halo = self
            .levels
            .iter()
            .position(|l| l.halo() <= MAX_DESCRIPTOR_HALO)
            .unwrap_or(self.levels.len() - 1);
        by_pixel.max(by_halo)
    }

    /// Sun visibility of `cells` of `level`: the cell is lit when it is not below
    /// max(near, far), where *near* = max over k = 1..[`NEAR_STEPS`] of h(p + k·s) − k·drop on
    /// the level's heights (s one step toward the sun: one cell along the grid axis closest to
    /// the sun's direction, a fraction along the other, heights interpolated between two cells
    /// as [`sun_visibility`]'s sweep does; drop the sun's fall over one step), and *far* = the
    /// overview's [`shadow_top`] at p + [`NEAR_STEPS`]·s (bilinear) − [`NEAR_STEPS`]·drop. The
    /// same ramp as the sweep's turns the height's distance to it into visibility. Every value
    /// depends on the cell's position alone, so tiles agree across edges.
    fn sun(
        &self,
        l: usize,
        cells: Cells,
        azimuth: f32,
        elevation: f32,
    ) -> Result<Vec<f32>, CogError> {
        let level = &self.levels[l];
        let (w, h) = (cells.width(), cells.r1 - cells.r0);
        if elevation >= 90.0 {
            return Ok(vec![1.0; w * h]);
        }
        let az = f64::from(azimuth).to_radians();
        let tan_el = f64::from(elevation).to_radians().tan().max(1e-6);
        let uc = az.sin() / level.dx.abs().max(1e-9);
        let ur = -az.cos() / level.dy.abs().max(1e-9);
        let m = uc.abs().max(ur.abs());
        let (sc, sr) = (uc / m, ur / m);
        let drop = (tan_el / m) as f32;
        // The heights the near field reads: the cells grown by the steps on every side.
        let grow = NEAR_STEPS + 1;
        let ext = Cells {
            c0: cells.c0.saturating_sub(grow),
            r0: cells.r0.saturating_sub(grow),
            c1: (cells.c1 + grow).min(level.width),
            r1: (cells.r1 + grow).min(level.height),
        };
        let hx = self.cog.read_window(l, ext.c0, ext.r0, ext.c1, ext.r1)?;
        let ew = ext.width();
        let eh = ext.r1 - ext.r0;
        let far = self
            .far
            .get_or_init(|| shadow_top(&self.overview, azimuth, elevation));
        let ov = &self.overview;
        let [x0, a, y0, e] = level.transform;
        let ot = ov.georef.transform.unwrap_or([x0, a, 0.0, y0, 0.0, e]);
        // Height at level position (c, r) with one integer coordinate (the step's primary axis),
        // −∞ outside the fetched cells or on nodata.
        let height_at = |c: f64, r: f64| -> f32 {
            let (cf, rf) = (c - ext.c0 as f64, r - ext.r0 as f64);
            let (c0, r0) = (cf.floor(), rf.floor());
            let (fc, fr) = ((cf - c0) as f32, (rf - r0) as f32);
            let get = |ci: f64, ri: f64| -> f32 {
                if ci < 0.0 || ri < 0.0 || ci >= ew as f64 || ri >= eh as f64 {
                    return f32::NEG_INFINITY;
                }
                let v = hx[ri as usize * ew + ci as usize];
                if v.is_nan() {
                    f32::NEG_INFINITY
                } else {
                    v
                }
            };
            let mix = |p: f32, q: f32, f: f32| -> f32 {
                if p == f32::NEG_INFINITY || f >= 1.0 {
                    q
                } else if q == f32::NEG_INFINITY || f <= 0.0 {
                    p
                } else {
                    p + (q - p) * f
                }
            };
            if fc == 0.0 {
                mix(get(c0, r0), get(c0, r0 + 1.0), fr)
            } else {
                mix(get(c0, r0), get(c0 + 1.0, r0), fc)
            }
        };
        // The overview's shadow top at level position (c, r), −∞ outside it.
        let far_at = |c: f64, r: f64| -> f32 {
            let x = x0 + (c + 0.5) * a;
            let y = y0 + (r + 0.5) * e;
            let oc = (x - ot[0]) / ot[1] - 0.5;
            let or = (y - ot[3]) / ot[5] - 0.5;
            let (ow, oh) = (ov.width as f64, ov.height as f64);
            if !(oc >= -0.5 && or >= -0.5 && oc <= ow - 0.5 && or <= oh - 0.5) {
                return f32::NEG_INFINITY;
            }
            let (oc, or) = (oc.clamp(0.0, ow - 1.0), or.clamp(0.0, oh - 1.0));
            let (c0, r0) = (oc.floor() as usize, or.floor() as usize);
            let (c1, r1) = ((c0 + 1).min(ov.width - 1), (r0 + 1).min(ov.height - 1));
            let (fc, fr) = ((oc - c0 as f64) as f32, (or - r0 as f64) as f32);
            let mut s = 0.0f32;
            let mut wsum = 0.0f32;
            let mut best = f32::NEG_INFINITY;
            for (ci, ri, wt) in [
                (c0, r0, (1.0 - fc) * (1.0 - fr)),
                (c1, r0, fc * (1.0 - fr)),
                (c0, r1, (1.0 - fc) * fr),
                (c1, r1, fc * fr),
            ] {
                let v = far[ri * ov.width + ci];
                if v.is_finite() {
                    best = best.max(v);
                    if wt > 0.0 {
                        s += v * wt;
                        wsum += wt;
                    }
                }
            }
            if wsum > 0.0 {
                s / wsum
            } else {
                best
            }
        };
        let n = NEAR_STEPS as f64;
        let out = (0..w * h)
            .into_par_iter()
            .map(|k| {
                let (c, r) = ((cells.c0 + k % w) as f64, (cells.r0 + k / w) as f64);
                let hk = hx[(k / w + cells.r0 - ext.r0) * ew + (k % w + cells.c0 - ext.c0)];
                if hk.is_nan() {
                    return 1.0;
                }
                let mut s = far_at(c + n * sc, r + n * sr) - NEAR_STEPS as f32 * drop;
                for step in 1..=NEAR_STEPS {
                    let t = step as f64;
                    let v = height_at(c + t * sc, r + t * sr);
                    s = s.max(v - step as f32 * drop);
                }
                ((hk - s) / drop + 0.5).clamp(0.0, 1.0)
            })
            .collect();
        Ok(out)
    }
}

/// Bounds, centre and zooms of a grid of `w × h` cells of `dx × dy` metres.
fn map_info(
    crs: &CrsTransform,
    t: [f64; 4],
    (width, height): (usize, usize),
    (dx, dy): (f64, f64),
    epsg: Option<u32>,
) -> Result<MapInfo, CrsError> {
    let (w, h) = (width as f64, height as f64);
    // The outline, 32 points a side: a projected grid's edges are curves in WGS 84.
    let ring = crs
        .outline_lonlat(t, width, height, 32)
        .ok_or(CrsError::Unsupported(epsg.unwrap_or(0)))?;
    let mut b = lonlat_bbox(&ring);
    let lim = mercator::MAX_LATITUDE;
    b[1] = b[1].clamp(-lim, lim);
    b[3] = b[3].clamp(-lim, lim);
    let lat_c = (b[1] + b[3]) / 2.0;
    let cell = (dx * dy).abs().sqrt().max(1e-6);
    let zoom_for =
        |metres_per_pixel: f64| (mercator::ground_resolution(0, lat_c) / metres_per_pixel).log2();
    let maxzoom = zoom_for(cell).ceil().clamp(0.0, f64::from(MAX_ZOOM)) as u8;
    let extent = (w * dx.abs()).max(h * dy.abs()).max(1e-6);
    let minzoom = (zoom_for(extent / 256.0)
        .floor()
        .clamp(0.0, f64::from(maxzoom))) as u8;
    let crs_name = match epsg {
        Some(code) => format!("EPSG:{code}"),
        None => "EPSG:4326".to_string(),
    };
    Ok(MapInfo {
        bounds: b,
        center: [
            (b[0] + b[2]) / 2.0,
            lat_c,
            f64::from(minzoom.saturating_add(2).min(maxzoom)),
        ],
        minzoom,
        maxzoom,
        width,
        height,
        cell_m: [dx.abs(), dy.abs()],
        crs: crs_name,
    })
}

/// West, south, east, north of longitude/latitude points, degrees.
pub fn lonlat_bbox(points: &[(f64, f64)]) -> [f64; 4] {
    points.iter().fold(
        [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ],
        |b, &(lon, lat)| [b[0].min(lon), b[1].min(lat), b[2].max(lon), b[3].max(lat)],
    )
}

/// The grid positions of a region's nodes, `(nx + 1) × (ny + 1)`, NaN where the CRS has none.
struct Nodes {
    nx: usize,
    pos: Vec<(f64, f64)>,
}

impl Nodes {
    fn new(src: &MapSource, level: &Level, r: &Region) -> Self {
        let nx = r.width.div_ceil(NODE_PX) as usize;
        let ny = r.height.div_ceil(NODE_PX) as usize;
        let pos = (0..(nx + 1) * (ny + 1))
            .into_par_iter()
            .map(|k| {
                let (i, j) = ((k % (nx + 1)) as u64, (k / (nx + 1)) as u64);
                let px = (r.x0 + i * u64::from(NODE_PX)) as f64;
                let py = (r.y0 + j * u64::from(NODE_PX)) as f64;
                let (mx, my) = mercator::pixel_to_mercator(r.z, r.tile_size, px, py);
                let (lon, lat) = mercator::mercator_to_lonlat(mx, my);
                level
                    .grid_position(&src.crs, lon, lat)
                    .unwrap_or((f64::NAN, f64::NAN))
            })
            .collect();
        Nodes { nx, pos }
    }

    /// Grid position of local pixel (`i`, `j`)'s centre.
    #[inline]
    fn at(&self, i: u32, j: u32) -> (f64, f64) {
        let (ki, kj) = ((i / NODE_PX) as usize, (j / NODE_PX) as usize);
        let u = (f64::from(i % NODE_PX) + 0.5) / f64::from(NODE_PX);
        let v = (f64::from(j % NODE_PX) + 0.5) / f64::from(NODE_PX);
        let s = self.nx + 1;
        let (a, b) = (self.pos[kj * s + ki], self.pos[kj * s + ki + 1]);
        let (c, d) = (self.pos[(kj + 1) * s + ki], self.pos[(kj + 1) * s + ki + 1]);
        let lerp = |p: f64, q: f64, t: f64| p + (q - p) * t;
        (
            lerp(lerp(a.0, b.0, u), lerp(c.0, d.0, u), v),
            lerp(lerp(a.1, b.1, u), lerp(c.1, d.1, u), v),
        )
    }
}

/// Cells `[c0, c1) × [r0, r1)` of the DEM.
#[derive(Debug, Clone, Copy)]
struct Cells {
    c0: usize,
    r0: usize,
    c1: usize,
    r1: usize,
}

impl Cells {
    fn width(&self) -> usize {
        self.c1 - self.c0
    }
}

/// Per-cell values of a layer on a window, `channels` per cell, NaN where transparent.
struct Field {
    cells: Cells,
    channels: usize,
    values: Vec<f32>,
}

/// The layer's per-cell values on `cells` of `level`.
fn layer_field(
    src: &MapSource,
    (l, level): (usize, &Level),
    layer: Layer,
    cells: Cells,
) -> Result<Field, CogError> {
    let (w, h) = (cells.width(), cells.r1 - cells.r0);
    let heights = src.heights(l, cells)?;
    let p = &src.params;
    let (dx, dy) = (level.dx as f32, level.dy as f32);
    let (channels, values) = match layer {
        Layer::TerrainRgb | Layer::Terrarium => (1, heights),
        Layer::Hillshade => {
            let light = light_from(315.0, 45.0);
            let v = (0..w * h)
                .into_par_iter()
                .map(|k| {
                    let n = normal(&heights, w, h, k % w, k / w, dx, dy);
                    if heights[k].is_nan() {
                        f32::NAN
                    } else {
                        dot(n, light).max(0.0)
                    }
                })
                .collect();
            (1, v)
        }
        Layer::Snow | Layer::Relief => {
            let window = Dem {
                width: w,
                height: h,
                heights,
                dx: level.dx,
                dy: level.dy,
                georef: crate::geom::heightfield::GeoRef::default(),
            };
            // The descriptor of §4.1 on the window, with the whole DEM's values resolved (the
            // georeferencing only resolves the sun's azimuth, which is given); no cancellation
            // within a tile (a few milliseconds of work).
            let t = match descriptor::compute(
                &window,
                &level.descriptor,
                &crate::NoControl,
                (0.0, 1.0),
            ) {
                Ok(d) => d.t,
                Err(_) => vec![f32::NAN; w * h],
            };
            if layer == Layer::Snow {
                (1, t.into_iter().map(|t| 1.0 - t).collect())
            } else {
                let sun = if src.casts_shadows() {
                    Some(src.sun(l, cells)?)
                } else {
                    None
                };
                (3, relief(&window, &t, sun.as_deref(), p))
            }
        }
    };
    debug_assert!(layer.needs_descriptor() || channels == 1);
    Ok(Field {
        cells,
        channels,
        values,
    })
}

/// Linear RGB per cell of the `relief` layer: §4.2's blend t·rock + (1 − t)·snow (the sea in
/// `sea_color`), times the shade `(ambient + (1 − ambient)·v·max(0, n·l)) / (ambient +
/// (1 − ambient)·sin(elevation))` for the sun at the resolved azimuth and `sun_elevation_deg`,
/// v the cell's sun visibility (`sun`, 1 without cast shadows), each channel at most 1
/// (`shading: false`: unshaded).
///
/// The shade is normalised to level, sunlit ground, as a hillshade multiplied over a map: a
/// snowfield on a plain shows the snow colour itself (white, not the pale grey an unnormalised
/// `ambient + (1 − ambient)·n·l` of at most ≈ 0.7 gave at the default 35° sun), slopes facing
/// the sun brighten to white, and slopes away from it and cast shadows darken.
fn relief(dem: &Dem, t: &[f32], sun: Option<&[f32]>, p: &SnowTerrainParams) -> Vec<f32> {
    let (w, h) = (dem.width, dem.height);
    let rock = p.rock_linear();
    let snow = p.snow_color.srgb8().map(srgb8_to_linear);
    let sea = match (&p.sea_color, p.descriptor.sea_level) {
        (Some(c), Some(level)) => Some((c.srgb8().map(srgb8_to_linear), level)),
        _ => None,
    };
    let azimuth = p.descriptor.sun_azimuth_deg.unwrap_or(180.0);
    let light = light_from(azimuth, p.sun_elevation_deg as f32);
    let (dx, dy) = (dem.dx as f32, dem.dy as f32);
    let level = p.ambient + (1.0 - p.ambient) * light[1].max(0.0);
    let mut out = vec![f32::NAN; w * h * 3];
    out.par_chunks_mut(3).enumerate().for_each(|(k, px)| {
        let (hk, tk) = (dem.heights[k], t[k]);
        if hk.is_nan() || tk.is_nan() {
            return;
        }
        let tk = tk.clamp(0.0, 1.0);
        let albedo: [f32; 3] = match sea {
            Some((c, level)) if hk <= level => c,
            _ => std::array::from_fn(|i| tk * rock[i] + (1.0 - tk) * snow[i]),
        };
        let shade = if p.shading {
            let n = normal(&dem.heights, w, h, k % w, k / w, dx, dy);
            let v = sun.map_or(1.0, |s| s[k]);
            (p.ambient + (1.0 - p.ambient) * v * dot(n, light).max(0.0)) / level.max(1e-3)
        } else {
            1.0
        };
        for i in 0..3 {
            px[i] = (albedo[i] * shade).min(1.0);
        }
    });
    out
}

/// Sun visibility of every cell of `dem`, 0 (in a cast shadow) to 1 (lit), for a sun at compass
/// `azimuth_deg` and `elevation_deg`: the cell is lit when it is not below the *shadow surface*
/// that the terrain toward the sun casts.
///
/// One sweep away from the sun (O(cells), no ray marching): the grid is walked slice by slice
/// along its axis closest to the sun's direction (columns or rows), starting on the sun's side.
/// A cell's predecessor toward the sun lies on the previous slice, at a fractional position on
/// the other axis; the shadow surface there, S = max(S_prev, h_prev) − d·tan(elevation) (d the
/// horizontal step, metres), is interpolated linearly between the two cells of that slice. Edge
/// of the grid and nodata cast nothing. A cell's visibility ramps from 0 to 1 while its height
/// rises from half a step's drop below S to half a step above, so shadow edges are smooth rather
/// than staircased. The cells of a slice are independent (in parallel); slices run in order.
///
/// Cost: O(cells) time, the field plus two slices of memory; strided reads when slicing by
/// columns.
pub fn sun_visibility(dem: &Dem, azimuth_deg: f32, elevation_deg: f32) -> Vec<f32> {
    sun_sweep(dem, azimuth_deg, elevation_deg, None)
}

/// The top of what casts shadow onward at every cell of `dem`: max(S, h), S the shadow surface
/// of [`sun_visibility`]'s sweep (−∞ where nothing toward the sun casts one, S alone on
/// nodata). A tiled map's far-field shadows read it on its overview ([`Tiled::sun`]).
pub fn shadow_top(dem: &Dem, azimuth_deg: f32, elevation_deg: f32) -> Vec<f32> {
    let mut top = vec![f32::NEG_INFINITY; dem.width * dem.height];
    sun_sweep(dem, azimuth_deg, elevation_deg, Some(&mut top));
    top
}

/// The sweep of [`sun_visibility`]; also writes [`shadow_top`] into `tops` when given.
fn sun_sweep(
    dem: &Dem,
    azimuth_deg: f32,
    elevation_deg: f32,
    mut tops: Option<&mut Vec<f32>>,
) -> Vec<f32> {
    let (w, h) = (dem.width, dem.height);
    let mut vis = vec![1.0f32; w * h];
    if w == 0 || h == 0 || elevation_deg >= 90.0 {
        return vis;
    }
    let az = f64::from(azimuth_deg).to_radians();
    let tan_el = f64::from(elevation_deg).to_radians().tan().max(1e-6);
    // Toward the sun, in cells per metre: columns east, rows south.
    let uc = az.sin() / dem.dx.abs().max(1e-9);
    let ur = -az.cos() / dem.dy.abs().max(1e-9);
    let by_columns = uc.abs() >= ur.abs();
    // Slices along the primary axis; `n` cells per slice along the secondary one.
    let (slices, n, up, us) = if by_columns {
        (w, h, uc, ur)
    } else {
        (h, w, ur, uc)
    };
    // One slice step toward the sun: ±1 on the primary axis, `shift` on the secondary, `d`
    // metres horizontally, and the drop of the sun's ray over it.
    let shift = us / up.abs();
    let d = 1.0 / up.abs();
    let drop = (d * tan_el) as f32;
    let at = |slice: usize, i: usize| -> usize {
        if by_columns {
            i * w + slice
        } else {
            slice * w + i
        }
    };
    // The first slice is on the sun's side.
    let order: Vec<usize> = if up > 0.0 {
        (0..slices).rev().collect()
    } else {
        (0..slices).collect()
    };
    // Per cell of the previous slice: max(S, h), the top of what casts shadow onward.
    let mut top = vec![f32::NEG_INFINITY; n];
    let mut next = vec![f32::NEG_INFINITY; n];
    let mut out = vec![1.0f32; n];
    for &slice in &order {
        let heights = &dem.heights;
        let prev = &top;
        next.par_iter_mut()
            .zip(out.par_iter_mut())
            .enumerate()
            .for_each(|(i, (nx, o))| {
                let hk = heights[at(slice, i)];
                // (The first slice's predecessors are all −∞: no shadow.)
                let s = {
                    let pos = i as f64 + shift;
                    let p0 = pos.floor();
                    let f = (pos - p0) as f32;
                    let get = |j: f64| -> f32 {
                        if j < 0.0 || j >= n as f64 {
                            f32::NEG_INFINITY
                        } else {
                            prev[j as usize]
                        }
                    };
                    let (a, b) = (get(p0), get(p0 + 1.0));
                    // A side outside the grid (or below every cell) does not dilute the other.
                    let s = if a == f32::NEG_INFINITY || f == 1.0 {
                        b
                    } else if b == f32::NEG_INFINITY || f == 0.0 {
                        a
                    } else {
                        a + (b - a) * f
                    };
                    s - drop
                };
                *o = if hk.is_nan() {
                    1.0
                } else {
                    ((hk - s) / drop + 0.5).clamp(0.0, 1.0)
                };
                *nx = if hk.is_nan() { s } else { s.max(hk) };
            });
        for (i, &v) in out.iter().enumerate() {
            vis[at(slice, i)] = v;
        }
        if let Some(t) = tops.as_deref_mut() {
            for (i, &v) in next.iter().enumerate() {
                t[at(slice, i)] = v;
            }
        }
        std::mem::swap(&mut top, &mut next);
    }
    vis
}

/// Unit vector toward a sun at compass `azimuth_deg` and `elevation_deg`, in (east, up, south).
fn light_from(azimuth_deg: f32, elevation_deg: f32) -> [f32; 3] {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    [az.sin() * el.cos(), el.sin(), -az.cos() * el.cos()]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Upward unit normal (east, up, south) of `f` at (c, r) by central differences, one-sided at
/// the grid's edge and next to nodata, flat along an axis with no neighbour.
fn normal(f: &[f32], w: usize, h: usize, c: usize, r: usize, dx: f32, dy: f32) -> [f32; 3] {
    let here = f[r * w + c];
    let diff = |a: Option<f32>, b: Option<f32>, step: f32| -> f32 {
        match (a.filter(|v| !v.is_nan()), b.filter(|v| !v.is_nan())) {
            (Some(a), Some(b)) => (b - a) / (2.0 * step),
            (Some(a), None) => (here - a) / step,
            (None, Some(b)) => (b - here) / step,
            (None, None) => 0.0,
        }
    };
    let gx = diff(
        c.checked_sub(1).map(|c| f[r * w + c]),
        (c + 1 < w).then(|| f[r * w + c + 1]),
        dx,
    );
    let gz = diff(
        r.checked_sub(1).map(|r| f[r * w + c]),
        (r + 1 < h).then(|| f[(r + 1) * w + c]),
        dy,
    );
    let n = [-gx, 1.0, -gz];
    let len = dot(n, n).sqrt();
    [n[0] / len, n[1] / len, n[2] / len]
}

/// Renders `region` of `layer`, computed on `window`; `None` when no pixel of it falls on the
/// DEM. A whole DEM is drawn from level 0; a DEM read by ranges from the level of the region's
/// zoom ([`Tiled`]), whose [`Window::Whole`] would be the whole level (tests only).
pub fn render_region(
    src: &MapSource,
    layer: Layer,
    region: &Region,
    window: Window,
) -> Result<Option<RgbaImage>, MapError> {
    let (l, level) = src.level(region.z, region.tile_size, layer);
    let nodes = Nodes::new(src, level, region);
    let (w, h) = (level.width, level.height);
    // The cells under the region (their bilinear neighbours included).
    let mut lo = (f64::INFINITY, f64::INFINITY);
    let mut hi = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    for &(c, r) in nodes
        .pos
        .iter()
        .filter(|p| p.0.is_finite() && p.1.is_finite())
    {
        lo = (lo.0.min(c), lo.1.min(r));
        hi = (hi.0.max(c), hi.1.max(r));
    }
    let (wf, hf) = (w as f64, h as f64);
    if !(lo.0 <= wf - 0.5 && hi.0 >= -0.5 && lo.1 <= hf - 0.5 && hi.1 >= -0.5) {
        return Ok(None);
    }
    let cells = match window {
        Window::Whole => Cells {
            c0: 0,
            r0: 0,
            c1: w,
            r1: h,
        },
        Window::Halo => {
            let halo = level.halo() as f64 + 1.0;
            let clip = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
            Cells {
                c0: clip((lo.0 - halo).floor(), w),
                r0: clip((lo.1 - halo).floor(), h),
                c1: clip((hi.0 + halo).ceil() + 1.0, w),
                r1: clip((hi.1 + halo).ceil() + 1.0, h),
            }
        }
    };
    let field = layer_field(src, (l, level), layer, cells)?;
    Ok(Some(resample(&field, layer, &nodes, region, (w, h))))
}

/// Tile (`x`, `y`) of zoom `z`, `size` pixels, computed on its window with the halo: `None`
/// when the tile does not exist or no pixel of it falls on the DEM.
pub fn render_tile(
    src: &MapSource,
    layer: Layer,
    z: u8,
    x: u64,
    y: u64,
    size: u32,
) -> Result<Option<RgbaImage>, MapError> {
    match Region::tile(z, x, y, size) {
        Some(region) => render_region(src, layer, &region, Window::Halo),
        None => Ok(None),
    }
}

/// The tile as PNG bytes (see [`render_tile`]).
pub fn tile_png(
    src: &MapSource,
    layer: Layer,
    z: u8,
    x: u64,
    y: u64,
    size: u32,
) -> Result<Option<Vec<u8>>, MapError> {
    Ok(render_tile(src, layer, z, x, y, size)?
        .map(|img| crate::formats::png_write::encode_rgba(&img)))
}

/// Bilinear resampling of `field` (grid points at cell centres) into the region's pixels.
fn resample(
    field: &Field,
    layer: Layer,
    nodes: &Nodes,
    region: &Region,
    (w, h): (usize, usize),
) -> RgbaImage {
    let (rw, rh) = (region.width, region.height);
    let mut data = vec![0u8; rw as usize * rh as usize * 4];
    let fw = field.cells.width();
    let ch = field.channels;
    data.par_chunks_mut(rw as usize * 4)
        .enumerate()
        .for_each(|(j, row)| {
            let mut v = [0f32; 3];
            for i in 0..rw {
                let (c, r) = nodes.at(i, j as u32);
                if !sample(field, (w, h), fw, ch, c, r, &mut v) {
                    continue;
                }
                let px = &mut row[i as usize * 4..i as usize * 4 + 4];
                px.copy_from_slice(&encode(layer, &v));
            }
        });
    RgbaImage {
        width: rw,
        height: rh,
        data,
    }
}

/// Bilinear value at grid position (`c`, `r`) into `out`; false when transparent (outside the
/// DEM's extent, or the nearest grid point is nodata). Nodata neighbours are left out of the
/// weights.
fn sample(
    field: &Field,
    (w, h): (usize, usize),
    fw: usize,
    ch: usize,
    c: f64,
    r: f64,
    out: &mut [f32; 3],
) -> bool {
    let (wf, hf) = (w as f64, h as f64);
    if !(c >= -0.5 && c <= wf - 0.5 && r >= -0.5 && r <= hf - 0.5) {
        return false;
    }
    let c = c.clamp(0.0, wf - 1.0);
    let r = r.clamp(0.0, hf - 1.0);
    let cl = &field.cells;
    let c0 = (c.floor() as usize).min(w.saturating_sub(2));
    let r0 = (r.floor() as usize).min(h.saturating_sub(2));
    let (fx, fy) = ((c - c0 as f64) as f32, (r - r0 as f64) as f32);
    let c1 = (c0 + 1).min(w - 1);
    let r1 = (r0 + 1).min(h - 1);
    // Every point needed must be in the window (the halo guarantees it for tiles).
    if c0 < cl.c0 || c1 >= cl.c1 || r0 < cl.r0 || r1 >= cl.r1 {
        return false;
    }
    let at = |cc: usize, rr: usize, k: usize| -> f32 {
        field.values[((rr - cl.r0) * fw + (cc - cl.c0)) * ch + k]
    };
    let (nc, nr) = (
        if fx < 0.5 { c0 } else { c1 },
        if fy < 0.5 { r0 } else { r1 },
    );
    if at(nc, nr, 0).is_nan() {
        return false;
    }
    let corners = [
        (c0, r0, (1.0 - fx) * (1.0 - fy)),
        (c1, r0, fx * (1.0 - fy)),
        (c0, r1, (1.0 - fx) * fy),
        (c1, r1, fx * fy),
    ];
    for (k, o) in out.iter_mut().enumerate().take(ch) {
        let (mut s, mut wsum) = (0.0f32, 0.0f32);
        for &(cc, rr, wt) in &corners {
            let v = at(cc, rr, k);
            if !v.is_nan() && wt > 0.0 {
                s += v * wt;
                wsum += wt;
            }
        }
        *o = if wsum > 0.0 { s / wsum } else { at(nc, nr, k) };
    }
    true
}

/// The pixel of `layer` for the interpolated value `v`.
fn encode(layer: Layer, v: &[f32; 3]) -> [u8; 4] {
    let byte = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    match layer {
        Layer::Snow => [255, 255, 255, byte(v[0])],
        Layer::Hillshade => {
            let g = byte(v[0]);
            [g, g, g, 255]
        }
        Layer::Relief => [
            linear_to_srgb8(v[0]),
            linear_to_srgb8(v[1]),
            linear_to_srgb8(v[2]),
            255,
        ],
        Layer::TerrainRgb => {
            let [r, g, b] = terrain_rgb(v[0]);
            [r, g, b, 255]
        }
        Layer::Terrarium => {
            let [r, g, b] = terrarium(v[0]);
            [r, g, b, 255]
        }
    }
}

/// An elevation in metres as a 24-bit big-endian integer in RGB: `(h + offset) × steps` per
/// metre, rounded and clamped to the 24-bit range (the rule Terrain-RGB and Terrarium share).
fn pack24(h: f32, offset: f64, steps: f64) -> [u8; 3] {
    let v = ((f64::from(h) + offset) * steps)
        .round()
        .clamp(0.0, 16_777_215.0) as u32;
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

/// The elevation of [`pack24`]'s RGB, metres.
fn unpack24([r, g, b]: [u8; 3], offset: f64, steps: f64) -> f64 {
    (f64::from(r) * 65_536.0 + f64::from(g) * 256.0 + f64::from(b)) / steps - offset
}

/// Mapbox Terrain-RGB of an elevation in metres: 0.1 m steps from −10 000 m (clamped to the
/// 24-bit range).
pub fn terrain_rgb(h: f32) -> [u8; 3] {
    pack24(h, 10_000.0, 10.0)
}

/// Elevation of a Terrain-RGB pixel, metres.
pub fn decode_terrain_rgb(rgb: [u8; 3]) -> f64 {
    unpack24(rgb, 10_000.0, 10.0)
}

/// Terrarium of an elevation in metres: 1/256 m steps from −32 768 m (clamped).
pub fn terrarium(h: f32) -> [u8; 3] {
    pack24(h, 32_768.0, 256.0)
}

/// Elevation of a Terrarium pixel, metres.
pub fn decode_terrarium(rgb: [u8; 3]) -> f64 {
    unpack24(rgb, 32_768.0, 256.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodings_round_trip_within_their_step() {
        for h in [-432.7f32, 0.0, 0.05, 1.0, 1234.56, 8848.86] {
            assert!((decode_terrain_rgb(terrain_rgb(h)) - f64::from(h)).abs() <= 0.05 + 1e-6);
            assert!((decode_terrarium(terrarium(h)) - f64::from(h)).abs() <= 0.5 / 256.0 + 1e-6);
        }
        // Terrarium's bytes are R·256 + G + B/256 − 32768 exactly.
        assert_eq!(terrarium(0.0), [128, 0, 0]);
        assert_eq!(terrain_rgb(0.0), [1, 134, 160]);
    }

    #[test]
    fn layers_parse_by_name() {
        for l in Layer::ALL {
            assert_eq!(Layer::parse(l.name()), Some(l));
        }
        assert_eq!(Layer::parse("snowy"), None);
        assert_eq!(Layer::TerrainRgb.encoding(), Some("mapbox"));
    }

    #[test]
    fn tiles_outside_the_matrix_do_not_exist() {
        assert!(Region::tile(0, 0, 0, 256).is_some());
        assert!(Region::tile(0, 1, 0, 256).is_none());
        assert!(Region::tile(3, 7, 7, 512).is_some());
        assert!(Region::tile(3, 7, 7, 300).is_none());
        assert!(Region::tile(25, 0, 0, 256).is_none());
    }
}
