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
