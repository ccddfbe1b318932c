//! Mesh subdivision by edge midpoints: the snow cover's displaced mesh (SPEC §2 step 7, workshop
//! §2.3 polygon variant) and the dust's refined surface (SPEC §4) both cut long edges this way.

use std::collections::HashMap;

use super::vec::Vec3;

/// Most subdivision passes (each halves the long edges; 32 passes cut any edge by 2³²).
const MAX_SUBDIVISION_PASSES: usize = 32;

/// Subdivide in place by edge midpoints until no edge is longer than `max_len` metres, in passes:
/// each pass splits every too-long edge once (a triangle with 1, 2 or 3 split edges becomes 2, 3
/// or 4; with 2, the remaining quad is cut along its shorter diagonal), shared edges get one
/// midpoint, so the surface stays crack-free and keeps its winding. Stops before a pass would make
/// more than `max_triangles` triangles, or after 32 passes; edges may then stay longer than
/// `max_len`. Deterministic: midpoints are keyed by their sorted vertex pair and created in
/// triangle order. Allocates one map of midpoints per pass.
pub fn subdivide(
    positions: &mut Vec<[f32; 3]>,
    triangles: &mut Vec<[u32; 3]>,
    max_len: f32,
    max_triangles: usize,
) {
    subdivide_with(positions, triangles, max_len, max_triangles, |_, _| {});
}

/// [`subdivide`], calling `on_mid(a, b)` right after the midpoint of edge (a, b) is appended to
/// `positions`, so callers can append the vertex's other attributes (normal, UV) in step.
pub fn subdivide_with(
    positions: &mut Vec<[f32; 3]>,
    triangles: &mut Vec<[u32; 3]>,
    max_len: f32,
    max_triangles: usize,
    mut on_mid: impl FnMut(u32, u32),
) {
    let too_long = |p: &[[f32; 3]], a: u32, b: u32| {
        Vec3::from(p[a as usize]).distance_squared(Vec3::from(p[b as usize])) > max_len * max_len
    };
    for _ in 0..MAX_SUBDIVISION_PASSES {
        let splits: usize = triangles
            .iter()
            .map(|t| {
                (0..3)
                    .filter(|&e| too_long(positions, t[e], t[(e + 1) % 3]))
                    .count()
            })
            .sum();
        if splits == 0 || triangles.len() + splits > max_triangles {
            return;
        }
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(triangles.len() + splits);
        for &t in triangles.iter() {
            let mut m = [u32::MAX; 3]; // midpoint of edge e = (t[e], t[e+1])
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                if too_long(positions, a, b) {
                    let key = (a.min(b), a.max(b));
                    m[e] = *mid.entry(key).or_insert_with(|| {
                        let (pa, pb) = (positions[a as usize], positions[b as usize]);
                        positions.push([
                            0.5 * (pa[0] + pb[0]),
                            0.5 * (pa[1] + pb[1]),
                            0.5 * (pa[2] + pb[2]),
                        ]);
                        on_mid(a, b);
                        positions.len() as u32 - 1
                    });
                }
            }
            let split: Vec<usize> = (0..3).filter(|&e| m[e] != u32::MAX).collect();
            match split.len() {
                0 => next.push(t),
                1 => {
                    // Edge e split: (a, m, c), (m, b, c).
                    let e = split[0];
                    let (a, b, c) = (t[e], t[(e + 1) % 3], t[(e + 2) % 3]);
                    next.push([a, m[e], c]);
                    next.push([m[e], b, c]);
                }
                2 => {
                    // The unsplit edge u = (a, b); c opposite. Midpoints mb on (b, c), mc on (c, a).
                    let u = (0..3).find(|&e| m[e] == u32::MAX).unwrap_or(0);
                    let (a, b, c) = (t[u], t[(u + 1) % 3], t[(u + 2) % 3]);
                    let (mb, mc) = (m[(u + 1) % 3], m[(u + 2) % 3]);
                    next.push([mc, mb, c]);
                    // Quad (a, b, mb, mc): cut along its shorter diagonal (ties: a–mb).
                    let at = |i: u32| Vec3::from(positions[i as usize]);
                    if at(a).distance_squared(at(mb)) <= at(b).distance_squared(at(mc)) {
                        next.push([a, b, mb]);
                        next.push([a, mb, mc]);
                    } else {
                        next.push([a, b, mc]);
                        next.push([b, mb, mc]);
                    }
                }
                _ => {
                    let (a, b, c) = (t[0], t[1], t[2]);
                    next.push([a, m[0], m[2]]);
                    next.push([m[0], b, m[1]]);
                    next.push([m[2], m[1], c]);
                    next.push([m[0], m[1], m[2]]);
                }
            }
        }
        *triangles = next;
    }
}
