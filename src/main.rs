//! The `phenomena` binary: `serve` (the HTTP service) and `render` (one pipeline run offline).

use anyhow::Context;
use clap::{Parser, Subcommand};
use phenomena::cli::RenderArgs;
use phenomena::config::{Config, LogFormat, ServeArgs};
use tracing_subscriber::EnvFilter;

#[derive(Debug, Parser)]
#[command(
    name = "phenomena",
    version,
    about = "Rendering service for natural phenomena"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the HTTP API and its workers (embedded job system, or Redis with `--redis-url`).
    Serve(Box<ServeArgs>),
    /// Run one pipeline offline: the same code the service's workers run.
    Render(RenderArgs),
}

fn init_tracing(format: LogFormat) {
    let filter = EnvFilter::try_from_env("PHENOMENA_LOG")
        .unwrap_or_else(|_| EnvFilter::new("info,tower_http=info"));
    let builder = tracing_subscriber::fmt().with_env_filter(filter);
    match format {
        LogFormat::Json => builder.json().init(),
        LogFormat::Text => builder.init(),
    }
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Serve(args) => {
            let cfg = Config::resolve(*args)?;
            init_tracing(cfg.log_format);
            tracing::info!(config = %serde_json::to_string(&cfg)?, "starting phenomena");
            let rt = tokio::runtime::Builder::new_multi_thread()
                .enable_all()
                .build()
                .context("cannot start the async runtime")?;
            rt.block_on(async move {
                let bind = cfg.bind;
                let state = phenomena::state(cfg).await?;
                let listener = tokio::net::TcpListener::bind(bind)
                    .await
                    .with_context(|| format!("cannot listen on {bind}"))?;
                tracing::info!(addr = %listener.local_addr()?, "listening");
                phenomena::run(listener, state, phenomena::shutdown_signal()).await?;
                tracing::info!("stopped");
                anyhow::Ok(())
            })
        }
        Command::Render(args) => Ok(phenomena::cli::render(args)?),
    }
}
