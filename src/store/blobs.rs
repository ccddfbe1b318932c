//! Content-addressed blobs (input assets and job outputs) in object storage through the
//! `object_store` crate: a local directory (the default, `<data_dir>/blobs/…`), a directory shared
//! by replicas, or S3-compatible storage (`s3://bucket/prefix`, credentials and region from the
//! usual `AWS_*` environment variables).
//!
//! A blob is named by the SHA-256 of its bytes (`blobs/sha256/ab/abcdef…`), so writing one that
//! exists is a no-op and a job run twice (after a crash, on another replica) writes the same
//! objects. Every write is atomic: the local store writes a temporary file and renames it, S3's
//! PUT and multipart completion are atomic. Large uploads stream through
//! [`Store::put_blob_stream`] without being held whole in memory.

use std::collections::HashSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use bytes::Bytes;
use futures_util::{Stream, StreamExt, TryStreamExt};
use object_store::path::Path as ObjPath;
use object_store::{ObjectStore, ObjectStoreExt, PutPayload, WriteMultipart};
use sha2::{Digest, Sha256};

use super::{is_sha256_hex, Store, StoreError};

/// Where blobs live.
#[derive(Debug, Clone)]
pub(super) struct Blobs {
    pub objects: Arc<dyn ObjectStore>,
    /// Shown in logs and errors (`file:///data`, `s3://bucket/prefix`).
    pub url: String,
}

fn obj_err(e: object_store::Error) -> StoreError {
    StoreError::Object(e.to_string())
}

/// Opens the object store named by `url` (`file:///path`, `s3://bucket/prefix`), or a local
/// directory under `data_dir` when `url` is `None`.
pub(super) fn open(url: Option<&str>, data_dir: &std::path::Path) -> Result<Blobs, StoreError> {
    let local = |dir: &std::path::Path| -> Result<Blobs, StoreError> {
        std::fs::create_dir_all(dir).map_err(|source| StoreError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let fs = object_store::local::LocalFileSystem::new_with_prefix(dir)
            .map_err(obj_err)?
            .with_automatic_cleanup(true);
        Ok(Blobs {
            objects: Arc::new(fs),
            url: format!("file://{}", dir.display()),
        })
    };
    match url {
        None => local(data_dir),
        Some(u) if u.starts_with("file://") => local(std::path::Path::new(&u["file://".len()..])),
        Some(u) if u.starts_with("s3://") => {
            let rest = &u["s3://".len()..];
            let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
            let s3 = object_store::aws::AmazonS3Builder::from_env()
                .with_bucket_name(bucket)
                .build()
                .map_err(obj_err)?;
            let objects: Arc<dyn ObjectStore> = if prefix.trim_matches('/').is_empty() {
                Arc::new(s3)
            } else {
                Arc::new(object_store::prefix::PrefixStore::new(
                    s3,
                    prefix.trim_matches('/'),
                ))
            };
            Ok(Blobs {
                objects,
                url: u.to_string(),
            })
        }
        Some(u) => Err(StoreError::Object(format!(
            "unsupported store URL {u:?}: use file:///path or s3://bucket/prefix"
        ))),
    }
}

/// Object prefix of uploads being streamed in and of readiness probes. Not `tmp/`: with blobs in
/// the data directory (the default) that is the local records' staging directory, which the
/// local object store's automatic cleanup would remove when its last object goes.
const STAGING: &str = "staging";

/// Object path of the blob with this digest (which must be validated hex).
fn blob_path(sha: &str) -> ObjPath {
    let prefix = sha.get(..2).unwrap_or("00");
    ObjPath::from(format!("blobs/sha256/{prefix}/{sha}"))
}

/// A blob read by ranges (a map's DEM, issue 22): each [`ByteSource::read_at`] is one ranged
/// `GET` (an S3 `Range` request; a positioned read of the local file), so a caller that reads a
/// header and a few tiles never downloads the object whole. Blocking: call it from a thread of
/// its own (the map pool), never from the async runtime's.
pub struct BlobRanges {
    objects: Arc<dyn ObjectStore>,
    path: ObjPath,
    size: u64,
    rt: tokio::runtime::Handle,
    /// Bytes read so far, shared with the caller's counter.
    read: Arc<AtomicU64>,
}

impl phenomena_engine::formats::dem::cog::ByteSource for BlobRanges {
    fn size(&self) -> u64 {
        self.size
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        if buf.is_empty() {
            return Ok(());
        }
        let end = offset
            .checked_add(buf.len() as u64)
            .filter(|&e| e <= self.size)
            .ok_or_else(|| std::io::Error::from(std::io::ErrorKind::UnexpectedEof))?;
        let got = self
            .rt
            .block_on(self.objects.get_range(&self.path, offset..end))
            .map_err(std::io::Error::other)?;
        if got.len() != buf.len() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                format!("asked {} bytes, got {}", buf.len(), got.len()),
            ));
        }
        buf.copy_from_slice(&got);
        self.read.fetch_add(got.len() as u64, Ordering::Relaxed);
        Ok(())
    }
}

impl Store {
    /// The blob `sha` read by ranges (see [`BlobRanges`]), counting the bytes read into `read`.
    /// Call from within the async runtime (it keeps a handle to it).
    pub async fn blob_ranges(
        &self,
        sha: &str,
        read: Arc<AtomicU64>,
    ) -> Result<BlobRanges, StoreError> {
        if !is_sha256_hex(sha) {
            return Err(StoreError::Object(format!("no blob {sha:?}")));
        }
        let path = blob_path(sha);
        let size = self.objects().head(&path).await.map_err(obj_err)?.size;
        Ok(BlobRanges {
            objects: self.objects().clone(),
            path,
            size,
            rt: tokio::runtime::Handle::current(),
            read,
        })
    }

    fn objects(&self) -> &Arc<dyn ObjectStore> {
        &self.blobs.objects
    }

    /// Where blobs are stored (for logs).
    pub fn blob_url(&self) -> &str {
        &self.blobs.url
    }

    pub async fn has_blob(&self, sha: &str) -> bool {
        is_sha256_hex(sha) && self.objects().head(&blob_path(sha)).await.is_ok()
    }

    /// Stores `bytes`, returning their SHA-256. Idempotent.
    pub async fn put_blob(&self, bytes: Bytes) -> Result<String, StoreError> {
        let sha = super::sha256_hex(&bytes);
        let path = blob_path(&sha);
        if self.objects().head(&path).await.is_err() {
            self.objects()
                .put(&path, PutPayload::from_bytes(bytes))
                .await
                .map_err(obj_err)?;
        }
        Ok(sha)
    }

    /// Stores a stream of chunks as one blob without holding it whole: the chunks go to a
    /// temporary object (multipart) while they are hashed, which is then renamed to its digest.
    /// Returns (SHA-256, size). Fails with `TooLarge` past `max` bytes.
    pub async fn put_blob_stream<S>(
        &self,
        mut chunks: S,
        max: u64,
    ) -> Result<(String, u64), StoreError>
    where
        S: Stream<Item = Result<Bytes, StoreError>> + Unpin,
    {
        let tmp = ObjPath::from(format!(
            "{STAGING}/upload-{}",
            hex::encode(rand::random::<[u8; 16]>())
        ));
        let upload = self.objects().put_multipart(&tmp).await.map_err(obj_err)?;
        let mut w = WriteMultipart::new(upload);
        let mut hash = Sha256::new();
        let mut size = 0u64;
        let mut failure = None;
        while let Some(chunk) = chunks.next().await {
            match chunk {
                Ok(c) => {
                    size += c.len() as u64;
                    if size > max {
                        failure = Some(StoreError::TooLarge { max });
                        break;
                    }
                    hash.update(&c);
                    // Bounded memory: at most a few parts in flight.
                    if let Err(e) = w.wait_for_capacity(4).await {
                        failure = Some(obj_err(e));
                        break;
                    }
                    w.put(c);
                }
                Err(e) => {
                    failure = Some(e);
                    break;
                }
            }
        }
        if let Some(e) = failure {
            let _ = w.abort().await;
            return Err(e);
        }
        w.finish().await.map_err(obj_err)?;
        let sha = hex::encode(hash.finalize());
        let path = blob_path(&sha);
        if self.objects().head(&path).await.is_ok() {
            let _ = self.objects().delete(&tmp).await;
        } else {
            self.objects().rename(&tmp, &path).await.map_err(obj_err)?;
        }
        Ok((sha, size))
    }

    pub async fn read_blob(&self, sha: &str) -> Result<Bytes, StoreError> {
        self.objects()
            .get(&blob_path(sha))
            .await
            .map_err(obj_err)?
            .bytes()
            .await
            .map_err(obj_err)
    }

    /// The blob's bytes as a stream (downloads), or an error if it is missing.
    pub async fn blob_stream(
        &self,
        sha: &str,
    ) -> Result<impl Stream<Item = Result<Bytes, std::io::Error>> + Send + 'static, StoreError>
    {
        let got = self.objects().get(&blob_path(sha)).await.map_err(obj_err)?;
        Ok(got.into_stream().map_err(std::io::Error::other))
    }

    /// Size in bytes of a stored blob.
    pub async fn blob_size(&self, sha: &str) -> Result<u64, StoreError> {
        Ok(self
            .objects()
            .head(&blob_path(sha))
            .await
            .map_err(obj_err)?
            .size)
    }

    /// Removes blobs not in `keep` and older than `min_age` (so blobs being written by a job that
    /// has not yet recorded them survive). Returns (blobs removed, bytes freed).
    pub async fn sweep_blobs(
        &self,
        keep: &HashSet<String>,
        min_age: std::time::Duration,
    ) -> Result<(u64, u64), StoreError> {
        let now = chrono::Utc::now();
        let min_age = chrono::Duration::from_std(min_age).unwrap_or(chrono::Duration::MAX);
        let prefix = ObjPath::from("blobs/sha256");
        let metas: Vec<_> = self
            .objects()
            .list(Some(&prefix))
            .try_collect()
            .await
            .map_err(obj_err)?;
        let mut removed = (0u64, 0u64);
        for m in metas {
            let Some(name) = m.location.filename() else {
                continue;
            };
            if keep.contains(name) || now - m.last_modified < min_age {
                continue;
            }
            if self.objects().delete(&m.location).await.is_ok() {
                removed.0 += 1;
                removed.1 += m.size;
            }
        }
        // Uploads cut off by a crash leave their staging object behind.
        let staging = ObjPath::from(STAGING);
        let stale: Vec<_> = self
            .objects()
            .list(Some(&staging))
            .try_collect()
            .await
            .map_err(obj_err)?;
        for m in stale {
            if now - m.last_modified >= min_age && self.objects().delete(&m.location).await.is_ok()
            {
                removed.0 += 1;
                removed.1 += m.size;
            }
        }
        Ok(removed)
    }

    /// Total bytes held in blobs (for the `phenomena_store_bytes` gauge).
    pub async fn blob_bytes(&self) -> u64 {
        let prefix = ObjPath::from("blobs/sha256");
        self.objects()
            .list(Some(&prefix))
            .filter_map(|m| async move { m.ok().map(|m| m.size) })
            .fold(0u64, |a, b| async move { a + b })
            .await
    }

    /// Checks that the blob store takes writes (readiness).
    pub async fn probe(&self) -> bool {
        let path = ObjPath::from(format!(
            "{STAGING}/probe-{}",
            hex::encode(rand::random::<[u8; 8]>())
        ));
        let ok = self
            .objects()
            .put(&path, PutPayload::from_static(b"ok"))
            .await
            .is_ok();
        let _ = self.objects().delete(&path).await;
        ok
    }

    /// Writes a small JSON object (asset records) to the object store.
    pub(super) async fn put_object_json<T: serde::Serialize>(
        &self,
        key: &str,
        value: &T,
    ) -> Result<(), StoreError> {
        let bytes = serde_json::to_vec(value).map_err(|source| StoreError::Json {
            path: key.into(),
            source,
        })?;
        self.objects()
            .put(&ObjPath::from(key), PutPayload::from(bytes))
            .await
            .map_err(obj_err)?;
        Ok(())
    }

    /// Reads a small JSON object; `None` if it is missing or unreadable.
    pub(super) async fn get_object_json<T: serde::de::DeserializeOwned>(
        &self,
        key: &str,
    ) -> Option<T> {
        let got = self.objects().get(&ObjPath::from(key)).await.ok()?;
        let bytes = got.bytes().await.ok()?;
        serde_json::from_slice(&bytes).ok()
    }

    /// Every object under `prefix` (asset records), as (key, bytes).
    pub(super) async fn list_objects(
        &self,
        prefix: &str,
    ) -> Result<Vec<(String, Bytes)>, StoreError> {
        let metas: Vec<_> = self
            .objects()
            .list(Some(&ObjPath::from(prefix)))
            .try_collect()
            .await
            .map_err(obj_err)?;
        let mut out = Vec::with_capacity(metas.len());
        for m in metas {
            if let Ok(got) = self.objects().get(&m.location).await {
                if let Ok(b) = got.bytes().await {
                    out.push((m.location.to_string(), b));
                }
            }
        }
        Ok(out)
    }

    /// Writes an object's bytes (cached map tiles).
    pub(super) async fn put_object(&self, key: &str, bytes: Bytes) -> Result<(), StoreError> {
        self.objects()
            .put(&ObjPath::from(key), PutPayload::from_bytes(bytes))
            .await
            .map_err(obj_err)?;
        Ok(())
    }

    /// An object's bytes; `None` if it is missing, `Err` if the store cannot answer.
    pub(super) async fn get_object(&self, key: &str) -> Result<Option<Bytes>, StoreError> {
        match self.objects().get(&ObjPath::from(key)).await {
            Ok(got) => got.bytes().await.map(Some).map_err(obj_err),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(obj_err(e)),
        }
    }

    /// Deletes every object under `prefix`; returns (objects, bytes) removed.
    pub(super) async fn delete_prefix(&self, prefix: &str) -> Result<(u64, u64), StoreError> {
        let metas: Vec<_> = self
            .objects()
            .list(Some(&ObjPath::from(prefix)))
            .try_collect()
            .await
            .map_err(obj_err)?;
        let mut removed = (0u64, 0u64);
        for m in metas {
            match self.objects().delete(&m.location).await {
                Ok(()) => {
                    removed.0 += 1;
                    removed.1 += m.size;
                }
                Err(object_store::Error::NotFound { .. }) => {}
                Err(e) => return Err(obj_err(e)),
            }
        }
        Ok(removed)
    }

    pub(super) async fn delete_object(&self, key: &str) -> Result<(), StoreError> {
        match self.objects().delete(&ObjPath::from(key)).await {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(obj_err(e)),
        }
    }
}
