//! A synthetic OpenVDB file written the way OpenVDB 224 writes one (tiles, half floats, zip and
//! Blosc/LZ4 codecs, a `ScaleTranslateMap`), checked value for value against its construction and
//! fuzzed byte by byte — small enough to flip every interesting byte, unlike the real files.

use std::io::Write;

use super::{assert_bounds, decode, opts, vdb_err};
use phenomena_engine::formats::volume::{decode_volume, VolumeOptions};
use phenomena_engine::InputError;

/// Codec of the synthetic file: OpenVDB's compression flags (active-mask always on, as OpenVDB
/// writes), and whether values are saved as half floats.
#[derive(Clone, Copy, Debug)]
struct Synth {
    compression: u32,
    half: bool,
}

/// Leaf A (origin (−8, 0, 0)): voxel `(x, y, z)` local is active when `(x + y + z) % 3 == 0`, with
/// value `(1 + x + 8y + 64z) / 64` (exact in half floats). Leaf B (origin (−8, 8, 0)): only local
/// (7, 7, 7) active, value 2. An active 8³ tile of 0.25 at (−16, 0, 0) in the 4-level node.
fn synth_expected(g: [i64; 3]) -> f32 {
    let [x, y, z] = g;
    if (-16..-8).contains(&x) && (0..8).contains(&y) {
        return 0.25;
    }
    if (-8..0).contains(&x) && (0..8).contains(&y) {
        let l = [x + 8, y, z];
        return if (l[0] + l[1] + l[2]) % 3 == 0 {
            (1 + l[0] + 8 * l[1] + 64 * l[2]) as f32 / 64.0
        } else {
            0.0
        };
    }
    if g == [-1, 15, 7] {
        return 2.0;
    }
    0.0
}

fn f32_to_f16(v: f32) -> u16 {
    // Normal numbers and zero only (all the synthetic values are).
    if v == 0.0 {
        return 0;
    }
    let b = v.to_bits();
    let exp = ((b >> 23) & 0xff) as i32 - 127 + 15;
    (((b >> 16) & 0x8000) | ((exp as u32) << 10) | ((b >> 13) & 0x3ff)) as u16
}

/// `io::writeData`: stored, zlib or Blosc (one LZ4 block, shuffled and split as c-blosc does);
/// chunks under 48 bytes are stored with a negative length, as OpenVDB does.
fn write_data(out: &mut Vec<u8>, s: Synth, raw: &[u8], typesize: usize) {
    if s.compression & 0x5 == 0 {
        out.extend(raw);
        return;
    }
    if raw.len() < 48 {
        out.extend((-(raw.len() as i64)).to_le_bytes());
        out.extend(raw);
        return;
    }
    let body = if s.compression & 0x4 != 0 {
        let n = raw.len();
        let count = n / typesize;
        let mut shuffled = vec![0u8; n];
        for i in 0..count {
            for j in 0..typesize {
                shuffled[j * count + i] = raw[i * typesize + j];
            }
        }
        let split = n / typesize >= 128;
        let streams: Vec<&[u8]> = if split {
            shuffled.chunks(count).collect()
        } else {
            vec![&shuffled]
        };
        let mut blocks = Vec::new();
        for st in streams {
            let c = lz4_flex::block::compress(st);
            let c = if c.len() < st.len() { c } else { st.to_vec() };
            blocks.extend((c.len() as u32).to_le_bytes());
            blocks.extend(c);
        }
        let mut f = vec![2, 1, 0x1 | (1 << 5), typesize as u8];
        f.extend((n as u32).to_le_bytes());
        f.extend((n as u32).to_le_bytes());
        f.extend(((20 + blocks.len()) as u32).to_le_bytes());
        f.extend(20u32.to_le_bytes());
        f.extend(blocks);
        f
    } else {
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(raw).unwrap();
        e.finish().unwrap()
    };
    out.extend((body.len() as i64).to_le_bytes());
    out.extend(body);
}

fn string(out: &mut Vec<u8>, s: &str) {
    out.extend((s.len() as u32).to_le_bytes());
    out.extend(s.as_bytes());
}

fn mask(out: &mut Vec<u8>, bits: usize, on: impl Fn(usize) -> bool) {
    for w in 0..bits / 64 {
        let word = (0..64).fold(0u64, |acc, b| acc | (u64::from(on(w * 64 + b)) << b));
        out.extend(word.to_le_bytes());
    }
}

/// `readCompressedValues` input: metadata 0 (inactive = background), then the active values.
fn values(out: &mut Vec<u8>, s: Synth, active: &[f32]) {
    out.push(0);
    let raw: Vec<u8> = if s.half {
        active
            .iter()
            .flat_map(|&v| f32_to_f16(v).to_le_bytes())
            .collect()
    } else {
        active.iter().flat_map(|v| v.to_le_bytes()).collect()
    };
    write_data(out, s, &raw, if s.half { 2 } else { 4 });
}

/// The file layout of OpenVDB 224 (`Archive::write`, `GridDescriptor`, `Grid::writeTopology`,
/// `writeBuffers`): one grid "density", `ScaleTranslateMap` (scale 0.5, translation (1, 2, 3)),
/// one root child at (−4096, 0, 0) holding one 4-level node at (−128, 0, 0).
fn synth_vdb(s: Synth) -> Vec<u8> {
    synth_vdb_with(s, "fog volume", "Tree_float_5_4_3", "ScaleTranslateMap")
}

/// [`synth_vdb`] with another grid class, tree type or map name.
fn synth_vdb_with(s: Synth, class: &str, tree: &str, map: &str) -> Vec<u8> {
    let leaf_a = |n: usize| (n >> 6) + ((n >> 3) & 7) + (n & 7);
    let a_on = |n: usize| leaf_a(n) % 3 == 0;
    let b_on = |n: usize| n == 511;
    let mut f = vec![0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0];
    f.extend(224u32.to_le_bytes());
    f.extend(10u32.to_le_bytes());
    f.extend(0u32.to_le_bytes());
    f.push(1);
    f.extend([b'0'; 36]);
    f.extend(0u32.to_le_bytes()); // file metadata
    f.extend(1u32.to_le_bytes()); // grids
    string(&mut f, "density");
    string(
        &mut f,
        &format!("{tree}{}", if s.half { "_HalfFloat" } else { "" }),
    );
    string(&mut f, "");
    let offsets_at = f.len();
    f.extend([0u8; 24]);
    let grid_pos = f.len();
    f.extend(s.compression.to_le_bytes());
    f.extend(1u32.to_le_bytes());
    string(&mut f, "class");
    string(&mut f, "string");
    string(&mut f, class);
    string(&mut f, map);
    for v in [
        [1.0, 2.0, 3.0],
        [0.5; 3],
        [0.5; 3],
        [2.0; 3],
        [4.0; 3],
        [1.0; 3],
    ] {
        for c in v {
            f.extend(f64::to_le_bytes(c));
        }
    }
    f.extend(1u32.to_le_bytes()); // buffer count
    f.extend(0f32.to_le_bytes()); // background
    f.extend(0u32.to_le_bytes()); // root tiles
    f.extend(1u32.to_le_bytes()); // root children
    for c in [-4096i32, 0, 0] {
        f.extend(c.to_le_bytes());
    }
    // 5-level node: one child, the 4-level node at local (31, 0, 0).
    mask(&mut f, 32768, |n| n == 31 << 10);
    mask(&mut f, 32768, |_| false);
    values(&mut f, s, &[]);
    // 4-level node: leaves at local (15, 0, 0) and (15, 1, 0), an active tile at (14, 0, 0).
    let (la, lb, tile) = (15 << 8, (15 << 8) | (1 << 4), 14 << 8);
    mask(&mut f, 4096, |n| n == la || n == lb);
    mask(&mut f, 4096, |n| n == tile);
    values(&mut f, s, &[0.25]);
    mask(&mut f, 512, a_on);
    mask(&mut f, 512, b_on);
    let block_pos = f.len();
    let a_vals: Vec<f32> = (0..512)
        .filter(|&n| a_on(n))
        .map(|n| (1 + (n >> 6) + 8 * ((n >> 3) & 7) + 64 * (n & 7)) as f32 / 64.0)
        .collect();
    mask(&mut f, 512, a_on);
    values(&mut f, s, &a_vals);
    mask(&mut f, 512, b_on);
    values(&mut f, s, &[2.0]);
    let end = f.len();
    for (k, v) in [grid_pos, block_pos, end].into_iter().enumerate() {
        f[offsets_at + 8 * k..offsets_at + 8 * k + 8].copy_from_slice(&(v as u64).to_le_bytes());
    }
    f
}

const SYNTHS: [Synth; 5] = [
    Synth {
        compression: 0x2,
        half: false,
    },
    Synth {
        compression: 0x3,
        half: false,
    },
    Synth {
        compression: 0x6,
        half: false,
    },
    Synth {
        compression: 0x6,
        half: true,
    },
    Synth {
        compression: 0x2,
        half: true,
    },
];

/// Every value of the dense copy against the construction, in every codec; the box from the
/// `ScaleTranslateMap` (scale 0.5, translation (1, 2, 3)) over the index bbox (−16, 0, 0)…(−1, 15, 7).
#[test]
fn vdb_synthetic_codecs_tiles_half_floats() {
    for s in SYNTHS {
        let v = decode(&synth_vdb(s), Some("s.vdb")).unwrap_or_else(|e| panic!("{s:?}: {e}"));
        assert_eq!(v.dims, [16, 16, 8], "{s:?}");
        for z in 0..8 {
            for y in 0..16 {
                for x in 0..16 {
                    let g = [x as i64 - 16, y as i64, z as i64];
                    assert_eq!(
                        v.density[v.index(x, y, z)],
                        synth_expected(g),
                        "{s:?} {g:?}"
                    );
                }
            }
        }
        assert_bounds(&v, [-7.25, 1.75, 2.75], [0.75, 9.75, 6.75]);
    }
}

/// Level sets (signed distances), non-float trees and unknown maps: clear refusals naming them.
#[test]
fn vdb_level_sets_other_trees_and_maps_are_refused() {
    let s = SYNTHS[0];
    match vdb_err(&synth_vdb_with(
        s,
        "level set",
        "Tree_float_5_4_3",
        "ScaleTranslateMap",
    )) {
        InputError::Unusable(m) => assert!(m.contains("level set"), "{m}"),
        e => panic!("{e:?}"),
    }
    match vdb_err(&synth_vdb_with(
        s,
        "fog volume",
        "Tree_vec3s_5_4_3",
        "ScaleTranslateMap",
    )) {
        InputError::UnsupportedFormat(m) => assert!(m.contains("Tree_vec3s_5_4_3"), "{m}"),
        e => panic!("{e:?}"),
    }
    match vdb_err(&synth_vdb_with(
        s,
        "fog volume",
        "Tree_float_5_4_3",
        "NonlinearFrustumMap",
    )) {
        InputError::UnsupportedFormat(m) => assert!(m.contains("NonlinearFrustumMap"), "{m}"),
        e => panic!("{e:?}"),
    }
    // An unclassified float grid is read (a density need not be tagged a fog volume).
    let v = decode(
        &synth_vdb_with(s, "unknown", "Tree_float_5_4_3", "ScaleTranslateMap"),
        None,
    );
    assert_eq!(v.unwrap().dims, [16, 16, 8]);
}

/// The bytes of the synthetic file flipped (two patterns) and its truncations: a volume or
/// an error, never a panic.
#[test]
fn vdb_synthetic_every_byte() {
    // A flipped mask bit can add a tile anywhere in a 4096³ node: keep such boxes cheap to refuse.
    let small = VolumeOptions {
        max_voxels: 1 << 16,
        ..opts()
    };
    for (k, s) in SYNTHS.into_iter().enumerate() {
        let b = synth_vdb(s);
        // Every truncation of the zip and the Blosc/half files, a stride through the others.
        let stride = if k == 1 || k == 3 { 1 } else { 7 };
        for len in (0..b.len()).step_by(stride) {
            vdb_err(&b[..len]);
        }
        let mut c = b.clone();
        // The 5-level node's 8 KiB of masks (bytes ~370…8560, all alike) at a stride; every
        // other byte — header, transform, root, 4-level node, leaves, codec frames — each.
        let n = c.len();
        let places = (0..n).filter(|&i| i < 600 || i + 2600 > n || i % 13 == 0);
        for i in places {
            for x in [0xffu8, 0x01] {
                c[i] ^= x;
                if let Err(e) = decode_volume(&c, Some("s.vdb"), &small) {
                    assert!(!e.to_string().contains("panicked"), "{s:?} @{i}: {e}");
                }
                c[i] ^= x;
            }
        }
    }
}
