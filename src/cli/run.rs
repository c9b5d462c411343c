//! `snakectl run`: the control daemon on the config's arm, commanded over its socket.
//!
//! Its exit code says how it ended (docs/DAEMON.md, **Stopping**): 0 when every servo was left as
//! `[bus] on_exit` says, else [`EXIT_FAILED`], [`EXIT_REFUSED`] or [`EXIT_UNREACHED`].

use std::path::PathBuf;

use clap::Args;

use snakectl::config::Config;
use snakectl::daemon::view::ViewError;
use snakectl::daemon::{self, DaemonError, RunOptions};
use snakectl::record::RecordOptions;

use super::Failure;

/// The daemon failed while running (the socket, the loop's thread); the servos were shut down
/// after it as far as they could be.
pub const EXIT_FAILED: u8 = 1;
/// Start-up refused before the arm was brought up, or during bring-up: a bad config or token
/// file, a recording that cannot be created, a port that cannot be opened, a servo missing, of the wrong model, in hardware error or
/// outside its limits. The log names the cause.
pub const EXIT_REFUSED: u8 = 2;
/// Shut down, but servos could not be reached (silent, or the port lost): their state is
/// unknown (their torque may still be on). The log names each one.
pub const EXIT_UNREACHED: u8 = 3;

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Config file: the arm, `[bus]`, `[control]`, `[server]`.
    #[arg(long)]
    config: PathBuf,
    /// Open this serial port whatever `[bus] kind` says (a real adapter or a simulator's link);
    /// once per port of `[bus]`, in order, for a bus of several ports.
    #[arg(long)]
    port: Vec<PathBuf>,
    /// Listen here instead of `[server] listen` (`host:port`; port 0 picks a free one).
    #[arg(long)]
    listen: Option<std::net::SocketAddr>,
    /// Record the run to this MCAP file (JointState, tips, target, telemetry, events, the
    /// config); see docs/RECORDING.md.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Replace the `--record` file if it exists (else that is refused, and the file kept).
    #[arg(long, requires = "record")]
    overwrite: bool,
    /// More log lines (debug level); `RUST_LOG` overrides.
    #[arg(short, long)]
    verbose: bool,
}

/// Runs the daemon until SIGINT, SIGTERM or SIGHUP: the arm is brought to rest (at once when the
/// estop latch or a fault already holds it), then left as `[bus] on_exit` says; the exit code
/// says how that went.
pub fn run(args: RunArgs) -> Result<(), Failure> {
    super::init_logs(args.verbose);
    let config = Config::load(&args.config).map_err(Failure::bad_input)?;
    // Two ports on one device are refused before anything is bound or opened.
    snakectl::connect::check_ports(&config, &args.port).map_err(Failure::bad_input)?;
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
        // An address taken or not this host's refuses start-up, as a bad config does.
        let listener = tokio::net::TcpListener::bind(listen)
            .await
            .map_err(|e| Failure {
                code: EXIT_REFUSED,
                error: anyhow::anyhow!("listening on {listen}: {e}"),
            })?;
        let options = RunOptions {
            ports: args.port,
            record: args
                .record
                .map(|path| RecordOptions::to(path).overwriting(args.overwrite)),
        };
        let summary = daemon::run(config, listener, options, shutdown)
            .await
            .map_err(failure)?;
        tracing::info!(
            ticks = summary.ticks,
            overruns = summary.overruns,
            "stopped"
        );
        Ok(())
    })
}

/// The exit code and error of a daemon that did not end cleanly.
fn failure(e: DaemonError) -> Failure {
    let code = match e {
        DaemonError::BringUp(_)
        | DaemonError::Connect(_)
        | DaemonError::Controller(_)
        | DaemonError::Access(_)
        | DaemonError::Record(_)
        | DaemonError::ZenohNotBuilt { .. }
        | DaemonError::Foxglove {
            source: ViewError::Listen { .. },
            ..
        } => EXIT_REFUSED,
        // Only start-up returns it: a session that cannot open (an endpoint taken, no router)
        // or a config that would expose the arm's commands.
        #[cfg(feature = "zenoh")]
        DaemonError::Zenoh { .. } => EXIT_REFUSED,
        DaemonError::ShutDown(_) => EXIT_UNREACHED,
        _ => EXIT_FAILED,
    };
    Failure {
        code,
        error: e.into(),
    }
}

/// Installs the SIGINT, SIGTERM and SIGHUP handlers; the future resolves on the first of them.
/// A hang-up (the terminal or SSH session the daemon was started from closed) stops it as the
/// others do, never by default, which would leave the servos as a `kill -9` does.
fn signals() -> std::io::Result<impl std::future::Future<Output = ()>> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut int = signal(SignalKind::interrupt())?;
    let mut term = signal(SignalKind::terminate())?;
    let mut hup = signal(SignalKind::hangup())?;
    Ok(async move {
        tokio::select! {
            _ = int.recv() => {}
            _ = term.recv() => {}
            _ = hup.recv() => {}
        }
        tracing::info!("signal received: stopping");
    })
}
