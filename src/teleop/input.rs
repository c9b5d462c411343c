//! What the operator's keys and stick ask of the daemon: pure, events and time (seconds, from
//! any origin) in, [`Action`]s out.

/// A key, as the terminal reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Key {
    /// Arrow up (or `w`).
    Up,
    /// Arrow down (or `s`).
    Down,
    /// Arrow left (or `a`).
    Left,
    /// Arrow right (or `d`).
    Right,
    /// Space bar.
    Space,
    /// Tab.
    Tab,
    /// A character key.
    Char(char),
    /// Any other key.
    Other,
}

/// How the terminal reported a key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeyKind {
    /// Pressed (or, without release reporting, pressed or repeated: they look the same).
    Press,
    /// Auto-repeated while held (kitty keyboard protocol only).
    Repeat,
    /// Released (kitty keyboard protocol only).
    Release,
}

/// What the UI should do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// Send `velocity` with this tip velocity, m/s (a zero ends a motion).
    Velocity([f64; 2]),
    /// Send `stop`.
    Stop,
    /// Send `estop`.
    Estop,
    /// Send `reset`.
    Reset,
    /// Send `home`.
    Home,
    /// Send `strategy` with the next of the arm's strategies.
    NextStrategy,
    /// Send `torque` with the opposite of the present state.
    ToggleTorque,
    /// Send `take_control`.
    TakeControl,
    /// Quit the UI.
    Quit,
}

/// The speed the arrows move the tip at when the UI starts, m/s.
pub const DEFAULT_SPEED_M_S: f64 = 0.05;

/// Without release reports, a first press counts as held this long, s: longer than the usual
/// 500-660 ms delay before a terminal's auto-repeat starts.
pub const HOLD_FIRST_S: f64 = 0.6;

/// Without release reports, a hold lasts this long after the last repeat, s.
pub const HOLD_AFTER_REPEAT_S: f64 = 0.15;

/// How often a held velocity is renewed, Hz (well inside the daemon's deadman).
pub const RENEW_HZ: f64 = 20.0;

/// The keyboard's hold-to-move state.
#[derive(Debug, Clone)]
pub struct Keyboard {
    speed_m_s: f64,
}

impl Keyboard {
    /// At `speed_m_s`, without release reports.
    pub fn new(speed_m_s: f64) -> Self {
        Self { speed_m_s }
    }

    /// The speed the arrows move the tip at, m/s.
    pub fn speed_m_s(&self) -> f64 {
        self.speed_m_s
    }

    /// Whether the terminal reports releases (kitty keyboard protocol): holds then end on
    /// the release instead of by timing.
    pub fn set_releases_reported(&mut self, _reported: bool) {}

    /// A key event at `now_s`; `in_control`: whether this client may command the arm.
    pub fn key(
        &mut self,
        _key: Key,
        _kind: KeyKind,
        _now_s: f64,
        _in_control: bool,
        _out: &mut Vec<Action>,
    ) {
    }

    /// Time passing: the renewals while a key is held, the one zero velocity when its hold
    /// ends.
    pub fn tick(&mut self, _now_s: f64, _in_control: bool, _out: &mut Vec<Action>) {}

    /// The tip velocity being held, m/s (`None` when no key is held).
    pub fn held_velocity(&self) -> Option<[f64; 2]> {
        None
    }

    /// When [`Keyboard::tick`] next has something to do, s (for the UI's poll timeout).
    pub fn next_deadline(&self) -> Option<f64> {
        None
    }
}
