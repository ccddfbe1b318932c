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
//! than the pixels are to ray cast: [`render_with`] builds the grid's triangles (both triangles
//! of a cell with a nodata corner are dropped, as `cell_hit` does) and draws them with
//! [`render_adaptive_with`]. A fragment's perspective-correct barycentrics give the cell
//! position (`fx`, `fz`), from which the *same* shading code as a ray hit runs (smooth normals
//! from the same corner gradients, precomputed per grid point; bilinear albedo; the per-grid-point
//! sun map; haze from the eye distance with the same depth range); samples that hit no triangle
//! take the ray caster's miss rule (sky or transparent via `through_footprint`), and the AA
//! pattern and refinement test are shared. The raster path always uses the per-grid-point sun
//! map (it has no per-sample rays), computed in parallel with the triangle setup. Measured
//! crossover on the paper DEM resampled to 900×600 (`timings_crossover`, 2 busy cores, CPU ms
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

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::adaptive::{sample_pattern, write_pixel, RowSink, Sample, Shaded};
use super::camera::{dot, normalize, Camera};
use super::image::RgbaImage;
use super::raster;
use crate::control::{Canceled, Control};

mod ao;
mod raster_path;
pub use ao::{sky_view_factor, AoMap};
use raster_path::{render_raster, RasterSetup};

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
                let r = 0.5 * dot(sub3(hi, lo), sub3(hi, lo)).sqrt();
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
            sun_dir: sun_direction(135.0, 40.0),
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

/// Unit vector toward a sun at compass `azimuth_deg` (0 = north, 90 = east, 180 = south) and
/// `elevation_deg` above the horizon.
pub fn sun_direction(azimuth_deg: f64, elevation_deg: f64) -> [f64; 3] {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    [el.cos() * az.sin(), el.sin(), -el.cos() * az.cos()]
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

/// Pyramid level at which rays start (nodes of 2^4 = 16 cells).
const START_LEVEL: usize = 4;

struct Level {
    w: usize,
    h: usize,
    max: Vec<f32>,
}

/// The maximum-height pyramid over a [`TerrainScene`] and the ray queries on it. Building costs one
/// pass over the heights (parallel) and n/3 floats; queries are read-only and thread-safe.
pub struct TerrainAccel<'a> {
    scene: TerrainScene<'a>,
    /// Cells along X and Z (grid points − 1).
    cw: usize,
    ch: usize,
    /// `levels[k]` has nodes of `2^(k+1)` cells; the last one is a single node.
    levels: Vec<Level>,
    /// Node counts (x, z) per level, level 0 = cells; `dims[level]`.
    dims: Vec<(usize, usize)>,
    hmin: f64,
    hmax: f64,
    half_x: f64,
    half_z: f64,
    /// Smallest cell size, for epsilons.
    cell: f64,
    /// Slack on height comparisons (rounding of `o + t·d`), world units.
    eps_y: f64,
}

impl<'a> TerrainAccel<'a> {
    /// Build the pyramid. Panics when `heights` or `albedo` is not `width × height` long or a cell
    /// size is not positive (caller bugs, not input errors).
    pub fn new(scene: &TerrainScene<'a>) -> Self {
        let n = scene.width * scene.height;
        assert_eq!(scene.albedo.len(), n, "albedo must be width × height");
        Self::new_geometry(scene)
    }

    /// [`Self::new`] for a scene whose `albedo` is not known yet (it may be empty): enough for
    /// [`prepare_view`], which reads the heights only. Give it the colours with
    /// [`Self::with_albedo`] before drawing.
    pub fn new_geometry(scene: &TerrainScene<'a>) -> Self {
        let n = scene.width * scene.height;
        assert_eq!(scene.heights.len(), n, "heights must be width × height");
        assert!(
            scene.dx > 0.0 && scene.dy > 0.0,
            "cell sizes must be positive"
        );
        let cw = scene.width.saturating_sub(1);
        let ch = scene.height.saturating_sub(1);
        let (hmin, hmax) =
            height_range(scene.heights).map_or((0.0, -1.0), |(a, b)| (f64::from(a), f64::from(b)));
        let mut levels: Vec<Level> = Vec::new();
        if cw > 0 && ch > 0 && hmax >= hmin {
            // Level 1 straight from the grid points: node (i, j) covers points [2i, 2i+2]².
            let (w, h) = (cw.div_ceil(2), ch.div_ceil(2));
            let mut max = vec![f32::NEG_INFINITY; w * h];
            let (gw, gh) = (scene.width, scene.height);
            max.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
                let r1 = (2 * j + 2).min(gh - 1);
                for (i, m) in row.iter_mut().enumerate() {
                    let c1 = (2 * i + 2).min(gw - 1);
                    let mut acc = f32::NEG_INFINITY;
                    for r in 2 * j..=r1 {
                        for &v in &scene.heights[r * gw + 2 * i..=r * gw + c1] {
                            // `max` ignores NaN operands.
                            acc = acc.max(v);
                        }
                    }
                    *m = acc;
                }
            });
            levels.push(Level { w, h, max });
            while levels.last().is_some_and(|l| l.w > 1 || l.h > 1) {
                let Some(prev) = levels.last() else { break };
                let (w, h) = (prev.w.div_ceil(2), prev.h.div_ceil(2));
                let mut max = vec![f32::NEG_INFINITY; w * h];
                max.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
                    for (i, m) in row.iter_mut().enumerate() {
                        let mut acc = f32::NEG_INFINITY;
                        for cj in 2 * j..(2 * j + 2).min(prev.h) {
                            for ci in 2 * i..(2 * i + 2).min(prev.w) {
                                acc = acc.max(prev.max[cj * prev.w + ci]);
                            }
                        }
                        *m = acc;
                    }
                });
                levels.push(Level { w, h, max });
            }
        }
        let dims = std::iter::once((cw, ch))
            .chain(levels.iter().map(|l| (l.w, l.h)))
            .collect();
        Self {
            scene: *scene,
            cw,
            ch,
            levels,
            dims,
            hmin,
            hmax,
            half_x: cw as f64 * scene.dx * 0.5,
            half_z: ch as f64 * scene.dy * 0.5,
            cell: scene.dx.min(scene.dy),
            eps_y: 1e-9 * (hmin.abs().max(hmax.abs()) + scene.dx.max(scene.dy)),
        }
    }

    /// This pyramid (heights unchanged) over the scene with `albedo` (the pyramid does not depend
    /// on it). Panics when `albedo` is not `width × height` long (a caller bug).
    pub fn with_albedo<'b>(self, albedo: &'b [[f32; 3]]) -> TerrainAccel<'b>
    where
        'a: 'b,
    {
        let this: TerrainAccel<'b> = self;
        assert_eq!(
            albedo.len(),
            this.scene.width * this.scene.height,
            "albedo must be width × height"
        );
        TerrainAccel {
            scene: TerrainScene {
                albedo,
                ..this.scene
            },
            ..this
        }
    }

    /// The scene this pyramid was built over.
    pub fn scene(&self) -> &TerrainScene<'a> {
        &self.scene
    }

    /// First intersection of the ray `origin + t·dir` (`dir` unit length) with `t` in
    /// `[tmin, tmax]`. O(log n) node visits on typical terrain; no allocation.
    pub fn intersect(&self, origin: [f64; 3], dir: [f64; 3], tmin: f64, tmax: f64) -> Option<Hit> {
        if self.levels.is_empty() {
            return None;
        }
        let r = self.grid_ray(origin, dir);
        let (t0, t1) = self.clip(&r, tmin, tmax)?;
        let top = self.levels.len();
        // Start at 16-cell nodes rather than the root: from the root every ray first spends
        // ~log2(n) visits descending; the ascent rule climbs again where the ray is high.
        // Measured: 19 → 15 node visits per ray on the paper case.
        let mut level = top.min(START_LEVEL);
        let (lw, lh) = self.dims(level);
        let s0 = (1u64 << level) as f64;
        let mut ci = (((r.ou + r.du * t0) / s0).floor().max(0.0) as usize).min(lw - 1);
        let mut cj = (((r.ov + r.dv * t0) / s0).floor().max(0.0) as usize).min(lh - 1);
        let mut t = t0;
        loop {
            let s = (1u64 << level) as f64;
            let tx = exit_t(ci, s, r.ou, r.du, r.inv_du);
            let tz = exit_t(cj, s, r.ov, r.dv, r.inv_dv);
            let texit = tx.min(tz);
            let tend = texit.min(t1);
            if level == 0 {
                let (ya, yb) = (r.oy + r.dy * t, r.oy + r.dy * tend);
                if let Some(hit) = self.cell_hit(ci, cj, &r, ya.min(yb), ya.max(yb), tmin, tmax) {
                    return Some(hit);
                }
            } else {
                let lv = &self.levels[level - 1];
                let m = f64::from(lv.max[cj * lv.w + ci]);
                let ylo = (r.oy + r.dy * t).min(r.oy + r.dy * tend);
                if ylo <= m + self.eps_y {
                    // Descend into the child holding the ray at `t`.
                    level -= 1;
                    let (cw, ch) = self.dims(level);
                    ci = child(ci, s, r.ou + r.du * t, r.du).min(cw - 1);
                    cj = child(cj, s, r.ov + r.dv * t, r.dv).min(ch - 1);
                    continue;
                }
            }
            if texit >= t1 {
                return None;
            }
            t = texit;
            let (w, h) = self.dims(level);
            let mut new_parent = false;
            if tx <= tz {
                new_parent |= step_axis(&mut ci, r.du > 0.0, w)?;
            }
            if tz <= tx {
                new_parent |= step_axis(&mut cj, r.dv > 0.0, h)?;
            }
            if new_parent && level < top {
                level += 1;
                ci >>= 1;
                cj >>= 1;
            }
        }
    }

    /// Reference for tests: the nearest hit over *every* cell, O(n) per ray.
    pub fn intersect_brute(
        &self,
        origin: [f64; 3],
        dir: [f64; 3],
        tmin: f64,
        tmax: f64,
    ) -> Option<Hit> {
        let r = self.grid_ray(origin, dir);
        let mut best: Option<Hit> = None;
        for j in 0..self.ch {
            for i in 0..self.cw {
                if let Some(h) = self.cell_hit(i, j, &r, f64::MIN, f64::MAX, tmin, tmax) {
                    if best.is_none_or(|b| h.t < b.t) {
                        best = Some(h);
                    }
                }
            }
        }
        best
    }

    /// World position of a hit's surface point.
    pub fn hit_position(&self, hit: &Hit) -> [f64; 3] {
        let s = &self.scene;
        let k = hit.row * s.width + hit.col;
        let (h00, h10, h01, h11) = (
            f64::from(s.heights[k]),
            f64::from(s.heights[k + 1]),
            f64::from(s.heights[k + s.width]),
            f64::from(s.heights[k + s.width + 1]),
        );
        let (fx, fz) = (hit.fx, hit.fz);
        let y = if fx >= fz {
            h00 + (h10 - h00) * fx + (h11 - h10) * fz
        } else {
            h00 + (h11 - h01) * fx + (h01 - h00) * fz
        };
        [
            (hit.col as f64 + fx) * s.dx - self.half_x,
            y,
            (hit.row as f64 + fz) * s.dy - self.half_z,
        ]
    }

    /// Smooth unit normal at a hit: corner gradients (central differences, one-sided at borders
    /// and next to holes) interpolated bilinearly.
    pub fn hit_normal(&self, hit: &Hit) -> [f64; 3] {
        let (c, r) = (hit.col, hit.row);
        let g00 = self.gradient(c, r);
        let g10 = self.gradient(c + 1, r);
        let g01 = self.gradient(c, r + 1);
        let g11 = self.gradient(c + 1, r + 1);
        let (fx, fz) = (hit.fx, hit.fz);
        let w = [
            (1.0 - fx) * (1.0 - fz),
            fx * (1.0 - fz),
            (1.0 - fx) * fz,
            fx * fz,
        ];
        let gx = w[0] * g00.0 + w[1] * g10.0 + w[2] * g01.0 + w[3] * g11.0;
        let gz = w[0] * g00.1 + w[1] * g10.1 + w[2] * g01.1 + w[3] * g11.1;
        normalize([-gx, 1.0, -gz])
    }

    /// [`Self::gradient`] at every grid point, parallel over rows. Allocates 16 B per point.
    fn gradients(&self) -> Vec<[f64; 2]> {
        let s = &self.scene;
        let mut g = vec![[0.0; 2]; s.width * s.height];
        g.par_chunks_mut(s.width.max(1))
            .enumerate()
            .for_each(|(r, row)| {
                for (c, v) in row.iter_mut().enumerate() {
                    let (gx, gz) = self.gradient(c, r);
                    *v = [gx, gz];
                }
            });
        g
    }

    /// True when nothing lies between surface point `p` and the sun (`sun` unit). One shadow ray
    /// through the pyramid, started `eps` above the surface.
    pub fn sunlit(&self, p: [f64; 3], sun: [f64; 3], eps: f64) -> bool {
        let o = [
            p[0] + sun[0] * eps,
            p[1] + sun[1] * eps + eps,
            p[2] + sun[2] * eps,
        ];
        self.intersect(o, sun, eps, f64::INFINITY).is_none()
    }

    /// Sun visibility (1 lit, 0 shadowed; 1 for nodata) at every grid point. By a horizon sweep
    /// ([`Self::sun_visibility_sweep`], O(n)) when the sun's azimuth runs along a grid axis (the
    /// default south sun), else one shadow ray per point ([`Self::sun_visibility_rays`]).
    /// Allocates `width × height` bytes.
    pub fn sun_visibility(
        &self,
        sun: [f64; 3],
        eps: f64,
        ctl: &dyn Control,
    ) -> Result<Vec<u8>, Canceled> {
        match self.sun_visibility_sweep(sun, eps, ctl)? {
            Some(vis) => Ok(vis),
            None => self.sun_visibility_rays(sun, eps, ctl),
        }
    }

    /// True when [`Self::sun_visibility`] takes the O(n) horizon sweep for this sun.
    pub fn sweeps(&self, sun: [f64; 3]) -> bool {
        sweep_axis(sun).is_some()
    }

    /// Sun visibility by a horizon sweep, the same answer as [`Self::sun_visibility_rays`] (up to
    /// rays that graze a vertex within rounding), or `None` when the sun's horizontal direction
    /// is not along a grid axis (azimuth 0, 90, 180 or 270°) or the sun is not above the horizon.
    ///
    /// Why it is exact: with the sun due south (or north, east, west), the shadow ray of grid
    /// point `r` runs along its own grid line, where the surface is the polyline through the
    /// line's grid points (the two triangles on either side share that edge). The ray, started
    /// `eps` above the point as in [`Self::sunlit`], has height `h_r + eps + D·tan(elevation)` at
    /// horizontal distance `D`, so it meets the polyline iff some grid point `k` beyond `r`
    /// toward the sun has `h_k ≥ h_r + eps + D_k·tan`, i.e. `g_k ≥ g_r + eps` with
    /// `g = h − (position toward the sun)·tan`. One pass from the sun's side keeps the running
    /// maximum of `g`: O(1) per point. Nodata: a grid line segment exists when a cell on either
    /// side of it is valid (all four corners), and a point blocks only if it ends such a segment;
    /// the ground counts as solid, so a ray that crosses a hole below the far side's surface is
    /// blocked (the shadow rays pass under the surface sheet there), and a ray along the edge of
    /// the surface grazes it (the shadow rays test one side, chosen by rounding). On a steep
    /// slope facing away from the sun the sweep says shadowed where a shadow ray may escape: its
    /// crossing lies within `eps` of its start, inside the self-intersection guard. Test:
    /// `sun_sweep_matches_shadow_rays` (everywhere else identical).
    /// Lines run in parallel (rows directly; columns in stripes of 256, whose results are copied
    /// into the row-major map), so the result does not depend on the thread count.
    /// Cost: ~2 reads and a compare per point (4096²: tens of ms); allocates the map (one byte
    /// per point) and, for columns, as much again of stripes.
    pub fn sun_visibility_sweep(
        &self,
        sun: [f64; 3],
        eps: f64,
        ctl: &dyn Control,
    ) -> Result<Option<Vec<u8>>, Canceled> {
        let Some(axis) = sweep_axis(sun) else {
            return Ok(None);
        };
        let s = &self.scene;
        let (w, h) = (s.width, s.height);
        let mut vis = vec![1u8; w * h];
        if w == 0 || h == 0 {
            return Ok(Some(vis));
        }
        let holes = s.heights.par_iter().any(|v| v.is_nan());
        let hs = s.heights;
        // Cell (ci, cj) is drawn when its four corners are valid.
        let cell = |ci: usize, cj: usize| -> bool {
            let k = cj * w + ci;
            !(hs[k] + hs[k + 1] + hs[k + w] + hs[k + w + 1]).is_nan()
        };
        match axis {
            SweepAxis::Vertical => {}
            SweepAxis::Rows { forward, tan } => {
                // Sun due east (forward) or west: each row is its own line.
                let step = s.dx * tan;
                vis.par_chunks_mut(w).enumerate().try_for_each(|(r, row)| {
                    ctl.checkpoint()?;
                    // Segment i..i+1 of row r exists when cell (i, r−1) or (i, r) does.
                    let seg = |i: usize| -> bool {
                        i + 1 < w && ((r > 0 && cell(i, r - 1)) || (r + 1 < h && cell(i, r)))
                    };
                    let line = &hs[r * w..(r + 1) * w];
                    let mut m = f64::NEG_INFINITY;
                    let mut visit = |k: usize| {
                        let v = line[k];
                        if v.is_nan() {
                            return;
                        }
                        let pos = if forward { k as f64 } else { -(k as f64) };
                        let g = f64::from(v) - pos * step;
                        if m >= g + eps {
                            row[k] = 0;
                        }
                        if !holes || (k > 0 && seg(k - 1)) || seg(k) {
                            m = m.max(g);
                        }
                    };
                    if forward {
                        (0..w).rev().for_each(&mut visit);
                    } else {
                        (0..w).for_each(&mut visit);
                    }
                    Ok(())
                })?;
            }
            SweepAxis::Columns { forward, tan } => {
                // Sun due south (forward: toward increasing rows) or north. Stripes of columns,
                // each swept row by row with a running maximum per column.
                const STRIPE: usize = 256;
                let step = s.dy * tan;
                let stripes: Vec<Vec<u8>> = (0..w.div_ceil(STRIPE))
                    .into_par_iter()
                    .map(|si| {
                        ctl.checkpoint()?;
                        let (c0, c1) = (si * STRIPE, ((si + 1) * STRIPE).min(w));
                        let sw = c1 - c0;
                        let mut out = vec![1u8; sw * h];
                        let mut m = vec![f64::NEG_INFINITY; sw];
                        // Segment r..r+1 of column c exists when cell (c−1, r) or (c, r) does.
                        let seg = |c: usize, r: usize| -> bool {
                            r + 1 < h && ((c > 0 && cell(c - 1, r)) || (c + 1 < w && cell(c, r)))
                        };
                        let mut visit = |r: usize| {
                            let pos = if forward { r as f64 } else { -(r as f64) };
                            let line = &hs[r * w + c0..r * w + c1];
                            let o = &mut out[r * sw..(r + 1) * sw];
                            for (j, ((&v, mj), oj)) in line.iter().zip(&mut m).zip(o).enumerate() {
                                let g = f64::from(v) - pos * step;
                                // NaN heights fail the compare and stay lit.
                                if *mj >= g + eps {
                                    *oj = 0;
                                }
                                let c = c0 + j;
                                if !v.is_nan() && (!holes || (r > 0 && seg(c, r - 1)) || seg(c, r))
                                {
                                    *mj = mj.max(g);
                                }
                            }
                        };
                        if forward {
                            (0..h).rev().for_each(&mut visit);
                        } else {
                            (0..h).for_each(&mut visit);
                        }
                        Ok(out)
                    })
                    .collect::<Result<_, Canceled>>()?;
                vis.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
                    for (si, st) in stripes.iter().enumerate() {
                        let (c0, c1) = (si * STRIPE, ((si + 1) * STRIPE).min(w));
                        let sw = c1 - c0;
                        row[c0..c1].copy_from_slice(&st[r * sw..(r + 1) * sw]);
                    }
                });
            }
        }
        Ok(Some(vis))
    }

    /// Sun visibility (1 lit, 0 shadowed; 1 for nodata) at every grid point: one shadow ray per
    /// valid point, parallel over rows, `checkpoint` per row. Allocates `width × height` bytes.
    /// ~0.2 µs per point on rugged terrain.
    pub fn sun_visibility_rays(
        &self,
        sun: [f64; 3],
        eps: f64,
        ctl: &dyn Control,
    ) -> Result<Vec<u8>, Canceled> {
        let s = &self.scene;
        let mut vis = vec![1u8; s.width * s.height];
        vis.par_chunks_mut(s.width.max(1))
            .enumerate()
            .try_for_each(|(r, row)| {
                ctl.checkpoint()?;
                for (c, v) in row.iter_mut().enumerate() {
                    let h = s.heights[r * s.width + c];
                    if !h.is_nan() {
                        let p = [
                            c as f64 * s.dx - self.half_x,
                            f64::from(h),
                            r as f64 * s.dy - self.half_z,
                        ];
                        *v = u8::from(self.sunlit(p, sun, eps));
                    }
                }
                Ok(())
            })?;
        Ok(vis)
    }

    /// [`Self::hit_bilinear`] of a 0/1 byte map (the sun visibility: a quarter of the memory of
    /// floats, so 4096² fits 16 MB and the per-hit lookups miss the cache less).
    #[inline]
    fn hit_bilinear_u8(&self, hit: &Hit, values: &[u8]) -> f32 {
        let w = self.scene.width;
        let k = hit.row * w + hit.col;
        let (fx, fz) = (hit.fx as f32, hit.fz as f32);
        let v = |i: usize| f32::from(values[i]);
        (1.0 - fx) * (1.0 - fz) * v(k)
            + fx * (1.0 - fz) * v(k + 1)
            + (1.0 - fx) * fz * v(k + w)
            + fx * fz * v(k + w + 1)
    }

    /// Bilinear interpolation of a per-grid-point scalar at a hit.
    pub fn hit_bilinear(&self, hit: &Hit, values: &[f32]) -> f32 {
        let w = self.scene.width;
        let k = hit.row * w + hit.col;
        let (fx, fz) = (hit.fx as f32, hit.fz as f32);
        (1.0 - fx) * (1.0 - fz) * values[k]
            + fx * (1.0 - fz) * values[k + 1]
            + (1.0 - fx) * fz * values[k + w]
            + fx * fz * values[k + w + 1]
    }

    /// Bilinear albedo at a hit, linear RGB.
    pub fn hit_albedo(&self, hit: &Hit) -> [f32; 3] {
        let s = &self.scene;
        let k = hit.row * s.width + hit.col;
        let (fx, fz) = (hit.fx as f32, hit.fz as f32);
        let w = [
            (1.0 - fx) * (1.0 - fz),
            fx * (1.0 - fz),
            (1.0 - fx) * fz,
            fx * fz,
        ];
        let a = [
            s.albedo[k],
            s.albedo[k + 1],
            s.albedo[k + s.width],
            s.albedo[k + s.width + 1],
        ];
        let mut out = [0.0f32; 3];
        for (ch, o) in out.iter_mut().enumerate() {
            *o = w[0] * a[0][ch] + w[1] * a[1][ch] + w[2] * a[2][ch] + w[3] * a[3][ch];
        }
        out
    }

    /// True when a ray that hit nothing fell through a hole: it enters the DEM's footprint
    /// (the `x`, `z` rectangle) above the terrain's edge — or over a nodata stretch of the edge, or
    /// starts inside the footprint — and then crosses the plane of the lowest valid height inside
    /// the footprint at `t ≥ tmin`. Rays that pass *under* a valid edge see the cut face of the
    /// DEM and get the sky instead of a transparent sliver.
    pub fn through_footprint(&self, origin: [f64; 3], dir: [f64; 3], tmin: f64) -> bool {
        if self.levels.is_empty() || dir[1] == 0.0 {
            return false;
        }
        let t = (self.hmin - origin[1]) / dir[1];
        if t.is_nan() || t < tmin {
            return false;
        }
        let x = origin[0] + dir[0] * t;
        let z = origin[2] + dir[2] * t;
        if x.abs() > self.half_x || z.abs() > self.half_z {
            return false;
        }
        // Horizontal entry into the footprint: the later of the two slab entries.
        let r = self.grid_ray(origin, dir);
        let entry = |o: f64, d: f64, hi: f64| -> f64 {
            if d > 0.0 {
                -o / d
            } else if d < 0.0 {
                (hi - o) / d
            } else {
                f64::NEG_INFINITY
            }
        };
        let tu = entry(r.ou, r.du, self.cw as f64);
        let tv = entry(r.ov, r.dv, self.ch as f64);
        let te = tu.max(tv);
        if te <= tmin {
            return true; // starts inside the footprint
        }
        let s = &self.scene;
        let (u, v) = (r.ou + r.du * te, r.ov + r.dv * te);
        // Height of the edge line at the entry point (linear between its grid points).
        let edge = |along: f64, n: usize, at: &dyn Fn(usize) -> f32| -> f64 {
            let a = along.clamp(0.0, n as f64);
            let i = (a.floor() as usize).min(n.saturating_sub(1));
            let f = a - i as f64;
            let (h0, h1) = (f64::from(at(i)), f64::from(at((i + 1).min(n))));
            h0 + (h1 - h0) * f
        };
        let h_edge = if tu >= tv {
            let col = if r.du > 0.0 { 0 } else { self.cw };
            edge(v, self.ch, &|j| s.heights[j * s.width + col])
        } else {
            let row = if r.dv > 0.0 { 0 } else { self.ch };
            edge(u, self.cw, &|i| s.heights[row * s.width + i])
        };
        // A NaN edge (nodata margin) counts as falling through.
        h_edge.is_nan() || r.oy + r.dy * te >= h_edge - self.eps_y
    }

    /// Distances from `eye` to the nearest and farthest points of the bounding box.
    fn depth_range(&self, eye: [f64; 3]) -> (f64, f64) {
        let lo = [-self.half_x, self.hmin, -self.half_z];
        let hi = [self.half_x, self.hmax.max(self.hmin), self.half_z];
        let mut near2 = 0.0;
        let mut far2 = 0.0;
        for a in 0..3 {
            let d = if eye[a] < lo[a] {
                lo[a] - eye[a]
            } else if eye[a] > hi[a] {
                eye[a] - hi[a]
            } else {
                0.0
            };
            near2 += d * d;
            let f = (eye[a] - lo[a]).abs().max((eye[a] - hi[a]).abs());
            far2 += f * f;
        }
        (near2.sqrt(), far2.sqrt())
    }

    #[inline]
    fn dims(&self, level: usize) -> (usize, usize) {
        self.dims[level]
    }

    #[inline]
    fn grid_ray(&self, o: [f64; 3], d: [f64; 3]) -> GridRay {
        let s = &self.scene;
        let du = d[0] / s.dx;
        let dv = d[2] / s.dy;
        GridRay {
            ou: (o[0] + self.half_x) / s.dx,
            ov: (o[2] + self.half_z) / s.dy,
            oy: o[1],
            du,
            dv,
            dy: d[1],
            inv_du: 1.0 / du,
            inv_dv: 1.0 / dv,
        }
    }

    /// Clip the ray to the bounding box: `(t0, t1)` or `None` when it misses.
    #[inline]
    fn clip(&self, r: &GridRay, tmin: f64, tmax: f64) -> Option<(f64, f64)> {
        let mut t0 = tmin;
        let mut t1 = tmax;
        for (o, d, inv, lo, hi) in [
            (r.ou, r.du, r.inv_du, 0.0, self.cw as f64),
            (r.ov, r.dv, r.inv_dv, 0.0, self.ch as f64),
            (
                r.oy,
                r.dy,
                1.0 / r.dy,
                self.hmin - self.eps_y,
                self.hmax + self.eps_y,
            ),
        ] {
            if d == 0.0 {
                if o < lo || o > hi {
                    return None;
                }
            } else {
                let (a, b) = ((lo - o) * inv, (hi - o) * inv);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        (t0 <= t1).then_some((t0, t1))
    }

    /// Exact intersection with the two triangles of cell (`i`, `j`), `t` in `[tmin, tmax]`.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn cell_hit(
        &self,
        i: usize,
        j: usize,
        r: &GridRay,
        ylo: f64,
        yhi: f64,
        tmin: f64,
        tmax: f64,
    ) -> Option<Hit> {
        const EPS: f64 = 1e-9;
        let w = self.scene.width;
        let k = j * w + i;
        let hs = self.scene.heights;
        let (h00, h10, h01, h11) = (
            f64::from(hs[k]),
            f64::from(hs[k + 1]),
            f64::from(hs[k + w]),
            f64::from(hs[k + w + 1]),
        );
        // Quick reject on the ray's height range over the cell (NaN corners fail both tests).
        let (hlo, hhi) = (
            h00.min(h10).min(h01.min(h11)),
            h00.max(h10).max(h01.max(h11)),
        );
        if ylo > hhi + self.eps_y || yhi < hlo - self.eps_y || (h00 + h10 + h01 + h11).is_nan() {
            return None;
        }
        let a = r.ou - i as f64;
        let c = r.ov - j as f64;
        let mut best: Option<Hit> = None;
        // Triangle A (fx ≥ fz): points 00, 10, 11. Triangle B (fx < fz): points 00, 01, 11.
        for (ga, gb, upper) in [(h10 - h00, h11 - h10, true), (h11 - h01, h01 - h00, false)] {
            let denom = r.dy - ga * r.du - gb * r.dv;
            if denom == 0.0 {
                continue;
            }
            let t = (h00 + ga * a + gb * c - r.oy) / denom;
            if !(t >= tmin && t <= tmax) {
                continue;
            }
            let fx = a + r.du * t;
            let fz = c + r.dv * t;
            let inside = (-EPS..=1.0 + EPS).contains(&fx) && (-EPS..=1.0 + EPS).contains(&fz);
            let side = if upper {
                fx - fz >= -EPS
            } else {
                fz - fx >= -EPS
            };
            if inside && side && best.is_none_or(|b| t < b.t) {
                best = Some(Hit {
                    t,
                    col: i,
                    row: j,
                    fx: fx.clamp(0.0, 1.0),
                    fz: fz.clamp(0.0, 1.0),
                });
            }
        }
        best
    }

    /// (dh/dx, dh/dz) at grid point (`c`, `r`), world units.
    #[inline]
    fn gradient(&self, c: usize, r: usize) -> (f64, f64) {
        let s = &self.scene;
        let w = s.width;
        let h = |c: usize, r: usize| f64::from(s.heights[r * w + c]);
        let centre = h(c, r);
        let diff = |lo: Option<f64>, hi: Option<f64>, step: f64| -> f64 {
            match (lo.filter(|v| !v.is_nan()), hi.filter(|v| !v.is_nan())) {
                (Some(a), Some(b)) => (b - a) / (2.0 * step),
                (Some(a), None) => (centre - a) / step,
                (None, Some(b)) => (b - centre) / step,
                (None, None) => 0.0,
            }
        };
        let gx = diff(
            (c > 0).then(|| h(c - 1, r)),
            (c + 1 < w).then(|| h(c + 1, r)),
            s.dx,
        );
        let gz = diff(
            (r > 0).then(|| h(c, r - 1)),
            (r + 1 < s.height).then(|| h(c, r + 1)),
            s.dy,
        );
        (gx, gz)
    }
}

/// A ray in grid coordinates: u = column (east), v = row (south), y = world height; the parameter
/// t is still the world distance.
struct GridRay {
    ou: f64,
    ov: f64,
    oy: f64,
    du: f64,
    dv: f64,
    dy: f64,
    inv_du: f64,
    inv_dv: f64,
}

/// Where a ray leaves node `c` (of `s` cells) along one axis; +∞ when parallel to it.
#[inline]
fn exit_t(c: usize, s: f64, o: f64, d: f64, inv: f64) -> f64 {
    if d > 0.0 {
        ((c + 1) as f64 * s - o) * inv
    } else if d < 0.0 {
        (c as f64 * s - o) * inv
    } else {
        f64::INFINITY
    }
}

/// The child (at half size) of node `c` of size `s` that holds coordinate `p`, ties broken toward
/// the direction of travel.
#[inline]
fn child(c: usize, s: f64, p: f64, d: f64) -> usize {
    let mid = (2 * c + 1) as f64 * (s * 0.5);
    2 * c + usize::from(p > mid || (p == mid && d >= 0.0))
}

fn sub3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn height_range(h: &[f32]) -> Option<(f32, f32)> {
    let (lo, hi) = h
        .iter()
        .filter(|v| !v.is_nan())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    (lo <= hi).then_some((lo, hi))
}

/// Shade one sample.
#[derive(Clone, Copy)]
struct Shader<'s, 'a> {
    accel: &'s TerrainAccel<'a>,
    light: &'s Lighting,
    eye: [f64; 3],
    sun: [f64; 3],
    near: f64,
    inv_range: f64,
    eps: f64,
    /// Per-grid-point sun visibility (small DEMs); `None` = a shadow ray per hit.
    sun_map: Option<&'s [u8]>,
    /// The DEM has nodata points. Without them a miss is drawn as the sky without
    /// [`TerrainAccel::through_footprint`]: a ray that enters the footprint above the edge and
    /// sinks below the lowest height crosses the (continuous) surface, so it is a hit — up to
    /// rays that graze the DEM's edge within rounding (one pixel of the paper case changed).
    holes: bool,
    /// The sky-view factor when `ambient_occlusion` > 0.
    ao: Option<&'s AoMap>,
    /// [`Lighting::ambient_tint`].
    amb_tint: [f32; 3],
}

impl Shader<'_, '_> {
    #[inline]
    fn shade(&self, dir: [f64; 3], y_frac: f32) -> Px {
        match self.accel.intersect(self.eye, dir, 0.0, f64::INFINITY) {
            Some(hit) => Px::hit(self.shade_hit(&hit), &hit),
            None => Px::background(self.miss(dir, y_frac)),
        }
    }

    /// A ray that hit nothing: transparent through a hole, else the sky.
    #[inline]
    fn miss(&self, dir: [f64; 3], y_frac: f32) -> Sample {
        if self.holes && self.accel.through_footprint(self.eye, dir, 0.0) {
            return Sample {
                c: [0.0; 3],
                a: 0.0,
                t: -1.0,
            };
        }
        Sample {
            c: self.sky(y_frac),
            a: 1.0,
            t: f32::INFINITY,
        }
    }

    /// Shade a surface point.
    #[inline]
    fn shade_hit(&self, hit: &Hit) -> Sample {
        let acc = self.accel;
        let l = self.light;
        let hit = *hit;
        let albedo = acc.hit_albedo(&hit);
        let mut c = albedo;
        if l.shading {
            let n = acc.hit_normal(&hit);
            let ndl = dot(n, self.sun);
            let mut direct = 0.0f32;
            if ndl > 0.0 && self.sun[1] > -1.0 {
                direct = ndl as f32;
                if let Some(map) = self.sun_map {
                    direct *= acc.hit_bilinear_u8(&hit, map);
                } else if l.shadows && !acc.sunlit(acc.hit_position(&hit), self.sun, self.eps) {
                    direct = 0.0;
                }
            }
            let mut amb = l.ambient * (0.5 + 0.5 * n[1] as f32);
            if let Some(ao) = self.ao {
                let w = l.ambient_occlusion;
                amb *= 1.0 - w + w * ao.at(hit.col, hit.row, hit.fx as f32, hit.fz as f32);
            }
            for ch in 0..3 {
                c[ch] = albedo[ch] * (l.sun_color[ch] * direct + amb * self.amb_tint[ch]);
            }
        }
        self.haze(&mut c, hit.t);
        Sample {
            c,
            a: 1.0,
            t: hit.t as f32,
        }
    }

    /// Aerial perspective (SPEC §1 step 8) on colour `c` of a point at distance `t`.
    #[inline]
    fn haze(&self, c: &mut [f32; 3], t: f64) {
        let l = self.light;
        if l.haze > 0.0 && l.sky_tint > 0.0 {
            // In-scattered sky light: the colour fades toward the horizon sky with depth.
            let d = ((t - self.near) * self.inv_range).clamp(0.0, 1.0) as f32;
            let k = (l.haze * d).clamp(0.0, 1.0);
            let t = l.sky_tint.clamp(0.0, 1.0);
            let mean = (c[0] + c[1] + c[2]) / 3.0;
            for (ch, v) in c.iter_mut().enumerate() {
                let target = mean + t * (l.sky_horizon[ch] - mean);
                *v += (target - *v) * k;
            }
        } else if l.haze > 0.0 {
            let d = ((t - self.near) * self.inv_range).clamp(0.0, 1.0) as f32;
            let k = (l.haze * d).clamp(0.0, 1.0);
            let mean = (c[0] + c[1] + c[2]) / 3.0;
            for v in c.iter_mut() {
                *v += (mean - *v) * k;
            }
            c[0] *= 1.0 - 0.2 * k;
            c[1] *= 1.0 - 0.1 * k;
        }
    }

    #[inline]
    fn sky(&self, y_frac: f32) -> [f32; 3] {
        self.light.sky(y_frac)
    }
}

/// Render `scene` from `camera` into an `out_w × out_h` sRGB image.
///
/// Builds a [`TerrainAccel`] (one pass over the heights) and traces one ray per pixel plus
/// `light.samples` more where the image needs anti-aliasing (+ one shadow ray per hit when
/// `light.shadows`). Progress goes to `ctl` under stage
/// `"render"`, mapped linearly onto `frac.0..frac.1` of the job. Allocates the image and the
/// pyramid (~n/3 floats) and a 16-byte-per-pixel buffer of centre samples, nothing per pixel. Panics on the caller bugs listed at
/// [`TerrainAccel::new`].
pub fn render_terrain(
    scene: &TerrainScene,
    camera: &Camera,
    light: &Lighting,
    out_w: u32,
    out_h: u32,
    ctl: &dyn Control,
    frac: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    ctl.checkpoint()?;
    let accel = TerrainAccel::new(scene);
    render_with(&accel, camera, light, out_w, out_h, ctl, frac)
}

/// [`render_terrain`] with a pyramid built once, for several views of one scene (sweeps).
/// Chooses the rasteriser or the ray caster by [`RenderPath::Auto`].
pub fn render_with(
    accel: &TerrainAccel,
    camera: &Camera,
    light: &Lighting,
    out_w: u32,
    out_h: u32,
    ctl: &dyn Control,
    frac: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    render_with_path(
        accel,
        camera,
        light,
        out_w,
        out_h,
        RenderPath::Auto,
        ctl,
        frac,
    )
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
    /// The rasteriser, unless the image or grid is beyond its limits ([`raster::MAX_SIDE`],
    /// [`raster::MAX_TRIANGLES`]).
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

/// [`render_with`] on an explicit [`RenderPath`] (tests and benchmarks compare the two).
#[allow(clippy::too_many_arguments)]
pub fn render_with_path(
    accel: &TerrainAccel,
    camera: &Camera,
    light: &Lighting,
    out_w: u32,
    out_h: u32,
    path: RenderPath,
    ctl: &dyn Control,
    frac: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    let view = prepare_view(accel, camera, light, out_w, out_h, path, ctl)?;
    render_prepared(accel, view, &|_, _| {}, ctl, frac)
}

/// The part of a terrain render that depends on the heights, the camera and the lighting but
/// not on the colours ([`prepare_view`]); [`render_prepared`] draws it.
pub struct PreparedView {
    camera: Camera,
    light: Lighting,
    out_w: u32,
    out_h: u32,
    /// The grid it was prepared for (checked by [`render_prepared`]).
    grid: (usize, usize),
    near: f64,
    far: f64,
    sun: [f64; 3],
    eps: f64,
    /// The ray caster's per-grid-point sun map (the raster path keeps its own in `raster`).
    sun_map: Option<Vec<u8>>,
    holes: bool,
    /// The sky-view factor when the lighting has ambient occlusion.
    ao: Option<AoMap>,
    /// Wall time of the sky-view factor, ms (`None` without ambient occlusion).
    ao_ms: Option<f64>,
    raster: Option<raster_path::RasterGeometry>,
    /// The image's bytes, allocated (zeroed) here so that it happens during the set-up.
    image: Vec<u8>,
}

impl PreparedView {
    /// Wall time of the ambient-occlusion map ([`sky_view_factor`]) inside [`prepare_view`], ms;
    /// `None` without ambient occlusion.
    pub fn ambient_occlusion_ms(&self) -> Option<f64> {
        self.ao_ms
    }
}

/// Everything of a render that reads only the heights: the path choice, the depth range, the
/// sun map and, on the raster path, the mesh, its projection and binning
/// ([`raster::Rasterizer::new`]) and the corner gradients. `accel`'s albedo is not read, so it
/// may be empty ([`TerrainAccel::new_geometry`]): the terrain pipeline runs this while the
/// descriptor and the colours are still being computed (a `rayon::join`; both sides only read
/// the heights), which fills the cores the descriptor's short parallel loops leave idle. No
/// progress reports (it may run beside another stage that reports); checkpoints in the sun
/// map. Then [`render_prepared`] with the same heights and their colours.
pub fn prepare_view(
    accel: &TerrainAccel,
    camera: &Camera,
    light: &Lighting,
    out_w: u32,
    out_h: u32,
    path: RenderPath,
    ctl: &dyn Control,
) -> Result<PreparedView, Canceled> {
    let (w, h) = (out_w as usize, out_h as usize);
    let gen = camera.ray_gen(out_w, out_h);
    let (near, far) = accel.depth_range(gen.eye);
    let sun = normalize(light.sun_dir);
    let eps = 1e-3 * accel.cell;
    // Shadows: one ray per grid point when the grid has fewer points than the image has pixels,
    // else one ray per hit.
    let sc = accel.scene();
    let mut path = path.resolve(accel.cw * accel.ch, w * h);
    // Outside the rasteriser's limits (image side, triangle ids) only the ray caster is exact.
    if out_w.max(out_h) > raster::MAX_SIDE || 2 * accel.cw * accel.ch > raster::MAX_TRIANGLES {
        path = RenderPath::RayCast;
    }
    let raster = path == RenderPath::Raster;
    // The rasteriser has no per-sample rays, so it always uses the per-grid-point map; the ray
    // caster uses it for small DEMs and whenever the O(n) sweep applies (one cell-wide soft
    // edge instead of a sharp one: below a pixel once cells outnumber pixels).
    let want_map = light.shading
        && light.shadows
        && (raster || sc.width * sc.height < w * h || accel.sweeps(sun));
    let empty = w == 0 || h == 0;
    // The raster path computes the map itself, in parallel with its triangle setup. The AO map
    // (heights only) runs beside both.
    let want_ao = light.shading && light.ambient_occlusion > 0.0 && !empty && accel.cw > 0;
    let holes = sc.heights.par_iter().any(|v| v.is_nan());
    let (maps, ao) = rayon::join(
        || -> Result<_, Canceled> {
            let sun_map = (want_map && !raster && !empty)
                .then(|| accel.sun_visibility(sun, eps, ctl))
                .transpose()?;
            let raster = if raster && !empty {
                let s = RasterSetup {
                    camera,
                    out_w,
                    out_h,
                    near,
                    far,
                    sun_map: want_map,
                };
                Some(raster_path::raster_geometry(accel, sun, eps, &s, ctl)?)
            } else {
                None
            };
            Ok((sun_map, raster))
        },
        || {
            want_ao
                .then(|| {
                    let t0 = std::time::Instant::now();
                    let radius = 0.1 * (2.0 * accel.half_x).max(2.0 * accel.half_z);
                    let m =
                        sky_view_factor(sc.heights, sc.width, sc.height, sc.dx, sc.dy, radius, ctl);
                    m.map(|m| (m, t0.elapsed().as_secs_f64() * 1e3))
                })
                .transpose()
        },
    );
    let ((sun_map, raster), ao) = (maps?, ao?);
    let (ao, ao_ms) = match ao {
        Some((m, ms)) => (Some(m), Some(ms)),
        None => (None, None),
    };
    Ok(PreparedView {
        camera: *camera,
        light: *light,
        out_w,
        out_h,
        grid: (sc.width, sc.height),
        near,
        far,
        sun,
        eps,
        sun_map,
        holes,
        ao,
        ao_ms,
        raster,
        image: vec![0u8; w * h * 4],
    })
}

/// Draw a view prepared by [`prepare_view`] over the same heights, `accel` now with the
/// albedo. Every finished band of rows also goes to `rows(first_row, bytes)` (whole rows of
/// final sRGBA bytes, each row once, roughly top to bottom, from the thread that drew it) while
/// the render goes on: the terrain pipeline feeds them to its PNG encoder
/// ([`crate::formats::png_write::RgbaPngStream`]) so the deflate overlaps the render. The
/// image is the one [`render_with_path`] draws in one call. Panics when `accel`'s grid is not the one the view was prepared for (a caller
/// bug).
pub fn render_prepared(
    accel: &TerrainAccel,
    view: PreparedView,
    rows: &RowSink,
    ctl: &dyn Control,
    frac: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    const BAND: usize = 4;
    let sc = accel.scene();
    assert_eq!(
        view.grid,
        (sc.width, sc.height),
        "view prepared for another grid"
    );
    let (out_w, out_h) = (view.out_w, view.out_h);
    let (w, h) = (out_w as usize, out_h as usize);
    if w == 0 || h == 0 {
        return Ok(RgbaImage {
            width: out_w,
            height: out_h,
            data: Vec::new(),
        });
    }
    let light = &view.light;
    let gen = view.camera.ray_gen(out_w, out_h);
    let (near, far) = (view.near, view.far);
    let shader = Shader {
        accel,
        light,
        eye: gen.eye,
        sun: view.sun,
        near,
        inv_range: if far > near { 1.0 / (far - near) } else { 0.0 },
        eps: view.eps,
        sun_map: view.sun_map.as_deref(),
        holes: view.holes,
        ao: view.ao.as_ref(),
        amb_tint: light.ambient_tint(),
    };
    if let Some(geo) = &view.raster {
        return render_raster(&shader, geo, gen, view.image, rows, ctl, frac);
    }
    let mut pattern = [(0.0, 0.0); 64];
    let ns = sample_pattern(light.samples, &mut pattern);
    let pattern = &pattern[..ns];
    let mut img = RgbaImage {
        width: out_w,
        height: out_h,
        data: view.image,
    };
    let bands = h.div_ceil(BAND);
    let done = AtomicUsize::new(0);
    // `done` counts bands over both passes.
    let report = || {
        let n = done.fetch_add(1, Ordering::Relaxed) + 1;
        let f = n as f32 / (2 * bands) as f32;
        ctl.progress("render", frac.0 + (frac.1 - frac.0) * f.min(1.0));
    };
    // Pass 1: one ray through every pixel centre.
    let mut centre = vec![Px::default(); w * h];
    centre
        .par_chunks_mut(w * BAND)
        .enumerate()
        .try_for_each(|(b, band)| {
            ctl.checkpoint()?;
            for (ry, row) in band.chunks_mut(w).enumerate() {
                let y = (b * BAND + ry) as f64 + 0.5;
                let y_frac = (y / h as f64) as f32;
                for (x, s) in row.iter_mut().enumerate() {
                    *s = shader.shade(gen.dir(x as f64 + 0.5, y), y_frac);
                }
            }
            report();
            Ok(())
        })?;
    // Pass 2: pixels that differ from a 4-neighbour get the rotated-grid samples too (averaged
    // with the centre, premultiplied by coverage); the rest keep the centre sample.
    let centre = &centre;
    img.data
        .par_chunks_mut(w * 4 * BAND)
        .enumerate()
        .try_for_each(|(b, band)| {
            ctl.checkpoint()?;
            for (ry, row) in band.chunks_mut(w * 4).enumerate() {
                let yi = b * BAND + ry;
                let y = yi as f64;
                let y_frac = ((y + 0.5) / h as f64) as f32;
                for (x, px) in row.chunks_exact_mut(4).enumerate() {
                    let p0 = &centre[yi * w + x];
                    let differs = |k: usize| p0.differs(&centre[k]);
                    let refine = ns > 1
                        && ((x > 0 && differs(yi * w + x - 1))
                            || (x + 1 < w && differs(yi * w + x + 1))
                            || (yi > 0 && differs((yi - 1) * w + x))
                            || (yi + 1 < h && differs((yi + 1) * w + x)));
                    let c0 = &p0.s;
                    let mut sum = [c0.c[0] * c0.a, c0.c[1] * c0.a, c0.c[2] * c0.a];
                    let mut cover = c0.a;
                    let mut n = 1.0f32;
                    if refine {
                        for &(ox, oy) in pattern {
                            let s = shader.shade(gen.dir(x as f64 + ox, y + oy), y_frac).s;
                            for (acc, c) in sum.iter_mut().zip(s.c) {
                                *acc += c * s.a;
                            }
                            cover += s.a;
                        }
                        n += ns as f32;
                    }
                    write_pixel(px, sum, cover, n);
                }
            }
            rows(b * BAND, band);
            report();
            Ok(())
        })?;
    Ok(img)
}

/// A shaded sample and the cell it hit (`u32::MAX` for the background), for the
/// anti-aliasing test [`Px::differs`].
#[derive(Debug, Clone, Copy, Default)]
struct Px {
    s: Sample,
    col: u32,
    row: u32,
}

impl Px {
    #[inline]
    fn hit(s: Sample, hit: &Hit) -> Self {
        Self {
            s,
            col: hit.col as u32,
            row: hit.row as u32,
        }
    }

    #[inline]
    fn background(s: Sample) -> Self {
        Self {
            s,
            col: u32::MAX,
            row: u32::MAX,
        }
    }
}

impl Shaded for Px {
    #[inline]
    fn sample(&self) -> Sample {
        self.s
    }

    /// True when a pixel whose centre is `self` needs super-sampling because of its neighbour
    /// `o`: another kind (surface / background / transparent), a depth jump over 3 %, or —
    /// unless both centres lie in the same or adjacent cells — a colour step over ~6/255 in a
    /// gamma-2 approximation of sRGB ([`Sample::differs`]' thresholds).
    ///
    /// The cell exception: between centres in the same or adjacent cells the surface is smooth
    /// (bilinear albedo, normals and sun map, continuous across cell edges), so the pattern
    /// samples would average a nearly linear colour ramp and land within rounding of the
    /// centre value; colour steps there come from shading gradients, not from edges. Where
    /// centres are cells apart (sub-pixel terrain detail) the colour test still applies.
    /// Measured on the paper case (400×200 → 900×600): refined pixels … (see the module doc).
    #[inline]
    fn differs(&self, o: &Px) -> bool {
        let (p, q) = (&self.s, &o.s);
        if p.a != q.a || p.t.is_finite() != q.t.is_finite() {
            return true;
        }
        if p.t.is_finite() {
            if (p.t - q.t).abs() > 0.03 * p.t.min(q.t) {
                return true;
            }
            if self.col.abs_diff(o.col) <= 1 && self.row.abs_diff(o.row) <= 1 {
                return false;
            }
        }
        // Square roots only here: most neighbours are decided above (and equal colours, e.g.
        // the sky along a row, need none).
        p.c != q.c
            && (0..3).any(|ch| (p.c[ch].max(0.0).sqrt() - q.c[ch].max(0.0).sqrt()).abs() > 0.025)
    }
}

/// The direction of a horizon sweep ([`TerrainAccel::sun_visibility_sweep`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum SweepAxis {
    /// Sun at the zenith: nothing on a height field shades a point.
    Vertical,
    /// Sun due east (`forward`) or west: rays run along grid rows; `tan` = tan(elevation).
    Rows { forward: bool, tan: f64 },
    /// Sun due south (`forward`) or north: rays run along grid columns.
    Columns { forward: bool, tan: f64 },
}

/// The sweep for a sun direction, `None` when its azimuth is not along a grid axis or it is not
/// above the horizon. "Along" allows a relative horizontal component of 1e-12, which covers the
/// rounding of `sin(180°)` in [`sun_direction`] (1.2e-16) and moves a ray by under 1e-6 of a
/// cell per million cells of travel.
fn sweep_axis(sun: [f64; 3]) -> Option<SweepAxis> {
    const AXIS: f64 = 1e-12;
    let (sx, sz) = (sun[0], sun[2]);
    let hor = (sx * sx + sz * sz).sqrt();
    if sun[1].is_nan() || sun[1] <= 0.0 || !hor.is_finite() {
        return None;
    }
    if hor <= AXIS * sun[1] {
        return Some(SweepAxis::Vertical);
    }
    if sx.abs() <= AXIS * hor {
        return Some(SweepAxis::Columns {
            forward: sz > 0.0,
            tan: sun[1] / sz.abs(),
        });
    }
    if sz.abs() <= AXIS * hor {
        return Some(SweepAxis::Rows {
            forward: sx > 0.0,
            tan: sun[1] / sx.abs(),
        });
    }
    None
}

/// Steps a node index one node along the ray (`forward` = increasing index) on a level `n` nodes
/// wide. `None` when the ray leaves the grid; otherwise whether it crossed into a new parent node.
#[inline]
fn step_axis(c: &mut usize, forward: bool, n: usize) -> Option<bool> {
    if forward {
        *c += 1;
        if *c >= n {
            return None;
        }
        Some(*c & 1 == 0)
    } else {
        if *c == 0 {
            return None;
        }
        *c -= 1;
        Some(*c & 1 == 1)
    }
}
