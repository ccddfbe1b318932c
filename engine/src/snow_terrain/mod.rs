//! Snow on terrain (SPEC §1): Nakatani, Fujishiro and Ohno's surface descriptor.
//!
//! One module per step of the paper's algorithm (§4.1): [`smooth`] (lines 1–3 and 9), [`tsa`]
//! (line 5, Eq. 3), [`transfer`] (line 6, Eq. 4), [`altitude`] (line 7), [`sun`] (lines 10–15),
//! composed by [`descriptor`]; then [`color`] (§4.2) and [`run`] (rendering and outputs).

pub mod altitude;
pub mod catalog;
pub mod color;
pub mod descriptor;
pub mod ortho;
pub mod params;
pub mod run;
pub mod smooth;
pub mod sun;
pub mod tiles;
pub mod transfer;
pub mod tsa;
pub mod view;

pub use params::{SnowTerrainParams, TerrainOutput};
pub use run::{run, run_with_rock};

/// The benchmarks' overview render of `dem` with per-cell `colour`: the default camera (orbit,
/// azimuth 200°, elevation 30°, 40° field of view, framing the terrain) and sun (azimuth 180°,
/// elevation 35°) that `run` uses without parameters, `w × h` pixels. Shared by the timing tests
/// and `benches/snow_terrain.rs` so both measure the same work (behind the `testkit` feature).
#[cfg(feature = "testkit")]
pub fn overview_render(
    dem: &crate::geom::Dem,
    color: &[[f32; 3]],
    w: u32,
    h: u32,
) -> Result<crate::render::RgbaImage, crate::Canceled> {
    use crate::geom::camera::Camera;
    use crate::geom::vec::sun_direction;
    use crate::render::terrain::{render_accel, Lighting, TerrainAccel, TerrainScene};
    let scene = TerrainScene {
        width: dem.width,
        height: dem.height,
        dx: dem.dx,
        dy: dem.dy,
        heights: &dem.heights,
        albedo: color,
    };
    let accel = TerrainAccel::new(&scene);
    let (center, radius) = scene.bounding_sphere();
    let camera = Camera::orbit(
        center,
        200.0,
        30.0,
        Camera::auto_distance(radius, 40.0),
        40.0,
    );
    let light = Lighting {
        sun_dir: sun_direction(180.0, 35.0),
        ..Lighting::default()
    };
    render_accel(&accel, &camera, &light, w, h, &crate::NoControl, (0.0, 1.0))
}
