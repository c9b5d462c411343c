//! What the loop reports: the telemetry snapshot ([`Telemetry`]) and the values it is made of,
//! the `status` reply ([`Status`]: a snapshot and who is in control), and the arm's description
//! ([`Describe`]).
//!
//! Reading tolerates what a newer or older daemon may do within the same protocol version: a
//! field this version does not know is ignored, one that is missing takes its default, and a
//! number written as `null` (not finite) reads back as NaN.

use std::borrow::{Borrow, BorrowMut};
use std::fmt;
use std::ops::{Deref, DerefMut};

use serde::{Deserialize, Serialize};

use super::values;
use super::{ClientId, CmdName, RequestId, PROTOCOL_VERSION};
use crate::chain::{Chain, ChainError, JointLimit, Vec2, MAX_MAGNITUDE};
use crate::resolve::Strategy;

/// The arm's state as telemetry reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum State {
    /// A command is moving the tip or the joints.
    Moving,
    /// At rest, holding the last goal.
    #[default]
    Holding,
    /// Decelerating after `stop` or a lapsed deadman.
    Stopping,
    /// The estop latch is set.
    Estop,
    /// A fault holds the arm.
    Fault,
    /// Torque is off by command (`torque` with `on: false`): the arm is limp and the goals
    /// frozen until `torque` on.
    TorqueOff,
}

impl State {
    /// The state as the wire writes it.
    pub const fn as_str(self) -> &'static str {
        match self {
            State::Moving => "moving",
            State::Holding => "holding",
            State::Stopping => "stopping",
            State::Estop => "estop",
            State::Fault => "fault",
            State::TorqueOff => "torque_off",
        }
    }
}

impl fmt::Display for State {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl PartialEq<str> for State {
    fn eq(&self, other: &str) -> bool {
        self.as_str() == other
    }
}

impl PartialEq<&str> for State {
    fn eq(&self, other: &&str) -> bool {
        self.as_str() == *other
    }
}

/// How the active or last motion command stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// It is running.
    Active,
    /// It reached its target.
    Arrived,
    /// It ended short of its target: out of reach, or held by a joint limit or its own links.
    Saturated,
    /// Another command replaced it.
    Preempted,
    /// A `stop`, its deadman, `torque` off or a `reboot` ended it.
    Stopped,
    /// An `estop` ended it.
    Estop,
    /// A fault ended it.
    Fault,
    /// A goto or path whose body could not follow the tip without losing its clearance from
    /// an obstacle, or whose tip made no headway: it ended, the arm holding clear (a `blocked`
    /// event names the link and the obstacle).
    Blocked,
}

/// The active or last motion command, as telemetry reports it: accumulated per tick.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CommandInfo {
    /// Its `cmd` name.
    pub kind: CmdName,
    /// Its request id, when it had one.
    #[serde(default)]
    pub id: Option<RequestId>,
    /// How it stands.
    pub outcome: Outcome,
    /// Fastest joint speed while it ran, rad/s.
    #[serde(default, deserialize_with = "values::number::deserialize")]
    pub peak_joint_speed_rad_s: f64,
    /// Metric 3 travelled while it ran (sum over ticks of the squared joint steps), rad².
    #[serde(default, deserialize_with = "values::number::deserialize")]
    pub m3_rad2: f64,
}

/// What a fault or a warning is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// No valid reply for `control.max_silence_ms`.
    Silent,
    /// The servo's alert flag: a latched hardware error (`detail` names it).
    HardwareError,
    /// The serial port failed.
    Port,
    /// The Bus Watchdog fired and was recovered.
    Watchdog,
    /// The servo answered again with its RAM reset to the defaults (it lost power): its
    /// settings were written again, torque left off, the arm latched until `reset`.
    PowerLoss,
    /// A joint's load stayed above its `[world] contact_load` threshold for `contact_ms`: the
    /// arm met something (`detail` names the load and the threshold); latched as an estop
    /// until `reset`.
    Contact,
    /// A warning: the temperature is near the servo's limit.
    Temperature,
    /// A warning: the input voltage is near the servo's limits.
    Voltage,
}

impl FaultKind {
    /// The kind as the wire writes it.
    pub const fn as_str(self) -> &'static str {
        match self {
            FaultKind::Silent => "silent",
            FaultKind::HardwareError => "hardware_error",
            FaultKind::Port => "port",
            FaultKind::Watchdog => "watchdog",
            FaultKind::PowerLoss => "power_loss",
            FaultKind::Contact => "contact",
            FaultKind::Temperature => "temperature",
            FaultKind::Voltage => "voltage",
        }
    }

    /// Whether it is a health warning (nothing holds for it) rather than a fault.
    pub const fn is_warning(self) -> bool {
        match self {
            FaultKind::Temperature | FaultKind::Voltage => true,
            FaultKind::Silent
            | FaultKind::HardwareError
            | FaultKind::Port
            | FaultKind::Watchdog
            | FaultKind::PowerLoss
            | FaultKind::Contact => false,
        }
    }
}

impl fmt::Display for FaultKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A fault or a warning, active or (in an event) raised, cleared or recovered. A servo's
/// carries its `id` and `joint` and the `port` it is on; the port's own (`kind: "port"`)
/// carries `port` with `id` and `joint` null.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaultInfo {
    /// Servo id (`None` for the port itself).
    #[serde(default)]
    pub id: Option<u8>,
    /// Joint number, from 1 (`None` for the port itself).
    #[serde(default)]
    pub joint: Option<usize>,
    /// The serial port (its path) the fault is about or the servo is on; `None` when the daemon
    /// does not know it (a bus handed to it without a path).
    #[serde(default)]
    pub port: Option<String>,
    /// What kind.
    pub kind: FaultKind,
    /// The tick of its first symptom (the first missed read, the alert seen, the stall).
    pub since_tick: u64,
    /// Details for a person.
    #[serde(default)]
    pub detail: String,
}

impl FaultInfo {
    /// A fault or warning of servo `id` driving joint `joint`, on `port`.
    pub fn servo(
        id: u8,
        joint: usize,
        port: Option<String>,
        kind: FaultKind,
        since_tick: u64,
        detail: String,
    ) -> FaultInfo {
        FaultInfo {
            id: Some(id),
            joint: Some(joint),
            port,
            kind,
            since_tick,
            detail,
        }
    }

    /// A fault of the port itself.
    pub fn port(port: Option<String>, since_tick: u64, detail: String) -> FaultInfo {
        FaultInfo {
            id: None,
            joint: None,
            port,
            kind: FaultKind::Port,
            since_tick,
            detail,
        }
    }
}

impl fmt::Display for FaultInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.id, self.joint, self.port.as_deref()) {
            (Some(id), Some(joint), _) => write!(
                f,
                "servo {id} (joint {joint}): {} ({})",
                self.kind, self.detail
            ),
            (Some(id), None, _) => write!(f, "servo {id}: {} ({})", self.kind, self.detail),
            (None, _, Some(port)) => write!(f, "port {port}: {} ({})", self.kind, self.detail),
            (None, _, None) => write!(f, "port: {} ({})", self.kind, self.detail),
        }
    }
}

/// Counters since start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(default)]
pub struct Counters {
    /// Status replies that never came.
    pub dropped: u64,
    /// Status replies that came damaged (bad CRC or length).
    pub corrupted: u64,
    /// Exchanges sent again after a transient error.
    pub retries: u64,
    /// Ticks whose goals the final per-joint clamp shortened.
    pub clamped: u64,
}

/// The unit of a joint's `load`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum LoadUnit {
    /// Present Load, % of the maximum torque (XL430, XC430).
    #[serde(rename = "percent")]
    Percent,
    /// Present Current, A (XM430, XH430, XM540, XL330).
    #[serde(rename = "A")]
    Amps,
}

/// One telemetry snapshot: what the loop did in its last tick. `status` replies carry the same
/// fields under the same names. SI units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Telemetry {
    /// Ticks since start.
    pub tick: u64,
    /// `tick` times the nominal period, s.
    #[serde(deserialize_with = "values::number::deserialize")]
    pub t_s: f64,
    /// The arm's state.
    pub state: State,
    /// The active strategy.
    #[serde(with = "values::strategy")]
    pub strategy: Strategy,
    /// This tick's motion reference for the tip, m.
    #[serde(deserialize_with = "values::point::deserialize")]
    pub tip_ref: [f64; 2],
    /// The tip of the commanded pose, m.
    #[serde(deserialize_with = "values::point::deserialize")]
    pub tip: [f64; 2],
    /// The tip of the measured pose, m.
    #[serde(deserialize_with = "values::point::deserialize")]
    pub tip_meas: [f64; 2],
    /// Where the active command is going, m.
    #[serde(deserialize_with = "values::optional_point::deserialize")]
    pub target: Option<[f64; 2]>,
    /// The commanded pose (the goals sent), rad.
    #[serde(deserialize_with = "values::numbers::deserialize")]
    pub theta_cmd: Vec<f64>,
    /// The measured pose, rad.
    #[serde(deserialize_with = "values::numbers::deserialize")]
    pub theta_meas: Vec<f64>,
    /// The measured joint velocities, rad/s.
    #[serde(deserialize_with = "values::numbers::deserialize")]
    pub omega_meas: Vec<f64>,
    /// `|tip_ref - tip_meas|`, m.
    #[serde(deserialize_with = "values::number::deserialize")]
    pub tracking_error_m: f64,
    /// Whether this tick's reference could not be resolved (out of reach, past a joint limit, or
    /// folding the arm onto itself) and the tip stopped short.
    pub saturated: bool,
    /// Whether this tick's step was cut short because the links would have crossed.
    pub self_collision: bool,
    /// The clearance of the commanded pose (`theta_cmd`) among the obstacles: the least gap
    /// between a link's capsule and an obstacle, m, negative when one overlaps; `None`
    /// (`null`) when the world has no obstacles.
    pub min_clearance_m: Option<f64>,
    /// Whether this tick's step was cut short to keep every link clear of the obstacles (or,
    /// from a pose not clear, to shrink no link's clearance).
    pub blocked: bool,
    /// The active or last motion command.
    pub command: Option<CommandInfo>,
    /// This tick's resolve time, µs.
    #[serde(deserialize_with = "values::number::deserialize")]
    pub solve_us: f64,
    /// Ticks per second over the last 1000 ticks.
    #[serde(deserialize_with = "values::number::deserialize")]
    pub loop_hz: f64,
    /// 99th percentile of the tick's working time over the last 1000 ticks, µs.
    #[serde(deserialize_with = "values::number::deserialize")]
    pub tick_p99_us: f64,
    /// Periods missed because a tick ran past its own, since start.
    pub overruns: u64,
    /// The loop cannot hold its configured rate: more than half the last 1000 ticks ran past
    /// their period, and it runs back to back at `loop_hz`, the rate its work allows.
    pub behind: bool,
    /// Fastest joint speed commanded since start or `reset_stats`, rad/s.
    #[serde(deserialize_with = "values::number::deserialize")]
    pub peak_joint_speed_rad_s: f64,
    /// Metric 3 travelled since start or `reset_stats`, rad².
    #[serde(deserialize_with = "values::number::deserialize")]
    pub m3_total_rad2: f64,
    /// The active faults: while there is one, the arm holds (`state` is `fault`).
    pub faults: Vec<FaultInfo>,
    /// The active health warnings (temperature or input voltage near the servo's own
    /// shutdown thresholds): nothing holds for them.
    pub warnings: Vec<FaultInfo>,
    /// Whether the servos' torque is on (off after `torque {on: false}`, or an `estop` where
    /// `[bus] on_exit = "torque_off"`).
    pub torque: bool,
    /// Present Temperature per joint, °C, as of `health_tick`.
    #[serde(deserialize_with = "values::numbers::deserialize")]
    pub temperature_c: Vec<f64>,
    /// Present Input Voltage per joint, V, as of `health_tick`.
    #[serde(deserialize_with = "values::numbers::deserialize")]
    pub voltage_v: Vec<f64>,
    /// Present Load or Current per joint, in the joint's frame (positive = the positive
    /// direction), in the unit `load_unit` names, as of `health_tick`.
    #[serde(deserialize_with = "values::numbers::deserialize")]
    pub load: Vec<f64>,
    /// Per joint, the unit of `load`.
    pub load_unit: Vec<LoadUnit>,
    /// The tick of the last health read (every `control.health_every`-th tick); 0 before it.
    pub health_tick: u64,
    /// Counters since start.
    pub counters: Counters,
}

impl Default for Telemetry {
    /// The snapshot before the first tick: nothing measured, the first strategy listed.
    fn default() -> Self {
        Telemetry {
            tick: 0,
            t_s: 0.0,
            state: State::default(),
            strategy: values::STRATEGIES[0],
            tip_ref: [0.0; 2],
            tip: [0.0; 2],
            tip_meas: [0.0; 2],
            target: None,
            theta_cmd: Vec::new(),
            theta_meas: Vec::new(),
            omega_meas: Vec::new(),
            tracking_error_m: 0.0,
            saturated: false,
            self_collision: false,
            min_clearance_m: None,
            blocked: false,
            command: None,
            solve_us: 0.0,
            loop_hz: 0.0,
            tick_p99_us: 0.0,
            overruns: 0,
            behind: false,
            peak_joint_speed_rad_s: 0.0,
            m3_total_rad2: 0.0,
            faults: Vec::new(),
            warnings: Vec::new(),
            torque: false,
            temperature_c: Vec::new(),
            voltage_v: Vec::new(),
            load: Vec::new(),
            load_unit: Vec::new(),
            health_tick: 0,
            counters: Counters::default(),
        }
    }
}

impl Telemetry {
    /// Every field under its wire name: the fields of a `status` reply (without who is in
    /// control).
    pub fn to_fields(&self) -> serde_json::Map<String, serde_json::Value> {
        super::write::fields_of(self)
    }
}

/// A telemetry snapshot as a client receives it (a telemetry line, a `status` reply): the
/// snapshot, and who is in control, which the socket side adds (the loop does not know).
///
/// `T` is the snapshot, owned when read, borrowed when written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Status<T = Telemetry> {
    /// The loop's snapshot.
    #[serde(flatten)]
    pub telemetry: T,
    /// The client in control (`None`: nobody).
    #[serde(default)]
    pub controller: Option<ClientId>,
    /// Whether the client reading it is in control.
    #[serde(default)]
    pub in_control: bool,
}

impl<T> Status<T> {
    /// `telemetry` with nobody named in control: what the loop answers, before the socket side
    /// says who is.
    pub fn of(telemetry: T) -> Self {
        Status {
            telemetry,
            controller: None,
            in_control: false,
        }
    }
}

/// A status is read as the snapshot it carries (`status.tip_meas`).
impl<T: Borrow<Telemetry>> Deref for Status<T> {
    type Target = Telemetry;

    fn deref(&self) -> &Telemetry {
        self.telemetry.borrow()
    }
}

impl<T: BorrowMut<Telemetry>> DerefMut for Status<T> {
    fn deref_mut(&mut self) -> &mut Telemetry {
        self.telemetry.borrow_mut()
    }
}

/// What a remote UI needs to draw the arm: the reply to `describe`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default)]
pub struct Describe {
    /// Link lengths, base to tip, m.
    pub links_m: Vec<f64>,
    /// Base pose: x, y (m), heading (rad).
    pub base: [f64; 3],
    /// Lower joint limits, rad (the lowest `f64` for a joint without limits).
    pub min_rad: Vec<f64>,
    /// Upper joint limits, rad (the highest `f64` for a joint without limits).
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
    #[serde(with = "values::strategies")]
    pub strategies: Vec<Strategy>,
    /// [`PROTOCOL_VERSION`].
    pub protocol_version: u32,
    /// Half the width of every link (the radius of the capsule each link is), m.
    pub link_radius_m: f64,
    /// The gap every link keeps from every obstacle, m.
    pub clearance_m: f64,
    /// How the loop reads the servos: `"fast"` (Fast Sync Read) or `"sync"` (Sync Read), as
    /// bring-up chose from `[bus] read` and the servos' firmware, `"mixed"` when the ports of
    /// a bus of several differ; empty when not known.
    pub read: String,
}

impl Describe {
    /// Every field under its wire name: the fields of a `describe` reply.
    pub fn to_fields(&self) -> serde_json::Map<String, serde_json::Value> {
        super::write::fields_of(self)
    }

    /// The description of `chain` (its links, base and limits; a joint without limits as the
    /// lowest and highest `f64`) with the rest as given, and no world (link radius and
    /// clearance 0; [`Describe::with_world`] sets them).
    pub fn of_chain(
        chain: &Chain,
        ids: Vec<u8>,
        models: Vec<String>,
        home_rad: Vec<f64>,
        rate_hz: f64,
    ) -> Describe {
        let base = chain.base();
        let (min_rad, max_rad) = chain
            .limits()
            .iter()
            .map(|l| l.map_or((f64::MIN, f64::MAX), |l| (l.lo, l.hi)))
            .unzip();
        Describe {
            links_m: chain.links().to_vec(),
            base: [base.x, base.y, chain.heading()],
            min_rad,
            max_rad,
            ids,
            models,
            home_rad,
            rate_hz,
            strategies: values::STRATEGIES.to_vec(),
            protocol_version: PROTOCOL_VERSION,
            link_radius_m: 0.0,
            clearance_m: 0.0,
            read: String::new(),
        }
    }

    /// The description with the link radius and clearance of `world`.
    pub fn with_world(self, world: &crate::world::World) -> Describe {
        Describe {
            link_radius_m: world.link_radius_m(),
            clearance_m: world.clearance_m(),
            ..self
        }
    }

    /// The chain it describes, for forward kinematics on the client's side. A joint whose
    /// limits are not finite (or beyond what a chain accepts) has none, as the daemon writes
    /// a joint without limits.
    pub fn chain(&self) -> Result<Chain, ChainError> {
        let within = |x: f64| x.is_finite() && x.abs() <= MAX_MAGNITUDE;
        let limits = if self.min_rad.is_empty() && self.max_rad.is_empty() {
            Vec::new()
        } else {
            (0..self.links_m.len())
                .map(|i| match (self.min_rad.get(i), self.max_rad.get(i)) {
                    (Some(&lo), Some(&hi)) if within(lo) && within(hi) => {
                        Some(JointLimit { lo, hi })
                    }
                    _ => None,
                })
                .collect()
        };
        let [x, y, heading] = self.base;
        Chain::new(self.links_m.clone(), Vec2::new(x, y), heading, limits)
    }
}
