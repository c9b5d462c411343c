//! The daemon on a Zenoh network, in ROS 2's message formats: the one file that speaks Zenoh
//! (the `zenoh` feature).
//!
//! [`Bridge`] runs a Zenoh session on a thread of its own, with a runtime of its own (Zenoh
//! needs a multi-threaded one; the daemon's is single-threaded). Under `<prefix>/` it publishes
//! `joint_states`, `tip`, `target` (ROS 2 messages in CDR, [`crate::ros`]), `telemetry` (the
//! socket's telemetry line) and `events` (event lines, and refusals of network commands), at
//! `publish_hz` from the loop's latest telemetry, right after the end of a tick (in the idle
//! rest of the loop's period): the loop hands over a snapshot, latest wins, and never waits on
//! Zenoh. It answers `<prefix>/status` (the socket's `status` reply) and
//! `<prefix>/describe`, and holds the liveliness token `<prefix>` while it runs.
//!
//! With `accept_commands`, `cmd_vel` (`Twist`), `goal` and `reach` (`PointStamped`) become
//! `velocity`, `goto` and `reach` through a [`Door`]: one controller id for everything that
//! comes from the network, put to the same arbiter and the same bounded queue as a socket
//! client's commands, and let go of after the deadman's silence.
//!
//! With `ros2`, the daemon is also a ROS 2 node as rmw_zenoh sees one: node `snakectl` in
//! the namespace `/<prefix>`, publishing `joint_states`, `tip_cmd`, `tip_meas` and `target` on
//! rmw_zenoh's data keys with its attachment, subscribing `cmd_vel`, `goal` and `reach` there
//! when commands are accepted, and holding a graph token for the node and for each of those;
//! the names and bytes come from [`crate::ros::rmw`]. Both key layouts may be served at once. A
//! sample on a ROS 2 key without rmw_zenoh's attachment is refused (`bad_arg`, on the events
//! key), as rmw_zenoh itself drops one; the plain keys take samples with or without one.
//!
//! [`Peer`] is a plain, blocking session for tools and tests (`snakectl fleet`), and [`fleet`]
//! lists the arms a peer can see.

use std::cell::Cell;
use std::path::PathBuf;
use std::pin::Pin;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde_json::Value;
use tokio::sync::futures::Notified;
use tokio::sync::{broadcast, oneshot};
use tokio::time::{self, MissedTickBehavior};
use tracing::{debug, info, warn};
use zenoh::bytes::Encoding;
use zenoh::handlers::{RingChannel, RingChannelHandler};
use zenoh::qos::CongestionControl;
use zenoh::sample::{Sample, SampleKind};
use zenoh::{Session, Wait};

use super::server::Door;
use super::side::{Side, SideEnds};
use crate::config::{Config, Endpoint, Zenoh, ZenohMode};
use crate::protocol::{
    self, Cmd, CmdName, Code, Fields, Rejection, Reply, ReplyLine, ServerLine, Status, Telemetry,
};
use crate::ros::{self, rmw};

/// Network commands held for the bridge between two of its turns; the newest win (a newer
/// `cmd_vel` replaces an older one anyway).
const COMMAND_RING: usize = 8;

/// At most one refusal of a network command is published per this gap; those in between are
/// folded into the next one told, with their count.
const REFUSAL_EVENT_GAP: Duration = Duration::from_millis(100);

/// The log tells a run of the same refusal once, and again after this long, with the count.
const REFUSAL_LOG_GAP: Duration = Duration::from_secs(10);

/// Queries held before the bridge answers them; more wait in Zenoh.
const QUERY_QUEUE: usize = 64;

/// A queryable whose queries wait in a bounded channel.
type Queryable = zenoh::query::Queryable<zenoh::handlers::FifoChannelHandler<zenoh::query::Query>>;

/// How long start-up looks for another daemon's liveliness token on the prefix: those already
/// known, and those of sessions whose connections come up meanwhile.
pub const PREFIX_WAIT: Duration = Duration::from_millis(500);

/// Samples a [`Subscription`] keeps for a reader that is behind; older ones are dropped.
pub const SUBSCRIPTION_RING: usize = 256;

/// Why Zenoh could not be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NetError {
    /// The session's settings were refused.
    #[error("the Zenoh settings `{key}`: {message}")]
    Setting {
        /// The Zenoh config key.
        key: &'static str,
        /// Zenoh's reason.
        message: String,
    },
    /// `config_file` could not be read as a Zenoh config.
    #[error("the Zenoh config file {}: {message}", path.display())]
    ConfigFile {
        /// The file.
        path: PathBuf,
        /// Zenoh's reason.
        message: String,
    },
    /// The session could not be opened (an endpoint taken, no router to reach, ...).
    #[error("opening the Zenoh session: {0}")]
    Open(String),
    /// Commands would be taken from a network other hosts can reach, and the session's config
    /// sets up no access control.
    #[error(
        "accept_commands = true, but {exposure}: any host that reaches the arm could move it; \
         enable Zenoh's access control (access_control.enabled = true, default_permission = \
         \"deny\") in the file named by config_file, or keep every endpoint on loopback with \
         multicast = false"
    )]
    CommandsExposed {
        /// What opens the session to other hosts, as in effect once `config_file` is read.
        exposure: String,
    },
    /// Commands would be taken from Zenoh, which never asks for the `[server] token_file`
    /// token, and the session's config sets up no access control instead.
    #[error(
        "accept_commands = true, but [server] token_file ({}) is set and Zenoh never asks for \
         it: any program that reaches the Zenoh session, on this host too, could move the arm; \
         enable Zenoh's access control (access_control.enabled = true, default_permission = \
         \"deny\") in the file named by config_file, or set accept_commands = false",
        token_file.display()
    )]
    TokenNotAsked {
        /// The token file.
        token_file: PathBuf,
    },
    /// A publisher, subscriber, queryable or token could not be declared.
    #[error("declaring `{key}` on Zenoh: {message}")]
    Declare {
        /// The key.
        key: String,
        /// Zenoh's reason.
        message: String,
    },
    /// A put or a query failed.
    #[error("`{key}` on Zenoh: {message}")]
    Io {
        /// The key.
        key: String,
        /// Zenoh's reason.
        message: String,
    },
    /// Another daemon holds the liveliness token of the prefix on this network.
    #[error(
        "another daemon on this Zenoh network holds the prefix {prefix:?} (its liveliness \
         token): two daemons on one prefix would both obey its commands and mix their \
         telemetry; give each arm its own [zenoh] prefix, or stop the other daemon"
    )]
    PrefixTaken {
        /// The prefix.
        prefix: String,
    },
    /// The bridge's thread could not be started, or ended before it said why.
    #[error("the Zenoh thread: {0}")]
    Thread(String),
}

/// The session's Zenoh config from the `[zenoh]` table: `config_file` as the start (access
/// control, timeouts), then the table's `mode` and `multicast`, and its endpoint lists.
/// A list is set even when empty, so that the session never falls back to Zenoh's default of
/// listening on every interface; only with `file_endpoints` and a `config_file` does an empty
/// list leave the file's (the daemon's rule: endpoints may live in that file), and a file that
/// leaves `listen` at Zenoh's default listens nowhere all the same.
fn session_config(table: &Zenoh, file_endpoints: bool) -> Result<zenoh::Config, NetError> {
    let mut config = match &table.config_file {
        Some(path) => zenoh::Config::from_file(path).map_err(|e| NetError::ConfigFile {
            path: path.clone(),
            message: e.to_string(),
        })?,
        None => zenoh::Config::default(),
    };
    set(&mut config, "mode", &Value::from(mode_name(table.mode)))?;
    set(
        &mut config,
        "scouting/multicast/enabled",
        &Value::from(table.multicast),
    )?;
    let from_file = file_endpoints && table.config_file.is_some();
    let default_listen = get(&zenoh::Config::default(), "listen/endpoints")?;
    for (key, list) in [
        ("connect/endpoints", &table.connect),
        ("listen/endpoints", &table.listen),
    ] {
        let file_has_them = from_file
            && list.is_empty()
            && !(key == "listen/endpoints" && get(&config, key)? == default_listen);
        if !file_has_them {
            let list: Vec<Value> = list.iter().map(|e| e.to_string().into()).collect();
            set(&mut config, key, &Value::from(list))?;
        }
    }
    Ok(config)
}

/// The value of `key` in `config`, as JSON.
fn get(config: &zenoh::Config, key: &'static str) -> Result<Value, NetError> {
    let setting = |message: String| NetError::Setting { key, message };
    let text = config.get_json(key).map_err(|e| setting(e.to_string()))?;
    serde_json::from_str(&text).map_err(|e| setting(e.to_string()))
}

/// The endpoints of `key` (`listen/endpoints`, `connect/endpoints`) in effect for `mode`: a
/// list for every mode, or one per mode.
fn endpoints_in_effect(
    config: &zenoh::Config,
    key: &'static str,
    mode: ZenohMode,
) -> Result<Vec<String>, NetError> {
    fn strings(value: &Value, out: &mut Vec<String>) {
        match value {
            Value::String(s) => out.push(s.clone()),
            Value::Array(items) => items.iter().for_each(|v| strings(v, out)),
            _ => {}
        }
    }
    let value = get(config, key)?;
    let value = match &value {
        Value::Object(modes) => modes.get(mode_name(mode)).unwrap_or(&Value::Null),
        other => other,
    };
    let mut out = Vec::new();
    strings(value, &mut out);
    Ok(out)
}

/// Whether an endpoint as Zenoh takes it (metadata and options after `?` or `#`) is on
/// loopback; one that is not a TCP endpoint snakectl can read is taken as not.
fn loopback_endpoint(text: &str) -> bool {
    let address = text.split(['?', '#']).next().unwrap_or(text);
    Endpoint::parse(address).is_ok_and(|e| e.is_loopback())
}

/// Whether `config` sets up Zenoh's access control so that only what its rules allow gets
/// through: enabled, with `default_permission` "deny". (Zenoh's user/password and public-key
/// authentication are not built into snakectl, so they do not count.)
fn access_controlled(config: &zenoh::Config) -> Result<bool, NetError> {
    Ok(get(config, "access_control/enabled")? == Value::Bool(true)
        && get(config, "access_control/default_permission")? == "deny")
}

/// Refuses to take commands from Zenoh when the session `config` (as it will be opened, the
/// file merged) lets other hosts reach it, or when a `[server] token_file` is set, unless
/// Zenoh's access control guards the session.
fn check_commands(
    table: &Zenoh,
    config: &zenoh::Config,
    token_file: Option<&std::path::Path>,
) -> Result<(), NetError> {
    if !table.accept_commands || access_controlled(config)? {
        return Ok(());
    }
    if let Some(token_file) = token_file {
        return Err(NetError::TokenNotAsked {
            token_file: token_file.to_path_buf(),
        });
    }
    if get(config, "scouting/multicast/enabled")? == Value::Bool(true) {
        return Err(NetError::CommandsExposed {
            exposure: "multicast scouting is on".to_owned(),
        });
    }
    for key in ["listen/endpoints", "connect/endpoints"] {
        if let Some(open) = endpoints_in_effect(config, key, table.mode)?
            .into_iter()
            .find(|e| !loopback_endpoint(e))
        {
            return Err(NetError::CommandsExposed {
                exposure: format!("the session's {key} has {open:?}, which is not loopback"),
            });
        }
    }
    Ok(())
}

/// Warns, when commands are taken, that they may come through a session the daemon connects
/// to: the daemon cannot see how exposed that router or peer is (rmw_zenohd listens on every
/// interface by default), nor the peers it tells of.
fn warn_routed(table: &Zenoh, config: &zenoh::Config) -> Result<(), NetError> {
    if !table.accept_commands {
        return Ok(());
    }
    let connect = endpoints_in_effect(config, "connect/endpoints", table.mode)?;
    if table.mode == ZenohMode::Client || !connect.is_empty() {
        warn!(
            mode = mode_name(table.mode),
            connect = ?connect,
            "accept_commands through a Zenoh session the daemon connects to: the arm takes \
             commands from anything that reaches that router or peer, on every interface it \
             listens on (rmw_zenohd's default is tcp/[::]:7447); keep the router on loopback \
             or behind Zenoh's access control (docs/ROS2.md)"
        );
    }
    Ok(())
}

/// Zenoh's name of `mode`.
fn mode_name(mode: ZenohMode) -> &'static str {
    match mode {
        ZenohMode::Peer => "peer",
        ZenohMode::Client => "client",
    }
}

fn set(config: &mut zenoh::Config, key: &'static str, value: &Value) -> Result<(), NetError> {
    config
        .insert_json5(key, &value.to_string())
        .map_err(|e| NetError::Setting {
            key,
            message: e.to_string(),
        })
}

/// Nanoseconds since the Unix epoch now, for rmw_zenoh's attachment.
fn wall_clock_ns() -> i64 {
    match SystemTime::now().duration_since(UNIX_EPOCH) {
        Ok(d) => i64::try_from(d.as_nanos()).unwrap_or(i64::MAX),
        Err(e) => i64::try_from(e.duration().as_nanos()).map_or(i64::MIN, |ns| -ns),
    }
}

/// Seconds since the Unix epoch now: ROS stamps are wall-clock time.
fn wall_clock_s() -> f64 {
    match SystemTime::now().duration_since(UNIX_EPOCH) {
        Ok(d) => d.as_secs_f64(),
        Err(e) => -e.duration().as_secs_f64(),
    }
}

/// What the bridge needs of the config, taken before the loop's thread owns it.
#[derive(Debug, Clone)]
struct Settings {
    prefix: String,
    publish_period: Duration,
    accept_commands: bool,
    deadman: Duration,
    /// The ROS 2 domain, when the daemon is a ROS 2 node too.
    ros2: Option<u32>,
}

impl Settings {
    fn key(&self, name: &str) -> String {
        format!("{}/{name}", self.prefix)
    }
}

/// The daemon's Zenoh session, on its own thread: opened by [`Bridge::open`] before anything
/// moves, serving once [`Bridge::start`] hands it the way in, closed by [`Bridge::stop`].
#[derive(Debug)]
pub struct Bridge {
    side: Side,
}

impl Bridge {
    /// Opens the session `config`'s `[zenoh]` table describes; returns once it is open, or
    /// with why it could not be.
    pub async fn open(config: &Config) -> Result<Bridge, NetError> {
        let table = config.zenoh();
        let zenoh_config = session_config(table, true)?;
        check_commands(table, &zenoh_config, config.server().token_file.as_deref())?;
        warn_routed(table, &zenoh_config)?;
        let settings = Settings {
            prefix: table.prefix.clone(),
            publish_period: Duration::try_from_secs_f64(1.0 / table.publish_hz)
                .unwrap_or(Duration::from_secs(1))
                .max(Duration::from_micros(100)),
            accept_commands: table.accept_commands,
            deadman: config.control().deadman,
            ros2: table.ros2.then_some(table.domain_id),
        };
        let body = move |ends: SideEnds<(), NetError>| {
            bridge_thread(zenoh_config, settings, ends.opened, ends.start, ends.stop);
        };
        let (side, ()) = Side::open("snakectl-zenoh", body, NetError::Thread).await?;
        Ok(Bridge { side })
    }

    /// Starts publishing, answering and (with `accept_commands`) commanding through `door`.
    pub fn start(&mut self, door: Door) {
        self.side.start(door);
    }

    /// Withdraws the token, closes the session and waits for the thread.
    pub async fn stop(self) {
        self.side.stop().await;
    }
}

fn bridge_thread(
    zenoh_config: zenoh::Config,
    settings: Settings,
    opened: oneshot::Sender<Result<(), NetError>>,
    start: oneshot::Receiver<Door>,
    mut stop: oneshot::Receiver<()>,
) {
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("snakectl-zenoh-rt")
        .enable_all()
        .build()
    {
        Ok(runtime) => runtime,
        Err(e) => {
            let _ = opened.send(Err(NetError::Thread(e.to_string())));
            return;
        }
    };
    runtime.block_on(async move {
        let session = match zenoh::open(zenoh_config).await {
            Ok(session) => session,
            Err(e) => {
                let _ = opened.send(Err(NetError::Open(e.to_string())));
                return;
            }
        };
        if let Err(e) = prefix_free(&session, &settings.prefix).await {
            let _ = opened.send(Err(e));
            if let Err(e) = session.close().await {
                debug!(error = %e, "closing the Zenoh session");
            }
            return;
        }
        let _ = opened.send(Ok(()));
        let door = tokio::select! {
            door = start => door.ok(),
            _ = &mut stop => None,
        };
        if let Some(door) = door {
            match Served::declare(&session, &settings, door).await {
                Ok(served) => served.run(&mut stop).await,
                Err(e) => {
                    warn!(error = %e, "the Zenoh bridge could not start; the socket serves on")
                }
            }
        }
        if let Err(e) = session.close().await {
            debug!(error = %e, "closing the Zenoh session");
        }
    });
}

/// Refuses a prefix whose liveliness token another session holds, seen within
/// [`PREFIX_WAIT`]: two daemons on one prefix would both obey one command stream.
async fn prefix_free(session: &Session, prefix: &str) -> Result<(), NetError> {
    let tokens = session
        .liveliness()
        .declare_subscriber(prefix.to_owned())
        .history(true)
        .with(RingChannel::new(SUBSCRIPTION_RING))
        .await
        .map_err(|e| NetError::Declare {
            key: prefix.to_owned(),
            message: e.to_string(),
        })?;
    let deadline = time::Instant::now() + PREFIX_WAIT;
    while let Ok(Ok(sample)) = time::timeout_at(deadline, tokens.recv_async()).await {
        if sample.kind() == SampleKind::Put {
            return Err(NetError::PrefixTaken {
                prefix: prefix.to_owned(),
            });
        }
    }
    Ok(())
}

/// The bridge's declarations, while it serves.
struct Served<'a> {
    session: &'a Session,
    settings: &'a Settings,
    door: Door,
    joint_states: zenoh::pubsub::Publisher<'static>,
    tip: zenoh::pubsub::Publisher<'static>,
    target: zenoh::pubsub::Publisher<'static>,
    telemetry: zenoh::pubsub::Publisher<'static>,
    events_key: String,
    status: Queryable,
    describe: Queryable,
    cmd_vel: Option<Subscriber>,
    goal: Option<Subscriber>,
    reach: Option<Subscriber>,
    _token: zenoh::liveliness::LivelinessToken,
    frame_id: String,
    /// The ROS 2 node's side, with `ros2`.
    ros: Option<RosNode>,
}

/// What the bridge takes from the network in one turn.
enum Work {
    /// A command sample, read (or why it cannot be one).
    Command(Result<Cmd, Rejection>),
    /// A `status` query.
    Status(zenoh::query::Query),
    /// A `describe` query.
    Describe(zenoh::query::Query),
}

/// A subscriber whose samples wait in a ring: the newest are kept.
type Subscriber = zenoh::pubsub::Subscriber<RingChannelHandler<Sample>>;

/// The frame of the points on the ROS 2 topics: the config's own frame, which the URDF
/// (`snakectl urdf`) names `base`.
const ROS_FRAME: &str = "base";

/// A publisher on an rmw_zenoh data key: its graph token, its GID and its count of samples.
struct RosPublisher {
    publisher: zenoh::pubsub::Publisher<'static>,
    gid: [u8; 16],
    sequence: Cell<i64>,
    _token: zenoh::liveliness::LivelinessToken,
}

/// The ROS 2 node: its token, publishers and (with `accept_commands`) subscriptions.
struct RosNode {
    _token: zenoh::liveliness::LivelinessToken,
    joint_states: RosPublisher,
    tip_cmd: RosPublisher,
    tip_meas: RosPublisher,
    target: RosPublisher,
    cmd_vel: Option<Subscriber>,
    goal: Option<Subscriber>,
    reach: Option<Subscriber>,
    _subscription_tokens: Vec<zenoh::liveliness::LivelinessToken>,
}

impl RosNode {
    /// Declares node `snakectl` in `/<prefix>` of `domain`, with ids 0 (the node), 1-4 (the
    /// publishers) and 5-7 (the subscriptions).
    async fn declare(
        session: &Session,
        settings: &Settings,
        domain: u32,
    ) -> Result<RosNode, NetError> {
        let node = rmw::Node::snakectl(domain, &session.zid().to_string(), &settings.prefix);
        let topic = |name: &str| rmw::topic_name(&settings.prefix, name);
        let node_token = live_token(session, node.token()).await?;
        let names = ["joint_states", "tip_cmd", "tip_meas", "target"].map(topic);
        let joint_states = ros_publisher::<ros::JointState>(session, &node, 1, &names[0]).await?;
        let tip_cmd = ros_publisher::<ros::PointStamped>(session, &node, 2, &names[1]).await?;
        let tip_meas = ros_publisher::<ros::PointStamped>(session, &node, 3, &names[2]).await?;
        let target = ros_publisher::<ros::PointStamped>(session, &node, 4, &names[3]).await?;
        let mut subscription_tokens = Vec::new();
        let (cmd_vel, goal, reach) = if settings.accept_commands {
            let subscription = rmw::EntityKind::Subscription;
            let qos = &rmw::Qos::DEFAULT;
            let cmd_vel = topic("cmd_vel");
            let cmd_vel_token = node.entity_token::<ros::Twist>(5, subscription, &cmd_vel, qos);
            let cmd_vel = subscribe(session, rmw::data_key::<ros::Twist>(domain, &cmd_vel)).await?;
            subscription_tokens.push(live_token(session, cmd_vel_token).await?);
            let mut points = Vec::with_capacity(2);
            for (id, name) in [(6, "goal"), (7, "reach")] {
                let name = topic(name);
                let token = node.entity_token::<ros::PointStamped>(id, subscription, &name, qos);
                let key = rmw::data_key::<ros::PointStamped>(domain, &name);
                points.push(subscribe(session, key).await?);
                subscription_tokens.push(live_token(session, token).await?);
            }
            let mut points = points.into_iter();
            (Some(cmd_vel), points.next(), points.next())
        } else {
            (None, None, None)
        };
        Ok(RosNode {
            _token: node_token,
            joint_states,
            tip_cmd,
            tip_meas,
            target,
            cmd_vel,
            goal,
            reach,
            _subscription_tokens: subscription_tokens,
        })
    }
}

/// A liveliness token on `key`.
async fn live_token(
    session: &Session,
    key: String,
) -> Result<zenoh::liveliness::LivelinessToken, NetError> {
    session
        .liveliness()
        .declare_token(key.clone())
        .await
        .map_err(|e| NetError::Declare {
            key,
            message: e.to_string(),
        })
}

/// Publisher `id` of `node` on the full topic name `topic`, of type `T`, with its token.
async fn ros_publisher<T: rmw::Typed>(
    session: &Session,
    node: &rmw::Node,
    id: u64,
    topic: &str,
) -> Result<RosPublisher, NetError> {
    let key = rmw::data_key::<T>(node.domain, topic);
    let token = node.entity_token::<T>(id, rmw::EntityKind::Publisher, topic, &rmw::Qos::DEFAULT);
    let publisher = session
        .declare_publisher(key.clone())
        .encoding(Encoding::APPLICATION_CDR)
        // A congested link drops a sample rather than hold the bridge up.
        .congestion_control(CongestionControl::Drop)
        .await
        .map_err(|e| NetError::Declare {
            key,
            message: e.to_string(),
        })?;
    Ok(RosPublisher {
        publisher,
        gid: rmw::gid(&token),
        sequence: Cell::new(0),
        _token: live_token(session, token).await?,
    })
}

/// A subscriber on `key` whose samples wait in a ring of [`COMMAND_RING`].
async fn subscribe(session: &Session, key: String) -> Result<Subscriber, NetError> {
    session
        .declare_subscriber(key.clone())
        .with(RingChannel::new(COMMAND_RING))
        .await
        .map_err(|e| NetError::Declare {
            key,
            message: e.to_string(),
        })
}

impl<'a> Served<'a> {
    async fn declare(
        session: &'a Session,
        settings: &'a Settings,
        door: Door,
    ) -> Result<Served<'a>, NetError> {
        let declare_err = |key: &str| {
            let key = key.to_owned();
            move |e: zenoh::Error| NetError::Declare {
                key,
                message: e.to_string(),
            }
        };
        let publisher = |name: &'static str, encoding: Encoding| {
            let key = settings.key(name);
            async move {
                session
                    .declare_publisher(key.clone())
                    .encoding(encoding)
                    // A congested link drops a sample rather than hold the bridge up.
                    .congestion_control(CongestionControl::Drop)
                    .await
                    .map_err(declare_err(&key))
            }
        };
        let queryable = |name: &'static str| {
            let key = settings.key(name);
            async move {
                session
                    .declare_queryable(key.clone())
                    .with(zenoh::handlers::FifoChannel::new(QUERY_QUEUE))
                    .await
                    .map_err(declare_err(&key))
            }
        };
        let subscriber = |name: &'static str| subscribe(session, settings.key(name));
        let joint_states = publisher("joint_states", Encoding::APPLICATION_CDR).await?;
        let tip = publisher("tip", Encoding::APPLICATION_CDR).await?;
        let target = publisher("target", Encoding::APPLICATION_CDR).await?;
        let telemetry = publisher("telemetry", Encoding::APPLICATION_JSON).await?;
        let status = queryable("status").await?;
        let describe = queryable("describe").await?;
        let (cmd_vel, goal, reach) = if settings.accept_commands {
            (
                Some(subscriber("cmd_vel").await?),
                Some(subscriber("goal").await?),
                Some(subscriber("reach").await?),
            )
        } else {
            (None, None, None)
        };
        let token = session
            .liveliness()
            .declare_token(settings.prefix.clone())
            .await
            .map_err(declare_err(&settings.prefix))?;
        let ros = match settings.ros2 {
            Some(domain) => Some(RosNode::declare(session, settings, domain).await?),
            None => None,
        };
        info!(
            prefix = %settings.prefix,
            controller = door.id(),
            accept_commands = settings.accept_commands,
            ros2_domain = settings.ros2,
            "on the Zenoh network"
        );
        Ok(Served {
            session,
            settings,
            door,
            joint_states,
            tip,
            target,
            telemetry,
            events_key: settings.key("events"),
            status,
            describe,
            cmd_vel,
            goal,
            reach,
            _token: token,
            frame_id: format!("{}/world", settings.prefix),
            ros,
        })
    }

    /// Serves until `stop`: publishing first (a tick's end is never missed, however busy the
    /// rest), then the loop's events, the deadman and refusals, then one command sample or
    /// query per turn.
    async fn run(self, stop: &mut oneshot::Receiver<()>) {
        let mut ticker = time::interval(self.settings.publish_period);
        ticker.set_missed_tick_behavior(MissedTickBehavior::Skip);
        let mut telemetry = self.door.telemetry();
        let tick_done = self.door.tick_done();
        let mut events = self.door.events();
        let mut events_open = true;
        // When the last network command was taken, while this door may hold control.
        let mut last_command: Option<time::Instant> = None;
        let mut refusals = Refusals::new(time::Instant::now());
        let (answers_tx, mut answers) = tokio::sync::mpsc::channel::<Rejection>(QUERY_QUEUE);
        // A publication is due: it goes out when the loop's next tick ends, in the idle rest
        // of the loop's period, so that encoding and sending it never overlap a tick's work.
        // The wait is registered as soon as it is due, so that a tick that ends while the
        // bridge is busy elsewhere still wakes it.
        let mut tick_end: Option<Pin<Box<Notified<'_>>>> = None;
        loop {
            let silence = last_command.map(|t| t + self.settings.deadman);
            tokio::select! {
                biased;
                _ = &mut *stop => break,
                () = ended(&mut tick_end) => {
                    tick_end = None;
                    if telemetry.has_changed().unwrap_or(false) {
                        // Cloned, then the snapshot is let go: encoding never holds the loop.
                        let t = telemetry.borrow_and_update().clone();
                        self.publish(&t).await;
                    }
                }
                _ = ticker.tick() => {
                    if tick_end.is_none() {
                        let mut wait = Box::pin(tick_done.notified());
                        wait.as_mut().enable();
                        tick_end = Some(wait);
                    }
                }
                event = events.recv(), if events_open => match event {
                    Ok(event) => {
                        if event.owner.is_none_or(|owner| owner == self.door.id()) {
                            self.put_event(protocol::event_line(&event)).await;
                        }
                    }
                    Err(broadcast::error::RecvError::Lagged(missed)) => {
                        debug!(missed, "the Zenoh bridge fell behind the events");
                    }
                    Err(broadcast::error::RecvError::Closed) => events_open = false,
                },
                () = sleep_until(silence), if silence.is_some() => {
                    last_command = None;
                    if self.door.release() {
                        info!(
                            deadman_ms = self.settings.deadman.as_millis() as u64,
                            "no Zenoh command for the deadman: control released"
                        );
                    }
                }
                () = sleep_until(refusals.due()) => {
                    if let Some(why) = refusals.flush(time::Instant::now()) {
                        self.put_event(protocol::error_line(None, &why)).await;
                    }
                }
                Some(why) = answers.recv() => self.refused(why, &mut refusals).await,
                work = self.next_work() => match work {
                    Work::Command(cmd) => {
                        if self.command(cmd, &answers_tx, &mut refusals).await {
                            last_command = Some(time::Instant::now());
                        }
                    }
                    Work::Status(query) => {
                        let t = telemetry.borrow().clone();
                        self.answer(&query, "status", self.door.status_line(&t)).await;
                    }
                    Work::Describe(query) => {
                        self.answer(&query, "describe", self.door.describe_line()).await;
                    }
                },
            }
        }
    }

    /// The next command sample (read) or query, whichever comes first: one per turn, taken
    /// fairly among them, so that a flood of one kind does not starve the others.
    async fn next_work(&self) -> Work {
        let ros = self.ros.as_ref();
        tokio::select! {
            sample = recv(self.cmd_vel.as_ref()) => Work::Command(velocity(&sample)),
            sample = recv(self.goal.as_ref()) => Work::Command(goto(&sample)),
            sample = recv(self.reach.as_ref()) => Work::Command(reach(&sample)),
            sample = recv(ros.and_then(|r| r.cmd_vel.as_ref())) => Work::Command(
                from_ros(&sample, &self.settings.key("cmd_vel")).and_then(|()| velocity(&sample)),
            ),
            sample = recv(ros.and_then(|r| r.goal.as_ref())) => Work::Command(
                from_ros(&sample, &self.settings.key("goal")).and_then(|()| goto(&sample)),
            ),
            sample = recv(ros.and_then(|r| r.reach.as_ref())) => Work::Command(
                from_ros(&sample, &self.settings.key("reach")).and_then(|()| reach(&sample)),
            ),
            query = next_query(&self.status) => Work::Status(query),
            query = next_query(&self.describe) => Work::Describe(query),
        }
    }

    /// Publishes one snapshot on every key.
    async fn publish(&self, t: &Telemetry) {
        let stamp = wall_clock_s();
        let cdr = |result: Result<Vec<u8>, ros::RosError>| match result {
            Ok(bytes) => Some(bytes),
            Err(e) => {
                warn!(error = %e, "a ROS message could not be encoded");
                None
            }
        };
        if let Some(bytes) = cdr(ros::encode(&ros::joint_state(t, stamp))) {
            self.put(&self.joint_states, bytes).await;
        }
        let tip = ros::point_stamped(t.tip_meas, stamp, &self.frame_id);
        if let Some(bytes) = cdr(ros::encode(&tip)) {
            self.put(&self.tip, bytes).await;
        }
        if let Some(target) = t.target {
            let target = ros::point_stamped(target, stamp, &self.frame_id);
            if let Some(bytes) = cdr(ros::encode(&target)) {
                self.put(&self.target, bytes).await;
            }
        }
        let line = self.door.telemetry_line(t);
        self.put(&self.telemetry, line.trim_end().as_bytes().to_vec())
            .await;
        if let Some(node) = &self.ros {
            if let Some(bytes) = cdr(ros::encode(&ros::joint_state(t, stamp))) {
                self.put_ros(&node.joint_states, bytes).await;
            }
            for (publisher, point) in [
                (&node.tip_cmd, Some(t.tip)),
                (&node.tip_meas, Some(t.tip_meas)),
                (&node.target, t.target),
            ] {
                let Some(point) = point else { continue };
                if let Some(bytes) = cdr(ros::encode(&ros::point_stamped(point, stamp, ROS_FRAME)))
                {
                    self.put_ros(publisher, bytes).await;
                }
            }
        }
    }

    /// Puts `bytes` on an rmw_zenoh key with the attachment: the publisher's next sequence
    /// number, now, its GID.
    async fn put_ros(&self, publisher: &RosPublisher, bytes: Vec<u8>) {
        let sequence = publisher.sequence.get().saturating_add(1);
        publisher.sequence.set(sequence);
        let attachment = rmw::Attachment {
            sequence,
            source_timestamp_ns: wall_clock_ns(),
            gid: publisher.gid,
        };
        let sent = publisher
            .publisher
            .put(bytes)
            .attachment(attachment.encode().to_vec())
            .await;
        if let Err(e) = sent {
            debug!(key = %publisher.publisher.key_expr(), error = %e, "a Zenoh put failed");
        }
    }

    async fn put(&self, publisher: &zenoh::pubsub::Publisher<'static>, bytes: Vec<u8>) {
        if let Err(e) = publisher.put(bytes).await {
            debug!(key = %publisher.key_expr(), error = %e, "a Zenoh put failed");
        }
    }

    async fn put_event(&self, line: String) {
        let sent = self
            .session
            .put(&self.events_key, line.trim_end().to_owned())
            .encoding(Encoding::APPLICATION_JSON)
            .congestion_control(CongestionControl::Drop)
            .await;
        if let Err(e) = sent {
            debug!(key = %self.events_key, error = %e, "a Zenoh put failed");
        }
    }

    async fn answer(&self, query: &zenoh::query::Query, name: &str, line: String) {
        let key = self.settings.key(name);
        let sent = query
            .reply(key.clone(), line.trim_end().to_owned())
            .encoding(Encoding::APPLICATION_JSON)
            .await;
        if let Err(e) = sent {
            debug!(%key, error = %e, "a Zenoh reply failed");
        }
    }

    /// Puts a network command through the door; whether it was taken (admitted and queued).
    /// The loop's refusal, if any, arrives later through `answers`.
    async fn command(
        &self,
        cmd: Result<Cmd, Rejection>,
        answers: &tokio::sync::mpsc::Sender<Rejection>,
        refusals: &mut Refusals,
    ) -> bool {
        let sent = cmd.and_then(|cmd| self.door.send(cmd));
        match sent {
            Ok(answer) => {
                let answers = answers.clone();
                tokio::spawn(async move {
                    if let Ok(Err(why)) = answer.await {
                        // Full: the refusal is dropped, the next one will be told.
                        let _ = answers.try_send(why);
                    }
                });
                true
            }
            Err(why) => {
                self.refused(why, refusals).await;
                false
            }
        }
    }

    /// Tells the network why a command was refused, on `<prefix>/events` (at most one per
    /// [`REFUSAL_EVENT_GAP`], the rest folded in), and the log once per run of the same refusal
    /// (again after [`REFUSAL_LOG_GAP`]).
    async fn refused(&self, why: Rejection, refusals: &mut Refusals) {
        let now = time::Instant::now();
        if let Some(since) = refusals.log(why.code, now) {
            warn!(
                code = ?why.code,
                reason = %why.message,
                refused_since = since,
                "a Zenoh command was refused"
            );
        }
        if let Some(why) = refusals.event(why, now) {
            self.put_event(protocol::error_line(None, &why)).await;
        }
    }
}

/// Refusals of network commands, told without flooding the log or the network: a stream of
/// garbage is one log line and at most one event per [`REFUSAL_EVENT_GAP`].
struct Refusals {
    /// The refusal the log told last, and when.
    logged: Option<(Code, time::Instant)>,
    /// Refusals since the log told one.
    unlogged: u64,
    /// When the next refusal may be published.
    next_event: time::Instant,
    /// The latest refusal held back, and how many refusals it stands for.
    held: Option<(Rejection, u64)>,
}

impl Refusals {
    fn new(now: time::Instant) -> Refusals {
        Refusals {
            logged: None,
            unlogged: 0,
            next_event: now,
            held: None,
        }
    }

    /// Whether a refusal with `code` is to be logged at `now` (another refusal than the last
    /// told, or the same after [`REFUSAL_LOG_GAP`]): then how many went unlogged before it.
    fn log(&mut self, code: Code, now: time::Instant) -> Option<u64> {
        let tell = match self.logged {
            Some((last, at)) => last != code || now >= at + REFUSAL_LOG_GAP,
            None => true,
        };
        if tell {
            self.logged = Some((code, now));
            Some(std::mem::take(&mut self.unlogged))
        } else {
            self.unlogged = self.unlogged.saturating_add(1);
            None
        }
    }

    /// The refusal to publish at `now`: `why`, with those held back folded in, when none was
    /// published within [`REFUSAL_EVENT_GAP`]; otherwise `why` is held back.
    fn event(&mut self, why: Rejection, now: time::Instant) -> Option<Rejection> {
        let count = self.held.take().map_or(0, |(_, n)| n).saturating_add(1);
        if now >= self.next_event {
            self.next_event = now + REFUSAL_EVENT_GAP;
            Some(folded(why, count))
        } else {
            self.held = Some((why, count));
            None
        }
    }

    /// When the refusal held back is to be published; `None` without one.
    fn due(&self) -> Option<time::Instant> {
        self.held.as_ref().map(|_| self.next_event)
    }

    /// The refusal held back, with its count, once it is due at `now`.
    fn flush(&mut self, now: time::Instant) -> Option<Rejection> {
        if now < self.next_event {
            return None;
        }
        let (why, count) = self.held.take()?;
        self.next_event = now + REFUSAL_EVENT_GAP;
        Some(folded(why, count))
    }
}

/// `why`, the last of `count` refusals: the count said in its message when more than one.
fn folded(why: Rejection, count: u64) -> Rejection {
    match count {
        0 | 1 => why,
        _ => Rejection::new(
            why.code,
            format!(
                "{} (the last of {count} refusals: at most one is told per {} ms)",
                why.message,
                REFUSAL_EVENT_GAP.as_millis()
            ),
        ),
    }
}

/// The next sample of `subscriber`; never, without one.
async fn recv(subscriber: Option<&Subscriber>) -> Sample {
    match subscriber {
        Some(subscriber) => match subscriber.recv_async().await {
            Ok(sample) => sample,
            Err(_) => std::future::pending().await,
        },
        None => std::future::pending().await,
    }
}

/// The next query of `queryable`; never, once it is closed.
async fn next_query(queryable: &Queryable) -> zenoh::query::Query {
    match queryable.recv_async().await {
        Ok(query) => query,
        Err(_) => std::future::pending().await,
    }
}

/// The end of the tick `wait` waits for; never, without one.
async fn ended(wait: &mut Option<Pin<Box<Notified<'_>>>>) {
    match wait {
        Some(wait) => wait.as_mut().await,
        None => std::future::pending().await,
    }
}

async fn sleep_until(deadline: Option<time::Instant>) {
    match deadline {
        Some(deadline) => time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

fn bad(what: &str, e: impl std::fmt::Display) -> Rejection {
    Rejection::new(Code::BadArg, format!("{what}: {e}"))
}

/// Whether a sample on an rmw_zenoh key carries rmw_zenoh's attachment, as every ROS 2
/// publisher's does; `plain_key` is where a sample without one belongs.
fn from_ros(sample: &Sample, plain_key: &str) -> Result<(), Rejection> {
    let bytes = sample
        .attachment()
        .map(|a| a.to_bytes().into_owned())
        .unwrap_or_default();
    rmw::Attachment::decode(&bytes).map(|_| ()).map_err(|e| {
        bad(
            &format!(
                "a sample on the ROS 2 key {} without rmw_zenoh's attachment (ROS 2 drops \
                 it; put plain samples on {plain_key})",
                sample.key_expr()
            ),
            e,
        )
    })
}

/// A `cmd_vel` sample as `velocity`: `linear.x`, `linear.y`, m/s; the rest is ignored.
fn velocity(sample: &Sample) -> Result<Cmd, Rejection> {
    let twist: ros::Twist = ros::decode(&sample.payload().to_bytes())
        .map_err(|e| bad("cmd_vel is not a geometry_msgs/msg/Twist in CDR", e))?;
    let v = protocol::checked_point("v", [twist.linear.x, twist.linear.y])?;
    Ok(Cmd::Velocity { v })
}

/// A `goal` sample as `goto` at the default speed: `point.x`, `point.y`, m.
fn goto(sample: &Sample) -> Result<Cmd, Rejection> {
    let target = point_of(sample, "goal")?;
    Ok(Cmd::Goto {
        target,
        speed: None,
    })
}

/// A `reach` sample as `reach`: `point.x`, `point.y`, m.
fn reach(sample: &Sample) -> Result<Cmd, Rejection> {
    let target = point_of(sample, "reach")?;
    Ok(Cmd::Reach { target })
}

/// The target a `PointStamped` sample on `topic` carries: `point.x`, `point.y`, m.
fn point_of(sample: &Sample, topic: &str) -> Result<[f64; 2], Rejection> {
    let point: ros::PointStamped = ros::decode(&sample.payload().to_bytes()).map_err(|e| {
        bad(
            &format!("{topic} is not a geometry_msgs/msg/PointStamped in CDR"),
            e,
        )
    })?;
    protocol::checked_point("target", [point.point.x, point.point.y])
}

/// A blocking Zenoh session for tools and tests: peer mode, the given endpoints, multicast
/// scouting off unless a `[zenoh]` table says otherwise. Not for use inside an async runtime.
pub struct Peer {
    session: Session,
}

/// One sample a [`Subscription`] received.
#[derive(Debug, Clone, PartialEq)]
pub struct Received {
    /// The key it was put on.
    pub key: String,
    /// Its payload.
    pub payload: Vec<u8>,
    /// Its attachment, if it had one.
    pub attachment: Option<Vec<u8>>,
}

impl Received {
    fn from_sample(sample: &Sample) -> Received {
        Received {
            key: sample.key_expr().to_string(),
            payload: sample.payload().to_bytes().into_owned(),
            attachment: sample.attachment().map(|a| a.to_bytes().into_owned()),
        }
    }
}

/// A subscription of a [`Peer`]: the newest [`SUBSCRIPTION_RING`] samples are kept.
pub struct Subscription {
    inner: zenoh::pubsub::Subscriber<RingChannelHandler<Sample>>,
}

impl Subscription {
    /// The next sample, waiting up to `timeout`.
    pub fn recv_timeout(&self, timeout: Duration) -> Option<Received> {
        match self.inner.recv_timeout(timeout) {
            Ok(Some(sample)) if sample.kind() == SampleKind::Put => {
                Some(Received::from_sample(&sample))
            }
            _ => None,
        }
    }
}

impl Peer {
    /// A peer that connects to `connect` and listens on `listen` (none: it listens nowhere).
    pub fn open(connect: &[Endpoint], listen: &[Endpoint]) -> Result<Peer, NetError> {
        Peer::with_table(&Zenoh::peer(connect.to_vec(), listen.to_vec()))
    }

    /// A session as `table` describes (its mode, endpoints, multicast and `config_file`; the
    /// table's endpoint lists replace the file's, even when empty).
    pub fn with_table(table: &Zenoh) -> Result<Peer, NetError> {
        let config = session_config(table, false)?;
        let session = zenoh::open(config)
            .wait()
            .map_err(|e| NetError::Open(e.to_string()))?;
        Ok(Peer { session })
    }

    /// Subscribes to `key` (wildcards allowed).
    pub fn subscribe(&self, key: &str) -> Result<Subscription, NetError> {
        let inner = self
            .session
            .declare_subscriber(key.to_owned())
            .with(RingChannel::new(SUBSCRIPTION_RING))
            .wait()
            .map_err(|e| NetError::Declare {
                key: key.to_owned(),
                message: e.to_string(),
            })?;
        Ok(Subscription { inner })
    }

    /// Puts `payload` on `key`.
    pub fn put(&self, key: &str, payload: Vec<u8>) -> Result<(), NetError> {
        self.session
            .put(key.to_owned(), payload)
            .wait()
            .map_err(|e| NetError::Io {
                key: key.to_owned(),
                message: e.to_string(),
            })
    }

    /// Puts `payload` on `key` with `attachment` (as a ROS 2 publisher on rmw_zenoh does).
    pub fn put_attached(
        &self,
        key: &str,
        payload: Vec<u8>,
        attachment: Vec<u8>,
    ) -> Result<(), NetError> {
        self.session
            .put(key.to_owned(), payload)
            .attachment(attachment)
            .wait()
            .map_err(|e| NetError::Io {
                key: key.to_owned(),
                message: e.to_string(),
            })
    }

    /// Asks `selector` and gathers the answers that arrive within `timeout`.
    pub fn get(&self, selector: &str, timeout: Duration) -> Result<Vec<Received>, NetError> {
        let replies = self
            .session
            .get(selector.to_owned())
            .timeout(timeout)
            .wait()
            .map_err(|e| NetError::Io {
                key: selector.to_owned(),
                message: e.to_string(),
            })?;
        let deadline = Instant::now() + timeout;
        let mut out = Vec::new();
        while let Ok(Some(reply)) = replies.recv_deadline(deadline) {
            if let Ok(sample) = reply.result() {
                out.push(Received::from_sample(sample));
            }
        }
        Ok(out)
    }

    /// The liveliness tokens matching `key` seen within `wait` (those alive when it starts, and
    /// those that come up meanwhile), sorted, each once.
    pub fn alive(&self, key: &str, wait: Duration) -> Result<Vec<String>, NetError> {
        let tokens = self
            .session
            .liveliness()
            .declare_subscriber(key.to_owned())
            .history(true)
            .with(RingChannel::new(SUBSCRIPTION_RING))
            .wait()
            .map_err(|e| NetError::Declare {
                key: key.to_owned(),
                message: e.to_string(),
            })?;
        let deadline = Instant::now() + wait;
        let mut seen = std::collections::BTreeSet::new();
        while let Ok(Some(sample)) = tokens.recv_deadline(deadline) {
            let key = sample.key_expr().to_string();
            match sample.kind() {
                SampleKind::Put => seen.insert(key),
                SampleKind::Delete => seen.remove(&key),
            };
        }
        Ok(seen.into_iter().collect())
    }
}

/// An arm a [`Peer`] found: its prefix, and its `status` reply (`None` when it did not answer
/// in time).
#[derive(Debug, Clone, PartialEq)]
pub struct ArmSeen {
    /// The arm's prefix (its liveliness token).
    pub prefix: String,
    /// Its `status` reply's fields, every one as it came.
    pub status: Option<serde_json::Map<String, Value>>,
}

impl ArmSeen {
    /// Its `status` reply, read.
    pub fn read_status(&self) -> Option<Status> {
        let fields = Fields::read(CmdName::Status, self.status.clone()?).ok()?;
        match fields.reply {
            Reply::Status(status) => Some(*status),
            _ => None,
        }
    }
}

/// The fields of `payload` when it is a snakectl `status` reply (ok, with a status's fields).
fn status_reply(payload: &[u8]) -> Option<serde_json::Map<String, Value>> {
    let text = std::str::from_utf8(payload).ok()?;
    let ServerLine::Reply(ReplyLine {
        result: Ok(fields), ..
    }) = protocol::read_line(text).ok()?
    else {
        return None;
    };
    Fields::read(CmdName::Status, fields.clone()).ok()?;
    Some(fields)
}

/// The arms `peer` sees, sorted by prefix: liveliness tokens seen within `wait`, each asked
/// for `<prefix>/status`. Tokens under Zenoh's `@` namespaces (ROS 2's own among them) are not
/// arms, nor is a token whose status answers are not a snakectl `status` reply; one that does
/// not answer within `wait` is listed without a status.
pub fn fleet(peer: &Peer, wait: Duration) -> Result<Vec<ArmSeen>, NetError> {
    let mut arms = Vec::new();
    for prefix in peer.alive("**", wait)? {
        if prefix.starts_with('@') {
            continue;
        }
        let replies = peer.get(&format!("{prefix}/status"), wait)?;
        let status = replies.iter().find_map(|r| status_reply(&r.payload));
        if status.is_some() || replies.is_empty() {
            arms.push(ArmSeen { prefix, status });
        }
    }
    Ok(arms)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;

    /// A table that accepts commands, listening on `listen`, with `file` as its
    /// `config_file` (written to a temporary directory, kept alive by the returned guard).
    fn table(listen: &[&str], file: Option<&str>) -> (Zenoh, Option<tempfile::TempDir>) {
        let listen = listen.iter().map(|e| Endpoint::parse(e).unwrap()).collect();
        let mut table = Zenoh::peer(Vec::new(), listen);
        table.accept_commands = true;
        let dir = file.map(|text| {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("zenoh.json5");
            std::fs::write(&path, text).unwrap();
            table.config_file = Some(path);
            dir
        });
        (table, dir)
    }

    fn checked(table: &Zenoh, token_file: Option<&str>) -> Result<(), NetError> {
        let config = session_config(table, true).unwrap();
        check_commands(table, &config, token_file.map(std::path::Path::new))
    }

    const DENY: &str = r#"{ access_control: { enabled: true, default_permission: "deny" } }"#;

    #[test]
    fn a_config_file_without_access_control_lifts_nothing() {
        let (t, _dir) = table(
            &[],
            Some(r#"{ listen: { endpoints: ["tcp/0.0.0.0:7447"] } }"#),
        );
        let e = checked(&t, None).unwrap_err();
        assert!(matches!(e, NetError::CommandsExposed { .. }), "{e}");
        assert!(e.to_string().contains("tcp/0.0.0.0:7447"), "{e}");
        // Access control that lets everything through is no guard either.
        let (t, _dir) = table(
            &[],
            Some(
                r#"{ access_control: { enabled: true, default_permission: "allow" },
                     listen: { endpoints: ["tcp/0.0.0.0:7447"] } }"#,
            ),
        );
        assert!(checked(&t, None).is_err());
        let (t, _dir) = table(&["tcp/0.0.0.0:7447"], Some(DENY));
        checked(&t, None).unwrap();
    }

    #[test]
    fn a_config_file_without_endpoints_listens_nowhere() {
        // Zenoh's own default would be tcp/[::]:0, every interface.
        let (t, _dir) = table(&[], Some("{}"));
        let config = session_config(&t, true).unwrap();
        let listen = endpoints_in_effect(&config, "listen/endpoints", ZenohMode::Peer).unwrap();
        assert!(listen.is_empty(), "{listen:?}");
        checked(&t, None).unwrap();
        // Endpoints the file lists are kept, and checked.
        let (t, _dir) = table(
            &[],
            Some(r#"{ listen: { endpoints: { peer: ["tcp/[::]:0"] } } }"#),
        );
        let config = session_config(&t, true).unwrap();
        let listen = endpoints_in_effect(&config, "listen/endpoints", ZenohMode::Peer).unwrap();
        assert_eq!(listen, ["tcp/[::]:0"]);
        assert!(checked(&t, None).is_err());
        let (t, _dir) = table(
            &[],
            Some(
                r#"{ connect: { endpoints: ["tcp/127.0.0.1:7447#iface=lo", "tcp/10.0.0.1:7447"] } }"#,
            ),
        );
        let e = checked(&t, None).unwrap_err();
        assert!(e.to_string().contains("tcp/10.0.0.1:7447"), "{e}");
    }

    #[test]
    fn a_token_file_needs_access_control_for_zenoh_commands() {
        let (t, _dir) = table(&["tcp/127.0.0.1:7447"], None);
        checked(&t, None).unwrap();
        let e = checked(&t, Some("/etc/snakectl/token")).unwrap_err();
        assert!(matches!(e, NetError::TokenNotAsked { .. }), "{e}");
        let message = e.to_string();
        assert!(message.contains("/etc/snakectl/token"), "{message}");
        assert!(message.contains("accept_commands"), "{message}");
        let (t, _dir) = table(&["tcp/127.0.0.1:7447"], Some(DENY));
        checked(&t, Some("/etc/snakectl/token")).unwrap();
        // Watching only: the token is not bypassed.
        let (mut t, _dir) = table(&["tcp/127.0.0.1:7447"], None);
        t.accept_commands = false;
        checked(&t, Some("/etc/snakectl/token")).unwrap();
    }

    #[test]
    fn accepted_commands_between_refusals_do_not_start_a_new_run_in_the_log() {
        let t0 = time::Instant::now();
        let mut refusals = Refusals::new(t0);
        assert_eq!(refusals.log(Code::NotInControl, t0), Some(0));
        // Accepted commands in between change nothing: the same refusal is not told again...
        for i in 1..100 {
            let at = t0 + Duration::from_millis(i);
            assert_eq!(refusals.log(Code::NotInControl, at), None);
        }
        // ...until another one comes, or the gap has passed, with the count since.
        assert_eq!(
            refusals.log(Code::BadArg, t0 + Duration::from_millis(200)),
            Some(99)
        );
        assert_eq!(
            refusals.log(Code::BadArg, t0 + Duration::from_millis(300)),
            None
        );
        let later = t0 + Duration::from_millis(200) + REFUSAL_LOG_GAP;
        assert_eq!(refusals.log(Code::BadArg, later), Some(1));
    }

    #[test]
    fn a_flood_of_refusals_is_one_event_per_gap_with_the_count() {
        let t0 = time::Instant::now();
        let mut refusals = Refusals::new(t0);
        let why = |n: u32| Rejection::new(Code::BadArg, format!("garbage {n}"));
        let first = refusals.event(why(0), t0).unwrap();
        assert_eq!(first.message, "garbage 0");
        // 1000 within the gap: none published, the last held with the count.
        for n in 1..=1000 {
            assert!(refusals
                .event(why(n), t0 + Duration::from_micros(n.into()))
                .is_none());
        }
        assert_eq!(refusals.due(), Some(t0 + REFUSAL_EVENT_GAP));
        assert!(refusals.flush(t0 + REFUSAL_EVENT_GAP / 2).is_none());
        let told = refusals.flush(t0 + REFUSAL_EVENT_GAP).unwrap();
        assert_eq!(told.code, Code::BadArg);
        assert!(
            told.message
                .starts_with("garbage 1000 (the last of 1000 refusals"),
            "{}",
            told.message
        );
        assert_eq!(refusals.due(), None);
        assert!(refusals.flush(t0 + REFUSAL_EVENT_GAP * 3).is_none());
        // After a quiet gap, the next refusal goes out at once, as it is.
        let next = refusals.event(why(7), t0 + REFUSAL_EVENT_GAP * 3).unwrap();
        assert_eq!(next.message, "garbage 7");
    }
}
