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
    /// Also make this path a symlink to the pseudo-terminal (replacing an old symlink).
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
    let handle =
        connect::spawn_sim(&config, Arc::new(snakectl_sim::RealClock)).map_err(|e| match e {
            ConnectError::Sim {
                source: snakectl_sim::SimError::Pty(_) | snakectl_sim::SimError::Io(_),
                ..
            } => other(e.into()),
            _ => Failure::bad_input(e),
        })?;
    if let Some(link) = &args.link {
        if link
            .symlink_metadata()
            .is_ok_and(|m| m.file_type().is_symlink())
        {
            std::fs::remove_file(link)
                .map_err(|e| other(anyhow::anyhow!("{}: {e}", link.display())))?;
        }
        std::os::unix::fs::symlink(handle.path(), link)
            .map_err(|e| other(anyhow::anyhow!("{}: {e}", link.display())))?;
    }
    // Printed once the link exists: a script reading this line may use either at once.
    outln!("{}", handle.path().display())?;
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .map_err(|e| other(anyhow::anyhow!("installing the signal handler: {e}")))?;
    }
    while !stop.load(Ordering::Relaxed) && handle.is_running() {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    if let Some(link) = &args.link {
        let _ = std::fs::remove_file(link);
    }
    tracing::info!("stopping");
    handle.stop().map_err(|e| other(e.into()))
}
