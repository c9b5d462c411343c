//! The arm as the tools of the field show it: the channels a live Foxglove view and a
//! recording share (topic names, encodings, schemas) and the messages they carry.
//!
//! Every channel lives under `/<prefix>/` (the `[zenoh] prefix`, `snakectl` by default):
//!
//! | topic | message | encoding |
//! |---|---|---|
//! | `joint_states` | `sensor_msgs/msg/JointState` | `cdr`, schema `ros2msg` |
//! | `tip_cmd`, `tip_meas`, `target` | `geometry_msgs/msg/PointStamped` | `cdr`, schema `ros2msg` |
//! | `telemetry` | the socket's telemetry line ([`TELEMETRY_SCHEMA_NAME`]) | `json`, schema `jsonschema` |
//! | `events` | the socket's event lines ([`EVENT_SCHEMA_NAME`]) | `json`, schema `jsonschema` |
//! | `log` | the same events as `foxglove.Log`, for a Log panel | `protobuf` |
//! | `scene` | `foxglove.SceneUpdate` ([`scene()`]) | `protobuf` |
//!
//! The `ros2msg` schemas are the `.msg` texts with their dependencies concatenated, as MCAP's
//! ROS 2 profile and rosbag2 write them, so a recording reads with the ROS 2 tools. Points and
//! the scene are in the frame [`FRAME_ID`]: the coordinates telemetry reports, in which
//! `[arm]` places the base.
//!
//! Everything here is pure: time comes in as an argument; the live server
//! (`crate::daemon::view`) and a recorder do the I/O.

pub mod scene;

use foxglove::schemas::log::Level;
use foxglove::schemas::{Log, Timestamp};
use foxglove::Encode;

use crate::protocol::{self, Event, EventKind, Telemetry};
use crate::ros::{self, RosError};

pub use scene::{scene, Trail};

/// The frame every point and the scene is in: the coordinates of telemetry (the config's
/// frame, in which `[arm]` places the base).
pub const FRAME_ID: &str = "base";

/// The prefix of the topics when the config names none.
pub const DEFAULT_PREFIX: &str = "snakectl";

/// The message encoding of ROS 2 messages.
pub const CDR: &str = "cdr";
/// The schema encoding of ROS 2 messages: `.msg` text, dependencies concatenated.
pub const ROS2MSG: &str = "ros2msg";
/// The message encoding of the telemetry and events.
pub const JSON: &str = "json";
/// The schema encoding of the telemetry and events.
pub const JSONSCHEMA: &str = "jsonschema";
/// The message and schema encoding of Foxglove's own schemas.
pub const PROTOBUF: &str = "protobuf";

/// The schema name of the telemetry channel.
pub const TELEMETRY_SCHEMA_NAME: &str = "snakectl.Telemetry";
/// The schema name of the events channel.
pub const EVENT_SCHEMA_NAME: &str = "snakectl.Event";

// The schemas are written once, with the recordings' channels (the `.msg` texts as rosbag2
// stores them, and the JSON Schemas of the socket's telemetry and events).
pub use crate::record::schema::{
    joint_state_schema, point_stamped_schema, EVENT_SCHEMA, TELEMETRY_SCHEMA,
};

/// One of the channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Topic {
    /// `sensor_msgs/msg/JointState`: the measured joints.
    JointStates,
    /// `geometry_msgs/msg/PointStamped`: the tip of the commanded pose.
    TipCmd,
    /// `geometry_msgs/msg/PointStamped`: the tip of the measured pose.
    TipMeas,
    /// `geometry_msgs/msg/PointStamped`: where the active command goes (only while there is
    /// one).
    Target,
    /// The telemetry line, JSON.
    Telemetry,
    /// The event lines, JSON.
    Events,
    /// The events as `foxglove.Log`.
    Log,
    /// `foxglove.SceneUpdate`: the arm, the tips, the trail, the target, the reachable ring,
    /// the obstacles.
    Scene,
}

impl Topic {
    /// Every channel, in the order a writer declares them.
    pub const ALL: [Topic; 8] = [
        Topic::JointStates,
        Topic::TipCmd,
        Topic::TipMeas,
        Topic::Target,
        Topic::Telemetry,
        Topic::Events,
        Topic::Log,
        Topic::Scene,
    ];

    /// The last part of its topic name.
    pub const fn name(self) -> &'static str {
        match self {
            Topic::JointStates => "joint_states",
            Topic::TipCmd => "tip_cmd",
            Topic::TipMeas => "tip_meas",
            Topic::Target => "target",
            Topic::Telemetry => "telemetry",
            Topic::Events => "events",
            Topic::Log => "log",
            Topic::Scene => "scene",
        }
    }

    /// Its topic under `prefix`: `/<prefix>/<name>`.
    pub fn topic(self, prefix: &str) -> String {
        format!("/{prefix}/{}", self.name())
    }

    /// Its channel under `prefix`: topic, encodings and schema.
    pub fn channel(self, prefix: &str) -> ChannelSpec {
        let (message_encoding, schema) = match self {
            Topic::JointStates => (
                CDR,
                foxglove::Schema::new(
                    <ros::JointState as ros::Message>::TYPE_NAME,
                    ROS2MSG,
                    joint_state_schema(),
                ),
            ),
            Topic::TipCmd | Topic::TipMeas | Topic::Target => (
                CDR,
                foxglove::Schema::new(
                    <ros::PointStamped as ros::Message>::TYPE_NAME,
                    ROS2MSG,
                    point_stamped_schema(),
                ),
            ),
            Topic::Telemetry => (
                JSON,
                foxglove::Schema::new(
                    TELEMETRY_SCHEMA_NAME,
                    JSONSCHEMA,
                    TELEMETRY_SCHEMA.as_bytes(),
                ),
            ),
            Topic::Events => (
                JSON,
                foxglove::Schema::new(EVENT_SCHEMA_NAME, JSONSCHEMA, EVENT_SCHEMA.as_bytes()),
            ),
            Topic::Log => (PROTOBUF, protobuf_schema::<Log>("foxglove.Log")),
            Topic::Scene => (
                PROTOBUF,
                protobuf_schema::<foxglove::schemas::SceneUpdate>("foxglove.SceneUpdate"),
            ),
        };
        ChannelSpec {
            topic: self.topic(prefix),
            message_encoding,
            schema,
        }
    }
}

/// Foxglove's own schema of `T` (its protobuf descriptor set).
fn protobuf_schema<T: Encode>(name: &str) -> foxglove::Schema {
    // Every schema of the `foxglove` crate has one; an empty one would still name the type.
    T::get_schema().unwrap_or_else(|| foxglove::Schema::new(name, PROTOBUF, Vec::new()))
}

/// A channel as a writer declares it: an MCAP channel and schema, or a Foxglove server's.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelSpec {
    /// Its topic, `/<prefix>/<name>`.
    pub topic: String,
    /// How each message is encoded: [`CDR`], [`JSON`] or [`PROTOBUF`].
    pub message_encoding: &'static str,
    /// Its schema: `name`, `encoding` ([`ROS2MSG`], [`JSONSCHEMA`], [`PROTOBUF`]) and `data`.
    pub schema: foxglove::Schema,
}

/// Every channel under `prefix`, in [`Topic::ALL`]'s order.
pub fn channels(prefix: &str) -> Vec<ChannelSpec> {
    Topic::ALL.iter().map(|t| t.channel(prefix)).collect()
}

/// The `joint_states` message of `telemetry` at `t_s` (seconds since the Unix epoch): CDR.
pub fn joint_states(telemetry: &Telemetry, t_s: f64) -> Result<Vec<u8>, RosError> {
    ros::encode(&ros::joint_state(telemetry, t_s))
}

/// A `tip_cmd`, `tip_meas` or `target` message: `point` at `t_s` in [`FRAME_ID`], CDR.
pub fn point(point: [f64; 2], t_s: f64) -> Result<Vec<u8>, RosError> {
    ros::encode(&ros::point_stamped(point, t_s, FRAME_ID))
}

/// A `telemetry` or `events` message from the socket's line (its newline dropped).
pub fn json_line(line: &str) -> Vec<u8> {
    line.trim_end().as_bytes().to_vec()
}

/// The `events` message of `event`.
pub fn event(event: &Event) -> Vec<u8> {
    json_line(&protocol::event_line(event))
}

/// The `log` message of `event` at `t_s`: the event line as the text, at a level by its kind
/// (faults and the estop are errors; warnings, refusals by an obstacle and a lost clearance
/// are warnings; the rest is information).
pub fn log(event: &Event, t_s: f64) -> Log {
    let level = match event.what.kind() {
        Some(EventKind::Estop | EventKind::Fault) => Level::Error,
        Some(EventKind::Warning | EventKind::Blocked | EventKind::NotClear) => Level::Warning,
        _ => Level::Info,
    };
    Log {
        timestamp: Some(timestamp(t_s)),
        level: level as i32,
        message: protocol::event_line(event).trim_end().to_owned(),
        name: DEFAULT_PREFIX.to_owned(),
        file: String::new(),
        line: 0,
    }
}

/// Encodes one of Foxglove's messages (the scene, a log line) as its channel carries it.
pub fn encode<T: Encode>(message: &T) -> Result<Vec<u8>, T::Error> {
    let mut buf = Vec::with_capacity(message.encoded_len().unwrap_or(256));
    message.encode(&mut buf)?;
    Ok(buf)
}

/// `t_s` seconds since the Unix epoch as Foxglove's timestamp, the same nanosecond as
/// [`nanos`] gives the message's log time (before the epoch is the epoch; saturating).
pub fn timestamp(t_s: f64) -> Timestamp {
    timestamp_ns(nanos(t_s))
}

/// `ns` nanoseconds since the Unix epoch as Foxglove's timestamp, exactly (saturating beyond
/// its range, in 2106).
pub fn timestamp_ns(ns: u64) -> Timestamp {
    const NS: u64 = 1_000_000_000;
    u32::try_from(ns / NS)
        .ok()
        // The remainder is below 1e9: it fits, and carries nothing.
        .and_then(|sec| Timestamp::new_checked(sec, (ns % NS) as u32))
        .unwrap_or(Timestamp::MAX)
}

/// `t_s` seconds since the Unix epoch in nanoseconds, as log times are written (0 before the
/// epoch, saturating far after it).
pub fn nanos(t_s: f64) -> u64 {
    // `as` saturates and maps NaN to 0.
    (t_s * 1e9).round().max(0.0) as u64
}

#[cfg(test)]
mod tests;
