//! A z-buffered triangle rasteriser for arbitrary triangle meshes, with the same camera, sample
//! pattern and adaptive anti-aliasing as the height-field ray caster ([`super::terrain`]).
//!
//! **Pipeline.** [`Rasterizer::new`] projects every vertex once through a [`Projection`] (the same
//! pin-hole model as [`Camera::ray_gen`], so pixel (x + 0.5, y + 0.5) of both renderers looks along
//! the same ray), clips triangles that cross the near plane or a 16 384-pixel guard band
//! (Sutherland–Hodgman in camera space, then a fan), snaps the vertices to 1/256 pixel, and bins the
//! screen triangles into bands of [`BAND`] image rows (counting sort in triangle order, so a band's
//! list is in mesh order whatever the thread count). [`Rasterizer::rasterize_band`] then fills a
//! per-band *visibility buffer*: for every pixel and every sample position, the id of the nearest
//! triangle and its depth (1/z, larger is nearer; ties keep the earlier triangle). Attributes are
//! resolved afterwards, only for the samples that get shaded: [`Rasterizer::fragment`] returns the
//! *perspective-correct* barycentric coordinates with respect to the original mesh triangle (exact
//! also for clipped pieces) and the view depth, and [`Fragment::interpolate`] interpolates any
//! per-vertex attribute (normal, albedo, world position…).
//!
//! **Coverage.** Integer edge functions on the snapped vertices (i64, exact) with the top-left fill
//! rule (D3D/OpenGL convention, y down): a sample on an edge shared by two triangles belongs to
//! exactly one of them, so meshes are watertight and nothing is drawn twice. Degenerate (zero-area)
//! triangles and triangles with a non-finite vertex (e.g. a NaN height) are skipped. No back-face
//! culling (terrain is seen from below at grazing angles too).
//!
//! **Anti-aliasing** lives in [`super::adaptive`] ([`super::adaptive::render_adaptive`]):
//! centre samples first, then the pattern samples only at the pixels that need them
//! ([`Rasterizer::rasterize_masked`]).
//!
//! **Visibility buffer.** One `u64` per sample, `1/z` bits over `!id` ([`VisBuffer`]), updated
//! with one `max` per covered sample.
//!
//! **Parallelism and determinism.** Rayon over bands of [`BAND`] rows; a band rasterises its own
//! binned triangles (plus one apron row above and below for the neighbour test) into its own
//! buffers and writes only its own rows, so the bytes do not depend on the thread count.
//! Allocation: the projected vertices (40 B per vertex), screen triangles (80 B each), bins (4 B
//! per binned triangle), and per band the visibility buffers of [`super::adaptive`]; nothing per
//! pixel.
//!
//! **Files.** [`Projection`] (`projection.rs`: the camera model and the clip planes), triangle
//! set-up (`setup.rs`: projection, near-plane and guard-band clipping, snapping, edge functions),
//! the per-band buffers (`visbuf.rs`: [`VisBuffer`], [`RowMask`]) and the rasteriser itself here
//! (binning, coverage, depth, [`Rasterizer::fragment`]).
//!
//! **Cost.** Setup O(vertices + triangles); coverage O(Σ bounding-box pixels × (1 + samples))
//! integer adds, depth by one plane evaluation per covered sample; shading as the caller's. The
//! paper case (400×200 DEM, 159 k screen triangles → 900×600) is measured in
//! [`super::terrain`]'s module doc.
//! Rejected: screen tiles with per-tile triangle lists (bands need no 2-D binning and write
//! contiguous image rows), and f32 edge functions (not watertight).

mod projection;
mod setup;
#[cfg(test)]
mod tests;
mod visbuf;

use rayon::prelude::*;

pub use projection::{Projection, MAX_SIDE};
pub use setup::NO_TRI;
use setup::{edges, plane, setup, snap, snap1, PVert, ScreenTri, SUB};
pub use visbuf::{RowMask, VisBuffer};

/// Image rows per band (the unit of parallel work and binning). 32 rows: 19 bands on a 900×600
/// image (enough to balance 2–4 threads) with a 2-row apron overhead of 6 % (16 rows: 12 %,
/// measured slower on the paper case).
pub const BAND: usize = 32;

/// An indexed triangle mesh in world coordinates. Triangles with an out-of-range index or a
/// non-finite vertex are skipped, and so are triangles past [`MAX_TRIANGLES`] (2^28).
#[derive(Debug, Clone, Copy)]
pub struct Mesh<'a> {
    pub positions: &'a [[f64; 3]],
    pub triangles: &'a [[u32; 3]],
}

/// The visible surface at one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fragment {
    /// Index of the mesh triangle.
    pub triangle: u32,
    /// Perspective-correct barycentric coordinates with respect to the triangle's vertices in
    /// mesh order (sum to 1).
    pub bary: [f64; 3],
    /// View depth (camera-space z, world units).
    pub z: f64,
}

impl Fragment {
    /// Perspective-correct interpolation of a per-vertex attribute (values in the triangle's
    /// vertex order).
    #[inline]
    pub fn interpolate<const N: usize>(&self, v: [[f32; N]; 3]) -> [f32; N] {
        let b = [
            self.bary[0] as f32,
            self.bary[1] as f32,
            self.bary[2] as f32,
        ];
        let mut out = [0.0f32; N];
        for (k, o) in out.iter_mut().enumerate() {
            *o = b[0] * v[0][k] + b[1] * v[1][k] + b[2] * v[2][k];
        }
        out
    }
}

/// Mesh triangles per setup chunk (ids are `chunk << 16 | local`, see [`Rasterizer::new`]).
const CHUNK: usize = 4096;

/// Largest mesh accepted (triangle ids need 16 bits for the chunk); later triangles are ignored.
pub const MAX_TRIANGLES: usize = CHUNK << 16;

/// The screen triangles of one chunk, their clip table and their band bins.
struct Part {
    tris: Vec<ScreenTri>,
    /// `tris[i].src`, packed (shaders that need only the mesh triangle read 4 B, not 80).
    src: Vec<u32>,
    clipped: Vec<[[f64; 3]; 3]>,
    /// Band b's local ids are `ids[start[b]..start[b + 1]]`.
    start: Vec<u32>,
    ids: Vec<u32>,
}

/// A mesh prepared for one view: projected, clipped and binned into bands.
pub struct Rasterizer {
    proj: Projection,
    /// Screen triangles per chunk of [`CHUNK`] mesh triangles.
    parts: Vec<Part>,
    /// Band b's triangles are `bins[bin_start[b]..bin_start[b + 1]]`.
    bin_start: Vec<usize>,
    bins: Vec<u32>,
}

impl Rasterizer {
    /// Project, clip and bin `mesh` for `proj`. Parallel over vertices and chunks of 4096
    /// triangles; allocates 40 B per vertex, 80 B per screen triangle and 4 B per binning.
    pub fn new(mesh: &Mesh, proj: &Projection) -> Self {
        let planes = proj.planes();
        let pv: Vec<PVert> = mesh
            .positions
            .par_iter()
            .map(|&p| {
                let c = proj.to_camera(p);
                if !(c[0].is_finite() && c[1].is_finite() && c[2].is_finite()) {
                    return PVert {
                        c,
                        out: 0xFF,
                        s: [0; 2],
                    };
                }
                let mut out = 0u8;
                for (k, pl) in planes.iter().enumerate() {
                    if plane(pl, c) < 0.0 {
                        out |= 1 << k;
                    }
                }
                let s = if out == 0 {
                    snap(proj.screen(c))
                } else {
                    [0; 2]
                };
                PVert { c, out, s }
            })
            .collect();
        // Per chunk of triangles (in parallel): screen triangles, clip table and a counting sort
        // of its screen triangles by band. Ids are `chunk << 16 | local` (a chunk of 4096
        // triangles makes at most 7 × 4096 < 2^16 pieces), so no concatenation is needed.
        let (w, h) = (proj.width as i64, proj.height as i64);
        let nb = (h as usize).div_ceil(BAND);
        let band_range = |t: &ScreenTri| -> Option<(usize, usize)> {
            let [x0, x1, y0, y1] = t.bb.map(i64::from);
            if x1 < 0 || x0 >= w || y1 < -1 || y0 > h {
                return None;
            }
            let lo = (y0 - 1).clamp(0, h - 1) as usize / BAND;
            let hi = (y1 + 1).clamp(0, h - 1) as usize / BAND;
            Some((lo, hi))
        };
        let n = mesh.triangles.len().min(MAX_TRIANGLES);
        let parts: Vec<Part> = mesh.triangles[..n]
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(ci, chunk)| {
                let mut tris = Vec::with_capacity(chunk.len());
                let mut clipped = Vec::new();
                for (k, t) in chunk.iter().enumerate() {
                    let src = (ci * CHUNK + k) as u32;
                    setup(proj, &planes, &pv, t, src, &mut tris, &mut clipped);
                }
                let mut start = vec![0u32; nb + 1];
                for t in &tris {
                    if let Some((lo, hi)) = band_range(t) {
                        for c in &mut start[lo + 1..=hi + 1] {
                            *c += 1;
                        }
                    }
                }
                for b in 0..nb {
                    start[b + 1] += start[b];
                }
                let mut fill = start.clone();
                let mut ids = vec![0u32; start[nb] as usize];
                let base = (ci as u32) << 16;
                for (i, t) in tris.iter().enumerate() {
                    if let Some((lo, hi)) = band_range(t) {
                        for f in &mut fill[lo..=hi] {
                            ids[*f as usize] = base | i as u32;
                            *f += 1;
                        }
                    }
                }
                Part {
                    src: tris.iter().map(|t| t.src).collect(),
                    tris,
                    clipped,
                    start,
                    ids,
                }
            })
            .collect();
        // Merge the bins band by band in chunk order (mesh order within a band).
        let mut bin_start = vec![0usize; nb + 1];
        let mut bins = Vec::with_capacity(parts.iter().map(|p| p.ids.len()).sum());
        for b in 0..nb {
            for p in &parts {
                bins.extend_from_slice(&p.ids[p.start[b] as usize..p.start[b + 1] as usize]);
            }
            bin_start[b + 1] = bins.len();
        }
        Self {
            proj: *proj,
            parts,
            bin_start,
            bins,
        }
    }

    #[inline]
    fn tri(&self, id: u32) -> &ScreenTri {
        &self.parts[(id >> 16) as usize].tris[(id & 0xFFFF) as usize]
    }

    /// The projection this rasteriser was built for.
    pub fn projection(&self) -> &Projection {
        &self.proj
    }

    /// Number of bands of [`BAND`] rows.
    pub fn bands(&self) -> usize {
        self.bin_start.len() - 1
    }

    /// True when no triangle touches band `band` or its apron rows (every sample of
    /// [`Self::rasterize_band`] and [`Self::rasterize_masked`] there is [`NO_TRI`]).
    pub fn band_is_empty(&self, band: usize) -> bool {
        band + 1 >= self.bin_start.len() || self.bin_start[band] == self.bin_start[band + 1]
    }

    /// Number of screen triangles after clipping (a clipped triangle may become two).
    pub fn screen_triangles(&self) -> usize {
        self.parts.iter().map(|p| p.tris.len()).sum()
    }

    /// Rasterise rows `y0..y1` (within band `band`'s rows ± 1) at the sample `offsets` (pixel
    /// fractions in [0, 1)², snapped to 1/256) into `buf`, reshaped and cleared. No allocation
    /// once `buf` has grown to size.
    pub fn rasterize_band(
        &self,
        band: usize,
        y0: usize,
        y1: usize,
        offsets: &[(f64, f64)],
        buf: &mut VisBuffer,
    ) {
        let w = self.proj.width as usize;
        let rows = y1.saturating_sub(y0);
        buf.shape(y0, rows, w, offsets.len(), false);
        buf.key[..offsets.len() * rows * w].fill(0);
        self.raster_rows::<false>(band, y0, y1, offsets, None, buf);
    }

    /// [`Self::rasterize_band`] for rows `y0..y0 + mask.rows` at the marked pixels of `mask`
    /// only: the samples of unmarked pixels are left undefined (the caller must not read them).
    /// Clears only the marked samples; a triangle row is drawn from its first to its last marked
    /// pixel, and rows without marks are skipped.
    pub fn rasterize_masked(
        &self,
        band: usize,
        y0: usize,
        offsets: &[(f64, f64)],
        mask: &RowMask,
        buf: &mut VisBuffer,
    ) {
        let w = self.proj.width as usize;
        let (rows, ns) = (mask.rows, offsets.len());
        buf.shape(y0, rows, w, ns, true);
        for r in 0..rows {
            for (wi, &word) in mask.row(r).iter().enumerate() {
                let mut m = word;
                while m != 0 {
                    let x = wi * 64 + m.trailing_zeros() as usize;
                    m &= m - 1;
                    let p = (r * w + x) * ns;
                    buf.key[p..p + ns].fill(0);
                }
            }
        }
        self.raster_rows::<true>(band, y0, y0 + rows, offsets, Some(mask), buf);
    }

    /// The coverage loop of [`Self::rasterize_band`] and [`Self::rasterize_masked`] on a
    /// shaped buffer.
    #[inline(never)]
    fn raster_rows<const MASKED: bool>(
        &self,
        band: usize,
        y0: usize,
        y1: usize,
        offsets: &[(f64, f64)],
        mask: Option<&RowMask>,
        buf: &mut VisBuffer,
    ) {
        let w = self.proj.width as usize;
        let rows = y1.saturating_sub(y0);
        let ns = offsets.len().min(65);
        if rows == 0 || w == 0 || band + 1 >= self.bin_start.len() {
            return;
        }
        let offs: [(i64, i64); 65] = {
            let mut o = [(0i64, 0i64); 65];
            for (d, &(ox, oy)) in o.iter_mut().zip(offsets) {
                *d = (snap1(ox), snap1(oy));
            }
            o
        };
        let VisBuffer {
            key,
            delta,
            depth_at,
            ..
        } = buf;
        delta.clear();
        delta.resize(ns, [0; 3]);
        depth_at.clear();
        depth_at.resize(ns, 0.0);
        let list = &self.bins[self.bin_start[band]..self.bin_start[band + 1]];
        let n = list.len();
        // Front to back when the band's list runs back to front (a height field's rows seen
        // from the far side), so the span depth test below rejects hidden triangles. The keys'
        // `max` makes the result independent of the order.
        let nearest = |id: u32| {
            let w = self.tri(id).w;
            w[0].max(w[1]).max(w[2])
        };
        let reverse = n > 1 && nearest(list[n - 1]) > nearest(list[0]);
        for j in 0..n {
            let id = list[if reverse { n - 1 - j } else { j }];
            let t = self.tri(id);
            let bb = t.bb;
            let (x0, x1) = (i64::from(bb[0]).max(0), i64::from(bb[1]).min(w as i64 - 1));
            let (ty0, ty1) = (
                i64::from(bb[2]).max(y0 as i64),
                i64::from(bb[3]).min(y1 as i64 - 1),
            );
            if x0 > x1 || ty0 > ty1 {
                continue;
            }
            // Masked: skip the triangle unless one of its rows has a marked pixel under it.
            if let (true, Some(m)) = (MASKED, mask) {
                let (r0, r1) = (ty0 as usize - y0, ty1 as usize - y0);
                if !m.any(r0, r1, x0 as usize, x1 as usize) {
                    continue;
                }
            }
            let e = edges(t);
            // 1/z as a plane in the fixed-point sample position (X, Y): Σ_k λ_k w_k with
            // λ_k = (E_k + bias_k) / area.
            let inv_area = 1.0 / e.area2 as f64;
            let plane = |k: [i64; 3]| {
                (k[0] as f64 * t.w[0] + k[1] as f64 * t.w[1] + k[2] as f64 * t.w[2]) * inv_area
            };
            let (da, db) = (plane(e.a), plane(e.b));
            let dc = plane([e.c[0] + e.bias[0], e.c[1] + e.bias[1], e.c[2] + e.bias[2]]);
            let step_d = da * 256.0;
            // Nearest 1/z of the triangle, padded far beyond the rounding of `dw`: a span whose
            // samples all hold a nearer surface cannot change.
            let near_bits = ((t.w[0].max(t.w[1]).max(t.w[2]) * (1.0 + 1e-5)) as f32).to_bits();
            let step = [e.a[0] * 256, e.a[1] * 256, e.a[2] * 256];
            for (d, &(ox, oy)) in delta.iter_mut().zip(&offs[..ns]) {
                *d = [
                    e.a[0] * ox + e.b[0] * oy,
                    e.a[1] * ox + e.b[1] * oy,
                    e.a[2] * ox + e.b[2] * oy,
                ];
            }
            let low = u64::from(!id);
            if let (true, Some(m)) = (MASKED, mask) {
                // Marked pixels only, sample by sample: a refined pixel's samples are few and
                // scattered, so spans would mostly walk unmarked pixels.
                for (d, &(ox, oy)) in depth_at.iter_mut().zip(&offs[..ns]) {
                    *d = da * ox as f64 + db * oy as f64 + dc;
                }
                // The largest value edge k takes over a pixel's sample offsets ([0, 255]² in
                // 1/256 pixel) beyond its value at the pixel's corner: a pixel where some edge
                // stays negative even there holds no covered sample, and is skipped whole (a
                // bounding-box pixel of a small triangle often is). Exact: it only skips
                // samples the per-sample test would reject.
                let reach = [0, 1, 2].map(|k| (e.a[k].max(0) + e.b[k].max(0)) * 255);
                for py in ty0..=ty1 {
                    let r = py as usize - y0;
                    let sy = py * 256;
                    let base = [e.b[0] * sy, e.b[1] * sy, e.b[2] * sy];
                    let dy = db * sy as f64;
                    m.for_each(r, x0 as usize, x1 as usize, |x| {
                        let sx = x as i64 * 256;
                        let corner = [
                            e.a[0] * sx + base[0] + e.c[0],
                            e.a[1] * sx + base[1] + e.c[1],
                            e.a[2] * sx + base[2] + e.c[2],
                        ];
                        if ((corner[0] + reach[0])
                            | (corner[1] + reach[1])
                            | (corner[2] + reach[2]))
                            < 0
                        {
                            return;
                        }
                        let dx = da * sx as f64 + dy;
                        let px = &mut key[(r * w + x) * ns..(r * w + x + 1) * ns];
                        for (s, (d, slot)) in delta.iter().zip(px).enumerate() {
                            let ev = [corner[0] + d[0], corner[1] + d[1], corner[2] + d[2]];
                            let z = (dx + depth_at[s]) as f32;
                            if ((ev[0] | ev[1] | ev[2]) >= 0) & (z > 0.0) {
                                *slot = (*slot).max((u64::from(z.to_bits()) << 32) | low);
                            }
                        }
                    });
                }
                continue;
            }
            for py in ty0..=ty1 {
                let r = py as usize - y0;
                let (xa, xb) = (x0, x1);
                let (sx, sy) = (xa * 256, py * 256);
                let base = [
                    e.a[0] * sx + e.b[0] * sy + e.c[0],
                    e.a[1] * sx + e.b[1] * sy + e.c[1],
                    e.a[2] * sx + e.b[2] * sy + e.c[2],
                ];
                for (s, d) in delta.iter().enumerate() {
                    let row = (s * rows + r) * w;
                    let keys = &mut key[row + xa as usize..=row + xb as usize];
                    if keys.iter().all(|&k| ((k >> 32) as u32) > near_bits) {
                        continue;
                    }
                    let mut ev = [base[0] + d[0], base[1] + d[1], base[2] + d[2]];
                    let (ox, oy) = offs[s];
                    let mut dw = da * (sx + ox) as f64 + (db * (sy + oy) as f64 + dc);
                    for slot in keys {
                        // Branch-free: coverage is close to random on small triangles, and a
                        // mispredicted branch per sample cost more than the arithmetic.
                        let z = dw as f32;
                        let inside = ((ev[0] | ev[1] | ev[2]) >= 0) & (z > 0.0);
                        let k = (u64::from(z.to_bits()) << 32) | low;
                        let cand = if inside { k } else { 0 };
                        *slot = (*slot).max(cand);
                        ev[0] += step[0];
                        ev[1] += step[1];
                        ev[2] += step[2];
                        dw += step_d;
                    }
                }
            }
        }
    }

    /// The mesh triangle that screen triangle `id` (from a [`VisBuffer`]) was cut from.
    #[inline]
    pub fn source(&self, id: u32) -> u32 {
        self.parts[(id >> 16) as usize].src[(id & 0xFFFF) as usize]
    }

    /// The fragment of screen triangle `id` (from a [`VisBuffer`]) at image point (`x`, `y`):
    /// perspective-correct barycentrics of the source mesh triangle and view depth.
    pub fn fragment(&self, id: u32, x: f64, y: f64) -> Fragment {
        let t = self.tri(id);
        let p = |k: usize| (f64::from(t.v[k][0]) / SUB, f64::from(t.v[k][1]) / SUB);
        let (p0, p1, p2) = (p(0), p(1), p(2));
        let ed = |a: (f64, f64), b: (f64, f64)| (b.0 - a.0) * (y - a.1) - (b.1 - a.1) * (x - a.0);
        let l = [ed(p1, p2), ed(p2, p0), ed(p0, p1)];
        let q = [l[0] * t.w[0], l[1] * t.w[1], l[2] * t.w[2]];
        let sum = q[0] + q[1] + q[2];
        let area = l[0] + l[1] + l[2];
        let (b, z) = if sum.abs() > 0.0 && area != 0.0 {
            let inv = 1.0 / sum;
            ([q[0] * inv, q[1] * inv, q[2] * inv], area / sum)
        } else {
            ([1.0 / 3.0; 3], 1.0 / t.w[0])
        };
        let mut bary = [0.0; 3];
        if t.clip == NO_TRI {
            for k in 0..3 {
                bary[t.perm[k] as usize] = b[k];
            }
        } else {
            let cb = &self.parts[(id >> 16) as usize].clipped[t.clip as usize];
            for k in 0..3 {
                for (o, v) in bary.iter_mut().zip(cb[k]) {
                    *o += b[k] * v;
                }
            }
        }
        Fragment {
            triangle: t.src,
            bary,
            z,
        }
    }
}
