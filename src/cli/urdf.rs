//! `snakectl urdf`: the configured arm as a URDF on stdout, for `robot_state_publisher` and
//! RViz.

use std::path::PathBuf;

use clap::Args;

use snakectl::config::Config;

use super::{outln, Failure};

/// The shipped simulator config, compiled in: the arm described when no `--config` is given.
/// Compiled in rather than read, so that the default does not hang on the current directory; the
/// URDF's header names it as such, so that nobody takes it for their own config/sim.toml.
const SHIPPED: &str = include_str!("../../config/sim.toml");
const SHIPPED_PATH: &str = "the built-in copy of the shipped config/sim.toml";

#[derive(Debug, Args)]
pub struct UrdfArgs {
    /// Config file: the arm (`[arm]`, `[[joint]]`), `[world] link_radius_m` and
    /// `[control] max_joint_speed_rad_s`. Default: the built-in copy of the shipped
    /// config/sim.toml (compiled in: a config/sim.toml in the current directory is not read;
    /// pass it with --config).
    #[arg(long)]
    config: Option<PathBuf>,
}

/// Prints the URDF.
pub fn run(args: UrdfArgs) -> Result<(), Failure> {
    let config = match &args.config {
        Some(path) => Config::load(path).map_err(Failure::bad_input)?,
        None => Config::from_str(SHIPPED, SHIPPED_PATH).map_err(Failure::other)?,
    };
    let text = snakectl::urdf::urdf(&config);
    outln!("{}", text.trim_end())
}
