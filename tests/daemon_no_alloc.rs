//! The daemon's loop thread allocates nothing once warm: ticks that move the arm (motion,
//! resolve, joint-speed limit, Sync Write, Sync Read, telemetry) and ticks that hold it.
//! A counting allocator counts the allocations made on the thread named `snakectl-loop` only.
#![allow(clippy::unwrap_used)]

use crate::daemon_support;

use crate::alloc_support;

use daemon_support::{sim_config, xy, Daemon};
use serde_json::json;

/// The tests of this file run one at a time: the count is of every thread named
/// `snakectl-loop`, and each test has a daemon of its own.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Telemetry lines until `ticks` more ticks have run; no request is sent meanwhile.
fn watch_ticks(c: &mut daemon_support::Client, ticks: u64) -> serde_json::Value {
    let mut first = None;
    c.telemetry_until(|t| {
        let tick = t["tick"].as_u64().unwrap();
        let start = *first.get_or_insert(tick);
        tick >= start + ticks
    })
    .pop()
    .unwrap()
}

#[test]
fn warm_ticks_of_the_loop_thread_allocate_nothing() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    let s = c.status();
    let tip = xy(&s["tip"]);
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));

    // Holding.
    watch_ticks(&mut c, 50);
    let before = alloc_support::loop_thread();
    watch_ticks(&mut c, 100);
    let holding = alloc_support::loop_thread() - before;

    // Moving: a slow goto that lasts longer than the window watched.
    c.ok(json!({"cmd": "goto", "target": [tip[0] + 0.06, tip[1] - 0.02], "speed": 0.02}));
    let t = watch_ticks(&mut c, 30);
    assert_eq!(t["state"], "moving");
    let before = alloc_support::loop_thread();
    let t = watch_ticks(&mut c, 150);
    let moving = alloc_support::loop_thread() - before;
    assert_eq!(
        t["state"], "moving",
        "the goto ended inside the window: {t}"
    );

    assert_eq!(holding, 0, "allocations on the loop thread while holding");
    assert_eq!(moving, 0, "allocations on the loop thread while moving");
    // The counter does count on that thread: a command's answer allocates.
    let before = alloc_support::loop_thread();
    c.status();
    assert!(alloc_support::loop_thread() > before);
}

#[test]
fn warm_ticks_among_obstacles_allocate_nothing() {
    let _one = one_at_a_time();
    let d = Daemon::start(sim_config(&[]));
    let mut c = d.client();
    c.ok(json!({"cmd": "take_control"}));
    let s = c.status();
    let tip = xy(&s["tip"]);
    // A wall 5 cm under the tip and a post beside the way: a goto along the wall keeps the
    // pairs near contact in the solve.
    let top = tip[1] - 0.05;
    let wall = json!({"id": "wall", "polygon": {"points": [
        [-1.0, top - 0.02], [tip[0] + 0.03, top - 0.02], [tip[0] + 0.03, top], [-1.0, top]]}});
    let post = json!({"id": "post", "circle": {"center": [tip[0] - 0.03, tip[1] + 0.06], "radius": 0.015}});
    c.ok(json!({"cmd": "set_world", "obstacles": [wall, post]}));
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));
    c.ok(json!({"cmd": "goto", "target": [tip[0] - 0.08, top + 0.025], "speed": 0.02}));
    let t = watch_ticks(&mut c, 30);
    assert_eq!(t["state"], "moving");
    let before = alloc_support::loop_thread();
    let t = watch_ticks(&mut c, 150);
    let moving = alloc_support::loop_thread() - before;
    assert_eq!(
        t["state"], "moving",
        "the goto ended inside the window: {t}"
    );
    assert!(
        t["min_clearance_m"].as_f64().unwrap() < 0.04,
        "near the wall: {t}"
    );
    assert_eq!(moving, 0, "allocations on the loop thread among obstacles");
}

#[test]
fn warm_ticks_of_a_recorded_run_allocate_nothing_on_the_loop_thread() {
    let _one = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let record = snakectl::record::RecordOptions::to(dir.path().join("run.mcap"));
    let d = Daemon::start_with(sim_config(&[]), Some(record));
    let mut c = d.client();
    let s = c.status();
    let tip = xy(&s["tip"]);
    c.ok(json!({"cmd": "subscribe", "rate_hz": 100.0}));

    watch_ticks(&mut c, 50);
    let before = alloc_support::loop_thread();
    watch_ticks(&mut c, 100);
    let holding = alloc_support::loop_thread() - before;

    c.ok(json!({"cmd": "goto", "target": [tip[0] + 0.06, tip[1] - 0.02], "speed": 0.02}));
    let t = watch_ticks(&mut c, 30);
    assert_eq!(t["state"], "moving");
    let before = alloc_support::loop_thread();
    let t = watch_ticks(&mut c, 150);
    let moving = alloc_support::loop_thread() - before;
    assert_eq!(
        t["state"], "moving",
        "the goto ended inside the window: {t}"
    );

    assert_eq!(
        holding, 0,
        "allocations on the loop thread while holding, recorded"
    );
    assert_eq!(
        moving, 0,
        "allocations on the loop thread while moving, recorded"
    );
    drop(c);
    let summary = d.stop().unwrap();
    let recording = snakectl::record::Recording::open(&dir.path().join("run.mcap")).unwrap();
    assert_eq!(
        recording.channels["/snakectl/joint_states"].messages.len() as u64,
        summary.ticks + 1,
        "every tick recorded"
    );
}
