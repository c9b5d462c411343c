//! The seam between the control loop's thread and the socket side.
//!
//! Commands go in through one bounded queue ([`COMMAND_QUEUE`] envelopes; when it is full the
//! server answers `busy` at once instead of waiting), each with a oneshot for its reply, sent once
//! the loop has applied the command (and one to say the reply comes later, for a command the
//! loop works on over ticks). `stop` and `estop` have a queue of their own
//! ([`STOP_QUEUE`]), so that no backlog of other commands can hold them back; the loop drains
//! both at the start of every tick and applies what it took in the order the lines arrived.
//! Telemetry comes out latest-wins through a `watch` (a slow reader sees fewer snapshots, never
//! older ones). Events go out through a `broadcast` of
//! [`EVENT_QUEUE`] slots (a reader that falls that far behind loses the oldest, and is told
//! how many it lost). A `Notify` says when a tick's work is done, after its time is taken:
//! a side thread that waits for it publishes in the idle rest of the loop's period, and the
//! loop wakes it outside its tick.

use std::sync::Arc;
use std::time::Instant;

use tokio::sync::{broadcast, mpsc, oneshot, watch, Notify};

pub use crate::protocol::Answer;
use crate::protocol::{ClientId, Describe, Event, LoopCmd, RequestId, Telemetry};

/// Envelopes the command queue holds.
pub const COMMAND_QUEUE: usize = 64;

/// Envelopes the `stop`/`estop` queue holds: far more than the clients can fill in one tick
/// within their share ([`crate::daemon::server::STOPS_IN_FLIGHT`] each).
pub const STOP_QUEUE: usize = 256;

/// Events the broadcast holds for its slowest reader.
pub const EVENT_QUEUE: usize = 256;

/// One command on its way to the loop.
#[derive(Debug)]
pub struct Envelope {
    /// Who sent it.
    pub client: ClientId,
    /// Its request id, when it had one.
    pub id: Option<RequestId>,
    /// The command, validated and routed to the loop.
    pub cmd: LoopCmd,
    /// When the server read its line (the start of the command-to-wire latency).
    pub received: Instant,
    /// Where the loop sends the answer once it has applied the command. A client gone by then
    /// is not an error.
    pub reply: oneshot::Sender<Answer>,
    /// Told when the loop keeps the answer for later than the tick that takes the command (a
    /// `goto`, `path` or `reach` planned beside the loop, a `reboot`): the sender's connection
    /// then serves its lines after it meanwhile. `None`: the sender waits for the answer
    /// whenever it comes.
    pub later: Option<oneshot::Sender<()>>,
}

/// What the socket side holds of a running loop.
#[derive(Debug, Clone)]
pub struct Handle {
    /// The command queue (bounded: full means `busy`).
    pub commands: mpsc::Sender<Envelope>,
    /// The queue of `stop` and `estop`, beside the other commands' so never behind them.
    pub stops: mpsc::Sender<Envelope>,
    /// The latest telemetry snapshot.
    pub telemetry: watch::Receiver<Telemetry>,
    /// Events; each client subscribes its own receiver.
    pub events: broadcast::Sender<Event>,
    /// Notified (`notify_waiters`) each time a tick's work is done.
    pub tick_done: Arc<Notify>,
    /// The arm's description, fixed for the daemon's life.
    pub describe: Arc<Describe>,
}

/// The loop's ends of the same channels.
#[derive(Debug)]
pub struct LoopEnds {
    /// Commands, drained with `try_recv` at the start of each tick.
    pub commands: mpsc::Receiver<Envelope>,
    /// `stop` and `estop`, drained with the commands.
    pub stops: mpsc::Receiver<Envelope>,
    /// Telemetry, updated in place with `send_modify` (no allocation once warm).
    pub telemetry: watch::Sender<Telemetry>,
    /// Events.
    pub events: broadcast::Sender<Event>,
    /// Notified once a tick's work is done, outside the tick's time.
    pub tick_done: Arc<Notify>,
}

/// A connected pair of ends, the telemetry starting from `initial`.
pub fn channel(describe: Describe, initial: Telemetry) -> (Handle, LoopEnds) {
    let (commands_tx, commands_rx) = mpsc::channel(COMMAND_QUEUE);
    let (stops_tx, stops_rx) = mpsc::channel(STOP_QUEUE);
    let (telemetry_tx, telemetry_rx) = watch::channel(initial);
    let (events_tx, _) = broadcast::channel(EVENT_QUEUE);
    let tick_done = Arc::new(Notify::new());
    (
        Handle {
            commands: commands_tx,
            stops: stops_tx,
            telemetry: telemetry_rx,
            events: events_tx.clone(),
            tick_done: Arc::clone(&tick_done),
            describe: Arc::new(describe),
        },
        LoopEnds {
            commands: commands_rx,
            stops: stops_rx,
            telemetry: telemetry_tx,
            events: events_tx,
            tick_done,
        },
    )
}
