//! Content-addressed blob storage and small JSON records under the data directory.
//!
//! Layout (all under `data_dir`):
//! ```text
//! blobs/sha256/ab/abcdef…   input assets and job outputs, named by the SHA-256 of their bytes
//! assets/<sha256>.json      asset metadata (file name, size, last use)
//! jobs/<id>.json            job records (see `jobs::record`)
//! tmp/                      staging for atomic writes (same file system, then rename)
//! ```
//! Every write goes to `tmp/` first, is fsynced, then renamed into place, so a crash never leaves a
//! half-written blob or record under its final name. Blobs are immutable: writing a blob that exists
//! is a no-op, which makes re-running a job idempotent.

pub mod assets;

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

/// The on-disk store. Cheap to clone (just paths); all methods are blocking file I/O, to be called
/// from `spawn_blocking` or worker threads.
#[derive(Debug, Clone)]
pub struct Store {
    root: PathBuf,
}

impl Store {
    /// Opens (creating if needed) the store under `root`.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        for sub in ["blobs/sha256", "assets", "jobs", "clouds", "tmp"] {
            let p = root.join(sub);
            std::fs::create_dir_all(&p).map_err(io(&p))?;
        }
        Ok(Self {
            root: root.to_path_buf(),
        })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Path of the blob with this digest (which must be validated hex).
    pub fn blob_path(&self, sha: &str) -> PathBuf {
        let prefix = sha.get(..2).unwrap_or("00");
        self.root.join("blobs/sha256").join(prefix).join(sha)
    }

    pub fn has_blob(&self, sha: &str) -> bool {
        is_sha256_hex(sha) && self.blob_path(sha).is_file()
    }

    /// Stores `bytes`, returning their SHA-256. Idempotent.
    pub fn put_blob(&self, bytes: &[u8]) -> Result<String, StoreError> {
        let sha = sha256_hex(bytes);
        let path = self.blob_path(&sha);
        if !path.is_file() {
            self.write_atomic(&path, bytes)?;
        }
        Ok(sha)
    }

    pub fn read_blob(&self, sha: &str) -> Result<Vec<u8>, StoreError> {
        let path = self.blob_path(sha);
        std::fs::read(&path).map_err(io(&path))
    }

    /// Size in bytes of a stored blob.
    pub fn blob_size(&self, sha: &str) -> Result<u64, StoreError> {
        let path = self.blob_path(sha);
        Ok(std::fs::metadata(&path).map_err(io(&path))?.len())
    }

    /// Writes `bytes` to `path` atomically: a temp file in `tmp/`, fsync, rename.
    pub fn write_atomic(&self, path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
        let tmp_dir = self.root.join("tmp");
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(io(parent))?;
        }
        let mut tmp = tempfile::NamedTempFile::new_in(&tmp_dir).map_err(io(&tmp_dir))?;
        tmp.write_all(bytes).map_err(io(path))?;
        tmp.as_file().sync_all().map_err(io(path))?;
        tmp.persist(path).map_err(|e| StoreError::Io {
            path: path.to_path_buf(),
            source: e.error,
        })?;
        Ok(())
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

    /// Removes blobs not in `keep` and older than `min_age` (so blobs being written by a job that
    /// has not yet recorded them survive). Returns (files removed, bytes freed).
    pub fn sweep_blobs(
        &self,
        keep: &std::collections::HashSet<String>,
        min_age: std::time::Duration,
    ) -> Result<(u64, u64), StoreError> {
        let dir = self.root.join("blobs/sha256");
        let mut removed = (0u64, 0u64);
        let now = std::time::SystemTime::now();
        for prefix in std::fs::read_dir(&dir).map_err(io(&dir))? {
            let prefix = prefix.map_err(io(&dir))?.path();
            let Ok(entries) = std::fs::read_dir(&prefix) else {
                continue;
            };
            for entry in entries.flatten() {
                let name = entry.file_name().to_string_lossy().into_owned();
                if keep.contains(&name) {
                    continue;
                }
                let Ok(meta) = entry.metadata() else { continue };
                let old = meta
                    .modified()
                    .ok()
                    .and_then(|m| now.duration_since(m).ok())
                    .is_some_and(|age| age >= min_age);
                if old && std::fs::remove_file(entry.path()).is_ok() {
                    removed.0 += 1;
                    removed.1 += meta.len();
                }
            }
        }
        Ok(removed)
    }

    /// Total bytes held in blobs (for the `phenomena_store_bytes` gauge).
    pub fn blob_bytes(&self) -> u64 {
        let dir = self.root.join("blobs/sha256");
        let Ok(prefixes) = std::fs::read_dir(&dir) else {
            return 0;
        };
        prefixes
            .flatten()
            .filter_map(|p| std::fs::read_dir(p.path()).ok())
            .flat_map(|d| d.flatten())
            .filter_map(|e| e.metadata().ok())
            .map(|m| m.len())
            .sum()
    }

    /// Checks that the store is writable (readiness).
    pub fn probe(&self) -> bool {
        let dir = self.root.join("tmp");
        tempfile::NamedTempFile::new_in(&dir)
            .and_then(|mut f| f.write_all(b"ok"))
            .is_ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blobs_are_content_addressed_and_idempotent() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let a = store.put_blob(b"hello").unwrap();
        assert_eq!(
            a,
            "2cf24dba5fb0a30e26e83b2ac5b9e29e1b161e5c1fa7425e73043362938b9824"
        );
        assert_eq!(store.put_blob(b"hello").unwrap(), a);
        assert_eq!(store.read_blob(&a).unwrap(), b"hello");
        assert_eq!(store.blob_size(&a).unwrap(), 5);
        assert!(store.has_blob(&a));
        assert!(!store.has_blob("../../etc/passwd"));
    }

    #[test]
    fn sweep_keeps_referenced_blobs() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let a = store.put_blob(b"keep").unwrap();
        let b = store.put_blob(b"drop").unwrap();
        let keep = [a.clone()].into_iter().collect();
        let (n, bytes) = store.sweep_blobs(&keep, std::time::Duration::ZERO).unwrap();
        assert_eq!((n, bytes), (1, 4));
        assert!(store.has_blob(&a));
        assert!(!store.has_blob(&b));
    }
}
