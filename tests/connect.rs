//! The seam from a config to a running bus, as the daemon and the commands use it: the
//! in-process simulator for `kind = "sim"`, an explicit port (here an external `snakectl sim`)
//! whatever the kind says, and the errors a user sees for a file that cannot drive servos.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod cli_support;

use std::path::{Path, PathBuf};

use snakectl::config::Config;
use snakectl::connect::{self, ConnectError, Options};
use snakectl::servo::arm::BringUpOptions;
use snakectl::servo::{Register, ServoBus};

fn shipped(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config")
        .join(name)
}

/// The shipped simulator config with a reply timeout a loaded test machine keeps (the file's
/// 5 ms suits an idle machine or real servos; a real-time simulator on busy cores misses it).
fn sim_config() -> Config {
    let text = std::fs::read_to_string(shipped("sim.toml")).unwrap();
    assert!(text.contains("reply_timeout_ms = 20 "));
    let text = text.replace("reply_timeout_ms = 20 ", "reply_timeout_ms = 200");
    Config::from_str(&text, shipped("sim.toml")).unwrap()
}

/// Brings the arm up on `link`, checks every joint reads its home angle, shuts down.
fn drive(config: &Config, mut link: connect::Connection) {
    let arm = link.arm.clone();
    let up = arm
        .bring_up(&mut link.bus, BringUpOptions::default())
        .unwrap();
    let tick = std::f64::consts::TAU / 4096.0;
    for (got, want) in up.pose.iter().zip(config.home()) {
        assert!((got - want).abs() <= tick, "{got} vs {want}");
    }
    let t = arm.settings().reply_timeout;
    for id in arm.ids() {
        assert_eq!(
            link.bus.read(id, Register::TorqueEnable, t).unwrap().value,
            1
        );
    }
    arm.shut_down(&mut link.bus).unwrap();
}

#[test]
fn a_sim_config_spawns_its_chain_in_process() {
    let config = sim_config();
    let link = connect::open(&config, Options::default()).unwrap();
    let sim = link.sim.as_ref().expect("the simulator was started");
    assert_eq!(link.arm.ids(), (1..=12).collect::<Vec<u8>>());
    assert_eq!(sim.with_sim(|s| s.servos().len()), 12);
    drive(&config, link);
}

#[test]
fn an_explicit_port_drives_an_external_snakectl_sim_with_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let bus_link = dir.path().join("snake-bus");
    let (_child, pty) = cli_support::spawn_sim("config/sim.toml", &bus_link);
    assert!(pty.starts_with("/dev/pts/"), "{pty}");
    let config = sim_config();
    let options = Options {
        port: Some(bus_link.clone()),
        ..Options::default()
    };
    let link = connect::open(&config, options).unwrap();
    assert!(link.sim.is_none(), "no second simulator in-process");
    drive(&config, link);
}

#[test]
fn a_file_without_a_bus_cannot_be_opened() {
    let text = "[arm]\n[[joint]]\nlink_m = 0.1\nmin_rad = -1.0\nmax_rad = 1.0\n";
    let config = Config::from_str(text, "geometry.toml").unwrap();
    let err = connect::open(&config, Options::default()).unwrap_err();
    assert!(matches!(err, ConnectError::NoBus { .. }), "{err}");
    let text = err.to_string();
    assert!(
        text.contains("geometry.toml") && text.contains("[bus]"),
        "{text}"
    );
}

#[test]
fn a_missing_serial_port_is_named_with_a_hint() {
    let text = std::fs::read_to_string(shipped("sim.toml"))
        .unwrap()
        .replace(
            "kind = \"sim\"",
            "kind = \"dynamixel\"\nport = \"/nonexistent/ttyUSB7\"",
        );
    let config = Config::from_str(&text, "real.toml").unwrap();
    let err = connect::open(&config, Options::default()).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, ConnectError::Open { .. }), "{text}");
    assert!(
        text.contains("/nonexistent/ttyUSB7") && text.contains("snakectl ports"),
        "{text}"
    );
}

#[test]
fn a_model_the_simulator_lacks_is_named_with_its_joint() {
    let text = std::fs::read_to_string(shipped("sim.toml")).unwrap();
    let first = text.find("\"XL430-W250\"").unwrap();
    let text = format!(
        "{}\"XM540-W270\"{}",
        &text[..first],
        &text[first + "\"XL430-W250\"".len()..]
    );
    let config = Config::from_str(&text, "odd.toml").unwrap();
    let err = connect::open(&config, Options::default()).unwrap_err();
    let text = err.to_string();
    assert!(
        text.starts_with("odd.toml: joint[1].model: the simulator does not model the XM540-W270"),
        "{text}"
    );
}
