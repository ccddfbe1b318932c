//! Maps (`/v1/maps`, issue 22) in the object store: one small JSON record per map and the tiles
//! computed for it, so every replica sharing the store serves the same maps from one tile cache.

use bytes::Bytes;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use super::{is_sha256_hex, Store, StoreError};

/// Version of the tile renderer in the cache keys: bump it when a change to the engine changes
/// tile pixels, so no replica serves tiles of the old renderer (2: `relief` with cast shadows and
/// shading normalised to level ground).
pub const TILE_VERSION: u32 = 2;

/// A map: a DEM asset and the snow-terrain parameters it is drawn with. The id is the SHA-256 of
/// both (the same request gives the same map).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapRecord {
    pub id: String,
    /// The DEM asset.
    pub asset: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filename: Option<String>,
    /// Canonical snow-terrain parameters (defaults filled).
    pub params: serde_json::Value,
    /// Bounds, centre, zooms and grid of the DEM.
    pub info: phenomena_engine::snow_terrain::tiles::MapInfo,
    pub created_at: DateTime<Utc>,
}

fn map_key(id: &str) -> String {
    format!("maps/{id}.json")
}

/// The cache key of a tile. `layer` is one of the engine's layer names.
pub fn tile_key(map: &str, layer: &str, z: u8, x: u64, y: u64, size: u32) -> String {
    format!("tiles/v{TILE_VERSION}/{map}/{layer}/{z}/{x}/{y}@{size}.png")
}

impl Store {
    /// Stores a map record.
    pub async fn put_map(&self, rec: &MapRecord) -> Result<(), StoreError> {
        self.put_object_json(&map_key(&rec.id), rec).await
    }

    /// The map with this id, if the id is well-formed and the record exists.
    pub async fn get_map(&self, id: &str) -> Result<Option<MapRecord>, StoreError> {
        if !is_sha256_hex(id) {
            return Ok(None);
        }
        match self.get_object(&map_key(id)).await? {
            Some(bytes) => Ok(serde_json::from_slice(&bytes).ok()),
            None => Ok(None),
        }
    }

    /// A cached tile (see [`tile_key`]).
    pub async fn get_tile(&self, key: &str) -> Result<Option<Bytes>, StoreError> {
        self.get_object(key).await
    }

    /// Caches a tile.
    pub async fn put_tile(&self, key: &str, png: Bytes) -> Result<(), StoreError> {
        self.put_object(key, png).await
    }

    /// Retention of maps (issue 22): a map lives as long as its DEM asset (serving a map's
    /// tiles marks the asset used, see `crate::maps`), so the records of maps whose asset is not
    /// in `alive` (the assets still alive after `expire_assets`) are deleted with every tile
    /// cached for them, and tiles of renderer versions before [`TILE_VERSION`] (which no replica
    /// reads) go too. Returns (maps removed, tile objects removed, their bytes).
    pub async fn sweep_maps(
        &self,
        alive: &std::collections::HashSet<String>,
    ) -> Result<(usize, u64, u64), StoreError> {
        let mut maps = 0;
        let mut tiles = (0u64, 0u64);
        for (key, bytes) in self.list_objects("maps").await? {
            let Ok(rec) = serde_json::from_slice::<MapRecord>(&bytes) else {
                tracing::warn!(key = %key, "skipping an unreadable map record");
                continue;
            };
            if alive.contains(&rec.asset) {
                continue;
            }
            // Tiles first: a record without tiles is harmless, tiles without a record are
            // never swept.
            for v in 1..=TILE_VERSION {
                let (n, b) = self
                    .delete_prefix(&format!("tiles/v{v}/{}", rec.id))
                    .await?;
                tiles = (tiles.0 + n, tiles.1 + b);
            }
            self.delete_object(&map_key(&rec.id)).await?;
            maps += 1;
        }
        for v in 1..TILE_VERSION {
            let (n, b) = self.delete_prefix(&format!("tiles/v{v}")).await?;
            tiles = (tiles.0 + n, tiles.1 + b);
        }
        if maps > 0 {
            self.maps_swept
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        Ok((maps, tiles.0, tiles.1))
    }

    /// How many sweeps of this process removed maps so far.
    pub fn map_sweeps(&self) -> u64 {
        self.maps_swept.load(std::sync::atomic::Ordering::Relaxed)
    }
}
