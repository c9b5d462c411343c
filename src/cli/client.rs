//! The one-shot clients: `status`, `describe`, `goto`, `path`, `stop`, `estop`, `reset`, `home`,
//! `strategy`, `watch`. Each connects to the daemon's socket, does one thing and exits.

use std::path::PathBuf;

use clap::Args;

use super::Failure;

/// Where the daemon is and how to get in: every client takes these.
#[derive(Debug, Clone, Args)]
pub struct ConnectArgs {
    /// The daemon's address, `host:port`.
    #[arg(long, value_name = "ADDR", default_value = snakectl::client::DEFAULT_ADDR)]
    pub connect: String,
    /// A file whose first line is the daemon's token (`[server] token_file`).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
}

/// Arguments of the commands that take nothing else.
#[derive(Debug, Args)]
pub struct PlainArgs {
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `goto X Y`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct GotoArgs {
    /// Target x, m (world frame).
    pub x: f64,
    /// Target y, m.
    pub y: f64,
    /// Tip speed, m/s (default: the daemon's tip speed limit).
    #[arg(long)]
    pub speed: Option<f64>,
    /// Return once the daemon has accepted the command, without waiting for the arrival.
    #[arg(long)]
    pub no_wait: bool,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `path FILE.csv`.
#[derive(Debug, Args)]
pub struct PathArgs {
    /// CSV file, two columns `x,y` in metres, an optional header line.
    pub file: PathBuf,
    /// Tip speed, m/s (default: the daemon's tip speed limit).
    #[arg(long)]
    pub speed: Option<f64>,
    /// Return once the daemon has accepted the command, without waiting for the arrival.
    #[arg(long)]
    pub no_wait: bool,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `strategy NAME`.
#[derive(Debug, Args)]
pub struct StrategyArgs {
    /// `overall` or `sequential`.
    pub name: String,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `watch`.
#[derive(Debug, Args)]
pub struct WatchArgs {
    /// Telemetry lines per second.
    #[arg(long, default_value_t = 10.0)]
    pub rate_hz: f64,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `snakectl status`.
pub fn status(_args: PlainArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl describe`.
pub fn describe(_args: PlainArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl goto`.
pub fn goto(_args: GotoArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl path`.
pub fn path(_args: PathArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl stop`.
pub fn stop(_args: PlainArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl estop`.
pub fn estop(_args: PlainArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl reset`.
pub fn reset(_args: PlainArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl home`.
pub fn home(_args: PlainArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl strategy`.
pub fn strategy(_args: StrategyArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}

/// `snakectl watch`.
pub fn watch(_args: WatchArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}
