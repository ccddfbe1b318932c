//! Density-volume readers (SPEC §3, *Input*): NumPy `.npy`, NRRD (raw or gzip), raw little-endian
//! `float32` with `dims`, and OpenVDB float grids (`.vdb`), all decoded into one [`Volume`].
//!
//! **Sniffing.** Magic bytes first (`\x93NUMPY`, `NRRD000`, OpenVDB's 8-byte `0x56444220` magic,
//! NanoVDB's `NanoVDB` magic), the file extension as a fallback (`.npy`, `.nrrd`/`.nhdr`, `.vdb`,
//! `.nvdb`, `.raw`), and finally raw `float32` when the caller gave `dims`. A `.raw` file (or
//! unrecognised bytes with `dims`) must be exactly `4·nx·ny·nz` bytes long.
//!
//! **Limits before allocation.** Every reader derives the voxel count from its header (the NumPy
//! shape, the NRRD `sizes`, the raw `dims`, the OpenVDB active bounding box), refuses it above
//! [`VolumeOptions::max_voxels`] with [`InputError::TooLarge`], and checks it against the bytes
//! actually present before allocating the grid; decompression (NRRD gzip, OpenVDB zip/Blosc) is
//! capped at the expected byte count, so a zip bomb is refused after reading one byte too many.
//! Third-party decoders (`npyz`, `flate2`, `lz4_flex`) run inside [`std::panic::catch_unwind`] as a
//! second line of defence: a panic on hostile bytes becomes [`InputError::Corrupt`].
//!
//! **Bounds** (the world box of [`Volume`]): [`VolumeOptions::bounds`] when given; else the file's
//! own geometry — NRRD `space origin` + `space directions` (or `spacings`), OpenVDB's voxel size and
//! translation applied to the active bounding box — taking voxel *centres* at the sample positions
//! as both formats define them, so the box reaches half a voxel beyond the outer samples; else
//! [`Volume::default_bounds`] (the SPEC's unit cube scaled to the grid's aspect). `.npy` and raw
//! carry no geometry.
//!
//! **Negative densities** are clamped to 0 (after decoding, before [`Volume::new`]). A density field
//! cannot be negative; the negatives that real files carry are CT values below the chosen zero
//! (air in Hounsfield units), simulation undershoot (−1e‑7 around a smoke front) or a signed
//! transfer, and in each case "no medium" is what a renderer should see. Refusing them was the
//! alternative; it would turn away working smoke caches over rounding noise. NaN and ±∞ are not
//! clamped: they are refused by [`Volume::new`] with the voxel named. (OpenVDB level sets, whose
//! negatives mean *inside*, are refused by the VDB reader instead: see [`vdb`].) The CGAL skull
//! NRRD of `shared/data` has no negatives (2·10⁻¹³ … 5.43).
//!
//! **Values** are taken as stored, also for integer types (a `uint8` volume has densities 0 … 255):
//! the extinction coefficient κ of the cloud state scales them.

mod blosc;
mod npy;
mod nrrd;
mod raw;
mod vdb;

use crate::error::{InputError, ParamError};
use crate::geom::volume::Volume;

/// Bounds of a volume box: `(min, max)` in world units.
pub type Bounds = ([f64; 3], [f64; 3]);

/// Options a caller passes to [`decode_volume`].
#[derive(Debug, Clone)]
pub struct VolumeOptions {
    /// Refuse volumes with more voxels than this, before allocating the grid
    /// ([`InputError::TooLarge`]).
    pub max_voxels: u64,
    /// Grid size `[nx, ny, nz]` for raw `float32` input (required there, ignored otherwise).
    pub dims: Option<[usize; 3]>,
    /// World box `(min, max)`; overrides the file's geometry. Each `min < max`, finite.
    pub bounds: Option<Bounds>,
}

impl Default for VolumeOptions {
    /// 64 Mi voxels (a 400³ grid, 256 MiB of `f32`), no dims, no bounds.
    fn default() -> Self {
        Self {
            max_voxels: 1 << 26,
            dims: None,
            bounds: None,
        }
    }
}

/// The volume formats we recognise (NanoVDB only to refuse it clearly).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VolumeFormat {
    /// NumPy `.npy`, 3-D.
    Npy,
    /// NRRD with an attached header (`NRRD000x`).
    Nrrd,
    /// OpenVDB `.vdb`.
    Vdb,
    /// NanoVDB `.nvdb` (refused).
    NanoVdb,
    /// Raw little-endian `float32`, x fastest, shape from [`VolumeOptions::dims`].
    Raw,
}

impl VolumeFormat {
    /// Short name used in error messages.
    pub fn name(self) -> &'static str {
        match self {
            VolumeFormat::Npy => "NPY",
            VolumeFormat::Nrrd => "NRRD",
            VolumeFormat::Vdb => "OpenVDB",
            VolumeFormat::NanoVdb => "NanoVDB",
            VolumeFormat::Raw => "raw float32",
        }
    }
}

/// OpenVDB's magic: the little-endian `i64` 0x56444220 (`" BDV"` then four zero bytes).
pub(crate) const VDB_MAGIC: [u8; 8] = [0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0];

/// The format detected from magic bytes, then the file extension, then `dims` (raw), without
/// decoding.
pub fn sniff(
    bytes: &[u8],
    filename: Option<&str>,
    dims: Option<[usize; 3]>,
) -> Option<VolumeFormat> {
    if bytes.starts_with(b"\x93NUMPY") {
        return Some(VolumeFormat::Npy);
    }
    if bytes.starts_with(b"NRRD000") {
        return Some(VolumeFormat::Nrrd);
    }
    if bytes.starts_with(&VDB_MAGIC) {
        return Some(VolumeFormat::Vdb);
    }
    // NanoVDB: the 64-bit magic "NanoVDB0" (older files) or "NanoVDB1"/"NanoVDB2" (file header).
    if bytes.starts_with(b"NanoVDB") {
        return Some(VolumeFormat::NanoVdb);
    }
    let ext = filename
        .and_then(|n| n.rsplit('.').next().filter(|_| n.contains('.')))
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("npy") => return Some(VolumeFormat::Npy),
        Some("nrrd" | "nhdr") => return Some(VolumeFormat::Nrrd),
        Some("vdb") => return Some(VolumeFormat::Vdb),
        Some("nvdb") => return Some(VolumeFormat::NanoVdb),
        Some("raw") => return Some(VolumeFormat::Raw),
        _ => {}
    }
    dims.map(|_| VolumeFormat::Raw)
}

/// Decode a density volume of any supported format (see [`sniff`]).
///
/// Errors: [`InputError::UnsupportedFormat`] (415) when no format matches or a variant is not
/// supported (NanoVDB, a Blosc codec other than LZ4/zlib, NRRD `bzip2`, a detached NRRD data
/// file, …); [`InputError::Corrupt`] (422) for truncated or inconsistent bytes;
/// [`InputError::TooLarge`] (413) when the voxel count exceeds `opts.max_voxels`, checked before
/// the grid is allocated; [`InputError::Unusable`] (422) for NaN/∞ densities, wrong
/// dimensionality or an empty grid; [`InputError::Param`] for missing or invalid `dims`/`bounds`.
///
/// Allocates the `nx·ny·nz` `f32` grid, plus the decoder's buffer of the stored type for `.npy`
/// and the decompressed bytes for gzip NRRD.
pub fn decode_volume(
    bytes: &[u8],
    filename: Option<&str>,
    opts: &VolumeOptions,
) -> Result<Volume, InputError> {
    check_options(opts)?;
    let format = sniff(bytes, filename, opts.dims).ok_or_else(|| {
        InputError::UnsupportedFormat(
            "not a volume format we read (NumPy .npy, NRRD .nrrd, OpenVDB .vdb, raw float32 .raw \
             with dims)"
                .to_string(),
        )
    })?;
    let decoded = std::panic::catch_unwind(|| match format {
        VolumeFormat::Npy => npy::decode(bytes, opts),
        VolumeFormat::Nrrd => nrrd::decode(bytes, opts),
        VolumeFormat::Vdb => vdb::decode(bytes, opts),
        VolumeFormat::Raw => raw::decode(bytes, opts),
        VolumeFormat::NanoVdb => Err(InputError::UnsupportedFormat(
            "NanoVDB (.nvdb) is not read; convert it to OpenVDB (.vdb) with nanovdb_convert, or \
             upload a .npy/.nrrd dense copy"
                .to_string(),
        )),
    })
    .unwrap_or_else(|_| {
        Err(InputError::Corrupt {
            format: format.name(),
            detail: "the decoder panicked on malformed data".to_string(),
        })
    })?;
    finish(decoded, opts)
}

/// What a reader hands back: the grid, x fastest, and the file's own box if it has one.
pub(crate) struct Decoded {
    pub dims: [usize; 3],
    pub density: Vec<f32>,
    pub bounds: Option<Bounds>,
}

fn check_options(opts: &VolumeOptions) -> Result<(), InputError> {
    if let Some(d) = opts.dims {
        if d.contains(&0) {
            return Err(ParamError::new("dims", "each of [nx, ny, nz] must be ≥ 1").into());
        }
    }
    if let Some((lo, hi)) = opts.bounds {
        crate::geom::sanity::check_box(lo, hi).map_err(|e| ParamError::new("bounds", e))?;
    }
    Ok(())
}

/// Refuse `dims` with a zero side or more than `max_voxels` voxels, before allocating; returns the
/// voxel count.
pub(crate) fn check_voxels(dims: [u64; 3], max_voxels: u64) -> Result<usize, InputError> {
    if dims.contains(&0) {
        return Err(InputError::Unusable(format!(
            "the volume is {}×{}×{} voxels; every side must be ≥ 1",
            dims[0], dims[1], dims[2]
        )));
    }
    let n = dims
        .iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(d))
        .unwrap_or(u64::MAX);
    if n > max_voxels {
        return Err(InputError::TooLarge {
            what: "volume voxels",
            actual: n,
            max: max_voxels,
        });
    }
    usize::try_from(n).map_err(|_| InputError::TooLarge {
        what: "volume voxels",
        actual: n,
        max: usize::MAX as u64,
    })
}

/// Common final step: clamp finite negatives to 0 (module doc), pick the bounds, validate.
fn finish(mut d: Decoded, opts: &VolumeOptions) -> Result<Volume, InputError> {
    for v in &mut d.density {
        if *v < 0.0 && v.is_finite() {
            *v = 0.0;
        }
    }
    let file_bounds = d
        .bounds
        .filter(|(lo, hi)| (0..3).all(|k| lo[k].is_finite() && hi[k].is_finite() && lo[k] < hi[k]));
    let bounds = opts
        .bounds
        .or(file_bounds)
        .unwrap_or_else(|| Volume::default_bounds(d.dims));
    Volume::new(d.dims, d.density, bounds)
}
