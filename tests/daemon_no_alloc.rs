//! The daemon's loop thread allocates nothing once warm: ticks that move the arm (motion,
//! resolve, joint-speed limit, Sync Write, Sync Read, telemetry) and ticks that hold it.
//! A counting allocator counts the allocations made on the thread named `snakectl-loop` only.
#![allow(clippy::unwrap_used)]

mod daemon_support;

mod alloc_support;

use daemon_support::{sim_config, xy, Daemon};
use serde_json::json;

#[global_allocator]
static GLOBAL: alloc_support::Counting = alloc_support::Counting;

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
