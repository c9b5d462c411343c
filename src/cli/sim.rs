//! `snakectl sim`: the config's servo chain, simulated, served on a pseudo-terminal.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use clap::Args;

use snakectl::config::Config;
use snakectl::connect::{self, ConnectError};

use super::{outln, Failure};

#[derive(Debug, Args)]
pub struct SimArgs {
    /// Config file: the servos (ids, models, limits), `[bus]` baud and delay, `[sim]` faults.
    #[arg(long)]
    config: PathBuf,
    /// Also make this path a symlink to the pseudo-terminal (replacing an old symlink), kept
    /// pointing at it across `disconnect` faults and removed on exit.
    #[arg(long)]
    link: Option<PathBuf>,
    /// Log every packet (debug level); `RUST_LOG` overrides.
    #[arg(short, long)]
    verbose: bool,
}

/// Runs `snakectl sim` until SIGINT or SIGTERM.
pub fn run(args: SimArgs) -> Result<(), Failure> {
    super::init_logs(args.verbose);
    let other = Failure::other;
    let config = Config::load(&args.config).map_err(Failure::bad_input)?;
    let link = match &args.link {
        Some(path) => connect::Link::At(path.clone()),
        None => connect::Link::None,
    };
    let handle = connect::spawn_sim_linked(&config, Arc::new(snakectl_sim::RealClock), link)
        .map_err(|e| match e {
            ConnectError::Sim {
                source: snakectl_sim::SimError::Pty(_) | snakectl_sim::SimError::Io(_),
                ..
            } => other(e.into()),
            _ => Failure::bad_input(e),
        })?;
    // Printed once the link exists: a script reading this line may use either at once. (A
    // disconnect fault from the start has already unplugged it: the link is what comes back.)
    let pty = handle
        .pty_path()
        .unwrap_or_else(|| handle.path().to_path_buf());
    // The handlers go in before the line is printed: a script that signals as soon as it has
    // read it must find them installed, not the default action that kills the process.
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .map_err(|e| other(anyhow::anyhow!("installing the signal handler: {e}")))?;
    }
    outln!("{}", pty.display())?;
    while !stop.load(Ordering::Relaxed) && handle.is_running() {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // Stopping the handle removes the link.
    tracing::info!("stopping");
    handle.stop().map_err(|e| other(e.into()))
}
