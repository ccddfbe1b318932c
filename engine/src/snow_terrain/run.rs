//! The `snow-terrain` pipeline: DEM → descriptor (steps 1–6) → colour (7) → render with aerial
//! perspective (8) → outputs (SPEC §1 "Outputs").

use std::time::Instant;

use rayon::prelude::*;
use serde_json::json;

use super::altitude::{snow_by_elevation_decile_of_t, ElevationHistogram};
use super::color::{albedo_with_rock_and_sea, albedo_with_sea, Sea};
use super::descriptor;
use super::ortho::RockColors;
use super::params::{SnowTerrainParams, TerrainOutput};
use super::view;
use crate::formats::geotiff_write::write_float32_geotiff;
use crate::formats::glb::terrain_glb;
use crate::formats::png_write::{encode_rgba, RgbaPngStream};
use crate::geom::vec::sun_direction;
use crate::geom::Dem;
use crate::render::image::RgbaImage;
use crate::render::sheet::contact_sheet;
use crate::render::terrain::{
    prepare_view, render_accel, render_prepared, Lighting, RenderPath, TerrainAccel, TerrainScene,
};
use crate::{Canceled, Control, Output};

/// Share of the job's progress spent before rendering starts.
const DESCRIPTOR_END: f32 = 0.45;
const RENDER_END: f32 = 0.85;

/// The render scene of `dem` with these (exaggerated) heights and colours.
fn scene_of<'a>(dem: &Dem, heights: &'a [f32], color: &'a [[f32; 3]]) -> TerrainScene<'a> {
    TerrainScene {
        width: dem.width,
        height: dem.height,
        dx: dem.dx,
        dy: dem.dy,
        heights,
        albedo: color,
    }
}

/// Lighting of the render; the sun's azimuth is the descriptor's (given, or from the DEM's
/// hemisphere: [`descriptor::sun_azimuth_for`]).
fn lighting(dem: &Dem, p: &SnowTerrainParams) -> Lighting {
    let (azimuth, _) = descriptor::sun_azimuth_for(dem, p.descriptor.sun_azimuth_deg);
    Lighting {
        sun_dir: sun_direction(f64::from(azimuth), p.sun_elevation_deg),
        ambient: p.ambient,
        shading: p.shading,
        shadows: p.shadows,
        haze: p.haze,
        samples: p.samples,
        ambient_occlusion: p.view.ambient_occlusion,
        sky_tint: p.view.sky_tint,
        texture_lod: p.view.texture_lod,
        ..Lighting::default()
    }
}

/// Heights as rendered: the original field × vertical exaggeration (borrowed when it is 1).
fn world_heights(dem: &Dem, exaggeration: f32) -> std::borrow::Cow<'_, [f32]> {
    if exaggeration == 1.0 {
        std::borrow::Cow::Borrowed(&dem.heights)
    } else {
        std::borrow::Cow::Owned(dem.heights.par_iter().map(|h| h * exaggeration).collect())
    }
}

/// The view's vertical exaggeration: automatic ([`view::auto_exaggeration`], from the DEM's
/// relief and extent) or the given one.
fn view_exaggeration(relief: Option<(f64, f64)>, p: &SnowTerrainParams) -> f32 {
    if p.view.auto_exaggeration {
        view::auto_exaggeration_of(relief)
    } else {
        p.descriptor.vertical_exaggeration
    }
}

/// Colours of the descriptor `t` for the given parameters (the rock colour per grid point when
/// an orthophoto gives it), and the sea (`sea_color`) at grid points at or below `sea_level`,
/// which hold no snow: one pass.
fn colors(dem: &Dem, t: &[f32], p: &SnowTerrainParams, rock: Option<&RockColors>) -> Vec<[f32; 3]> {
    let snow = p.snow_color.srgb8();
    let sea = match (&p.sea_color, p.descriptor.sea_level) {
        (Some(sea), Some(level)) => Some(Sea {
            heights: &dem.heights,
            level,
            color: sea.srgb8().map(crate::render::image::srgb8_to_linear),
        }),
        _ => None,
    };
    match rock {
        Some(r) => albedo_with_rock_and_sea(t, &r.rgb, snow, sea),
        None => albedo_with_sea(t, p.rock_color.srgb8(), snow, sea),
    }
}

/// `descriptor.png`: t as grey (0 = snow black… no: 255·t, so snow is dark and rock bright is
/// avoided) — we draw snow white: grey = 255·(1 − t), transparent where nodata.
fn descriptor_preview(dem: &Dem, t: &[f32]) -> RgbaImage {
    let mut data = vec![0u8; t.len() * 4];
    data.par_chunks_mut(4)
        .zip(t.par_iter())
        .for_each(|(px, &v)| {
            if !v.is_nan() {
                let g = (255.0 * (1.0 - v.clamp(0.0, 1.0))).round() as u8;
                px.copy_from_slice(&[g, g, g, 255]);
            }
        });
    RgbaImage {
        width: dem.width as u32,
        height: dem.height as u32,
        data,
    }
}

/// Runs the whole pipeline. Outputs: those of `render.png`, `snow_cover.tif`, `descriptor.png`,
/// `terrain.glb` that `outputs` names (default all), `sweep.png` (when a sweep is given) and
/// `report.json`.
///
/// The body runs on a rayon pool thread (`rayon::scope` moves it there and blocks the caller):
/// the descriptor's many small parallel loops then split their work in the pool directly
/// instead of each waking the pool from outside and waiting to be woken in turn.
pub fn run(dem: &Dem, p: &SnowTerrainParams, ctl: &dyn Control) -> Result<Vec<Output>, Canceled> {
    run_with_rock(dem, None, p, ctl)
}

/// [`run`] with the rock colour per grid point from an orthophoto ([`super::ortho`]; SPEC §1
/// step 7), or `rock_color` when `None`.
pub fn run_with_rock(
    dem: &Dem,
    rock: Option<&RockColors>,
    p: &SnowTerrainParams,
    ctl: &dyn Control,
) -> Result<Vec<Output>, Canceled> {
    rayon::scope(|_| run_in_pool(dem, rock, p, ctl))
}

fn run_in_pool(
    dem: &Dem,
    rock: Option<&RockColors>,
    p: &SnowTerrainParams,
    ctl: &dyn Control,
) -> Result<Vec<Output>, Canceled> {
    let t_all = Instant::now();
    let mut timings: Vec<(String, f64)> = Vec::new();
    let ms = |t0: Instant| t0.elapsed().as_secs_f64() * 1e3;

    // The descriptor and terrain.glb see `vertical_exaggeration`; the render sees the view's
    // (automatic unless given, see `View::auto_exaggeration`).
    // The DEM's statistics, once (the exaggeration, the report's relief and elevations).
    // The land cells' range (above `sea_level`) comes from the same pass: the altitude band's
    // histogram then needs one pass, not two, when a sea leaves cells out.
    let (valid, land) = dem.valid_stats_above(p.descriptor.sea_level);
    let stats = valid.map(|(lo, hi, mean, _)| (lo, hi, mean));
    let relief = view::relief_and_extent_of(dem, stats);
    let exaggeration = view_exaggeration(relief, p);
    // What the asked outputs need (`outputs`): the colours feed the render and terrain.glb
    // only, the rendered heights the render only (terrain.glb takes `vertical_exaggeration`'s).
    let wants_render = p.wants(TerrainOutput::Render);
    let wants_color = wants_render || p.wants(TerrainOutput::Glb);
    let heights = if wants_render {
        world_heights(dem, exaggeration)
    } else {
        std::borrow::Cow::Borrowed(&dem.heights[..0])
    };
    let light = lighting(dem, p);
    // The render's set-up that needs only the heights and the camera (path choice, mesh,
    // rasteriser set-up, gradients, sun map: `prepare_view`) runs beside the descriptor and the
    // colours: the descriptor's passes over 80 k cells (the paper case) are short parallel
    // loops with serial stretches between them that leave a core idle. Both sides only read
    // the DEM; neither reports progress but the descriptor (the set-up has no progress of its
    // own). Stage "render_setup" is the set-up's time, overlapping "smooth" … "colour".
    let (((d, elevations), color, color_ms), geometry) = {
        let (dc, geometry) = rayon::join(
            || -> Result<_, Canceled> {
                // The elevations' histogram of every valid cell, once: the altitude band's
                // quantiles (unless a sea leaves cells out) and the report's deciles.
                let elevations = ElevationHistogram::of_valid(
                    &dem.heights,
                    None,
                    valid.map(|(lo, hi, _, n)| (lo, hi, n)),
                );
                // The altitude band's histogram: the land cells' when a sea leaves cells out
                // of the one above (built from the range found with the DEM's statistics).
                let sea = p.descriptor.sea_level;
                let land_hist = (descriptor::needs_quantiles(&p.descriptor)
                    && !elevations.as_ref().is_some_and(|e| e.is_of(sea)))
                .then(|| ElevationHistogram::of_range(&dem.heights, sea, land))
                .flatten();
                let d = descriptor::compute_with(
                    dem,
                    &p.descriptor,
                    ctl,
                    (0.0, DESCRIPTOR_END),
                    land_hist.as_ref().or(elevations.as_ref()),
                )?;
                if !wants_color {
                    return Ok(((d, elevations), Vec::new(), None));
                }
                ctl.progress("colour", DESCRIPTOR_END);
                let t0 = Instant::now();
                let color = colors(dem, &d.t, p, rock);
                Ok(((d, elevations), color, Some(ms(t0))))
            },
            || -> Result<_, Canceled> {
                if !wants_render {
                    return Ok(None);
                }
                let t0 = Instant::now();
                let scene = scene_of(dem, &heights, &[]);
                let accel = TerrainAccel::new_geometry(&scene);
                let camera = view::camera(
                    &p.camera,
                    &scene,
                    f64::from(p.width) / f64::from(p.height),
                    p.view.fill_frame,
                );
                let view = prepare_view(
                    &accel,
                    &camera,
                    &light,
                    p.width,
                    p.height,
                    RenderPath::Auto,
                    ctl,
                )?;
                Ok(Some((accel, view, ms(t0))))
            },
        );
        (dc?, geometry?)
    };
    if let Some(ms) = color_ms {
        timings.push(("colour".to_string(), ms));
    }

    // The outputs that do not need the picture (snow_cover.tif, descriptor.png, terrain.glb)
    // and the report's figures are made while the render draws (they read the descriptor and
    // the heights only): the render has stretches that leave a core idle. Stage "render" is the
    // render's own time after its set-up; "encode" below is the PNG's tail plus whatever the
    // other encoders took beyond the render. Outputs not asked for (`outputs`) are not made,
    // and without `render.png` there is no render.
    let t0 = Instant::now();
    // Snow s = 1 − t: stored for snow_cover.tif only (the report's figures read t).
    let snow: Vec<f32> = if p.wants(TerrainOutput::SnowCover) {
        d.t.par_iter().map(|&t| 1.0 - t).collect()
    } else {
        Vec::new()
    };
    let render_end = if p.sweep_runs.is_empty() {
        RENDER_END
    } else {
        0.6
    };
    // `render.png` is deflated while the render draws: each band goes to the encoder when it is
    // finished, and the thread that completes the next band in row order feeds the deflate
    // stream (`RgbaPngStream`); what is left after the last band is a few rows.
    let png_stream = RgbaPngStream::new(p.width, p.height);
    let ao_ms = geometry
        .as_ref()
        .and_then(|(_, view, _)| view.ambient_occlusion_ms());
    let ((image, setup_ms, render_ms), (tif, (preview, (glb, figures)))) = rayon::join(
        || {
            let Some((accel, view, setup_ms)) = geometry else {
                return (Ok(None), 0.0, 0.0);
            };
            let t0 = Instant::now();
            let accel = accel.with_albedo(&color);
            let image = render_prepared(
                &accel,
                view,
                &|y0, rows| png_stream.rows(y0, rows),
                ctl,
                (DESCRIPTOR_END, render_end),
            );
            (image.map(Some), setup_ms, ms(t0))
        },
        || {
            rayon::join(
                || {
                    p.wants(TerrainOutput::SnowCover)
                        .then(|| write_float32_geotiff(dem.width, dem.height, &snow, &dem.georef))
                },
                || {
                    rayon::join(
                        || {
                            p.wants(TerrainOutput::Descriptor)
                                .then(|| encode_rgba(&descriptor_preview(dem, &d.t)))
                        },
                        || {
                            rayon::join(
                                || {
                                    p.wants(TerrainOutput::Glb).then(|| {
                                        let glb_heights = if wants_render
                                            && exaggeration == p.descriptor.vertical_exaggeration
                                        {
                                            std::borrow::Cow::Borrowed(&*heights)
                                        } else {
                                            world_heights(dem, p.descriptor.vertical_exaggeration)
                                        };
                                        terrain_glb(
                                            &glb_heights,
                                            dem.width,
                                            dem.height,
                                            dem.dx,
                                            dem.dy,
                                            &color,
                                            p.mesh_max_vertices,
                                        )
                                    })
                                },
                                || {
                                    (
                                        report_figures(&d.t, stats),
                                        elevations.as_ref().map_or(vec![None; 10], |e| {
                                            snow_by_elevation_decile_of_t(e, &dem.heights, &d.t)
                                        }),
                                    )
                                },
                            )
                        },
                    )
                },
            )
        },
    );
    let image = image?;
    if image.is_some() {
        timings.push(("render_setup".to_string(), setup_ms));
        // Part of render_setup (beside the sun map).
        if let Some(ms) = ao_ms {
            timings.push(("ambient_occlusion".to_string(), ms));
        }
        timings.push(("render".to_string(), render_ms));
    }
    let overlap_ms = (ms(t0) - render_ms).max(0.0);

    let mut outputs = Vec::new();
    if !p.sweep_runs.is_empty() {
        let t0 = Instant::now();
        let sheet = sweep_sheet(dem, rock, p, ctl, (render_end, RENDER_END))?;
        outputs.push(Output::new("sweep.png", "image/png", encode_rgba(&sheet)));
        timings.push(("sweep".to_string(), ms(t0)));
    }

    ctl.progress("encode", RENDER_END);
    let t0 = Instant::now();
    let png = image.as_ref().map(|img| png_stream.finish(img));
    timings.push(("encode".to_string(), overlap_ms + ms(t0)));
    ctl.checkpoint()?;

    let ((valid, covered, mean_snow, stats), deciles) = figures;
    let mut stage_ms: Vec<serde_json::Value> = d
        .timings
        .iter()
        .map(|(s, ms)| json!({"stage": s, "ms": ms}))
        .collect();
    stage_ms.extend(timings.iter().map(|(s, ms)| json!({"stage": s, "ms": ms})));
    let report = json!({
        "pipeline": "snow-terrain",
        "params": serde_json::to_value(p).unwrap_or_default(),
        "input": {
            "width": dem.width,
            "height": dem.height,
            "cell_size_m": [dem.dx, dem.dy],
            "epsg": dem.georef.epsg,
            "geographic": dem.georef.geographic,
            "valid_cells": valid,
            "elevation_min": stats.map(|s| s.0),
            "elevation_max": stats.map(|s| s.1),
            "elevation_mean": stats.map(|s| s.2),
        },
        "resolved": d.resolved,
        "view": {
                        "vertical_exaggeration": exaggeration,
            "vertical_exaggeration_auto": p.view.auto_exaggeration,
            "relief_m": relief.map(|r| r.0),
            "extent_m": relief.map(|r| r.1),
        },
        "ortho": rock.map(|r| json!({"placement": r.placement, "coverage": r.coverage})),
        "snow_covered_fraction": covered as f64 / valid.max(1) as f64,
        "mean_snow": mean_snow,
        "snow_by_elevation_decile": deciles,
        "timings": stage_ms,
        "total_ms": t_all.elapsed().as_secs_f64() * 1e3,
    });
    let report = serde_json::to_vec_pretty(&report).unwrap_or_default();

    let made = [
        png.map(|b| Output::new("render.png", "image/png", b)),
        tif.map(|b| Output::new("snow_cover.tif", "image/tiff", b)),
        preview.map(|b| Output::new("descriptor.png", "image/png", b)),
        glb.map(|b| Output::new("terrain.glb", "model/gltf-binary", b)),
    ];
    outputs.splice(0..0, made.into_iter().flatten());
    outputs.push(Output::new("report.json", "application/json", report));
    ctl.progress("done", 1.0);
    Ok(outputs)
}

/// The report's figures: (valid cells, snow-covered cells, mean snow, the DEM's elevation
/// statistics), from the descriptor `t` (snow s = 1 − t). Computed beside the render (they
/// need only the descriptor). (valid cells, covered cells, Σ snow) per chunk, summed in chunk
/// order: the same figures whatever the thread count.
#[allow(clippy::type_complexity)]
fn report_figures(
    t: &[f32],
    stats: Option<(f32, f32, f64)>,
) -> (usize, usize, f64, Option<(f32, f32, f64)>) {
    let parts: Vec<(usize, usize, f64)> = t
        .par_chunks(1 << 16)
        .map(|c| {
            c.iter()
                .map(|&t| 1.0 - t)
                .filter(|s| !s.is_nan())
                .fold((0, 0, 0.0), |(n, k, sum), s| {
                    (n + 1, k + usize::from(s >= 0.5), sum + f64::from(s))
                })
        })
        .collect();
    let (valid, covered, total) = parts
        .iter()
        .fold((0, 0, 0.0), |(n, k, s), p| (n + p.0, k + p.1, s + p.2));
    (valid, covered, total / valid.max(1) as f64, stats)
}

/// `sweep.png`: one tile per sweep value, each a full descriptor + render at a third of the
/// output size, labelled `param = value`.
fn sweep_sheet(
    dem: &Dem,
    rock: Option<&RockColors>,
    p: &SnowTerrainParams,
    ctl: &dyn Control,
    progress_span: (f32, f32),
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
        let f0 = progress_span.0 + (progress_span.1 - progress_span.0) * i as f32 / n as f32;
        let f1 =
            progress_span.0 + (progress_span.1 - progress_span.0) * (i as f32 + 0.5) / n as f32;
        let f2 =
            progress_span.0 + (progress_span.1 - progress_span.0) * (i as f32 + 1.0) / n as f32;
        let d = descriptor::compute(dem, &run.descriptor, ctl, (f0, f1))?;
        let color = colors(dem, &d.t, run, rock);
        let relief = view::relief_and_extent(dem);
        let heights = world_heights(dem, view_exaggeration(relief, run));
        let scene = scene_of(dem, &heights, &color);
        let accel = TerrainAccel::new(&scene);
        let camera = view::camera(
            &run.camera,
            &scene,
            f64::from(tw) / f64::from(th),
            run.view.fill_frame,
        );
        let img = render_accel(&accel, &camera, &lighting(dem, run), tw, th, ctl, (f1, f2))?;
        tiles.push((img, format!("{name} = {value}")));
    }
    Ok(contact_sheet(&tiles, columns))
}
