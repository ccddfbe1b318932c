//! The terrain renderer's inputs and choices: the height field with its colours
//! ([`TerrainScene`]), the light ([`Lighting`]), a ray hit ([`Hit`]) and the render path
//! ([`RenderPath`]); see [`super`].

use crate::geom::vec::DVec3;

/// A DEM prepared for rendering. Grid point (`col`, `row`) sits at world
/// `(col·dx − (width−1)·dx/2, heights[row·width + col], row·dy − (height−1)·dy/2)`.
#[derive(Debug, Clone, Copy)]
pub struct TerrainScene<'a> {
    /// Grid points along X (east).
    pub width: usize,
    /// Grid points along Z (south).
    pub height: usize,
    /// Cell size along X, metres (> 0).
    pub dx: f64,
    /// Cell size along Z, metres (> 0).
    pub dy: f64,
    /// `width × height` heights in world units: original heights × vertical exaggeration; NaN = hole.
    pub heights: &'a [f32],
    /// `width × height` linear-RGB albedos (0..1), interpolated bilinearly across cells.
    pub albedo: &'a [[f32; 3]],
}

impl TerrainScene<'_> {
    /// Axis-aligned bounds `(min, max)` of the valid grid points in world units; `None` when every
    /// height is nodata. O(n).
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let (lo, hi) = height_range(self.heights)?;
        let hx = (self.width.saturating_sub(1)) as f64 * self.dx * 0.5;
        let hz = (self.height.saturating_sub(1)) as f64 * self.dy * 0.5;
        Some(([-hx, f64::from(lo), -hz], [hx, f64::from(hi), hz]))
    }

    /// Centre and radius of a sphere around [`Self::bounds`] (for orbit cameras); the origin and
    /// radius 1 when the DEM is all nodata. O(n).
    pub fn bounding_sphere(&self) -> ([f64; 3], f64) {
        match self.bounds() {
            Some((lo, hi)) => {
                let c = [0.0, 0.5 * (lo[1] + hi[1]), 0.0];
                let r = 0.5 * (DVec3::from(hi) - DVec3::from(lo)).length();
                (c, r.max(1e-9))
            }
            None => ([0.0; 3], 1.0),
        }
    }
}

/// Light, sky and image-quality settings for [`super::render_terrain`]. Colours are linear RGB.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lighting {
    /// Unit vector toward the sun (world frame). Default: azimuth 135° (south-east), 40° up.
    pub sun_dir: [f64; 3],
    /// Sun irradiance, linear RGB. Default: `[1.0, 0.96, 0.9]` × 0.9.
    pub sun_color: [f32; 3],
    /// Sky ambient, as a fraction of albedo on a flat surface (slopes see `(1 + n_y)/2` of it).
    /// Default: 0.35.
    pub ambient: f32,
    /// Lambert shading on; `false` draws the flat albedo (the paper's figures). Default: true.
    pub shading: bool,
    /// Aerial perspective strength, 0..1. Default: 0.5.
    pub haze: f32,
    /// Sky colour at the zenith, linear RGB. Default: a mid blue.
    pub sky_top: [f32; 3],
    /// Sky colour at the horizon (and below it), linear RGB. Default: a pale blue-grey.
    pub sky_horizon: [f32; 3],
    /// Extra rays for pixels that need anti-aliasing, 1..=64 (clamped; 1 = no anti-aliasing, one
    /// ray per pixel). Default: 4 (rotated grid).
    pub samples: u32,
    /// Cast shadows. DEMs with fewer grid points than image pixels (and every DEM drawn by the
    /// rasteriser) get one shadow ray per grid point, interpolated bilinearly (soft edges one
    /// cell wide); bigger DEMs one shadow ray per sample that hits (sharp). Default: true.
    pub shadows: bool,
    /// Ambient occlusion of the sky light, 0..1: the sky light is multiplied by
    /// `1 − w + w·SVF` with the horizon-based sky-view factor SVF of the height field
    /// ([`sky_view_factor`], search radius a tenth of the DEM's larger horizontal extent), so
    /// valley floors and hollows get less sky light than ridges. 0 = none (the paper's look).
    /// Default: 0.
    pub ambient_occlusion: f32,
    /// How much the sky light and the haze take the sky's colour, 0..1. 0: a neutral sky light
    /// (`ambient` × albedo) and the paper's haze (toward the grey mean, red and green lowered);
    /// 1: the sky light has the sky's mean colour at the same luminance (shade on snow turns
    /// cool blue, as on a clear day) and the haze fades toward `sky_horizon` (in-scattered sky
    /// light; aerial perspective). Default: 0.
    pub sky_tint: f32,
    /// Shade samples whose pixel spans several grid cells from box-averaged albedo, heights and
    /// sun visibility at the footprint's scale (mipmapping; see "Texture level of detail" in
    /// [`super`] and `lod.rs`), on the ray-casting path. Off: one point sample of the full
    /// grid per ray (the paper's look). Default: false.
    pub texture_lod: bool,
}

impl Default for Lighting {
    fn default() -> Self {
        Self {
            sun_dir: crate::geom::vec::sun_direction(135.0, 40.0),
            sun_color: [0.9, 0.864, 0.81],
            ambient: 0.35,
            shading: true,
            haze: 0.5,
            sky_top: [0.16, 0.32, 0.68],
            sky_horizon: [0.62, 0.72, 0.84],
            samples: 4,
            shadows: true,
            ambient_occlusion: 0.0,
            sky_tint: 0.0,
            texture_lod: false,
        }
    }
}

impl Lighting {
    /// The sky's linear colour at image row fraction `y_frac` (0 top, 1 bottom; see "Sky" in
    /// the module doc).
    #[inline]
    pub fn sky(&self, y_frac: f32) -> [f32; 3] {
        let s = (1.0 - y_frac).clamp(0.0, 1.0);
        let s = s * s.sqrt();
        [
            self.sky_horizon[0] + (self.sky_top[0] - self.sky_horizon[0]) * s,
            self.sky_horizon[1] + (self.sky_top[1] - self.sky_horizon[1]) * s,
            self.sky_horizon[2] + (self.sky_top[2] - self.sky_horizon[2]) * s,
        ]
    }

    /// The sky light's colour factor per channel (`[1, 1, 1]` without `sky_tint`): the mean of
    /// `sky_top` and `sky_horizon` scaled to luminance 1 (Rec. 709 weights), mixed with white by
    /// `sky_tint`.
    pub fn ambient_tint(&self) -> [f32; 3] {
        if self.sky_tint <= 0.0 {
            return [1.0; 3];
        }
        let m: [f32; 3] = std::array::from_fn(|c| 0.5 * (self.sky_top[c] + self.sky_horizon[c]));
        let y = (0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2]).max(1e-6);
        let t = self.sky_tint.clamp(0.0, 1.0);
        m.map(|v| 1.0 + t * (v / y - 1.0))
    }
}

/// A ray/terrain intersection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray, world units.
    pub t: f64,
    /// The cell: its north-west grid point.
    pub col: usize,
    pub row: usize,
    /// Position inside the cell, 0..1 east and south.
    pub fx: f64,
    pub fz: f64,
}

/// Which renderer draws the terrain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RenderPath {
    /// The rasteriser when the grid has fewer than [`RASTER_CELLS_PER_PIXEL`] cells per output
    /// pixel, else the ray caster. Default.
    #[default]
    Auto,
    /// Always the ray caster.
    RayCast,
    /// The rasteriser, unless the image or grid is beyond its limits ([`super::raster::MAX_SIDE`],
    /// [`super::raster::MAX_TRIANGLES`]).
    Raster,
}

/// The path-selection threshold: rasterise when `cells < RASTER_CELLS_PER_PIXEL × pixels`.
/// See the module doc of [`super`] ("Two paths") for the measured crossover.
pub const RASTER_CELLS_PER_PIXEL: f64 = 1.0;

impl RenderPath {
    /// The concrete path for `cells` grid cells and `pixels` output pixels.
    pub fn resolve(self, cells: usize, pixels: usize) -> RenderPath {
        match self {
            RenderPath::Auto if (cells as f64) < RASTER_CELLS_PER_PIXEL * pixels as f64 => {
                RenderPath::Raster
            }
            RenderPath::Auto => RenderPath::RayCast,
            p => p,
        }
    }
}

/// (lowest, highest) valid height, `None` when every height is NaN. Parallel over chunks (the
/// extremes do not depend on the order).
pub(crate) fn height_range(h: &[f32]) -> Option<(f32, f32)> {
    use rayon::prelude::*;
    let (lo, hi) = h
        .par_chunks(1 << 16)
        .map(|c| {
            c.iter()
                .filter(|v| !v.is_nan())
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                })
        })
        .reduce(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |x, y| (x.0.min(y.0), x.1.max(y.1)),
        );
    (lo <= hi).then_some((lo, hi))
}
