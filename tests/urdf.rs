//! `snakectl urdf` read back as a robot_state_publisher would read it: the XML parsed, the
//! tree walked from `base` to `tip`, each revolute joint turned by its `JointState` angle.
//! Its forward kinematics at the daemon's measured angles lands on the daemon's `tip_meas`;
//! names, limits and shapes are the config's.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::collections::HashMap;
use std::process::Command;

use daemon_support::{floats, sim_config, xy, Daemon};
use serde_json::json;
use snakectl::config::Config;

/// One `<joint>` of the description.
#[derive(Debug, Clone)]
struct Joint {
    name: String,
    kind: String,
    parent: String,
    child: String,
    xyz: [f64; 3],
    rpy: [f64; 3],
    axis: Option<[f64; 3]>,
    /// lower, upper, velocity, effort.
    limit: Option<[f64; 4]>,
}

/// The parsed description: link names (with their geometry element names, in order) and joints.
struct Robot {
    links: Vec<(String, Vec<String>)>,
    joints: Vec<Joint>,
}

fn numbers<const N: usize>(text: &str) -> [f64; N] {
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .unwrap_or_else(|_| panic!("{t:?} is not a number"))
        })
        .collect();
    v.try_into()
        .unwrap_or_else(|v: Vec<f64>| panic!("{} numbers, not {N}: {text:?}", v.len()))
}

fn parse(text: &str) -> Robot {
    let doc = roxmltree::Document::parse(text).unwrap();
    let robot = doc.root_element();
    assert_eq!(robot.tag_name().name(), "robot");
    assert_eq!(robot.attribute("name"), Some("snakectl"));
    let mut links = Vec::new();
    let mut joints = Vec::new();
    for node in robot.children().filter(|n| n.is_element()) {
        match node.tag_name().name() {
            "link" => {
                let mut shapes = Vec::new();
                for part in node.children().filter(|n| n.is_element()) {
                    let geometry = part
                        .children()
                        .find(|n| n.has_tag_name("geometry"))
                        .unwrap_or_else(|| panic!("a {} without geometry", part.tag_name().name()));
                    let shape = geometry.children().find(|n| n.is_element()).unwrap();
                    shapes.push(format!(
                        "{}:{}",
                        part.tag_name().name(),
                        shape.tag_name().name()
                    ));
                }
                links.push((node.attribute("name").unwrap().to_owned(), shapes));
            }
            "joint" => {
                let child = |tag: &str| node.children().find(|n| n.has_tag_name(tag));
                let origin = child("origin").unwrap();
                let limit = child("limit").map(|l| {
                    ["lower", "upper", "velocity", "effort"]
                        .map(|a| l.attribute(a).unwrap().parse::<f64>().unwrap())
                });
                joints.push(Joint {
                    name: node.attribute("name").unwrap().to_owned(),
                    kind: node.attribute("type").unwrap().to_owned(),
                    parent: child("parent")
                        .unwrap()
                        .attribute("link")
                        .unwrap()
                        .to_owned(),
                    child: child("child")
                        .unwrap()
                        .attribute("link")
                        .unwrap()
                        .to_owned(),
                    xyz: numbers(origin.attribute("xyz").unwrap()),
                    rpy: numbers(origin.attribute("rpy").unwrap()),
                    axis: child("axis").map(|a| numbers(a.attribute("xyz").unwrap())),
                    limit,
                });
            }
            "material" => {}
            other => panic!("unexpected <{other}>"),
        }
    }
    Robot { links, joints }
}

/// The planar pose (x, y, heading) of `frame` in `base`, with `angles[name]` for each
/// revolute joint on the way: the tree walked down from the root, as robot_state_publisher
/// composes it.
fn forward(robot: &Robot, angles: &HashMap<String, f64>, frame: &str) -> [f64; 3] {
    let by_child: HashMap<&str, &Joint> =
        robot.joints.iter().map(|j| (j.child.as_str(), j)).collect();
    let mut path = Vec::new();
    let mut at = frame;
    while let Some(joint) = by_child.get(at) {
        path.push(*joint);
        at = &joint.parent;
    }
    assert_eq!(at, "base", "the root is base");
    let (mut x, mut y, mut heading) = (0.0f64, 0.0f64, 0.0f64);
    for joint in path.iter().rev() {
        // A planar arm: every origin in the plane, turned about z only.
        assert_eq!(joint.xyz[2], 0.0, "{}", joint.name);
        assert_eq!([joint.rpy[0], joint.rpy[1]], [0.0, 0.0], "{}", joint.name);
        x += heading.cos() * joint.xyz[0] - heading.sin() * joint.xyz[1];
        y += heading.sin() * joint.xyz[0] + heading.cos() * joint.xyz[1];
        heading += joint.rpy[2];
        match joint.kind.as_str() {
            "revolute" => {
                assert_eq!(joint.axis, Some([0.0, 0.0, 1.0]), "{}", joint.name);
                heading += angles[&joint.name];
            }
            "fixed" => {}
            kind => panic!("{}: a {kind} joint", joint.name),
        }
    }
    [x, y, heading]
}

fn snakectl_urdf(config: &str) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["urdf", "--config", config])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn shipped(name: &str) -> String {
    format!("{}/config/{name}", env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn its_forward_kinematics_at_the_measured_angles_is_the_daemons_tip_meas() {
    let robot = parse(&snakectl_urdf(&shipped("sim.toml")));
    let daemon = Daemon::start(sim_config(&[]));
    let mut client = daemon.client();
    // Away from home, so that the angles are not the config's own.
    let id = client.ok(json!({"cmd": "goto", "target": [-0.40, 0.62]}))["id"].as_u64();
    client.event("arrived", id);
    let status = client.wait_status("at rest", |s| {
        s["state"] == "holding" && floats(&s["omega_meas"]).iter().all(|w| *w == 0.0)
    });
    let theta = floats(&status["theta_meas"]);
    let angles: HashMap<String, f64> = theta
        .iter()
        .enumerate()
        .map(|(i, a)| (format!("joint_{}", i + 1), *a))
        .collect();
    let tip = forward(&robot, &angles, "tip");
    let tip_meas = xy(&status["tip_meas"]);
    let error = (tip[0] - tip_meas[0]).hypot(tip[1] - tip_meas[1]);
    assert!(
        error < 1e-12,
        "URDF tip {tip:?} vs tip_meas {tip_meas:?}: {error} m apart"
    );
    // Every joint frame is the config's point p_{i-1} at those angles too.
    let points = daemon.config.chain().points(&theta);
    for (i, p) in points[..points.len() - 1].iter().enumerate() {
        let frame = forward(&robot, &angles, &format!("link_{}", i + 1));
        assert!(
            (frame[0] - p.x).hypot(frame[1] - p.y) < 1e-12,
            "link_{}",
            i + 1
        );
    }
    daemon.stop().unwrap();
}

#[test]
fn names_limits_and_shapes_are_the_configs() {
    let config = Config::load(shipped("sim.toml")).unwrap();
    let robot = parse(&snakectl_urdf(&shipped("sim.toml")));
    let revolute: Vec<&Joint> = robot
        .joints
        .iter()
        .filter(|j| j.kind == "revolute")
        .collect();
    let names: Vec<&str> = revolute.iter().map(|j| j.name.as_str()).collect();
    let expected: Vec<String> = (1..=12).map(|i| format!("joint_{i}")).collect();
    assert_eq!(names, expected, "the names JointState carries, base to tip");
    // XL430-W250: no-load 57 rev/min at 11.1 V is 5.97 rad/s, above the config's 2 rad/s
    // joint speed limit, which is then the velocity; stall torque 1.4 N·m.
    let max_speed = config.control().max_joint_speed_rad_s;
    assert!(max_speed < 57.0 * std::f64::consts::TAU / 60.0);
    for (joint, configured) in revolute.iter().zip(config.joints()) {
        assert_eq!(
            joint.limit,
            Some([configured.limit.lo, configured.limit.hi, max_speed, 1.4]),
            "{}",
            joint.name
        );
    }
    let fixed: Vec<&str> = robot
        .joints
        .iter()
        .filter(|j| j.kind == "fixed")
        .map(|j| j.name.as_str())
        .collect();
    assert_eq!(fixed, ["mount_joint", "tip_joint"]);
    // The chain: base -> mount -> link_1 -> ... -> link_12 -> tip.
    let links: Vec<&str> = robot.links.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(links[..2], ["base", "mount"]);
    assert_eq!(links[links.len() - 1], "tip");
    // sim.toml has no link radius: each link is a box, seen and collided with.
    for (name, shapes) in &robot.links {
        if name.starts_with("link_") {
            assert_eq!(shapes, &["visual:box", "collision:box"], "{name}");
        }
    }
}

#[test]
fn a_shifted_base_and_capsule_links() {
    // The shipped simulator arm, its base moved and turned, with links 12 mm in radius.
    let text = std::fs::read_to_string(shipped("sim.toml")).unwrap();
    let text = format!("{text}\n[world]\nlink_radius_m = 0.012\n")
        .replace("base_x_m = 0.0", "base_x_m = 0.125")
        .replace("base_y_m = 0.0", "base_y_m = -0.0625")
        .replace(
            "base_heading_rad = 1.5707963267948966",
            "base_heading_rad = 2.0",
        );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("shifted.toml");
    std::fs::write(&path, &text).unwrap();
    let config = Config::load(&path).unwrap();
    assert_eq!(config.chain().heading(), 2.0);
    assert_eq!(config.world().link_radius_m(), 0.012);
    let text = snakectl_urdf(path.to_str().unwrap());
    let robot = parse(&text);
    // Every link's cylinder is 80 mm long (sim.toml's links) and 12 mm in radius, seen and
    // collided with; its spheres are 12 mm too.
    assert_eq!(
        text.matches("<cylinder radius=\"0.012\" length=\"0.08\"/>")
            .count(),
        24
    );
    assert_eq!(text.matches("<sphere radius=\"0.012\"/>").count(), 48);

    let mount = robot
        .joints
        .iter()
        .find(|j| j.name == "mount_joint")
        .unwrap();
    assert_eq!(mount.xyz, [0.125, -0.0625, 0.0]);
    assert_eq!(mount.rpy, [0.0, 0.0, 2.0]);
    // Capsules: a cylinder and a sphere at each end, seen and collided with.
    let capsule = [
        "visual:cylinder",
        "visual:sphere",
        "visual:sphere",
        "collision:cylinder",
        "collision:sphere",
        "collision:sphere",
    ];
    for (name, shapes) in &robot.links {
        if name.starts_with("link_") {
            assert_eq!(shapes, &capsule, "{name}");
        }
    }
    // At some angles inside the limits, the URDF's tip is the chain's.
    let n = config.joints().len();
    let theta: Vec<f64> = (0..n).map(|i| 0.3 * ((i as f64) * 1.7).sin()).collect();
    let angles: HashMap<String, f64> = theta
        .iter()
        .enumerate()
        .map(|(i, a)| (format!("joint_{}", i + 1), *a))
        .collect();
    let tip = forward(&robot, &angles, "tip");
    let expected = config.chain().tip(&theta);
    assert!((tip[0] - expected.x).hypot(tip[1] - expected.y) < 1e-12);
}

/// A config whose path has runs of hyphens still gives well-formed XML: a comment may not hold
/// `--`, and a run of three is no pair replaced once.
#[test]
fn a_path_with_runs_of_hyphens_keeps_the_header_a_comment() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("arm---v2--x----.toml");
    std::fs::copy(shipped("sim.toml"), &path).unwrap();
    let text = snakectl_urdf(path.to_str().unwrap());
    let doc = roxmltree::Document::parse(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    let comment = doc
        .root()
        .children()
        .find(|n| n.is_comment())
        .and_then(|n| n.text())
        .unwrap();
    assert!(comment.contains("arm- - -v2- -x- - - -.toml"), "{comment}");
    assert_eq!(parse(&text).joints.len(), 14);
}

/// Without `--config`, the built-in copy of the shipped arm, named so in the header, even where
/// the current directory holds a config/sim.toml of its own.
#[test]
fn the_default_is_the_shipped_simulator_arm() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("config")).unwrap();
    std::fs::write(dir.path().join("config/sim.toml"), "not the arm").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .arg("urdf")
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    assert_eq!(
        String::from_utf8(out.stdout).unwrap(),
        snakectl_urdf(&shipped("sim.toml")).replace(
            &shipped("sim.toml"),
            "the built-in copy of the shipped config/sim.toml"
        )
    );
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["urdf", "--config", "/nonexistent/arm.toml"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    // The file, then why, said once.
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(
        err.trim_end(),
        format!(
            "snakectl: /nonexistent/arm.toml: cannot read: {}",
            std::fs::read_to_string("/nonexistent/arm.toml").unwrap_err()
        ),
        "{err}"
    );
}
