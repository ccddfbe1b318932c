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
//! stretch it skips the node (and climbs one level when it enters a new parent, if it cleared
//! the skipped node by more than twice its drop across it: a ray skimming the maximum would
//! fail the parent's test and come straight back down), otherwise it
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
//! **Texture level of detail** ([`Lighting::texture_lod`], the `winter` default; `lod.rs`).
//! Where a pixel spans two or more cells (big DEMs drawn small), the ray still finds its exact
//! hit on the full grid, but the hit is shaded from box-averaged albedo, heights (normal) and
//! sun visibility at the pyramid level that matches the pixel's footprint — mipmapping — and
//! [`Px::differs`]' "same or adjacent cells" exception widens to that level's cells (centres up
//! to `2^(L+1) − 1` grid cells apart). Measured on the
//! mirrored Tanzawa 4096² at 1920×1080 (`winter`): 490 k pixels refined instead of about 1.3 M,
//! and the render's rays roughly halved, with the snow pattern filtered instead of aliased.
//! Below two cells per pixel the level is 0 and the bytes are those of the point sample.
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

mod accel;
mod ao;
mod draw;
mod lod;
mod raster_path;
mod scene;
mod shade;
mod sun;

pub use accel::TerrainAccel;
pub use ao::{sky_view_factor, AoMap};
pub use draw::{
    prepare_view, render_accel, render_accel_on_path, render_prepared, render_terrain, PreparedView,
};
pub use scene::{Hit, Lighting, RenderPath, TerrainScene, RASTER_CELLS_PER_PIXEL};
