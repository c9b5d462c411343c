//! The control daemon: a fixed-rate loop on its own thread from commanded tip motion to servo
//! goals, and the JSON-lines socket that commands it.
//!
//! [`run`] opens the bus through [`crate::connect`], brings the arm up and starts the loop
//! ([`control_loop`]) on its own thread (the bus is blocking); only once the arm holds its
//! pose does it accept connections ([`server`]). The two sides meet in [`link`]: a bounded
//! command queue in (and one for `stop` and `estop`, so nothing queues ahead of them),
//! telemetry out latest-wins, events out through a bounded broadcast. When the shutdown future
//! resolves the loop tells every client (a `shutting_down` event), brings the arm to rest (at
//! once when a fault or the estop latch holds it) and leaves the servos as `[bus] on_exit`
//! says; then the server closes the connections and `run` returns.
//!
//! - [`access`]: who may connect (the token, and no listening beyond loopback without one).
//! - [`arbiter`]: who may command (one controller at a time).
//! - `bridge` (the `zenoh` feature): the daemon on a Zenoh network, in ROS 2's message formats.
//! - [`control_loop`]: the loop's thread: start-up, the fixed-rate cycle, the shut-down guard.
//! - [`embedded`]: the daemon started inside another program, on a loopback port.
//! - `gate`: the Foxglove view's only way in: the token, `max_clients`, the handshake.
//! - `hub`: the server side of the Foxglove WebSocket protocol, for the clients let in.
//! - [`link`]: the seam between the loop's thread and the socket side (bounded command queue,
//!   latest-wins telemetry, broadcast events).
//! - `outbox`: what waits for one Foxglove client, bounded, the oldest message data dropped for
//!   a client that falls behind.
//! - [`server`]: the JSON-lines TCP server on the socket side.
//! - [`side`]: a thread beside the loop serving another network (the view, the bridge).
//! - [`stats`]: fixed-size histograms for the run summary.
//! - [`view`]: the live Foxglove view (`[foxglove]`): the Foxglove WebSocket protocol on its
//!   own thread.

pub mod access;
pub mod arbiter;
#[cfg(feature = "zenoh")]
pub mod bridge;
pub mod control_loop;
pub mod embedded;
mod gate;
mod hub;
pub mod link;
mod outbox;
pub mod server;
pub mod side;
pub mod stats;
pub mod view;

use std::future::Future;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use tokio::net::TcpListener;
use tokio::sync::oneshot;

pub use embedded::Embedded;

use crate::config::Config;
use crate::connect::ConnectError;
use crate::control::Refused;
use crate::record::{RecordError, RecordOptions, Recorder, Setup};
use crate::servo::arm::{BringUpError, ShutDownError};

/// How [`run`] reaches the servos, beyond what the config says.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Open these ports whatever `[bus] kind` says (real adapters, or external simulators'
    /// links), one per port of `[bus]`, in order; empty: as the file says.
    pub ports: Vec<PathBuf>,
    /// Record the run to this MCAP file ([`crate::record`]); `None`: no recording.
    pub record: Option<RecordOptions>,
}

impl RunOptions {
    /// The one port of a one-port bus.
    pub fn port(path: impl Into<PathBuf>) -> Self {
        Self {
            ports: vec![path.into()],
            record: None,
        }
    }

    /// These options, the run recorded as `record` says.
    pub fn recorded(self, record: Option<RecordOptions>) -> Self {
        Self { record, ..self }
    }
}

/// What a daemon that stopped cleanly did (since start, or since the last `reset_stats`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Ticks run.
    pub ticks: u64,
    /// Periods skipped because a tick ran late.
    pub overruns: u64,
    /// Wall time the ticks took, s.
    pub elapsed_s: f64,
    /// A tick's working time (commands, motion, resolve, write, read, publish).
    pub tick: stats::Percentiles,
    /// The controller's share of it (motion, resolve, joint-speed limit).
    pub solve: stats::Percentiles,
    /// From the server reading a command's line to the Sync Write of the tick that applied it
    /// handed to the port.
    pub command_to_wire: stats::Percentiles,
}

impl Summary {
    /// Ticks per second achieved.
    pub fn rate_hz(&self) -> f64 {
        if self.elapsed_s > 0.0 {
            self.ticks as f64 / self.elapsed_s
        } else {
            0.0
        }
    }
}

/// Why the daemon could not start or stopped badly.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DaemonError {
    /// The bus could not be opened.
    #[error(transparent)]
    Connect(#[from] ConnectError),
    /// Bring-up refused or failed (a servo missing, of the wrong model, a joint outside its
    /// limits, ...).
    #[error(transparent)]
    BringUp(#[from] BringUpError),
    /// The measured pose cannot seed the controller.
    #[error("the measured pose cannot start the controller: {0}")]
    Controller(Refused),
    /// The loop's thread could not be started.
    #[error("starting the control loop's thread: {0}")]
    Thread(std::io::Error),
    /// `[control] realtime_priority` is set and the loop's thread could not take it.
    #[error("{}: control.realtime_priority: the control loop's thread {source}", path.display())]
    Realtime {
        /// The config file.
        path: PathBuf,
        /// Why.
        source: crate::beside::RealtimeError,
    },
    /// The socket failed.
    #[error("the command socket: {0}")]
    Socket(std::io::Error),
    /// The loop panicked; the servos were shut down after it.
    #[error("the control loop panicked (the servos were shut down after it)")]
    LoopPanicked,
    /// Shut-down could not reach every servo.
    #[error(transparent)]
    ShutDown(#[from] ShutDownError),
    /// The token file cannot be used, or the address is open to other hosts without a token.
    #[error(transparent)]
    Access(#[from] access::AccessError),
    /// The recording's file could not be created (a recording that fails later stops, the arm
    /// does not).
    #[error(transparent)]
    Record(RecordError),
    /// Start-up failed and its error went to the waiting [`run`].
    #[error("start-up failed")]
    StartUpReported,
    /// The config enables Zenoh, which this build does not have.
    #[error(
        "{}: [zenoh] enabled = true, but this snakectl was built without Zenoh: build it with \
         `cargo build --release --features zenoh` (or set enabled = false)",
        path.display()
    )]
    ZenohNotBuilt {
        /// The config file.
        path: PathBuf,
    },
    /// The Foxglove view could not start.
    #[error("{}: [foxglove]: {source}", path.display())]
    Foxglove {
        /// The config file.
        path: PathBuf,
        /// Why.
        source: view::ViewError,
    },
    /// The Zenoh session could not be opened or set up.
    #[cfg(feature = "zenoh")]
    #[error("{}: [zenoh]: {source}", path.display())]
    Zenoh {
        /// The config file.
        path: PathBuf,
        /// Why.
        source: bridge::NetError,
    },
}

/// Refuses a config that enables Zenoh in a build without the `zenoh` feature.
pub fn check_zenoh_built(config: &Config) -> Result<(), DaemonError> {
    if config.zenoh().enabled && !cfg!(feature = "zenoh") {
        return Err(DaemonError::ZenohNotBuilt {
            path: config.path().to_path_buf(),
        });
    }
    Ok(())
}

/// Runs the daemon on `config` until `shutdown` resolves: bring-up, then the loop, commanded
/// through `listener`. Connections that arrive before the arm is up wait in the listener's
/// backlog for their first reply.
///
/// Before anything moves, `[zenoh] enabled = true` in a build without Zenoh is refused
/// ([`DaemonError::ZenohNotBuilt`]), the `[server] token_file` is read and a `listener` on an
/// address other than loopback without one is refused ([`DaemonError::Access`]), and, with
/// the `zenoh` feature and the table enabled, the Zenoh session is opened; with a
/// `[foxglove] listen`, the Foxglove server is bound; with [`RunOptions::record`] the
/// recording's file is created.
pub async fn run(
    config: Config,
    listener: TcpListener,
    options: RunOptions,
    shutdown: impl Future<Output = ()>,
) -> Result<Summary, DaemonError> {
    check_zenoh_built(&config)?;
    let joints = config.chain().len();
    let max_clients = config.server().max_clients as usize;
    let addr = listener.local_addr().map_err(DaemonError::Socket)?;
    let access = access::Access::prepare(config.server(), addr)?;
    // Opened before anything moves: a taken endpoint stops start-up here.
    #[cfg(feature = "zenoh")]
    let mut bridge = match config.zenoh().enabled {
        true => Some(
            bridge::Bridge::open(&config)
                .await
                .map_err(|source| DaemonError::Zenoh {
                    path: config.path().to_path_buf(),
                    source,
                })?,
        ),
        false => None,
    };
    let mut foxglove = view::View::open(&config, access.token.clone())
        .await
        .map_err(|source| DaemonError::Foxglove {
            path: config.path().to_path_buf(),
            source,
        })?;
    // Created before anything moves: a file that cannot be made stops start-up here.
    let (recorder, tap) = match &options.record {
        Some(r) => {
            let (recorder, tap) =
                Recorder::create(r, Setup::of(&config)).map_err(DaemonError::Record)?;
            tracing::info!("recording to {}", r.path.display());
            (Some(recorder), Some(tap))
        }
        None => (None, None),
    };
    // Connections are taken from here on, but answered only once the arm is up (the loop
    // logs that it is serving).
    tracing::info!("listening on {addr} (bringing the arm up first)");
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_tx, ready_rx) = oneshot::channel();
    let (done_tx, mut done_rx) = oneshot::channel();
    let loop_stop = stop.clone();
    std::thread::Builder::new()
        .name("snakectl-loop".into())
        .spawn(move || {
            let result = control_loop::main(config, options, loop_stop, ready_tx, tap);
            let _ = done_tx.send(result);
        })
        .map_err(DaemonError::Thread)?;

    let handle = match ready_rx.await {
        Ok(Ok(handle)) => Ok(handle),
        Ok(Err(e)) => Err(e),
        // The thread ended without a word: it panicked during start-up.
        Err(_) => match (&mut done_rx).await {
            Ok(Err(e)) => Err(e),
            _ => Err(DaemonError::LoopPanicked),
        },
    };
    let handle = match handle {
        Ok(handle) => handle,
        Err(e) => {
            if let Some(recorder) = recorder {
                recorder.discard();
            }
            return Err(e);
        }
    };

    if let (Some(recorder), Ok(describe)) = (&recorder, serde_json::to_string(&*handle.describe)) {
        recorder.note(
            "snakectl.describe",
            std::collections::BTreeMap::from([("describe".to_owned(), describe)]),
        );
    }
    let mut ended = None;
    let served = {
        // The server outlives the loop: clients see the arm come to rest, hear the
        // `shutting_down` event, and get the answers the loop gave last, before their
        // connections close.
        let shutdown = async {
            tokio::select! {
                () = shutdown => {
                    stop.store(true, Ordering::Relaxed);
                    ended = Some((&mut done_rx).await.unwrap_or(Err(DaemonError::LoopPanicked)));
                }
                // The loop ended by itself (it panicked): stop serving too.
                r = &mut done_rx => ended = Some(r.unwrap_or(Err(DaemonError::LoopPanicked))),
            }
        };
        let options = server::ServerOptions::new(joints, max_clients).with_token(access.token);
        let server = server::Server::new(handle, options);
        #[cfg(feature = "zenoh")]
        if let Some(bridge) = bridge.as_mut() {
            bridge.start(server.door());
        }
        if let Some(foxglove) = foxglove.as_mut() {
            foxglove.start(server.door());
        }
        server.serve(listener, shutdown).await
    };
    if let Some(foxglove) = foxglove.take() {
        foxglove.stop().await;
    }
    #[cfg(feature = "zenoh")]
    if let Some(bridge) = bridge.take() {
        bridge.stop().await;
    }
    // The server may have stopped by itself (accept kept failing): the loop stops too.
    stop.store(true, Ordering::Relaxed);
    let result = match ended {
        Some(r) => r,
        None => done_rx.await.unwrap_or(Err(DaemonError::LoopPanicked)),
    };
    // The loop offers nothing more: what is queued is written, then the account.
    if let Some(recorder) = recorder {
        recorder.close();
    }
    served.map_err(DaemonError::Socket)?;
    result
}
