//! The daemon's wire format: JSON lines over TCP.
//!
//! One request per line, `{"cmd": NAME, "id": ANY?, ...}`; one reply per request,
//! `{"id": ..., "ok": true, ...fields}` or `{"id": ..., "ok": false, "error": {"code", "message"}}`.
//! Besides replies a client receives only `{"type": "telemetry", ...}` lines (after `subscribe`)
//! and `{"type": "event", "event": NAME, "cmd_id": ID?, ...}` lines. Joints are numbered from 1
//! on the wire (`joint_1..joint_n`); the daemon numbers them from 0 inside.
//!
//! This module owns the types shared by the daemon, the one-shot clients and the teleop UI:
//! the requests ([`Cmd`]), the error codes ([`Code`]), the telemetry snapshot ([`Telemetry`]),
//! the arm's description ([`Describe`]) and the events ([`Event`]); [`parse`] reads a request
//! line and the `*_line` functions write the lines a client receives.

mod parse;
mod write;

use std::fmt;
use std::sync::Arc;

use serde::Serialize;
use serde_json::Value;

pub use parse::{checked_point, parse, Request, COMMANDS, MAX_PATH_POINTS};
pub use write::{error_line, event_line, ok_line, request_line, telemetry_line};

/// The version of this wire format, reported by `describe`.
pub const PROTOCOL_VERSION: u32 = 1;

/// The longest request line accepted, bytes (newline excluded).
pub const MAX_LINE: usize = 64 * 1024;

/// The largest magnitude a number in a request may have.
pub const MAX_ARG: f64 = 1e6;

/// A client's connection, numbered by the server from 1 in accept order.
pub type ClientId = u64;

/// A request id as the client sent it (any JSON value), shared without copying.
pub type RequestId = Arc<Value>;

/// What a client asks for: the `cmd` of a request line with its arguments, validated (finite,
/// within [`MAX_ARG`], lengths and joint numbers checked against the arm).
#[derive(Debug, Clone, PartialEq)]
pub enum Cmd {
    /// The arm's geometry and the daemon's capabilities.
    Describe,
    /// The latest telemetry, as a reply.
    Status,
    /// Tip along a straight line to `target`, m, at `speed` m/s (default: the tip speed limit).
    Goto {
        /// Target tip position, m.
        target: [f64; 2],
        /// Tip speed, m/s.
        speed: Option<f64>,
    },
    /// A joint-space move to `theta`, rad.
    GotoJoints {
        /// Target pose, one angle per joint, rad.
        theta: Vec<f64>,
    },
    /// Tip along a polyline, stopping at each corner.
    Path {
        /// Corner points, m.
        points: Vec<[f64; 2]>,
        /// Tip speed, m/s.
        speed: Option<f64>,
    },
    /// A tip velocity, m/s, that lapses after the deadman unless renewed.
    Velocity {
        /// Tip velocity, m/s.
        v: [f64; 2],
    },
    /// One joint at a rate, rad/s, with the same deadman.
    Jog {
        /// Joint number, from 1.
        joint: usize,
        /// Joint rate, rad/s.
        rad_s: f64,
    },
    /// Decelerate to rest and hold.
    Stop,
    /// Freeze and torque off (or hold), latched until `reset`.
    Estop,
    /// Leave estop: goal := measured pose, torque on, holding.
    Reset,
    /// A joint-space move to the configured home pose.
    Home,
    /// Switch the redundancy-resolution strategy.
    Strategy {
        /// The new strategy.
        name: crate::resolve::Strategy,
    },
    /// Telemetry lines at `rate_hz` (at most the loop rate).
    Subscribe {
        /// Lines per second.
        rate_hz: f64,
    },
    /// No more telemetry lines.
    Unsubscribe,
    /// Zero the statistics kept since start (peak joint speed, metric 3 travelled, tick times).
    ResetStats,
    /// Become the client in control (the holder is told with a `control` event).
    TakeControl,
    /// Stop being the client in control.
    Release,
    /// The first line of a client when `[server] token_file` is set.
    Auth {
        /// The token, compared in constant time.
        token: String,
    },
    /// Torque on (goal := measured pose first) or off for every servo.
    Torque {
        /// On or off.
        on: bool,
    },
    /// Reboot servos (all when `ids` is absent) to clear a hardware error, then recover.
    Reboot {
        /// Servo ids.
        ids: Option<Vec<u8>>,
    },
}

impl Cmd {
    /// The name a request uses for it.
    pub fn name(&self) -> &'static str {
        match self {
            Cmd::Describe => "describe",
            Cmd::Status => "status",
            Cmd::Goto { .. } => "goto",
            Cmd::GotoJoints { .. } => "goto_joints",
            Cmd::Path { .. } => "path",
            Cmd::Velocity { .. } => "velocity",
            Cmd::Jog { .. } => "jog",
            Cmd::Stop => "stop",
            Cmd::Estop => "estop",
            Cmd::Reset => "reset",
            Cmd::Home => "home",
            Cmd::Strategy { .. } => "strategy",
            Cmd::Subscribe { .. } => "subscribe",
            Cmd::Unsubscribe => "unsubscribe",
            Cmd::ResetStats => "reset_stats",
            Cmd::TakeControl => "take_control",
            Cmd::Release => "release",
            Cmd::Auth { .. } => "auth",
            Cmd::Torque { .. } => "torque",
            Cmd::Reboot { .. } => "reboot",
        }
    }
}

/// Why a request was refused: the `code` of an error reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum Code {
    /// Not JSON, not an object, or a number JSON cannot hold (such as 1e999).
    BadJson,
    /// A `cmd` this daemon does not know.
    UnknownCmd,
    /// An argument missing, unknown, of the wrong type or length, non-finite, over [`MAX_ARG`],
    /// or a joint number out of range; the message names the field.
    BadArg,
    /// A line over [`MAX_LINE`] bytes; it was discarded, the connection lives.
    LineTooLong,
    /// A motion command while the estop latch is set.
    Estopped,
    /// A `goto_joints` pose outside the joint limits.
    Unreachable,
    /// The loop's command queue is full; send again.
    Busy,
    /// The daemon is stopping.
    ShuttingDown,
    /// A command that needs control, from a client that does not hold it.
    NotInControl,
    /// No `auth` first line, or a wrong token, where the daemon asks for one.
    Unauthorized,
    /// The arm holds for a fault; `status` names it (`reboot` or recovery clears it).
    Fault,
    /// The daemon already serves as many clients as it may; the connection is closed.
    TooManyClients,
}

impl Code {
    /// The code as it appears on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            Code::BadJson => "bad_json",
            Code::UnknownCmd => "unknown_cmd",
            Code::BadArg => "bad_arg",
            Code::LineTooLong => "line_too_long",
            Code::Estopped => "estopped",
            Code::Unreachable => "unreachable",
            Code::Busy => "busy",
            Code::ShuttingDown => "shutting_down",
            Code::NotInControl => "not_in_control",
            Code::Unauthorized => "unauthorized",
            Code::Fault => "fault",
            Code::TooManyClients => "too_many_clients",
        }
    }
}

impl fmt::Display for Code {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A refused request: the reply's `error`.
#[derive(Debug, Clone, PartialEq, Serialize, thiserror::Error)]
#[error("{code}: {message}")]
pub struct Rejection {
    /// The code.
    pub code: Code,
    /// What was wrong, naming the field and the value.
    pub message: String,
}

impl Rejection {
    /// A rejection with this code and message.
    pub fn new(code: Code, message: impl Into<String>) -> Self {
        Rejection {
            code,
            message: message.into(),
        }
    }
}

/// The arm's state as telemetry reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
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
}

/// The active or last motion command, as telemetry reports it: accumulated per tick.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CommandInfo {
    /// Its `cmd` name.
    pub kind: &'static str,
    /// Its request id, when it had one.
    pub id: Option<RequestId>,
    /// `active`, `arrived`, `saturated`, `preempted`, `stopped` or `estop`.
    pub outcome: &'static str,
    /// Fastest joint speed while it ran, rad/s.
    pub peak_joint_speed_rad_s: f64,
    /// Metric 3 travelled while it ran (sum over ticks of the squared joint steps), rad².
    pub m3_rad2: f64,
}

/// A fault or a warning, active or (in an event) raised, cleared or recovered.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FaultInfo {
    /// Servo id (0 for the port itself).
    pub id: u8,
    /// Joint number, from 1 (0 for the port itself).
    pub joint: usize,
    /// What kind: `silent` (no valid reply for `control.max_silence_ms`),
    /// `hardware_error` (the servo's alert flag; `detail` names the error), `port` (the serial
    /// port failed), `watchdog` (the Bus Watchdog fired and was recovered); for warnings
    /// `temperature` or `voltage`.
    pub kind: &'static str,
    /// The tick of its first symptom (the first missed read, the alert seen, the stall).
    pub since_tick: u64,
    /// Details for a person.
    pub detail: String,
}

/// Counters since start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
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

/// One telemetry snapshot: what the loop did in its last tick. `status` replies carry the same
/// fields under the same names. SI units.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct Telemetry {
    /// Ticks since start.
    pub tick: u64,
    /// `tick` times the nominal period, s.
    pub t_s: f64,
    /// The arm's state.
    pub state: State,
    /// The active strategy's name.
    pub strategy: &'static str,
    /// This tick's motion reference for the tip, m.
    pub tip_ref: [f64; 2],
    /// The tip of the commanded pose, m.
    pub tip: [f64; 2],
    /// The tip of the measured pose, m.
    pub tip_meas: [f64; 2],
    /// Where the active command is going, m.
    pub target: Option<[f64; 2]>,
    /// The commanded pose (the goals sent), rad.
    pub theta_cmd: Vec<f64>,
    /// The measured pose, rad.
    pub theta_meas: Vec<f64>,
    /// The measured joint velocities, rad/s.
    pub omega_meas: Vec<f64>,
    /// `|tip_ref - tip_meas|`, m.
    pub tracking_error_m: f64,
    /// Whether this tick's reference was out of reach and the tip stopped short.
    pub saturated: bool,
    /// Whether this tick's step was cut short because the links would have crossed.
    pub self_collision: bool,
    /// The active or last motion command.
    pub command: Option<CommandInfo>,
    /// This tick's resolve time, µs.
    pub solve_us: f64,
    /// Ticks per second over the last 1000 ticks.
    pub loop_hz: f64,
    /// 99th percentile of the tick's working time over the last 1000 ticks, µs.
    pub tick_p99_us: f64,
    /// Ticks skipped because the previous one ran late, since start.
    pub overruns: u64,
    /// Fastest joint speed commanded since start or `reset_stats`, rad/s.
    pub peak_joint_speed_rad_s: f64,
    /// Metric 3 travelled since start or `reset_stats`, rad².
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
    pub temperature_c: Vec<f64>,
    /// Present Input Voltage per joint, V, as of `health_tick`.
    pub voltage_v: Vec<f64>,
    /// Present Load or Current per joint, in the joint's frame (positive = the positive
    /// direction), in the unit `load_unit` names, as of `health_tick`.
    pub load: Vec<f64>,
    /// Per joint, the unit of `load`: `"percent"` (Present Load, % of the maximum torque:
    /// XL430, XC430) or `"A"` (Present Current: XM430, XH430, XM540, XL330).
    pub load_unit: Vec<&'static str>,
    /// The tick of the last health read (every `control.health_every`-th tick); 0 before it.
    pub health_tick: u64,
    /// Counters since start.
    pub counters: Counters,
}

impl Telemetry {
    /// Every field under its wire name: the fields of a `status` reply.
    pub fn to_fields(&self) -> serde_json::Map<String, Value> {
        write::fields_of(self)
    }
}

/// What a remote UI needs to draw the arm: the reply to `describe`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Describe {
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
    pub models: Vec<&'static str>,
    /// The home pose, rad.
    pub home_rad: Vec<f64>,
    /// The loop rate, Hz.
    pub rate_hz: f64,
    /// The strategies `strategy` accepts.
    pub strategies: Vec<&'static str>,
    /// [`PROTOCOL_VERSION`].
    pub protocol_version: u32,
}

impl Describe {
    /// Every field under its wire name: the fields of a `describe` reply.
    pub fn to_fields(&self) -> serde_json::Map<String, Value> {
        write::fields_of(self)
    }
}

/// What an event line announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum EventKind {
    /// A goto, path, goto_joints or home reached its target.
    Arrived,
    /// A goto or path ended short of a target out of reach.
    Saturated,
    /// A motion command was replaced by another before it finished.
    Preempted,
    /// A stop, or a velocity or jog whose deadman lapsed, came to rest.
    Stopped,
    /// The estop latch was set.
    Estop,
    /// The estop latch was cleared.
    Reset,
    /// A fault was raised, cleared or recovered (`reason`; `fault` names the servo and why).
    Fault,
    /// A health warning began or ended (`reason` `raised` or `cleared`; `fault` names it).
    Warning,
    /// Who is in control changed.
    Control,
}

/// One event from the loop. Events about a command go to the client that sent it (`owner`);
/// the others go to every client.
#[derive(Debug, Clone, PartialEq)]
pub struct Event {
    /// The client whose command this concerns; `None` for everyone.
    pub owner: Option<ClientId>,
    /// The request id of the command it concerns.
    pub cmd_id: Option<RequestId>,
    /// What happened.
    pub kind: EventKind,
    /// The tick it happened in.
    pub tick: u64,
    /// The commanded tip at that tick, m.
    pub tip: [f64; 2],
    /// For `preempted`, the command that replaced it; for `stopped`, why (`stop`, `deadman`);
    /// for `fault` and `warning`, `raised`, `cleared` or `recovered`.
    pub reason: Option<&'static str>,
    /// For `fault` and `warning`: which servo, what kind, the details.
    pub fault: Option<FaultInfo>,
}
