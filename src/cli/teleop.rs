//! `snakectl teleop`: steer the tip from the keyboard or a joystick, the arm drawn live.

use std::path::PathBuf;

use clap::Args;

use super::Failure;

#[derive(Debug, Args)]
pub struct TeleopArgs {
    /// The daemon's address, `host:port` (default: `--sim`'s `[server] listen`, else
    /// 127.0.0.1:7878).
    #[arg(long, value_name = "ADDR")]
    pub connect: Option<String>,
    /// Start the simulator and the daemon in this process on CONFIG, listening on its
    /// `[server] listen`, and steer that.
    #[arg(long, value_name = "CONFIG", conflicts_with = "connect")]
    pub sim: Option<PathBuf>,
    /// A joystick device (`/dev/input/js0`, `/dev/input/event5`), or `auto` for the first
    /// `/dev/input/js*`.
    #[arg(long, value_name = "DEV|auto")]
    pub joystick: Option<String>,
    /// The joystick button that must be held for the stick to move the tip.
    #[arg(long, default_value_t = 4)]
    pub deadman_button: u8,
    /// A file whose first line is the daemon's token (`[server] token_file`).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
}

/// Runs the UI until `q`.
pub fn run(_args: TeleopArgs) -> Result<(), Failure> {
    Err(Failure::other(anyhow::anyhow!("not yet")))
}
