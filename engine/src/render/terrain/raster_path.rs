//! The terrain's raster path (see "Two paths" in [`super`]): the grid's two triangles per cell
//! through [`render_adaptive_with`], each sample shaded as the ray caster shades a hit.
//!
//! **Where a sample lands.** The visibility buffer names the screen triangle; its mesh triangle
//! ([`Rasterizer::source`], 4 bytes per triangle) is triangle A or B of cell `k / 2`. The
//! sample's pixel ray is intersected with that triangle's plane (the same planes as the ray
//! caster's `cell_hit`), which gives the cell position (`fx`, `fz`) and the distance `t` at once.
//! Rejected: the rasteriser's perspective-correct barycentrics ([`Rasterizer::fragment`]): the
//! same answer up to the 1/256-pixel vertex snap, but they read the 80-byte screen triangle per
//! sample, a cache miss that cost ~12 % of the paper case's render (perf, load ≈ 10). A ray
//! parallel to the plane (or one that meets it behind the eye through rounding) falls back to
//! the barycentrics.
//!
//! **Shading record.** Per grid point one `[f32; 8]`: linear albedo (3), sun visibility, dh/dx,
//! dh/dz (the corner gradients of [`super::TerrainAccel::hit_normal`]), the sky light's
//! ambient-occlusion factor and a pad, so a sample's
//! bilinear interpolation reads two 64-byte runs of the grid instead of four arrays, and the
//! eight lanes interpolate together. Shading is the ray caster's ([`Shader::shade_hit`]) in
//! `f32` (the gradients were `f64`; the normals differ by ~1e-7).
//!
//! **Two halves.** [`raster_geometry`] (mesh, [`Rasterizer::new`], gradients, sun map) reads
//! the heights and the camera only, so a caller can run it while the colours are still being
//! computed ([`super::prepare_view`]); [`render_raster`] adds the albedo and draws.
//!
//! Allocation: the mesh (24 B per grid point, 12 B per triangle), the rasteriser's buffers, the
//! records (32 B per grid point), the sun map (1 B per grid point).

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::accel::TerrainAccel;
use super::scene::Hit;
use super::shade::{Px, Shader};
use crate::control::{Canceled, Control};
use crate::geom::camera::{Camera, RayGen};
use crate::geom::vec::DVec3;
use crate::render::adaptive::{render_adaptive_with, RowSink, Sample};
use crate::render::image::RgbaImage;
use crate::render::raster::{Mesh, Projection, Rasterizer};

/// View parameters of [`raster_geometry`].
pub(super) struct RasterSetup<'c> {
    pub camera: &'c Camera,
    pub out_w: u32,
    pub out_h: u32,
    /// Distances to the nearest and farthest bounding-box points.
    pub near: f64,
    pub far: f64,
    /// Compute the per-grid-point sun map.
    pub sun_map: bool,
}

/// The raster path's colour-independent part: the triangles projected and binned, the corner
/// gradients and the sun map.
pub(super) struct RasterGeometry {
    rast: Rasterizer,
    grads: Vec<[f64; 2]>,
    map: Option<Vec<u8>>,
}

/// The mesh, [`Rasterizer`], gradients and sun map of `accel`'s grid for the view `v`: reads
/// the heights only, never the albedo. The sun map (sweep or shadow rays) runs in parallel with
/// the mesh, gradients and triangle setup.
pub(super) fn raster_geometry(
    accel: &TerrainAccel,
    sun: [f64; 3],
    eps: f64,
    v: &RasterSetup,
    ctl: &dyn Control,
) -> Result<RasterGeometry, Canceled> {
    let (camera, out_w, out_h) = (v.camera, v.out_w, v.out_h);
    let s = accel.scene();
    let (gw, cw, ch) = (s.width, accel.cw, accel.ch);
    let prepare = || {
        // Grid points and two triangles per cell, A = (00, 10, 11) then B = (00, 01, 11) as in
        // the ray caster, so triangle k belongs to cell k / 2. The two lists are built side by
        // side (the triangle loop is serial: its output order is the cell order).
        let positions = || -> Vec<[f64; 3]> {
            (0..s.width * s.height)
                .into_par_iter()
                .map(|k| {
                    let (c, r) = (k % gw, k / gw);
                    [
                        c as f64 * s.dx - accel.half_x,
                        f64::from(s.heights[k]),
                        r as f64 * s.dy - accel.half_z,
                    ]
                })
                .collect()
        };
        let triangles = || {
            let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(2 * cw * ch);
            for j in 0..ch {
                for i in 0..cw {
                    let k = (j * gw + i) as u32;
                    let g = gw as u32;
                    let hs = &s.heights[k as usize..];
                    if (hs[0] + hs[1] + hs[gw] + hs[gw + 1]).is_nan() {
                        // A hole: any nodata corner removes both triangles (as in `cell_hit`);
                        // degenerate triangles keep the index ↔ cell mapping and are skipped.
                        triangles.extend([[k; 3], [k; 3]]);
                    } else {
                        triangles.extend([[k, k + 1, k + g + 1], [k, k + g, k + g + 1]]);
                    }
                }
            }
            triangles
        };
        let (triangles, positions) = rayon::join(triangles, positions);
        // Near plane: half the distance to the bounding box, but not so close that 1/z loses
        // the far range (geometry nearer than it would fill the view anyway).
        let near_plane = (0.5 * v.near).max(1e-6 * v.far).max(1e-9);
        let proj = Projection::new(camera, out_w, out_h, near_plane);
        let rast = Rasterizer::new(
            &Mesh {
                positions: &positions,
                triangles: &triangles,
            },
            &proj,
        );
        (rast, accel.gradients())
    };
    let (map, (rast, grads)) = rayon::join(
        || {
            v.sun_map
                .then(|| accel.sun_visibility(sun, eps, ctl))
                .transpose()
        },
        prepare,
    );
    Ok(RasterGeometry {
        rast,
        grads,
        map: map?,
    })
}

/// Draw `base`'s terrain (whose accel now has the albedo) with the geometry of
/// [`raster_geometry`] for the same heights and view, into `buffer` (see
/// [`render_adaptive_with`]).
pub(super) fn render_raster(
    base: &Shader,
    geo: &RasterGeometry,
    gen: RayGen,
    buffer: Vec<u8>,
    rows: &RowSink,
    ctl: &dyn Control,
    progress_span: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    let accel = base.accel;
    let s = accel.scene();
    let cw = accel.cw;
    let RasterGeometry { rast, grads, map } = geo;
    let proj = rast.projection();
    let out_h = proj.height;
    ctl.checkpoint()?;
    let aw = base.light.ambient_occlusion;
    let records: Vec<[f32; 8]> = grads
        .par_iter()
        .zip(s.albedo.par_iter())
        .enumerate()
        .map(|(k, (g, a))| {
            let sun = map.as_ref().map_or(1.0, |m| f32::from(m[k]));
            // The sky light's occlusion factor (1 without AO).
            let ao = base.ao.map_or(1.0, |ao| {
                1.0 - aw + aw * ao.at(k % s.width, k / s.width, 0.0, 0.0)
            });
            [a[0], a[1], a[2], sun, g[0] as f32, g[1] as f32, ao, 0.0]
        })
        .collect();
    let shader = RasterShader {
        base,
        rast,
        gen,
        records: &records,
        inv_h: 1.0 / f64::from(out_h.max(1)),
        cw: cw.max(1),
        origin: [
            (base.eye[0] + accel.half_x) / s.dx,
            (base.eye[2] + accel.half_z) / s.dy,
        ],
        sun32: base.sun.map(|c| c as f32),
        sky: (0..out_h)
            .map(|r| base.sky(((f64::from(r) + 0.5) * (1.0 / f64::from(out_h.max(1)))) as f32))
            .collect(),
    };
    let bands = rast.bands().max(1);
    let done = AtomicUsize::new(0);
    let report = |y0: usize, data: &[u8]| {
        rows(y0, data);
        let n = done.fetch_add(1, Ordering::Relaxed) + 1;
        let f = n as f32 / bands as f32;
        ctl.progress(
            "render",
            progress_span.0 + (progress_span.1 - progress_span.0) * f.min(1.0),
        );
    };
    let shade = |id: Option<u32>, x: f64, y: f64, row: usize| shader.shade(id, x, y, row);
    // Without holes a sample that hits no triangle is the sky of its image row (`shade`):
    // bands of sky alone are drawn a row at a time.
    render_adaptive_with(
        rast,
        base.light.samples,
        &shade,
        !base.holes,
        buffer,
        ctl,
        &report,
    )
}

/// The raster path's sample shader.
struct RasterShader<'s, 'a> {
    base: &'s Shader<'s, 'a>,
    rast: &'s Rasterizer,
    gen: RayGen,
    /// Per grid point: albedo (3), sun visibility, dh/dx, dh/dz, pads.
    records: &'s [[f32; 8]],
    inv_h: f64,
    cw: usize,
    /// The eye in grid units (column, row).
    origin: [f64; 2],
    sun32: [f32; 3],
    /// The sky colour of each image row.
    sky: Vec<[f32; 3]>,
}

impl RasterShader<'_, '_> {
    #[inline]
    fn shade(&self, id: Option<u32>, x: f64, y: f64, row: usize) -> Px {
        let b = self.base;
        let Some(id) = id else {
            if !b.holes {
                return Px::background(Sample {
                    c: self.sky[row],
                    a: 1.0,
                    t: f32::INFINITY,
                });
            }
            let y_frac = ((row as f64 + 0.5) * self.inv_h) as f32;
            return Px::background(b.miss(self.gen.dir(x, y), y_frac));
        };
        let hit = self.locate(id, x, y);
        Px::hit(self.shade_hit(&hit), &hit)
    }

    /// The cell position and distance of the sample at (`x`, `y`) on screen triangle `id`.
    #[inline]
    fn locate(&self, id: u32, x: f64, y: f64) -> Hit {
        let acc = self.base.accel;
        let s = acc.scene();
        let src = self.rast.source(id) as usize;
        let cell = src / 2;
        let (col, row) = (cell % self.cw, cell / self.cw);
        let k = row * s.width + col;
        let h = |i: usize| f64::from(s.heights[i]);
        let (h00, h10, h01, h11) = (h(k), h(k + 1), h(k + s.width), h(k + s.width + 1));
        // Triangle A (fx ≥ fz): y = h00 + (h10 − h00)·fx + (h11 − h10)·fz; B: y = h00 +
        // (h11 − h01)·fx + (h01 − h00)·fz.
        let (ga, gb) = if src % 2 == 0 {
            (h10 - h00, h11 - h10)
        } else {
            (h11 - h01, h01 - h00)
        };
        let d = self.gen.dir(x, y);
        let (du, dv) = (d[0] / s.dx, d[2] / s.dy);
        let (u0, v0) = (self.origin[0] - col as f64, self.origin[1] - row as f64);
        let t = (h00 + ga * u0 + gb * v0 - self.base.eye[1]) / (d[1] - ga * du - gb * dv);
        if t.is_finite() && t > 0.0 {
            return Hit {
                t,
                col,
                row,
                fx: (u0 + t * du).clamp(0.0, 1.0),
                fz: (v0 + t * dv).clamp(0.0, 1.0),
            };
        }
        // Parallel to the plane: the rasteriser's barycentrics.
        let f = self.rast.fragment(id, x, y);
        let b = f.bary;
        let (fx, fz) = if src % 2 == 0 {
            (b[1] + b[2], b[2])
        } else {
            (b[2], b[1] + b[2])
        };
        let mut hit = Hit {
            t: 0.0,
            col,
            row,
            fx: fx.clamp(0.0, 1.0),
            fz: fz.clamp(0.0, 1.0),
        };
        let p = acc.hit_position(&hit);
        let e = self.base.eye;
        hit.t = (DVec3::from(p) - DVec3::from(e)).length();
        hit
    }

    /// [`Shader::shade_hit`] from the packed records.
    #[inline]
    fn shade_hit(&self, hit: &Hit) -> Sample {
        let b = self.base;
        let l = b.light;
        let w = b.accel.scene().width;
        let k = hit.row * w + hit.col;
        let (fx, fz) = (hit.fx as f32, hit.fz as f32);
        let wt = [
            (1.0 - fx) * (1.0 - fz),
            fx * (1.0 - fz),
            (1.0 - fx) * fz,
            fx * fz,
        ];
        let r = self.records;
        let (p, q, u, v) = (&r[k], &r[k + 1], &r[k + w], &r[k + w + 1]);
        let mut m = [0.0f32; 8];
        for (i, o) in m.iter_mut().enumerate() {
            *o = wt[0] * p[i] + wt[1] * q[i] + wt[2] * u[i] + wt[3] * v[i];
        }
        let albedo = [m[0], m[1], m[2]];
        let mut light = None;
        if l.shading {
            let (gx, gz) = (m[4], m[5]);
            let inv = 1.0 / (gx * gx + 1.0 + gz * gz).sqrt();
            let n = [-gx * inv, inv, -gz * inv];
            let sun = self.sun32;
            let ndl = n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2];
            // The sun visibility lane is 1 without a map (no shadows).
            let direct = if ndl > 0.0 && sun[1] > -1.0 {
                ndl * m[3]
            } else {
                0.0
            };
            let mut amb = l.ambient * (0.5 + 0.5 * n[1]);
            if b.ao.is_some() {
                amb *= m[6];
            }
            light = Some((direct, amb));
        }
        b.finish_sample(albedo, light, hit.t)
    }
}
