//! A client of the daemon's socket, for the one-shot commands, teleop and the demo: connect
//! (with the token, where the daemon wants one), send requests, wait for their replies, and
//! read events and the latest telemetry.
//!
//! One thread per connection reads the socket. Replies and events go through a bounded queue
//! in arrival order; telemetry goes into a latest-wins slot, so a reader that falls behind sees
//! the newest snapshot, never a backlog. Everything the daemon sends is read into the owned,
//! tolerant views of this module ([`Snapshot`], [`ArmInfo`], [`EventInfo`]): a field a newer
//! daemon adds is ignored, one an older daemon lacks takes its default.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde::Deserialize;
use serde_json::{Map, Value};

use crate::protocol::{self, Cmd};

/// Where the daemon listens unless told otherwise (`[server] listen` of the shipped configs).
pub const DEFAULT_ADDR: &str = "127.0.0.1:7878";

/// How long [`Client::request`] waits for a reply by default. Replies come within a tick or
/// two; the first waits for the arm's bring-up.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(10);

/// Replies and events held for the caller before the reading thread waits for it.
const QUEUE: usize = 1024;

/// Events kept while [`Client::request`] waits for a reply, for [`Client::next_event`].
const HELD_EVENTS: usize = 256;

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
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The token file's first line is empty.
    #[error("{}: the token file is empty: its first line is the token", path.display())]
    EmptyToken {
        /// The file.
        path: PathBuf,
    },
    /// The daemon closed the connection (it stopped, or it refused this client).
    #[error("the daemon at {addr} closed the connection{}", reason.as_deref().map(|r| format!(": {r}")).unwrap_or_default())]
    Closed {
        /// Its address.
        addr: String,
        /// The last error it sent, if any (`unauthorized`, `too_many_clients`).
        reason: Option<String>,
    },
    /// The daemon refused a request.
    #[error("`{cmd}` refused: {code}: {message}")]
    Refused {
        /// The request's `cmd`.
        cmd: String,
        /// The error code (`not_in_control`, `estopped`, ...).
        code: String,
        /// The daemon's message.
        message: String,
    },
    /// No reply within the time allowed.
    #[error("no reply to `{cmd}` within {} ms", timeout.as_millis())]
    Timeout {
        /// The request's `cmd`.
        cmd: String,
        /// How long it waited.
        timeout: Duration,
    },
    /// A reply this client cannot read.
    #[error("cannot read the daemon's reply to `{cmd}`: {source}")]
    BadReply {
        /// The request's `cmd`.
        cmd: String,
        /// What did not fit.
        source: serde_json::Error,
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
    /// The daemon's error code, for a refused request.
    pub fn code(&self) -> Option<&str> {
        match self {
            ClientError::Refused { code, .. } => Some(code),
            _ => None,
        }
    }
}

/// The token in `path`: its first line, trimmed (as the daemon reads its own).
pub fn read_token(path: &Path) -> Result<String, ClientError> {
    let text = std::fs::read_to_string(path).map_err(|source| ClientError::TokenFile {
        path: path.to_path_buf(),
        source,
    })?;
    let token = text.lines().next().unwrap_or("").trim();
    if token.is_empty() {
        return Err(ClientError::EmptyToken {
            path: path.to_path_buf(),
        });
    }
    Ok(token.to_owned())
}

/// The arm as `describe` tells it: what a UI needs to draw it.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(default)]
pub struct ArmInfo {
    /// Link lengths, base to tip, m.
    pub links_m: Vec<f64>,
    /// Base pose: x, y (m), heading (rad).
    pub base: [f64; 3],
    /// Lower joint limits, rad.
    pub min_rad: Vec<f64>,
    /// Upper joint limits, rad.
    pub max_rad: Vec<f64>,
    /// Servo ids, base to tip.
    pub ids: Vec<u8>,
    /// Servo model names, base to tip.
    pub models: Vec<String>,
    /// The home pose, rad.
    pub home_rad: Vec<f64>,
    /// The loop rate, Hz.
    pub rate_hz: f64,
    /// The strategies `strategy` accepts.
    pub strategies: Vec<String>,
    /// The wire format's version.
    pub protocol_version: u32,
}

impl ArmInfo {
    /// The joint points `p_0` (the base) .. `p_n` (the tip) of a pose, m.
    pub fn points(&self, theta: &[f64]) -> Vec<[f64; 2]> {
        let [mut x, mut y, mut heading] = self.base;
        let mut points = Vec::with_capacity(self.links_m.len() + 1);
        points.push([x, y]);
        for (length, angle) in self.links_m.iter().zip(theta) {
            heading += angle;
            x += length * heading.cos();
            y += length * heading.sin();
            points.push([x, y]);
        }
        points
    }

    /// The arm's reach from the base, m (the outer radius of its workspace ring).
    pub fn reach(&self) -> f64 {
        self.links_m.iter().sum()
    }

    /// The inner radius of the workspace ring without limits, m.
    pub fn inner_radius(&self) -> f64 {
        let longest = self.links_m.iter().copied().fold(0.0, f64::max);
        (2.0 * longest - self.reach()).max(0.0)
    }
}

/// The motion command a snapshot reports.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(default)]
pub struct CommandInfo {
    /// Its `cmd` name.
    pub kind: String,
    /// Its request id.
    pub id: Value,
    /// `active`, `arrived`, `saturated`, `preempted`, `stopped`, `estop` or `fault`.
    pub outcome: String,
    /// Fastest joint speed while it ran, rad/s.
    pub peak_joint_speed_rad_s: f64,
    /// Metric 3 travelled while it ran, rad².
    pub m3_rad2: f64,
}

/// A fault or warning as telemetry and events name it.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(default)]
pub struct FaultInfo {
    /// Servo id (0 for the port).
    pub id: u8,
    /// Joint number, from 1 (0 for the port).
    pub joint: usize,
    /// `silent`, `hardware_error`, `port`, `watchdog`, `temperature`, `voltage`.
    pub kind: String,
    /// The tick of its first symptom.
    pub since_tick: u64,
    /// Details for a person.
    pub detail: String,
}

impl std::fmt::Display for FaultInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.id == 0 {
            write!(f, "port: {} ({})", self.kind, self.detail)
        } else {
            write!(
                f,
                "servo {} (joint {}): {} ({})",
                self.id, self.joint, self.kind, self.detail
            )
        }
    }
}

/// One telemetry line or `status` reply, as a client reads it.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(default)]
pub struct Snapshot {
    /// Ticks since start.
    pub tick: u64,
    /// `tick` times the nominal period, s.
    pub t_s: f64,
    /// `moving`, `holding`, `stopping`, `estop` or `fault`.
    pub state: String,
    /// The active strategy.
    pub strategy: String,
    /// This tick's motion reference for the tip, m.
    pub tip_ref: [f64; 2],
    /// The tip of the commanded pose, m.
    pub tip: [f64; 2],
    /// The tip of the measured pose, m.
    pub tip_meas: [f64; 2],
    /// Where the active `goto`/`path` goes, m.
    pub target: Option<[f64; 2]>,
    /// The commanded pose, rad.
    pub theta_cmd: Vec<f64>,
    /// The measured pose, rad.
    pub theta_meas: Vec<f64>,
    /// The measured joint velocities, rad/s.
    pub omega_meas: Vec<f64>,
    /// `|tip_ref - tip_meas|`, m.
    pub tracking_error_m: f64,
    /// The reference was out of reach this tick.
    pub saturated: bool,
    /// The step was cut short by the arm's own links.
    pub self_collision: bool,
    /// The active or last motion command.
    pub command: Option<CommandInfo>,
    /// This tick's controller time, µs.
    pub solve_us: f64,
    /// Ticks per second over the last 1000 ticks.
    pub loop_hz: f64,
    /// 99th percentile of a tick's working time, µs.
    pub tick_p99_us: f64,
    /// Periods skipped since start.
    pub overruns: u64,
    /// Fastest joint speed commanded since start or `reset_stats`, rad/s.
    pub peak_joint_speed_rad_s: f64,
    /// Metric 3 travelled since start or `reset_stats`, rad².
    pub m3_total_rad2: f64,
    /// The active faults.
    pub faults: Vec<FaultInfo>,
    /// The active health warnings.
    pub warnings: Vec<FaultInfo>,
    /// Whether torque is on.
    pub torque: bool,
    /// The client in control (`None`: nobody).
    pub controller: Option<u64>,
    /// Whether this client is in control.
    pub in_control: bool,
}

/// An event line, as a client reads it.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(default)]
pub struct EventInfo {
    /// `arrived`, `saturated`, `preempted`, `stopped`, `estop`, `reset`, `fault`, `warning`,
    /// `control`.
    pub event: String,
    /// The request id of the command it concerns.
    pub cmd_id: Option<Value>,
    /// The tick it happened in.
    pub tick: u64,
    /// The commanded tip then, m.
    pub tip: [f64; 2],
    /// Why (`preempted`: the new command; `stopped`: `stop`, `deadman` or `fault`; `fault`:
    /// `raised`, `cleared`, `recovered`).
    pub reason: Option<String>,
    /// For `fault` and `warning`: which servo and why.
    pub fault: Option<FaultInfo>,
    /// For `control`: the new holder.
    pub holder: Option<u64>,
    /// For `control`: the previous holder.
    pub previous: Option<u64>,
}

/// A reply: its id and, when `ok`, its fields.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    /// The id it echoes.
    pub id: Value,
    /// The reply's fields (`ok` and `id` removed), or the daemon's `(code, message)`.
    pub result: Result<Map<String, Value>, (String, String)>,
}

/// What the reading thread passes on, in arrival order.
#[derive(Debug, Clone, PartialEq)]
pub enum Incoming {
    /// A reply to a request.
    Reply(Reply),
    /// An event.
    Event(EventInfo),
}

/// The newest telemetry line, with a count of the lines seen so far.
#[derive(Default)]
struct Latest {
    slot: Mutex<(u64, Option<Arc<Telemetry>>)>,
    fresh: Condvar,
}

/// One telemetry line: the line as sent and what it says.
#[derive(Debug, Clone, PartialEq)]
pub struct Telemetry {
    /// The line itself, without its newline (for `watch`, which prints it as it came).
    pub line: String,
    /// What it says.
    pub snapshot: Snapshot,
}

/// A connection to the daemon.
pub struct Client {
    addr: String,
    writer: TcpStream,
    incoming: Receiver<Incoming>,
    held: VecDeque<EventInfo>,
    latest: Arc<Latest>,
    seen: u64,
    next_id: u64,
    id: Option<u64>,
    closed_reason: Arc<Mutex<Option<String>>>,
    reader: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Client {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
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
        let _ = stream.set_nodelay(true);
        let read_half = stream.try_clone().map_err(connect_error)?;
        let (tx, rx) = mpsc::sync_channel(QUEUE);
        let latest = Arc::new(Latest::default());
        let closed_reason = Arc::new(Mutex::new(None));
        let reader = {
            let latest = Arc::clone(&latest);
            let closed_reason = Arc::clone(&closed_reason);
            std::thread::Builder::new()
                .name("snakectl-client".into())
                .spawn(move || read_loop(read_half, tx, &latest, &closed_reason))
                .map_err(connect_error)?
        };
        let mut client = Client {
            addr: addr.to_owned(),
            writer: stream,
            incoming: rx,
            held: VecDeque::new(),
            latest,
            seen: 0,
            next_id: 1,
            id: None,
            closed_reason,
            reader: Some(reader),
        };
        if let Some(token) = token {
            let id = client.next_request_id();
            let line = format!(
                "{}\n",
                serde_json::json!({"cmd": "auth", "id": id, "token": token})
            );
            client.write_line(&line)?;
            let fields = client.wait_reply(id, "auth", REPLY_TIMEOUT)?;
            client.note_client_id(&fields);
        }
        Ok(client)
    }

    /// [`Client::connect`] with the token read from `token_file`, if given.
    pub fn connect_with(addr: &str, token_file: Option<&Path>) -> Result<Client, ClientError> {
        let token = token_file.map(read_token).transpose()?;
        Client::connect(addr, token.as_deref())
    }

    /// The address it is connected to.
    pub fn addr(&self) -> &str {
        &self.addr
    }

    /// This client's id on the daemon, once a reply to `auth`, `take_control` or `release` has
    /// told it.
    pub fn client_id(&self) -> Option<u64> {
        self.id
    }

    /// Sends `cmd` without waiting; returns the request id it carries.
    pub fn send(&mut self, cmd: &Cmd) -> Result<u64, ClientError> {
        let id = self.next_request_id();
        let line = protocol::request_line(Some(&Value::from(id)), cmd);
        self.write_line(&line)?;
        Ok(id)
    }

    /// Sends `cmd` and waits up to [`REPLY_TIMEOUT`] for its reply: its fields, or
    /// [`ClientError::Refused`] with the daemon's code and message. Events that arrive
    /// meanwhile are kept for [`Client::next_event`].
    pub fn request(&mut self, cmd: &Cmd) -> Result<Map<String, Value>, ClientError> {
        self.request_within(cmd, REPLY_TIMEOUT)
    }

    /// [`Client::request`] with its own timeout.
    pub fn request_within(
        &mut self,
        cmd: &Cmd,
        timeout: Duration,
    ) -> Result<Map<String, Value>, ClientError> {
        let id = self.send(cmd)?;
        let fields = self.wait_reply(id, cmd.name(), timeout)?;
        if matches!(cmd, Cmd::TakeControl | Cmd::Release | Cmd::Auth { .. }) {
            self.note_client_id(&fields);
        }
        Ok(fields)
    }

    /// `describe`.
    pub fn describe(&mut self) -> Result<ArmInfo, ClientError> {
        let fields = self.request(&Cmd::Describe)?;
        ArmInfo::deserialize(Value::Object(fields)).map_err(|source| ClientError::BadReply {
            cmd: "describe".into(),
            source,
        })
    }

    /// `status`.
    pub fn status(&mut self) -> Result<Snapshot, ClientError> {
        let fields = self.request(&Cmd::Status)?;
        Snapshot::deserialize(Value::Object(fields)).map_err(|source| ClientError::BadReply {
            cmd: "status".into(),
            source,
        })
    }

    /// The next reply or event within `timeout` (`Ok(None)`: none came); events held while a
    /// request waited come first. [`ClientError::Closed`] once the daemon has gone.
    pub fn next(&mut self, timeout: Duration) -> Result<Option<Incoming>, ClientError> {
        if let Some(event) = self.held.pop_front() {
            return Ok(Some(Incoming::Event(event)));
        }
        match self.incoming.recv_timeout(timeout) {
            Ok(incoming) => Ok(Some(incoming)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(self.closed()),
        }
    }

    /// The next event within `timeout`, skipping replies nobody waits for.
    pub fn next_event(&mut self, timeout: Duration) -> Result<Option<EventInfo>, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.next(left)? {
                Some(Incoming::Event(event)) => return Ok(Some(event)),
                Some(Incoming::Reply(_)) => {}
                None => return Ok(None),
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
        }
    }

    /// The newest telemetry line, if one came since the last call (latest wins: lines in
    /// between are skipped).
    pub fn telemetry(&mut self) -> Option<Arc<Telemetry>> {
        let slot = self.latest.slot.lock().unwrap_or_else(|e| e.into_inner());
        if slot.0 == self.seen {
            return None;
        }
        self.seen = slot.0;
        slot.1.clone()
    }

    /// Waits up to `timeout` for a telemetry line newer than the last one returned.
    /// [`ClientError::Closed`] once the daemon has gone and no newer line is left.
    pub fn wait_telemetry(
        &mut self,
        timeout: Duration,
    ) -> Result<Option<Arc<Telemetry>>, ClientError> {
        let deadline = Instant::now() + timeout;
        let mut slot = self.latest.slot.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if slot.0 != self.seen {
                self.seen = slot.0;
                return Ok(slot.1.clone());
            }
            if self.reader.as_ref().is_none_or(|r| r.is_finished()) {
                drop(slot);
                return Err(self.closed());
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            // Woken by every line, and at least every 100 ms to notice a closed socket.
            let wait = left.min(Duration::from_millis(100));
            slot = self
                .latest
                .fresh
                .wait_timeout(slot, wait)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    /// Whether the daemon has closed the connection.
    pub fn is_closed(&self) -> bool {
        self.reader.as_ref().is_none_or(|r| r.is_finished())
    }

    fn next_request_id(&mut self) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        id
    }

    fn note_client_id(&mut self, fields: &Map<String, Value>) {
        if let Some(id) = fields.get("client").and_then(Value::as_u64) {
            self.id = Some(id);
        }
    }

    fn write_line(&mut self, line: &str) -> Result<(), ClientError> {
        self.writer
            .write_all(line.as_bytes())
            .map_err(|source| match source.kind() {
                std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset => {
                    self.closed()
                }
                _ => ClientError::Write {
                    addr: self.addr.clone(),
                    source,
                },
            })
    }

    fn wait_reply(
        &mut self,
        id: u64,
        cmd: &str,
        timeout: Duration,
    ) -> Result<Map<String, Value>, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let incoming = match self.incoming.recv_timeout(left) {
                Ok(incoming) => incoming,
                Err(RecvTimeoutError::Timeout) => {
                    return Err(ClientError::Timeout {
                        cmd: cmd.to_owned(),
                        timeout,
                    })
                }
                Err(RecvTimeoutError::Disconnected) => return Err(self.closed()),
            };
            match incoming {
                Incoming::Reply(reply) if reply.id.as_u64() == Some(id) => {
                    return reply
                        .result
                        .map_err(|(code, message)| ClientError::Refused {
                            cmd: cmd.to_owned(),
                            code,
                            message,
                        });
                }
                // A refusal of a line the daemon could not read carries no id; it can only
                // be ours when nothing else is in flight, as here.
                Incoming::Reply(Reply {
                    id: Value::Null,
                    result: Err((code, message)),
                }) => {
                    return Err(ClientError::Refused {
                        cmd: cmd.to_owned(),
                        code,
                        message,
                    })
                }
                Incoming::Reply(_) => {}
                Incoming::Event(event) => {
                    if self.held.len() == HELD_EVENTS {
                        self.held.pop_front();
                    }
                    self.held.push_back(event);
                }
            }
        }
    }

    fn closed(&self) -> ClientError {
        ClientError::Closed {
            addr: self.addr.clone(),
            reason: self
                .closed_reason
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone(),
        }
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        let _ = self.writer.shutdown(std::net::Shutdown::Both);
        if let Some(reader) = self.reader.take() {
            let _ = reader.join();
        }
    }
}

/// The reading thread: sorts the daemon's lines until the socket closes.
fn read_loop(
    stream: TcpStream,
    tx: SyncSender<Incoming>,
    latest: &Latest,
    closed_reason: &Mutex<Option<String>>,
) {
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    loop {
        line.clear();
        match reader.read_line(&mut line) {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
        let text = line.trim_end();
        if text.is_empty() {
            continue;
        }
        let Ok(Value::Object(mut object)) = serde_json::from_str::<Value>(text) else {
            continue;
        };
        let kind = object
            .get("type")
            .and_then(Value::as_str)
            .map(str::to_owned);
        let incoming = match kind.as_deref() {
            Some("telemetry") => {
                if let Ok(snapshot) = Snapshot::deserialize(Value::Object(object)) {
                    let telemetry = Arc::new(Telemetry {
                        line: text.to_owned(),
                        snapshot,
                    });
                    let mut slot = latest.slot.lock().unwrap_or_else(|e| e.into_inner());
                    slot.0 += 1;
                    slot.1 = Some(telemetry);
                    latest.fresh.notify_all();
                }
                continue;
            }
            Some("event") => match EventInfo::deserialize(Value::Object(object)) {
                Ok(event) => Incoming::Event(event),
                Err(_) => continue,
            },
            _ => {
                let id = object.remove("id").unwrap_or(Value::Null);
                let ok = object
                    .remove("ok")
                    .and_then(|v| v.as_bool())
                    .unwrap_or(false);
                let result = if ok {
                    Ok(object)
                } else {
                    let error = object.get("error");
                    let field = |name: &str| {
                        error
                            .and_then(|e| e.get(name))
                            .and_then(Value::as_str)
                            .unwrap_or("")
                            .to_owned()
                    };
                    let (code, message) = (field("code"), field("message"));
                    *closed_reason.lock().unwrap_or_else(|e| e.into_inner()) =
                        Some(format!("{code}: {message}"));
                    Err((code, message))
                };
                Incoming::Reply(Reply { id, result })
            }
        };
        let mut pending = incoming;
        // Bounded: a caller that stops reading makes this thread wait (and the daemon's queue
        // for this client fill), never grow without end.
        loop {
            match tx.try_send(pending) {
                Ok(()) => break,
                Err(TrySendError::Full(back)) => {
                    pending = back;
                    std::thread::sleep(Duration::from_millis(5));
                }
                Err(TrySendError::Disconnected(_)) => return,
            }
        }
    }
    latest.fresh.notify_all();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_walk_the_links_from_the_base() {
        let arm = ArmInfo {
            links_m: vec![1.0, 1.0],
            base: [1.0, 2.0, std::f64::consts::FRAC_PI_2],
            ..ArmInfo::default()
        };
        let p = arm.points(&[0.0, -std::f64::consts::FRAC_PI_2]);
        let expected = [[1.0, 2.0], [1.0, 3.0], [2.0, 3.0]];
        for (got, want) in p.iter().zip(expected) {
            assert!((got[0] - want[0]).abs() < 1e-12 && (got[1] - want[1]).abs() < 1e-12);
        }
        assert_eq!(arm.reach(), 2.0);
        assert_eq!(arm.inner_radius(), 0.0);
    }

    #[test]
    fn a_refused_connection_says_no_daemon_listens() {
        // Bind and drop: the port is then (almost certainly) closed.
        let addr = {
            let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap_or_else(|e| panic!("{e}"));
            l.local_addr().unwrap_or_else(|e| panic!("{e}"))
        };
        let err = Client::connect(&addr.to_string(), None)
            .err()
            .unwrap_or_else(|| panic!("connected to a closed port"));
        let text = err.to_string();
        assert!(
            text.contains("no daemon is listening on 127.0.0.1"),
            "{text}"
        );
        assert!(text.contains("--connect"), "{text}");
    }

    #[test]
    fn token_files_are_read_as_the_daemon_reads_them() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let path = dir.path().join("token");
        std::fs::write(&path, "  s3cret \nsecond line\n").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            read_token(&path).unwrap_or_else(|e| panic!("{e}")),
            "s3cret"
        );
        std::fs::write(&path, "\n").unwrap_or_else(|e| panic!("{e}"));
        let err = read_token(&path)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.contains("the token file is empty"), "{err}");
    }
}
