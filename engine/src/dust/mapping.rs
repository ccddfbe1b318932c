//! How the fibre textures lie on the mesh (SPEC §4 *Input*): the mesh's own UVs when it has
//! them, otherwise tri-planar projection in object space (and box-projected UVs for the glTF
//! export, [`box_uvs`]).
//!
//! **Scale.** The textures tile; one tile covers `fiber_tile` metres (default: 1/8 of the mesh's
//! bounding-box diagonal, so a 48-step fibre on a 512² texture is ~1 % of the object across and
//! reads as fibre in a close-up and as a soft layer from afar). Mesh UVs are laid out for the
//! mesh's own texture, at an unknown scale, so they are rescaled: uv′ = uv · m / `fiber_tile` with
//! m = √(Σ world area / Σ UV area) the mesh's mean metres per UV unit. The layout (seams,
//! orientation) is the mesh's; only the scale is ours. A UV set with (almost) no area, or with
//! none on a tenth of the surface, falls back to tri-planar.
//!
//! **Tri-planar** (our reading of "tri-planar projection in object space"): the point q − lo (lo:
//! the mesh's bounding-box minimum, so the coordinates stay small) is projected on the three axis
//! planes — (z, y) for X, (x, z) for Y, (x, y) for Z — divided by `fiber_tile`; the three lookups
//! are blended with weights ∝ |n_k|⁴, and weights under [`MIN_WEIGHT`] are dropped (renormalised),
//! so most points take one lookup and only the blend bands near 45° take two or three.
//!
//! Texture coordinates here are in *tiles* (1 = one texture width); the renderer multiplies by
//! the texture size.

use crate::geom::Mesh;

/// Tri-planar weights below this (after normalising) are dropped.
pub const MIN_WEIGHT: f32 = 0.05;

/// The mapping of one run.
#[derive(Debug, Clone, PartialEq)]
pub enum Mapping {
    /// The mesh's UVs, rescaled to tiles (one entry per vertex).
    Uv { uvs: Vec<[f32; 2]> },
    /// Tri-planar projection: `origin` is subtracted from points, `tile` metres per tile.
    Triplanar { origin: [f32; 3], tile: f32 },
}

/// Up to three weighted texture lookups (tiles), weights summing to 1.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Lookups {
    pub count: usize,
    pub weight: [f32; 3],
    pub st: [[f32; 2]; 3],
}

impl Mapping {
    /// The mapping for `mesh` with tiles of `tile` metres (> 0): rescaled UVs when the mesh has
    /// a UV set with area, else tri-planar. Allocates the rescaled UVs.
    pub fn new(mesh: &Mesh, tile: f32) -> Self {
        let origin = mesh.bounds().map_or([0.0; 3], |(lo, _)| lo);
        let triplanar = Mapping::Triplanar { origin, tile };
        let Some(uvs) = mesh
            .uvs
            .as_ref()
            .filter(|u| u.len() == mesh.positions.len())
        else {
            return triplanar;
        };
        let (mut world, mut uv_area, mut flat) = (0.0f64, 0.0f64, 0.0f64);
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let f = mesh.face_normal(t);
            let w = 0.5 * f64::from(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
            world += w;
            let [a, b, c] = tri.map(|i| uvs[i as usize]);
            let cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            uv_area += 0.5 * f64::from(cross.abs());
            if cross == 0.0 {
                flat += w;
            }
        }
        // (Almost) no UV area, or a tenth of the surface without any (parts without UVs, which
        // the reader gives (0, 0) beside textured ones): the UVs cannot carry the fibres.
        if !(uv_area > 1e-9 * world.max(1e-30)
            && world > 0.0
            && uv_area.is_finite()
            && flat <= 0.1 * world)
        {
            return triplanar;
        }
        let k = ((world / uv_area).sqrt() / f64::from(tile)) as f32;
        Mapping::Uv {
            uvs: uvs.iter().map(|u| [u[0] * k, u[1] * k]).collect(),
        }
    }

    /// The lookups at a point: barycentric `b` in the triangle with vertices `v`, its
    /// object-space position `q` and unit normal `n` (for tri-planar).
    #[inline]
    pub fn lookups(&self, b: [f32; 3], v: [usize; 3], q: [f32; 3], n: [f32; 3]) -> Lookups {
        match self {
            Mapping::Uv { uvs } => {
                let [a, bb, c] = v.map(|i| uvs[i]);
                Lookups {
                    count: 1,
                    weight: [1.0, 0.0, 0.0],
                    st: [
                        [
                            b[0] * a[0] + b[1] * bb[0] + b[2] * c[0],
                            b[0] * a[1] + b[1] * bb[1] + b[2] * c[1],
                        ],
                        [0.0; 2],
                        [0.0; 2],
                    ],
                }
            }
            Mapping::Triplanar { origin, tile } => {
                let inv = 1.0 / tile;
                let p = [0, 1, 2].map(|k| (q[k] - origin[k]) * inv);
                triplanar(p, n)
            }
        }
    }
}

/// Tri-planar lookups for the point `p` (already in tiles) with unit normal `n`.
#[inline]
pub fn triplanar(p: [f32; 3], n: [f32; 3]) -> Lookups {
    let raw = n.map(|c| {
        let c2 = c * c;
        c2 * c2
    });
    let sum = raw[0] + raw[1] + raw[2];
    let mut out = Lookups::default();
    if sum.is_nan() || sum <= 0.0 {
        out.count = 1;
        out.weight[0] = 1.0;
        out.st[0] = [p[0], p[2]];
        return out;
    }
    let planes = [[p[2], p[1]], [p[0], p[2]], [p[0], p[1]]];
    let mut total = 0.0;
    for (k, plane) in planes.into_iter().enumerate() {
        let w = raw[k] / sum;
        if w >= MIN_WEIGHT {
            out.weight[out.count] = w;
            out.st[out.count] = plane;
            out.count += 1;
            total += w;
        }
    }
    for w in &mut out.weight[..out.count] {
        *w /= total;
    }
    out
}

/// Box-projected UVs for the glTF export (SPEC §4 *Input*): each triangle is projected on the
/// axis plane its face normal is most aligned with (the planes of [`triplanar`], in tiles of
/// `tile` metres from `origin`). A vertex shared by triangles projected on different planes is
/// split. Returns, for the triangles `triangles` over `positions`: the source vertex of each new
/// vertex, its UV, and the triangles re-indexed into the new vertices. Allocates.
pub fn box_uvs(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    origin: [f32; 3],
    tile: f32,
) -> (Vec<u32>, Vec<[f32; 2]>, Vec<[u32; 3]>) {
    let inv = 1.0 / tile;
    // New vertex of (source vertex, axis): 3 slots per source vertex.
    let mut slot = vec![u32::MAX; positions.len() * 3];
    let mut src = Vec::new();
    let mut uvs = Vec::new();
    let out = triangles
        .iter()
        .map(|tri| {
            let [a, b, c] = tri.map(|i| positions[i as usize]);
            let (axis, [su, sv]) = crate::geom::box_projection(a, b, c);
            tri.map(|i| {
                let s = &mut slot[i as usize * 3 + axis];
                if *s == u32::MAX {
                    *s = src.len() as u32;
                    src.push(i);
                    let p = positions[i as usize];
                    let q = [0, 1, 2].map(|k| (p[k] - origin[k]) * inv);
                    uvs.push([q[su], q[sv]]);
                }
                *s
            })
        })
        .collect();
    (src, uvs, out)
}
