//! Density-volume readers (SPEC §3 input): the real volumes of `shared/data/volume` against the
//! figures of its README and against each other (the NRRD is a dense copy of the VDB's active
//! box, the Blosc VDB the same grid as the uncompressed one), files written here for every NumPy
//! dtype and NRRD variant, and bad input of every format — each an error, never a panic.

use std::io::Write;
use std::sync::OnceLock;

use phenomena_engine::formats::volume::{decode_volume, VolumeOptions};
use phenomena_engine::geom::volume::Volume;
use phenomena_engine::InputError;

mod synthetic_vdb;

fn data(name: &str) -> Option<&'static [u8]> {
    static FILES: OnceLock<Vec<(String, Option<Vec<u8>>)>> = OnceLock::new();
    let files = FILES.get_or_init(|| {
        [
            "openvdb_smoke_density.vdb",
            "openvdb_smoke.vdb",
            "openvdb_smoke_density.nrrd",
            "cgal_skull_ct_64.nrrd",
            "bunny_fog_density.vdb",
            "smoke-blosc.nvdb",
        ]
        .iter()
        .map(|n| {
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../shared/data/volume")
                .join(n);
            (n.to_string(), std::fs::read(path).ok())
        })
        .collect()
    });
    let found = files.iter().find(|(n, _)| n == name)?.1.as_deref();
    if found.is_none() {
        eprintln!("shared/data/volume/{name} missing: skipped");
    }
    found
}

fn opts() -> VolumeOptions {
    VolumeOptions::default()
}

fn decode(bytes: &[u8], name: Option<&str>) -> Result<Volume, InputError> {
    decode_volume(bytes, name, &opts())
}

/// Each real file decoded once for all tests.
fn real(name: &'static str) -> Option<&'static Volume> {
    static SMOKE_VDB: OnceLock<Option<Volume>> = OnceLock::new();
    static SMOKE_BLOSC: OnceLock<Option<Volume>> = OnceLock::new();
    static SMOKE_NRRD: OnceLock<Option<Volume>> = OnceLock::new();
    static SKULL: OnceLock<Option<Volume>> = OnceLock::new();
    static BUNNY: OnceLock<Option<Volume>> = OnceLock::new();
    let cell = match name {
        "openvdb_smoke_density.vdb" => &SMOKE_VDB,
        "openvdb_smoke.vdb" => &SMOKE_BLOSC,
        "openvdb_smoke_density.nrrd" => &SMOKE_NRRD,
        "cgal_skull_ct_64.nrrd" => &SKULL,
        "bunny_fog_density.vdb" => &BUNNY,
        _ => unreachable!(),
    };
    cell.get_or_init(|| data(name).map(|b| decode(b, Some(name)).unwrap()))
        .as_ref()
}

fn nonzero(v: &Volume) -> usize {
    v.density.iter().filter(|&&d| d > 0.0).count()
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

fn assert_bounds(v: &Volume, lo: [f64; 3], hi: [f64; 3]) {
    for k in 0..3 {
        assert!(
            close(v.bounds.0[k], lo[k], 1e-9),
            "{:?} vs {lo:?}",
            v.bounds
        );
        assert!(
            close(v.bounds.1[k], hi[k], 1e-9),
            "{:?} vs {hi:?}",
            v.bounds
        );
    }
}

// ---- real volumes --------------------------------------------------------------------------------

/// README: active bbox 111×222×112, 1,049,275 active voxels, 1e-5 … 5.715; the dense copy has mean
/// 0.062 and 38 % non-zero. The sum 171 499.70 is what `vdb-rs` 0.6 (an independent reader, tried
/// during development) gives over the same grid's active voxels.
#[test]
fn smoke_vdb_uncompressed() {
    let Some(v) = real("openvdb_smoke_density.vdb") else {
        return;
    };
    assert_eq!(v.dims, [111, 222, 112]);
    assert_eq!(nonzero(v), 1_049_275);
    let (min, max, mean) = v.stats();
    assert_eq!(min, 0.0);
    assert!(close(f64::from(max), 5.7148, 1e-3), "{max}");
    assert!(close(mean, 0.0621, 5e-4), "{mean}");
    let sum: f64 = v.density.iter().map(|&d| f64::from(d)).sum();
    assert!(close(sum, 171_499.70, 0.05), "{sum}");
    let frac = nonzero(v) as f64 / v.len() as f64;
    assert!(close(frac, 0.38, 0.005), "{frac}");
    // Index bbox min (1, 2, 1), unit voxels: centres at integer indices.
    assert_bounds(v, [0.5, 1.5, 0.5], [111.5, 223.5, 112.5]);
    // The smallest active value is the README's 1e-5.
    let smallest = v
        .density
        .iter()
        .copied()
        .filter(|&d| d > 0.0)
        .fold(f32::MAX, f32::min);
    assert!(close(f64::from(smallest), 1e-5, 1e-6), "{smallest}");
}

#[test]
fn smoke_blosc_vdb_equals_uncompressed() {
    let (Some(a), Some(b)) = (real("openvdb_smoke_density.vdb"), real("openvdb_smoke.vdb")) else {
        return;
    };
    assert_eq!(a.dims, b.dims);
    assert_eq!(a.bounds, b.bounds);
    assert!(
        a.density == b.density,
        "Blosc and uncompressed grids differ"
    );
}

/// The NRRD is a dense copy of the VDB's active bbox: same grid voxel for voxel, same box (its
/// `space origin` is the bbox minimum, its directions the unit voxel).
#[test]
fn smoke_nrrd_equals_vdb() {
    let (Some(n), Some(v)) = (
        real("openvdb_smoke_density.nrrd"),
        real("openvdb_smoke_density.vdb"),
    ) else {
        return;
    };
    assert_eq!(n.dims, [111, 222, 112]);
    assert_eq!(n.bounds, v.bounds);
    let diff = n.density.iter().zip(&v.density).position(|(a, b)| a != b);
    assert_eq!(diff, None, "first differing voxel");
}

/// 64³ CT-like field; figures from a separate pass over the file's floats: 2.17e-13 … 5.4288,
/// mean 0.59621, no negatives. `space directions` (3.94305, 3.94305, 3.65079), origin 0.
#[test]
fn skull_nrrd() {
    let Some(v) = real("cgal_skull_ct_64.nrrd") else {
        return;
    };
    assert_eq!(v.dims, [64, 64, 64]);
    let (min, max, mean) = v.stats();
    assert!(min > 0.0 && min < 1e-12, "{min}");
    assert!(close(f64::from(max), 5.428_802, 1e-5), "{max}");
    assert!(close(mean, 0.596_213, 1e-5), "{mean}");
    let (h, hz) = (3.94305, 3.65079);
    assert_bounds(
        v,
        [-0.5 * h, -0.5 * h, -0.5 * hz],
        [63.5 * h, 63.5 * h, 63.5 * hz],
    );
}

/// 121×121×95 fog volume: 363,908 active voxels (the file's `file_voxel_count`), of which
/// 299 active 8³ tiles at the 4-level nodes, the rest in leaves; values in (0, 1].
#[test]
fn bunny_vdb() {
    let Some(v) = real("bunny_fog_density.vdb") else {
        return;
    };
    assert_eq!(v.dims, [121, 121, 95]);
    assert_eq!(nonzero(v), 363_908);
    let (min, max, _) = v.stats();
    assert_eq!(min, 0.0);
    assert_eq!(max, 1.0);
    let s = 0.008_181_795_477_867_126;
    assert_bounds(
        v,
        [-60.5 * s, -60.5 * s, -47.5 * s],
        [60.5 * s, 60.5 * s, 47.5 * s],
    );
}

#[test]
fn nanovdb_is_refused_clearly() {
    let Some(b) = data("smoke-blosc.nvdb") else {
        return;
    };
    match decode(b, Some("smoke-blosc.nvdb")) {
        Err(InputError::UnsupportedFormat(m)) => assert!(m.contains("NanoVDB"), "{m}"),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        decode(b"whatever", Some("x.nvdb")),
        Err(InputError::UnsupportedFormat(_))
    ));
}

#[test]
fn caller_bounds_override_the_file() {
    let Some(b) = data("cgal_skull_ct_64.nrrd") else {
        return;
    };
    let bounds = ([-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]);
    let o = VolumeOptions {
        bounds: Some(bounds),
        ..opts()
    };
    assert_eq!(decode_volume(b, None, &o).unwrap().bounds, bounds);
    let bad = VolumeOptions {
        bounds: Some(([0.0; 3], [1.0, 0.0, 1.0])),
        ..opts()
    };
    assert!(matches!(
        decode_volume(b, None, &bad),
        Err(InputError::Param(_))
    ));
}

#[test]
fn max_voxels_refuses_real_files_before_decoding() {
    for (name, voxels) in [
        ("openvdb_smoke_density.vdb", 111 * 222 * 112),
        ("openvdb_smoke.vdb", 111 * 222 * 112),
        ("openvdb_smoke_density.nrrd", 111 * 222 * 112),
        ("bunny_fog_density.vdb", 121 * 121 * 95),
    ] {
        let Some(b) = data(name) else { continue };
        let o = VolumeOptions {
            max_voxels: voxels - 1,
            ..opts()
        };
        match decode_volume(b, Some(name), &o) {
            Err(InputError::TooLarge { actual, .. }) => assert_eq!(actual, voxels, "{name}"),
            other => panic!("{name}: {other:?}"),
        }
    }
}

// ---- NumPy ---------------------------------------------------------------------------------------

const DIMS: [usize; 3] = [5, 4, 3];

/// The test field: distinct small integers, exact in every dtype.
fn field(x: usize, y: usize, z: usize) -> f64 {
    (x + 5 * y + 20 * z) as f64
}

fn npy(descr: &str, fortran: bool, shape: &[usize], body: &[u8]) -> Vec<u8> {
    let shape_txt = match shape {
        [a] => format!("({a},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!(
        "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape_txt}, }}",
        if fortran { "True" } else { "False" }
    );
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((header.len() as u16).to_le_bytes());
    out.extend(header.as_bytes());
    out.extend(body);
    out
}

/// `[z, y, x]` elements in C order (or Fortran order), encoded by `enc`.
fn npy_field(descr: &str, fortran: bool, enc: impl Fn(f64) -> Vec<u8>) -> Vec<u8> {
    let [nx, ny, nz] = DIMS;
    let mut body = Vec::new();
    if fortran {
        for x in 0..nx {
            for y in 0..ny {
                for z in 0..nz {
                    body.extend(enc(field(x, y, z)));
                }
            }
        }
    } else {
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    body.extend(enc(field(x, y, z)));
                }
            }
        }
    }
    npy(descr, fortran, &[nz, ny, nx], &body)
}

fn check_field(v: &Volume) {
    assert_eq!(v.dims, DIMS);
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                assert_eq!(
                    f64::from(v.density[v.index(x, y, z)]),
                    field(x, y, z),
                    "({x},{y},{z})"
                );
            }
        }
    }
    assert_eq!(v.bounds, Volume::default_bounds(DIMS));
}

#[test]
fn npy_every_dtype_both_orders() {
    type Enc = fn(f64) -> Vec<u8>;
    let cases: [(&str, Enc); 7] = [
        ("<f4", |v| (v as f32).to_le_bytes().to_vec()),
        (">f4", |v| (v as f32).to_be_bytes().to_vec()),
        ("<f8", |v| v.to_le_bytes().to_vec()),
        (">f8", |v| v.to_be_bytes().to_vec()),
        ("|u1", |v| vec![v as u8]),
        ("<u2", |v| (v as u16).to_le_bytes().to_vec()),
        (">u2", |v| (v as u16).to_be_bytes().to_vec()),
    ];
    for (descr, enc) in cases {
        for fortran in [false, true] {
            let bytes = npy_field(descr, fortran, enc);
            let v = decode(&bytes, None).unwrap_or_else(|e| panic!("{descr} {fortran}: {e}"));
            check_field(&v);
            // The same bytes named .npy decode identically.
            assert_eq!(decode(&bytes, Some("a.npy")).unwrap(), v);
        }
    }
}

#[test]
fn npy_refusals() {
    let f4 = |n: usize| vec![0u8; 4 * n];
    let err = |b: &[u8]| decode(b, Some("v.npy")).unwrap_err();
    // 2-D and 4-D arrays: clear "3-D" message.
    for shape in [&[4usize, 5][..], &[2, 3, 4, 5][..], &[7][..]] {
        let n = shape.iter().product();
        match err(&npy("<f4", false, shape, &f4(n))) {
            InputError::Unusable(m) => assert!(m.contains("3-D"), "{m}"),
            e => panic!("{shape:?}: {e:?}"),
        }
    }
    // Absurd shapes: refused before allocation, overflow included.
    for shape in [[100_000usize, 100_000, 100_000], [usize::MAX / 2, 4, 1]] {
        assert!(
            matches!(
                err(&npy("<f4", false, &shape, &f4(8))),
                InputError::TooLarge { .. }
            ),
            "{shape:?}"
        );
    }
    // Truncated data, unsupported and structured dtypes.
    assert!(matches!(
        err(&npy("<f4", false, &[3, 4, 5], &f4(59))),
        InputError::Corrupt { .. }
    ));
    assert!(matches!(
        err(&npy("<i4", false, &[3, 4, 5], &f4(60))),
        InputError::UnsupportedFormat(_)
    ));
    let mut s = npy("<f4", false, &[3, 4, 5], &f4(60));
    let at = s.windows(7).position(|w| w == b"'<f4', ").unwrap();
    s.splice(at..at + 5, b"[('a', '<f4')]".iter().copied());
    assert!(decode(&s, None).is_err());
    // NaN and infinity are refused with the voxel named; negatives clamp to 0.
    let mut vals = vec![1.0f32; 60];
    vals[7] = f32::NAN;
    let b: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
    match err(&npy("<f4", false, &[3, 4, 5], &b)) {
        InputError::Unusable(m) => assert!(m.contains("(2, 1, 0)"), "{m}"),
        e => panic!("{e:?}"),
    }
    vals[7] = f32::NEG_INFINITY;
    let b: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
    assert!(matches!(
        err(&npy("<f4", false, &[3, 4, 5], &b)),
        InputError::Unusable(_)
    ));
    vals[7] = -2.5;
    let b: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
    let v = decode(&npy("<f4", false, &[3, 4, 5], &b), None).unwrap();
    assert_eq!(v.density[7], 0.0);
    assert_eq!(v.density.iter().filter(|&&d| d == 1.0).count(), 59);
}

// ---- raw -----------------------------------------------------------------------------------------

#[test]
fn raw_float32_needs_exact_dims() {
    let [nx, ny, nz] = DIMS;
    let mut body = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                body.extend((field(x, y, z) as f32).to_le_bytes());
            }
        }
    }
    let with = |dims: Option<[usize; 3]>| VolumeOptions { dims, ..opts() };
    check_field(&decode_volume(&body, Some("v.raw"), &with(Some(DIMS))).unwrap());
    // Unrecognised bytes with dims are raw too.
    check_field(&decode_volume(&body, None, &with(Some(DIMS))).unwrap());
    check_field(&decode_volume(&body, Some("cloud.bin"), &with(Some(DIMS))).unwrap());
    // Wrong dims, a byte too many or too few.
    for dims in [[5, 4, 2], [4, 5, 4], [60, 1, 2]] {
        assert!(matches!(
            decode_volume(&body, Some("v.raw"), &with(Some(dims))),
            Err(InputError::Corrupt { .. })
        ));
    }
    for len in [body.len() - 1, body.len() + 1, 0] {
        let mut b = body.clone();
        b.resize(len, 0);
        assert!(
            decode_volume(&b, Some("v.raw"), &with(Some(DIMS))).is_err(),
            "{len}"
        );
    }
    // No dims: a .raw asks for them, unknown bytes are an unsupported format.
    assert!(matches!(
        decode_volume(&body, Some("v.raw"), &opts()),
        Err(InputError::Param(_))
    ));
    assert!(matches!(
        decode_volume(&body, None, &opts()),
        Err(InputError::UnsupportedFormat(_))
    ));
    assert!(matches!(
        decode_volume(&body, None, &with(Some([0, 4, 3]))),
        Err(InputError::Param(_))
    ));
    // Absurd dims: too large before anything else.
    assert!(matches!(
        decode_volume(&body, None, &with(Some([1 << 20, 1 << 20, 1 << 20]))),
        Err(InputError::TooLarge { .. })
    ));
    assert!(matches!(
        decode_volume(&body, None, &with(Some([usize::MAX, 2, 2]))),
        Err(InputError::TooLarge { .. })
    ));
}

// ---- NRRD ----------------------------------------------------------------------------------------

fn gzip(b: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(b).unwrap();
    e.finish().unwrap()
}

fn nrrd(fields: &str, body: &[u8]) -> Vec<u8> {
    let mut out = format!("NRRD0004\n# written by the test\n{fields}\n").into_bytes();
    out.extend(body);
    out
}

/// The test field as NRRD samples of one type.
fn nrrd_field(ty: &str, endian: &str, enc: impl Fn(f64) -> Vec<u8>) -> Vec<u8> {
    let [nx, ny, nz] = DIMS;
    let mut body = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                body.extend(enc(field(x, y, z)));
            }
        }
    }
    nrrd(
        &format!(
            "type: {ty}\ndimension: 3\nsizes: {nx} {ny} {nz}\nendian: {endian}\nencoding: raw\n"
        ),
        &body,
    )
}

#[test]
fn nrrd_types_and_encodings() {
    type Enc = fn(f64) -> Vec<u8>;
    let cases: [(&str, &str, Enc); 8] = [
        ("float", "little", |v| (v as f32).to_le_bytes().to_vec()),
        ("float", "big", |v| (v as f32).to_be_bytes().to_vec()),
        ("double", "little", |v| v.to_le_bytes().to_vec()),
        ("uchar", "little", |v| vec![v as u8]),
        ("unsigned short", "big", |v| {
            (v as u16).to_be_bytes().to_vec()
        }),
        ("short", "little", |v| (v as i16).to_le_bytes().to_vec()),
        ("int", "big", |v| (v as i32).to_be_bytes().to_vec()),
        ("uint32", "little", |v| (v as u32).to_le_bytes().to_vec()),
    ];
    for (ty, endian, enc) in cases {
        let raw = nrrd_field(ty, endian, enc);
        let v = decode(&raw, None).unwrap_or_else(|e| panic!("{ty} {endian}: {e}"));
        check_field(&v);
        // gzip: the same header with `encoding: gzip` and the body compressed.
        let split = raw.windows(2).position(|w| w == b"\n\n").unwrap() + 2;
        let head = String::from_utf8(raw[..split].to_vec()).unwrap();
        let mut gz = head.replace("encoding: raw", "encoding: gzip").into_bytes();
        gz.extend(gzip(&raw[split..]));
        check_field(&decode(&gz, Some("v.nrrd")).unwrap());
    }
    // ascii, CRLF line ends, key/value pairs and comments.
    let mut text = String::new();
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                text.push_str(&format!("{} ", field(x, y, z)));
            }
            text.push('\n');
        }
    }
    let b = nrrd(
        "type: float\r\ndimension: 3\r\nsizes: 5 4 3\r\nauthor:=me\r\n# c\r\nencoding: text\r\n",
        text.as_bytes(),
    );
    let b: Vec<u8> = String::from_utf8(b)
        .unwrap()
        .replacen("\r\n\n", "\r\n\r\n", 1)
        .into_bytes();
    check_field(&decode(&b, None).unwrap());
}

#[test]
fn nrrd_geometry_gives_bounds() {
    let body: Vec<u8> = (0..60).flat_map(|i| (i as f32).to_le_bytes()).collect();
    let head = "type: float\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: raw\n";
    // spacings without an origin: first sample centre at 0.
    let v = decode(&nrrd(&format!("{head}spacings: 2 1 0.5\n"), &body), None).unwrap();
    assert_bounds(&v, [-1.0, -0.5, -0.25], [9.0, 3.5, 1.25]);
    // space directions + origin.
    let geo = "space dimension: 3\nspace directions: (2,0,0) (0,1,0) (0,0,0.5)\nspace origin: (10,20,30)\n";
    let v = decode(&nrrd(&format!("{head}{geo}"), &body), None).unwrap();
    assert_bounds(&v, [9.0, 19.5, 29.75], [19.0, 23.5, 31.25]);
    assert_eq!(v.density[0], 0.0);
    // A negative x step flips the grid so it runs towards +x; the box is the same region.
    let geo = "space directions: (-2,0,0) (0,1,0) (0,0,0.5)\nspace origin: (10,20,30)\n";
    let v = decode(&nrrd(&format!("{head}{geo}"), &body), None).unwrap();
    assert_bounds(&v, [1.0, 19.5, 29.75], [11.0, 23.5, 31.25]);
    assert_eq!(v.density[v.index(4, 0, 0)], 0.0);
    assert_eq!(v.density[v.index(0, 0, 0)], 4.0);
    assert_eq!(v.density[v.index(0, 1, 2)], 4.0 + 5.0 + 40.0);
    // Oblique directions: the physical aspect with the default placement (longest side 1).
    let geo = "space directions: (0,2,0) (1,0,0) (0,0,0.5)\nspace origin: (10,20,30)\n";
    let v = decode(&nrrd(&format!("{head}{geo}"), &body), None).unwrap();
    assert_bounds(&v, [-0.5, 0.0, -0.075], [0.5, 0.4, 0.075]);
    // `none` directions or NaN spacings: the default box.
    let v = decode(
        &nrrd(&format!("{head}spacings: nan nan nan\n"), &body),
        None,
    )
    .unwrap();
    assert_eq!(v.bounds, Volume::default_bounds([5, 4, 3]));
}

fn nrrd_err(b: &[u8]) -> InputError {
    let e = decode(b, Some("v.nrrd")).unwrap_err();
    assert!(!e.to_string().contains("panicked"), "{e}");
    e
}

#[test]
fn nrrd_refusals() {
    let body = vec![0u8; 240];
    let ok = "type: float\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: raw\n";
    assert!(decode(&nrrd(ok, &body), None).is_ok());
    let with = |from: &str, to: &str| nrrd(&ok.replace(from, to), &body);
    match nrrd_err(&with(
        "encoding: raw\n",
        "encoding: raw\ndata file: v.raw\n",
    )) {
        InputError::UnsupportedFormat(m) => assert!(m.contains("detached"), "{m}"),
        e => panic!("{e:?}"),
    }
    match nrrd_err(&with(
        "dimension: 3\nsizes: 5 4 3",
        "dimension: 4\nsizes: 1 5 4 3",
    )) {
        InputError::Unusable(m) => assert!(m.contains("dimension 4"), "{m}"),
        e => panic!("{e:?}"),
    }
    assert!(matches!(
        nrrd_err(&with("raw", "bzip2")),
        InputError::UnsupportedFormat(_)
    ));
    assert!(matches!(
        nrrd_err(&with("float", "block")),
        InputError::UnsupportedFormat(_)
    ));
    assert!(matches!(
        nrrd_err(&with("endian: little\n", "")),
        InputError::Corrupt { .. }
    ));
    assert!(matches!(
        nrrd_err(&with("sizes: 5 4 3", "sizes: 5 4")),
        InputError::Corrupt { .. }
    ));
    assert!(matches!(
        nrrd_err(&with("sizes: 5 4 3", "sizes: 5 4 x")),
        InputError::Corrupt { .. }
    ));
    assert!(matches!(
        nrrd_err(&with("sizes: 5 4 3", "sizes: 5 0 3")),
        InputError::Unusable(_)
    ));
    for huge in [
        "sizes: 100000 100000 100000",
        "sizes: 18446744073709551615 2 2",
    ] {
        assert!(matches!(
            nrrd_err(&with("sizes: 5 4 3", huge)),
            InputError::TooLarge { .. }
        ));
    }
    // A header that never ends (detached .nhdr or truncated).
    assert!(matches!(
        nrrd_err(ok.as_bytes()),
        InputError::Corrupt { .. }
    ));
    // gzip: short stream, garbage, and a zip bomb (10 MB of zeros for a 240-byte volume) that is
    // refused after inflating 241 bytes.
    let gz = |payload: &[u8]| nrrd(&ok.replace("raw", "gzip"), payload);
    assert!(matches!(
        nrrd_err(&gz(&gzip(&body[..239]))),
        InputError::Corrupt { .. }
    ));
    assert!(matches!(
        nrrd_err(&gz(b"not gzip at all")),
        InputError::Corrupt { .. }
    ));
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    e.write_all(&vec![0u8; 10 << 20]).unwrap();
    let bomb = e.finish().unwrap();
    assert!(bomb.len() < 20_000);
    let t = std::time::Instant::now();
    match nrrd_err(&gz(&bomb)) {
        InputError::Corrupt { detail, .. } => assert!(detail.contains("more than"), "{detail}"),
        e => panic!("{e:?}"),
    }
    assert!(t.elapsed().as_millis() < 50, "{:?}", t.elapsed());
}

#[test]
fn nrrd_truncations_and_flips() {
    let b = nrrd_field("float", "little", |v| (v as f32).to_le_bytes().to_vec());
    for len in 0..b.len() {
        nrrd_err(&b[..len]);
    }
    let mut gz = String::from_utf8(b[..b.len() - 240].to_vec())
        .unwrap()
        .replace("raw", "gzip")
        .into_bytes();
    gz.extend(gzip(&b[b.len() - 240..]));
    for len in 0..gz.len() {
        nrrd_err(&gz[..len]);
    }
    // Every byte of the header flipped: an error or a volume, never a panic.
    let split = b.windows(2).position(|w| w == b"\n\n").unwrap() + 2;
    for i in 0..split {
        for flip in [0x01u8, 0x20, 0x80] {
            let mut c = b.clone();
            c[i] ^= flip;
            if let Err(e) = decode(&c, Some("v.nrrd")) {
                assert!(!e.to_string().contains("panicked"), "{e}");
            }
        }
    }
}

// ---- OpenVDB -------------------------------------------------------------------------------------

fn vdb_err(b: &[u8]) -> InputError {
    let e = decode(b, Some("v.vdb")).unwrap_err();
    assert!(!e.to_string().contains("panicked"), "{e}");
    e
}

/// Truncations at many lengths (every byte of the header and the start of the topology, then a
/// stride through the rest) of the tiled bunny and the Blosc smoke: each an error.
#[test]
fn vdb_truncations() {
    for name in ["bunny_fog_density.vdb", "openvdb_smoke.vdb"] {
        let Some(b) = data(name) else { continue };
        let lens = (0..4096).chain((4096..b.len()).step_by(b.len() / 24));
        for len in lens.chain([b.len() - 1]) {
            vdb_err(&b[..len]);
        }
    }
}

/// Absurd values and flipped bits at a spread of places in the real files (header, descriptor,
/// metadata, transform, root, node masks, Blosc lengths and frames): a volume or an error, never a
/// panic. The synthetic file below is fuzzed at every byte; these full-size decodes are slower.
#[test]
fn vdb_flipped_and_absurd_bytes() {
    for name in ["bunny_fog_density.vdb", "openvdb_smoke.vdb"] {
        let Some(b) = data(name) else { continue };
        let o = VolumeOptions {
            max_voxels: 1 << 22, // both files fit (2.8 M and 1.4 M voxels); flipped boxes stay cheap
            ..opts()
        };
        let mut c = b.to_vec();
        // The Blosc smoke takes ~4× the bunny's time per decode: fewer places there.
        let (head, body) = if name.starts_with("bunny") {
            (61, 12)
        } else {
            (199, 5)
        };
        let positions = (8..1024)
            .step_by(head)
            .chain((1024..b.len()).step_by(b.len() / body));
        for i in positions {
            let end = (i + 4).min(c.len());
            let saved: Vec<u8> = c[i..end].to_vec();
            c[i..end].copy_from_slice(&[0x7f, 0xff, 0xff, 0xff][..end - i]);
            if let Err(e) = decode_volume(&c, Some(name), &o) {
                assert!(!e.to_string().contains("panicked"), "{name} @{i}: {e}");
            }
            c[i..end].copy_from_slice(&saved);
            c[i] ^= 0x10;
            if let Err(e) = decode_volume(&c, Some(name), &o) {
                assert!(!e.to_string().contains("panicked"), "{name} @{i}: {e}");
            }
            c[i] ^= 0x10;
        }
    }
}

#[test]
fn vdb_version_and_sniffing() {
    let Some(b) = data("bunny_fog_density.vdb") else {
        return;
    };
    // Magic bytes win over a wrong name.
    assert_eq!(decode(b, Some("bunny.npy")).unwrap().dims, [121, 121, 95]);
    assert_eq!(decode(b, None).unwrap().dims, [121, 121, 95]);
    let mut old = b.to_vec();
    old[8..12].copy_from_slice(&221u32.to_le_bytes());
    match vdb_err(&old) {
        InputError::UnsupportedFormat(m) => assert!(m.contains("221"), "{m}"),
        e => panic!("{e:?}"),
    }
    // A .vdb name on other bytes: a corrupt OpenVDB file.
    assert!(matches!(
        vdb_err(b"NOT A VDB FILE AT ALL"),
        InputError::Corrupt { .. }
    ));
}
