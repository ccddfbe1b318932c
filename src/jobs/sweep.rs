//! Retention, the same for every backend: every `sweep_interval`, finished jobs older than the
//! retention period are forgotten, unused assets expire, maps whose DEM asset expired are deleted
//! with their cached tiles (a map in use keeps its asset alive, see `crate::maps`), and blobs
//! that nothing references any more (no job, live asset or cloud scene) are deleted from the
//! store.
//!
//! With many replicas only one sweeps per interval ([`super::JobBackend::sweep_turn`]): two
//! sweeps at once would be harmless (deletes are idempotent) but wasteful.

use std::time::Duration;

use super::{Jobs, JobsError};
use crate::metrics::Metrics;

/// Runs [`sweep_once`] every `interval` until the job system stops accepting work.
pub(crate) async fn sweeper(jobs: Jobs, retention: Duration, interval: Duration, metrics: Metrics) {
    loop {
        tokio::time::sleep(interval).await;
        if !jobs.accepting() {
            return;
        }
        if !jobs.sweep_turn(interval).await {
            continue;
        }
        match sweep_once(&jobs, retention, &metrics).await {
            Ok((expired, files, bytes)) => {
                if expired > 0 || files > 0 {
                    tracing::info!(
                        expired_jobs = expired,
                        blobs_removed = files,
                        bytes_freed = bytes,
                        "retention sweep"
                    );
                }
            }
            Err(e) => tracing::warn!(error = %e, "retention sweep failed"),
        }
    }
}

/// One retention pass; also refreshes the store-size gauge. Returns (expired jobs, blobs removed,
/// bytes freed).
pub(crate) async fn sweep_once(
    jobs: &Jobs,
    retention: Duration,
    metrics: &Metrics,
) -> Result<(usize, u64, u64), JobsError> {
    let cutoff = chrono::Utc::now()
        - chrono::Duration::from_std(retention).unwrap_or(chrono::Duration::days(3650));
    let expired = jobs.expire(cutoff).await?;
    let assets = jobs.store().expire_assets(cutoff).await?;
    // Maps go with their DEM asset (and their cached tiles with them).
    let (maps, tiles, tile_bytes) = jobs.store().sweep_maps(&assets).await?;
    if maps > 0 || tiles > 0 {
        tracing::info!(
            maps_removed = maps,
            tiles_removed = tiles,
            bytes_freed = tile_bytes,
            "retention sweep: maps"
        );
    }
    let mut keep = jobs.referenced_blobs().await?;
    keep.extend(assets);
    keep.extend(jobs.hooks().pinned_blobs().await?);
    // Blobs younger than this may belong to a job that is storing its outputs right now.
    let min_age = retention.min(Duration::from_secs(600));
    let (files, bytes) = jobs.store().sweep_blobs(&keep, min_age).await?;
    let total = jobs.store().blob_bytes().await;
    metrics
        .store_bytes
        .set(i64::try_from(total).unwrap_or(i64::MAX));
    Ok((expired, files, bytes))
}
