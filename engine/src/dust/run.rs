//! The `dust` pipeline (SPEC §4): mesh → surface with crease-split normals, long edges split
//! ([`super::surface`]) →
//! dust amount D with exposure (step 1) → Perlin field and one fibre texture per shell (steps 2–3)
//! → shell render over the base mesh (step 4) → outputs: `render.png`, `fibers.png`,
//! `dust_amount.png`, `dusty.glb`, `report.json`.
//!
//! `dust_amount.png` shows D on the mesh from the render's camera: the base mesh coloured by D / K
//! through the viridis colour map (dark violet = none, yellow = K), lit by the same sun without
//! shadows (so the colours stay readable), no shells.
//!
//! Defaults that depend on the mesh: `max_thickness` = 1 % and `fiber_tile` = 1/8 of the bounding-
//! box diagonal (report.json gives the values used).

use std::time::Instant;

use serde_json::json;

use super::amount::{directional, vertex_exposure, AmountModel};
use super::export::{dusty_glb, TextureAtlas};
use super::fibers::{fiber_texture, shell_fiber_count};
use super::mapping::Mapping;
use super::noise::TileableNoise;
use super::params::DustParams;
use super::render::{shell_overlay, Shells};
use super::surface::{crease_split, refine, MAX_REFINED_TRIANGLES};
use super::texture::ShellTexture;
use crate::formats::mesh::decode_upright;
use crate::formats::png_write::encode_rgba;
use crate::geom::camera::Camera;
use crate::geom::Mesh;
use crate::params::Limits;
use crate::render::image::srgb_to_linear;
use crate::render::mesh::{MeshColors, MeshInstance, MeshLighting, MeshRenderer};
use crate::{Canceled, Control, InputError, Output};

/// Largest `shells` × the mesh's triangles (or [`MAX_REFINED_TRIANGLES`] if more, what refining
/// may make of a coarse mesh): the shell meshes of `dusty.glb` hold up to ~36 bytes per shell
/// triangle, so 2^25 bounds them near 1.2 GB (e.g. 32 shells over a million triangles).
pub const MAX_SHELL_TRIANGLES: u64 = 1 << 25;

/// Decodes the mesh with the files it refers to (see [`decode_upright`] and
/// [`crate::formats::mesh::Sidecars`]) and checks that its shells stay within
/// [`MAX_SHELL_TRIANGLES`].
pub fn decode(
    bytes: &[u8],
    filename: Option<&str>,
    sidecars: &[(String, Vec<u8>)],
    p: &DustParams,
    limits: &Limits,
) -> Result<Mesh, InputError> {
    let mesh = decode_upright(bytes, filename, sidecars, p.view.up_axis, limits)?;
    let tris = mesh.triangles.len().max(MAX_REFINED_TRIANGLES) as u64;
    let shell_tris = tris * u64::from(p.shells);
    if shell_tris > MAX_SHELL_TRIANGLES {
        return Err(InputError::TooLarge {
            what: "shell triangles (shells × mesh triangles)",
            actual: shell_tris,
            max: MAX_SHELL_TRIANGLES,
        });
    }
    Ok(mesh)
}

/// Viridis at 0, ¼, ½, ¾, 1 (sRGB bytes), interpolated in linear RGB.
const VIRIDIS: [[u8; 3]; 5] = [
    [0x44, 0x01, 0x54],
    [0x3b, 0x52, 0x8b],
    [0x21, 0x91, 0x8c],
    [0x5e, 0xc9, 0x62],
    [0xfd, 0xe7, 0x25],
];

/// The colour (linear RGB) of `x` ∈ [0, 1] on the viridis map.
pub fn viridis(x: f32) -> [f32; 3] {
    let x = if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    } * 4.0;
    let k = (x.floor() as usize).min(3);
    let f = x - k as f32;
    let (a, b) = (VIRIDIS[k], VIRIDIS[k + 1]);
    [0, 1, 2].map(|c| {
        let (la, lb) = (
            srgb_to_linear(a[c] as f32 / 255.0),
            srgb_to_linear(b[c] as f32 / 255.0),
        );
        la + (lb - la) * f
    })
}

/// Bounding-box diagonal of `mesh`, metres (1 for an empty mesh).
fn diagonal(mesh: &Mesh) -> f32 {
    mesh.bounds()
        .map(|(lo, hi)| (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt())
        .filter(|d| d.is_finite() && *d > 0.0)
        .unwrap_or(1.0)
}

/// The close-up's target ([`DustParams::close_up`]): the middle of the dustiest patch the
/// default view's eye (`eye`) faces, so the close-up is filled with dust whatever the model's
/// size and shape. The triangles facing `eye` are binned by centroid into cubes of
/// [`CLOSE_UP_CELL`] × the bounding-box diagonal (about the close-up's field of view at its
/// default distance); each cube scores Σ area × mean D over itself and its 26 neighbours, and
/// the target is the vertex nearest the best cube's centre among those around it with at least
/// half their largest D; the mesh's centre when no vertex has dust. [`run`] passes D per unit
/// stickiness when K = 0, so a close-up without dust frames the same place. The first rule —
/// the most dusted vertex nearest the eye — picked a few-pixel cap at a propeller blade's tip
/// while the dust lay on another blade's face (held-out `occt_propeller`: the close-up showed
/// no fibres).
pub fn close_up_target(mesh: &Mesh, amount: &[f32], eye: [f64; 3]) -> [f64; 3] {
    let max = amount.iter().copied().fold(0.0f32, f32::max);
    let bounds = mesh.bounds();
    let centre = bounds.map_or([0.0; 3], |(lo, hi)| {
        [0, 1, 2].map(|k| 0.5 * (f64::from(lo[k]) + f64::from(hi[k])))
    });
    let Some((lo, _)) = bounds.filter(|_| max > 0.0) else {
        return centre;
    };
    let cell = f64::from(diagonal(mesh)) * CLOSE_UP_CELL;
    let key = |p: [f64; 3]| -> [i64; 3] {
        [0, 1, 2].map(|k| ((p[k] - f64::from(lo[k])) / cell).floor() as i64)
    };
    let mut cells: std::collections::HashMap<[i64; 3], f64> = std::collections::HashMap::new();
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize].map(f64::from));
        let e1 = [0, 1, 2].map(|k| b[k] - a[k]);
        let e2 = [0, 1, 2].map(|k| c[k] - a[k]);
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let g = [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0);
        let facing: f64 = (0..3).map(|k| n[k] * (eye[k] - g[k])).sum();
        let d: f64 = t
            .iter()
            .map(|&i| f64::from(amount[i as usize]))
            .sum::<f64>()
            / 3.0;
        if facing > 0.0 && d > 0.0 {
            // |n| / 2 is the area.
            let area = 0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            *cells.entry(key(g)).or_insert(0.0) += area * d;
        }
    }
    let mut best: Option<([i64; 3], f64)> = None;
    for k in cells.keys() {
        let mut sum = 0.0;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    sum += cells
                        .get(&[k[0] + dx, k[1] + dy, k[2] + dz])
                        .unwrap_or(&0.0);
                }
            }
        }
        // Ties broken by the key, so the choice does not depend on the map's order.
        if best.is_none_or(|(bk, bs)| sum > bs || (sum == bs && *k < bk)) {
            best = Some((*k, sum));
        }
    }
    let Some((cell_key, _)) = best else {
        return centre;
    };
    // The vertices of the best cube and its neighbours: of those with at least half their
    // largest D, the one nearest the cube's centre (the cube's centre itself when it has none).
    let mid = [0, 1, 2].map(|k| f64::from(lo[k]) + (cell_key[k] as f64 + 0.5) * cell);
    let near = |q: [f64; 3]| (0..3).all(|k| (key(q)[k] - cell_key[k]).abs() <= 1);
    let top = mesh
        .positions
        .iter()
        .zip(amount)
        .filter(|(p, _)| near(p.map(f64::from)))
        .fold(0f32, |m, (_, &d)| m.max(d));
    let mut pick = (f64::INFINITY, mid);
    for (p, &d) in mesh.positions.iter().zip(amount) {
        let q = p.map(f64::from);
        if d > 0.0 && d >= 0.5 * top && near(q) {
            let r2: f64 = (0..3).map(|k| (q[k] - mid[k]).powi(2)).sum();
            if r2 < pick.0 {
                pick = (r2, q);
            }
        }
    }
    pick.1
}

/// The close-up target's cube side, share of the bounding-box diagonal ([`close_up_target`]).
pub const CLOSE_UP_CELL: f64 = 0.05;

/// Runs the pipeline on a decoded mesh.
pub fn run(input: &Mesh, p: &DustParams, ctl: &dyn Control) -> Result<Vec<Output>, Canceled> {
    let t_all = Instant::now();
    let mut timings: Vec<(&str, f64)> = Vec::new();
    let mut lap = |name: &'static str, t0: Instant| {
        timings.push((name, t0.elapsed().as_secs_f64() * 1e3));
    };

    // Step 1: where dust lies.
    ctl.progress("amount", 0.0);
    let t0 = Instant::now();
    let (mut mesh, mut normals) = crease_split(input, p.dust_source);
    refine(&mut mesh, &mut normals);
    let model = p.amount_model();
    let exposure = vertex_exposure(&mesh, &normals, &model);
    let u = p.dust_source;
    let amount: Vec<f32> = normals
        .iter()
        .zip(&exposure)
        .map(|(n, e)| directional(&model, *n, u) * e)
        .collect();
    lap("amount", t0);
    ctl.checkpoint()?;

    // Steps 2–3: the noise and one fibre texture per shell.
    ctl.progress("noise", 0.2);
    let t0 = Instant::now();
    let side = p.texture_size;
    let noise = TileableNoise::new(p.seed, p.noise_scale, p.noise_octaves).texture(side, side);
    lap("noise", t0);
    ctl.progress("fibers", 0.25);
    let t0 = Instant::now();
    let fp = p.fiber_params();
    let mut atlas = TextureAtlas::new(side as usize, p.shells as usize);
    let mut textures = Vec::with_capacity(p.shells as usize);
    let mut fiber_counts = Vec::with_capacity(p.shells as usize);
    for k in 0..p.shells {
        ctl.checkpoint()?;
        let count = shell_fiber_count(p.fibers, k, p.shells);
        let tex = fiber_texture(&fp, &noise, side, side, p.seed, k, count);
        atlas.put(k as usize, &tex);
        textures.push(ShellTexture::new(&tex));
        fiber_counts.push(count);
        ctl.progress("fibers", 0.25 + 0.2 * (k + 1) as f32 / p.shells as f32);
    }
    lap("fibers", t0);

    // Step 4: the render.
    let t0 = Instant::now();
    let diag = diagonal(&mesh);
    let thickness = p.max_thickness.unwrap_or(0.01 * diag);
    let tile = p.fiber_tile.unwrap_or(diag / 8.0);
    let mapping = Mapping::new(&mesh, tile);
    let shells = Shells {
        mesh: &mesh,
        normals: &normals,
        amount: &amount,
        thickness,
        shells: p.shells,
        mapping: &mapping,
        texels_per_metre: side as f32 / tile,
        textures: &textures,
        noise: &noise,
        noise_side: side as usize,
        dust_color: p.dust_color_linear(),
    };
    let (w, h) = (p.view.width, p.view.height);
    let light = MeshLighting::for_view(&p.view, &mesh);
    let mut camera = p.view.camera_for(&mesh, w, h);
    if p.close_up {
        if let crate::params::CameraSpec::Orbit {
            azimuth_deg,
            elevation_deg,
            distance,
            fov_deg,
        } = p.view.camera
        {
            // Framed by D per unit stickiness (D ∝ K): K = 0 frames the patch dust would cover,
            // so a request without dust shows the same place as the dusty one (session 16's
            // survey compared the dusty patch with the mesh's centre). K > 0 uses D itself.
            let unit_amount: Vec<f32>;
            let framing = if p.stickiness > 0.0 {
                &amount
            } else {
                let unit = AmountModel {
                    stickiness: 1.0,
                    ..model
                };
                unit_amount = normals
                    .iter()
                    .zip(&exposure)
                    .map(|(n, e)| directional(&unit, *n, u) * e)
                    .collect();
                &unit_amount
            };
            let target = close_up_target(&mesh, framing, camera.eye);
            let d = distance.unwrap_or(f64::from(diag) / 10.0);
            camera = Camera::orbit(target, azimuth_deg, elevation_deg, d, fov_deg);
        }
    }
    let base = MeshInstance {
        positions: &mesh.positions,
        normals: Some(&normals),
        triangles: &mesh.triangles,
        colors: MeshColors::Materials(&mesh),
    };
    let view = MeshRenderer::new(&[base], &camera, &light, w, h, shells.bounds(), ctl)?;
    let overlay = shell_overlay(&view, &camera, &shells, ctl, (0.45, 0.75))?;
    lap("shells", t0);
    let t0 = Instant::now();
    let image = view.render(Some(&overlay), ctl, (0.75, 0.8))?;
    drop(overlay);
    lap("render", t0);

    // D on the mesh.
    let t0 = Instant::now();
    let k = p.stickiness.max(1e-6);
    let colors: Vec<[f32; 3]> = amount.iter().map(|d| viridis(d / k)).collect();
    let flat_light = MeshLighting {
        shadows: false,
        ..light.clone()
    };
    let amount_view = MeshRenderer::new(
        &[MeshInstance {
            colors: MeshColors::PerVertex(&colors),
            ..base
        }],
        &camera,
        &flat_light,
        w,
        h,
        None,
        ctl,
    )?;
    let amount_image = amount_view.render(None, ctl, (0.8, 0.85))?;
    drop(amount_view);
    lap("dust_amount", t0);

    // Outputs.
    ctl.progress("encode", 0.85);
    let t0 = Instant::now();
    let render_png = encode_rgba(&image);
    let amount_png = encode_rgba(&amount_image);
    let fibers_png = encode_rgba(&atlas.preview(p.dust_color.srgb8()));
    let glb = dusty_glb(
        &shells,
        &atlas,
        Some(json!({"pipeline": "dust", "shells": p.shells})),
    );
    lap("encode", t0);

    let n = amount.len().max(1) as f64;
    let dusty = amount.iter().filter(|&&d| d > 0.0).count();
    let report = json!({
        "pipeline": "dust",
        "params": serde_json::to_value(p).unwrap_or_default(),
        "input": {
            "vertices": input.positions.len(),
            "triangles": input.triangles.len(),
            "parts": input.parts.len(),
            "bounds": input.bounds().map(|(lo, hi)| [lo, hi]),
            "has_normals": input.normals.is_some(),
            "has_uvs": input.uvs.is_some(),
            "has_vertex_colors": input.colors.is_some(),
            "textures": input.textures.iter().map(|t| json!({"name": t.name, "mime": t.mime, "width": t.width, "height": t.height})).collect::<Vec<_>>(),
            "notes": input.notes,
        },
        "surface": {
            "vertices": mesh.positions.len(),
            "max_thickness_m": thickness,
            "fiber_tile_m": tile,
            "mapping": match mapping { Mapping::Uv { .. } => "uv", Mapping::Triplanar { .. } => "triplanar" },
        },
        "amount": {
            "mean": amount.iter().map(|&d| f64::from(d)).sum::<f64>() / n,
            "max": amount.iter().copied().fold(0.0f32, f32::max),
            "dusty_vertex_fraction": dusty as f64 / n,
            "mean_exposure": exposure.iter().map(|&e| f64::from(e)).sum::<f64>() / n,
        },
        "fibers": {
            "texture_size": side,
            "per_shell": fiber_counts,
            "atlas": {"columns": atlas.columns, "rows": atlas.rows, "width": atlas.width(), "height": atlas.height()},
            "preview_cell": atlas.side.min(super::export::PREVIEW_CELL),
        },
        "timings": timings.iter().map(|(s, ms)| json!({"stage": s, "ms": ms})).collect::<Vec<_>>(),
        "total_ms": t_all.elapsed().as_secs_f64() * 1e3,
    });
    ctl.progress("done", 1.0);
    Ok(vec![
        Output::new("render.png", "image/png", render_png),
        Output::new("fibers.png", "image/png", fibers_png),
        Output::new("dust_amount.png", "image/png", amount_png),
        Output::new("dusty.glb", "model/gltf-binary", glb),
        Output::new(
            "report.json",
            "application/json",
            serde_json::to_vec_pretty(&report).unwrap_or_default(),
        ),
    ])
}
