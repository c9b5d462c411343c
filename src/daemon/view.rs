//! The live Foxglove view: a Foxglove WebSocket server (the `foxglove` crate) on a thread of
//! its own, publishing the channels of [`crate::view`] from what the loop publishes.
//!
//! [`View::open`] binds the server before anything moves (a taken port stops start-up);
//! [`View::start`] hands it a [`Door`]; [`View::stop`] closes it (a client that does not take
//! its close within [`FLUSH_GRACE`] is cut off). Its thread runs its own runtime and never
//! holds the loop up: at `publish_hz`, right after the loop's next tick
//! ends (in the idle rest of its period, not across a tick), it clones the latest telemetry
//! from the loop's `watch` (latest wins: a skipped sample is never queued) and sends the joints,
//! the tips, the target, the telemetry line and the whole scene again (so a client that joins
//! late sees the arm at rest); events come from the loop's broadcast, and what it misses
//! when behind is counted ([`View::stop`] logs the count). What waits for a Foxglove client
//! that stalls is bounded and its oldest message data dropped: in the gate's outbox for the
//! client (`relay`), which reads the server as fast as it writes, and in the server's own
//! queue for it.
//!
//! With `accept_commands`, the server offers client publishing (`json` and `cdr`): a `Twist`
//! published on `/<prefix>/cmd_vel` becomes `velocity` (`linear.x`, `linear.y`, m/s), and a
//! `PointStamped` on `/<prefix>/goal` or `/<prefix>/reach` (the 3-D panel's click, say) a
//! `goto` or a `reach` to (`point.x`, `point.y`), all through the door: the same arbiter and
//! bounded queue as a socket client's commands, one controller id for every Foxglove client,
//! control let go of after the deadman's silence.
//! Without it the server offers no publishing and nothing a Foxglove client sends moves the
//! arm.
//!
//! The address asked for is a gate: the server listens on loopback behind it. A client is let
//! through while fewer than `[foxglove] max_clients` are connected (the next gets `503` and is
//! closed at once, its request not waited for), and, with a `[server]` token, only when the URL
//! it opens carries `?token=<token>` (percent-encoded), checked in constant time before the
//! handshake; others get `401`. What the server sends a client let through goes through a
//! bounded outbox in the gate (`relay`), and the gate's socket to the client has a small send
//! buffer ([`SEND_BUFFER`]): the kernel does not hide megabytes of stale messages.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use foxglove::websocket::{Capability, Client, ClientChannel, ServerListener};
use foxglove::{Context, PartialMetadata, RawChannel, WebSocketServer};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{broadcast, mpsc, oneshot, watch, Semaphore};
use tokio::time::{self, MissedTickBehavior};
use tracing::{debug, info, warn};

use super::access::Token;
use super::relay;
use super::server::{Door, FLUSH_GRACE, SEND_BUFFER};
use super::side::{Side, SideEnds};
use crate::chain::Chain;
use crate::config::Config;
use crate::protocol::{self, Cmd, Code, Event, Rejection, What};
use crate::ros;
use crate::view::{self, Topic, Trail};
use crate::world::World;

/// The topic a Teleop panel publishes to, under the prefix.
pub const CMD_VEL: &str = "cmd_vel";

/// The topics whose `PointStamped` is a `goto` and a `reach` target, under the prefix.
pub const GOAL: &str = "goal";
/// See [`GOAL`].
pub const REACH: &str = "reach";

/// Commands held between two turns of the view's task; when full the newest is dropped (a
/// `Twist`'s next one replaces it anyway) and counted.
const COMMAND_QUEUE: usize = 8;

/// Refusals of Foxglove commands held before they are logged.
const REFUSAL_QUEUE: usize = 16;

/// Messages each Foxglove client's queue in the server holds before its oldest are dropped
/// (under two seconds of every channel at the default rate). The gate reads each client's
/// connection as fast as the server writes, so this queue fills only when the view's thread
/// itself falls behind; a stalled client's backlog waits in the gate's outbox.
const CLIENT_BACKLOG: usize = 256;

/// Why the view could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ViewError {
    /// The server could not listen (the port taken, the address not this host's).
    #[error("the Foxglove server on {addr}: {message}")]
    Listen {
        /// The address.
        addr: SocketAddr,
        /// Why.
        message: String,
    },
    /// Its thread could not be started, or ended before it said why.
    #[error("the Foxglove server's thread: {0}")]
    Thread(String),
}

impl ViewError {
    /// The server on `addr` could not listen, for `why`.
    fn listen(addr: SocketAddr, why: impl std::fmt::Display) -> Self {
        ViewError::Listen {
            addr,
            message: why.to_string(),
        }
    }
}

/// What the view needs of the config, taken before the loop's thread owns it.
#[derive(Debug, Clone)]
struct Settings {
    listen: SocketAddr,
    prefix: String,
    publish_period: Duration,
    accept_commands: bool,
    deadman: Duration,
    chain: Chain,
    world: World,
    /// The `[server]` token every client presents in its URL; `None`: none asked for.
    token: Option<Token>,
    /// Most clients connected at once.
    max_clients: u32,
}

/// The Foxglove server on its own thread: bound by [`View::open`], serving once
/// [`View::start`] hands it the way in, closed by [`View::stop`].
#[derive(Debug)]
pub struct View {
    addr: SocketAddr,
    side: Side,
}

impl View {
    /// Binds the server `config`'s `[foxglove]` table describes; `None` when it sets no
    /// `listen`. With a `token` (the `[server]` token), the address is a gate that lets a
    /// client through to the server only with `?token=<token>` in its URL.
    pub async fn open(config: &Config, token: Option<Token>) -> Result<Option<View>, ViewError> {
        let table = config.foxglove();
        let Some(listen) = table.listen else {
            return Ok(None);
        };
        let settings = Settings {
            listen,
            prefix: config.zenoh().prefix.clone(),
            publish_period: Duration::try_from_secs_f64(1.0 / table.publish_hz)
                .unwrap_or(Duration::from_secs(1))
                .max(Duration::from_micros(100)),
            accept_commands: table.accept_commands,
            deadman: config.control().deadman,
            chain: config.chain().clone(),
            world: config.world().clone(),
            token,
            max_clients: table.max_clients,
        };
        let body = move |ends: SideEnds<SocketAddr, ViewError>| {
            view_thread(settings, ends.opened, ends.start, ends.stop);
        };
        let (side, addr) = Side::open("snakectl-foxglove", body, ViewError::Thread).await?;
        Ok(Some(View { addr, side }))
    }

    /// Where it listens (the port chosen when the config said 0).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Starts publishing and (with `accept_commands`) commanding through `door`.
    pub fn start(&mut self, door: Door) {
        self.side.start(door);
    }

    /// Closes the server and waits for its thread.
    pub async fn stop(self) {
        self.side.stop().await;
    }
}

/// Longest HTTP request head the gate reads before it refuses a client.
const GATE_HEAD: usize = 8192;

/// How long the gate waits after a failed accept before the next.
const GATE_RETRY: Duration = Duration::from_millis(100);

/// How long a client has to send its request head through the gate.
const GATE_WAIT: Duration = Duration::from_secs(5);

/// The address clients connect to, in front of the server. A client beyond `max_clients`
/// connected at once is answered `503` and closed as soon as it is accepted. Another's request
/// head is read (within [`GATE_WAIT`]), then it is let through to the server at `inner`, or
/// answered `401` and closed without `?token=<token>` when a token is asked for.
async fn gatekeeper(
    listener: TcpListener,
    token: Option<Token>,
    max_clients: u32,
    inner: SocketAddr,
) {
    let seats = Arc::new(Semaphore::new(max_clients as usize));
    loop {
        let (client, peer) = match listener.accept().await {
            Ok(accepted) => accepted,
            Err(e) => {
                // Out of descriptors, say: wait before trying again rather than spin.
                warn!(error = %e, "the Foxglove gate could not accept a client");
                time::sleep(GATE_RETRY).await;
                continue;
            }
        };
        // Small: what waits for a client that reads slowly waits in the relay's bounded outbox,
        // where stale messages are dropped, not in the kernel.
        if let Err(e) = socket2::SockRef::from(&client).set_send_buffer_size(SEND_BUFFER) {
            debug!(%peer, error = %e, "SO_SNDBUF not set");
        }
        // Taken before the head is read, so that clients that never send one count too.
        let seat = Arc::clone(&seats).try_acquire_owned().ok();
        let token = token.clone();
        tokio::spawn(async move {
            if let Err(e) = pass(client, peer, seat.is_some(), token.as_ref(), inner).await {
                debug!(%peer, error = %e, "a Foxglove client turned away");
            }
            drop(seat);
        });
    }
}

/// One client through the gate: its request head read and checked, then the bytes both ways.
/// `seated`: a place among `max_clients` was free for it.
async fn pass(
    mut client: TcpStream,
    peer: SocketAddr,
    seated: bool,
    token: Option<&Token>,
    inner: SocketAddr,
) -> std::io::Result<()> {
    if !seated {
        // Its request is not waited for: a client that is refused anyway holds nothing, not
        // even its descriptor, while it takes its time to send one.
        return refuse(
            client,
            "503 Service Unavailable",
            "[foxglove] max_clients are connected already",
        )
        .await;
    }
    let mut head = Vec::with_capacity(1024);
    let mut buf = [0u8; 1024];
    let read_head = async {
        while !head.windows(4).any(|w| w == b"\r\n\r\n") {
            if head.len() > GATE_HEAD {
                return Err(std::io::Error::other("a request head too long"));
            }
            let got = client.read(&mut buf).await?;
            if got == 0 {
                return Err(std::io::Error::other("closed before its request"));
            }
            head.extend_from_slice(&buf[..got]);
        }
        Ok(())
    };
    time::timeout(GATE_WAIT, read_head)
        .await
        .map_err(|_| std::io::Error::other("no request in time"))??;
    if token.is_some_and(|token| !url_token(&head).is_some_and(|given| token.matches(&given))) {
        return refuse(client, "401 Unauthorized", "no token, or the wrong one").await;
    }
    let mut server = TcpStream::connect(inner).await?;
    server.write_all(&head).await?;
    both_ways(client, server, peer).await
}

/// The bytes both ways between a client let through and the server: the client's as they come,
/// the server's through [`relay::forward`], which drops the oldest message data for a client
/// that falls behind rather than queue it.
async fn both_ways(
    mut client: TcpStream,
    mut server: TcpStream,
    peer: SocketAddr,
) -> std::io::Result<()> {
    let (mut client_r, client_w) = client.split();
    let (server_r, mut server_w) = server.split();
    let up = async {
        tokio::io::copy(&mut client_r, &mut server_w).await?;
        server_w.shutdown().await
    };
    let down = relay::forward(server_r, client_w, || {
        info!(%peer, "a Foxglove client reads slower than the view sends: its oldest messages are dropped");
    });
    tokio::pin!(up, down);
    let mut up_open = true;
    loop {
        tokio::select! {
            sent = &mut up, if up_open => {
                sent?;
                up_open = false;
            }
            relayed = &mut down => {
                let dropped = relayed?.dropped;
                if dropped > 0 {
                    debug!(%peer, dropped, "a Foxglove client that fell behind left");
                }
                return Ok(());
            }
        }
    }
}

/// Answers `client` `status`, with `why` as the body, and closes; the error says `why`. What the
/// client has sent already is read first (without waiting for more), so that the close does not
/// reset the connection under the answer.
async fn refuse(mut client: TcpStream, status: &str, why: &str) -> std::io::Result<()> {
    let answer = format!(
        "HTTP/1.1 {status}\r\nContent-Type: text/plain\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{why}\n",
        why.len() + 1
    );
    client.write_all(answer.as_bytes()).await?;
    let mut unread = [0u8; 1024];
    while matches!(client.try_read(&mut unread), Ok(n) if n > 0) {}
    Err(std::io::Error::other(why.to_owned()))
}

/// The `token` of the query of a request head's target (`GET /?token=... HTTP/1.1`),
/// percent-decoded; `None` without one, or with a broken escape.
fn url_token(head: &[u8]) -> Option<Vec<u8>> {
    let line = head.split(|&b| b == b'\r').next()?;
    let target = line.split(|&b| b == b' ').nth(1)?;
    let query = target.splitn(2, |&b| b == b'?').nth(1)?;
    let raw = query
        .split(|&b| b == b'&')
        .find_map(|pair| pair.strip_prefix(b"token="))?;
    let mut out = Vec::with_capacity(raw.len());
    let mut bytes = raw.iter();
    while let Some(&b) = bytes.next() {
        if b == b'%' {
            let hex = [*bytes.next()?, *bytes.next()?];
            let hex = std::str::from_utf8(&hex).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
        } else {
            out.push(b);
        }
    }
    Some(out)
}

/// A `Twist` as a Foxglove client sends it in JSON; missing fields are 0.
#[derive(Debug, Default, Deserialize)]
struct JsonTwist {
    #[serde(default)]
    linear: JsonVector,
}

#[derive(Debug, Default, Deserialize)]
struct JsonVector {
    #[serde(default)]
    x: f64,
    #[serde(default)]
    y: f64,
}

/// A `PointStamped` as a Foxglove client sends it in JSON; only `point.x`, `point.y` are read.
#[derive(Debug, Deserialize)]
struct JsonPointStamped {
    point: JsonVector,
}

/// Hands what Foxglove clients publish on the command topics to the view's task, never
/// waiting.
struct Commands {
    /// `/<prefix>/`: the command topics' common start.
    prefix: String,
    tx: mpsc::Sender<Result<Cmd, Rejection>>,
    dropped: Arc<AtomicU64>,
}

impl ServerListener for Commands {
    fn on_message_data(&self, _client: Client, channel: &ClientChannel, payload: &[u8]) {
        let Some(topic) = channel.topic.strip_prefix(&self.prefix) else {
            return;
        };
        let encoding = &channel.encoding;
        let cmd = match topic {
            CMD_VEL => twist(encoding, payload).map(|v| Cmd::Velocity { v }),
            GOAL => point(GOAL, encoding, payload).map(|target| Cmd::Goto {
                target,
                speed: None,
            }),
            REACH => point(REACH, encoding, payload).map(|target| Cmd::Reach { target }),
            _ => return,
        };
        if self.tx.try_send(cmd).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn on_client_advertise(&self, _client: Client, channel: &ClientChannel) {
        debug!(topic = %channel.topic, encoding = %channel.encoding, schema = %channel.schema_name, "a Foxglove client advertised");
    }
}

/// The planar velocity of a `Twist` in `encoding` (`json` or `cdr`): `linear.x`, `linear.y`.
fn twist(encoding: &str, payload: &[u8]) -> Result<[f64; 2], Rejection> {
    let v = planar(
        CMD_VEL,
        "geometry_msgs/msg/Twist",
        encoding,
        payload,
        |t: JsonTwist| [t.linear.x, t.linear.y],
        |t: ros::Twist| [t.linear.x, t.linear.y],
    )?;
    protocol::checked_point("v", v)
}

/// The target of a `PointStamped` on `topic` in `encoding` (`json` or `cdr`): `point.x`,
/// `point.y`, m.
fn point(topic: &str, encoding: &str, payload: &[u8]) -> Result<[f64; 2], Rejection> {
    let p = planar(
        topic,
        "geometry_msgs/msg/PointStamped",
        encoding,
        payload,
        |p: JsonPointStamped| [p.point.x, p.point.y],
        |p: ros::PointStamped| [p.point.x, p.point.y],
    )?;
    protocol::checked_point("target", p)
        .map_err(|e| Rejection::new(e.code, format!("{topic} {}", e.message)))
}

/// The two numbers a message of type `schema` on `topic` carries, decoded from `encoding`:
/// JSON as `J`, CDR as `C`; refused `bad_arg`, naming the topic and the type, when it is not
/// one.
fn planar<J: DeserializeOwned, C: DeserializeOwned>(
    topic: &str,
    schema: &str,
    encoding: &str,
    payload: &[u8],
    from_json: impl FnOnce(J) -> [f64; 2],
    from_cdr: impl FnOnce(C) -> [f64; 2],
) -> Result<[f64; 2], Rejection> {
    let bad = |e: &dyn std::fmt::Display| {
        Rejection::new(
            Code::BadArg,
            format!("{topic} is not a {schema} in {encoding}: {e}"),
        )
    };
    match encoding {
        "json" => Ok(from_json(
            serde_json::from_slice(payload).map_err(|e| bad(&e))?,
        )),
        "cdr" => Ok(from_cdr(ros::decode(payload).map_err(|e| bad(&e))?)),
        other => Err(Rejection::new(
            Code::BadArg,
            format!("{topic} in {other:?}: only json and cdr are taken"),
        )),
    }
}

/// Seconds since the Unix epoch now: the stamps of what the view sends.
fn wall_clock_s() -> f64 {
    match SystemTime::now().duration_since(UNIX_EPOCH) {
        Ok(d) => d.as_secs_f64(),
        Err(e) => -e.duration().as_secs_f64(),
    }
}

fn view_thread(
    settings: Settings,
    opened: oneshot::Sender<Result<SocketAddr, ViewError>>,
    start: oneshot::Receiver<Door>,
    mut stop: oneshot::Receiver<()>,
) {
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(runtime) => runtime,
        Err(e) => {
            let _ = opened.send(Err(ViewError::Thread(e.to_string())));
            return;
        }
    };
    runtime.block_on(async move {
        // A context of its own: several daemons in one process keep their channels apart.
        let context = Context::new();
        let (commands_tx, commands_rx) = mpsc::channel(COMMAND_QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        // The server listens on loopback, behind the gate on the address asked for.
        let gate = match TcpListener::bind(settings.listen).await {
            Ok(listener) => listener,
            Err(e) => {
                let _ = opened.send(Err(ViewError::listen(settings.listen, e)));
                return;
            }
        };
        let server_addr = SocketAddr::from(([127, 0, 0, 1], 0));
        let mut server = WebSocketServer::new()
            .name(settings.prefix.clone())
            .bind(server_addr.ip().to_string(), server_addr.port())
            .context(&context)
            .message_backlog_size(CLIENT_BACKLOG);
        if settings.accept_commands {
            server = server
                .capabilities([Capability::ClientPublish])
                .supported_encodings(["json", "cdr"])
                .listener(Arc::new(Commands {
                    prefix: format!("/{}/", settings.prefix),
                    tx: commands_tx,
                    dropped: Arc::clone(&dropped),
                }));
        }
        let handle = match server.start().await {
            Ok(handle) => handle,
            Err(e) => {
                let _ = opened.send(Err(ViewError::listen(settings.listen, e)));
                return;
            }
        };
        let inner = SocketAddr::new(server_addr.ip(), handle.port());
        let addr = gate.local_addr().unwrap_or(settings.listen);
        tokio::spawn(gatekeeper(
            gate,
            settings.token.clone(),
            settings.max_clients,
            inner,
        ));
        let _ = opened.send(Ok(addr));
        let door = tokio::select! {
            door = start => door.ok(),
            _ = &mut stop => None,
        };
        if let Some(door) = door {
            match Channels::declare(&context, &settings.prefix) {
                Ok(channels) => {
                    info!(
                        url = %format!("ws://{addr}"),
                        accept_commands = settings.accept_commands,
                        "the Foxglove view serves"
                    );
                    let served = Served {
                        settings: &settings,
                        door,
                        channels,
                        trail: Trail::default(),
                        world: settings.world.clone(),
                        lost_events: 0,
                        dropped_commands: dropped,
                    };
                    served.run(commands_rx, &mut stop).await;
                }
                Err(e) => warn!(error = %e, "the Foxglove channels could not be declared"),
            }
        }
        // Each client is sent its close; one that reads nothing more (its connection full)
        // would hold the stop, and the daemon's exit with it, for as long as it stays: it is
        // given the socket's grace, then cut off with the runtime.
        if time::timeout(FLUSH_GRACE, handle.stop().wait())
            .await
            .is_err()
        {
            warn!(
                grace_ms = FLUSH_GRACE.as_millis() as u64,
                "a Foxglove client did not take its close in time: cut off"
            );
        }
    });
}

/// The server's channels, one per [`Topic`].
struct Channels {
    channels: Vec<(Topic, Arc<RawChannel>)>,
}

impl Channels {
    fn declare(context: &Arc<Context>, prefix: &str) -> Result<Channels, foxglove::FoxgloveError> {
        let channels = Topic::ALL
            .iter()
            .map(|&topic| {
                let spec = topic.channel(prefix);
                context
                    .channel_builder(spec.topic)
                    .message_encoding(spec.message_encoding)
                    .schema(spec.schema)
                    .build_raw()
                    .map(|channel| (topic, channel))
            })
            .collect::<Result<_, _>>()?;
        Ok(Channels { channels })
    }

    fn log(&self, topic: Topic, bytes: &[u8], log_time: u64) {
        if let Some((_, channel)) = self.channels.iter().find(|(t, _)| *t == topic) {
            channel.log_with_meta(
                bytes,
                PartialMetadata {
                    log_time: Some(log_time),
                },
            );
        }
    }
}

/// The view while it serves.
struct Served<'a> {
    settings: &'a Settings,
    door: Door,
    channels: Channels,
    trail: Trail,
    world: World,
    lost_events: u64,
    dropped_commands: Arc<AtomicU64>,
}

impl Served<'_> {
    async fn run(
        mut self,
        mut commands: mpsc::Receiver<Result<Cmd, Rejection>>,
        stop: &mut oneshot::Receiver<()>,
    ) {
        let mut ticker = time::interval(self.settings.publish_period);
        ticker.set_missed_tick_behavior(MissedTickBehavior::Skip);
        let mut telemetry = self.door.telemetry();
        let tick_done = self.door.tick_done();
        let mut events = self.door.events();
        let mut events_open = true;
        let mut last_command: Option<time::Instant> = None;
        let mut last_refusal: Option<Code> = None;
        let (refusals_tx, mut refusals) = mpsc::channel::<Rejection>(REFUSAL_QUEUE);
        // A publication is due: it goes out when the loop's next tick ends, in the idle rest
        // of the loop's period, so that encoding and sending it never overlap a tick's work.
        let mut due = false;
        loop {
            let silence = last_command.map(|t| t + self.settings.deadman);
            tokio::select! {
                _ = &mut *stop => break,
                _ = ticker.tick() => {
                    if due {
                        // No tick ended in a whole publish period (the loop has stopped):
                        // the last snapshot goes out on the view's own clock.
                        self.publish_latest(&mut telemetry);
                    }
                    due = true;
                }
                () = tick_done.notified(), if due => {
                    due = false;
                    self.publish_latest(&mut telemetry);
                }
                event = events.recv(), if events_open => match event {
                    Ok(event) => self.event(&event),
                    Err(broadcast::error::RecvError::Lagged(missed)) => {
                        self.lost_events += missed;
                        debug!(missed, "the Foxglove view fell behind the events");
                    }
                    Err(broadcast::error::RecvError::Closed) => events_open = false,
                },
                Some(cmd) = commands.recv() => {
                    let sent = cmd.and_then(|cmd| self.door.send(cmd));
                    match sent {
                        Ok(answer) => {
                            last_command = Some(time::Instant::now());
                            last_refusal = None;
                            let refusals = refusals_tx.clone();
                            tokio::spawn(async move {
                                if let Ok(Err(why)) = answer.await {
                                    // Full: this refusal is not logged; the next one is.
                                    let _ = refusals.try_send(why);
                                }
                            });
                        }
                        Err(why) => refused(why, &mut last_refusal),
                    }
                }
                Some(why) = refusals.recv() => refused(why, &mut last_refusal),
                () = sleep_until(silence), if silence.is_some() => {
                    last_command = None;
                    if self.door.release() {
                        info!("no Foxglove command for the deadman: control released");
                    }
                }
            }
        }
        let dropped = self.dropped_commands.load(Ordering::Relaxed);
        if self.lost_events > 0 || dropped > 0 {
            warn!(
                lost_events = self.lost_events,
                dropped_commands = dropped,
                "the Foxglove view fell behind"
            );
        }
    }

    /// Publishes the loop's latest snapshot: cloned, then let go, so that building the
    /// messages never holds the loop.
    fn publish_latest(&mut self, telemetry: &mut watch::Receiver<protocol::Telemetry>) {
        let t = telemetry.borrow_and_update().clone();
        self.publish(&t);
    }

    /// Sends one snapshot on every channel, and the scene.
    fn publish(&mut self, t: &protocol::Telemetry) {
        let now = wall_clock_s();
        let log_time = view::nanos(now);
        let cdr = |result: Result<Vec<u8>, ros::RosError>| match result {
            Ok(bytes) => Some(bytes),
            Err(e) => {
                warn!(error = %e, "a ROS message could not be encoded");
                None
            }
        };
        if !t.theta_meas.is_empty() {
            if let Some(bytes) = cdr(view::joint_states(t, now)) {
                self.channels.log(Topic::JointStates, &bytes, log_time);
            }
        }
        for (topic, p) in [(Topic::TipCmd, t.tip), (Topic::TipMeas, t.tip_meas)] {
            if let Some(bytes) = cdr(view::point(p, now)) {
                self.channels.log(topic, &bytes, log_time);
            }
        }
        if let Some(target) = t.target {
            if let Some(bytes) = cdr(view::point(target, now)) {
                self.channels.log(Topic::Target, &bytes, log_time);
            }
        }
        let line = self.door.telemetry_line(t);
        self.channels
            .log(Topic::Telemetry, &view::json_line(&line), log_time);
        if t.theta_meas.len() == self.settings.chain.len() {
            self.trail.push(t.tip_meas);
        }
        let scene = view::scene(
            &self.settings.chain,
            &self.world,
            t,
            &self.trail,
            view::timestamp(now),
        );
        match view::encode(&scene) {
            Ok(bytes) => self.channels.log(Topic::Scene, &bytes, log_time),
            Err(e) => warn!(error = %e, "the scene could not be encoded"),
        }
    }

    /// Sends `event` on `events` and `log`; a `world` event changes the scene's obstacles.
    fn event(&mut self, event: &Event) {
        if let What::World { world, .. } = &event.what {
            match world.to_world() {
                Ok(w) => self.world = w,
                Err(e) => warn!(error = %e, "a world event the scene cannot draw"),
            }
        }
        let now = wall_clock_s();
        let log_time = view::nanos(now);
        self.channels
            .log(Topic::Events, &view::event(event), log_time);
        match view::encode(&view::log(event, now)) {
            Ok(bytes) => self.channels.log(Topic::Log, &bytes, log_time),
            Err(e) => warn!(error = %e, "a log message could not be encoded"),
        }
    }
}

/// Logs a refused Foxglove command, once per run of the same refusal.
fn refused(why: Rejection, last: &mut Option<Code>) {
    if *last != Some(why.code) {
        warn!(code = ?why.code, reason = %why.message, "a Foxglove command was refused");
        *last = Some(why.code);
    }
}

async fn sleep_until(deadline: Option<time::Instant>) {
    match deadline {
        Some(deadline) => time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn the_gate_reads_the_token_of_the_url_percent_decoded() {
        let head = |target: &str| format!("GET {target} HTTP/1.1\r\nHost: x\r\n\r\n");
        let token = |target: &str| url_token(head(target).as_bytes());
        assert_eq!(token("/?token=s3cret"), Some(b"s3cret".to_vec()));
        assert_eq!(
            token("/?a=1&token=correct%20horse&b=2"),
            Some(b"correct horse".to_vec())
        );
        assert_eq!(token("/"), None);
        assert_eq!(token("/?tok=s3cret"), None);
        assert_eq!(token("/?token=bad%2"), None, "a cut escape");
        assert_eq!(token("/?token=bad%zz"), None, "not hex");
    }

    #[tokio::test]
    async fn beyond_max_clients_a_client_is_refused_without_waiting_for_its_request() {
        // The Foxglove server behind the gate, and the gate with one seat.
        let server = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let gate = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = gate.local_addr().unwrap();
        tokio::spawn(gatekeeper(gate, None, 1, server.local_addr().unwrap()));
        // The seat taken by a client let through to the server.
        let mut first = TcpStream::connect(addr).await.unwrap();
        let request = b"GET / HTTP/1.1\r\nHost: x\r\n\r\n";
        first.write_all(request).await.unwrap();
        let (mut passed, _) = server.accept().await.unwrap();
        let mut head = vec![0u8; request.len()];
        passed.read_exact(&mut head).await.unwrap();
        assert_eq!(head, request);
        // From here no timer of the gate runs but one it starts for the next client: with time
        // paused, its clock jumps to that timer as soon as nothing else is left to do.
        time::pause();
        let paused = time::Instant::now();
        // A second client, which sends nothing.
        let mut second = TcpStream::connect(addr).await.unwrap();
        let mut answer = Vec::new();
        tokio::select! {
            read = second.read_to_end(&mut answer) => read.unwrap(),
            _ = server.accept() => panic!("the second client was let through"),
        };
        let answer = String::from_utf8_lossy(&answer);
        assert!(
            answer.starts_with("HTTP/1.1 503 Service Unavailable\r\n")
                && answer.ends_with("max_clients are connected already\n"),
            "{answer}"
        );
        assert!(
            time::Instant::now() - paused < GATE_WAIT,
            "closed only when the wait for its request ran out"
        );
    }

    #[test]
    fn a_twist_reads_from_json_and_cdr() {
        let json = br#"{"linear":{"x":0.1,"y":-0.2,"z":0},"angular":{"x":0,"y":0,"z":0.5}}"#;
        assert_eq!(twist("json", json).unwrap(), [0.1, -0.2]);
        let cdr = ros::encode(&ros::Twist {
            linear: ros::Vector3 {
                x: 0.03,
                y: 0.04,
                z: 9.0,
            },
            angular: ros::Vector3::default(),
        })
        .unwrap();
        assert_eq!(twist("cdr", &cdr).unwrap(), [0.03, 0.04]);
        for (encoding, payload) in [
            ("json", &b"{\"linear\": 3}"[..]),
            ("json", b"not json"),
            ("cdr", b"\x00\x01"),
            ("protobuf", b""),
        ] {
            let e = twist(encoding, payload).unwrap_err();
            assert_eq!(e.code, Code::BadArg, "{encoding}: {}", e.message);
        }
        // Out of the protocol's range, refused as a socket client's would be.
        let huge = br#"{"linear":{"x":1e300,"y":0}}"#;
        assert_eq!(twist("json", huge).unwrap_err().code, Code::BadArg);
    }

    #[test]
    fn a_point_reads_from_json_and_cdr_and_names_its_topic() {
        // As the 3-D panel's click publishes it: a header, and z.
        let json = br#"{"header":{"stamp":{"sec":1,"nanosec":2},"frame_id":"base"},
                        "point":{"x":-0.45,"y":0.62,"z":0.1}}"#;
        assert_eq!(point(REACH, "json", json).unwrap(), [-0.45, 0.62]);
        let cdr = ros::encode(&ros::point_stamped([0.3, -0.2], 5.0, "base")).unwrap();
        assert_eq!(point(GOAL, "cdr", &cdr).unwrap(), [0.3, -0.2]);
        for (encoding, payload) in [
            ("json", &br#"{"linear":{"x":1,"y":2}}"#[..]),
            ("json", br#"{"point":{"x":1e300,"y":0}}"#),
            ("cdr", b"\x00\x01"),
            ("protobuf", b""),
        ] {
            let e = point(REACH, encoding, payload).unwrap_err();
            assert_eq!(e.code, Code::BadArg, "{encoding}: {}", e.message);
            assert!(e.message.starts_with("reach "), "{}", e.message);
        }
    }
}
