//! Wavefront OBJ through `tobj` 4 (triangulated, single index per (v, vt, vn) corner).
//!
//! - Each `o`/`g` object (and each `usemtl` switch inside one, which is how `tobj` splits
//!   models) becomes a [`crate::geom::mesh::MeshPart`] named after it. The MTL library is a
//!   second file and only one is uploaded, so `Kd` is never available: every part is grey.
//! - `v`, `vt`, `vn`, negative (relative) indices, polygons (fanned by `tobj`). Points and lines
//!   are dropped. Normals/UVs are kept when every part has them for every corner.
//! - A counting pass runs before `tobj`: it counts `v` lines and the fanned triangles of the `f`
//!   lines against the limits, and checks every face index against the number of `v`/`vt`/`vn`
//!   (relative indices against those seen so far, as `tobj` resolves them), because `tobj`
//!   indexes its arrays unchecked and would panic on an index out of range.
//! - The default up axis is Y.

use std::io::BufReader;

use super::{check_counts, Builder, MeshOptions, PartData, GREY};
use crate::error::InputError;
use crate::geom::mesh::Mesh;

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

pub(super) fn decode(bytes: &[u8], opts: &MeshOptions) -> Result<Mesh, InputError> {
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
    // The MTL library is not uploaded: every `mtllib` fails to load, and we colour parts grey.
    let (models, _materials) =
        tobj::load_obj_buf(&mut reader, &load, |_| Err(tobj::LoadError::OpenFileFailed))
            .map_err(|e| corrupt(e.to_string()))?;

    let mut builder = Builder::new();
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
        let uvs = (m.texcoords.len() == 2 * n)
            .then(|| m.texcoords.chunks_exact(2).map(|c| [c[0], c[1]]).collect());
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
                base_color: GREY,
                positions,
                normals,
                uvs,
                triangles,
            },
            FORMAT,
        )?;
        // Corners split by (v, vt, vn) can outnumber the `v` lines; cap as we go.
        check_counts(builder.vertex_count() as u64, 0, opts)?;
    }
    Ok(builder.build())
}
