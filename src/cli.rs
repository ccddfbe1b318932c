//! `phenomena render <pipeline>`: one pipeline run offline, with a terminal progress bar, through the
//! same [`PipelineSet`] the server's workers use.

use std::path::PathBuf;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use phenomena_engine::Control;

use crate::config::Config;
use crate::pipeline_set::{EnginePipelines, PipelineSet, RunError};

#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// Pipeline name (`snow-terrain`).
    pub pipeline: String,
    /// Input file (DEM, mesh or volume).
    #[arg(long)]
    pub input: PathBuf,
    /// snow-terrain: an orthophoto (RGB/RGBA GeoTIFF, PNG or JPEG) whose colours replace
    /// `rock_color`; the server's `ortho` part.
    #[arg(long)]
    pub ortho: Option<PathBuf>,
    /// Parameters as a JSON file.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Set one parameter: `key=value`, with dots for nesting (`camera.azimuth_deg=200`). The value
    /// is read as JSON when it parses (`3`, `true`, `[1,2]`), else as a string. Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Output directory (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// Pipeline threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// CLI failures.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    #[error("unknown pipeline {0:?}; known: {1}")]
    UnknownPipeline(String, String),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not valid JSON: {source}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("--set {0:?}: expected KEY=VALUE")]
    Set(String),
    #[error("--ortho: {0}")]
    Ortho(String),
    #[error("invalid parameter {0}")]
    Param(#[from] phenomena_engine::ParamError),
    #[error("input {0}")]
    Input(#[from] phenomena_engine::InputError),
    #[error("canceled")]
    Canceled,
    #[error("{0}")]
    Unprocessable(String),
    #[error("cannot build the thread pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
}

/// Sets `root[a][b]… = value` for a dotted key, creating objects on the way.
pub fn set_dotted(
    root: &mut serde_json::Value,
    key: &str,
    value: serde_json::Value,
) -> Result<(), CliError> {
    let mut cur = root;
    let parts: Vec<&str> = key.split('.').collect();
    for (i, p) in parts.iter().enumerate() {
        if p.is_empty() {
            return Err(CliError::Set(key.to_string()));
        }
        let obj = match cur {
            serde_json::Value::Object(m) => m,
            _ => return Err(CliError::Set(key.to_string())),
        };
        if i + 1 == parts.len() {
            obj.insert((*p).to_string(), value);
            return Ok(());
        }
        cur = obj
            .entry((*p).to_string())
            .or_insert_with(|| serde_json::Value::Object(Default::default()));
    }
    Ok(())
}

struct BarControl(ProgressBar);

impl Control for BarControl {
    fn progress(&self, stage: &str, fraction: f32) {
        self.0
            .set_position((fraction.clamp(0.0, 1.0) * 1000.0) as u64);
        if self.0.message() != stage {
            self.0.set_message(stage.to_string());
        }
    }
    fn is_canceled(&self) -> bool {
        false
    }
}

/// Runs the command; returns after writing every output to `--out`.
pub fn render(args: RenderArgs) -> Result<(), CliError> {
    let cfg = Config::default();
    let set = EnginePipelines {
        limits: cfg.limits(),
    };
    let Some(name) = set
        .names()
        .into_iter()
        .find(|n| *n == args.pipeline.as_str())
    else {
        return Err(CliError::UnknownPipeline(
            args.pipeline,
            set.names().join(", "),
        ));
    };
    let mut raw = match &args.params {
        Some(p) => {
            let text = std::fs::read(p).map_err(|source| CliError::Io {
                path: p.clone(),
                source,
            })?;
            serde_json::from_slice(&text).map_err(|source| CliError::Json {
                path: p.clone(),
                source,
            })?
        }
        None => serde_json::Value::Object(Default::default()),
    };
    for kv in &args.set {
        let (k, v) = kv
            .split_once('=')
            .ok_or_else(|| CliError::Set(kv.clone()))?;
        let value = serde_json::from_str(v).unwrap_or_else(|_| serde_json::Value::String(v.into()));
        set_dotted(&mut raw, k, value)?;
    }
    let params = set.params(name, &raw)?.into_canonical();
    let input = std::fs::read(&args.input).map_err(|source| CliError::Io {
        path: args.input.clone(),
        source,
    })?;
    let filename = args
        .input
        .file_name()
        .map(|f| f.to_string_lossy().into_owned());
    let mut aux = Vec::new();
    if let Some(path) = &args.ortho {
        if !set
            .aux_parts(name)
            .contains(&phenomena_engine::registry::ORTHO)
        {
            return Err(CliError::Ortho(format!(
                "the {name} pipeline takes no orthophoto"
            )));
        }
        let bytes = std::fs::read(path).map_err(|source| CliError::Io {
            path: path.clone(),
            source,
        })?;
        aux.push((phenomena_engine::registry::ORTHO.to_string(), bytes));
    }

    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(1000)
    };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:40} {percent:>3}% {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    let ctl = BarControl(bar.clone());
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.unwrap_or(0))
        .build()?;
    // The mesh pipelines get the files the mesh refers to (an OBJ's material libraries and
    // textures, a .gltf's buffers and images) read from beside the input, as auxiliary inputs.
    if matches!(name, "snow-cover" | "dust") {
        let dir = args.input.parent().map(PathBuf::from).unwrap_or_default();
        aux.extend(phenomena_engine::formats::mesh::gather_sidecars(
            &input,
            filename.as_deref(),
            &mut |rel| std::fs::read(dir.join(rel)).ok(),
        ));
    }
    let result = pool.install(|| {
        set.run_with_named_inputs(name, &params, &input, filename.as_deref(), &aux, &ctl)
    });
    bar.finish_and_clear();
    let outputs = match result {
        Ok(o) => o,
        Err(RunError::Canceled) => return Err(CliError::Canceled),
        Err(RunError::Input(e)) => return Err(e.into()),
        Err(RunError::Param(e)) => return Err(e.into()),
        Err(RunError::Refused { detail, .. }) => return Err(CliError::Unprocessable(detail)),
    };
    std::fs::create_dir_all(&args.out).map_err(|source| CliError::Io {
        path: args.out.clone(),
        source,
    })?;
    for o in &outputs {
        let path = args.out.join(&o.name);
        std::fs::write(&path, &o.bytes).map_err(|source| CliError::Io {
            path: path.clone(),
            source,
        })?;
        if !args.quiet {
            println!("{}  {} bytes", path.display(), o.bytes.len());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dotted_keys_nest() {
        let mut v = serde_json::json!({});
        set_dotted(&mut v, "camera.azimuth_deg", serde_json::json!(200)).unwrap();
        set_dotted(&mut v, "width", serde_json::json!(64)).unwrap();
        assert_eq!(
            v,
            serde_json::json!({"camera": {"azimuth_deg": 200}, "width": 64})
        );
        assert!(set_dotted(&mut v, "width.x", serde_json::json!(1)).is_err());
        assert!(set_dotted(&mut v, "a..b", serde_json::json!(1)).is_err());
    }
}
