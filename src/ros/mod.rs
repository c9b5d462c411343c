//! ROS 2 messages in their wire format: the few `std_msgs`, `sensor_msgs` and `geometry_msgs`
//! types the arm publishes and reads, as serde structs, and their CDR encoding.
//!
//! A ROS 2 payload is a 4-byte encapsulation header followed by the message body in OMG CDR.
//! snakectl writes little-endian plain CDR (header `00 01 00 00`), as ROS 2 on common hardware
//! does, so that `zenoh-bridge-ros2dds` and `rmw_zenoh` pass the bytes to ROS 2 untouched. The
//! body is laid out by the `cdr-encoding` crate from the structs' serde derives; field order is
//! the `.msg` files' order, which is all CDR needs. [`decode`] also reads big-endian bodies
//! (header `00 00`), which a big-endian ROS 2 host may send.
//!
//! [`joint_state`] and [`point_stamped`] turn the daemon's telemetry into messages; time comes
//! in as an argument, so they are pure. [`rmw`] names the keys, graph tokens and attachments
//! with which rmw_zenoh, ROS 2's Zenoh middleware, carries them.

use byteorder::{BigEndian, LittleEndian};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::protocol::Telemetry;

pub mod rmw;

/// The encapsulation header [`encode`] writes: plain CDR, little-endian, no options.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Representation identifier of plain CDR, big-endian.
const CDR_BE_ID: [u8; 2] = [0x00, 0x00];
/// Representation identifier of plain CDR, little-endian.
const CDR_LE_ID: [u8; 2] = [0x00, 0x01];

/// Why a payload could not be encoded or decoded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RosError {
    /// Fewer bytes than the 4-byte encapsulation header.
    #[error("a CDR payload of {len} bytes is shorter than its 4-byte encapsulation header")]
    Short {
        /// Bytes received.
        len: usize,
    },
    /// The header names an encoding other than plain CDR (such as XCDR2 or a parameter list).
    #[error(
        "encapsulation id {:02x} {:02x} is not plain CDR (00 01 little-endian, or 00 00 \
         big-endian)",
        id[0],
        id[1]
    )]
    Encapsulation {
        /// The header's first two bytes.
        id: [u8; 2],
    },
    /// The body does not fit the message type, or the value cannot be written as CDR.
    #[error("CDR body: {0}")]
    Cdr(#[from] cdr_encoding::Error),
}

/// A message type with its ROS 2 name.
pub trait Message: Serialize + DeserializeOwned {
    /// The ROS 2 type name, e.g. `sensor_msgs/msg/JointState`.
    const TYPE_NAME: &'static str;
}

/// Encodes `value` as a ROS 2 payload: [`CDR_LE_HEADER`], then the little-endian CDR body,
/// aligned from the body's first byte.
pub fn encode<T: Serialize>(value: &T) -> Result<Vec<u8>, RosError> {
    let mut out = Vec::with_capacity(64);
    out.extend_from_slice(&CDR_LE_HEADER);
    // The serializer counts alignment from the first byte it writes: the body's.
    cdr_encoding::to_writer::<T, LittleEndian, _>(&mut out, value)?;
    Ok(out)
}

/// Decodes a ROS 2 payload of plain CDR, either byte order. Bytes after the message (the
/// padding some writers add to a multiple of 4) are ignored.
pub fn decode<T: DeserializeOwned>(payload: &[u8]) -> Result<T, RosError> {
    let (Some(id), Some(body)) = (payload.get(..2), payload.get(4..)) else {
        return Err(RosError::Short { len: payload.len() });
    };
    let (value, _used) = match [id[0], id[1]] {
        CDR_LE_ID => cdr_encoding::from_bytes::<T, LittleEndian>(body)?,
        CDR_BE_ID => cdr_encoding::from_bytes::<T, BigEndian>(body)?,
        id => return Err(RosError::Encapsulation { id }),
    };
    Ok(value)
}

/// `builtin_interfaces/msg/Time`: seconds and nanoseconds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds past `sec`, below 1 000 000 000.
    pub nanosec: u32,
}

impl Time {
    /// The time `t_s` seconds (after whatever epoch the caller counts from), to the nearest
    /// nanosecond. Saturates outside the range of `sec`; NaN gives zero.
    pub fn from_secs_f64(t_s: f64) -> Time {
        const NS: i128 = 1_000_000_000;
        // `as` saturates, and maps NaN to 0.
        let ns = (t_s * 1e9).round() as i128;
        let sec = ns.div_euclid(NS);
        // rem_euclid lies in 0..NS, which fits.
        let nanosec = ns.rem_euclid(NS) as u32;
        match i32::try_from(sec) {
            Ok(sec) => Time { sec, nanosec },
            Err(_) if sec > 0 => Time {
                sec: i32::MAX,
                nanosec: 999_999_999,
            },
            Err(_) => Time {
                sec: i32::MIN,
                nanosec: 0,
            },
        }
    }

    /// Seconds as a float.
    pub fn as_secs_f64(self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }
}

impl Message for Time {
    const TYPE_NAME: &'static str = "builtin_interfaces/msg/Time";
}

/// `std_msgs/msg/Header`: when, and in which frame.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    /// When the data was taken.
    pub stamp: Time,
    /// The coordinate frame; empty where none applies.
    pub frame_id: String,
}

impl Message for Header {
    const TYPE_NAME: &'static str = "std_msgs/msg/Header";
}

/// `sensor_msgs/msg/JointState`: one entry per joint in each non-empty list.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp and frame.
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Angles, rad.
    pub position: Vec<f64>,
    /// Angular velocities, rad/s.
    pub velocity: Vec<f64>,
    /// Torques, N·m; empty when not measured.
    pub effort: Vec<f64>,
}

impl Message for JointState {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/JointState";
}

/// `geometry_msgs/msg/Point`, m.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    /// x, m.
    pub x: f64,
    /// y, m.
    pub y: f64,
    /// z, m.
    pub z: f64,
}

impl Message for Point {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Point";
}

/// `geometry_msgs/msg/PointStamped`: a point in a frame at a time.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PointStamped {
    /// Stamp and frame.
    pub header: Header,
    /// The point.
    pub point: Point,
}

impl Message for PointStamped {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/PointStamped";
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    /// x component.
    pub x: f64,
    /// y component.
    pub y: f64,
    /// z component.
    pub z: f64,
}

impl Message for Vector3 {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Vector3";
}

/// `geometry_msgs/msg/Twist`: linear velocity, m/s, and angular velocity, rad/s.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity, m/s.
    pub linear: Vector3,
    /// Angular velocity, rad/s.
    pub angular: Vector3,
}

impl Message for Twist {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Twist";
}

/// The joint names snakectl publishes: `joint_1` (at the base) to `joint_n`.
pub fn joint_names(n: usize) -> Vec<String> {
    (1..=n).map(|i| format!("joint_{i}")).collect()
}

/// The measured joints of `telemetry` at time `t_s`: names `joint_1..joint_n`, positions
/// `theta_meas`, velocities `omega_meas`, no effort, empty frame.
pub fn joint_state(telemetry: &Telemetry, t_s: f64) -> JointState {
    JointState {
        header: Header {
            stamp: Time::from_secs_f64(t_s),
            frame_id: String::new(),
        },
        name: joint_names(telemetry.theta_meas.len()),
        position: telemetry.theta_meas.clone(),
        velocity: telemetry.omega_meas.clone(),
        effort: Vec::new(),
    }
}

/// A planar point (such as the measured tip), m, at time `t_s` in `frame_id`; `z` is 0.
pub fn point_stamped(tip: [f64; 2], t_s: f64, frame_id: &str) -> PointStamped {
    PointStamped {
        header: Header {
            stamp: Time::from_secs_f64(t_s),
            frame_id: frame_id.to_owned(),
        },
        point: Point {
            x: tip[0],
            y: tip[1],
            z: 0.0,
        },
    }
}

#[cfg(test)]
mod tests;
