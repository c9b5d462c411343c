//! `snakectl run`: the control daemon on the config's arm, commanded over its socket.

use std::path::PathBuf;

use clap::Args;

use snakectl::config::Config;
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
        let listener = tokio::net::TcpListener::bind(listen)
            .await
            .map_err(|e| Failure::other(anyhow::anyhow!("listening on {listen}: {e}")))?;
        let local = listener
            .local_addr()
            .map_err(|e| Failure::other(anyhow::anyhow!("listening on {listen}: {e}")))?;
        tracing::info!("listening on {local}");
        let options = RunOptions { port: args.port };
        let summary = daemon::run(config, listener, options, signal())
            .await
            .map_err(|e| match e {
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

/// Resolves on the first SIGINT or SIGTERM.
async fn signal() {
    use tokio::signal::unix::{signal, SignalKind};
    match (
        signal(SignalKind::interrupt()),
        signal(SignalKind::terminate()),
    ) {
        (Ok(mut int), Ok(mut term)) => {
            tokio::select! {
                _ = int.recv() => {}
                _ = term.recv() => {}
            }
        }
        _ => {
            tracing::error!("signal handlers could not be installed: Ctrl-C ends the daemon hard");
            std::future::pending::<()>().await;
        }
    }
    tracing::info!("signal received: stopping");
}
