//! The daemon's wire format: JSON lines over TCP, one set of types for the daemon and every
//! client, each written and read by the same type.
//!
//! One request per line, `{"cmd": NAME, "id": ANY?, ...}` ([`Request`], [`Cmd`]; [`parse()`]
//! reads one, [`request_line`] writes one); one reply per request,
//! `{"id": ..., "ok": true, ...fields}` ([`Reply`], [`Fields`]) or
//! `{"id": ..., "ok": false, "error": {"code", "message"}}` ([`Rejection`], [`Code`]).
//! Besides replies a client receives only `{"type": "telemetry", ...}` lines ([`Status`]: a
//! [`Telemetry`] snapshot and who is in control; after `subscribe`) and
//! `{"type": "event", "event": NAME, "cmd_id": ID?, ...}` lines ([`Event`], [`What`]);
//! [`read_line`] reads any of them. Joints are numbered from 1 on the wire
//! (`joint_1..joint_n`); the daemon numbers them from 0 inside.
//!
//! Where a command goes is decided here, once: [`Cmd::need`] (what the arbiter asks of its
//! sender) and [`Cmd::route`] (answered by the socket side, [`SessionCmd`], or applied by the
//! loop, [`LoopCmd`]) are exhaustive matches, as are parsing and writing.

mod cmd;
mod event;
mod parse;
mod read;
mod reply;
mod telemetry;
mod values;
mod world;
mod write;

use std::fmt;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

pub use cmd::{Cmd, CmdName, LoopCmd, Motion, Need, Request, Route, SessionCmd, COMMANDS};
pub use event::{Event, EventKind, FaultChange, StopReason, What};
pub use parse::{
    checked_point, parse, parse_obstacles, strict_json, MAX_PATH_POINTS, MIN_SPEED_M_S,
};
pub use read::{read_line, ReadError, ServerLine};
pub use reply::{
    Admitted, Answer, Applied, Fields, PoseNotClear, Rebooted, Released, Reply, ReplyLine,
    Subscribed, TookControl, TorqueOff, Unconfirmed, Unsubscribed, WorldChanged,
};
pub use telemetry::{
    CommandInfo, Counters, Describe, FaultInfo, FaultKind, LoadUnit, Outcome, State, Status,
    Telemetry,
};
pub use values::{strategy_named, STRATEGIES};
pub use world::{world_ids, world_rejection, Wire, WorldInfo};
pub use write::{error_line, event_line, ok_line, reply_line, request_line, telemetry_line};

/// The version of this wire format, reported by `describe`.
pub const PROTOCOL_VERSION: u32 = 1;

/// The longest request line accepted, bytes (newline excluded): 1 MiB.
///
/// Sized so that the longest `path` ([`MAX_PATH_POINTS`] points) fits however its numbers are
/// written: a coordinate at full precision takes at most 24 characters
/// (`-1.2345678901234567e-300`), a point with its brackets and separators at most 54 bytes
/// (`[x, y], ` with spaces), so 10,000 points take at most 540,000 bytes, about half the
/// line. The server's line reader holds up to this much per client, so `[server]
/// max_clients` connections hold at most that many MiB between them.
pub const MAX_LINE: usize = 1024 * 1024;

/// The largest magnitude a number in a request may have.
pub const MAX_ARG: f64 = 1e6;

/// A client's connection, numbered by the server from 1 in accept order.
pub type ClientId = u64;

/// A request id as the client sent it (any JSON value), shared without copying.
pub type RequestId = Arc<Value>;

/// Why a request was refused: the `code` of an error reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum Code {
    /// Not JSON, not an object, a number JSON cannot hold (such as 1e999), or an object (at any
    /// depth) with the same key twice.
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
    /// The loop's command queue is full, or this connection already has its share of it
    /// waiting; or a command that would move the arm or switch its torque while a `reboot` is
    /// under way. Send again.
    Busy,
    /// A `velocity` that waited longer than the deadman before the loop could apply it (the
    /// loop was held up); it was not applied.
    Stale,
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
            Code::Stale => "stale",
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, thiserror::Error)]
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

#[cfg(test)]
mod tests;
