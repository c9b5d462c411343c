//! A disconnect fault as a client sees it: the pseudo-terminal goes away for the window (the
//! client's port fails, the link is gone), then the chain is back on a new pseudo-terminal behind
//! the same link, every servo's state carried through. Time is a manual clock the test advances.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use dynamixel2::Bus;
use snakectl_sim::table::addr;
use snakectl_sim::{
    spawn_pty_linked, Fault, Link, ManualClock, Model, ServoSpec, SimConfig, Simulator,
};

type Client = Bus<Vec<u8>, Vec<u8>>;

const DEADLINE: Duration = Duration::from_secs(10);

fn chain(faults: Vec<Fault>) -> (Simulator, ManualClock) {
    let clock = ManualClock::new();
    let config = SimConfig {
        servos: vec![
            ServoSpec::new(1, Model::Xl430W250),
            ServoSpec::new(2, Model::Xl430W250),
        ],
        faults,
        ..SimConfig::default()
    };
    (
        Simulator::new(config, Arc::new(clock.clone())).unwrap(),
        clock,
    )
}

fn open(path: &Path) -> Client {
    Bus::open_with_buffers(path, 1_000_000, vec![0; 256], vec![0; 256]).expect("open")
}

/// Poll `done` until it holds; panics after [`DEADLINE`] (the serving thread is late only on
/// failure or on a very busy machine).
fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + DEADLINE;
    while !done() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn is_link(path: &Path) -> bool {
    path.symlink_metadata()
        .is_ok_and(|m| m.file_type().is_symlink())
}

/// A ping, sent again while dynamixel2's fixed reply wait runs out on a busy machine.
fn ping(bus: &mut Client, id: u8) -> u16 {
    let mut last = None;
    for _ in 0..5 {
        match bus.ping(id) {
            Ok(r) => return r.data.model,
            Err(e) => last = Some(e),
        }
    }
    panic!("servo {id} does not answer: {last:?}")
}

#[test]
fn a_disconnect_window_unplugs_the_pty_and_the_link_brings_the_servos_back_as_they_were() {
    let s = Duration::from_secs;
    let (sim, clock) = chain(vec![Fault::Disconnect.during(s(1), Some(s(3)))]);
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("bus");
    let handle = spawn_pty_linked(sim, Link::At(link.clone())).unwrap();
    assert_eq!(handle.path(), link);
    assert_eq!(handle.link(), Some(link.as_path()));
    let old = handle.pty_path().expect("served from the start");
    assert_eq!(std::fs::read_link(&link).unwrap(), old);

    let mut bus = open(&link);
    assert_eq!(ping(&mut bus, 1), 1060);
    bus.write_u8(1, addr::TORQUE_ENABLE, 1).unwrap();
    bus.write_u32(1, addr::GOAL_POSITION, 3000).unwrap();
    // Servo 2 holds with a 100 ms Bus Watchdog: a silent window longer than that trips it.
    bus.write_u8(2, addr::BUS_WATCHDOG, 5).unwrap();
    bus.write_u8(2, addr::TORQUE_ENABLE, 1).unwrap();

    clock.advance(s(1));
    wait_for("the unplug", || handle.pty_path().is_none());
    assert!(!is_link(&link), "the link is gone while unplugged");
    assert!(bus.ping(1).is_err(), "the port fails while unplugged");
    assert!(
        Bus::open(&link, 1_000_000).is_err(),
        "nothing to reopen yet"
    );

    clock.advance(s(2));
    wait_for("the plug-back", || handle.pty_path().is_some());
    let new = handle.pty_path().unwrap();
    assert_ne!(new, old, "a new pseudo-terminal");
    assert_eq!(std::fs::read_link(&link).unwrap(), new);
    assert!(bus.ping(1).is_err(), "the old port stays dead");

    let mut bus = open(&link);
    assert_eq!(ping(&mut bus, 1), 1060);
    assert_eq!(bus.read_u8(1, addr::TORQUE_ENABLE).unwrap().data, 1);
    assert_eq!(bus.read_u32(1, addr::GOAL_POSITION).unwrap().data, 3000);
    let present = bus.read_u32(1, addr::PRESENT_POSITION).unwrap().data as i32;
    assert!(
        (present - 3000).abs() <= 2,
        "servo 1 moved on during the window: at {present}"
    );
    assert_eq!(
        bus.read_u8(2, addr::BUS_WATCHDOG).unwrap().data as i8,
        -1,
        "servo 2's watchdog fired while unplugged"
    );
    drop(bus);
    handle.stop().unwrap();
    assert!(
        !is_link(&link),
        "the link is removed when the simulator stops"
    );
}

#[test]
fn a_disconnect_at_the_start_serves_nothing_until_its_window_closes() {
    let (sim, clock) = chain(vec![
        Fault::Disconnect.during(Duration::ZERO, Some(Duration::from_millis(500)))
    ]);
    let handle = spawn_pty_linked(sim, Link::Private).unwrap();
    wait_for("the unplug", || handle.pty_path().is_none());
    assert!(!is_link(handle.path()));
    clock.advance(Duration::from_millis(500));
    wait_for("the plug-back", || handle.pty_path().is_some());
    let mut bus = open(handle.path());
    assert_eq!(ping(&mut bus, 2), 1060);
}

#[test]
fn a_private_link_lives_in_its_own_temporary_directory_until_the_handle_drops() {
    let (sim, _clock) = chain(Vec::new());
    let handle = spawn_pty_linked(sim, Link::Private).unwrap();
    let link = handle.path().to_path_buf();
    let dir = link.parent().unwrap().to_path_buf();
    assert!(dir.starts_with(std::env::temp_dir()), "{}", link.display());
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        handle.pty_path().unwrap()
    );
    let mut bus = open(&link);
    assert_eq!(ping(&mut bus, 1), 1060);
    // A second simulator gets a directory of its own.
    let (other, _clock) = chain(Vec::new());
    let other = spawn_pty_linked(other, Link::Private).unwrap();
    assert_ne!(other.path().parent(), Some(dir.as_path()));
    drop(bus);
    drop(handle);
    assert!(
        !is_link(&link) && !dir.exists(),
        "{} is left",
        dir.display()
    );
}

#[test]
fn a_link_replaces_an_old_symlink_but_not_another_file() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("bus");
    std::os::unix::fs::symlink("/nonexistent/old-pty", &link).unwrap();
    let (sim, _clock) = chain(Vec::new());
    let handle = spawn_pty_linked(sim, Link::At(link.clone())).unwrap();
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        handle.pty_path().unwrap()
    );
    drop(handle);

    let file = dir.path().join("notes.txt");
    std::fs::write(&file, "keep me").unwrap();
    let (sim, _clock) = chain(Vec::new());
    let err = spawn_pty_linked(sim, Link::At(file.clone())).unwrap_err();
    assert!(err.to_string().contains("notes.txt"), "{err}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep me");
}
