//! Maps (issue 22): a DEM asset and snow-terrain parameters served as web-map tiles.
//!
//! A map is a record in the store ([`crate::store::maps`]); its tiles are computed by the engine
//! ([`phenomena_engine::snow_terrain::tiles`]) on this process's map pool, a rayon pool of its
//! own (never on the async runtime's threads), and cached in the store, so a second request (on
//! any replica sharing the store) is a read. The prepared DEM of the maps last used is kept in
//! memory ([`SOURCES_KEPT`]), so a cold tile decodes nothing. Concurrent requests for one cold
//! tile in this process compute it once: the first computes, the others wait for its result
//! (a per-key `tokio::sync::OnceCell`; if the first request goes away, a waiter takes over).
//!
//! Warm tiles are served from memory: the tiles last served (at most [`HOT_TILE_BYTES`], first
//! in first out) are kept with their ETag, and map records by id ([`RECORDS_KEPT`]), so a warm
//! tile request reads no file, parses no JSON and hashes nothing. Both are safe to keep: a map id
//! names its DEM and parameters, and a tile key its map, layer, position and renderer version
//! ([`crate::store::maps::TILE_VERSION`]), so neither changes under its key.
//!
//! **DEMs are read through the store by ranges** ([`crate::store::BlobRanges`]): a tiled GeoTIFF
//! with more than `map_whole_max_cells` cells is opened by its header and a bounded overview and
//! its tiles are read as map tiles need them ([`tiles::open_source`]); smaller DEMs are read
//! whole, as before. The bytes read are counted ([`Maps::dem_bytes_read`], the
//! `phenomena_map_dem_bytes_read_total` metric).
//!
//! **Retention.** A map lives as long as its DEM asset: the retention sweep deletes the maps
//! whose asset expired, with their tiles ([`crate::store::Store::sweep_maps`]). A record is
//! re-read from the store after [`RECORD_TTL`], and then its asset is checked and marked used
//! (so a map in use keeps its DEM; at most one store write a minute per map), so a swept map
//! stops being served by every replica within that time, and a map whose asset is gone answers
//! 410 ([`MapsError::AssetGone`]).

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bytes::Bytes;
use phenomena_engine::formats::dem::cog::ByteSource;
use phenomena_engine::params::Limits;
use phenomena_engine::snow_terrain::tiles::{self, Layer, MapError, MapSource, SourceKind};
use phenomena_engine::snow_terrain::SnowTerrainParams;
use phenomena_engine::ParamError;

use crate::store::maps::{tile_key, MapRecord};
use crate::store::{Store, StoreError};

/// Prepared DEMs kept in memory (most recently used first).
pub const SOURCES_KEPT: usize = 4;

/// Bytes of PNG tiles kept in memory for warm requests.
pub const HOT_TILE_BYTES: usize = 64 << 20;

/// Map records kept in memory (all forgotten when one more comes: maps are few and cheap to
/// read again).
pub const RECORDS_KEPT: usize = 256;

/// How long a map record is served from memory before it is read again and its DEM asset is
/// checked and marked used.
pub const RECORD_TTL: Duration = Duration::from_secs(60);

/// Tiles kept in memory with their ETags, evicted first in, first out past [`HOT_TILE_BYTES`].
#[derive(Default)]
struct HotTiles {
    tiles: HashMap<String, (Bytes, Arc<str>)>,
    order: VecDeque<String>,
    bytes: usize,
}

/// Why a tile or map could not be made.
#[derive(Debug, thiserror::Error)]
pub enum MapsError {
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The DEM or parameters make no map (a 4xx for the client).
    #[error(transparent)]
    Map(#[from] MapError),
    /// The map pool dropped the work (a panic in the engine).
    #[error("the tile computation failed: {0}")]
    Failed(String),
    /// The map's DEM asset is no longer stored (it expired unused).
    #[error("the DEM asset {0} of this map is no longer stored (unused past the retention period); upload the DEM and create the map again")]
    AssetGone(String),
}

/// A map record as kept in memory: when it was read, and whether its DEM asset was there.
#[derive(Clone)]
struct KeptRecord {
    rec: Arc<MapRecord>,
    read_at: Instant,
    asset_gone: bool,
}

/// The maps of this process: the store, the pool tiles are computed on, and the prepared DEMs.
#[derive(Clone)]
pub struct Maps {
    inner: Arc<Inner>,
}

struct Inner {
    store: Store,
    pool: rayon::ThreadPool,
    limits: Limits,
    sources: Mutex<Vec<(String, Arc<MapSource>)>>,
    /// Tiled GeoTIFFs with more cells than this are read by ranges.
    whole_max_cells: u64,
    /// Bytes of DEMs read from the store (whole or by ranges).
    dem_read: Arc<AtomicU64>,
    /// Tiles computed at once (more wait for a permit): as many as the pool has threads.
    permits: tokio::sync::Semaphore,
    /// Cold tiles being computed, by cache key: later requests for one wait for its result.
    inflight: Mutex<HashMap<String, Arc<tokio::sync::OnceCell<Option<Bytes>>>>>,
    /// Tiles this process has computed (not read from the cache).
    computed: AtomicU64,
    hot: Mutex<HotTiles>,
    records: Mutex<HashMap<String, KeptRecord>>,
    /// The store's map-sweep count when the records and tiles above were last trusted.
    sweeps_seen: AtomicU64,
}

impl std::fmt::Debug for Maps {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Maps").finish_non_exhaustive()
    }
}

impl Maps {
    /// `threads` = 0: one per core. Tiled GeoTIFF DEMs with more than `whole_max_cells` cells
    /// are read by ranges (see the module documentation).
    pub fn new(
        store: Store,
        threads: usize,
        limits: Limits,
        whole_max_cells: u64,
    ) -> Result<Self, rayon::ThreadPoolBuildError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("maps-{i}"))
            .build()?;
        let permits = tokio::sync::Semaphore::new(pool.current_num_threads().max(1));
        // Tiles are at most 512² pixels whatever `width` and `height` say (they shape only
        // `render.png`), so the output limit does not apply to a map's parameters.
        let limits = Limits {
            max_output_pixels: u64::MAX,
            ..limits
        };
        Ok(Self {
            inner: Arc::new(Inner {
                store,
                pool,
                limits,
                sources: Mutex::new(Vec::new()),
                whole_max_cells,
                dem_read: Arc::new(AtomicU64::new(0)),
                permits,
                inflight: Mutex::new(HashMap::new()),
                computed: AtomicU64::new(0),
                hot: Mutex::new(HotTiles::default()),
                records: Mutex::new(HashMap::new()),
                sweeps_seen: AtomicU64::new(0),
            }),
        })
    }

    pub fn store(&self) -> &Store {
        &self.inner.store
    }

    /// Tiles this process has computed so far (cache misses that ran the engine).
    pub fn tiles_computed(&self) -> u64 {
        self.inner.computed.load(Ordering::Relaxed)
    }

    /// Bytes of DEM assets this process has read from the store for maps.
    pub fn dem_bytes_read(&self) -> u64 {
        self.inner.dem_read.load(Ordering::Relaxed)
    }

    /// The DEM asset `asset` read by ranges; [`MapsError::AssetGone`] when it is not stored.
    async fn dem_source(&self, asset: &str) -> Result<Arc<dyn ByteSource>, MapsError> {
        if !self.inner.store.has_blob(asset).await {
            return Err(MapsError::AssetGone(asset.to_string()));
        }
        let src = self
            .inner
            .store
            .blob_ranges(asset, self.inner.dem_read.clone())
            .await?;
        Ok(Arc::new(src))
    }

    /// How the DEM asset `asset` would be read with `params` (its header only): what
    /// `POST /v1/maps` reserves memory by.
    pub async fn source_kind(
        &self,
        asset: &str,
        params: &serde_json::Value,
    ) -> Result<SourceKind, MapsError> {
        let src = self.dem_source(asset).await?;
        let (limits, whole) = (self.inner.limits, self.inner.whole_max_cells);
        let params = params.clone();
        Ok(self
            .on_pool(move || tiles::source_kind(&src, &params, &limits, whole))
            .await??)
    }

    /// Validates wire snow-terrain parameters for a map: the canonical JSON (defaults filled,
    /// what the map id hashes).
    pub fn params(&self, raw: &serde_json::Value) -> Result<serde_json::Value, ParamError> {
        let p = SnowTerrainParams::from_json(raw, &self.inner.limits)?;
        serde_json::to_value(&p).map_err(|e| ParamError::new("params", e.to_string()))
    }

    /// Runs `f` on the map pool and waits for it.
    async fn on_pool<T: Send + 'static>(
        &self,
        f: impl FnOnce() -> T + Send + 'static,
    ) -> Result<T, MapsError> {
        let _permit = self
            .inner
            .permits
            .acquire()
            .await
            .map_err(|e| MapsError::Failed(e.to_string()))?;
        let (tx, rx) = tokio::sync::oneshot::channel();
        self.inner.pool.spawn(move || {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
            let _ = tx.send(r);
        });
        match rx.await {
            Ok(Ok(v)) => Ok(v),
            Ok(Err(_)) => Err(MapsError::Failed("the engine panicked".into())),
            Err(e) => Err(MapsError::Failed(e.to_string())),
        }
    }

    /// Reads and prepares the DEM asset `asset` with `params` on the map pool (what
    /// `POST /v1/maps` checks and what a map's first tile needs), keeping it under `id`: whole,
    /// or by ranges (see the module documentation).
    pub async fn prepare(
        &self,
        id: &str,
        asset: &str,
        filename: Option<String>,
        params: serde_json::Value,
    ) -> Result<Arc<MapSource>, MapsError> {
        let bytes = self.dem_source(asset).await?;
        let (limits, whole) = (self.inner.limits, self.inner.whole_max_cells);
        let src = self
            .on_pool(move || {
                tiles::open_source(bytes, filename.as_deref(), &params, &limits, whole)
            })
            .await??;
        let src = Arc::new(src);
        self.keep(id, src.clone());
        Ok(src)
    }

    fn keep(&self, id: &str, src: Arc<MapSource>) {
        if let Ok(mut v) = self.inner.sources.lock() {
            v.retain(|(k, _)| k != id);
            v.insert(0, (id.to_string(), src));
            v.truncate(SOURCES_KEPT);
        }
    }

    fn kept(&self, id: &str) -> Option<Arc<MapSource>> {
        let mut v = self.inner.sources.lock().ok()?;
        let i = v.iter().position(|(k, _)| k == id)?;
        let e = v.remove(i);
        let src = e.1.clone();
        v.insert(0, e);
        Some(src)
    }

    /// The prepared DEM of `rec`: kept, or read from the store and prepared.
    async fn source(&self, rec: &MapRecord) -> Result<Arc<MapSource>, MapsError> {
        if let Some(src) = self.kept(&rec.id) {
            return Ok(src);
        }
        self.prepare(
            &rec.id,
            &rec.asset,
            rec.filename.clone(),
            rec.params.clone(),
        )
        .await
    }

    /// The map `id` (from memory when read within [`RECORD_TTL`], else the store); `None` when
    /// there is no such map, [`MapsError::AssetGone`] when its DEM asset is no longer stored.
    /// Reading it from the store marks its asset used, so a map in use is not swept.
    pub async fn record(&self, id: &str) -> Result<Option<Arc<MapRecord>>, MapsError> {
        self.forget_swept();
        let kept = self
            .inner
            .records
            .lock()
            .ok()
            .and_then(|m| m.get(id).cloned())
            .filter(|k| k.read_at.elapsed() < RECORD_TTL);
        let kept = match kept {
            Some(k) => k,
            None => {
                let store = &self.inner.store;
                let Some(rec) = store.get_map(id).await? else {
                    if let Ok(mut m) = self.inner.records.lock() {
                        m.remove(id);
                    }
                    return Ok(None);
                };
                let asset_gone = match store.get_asset(&rec.asset).await {
                    Some(a) => {
                        store.touch_asset(&a).await?;
                        false
                    }
                    None => true,
                };
                let k = KeptRecord {
                    rec: Arc::new(rec),
                    read_at: Instant::now(),
                    asset_gone,
                };
                if let Ok(mut m) = self.inner.records.lock() {
                    if m.len() >= RECORDS_KEPT {
                        m.clear();
                    }
                    m.insert(id.to_string(), k.clone());
                }
                k
            }
        };
        if kept.asset_gone {
            return Err(MapsError::AssetGone(kept.rec.asset.clone()));
        }
        Ok(Some(kept.rec))
    }

    /// Forgets the records, hot tiles and prepared DEMs kept in memory when a sweep of this
    /// process removed maps since the last call (other replicas' records expire within
    /// [`RECORD_TTL`]).
    fn forget_swept(&self) {
        let now = self.inner.store.map_sweeps();
        if self.inner.sweeps_seen.swap(now, Ordering::Relaxed) == now {
            return;
        }
        if let Ok(mut m) = self.inner.records.lock() {
            m.clear();
        }
        if let Ok(mut h) = self.inner.hot.lock() {
            *h = HotTiles::default();
        }
        if let Ok(mut v) = self.inner.sources.lock() {
            v.clear();
        }
    }

    /// [`Self::tile`] with its strong ETag (the quoted SHA-256 of the PNG), from memory when the
    /// tile was served lately.
    pub async fn tile_tagged(
        &self,
        rec: &MapRecord,
        layer: Layer,
        z: u8,
        x: u64,
        y: u64,
        size: u32,
    ) -> Result<Option<(Bytes, Arc<str>)>, MapsError> {
        let key = tile_key(&rec.id, layer.name(), z, x, y, size);
        if let Some(hit) = self
            .inner
            .hot
            .lock()
            .ok()
            .and_then(|h| h.tiles.get(&key).cloned())
        {
            return Ok(Some(hit));
        }
        let Some(png) = self.tile(rec, layer, z, x, y, size).await? else {
            return Ok(None);
        };
        let etag: Arc<str> = format!("\"{}\"", crate::store::sha256_hex(&png)).into();
        if let Ok(mut h) = self.inner.hot.lock() {
            if png.len() <= HOT_TILE_BYTES && !h.tiles.contains_key(&key) {
                while h.bytes + png.len() > HOT_TILE_BYTES {
                    let Some(old) = h.order.pop_front() else {
                        break;
                    };
                    if let Some((b, _)) = h.tiles.remove(&old) {
                        h.bytes -= b.len();
                    }
                }
                h.bytes += png.len();
                h.order.push_back(key.clone());
                h.tiles.insert(key, (png.clone(), etag.clone()));
            }
        }
        Ok(Some((png, etag)))
    }

    /// The tile's PNG (from the cache, else computed on the pool and cached); `None` when no
    /// pixel of it falls on the DEM. The caller checked that the tile exists.
    pub async fn tile(
        &self,
        rec: &MapRecord,
        layer: Layer,
        z: u8,
        x: u64,
        y: u64,
        size: u32,
    ) -> Result<Option<Bytes>, MapsError> {
        let key = tile_key(&rec.id, layer.name(), z, x, y, size);
        if let Some(png) = self.inner.store.get_tile(&key).await? {
            return Ok(Some(png));
        }
        let cell = match self.inner.inflight.lock() {
            Ok(mut m) => m.entry(key.clone()).or_default().clone(),
            // A poisoned map (a panic while holding it: none does) only loses the sharing.
            Err(_) => Arc::default(),
        };
        let result = cell
            .get_or_try_init(|| self.compute_tile(rec, &key, layer, z, x, y, size))
            .await
            .cloned();
        // Settled (cached in the store, or failed): later requests go to the store again.
        if let Ok(mut m) = self.inner.inflight.lock() {
            if m.get(&key).is_some_and(|c| Arc::ptr_eq(c, &cell)) {
                m.remove(&key);
            }
        }
        result
    }

    /// Computes a cold tile on the pool and caches it.
    #[allow(clippy::too_many_arguments)]
    async fn compute_tile(
        &self,
        rec: &MapRecord,
        key: &str,
        layer: Layer,
        z: u8,
        x: u64,
        y: u64,
        size: u32,
    ) -> Result<Option<Bytes>, MapsError> {
        let src = self.source(rec).await?;
        let png = self
            .on_pool(move || tiles::tile_png(&src, layer, z, x, y, size))
            .await??;
        self.inner.computed.fetch_add(1, Ordering::Relaxed);
        let Some(png) = png else {
            return Ok(None);
        };
        let png = Bytes::from(png);
        self.inner.store.put_tile(key, png.clone()).await?;
        Ok(Some(png))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)] // tests may unwrap (STYLE habit 4)

    use super::*;
    use phenomena_engine::geom::mercator::{lonlat_to_mercator, mercator_to_pixel};

    /// Two concurrent requests for one cold tile run the engine once and get the same PNG; a
    /// third is read from the cache.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn concurrent_requests_for_a_cold_tile_compute_it_once() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let maps = Maps::new(store.clone(), 2, Limits::default(), 1 << 22).unwrap();
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/dem/jacksboro_fault_dem_f32.tif"
        );
        let bytes = Bytes::from(std::fs::read(path).unwrap());
        let size = bytes.len() as u64;
        let (asset, _) = store.put_asset(bytes, Some("jacksboro.tif")).await.unwrap();
        let params = maps.params(&serde_json::json!({})).unwrap();
        let id = "0".repeat(64);
        let src = maps
            .prepare(&id, &asset.id, asset.filename.clone(), params.clone())
            .await
            .unwrap();
        assert!(!src.is_tiled(), "a small DEM is read whole");
        // Whole once, after its header was read to tell whether it is a large COG (a 64 KiB
        // read-ahead and the IFD's out-of-line values).
        let read = maps.dem_bytes_read();
        assert!(
            read >= size && read <= size + (128 << 10),
            "{read} bytes read for a {size}-byte DEM"
        );
        let info = src.info().clone();
        let rec = MapRecord {
            id,
            asset: asset.id.clone(),
            filename: None,
            params,
            info: info.clone(),
            created_at: chrono::Utc::now(),
        };
        let z = info.maxzoom;
        let (mx, my) = lonlat_to_mercator(info.center[0], info.center[1]);
        let (px, py) = mercator_to_pixel(z, 256, mx, my);
        let (x, y) = ((px / 256.0) as u64, (py / 256.0) as u64);
        let (a, b) = tokio::join!(
            maps.tile(&rec, Layer::Relief, z, x, y, 256),
            maps.tile(&rec, Layer::Relief, z, x, y, 256)
        );
        let (a, b) = (
            a.unwrap().expect("on the DEM"),
            b.unwrap().expect("on the DEM"),
        );
        assert_eq!(a, b);
        assert_eq!(maps.tiles_computed(), 1, "one computation for two requests");
        let c = maps.tile(&rec, Layer::Relief, z, x, y, 256).await.unwrap();
        assert_eq!(c, Some(a));
        assert_eq!(maps.tiles_computed(), 1, "the third from the cache");
        assert!(maps.inner.inflight.lock().unwrap().is_empty());

        // Tagged: the same bytes with the PNG's SHA-256 as the ETag, the second from memory.
        let (png, etag) = maps
            .tile_tagged(&rec, Layer::Relief, z, x, y, 256)
            .await
            .unwrap()
            .unwrap();
        assert_eq!(Some(png.clone()), c);
        assert_eq!(&*etag, format!("\"{}\"", crate::store::sha256_hex(&png)));
        assert_eq!(maps.inner.hot.lock().unwrap().bytes, png.len());
        let again = maps
            .tile_tagged(&rec, Layer::Relief, z, x, y, 256)
            .await
            .unwrap()
            .unwrap();
        assert!(Arc::ptr_eq(&again.1, &etag), "the second from memory");
        assert_eq!(maps.tiles_computed(), 1);
    }
}
