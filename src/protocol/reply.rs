//! Replies: `{"id": ID, "ok": true, ...fields}` with the fields each command answers, typed
//! ([`Reply`]), or `{"id": ID, "ok": false, "error": {"code", "message"}}` ([`Rejection`]).
//!
//! A reply's shape depends on the command it answers, which the reply does not name: a client
//! reads one with the name of the command it sent ([`Fields::read`]). Fields beside the typed
//! ones (a newer daemon's) are kept in [`Fields::more`], not refused.

use std::fmt;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::{ClientId, CmdName, Describe, Rejection, Status, WorldInfo};

/// `subscribe`: the rate granted (at most the loop's).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Subscribed {
    /// Telemetry lines per second.
    pub rate_hz: f64,
}

/// `unsubscribe`: nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub struct Unsubscribed {}

/// `take_control`: who this client is, who holds control now and who held it before.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct TookControl {
    /// This client's id.
    pub client: ClientId,
    /// The holder now (this client).
    pub holder: Option<ClientId>,
    /// The holder before (`None`: nobody).
    pub previous: Option<ClientId>,
}

/// `release`: who this client is and who holds control now.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Released {
    /// This client's id.
    pub client: ClientId,
    /// The holder now (`None`: nobody).
    pub holder: Option<ClientId>,
}

/// `auth`: who this client is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Admitted {
    /// This client's id.
    pub client: ClientId,
}

/// A command the loop applied: the tick it was applied in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Applied {
    /// The tick.
    pub tick: u64,
}

/// `estop` and `torque`: the tick, and the servos a torque off did not confirm (none for a
/// torque on, or when every servo read back torque off). The latch or the torque off stands
/// either way; the servos named are switched off when they answer again.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TorqueOff {
    /// The tick.
    pub tick: u64,
    /// The servos whose torque is not known to be off, each with why; absent when empty.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unconfirmed: Vec<Unconfirmed>,
}

/// A servo whose torque off was not confirmed: its state is unknown.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Unconfirmed {
    /// 1-based joint index.
    pub joint: usize,
    /// Servo id.
    pub id: u8,
    /// Why: not reached (its port failed), silent, or no reply in the time allowed.
    pub why: String,
}

impl fmt::Display for Unconfirmed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "servo {} (joint {}) {}", self.id, self.joint, self.why)
    }
}

/// `set_world`, `add_obstacle`, `remove_obstacle`: the tick, and, when the new world leaves
/// the arm's pose not clear (an obstacle put onto it), the link of least clearance (as the
/// `not_clear` event tells everyone).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorldChanged {
    /// The tick.
    pub tick: u64,
    /// The pose is not clear of the new world; absent when it is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_clear: Option<PoseNotClear>,
}

/// The link of least clearance of a pose not clear.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseNotClear {
    /// The link, from 1 at the base.
    pub link: usize,
    /// The obstacle's id.
    pub obstacle: String,
    /// The link's clearance, m (negative: inside, by that depth).
    pub clearance_m: f64,
    /// The clearance to keep, m.
    pub keep_m: f64,
}

/// `reboot`: the tick, and the servos rebooted.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rebooted {
    /// The tick.
    pub tick: u64,
    /// The servo ids rebooted.
    pub rebooted: Vec<u8>,
}

/// What an ok reply answers, by the command it answers; written flat beside `id` and `ok`.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Reply {
    /// `describe`.
    Describe(Arc<Describe>),
    /// `status`.
    Status(Box<Status>),
    /// `subscribe`.
    Subscribed(Subscribed),
    /// `unsubscribe`.
    Unsubscribed(Unsubscribed),
    /// `take_control`.
    TookControl(TookControl),
    /// `release`.
    Released(Released),
    /// `auth`.
    Admitted(Admitted),
    /// Every other command the loop applies.
    Applied(Applied),
    /// `reboot`.
    Rebooted(Rebooted),
    /// `estop`, `torque`.
    TorqueOff(TorqueOff),
    /// `set_world`, `add_obstacle`, `remove_obstacle`.
    WorldChanged(WorldChanged),
    /// `world`.
    World(Box<WorldInfo>),
}

impl Reply {
    /// The reply to `cmd` in `fields` (an ok reply's object, `id` and `ok` aside). Fields it
    /// does not name are ignored; a missing or mistyped one is an error.
    pub fn read(cmd: CmdName, fields: &Value) -> Result<Reply, serde_json::Error> {
        fn from<T: serde::de::DeserializeOwned>(fields: &Value) -> Result<T, serde_json::Error> {
            T::deserialize(fields)
        }
        Ok(match cmd {
            CmdName::Describe => Reply::Describe(Arc::new(from(fields)?)),
            CmdName::Status => Reply::Status(Box::new(from(fields)?)),
            CmdName::Subscribe => Reply::Subscribed(from(fields)?),
            CmdName::Unsubscribe => Reply::Unsubscribed(from(fields)?),
            CmdName::TakeControl => Reply::TookControl(from(fields)?),
            CmdName::Release => Reply::Released(from(fields)?),
            CmdName::Auth => Reply::Admitted(from(fields)?),
            CmdName::Reboot => Reply::Rebooted(from(fields)?),
            CmdName::World => Reply::World(Box::new(from(fields)?)),
            CmdName::Estop | CmdName::Torque => Reply::TorqueOff(from(fields)?),
            CmdName::SetWorld | CmdName::AddObstacle | CmdName::RemoveObstacle => {
                Reply::WorldChanged(from(fields)?)
            }
            CmdName::Goto
            | CmdName::GotoJoints
            | CmdName::Reach
            | CmdName::Path
            | CmdName::Velocity
            | CmdName::Jog
            | CmdName::Stop
            | CmdName::Reset
            | CmdName::Home
            | CmdName::Strategy
            | CmdName::ResetStats => Reply::Applied(from(fields)?),
        })
    }

    /// The tick the loop applied the command in, for the replies that carry one.
    pub fn tick(&self) -> Option<u64> {
        match self {
            Reply::Applied(Applied { tick })
            | Reply::Rebooted(Rebooted { tick, .. })
            | Reply::TorqueOff(TorqueOff { tick, .. })
            | Reply::WorldChanged(WorldChanged { tick, .. }) => Some(*tick),
            Reply::Status(status) => Some(status.tick),
            Reply::Describe(_)
            | Reply::Subscribed(_)
            | Reply::Unsubscribed(_)
            | Reply::TookControl(_)
            | Reply::Released(_)
            | Reply::Admitted(_)
            | Reply::World(_) => None,
        }
    }

    /// This client's id, for the replies that tell it (`take_control`, `release`, `auth`).
    pub fn client(&self) -> Option<ClientId> {
        match self {
            Reply::TookControl(TookControl { client, .. })
            | Reply::Released(Released { client, .. })
            | Reply::Admitted(Admitted { client }) => Some(*client),
            Reply::Describe(_)
            | Reply::Status(_)
            | Reply::Subscribed(_)
            | Reply::Unsubscribed(_)
            | Reply::Applied(_)
            | Reply::Rebooted(_)
            | Reply::TorqueOff(_)
            | Reply::WorldChanged(_)
            | Reply::World(_) => None,
        }
    }
}

/// An ok reply's fields: the reply, typed, and any fields beside those it names.
#[derive(Debug, Clone, PartialEq)]
pub struct Fields {
    /// What the command answers.
    pub reply: Reply,
    /// Fields the reply does not name: none from this daemon; a newer one's, kept as they came
    /// so that a client passing a reply on (`snakectl status`) passes them too.
    pub more: Map<String, Value>,
}

impl Fields {
    /// The fields of the reply to `cmd` (an ok reply's, `id` and `ok` aside).
    pub fn read(cmd: CmdName, fields: Map<String, Value>) -> Result<Fields, serde_json::Error> {
        let fields = Value::Object(fields);
        let reply = Reply::read(cmd, &fields)?;
        let mut more = match fields {
            Value::Object(map) => map,
            _ => Map::new(),
        };
        for key in super::write::fields_of(&reply).keys() {
            more.remove(key);
        }
        Ok(Fields { reply, more })
    }

    /// Every field under its wire name: the reply's, then the others (but never `id`, `ok`
    /// or `type`, which are the line's own, nor one the reply already names).
    pub fn to_map(&self) -> Map<String, Value> {
        let mut map = super::write::fields_of(&self.reply);
        for (key, value) in &self.more {
            if !matches!(key.as_str(), "id" | "ok" | "type") && !map.contains_key(key) {
                map.insert(key.clone(), value.clone());
            }
        }
        map
    }
}

impl From<Reply> for Fields {
    fn from(reply: Reply) -> Fields {
        Fields {
            reply,
            more: Map::new(),
        }
    }
}

/// An ok reply's fields, or why the command was refused.
pub type Answer = Result<Fields, Rejection>;

/// A reply line as read, before its fields are typed (which needs the command it answers).
#[derive(Debug, Clone, PartialEq)]
pub struct ReplyLine {
    /// The id it echoes (`None` for `null`).
    pub id: Option<super::RequestId>,
    /// Its fields (`id` and `ok` taken out), or the refusal.
    pub result: Result<Map<String, Value>, Rejection>,
}
