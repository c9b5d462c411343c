#![allow(clippy::unwrap_used)]

use foxglove::schemas::SceneUpdate;
use foxglove::Decode;

use super::*;
use crate::chain::{Chain, Vec2};
use crate::protocol::{Telemetry, What};
use crate::world::{Obstacle, Shape, World};

fn chain() -> Chain {
    Chain::unlimited(vec![0.3, 0.2, 0.1], Vec2::new(0.5, -0.25), 0.0).unwrap()
}

fn telemetry(chain: &Chain, theta: &[f64]) -> Telemetry {
    let tip = chain.tip(theta);
    Telemetry {
        theta_cmd: theta.to_vec(),
        theta_meas: theta.to_vec(),
        omega_meas: vec![0.0; theta.len()],
        tip: [tip.x, tip.y],
        tip_meas: [tip.x, tip.y],
        ..Telemetry::default()
    }
}

#[test]
fn every_channel_is_under_the_prefix_with_its_encodings() {
    let specs = channels("lab/arm");
    let topics: Vec<&str> = specs.iter().map(|c| c.topic.as_str()).collect();
    assert_eq!(
        topics,
        [
            "/lab/arm/joint_states",
            "/lab/arm/tip_cmd",
            "/lab/arm/tip_meas",
            "/lab/arm/target",
            "/lab/arm/telemetry",
            "/lab/arm/events",
            "/lab/arm/log",
            "/lab/arm/scene",
        ]
    );
    let by = |t: Topic| t.channel("snakectl");
    let js = by(Topic::JointStates);
    assert_eq!(
        (
            js.message_encoding,
            js.schema.name.as_str(),
            js.schema.encoding.as_str()
        ),
        ("cdr", "sensor_msgs/msg/JointState", "ros2msg")
    );
    let tip = by(Topic::TipMeas);
    assert_eq!(tip.schema.name, "geometry_msgs/msg/PointStamped");
    let tel = by(Topic::Telemetry);
    assert_eq!(
        (
            tel.message_encoding,
            tel.schema.name.as_str(),
            tel.schema.encoding.as_str()
        ),
        ("json", "snakectl.Telemetry", "jsonschema")
    );
    assert_eq!(by(Topic::Events).schema.name, "snakectl.Event");
    let scene = by(Topic::Scene);
    assert_eq!(
        (
            scene.message_encoding,
            scene.schema.name.as_str(),
            scene.schema.encoding.as_str()
        ),
        ("protobuf", "foxglove.SceneUpdate", "protobuf")
    );
    assert!(!scene.schema.data.is_empty(), "the descriptor set");
    assert_eq!(by(Topic::Log).schema.name, "foxglove.Log");
    // The JSON schemas are JSON.
    for text in [TELEMETRY_SCHEMA, EVENT_SCHEMA] {
        let v: serde_json::Value = serde_json::from_str(text).unwrap();
        assert_eq!(v["type"], "object");
    }
}

#[test]
fn ros2msg_schemas_carry_their_dependencies_as_rosbag2_writes_them() {
    let bar = "=".repeat(80);
    let js = String::from_utf8(joint_state_schema()).unwrap();
    assert!(
        js.starts_with("std_msgs/Header header\nstring[] name\n"),
        "{js}"
    );
    assert!(
        js.contains(&format!("\n{bar}\nMSG: std_msgs/Header\n")),
        "{js}"
    );
    assert!(js.contains(&format!(
        "\n{bar}\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
    )));
    let ps = String::from_utf8(point_stamped_schema()).unwrap();
    for dep in [
        "std_msgs/Header",
        "builtin_interfaces/Time",
        "geometry_msgs/Point",
    ] {
        assert_eq!(
            ps.matches(&format!("{bar}\nMSG: {dep}\n")).count(),
            1,
            "{dep}: {ps}"
        );
    }
}

#[test]
fn messages_decode_to_what_they_were_made_of() {
    let chain = chain();
    let t = telemetry(&chain, &[0.3, -0.2, 0.5]);
    let js: ros::JointState = ros::decode(&joint_states(&t, 12.5).unwrap()).unwrap();
    assert_eq!(js.position, t.theta_meas);
    assert_eq!(js.name, ["joint_1", "joint_2", "joint_3"]);
    assert_eq!(
        js.header.stamp,
        ros::Time {
            sec: 12,
            nanosec: 500_000_000
        }
    );
    let p: ros::PointStamped = ros::decode(&point([1.5, -2.0], 3.0).unwrap()).unwrap();
    assert_eq!((p.point.x, p.point.y, p.point.z), (1.5, -2.0, 0.0));
    assert_eq!(p.header.frame_id, FRAME_ID);
    assert_eq!(json_line("{\"a\":1}\n"), b"{\"a\":1}");
    assert_eq!(nanos(1.5), 1_500_000_000);
    assert_eq!(nanos(-3.0), 0);
}

#[test]
fn a_scene_or_log_stamp_is_its_message_log_time_to_the_nanosecond() {
    // Wall-clock seconds, where an f64 holds a time to about 240 ns: the stamp and the log
    // time are the same nanosecond, and that of the ROS headers.
    for t_s in [1_796_684_472.355_119_6, 1_796_684_461.515_119_6, 1.5, 0.0] {
        let stamp = timestamp(t_s);
        assert_eq!(stamp.total_nanos(), nanos(t_s), "{t_s}");
        let ros = ros::Time::from_secs_f64(t_s);
        assert_eq!(
            (i64::from(stamp.sec()), stamp.nsec()),
            (i64::from(ros.sec), ros.nanosec),
            "{t_s}"
        );
    }
    let ns = 1_796_684_472_355_119_604;
    assert_eq!(timestamp_ns(ns).total_nanos(), ns);
    assert_eq!(timestamp(-1.0).total_nanos(), 0);
    assert_eq!(timestamp_ns(u64::MAX), Timestamp::MAX);
}

#[test]
fn events_go_to_the_log_at_their_level() {
    let event = |what| Event {
        owner: None,
        cmd_id: None,
        tick: 7,
        what,
    };
    let estop = log(&event(What::Estop { tip: [0.1, 0.2] }), 1.0);
    assert_eq!(estop.level, Level::Error as i32);
    assert!(
        estop.message.contains("\"event\":\"estop\""),
        "{}",
        estop.message
    );
    let arrived = log(&event(What::Arrived { tip: [0.1, 0.2] }), 1.0);
    assert_eq!(arrived.level, Level::Info as i32);
    let line: serde_json::Value =
        serde_json::from_slice(&super::event(&event(What::Arrived { tip: [0.1, 0.2] }))).unwrap();
    assert_eq!(
        (line["event"].as_str(), line["tick"].as_u64()),
        (Some("arrived"), Some(7))
    );
}

fn entity<'a>(scene: &'a SceneUpdate, id: &str) -> Option<&'a foxglove::schemas::SceneEntity> {
    scene.entities.iter().find(|e| e.id == id)
}

#[test]
fn the_scene_draws_the_arm_where_the_chain_puts_it() {
    let chain = chain();
    let theta = [0.4, -0.3, 0.2];
    let mut t = telemetry(&chain, &theta);
    t.theta_cmd = vec![0.0; 3];
    t.target = Some([0.7, 0.1]);
    let world = World::new(
        0.02,
        0.01,
        vec![
            Obstacle {
                id: "post".into(),
                shape: Shape::Circle {
                    center: Vec2::new(0.2, 0.4),
                    radius_m: 0.05,
                },
            },
            Obstacle {
                id: "shelf".into(),
                shape: Shape::Polygon {
                    points: vec![
                        Vec2::new(-0.5, 0.5),
                        Vec2::new(-0.3, 0.5),
                        Vec2::new(-0.3, 0.7),
                    ],
                },
            },
        ],
    )
    .unwrap();
    let mut trail = Trail::new(4);
    for p in [
        [0.0, 0.0],
        [0.1, 0.0],
        [0.1, 0.0],
        [0.2, 0.0],
        [0.3, 0.0],
        [0.4, 0.0],
    ] {
        trail.push(p);
    }
    assert_eq!(trail.len(), 4, "bounded, a repeated point not added");
    let stamp = timestamp(100.0);
    let scene = scene(&chain, &world, &t, &trail, stamp);
    // It survives its own encoding, as a client decodes it.
    let bytes = encode(&scene).unwrap();
    let scene = SceneUpdate::decode(&bytes[..]).unwrap();

    let meas = entity(&scene, "arm_meas").unwrap();
    assert_eq!(meas.frame_id, FRAME_ID);
    let drawn: Vec<(f64, f64)> = meas.lines[0].points.iter().map(|p| (p.x, p.y)).collect();
    let expected: Vec<(f64, f64)> = chain.points(&theta).iter().map(|p| (p.x, p.y)).collect();
    assert_eq!(drawn, expected);
    assert_eq!(meas.spheres.len(), 3, "one per joint");
    let cmd = entity(&scene, "arm_cmd").unwrap();
    let last = cmd.lines[0].points.last().unwrap();
    assert!(
        (last.x - 1.1).abs() < 1e-12 && (last.y + 0.25).abs() < 1e-12,
        "straight: {last:?}"
    );
    assert_eq!(cmd.lines[0].thickness, 0.04, "the links' width");
    let target = entity(&scene, "target").unwrap();
    let at = target.spheres[0].pose.unwrap().position.unwrap();
    assert_eq!((at.x, at.y), (0.7, 0.1));
    assert!(scene.deletions.is_empty());
    let trail = entity(&scene, "trail").unwrap();
    assert_eq!(trail.lines[0].points.len(), 4);
    assert_eq!(trail.lines[0].points[0].x, 0.1, "the oldest left first");
    // The ring of an unlimited chain: two circles about the base, radii 0.6 and 0.
    let reach = entity(&scene, "reach").unwrap();
    assert_eq!(reach.lines.len(), 1, "the inner radius is 0");
    for p in &reach.lines[0].points {
        let r = ((p.x - 0.5).powi(2) + (p.y + 0.25).powi(2)).sqrt();
        assert!((r - 0.6).abs() < 1e-12, "{r}");
    }
    let obstacles = entity(&scene, "obstacles").unwrap();
    assert_eq!(obstacles.cylinders.len(), 1);
    assert_eq!(obstacles.cylinders[0].size.unwrap().x, 0.1);
    assert_eq!(obstacles.lines.len(), 1);
    assert_eq!(obstacles.lines[0].points.len(), 3);
    let labels: Vec<&str> = obstacles.texts.iter().map(|t| t.text.as_str()).collect();
    assert_eq!(labels, ["post", "shelf"]);
}

#[test]
fn without_a_target_or_angles_the_scene_says_so() {
    let chain = chain();
    let mut t = telemetry(&chain, &[0.0; 3]);
    t.theta_cmd.clear();
    t.theta_meas.clear();
    let scene = scene(
        &chain,
        &World::default(),
        &t,
        &Trail::default(),
        timestamp(1.0),
    );
    assert!(entity(&scene, "arm_cmd").is_none());
    assert!(entity(&scene, "arm_meas").is_none());
    assert!(entity(&scene, "tip_meas").is_some());
    assert_eq!(scene.deletions.len(), 1);
    assert_eq!(scene.deletions[0].id, "target");
    let obstacles = entity(&scene, "obstacles").unwrap();
    assert!(obstacles.cylinders.is_empty() && obstacles.lines.is_empty());
}
