//! A pure-Rust decoder for Blosc 1 frames as OpenVDB writes them (its default codec since file
//! version 223: `blosc_compress_ctx(level 9, byte shuffle, sizeof(value), …, "lz4")` per node
//! buffer), so `.vdb` uploads need neither C code nor `unsafe`.
//!
//! Frame (c-blosc 1.x `blosc.c`): a 16-byte header — version, codec version, flags, type size,
//! then little-endian `u32` uncompressed size, block size and frame size — and either the raw
//! bytes (flag `MEMCPYED`) or one `i32` start offset per block followed by the blocks. Each block
//! is split into `typesize` streams when the `DONT_SPLIT` flag is clear, `typesize ≤ 16`,
//! `blocksize / typesize ≥ 128` and the block is not the short last one (c-blosc's `blosc_d`
//! rule, which also reads frames written before the flag existed); each stream is an `i32`
//! compressed length and the codec's bytes (stored as is when the length equals the stream's
//! size). Byte-shuffled blocks are unshuffled afterwards.
//!
//! Codecs: LZ4 and LZ4HC (one format, via `lz4_flex`'s safe decoder) and zlib (`flate2`). BloscLZ,
//! Snappy, Zstd and bit-shuffle are refused with [`InputError::UnsupportedFormat`] naming them;
//! OpenVDB does not write them.
//!
//! Every size is checked against the caller's expected size before anything is allocated, so a
//! frame cannot ask for more memory than the node buffer it belongs to.

use std::io::Read;

use crate::error::InputError;

const FLAG_SHUFFLE: u8 = 0x1;
const FLAG_MEMCPYED: u8 = 0x2;
const FLAG_BITSHUFFLE: u8 = 0x4;
const FLAG_DONT_SPLIT: u8 = 0x10;
/// c-blosc's `MAX_SPLITS` and `MIN_BUFFERSIZE`.
const MAX_SPLITS: usize = 16;
const MIN_BUFFERSIZE: usize = 128;

fn corrupt(detail: impl std::fmt::Display) -> InputError {
    InputError::Corrupt {
        format: "OpenVDB",
        detail: format!("Blosc data: {detail}"),
    }
}

fn le32(b: &[u8], at: usize) -> Result<u32, InputError> {
    b.get(at..at + 4)
        .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
        .ok_or_else(|| corrupt("truncated"))
}

/// Decompress one frame that must hold exactly `expected` bytes.
pub(super) fn decompress(src: &[u8], expected: usize) -> Result<Vec<u8>, InputError> {
    let header = src
        .get(..16)
        .ok_or_else(|| corrupt("shorter than its header"))?;
    let (version, flags, typesize) = (header[0], header[2], usize::from(header[3]));
    let nbytes = le32(src, 4)? as usize;
    let blocksize = le32(src, 8)? as usize;
    let cbytes = le32(src, 12)? as usize;
    if version == 0 || version > 2 {
        return Err(corrupt(format!("format version {version}")));
    }
    if nbytes != expected {
        return Err(corrupt(format!(
            "holds {nbytes} bytes, the node needs {expected}"
        )));
    }
    if cbytes > src.len() {
        return Err(corrupt(format!(
            "frame of {cbytes} bytes, {} present",
            src.len()
        )));
    }
    let src = &src[..cbytes];
    if flags & FLAG_MEMCPYED != 0 {
        return src
            .get(16..16 + nbytes)
            .map(<[u8]>::to_vec)
            .ok_or_else(|| corrupt("truncated stored frame"));
    }
    if flags & FLAG_BITSHUFFLE != 0 {
        return Err(InputError::UnsupportedFormat(
            "OpenVDB grid compressed with Blosc bit-shuffle, which we do not decode".to_string(),
        ));
    }
    let codec = Codec::from_flags(flags)?;
    if nbytes == 0 {
        return Ok(Vec::new());
    }
    if blocksize == 0 || typesize == 0 {
        return Err(corrupt("zero block or type size"));
    }
    let nblocks = nbytes.div_ceil(blocksize);
    let mut out = vec![0u8; nbytes];
    let mut tmp = vec![0u8; blocksize.min(nbytes)];
    for (j, dest) in out.chunks_mut(blocksize).enumerate() {
        let start = le32(src, 16 + 4 * j)? as usize;
        if start < 16 + 4 * nblocks || start >= src.len() {
            return Err(corrupt(format!("block {j} starts at {start}")));
        }
        let bsize = dest.len();
        let leftover = bsize < blocksize;
        let split = flags & FLAG_DONT_SPLIT == 0
            && typesize <= MAX_SPLITS
            && bsize / typesize >= MIN_BUFFERSIZE
            && !leftover;
        let nsplits = if split { typesize } else { 1 };
        let shuffled = flags & FLAG_SHUFFLE != 0;
        let target: &mut [u8] = if shuffled { &mut tmp[..bsize] } else { dest };
        let neblock = bsize / nsplits;
        let mut at = start;
        for stream in target.chunks_mut(neblock).take(nsplits) {
            let clen = le32(src, at)? as usize;
            at += 4;
            let body = src
                .get(at..at.saturating_add(clen))
                .ok_or_else(|| corrupt(format!("stream of {clen} bytes past the frame end")))?;
            at += clen;
            if clen == neblock {
                stream.copy_from_slice(body);
            } else {
                codec.decompress(body, stream)?;
            }
        }
        if shuffled {
            unshuffle(typesize, &tmp[..bsize], dest);
        }
    }
    Ok(out)
}

#[derive(Debug, Clone, Copy)]
enum Codec {
    Lz4,
    Zlib,
}

impl Codec {
    fn from_flags(flags: u8) -> Result<Self, InputError> {
        match flags >> 5 {
            1 => Ok(Codec::Lz4),
            3 => Ok(Codec::Zlib),
            code => {
                let name = match code {
                    0 => "BloscLZ",
                    2 => "Snappy",
                    4 => "Zstd",
                    _ => "an unknown codec",
                };
                Err(InputError::UnsupportedFormat(format!(
                    "OpenVDB grid compressed with Blosc/{name}; we decode Blosc with LZ4 or zlib \
                     (OpenVDB's default) — re-save it with `vdb_print`/`vdb_tool` defaults or \
                     without compression"
                )))
            }
        }
    }

    /// Fill `out` exactly from `body`.
    fn decompress(self, body: &[u8], out: &mut [u8]) -> Result<(), InputError> {
        let n = match self {
            Codec::Lz4 => lz4_flex::block::decompress_into(body, out)
                .map_err(|e| corrupt(format!("LZ4: {e}")))?,
            Codec::Zlib => {
                let mut r = flate2::read::ZlibDecoder::new(body).take(out.len() as u64);
                let mut n = 0;
                while n < out.len() {
                    match r.read(&mut out[n..]) {
                        Ok(0) => break,
                        Ok(k) => n += k,
                        Err(e) => return Err(corrupt(format!("zlib: {e}"))),
                    }
                }
                n
            }
        };
        if n != out.len() {
            return Err(corrupt(format!(
                "a stream inflates to {n} bytes, {} expected",
                out.len()
            )));
        }
        Ok(())
    }
}

/// c-blosc's `unshuffle_generic`: byte `j` of element `i` was stored at `j·(n/typesize) + i`; the
/// `n mod typesize` tail bytes are stored as is.
fn unshuffle(typesize: usize, src: &[u8], dest: &mut [u8]) {
    let count = src.len() / typesize;
    for i in 0..count {
        for j in 0..typesize {
            dest[i * typesize + j] = src[j * count + i];
        }
    }
    let tail = count * typesize;
    dest[tail..].copy_from_slice(&src[tail..]);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A hand-made frame: shuffled, split into 4 streams stored verbatim (clen == neblock).
    #[test]
    fn stored_split_shuffled_frame_round_trips() {
        let values: Vec<f32> = (0..256).map(|i| i as f32 * 0.5 - 3.0).collect();
        let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let n = raw.len();
        let count = n / 4;
        let mut shuffled = vec![0u8; n];
        for i in 0..count {
            for j in 0..4 {
                shuffled[j * count + i] = raw[i * 4 + j];
            }
        }
        let mut frame = vec![2, 1, FLAG_SHUFFLE | (1 << 5), 4];
        frame.extend((n as u32).to_le_bytes());
        frame.extend((n as u32).to_le_bytes());
        let total = 16 + 4 + 4 * 4 + n;
        frame.extend((total as u32).to_le_bytes());
        frame.extend(20u32.to_le_bytes());
        for s in shuffled.chunks(count) {
            frame.extend((count as u32).to_le_bytes());
            frame.extend_from_slice(s);
        }
        assert_eq!(decompress(&frame, n).unwrap(), raw);
        // A frame that holds another size than the node needs, and every truncation, is refused.
        assert!(decompress(&frame, n + 4).is_err());
        for len in 0..frame.len() {
            assert!(decompress(&frame[..len], n).is_err());
        }
    }
}
