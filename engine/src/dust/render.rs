//! Rendering the dust (SPEC §4 step 4; paper §2.2 and §3 after Lengyel et al. 2001): the shells
//! drawn as lit, semi-transparent layers over the opaque base mesh, in the dust colour.
//!
//! **Passes**, all with the projection of the base render ([`MeshRenderer`], the shared mesh
//! renderer and rasteriser):
//! 1. *Depth of the base*: the opaque scene's nearest depth (1/z) at every pixel centre.
//! 2. *Shells*, layer `shells` (top) down to 1 (bottom), one layer at a time: the layer's
//!    triangles ([`super::shells::layer`], less those clearly turned away from the eye,
//!    [`facing_triangles`]) at height (i / shells)·`max_thickness`·D are rasterised at pixel
//!    centres; where the layer is in front of the base, its fragment is shaded and composited
//!    *under* the layers above it into an [`Overlay`] (front to back: C += (1 − A)·α·c,
//!    A += (1 − A)·α — the same picture as drawing bottom to top with "over", but a pixel whose
//!    coverage has reached 1 − 1/512 skips the layers below it).
//! 3. *Base render* with the overlay composited over every anti-aliasing sample of its pixel.
//!
//! **Depth order.** The shells lie above their surface along its normal, so for a surface seen
//! from its dusty side, layer order (outer to inner) *is* front-to-back, and fragments behind the
//! base are dropped by its depth — Lengyel et al.'s order. Where shells of two different surfaces
//! overlap on screen (the fuzz on a silhouette over dust further back) they are composited in
//! layer order, not sorted: both are dust of the same colour and the difference is invisible in
//! practice. Rejected: per-pixel fragment lists sorted by depth (memory grows with shells × pixels,
//! ~0.5 GB at 1080p and 32 shells), and keeping every layer's rasteriser alive to sort per band
//! (~12 MB per layer per 100k triangles).
//!
//! **A shell fragment** of layer i at barycentrics b in base triangle t: D, the normal and the base
//! point are interpolated from the base vertices; the texture coordinates come from
//! [`super::mapping`]. Per lookup, the texel is drawn only where noise × D ≥ i / shells (SPEC §4
//! step 2; the noise at the nearest texel), and then contributes the fibre texture of layer i
//! sampled trilinearly at the mip level of the pixel's footprint: texels per pixel =
//! z · (2 tan(fov/2) / height) · (texels per metre) / √|cos θ| (θ between normal and view; the
//! square root is a compromise between the footprint's short and long axes). The albedo is
//! `dust_color` scaled by the fibre's brightness ([`DEPTH_SHADE`]) and by the dust above it
//! ([`SELF_SHADOW`]), lit like the base but on the side the dust lies on
//! ([`MeshRenderer::irradiance_one_sided`]: sun with the shadow map, sky ambient; fog over the
//! finished stack); the texture's coverage is the opacity. The light, fog and mip level are taken once
//! per pixel from its first (topmost) shell fragment ([`PixelCache`]).
//!
//! **Determinism.** Layers in order; within a layer, bands of rows in parallel, each pixel written
//! by one band — the same bytes for any thread count.
//!
//! Cost: per layer O(vertices + triangles) setup (Rasterizer: 40 B per vertex, 84 B per triangle,
//! freed before the next layer) plus coverage at one sample per pixel and the shading of the
//! fragments in front of the base; the base depth pass (4 B per pixel), the overlay (8 B per
//! pixel) and the per-pixel cache (10 B per pixel). Triangles whose corners all have D < i / shells are left out of layer i.

use crate::geom::unit;
use rayon::prelude::*;

use super::mapping::Mapping;
use super::shells::{layer, layer_fraction};
use super::texture::{noise_at, ShellTexture};
use crate::control::{Canceled, Control};
use crate::geom::camera::Camera;
use crate::geom::Mesh;
use crate::render::mesh::{MeshRenderer, Overlay};
use crate::render::raster::{Mesh as RMesh, Rasterizer, VisBuffer, BAND, NO_TRI};

/// Everything the shells are made of.
#[derive(Debug, Clone, Copy)]
pub struct Shells<'a> {
    /// The base mesh.
    pub mesh: &'a Mesh,
    /// Unit vertex normals (the offset direction), one per vertex.
    pub normals: &'a [[f32; 3]],
    /// D per vertex.
    pub amount: &'a [f32],
    /// Height of the top layer where D = 1, metres.
    pub thickness: f32,
    /// ShellLayer count.
    pub shells: u32,
    pub mapping: &'a Mapping,
    /// Texels per metre on the surface (texture side / tile size).
    pub texels_per_metre: f32,
    /// ShellLayer i's texture is `textures[i − 1]`.
    pub textures: &'a [ShellTexture],
    /// The noise field at texture resolution (square, side = `noise_side`).
    pub noise: &'a [f32],
    pub noise_side: usize,
    /// Dust colour, linear RGB.
    pub dust_color: [f32; 3],
}

impl Shells<'_> {
    /// Positions of layer `i`'s vertices (`vertices`: base vertex ids).
    fn layer_positions(&self, vertices: &[u32], i: u32) -> Vec<[f64; 3]> {
        let h = layer_fraction(i, self.shells) * self.thickness;
        vertices
            .iter()
            .map(|&v| {
                let v = v as usize;
                let (p, n, d) = (self.mesh.positions[v], self.normals[v], self.amount[v]);
                [0, 1, 2].map(|k| f64::from(p[k] + h * d * n[k]))
            })
            .collect()
    }

    /// Bounds of the top layer together with the base (for the near plane).
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for ((p, n), d) in self
            .mesh
            .positions
            .iter()
            .zip(self.normals)
            .zip(self.amount)
        {
            let h = self.thickness * d;
            for k in 0..3 {
                let (a, b) = (f64::from(p[k]), f64::from(p[k] + h * n[k]));
                lo[k] = lo[k].min(a.min(b));
                hi[k] = hi[k].max(a.max(b));
            }
        }
        lo[0].is_finite().then_some((lo, hi))
    }
}

/// Renders the shells' overlay for `view` (built for `camera`): passes 1 and 2 of the module doc.
/// Progress under stage `"shells"`, mapped onto `progress_span`.
pub fn shell_overlay(
    view: &MeshRenderer,
    camera: &Camera,
    sh: &Shells,
    ctl: &dyn Control,
    progress_span: (f32, f32),
) -> Result<Overlay, Canceled> {
    let proj = *view.projection();
    let (w, h) = (proj.width as usize, proj.height as usize);
    let mut overlay = Overlay::new(proj.width, proj.height);
    if sh.shells == 0 || sh.textures.is_empty() || w == 0 || h == 0 {
        return Ok(overlay);
    }
    let centre = [(0.5, 0.5)];
    // Pass 1: the base's depth at pixel centres.
    let mut base_depth = vec![0.0f32; w * h];
    base_depth
        .par_chunks_mut(w * BAND)
        .enumerate()
        .for_each_init(VisBuffer::default, |vis, (b, rows)| {
            let (c0, c1) = (b * BAND, (b * BAND + BAND).min(h));
            view.rasterizer().rasterize_band(b, c0, c1, &centre, vis);
            for (k, d) in rows.iter_mut().enumerate() {
                *d = vis.depth(0, k % w, c0 + k / w);
            }
        });
    ctl.checkpoint()?;
    // World size of a pixel at unit depth.
    let pixel = 2.0 * (camera.fov_deg.clamp(1e-3, 179.0) * 0.5).to_radians().tan() / h as f64;
    let eye = camera.eye;
    // Per pixel, from its first (topmost) shell fragment: light, fog and mip level (module doc).
    let mut cache = vec![PixelCache::EMPTY; w * h];
    let mut remap = vec![u32::MAX; sh.mesh.positions.len()];
    let front = facing_triangles(sh, eye);
    let shadow = ShadowTable::new(sh.textures, sh.shells);
    let total = sh.shells as usize;
    for (done, i) in (1..=sh.shells).rev().enumerate() {
        ctl.checkpoint()?;
        ctl.progress(
            "shells",
            progress_span.0
                + (progress_span.1 - progress_span.0) * (done as f32 / total as f32).min(1.0),
        );
        let lay = layer(&front, sh.amount, i, sh.shells, &mut remap);
        let Some(tex) = sh.textures.get(i as usize - 1) else {
            continue;
        };
        if lay.triangles.is_empty() {
            continue;
        }
        let pos = sh.layer_positions(&lay.vertices, i);
        let raster = Rasterizer::new(
            &RMesh {
                positions: &pos,
                triangles: &lay.triangles,
            },
            &proj,
        );
        let thr = layer_fraction(i, sh.shells);
        overlay
            .data
            .par_chunks_mut(w * BAND)
            .zip(cache.par_chunks_mut(w * BAND))
            .enumerate()
            .for_each_init(VisBuffer::default, |vis, (b, (rows, cached))| {
                let (c0, c1) = (b * BAND, (b * BAND + BAND).min(h));
                raster.rasterize_band(b, c0, c1, &centre, vis);
                for (k, (out, pc)) in rows.iter_mut().zip(cached.iter_mut()).enumerate() {
                    let (px, py) = (k % w, c0 + k / w);
                    let id = vis.at(0, px, py);
                    if id == NO_TRI
                        || vis.depth(0, px, py) <= base_depth[c0 * w + k]
                        || out[3] >= OPAQUE
                    {
                        continue;
                    }
                    let (x, y) = (px as f64 + 0.5, py as f64 + 0.5);
                    let f = raster.fragment(id, x, y);
                    let lt = f.triangle as usize;
                    let v = front[lay.source[lt] as usize].map(|v| v as usize);
                    let bc = f.bary.map(|c| c as f32);
                    let d =
                        bc[0] * sh.amount[v[0]] + bc[1] * sh.amount[v[1]] + bc[2] * sh.amount[v[2]];
                    if d < thr {
                        continue; // noise ≤ 1: nothing of this layer here
                    }
                    let n = unit(f.interpolate(v.map(|v| sh.normals[v])));
                    if pc.level == PixelCache::UNSET {
                        let lv = lay.triangles[lt].map(|j| pos[j as usize]);
                        let p = [0, 1, 2].map(|c| {
                            f.bary[0] * lv[0][c] + f.bary[1] * lv[1][c] + f.bary[2] * lv[2][c]
                        });
                        *pc = PixelCache::new(view, p, n, eye, f.z * pixel, sh.texels_per_metre);
                    }
                    let level = pc.level();
                    let q = f.interpolate(v.map(|v| sh.mesh.positions[v]));
                    let lk = sh.mapping.lookups(bc, v, q, n);
                    // Σ weight·(premultiplied grey × self-shadow), Σ weight·alpha.
                    let (mut lum, mut alpha) = (0.0f32, 0.0f32);
                    for j in 0..lk.count {
                        let [s, t] = lk.st[j];
                        let top = noise_at(sh.noise, sh.noise_side, s, t) * d;
                        if top < thr {
                            continue;
                        }
                        let (l, a) = tex.sample(s, t, level);
                        let lit = shadow.lit(i, top);
                        lum += lk.weight[j] * l * lit;
                        alpha += lk.weight[j] * a;
                    }
                    if alpha < 1.0 / 512.0 {
                        continue;
                    }
                    // Albedo: the dust colour scaled by the fibre's brightness (module doc).
                    let grey = (lum / alpha).min(1.0);
                    let shade = 1.0 - DEPTH_SHADE * (1.0 - grey);
                    let e = pc.irradiance();
                    // Under what the layers above have laid (front to back).
                    let [r, g, bl, a0] = Overlay::unpack(*out);
                    let wgt = (1.0 - a0) * alpha;
                    let lit = |c: usize| sh.dust_color[c] * shade * e[c] * wgt;
                    *out = Overlay::pack([lit(0) + r, lit(1) + g, lit(2) + bl, a0 + wgt]);
                }
            });
    }
    // Fog over the whole stack of a pixel (its layers are at one distance).
    let fog_color = view.fog_color();
    overlay
        .data
        .par_iter_mut()
        .zip(cache.par_iter())
        .for_each(|(o, pc)| {
            if pc.level != PixelCache::UNSET && pc.fog != FOG_ONE {
                let f = f32::from(pc.fog) / f32::from(FOG_ONE);
                let [r, g, b, a] = Overlay::unpack(*o);
                let fc = |c: usize| fog_color[c] * (1.0 - f) * a;
                *o = Overlay::pack([r * f + fc(0), g * f + fc(1), b * f + fc(2), a]);
            }
        });
    Ok(overlay)
}

/// How much a fibre's brightness g (0–1, the paper's depth cue within a texture, §2.3.3) darkens
/// the dust colour: albedo = `dust_color` · (1 − DEPTH_SHADE · (1 − g)). Our reading: the
/// brightness is relative (a fibre deeper in the texture is darker than the dust colour, at most
/// by half), so dust keeps the colour the user asked for instead of turning into dark dirt where
/// fibres are dim. (It was 1.0, which contradicted "at most by half" and made the dust of the
/// default view a darker grey than a grey model: dim fibres averaged to ~0.35 of the dust
/// colour; issue 18, "looks like a plain grey model".)
pub const DEPTH_SHADE: f32 = 0.5;

/// Self-shadowing inside the dust: the fibres of the outer shells shadow the inner ones. At a
/// texel where layers i+1..=J are drawn above layer i (J: the top layer there, the largest j with
/// noise × D ≥ j / shells), the light reaching layer i is the share the fibres of those layers
/// let through, T = Π (1 − ᾱ_j) over j = i+1..=J, with ᾱ_j the mean coverage of layer j's
/// texture (a soft shadow: the sky's light comes from many directions, so it sees the layers'
/// mean coverage rather than the fibre straight above); the fibre's brightness is scaled by
/// 1 − SELF_SHADOW × (1 − T). Not in the paper: its shells (§2.2, §3) are textured layers with no
/// lighting between them, and §4 leaves fibre lighting to future work; we add it because without
/// it 32 layers of fibres average into a felt of one brightness where the dust is thick (issue 18:
/// the bench's close-up showed no fibres), while with it the top fibres stand bright on the
/// darker dust below. It was 1 − 0.6 × (noise × D − i / shells), linear in depth: a few % per
/// layer near the top, so thick dust read as felt.
pub const SELF_SHADOW: f32 = 0.8;

/// The light T of [`SELF_SHADOW`] for every layer i and top layer J, as the factor
/// 1 − SELF_SHADOW × (1 − T): (shells + 1)² entries, built once per render.
struct ShadowTable {
    shells: u32,
    /// Factor for layer i under top layer J at `lit[J * (shells + 1) + i]` (i ≤ J).
    lit: Vec<f32>,
}

impl ShadowTable {
    fn new(textures: &[ShellTexture], shells: u32) -> Self {
        let n = shells as usize;
        // Coverage of layer j (1-based) = textures[j − 1]; layers without a texture stop nothing.
        let cover = |j: usize| {
            textures
                .get(j.wrapping_sub(1))
                .map_or(0.0, |t| f64::from(t.mean_alpha()))
        };
        let mut lit = vec![1.0f32; (n + 1) * (n + 1)];
        for top in 1..=n {
            let mut t = 1.0f64;
            for i in (0..=top).rev() {
                lit[top * (n + 1) + i] = (1.0 - f64::from(SELF_SHADOW) * (1.0 - t)) as f32;
                t *= 1.0 - cover(i);
            }
        }
        Self { shells, lit }
    }

    /// The factor for a fibre of layer `i` where noise × D = `top` (≥ i / shells).
    #[inline]
    fn lit(&self, i: u32, top: f32) -> f32 {
        let n = self.shells;
        let mut j = ((top * n as f32) as u32).clamp(i, n);
        while j < n && top >= layer_fraction(j + 1, n) {
            j += 1;
        }
        while j > i && top < layer_fraction(j, n) {
            j -= 1;
        }
        self.lit[j as usize * (n as usize + 1) + i as usize]
    }
}

/// Overlay alpha (fixed-point) beyond which the layers below no longer show: 1 − 1/512.
const OPAQUE: u16 = (Overlay::SCALE * (1.0 - 1.0 / 512.0)) as u16;

/// The base triangles whose shells can be seen from `eye`: not clearly turned away. A triangle is
/// dropped when at every corner the normal points away from the eye by more than [`BACK_COS`]
/// (cos of the angle to the eye direction below −0.3, i.e. > 107°): its shells lie behind its own
/// opaque surface, except within `max_thickness` of a silhouette, where the shells of the
/// triangles just in front of the silhouette draw the fuzz. Saves about half the rasterisation
/// of a closed mesh. Allocates the list.
fn facing_triangles(sh: &Shells, eye: [f64; 3]) -> Vec<[u32; 3]> {
    let away = |v: u32| {
        let (p, n) = (sh.mesh.positions[v as usize], sh.normals[v as usize]);
        let d = [0, 1, 2].map(|k| eye[k] - f64::from(p[k]));
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-30);
        (f64::from(n[0]) * d[0] + f64::from(n[1]) * d[1] + f64::from(n[2]) * d[2]) / l < BACK_COS
    };
    sh.mesh
        .triangles
        .iter()
        .filter(|t| !t.iter().all(|&v| away(v)))
        .copied()
        .collect()
}

/// See [`facing_triangles`].
const BACK_COS: f64 = -0.3;

/// The fog factor 1, fixed-point.
const FOG_ONE: u16 = 65_535;

/// What a pixel's shell fragments share, taken from its first one (topmost layer): the light a
/// unit albedo reflects there (sun with shadow + ambient), the fog factor and the mip level. The
/// layers below it lie within `max_thickness` along the same normal, so their light and
/// footprint differ by less than the quantisation (and a shadow-map texel). Saves the shadow
/// lookup, the fog and the footprint per fragment. 10 bytes per pixel.
#[derive(Debug, Clone, Copy)]
struct PixelCache {
    e: [u16; 3],
    fog: u16,
    /// Mip level × 256; [`PixelCache::UNSET`] before the first fragment.
    level: u16,
}

impl PixelCache {
    const UNSET: u16 = u16::MAX;
    const EMPTY: PixelCache = PixelCache {
        e: [0; 3],
        fog: FOG_ONE,
        level: Self::UNSET,
    };

    /// From the first fragment at world point `p` with unit normal `n`, at view depth times the
    /// pixel size `footprint` (world units per pixel).
    fn new(
        view: &MeshRenderer,
        p: [f64; 3],
        n: [f32; 3],
        eye: [f64; 3],
        footprint: f64,
        texels_per_metre: f32,
    ) -> Self {
        let e = view.irradiance_one_sided(p, n);
        let fog = view.fog_factor(p);
        let to_eye = [eye[0] - p[0], eye[1] - p[1], eye[2] - p[2]];
        let dist = (to_eye[0] * to_eye[0] + to_eye[1] * to_eye[1] + to_eye[2] * to_eye[2])
            .sqrt()
            .max(1e-12);
        let cos = ((f64::from(n[0]) * to_eye[0]
            + f64::from(n[1]) * to_eye[1]
            + f64::from(n[2]) * to_eye[2])
            / dist)
            .abs()
            .max(0.05);
        let rho = footprint * f64::from(texels_per_metre) / cos.sqrt();
        let level = (rho.max(1.0).log2() - 0.5).clamp(0.0, 200.0);
        let pe = Overlay::pack([e[0], e[1], e[2], 0.0]);
        Self {
            e: [pe[0], pe[1], pe[2]],
            fog: (fog.clamp(0.0, 1.0) * f32::from(FOG_ONE) + 0.5) as u16,
            level: (level * 256.0) as u16,
        }
    }

    #[inline]
    fn irradiance(&self) -> [f32; 3] {
        self.e.map(|v| f32::from(v) / Overlay::SCALE)
    }

    #[inline]
    fn level(&self) -> f32 {
        f32::from(self.level) / 256.0
    }
}
