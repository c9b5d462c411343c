//! The daemon on a bus of two ports: the embedded simulator serves one pseudo-terminal per
//! port, each with its servos; the arm moves as one and telemetry carries every joint. The
//! faults of one port (a silent servo, a vanished port) are in `daemon_faults.rs`, run on one
//! port and on two.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::net::SocketAddr;

use daemon_support::{dist, floats, sim_config_with, xy, Client, Daemon, TWO_PORTS};
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

#[test]
fn a_port_with_a_servo_too_old_for_fast_sync_read_reads_sync_and_the_other_port_fast() {
    // Servo 9 (second port) has a firmware without Fast Sync Read; `[bus] read = "auto"`.
    let extra = format!("{TWO_PORTS}[sim.firmware_by_id]\n9 = 44\n");
    let d = Daemon::start(sim_config_with(&[], &extra));
    let mut c = d.client();
    let describe = c.ok(json!({"cmd": "describe"}));
    assert_eq!(describe["read"], json!("mixed"), "{describe}");
    // Over the same ticks, the first port answers each read with one packet (Fast Sync Read),
    // the second with one per servo (Sync Read: six).
    let replies =
        |d: &Daemon| [&d.sim, &d.more_sims[0]].map(|sim| sim.with_sim(|s| s.stats().replies));
    let before = replies(&d);
    let start = xy(&c.status()["tip"]);
    let target = [start[0] + 0.03, start[1] - 0.02];
    let id = c.send(json!({"cmd": "goto", "target": target}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    c.event("arrived", Some(id));
    let after = replies(&d);
    let (fast, sync) = (after[0] - before[0], after[1] - before[1]);
    println!("replies over the goto: first port {fast}, second port {sync}");
    assert!(fast > 10, "{fast} replies on the first port");
    assert!(
        sync >= 5 * fast && sync <= 7 * fast,
        "first port {fast} replies, second {sync}: not one reply a read against six"
    );
    let s = c.status();
    assert_eq!(s["faults"], json!([]), "{s}");
    assert!(dist(xy(&s["tip"]), target) < 1e-9, "{s}");
}

/// Each thread of this process, by name: (name, scheduling policy, real-time priority), from
/// `/proc/self/task/*/stat` (fields 41 and 40; 1 is `SCHED_FIFO`, 0 the normal policy).
fn threads() -> Vec<(String, u32, u32)> {
    let mut out = Vec::new();
    for task in std::fs::read_dir("/proc/self/task").unwrap() {
        let Ok(stat) = std::fs::read_to_string(task.unwrap().path().join("stat")) else {
            continue; // the thread ended meanwhile
        };
        let open = stat.find('(').unwrap();
        let close = stat.rfind(')').unwrap();
        let name = stat[open + 1..close].to_owned();
        // After the name, fields 3 on.
        let rest: Vec<&str> = stat[close + 1..].split_whitespace().collect();
        let field = |k: usize| rest[k - 3].parse::<u32>().unwrap();
        out.push((name, field(41), field(40)));
    }
    out
}

#[test]
fn with_a_realtime_priority_the_loop_its_ports_and_simulators_run_fifo_and_nothing_else() {
    const SCHED_FIFO: u32 = 1;
    let config = sim_config_with(
        &[(
            "max_joint_speed_rad_s = 2.0\n",
            "max_joint_speed_rad_s = 2.0\nrealtime_priority = 20\n",
        )],
        TWO_PORTS,
    );
    assert_eq!(config.control().realtime_priority, Some(20));
    // Whether this process may: the daemon must run FIFO if so, and refuse to start if not.
    let allowed = std::thread::spawn(|| snakectl::beside::realtime(20))
        .join()
        .unwrap();
    let localhost = SocketAddr::from(([127, 0, 0, 1], 0));
    let daemon = Embedded::start(config, localhost, RunOptions::default()).unwrap();
    match allowed {
        Ok(()) => {
            let mut c = Client::connect(daemon.addr());
            assert_eq!(c.status()["faults"], json!([]));
            // Other tests of this binary run daemons of their own meanwhile, at the normal
            // policy: this one's are the threads under SCHED_FIFO.
            let all = threads();
            let mut fifo: Vec<(&str, u32)> = all
                .iter()
                .filter(|t| t.1 == SCHED_FIFO)
                .map(|t| (t.0.split(' ').next().unwrap_or_default(), t.2))
                .collect();
            fifo.sort_unstable();
            // The loop, each port's thread ("port /dev/pts/N") and each port's simulator; not
            // the socket side ("snakectl-daemon"), nor the test's own threads.
            assert_eq!(
                fifo,
                [
                    ("port", 20),
                    ("port", 20),
                    ("snakectl-loop", 20),
                    ("snakectl-sim", 20),
                    ("snakectl-sim", 20)
                ],
                "{all:?}"
            );
            daemon.stop().unwrap();
        }
        Err(refused) => {
            assert_eq!(
                refused.source.kind(),
                std::io::ErrorKind::PermissionDenied,
                "{refused}"
            );
            let e = daemon.stop().unwrap_err().to_string();
            for part in [
                "control.realtime_priority",
                "SCHED_FIFO",
                "priority 20",
                "ulimit -r",
            ] {
                assert!(e.contains(part), "{part:?} missing from: {e}");
            }
        }
    }
}
