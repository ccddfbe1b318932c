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

impl Store {
    fn asset_path(&self, id: &str) -> std::path::PathBuf {
        self.root().join("assets").join(format!("{id}.json"))
    }

    /// Stores an asset. Returns the record and whether it was new. Uploading the same bytes again
    /// refreshes `last_used_at` (and keeps the first file name).
    pub fn put_asset(
        &self,
        bytes: &[u8],
        filename: Option<&str>,
    ) -> Result<(AssetRecord, bool), StoreError> {
        let id = self.put_blob(bytes)?;
        let now = Utc::now();
        let (rec, created) = match self.get_asset(&id) {
            Some(mut r) => {
                // Re-uploads are frequent (every multipart submit of a cached request): rewrite
                // the record at most once a minute, so the hot path does no synchronous write.
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
                    id: id.clone(),
                    size: bytes.len() as u64,
                    filename: filename.map(str::to_string),
                    created_at: now,
                    last_used_at: now,
                },
                true,
            ),
        };
        self.put_json(&self.asset_path(&id), &rec)?;
        Ok((rec, created))
    }

    /// The asset's record, if the id is well-formed and both record and blob exist.
    pub fn get_asset(&self, id: &str) -> Option<AssetRecord> {
        if !is_sha256_hex(id) || !self.has_blob(id) {
            return None;
        }
        self.get_json(&self.asset_path(id)).ok()
    }

    /// Marks an asset as used now (skipped when it was marked less than a minute ago).
    pub fn touch_asset(&self, rec: &AssetRecord) -> Result<(), StoreError> {
        if Utc::now() - rec.last_used_at < chrono::Duration::seconds(60) {
            return Ok(());
        }
        let mut r = rec.clone();
        r.last_used_at = Utc::now();
        self.put_json(&self.asset_path(&r.id), &r)
    }

    /// Deletes asset records unused since `older_than`; returns the ids still alive.
    pub fn expire_assets(
        &self,
        older_than: DateTime<Utc>,
    ) -> Result<std::collections::HashSet<String>, StoreError> {
        let mut alive = std::collections::HashSet::new();
        for rec in self.list_json::<AssetRecord>("assets")? {
            if rec.last_used_at < older_than {
                self.remove(&self.asset_path(&rec.id))?;
            } else {
                alive.insert(rec.id);
            }
        }
        Ok(alive)
    }
}
