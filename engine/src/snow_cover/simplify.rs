//! Snow meshes sized to the scene (SPEC §2 step 7; our addition to journal §2.5, which turns every
//! map cell into polygons): the closed meshes of [`super::shape::snow_meshes`], with the top and
//! bottom surfaces simplified where they are flat, within a height error and a triangle budget.
//!
//! **Method: a right-triangulated irregular network** (RTIN; Evans, Kirkpatrick and Townsend,
//! "Right-triangulated irregular networks", Algorithmica 30, 2001) per snow region, on the grid of
//! the region's cell corners padded to `2ᵏ + 1` a side. Every triangle of the hierarchy is split in
//! two at the midpoint of its hypotenuse; a vertex's error is the larger of the top and bottom
//! surfaces' vertical distances from the hypotenuse's linear interpolation, raised to the largest
//! error of the vertices below it in the hierarchy (Martini's metric), so a triangle is kept whole
//! only when every hypotenuse midpoint below it lies within the threshold of its own edge. That
//! bounds each level, not the distance to the kept triangle's plane, which can be somewhat larger
//! (the tests check 2 × the threshold). A triangle is split exactly when its
//! hypotenuse midpoint's error exceeds the threshold, and the neighbour across the hypotenuse
//! tests the same vertex, so the triangulation is conforming (no cracks, no T-junctions).
//!
//! **Detail at edges.** A corner that is not interior to the region (not shared by four region
//! cells through one corner root: the region's boundary, a cut between unlinked cells, padding)
//! gets an infinite error, so every cell touching the boundary stays at full resolution: the
//! outline, the skirts and the rims keep the map's detail, and a kept triangle never covers a cell
//! outside the region (any such cell has a corner inside the triangle below its corners, with
//! infinite error). The skirts are those of the full-resolution mesh, so the mesh stays closed.
//!
//! **Budget.** The threshold starts at [`DEFAULT_MAX_ERROR_CELLS`] of a cell; while the meshes would
//! exceed `max_triangles`, it doubles (counting is a traversal without output). The RTIN never
//! simplifies the boundary, so a scene whose full-resolution outlines alone need more triangles
//! goes on to the edge-collapse pass below.
//!
//! **Over the budget** (issue 18: a slatted container roof and a piano gave 4,803 and 1,522
//! regions, thin strips and single cells, whose outlines alone were 290 k and 170 k triangles,
//! 7.15 and 4.07 MB of `snow.glb`): the RTIN meshes at the starting threshold, then their top
//! surfaces together through meshoptimizer's edge-collapse simplifier (Garland–Heckbert quadric
//! error; `meshopt` crate, meshoptimizer 0.25) with the base height under each vertex as an
//! attribute, lowest-error collapses first, so flat tops and straight runs of an outline merge
//! first (at no error) and curved detail goes last. Each region is rebuilt closed from its
//! simplified top: the same triangulation at the base heights, and a skirt under every outline
//! edge. The target count is lowered until tops, bottoms and skirts fit the budget (at most four
//! tries); a region whose rebuilt mesh is not closed keeps its RTIN mesh
//! ([`SimplifyReport::collapse_kept_regions`]); the report's `max_error_m` is the larger of the
//! two passes' errors, and [`SimplifyReport::within_budget`] says whether the budget was met
//! (single cells cannot go below 12 triangles). Why not the whole closed mesh through the
//! collapse: on thin slabs it pinched them (directed edges used twice in 1,252 of the
//! container's 4,803 regions), and a pinched region has to keep its full mesh.
//!
//! Cost: per region `O(G²)` for the errors (G the padded side) and a traversal per threshold tried;
//! regions in parallel (rayon), output in region order, so the result does not depend on the
//! thread count. Allocates per region three `G²` arrays.

use rayon::prelude::*;

use super::maps::{SnowMaps, NEIGHBOURS};
use super::shape::{push_skirt, regions, smooth_normals, Regions, SnowMesh, CORNERS, EDGE_CORNERS};

/// Default error threshold (vertical, in cells of the snow map) of the simplified surfaces.
pub const DEFAULT_MAX_ERROR_CELLS: f32 = 0.1;

/// Default triangle budget of all snow meshes together (`snow_max_triangles`): about 2.4 MB of
/// `snow.glb`.
pub const DEFAULT_MAX_TRIANGLES: usize = 100_000;

/// What [`simplified_snow_meshes`] did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SimplifyReport {
    /// Triangles at full resolution (two top, two bottom per cell, plus the skirts).
    pub full_triangles: usize,
    /// Triangles kept.
    pub triangles: usize,
    /// The height error threshold used, metres.
    pub max_error_m: f32,
    /// False when even the coarsest threshold tried left more than the budget (the boundary is
    /// kept at full resolution).
    pub within_budget: bool,
    /// Regions whose simplified mesh was not closed and were built at full resolution instead.
    pub full_resolution_regions: usize,
    /// Regions whose mesh is not closed even at full resolution (kept simplified).
    pub open_regions: usize,
    /// The RTIN alone could not reach the budget, so the edge-collapse pass ran (module doc,
    /// "Over the budget"); `max_error_m` is then the larger of the RTIN's threshold and the
    /// collapse's error.
    pub collapsed: bool,
    /// Regions whose collapsed mesh was not closed and that kept their RTIN mesh.
    pub collapse_kept_regions: usize,
}

/// One region's RTIN: the padded grid and the accumulated errors.
struct Rtin {
    /// Region's first cell (i, j) on the map.
    i0: usize,
    j0: usize,
    /// Padded grid side (vertices), `2ᵏ + 1`.
    g: usize,
    /// Per padded cell (`(g − 1)²`): the node there, or `u32::MAX`.
    cell_node: Vec<u32>,
    /// Per vertex: accumulated error (∞ where not interior).
    error: Vec<f32>,
    /// Skirt triangles (fixed by the outline).
    skirts: usize,
    /// Nodes sharing a cell with another node of the region (drawn at full resolution).
    extra: Vec<u32>,
}

impl Rtin {
    fn new(maps: &SnowMaps, r: &Regions, list: &[u32]) -> Self {
        let nx = maps.nx;
        let (mut i0, mut j0, mut i1, mut j1) = (usize::MAX, usize::MAX, 0, 0);
        for &a in list {
            let c = r.nodes[a as usize].0;
            let (i, j) = (c % nx, c / nx);
            i0 = i0.min(i);
            j0 = j0.min(j);
            i1 = i1.max(i);
            j1 = j1.max(j);
        }
        let side = (i1 - i0 + 1).max(j1 - j0 + 1).next_power_of_two().max(2);
        let g = side + 1;
        let mut cell_node = vec![u32::MAX; side * side];
        // Per vertex: the root seen there (MAX: none yet, MAX − 1: several) and the cell count.
        let mut vroot = vec![u32::MAX; g * g];
        let mut count = vec![0u8; g * g];
        let mut skirts = 0;
        let mut extra = Vec::new();
        for &a in list {
            let c = r.nodes[a as usize].0;
            let (x, y) = (c % nx - i0, c / nx - j0);
            if cell_node[y * side + x] != u32::MAX {
                // A second node of the region at this cell (stacked layers linked into one
                // region): drawn at full resolution, its corners kept fine.
                extra.push(a);
                for &(dx, dy) in &CORNERS {
                    vroot[(y + dy) * g + x + dx] = u32::MAX - 1;
                }
            } else {
                cell_node[y * side + x] = a;
                for (q, &(dx, dy)) in CORNERS.iter().enumerate() {
                    let v = (y + dy) * g + x + dx;
                    let root = r.root[a as usize * 4 + q];
                    vroot[v] = match vroot[v] {
                        u32::MAX => root,
                        old if old == root => old,
                        _ => u32::MAX - 1,
                    };
                    count[v] += 1;
                }
            }
            skirts += 2 * (0..4).filter(|&d| !r.edge_shared(maps, a, d)).count();
        }
        let mut top = vec![0f32; g * g];
        let mut bot = vec![0f32; g * g];
        let mut error = vec![f32::INFINITY; g * g];
        for (v, (&n, &root)) in count.iter().zip(&vroot).enumerate() {
            if n == 4 && root < u32::MAX - 1 {
                (top[v], bot[v]) = r.height[root as usize];
                error[v] = 0.0;
            }
        }
        // Bottom-up over the triangle hierarchy (largest id first = smallest triangles first).
        let n_tri = side * side * 2 - 2;
        let n_parent = n_tri - side * side;
        for t in (0..n_tri).rev() {
            let [a, b, c] = triangle(t + 2, side);
            let (mx, my) = ((a.0 + b.0) / 2, (a.1 + b.1) / 2);
            let m = my * g + mx;
            let (ia, ib, ic) = (a.1 * g + a.0, b.1 * g + b.0, c.1 * g + c.0);
            let mut e = error[m];
            // All three corners must be interior, the right angle `c` too: at the finest level
            // (hypotenuse two cells long) no child's midpoint checks `c`, and a triangle kept
            // whole around a boundary or cut corner would take one root for a corner that has
            // several, leaving the mesh open where the cells around it are drawn separately.
            // (Corners of a level are midpoints of coarser levels, so their errors here are
            // still the initial ones: 0 interior, ∞ not.)
            if e.is_finite()
                && error[ia].is_finite()
                && error[ib].is_finite()
                && error[ic].is_finite()
            {
                let et = (0.5 * (top[ia] + top[ib]) - top[m]).abs();
                let eb = (0.5 * (bot[ia] + bot[ib]) - bot[m]).abs();
                e = e.max(et).max(eb);
            } else {
                e = f32::INFINITY;
            }
            if t < n_parent {
                let l = ((a.1 + c.1) / 2) * g + (a.0 + c.0) / 2;
                let rr = ((b.1 + c.1) / 2) * g + (b.0 + c.0) / 2;
                e = e.max(error[l]).max(error[rr]);
            }
            error[m] = e;
        }
        Self {
            i0,
            j0,
            g,
            cell_node,
            extra,
            error,
            skirts,
        }
    }

    /// Visit the kept triangles at threshold `tau` (grid corners, any winding), full-resolution
    /// triangles only where their cell is in the region.
    fn walk(&self, tau: f32, f: &mut impl FnMut([(usize, usize); 3])) {
        let s = self.g - 1;
        self.split((0, 0), (s, s), (s, 0), tau, f);
        self.split((s, s), (0, 0), (0, s), tau, f);
    }

    fn split(
        &self,
        a: (usize, usize),
        b: (usize, usize),
        c: (usize, usize),
        tau: f32,
        f: &mut impl FnMut([(usize, usize); 3]),
    ) {
        let (mx, my) = ((a.0 + b.0) / 2, (a.1 + b.1) / 2);
        let leg = a.0.abs_diff(c.0) + a.1.abs_diff(c.1);
        if leg > 1 && self.error[my * self.g + mx] > tau {
            self.split(c, a, (mx, my), tau, f);
            self.split(b, c, (mx, my), tau, f);
        } else if leg > 1 || self.cell_of([a, b, c]) != u32::MAX {
            f([a, b, c]);
        }
    }

    /// The node of the cell holding the centroid of a full-resolution triangle.
    fn cell_of(&self, t: [(usize, usize); 3]) -> u32 {
        let s = self.g - 1;
        let x = (t[0].0 + t[1].0 + t[2].0) / 3;
        let y = (t[0].1 + t[1].1 + t[2].1) / 3;
        self.cell_node[y.min(s - 1) * s + x.min(s - 1)]
    }

    /// Triangles at threshold `tau`: top and bottom, plus the skirts.
    fn count(&self, tau: f32) -> usize {
        let mut n = 0;
        self.walk(tau, &mut |_| n += 1);
        2 * n + self.skirts + 4 * self.extra.len()
    }
}

/// Corners `[a, b, c]` (hypotenuse a–b, right angle at c) of the RTIN triangle with id `id` (≥ 2)
/// on a grid of `side` cells, in Martini's numbering (V. Agafonkin's RTIN implementation): the
/// lowest bit picks one of the two halves of the square, each further bit (upward) the first
/// `(c, a, m)` or second `(b, c, m)` child, m the hypotenuse's midpoint. Ids of one bit length
/// are one level, so descending ids visit children before parents.
fn triangle(mut id: usize, side: usize) -> [(usize, usize); 3] {
    let (mut a, mut b, mut c) = if id & 1 == 1 {
        ((0, 0), (side, side), (side, 0))
    } else {
        ((side, side), (0, 0), (0, side))
    };
    loop {
        id >>= 1;
        if id <= 1 {
            break;
        }
        let m = ((a.0 + b.0) / 2, (a.1 + b.1) / 2);
        (a, b, c) = if id & 1 == 1 { (c, a, m) } else { (b, c, m) };
    }
    [a, b, c]
}

/// The closed snow meshes of `maps` (as [`super::shape::snow_meshes`]: one per connected region
/// of cells with more than `min_depth_m` of snow), their top and bottom simplified within a
/// height error (module doc): the threshold starts at `max_error_cells` cells of the map and
/// doubles until all meshes together have at most `max_triangles` triangles (or the boundary alone
/// is left). Smooth normals are computed on the simplified meshes.
pub fn simplified_snow_meshes(
    maps: &SnowMaps,
    min_depth_m: f32,
    max_error_cells: f32,
    max_triangles: usize,
) -> (Vec<SnowMesh>, SimplifyReport) {
    let mut rep = SimplifyReport {
        within_budget: true,
        ..SimplifyReport::default()
    };
    let Some(r) = regions(maps, min_depth_m) else {
        return (Vec::new(), rep);
    };
    let rtins: Vec<Rtin> = r
        .members
        .par_iter()
        .map(|list| Rtin::new(maps, &r, list))
        .collect();
    rep.full_triangles = rtins
        .iter()
        .zip(&r.members)
        .map(|(t, l)| 4 * l.len() + t.skirts)
        .sum();
    let mut tau = (max_error_cells.max(0.0) * maps.cell).max(1e-9);
    let count = |tau: f32| -> usize { rtins.par_iter().map(|t| t.count(tau)).sum() };
    let mut n = count(tau);
    // Beyond the largest height difference in the maps a larger threshold keeps nothing more
    // whole: the doubling stops there (and the report states a threshold that means something).
    let (lo, hi) = r
        .height
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &(t, b)| {
            (lo.min(t).min(b), hi.max(t).max(b))
        });
    let span = (hi - lo).max(0.0);
    while n > max_triangles && tau <= span {
        tau *= 2.0;
        n = count(tau);
    }
    // The outlines alone exceed the budget: the RTIN at the starting threshold, then the
    // edge-collapse pass (module doc, "Over the budget").
    let collapse = n > max_triangles;
    if collapse {
        tau = (max_error_cells.max(0.0) * maps.cell).max(1e-9);
    }
    rep.within_budget = n <= max_triangles;
    rep.max_error_m = tau;
    let built: Vec<RegionMesh> = rtins
        .par_iter()
        .zip(r.members.par_iter())
        .enumerate()
        .map(|(ri, (t, list))| {
            let m = build(maps, &r, t, list, tau, ri);
            if closed(&m) {
                return RegionMesh::Simplified(m);
            }
            // Safety net: a region the simplification could not close (none known since the
            // right-angle corner is checked) is built at full resolution; a region that is open
            // at full resolution as well (stacked layers sharing an edge's corners, rare) keeps
            // its simplified mesh, and the report counts it.
            let full = build(maps, &r, t, list, -1.0, ri);
            if closed(&full) {
                RegionMesh::FullResolution(full)
            } else {
                RegionMesh::Open(m)
            }
        })
        .collect();
    rep.full_resolution_regions = built
        .iter()
        .filter(|b| matches!(b, RegionMesh::FullResolution(_)))
        .count();
    rep.open_regions = built
        .iter()
        .filter(|b| matches!(b, RegionMesh::Open(_)))
        .count();
    let mut meshes: Vec<SnowMesh> = built.into_iter().map(RegionMesh::into_mesh).collect();
    if collapse {
        let (err, kept) = collapse_to_budget(&mut meshes, max_triangles, span.max(tau));
        rep.collapsed = true;
        rep.collapse_kept_regions = kept;
        rep.max_error_m = rep.max_error_m.max(err);
    }
    rep.triangles = meshes.iter().map(|m| m.triangles.len()).sum();
    if collapse {
        rep.within_budget = rep.triangles <= max_triangles;
    }
    (meshes, rep)
}

/// The edge-collapse pass (module doc, "Over the budget"): the top surfaces of all `meshes`
/// together through meshoptimizer's simplifier (quadric error on the top, the base height under
/// each vertex weighed in as an attribute; lowest-error collapses first; the outline may
/// collapse along itself, so straight runs of it merge), down to a triangle count for which the
/// tops, their mirrored bottoms and the skirts along their new outlines fit `max_triangles`, or
/// until the next collapse would cost more than `max_error` metres. Each region is then rebuilt
/// closed: the simplified top, the same triangulation at the base heights (reversed), and a
/// two-triangle skirt per outline edge. A region whose rebuilt mesh is not closed (a collapse
/// pinched its outline) or is empty keeps its mesh. Returns the error reached (metres) and the
/// number of regions that kept their mesh. Serial (meshoptimizer is single-threaded) and
/// deterministic.
fn collapse_to_budget(
    meshes: &mut [SnowMesh],
    max_triangles: usize,
    max_error: f32,
) -> (f32, usize) {
    // The top vertices are the even ones (`build` pushes a corner's top, then its bottom), the
    // top triangles those with three even corners.
    let mut top: Vec<[f32; 3]> = Vec::new();
    let mut base_y: Vec<f32> = Vec::new();
    let mut indices: Vec<u32> = Vec::new();
    let mut first: Vec<u32> = Vec::with_capacity(meshes.len() + 1);
    for m in meshes.iter() {
        let off = top.len() as u32;
        first.push(off);
        for v in m.positions.chunks_exact(2) {
            top.push(v[0]);
            base_y.push(v[1][1]);
        }
        for t in &m.triangles {
            if t.iter().all(|&i| i % 2 == 0) {
                indices.extend(t.iter().map(|&i| i / 2 + off));
            }
        }
    }
    first.push(top.len() as u32);
    let locks = vec![false; top.len()];
    // Triangles of the closed meshes built on a simplified top: top, bottom, and 2 per outline
    // edge (a directed edge whose reverse is not in the top).
    let closed_count = |out: &[u32]| -> usize {
        let mut edges: Vec<u64> = out
            .chunks_exact(3)
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .map(|(a, b)| (u64::from(a) << 32) | u64::from(b))
            .collect();
        edges.sort_unstable();
        let outline = edges
            .iter()
            .filter(|&&e| edges.binary_search(&e.rotate_left(32)).is_err())
            .count();
        2 * out.len() / 3 + 2 * outline
    };
    let mut target = max_triangles / 2;
    let mut out = Vec::new();
    let mut err = 0f32;
    for _ in 0..4 {
        // meshoptimizer asserts (aborts) on a target above the input's count.
        target = target.min(indices.len() / 3);
        err = 0.0;
        out = meshopt::simplify_with_attributes_and_locks_decoder(
            &indices,
            &top,
            &base_y,
            &[1.0],
            std::mem::size_of::<f32>(),
            &locks,
            target * 3,
            max_error,
            meshopt::SimplifyOptions::ErrorAbsolute,
            Some(&mut err),
        );
        let n = closed_count(&out);
        if n <= max_triangles || out.len() / 3 > target {
            // Within the budget, or stopped by the error limit (a smaller target would not help).
            break;
        }
        target = ((target as f64 * max_triangles as f64 / n as f64) * 0.97) as usize;
    }
    // Collapses never join two regions (they share no edge), so each output triangle lies in
    // the vertex range of the region it came from.
    let mut per_region: Vec<Vec<[u32; 3]>> = vec![Vec::new(); meshes.len()];
    for t in out.chunks_exact(3) {
        let r = first.partition_point(|&f| f <= t[0]) - 1;
        per_region[r].push([t[0], t[1], t[2]].map(|i| i - first[r]));
    }
    let mut kept = 0;
    for (m, tris) in meshes.iter_mut().zip(per_region) {
        let n_top = m
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&i| i % 2 == 0))
            .count();
        if tris.len() == n_top {
            continue;
        }
        match rebuild(m, &tris) {
            Some(s) => *m = s,
            None => kept += 1,
        }
    }
    (err, kept)
}

/// The closed mesh of region mesh `m` on the simplified top `tris` (indices of `m`'s top
/// vertices, counted from 0: top vertex `v` is `m.positions[2v]`, its base `2v + 1`); `None`
/// when it is empty or not closed.
fn rebuild(m: &SnowMesh, tris: &[[u32; 3]]) -> Option<SnowMesh> {
    let mut remap = vec![u32::MAX; m.positions.len() / 2];
    let mut s = SnowMesh {
        name: m.name.clone(),
        ..SnowMesh::default()
    };
    let mut tops: Vec<[u32; 3]> = Vec::with_capacity(tris.len());
    for t in tris {
        tops.push(t.map(|v| {
            let r = &mut remap[v as usize];
            if *r == u32::MAX {
                *r = s.positions.len() as u32;
                s.positions.push(m.positions[2 * v as usize]);
                s.positions.push(m.positions[2 * v as usize + 1]);
            }
            *r
        }));
    }
    let mut edges: Vec<(u32, u32)> = tops
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .collect();
    edges.sort_unstable();
    for t in &tops {
        s.triangles.push(*t);
        s.triangles.push([t[0] + 1, t[2] + 1, t[1] + 1]);
    }
    // A skirt under every outline edge a → b of the top (wound so that its edges pair with the
    // top's a → b, the bottom's b' → a' and the neighbouring skirts' verticals).
    for &(a, b) in &edges {
        if edges.binary_search(&(b, a)).is_err() {
            s.triangles.push([b, a, a + 1]);
            s.triangles.push([b, a + 1, b + 1]);
        }
    }
    if s.triangles.is_empty() || !closed(&s) {
        return None;
    }
    s.normals = smooth_normals(&s.positions, &s.triangles);
    Some(s)
}

/// How one region's mesh came out of [`simplified_snow_meshes`].
enum RegionMesh {
    /// Simplified within the threshold, and closed.
    Simplified(SnowMesh),
    /// The simplified mesh was open; built at full resolution instead, closed.
    FullResolution(SnowMesh),
    /// Open even at full resolution; the simplified mesh is kept.
    Open(SnowMesh),
}

impl RegionMesh {
    fn into_mesh(self) -> SnowMesh {
        match self {
            Self::Simplified(m) | Self::FullResolution(m) | Self::Open(m) => m,
        }
    }
}

/// The mesh of one region at threshold `tau`.
fn build(maps: &SnowMaps, r: &Regions, t: &Rtin, list: &[u32], tau: f32, ri: usize) -> SnowMesh {
    let mut m = SnowMesh {
        name: format!("snow{ri}"),
        ..SnowMesh::default()
    };
    // Corner root → top vertex (its bottom vertex follows it); roots are per node corner.
    let mut verts: std::collections::HashMap<u32, u32> = std::collections::HashMap::new();
    let mut vertex = |m: &mut SnowMesh, root: u32, gx: usize, gy: usize| -> (u32, u32) {
        let v = *verts.entry(root).or_insert_with(|| {
            let x = maps.origin[0] + (t.i0 + gx) as f32 * maps.cell;
            let z = maps.origin[1] + (t.j0 + gy) as f32 * maps.cell;
            let (top, bottom) = r.height[root as usize];
            let v = m.positions.len() as u32;
            m.positions.push([x, top, z]);
            m.positions.push([x, bottom, z]);
            v
        });
        (v, v + 1)
    };
    let s = t.g - 1;
    let mut tris: Vec<[(usize, usize); 3]> = Vec::new();
    t.walk(tau, &mut |tri| tris.push(tri));
    for tri in tris {
        let cx2 = (tri[0].0 + tri[1].0 + tri[2].0) as f32 / 3.0;
        let cy2 = (tri[0].1 + tri[1].1 + tri[2].1) as f32 / 3.0;
        let v: [(u32, u32); 3] = tri.map(|(gx, gy)| {
            // The cell at this corner on the triangle's side: 0.3 cell toward the centroid.
            let (ux, uy) = (cx2 - gx as f32, cy2 - gy as f32);
            let len = (ux * ux + uy * uy).sqrt().max(1e-6);
            let px = gx as f32 + ux * 0.3 / len;
            let py = gy as f32 + uy * 0.3 / len;
            let (ci, cj) = (
                (px.floor() as usize).min(s - 1),
                (py.floor() as usize).min(s - 1),
            );
            let a = t.cell_node[cj * s + ci];
            // The corner of that cell at (gx, gy).
            let q = CORNERS
                .iter()
                .position(|&(dx, dy)| ci + dx == gx && cj + dy == gy)
                .unwrap_or(0);
            let root = if a == u32::MAX {
                u32::MAX
            } else {
                r.root[a as usize * 4 + q]
            };
            if root == u32::MAX {
                return (u32::MAX, u32::MAX);
            }
            vertex(&mut m, root, gx, gy)
        });
        if v.iter().any(|x| x.0 == u32::MAX) {
            continue; // cannot happen for a kept triangle (module doc); skipped defensively
        }
        // Winding: +Y for the top (grid x = world x, grid y = world z).
        let (a, b, c) = (tri[0], tri[1], tri[2]);
        let (d1, d2) = (
            (b.0 as i64 - a.0 as i64, b.1 as i64 - a.1 as i64),
            (c.0 as i64 - a.0 as i64, c.1 as i64 - a.1 as i64),
        );
        // cross(d1, d2).y with d = (dx, 0, dz): d1.z · d2.x − d1.x · d2.z.
        let up = d1.1 * d2.0 - d1.0 * d2.1 > 0;
        let (p, q) = if up { (1, 2) } else { (2, 1) };
        m.triangles.push([v[0].0, v[p].0, v[q].0]);
        m.triangles.push([v[0].1, v[q].1, v[p].1]);
    }
    // Stacked nodes at full resolution, as in `snow_meshes`.
    for &a in &t.extra {
        let c = r.nodes[a as usize].0;
        let (gx, gy) = (c % maps.nx - t.i0, c / maps.nx - t.j0);
        let v: [(u32, u32); 4] = std::array::from_fn(|q| {
            let root = r.root[a as usize * 4 + q];
            vertex(&mut m, root, gx + CORNERS[q].0, gy + CORNERS[q].1)
        });
        m.triangles.push([v[0].0, v[3].0, v[1].0]);
        m.triangles.push([v[1].0, v[3].0, v[2].0]);
        m.triangles.push([v[0].1, v[1].1, v[3].1]);
        m.triangles.push([v[1].1, v[2].1, v[3].1]);
    }
    // Skirts on boundary edges, as at full resolution.
    for &a in list {
        let c = r.nodes[a as usize].0;
        let (gx, gy) = (c % maps.nx - t.i0, c / maps.nx - t.j0);
        for (d, &(mine, _)) in EDGE_CORNERS.iter().enumerate() {
            if r.edge_shared(maps, a, d) {
                continue;
            }
            let p = mine.map(|q| {
                let root = r.root[a as usize * 4 + q];
                vertex(&mut m, root, gx + CORNERS[q].0, gy + CORNERS[q].1)
            });
            let (dx, dz) = NEIGHBOURS[d];
            push_skirt(&mut m, p[0], p[1], [dx as f32, 0.0, dz as f32]);
        }
    }
    m.normals = smooth_normals(&m.positions, &m.triangles);
    m
}

/// Every directed edge of `m` has its reverse, exactly once (closed and consistently wound).
fn closed(m: &SnowMesh) -> bool {
    let mut edges: Vec<(u32, u32)> = m
        .triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .collect();
    edges.sort_unstable();
    let n = edges.len();
    edges.dedup();
    edges.len() == n
        && edges
            .iter()
            .all(|&(a, b)| edges.binary_search(&(b, a)).is_ok())
}
