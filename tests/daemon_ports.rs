//! The daemon on a bus of two ports: the embedded simulator serves one pseudo-terminal per
//! port, each with its servos; the arm moves as one and telemetry carries every joint. The
//! faults of one port (a silent servo, a vanished port) are in `daemon_faults.rs`, run on one
//! port and on two.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::net::SocketAddr;

use daemon_support::{dist, floats, sim_config_with, xy, Client, TWO_PORTS};
use serde_json::json;
use snakectl::daemon::{Embedded, RunOptions};

#[test]
fn on_two_ports_of_the_embedded_simulator_the_arm_moves_as_one() {
    let config = sim_config_with(&[], TWO_PORTS);
    assert_eq!(config.bus().unwrap().ports.len(), 2);
    // No port given: the daemon starts one simulator per port itself.
    let localhost = SocketAddr::from(([127, 0, 0, 1], 0));
    let daemon = Embedded::start(config, localhost, RunOptions::default()).unwrap();
    let mut c = Client::connect(daemon.addr());
    let s = c.status();
    let joints = 12;
    for key in [
        "theta_meas",
        "omega_meas",
        "temperature_c",
        "voltage_v",
        "load",
    ] {
        assert_eq!(floats(&s[key]).len(), joints, "{key}: {s}");
    }
    assert_eq!(s["faults"], json!([]), "{s}");
    let start = xy(&s["tip"]);
    let target = [start[0] + 0.04, start[1] - 0.03];
    let id = c.send(json!({"cmd": "goto", "target": target}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    c.event("arrived", Some(id));
    // Both ports' servos followed: the measured tip reaches the target.
    let s = c.wait_status("measured tip on target", |s| {
        dist(xy(&s["tip_meas"]), target) < 2e-3
    });
    let (cmd, meas) = (floats(&s["theta_cmd"]), floats(&s["theta_meas"]));
    for j in 0..joints {
        assert!(
            (cmd[j] - meas[j]).abs() < 2e-3,
            "joint {} measured {} for {}",
            j + 1,
            meas[j],
            cmd[j]
        );
    }
    assert!(s["behind"].is_boolean(), "{s}");
    assert!(s["health_tick"].as_u64().unwrap() > 0, "{s}");
    let summary = daemon.stop().unwrap();
    assert!(summary.ticks > 0, "{summary:?}");
}
