//! The file as written: one serde struct per TOML table, before any checking.
//!
//! Every table refuses keys it does not know (`deny_unknown_fields`), so a misspelt key is an
//! error rather than a silently ignored setting. Field names carry their units (`_m`, `_rad`,
//! `_hz`, `_ms`, `_us`, `_s`, `_rad_s`, ...; `contact_load` alone takes the unit of its servo's
//! load reading). Enumerations (bus kind, exit policy, strategy, fault kind) are checked by
//! serde itself; numbers that serde cannot judge (signs, ranges, uniqueness) are checked
//! afterwards by [`super::Config`]. Integers a user may plausibly get wrong (servo ids) are read
//! wide here so that the validated error can quote the bad value.
//!
//! Defaults live in the `default_*` functions below, one place for the table in
//! `docs/CONFIG.md` to cite.

use std::path::PathBuf;

use serde::Deserialize;

/// The whole file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    /// `[arm]`: base pose and home pose; every key has a default, and so has the table.
    #[serde(default)]
    pub arm: RawArm,
    /// `[[joint]]`: one table per joint, base to tip.
    #[serde(default, rename = "joint")]
    pub joints: Vec<RawJoint>,
    /// `[bus]`: how the servos are reached; absent for a geometry-only file.
    #[serde(default)]
    pub bus: Option<RawBus>,
    /// `[sim]`: the simulated servo chain, used when `bus.kind = "sim"`.
    #[serde(default)]
    pub sim: Option<RawSim>,
    /// `[control]`: the control loop; defaults apply when absent.
    #[serde(default)]
    pub control: Option<RawControl>,
    /// `[server]`: the command/telemetry socket; defaults apply when absent.
    #[serde(default)]
    pub server: Option<RawServer>,
    /// `[zenoh]`: the daemon on a Zenoh network; off when absent.
    #[serde(default)]
    pub zenoh: Option<RawZenoh>,
    /// `[foxglove]`: the live view for Foxglove; no server when absent.
    #[serde(default)]
    pub foxglove: Option<RawFoxglove>,
    /// `[world]`: the obstacles the arm keeps clear of, and contact detection; none when
    /// absent.
    #[serde(default)]
    pub world: Option<RawWorld>,
}

/// `[arm]`: where the chain is mounted and where it starts.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawArm {
    /// Base point x, metres.
    #[serde(default)]
    pub base_x_m: f64,
    /// Base point y, metres.
    #[serde(default)]
    pub base_y_m: f64,
    /// Base heading, radians: the direction of link 1 when joint 1 is at 0.
    #[serde(default)]
    pub base_heading_rad: f64,
    /// Start pose, radians, one entry per joint; all zeros when absent.
    #[serde(default)]
    pub home_rad: Option<Vec<f64>>,
}

/// `[[joint]]`: one revolute joint and the link it turns.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawJoint {
    /// Length of the link this joint turns, metres.
    pub link_m: f64,
    /// Lower limit of the relative angle, radians.
    pub min_rad: f64,
    /// Upper limit of the relative angle, radians.
    pub max_rad: f64,
    /// Servo id on the bus (1..=252); read wide so a bad value can be quoted.
    #[serde(default)]
    pub id: Option<i64>,
    /// Servo model name, e.g. `"XL430-W250"`.
    #[serde(default)]
    pub model: Option<String>,
    /// Servo ticks read at 0 rad, added to the nominal centre (2048).
    #[serde(default)]
    pub offset_ticks: i64,
    /// True when a positive angle turns the servo the negative way.
    #[serde(default)]
    pub reverse: bool,
}

/// Which kind of bus carries the servos.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BusKind {
    /// Simulated servos behind a pseudo-terminal, speaking the real protocol.
    Sim,
    /// Real Dynamixel servos on a serial port.
    Dynamixel,
}

/// What the servos do when the daemon exits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnExit {
    /// Switch torque off: the arm goes limp (and may sag).
    TorqueOff,
    /// Keep torque on at the last goal (the bus watchdog still stops motion).
    Hold,
}

/// `[bus]`: the serial bus and the settings written to every servo at bring-up.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawBus {
    /// `"sim"` or `"dynamixel"`.
    pub kind: BusKind,
    /// Serial device; required for `"dynamixel"`; not opened for `"sim"` (it makes its own
    /// pty), with a warning.
    #[serde(default)]
    pub port: Option<String>,
    /// Baud rate, bits/s.
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Return Delay Time written to each servo, microseconds (even, 0..=508).
    #[serde(default)]
    pub return_delay_us: u32,
    /// Profile Velocity written to each servo, rad/s; 0 = no profile (fastest), else 1 to 32767
    /// register units (checked, never clamped).
    #[serde(default)]
    pub profile_velocity_rad_s: f64,
    /// Profile Acceleration written to each servo, rad/s²; 0 = no profile, else 1 to 32767
    /// register units (checked, never clamped).
    #[serde(default)]
    pub profile_acceleration_rad_s2: f64,
    /// What the servos do when the daemon exits.
    #[serde(default = "default_on_exit")]
    pub on_exit: OnExit,
    /// Bus Watchdog: servos stop if the bus is silent this long, milliseconds (multiple of 20,
    /// 20..=2540); 0 disables it; [`default_watchdog_ms`] when absent.
    #[serde(default)]
    pub watchdog_ms: Option<u32>,
    /// How long to wait for one status reply before counting it missing, milliseconds.
    #[serde(default = "default_reply_timeout_ms")]
    pub reply_timeout_ms: u32,
    /// `"auto"` (Fast Sync Read where every servo supports it), `"fast"` or `"sync"`.
    #[serde(default = "default_read")]
    pub read: ReadChoice,
    /// `[[bus.ports]]`: several serial ports, each with its servos; absent, one port
    /// (`port`) carries every joint's servo. Given empty (`ports = []`), refused.
    #[serde(default)]
    pub ports: Option<Vec<RawPort>>,
}

/// `[bus] read`: how the loop reads every servo in one exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReadChoice {
    /// Fast Sync Read where every servo's model and firmware support it, else Sync Read.
    Auto,
    /// Fast Sync Read; a servo that cannot do it is refused at start-up.
    Fast,
    /// Sync Read.
    Sync,
}

fn default_read() -> ReadChoice {
    ReadChoice::Auto
}

/// `[[bus.ports]]`: one serial port and the servos on it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPort {
    /// The servo ids on this port; read wide so a bad value can be quoted.
    pub ids: Vec<i64>,
    /// Serial device; required for `"dynamixel"`, ignored for `"sim"`.
    #[serde(default)]
    pub port: Option<String>,
}

/// `[sim]`: the simulated servo chain.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSim {
    /// Sleep for the wire time of every packet, as a real bus would take.
    #[serde(default)]
    pub wire_timing: bool,
    /// What hands the replies to the host: `"none"` (the pseudo-terminal alone, default) or
    /// `"ftdi"` (an FTDI chip's USB packets and latency timer, as in a U2D2).
    #[serde(default)]
    pub adapter: RawAdapter,
    /// The FTDI chip's latency timer, ms (1..=255; 16 as the chip comes). Only with
    /// `adapter = "ftdi"`.
    #[serde(default)]
    pub latency_timer_ms: Option<u32>,
    /// Seed of the simulator's random faults.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// `[[sim.fault]]`: faults to inject.
    #[serde(default, rename = "fault")]
    pub faults: Vec<Fault>,
    /// Firmware Version every simulated servo reports (default 48: one that answers Fast Sync
    /// Read).
    #[serde(default)]
    pub firmware: Option<u8>,
    /// `[sim.firmware_by_id]`: per-servo Firmware Version, servo id = version.
    #[serde(default)]
    pub firmware_by_id: std::collections::BTreeMap<String, u8>,
    /// How long a servo boots after REBOOT or a factory reset, ms (0..=60000; the simulator's
    /// default when absent).
    #[serde(default)]
    pub boot_ms: Option<u32>,
}

/// `[sim] adapter`: what stands between the simulated bus and the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RawAdapter {
    /// The pseudo-terminal hands every reply over as it leaves the bus.
    #[default]
    None,
    /// An FTDI USB-serial chip (a U2D2's): 62-byte USB packets, a latency timer.
    Ftdi,
}

/// A hardware error a simulated servo can raise (bits of Hardware Error Status, address 70).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HardwareError {
    /// Input voltage out of range (bit 0); `voltage` too, as the simulator's names have it.
    #[serde(alias = "voltage")]
    InputVoltage,
    /// Internal temperature too high (bit 2).
    Overheating,
    /// Encoder malfunction (bit 3).
    Encoder,
    /// Electrical shock or insufficient power (bit 4).
    ElectricalShock,
    /// Persistent load beyond the maximum (bit 5).
    Overload,
}

/// `[[sim.fault]]`: one injected fault: its `kind`, and the keys that kind takes. Times are
/// seconds since the simulator started; an absent `until_s` means "until the end". An absent
/// `id` means every servo (for the kinds where it may be absent).
///
/// One struct for every kind (not a serde enum tagged by `kind`, whose errors lose the line
/// and the key): a key no kind takes, or a value of the wrong type, is refused here at its
/// line; which keys a kind needs or refuses is checked by [`super::Config`], which names the
/// field (`sim.fault[2].fraction`). The kinds and their keys:
/// - `drop`, `corrupt`: `fraction` (0..=1, required), `id`, `at_s` (default 0), `until_s`;
/// - `latency`: `extra_us` (required), `id`, `at_s` (default 0), `until_s`;
/// - `silent`: `id` and `at_s` (required), `until_s`;
/// - `hardware_error`: `id`, `at_s` and `error` (required);
/// - `blocked`: `id` (required), `at_s` (default 0), `until_s`;
/// - `disconnect`: `port` (from 1; every port when absent), `at_s` (required), `until_s`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Fault {
    /// What goes wrong.
    pub kind: FaultKindName,
    /// Fraction of replies dropped or corrupted, 0..=1 (`drop`, `corrupt`).
    #[serde(default)]
    pub fraction: Option<f64>,
    /// Extra delay per reply, microseconds (`latency`).
    #[serde(default)]
    pub extra_us: Option<u32>,
    /// Servo affected; read wide so a bad value can be quoted.
    #[serde(default)]
    pub id: Option<i64>,
    /// Which of `[[bus.ports]]` is unplugged, from 1 (`disconnect`).
    #[serde(default)]
    pub port: Option<i64>,
    /// Start, seconds.
    #[serde(default)]
    pub at_s: Option<f64>,
    /// End, seconds.
    #[serde(default)]
    pub until_s: Option<f64>,
    /// Which hardware error (`hardware_error`).
    #[serde(default)]
    pub error: Option<HardwareError>,
}

/// `[[sim.fault]] kind`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKindName {
    /// Drop a fraction of status replies.
    Drop,
    /// Flip a bit in a fraction of status replies (a CRC failure for the reader).
    Corrupt,
    /// Delay every status reply by an extra amount.
    Latency,
    /// One servo stops answering (unplugged, or its id changed).
    Silent,
    /// One servo raises a hardware error and, like a real one, drops torque until rebooted.
    HardwareError,
    /// One servo's shaft is blocked (something in its way): it stays where it was when the
    /// block began while the servo pushes toward its goal, its load rising as a stalled
    /// servo's.
    Blocked,
    /// The serial adapter is unplugged: the port goes away for the window and comes back as a
    /// new device behind the simulator's link. Concerns a whole port, so it takes no `id`.
    Disconnect,
}

impl FaultKindName {
    /// The name as the file writes it.
    pub fn name(self) -> &'static str {
        match self {
            FaultKindName::Drop => "drop",
            FaultKindName::Corrupt => "corrupt",
            FaultKindName::Latency => "latency",
            FaultKindName::Silent => "silent",
            FaultKindName::HardwareError => "hardware_error",
            FaultKindName::Blocked => "blocked",
            FaultKindName::Disconnect => "disconnect",
        }
    }
}

/// How the redundancy is resolved, as written in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StrategyName {
    /// Tractrix propagation from tip to base.
    Sequential,
    /// Minimum sum of squared joint rotations over the whole arm.
    Overall,
}

/// `[control]`: the control loop.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawControl {
    /// Loop rate, Hz.
    #[serde(default = "default_rate_hz")]
    pub rate_hz: f64,
    /// `"sequential"` or `"overall"`.
    #[serde(default = "default_strategy")]
    pub strategy: StrategyName,
    /// Fastest commanded tip speed, m/s.
    #[serde(default = "default_max_tip_speed_m_s")]
    pub max_tip_speed_m_s: f64,
    /// Fastest joint speed, rad/s; faster resolved steps are scaled down.
    #[serde(default = "default_max_joint_speed_rad_s")]
    pub max_joint_speed_rad_s: f64,
    /// Removed (it was read, never used): refused with a message saying so, whatever its
    /// value.
    #[serde(default)]
    pub substeps: Option<toml::Value>,
    /// Fastest change of the commanded tip velocity, m/s².
    #[serde(default = "default_max_tip_accel_m_s2")]
    pub max_tip_accel_m_s2: f64,
    /// A `velocity` or `jog` command lapses this long after its last renewal, ms.
    #[serde(default = "default_deadman_ms")]
    pub deadman_ms: u32,
    /// Read the servos every k-th tick.
    #[serde(default = "default_read_every")]
    pub read_every: u32,
    /// How long a servo may go without a valid reply before it is declared silent, ms
    /// (default 50).
    #[serde(default)]
    pub max_silence_ms: Option<u32>,
    /// Deprecated: the same budget counted in reads; converted to `max_silence_ms` at the read
    /// rate, with a warning. Refused together with `max_silence_ms`.
    #[serde(default)]
    pub max_missed_reads: Option<u32>,
    /// Read temperature, load and input voltage every k-th tick.
    #[serde(default = "default_health_every")]
    pub health_every: u32,
    /// The loop's thread (and the threads it starts) under `SCHED_FIFO` at this priority,
    /// 1 to 99; the normal policy when absent.
    #[serde(default)]
    pub realtime_priority: Option<i64>,
}

/// `[server]`: the command/telemetry socket.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawServer {
    /// Address to listen on: an IP address and port, `127.0.0.1:7878` (no host name).
    #[serde(default = "default_listen")]
    pub listen: String,
    /// File holding the client token; relative to the config file's directory. No token
    /// (open access) when absent.
    #[serde(default)]
    pub token_file: Option<PathBuf>,
    /// Most clients connected at once.
    #[serde(default = "default_max_clients")]
    pub max_clients: u32,
}

/// How the Zenoh session joins the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ZenohMode {
    /// A peer: talks to other peers directly, and to routers.
    Peer,
    /// A client: reaches the network only through a router it connects to.
    Client,
}

/// `[zenoh]`: publishing telemetry and taking commands on a Zenoh network.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawZenoh {
    /// Join the network at all.
    #[serde(default)]
    pub enabled: bool,
    /// `"peer"` or `"client"`.
    #[serde(default = "default_zenoh_mode")]
    pub mode: ZenohMode,
    /// Endpoints to connect to, such as `"tcp/192.168.1.10:7447"`.
    #[serde(default)]
    pub connect: Vec<String>,
    /// Endpoints to listen on, such as `"tcp/127.0.0.1:7447"`.
    #[serde(default)]
    pub listen: Vec<String>,
    /// Find other sessions by multicast scouting.
    #[serde(default)]
    pub multicast: bool,
    /// The arm's namespace: every key starts with it.
    #[serde(default = "default_zenoh_prefix")]
    pub prefix: String,
    /// Publishing rate, Hz; the smaller of 50 and `control.rate_hz` when absent.
    #[serde(default)]
    pub publish_hz: Option<f64>,
    /// Take `cmd_vel`, `goal` and `reach` from the network.
    #[serde(default)]
    pub accept_commands: bool,
    /// A Zenoh json5 config file passed through to the session (access control, TLS, ...);
    /// relative to the config file's directory.
    #[serde(default)]
    pub config_file: Option<PathBuf>,
    /// Also be a ROS 2 node as rmw_zenoh sees one (its keys, attachments and graph tokens).
    #[serde(default)]
    pub ros2: bool,
    /// The ROS 2 domain id of those keys and tokens.
    #[serde(default)]
    pub domain_id: u32,
}

/// `[foxglove]`: the live view a Foxglove app connects to over WebSocket.
#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct RawFoxglove {
    /// Address to serve on, `HOST:PORT`; no server when absent.
    #[serde(default)]
    pub listen: Option<String>,
    /// Publishing rate, Hz; the smaller of 30 and `control.rate_hz` when absent.
    #[serde(default)]
    pub publish_hz: Option<f64>,
    /// Take `cmd_vel` (a Teleop panel's `Twist`), `goal` and `reach` (a `PointStamped`) from
    /// Foxglove.
    #[serde(default)]
    pub accept_commands: bool,
    /// Most Foxglove clients connected at once; [`DEFAULT_FOXGLOVE_MAX_CLIENTS`] when absent.
    #[serde(default)]
    pub max_clients: Option<u32>,
}

/// `[world]`: the obstacles every link keeps clear of, and contact detection.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawWorld {
    /// Half the width of every link (the capsule's radius), metres.
    #[serde(default)]
    pub link_radius_m: f64,
    /// The least gap every link keeps from every obstacle, metres.
    #[serde(default = "default_clearance_m")]
    pub clearance_m: f64,
    /// `[[world.obstacle]]`: the obstacles.
    #[serde(default, rename = "obstacle")]
    pub obstacles: Vec<RawObstacle>,
    /// Contact detection: the |Present Load or Current| above which a joint is in contact, in
    /// the unit telemetry's `load` reports for its servo (percent, or amperes); off when absent.
    #[serde(default)]
    pub contact_load: Option<ContactLoad>,
    /// How long a load must stay above its threshold before the arm stops, milliseconds.
    #[serde(default)]
    pub contact_ms: Option<u32>,
}

/// `[[world.obstacle]]`: one obstacle, with exactly one of `circle` and `polygon`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawObstacle {
    /// Its name, unique in the file.
    pub id: String,
    /// A disc.
    #[serde(default)]
    pub circle: Option<RawCircle>,
    /// A closed simple polygon.
    #[serde(default)]
    pub polygon: Option<RawPolygon>,
}

/// `circle = { center_m = [x, y], radius_m = r }`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawCircle {
    /// Centre `[x, y]`, metres.
    #[serde(deserialize_with = "pair")]
    pub center_m: [f64; 2],
    /// Radius, metres.
    pub radius_m: f64,
}

/// `polygon = { points_m = [[x, y], ...] }`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPolygon {
    /// Vertices `[x, y]` in order (either turning sense), metres; the last joins the first.
    #[serde(deserialize_with = "pairs")]
    pub points_m: Vec<[f64; 2]>,
}

/// Exactly two numbers `[x, y]` (a longer or shorter array is refused, not cut).
pub fn pair<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
    to_pair::<D::Error>(Vec::<f64>::deserialize(d)?)
}

/// A list of `[x, y]` pairs, each exactly two numbers.
pub fn pairs<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<[f64; 2]>, D::Error> {
    Vec::<Vec<f64>>::deserialize(d)?
        .into_iter()
        .map(to_pair::<D::Error>)
        .collect()
}

fn to_pair<E: serde::de::Error>(v: Vec<f64>) -> Result<[f64; 2], E> {
    match v[..] {
        [x, y] => Ok([x, y]),
        _ => Err(E::invalid_length(v.len(), &"a point [x, y] in metres")),
    }
}

/// `contact_load`: one threshold for every joint, or one per joint.
#[derive(Debug, Clone, PartialEq)]
pub enum ContactLoad {
    /// The same threshold for every joint.
    All(f64),
    /// One threshold per `[[joint]]`, base to tip.
    PerJoint(Vec<f64>),
}

impl<'de> Deserialize<'de> for ContactLoad {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = ContactLoad;

            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a number (every joint) or an array of numbers (one per joint)")
            }

            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<ContactLoad, E> {
                Ok(ContactLoad::All(v))
            }

            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<ContactLoad, E> {
                Ok(ContactLoad::All(v as f64))
            }

            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<ContactLoad, E> {
                Ok(ContactLoad::All(v as f64))
            }

            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<ContactLoad, A::Error> {
                let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(256));
                while let Some(v) = seq.next_element::<f64>()? {
                    out.push(v);
                }
                Ok(ContactLoad::PerJoint(out))
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// Factory baud rate of X-series servos.
pub fn default_baud() -> u32 {
    57_600
}

/// Torque off on exit: the safe choice when nothing watches the arm.
pub fn default_on_exit() -> OnExit {
    OnExit::TorqueOff
}

/// Bus watchdog, ms.
pub fn default_watchdog_ms() -> u32 {
    100
}

/// Reply timeout, ms.
pub fn default_reply_timeout_ms() -> u32 {
    5
}

/// Simulator seed.
pub fn default_seed() -> u64 {
    1
}

/// An FTDI chip's latency timer as it comes, ms.
pub fn default_latency_timer_ms() -> u32 {
    16
}

/// Control rate, Hz.
pub fn default_rate_hz() -> f64 {
    100.0
}

/// Strategy.
pub fn default_strategy() -> StrategyName {
    StrategyName::Overall
}

/// Tip speed, m/s.
pub fn default_max_tip_speed_m_s() -> f64 {
    0.1
}

/// Joint speed, rad/s.
pub fn default_max_joint_speed_rad_s() -> f64 {
    2.0
}

/// Tip acceleration, m/s².
pub fn default_max_tip_accel_m_s2() -> f64 {
    0.5
}

/// Deadman of velocity and jog commands, ms.
pub fn default_deadman_ms() -> u32 {
    500
}

/// Read every tick.
pub fn default_read_every() -> u32 {
    1
}

/// How long a servo may stay silent before it is declared so, ms.
pub const DEFAULT_MAX_SILENCE_MS: u32 = 50;

/// Health read every tenth tick.
pub fn default_health_every() -> u32 {
    10
}

/// Listen address: local only.
pub fn default_listen() -> String {
    "127.0.0.1:7878".to_owned()
}

/// Clients at once.
pub fn default_max_clients() -> u32 {
    8
}

/// The clearance every link keeps, m: the world's own default.
pub fn default_clearance_m() -> f64 {
    crate::world::DEFAULT_CLEARANCE_M
}

/// How long a load must stay above its threshold when `contact_ms` is not given, ms.
pub const DEFAULT_CONTACT_MS: u32 = 100;

/// Zenoh mode: a peer, which needs no router.
pub fn default_zenoh_mode() -> ZenohMode {
    ZenohMode::Peer
}

/// Zenoh key prefix.
pub fn default_zenoh_prefix() -> String {
    "snakectl".to_owned()
}

/// Foxglove publishing rate, Hz, when the loop runs at least this fast.
pub const DEFAULT_FOXGLOVE_PUBLISH_HZ: f64 = 30.0;

/// Most Foxglove clients connected at once, by default.
pub const DEFAULT_FOXGLOVE_MAX_CLIENTS: u32 = 8;

/// Zenoh publishing rate, Hz, when the loop runs at least this fast.
pub const DEFAULT_ZENOH_PUBLISH_HZ: f64 = 50.0;

impl Default for RawControl {
    fn default() -> Self {
        Self {
            rate_hz: default_rate_hz(),
            strategy: default_strategy(),
            max_tip_speed_m_s: default_max_tip_speed_m_s(),
            max_joint_speed_rad_s: default_max_joint_speed_rad_s(),
            substeps: None,
            max_tip_accel_m_s2: default_max_tip_accel_m_s2(),
            deadman_ms: default_deadman_ms(),
            read_every: default_read_every(),
            max_silence_ms: None,
            max_missed_reads: None,
            health_every: default_health_every(),
            realtime_priority: None,
        }
    }
}

impl Default for RawZenoh {
    fn default() -> Self {
        Self {
            enabled: false,
            mode: default_zenoh_mode(),
            connect: Vec::new(),
            listen: Vec::new(),
            multicast: false,
            prefix: default_zenoh_prefix(),
            publish_hz: None,
            accept_commands: false,
            config_file: None,
            ros2: false,
            domain_id: 0,
        }
    }
}

impl Default for RawServer {
    fn default() -> Self {
        Self {
            listen: default_listen(),
            token_file: None,
            max_clients: default_max_clients(),
        }
    }
}
