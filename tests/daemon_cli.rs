//! `snakectl run` as a user runs it: the binary a child process, the simulator served by this
//! test on a real pseudo-terminal (`--port`), so the test sees what the servos do when the
//! daemon stops, is told to stop, or is killed.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};

use daemon_support::child::DaemonChild;
use daemon_support::{Client, DEADLINE};
use serde_json::{json, Value};
use snakectl::config::Config;
use snakectl::connect;
use snakectl_sim::{RealClock, SimHandle};

/// The shipped simulator config with `edits`, written to a file in `dir`.
fn config_file(dir: &Path, edits: &[(&str, &str)]) -> (PathBuf, Config) {
    let path = write_config(dir, edits);
    let config = Config::load(&path).unwrap();
    (path, config)
}

/// The same, only written (it may not be valid).
fn write_config(dir: &Path, edits: &[(&str, &str)]) -> PathBuf {
    let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    let mut text = std::fs::read_to_string(shipped).unwrap();
    for (old, new) in [("reply_timeout_ms = 20 ", "reply_timeout_ms = 100")]
        .iter()
        .chain(edits)
    {
        assert!(text.contains(old), "no `{old}` in config/sim.toml");
        text = text.replace(old, new);
    }
    let path = dir.join("arm.toml");
    std::fs::write(&path, &text).unwrap();
    path
}

fn sim(config: &Config) -> SimHandle {
    connect::spawn_sim(config, Arc::new(RealClock)).unwrap()
}

/// Starts a goto that takes about a second and waits until the arm moves.
fn start_moving(client: &mut Client) {
    let s = client.status();
    let tip = [s["tip"][0].as_f64().unwrap(), s["tip"][1].as_f64().unwrap()];
    client.ok(json!({"cmd": "goto", "target": [tip[0] + 0.1, tip[1]]}));
    client.wait_status("moving", |s| s["state"] == "moving");
}

#[test]
fn sigterm_brings_the_arm_to_rest_then_torque_off_and_exits_0() {
    let dir = tempfile::tempdir().unwrap();
    let (path, config) = config_file(dir.path(), &[]);
    let sim = sim(&config);
    let mut daemon = DaemonChild::spawn(&path, sim.path());
    let mut client = Client::connect(daemon.address());
    start_moving(&mut client);
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
    for id in config.arm().unwrap().ids() {
        let (torque, moving) = sim
            .with_servo(id, |s| (s.torque_enabled(), s.moving()))
            .unwrap();
        assert!(!torque, "servo {id} left with torque on");
        assert!(!moving, "servo {id} still moving");
    }
    // The client was told before the connection closed.
    let told: Vec<Value> =
        std::iter::from_fn(|| client.read_line(Duration::from_secs(5))).collect();
    assert!(
        told.iter().any(|l| l["event"] == "shutting_down"),
        "no shutting_down event: {told:?}"
    );
    // The goto came to rest for the shut-down, and is told so (not as if someone sent `stop`).
    assert!(
        told.iter()
            .any(|l| l["event"] == "stopped" && l["reason"] == "shutdown"),
        "no stopped event for the shut-down: {told:?}"
    );
}

/// A hang-up (the terminal or SSH session the daemon ran in closed) stops it as SIGTERM does:
/// the arm at rest, torque off, exit 0; not killed with the servos' torque left on.
#[test]
fn sighup_stops_the_daemon_as_sigterm_does() {
    let dir = tempfile::tempdir().unwrap();
    let (path, config) = config_file(dir.path(), &[]);
    let sim = sim(&config);
    let mut daemon = DaemonChild::spawn(&path, sim.path());
    let mut client = Client::connect(daemon.address());
    start_moving(&mut client);
    daemon.signal("-HUP");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
    for id in config.arm().unwrap().ids() {
        let torque = sim.with_servo(id, |s| s.torque_enabled()).unwrap();
        assert!(!torque, "servo {id} left with torque on");
    }
}

#[test]
fn after_kill_9_the_bus_watchdog_stops_the_servos() {
    let dir = tempfile::tempdir().unwrap();
    let (path, config) = config_file(dir.path(), &[]);
    let watchdog = Duration::from_millis(config.arm().unwrap().settings().watchdog_ms.into());
    let period = Duration::from_secs_f64(1.0 / config.control().rate_hz);
    let sim = sim(&config);
    let mut daemon = DaemonChild::spawn(&path, sim.path());
    let mut client = Client::connect(daemon.address());
    start_moving(&mut client);
    let ids = config.arm().unwrap().ids();
    assert!(ids
        .iter()
        .all(|&id| sim.with_servo(id, |s| s.watchdog()).unwrap() > 0));
    let killed = Instant::now();
    daemon.kill();
    // Poll the simulated servos until every watchdog has fired.
    let fired = loop {
        let tripped = ids
            .iter()
            .all(|&id| sim.with_servo(id, |s| s.watchdog()).unwrap() < 0);
        if tripped {
            break killed.elapsed();
        }
        assert!(killed.elapsed() < DEADLINE, "the watchdogs never fired");
        std::thread::sleep(Duration::from_millis(1));
    };
    // The simulator fires each watchdog exactly `watchdog_ms` after the last packet; the
    // margin is this test's own polling and scheduling.
    assert!(
        fired <= watchdog + period + Duration::from_millis(100),
        "fired {fired:?} after the kill (watchdog {watchdog:?}, period {period:?})"
    );
    let positions = |sim: &SimHandle| -> Vec<i32> {
        ids.iter()
            .map(|&id| sim.with_servo(id, |s| s.present_position()).unwrap())
            .collect()
    };
    let stopped = positions(&sim);
    for &id in &ids {
        assert!(
            !sim.with_servo(id, |s| s.moving()).unwrap(),
            "servo {id} moves"
        );
    }
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(positions(&sim), stopped, "the servos still move");
}

#[test]
fn a_missing_servo_refuses_to_start_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = config_file(dir.path(), &[]);
    // The chain on the bus lacks servo 12.
    let shipped = std::fs::read_to_string(&path).unwrap();
    // The last `[[joint]]` table (a line of its own, not a mention in a comment).
    let cut = shipped.rfind("\n[[joint]]").unwrap() + 1;
    let end = shipped[cut..].find("\n\n").unwrap() + cut;
    let short_text = format!("{}{}", &shipped[..cut], &shipped[end + 2..]).replace(
        "home_rad = [0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1]",
        "home_rad = [0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1]",
    );
    let short = Config::from_str(&short_text, &path).unwrap();
    let sim = sim(&short);
    let mut daemon = DaemonChild::spawn(&path, sim.path());
    let (status, log) = daemon.wait();
    assert_eq!(status.code(), Some(2), "log:\n{log}");
    assert!(
        log.contains("12"),
        "the refusal does not name servo 12:\n{log}"
    );
}

#[test]
fn a_bad_config_value_is_refused_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_config(dir.path(), &[("rate_hz = 100.0", "rate_hz = 5000.0")]);
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["run", "--config"])
        .arg(&path)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("control.rate_hz") && err.contains("2000"),
        "{err}"
    );
}

/// An address another program listens on, or one other hosts reach without a token, refuses
/// start-up (exit code 2), naming it, before anything says it listens.
#[test]
fn a_taken_address_refuses_start_up_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_config(dir.path(), &[]);
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["run", "--listen", &addr, "--config"])
        .arg(&path)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!("listening on {addr}")) && !err.contains("bringing the arm up"),
        "{err}"
    );
    // An address other hosts reach, without a token: refused before the daemon says it
    // listens.
    let out = Command::new(env!("CARGO_BIN_EXE_snakectl"))
        .args(["run", "--listen", "0.0.0.0:0", "--config"])
        .arg(&path)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("refusing to listen on 0.0.0.0:") && !err.contains("bringing the arm up"),
        "{err}"
    );
}

#[test]
fn a_stall_longer_than_the_bus_watchdog_is_recovered_and_the_arm_moves_again() {
    let dir = tempfile::tempdir().unwrap();
    let (path, config) = config_file(dir.path(), &[]);
    let watchdog = Duration::from_millis(config.arm().unwrap().settings().watchdog_ms.into());
    let ids = config.arm().unwrap().ids();
    let sim = sim(&config);
    let mut daemon = DaemonChild::spawn(&path, sim.path());
    let mut client = Client::connect(daemon.address());
    start_moving(&mut client);
    // Stopped for three watchdog periods: every servo's watchdog fires.
    daemon.signal("-STOP");
    let stopped = Instant::now();
    while !ids
        .iter()
        .all(|&id| sim.with_servo(id, |s| s.watchdog()).unwrap() < 0)
    {
        assert!(stopped.elapsed() < DEADLINE, "the watchdogs never fired");
        std::thread::sleep(Duration::from_millis(1));
    }
    // The stall's length is the input here, not a wait for something.
    std::thread::sleep((3 * watchdog).saturating_sub(stopped.elapsed()));
    // A tripped watchdog refuses goals (data range error) until cleared.
    let refused = sim
        .with_servo(1, |s| s.check_write(116, &2048i32.to_le_bytes()))
        .unwrap();
    assert_eq!(refused, Err(4), "a tripped watchdog takes goals");
    daemon.signal("-CONT");
    let event = client
        .next_matching(DEADLINE, |l| {
            l["type"] == "event" && l["event"] == "fault" && l["reason"] == "recovered"
        })
        .expect("a `recovered` fault event");
    assert_eq!(event["fault"]["kind"], "watchdog", "{event}");
    let detail = event["fault"]["detail"].as_str().unwrap();
    println!("stall of {:?}: {detail}", 3 * watchdog);
    for &id in &ids {
        assert!(
            sim.with_servo(id, |s| s.watchdog()).unwrap() > 0,
            "servo {id}: watchdog not re-armed"
        );
    }
    let s = client.status();
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["command"]["outcome"], "fault", "{s}");
    // A goto after the recovery arrives, and the servos follow it.
    let tip = [s["tip"][0].as_f64().unwrap(), s["tip"][1].as_f64().unwrap()];
    let target = [tip[0] - 0.03, tip[1] - 0.02];
    let id = client.send(json!({"cmd": "goto", "target": target}));
    assert_eq!(client.reply(&json!(id))["ok"], json!(true));
    client.event("arrived", Some(id));
    client.wait_status("the servos follow", |s| {
        let m = [
            s["tip_meas"][0].as_f64().unwrap(),
            s["tip_meas"][1].as_f64().unwrap(),
        ];
        (m[0] - target[0]).hypot(m[1] - target[1]) < 2e-3
    });
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    assert!(status.success(), "exit {status:?}; log:\n{log}");
    for &id in &ids {
        assert!(
            !sim.with_servo(id, |s| s.torque_enabled()).unwrap(),
            "servo {id} torque on"
        );
    }
}

#[test]
fn sigterm_with_a_silent_servo_exits_within_a_second_with_code_3_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let (path, config) = config_file(dir.path(), &[]);
    let sim = sim(&config);
    let mut daemon = DaemonChild::spawn(&path, sim.path());
    let mut client = Client::connect(daemon.address());
    start_moving(&mut client);
    sim.with_servo(5, |s| s.set_silent(true)).unwrap();
    client.wait_status("servo 5 held silent", |s| {
        s["faults"]
            .as_array()
            .is_some_and(|f| f.iter().any(|f| f["id"] == 5 && f["kind"] == "silent"))
    });
    let signalled = Instant::now();
    daemon.signal("-TERM");
    let (status, log) = daemon.wait();
    let took = signalled.elapsed();
    println!("SIGTERM with servo 5 silent: exited in {took:?} with {status:?}");
    // Generous for a busy machine: the daemon itself waits on nothing it knows is silent.
    assert!(
        took < Duration::from_secs(1),
        "exited {took:?} after the signal; log:\n{log}"
    );
    assert_eq!(status.code(), Some(3), "log:\n{log}");
    assert!(log.contains("servo 5 (joint 5)"), "log:\n{log}");
    for id in config.arm().unwrap().ids() {
        if id != 5 {
            let torque = sim.with_servo(id, |s| s.torque_enabled()).unwrap();
            assert!(!torque, "servo {id} left with torque on");
        }
    }
}
