//! Rendering of triangle scenes with the rasteriser ([`super::raster`]): the snow-cover render
//! (SPEC §2 "Rendering": scene and snow with sun shading, shadows and fog) and the dust render.
//!
//! **Shading**, per sample, linear RGB: `albedo · (sun_color · max(0, n·l) · visibility +
//! ambient · (1 + n_y)/2)`, then exponential fog `c·f + fog_color·(1 − f)`, `f = e^(−density·d)`
//! with `d` the distance from the eye *beyond the scene's near side* (the distance from the eye to
//! the scene's bounding box): the paper renders with fog as a depth cue (SPEC §2 "Rendering"), and
//! fog counted from the eye would wash the whole model toward the fog colour (at the default
//! framing, 1.5–2 diagonals away, 0.6 per diagonal left a third of the model's own colour), while
//! from the near side the front of the model keeps its colours and the back fades. Lighting is two-sided: the normal (interpolated per-vertex
//! normals, else the flat face normal) is flipped toward the eye, because input windings are not
//! reliable (OBJ/STL/PLY exports, open meshes seen from behind). The background is the terrain
//! renderer's sky gradient (zenith colour at the top of the image, horizon colour at the bottom)
//! or a fixed RGBA.
//!
//! **Materials** ([`MeshColors::Materials`]): albedo = part base colour × vertex colour × the
//! part's texture, glTF's rule. Textures are sampled bilinearly (sRGB texels to linear, wrap
//! modes of the sampler) from a mip pyramid built when the renderer is set up (box-filtered
//! halves averaged in linear light, 4/3 of the texture's texels); the level is log2 of the
//! sample's footprint in texels, `view depth × pixel size × texel density / √|cos θ|`, with the
//! triangle's texel density √(texel area / world area) (the same footprint rule as the dust
//! shells). The texture's alpha is not used (surfaces are opaque).
//!
//! **Shadows**: an orthographic depth map along the sun direction covering the scene's extent
//! across the sun (`shadow_map_size`² texels, square texels), filled by a scanline pass that keeps
//! the largest depth toward the sun per texel centre — a max, so the result does not depend on
//! triangle or thread order. Lookups take a 2×2 percentage-closer filter (bilinear weights) with a
//! slope-scaled bias: `texel · (1 + 2·tan θ)` (θ the angle between normal and sun, tan clamped to
//! 8), plus 1e-5 of the scene size. Thin geometry below a texel may leak light; raise
//! `shadow_map_size`. Rejected: ray-cast shadows against the triangles (needs a BVH; the map is
//! one linear pass).
//!
//! **Reuse.** [`MeshRenderer`] holds a scene prepared for one view (merged instances, shadow map,
//! rasteriser). Besides rendering it, it lights other surface points the same way
//! ([`MeshRenderer::irradiance`], [`MeshRenderer::shade_point`]) and lends its projection and
//! rasteriser to extra passes; an [`Overlay`] (premultiplied RGBA per pixel) is composited over
//! every sample of its pixel — how the dust shells (SPEC §4 step 4) are drawn over the mesh.
//! [`render_meshes`] is the one-shot form.
//!
//! **Anti-aliasing and determinism** are [`render_adaptive`]'s: bands of rows, fixed sample
//! pattern, identical bytes for any thread count (the shadow map is a max per texel).
//!
//! **Cost.** Setup allocates 24 B per vertex and 84 B per triangle (combined mesh, per-triangle
//! normals and albedo; 72 B more per triangle while the shadow map is built; 32 B more per
//! triangle and the mip pyramids when textured), the rasteriser's buffers and 4 B per shadow texel (16 MiB at 2048²).
//! Shadow pass: the triangles binned by band of rows, then per row only the texels near the
//! triangle's span (the covered texels plus a few; `shadow.rs`).

use std::sync::atomic::{AtomicUsize, Ordering};

use super::adaptive::{render_adaptive, Sample};
use super::image::RgbaImage;
use super::raster::{Fragment, Mesh as RMesh, Projection, Rasterizer};
use crate::control::{Canceled, Control};
use crate::geom::camera::Camera;
use crate::geom::mesh::Mesh;
use crate::geom::vec::{normalized, sun_direction, unit, DVec3};
use crate::params::MeshView;

mod scene;
mod shadow;
mod texture;

use scene::{merge, Scene};
pub use scene::{MeshColors, MeshInstance};
use shadow::ShadowMap;

/// Wrap of the snow material's diffuse term (light reaches `SNOW_WRAP` past the terminator in
/// `n·l` units: the softness of light scattered under the surface).
pub const SNOW_WRAP: f32 = 0.35;
/// Sky light on snow relative to [`MeshLighting::ambient`], per channel: snow in shadow is lit by
/// the blue sky (cool) and its multiple scattering returns more of it than a matte surface
/// (luminance 1.09).
pub const SNOW_SKY: [f32; 3] = [1.0, 1.1, 1.35];

/// The snow material's irradiance factors for `ndl = n·l` (unit normal `n` toward the eye,
/// `l` toward the sun) and `n_y`: `(direct, sky)` where the lit colour is
/// `albedo · (sun_color · direct · visibility + ambient · sky)`. `direct = max(0, (ndl + w) /
/// (1 + w))` (wrapped diffuse, w = [`SNOW_WRAP`]), `sky = SNOW_SKY · (1 + n_y) / 2`.
#[inline]
pub fn snow_irradiance(ndl: f32, n_y: f32) -> (f32, [f32; 3]) {
    let direct = ((ndl + SNOW_WRAP) / (1.0 + SNOW_WRAP)).max(0.0);
    let up = 0.5 + 0.5 * n_y;
    (direct, SNOW_SKY.map(|k| k * up))
}

/// Light, shadows, fog and background of a mesh render.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshLighting {
    /// Direction *toward* the sun, world frame (normalised here). Default:
    /// [`sun_direction`]`(135, 40)` (south-east, 40° up).
    pub sun_dir: [f64; 3],
    /// Sun irradiance, linear RGB. Default: `[0.9, 0.864, 0.81]`.
    pub sun_color: [f32; 3],
    /// Sky light on an upward-facing surface (scaled by `(1 + n_y)/2`), linear. Default: 0.35.
    pub ambient: f32,
    /// Cast shadows from the sun. Default: true.
    pub shadows: bool,
    /// Shadow map side, texels (clamped 16..=8192). Default: 2048.
    pub shadow_map_size: u32,
    /// Exponential fog density, 1/metre; 0 = off. Default: 0.
    pub fog_density: f32,
    /// Fog colour, linear RGB. Default: `[0.7, 0.75, 0.8]`.
    pub fog_color: [f32; 3],
    /// Sky colour at the top of the image, linear RGB. Default: a mid blue.
    pub sky_top: [f32; 3],
    /// Sky colour at the bottom of the image, linear RGB. Default: a pale blue-grey.
    pub sky_horizon: [f32; 3],
    /// Extra samples on pixels that need anti-aliasing (1 = centre only, max 64). Default: 4.
    pub samples: u32,
    /// A fixed background, linear RGB + alpha (alpha 0 = transparent) instead of the sky.
    /// Default: none (sky).
    pub background: Option<[f32; 4]>,
}

impl MeshLighting {
    /// Sun, shadows and fog of a mesh pipeline's view for rendering `mesh`; `fog` is per scene
    /// diagonal so the same value suits a table and a house.
    pub fn for_view(view: &MeshView, mesh: &Mesh) -> Self {
        let diag = mesh
            .bounds()
            .map(|(lo, hi)| (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt())
            .unwrap_or(1.0)
            .max(1e-3);
        Self {
            sun_dir: sun_direction(view.sun_azimuth_deg, view.sun_elevation_deg),
            shadows: view.shadows,
            fog_density: view.fog / diag,
            ..Self::default()
        }
    }
}

impl Default for MeshLighting {
    fn default() -> Self {
        Self {
            sun_dir: sun_direction(135.0, 40.0),
            sun_color: [0.9, 0.864, 0.81],
            ambient: 0.35,
            shadows: true,
            shadow_map_size: 2048,
            fog_density: 0.0,
            fog_color: [0.7, 0.75, 0.8],
            sky_top: [0.16, 0.32, 0.68],
            sky_horizon: [0.62, 0.72, 0.84],
            samples: 4,
            background: None,
        }
    }
}

/// An orbit camera (see [`Camera::orbit`]) around the centre of `bounds` (min, max) at the
/// smallest distance that keeps its 8 corners inside 92 % of a frame of aspect `width / height`.
pub fn frame_camera(
    bounds: ([f32; 3], [f32; 3]),
    azimuth_deg: f64,
    elevation_deg: f64,
    fov_deg: f64,
    aspect: f64,
) -> Camera {
    Camera::frame_box(
        bounds.0.map(f64::from),
        bounds.1.map(f64::from),
        azimuth_deg,
        elevation_deg,
        fov_deg,
        aspect,
    )
}

/// The distance from `eye` to the box `lo`–`hi` (0 inside it), and the box's diagonal.
fn box_distance(eye: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> (f64, f64) {
    let (mut near2, mut diag2) = (0.0, 0.0);
    for (k, &e) in eye.iter().enumerate() {
        let d = (lo[k] - e).max(e - hi[k]).max(0.0);
        near2 += d * d;
        let e = (hi[k] - lo[k]).max(0.0);
        diag2 += e * e;
    }
    (near2.sqrt(), diag2.sqrt())
}

/// The near-plane distance for viewing the box `lo`–`hi` from `eye`: just inside the box as
/// seen from the eye (0.99 × the distance to it), at least 10⁻⁴ of its diagonal.
pub fn near_plane(eye: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
    let (near, diag) = box_distance(eye, lo, hi);
    if diag.is_finite() {
        (0.99 * near).max(1e-4 * diag).max(1e-6)
    } else {
        1e-3
    }
}

/// Premultiplied linear RGBA per pixel (row-major, `width × height`), composited *over* every
/// sample of its pixel by [`MeshRenderer::render`]: translucent layers drawn on top of the
/// opaque scene, such as the dust shells (SPEC §4 step 4). Values are 1/[`Overlay::SCALE`] units
/// (u16: 8 bytes per pixel instead of 16, and steps far below one sRGB code).
#[derive(Debug, Clone, PartialEq)]
pub struct Overlay {
    pub width: u32,
    pub height: u32,
    pub data: Vec<[u16; 4]>,
}

impl Overlay {
    /// Fixed-point scale: 1.0 = 16384, so lit colours up to 4 fit.
    pub const SCALE: f32 = 16384.0;

    /// A transparent overlay.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![[0; 4]; width as usize * height as usize],
        }
    }

    /// Encodes premultiplied linear RGBA.
    #[inline]
    pub fn pack(c: [f32; 4]) -> [u16; 4] {
        c.map(|v| (v.clamp(0.0, 65535.0 / Self::SCALE) * Self::SCALE + 0.5) as u16)
    }

    /// Decodes premultiplied linear RGBA.
    #[inline]
    pub fn unpack(v: [u16; 4]) -> [f32; 4] {
        v.map(|x| f32::from(x) / Self::SCALE)
    }
}

/// A scene prepared for one view: merged instances, shadow map, projection and rasteriser. Build
/// it once, then [`MeshRenderer::render`] it, shade extra surface points with its lighting
/// ([`MeshRenderer::shade_point`]), or rasterise more geometry with the same projection
/// ([`MeshRenderer::projection`]).
pub struct MeshRenderer<'a> {
    scene: Scene,
    shadow: Option<ShadowMap>,
    light: &'a MeshLighting,
    sun: [f32; 3],
    sun_ok: bool,
    eye: [f64; 3],
    /// Where the fog starts: the distance from the eye to the scene's bounding box (module doc).
    fog_start: f64,
    /// World size of a pixel at unit view depth.
    pixel: f64,
    raster: Rasterizer,
}

impl<'a> MeshRenderer<'a> {
    /// Merges `instances`, builds the shadow map (when `light.shadows`) and rasterises the scene
    /// for `camera` at `width × height`. The near plane is [`near_plane`] of the scene's bounds,
    /// widened to `extra_bounds` when given (geometry drawn later, such as shells above the
    /// surface). Allocates the setup of the module doc.
    pub fn new(
        instances: &[MeshInstance],
        camera: &Camera,
        light: &'a MeshLighting,
        width: u32,
        height: u32,
        extra_bounds: Option<([f64; 3], [f64; 3])>,
        ctl: &dyn Control,
    ) -> Result<Self, Canceled> {
        ctl.checkpoint()?;
        let scene = merge(instances);
        let sun = normalized(DVec3::from(light.sun_dir)).to_array();
        let sun_ok = sun.iter().all(|v| v.is_finite());
        let shadow = if light.shadows && sun_ok && !scene.triangles.is_empty() {
            Some(ShadowMap::build(&scene, sun, light.shadow_map_size, ctl)?)
        } else {
            None
        };
        let (mut lo, mut hi) = (scene.lo, scene.hi);
        if let Some((elo, ehi)) = extra_bounds {
            lo = [0, 1, 2].map(|k| lo[k].min(elo[k]));
            hi = [0, 1, 2].map(|k| hi[k].max(ehi[k]));
        }
        let proj = Projection::new(camera, width, height, near_plane(camera.eye, lo, hi));
        let raster = Rasterizer::new(
            &RMesh {
                positions: &scene.positions,
                triangles: &scene.triangles,
            },
            &proj,
        );
        let fog_start = Some(box_distance(camera.eye, scene.lo, scene.hi).0)
            .filter(|d| d.is_finite())
            .unwrap_or(0.0);
        Ok(Self {
            scene,
            shadow,
            light,
            sun: sun.map(|v| v as f32),
            sun_ok,
            eye: camera.eye,
            fog_start,
            pixel: 2.0 * (camera.fov_deg.clamp(1e-3, 179.0) * 0.5).to_radians().tan()
                / f64::from(height.max(1)),
            raster,
        })
    }

    /// The projection every pass of this view uses.
    pub fn projection(&self) -> &Projection {
        self.raster.projection()
    }

    /// The scene's rasteriser (for depth passes against the opaque scene).
    pub fn rasterizer(&self) -> &Rasterizer {
        &self.raster
    }

    /// The light (linear RGB) a unit albedo at surface point `p` (world) with normal `n` (unit
    /// or zero; flipped toward the eye) reflects: sun with shadows plus sky ambient, before fog.
    #[inline]
    pub fn irradiance(&self, p: [f64; 3], n: [f32; 3]) -> [f32; 3] {
        let to_eye = DVec3::from(self.eye) - DVec3::from(p);
        let mut n = n;
        if DVec3::from(n.map(f64::from)).dot(to_eye) < 0.0 {
            n = n.map(|v| -v);
        }
        self.irradiance_one_sided(p, n)
    }

    /// [`MeshRenderer::irradiance`] with `n` taken as it is (not flipped toward the eye): for
    /// matter lying on the outside of a surface, such as dust, lit on the side it lies on even
    /// where the surface turns away from the eye.
    #[inline]
    pub fn irradiance_one_sided(&self, p: [f64; 3], n: [f32; 3]) -> [f32; 3] {
        let light = self.light;
        let sun = self.sun;
        let ndl = n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2];
        let mut direct = 0.0f32;
        if self.sun_ok && ndl > 0.0 {
            direct = ndl;
            if let Some(m) = &self.shadow {
                direct *= m.visibility(p, f64::from(ndl));
            }
        }
        let amb = light.ambient * (0.5 + 0.5 * n[1]);
        [0, 1, 2].map(|k| light.sun_color[k] * direct + amb)
    }

    /// [`MeshRenderer::irradiance`] for the snow material ([`snow_irradiance`]; `n` flipped
    /// toward the eye). The shadow lookup takes the bias of a grazing sun where the wrap lights a
    /// face turned away from it.
    #[inline]
    fn snow_irradiance_at(&self, p: [f64; 3], n: [f32; 3]) -> [f32; 3] {
        let to_eye = DVec3::from(self.eye) - DVec3::from(p);
        let mut n = n;
        if DVec3::from(n.map(f64::from)).dot(to_eye) < 0.0 {
            n = n.map(|v| -v);
        }
        let sun = self.sun;
        let ndl = n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2];
        let (mut direct, sky) = snow_irradiance(ndl, n[1]);
        if !self.sun_ok {
            direct = 0.0;
        } else if direct > 0.0 {
            if let Some(m) = &self.shadow {
                direct *= m.visibility(p, f64::from(ndl.max(0.05)));
            }
        }
        let light = self.light;
        [0, 1, 2].map(|k| light.sun_color[k] * direct + light.ambient * sky[k])
    }

    /// The share of a colour at `p` that survives the fog (1 without fog; fog counted from the
    /// scene's near side, module doc); the rest is
    /// [`MeshRenderer::fog_color`].
    #[inline]
    pub fn fog_factor(&self, p: [f64; 3]) -> f32 {
        if self.light.fog_density > 0.0 {
            let dist = (DVec3::from(self.eye).distance(DVec3::from(p)) - self.fog_start).max(0.0);
            (-(f64::from(self.light.fog_density)) * dist).exp() as f32
        } else {
            1.0
        }
    }

    /// The fog colour, linear RGB.
    pub fn fog_color(&self) -> [f32; 3] {
        self.light.fog_color
    }

    /// The lit colour (linear RGB) of a surface point `p` (world) with normal `n` (unit or
    /// zero; flipped toward the eye) and `albedo`: sun with shadows, sky ambient and fog as in
    /// the module doc.
    #[inline]
    pub fn shade_point(&self, p: [f64; 3], n: [f32; 3], albedo: [f32; 3]) -> [f32; 3] {
        let e = self.irradiance(p, n);
        self.apply_fog(p, [0, 1, 2].map(|k| albedo[k] * e[k]))
    }

    /// `c` (linear RGB at `p`) seen through the fog.
    #[inline]
    fn apply_fog(&self, p: [f64; 3], mut c: [f32; 3]) -> [f32; 3] {
        if self.light.fog_density > 0.0 {
            let fog = self.fog_factor(p);
            for (v, fc) in c.iter_mut().zip(self.light.fog_color) {
                *v = *v * fog + fc * (1.0 - fog);
            }
        }
        c
    }

    /// Renders the scene into a `width × height` sRGB image (straight alpha) with `overlay`
    /// (same size) composited over each sample. Progress goes to `ctl` under stage `"render"`,
    /// mapped onto `progress_span.0..progress_span.1`.
    pub fn render(
        &self,
        overlay: Option<&Overlay>,
        ctl: &dyn Control,
        progress_span: (f32, f32),
    ) -> Result<RgbaImage, Canceled> {
        let light = self.light;
        let scene = &self.scene;
        let proj = self.raster.projection();
        let (pw, ph) = (proj.width as usize, proj.height as usize);
        let overlay = overlay.filter(|o| o.width as usize == pw && o.height as usize == ph);
        let h = f64::from(proj.height);
        let sky = |y: f64| -> [f32; 3] {
            let s = (1.0 - (y / h) as f32).clamp(0.0, 1.0);
            let s = s * s.sqrt();
            [0, 1, 2].map(|k| light.sky_horizon[k] + (light.sky_top[k] - light.sky_horizon[k]) * s)
        };
        let surface = |f: Option<&Fragment>, y: f64| -> Sample {
            let Some(f) = f else {
                return match light.background {
                    Some(bg) => Sample {
                        c: [bg[0], bg[1], bg[2]],
                        a: bg[3].clamp(0.0, 1.0),
                        t: f32::INFINITY,
                    },
                    None => Sample {
                        c: sky(y),
                        a: 1.0,
                        t: f32::INFINITY,
                    },
                };
            };
            let t = f.triangle as usize;
            let corners = scene.triangles[t].map(|i| scene.positions[i as usize]);
            let p = [0, 1, 2].map(|k| {
                f.bary[0] * corners[0][k] + f.bary[1] * corners[1][k] + f.bary[2] * corners[2][k]
            });
            let n = unit(f.interpolate(scene.normals[t]));
            let mut albedo = f.interpolate(scene.albedo[t]);
            if let Some(map) = scene
                .tex
                .id
                .get(t)
                .and_then(|&k| scene.tex.maps.get(k as usize))
            {
                // Mip level from the sample's footprint (module doc, *Materials*).
                let to_eye = DVec3::from(self.eye) - DVec3::from(p);
                let dist = to_eye.length().max(1e-12);
                let cos = (DVec3::from(n.map(f64::from)).dot(to_eye) / dist)
                    .abs()
                    .max(0.05);
                let rho = f.z * self.pixel * f64::from(scene.tex.density[t]) / cos.sqrt();
                let level = if rho > 1.0 { rho.log2() as f32 } else { 0.0 };
                let c = map.sample(f.interpolate(scene.tex.uv[t]), level);
                albedo = [0, 1, 2].map(|k| albedo[k] * c[k]);
            }
            let c = if scene.snow[t] {
                let e = self.snow_irradiance_at(p, n);
                self.apply_fog(p, [0, 1, 2].map(|k| albedo[k] * e[k]))
            } else {
                self.shade_point(p, n, albedo)
            };
            Sample {
                c,
                a: 1.0,
                t: f.z as f32,
            }
        };
        let shade = |f: Option<&Fragment>, x: f64, y: f64, row: usize| -> Sample {
            let mut s = surface(f, y);
            if let Some(o) = overlay {
                let px = (x.max(0.0) as usize).min(pw - 1);
                let [r, g, b, a] = Overlay::unpack(o.data[row.min(ph - 1) * pw + px]);
                if a > 0.0 {
                    // Premultiplied "over": the sample's colour is straight (coverage s.a).
                    let cover = a + (1.0 - a) * s.a;
                    if cover > 0.0 {
                        let keep = (1.0 - a) * s.a;
                        let inv = 1.0 / cover;
                        s.c = [
                            (r + keep * s.c[0]) * inv,
                            (g + keep * s.c[1]) * inv,
                            (b + keep * s.c[2]) * inv,
                        ];
                        s.a = cover;
                    }
                }
            }
            s
        };
        let bands = self.raster.bands().max(1);
        let done = AtomicUsize::new(0);
        let band_done = || {
            let k = done.fetch_add(1, Ordering::Relaxed) + 1;
            let x = (k as f32 / bands as f32).min(1.0);
            ctl.progress(
                "render",
                progress_span.0 + (progress_span.1 - progress_span.0) * x,
            );
        };
        render_adaptive(&self.raster, light.samples, &shade, ctl, &band_done)
    }
}

/// Render `instances` from `camera` into a `width × height` sRGB image (straight alpha), with
/// the shading, shadows, fog and background of `light` (see the module doc). Progress goes to
/// `ctl` under stage `"render"`, mapped onto `progress_span.0..progress_span.1`. An empty scene renders the
/// background. Triangles with an out-of-range index are skipped.
pub fn render_meshes(
    instances: &[MeshInstance],
    camera: &Camera,
    light: &MeshLighting,
    width: u32,
    height: u32,
    ctl: &dyn Control,
    progress_span: (f32, f32),
) -> Result<RgbaImage, Canceled> {
    MeshRenderer::new(instances, camera, light, width, height, None, ctl)?.render(
        None,
        ctl,
        progress_span,
    )
}
