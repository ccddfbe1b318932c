//! The surface the dust lies on: the input mesh with one unit normal per vertex, split at creases.
//!
//! D (SPEC §4 step 1) is computed per vertex from the vertex normal, and the shells (step 2) are
//! offset along it. A mesh without normals (STL, PLY, many OBJ and glTF files) shares a vertex
//! between, say, the top of a table and its rim; the area-weighted mean normal there leans 45° off
//! the top, so the whole top would get D = K·cos^s 45° from its corners and its shells would bulge
//! over the edge. So, as modelling tools do with smoothing groups, each vertex is split into one
//! copy per *smoothing group* of the faces around it: faces that share an edge at the vertex and
//! whose normals are within [`CREASE_DEG`] of each other are in one group (transitively, so a
//! finely tessellated curve stays one group); each copy's normal is the area-weighted mean of its
//! group's face normals. A mesh with its own normals (glTF, OBJ `vn`) keeps them: its vertices are
//! already split where its author wanted hard edges.
//!
//! **Which side is up.** D needs the *outward* normal, and input windings are not reliable (the
//! renderer draws both sides for the same reason): the Inventor scenes' floor is a quad wound
//! facing down. So the faces are oriented per connected piece (triangles joined by shared
//! vertices) before anything else ([`flipped_triangles`]): a *closed* piece (every edge used by
//! two triangles) keeps its winding unless its signed volume is negative (wound inside out); an
//! *open* piece that is a sheet (a floor, a leaf: its area-weighted mean normal at least
//! [`SHEET_MEAN_NORMAL`] long) has no inside, so dust lies on the side that faces the dust source
//! more — it is flipped when Σ area·(n·U) < 0; an open piece that encloses space (a scanned shell
//! with a few holes, a body without its base) is oriented by its signed volume about its own
//! centre, like a closed one. Our reading; a closed piece's underside still gets no dust.
//!
//! **Refined.** D and the exposure live on the vertices, so a floor made of one quad would carry
//! one value per corner and could not be thinner under a table. [`refine`] splits edges longer
//! than 1/[`EDGES_PER_DIAGONAL`] of the bounding-box diagonal (per part, by edge midpoints,
//! crack-free: [`crate::geom::subdivide::subdivide`], shared with the snow cover), up to
//! [`MAX_REFINED_TRIANGLES`] triangles; normals, UVs and vertex colours are interpolated to the
//! new vertices (textures and parts are shared).
//! Finely tessellated meshes (the Stanford models) are left as they are.
//!
//! Known limitation: shells of two groups meeting at a crease part along it (each is offset along
//! its own normal) — the shell method's usual gap at hard edges.
//!
//! Cost: O(Σ valence²) comparisons, parallel over nothing (one pass); allocates a copy of the mesh
//! (plus one vertex per extra group) and the per-vertex incidence lists (8 B per corner).

use crate::geom::unit;
use crate::geom::Mesh;

/// Faces meeting at a vertex at less than this angle share its normal.
pub const CREASE_DEG: f32 = 45.0;

/// An open piece is a sheet (oriented by the side facing the dust source) when its mean unit
/// normal, area-weighted, is at least this long; an open piece below it encloses space (a shell
/// with holes, a body without its base: Σ area·n is the missing part's) and is oriented by its
/// signed volume like a closed one. A turbine blade scanned with a few holes (0.01) was taken
/// for a sheet and turned upside down by the facing rule (its underside is 1.6 % larger than
/// its top), so its top got no dust.
pub const SHEET_MEAN_NORMAL: f64 = 0.5;

/// [`refine`] splits edges longer than the bounding-box diagonal / this.
pub const EDGES_PER_DIAGONAL: f32 = 48.0;

/// [`refine`] stops before the mesh would exceed this many triangles (or its own count, if
/// larger): the exposure costs 64 rays per vertex, ~1 s per 100,000 vertices.
pub const MAX_REFINED_TRIANGLES: usize = 150_000;

/// Splits long edges (module doc, "Refined"), per part; `normals` (one per vertex) grow with the
/// mesh. Parts keep their order and get their new triangle ranges. Allocates the new arrays.
pub fn refine(mesh: &mut Mesh, normals: &mut Vec<[f32; 3]>) {
    let Some((lo, hi)) = mesh.bounds() else {
        return;
    };
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt();
    let max_len = diag / EDGES_PER_DIAGONAL;
    if !(max_len > 0.0 && max_len.is_finite()) || normals.len() != mesh.positions.len() {
        return;
    }
    let cap = MAX_REFINED_TRIANGLES.max(mesh.triangles.len());
    // Parts tile the triangles; a mesh without parts is one.
    let ranges: Vec<(usize, usize)> = if mesh.parts.is_empty() {
        vec![(0, mesh.triangles.len())]
    } else {
        mesh.parts
            .iter()
            .map(|p| {
                let end = (p.first_triangle + p.triangle_count).min(mesh.triangles.len());
                (p.first_triangle.min(end), end)
            })
            .collect()
    };
    let mut out: Vec<[u32; 3]> = Vec::with_capacity(mesh.triangles.len());
    let mut new_ranges = Vec::with_capacity(ranges.len());
    let mut total = mesh.triangles.len();
    for (a, b) in ranges {
        let mut tris = mesh.triangles[a..b].to_vec();
        let before = tris.len();
        let budget = cap.saturating_sub(total - before);
        let uvs = &mut mesh.uvs;
        let colors = &mut mesh.colors;
        crate::geom::subdivide::subdivide_with(
            &mut mesh.positions,
            &mut tris,
            max_len,
            budget,
            |i, j| {
                let (ni, nj) = (normals[i as usize], normals[j as usize]);
                normals.push(unit([ni[0] + nj[0], ni[1] + nj[1], ni[2] + nj[2]]));
                if let Some(u) = uvs.as_mut() {
                    let (ui, uj) = (u[i as usize], u[j as usize]);
                    u.push([0.5 * (ui[0] + uj[0]), 0.5 * (ui[1] + uj[1])]);
                }
                if let Some(c) = colors.as_mut() {
                    let (ci, cj) = (c[i as usize], c[j as usize]);
                    c.push([0, 1, 2, 3].map(|k| 0.5 * (ci[k] + cj[k])));
                }
            },
        );
        total = total - before + tris.len();
        new_ranges.push((out.len(), tris.len()));
        out.extend(tris);
    }
    for (p, (first, count)) in mesh.parts.iter_mut().zip(new_ranges) {
        p.first_triangle = first;
        p.triangle_count = count;
    }
    mesh.triangles = out;
    mesh.normals = Some(normals.clone());
}

/// Per triangle, whether its winding is turned over for dust lying toward `u` (the unit direction
/// to the dust source): see "Which side is up" in the module doc. Allocates a union-find over the
/// vertices and an edge map. O(triangles).
pub fn flipped_triangles(mesh: &Mesh, u: [f32; 3]) -> Vec<bool> {
    let nv = mesh.positions.len();
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    fn find(p: &mut [u32], mut i: u32) -> u32 {
        while p[i as usize] != i {
            p[i as usize] = p[p[i as usize] as usize];
            i = p[i as usize];
        }
        i
    }
    for t in &mesh.triangles {
        for k in 1..3 {
            let (a, b) = (find(&mut parent, t[0]), find(&mut parent, t[k]));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    // Edge uses, to tell closed pieces from open ones.
    let mut edges: std::collections::HashMap<(u32, u32), u32> =
        std::collections::HashMap::with_capacity(mesh.triangles.len() * 3 / 2);
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    // Per piece (by root vertex): open?, signed volume ×6, Σ area·(n·U) ×2.
    let mut open = vec![false; nv];
    for (&(a, _), &n) in &edges {
        if n != 2 {
            let r = find(&mut parent, a);
            open[r as usize] = true;
        }
    }
    // Per piece: a reference point (the mean of its triangles' corners), so that the signed
    // volume of a piece with a hole does not depend on where the file's origin is.
    let mut centre = vec![[0.0f64; 3]; nv];
    let mut corners = vec![0u64; nv];
    for (ti, t) in mesh.triangles.iter().enumerate() {
        let r = find(&mut parent, t[0]) as usize;
        for p in mesh.corners(ti) {
            for k in 0..3 {
                centre[r][k] += f64::from(p[k]);
            }
        }
        corners[r] += 3;
    }
    for (c, &n) in centre.iter_mut().zip(&corners) {
        if n > 0 {
            *c = c.map(|v| v / n as f64);
        }
    }
    let mut volume = vec![0.0f64; nv];
    let mut facing = vec![0.0f64; nv];
    let mut normal_sum = vec![[0.0f64; 3]; nv];
    let mut area = vec![0.0f64; nv];
    for (ti, t) in mesh.triangles.iter().enumerate() {
        let r = find(&mut parent, t[0]) as usize;
        let o = centre[r];
        let [a, b, c] = mesh
            .corners(ti)
            .map(|p| [0, 1, 2].map(|k| f64::from(p[k]) - o[k]));
        volume[r] += a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]);
        let f = mesh.face_normal(ti).map(f64::from);
        facing[r] += f[0] * f64::from(u[0]) + f[1] * f64::from(u[1]) + f[2] * f64::from(u[2]);
        for k in 0..3 {
            normal_sum[r][k] += f[k];
        }
        area[r] += (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
    }
    mesh.triangles
        .iter()
        .map(|t| {
            let r = find(&mut parent, t[0]) as usize;
            let n = normal_sum[r];
            let sheet =
                (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() >= SHEET_MEAN_NORMAL * area[r];
            if open[r] && sheet {
                facing[r] < 0.0
            } else {
                volume[r] < 0.0
            }
        })
        .collect()
}

/// The mesh prepared for dust lying toward `u` (unit direction to the source) and its unit vertex
/// normals (module doc): faces oriented, vertices split at creases. Triangle order, parts and UVs
/// are kept (UVs copied with their vertex); turned-over triangles keep their winding (the renderer
/// and the GLB are two-sided) — only the normals say which side is up.
pub fn crease_split(mesh: &Mesh, u: [f32; 3]) -> (Mesh, Vec<[f32; 3]>) {
    let flip = flipped_triangles(mesh, u);
    if let Some(n) = mesh
        .normals
        .as_ref()
        .filter(|n| n.len() == mesh.positions.len())
    {
        let mut normals: Vec<[f32; 3]> = n.iter().map(|v| unit(*v)).collect();
        // The file's normals follow its winding: turn those of turned-over pieces.
        let mut turned = vec![false; normals.len()];
        for (t, f) in mesh.triangles.iter().zip(&flip) {
            if *f {
                for &v in t {
                    turned[v as usize] = true;
                }
            }
        }
        for (n, t) in normals.iter_mut().zip(&turned) {
            if *t {
                *n = n.map(|c| -c);
            }
        }
        let mut out = mesh.clone();
        out.normals = Some(normals.clone());
        return (out, normals);
    }
    let nv = mesh.positions.len();
    let faces: Vec<[f32; 3]> = (0..mesh.triangles.len())
        .map(|t| {
            let f = mesh.face_normal(t);
            if flip[t] {
                f.map(|c| -c)
            } else {
                f
            }
        })
        .collect();
    let unit_faces: Vec<[f32; 3]> = faces.iter().map(|f| unit(*f)).collect();
    // Incidence lists (CSR): the triangles around each vertex, in triangle order.
    let mut start = vec![0usize; nv + 1];
    for t in &mesh.triangles {
        for &v in t {
            start[v as usize + 1] += 1;
        }
    }
    for i in 0..nv {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut around = vec![0u32; start[nv]];
    for (ti, t) in mesh.triangles.iter().enumerate() {
        for &v in t {
            around[fill[v as usize]] = ti as u32;
            fill[v as usize] += 1;
        }
    }
    let cos_crease = CREASE_DEG.to_radians().cos();
    let mut positions = Vec::with_capacity(nv);
    let mut uvs = mesh.uvs.as_ref().map(|_| Vec::with_capacity(nv));
    let mut colors = mesh.colors.as_ref().map(|_| Vec::with_capacity(nv));
    let mut normals = Vec::with_capacity(nv);
    // New vertex of each corner (triangle, corner index).
    let mut corner = vec![u32::MAX; mesh.triangles.len() * 3];
    let mut group: Vec<usize> = Vec::new();
    for v in 0..nv {
        let fs = &around[start[v]..start[v + 1]];
        if fs.is_empty() {
            // A vertex no triangle uses is dropped.
            continue;
        }
        // Union-find over the faces around v.
        group.clear();
        group.extend(0..fs.len());
        fn root(g: &mut [usize], mut i: usize) -> usize {
            while g[i] != i {
                g[i] = g[g[i]];
                i = g[i];
            }
            i
        }
        for a in 0..fs.len() {
            for b in a + 1..fs.len() {
                let (ta, tb) = (
                    mesh.triangles[fs[a] as usize],
                    mesh.triangles[fs[b] as usize],
                );
                let shares_edge = ta.iter().any(|&x| x as usize != v && tb.contains(&x));
                let (na, nb) = (unit_faces[fs[a] as usize], unit_faces[fs[b] as usize]);
                let close = na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2] >= cos_crease;
                if shares_edge && close {
                    let (ra, rb) = (root(&mut group, a), root(&mut group, b));
                    if ra != rb {
                        group[ra.max(rb)] = ra.min(rb);
                    }
                }
            }
        }
        // One new vertex per group, in order of the group's first face.
        let first_new = positions.len();
        let mut roots: Vec<usize> = Vec::new();
        for (a, &fa) in fs.iter().enumerate() {
            let r = root(&mut group, a);
            let k = match roots.iter().position(|&x| x == r) {
                Some(k) => k,
                None => {
                    roots.push(r);
                    positions.push(mesh.positions[v]);
                    if let (Some(out), Some(src)) = (uvs.as_mut(), mesh.uvs.as_ref()) {
                        out.push(src[v]);
                    }
                    if let (Some(out), Some(src)) = (colors.as_mut(), mesh.colors.as_ref()) {
                        out.push(src[v]);
                    }
                    normals.push([0.0f32; 3]);
                    roots.len() - 1
                }
            };
            let t = fa as usize;
            let f = faces[t];
            let n = &mut normals[first_new + k];
            for (nc, fc) in n.iter_mut().zip(f) {
                *nc += fc;
            }
            for (c, &x) in mesh.triangles[t].iter().enumerate() {
                if x as usize == v {
                    corner[t * 3 + c] = (first_new + k) as u32;
                }
            }
        }
    }
    for n in &mut normals {
        *n = unit(*n);
    }
    let triangles = (0..mesh.triangles.len())
        .map(|t| [corner[t * 3], corner[t * 3 + 1], corner[t * 3 + 2]])
        .collect();
    let out = Mesh {
        positions,
        triangles,
        normals: Some(normals.clone()),
        uvs,
        colors,
        textures: mesh.textures.clone(),
        parts: mesh.parts.clone(),
        notes: mesh.notes.clone(),
    };
    (out, normals)
}
