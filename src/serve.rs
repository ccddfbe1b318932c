//! The connection layer: accepts TCP connections and serves HTTP/1.1 on each with hyper's
//! connection builder, which (unlike `axum::serve`) can bound how clients use a connection:
//!
//! - a header-read timeout (`header_read_timeout_secs`): a client that has not sent its whole
//!   request line and headers in time — a slow-header ("slowloris") client, or a keep-alive
//!   connection left idle — is disconnected without a response (hyper sends none);
//! - a cap on header fields (`max_header_count`) and on request-line-plus-header bytes
//!   (`max_header_bytes`): hyper answers `431 Request Header Fields Too Large` (empty body) and
//!   closes the connection.
//!
//! The request-body idle timeout lives in the router ([`crate::api`]), where a 408 problem can
//! still be answered.
//!
//! Each connection is a task of its own, so a slow client costs a socket and a small buffer, not
//! a thread, and never delays other clients. Shutdown is graceful: once `stop` is cancelled, no
//! new connections are accepted, idle connections close, in-flight requests finish, and `serve`
//! returns when every connection has closed.
//!
//! Rejected design: HTTP/2 (hyper-util's `auto` builder). The service speaks HTTP/1.1 only, as it
//! did under `axum::serve` without axum's `http2` feature; h2c would need its own limits (header
//! list size, stream count, keep-alive) and the `auto` builder's version sniffing has no timeout.

use std::time::Duration;

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;
use tokio_util::sync::CancellationToken;

use crate::config::Config;

/// Per-connection limits (from [`Config`]).
#[derive(Debug, Clone, Copy)]
pub struct ConnLimits {
    pub header_read_timeout: Duration,
    pub max_header_count: usize,
    pub max_header_bytes: usize,
}

impl ConnLimits {
    pub fn from_config(cfg: &Config) -> Self {
        ConnLimits {
            header_read_timeout: Duration::from_secs(cfg.header_read_timeout_secs),
            max_header_count: cfg.max_header_count,
            max_header_bytes: cfg.max_header_bytes,
        }
    }
}

/// Serves `router` on `listener` until `stop` is cancelled, then closes connections gracefully
/// and returns once they are all closed.
pub async fn serve(
    listener: tokio::net::TcpListener,
    router: Router,
    limits: ConnLimits,
    stop: CancellationToken,
) -> std::io::Result<()> {
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout)
        .max_headers(limits.max_header_count)
        .max_header_size(limits.max_header_bytes);
    let graceful = GracefulShutdown::new();
    loop {
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(c) => c,
                Err(e) => {
                    accept_error(e).await;
                    continue;
                }
            },
            () = stop.cancelled() => break,
        };
        let svc = TowerToHyperService::new(router.clone());
        let conn = graceful.watch(http.serve_connection(TokioIo::new(stream), svc));
        tokio::spawn(async move {
            if let Err(e) = conn.await {
                // Header timeouts, 431s, resets: the client's doing, not ours.
                tracing::debug!(%peer, error = %e, "connection ended with an error");
            }
        });
    }
    drop(listener);
    graceful.shutdown().await;
    Ok(())
}

/// What to do when `accept` fails: a connection that died before it was accepted is skipped; a
/// resource error (out of file descriptors) is logged and accepting pauses for a second, so the
/// loop does not spin while the process is at its limit (as `axum::serve` does).
async fn accept_error(e: std::io::Error) {
    use std::io::ErrorKind::{ConnectionAborted, ConnectionRefused, ConnectionReset};
    if matches!(
        e.kind(),
        ConnectionAborted | ConnectionRefused | ConnectionReset
    ) {
        return;
    }
    tracing::error!(error = %e, "accept failed; pausing 1 s");
    tokio::time::sleep(Duration::from_secs(1)).await;
}
