//! NRRD density volumes (SPEC §3; format: teem's NRRD0001–0005 specification) with an attached
//! header: the magic line `NRRD000x`, `field: value` lines (`#` comments and `key:=value` pairs are
//! skipped), a blank line, then the data.
//!
//! Read: `dimension: 3`; `sizes` (x fastest, as NRRD's first axis is the fastest); `type` float,
//! double, (u)char/int8, (u)short, (u)int, (u)longlong in any of NRRD's spellings; `encoding` raw,
//! gzip or ascii (text); `endian` (required for multi-byte raw/gzip data, as the spec says);
//! `byte skip` (≥ 0, or −1 = the data are the last bytes of a raw file). Refused with 415: detached
//! data (`data file`), `bzip2`/`hex` encodings, `line skip`, the `block` type. A `dimension` other
//! than 3 is refused as unusable (a 4-D NRRD of vectors or time steps needs a choice we cannot make).
//!
//! Geometry (→ [`Volume`](crate::geom::volume::Volume) bounds): NRRD puts the *centre* of the first
//! sample at `space origin` (0 when absent) and steps by the axis' `space directions` vector (or
//! its `spacings` entry). With axis-aligned directions (vector k non-zero in component k only, the
//! usual case) the box runs from half a step before the first sample to half a step after the last;
//! an axis with a negative step is flipped so that the grid runs towards increasing world
//! coordinates. Oblique or permuted directions cannot be an axis-aligned box: we keep only their
//! lengths and use the SPEC's default placement (longest side 1, centred, base at Y = 0) with the
//! physical aspect. Missing, zero or NaN steps → no file geometry (the caller's default).
//!
//! Limits: `sizes` × type width is checked against `max_voxels` and against the data present
//! before the grid is allocated; gzip data are inflated through a reader capped at the expected
//! byte count + 1, so a zip bomb costs one extra byte, not its expansion.

use std::io::Read;

use super::{check_voxels, Bounds, Decoded, VolumeOptions};
use crate::error::InputError;

const FORMAT: &str = "NRRD";

fn corrupt(detail: impl std::fmt::Display) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: detail.to_string(),
    }
}

fn unsupported(detail: impl std::fmt::Display) -> InputError {
    InputError::UnsupportedFormat(format!("NRRD {detail}"))
}

/// NRRD sample types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SampleType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl SampleType {
    fn parse(s: &str) -> Result<Self, InputError> {
        Ok(match s {
            "signed char" | "int8" | "int8_t" => Self::I8,
            "uchar" | "unsigned char" | "uint8" | "uint8_t" => Self::U8,
            "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
                Self::I16
            }
            "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => Self::U16,
            "int" | "signed int" | "int32" | "int32_t" => Self::I32,
            "uint" | "unsigned int" | "uint32" | "uint32_t" => Self::U32,
            "longlong"
            | "long long"
            | "long long int"
            | "signed long long"
            | "signed long long int"
            | "int64"
            | "int64_t" => Self::I64,
            "ulonglong"
            | "unsigned long long"
            | "unsigned long long int"
            | "uint64"
            | "uint64_t" => Self::U64,
            "float" => Self::F32,
            "double" => Self::F64,
            other => return Err(unsupported(format!("type {other:?}"))),
        })
    }

    fn width(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }

    /// One sample from exactly `width()` bytes.
    fn value(self, b: &[u8], big_endian: bool) -> f32 {
        let mut a = [0u8; 8];
        let w = self.width();
        a[..w].copy_from_slice(&b[..w]);
        if big_endian {
            a[..w].reverse();
        }
        match self {
            Self::I8 => f32::from(a[0] as i8),
            Self::U8 => f32::from(a[0]),
            Self::I16 => f32::from(i16::from_le_bytes([a[0], a[1]])),
            Self::U16 => f32::from(u16::from_le_bytes([a[0], a[1]])),
            Self::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f32,
            Self::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f32,
            Self::I64 => i64::from_le_bytes(a) as f32,
            Self::U64 => u64::from_le_bytes(a) as f32,
            Self::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]),
            Self::F64 => f64::from_le_bytes(a) as f32,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Raw,
    Gzip,
    Ascii,
}

/// The header fields we use; everything else is skipped.
#[derive(Debug, Default)]
struct Header {
    sample: Option<SampleType>,
    dimension: Option<usize>,
    sizes: Option<Vec<u64>>,
    encoding: Option<Encoding>,
    big_endian: Option<bool>,
    byte_skip: i64,
    spacings: Option<Vec<f64>>,
    directions: Option<Vec<Option<[f64; 3]>>>,
    origin: Option<[f64; 3]>,
}

/// Splits off the header; returns it and the offset of the first data byte.
fn parse_header(bytes: &[u8]) -> Result<(Header, usize), InputError> {
    let mut h = Header::default();
    let mut pos = 0;
    let mut first = true;
    loop {
        let Some(nl) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err(corrupt(
                "the header does not end in a blank line (truncated, or a detached .nhdr header)",
            ));
        };
        let raw = &bytes[pos..pos + nl];
        pos += nl + 1;
        let line = String::from_utf8_lossy(raw);
        let line = line.trim_end_matches('\r');
        if first {
            first = false;
            if !line.starts_with("NRRD000") {
                return Err(corrupt("the first line is not NRRD000x"));
            }
            continue;
        }
        if line.is_empty() {
            return Ok((h, pos));
        }
        if line.starts_with('#') || line.contains(":=") {
            continue;
        }
        let Some((key, value)) = line.split_once(": ") else {
            return Err(corrupt(format!(
                "header line {line:?} is not `field: value`"
            )));
        };
        field(&mut h, &key.to_ascii_lowercase(), value.trim())?;
    }
}

fn field(h: &mut Header, key: &str, value: &str) -> Result<(), InputError> {
    let bad = |what: &str| corrupt(format!("bad {what} field {value:?}"));
    match key {
        "type" => h.sample = Some(SampleType::parse(&value.to_ascii_lowercase())?),
        "dimension" => h.dimension = Some(value.parse().map_err(|_| bad(key))?),
        "sizes" => {
            h.sizes = Some(
                value
                    .split_whitespace()
                    .map(|s| s.parse::<u64>().map_err(|_| bad(key)))
                    .collect::<Result<_, _>>()?,
            )
        }
        "encoding" => {
            h.encoding = Some(match value.to_ascii_lowercase().as_str() {
                "raw" => Encoding::Raw,
                "gzip" | "gz" => Encoding::Gzip,
                "ascii" | "text" | "txt" => Encoding::Ascii,
                other => {
                    return Err(unsupported(format!(
                        "encoding {other:?}; we read raw, gzip and ascii"
                    )))
                }
            })
        }
        "endian" => {
            h.big_endian = Some(match value.to_ascii_lowercase().as_str() {
                "little" => false,
                "big" => true,
                _ => return Err(bad(key)),
            })
        }
        "byte skip" | "byteskip" => {
            h.byte_skip = value.parse().map_err(|_| bad(key))?;
            if h.byte_skip < -1 {
                return Err(bad(key));
            }
        }
        "line skip" | "lineskip" if value != "0" => {
            return Err(unsupported("`line skip` is not supported"));
        }
        "data file" | "datafile" => {
            return Err(unsupported(format!(
                "with a detached data file ({value}) is not read; upload one .nrrd with the \
                 data attached (e.g. `unu save -f nrrd -i in.nhdr -o out.nrrd`)"
            )))
        }
        "spacings" => {
            h.spacings = Some(
                value
                    .split_whitespace()
                    .map(|s| s.parse::<f64>().map_err(|_| bad(key)))
                    .collect::<Result<_, _>>()?,
            )
        }
        "space directions" => h.directions = Some(parse_directions(value).ok_or_else(|| bad(key))?),
        "space origin" => {
            let v = parse_vectors(value).ok_or_else(|| bad(key))?;
            match v[..] {
                [o] => h.origin = Some(o),
                _ => return Err(bad(key)),
            }
        }
        _ => {}
    }
    Ok(())
}

/// `(a,b,c) (d,e,f) none …` → one entry per axis.
fn parse_directions(value: &str) -> Option<Vec<Option<[f64; 3]>>> {
    let mut out = Vec::new();
    let mut rest = value.trim();
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("none") {
            out.push(None);
            rest = r.trim_start();
        } else {
            let close = rest.find(')')?;
            out.push(Some(parse_vectors(&rest[..=close])?.first().copied()?));
            rest = rest[close + 1..].trim_start();
        }
    }
    Some(out)
}

/// `(a,b,c)` groups → vectors of three components.
fn parse_vectors(value: &str) -> Option<Vec<[f64; 3]>> {
    let mut out = Vec::new();
    for group in value.split(')').map(str::trim).filter(|g| !g.is_empty()) {
        let inner = group.strip_prefix('(')?;
        let c: Vec<f64> = inner
            .split(',')
            .map(|s| s.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .ok()?;
        out.push([*c.first()?, *c.get(1)?, *c.get(2)?]);
        if c.len() != 3 {
            return None;
        }
    }
    Some(out)
}

pub(super) fn decode(bytes: &[u8], opts: &VolumeOptions) -> Result<Decoded, InputError> {
    let (h, data_start) = parse_header(bytes)?;
    let sample = h.sample.ok_or_else(|| corrupt("no `type` field"))?;
    match h.dimension {
        Some(3) => {}
        Some(d) => {
            return Err(InputError::Unusable(format!(
                "the NRRD has dimension {d}; a density volume has dimension 3"
            )))
        }
        None => return Err(corrupt("no `dimension` field")),
    }
    let sizes = h
        .sizes
        .as_deref()
        .ok_or_else(|| corrupt("no `sizes` field"))?;
    let &[nx, ny, nz] = sizes else {
        return Err(corrupt(format!(
            "`sizes` has {} entries for dimension 3",
            sizes.len()
        )));
    };
    let n = check_voxels([nx, ny, nz], opts.max_voxels)?;
    let dims = [nx as usize, ny as usize, nz as usize];
    let width = sample.width();
    let expected = n
        .checked_mul(width)
        .ok_or_else(|| corrupt("sizes overflow"))?;
    let encoding = h.encoding.ok_or_else(|| corrupt("no `encoding` field"))?;
    let big_endian = match (h.big_endian, width, encoding) {
        (Some(b), _, _) => b,
        (None, 1, _) | (None, _, Encoding::Ascii) => false,
        (None, _, _) => return Err(corrupt("no `endian` field for multi-byte samples")),
    };
    let data = &bytes[data_start..];
    let mut density = match encoding {
        Encoding::Raw => {
            let body = match h.byte_skip {
                -1 => data.get(data.len().saturating_sub(expected)..),
                k => data.get(usize::try_from(k).unwrap_or(usize::MAX)..),
            }
            .unwrap_or(&[]);
            samples(body, expected, sample, big_endian)?
        }
        Encoding::Gzip => {
            let skip = usize::try_from(h.byte_skip.max(0)).unwrap_or(usize::MAX);
            let inflated = gunzip_capped(data.get(skip..).unwrap_or(&[]), expected)?;
            samples(&inflated, expected, sample, big_endian)?
        }
        Encoding::Ascii => ascii(data, n)?,
    };
    let bounds = geometry(&h, dims, &mut density);
    Ok(Decoded {
        dims,
        density,
        bounds,
    })
}

/// Inflate at most `expected + 1` bytes; exactly `expected` must come out.
fn gunzip_capped(data: &[u8], expected: usize) -> Result<Vec<u8>, InputError> {
    let mut out = Vec::with_capacity(expected);
    flate2::read::MultiGzDecoder::new(data)
        .take(expected as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| corrupt(format!("gzip data: {e}")))?;
    match out.len().cmp(&expected) {
        std::cmp::Ordering::Equal => Ok(out),
        std::cmp::Ordering::Less => Err(corrupt(format!(
            "the gzip data inflate to {} bytes; the sizes need {expected}",
            out.len()
        ))),
        std::cmp::Ordering::Greater => Err(corrupt(format!(
            "the gzip data inflate to more than the {expected} bytes the sizes need"
        ))),
    }
}

fn samples(
    body: &[u8],
    expected: usize,
    sample: SampleType,
    big_endian: bool,
) -> Result<Vec<f32>, InputError> {
    let body = body.get(..expected).ok_or_else(|| {
        corrupt(format!(
            "truncated: the sizes need {expected} data bytes, {} present",
            body.len()
        ))
    })?;
    Ok(body
        .chunks_exact(sample.width())
        .map(|c| sample.value(c, big_endian))
        .collect())
}

/// Whitespace-separated numbers; at least two bytes per value, so `n` is checked against the
/// length before allocating.
fn ascii(data: &[u8], n: usize) -> Result<Vec<f32>, InputError> {
    if data.len() / 2 + 1 < n {
        return Err(corrupt(format!(
            "truncated: {n} ascii values need more than {} bytes",
            data.len()
        )));
    }
    let text = std::str::from_utf8(data).map_err(|_| corrupt("ascii data are not text"))?;
    let mut out = Vec::with_capacity(n);
    for tok in text
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
    {
        if out.len() == n {
            break;
        }
        out.push(
            tok.parse::<f32>()
                .map_err(|_| corrupt(format!("ascii value {tok:?}")))?,
        );
    }
    if out.len() != n {
        return Err(corrupt(format!(
            "{} ascii values, the sizes need {n}",
            out.len()
        )));
    }
    Ok(out)
}

/// Bounds from the header (module doc); flips axes with negative steps in `density`.
fn geometry(h: &Header, dims: [usize; 3], density: &mut Vec<f32>) -> Option<Bounds> {
    let origin = h.origin.unwrap_or([0.0; 3]);
    let steps: [f64; 3] = if let Some(dirs) = &h.directions {
        let [Some(a), Some(b), Some(c)] = dirs[..] else {
            return None;
        };
        let d = [a, b, c];
        let aligned = (0..3).all(|k| (0..3).all(|j| j == k || d[k][j] == 0.0));
        if !aligned {
            let len = d.map(|v| v.iter().map(|c| c * c).sum::<f64>().sqrt());
            return aspect_box(dims, len);
        }
        [d[0][0], d[1][1], d[2][2]]
    } else if let Some(&[a, b, c]) = h.spacings.as_deref() {
        [a, b, c]
    } else {
        return None;
    };
    if steps.iter().any(|s| !s.is_finite() || *s == 0.0) {
        return None;
    }
    let mut lo = [0.0; 3];
    let mut hi = [0.0; 3];
    for k in 0..3 {
        let first = origin[k] - 0.5 * steps[k];
        let last = origin[k] + (dims[k] as f64 - 0.5) * steps[k];
        lo[k] = first.min(last);
        hi[k] = first.max(last);
    }
    let flip = steps.map(|s| s < 0.0);
    if flip.contains(&true) {
        *density = flipped(density, dims, flip);
    }
    Some((lo, hi))
}

/// The SPEC's default placement with a physical aspect: extents `n_k·step_k`, the longest 1.
fn aspect_box(dims: [usize; 3], step: [f64; 3]) -> Option<Bounds> {
    let ext: [f64; 3] = [0, 1, 2].map(|k| dims[k] as f64 * step[k]);
    let longest = ext.iter().copied().fold(0.0, f64::max);
    if !(longest.is_finite() && ext.iter().all(|&e| e > 0.0)) {
        return None;
    }
    let e = ext.map(|v| v / longest);
    Some((
        [-0.5 * e[0], 0.0, -0.5 * e[2]],
        [0.5 * e[0], e[1], 0.5 * e[2]],
    ))
}

/// A copy of `src` with the flagged axes reversed. Allocates the output.
fn flipped(src: &[f32], [nx, ny, nz]: [usize; 3], flip: [bool; 3]) -> Vec<f32> {
    let at = |i: usize, n: usize, f: bool| if f { n - 1 - i } else { i };
    let mut out = Vec::with_capacity(src.len());
    for z in 0..nz {
        let sz = at(z, nz, flip[2]);
        for y in 0..ny {
            let sy = at(y, ny, flip[1]);
            out.extend((0..nx).map(|x| src[at(x, nx, flip[0]) + nx * (sy + ny * sz)]));
        }
    }
    out
}
