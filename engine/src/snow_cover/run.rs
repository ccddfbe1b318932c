//! The `snow-cover` pipeline: mesh → snow maps, probability, snowfall, stabilization and falling
//! (SPEC §2 steps 1–5, [`super::snowfall::simulate`]) → sparse snow (step 6) and output shape
//! (step 7) → outputs: `snow.glb`, `scene.glb`, `displaced.glb`, `render.png`, `timelapse.png`
//! (when `frames` > 1) and `report.json` with the mass balance.
//!
//! Adapted: `displaced.glb` carries the snow as vertex colour (`COLOR_0` = white where the snow is
//! at least `sparse_depth` deep, blended by the sparse-flake coverage below that, over the part's
//! grey); the per-vertex probability and depth are summarised in `report.json`, not written as
//! custom glTF attributes.

use std::time::Instant;

use serde_json::json;

use super::params::Params;
use super::probability::main_direction;
use super::shape::{displace, snow_meshes, SnowMesh, DEFAULT_MIN_DEPTH_M};
use super::snowfall::simulate;
use super::sparse::vertex_coverage;
use crate::formats::mesh_glb::{mesh_glb, scene_nodes, GlbMaterial, GlbNode};
use crate::formats::png_write::{encode_apng, encode_rgba};
use crate::geom::Mesh;
use crate::pipeline::Limits;
use crate::render::image::RgbaImage;
use crate::render::mesh::{render_meshes, MeshColors, MeshInstance};
use crate::{Canceled, Control, InputError, NoControl, Output};

/// Snow's albedo, linear RGB.
const SNOW: [f32; 3] = [0.9, 0.92, 0.95];

/// Decodes the scene (see [`crate::mesh_view::MeshView::decode`]).
pub fn decode(
    bytes: &[u8],
    filename: Option<&str>,
    p: &Params,
    limits: &Limits,
) -> Result<Mesh, InputError> {
    p.view.decode(bytes, filename, limits)
}

fn render_scene(
    mesh: &Mesh,
    snow: &[SnowMesh],
    p: &Params,
    width: u32,
    height: u32,
    ctl: &dyn Control,
    frac: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    let mut instances = vec![MeshInstance {
        positions: &mesh.positions,
        normals: mesh.normals.as_deref(),
        triangles: &mesh.triangles,
        colors: MeshColors::PerPart(&mesh.parts),
    }];
    instances.extend(snow.iter().map(|s| MeshInstance {
        positions: &s.positions,
        normals: Some(&s.normals),
        triangles: &s.triangles,
        colors: MeshColors::Uniform(SNOW),
    }));
    render_meshes(
        &instances,
        &p.view.camera_for(mesh, width, height),
        &p.view.lighting(mesh),
        width,
        height,
        ctl,
        frac,
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
        material: GlbMaterial {
            name: "snow".into(),
            base_color: [SNOW[0], SNOW[1], SNOW[2], 1.0],
            roughness: 0.9,
            ..GlbMaterial::default()
        },
    }
}

/// Runs the pipeline on a decoded scene.
pub fn run(mesh: &Mesh, p: &Params, ctl: &dyn Control) -> Result<Vec<Output>, Canceled> {
    let t_all = Instant::now();
    let model = p.model();
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
            let snow = snow_meshes(maps, DEFAULT_MIN_DEPTH_M);
            // Frames are previews: rendered without cancellation checks (they are small).
            if let Ok(img) = render_scene(mesh, &snow, p, fw, fh, &NoControl, (0.0, 0.0)) {
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
    let snow = snow_meshes(&maps, DEFAULT_MIN_DEPTH_M);
    let displaced = displace(mesh, &maps, p.max_edge_length);
    let coverage = vertex_coverage(
        &displaced.positions,
        &displaced.triangles,
        &displaced.depth,
        main_direction(model.wind),
        p.sparse_depth,
    );
    timings.push(("shape".into(), t0.elapsed().as_secs_f64() * 1e3));
    ctl.checkpoint()?;

    let t0 = Instant::now();
    let image = render_scene(
        mesh,
        &snow,
        p,
        p.view.width,
        p.view.height,
        ctl,
        (0.82, 0.95),
    )?;
    timings.push(("render".into(), t0.elapsed().as_secs_f64() * 1e3));

    ctl.progress("encode", 0.95);
    let t0 = Instant::now();
    let snow_nodes: Vec<GlbNode> = snow.iter().map(snow_node).collect();
    let snow_glb = mesh_glb(&snow_nodes, None);
    let parts = scene_nodes(mesh);
    let mut scene: Vec<GlbNode> = parts.iter().map(|n| n.node()).collect();
    scene.extend(snow.iter().map(snow_node));
    let scene_glb = mesh_glb(&scene, None);
    let colors: Vec<[f32; 4]> = displaced
        .depth
        .iter()
        .zip(&coverage)
        .map(|(&d, &c)| {
            let s = if d >= p.sparse_depth && d > 0.0 {
                1.0
            } else {
                c.clamp(0.0, 1.0)
            };
            let g = 0.55;
            [
                g + (SNOW[0] - g) * s,
                g + (SNOW[1] - g) * s,
                g + (SNOW[2] - g) * s,
                1.0,
            ]
        })
        .collect();
    let displaced_glb = mesh_glb(
        &[GlbNode {
            name: "displaced",
            positions: &displaced.positions,
            normals: Some(&displaced.normals),
            uvs: None,
            colors: Some(&colors),
            triangles: &displaced.triangles,
            material: GlbMaterial {
                name: "displaced".into(),
                double_sided: true,
                ..GlbMaterial::default()
            },
        }],
        None,
    );
    let png = encode_rgba(&image);
    let timelapse = (frames.len() > 1).then(|| encode_apng(&frames, 250));
    timings.push(("encode".into(), t0.elapsed().as_secs_f64() * 1e3));

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
            "bounds": mesh.bounds().map(|(lo, hi)| [lo, hi]),
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
        },
        "snow_meshes": snow.iter().map(|s| json!({"name": s.name, "triangles": s.triangles.len()})).collect::<Vec<_>>(),
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
