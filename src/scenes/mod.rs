//! Cloud scenes (SPEC §3 "Editing"): an uploaded density volume with a history of immutable
//! versions, each a complete renderer state (κ, sun direction and colour, ambient, …) and, after an
//! ambient edit, a per-voxel ambient field.
//!
//! Version 1 is the upload. Every edit names a base version and becomes a new version computed by a
//! job (`cloud-edit`); the version is `pending` until that job ends, then `ready` (its state and
//! field read from the job's `state.json` and `ambient.bin` outputs) or `failed`. Any ready version
//! can be rendered or edited again, so undo is "render or edit version n".
//!
//! Scenes live behind [`SceneBackend`]: files under the data directory ([`files`], with the
//! embedded job backend) or Redis (with the Redis job backend, so every replica sees the same
//! versions). Their volume and ambient-field blobs are pinned against the retention sweeper for as
//! long as the scene exists. A version's job is resolved when it finishes (the [`JobHooks`]
//! callback), and again lazily whenever the scene is read, which covers jobs canceled while queued,
//! jobs reused from an identical earlier request and a crash between a job's end and the callback.

pub mod files;
pub mod redis;

use std::collections::HashSet;
use std::sync::Arc;

use async_trait::async_trait;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};

use crate::error::Problem;
use crate::jobs::{InputRef, JobError, JobHooks, JobRecord, JobsError, Status};
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
    #[error("scene store unavailable: {0}")]
    Backend(String),
}

/// True for a well-formed scene id (32 lowercase hex digits).
pub fn is_scene_id(s: &str) -> bool {
    crate::jobs::record::is_job_id(s)
}

/// Where scenes are kept. Every method is atomic with respect to other replicas: two edits of one
/// scene get distinct version numbers, and a version is settled once.
#[async_trait]
pub trait SceneBackend: Send + Sync + 'static {
    /// Stores a new scene (persisted before it is returned).
    async fn insert(&self, rec: &SceneRecord) -> Result<(), SceneError>;
    async fn get(&self, id: &str) -> Result<Option<SceneRecord>, SceneError>;
    /// Deletes a scene; its blobs are freed by the next retention sweep unless a job still uses them.
    async fn delete(&self, id: &str) -> Result<(), SceneError>;
    /// Appends `v` as the next version (its `version` field is assigned here) and returns it.
    async fn push_version(&self, id: &str, v: VersionRecord) -> Result<VersionRecord, SceneError>;
    /// Scenes with a version pending on `job` (all scenes' pending jobs when `job` is `None`), as
    /// (scene id, job id).
    async fn pending(&self, scene: Option<&str>) -> Result<Vec<(String, String)>, SceneError>;
    /// Applies `settle` to the scene (under the backend's lock or transaction) and stores it if
    /// `settle` returns true.
    async fn update(
        &self,
        id: &str,
        settle: &(dyn for<'s> Fn(&'s mut SceneRecord) -> bool + Send + Sync),
    ) -> Result<(), SceneError>;
    /// Every blob any scene holds (volumes and ambient fields).
    async fn pinned(&self) -> Result<HashSet<String>, SceneError>;
}

/// The scene store; cheap to clone.
#[derive(Clone)]
pub struct Scenes {
    backend: Arc<dyn SceneBackend>,
    store: Store,
}

/// How a finished job settles the versions it computed.
enum Outcome {
    Ready(serde_json::Value, Option<String>),
    Failed(JobError),
}

impl Scenes {
    pub fn new(backend: Arc<dyn SceneBackend>, store: Store) -> Self {
        Self { backend, store }
    }

    /// Creates a scene whose version 1 is `state` (persisted before it is returned).
    pub async fn create(
        &self,
        volume: InputRef,
        input: serde_json::Map<String, serde_json::Value>,
        info: serde_json::Value,
        state: serde_json::Value,
    ) -> Result<SceneRecord, SceneError> {
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
        self.backend.insert(&rec).await?;
        Ok(rec)
    }

    pub async fn get(&self, id: &str) -> Result<Option<SceneRecord>, SceneError> {
        self.backend.get(id).await
    }

    pub async fn delete(&self, id: &str) -> Result<(), SceneError> {
        self.backend.delete(id).await
    }

    /// Appends a pending version edited from `parent`, computed by `job`; resolves it at once
    /// when the job already ended (a reused identical request).
    pub async fn add_version(
        &self,
        id: &str,
        parent: u32,
        kind: &str,
        edit: serde_json::Value,
        job: &JobRecord,
    ) -> Result<VersionRecord, SceneError> {
        let v = VersionRecord {
            version: 0,
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
        let v = self.backend.push_version(id, v).await?;
        if job.status.is_terminal() {
            self.resolve(job).await?;
        }
        Ok(v)
    }

    /// The jobs computing pending versions (of scene `id`, or of every scene), for lazy resolution.
    pub async fn pending_jobs(&self, id: Option<&str>) -> Result<Vec<String>, SceneError> {
        let mut jobs: Vec<String> = self
            .backend
            .pending(id)
            .await?
            .into_iter()
            .map(|(_, j)| j)
            .collect();
        jobs.sort();
        jobs.dedup();
        Ok(jobs)
    }

    /// Settles every pending version computed by `job` if the job has ended: `ready` with the
    /// state and ambient field from its outputs, or `failed` with its error.
    pub async fn resolve(&self, job: &JobRecord) -> Result<(), SceneError> {
        if !job.status.is_terminal() {
            return Ok(());
        }
        let scenes: Vec<String> = self
            .backend
            .pending(None)
            .await?
            .into_iter()
            .filter(|(_, j)| *j == job.id)
            .map(|(s, _)| s)
            .collect();
        if scenes.is_empty() {
            return Ok(());
        }
        let outcome = self.outcome(job).await?;
        let job_id = job.id.clone();
        for scene in scenes {
            let settle = |rec: &mut SceneRecord| settle(rec, &job_id, &outcome);
            match self.backend.update(&scene, &settle).await {
                Ok(()) | Err(SceneError::NotFound(_)) => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// What `job` (ended) means for its versions; reads its small `state.json` output.
    async fn outcome(&self, job: &JobRecord) -> Result<Outcome, SceneError> {
        Ok(match job.status {
            Status::Succeeded => {
                let state = match job.outputs.iter().find(|o| o.name == "state.json") {
                    Some(o) => {
                        let bytes = self.store.read_blob(&o.sha256).await?;
                        serde_json::from_slice::<serde_json::Value>(&bytes).ok()
                    }
                    None => None,
                };
                let field = job
                    .outputs
                    .iter()
                    .find(|o| o.name == "ambient.bin")
                    .map(|o| o.sha256.clone());
                match state {
                    Some(s) => Outcome::Ready(s, field),
                    None => Outcome::Failed(JobError::new(
                        Problem::Internal,
                        "the edit produced no state",
                    )),
                }
            }
            Status::Canceled => Outcome::Failed(JobError::new(
                Problem::Canceled,
                "the edit's job was canceled",
            )),
            _ => Outcome::Failed(
                job.error
                    .clone()
                    .unwrap_or_else(|| JobError::new(Problem::Internal, "the edit's job failed")),
            ),
        })
    }
}

/// Settles the versions of `rec` pending on `job`; true if any changed.
fn settle(rec: &mut SceneRecord, job: &str, outcome: &Outcome) -> bool {
    let mut touched = false;
    for i in 0..rec.versions.len() {
        let v = &rec.versions[i];
        if v.status != VersionStatus::Pending || v.job.as_deref() != Some(job) {
            continue;
        }
        let inherited = v
            .parent
            .and_then(|p| rec.version(p))
            .and_then(|p| p.ambient_field.clone());
        let v = &mut rec.versions[i];
        match outcome {
            Outcome::Ready(state, field) => {
                v.status = VersionStatus::Ready;
                v.state = Some(state.clone());
                v.ambient_field = field.clone().or(inherited);
            }
            Outcome::Failed(e) => {
                v.status = VersionStatus::Failed;
                v.error = Some(e.clone());
            }
        }
        touched = true;
    }
    touched
}

/// The blobs a scene holds.
pub(crate) fn scene_blobs(s: &SceneRecord) -> impl Iterator<Item = String> + '_ {
    std::iter::once(s.volume.asset.clone())
        .chain(s.versions.iter().filter_map(|v| v.ambient_field.clone()))
}

#[async_trait]
impl JobHooks for Scenes {
    async fn finished(&self, rec: &JobRecord) {
        if let Err(e) = self.resolve(rec).await {
            tracing::error!(job = %rec.id, error = %e, "could not record a cloud version");
        }
    }

    async fn pinned_blobs(&self) -> Result<HashSet<String>, JobsError> {
        self.backend
            .pinned()
            .await
            .map_err(|e| JobsError::Backend(e.to_string()))
    }
}

impl From<SceneError> for crate::error::ApiError {
    fn from(e: SceneError) -> Self {
        use crate::error::ApiError;
        match e {
            SceneError::NotFound(d) => ApiError::NotFound(format!("no cloud scene {d}")),
            SceneError::Store(s) => s.into(),
            SceneError::Backend(msg) => {
                tracing::error!(error = %msg, "scene store failure");
                ApiError::Unavailable("the scene store is unavailable; try again later".into())
            }
        }
    }
}
