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

use super::descriptor::{self, DescriptorParams};
use super::params::SnowTerrainParams;
use crate::error::{InputError, ParamError};
use crate::formats::dem::{decode_dem, DemOptions};
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

/// A DEM prepared for tiles: the heights, the CRS transformation and the parameters with every
/// whole-DEM value resolved. Built once per map.
#[derive(Debug)]
pub struct MapSource {
    dem: Dem,
    crs: CrsTransform,
    params: SnowTerrainParams,
    /// x = x0 + col·a, y = y0 + row·e (cell corners, CRS units).
    transform: [f64; 4],
    info: MapInfo,
    /// The whole DEM's sun visibility (cast shadows), made by the first `relief` tile.
    sun: std::sync::OnceLock<Vec<f32>>,
}

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
    let opts = DemOptions {
        max_cells: limits.max_input_cells,
        cell_size: p.cell_size,
        vertical_scale: p.vertical_scale,
    };
    let dem = decode_dem(bytes, filename, &opts)?;
    Ok(MapSource::new(dem, &p)?)
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
        let info = map_info(&dem, &crs, transform)?;
        Ok(Self {
            dem,
            crs,
            params,
            transform,
            info,
            sun: std::sync::OnceLock::new(),
        })
    }

    /// Whether `relief` draws cast shadows (`shading` and `shadows` both on).
    fn casts_shadows(&self) -> bool {
        self.params.shading && self.params.shadows
    }

    /// The sun visibility of every cell (see [`sun_visibility`]), computed on the first call.
    pub fn sun_field(&self) -> &[f32] {
        self.sun.get_or_init(|| {
            let azimuth = self.params.descriptor.sun_azimuth_deg.unwrap_or(180.0);
            sun_visibility(&self.dem, azimuth, self.params.sun_elevation_deg as f32)
        })
    }

    pub fn info(&self) -> &MapInfo {
        &self.info
    }

    pub fn dem(&self) -> &Dem {
        &self.dem
    }

    /// The descriptor parameters with the whole DEM's values resolved.
    pub fn descriptor_params(&self) -> &DescriptorParams {
        &self.params.descriptor
    }

    /// Cells a tile's window is grown by on each side.
    pub fn halo(&self) -> usize {
        descriptor::reach(&self.params.descriptor) + 2
    }

    /// Fractional (column, row) of cell-centre coordinates (grid point (c, r) at (c, r)) of a
    /// longitude/latitude; `None` where the CRS has no value.
    fn grid_position(&self, lon: f64, lat: f64) -> Option<(f64, f64)> {
        let (x, y) = self.crs.from_lonlat(lon, lat)?;
        let [x0, a, y0, e] = self.transform;
        Some(((x - x0) / a - 0.5, (y - y0) / e - 0.5))
    }
}

/// Bounds, centre and zooms of a DEM.
fn map_info(dem: &Dem, crs: &CrsTransform, t: [f64; 4]) -> Result<MapInfo, CrsError> {
    let (w, h) = (dem.width as f64, dem.height as f64);
    // The outline, 32 points a side: a projected grid's edges are curves in WGS 84.
    let ring = crs
        .outline_lonlat(t, dem.width, dem.height, 32)
        .ok_or(CrsError::Unsupported(dem.georef.epsg.unwrap_or(0)))?;
    let mut b = lonlat_bbox(&ring);
    let lim = mercator::MAX_LATITUDE;
    b[1] = b[1].clamp(-lim, lim);
    b[3] = b[3].clamp(-lim, lim);
    let lat_c = (b[1] + b[3]) / 2.0;
    let cell = (dem.dx * dem.dy).abs().sqrt().max(1e-6);
    let zoom_for =
        |metres_per_pixel: f64| (mercator::ground_resolution(0, lat_c) / metres_per_pixel).log2();
    let maxzoom = zoom_for(cell).ceil().clamp(0.0, f64::from(MAX_ZOOM)) as u8;
    let extent = (w * dem.dx.abs()).max(h * dem.dy.abs()).max(1e-6);
    let minzoom = (zoom_for(extent / 256.0)
        .floor()
        .clamp(0.0, f64::from(maxzoom))) as u8;
    let crs_name = match dem.georef.epsg {
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
        width: dem.width,
        height: dem.height,
        cell_m: [dem.dx.abs(), dem.dy.abs()],
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
    fn new(src: &MapSource, r: &Region) -> Self {
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
                src.grid_position(lon, lat).unwrap_or((f64::NAN, f64::NAN))
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

/// The layer's per-cell values on `cells`.
fn layer_field(src: &MapSource, layer: Layer, cells: Cells) -> Field {
    let dem = &src.dem;
    let (w, h) = (cells.width(), cells.r1 - cells.r0);
    let mut heights = Vec::with_capacity(w * h);
    for r in cells.r0..cells.r1 {
        heights.extend_from_slice(&dem.heights[r * dem.width + cells.c0..r * dem.width + cells.c1]);
    }
    let p = &src.params;
    let (dx, dy) = (dem.dx as f32, dem.dy as f32);
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
                dx: dem.dx,
                dy: dem.dy,
                georef: dem.georef.clone(),
            };
            // The descriptor of §4.1 on the window, with the whole DEM's values resolved; no
            // cancellation within a tile (a few milliseconds of work).
            let t = match descriptor::compute(&window, &p.descriptor, &crate::NoControl, (0.0, 1.0))
            {
                Ok(d) => d.t,
                Err(_) => vec![f32::NAN; w * h],
            };
            if layer == Layer::Snow {
                (1, t.into_iter().map(|t| 1.0 - t).collect())
            } else {
                let sun = src.casts_shadows().then(|| {
                    let field = src.sun_field();
                    let mut v = Vec::with_capacity(w * h);
                    for r in cells.r0..cells.r1 {
                        v.extend_from_slice(&field[r * dem.width + cells.c0..][..w]);
                    }
                    v
                });
                (3, relief(&window, &t, sun.as_deref(), p))
            }
        }
    };
    debug_assert!(layer.needs_descriptor() || channels == 1);
    Field {
        cells,
        channels,
        values,
    }
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
/// DEM.
pub fn render_region(
    src: &MapSource,
    layer: Layer,
    region: &Region,
    window: Window,
) -> Option<RgbaImage> {
    let nodes = Nodes::new(src, region);
    let (w, h) = (src.dem.width, src.dem.height);
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
        return None;
    }
    let cells = match window {
        Window::Whole => Cells {
            c0: 0,
            r0: 0,
            c1: w,
            r1: h,
        },
        Window::Halo => {
            let halo = src.halo() as f64 + 1.0;
            let clip = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
            Cells {
                c0: clip((lo.0 - halo).floor(), w),
                r0: clip((lo.1 - halo).floor(), h),
                c1: clip((hi.0 + halo).ceil() + 1.0, w),
                r1: clip((hi.1 + halo).ceil() + 1.0, h),
            }
        }
    };
    let field = layer_field(src, layer, cells);
    Some(resample(&field, layer, &nodes, region, (w, h)))
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
) -> Option<RgbaImage> {
    let region = Region::tile(z, x, y, size)?;
    render_region(src, layer, &region, Window::Halo)
}

/// The tile as PNG bytes (see [`render_tile`]).
pub fn tile_png(
    src: &MapSource,
    layer: Layer,
    z: u8,
    x: u64,
    y: u64,
    size: u32,
) -> Option<Vec<u8>> {
    render_tile(src, layer, z, x, y, size).map(|img| crate::formats::png_write::encode_rgba(&img))
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
