//! Reference-image comparison (STYLE habit 8): `tests/golden/<pipeline>/<case>.png` at the
//! repository root, compared per channel with a stated tolerance; on failure a diff image is
//! written under `target/golden-diff/`. `BLESS=1` regenerates the references locally (never on CI).

use std::path::PathBuf;

use phenomena_engine::formats::png_write::encode_rgba;
use phenomena_engine::render::image::RgbaImage;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

pub(crate) fn decode_png(bytes: &[u8]) -> RgbaImage {
    let mut dec = png::Decoder::new(std::io::Cursor::new(bytes));
    dec.set_transformations(png::Transformations::EXPAND);
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(
        info.color_type,
        png::ColorType::Rgba,
        "golden images are RGBA"
    );
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    buf.truncate(info.buffer_size());
    RgbaImage {
        width: info.width,
        height: info.height,
        data: buf,
    }
}

/// Compares `img` with the reference: every channel within `tol` (0–255) except at most
/// `max_outliers` (a fraction of pixels) that may differ more — ray-cast silhouettes can flip a
/// few edge pixels between CPUs with different FMA contraction.
pub fn assert_golden(pipeline: &str, case: &str, img: &RgbaImage, tol: u8, max_outliers: f64) {
    let path = root()
        .join("tests/golden")
        .join(pipeline)
        .join(format!("{case}.png"));
    if std::env::var_os("BLESS").is_some() && std::env::var_os("CI").is_none() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, encode_rgba(img)).unwrap();
        return;
    }
    let bytes = std::fs::read(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (run with BLESS=1 to create it)", path.display()));
    let reference = decode_png(&bytes);
    assert_eq!(
        (img.width, img.height),
        (reference.width, reference.height),
        "{case}: size"
    );
    let mut diff = RgbaImage {
        width: img.width,
        height: img.height,
        data: vec![0; img.data.len()],
    };
    let mut outliers = 0usize;
    let mut worst = 0u8;
    for (i, (a, b)) in img.data.chunks(4).zip(reference.data.chunks(4)).enumerate() {
        let d = a
            .iter()
            .zip(b)
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0);
        worst = worst.max(d);
        if d > tol {
            outliers += 1;
        }
        let v = d.saturating_mul(8);
        diff.data[i * 4..i * 4 + 4].copy_from_slice(&[v, v, v, 255]);
    }
    let pixels = (img.width * img.height) as usize;
    let share = outliers as f64 / pixels as f64;
    if share > max_outliers {
        let dir = root().join("target/golden-diff");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join(format!("{pipeline}-{case}-actual.png")),
            encode_rgba(img),
        )
        .unwrap();
        std::fs::write(
            dir.join(format!("{pipeline}-{case}-diff.png")),
            encode_rgba(&diff),
        )
        .unwrap();
        panic!(
            "{pipeline}/{case}: {outliers} of {pixels} pixels ({:.3} %) differ by more than {tol} \
             (worst {worst}); allowed {:.3} %. See {}",
            share * 100.0,
            max_outliers * 100.0,
            dir.display()
        );
    }
}
