//! The baud rate end to end: `snakectl scan` and `snakectl servo set-baud` against a simulated
//! chain whose servos hear only the rate their Baud Rate register selects, as on hardware.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::cli_support;

use std::process::Output;
use std::sync::Arc;

use snakectl_sim::{Model, RealClock, ServoSpec, SimConfig, SimHandle};

fn serve(baud: u32) -> SimHandle {
    let config = SimConfig {
        servos: (1..=4)
            .map(|id| ServoSpec::new(id, Model::Xl430W250))
            .collect(),
        baud,
        ..SimConfig::default()
    };
    snakectl::connect::serve(config, Arc::new(RealClock)).unwrap()
}

/// Runs the binary with nothing on stdin.
fn snakectl(args: &[&str]) -> Output {
    cli_support::snakectl(args, "")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The `<rate> baud: ...` lines of a scan, and the ids listed under them.
fn scan(port: &str, baud: Option<&str>) -> (Vec<String>, Vec<u8>) {
    let mut args = vec!["scan", "--port", port, "--timeout-ms", "300"];
    if let Some(b) = baud {
        args.extend(["--baud", b]);
    }
    let out = snakectl(&args);
    let text = stdout(&out);
    let rates = text
        .lines()
        .filter(|l| l.contains(" baud: "))
        .map(str::to_string)
        .collect();
    let ids = text
        .lines()
        .filter_map(|l| l.trim().strip_prefix("id "))
        .filter_map(|l| l.split_whitespace().next())
        .map(|id| id.parse().unwrap())
        .collect();
    (rates, ids)
}

#[test]
fn scan_without_baud_finds_the_servos_only_at_their_rate() {
    let sim = serve(115_200);
    let port = sim.path().to_str().unwrap().to_string();
    let (rates, ids) = scan(&port, None);
    assert_eq!(rates, ["115200 baud: 4 servo(s)"]);
    assert_eq!(ids, [1, 2, 3, 4]);
    let (rates, ids) = scan(&port, Some("1000000"));
    assert_eq!(rates, ["1000000 baud: no servo"]);
    assert!(ids.is_empty());
}

#[test]
fn set_baud_moves_one_servo_to_the_new_rate() {
    let sim = serve(1_000_000);
    let port = sim.path().to_str().unwrap().to_string();
    let out = snakectl(&[
        "servo",
        "--port",
        &port,
        "--baud",
        "1000000",
        "--timeout-ms",
        "300",
        "--id",
        "3",
        "set-baud",
        "57600",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        stdout(&out).trim(),
        "servo 3: now at 57600 baud; servos still at 1000000 baud no longer hear it: move each \
         to 57600 too, then set [bus] baud = 57600"
    );
    // Baud Rate register 1 selects 57600.
    assert_eq!(sim.with_servo(3, |s| s.baud_index()), Some(1));
    assert_eq!(scan(&port, Some("57600")).1, [3]);
    assert_eq!(scan(&port, Some("1000000")).1, [1, 2, 4]);
    // Without --baud both rates show up, each with its own servos.
    let (rates, ids) = scan(&port, None);
    assert_eq!(
        rates,
        ["57600 baud: 1 servo(s)", "1000000 baud: 3 servo(s)"]
    );
    assert_eq!(ids, [3, 1, 2, 4]);
}
