//! The `snow-terrain` pipeline: DEM → descriptor (steps 1–6) → colour (7) → render with aerial
//! perspective (8) → outputs (SPEC §1 "Outputs").

use std::time::Instant;

use serde_json::json;

use super::colour::albedo;
use super::descriptor;
use super::params::Params;
use crate::formats::geotiff_write::write_float32_geotiff;
use crate::formats::glb::terrain_glb;
use crate::formats::png_write::encode_rgba;
use crate::geom::Dem;
use crate::params::parse_hex_color;
use crate::render::image::RgbaImage;
use crate::render::sheet::contact_sheet;
use crate::render::terrain::{render_with, sun_direction, Lighting, TerrainAccel, TerrainScene};
use crate::{Canceled, Control, Output};

/// Share of the job's progress spent before rendering starts.
const DESCRIPTOR_END: f32 = 0.45;
const RENDER_END: f32 = 0.85;

/// The render scene of `dem` with these (exaggerated) heights and colours.
fn scene_of<'a>(dem: &Dem, heights: &'a [f32], colour: &'a [[f32; 3]]) -> TerrainScene<'a> {
    TerrainScene {
        width: dem.width,
        height: dem.height,
        dx: dem.dx,
        dy: dem.dy,
        heights,
        albedo: colour,
    }
}

fn lighting(p: &Params) -> Lighting {
    Lighting {
        sun_dir: sun_direction(f64::from(p.descriptor.sun_azimuth_deg), p.sun_elevation_deg),
        ambient: p.ambient,
        shading: p.shading,
        shadows: p.shadows,
        haze: p.haze,
        samples: p.samples,
        ..Lighting::default()
    }
}

/// Heights as rendered: the original field × vertical exaggeration (borrowed when it is 1).
fn world_heights(dem: &Dem, exaggeration: f32) -> std::borrow::Cow<'_, [f32]> {
    if exaggeration == 1.0 {
        std::borrow::Cow::Borrowed(&dem.heights)
    } else {
        std::borrow::Cow::Owned(dem.heights.iter().map(|h| h * exaggeration).collect())
    }
}

/// Colours of the descriptor `t` for the given parameters.
fn colours(t: &[f32], p: &Params) -> Vec<[f32; 3]> {
    // Validated at parse time; fall back to mid-grey rather than fail.
    let rock = parse_hex_color("rock_color", &p.rock_color).unwrap_or([110, 102, 92]);
    let snow = parse_hex_color("snow_color", &p.snow_color).unwrap_or([244, 247, 251]);
    albedo(t, rock, snow)
}

/// `descriptor.png`: t as grey (0 = snow black… no: 255·t, so snow is dark and rock bright is
/// avoided) — we draw snow white: grey = 255·(1 − t), transparent where nodata.
fn descriptor_preview(dem: &Dem, t: &[f32]) -> RgbaImage {
    let mut data = Vec::with_capacity(t.len() * 4);
    for &v in t {
        if v.is_nan() {
            data.extend_from_slice(&[0, 0, 0, 0]);
        } else {
            let g = (255.0 * (1.0 - v.clamp(0.0, 1.0))).round() as u8;
            data.extend_from_slice(&[g, g, g, 255]);
        }
    }
    RgbaImage {
        width: dem.width as u32,
        height: dem.height as u32,
        data,
    }
}

/// Runs the whole pipeline. Outputs: `render.png`, `snow_cover.tif`, `descriptor.png`,
/// `terrain.glb`, `sweep.png` (when a sweep is given) and `report.json`.
pub fn run(dem: &Dem, p: &Params, ctl: &dyn Control) -> Result<Vec<Output>, Canceled> {
    let t_all = Instant::now();
    let mut timings: Vec<(String, f64)> = Vec::new();
    let mut lap = |name: &str, t0: Instant| {
        timings.push((name.to_string(), t0.elapsed().as_secs_f64() * 1e3))
    };

    let d = descriptor::compute(dem, &p.descriptor, ctl, (0.0, DESCRIPTOR_END))?;

    ctl.progress("colour", DESCRIPTOR_END);
    let t0 = Instant::now();
    let colour = colours(&d.t, p);
    let heights = world_heights(dem, p.descriptor.vertical_exaggeration);
    lap("colour", t0);

    let t0 = Instant::now();
    let scene = scene_of(dem, &heights, &colour);
    let accel = TerrainAccel::new(&scene);
    let camera = p
        .camera
        .camera(scene.bounds(), f64::from(p.width) / f64::from(p.height));
    let render_end = if p.sweep_runs.is_empty() {
        RENDER_END
    } else {
        0.6
    };
    let image = render_with(
        &accel,
        &camera,
        &lighting(p),
        p.width,
        p.height,
        ctl,
        (DESCRIPTOR_END, render_end),
    )?;
    lap("render", t0);

    let mut outputs = Vec::new();
    if !p.sweep_runs.is_empty() {
        let t0 = Instant::now();
        let sheet = sweep_sheet(dem, p, ctl, (render_end, RENDER_END))?;
        outputs.push(Output::new("sweep.png", "image/png", encode_rgba(&sheet)));
        lap("sweep", t0);
    }

    ctl.progress("encode", RENDER_END);
    let t0 = Instant::now();
    let snow: Vec<f32> = d.t.iter().map(|&t| 1.0 - t).collect();
    let (png, tif, preview, glb) = {
        let ((png, tif), (preview, glb)) = rayon::join(
            || {
                rayon::join(
                    || encode_rgba(&image),
                    || write_float32_geotiff(dem.width, dem.height, &snow, &dem.georef),
                )
            },
            || {
                rayon::join(
                    || encode_rgba(&descriptor_preview(dem, &d.t)),
                    || {
                        terrain_glb(
                            &heights,
                            dem.width,
                            dem.height,
                            dem.dx,
                            dem.dy,
                            &colour,
                            p.mesh_max_vertices,
                        )
                    },
                )
            },
        );
        ((png, tif), (preview, glb)).into_flat()
    };
    lap("encode", t0);
    ctl.checkpoint()?;

    let valid: Vec<f32> = snow.iter().copied().filter(|s| !s.is_nan()).collect();
    let covered = valid.iter().filter(|&&s| s >= 0.5).count();
    let mean_snow = valid.iter().map(|&s| f64::from(s)).sum::<f64>() / valid.len().max(1) as f64;
    let mut stage_ms: Vec<serde_json::Value> = d
        .timings
        .iter()
        .map(|(s, ms)| json!({"stage": s, "ms": ms}))
        .collect();
    stage_ms.extend(timings.iter().map(|(s, ms)| json!({"stage": s, "ms": ms})));
    let stats = dem.stats();
    let report = json!({
        "pipeline": "snow-terrain",
        "params": serde_json::to_value(p).unwrap_or_default(),
        "input": {
            "width": dem.width,
            "height": dem.height,
            "cell_size_m": [dem.dx, dem.dy],
            "epsg": dem.georef.epsg,
            "geographic": dem.georef.geographic,
            "valid_cells": valid.len(),
            "elevation_min": stats.map(|s| s.0),
            "elevation_max": stats.map(|s| s.1),
            "elevation_mean": stats.map(|s| s.2),
        },
        "snow_covered_fraction": covered as f64 / valid.len().max(1) as f64,
        "mean_snow": mean_snow,
        "timings": stage_ms,
        "total_ms": t_all.elapsed().as_secs_f64() * 1e3,
    });
    let report = serde_json::to_vec_pretty(&report).unwrap_or_default();

    outputs.splice(
        0..0,
        [
            Output::new("render.png", "image/png", png),
            Output::new("snow_cover.tif", "image/tiff", tif),
            Output::new("descriptor.png", "image/png", preview),
            Output::new("terrain.glb", "model/gltf-binary", glb),
        ],
    );
    outputs.push(Output::new("report.json", "application/json", report));
    ctl.progress("done", 1.0);
    Ok(outputs)
}

trait IntoFlat<A, B, C, D> {
    fn into_flat(self) -> (A, B, C, D);
}
impl<A, B, C, D> IntoFlat<A, B, C, D> for ((A, B), (C, D)) {
    fn into_flat(self) -> (A, B, C, D) {
        let ((a, b), (c, d)) = self;
        (a, b, c, d)
    }
}

/// `sweep.png`: one tile per sweep value, each a full descriptor + render at a third of the
/// output size, labelled `param = value`.
fn sweep_sheet(
    dem: &Dem,
    p: &Params,
    ctl: &dyn Control,
    frac: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    let n = p.sweep_runs.len();
    let columns = if n <= 4 { n } else { 3 };
    let tw = (p.width / 3).max(160);
    let th = (u64::from(tw) * u64::from(p.height) / u64::from(p.width.max(1))).max(90) as u32;
    let name = p.sweep.as_ref().map(|s| s.param.as_str()).unwrap_or("");
    let mut tiles = Vec::with_capacity(n);
    for (i, (run, value)) in p
        .sweep_runs
        .iter()
        .zip(p.sweep.iter().flat_map(|s| s.values.iter()))
        .enumerate()
    {
        let f0 = frac.0 + (frac.1 - frac.0) * i as f32 / n as f32;
        let f1 = frac.0 + (frac.1 - frac.0) * (i as f32 + 0.5) / n as f32;
        let f2 = frac.0 + (frac.1 - frac.0) * (i as f32 + 1.0) / n as f32;
        let d = descriptor::compute(dem, &run.descriptor, ctl, (f0, f1))?;
        let colour = colours(&d.t, run);
        let heights = world_heights(dem, run.descriptor.vertical_exaggeration);
        let scene = scene_of(dem, &heights, &colour);
        let accel = TerrainAccel::new(&scene);
        let camera = run
            .camera
            .camera(scene.bounds(), f64::from(tw) / f64::from(th));
        let img = render_with(&accel, &camera, &lighting(run), tw, th, ctl, (f1, f2))?;
        tiles.push((img, format!("{name} = {value}")));
    }
    Ok(contact_sheet(&tiles, columns))
}
