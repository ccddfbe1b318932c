//! The instances of a mesh scene merged into one mesh with per-triangle shading data: normals,
//! albedo (materials, vertex colours, snow) and texture lookups (see "Materials" in [`super`]).

use super::texture::MipTexture;
use crate::geom::mesh::{Mesh, MeshPart};
use crate::geom::vec::{unit, Vec3};

/// Per-triangle or per-vertex surface colour (albedo, linear RGB 0..1).
#[derive(Debug, Clone, Copy)]
pub enum MeshColors<'a> {
    /// One colour for the whole instance.
    Uniform([f32; 3]),
    /// One colour per vertex (same length as `positions`), interpolated.
    PerVertex(&'a [[f32; 3]]),
    /// The base colour (RGB) of the part each triangle lies in; triangles outside every part are
    /// mid grey.
    PerPart(&'a [MeshPart]),
    /// The mesh's own materials (the instance's arrays are this mesh's or share its vertex and
    /// triangle numbering): per part its base colour, times [`Mesh::colors`] per vertex, times
    /// its texture looked up through [`Mesh::uvs`] ([`super`]'s doc, *Materials*).
    Materials(&'a Mesh),
    /// Snow of this albedo, drawn with the snow material ([`super::snow_irradiance`]): wrapped diffuse
    /// sun and a cool, stronger sky term, so snow reads as snow on a white model too.
    Snow([f32; 3]),
}

/// One triangle mesh of the scene, world space (metres, Y up).
#[derive(Debug, Clone, Copy)]
pub struct MeshInstance<'a> {
    pub positions: &'a [[f32; 3]],
    /// Per-vertex normals (need not be unit); `None` = flat face normals.
    pub normals: Option<&'a [[f32; 3]]>,
    pub triangles: &'a [[u32; 3]],
    pub colors: MeshColors<'a>,
}

/// Per-triangle texture lookups of a scene (empty vectors when nothing is textured).
#[derive(Default)]
pub(super) struct SceneTextures {
    /// Per triangle: index into `maps`, or `u32::MAX`.
    pub(super) id: Vec<u32>,
    /// Per triangle: the corners' texture coordinates.
    pub(super) uv: Vec<[[f32; 2]; 3]>,
    /// Per triangle: texels (of level 0) per metre on the surface, √(texel area / world area).
    pub(super) density: Vec<f32>,
    pub(super) maps: Vec<MipTexture>,
}

/// The instances merged into one mesh, with per-triangle shading data.
pub(super) struct Scene {
    pub(super) positions: Vec<[f64; 3]>,
    pub(super) triangles: Vec<[u32; 3]>,
    /// Per triangle: the three vertex normals (face normal repeated when none), unit or zero.
    pub(super) normals: Vec<[[f32; 3]; 3]>,
    /// Per triangle: the three vertex albedos.
    pub(super) albedo: Vec<[[f32; 3]; 3]>,
    pub(super) tex: SceneTextures,
    /// Per triangle: drawn with the snow material ([`MeshColors::Snow`]).
    pub(super) snow: Vec<bool>,
    pub(super) lo: [f64; 3],
    pub(super) hi: [f64; 3],
}

pub(super) fn merge(instances: &[MeshInstance]) -> Scene {
    let nv: usize = instances.iter().map(|i| i.positions.len()).sum();
    let nt: usize = instances.iter().map(|i| i.triangles.len()).sum();
    let mut s = Scene {
        positions: Vec::with_capacity(nv),
        triangles: Vec::with_capacity(nt),
        normals: Vec::with_capacity(nt),
        albedo: Vec::with_capacity(nt),
        tex: SceneTextures::default(),
        snow: Vec::with_capacity(nt),
        lo: [f64::INFINITY; 3],
        hi: [f64::NEG_INFINITY; 3],
    };
    for inst in instances {
        let base = s.positions.len() as u32;
        let n = inst.positions.len();
        // This instance's textures, if its materials have any it can look up.
        let tex_base = s.tex.maps.len() as u32;
        let textured = match inst.colors {
            MeshColors::Materials(m)
                if m.has_textures() && m.uvs.as_ref().is_some_and(|u| u.len() == n) =>
            {
                s.tex
                    .maps
                    .extend(m.textures.iter().map(|t| MipTexture::new(t)));
                Some(m)
            }
            _ => None,
        };
        for p in inst.positions {
            let p = p.map(f64::from);
            if p.iter().all(|v| v.is_finite()) {
                s.lo = [0, 1, 2].map(|k| s.lo[k].min(p[k]));
                s.hi = [0, 1, 2].map(|k| s.hi[k].max(p[k]));
            }
            s.positions.push(p);
        }
        let mut part = 0usize;
        for (ti, t) in inst.triangles.iter().enumerate() {
            if t.iter().any(|&i| i as usize >= n) {
                continue; // out of range: skipped (the rasteriser would skip it too)
            }
            let [a, b, c] = t.map(|i| inst.positions[i as usize]);
            let face = unit([
                (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1]),
                (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2]),
                (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]),
            ]);
            let normals = match inst.normals {
                Some(ns) if ns.len() == n => t.map(|i| {
                    let v = unit(ns[i as usize]);
                    if v == [0.0; 3] {
                        face
                    } else {
                        v
                    }
                }),
                _ => [face; 3],
            };
            let albedo = match inst.colors {
                MeshColors::Uniform(c) | MeshColors::Snow(c) => [c; 3],
                MeshColors::PerVertex(cs) if cs.len() == n => t.map(|i| cs[i as usize]),
                MeshColors::PerVertex(_) => [[0.5; 3]; 3],
                MeshColors::PerPart(parts) => {
                    // Parts are in triangle order: advance, falling back to a search.
                    let inside = |p: &MeshPart| {
                        (p.first_triangle..p.first_triangle + p.triangle_count).contains(&ti)
                    };
                    if !parts.get(part).is_some_and(inside) {
                        part = parts.iter().position(inside).unwrap_or(usize::MAX);
                    }
                    let c = parts.get(part).map_or([0.5; 3], |p| {
                        [p.base_color[0], p.base_color[1], p.base_color[2]]
                    });
                    [c; 3]
                }
                MeshColors::Materials(m) => {
                    let inside = |p: &MeshPart| {
                        (p.first_triangle..p.first_triangle + p.triangle_count).contains(&ti)
                    };
                    if !m.parts.get(part).is_some_and(inside) {
                        part = m.parts.iter().position(inside).unwrap_or(usize::MAX);
                    }
                    let c = m.parts.get(part).map_or([0.5; 3], |p| {
                        [p.base_color[0], p.base_color[1], p.base_color[2]]
                    });
                    match m.colors.as_ref().filter(|cs| cs.len() == n) {
                        Some(cs) => t.map(|i| {
                            let v = cs[i as usize];
                            [c[0] * v[0], c[1] * v[1], c[2] * v[2]]
                        }),
                        None => [c; 3],
                    }
                }
            };
            if let Some(m) = textured {
                let id = m
                    .parts
                    .get(part)
                    .and_then(|p| p.texture)
                    .filter(|&k| k < m.textures.len());
                if s.tex.id.len() < s.triangles.len() {
                    // First textured triangle: the ones before it have none.
                    s.tex.id.resize(s.triangles.len(), u32::MAX);
                    s.tex.uv.resize(s.triangles.len(), [[0.0; 2]; 3]);
                    s.tex.density.resize(s.triangles.len(), 0.0);
                }
                let uvs = m.uvs.as_deref().unwrap_or(&[]);
                let uv = t.map(|i| uvs.get(i as usize).copied().unwrap_or([0.0; 2]));
                let density = id.map_or(0.0, |k| {
                    let tx = &m.textures[k];
                    let (w, h) = (tx.width as f32, tx.height as f32);
                    let (du, dv) = (
                        [(uv[1][0] - uv[0][0]) * w, (uv[1][1] - uv[0][1]) * h],
                        [(uv[2][0] - uv[0][0]) * w, (uv[2][1] - uv[0][1]) * h],
                    );
                    let texel_area = 0.5 * (du[0] * dv[1] - du[1] * dv[0]).abs();
                    let [p0, p1, p2] = t.map(|i| inst.positions[i as usize]);
                    let world = 0.5
                        * (Vec3::from(p1) - Vec3::from(p0))
                            .cross(Vec3::from(p2) - Vec3::from(p0))
                            .length();
                    if world > 0.0 && texel_area.is_finite() {
                        (texel_area / world).sqrt()
                    } else {
                        0.0
                    }
                });
                s.tex.id.push(id.map_or(u32::MAX, |k| tex_base + k as u32));
                s.tex.uv.push(uv);
                s.tex.density.push(density);
            } else if !s.tex.id.is_empty() {
                s.tex.id.push(u32::MAX);
                s.tex.uv.push([[0.0; 2]; 3]);
                s.tex.density.push(0.0);
            }
            s.triangles.push(t.map(|i| base + i));
            s.normals.push(normals);
            s.albedo.push(albedo);
            s.snow.push(matches!(inst.colors, MeshColors::Snow(_)));
        }
    }
    s
}
