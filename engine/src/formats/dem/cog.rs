//! A tiled GeoTIFF / Cloud-Optimized GeoTIFF DEM read **by ranges** (issue 22: "a DEM in the
//! object store is never downloaded whole to serve a tile", "a 50 000²-cell COG DEM served with
//! bounded RSS"): [`CogDem::open`] reads the header and the image file directories (IFDs) only —
//! the full-resolution image and its reduced-resolution overviews (NewSubfileType bit 0), each a
//! *level* — and [`CogDem::read_window`] then reads, decodes and caches only the internal tiles a
//! window of one level overlaps.
//!
//! The bytes come from a [`ByteSource`]: a byte slice in memory, a file read by offset
//! ([`FileSource`]), or the service's object store (an S3 `GET` with a `Range` per read, see
//! `src/store/blobs.rs`). Reads go through a small read-ahead buffer ([`RangeReader`], 64 KiB
//! per miss while the IFDs are parsed) and, for a tile, exactly its byte range, fetched before
//! the `tiff` crate decodes it (deflate, LZW, PackBits or none, with or without a predictor).
//!
//! Hostile headers cost nothing: the level's dimensions are checked against
//! [`MAX_TILED_CELLS`], internal tiles against [`MAX_TILE_SIDE`], every tile's byte range
//! against the object's size and a bound on its compressed size, the IFD count against
//! [`MAX_LEVELS`], all before a tile is decoded; the decoder's own limits cap every buffer at one
//! tile. A truncated or corrupt tile is [`InputError::Corrupt`] when it is read (the tiff crate
//! runs inside `catch_unwind`, as for whole DEMs), a failure of the byte source itself
//! [`CogError::Source`].
//!
//! Cost: the IFDs' tile offset arrays (8 bytes per internal tile per level), a cache of decoded
//! tiles ([`TILE_CACHE_BYTES`], first in first out) and one decoder per level and thread.

use std::collections::{HashMap, VecDeque};
use std::io::{Read, Seek, SeekFrom};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;
use tiff::decoder::{ChunkType, Decoder, Limits};
use tiff::tags::Tag;
use tiff::ColorType;

use super::geo::{cell_size_metres, crs_info, transform_from_tags};
use super::geotiff::{map_tiff_err, parse_nodata, read_geo_tags, to_heights};
use super::{required_cell_size, DemOptions};
use crate::error::InputError;
use crate::geom::heightfield::{Dem, GeoRef};

const FORMAT: &str = "GeoTIFF";

/// Cells of the full-resolution level at most (2³², e.g. 65 536²): beyond BigTIFF-sized DEMs.
pub const MAX_TILED_CELLS: u64 = 1 << 32;

/// Side of an internal tile at most, pixels (GDAL writes 256 or 512).
pub const MAX_TILE_SIDE: usize = 2048;

/// Image file directories read at most (the full resolution, overviews and masks).
pub const MAX_LEVELS: usize = 32;

/// Bytes of decoded tiles kept (f32 heights).
pub const TILE_CACHE_BYTES: usize = 64 << 20;

/// Bytes fetched per read-ahead miss while the header and IFDs are parsed.
const READ_AHEAD: usize = 64 << 10;

/// Random-access bytes: a file, a buffer, an object in a store read by ranges.
pub trait ByteSource: Send + Sync {
    /// Size in bytes.
    fn size(&self) -> u64;
    /// Fills `buf` from `offset` (the caller keeps `offset + buf.len() ≤ size()`).
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()>;
}

impl ByteSource for Vec<u8> {
    fn size(&self) -> u64 {
        self.len() as u64
    }
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        let start = usize::try_from(offset).map_err(std::io::Error::other)?;
        let src = self
            .get(start..start + buf.len())
            .ok_or_else(|| std::io::Error::from(std::io::ErrorKind::UnexpectedEof))?;
        buf.copy_from_slice(src);
        Ok(())
    }
}

/// A file read by offset (`pread`), never whole.
#[derive(Debug)]
pub struct FileSource {
    file: std::fs::File,
    size: u64,
}

impl FileSource {
    pub fn open(path: &std::path::Path) -> std::io::Result<Self> {
        let file = std::fs::File::open(path)?;
        let size = file.metadata()?.len();
        Ok(Self { file, size })
    }
}

impl ByteSource for FileSource {
    fn size(&self) -> u64 {
        self.size
    }
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        std::os::unix::fs::FileExt::read_exact_at(&self.file, buf, offset)
    }
}

/// Why a window could not be read.
#[derive(Debug, thiserror::Error)]
pub enum CogError {
    /// The file is not a DEM we read this way, or a tile is corrupt (a 4xx for the client).
    #[error(transparent)]
    Input(#[from] InputError),
    /// The byte source failed (the store is unavailable).
    #[error("reading the DEM: {0}")]
    Source(std::io::Error),
}

fn corrupt(e: impl std::fmt::Display) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: e.to_string(),
    }
}

/// A failure of the byte source itself, told apart from the decoder's errors after the `tiff`
/// crate has wrapped it.
#[derive(Debug)]
struct SourceFailure(std::io::Error);

impl std::fmt::Display for SourceFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the byte source failed: {}", self.0)
    }
}

impl std::error::Error for SourceFailure {}

/// `Read + Seek` over a [`ByteSource`] with one read-ahead buffer; counts the bytes fetched.
/// `next_len` is how much the next miss fetches at least (a tile's byte count, set before the
/// tile is decoded, so a tile costs one range request).
struct RangeReader {
    src: Arc<dyn ByteSource>,
    size: u64,
    pos: u64,
    start: u64,
    buf: Vec<u8>,
    fetched: Arc<AtomicU64>,
    next_len: Arc<AtomicU64>,
}

impl RangeReader {
    fn new(src: Arc<dyn ByteSource>, fetched: Arc<AtomicU64>, next_len: Arc<AtomicU64>) -> Self {
        Self {
            size: src.size(),
            src,
            pos: 0,
            start: 0,
            buf: Vec::new(),
            fetched,
            next_len,
        }
    }

    /// Makes `[at, at + len)` (clipped to the object) the buffer.
    fn fetch(&mut self, at: u64, len: usize) -> std::io::Result<()> {
        let n = usize::try_from((len as u64).min(self.size.saturating_sub(at))).unwrap_or(0);
        self.buf.clear();
        self.buf.resize(n, 0);
        self.start = at;
        if let Err(e) = self.src.read_at(at, &mut self.buf) {
            self.buf.clear();
            return Err(std::io::Error::new(e.kind(), SourceFailure(e)));
        }
        self.fetched.fetch_add(n as u64, Ordering::Relaxed);
        Ok(())
    }
}

impl Read for RangeReader {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        if self.pos >= self.size || out.is_empty() {
            return Ok(0);
        }
        let inside = self.pos >= self.start && self.pos < self.start + self.buf.len() as u64;
        if !inside {
            let hint = usize::try_from(self.next_len.swap(0, Ordering::Relaxed)).unwrap_or(0);
            let want = out.len().max(hint).clamp(READ_AHEAD, 16 << 20);
            self.fetch(self.pos, want)?;
        }
        let off = (self.pos - self.start) as usize;
        let n = out.len().min(self.buf.len() - off);
        out[..n].copy_from_slice(&self.buf[off..off + n]);
        self.pos += n as u64;
        Ok(n)
    }
}

impl Seek for RangeReader {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let p = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::End(d) => self.size.checked_add_signed(d),
            SeekFrom::Current(d) => self.pos.checked_add_signed(d),
        };
        self.pos = p.ok_or_else(|| std::io::Error::from(std::io::ErrorKind::InvalidInput))?;
        Ok(self.pos)
    }
}

/// One image of the file: the full resolution (level 0) or an overview.
#[derive(Debug, Clone)]
pub struct CogLevel {
    pub width: usize,
    pub height: usize,
    tile_w: usize,
    tile_h: usize,
    /// Index of its IFD in the file.
    ifd: usize,
    /// Each tile's compressed size (its range was checked at open).
    counts: Vec<u64>,
}

impl CogLevel {
    fn tiles_across(&self) -> usize {
        self.width.div_ceil(self.tile_w)
    }
}

/// Decoded tiles by (level, tile index), first in first out past [`TILE_CACHE_BYTES`].
#[derive(Default)]
struct TileCache {
    tiles: HashMap<(usize, usize), Arc<Vec<f32>>>,
    order: VecDeque<(usize, usize)>,
    bytes: usize,
}

type LevelDecoder = (Decoder<RangeReader>, Arc<AtomicU64>);

/// A decoded internal tile, shared with the cache.
type Tile = Arc<Vec<f32>>;

/// A tiled GeoTIFF DEM whose tiles are read on demand (see the module documentation).
pub struct CogDem {
    src: Arc<dyn ByteSource>,
    levels: Vec<CogLevel>,
    samples: usize,
    nodata: Option<f64>,
    /// The georeferencing of level 0.
    georef: GeoRef,
    /// Level 0's cell size, metres (east, south).
    dx: f64,
    dy: f64,
    fetched: Arc<AtomicU64>,
    /// Idle decoders per level (each holds its level's IFD), with their reader's `next_len`.
    decoders: Vec<Mutex<Vec<LevelDecoder>>>,
    cache: Mutex<TileCache>,
}

impl std::fmt::Debug for CogDem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CogDem")
            .field("levels", &self.levels)
            .field("georef", &self.georef)
            .finish_non_exhaustive()
    }
}

fn limits() -> Limits {
    let mut l = Limits::default();
    // One tile of up to four 8-byte samples per pixel.
    let tile = MAX_TILE_SIDE * MAX_TILE_SIDE * 4 * 8;
    l.decoding_buffer_size = tile;
    l.intermediate_buffer_size = tile;
    // Tile offsets of a 65 536² level in 256-px tiles, 8 bytes each.
    l.ifd_value_size = 1 << 20;
    l
}

/// Runs a `tiff` call, turning a panic on hostile bytes into `Corrupt`.
fn guarded<T>(f: impl FnOnce() -> Result<T, CogError>) -> Result<T, CogError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
        .unwrap_or_else(|_| Err(corrupt("the decoder panicked on malformed data").into()))
}

impl CogDem {
    /// Reads the header and IFDs of the tiled GeoTIFF in `src`: an error when it is not a tiled,
    /// single-plane TIFF of at most [`MAX_TILED_CELLS`] cells, or a header is inconsistent.
    /// `opts.cell_size` places a TIFF without georeferencing, as for whole DEMs.
    pub fn open(src: Arc<dyn ByteSource>, opts: &DemOptions) -> Result<Self, CogError> {
        guarded(|| Self::open_inner(src, opts))
    }

    fn open_inner(src: Arc<dyn ByteSource>, opts: &DemOptions) -> Result<Self, CogError> {
        let fetched = Arc::new(AtomicU64::new(0));
        let size = src.size();
        let (mut dec, _) = Self::decoder(&src, &fetched, 0)?;
        let (w, h) = dec.dimensions().map_err(tiff_failure)?;
        let cells = u64::from(w) * u64::from(h);
        if cells > MAX_TILED_CELLS {
            return Err(InputError::TooLarge {
                what: "DEM cells (tiled GeoTIFF)",
                actual: cells,
                max: MAX_TILED_CELLS,
            }
            .into());
        }
        if w < 3 || h < 3 {
            return Err(InputError::Unusable(format!(
                "the DEM is {w}×{h} cells; at least 3×3 are needed"
            ))
            .into());
        }
        let colortype = dec.colortype().map_err(tiff_failure)?;
        let samples = match colortype {
            ColorType::Gray(_) => 1,
            ColorType::GrayA(_) => 2,
            ColorType::RGB(_) => 3,
            ColorType::RGBA(_) | ColorType::CMYK(_) => 4,
            other => {
                return Err(InputError::UnsupportedFormat(format!(
                    "TIFF colour type {other:?} is not an elevation band"
                ))
                .into())
            }
        };
        let tags = read_geo_tags(&mut dec)?;
        let nodata = match dec.find_tag(Tag::GdalNodata).map_err(tiff_failure)? {
            Some(v) => parse_nodata(&v.into_string().map_err(tiff_failure)?),
            None => None,
        };
        let bytes_per_pixel = samples * 8;
        let level0 = Self::level(&mut dec, 0, size, bytes_per_pixel)?;
        let mut levels = vec![level0];
        let mut ifd = 0;
        while dec.more_images() && ifd + 1 < MAX_LEVELS {
            ifd += 1;
            // In order (`seek_to_image` does not keep `more_images` true to the chain).
            dec.next_image().map_err(tiff_failure)?;
            let kind: u32 = dec
                .find_tag_unsigned(Tag::NewSubfileType)
                .map_err(tiff_failure)?
                .unwrap_or(0);
            // Reduced-resolution images only (not masks, bit 2, nor other pages).
            if kind & 1 == 0 || kind & 4 != 0 {
                continue;
            }
            // An overview of another sample type is not one of this DEM's.
            if dec.colortype().map_err(tiff_failure)? != colortype {
                continue;
            }
            let l = Self::level(&mut dec, ifd, size, bytes_per_pixel)?;
            let prev = levels
                .last()
                .map_or((w as usize, h as usize), |p| (p.width, p.height));
            if l.width < prev.0 && l.height < prev.1 && l.width >= 1 && l.height >= 1 {
                levels.push(l);
            }
        }
        let crs = crs_info(&tags);
        let transform = transform_from_tags(&tags, crs.pixel_is_point);
        let (width, height) = (w as usize, h as usize);
        let (dx, dy) = match transform {
            Some(t) => cell_size_metres(&t, width, height, crs.geographic, crs.linear_unit),
            None => {
                let c = required_cell_size(opts, "a TIFF without georeferencing")?;
                (c, c)
            }
        };
        if !(dx.is_finite() && dx > 0.0 && dy.is_finite() && dy > 0.0) {
            return Err(InputError::Unusable(format!(
                "the DEM's cell size ({dx} × {dy} m) is not a positive finite number"
            ))
            .into());
        }
        let decoders = levels.iter().map(|_| Mutex::new(Vec::new())).collect();
        Ok(Self {
            src,
            levels,
            samples,
            nodata,
            georef: GeoRef {
                transform,
                epsg: crs.epsg,
                geographic: crs.geographic,
                nodata,
                tags,
            },
            dx,
            dy,
            fetched,
            decoders,
            cache: Mutex::new(TileCache::default()),
        })
    }

    fn decoder(
        src: &Arc<dyn ByteSource>,
        fetched: &Arc<AtomicU64>,
        ifd: usize,
    ) -> Result<LevelDecoder, CogError> {
        let next_len = Arc::new(AtomicU64::new(0));
        let reader = RangeReader::new(src.clone(), fetched.clone(), next_len.clone());
        let mut dec = Decoder::new(reader).map_err(tiff_failure)?;
        dec = dec.with_limits(limits());
        if ifd > 0 {
            dec.seek_to_image(ifd).map_err(tiff_failure)?;
        }
        Ok((dec, next_len))
    }

    /// The current IFD of `dec` as a level, checked.
    fn level(
        dec: &mut Decoder<RangeReader>,
        ifd: usize,
        size: u64,
        bytes_per_pixel: usize,
    ) -> Result<CogLevel, CogError> {
        let (w, h) = dec.dimensions().map_err(tiff_failure)?;
        if dec.get_chunk_type() != ChunkType::Tile {
            return Err(InputError::UnsupportedFormat(
                "a DEM this large must be a tiled GeoTIFF (a Cloud-Optimized GeoTIFF: gdal_translate \
                 -of COG); this one is stored in strips"
                    .into(),
            )
            .into());
        }
        let planar: u16 = dec
            .find_tag_unsigned(Tag::PlanarConfiguration)
            .map_err(tiff_failure)?
            .unwrap_or(1);
        // 1: chunky (pixel-interleaved), 2: planar; one band reads the same either way.
        if planar != 1 && bytes_per_pixel > 8 {
            return Err(InputError::UnsupportedFormat(
                "planar (band-separate) tiled TIFF; write it pixel-interleaved".into(),
            )
            .into());
        }
        let (tw, th) = dec.chunk_dimensions();
        let (tw, th) = (tw as usize, th as usize);
        if tw == 0 || th == 0 || tw > MAX_TILE_SIDE || th > MAX_TILE_SIDE {
            return Err(corrupt(format!(
                "internal tiles of {tw}×{th} pixels (at most {MAX_TILE_SIDE} a side)"
            ))
            .into());
        }
        let offsets = dec
            .get_tag_u64_vec(Tag::TileOffsets)
            .map_err(tiff_failure)?;
        let counts = dec
            .get_tag_u64_vec(Tag::TileByteCounts)
            .map_err(tiff_failure)?;
        let n = (w as usize).div_ceil(tw) * (h as usize).div_ceil(th);
        if offsets.len() != n || counts.len() != n {
            return Err(corrupt(format!(
                "{} tile offsets and {} byte counts for {n} tiles",
                offsets.len(),
                counts.len()
            ))
            .into());
        }
        // Compressed data may grow a little past the raw tile (deflate's stored blocks, LZW).
        let max_count = (tw * th * bytes_per_pixel) as u64 * 2 + 4096;
        for (&o, &c) in offsets.iter().zip(&counts) {
            if c > max_count || o.checked_add(c).is_none_or(|end| end > size) {
                return Err(corrupt(format!(
                    "a tile's bytes [{o}, {o}+{c}) lie outside the {size}-byte file or exceed a \
                     tile's size"
                ))
                .into());
            }
        }
        Ok(CogLevel {
            width: w as usize,
            height: h as usize,
            tile_w: tw,
            tile_h: th,
            ifd,
            counts,
        })
    }

    /// The levels, full resolution first, then overviews from finest to coarsest.
    pub fn levels(&self) -> &[CogLevel] {
        &self.levels
    }

    /// The georeferencing of level 0.
    pub fn georef(&self) -> &GeoRef {
        &self.georef
    }

    /// Level 0's cell size, metres (east, south).
    pub fn cell_size(&self) -> (f64, f64) {
        (self.dx, self.dy)
    }

    /// Bytes read from the source so far (header, IFDs and tiles).
    pub fn bytes_fetched(&self) -> u64 {
        self.fetched.load(Ordering::Relaxed)
    }

    /// Size of the whole object, bytes.
    pub fn object_size(&self) -> u64 {
        self.src.size()
    }

    /// Level `l`'s (dx, dy) in metres and its transform: level 0's scaled by the size ratio.
    pub fn level_grid(&self, l: usize) -> (f64, f64, Option<[f64; 6]>) {
        let (w0, h0) = (self.levels[0].width as f64, self.levels[0].height as f64);
        let lv = &self.levels[l];
        let (sx, sy) = (w0 / lv.width as f64, h0 / lv.height as f64);
        let t = self
            .georef
            .transform
            .map(|t| [t[0], t[1] * sx, t[2] * sy, t[3], t[4] * sx, t[5] * sy]);
        (self.dx * sx, self.dy * sy, t)
    }

    /// Level `l` whole as a [`Dem`] (what a bounded overview is read with).
    pub fn read_level(&self, l: usize) -> Result<Dem, CogError> {
        let lv = &self.levels[l];
        let (w, h) = (lv.width, lv.height);
        let heights = self.read_window(l, 0, 0, w, h)?;
        if heights.iter().all(|v| v.is_nan()) {
            return Err(InputError::Unusable("every cell of the DEM is nodata".into()).into());
        }
        let (dx, dy, transform) = self.level_grid(l);
        Ok(Dem {
            width: w,
            height: h,
            heights,
            dx,
            dy,
            georef: GeoRef {
                transform,
                ..self.georef.clone()
            },
        })
    }

    /// Heights of cells `[c0, c1) × [r0, r1)` of level `l` (clipped to the level; the caller
    /// asks within it), row-major, NaN for nodata. Reads each internal tile it overlaps once
    /// (from the cache when it was read lately), in parallel.
    pub fn read_window(
        &self,
        l: usize,
        c0: usize,
        r0: usize,
        c1: usize,
        r1: usize,
    ) -> Result<Vec<f32>, CogError> {
        let lv = &self.levels[l];
        let (c1, r1) = (c1.min(lv.width), r1.min(lv.height));
        let (c0, r0) = (c0.min(c1), r0.min(r1));
        let (w, h) = (c1 - c0, r1 - r0);
        let mut out = vec![f32::NAN; w * h];
        if w == 0 || h == 0 {
            return Ok(out);
        }
        let (tx0, tx1) = (c0 / lv.tile_w, (c1 - 1) / lv.tile_w);
        let (ty0, ty1) = (r0 / lv.tile_h, (r1 - 1) / lv.tile_h);
        let across = lv.tiles_across();
        let wanted: Vec<(usize, usize)> = (ty0..=ty1)
            .flat_map(|ty| (tx0..=tx1).map(move |tx| (tx, ty)))
            .collect();
        let tiles: Vec<((usize, usize), Tile)> = wanted
            .par_iter()
            .map(|&(tx, ty)| Ok(((tx, ty), self.tile(l, ty * across + tx)?)))
            .collect::<Result<_, CogError>>()?;
        for ((tx, ty), data) in tiles {
            let (tc0, tr0) = (tx * lv.tile_w, ty * lv.tile_h);
            let dw = (lv.width - tc0).min(lv.tile_w);
            let dh = (lv.height - tr0).min(lv.tile_h);
            let (a0, a1) = (c0.max(tc0), c1.min(tc0 + dw));
            let (b0, b1) = (r0.max(tr0), r1.min(tr0 + dh));
            for r in b0..b1 {
                let src = &data[(r - tr0) * dw + (a0 - tc0)..(r - tr0) * dw + (a1 - tc0)];
                out[(r - r0) * w + (a0 - c0)..(r - r0) * w + (a1 - c0)].copy_from_slice(src);
            }
        }
        Ok(out)
    }

    /// Internal tile `i` of level `l`, decoded (data size: edge tiles are cropped).
    fn tile(&self, l: usize, i: usize) -> Result<Arc<Vec<f32>>, CogError> {
        if let Some(t) = self
            .cache
            .lock()
            .ok()
            .and_then(|c| c.tiles.get(&(l, i)).cloned())
        {
            return Ok(t);
        }
        let lv = &self.levels[l];
        let (mut dec, next_len) = match self.decoders[l].lock().ok().and_then(|mut v| v.pop()) {
            Some(d) => d,
            None => guarded(|| Self::decoder(&self.src, &self.fetched, lv.ifd))?,
        };
        // The tile's bytes in one request (the checks at open bound the count).
        next_len.store(lv.counts[i], Ordering::Relaxed);
        let data = guarded(|| {
            let (dw, dh) = dec.chunk_data_dimensions(i as u32);
            let image = dec.read_chunk(i as u32).map_err(tiff_failure)?;
            let cells = dw as usize * dh as usize;
            let mut v = to_heights(image, cells, self.samples, self.nodata)?;
            for x in &mut v {
                if x.is_infinite() {
                    *x = f32::NAN;
                }
            }
            Ok(v)
        })?;
        if let Ok(mut v) = self.decoders[l].lock() {
            v.push((dec, next_len));
        }
        let data = Arc::new(data);
        if let Ok(mut c) = self.cache.lock() {
            let bytes = data.len() * 4;
            if !c.tiles.contains_key(&(l, i)) {
                while c.bytes + bytes > TILE_CACHE_BYTES {
                    let Some(old) = c.order.pop_front() else {
                        break;
                    };
                    if let Some(t) = c.tiles.remove(&old) {
                        c.bytes -= t.len() * 4;
                    }
                }
                c.bytes += bytes;
                c.order.push_back((l, i));
                c.tiles.insert((l, i), data.clone());
            }
        }
        Ok(data)
    }
}

/// A tiff error as an input error, or the byte source's own failure behind it.
fn tiff_failure(e: tiff::TiffError) -> CogError {
    if let tiff::TiffError::IoError(io) = &e {
        if let Some(f) = io.get_ref().and_then(|r| r.downcast_ref::<SourceFailure>()) {
            return CogError::Source(std::io::Error::new(f.0.kind(), f.0.to_string()));
        }
    }
    map_tiff_err(e).into()
}
