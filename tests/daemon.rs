//! The daemon end to end: the simulator on a real pseudo-terminal, the daemon on a port-0
//! socket, driven as any client would. Timing is asserted in ticks (the daemon's own clock),
//! never in wall-clock speed.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::time::Duration;

use daemon_support::{dist, floats, rounding_bound, sim_config, xy, Daemon};
use serde_json::{json, Value};
use snakectl_sim::table::addr;

/// The shipped simulator config's limits.
const MAX_JOINT_SPEED: f64 = 2.0;
const MAX_TIP_SPEED: f64 = 0.10;
const MAX_TIP_ACCEL: f64 = 0.5;
const DEADMAN_S: f64 = 0.5;
const DT: f64 = 0.01;

fn tip(s: &Value) -> [f64; 2] {
    xy(&s["tip"])
}

/// Distance of `p` from the segment `a`-`b`.
fn off_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0);
    dist(p, [a[0] + t * dx, a[1] + t * dy])
}

/// Every consecutive pair of telemetry samples moves no joint goal faster than the limit.
fn assert_joint_speed_bound(samples: &[Value]) {
    for w in samples.windows(2) {
        let ticks = w[1]["tick"].as_u64().unwrap() - w[0]["tick"].as_u64().unwrap();
        let (a, b) = (floats(&w[0]["theta_cmd"]), floats(&w[1]["theta_cmd"]));
        for (j, (x, y)) in a.iter().zip(&b).enumerate() {
            let bound = MAX_JOINT_SPEED * DT * ticks as f64 + 1e-9;
            assert!(
                (y - x).abs() <= bound,
                "joint {} moved {:.3e} rad in {ticks} ticks (bound {bound:.3e}) at tick {}",
                j + 1,
                (y - x).abs(),
                w[1]["tick"]
            );
        }
    }
}

#[test]
fn a_goto_arrives_on_target_and_the_servos_follow() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    // The first reply waits for bring-up.
    let start = tip(&c.status());
    let target = [start[0] + 0.05, start[1] - 0.03];
    let id = c.send(json!({"cmd": "goto", "target": target}));
    let reply = c.reply(&json!(id));
    assert_eq!(reply["ok"], json!(true), "{reply}");
    assert!(reply["tick"].as_u64().is_some(), "{reply}");
    let arrived = c.event("arrived", Some(id));
    let s = c.status();
    assert!(dist(tip(&s), target) < 1e-9, "commanded tip {:?}", tip(&s));
    assert_eq!(s["state"], "holding");
    assert_eq!(s["command"]["kind"], "goto");
    assert_eq!(s["command"]["id"], json!(id));
    assert_eq!(s["command"]["outcome"], "arrived");
    assert!(s["command"]["m3_rad2"].as_f64().unwrap() > 0.0);
    assert!(s["command"]["peak_joint_speed_rad_s"].as_f64().unwrap() <= MAX_JOINT_SPEED + 1e-9);
    // The trapezoid the tip limits allow, plus a little.
    let d_m = dist(start, target);
    let trapezoid = d_m / MAX_TIP_SPEED + MAX_TIP_SPEED / MAX_TIP_ACCEL;
    let took = (arrived["tick"].as_u64().unwrap() - reply["tick"].as_u64().unwrap()) as f64 * DT;
    assert!(
        took <= trapezoid + 0.1,
        "took {took:.2} s, trapezoid {trapezoid:.2} s"
    );
    // The servos follow to within the rounding of their goals to ticks.
    let theta = floats(&s["theta_cmd"]);
    let bound = rounding_bound(&d.config, &theta);
    let s = c.wait_status("measured tip on target", |s| {
        dist(xy(&s["tip_meas"]), target) <= bound
    });
    assert!(
        s["tracking_error_m"].as_f64().unwrap() <= bound + 1e-12,
        "{s}"
    );
}

#[test]
fn a_path_takes_its_corners_and_arrives() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let start = tip(&c.status());
    let corners = [
        [start[0] + 0.03, start[1]],
        [start[0] + 0.03, start[1] - 0.03],
        [start[0], start[1] - 0.03],
    ];
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    let id = c.send(json!({"cmd": "path", "points": corners, "speed": 0.08}));
    let samples = c.telemetry_until(|t| {
        t["command"]["id"] == json!(id) && t["command"]["outcome"] == "arrived"
    });
    c.event("arrived", Some(id));
    for corner in corners {
        let nearest = samples
            .iter()
            .map(|t| dist(tip(t), corner))
            .fold(f64::INFINITY, f64::min);
        // Slowing to a stop there: within a few ticks of the corner the tip moves ~1e-4 m.
        assert!(
            nearest < 5e-4,
            "corner {corner:?} missed by {nearest:.2e} m"
        );
    }
    let last = samples.last().unwrap();
    assert!(dist(tip(last), corners[2]) < 1e-9);
    assert_joint_speed_bound(&samples);
}

#[test]
fn a_velocity_stops_within_the_deadman() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    c.status();
    let v = 0.05;
    let id = c.send(json!({"cmd": "velocity", "v": [v, 0.0]}));
    let reply = c.reply(&json!(id));
    let stopped = c.event("stopped", Some(id));
    assert_eq!(stopped["reason"], "deadman", "{stopped}");
    let ticks = stopped["tick"].as_u64().unwrap() - reply["tick"].as_u64().unwrap();
    let bound = (DEADMAN_S + v / MAX_TIP_ACCEL) / DT + 2.0;
    assert!(
        (ticks as f64) <= bound,
        "stopped after {ticks} ticks, bound {bound}"
    );
    // Not before the deadman either: it moved for the deadman's length.
    assert!((ticks as f64) >= DEADMAN_S / DT - 1.0, "{ticks} ticks");
    let s = c.status();
    assert_eq!(s["state"], "holding");
    let later = c.status();
    assert_eq!(tip(&s), tip(&later), "the tip moves after the deadman");
}

#[test]
fn a_jog_stops_within_the_deadman_and_at_the_joint_limit() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    c.status();
    // Once, briefly: it lapses.
    let id = c.send(json!({"cmd": "jog", "joint": 3, "rad_s": 0.5}));
    let reply = c.reply(&json!(id));
    let stopped = c.event("stopped", Some(id));
    assert_eq!(stopped["reason"], "deadman");
    let ticks = stopped["tick"].as_u64().unwrap() - reply["tick"].as_u64().unwrap();
    assert!(
        (ticks as f64) <= (DEADMAN_S + 0.5) / DT,
        "{ticks} ticks after the last jog"
    );

    // Ten times the joint speed limit, renewed, toward joint 12's upper limit (2.0 rad).
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    let mut samples = Vec::new();
    for _ in 0..30 {
        c.ok(json!({"cmd": "jog", "joint": 12, "rad_s": 10.0 * MAX_JOINT_SPEED}));
        let mut n = 0;
        samples.extend(c.telemetry_until(|_| {
            n += 1;
            n >= 10
        }));
    }
    assert_joint_speed_bound(&samples);
    let last = floats(&samples.last().unwrap()["theta_cmd"]);
    for t in &samples {
        assert!(floats(&t["theta_cmd"])[11] <= 2.0 + 1e-12, "{t}");
    }
    assert!(
        last[11] > 2.0 - 0.01,
        "joint 12 stopped at {} before its limit",
        last[11]
    );
}

#[test]
fn the_strategy_switches_mid_motion_without_a_jump() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let s = c.status();
    assert_eq!(s["strategy"], "overall");
    let start = tip(&s);
    let target = [start[0] + 0.12, start[1] + 0.02];
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    let id = c.send(json!({"cmd": "goto", "target": target}));
    let mut n = 0;
    let mut samples = c.telemetry_until(|_| {
        n += 1;
        n >= 40
    });
    c.ok(json!({"cmd": "strategy", "name": "sequential"}));
    samples.extend(c.telemetry_until(|t| t["command"]["outcome"] == "arrived"));
    c.event("arrived", Some(id));
    assert!(samples.iter().any(|t| t["strategy"] == "sequential"));
    assert_eq!(samples.last().unwrap()["strategy"], "sequential");
    assert_joint_speed_bound(&samples);
    let clamped = |t: &Value| t["counters"]["clamped"].as_u64().unwrap();
    if clamped(samples.last().unwrap()) == clamped(&samples[0]) {
        for t in &samples {
            let off = off_segment(tip(t), start, target);
            assert!(
                off < 1e-6,
                "the tip left its line by {off:.2e} m at tick {}",
                t["tick"]
            );
        }
    }
}

#[test]
fn estop_latches_until_reset_which_holds_without_moving() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let start = tip(&c.status());
    let goto = c.send(json!({"cmd": "goto", "target": [start[0] + 0.1, start[1]]}));
    c.reply(&json!(goto));
    c.wait_status("moving", |s| s["state"] == "moving");
    let estop = c.ok(json!({"cmd": "estop"}));
    let s = c.status();
    assert_eq!(s["state"], "estop", "status right after the estop reply");
    assert!(s["tick"].as_u64() >= estop["tick"].as_u64());
    for id in d.config.arm().unwrap().ids() {
        assert!(!d.torque(id), "servo {id} still has torque after estop");
    }
    assert_eq!(
        estop.get("unconfirmed"),
        None,
        "every servo confirmed off: {estop}"
    );
    assert_eq!(
        c.error_code(json!({"cmd": "goto", "target": start})),
        "estopped"
    );
    assert_eq!(
        c.error_code(json!({"cmd": "velocity", "v": [0.01, 0.0]})),
        "estopped"
    );
    assert_eq!(c.error_code(json!({"cmd": "home"})), "estopped");
    // Stopping is never refused.
    c.ok(json!({"cmd": "stop"}));
    c.event("estop", None);
    let frozen = tip(&c.status());
    assert_eq!(tip(&c.status()), frozen, "goals move under estop");

    c.ok(json!({"cmd": "reset"}));
    c.event("reset", None);
    let s = c.status();
    assert_eq!(s["state"], "holding");
    for id in d.config.arm().unwrap().ids() {
        assert!(d.torque(id), "servo {id} without torque after reset");
    }
    // Goal := measured: the commanded pose is the measured one, to a tick.
    let (cmd, meas) = (floats(&s["theta_cmd"]), floats(&s["theta_meas"]));
    for (a, b) in cmd.iter().zip(&meas) {
        assert!(
            (a - b).abs() <= std::f64::consts::TAU / 4096.0,
            "{a} vs {b}"
        );
    }
    // Reset never starts motion by itself.
    std::thread::sleep(Duration::from_millis(100));
    let later = c.status();
    assert_eq!(tip(&later), tip(&s));
    assert_eq!(later["state"], "holding");
    // And the arm can move again.
    let again = c.send(json!({"cmd": "goto", "target": [tip(&s)[0], tip(&s)[1] - 0.02]}));
    c.event("arrived", Some(again));
}

#[test]
fn every_error_code_is_answered_with_the_request_id() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    c.status();
    let raw = |c: &mut daemon_support::Client, line: &str| -> Value {
        c.write_raw(line.as_bytes());
        c.write_raw(b"\n");
        c.next_matching(daemon_support::DEADLINE, |l| l.get("type").is_none())
            .expect("a reply")
    };
    let r = raw(&mut c, "this is not json");
    assert_eq!(r["error"]["code"], "bad_json");
    assert_eq!(r["id"], Value::Null);
    let r = raw(&mut c, r#"{"cmd":"goto","id":"a","target":[1e999,0]}"#);
    assert_eq!(r["error"]["code"], "bad_json", "{r}");
    let r = raw(&mut c, r#"{"cmd":"fly","id":{"n":[1,2]}}"#);
    assert_eq!(r["error"]["code"], "unknown_cmd");
    assert_eq!(r["id"], json!({"n": [1, 2]}));

    let bad_arg = |c: &mut daemon_support::Client, req: Value, field: &str| {
        let r = c.request(req.clone());
        assert_eq!(r["error"]["code"], "bad_arg", "{req} -> {r}");
        let msg = r["error"]["message"].as_str().unwrap();
        assert!(
            msg.contains(field),
            "{req} -> {msg:?} does not name `{field}`"
        );
    };
    bad_arg(
        &mut c,
        json!({"cmd": "goto", "target": [2e6, 0.0]}),
        "target",
    );
    bad_arg(&mut c, json!({"cmd": "goto", "target": [0.1]}), "target");
    bad_arg(
        &mut c,
        json!({"cmd": "goto", "target": [0.1, 0.2], "sped": 1}),
        "sped",
    );
    bad_arg(
        &mut c,
        json!({"cmd": "goto_joints", "theta": [0.0, 0.1]}),
        "theta",
    );
    bad_arg(
        &mut c,
        json!({"cmd": "jog", "joint": 13, "rad_s": 0.1}),
        "joint",
    );
    bad_arg(
        &mut c,
        json!({"cmd": "jog", "joint": 0, "rad_s": 0.1}),
        "joint",
    );
    bad_arg(&mut c, json!({"cmd": "velocity", "v": "fast"}), "v");
    bad_arg(
        &mut c,
        json!({"cmd": "strategy", "name": "fastest"}),
        "name",
    );

    // An over-long line is discarded; the connection lives.
    let long = format!(
        r#"{{"cmd":"status","pad":"{}"}}"#,
        "x".repeat(snakectl::protocol::MAX_LINE)
    );
    let r = raw(&mut c, &long);
    assert_eq!(r["error"]["code"], "line_too_long");
    c.status();

    assert_eq!(
        c.error_code(json!({"cmd": "goto_joints", "theta": vec![3.0; 12]})),
        "unreachable"
    );
    c.ok(json!({"cmd": "estop"}));
    assert_eq!(
        c.error_code(json!({"cmd": "jog", "joint": 1, "rad_s": 0.1})),
        "estopped"
    );
}

#[test]
fn an_unreachable_goto_ends_short_with_one_saturated_event() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let start = tip(&c.status());
    let far = [3.0, 3.0];
    let id = c.send(json!({"cmd": "goto", "target": far}));
    c.reply(&json!(id));
    let ev = c.event("saturated", Some(id));
    let s = c.status();
    assert_eq!(s["state"], "holding");
    assert_eq!(s["command"]["outcome"], "saturated");
    let reach = 12.0 * 0.08;
    assert!(dist(tip(&s), [0.0, 0.0]) <= reach + 1e-9);
    assert!(
        dist(tip(&s), far) < dist(start, far),
        "no progress toward the target"
    );
    let more = c.drain_events(Duration::from_millis(300));
    assert!(
        !more
            .iter()
            .any(|e| e["event"] == "saturated" && e["cmd_id"] == json!(id)),
        "a second saturated event after {ev}: {more:?}"
    );
}

#[test]
fn a_new_motion_preempts_the_old_one_and_goto_joints_arrives() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let start = tip(&c.status());
    let first = c.send(json!({"cmd": "goto", "target": [start[0] + 0.1, start[1]]}));
    c.reply(&json!(first));
    let pose = vec![0.05; 12];
    let second = c.send(json!({"cmd": "goto_joints", "theta": pose}));
    c.reply(&json!(second));
    let pre = c.event("preempted", Some(first));
    assert_eq!(pre["reason"], "goto_joints", "{pre}");
    c.event("arrived", Some(second));
    let s = c.status();
    for t in floats(&s["theta_cmd"]) {
        assert!((t - 0.05).abs() < 1e-9, "{t}");
    }
    let home = c.send(json!({"cmd": "home"}));
    c.event("arrived", Some(home));
    let s = c.status();
    for t in floats(&s["theta_cmd"]) {
        assert!((t - 0.1).abs() < 1e-9, "{t}");
    }
}

#[test]
fn describe_tells_a_ui_how_to_draw_the_arm() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let r = c.ok(json!({"cmd": "describe"}));
    assert_eq!(floats(&r["links_m"]), vec![0.08; 12]);
    assert_eq!(floats(&r["min_rad"]), vec![-2.0; 12]);
    assert_eq!(floats(&r["max_rad"]), vec![2.0; 12]);
    assert_eq!(floats(&r["home_rad"]), vec![0.1; 12]);
    let base = floats(&r["base"]);
    assert_eq!(base[..2], [0.0, 0.0]);
    assert!((base[2] - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
    assert_eq!(r["ids"], json!((1..=12).collect::<Vec<_>>()));
    assert_eq!(r["models"][0], "XL430-W250");
    assert_eq!(r["rate_hz"], json!(100.0));
    assert_eq!(r["strategies"], json!(["overall", "sequential"]));
    assert_eq!(r["protocol_version"], json!(1));
}

#[test]
fn status_carries_every_telemetry_field() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let s = c.status();
    // Every field of the snapshot (the list itself is pinned in the protocol's unit tests).
    let fields = snakectl::protocol::Telemetry::default().to_fields();
    assert!(fields.len() > 20);
    for key in fields.keys() {
        assert!(s.get(key).is_some(), "status has no `{key}`: {s}");
    }
    c.ok(json!({"cmd": "subscribe", "rate_hz": 50.0}));
    let t = c.telemetry_until(|_| true).pop().unwrap();
    let mut a: Vec<_> = s.as_object().unwrap().keys().cloned().collect();
    let mut b: Vec<_> = t.as_object().unwrap().keys().cloned().collect();
    a.retain(|k| k != "id" && k != "ok");
    b.retain(|k| k != "type");
    a.sort();
    b.sort();
    assert_eq!(a, b, "status and telemetry differ in their fields");
    let tick = s["tick"].as_u64().unwrap() as f64;
    assert!((s["t_s"].as_f64().unwrap() - tick * DT).abs() < 1e-9);
}

#[test]
fn shutdown_brings_the_arm_to_rest_then_torque_off() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let start = tip(&c.status());
    let id = c.send(json!({"cmd": "goto", "target": [start[0] + 0.1, start[1]]}));
    c.reply(&json!(id));
    c.wait_status("moving", |s| s["state"] == "moving");
    let ids = d.config.arm().unwrap().ids();
    let sim = d.sim.simulator();
    let summary = d.stop().unwrap();
    assert!(summary.ticks > 0);
    let sim = sim.lock().unwrap();
    for id in ids {
        let servo = sim.servo(id).unwrap();
        assert!(!servo.torque_enabled(), "servo {id} left with torque on");
    }
}

#[test]
fn estop_keeps_torque_where_the_arm_would_fall() {
    let d = Daemon::start(sim_config(&[(
        "on_exit = \"torque_off\"",
        "on_exit = \"hold\"",
    )]));
    let mut c = d.client();
    let start = tip(&c.status());
    let id = c.send(json!({"cmd": "goto", "target": [start[0] + 0.1, start[1]]}));
    c.reply(&json!(id));
    c.wait_status("moving", |s| s["state"] == "moving");
    c.ok(json!({"cmd": "estop"}));
    let s = c.status();
    assert_eq!(s["state"], "estop");
    for id in d.config.arm().unwrap().ids() {
        assert!(
            d.torque(id),
            "servo {id} lost torque under estop with on_exit = hold"
        );
    }
    // Frozen: the goals do not move while latched.
    let frozen = floats(&s["theta_cmd"]);
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(floats(&c.status()["theta_cmd"]), frozen);
}

#[test]
fn reset_stats_zeroes_what_is_kept_since_start() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let start = tip(&c.status());
    let id = c.send(json!({"cmd": "goto", "target": [start[0], start[1] - 0.02]}));
    c.event("arrived", Some(id));
    let s = c.status();
    assert!(s["m3_total_rad2"].as_f64().unwrap() > 0.0);
    assert!(s["peak_joint_speed_rad_s"].as_f64().unwrap() > 0.0);
    let overruns = s["overruns"].as_u64().unwrap();
    c.ok(json!({"cmd": "reset_stats"}));
    let s = c.status();
    assert_eq!(s["m3_total_rad2"], json!(0.0));
    assert_eq!(s["peak_joint_speed_rad_s"], json!(0.0));
    // Overruns count since start.
    assert!(s["overruns"].as_u64().unwrap() >= overruns);
    // The command's own account stays.
    assert!(s["command"]["m3_rad2"].as_f64().unwrap() > 0.0);
}

#[test]
fn a_stop_decelerates_and_holds_and_the_next_motion_resumes() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let start = tip(&c.status());
    let target = [start[0] + 0.1, start[1]];
    let goto = c.send(json!({"cmd": "goto", "target": target}));
    c.reply(&json!(goto));
    c.wait_status("moving", |s| s["state"] == "moving");
    let stop = c.send(json!({"cmd": "stop"}));
    let reply = c.reply(&json!(stop));
    let pre = c.event("preempted", Some(goto));
    assert_eq!(pre["reason"], "stop");
    let stopped = c.event("stopped", Some(stop));
    assert_eq!(stopped["reason"], "stop");
    // From at most the tip speed limit, at the tip acceleration limit, plus a tick.
    let ticks = stopped["tick"].as_u64().unwrap() - reply["tick"].as_u64().unwrap();
    assert!(
        ticks as f64 <= MAX_TIP_SPEED / MAX_TIP_ACCEL / DT + 2.0,
        "{ticks} ticks to rest"
    );
    let s = c.status();
    assert_eq!(s["state"], "holding");
    assert!(dist(tip(&s), target) > 0.01, "the stop did not stop short");
    // A stop while holding comes to rest at once.
    let again = c.send(json!({"cmd": "stop"}));
    c.event("stopped", Some(again));
    let resume = c.send(json!({"cmd": "goto", "target": target}));
    c.event("arrived", Some(resume));
}

#[test]
fn a_path_that_would_fold_the_arm_onto_itself_stops_short_flagged() {
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    c.status();
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    // Down beside the base, then straight across it: through the arm's own first links.
    let across = [0.1, 0.04];
    let points = json!([[-0.2, 0.2], [-0.1, 0.04], across]);
    let id = c.send(json!({"cmd": "path", "points": points, "speed": 0.1}));
    let samples = c.telemetry_until(|t| {
        t["command"]["id"] == json!(id) && t["command"]["outcome"] == "saturated"
    });
    c.event("saturated", Some(id));
    assert!(
        samples.iter().any(|t| t["self_collision"] == json!(true)),
        "never flagged self_collision"
    );
    for t in &samples {
        if t["self_collision"] == json!(true) {
            assert_eq!(t["saturated"], json!(true), "{t}");
        }
    }
    assert_joint_speed_bound(&samples);
    let s = c.status();
    assert!(
        dist(tip(&s), across) > 0.05,
        "the tip got across: {:?}",
        tip(&s)
    );
    // The goals never crossed: check every sample's pose.
    let chain = d.config.chain();
    for t in &samples {
        let points = chain.points(&floats(&t["theta_cmd"]));
        assert_eq!(
            snakectl::chain::Chain::self_intersects(&points),
            None,
            "links touch at tick {}",
            t["tick"]
        );
    }
}

/// Regression: at 1 kHz a read's wait is under a millisecond, which the serial port's
/// millisecond timeout truncated to nothing: every read gave up at once and the arm went to
/// `fault` with every servo "silent".
#[test]
fn a_loop_at_1_khz_hears_its_servos() {
    let d = Daemon::start(sim_config(&[("rate_hz = 100.0", "rate_hz = 1000.0")]));
    let mut c = d.client();
    let first = c.status();
    let s = c.wait_status("1000 ticks", |s| {
        s["tick"].as_u64().unwrap() >= first["tick"].as_u64().unwrap() + 1000
    });
    assert_eq!(s["faults"], json!([]), "{s}");
    assert_ne!(s["state"], "fault");
    let reads = s["tick"].as_u64().unwrap() * 12;
    let missed = s["counters"]["dropped"].as_u64().unwrap();
    // A busy machine may delay a reply past its millisecond now and then; not every one.
    assert!(
        (missed as f64) < 0.05 * reads as f64,
        "{missed} of {reads} replies missed"
    );
}

/// A home pose exactly on joint limits (joint 1 on its upper one, joint 2 on its lower one)
/// starts: the simulated servos power on at ticks inside the limits rounded inward, and the
/// daemon measures and holds each joint inside its limits, within a tick of the limit.
#[test]
fn a_home_pose_exactly_on_joint_limits_starts_inside_them() {
    let config =
        daemon_support::sim_config_with(&[("home_rad = [0.1, 0.1,", "home_rad = [2.0, -2.0,")], "");
    assert_eq!(config.home()[..2], [2.0, -2.0]);
    let arm = config.arm().unwrap().clone();
    let sim = snakectl::connect::sim_config(&config).unwrap();
    for (spec, j) in sim.servos.iter().zip(arm.joints()).take(2) {
        let t = spec.initial_position_ticks.unwrap();
        assert!(
            (j.ticks.min..=j.ticks.max).contains(&t),
            "servo {} powers on at tick {t}, limits {:?}",
            j.id,
            j.ticks
        );
    }
    let d = Daemon::start(config);
    for j in &arm.joints()[..2] {
        let present = d
            .sim
            .with_servo(j.id, |s| s.value(addr::PRESENT_POSITION))
            .flatten()
            .unwrap();
        let present = i32::try_from(present).unwrap();
        assert!(
            (j.ticks.min..=j.ticks.max).contains(&present),
            "servo {} at tick {present}, limits {:?}",
            j.id,
            j.ticks
        );
    }
    let mut c = d.client();
    let s = c.status();
    assert_eq!(s["state"], "holding", "{s}");
    let tick = std::f64::consts::TAU / 4096.0;
    for key in ["theta_cmd", "theta_meas"] {
        let theta = floats(&s[key]);
        assert!(theta[0] <= 2.0 && theta[0] > 2.0 - tick, "{key}: {s}");
        assert!(theta[1] >= -2.0 && theta[1] < -2.0 + tick, "{key}: {s}");
    }
    drop(c);
    d.stop().unwrap();
}
