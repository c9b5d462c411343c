//! The joystick: Linux joystick (`/dev/input/js*`, 8-byte `js_event`) and evdev
//! (`/dev/input/event*`) devices read without libudev.

use super::input::Action;

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

/// The stick's state: the left stick gives the tip velocity while the deadman button is held.
#[derive(Debug, Clone)]
pub struct Stick {
    deadman_button: u8,
}

impl Stick {
    /// With `deadman_button` as the button that must be held.
    pub fn new(deadman_button: u8) -> Self {
        Self { deadman_button }
    }

    /// The deadman button's number.
    pub fn deadman_button(&self) -> u8 {
        self.deadman_button
    }

    /// A device event at `now_s`; the stick's full deflection is `speed_m_s`.
    pub fn event(
        &mut self,
        _event: StickEvent,
        _now_s: f64,
        _speed_m_s: f64,
        _in_control: bool,
        _out: &mut Vec<Action>,
    ) {
    }

    /// Time passing: renewals while the deadman is held and the stick is out of its dead zone.
    pub fn tick(
        &mut self,
        _now_s: f64,
        _speed_m_s: f64,
        _in_control: bool,
        _out: &mut Vec<Action>,
    ) {
    }

    /// When [`Stick::tick`] next has something to do, s.
    pub fn next_deadline(&self) -> Option<f64> {
        None
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

/// Reads `device` on a thread of its own and sends what happens to `events` (bounded); opens
/// it again after it goes away. The thread ends when the receiver is dropped.
pub fn spawn(
    device: Device,
    events: std::sync::mpsc::SyncSender<StickEvent>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("snakectl-joystick".into())
        .spawn(move || {
            let _ = (device, events);
        })
}
