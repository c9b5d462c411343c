//! The CDR bytes of the messages, written out by hand from the CDR rules, and round trips.
//!
//! The rules the golden bytes follow: a primitive is aligned to its own size, counted from the
//! first byte of the body (after the 4-byte header), padding with zeros before it; a string is
//! a u32 length that counts its NUL, its bytes, then the NUL; a sequence is a u32 count, then
//! its elements; a struct is its fields in order, with no alignment of its own.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;

/// Little-endian bytes of the f64 values the golden messages use (exact in binary).
const F_0_5: [u8; 8] = [0, 0, 0, 0, 0, 0, 0xE0, 0x3F]; // 0.5 = 0x3FE0_0000_0000_0000
const F_M0_25: [u8; 8] = [0, 0, 0, 0, 0, 0, 0xD0, 0xBF]; // -0.25 = 0xBFD0_0000_0000_0000
const F_1: [u8; 8] = [0, 0, 0, 0, 0, 0, 0xF0, 0x3F]; // 1.0 = 0x3FF0_0000_0000_0000
const F_M2: [u8; 8] = [0, 0, 0, 0, 0, 0, 0x00, 0xC0]; // -2.0 = 0xC000_0000_0000_0000
const F_0: [u8; 8] = [0; 8];

fn concat(parts: &[&[u8]]) -> Vec<u8> {
    parts.concat()
}

fn two_joints() -> JointState {
    JointState {
        header: Header {
            stamp: Time { sec: 1, nanosec: 2 },
            frame_id: String::new(),
        },
        name: vec!["joint_1".into(), "joint_2".into()],
        position: vec![0.5, -0.25],
        velocity: vec![1.0, -2.0],
        effort: vec![],
    }
}

fn two_joints_bytes() -> Vec<u8> {
    concat(&[
        &[0x00, 0x01, 0x00, 0x00], // encapsulation: plain CDR, little-endian; body starts here
        &[1, 0, 0, 0],             // body 0: header.stamp.sec = 1 (i32)
        &[2, 0, 0, 0],             // body 4: header.stamp.nanosec = 2 (u32)
        &[1, 0, 0, 0],             // body 8: header.frame_id length 1 (only its NUL)
        &[0],                      // body 12: the NUL of ""
        &[0, 0, 0],                // body 13: padding to 16 for the next u32
        &[2, 0, 0, 0],             // body 16: name: 2 strings
        &[8, 0, 0, 0],             // body 20: name[0] length 8 = "joint_1" + NUL
        b"joint_1\0",              // body 24
        &[8, 0, 0, 0],             // body 32: name[1] length 8
        b"joint_2\0",              // body 36
        &[2, 0, 0, 0],             // body 44: position: 2 f64, and 48 is already 8-aligned
        &F_0_5,                    // body 48: position[0] = 0.5
        &F_M0_25,                  // body 56: position[1] = -0.25
        &[2, 0, 0, 0],             // body 64: velocity: 2 f64
        &[0, 0, 0, 0],             // body 68: padding to 72 for the f64
        &F_1,                      // body 72: velocity[0] = 1.0
        &F_M2,                     // body 80: velocity[1] = -2.0
        &[0, 0, 0, 0],             // body 88: effort: 0 f64 (no padding: nothing follows)
    ])
}

#[test]
fn joint_state_golden_bytes() {
    let bytes = encode(&two_joints()).unwrap();
    let expected = two_joints_bytes();
    assert_eq!(expected.len(), 4 + 92);
    assert_eq!(bytes, expected);
}

#[test]
fn twist_golden_bytes() {
    let twist = Twist {
        linear: Vector3 {
            x: 0.5,
            y: -0.25,
            z: 0.0,
        },
        angular: Vector3 {
            x: 0.0,
            y: 0.0,
            z: 1.0,
        },
    };
    let expected = concat(&[
        &[0x00, 0x01, 0x00, 0x00], // encapsulation: plain CDR, little-endian
        &F_0_5,                    // body 0: linear.x = 0.5
        &F_M0_25,                  // body 8: linear.y = -0.25
        &F_0,                      // body 16: linear.z = 0
        &F_0,                      // body 24: angular.x = 0
        &F_0,                      // body 32: angular.y = 0
        &F_1,                      // body 40: angular.z = 1.0
    ]);
    assert_eq!(encode(&twist).unwrap(), expected);
    assert_eq!(decode::<Twist>(&expected).unwrap(), twist);
}

/// A frame name whose NUL ends off an 8-byte boundary: the point's first f64 is padded to a
/// multiple of 8 from the body's start (not from the header's).
#[test]
fn point_stamped_golden_bytes() {
    let message = point_stamped([0.5, -0.25], 1.000_000_002, "base");
    let expected = concat(&[
        &[0x00, 0x01, 0x00, 0x00], // encapsulation
        &[1, 0, 0, 0],             // body 0: stamp.sec = 1
        &[2, 0, 0, 0],             // body 4: stamp.nanosec = 2
        &[5, 0, 0, 0],             // body 8: frame_id length 5 = "base" + NUL
        b"base\0",                 // body 12
        &[0, 0, 0, 0, 0, 0, 0],    // body 17: padding to 24
        &F_0_5,                    // body 24: point.x = 0.5
        &F_M0_25,                  // body 32: point.y = -0.25
        &F_0,                      // body 40: point.z = 0
    ]);
    assert_eq!(encode(&message).unwrap(), expected);
}

#[test]
fn round_trips() {
    let joints = JointState {
        header: Header {
            stamp: Time {
                sec: -3,
                nanosec: 999_999_999,
            },
            frame_id: "arm/base".into(),
        },
        name: joint_names(3),
        position: vec![0.1, -1.9, 2.0],
        velocity: vec![f64::MIN_POSITIVE, -0.0, 1e300],
        effort: vec![0.25],
    };
    assert_eq!(
        decode::<JointState>(&encode(&joints).unwrap()).unwrap(),
        joints
    );

    let point = point_stamped([-0.547, 0.72], 12.5, "snakectl");
    assert_eq!(
        decode::<PointStamped>(&encode(&point).unwrap()).unwrap(),
        point
    );

    let empty = JointState::default();
    assert_eq!(
        decode::<JointState>(&encode(&empty).unwrap()).unwrap(),
        empty
    );
}

#[test]
fn trailing_padding_is_ignored() {
    // Some writers pad a payload past its message (to a multiple of 4, or of 8 in XCDR2's
    // options): such bytes are not part of the message.
    let mut bytes = two_joints_bytes();
    bytes.extend_from_slice(&[0, 0, 0, 0]);
    assert_eq!(decode::<JointState>(&bytes).unwrap(), two_joints());
}

#[test]
fn big_endian_payloads_are_read() {
    let expected = Vector3 {
        x: 0.5,
        y: -0.25,
        z: 1.0,
    };
    let mut bytes = vec![0x00, 0x00, 0x00, 0x00];
    for v in [0.5f64, -0.25, 1.0] {
        bytes.extend_from_slice(&v.to_be_bytes());
    }
    assert_eq!(decode::<Vector3>(&bytes).unwrap(), expected);
}

#[test]
fn short_input_is_refused() {
    for len in 0..4 {
        let err = decode::<Twist>(&CDR_LE_HEADER[..len]).unwrap_err();
        assert!(
            matches!(err, RosError::Short { len: l } if l == len),
            "{err}"
        );
        assert!(err.to_string().contains(&format!("{len} bytes")), "{err}");
    }
}

#[test]
fn other_encapsulations_are_refused() {
    let mut bytes = encode(&Twist::default()).unwrap();
    // 00 07: XCDR2 little-endian; 00 03: parameter list little-endian.
    for id in [[0x00, 0x07], [0x00, 0x03]] {
        bytes[..2].copy_from_slice(&id);
        let err = decode::<Twist>(&bytes).unwrap_err();
        assert!(
            matches!(err, RosError::Encapsulation { id: got } if got == id),
            "{err}"
        );
        assert!(
            err.to_string().contains(&format!("00 {:02x}", id[1])),
            "{err}"
        );
    }
}

#[test]
fn truncated_bodies_are_crate_errors() {
    let bytes = two_joints_bytes();
    for cut in [4, 10, 30, 50, bytes.len() - 1] {
        let err = decode::<JointState>(&bytes[..cut]).unwrap_err();
        assert!(matches!(err, RosError::Cdr(_)), "cut at {cut}: {err}");
    }
}

#[test]
fn a_huge_sequence_count_is_an_error_not_an_allocation() {
    // Header, stamp, empty frame_id, then a name count of u32::MAX with nothing behind it.
    let bytes = concat(&[
        &CDR_LE_HEADER,
        &[0; 8],
        &[1, 0, 0, 0, 0, 0, 0, 0],
        &[0xFF; 4],
    ]);
    assert!(matches!(
        decode::<JointState>(&bytes),
        Err(RosError::Cdr(_))
    ));
}

#[test]
fn joint_state_carries_the_measured_pose() {
    let telemetry = Telemetry {
        theta_cmd: vec![9.0, 9.0, 9.0],
        theta_meas: vec![0.1, 0.2, 0.3],
        omega_meas: vec![0.0, -1.0, 0.5],
        t_s: 99.0,
        ..Telemetry::default()
    };
    let message = joint_state(&telemetry, 1.25);
    assert_eq!(message.name, ["joint_1", "joint_2", "joint_3"]);
    assert_eq!(message.position, telemetry.theta_meas);
    assert_eq!(message.velocity, telemetry.omega_meas);
    assert!(message.effort.is_empty());
    assert_eq!(
        message.header.stamp,
        Time {
            sec: 1,
            nanosec: 250_000_000
        }
    );
    assert_eq!(message.header.frame_id, "");
}

#[test]
fn point_stamped_is_the_tip_in_the_plane() {
    let message = point_stamped([-0.547, 0.72], 3.5, "snakectl");
    assert_eq!(
        message.point,
        Point {
            x: -0.547,
            y: 0.72,
            z: 0.0
        }
    );
    assert_eq!(message.header.frame_id, "snakectl");
    assert_eq!(message.header.stamp.as_secs_f64(), 3.5);
}

#[test]
fn stamps_from_seconds() {
    let t = |sec, nanosec| Time { sec, nanosec };
    assert_eq!(Time::from_secs_f64(0.0), t(0, 0));
    assert_eq!(Time::from_secs_f64(1.000_000_002), t(1, 2));
    // Rounding up to the next second carries.
    assert_eq!(Time::from_secs_f64(1.999_999_999_9), t(2, 0));
    // Before the epoch: the second below, plus a positive remainder.
    assert_eq!(Time::from_secs_f64(-0.25), t(-1, 750_000_000));
    assert_eq!(Time::from_secs_f64(f64::NAN), t(0, 0));
    assert_eq!(Time::from_secs_f64(1e12), t(i32::MAX, 999_999_999));
    assert_eq!(Time::from_secs_f64(f64::NEG_INFINITY), t(i32::MIN, 0));
    // A present-day Unix time keeps microseconds.
    let now = Time::from_secs_f64(1_750_000_000.123_456);
    assert_eq!(now.sec, 1_750_000_000);
    assert!(now.nanosec.abs_diff(123_456_000) < 1_000, "{now:?}");
}
