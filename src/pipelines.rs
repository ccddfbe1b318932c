//! The boundary between the job system and the engine: a set of named pipelines the server can
//! run. The shipped set is [`EnginePipelines`]; tests may build the server with their own set (for
//! example a pipeline that sleeps in stages) to exercise the job mechanics.

use phenomena_engine::pipeline::{self, Limits, PipelineKind};
use phenomena_engine::{Canceled, Control, InputError, Output, ParamError};

/// Why a run produced no outputs.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("canceled")]
    Canceled,
    /// The stored input or params no longer validate (only if limits changed between runs).
    #[error(transparent)]
    Input(#[from] InputError),
    #[error(transparent)]
    Param(#[from] ParamError),
}

impl From<Canceled> for RunError {
    fn from(_: Canceled) -> Self {
        RunError::Canceled
    }
}

/// Named pipelines: validation, input checks and the run itself. All methods are blocking; the
/// server calls `check_input` on the blocking pool and `run` on the rayon pool.
pub trait PipelineSet: Send + Sync + 'static {
    /// API names (`snow-terrain`), in a stable order.
    fn names(&self) -> Vec<&'static str>;
    /// Name of the multipart part holding the input (`dem`, `mesh`, `volume`).
    fn input_part(&self, pipeline: &str) -> Option<&'static str>;
    /// Validates wire parameters and returns them resolved (defaults filled) as canonical JSON.
    fn params(
        &self,
        pipeline: &str,
        raw: &serde_json::Value,
    ) -> Result<serde_json::Value, ParamError>;
    /// Decodes the input enough to reject a corrupt, unsupported or oversize file up front.
    fn check_input(
        &self,
        pipeline: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
    ) -> Result<(), InputError>;
    /// Runs the pipeline to its outputs.
    fn run(
        &self,
        pipeline: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError>;
}

/// The pipelines of `phenomena-engine`, with the configured input and output limits.
#[derive(Debug, Clone)]
pub struct EnginePipelines {
    pub limits: Limits,
}

fn kind(name: &str) -> Result<PipelineKind, ParamError> {
    PipelineKind::parse(name)
        .ok_or_else(|| ParamError::new("pipeline", format!("unknown pipeline {name:?}")))
}

impl PipelineSet for EnginePipelines {
    fn names(&self) -> Vec<&'static str> {
        PipelineKind::ALL.iter().map(|k| k.name()).collect()
    }

    fn input_part(&self, name: &str) -> Option<&'static str> {
        PipelineKind::parse(name).map(PipelineKind::input_part)
    }

    fn params(&self, name: &str, raw: &serde_json::Value) -> Result<serde_json::Value, ParamError> {
        let p = pipeline::Params::parse(kind(name)?, raw, &self.limits)?;
        Ok(p.canonical())
    }

    fn check_input(
        &self,
        name: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
    ) -> Result<(), InputError> {
        let p = pipeline::Params::parse(kind(name)?, params, &self.limits)?;
        pipeline::decode(p, input, filename, &self.limits).map(|_| ())
    }

    fn run(
        &self,
        name: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError> {
        let p = pipeline::Params::parse(kind(name)?, params, &self.limits)?;
        let job = pipeline::decode(p, input, filename, &self.limits)?;
        Ok(pipeline::run(&job, ctl)?)
    }
}
