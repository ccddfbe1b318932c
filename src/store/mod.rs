//! Storage: content-addressed blobs and asset records in object storage ([`blobs`]: a local or
//! shared directory, or S3), and the embedded backend's small JSON records under the data directory.
//!
//! Layout (object store; by default rooted at `data_dir`):
//! ```text
//! blobs/sha256/ab/abcdef…   input assets and job outputs, named by the SHA-256 of their bytes
//! assets/<sha256>.json      asset metadata (file name, size, last use)
//! maps/<id>.json            map records (`POST /v1/maps`); swept with their DEM asset
//! tiles/v<n>/<map>/…         cached map tiles, by map, layer, zoom, column, row and size
//! staging/                  uploads being streamed in, readiness probes
//! ```
//! Local files (always under `data_dir`):
//! ```text
//! jobs/<id>.json            job records of the embedded backend (see `jobs::record`)
//! clouds/<id>.json          cloud scenes of the embedded backend
//! tmp/                      staging for atomic writes (same file system, then rename)
//! ```
//! Every local write goes to `tmp/` first, is fsynced, then renamed into place, so a crash never
//! leaves a half-written record under its final name. Blobs are immutable: writing a blob that
//! exists is a no-op, which makes re-running a job idempotent.

pub mod assets;
mod blobs;
pub use blobs::BlobRanges;
pub mod maps;

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{de::DeserializeOwned, Serialize};
use sha2::{Digest, Sha256};

/// Store failures. Callers map them to 503 (storage unavailable) or 500.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("storage I/O on {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("record {path} is not valid JSON: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("object store: {0}")]
    Object(String),
    #[error("the upload is larger than {max} bytes")]
    TooLarge { max: u64 },
    #[error("the upload was interrupted: {0}")]
    Upload(String),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// A SHA-256 digest as 64 lowercase hex characters.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

/// True for a well-formed SHA-256 hex id (guards every path built from a client-supplied id).
pub fn is_sha256_hex(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// The store: blobs in object storage, records on the local disk. Cheap to clone. Blob methods
/// are async; record methods are blocking file I/O, to be called from `spawn_blocking` or worker
/// threads.
#[derive(Debug, Clone)]
pub struct Store {
    root: PathBuf,
    blobs: blobs::Blobs,
    /// Map sweeps of this process that removed a map (see `Store::sweep_maps`): the maps of
    /// this process forget what they keep in memory when it moves.
    maps_swept: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl Store {
    /// Opens (creating if needed) the store under `root`, with blobs there too.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        Self::open_with(root, None)
    }

    /// Opens the store under `root` with blobs and asset records in the object store at
    /// `blob_url` (`file:///path`, `s3://bucket/prefix`) when given.
    pub fn open_with(root: &Path, blob_url: Option<&str>) -> Result<Self, StoreError> {
        for sub in ["jobs", "clouds", "tmp"] {
            let p = root.join(sub);
            std::fs::create_dir_all(&p).map_err(io(&p))?;
        }
        Ok(Self {
            root: root.to_path_buf(),
            blobs: blobs::open(blob_url, root)?,
            maps_swept: Default::default(),
        })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Writes `bytes` to `path` atomically: a temp file in `tmp/`, fsync, rename.
    pub fn write_atomic(&self, path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
        let tmp_dir = self.root.join("tmp");
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(io(parent))?;
        }
        // Recreated if an operator cleaned it out while the service ran (the blob store no
        // longer shares it: its staging objects live under `staging/`).
        std::fs::create_dir_all(&tmp_dir).map_err(io(&tmp_dir))?;
        let mut tmp = tempfile::NamedTempFile::new_in(&tmp_dir).map_err(io(&tmp_dir))?;
        tmp.write_all(bytes).map_err(io(path))?;
        tmp.as_file().sync_all().map_err(io(path))?;
        tmp.persist(path).map_err(|e| StoreError::Io {
            path: path.to_path_buf(),
            source: e.error,
        })?;
        Ok(())
    }

    /// Checks that the local data directory takes writes (readiness): a small file written,
    /// fsynced and renamed like every record. False when the disk is full or read-only.
    /// Blocking.
    pub fn probe_local(&self) -> bool {
        let path = self
            .root
            .join("tmp")
            .join(format!("probe-{}", hex::encode(rand::random::<[u8; 8]>())));
        let ok = self.write_atomic(&path, b"ok").is_ok();
        let _ = std::fs::remove_file(&path);
        ok
    }

    /// Writes a JSON record atomically.
    pub fn put_json<T: Serialize>(&self, path: &Path, value: &T) -> Result<(), StoreError> {
        let bytes = serde_json::to_vec_pretty(value).map_err(|source| StoreError::Json {
            path: path.to_path_buf(),
            source,
        })?;
        self.write_atomic(path, &bytes)
    }

    pub fn get_json<T: DeserializeOwned>(&self, path: &Path) -> Result<T, StoreError> {
        let bytes = std::fs::read(path).map_err(io(path))?;
        serde_json::from_slice(&bytes).map_err(|source| StoreError::Json {
            path: path.to_path_buf(),
            source,
        })
    }

    /// All JSON records in a sub-directory (`jobs`, `assets`), skipping unreadable ones (logged).
    pub fn list_json<T: DeserializeOwned>(&self, sub: &str) -> Result<Vec<T>, StoreError> {
        let dir = self.root.join(sub);
        let mut out = Vec::new();
        for entry in std::fs::read_dir(&dir).map_err(io(&dir))? {
            let entry = entry.map_err(io(&dir))?;
            let path = entry.path();
            if path.extension().is_some_and(|e| e == "json") {
                match self.get_json(&path) {
                    Ok(v) => out.push(v),
                    Err(e) => tracing::warn!(error = %e, "skipping unreadable record"),
                }
            }
        }
        Ok(out)
    }

    pub fn remove(&self, path: &Path) -> Result<(), StoreError> {
        match std::fs::remove_file(path) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(StoreError::Io {
                path: path.to_path_buf(),
                source: e,
            }),
        }
    }
}

impl From<StoreError> for crate::error::ApiError {
    fn from(e: StoreError) -> Self {
        use crate::error::ApiError;
        match e {
            StoreError::TooLarge { .. } => {
                ApiError::PayloadTooLarge("request body too large".into())
            }
            StoreError::Upload(detail) => {
                ApiError::bad_request(format!("the upload failed: {detail}"))
            }
            e => {
                tracing::error!(error = %e, "store failure");
                ApiError::Unavailable("storage is unavailable; try again later".into())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn blobs_are_content_addressed_and_idempotent() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let a = store
            .put_blob(bytes::Bytes::from_static(b"hello"))
            .await
            .unwrap();
        assert_eq!(
            a,
            "2cf24dba5fb0a30e26e83b2ac5b9e29e1b161e5c1fa7425e73043362938b9824"
        );
        assert_eq!(
            store
                .put_blob(bytes::Bytes::from_static(b"hello"))
                .await
                .unwrap(),
            a
        );
        assert_eq!(store.read_blob(&a).await.unwrap().as_ref(), b"hello");
        assert_eq!(store.blob_size(&a).await.unwrap(), 5);
        assert!(store.has_blob(&a).await);
        assert!(!store.has_blob("../../etc/passwd").await);
        // The local layout: blobs/sha256/<first two hex digits>/<digest>.
        assert!(dir.path().join("blobs/sha256/2c").join(&a).is_file());
    }

    #[tokio::test]
    async fn streamed_uploads_hash_as_they_go_and_respect_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let chunks: Vec<Result<bytes::Bytes, StoreError>> = (0..40)
            .map(|i| Ok(bytes::Bytes::from(vec![i as u8; 100_000])))
            .collect();
        let whole: Vec<u8> = (0..40).flat_map(|i| vec![i as u8; 100_000]).collect();
        let (sha, size) = store
            .put_blob_stream(futures_util::stream::iter(chunks), 10_000_000)
            .await
            .unwrap();
        assert_eq!(size, 4_000_000);
        assert_eq!(sha, sha256_hex(&whole));
        assert_eq!(
            store.read_blob(&sha).await.unwrap().as_ref(),
            whole.as_slice()
        );
        let chunks: Vec<Result<bytes::Bytes, StoreError>> = (0..3)
            .map(|_| Ok(bytes::Bytes::from(vec![1u8; 1000])))
            .collect();
        let r = store
            .put_blob_stream(futures_util::stream::iter(chunks), 2500)
            .await;
        assert!(matches!(r, Err(StoreError::TooLarge { max: 2500 })));
        // Nothing half-written is left under blobs/.
        assert_eq!(store.blob_bytes().await, 4_000_000);
    }

    #[tokio::test]
    async fn sweep_keeps_referenced_blobs() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let a = store
            .put_blob(bytes::Bytes::from_static(b"keep"))
            .await
            .unwrap();
        let b = store
            .put_blob(bytes::Bytes::from_static(b"drop"))
            .await
            .unwrap();
        let keep = [a.clone()].into_iter().collect();
        let (n, bytes) = store
            .sweep_blobs(&keep, std::time::Duration::ZERO)
            .await
            .unwrap();
        assert_eq!((n, bytes), (1, 4));
        assert!(store.has_blob(&a).await);
        assert!(!store.has_blob(&b).await);
    }
}
