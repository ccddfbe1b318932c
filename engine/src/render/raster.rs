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
//! **Anti-aliasing** lives in [`super::adaptive`] ([`render_adaptive`], re-exported here):
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
//! **Cost.** Setup O(vertices + triangles); coverage O(Σ bounding-box pixels × (1 + samples))
//! integer adds, depth by one plane evaluation per covered sample; shading as the caller's. The
//! paper case (400×200 DEM, 159 k screen triangles → 900×600) is measured in
//! [`super::terrain`]'s module doc.
//! Rejected: screen tiles with per-tile triangle lists (bands need no 2-D binning and write
//! contiguous image rows), and f32 edge functions (not watertight).

use rayon::prelude::*;

pub use super::adaptive::{render_adaptive, sample_pattern, Sample, ShadeFn};
use super::camera::{cross, dot, normalize, sub, Camera};

/// Image rows per band (the unit of parallel work and binning). 32 rows: 19 bands on a 900×600
/// image (enough to balance 2–4 threads) with a 2-row apron overhead of 6 % (16 rows: 12 %,
/// measured slower on the paper case).
pub const BAND: usize = 32;

/// Fixed-point sub-pixel precision: vertices and sample positions snap to 1/256 pixel.
const SUB: f64 = 256.0;
/// Guard band beyond each image edge, pixels. Triangles are clipped to it so fixed-point
/// coordinates stay below 2^24 (i32) and edge-function products below 2^50 (i64).
const GUARD: f64 = 16_384.0;
/// Largest image side accepted by the fixed-point coverage (larger images are clamped).
pub const MAX_SIDE: u32 = 32_768;
/// "No triangle" in a visibility buffer.
pub const NO_TRI: u32 = u32::MAX;

/// The camera's projection for a `width × height` image: the model of [`Camera::ray_gen`]
/// (pixel (0, 0) top-left, y down), plus a near plane at view depth `near` (world units, > 0).
#[derive(Debug, Clone, Copy)]
pub struct Projection {
    pub eye: [f64; 3],
    right: [f64; 3],
    up: [f64; 3],
    forward: [f64; 3],
    /// Screen-x per unit of x/z and screen-y per unit of y/z (in NDC).
    kx: f64,
    ky: f64,
    half_w: f64,
    half_h: f64,
    pub width: u32,
    pub height: u32,
    pub near: f64,
}

impl Projection {
    /// Projection of `camera` onto a `width × height` image (each side clamped to 1..=32 768)
    /// with near plane `near` (clamped to ≥ 1e-9).
    pub fn new(camera: &Camera, width: u32, height: u32, near: f64) -> Self {
        let f = normalize(sub(camera.target, camera.eye));
        let mut r = cross(f, camera.up);
        if dot(r, r) < 1e-18 {
            r = cross(f, [0.0, 0.0, -1.0]);
        }
        let r = normalize(r);
        let u = cross(r, f);
        let tan_half = (camera.fov_deg.clamp(1e-3, 179.0) * 0.5).to_radians().tan();
        let width = width.clamp(1, MAX_SIDE);
        let height = height.clamp(1, MAX_SIDE);
        let (w, h) = (f64::from(width), f64::from(height));
        Self {
            eye: camera.eye,
            right: r,
            up: u,
            forward: f,
            kx: h / (tan_half * w),
            ky: 1.0 / tan_half,
            half_w: 0.5 * w,
            half_h: 0.5 * h,
            width,
            height,
            near: near.max(1e-9),
        }
    }

    /// Camera-space coordinates of world point `p`: x right, y up, z forward (view depth).
    #[inline]
    pub fn to_camera(&self, p: [f64; 3]) -> [f64; 3] {
        let v = sub(p, self.eye);
        [dot(v, self.right), dot(v, self.up), dot(v, self.forward)]
    }

    /// Image position (pixels, y down) of a camera-space point with `c[2] > 0`.
    #[inline]
    pub fn screen(&self, c: [f64; 3]) -> (f64, f64) {
        let iz = 1.0 / c[2];
        (
            (c[0] * iz * self.kx + 1.0) * self.half_w,
            (1.0 - c[1] * iz * self.ky) * self.half_h,
        )
    }

    /// Clip planes `a·x + b·y + c·z + d ≥ 0` in camera space: near, then the guard band.
    fn planes(&self) -> [[f64; 4]; 5] {
        let mx = 1.0 + GUARD / self.half_w;
        let my = 1.0 + GUARD / self.half_h;
        [
            [0.0, 0.0, 1.0, -self.near],
            [-self.kx, 0.0, mx, 0.0],
            [self.kx, 0.0, mx, 0.0],
            [0.0, -self.ky, my, 0.0],
            [0.0, self.ky, my, 0.0],
        ]
    }
}

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

/// A projected, clipped and snapped triangle: vertices in 1/256 pixel, counter-clockwise on
/// screen in the y-down sense (positive edge functions inside).
#[derive(Debug, Clone, Copy)]
struct ScreenTri {
    v: [[i32; 2]; 3],
    /// 1/z per vertex.
    w: [f64; 3],
    src: u32,
    /// Index into `Rasterizer::clipped` (barycentrics of the vertices in the source triangle),
    /// or `NO_TRI` when the vertices are the source's own, in order `perm`.
    clip: u32,
    perm: [u8; 3],
    /// Pixel bounding box (inclusive), x0, x1, y0, y1.
    bb: [i32; 4],
}

/// Per-vertex projection.
#[derive(Debug, Clone, Copy)]
struct PVert {
    c: [f64; 3],
    /// Bit k set when the vertex is outside clip plane k; 0xFF when non-finite.
    out: u8,
    /// Snapped screen position (valid when `out == 0`).
    s: [i32; 2],
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

/// A band's visibility buffer for rows `y0..y0 + rows` of the image, `ns` samples per pixel:
/// [`Rasterizer::rasterize_band`] stores `ns` sample planes of `width × rows` (its span loop
/// walks one plane's row), [`Rasterizer::rasterize_masked`] a pixel's `ns` samples side by side
/// (it visits scattered pixels, all samples of each: one cache line per pixel instead of `ns`,
/// and the shading pass reads them in the same order). Each sample holds one `u64` key,
/// `(1/z as f32 bits) << 32 | !triangle id` (0 = empty): for positive `f32` the bit patterns
/// order like the values, so the nearer triangle is the larger key, and on equal depth the
/// earlier triangle (smaller id, larger `!id`) wins — one compare-and-select per sample instead
/// of two arrays.
#[derive(Debug, Default, Clone)]
pub struct VisBuffer {
    pub y0: usize,
    pub rows: usize,
    pub width: usize,
    pub ns: usize,
    /// Samples of a pixel side by side (`rasterize_masked`) rather than in planes.
    interleaved: bool,
    key: Vec<u64>,
    /// Scratch: per sample offset, the three edge functions' offsets of the current triangle.
    delta: Vec<[i64; 3]>,
    /// Scratch: per sample offset, the current triangle's 1/z plane at the pixel's origin.
    depth_at: Vec<f64>,
}

impl VisBuffer {
    /// Screen-triangle id at sample `s` of pixel (`x`, `y`) (`NO_TRI` = empty); resolve with
    /// [`Rasterizer::fragment`].
    #[inline]
    pub fn at(&self, s: usize, x: usize, y: usize) -> u32 {
        !(self.key[self.index(s, x, y)] as u32)
    }

    /// 1/z at sample `s` of pixel (`x`, `y`) (0 = empty).
    #[inline]
    pub fn depth(&self, s: usize, x: usize, y: usize) -> f32 {
        f32::from_bits((self.key[self.index(s, x, y)] >> 32) as u32)
    }

    #[inline]
    fn index(&self, s: usize, x: usize, y: usize) -> usize {
        if self.interleaved {
            ((y - self.y0) * self.width + x) * self.ns + s
        } else {
            (s * self.rows + (y - self.y0)) * self.width + x
        }
    }

    /// Shape the buffer for `ns` samples per pixel of rows `y0..y0 + rows`, `width` wide, in
    /// planes or `interleaved`; the contents are left as they were (the caller clears what it
    /// reads).
    fn shape(&mut self, y0: usize, rows: usize, width: usize, ns: usize, interleaved: bool) {
        self.interleaved = interleaved;
        self.y0 = y0;
        self.rows = rows;
        self.width = width;
        self.ns = ns;
        let n = ns * rows * width;
        if self.key.len() < n {
            self.key.resize(n, 0);
        }
    }
}

/// One bit per pixel for rows `0..rows` of a band: the pixels whose pattern samples
/// [`Rasterizer::rasterize_masked`] rasterises.
#[derive(Debug, Default, Clone)]
pub struct RowMask {
    rows: usize,
    words: usize,
    bits: Vec<u64>,
}

impl RowMask {
    /// All clear, `rows × width`.
    pub fn reset(&mut self, rows: usize, width: usize) {
        self.rows = rows;
        self.words = width.div_ceil(64);
        self.bits.clear();
        self.bits.resize(rows * self.words, 0);
    }

    #[inline]
    pub fn set(&mut self, r: usize, x: usize) {
        self.bits[r * self.words + x / 64] |= 1 << (x % 64);
    }

    #[inline]
    pub fn get(&self, r: usize, x: usize) -> bool {
        self.bits[r * self.words + x / 64] >> (x % 64) & 1 != 0
    }

    /// Row `r`'s words.
    #[inline]
    fn row(&self, r: usize) -> &[u64] {
        &self.bits[r * self.words..(r + 1) * self.words]
    }

    /// Calls `f(x)` for every marked pixel of row `r` in `x0..=x1`, left to right.
    #[inline]
    fn for_each(&self, r: usize, x0: usize, x1: usize, mut f: impl FnMut(usize)) {
        let row = self.row(r);
        let (w0, w1) = (x0 / 64, x1 / 64);
        for (wi, &word) in row.iter().enumerate().take(w1 + 1).skip(w0) {
            let lo = if wi == w0 { x0 % 64 } else { 0 };
            let hi = if wi == w1 { x1 % 64 } else { 63 };
            let mut m = word & (!0u64 << lo) & (!0u64 >> (63 - hi));
            while m != 0 {
                f(wi * 64 + m.trailing_zeros() as usize);
                m &= m - 1;
            }
        }
    }

    /// True when a pixel of rows `r0..=r1`, columns `x0..=x1` is marked.
    #[inline]
    fn any(&self, r0: usize, r1: usize, x0: usize, x1: usize) -> bool {
        let (w0, w1) = (x0 / 64, x1 / 64);
        (w0..=w1).any(|wi| {
            let lo = if wi == w0 { x0 % 64 } else { 0 };
            let hi = if wi == w1 { x1 % 64 } else { 63 };
            let m = (!0u64 << lo) & (!0u64 >> (63 - hi));
            (r0..=r1).any(|r| self.bits[r * self.words + wi] & m != 0)
        })
    }
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

#[inline]
fn plane(p: &[f64; 4], c: [f64; 3]) -> f64 {
    p[0] * c[0] + p[1] * c[1] + p[2] * c[2] + p[3]
}

#[inline]
fn snap((x, y): (f64, f64)) -> [i32; 2] {
    [(x * SUB).round() as i32, (y * SUB).round() as i32]
}

#[inline]
fn snap1(o: f64) -> i64 {
    ((o * SUB).round() as i64).clamp(0, SUB as i64 - 1)
}

/// Integer edge functions `E_k = a·x + b·y + c` (edge k opposite vertex k), top-left bias
/// folded into `c` (`E ≥ 0` inside), and `bias` to undo it for interpolation.
struct Edges {
    a: [i64; 3],
    b: [i64; 3],
    c: [i64; 3],
    bias: [i64; 3],
    area2: i64,
}

#[inline]
fn edges(t: &ScreenTri) -> Edges {
    let v = |k: usize| (i64::from(t.v[k][0]), i64::from(t.v[k][1]));
    let mut e = Edges {
        a: [0; 3],
        b: [0; 3],
        c: [0; 3],
        bias: [0; 3],
        area2: 0,
    };
    for k in 0..3 {
        let (ax, ay) = v((k + 1) % 3);
        let (bx, by) = v((k + 2) % 3);
        let (dx, dy) = (bx - ax, by - ay);
        // E(p) = dx·(py − ay) − dy·(px − ax)
        e.a[k] = -dy;
        e.b[k] = dx;
        e.c[k] = dy * ax - dx * ay;
        // Top edge (horizontal, pointing right) or left edge (pointing up, y down).
        let top_left = (dy == 0 && dx > 0) || dy < 0;
        if !top_left {
            e.c[k] -= 1;
            e.bias[k] = 1;
        }
    }
    let (x0, y0) = v(0);
    e.area2 = e.a[0] * x0 + e.b[0] * y0 + e.c[0] + e.bias[0];
    e
}

/// A clip-space polygon vertex: camera-space position and barycentrics in the source triangle.
#[derive(Debug, Clone, Copy, Default)]
struct CVert {
    c: [f64; 3],
    b: [f64; 3],
}

/// Project, clip and snap mesh triangle `t` (index `src`), appending 0..=7 screen triangles.
#[allow(clippy::too_many_arguments)]
fn setup(
    proj: &Projection,
    planes: &[[f64; 4]; 5],
    pv: &[PVert],
    t: &[u32; 3],
    src: u32,
    tris: &mut Vec<ScreenTri>,
    clipped: &mut Vec<[[f64; 3]; 3]>,
) {
    let (Some(a), Some(b), Some(c)) = (
        pv.get(t[0] as usize),
        pv.get(t[1] as usize),
        pv.get(t[2] as usize),
    ) else {
        return;
    };
    if (a.out | b.out | c.out) == 0xFF || a.out == 0xFF || b.out == 0xFF || c.out == 0xFF {
        return;
    }
    if a.out & b.out & c.out != 0 {
        return; // all outside one plane
    }
    if a.out | b.out | c.out == 0 {
        push_tri(
            [a.s, b.s, c.s],
            [a.c[2], b.c[2], c.c[2]],
            src,
            None,
            tris,
            clipped,
        );
        return;
    }
    // Sutherland–Hodgman against the planes a vertex violates.
    let mut poly = [CVert::default(); 9];
    let mut tmp = [CVert::default(); 9];
    poly[0] = CVert {
        c: a.c,
        b: [1.0, 0.0, 0.0],
    };
    poly[1] = CVert {
        c: b.c,
        b: [0.0, 1.0, 0.0],
    };
    poly[2] = CVert {
        c: c.c,
        b: [0.0, 0.0, 1.0],
    };
    let mut n = 3;
    let any = a.out | b.out | c.out;
    for (k, pl) in planes.iter().enumerate() {
        if any & (1 << k) == 0 {
            continue;
        }
        let mut m = 0;
        for i in 0..n {
            let (p, q) = (poly[i], poly[(i + 1) % n]);
            let (dp, dq) = (plane(pl, p.c), plane(pl, q.c));
            if dp >= 0.0 {
                tmp[m] = p;
                m += 1;
            }
            if (dp >= 0.0) != (dq >= 0.0) {
                let s = dp / (dp - dq);
                let lerp = |u: [f64; 3], v: [f64; 3]| {
                    [
                        u[0] + (v[0] - u[0]) * s,
                        u[1] + (v[1] - u[1]) * s,
                        u[2] + (v[2] - u[2]) * s,
                    ]
                };
                tmp[m] = CVert {
                    c: lerp(p.c, q.c),
                    b: lerp(p.b, q.b),
                };
                m += 1;
            }
        }
        n = m;
        poly[..n].copy_from_slice(&tmp[..n]);
        if n < 3 {
            return;
        }
    }
    for i in 1..n - 1 {
        let vs = [poly[0], poly[i], poly[i + 1]];
        let s = vs.map(|v| snap(proj.screen(v.c)));
        push_tri(
            s,
            vs.map(|v| v.c[2]),
            src,
            Some(vs.map(|v| v.b)),
            tris,
            clipped,
        );
    }
}

fn push_tri(
    mut s: [[i32; 2]; 3],
    z: [f64; 3],
    src: u32,
    bary: Option<[[f64; 3]; 3]>,
    tris: &mut Vec<ScreenTri>,
    clipped: &mut Vec<[[f64; 3]; 3]>,
) {
    let area = |s: &[[i32; 2]; 3]| {
        let (x0, y0) = (i64::from(s[0][0]), i64::from(s[0][1]));
        (i64::from(s[1][0]) - x0) * (i64::from(s[2][1]) - y0)
            - (i64::from(s[1][1]) - y0) * (i64::from(s[2][0]) - x0)
    };
    let a2 = area(&s);
    if a2 == 0 {
        return;
    }
    let mut perm = [0u8, 1, 2];
    let mut w = [1.0 / z[0], 1.0 / z[1], 1.0 / z[2]];
    let mut bary = bary;
    if a2 < 0 {
        s.swap(1, 2);
        perm.swap(1, 2);
        w.swap(1, 2);
        if let Some(b) = bary.as_mut() {
            b.swap(1, 2);
        }
    }
    let clip = match bary {
        Some(b) => {
            clipped.push(b);
            (clipped.len() - 1) as u32
        }
        None => NO_TRI,
    };
    let bb = [
        s[0][0].min(s[1][0]).min(s[2][0]) >> 8,
        s[0][0].max(s[1][0]).max(s[2][0]) >> 8,
        s[0][1].min(s[1][1]).min(s[2][1]) >> 8,
        s[0][1].max(s[1][1]).max(s[2][1]) >> 8,
    ];
    tris.push(ScreenTri {
        v: s,
        w,
        src,
        clip,
        perm,
        bb,
    });
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// Eye at the origin looking down −Z, 90° fov, 200 × 200: world (x, y, −1) lands on pixel
    /// (100·(x + 1), 100·(1 − y)).
    fn proj() -> Projection {
        let cam = Camera {
            eye: [0.0; 3],
            target: [0.0, 0.0, -1.0],
            up: [0.0, 1.0, 0.0],
            fov_deg: 90.0,
        };
        Projection::new(&cam, 200, 200, 1e-3)
    }

    /// Centre-sample visibility of the whole image: screen-triangle id per pixel.
    fn coverage(pos: &[[f64; 3]], tris: &[[u32; 3]]) -> (Rasterizer, Vec<u32>) {
        let r = Rasterizer::new(
            &Mesh {
                positions: pos,
                triangles: tris,
            },
            &proj(),
        );
        let mut out = Vec::new();
        let mut buf = VisBuffer::default();
        for b in 0..r.bands() {
            let (y0, y1) = (b * BAND, ((b + 1) * BAND).min(200));
            r.rasterize_band(b, y0, y1, &[(0.5, 0.5)], &mut buf);
            for y in y0..y1 {
                out.extend((0..200).map(|x| buf.at(0, x, y)));
            }
        }
        (r, out)
    }

    fn to_world(px: f64, py: f64) -> [f64; 3] {
        [px / 100.0 - 1.0, 1.0 - py / 100.0, -1.0]
    }

    #[test]
    fn covered_pixels_match_area_and_shared_edges_are_watertight() {
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 180.0 + 10.0
        };
        for _ in 0..50 {
            let q: Vec<(f64, f64)> = (0..4).map(|_| (rnd(), rnd())).collect();
            let pos: Vec<[f64; 3]> = q.iter().map(|&(x, y)| to_world(x, y)).collect();
            let area = |a: (f64, f64), b: (f64, f64), c: (f64, f64)| {
                ((b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)).abs() * 0.5
            };
            let per = |a: (f64, f64), b: (f64, f64), c: (f64, f64)| {
                let d = |p: (f64, f64), q: (f64, f64)| {
                    ((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt()
                };
                d(a, b) + d(b, c) + d(c, a)
            };
            // Two triangles sharing the edge 0–2 (a quad that may be non-convex: then they overlap
            // and the check below is only on the area, so keep convex-or-not generic).
            let (_, a) = coverage(&pos, &[[0, 1, 2]]);
            let (_, b) = coverage(&pos, &[[2, 3, 0]]);
            let na = a.iter().filter(|&&t| t != NO_TRI).count() as f64;
            let nb = b.iter().filter(|&&t| t != NO_TRI).count() as f64;
            // Pixel-count error is bounded by about half the perimeter (+ 1 for rounding).
            let (ta, tb) = ((q[0], q[1], q[2]), (q[2], q[3], q[0]));
            assert!((na - area(ta.0, ta.1, ta.2)).abs() <= 0.5 * per(ta.0, ta.1, ta.2) + 1.0);
            assert!((nb - area(tb.0, tb.1, tb.2)).abs() <= 0.5 * per(tb.0, tb.1, tb.2) + 1.0);
            // The two triangles lie on opposite sides of the diagonal when the quad is convex:
            // then no pixel is covered twice and none on the diagonal is lost.
            let s = |p: (f64, f64)| {
                (q[2].0 - q[0].0) * (p.1 - q[0].1) - (q[2].1 - q[0].1) * (p.0 - q[0].0)
            };
            if s(q[1]) * s(q[3]) < 0.0 {
                let both = a
                    .iter()
                    .zip(&b)
                    .filter(|(x, y)| **x != NO_TRI && **y != NO_TRI);
                assert_eq!(both.count(), 0, "a shared-edge pixel drawn twice");
                let (_, ab) = coverage(&pos, &[[0, 1, 2], [2, 3, 0]]);
                let nab = ab.iter().filter(|&&t| t != NO_TRI).count() as f64;
                assert_eq!(nab, na + nb, "a shared-edge pixel lost");
            }
        }
        // An axis-aligned 40 × 30 rectangle on pixel boundaries: exactly 1200 centres.
        let pos: Vec<[f64; 3]> = [(20.0, 50.0), (60.0, 50.0), (60.0, 80.0), (20.0, 80.0)]
            .iter()
            .map(|&(x, y)| to_world(x, y))
            .collect();
        let (_, c) = coverage(&pos, &[[0, 1, 2], [0, 2, 3]]);
        assert_eq!(c.iter().filter(|&&t| t != NO_TRI).count(), 1200);
    }

    #[test]
    fn nearer_triangle_wins_in_either_order() {
        // Two overlapping triangles at z = −2 (far) and z = −1 (near).
        let pos = vec![
            [-1.0, -1.0, -2.0],
            [1.0, -1.0, -2.0],
            [0.0, 1.0, -2.0],
            [-0.25, -0.25, -1.0],
            [0.25, -0.25, -1.0],
            [0.0, 0.25, -1.0],
        ];
        for tris in [[[0, 1, 2], [3, 4, 5]], [[3, 4, 5], [0, 1, 2]]] {
            let (r, c) = coverage(&pos, &tris);
            let id = c[100 * 200 + 100];
            let f = r.fragment(id, 100.5, 100.5);
            assert_eq!(tris[f.triangle as usize], [3, 4, 5]);
            assert!((f.z - 1.0).abs() < 1e-9, "{}", f.z);
            // Outside the near one but inside the far one.
            let id = c[140 * 200 + 100];
            let f = r.fragment(id, 100.5, 140.5);
            assert_eq!(tris[f.triangle as usize], [0, 1, 2]);
            assert!((f.z - 2.0).abs() < 1e-9);
        }
    }

    #[test]
    fn attributes_are_perspective_correct_on_a_tilted_quad() {
        // A quad from z = −1 (bottom) to z = −5 (top), partly behind the near plane's guard: the
        // interpolated world position must be the exact ray/plane intersection.
        let pos = vec![
            [-1.0, -0.5, -1.0],
            [1.0, -0.5, -1.0],
            [1.0, 1.5, -5.0],
            [-1.0, 1.5, -5.0],
        ];
        let tris = [[0u32, 1, 2], [0, 2, 3]];
        let (r, c) = coverage(&pos, &tris);
        let mut checked = 0;
        for py in (0..200).step_by(7) {
            for px in (0..200).step_by(5) {
                let id = c[py * 200 + px];
                if id == NO_TRI {
                    continue;
                }
                let (x, y) = (px as f64 + 0.5, py as f64 + 0.5);
                let f = r.fragment(id, x, y);
                let t = tris[f.triangle as usize].map(|k| {
                    let p = pos[k as usize];
                    [p[0] as f32, p[1] as f32, p[2] as f32]
                });
                let p = f.interpolate(t);
                // Camera ray through (x, y): direction (x/100 − 1, 1 − y/100, −1). Plane of the
                // quad: y = −0.5 + (−1 − z)/2 ⇔ 2y + z + 2 = 0.
                let d = [x / 100.0 - 1.0, 1.0 - y / 100.0, -1.0];
                let s = -2.0 / (2.0 * d[1] + d[2]);
                for k in 0..3 {
                    assert!(
                        (f64::from(p[k]) - s * d[k]).abs() < 1e-4,
                        "{p:?} vs {:?}",
                        d.map(|v| v * s)
                    );
                }
                assert!((f.z - s).abs() < 1e-9);
                checked += 1;
            }
        }
        assert!(checked > 200, "{checked}");
    }

    #[test]
    fn triangles_behind_the_eye_are_clipped() {
        // One vertex behind the camera: the visible part still interpolates correctly.
        let pos = vec![[-1.0, -0.5, -2.0], [1.0, -0.5, -2.0], [0.0, -0.5, 3.0]];
        let (r, c) = coverage(&pos, &[[0, 1, 2]]);
        let n = c.iter().filter(|&&t| t != NO_TRI).count();
        assert!(n > 1000, "{n}");
        let id = c[190 * 200 + 100];
        let f = r.fragment(id, 100.5, 190.5);
        let p = f.interpolate([[-1.0f32, -0.5, -2.0], [1.0, -0.5, -2.0], [0.0, -0.5, 3.0]]);
        // Ray through (100.5, 190.5) meets y = −0.5 at z = −0.5 / (1 − 1.905)·(−1)…
        let d = [0.005, 1.0 - 1.905, -1.0];
        let s = -0.5 / d[1];
        assert!((f64::from(p[2]) - s * d[2]).abs() < 1e-4, "{p:?}");
    }
}
