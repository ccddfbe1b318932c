//! The boundary between the job system and the engine: a set of named pipelines the server can
//! run. The shipped set is [`EnginePipelines`]; tests may build the server with their own set (for
//! example a pipeline that sleeps in stages) to exercise the job mechanics.

use phenomena_engine::pipeline::{self, Limits, PipelineKind, RunFailure};
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
    /// The pipeline ran but cannot produce what was asked (a cloud edit whose drag starts on empty
    /// sky); the message is for the user.
    #[error("{0}")]
    Unprocessable(String),
    /// Unprocessable with a problem type of its own (the last part of its URI) and title.
    #[error("{detail}")]
    Refused {
        problem: &'static str,
        title: &'static str,
        detail: String,
    },
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
    /// Like [`PipelineSet::run`] with the job's named auxiliary inputs (name, bytes); pipelines
    /// that take none ignore them.
    fn run_with_aux(
        &self,
        pipeline: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
        _aux: &[(String, Vec<u8>)],
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError> {
        self.run(pipeline, params, input, filename, ctl)
    }
    /// Auxiliary file parts the pipeline accepts besides its input (snow-terrain's `ortho`):
    /// multipart part names, and `{name}_asset` in a JSON submission.
    fn aux_parts(&self, _pipeline: &str) -> &'static [&'static str] {
        &[]
    }
    /// Decodes the input with its auxiliary inputs (name, bytes), as a run would, and says
    /// which input an error is about (`None` = the main input, else the auxiliary part's name).
    fn check_with_aux(
        &self,
        pipeline: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
        _aux: &[(String, Vec<u8>)],
    ) -> Result<(), (Option<&'static str>, InputError)> {
        self.check_input(pipeline, params, input, filename)
            .map_err(|e| (None, e))
    }
    /// The most memory, in bytes, that checking one input of `pipeline` can allocate besides
    /// the input's bytes, with auxiliary inputs (`with_aux`) or without: what a check reserves
    /// from the decode budget. Default 0 (a pipeline whose check allocates nothing).
    fn decode_cost(&self, _pipeline: &str, _with_aux: bool) -> u64 {
        0
    }
    /// Decodes the input like [`PipelineSet::check_input`] and describes it (a volume's
    /// dimensions and box) for resources that keep the input, such as cloud scenes.
    fn describe_input(
        &self,
        pipeline: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
    ) -> Result<serde_json::Value, InputError> {
        self.check_input(pipeline, params, input, filename)
            .map(|()| serde_json::Value::Object(Default::default()))
    }
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
        PipelineKind::public().map(|k| k.name()).collect()
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
        self.run_with_aux(name, params, input, filename, &[], ctl)
    }

    fn run_with_aux(
        &self,
        name: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
        aux: &[(String, Vec<u8>)],
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError> {
        let p = pipeline::Params::parse(kind(name)?, params, &self.limits)?;
        let job = pipeline::decode_with_aux(p, input, filename, aux, &self.limits)?;
        pipeline::run(&job, ctl).map_err(|e| match e {
            RunFailure::Canceled => RunError::Canceled,
            RunFailure::Unprocessable(m) => RunError::Unprocessable(m),
            RunFailure::Refused {
                problem,
                title,
                detail,
            } => RunError::Refused {
                problem,
                title,
                detail,
            },
        })
    }

    fn decode_cost(&self, name: &str, with_aux: bool) -> u64 {
        PipelineKind::parse(name).map_or(0, |k| pipeline::decode_cost(k, &self.limits, with_aux))
    }

    fn aux_parts(&self, name: &str) -> &'static [&'static str] {
        match PipelineKind::parse(name) {
            Some(PipelineKind::SnowTerrain) => &[pipeline::ORTHO],
            _ => &[],
        }
    }

    fn check_with_aux(
        &self,
        name: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
        aux: &[(String, Vec<u8>)],
    ) -> Result<(), (Option<&'static str>, InputError)> {
        let k = kind(name).map_err(|e| (None, e.into()))?;
        let p = pipeline::Params::parse(k, params, &self.limits).map_err(|e| (None, e.into()))?;
        pipeline::decode_parts(p, input, filename, aux, &self.limits).map(|_| ())
    }

    fn describe_input(
        &self,
        name: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
    ) -> Result<serde_json::Value, InputError> {
        let p = pipeline::Params::parse(kind(name)?, params, &self.limits)?;
        let job = pipeline::decode(p, input, filename, &self.limits)?;
        Ok(pipeline::describe(&job))
    }
}
