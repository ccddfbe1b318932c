//! The terrain renderer (SPEC §1 "Rendering", with the aerial perspective of step 8): a
//! height-field ray caster that draws a DEM at full detail, one ray per sample, without building a
//! mesh, and — for DEMs with fewer cells than output pixels — the triangle rasteriser
//! ([`super::raster`]) drawing the same surface with the same shading.
//!
//! **Surface.** Each grid cell (2 × 2 grid points) is two triangles split along the
//! north-west → south-east diagonal, exactly as [`crate::formats::glb`] triangulates it; a cell with
//! any nodata corner is a hole. Rays intersect those triangles exactly. Shading uses smooth
//! normals (central-difference gradients at the corners, interpolated bilinearly) and bilinear
//! albedo, so the facets do not show.
//!
//! **Acceleration.** A maximum-height mip pyramid ([`TerrainAccel`]): level 1 holds the highest
//! grid point of each 2 × 2 block of cells, level k+1 the maximum of 2 × 2 level-k nodes, up to one
//! root node. A ray is clipped to the DEM's bounding box and walks the pyramid front to back: at a
//! node it computes where it leaves the node; if the ray stays above the node's maximum over that
//! stretch it skips the node (and climbs one level when it enters a new parent), otherwise it
//! descends into the child that contains it; at level 0 it intersects the cell's triangles. Rays
//! start at 16-cell nodes rather than the root (fewer visits: 19 → 15 per ray on the paper case).
//! Cost is O(log n) nodes per ray over smooth terrain (~15 node visits and ~4 cell tests per ray
//! on rugged 50 m terrain), and the pyramid costs n/3 floats (level 0 is the heights themselves);
//! //! building it for 4096² takes ~90 ms of CPU. Rejected for big DEMs: a mesh rasteriser (2
//! triangles per cell per frame is 33 M triangles for a 4096² DEM); rejected everywhere:
//! fixed-step ray marching (misses thin ridges, slow at grazing angles).
//!
//! **Two paths** ([`RenderPath`]). With fewer cells than output pixels
//! (`cells < RASTER_CELLS_PER_PIXEL × pixels`, factor 1) the triangles are cheaper to rasterise
//! than the pixels are to ray cast: [`render_accel`] builds the grid's triangles (both triangles
//! of a cell with a nodata corner are dropped, as `cell_hit` does) and draws them with
//! [`render_adaptive_with`]. A fragment's perspective-correct barycentrics give the cell
//! position (`fx`, `fz`), from which the *same* shading code as a ray hit runs (smooth normals
//! from the same corner gradients, precomputed per grid point; bilinear albedo; the per-grid-point
//! sun map; haze from the eye distance with the same depth range); samples that hit no triangle
//! take the ray caster's miss rule (sky or transparent via `through_footprint`), and the AA
//! pattern and refinement test are shared. The raster path always uses the per-grid-point sun
//! map (it has no per-sample rays), computed in parallel with the triangle setup. Measured
//! crossover on the paper DEM resampled to 900×600 (then the test `timings_crossover`, now `cargo bench --bench snow_terrain -- crossover`; 2 busy cores, CPU ms
//! ray / raster, shadows and 4 samples): 0.25 cells per pixel 152 / 120, 0.5: 196 / 206,
//! 1: 252 / 370, 2: 286 / 654, 4: 334 / 1204. The raster cost grows ~linearly with cells
//! (~230 ns of CPU per cell all in: shadow ray, setup, 5-sample coverage) while the ray caster
//! grows with log(cells), so the measured break-even with shadows is ~0.4 cells per pixel; the
//! factor 1 is kept because the paper case (0.15) is far inside it, the rasteriser draws exact
//! silhouettes at any size, and the per-point sun map is already used by both paths below 1.
//! (Measured before the horizon sweep; with the sweep the shadows cost the raster path almost
//! nothing for axis-aligned suns, which moves the break-even toward fewer cells per pixel.)
//!
//! **Nodata and alpha.** A ray that hits nothing is *transparent* (alpha 0) if it fell through a
//! hole: it entered the DEM's footprint from above the terrain's edge (or over a nodata stretch of
//! the edge) and crossed the horizontal plane of the lowest valid height inside the footprint.
//! Otherwise — beside or above the DEM, or under its valid edge (looking at the cut face) — it
//! shows the *sky*, opaque. Nodata regions and nodata margins are transparent from any view while
//! the horizon stays sky and there is no transparent sliver under the near edge.
//!
//! **Shadows.** A per-grid-point sun visibility map, interpolated bilinearly (soft edges one cell
//! wide), whenever the sun's azimuth runs along a grid axis (0, 90, 180 — the default — or
//! 270°): then a horizon sweep along the grid lines computes it exactly in O(n)
//! ([`TerrainAccel::sun_visibility_sweep`]; 80 k points in well under a millisecond, where one
//! shadow ray per point took ~13 ms of CPU). Other azimuths shoot one shadow ray through the same
//! pyramid per grid point for DEMs with fewer grid points than the image has pixels, else one per
//! hit sample (sharp). Once cells are smaller than pixels the map's one-cell soft edge is below a
//! pixel, so big DEMs lose nothing by the map (4096² → 1080p: per-hit shadow rays were ~0.7 s of
//! the render's ~2 s of CPU).
//!
//! **Sky.** A vertical gradient in *screen space*, `sky_top` at the top row to `sky_horizon` at
//! the bottom (`(1 − y/h)^1.5`): orbit views look down, so a gradient by ray elevation would show
//! only the horizon colour.
//!
//! **Aerial perspective** (SPEC §1 step 8): the depth d ∈ [0, 1] runs from the nearest to the
//! farthest point of the DEM's bounding box as seen from the eye (a view-dependent, scene-
//! independent range, so tiles of a sweep get the same haze); the colour moves toward the mean of
//! its RGB by `haze·d`, then R and G are lowered by `0.2·haze·d` and `0.1·haze·d` so blue stands
//! out.
//!
//! **Anti-aliasing (adaptive).** Pass 1 traces one ray through every pixel centre. Pass 2 adds
//! `samples` rays on a rotated-grid pattern (4 = the classic RGSS; other counts an n-rooks pattern
//! with a rotated-grid stride) to pixels whose centre sample differs from a 4-neighbour's — another
//! kind (terrain, sky, hole), a depth jump, or a visible colour step between centres that lie
//! more than one cell apart ([`Px::differs`]) — and averages them with the centre in linear RGB,
//! premultiplied by coverage. Smooth interiors cost one ray per pixel; silhouettes, the horizon
//! and sub-pixel detail get `samples + 1`. A colour step between centres in the same or adjacent
//! cells is a shading gradient of the (bilinear, continuous) surface, not an edge: super-sampling
//! it moved the paper case's pixels by ≤ 3/255 on all but 0.02 % of them (worst 12/255) while
//! cutting the render's CPU by a quarter. The raster path runs the same test through
//! [`render_adaptive_with`] (the mesh renderer's loop with `Px`'s test). Rejected: a fixed
//! `samples` rays per every pixel (3–4× slower for the same edges). Output is sRGB with straight
//! alpha.
//!
//! **Parallelism.** Rayon over bands of 4 image rows; every pixel is computed independently, so the
//! bytes do not depend on the thread count. No allocation per pixel; `checkpoint` per band.
//!
//! **Measured** (release, 2 busy cores at load 6–8, CPU time ÷ 2 ≈ idle wall time; `timings_*`
//! tests in `engine/tests/it/render.rs`): paper case 400×200 → 900×600 with AA and shadows:
//! ray caster ~136 ms CPU (~68 ms idle wall), raster path ~100 ms CPU (~50 ms); one sample per
//! pixel 81 → 62 ms CPU; without shading 75 → 61 ms CPU. Of the raster path's ~100 ms CPU, the
//! sun map (80 k shadow rays) is ~30, the AA refinement (pattern coverage + extra shading) ~35,
//! centre coverage and shading ~35. 4096² → 1920×1080 (ray cast) with AA and shadows
//! ~1150 ms CPU (~570 ms idle wall) including the pyramid, unchanged by the raster path.

use crate::geom::vec::DVec3;

mod accel;
mod ao;
mod draw;
mod raster_path;
mod shade;
mod sun;

pub use accel::TerrainAccel;
pub use ao::{sky_view_factor, AoMap};
pub use draw::{
    prepare_view, render_accel, render_accel_on_path, render_prepared, render_terrain, PreparedView,
};
use shade::{Px, Shader};

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

/// Light, sky and image-quality settings for [`render_terrain`]. Colours are linear RGB.
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
/// See the module doc ("Two paths") for the measured crossover.
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

pub(crate) fn height_range(h: &[f32]) -> Option<(f32, f32)> {
    let (lo, hi) = h
        .iter()
        .filter(|v| !v.is_nan())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    (lo <= hi).then_some((lo, hi))
}
