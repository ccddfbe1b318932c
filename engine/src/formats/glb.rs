//! Binary glTF 2.0 (GLB) export of a terrain: one mesh of the DEM's grid with vertex colours
//! (SPEC §1 "Outputs", `terrain.glb`).
//!
//! **Frame.** The renderer's: X = east, Y = up, Z = south, the grid centred on the origin
//! horizontally: point (col, row) → `(col·dx − (w−1)·dx/2, h, row·dy − (h−1)·dy/2)`. glTF is Y-up
//! and right-handed, so this needs no node transform.
//!
//! **Simplification.** Regular decimation: the smallest stride `s` with
//! `(⌈(w−1)/s⌉+1)·(⌈(h−1)/s⌉+1) ≤ max_vertices` keeps every `s`-th row and column *plus the last
//! one*, so the mesh covers the whole DEM. Heights and colours are sampled at the kept points
//! (not averaged: peaks on kept points keep their height, and averaging would mix in holes).
//! Rejected for now: error-driven simplification (quadric or RTIN), better per vertex but slower
//! and more code.
//!
//! **Nodata.** Triangles touching a NaN vertex are dropped and unused vertices removed, so every
//! position is finite. Cells are split along the north-west → south-east diagonal, the same as
//! the ray caster.
//!
//! **Layout.** POSITION, NORMAL (smooth, from central differences on the kept grid) and COLOR_0
//! (float VEC3, linear RGB per the glTF spec) in three bufferViews, then u32 indices; every view
//! starts on a 4-byte boundary; the JSON chunk is padded with spaces and the BIN chunk with zeros
//! to 4 bytes. Costs one pass over the kept grid; allocates ~40 bytes per vertex.

use serde_json::json;

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

/// The decimation stride for a `width × height` grid and a vertex budget (at least 4 vertices:
/// the corners are always kept).
pub fn decimation_stride(width: usize, height: usize, max_vertices: usize) -> usize {
    let budget = max_vertices.max(4);
    let n = |len: usize, s: usize| len.saturating_sub(1).div_ceil(s) + 1;
    let mut s = 1;
    // Start near the answer: s ≈ sqrt(w·h / budget).
    let guess = ((width as f64 * height as f64 / budget as f64)
        .sqrt()
        .floor() as usize)
        .max(1);
    if guess > 1 && n(width, guess - 1) * n(height, guess - 1) > budget {
        s = guess - 1;
    }
    while n(width, s) * n(height, s) > budget {
        s += 1;
    }
    s
}

/// Encode the grid as a GLB. `heights` and `colors` are `width × height`, row-major, row 0 north;
/// heights in world units (already exaggerated), NaN = nodata; `colors` linear RGB 0..1. `dx`,
/// `dy` are the cell sizes in metres. At most `max_vertices` vertices (min 4). Panics when the
/// slices are not `width × height` long (a caller bug). A DEM with no valid triangle gives a valid
/// GLB with an empty scene.
pub fn terrain_glb(
    heights: &[f32],
    width: usize,
    height: usize,
    dx: f64,
    dy: f64,
    colors: &[[f32; 3]],
    max_vertices: usize,
) -> Vec<u8> {
    assert_eq!(
        heights.len(),
        width * height,
        "heights must be width × height"
    );
    assert_eq!(
        colors.len(),
        width * height,
        "colors must be width × height"
    );
    let s = decimation_stride(width, height, max_vertices);
    let axis = |len: usize| -> Vec<usize> {
        let mut v: Vec<usize> = (0..len).step_by(s).collect();
        if len > 0 && v.last() != Some(&(len - 1)) {
            v.push(len - 1);
        }
        v
    };
    let cols = axis(width);
    let rows = axis(height);
    let (nc, nr) = (cols.len(), rows.len());
    let hx = width.saturating_sub(1) as f64 * dx * 0.5;
    let hz = height.saturating_sub(1) as f64 * dy * 0.5;
    let hk = |ci: usize, ri: usize| heights[rows[ri] * width + cols[ci]];

    // Triangles on the kept grid, skipping any that touch a hole.
    let mut used = vec![false; nc * nr];
    let mut tris: Vec<[usize; 3]> = Vec::new();
    for ri in 0..nr.saturating_sub(1) {
        for ci in 0..nc.saturating_sub(1) {
            let a = ri * nc + ci;
            let (b, c, d) = (a + 1, a + nc, a + nc + 1);
            let ok = |k: usize| !hk(k % nc, k / nc).is_nan();
            for t in [[a, c, d], [a, d, b]] {
                if t.iter().all(|&k| ok(k)) {
                    for &k in &t {
                        used[k] = true;
                    }
                    tris.push(t);
                }
            }
        }
    }

    // Compact the vertices.
    let mut remap = vec![u32::MAX; nc * nr];
    let mut pos: Vec<f32> = Vec::new();
    let mut nor: Vec<f32> = Vec::new();
    let mut col: Vec<f32> = Vec::new();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    let mut next = 0u32;
    for ri in 0..nr {
        for ci in 0..nc {
            let k = ri * nc + ci;
            if !used[k] {
                continue;
            }
            remap[k] = next;
            next += 1;
            let p = [
                (cols[ci] as f64 * dx - hx) as f32,
                hk(ci, ri),
                (rows[ri] as f64 * dy - hz) as f32,
            ];
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
            pos.extend_from_slice(&p);
            // Gradient over the neighbouring kept points that hold data.
            let grad = |n: usize, i: usize, at: &dyn Fn(usize) -> (f64, f32)| -> f64 {
                let (x0, h0) = at(i);
                let prev = (i > 0).then(|| at(i - 1)).filter(|v| !v.1.is_nan());
                let next = (i + 1 < n).then(|| at(i + 1)).filter(|v| !v.1.is_nan());
                let (a, b) = match (prev, next) {
                    (Some(a), Some(b)) => (a, b),
                    (Some(a), None) => (a, (x0, h0)),
                    (None, Some(b)) => ((x0, h0), b),
                    (None, None) => return 0.0,
                };
                if b.0 > a.0 {
                    f64::from(b.1 - a.1) / (b.0 - a.0)
                } else {
                    0.0
                }
            };
            let gx = grad(nc, ci, &|i| (cols[i] as f64 * dx, hk(i, ri)));
            let gz = grad(nr, ri, &|j| (rows[j] as f64 * dy, hk(ci, j)));
            let l = (gx * gx + 1.0 + gz * gz).sqrt();
            nor.extend_from_slice(&[(-gx / l) as f32, (1.0 / l) as f32, (-gz / l) as f32]);
            col.extend_from_slice(&colors[rows[ri] * width + cols[ci]]);
        }
    }
    let indices: Vec<u32> = tris.iter().flat_map(|t| t.map(|k| remap[k])).collect();
    let n = next as usize;

    let mut bin: Vec<u8> = Vec::with_capacity(n * 36 + indices.len() * 4);
    let mut views = Vec::new();
    let mut push_view = |bin: &mut Vec<u8>, bytes: &[u8], target: u32| {
        let off = bin.len();
        bin.extend_from_slice(bytes);
        views.push(
            json!({ "buffer": 0, "byteOffset": off, "byteLength": bytes.len(), "target": target }),
        );
    };
    let doc = if n == 0 || indices.is_empty() {
        json!({
            "asset": { "version": "2.0", "generator": "phenomena" },
            "scene": 0,
            "scenes": [{}]
        })
    } else {
        push_view(&mut bin, &f32_bytes(&pos), ARRAY_BUFFER);
        push_view(&mut bin, &f32_bytes(&nor), ARRAY_BUFFER);
        push_view(&mut bin, &f32_bytes(&col), ARRAY_BUFFER);
        let idx: Vec<u8> = indices.iter().flat_map(|v| v.to_le_bytes()).collect();
        push_view(&mut bin, &idx, ELEMENT_ARRAY_BUFFER);
        json!({
            "asset": { "version": "2.0", "generator": "phenomena" },
            "scene": 0,
            "scenes": [{ "nodes": [0] }],
            "nodes": [{ "mesh": 0, "name": "terrain" }],
            "meshes": [{ "name": "terrain", "primitives": [{
                "attributes": { "POSITION": 0, "NORMAL": 1, "COLOR_0": 2 },
                "indices": 3, "material": 0, "mode": 4
            }]}],
            "materials": [{ "name": "terrain", "pbrMetallicRoughness": {
                "baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0
            }}],
            "accessors": [
                { "bufferView": 0, "componentType": FLOAT, "count": n, "type": "VEC3",
                  "min": lo, "max": hi },
                { "bufferView": 1, "componentType": FLOAT, "count": n, "type": "VEC3" },
                { "bufferView": 2, "componentType": FLOAT, "count": n, "type": "VEC3" },
                { "bufferView": 3, "componentType": UNSIGNED_INT, "count": indices.len(), "type": "SCALAR" }
            ],
            "bufferViews": views,
            "buffers": [{ "byteLength": bin.len() }]
        })
    };
    glb_container(&doc, &bin)
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Wrap a glTF JSON document and its binary buffer in the GLB container (header, JSON chunk
/// padded with spaces, BIN chunk padded with zeros; the BIN chunk is omitted when empty).
pub fn glb_container(doc: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut json = doc.to_string().into_bytes();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let bin_padded = bin.len().div_ceil(4) * 4;
    let total = 12 + 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin_padded };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin_padded as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin);
        out.resize(total, 0);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stride_fits_budget_and_is_minimal() {
        for (w, h, b) in [
            (400, 200, 10_000),
            (4096, 4096, 1_000_000),
            (2, 2, 1),
            (1000, 3, 50),
        ] {
            let s = decimation_stride(w, h, b);
            let n = |len: usize, s: usize| (len - 1).div_ceil(s) + 1;
            assert!(
                n(w, s) * n(h, s) <= b.max(4),
                "{w}x{h} budget {b}: stride {s}"
            );
            if s > 1 {
                assert!(n(w, s - 1) * n(h, s - 1) > b.max(4));
            }
        }
    }
}
