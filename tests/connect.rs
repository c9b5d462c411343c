//! The seam from a config to a running bus, as the daemon and the commands use it: the
//! in-process simulator for `kind = "sim"`, an explicit port (here an external `snakectl sim`)
//! whatever the kind says, and the errors a user sees for a file that cannot drive servos.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::cli_support;

use std::path::{Path, PathBuf};
use std::time::Duration;

use snakectl::config::Config;
use snakectl::connect::{self, ConnectError, Options};
use snakectl::servo::arm::{BringUpOptions, Within};
use snakectl::servo::{Register, ServoBus, ServoError};

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
    arm.shut_down(&mut link.bus, &[], &Within::wall(Duration::from_secs(1), t))
        .unwrap();
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

/// Two `[[bus.ports]]` on one device are refused naming the file and the fields, as the
/// config's own errors do; two `--port` flags on one, naming the ports by number.
#[test]
fn one_device_named_twice_is_refused_naming_where() {
    let joints = "[[joint]]\nlink_m = 0.1\nmin_rad = -1\nmax_rad = 1\nid = 1\nmodel = \"XL430-W250\"\n\
                  [[joint]]\nlink_m = 0.1\nmin_rad = -1\nmax_rad = 1\nid = 2\nmodel = \"XL430-W250\"\n";
    let text = format!(
        "{joints}[bus]\nkind = \"dynamixel\"\n[[bus.ports]]\nids = [1]\nport = \"/dev/null\"\n\
         [[bus.ports]]\nids = [2]\nport = \"/dev/../dev/null\"\n"
    );
    let config = Config::from_str(&text, "two.toml").unwrap();
    let err = connect::check_ports(&config, &[]).unwrap_err().to_string();
    assert_eq!(
        err,
        "two.toml: bus.ports[2].port: \"/dev/../dev/null\" is the same device as \
         bus.ports[1].port (\"/dev/null\")"
    );
    let given = [PathBuf::from("/dev/null"), PathBuf::from("/dev/./null")];
    let err = connect::check_ports(&config, &given)
        .unwrap_err()
        .to_string();
    assert_eq!(err, "port 2 (/dev/./null) is the same device as port 1");
}

/// Ports given for a bus of one are counted in the singular.
#[test]
fn ports_given_for_a_bus_of_one_are_counted_in_words_that_agree() {
    let config = sim_config();
    let given = [PathBuf::from("/dev/null"), PathBuf::from("/dev/zero")];
    let err = connect::check_ports(&config, &given)
        .unwrap_err()
        .to_string();
    assert!(
        err.ends_with("2 --port given for the 1 port of [bus]: give one per port, in order"),
        "{err}"
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

/// The shipped simulator config, with `extra` appended (more `[[sim.fault]]` tables).
fn sim_config_with(extra: &str) -> Config {
    let text = std::fs::read_to_string(shipped("sim.toml")).unwrap();
    let text = text.replace("reply_timeout_ms = 20 ", "reply_timeout_ms = 200") + extra;
    Config::from_str(&text, shipped("sim.toml")).unwrap()
}

/// `[sim] adapter = "ftdi"` holds the replies as the chip would, on a pseudo-terminal that tells
/// no latency timer: the bus is opened as behind that adapter, on one port and on several, and
/// so waits out its timer (the chip's default 16 ms) instead of taking the held reply for a
/// chain that broke.
#[test]
fn a_simulated_ftdi_adapter_is_the_one_the_opened_bus_is_behind() {
    use snakectl::servo::wire::Adapter;
    let text = std::fs::read_to_string(shipped("sim.toml")).unwrap();
    let modelled = "# adapter = \"ftdi\"";
    assert!(text.contains(modelled));
    let text = text.replacen(modelled, "adapter = \"ftdi\" #", 1);
    let config = Config::from_str(&text, shipped("sim.toml")).unwrap();
    let ftdi = Adapter::ftdi(Duration::from_millis(16));
    assert_eq!(config.modelled_adapter(), Some(ftdi));
    let options = || Options {
        clock: std::sync::Arc::new(snakectl_sim::ManualClock::new()),
        ..Options::default()
    };
    let one = connect::open(&config, options()).unwrap();
    assert_eq!(one.bus.adapters(), [Some(ftdi)]);
    drop(one);
    let arm = connect::open_arm(&config, options()).unwrap();
    assert_eq!(arm.bus.adapters(), [Some(ftdi)]);
    // Without the model, nothing is assumed.
    let plain = connect::open_arm(&sim_config(), options()).unwrap();
    assert_eq!(plain.bus.adapters(), [None]);
}

/// Poll `done` until it holds, for at most 10 s (reached only on failure).
fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while !done() {
        assert!(
            std::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
}

#[test]
fn the_in_process_simulator_is_reopened_on_its_link_after_a_disconnect() {
    use snakectl::servo::ErrorClass;
    let config =
        sim_config_with("\n[[sim.fault]]\nkind = \"disconnect\"\nat_s = 1.0\nuntil_s = 2.0\n");
    let clock = snakectl_sim::ManualClock::new();
    let options = Options {
        clock: std::sync::Arc::new(clock.clone()),
        ..Options::default()
    };
    let connect::Connection { mut bus, arm, sim } =
        connect::open(&config, options.clone()).unwrap();
    let sim = sim.expect("the simulator was started");
    // `open` went through the simulator's link, in a private temporary directory.
    let port = connect::port_path(&config, &options, Some(&sim)).unwrap();
    assert_eq!(port, sim.path());
    assert!(port.starts_with(std::env::temp_dir()), "{}", port.display());
    let old = sim.pty_path().unwrap();
    assert_eq!(std::fs::read_link(&port).unwrap(), old);
    let t = arm.settings().reply_timeout;
    arm.bring_up(&mut bus, BringUpOptions::default()).unwrap();

    clock.advance(std::time::Duration::from_secs(1));
    wait_for("the unplug", || sim.pty_path().is_none());
    // What the daemon sees: the port itself failed, not a servo. (The kernel may hang the
    // terminal up a little after the other end closed: a ping meanwhile only times out.)
    let mut last = None;
    wait_for("the hang-up", || {
        let e = bus.ping(1, t).unwrap_err();
        let timed_out = e.is_timeout();
        last = Some(e);
        !timed_out
    });
    let err = last.unwrap();
    assert!(
        matches!(err, ServoError::Io(_)) && err.class() == ErrorClass::Bus,
        "{err:?}"
    );
    let err = arm.write_pose(&mut bus, config.home()).unwrap_err();
    assert_eq!(err.class(), ErrorClass::Bus, "{err:?}");
    let baud = config.bus().unwrap().baud;
    match connect::reopen(
        &port,
        baud,
        config.modelled_adapter(),
        &arm,
        options.strategy,
    ) {
        Err(ConnectError::Open { source }) => assert_eq!(source.class(), ErrorClass::Bus),
        other => panic!("reopened while unplugged: {other:?}"),
    }

    clock.advance(std::time::Duration::from_secs(1));
    wait_for("the plug-back", || sim.pty_path().is_some());
    assert_ne!(sim.pty_path().unwrap(), old);
    assert_eq!(bus.ping(1, t).unwrap_err().class(), ErrorClass::Bus);
    let mut bus = connect::reopen(
        &port,
        baud,
        config.modelled_adapter(),
        &arm,
        options.strategy,
    )
    .unwrap();
    for id in arm.ids() {
        bus.ping(id, t).unwrap();
        // Torque stayed on; the Bus Watchdog fired in the silence.
        assert_eq!(bus.read(id, Register::TorqueEnable, t).unwrap().value, 1);
        assert_eq!(bus.read(id, Register::BusWatchdog, t).unwrap().value, -1);
    }
    // Bring-up clears the fired watchdogs and takes the arm back.
    arm.bring_up(&mut bus, BringUpOptions::default()).unwrap();
    let t = arm.settings().reply_timeout;
    arm.shut_down(&mut bus, &[], &Within::wall(Duration::from_secs(1), t))
        .unwrap();
    drop(sim);
    assert!(
        port.symlink_metadata().is_err() && !port.parent().unwrap().exists(),
        "the private link and its directory are removed"
    );
}
