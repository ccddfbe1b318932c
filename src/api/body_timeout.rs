//! Request-body read limits in time: a client that stalls or trickles its body gets `408`
//! problem+json and the connection is closed.
//!
//! Two rules, both only while a handler waits for the body:
//! - **idle** (`body_read_timeout_secs`): no piece of body for that long;
//! - **rate floor** (`body_min_bytes_per_sec`): the body must keep up an average of that rate
//!   after a first allowance of `body_read_timeout_secs` — the deadline is
//!   `start + timeout + received / rate`, as Apache's `mod_reqtimeout` `MinRate` does. Without it a
//!   client sending one byte every few seconds would never be idle long enough to be cut.
//!
//! Neither rule limits the total time, so a big upload that keeps flowing is never cut.
//!
//! A handler sees the timeout as a body error, which the multipart, JSON and upload readers would
//! report as 400 or 413; this middleware notes that the guard fired and answers 408 instead, with
//! `Connection: close` since the rest of the body is never read.
//!
//! Rejected: tower-http's `RequestBodyTimeoutLayer` (idle rule only; a trickle defeats it) and a
//! total timeout (it cuts big uploads on slow links).

use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::{Body, Bytes};
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use http_body::{Frame, SizeHint};
use tokio::time::{Instant, Sleep};

use super::AppState;
use crate::error::ApiError;

type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// The body error a handler sees when the guard fires.
#[derive(Debug, thiserror::Error)]
#[error("the request body stalled or arrived too slowly")]
pub struct BodyTimeout;

/// The time rules of one request body.
#[derive(Debug, Clone, Copy)]
struct Rules {
    idle: Duration,
    /// Bytes per second; 0 = no rate floor.
    min_rate: u64,
}

/// A request body under [`Rules`] that records whether it fired.
struct GuardedBody {
    inner: Body,
    rules: Rules,
    /// When a handler first waited for the body.
    started: Option<Instant>,
    /// When the last piece arrived (or `started`).
    last: Option<Instant>,
    received: u64,
    sleep: Option<Pin<Box<Sleep>>>,
    fired: Arc<AtomicBool>,
}

impl GuardedBody {
    fn deadline(&self, now: Instant) -> Instant {
        let started = self.started.unwrap_or(now);
        let idle = self.last.unwrap_or(started) + self.rules.idle;
        if self.rules.min_rate == 0 {
            return idle;
        }
        let credit = Duration::from_secs_f64(self.received as f64 / self.rules.min_rate as f64);
        idle.min(started + self.rules.idle + credit)
    }
}

impl http_body::Body for GuardedBody {
    type Data = Bytes;
    type Error = BoxError;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, BoxError>>> {
        let now = Instant::now();
        self.started.get_or_insert(now);
        match Pin::new(&mut self.inner).poll_frame(cx) {
            Poll::Ready(frame) => {
                if let Some(Ok(f)) = &frame {
                    let n = f.data_ref().map_or(0, |d| d.len() as u64);
                    self.received += n;
                }
                self.last = Some(now);
                Poll::Ready(frame.map(|r| r.map_err(Into::into)))
            }
            Poll::Pending => {
                let deadline = self.deadline(now);
                let sleep = match &mut self.sleep {
                    Some(s) => {
                        if s.deadline() != deadline {
                            s.as_mut().reset(deadline);
                        }
                        s
                    }
                    slot => slot.insert(Box::pin(tokio::time::sleep_until(deadline))),
                };
                if sleep.as_mut().poll(cx).is_ready() {
                    self.fired.store(true, Ordering::Release);
                    return Poll::Ready(Some(Err(Box::new(BodyTimeout))));
                }
                Poll::Pending
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

/// Middleware: puts the request body under the time rules; if they fired, the answer is 408.
pub(super) async fn body_timeout(State(st): State<AppState>, req: Request, next: Next) -> Response {
    let rules = Rules {
        idle: Duration::from_secs(st.cfg.body_read_timeout_secs),
        min_rate: st.cfg.body_min_bytes_per_sec,
    };
    let fired = Arc::new(AtomicBool::new(false));
    let req = req.map(|b| {
        Body::new(GuardedBody {
            inner: b,
            rules,
            started: None,
            last: None,
            received: 0,
            sleep: None,
            fired: fired.clone(),
        })
    });
    let resp = next.run(req).await;
    if !fired.load(Ordering::Acquire) {
        return resp;
    }
    tracing::info!(
        idle_secs = rules.idle.as_secs(),
        min_rate = rules.min_rate,
        "request body stalled or too slow; answering 408"
    );
    let mut resp = ApiError::RequestTimeout(format!(
        "the request body stalled for {} s or arrived slower than {} bytes/s; the request was \
         abandoned",
        rules.idle.as_secs(),
        rules.min_rate
    ))
    .into_response();
    resp.headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    resp
}
