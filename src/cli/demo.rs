//! `snakectl demo` (and `cargo run --release` with no arguments): the whole product in one
//! command, driven through the daemon's socket as any client would drive it.

use std::path::PathBuf;

use clap::Args;

use super::Failure;

#[derive(Debug, Args, Default)]
pub struct DemoArgs {
    /// The simulated arm's config (default: the shipped `config/sim.toml`).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Where to write `summary.json` and the figures.
    #[arg(long, value_name = "DIR", default_value = "snakectl-demo")]
    pub out: PathBuf,
    /// How long the figure eights take, each, s (the whole demo takes about twice this, plus
    /// the path).
    #[arg(long)]
    pub seconds: Option<f64>,
}

/// Runs the demo and writes its outputs.
pub fn run(_args: DemoArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}
