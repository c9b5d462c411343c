//! Events: `{"type": "event", "event": NAME, "cmd_id": ID?, "tick": N, ...}` lines, what each
//! carries typed by its name ([`What`]).
//!
//! A name this version does not know (a newer daemon's) reads as [`What::Other`], not as an
//! error; a field it does not know is ignored.

use std::fmt;
use std::sync::Arc;

use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::{Map, Value};

use super::values;
use super::{ClientId, CmdName, FaultInfo, RequestId, WorldInfo};

/// An event's name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// A goto, path, goto_joints or home reached its target.
    Arrived,
    /// A goto or path ended short of its target: out of reach, or held by a joint at its limit
    /// or by the arm's own links.
    Saturated,
    /// A motion command was replaced by another before it finished.
    Preempted,
    /// A stop, or a velocity or jog whose deadman lapsed, came to rest; or torque off, a
    /// fault or a reboot ended a command.
    Stopped,
    /// The estop latch was set.
    Estop,
    /// The estop latch was cleared.
    Reset,
    /// A fault was raised, cleared or recovered.
    Fault,
    /// A health warning began or ended.
    Warning,
    /// Who is in control changed.
    Control,
    /// The daemon is shutting down: the connection closes once the loop has ended.
    ShuttingDown,
    /// The world changed (`set_world`, `add_obstacle`, `remove_obstacle`): the whole new world.
    World,
    /// The commanded pose is not clear of an obstacle (one was put onto the arm).
    NotClear,
    /// The commanded pose is clear again.
    Clear,
    /// A goto or path ended caught on an obstacle, or without headway.
    Blocked,
}

impl EventKind {
    /// Every event name.
    pub const ALL: [EventKind; 14] = [
        EventKind::Arrived,
        EventKind::Saturated,
        EventKind::Preempted,
        EventKind::Stopped,
        EventKind::Estop,
        EventKind::Reset,
        EventKind::Fault,
        EventKind::Warning,
        EventKind::Control,
        EventKind::ShuttingDown,
        EventKind::World,
        EventKind::NotClear,
        EventKind::Clear,
        EventKind::Blocked,
    ];

    /// The name as the wire writes it.
    pub const fn as_str(self) -> &'static str {
        match self {
            EventKind::Arrived => "arrived",
            EventKind::Saturated => "saturated",
            EventKind::Preempted => "preempted",
            EventKind::Stopped => "stopped",
            EventKind::Estop => "estop",
            EventKind::Reset => "reset",
            EventKind::Fault => "fault",
            EventKind::Warning => "warning",
            EventKind::Control => "control",
            EventKind::ShuttingDown => "shutting_down",
            EventKind::World => "world",
            EventKind::NotClear => "not_clear",
            EventKind::Clear => "clear",
            EventKind::Blocked => "blocked",
        }
    }

    /// The event of this name; `None` for a name this version does not know.
    pub fn from_name(name: &str) -> Option<EventKind> {
        EventKind::ALL.into_iter().find(|k| k.as_str() == name)
    }
}

impl fmt::Display for EventKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why a command came to rest or was cut short: the `reason` of a `stopped` event.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// A `stop`.
    Stop,
    /// A `velocity` or `jog` not renewed within the deadman.
    Deadman,
    /// A fault holds the arm.
    Fault,
    /// `torque` off.
    Torque,
    /// A `reboot`.
    Reboot,
    /// The daemon is shutting down: it brought the arm to rest.
    Shutdown,
    /// A world change put an obstacle onto the arm: it came to rest and holds.
    NotClear,
}

impl StopReason {
    /// The reason as the wire writes it.
    pub const fn as_str(self) -> &'static str {
        match self {
            StopReason::Stop => "stop",
            StopReason::Deadman => "deadman",
            StopReason::Fault => "fault",
            StopReason::Torque => "torque",
            StopReason::Reboot => "reboot",
            StopReason::Shutdown => "shutdown",
            StopReason::NotClear => "not_clear",
        }
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What became of a fault or a warning: the `reason` of a `fault` or `warning` event.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultChange {
    /// It began.
    Raised,
    /// It ended.
    Cleared,
    /// It was recovered from at once (a Bus Watchdog that fired).
    Recovered,
}

impl FaultChange {
    /// The reason as the wire writes it.
    pub const fn as_str(self) -> &'static str {
        match self {
            FaultChange::Raised => "raised",
            FaultChange::Cleared => "cleared",
            FaultChange::Recovered => "recovered",
        }
    }
}

impl fmt::Display for FaultChange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What an event announces, with what it carries; `tip` is the commanded tip at the event's
/// tick, m.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum What {
    /// The command reached its target.
    Arrived {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
    },
    /// The command ended short of its target: out of reach, or held by a joint at its limit or
    /// by the arm's own links.
    Saturated {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
    },
    /// The command was replaced before it finished.
    Preempted {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
        /// The command that replaced it.
        reason: CmdName,
    },
    /// The command came to rest, or was cut short.
    Stopped {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
        /// Why.
        reason: StopReason,
    },
    /// The estop latch was set.
    Estop {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
    },
    /// The estop latch was cleared.
    Reset {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
    },
    /// A fault was raised, cleared or recovered.
    Fault {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
        /// What became of it.
        reason: FaultChange,
        /// Which servo, what kind, the details.
        fault: FaultInfo,
    },
    /// A health warning began or ended.
    Warning {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
        /// What became of it.
        reason: FaultChange,
        /// Which servo, what kind, the details.
        fault: FaultInfo,
    },
    /// Who is in control changed.
    Control {
        /// The new holder (`None`: control is free).
        holder: Option<ClientId>,
        /// The holder before.
        previous: Option<ClientId>,
    },
    /// The daemon is shutting down (a signal, or its owner stopped it): the arm comes to rest
    /// (at once when a fault or the estop latch holds it), the servos are left as
    /// `[bus] on_exit` says, then the connections close.
    ShuttingDown {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
    },
    /// The world changed: the whole new world, so that every client can draw it.
    World {
        /// The client whose command changed it.
        by: ClientId,
        /// The world now in force.
        #[serde(flatten)]
        world: Box<WorldInfo>,
    },
    /// The commanded pose is not clear of an obstacle (a world change put one onto the arm):
    /// the arm holds, and moves only where no link's clearance shrinks, until a `clear`.
    NotClear {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
        /// The link of least clearance, from 1 at the base.
        link: usize,
        /// The obstacle's id.
        obstacle: String,
        /// That link's clearance, m (negative: inside the obstacle by that depth).
        #[serde(deserialize_with = "values::number::deserialize")]
        clearance_m: f64,
        /// The clearance to keep, m.
        #[serde(deserialize_with = "values::number::deserialize")]
        keep_m: f64,
    },
    /// The commanded pose is clear again after a `not_clear`.
    Clear {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
        /// The pose's clearance now, m (`null`: no obstacles are left).
        #[serde(default)]
        min_clearance_m: Option<f64>,
    },
    /// The command ended caught on an obstacle (or without headway); the arm holds, clear.
    Blocked {
        /// The commanded tip, m.
        #[serde(deserialize_with = "values::point::deserialize")]
        tip: [f64; 2],
        /// The link held back, from 1 at the base.
        link: usize,
        /// The obstacle's id.
        obstacle: String,
    },
    /// An event this version does not know, by its name (a newer daemon's).
    #[serde(skip)]
    Other {
        /// Its `event` name.
        name: String,
    },
}

impl What {
    /// A `fault` event about `fault`, or a `warning` one when its kind is a warning.
    pub fn alarm(tip: [f64; 2], reason: FaultChange, fault: FaultInfo) -> What {
        if fault.kind.is_warning() {
            What::Warning { tip, reason, fault }
        } else {
            What::Fault { tip, reason, fault }
        }
    }

    /// Its name; `None` for [`What::Other`].
    pub fn kind(&self) -> Option<EventKind> {
        Some(match self {
            What::Arrived { .. } => EventKind::Arrived,
            What::Saturated { .. } => EventKind::Saturated,
            What::Preempted { .. } => EventKind::Preempted,
            What::Stopped { .. } => EventKind::Stopped,
            What::Estop { .. } => EventKind::Estop,
            What::Reset { .. } => EventKind::Reset,
            What::Fault { .. } => EventKind::Fault,
            What::Warning { .. } => EventKind::Warning,
            What::Control { .. } => EventKind::Control,
            What::ShuttingDown { .. } => EventKind::ShuttingDown,
            What::World { .. } => EventKind::World,
            What::NotClear { .. } => EventKind::NotClear,
            What::Clear { .. } => EventKind::Clear,
            What::Blocked { .. } => EventKind::Blocked,
            What::Other { .. } => return None,
        })
    }

    /// Its name as the wire writes it.
    pub fn name(&self) -> &str {
        match self {
            What::Other { name } => name,
            known => known.kind().map_or("", EventKind::as_str),
        }
    }

    /// The commanded tip it carries (every event of the loop does; `control` does not).
    pub fn tip(&self) -> Option<[f64; 2]> {
        match self {
            What::Arrived { tip }
            | What::Saturated { tip }
            | What::Preempted { tip, .. }
            | What::Stopped { tip, .. }
            | What::Estop { tip }
            | What::Reset { tip }
            | What::Fault { tip, .. }
            | What::Warning { tip, .. }
            | What::ShuttingDown { tip }
            | What::NotClear { tip, .. }
            | What::Clear { tip, .. }
            | What::Blocked { tip, .. } => Some(*tip),
            What::Control { .. } | What::World { .. } | What::Other { .. } => None,
        }
    }
}

/// One event. Events about a command go to the client that sent it (`owner`); the others go
/// to every client.
#[derive(Debug, Clone, PartialEq)]
pub struct Event {
    /// The client whose command this concerns; `None` for everyone. The daemon's routing, not
    /// on the wire (read back as `None`).
    pub owner: Option<ClientId>,
    /// The request id of the command it concerns (or that made the change).
    pub cmd_id: Option<RequestId>,
    /// The tick it happened in (for `control`, the latest published tick).
    pub tick: u64,
    /// What happened.
    pub what: What,
}

impl Event {
    /// Its name, typed; `None` for one this version does not know.
    pub fn kind(&self) -> Option<EventKind> {
        self.what.kind()
    }
}

impl Serialize for Event {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Known<'a> {
            #[serde(flatten)]
            what: &'a What,
            #[serde(skip_serializing_if = "Option::is_none")]
            cmd_id: Option<&'a Value>,
            tick: u64,
        }
        #[derive(Serialize)]
        struct Unknown<'a> {
            event: &'a str,
            #[serde(skip_serializing_if = "Option::is_none")]
            cmd_id: Option<&'a Value>,
            tick: u64,
        }
        let cmd_id = self.cmd_id.as_deref();
        match &self.what {
            What::Other { name } => Unknown {
                event: name,
                cmd_id,
                tick: self.tick,
            }
            .serialize(s),
            what => Known {
                what,
                cmd_id,
                tick: self.tick,
            }
            .serialize(s),
        }
    }
}

impl<'de> Deserialize<'de> for Event {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Event, D::Error> {
        let map = Map::<String, Value>::deserialize(d)?;
        let tick = match map.get("tick") {
            Some(tick) => u64::deserialize(tick).map_err(D::Error::custom)?,
            None => return Err(D::Error::missing_field("tick")),
        };
        let cmd_id = map
            .get("cmd_id")
            .filter(|id| !id.is_null())
            .map(|id| Arc::new(id.clone()));
        let name = match map.get("event") {
            Some(Value::String(name)) => name.clone(),
            Some(other) => {
                return Err(D::Error::custom(format!(
                    "`event` must be a name, got {other}"
                )))
            }
            None => return Err(D::Error::missing_field("event")),
        };
        let what = match EventKind::from_name(&name) {
            Some(_) => What::deserialize(Value::Object(map)).map_err(D::Error::custom)?,
            None => What::Other { name },
        };
        Ok(Event {
            owner: None,
            cmd_id,
            tick,
            what,
        })
    }
}
