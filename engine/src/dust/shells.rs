//! How thick the dust lies: the shell method (SPEC §4 step 2; paper §2.2, after Lengyel et al.
//! 2001, "Real-time fur over arbitrary surfaces").
//!
//! `shells` layers are offset along the vertex normal, up to `max_thickness`·D. **Our reading of
//! the indices:** layers are numbered i = 1..=`shells` (bottom to top); layer i sits at height
//! h_i = (i / `shells`) · `max_thickness` · D above the base surface, and a texel of layer i is
//! drawn only where noise × D ≥ i / `shells` (the Perlin fBm of [`super::noise`] raises bumps).
//! Numbering from 1 keeps both rules of the SPEC with the same i while (a) no layer lies on the
//! base surface itself (no z-fighting) and (b) a surface without dust (D = 0) gets no layer at
//! all. Where noise × D < 1/`shells` the surface shows no dust; the top layer only shows where
//! noise × D reaches 1, so with K ≤ 1 the dust is thickest in the noise's bright blobs on the most
//! exposed, most horizontal faces.
//!
//! Cost: O(V · shells) for the offsets; no allocation beyond the returned vectors.

/// Height fraction of layer `i` (1-based) of `shells`: i / shells.
#[inline]
pub fn layer_fraction(i: u32, shells: u32) -> f32 {
    if shells == 0 {
        0.0
    } else {
        i as f32 / shells as f32
    }
}

/// Whether a texel of layer `i` (1-based) of `shells` is drawn, given the noise value (0–1) and
/// the dust amount D there: noise × D ≥ i / shells.
#[inline]
pub fn texel_drawn(i: u32, shells: u32, noise: f32, d: f32) -> bool {
    i >= 1 && i <= shells && noise * d >= layer_fraction(i, shells)
}

/// Positions of layer `i` (1-based): each vertex moved along its unit normal by
/// (i / shells) · `max_thickness` · D. `positions`, `normals` and `amount` have one entry per
/// vertex. Allocates the result.
pub fn layer_positions(
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    amount: &[f32],
    max_thickness: f32,
    i: u32,
    shells: u32,
) -> Vec<[f32; 3]> {
    let f = layer_fraction(i, shells) * max_thickness;
    positions
        .iter()
        .zip(normals)
        .zip(amount)
        .map(|((p, n), d)| {
            let h = f * d;
            [p[0] + h * n[0], p[1] + h * n[1], p[2] + h * n[2]]
        })
        .collect()
}

/// Whether any texel of a triangle with corner amounts `d` can be drawn in layer `i` of
/// `shells`: the noise is at most 1 and D is interpolated linearly, so only where the largest
/// corner D reaches i / shells. The renderer and the glTF export draw layer i over these
/// triangles only.
#[inline]
pub fn triangle_reaches(d: [f32; 3], i: u32, shells: u32) -> bool {
    d[0].max(d[1]).max(d[2]) >= layer_fraction(i, shells) && i >= 1 && i <= shells
}

/// The part of the mesh that layer `i` (1-based) covers: the triangles that reach it
/// ([`triangle_reaches`]) and only the vertices they use, renumbered in first-use order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ShellLayer {
    /// ShellLayer number, 1 = bottom.
    pub index: u32,
    /// Base-mesh vertex of each layer vertex.
    pub vertices: Vec<u32>,
    /// Triangles, indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
    /// Base-mesh triangle of each layer triangle.
    pub source: Vec<u32>,
}

/// Builds layer `i` of `shells` over `triangles` with per-vertex `amount` (D). `remap` is
/// scratch space of one entry per base vertex, all `u32::MAX` on entry and on return (so one
/// buffer serves every layer without clearing). Allocates the layer. O(triangles).
pub fn layer(
    triangles: &[[u32; 3]],
    amount: &[f32],
    i: u32,
    shells: u32,
    remap: &mut [u32],
) -> ShellLayer {
    let mut out = ShellLayer {
        index: i,
        ..ShellLayer::default()
    };
    for (t, tri) in triangles.iter().enumerate() {
        let d = tri.map(|v| amount.get(v as usize).copied().unwrap_or(0.0));
        if !triangle_reaches(d, i, shells) {
            continue;
        }
        let local = tri.map(|v| {
            let r = &mut remap[v as usize];
            if *r == u32::MAX {
                *r = out.vertices.len() as u32;
                out.vertices.push(v);
            }
            *r
        });
        out.triangles.push(local);
        out.source.push(t as u32);
    }
    for &v in &out.vertices {
        remap[v as usize] = u32::MAX;
    }
    out
}
