//! The terrain render's entry points (see "Two paths", "Anti-aliasing" and "Parallelism" in
//! [`super`]): the set-up that reads only the heights ([`prepare_view`]) and the drawing
//! ([`render_prepared`]), and the one-call forms.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::accel::TerrainAccel;
use super::ao::{sky_view_factor, AoMap};
use super::lod::ShadeLod;
use super::raster_path::{self, render_raster, RasterSetup};
use super::scene::{Lighting, RenderPath, TerrainScene};
use super::shade::{Px, Shader};
use crate::control::{Canceled, Control};
use crate::geom::camera::Camera;
use crate::geom::vec::{normalized, DVec3};
use crate::render::adaptive::{sample_pattern, write_pixel, RowSink, Shaded};
use crate::render::image::RgbaImage;
use crate::render::raster;

/// Render `scene` from `camera` into an `out_w × out_h` sRGB image.
///
/// Builds a [`TerrainAccel`] (one pass over the heights) and traces one ray per pixel plus
/// `light.samples` more where the image needs anti-aliasing (+ one shadow ray per hit when
/// `light.shadows`). Progress goes to `ctl` under stage
/// `"render"`, mapped linearly onto `progress_span.0..progress_span.1` of the job. Allocates the image and the
/// pyramid (~n/3 floats) and a 16-byte-per-pixel buffer of centre samples, nothing per pixel. Panics on the caller bugs listed at
/// [`TerrainAccel::new`].
pub fn render_terrain(
    scene: &TerrainScene,
    camera: &Camera,
    light: &Lighting,
    out_w: u32,
    out_h: u32,
    ctl: &dyn Control,
    progress_span: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    ctl.checkpoint()?;
    let accel = TerrainAccel::new(scene);
    render_accel(&accel, camera, light, out_w, out_h, ctl, progress_span)
}

/// [`render_terrain`] with a pyramid built once, for several views of one scene (sweeps).
/// Chooses the rasteriser or the ray caster by [`RenderPath::Auto`].
pub fn render_accel(
    accel: &TerrainAccel,
    camera: &Camera,
    light: &Lighting,
    out_w: u32,
    out_h: u32,
    ctl: &dyn Control,
    progress_span: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    render_accel_on_path(
        accel,
        camera,
        light,
        out_w,
        out_h,
        RenderPath::Auto,
        ctl,
        progress_span,
    )
}

/// [`render_accel`] on an explicit [`RenderPath`] (tests and benchmarks compare the two).
#[allow(clippy::too_many_arguments)]
pub fn render_accel_on_path(
    accel: &TerrainAccel,
    camera: &Camera,
    light: &Lighting,
    out_w: u32,
    out_h: u32,
    path: RenderPath,
    ctl: &dyn Control,
    progress_span: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    let view = prepare_view(accel, camera, light, out_w, out_h, path, ctl)?;
    render_prepared(accel, view, &|_, _| {}, ctl, progress_span)
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
    /// The shading pyramid's geometry levels ([`Lighting::texture_lod`], ray caster only).
    lod: Option<ShadeLod>,
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
    let sun = normalized(DVec3::from(light.sun_dir)).to_array();
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
    // Prefiltered shading (`lod.rs`): the angle of a pixel over the cell size, so that
    // `t · footprint_per_t` is a sample's footprint in cells at distance `t`.
    let lod = (light.texture_lod && raster.is_none() && !empty)
        .then(|| {
            ctl.checkpoint()?;
            let footprint_per_t = 2.0 * camera.tan_half_fov() / h as f64 / accel.cell;
            Ok::<_, Canceled>(ShadeLod::new(
                sc.heights,
                !holes,
                sun_map.as_deref(),
                sc.width,
                sc.height,
                sc.dx,
                sc.dy,
                footprint_per_t,
                far,
            ))
        })
        .transpose()?
        .flatten();
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
        lod,
        image: vec![0u8; w * h * 4],
    })
}

/// Draw a view prepared by [`prepare_view`] over the same heights, `accel` now with the
/// albedo. Every finished band of rows also goes to `rows(first_row, bytes)` (whole rows of
/// final sRGBA bytes, each row once, roughly top to bottom, from the thread that drew it) while
/// the render goes on: the terrain pipeline feeds them to its PNG encoder
/// ([`crate::formats::png_write::RgbaPngStream`]) so the deflate overlaps the render. The
/// image is the one [`render_accel_on_path`] draws in one call. Panics when `accel`'s grid is not the one the view was prepared for (a caller
/// bug).
pub fn render_prepared(
    accel: &TerrainAccel,
    view: PreparedView,
    rows: &RowSink,
    ctl: &dyn Control,
    progress_span: (f32, f32),
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
    let lod = view
        .lod
        .map(|l| l.with_albedo(sc.heights, sc.albedo, sc.width, sc.height));
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
        lod: lod.as_ref(),
    };
    if let Some(geo) = &view.raster {
        return render_raster(&shader, geo, gen, view.image, rows, ctl, progress_span);
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
        ctl.progress(
            "render",
            progress_span.0 + (progress_span.1 - progress_span.0) * f.min(1.0),
        );
    };
    // Pass 1: one ray through every pixel centre.
    // Filled in parallel (a serial fill of the 64 MB a 1080p image takes, and its page faults,
    // held one core for tens of ms at 4096²; every entry is overwritten below).
    let mut centre: Vec<Px> = Vec::with_capacity(w * h);
    centre.par_extend(rayon::iter::repeat_n(Px::default(), w * h));
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
