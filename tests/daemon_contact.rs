//! Contact detection end to end: the simulator blocks joint 1's servo (`[[sim.fault]] kind =
//! "blocked"`, as if the arm had met something no one modelled), a `goto` makes that joint push,
//! and with `[world] contact_load` the daemon stops the arm, latches it and names the joint and
//! the load; `reset` clears it. Without `contact_load` the same push raises nothing.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use daemon_support::{floats, sim_config_with, xy, Client, Daemon};
use serde_json::{json, Value};

/// One servo tick, rad.
const TICK_RAD: f64 = std::f64::consts::TAU / 4096.0;

/// Servo 1 (joint 1, at the base) blocked from the start; `world` appended as a table.
fn blocked_base(world: &str) -> Daemon {
    Daemon::start(sim_config_with(
        &[],
        &format!("[[sim.fault]]\nkind = \"blocked\"\nid = 1\n\n{world}"),
    ))
}

/// The tip turned `angle` about the base (the origin): reaching it mostly turns joint 1.
fn turned(tip: [f64; 2], angle: f64) -> [f64; 2] {
    let (s, c) = angle.sin_cos();
    [c * tip[0] - s * tip[1], s * tip[0] + c * tip[1]]
}

/// Telemetry at the loop's rate and a `goto` that swings the arm about joint 1; the goto's id.
fn push(c: &mut Client) -> u64 {
    let start = xy(&c.status()["tip"]);
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    let id = c.send(json!({"cmd": "goto", "target": turned(start, -0.4)}));
    assert_eq!(c.reply(&json!(id))["ok"], json!(true));
    id
}

/// Telemetry lines and events until `stop` holds for an event; returns both.
fn until_event(c: &mut Client, mut stop: impl FnMut(&Value) -> bool) -> (Vec<Value>, Vec<Value>) {
    let (mut samples, mut events) = (Vec::new(), Vec::new());
    let deadline = std::time::Instant::now() + daemon_support::DEADLINE;
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        assert!(!left.is_zero(), "no such event; events: {events:?}");
        let Some(line) = c.read_line(left) else {
            continue;
        };
        if line["type"] == "telemetry" {
            samples.push(line);
        } else if line["type"] == "event" {
            let done = stop(&line);
            events.push(line);
            if done {
                return (samples, events);
            }
        }
    }
}

fn is_contact(e: &Value, reason: &str) -> bool {
    e["event"] == "fault" && e["reason"] == reason && e["fault"]["kind"] == "contact"
}

#[test]
fn a_joint_pushing_past_its_contact_load_stops_the_arm_until_reset() {
    let d = blocked_base("[world]\ncontact_load = 40\ncontact_ms = 200\n");
    let mut c = d.client();
    let goto = push(&mut c);
    let (samples, events) = until_event(&mut c, |e| is_contact(e, "raised"));
    let raised = events.last().unwrap();
    println!("contact: {raised}");
    let f = &raised["fault"];
    assert_eq!(
        (f["joint"].clone(), f["id"].clone()),
        (json!(1), json!(1)),
        "{raised}"
    );
    assert!(f["port"].is_string(), "{raised}");
    let detail = f["detail"].as_str().unwrap();
    assert!(
        detail.contains("contact_load = 40 %") && detail.contains("contact_ms = 200"),
        "{detail}"
    );
    // The load it names is the one the health reads saw, above the threshold.
    let named: f64 = detail
        .strip_prefix("load ")
        .and_then(|r| r.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no load in {detail}"));
    assert!(named.abs() > 40.0, "{detail}");
    let tick = raised["tick"].as_u64().unwrap();
    let mut seen = samples.clone();
    seen.extend(c.telemetry_until(|t| t["tick"].as_u64().unwrap() >= tick));
    match seen.iter().find(|t| t["tick"] == json!(tick)) {
        Some(at) => {
            assert_eq!(at["health_tick"], json!(tick), "{at}");
            assert_eq!(
                floats(&at["load"])[0],
                named,
                "telemetry's load of joint 1: {at}"
            );
        }
        None => {
            // Telemetry is latest-wins: on a busy machine the contact's own sample may have
            // been replaced by the next before this client read it. The last sample before it
            // then shows the same push, beyond the threshold, read in its own tick.
            let before = seen
                .iter()
                .rev()
                .find(|t| t["tick"].as_u64().unwrap() < tick)
                .unwrap_or_else(|| panic!("no telemetry before tick {tick}"));
            assert_eq!(before["health_tick"], before["tick"], "{before}");
            let load = floats(&before["load"])[0];
            assert!(
                load.abs() > 40.0 && load.signum() == named.signum(),
                "telemetry's load of joint 1 before the contact: {before}"
            );
        }
    }
    // 200 ms above 40 % at 100 Hz with the health registers in every read: 21 reads, 20 ticks.
    let held = tick - f["since_tick"].as_u64().unwrap();
    assert_eq!(held, 20, "{raised}");
    // Before the contact, joint 1's goal ran away from its shaft, which stayed put.
    let first = samples.first().unwrap();
    let t0 = floats(&first["theta_meas"])[0];
    for t in &samples {
        assert!((floats(&t["theta_meas"])[0] - t0).abs() <= TICK_RAD, "{t}");
    }
    // The goto ended as for a fault, and the arm is latched (events in the contact's tick).
    assert!(
        events.iter().any(|e| e["event"] == "stopped"
            && e["cmd_id"] == json!(goto)
            && e["reason"] == "fault"
            && e["tick"] == json!(tick)),
        "no stopped event for the goto: {events:?}"
    );
    assert!(
        events
            .iter()
            .any(|e| e["event"] == "estop" && e["tick"] == json!(tick)),
        "no estop event: {events:?}"
    );
    let s = c.status();
    assert_eq!(s["state"], "estop", "{s}");
    assert_eq!(s["command"]["outcome"], "fault", "{s}");
    assert_eq!(s["faults"].as_array().unwrap().len(), 1, "{s}");
    assert_eq!(s["faults"][0]["kind"], "contact", "{s}");
    assert_eq!(s["torque"], json!(true), "held with torque on: {s}");
    assert!(d.torque(1));
    // It stopped pushing: goals := the measured pose, so joint 1's load falls, and nothing
    // moves while the latch holds.
    let calm = c
        .telemetry_until(|t| t["health_tick"].as_u64().unwrap() > s["tick"].as_u64().unwrap() + 10);
    let cmd0 = floats(&calm[0]["theta_cmd"]);
    for t in &calm {
        assert_eq!(
            floats(&t["theta_cmd"]),
            cmd0,
            "the goals moved under the latch: {t}"
        );
    }
    assert!(
        (cmd0[0] - t0).abs() <= TICK_RAD,
        "joint 1's goal is where its shaft is"
    );
    let after = floats(&calm.last().unwrap()["load"])[0];
    assert!(after.abs() < 5.0, "joint 1 still pushes: {after} %");
    assert_eq!(
        c.error_code(json!({"cmd": "goto", "target": [0.1, 0.5]})),
        "estopped"
    );
    assert_eq!(
        c.error_code(json!({"cmd": "torque", "on": true})),
        "estopped"
    );
    // `reset` releases the latch and clears the contact.
    c.ok(json!({"cmd": "reset"}));
    let s = c.status();
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["faults"], json!([]), "{s}");
    let cleared = c
        .next_matching(daemon_support::DEADLINE, |e| is_contact(e, "cleared"))
        .expect("a cleared event");
    assert_eq!(cleared["fault"]["joint"], json!(1), "{cleared}");
    let (result, torques) = d.stop_and_torques();
    result.unwrap();
    assert!(torques.iter().all(|(_, on)| !on), "{torques:?}");
}

#[test]
fn without_contact_load_the_same_push_raises_nothing() {
    let d = blocked_base("");
    let mut c = d.client();
    let goto = push(&mut c);
    let (samples, events) = until_event(&mut c, |e| {
        e["event"] == "arrived" && e["cmd_id"] == json!(goto)
    });
    // The push was there: joint 1's load stayed above 40 % on health reads 20 ticks apart and
    // more, which with contact_load = 40 and contact_ms = 200 is a contact.
    let mut reads: Vec<(u64, f64)> = samples
        .iter()
        .map(|t| (t["health_tick"].as_u64().unwrap(), floats(&t["load"])[0]))
        .collect();
    reads.dedup_by_key(|r| r.0);
    let (mut since, mut longest) = (None, 0);
    for &(tick, load) in &reads {
        if load.abs() > 40.0 {
            let from = *since.get_or_insert(tick);
            longest = longest.max(tick - from);
        } else {
            since = None;
        }
    }
    let peak = reads.iter().map(|r| r.1.abs()).fold(0.0, f64::max);
    println!(
        "without contact_load: joint 1's load peaked at {peak} % and stayed above 40 % for \
         {longest} ticks"
    );
    assert!(longest >= 20, "joint 1 never pushed for long: {reads:?}");
    assert!(
        events
            .iter()
            .all(|e| e["event"] != "fault" && e["event"] != "estop"),
        "{events:?}"
    );
    let s = c.status();
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["faults"], json!([]), "{s}");
    assert!(floats(&s["load"])[0].abs() > 40.0, "still pushing: {s}");
    d.stop().unwrap();
}
