//! Uploaded inputs ("assets"): content-addressed blobs with a small metadata record, so a client
//! uploads a DEM once and re-renders it with new parameters by naming its SHA-256.

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use super::{is_sha256_hex, Store, StoreError};

/// Metadata of one asset, stored as `assets/<sha256>.json`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AssetRecord {
    /// SHA-256 of the bytes, 64 hex characters.
    pub id: String,
    pub size: u64,
    /// The file name given at upload (used for format detection by extension).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub filename: Option<String>,
    pub created_at: DateTime<Utc>,
    /// Refreshed whenever a job uses the asset; retention counts from here.
    pub last_used_at: DateTime<Utc>,
}

fn asset_key(id: &str) -> String {
    format!("assets/{id}.json")
}

impl Store {
    /// Records an asset whose blob is stored (`put_blob` / `put_blob_stream`). Returns the record
    /// and whether it was new. Uploading the same bytes again refreshes `last_used_at` (and keeps
    /// the first file name).
    pub async fn record_asset(
        &self,
        id: &str,
        size: u64,
        filename: Option<&str>,
    ) -> Result<(AssetRecord, bool), StoreError> {
        let now = Utc::now();
        let (rec, created) = match self.get_asset(id).await {
            Some(mut r) => {
                // Re-uploads are frequent (every multipart submit of a cached request): rewrite
                // the record at most once a minute, so the hot path does no write.
                let fresh = now - r.last_used_at < chrono::Duration::seconds(60);
                if fresh && (r.filename.is_some() || filename.is_none()) {
                    return Ok((r, false));
                }
                r.last_used_at = now;
                if r.filename.is_none() {
                    r.filename = filename.map(str::to_string);
                }
                (r, false)
            }
            None => (
                AssetRecord {
                    id: id.to_string(),
                    size,
                    filename: filename.map(str::to_string),
                    created_at: now,
                    last_used_at: now,
                },
                true,
            ),
        };
        self.put_object_json(&asset_key(id), &rec).await?;
        Ok((rec, created))
    }

    /// Stores an asset's bytes and record.
    pub async fn put_asset(
        &self,
        bytes: bytes::Bytes,
        filename: Option<&str>,
    ) -> Result<(AssetRecord, bool), StoreError> {
        let size = bytes.len() as u64;
        let id = self.put_blob(bytes).await?;
        self.record_asset(&id, size, filename).await
    }

    /// The asset's record, if the id is well-formed and both record and blob exist.
    pub async fn get_asset(&self, id: &str) -> Option<AssetRecord> {
        if !is_sha256_hex(id) || !self.has_blob(id).await {
            return None;
        }
        self.get_object_json(&asset_key(id)).await
    }

    /// Marks an asset as used now (skipped when it was marked less than a minute ago).
    pub async fn touch_asset(&self, rec: &AssetRecord) -> Result<(), StoreError> {
        if Utc::now() - rec.last_used_at < chrono::Duration::seconds(60) {
            return Ok(());
        }
        let mut r = rec.clone();
        r.last_used_at = Utc::now();
        self.put_object_json(&asset_key(&r.id), &r).await
    }

    /// Deletes asset records unused since `older_than`; returns the ids still alive.
    pub async fn expire_assets(
        &self,
        older_than: DateTime<Utc>,
    ) -> Result<std::collections::HashSet<String>, StoreError> {
        let mut alive = std::collections::HashSet::new();
        for (key, bytes) in self.list_objects("assets").await? {
            let Ok(rec) = serde_json::from_slice::<AssetRecord>(&bytes) else {
                tracing::warn!(key = %key, "skipping an unreadable asset record");
                continue;
            };
            if rec.last_used_at < older_than {
                self.delete_object(&asset_key(&rec.id)).await?;
            } else {
                alive.insert(rec.id);
            }
        }
        Ok(alive)
    }
}
