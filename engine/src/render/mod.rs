//! Rendering shared by the pipelines: cameras, images, the height-field ray caster and contact
//! sheets.
//!
//! - [`image`]: 8-bit sRGB images with straight alpha and the linear ↔ sRGB conversions.
//! - [`terrain`]: a ray caster over a maximum-height mip pyramid that draws big DEMs at full detail
//!   with Lambert shading, cast shadows, aerial perspective (SPEC §1 step 8) and a sky background.
//! - [`raster`]: a z-buffered, binned, parallel triangle rasteriser with perspective-correct
//!   attributes and the ray caster's adaptive anti-aliasing; draws DEMs with fewer cells than
//!   output pixels, and meshes.
//! - [`adaptive`]: the adaptive anti-aliasing loop over the rasteriser (centre samples, then
//!   the pattern only where neighbouring centres differ).
//! - [`sheet`]: labelled contact sheets of tiles (the paper's Figs. 11–12).
//!
//! World frame (shared with `geom::heightfield` and the glTF writer): X = east, Y = up, Z = south,
//! right-handed; the grid is centred on the origin horizontally.

pub mod adaptive;
pub mod image;
pub mod mesh;
pub mod raster;
pub mod sheet;
pub mod terrain;

pub use image::RgbaImage;
pub use sheet::contact_sheet;

pub use terrain::{
    render_accel, render_accel_on_path, render_terrain, Hit, Lighting, RenderPath, TerrainAccel,
    TerrainScene, RASTER_CELLS_PER_PIXEL,
};
