//! The daemon's fault matrix end to end: the simulator's injected faults (`[[sim.fault]]` in
//! the config), the daemon on a socket, driven and watched as a client. Every case checks
//! that no goal left the joint limits or was non-finite, that goals moved no faster than the
//! joint-speed limit except to the measured pose on a recovery, and that shut-down leaves
//! torque off. Detection times are in ticks (the daemon's clock). Run with `--nocapture` for
//! the figures the fault matrix of `docs/FAULTS.md` quotes.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod daemon_support;

use std::time::{Duration, Instant};

use daemon_support::{
    dist, floats, sim_config, sim_config_with, xy, Client, Daemon, DEADLINE, TWO_PORTS,
};
use serde_json::{json, Value};

const MAX_JOINT_SPEED: f64 = 2.0;
const DT: f64 = 0.01;
/// One tick of a servo, rad.
const TICK_RAD: f64 = std::f64::consts::TAU / 4096.0;

/// The edit of the shipped config that sets `[bus] read`.
fn read_edit(read: &str) -> (&'static str, &'static str) {
    match read {
        "sync" => ("read = \"auto\"", "read = \"sync\""),
        _ => ("read = \"auto\"", "read = \"fast\""),
    }
}

/// The joint limits the daemon reports.
fn limits(c: &mut Client) -> (Vec<f64>, Vec<f64>) {
    let d = c.ok(json!({"cmd": "describe"}));
    (floats(&d["min_rad"]), floats(&d["max_rad"]))
}

/// A client subscribed to telemetry at the loop's rate, the joint limits and the tip at start.
fn watching(d: &Daemon) -> (Client, (Vec<f64>, Vec<f64>), [f64; 2]) {
    let mut c = d.client();
    // The loop reads as the config asks (the shipped chain's firmware has Fast Sync Read).
    let read = match d.config.arm().map(|a| a.settings().read) {
        Some(snakectl::servo::ReadChoice::Sync) => "sync",
        _ => "fast",
    };
    assert_eq!(c.ok(json!({"cmd": "describe"}))["read"], json!(read));
    let limits = limits(&mut c);
    let start = xy(&c.status()["tip"]);
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    (c, limits, start)
}

/// Every sample: goals finite and inside the limits. Between consecutive samples: no goal
/// faster than the joint-speed limit, unless the later goals are the measured pose (a
/// recovery re-seeds there). Returns the number of such re-seeds seen.
fn check_goals(samples: &[Value], lo: &[f64], hi: &[f64]) -> usize {
    let mut reseeds = 0;
    for t in samples {
        for (j, x) in floats(&t["theta_cmd"]).iter().enumerate() {
            assert!(
                x.is_finite(),
                "joint {} goal {x} at tick {}",
                j + 1,
                t["tick"]
            );
            assert!(
                *x >= lo[j] - 1e-12 && *x <= hi[j] + 1e-12,
                "joint {} goal {x} outside {}..{} at tick {}",
                j + 1,
                lo[j],
                hi[j],
                t["tick"]
            );
        }
    }
    for w in samples.windows(2) {
        let ticks = w[1]["tick"].as_u64().unwrap() - w[0]["tick"].as_u64().unwrap();
        let (a, b) = (floats(&w[0]["theta_cmd"]), floats(&w[1]["theta_cmd"]));
        let meas = floats(&w[1]["theta_meas"]);
        let bound = MAX_JOINT_SPEED * DT * ticks as f64 + 1e-9;
        let fast = a.iter().zip(&b).any(|(x, y)| (y - x).abs() > bound);
        if fast {
            let at_measured = b.iter().zip(&meas).all(|(x, m)| (x - m).abs() <= TICK_RAD);
            assert!(
                at_measured,
                "goals jumped in {ticks} ticks at tick {} (bound {bound:.3e}), not to the \
                 measured pose:\n{a:?}\n{b:?}\n{meas:?}",
                w[1]["tick"]
            );
            reseeds += 1;
        }
    }
    reseeds
}

/// Telemetry lines for `ticks` ticks (from the first one seen).
fn watch(c: &mut Client, ticks: u64) -> Vec<Value> {
    let mut first = None;
    c.telemetry_until(|t| {
        let tick = t["tick"].as_u64().unwrap();
        tick >= *first.get_or_insert(tick) + ticks
    })
}

/// Telemetry lines until the next event that satisfies `pred`, and that event; the other
/// events on the way are in `skipped`.
fn watch_until_event(c: &mut Client, pred: impl FnMut(&Value) -> bool) -> (Vec<Value>, Value) {
    let mut skipped = Vec::new();
    watch_until_event_keeping(c, pred, &mut skipped)
}

fn watch_until_event_keeping(
    c: &mut Client,
    mut pred: impl FnMut(&Value) -> bool,
    skipped: &mut Vec<Value>,
) -> (Vec<Value>, Value) {
    let mut samples = Vec::new();
    let deadline = Instant::now() + DEADLINE;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "no such event within {DEADLINE:?}");
        let Some(line) = c.read_line(left) else {
            continue;
        };
        if line["type"] == "telemetry" {
            samples.push(line);
        } else if line["type"] == "event" {
            if pred(&line) {
                return (samples, line);
            }
            skipped.push(line);
        }
    }
}

fn fault_event<'a>(reason: &'a str, kind: &'a str) -> impl FnMut(&Value) -> bool + 'a {
    move |e: &Value| e["event"] == "fault" && e["reason"] == reason && e["fault"]["kind"] == kind
}

/// A goto to `target` that arrives.
fn goto_arrives(c: &mut Client, target: [f64; 2]) {
    let id = c.send(json!({"cmd": "goto", "target": target}));
    let reply = c.reply(&json!(id));
    assert_eq!(reply["ok"], json!(true), "{reply}");
    c.event("arrived", Some(id));
    let s = c.status();
    assert!(dist(xy(&s["tip"]), target) < 1e-9, "{s}");
}

/// Stops the daemon; every servo's torque must be off afterwards.
fn stop_torque_off(d: Daemon) {
    let (result, torques) = d.stop_and_torques();
    result.unwrap();
    for (id, on) in torques {
        assert!(!on, "servo {id} left with torque on");
    }
}

#[test]
fn one_percent_drops_and_corruption_stay_within_the_error_budget() {
    drops_and_corruption("fast", "");
}

/// The same with Sync Read (`[bus] read = "sync"`).
#[test]
fn one_percent_drops_and_corruption_stay_within_the_error_budget_with_sync_read() {
    drops_and_corruption("sync", "");
}

/// The same on two ports, each read in parallel.
#[test]
fn one_percent_drops_and_corruption_on_two_ports_stay_within_the_error_budget() {
    drops_and_corruption("fast", TWO_PORTS);
}

/// What every port's simulator dropped and corrupted so far.
fn sim_losses(d: &Daemon) -> (u64, u64) {
    d.sims()
        .map(|sim| sim.with_sim(|s| s.stats()))
        .fold((0, 0), |(dr, co), st| (dr + st.dropped, co + st.corrupted))
}

/// 1% of the replies dropped and 1% corrupted, read with `read`, on the bus `ports`
/// (`[[bus.ports]]` tables) describes.
fn drops_and_corruption(read: &str, ports: &str) {
    let d = Daemon::start(sim_config_with(
        &[read_edit(read)],
        &format!(
            "[[sim.fault]]\nkind = \"drop\"\nfraction = 0.01\n\n\
             [[sim.fault]]\nkind = \"corrupt\"\nfraction = 0.01\n{ports}"
        ),
    ));
    let (mut c, (lo, hi), start) = watching(&d);
    let sim0 = sim_losses(&d);
    let first = watch(&mut c, 1).pop().unwrap();
    // Back and forth for about five seconds.
    let corners = [
        [start[0] + 0.06, start[1]],
        [start[0] + 0.06, start[1] - 0.06],
        [start[0], start[1]],
        [start[0] + 0.06, start[1]],
        [start[0], start[1]],
    ];
    let id = c.send(json!({"cmd": "path", "points": corners, "speed": 0.08}));
    let mut samples = c.telemetry_until(|t| {
        t["command"]["id"] == json!(id) && t["command"]["outcome"] != "active"
    });
    samples.extend(watch(&mut c, 50));
    let last = samples.last().unwrap().clone();
    let sim1 = sim_losses(&d);
    assert_eq!(last["command"]["outcome"], "arrived", "{last}");
    for t in &samples {
        assert_ne!(
            t["state"], "fault",
            "a false fault at tick {}: {t}",
            t["tick"]
        );
        assert_eq!(t["faults"], json!([]), "{t}");
    }
    let events = c.drain_events(Duration::ZERO);
    assert!(
        events.iter().all(|e| e["event"] != "fault"),
        "a fault event: {events:?}"
    );
    let count = |t: &Value, k: &str| t["counters"][k].as_u64().unwrap();
    let ticks = last["tick"].as_u64().unwrap() - first["tick"].as_u64().unwrap();
    let dropped = count(&last, "dropped") - count(&first, "dropped");
    let corrupted = count(&last, "corrupted") - count(&first, "corrupted");
    let sim_dropped = sim1.0 - sim0.0;
    let sim_corrupted = sim1.1 - sim0.1;
    let overruns = last["overruns"].as_u64().unwrap() - first["overruns"].as_u64().unwrap();
    let replies = ticks * 12;
    println!(
        "drop+corrupt 1%+1%: {ticks} ticks, {replies} replies expected; daemon counted \
         {dropped} dropped + {corrupted} corrupted ({:.2} %), the simulator {sim_dropped} + \
         {sim_corrupted}; overruns {overruns}; loop {:.1} Hz; no fault",
        100.0 * (dropped + corrupted) as f64 / replies as f64,
        last["loop_hz"].as_f64().unwrap()
    );
    // Every reply the simulator lost or damaged is counted (the snapshots are a few reads
    // apart at most); a damaged reply may count as lost when it came too late. With Fast Sync
    // Read a block lost breaks the chain there, and the servos from there on are asked again
    // by Sync Read in the same read: a lost block costs a reading only when that reply is lost
    // too, so fewer are counted lost than the simulator dropped, never more.
    assert!(sim_dropped > 0 && sim_corrupted > 0, "{sim1:?}");
    if read == "sync" {
        assert!(
            dropped + corrupted + 24 >= sim_dropped + sim_corrupted,
            "counted {dropped} + {corrupted}, the simulator {sim_dropped} + {sim_corrupted}"
        );
    } else {
        assert!(
            dropped <= sim_dropped + 24 && corrupted + 24 >= sim_corrupted,
            "counted {dropped} + {corrupted}, the simulator {sim_dropped} + {sim_corrupted}"
        );
    }
    assert!(corrupted > 0 && corrupted <= sim_corrupted + 24);
    // About 2 % of the replies, not more than twice that.
    assert!(
        ((dropped + corrupted) as f64) < 0.04 * replies as f64,
        "{dropped} + {corrupted} of {replies}"
    );
    // The loop keeps its rate: a lost reply costs no overrun.
    assert!(
        overruns * 20 <= ticks,
        "{overruns} overruns in {ticks} ticks"
    );
    check_goals(&samples, &lo, &hi);
    stop_torque_off(d);
}

#[test]
fn a_silent_servo_holds_the_arm_until_it_answers_then_the_arm_moves_again() {
    silent_servo("fast", "");
}

/// The same with Sync Read.
#[test]
fn a_silent_servo_holds_the_arm_until_it_answers_then_the_arm_moves_again_with_sync_read() {
    silent_servo("sync", "");
}

#[test]
fn a_silent_servo_on_one_of_two_ports_holds_the_arm_named_with_its_port() {
    silent_servo("fast", TWO_PORTS);
}

/// On a wire with its timing, where a recovery's round trips take more than a tick leaves:
/// recovered as anywhere else, not refused for time and then, with the torque it had switched
/// off, taken for a servo that lost power.
#[test]
fn a_silent_servo_on_a_timed_wire_is_recovered_not_taken_for_a_power_loss() {
    silent_servo_on(
        &[
            read_edit("sync"),
            ("wire_timing = false", "wire_timing = true"),
        ],
        TWO_PORTS,
    );
}

/// The servos' factory baud rate, 57600, on a timed wire: a dozen servos bring up and hold
/// with a 140 ms Bus Watchdog that never fires (the loop runs back to back, a tick about 60 ms). Bring-up's writes queue on the slow wire ahead
/// of its reads, and the health thresholds read after the watchdogs are armed once took a
/// servo at a time, leaving the first one unaddressed for 0.18 s.
#[test]
fn twelve_servos_at_57600_baud_come_up_and_hold_without_a_watchdog_firing() {
    let d = Daemon::start(sim_config(&[
        ("baud = 1000000", "baud = 57600"),
        ("wire_timing = false", "wire_timing = true"),
        ("watchdog_ms = 100", "watchdog_ms = 140"),
    ]));
    let mut c = d.client();
    let start = c.status()["tick"].as_u64().unwrap();
    let s = c.wait_status("ten more ticks", |s| {
        s["tick"].as_u64().unwrap() >= start + 10
    });
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["faults"], json!([]), "{s}");
    for id in 1..=12 {
        let fires = d.sim_of(id).with_servo(id, |s| s.watchdog_fires()).unwrap();
        assert_eq!(fires, 0, "servo {id}'s Bus Watchdog fired");
    }
    stop_torque_off(d);
}

/// Servo 5 silent from 2.5 s to 4 s, read with `read`, on the bus `ports` (`[[bus.ports]]`
/// tables) describes.
fn silent_servo(read: &str, ports: &str) {
    silent_servo_on(&[read_edit(read)], ports);
}

/// [`silent_servo`] with the shipped config edited as `edits` say.
fn silent_servo_on(edits: &[(&str, &str)], ports: &str) {
    let d = Daemon::start(sim_config_with(
        edits,
        &format!("[[sim.fault]]\nkind = \"silent\"\nid = 5\nat_s = 2.5\nuntil_s = 4.0\n{ports}"),
    ));
    // The budget is a time: at this rate, the reads it spans on schedule.
    let control = d.config.control();
    let read_period_s = f64::from(control.read_every) / control.rate_hz;
    let budget = (control.max_silence.as_secs_f64() / read_period_s).round() as u64;
    let (mut c, (lo, hi), start) = watching(&d);
    // A slow goto that is still moving when the servo goes silent.
    let goto = c.send(json!({"cmd": "goto", "target": [start[0] + 0.08, start[1]], "speed": 0.01}));
    assert_eq!(c.reply(&json!(goto))["ok"], json!(true));
    let mut skipped = Vec::new();
    let (mut samples, raised) =
        watch_until_event_keeping(&mut c, fault_event("raised", "silent"), &mut skipped);
    assert_eq!(raised["fault"]["id"], json!(5), "{raised}");
    assert_eq!(raised["fault"]["joint"], json!(5), "{raised}");
    assert_eq!(raised["fault"]["port"], json!(d.port_path(0)), "{raised}");
    let detected =
        raised["tick"].as_u64().unwrap() - raised["fault"]["since_tick"].as_u64().unwrap() + 1;
    println!("silent servo 5: fault raised on read {detected} without its reply (budget {budget})");
    // On schedule the fault comes on exactly the read that completes the budget; a tick that
    // ran late (an overrun) makes the same time pass in fewer reads, never more.
    let overran = samples.first().map(|t| &t["overruns"]) != samples.last().map(|t| &t["overruns"]);
    if overran {
        assert!((1..=budget).contains(&detected), "{raised}");
    } else {
        assert_eq!(detected, budget, "{raised}");
    }
    // The arm had not held before (a single miss never holds it).
    let raised_tick = raised["tick"].as_u64().unwrap();
    for t in samples
        .iter()
        .filter(|t| t["tick"].as_u64().unwrap() < raised_tick)
    {
        assert_ne!(t["state"], "fault", "{t}");
    }
    let s = c.status();
    assert_eq!(s["state"], "fault", "{s}");
    assert_eq!(s["faults"].as_array().unwrap().len(), 1, "{s}");
    assert_eq!(s["faults"][0]["id"], json!(5));
    assert_eq!(s["faults"][0]["kind"], "silent");
    assert!(s["faults"][0]["detail"]
        .as_str()
        .unwrap()
        .contains("consecutive reads"));
    assert_eq!(s["command"]["outcome"], "fault", "{s}");
    let stopped = skipped
        .iter()
        .find(|e| e["event"] == "stopped" && e["cmd_id"] == json!(goto))
        .unwrap_or_else(|| panic!("no `stopped` event for the goto: {skipped:?}"));
    assert_eq!(stopped["reason"], "fault");
    // Motion is refused while the fault holds; stop is fine.
    assert_eq!(
        c.error_code(json!({"cmd": "goto", "target": start})),
        "fault"
    );
    assert_eq!(
        c.error_code(json!({"cmd": "jog", "joint": 1, "rad_s": 0.1})),
        "fault"
    );
    c.ok(json!({"cmd": "stop"}));
    // Held: the goals do not move until it answers again.
    let mut between = Vec::new();
    // Servo 5's: on a loaded machine another servo's reply can come late enough to be held
    // silent a moment too.
    let mut cleared_5 = fault_event("cleared", "silent");
    let (held, cleared) = watch_until_event_keeping(
        &mut c,
        |e| cleared_5(e) && e["fault"]["id"] == json!(5),
        &mut between,
    );
    let faulted: Vec<&Value> = held.iter().filter(|t| t["state"] == "fault").collect();
    assert!(faulted.len() > 10, "{} samples in fault", faulted.len());
    for t in &faulted {
        assert_eq!(
            t["theta_cmd"], faulted[0]["theta_cmd"],
            "goals moved in fault"
        );
    }
    assert_eq!(cleared["fault"]["id"], json!(5));
    // Silent for 1.5 s with torque on: its watchdog fired and was cleared, by this recovery
    // (with others if the loop itself stalled past the watchdog on a loaded machine) or by a
    // stall's recovery just before it, which reports it on its own.
    let detail = cleared["fault"]["detail"].as_str().unwrap();
    let by_a_stall = between
        .iter()
        .any(|e| fault_event("recovered", "watchdog")(e) && e["fault"]["id"] == json!(5));
    assert!(
        fired_watchdogs(detail).contains(&5) || by_a_stall,
        "{detail}; before it: {between:?}"
    );
    println!("silent servo 5: cleared on its first answer: {detail}");
    samples.extend(held);
    let s = c.status();
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["faults"], json!([]));
    assert!(
        d.sim_of(5).with_servo(5, |s| s.watchdog()).unwrap() > 0,
        "watchdog not re-armed"
    );
    // Able to move again.
    goto_arrives(&mut c, [start[0] + 0.03, start[1] - 0.02]);
    samples.extend(watch(&mut c, 5));
    let reseeds = check_goals(&samples, &lo, &hi);
    assert!(reseeds <= 1, "{reseeds} jumps to the measured pose");
    stop_torque_off(d);
}

/// The servos a recovery's detail names as those whose Bus Watchdog had fired.
fn fired_watchdogs(detail: &str) -> Vec<u8> {
    let Some((_, list)) = detail.split_once("the Bus Watchdog of servos [") else {
        return Vec::new();
    };
    let list = list.split(']').next().unwrap_or_default();
    list.split(", ").filter_map(|id| id.parse().ok()).collect()
}

#[test]
fn a_hardware_error_holds_until_reboot_then_torque_is_back_and_the_arm_moves() {
    hardware_error("", 0);
}

/// The same with servo 9 on the second of two ports.
#[test]
fn a_hardware_error_on_the_second_of_two_ports_is_named_with_its_port() {
    hardware_error(TWO_PORTS, 1);
}

/// An overload of servo 9 (on port `k` of the bus `ports` describes) at 2 s.
fn hardware_error(ports: &str, k: usize) {
    let d = Daemon::start(sim_config_with(
        &[],
        &format!(
            "[[sim.fault]]\nkind = \"hardware_error\"\nid = 9\nat_s = 2.0\nerror = \
             \"overload\"\n{ports}"
        ),
    ));
    let (mut c, (lo, hi), start) = watching(&d);
    let (mut samples, raised) = watch_until_event(&mut c, fault_event("raised", "hardware_error"));
    assert_eq!(raised["fault"]["id"], json!(9), "{raised}");
    assert_eq!(raised["fault"]["port"], json!(d.port_path(k)), "{raised}");
    let detail = raised["fault"]["detail"].as_str().unwrap();
    assert!(detail.contains("overload"), "{detail}");
    let ticks = raised["tick"].as_u64().unwrap() - raised["fault"]["since_tick"].as_u64().unwrap();
    println!("hardware error on servo 9: raised {ticks} ticks after the alert was read: {detail}");
    assert_eq!(ticks, 0);
    let s = c.status();
    assert_eq!(s["state"], "fault");
    assert_eq!(s["faults"][0]["kind"], "hardware_error");
    assert!(!d.torque(9), "the servo's own shutdown switched torque off");
    assert_eq!(
        c.error_code(json!({"cmd": "goto", "target": start})),
        "fault"
    );
    assert_eq!(c.error_code(json!({"cmd": "torque", "on": true})), "fault");
    // It holds until rebooted: a while later it still does.
    samples.extend(watch(&mut c, 30));
    assert_eq!(c.status()["state"], "fault");
    let r = c.ok(json!({"cmd": "reboot"}));
    assert_eq!(r["rebooted"], json!([9]), "{r}");
    let cleared = c.event("fault", None);
    assert_eq!(cleared["reason"], "cleared", "{cleared}");
    assert_eq!(cleared["fault"]["id"], json!(9));
    let s = c.status();
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["torque"], json!(true));
    assert_eq!(s["faults"], json!([]));
    for id in 1..=12 {
        assert!(d.torque(id), "servo {id} torque off after the reboot");
    }
    assert_eq!(
        d.sim_of(9)
            .with_servo(9, |s| s.hardware_error_status())
            .unwrap(),
        0
    );
    goto_arrives(&mut c, [start[0] + 0.04, start[1] - 0.02]);
    samples.extend(watch(&mut c, 5));
    check_goals(&samples, &lo, &hi);
    stop_torque_off(d);
}

#[test]
fn torque_off_and_on_holds_the_measured_pose() {
    let d = Daemon::start(sim_config_with(&[], ""));
    let mut c = d.client();
    let start = xy(&c.status()["tip"]);
    c.ok(json!({"cmd": "torque", "on": false}));
    let s = c.status();
    assert_eq!(s["torque"], json!(false), "{s}");
    assert!((1..=12).all(|id| !d.torque(id)));
    assert_eq!(
        c.error_code(json!({"cmd": "goto", "target": start})),
        "fault"
    );
    c.ok(json!({"cmd": "torque", "on": true}));
    let s = c.status();
    assert_eq!(s["torque"], json!(true));
    assert!((1..=12).all(|id| d.torque(id)));
    // Goals := the measured pose.
    for (x, m) in floats(&s["theta_cmd"]).iter().zip(floats(&s["theta_meas"])) {
        assert!((x - m).abs() <= TICK_RAD, "goal {x} measured {m}");
    }
    goto_arrives(&mut c, [start[0] + 0.02, start[1]]);
    stop_torque_off(d);
}

/// A joint turned past its limit by hand while the arm is limp: `torque` on and `reset` refuse
/// to hold there (the goal, clamped into the limits, would drive it to the limit at full
/// speed), naming the joint, as bring-up does; once turned back inside, torque comes on.
#[test]
fn torque_on_and_reset_refuse_a_joint_turned_past_its_limit_by_hand() {
    let d = Daemon::start(sim_config_with(&[], ""));
    let mut c = d.client();
    let (_, hi) = limits(&mut c);
    let joint = d.config.arm().unwrap().joints()[2].clone();
    let turn = |rad: f64| {
        let ticks = joint.calibration.ticks(rad);
        d.sim_of(joint.id)
            .with_servo(joint.id, |s| s.turn_by_hand(ticks))
            .unwrap();
    };
    let message = |reply: &Value| reply["error"]["message"].as_str().unwrap().to_owned();
    c.ok(json!({"cmd": "torque", "on": false}));
    turn(hi[2] + 0.3);
    let refused = c.request(json!({"cmd": "torque", "on": true}));
    assert_eq!(refused["error"]["code"], json!("fault"), "{refused}");
    let why = message(&refused);
    assert!(
        why.contains("joint 3") && why.contains("outside its limits") && why.contains("by hand"),
        "{why}"
    );
    assert!((1..=12).all(|id| !d.torque(id)), "torque stays off");
    assert_eq!(c.status()["torque"], json!(false));

    // Under the estop latch, `reset` refuses the same and the latch stays.
    c.ok(json!({"cmd": "estop"}));
    let refused = c.request(json!({"cmd": "reset"}));
    assert_eq!(refused["error"]["code"], json!("fault"), "{refused}");
    let why = message(&refused);
    assert!(
        why.contains("joint 3") && why.contains("the latch stays"),
        "{why}"
    );
    assert_eq!(c.status()["state"], json!("estop"));
    assert!((1..=12).all(|id| !d.torque(id)), "torque stays off");

    // Back inside, on the limit itself: held there, no jump.
    turn(hi[2]);
    c.ok(json!({"cmd": "reset"}));
    let s = c.status();
    assert_eq!(s["torque"], json!(true), "{s}");
    assert!((1..=12).all(|id| d.torque(id)));
    assert!(
        (floats(&s["theta_cmd"])[2] - hi[2]).abs() <= TICK_RAD,
        "{s}"
    );
    stop_torque_off(d);
}

#[test]
fn health_rides_along_every_read_and_warns_before_the_servo_limits() {
    let d = Daemon::start(sim_config_with(&[], ""));
    let mut c = d.client();
    // The first answer already carries a health read: the one made before any client.
    let first = c.status();
    assert_eq!(first["load_unit"], json!(vec!["percent"; 12]), "{first}");
    assert_eq!(floats(&first["temperature_c"]), vec![30.0; 12], "{first}");
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    // Through Indirect Address every read carries load, voltage and temperature: the health
    // tick is the tick itself, whatever `health_every` says.
    let samples = watch(&mut c, 30);
    let fresh = samples
        .iter()
        .filter(|t| t["health_tick"] == t["tick"])
        .count();
    assert!(
        fresh * 10 >= samples.len() * 9,
        "{fresh} of {}",
        samples.len()
    );
    for t in &samples {
        assert_eq!(t["load_unit"], json!(vec!["percent"; 12]));
        assert!(floats(&t["voltage_v"]).iter().all(|&v| v > 10.0), "{t}");
    }
    // Bring-up mapped Indirect Address 1.. onto Present Load (126, 127), Velocity, Position...
    for id in [1, 12] {
        let first = d.sim.with_servo(id, |s| s.value(168)).unwrap().unwrap();
        let last = d.sim.with_servo(id, |s| s.value(192)).unwrap().unwrap();
        assert_eq!((first, last), (126, 146), "servo {id}");
    }
    let t = samples.last().unwrap();
    let v0 = d.sim.with_servo(4, |s| s.value(144)).unwrap().unwrap() as f64 / 10.0;
    assert!((floats(&t["voltage_v"])[3] - v0).abs() < 1e-9, "{t}");
    assert!((floats(&t["temperature_c"])[2] - 30.0).abs() < 1e-9, "{t}");
    // Temperature 4 °C under servo 3's limit: a warning, no fault.
    let limit = d.sim.with_servo(3, |s| s.value(31)).unwrap().unwrap() as f64;
    d.sim
        .with_servo(3, |s| s.set_temperature(limit - 4.0))
        .unwrap();
    let (_, warning) = watch_until_event(&mut c, |e| e["event"] == "warning");
    println!("temperature warning: {warning}");
    assert_eq!(warning["reason"], "raised");
    assert_eq!(warning["fault"]["id"], json!(3));
    assert_eq!(warning["fault"]["kind"], "temperature");
    let s = c.status();
    assert_eq!(s["state"], "holding");
    assert_eq!(s["warnings"][0]["kind"], "temperature", "{s}");
    assert!((floats(&s["temperature_c"])[2] - (limit - 4.0)).abs() < 1e-9);
    d.sim.with_servo(3, |s| s.set_temperature(40.0)).unwrap();
    let (_, cleared) = watch_until_event(&mut c, |e| e["event"] == "warning");
    assert_eq!(cleared["reason"], "cleared");
    // Input voltage 0.3 V above servo 4's Min Voltage Limit.
    let min = d.sim.with_servo(4, |s| s.value(34)).unwrap().unwrap() as f64;
    d.sim
        .with_servo(4, |s| s.set_input_voltage(min + 3.0))
        .unwrap();
    let (_, warning) = watch_until_event(&mut c, |e| e["event"] == "warning");
    println!("voltage warning: {warning}");
    assert_eq!(warning["fault"]["id"], json!(4));
    assert_eq!(warning["fault"]["kind"], "voltage");
    assert_eq!(c.status()["warnings"].as_array().unwrap().len(), 1);
    stop_torque_off(d);
}

#[test]
fn a_latency_spike_beyond_the_tick_costs_replies_never_a_burst_of_writes() {
    // A spike of 150 ms, every reply 20 ms late (two ticks): a budget of 300 ms (30 reads at
    // 100 Hz) rides it out whatever share of the replies it costs.
    let d = Daemon::start(sim_config_with(
        &[(
            "max_joint_speed_rad_s = 2.0\n",
            "max_joint_speed_rad_s = 2.0\nmax_silence_ms = 300\n",
        )],
        "[[sim.fault]]\nkind = \"latency\"\nextra_us = 20000\nat_s = 2.5\nuntil_s = 2.65\n",
    ));
    let (mut c, (lo, hi), start) = watching(&d);
    let goto = c.send(json!({"cmd": "goto", "target": [start[0] + 0.08, start[1]], "speed": 0.02}));
    assert_eq!(c.reply(&json!(goto))["ok"], json!(true));
    let first = watch(&mut c, 1).pop().unwrap();
    let t0 = Instant::now();
    let dropped0 = first["counters"]["dropped"].as_u64().unwrap();
    // Until half a second after the spike, by the simulator's clock.
    let sim_elapsed = || d.sim.with_sim(|s| s.start().elapsed());
    let mut samples = c.telemetry_until(|_| sim_elapsed() >= Duration::from_secs_f64(3.15));
    let wall = t0.elapsed().as_secs_f64();
    let last = samples.last().unwrap();
    let ticks = last["tick"].as_u64().unwrap() - first["tick"].as_u64().unwrap();
    let overruns = last["overruns"].as_u64().unwrap() - first["overruns"].as_u64().unwrap();
    let dropped = last["counters"]["dropped"].as_u64().unwrap() - dropped0;
    println!(
        "latency spike 20 ms for 150 ms: {dropped} replies lost, {ticks} ticks + {overruns} \
         overruns in {wall:.2} s of wall time ({:.0} periods), state {}",
        wall / DT,
        last["state"]
    );
    for t in &samples {
        assert_ne!(t["state"], "fault", "{t}");
    }
    // The first read in the spike waits at most to the end of its tick: every reply is lost
    // (later reads may get the late replies of the one before, or lose them too).
    assert!(dropped >= 12, "{dropped} replies lost");
    // Never catching up: no more ticks than periods in the wall time (a late tick is followed
    // at once by the next, which starts the schedule again, never by a burst), and the late
    // ones are counted.
    assert!(
        ticks as f64 <= wall / DT + 3.0,
        "{ticks} ticks + {overruns} overruns in {wall:.3} s"
    );
    assert!(overruns >= 1, "{ticks} ticks, no overrun in the spike");
    samples.extend(watch(&mut c, 5));
    assert_eq!(check_goals(&samples, &lo, &hi), 0);
    stop_torque_off(d);
}

#[test]
fn a_vanished_port_holds_the_arm_is_reopened_and_the_arm_moves_again() {
    vanished_port("fast", "", 0);
}

/// The same with Sync Read.
#[test]
fn a_vanished_port_holds_the_arm_is_reopened_and_the_arm_moves_again_with_sync_read() {
    vanished_port("sync", "", 0);
}

#[test]
fn a_vanished_port_of_two_holds_the_whole_arm_named_and_is_reopened() {
    vanished_port("fast", TWO_PORTS, 1);
}

/// Port `k` (from 0) of the bus `ports` describes vanishes from 2 s to 3.5 s; read with `read`.
fn vanished_port(read: &str, ports: &str, k: usize) {
    // The pseudo-terminal goes away for 1.5 s and comes back as a new device behind the same
    // link, as a USB adapter re-plugged behind its /dev/serial/by-id link.
    let which = if ports.is_empty() {
        String::new()
    } else {
        format!("port = {}\n", k + 1)
    };
    let d = Daemon::start(sim_config_with(
        &[read_edit(read)],
        &format!("[[sim.fault]]\nkind = \"disconnect\"\n{which}at_s = 2.0\nuntil_s = 3.5\n{ports}"),
    ));
    let (mut c, (lo, hi), start) = watching(&d);
    let goto = c.send(json!({"cmd": "goto", "target": [start[0] + 0.08, start[1]], "speed": 0.01}));
    assert_eq!(c.reply(&json!(goto))["ok"], json!(true));
    let (mut samples, raised) = watch_until_event(&mut c, fault_event("raised", "port"));
    let path = d.port_path(k);
    assert_eq!(raised["fault"]["port"], json!(path), "{raised}");
    assert!(
        raised["fault"]["detail"].as_str().unwrap().contains(&path) || ports.is_empty(),
        "{raised}"
    );
    let detected =
        raised["tick"].as_u64().unwrap() - raised["fault"]["since_tick"].as_u64().unwrap();
    println!("port gone: fault raised {detected} ticks after the first failed exchange");
    let s = c.status();
    assert_eq!(s["state"], "fault", "{s}");
    assert!(s["faults"]
        .as_array()
        .unwrap()
        .iter()
        .any(|f| f["kind"] == "port"));
    assert_eq!(
        c.error_code(json!({"cmd": "goto", "target": start})),
        "fault"
    );
    c.ok(json!({"cmd": "stop"}));
    let (held, cleared) = watch_until_event(&mut c, fault_event("cleared", "port"));
    let faulted: Vec<&Value> = held.iter().filter(|t| t["state"] == "fault").collect();
    for t in &faulted {
        assert_eq!(
            t["theta_cmd"], faulted[0]["theta_cmd"],
            "goals moved while the port was gone"
        );
    }
    // Periods of the loop, not ticks: on a loaded machine a late tick stands for the periods
    // it overran, and the window is wall-clock time.
    let overruns = |t: Option<&Value>| t.map_or(0, |t| t["overruns"].as_u64().unwrap());
    let overran = overruns(held.last()).saturating_sub(overruns(samples.last()));
    let gone = cleared["tick"].as_u64().unwrap() - raised["tick"].as_u64().unwrap() + overran;
    println!(
        "port gone: reopened {gone} periods after the fault ({overran} of them overrun; window \
         150 periods, retried every second)"
    );
    // The window is 1.5 s; the next attempt after it comes within a second.
    assert!((140..=260).contains(&gone), "reopened after {gone} periods");
    samples.extend(held);
    let s = c.wait_status("holding after the reopen", |s| s["state"] == "holding");
    assert_eq!(s["faults"], json!([]), "{s}");
    goto_arrives(&mut c, [start[0] + 0.03, start[1] - 0.02]);
    samples.extend(watch(&mut c, 5));
    let reseeds = check_goals(&samples, &lo, &hi);
    assert!(reseeds <= 1, "{reseeds} jumps to the measured pose");
    stop_torque_off(d);
}

/// Port 2 vanishes, then port 1 while port 2 is still gone: each is a fault of its own, both
/// listed while either is gone, both cleared once the two are back, and the arm holds again.
#[test]
fn both_ports_of_two_lost_one_after_the_other_are_each_named_and_both_recovered() {
    let d = Daemon::start(sim_config_with(
        &[],
        &format!(
            "[[sim.fault]]\nkind = \"disconnect\"\nport = 2\nat_s = 1.0\nuntil_s = 2.5\n\
             [[sim.fault]]\nkind = \"disconnect\"\nport = 1\nat_s = 1.5\nuntil_s = 2.5\n\
             {TWO_PORTS}"
        ),
    ));
    let (mut c, _, _) = watching(&d);
    let (first, second) = (d.port_path(1), d.port_path(0));
    let (_, raised) = watch_until_event(&mut c, fault_event("raised", "port"));
    assert_eq!(raised["fault"]["port"], json!(first), "{raised}");
    let (_, raised) = watch_until_event(&mut c, fault_event("raised", "port"));
    assert_eq!(raised["fault"]["port"], json!(second), "{raised}");
    assert!(
        raised["fault"]["detail"]
            .as_str()
            .unwrap()
            .contains(&second),
        "{raised}"
    );
    let s = c.status();
    let listed: Vec<&Value> = s["faults"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["kind"] == "port")
        .map(|f| &f["port"])
        .collect();
    assert_eq!(listed, [&json!(first), &json!(second)], "{s}");
    let mut cleared = Vec::new();
    while cleared.len() < 2 {
        let (_, e) = watch_until_event(&mut c, fault_event("cleared", "port"));
        cleared.push(e["fault"]["port"].clone());
    }
    assert_eq!(cleared, [json!(first), json!(second)]);
    let s = c.wait_status("holding after both ports are back", |s| {
        s["state"] == "holding"
    });
    assert_eq!(s["faults"], json!([]), "{s}");
    stop_torque_off(d);
}

#[test]
fn a_port_of_two_lost_for_good_leaves_the_other_open_and_estop_switches_its_servos_off() {
    lost_for_good(true);
}

#[test]
fn a_port_of_two_lost_for_good_leaves_shut_down_to_switch_the_other_ports_servos_off() {
    lost_for_good(false);
}

/// Port 2 (servos 7 to 12) of two vanishes for good: port 1 stays open and locked through the
/// reopening of port 2, its servos held (their Bus Watchdog fed) and switched off by an
/// `estop` (when `estop`, whose reply names servos 7 to 12 alone as not confirmed off) and by
/// shut-down, which names servos 7 to 12 alone as unreached, each for port 2.
fn lost_for_good(estop: bool) {
    let d = Daemon::start(sim_config_with(
        &[],
        &format!("[[sim.fault]]\nkind = \"disconnect\"\nport = 2\nat_s = 1.0\n{TWO_PORTS}"),
    ));
    let (mut c, _, _) = watching(&d);
    let (_, raised) = watch_until_event(&mut c, fault_event("raised", "port"));
    let (kept, lost) = (d.port_path(0), d.port_path(1));
    assert_eq!(raised["fault"]["port"], json!(lost), "{raised}");
    // Past two tries to reopen port 2 (one a second).
    watch(&mut c, 250);
    let s = c.status();
    assert_eq!(s["state"], "fault", "{s}");
    // Port 1 is still the daemon's: not even this process opens it a second time.
    let baud = d.config.bus().unwrap().baud;
    match snakectl::connect::open_port(&d.sim.pty_path().unwrap(), baud) {
        Err(snakectl::connect::ConnectError::InUse(_)) => {}
        other => panic!("port 1 ({kept}) was let go while port 2 was lost: {other:?}"),
    }
    for id in 1..=6 {
        assert!(d.torque(id), "servo {id} let go while port 2 was lost");
        let watchdog = d.sim.with_servo(id, |s| s.watchdog()).unwrap();
        assert!(watchdog > 0, "servo {id}: Bus Watchdog {watchdog}, not fed");
    }
    // Port 1's servos are still read: their health stays current while port 2 is lost.
    d.sim.with_servo(2, |s| s.set_temperature(47.0)).unwrap();
    let later = watch(&mut c, 30);
    let t = later.last().unwrap();
    assert!(
        t["health_tick"].as_u64() > s["health_tick"].as_u64(),
        "health not read while port 2 was lost: {t}"
    );
    assert!((floats(&t["temperature_c"])[1] - 47.0).abs() < 1e-9, "{t}");
    if estop {
        let reply = c.ok(json!({"cmd": "estop"}));
        for id in 1..=6 {
            assert!(!d.torque(id), "servo {id} torque on after the estop");
        }
        let unconfirmed = reply["unconfirmed"].as_array().cloned().unwrap_or_default();
        let ids: Vec<u64> = unconfirmed
            .iter()
            .filter_map(|u| u["id"].as_u64())
            .collect();
        assert_eq!(ids, (7..=12).collect::<Vec<u64>>(), "{reply}");
        for u in &unconfirmed {
            assert_eq!(u["joint"], u["id"], "{u}");
            let why = u["why"].as_str().unwrap_or_default();
            assert!(
                why.contains(&lost),
                "servo {} not named for port 2: {why}",
                u["id"]
            );
        }
        // Again from the command line: the latch stands, the servos of port 2 are still not
        // known to be off, and it says so, exiting 1.
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_snakectl"))
            .args(["estop", "--connect", &d.addr.to_string()])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(stderr.contains("estop latched"), "{stderr}");
        for id in 7..=12 {
            assert!(
                stderr.contains(&format!("servo {id} (joint {id})")),
                "{stderr}"
            );
        }
        assert!(!stderr.contains("servo 1 (joint 1)"), "{stderr}");
    }
    let (result, torques) = d.stop_and_torques();
    for (id, on) in torques.iter().filter(|(id, _)| *id <= 6) {
        assert!(!on, "servo {id} left with torque on by shut-down");
    }
    let unreached = match result {
        Err(snakectl::daemon::DaemonError::ShutDown(e)) => e.unreached,
        other => panic!("shut-down with port 2 lost: {other:?}"),
    };
    let ids: Vec<u8> = unreached.iter().map(|u| u.id).collect();
    assert_eq!(ids, (7..=12).collect::<Vec<u8>>(), "{unreached:?}");
    for u in &unreached {
        assert!(
            u.why.contains(&lost) && !u.why.contains(&kept),
            "servo {} unreached for the wrong port: {}",
            u.id,
            u.why
        );
    }
}

#[test]
fn a_servo_that_lost_power_latches_the_arm_until_reset_turns_torque_back_on() {
    power_loss("", 5);
}

/// The same with servo 9, on the second of two ports.
#[test]
fn a_servo_on_the_second_of_two_ports_that_lost_power_latches_the_arm() {
    power_loss(TWO_PORTS, 9);
}

/// Servo `id` (joint `id`) loses power during a slow goto, on the bus `ports` describes.
fn power_loss(ports: &str, id: u8) {
    let d = Daemon::start(sim_config_with(&[], ports));
    let (mut c, (lo, hi), start) = watching(&d);
    let goto = c.send(json!({"cmd": "goto", "target": [start[0] + 0.08, start[1]], "speed": 0.01}));
    assert_eq!(c.reply(&json!(goto))["ok"], json!(true));
    assert!(d.sim_of(id).with_sim(|s| s.lose_power(id)));
    let (mut samples, _) = watch_until_event(&mut c, fault_event("raised", "silent"));
    // Power back: the servo answers with its RAM at the defaults.
    assert!(d.sim_of(id).with_sim(|s| s.restore_power(id)));
    let mut skipped = Vec::new();
    let (held, raised) =
        watch_until_event_keeping(&mut c, fault_event("raised", "power_loss"), &mut skipped);
    samples.extend(held);
    println!("power loss of servo {id}: {raised}");
    assert_eq!(raised["fault"]["id"], json!(id), "{raised}");
    assert_eq!(raised["fault"]["joint"], json!(id), "{raised}");
    let detail = raised["fault"]["detail"].as_str().unwrap();
    assert!(detail.contains("Bus Watchdog 0"), "{detail}");
    assert!(detail.contains("`reset`"), "{detail}");
    assert!(
        skipped.iter().any(|e| e["event"] == "estop"),
        "no estop event: {skipped:?}"
    );
    let s = c.status();
    assert_eq!(s["state"], "estop", "{s}");
    assert_eq!(s["torque"], json!(false), "{s}");
    // Not handed torque by itself: a second on, every servo is still limp.
    samples.extend(watch(&mut c, 100));
    for id in 1..=12 {
        assert!(!d.torque(id), "servo {id} torque on under the latch");
    }
    // Its RAM was written again as bring-up did.
    assert!(d.sim_of(id).with_servo(id, |s| s.watchdog()).unwrap() > 0);
    assert_eq!(
        c.error_code(json!({"cmd": "goto", "target": start})),
        "estopped"
    );
    assert_eq!(
        c.error_code(json!({"cmd": "torque", "on": true})),
        "estopped"
    );
    c.ok(json!({"cmd": "reset"}));
    let s = c.status();
    assert_eq!(s["state"], "holding", "{s}");
    assert_eq!(s["faults"], json!([]), "{s}");
    for id in 1..=12 {
        assert!(d.torque(id), "servo {id} torque off after the reset");
    }
    goto_arrives(&mut c, [start[0] + 0.03, start[1] - 0.02]);
    samples.extend(watch(&mut c, 5));
    check_goals(&samples, &lo, &hi);
    stop_torque_off(d);
}
