//! `snakectl scan`, `ports` and `servo` as a user runs them, against a simulated chain served
//! in-process on a pseudo-terminal (real time).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::cli_support;

use std::process::Output;
use std::sync::Arc;
use std::time::Duration;

use snakectl_sim::table::addr;
use snakectl_sim::{Fault, HardwareErrorKind, Model, RealClock, ServoSpec, SimConfig, SimHandle};

fn serve(faults: Vec<Fault>) -> SimHandle {
    let mut servos: Vec<ServoSpec> = (1..=4)
        .map(|id| ServoSpec::new(id, Model::Xl430W250))
        .collect();
    servos[3].initial_position_ticks = Some(2100);
    servos.push(ServoSpec::new(7, Model::Xl330M288));
    let config = SimConfig {
        servos,
        faults,
        ..SimConfig::default()
    };
    snakectl::connect::serve(config, Arc::new(RealClock)).unwrap()
}

/// Runs the binary with nothing on stdin.
fn snakectl(args: &[&str]) -> Output {
    cli_support::snakectl(args, "")
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn scan_lists_id_model_and_firmware() {
    let sim = serve(vec![]);
    let port = sim.path().to_str().unwrap().to_string();
    let out = snakectl(&[
        "scan",
        "--port",
        &port,
        "--baud",
        "1000000",
        "--timeout-ms",
        "300",
    ]);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stderr}");
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines[0], "1000000 baud: 5 servo(s)");
    assert_eq!(lines[1], "  id   1  XL430-W250 (1060)  firmware 48");
    assert_eq!(lines[5], "  id   7  XL330-M288 (1200)  firmware 48");
}

#[test]
fn scan_of_a_dead_port_fails_with_a_hint() {
    let out = snakectl(&["scan", "--port", "/dev/does-not-exist", "--baud", "57600"]);
    let (_, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr.contains("snakectl ports"), "{stderr}");
    let out = snakectl(&["scan", "--port", "/dev/null", "--baud", "12345"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out).1.contains("not a Dynamixel baud rate"));
    // An id no servo can have is refused before the port is opened.
    for id in ["253", "254", "255"] {
        let out = snakectl(&["servo", "--port", "/dev/does-not-exist", "--id", id, "info"]);
        assert_eq!(out.status.code(), Some(2));
        assert!(
            text(&out).1.contains("out of range 0..=252"),
            "{}",
            text(&out).1
        );
    }
}

#[test]
fn servo_set_id_and_return_delay_then_refuse_a_taken_id() {
    let sim = serve(vec![]);
    let port = sim.path().to_str().unwrap().to_string();
    let base = [
        "servo",
        "--port",
        &port,
        "--baud",
        "1000000",
        "--timeout-ms",
        "300",
    ];
    let run = |extra: &[&str]| snakectl(&[&base[..], extra].concat());

    let out = run(&["--id", "3", "set-id", "20"]);
    assert!(out.status.success(), "{:?}", text(&out));
    assert_eq!(text(&out).0.trim(), "servo 3: now id 20");
    assert!(sim.with_servo(20, |_| ()).is_some() && sim.with_servo(3, |_| ()).is_none());

    let out = run(&["--id", "20", "set-return-delay", "100"]);
    assert!(out.status.success(), "{:?}", text(&out));
    assert_eq!(
        sim.with_servo(20, |s| s.value(addr::RETURN_DELAY_TIME))
            .flatten(),
        Some(50)
    );

    let out = run(&["--id", "4", "info"]);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stdout.contains("model XL430-W250 (1060), firmware 48\n"),
        "{stdout}"
    );
    assert!(stdout.contains("baud rate 1000000\n"), "{stdout}");
    assert!(
        stdout.contains("present position 2100 ticks (offset_ticks = 52 makes it 0 rad)"),
        "{stdout}"
    );

    let out = run(&["--id", "1", "set-id", "2"]);
    assert_eq!(out.status.code(), Some(2), "{:?}", text(&out));
    assert!(text(&out).1.contains("id 2 is already taken"));

    let out = run(&["--id", "1", "set-return-delay", "3"]);
    assert_eq!(out.status.code(), Some(2));
    let out = run(&["--id", "9", "torque-off"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out).1.contains("servo 9 does not answer"),
        "{:?}",
        text(&out)
    );
}

#[test]
fn servo_reboot_clears_a_hardware_error_and_torque_off_works() {
    let sim = serve(vec![Fault::HardwareError {
        id: 2,
        at: Duration::ZERO,
        kind: HardwareErrorKind::Overload,
    }]);
    let port = sim.path().to_str().unwrap().to_string();
    sim.with_servo(4, |s| s.poke(addr::TORQUE_ENABLE, 1));
    // Without --baud: the servo is found by trying the common rates.
    let out = snakectl(&[
        "servo",
        "--port",
        &port,
        "--timeout-ms",
        "300",
        "--id",
        "2",
        "reboot",
    ]);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stderr}");
    assert_eq!(stdout.trim(), "servo 2: rebooted; hardware errors: none");
    assert_eq!(sim.with_servo(2, |s| s.hardware_error_status()), Some(0));

    let out = snakectl(&[
        "servo",
        "--port",
        &port,
        "--baud",
        "1000000",
        "--id",
        "4",
        "torque-off",
    ]);
    assert!(out.status.success(), "{:?}", text(&out));
    assert_eq!(sim.with_servo(4, |s| s.torque_enabled()), Some(false));
}

#[test]
fn servo_clear_calibration_prints_the_values_before_and_after() {
    let sim = serve(vec![]);
    let port = sim.path().to_str().unwrap().to_string();
    sim.with_servo(2, |s| {
        s.poke(addr::HOMING_OFFSET, -300);
        // Reverse (bit 0) and time-based profile (bit 2).
        s.poke(addr::DRIVE_MODE, 0b101);
        s.poke(addr::TORQUE_ENABLE, 1);
    });
    let run = || {
        snakectl(&[
            "servo",
            "--port",
            &port,
            "--baud",
            "1000000",
            "--timeout-ms",
            "300",
            "--id",
            "2",
            "clear-calibration",
        ])
    };
    let out = run();
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert_eq!(
        stdout.trim(),
        "servo 2: Homing Offset -300 -> 0, Drive Mode 5 -> 4"
    );
    assert_eq!(
        sim.with_servo(2, |s| (
            s.value(addr::HOMING_OFFSET),
            s.value(addr::DRIVE_MODE)
        )),
        Some((Some(0), Some(4)))
    );
    // The others keep theirs; a second run finds nothing left to clear.
    assert_eq!(
        sim.with_servo(1, |s| s.value(addr::DRIVE_MODE)).flatten(),
        Some(0)
    );
    let out = run();
    assert_eq!(out.status.code(), Some(0), "{:?}", text(&out));
    assert_eq!(
        text(&out).0.trim(),
        "servo 2: Homing Offset 0 -> 0, Drive Mode 4 -> 4"
    );
}

#[test]
fn ports_runs_without_libudev() {
    let out = snakectl(&["ports"]);
    assert!(out.status.success(), "{:?}", text(&out));
}

/// Runs `snakectl servo` on `port` at `baud` with `extra` after the common flags.
fn servo_at(port: &str, baud: &str, extra: &[&str]) -> Output {
    let base = [
        "servo",
        "--port",
        port,
        "--baud",
        baud,
        "--timeout-ms",
        "300",
    ];
    snakectl(&[&base[..], extra].concat())
}

/// The ids a `scan --baud` lists, one per reply.
fn scanned(port: &str, baud: &str) -> (Vec<u8>, Output) {
    let out = snakectl(&[
        "scan",
        "--port",
        port,
        "--baud",
        baud,
        "--timeout-ms",
        "300",
    ]);
    let ids = text(&out)
        .0
        .lines()
        .filter_map(|l| l.trim().strip_prefix("id "))
        .filter_map(|l| l.split_whitespace().next())
        .map(|id| id.parse().unwrap())
        .collect();
    (ids, out)
}

#[test]
fn set_baud_refuses_a_rate_where_its_id_is_taken() {
    let sim = serve(vec![]);
    let port = sim.path().to_str().unwrap().to_string();
    // Servo 2 moved to 57600, where id 1 is free: it becomes 1 there.
    let out = servo_at(&port, "1000000", &["--id", "2", "set-baud", "57600"]);
    assert!(out.status.success(), "{:?}", text(&out));
    let out = servo_at(&port, "57600", &["--id", "2", "set-id", "1"]);
    assert!(out.status.success(), "{:?}", text(&out));
    // Back to 1 Mbps would make it a second id 1 there: refused, nothing written.
    let out = servo_at(&port, "57600", &["--id", "1", "set-baud", "1000000"]);
    let (_, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("id 1 is already taken on this bus at 1000000 baud"),
        "{stderr}"
    );
    assert_eq!(scanned(&port, "57600").0, [1]);
    assert_eq!(scanned(&port, "1000000").0, [1, 3, 4, 7]);
    // A rate where the id is free is taken.
    let out = servo_at(&port, "57600", &["--id", "1", "set-baud", "115200"]);
    assert!(out.status.success(), "{:?}", text(&out));
    assert_eq!(scanned(&port, "115200").0, [1]);
}

#[test]
fn scan_reports_an_id_two_servos_answer_and_set_id_refuses_it() {
    let sim = serve(vec![]);
    let port = sim.path().to_str().unwrap().to_string();
    sim.with_servo(2, |s| s.poke(addr::ID, 1));
    let (ids, out) = scanned(&port, "1000000");
    let (_, stderr) = text(&out);
    assert_eq!(ids, [1, 1, 3, 4, 7]);
    assert!(
        stderr.contains("warning: id 1 answered 2 times at 1000000 baud"),
        "{stderr}"
    );
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    // Renaming id 1 would rename both: refused, both keep it.
    let out = servo_at(&port, "1000000", &["--id", "1", "set-id", "9"]);
    let (_, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("id 1 answered 2 times"), "{stderr}");
    assert!(sim.with_servo(9, |_| ()).is_none());
    assert_eq!(scanned(&port, "1000000").0, [1, 1, 3, 4, 7]);
}

#[test]
fn servos_at_9600_and_4500000_are_found_without_baud() {
    let sim = serve(vec![]);
    let port = sim.path().to_str().unwrap().to_string();
    // Baud Rate 0 selects 9600, 7 selects 4.5 Mbps.
    sim.with_servo(3, |s| s.poke(addr::BAUD_RATE, 0));
    sim.with_servo(4, |s| s.poke(addr::BAUD_RATE, 7));
    for (id, rate) in [("3", "9600"), ("4", "4500000")] {
        let out = snakectl(&[
            "servo",
            "--port",
            &port,
            "--timeout-ms",
            "300",
            "--id",
            id,
            "info",
        ]);
        let (stdout, stderr) = text(&out);
        assert!(out.status.success(), "{stderr}");
        assert!(stdout.contains(&format!("baud rate {rate}\n")), "{stdout}");
    }
    let out = snakectl(&["scan", "--port", &port, "--timeout-ms", "50"]);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stderr}");
    assert!(stdout.contains("4500000 baud: 1 servo(s)\n"), "{stdout}");
    assert!(stdout.contains("9600 baud: 1 servo(s)\n"), "{stdout}");
    assert!(
        stdout.ends_with(
            "baud rates tried: 57600, 1000000, 115200, 2000000, 3000000, 4000000, 4500000, 9600\n"
        ),
        "{stdout}"
    );
}

#[test]
fn eeprom_writes_tell_when_they_switched_torque_off() {
    let sim = serve(vec![]);
    let port = sim.path().to_str().unwrap().to_string();
    sim.with_servo(2, |s| s.poke(addr::TORQUE_ENABLE, 1));
    let out = servo_at(&port, "1000000", &["--id", "2", "set-return-delay", "0"]);
    let (_, stderr) = text(&out);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("servo 2: torque was on: switched off to write its EEPROM"),
        "{stderr}"
    );
    assert_eq!(sim.with_servo(2, |s| s.torque_enabled()), Some(false));
    // Off already: nothing to tell.
    let out = servo_at(&port, "1000000", &["--id", "2", "set-return-delay", "0"]);
    let (_, stderr) = text(&out);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("torque was on"), "{stderr}");
    for action in [&["set-id", "20"][..], &["set-baud", "57600"][..]] {
        sim.with_servo(3, |s| s.poke(addr::TORQUE_ENABLE, 1));
        let out = servo_at(&port, "1000000", &[&["--id", "3"][..], action].concat());
        let (_, stderr) = text(&out);
        assert!(out.status.success(), "{stderr}");
        assert!(
            stderr.contains("servo 3: torque was on: switched off"),
            "{action:?}: {stderr}"
        );
        if action[0] == "set-id" {
            sim.with_servo(20, |s| s.poke(addr::ID, 3));
        }
    }
}

#[test]
fn timeouts_and_ids_out_of_range_are_refused_with_one_message() {
    for args in [
        &["servo", "--port", "/dev/does-not-exist", "--id", "1"][..],
        &["scan", "--port", "/dev/does-not-exist"][..],
    ] {
        let mut args = args.to_vec();
        args.extend(["--timeout-ms", "99999999999"]);
        if args[0] == "servo" {
            args.push("info");
        }
        let out = snakectl(&args);
        let (_, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains("--timeout-ms 99999999999 is out of range 0..=10000"),
            "{stderr}"
        );
    }
    for id in ["253", "256", "1000"] {
        let out = snakectl(&[
            "servo",
            "--port",
            "/dev/does-not-exist",
            "--id",
            "1",
            "set-id",
            id,
        ]);
        let (_, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains(&format!("new id {id} is out of range 0..=252")),
            "{stderr}"
        );
        let out = snakectl(&["servo", "--port", "/dev/does-not-exist", "--id", id, "info"]);
        let (_, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains(&format!("--id {id} is out of range 0..=252")),
            "{stderr}"
        );
    }
}

#[test]
fn a_port_lost_mid_scan_is_named() {
    // A simulator of its own process: one served in this process would have its pseudo-
    // terminal inherited by the command run, and never hang up.
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("sim.toml");
    let shipped = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml"));
    std::fs::write(
        &config,
        shipped.unwrap() + "\n[[sim.fault]]\nkind = \"disconnect\"\nat_s = 1.0\n",
    )
    .unwrap();
    let link = dir.path().join("snake-bus");
    let (_sim, _pty) = cli_support::spawn_sim(config.to_str().unwrap(), &link);
    let port = link.to_str().unwrap();
    let out = snakectl(&["scan", "--port", port, "--timeout-ms", "50"]);
    let (_, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "{port} failed (the adapter may have been unplugged)"
        )),
        "{stderr}"
    );
}
