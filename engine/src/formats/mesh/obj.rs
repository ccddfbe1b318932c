//! Wavefront OBJ through `tobj` 4 (triangulated, single index per (v, vt, vn) corner).
//!
//! - Each `o`/`g` object (and each `usemtl` switch inside one, which is how `tobj` splits
//!   models) becomes a [`crate::geom::mesh::MeshPart`] named after it.
//! - **Materials.** The `mtllib` files and the textures they name are *sidecars*
//!   ([`super::Sidecars`]): the CLI reads them from beside the OBJ; an HTTP upload is one file and
//!   has none. A part takes its material's `Kd` (read as linear RGB, as exporters write the
//!   material's colour; `d` is its alpha) or, when it resolves, `map_Kd` instead (with Kd's
//!   default 0.8 beside a texture, as many exporters write it, multiplying would darken it) (PNG or JPEG; options such as `-s 1 1 1`
//!   before the file name are skipped, scale/offset not applied). A missing or unreadable library,
//!   material or texture is never an error: the part keeps grey or its `Kd`, and
//!   [`crate::geom::Mesh::notes`] says what was missing. Texture coordinates are flipped to glTF's
//!   convention (v = 1 − v). `v x y z r g b` vertex colours (0–1, sRGB) are kept, as linear.
//! - `v`, `vt`, `vn`, negative (relative) indices, polygons (fanned by `tobj`). Points and lines
//!   are dropped. Normals/UVs are kept when every part has them for every corner.
//! - A counting pass runs before `tobj`: it counts `v` lines and the fanned triangles of the `f`
//!   lines against the limits, and checks every face index against the number of `v`/`vt`/`vn`
//!   (relative indices against those seen so far, as `tobj` resolves them), because `tobj`
//!   indexes its arrays unchecked and would panic on an index out of range.
//! - **The common subset in parallel** (issue 19): a file of only `v x y z`, `vt`, `vn`, `f` (3+
//!   corners), `o`/`g` and ignored statements is read by [`super::obj_fast`] on all threads into
//!   the very models `tobj` returns; anything else (`mtllib`, `usemtl`, `l`, vertex colours, a
//!   non-ASCII byte, anything the checking pass or `tobj` would refuse) takes the `tobj` path
//!   below, so its errors and limits are unchanged.
//! - The default up axis is Y.

use std::io::BufReader;

use std::collections::HashMap;
use std::sync::Arc;

use super::obj_fast;
use super::texture::{decode_image, store_side, ImageError};
use super::{
    check_counts, normalize_ref, srgb_to_linear, Builder, MeshOptions, PartData, Sidecars, GREY,
};
use crate::error::InputError;
use crate::geom::mesh::{Mesh, Texture, TextureWrap};

const FORMAT: &str = "OBJ";

fn corrupt(detail: impl Into<String>) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: detail.into(),
    }
}

/// Text whose first statements look like OBJ.
pub(super) fn looks_like_obj(head: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(head) else {
        // The head may end inside a multi-byte character; judge what decodes.
        return std::str::from_utf8(&head[..head.len().saturating_sub(4)])
            .is_ok_and(looks_like_obj_text);
    };
    looks_like_obj_text(text)
}

fn looks_like_obj_text(text: &str) -> bool {
    let mut seen = 0;
    for line in text.lines().take(200) {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let key = line.split_whitespace().next().unwrap_or("");
        match key {
            "v" | "vt" | "vn" | "vp" | "f" | "o" | "g" | "s" | "l" | "p" | "mtllib" | "usemtl" => {
                seen += 1;
                if seen >= 3 {
                    return true;
                }
            }
            _ => return false,
        }
    }
    seen > 0
}

/// Counts from the checking pass.
struct Counts {
    vertices: u64,
    triangles: u64,
}

/// Count vertices and fanned triangles and check every face index (see the module doc).
fn check_pass(bytes: &[u8], opts: &MeshOptions) -> Result<Counts, InputError> {
    let text = std::str::from_utf8(bytes).map_err(|e| corrupt(format!("not UTF-8 text: {e}")))?;
    let (mut nv, mut nvt, mut nvn) = (0u64, 0u64, 0u64);
    let mut triangles = 0u64;
    // Positive indices may point forward; check them against the totals at the end.
    let mut max_pos = [0u64; 3];
    let mut max_pos_line = [0usize; 3];
    for (ln, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                nv += 1;
                if nv > opts.max_vertices {
                    check_counts(nv, 0, opts)?;
                }
            }
            Some("vt") => nvt += 1,
            Some("vn") => nvn += 1,
            Some("f") => {
                let mut corners = 0u64;
                for corner in it {
                    corners += 1;
                    for (k, s) in corner.split('/').enumerate() {
                        if s.is_empty() {
                            continue;
                        }
                        let have = [nv, nvt, nvn];
                        if k > 2 {
                            return Err(corrupt(format!(
                                "line {}: face corner '{corner}' has more than 3 indices",
                                ln + 1
                            )));
                        }
                        let x: i64 = s.parse().map_err(|_| {
                            corrupt(format!("line {}: bad face index '{s}'", ln + 1))
                        })?;
                        if x == 0 || (x < 0 && x.unsigned_abs() > have[k]) {
                            return Err(corrupt(format!(
                                "line {}: face index {x} is out of range ({} {} defined so far)",
                                ln + 1,
                                have[k],
                                ["vertices", "texture coordinates", "normals"][k]
                            )));
                        }
                        if x > 0 && x as u64 > max_pos[k] {
                            max_pos[k] = x as u64;
                            max_pos_line[k] = ln + 1;
                        }
                    }
                }
                triangles += corners.saturating_sub(2);
                if triangles > opts.max_triangles {
                    check_counts(0, triangles, opts)?;
                }
            }
            _ => {}
        }
    }
    for (k, total) in [nv, nvt, nvn].into_iter().enumerate() {
        if max_pos[k] > total {
            return Err(corrupt(format!(
                "line {}: face index {} is out of range (the file has {total} {})",
                max_pos_line[k],
                max_pos[k],
                ["vertices", "texture coordinates", "normals"][k]
            )));
        }
    }
    Ok(Counts {
        vertices: nv,
        triangles,
    })
}

/// The `mtllib` references of an OBJ (the rest of each line, as `tobj` reads it).
pub(super) fn material_libraries(bytes: &[u8]) -> Vec<String> {
    let text = String::from_utf8_lossy(bytes);
    text.lines()
        .filter_map(|l| l.trim_start().strip_prefix("mtllib"))
        .filter(|r| r.starts_with([' ', '\t']))
        .map(|r| r.trim().to_string())
        .filter(|r| !r.is_empty())
        .collect()
}

/// The file name of a `map_Kd` value: options (`-s u v w`, `-o …`, `-bm x`, …) skipped, so the
/// last word when options are present, else the whole value (names may hold spaces).
fn map_file(value: &str) -> String {
    let v = value.trim();
    if v.starts_with('-') {
        v.split_whitespace().last().unwrap_or("").to_string()
    } else {
        v.to_string()
    }
}

/// The `map_Kd` files an MTL names.
pub(super) fn mtl_textures(bytes: &[u8]) -> Vec<String> {
    let text = String::from_utf8_lossy(bytes);
    text.lines()
        .filter_map(|l| l.trim_start().strip_prefix("map_Kd"))
        .map(map_file)
        .filter(|r| !r.is_empty())
        .collect()
}

/// The models and materials of `bytes` through the checking pass and `tobj`; notes about
/// missing libraries go to `builder`.
fn tobj_models(
    bytes: &[u8],
    opts: &MeshOptions,
    sidecars: Sidecars<'_>,
    builder: &mut Builder,
) -> Result<(Vec<tobj::Model>, Vec<tobj::Material>), InputError> {
    let counts = check_pass(bytes, opts)?;
    check_counts(counts.vertices, counts.triangles, opts)?;
    if counts.triangles == 0 {
        return Err(InputError::Unusable(
            "the OBJ file has no faces (f lines)".to_string(),
        ));
    }
    let load = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let mut reader = BufReader::new(bytes);
    for lib in material_libraries(bytes) {
        match sidecars.get(&lib) {
            None => builder.note(format!(
                "material library '{lib}' was not given (an upload is one file: send a GLB to \
                 keep materials; the CLI reads it from beside the OBJ); parts are grey"
            )),
            Some(b) if tobj::load_mtl_buf(&mut BufReader::new(b)).is_err() => {
                builder.note(format!(
                    "material library '{lib}' could not be read; parts are grey"
                ));
            }
            Some(_) => {}
        }
    }
    // Libraries come from the sidecars; a missing one loads nothing (noted above).
    let (models, materials) = tobj::load_obj_buf(&mut reader, &load, |path| {
        let name = path.to_string_lossy();
        match sidecars.get(&name) {
            Some(b) => tobj::load_mtl_buf(&mut BufReader::new(b)),
            None => Err(tobj::LoadError::OpenFileFailed),
        }
    })
    .map_err(|e| corrupt(e.to_string()))?;
    Ok((models, materials.unwrap_or_default()))
}

pub(super) fn decode(
    bytes: &[u8],
    opts: &MeshOptions,
    sidecars: Sidecars<'_>,
) -> Result<Mesh, InputError> {
    decode_with(bytes, opts, sidecars, true)
}

/// [`decode`]; `fast` tries the parallel reader of the common subset first ([`super::obj_fast`]:
/// the same models, or `None` and the `tobj` path below).
pub(super) fn decode_with(
    bytes: &[u8],
    opts: &MeshOptions,
    sidecars: Sidecars<'_>,
    fast: bool,
) -> Result<Mesh, InputError> {
    let mut builder = Builder::new();
    let (models, materials) = match fast.then(|| obj_fast::models(bytes, opts)).flatten() {
        // No `mtllib` in the subset: no materials, no notes.
        Some(models) => (models, Vec::new()),
        None => tobj_models(bytes, opts, sidecars, &mut builder)?,
    };
    // The textures the used materials name, decoded once each.
    let mut used: Vec<String> = Vec::new();
    for model in &models {
        if let Some(t) = model
            .mesh
            .material_id
            .and_then(|m| materials.get(m))
            .and_then(|m| m.diffuse_texture.as_deref())
        {
            let t = normalize_ref(&map_file(t));
            if !used.contains(&t) {
                used.push(t);
            }
        }
    }
    let side = store_side(used.len());
    let mut textures: Vec<Arc<Texture>> = Vec::new();
    let mut texture_of: HashMap<String, usize> = HashMap::new();
    for name in used {
        let Some(b) = sidecars.get(&name) else {
            builder.note(format!(
                "texture '{name}' was not given; its parts keep their Kd colour"
            ));
            continue;
        };
        match decode_image(
            Arc::from(b),
            &name,
            [TextureWrap::Repeat; 2],
            opts.max_texture_pixels,
            side,
        ) {
            Ok(t) => {
                texture_of.insert(name, textures.len());
                textures.push(Arc::new(t));
            }
            Err(ImageError::TooLarge(e)) => return Err(e),
            Err(e) => builder.note(format!("{e}; its parts keep their Kd colour")),
        }
    }

    for (i, model) in models.into_iter().enumerate() {
        let m = model.mesh;
        let n = m.positions.len() / 3;
        let positions: Vec<[f32; 3]> = m
            .positions
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let normals = (m.normals.len() == 3 * n).then(|| {
            m.normals
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect()
        });
        let uvs = (m.texcoords.len() == 2 * n).then(|| {
            m.texcoords
                .chunks_exact(2)
                .map(|c| [c[0], 1.0 - c[1]])
                .collect()
        });
        let colors = (m.vertex_color.len() == 3 * n).then(|| {
            m.vertex_color
                .chunks_exact(3)
                .map(|c| {
                    [
                        srgb_to_linear(c[0]),
                        srgb_to_linear(c[1]),
                        srgb_to_linear(c[2]),
                        1.0,
                    ]
                })
                .collect()
        });
        let material = m.material_id.and_then(|i| materials.get(i));
        let base_color = material.map_or(GREY, |mat| {
            let kd = mat.diffuse.unwrap_or([0.8; 3]);
            let alpha = mat.dissolve.unwrap_or(1.0);
            [kd[0], kd[1], kd[2], alpha].map(|v| {
                if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    1.0
                }
            })
        });
        let texture = material
            .and_then(|mat| mat.diffuse_texture.as_deref())
            .and_then(|t| texture_of.get(&normalize_ref(&map_file(t))).copied());
        // A resolved `map_Kd` replaces `Kd` (as Blender's importer reads it; exporters often
        // write a default Kd of 0.8 beside a texture).
        let base_color = if texture.is_some() {
            [1.0, 1.0, 1.0, base_color[3]]
        } else {
            base_color
        };
        let triangles = m
            .indices
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let name = if model.name.is_empty() || model.name == "unnamed_object" {
            format!("part{i}")
        } else {
            model.name
        };
        builder.push_part(
            PartData {
                name,
                base_color,
                texture,
                positions,
                normals,
                uvs,
                colors,
                triangles,
            },
            FORMAT,
        )?;
        // Corners split by (v, vt, vn) can outnumber the `v` lines; cap as we go.
        check_counts(builder.vertex_count() as u64, 0, opts)?;
    }
    Ok(builder.build_with(textures))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parallel reader and the `tobj` path give the same result (mesh or error), bit for bit.
    fn same(text: &str, opts: &MeshOptions) -> bool {
        let fast = decode_with(text.as_bytes(), opts, Sidecars(&[]), true);
        let slow = decode_with(text.as_bytes(), opts, Sidecars(&[]), false);
        assert_eq!(format!("{fast:?}"), format!("{slow:?}"), "{text}");
        obj_fast::models(text.as_bytes(), opts).is_some()
    }

    #[test]
    fn fast_reader_matches_tobj() {
        let opts = MeshOptions::default();
        let cases = [
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\nf -1 -2 -3\n",
            "o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\no b\nf 3 2 1\ng\nf 1 3 2\no  end \n",
            "  o spaced\r\nv 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0 9\nvt 0 1\nvn 0 0 1\n\
             f 1/1/1 2/2/1 3/3/1\nf 1//1 2//1 3//1\nf 1/1 2/2 3/3\nf 1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 2 2\nv 3 3 3\nf 1 2 3 4 5\n# f 1 2\ns off\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 4\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\nf 1 2 3\n",
            "v 0 0 0 1\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n",
            "v 0 0 x\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\nvt 0 0\n",
            "f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n",
            "o a\nf 1 2 3\no b\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/2/3/ 2 3\nf 1/1/1/1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf +1 +2 +3\nf 01 2 3 \nf 1 2 99999999999999999999\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nusemtl x\nf 1 2 3\n",
            "mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\no é\nf 1 2 3\n",
            "v 0 0 0\x0bv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            "v 0 0 0\nv 1 0 0\nv inf 1 0\nf 1 2 3\n",
            "# nothing\n",
            "",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\no tail\n",
        ];
        let used = cases.iter().filter(|c| same(c, &opts)).count();
        assert!(used >= 8, "{used}");
        // Limits.
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 3 4\nf 1 2 3 4\n";
        for (v, t) in [(3, 100), (4, 3), (4, 4), (100, 100)] {
            let opts = MeshOptions {
                max_vertices: v,
                max_triangles: t,
                ..MeshOptions::default()
            };
            same(text, &opts);
        }
    }

    /// Random OBJ-like text, in several chunks (over 1 MiB), mixing the subset with what it sends
    /// to `tobj`.
    #[test]
    fn fast_reader_matches_tobj_on_random_text() {
        let mut s = 0x9e37_79b9_7f4a_7c15_u64;
        let mut rnd = move |n: u64| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s % n
        };
        let mut used = 0;
        for round in 0..24 {
            let mut text = String::new();
            let (mut nv, mut nt, mut nn) = (0i64, 0i64, 0i64);
            let big = round % 4 == 0;
            let lines = if big { 60_000 } else { 40 };
            let rare = if round % 3 == 0 { 1000 } else { 1_000_000 };
            for _ in 0..lines {
                let r = rnd(100);
                if r < 35 {
                    text += &format!("v {} {}.5 -{}e-1\n", rnd(9), rnd(7), rnd(5));
                    nv += 1;
                } else if r < 42 && round % 2 == 1 {
                    text += &format!("vt 0.{} {}\n", rnd(9), rnd(3));
                    nt += 1;
                } else if r < 48 && round % 2 == 1 {
                    text += "vn 0 1 0\n";
                    nn += 1;
                } else if r < 95 && nv > 0 {
                    let corners = 3 + rnd(3) * rnd(2);
                    text += "f";
                    for _ in 0..corners {
                        let v = if rnd(4) == 0 {
                            -(1 + rnd(nv as u64) as i64)
                        } else {
                            1 + rnd(nv as u64) as i64
                        };
                        text += &format!(" {v}");
                        if nt > 0 && rnd(3) != 0 {
                            text += &format!("/{}", 1 + rnd(nt as u64));
                        } else if nn > 0 {
                            text += "/";
                        }
                        if nn > 0 && rnd(3) != 0 {
                            text += &format!("/{}", -(1 + rnd(nn as u64) as i64));
                        }
                    }
                    text += "\n";
                } else if r < 97 {
                    text += ["o a\n", "g b c\n", "g\n", "s 1\n"][rnd(4) as usize];
                } else if rnd(rare) == 0 {
                    text += ["l 1 2\n", "f 1 2\n", "v 1 2\n", "f 1 2 0\n"][rnd(4) as usize];
                } else {
                    text += "# c\n";
                }
            }
            used += usize::from(same(&text, &MeshOptions::default()));
        }
        assert!(used >= 10, "{used}");
    }
}
