//! The joystick from bytes to actions: recorded-style `js_event` streams through the parser
//! and the stick, and the device reader on a FIFO standing in for `/dev/input/js0`.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fs::OpenOptions;
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::mpsc::{sync_channel, Receiver};
use std::time::{Duration, Instant};

use snakectl::teleop::input::{Action, RENEW_HZ};
use snakectl::teleop::joystick::{
    parse_js_events, spawn, Device, EvdevEvent, JsEvent, Stick, StickEvent, EV_ABS, EV_KEY,
    JS_EVENT_AXIS, JS_EVENT_BUTTON, JS_EVENT_INIT,
};

const SPEED: f64 = 0.1;
const DEADMAN: u8 = 4;
const WAIT: Duration = Duration::from_secs(10);
/// `O_NONBLOCK` on Linux: open a FIFO's write end without waiting for a reader.
const O_NONBLOCK: i32 = 0o4000;

fn fixture(name: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/joystick")
        .join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// What a played stream gave: the actions its events caused (time in ms from its first
/// event), and those the ticks between them caused (time in s).
struct Played {
    from_events: Vec<(u32, Action)>,
    from_ticks: Vec<(f64, Action)>,
}

/// Plays `bytes` through a stick, ticking at its deadlines between events.
fn play(bytes: &[u8]) -> Played {
    let events = parse_js_events(bytes).unwrap();
    let t0 = events[0].time_ms;
    let mut stick = Stick::new(DEADMAN);
    let mut out = Vec::new();
    stick.event(StickEvent::Connected, 0.0, SPEED, true, &mut out);
    let (mut from_events, mut from_ticks) = (Vec::new(), Vec::new());
    for event in &events {
        let now = f64::from(event.time_ms - t0) / 1000.0;
        while let Some(deadline) = stick.next_deadline().filter(|d| *d < now) {
            stick.tick(deadline, SPEED, true, &mut out);
            from_ticks.extend(out.drain(..).map(|a| (deadline, a)));
        }
        if let Some(event) = event.stick_event() {
            stick.event(event, now, SPEED, true, &mut out);
        }
        from_events.extend(out.drain(..).map(|a| (event.time_ms - t0, a)));
    }
    Played {
        from_events,
        from_ticks,
    }
}

fn assert_actions(got: &[(u32, Action)], want: &[(u32, Option<[f64; 2]>)]) {
    assert_eq!(got.len(), want.len(), "{got:?}");
    for ((t, action), (want_t, want_v)) in got.iter().zip(want) {
        let Action::Velocity(v) = action else {
            panic!("not a velocity at {t}: {action:?}")
        };
        assert_eq!(t, want_t, "{got:?}");
        let want_v = want_v.unwrap_or([0.0, 0.0]);
        assert!(
            (v[0] - want_v[0]).abs() < 1e-6 && (v[1] - want_v[1]).abs() < 1e-6,
            "at {t}: {v:?}, want {want_v:?}"
        );
    }
}

#[test]
fn a_pad_session_gives_the_motions_the_operator_made() {
    let bytes = fixture("pad_session.bin");
    assert_eq!(bytes.len(), 34 * 8);
    let events = parse_js_events(&bytes).unwrap();
    assert_eq!(events.iter().filter(|e| e.is_init()).count(), 19);
    let Played {
        from_events,
        from_ticks,
    } = play(&bytes);
    assert_actions(
        &from_events,
        &[
            (2350, Some([-0.0017542, 0.0263271])),
            (2380, Some([-0.0019472, 0.0652659])),
            (2410, Some([-0.0019986, 0.0999800])),
            (2700, Some([0.0410361, 0.0911923])),
            (2730, Some([0.0707107, 0.0707107])),
            (3400, Some([0.0036933, 0.0999318])),
            (3400, None),
            (3900, Some([-0.0789507, 0.0021986])),
            (4300, None),
        ],
    );
    // While moving, the velocity is renewed at 20 Hz: no gap longer than 50 ms, and only
    // inside the two motions (the last one ends with a nonzero send just before its zero).
    let mut sends: Vec<f64> = from_events
        .iter()
        .filter(|(_, a)| *a != Action::Velocity([0.0, 0.0]))
        .map(|(t, _)| f64::from(*t) / 1000.0)
        .chain(from_ticks.iter().map(|(t, _)| *t))
        .collect();
    sends.sort_by(f64::total_cmp);
    let motions = [(2.35, 3.4), (3.9, 4.3)];
    for (start, end) in motions {
        let inside: Vec<f64> = sends
            .iter()
            .copied()
            .filter(|t| (start..end).contains(t))
            .collect();
        let expected = ((end - start) * RENEW_HZ).ceil() as usize;
        assert!(inside.len() >= expected, "{start}..{end}: {inside:?}");
        for pair in inside.windows(2) {
            assert!(pair[1] - pair[0] <= 1.0 / RENEW_HZ + 1e-9, "{inside:?}");
        }
        assert!(end - inside.last().unwrap() <= 1.0 / RENEW_HZ + 1e-9);
    }
    assert!(sends
        .iter()
        .all(|t| motions.iter().any(|(s, e)| (*s..=*e).contains(t))));
}

#[test]
fn a_deadman_held_when_the_device_opens_moves_nothing_until_pressed_again() {
    let bytes = fixture("held_at_open.bin");
    let events = parse_js_events(&bytes).unwrap();
    let init_deadman = events
        .iter()
        .find(|e| e.is_init() && e.kind & !JS_EVENT_INIT == JS_EVENT_BUTTON && e.number == DEADMAN)
        .unwrap();
    assert_eq!(
        init_deadman.value, 1,
        "the fixture opens with the deadman held"
    );
    let from_events = play(&bytes).from_events;
    assert_actions(
        &from_events,
        &[(1500, Some([0.0003834, 0.0589864])), (2000, None)],
    );
}

fn mkfifo(path: &Path) {
    let status = Command::new("mkfifo").arg(path).status().unwrap();
    assert!(status.success(), "mkfifo {}", path.display());
}

/// Opens the FIFO's write end once the reader has its read end open.
fn open_writer(path: &Path) -> std::fs::File {
    let deadline = Instant::now() + WAIT;
    loop {
        match OpenOptions::new()
            .write(true)
            .custom_flags(O_NONBLOCK)
            .open(path)
        {
            Ok(file) => return file,
            Err(e) => assert!(
                Instant::now() < deadline,
                "no reader on {}: {e}",
                path.display()
            ),
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn next(rx: &Receiver<StickEvent>) -> StickEvent {
    rx.recv_timeout(WAIT).expect("an event from the reader")
}

fn js(kind: u8, number: u8, value: i16) -> [u8; 8] {
    JsEvent {
        time_ms: 77_000,
        value,
        kind,
        number,
    }
    .to_bytes()
}

fn wait_finished(handle: &std::thread::JoinHandle<()>) {
    let deadline = Instant::now() + WAIT;
    while !handle.is_finished() {
        assert!(Instant::now() < deadline, "the reader thread did not end");
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn fifo_in_temp(name: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    mkfifo(&path);
    (dir, path)
}

#[test]
fn the_reader_reports_events_disconnects_and_finds_the_device_again() {
    let (_dir, fifo) = fifo_in_temp("js0");
    let (tx, rx) = sync_channel(16);
    let handle = spawn(Device::Path(fifo.clone()), tx).unwrap();

    let mut writer = open_writer(&fifo);
    assert_eq!(next(&rx), StickEvent::Connected);
    let mut bytes = Vec::new();
    bytes.extend(js(JS_EVENT_BUTTON | JS_EVENT_INIT, DEADMAN, 0));
    bytes.extend(js(JS_EVENT_AXIS | JS_EVENT_INIT, 1, 0));
    bytes.extend(js(JS_EVENT_BUTTON, DEADMAN, 1));
    bytes.extend(js(JS_EVENT_AXIS, 1, -32767));
    writer.write_all(&bytes).unwrap();
    let deadman = |pressed| StickEvent::Button {
        number: DEADMAN,
        pressed,
    };
    assert_eq!(next(&rx), deadman(false));
    assert_eq!(
        next(&rx),
        StickEvent::Axis {
            number: 1,
            value: 0.0
        }
    );
    assert_eq!(next(&rx), deadman(true));
    assert_eq!(
        next(&rx),
        StickEvent::Axis {
            number: 1,
            value: -1.0
        }
    );

    // Unplugged (half an event, then gone): no event from the half, one Disconnected.
    writer.write_all(&js(JS_EVENT_AXIS, 0, 500)[..3]).unwrap();
    drop(writer);
    assert_eq!(next(&rx), StickEvent::Disconnected);

    // Plugged back: found again, state and events as before.
    let mut writer = open_writer(&fifo);
    assert_eq!(next(&rx), StickEvent::Connected);
    writer
        .write_all(&js(JS_EVENT_BUTTON | JS_EVENT_INIT, DEADMAN, 1))
        .unwrap();
    assert_eq!(next(&rx), deadman(true));

    // The receiver gone: the reader ends at its next event.
    drop(rx);
    let _ = writer.write_all(&js(JS_EVENT_BUTTON, DEADMAN, 0));
    wait_finished(&handle);
}

#[test]
fn an_evdev_device_reports_buttons_released_on_open_then_its_events() {
    let (_dir, fifo) = fifo_in_temp("event3");
    let (tx, rx) = sync_channel(64);
    let handle = spawn(Device::Path(fifo.clone()), tx).unwrap();
    let mut writer = open_writer(&fifo);
    assert_eq!(next(&rx), StickEvent::Connected);
    for number in 0..16 {
        assert_eq!(
            next(&rx),
            StickEvent::Button {
                number,
                pressed: false
            }
        );
    }
    let event = |kind, code, value| EvdevEvent {
        sec: 1_700_000_000,
        usec: 5,
        kind,
        code,
        value,
    };
    let mut bytes = Vec::new();
    bytes.extend(event(EV_KEY, 0x136, 1).to_bytes()); // BTN_TL: button 6
    bytes.extend(event(0, 0, 0).to_bytes()); // SYN_REPORT: nothing
    bytes.extend(event(EV_ABS, 0, -32767).to_bytes());
    writer.write_all(&bytes).unwrap();
    assert_eq!(
        next(&rx),
        StickEvent::Button {
            number: 6,
            pressed: true
        }
    );
    assert_eq!(
        next(&rx),
        StickEvent::Axis {
            number: 0,
            value: -1.0
        }
    );
    drop(writer);
    assert_eq!(next(&rx), StickEvent::Disconnected);
    drop(rx);
    // Waiting in open for a writer: one comes, the Connected fails, the thread ends.
    let _writer = open_writer(&fifo);
    wait_finished(&handle);
}

#[test]
fn a_missing_device_is_retried_and_the_reader_ends_when_the_receiver_goes() {
    let dir = tempfile::tempdir().unwrap();
    let (tx, rx) = sync_channel(4);
    let handle = spawn(Device::Path(dir.path().join("js7")), tx).unwrap();
    assert_eq!(next(&rx), StickEvent::Disconnected);
    assert_eq!(next(&rx), StickEvent::Disconnected);
    assert!(!handle.is_finished());
    drop(rx);
    wait_finished(&handle);
}
