//! A client of the daemon's socket, for the one-shot commands, teleop and the demo: connect
//! (with the token, where the daemon wants one), send requests, wait for their replies, read
//! events and the latest telemetry, and run a motion command to its end ([`Client::start_motion`],
//! [`Client::wait_ending`]).
//!
//! Everything is read with the daemon's own types ([`crate::protocol`]): replies are typed by
//! the command they answer ([`Fields`]), telemetry is a [`Status`], events are [`Event`]s, the
//! arm is built from `describe` into an [`ArmInfo`] whose forward kinematics are its
//! [`Chain`]'s. A field a newer daemon adds, or an event name it adds, is not an error; a line
//! this client cannot read is, and it is handed to the caller with the line
//! ([`ClientError::Unreadable`]), never dropped.
//!
//! One thread per connection reads the socket into one inbox: replies, events and unreadable
//! lines queue in arrival order, telemetry goes into a latest-wins slot, so a reader that falls
//! behind sees the newest snapshot, never a backlog. The queue is bounded by count (1024) and by
//! bytes ([`QUEUE_BYTES`]): past either the reading thread waits for the caller. A request
//! waiting for its reply lets it grow past them, to find the reply behind what waits, up to
//! [`MAX_QUEUE_BYTES`] in all; past that the connection is closed
//! ([`ClientError::Backlog`]). Nothing queued is dropped.

use std::collections::{HashMap, VecDeque};
use std::fmt;
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::ops::Deref;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::chain::{Chain, ChainError};
use crate::protocol::{
    self, world_rejection, ClientId, ReadError, ReplyLine, RequestId, ServerLine,
};
pub use crate::protocol::{
    Cmd, CmdName, Code, CommandInfo, Describe, Event, EventKind, FaultChange, FaultInfo, FaultKind,
    Fields, Rejection, Reply, State, Status, StopReason, Telemetry, TookControl, What, WorldInfo,
};
use crate::world::{CheckedObstacle, Obstacles};
pub use crate::world::{Obstacle, Shape};

/// Where the daemon listens unless told otherwise (`[server] listen` of the shipped configs).
pub const DEFAULT_ADDR: &str = "127.0.0.1:7878";

/// How long [`Client::request`] waits for a reply by default. Replies come within a tick or
/// two (a `reboot`'s once its servos are back, a `goto`'s whose routes are planned beside the
/// loop once they are); the first waits for the arm's bring-up.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(10);

/// How long a request's line may wait, by default, for the daemon to take it (see
/// [`Client::set_write_timeout`]): as long as a reply may take.
pub const WRITE_TIMEOUT: Duration = REPLY_TIMEOUT;

/// The shortest wait a write is given, even past its deadline: one try.
const MIN_WRITE_WAIT: Duration = Duration::from_millis(1);

/// Replies, events and unreadable lines held for the caller before the reading thread waits
/// for it (unless a request is waiting for its reply behind them).
const QUEUE: usize = 1024;

/// Bytes of lines (as they came) held for the caller before the reading thread waits for it,
/// beside the count of 1024 lines, which alone would let lines of up to [`MAX_REPLY_LINE`]
/// hold 4 GiB.
pub const QUEUE_BYTES: usize = 8 << 20;

/// The most the queue holds while a request waits for its reply behind it, bytes of lines:
/// past it the connection is closed ([`ClientError::Backlog`]). Twice [`QUEUE_BYTES`], so that
/// a request sent with the queue full still has room to find its reply.
pub const MAX_QUEUE_BYTES: usize = 2 * QUEUE_BYTES;

/// The most of a line an error message shows (the error itself carries all of it).
const SHOWN: usize = 200;

/// The longest line read from the daemon, bytes: past it the connection is closed
/// ([`ClientError::LineTooLong`]), so a daemon gone wrong cannot make the client hold without
/// end. Generous: the largest reply, `world`'s with [`crate::world::MAX_OBSTACLES`] obstacles
/// and [`crate::world::MAX_POLYGON_POINTS`] points, is some 100 kB, and the daemon reads
/// requests of at most [`protocol::MAX_LINE`] bytes.
pub const MAX_REPLY_LINE: usize = 4 * protocol::MAX_LINE;

/// Why a client could not talk to the daemon.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClientError {
    /// Nothing listens at the address.
    #[error(
        "no daemon is listening on {addr}: start one with `snakectl run --config config/sim.toml` \
         (or `snakectl teleop --sim config/sim.toml`), or pass --connect ADDR"
    )]
    NoDaemon {
        /// The address tried.
        addr: String,
    },
    /// The address could not be resolved or reached.
    #[error("cannot connect to {addr}: {source}")]
    Connect {
        /// The address tried.
        addr: String,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The token file could not be read.
    #[error("{}: cannot read the token file: {source}", path.display())]
    TokenFile {
        /// The file.
        path: PathBuf,
        /// Why: what the operating system said, or not a regular file, or too large.
        source: crate::textfile::TextFileError,
    },
    /// The token file holds nothing but blanks.
    #[error("{}: the token file is empty: its first line is the token", path.display())]
    EmptyToken {
        /// The file.
        path: PathBuf,
    },
    /// The token file's first line is blank, a later one not: only the first line is read.
    #[error(
        "{}: the first line of the token file is blank: the token is the first line, and line \
         {line} is not read (move the token to line 1)",
        path.display()
    )]
    BlankFirstLine {
        /// The file.
        path: PathBuf,
        /// The first line that is not blank, from 1.
        line: usize,
    },
    /// The daemon closed the connection (it stopped, or it refused this client).
    #[error("the daemon at {addr} closed the connection{}", reason.as_ref().map(|r| format!(": {}", Escaped(&r.to_string()))).unwrap_or_default())]
    Closed {
        /// Its address.
        addr: String,
        /// The last refusal it sent, if any (`unauthorized`, `too_many_clients`).
        reason: Option<Rejection>,
    },
    /// The daemon refused a request.
    #[error("`{cmd}` refused: {}", Escaped(&rejection.to_string()))]
    Refused {
        /// The request's command.
        cmd: CmdName,
        /// The daemon's code and message.
        rejection: Rejection,
    },
    /// No reply within the time allowed.
    #[error("no reply to `{cmd}` within {} ms", timeout.as_millis())]
    Timeout {
        /// The request's command.
        cmd: CmdName,
        /// How long it waited.
        timeout: Duration,
    },
    /// A reply to a request of this client's without the fields its command answers.
    #[error("cannot read the daemon's reply to `{cmd}`: {source}: {}", Shown(line))]
    BadReply {
        /// The request's command.
        cmd: CmdName,
        /// The line as it came.
        line: String,
        /// What did not fit.
        source: serde_json::Error,
    },
    /// A line this client cannot read at all.
    #[error("cannot read a line from the daemon: {source}: {}", Shown(line))]
    Unreadable {
        /// The line as it came.
        line: String,
        /// Why it does not read.
        source: ReadError,
    },
    /// The daemon sent a line longer than [`MAX_REPLY_LINE`]: the connection was closed.
    #[error(
        "the daemon at {addr} sent a line over {max} bytes (it begins: {}); the connection is \
         closed",
        Shown(start)
    )]
    LineTooLong {
        /// Its address.
        addr: String,
        /// The most a line may hold, bytes.
        max: usize,
        /// The line's first bytes.
        start: String,
    },
    /// Replies and events left unread filled the queue ([`MAX_QUEUE_BYTES`]) while a request
    /// waited for its reply behind them: the connection was closed. What was queued is still
    /// read, in order, before this error.
    #[error(
        "the daemon at {addr} sent over {max} bytes of replies and events left unread while a \
         request waited for its reply; the connection is closed"
    )]
    Backlog {
        /// Its address.
        addr: String,
        /// The most the queue holds, bytes.
        max: usize,
    },
    /// An ok reply whose id names no request of this client's.
    #[error("a reply to no request of this client: {}", Shown(line))]
    Stray {
        /// The line as it came.
        line: String,
    },
    /// A reply read as another command's than the one asked (replies are typed by the command
    /// they answer, so this is a fault of this client's).
    #[error("the reply to `{cmd}` was read as another command's")]
    WrongReply {
        /// The command asked.
        cmd: CmdName,
    },
    /// `describe` described an arm no chain can be built from.
    #[error("the daemon describes an arm that cannot be drawn: {source}")]
    BadArm {
        /// Why its chain was refused.
        source: ChainError,
    },
    /// The daemon took no more of a request's line within the time allowed: it has stopped
    /// reading. The connection is closed, since the line may be half sent.
    #[error(
        "the daemon at {addr} took no `{cmd}` request within {} ms: it has stopped reading; \
         the connection is closed",
        timeout.as_millis()
    )]
    WriteTimeout {
        /// Its address.
        addr: String,
        /// The request's command.
        cmd: CmdName,
        /// How long the write waited.
        timeout: Duration,
    },
    /// Writing to the socket failed.
    #[error("cannot write to the daemon at {addr}: {source}")]
    Write {
        /// Its address.
        addr: String,
        /// What the operating system said.
        source: std::io::Error,
    },
}

impl ClientError {
    /// The daemon's error code: of a refused request, or of the refusal it closed the
    /// connection with.
    pub fn code(&self) -> Option<Code> {
        match self {
            ClientError::Refused { rejection, .. } => Some(rejection.code),
            ClientError::Closed { reason, .. } => reason.as_ref().map(|r| r.code),
            _ => None,
        }
    }

    /// Whether the connection is gone (rather than one line or one request having failed).
    pub fn is_closed(&self) -> bool {
        matches!(
            self,
            ClientError::Closed { .. }
                | ClientError::WriteTimeout { .. }
                | ClientError::LineTooLong { .. }
                | ClientError::Backlog { .. }
        )
    }
}

/// A line in a message: its first [`SHOWN`] bytes, escaped as [`Escaped`].
struct Shown<'a>(&'a str);

impl fmt::Display for Shown<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0.len() <= SHOWN {
            return Escaped(self.0).fmt(f);
        }
        let mut end = SHOWN;
        while !self.0.is_char_boundary(end) {
            end -= 1;
        }
        write!(f, "{}...", Escaped(self.0.get(..end).unwrap_or_default()))
    }
}

/// Text the daemon sent, in a message: control characters escaped (`\0`, `\u{1b}`), so that
/// what reaches a terminal is only printable.
struct Escaped<'a>(&'a str);

impl fmt::Display for Escaped<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for c in self.0.chars() {
            if c.is_control() {
                write!(f, "{}", c.escape_debug())?;
            } else {
                fmt::Write::write_char(f, c)?;
            }
        }
        Ok(())
    }
}

/// The token in `path`: its first line, trimmed (as the daemon reads its own).
pub fn read_token(path: &Path) -> Result<String, ClientError> {
    let text =
        crate::textfile::read_text(path, crate::textfile::MAX_TEXT_BYTES).map_err(|source| {
            ClientError::TokenFile {
                path: path.to_path_buf(),
                source,
            }
        })?;
    let token = text.lines().next().unwrap_or("").trim();
    if token.is_empty() {
        let path = path.to_path_buf();
        return Err(match crate::textfile::first_text_line(&text) {
            Some(line) => ClientError::BlankFirstLine { path, line },
            None => ClientError::EmptyToken { path },
        });
    }
    Ok(token.to_owned())
}

/// The arm as `describe` tells it, with the chain built from it: what a UI needs to draw it.
/// It reads as its [`Describe`] (`arm.rate_hz`); its geometry is its [`Chain`]'s.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmInfo {
    describe: Describe,
    chain: Chain,
}

impl ArmInfo {
    /// The arm `describe` tells of; refused when its links, base or limits make no chain.
    pub fn new(describe: Describe) -> Result<ArmInfo, ChainError> {
        let chain = describe.chain()?;
        Ok(ArmInfo { describe, chain })
    }

    /// What `describe` said.
    pub fn describe(&self) -> &Describe {
        &self.describe
    }

    /// The chain: links, base, limits and forward kinematics.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// The joint points `p_0` (the base) .. `p_n` (the tip) of a pose, m; none when the pose
    /// does not have one angle per joint.
    pub fn points(&self, theta: &[f64]) -> Vec<[f64; 2]> {
        self.chain
            .checked_points(theta)
            .unwrap_or_default()
            .iter()
            .map(|p| [p.x, p.y])
            .collect()
    }

    /// The arm's reach from the base, m (the outer radius of its workspace ring).
    pub fn reach(&self) -> f64 {
        self.chain.reach()
    }

    /// The inner radius of the workspace ring without limits, m.
    pub fn inner_radius(&self) -> f64 {
        self.chain.ring().r_min
    }
}

impl Deref for ArmInfo {
    type Target = Describe;

    fn deref(&self) -> &Describe {
        &self.describe
    }
}

/// A reply as the client reads it: its id, the command it answers (when it is one of this
/// client's), and its fields typed by that command, or the refusal.
#[derive(Debug, Clone, PartialEq)]
pub struct Replied {
    /// The id it echoes (`None` for `null`: a line the daemon could not read).
    pub id: Option<RequestId>,
    /// The command it answers, when its id is one this client sent.
    pub cmd: Option<CmdName>,
    /// The reply's fields, or the daemon's refusal.
    pub result: Result<Fields, Rejection>,
}

/// What the caller reads, in arrival order.
#[derive(Debug, Clone, PartialEq)]
pub enum Incoming {
    /// A reply to a request.
    Reply(Replied),
    /// An event.
    Event(Event),
}

/// One telemetry line: the line as sent and what it says.
#[derive(Debug, Clone, PartialEq)]
pub struct TelemetryLine {
    /// The line itself, without its newline (for `watch`, which prints it as it came).
    pub line: String,
    /// What it says.
    pub status: Status,
}

/// Something [`Client::watch`] shows its caller.
#[derive(Debug, Clone, Copy)]
pub enum Seen<'a> {
    /// The newest telemetry line.
    Telemetry(&'a TelemetryLine),
    /// A reply (to a request sent without waiting).
    Reply(&'a Replied),
    /// An event.
    Event(&'a Event),
}

/// A motion command the daemon accepted: what [`Client::wait_ending`] waits on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Motion {
    /// Its request id.
    pub id: u64,
    /// Its command.
    pub cmd: CmdName,
    /// The tick it was applied in.
    pub accepted: u64,
}

impl Motion {
    /// Whether `event` ends this command, and how: an `arrived`, `saturated`, `blocked`,
    /// `preempted` or `stopped` about its own request id; an `estop`, or a `fault` raised, from its tick on.
    pub fn ending(&self, event: &Event) -> Option<Ending> {
        let ours = event.cmd_id.as_deref().and_then(Value::as_u64) == Some(self.id);
        let since = event.tick >= self.accepted;
        let tick = event.tick;
        match &event.what {
            What::Arrived { tip } if ours => Some(Ending::Arrived { tick, tip: *tip }),
            What::Saturated { tip } if ours => Some(Ending::Saturated { tick, tip: *tip }),
            What::Preempted { tip, reason } if ours => Some(Ending::Preempted {
                tick,
                tip: *tip,
                by: *reason,
            }),
            What::Stopped { tip, reason } if ours => Some(Ending::Stopped {
                tick,
                tip: *tip,
                reason: *reason,
            }),
            What::Blocked {
                tip,
                link,
                obstacle,
            } if ours => Some(Ending::Blocked {
                tick,
                tip: *tip,
                link: *link,
                obstacle: obstacle.clone(),
            }),
            What::Estop { tip } if since => Some(Ending::Estop { tick, tip: *tip }),
            What::Fault {
                tip,
                reason: FaultChange::Raised,
                fault,
            } if since => Some(Ending::Fault {
                tick,
                tip: *tip,
                fault: fault.clone(),
            }),
            _ => None,
        }
    }
}

/// How a motion command ended: the tick and the commanded tip then, and why.
#[derive(Debug, Clone, PartialEq)]
pub enum Ending {
    /// It reached its target.
    Arrived {
        /// The tick.
        tick: u64,
        /// The commanded tip, m.
        tip: [f64; 2],
    },
    /// It stopped short of its target: out of reach, or held by a joint at its limit or by
    /// the arm's own links (the event does not tell which).
    Saturated {
        /// The tick.
        tick: u64,
        /// The commanded tip, m.
        tip: [f64; 2],
    },
    /// Another command replaced it.
    Preempted {
        /// The tick.
        tick: u64,
        /// The commanded tip, m.
        tip: [f64; 2],
        /// The command that replaced it.
        by: CmdName,
    },
    /// It came to rest, or was cut short.
    Stopped {
        /// The tick.
        tick: u64,
        /// The commanded tip, m.
        tip: [f64; 2],
        /// Why.
        reason: StopReason,
    },
    /// It was caught on an obstacle (or made no headway); the arm holds, clear.
    Blocked {
        /// The tick.
        tick: u64,
        /// The commanded tip, m.
        tip: [f64; 2],
        /// The link held back, from 1 at the base.
        link: usize,
        /// The obstacle's id.
        obstacle: String,
    },
    /// An estop.
    Estop {
        /// The tick.
        tick: u64,
        /// The commanded tip, m.
        tip: [f64; 2],
    },
    /// A fault was raised.
    Fault {
        /// The tick.
        tick: u64,
        /// The commanded tip, m.
        tip: [f64; 2],
        /// Which servo, and why.
        fault: FaultInfo,
    },
}

impl Ending {
    /// The tick it ended in.
    pub fn tick(&self) -> u64 {
        match self {
            Ending::Arrived { tick, .. }
            | Ending::Saturated { tick, .. }
            | Ending::Preempted { tick, .. }
            | Ending::Stopped { tick, .. }
            | Ending::Blocked { tick, .. }
            | Ending::Estop { tick, .. }
            | Ending::Fault { tick, .. } => *tick,
        }
    }

    /// The commanded tip then, m.
    pub fn tip(&self) -> [f64; 2] {
        match self {
            Ending::Arrived { tip, .. }
            | Ending::Saturated { tip, .. }
            | Ending::Preempted { tip, .. }
            | Ending::Stopped { tip, .. }
            | Ending::Blocked { tip, .. }
            | Ending::Estop { tip, .. }
            | Ending::Fault { tip, .. } => *tip,
        }
    }
}

impl fmt::Display for Ending {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // A coordinate that rounds to zero at four decimals is shown as 0.0000, not -0.0000.
        let [x, y] = self.tip().map(|v| if v.abs() < 5e-5 { 0.0 } else { v });
        let at = format!("({x:.4}, {y:.4}) m, tick {}", self.tick());
        match self {
            Ending::Arrived { .. } => write!(f, "arrived at {at}"),
            Ending::Saturated { .. } => write!(
                f,
                "saturated: the tip stopped short at {at}: the target is out of reach, or a \
                 joint at its limit or the arm's own links held it"
            ),
            Ending::Preempted { by, .. } => write!(f, "preempted by `{by}` at {at}"),
            Ending::Stopped { reason, .. } => write!(f, "stopped ({reason}) at {at}"),
            Ending::Blocked { link, obstacle, .. } => write!(
                f,
                "blocked: link {link} cannot follow past obstacle \"{obstacle}\" without losing \
                 its clearance; the arm holds at {at}"
            ),
            Ending::Estop { .. } => write!(f, "estop: emergency stop at {at}"),
            Ending::Fault { fault, .. } => write!(f, "fault: {fault}, at {at}"),
        }
    }
}

/// One thing the reading thread queued.
#[derive(Debug)]
enum Arrival {
    Reply { line: String, reply: ReplyLine },
    Event(Event),
    Unreadable { line: String, error: ReadError },
}

/// Arrivals in order, each with the length of its line, and their sum.
#[derive(Debug, Default)]
struct Queue {
    arrivals: VecDeque<(usize, Arrival)>,
    bytes: usize,
}

impl Queue {
    fn len(&self) -> usize {
        self.arrivals.len()
    }

    fn is_empty(&self) -> bool {
        self.arrivals.is_empty()
    }

    /// Queues `arrival`, whose line was `bytes` long.
    fn push_back(&mut self, bytes: usize, arrival: Arrival) {
        self.bytes = self.bytes.saturating_add(bytes);
        self.arrivals.push_back((bytes, arrival));
    }

    fn pop_front(&mut self) -> Option<Arrival> {
        self.remove(0)
    }

    /// Takes out the arrival at `at`.
    fn remove(&mut self, at: usize) -> Option<Arrival> {
        let (bytes, arrival) = self.arrivals.remove(at)?;
        self.bytes = self.bytes.saturating_sub(bytes);
        Some(arrival)
    }

    /// Where the first arrival that `found` picks is.
    fn position(&self, mut found: impl FnMut(&Arrival) -> bool) -> Option<usize> {
        self.arrivals.iter().position(|(_, arrival)| found(arrival))
    }
}

/// What the reading thread hands the caller.
#[derive(Debug, Default)]
struct Inbox {
    /// Replies, events and unreadable lines, in arrival order.
    queue: Queue,
    /// Telemetry lines seen so far, and the newest.
    telemetry_count: u64,
    telemetry: Option<Arc<TelemetryLine>>,
    /// The reading thread has ended: the connection is closed.
    closed: bool,
    /// The last refusal the daemon sent (why it closed, if it did).
    refusal: Option<Rejection>,
    /// A request waits for its reply: the queue may grow past [`QUEUE`] and [`QUEUE_BYTES`]
    /// meanwhile, up to [`MAX_QUEUE_BYTES`].
    waiting: bool,
    /// The client is gone: the reading thread stops waiting for room.
    dropped: bool,
    /// The first bytes of a line over [`MAX_REPLY_LINE`], which closed the connection.
    overlong: Option<String>,
    /// The queue overflowed [`MAX_QUEUE_BYTES`] while a request waited: the connection was
    /// closed.
    backlog: bool,
}

/// The inbox and its two conditions.
#[derive(Debug, Default)]
struct Shared {
    inbox: Mutex<Inbox>,
    /// Something arrived, or the connection closed.
    changed: Condvar,
    /// The caller took something from a full queue, or went away.
    room: Condvar,
}

impl Shared {
    fn inbox(&self) -> MutexGuard<'_, Inbox> {
        // The inbox is whole after any panic: each change is one push or pop.
        self.inbox.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Waits up to `wait` for the inbox to change.
    fn wait_changed<'a>(
        &'a self,
        inbox: MutexGuard<'a, Inbox>,
        wait: Duration,
    ) -> MutexGuard<'a, Inbox> {
        self.changed
            .wait_timeout(inbox, wait)
            .unwrap_or_else(|e| e.into_inner())
            .0
    }
}

/// A connection to the daemon.
pub struct Client {
    addr: String,
    writer: TcpStream,
    shared: Arc<Shared>,
    /// The count of the last telemetry line returned.
    seen: u64,
    next_id: u64,
    id: Option<ClientId>,
    /// The requests sent whose replies have not been read: id to command.
    pending: HashMap<u64, CmdName>,
    reader: Option<JoinHandle<()>>,
    /// How long a line may wait for the daemon to take it.
    write_timeout: Duration,
    /// The socket's send timeout as last set (`None`: none, as on a new socket).
    socket_wait: Option<Duration>,
}

impl fmt::Debug for Client {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Client")
            .field("addr", &self.addr)
            .field("id", &self.id)
            .finish_non_exhaustive()
    }
}

impl Client {
    /// Connects to `addr` (`host:port`); with a token, sends `auth` first and waits for its
    /// reply. "Connection refused" becomes [`ClientError::NoDaemon`].
    pub fn connect(addr: &str, token: Option<&str>) -> Result<Client, ClientError> {
        let connect_error = |source: std::io::Error| {
            if source.kind() == std::io::ErrorKind::ConnectionRefused {
                ClientError::NoDaemon {
                    addr: addr.to_owned(),
                }
            } else {
                ClientError::Connect {
                    addr: addr.to_owned(),
                    source,
                }
            }
        };
        let targets: Vec<SocketAddr> = addr.to_socket_addrs().map_err(connect_error)?.collect();
        let mut last = std::io::Error::new(std::io::ErrorKind::NotFound, "no address");
        let mut stream = None;
        for target in targets {
            match TcpStream::connect_timeout(&target, Duration::from_secs(3)) {
                Ok(s) => {
                    stream = Some(s);
                    break;
                }
                Err(e) => last = e,
            }
        }
        let stream = stream.ok_or_else(|| connect_error(last))?;
        Client::over(addr, stream, token)
    }

    /// [`Client::connect`] with the token read from `token_file`, if given.
    pub fn connect_with(addr: &str, token_file: Option<&Path>) -> Result<Client, ClientError> {
        let token = token_file.map(read_token).transpose()?;
        Client::connect(addr, token.as_deref())
    }

    /// A client on a connected `stream` to the daemon at `addr`.
    fn over(addr: &str, stream: TcpStream, token: Option<&str>) -> Result<Client, ClientError> {
        let io_error = |source: std::io::Error| ClientError::Connect {
            addr: addr.to_owned(),
            source,
        };
        let _ = stream.set_nodelay(true);
        let read_half = stream.try_clone().map_err(io_error)?;
        let shared = Arc::new(Shared::default());
        let reader = {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name("snakectl-client".into())
                .spawn(move || read_loop(read_half, &shared))
                .map_err(io_error)?
        };
        let mut client = Client {
            addr: addr.to_owned(),
            writer: stream,
            shared,
            seen: 0,
            next_id: 1,
            id: None,
            pending: HashMap::new(),
            reader: Some(reader),
            write_timeout: WRITE_TIMEOUT,
            socket_wait: None,
        };
        if let Some(token) = token {
            client.request(&Cmd::Auth {
                token: token.to_owned(),
            })?;
        }
        Ok(client)
    }

    /// The address it is connected to.
    pub fn addr(&self) -> &str {
        &self.addr
    }

    /// This client's id on the daemon, once a reply to `auth`, `take_control` or `release` has
    /// told it.
    pub fn client_id(&self) -> Option<ClientId> {
        self.id
    }

    /// How long a request's line may wait for the daemon to take it, from now on (default
    /// [`WRITE_TIMEOUT`]); a UI that must not stall gives it less.
    pub fn set_write_timeout(&mut self, timeout: Duration) {
        self.write_timeout = timeout;
    }

    /// Sends `cmd` without waiting for its reply; returns the request id it carries. Its reply
    /// comes through [`Client::next`] (or [`Client::watch`]), typed by `cmd`. A daemon that
    /// takes none of the line within the write timeout ([`Client::set_write_timeout`]) has
    /// stopped reading: [`ClientError::WriteTimeout`], and the connection is closed.
    pub fn send(&mut self, cmd: &Cmd) -> Result<u64, ClientError> {
        let id = self.next_id;
        self.next_id += 1;
        let line = protocol::request_line(Some(&Value::from(id)), cmd);
        self.write_line(cmd.name(), &line)?;
        self.pending.insert(id, cmd.name());
        Ok(id)
    }

    /// Sends `cmd` and waits up to [`REPLY_TIMEOUT`] for its reply: its fields, or
    /// [`ClientError::Refused`] with the daemon's code and message. Events and other replies
    /// that arrive meanwhile stay queued, in order, for [`Client::next`].
    pub fn request(&mut self, cmd: &Cmd) -> Result<Fields, ClientError> {
        self.request_within(cmd, REPLY_TIMEOUT)
    }

    /// [`Client::request`] with its own timeout.
    pub fn request_within(&mut self, cmd: &Cmd, timeout: Duration) -> Result<Fields, ClientError> {
        let id = self.send(cmd)?;
        self.wait_reply(id, cmd.name(), timeout)
    }

    /// `describe`: the arm, its chain built.
    pub fn describe(&mut self) -> Result<ArmInfo, ClientError> {
        let fields = self.request(&Cmd::Describe)?;
        let Reply::Describe(describe) = fields.reply else {
            return Err(ClientError::WrongReply {
                cmd: CmdName::Describe,
            });
        };
        ArmInfo::new(Arc::unwrap_or_clone(describe))
            .map_err(|source| ClientError::BadArm { source })
    }

    /// `status`.
    pub fn status(&mut self) -> Result<Status, ClientError> {
        let fields = self.request(&Cmd::Status)?;
        match fields.reply {
            Reply::Status(status) => Ok(*status),
            _ => Err(ClientError::WrongReply {
                cmd: CmdName::Status,
            }),
        }
    }

    /// `take_control`: this client's id, the holder now and before.
    pub fn take_control(&mut self) -> Result<TookControl, ClientError> {
        let fields = self.request(&Cmd::TakeControl)?;
        match fields.reply {
            Reply::TookControl(took) => Ok(took),
            _ => Err(ClientError::WrongReply {
                cmd: CmdName::TakeControl,
            }),
        }
    }

    /// `world`: the obstacles the arm keeps clear of, with the link radius and the clearance.
    pub fn world(&mut self) -> Result<WorldInfo, ClientError> {
        let fields = self.request(&Cmd::World)?;
        match fields.reply {
            Reply::World(world) => Ok(*world),
            _ => Err(ClientError::WrongReply {
                cmd: CmdName::World,
            }),
        }
    }

    /// `set_world`: replaces every obstacle (needs control); the tick it was applied in.
    /// Obstacles that make no world are refused here, as the daemon would refuse them.
    pub fn set_world(&mut self, obstacles: Vec<Obstacle>) -> Result<u64, ClientError> {
        let obstacles = Obstacles::new(obstacles).map_err(|e| ClientError::Refused {
            cmd: CmdName::SetWorld,
            rejection: world_rejection(&e, None),
        })?;
        self.applied(&Cmd::SetWorld { obstacles })
    }

    /// `add_obstacle` (needs control); the tick it was applied in. A bad shape or id is
    /// refused here, as the daemon would refuse it.
    pub fn add_obstacle(&mut self, obstacle: Obstacle) -> Result<u64, ClientError> {
        let obstacle = CheckedObstacle::new(obstacle).map_err(|e| ClientError::Refused {
            cmd: CmdName::AddObstacle,
            rejection: world_rejection(&e, None),
        })?;
        self.applied(&Cmd::AddObstacle { obstacle })
    }

    /// `remove_obstacle` of the obstacle `id` (needs control); the tick it was applied in.
    pub fn remove_obstacle(&mut self, id: &str) -> Result<u64, ClientError> {
        self.applied(&Cmd::RemoveObstacle { id: id.to_owned() })
    }

    /// Sends `cmd`, answered with the tick the loop applied it in.
    fn applied(&mut self, cmd: &Cmd) -> Result<u64, ClientError> {
        let fields = self.request(cmd)?;
        fields
            .reply
            .tick()
            .ok_or(ClientError::WrongReply { cmd: cmd.name() })
    }

    /// Sends a motion command and waits for its reply: the command, accepted, to wait on with
    /// [`Client::wait_ending`].
    pub fn start_motion(&mut self, cmd: &Cmd) -> Result<Motion, ClientError> {
        let id = self.send(cmd)?;
        let fields = self.wait_reply(id, cmd.name(), REPLY_TIMEOUT)?;
        Ok(Motion {
            id,
            cmd: cmd.name(),
            accepted: fields.reply.tick().unwrap_or(0),
        })
    }

    /// Waits up to `timeout` for `motion` to end (`Ok(None)`: it did not); everything that
    /// comes meanwhile (telemetry, replies, events, the ending included) is shown to `seen`
    /// first, which may stop the wait with an error.
    pub fn wait_ending<E: From<ClientError>>(
        &mut self,
        motion: &Motion,
        timeout: Duration,
        mut seen: impl FnMut(Seen<'_>) -> Result<(), E>,
    ) -> Result<Option<Ending>, E> {
        self.watch(timeout, |what| {
            let ending = match what {
                Seen::Event(event) => motion.ending(event),
                Seen::Telemetry(_) | Seen::Reply(_) => None,
            };
            seen(what)?;
            Ok(ending)
        })
    }

    /// Shows `look` everything that comes, in order (the queued replies and events first, then
    /// the newest telemetry line when there is a newer one), until it returns `Some` or
    /// `timeout` passes (`Ok(None)`). A line this client cannot read ends the watch with its
    /// error; so does the connection closing.
    pub fn watch<T, E: From<ClientError>>(
        &mut self,
        timeout: Duration,
        mut look: impl FnMut(Seen<'_>) -> Result<Option<T>, E>,
    ) -> Result<Option<T>, E> {
        let deadline = Instant::now().checked_add(timeout);
        let shared = Arc::clone(&self.shared);
        loop {
            let mut inbox = shared.inbox();
            if let Some(arrival) = inbox.queue.pop_front() {
                drop(inbox);
                shared.room.notify_one();
                let found = match self.take(arrival)? {
                    Incoming::Reply(reply) => look(Seen::Reply(&reply))?,
                    Incoming::Event(event) => look(Seen::Event(&event))?,
                };
                if found.is_some() {
                    return Ok(found);
                }
                continue;
            }
            if inbox.telemetry_count != self.seen {
                self.seen = inbox.telemetry_count;
                let line = inbox.telemetry.clone();
                drop(inbox);
                if let Some(line) = line {
                    if let Some(found) = look(Seen::Telemetry(&line))? {
                        return Ok(Some(found));
                    }
                }
                continue;
            }
            if inbox.closed {
                drop(inbox);
                return Err(self.closed().into());
            }
            let left = time_left(deadline);
            if left.is_zero() {
                return Ok(None);
            }
            drop(shared.wait_changed(inbox, left));
        }
    }

    /// The next reply or event within `timeout` (`Ok(None)`: none came).
    /// [`ClientError::Closed`] once the daemon has gone and nothing is left;
    /// [`ClientError::Unreadable`] for a line that does not read (the next call goes on after
    /// it).
    pub fn next(&mut self, timeout: Duration) -> Result<Option<Incoming>, ClientError> {
        let deadline = Instant::now().checked_add(timeout);
        let shared = Arc::clone(&self.shared);
        let mut inbox = shared.inbox();
        loop {
            if let Some(arrival) = inbox.queue.pop_front() {
                drop(inbox);
                shared.room.notify_one();
                return self.take(arrival).map(Some);
            }
            if inbox.closed {
                drop(inbox);
                return Err(self.closed());
            }
            let left = time_left(deadline);
            if left.is_zero() {
                return Ok(None);
            }
            inbox = shared.wait_changed(inbox, left);
        }
    }

    /// The newest telemetry line, if one came since the last one returned (latest wins: lines
    /// in between are skipped).
    pub fn telemetry(&mut self) -> Option<Arc<TelemetryLine>> {
        let inbox = self.shared.inbox();
        if inbox.telemetry_count == self.seen {
            return None;
        }
        self.seen = inbox.telemetry_count;
        inbox.telemetry.clone()
    }

    /// Waits up to `timeout` for a telemetry line newer than the last one returned.
    /// [`ClientError::Closed`] once the daemon has gone and no newer line is left.
    pub fn wait_telemetry(
        &mut self,
        timeout: Duration,
    ) -> Result<Option<Arc<TelemetryLine>>, ClientError> {
        let deadline = Instant::now().checked_add(timeout);
        let shared = Arc::clone(&self.shared);
        let mut inbox = shared.inbox();
        loop {
            if inbox.telemetry_count != self.seen {
                self.seen = inbox.telemetry_count;
                return Ok(inbox.telemetry.clone());
            }
            if inbox.closed {
                drop(inbox);
                return Err(self.closed());
            }
            let left = time_left(deadline);
            if left.is_zero() {
                return Ok(None);
            }
            inbox = shared.wait_changed(inbox, left);
        }
    }

    /// Whether the daemon has closed the connection.
    pub fn is_closed(&self) -> bool {
        self.shared.inbox().closed
    }

    /// What the caller reads of an arrival: a reply typed by the command it answers.
    fn take(&mut self, arrival: Arrival) -> Result<Incoming, ClientError> {
        match arrival {
            Arrival::Event(event) => Ok(Incoming::Event(event)),
            Arrival::Unreadable { line, error } => Err(ClientError::Unreadable {
                line,
                source: error,
            }),
            Arrival::Reply { line, reply } => {
                let cmd = reply
                    .id
                    .as_deref()
                    .and_then(Value::as_u64)
                    .and_then(|id| self.pending.remove(&id));
                let result = match (reply.result, cmd) {
                    (Ok(fields), Some(cmd)) => Ok(self.typed(cmd, fields, line)?),
                    (Ok(_), None) => return Err(ClientError::Stray { line }),
                    (Err(rejection), _) => Err(rejection),
                };
                Ok(Incoming::Reply(Replied {
                    id: reply.id,
                    cmd,
                    result,
                }))
            }
        }
    }

    /// An ok reply's fields typed by `cmd`; the client's id noted when they tell it.
    fn typed(
        &mut self,
        cmd: CmdName,
        fields: serde_json::Map<String, Value>,
        line: String,
    ) -> Result<Fields, ClientError> {
        let fields = Fields::read(cmd, fields).map_err(|source| ClientError::BadReply {
            cmd,
            line,
            source,
        })?;
        if let Some(id) = fields.reply.client() {
            self.id = Some(id);
        }
        Ok(fields)
    }

    /// Writes `line` (a `cmd` request) within the write timeout; past it, closes the
    /// connection.
    fn write_line(&mut self, cmd: CmdName, line: &str) -> Result<(), ClientError> {
        use std::io::ErrorKind;
        let timeout = self.write_timeout;
        // `None` (a deadline past what an `Instant` holds): no timeout.
        let deadline = Instant::now().checked_add(timeout);
        // The whole timeout for the first try (as set before, mostly); what is left of it for
        // the rest of a line cut short.
        let mut wait = deadline.map(|_| timeout.max(MIN_WRITE_WAIT));
        let mut rest = line.as_bytes();
        while !rest.is_empty() {
            if self.socket_wait != wait {
                self.writer
                    .set_write_timeout(wait)
                    .map_err(|source| ClientError::Write {
                        addr: self.addr.clone(),
                        source,
                    })?;
                self.socket_wait = wait;
            }
            match self.writer.write(rest) {
                Ok(0) => return Err(self.closed()),
                Ok(n) => rest = rest.get(n..).unwrap_or_default(),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    // A line cut short would garble the next one: the connection is done.
                    let _ = self.writer.shutdown(std::net::Shutdown::Both);
                    return Err(ClientError::WriteTimeout {
                        addr: self.addr.clone(),
                        cmd,
                        timeout,
                    });
                }
                Err(e)
                    if matches!(e.kind(), ErrorKind::BrokenPipe | ErrorKind::ConnectionReset) =>
                {
                    return Err(self.closed())
                }
                Err(source) => {
                    return Err(ClientError::Write {
                        addr: self.addr.clone(),
                        source,
                    })
                }
            }
            wait = deadline.map(|d| {
                d.saturating_duration_since(Instant::now())
                    .max(MIN_WRITE_WAIT)
            });
        }
        Ok(())
    }

    /// Waits for the reply to request `id` (of `cmd`), leaving everything else queued in
    /// order. A refusal without an id (of a line the daemon could not read) is taken as this
    /// request's, and a line this client cannot read ends the wait with its error.
    fn wait_reply(
        &mut self,
        id: u64,
        cmd: CmdName,
        timeout: Duration,
    ) -> Result<Fields, ClientError> {
        let deadline = Instant::now().checked_add(timeout);
        let shared = Arc::clone(&self.shared);
        let mut inbox = shared.inbox();
        inbox.waiting = true;
        let found = loop {
            let at = inbox.queue.position(|arrival| match arrival {
                Arrival::Reply { reply, .. } => match reply.id.as_deref() {
                    Some(got) => got.as_u64() == Some(id),
                    None => reply.result.is_err(),
                },
                Arrival::Unreadable { .. } => true,
                Arrival::Event(_) => false,
            });
            if let Some(arrival) = at.and_then(|at| inbox.queue.remove(at)) {
                break Ok(arrival);
            }
            if inbox.closed {
                break Err(None);
            }
            let left = time_left(deadline);
            if left.is_zero() {
                break Err(Some(ClientError::Timeout { cmd, timeout }));
            }
            inbox = shared.wait_changed(inbox, left);
        };
        inbox.waiting = false;
        drop(inbox);
        shared.room.notify_all();
        let arrival = match found {
            Ok(arrival) => arrival,
            Err(Some(timeout)) => return Err(timeout),
            Err(None) => return Err(self.closed()),
        };
        match arrival {
            Arrival::Reply { line, reply } => {
                self.pending.remove(&id);
                match reply.result {
                    Ok(fields) => self.typed(cmd, fields, line),
                    Err(rejection) => Err(ClientError::Refused { cmd, rejection }),
                }
            }
            Arrival::Unreadable { line, error } => Err(ClientError::Unreadable {
                line,
                source: error,
            }),
            Arrival::Event(_) => Err(ClientError::WrongReply { cmd }),
        }
    }

    fn closed(&self) -> ClientError {
        if let Some(start) = self.shared.inbox().overlong.clone() {
            return ClientError::LineTooLong {
                addr: self.addr.clone(),
                max: MAX_REPLY_LINE,
                start,
            };
        }
        if self.shared.inbox().backlog {
            return ClientError::Backlog {
                addr: self.addr.clone(),
                max: MAX_QUEUE_BYTES,
            };
        }
        ClientError::Closed {
            addr: self.addr.clone(),
            reason: self.shared.inbox().refusal.clone(),
        }
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        self.shared.inbox().dropped = true;
        self.shared.room.notify_all();
        let _ = self.writer.shutdown(std::net::Shutdown::Both);
        if let Some(reader) = self.reader.take() {
            let _ = reader.join();
        }
    }
}

/// What is left of a wait until `deadline`; `None` (a timeout past what an [`Instant`] holds,
/// such as [`Duration::MAX`]) waits as long as it takes, an hour at a time.
fn time_left(deadline: Option<Instant>) -> Duration {
    match deadline {
        Some(deadline) => deadline.saturating_duration_since(Instant::now()),
        None => Duration::from_secs(3600),
    }
}

/// The reading thread: reads the daemon's lines into the inbox until the socket closes.
fn read_loop(stream: TcpStream, shared: &Shared) {
    let mut reader = BufReader::new(stream);
    let mut bytes = Vec::new();
    // A line of MAX_REPLY_LINE bytes and its newline.
    let most = u64::try_from(MAX_REPLY_LINE)
        .unwrap_or(u64::MAX)
        .saturating_add(1);
    loop {
        bytes.clear();
        match std::io::Read::take(&mut reader, most).read_until(b'\n', &mut bytes) {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
        if bytes.len() > MAX_REPLY_LINE && bytes.last() != Some(&b'\n') {
            let start = bytes.get(..SHOWN).unwrap_or_default();
            shared.inbox().overlong = Some(String::from_utf8_lossy(start).into_owned());
            let _ = reader.get_ref().shutdown(std::net::Shutdown::Both);
            break;
        }
        let text = String::from_utf8_lossy(&bytes);
        let text = text.trim_end();
        if text.is_empty() {
            continue;
        }
        let arrival = match protocol::read_line(text) {
            Ok(ServerLine::Telemetry(status)) => {
                let line = Arc::new(TelemetryLine {
                    line: text.to_owned(),
                    status: *status,
                });
                let mut inbox = shared.inbox();
                inbox.telemetry_count += 1;
                inbox.telemetry = Some(line);
                drop(inbox);
                shared.changed.notify_all();
                continue;
            }
            Ok(ServerLine::Event(event)) => Arrival::Event(event),
            Ok(ServerLine::Reply(reply)) => Arrival::Reply {
                line: text.to_owned(),
                reply,
            },
            Err(error) => Arrival::Unreadable {
                line: text.to_owned(),
                error,
            },
        };
        let mut inbox = shared.inbox();
        if let Arrival::Reply { reply, .. } = &arrival {
            if let Err(rejection) = &reply.result {
                inbox.refusal = Some(rejection.clone());
            }
        }
        // Bounded: a caller that stops reading makes this thread wait (and the daemon's queue
        // for this client fill), never grow without end; a request waiting for its reply
        // behind the queue lets it grow meanwhile, to a bound of bytes of its own. An empty
        // queue takes any line (one is at most MAX_REPLY_LINE).
        let bytes = text.len();
        let fits = |queue: &Queue, most: usize| {
            queue.is_empty() || queue.bytes.saturating_add(bytes) <= most
        };
        while (inbox.queue.len() >= QUEUE || !fits(&inbox.queue, QUEUE_BYTES))
            && !inbox.waiting
            && !inbox.dropped
        {
            inbox = shared.room.wait(inbox).unwrap_or_else(|e| e.into_inner());
        }
        if inbox.dropped {
            return;
        }
        if !fits(&inbox.queue, MAX_QUEUE_BYTES) {
            // The reply waited for is behind more than the client holds: the connection is
            // done (nothing queued is dropped; the caller reads it, then this).
            inbox.backlog = true;
            drop(inbox);
            let _ = reader.get_ref().shutdown(std::net::Shutdown::Both);
            break;
        }
        inbox.queue.push_back(bytes, arrival);
        drop(inbox);
        shared.changed.notify_all();
    }
    shared.inbox().closed = true;
    shared.changed.notify_all();
}

#[cfg(test)]
mod tests;
