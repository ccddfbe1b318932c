//! Progress reporting and cooperative cancellation for long-running pipelines.

/// The job was canceled (by the user, a time limit or shutdown) while the pipeline ran.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("canceled")]
pub struct Canceled;

/// What a pipeline sees of the job running it: it reports progress and polls for cancellation.
///
/// `stage` names the paper step being computed (`"smooth"`, `"tsa"`, …); `fraction` is the job's
/// overall progress in `[0, 1]`. Implementations must be cheap: pipelines call [`Control::checkpoint`]
/// from inside row loops (once per row or tile, never per cell).
pub trait Control: Sync {
    /// Report that `stage` is running and the whole job is `fraction` done.
    fn progress(&self, stage: &str, fraction: f32);
    /// True once the job should stop.
    fn is_canceled(&self) -> bool;
    /// `Err(Canceled)` once the job should stop; call between stages and inside long loops.
    fn checkpoint(&self) -> Result<(), Canceled> {
        if self.is_canceled() {
            Err(Canceled)
        } else {
            Ok(())
        }
    }
}

/// A control that never cancels and discards progress (tests, benches).
#[derive(Debug, Default, Clone, Copy)]
pub struct NoControl;

impl Control for NoControl {
    fn progress(&self, _stage: &str, _fraction: f32) {}
    fn is_canceled(&self) -> bool {
        false
    }
}

/// A stage of a longer job: maps the inner work's progress `[0, 1]` onto `[from, to]` of the
/// job's, so a pipeline that calls a self-contained step (which reports its own 0–1) keeps its
/// overall progress monotonic.
pub struct Span<'a> {
    pub inner: &'a dyn Control,
    pub from: f32,
    pub to: f32,
}

impl Control for Span<'_> {
    fn progress(&self, stage: &str, fraction: f32) {
        let f = fraction.clamp(0.0, 1.0);
        self.inner
            .progress(stage, self.from + (self.to - self.from) * f);
    }
    fn is_canceled(&self) -> bool {
        self.inner.is_canceled()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    struct Record(Mutex<Vec<f32>>);
    impl Control for Record {
        fn progress(&self, _: &str, f: f32) {
            self.0.lock().unwrap().push(f);
        }
        fn is_canceled(&self) -> bool {
            false
        }
    }

    #[test]
    fn a_span_maps_its_progress_into_its_range() {
        let r = Record(Mutex::new(Vec::new()));
        let s = Span {
            inner: &r,
            from: 0.2,
            to: 0.6,
        };
        for f in [0.0, 0.5, 1.0, 2.0] {
            s.progress("x", f);
        }
        let got = r.0.lock().unwrap().clone();
        let want = [0.2, 0.4, 0.6, 0.6];
        assert!(
            got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6),
            "{got:?}"
        );
    }
}
