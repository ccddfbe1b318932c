//! Snow shape data (journal §2.5 "積雪形状データの作成"; workshop §2.3(4) polygon variant; SPEC §2
//! step 7): polygon meshes of the snow, built from the snow maps, for `snow.glb` / `scene.glb`, and
//! the displaced input mesh for `displaced.glb`.
//!
//! **Snow meshes** ([`snow_meshes`]). The paper turns every snow map into polygons and renders them
//! with the scene. We build one **closed** mesh per *connected snow region*: the graph whose nodes
//! are the map cells `(cell, layer)` with more than `min_depth_m` of snow, and whose edges join
//! 4-neighbours that link to each other *both ways* ([`super::maps::MapLayer::links`]: snow from A
//! moves onto B and from B onto A). So the floor outside a table and the floor under it are one
//! region (they link both ways across the table's edge), while the table top is another: snow
//! leaving the top falls onto the floor, but snow on the floor cannot climb onto the top. A region
//! may span several layer indices; one mesh per layer index would cut the floor at the table's
//! edge (rejected).
//!
//! Each mesh has a top surface at `base + depth`, a bottom face at `base`, and vertical skirts
//! joining them along the region's boundary. Vertices sit at cell *corners*; a corner is shared by
//! the region's cells that meet there through linked edges, and its top and bottom heights are the
//! means of those cells' snow surfaces and bases (so a uniform depth `d` gives `top − bottom = d`
//! everywhere, and the enclosed volume is the snow volume exactly; for uneven snow the corner
//! averaging smooths it, see the tests for the tolerance). Every cell gives two top and two bottom
//! triangles; every boundary edge a two-triangle skirt. Every edge is shared by exactly two
//! triangles, all wound counter-clockwise seen from outside (signed volume > 0). Normals are
//! smooth: area-weighted sums of the incident faces' normals (what the journal's smooth shading
//! does), so rims are rounded in shading. Y up, world metres.
//!
//! Snow thinner than `min_depth_m` (default [`DEFAULT_MIN_DEPTH_M`], 1 mm) is left out: that is the
//! sparse-snow regime ([`super::sparse`]). The top is clipped at the ceiling
//! ([`super::maps::MapLayer::surface`]): the model keeps snow under it already
//! ([`super::settle`], "Ceiling"), and the clip holds for maps a caller filled by hand.
//!
//! **Displaced mesh** ([`displace`]): workshop §2.3 (polygon variant): the input mesh, optionally
//! subdivided by edge midpoints until no edge is longer than `max_edge_length` (at most
//! [`MAX_DISPLACED_TRIANGLES`] triangles), each vertex raised along +Y by the snow depth of the map
//! layer under it, and a per-vertex snow probability averaged from the incident faces, area-weighted
//! as for smooth normals (workshop §2.3(2): "スムーズシェーディング時の法線の求め方と同様に").
//!
//! Known limitation: corners are shared through chains of linked cells, so a region that spirals
//! over itself (a ramp winding once around a column, linked all the way) could share a corner
//! between two stacked cells; no scene in the tests does, and [`snow_meshes`] does not detect it.
//!
//! Cost: [`snow_meshes`] is `O(cells · layers)`: a `u32` per (cell, layer), two union-find arrays
//! (5 `u32` per snowy cell) and a hash map of corners per region; the meshes hold ≈ 2 vertices and
//! 4 triangles per snowy cell plus the skirts (measured: a fully covered 512² map, 1.05 M
//! triangles, 0.22 s on one core). [`displace`] is linear in the output size (1 M triangles by
//! subdivision: 0.2 s). Both allocate their outputs.

use std::collections::HashMap;

use super::maps::{opposite, SnowMaps, NEIGHBOURS};
use super::region::{DEPTH_EPS_REL, STEP_SLOPE_DEG, UP_FACING_MIN_NY};
use crate::geom::mesh::{Mesh, MeshPart};
use crate::geom::subdivide::subdivide_with;
use crate::geom::vec::{DVec3, Vec3};

/// Snow thinner than this (metres) gets no snow mesh (it is sparse snow). 1 mm.
pub const DEFAULT_MIN_DEPTH_M: f32 = 1e-3;

/// Most triangles [`displace`] produces by subdivision: 4 M triangles ≈ 2 M vertices ≈ 150 MB of
/// output attributes, about the largest `displaced.glb` a viewer handles. Subdivision stops before
/// a pass would exceed it (edges may then stay longer than asked).
pub const MAX_DISPLACED_TRIANGLES: usize = 4_000_000;

/// A closed snow mesh (world metres, Y up, CCW seen from outside).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SnowMesh {
    /// `snow<i>`, regions numbered in order of their first cell (row-major, then layer).
    pub name: String,
    /// Vertex positions, metres.
    pub positions: Vec<[f32; 3]>,
    /// Smooth unit normals, one per vertex.
    pub normals: Vec<[f32; 3]>,
    /// Vertex indices, CCW seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl SnowMesh {
    /// All `meshes` as one mesh named `name` (vertices appended, indices offset): the outputs
    /// draw and store the snow as one node, whatever the number of regions (a scene can have
    /// thousands of small ones; one glTF node each costs more JSON than geometry).
    pub fn merged(meshes: &[SnowMesh], name: &str) -> SnowMesh {
        let nv = meshes.iter().map(|m| m.positions.len()).sum();
        let nt = meshes.iter().map(|m| m.triangles.len()).sum();
        let mut out = SnowMesh {
            name: name.to_string(),
            positions: Vec::with_capacity(nv),
            normals: Vec::with_capacity(nv),
            triangles: Vec::with_capacity(nt),
        };
        for m in meshes {
            let base = out.positions.len() as u32;
            out.positions.extend_from_slice(&m.positions);
            out.normals.extend_from_slice(&m.normals);
            out.triangles
                .extend(m.triangles.iter().map(|t| t.map(|i| i + base)));
        }
        out
    }
}

/// The displaced input mesh of `displaced.glb` (see the module doc).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DisplacedMesh {
    /// Positions after subdivision, raised by `depth` along +Y; metres.
    pub positions: Vec<[f32; 3]>,
    /// Smooth unit normals of the displaced surface.
    pub normals: Vec<[f32; 3]>,
    /// Triangles (the input's winding).
    pub triangles: Vec<[u32; 3]>,
    /// Snow probability per vertex in [0, 1], area-weighted mean of the incident faces'.
    pub probability: Vec<f32>,
    /// Snow depth per vertex, metres (the amount the vertex was raised).
    pub depth: Vec<f32>,
    /// The input's texture coordinates, carried to the new vertices.
    pub uvs: Option<Vec<[f32; 2]>>,
    /// The input's vertex colours (linear RGBA), carried to the new vertices.
    pub colors: Option<Vec<[f32; 4]>>,
    /// The input's parts (materials) with their triangle ranges in `triangles`.
    pub parts: Vec<MeshPart>,
}

// ---------------------------------------------------------------------------------------------
// Normals and volume

/// Twice the area-weighted normal of a triangle (its edge cross product), f64 for accuracy.
fn face_cross(p: &[[f32; 3]], t: [u32; 3]) -> [f64; 3] {
    let [a, b, c] = t.map(|i| DVec3::from(p[i as usize].map(f64::from)));
    (b - a).cross(c - a).to_array()
}

/// Smooth per-vertex unit normals: the area-weighted sum of the incident faces' normals,
/// normalised; `[0, 1, 0]` for a vertex with no (non-degenerate) face. Allocates the result.
pub fn smooth_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let mut acc = vec![[0.0f64; 3]; positions.len()];
    for &t in triangles {
        let n = face_cross(positions, t);
        for &v in &t {
            let a = &mut acc[v as usize];
            a[0] += n[0];
            a[1] += n[1];
            a[2] += n[2];
        }
    }
    acc.into_iter()
        .map(|a| {
            let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            if l > 0.0 && l.is_finite() {
                [(a[0] / l) as f32, (a[1] / l) as f32, (a[2] / l) as f32]
            } else {
                [0.0, 1.0, 0.0]
            }
        })
        .collect()
}

/// Signed volume enclosed by a triangle mesh (divergence theorem), m³; positive for a closed mesh
/// wound CCW seen from outside.
pub fn signed_volume(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| DVec3::from(positions[i as usize].map(f64::from)));
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

// ---------------------------------------------------------------------------------------------
// Snow meshes

/// Union-find with path halving.
struct Dsu(Vec<u32>);

impl Dsu {
    fn new(n: usize) -> Self {
        Self((0..n as u32).collect())
    }
    fn find(&mut self, mut x: u32) -> u32 {
        while self.0[x as usize] != x {
            let p = self.0[self.0[x as usize] as usize];
            self.0[x as usize] = p;
            x = p;
        }
        x
    }
    /// Union keeping the smaller root (deterministic roots).
    fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
            self.0[hi as usize] = lo;
        }
    }
}

/// Corners of a cell: 0 = (i, j), 1 = (i+1, j), 2 = (i+1, j+1), 3 = (i, j+1) (corner offsets).
pub(super) const CORNERS: [(usize, usize); 4] = [(0, 0), (1, 0), (1, 1), (0, 1)];

/// Per direction of [`NEIGHBOURS`]: the two corners of this cell on that edge, and the matching
/// corners of the neighbour across it.
pub(super) const EDGE_CORNERS: [([usize; 2], [usize; 2]); 4] = [
    ([0, 3], [1, 2]), // −X
    ([1, 2], [0, 3]), // +X
    ([0, 1], [3, 2]), // −Z
    ([3, 2], [0, 1]), // +Z
];

/// The connected snow regions of `maps` (module doc): snowy `(cell, layer)` nodes, the root of
/// each node corner (corners shared through mutual links have one root), the mean top and base
/// heights per root, and the nodes of each region in order of its first node.
pub(super) struct Regions {
    /// Snowy nodes `(cell, layer)`, row-major then by layer.
    pub nodes: Vec<(usize, usize)>,
    /// `node_of[cell · layers + layer]`: the node, or `u32::MAX`.
    pub node_of: Vec<u32>,
    /// `root[node · 4 + corner]` (corners as in [`CORNERS`]).
    pub root: Vec<u32>,
    /// Per root: (top, base) height, metres (meaningful at roots only).
    pub height: Vec<(f32, f32)>,
    /// Nodes of each region.
    pub members: Vec<Vec<u32>>,
    /// Layers of the maps.
    pub layers: usize,
}

impl Regions {
    /// The node at cell `c`, layer `k`.
    #[inline]
    pub fn node_at(&self, c: usize, k: usize) -> Option<u32> {
        (k < self.layers)
            .then(|| self.node_of[c * self.layers + k])
            .filter(|&v| v != u32::MAX)
    }

    /// Whether the edge `d` of node `a` (cell `c`) is shared with a snowy node across it (both of
    /// its corners have the same roots there); otherwise it is a boundary edge with a skirt.
    pub fn edge_shared(&self, maps: &SnowMaps, a: u32, d: usize) -> bool {
        let c = self.nodes[a as usize].0;
        let (i, j) = (c % maps.nx, c / maps.nx);
        let (mine, theirs) = EDGE_CORNERS[d];
        maps.neighbour(i, j, d).is_some_and(|c2| {
            (0..self.layers).any(|k2| {
                self.node_at(c2, k2).is_some_and(|b| {
                    (0..2).all(|e| {
                        self.root[a as usize * 4 + mine[e]] == self.root[b as usize * 4 + theirs[e]]
                    })
                })
            })
        })
    }
}

/// The regions of `maps` with more than `min_depth_m` of snow; `None` when no cell has any.
pub(super) fn regions(maps: &SnowMaps, min_depth_m: f32) -> Option<Regions> {
    let n = maps.len();
    let nl = maps.layers.len();
    // Nodes: snowy (cell, layer), numbered row-major then by layer.
    let mut node_of = vec![u32::MAX; n * nl];
    let mut nodes: Vec<(usize, usize)> = Vec::new();
    for c in 0..n {
        for (k, l) in maps.layers.iter().enumerate() {
            if !l.base[c].is_nan() && l.depth_m(c) > min_depth_m {
                node_of[c * nl + k] = nodes.len() as u32;
                nodes.push((c, k));
            }
        }
    }
    if nodes.is_empty() {
        return None;
    }
    let node_at = |c: usize, k: usize| -> Option<u32> {
        (k < nl)
            .then(|| node_of[c * nl + k])
            .filter(|&v| v != u32::MAX)
    };

    // Regions (nodes) and shared corners (node * 4 + corner) through mutual links.
    let mut regions = Dsu::new(nodes.len());
    let mut corners = Dsu::new(nodes.len() * 4);
    for (a, &(c, k)) in nodes.iter().enumerate() {
        let (i, j) = (c % maps.nx, c / maps.nx);
        for (d, &(mine, theirs)) in EDGE_CORNERS.iter().enumerate() {
            let Some(c2) = maps.neighbour(i, j, d) else {
                continue;
            };
            let k2 = maps.layers[k].links[c][d] as usize;
            let Some(b) = node_at(c2, k2) else { continue };
            if maps.layers[k2].links[c2][opposite(d)] as usize != k || (b as usize) < a {
                continue;
            }
            regions.union(a as u32, b);
            for e in 0..2 {
                corners.union(a as u32 * 4 + mine[e] as u32, b * 4 + theirs[e] as u32);
            }
        }
    }
    let root: Vec<u32> = (0..nodes.len() as u32 * 4)
        .map(|x| corners.find(x))
        .collect();

    // Corner heights: mean surface and base over the cells sharing each corner.
    let mut sums = vec![[0.0f64; 3]; nodes.len() * 4]; // (top, base, count) at roots
    for (a, &(c, k)) in nodes.iter().enumerate() {
        let l = &maps.layers[k];
        for q in 0..4 {
            let r = root[a * 4 + q] as usize;
            sums[r][0] += f64::from(l.surface(c));
            sums[r][1] += f64::from(l.base[c]);
            sums[r][2] += 1.0;
        }
    }
    let height = sums
        .iter()
        .map(|s| {
            if s[2] > 0.0 {
                ((s[0] / s[2]) as f32, (s[1] / s[2]) as f32)
            } else {
                (0.0, 0.0)
            }
        })
        .collect();

    // Group nodes by region, in order of the region's first node.
    let mut region_index: HashMap<u32, usize> = HashMap::new();
    let mut members: Vec<Vec<u32>> = Vec::new();
    for a in 0..nodes.len() as u32 {
        let r = regions.find(a);
        let idx = *region_index.entry(r).or_insert_with(|| {
            members.push(Vec::new());
            members.len() - 1
        });
        members[idx].push(a);
    }
    Some(Regions {
        nodes,
        node_of,
        root,
        height,
        members,
        layers: nl,
    })
}

/// Push the two skirt triangles of the boundary edge from corner `p` to corner `q` (each `(top,
/// bottom)` vertex), facing `out_dir` (the edge's outward direction).
pub(super) fn push_skirt(m: &mut SnowMesh, p: (u32, u32), q: (u32, u32), out_dir: [f32; 3]) {
    // (bottom p, top p, top q): flip if its normal does not point outward.
    let at = |i: u32| Vec3::from(m.positions[i as usize]);
    let n = (at(p.0) - at(p.1)).cross(at(q.0) - at(p.1));
    if n.dot(Vec3::from(out_dir)) > 0.0 {
        m.triangles.push([p.1, p.0, q.0]);
        m.triangles.push([p.1, q.0, q.1]);
    } else {
        m.triangles.push([p.1, q.0, p.0]);
        m.triangles.push([p.1, q.1, q.0]);
    }
}

/// Build the closed snow meshes of `maps` (module doc) at full resolution (two top and two
/// bottom triangles per cell): one per connected region of cells with more than `min_depth_m`
/// metres of snow (default [`DEFAULT_MIN_DEPTH_M`]); none when no cell has. Allocates the meshes
/// and `O(cells · layers)` scratch. [`super::simplify::simplified_snow_meshes`] builds the same
/// regions within an error and a triangle budget.
pub fn snow_meshes(maps: &SnowMaps, min_depth_m: f32) -> Vec<SnowMesh> {
    let Some(r) = regions(maps, min_depth_m) else {
        return Vec::new();
    };
    let mut out = Vec::with_capacity(r.members.len());
    let mut verts = vec![u32::MAX; r.nodes.len() * 4];
    for (ri, list) in r.members.iter().enumerate() {
        let mut m = SnowMesh {
            name: format!("snow{ri}"),
            ..SnowMesh::default()
        };
        // Corner root → top vertex (its bottom vertex follows it).
        let mut vertex = |m: &mut SnowMesh, a: u32, q: usize| -> (u32, u32) {
            let root = r.root[a as usize * 4 + q] as usize;
            if verts[root] == u32::MAX {
                let (c, _) = r.nodes[a as usize];
                let (i, j) = (c % maps.nx + CORNERS[q].0, c / maps.nx + CORNERS[q].1);
                let x = maps.origin[0] + i as f32 * maps.cell;
                let z = maps.origin[1] + j as f32 * maps.cell;
                let (top, bottom) = r.height[root];
                verts[root] = m.positions.len() as u32;
                m.positions.push([x, top, z]);
                m.positions.push([x, bottom, z]);
            }
            (verts[root], verts[root] + 1)
        };
        for &a in list {
            let v: [(u32, u32); 4] = std::array::from_fn(|q| vertex(&mut m, a, q));
            // Top (normal +Y): corners 0 (i,j), 3 (i,j+1), 1 (i+1,j) — see the winding test.
            m.triangles.push([v[0].0, v[3].0, v[1].0]);
            m.triangles.push([v[1].0, v[3].0, v[2].0]);
            // Bottom (normal −Y).
            m.triangles.push([v[0].1, v[1].1, v[3].1]);
            m.triangles.push([v[1].1, v[2].1, v[3].1]);
            // Skirts on boundary edges: no snowy cell across whose corners are these corners.
            for (d, &(mine, _)) in EDGE_CORNERS.iter().enumerate() {
                if r.edge_shared(maps, a, d) {
                    continue;
                }
                let (dx, dz) = NEIGHBOURS[d];
                push_skirt(&mut m, v[mine[0]], v[mine[1]], [dx as f32, 0.0, dz as f32]);
            }
        }
        m.normals = smooth_normals(&m.positions, &m.triangles);
        out.push(m);
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Displaced mesh (polygon variant)

/// The map layer at world point `p`: the layer whose base is nearest below `p` (or above by at most
/// the map's depth epsilon) and within one continuous step (`cell · tan 75°`) of it, looked up in
/// the cell containing `p` and, failing that, its 8 neighbours (points on a cell's edge). Returns
/// `(cell, layer)`.
pub fn layer_at(maps: &SnowMaps, p: [f32; 3]) -> Option<(usize, usize)> {
    if maps.is_empty() {
        return None;
    }
    let fi = ((p[0] - maps.origin[0]) / maps.cell).floor();
    let fj = ((p[2] - maps.origin[1]) / maps.cell).floor();
    let ci = (fi.max(0.0) as usize).min(maps.nx - 1);
    let cj = (fj.max(0.0) as usize).min(maps.nz - 1);
    let above = on_surface_eps(maps);
    let below = maps.cell * STEP_SLOPE_DEG.to_radians().tan() + above;
    let search = |i: usize, j: usize| -> Option<(f32, usize, usize)> {
        let c = j * maps.nx + i;
        let mut best: Option<(f32, usize, usize)> = None;
        for (k, l) in maps.layers.iter().enumerate() {
            let d = p[1] - l.base[c];
            if d >= -above && d <= below && best.is_none_or(|b| d.abs() < b.0) {
                best = Some((d.abs(), c, k));
            }
        }
        best
    };
    if let Some(b) = search(ci, cj) {
        return Some((b.1, b.2));
    }
    let mut best: Option<(f32, usize, usize)> = None;
    for dj in -1isize..=1 {
        for di in -1isize..=1 {
            let (i, j) = (ci as isize + di, cj as isize + dj);
            if (di, dj) == (0, 0)
                || i < 0
                || j < 0
                || i >= maps.nx as isize
                || j >= maps.nz as isize
            {
                continue;
            }
            if let Some(b) = search(i as usize, j as usize) {
                if best.is_none_or(|x| b.0 < x.0) {
                    best = Some(b);
                }
            }
        }
    }
    best.map(|b| (b.1, b.2))
}

/// How far (metres) a point may lie above a layer's base and still be on it: the peeling's depth
/// epsilon plus 10 µm of float slack.
fn on_surface_eps(maps: &SnowMaps) -> f32 {
    maps.extent * DEPTH_EPS_REL + 1e-5
}

/// The polygon variant for `displaced.glb` (module doc): subdivide `mesh` so that no edge exceeds
/// `max_edge_length` metres (`None`: no subdivision; capped at [`MAX_DISPLACED_TRIANGLES`]), then
/// per face the snow probability of the map layer under its centroid (0 for faces that do not face
/// up, `n_y ≤ 0.05`), per vertex the area-weighted mean of its faces' probabilities, and the snow
/// depth of the layer under the vertex (0 for vertices with no up-facing face, or off the maps);
/// vertices are raised by that depth along +Y. Allocates the output.
///
/// The input's texture coordinates and vertex colours are carried to the new vertices (midpoint
/// means) and its parts keep their order with their new triangle ranges (the subdivision runs
/// per part, so each part's triangles stay contiguous), so `displaced.glb` can draw every part
/// with its own material and texture.
pub fn displace(mesh: &Mesh, maps: &SnowMaps, max_edge_length: Option<f32>) -> DisplacedMesh {
    let mut positions = mesh.positions.clone();
    let mut triangles = mesh.triangles.clone();
    let mut uvs = mesh.uvs.clone();
    let mut colors = mesh.colors.clone();
    let mut parts = mesh.parts.clone();
    if let Some(l) = max_edge_length.filter(|l| l.is_finite() && *l > 0.0) {
        let mut out: Vec<[u32; 3]> = Vec::with_capacity(triangles.len());
        let ranges: Vec<(usize, usize)> = if parts.is_empty() {
            vec![(0, triangles.len())]
        } else {
            parts
                .iter()
                .map(|p| {
                    let end = (p.first_triangle + p.triangle_count).min(triangles.len());
                    (p.first_triangle.min(end), end)
                })
                .collect()
        };
        let mut total = triangles.len();
        let mut new_ranges = Vec::with_capacity(ranges.len());
        for (a, b) in ranges {
            let mut tris = triangles[a..b].to_vec();
            let before = tris.len();
            let budget = MAX_DISPLACED_TRIANGLES.saturating_sub(total - before);
            subdivide_with(&mut positions, &mut tris, l, budget, |i, j| {
                if let Some(u) = uvs.as_mut() {
                    let (ui, uj) = (u[i as usize], u[j as usize]);
                    u.push([0.5 * (ui[0] + uj[0]), 0.5 * (ui[1] + uj[1])]);
                }
                if let Some(c) = colors.as_mut() {
                    let (ci, cj) = (c[i as usize], c[j as usize]);
                    c.push([0, 1, 2, 3].map(|k| 0.5 * (ci[k] + cj[k])));
                }
            });
            total = total - before + tris.len();
            new_ranges.push((out.len(), tris.len()));
            out.extend(tris);
        }
        for (p, (first, count)) in parts.iter_mut().zip(new_ranges) {
            p.first_triangle = first;
            p.triangle_count = count;
        }
        triangles = out;
    }
    let nv = positions.len();
    let mut p_acc = vec![(0.0f64, 0.0f64); nv]; // (Σ area·P, Σ area)
    let mut up = vec![false; nv];
    let eps = on_surface_eps(maps);
    for &t in &triangles {
        let n = face_cross(&positions, t);
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let area = 0.5 * len;
        let ny = if len > 0.0 { n[1] / len } else { 0.0 };
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let g = [
            (a[0] + b[0] + c[0]) / 3.0,
            (a[1] + b[1] + c[1]) / 3.0,
            (a[2] + b[2] + c[2]) / 3.0,
        ];
        let min_ny = f64::from(UP_FACING_MIN_NY);
        let layer = if ny > min_ny {
            layer_at(maps, g)
        } else if ny < -min_ny {
            // An open surface wound downward is a layer of its own (see `super::region`): the
            // triangle counts when a layer's base lies on it.
            layer_at(maps, g).filter(|&(cell, k)| (maps.layers[k].base[cell] - g[1]).abs() <= eps)
        } else {
            None
        };
        let facing_up = ny > min_ny || layer.is_some();
        let prob = layer.map_or(0.0, |(cell, k)| maps.layers[k].probability[cell]);
        for &v in &t {
            let acc = &mut p_acc[v as usize];
            acc.0 += area * f64::from(prob);
            acc.1 += area;
            up[v as usize] |= facing_up;
        }
    }
    let probability = p_acc
        .iter()
        .map(|&(s, w)| if w > 0.0 { (s / w) as f32 } else { 0.0 })
        .collect();
    let depth: Vec<f32> = positions
        .iter()
        .zip(&up)
        .map(|(&p, &u)| {
            if !u {
                return 0.0;
            }
            layer_at(maps, p).map_or(0.0, |(cell, k)| {
                let l = &maps.layers[k];
                (l.surface(cell) - l.base[cell]).max(0.0)
            })
        })
        .collect();
    for (p, d) in positions.iter_mut().zip(&depth) {
        p[1] += d;
    }
    let normals = smooth_normals(&positions, &triangles);
    DisplacedMesh {
        positions,
        normals,
        triangles,
        probability,
        depth,
        uvs,
        colors,
        parts,
    }
}
