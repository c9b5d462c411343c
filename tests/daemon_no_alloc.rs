//! The daemon's loop thread allocates nothing once warm: ticks that move the arm (motion,
//! resolve, joint-speed limit, Sync Write, Sync Read, telemetry) and ticks that hold it.
//! A counting allocator counts the allocations made on the thread named `snakectl-loop` only.
#![allow(clippy::unwrap_used, unsafe_code)]

mod daemon_support;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

use daemon_support::{sim_config, xy, Daemon};
use serde_json::json;

struct Counting;

static LOOP_ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    /// Inside the allocator already (asking for the thread's name may allocate once).
    static BUSY: Cell<bool> = const { Cell::new(false) };
    /// Whether this thread is the loop's, once known.
    static IS_LOOP: Cell<Option<bool>> = const { Cell::new(None) };
}

fn count() {
    let _ = BUSY.try_with(|busy| {
        if busy.replace(true) {
            return;
        }
        let is_loop = IS_LOOP.try_with(|l| match l.get() {
            Some(v) => v,
            None => {
                let v = std::thread::current().name() == Some("snakectl-loop");
                l.set(Some(v));
                v
            }
        });
        if is_loop == Ok(true) {
            LOOP_ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        busy.set(false);
    });
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

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
    let before = LOOP_ALLOCATIONS.load(Ordering::Relaxed);
    watch_ticks(&mut c, 100);
    let holding = LOOP_ALLOCATIONS.load(Ordering::Relaxed) - before;

    // Moving: a slow goto that lasts longer than the window watched.
    c.ok(json!({"cmd": "goto", "target": [tip[0] + 0.06, tip[1] - 0.02], "speed": 0.02}));
    let t = watch_ticks(&mut c, 30);
    assert_eq!(t["state"], "moving");
    let before = LOOP_ALLOCATIONS.load(Ordering::Relaxed);
    let t = watch_ticks(&mut c, 150);
    let moving = LOOP_ALLOCATIONS.load(Ordering::Relaxed) - before;
    assert_eq!(
        t["state"], "moving",
        "the goto ended inside the window: {t}"
    );

    assert_eq!(holding, 0, "allocations on the loop thread while holding");
    assert_eq!(moving, 0, "allocations on the loop thread while moving");
    // The counter does count on that thread: a command's answer allocates.
    let before = LOOP_ALLOCATIONS.load(Ordering::Relaxed);
    c.status();
    assert!(LOOP_ALLOCATIONS.load(Ordering::Relaxed) > before);
}
