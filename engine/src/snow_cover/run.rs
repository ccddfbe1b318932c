//! The `snow-cover` pipeline: mesh → snow maps, probability, snowfall, stabilization and falling
//! (SPEC §2 steps 1–5, [`super::snowfall::simulate`]) → sparse snow (step 6) and output shape
//! (step 7) → outputs: `snow.glb`, `scene.glb`, `displaced.glb`, `render.png`, `timelapse.png`
//! (when `frames` > 1) and `report.json` with the mass balance.
//!
//! `displaced.glb` (polygon mode) is one node whose mesh has these primitives:
//!
//! 1. the displaced surface, double-sided, one primitive per input part with the part's own
//!    material (base colour, base-colour texture through the input's `TEXCOORD_0`, the input's
//!    vertex colours as `COLOR_0`), all sharing one set of vertices, with the application-specific
//!    float attributes `_SNOW_COVERAGE` (the sparse-flake coverage of step 6,
//!    [`vertex_coverage`]), `_SNOW_DEPTH` (metres), `_SNOW_PROBABILITY` (0–1) and
//!    `_SNOW_POINT_PROBABILITY`, one value per vertex, for tools that read them;
//! 2. the snow: [`snow_layer`]'s shell lifted half a thousandth of the diagonal, snow-coloured,
//!    `alphaMode: BLEND`, `COLOR_0` alpha = the snow amount `min(depth / sparse_depth, 1)` (opaque
//!    white where the snow is at least `sparse_depth` deep, the model's own material where there
//!    is none);
//! 3. the sparse flakes: [`flake_overlay`]'s shell lifted a thousandth of the diagonal off the
//!    surface, `alphaMode: BLEND`, the generated [`flake_texture`] (256², seeded by `seed`, PNG in a
//!    bufferView, REPEAT) through tri-planar `TEXCOORD_0` at an eighth of the diagonal a tile, and `COLOR_0` alpha =
//!    the coverage, so core glTF's `factor × texture × COLOR_0` shows flakes only where the
//!    coverage is partial (see [`flake_overlay`] for why a lifted shell and not a coplanar copy).

use std::time::Instant;

use serde_json::json;

use super::params::SnowCoverParams;
use super::probability::{angle_weights, main_direction, point_probability, snowfall_directions};
use super::shape::{displace, DisplacedMesh, SnowMesh, DEFAULT_MIN_DEPTH_M};
use super::simplify::{simplified_snow_meshes, DEFAULT_MAX_ERROR_CELLS};
use super::snowfall::{simulate, Snowfall, DEFAULT_RATE_M_PER_H};
use super::sparse::{
    flake_overlay, flake_particles, flake_texture, snow_layer, vertex_coverage_with_probability,
    Flakes, FLAKE_TEXTURE_SIZE,
};
use crate::formats::mesh::decode_upright;
use crate::formats::mesh_glb::{mesh_glb, scene_nodes, GlbGroup, GlbMaterial, GlbNode};
use crate::formats::png_write::{encode_apng, encode_rgba};
use crate::geom::Mesh;
use crate::params::Limits;
use crate::render::image::RgbaImage;
use crate::render::mesh::{render_meshes, MeshColors, MeshInstance, MeshLighting};
use crate::{Canceled, Control, InputError, NoControl, Output};

/// Snowfall directions (the first of the model's) behind the flakes' point probability.
pub const FLAKE_DIRECTIONS: usize = 8;

/// Most flakes drawn in `render.png` ([`flake_particles`]; one triangle each).
pub const MAX_RENDER_FLAKES: usize = 200_000;

/// Snow's albedo, linear RGB.
const SNOW: [f32; 3] = [0.9, 0.92, 0.95];

/// The displaced surface's colour when the input has no parts (so no materials), linear grey.
const GROUND: f32 = 0.55;

/// The snow amount of the sparse-snow rule, `min(depth / sparse_depth, 1)` (any snow counts as
/// full when `sparse_depth` is 0; see [`super::sparse`]).
fn amount(depth: f32, sparse_depth: f32) -> f32 {
    if depth.is_nan() || depth <= 0.0 {
        0.0
    } else if sparse_depth <= 0.0 {
        1.0
    } else {
        (depth / sparse_depth).min(1.0)
    }
}

/// Decodes the scene with the files it refers to (see [`decode_upright`]).
pub fn decode(
    bytes: &[u8],
    filename: Option<&str>,
    sidecars: &[(String, Vec<u8>)],
    p: &SnowCoverParams,
    limits: &Limits,
) -> Result<Mesh, InputError> {
    decode_upright(bytes, filename, sidecars, p.view.up_axis, limits)
}

#[allow(clippy::too_many_arguments)]
fn render_scene(
    mesh: &Mesh,
    snow: &[SnowMesh],
    flakes: Option<&Flakes>,
    p: &SnowCoverParams,
    width: u32,
    height: u32,
    ctl: &dyn Control,
    progress_span: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    let mut instances = vec![MeshInstance {
        positions: &mesh.positions,
        normals: mesh.normals.as_deref(),
        triangles: &mesh.triangles,
        colors: MeshColors::Materials(mesh),
    }];
    instances.extend(snow.iter().map(|s| MeshInstance {
        positions: &s.positions,
        normals: Some(&s.normals),
        triangles: &s.triangles,
        colors: MeshColors::Snow(SNOW),
    }));
    if let Some(f) = flakes.filter(|f| !f.triangles.is_empty()) {
        instances.push(MeshInstance {
            positions: &f.positions,
            normals: Some(&f.normals),
            triangles: &f.triangles,
            colors: MeshColors::Snow(SNOW),
        });
    }
    render_meshes(
        &instances,
        &p.view.camera_for(mesh, width, height),
        &MeshLighting::for_view(&p.view, mesh),
        width,
        height,
        ctl,
        progress_span,
    )
}

fn snow_node(s: &SnowMesh) -> GlbNode<'_> {
    GlbNode {
        name: &s.name,
        positions: &s.positions,
        normals: Some(&s.normals),
        uvs: None,
        colors: None,
        triangles: &s.triangles,
        custom: &[],
        groups: &[],
        overlays: &[],
        material: GlbMaterial {
            name: "snow".into(),
            base_color: [SNOW[0], SNOW[1], SNOW[2], 1.0],
            roughness: 0.9,
            ..GlbMaterial::default()
        },
    }
}

/// `snow.glb`, `scene.glb` and `displaced.glb` (module doc).
fn encode_glbs(
    mesh: &Mesh,
    p: &SnowCoverParams,
    snow: &[SnowMesh],
    displaced: &DisplacedMesh,
    coverage: &[f32],
    point_p: &[f32],
) -> [Vec<u8>; 3] {
    // One node for all regions (issue 18: a node per region cost more JSON than geometry).
    let snow_all = SnowMesh::merged(snow, "snow");
    let snow_nodes: Vec<GlbNode> = (!snow_all.triangles.is_empty())
        .then(|| snow_node(&snow_all))
        .into_iter()
        .collect();
    // The three files side by side (the displaced surface is the largest).
    let ((snow_glb, scene_glb), displaced_glb) = rayon::join(
        || {
            rayon::join(
                || mesh_glb(&snow_nodes, None),
                || {
                    let parts = scene_nodes(mesh);
                    let mut scene: Vec<GlbNode> = parts.iter().map(|n| n.node()).collect();
                    scene.extend(snow_nodes.iter().cloned());
                    mesh_glb(&scene, None)
                },
            )
        },
        || displaced_glb(mesh, p, displaced, coverage, point_p),
    );
    [snow_glb, scene_glb, displaced_glb]
}

/// `displaced.glb` (module doc).
fn displaced_glb(
    mesh: &Mesh,
    p: &SnowCoverParams,
    displaced: &DisplacedMesh,
    coverage: &[f32],
    point_p: &[f32],
) -> Vec<u8> {
    // The displaced surface in the input's own materials (one primitive per part, sharing the
    // vertices), the snow over it as a blended layer whose alpha is the snow amount
    // f = min(depth / sparse_depth, 1), and the flakes above that.
    let amounts: Vec<f32> = displaced
        .depth
        .iter()
        .map(|&d| amount(d, p.sparse_depth))
        .collect();
    let groups: Vec<GlbGroup> = displaced
        .parts
        .iter()
        .map(|part| GlbGroup {
            triangles: part.first_triangle..part.first_triangle + part.triangle_count,
            material: GlbMaterial {
                name: part.name.clone(),
                base_color: part.base_color,
                alpha_blend: part.base_color[3] < 1.0,
                double_sided: true,
                texture: part
                    .texture
                    .filter(|_| displaced.uvs.is_some())
                    .and_then(|k| mesh.textures.get(k).cloned()),
                ..GlbMaterial::default()
            },
        })
        .collect();
    let layer = snow_layer(
        &displaced.positions,
        &displaced.normals,
        &displaced.triangles,
        &amounts,
    );
    let overlay = flake_overlay(
        &displaced.positions,
        &displaced.normals,
        &displaced.triangles,
        coverage,
    );
    let flakes = RgbaImage {
        width: FLAKE_TEXTURE_SIZE as u32,
        height: FLAKE_TEXTURE_SIZE as u32,
        data: flake_texture(FLAKE_TEXTURE_SIZE, p.seed),
    };
    let overlays = [
        GlbNode {
            name: "snow_layer",
            positions: &layer.positions,
            normals: Some(&layer.normals),
            uvs: None,
            colors: Some(&layer.colors),
            triangles: &layer.triangles,
            material: GlbMaterial {
                name: "snow_layer".into(),
                base_color: [SNOW[0], SNOW[1], SNOW[2], 1.0],
                roughness: 0.9,
                alpha_blend: true,
                double_sided: true,
                ..GlbMaterial::default()
            },
            custom: &[],
            groups: &[],
            overlays: &[],
        },
        GlbNode {
            name: "flakes",
            positions: &overlay.positions,
            normals: Some(&overlay.normals),
            uvs: Some(&overlay.uvs),
            colors: Some(&overlay.colors),
            triangles: &overlay.triangles,
            material: GlbMaterial {
                name: "snow_flakes".into(),
                base_color: [SNOW[0], SNOW[1], SNOW[2], 1.0],
                roughness: 0.9,
                alpha_blend: true,
                double_sided: true,
                texture_png: Some(encode_rgba(&flakes)),
                ..GlbMaterial::default()
            },
            custom: &[],
            groups: &[],
            overlays: &[],
        },
    ];
    let custom: [(&str, &[f32]); 4] = [
        ("_SNOW_COVERAGE", coverage),
        ("_SNOW_DEPTH", &displaced.depth),
        ("_SNOW_PROBABILITY", &displaced.probability),
        ("_SNOW_POINT_PROBABILITY", point_p),
    ];
    mesh_glb(
        &[GlbNode {
            name: "displaced",
            positions: &displaced.positions,
            normals: Some(&displaced.normals),
            uvs: displaced.uvs.as_deref(),
            colors: displaced.colors.as_deref(),
            triangles: &displaced.triangles,
            material: GlbMaterial {
                name: "displaced".into(),
                base_color: [GROUND, GROUND, GROUND, 1.0],
                double_sided: true,
                ..GlbMaterial::default()
            },
            custom: &custom,
            groups: &groups,
            overlays: &overlays,
        }],
        None,
    )
}

/// Runs the pipeline on a decoded scene.
pub fn run(mesh: &Mesh, p: &SnowCoverParams, ctl: &dyn Control) -> Result<Vec<Output>, Canceled> {
    let t_all = Instant::now();
    let scene_height = mesh
        .bounds()
        .map_or(0.0, |(lo, hi)| f64::from(hi[1] - lo[1]));
    let model = p.model(scene_height);
    // Time-lapse frames: rendered inside the simulation at the steps that end each 1/frames of it.
    let (fw, fh) = ((p.view.width / 2).max(16), (p.view.height / 2).max(16));
    let mut frames: Vec<RgbaImage> = Vec::new();
    let mut frame_ms = 0.0;
    let wanted = |step: usize| {
        p.frames > 1
            && (step * p.frames).div_ceil(model.steps)
                != ((step - 1) * p.frames).div_ceil(model.steps)
    };
    // The model reports its own 0–1; it is the first 80 % of the job.
    let model_ctl = crate::Span {
        inner: ctl,
        from: 0.0,
        to: 0.8,
    };
    let (maps, report) = simulate(mesh, &model, &model_ctl, |maps, step| {
        if wanted(step) {
            let t0 = Instant::now();
            let (snow, _) = simplified_snow_meshes(
                maps,
                DEFAULT_MIN_DEPTH_M,
                DEFAULT_MAX_ERROR_CELLS,
                p.snow_max_triangles,
            );
            // Frames are previews: rendered without cancellation checks (they are small).
            if let Ok(img) = render_scene(mesh, &snow, None, p, fw, fh, &NoControl, (0.0, 0.0)) {
                frames.push(img);
            }
            frame_ms += t0.elapsed().as_secs_f64() * 1e3;
        }
    })?;
    let mut timings: Vec<(String, f64)> = report
        .timings
        .iter()
        .map(|(s, ms)| (s.to_string(), *ms))
        .collect();
    if p.frames > 1 {
        timings.push(("timelapse_frames".into(), frame_ms));
    }

    ctl.progress("shape", 0.8);
    let t0 = Instant::now();
    // The snow meshes and the displaced surface with its flakes depend only on the maps: the
    // two run side by side (the simplification of a scene with one large region is mostly one
    // core's work; measured in BENCHMARKS.md, snow cover session 22).
    let ((snow, simplified), shaped) = rayon::join(
        || {
            simplified_snow_meshes(
                &maps,
                DEFAULT_MIN_DEPTH_M,
                DEFAULT_MAX_ERROR_CELLS,
                p.snow_max_triangles,
            )
        },
        || -> Result<_, Canceled> {
            let displaced = displace(mesh, &maps, p.max_edge_length);
            // The flakes' snow probability at the displaced vertices themselves (walls included), from
            // the first FLAKE_DIRECTIONS of the model's snowfall directions (independent draws, so an
            // unbiased subset).
            let dirs =
                snowfall_directions(model.directions, model.spread_deg, model.wind, model.seed);
            let dirs = &dirs[..dirs.len().min(FLAKE_DIRECTIONS)];
            let weights = model
                .angle_weighting
                .then(|| angle_weights(dirs, model.spread_deg, model.wind));
            let point_p = point_probability(
                mesh,
                &displaced.positions,
                &displaced.normals,
                dirs,
                weights.as_deref(),
                maps.cell,
                ctl,
            )?;
            // No snowfall, no flakes (the angle term alone would put them on every wall).
            let coverage = if model.snowfall.cumulative(model.duration_h) > 0.0 {
                vertex_coverage_with_probability(
                    &displaced.positions,
                    &displaced.triangles,
                    &displaced.depth,
                    Some(&point_p),
                    main_direction(model.wind),
                    p.sparse_depth,
                )
            } else {
                vec![0.0; displaced.positions.len()]
            };
            let flakes = flake_particles(
                &displaced.positions,
                &displaced.normals,
                &displaced.triangles,
                &coverage,
                p.seed,
                MAX_RENDER_FLAKES,
            );
            Ok((displaced, point_p, coverage, flakes))
        },
    );
    let (displaced, point_p, coverage, flakes) = shaped?;
    timings.push(("shape".into(), t0.elapsed().as_secs_f64() * 1e3));
    ctl.checkpoint()?;

    // The render and the three glTF files need only the shapes: they are built side by side
    // (their stage times overlap; `render` is the image's, `encode` the files' and the PNGs').
    let ((image, render_ms), (glbs, glb_ms)) = rayon::join(
        || {
            let t0 = Instant::now();
            let image = render_scene(
                mesh,
                &snow,
                Some(&flakes),
                p,
                p.view.width,
                p.view.height,
                ctl,
                (0.82, 0.95),
            );
            (image, t0.elapsed().as_secs_f64() * 1e3)
        },
        || {
            let t0 = Instant::now();
            let glbs = encode_glbs(mesh, p, &snow, &displaced, &coverage, &point_p);
            (glbs, t0.elapsed().as_secs_f64() * 1e3)
        },
    );
    let image = image?;
    timings.push(("render".into(), render_ms));
    ctl.progress("encode", 0.95);
    let t0 = Instant::now();
    let [snow_glb, scene_glb, displaced_glb] = glbs;
    let png = encode_rgba(&image);
    let timelapse = (frames.len() > 1).then(|| encode_apng(&frames, 250));
    timings.push(("encode".into(), glb_ms + t0.elapsed().as_secs_f64() * 1e3));

    let scaled_to_scene =
        p.snowfall.is_none() && model.snowfall != Snowfall::Constant(DEFAULT_RATE_M_PER_H);
    let b = &report.balance;
    let resting: f64 = b.resting_m3.iter().sum();
    let n = displaced.probability.len().max(1) as f64;
    let report_json = json!({
        "pipeline": "snow-cover",
        "params": serde_json::to_value(p).unwrap_or_default(),
        "input": {
            "vertices": mesh.positions.len(),
            "triangles": mesh.triangles.len(),
            "parts": mesh.parts.len(),
            "textures": mesh.textures.iter().map(|t| json!({"name": t.name, "mime": t.mime, "width": t.width, "height": t.height})).collect::<Vec<_>>(),
            "bounds": mesh.bounds().map(|(lo, hi)| [lo, hi]),
        },
        "snowfall": {
            "total_m": model.snowfall.cumulative(model.duration_h),
            "scaled_to_scene": scaled_to_scene,
        },
        "maps": {
            "nx": maps.nx,
            "nz": maps.nz,
            "cell_m": maps.cell,
            "layers": maps.layers.len(),
        },
        "mass_balance": {
            "fallen_m3": b.fallen_m3,
            "resting_m3": resting,
            "resting_per_layer_m3": b.resting_m3,
            "lost_off_edges_m3": b.lost_m3,
            "fallen_units": b.fallen_units,
            "resting_units": b.resting_units,
            "lost_units": b.lost_units,
        },
        "stabilization": {
            "iterations": report.stabilize_iterations,
            "unconverged_steps": report.unconverged_steps,
            "routing_over_budget_steps": report.routing_over_budget_steps,
            "steps": report.step_iterations.len(),
            "max_step_iterations": report.step_iterations.iter().copied().max().unwrap_or(0),
            "iterations_per_step": report.step_iterations,
            "residual_tan": report.residual_tan,
            "tolerance_tan": crate::snow_cover::settle::SLOPE_TOLERANCE,
        },
        "snow_meshes": {
            "regions": snow.len(),
            "triangles": simplified.triangles,
            "full_resolution_triangles": simplified.full_triangles,
            "max_error_m": simplified.max_error_m,
            "within_budget": simplified.within_budget,
            "full_resolution_regions": simplified.full_resolution_regions,
            "open_regions": simplified.open_regions,
            "collapsed": simplified.collapsed,
            "collapse_kept_regions": simplified.collapse_kept_regions,
        },
        "displaced": {
            "vertices": displaced.positions.len(),
            "triangles": displaced.triangles.len(),
            "mean_probability": displaced.probability.iter().map(|&x| f64::from(x)).sum::<f64>() / n,
            "max_depth_m": displaced.depth.iter().copied().fold(0.0f32, f32::max),
        },
        "timings": timings.iter().map(|(s, ms)| json!({"stage": s, "ms": ms})).collect::<Vec<_>>(),
        "total_ms": t_all.elapsed().as_secs_f64() * 1e3,
    });
    let mut outputs = vec![
        Output::new("render.png", "image/png", png),
        Output::new("snow.glb", "model/gltf-binary", snow_glb),
        Output::new("scene.glb", "model/gltf-binary", scene_glb),
        Output::new("displaced.glb", "model/gltf-binary", displaced_glb),
    ];
    if let Some(t) = timelapse {
        outputs.push(Output::new("timelapse.png", "image/apng", t));
    }
    outputs.push(Output::new(
        "report.json",
        "application/json",
        serde_json::to_vec_pretty(&report_json).unwrap_or_default(),
    ));
    ctl.progress("done", 1.0);
    Ok(outputs)
}
