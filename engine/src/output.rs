//! Named pipeline outputs.

/// One named output of a pipeline run (`render.png`, `snow_cover.tif`, …), held in memory.
#[derive(Debug, Clone)]
pub struct Output {
    /// File name, unique within a run (`render.png`).
    pub name: String,
    /// IANA media type (`image/png`, `image/tiff`, `model/gltf-binary`, `application/json`).
    pub media_type: &'static str,
    /// The encoded bytes.
    pub bytes: Vec<u8>,
}

impl Output {
    pub fn new(name: impl Into<String>, media_type: &'static str, bytes: Vec<u8>) -> Self {
        Self {
            name: name.into(),
            media_type,
            bytes,
        }
    }
}
