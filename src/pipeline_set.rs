//! The boundary between the job system and the engine: a set of named pipelines the server can
//! run. The shipped set is [`EnginePipelines`]; tests may build the server with their own set (for
//! example a pipeline that sleeps in stages) to exercise the job mechanics.
//!
//! Parameters are parsed once on each side of the job boundary: a submission's
//! [`PipelineSet::params`] returns them [`Validated`] (canonical JSON for request keys and job
//! records, plus the engine's typed form that the input check reuses), and a worker parses the
//! record's JSON once to run.

use std::sync::Arc;

use phenomena_engine::params::Limits;
use phenomena_engine::registry::{self, PipelineKind, RunFailure};
use phenomena_engine::{Canceled, Control, InputError, Output, ParamError, Refusal};

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
    /// sky, a stroke that misses the cloud); the message is for the user.
    #[error("{detail}")]
    Refused { reason: Refusal, detail: String },
}

impl From<Canceled> for RunError {
    fn from(_: Canceled) -> Self {
        RunError::Canceled
    }
}

/// Parameters a [`PipelineSet`] validated: the canonical JSON (resolved, defaults filled: what
/// request keys hash and job records store) and, for the engine's pipelines, the typed parameters
/// it was made from, so the input check of the same request does not parse it again.
#[derive(Debug, Clone)]
pub struct Validated {
    canonical: serde_json::Value,
    typed: Option<Arc<registry::PipelineParams>>,
}

impl Validated {
    /// Parameters known only as canonical JSON (a test pipeline's, or read from a record).
    pub fn json(canonical: serde_json::Value) -> Self {
        Self {
            canonical,
            typed: None,
        }
    }

    /// The canonical JSON.
    pub fn canonical(&self) -> &serde_json::Value {
        &self.canonical
    }

    /// The canonical JSON, owned.
    pub fn into_canonical(self) -> serde_json::Value {
        self.canonical
    }
}

/// Named pipelines: validation, input checks and the run itself. All methods are blocking; the
/// server calls `check_input` on the blocking pool and `run` on the rayon pool.
pub trait PipelineSet: Send + Sync + 'static {
    /// API names (`snow-terrain`), in a stable order.
    fn names(&self) -> Vec<&'static str>;
    /// Name of the multipart part holding the input (`dem`, `mesh`, `volume`).
    fn input_part(&self, pipeline: &str) -> Option<&'static str>;
    /// Validates wire parameters and returns them resolved (defaults filled).
    fn params(&self, pipeline: &str, raw: &serde_json::Value) -> Result<Validated, ParamError>;
    /// Decodes the input enough to reject a corrupt, unsupported or oversize file up front.
    fn check_input(
        &self,
        pipeline: &str,
        params: &Validated,
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
    fn run_with_named_inputs(
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
    /// Every output a run of the pipeline may produce (see `registry::PipelineKind::outputs`);
    /// default none known (a test set).
    fn outputs(&self, _pipeline: &str) -> &'static [registry::OutputKind] {
        &[]
    }
    /// Decodes the input with its auxiliary inputs (name, bytes), as a run would, and says
    /// which input an error is about (`None` = the main input, else the auxiliary part's name).
    fn check_with_named_inputs(
        &self,
        pipeline: &str,
        params: &Validated,
        input: &[u8],
        filename: Option<&str>,
        _aux: &[(String, Vec<u8>)],
    ) -> Result<(), (Option<&'static str>, InputError)> {
        self.check_input(pipeline, params, input, filename)
            .map_err(|e| (None, e))
    }
    /// The most memory, in bytes, that checking one input of `pipeline` can allocate besides
    /// the input's bytes, with auxiliary inputs (`with_extra_input`) or without: what a check reserves
    /// from the decode budget. Default 0 (a pipeline whose check allocates nothing).
    fn decode_cost(&self, _pipeline: &str, _with_aux: bool) -> u64 {
        0
    }
    /// Admits a submission's input: decodes it with its auxiliary inputs as a run would (a 4xx
    /// naming the input at fault otherwise), describes it (see [`PipelineSet::describe_input`])
    /// and estimates the most memory the job's run will take ([`Admitted::run_bytes`]).
    /// `decode_bytes`: decode with the input limits scaled down so that the decode allocates at
    /// most that many bytes (a file declaring more is refused `TooLarge` before allocating);
    /// `None`: the configured limits. The default decodes with [`PipelineSet::describe_input`]
    /// or [`PipelineSet::check_with_named_inputs`] and estimates 0.
    fn admit(
        &self,
        pipeline: &str,
        params: &Validated,
        input: &[u8],
        filename: Option<&str>,
        aux: &[(String, Vec<u8>)],
        _decode_bytes: Option<u64>,
    ) -> Result<Admitted, (Option<&'static str>, InputError)> {
        let info = if aux.is_empty() {
            self.describe_input(pipeline, params, input, filename)
                .map_err(|e| (None, e))?
        } else {
            self.check_with_named_inputs(pipeline, params, input, filename, aux)?;
            serde_json::Value::Object(Default::default())
        };
        Ok(Admitted { info, run_bytes: 0 })
    }
    /// The estimated peak memory of a run of `pipeline` on an input of `units` elements (DEM
    /// cells, mesh triangles, volume voxels) rendering `pixels` pixels, with an auxiliary input
    /// or without: for jobs whose input was admitted earlier (a cloud scene's renders and
    /// edits). Default 0.
    fn run_cost(&self, _pipeline: &str, _units: u64, _pixels: u64, _with_aux: bool) -> u64 {
        0
    }
    /// Decodes the input like [`PipelineSet::check_input`] and describes it (a volume's
    /// dimensions and box) for resources that keep the input, such as cloud scenes.
    fn describe_input(
        &self,
        pipeline: &str,
        params: &Validated,
        input: &[u8],
        filename: Option<&str>,
    ) -> Result<serde_json::Value, InputError> {
        self.check_input(pipeline, params, input, filename)
            .map(|()| serde_json::Value::Object(Default::default()))
    }
}

/// What [`PipelineSet::admit`] learned about an input.
#[derive(Debug, Clone)]
pub struct Admitted {
    /// The input's description ([`PipelineSet::describe_input`]).
    pub info: serde_json::Value,
    /// The job's estimated peak memory in bytes: what a worker reserves from its memory budget
    /// before it starts the job.
    pub run_bytes: u64,
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

impl EnginePipelines {
    /// The typed parameters of `params`: those it was validated into, or (JSON only) parsed.
    fn typed(
        &self,
        name: &str,
        params: &Validated,
    ) -> Result<registry::PipelineParams, ParamError> {
        match &params.typed {
            Some(p) => Ok(p.as_ref().clone()),
            None => registry::PipelineParams::parse(kind(name)?, &params.canonical, &self.limits),
        }
    }
}

impl PipelineSet for EnginePipelines {
    fn names(&self) -> Vec<&'static str> {
        PipelineKind::public().map(|k| k.name()).collect()
    }

    fn input_part(&self, name: &str) -> Option<&'static str> {
        PipelineKind::parse(name).map(PipelineKind::input_part)
    }

    fn params(&self, name: &str, raw: &serde_json::Value) -> Result<Validated, ParamError> {
        let p = registry::PipelineParams::parse(kind(name)?, raw, &self.limits)?;
        Ok(Validated {
            canonical: p.canonical(),
            typed: Some(Arc::new(p)),
        })
    }

    fn check_input(
        &self,
        name: &str,
        params: &Validated,
        input: &[u8],
        filename: Option<&str>,
    ) -> Result<(), InputError> {
        let p = self.typed(name, params)?;
        registry::decode(p, input, filename, &self.limits).map(|_| ())
    }

    fn run(
        &self,
        name: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError> {
        self.run_with_named_inputs(name, params, input, filename, &[], ctl)
    }

    fn run_with_named_inputs(
        &self,
        name: &str,
        params: &serde_json::Value,
        input: &[u8],
        filename: Option<&str>,
        aux: &[(String, Vec<u8>)],
        ctl: &dyn Control,
    ) -> Result<Vec<Output>, RunError> {
        let p = registry::PipelineParams::parse(kind(name)?, params, &self.limits)?;
        let job = registry::decode_parts(p, input, filename, aux, &self.limits)
            .map_err(InputError::from)?;
        registry::run(&job, ctl).map_err(|e| match e {
            RunFailure::Canceled => RunError::Canceled,
            RunFailure::Refused { reason, detail } => RunError::Refused { reason, detail },
        })
    }

    fn decode_cost(&self, name: &str, with_extra_input: bool) -> u64 {
        PipelineKind::parse(name).map_or(0, |k| {
            registry::decode_cost(k, &self.limits, with_extra_input)
        })
    }

    fn admit(
        &self,
        name: &str,
        params: &Validated,
        input: &[u8],
        filename: Option<&str>,
        aux: &[(String, Vec<u8>)],
        decode_bytes: Option<u64>,
    ) -> Result<Admitted, (Option<&'static str>, InputError)> {
        let k = kind(name).map_err(|e| (None, e.into()))?;
        let limits = match decode_bytes {
            Some(b) => registry::limits_within(k, &self.limits, !aux.is_empty(), b),
            None => self.limits,
        };
        let p = self.typed(name, params).map_err(|e| (None, e.into()))?;
        let job = registry::decode_parts(p, input, filename, aux, &limits)
            .map_err(|e| (e.part, e.error))?;
        let (kind, units, pixels, extra) = registry::job_size(&job);
        Ok(Admitted {
            info: registry::describe(&job),
            run_bytes: registry::run_cost(kind, units, pixels, extra),
        })
    }

    fn run_cost(&self, name: &str, units: u64, pixels: u64, with_aux: bool) -> u64 {
        PipelineKind::parse(name).map_or(0, |k| registry::run_cost(k, units, pixels, with_aux))
    }

    fn aux_parts(&self, name: &str) -> &'static [&'static str] {
        match PipelineKind::parse(name) {
            Some(PipelineKind::SnowTerrain) => &[registry::ORTHO],
            _ => &[],
        }
    }

    fn outputs(&self, name: &str) -> &'static [registry::OutputKind] {
        PipelineKind::parse(name).map_or(&[], PipelineKind::outputs)
    }

    fn check_with_named_inputs(
        &self,
        name: &str,
        params: &Validated,
        input: &[u8],
        filename: Option<&str>,
        aux: &[(String, Vec<u8>)],
    ) -> Result<(), (Option<&'static str>, InputError)> {
        let p = self.typed(name, params).map_err(|e| (None, e.into()))?;
        registry::decode_parts(p, input, filename, aux, &self.limits)
            .map(|_| ())
            .map_err(|e| (e.part, e.error))
    }

    fn describe_input(
        &self,
        name: &str,
        params: &Validated,
        input: &[u8],
        filename: Option<&str>,
    ) -> Result<serde_json::Value, InputError> {
        let p = self.typed(name, params)?;
        let job = registry::decode(p, input, filename, &self.limits)?;
        Ok(registry::describe(&job))
    }
}
