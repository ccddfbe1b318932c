//! Scenes built in code for the snow-cover tests, benchmarks and timings (not part of the API):
//! one copy shared by `engine/tests/it/snow_cover.rs`, `snow_shape.rs` and `benches/snow_cover.rs`.
//!
//! The benchmark scenes stand in for the journal's (§3, Table 1: 5,114 and 12,646 triangles) and
//! for the 1 M-triangle case: a bumpy 10 × 10 m grid with boxes on it (the boxes' tops and
//! undersides give a second layer and real occlusion), and a table on a gently waved floor.

use rayon::prelude::*;

use crate::geom::mesh::{Mesh, MeshPart};
use crate::geom::vec::Vec3;
use crate::snow_cover::SnowMaps;

/// Builds a [`Mesh`] from quads, grids and boxes (one part, grey).
#[derive(Debug, Default)]
pub struct SceneBuilder {
    /// The mesh so far.
    pub mesh: Mesh,
}

impl SceneBuilder {
    /// A quad with corners in order around it; flipped if needed so its normal points along `out`.
    pub fn quad(&mut self, q: [[f32; 3]; 4], out: [f32; 3]) {
        let base = self.mesh.positions.len() as u32;
        self.mesh.positions.extend_from_slice(&q);
        let [p0, p1, p2] = [q[0], q[1], q[2]].map(Vec3::from);
        let n = (p1 - p0).cross(p2 - p0);
        let (a, b, c, d) = (base, base + 1, base + 2, base + 3);
        if n.dot(Vec3::from(out)) >= 0.0 {
            self.mesh.triangles.push([a, b, c]);
            self.mesh.triangles.push([a, c, d]);
        } else {
            self.mesh.triangles.push([a, c, b]);
            self.mesh.triangles.push([a, d, c]);
        }
    }

    /// A horizontal grid of `n × m` quads at height `y(x, z)` over [x0, x1] × [z0, z1], facing up.
    pub fn grid(
        &mut self,
        x: [f32; 2],
        z: [f32; 2],
        n: usize,
        m: usize,
        y: impl Fn(f32, f32) -> f32,
    ) {
        let base = self.mesh.positions.len() as u32;
        for j in 0..=m {
            for i in 0..=n {
                let px = x[0] + (x[1] - x[0]) * i as f32 / n as f32;
                let pz = z[0] + (z[1] - z[0]) * j as f32 / m as f32;
                self.mesh.positions.push([px, y(px, pz), pz]);
            }
        }
        let row = (n + 1) as u32;
        for j in 0..m as u32 {
            for i in 0..n as u32 {
                let a = base + j * row + i;
                // (a, a+row, a+1) has normal +Y (z grows with j, x with i).
                self.mesh.triangles.push([a, a + row, a + 1]);
                self.mesh.triangles.push([a + 1, a + row, a + row + 1]);
            }
        }
    }

    /// A closed axis-aligned box with outward normals (12 triangles).
    pub fn cuboid(&mut self, lo: [f32; 3], hi: [f32; 3]) {
        let p = |x: usize, y: usize, z: usize| {
            [
                if x == 0 { lo[0] } else { hi[0] },
                if y == 0 { lo[1] } else { hi[1] },
                if z == 0 { lo[2] } else { hi[2] },
            ]
        };
        self.quad(
            [p(0, 1, 0), p(1, 1, 0), p(1, 1, 1), p(0, 1, 1)],
            [0.0, 1.0, 0.0],
        );
        self.quad(
            [p(0, 0, 0), p(1, 0, 0), p(1, 0, 1), p(0, 0, 1)],
            [0.0, -1.0, 0.0],
        );
        self.quad(
            [p(0, 0, 0), p(0, 1, 0), p(0, 1, 1), p(0, 0, 1)],
            [-1.0, 0.0, 0.0],
        );
        self.quad(
            [p(1, 0, 0), p(1, 1, 0), p(1, 1, 1), p(1, 0, 1)],
            [1.0, 0.0, 0.0],
        );
        self.quad(
            [p(0, 0, 0), p(1, 0, 0), p(1, 1, 0), p(0, 1, 0)],
            [0.0, 0.0, -1.0],
        );
        self.quad(
            [p(0, 0, 1), p(1, 0, 1), p(1, 1, 1), p(0, 1, 1)],
            [0.0, 0.0, 1.0],
        );
    }

    /// A `size × size` floor at y = 0 from the origin, facing up.
    pub fn floor(&mut self, size: f32) {
        self.quad(
            [
                [0.0, 0.0, 0.0],
                [size, 0.0, 0.0],
                [size, 0.0, size],
                [0.0, 0.0, size],
            ],
            [0.0, 1.0, 0.0],
        );
    }

    /// A table: top slab [x0, x1] × [z0, z1] from `h − 0.05` to `h`, four 0.1 m legs.
    pub fn table(&mut self, x: [f32; 2], z: [f32; 2], h: f32) {
        self.cuboid([x[0], h - 0.05, z[0]], [x[1], h, z[1]]);
        for (lx, lz) in [
            (x[0], z[0]),
            (x[1] - 0.1, z[0]),
            (x[0], z[1] - 0.1),
            (x[1] - 0.1, z[1] - 0.1),
        ] {
            self.cuboid([lx, 0.0, lz], [lx + 0.1, h - 0.05, lz + 0.1]);
        }
    }

    /// The mesh, as one part.
    pub fn build(mut self) -> Mesh {
        self.mesh.parts = vec![MeshPart {
            name: "scene".into(),
            first_triangle: 0,
            triangle_count: self.mesh.triangles.len(),
            base_color: [0.8, 0.8, 0.8, 1.0],
            texture: None,
        }];
        self.mesh
    }
}

/// A bumpy 10 × 10 m grid of `n × m` quads (`0.2 sin(1.3x) cos(0.9z)`) with `boxes` boxes on it
/// (up to 16 places, 1.2 × 0.9 m, tops 0.8 m + 0.1 m per box).
pub fn bumpy_scene(n: usize, m: usize, boxes: usize) -> Mesh {
    let mut b = SceneBuilder::default();
    b.grid([0.0, 10.0], [0.0, 10.0], n, m, |x, z| {
        0.2 * (x * 1.3).sin() * (z * 0.9).cos()
    });
    for k in 0..boxes {
        let x = 1.0 + (k % 4) as f32 * 2.2;
        let z = 1.0 + (k / 4 % 4) as f32 * 2.2;
        b.cuboid([x, 0.5, z], [x + 1.2, 0.8 + 0.1 * k as f32, z + 0.9]);
    }
    b.build()
}

/// The paper-scale probability scene: 5,114 triangles (a 50 × 51 bumpy grid, one box, and a 1 m
/// square floating at y = 1).
pub fn paper_scene() -> Mesh {
    let mut b = SceneBuilder {
        mesh: bumpy_scene(50, 51, 1),
    };
    b.quad(
        [
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.0],
            [1.0, 1.0, 1.0],
            [0.0, 1.0, 1.0],
        ],
        [0.0, 1.0, 0.0],
    );
    b.build()
}

/// The large probability scene: 999,890 triangles (a 707 × 707 bumpy grid, 16 boxes).
pub fn million_scene() -> Mesh {
    bumpy_scene(707, 707, 16)
}

/// The animation scene: 12,646 triangles (a 203 × 31 gently waved 10 × 10 m floor and a 1 m
/// table, top [3, 7]²); two layers (floor and table top).
pub fn animation_scene() -> Mesh {
    let mut b = SceneBuilder::default();
    b.grid([0.0, 10.0], [0.0, 10.0], 203, 31, |x, z| {
        0.02 * (x * 3.0).sin() * z.cos()
    });
    b.table([3.0, 7.0], [3.0, 7.0], 1.0);
    b.build()
}

/// Floor 10 × 10 m and a 1 m high table, top [3, 7]².
pub fn table_scene() -> Mesh {
    let mut b = SceneBuilder::default();
    b.floor(10.0);
    b.table([3.0, 7.0], [3.0, 7.0], 1.0);
    b.build()
}

/// A 10.24 m square floor (one quad): with a 1024² map, 1 cm cells.
pub fn pile_plane() -> Mesh {
    let mut b = SceneBuilder::default();
    b.floor(10.24);
    b.build()
}

/// Put a 1 m pile (a disc of radius 0.5 m at the centre of the map) on layer 0 of `maps`.
pub fn put_pile(maps: &mut SnowMaps) {
    let (nx, nz) = (maps.nx, maps.nz);
    let mid = [
        maps.origin[0] + 0.5 * nx as f32 * maps.cell,
        maps.origin[1] + 0.5 * nz as f32 * maps.cell,
    ];
    for j in 0..nz {
        for i in 0..nx {
            let [x, z] = maps.centre(i, j);
            if (x - mid[0]).powi(2) + (z - mid[1]).powi(2) < 0.25 {
                maps.layers[0].snow[j * nx + i] = 1_000_000;
            }
        }
    }
}

// The honest baseline (issue 4): upward ray casting through a BVH, K rays per point toward the
// sky along the same snowfall directions.

/// Snow probability by upward ray casting: for each point, the share of the K directions along
/// which a ray toward the sky (against the fall direction) leaves the scene unblocked. The ray
/// starts `eps` above the point (the surface itself must not occlude). BVH: `obvhs`'s compressed
/// wide BVH (CWBVH, SAH/PLOC "medium" build); rays in parallel over points (rayon).
pub fn upward_ray_casting(
    bvh: &obvhs::cwbvh::CwBvh,
    tris: &[obvhs::triangle::Triangle],
    points: &[[f32; 3]],
    dirs: &[[f32; 3]],
    eps: f32,
) -> Vec<f32> {
    use obvhs::ray::Ray;
    points
        .par_iter()
        .map(|p| {
            let o = glam::Vec3A::new(p[0], p[1] + eps, p[2]);
            let open = dirs
                .iter()
                .filter(|d| {
                    // `+ 0.0` turns −0 into +0: obvhs 0.4's CWBVH traversal misses every hit for a
                    // direction with a −0 component (measured; its BVH2 and brute force do not).
                    let up = glam::Vec3A::new(-d[0] + 0.0, -d[1] + 0.0, -d[2] + 0.0);
                    bvh.ray_traverse_miss(Ray::new_inf(o, up), |ray, id| {
                        tris[bvh.primitive_indices[id] as usize].intersect(ray)
                    })
                })
                .count();
            open as f32 / dirs.len() as f32
        })
        .collect()
}

/// The triangles of `mesh` for `obvhs` and their CWBVH.
pub fn obvhs_scene(mesh: &Mesh) -> (obvhs::cwbvh::CwBvh, Vec<obvhs::triangle::Triangle>) {
    let v = |i: u32| {
        let p = mesh.positions[i as usize];
        glam::Vec3A::new(p[0], p[1], p[2])
    };
    let tris: Vec<obvhs::triangle::Triangle> = mesh
        .triangles
        .iter()
        .map(|t| obvhs::triangle::Triangle {
            v0: v(t[0]),
            v1: v(t[1]),
            v2: v(t[2]),
        })
        .collect();
    let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(
        &tris,
        obvhs::BvhBuildParams::medium_build(),
        &mut std::time::Duration::default(),
    );
    (bvh, tris)
}

/// Snow-map cell centres on their base (every layer): the same receivers as ours.
pub fn map_points(maps: &SnowMaps, stride: usize) -> Vec<[f32; 3]> {
    let mut pts = Vec::new();
    for l in &maps.layers {
        for c in (0..maps.len()).step_by(stride) {
            if !l.base[c].is_nan() {
                let [x, z] = maps.centre(c % maps.nx, c / maps.nx);
                pts.push([x, l.base[c], z]);
            }
        }
    }
    pts
}
