//! Sparse snow (workshop §2.1(4) "積雪が非常に少量の場合" and §2.3(5) "例外的な処理"; SPEC §2 step 6):
//! where snow is too thin to model as an amount, or on faces at 90° or more to the ground where
//! it cannot rest, the paper shows *flakes stuck sparsely* to the surface, as a texture whose
//! sparseness follows the amount of snow and two angles. We export a per-vertex **coverage** in
//! [0, 1] (the share of the surface the flake texture covers) and a generated, tileable flake
//! texture ([`flake_texture`]).
//!
//! **Our reading of the paper's conditions** (§2.3(5)): "the larger the angle between the snowfall
//! direction and the face, the larger the sticking" and "the larger the angle to the ground, the
//! larger the sticking"; "combine them". With the face's unit normal `n`, the snowfall direction
//! `s` (unit, the way the snow travels, `[0, −1, 0]` without wind):
//!
//! * angle to the ground `γ = acos(n_y)` ∈ [0°, 180°] (0 flat and facing up, 90° a wall, 180° an
//!   underside), term `g = γ / 180°` ∈ [0, 1];
//! * angle of incidence `α = asin(n · (−s))` ∈ [−90°, 90°]: the angle between the snowfall
//!   direction and the face's plane, positive on the side the snow comes from, term
//!   `h = (1 + sin α) / 2` ∈ [0, 1] (1 when snow hits the face square on, ½ grazing, 0 from behind);
//! * "combined" as a product, `a = g · h` (both conditions must hold; an underside gets none);
//! * the amount (§2.1(4)): `f = min(depth / sparse_depth, 1)` (on a face at 90° or more the model
//!   rests no snow, so `depth` there is 0 unless averaged in from a neighbouring top face; counting
//!   it keeps the coverage continuous across 90°).
//!
//! `coverage = f + (1 − f) · a` where the face is at 90° or more to the ground or its snow is
//! thinner than `sparse_depth`; `0` elsewhere (deep snow on a face below 90°: the snow mesh covers
//! it). So coverage is non-decreasing in γ, in α and in the depth (below `sparse_depth`), 0 on open
//! flat ground under deep snow or with no snow at all (γ = 0 ⇒ a = 0, f = 0), and reaches 1 as thin
//! snow approaches `sparse_depth`, where the snow mesh takes over (in depth it is monotone up to
//! `sparse_depth` and drops to 0 beyond it on faces below 90°: that is the hand-over).
//!
//! **Occlusion** (workshop §2.1(4): the flakes are snow that reaches the face, so they follow the
//! snow probability too): the angle term is scaled by the point's snow probability `p`, the share
//! of the snowfall directions' shadow maps in which it is lit
//! ([`super::probability::point_probability`]), `coverage = f + (1 − f) · a · p`: a wall under an
//! eave gets fewer flakes than an open wall. The thin-snow term `f` already holds P (the depth is
//! `P · snowfall`).
//!
//! **Flakes in the render** ([`flake_particles`]): the coverage is turned into small flat flakes on
//! the surface, seeded, so `render.png` shows them as the glTF overlay does.
//!
//! Rejected: a sum `(g + h) / 2` (it gives a table's underside flakes under vertical snowfall,
//! where no snow reaches); the paper gives no formula, only the two monotone conditions above.
//!
//! The texture: white flakes (RGB 255, straight alpha) of random radius at random points on a torus,
//! so that the image tiles; seeded SplitMix64, deterministic. Cost: `O(size² + flakes · r²)`.

use crate::geom::mesh::bounds_of;
use crate::geom::unit as unit_vector;
use crate::geom::vec::{DVec3, Vec3};

/// Sparse-flake coverage from the two angles (degrees) and the snow amount (module doc).
/// `ground_deg` ∈ [0, 180] (clamped), `incidence_deg` ∈ [−90, 90] (clamped), `depth` and
/// `sparse_depth` in metres (`sparse_depth ≤ 0`: no thin-snow regime).
pub fn coverage_from_angles(
    ground_deg: f32,
    incidence_deg: f32,
    depth: f32,
    sparse_depth: f32,
) -> f32 {
    coverage_with_probability(ground_deg, incidence_deg, depth, sparse_depth, 1.0)
}

/// [`coverage_from_angles`] with the angle term `a` scaled by the snow probability `p` ∈ [0, 1]
/// of the point (module doc, "Occlusion"): `f + (1 − f) · a · p`.
pub fn coverage_with_probability(
    ground_deg: f32,
    incidence_deg: f32,
    depth: f32,
    sparse_depth: f32,
    p: f32,
) -> f32 {
    let gamma = ground_deg.clamp(0.0, 180.0);
    let steep = gamma >= 90.0;
    let thin = sparse_depth > 0.0 && depth < sparse_depth;
    if !steep && !thin {
        return 0.0;
    }
    let g = gamma / 180.0;
    let h = 0.5 * (1.0 + incidence_deg.clamp(-90.0, 90.0).to_radians().sin());
    let a = g * h * p.clamp(0.0, 1.0);
    let f = if sparse_depth <= 0.0 {
        0.0
    } else {
        (depth.max(0.0) / sparse_depth).min(1.0)
    };
    (f + (1.0 - f) * a).clamp(0.0, 1.0)
}

/// The two angles of a face with unit normal `normal` under snowfall direction `snowfall` (unit, the
/// way snow travels): `(ground_deg, incidence_deg)` as in the module doc.
pub fn face_angles(normal: [f32; 3], snowfall: [f32; 3]) -> (f32, f32) {
    let ground = normal[1].clamp(-1.0, 1.0).acos().to_degrees();
    let d = -(normal[0] * snowfall[0] + normal[1] * snowfall[1] + normal[2] * snowfall[2]);
    let incidence = d.clamp(-1.0, 1.0).asin().to_degrees();
    (ground, incidence)
}

/// Coverage of one face (module doc).
pub fn face_coverage(normal: [f32; 3], snowfall: [f32; 3], depth: f32, sparse_depth: f32) -> f32 {
    let (g, i) = face_angles(normal, snowfall);
    coverage_from_angles(g, i, depth, sparse_depth)
}

/// Per-vertex coverage of a mesh (e.g. the displaced mesh): per face, [`face_coverage`] of its
/// normal with the mean of its vertices' `depth` (metres); per vertex, the area-weighted mean of
/// its faces' (as for smooth normals); 0 for a vertex with no non-degenerate face. Allocates the
/// result.
pub fn vertex_coverage(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    depth: &[f32],
    snowfall: [f32; 3],
    sparse_depth: f32,
) -> Vec<f32> {
    vertex_coverage_with_probability(positions, triangles, depth, None, snowfall, sparse_depth)
}

/// [`vertex_coverage`] with a per-vertex snow probability (module doc, "Occlusion"): each face's
/// angle term is scaled by the mean of its vertices' `probability` (`None`: 1).
pub fn vertex_coverage_with_probability(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    depth: &[f32],
    probability: Option<&[f32]>,
    snowfall: [f32; 3],
    sparse_depth: f32,
) -> Vec<f32> {
    let mut acc = vec![(0.0f64, 0.0f64); positions.len()];
    for &t in triangles {
        let [a, b, c] = t.map(|i| DVec3::from(positions[i as usize].map(f64::from)));
        let n = (b - a).cross(c - a);
        let len = n.length();
        let n = n.to_array();
        if len <= 0.0 || len.is_nan() {
            continue;
        }
        let unit = n.map(|x| (x / len) as f32);
        let d = t
            .iter()
            .map(|&i| depth.get(i as usize).copied().unwrap_or(0.0))
            .sum::<f32>()
            / 3.0;
        let p = probability.map_or(1.0, |pr| {
            t.iter()
                .map(|&i| pr.get(i as usize).copied().unwrap_or(1.0))
                .sum::<f32>()
                / 3.0
        });
        let (g, inc) = face_angles(unit, snowfall);
        let cov = f64::from(coverage_with_probability(g, inc, d, sparse_depth, p));
        let area = 0.5 * len;
        for &i in &t {
            let e = &mut acc[i as usize];
            e.0 += area * cov;
            e.1 += area;
        }
    }
    acc.into_iter()
        .map(|(s, w)| if w > 0.0 { (s / w) as f32 } else { 0.0 })
        .collect()
}

/// SplitMix64 step.
fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Uniform in [0, 1).
fn unit(state: &mut u64) -> f32 {
    (splitmix(state) >> 40) as f32 / (1u64 << 24) as f32
}

/// A tileable flake texture, `size × size` RGBA8 (row-major, straight alpha, sRGB white): about one
/// flake per 64 pixels, radii 0.8–2.5 px (scaled by `size / 256`), soft edges, alpha the maximum
/// over flakes; positions wrap around both edges (a torus), so the image tiles seamlessly.
/// Deterministic for `(size, seed)`. `size` is clamped to 4..=4096 (4096² × 4 B = 64 MiB, the largest
/// texture a glTF viewer should need). Allocates `size² × 4` bytes.
pub fn flake_texture(size: usize, seed: u64) -> Vec<u8> {
    let size = size.clamp(4, 4096);
    let mut alpha = vec![0.0f32; size * size];
    let mut st = seed ^ 0x5EED_F1A4_E000_0000;
    let flakes = (size * size) / 64;
    let scale = size as f32 / 256.0;
    let s = size as isize;
    for _ in 0..flakes {
        let cx = unit(&mut st) * size as f32;
        let cy = unit(&mut st) * size as f32;
        let r = (0.8 + 1.7 * unit(&mut st)) * scale.max(0.25);
        let peak = 0.6 + 0.4 * unit(&mut st);
        let reach = (r + 1.0).ceil() as isize;
        let (x0, y0) = (cx.floor() as isize, cy.floor() as isize);
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let (px, py) = (x0 + dx, y0 + dy);
                // Distance from the pixel centre (unwrapped), then wrap the pixel onto the torus.
                let fx = px as f32 + 0.5 - cx;
                let fy = py as f32 + 0.5 - cy;
                let d = (fx * fx + fy * fy).sqrt();
                let a = peak * (r + 0.5 - d).clamp(0.0, 1.0);
                if a > 0.0 {
                    let (wx, wy) = (px.rem_euclid(s) as usize, py.rem_euclid(s) as usize);
                    let cell = &mut alpha[wy * size + wx];
                    *cell = cell.max(a);
                }
            }
        }
    }
    let mut out = Vec::with_capacity(size * size * 4);
    for a in alpha {
        out.extend_from_slice(&[255, 255, 255, (a * 255.0).round() as u8]);
    }
    out
}

/// Side of the flake texture written into `displaced.glb`, pixels.
pub const FLAKE_TEXTURE_SIZE: usize = 256;

/// Tiles of the flake texture across the mesh's bounding-box diagonal: one tile is a eighth of
/// the diagonal, 25 cm on the 2.1 m Inventor table (256 px over 25 cm: ≈ 1 mm a pixel, flakes
/// 1.6–5 mm across, the size of real flakes).
///
/// Scaled to the scene, not fixed in metres, because meshes come in unknown units (as for the
/// default snowfall, [`super::params::default_rate`]): at a fixed 25 cm the 41-unit teapot had
/// 160 tiles across and its flakes were a sub-pixel grain in three.js at the framing of the whole
/// model; a share of the diagonal gives flakes the same size relative to the model, so the same
/// size on screen in any viewer that frames the model.
pub const FLAKE_TILES_PER_DIAGONAL: f64 = 8.0;

/// How far the flake overlay floats above the surface, as a share of the mesh's bounding-box
/// diagonal (see [`flake_overlay`]).
pub const FLAKE_LIFT: f32 = 1e-3;

/// The sparse-flake layer of `displaced.glb` (SPEC §2 step 6): a second surface carrying the flake
/// texture where the coverage is partial, to be drawn alpha-blended over the displaced mesh.
///
/// **Our reading of "exported as … a generated flake texture"** (the paper shows the flakes as a
/// texture on the surface, §2.3(5)): core glTF has no per-vertex blend between two textures, but
/// its base colour is `baseColorFactor × baseColorTexture × COLOR_0`, alpha included. So the flakes
/// are a second primitive with `alphaMode: BLEND`, the flake texture (white, its alpha the flakes)
/// and `COLOR_0 = (1, 1, 1, coverage)`: a flake's opacity is its texel's alpha × the coverage, and
/// where the coverage is 0 nothing shows.
///
/// **Why a lifted shell and not a coplanar copy.** A coplanar overlay relies on the viewer's depth
/// test passing on equal depths (three.js uses LessEqual; others use Less, and Blender's importer
/// merges the two primitives into one mesh, where Cycles sees coincident faces) and on both
/// primitives' vertex shaders giving bit-equal depths, which GLSL does not promise without
/// `invariant`. glTF has no polygon offset. So the overlay's vertices are the displaced vertices
/// moved along their smooth unit normal by [`FLAKE_LIFT`] × the bounding-box diagonal (2 mm on a
/// 2 m table): far above one step of a 24-bit depth buffer at any distance that frames the model
/// (≈ 1e-4 diagonal with the near plane at a thousandth of the distance), and too small to see.
///
/// **UVs** (`TEXCOORD_0`): per triangle, a planar projection along the axis its face normal is
/// most aligned with (tri-planar by the dominant axis), in units of one tile (the diagonal ÷
/// [`FLAKE_TILES_PER_DIAGONAL`]), so a flake has the same size everywhere on the model. Each overlay triangle has its own three vertices (no UV
/// stretching where the dominant axis changes between neighbouring faces; the seam this leaves
/// is invisible on a random texture).
///
/// Only triangles with coverage > 0 at one of their vertices are kept, in the input order; overlay
/// vertex `3k + j` is corner `j` of the `k`-th kept triangle and its alpha is that corner's
/// coverage. Deterministic; `O(triangles)`; allocates the overlay's arrays. Indices out of range
/// of `positions` panic (caller bug); `coverage` and `normals` must be as long as `positions`.
pub fn flake_overlay(
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    triangles: &[[u32; 3]],
    coverage: &[f32],
) -> FlakeOverlay {
    let diag = bounds_of(positions).map_or(0.0, |(lo, hi)| {
        (0..3)
            .map(|k| f64::from(hi[k] - lo[k]).powi(2))
            .sum::<f64>()
            .sqrt()
    });
    let (lift, per_tile) = if diag.is_finite() && diag > 0.0 {
        (
            (diag * f64::from(FLAKE_LIFT)) as f32,
            (FLAKE_TILES_PER_DIAGONAL / diag) as f32,
        )
    } else {
        (0.0, 1.0)
    };
    let mut out = FlakeOverlay::default();
    for t in triangles {
        let cov = t.map(|i| coverage[i as usize]);
        if cov.iter().all(|&c| c.is_nan() || c <= 0.0) {
            continue;
        }
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let (_, [s, r]) = crate::geom::box_projection(a, b, c);
        let base = out.positions.len() as u32;
        for (j, &i) in t.iter().enumerate() {
            let p = positions[i as usize];
            let n = match unit_vector(normals[i as usize]) {
                [0.0, 0.0, 0.0] => [0.0, 1.0, 0.0],
                n => n,
            };
            out.positions.push([0, 1, 2].map(|k| p[k] + n[k] * lift));
            out.normals.push(n);
            out.uvs.push([p[s] * per_tile, p[r] * per_tile]);
            let alpha = if cov[j].is_nan() {
                0.0
            } else {
                cov[j].clamp(0.0, 1.0)
            };
            out.colors.push([1.0, 1.0, 1.0, alpha]);
        }
        out.triangles.push([base, base + 1, base + 2]);
    }
    out
}

/// The arrays of [`flake_overlay`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FlakeOverlay {
    /// Vertices lifted off the surface, metres; three per triangle.
    pub positions: Vec<[f32; 3]>,
    /// The surface's smooth unit normals at those vertices.
    pub normals: Vec<[f32; 3]>,
    /// Flake-texture coordinates (tiles).
    pub uvs: Vec<[f32; 2]>,
    /// `(1, 1, 1, coverage)`.
    pub colors: Vec<[f32; 4]>,
    /// `[3k, 3k + 1, 3k + 2]`.
    pub triangles: Vec<[u32; 3]>,
}

/// How far the snow layer of `displaced.glb` ([`snow_layer`]) floats above the surface, as a
/// share of the bounding-box diagonal: half of [`FLAKE_LIFT`], so the flakes stay above it.
pub const SNOW_LAYER_LIFT: f32 = 0.5 * FLAKE_LIFT;

/// The snow of `displaced.glb` as a layer over the input's own materials: the displaced surface's
/// triangles with snow at a corner, lifted along the smooth normals by [`SNOW_LAYER_LIFT`] × the
/// bounding-box diagonal (why lifted: see [`flake_overlay`]), `COLOR_0 = (1, 1, 1, amount)`, to be
/// drawn alpha-blended in the snow colour. `amount` is the snow amount per vertex in [0, 1]
/// (`min(depth / sparse_depth, 1)`): where it is 1 the snow hides the surface, where it is 0 the
/// surface's own material shows (a textured model keeps its texture beside the snow). Core
/// glTF multiplies `COLOR_0` into the base colour, so whitening the surface itself cannot work on a
/// dark or textured material; a blended layer can. Vertices are shared between the kept
/// triangles (renumbered in first-use order). Deterministic; `O(triangles)`.
pub fn snow_layer(
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    triangles: &[[u32; 3]],
    amount: &[f32],
) -> SnowLayer {
    let diag = bounds_of(positions).map_or(0.0, |(lo, hi)| {
        (0..3)
            .map(|k| f64::from(hi[k] - lo[k]).powi(2))
            .sum::<f64>()
            .sqrt()
    });
    let lift = if diag.is_finite() {
        (diag * f64::from(SNOW_LAYER_LIFT)) as f32
    } else {
        0.0
    };
    let alpha = |i: u32| {
        let a = amount[i as usize];
        if a.is_nan() {
            0.0
        } else {
            a.clamp(0.0, 1.0)
        }
    };
    let mut remap = vec![u32::MAX; positions.len()];
    let mut out = SnowLayer::default();
    for t in triangles {
        if t.iter().all(|&i| alpha(i) <= 0.0) {
            continue;
        }
        let tri = t.map(|i| {
            let r = &mut remap[i as usize];
            if *r == u32::MAX {
                *r = out.positions.len() as u32;
                let p = positions[i as usize];
                let n = match unit_vector(normals[i as usize]) {
                    [0.0, 0.0, 0.0] => [0.0, 1.0, 0.0],
                    n => n,
                };
                out.positions.push([0, 1, 2].map(|k| p[k] + n[k] * lift));
                out.normals.push(n);
                out.colors.push([1.0, 1.0, 1.0, alpha(i)]);
            }
            *r
        });
        out.triangles.push(tri);
    }
    out
}

/// The arrays of [`snow_layer`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SnowLayer {
    /// Vertices lifted off the surface, metres.
    pub positions: Vec<[f32; 3]>,
    /// The surface's smooth unit normals at those vertices.
    pub normals: Vec<[f32; 3]>,
    /// `(1, 1, 1, amount)`.
    pub colors: Vec<[f32; 4]>,
    pub triangles: Vec<[u32; 3]>,
}

/// Flake geometry for the render (module doc, "Flakes in the render").
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Flakes {
    /// Vertex positions, metres.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals (the face's).
    pub normals: Vec<[f32; 3]>,
    /// Triangles (one per flake).
    pub triangles: Vec<[u32; 3]>,
    /// Circumradius of a flake, metres.
    pub radius: f32,
}

/// Flake radius as a share of the mesh's bounding-box diagonal: about 1.5 px across in a
/// default 900 × 600 render framing the whole model.
pub const FLAKE_RADIUS_PER_DIAGONAL: f32 = 1.0 / 600.0;

/// Share of a face with coverage 1 that its flakes cover.
pub const FLAKE_FILL: f32 = 0.5;

/// Sparse flakes as geometry: on every face of `positions`/`triangles` with mean vertex
/// `coverage` c > 0, `c · FLAKE_FILL · area / flake area` flakes (the fraction drawn with a
/// seeded coin) at uniform random points, each a triangle of circumradius
/// [`FLAKE_RADIUS_PER_DIAGONAL`] of the diagonal at a random angle in the face's plane, lifted a
/// third of its radius along the face normal (which side: `normals` at the first corner, the
/// surface's outside). At most `max_flakes`: beyond, the flakes grow so that the covered area stays
/// the same. Deterministic for `seed` (SplitMix64 per face). Allocates the output.
pub fn flake_particles(
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    triangles: &[[u32; 3]],
    coverage: &[f32],
    seed: u64,
    max_flakes: usize,
) -> Flakes {
    let Some((lo, hi)) = bounds_of(positions) else {
        return Flakes::default();
    };
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt();
    let mut radius = (diag * FLAKE_RADIUS_PER_DIAGONAL).max(1e-9);
    // A flake's area: an equilateral triangle of circumradius r.
    let flake_area = |r: f32| 1.299_038 * r * r;
    let face = |t: &[u32; 3]| -> Option<([f32; 3], f32, f32)> {
        let [a, b, c] = t.map(|i| positions.get(i as usize).copied());
        let (a, b, c) = (Vec3::from(a?), Vec3::from(b?), Vec3::from(c?));
        let n = (b - a).cross(c - a);
        let len = n.length();
        let n = n.to_array();
        let cov = t
            .iter()
            .map(|&i| coverage.get(i as usize).copied().unwrap_or(0.0))
            .sum::<f32>()
            / 3.0;
        (len > 0.0 && len.is_finite() && cov > 0.0).then(|| (n.map(|x| x / len), 0.5 * len, cov))
    };
    let wanted: f64 = triangles
        .iter()
        .filter_map(face)
        .map(|(_, area, cov)| f64::from(cov * FLAKE_FILL * area))
        .sum::<f64>()
        / f64::from(flake_area(radius));
    if wanted > max_flakes as f64 {
        radius *= (wanted / max_flakes.max(1) as f64).sqrt() as f32;
    }
    let mut out = Flakes {
        radius,
        ..Flakes::default()
    };
    for (ti, t) in triangles.iter().enumerate() {
        let Some((mut n, area, cov)) = face(t) else {
            continue;
        };
        // Outside: the side the vertex normals point to.
        if let Some(vn) = normals.get(t[0] as usize) {
            if n[0] * vn[0] + n[1] * vn[1] + n[2] * vn[2] < 0.0 {
                n = n.map(|x| -x);
            }
        }
        let mut st = seed ^ (ti as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x00F1_A4E5;
        let expect = cov * FLAKE_FILL * area / flake_area(radius);
        let mut count = expect.floor() as usize;
        if unit(&mut st) < expect - expect.floor() {
            count += 1;
        }
        let count = count.min(max_flakes.saturating_sub(out.triangles.len()));
        if count == 0 {
            continue;
        }
        let [a, b, c] = t.map(|i| positions[i as usize]);
        // In-plane axes.
        let e1 = unit_vector((Vec3::from(b) - Vec3::from(a)).to_array());
        let e2 = Vec3::from(n).cross(Vec3::from(e1)).to_array();
        for _ in 0..count {
            let (mut r1, mut r2) = (unit(&mut st), unit(&mut st));
            if r1 + r2 > 1.0 {
                (r1, r2) = (1.0 - r1, 1.0 - r2);
            }
            let lift = radius / 3.0;
            let centre =
                [0, 1, 2].map(|k| a[k] + r1 * (b[k] - a[k]) + r2 * (c[k] - a[k]) + n[k] * lift);
            let angle = unit(&mut st) * std::f32::consts::TAU;
            let base = out.positions.len() as u32;
            for q in 0..3 {
                let th = angle + q as f32 * std::f32::consts::TAU / 3.0;
                let (s, co) = th.sin_cos();
                out.positions
                    .push([0, 1, 2].map(|k| centre[k] + radius * (co * e1[k] + s * e2[k])));
                out.normals.push(n);
            }
            out.triangles.push([base, base + 1, base + 2]);
        }
    }
    out
}
