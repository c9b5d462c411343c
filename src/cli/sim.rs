//! `snakectl sim`: the config's servo chain, simulated, served on a pseudo-terminal (one per
//! port of a bus of several).

use std::path::{Path, PathBuf};
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
    /// pointing at it across `disconnect` faults and removed on exit. For a bus of several
    /// ports (`[[bus.ports]]`), once per port, in order: one simulator per port.
    #[arg(long)]
    link: Vec<PathBuf>,
    /// Log every packet (debug level); `RUST_LOG` overrides.
    #[arg(short, long)]
    verbose: bool,
}

/// Runs `snakectl sim` until SIGINT or SIGTERM.
pub fn run(args: SimArgs) -> Result<(), Failure> {
    super::init_logs(args.verbose);
    let other = Failure::other;
    let config = Config::load(&args.config).map_err(Failure::bad_input)?;
    let ports = config.bus().map_or(1, |b| b.ports.len());
    distinct_links(&args.link).map_err(Failure::bad_input)?;
    let links: Vec<connect::Link> = if args.link.is_empty() {
        (0..ports).map(|_| connect::Link::None).collect()
    } else {
        args.link.iter().cloned().map(connect::Link::At).collect()
    };
    let handles = connect::spawn_sims_linked(&config, Arc::new(snakectl_sim::RealClock), links)
        .map_err(|e| match e {
            ConnectError::Sim {
                source: snakectl_sim::SimError::Pty(_) | snakectl_sim::SimError::Io(_),
                ..
            } => other(e.into()),
            _ => Failure::bad_input(e),
        })?;
    // Printed once the links exist, one line per port in order: a script reading them may use
    // either at once. (A disconnect fault from the start has already unplugged a port: its
    // link is what comes back.)
    let ptys: Vec<PathBuf> = handles
        .iter()
        .map(|h| h.pty_path().unwrap_or_else(|| h.path().to_path_buf()))
        .collect();
    // The handlers go in before the line is printed: a script that signals as soon as it has
    // read it must find them installed, not the default action that kills the process.
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .map_err(|e| other(anyhow::anyhow!("installing the signal handler: {e}")))?;
    }
    for pty in &ptys {
        outln!("{}", pty.display())?;
    }
    while !stop.load(Ordering::Relaxed) && handles.iter().all(|h| h.is_running()) {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // Stopping a handle removes its link.
    tracing::info!("stopping");
    let mut stopped = Ok(());
    for h in handles {
        if let Err(e) = h.stop() {
            stopped = stopped.and(Err(other(e.into())));
        }
    }
    stopped
}

/// `--link` given twice for one path: the second would replace the first's symlink and leave
/// that port's pseudo-terminal without one.
#[derive(Debug, thiserror::Error)]
#[error("--link {link} ({path}) is the same path as --link {first}: give each port a link of its own", path = path.display())]
struct SameLink {
    /// The later `--link`, from 1 in order.
    link: usize,
    /// Its path as given.
    path: PathBuf,
    /// The earlier `--link` with that path, from 1.
    first: usize,
}

/// Refuses two `--link` flags for one path, compared as resolved: the directory with its
/// symbolic links followed (the link itself may not exist yet, or be an old one replaced).
fn distinct_links(links: &[PathBuf]) -> Result<(), SameLink> {
    let resolved: Vec<PathBuf> = links.iter().map(|l| resolve_link(l)).collect();
    for (k, path) in resolved.iter().enumerate() {
        if let Some(first) = resolved[..k].iter().position(|p| p == path) {
            return Err(SameLink {
                link: k + 1,
                path: links[k].clone(),
                first: first + 1,
            });
        }
    }
    Ok(())
}

/// Where `link` would be made: its directory resolved (the current one for a bare name), its
/// name kept; as written when the directory does not resolve.
fn resolve_link(link: &Path) -> PathBuf {
    let dir = match link.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    match (std::fs::canonicalize(dir), link.file_name()) {
        (Ok(dir), Some(name)) => dir.join(name),
        _ => link.to_path_buf(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_path_given_twice_as_link_is_refused_naming_both_flags() {
        let links = [
            PathBuf::from("a"),
            PathBuf::from("same"),
            PathBuf::from("./same"),
        ];
        let e = distinct_links(&links).err().map(|e| e.to_string());
        assert_eq!(
            e.as_deref(),
            Some(
                "--link 3 (./same) is the same path as --link 2: give each port a link of its own"
            )
        );
        assert!(distinct_links(&links[..2]).is_ok());
    }
}
