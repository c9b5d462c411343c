//! The joystick: Linux joystick (`/dev/input/js*`, 8-byte `js_event`) and evdev
//! (`/dev/input/event*`) devices read without libudev, and [`Stick`], the pure logic that
//! turns the left stick and a deadman button into tip velocities.
//!
//! evdev without ioctls cannot ask a device for its axis range, so evdev axes are taken as
//! the signed 16-bit range (-32768..=32767, as the xpad driver reports). An axis that reports
//! a value outside it has another range; it reads 0 from then on (no motion rather than a
//! wrong one). The js interface has no such problem: the kernel scales its axes to ±32767.
//! evdev buttons are numbered from their codes: `BTN_SOUTH` (0x130) .. 0x13f are 0..=15
//! (south 0, east 1, c 2, north 3, west 4, z 5, tl 6, tr 7, ...) and `BTN_TRIGGER` (0x120)
//! .. 0x12f are 0..=15 too (joysticks); other codes are not reported. This numbering
//! differs from the js interface's, which counts only the buttons the device has.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::mpsc::SyncSender;
use std::time::Duration;

use super::input::{Action, RENEW_HZ};

/// What the device reader reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StickEvent {
    /// The device was opened (again); its state follows as events.
    Connected,
    /// The device went away; the reader tries to open it again.
    Disconnected,
    /// An axis moved: its number and position, -1..=1 (y positive down, as devices report).
    Axis {
        /// Axis number (0: left stick x, 1: left stick y).
        number: u8,
        /// Position, -1..=1.
        value: f64,
    },
    /// A button was pressed or released.
    Button {
        /// Button number.
        number: u8,
        /// Pressed.
        pressed: bool,
    },
}

/// The stick's dead zone: deflections up to this (radially) give no motion; beyond it the
/// speed rises from 0 at its edge to full at full deflection.
pub const DEAD_ZONE: f64 = 0.05;

/// The stick's state: the left stick gives the tip velocity while the deadman button is held.
#[derive(Debug, Clone)]
pub struct Stick {
    deadman_button: u8,
    /// Left stick x and y as the device reports them (y positive down).
    axes: [f64; 2],
    /// The deadman is held and counts (pressed after a release seen since the device opened).
    engaged: bool,
    /// A release of the deadman was seen since the device opened, so a press may count.
    armed: bool,
    /// The last velocity sent, when a motion is going on.
    moving: Option<[f64; 2]>,
    /// When the motion was last sent at once; renewals count from here, s.
    base_s: f64,
    /// The number of the next renewal after `base_s`.
    renewal: u32,
}

impl Stick {
    /// With `deadman_button` as the button that must be held.
    pub fn new(deadman_button: u8) -> Self {
        Self {
            deadman_button,
            axes: [0.0; 2],
            engaged: false,
            armed: false,
            moving: None,
            base_s: 0.0,
            renewal: 1,
        }
    }

    /// The deadman button's number.
    pub fn deadman_button(&self) -> u8 {
        self.deadman_button
    }

    /// The tip velocity the stick asks for now, m/s: `None` without the deadman or in the
    /// dead zone.
    pub fn velocity(&self, speed_m_s: f64) -> Option<[f64; 2]> {
        if !self.engaged {
            return None;
        }
        let [x, y] = stick_deflection(self.axes);
        (x != 0.0 || y != 0.0).then_some([x * speed_m_s, y * speed_m_s])
    }

    /// A device event at `now_s`; the stick's full deflection is `speed_m_s`.
    pub fn event(
        &mut self,
        event: StickEvent,
        now_s: f64,
        speed_m_s: f64,
        in_control: bool,
        out: &mut Vec<Action>,
    ) {
        match event {
            StickEvent::Connected | StickEvent::Disconnected => {
                // Whatever was held before is unknown now: a press counts only after a release.
                self.axes = [0.0; 2];
                self.engaged = false;
                self.armed = false;
            }
            StickEvent::Axis { number, value } => {
                if let Some(axis) = self.axes.get_mut(usize::from(number)) {
                    *axis = if value.is_nan() {
                        0.0
                    } else {
                        value.clamp(-1.0, 1.0)
                    };
                }
            }
            StickEvent::Button { number, pressed } if number == self.deadman_button => {
                if pressed {
                    self.engaged = self.armed;
                } else {
                    self.engaged = false;
                    self.armed = true;
                }
            }
            StickEvent::Button { .. } => {}
        }
        self.update(now_s, speed_m_s, in_control, out);
    }

    /// Time passing: renewals while the deadman is held and the stick is out of its dead zone.
    pub fn tick(&mut self, now_s: f64, speed_m_s: f64, in_control: bool, out: &mut Vec<Action>) {
        self.update(now_s, speed_m_s, in_control, out);
        if let (Some(v), true) = (self.moving, now_s >= self.next_renewal_s()) {
            let behind = ((now_s - self.base_s) * RENEW_HZ).floor();
            let mut renewal = if (0.0..1e9).contains(&behind) {
                (behind as u32).max(self.renewal)
            } else {
                self.renewal
            };
            while self.base_s + f64::from(renewal) / RENEW_HZ <= now_s && renewal < u32::MAX {
                renewal += 1;
            }
            self.renewal = renewal;
            out.push(Action::Velocity(v));
        }
    }

    /// Ends the motion going on, if any, with its one zero (teleop quitting, say); the deadman
    /// counts again only after a release.
    pub fn halt(&mut self, in_control: bool, out: &mut Vec<Action>) {
        if self.moving.take().is_some() && in_control {
            out.push(Action::Velocity([0.0, 0.0]));
        }
        self.engaged = false;
        self.armed = false;
    }

    /// When [`Stick::tick`] next has something to do, s.
    pub fn next_deadline(&self) -> Option<f64> {
        self.moving.map(|_| self.next_renewal_s())
    }

    fn next_renewal_s(&self) -> f64 {
        self.base_s + f64::from(self.renewal) / RENEW_HZ
    }

    /// Sends the velocity at once when it changed, the one zero when the motion ended.
    fn update(&mut self, now_s: f64, speed_m_s: f64, in_control: bool, out: &mut Vec<Action>) {
        if !in_control {
            // Not ours to command: nothing, and nothing to end later.
            self.moving = None;
            return;
        }
        match (self.velocity(speed_m_s), self.moving) {
            (Some(v), moving) if moving != Some(v) => {
                out.push(Action::Velocity(v));
                self.moving = Some(v);
                self.base_s = now_s;
                self.renewal = 1;
            }
            (None, Some(_)) => {
                out.push(Action::Velocity([0.0, 0.0]));
                self.moving = None;
            }
            _ => {}
        }
    }
}

/// The tip direction and size, 0..=1, for stick axes `[x, y]` as devices report them (y
/// positive down): tip +y is stick up; radial dead zone [`DEAD_ZONE`], rescaled so the size
/// rises from 0 at its edge.
pub fn stick_deflection(axes: [f64; 2]) -> [f64; 2] {
    let [x, y] = [axes[0], -axes[1]];
    let size = (x * x + y * y).sqrt();
    if size.is_nan() || size <= DEAD_ZONE {
        return [0.0, 0.0];
    }
    let scaled = (size.min(1.0) - DEAD_ZONE) / (1.0 - DEAD_ZONE);
    [x / size * scaled, y / size * scaled]
}

/// A read or a byte slice too short for one device event.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("a {format} is {needed} bytes, got {got}")]
pub struct ShortEvent {
    /// `js_event` or `input_event`.
    pub format: &'static str,
    /// The event's size, bytes.
    pub needed: usize,
    /// The bytes there were.
    pub got: usize,
}

/// The size of one `js_event`, bytes.
pub const JS_EVENT_SIZE: usize = 8;

/// The size of one evdev `input_event` on a 64-bit system, bytes.
pub const EVDEV_EVENT_SIZE: usize = 24;

/// `js_event` type: a button.
pub const JS_EVENT_BUTTON: u8 = 0x01;
/// `js_event` type: an axis.
pub const JS_EVENT_AXIS: u8 = 0x02;
/// `js_event` type flag: the state on open, not a change.
pub const JS_EVENT_INIT: u8 = 0x80;

/// One `js_event` as the joystick interface reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JsEvent {
    /// The event's time stamp, ms (from an arbitrary origin).
    pub time_ms: u32,
    /// The button's state (0, 1) or the axis position (-32767..=32767).
    pub value: i16,
    /// [`JS_EVENT_BUTTON`] or [`JS_EVENT_AXIS`], maybe with [`JS_EVENT_INIT`].
    pub kind: u8,
    /// The button or axis number.
    pub number: u8,
}

impl JsEvent {
    /// The first [`JS_EVENT_SIZE`] bytes of `bytes` as a `js_event` (little-endian).
    pub fn parse(bytes: &[u8]) -> Result<Self, ShortEvent> {
        let short = || ShortEvent {
            format: "js_event",
            needed: JS_EVENT_SIZE,
            got: bytes.len(),
        };
        let b: &[u8; JS_EVENT_SIZE] = bytes
            .get(..JS_EVENT_SIZE)
            .and_then(|b| b.try_into().ok())
            .ok_or_else(short)?;
        Ok(Self {
            time_ms: u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            value: i16::from_le_bytes([b[4], b[5]]),
            kind: b[6],
            number: b[7],
        })
    }

    /// These events' bytes (the inverse of [`JsEvent::parse`]).
    pub fn to_bytes(&self) -> [u8; JS_EVENT_SIZE] {
        let t = self.time_ms.to_le_bytes();
        let v = self.value.to_le_bytes();
        [t[0], t[1], t[2], t[3], v[0], v[1], self.kind, self.number]
    }

    /// Whether this is part of the state reported on open.
    pub fn is_init(&self) -> bool {
        self.kind & JS_EVENT_INIT != 0
    }

    /// What it says, as a [`StickEvent`] (`None` for types other than button and axis). An
    /// INIT event gives the state like a change would.
    pub fn stick_event(&self) -> Option<StickEvent> {
        match self.kind & !JS_EVENT_INIT {
            JS_EVENT_BUTTON => Some(StickEvent::Button {
                number: self.number,
                pressed: self.value != 0,
            }),
            JS_EVENT_AXIS => Some(StickEvent::Axis {
                number: self.number,
                value: (f64::from(self.value) / 32767.0).clamp(-1.0, 1.0),
            }),
            _ => None,
        }
    }
}

/// All whole `js_event`s in `bytes`, in order; an error for trailing bytes that do not make
/// one.
pub fn parse_js_events(bytes: &[u8]) -> Result<Vec<JsEvent>, ShortEvent> {
    let chunks = bytes.chunks(JS_EVENT_SIZE);
    chunks.map(JsEvent::parse).collect()
}

/// evdev event type: a key or button.
pub const EV_KEY: u16 = 0x01;
/// evdev event type: an absolute axis.
pub const EV_ABS: u16 = 0x03;
/// evdev code of the first gamepad button (`BTN_SOUTH`, `BTN_A`).
pub const BTN_SOUTH: u16 = 0x130;
/// evdev code of the first joystick button (`BTN_TRIGGER`).
pub const BTN_TRIGGER: u16 = 0x120;
/// The evdev axis codes reported, `ABS_X` (0) ..= this (`ABS_BRAKE`), as axis numbers 0..=10.
const ABS_LAST: u16 = 0x0a;

/// One evdev `input_event` (64-bit layout).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EvdevEvent {
    /// Seconds of the time stamp.
    pub sec: i64,
    /// Microseconds of the time stamp.
    pub usec: i64,
    /// The event type ([`EV_KEY`], [`EV_ABS`], ...).
    pub kind: u16,
    /// The code within the type.
    pub code: u16,
    /// The value: 1 pressed, 0 released, 2 auto-repeat for keys; the position for axes.
    pub value: i32,
}

impl EvdevEvent {
    /// The first [`EVDEV_EVENT_SIZE`] bytes of `bytes` as an `input_event` (little-endian).
    pub fn parse(bytes: &[u8]) -> Result<Self, ShortEvent> {
        let short = || ShortEvent {
            format: "input_event",
            needed: EVDEV_EVENT_SIZE,
            got: bytes.len(),
        };
        let b = bytes.get(..EVDEV_EVENT_SIZE).ok_or_else(short)?;
        let i64_at = |i: usize| {
            let mut w = [0u8; 8];
            w.copy_from_slice(&b[i..i + 8]);
            i64::from_le_bytes(w)
        };
        Ok(Self {
            sec: i64_at(0),
            usec: i64_at(8),
            kind: u16::from_le_bytes([b[16], b[17]]),
            code: u16::from_le_bytes([b[18], b[19]]),
            value: i32::from_le_bytes([b[20], b[21], b[22], b[23]]),
        })
    }

    /// This event's bytes (the inverse of [`EvdevEvent::parse`]).
    pub fn to_bytes(&self) -> [u8; EVDEV_EVENT_SIZE] {
        let mut b = [0u8; EVDEV_EVENT_SIZE];
        b[0..8].copy_from_slice(&self.sec.to_le_bytes());
        b[8..16].copy_from_slice(&self.usec.to_le_bytes());
        b[16..18].copy_from_slice(&self.kind.to_le_bytes());
        b[18..20].copy_from_slice(&self.code.to_le_bytes());
        b[20..24].copy_from_slice(&self.value.to_le_bytes());
        b
    }
}

/// The button number an evdev button code is reported as (see the module doc).
pub fn evdev_button_number(code: u16) -> Option<u8> {
    let number = match code {
        0x130..=0x13f => code - BTN_SOUTH,
        0x120..=0x12f => code - BTN_TRIGGER,
        _ => return None,
    };
    u8::try_from(number).ok()
}

/// Turns evdev events into [`StickEvent`]s, remembering which axes turned out to have a
/// range other than the assumed signed 16-bit one.
#[derive(Debug, Clone, Default)]
pub struct EvdevMapper {
    /// Per axis number, whether it reported a value outside -32768..=32767.
    foreign_range: [bool; ABS_LAST as usize + 1],
}

impl EvdevMapper {
    /// What `event` says, if it is about a button or an axis that is reported.
    pub fn map(&mut self, event: &EvdevEvent) -> Option<StickEvent> {
        match event.kind {
            EV_KEY => Some(StickEvent::Button {
                number: evdev_button_number(event.code)?,
                pressed: event.value != 0,
            }),
            EV_ABS if event.code <= ABS_LAST => {
                let number = u8::try_from(event.code).ok()?;
                let foreign = self.foreign_range.get_mut(usize::from(number))?;
                if i16::try_from(event.value).is_err() {
                    *foreign = true;
                }
                let value = if *foreign {
                    0.0
                } else {
                    (f64::from(event.value) / 32767.0).clamp(-1.0, 1.0)
                };
                Some(StickEvent::Axis { number, value })
            }
            _ => None,
        }
    }
}

/// Which device to read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Device {
    /// This path: `/dev/input/js*` is read as `js_event`s, anything else as evdev.
    Path(std::path::PathBuf),
    /// The first `/dev/input/js*` that opens.
    Auto,
}

/// The highest button number an evdev device is assumed to have released on open.
const EVDEV_BUTTONS: u8 = 16;

/// How long the reader waits between attempts to open the device.
pub const RETRY_INTERVAL: Duration = Duration::from_millis(500);

/// How a device's bytes are read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// `js_event`s (`/dev/input/js*`).
    Js,
    /// evdev `input_event`s (anything else).
    Evdev,
}

/// The format of the device at `path`: [`Format::Js`] when its file name starts with `js`.
pub fn format_of(path: &Path) -> Format {
    let js = path
        .file_name()
        .and_then(|name| name.to_str())
        .is_some_and(|name| name.starts_with("js"));
    if js {
        Format::Js
    } else {
        Format::Evdev
    }
}

/// The `js*` devices in `dir`, by number (`js0` first).
pub fn js_devices(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut found: Vec<(u32, PathBuf)> = entries
        .filter_map(Result::ok)
        .filter_map(|entry| {
            let name = entry.file_name();
            let number = name.to_str()?.strip_prefix("js")?.parse().ok()?;
            Some((number, entry.path()))
        })
        .collect();
    found.sort();
    found.into_iter().map(|(_, path)| path).collect()
}

fn open(device: &Device) -> Option<(std::fs::File, Format)> {
    match device {
        Device::Path(path) => std::fs::File::open(path)
            .ok()
            .map(|file| (file, format_of(path))),
        Device::Auto => js_devices(Path::new("/dev/input"))
            .iter()
            .find_map(|path| std::fs::File::open(path).ok())
            .map(|file| (file, Format::Js)),
    }
}

/// Sends the events read from `file` until it fails or ends; `false` when the receiver is
/// gone.
fn pump(file: std::fs::File, format: Format, events: &SyncSender<StickEvent>) -> bool {
    let mut reader = std::io::BufReader::new(file);
    match format {
        Format::Js => {
            let mut buf = [0u8; JS_EVENT_SIZE];
            while reader.read_exact(&mut buf).is_ok() {
                let Ok(event) = JsEvent::parse(&buf) else {
                    return true;
                };
                if let Some(event) = event.stick_event() {
                    if events.send(event).is_err() {
                        return false;
                    }
                }
            }
        }
        Format::Evdev => {
            // Without an ioctl the button state cannot be read: take all as released. A
            // button held now reports nothing until it is released and pressed again.
            for number in 0..EVDEV_BUTTONS {
                let released = StickEvent::Button {
                    number,
                    pressed: false,
                };
                if events.send(released).is_err() {
                    return false;
                }
            }
            let mut mapper = EvdevMapper::default();
            let mut buf = [0u8; EVDEV_EVENT_SIZE];
            while reader.read_exact(&mut buf).is_ok() {
                let Ok(event) = EvdevEvent::parse(&buf) else {
                    return true;
                };
                if let Some(event) = mapper.map(&event) {
                    if events.send(event).is_err() {
                        return false;
                    }
                }
            }
        }
    }
    true
}

/// Reads `device` on a thread of its own and sends what happens to `events` (bounded); opens
/// it again after it goes away. The thread ends when the receiver is dropped.
///
/// On each open: [`StickEvent::Connected`], then the state (the js interface's INIT events;
/// for evdev, every button released), then the changes. On a read error or end of file:
/// [`StickEvent::Disconnected`], then an attempt to open every [`RETRY_INTERVAL`], each
/// failed one reported by another `Disconnected` (which is also how a dropped receiver is
/// noticed while the device is away). A device that is open but silent is not left until it
/// sends something.
pub fn spawn(
    device: Device,
    events: std::sync::mpsc::SyncSender<StickEvent>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("snakectl-joystick".into())
        .spawn(move || loop {
            if let Some((file, format)) = open(&device) {
                if events.send(StickEvent::Connected).is_err() || !pump(file, format, &events) {
                    return;
                }
            }
            if events.send(StickEvent::Disconnected).is_err() {
                return;
            }
            std::thread::sleep(RETRY_INTERVAL);
        })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    const ZERO: Action = Action::Velocity([0.0, 0.0]);
    const SPEED: f64 = 0.1;
    const DEADMAN: u8 = 4;

    fn feed(stick: &mut Stick, events: &[StickEvent], now: f64, in_control: bool) -> Vec<Action> {
        let mut out = Vec::new();
        for event in events {
            stick.event(*event, now, SPEED, in_control, &mut out);
        }
        out
    }

    fn deadman(pressed: bool) -> StickEvent {
        StickEvent::Button {
            number: DEADMAN,
            pressed,
        }
    }

    fn axis(number: u8, value: f64) -> StickEvent {
        StickEvent::Axis { number, value }
    }

    /// A stick freshly connected with the deadman reported released.
    fn connected() -> Stick {
        let mut stick = Stick::new(DEADMAN);
        assert!(feed(
            &mut stick,
            &[StickEvent::Connected, deadman(false)],
            0.0,
            true
        )
        .is_empty());
        stick
    }

    fn velocity(action: Action) -> [f64; 2] {
        match action {
            Action::Velocity(v) => v,
            other => panic!("not a velocity: {other:?}"),
        }
    }

    #[test]
    fn stick_up_moves_the_tip_up_and_right_moves_it_right() {
        let mut stick = connected();
        let out = feed(&mut stick, &[deadman(true), axis(1, -1.0)], 0.0, true);
        assert_eq!(out, [Action::Velocity([0.0, SPEED])]);
        let out = feed(&mut stick, &[axis(1, 0.0), axis(0, 1.0)], 0.1, true);
        // Back through the dead zone on the way: one zero, then right.
        assert_eq!(out, [ZERO, Action::Velocity([SPEED, 0.0])]);
    }

    #[test]
    fn the_dead_zone_gives_nothing_and_speed_rises_smoothly_from_its_edge() {
        assert_eq!(stick_deflection([0.03, -0.03]), [0.0, 0.0]);
        assert_eq!(stick_deflection([DEAD_ZONE, 0.0]), [0.0, 0.0]);
        let just_out = stick_deflection([DEAD_ZONE + 0.001, 0.0]);
        assert!(just_out[0] > 0.0 && just_out[0] < 0.002, "{just_out:?}");
        let half = stick_deflection([0.0, -0.525]);
        assert!((half[1] - 0.5).abs() < 1e-12, "{half:?}");
        // Beyond full deflection (a diagonal on a square gate): full speed, not more.
        let corner = stick_deflection([1.0, -1.0]);
        let size = (corner[0] * corner[0] + corner[1] * corner[1]).sqrt();
        assert!((size - 1.0).abs() < 1e-12 && corner[0] > 0.0 && corner[1] > 0.0);

        let mut stick = connected();
        let out = feed(
            &mut stick,
            &[deadman(true), axis(0, 0.04), axis(1, 0.02)],
            0.0,
            true,
        );
        assert!(out.is_empty(), "{out:?}");
        assert_eq!(stick.next_deadline(), None);
    }

    #[test]
    fn nothing_moves_without_the_deadman() {
        let mut stick = connected();
        assert!(feed(&mut stick, &[axis(0, 1.0), axis(1, -1.0)], 0.0, true).is_empty());
        let mut out = Vec::new();
        stick.tick(1.0, SPEED, true, &mut out);
        assert!(out.is_empty());
        // Another button is not the deadman.
        let other = StickEvent::Button {
            number: 0,
            pressed: true,
        };
        assert!(feed(&mut stick, &[other], 1.0, true).is_empty());
        // The deadman with the stick already out: motion at once.
        assert_eq!(feed(&mut stick, &[deadman(true)], 1.1, true).len(), 1);
    }

    #[test]
    fn exactly_one_zero_when_the_deadman_is_released_or_the_stick_centres() {
        let mut stick = connected();
        feed(&mut stick, &[deadman(true), axis(0, 0.5)], 0.0, true);
        let out = feed(
            &mut stick,
            &[deadman(false), axis(0, 0.7), axis(0, 0.0)],
            0.1,
            true,
        );
        assert_eq!(out, [ZERO]);
        let mut out = Vec::new();
        stick.tick(1.0, SPEED, true, &mut out);
        assert!(out.is_empty());

        feed(&mut stick, &[deadman(true), axis(0, 0.5)], 2.0, true);
        let out = feed(&mut stick, &[axis(0, 0.02), axis(0, 0.0)], 2.1, true);
        assert_eq!(out, [ZERO]);
    }

    #[test]
    fn disconnect_sends_one_zero_and_a_reconnect_needs_a_fresh_press() {
        let mut stick = connected();
        feed(&mut stick, &[deadman(true), axis(1, -0.8)], 0.0, true);
        let out = feed(
            &mut stick,
            &[StickEvent::Disconnected, StickEvent::Disconnected],
            0.1,
            true,
        );
        assert_eq!(out, [ZERO]);
        let out = feed(
            &mut stick,
            &[StickEvent::Connected, deadman(true), axis(1, -0.8)],
            1.0,
            true,
        );
        assert!(out.is_empty(), "{out:?}");
    }

    #[test]
    fn a_deadman_already_held_at_connect_does_not_move_until_pressed_again() {
        let mut stick = Stick::new(DEADMAN);
        let init = [
            StickEvent::Connected,
            deadman(true),
            axis(0, 0.0),
            axis(1, -1.0),
        ];
        assert!(feed(&mut stick, &init, 0.0, true).is_empty());
        assert!(feed(&mut stick, &[axis(1, -0.9), axis(0, 0.3)], 0.5, true).is_empty());
        assert!(feed(&mut stick, &[deadman(false)], 1.0, true).is_empty());
        let out = feed(&mut stick, &[deadman(true)], 1.5, true);
        assert_eq!(out.len(), 1);
        let v = velocity(out[0]);
        assert!(v[0] > 0.0 && v[1] > 0.0, "{v:?}");
    }

    #[test]
    fn renewals_at_20_hz_while_held_with_the_speed_of_the_moment() {
        let mut stick = connected();
        let mut out = feed(&mut stick, &[deadman(true), axis(0, -1.0)], 10.0, true);
        for i in 1..=1000 {
            stick.tick(10.0 + f64::from(i) / 1000.0, SPEED, true, &mut out);
        }
        assert_eq!(out.len(), 21, "one at once, then 20 in 1 s");
        assert!(out.iter().all(|a| *a == Action::Velocity([-SPEED, 0.0])));
        let mut out = Vec::new();
        stick.tick(11.05, 2.0 * SPEED, true, &mut out);
        assert_eq!(out, [Action::Velocity([-2.0 * SPEED, 0.0])]);
        let next = stick.next_deadline().unwrap();
        assert!(next > 11.05 && next <= 11.1 + 1e-9, "{next}");
    }

    #[test]
    fn a_halt_sends_the_one_zero_and_the_deadman_needs_a_fresh_press() {
        let mut stick = connected();
        feed(&mut stick, &[deadman(true), axis(0, 1.0)], 0.0, true);
        let mut out = Vec::new();
        stick.halt(true, &mut out);
        assert_eq!(out, [ZERO]);
        stick.halt(true, &mut out);
        stick.tick(1.0, SPEED, true, &mut out);
        assert_eq!(
            out,
            [ZERO],
            "one zero, then nothing while the deadman stays down"
        );
        assert_eq!(stick.next_deadline(), None);
        assert!(feed(&mut stick, &[axis(0, 0.9)], 1.1, true).is_empty());
        assert!(feed(&mut stick, &[deadman(false)], 1.2, true).is_empty());
        assert_eq!(feed(&mut stick, &[deadman(true)], 1.3, true).len(), 1);
        // Without control there is no zero to send.
        let mut out = Vec::new();
        stick.halt(false, &mut out);
        assert!(out.is_empty());
    }

    #[test]
    fn without_control_nothing_goes_out_not_even_a_zero() {
        let mut stick = connected();
        assert!(feed(&mut stick, &[deadman(true), axis(0, 1.0)], 0.0, false).is_empty());
        let mut out = Vec::new();
        stick.tick(1.0, SPEED, false, &mut out);
        assert!(out.is_empty());
        // Control lost during a motion: the renewals stop, no zero.
        assert_eq!(feed(&mut stick, &[axis(0, 0.9)], 2.0, true).len(), 1);
        stick.tick(2.1, SPEED, false, &mut out);
        assert!(out.is_empty());
        assert!(feed(&mut stick, &[deadman(false)], 2.2, false).is_empty());
    }

    #[test]
    fn js_events_parse_little_endian_and_map_init_as_state() {
        let bytes = [0x10, 0x27, 0, 0, 0x01, 0x80, 0x82, 1];
        let event = JsEvent::parse(&bytes).unwrap();
        assert_eq!(
            event,
            JsEvent {
                time_ms: 10_000,
                value: -32767,
                kind: 0x82,
                number: 1
            }
        );
        assert!(event.is_init());
        assert_eq!(event.stick_event(), Some(axis(1, -1.0)));
        assert_eq!(event.to_bytes(), bytes);
        let press = JsEvent::parse(&[0, 0, 0, 0, 1, 0, 0x01, 4]).unwrap();
        assert_eq!(press.stick_event(), Some(deadman(true)));
        assert!(!press.is_init());
        assert_eq!(
            JsEvent::parse(&[0, 0, 0, 0, 0, 0, 0x03, 0])
                .unwrap()
                .stick_event(),
            None
        );
    }

    #[test]
    fn short_input_is_a_typed_error_with_the_sizes() {
        let err = JsEvent::parse(&[1, 2, 3]).unwrap_err();
        assert_eq!((err.needed, err.got), (8, 3));
        assert_eq!(err.to_string(), "a js_event is 8 bytes, got 3");
        let err = parse_js_events(&[0; 20]).unwrap_err();
        assert_eq!((err.needed, err.got), (8, 4));
        assert_eq!(parse_js_events(&[0; 16]).unwrap().len(), 2);
        let err = EvdevEvent::parse(&[0; 23]).unwrap_err();
        assert_eq!((err.format, err.needed, err.got), ("input_event", 24, 23));
    }

    #[test]
    fn evdev_events_parse_and_map_buttons_and_axes() {
        let event = EvdevEvent {
            sec: 1_700_000_000,
            usec: 250_000,
            kind: EV_ABS,
            code: 1,
            value: 16384,
        };
        let bytes = event.to_bytes();
        assert_eq!(&bytes[16..], &[3, 0, 1, 0, 0, 0x40, 0, 0]);
        assert_eq!(EvdevEvent::parse(&bytes).unwrap(), event);
        let mut mapper = EvdevMapper::default();
        let Some(StickEvent::Axis { number: 1, value }) = mapper.map(&event) else {
            panic!()
        };
        assert!((value - 16384.0 / 32767.0).abs() < 1e-12);
        let key = |code, value| EvdevEvent {
            sec: 0,
            usec: 0,
            kind: EV_KEY,
            code,
            value,
        };
        // BTN_TL (0x136) is button 6; auto-repeat (2) still reads as held.
        assert_eq!(
            mapper.map(&key(0x136, 1)),
            Some(StickEvent::Button {
                number: 6,
                pressed: true
            })
        );
        assert_eq!(
            mapper.map(&key(0x136, 2)),
            Some(StickEvent::Button {
                number: 6,
                pressed: true
            })
        );
        assert_eq!(
            mapper.map(&key(BTN_SOUTH, 0)),
            Some(StickEvent::Button {
                number: 0,
                pressed: false
            })
        );
        assert_eq!(
            mapper.map(&key(0x1e, 1)),
            None,
            "a keyboard key is not a button"
        );
        let syn = EvdevEvent {
            kind: 0,
            code: 0,
            value: 0,
            ..event
        };
        assert_eq!(mapper.map(&syn), None);
    }

    #[test]
    fn an_evdev_axis_with_another_range_reads_zero() {
        let mut mapper = EvdevMapper::default();
        let abs = |value| EvdevEvent {
            sec: 0,
            usec: 0,
            kind: EV_ABS,
            code: 0,
            value,
        };
        assert_eq!(mapper.map(&abs(32767)), Some(axis(0, 1.0)));
        assert_eq!(mapper.map(&abs(40000)), Some(axis(0, 0.0)));
        assert_eq!(mapper.map(&abs(30000)), Some(axis(0, 0.0)), "stays off");
        let other = EvdevEvent {
            code: 1,
            ..abs(-32768)
        };
        assert_eq!(mapper.map(&other), Some(axis(1, -1.0)));
    }

    #[test]
    fn device_formats_and_js_device_order() {
        assert_eq!(format_of(Path::new("/dev/input/js0")), Format::Js);
        assert_eq!(format_of(Path::new("/dev/input/event7")), Format::Evdev);
        let dir = tempfile::tempdir().unwrap();
        for name in ["js10", "js2", "event0", "jsx", "mouse0"] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        let found = js_devices(dir.path());
        assert_eq!(found, [dir.path().join("js2"), dir.path().join("js10")]);
        assert!(js_devices(&dir.path().join("missing")).is_empty());
    }
}
