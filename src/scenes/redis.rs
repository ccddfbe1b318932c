//! Scenes in Redis (with the Redis job backend), so every replica sees the same versions.
//!
//! ```text
//! P:scene:<id>     hash: `meta` (the scene without its versions, JSON), `n` (version count),
//!                  `v:<n>` (version n, JSON)
//! P:scenes         set of scene ids (retention pins their blobs)
//! P:scene-pending  set of `<scene>:<job>` for versions still pending on a job
//! ```
//! A new version takes its number from `HINCRBY n` inside one script, so concurrent edits on
//! different replicas get distinct numbers; a version is settled with a compare-and-set on its
//! JSON, so it is settled once.

use std::collections::HashSet;
use std::sync::LazyLock;

use async_trait::async_trait;
use redis::aio::ConnectionManager;
use redis::Script;

use super::{scene_blobs, SceneBackend, SceneError, SceneRecord, VersionRecord, VersionStatus};

/// Appends a version. ARGV: prefix, scene id, version JSON, job id (may be empty). Returns the
/// version number, or 0 when the scene does not exist.
static PUSH: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
local key = p .. ':scene:' .. id
if redis.call('EXISTS', key) == 0 then return 0 end
local n = redis.call('HINCRBY', key, 'n', 1)
redis.call('HSET', key, 'v:' .. n, ARGV[3])
if ARGV[4] ~= '' then redis.call('SADD', p .. ':scene-pending', id .. ':' .. ARGV[4]) end
return n
"#,
    )
});

/// Replaces version `n` if it still holds `old`. ARGV: prefix, scene id, n, old, new, pending
/// entry to remove (may be empty). Returns 1 or 0.
static SETTLE: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
local key = p .. ':scene:' .. id
if redis.call('HGET', key, 'v:' .. ARGV[3]) ~= ARGV[4] then return 0 end
redis.call('HSET', key, 'v:' .. ARGV[3], ARGV[5])
if ARGV[6] ~= '' then redis.call('SREM', p .. ':scene-pending', ARGV[6]) end
return 1
"#,
    )
});

fn be(e: redis::RedisError) -> SceneError {
    SceneError::Backend(e.to_string())
}

fn bad(e: serde_json::Error) -> SceneError {
    SceneError::Backend(format!("a scene record in Redis is not valid JSON: {e}"))
}

/// The scene record without versions, as stored under `meta`.
#[derive(serde::Serialize, serde::Deserialize)]
struct Meta {
    id: String,
    created_at: chrono::DateTime<chrono::Utc>,
    volume: crate::jobs::InputRef,
    input: serde_json::Map<String, serde_json::Value>,
    info: serde_json::Value,
}

/// The Redis scene store; cheap to clone.
#[derive(Clone)]
pub struct RedisScenes {
    con: ConnectionManager,
    prefix: String,
}

impl RedisScenes {
    pub fn new(con: ConnectionManager, prefix: &str) -> Self {
        Self {
            con,
            prefix: prefix.to_string(),
        }
    }

    fn key(&self, id: &str) -> String {
        format!("{}:scene:{id}", self.prefix)
    }

    fn named(&self, name: &str) -> String {
        format!("{}:{name}", self.prefix)
    }

    /// The scene and the raw JSON of each version (for compare-and-set).
    async fn read(&self, id: &str) -> Result<Option<(SceneRecord, Vec<String>)>, SceneError> {
        let fields: Vec<(String, String)> = redis::cmd("HGETALL")
            .arg(self.key(id))
            .query_async(&mut self.con.clone())
            .await
            .map_err(be)?;
        let mut meta = None;
        let mut versions: Vec<(u32, String)> = Vec::new();
        for (k, v) in fields {
            if k == "meta" {
                meta = Some(serde_json::from_str::<Meta>(&v).map_err(bad)?);
            } else if let Some(n) = k.strip_prefix("v:").and_then(|n| n.parse().ok()) {
                versions.push((n, v));
            }
        }
        let Some(m) = meta else { return Ok(None) };
        versions.sort_by_key(|(n, _)| *n);
        let mut recs = Vec::with_capacity(versions.len());
        let mut raws = Vec::with_capacity(versions.len());
        for (n, raw) in versions {
            let mut v: VersionRecord = serde_json::from_str(&raw).map_err(bad)?;
            v.version = n;
            recs.push(v);
            raws.push(raw);
        }
        Ok(Some((
            SceneRecord {
                id: m.id,
                created_at: m.created_at,
                volume: m.volume,
                input: m.input,
                info: m.info,
                versions: recs,
            },
            raws,
        )))
    }
}

#[async_trait]
impl SceneBackend for RedisScenes {
    async fn insert(&self, rec: &SceneRecord) -> Result<(), SceneError> {
        let meta = serde_json::to_string(&Meta {
            id: rec.id.clone(),
            created_at: rec.created_at,
            volume: rec.volume.clone(),
            input: rec.input.clone(),
            info: rec.info.clone(),
        })
        .map_err(bad)?;
        let mut cmd = redis::cmd("HSET");
        cmd.arg(self.key(&rec.id))
            .arg("meta")
            .arg(meta)
            .arg("n")
            .arg(rec.versions.len());
        for v in &rec.versions {
            cmd.arg(format!("v:{}", v.version))
                .arg(serde_json::to_string(v).map_err(bad)?);
        }
        redis::pipe()
            .atomic()
            .add_command(cmd)
            .ignore()
            .cmd("SADD")
            .arg(self.named("scenes"))
            .arg(&rec.id)
            .ignore()
            .query_async::<()>(&mut self.con.clone())
            .await
            .map_err(be)
    }

    async fn get(&self, id: &str) -> Result<Option<SceneRecord>, SceneError> {
        Ok(self.read(id).await?.map(|(s, _)| s))
    }

    async fn delete(&self, id: &str) -> Result<(), SceneError> {
        let removed: i64 = redis::cmd("DEL")
            .arg(self.key(id))
            .query_async(&mut self.con.clone())
            .await
            .map_err(be)?;
        let _: () = redis::cmd("SREM")
            .arg(self.named("scenes"))
            .arg(id)
            .query_async(&mut self.con.clone())
            .await
            .map_err(be)?;
        if removed == 0 {
            return Err(SceneError::NotFound(id.to_string()));
        }
        // Forget its pending entries (a job still running just finds no version to settle).
        let stale: Vec<String> = self
            .pending(Some(id))
            .await?
            .into_iter()
            .map(|(s, j)| format!("{s}:{j}"))
            .collect();
        if !stale.is_empty() {
            let _: () = redis::cmd("SREM")
                .arg(self.named("scene-pending"))
                .arg(stale)
                .query_async(&mut self.con.clone())
                .await
                .map_err(be)?;
        }
        Ok(())
    }

    async fn push_version(
        &self,
        id: &str,
        mut v: VersionRecord,
    ) -> Result<VersionRecord, SceneError> {
        let raw = serde_json::to_string(&v).map_err(bad)?;
        let n: u32 = PUSH
            .arg(&self.prefix)
            .arg(id)
            .arg(raw)
            .arg(v.job.as_deref().unwrap_or(""))
            .invoke_async(&mut self.con.clone())
            .await
            .map_err(be)?;
        if n == 0 {
            return Err(SceneError::NotFound(id.to_string()));
        }
        v.version = n;
        Ok(v)
    }

    async fn pending(&self, scene: Option<&str>) -> Result<Vec<(String, String)>, SceneError> {
        let all: Vec<String> = redis::cmd("SMEMBERS")
            .arg(self.named("scene-pending"))
            .query_async(&mut self.con.clone())
            .await
            .map_err(be)?;
        Ok(all
            .into_iter()
            .filter_map(|e| {
                e.split_once(':')
                    .map(|(s, j)| (s.to_string(), j.to_string()))
            })
            .filter(|(s, _)| scene.is_none_or(|want| want == s))
            .collect())
    }

    async fn update(
        &self,
        id: &str,
        settle: &(dyn for<'s> Fn(&'s mut SceneRecord) -> bool + Send + Sync),
    ) -> Result<(), SceneError> {
        let Some((before, raws)) = self.read(id).await? else {
            return Err(SceneError::NotFound(id.to_string()));
        };
        let mut after = before.clone();
        if !settle(&mut after) {
            return Ok(());
        }
        for ((old, new), raw) in before.versions.iter().zip(&after.versions).zip(&raws) {
            if old == new {
                continue;
            }
            let pending_entry = match (&old.job, new.status) {
                (Some(j), s) if s != VersionStatus::Pending => format!("{id}:{j}"),
                _ => String::new(),
            };
            // Lost races are fine: someone else settled the version the same way.
            let _: i64 = SETTLE
                .arg(&self.prefix)
                .arg(id)
                .arg(new.version)
                .arg(raw)
                .arg(serde_json::to_string(new).map_err(bad)?)
                .arg(pending_entry)
                .invoke_async(&mut self.con.clone())
                .await
                .map_err(be)?;
        }
        Ok(())
    }

    async fn pinned(&self) -> Result<HashSet<String>, SceneError> {
        let ids: Vec<String> = redis::cmd("SMEMBERS")
            .arg(self.named("scenes"))
            .query_async(&mut self.con.clone())
            .await
            .map_err(be)?;
        let mut keep = HashSet::new();
        for id in ids {
            if let Some((s, _)) = self.read(&id).await? {
                keep.extend(scene_blobs(&s));
            }
        }
        Ok(keep)
    }
}
