//! `snakectl run`: the control daemon on the config's arm, commanded over its socket.

use std::path::PathBuf;

use clap::Args;

use snakectl::config::Config;
use snakectl::connect::ConnectError;
use snakectl::daemon::{self, DaemonError, RunOptions};

use super::Failure;

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Config file: the arm, `[bus]`, `[control]`, `[server]`.
    #[arg(long)]
    config: PathBuf,
    /// Open this serial port whatever `[bus] kind` says (a real adapter or a simulator's link).
    #[arg(long)]
    port: Option<PathBuf>,
    /// Listen here instead of `[server] listen` (`host:port`; port 0 picks a free one).
    #[arg(long)]
    listen: Option<std::net::SocketAddr>,
    /// More log lines (debug level); `RUST_LOG` overrides.
    #[arg(short, long)]
    verbose: bool,
}

/// Runs the daemon until SIGINT or SIGTERM: the arm is brought to rest, then left as
/// `[bus] on_exit` says.
pub fn run(args: RunArgs) -> Result<(), Failure> {
    super::init_logs(args.verbose);
    let config = Config::load(&args.config).map_err(Failure::bad_input)?;
    let listen = args.listen.unwrap_or(config.server().listen);
    // The socket side is light: one thread of its own, off the loop's.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::other(anyhow::anyhow!("starting the runtime: {e}")))?;
    runtime.block_on(async move {
        // Installed before anything is announced: a signal from then on stops the daemon
        // gracefully (once the arm is up, if it comes during bring-up), never by default.
        let shutdown = signals()
            .map_err(|e| Failure::other(anyhow::anyhow!("installing the signal handlers: {e}")))?;
        let listener = tokio::net::TcpListener::bind(listen)
            .await
            .map_err(|e| Failure::other(anyhow::anyhow!("listening on {listen}: {e}")))?;
        let local = listener
            .local_addr()
            .map_err(|e| Failure::other(anyhow::anyhow!("listening on {listen}: {e}")))?;
        tracing::info!("listening on {local}");
        let options = RunOptions { port: args.port };
        let summary = daemon::run(config, listener, options, shutdown)
            .await
            .map_err(|e| match e {
                // Not the input's fault: the port is busy, and free again once its holder exits.
                DaemonError::Connect(ConnectError::InUse(_)) => Failure::other(e),
                DaemonError::BringUp(_) | DaemonError::Connect(_) | DaemonError::Controller(_) => {
                    Failure::bad_input(e)
                }
                e => Failure::other(e),
            })?;
        tracing::info!(
            ticks = summary.ticks,
            overruns = summary.overruns,
            "stopped"
        );
        Ok(())
    })
}

/// Installs the SIGINT and SIGTERM handlers; the future resolves on the first of them.
fn signals() -> std::io::Result<impl std::future::Future<Output = ()>> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut int = signal(SignalKind::interrupt())?;
    let mut term = signal(SignalKind::terminate())?;
    Ok(async move {
        tokio::select! {
            _ = int.recv() => {}
            _ = term.recv() => {}
        }
        tracing::info!("signal received: stopping");
    })
}
