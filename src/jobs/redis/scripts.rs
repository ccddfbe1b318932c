//! The Redis backend's atomic steps, as Lua scripts. Each one checks the job record it expects
//! (compare-and-set on the whole JSON string, so no JSON is parsed in Lua and no number is
//! reformatted) and applies every index change of one transition at once.
//!
//! Keys are built from the prefix (`ARGV[1]`) inside the scripts: the backend targets a standalone
//! Redis (or a primary with replicas), not Redis Cluster.

use std::sync::LazyLock;

use redis::Script;

/// Queue a job unless its request key already names a live job, or the queue is full.
/// ARGV: prefix, request key, job id, record, capacity, created (µs). Returns
/// `{"reused", id}`, `{"full"}` or `{"queued", id}`.
pub(super) static SUBMIT: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p = ARGV[1]
local existing = redis.call('GET', p .. ':key:' .. ARGV[2])
if existing and redis.call('EXISTS', p .. ':job:' .. existing) == 1 then
  return {'reused', existing}
end
if redis.call('SCARD', p .. ':queued') >= tonumber(ARGV[5]) then
  return {'full'}
end
redis.call('SET', p .. ':job:' .. ARGV[3], ARGV[4])
redis.call('SADD', p .. ':queued', ARGV[3])
redis.call('ZADD', p .. ':jobs', ARGV[6], ARGV[3])
redis.call('SET', p .. ':key:' .. ARGV[2], ARGV[3])
redis.call('XADD', p .. ':queue', '*', 'job', ARGV[3])
redis.call('PUBLISH', p .. ':work', ARGV[3])
return {'queued', ARGV[3]}
"#,
    )
});

/// A worker starts (or takes over) a job. ARGV: prefix, id, old record, new record, owner.
/// Returns 1, or 0 when the record changed meanwhile.
pub(super) static START: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
if redis.call('GET', p .. ':job:' .. id) ~= ARGV[3] then return 0 end
redis.call('SET', p .. ':job:' .. id, ARGV[4])
redis.call('SREM', p .. ':queued', id)
redis.call('HSET', p .. ':running', id, ARGV[5])
redis.call('DEL', p .. ':snap:' .. id)
return 1
"#,
    )
});

/// A run ends with a terminal status. ARGV: prefix, id, old record, new record, owner, stream
/// entry, status, request key, finished (ms). Returns 1, or 0 when another worker owns the job now
/// (this run's result is dropped: its outputs are content-addressed blobs, harmless).
pub(super) static FINISH: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
if redis.call('GET', p .. ':job:' .. id) ~= ARGV[3] then return 0 end
if redis.call('HGET', p .. ':running', id) ~= ARGV[5] then return 0 end
redis.call('SET', p .. ':job:' .. id, ARGV[4])
redis.call('HDEL', p .. ':running', id)
redis.call('XACK', p .. ':queue', 'workers', ARGV[6])
redis.call('XDEL', p .. ':queue', ARGV[6])
redis.call('ZADD', p .. ':done', ARGV[9], id)
redis.call('DEL', p .. ':snap:' .. id, p .. ':cancel:' .. id)
if ARGV[7] ~= 'succeeded' and redis.call('GET', p .. ':key:' .. ARGV[8]) == id then
  redis.call('DEL', p .. ':key:' .. ARGV[8])
end
return 1
"#,
    )
});

/// A job started `max_attempts` times none of whose attempts reached an end (a panic, a dead worker) ends failed (poisoned)
/// instead of starting again, and its id goes on the dead-letter list `P:dead`. ARGV: prefix, id,
/// old record, new record, stream entry, request key, finished (ms). Returns 1, or 0 when the
/// record changed meanwhile.
pub(super) static POISON: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
if redis.call('GET', p .. ':job:' .. id) ~= ARGV[3] then return 0 end
redis.call('SET', p .. ':job:' .. id, ARGV[4])
redis.call('HDEL', p .. ':running', id)
redis.call('SREM', p .. ':queued', id)
redis.call('XACK', p .. ':queue', 'workers', ARGV[5])
redis.call('XDEL', p .. ':queue', ARGV[5])
redis.call('ZADD', p .. ':done', ARGV[7], id)
redis.call('DEL', p .. ':snap:' .. id, p .. ':cancel:' .. id)
if redis.call('GET', p .. ':key:' .. ARGV[6]) == id then
  redis.call('DEL', p .. ':key:' .. ARGV[6])
end
redis.call('RPUSH', p .. ':dead', id)
return 1
"#,
    )
});

/// A run interrupted by shutdown goes back to the queue (a new stream entry, so any replica takes
/// it at once). ARGV: prefix, id, old record, new record, owner, stream entry. Returns 1 or 0.
pub(super) static REQUEUE: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
if redis.call('GET', p .. ':job:' .. id) ~= ARGV[3] then return 0 end
if redis.call('HGET', p .. ':running', id) ~= ARGV[5] then return 0 end
redis.call('SET', p .. ':job:' .. id, ARGV[4])
redis.call('HDEL', p .. ':running', id)
redis.call('SADD', p .. ':queued', id)
redis.call('XACK', p .. ':queue', 'workers', ARGV[6])
redis.call('XDEL', p .. ':queue', ARGV[6])
redis.call('DEL', p .. ':snap:' .. id)
redis.call('XADD', p .. ':queue', '*', 'job', id)
redis.call('PUBLISH', p .. ':work', id)
return 1
"#,
    )
});

/// Cancel a queued job. ARGV: prefix, id, old record, new record, request key, finished (ms),
/// progress message. Returns 1 or 0. The stream entry stays; the worker that reads it skips it.
pub(super) static CANCEL_QUEUED: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
if redis.call('GET', p .. ':job:' .. id) ~= ARGV[3] then return 0 end
redis.call('SET', p .. ':job:' .. id, ARGV[4])
redis.call('SREM', p .. ':queued', id)
redis.call('ZADD', p .. ':done', ARGV[6], id)
if redis.call('GET', p .. ':key:' .. ARGV[5]) == id then
  redis.call('DEL', p .. ':key:' .. ARGV[5])
end
redis.call('PUBLISH', p .. ':progress', ARGV[7])
return 1
"#,
    )
});

/// A running job's heartbeat: resets the idle time of its stream entry (so no one reclaims it)
/// while this worker still owns it. ARGV: prefix, id, owner, stream entry, consumer. Returns -1
/// when the job is no longer ours, else 1 if a cancel was requested, 0 if not.
pub(super) static HEARTBEAT: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
if redis.call('HGET', p .. ':running', id) ~= ARGV[3] then return -1 end
redis.call('XCLAIM', p .. ':queue', 'workers', ARGV[5], 0, ARGV[4], 'JUSTID')
return redis.call('EXISTS', p .. ':cancel:' .. id)
"#,
    )
});

/// Forget an expired job. ARGV: prefix, id, request key.
pub(super) static EXPIRE: LazyLock<Script> = LazyLock::new(|| {
    Script::new(
        r#"
local p, id = ARGV[1], ARGV[2]
redis.call('DEL', p .. ':job:' .. id, p .. ':snap:' .. id, p .. ':cancel:' .. id)
redis.call('ZREM', p .. ':jobs', id)
redis.call('ZREM', p .. ':done', id)
redis.call('LREM', p .. ':dead', 0, id)
if redis.call('GET', p .. ':key:' .. ARGV[3]) == id then
  redis.call('DEL', p .. ':key:' .. ARGV[3])
end
return 1
"#,
    )
});
