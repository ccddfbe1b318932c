//! Clouds from volumes in the wild (issue 18), through the registry as a user's request runs:
//! every committed real volume (`tests/data/volume`, provenance in its README: 0/255
//! segmentation masks, MR scans in int16/uint16/uint8/float, anisotropic voxels) with **no
//! parameters** renders with visible lighting, takes a sun-colour stroke inside the cloud and a
//! shadow drag, and an ambient stroke on it stays a local change. Also the edits' two refusals,
//! the coarse ambient solve against the full-resolution one, and golden images of three of the
//! volumes.

use phenomena_engine::cloud::edit::ambient::{propagate_paint_with, MAX_SOLVE_VOXELS};
use phenomena_engine::cloud::edit::{apply_edit, Edit, EditError};
use phenomena_engine::cloud::light::SunLight;
use phenomena_engine::cloud::CloudState;
use phenomena_engine::geom::Volume;
use phenomena_engine::params::Limits;
use phenomena_engine::registry::{self, Job, PipelineKind, PipelineParams, RunFailure};
use phenomena_engine::render::RgbaImage;
use phenomena_engine::{NoControl, Refusal};
use serde_json::{json, Value};

use super::render::decode_rgba;
use crate::support::golden::assert_golden;

/// The committed real volumes (file names under `tests/data/volume`).
pub const WILD: &[&str] = &[
    "frog_body_mask_4x.nrrd",
    "colin27_brain_mask_2x.nrrd",
    "inia19_macaque_t1_2x.nrrd",
    "volpack_brainsmall.nrrd",
    "nibabel_anatomical_i16be.nrrd",
    "pydicom_emri_small_u16.nrrd",
    "dipy_aniso_vox_t1_i16.nrrd",
];

/// The view the tests render and edit at.
const W: u32 = 160;
const H: u32 = 120;

pub fn wild_bytes(name: &str) -> Vec<u8> {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data/volume")
        .join(name);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn run(kind: PipelineKind, params: Value, bytes: &[u8], name: &str) -> Result<Outputs, RunFailure> {
    let l = Limits::default();
    let p = PipelineParams::parse(kind, &params, &l).unwrap();
    let job = registry::decode(p, bytes, Some(name), &l).unwrap();
    registry::run(&job, &NoControl)
        .map(|o| Outputs(o.into_iter().map(|o| (o.name, o.bytes)).collect()))
}

fn volume_of(bytes: &[u8], name: &str) -> Volume {
    let l = Limits::default();
    let p = PipelineParams::parse(PipelineKind::Cloud, &json!({}), &l).unwrap();
    match registry::decode(p, bytes, Some(name), &l).unwrap() {
        Job::Cloud { volume, .. } => volume,
        _ => unreachable!(),
    }
}

struct Outputs(Vec<(String, Vec<u8>)>);

impl Outputs {
    fn get(&self, name: &str) -> &[u8] {
        &self
            .0
            .iter()
            .find(|(n, _)| n == name)
            .unwrap_or_else(|| panic!("no {name}"))
            .1
    }
    fn image(&self) -> RgbaImage {
        decode_rgba(self.get("render.png"))
    }
    fn state(&self) -> Value {
        serde_json::from_slice(self.get("state.json")).unwrap()
    }
}

/// Rec. 709 luminance of a pixel's (straight) sRGB bytes.
fn luma(p: &[u8]) -> f64 {
    0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2])
}

/// The cloud pixels: alpha ≥ ½.
fn cloud_pixels(img: &RgbaImage) -> Vec<[u32; 2]> {
    let mut out = Vec::new();
    for y in 0..img.height {
        for x in 0..img.width {
            if img.data[((y * img.width + x) * 4 + 3) as usize] >= 128 {
                out.push([x, y]);
            }
        }
    }
    out
}

/// Standard deviation over mean of the luminance of the cloud pixels.
fn lighting_contrast(img: &RgbaImage) -> f64 {
    let px = cloud_pixels(img);
    let l: Vec<f64> = px
        .iter()
        .map(|p| {
            let i = ((p[1] * img.width + p[0]) * 4) as usize;
            luma(&img.data[i..i + 4])
        })
        .collect();
    let n = l.len().max(1) as f64;
    let mean = l.iter().sum::<f64>() / n;
    let var = l.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    var.sqrt() / mean.max(1e-9)
}

fn default_render_of(bytes: &[u8], name: &str) -> Outputs {
    run(
        PipelineKind::Cloud,
        json!({"width": W, "height": H}),
        bytes,
        name,
    )
    .unwrap()
}

fn default_render(name: &str) -> Outputs {
    default_render_of(&wild_bytes(name), name)
}

/// The default render's lighting on one volume: the number of cloud pixels, the luminance's
/// standard deviation over its mean on them, and `state.json`.
fn default_lighting(bytes: &[u8], name: &str) -> (usize, f64, Value) {
    let out = default_render_of(bytes, name);
    let img = out.image();
    let cover = cloud_pixels(&img).len();
    let c = lighting_contrast(&img);
    let state = out.state();
    eprintln!(
        "{name}: κ {} ({} rays), {cover} cloud pixels, luminance std/mean {c:.3}",
        state["kappa"], state["kappa_auto"]["rays"]
    );
    (cover, c, state)
}

/// The default render of every real volume has visible lighting: the luminance's standard
/// deviation over the cloud pixels is at least 8 % of its mean (issue 18), and `state.json`
/// states the κ chosen and how.
/// `pydicom_emri_small_u16.nrrd` (a 64×64×10 slab seen face-on) meets it since the default sun
/// grazes a slab's plane ([`phenomena_engine::cloud::sun`]); before, with the sun on the same face
/// at 45°, its std/mean was 0.054.
#[test]
fn every_real_volume_renders_lit_by_default() {
    for name in WILD {
        let (cover, c, state) = default_lighting(&wild_bytes(name), name);
        assert!(cover > 200, "{name}: the cloud covers only {cover} pixels");
        assert!(c >= 0.08, "{name}: luminance std/mean {c:.3} < 0.08");
        assert!(state["kappa"].as_f64().is_some_and(|k| k > 0.0), "{name}");
        assert_eq!(state["kappa_auto"]["optical_depth"], json!(4.0), "{name}");
        assert!(state["kappa_auto"]["rule"]
            .as_str()
            .unwrap()
            .contains("median"));
    }
}

/// An explicit κ wins over the choice, and the state then says nothing of a choice.
#[test]
fn an_explicit_kappa_wins() {
    let name = WILD[0];
    let out = run(
        PipelineKind::Cloud,
        json!({"width": 32, "height": 24, "kappa": 7.5}),
        &wild_bytes(name),
        name,
    )
    .unwrap();
    let s = out.state();
    assert_eq!(s["kappa"], json!(7.5));
    assert!(s.get("kappa_auto").is_none(), "{s}");
}

/// The chosen κ makes the median optical depth through the cloud 4 whatever the density's
/// units: the same mask as 0/1 and as 0/255 gets κ in the ratio 255:1.
#[test]
fn the_chosen_kappa_follows_the_density_scale() {
    let v = volume_of(&wild_bytes(WILD[0]), WILD[0]);
    let scaled = Volume::new(
        v.dims,
        v.density.iter().map(|d| d / 255.0).collect(),
        v.bounds,
    )
    .unwrap();
    let sun = CloudState::default().sun_direction;
    let (k255, c255) = phenomena_engine::cloud::kappa::choose(&v, sun);
    let (k1, c1) = phenomena_engine::cloud::kappa::choose(&scaled, sun);
    assert!((k1 / k255 - 255.0).abs() < 0.255, "{k1} vs {k255}");
    assert_eq!(c255.rays, c1.rays);
    assert!((k255 * c255.median_column - 4.0).abs() < 1e-9);
}

fn edit(
    kind: &str,
    base: &Value,
    e: Value,
    bytes: &[u8],
    name: &str,
) -> Result<Outputs, RunFailure> {
    let mut e = e;
    e["width"] = json!(W);
    e["height"] = json!(H);
    run(
        PipelineKind::CloudEdit,
        json!({"kind": kind, "base": base, "edit": e}),
        bytes,
        name,
    )
}

/// The centroid of the cloud pixels and the pixels of the row through it that are cloud.
fn middle_row(img: &RgbaImage) -> ([f64; 2], Vec<[u32; 2]>) {
    let px = cloud_pixels(img);
    let n = px.len() as f64;
    let c = [
        px.iter().map(|p| f64::from(p[0])).sum::<f64>() / n,
        px.iter().map(|p| f64::from(p[1])).sum::<f64>() / n,
    ];
    let row = c[1].round() as u32;
    let strip: Vec<[u32; 2]> = px
        .iter()
        .copied()
        .filter(|p| p[1].abs_diff(row) <= 1)
        .collect();
    (c, strip)
}

/// A sun-colour stroke across the middle of the cloud's default render, and a shadow drag from
/// the middle to a point of the cloud to its right: the stroke's paint distance before and after,
/// or what went wrong.
fn stroke_and_drag(bytes: &[u8], name: &str) -> Result<(f64, f64), String> {
    let out = default_render_of(bytes, name);
    let img = out.image();
    let base = out.state();
    let (c, strip) = middle_row(&img);
    if strip.is_empty() {
        return Err("no cloud pixel on the middle row".into());
    }
    let paint = [255u8, 150, 80];
    let r = edit(
        "sun-color",
        &base,
        json!({"strokes": [{"color": "#ff9650", "pixels": strip}]}),
        bytes,
        name,
    )
    .map_err(|e| format!("sun-colour stroke refused: {e}"))?;
    let after = r.image();
    // The painted pixels' mean colour moves toward the paint.
    let dist = |im: &RgbaImage| {
        strip
            .iter()
            .map(|p| {
                let i = ((p[1] * im.width + p[0]) * 4) as usize;
                (0..3)
                    .map(|q| (f64::from(im.data[i + q]) - f64::from(paint[q])).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .sum::<f64>()
            / strip.len() as f64
    };
    let (d0, d1) = (dist(&img), dist(&after));
    // Shadow drag: from the centroid to the cloud pixel of its row farthest right.
    let from = [c[0].round() as u32, c[1].round() as u32];
    let to = *strip.iter().max_by_key(|p| p[0]).unwrap();
    let to = [from[0] + (to[0] - from[0].min(to[0])) * 2 / 3, to[1]];
    let s = edit(
        "sun-direction",
        &base,
        json!({"from": from, "to": to}),
        bytes,
        name,
    )
    .map_err(|e| format!("shadow drag {from:?} → {to:?} refused: {e}"))?
    .state();
    if s["sun_direction"] == base["sun_direction"] {
        return Err("the shadow drag left the sun where it was".into());
    }
    eprintln!(
        "{name}: sun-colour stroke of {} px: distance to paint {d0:.1} → {d1:.1}; drag {from:?} → {to:?}: sun {}",
        strip.len(),
        s["sun_direction"]
    );
    Ok((d0, d1))
}

/// On every real volume with no parameters: a sun-colour stroke across the middle of the cloud
/// succeeds (and moves the painted pixels toward the paint), and a shadow drag from the middle
/// to a point of the cloud to its right succeeds.
#[test]
fn strokes_and_drags_succeed_on_every_real_volume() {
    for name in WILD {
        let (d0, d1) =
            stroke_and_drag(&wild_bytes(name), name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(d1 < d0, "{name}: paint distance {d0:.1} → {d1:.1}");
    }
}

/// Mean absolute change of the sRGB bytes of two renders, per cloud pixel, split into pixels
/// within `near` pixels of `at` and those farther than `far`.
fn change_near_far(
    a: &RgbaImage,
    b: &RgbaImage,
    at: [f64; 2],
    near: f64,
    far: f64,
) -> (f64, f64, usize, usize) {
    let (mut sn, mut nn, mut sf, mut nf) = (0.0, 0usize, 0.0, 0usize);
    for p in cloud_pixels(a) {
        let i = ((p[1] * a.width + p[0]) * 4) as usize;
        let d: f64 = (0..3)
            .map(|q| (f64::from(a.data[i + q]) - f64::from(b.data[i + q])).abs())
            .sum::<f64>()
            / 3.0;
        let r = (f64::from(p[0]) - at[0]).hypot(f64::from(p[1]) - at[1]);
        if r <= near {
            sn += d;
            nn += 1;
        } else if r >= far {
            sf += d;
            nf += 1;
        }
    }
    (sn / nn.max(1) as f64, sf / nf.max(1) as f64, nn, nf)
}

/// A dab of paint centred at `at`, radius `r` pixels, on cloud pixels only.
fn dab(img: &RgbaImage, at: [u32; 2], r: u32) -> Vec<[u32; 2]> {
    cloud_pixels(img)
        .into_iter()
        .filter(|p| {
            let (dx, dy) = (
                f64::from(p[0]) - f64::from(at[0]),
                f64::from(p[1]) - f64::from(at[1]),
            );
            dx.hypot(dy) <= f64::from(r)
        })
        .collect()
}

/// An ambient stroke (a dab a quarter of the way across the middle row of the default render):
/// the mean change of the cloud pixels near it (within the dab's radius + 4 px) and far from it
/// (beyond half the cloud's width), and how many of each; or what went wrong.
fn ambient_dab(bytes: &[u8], name: &str) -> Result<(f64, f64, usize, usize), String> {
    let out = default_render_of(bytes, name);
    let img = out.image();
    let base = out.state();
    let px = cloud_pixels(&img);
    let (Some(xmin), Some(xmax)) = (px.iter().map(|p| p[0]).min(), px.iter().map(|p| p[0]).max())
    else {
        return Err("no cloud pixel".into());
    };
    let (c, strip) = middle_row(&img);
    // The dab: a quarter of the way across the middle row.
    let target = f64::from(xmin) + 0.25 * f64::from(xmax - xmin);
    let at = *strip
        .iter()
        .min_by(|a, b| {
            (f64::from(a[0]) - target)
                .abs()
                .total_cmp(&(f64::from(b[0]) - target).abs())
        })
        .ok_or("no cloud pixel on the middle row")?;
    let pixels = dab(&img, at, 4);
    let r = edit(
        "ambient",
        &base,
        json!({"strokes": [{"color": "#ff2000", "pixels": pixels}]}),
        bytes,
        name,
    )
    .map_err(|e| format!("ambient stroke refused: {e}"))?;
    let after = r.image();
    let half = 0.5 * f64::from(xmax - xmin);
    let (near, far, nn, nf) = change_near_far(
        &img,
        &after,
        [f64::from(at[0]), f64::from(at[1])],
        8.0,
        half,
    );
    eprintln!(
        "{name}: ambient dab at {at:?} (centre {c:?}): mean change near {near:.2} ({nn} px), far {far:.2} ({nf} px)"
    );
    Ok((near, far, nn, nf))
}

/// On every real volume: an ambient stroke (a dab on the left part of the cloud) is a local
/// change — the cloud pixels far from it (beyond half the cloud's width) change less than those
/// near it (within the dab's radius + 4 px), on average by more than 2×; before issue 18 a dab
/// turned the whole silhouette the paint's colour.
#[test]
fn an_ambient_stroke_stays_local_on_every_real_volume() {
    for name in WILD {
        let (near, far, nn, nf) =
            ambient_dab(&wild_bytes(name), name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(nn > 0 && nf > 0, "{name}: {nn} near, {nf} far");
        assert!(
            near > 1.0,
            "{name}: the dab changed nothing near it ({near:.2})"
        );
        assert!(
            far < 0.5 * near,
            "{name}: far pixels changed {far:.2}, near ones {near:.2}"
        );
    }
}

/// The two refusals of a stroke are told apart: paint on empty sky misses the cloud; paint on
/// cloud that no sunlight reaches (the sun straight below a dense mask seen from above) is "not
/// lit" — each with its own problem type.
#[test]
fn a_stroke_on_sky_and_a_stroke_on_unlit_cloud_are_different_refusals() {
    let name = WILD[1];
    let bytes = wild_bytes(name);
    let out = default_render(name);
    let base = out.state();
    match edit(
        "sun-color",
        &base,
        json!({"strokes": [{"color": "#ffffff", "pixels": [[0, 0], [1, 0], [0, 1]]}]}),
        &bytes,
        name,
    ) {
        Err(RunFailure::Refused { reason, detail }) => {
            assert_eq!(reason, Refusal::StrokeMissesCloud);
            assert!(detail.contains("misses the cloud"), "{detail}");
        }
        other => panic!("expected a refusal, got {:?}", other.err()),
    }
    // The sun below the volume, a κ 50× the chosen one, seen from above.
    let mut dark = base.clone();
    dark["sun_direction"] = json!([0.0, -1.0, 0.0]);
    dark["kappa"] = json!(base["kappa"].as_f64().unwrap() * 50.0);
    let view =
        json!({"width": W, "height": H, "camera": {"azimuth_deg": 200, "elevation_deg": 60}});
    let seen = run(
        PipelineKind::Cloud,
        {
            let mut p = dark.clone();
            for (k, v) in view.as_object().unwrap() {
                p[k] = v.clone();
            }
            p
        },
        &bytes,
        name,
    )
    .unwrap()
    .image();
    let (_, strip) = middle_row(&seen);
    let mut e = view.clone();
    e["strokes"] = json!([{"color": "#ffffff", "pixels": strip}]);
    match run(
        PipelineKind::CloudEdit,
        json!({"kind": "sun-color", "base": dark, "edit": e}),
        &bytes,
        name,
    ) {
        Err(RunFailure::Refused { reason, detail }) => {
            assert_eq!(reason, Refusal::StrokeNotLit);
            assert_eq!(
                detail,
                "nothing under the stroke is lit by the sun: move the sun or lower κ"
            );
        }
        other => panic!("expected a refusal, got {:?}", other.err()),
    }
}

/// The `set` edit replaces κ (dropping the choice), the sun and its colour; at least one.
#[test]
fn the_set_edit_replaces_kappa_sun_and_color() {
    let name = WILD[3];
    let bytes = wild_bytes(name);
    let base = default_render(name).state();
    let out = edit(
        "set",
        &base,
        json!({"kappa": 3.5, "sun_azimuth_deg": 90, "sun_elevation_deg": 0, "sun_color": "#ff8000"}),
        &bytes,
        name,
    )
    .unwrap();
    let s = out.state();
    assert_eq!(s["kappa"], json!(3.5));
    assert!(s.get("kappa_auto").is_none());
    let d: Vec<f64> = serde_json::from_value(s["sun_direction"].clone()).unwrap();
    assert!((d[0] - 1.0).abs() < 1e-12 && d[1].abs() < 1e-12, "{d:?}");
    let c: Vec<f64> = serde_json::from_value(s["sun_color"].clone()).unwrap();
    assert!(
        (c[0] - 1.0).abs() < 1e-6 && (c[1] - 0.2158605).abs() < 1e-4 && c[2] == 0.0,
        "{c:?}"
    );
    // Only the sun colour: κ and its choice stay.
    let out = edit("set", &base, json!({"sun_color": [2, 2, 2]}), &bytes, name).unwrap();
    let s = out.state();
    assert_eq!(s["kappa"], base["kappa"]);
    assert_eq!(s["kappa_auto"], base["kappa_auto"]);
    let e = PipelineParams::parse(
        PipelineKind::CloudEdit,
        &json!({"kind": "set", "base": base, "edit": {}}),
        &Limits::default(),
    )
    .unwrap_err();
    assert_eq!(e.field, "edit.kappa");
}

/// The coarse ambient solve (the volume solved on ≤ [`MAX_SOLVE_VOXELS`] voxels and upsampled
/// with the guide) against the full-resolution solve, on a real mask at 2× (k = 2) and the MR
/// scan (k = 3 for both): the relative RMS difference of the *change* the edit makes to the
/// field, over the voxels it changes, stays under 50 % (measured: mask 0.17, MR 0.45 — the
/// difference sits at the edge of the painted tube, where the full solve has the sharper
/// falloff), and the renders differ by under 2 sRGB codes on average over the cloud pixels
/// (measured 1.35 and 1.33; with the density floor, which leaves brainsmall's head without its
/// fog box: mask 0.169 / 1.35, MR 0.231 / 1.97 — fewer cloud pixels, the same edit; figures in
/// BENCHMARKS.md "Clouds").
#[test]
fn coarse_ambient_solve_is_close_to_the_full_one() {
    for name in ["colin27_brain_mask_2x.nrrd", "volpack_brainsmall.nrrd"] {
        let bytes = wild_bytes(name);
        let v = volume_of(&bytes, name);
        let out = default_render(name);
        let img = out.image();
        let base: CloudState = serde_json::from_value(out.state()).unwrap();
        let (_, strip) = middle_row(&img);
        let at = strip[strip.len() / 3];
        let e = Edit::from_json(
            "ambient",
            &json!({"width": W, "height": H,
                    "strokes": [{"color": "#ff2000", "pixels": dab(&img, at, 5)}]}),
            &Limits::default(),
        )
        .unwrap();
        let Edit::Ambient(ae) = &e else {
            unreachable!()
        };
        let light =
            SunLight::compute(&v, base.sun_direction, base.kappa.unwrap(), &NoControl).unwrap();
        let (full, _) =
            propagate_paint_with(&v, &light, ae, &base, None, usize::MAX, &NoControl).unwrap();
        let (coarse, _) =
            propagate_paint_with(&v, &light, ae, &base, None, MAX_SOLVE_VOXELS, &NoControl)
                .unwrap();
        let amb = base.ambient.map(|x| x as f32);
        let (mut e2, mut r2) = (0f64, 0f64);
        for (a, b) in full.rgb.iter().zip(&coarse.rgb) {
            for q in 0..3 {
                let df = f64::from(a[q] - amb[q]);
                if df.abs() > 1e-6 || (b[q] - amb[q]).abs() > 1e-6 {
                    e2 += f64::from(a[q] - b[q]).powi(2);
                    r2 += df * df;
                }
            }
        }
        let rel = (e2 / r2).sqrt();
        // The renders of both fields at the edit's view.
        let view = e.view().clone();
        let render = |f| {
            let l = phenomena_engine::cloud::run::render(&v, &base, Some(f), &view, &NoControl)
                .unwrap();
            l.to_image(
                base.sun_color.map(|x| x as f32),
                None,
                phenomena_engine::cloud::march::Show::All,
            )
        };
        let (a, b) = (render(&full), render(&coarse));
        let px = cloud_pixels(&a);
        let mean_codes = px
            .iter()
            .map(|p| {
                let i = ((p[1] * a.width + p[0]) * 4) as usize;
                (0..3)
                    .map(|q| f64::from(a.data[i + q].abs_diff(b.data[i + q])))
                    .sum::<f64>()
                    / 3.0
            })
            .sum::<f64>()
            / px.len() as f64;
        eprintln!(
            "{name} {:?}: coarse vs full ambient change: relative RMS {rel:.3}, render mean |Δ| {mean_codes:.3} codes",
            v.dims
        );
        assert!(rel < 0.5, "{name}: relative RMS {rel}");
        assert!(mean_codes < 2.0, "{name}: {mean_codes} codes");
    }
}

/// The pins of an ambient stroke keep their colour exactly whether the solve is coarse or not.
#[test]
fn the_painted_voxels_keep_the_paint_in_the_coarse_solve() {
    let name = "volpack_brainsmall.nrrd";
    let bytes = wild_bytes(name);
    let v = volume_of(&bytes, name);
    let out = default_render(name);
    let img = out.image();
    let base: CloudState = serde_json::from_value(out.state()).unwrap();
    let (_, strip) = middle_row(&img);
    let e = Edit::from_json(
        "ambient",
        &json!({"width": W, "height": H,
                "strokes": [{"color": [0.2, 0.9, 0.1], "pixels": dab(&img, strip[0], 3)}]}),
        &Limits::default(),
    )
    .unwrap();
    let out = apply_edit(&v, &base, None, &e, &NoControl).unwrap();
    let Edit::Ambient(ae) = &e else {
        unreachable!()
    };
    let pins = phenomena_engine::cloud::edit::ambient::pins(&v, ae);
    assert!(!pins.is_empty());
    let f = out.ambient.unwrap();
    for (i, c) in pins {
        assert_eq!(f.rgb[i], c);
    }
    assert_eq!(
        apply_edit(
            &v,
            &base,
            None,
            &Edit::from_json(
                "ambient",
                &json!({"width": W, "height": H, "strokes": [{"color": "#ff0000", "pixels": [[0, 0]]}]}),
                &Limits::default()
            )
            .unwrap(),
            &NoControl
        )
        .unwrap_err(),
        EditError::MissesCloud
    );
}

fn golden_wild(name: &str, case: &str) {
    let out = run(
        PipelineKind::Cloud,
        json!({"width": 200, "height": 150, "background": "#5b88c4"}),
        &wild_bytes(name),
        name,
    )
    .unwrap();
    assert_golden("cloud", case, &out.image(), 3, 0.005);
}

/// Golden images of three real volumes with no parameters but the background: a 0/255 mask,
/// an MR scan in uint8 and a float MR scan.
#[test]
fn golden_wild_frog_mask() {
    golden_wild("frog_body_mask_4x.nrrd", "wild-frog-mask");
}

#[test]
fn golden_wild_brainsmall() {
    golden_wild("volpack_brainsmall.nrrd", "wild-brainsmall");
}

#[test]
fn golden_wild_macaque() {
    golden_wild("inia19_macaque_t1_2x.nrrd", "wild-macaque");
}

/// Issue 18's cloud criteria on held-out volumes (not committed; `/work/heldout/volume`,
/// provenance in the README there): each volume the decoder reads, with no parameters, is
/// checked as the tests above check the committed ones (lighting std/mean ≥ 0.08, a sun-colour
/// stroke that moves toward its paint and a shadow drag, an ambient dab that changes far pixels
/// less than half as much as near ones); one line per volume, the default render written to OUT,
/// and the test fails at the end if any volume failed a criterion:
/// `cargo test -p phenomena-engine --test it cloud::wild::heldout_survey -- --ignored --nocapture`
/// (HELDOUT=dir, OUT=dir change the folders; default `/work/heldout/volume`, `/tmp/cloud_survey`).
#[test]
#[ignore]
fn heldout_survey() {
    use std::path::PathBuf;
    let dir = PathBuf::from(std::env::var("HELDOUT").unwrap_or("/work/heldout/volume".into()));
    let out = PathBuf::from(std::env::var("OUT").unwrap_or("/tmp/cloud_survey".into()));
    std::fs::create_dir_all(&out).unwrap();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.extension().is_some_and(|x| {
                ["nrrd", "nhdr", "vdb", "npy", "raw", "gz"].contains(&x.to_str().unwrap())
            })
        })
        .collect();
    files.sort();
    let mut failed = Vec::new();
    println!(
        "volume | dims | κ | cloud px | std/mean | stroke (paint distance) | ambient near / far"
    );
    for path in files {
        let name = path.file_name().unwrap().to_str().unwrap().to_owned();
        let bytes = std::fs::read(&path).unwrap();
        let l = Limits::default();
        let p = PipelineParams::parse(PipelineKind::Cloud, &json!({}), &l).unwrap();
        let dims = match registry::decode(p, &bytes, Some(&name), &l) {
            Ok(Job::Cloud { volume, .. }) => volume.dims,
            Ok(_) => unreachable!(),
            Err(e) => {
                println!("{name} | refused: {e}");
                continue;
            }
        };
        let (cover, c, state) = default_lighting(&bytes, &name);
        let render = default_render_of(&bytes, &name);
        std::fs::write(out.join(format!("{name}.png")), render.get("render.png")).unwrap();
        let stroke = stroke_and_drag(&bytes, &name);
        let amb = ambient_dab(&bytes, &name);
        let mut bad = Vec::new();
        if cover <= 200 || c < 0.08 {
            bad.push("lighting");
        }
        if !matches!(stroke, Ok((d0, d1)) if d1 < d0) {
            bad.push("stroke/drag");
        }
        if !matches!(amb, Ok((near, far, nn, nf)) if nn > 0 && nf > 0 && near > 1.0 && far < 0.5 * near)
        {
            bad.push("ambient locality");
        }
        println!(
            "{name} | {dims:?} | {} | {cover} | {c:.3} | {stroke:?} | {amb:?} | {}",
            state["kappa"],
            if bad.is_empty() {
                "ok".to_string()
            } else {
                format!("FAILS {bad:?}")
            }
        );
        if !bad.is_empty() {
            failed.push((name, bad));
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}
