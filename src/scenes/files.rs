//! Scenes as files: `clouds/<id>.json` under the data directory, written atomically at every
//! change, all held in memory behind one lock (the embedded deployment: one process owns the
//! directory).

use std::collections::{HashMap, HashSet};
use std::sync::{Arc, Mutex, MutexGuard};

use async_trait::async_trait;

use super::VersionStatus;
use super::{is_scene_id, scene_blobs, SceneBackend, SceneError, SceneRecord, VersionRecord};
use crate::store::{Store, StoreError};

struct Inner {
    store: Store,
    scenes: Mutex<HashMap<String, SceneRecord>>,
}

/// The file-backed scene store; cheap to clone.
#[derive(Clone)]
pub struct FileScenes {
    inner: Arc<Inner>,
}

impl FileScenes {
    /// Loads every stored scene.
    pub fn open(store: Store) -> Result<Self, StoreError> {
        let list: Vec<SceneRecord> = store.list_json("clouds")?;
        let scenes = list
            .into_iter()
            .filter(|s| is_scene_id(&s.id))
            .map(|s| (s.id.clone(), s))
            .collect();
        Ok(Self {
            inner: Arc::new(Inner {
                store,
                scenes: Mutex::new(scenes),
            }),
        })
    }

    fn lock(&self) -> MutexGuard<'_, HashMap<String, SceneRecord>> {
        // No code that can panic runs under this lock; recover rather than poison the store.
        self.inner
            .scenes
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn path(&self, id: &str) -> std::path::PathBuf {
        self.inner
            .store
            .root()
            .join("clouds")
            .join(format!("{id}.json"))
    }

    /// Writes the record on the blocking pool (a small file, fsynced).
    async fn persist(&self, rec: SceneRecord) -> Result<(), SceneError> {
        let this = self.clone();
        tokio::task::spawn_blocking(move || this.inner.store.put_json(&this.path(&rec.id), &rec))
            .await
            .map_err(|e| SceneError::Backend(e.to_string()))??;
        Ok(())
    }
}

#[async_trait]
impl SceneBackend for FileScenes {
    async fn insert(&self, rec: &SceneRecord) -> Result<(), SceneError> {
        self.persist(rec.clone()).await?;
        self.lock().insert(rec.id.clone(), rec.clone());
        Ok(())
    }

    async fn get(&self, id: &str) -> Result<Option<SceneRecord>, SceneError> {
        Ok(self.lock().get(id).cloned())
    }

    async fn delete(&self, id: &str) -> Result<(), SceneError> {
        if !self.lock().contains_key(id) {
            return Err(SceneError::NotFound(id.to_string()));
        }
        let this = self.clone();
        let path = self.path(id);
        tokio::task::spawn_blocking(move || this.inner.store.remove(&path))
            .await
            .map_err(|e| SceneError::Backend(e.to_string()))??;
        self.lock().remove(id);
        Ok(())
    }

    async fn push_version(
        &self,
        id: &str,
        mut v: VersionRecord,
    ) -> Result<VersionRecord, SceneError> {
        let snapshot = {
            let mut map = self.lock();
            let rec = map
                .get_mut(id)
                .ok_or_else(|| SceneError::NotFound(id.to_string()))?;
            v.version = rec.versions.len() as u32 + 1;
            rec.versions.push(v.clone());
            rec.clone()
        };
        self.persist(snapshot).await?;
        Ok(v)
    }

    async fn pending(&self, scene: Option<&str>) -> Result<Vec<(String, String)>, SceneError> {
        let map = self.lock();
        Ok(map
            .values()
            .filter(|s| scene.is_none_or(|i| s.id == i))
            .flat_map(|s| {
                s.versions
                    .iter()
                    .filter(|v| v.status == VersionStatus::Pending)
                    .filter_map(|v| v.job.clone().map(|j| (s.id.clone(), j)))
            })
            .collect())
    }

    async fn update(
        &self,
        id: &str,
        settle: &(dyn for<'s> Fn(&'s mut SceneRecord) -> bool + Send + Sync),
    ) -> Result<(), SceneError> {
        let changed = {
            let mut map = self.lock();
            let rec = map
                .get_mut(id)
                .ok_or_else(|| SceneError::NotFound(id.to_string()))?;
            settle(rec).then(|| rec.clone())
        };
        if let Some(rec) = changed {
            self.persist(rec).await?;
        }
        Ok(())
    }

    async fn pinned(&self) -> Result<HashSet<String>, SceneError> {
        Ok(self.lock().values().flat_map(scene_blobs).collect())
    }
}
