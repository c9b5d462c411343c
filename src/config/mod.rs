//! The one config file: raw serde tables, then validated types.
//!
//! One TOML file describes an arm and how to reach it, and every command reads the same file.
//! Reading happens in two steps, so that nothing downstream sees an unchecked value:
//! - [`raw`]: the file as written, one `deny_unknown_fields` struct per table, units in the
//!   field names, defaults in one place;
//! - [`Config`]: the checked result. [`Config::load`] and [`Config::from_str`] are the only ways
//!   to get one; every refusal is a [`ConfigError`] naming the file and the field (or the line
//!   and column, for TOML syntax) and quoting the value.
//!
//! The tables: `[arm]` and `[[joint]]` (geometry, limits, home pose and per-joint servo
//! settings), `[bus]` (serial bus), `[sim]` with `[[sim.fault]]` (the simulated servo chain),
//! `[control]` (the loop), `[server]` (the socket), `[zenoh]` (the daemon on a Zenoh
//! network, in [`zenoh_table`]), `[foxglove]` (the live view, in [`foxglove_table`]) and `[world]` with `[[world.obstacle]]` (the obstacles every
//! link keeps clear of, and contact detection). Geometry is checked in full, the world against
//! the arm too (no obstacle at the base, the home pose clear); the other tables get the cheap
//! checks (signs, ranges, known names, ids that exist, endpoint syntax).

mod error;
pub mod foxglove_table;
pub mod raw;
pub mod zenoh_table;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

pub use error::{ConfigError, FieldProblem};
pub use foxglove_table::Foxglove;
pub use raw::{BusKind, HardwareError};
pub use zenoh_table::{Endpoint, Host, Zenoh, ZenohMode};

use std::time::Duration;

use crate::chain::{Chain, JointLimit, Vec2, MAX_MAGNITUDE};
use crate::resolve::overall::MAX_LINKS_AMONG_OBSTACLES;
use crate::resolve::Strategy;
use crate::servo::arm::{Arm, JointServo, OnExit, Settings};
use crate::servo::units::CurrentUnit;
use crate::servo::units::{self, Calibration};
use crate::servo::wire::{Adapter, ReadKind, Wire};
use crate::servo::{
    model::model_names, Fields, Layout, ReadChoice, ServoModel, BAUD_RATES, MAX_ID,
};
use crate::textfile::{read_text, MAX_TEXT_BYTES};
use crate::world::{Obstacle, Shape, World, WorldError};
use raw::{
    ContactLoad, RawArm, RawBus, RawConfig, RawControl, RawJoint, RawObstacle, RawServer, RawSim,
    RawWorld, StrategyName, DEFAULT_CONTACT_MS, DEFAULT_MAX_SILENCE_MS,
};

/// Lowest servo id a joint may use (0 is reserved by convention).
pub const MIN_SERVO_ID: u8 = 1;
/// Shortest link accepted, m (a micrometre): a shorter one is a typo, and the geometry's
/// tolerances are far coarser.
pub const MIN_LINK_M: f64 = 1e-6;
/// Largest software offset, ticks: one full turn of an X-series servo.
pub const MAX_OFFSET_TICKS: i32 = 4095;

/// One validated `[[joint]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    /// Length of the link this joint turns, m.
    pub link_m: f64,
    /// Allowed relative angles, rad.
    pub limit: JointLimit,
    /// Servo id, 1..=252, unique in the file.
    pub id: Option<u8>,
    /// Servo model.
    pub model: Option<ServoModel>,
    /// Ticks at 0 rad relative to the nominal centre 2048, within one turn.
    pub offset_ticks: i32,
    /// A positive angle turns the servo the negative way.
    pub reverse: bool,
}

/// The validated `[bus]`: where the servos are. What bring-up writes to them is the servo
/// layer's [`Settings`], in [`Config::arm`].
#[derive(Debug, Clone, PartialEq)]
pub struct Bus {
    /// Simulated or real servos.
    pub kind: BusKind,
    /// Baud rate, one of [`BAUD_RATES`], shared by every port.
    pub baud: u32,
    /// The serial ports, each with its servos: one unless the file has `[[bus.ports]]`. Every
    /// joint's servo is on exactly one of them.
    pub ports: Vec<BusPort>,
}

impl Bus {
    /// The one port's path when the bus has a single port (`None` for a simulated one without
    /// a path, or several ports).
    pub fn port(&self) -> Option<&str> {
        match self.ports.as_slice() {
            [one] => one.port.as_deref(),
            _ => None,
        }
    }
}

/// One serial port of the bus and the servos wired to it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BusPort {
    /// Serial device; always present for [`BusKind::Dynamixel`].
    pub port: Option<String>,
    /// Its servo ids, as listed (the joints' order for the single port of a file without
    /// `[[bus.ports]]`).
    pub ids: Vec<u8>,
}

/// One validated `[[sim.fault]]`: what goes wrong, on which servo, when.
#[derive(Debug, Clone, PartialEq)]
pub struct Fault {
    /// What goes wrong.
    pub kind: FaultKind,
    /// The servo; every servo when `None`.
    pub id: Option<u8>,
    /// The port a `disconnect` unplugs (index into [`Bus::ports`]); every port when `None`,
    /// and always `None` for the other kinds.
    pub port: Option<usize>,
    /// From this long after the simulator starts.
    pub from: Duration,
    /// Until this long after the start; for good when `None`.
    pub until: Option<Duration>,
}

/// What a fault does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FaultKind {
    /// Drop this fraction (0..=1) of status replies.
    Drop(f64),
    /// Damage this fraction (0..=1) of status replies.
    Corrupt(f64),
    /// Delay every status reply by this much more.
    Latency(Duration),
    /// The servo stops answering.
    Silent,
    /// The servo raises this hardware error (and drops torque until rebooted).
    HardwareError(HardwareError),
    /// The whole bus is unplugged (the simulator's port goes away); never has an `id`.
    Disconnect,
    /// The servo's shaft is blocked: it stays put and pushes, its load rising.
    Blocked,
}

/// The validated `[sim]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Sim {
    /// Sleep for the wire time of every packet.
    pub wire_timing: bool,
    /// An FTDI adapter's latency timer when `adapter = "ftdi"` (the replies reach the host in
    /// its USB packets); `None`: no adapter model.
    pub ftdi_latency: Option<Duration>,
    /// Seed of the random faults.
    pub seed: u64,
    /// Faults to inject; every id names a joint's servo, fractions lie in [0, 1], windows are
    /// ordered.
    pub faults: Vec<Fault>,
    /// Firmware Version of every simulated servo; the simulator's default (one that answers
    /// Fast Sync Read) when `None`.
    pub firmware: Option<u8>,
    /// Per-servo Firmware Version (servo id, version), over `firmware`; every id names a
    /// joint's servo.
    pub firmware_by_id: Vec<(u8, u8)>,
    /// How long a servo boots after REBOOT, at most the simulator's
    /// [`snakectl_sim::MAX_BOOT_TIME`]; the simulator's default when `None`.
    pub boot_time: Option<Duration>,
}

/// The validated `[control]` (defaults when the table is absent).
#[derive(Debug, Clone, PartialEq)]
pub struct Control {
    /// Loop rate, Hz, positive.
    pub rate_hz: f64,
    /// Redundancy resolution strategy.
    pub strategy: Strategy,
    /// Fastest tip speed, m/s, positive.
    pub max_tip_speed_m_s: f64,
    /// Fastest joint speed, rad/s, positive.
    pub max_joint_speed_rad_s: f64,
    /// Fastest change of the commanded tip velocity, m/s², positive.
    pub max_tip_accel_m_s2: f64,
    /// How long a `velocity` or `jog` command lasts after its last renewal.
    pub deadman: Duration,
    /// Servos are read every `read_every`-th tick, at least 1.
    pub read_every: u32,
    /// How long a servo may go without a valid reply before it is declared silent: the same
    /// at every loop rate.
    pub max_silence: Duration,
    /// Temperature, load and input voltage are read every `health_every`-th tick, at least 1.
    pub health_every: u32,
    /// The loop's thread, and those it starts (each port's, an embedded simulator's), run under
    /// `SCHED_FIFO` at this priority (1 to 99); `None`: the normal policy.
    pub realtime_priority: Option<u8>,
}

/// Contact detection (`[world] contact_load` and `contact_ms`): a joint whose |Present Load or
/// Current| stays above its threshold this long is in contact with something.
#[derive(Debug, Clone, PartialEq)]
pub struct Contact {
    /// Per joint, base to tip: the threshold, positive, in the unit telemetry's `load` reports
    /// for the joint's servo (percent of the maximum torque for a Present Load, amperes for a
    /// Present Current).
    pub load: Vec<f64>,
    /// How long the load must stay above it.
    pub hold: Duration,
}

/// The fastest control rate accepted, Hz.
pub const MAX_RATE_HZ: f64 = 2000.0;
/// The lowest loop rate: a tick's `dt` is capped at a second ([`crate::control::MAX_DT_S`]), so
/// a slower loop would run every motion slower than asked.
pub const MIN_RATE_HZ: f64 = 1.0;

/// The validated `[server]` (defaults when the table is absent).
#[derive(Debug, Clone, PartialEq)]
pub struct Server {
    /// Address to listen on.
    pub listen: SocketAddr,
    /// Token file, resolved against the config file's directory; `None` = no token.
    pub token_file: Option<PathBuf>,
    /// Most clients at once, at least 1.
    pub max_clients: u32,
}

/// A checked config file.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    path: PathBuf,
    chain: Chain,
    home: Vec<f64>,
    joints: Vec<Joint>,
    bus: Option<Bus>,
    arm: Option<Arm>,
    sim: Option<Sim>,
    control: Control,
    server: Server,
    zenoh: Zenoh,
    foxglove: Foxglove,
    world: World,
    contact: Option<Contact>,
    /// The TOML text the config was read from (recordings keep it).
    text: String,
}

impl Config {
    /// Reads and checks the file at `path`.
    pub fn load(path: impl AsRef<Path>) -> Result<Config, ConfigError> {
        let path = path.as_ref();
        let text = read_text(path, MAX_TEXT_BYTES).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_str(&text, path)
    }

    /// Checks `text` as if read from `path`, which names the file in errors and anchors a
    /// relative `server.token_file` and `zenoh.config_file`.
    #[allow(clippy::should_implement_trait)]
    pub fn from_str(text: &str, path: impl AsRef<Path>) -> Result<Config, ConfigError> {
        let path = path.as_ref();
        let raw: RawConfig = serde_path_to_error::deserialize(toml::Deserializer::new(text))
            .map_err(|e| syntax_error(text, path, &e))?;
        let mut config = Checker { path }.config(raw)?;
        config.text = text.to_owned();
        Ok(config)
    }

    /// The file this came from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The TOML text this was read from, as it was (a recording keeps it beside the run).
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The arm's chain: links, base pose and joint limits.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// The start pose, rad, one entry per joint, inside the limits.
    pub fn home(&self) -> &[f64] {
        &self.home
    }

    /// The joints, base to tip.
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }

    /// The bus, if the file describes one.
    pub fn bus(&self) -> Option<&Bus> {
        self.bus.as_ref()
    }

    /// The servo chain (every joint's servo, calibration and tick limits, and the `[bus]`
    /// settings bring-up applies), when the file has a `[bus]`.
    pub fn arm(&self) -> Option<&Arm> {
        self.arm.as_ref()
    }

    /// Each port's tick on the wire, for the wire bound ([`crate::servo::wire`]), port `k`
    /// read with `reads[k]` (what bring-up chose; the last one for ports beyond): its servos,
    /// the baud rate and Return Delay Time, the block the loop reads (the 13 bytes of the
    /// indirect block, health included, where every joint's model shares its address; else
    /// Present Velocity and Position) and its adapter: `found[k]` where the port told one
    /// when it opened ([`crate::servo::ServoBus::adapters`]: a real port's FTDI latency
    /// timer), else, for a simulated bus, the FTDI adapter model when `[sim] adapter` names it.
    /// Empty without a `[bus]`.
    pub fn wire(&self, reads: &[ReadKind], found: &[Option<Adapter>]) -> Vec<Wire> {
        let (Some(bus), Some(arm)) = (&self.bus, &self.arm) else {
            return Vec::new();
        };
        let data_bytes = match arm.layout() {
            Layout::Indirect { .. } => arm.layout().span().1,
            Layout::Direct(_) => {
                Fields {
                    velocity: true,
                    ..Fields::POSITION
                }
                .span()
                .1
            }
        };
        let modelled = self.modelled_adapter();
        let return_delay = Duration::from_micros(u64::from(arm.settings().return_delay_us));
        bus.ports
            .iter()
            .enumerate()
            .map(|(k, p)| Wire {
                servos: p.ids.len(),
                baud: bus.baud,
                read: reads
                    .get(k)
                    .or(reads.last())
                    .copied()
                    .unwrap_or(ReadKind::Sync),
                data_bytes: usize::from(data_bytes),
                return_delay,
                adapter: found.get(k).copied().flatten().or(modelled),
            })
            .collect()
    }

    /// The adapter a simulated bus's replies come through: the FTDI model when `[bus] kind =
    /// "sim"` and `[sim] adapter = "ftdi"` (`None` otherwise). What the wire bound counts for a
    /// port that told no adapter of its own, and what such a port is taken to be behind
    /// ([`crate::servo::dynamixel::DynamixelBus::assume_adapter`]).
    pub fn modelled_adapter(&self) -> Option<Adapter> {
        self.sim
            .as_ref()
            .and_then(|s| s.ftdi_latency)
            .filter(|_| self.bus.as_ref().is_some_and(|b| b.kind == BusKind::Sim))
            .map(Adapter::ftdi)
    }

    /// The simulator settings, if the file has a `[sim]` table.
    pub fn sim(&self) -> Option<&Sim> {
        self.sim.as_ref()
    }

    /// The control loop settings.
    pub fn control(&self) -> &Control {
        &self.control
    }

    /// The server settings.
    pub fn server(&self) -> &Server {
        &self.server
    }

    /// The Zenoh settings (`enabled = false` when the file has no `[zenoh]`).
    pub fn zenoh(&self) -> &Zenoh {
        &self.zenoh
    }

    /// The Foxglove view's settings (no server, `listen = None`, when the file has no
    /// `[foxglove]`).
    pub fn foxglove(&self) -> &Foxglove {
        &self.foxglove
    }

    /// The obstacles the arm keeps clear of (an empty world with the default clearance when
    /// the file has no `[world]`). Its home pose is clear of them.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// Contact detection, when `[world] contact_load` turns it on.
    pub fn contact(&self) -> Option<&Contact> {
        self.contact.as_ref()
    }
}

/// A refusal of [`World::new`] as a config file's `[world]` table would be refused: the field
/// as the file names it ([`world_field`]: `world.obstacle[3].circle.radius_m`, counted from 1)
/// and what is wrong with it, with the obstacles and edges it names counted from 1 too.
pub fn world_problem(e: WorldError) -> (String, FieldProblem) {
    let (field, problem) = match e {
        WorldError::NotFinite { field, value } => (field, FieldProblem::NotFinite { value }),
        WorldError::NotPositive { field, value } => (field, FieldProblem::NotPositive { value }),
        WorldError::Negative { field, value } => (field, FieldProblem::Negative { value }),
        WorldError::EmptyId { field } => (field, FieldProblem::EmptyId),
        WorldError::BadId { field, why } => (field, FieldProblem::BadObstacleId { why }),
        WorldError::DuplicateId { field, id, first } => (
            field,
            FieldProblem::DuplicateObstacle {
                id,
                other: first + 1,
            },
        ),
        WorldError::TooFewPoints { field, count } => (field, FieldProblem::TooFewPoints { count }),
        WorldError::RepeatedPoint { field, first, x, y } => (
            field,
            FieldProblem::RepeatedPoint {
                x,
                y,
                first: first + 1,
            },
        ),
        WorldError::SelfIntersecting {
            field,
            edge_a,
            edge_b,
            x,
            y,
        } => (
            field,
            FieldProblem::SelfIntersecting {
                edge_a: edge_a + 1,
                edge_b: edge_b + 1,
                x,
                y,
            },
        ),
        WorldError::ZeroArea { field } => (field, FieldProblem::ZeroArea),
        WorldError::TooManyObstacles { count, max } => (
            "obstacles".to_owned(),
            FieldProblem::TooMany {
                what: "obstacles",
                count,
                max,
            },
        ),
        WorldError::TooManyPoints { count, max } => (
            "obstacles".to_owned(),
            FieldProblem::TooMany {
                what: "polygon points in all",
                count,
                max,
            },
        ),
    };
    (world_field(&field), problem)
}

/// A field path of [`World::new`] (`obstacles[2].polygon.points[4]`, indices from 0) as the
/// file names it (`world.obstacle[3].polygon.points_m[5]`, counted from 1 as every list of the
/// config is).
pub fn world_field(field: &str) -> String {
    /// `NAME[i]rest` -> (i, rest).
    fn index<'a>(s: &'a str, name: &str) -> Option<(usize, &'a str)> {
        let s = s.strip_prefix(name)?.strip_prefix('[')?;
        let (i, rest) = s.split_once(']')?;
        Some((i.parse().ok()?, rest))
    }
    let Some((i, rest)) = index(field, "obstacles") else {
        return format!("world.{}", field.replace("obstacles", "obstacle"));
    };
    let at = format!("world.obstacle[{}]", i + 1);
    let rest = match rest {
        ".circle.center.x" => ".circle.center_m[1]".to_owned(),
        ".circle.center.y" => ".circle.center_m[2]".to_owned(),
        ".polygon.points" => ".polygon.points_m".to_owned(),
        other => match other
            .strip_prefix(".polygon.")
            .and_then(|p| index(p, "points"))
        {
            Some((j, tail)) => format!(".polygon.points_m[{}]{tail}", j + 1),
            None => other.to_owned(),
        },
    };
    format!("{at}{rest}")
}

/// Turns a TOML error into one naming the file, line and column, and the field where the
/// error is about one (`sim.fault[2].fraction: invalid type: ...`).
fn syntax_error(
    text: &str,
    path: &Path,
    e: &serde_path_to_error::Error<toml::de::Error>,
) -> ConfigError {
    let (line, column, message) = toml_where(text, e.inner());
    let field = toml_field(e.path());
    ConfigError::Syntax {
        path: path.to_path_buf(),
        line,
        column,
        message: if field.is_empty() {
            message
        } else {
            format!("{field}: {message}")
        },
    }
}

/// A field path as the config's errors name fields: dotted keys, tables of an array counted
/// from 1 (`joint[3].link_m`, `sim.fault[2].fraction`); empty where serde could not tell.
fn toml_field(path: &serde_path_to_error::Path) -> String {
    use serde_path_to_error::Segment;
    let mut out = String::new();
    for segment in path.iter() {
        match segment {
            Segment::Seq { index } => out.push_str(&format!("[{}]", index + 1)),
            Segment::Map { key } | Segment::Enum { variant: key } => {
                if !out.is_empty() {
                    out.push('.');
                }
                out.push_str(key);
            }
            Segment::Unknown => break,
        }
    }
    out
}

/// Where in `text` a TOML error is (line and column from 1; 0 when it does not say) and its
/// message on one line.
pub fn toml_where(text: &str, e: &toml::de::Error) -> (usize, usize, String) {
    let (line, column) = match e.span().and_then(|s| text.get(..s.start)) {
        Some(before) => {
            let line = before.matches('\n').count() + 1;
            let line_start = before.rfind('\n').map_or(0, |i| i + 1);
            (line, before[line_start..].chars().count() + 1)
        }
        None => (0, 0),
    };
    let message = e
        .message()
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join("; ");
    (line, column, message)
}

fn finite_within(value: f64) -> bool {
    value.is_finite() && value.abs() <= MAX_MAGNITUDE
}

/// Holds the file name while checking, so each check only says what and where.
struct Checker<'a> {
    path: &'a Path,
}

impl Checker<'_> {
    fn invalid(&self, field: impl Into<String>, problem: FieldProblem) -> ConfigError {
        ConfigError::Invalid {
            path: self.path.to_path_buf(),
            field: field.into(),
            problem,
        }
    }

    /// `file` as named in the config: relative paths start at the config file's directory.
    fn relative_to_file(&self, file: PathBuf) -> PathBuf {
        if file.is_relative() {
            self.path.parent().unwrap_or(Path::new("")).join(file)
        } else {
            file
        }
    }

    fn positive(&self, field: impl Into<String>, value: f64) -> Result<f64, ConfigError> {
        if finite_within(value) && value > 0.0 {
            Ok(value)
        } else {
            Err(self.invalid(field, FieldProblem::NotPositive { value }))
        }
    }

    fn non_negative(&self, field: impl Into<String>, value: f64) -> Result<f64, ConfigError> {
        if finite_within(value) && value >= 0.0 {
            Ok(value)
        } else {
            Err(self.invalid(field, FieldProblem::Negative { value }))
        }
    }

    fn finite(&self, field: impl Into<String>, value: f64) -> Result<f64, ConfigError> {
        if finite_within(value) {
            Ok(value)
        } else {
            Err(self.invalid(field, FieldProblem::NotFinite { value }))
        }
    }

    fn config(&self, raw: RawConfig) -> Result<Config, ConfigError> {
        let joints = raw
            .joints
            .iter()
            .enumerate()
            .map(|(i, j)| self.joint(i + 1, j))
            .collect::<Result<Vec<_>, _>>()?;
        if joints.is_empty() {
            return Err(self.invalid("joint", FieldProblem::NoJoints));
        }
        self.unique_ids(&joints)?;
        let (base, heading, home) = self.arm(&raw.arm, &joints)?;
        let chain = Chain::new(
            joints.iter().map(|j| j.link_m).collect(),
            base,
            heading,
            joints.iter().map(|j| Some(j.limit)).collect(),
        )
        .map_err(|source| ConfigError::Chain {
            path: self.path.to_path_buf(),
            source,
        })?;
        let raw_bus = raw.bus;
        let (bus, arm) = match &raw_bus {
            Some(b) => {
                let (bus, arm) = self.bus(b, &joints)?;
                (Some(bus), Some(arm))
            }
            None => (None, None),
        };
        // The daemon refuses a home pose that folds the arm onto itself (it could never go
        // home). Checked with a `[bus]` only, whose servo ids (checked above) bound the joints
        // to 252: the check is quadratic in them.
        if bus.is_some() {
            if let Some((a, b)) = Chain::self_intersects(&chain.points(&home)) {
                return Err(self.invalid(
                    "arm.home_rad",
                    FieldProblem::HomeSelfCollision { a: a + 1, b: b + 1 },
                ));
            }
        }
        let ports = bus.as_ref().map_or(1, |b: &Bus| b.ports.len());
        let sim = raw.sim.map(|s| self.sim(s, &joints, ports)).transpose()?;
        if let (Some(sim), Some(BusKind::Dynamixel)) = (&sim, bus.as_ref().map(|b| b.kind)) {
            self.sim_unused(sim);
        }
        let control = self.control(&raw.control.unwrap_or_default())?;
        if let (Some(b), Some(arm)) = (&raw_bus, &arm) {
            self.watchdog_covers_ticks(arm.settings().watchdog_ms, b, control.rate_hz)?;
            self.profile_keeps_up(arm.settings().profile_velocity_rad_s, &control);
        }
        let server = self.server(raw.server.unwrap_or_default())?;
        let zenoh = self.zenoh(raw.zenoh.unwrap_or_default(), control.rate_hz)?;
        let foxglove = self.foxglove(raw.foxglove.unwrap_or_default(), control.rate_hz, &server)?;
        let (world, contact) = match raw.world {
            Some(w) => self.world(w, &chain, &home, &joints)?,
            None => (World::default(), None),
        };
        Ok(Config {
            path: self.path.to_path_buf(),
            chain,
            home,
            joints,
            bus,
            arm,
            sim,
            control,
            server,
            zenoh,
            foxglove,
            world,
            contact,
            text: String::new(),
        })
    }

    fn joint(&self, n: usize, raw: &RawJoint) -> Result<Joint, ConfigError> {
        let field = |name: &str| format!("joint[{n}].{name}");
        let link_m = self.positive(field("link_m"), raw.link_m)?;
        if link_m < MIN_LINK_M {
            return Err(self.invalid(
                field("link_m"),
                FieldProblem::Outside {
                    value: link_m,
                    lo: MIN_LINK_M,
                    hi: MAX_MAGNITUDE,
                },
            ));
        }
        let min_rad = self.finite(field("min_rad"), raw.min_rad)?;
        let max_rad = self.finite(field("max_rad"), raw.max_rad)?;
        if min_rad >= max_rad {
            return Err(self.invalid(
                field("max_rad"),
                FieldProblem::EmptyRange { min_rad, max_rad },
            ));
        }
        let id = match raw.id {
            None => None,
            Some(v) => match u8::try_from(v) {
                Ok(id) if (MIN_SERVO_ID..=MAX_ID).contains(&id) => Some(id),
                _ => return Err(self.invalid(field("id"), FieldProblem::BadId { value: v })),
            },
        };
        let model = match &raw.model {
            None => None,
            Some(name) => match ServoModel::from_name(name) {
                Some(m) => Some(m),
                None => {
                    return Err(self.invalid(
                        field("model"),
                        FieldProblem::UnknownModel {
                            value: name.clone(),
                            known: model_names(),
                        },
                    ))
                }
            },
        };
        let offset_ticks = match i32::try_from(raw.offset_ticks) {
            Ok(t) if t.abs() <= MAX_OFFSET_TICKS => t,
            _ => {
                return Err(self.invalid(
                    field("offset_ticks"),
                    FieldProblem::OutOfRange {
                        value: raw.offset_ticks,
                        expected: "must lie within one turn, -4095..=4095",
                    },
                ))
            }
        };
        Ok(Joint {
            link_m,
            limit: JointLimit {
                lo: min_rad,
                hi: max_rad,
            },
            id,
            model,
            offset_ticks,
            reverse: raw.reverse,
        })
    }

    fn unique_ids(&self, joints: &[Joint]) -> Result<(), ConfigError> {
        let mut owner = [0usize; 256];
        for (i, j) in joints.iter().enumerate() {
            if let Some(id) = j.id {
                let slot = &mut owner[usize::from(id)];
                if *slot != 0 {
                    return Err(self.invalid(
                        format!("joint[{}].id", i + 1),
                        FieldProblem::DuplicateId { id, other: *slot },
                    ));
                }
                *slot = i + 1;
            }
        }
        Ok(())
    }

    fn arm(&self, raw: &RawArm, joints: &[Joint]) -> Result<(Vec2, f64, Vec<f64>), ConfigError> {
        let x = self.finite("arm.base_x_m", raw.base_x_m)?;
        let y = self.finite("arm.base_y_m", raw.base_y_m)?;
        let heading = self.finite("arm.base_heading_rad", raw.base_heading_rad)?;
        let home = match &raw.home_rad {
            Some(home) => {
                if home.len() != joints.len() {
                    return Err(self.invalid(
                        "arm.home_rad",
                        FieldProblem::Count {
                            got: home.len(),
                            expected: joints.len(),
                        },
                    ));
                }
                for (i, (&value, j)) in home.iter().zip(joints).enumerate() {
                    if !j.limit.contains(value) {
                        return Err(self.invalid(
                            format!("arm.home_rad[{}]", i + 1),
                            FieldProblem::OutsideLimits {
                                joint: i + 1,
                                value,
                                min_rad: j.limit.lo,
                                max_rad: j.limit.hi,
                            },
                        ));
                    }
                }
                home.clone()
            }
            None => {
                if let Some((i, j)) = joints
                    .iter()
                    .enumerate()
                    .find(|(_, j)| !j.limit.contains(0.0))
                {
                    return Err(self.invalid(
                        "arm.home_rad",
                        FieldProblem::ZeroOutsideLimits {
                            joint: i + 1,
                            min_rad: j.limit.lo,
                            max_rad: j.limit.hi,
                        },
                    ));
                }
                vec![0.0; joints.len()]
            }
        };
        Ok((Vec2::new(x, y), heading, home))
    }

    fn bus(&self, raw: &RawBus, joints: &[Joint]) -> Result<(Bus, Arm), ConfigError> {
        let mut servos = Vec::with_capacity(joints.len());
        for (i, j) in joints.iter().enumerate() {
            let Some(id) = j.id else {
                return Err(self.invalid(
                    format!("joint[{}].id", i + 1),
                    FieldProblem::Missing {
                        why: "every joint needs a servo id when the file has a [bus]",
                    },
                ));
            };
            let Some(model) = j.model else {
                return Err(self.invalid(
                    format!("joint[{}].model", i + 1),
                    FieldProblem::Missing {
                        why: "every joint needs a servo model when the file has a [bus]",
                    },
                ));
            };
            let calibration = Calibration {
                offset_ticks: j.offset_ticks,
                reverse: j.reverse,
            };
            self.tick_limits(i + 1, calibration, j.limit)?;
            servos.push(JointServo::new(i + 1, id, model, calibration, j.limit));
        }
        let ports = self.ports(raw, &servos)?;
        if !BAUD_RATES.contains(&raw.baud) {
            return Err(self.invalid(
                "bus.baud",
                FieldProblem::OutOfRange {
                    value: raw.baud.into(),
                    expected: "must be one of 9600, 57600, 115200, 1000000, 2000000, 3000000, \
                               4000000, 4500000",
                },
            ));
        }
        if raw.return_delay_us % 2 != 0 || raw.return_delay_us > 508 {
            return Err(self.invalid(
                "bus.return_delay_us",
                FieldProblem::OutOfRange {
                    value: raw.return_delay_us.into(),
                    expected: "must be even and at most 508 (the register counts 2 µs)",
                },
            ));
        }
        let profile_velocity_rad_s = self.profile(
            "bus.profile_velocity_rad_s",
            raw.profile_velocity_rad_s,
            units::VELOCITY_UNIT_RAD_S,
            "rad/s",
        )?;
        let profile_acceleration_rad_s2 = self.profile(
            "bus.profile_acceleration_rad_s2",
            raw.profile_acceleration_rad_s2,
            units::ACCELERATION_UNIT_RAD_S2,
            "rad/s²",
        )?;
        let watchdog_ms = raw.watchdog_ms.unwrap_or_else(raw::default_watchdog_ms);
        if watchdog_ms % units::WATCHDOG_UNIT_MS != 0
            || watchdog_ms > units::WATCHDOG_UNIT_MS * units::WATCHDOG_MAX_UNITS
        {
            return Err(self.invalid(
                "bus.watchdog_ms",
                FieldProblem::OutOfRange {
                    value: watchdog_ms.into(),
                    expected: "must be 0 (off) or a multiple of 20 up to 2540",
                },
            ));
        }
        if !(1..=1000).contains(&raw.reply_timeout_ms) {
            return Err(self.invalid(
                "bus.reply_timeout_ms",
                FieldProblem::OutOfRange {
                    value: raw.reply_timeout_ms.into(),
                    expected: "must lie in 1..=1000",
                },
            ));
        }
        let settings = Settings {
            return_delay_us: raw.return_delay_us,
            profile_velocity_rad_s,
            profile_acceleration_rad_s2,
            watchdog_ms,
            on_exit: match raw.on_exit {
                raw::OnExit::TorqueOff => OnExit::TorqueOff,
                raw::OnExit::Hold => OnExit::Hold,
            },
            reply_timeout: Duration::from_millis(u64::from(raw.reply_timeout_ms)),
            read: match raw.read {
                raw::ReadChoice::Auto => ReadChoice::Auto,
                raw::ReadChoice::Fast => ReadChoice::Fast,
                raw::ReadChoice::Sync => ReadChoice::Sync,
            },
        };
        let bus = Bus {
            kind: raw.kind,
            baud: raw.baud,
            ports,
        };
        Ok((bus, Arm::new(servos, settings)))
    }

    /// A profile value: 0 (none) or what its register holds, 1 to [`units::PROFILE_MAX`] units
    /// of `step` (rounded to the nearest), never clamped into it.
    fn profile(
        &self,
        field: &str,
        value: f64,
        step: f64,
        unit: &'static str,
    ) -> Result<f64, ConfigError> {
        let value = self.non_negative(field, value)?;
        // One unit and the largest, as the message shows them: the lower rounded up, the
        // upper down, so that both are accepted and the check is what the message says.
        let lo = (step * 1e5).ceil() / 1e5;
        let hi = (step * units::PROFILE_MAX as f64 * 1e2).floor() / 1e2;
        if value == 0.0 || (lo..=hi).contains(&value) {
            return Ok(value);
        }
        Err(self.invalid(
            field,
            FieldProblem::ProfileOutside {
                value,
                lo,
                hi,
                step: (step * 1e6).round() / 1e6,
                unit,
            },
        ))
    }

    /// Warns that `[sim]` (and its faults) is not used by a bus of real servos, as a `port`
    /// given to `kind = "sim"` is warned of: only a simulator serves it.
    fn sim_unused(&self, sim: &Sim) {
        let faults = match sim.faults.len() {
            0 => String::new(),
            1 => ", nor its [[sim.fault]]".to_owned(),
            n => format!(", nor its {n} [[sim.fault]] tables"),
        };
        tracing::warn!(
            "{}: [sim] is not used{faults}: kind = \"dynamixel\" drives the servos on the \
             serial devices, not a simulator (only kind = \"sim\", or `snakectl sim` on this \
             file, serves it)",
            self.path.display()
        );
    }

    /// Warns when the servos' Profile Velocity (0: none) is below the speed the daemon commands
    /// joints at: they then lag behind their goals, and a motion is told done before they
    /// arrive. Accepted all the same, for a gentle profile on purpose.
    fn profile_keeps_up(&self, profile_velocity_rad_s: f64, control: &Control) {
        if profile_velocity_rad_s > 0.0 && profile_velocity_rad_s < control.max_joint_speed_rad_s {
            tracing::warn!(
                "{}: bus.profile_velocity_rad_s = {profile_velocity_rad_s} is below \
                 control.max_joint_speed_rad_s = {}: the servos move no faster than their \
                 profile, so they lag behind the goals the daemon sends and a motion is told \
                 done before they arrive; raise the profile (or 0 for none), or lower \
                 max_joint_speed_rad_s to it",
                self.path.display(),
                control.max_joint_speed_rad_s
            );
        }
    }

    /// `bus.watchdog_ms` (0: off) covers two ticks at `rate_hz`: the loop renews the Bus
    /// Watchdog with each tick's Sync Write of the goals, which may come early in one tick and
    /// late in the next, and it takes a gap as long as the watchdog for a stall.
    fn watchdog_covers_ticks(
        &self,
        watchdog_ms: u32,
        raw: &RawBus,
        rate_hz: f64,
    ) -> Result<(), ConfigError> {
        let two_ticks_ms = 2e3 / rate_hz;
        if watchdog_ms == 0 || f64::from(watchdog_ms) >= two_ticks_ms {
            return Ok(());
        }
        let unit = f64::from(units::WATCHDOG_UNIT_MS);
        let min_ms = ((two_ticks_ms / unit).ceil() * unit) as u32;
        Err(self.invalid(
            "bus.watchdog_ms",
            FieldProblem::WatchdogShort {
                watchdog_ms,
                given: raw.watchdog_ms.is_some(),
                rate_hz,
                two_ticks_ms,
                min_ms,
            },
        ))
    }

    /// The bus's ports: `[[bus.ports]]`, each path given once (for real servos), each joint's
    /// servo on exactly one port, no port empty; absent, one port of every joint's servo.
    fn ports(&self, raw: &RawBus, servos: &[JointServo]) -> Result<Vec<BusPort>, ConfigError> {
        const NEEDS_PATH: &str = "kind = \"dynamixel\" needs the serial device, e.g. /dev/ttyUSB0";
        if raw.ports.as_ref().is_some_and(Vec::is_empty) {
            return Err(self.invalid("bus.ports", FieldProblem::NoPorts));
        }
        let listed = raw.ports.as_deref().unwrap_or_default();
        if raw.kind == BusKind::Sim {
            let named = raw.port.iter().map(|p| ("bus.port".to_owned(), p)).chain(
                listed.iter().enumerate().filter_map(|(k, p)| {
                    p.port
                        .as_ref()
                        .map(|q| (format!("bus.ports[{}].port", k + 1), q))
                }),
            );
            for (field, path) in named {
                tracing::warn!(
                    "{}: {field} = {path:?} is not opened: kind = \"sim\" serves its own \
                     pseudo-terminal (give --port, or kind = \"dynamixel\", to drive a device)",
                    self.path.display()
                );
            }
        }
        if listed.is_empty() {
            if raw.kind == BusKind::Dynamixel && raw.port.is_none() {
                return Err(self.invalid("bus.port", FieldProblem::Missing { why: NEEDS_PATH }));
            }
            if raw.port.as_deref().is_some_and(|p| p.trim().is_empty()) {
                return Err(self.invalid("bus.port", FieldProblem::EmptyPath));
            }
            return Ok(vec![BusPort {
                port: raw.port.clone(),
                ids: servos.iter().map(|s| s.id).collect(),
            }]);
        }
        if raw.port.is_some() {
            return Err(self.invalid(
                "bus.port",
                FieldProblem::Replaced {
                    other: "the port of each [[bus.ports]]",
                },
            ));
        }
        // Which port (1-based) each id is on, and which port each path names.
        let mut on_port: std::collections::BTreeMap<u8, usize> = Default::default();
        let mut paths: Vec<&str> = Vec::new();
        let mut ports = Vec::with_capacity(listed.len());
        for (k, p) in listed.iter().enumerate() {
            let n = k + 1;
            if p.ids.is_empty() {
                return Err(self.invalid(format!("bus.ports[{n}].ids"), FieldProblem::EmptyPort));
            }
            let mut ids = Vec::with_capacity(p.ids.len());
            for (j, &wide) in p.ids.iter().enumerate() {
                let field = || format!("bus.ports[{n}].ids[{}]", j + 1);
                let id = u8::try_from(wide)
                    .ok()
                    .filter(|id| (MIN_SERVO_ID..=MAX_ID).contains(id))
                    .ok_or_else(|| self.invalid(field(), FieldProblem::BadId { value: wide }))?;
                if let Some(&other) = on_port.get(&id) {
                    return Err(self.invalid(field(), FieldProblem::IdOnTwoPorts { id, other }));
                }
                if !servos.iter().any(|s| s.id == id) {
                    return Err(self.invalid(field(), FieldProblem::UnknownId { id }));
                }
                on_port.insert(id, n);
                ids.push(id);
            }
            match (&p.port, raw.kind) {
                (None, BusKind::Dynamixel) => {
                    return Err(self.invalid(
                        format!("bus.ports[{n}].port"),
                        FieldProblem::Missing { why: NEEDS_PATH },
                    ))
                }
                (Some(path), _) if path.trim().is_empty() => {
                    return Err(
                        self.invalid(format!("bus.ports[{n}].port"), FieldProblem::EmptyPath)
                    )
                }
                (Some(path), _) => {
                    if let Some(other) = paths.iter().position(|q| q == path) {
                        return Err(self.invalid(
                            format!("bus.ports[{n}].port"),
                            FieldProblem::DuplicatePort {
                                path: path.clone(),
                                other: other + 1,
                            },
                        ));
                    }
                    paths.push(path);
                }
                (None, BusKind::Sim) => {}
            }
            ports.push(BusPort {
                port: p.port.clone(),
                ids,
            });
        }
        if let Some(s) = servos.iter().find(|s| !on_port.contains_key(&s.id)) {
            return Err(self.invalid(
                format!("joint[{}].id", s.joint),
                FieldProblem::IdOnNoPort { id: s.id },
            ));
        }
        Ok(ports)
    }

    /// Joint `n`'s limits as servo ticks: within the servo's one turn, and at least one whole
    /// tick apart once rounded inward (so that every angle inside the limits, a home pose on
    /// one of them included, has a tick inside them).
    fn tick_limits(
        &self,
        n: usize,
        calibration: Calibration,
        limit: JointLimit,
    ) -> Result<(), ConfigError> {
        for (name, value) in [("min_rad", limit.lo), ("max_rad", limit.hi)] {
            let ticks = calibration.ticks(value);
            if !(0.0..=4095.0).contains(&ticks) {
                return Err(self.invalid(
                    format!("joint[{n}].{name}"),
                    FieldProblem::BeyondTurn { value, ticks },
                ));
            }
        }
        let (lo, hi) = calibration.tick_range(limit.lo, limit.hi);
        if lo > hi {
            return Err(self.invalid(
                format!("joint[{n}].max_rad"),
                FieldProblem::NoWholeTick {
                    min_rad: limit.lo,
                    max_rad: limit.hi,
                },
            ));
        }
        Ok(())
    }

    fn sim(&self, raw: RawSim, joints: &[Joint], ports: usize) -> Result<Sim, ConfigError> {
        let faults = raw
            .faults
            .iter()
            .enumerate()
            .map(|(i, f)| self.fault(i + 1, f, joints, ports))
            .collect::<Result<_, _>>()?;
        let ftdi_latency = match (raw.adapter, raw.latency_timer_ms) {
            (raw::RawAdapter::None, None) => None,
            (raw::RawAdapter::None, Some(ms)) => {
                return Err(self.invalid(
                    "sim.latency_timer_ms",
                    FieldProblem::OutOfRange {
                        value: ms.into(),
                        expected: "is an FTDI adapter's: give it with adapter = \"ftdi\"",
                    },
                ))
            }
            (raw::RawAdapter::Ftdi, ms) => {
                let ms = ms.unwrap_or(raw::default_latency_timer_ms());
                if !(1..=255).contains(&ms) {
                    return Err(self.invalid(
                        "sim.latency_timer_ms",
                        FieldProblem::OutOfRange {
                            value: ms.into(),
                            expected: "must lie in 1..=255, the FTDI chip's range",
                        },
                    ));
                }
                Some(Duration::from_millis(ms.into()))
            }
        };
        let mut firmware_by_id = Vec::with_capacity(raw.firmware_by_id.len());
        for (key, &version) in &raw.firmware_by_id {
            let id = key.trim().parse::<u8>();
            // The key as TOML writes it: bare where it may be, else quoted.
            let bare = !key.is_empty()
                && key
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
            let field = if bare {
                format!("sim.firmware_by_id.{key}")
            } else {
                format!("sim.firmware_by_id.{key:?}")
            };
            let id = match id {
                // `03`, `+3` and ` 3 ` would be servo 3 as well as `3`: one spelling only, so
                // that no servo is given twice.
                Ok(id) if id.to_string() != *key => {
                    return Err(self.invalid(
                        field,
                        FieldProblem::NonCanonicalId {
                            key: key.clone(),
                            id,
                        },
                    ))
                }
                Ok(id) if joints.iter().any(|j| j.id == Some(id)) => id,
                Ok(id) => return Err(self.invalid(field, FieldProblem::UnknownId { id })),
                Err(_) => {
                    return Err(self.invalid(field, FieldProblem::NotAnId { key: key.clone() }))
                }
            };
            firmware_by_id.push((id, version));
        }
        let boot_time = match raw.boot_ms.map(|ms| Duration::from_millis(ms.into())) {
            Some(t) if t > snakectl_sim::MAX_BOOT_TIME => {
                return Err(self.invalid(
                    "sim.boot_ms",
                    FieldProblem::OutOfRange {
                        value: i64::try_from(t.as_millis()).unwrap_or(i64::MAX),
                        expected: "must lie in 0..=60000",
                    },
                ))
            }
            t => t,
        };
        Ok(Sim {
            wire_timing: raw.wire_timing,
            ftdi_latency,
            seed: raw.seed,
            faults,
            firmware: raw.firmware,
            firmware_by_id,
            boot_time,
        })
    }

    /// Seconds as a duration the simulator's clock can hold.
    fn seconds(&self, field: String, s: f64) -> Result<Duration, ConfigError> {
        let s = self.non_negative(field.clone(), s)?;
        Duration::try_from_secs_f64(s).map_err(|_| {
            self.invalid(
                field,
                FieldProblem::Outside {
                    value: s,
                    lo: 0.0,
                    hi: u64::MAX as f64,
                },
            )
        })
    }

    fn fault(
        &self,
        n: usize,
        fault: &raw::Fault,
        joints: &[Joint],
        ports: usize,
    ) -> Result<Fault, ConfigError> {
        use raw::FaultKindName as K;
        let field = |name: &str| format!("sim.fault[{n}].{name}");
        let name = fault.kind.name();
        // The keys each kind takes, `!` marking a required one.
        let takes: &'static [&'static str] = match fault.kind {
            K::Drop | K::Corrupt => &["fraction!", "id", "at_s", "until_s"],
            K::Latency => &["extra_us!", "id", "at_s", "until_s"],
            K::Silent => &["id!", "at_s!", "until_s"],
            K::HardwareError => &["id!", "at_s!", "error!"],
            K::Blocked => &["id!", "at_s", "until_s"],
            K::Disconnect => &["port", "at_s!", "until_s"],
        };
        let given = [
            ("fraction", fault.fraction.is_some()),
            ("extra_us", fault.extra_us.is_some()),
            ("id", fault.id.is_some()),
            ("port", fault.port.is_some()),
            ("at_s", fault.at_s.is_some()),
            ("until_s", fault.until_s.is_some()),
            ("error", fault.error.is_some()),
        ];
        let listed = |key: &str| {
            takes
                .iter()
                .find(|t| t.trim_end_matches('!') == key)
                .map(|t| t.ends_with('!'))
        };
        let keys = || {
            takes
                .iter()
                .map(|t| t.trim_end_matches('!'))
                .collect::<Vec<_>>()
                .join(", ")
        };
        for (key, is_given) in given {
            match listed(key) {
                None if is_given => {
                    return Err(self.invalid(
                        field(key),
                        FieldProblem::NotOfKind {
                            kind: name,
                            takes: keys(),
                        },
                    ))
                }
                Some(true) if !is_given => {
                    return Err(self.invalid(
                        field(key),
                        FieldProblem::KindNeeds {
                            kind: name,
                            takes: keys(),
                        },
                    ))
                }
                _ => {}
            }
        }
        // Every required key is given (checked above): the defaults below are never used for
        // those.
        let at_s = fault.at_s.unwrap_or(0.0);
        let until_s = fault.until_s;
        let id = fault.id;
        let kind = match fault.kind {
            K::Drop => FaultKind::Drop(fault.fraction.unwrap_or(0.0)),
            K::Corrupt => FaultKind::Corrupt(fault.fraction.unwrap_or(0.0)),
            K::Latency => FaultKind::Latency(Duration::from_micros(u64::from(
                fault.extra_us.unwrap_or(0),
            ))),
            K::Silent => FaultKind::Silent,
            K::HardwareError => {
                FaultKind::HardwareError(fault.error.unwrap_or(HardwareError::Overload))
            }
            K::Blocked => FaultKind::Blocked,
            K::Disconnect => FaultKind::Disconnect,
        };
        let id = match id {
            None => None,
            Some(wide) => match u8::try_from(wide) {
                Ok(id) if joints.iter().any(|j| j.id == Some(id)) => Some(id),
                Ok(id) if (MIN_SERVO_ID..=MAX_ID).contains(&id) => {
                    return Err(self.invalid(field("id"), FieldProblem::UnknownId { id }))
                }
                _ => return Err(self.invalid(field("id"), FieldProblem::BadId { value: wide })),
            },
        };
        let from = self.seconds(field("at_s"), at_s)?;
        let until = match until_s {
            Some(until_s) if !(finite_within(until_s) && until_s > at_s) => {
                return Err(self.invalid(
                    field("until_s"),
                    FieldProblem::EndsBeforeStart { at_s, until_s },
                ))
            }
            Some(until_s) => Some(self.seconds(field("until_s"), until_s)?),
            None => None,
        };
        if let FaultKind::Drop(value) | FaultKind::Corrupt(value) = kind {
            if !(0.0..=1.0).contains(&value) {
                return Err(self.invalid(
                    field("fraction"),
                    FieldProblem::Outside {
                        value,
                        lo: 0.0,
                        hi: 1.0,
                    },
                ));
            }
        }
        let port = match fault.port {
            Some(wide) => match usize::try_from(wide) {
                Ok(n @ 1..) if n <= ports => Some(n - 1),
                _ => {
                    return Err(self.invalid(
                        field("port"),
                        FieldProblem::OutOfRange {
                            value: wide,
                            expected: "must be the number of one of the bus's ports, from 1",
                        },
                    ))
                }
            },
            _ => None,
        };
        Ok(Fault {
            kind,
            id,
            port,
            from,
            until,
        })
    }

    /// `[world]`: the obstacles (through [`World::new`], its field paths turned into the file's
    /// names), checked against the arm (none at the base, the home pose clear), and contact
    /// detection.
    fn world(
        &self,
        raw: RawWorld,
        chain: &Chain,
        home: &[f64],
        joints: &[Joint],
    ) -> Result<(World, Option<Contact>), ConfigError> {
        let contact = self.contact(&raw, joints)?;
        let obstacles = raw
            .obstacles
            .into_iter()
            .enumerate()
            .map(|(i, o)| self.obstacle(i + 1, o))
            .collect::<Result<Vec<_>, _>>()?;
        let world = World::new(raw.link_radius_m, raw.clearance_m, obstacles)
            .map_err(|e| self.world_error(e))?;
        if joints.len() > MAX_LINKS_AMONG_OBSTACLES && !world.obstacles().is_empty() {
            return Err(self.invalid(
                "joint",
                FieldProblem::TooManyJointsAmongObstacles {
                    count: joints.len(),
                    max: MAX_LINKS_AMONG_OBSTACLES,
                },
            ));
        }
        let keep_m = world.link_radius_m() + world.clearance_m();
        if let Some((distance_m, k)) = world.point_distance(chain.base()) {
            if distance_m < keep_m {
                return Err(self.invalid(
                    format!("world.obstacle[{}]", k + 1),
                    FieldProblem::TouchesBase {
                        id: world.obstacles()[k].id.clone(),
                        distance_m,
                        keep_m,
                    },
                ));
            }
        }
        // The servos take the home pose in whole ticks: rounded, it must be clear as well, or
        // `home` could never arrive.
        let tick = std::f64::consts::TAU / crate::servo::units::TICKS_PER_TURN;
        let rounded: Vec<f64> = home.iter().map(|t| (t / tick).round() * tick).collect();
        for (pose, rounded) in [(home, false), (&rounded[..], true)] {
            let Some(pair) = world.clearance(&chain.points(pose)) else {
                break;
            };
            if pair.clearance_m < world.clearance_m() {
                return Err(self.invalid(
                    format!("world.obstacle[{}]", pair.obstacle + 1),
                    FieldProblem::HomeNotClear {
                        id: pair.id(&world).to_owned(),
                        link: pair.link,
                        clearance_m: pair.clearance_m,
                        keep_m: world.clearance_m(),
                        rounded,
                    },
                ));
            }
        }
        Ok((world, contact))
    }

    /// `[[world.obstacle]]` number `n` (from 1) with exactly one shape; the numbers are
    /// checked by [`World::new`].
    fn obstacle(&self, n: usize, raw: RawObstacle) -> Result<Obstacle, ConfigError> {
        let shape = match (raw.circle, raw.polygon) {
            (Some(c), None) => Shape::Circle {
                center: Vec2::new(c.center_m[0], c.center_m[1]),
                radius_m: c.radius_m,
            },
            (None, Some(p)) => Shape::Polygon {
                points: p.points_m.iter().map(|&[x, y]| Vec2::new(x, y)).collect(),
            },
            (c, _) => {
                return Err(self.invalid(
                    format!("world.obstacle[{n}]"),
                    FieldProblem::OneShape {
                        given: if c.is_some() { "both" } else { "neither" },
                    },
                ))
            }
        };
        Ok(Obstacle { id: raw.id, shape })
    }

    /// A refusal of [`World::new`], its field named as in the file (`world.obstacle[3]...`,
    /// counted from 1).
    fn world_error(&self, e: WorldError) -> ConfigError {
        let (field, problem) = world_problem(e);
        self.invalid(field, problem)
    }

    /// `contact_load` (one number for every joint, or one per joint) and `contact_ms`.
    fn contact(&self, raw: &RawWorld, joints: &[Joint]) -> Result<Option<Contact>, ConfigError> {
        let load = match &raw.contact_load {
            None if raw.contact_ms.is_some() => {
                return Err(self.invalid(
                    "world.contact_load",
                    FieldProblem::Missing {
                        why: "contact_ms is given, but contact detection needs its threshold \
                              (one number for every joint, or one per joint)",
                    },
                ))
            }
            None => return Ok(None),
            Some(ContactLoad::All(v)) => vec![*v; joints.len()],
            Some(ContactLoad::PerJoint(list)) => {
                if list.len() != joints.len() {
                    return Err(self.invalid(
                        "world.contact_load",
                        FieldProblem::Count {
                            got: list.len(),
                            expected: joints.len(),
                        },
                    ));
                }
                list.clone()
            }
        };
        // Above 0, in the unit of the joint's servo; a Present Load reads at most 100 %: a
        // threshold above it would never fire.
        for (i, (&value, j)) in load.iter().zip(joints).enumerate() {
            let (unit, hi) = match j.model.map(|m| m.current_unit()) {
                Some(CurrentUnit::LoadPermille) => ("%", 100.0),
                Some(CurrentUnit::MilliAmps(_)) => ("A", MAX_MAGNITUDE),
                None => ("(the unit of the joint's servo)", MAX_MAGNITUDE),
            };
            if !(finite_within(value) && value > 0.0 && value <= hi) {
                let field = match raw.contact_load {
                    Some(ContactLoad::PerJoint(_)) => format!("world.contact_load[{}]", i + 1),
                    _ => "world.contact_load".to_owned(),
                };
                return Err(self.invalid(
                    field,
                    FieldProblem::ContactLoad {
                        value,
                        joint: i + 1,
                        unit,
                        hi,
                    },
                ));
            }
        }
        let ms = raw.contact_ms.unwrap_or(DEFAULT_CONTACT_MS);
        if ms == 0 {
            return Err(self.invalid(
                "world.contact_ms",
                FieldProblem::OutOfRange {
                    value: 0,
                    expected: "must be at least 1: a load above its threshold for no time at all \
                               would stop the arm on every health read's noise",
                },
            ));
        }
        Ok(Some(Contact {
            load,
            hold: Duration::from_millis(ms.into()),
        }))
    }

    fn control(&self, raw: &RawControl) -> Result<Control, ConfigError> {
        // One message for every value outside the documented range, NaN and 0 included.
        let rate_hz = raw.rate_hz;
        if !(MIN_RATE_HZ..=MAX_RATE_HZ).contains(&rate_hz) {
            return Err(self.invalid(
                "control.rate_hz",
                FieldProblem::Outside {
                    value: rate_hz,
                    lo: MIN_RATE_HZ,
                    hi: MAX_RATE_HZ,
                },
            ));
        }
        let max_tip_accel_m_s2 =
            self.positive("control.max_tip_accel_m_s2", raw.max_tip_accel_m_s2)?;
        if raw.deadman_ms == 0 {
            return Err(self.invalid(
                "control.deadman_ms",
                FieldProblem::OutOfRange {
                    value: 0,
                    expected: "must be at least 1",
                },
            ));
        }
        for (field, value) in [
            ("control.read_every", raw.read_every),
            ("control.health_every", raw.health_every),
        ] {
            if value == 0 {
                return Err(self.invalid(
                    field,
                    FieldProblem::OutOfRange {
                        value: 0,
                        expected: "must be at least 1",
                    },
                ));
            }
        }
        let max_tip_speed_m_s =
            self.positive("control.max_tip_speed_m_s", raw.max_tip_speed_m_s)?;
        let max_joint_speed_rad_s =
            self.positive("control.max_joint_speed_rad_s", raw.max_joint_speed_rad_s)?;
        if raw.substeps.is_some() {
            return Err(self.invalid(
                "control.substeps",
                FieldProblem::Removed {
                    why: "every tick resolves its step in one straight step (the controller \
                          never read this key)",
                },
            ));
        }
        let max_silence = self.max_silence(raw, rate_hz)?;
        if raw.max_missed_reads.is_none() {
            // A missed read counts as silent since the read before it (`silence()` in the
            // daemon's health): a budget within one read interval is spent by one miss.
            let interval = Duration::from_secs_f64(1.0 / rate_hz).checked_mul(raw.read_every);
            if interval.is_none_or(|i| i >= max_silence) {
                return Err(self.invalid(
                    "control.max_silence_ms",
                    FieldProblem::SilenceWithinRead {
                        max_silence_ms: max_silence.as_millis(),
                        given: raw.max_silence_ms.is_some(),
                        read_every: raw.read_every,
                        rate_hz,
                        interval_ms: f64::from(raw.read_every) * 1e3 / rate_hz,
                    },
                ));
            }
        }
        let realtime_priority = match raw.realtime_priority {
            None => None,
            Some(p) => match u8::try_from(p) {
                Ok(p) if crate::beside::REALTIME_PRIORITIES.contains(&p) => Some(p),
                _ => {
                    return Err(self.invalid(
                        "control.realtime_priority",
                        FieldProblem::OutOfRange {
                            value: p,
                            expected: "must be 1 to 99 (SCHED_FIFO's priorities)",
                        },
                    ))
                }
            },
        };
        Ok(Control {
            rate_hz,
            strategy: match raw.strategy {
                StrategyName::Sequential => Strategy::Sequential,
                StrategyName::Overall => Strategy::Overall,
            },
            max_tip_speed_m_s,
            max_joint_speed_rad_s,
            max_tip_accel_m_s2,
            deadman: Duration::from_millis(raw.deadman_ms.into()),
            read_every: raw.read_every,
            max_silence,
            health_every: raw.health_every,
            realtime_priority,
        })
    }

    /// `control.max_silence_ms`, or the deprecated `control.max_missed_reads` converted at the
    /// read rate (`read_every` ticks at `rate_hz`), with a warning in the log.
    fn max_silence(&self, raw: &RawControl, rate_hz: f64) -> Result<Duration, ConfigError> {
        match (raw.max_silence_ms, raw.max_missed_reads) {
            (Some(_), Some(_)) => Err(self.invalid(
                "control.max_missed_reads",
                FieldProblem::Replaced {
                    other: "control.max_silence_ms",
                },
            )),
            (Some(0), None) => Err(self.invalid(
                "control.max_silence_ms",
                FieldProblem::OutOfRange {
                    value: 0,
                    expected: "must be at least 1",
                },
            )),
            (Some(ms), None) => Ok(Duration::from_millis(ms.into())),
            (None, Some(0)) => Err(self.invalid(
                "control.max_missed_reads",
                FieldProblem::OutOfRange {
                    value: 0,
                    expected: "must be at least 1",
                },
            )),
            (None, Some(reads)) => {
                let read_period_s = f64::from(raw.read_every) / rate_hz;
                // Read as `max_silence_ms`, so within what that field holds.
                let silence_s = f64::from(reads) * read_period_s;
                if silence_s > f64::from(u32::MAX) / 1e3 {
                    return Err(self.invalid(
                        "control.max_missed_reads",
                        FieldProblem::OutOfRange {
                            value: reads.into(),
                            expected: "reads at the read rate (read_every / rate_hz) last \
                                       longer than control.max_silence_ms can say \
                                       (4294967295 ms)",
                        },
                    ));
                }
                let silence = Duration::from_secs_f64(silence_s);
                tracing::warn!(
                    "{}: control.max_missed_reads = {reads} is deprecated; read as \
                     control.max_silence_ms = {} (that many reads at the read rate): \
                     write that instead",
                    self.path.display(),
                    silence.as_millis()
                );
                Ok(silence)
            }
            (None, None) => Ok(Duration::from_millis(DEFAULT_MAX_SILENCE_MS.into())),
        }
    }

    fn server(&self, raw: RawServer) -> Result<Server, ConfigError> {
        let listen = raw.listen.parse::<SocketAddr>().map_err(|e| {
            self.invalid(
                "server.listen",
                FieldProblem::BadAddress {
                    value: raw.listen.clone(),
                    reason: e.to_string(),
                },
            )
        })?;
        if raw.max_clients == 0 {
            return Err(self.invalid(
                "server.max_clients",
                FieldProblem::OutOfRange {
                    value: 0,
                    expected: "must be at least 1",
                },
            ));
        }
        if raw
            .token_file
            .as_ref()
            .is_some_and(|f| f.as_os_str().to_string_lossy().trim().is_empty())
        {
            return Err(self.invalid("server.token_file", FieldProblem::EmptyFileName));
        }
        let token_file = raw.token_file.map(|f| self.relative_to_file(f));
        Ok(Server {
            listen,
            token_file,
            max_clients: raw.max_clients,
        })
    }
}

#[cfg(test)]
mod tests;
