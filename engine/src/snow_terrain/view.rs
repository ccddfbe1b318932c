//! How the terrain is shown by default (issue 17): the automatic vertical exaggeration and the
//! camera that fills the image with the terrain. The paper draws its figures from hand-placed
//! viewpoints; these are this service's choices for "no parameters", documented at
//! [`super::params::View`].

use rayon::prelude::*;

use crate::geom::camera::Camera;
use crate::geom::vec::{normalized, DVec3};
use crate::geom::Dem;
use crate::params::CameraSpec;
use crate::render::terrain::TerrainScene;

/// Relief (highest − lowest valid elevation) as a fraction of the longer horizontal side that
/// the automatic exaggeration raises small reliefs to.
pub const RELIEF_TARGET: f64 = 0.08;
/// Largest automatic exaggeration.
pub const MAX_AUTO_EXAGGERATION: f64 = 8.0;

/// The relief of `dem` in metres and its longer horizontal side in metres; `None` when every
/// cell is nodata.
pub fn relief_and_extent(dem: &Dem) -> Option<(f64, f64)> {
    relief_and_extent_of(dem, dem.stats())
}

/// [`relief_and_extent`] from the DEM's statistics already computed ([`Dem::stats`]; one
/// serial pass over the heights, ~20 ms at 4096², that the pipeline makes once).
pub fn relief_and_extent_of(dem: &Dem, stats: Option<(f32, f32, f64)>) -> Option<(f64, f64)> {
    let (lo, hi, _) = stats?;
    let extent = (dem.width.saturating_sub(1) as f64 * dem.dx)
        .max(dem.height.saturating_sub(1) as f64 * dem.dy);
    Some((f64::from(hi) - f64::from(lo), extent))
}

/// The automatic vertical exaggeration: `clamp(RELIEF_TARGET / (relief / extent), 1,
/// MAX_AUTO_EXAGGERATION)` rounded to 0.1 (1 for an all-nodata or single-cell DEM; the maximum
/// for a perfectly flat one).
pub fn auto_exaggeration(dem: &Dem) -> f32 {
    auto_exaggeration_of(relief_and_extent(dem))
}

/// [`auto_exaggeration`] from [`relief_and_extent`]'s answer.
pub fn auto_exaggeration_of(relief_and_extent: Option<(f64, f64)>) -> f32 {
    let Some((relief, extent)) = relief_and_extent else {
        return 1.0;
    };
    if extent <= 0.0 {
        return 1.0;
    }
    let ratio = relief / extent;
    let e = if ratio <= 0.0 {
        MAX_AUTO_EXAGGERATION
    } else {
        (RELIEF_TARGET / ratio).clamp(1.0, MAX_AUTO_EXAGGERATION)
    };
    ((e * 10.0).round() / 10.0) as f32
}

/// Grid points (world coordinates) used to frame the terrain: valid points on a lattice of at
/// most 64 × 64 plus every valid point of the four edges at the same spacing (the silhouette of
/// a DEM is mostly its edges and its highest ridges).
fn frame_points(scene: &TerrainScene) -> Vec<[f64; 3]> {
    let (w, h) = (scene.width, scene.height);
    let (sx, sz) = (w.div_ceil(64).max(1), h.div_ceil(64).max(1));
    let hx = w.saturating_sub(1) as f64 * scene.dx * 0.5;
    let hz = h.saturating_sub(1) as f64 * scene.dy * 0.5;
    let mut out = Vec::new();
    let mut push = |c: usize, r: usize| {
        let y = scene.heights[r * w + c];
        if !y.is_nan() {
            out.push([
                c as f64 * scene.dx - hx,
                f64::from(y),
                r as f64 * scene.dy - hz,
            ]);
        }
    };
    let rows = (0..h).step_by(sz).chain(std::iter::once(h - 1));
    for r in rows {
        let cols = (0..w).step_by(sx).chain(std::iter::once(w - 1));
        for c in cols {
            push(c, r);
        }
    }
    // Local maxima between lattice points would poke out of the frame: add the highest point of
    // each lattice block (the first one in row order on ties). Block rows in parallel, then in
    // order: the same points whatever the thread count.
    let block_rows: Vec<Vec<(usize, usize)>> = (0..h)
        .step_by(sz)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|bj| {
            let r1 = (bj + sz).min(h);
            (0..w)
                .step_by(sx)
                .filter_map(|bi| {
                    let c1 = (bi + sx).min(w);
                    let mut best: Option<(usize, usize, f32)> = None;
                    for r in bj..r1 {
                        for (c, &y) in scene.heights[r * w + bi..r * w + c1].iter().enumerate() {
                            if !y.is_nan() && best.is_none_or(|b| y > b.2) {
                                best = Some((bi + c, r, y));
                            }
                        }
                    }
                    best.map(|(c, r, _)| (c, r))
                })
                .collect()
        })
        .collect();
    for (c, r) in block_rows.into_iter().flatten() {
        push(c, r);
    }
    out
}

/// The camera of `spec` for `scene`. An orbit without a `distance` and with `fill` frames the
/// terrain's own points ([`frame_points`]) within 95 % of the frame and then moves the orbit's
/// centre so that their projection is centred (two rounds: the framing distance changes with
/// the centre); otherwise [`CameraSpec::camera`] (the bounding box within 92 %).
pub fn camera(spec: &CameraSpec, scene: &TerrainScene, aspect: f64, fill: bool) -> Camera {
    let bounds = scene.bounds();
    let CameraSpec::Orbit {
        azimuth_deg,
        elevation_deg,
        distance: None,
        fov_deg,
    } = *spec
    else {
        return spec.camera(bounds, aspect);
    };
    let Some((lo, hi)) = bounds.filter(|_| fill) else {
        return spec.camera(bounds, aspect);
    };
    let points = frame_points(scene);
    if points.is_empty() {
        return spec.camera(bounds, aspect);
    }
    const MARGIN: f64 = 0.95;
    let mut center = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
    let mut cam = Camera::orbit_fit(
        center,
        azimuth_deg,
        elevation_deg,
        fov_deg,
        aspect,
        &points,
        MARGIN,
    );
    for _ in 0..2 {
        // The projection's extent, and the world offset that centres it (at the target's depth).
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        let proj = cam.projector(aspect);
        for p in &points {
            if let Some([x, y]) = proj.project(*p) {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
        if x0 > x1 {
            break;
        }
        let to_target = DVec3::from(cam.target) - DVec3::from(cam.eye);
        let f = normalized(to_target);
        let r = normalized(f.cross(DVec3::from(cam.up)));
        let u = r.cross(f);
        let d = to_target.dot(f);
        let tan_half = (fov_deg.clamp(1e-3, 179.0) * 0.5).to_radians().tan();
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        center = (DVec3::from(center)
            + (r * (cx * d * tan_half * aspect) + u * (cy * d * tan_half)))
            .to_array();
        cam = Camera::orbit_fit(
            center,
            azimuth_deg,
            elevation_deg,
            fov_deg,
            aspect,
            &points,
            MARGIN,
        );
    }
    cam
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::heightfield::GeoRef;

    fn dem(w: usize, h: usize, cell: f64, f: impl Fn(usize, usize) -> f32) -> Dem {
        Dem {
            width: w,
            height: h,
            heights: (0..w * h).map(|k| f(k % w, k / w)).collect(),
            dx: cell,
            dy: cell,
            georef: GeoRef::default(),
        }
    }

    #[test]
    fn small_relief_is_exaggerated_and_large_is_not() {
        // 150 km wide, 3 km of relief: 0.08 / 0.02 = 4.
        let wide = dem(1501, 1001, 100.0, |c, _| 3000.0 * c as f32 / 1500.0);
        assert_eq!(auto_exaggeration(&wide), 4.0);
        // 10 km wide, 1 km of relief: ratio 0.1 > 0.08, no exaggeration.
        let steep = dem(101, 101, 100.0, |c, _| 10.0 * c as f32);
        assert_eq!(auto_exaggeration(&steep), 1.0);
        // Flat: the cap.
        let flat = dem(50, 50, 30.0, |_, _| 12.0);
        assert_eq!(auto_exaggeration(&flat), MAX_AUTO_EXAGGERATION as f32);
    }

    /// The fill framing puts the terrain's points inside the frame, touching it on at least
    /// one side within a few per cent (it fills the image), and centred.
    #[test]
    fn fill_framing_fits_and_fills() {
        let d = dem(200, 120, 50.0, |c, r| {
            let (x, z) = (c as f32 - 100.0, r as f32 - 60.0);
            800.0 * (-(x * x + z * z) / 900.0).exp()
        });
        let scene = TerrainScene {
            width: d.width,
            height: d.height,
            dx: d.dx,
            dy: d.dy,
            heights: &d.heights,
            albedo: &[],
        };
        let spec = CameraSpec::Orbit {
            azimuth_deg: 200.0,
            elevation_deg: 30.0,
            distance: None,
            fov_deg: 40.0,
        };
        let aspect = 1.5;
        let cam = camera(&spec, &scene, aspect, true);
        let pts = frame_points(&scene);
        let ndc: Vec<[f64; 2]> = pts
            .iter()
            .map(|p| cam.project_ndc(*p, aspect).unwrap())
            .collect();
        let ext = |k: usize| {
            ndc.iter()
                .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p[k]), b.max(p[k])))
        };
        let ((x0, x1), (y0, y1)) = (ext(0), ext(1));
        assert!(x0 >= -0.951 && x1 <= 0.951 && y0 >= -0.951 && y1 <= 0.951);
        assert!(x1 - x0 > 1.8 || y1 - y0 > 1.8, "{x0} {x1} {y0} {y1}");
        assert!((x0 + x1).abs() < 0.05 && (y0 + y1).abs() < 0.05);
    }
}
