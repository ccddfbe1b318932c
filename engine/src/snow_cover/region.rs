//! Snow-possible regions (journal §2.1 "積雪可能領域の判定"; SPEC §2 step 1), automated.
//!
//! The paper groups polygons that do not overlap seen from above by hand and z-buffers each group
//! from above. We peel instead: every triangle (both facings) is rasterised top-down at the cell
//! centres into per-cell fragment lists `(height, facing)`; each list is sorted from the top and
//! fragments within a depth epsilon of a group's top (`1e-4 ×` the scene's diagonal) merge into one
//! *depth group*. A group is a **snow-possible surface** — a layer at that cell — when it contains
//! an upward-facing fragment (unit normal `n_y > 0.05`, i.e. slopes below ~87°) and nothing else:
//! a downward or near-vertical fragment in the same group means the surface is covered by solid
//! (the floor under a closed box standing on it), so no snow rests there. **Winding**: real files
//! hold open surfaces wound either way (the floor of `inventor_chesschairs.glb` faces down), so the
//! peeling counts, from the sky down, the solids a column has entered (an upward group) and left
//! (a downward group); a group of only downward fragments met *outside* every solid is an open
//! surface wound the other way and is snow-possible too, with its normal turned up. A closed
//! solid's underside always comes after its top in the column, so it is never mistaken for one.
//! Its base is the group's
//! highest upward fragment, its ceiling the lowest fragment of the group above (`+∞` under open
//! sky). At most [`MAX_LAYERS`] layers per cell are kept (the deepest are dropped). Layers are
//! indexed per cell from the top (see [`super::maps`]), so a table top and the floor under it are
//! layers 0 and 1 there while the floor outside is layer 0.
//!
//! **Connectivity** ([`MapLayer::links`]). From layer k at cell c (base b) toward a 4-neighbour c',
//! snow lands on the *highest layer of c' whose base is at most `b + step`*, with
//! `step = cell · tan 75°` (surfaces up to 75° steep count as continuous): the floor continues
//! from layer 0 outside a table to layer 1 under it, and snow leaving a table top lands on the
//! floor below — the paper's falling (§2.4.2: "the highest region lower than the source"), found by
//! this per-cell lookup instead of the ID buffer of §5.1. If c' has geometry but no such layer it
//! is a **wall** (no move); if c' is off the map or has no geometry at all, it is the **edge of the
//! scene** and snow moved there is lost.
//!
//! Rejected: (a) a fixed K passes of max-depth peeling (one rasterisation per layer and no way to see
//! that a floor is covered by the bottom of a box standing on it); (b) choosing layers by normal
//! only (the paper's reference [7]): that cannot tell the floor under a table from the floor beside
//! it; (c) treating only equal layer indices as neighbours: the floor would break at the table's
//! edge.
//!
//! Cost: one rasterisation of the scene (rayon over bands of rows, triangles binned by band), a
//! sort of each band's fragments, then `O(cells · layers)`. Allocates the fragment lists (8 bytes
//! per covered cell centre per triangle) and the maps.

use rayon::prelude::*;

use super::maps::{MapLayer, SnowMaps, LINK_LOST, LINK_WALL, NEIGHBOURS};
use crate::geom::mesh::Mesh;
use crate::{Canceled, Control};

/// Most layers kept per cell.
pub const MAX_LAYERS: usize = 8;
/// A triangle faces up when its unit normal's Y exceeds this (slopes below ~87.1°).
pub const UP_FACING_MIN_NY: f32 = 0.05;
/// Depth epsilon as a fraction of the scene's bounding-box diagonal.
pub const DEPTH_EPS_REL: f32 = 1e-4;
/// Steepest surface (degrees) still counted as continuous between neighbouring cells.
pub const STEP_SLOPE_DEG: f32 = 75.0;

/// Rows per rasterisation band.
const BAND_ROWS: usize = 16;

/// One fragment: cell index within the band, height, triangle index (its facing and normal).
#[derive(Clone, Copy)]
struct Fragment {
    cell: u32,
    h: f32,
    tri: u32,
}

/// Per-cell result of the peeling: the snow layers from the top and the column's top.
struct BandOut {
    /// Per cell of the band: up to MAX_LAYERS (base, ceiling, triangle, wound downward).
    layers: Vec<Vec<(f32, f32, u32, bool)>>,
    /// Per cell: highest fragment (NaN = empty column).
    top: Vec<f32>,
}

/// Grid of the snow maps for a mesh: `resolution` cells across the longer horizontal side.
/// Returns `(nx, nz, cell, origin)`; `None` for an empty mesh.
pub fn grid_for(mesh: &Mesh, resolution: usize) -> Option<(usize, usize, f32, [f32; 2], f32)> {
    let (lo, hi) = mesh.bounds()?;
    let ex = hi[0] - lo[0];
    let ez = hi[2] - lo[2];
    let diag = ((ex * ex) + (hi[1] - lo[1]).powi(2) + ez * ez)
        .sqrt()
        .max(1e-6);
    let longer = ex.max(ez);
    let res = resolution.max(1);
    let cell = if longer > 0.0 {
        longer / res as f32
    } else {
        diag.max(1.0) / res as f32
    };
    let nx = ((ex / cell).ceil() as usize).clamp(1, res);
    let nz = ((ez / cell).ceil() as usize).clamp(1, res);
    Some((nx, nz, cell, [lo[0], lo[2]], diag))
}

/// Build the snow maps of `mesh` (module doc): geometry, links; probability and snow zero.
/// `resolution` ≥ 1 cells across the longer horizontal side. An empty mesh gives a 1 × 1 map with
/// no surface. Checks for cancellation between bands.
pub fn build_snow_maps(
    mesh: &Mesh,
    resolution: usize,
    ctl: &dyn Control,
) -> Result<SnowMaps, Canceled> {
    let Some((nx, nz, cell, origin, extent)) = grid_for(mesh, resolution) else {
        return Ok(SnowMaps {
            nx: 1,
            nz: 1,
            cell: 1.0,
            origin: [0.0, 0.0],
            layers: vec![MapLayer::empty(1)],
            extent: 1.0,
        });
    };
    ctl.checkpoint()?;
    let eps = DEPTH_EPS_REL * extent;

    // Bin triangles by band of rows (by their z-range).
    let n_bands = nz.div_ceil(BAND_ROWS);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); n_bands];
    let mut unit_ny = Vec::with_capacity(mesh.triangles.len());
    for t in 0..mesh.triangles.len() {
        let n = mesh.face_normal(t);
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        unit_ny.push(if len > 0.0 { n[1] / len } else { 0.0 });
        let [a, b, c] = mesh.corners(t);
        let zmin = a[2].min(b[2]).min(c[2]);
        let zmax = a[2].max(b[2]).max(c[2]);
        // Rows whose centre may lie in [zmin, zmax].
        let j0 = ((zmin - origin[1]) / cell - 0.5).ceil().max(0.0) as usize;
        let j1 = ((zmax - origin[1]) / cell - 0.5).floor();
        if j1 < 0.0 || j0 >= nz {
            continue;
        }
        let j1 = (j1 as usize).min(nz - 1);
        if j0 > j1 {
            continue;
        }
        for bin in bins
            .iter_mut()
            .take(j1 / BAND_ROWS + 1)
            .skip(j0 / BAND_ROWS)
        {
            bin.push(t as u32);
        }
    }

    let bands: Vec<Result<BandOut, Canceled>> = bins
        .par_iter()
        .enumerate()
        .map(|(band, tris)| {
            ctl.checkpoint()?;
            let j0 = band * BAND_ROWS;
            let j1 = (j0 + BAND_ROWS).min(nz);
            Ok(peel_band(
                mesh,
                tris,
                &unit_ny,
                nx,
                j0..j1,
                cell,
                origin,
                eps,
            ))
        })
        .collect();

    let n = nx * nz;
    let mut n_layers = 1;
    let mut outs = Vec::with_capacity(n_bands);
    for b in bands {
        let b = b?;
        n_layers = n_layers.max(b.layers.iter().map(Vec::len).max().unwrap_or(0));
        outs.push(b);
    }
    let mut layers: Vec<MapLayer> = (0..n_layers).map(|_| MapLayer::empty(n)).collect();
    let mut top = vec![f32::NAN; n];
    for (band, out) in outs.iter().enumerate() {
        let c0 = band * BAND_ROWS * nx;
        for (k, cell_layers) in out.layers.iter().enumerate() {
            let c = c0 + k;
            top[c] = out.top[k];
            for (l, &(base, ceiling, tri, flipped)) in cell_layers.iter().enumerate() {
                let nrm = mesh.face_normal(tri as usize);
                let len = (nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]).sqrt();
                let len = if flipped { -len } else { len };
                let layer = &mut layers[l];
                layer.base[c] = base;
                layer.ceiling[c] = ceiling;
                layer.normal[c] = [nrm[0] / len, nrm[1] / len, nrm[2] / len];
            }
        }
    }
    ctl.checkpoint()?;

    let mut maps = SnowMaps {
        nx,
        nz,
        cell,
        origin,
        layers,
        extent,
    };
    compute_links(&mut maps, &top);
    Ok(maps)
}

/// Rasterise the band's triangles at the cell centres of rows `rows` and group the fragments.
#[allow(clippy::too_many_arguments)]
fn peel_band(
    mesh: &Mesh,
    tris: &[u32],
    unit_ny: &[f32],
    nx: usize,
    rows: std::ops::Range<usize>,
    cell: f32,
    origin: [f32; 2],
    eps: f32,
) -> BandOut {
    let ncell = rows.len() * nx;
    let mut frags: Vec<Fragment> = Vec::new();
    for &t in tris {
        let [a, b, c] = mesh.corners(t as usize);
        // Grid coordinates (cell centres at integers).
        let p = [a, b, c].map(|v| {
            [
                (v[0] - origin[0]) / cell - 0.5,
                (v[2] - origin[1]) / cell - 0.5,
                v[1],
            ]
        });
        let area =
            (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[1][1] - p[0][1]) * (p[2][0] - p[0][0]);
        if area.abs() < 1e-12 {
            continue; // vertical in plan: covers no centre
        }
        let inv = 1.0 / area;
        let xmin = p[0][0].min(p[1][0]).min(p[2][0]).ceil().max(0.0);
        let xmax = p[0][0]
            .max(p[1][0])
            .max(p[2][0])
            .floor()
            .min(nx as f32 - 1.0);
        let zmin = p[0][1]
            .min(p[1][1])
            .min(p[2][1])
            .ceil()
            .max(rows.start as f32);
        let zmax = p[0][1]
            .max(p[1][1])
            .max(p[2][1])
            .floor()
            .min(rows.end as f32 - 1.0);
        if xmin > xmax || zmin > zmax {
            continue;
        }
        for j in zmin as usize..=zmax as usize {
            let z = j as f32;
            for i in xmin as usize..=xmax as usize {
                let x = i as f32;
                // Barycentrics (inclusive edges: no cracks between triangles).
                let w0 = ((p[1][0] - x) * (p[2][1] - z) - (p[1][1] - z) * (p[2][0] - x)) * inv;
                let w1 = ((p[2][0] - x) * (p[0][1] - z) - (p[2][1] - z) * (p[0][0] - x)) * inv;
                let w2 = 1.0 - w0 - w1;
                const E: f32 = -1e-6;
                if w0 < E || w1 < E || w2 < E {
                    continue;
                }
                let h = w0 * p[0][2] + w1 * p[1][2] + w2 * p[2][2];
                frags.push(Fragment {
                    cell: ((j - rows.start) * nx + i) as u32,
                    h,
                    tri: t,
                });
            }
        }
    }
    // Deterministic order: by cell, height descending, then triangle index.
    frags.sort_unstable_by(|a, b| {
        a.cell
            .cmp(&b.cell)
            .then(b.h.total_cmp(&a.h))
            .then(a.tri.cmp(&b.tri))
    });
    let mut layers: Vec<Vec<(f32, f32, u32, bool)>> = vec![Vec::new(); ncell];
    let mut top = vec![f32::NAN; ncell];
    let mut k = 0;
    while k < frags.len() {
        let c = frags[k].cell as usize;
        let mut end = k;
        while end < frags.len() && frags[end].cell as usize == c {
            end += 1;
        }
        top[c] = frags[k].h;
        let mut ceiling = f32::INFINITY;
        // Solids entered minus left, counting from the sky down (module doc: winding).
        let mut inside = 0u32;
        let mut g = k;
        while g < end {
            let g_top = frags[g].h;
            let mut up: Option<(f32, u32)> = None;
            let mut down: Option<(f32, u32)> = None;
            let mut vertical = false;
            let mut g_end = g;
            while g_end < end && frags[g_end].h >= g_top - eps {
                let f = frags[g_end];
                let ny = unit_ny[f.tri as usize];
                if ny > UP_FACING_MIN_NY {
                    up = up.or(Some((f.h, f.tri)));
                } else if ny < -UP_FACING_MIN_NY {
                    down = down.or(Some((f.h, f.tri)));
                } else {
                    vertical = true;
                }
                g_end += 1;
            }
            let surface = match (up, down, vertical) {
                (Some((h, tri)), None, false) => {
                    inside += 1;
                    Some((h, tri, false))
                }
                (None, Some(_), _) if inside > 0 => {
                    inside -= 1;
                    None
                }
                // Facing down with no solid above it: an open surface wound the other way.
                (None, Some((h, tri)), false) => Some((h, tri, true)),
                _ => None,
            };
            if let Some(s) = surface {
                if layers[c].len() < MAX_LAYERS {
                    layers[c].push((s.0, ceiling, s.1, s.2));
                }
            }
            ceiling = frags[g_end - 1].h;
            g = g_end;
        }
        k = end;
    }
    BandOut { layers, top }
}

/// Fill [`MapLayer::links`] of every layer (module doc). `top` = highest geometry per column.
fn compute_links(maps: &mut SnowMaps, top: &[f32]) {
    let (nx, nz) = (maps.nx, maps.nz);
    let step = maps.cell * STEP_SLOPE_DEG.to_radians().tan();
    let bases: Vec<Vec<f32>> = maps.layers.iter().map(|l| l.base.clone()).collect();
    let n_layers = bases.len();
    for layer in maps.layers.iter_mut() {
        layer
            .links
            .par_chunks_mut(nx)
            .zip(layer.base.par_chunks(nx))
            .enumerate()
            .for_each(|(j, (links, base))| {
                for i in 0..nx {
                    let b = base[i];
                    if b.is_nan() {
                        continue;
                    }
                    for (d, &(di, dj)) in NEIGHBOURS.iter().enumerate() {
                        let (i2, j2) = (i as isize + di, j as isize + dj);
                        if i2 < 0 || j2 < 0 || i2 as usize >= nx || j2 as usize >= nz {
                            links[i][d] = LINK_LOST;
                            continue;
                        }
                        let c2 = j2 as usize * nx + i2 as usize;
                        let mut link = if top[c2].is_nan() {
                            LINK_LOST
                        } else {
                            LINK_WALL
                        };
                        // Layers are ordered from the top: the first one low enough is the highest.
                        for (k2, b2) in bases.iter().enumerate().take(n_layers) {
                            let h2 = b2[c2];
                            if !h2.is_nan() && h2 <= b + step {
                                link = k2 as u8;
                                break;
                            }
                        }
                        links[i][d] = link;
                    }
                }
            });
    }
}
