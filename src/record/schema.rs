//! What each channel of a recording carries: its topic under the prefix, its schema (the ROS 2
//! message definitions as MCAP's ROS 2 profile stores them, or a JSON Schema) and its message
//! encoding.
//!
//! A `ros2msg` schema is the type's `.msg` text, then each type it uses, each after a line of
//! 80 `=` and a line `MSG: pkg/Type`: what `ros2 bag record` writes, and what Foxglove and
//! `mcap-ros2-support` parse.

use std::collections::BTreeMap;

/// How a channel's messages and its schema are written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelSpec {
    /// The topic, e.g. `/snakectl/joint_states`.
    pub topic: String,
    /// The schema's name, e.g. `sensor_msgs/msg/JointState`.
    pub schema_name: String,
    /// The schema's encoding: `ros2msg`, `jsonschema`, `protobuf`, ...
    pub schema_encoding: String,
    /// The schema itself.
    pub schema: Vec<u8>,
    /// The messages' encoding: `cdr`, `json`, `protobuf`, ...
    pub message_encoding: String,
    /// The channel's metadata (for ROS 2 channels, `offered_qos_profiles` and
    /// `topic_type_hash`).
    pub metadata: BTreeMap<String, String>,
}

/// The line before each dependency of a `ros2msg` schema.
const SEPARATOR: &str =
    "================================================================================";

/// `builtin_interfaces/msg/Time`.
const TIME_MSG: &str = "int32 sec\nuint32 nanosec\n";
/// `std_msgs/msg/Header`.
const HEADER_MSG: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";
/// `sensor_msgs/msg/JointState`.
const JOINT_STATE_MSG: &str = "std_msgs/Header header\n\
                               string[] name\n\
                               float64[] position\n\
                               float64[] velocity\n\
                               float64[] effort\n";
/// `geometry_msgs/msg/Point`.
const POINT_MSG: &str = "float64 x\nfloat64 y\nfloat64 z\n";
/// `geometry_msgs/msg/PointStamped`.
const POINT_STAMPED_MSG: &str = "std_msgs/Header header\ngeometry_msgs/Point point\n";

/// RIHS01 hash of `sensor_msgs/msg/JointState` (REP-2016).
const JOINT_STATE_HASH: &str =
    "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e";
/// RIHS01 hash of `geometry_msgs/msg/PointStamped` (REP-2016).
const POINT_STAMPED_HASH: &str =
    "RIHS01_4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897";

/// A `ros2msg` schema: the type's own text, then each dependency (name as its fields write
/// it, and text) after the separator.
fn ros2msg(own: &str, dependencies: &[(&str, &str)]) -> Vec<u8> {
    let mut text = own.to_owned();
    for (name, body) in dependencies {
        text.push_str(SEPARATOR);
        text.push_str("\nMSG: ");
        text.push_str(name);
        text.push('\n');
        text.push_str(body);
    }
    text.into_bytes()
}

/// The `ros2msg` schema of `sensor_msgs/msg/JointState`, dependencies included.
pub fn joint_state_schema() -> Vec<u8> {
    ros2msg(
        JOINT_STATE_MSG,
        &[
            ("std_msgs/Header", HEADER_MSG),
            ("builtin_interfaces/Time", TIME_MSG),
        ],
    )
}

/// The `ros2msg` schema of `geometry_msgs/msg/PointStamped`, dependencies included.
pub fn point_stamped_schema() -> Vec<u8> {
    ros2msg(
        POINT_STAMPED_MSG,
        &[
            ("std_msgs/Header", HEADER_MSG),
            ("builtin_interfaces/Time", TIME_MSG),
            ("geometry_msgs/Point", POINT_MSG),
        ],
    )
}

/// A ROS 2 channel: `ros2msg`/`cdr`, with the metadata `ros2 bag` reads (an empty QoS list,
/// which it plays back with its defaults, and the type hash).
fn ros2_channel(topic: String, type_name: &str, schema: Vec<u8>, hash: &str) -> ChannelSpec {
    ChannelSpec {
        topic,
        schema_name: type_name.to_owned(),
        schema_encoding: "ros2msg".to_owned(),
        schema,
        message_encoding: "cdr".to_owned(),
        metadata: BTreeMap::from([
            ("offered_qos_profiles".to_owned(), String::new()),
            ("topic_type_hash".to_owned(), hash.to_owned()),
        ]),
    }
}

/// A JSON channel with its JSON Schema.
fn json_channel(topic: String, schema_name: &str, schema: &str) -> ChannelSpec {
    ChannelSpec {
        topic,
        schema_name: schema_name.to_owned(),
        schema_encoding: "jsonschema".to_owned(),
        schema: schema.as_bytes().to_vec(),
        message_encoding: "json".to_owned(),
        metadata: BTreeMap::new(),
    }
}

/// `/<prefix>/<name>`.
pub fn topic(prefix: &str, name: &str) -> String {
    format!("/{prefix}/{name}")
}

/// `/<prefix>/joint_states`: the measured joints, `sensor_msgs/msg/JointState`.
pub fn joint_states(prefix: &str) -> ChannelSpec {
    ros2_channel(
        topic(prefix, "joint_states"),
        "sensor_msgs/msg/JointState",
        joint_state_schema(),
        JOINT_STATE_HASH,
    )
}

/// A point channel `/<prefix>/<name>` (`tip_cmd`, `tip_meas`, `target`),
/// `geometry_msgs/msg/PointStamped`.
pub fn point(prefix: &str, name: &str) -> ChannelSpec {
    ros2_channel(
        topic(prefix, name),
        "geometry_msgs/msg/PointStamped",
        point_stamped_schema(),
        POINT_STAMPED_HASH,
    )
}

/// `/<prefix>/telemetry`: the socket's telemetry object, JSON.
pub fn telemetry(prefix: &str) -> ChannelSpec {
    json_channel(
        topic(prefix, "telemetry"),
        "snakectl.Telemetry",
        TELEMETRY_SCHEMA,
    )
}

/// `/<prefix>/events`: the socket's event objects, JSON.
pub fn events(prefix: &str) -> ChannelSpec {
    json_channel(topic(prefix, "events"), "snakectl.Event", EVENT_SCHEMA)
}

/// The JSON Schema of a telemetry object (docs/PROTOCOL.md, **Telemetry**). A number that is
/// not finite is written `null`.
pub const TELEMETRY_SCHEMA: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "snakectl.Telemetry",
  "description": "What the control loop did in one tick (SI units)",
  "type": "object",
  "$defs": {
    "number": {"type": ["number", "null"]},
    "numbers": {"type": "array", "items": {"type": ["number", "null"]}},
    "point": {"type": "array", "items": {"type": ["number", "null"]}, "minItems": 2, "maxItems": 2},
    "fault": {
      "type": "object",
      "properties": {
        "id": {"type": ["integer", "null"]},
        "joint": {"type": ["integer", "null"]},
        "port": {"type": ["string", "null"]},
        "kind": {"type": "string"},
        "since_tick": {"type": "integer"},
        "detail": {"type": "string"}
      }
    }
  },
  "properties": {
    "type": {"const": "telemetry"},
    "tick": {"type": "integer", "description": "ticks since start"},
    "t_s": {"$ref": "#/$defs/number", "description": "tick times the nominal period, s"},
    "state": {"type": "string", "enum": ["moving", "holding", "stopping", "estop", "fault", "torque_off"]},
    "strategy": {"type": "string"},
    "tip_ref": {"$ref": "#/$defs/point", "description": "the tip's motion reference, m"},
    "tip": {"$ref": "#/$defs/point", "description": "the tip of the commanded pose, m"},
    "tip_meas": {"$ref": "#/$defs/point", "description": "the tip of the measured pose, m"},
    "target": {"oneOf": [{"$ref": "#/$defs/point"}, {"type": "null"}]},
    "theta_cmd": {"$ref": "#/$defs/numbers", "description": "commanded joint angles, rad"},
    "theta_meas": {"$ref": "#/$defs/numbers", "description": "measured joint angles, rad"},
    "omega_meas": {"$ref": "#/$defs/numbers", "description": "measured joint velocities, rad/s"},
    "tracking_error_m": {"$ref": "#/$defs/number"},
    "saturated": {"type": "boolean"},
    "self_collision": {"type": "boolean"},
    "min_clearance_m": {"$ref": "#/$defs/number"},
    "blocked": {"type": "boolean"},
    "command": {
      "type": ["object", "null"],
      "properties": {
        "kind": {"type": "string"},
        "id": {},
        "outcome": {"type": "string"},
        "peak_joint_speed_rad_s": {"$ref": "#/$defs/number"},
        "m3_rad2": {"$ref": "#/$defs/number"}
      }
    },
    "solve_us": {"$ref": "#/$defs/number"},
    "loop_hz": {"$ref": "#/$defs/number"},
    "tick_p99_us": {"$ref": "#/$defs/number"},
    "overruns": {"type": "integer"},
    "behind": {"type": "boolean"},
    "peak_joint_speed_rad_s": {"$ref": "#/$defs/number"},
    "m3_total_rad2": {"$ref": "#/$defs/number"},
    "faults": {"type": "array", "items": {"$ref": "#/$defs/fault"}},
    "warnings": {"type": "array", "items": {"$ref": "#/$defs/fault"}},
    "torque": {"type": "boolean"},
    "temperature_c": {"$ref": "#/$defs/numbers"},
    "voltage_v": {"$ref": "#/$defs/numbers"},
    "load": {"$ref": "#/$defs/numbers"},
    "load_unit": {"type": "array", "items": {"type": "string", "enum": ["percent", "A"]}},
    "health_tick": {"type": "integer"},
    "counters": {
      "type": "object",
      "properties": {
        "dropped": {"type": "integer"},
        "corrupted": {"type": "integer"},
        "retries": {"type": "integer"},
        "clamped": {"type": "integer"}
      }
    },
    "controller": {"type": ["integer", "null"]},
    "in_control": {"type": "boolean"}
  }
}
"##;

/// The JSON Schema of an event object (docs/PROTOCOL.md, **Events**): its name, its tick,
/// the request it concerns, and what each kind carries.
pub const EVENT_SCHEMA: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "snakectl.Event",
  "description": "Something the control loop reports once: a command's ending, an estop, a fault, a world change, ...",
  "type": "object",
  "properties": {
    "type": {"const": "event"},
    "event": {"type": "string"},
    "tick": {"type": "integer"},
    "cmd_id": {},
    "tip": {"type": "array", "items": {"type": ["number", "null"]}}
  },
  "required": ["type", "event", "tick"],
  "additionalProperties": true
}
"##;

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_ros2msg_schema_lists_each_dependency_after_80_equals_and_its_name() {
        let text = String::from_utf8(joint_state_schema()).unwrap();
        let sections: Vec<&str> = text.split(&format!("{}\n", "=".repeat(80))).collect();
        assert_eq!(sections.len(), 3, "{text}");
        assert!(sections[0].starts_with("std_msgs/Header header\n"));
        assert!(sections[1].starts_with("MSG: std_msgs/Header\n"));
        assert!(sections[2].starts_with("MSG: builtin_interfaces/Time\n"));
        let point = String::from_utf8(point_stamped_schema()).unwrap();
        assert!(point.contains("MSG: geometry_msgs/Point\nfloat64 x\n"));
    }

    #[test]
    fn the_telemetry_schema_names_every_field_a_telemetry_line_has() {
        let schema: serde_json::Value = serde_json::from_str(TELEMETRY_SCHEMA).unwrap();
        let properties = schema["properties"].as_object().unwrap();
        let t = crate::protocol::Telemetry {
            theta_meas: vec![0.1, 0.2],
            command: None,
            ..Default::default()
        };
        let line = crate::protocol::telemetry_line(&crate::protocol::Status::of(&t)).to_string();
        let value: serde_json::Value = serde_json::from_str(&line).unwrap();
        for key in value.as_object().unwrap().keys() {
            assert!(properties.contains_key(key), "the schema lacks `{key}`");
        }
        let _: serde_json::Value = serde_json::from_str(EVENT_SCHEMA).unwrap();
    }
}
