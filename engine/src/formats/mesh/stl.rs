//! STL, binary and ASCII. Units are whatever the file uses (taken as metres); the default up
//! axis is Z (see the module doc of [`super`]).
//!
//! - **Binary** is read here, not by `stl_io`: the format is 84 header bytes and 50 bytes per
//!   triangle, the header count must give the file size exactly, and `stl_io`'s own detection
//!   takes any file whose 80-byte header starts with `solid ` for ASCII — a habit of many
//!   exporters — while its binary reader is not public. A file that does not start with `solid`
//!   is binary; its count is checked against the limit, then against the size, before anything
//!   is allocated. The 2-byte attribute (some exporters' colour) is ignored.
//! - **ASCII** goes through `stl_io` (0.11), capped at `max_triangles` while it iterates.
//!   `solid` without a name is accepted (`stl_io` wants `solid `).
//! - Corners are welded by exact bit pattern (−0 = +0), as `stl_io`'s indexed reader does, so
//!   the mesh is indexed and shared edges are shared. The facet normals are not kept: they are
//!   per face, and [`Mesh::normals`] is per vertex.

use std::collections::HashMap;
use std::io::Cursor;

use super::{check_counts, MeshOptions, GREY};
use crate::error::InputError;
use crate::geom::mesh::{Mesh, MeshPart};

const FORMAT: &str = "STL";

fn corrupt(detail: impl Into<String>) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: detail.into(),
    }
}

/// Binary STL: the header count gives the file size exactly, and the file is not an ASCII STL
/// that happens to have that size (`solid` … `endsolid`).
pub(super) fn is_binary(bytes: &[u8]) -> bool {
    let Some(n) = header_count(bytes) else {
        return false;
    };
    if 84 + 50 * n != bytes.len() as u64 {
        return false;
    }
    !(bytes.starts_with(b"solid") && is_ascii_tail(bytes))
}

fn header_count(bytes: &[u8]) -> Option<u64> {
    let c = bytes.get(80..84)?;
    Some(u64::from(u32::from_le_bytes([c[0], c[1], c[2], c[3]])))
}

fn is_ascii_tail(bytes: &[u8]) -> bool {
    let tail = &bytes[bytes.len().saturating_sub(512)..];
    tail.windows(8).any(|w| w.eq_ignore_ascii_case(b"endsolid"))
}

pub(super) fn decode(bytes: &[u8], opts: &MeshOptions) -> Result<Mesh, InputError> {
    let text_start = bytes
        .iter()
        .position(|c| !c.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    let looks_ascii = bytes[text_start..].starts_with(b"solid") && !is_binary(bytes);
    if looks_ascii {
        decode_ascii(&bytes[text_start..], opts)
    } else {
        decode_binary(bytes, opts)
    }
}

fn decode_binary(bytes: &[u8], opts: &MeshOptions) -> Result<Mesh, InputError> {
    let n = header_count(bytes).ok_or_else(|| {
        corrupt(format!(
            "a binary STL needs an 84-byte header; the file has {} bytes",
            bytes.len()
        ))
    })?;
    check_counts(0, n, opts)?;
    let expected = 84 + 50 * n;
    if expected != bytes.len() as u64 {
        return Err(corrupt(format!(
            "the header declares {n} triangles ({expected} bytes) but the file has {} bytes",
            bytes.len()
        )));
    }
    let mut welder = Welder::new(n as usize, opts);
    for (t, rec) in bytes[84..].chunks_exact(50).enumerate() {
        let f = |k: usize| {
            let o = 12 + 4 * k;
            f32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]])
        };
        let corners = [[f(0), f(1), f(2)], [f(3), f(4), f(5)], [f(6), f(7), f(8)]];
        welder.push(t, corners)?;
    }
    Ok(welder.into_mesh("stl".to_string()))
}

fn decode_ascii(text: &[u8], opts: &MeshOptions) -> Result<Mesh, InputError> {
    let name = text
        .split(|&c| c == b'\n')
        .next()
        .and_then(|l| std::str::from_utf8(l).ok())
        .map(|l| l["solid".len().min(l.len())..].trim().to_string())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "stl".to_string());
    // stl_io wants "solid " with a space; a nameless "solid\n" is common.
    let patched;
    let text = if text.starts_with(b"solid ") {
        text
    } else {
        let mut v = Vec::with_capacity(text.len() + 1);
        v.extend_from_slice(b"solid ");
        v.extend_from_slice(&text[5..]);
        patched = v;
        &patched[..]
    };
    let mut cursor = Cursor::new(text);
    let reader =
        stl_io::create_stl_reader(&mut cursor).map_err(|e| corrupt(format!("ASCII STL: {e}")))?;
    let mut welder = Welder::new(0, opts);
    for (t, tri) in reader.enumerate() {
        let tri = tri.map_err(|e| corrupt(format!("ASCII STL, facet {t}: {e}")))?;
        check_counts(0, t as u64 + 1, opts)?;
        welder.push(t, tri.vertices.map(|v| v.0))?;
    }
    Ok(welder.into_mesh(name))
}

/// Welds corners by bit pattern into an indexed mesh, capped at `max_vertices`.
struct Welder {
    index: HashMap<[u32; 3], u32>,
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    max_vertices: u64,
}

impl Welder {
    fn new(triangles: usize, opts: &MeshOptions) -> Self {
        Self {
            index: HashMap::new(),
            positions: Vec::new(),
            triangles: Vec::with_capacity(triangles),
            max_vertices: opts.max_vertices,
        }
    }

    fn push(&mut self, t: usize, corners: [[f32; 3]; 3]) -> Result<(), InputError> {
        let mut tri = [0u32; 3];
        for (k, p) in corners.into_iter().enumerate() {
            if let Some(c) = p.iter().position(|c| !c.is_finite()) {
                return Err(corrupt(format!(
                    "triangle {t}, corner {k} has a non-finite coordinate {} (vertex {})",
                    p[c],
                    3 * t + k
                )));
            }
            // −0 and +0 are the same point.
            let key = p.map(|c| if c == 0.0 { 0 } else { c.to_bits() });
            let next = self.positions.len() as u32;
            let i = *self.index.entry(key).or_insert(next);
            if i == next {
                if self.positions.len() as u64 >= self.max_vertices {
                    return Err(InputError::TooLarge {
                        what: "mesh vertices",
                        actual: self.positions.len() as u64 + 1,
                        max: self.max_vertices,
                    });
                }
                self.positions.push(p);
            }
            tri[k] = i;
        }
        self.triangles.push(tri);
        Ok(())
    }

    fn into_mesh(self, name: String) -> Mesh {
        Mesh {
            parts: vec![MeshPart {
                name,
                first_triangle: 0,
                triangle_count: self.triangles.len(),
                base_color: GREY,
                texture: None,
            }],
            positions: self.positions,
            triangles: self.triangles,
            ..Mesh::default()
        }
    }
}
