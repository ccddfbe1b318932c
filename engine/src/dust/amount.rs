//! Where dust lies and how much (SPEC §4 step 1; paper §2.1, after Hsu & Wong 1995, "Simulating
//! Dust Accumulation").
//!
//! The paper only says that the dust amount is controlled by cos θ = N·U (U: unit direction toward
//! the dust source), the dust's stickiness K and the surface's slipperiness s; the exact Hsu–Wong
//! formula is not in our papers. **Our reading** (SPEC §4):
//!
//! ```text
//! D(P) = K · max(0, N·U)^s · E(P)
//! ```
//!
//! a fall-off like Phong's specular term, with E(P) ∈ [0, 1] Hsu and Wong's surface-exposure factor,
//! computed here as ambient occlusion around U:
//!
//! - `exposure_rays` directions are spread over the hemisphere around U, cosine-weighted about U
//!   (dust falls mostly along −U), as a Fibonacci spiral (deterministic, no RNG) rotated about U by
//!   a per-vertex angle hashed from the vertex index (so neighbouring vertices do not share the
//!   same directions and banding turns into fine noise — still deterministic).
//! - A ray starts at P + ε·N (ε = 10⁻⁴ × the bounding-box diagonal, so the surface itself does not
//!   occlude) and *escapes* when it hits no triangle (obvhs's compressed wide BVH, any hit,
//!   through [`crate::geom::bvh::RayScene`]).
//! - A direction below the vertex's own tangent plane (d·N ≤ 0) is not cast and counts as escaped:
//!   the surface's self-shadowing is already the max(0, N·U)^s term, and E measures only the
//!   occlusion by the *rest* of the scene. Hence a lone tilted plane has E = 1 and D = K·cos^s θ
//!   exactly, and "less dust in crevices" comes from E alone. (Rejected: counting those rays as
//!   blocked — that would double-count the tilt and make E depend on θ on an open plane; and
//!   dividing by the number of rays above the plane — noisy near grazing, where few rays remain.)
//! - With `exposure` off, E = 1.
//!
//! N is the vertex normal: the file's normals when present, otherwise the area-weighted mean of the
//! adjacent face normals (see [`vertex_normals`]).
//!
//! Cost: building the BVH is O(T log T) and allocates; the rays are O(V · exposure_rays · log T),
//! parallel over vertices (rayon) with no allocation per vertex; the result does not depend on the
//! thread count (each vertex is computed independently and written to its own slot).

use glam::Vec3A;
use rayon::prelude::*;

use crate::geom::bvh::RayScene;
use crate::geom::mesh::Mesh;
use crate::geom::vec::{unit, Vec3};

/// The dust-amount model of SPEC §4 step 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmountModel {
    /// K, the dust's stickiness: the amount on a horizontal (N = U), fully exposed face.
    /// Unitless, ≥ 0. Default: 1.
    pub stickiness: f32,
    /// s, the surface's slipperiness: exponent of the N·U fall-off; larger s, less dust on tilted
    /// faces. Unitless, ≥ 0 (0: tilt does not matter while N·U > 0). Default: 2.
    pub slipperiness: f32,
    /// U, unit direction toward the dust source (world space, Y up). Default: up, `[0, 1, 0]`.
    pub source: [f32; 3],
    /// Whether the exposure term E(P) is computed (`exposure`); when off, E = 1. Default: true.
    pub exposure: bool,
    /// Number of hemisphere rays per vertex for E(P) (`exposure_rays`), ≥ 1. Default: 64.
    pub exposure_rays: u32,
}

impl Default for AmountModel {
    fn default() -> Self {
        Self {
            stickiness: 1.0,
            slipperiness: 2.0,
            source: [0.0, 1.0, 0.0],
            exposure: true,
            exposure_rays: 64,
        }
    }
}

/// Per-vertex unit normals: the mesh's own when it has them (renormalised), otherwise the
/// area-weighted mean of the adjacent faces' normals. A vertex with no area around it gets
/// `[0, 0, 0]` (no dust: N·U = 0). Allocates one `Vec` of `positions.len()`.
pub fn vertex_normals(mesh: &Mesh) -> Vec<[f32; 3]> {
    if let Some(n) = &mesh.normals {
        if n.len() == mesh.positions.len() {
            return n.iter().map(|v| unit(*v)).collect();
        }
    }
    let mut acc = vec![[0.0f32; 3]; mesh.positions.len()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let f = mesh.face_normal(t);
        for &i in tri {
            for (a, fk) in acc[i as usize].iter_mut().zip(f) {
                *a += fk;
            }
        }
    }
    acc.into_iter().map(unit).collect()
}

/// The directional factor K · max(0, N·U)^s (no exposure). `n` and `u` are unit vectors.
#[inline]
pub fn directional(model: &AmountModel, n: [f32; 3], u: [f32; 3]) -> f32 {
    let c = (n[0] * u[0] + n[1] * u[1] + n[2] * u[2]).min(1.0);
    if c <= 0.0 {
        0.0
    } else {
        model.stickiness * c.powf(model.slipperiness)
    }
}

/// `count` unit directions cosine-weighted over the hemisphere around `u` (a Fibonacci spiral,
/// deterministic). `u` must be a unit vector. Allocates.
pub fn hemisphere_directions(u: [f32; 3], count: u32) -> Vec<[f32; 3]> {
    let (t, b) = tangent_frame(u);
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..count)
        .map(|i| {
            let r = ((i as f32 + 0.5) / count as f32).sqrt();
            let phi = i as f32 * golden;
            let (x, y) = (r * phi.cos(), r * phi.sin());
            let z = (1.0 - r * r).max(0.0).sqrt();
            [
                x * t[0] + y * b[0] + z * u[0],
                x * t[1] + y * b[1] + z * u[1],
                x * t[2] + y * b[2] + z * u[2],
            ]
        })
        .collect()
}

/// An orthonormal pair perpendicular to the unit vector `u`.
fn tangent_frame(u: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let helper = if u[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let u = Vec3::from(u);
    let t = unit(Vec3::from(helper).cross(u).to_array());
    let b = u.cross(Vec3::from(t)).to_array();
    (t, b)
}

/// The scene for the exposure rays: obvhs's compressed wide BVH over the mesh's triangles,
/// built so that it holds on any real mesh ([`crate::geom::bvh::RayScene`]: depth within the
/// traversal stack, the scene scaled to the unit box).
pub struct ExposureScene {
    scene: RayScene,
    /// Ray-origin offset along the normal: 10⁻⁴ × the bounding-box diagonal.
    epsilon: f32,
}

impl std::fmt::Debug for ExposureScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExposureScene")
            .field("scene", &self.scene)
            .field("epsilon", &self.epsilon)
            .finish()
    }
}

impl ExposureScene {
    /// Builds the BVH over `mesh` (allocates; O(T log T)). Triangles of zero area are left out:
    /// no ray can be stopped by them.
    pub fn new(mesh: &Mesh) -> Self {
        let v = |i: u32| {
            let p = mesh.positions[i as usize];
            Vec3A::new(p[0], p[1], p[2])
        };
        let scene = RayScene::new(mesh.triangles.iter().map(|t| [v(t[0]), v(t[1]), v(t[2])]));
        let diag = mesh
            .bounds()
            .map(|(lo, hi)| {
                let d = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
            })
            .unwrap_or(1.0);
        Self {
            scene,
            epsilon: 1e-4 * diag.max(f32::MIN_POSITIVE),
        }
    }

    /// The depth of the scene's BVH (root 0), below obvhs's traversal stack of
    /// [`crate::geom::bvh::CWBVH_STACK`].
    pub fn depth(&self) -> usize {
        self.scene.depth()
    }

    /// Whether the ray from `origin` along the unit direction `dir` hits nothing.
    #[inline]
    fn escapes(&self, origin: Vec3A, dir: [f32; 3]) -> bool {
        self.scene
            .escapes(origin, Vec3A::new(dir[0], dir[1], dir[2]))
    }

    /// E(P) for a point `p` with unit normal `n`: the share of `dirs` (hemisphere directions
    /// around U, see [`hemisphere_directions`]), rotated about `u` by `angle` radians, that escape
    /// the scene; directions below the tangent plane count as escaped (module doc).
    pub fn exposure(
        &self,
        p: [f32; 3],
        n: [f32; 3],
        u: [f32; 3],
        dirs: &[[f32; 3]],
        angle: f32,
    ) -> f32 {
        if dirs.is_empty() {
            return 1.0;
        }
        let e = self.epsilon;
        let origin = Vec3A::new(p[0] + e * n[0], p[1] + e * n[1], p[2] + e * n[2]);
        let (s, c) = angle.sin_cos();
        let mut escaped = 0u32;
        for d in dirs {
            let d = rotate_about(*d, u, s, c);
            let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
            if dn <= 0.0 || self.escapes(origin, d) {
                escaped += 1;
            }
        }
        escaped as f32 / dirs.len() as f32
    }
}

/// Rodrigues rotation of `v` about the unit axis `k` by the angle with sine `s`, cosine `c`.
#[inline]
fn rotate_about(v: [f32; 3], k: [f32; 3], s: f32, c: f32) -> [f32; 3] {
    let (v, k) = (Vec3::from(v), Vec3::from(k));
    (v * c + k.cross(v) * s + k * k.dot(v) * (1.0 - c)).to_array()
}

/// Per-vertex rotation angle of the ray set about U: a hash of the vertex index mapped to
/// [0, 2π) (deterministic, independent of threads).
#[inline]
fn vertex_angle(i: usize) -> f32 {
    let mut x = (i as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 40) as f32 / (1u64 << 24) as f32 * std::f32::consts::TAU
}

/// Per-vertex exposure E(P) ∈ [0, 1] (all 1 when `model.exposure` is off). `normals` as from
/// [`vertex_normals`]. Parallel over vertices; allocates the result and the BVH.
pub fn vertex_exposure(mesh: &Mesh, normals: &[[f32; 3]], model: &AmountModel) -> Vec<f32> {
    let u = unit(model.source);
    if !model.exposure || model.exposure_rays == 0 || u == [0.0; 3] {
        return vec![1.0; mesh.positions.len()];
    }
    let scene = ExposureScene::new(mesh);
    let dirs = hemisphere_directions(u, model.exposure_rays);
    mesh.positions
        .par_iter()
        .zip(normals.par_iter())
        .enumerate()
        .map(|(i, (p, n))| {
            // Vertices that get no dust anyway need no rays.
            if n[0] * u[0] + n[1] * u[1] + n[2] * u[2] <= 0.0 {
                1.0
            } else {
                scene.exposure(*p, *n, u, &dirs, vertex_angle(i))
            }
        })
        .collect()
}

/// The dust amount D per vertex of `mesh` (SPEC §4 step 1): K · max(0, N·U)^s · E(P).
/// Parallel over vertices; deterministic for any thread count. Allocates.
pub fn dust_amount(mesh: &Mesh, model: &AmountModel) -> Vec<f32> {
    let normals = vertex_normals(mesh);
    let exposure = vertex_exposure(mesh, &normals, model);
    let u = unit(model.source);
    normals
        .par_iter()
        .zip(exposure.par_iter())
        .map(|(n, e)| directional(model, *n, u) * e)
        .collect()
}
