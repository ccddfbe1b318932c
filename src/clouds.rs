//! Cloud scenes (SPEC §3 "Editing"): an uploaded density volume with a history of immutable
//! versions, each a complete renderer state (κ, sun direction and colour, ambient, …) and, after an
//! ambient edit, a per-voxel ambient field.
//!
//! Version 1 is the upload. Every edit names a base version and becomes a new version computed by a
//! job (`cloud-edit`); the version is `pending` until that job ends, then `ready` (its state and
//! field read from the job's `state.json` and `ambient.bin` outputs) or `failed`. Any ready version
//! can be rendered or edited again, so undo is "render or edit version n".
//!
//! Scenes are stored as `clouds/<id>.json` under the data directory (written atomically at every
//! change) and survive restarts; their volume and ambient-field blobs are pinned against the
//! retention sweeper for as long as the scene exists. A version's job is resolved when it finishes
//! (the [`JobHooks`] callback), and again lazily whenever the scene is read, which covers jobs
//! canceled while queued, jobs reused from an identical earlier request and a crash between a
//! job's end and the callback.

use std::collections::{HashMap, HashSet};
use std::sync::{Arc, Mutex, MutexGuard};

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use crate::jobs::{InputRef, JobError, JobHooks, JobRecord, Status};
use crate::store::{Store, StoreError};

/// A version's lifecycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VersionStatus {
    Pending,
    Ready,
    Failed,
}

/// One immutable version of a scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VersionRecord {
    /// 1, 2, 3, … in creation order.
    pub version: u32,
    /// The version this one was edited from (`None` for the upload).
    pub parent: Option<u32>,
    /// `upload`, `sun-color`, `ambient` or `sun-direction`.
    pub kind: String,
    pub status: VersionStatus,
    pub created_at: DateTime<Utc>,
    /// The edit request as sent (strokes or drag, camera, image size).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub edit: Option<serde_json::Value>,
    /// The renderer state (`state.json`) once ready.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub state: Option<serde_json::Value>,
    /// Blob of the per-voxel ambient field (`ambient.bin`), inherited from the parent unless this
    /// version's edit produced a new one; `None` while the ambient is uniform.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ambient_field: Option<String>,
    /// The job computing (or that computed) this version.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub job: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<JobError>,
}

/// A scene: the volume, how to decode it, and its versions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneRecord {
    /// Random 128-bit id, 32 hex characters.
    pub id: String,
    pub created_at: DateTime<Utc>,
    /// The volume blob (and upload file name, for format detection).
    pub volume: InputRef,
    /// Decoder options given at upload (`bounds`, `dims`), passed to every job of the scene.
    pub input: serde_json::Map<String, serde_json::Value>,
    /// What the decoder found (dimensions, box, density range).
    pub info: serde_json::Value,
    pub versions: Vec<VersionRecord>,
}

impl SceneRecord {
    pub fn version(&self, n: u32) -> Option<&VersionRecord> {
        n.checked_sub(1)
            .and_then(|i| self.versions.get(i as usize))
            .filter(|v| v.version == n)
    }

    /// The newest version that has not failed (it may still be pending): what an edit or render
    /// without an explicit version starts from, so successive edits chain.
    pub fn latest(&self) -> Option<&VersionRecord> {
        self.versions
            .iter()
            .rev()
            .find(|v| v.status != VersionStatus::Failed)
    }

    /// The newest ready version.
    pub fn latest_ready(&self) -> Option<&VersionRecord> {
        self.versions
            .iter()
            .rev()
            .find(|v| v.status == VersionStatus::Ready)
    }
}

/// Scene-store failures.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("no cloud scene {0}")]
    NotFound(String),
    #[error(transparent)]
    Store(#[from] StoreError),
}

struct Inner {
    store: Store,
    scenes: Mutex<HashMap<String, SceneRecord>>,
}

/// The scene store; cheap to clone.
#[derive(Clone)]
pub struct Scenes {
    inner: Arc<Inner>,
}

/// True for a well-formed scene id (32 lowercase hex digits).
pub fn is_scene_id(s: &str) -> bool {
    crate::jobs::record::is_job_id(s)
}

impl Scenes {
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

    fn persist(&self, rec: &SceneRecord) -> Result<(), StoreError> {
        self.inner.store.put_json(&self.path(&rec.id), rec)
    }

    /// Creates a scene whose version 1 is `state` (persisted before it is returned).
    pub fn create(
        &self,
        volume: InputRef,
        input: serde_json::Map<String, serde_json::Value>,
        info: serde_json::Value,
        state: serde_json::Value,
    ) -> Result<SceneRecord, StoreError> {
        let now = Utc::now();
        let rec = SceneRecord {
            id: crate::jobs::record::new_job_id(),
            created_at: now,
            volume,
            input,
            info,
            versions: vec![VersionRecord {
                version: 1,
                parent: None,
                kind: "upload".into(),
                status: VersionStatus::Ready,
                created_at: now,
                edit: None,
                state: Some(state),
                ambient_field: None,
                job: None,
                error: None,
            }],
        };
        self.persist(&rec)?;
        self.lock().insert(rec.id.clone(), rec.clone());
        Ok(rec)
    }

    pub fn get(&self, id: &str) -> Option<SceneRecord> {
        self.lock().get(id).cloned()
    }

    /// Deletes a scene; its blobs are freed by the next retention sweep unless a job still uses them.
    pub fn delete(&self, id: &str) -> Result<(), SceneError> {
        let mut map = self.lock();
        if !map.contains_key(id) {
            return Err(SceneError::NotFound(id.to_string()));
        }
        self.inner.store.remove(&self.path(id))?;
        map.remove(id);
        Ok(())
    }

    /// Appends a pending version edited from `parent`, computed by `job`; resolves it at once
    /// when the job already ended (a reused identical request).
    pub fn add_version(
        &self,
        id: &str,
        parent: u32,
        kind: &str,
        edit: serde_json::Value,
        job: &JobRecord,
    ) -> Result<VersionRecord, SceneError> {
        let mut map = self.lock();
        let rec = map
            .get_mut(id)
            .ok_or_else(|| SceneError::NotFound(id.to_string()))?;
        let v = VersionRecord {
            version: rec.versions.len() as u32 + 1,
            parent: Some(parent),
            kind: kind.to_string(),
            status: VersionStatus::Pending,
            created_at: Utc::now(),
            edit: Some(edit),
            state: None,
            ambient_field: None,
            job: Some(job.id.clone()),
            error: None,
        };
        rec.versions.push(v.clone());
        let snapshot = rec.clone();
        drop(map);
        self.persist(&snapshot)?;
        if job.status.is_terminal() {
            self.resolve(job)?;
        }
        Ok(v)
    }

    /// Pending versions and the jobs computing them, for lazy resolution.
    pub fn pending_jobs(&self, id: Option<&str>) -> Vec<String> {
        let map = self.lock();
        map.values()
            .filter(|s| id.is_none_or(|i| s.id == i))
            .flat_map(|s| s.versions.iter())
            .filter(|v| v.status == VersionStatus::Pending)
            .filter_map(|v| v.job.clone())
            .collect()
    }

    /// Settles every pending version computed by `job` if the job has ended: `ready` with the
    /// state and ambient field from its outputs, or `failed` with its error.
    pub fn resolve(&self, job: &JobRecord) -> Result<(), StoreError> {
        if !job.status.is_terminal() {
            return Ok(());
        }
        // Read the state outside the lock (a small blob).
        let outcome = match job.status {
            Status::Succeeded => {
                let state = job
                    .outputs
                    .iter()
                    .find(|o| o.name == "state.json")
                    .map(|o| self.inner.store.read_blob(&o.sha256))
                    .transpose()?
                    .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
                let field = job
                    .outputs
                    .iter()
                    .find(|o| o.name == "ambient.bin")
                    .map(|o| o.sha256.clone());
                match state {
                    Some(s) => Ok((s, field)),
                    None => Err(JobError {
                        kind: format!("{}internal", crate::error::PROBLEM_BASE),
                        title: "Internal error".into(),
                        detail: "the edit produced no state".into(),
                    }),
                }
            }
            Status::Canceled => Err(JobError {
                kind: format!("{}canceled", crate::error::PROBLEM_BASE),
                title: "Canceled".into(),
                detail: "the edit's job was canceled".into(),
            }),
            _ => Err(job.error.clone().unwrap_or_else(|| JobError {
                kind: format!("{}internal", crate::error::PROBLEM_BASE),
                title: "Internal error".into(),
                detail: "the edit's job failed".into(),
            })),
        };
        let mut changed = Vec::new();
        {
            let mut map = self.lock();
            for rec in map.values_mut() {
                let mut touched = false;
                for i in 0..rec.versions.len() {
                    let v = &rec.versions[i];
                    if v.status != VersionStatus::Pending || v.job.as_deref() != Some(&job.id) {
                        continue;
                    }
                    let inherited = v
                        .parent
                        .and_then(|p| rec.version(p))
                        .and_then(|p| p.ambient_field.clone());
                    let v = &mut rec.versions[i];
                    match &outcome {
                        Ok((state, field)) => {
                            v.status = VersionStatus::Ready;
                            v.state = Some(state.clone());
                            v.ambient_field = field.clone().or(inherited);
                        }
                        Err(e) => {
                            v.status = VersionStatus::Failed;
                            v.error = Some(e.clone());
                        }
                    }
                    touched = true;
                }
                if touched {
                    changed.push(rec.clone());
                }
            }
        }
        for rec in &changed {
            self.persist(rec)?;
        }
        Ok(())
    }
}

impl JobHooks for Scenes {
    fn finished(&self, rec: &JobRecord) {
        if let Err(e) = self.resolve(rec) {
            tracing::error!(job = %rec.id, error = %e, "could not record a cloud version");
        }
    }

    fn pinned_blobs(&self) -> HashSet<String> {
        let map = self.lock();
        let mut keep = HashSet::new();
        for s in map.values() {
            keep.insert(s.volume.asset.clone());
            keep.extend(s.versions.iter().filter_map(|v| v.ambient_field.clone()));
        }
        keep
    }
}
