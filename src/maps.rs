//! Maps (issue 22): a DEM asset and snow-terrain parameters served as web-map tiles.
//!
//! A map is a record in the store ([`crate::store::maps`]); its tiles are computed by the engine
//! ([`phenomena_engine::snow_terrain::tiles`]) on this process's map pool, a rayon pool of its
//! own (never on the async runtime's threads), and cached in the store, so a second request (on
//! any replica sharing the store) is a read. The prepared DEM of the maps last used is kept in
//! memory ([`SOURCES_KEPT`]), so a cold tile decodes nothing.

use std::sync::{Arc, Mutex};

use bytes::Bytes;
use phenomena_engine::params::Limits;
use phenomena_engine::snow_terrain::tiles::{self, Layer, MapError, MapSource};
use phenomena_engine::snow_terrain::SnowTerrainParams;
use phenomena_engine::ParamError;

use crate::store::maps::{tile_key, MapRecord};
use crate::store::{Store, StoreError};

/// Prepared DEMs kept in memory (most recently used first).
pub const SOURCES_KEPT: usize = 4;

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
    /// Tiles computed at once (more wait for a permit): as many as the pool has threads.
    permits: tokio::sync::Semaphore,
}

impl std::fmt::Debug for Maps {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Maps").finish_non_exhaustive()
    }
}

impl Maps {
    /// `threads` = 0: one per core.
    pub fn new(
        store: Store,
        threads: usize,
        limits: Limits,
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
                permits,
            }),
        })
    }

    pub fn store(&self) -> &Store {
        &self.inner.store
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

    /// Decodes and prepares the DEM `bytes` with `params` on the map pool (what `POST /v1/maps`
    /// checks and what a map's first tile needs), keeping it under `id`.
    pub async fn prepare(
        &self,
        id: &str,
        bytes: Bytes,
        filename: Option<String>,
        params: serde_json::Value,
    ) -> Result<Arc<MapSource>, MapsError> {
        let limits = self.inner.limits;
        let src = self
            .on_pool(move || tiles::open(&bytes, filename.as_deref(), &params, &limits))
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
        let bytes = self.inner.store.read_blob(&rec.asset).await?;
        self.prepare(&rec.id, bytes, rec.filename.clone(), rec.params.clone())
            .await
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
        let src = self.source(rec).await?;
        let png = self
            .on_pool(move || tiles::tile_png(&src, layer, z, x, y, size))
            .await?;
        let Some(png) = png else {
            return Ok(None);
        };
        let png = Bytes::from(png);
        self.inner.store.put_tile(&key, png.clone()).await?;
        Ok(Some(png))
    }
}
