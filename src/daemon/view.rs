//! The live Foxglove view: the Foxglove WebSocket protocol served on `[foxglove] listen`, on a
//! thread of its own, publishing the channels of [`crate::view`] from what the loop publishes.
//!
//! [`View::open`] binds the address before anything moves (a taken port stops start-up);
//! [`View::start`] hands the view a [`Door`]; [`View::stop`] closes it (a client that does not
//! take its close within [`FLUSH_GRACE`] is cut off). Its thread runs its own runtime and never
//! holds the loop up: at `publish_hz`, right after the loop's next tick ends (in the idle rest
//! of its period, not across a tick), it clones the latest telemetry from the loop's `watch`
//! (latest wins: a skipped sample is never queued) and sends the joints, the tips, the target,
//! the telemetry line and the whole scene again (so a client that joins late sees the arm at
//! rest); events come from the loop's broadcast, and what it misses when behind is counted
//! ([`View::stop`] logs the count).
//!
//! The `foxglove` crate gives the channels, their schemas and the messages' encodings, on a
//! [`Context`] of the view's own; the protocol's server side is the daemon's (`gate`, `hub`),
//! so that the address asked for is the only way in: no other socket listens. There a client is
//! let in while fewer than `[foxglove] max_clients` are connected (the next gets `503`), and,
//! with a `[server]` token, only when the URL it opens carries `?token=<token>` (`401`
//! otherwise); what waits for it is bounded, its oldest message data dropped (`outbox`).
//!
//! With `accept_commands`, the server offers client publishing (`json` and `cdr`): a `Twist`
//! published on `/<prefix>/cmd_vel` becomes `velocity` (`linear.x`, `linear.y`, m/s), and a
//! `PointStamped` on `/<prefix>/goal` or `/<prefix>/reach` (the 3-D panel's click, say) a
//! `goto` or a `reach` to (`point.x`, `point.y`), all through the door: the same arbiter and
//! bounded queue as a socket client's commands, one controller id for every Foxglove client,
//! control let go of after the deadman's silence. A refused command is logged once per run of
//! refusals with the same code on the same topic; the run's end says how many more there were.
//! Without it the server offers no publishing and nothing a Foxglove client sends moves the
//! arm.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use foxglove::{Context, PartialMetadata, RawChannel};
use serde::de::DeserializeOwned;
use serde_json::Value;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, mpsc, oneshot, watch};
use tokio::time::{self, MissedTickBehavior};
use tracing::{debug, info, warn};

use super::access::Token;
use super::gate::{self, Gate};
use super::hub::Hub;
use super::server::{Door, FLUSH_GRACE};
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

/// Answers to Foxglove commands held before they are looked at (for the log of refusals).
const OUTCOME_QUEUE: usize = 16;

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

/// A command a Foxglove client published, or why it is refused, with the topic it came on.
#[derive(Debug)]
struct Order {
    topic: &'static str,
    cmd: Result<Cmd, Rejection>,
}

/// Hands what Foxglove clients publish on the command topics to the view's task, never
/// waiting.
#[derive(Debug)]
pub(super) struct Commands {
    /// `/<prefix>/`: the command topics' common start.
    prefix: String,
    tx: mpsc::Sender<Order>,
    dropped: Arc<AtomicU64>,
}

impl Commands {
    /// Takes `payload`, published in `encoding` on `topic`: a command on one of the command
    /// topics, nothing on another.
    pub(super) fn take(&self, topic: &str, encoding: &str, payload: &[u8]) {
        let Some(topic) = topic.strip_prefix(&self.prefix) else {
            return;
        };
        let order = match topic {
            CMD_VEL => Order {
                topic: CMD_VEL,
                cmd: twist(encoding, payload).map(|v| Cmd::Velocity { v }),
            },
            GOAL => Order {
                topic: GOAL,
                cmd: point(GOAL, encoding, payload).map(|target| Cmd::Goto {
                    target,
                    speed: None,
                }),
            },
            REACH => Order {
                topic: REACH,
                cmd: point(REACH, encoding, payload).map(|target| Cmd::Reach { target }),
            },
            _ => return,
        };
        if self.tx.try_send(order).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The planar velocity of a `Twist` in `encoding` (`json` or `cdr`): `linear.x`, `linear.y`.
/// In JSON, `linear` is an object (its missing `x` or `y` is 0).
fn twist(encoding: &str, payload: &[u8]) -> Result<[f64; 2], Rejection> {
    let v = planar(
        CMD_VEL,
        "geometry_msgs/msg/Twist",
        "linear",
        encoding,
        payload,
        |t: ros::Twist| [t.linear.x, t.linear.y],
    )?;
    protocol::checked_point("v", v)
        .map_err(|e| Rejection::new(e.code, format!("{CMD_VEL} {}", e.message)))
}

/// The target of a `PointStamped` on `topic` in `encoding` (`json` or `cdr`): `point.x`,
/// `point.y`, m. In JSON, `point` is an object (its missing `x` or `y` is 0).
fn point(topic: &str, encoding: &str, payload: &[u8]) -> Result<[f64; 2], Rejection> {
    let p = planar(
        topic,
        "geometry_msgs/msg/PointStamped",
        "point",
        encoding,
        payload,
        |p: ros::PointStamped| [p.point.x, p.point.y],
    )?;
    protocol::checked_point("target", p)
        .map_err(|e| Rejection::new(e.code, format!("{topic} {}", e.message)))
}

/// The two numbers a message of type `schema` on `topic` carries, decoded from `encoding`: in
/// JSON the `x` and `y` of its object `field`, in CDR as `C`; refused `bad_arg`, naming the
/// topic and the type, when it is not one.
fn planar<C: DeserializeOwned>(
    topic: &str,
    schema: &str,
    field: &str,
    encoding: &str,
    payload: &[u8],
    from_cdr: impl FnOnce(C) -> [f64; 2],
) -> Result<[f64; 2], Rejection> {
    let bad = |e: &dyn std::fmt::Display| {
        Rejection::new(
            Code::BadArg,
            format!("{topic} is not a {schema} in {encoding}: {e}"),
        )
    };
    match encoding {
        "json" => {
            let message: Value = serde_json::from_slice(payload).map_err(|e| bad(&e))?;
            json_xy(&message, field).map_err(|e| bad(&e))
        }
        "cdr" => Ok(from_cdr(ros::decode(payload).map_err(|e| bad(&e))?)),
        other => Err(Rejection::new(
            Code::BadArg,
            format!("{topic} in {other:?}: only json and cdr are taken"),
        )),
    }
}

/// The `x` and `y` of the object `field` of the JSON object `message`; a missing one is 0.
fn json_xy(message: &Value, field: &str) -> Result<[f64; 2], String> {
    let Some(vector) = message.get(field).and_then(Value::as_object) else {
        return Err(format!("no `{field}` object"));
    };
    let mut xy = [0.0; 2];
    for (slot, axis) in xy.iter_mut().zip(["x", "y"]) {
        if let Some(v) = vector.get(axis) {
            *slot = v
                .as_f64()
                .ok_or_else(|| format!("`{field}.{axis}` is not a number"))?;
        }
    }
    Ok(xy)
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
        // The one socket the view listens on: the gate, on the address asked for.
        let listener = match TcpListener::bind(settings.listen).await {
            Ok(listener) => listener,
            Err(e) => {
                let _ = opened.send(Err(ViewError::listen(settings.listen, e)));
                return;
            }
        };
        let addr = listener.local_addr().unwrap_or(settings.listen);
        // Every message logged on the context's channels reaches the clients through it.
        let hub = Arc::new(Hub::new(&settings.prefix, settings.accept_commands));
        context.add_sink(Arc::clone(&hub) as Arc<dyn foxglove::Sink>);
        let commands = settings.accept_commands.then(|| {
            Arc::new(Commands {
                prefix: format!("/{}/", settings.prefix),
                tx: commands_tx,
                dropped: Arc::clone(&dropped),
            })
        });
        let gate = Gate {
            token: settings.token.clone(),
            max_clients: settings.max_clients,
            hub: Arc::clone(&hub),
            commands,
        };
        let gatekeeper = tokio::spawn(gate::keep(listener, gate));
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
        // No one new comes in. Each client is sent its close; one that reads nothing more (its
        // connection full) would hold the stop, and the daemon's exit with it, for as long as
        // it stays: it is given the socket's grace, then cut off with the runtime.
        gatekeeper.abort();
        if !hub.close(FLUSH_GRACE).await {
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
    async fn run(mut self, mut commands: mpsc::Receiver<Order>, stop: &mut oneshot::Receiver<()>) {
        let mut ticker = time::interval(self.settings.publish_period);
        ticker.set_missed_tick_behavior(MissedTickBehavior::Skip);
        let mut telemetry = self.door.telemetry();
        let tick_done = self.door.tick_done();
        let mut events = self.door.events();
        let mut events_open = true;
        let mut last_command: Option<time::Instant> = None;
        let mut refusals = Refusals::default();
        let (outcomes_tx, mut outcomes) = mpsc::channel::<Outcome>(OUTCOME_QUEUE);
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
                Some(order) = commands.recv() => {
                    let topic = order.topic;
                    match order.cmd.and_then(|cmd| self.door.send(cmd)) {
                        Ok(answer) => {
                            last_command = Some(time::Instant::now());
                            let outcomes = outcomes_tx.clone();
                            tokio::spawn(async move {
                                if let Ok(answer) = answer.await {
                                    // Full: this outcome is not logged.
                                    let _ = outcomes.try_send(Outcome {
                                        topic,
                                        refused: answer.err(),
                                    });
                                }
                            });
                        }
                        Err(why) => refusals.refused(topic, &why),
                    }
                }
                Some(outcome) = outcomes.recv() => match outcome.refused {
                    Some(why) => refusals.refused(outcome.topic, &why),
                    None => refusals.end_run(),
                },
                () = sleep_until(silence), if silence.is_some() => {
                    last_command = None;
                    if self.door.release() {
                        info!("no Foxglove command for the deadman: control released");
                    }
                }
            }
        }
        refusals.end_run();
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

/// What the loop answered a Foxglove command on `topic`: `refused` it, or took it.
#[derive(Debug)]
struct Outcome {
    topic: &'static str,
    refused: Option<Rejection>,
}

/// The log of refused Foxglove commands: once per run of refusals with the same code on the
/// same topic (a Teleop panel publishing during an estop is refused ten times a second); the
/// run's end (a command taken, another refusal, the stop) says how many more there were.
#[derive(Debug, Default)]
struct Refusals {
    /// The code and topic of the run, once its first refusal is logged.
    run: Option<(Code, &'static str)>,
    /// Refusals of the run not logged.
    more: u64,
}

impl Refusals {
    /// A command on `topic` was refused for `why`.
    fn refused(&mut self, topic: &'static str, why: &Rejection) {
        if self.run == Some((why.code, topic)) {
            self.more += 1;
            return;
        }
        self.end_run();
        warn!(topic, code = why.code.as_str(), reason = %why.message, "a Foxglove command was refused");
        self.run = Some((why.code, topic));
    }

    /// The run of refusals ends (a command was taken, or the view stops).
    fn end_run(&mut self) {
        if let Some((code, topic)) = self.run.take() {
            if self.more > 0 {
                warn!(
                    topic,
                    code = code.as_str(),
                    count = self.more,
                    "more Foxglove commands were refused alike"
                );
            }
        }
        self.more = 0;
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
        // `linear` alone, or its x alone: the rest is 0.
        assert_eq!(
            twist("json", br#"{"linear":{"x":0.1}}"#).unwrap(),
            [0.1, 0.0]
        );
        for (encoding, payload) in [
            ("json", &b"{\"linear\": 3}"[..]),
            ("json", b"not json"),
            // Not a Twist: no `linear` object, or not numbers in it.
            ("json", b"[]"),
            ("json", b"{}"),
            ("json", br#"{"data":"hi"}"#),
            ("json", br#"{"linear":[0.1,0.2]}"#),
            ("json", br#"{"linear":{"x":"0.1"}}"#),
            ("cdr", b"\x00\x01"),
            ("protobuf", b""),
        ] {
            let e = twist(encoding, payload).unwrap_err();
            assert_eq!(e.code, Code::BadArg, "{encoding}: {}", e.message);
            assert!(e.message.starts_with("cmd_vel "), "{}", e.message);
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
            ("json", br#"{"point":[1,2]}"#),
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
