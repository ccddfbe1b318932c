//! A parallel reader for the common subset of Wavefront OBJ (issue 19): the same models as
//! `tobj` 4 with the options [`super::obj`] uses (single index, fanned polygons, points and lines
//! dropped), or `None`, and the caller takes the `tobj` path (its checking pass and its errors).
//!
//! - **The subset.** ASCII text; `v x y z` (exactly three numbers: no `w`, no colour), `vt` (its
//!   first two numbers), `vn` (its first three), `f` with three corners or more (`v`, `v/vt`,
//!   `v//vn`, `v/vt/vn`; negative indices), `o`/`g` (a new model when the current one has faces,
//!   as `tobj` splits them, named as `tobj` names it). Every other statement is ignored, as `tobj`
//!   ignores it, except `l`, `mtllib` and `usemtl` (and an `f` with one or two corners), which
//!   send the file to `tobj`. So does anything `tobj` or the checking pass would reject: a number
//!   that does not parse, an index 0 or out of range, a count over the limits, a face index that
//!   `tobj` would find out of bounds when it closes a model.
//! - **Equality.** Words are split at the characters `str::split_whitespace` splits at (the text
//!   is ASCII), numbers are parsed by the same `FromStr` as `tobj`'s, and the models are closed and
//!   their vertices numbered by first appearance of each (v, vt, vn) corner exactly as `tobj`'s
//!   `add_vertex` does, corner by corner along the fanned triangles: the same `Vec`s, bit for bit.
//! - **Parallel.** The file is cut into chunks at line ends. A first pass counts the `v`, `vt`
//!   and `vn` lines per chunk (the vertex limit is checked before anything is allocated; relative
//!   indices resolve against the counts before the chunk); the second parses each chunk into
//!   numbers and absolute corner indices, on all threads. Numbering the corners of each model is
//!   one sequential pass over `u32`s.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use rayon::prelude::*;

use super::MeshOptions;

/// Smallest chunk, bytes (small in tests, so that they cross chunks).
const MIN_CHUNK: usize = if cfg!(test) { 512 } else { 1 << 20 };

/// Index of an absent `vt`/`vn`.
const MISSING: u32 = u32::MAX;

/// Whitespace as `char::is_whitespace` has it in ASCII.
#[inline(always)]
fn is_ws(b: u8) -> bool {
    b == b' ' || (b'\t'..=b'\r').contains(&b)
}

/// The file cut at line ends into about `parts` pieces of at least `min` bytes.
fn chunks(bytes: &[u8], parts: usize, min: usize) -> Vec<&[u8]> {
    let want = (bytes.len() / min.max(1)).clamp(1, parts.max(1));
    let step = bytes.len().div_ceil(want).max(1);
    let mut out = Vec::with_capacity(want);
    let mut start = 0;
    while start < bytes.len() {
        let mut end = (start + step).min(bytes.len());
        while end < bytes.len() && bytes[end - 1] != b'\n' {
            end += 1;
        }
        out.push(&bytes[start..end]);
        start = end;
    }
    if out.is_empty() {
        out.push(bytes);
    }
    out
}

/// The lines of a chunk (without their `\n`).
#[inline]
fn lines(chunk: &[u8]) -> impl Iterator<Item = &[u8]> {
    chunk
        .strip_suffix(b"\n")
        .unwrap_or(chunk)
        .split(|&b| b == b'\n')
}

/// What a line's first word makes it.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    V,
    Vt,
    Vn,
    F,
    Group,
    /// `l`, `mtllib`, `usemtl`: not in the subset.
    Other,
    Ignored,
}

/// The first word's kind and the rest of the line after it.
#[inline(always)]
fn classify(line: &[u8]) -> (Kind, &[u8]) {
    let mut i = 0;
    while i < line.len() && is_ws(line[i]) {
        i += 1;
    }
    let s = i;
    while i < line.len() && !is_ws(line[i]) {
        i += 1;
    }
    let kind = match &line[s..i] {
        b"v" => Kind::V,
        b"vt" => Kind::Vt,
        b"vn" => Kind::Vn,
        b"f" => Kind::F,
        b"o" | b"g" => Kind::Group,
        b"l" | b"mtllib" | b"usemtl" => Kind::Other,
        _ => Kind::Ignored,
    };
    (kind, &line[i..])
}

/// The words of `rest`.
#[inline(always)]
fn words(rest: &[u8]) -> impl Iterator<Item = &[u8]> {
    rest.split(|&b| is_ws(b)).filter(|w| !w.is_empty())
}

#[inline(always)]
fn float(word: &[u8]) -> Option<f32> {
    // ASCII (checked by the counting pass), so UTF-8.
    std::str::from_utf8(word).ok()?.parse().ok()
}

/// An index as `isize::from_str` reads it: an optional sign, then digits (at most 18 here, so
/// no overflow; longer ones go to `tobj`).
#[inline(always)]
fn index(word: &[u8]) -> Option<i64> {
    let (neg, digits) = match word.first()? {
        b'-' => (true, &word[1..]),
        b'+' => (false, &word[1..]),
        _ => (false, word),
    };
    if digits.is_empty() || digits.len() > 18 {
        return None;
    }
    let mut x: i64 = 0;
    for &d in digits {
        if !d.is_ascii_digit() {
            return None;
        }
        x = x * 10 + i64::from(d - b'0');
    }
    Some(if neg { -x } else { x })
}

/// First pass over a chunk: `v`, `vt`, `vn` lines; `None` when the chunk is not ASCII or has
/// a statement outside the subset.
fn count(chunk: &[u8]) -> Option<[u64; 3]> {
    if !chunk.is_ascii() {
        return None;
    }
    let mut n = [0u64; 3];
    for line in lines(chunk) {
        match classify(line).0 {
            Kind::V => n[0] += 1,
            Kind::Vt => n[1] += 1,
            Kind::Vn => n[2] += 1,
            Kind::Other => return None,
            _ => {}
        }
    }
    Some(n)
}

/// An `o`/`g` line: the corner it comes before, its name, and the `v`/`vt`/`vn` counts so far.
struct Group {
    corner: usize,
    name: String,
    seen: [u64; 3],
}

/// One chunk, parsed.
#[derive(Default)]
struct Parsed {
    pos: Vec<f32>,
    tex: Vec<f32>,
    nrm: Vec<f32>,
    /// Absolute 0-based indices per corner of the fanned triangles (`vt`/`vn`: empty when no
    /// corner of the chunk has one, else [`MISSING`] where absent).
    cv: Vec<u32>,
    ct: Vec<u32>,
    cn: Vec<u32>,
    groups: Vec<Group>,
}

/// Second pass over a chunk; `base` = the counts before it, `total` = the file's.
fn parse(chunk: &[u8], base: [u64; 3], total: [u64; 3], opts: &MeshOptions) -> Option<Parsed> {
    let mut p = Parsed::default();
    let mut seen = base;
    let mut corner = [[MISSING; 3]; 2];
    let mut face: Vec<[u32; 3]> = Vec::new();
    for line in lines(chunk) {
        let (kind, rest) = classify(line);
        match kind {
            Kind::Ignored => {}
            Kind::Other => return None,
            Kind::V => {
                let mut w = words(rest);
                for _ in 0..3 {
                    p.pos.push(float(w.next()?)?);
                }
                if w.next().is_some() {
                    return None;
                }
                seen[0] += 1;
            }
            Kind::Vt => {
                let mut w = words(rest);
                for _ in 0..2 {
                    p.tex.push(float(w.next()?)?);
                }
                seen[1] += 1;
            }
            Kind::Vn => {
                let mut w = words(rest);
                for _ in 0..3 {
                    p.nrm.push(float(w.next()?)?);
                }
                seen[2] += 1;
            }
            Kind::Group => {
                let text = std::str::from_utf8(line).ok()?;
                let name = text[1..].trim();
                p.groups.push(Group {
                    corner: p.cv.len(),
                    name: if name.is_empty() {
                        "unnamed_object".to_string()
                    } else {
                        name.to_string()
                    },
                    seen,
                });
            }
            Kind::F => {
                face.clear();
                for w in words(rest) {
                    let mut c = [MISSING; 3];
                    for (k, s) in w.split(|&b| b == b'/').enumerate() {
                        if s.is_empty() {
                            continue;
                        }
                        if k > 2 {
                            return None;
                        }
                        let x = index(s)?;
                        let i = if x < 0 {
                            seen[k].checked_sub(x.unsigned_abs())?
                        } else if x > 0 && (x as u64) <= total[k] {
                            x as u64 - 1
                        } else {
                            return None;
                        };
                        c[k] = u32::try_from(i).ok().filter(|&i| i != MISSING)?;
                    }
                    face.push(c);
                }
                if face.len() < 3 {
                    return None;
                }
                // Fanned as `tobj` fans: (0, i, i + 1), corner by corner.
                corner[0] = face[0];
                for pair in face[1..].windows(2) {
                    corner[1] = pair[0];
                    for c in [corner[0], corner[1], pair[1]] {
                        p.cv.push(c[0]);
                        for (k, list) in [(1, &mut p.ct), (2, &mut p.cn)] {
                            if c[k] != MISSING || !list.is_empty() {
                                // The corners before the first with this index lack it.
                                list.resize(p.cv.len() - 1, MISSING);
                                list.push(c[k]);
                            }
                        }
                    }
                }
                if (p.cv.len() / 3) as u64 > opts.max_triangles {
                    return None;
                }
            }
        }
    }
    Some(p)
}

/// FxHash's multiply-rotate: the keys are small integers, and the numbering does not depend on
/// the hasher.
#[derive(Default)]
struct Fx(u64);

impl Hasher for Fx {
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    #[inline]
    fn write_u32(&mut self, i: u32) {
        self.write_u64(u64::from(i));
    }
    #[inline]
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }
}

/// The models `tobj::load_obj_buf` returns for `bytes` (no materials), or `None` for the `tobj`
/// path (module doc): also when the checking pass would refuse the file (its limits, its index
/// checks, no faces), so that errors always come from there.
pub(super) fn models(bytes: &[u8], opts: &MeshOptions) -> Option<Vec<tobj::Model>> {
    let threads = rayon::current_num_threads().max(1);
    let parts = chunks(bytes, threads * 4, MIN_CHUNK);
    let counts: Vec<[u64; 3]> = parts.par_iter().map(|c| count(c)).collect::<Option<_>>()?;
    let mut base = Vec::with_capacity(parts.len());
    let mut total = [0u64; 3];
    for c in &counts {
        base.push(total);
        for k in 0..3 {
            total[k] += c[k];
        }
    }
    if total[0] > opts.max_vertices || total.iter().any(|&n| n >= u64::from(MISSING)) {
        return None;
    }
    let parsed: Vec<Parsed> = parts
        .par_iter()
        .zip(&base)
        .map(|(c, &b)| parse(c, b, total, opts))
        .collect::<Option<_>>()?;
    let triangles: u64 = parsed.iter().map(|p| (p.cv.len() / 3) as u64).sum();
    if triangles > opts.max_triangles || triangles == 0 {
        return None;
    }
    let cat = |f: fn(&Parsed) -> &Vec<f32>| -> Vec<f32> {
        let mut v = Vec::with_capacity(parsed.iter().map(|p| f(p).len()).sum());
        for p in &parsed {
            v.extend_from_slice(f(p));
        }
        v
    };
    let (pos, tex, nrm) = (cat(|p| &p.pos), cat(|p| &p.tex), cat(|p| &p.nrm));

    // Models as `tobj` closes them: at an `o`/`g` after faces, and at the end. Corners are
    // numbered across chunks.
    let mut first = Vec::with_capacity(parsed.len());
    let mut corners = 0usize;
    for p in &parsed {
        first.push(corners);
        corners += p.cv.len();
    }
    let mut models = Vec::new();
    let mut name = "unnamed_object".to_string();
    let mut start = 0usize;
    let mut numbering = Numbering::new(total[0] as usize);
    let mut close = |start: usize, end: usize, seen: [u64; 3]| {
        numbering.mesh(&parsed, &first, start..end, seen, &pos, &tex, &nrm)
    };
    for (p, &f) in parsed.iter().zip(&first) {
        for g in &p.groups {
            let at = f + g.corner;
            if at > start {
                let mesh = close(start, at, g.seen)?;
                models.push(tobj::Model::new(mesh, std::mem::take(&mut name)));
                start = at;
            }
            name.clone_from(&g.name);
        }
    }
    let mesh = close(start, corners, total)?;
    models.push(tobj::Model::new(mesh, name));
    Some(models)
}

/// Numbers the (v, vt, vn) corners of a model by first appearance (`tobj`'s `add_vertex`).
struct Numbering {
    /// By `v` alone, when no corner has `vt` or `vn`: the vertex number, or [`MISSING`].
    by_v: Vec<u32>,
    by_key: HashMap<[u32; 3], u32, BuildHasherDefault<Fx>>,
}

impl Numbering {
    fn new(nv: usize) -> Self {
        Self {
            by_v: vec![MISSING; nv],
            by_key: HashMap::default(),
        }
    }

    /// The mesh of the corners `range` (numbered across the chunks, which start at `first`),
    /// closed when the file had `seen` `v`/`vt`/`vn` lines; `None` where `tobj` would fail.
    #[allow(clippy::too_many_arguments)]
    fn mesh(
        &mut self,
        parsed: &[Parsed],
        first: &[usize],
        range: std::ops::Range<usize>,
        seen: [u64; 3],
        pos: &[f32],
        tex: &[f32],
        nrm: &[f32],
    ) -> Option<tobj::Mesh> {
        let mut m = tobj::Mesh::default();
        let (nv, nt, nn) = (seen[0] as usize, seen[1] as usize, seen[2] as usize);
        // Per chunk overlapping the range: (chunk, its first and end corner in the range).
        let segs: Vec<(&Parsed, usize, usize)> = parsed
            .iter()
            .zip(first)
            .filter_map(|(p, &f)| {
                let a = range.start.max(f) - f;
                let b = range.end.min(f + p.cv.len()).saturating_sub(f);
                (a < b).then_some((p, a, b))
            })
            .collect();
        let plain = segs
            .iter()
            .all(|(p, _, _)| p.ct.is_empty() && p.cn.is_empty());
        m.indices.reserve(range.len());
        if plain {
            let mut added: Vec<u32> = Vec::new();
            let mut ok = true;
            for &(p, a, b) in &segs {
                for &v in &p.cv[a..b] {
                    let slot = &mut self.by_v[v as usize];
                    if *slot == MISSING {
                        if v as usize >= nv {
                            ok = false;
                            break;
                        }
                        *slot = added.len() as u32;
                        added.push(v);
                        let i = 3 * v as usize;
                        m.positions.extend_from_slice(&pos[i..i + 3]);
                    }
                    m.indices.push(*slot);
                }
                if !ok {
                    break;
                }
            }
            for v in added {
                self.by_v[v as usize] = MISSING;
            }
            return ok.then_some(m);
        }
        self.by_key.clear();
        for &(p, a, b) in &segs {
            for q in a..b {
                let t = p.ct.get(q).copied().unwrap_or(MISSING);
                let n = p.cn.get(q).copied().unwrap_or(MISSING);
                let key = [p.cv[q], t, n];
                let next = self.by_key.len() as u32;
                let slot = *self.by_key.entry(key).or_insert(next);
                if slot == next {
                    let v = key[0] as usize;
                    if v >= nv {
                        return None;
                    }
                    m.positions.extend_from_slice(&pos[3 * v..3 * v + 3]);
                    if t != MISSING {
                        // `tobj` ignores a `vt` while there are none yet; leave that to it.
                        if t as usize >= nt {
                            return None;
                        }
                        m.texcoords
                            .extend_from_slice(&tex[2 * t as usize..2 * t as usize + 2]);
                    }
                    if n != MISSING {
                        if n as usize >= nn {
                            return None;
                        }
                        m.normals
                            .extend_from_slice(&nrm[3 * n as usize..3 * n as usize + 3]);
                    }
                }
                m.indices.push(slot);
            }
        }
        Some(m)
    }
}
