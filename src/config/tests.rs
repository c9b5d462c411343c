//! Every refusal the checker can give, each asserting the file, the field and the value appear
//! in the message.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;

const FILE: &str = "config/test.toml";

/// A small valid file: three joints with servos, every table present.
fn base_text() -> String {
    r#"
[arm]
base_x_m = 0.0
base_y_m = 0.0
base_heading_rad = 0.0
home_rad = [0.1, -0.2, 0.3]

[[joint]]
link_m = 0.1
min_rad = -2.0
max_rad = 2.0
id = 1
model = "XL430-W250"

[[joint]]
link_m = 0.1
min_rad = -2.0
max_rad = 2.0
id = 2
model = "XM430-W350"

[[joint]]
link_m = 0.1
min_rad = -2.0
max_rad = 2.0
id = 3
model = "XL330-M288"
offset_ticks = -12
reverse = true

[bus]
kind = "sim"
baud = 1000000
return_delay_us = 0
watchdog_ms = 100

[sim]
seed = 7

[control]
rate_hz = 100.0
strategy = "overall"

[server]
listen = "127.0.0.1:7878"
token_file = "token.txt"
max_clients = 4

[zenoh]
enabled = true
mode = "peer"
listen = ["tcp/127.0.0.1:7447"]
connect = ["tcp/[::1]:7448", "tcp/localhost:7449"]
prefix = "lab/arm_1"
publish_hz = 25.0
accept_commands = true
"#
    .to_owned()
}

/// `base_text` with the first occurrence of `from` replaced by `to` (which must exist).
fn with(from: &str, to: &str) -> String {
    let text = base_text();
    assert!(
        text.contains(from),
        "test setup: {from:?} not in the base text"
    );
    text.replacen(from, to, 1)
}

fn load(text: &str) -> Result<Config, ConfigError> {
    Config::from_str(text, FILE)
}

/// Loads `text`, expects a refusal, checks the message mentions each of `parts` and the file,
/// and returns the message.
fn refused(text: &str, parts: &[&str]) -> String {
    let err = load(text).expect_err("the text should be refused");
    let msg = err.to_string();
    assert!(msg.starts_with(FILE), "no file name in: {msg}");
    for part in parts {
        assert!(msg.contains(part), "{part:?} missing from: {msg}");
    }
    msg
}

#[test]
fn base_text_loads() {
    let c = load(&base_text()).unwrap();
    assert_eq!(c.chain().len(), 3);
    assert_eq!(c.home(), &[0.1, -0.2, 0.3]);
    assert_eq!(
        c.joints()[2].model.map(ServoModel::name),
        Some("XL330-M288")
    );
    assert_eq!(c.joints()[2].offset_ticks, -12);
    assert!(c.joints()[2].reverse);
    assert_eq!(c.bus().unwrap().kind, BusKind::Sim);
    assert_eq!(c.arm().unwrap().settings().on_exit, OnExit::TorqueOff);
    // The servo chain the config builds: ids, models and the calibration of every joint.
    let arm = c.arm().unwrap();
    assert_eq!(arm.ids(), [1, 2, 3]);
    assert_eq!(arm.joints()[2].calibration.offset_ticks, -12);
    assert!(arm.joints()[2].calibration.reverse);
    assert_eq!(c.sim().unwrap().seed, 7);
    assert_eq!(c.control().strategy, Strategy::Overall);
    assert_eq!(c.server().max_clients, 4);
    assert_eq!(
        c.server().token_file.as_deref(),
        Some(Path::new("config/token.txt"))
    );
    assert_eq!(c.path(), Path::new(FILE));
    let z = c.zenoh();
    assert!(z.enabled && z.accept_commands && !z.multicast);
    assert_eq!(z.mode, ZenohMode::Peer);
    assert_eq!(z.prefix, "lab/arm_1");
    assert_eq!(z.key("joint_states"), "lab/arm_1/joint_states");
    assert_eq!(z.publish_hz, 25.0);
    assert!(z.config_file.is_none());
    let shown = |list: &[Endpoint]| list.iter().map(ToString::to_string).collect::<Vec<_>>();
    assert_eq!(shown(&z.listen), ["tcp/127.0.0.1:7447"]);
    assert_eq!(shown(&z.connect), ["tcp/[::1]:7448", "tcp/localhost:7449"]);
    assert_eq!(z.connect[1].host, Host::Name("localhost".into()));
    assert_eq!(z.connect[1].port, 7449);
}

#[test]
fn defaults_fill_absent_tables() {
    let text = "[arm]\n[[joint]]\nlink_m = 0.5\nmin_rad = -1\nmax_rad = 1\n";
    let c = load(text).unwrap();
    assert_eq!(c.home(), &[0.0]);
    assert_eq!(c.chain().base(), Vec2::zeros());
    assert!(c.bus().is_none());
    assert!(c.sim().is_none());
    assert_eq!(c.control().rate_hz, 100.0);
    assert_eq!(c.control().max_tip_accel_m_s2, 0.5);
    assert_eq!(c.control().deadman, std::time::Duration::from_millis(500));
    assert_eq!(c.control().read_every, 1);
    assert_eq!(
        c.control().max_silence,
        std::time::Duration::from_millis(50)
    );
    assert_eq!(c.control().health_every, 10);
    assert_eq!(c.server().listen.to_string(), "127.0.0.1:7878");
    assert!(c.server().token_file.is_none());
    let z = c.zenoh();
    assert!(!z.enabled && !z.multicast && !z.accept_commands);
    assert_eq!(z.mode, ZenohMode::Peer);
    assert!(z.connect.is_empty() && z.listen.is_empty());
    assert_eq!(z.prefix, "snakectl");
    assert_eq!(z.publish_hz, 50.0);
    assert!(z.config_file.is_none());
}

#[test]
fn chain_matches_the_joints() {
    let c = load(&with("base_x_m = 0.0", "base_x_m = 1.5")).unwrap();
    let chain = c.chain();
    assert_eq!(chain.links(), &[0.1, 0.1, 0.1]);
    assert_eq!(chain.base(), Vec2::new(1.5, 0.0));
    assert_eq!(chain.limits()[1], Some(JointLimit { lo: -2.0, hi: 2.0 }));
}

#[test]
fn no_joints() {
    let text = "[arm]\n";
    refused(text, &["joint", "at least one joint"]);
}

#[test]
fn negative_link() {
    let msg = refused(
        &with(
            "link_m = 0.1\nmin_rad = -2.0\nmax_rad = 2.0\nid = 3",
            "link_m = -0.1\nmin_rad = -2.0\nmax_rad = 2.0\nid = 3",
        ),
        &["joint[3].link_m", "-0.1", "positive"],
    );
    assert_eq!(
        msg,
        "config/test.toml: joint[3].link_m: -0.1 must be finite and positive, at most 1000000"
    );
}

#[test]
fn zero_link() {
    refused(
        &with("link_m = 0.1", "link_m = 0.0"),
        &["joint[1].link_m", "0"],
    );
}

#[test]
fn non_finite_link() {
    refused(
        &with("link_m = 0.1", "link_m = nan"),
        &["joint[1].link_m", "NaN"],
    );
    refused(
        &with("link_m = 0.1", "link_m = inf"),
        &["joint[1].link_m", "inf"],
    );
}

#[test]
fn huge_link() {
    refused(
        &with("link_m = 0.1", "link_m = 2e6"),
        &["joint[1].link_m", "2000000"],
    );
    // Past 1e15 in exponent form, not 301 digits.
    let msg = refused(
        &with("link_m = 0.1", "link_m = 1e300"),
        &["joint[1].link_m"],
    );
    assert_eq!(
        msg,
        "config/test.toml: joint[1].link_m: 1e300 must be finite and positive, at most 1000000"
    );
}

#[test]
fn non_finite_limit() {
    refused(
        &with("min_rad = -2.0", "min_rad = -inf"),
        &["joint[1].min_rad", "-inf"],
    );
    refused(
        &with("max_rad = 2.0", "max_rad = nan"),
        &["joint[1].max_rad", "NaN"],
    );
}

#[test]
fn empty_limits() {
    refused(
        &with(
            "min_rad = -2.0\nmax_rad = 2.0",
            "min_rad = 1.0\nmax_rad = 1.0",
        ),
        &["joint[1].max_rad", "[1, 1]", "min_rad < max_rad"],
    );
    refused(
        &with(
            "min_rad = -2.0\nmax_rad = 2.0",
            "min_rad = 1.0\nmax_rad = -1.0",
        ),
        &["joint[1].max_rad", "[1, -1]"],
    );
}

#[test]
fn base_not_finite() {
    refused(
        &with("base_x_m = 0.0", "base_x_m = nan"),
        &["arm.base_x_m", "NaN"],
    );
    refused(
        &with("base_y_m = 0.0", "base_y_m = 1e9"),
        &["arm.base_y_m", "1000000000"],
    );
    refused(
        &with("base_heading_rad = 0.0", "base_heading_rad = inf"),
        &["arm.base_heading_rad", "inf"],
    );
}

#[test]
fn home_wrong_length() {
    refused(
        &with("home_rad = [0.1, -0.2, 0.3]", "home_rad = [0.1, -0.2]"),
        &["arm.home_rad", "2 entries for 3 joints"],
    );
}

#[test]
fn home_outside_limits() {
    refused(
        &with("home_rad = [0.1, -0.2, 0.3]", "home_rad = [0.1, -2.5, 0.3]"),
        &["arm.home_rad[2]", "-2.5", "joint 2", "[-2, 2]"],
    );
    refused(
        &with("home_rad = [0.1, -0.2, 0.3]", "home_rad = [0.1, nan, 0.3]"),
        &["arm.home_rad[2]", "NaN"],
    );
}

/// A home pose that folds the arm onto itself is refused with the file, naming the links: the
/// daemon could never start from it or go home.
#[test]
fn home_folded_onto_itself() {
    let folded = base_text()
        .replacen(
            "home_rad = [0.1, -0.2, 0.3]",
            "home_rad = [0.0, 3.0, 3.0]",
            1,
        )
        .replace(
            "min_rad = -2.0\nmax_rad = 2.0",
            "min_rad = -3.1\nmax_rad = 3.1",
        );
    refused(&folded, &["arm.home_rad", "links 1 and 3", "home pose"]);
    // The same pose without a [bus] (geometry only, for `solve --config`) is a start like any.
    let (head, _) = folded.split_once("[bus]").unwrap();
    assert!(load(head).is_ok());
}

/// A home pose exactly on a limit is inside it, and so is the servo position it becomes:
/// on the upper limit of joint 1, the lower of joint 2, and both limits of the reversed,
/// offset joint 3 (the nearest tick of 2 rad lies past the limit rounded inward).
#[test]
fn home_on_a_limit_is_inside_in_ticks_too() {
    for home in ["[2.0, -2.0, 2.0]", "[-2.0, 2.0, -2.0]"] {
        let c = load(&with(
            "home_rad = [0.1, -0.2, 0.3]",
            &format!("home_rad = {home}"),
        ))
        .unwrap();
        let arm = c.arm().unwrap();
        for (j, &theta) in arm.joints().iter().zip(c.home()) {
            let nearest = j.calibration.ticks(theta).round() as i32;
            let t = j.position_ticks(theta).unwrap();
            assert!(
                (j.ticks.min..=j.ticks.max).contains(&t),
                "joint {}: {theta} rad is tick {t}, limits {:?}",
                j.joint,
                j.ticks
            );
            assert!((t - nearest).abs() <= 1, "{t} against {nearest}");
            let back = j.calibration.radians(f64::from(t));
            assert!(j.limit.contains(back), "{back} rad");
        }
    }
}

#[test]
fn limits_beyond_the_servos_turn_or_within_one_tick() {
    // 3.5 rad is 2048 + 2281.6 ticks: past 4095.
    refused(
        &with(
            "min_rad = -2.0\nmax_rad = 2.0\nid = 2",
            "min_rad = -2.0\nmax_rad = 3.5\nid = 2",
        ),
        &["joint[2].max_rad", "3.5 rad", "4329.6 ticks", "0..=4095"],
    );
    // Reversed and 12 ticks off: -3.2 rad is 2036 + 2086.1 ticks.
    refused(
        &with(
            "min_rad = -2.0\nmax_rad = 2.0\nid = 3",
            "min_rad = -3.2\nmax_rad = 2.0\nid = 3",
        ),
        &["joint[3].min_rad", "-3.2 rad", "4122.1 ticks"],
    );
    // 1 mrad wide, between two ticks (a tick is 1.53 mrad).
    refused(
        &with(
            "min_rad = -2.0\nmax_rad = 2.0\nid = 1",
            "min_rad = 0.0002\nmax_rad = 0.0012\nid = 1",
        )
        .replace(
            "home_rad = [0.1, -0.2, 0.3]",
            "home_rad = [0.001, -0.2, 0.3]",
        ),
        &["joint[1].max_rad", "no whole servo tick"],
    );
    // Without servos, nothing in ticks is asked of the limits.
    let text = with(
        "min_rad = -2.0\nmax_rad = 2.0\nid = 2",
        "min_rad = -2.0\nmax_rad = 3.5\nid = 2",
    );
    let cut = text.find("[bus]").unwrap();
    let text = text[..cut].to_owned() + &text[text.find("[control]").unwrap()..];
    load(&text).unwrap();
}

#[test]
fn absent_home_must_have_zero_inside() {
    let text = with("home_rad = [0.1, -0.2, 0.3]", "")
        .replacen("min_rad = -2.0", "min_rad = 0.5", 2)
        .replacen("min_rad = 0.5", "min_rad = -2.0", 1);
    refused(
        &text,
        &["arm.home_rad", "absent", "joint 2", "0 rad", "[0.5, 2]"],
    );
}

#[test]
fn absent_home_is_zeros() {
    let c = load(&with("home_rad = [0.1, -0.2, 0.3]", "")).unwrap();
    assert_eq!(c.home(), &[0.0, 0.0, 0.0]);
}

#[test]
fn bad_ids() {
    refused(&with("id = 2", "id = 0"), &["joint[2].id", "0", "1..=252"]);
    refused(&with("id = 2", "id = 253"), &["joint[2].id", "253"]);
    refused(&with("id = 2", "id = -4"), &["joint[2].id", "-4"]);
    refused(
        &with("id = 2", "id = 99999999999"),
        &["joint[2].id", "99999999999"],
    );
}

#[test]
fn duplicate_ids() {
    refused(&with("id = 3", "id = 1"), &["joint[3].id", "1", "joint[1]"]);
}

#[test]
fn unknown_model() {
    refused(
        &with("model = \"XM430-W350\"", "model = \"XM430-W999\""),
        &["joint[2].model", "XM430-W999"],
    );
    // The spelling must be exact.
    refused(
        &with("model = \"XM430-W350\"", "model = \"xm430-w350\""),
        &["joint[2].model", "xm430-w350"],
    );
}

#[test]
fn offset_beyond_one_turn() {
    refused(
        &with("offset_ticks = -12", "offset_ticks = 5000"),
        &["joint[3].offset_ticks", "5000"],
    );
}

#[test]
fn servo_fields_optional_without_bus() {
    let text = base_text();
    let cut = text.find("[bus]").unwrap();
    let text = text[..cut]
        .replace("id = 1\n", "")
        .replace("model = \"XM430-W350\"\n", "");
    let c = load(&text).unwrap();
    assert_eq!(c.joints()[0].id, None);
    assert_eq!(c.joints()[1].model, None);
    assert!(c.bus().is_none());
}

#[test]
fn bus_needs_ids_and_models() {
    refused(&with("id = 1\n", ""), &["joint[1].id", "missing"]);
    refused(
        &with("model = \"XM430-W350\"\n", ""),
        &["joint[2].model", "missing"],
    );
}

#[test]
fn dynamixel_needs_a_port() {
    refused(
        &with("kind = \"sim\"", "kind = \"dynamixel\""),
        &["bus.port", "missing"],
    );
    refused(
        &with("kind = \"sim\"", "kind = \"dynamixel\"\nport = \" \""),
        &["bus.port", "an empty path"],
    );
    let c = load(&with(
        "kind = \"sim\"",
        "kind = \"dynamixel\"\nport = \"/dev/ttyUSB0\"",
    ))
    .unwrap();
    assert_eq!(c.bus().unwrap().port(), Some("/dev/ttyUSB0"));
    assert_eq!(
        c.bus().unwrap().ports,
        [BusPort {
            port: Some("/dev/ttyUSB0".into()),
            ids: vec![1, 2, 3],
        }]
    );
}

/// The base file with `[[bus.ports]]` tables `ports` appended to its `[bus]`.
fn with_ports(kind: &str, ports: &str) -> String {
    with(
        "watchdog_ms = 100\n",
        &format!("watchdog_ms = 100\n{}{ports}", kind),
    )
    .replacen("kind = \"sim\"\n", "", 1)
}

#[test]
fn several_ports_each_with_its_servos() {
    let c = load(&with_ports(
        "kind = \"dynamixel\"\n",
        "[[bus.ports]]\nids = [2, 1]\nport = \"/dev/ttyUSB0\"\n\
         [[bus.ports]]\nids = [3]\nport = \"/dev/ttyUSB1\"\n",
    ))
    .unwrap();
    let bus = c.bus().unwrap();
    assert_eq!(bus.ports.len(), 2);
    assert_eq!(bus.ports[0].ids, [2, 1]);
    assert_eq!(bus.ports[1].port.as_deref(), Some("/dev/ttyUSB1"));
    assert_eq!(bus.port(), None, "no single port");
    assert_eq!(
        c.wire(&[crate::servo::ReadKind::Sync], &[])
            .iter()
            .map(|w| w.servos)
            .collect::<Vec<_>>(),
        [2, 1]
    );
    // Simulated ports need no path.
    let c = load(&with_ports(
        "kind = \"sim\"\n",
        "[[bus.ports]]\nids = [1]\n[[bus.ports]]\nids = [2, 3]\n",
    ))
    .unwrap();
    assert_eq!(c.bus().unwrap().ports[1].ids, [2, 3]);
}

#[test]
fn several_ports_refusals_name_the_field() {
    let sim = "kind = \"sim\"\n";
    let real = "kind = \"dynamixel\"\n";
    for (kind, ports, parts) in [
        (
            sim,
            "[[bus.ports]]\nids = [1, 2]\n[[bus.ports]]\nids = [3, 2]\n",
            &["bus.ports[2].ids[2]", "2 is already on bus.ports[1]"][..],
        ),
        (
            sim,
            "[[bus.ports]]\nids = [1, 1, 2, 3]\n",
            &["bus.ports[1].ids[2]", "already on bus.ports[1]"],
        ),
        (
            sim,
            "[[bus.ports]]\nids = [1]\n[[bus.ports]]\nids = [2]\n",
            &["joint[3].id", "3 is on none of the [[bus.ports]]"],
        ),
        (
            sim,
            "[[bus.ports]]\nids = [1, 2, 3]\n[[bus.ports]]\nids = []\n",
            &["bus.ports[2].ids", "no servo ids"],
        ),
        (
            sim,
            "[[bus.ports]]\nids = [1, 2, 3, 9]\n",
            &["bus.ports[1].ids[4]", "9 is not the id of any [[joint]]"],
        ),
        (
            sim,
            "[[bus.ports]]\nids = [1, 2, 300]\n",
            &["bus.ports[1].ids[3]", "300"],
        ),
        (
            real,
            "[[bus.ports]]\nids = [1]\nport = \"/dev/ttyUSB0\"\n[[bus.ports]]\nids = [2, 3]\n",
            &["bus.ports[2].port", "missing"],
        ),
        (
            real,
            "[[bus.ports]]\nids = [1]\nport = \"/dev/ttyUSB0\"\n\
             [[bus.ports]]\nids = [2, 3]\nport = \"/dev/ttyUSB0\"\n",
            &[
                "bus.ports[2].port",
                "\"/dev/ttyUSB0\" is already the port of bus.ports[1]",
            ],
        ),
        (
            "kind = \"dynamixel\"\nport = \"/dev/ttyUSB0\"\n",
            "[[bus.ports]]\nids = [1, 2, 3]\nport = \"/dev/ttyUSB1\"\n",
            &["bus.port", "[[bus.ports]]"],
        ),
        (
            real,
            "[[bus.ports]]\nids = [1]\nport = \"/dev/ttyUSB0\"\n[[bus.ports]]\nids = [2, 3]\nport = \"\"\n",
            &["bus.ports[2].port", "an empty path"],
        ),
        (
            sim,
            "[[bus.ports]]\nids = [1, 2, 3]\nspeed = 3\n",
            &["unknown field", "speed"],
        ),
    ] {
        refused(&with_ports(kind, ports), parts);
    }
}

#[test]
fn a_disconnect_names_one_of_the_ports() {
    let two = with_ports(
        "kind = \"sim\"\n",
        "[[bus.ports]]\nids = [1]\n[[bus.ports]]\nids = [2, 3]\n",
    );
    let c = load(&format!(
        "{two}\n[[sim.fault]]\nkind = \"disconnect\"\nport = 2\nat_s = 1.0\n"
    ))
    .unwrap();
    assert_eq!(c.sim().unwrap().faults[0].port, Some(1));
    refused(
        &format!("{two}\n[[sim.fault]]\nkind = \"disconnect\"\nport = 3\nat_s = 1.0\n"),
        &["sim.fault[1].port", "3"],
    );
}

#[test]
fn bus_numbers() {
    refused(
        &with("baud = 1000000", "baud = 100000"),
        &["bus.baud", "100000"],
    );
    refused(
        &with("return_delay_us = 0", "return_delay_us = 3"),
        &["bus.return_delay_us", "3"],
    );
    refused(
        &with("return_delay_us = 0", "return_delay_us = 510"),
        &["bus.return_delay_us", "510"],
    );
    refused(
        &with("watchdog_ms = 100", "watchdog_ms = 30"),
        &["bus.watchdog_ms", "30"],
    );
    refused(
        &with("watchdog_ms = 100", "watchdog_ms = 2560"),
        &["bus.watchdog_ms", "2560"],
    );
    refused(
        &with("watchdog_ms = 100", "reply_timeout_ms = 0"),
        &["bus.reply_timeout_ms", "0"],
    );
    refused(
        &with("watchdog_ms = 100", "profile_velocity_rad_s = -1.0"),
        &["bus.profile_velocity_rad_s", "-1"],
    );
    refused(
        &with("watchdog_ms = 100", "profile_acceleration_rad_s2 = nan"),
        &["bus.profile_acceleration_rad_s2", "NaN"],
    );
}

#[test]
fn unknown_enum_values_are_syntax_errors() {
    refused(
        &with("kind = \"sim\"", "kind = \"usb\""),
        &[":", "usb", "dynamixel"],
    );
    refused(
        &with("watchdog_ms = 100", "on_exit = \"explode\""),
        &["explode", "torque_off"],
    );
    refused(
        &with("strategy = \"overall\"", "strategy = \"greedy\""),
        &["greedy", "sequential"],
    );
}

#[test]
fn faults_parse() {
    let text = with(
        "seed = 7",
        r#"seed = 7
[[sim.fault]]
kind = "drop"
fraction = 0.1
[[sim.fault]]
kind = "corrupt"
fraction = 0.05
id = 2
at_s = 1.0
until_s = 2.0
[[sim.fault]]
kind = "latency"
extra_us = 300
[[sim.fault]]
kind = "silent"
id = 3
at_s = 2.0
[[sim.fault]]
kind = "hardware_error"
id = 1
at_s = 4.5
error = "overload""#,
    );
    let c = load(&text).unwrap();
    let faults = &c.sim().unwrap().faults;
    assert_eq!(faults.len(), 5);
    assert_eq!(
        faults[3],
        Fault {
            kind: FaultKind::Silent,
            id: Some(3),
            port: None,
            from: Duration::from_secs(2),
            until: None
        }
    );
    assert_eq!(
        faults[4],
        Fault {
            kind: FaultKind::HardwareError(HardwareError::Overload),
            id: Some(1),
            port: None,
            from: Duration::from_millis(4500),
            until: None
        }
    );
}

#[test]
fn a_hardware_error_takes_the_simulators_names() {
    for name in ["voltage", "input_voltage"] {
        let c = load(&with_fault(&format!(
            "kind = \"hardware_error\"\nid = 2\nat_s = 1.0\nerror = \"{name}\""
        )))
        .unwrap();
        assert_eq!(
            c.sim().unwrap().faults[0].kind,
            FaultKind::HardwareError(HardwareError::InputVoltage),
            "{name}"
        );
    }
}

#[test]
fn a_disconnect_fault_parses_with_its_window_and_no_servo() {
    let c = load(&with_fault(
        "kind = \"disconnect\"\nat_s = 2.0\nuntil_s = 3.5",
    ))
    .unwrap();
    assert_eq!(
        c.sim().unwrap().faults,
        [Fault {
            kind: FaultKind::Disconnect,
            id: None,
            port: None,
            from: Duration::from_secs(2),
            until: Some(Duration::from_millis(3500)),
        }]
    );
    // Without `until_s` the bus never comes back.
    let c = load(&with_fault("kind = \"disconnect\"\nat_s = 1.0")).unwrap();
    assert_eq!(c.sim().unwrap().faults[0].until, None);
}

#[test]
fn a_disconnect_fault_is_checked_like_the_others() {
    // The whole bus goes: no servo to name.
    refused(
        &with_fault("kind = \"disconnect\"\nid = 2\nat_s = 1.0\nuntil_s = 2.0"),
        &["id", "at_s", "until_s"],
    );
    refused(
        &with_fault("kind = \"disconnect\"\nat_s = 3.0\nuntil_s = 2.0"),
        &["sim.fault[1].until_s", "2", "3"],
    );
    refused(
        &with_fault("kind = \"disconnect\"\nat_s = -1.0\nuntil_s = 2.0"),
        &["sim.fault[1].at_s", "-1"],
    );
    refused(
        &with_fault("kind = \"disconnect\"\nuntil_s = 2.0"),
        &["at_s"],
    );
    // The list of kinds in the refusal of an unknown one names it.
    refused(&with_fault("kind = \"meteor\""), &["meteor", "disconnect"]);
}

fn with_fault(fault: &str) -> String {
    with("seed = 7", &format!("seed = 7\n[[sim.fault]]\n{fault}"))
}

#[test]
fn fault_checks() {
    refused(
        &with_fault("kind = \"drop\"\nfraction = 1.5"),
        &["sim.fault[1].fraction", "1.5"],
    );
    refused(
        &with_fault("kind = \"silent\"\nid = 9\nat_s = 1.0"),
        &["sim.fault[1].id", "9"],
    );
    refused(
        &with_fault("kind = \"silent\"\nid = 2\nat_s = -1.0"),
        &["sim.fault[1].at_s", "-1"],
    );
    refused(
        &with_fault("kind = \"latency\"\nextra_us = 5\nat_s = 3.0\nuntil_s = 2.0"),
        &["sim.fault[1].until_s", "2", "3"],
    );
    refused(
        &with_fault("kind = \"hardware_error\"\nid = 2\nat_s = 1.0\nerror = \"tired\""),
        &["tired", "overheating"],
    );
    refused(&with_fault("kind = \"meteor\""), &["meteor", "silent"]);
}

#[test]
fn control_checks() {
    refused(
        &with("rate_hz = 100.0", "rate_hz = 0.0"),
        &["control.rate_hz", "0"],
    );
    refused(
        &with("rate_hz = 100.0", "rate_hz = -5.0"),
        &["control.rate_hz", "-5"],
    );
    refused(
        &with("rate_hz = 100.0", "max_tip_speed_m_s = inf"),
        &["control.max_tip_speed_m_s", "inf"],
    );
    refused(
        &with("rate_hz = 100.0", "max_joint_speed_rad_s = 0"),
        &["control.max_joint_speed_rad_s", "0"],
    );
    refused(
        &with("rate_hz = 100.0", "rate_hz = 2000.5"),
        &["control.rate_hz", "2000.5", "2000"],
    );
    load(&with("rate_hz = 100.0", "rate_hz = 2000.0")).unwrap();
    refused(
        &with("rate_hz = 100.0", "max_tip_accel_m_s2 = 0.0"),
        &["control.max_tip_accel_m_s2", "0"],
    );
    refused(
        &with("rate_hz = 100.0", "deadman_ms = 0"),
        &["control.deadman_ms", "0"],
    );
    refused(
        &with("rate_hz = 100.0", "read_every = 0"),
        &["control.read_every", "0"],
    );
    refused(
        &with("rate_hz = 100.0", "max_missed_reads = 0"),
        &["control.max_missed_reads", "0"],
    );
    refused(
        &with("rate_hz = 100.0", "health_every = 0"),
        &["control.health_every", "0"],
    );
    refused(
        &with("rate_hz = 100.0", "max_silence_ms = 0"),
        &["control.max_silence_ms", "0"],
    );
    for bad in ["0", "100", "-1", "300"] {
        refused(
            &with("rate_hz = 100.0", &format!("realtime_priority = {bad}")),
            &["control.realtime_priority", bad, "1 to 99"],
        );
    }
}

#[test]
fn a_realtime_priority_is_taken_as_given_and_absent_by_default() {
    for p in [1, 50, 99] {
        let text = with(
            "rate_hz = 100.0",
            &format!("rate_hz = 100.0\nrealtime_priority = {p}"),
        );
        assert_eq!(load(&text).unwrap().control().realtime_priority, Some(p));
    }
    assert_eq!(
        load(&base_text()).unwrap().control().realtime_priority,
        None
    );
}

#[test]
fn the_error_budget_is_a_time_and_the_old_count_converts_at_the_read_rate() {
    let c = load(&with(
        "rate_hz = 100.0",
        "rate_hz = 100.0\nmax_silence_ms = 120",
    ))
    .unwrap();
    assert_eq!(
        c.control().max_silence,
        std::time::Duration::from_millis(120)
    );
    // 5 reads, every 2nd tick at 200 Hz: 50 ms.
    let c = load(&with(
        "rate_hz = 100.0",
        "rate_hz = 200.0\nread_every = 2\nmax_missed_reads = 5",
    ))
    .unwrap();
    assert_eq!(
        c.control().max_silence,
        std::time::Duration::from_millis(50)
    );
    let msg = refused(
        &with(
            "rate_hz = 100.0",
            "rate_hz = 100.0\nmax_missed_reads = 5\nmax_silence_ms = 50",
        ),
        &["control.max_missed_reads", "control.max_silence_ms"],
    );
    assert!(msg.contains("replaces"), "{msg}");
}

#[test]
fn server_checks() {
    refused(
        &with("listen = \"127.0.0.1:7878\"", "listen = \"localhost\""),
        &["server.listen", "localhost"],
    );
    refused(
        &with("max_clients = 4", "max_clients = 0"),
        &["server.max_clients", "0"],
    );
    let c = load(&with(
        "token_file = \"token.txt\"",
        "token_file = \"/etc/snake\"",
    ))
    .unwrap();
    assert_eq!(
        c.server().token_file.as_deref(),
        Some(Path::new("/etc/snake"))
    );
}

/// A key that no table knows is refused with its name and its line, in every table.
#[test]
fn unknown_keys_refused_everywhere() {
    let cases = [
        ("[arm]\n", "[arm]\nbase_z_m = 1.0\n", "base_z_m"),
        ("id = 1\n", "id = 1\nspeed = 3\n", "speed"),
        ("kind = \"sim\"\n", "kind = \"sim\"\nparity = 1\n", "parity"),
        ("seed = 7\n", "seed = 7\nnoise = 1\n", "noise"),
        (
            "rate_hz = 100.0\n",
            "rate_hz = 100.0\nrate_ms = 1\n",
            "rate_ms",
        ),
        (
            "max_clients = 4\n",
            "max_clients = 4\npassword = \"x\"\n",
            "password",
        ),
        (
            "publish_hz = 25.0\n",
            "publish_hz = 25.0\nrouter = true\n",
            "router",
        ),
    ];
    for (from, to, key) in cases {
        let text = with(from, to);
        let line = text[..text.find(key).unwrap()].matches('\n').count() + 1;
        let msg = refused(&text, &[key, "unknown field"]);
        assert!(
            msg.starts_with(&format!("{FILE}:{line}:")),
            "wrong line for {key}: {msg}"
        );
    }
    // A top-level table nobody knows.
    refused(
        &format!("{}\n[joystick]\ndeadman = 1\n", base_text()),
        &["joystick"],
    );
    // A key inside a fault, whatever its kind.
    refused(
        &with_fault("kind = \"silent\"\nid = 2\nat_s = 1.0\nfor_s = 1.0"),
        &["for_s"],
    );
}

#[test]
fn syntax_error_has_line_and_column() {
    let text = "[arm]\n\n[[joint]]\nlink_m = = 0.1\n";
    let err = load(text).unwrap_err();
    match &err {
        ConfigError::Syntax { line, column, .. } => {
            assert_eq!(*line, 4);
            assert!(*column >= 8, "column {column}");
        }
        other => panic!("expected a syntax error, got {other:?}"),
    }
    assert!(err.to_string().starts_with("config/test.toml:4:"));
}

#[test]
fn wrong_type_is_a_syntax_error() {
    refused(
        &with("link_m = 0.1", "link_m = \"long\""),
        &["config/test.toml:9:"],
    );
}

#[test]
fn missing_required_key() {
    refused(&with("link_m = 0.1\n", ""), &["link_m", "missing"]);
}

#[test]
fn load_reports_unreadable_file() {
    let err = Config::load("/nonexistent/snake.toml").unwrap_err();
    assert!(matches!(err, ConfigError::Read { .. }));
    assert!(err
        .to_string()
        .starts_with("/nonexistent/snake.toml: cannot read"));
}

#[test]
fn an_unknown_model_names_the_known_ones() {
    let err = load(&base_text().replace("\"XL330-M288\"", "\"XL330-M999\"")).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("joint[3].model") && msg.contains("XL330-M999"),
        "{msg}"
    );
    assert!(
        msg.contains("XL430-W250") && msg.contains("XM540-W270"),
        "{msg}"
    );
}

#[test]
fn a_fault_time_beyond_any_clock_is_refused() {
    refused(
        &with_fault("kind = \"silent\"\nid = 1\nat_s = 1e300"),
        &["sim.fault[1].at_s"],
    );
}

/// `base_text` with its `[zenoh]` table replaced by `table` (the lines after the header).
fn with_zenoh(table: &str) -> String {
    let text = base_text();
    let at = text.find("[zenoh]\n").unwrap();
    format!("{}[zenoh]\n{table}\n", &text[..at])
}

#[test]
fn zenoh_defaults_follow_a_slow_loop() {
    // Absent publish_hz: 50 Hz, or the loop's rate when that is slower.
    // (A read every 50 ms needs a silence budget above it.)
    let c = load(
        &with("rate_hz = 100.0", "rate_hz = 20.0\nmax_silence_ms = 100")
            .replace("publish_hz = 25.0\n", ""),
    )
    .unwrap();
    assert_eq!(c.zenoh().publish_hz, 20.0);
    let c = load(&with_zenoh("")).unwrap();
    assert_eq!(c.zenoh().publish_hz, 50.0);
    assert!(!c.zenoh().enabled);
}

#[test]
fn zenoh_endpoints_must_be_tcp_host_port() {
    let cases = [
        ("udp/127.0.0.1:7447", "only tcp"),
        ("tls/arm.local:7447", "only tcp"),
        ("127.0.0.1:7447", "no transport"),
        ("tcp/127.0.0.1", "no :port"),
        ("tcp/127.0.0.1:70000", "70000"),
        ("tcp/127.0.0.1:", "port"),
        ("tcp/::1:7447", "brackets"),
        ("tcp/[::1:7447", "[address]:port"),
        ("tcp/[fe80::zz]:7447", "not an IPv6 address"),
        ("tcp/arm_1.local:7447", "host name"),
        ("tcp/:7447", "host name"),
        ("tcp/10.0.0.300:7447", "host name"),
        ("tcp/127.0.0.1:7447#iface=lo", "config_file"),
        ("tcp/127.0.0.1:7447?prio=1", "config_file"),
    ];
    for (endpoint, reason) in cases {
        let table = format!("listen = [\"tcp/127.0.0.1:7447\", \"{endpoint}\"]");
        refused(&with_zenoh(&table), &["zenoh.listen[2]", endpoint, reason]);
        let table = format!("connect = [\"{endpoint}\"]");
        refused(&with_zenoh(&table), &["zenoh.connect[1]", endpoint, reason]);
    }
    // Port 0 picks a free port for a listener, but cannot be connected to.
    let c = load(&with_zenoh("listen = [\"tcp/127.0.0.1:0\"]")).unwrap();
    assert_eq!(c.zenoh().listen[0].port, 0);
    refused(
        &with_zenoh("connect = [\"tcp/127.0.0.1:0\"]"),
        &["zenoh.connect[1]", "port 0"],
    );
}

#[test]
fn zenoh_endpoints_are_listed_once() {
    refused(
        &with_zenoh(r#"listen = ["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/127.0.0.1:7447"]"#),
        &[
            "zenoh.listen[3]",
            "\"tcp/127.0.0.1:7447\" is already zenoh.listen[1]",
        ],
    );
    refused(
        &with_zenoh(r#"connect = ["tcp/10.0.0.1:7447", "tcp/10.0.0.1:7447"]"#),
        &["zenoh.connect[2]", "is already zenoh.connect[1]"],
    );
    // Port 0 is a new port each time.
    let c = load(&with_zenoh(
        r#"listen = ["tcp/127.0.0.1:0", "tcp/127.0.0.1:0"]"#,
    ))
    .unwrap();
    assert_eq!(c.zenoh().listen.len(), 2);
}

#[test]
fn zenoh_endpoints_know_loopback() {
    let loopback = |text: &str| Endpoint::parse(text).unwrap().is_loopback();
    assert!(loopback("tcp/127.0.0.1:7447"));
    assert!(loopback("tcp/127.3.2.1:7447"));
    assert!(loopback("tcp/[::1]:7447"));
    assert!(loopback("tcp/LocalHost:7447"));
    assert!(!loopback("tcp/0.0.0.0:7447"));
    assert!(!loopback("tcp/[::]:7447"));
    assert!(!loopback("tcp/192.168.1.10:7447"));
    assert!(!loopback("tcp/arm.local:7447"));
    assert!(!loopback("tcp/localhost.example.org:7447"));
}

#[test]
fn zenoh_prefix_is_a_plain_key_expression() {
    for (prefix, reason) in [
        ("", "empty"),
        ("arm/*", "wildcards"),
        ("arm/**", "wildcards"),
        ("arm$*", "wildcards"),
        ("arm?x", "wildcards"),
        ("arm#1", "wildcards"),
        ("/arm", "leading or trailing"),
        ("arm/", "leading or trailing"),
        ("lab//arm", "empty chunk"),
        ("lab/@arm", "reserved"),
    ] {
        let table = format!("prefix = \"{prefix}\"");
        refused(
            &with_zenoh(&table),
            &["zenoh.prefix", &format!("\"{prefix}\""), reason],
        );
    }
    for prefix in ["arm", "lab/arm_1", "fleet/row-2/arm.3"] {
        let table = format!("prefix = \"{prefix}\"");
        assert_eq!(load(&with_zenoh(&table)).unwrap().zenoh().prefix, prefix);
    }
}

#[test]
fn zenoh_prefix_is_printable_ascii_without_spaces() {
    // TOML escapes in, Rust's escapes in the message: the field is named, the value shown.
    for (toml, shown) in [
        (r"arm\n1", r#""arm\n1""#),
        (r"arm\u0000", r#""arm\0""#),
        ("arm 1", r#""arm 1""#),
        (r"arm\t1", r#""arm\t1""#),
        ("bras_é", r#""bras_é""#),
        (r"arm\u202e1", r#""arm\u{202e}1""#),
    ] {
        let table = format!("prefix = \"{toml}\"");
        refused(
            &with_zenoh(&table),
            &["zenoh.prefix", shown, "only printable ASCII"],
        );
    }
    refused(
        &with_zenoh(r#"prefix = 'lab\arm'"#),
        &["zenoh.prefix", r#""lab\\arm""#, "no \\"],
    );
}

#[test]
fn zenoh_ros2_needs_a_ros_namespace_and_a_domain_id_in_range() {
    let c = load(&with_zenoh("")).unwrap();
    assert!(!c.zenoh().ros2);
    assert_eq!(c.zenoh().domain_id, 0);
    let c = load(&with_zenoh(
        "ros2 = true\ndomain_id = 232\nprefix = \"lab/arm_1\"",
    ))
    .unwrap();
    assert!(c.zenoh().ros2);
    assert_eq!(c.zenoh().domain_id, 232);
    // A key prefix Zenoh takes, but not a ROS 2 namespace: refused only with ros2 on.
    let table = "prefix = \"fleet/row-2\"";
    assert_eq!(
        load(&with_zenoh(table)).unwrap().zenoh().prefix,
        "fleet/row-2"
    );
    refused(
        &with_zenoh(&format!("ros2 = true\n{table}")),
        &["zenoh.prefix", "\"fleet/row-2\"", "letters, digits and _"],
    );
    refused(
        &with_zenoh("ros2 = true\nprefix = \"lab/2nd_arm\""),
        &["zenoh.prefix", "may not start with a digit"],
    );
    refused(
        &with_zenoh("domain_id = 233"),
        &["zenoh.domain_id", "233", "0..=232"],
    );
}

#[test]
fn zenoh_publish_hz_is_positive_and_at_most_the_loop_rate() {
    for value in ["0.0", "-5.0", "100.5", "nan", "inf"] {
        let table = format!("publish_hz = {value}");
        refused(
            &with_zenoh(&table),
            &["zenoh.publish_hz", "control.rate_hz = 100 Hz"],
        );
    }
    let c = load(&with_zenoh("publish_hz = 100.0")).unwrap();
    assert_eq!(c.zenoh().publish_hz, 100.0);
}

#[test]
fn zenoh_commands_from_beyond_this_host_need_access_control() {
    let exposed = [
        (
            "listen = [\"tcp/127.0.0.1:7447\", \"tcp/0.0.0.0:7447\"]",
            "zenoh.listen[2] = \"tcp/0.0.0.0:7447\" is not loopback",
        ),
        (
            "connect = [\"tcp/192.168.1.10:7447\"]",
            "zenoh.connect[1] = \"tcp/192.168.1.10:7447\" is not loopback",
        ),
        (
            "connect = [\"tcp/router.lab:7447\"]",
            "\"tcp/router.lab:7447\" is not loopback",
        ),
        (
            "listen = [\"tcp/127.0.0.1:7447\"]\nmulticast = true",
            "multicast",
        ),
    ];
    for (lines, exposure) in exposed {
        let table = format!("enabled = true\naccept_commands = true\n{lines}");
        let msg = refused(
            &with_zenoh(&table),
            &[
                "zenoh.accept_commands",
                exposure,
                "config_file",
                "could move",
            ],
        );
        // The same network without commands is fine: watching is harmless.
        load(&with_zenoh(&format!("enabled = true\n{lines}"))).unwrap_or_else(|e| {
            panic!("watching refused ({msg}): {e}");
        });
        // With Zenoh's access control configured, the choice is the user's.
        let table = format!("{table}\nconfig_file = \"zenoh.json5\"");
        let c = load(&with_zenoh(&table)).unwrap();
        assert_eq!(
            c.zenoh().config_file.as_deref(),
            Some(Path::new("config/zenoh.json5"))
        );
    }
    let table = "accept_commands = true\nconfig_file = \"/etc/zenoh/arm.json5\"";
    let c = load(&with_zenoh(table)).unwrap();
    assert_eq!(
        c.zenoh().config_file.as_deref(),
        Some(Path::new("/etc/zenoh/arm.json5"))
    );
}

#[test]
fn an_enabled_zenoh_must_be_reachable() {
    refused(
        &with_zenoh("enabled = true"),
        &["zenoh.listen", "no other session could reach the arm"],
    );
    refused(
        &with_zenoh("enabled = true\nmode = \"client\"\nlisten = [\"tcp/127.0.0.1:7447\"]"),
        &["zenoh.connect", "router"],
    );
    for table in [
        "enabled = true\nmulticast = true",
        "enabled = true\nconnect = [\"tcp/127.0.0.1:7447\"]",
        "enabled = true\nmode = \"client\"\nconnect = [\"tcp/127.0.0.1:7447\"]",
        "enabled = true\nconfig_file = \"zenoh.json5\"",
    ] {
        assert!(load(&with_zenoh(table)).unwrap().zenoh().enabled, "{table}");
    }
    refused(
        &with_zenoh("mode = \"router\""),
        &["config/test.toml:", "router"],
    );
}

mod hostile;
mod world;

#[test]
fn the_ftdi_adapter_model_takes_a_latency_timer_of_the_chip_s_range() {
    let sim = |text: &str| load(text).unwrap().sim().cloned().unwrap();
    assert_eq!(sim(&base_text()).ftdi_latency, None);
    let ftdi = sim(&with("seed = 7", "seed = 7\nadapter = \"ftdi\""));
    assert_eq!(
        ftdi.ftdi_latency,
        Some(Duration::from_millis(16)),
        "the chip's default"
    );
    let one = sim(&with(
        "seed = 7",
        "seed = 7\nadapter = \"ftdi\"\nlatency_timer_ms = 1",
    ));
    assert_eq!(one.ftdi_latency, Some(Duration::from_millis(1)));
    refused(
        &with(
            "seed = 7",
            "seed = 7\nadapter = \"ftdi\"\nlatency_timer_ms = 0",
        ),
        &["sim.latency_timer_ms", "0", "1..=255"],
    );
    refused(
        &with(
            "seed = 7",
            "seed = 7\nadapter = \"ftdi\"\nlatency_timer_ms = 256",
        ),
        &["sim.latency_timer_ms", "256"],
    );
    refused(
        &with("seed = 7", "seed = 7\nlatency_timer_ms = 1"),
        &["sim.latency_timer_ms", "adapter = \"ftdi\""],
    );
    refused(
        &with("seed = 7", "seed = 7\nadapter = \"u2d2\""),
        &["u2d2", "ftdi"],
    );
}

#[test]
fn a_port_s_own_adapter_sets_its_wire_over_the_simulator_s_model() {
    use crate::servo::wire::Adapter;
    use crate::servo::ReadKind;
    let c = load(&with(
        "seed = 7",
        "seed = 7\nadapter = \"ftdi\"\nlatency_timer_ms = 4",
    ))
    .unwrap();
    let modelled = Adapter::ftdi(Duration::from_millis(4));
    let adapter = |found: &[Option<Adapter>]| c.wire(&[ReadKind::Fast], found)[0].adapter;
    assert_eq!(adapter(&[]), Some(modelled));
    assert_eq!(adapter(&[None]), Some(modelled));
    assert_eq!(adapter(&[Some(Adapter::FTDI_1MS)]), Some(Adapter::FTDI_1MS));
    let plain = load(&base_text()).unwrap();
    assert_eq!(plain.wire(&[ReadKind::Sync], &[])[0].adapter, None);
}

#[test]
fn the_bus_read_and_the_simulated_firmware() {
    use crate::servo::ReadChoice;
    let c = load(&base_text()).unwrap();
    assert_eq!(c.arm().unwrap().settings().read, ReadChoice::Auto);
    let sim = c.sim().unwrap();
    assert_eq!(
        (sim.firmware, sim.firmware_by_id.clone()),
        (None, Vec::new())
    );
    for (text, read) in [
        ("\"fast\"", ReadChoice::Fast),
        ("\"sync\"", ReadChoice::Sync),
    ] {
        let c = load(&with(
            "watchdog_ms = 100",
            &format!("watchdog_ms = 100\nread = {text}"),
        ))
        .unwrap();
        assert_eq!(c.arm().unwrap().settings().read, read);
    }
    refused(
        &with("watchdog_ms = 100", "watchdog_ms = 100\nread = \"bulk\""),
        &["bulk", "auto", "fast", "sync"],
    );
    let c = load(&with(
        "seed = 7",
        "seed = 7\nfirmware = 44\n[sim.firmware_by_id]\n2 = 46\n",
    ))
    .unwrap();
    let sim = c.sim().unwrap();
    assert_eq!(
        (sim.firmware, sim.firmware_by_id.clone()),
        (Some(44), vec![(2, 46)])
    );
    refused(
        &with("seed = 7", "seed = 7\n[sim.firmware_by_id]\n9 = 46\n"),
        &["sim.firmware_by_id.9", "9"],
    );
    refused(
        &with("seed = 7", "seed = 7\n[sim.firmware_by_id]\nthree = 46\n"),
        &["sim.firmware_by_id.three", "not a servo id"],
    );
    refused(
        &with("seed = 7", "seed = 7\nfirmware = 300\n"),
        &["300", "u8"],
    );
}

#[test]
fn the_simulated_boot_time() {
    use crate::connect::sim::sim_config;
    let default = sim_config(&load(&base_text()).unwrap()).unwrap();
    assert_eq!(default.boot_time, snakectl_sim::DEFAULT_BOOT_TIME);
    for ms in [0u64, 50, 60_000] {
        let c = load(&with("seed = 7", &format!("seed = 7\nboot_ms = {ms}"))).unwrap();
        assert_eq!(c.sim().unwrap().boot_time, Some(Duration::from_millis(ms)));
        assert_eq!(sim_config(&c).unwrap().boot_time, Duration::from_millis(ms));
    }
    refused(
        &with("seed = 7", "seed = 7\nboot_ms = 60001"),
        &["sim.boot_ms", "60001", "0..=60000"],
    );
    refused(&with("seed = 7", "seed = 7\nboot_ms = -1"), &["-1", "u32"]);
}

/// `base_text` with a `[foxglove]` table of `table` added (the base text has a token file
/// unless `no_token`).
fn with_foxglove(table: &str, no_token: bool) -> String {
    let mut text = base_text();
    if no_token {
        text = text.replacen("token_file = \"token.txt\"\n", "", 1);
    }
    format!("{text}\n[foxglove]\n{table}\n")
}

#[test]
fn foxglove_is_off_unless_it_listens_and_defaults_follow_the_loop() {
    let c = load(&base_text()).unwrap();
    assert_eq!(c.foxglove().listen, None);
    assert!(!c.foxglove().accept_commands);
    assert_eq!(c.foxglove().publish_hz, 30.0);
    assert_eq!(c.foxglove().max_clients, 8);
    let c = load(&with_foxglove(
        "listen = \"127.0.0.1:8765\"\nmax_clients = 2",
        false,
    ))
    .unwrap();
    assert_eq!(c.foxglove().max_clients, 2);
    let c = load(&with_foxglove("listen = \"127.0.0.1:8765\"", false)).unwrap();
    assert_eq!(c.foxglove().listen, Some("127.0.0.1:8765".parse().unwrap()));
    let slow = with_foxglove("listen = \"[::1]:0\"", false)
        .replacen("rate_hz = 100.0", "rate_hz = 20.0\nmax_silence_ms = 100", 1)
        .replacen("publish_hz = 25.0\n", "", 1);
    let c = load(&slow).unwrap();
    assert_eq!(c.foxglove().publish_hz, 20.0, "at most the loop's rate");
    let c = load(&with_foxglove(
        "listen = \"127.0.0.1:0\"\npublish_hz = 10.0\naccept_commands = true",
        true,
    ))
    .unwrap();
    assert_eq!(
        (c.foxglove().publish_hz, c.foxglove().accept_commands),
        (10.0, true)
    );
}

#[test]
fn foxglove_refusals_name_the_field() {
    refused(
        &with_foxglove("listen = \"localhost:8765\"", false),
        &["foxglove.listen", "localhost:8765", "not an address"],
    );
    for exposed in ["0.0.0.0:8765", "192.168.1.5:8765", "[::]:8765"] {
        // With the token every client must present, any address will do.
        let c = load(&with_foxglove(&format!("listen = \"{exposed}\""), false)).unwrap();
        assert_eq!(c.foxglove().listen, Some(exposed.parse().unwrap()));
        let msg = refused(
            &with_foxglove(&format!("listen = \"{exposed}\""), true),
            &[
                "foxglove.listen",
                exposed,
                "loopback",
                "ssh -L 8765:127.0.0.1:8765",
            ],
        );
        assert!(msg.contains("token"), "{msg}");
    }
    refused(
        &with_foxglove("listen = \"127.0.0.1:8765\"\nmax_clients = 0", false),
        &["foxglove.max_clients", "0", "at least 1"],
    );
    for rate in ["0.0", "-1.0", "200.0", "nan"] {
        refused(
            &with_foxglove(
                &format!("listen = \"127.0.0.1:8765\"\npublish_hz = {rate}"),
                false,
            ),
            &["foxglove.publish_hz", "control.rate_hz = 100"],
        );
    }
    let c = load(&with_foxglove(
        "listen = \"127.0.0.1:8765\"\naccept_commands = true",
        false,
    ))
    .unwrap();
    assert!(c.foxglove().accept_commands, "commands behind the token");
    refused(
        &with_foxglove("listen_port = 8765", false),
        &["listen_port"],
    );
}

#[test]
fn a_loop_rate_below_one_hertz_and_a_read_budget_beyond_the_silence_field_are_refused() {
    // 1e-20 Hz is positive and finite, but its period, 1e20 s, is beyond any `Duration` (the
    // loop's schedule and the recorder panicked converting it); below 1 Hz the tick's `dt`,
    // capped at a second, would run every motion slower than asked.
    let slow = |control: &str| {
        base_text()
            .replacen("publish_hz = 25.0\n", "", 1)
            .replacen("watchdog_ms = 100", "watchdog_ms = 2000", 1)
            .replacen("rate_hz = 100.0", control, 1)
    };
    for bad in ["1e-20", "0.5"] {
        refused(
            &slow(&format!("rate_hz = {bad}")),
            &["control.rate_hz", "[1, 2000]"],
        );
    }
    assert!(load(&slow("rate_hz = 1.0\nmax_silence_ms = 1001")).is_ok());
    // The deprecated budget, read as `max_silence_ms`, must fit that field (and a `Duration`:
    // its conversion panicked).
    let msg = std::panic::catch_unwind(|| {
        load(&slow(
            "rate_hz = 1.0\nread_every = 4294967295\nmax_missed_reads = 4294967295",
        ))
        .map_err(|e| e.to_string())
    })
    .expect("the deprecated budget's conversion must not panic")
    .expect_err("the text should be refused");
    assert!(msg.starts_with(FILE), "{msg}");
    assert!(msg.contains("control.max_missed_reads"), "{msg}");
    assert!(msg.contains("4294967295 ms"), "{msg}");
}

#[test]
fn a_fault_s_servo_id_out_of_range_is_named_with_its_value() {
    for (fault, bad) in [
        ("kind = \"silent\"\nid = 300\nat_s = 1.0", "300"),
        ("kind = \"drop\"\nfraction = 0.5\nid = -1", "-1"),
        ("kind = \"blocked\"\nid = 256", "256"),
    ] {
        refused(&with_fault(fault), &["sim.fault[1].id", bad, "1..=252"]);
    }
    refused(
        &with_fault("kind = \"silent\"\nid = 9\nat_s = 1.0"),
        &["sim.fault[1].id", "9", "not the id of any"],
    );
}
