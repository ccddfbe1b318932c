//! The dust's file outputs (SPEC §4 *Outputs*): `fibers.png`, the shell textures as one atlas,
//! and `dusty.glb`, the base mesh plus one shell mesh per layer with its alpha-blended fibre
//! texture — Lengyel et al.'s shells as a real-time engine draws them (the paper's goal).
//!
//! **Atlas.** Shell textures (layer 1 = bottom first) in a grid of ⌈√shells⌉ columns, row-major,
//! each `texture_size`² texels, 8-bit grey + alpha with *straight* grey = the fibre's brightness
//! and alpha = its coverage (the textures of [`super::fibers`]). Unused cells are transparent.
//!
//! **Preview** (`fibers.png`): the atlas drawn to be looked at, not the raw textures (those are
//! in `dusty.glb`, one per shell): a fibre texture is mostly transparent, and 32 of them at full
//! size made a 10 MB image that showed a checkerboard. Each cell is the top-left 128² texels of
//! its shell at full resolution (single fibres stay sharp), fibres in the dust colour shaded by
//! their brightness as the renderer does, their opacity doubled for the eye, over a dark
//! background, opaque; under 1 MB at the defaults (32 shells).
//!
//! **Shell meshes.** ShellLayer i covers the triangles that reach it ([`super::shells::layer`]), its
//! vertices raised along the normal by (i / shells)·`max_thickness`·D, with the base normals and
//! texture coordinates in tiles: the mesh's UVs rescaled, or box-projected UVs
//! ([`super::mapping::box_uvs`], vertices split where the projection plane changes). The
//! material is `dust_color` (base colour factor) × the layer's texture, alpha-blended and
//! double-sided (input windings are not trusted).
//!
//! **Adapted: the bumps.** The renderer draws a texel of layer i where noise × D ≥ i / shells. A
//! core glTF material cannot threshold a product of a texture and a vertex value, so the export
//! splits the rule: the layer's texture carries the fibre alpha where noise ≥ i / shells (the rule
//! at D = 1, baked per texel), and each vertex's `COLOR_0` alpha fades the layer out where D falls
//! below i / shells (clamp(D·shells − i + 1, 0, 1)). Exact where D = 1; elsewhere the dust keeps
//! the right thickness and the bumps are a little coarser. Real-time engines sort transparent
//! nodes by distance; shells share a centre, so draw them in node order (bottom first) for the
//! intended look.
//!
//! Cost: the atlas holds 2 bytes per texel of every shell; the GLB per shell vertex 48 bytes
//! (position, normal, UV, colour) and per triangle 12, plus one PNG per shell (encoded in
//! parallel).

use rayon::prelude::*;
use serde_json::Value;

use super::fibers::FiberTexture;
use super::mapping::{box_uvs, Mapping};
use super::render::Shells;
use super::shells::{layer, layer_fraction};
use crate::formats::mesh_glb::{mesh_glb, scene_nodes, GlbMaterial, GlbNode};
use crate::formats::png_write::encode_gray_alpha8;
use crate::render::image::RgbaImage;

/// The shell textures as one 8-bit grey + alpha atlas (module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct TextureAtlas {
    /// Side of one texture, texels.
    pub side: usize,
    /// Number of textures.
    pub count: usize,
    pub columns: usize,
    pub rows: usize,
    /// Grey, alpha per texel; `columns·side` wide.
    pub data: Vec<u8>,
}

impl TextureAtlas {
    /// An empty (transparent) atlas for `count` textures of `side`² texels. Allocates it.
    pub fn new(side: usize, count: usize) -> Self {
        let columns = ((count as f64).sqrt().ceil() as usize).max(1);
        let rows = count.div_ceil(columns).max(1);
        Self {
            side,
            count,
            columns,
            rows,
            data: vec![0; columns * side * rows * side * 2],
        }
    }

    /// Atlas width, texels.
    pub fn width(&self) -> usize {
        self.columns * self.side
    }

    /// Atlas height, texels.
    pub fn height(&self) -> usize {
        self.rows * self.side
    }

    /// Stores texture `k` (0-based; layer k + 1). `tex` must be `side`² texels.
    pub fn put(&mut self, k: usize, tex: &FiberTexture) {
        let (s, w) = (self.side, self.width());
        let (x0, y0) = ((k % self.columns) * s, (k / self.columns) * s);
        if k >= self.count || tex.alpha.len() != s * s {
            return;
        }
        for y in 0..s {
            let row = &mut self.data[((y0 + y) * w + x0) * 2..((y0 + y) * w + x0 + s) * 2];
            for (x, px) in row.chunks_exact_mut(2).enumerate() {
                let (l, a) = (tex.luminance[y * s + x], tex.alpha[y * s + x]);
                let grey = if a > 0.0 {
                    (l / a).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                px[0] = (grey * 255.0 + 0.5) as u8;
                px[1] = (a.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            }
        }
    }

    /// Texture `k` as grey + alpha bytes, `side`² texels. Allocates.
    pub fn tile(&self, k: usize) -> Vec<u8> {
        let (s, w) = (self.side, self.width());
        let (x0, y0) = ((k % self.columns) * s, (k / self.columns) * s);
        let mut out = Vec::with_capacity(s * s * 2);
        for y in 0..s {
            out.extend_from_slice(&self.data[((y0 + y) * w + x0) * 2..((y0 + y) * w + x0 + s) * 2]);
        }
        out
    }

    /// The atlas itself (grey + alpha, every texel of every shell) as PNG; `dusty.glb` embeds
    /// the same textures per shell.
    pub fn png(&self) -> Vec<u8> {
        encode_gray_alpha8(self.width() as u32, self.height() as u32, &self.data)
    }

    /// `fibers.png`, the atlas as a picture to look at (module doc, *Preview*): per shell, its
    /// top-left `min(side, PREVIEW_CELL)`² texels at full resolution, the fibres in `dust_color`
    /// (sRGB bytes) scaled by their brightness over [`PREVIEW_BACKGROUND`], opaque, cells in the
    /// atlas's grid with [`PREVIEW_GAP`] pixels between them.
    pub fn preview(&self, dust_color: [u8; 3]) -> RgbaImage {
        let cell = self.side.min(PREVIEW_CELL);
        let pitch = cell + PREVIEW_GAP;
        let (w, h) = (
            self.columns * pitch - PREVIEW_GAP,
            self.rows * pitch - PREVIEW_GAP,
        );
        let mut data = vec![0u8; w * h * 4];
        for px in data.chunks_exact_mut(4) {
            px.copy_from_slice(&[
                PREVIEW_GAP_COLOR[0],
                PREVIEW_GAP_COLOR[1],
                PREVIEW_GAP_COLOR[2],
                255,
            ]);
        }
        let aw = self.width();
        let bg = PREVIEW_BACKGROUND.map(f32::from);
        let dust = dust_color.map(f32::from);
        for k in 0..self.columns * self.rows {
            let (x0, y0) = ((k % self.columns) * pitch, (k / self.columns) * pitch);
            let (sx, sy) = (
                (k % self.columns) * self.side,
                (k / self.columns) * self.side,
            );
            for y in 0..cell {
                for x in 0..cell {
                    let (g, a) = if k < self.count {
                        let i = ((sy + y) * aw + sx + x) * 2;
                        (
                            f32::from(self.data[i]) / 255.0,
                            f32::from(self.data[i + 1]) / 255.0,
                        )
                    } else {
                        (0.0, 0.0)
                    };
                    // Contrast for the eye: the fibre's colour as the renderer's albedo rule
                    // (DEPTH_SHADE), its opacity doubled (a single texel is faint by design).
                    let shade = 1.0 - super::render::DEPTH_SHADE * (1.0 - g);
                    let a = (2.0 * a).min(1.0);
                    let o = ((y0 + y) * w + x0 + x) * 4;
                    for c in 0..3 {
                        let v = bg[c] + (dust[c] * shade - bg[c]) * a;
                        data[o + c] = (v + 0.5).clamp(0.0, 255.0) as u8;
                    }
                }
            }
        }
        RgbaImage {
            width: w as u32,
            height: h as u32,
            data,
        }
    }
}

/// Largest side of a shell's cell in the `fibers.png` preview, texels (a full-resolution crop).
pub const PREVIEW_CELL: usize = 128;

/// Pixels between the preview's cells.
pub const PREVIEW_GAP: usize = 4;

/// The preview's background under the fibres, sRGB (a dark slate, so light dust shows).
pub const PREVIEW_BACKGROUND: [u8; 3] = [38, 40, 46];

/// The preview's gaps between cells, sRGB.
pub const PREVIEW_GAP_COLOR: [u8; 3] = [110, 112, 118];

/// One shell's mesh for the GLB.
struct ShellMesh {
    name: String,
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    colors: Vec<[f32; 4]>,
    triangles: Vec<[u32; 3]>,
    /// The layer's texture, grey + alpha bytes (encoded as PNG at the end).
    texels: Vec<u8>,
}

fn shell_mesh(sh: &Shells, atlas: &TextureAtlas, i: u32, remap: &mut [u32]) -> Option<ShellMesh> {
    let mesh = sh.mesh;
    let lay = layer(&mesh.triangles, sh.amount, i, sh.shells, remap);
    if lay.triangles.is_empty() {
        return None;
    }
    // (base vertex of each shell vertex, its UV, the triangles).
    let (verts, uvs, triangles): (Vec<u32>, Vec<[f32; 2]>, Vec<[u32; 3]>) = match sh.mapping {
        Mapping::Uv { uvs } => (
            lay.vertices.clone(),
            lay.vertices.iter().map(|&v| uvs[v as usize]).collect(),
            lay.triangles.clone(),
        ),
        Mapping::Triplanar { origin, tile } => {
            let base: Vec<[f32; 3]> = lay
                .vertices
                .iter()
                .map(|&v| mesh.positions[v as usize])
                .collect();
            let (src, uvs, tris) = box_uvs(&base, &lay.triangles, *origin, *tile);
            (
                src.iter().map(|&j| lay.vertices[j as usize]).collect(),
                uvs,
                tris,
            )
        }
    };
    let h = layer_fraction(i, sh.shells) * sh.thickness;
    let s = sh.shells as f32;
    let positions = verts
        .iter()
        .map(|&v| {
            let v = v as usize;
            let (p, n, d) = (mesh.positions[v], sh.normals[v], sh.amount[v]);
            [0, 1, 2].map(|k| p[k] + h * d * n[k])
        })
        .collect();
    let normals = verts.iter().map(|&v| sh.normals[v as usize]).collect();
    let colors = verts
        .iter()
        .map(|&v| {
            let fade = (sh.amount[v as usize] * s - i as f32 + 1.0).clamp(0.0, 1.0);
            [1.0, 1.0, 1.0, fade]
        })
        .collect();
    // The layer's texture with the bumps at D = 1 baked into its alpha.
    let thr = layer_fraction(i, sh.shells);
    let mut tile = atlas.tile(i as usize - 1);
    if sh.noise.len() == atlas.side * atlas.side {
        for (px, &nz) in tile.chunks_exact_mut(2).zip(sh.noise) {
            if nz < thr {
                px[1] = 0;
            }
        }
    }
    Some(ShellMesh {
        name: format!("dust_shell_{i:03}"),
        positions,
        normals,
        uvs,
        colors,
        triangles,
        texels: tile,
    })
}

/// `dusty.glb`: the base mesh's parts, then the shells bottom to top (module doc). `extras` goes
/// on the root object.
pub fn dusty_glb(sh: &Shells, atlas: &TextureAtlas, extras: Option<Value>) -> Vec<u8> {
    let mut remap = vec![u32::MAX; sh.mesh.positions.len()];
    let mut shells: Vec<ShellMesh> = Vec::new();
    for i in 1..=sh.shells.min(atlas.count as u32) {
        match shell_mesh(sh, atlas, i, &mut remap) {
            Some(m) => shells.push(m),
            None => break,
        }
    }
    let side = atlas.side as u32;
    let pngs: Vec<Vec<u8>> = shells
        .par_iter_mut()
        .map(|m| encode_gray_alpha8(side, side, &std::mem::take(&mut m.texels)))
        .collect();
    let parts = scene_nodes(sh.mesh);
    let mut nodes: Vec<GlbNode> = parts.iter().map(|p| p.node()).collect();
    let c = sh.dust_color;
    nodes.extend(shells.iter().zip(pngs).map(|(m, png)| GlbNode {
        name: &m.name,
        positions: &m.positions,
        normals: Some(&m.normals),
        uvs: Some(&m.uvs),
        colors: Some(&m.colors),
        triangles: &m.triangles,
        custom: &[],
        groups: &[],
        overlays: &[],
        material: GlbMaterial {
            name: m.name.clone(),
            base_color: [c[0], c[1], c[2], 1.0],
            roughness: 1.0,
            alpha_blend: true,
            double_sided: true,
            texture_png: Some(png),
            ..GlbMaterial::default()
        },
    }));
    mesh_glb(&nodes, extras)
}
