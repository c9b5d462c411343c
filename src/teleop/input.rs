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
    /// Escape.
    Esc,
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

/// With release reports, a hold that hears nothing of its keys (no repeat, no release) for
/// this long ends all the same, s, so a lost release (the terminal lost focus, say) cannot leave
/// the tip moving. A held key repeats every 30-50 ms once the repeat delay (usually 500-660 ms)
/// has passed.
pub const RELEASE_GUARD_S: f64 = 1.5;

/// How often a held velocity is renewed, Hz (well inside the daemon's deadman).
pub const RENEW_HZ: f64 = 20.0;

/// The slowest speed `-` steps down to, m/s.
pub const MIN_SPEED_M_S: f64 = 0.005;

/// The fastest speed `+` steps up to, m/s.
pub const MAX_SPEED_M_S: f64 = 0.5;

/// The factor one `+` multiplies the speed by (and one `-` divides it by).
pub const SPEED_STEP: f64 = 1.25;

/// The pieces of an arrow key's escape sequence (ESC `[` or `O`, then the letter) that come in
/// separate reads (over a slow link) are taken together when each follows the one before within
/// this long, s. The terminal library reports such pieces as Esc, `[` and a capital letter, and
/// the letter alone would mean something else: `D` (left) would move the tip right.
pub const ESCAPE_JOIN_S: f64 = 0.25;

/// The four motion directions, as indices into [`Hold::held`].
const UP: usize = 0;
const DOWN: usize = 1;
const LEFT: usize = 2;
const RIGHT: usize = 3;

/// What a key means, before `in_control` and the hold are considered.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Meaning {
    Move(usize),
    Faster,
    Slower,
    Command(Action),
}

fn meaning(key: Key) -> Meaning {
    match key {
        Key::Up => Meaning::Move(UP),
        Key::Down => Meaning::Move(DOWN),
        Key::Left => Meaning::Move(LEFT),
        Key::Right => Meaning::Move(RIGHT),
        Key::Space => Meaning::Command(Action::Stop),
        Key::Tab => Meaning::Command(Action::NextStrategy),
        Key::Char(c) => match c.to_ascii_lowercase() {
            'w' => Meaning::Move(UP),
            's' => Meaning::Move(DOWN),
            'a' => Meaning::Move(LEFT),
            'd' => Meaning::Move(RIGHT),
            '+' | '=' => Meaning::Faster,
            '-' => Meaning::Slower,
            ' ' => Meaning::Command(Action::Stop),
            'e' => Meaning::Command(Action::Estop),
            'r' => Meaning::Command(Action::Reset),
            'h' => Meaning::Command(Action::Home),
            't' => Meaning::Command(Action::ToggleTorque),
            'c' => Meaning::Command(Action::TakeControl),
            'q' => Meaning::Command(Action::Quit),
            _ => Meaning::Command(Action::Stop),
        },
        Key::Esc | Key::Other => Meaning::Command(Action::Stop),
    }
}

/// Where a split escape sequence stands (see [`ESCAPE_JOIN_S`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Escape {
    /// No sequence under way.
    None,
    /// Esc came at this time, s.
    Esc(f64),
    /// Esc and `[` (or `O`) came, the last piece at this time, s.
    Intro(f64),
}

/// Whether `action` goes out without control of the arm.
fn allowed_without_control(action: Action) -> bool {
    matches!(
        action,
        Action::Stop | Action::Estop | Action::TakeControl | Action::Quit
    )
}

/// Whether the daemon ends a running `velocity` on `action`'s command by itself: `stop`,
/// `estop`, `home` (which replaces it) and `torque` (on only while it is off, when nothing
/// moves). Any other (`strategy`, `take_control`, a `reset` without a latch, quitting) leaves it
/// running to its deadman.
fn halts_a_velocity(action: Action) -> bool {
    matches!(
        action,
        Action::Stop | Action::Estop | Action::Home | Action::ToggleTorque
    )
}

/// One hold: the motion keys held, when it ends, when it is renewed.
#[derive(Debug, Clone)]
struct Hold {
    /// Per direction, the order in which it was pressed (`None`: not held). Without release
    /// reports exactly one is held.
    held: [Option<u64>; 4],
    /// When the first press of this hold came, s.
    first_s: f64,
    /// When the hold ends unless a key event extends it, s: by timing without release
    /// reports, by [`RELEASE_GUARD_S`] with them.
    end_s: Option<f64>,
    /// When the velocity last went out at once; renewals count from here, s.
    base_s: f64,
    /// The number of the next renewal after `base_s`.
    renewal: u32,
    /// Whether the velocity goes out (false once control is lost or when it began without).
    live: bool,
}

impl Hold {
    fn next_renewal_s(&self) -> f64 {
        self.base_s + f64::from(self.renewal) / RENEW_HZ
    }

    /// The unit direction the held keys give: on each axis the later pressed of the two
    /// opposite keys wins; a diagonal is scaled to unit length.
    fn direction(&self) -> [f64; 2] {
        let axis = |neg: usize, pos: usize| -> f64 {
            match (self.held[neg], self.held[pos]) {
                (None, None) => 0.0,
                (Some(_), None) => -1.0,
                (None, Some(_)) => 1.0,
                (Some(n), Some(p)) => {
                    if p > n {
                        1.0
                    } else {
                        -1.0
                    }
                }
            }
        };
        let x = axis(LEFT, RIGHT);
        let y = axis(DOWN, UP);
        let norm = (x * x + y * y).sqrt();
        if norm > 0.0 {
            [x / norm, y / norm]
        } else {
            [0.0, 0.0]
        }
    }

    fn is_empty(&self) -> bool {
        self.held.iter().all(Option::is_none)
    }
}

/// The keyboard's hold-to-move state.
///
/// Arrows and `w`/`a`/`s`/`d` move the tip in the world frame (right +x, up +y). Without
/// release reports a hold lasts [`HOLD_FIRST_S`] from its first press and
/// [`HOLD_AFTER_REPEAT_S`] past its last repeat, whichever is later; with them, until the
/// release (or [`RELEASE_GUARD_S`] without a word of its keys). With release reports two held keys combine: on each axis the later pressed of two
/// opposite keys wins, and a diagonal goes at the same speed as a straight move. Letters are
/// taken in either case. A hold that starts without control, or loses it, stays silent to its
/// end even if control comes back: motion starts only from a press made in control.
#[derive(Debug, Clone)]
pub struct Keyboard {
    speed_m_s: f64,
    releases_reported: bool,
    hold: Option<Hold>,
    /// A hold was ended outside `key`/`tick` (mode change): its zero goes out at the next tick.
    pending_zero: bool,
    /// The latest time seen, s.
    last_now_s: f64,
    /// Counts motion-key presses, to order them.
    presses: u64,
    /// A split escape sequence under way.
    escape: Escape,
}

impl Keyboard {
    /// At `speed_m_s`, without release reports.
    pub fn new(speed_m_s: f64) -> Self {
        Self {
            speed_m_s: clamp_speed(speed_m_s),
            releases_reported: false,
            hold: None,
            pending_zero: false,
            last_now_s: f64::NEG_INFINITY,
            presses: 0,
            escape: Escape::None,
        }
    }

    /// The speed the arrows move the tip at, m/s.
    pub fn speed_m_s(&self) -> f64 {
        self.speed_m_s
    }

    /// Whether the terminal reports releases (kitty keyboard protocol): holds then end on
    /// the release instead of by timing.
    pub fn set_releases_reported(&mut self, reported: bool) {
        if reported == self.releases_reported {
            return;
        }
        self.releases_reported = reported;
        if let Some(hold) = self.hold.take() {
            // A motion under the other rules: end it, its zero at the next tick.
            self.pending_zero |= hold.live;
        }
    }

    /// A key event at `now_s`; `in_control`: whether this client may command the arm.
    pub fn key(
        &mut self,
        key: Key,
        kind: KeyKind,
        now_s: f64,
        in_control: bool,
        out: &mut Vec<Action>,
    ) {
        // A hold whose time is up ends before this key counts; renewals wait for `tick`.
        self.expire(now_s, in_control, out);
        let Some(key) = self.rejoin(key, kind, now_s) else {
            return;
        };
        match meaning(key) {
            Meaning::Move(dir) => {
                if self.releases_reported {
                    self.move_with_releases(dir, kind, now_s, in_control, out);
                } else {
                    self.move_by_timing(dir, kind, now_s, in_control, out);
                }
            }
            Meaning::Faster | Meaning::Slower if kind != KeyKind::Release => {
                let factor = if meaning(key) == Meaning::Faster {
                    SPEED_STEP
                } else {
                    1.0 / SPEED_STEP
                };
                self.speed_m_s = clamp_speed(self.speed_m_s * factor);
            }
            Meaning::Faster | Meaning::Slower => {}
            Meaning::Command(action) => {
                let acts = match kind {
                    KeyKind::Press => true,
                    // A repeat looks like a press without release reports.
                    KeyKind::Repeat => !self.releases_reported,
                    KeyKind::Release => false,
                };
                if !acts {
                    return;
                }
                if let Some(hold) = self.hold.take() {
                    if !halts_a_velocity(action) && hold.live && in_control {
                        out.push(Action::Velocity([0.0, 0.0]));
                    }
                }
                if in_control || allowed_without_control(action) {
                    out.push(action);
                }
            }
        }
    }

    /// `key` as part of a split escape sequence: the arrow its letter ends, `None` for a piece
    /// to swallow (`[`, `O`, parameters), [`Key::Other`] for a sequence of another key (Home
    /// is ESC `[` `H`, which alone would send the arm home), else `key` itself.
    fn rejoin(&mut self, key: Key, kind: KeyKind, now_s: f64) -> Option<Key> {
        if kind == KeyKind::Release {
            return Some(key);
        }
        let within = |t: f64| now_s - t <= ESCAPE_JOIN_S;
        match (std::mem::replace(&mut self.escape, Escape::None), key) {
            (_, Key::Esc) => {
                self.escape = Escape::Esc(now_s);
                Some(key)
            }
            (Escape::Esc(t), Key::Char('[' | 'O')) if within(t) => {
                self.escape = Escape::Intro(now_s);
                None
            }
            (Escape::Intro(t), Key::Char(c)) if within(t) => match c {
                '0'..='9' | ';' => {
                    self.escape = Escape::Intro(now_s);
                    None
                }
                'A' => Some(Key::Up),
                'B' => Some(Key::Down),
                'C' => Some(Key::Right),
                'D' => Some(Key::Left),
                _ => Some(Key::Other),
            },
            _ => Some(key),
        }
    }

    /// Time passing: the renewals while a key is held, the one zero velocity when its hold
    /// ends.
    pub fn tick(&mut self, now_s: f64, in_control: bool, out: &mut Vec<Action>) {
        self.expire(now_s, in_control, out);
        let Some(hold) = self.hold.as_mut() else {
            return;
        };
        if hold.live && now_s >= hold.next_renewal_s() {
            // A late tick sends one renewal, not the missed ones: the next is the first
            // renewal time after now.
            let behind = ((now_s - hold.base_s) * RENEW_HZ).floor();
            let mut renewal = if (0.0..1e9).contains(&behind) {
                (behind as u32).max(hold.renewal)
            } else {
                hold.renewal
            };
            while hold.base_s + f64::from(renewal) / RENEW_HZ <= now_s && renewal < u32::MAX {
                renewal += 1;
            }
            hold.renewal = renewal;
            let v = scale(hold.direction(), self.speed_m_s);
            out.push(Action::Velocity(v));
        }
    }

    /// Another command took the arm over (a click's `goto`): a hold going on ends, without its
    /// zero, which would stop that command, and without more renewals, which would replace it.
    pub fn give_way(&mut self) {
        self.hold = None;
        self.pending_zero = false;
    }

    /// The tip velocity being held, m/s (`None` when no key is held, or when the hold does
    /// not command the arm for want of control).
    pub fn held_velocity(&self) -> Option<[f64; 2]> {
        self.hold
            .as_ref()
            .filter(|hold| hold.live)
            .map(|hold| scale(hold.direction(), self.speed_m_s))
    }

    /// When [`Keyboard::tick`] next has something to do, s (for the UI's poll timeout).
    pub fn next_deadline(&self) -> Option<f64> {
        if self.pending_zero {
            return Some(self.last_now_s);
        }
        let hold = self.hold.as_ref()?;
        let renewal = hold
            .live
            .then(|| hold.next_renewal_s())
            .filter(|renewal| hold.end_s.is_none_or(|end| *renewal < end));
        match (renewal, hold.end_s) {
            (Some(r), Some(e)) => Some(r.min(e)),
            (r, e) => r.or(e),
        }
    }

    /// The pending zero, control lost, a hold whose time is up.
    fn expire(&mut self, now_s: f64, in_control: bool, out: &mut Vec<Action>) {
        if now_s > self.last_now_s {
            self.last_now_s = now_s;
        }
        if self.pending_zero {
            self.pending_zero = false;
            if in_control {
                out.push(Action::Velocity([0.0, 0.0]));
            }
        }
        let Some(hold) = self.hold.as_mut() else {
            return;
        };
        if !in_control {
            // Control lost: the renewals stop, and no zero (it is no longer ours to send).
            hold.live = false;
        }
        if hold.end_s.is_some_and(|end| now_s >= end) {
            let live = hold.live;
            self.hold = None;
            if live {
                out.push(Action::Velocity([0.0, 0.0]));
            }
        }
    }

    /// Without release reports: a press or repeat starts or extends a hold, a release (should
    /// one come all the same) ends it.
    fn move_by_timing(
        &mut self,
        dir: usize,
        kind: KeyKind,
        now_s: f64,
        in_control: bool,
        out: &mut Vec<Action>,
    ) {
        let same = self
            .hold
            .as_ref()
            .is_some_and(|hold| hold.held[dir].is_some());
        if kind == KeyKind::Release {
            if same {
                self.end_hold_with_zero(in_control, out);
            }
            return;
        }
        if same {
            if let Some(hold) = self.hold.as_mut() {
                let end = (hold.first_s + HOLD_FIRST_S).max(now_s + HOLD_AFTER_REPEAT_S);
                hold.end_s = Some(end);
            }
            return;
        }
        // A first press, or another direction: a new hold, at once, with no zero between.
        let mut held = [None; 4];
        held[dir] = Some(self.next_press());
        self.start_hold(held, Some(now_s + HOLD_FIRST_S), now_s, in_control, out);
    }

    /// With release reports: a press adds a key to the hold, its release takes it away;
    /// repeats change nothing.
    fn move_with_releases(
        &mut self,
        dir: usize,
        kind: KeyKind,
        now_s: f64,
        in_control: bool,
        out: &mut Vec<Action>,
    ) {
        let guard = Some(now_s + RELEASE_GUARD_S);
        match kind {
            KeyKind::Repeat => {
                if let Some(hold) = self.hold.as_mut().filter(|hold| hold.held[dir].is_some()) {
                    hold.end_s = guard;
                }
            }
            KeyKind::Press => {
                let order = self.next_press();
                match self.hold.as_mut() {
                    None => {
                        let mut held = [None; 4];
                        held[dir] = Some(order);
                        self.start_hold(held, guard, now_s, in_control, out);
                    }
                    Some(hold) if hold.held[dir].is_none() => {
                        let before = hold.direction();
                        hold.held[dir] = Some(order);
                        hold.end_s = guard;
                        self.redirect(before, now_s, out);
                    }
                    Some(hold) => hold.end_s = guard,
                }
            }
            KeyKind::Release => {
                let Some(hold) = self.hold.as_mut() else {
                    return;
                };
                let before = hold.direction();
                if hold.held[dir].take().is_none() {
                    return;
                }
                if hold.is_empty() {
                    self.end_hold_with_zero(in_control, out);
                } else {
                    self.redirect(before, now_s, out);
                }
            }
        }
    }

    fn next_press(&mut self) -> u64 {
        self.presses = self.presses.wrapping_add(1);
        self.presses
    }

    fn start_hold(
        &mut self,
        held: [Option<u64>; 4],
        end_s: Option<f64>,
        now_s: f64,
        in_control: bool,
        out: &mut Vec<Action>,
    ) {
        let hold = Hold {
            held,
            first_s: now_s,
            end_s,
            base_s: now_s,
            renewal: 1,
            live: in_control,
        };
        if hold.live {
            out.push(Action::Velocity(scale(hold.direction(), self.speed_m_s)));
        }
        self.hold = Some(hold);
    }

    /// After the held keys changed: the new velocity at once if the direction did.
    fn redirect(&mut self, before: [f64; 2], now_s: f64, out: &mut Vec<Action>) {
        let speed = self.speed_m_s;
        if let Some(hold) = self.hold.as_mut() {
            let after = hold.direction();
            if hold.live && after != before {
                hold.base_s = now_s;
                hold.renewal = 1;
                out.push(Action::Velocity(scale(after, speed)));
            }
        }
    }

    fn end_hold_with_zero(&mut self, in_control: bool, out: &mut Vec<Action>) {
        if let Some(hold) = self.hold.take() {
            if hold.live && in_control {
                out.push(Action::Velocity([0.0, 0.0]));
            }
        }
    }
}

impl Default for Keyboard {
    fn default() -> Self {
        Self::new(DEFAULT_SPEED_M_S)
    }
}

/// `speed_m_s` within [`MIN_SPEED_M_S`]..=[`MAX_SPEED_M_S`] (the default for NaN).
fn clamp_speed(speed_m_s: f64) -> f64 {
    if speed_m_s.is_nan() {
        DEFAULT_SPEED_M_S
    } else {
        speed_m_s.clamp(MIN_SPEED_M_S, MAX_SPEED_M_S)
    }
}

fn scale(v: [f64; 2], by: f64) -> [f64; 2] {
    [v[0] * by, v[1] * by]
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    const ZERO: Action = Action::Velocity([0.0, 0.0]);
    const EPS: f64 = 1e-12;

    fn is_moving(action: &Action) -> bool {
        matches!(action, Action::Velocity(v) if *v != [0.0, 0.0])
    }

    fn close(a: [f64; 2], b: [f64; 2]) -> bool {
        (a[0] - b[0]).abs() < EPS && (a[1] - b[1]).abs() < EPS
    }

    /// Ticks every millisecond from `from_s` up to `to_s`, collecting what comes out.
    fn run(kb: &mut Keyboard, from_s: f64, to_s: f64, in_control: bool) -> Vec<(f64, Action)> {
        let mut got = Vec::new();
        let mut out = Vec::new();
        let steps = ((to_s - from_s) * 1000.0).round() as u64;
        for i in 1..=steps {
            let now = from_s + i as f64 / 1000.0;
            kb.tick(now, in_control, &mut out);
            got.extend(out.drain(..).map(|a| (now, a)));
        }
        got
    }

    fn press(kb: &mut Keyboard, key: Key, now: f64) -> Vec<Action> {
        let mut out = Vec::new();
        kb.key(key, KeyKind::Press, now, true, &mut out);
        out
    }

    #[test]
    fn a_single_press_moves_for_the_first_hold_then_one_zero() {
        let mut kb = Keyboard::new(0.05);
        assert_eq!(
            press(&mut kb, Key::Right, 0.0),
            [Action::Velocity([0.05, 0.0])]
        );
        assert_eq!(kb.held_velocity(), Some([0.05, 0.0]));
        let got = run(&mut kb, 0.0, 2.0, true);
        let renewals: Vec<f64> = got
            .iter()
            .filter(|(_, a)| is_moving(a))
            .map(|(t, _)| *t)
            .collect();
        // At 20 Hz over 0..0.6 s, after the one at the press: 0.05, 0.10, ... 0.55.
        assert_eq!(renewals.len(), 11, "{renewals:?}");
        for (i, t) in renewals.iter().enumerate() {
            assert!((t - 0.05 * (i as f64 + 1.0)).abs() < 0.0015, "{renewals:?}");
        }
        let zeros: Vec<f64> = got
            .iter()
            .filter(|(_, a)| *a == ZERO)
            .map(|(t, _)| *t)
            .collect();
        assert_eq!(zeros.len(), 1);
        assert!((zeros[0] - HOLD_FIRST_S).abs() < 0.0015, "{zeros:?}");
        assert_eq!(got.len(), 12);
        assert_eq!(kb.held_velocity(), None);
        assert_eq!(kb.next_deadline(), None);
    }

    #[test]
    fn an_arrow_split_over_three_reads_moves_its_own_way() {
        // ESC, `[`, the letter: left, up, right, down, each piece 30 ms after the one before.
        for (letter, velocity) in [
            ('D', [-0.05, 0.0]),
            ('A', [0.0, 0.05]),
            ('C', [0.05, 0.0]),
            ('B', [0.0, -0.05]),
        ] {
            let mut kb = Keyboard::new(0.05);
            let mut got = press(&mut kb, Key::Esc, 10.0);
            got.extend(press(&mut kb, Key::Char('['), 10.03));
            got.extend(press(&mut kb, Key::Char(letter), 10.06));
            assert_eq!(
                got,
                [Action::Stop, Action::Velocity(velocity)],
                "ESC [ {letter}"
            );
        }
        // SS3 arrows (ESC O D) and a modified one (ESC [ 1 ; 5 D) too.
        let mut kb = Keyboard::new(0.05);
        let mut got = Vec::new();
        for (i, key) in [Key::Esc, Key::Char('O'), Key::Char('D')]
            .into_iter()
            .enumerate()
        {
            got.extend(press(&mut kb, key, 1.0 + 0.01 * i as f64));
        }
        assert_eq!(got, [Action::Stop, Action::Velocity([-0.05, 0.0])]);
        let mut kb = Keyboard::new(0.05);
        let mut got = Vec::new();
        for (i, c) in "[1;5D".chars().enumerate() {
            if i == 0 {
                got.extend(press(&mut kb, Key::Esc, 1.0));
            }
            got.extend(press(&mut kb, Key::Char(c), 1.01 + 0.01 * i as f64));
        }
        assert_eq!(got, [Action::Stop, Action::Velocity([-0.05, 0.0])]);
    }

    #[test]
    fn a_split_home_key_does_not_send_the_arm_home_and_late_pieces_are_keys_again() {
        // ESC [ H is the Home key; `H` alone is `h`, home.
        let mut kb = Keyboard::new(0.05);
        let mut got = press(&mut kb, Key::Esc, 0.0);
        got.extend(press(&mut kb, Key::Char('['), 0.01));
        got.extend(press(&mut kb, Key::Char('H'), 0.02));
        assert_eq!(got, [Action::Stop, Action::Stop]);
        // Keys typed after the join's time are what they are.
        let mut kb = Keyboard::new(0.05);
        let late = ESCAPE_JOIN_S + 0.05;
        let mut got = press(&mut kb, Key::Esc, 0.0);
        got.extend(press(&mut kb, Key::Char('['), late));
        got.extend(press(&mut kb, Key::Char('D'), 2.0 * late));
        assert_eq!(
            got,
            [Action::Stop, Action::Stop, Action::Velocity([0.05, 0.0])]
        );
        // A `d` after Esc alone is `d`.
        let mut kb = Keyboard::new(0.05);
        let mut got = press(&mut kb, Key::Esc, 0.0);
        got.extend(press(&mut kb, Key::Char('d'), 0.01));
        assert_eq!(got, [Action::Stop, Action::Velocity([0.05, 0.0])]);
    }

    #[test]
    fn ticking_at_the_deadlines_gives_the_same_renewals() {
        let mut kb = Keyboard::new(0.05);
        let mut out = press(&mut kb, Key::Up, 100.0);
        let mut ticks = 0;
        while let Some(deadline) = kb.next_deadline() {
            kb.tick(deadline, true, &mut out);
            ticks += 1;
            assert!(ticks < 100, "the hold never ends");
        }
        assert_eq!(out.iter().filter(|a| is_moving(a)).count(), 12);
        assert_eq!(out.last(), Some(&ZERO));
        assert_eq!(out.iter().filter(|a| **a == ZERO).count(), 1);
        assert_eq!(out[0], Action::Velocity([0.0, 0.05]));
    }

    #[test]
    fn repeats_extend_the_hold_past_the_first_period_by_the_repeat_hold() {
        let mut kb = Keyboard::new(0.05);
        let mut out = press(&mut kb, Key::Left, 0.0);
        // Auto-repeat from 0.5 s every 33 ms until 1.49 s.
        let mut t = 0.0;
        let mut last_repeat = 0.0;
        let mut zero_at = None;
        for i in 1..=3000 {
            let now = i as f64 / 1000.0;
            if (0.5..=1.49).contains(&now) && now - last_repeat >= 0.033 - 1e-9 {
                kb.key(Key::Left, KeyKind::Press, now, true, &mut out);
                last_repeat = now;
            }
            let before = out.len();
            kb.tick(now, true, &mut out);
            if out[before..].contains(&ZERO) {
                zero_at = Some(now);
            }
            t = now;
        }
        assert!(t > 2.9);
        let zero_at = zero_at.expect("the hold ended");
        assert!(
            (zero_at - (last_repeat + HOLD_AFTER_REPEAT_S)).abs() < 0.0015,
            "{zero_at} after {last_repeat}"
        );
        assert_eq!(out.iter().filter(|a| **a == ZERO).count(), 1);
        assert!(out
            .iter()
            .all(|a| *a == ZERO || *a == Action::Velocity([-0.05, 0.0])));
        // Renewed at 20 Hz for the whole hold (give or take one at each end).
        let moving = out.iter().filter(|a| is_moving(a)).count() as f64;
        assert!((moving - zero_at * RENEW_HZ).abs() <= 1.0, "{moving}");
    }

    #[test]
    fn an_early_repeat_does_not_end_the_hold_before_the_first_period() {
        let mut kb = Keyboard::new(0.05);
        press(&mut kb, Key::Down, 0.0);
        let mut out = Vec::new();
        kb.key(Key::Down, KeyKind::Press, 0.1, true, &mut out);
        assert!(out.is_empty(), "{out:?}");
        let got = run(&mut kb, 0.1, 1.0, true);
        let zero = got.iter().find(|(_, a)| *a == ZERO).expect("one zero");
        assert!((zero.0 - HOLD_FIRST_S).abs() < 0.0015, "{got:?}");
    }

    #[test]
    fn another_direction_starts_a_new_hold_without_a_zero_between() {
        let mut kb = Keyboard::new(0.05);
        press(&mut kb, Key::Up, 0.0);
        let mut got = run(&mut kb, 0.0, 0.3, true);
        assert_eq!(
            press(&mut kb, Key::Char('d'), 0.3),
            [Action::Velocity([0.05, 0.0])]
        );
        got.extend(run(&mut kb, 0.3, 2.0, true));
        assert_eq!(got.iter().filter(|(_, a)| *a == ZERO).count(), 1);
        let zero = got.iter().find(|(_, a)| *a == ZERO).unwrap();
        // The new hold has its own first period.
        assert!((zero.0 - (0.3 + HOLD_FIRST_S)).abs() < 0.0015, "{zero:?}");
        assert!(got
            .iter()
            .filter(|(t, _)| *t > 0.3)
            .all(|(_, a)| *a == ZERO || *a == Action::Velocity([0.05, 0.0])));
    }

    #[test]
    fn wasd_as_characters_move_like_the_arrows() {
        for (c, v) in [
            ('w', [0.0, 0.05]),
            ('a', [-0.05, 0.0]),
            ('s', [0.0, -0.05]),
            ('d', [0.05, 0.0]),
        ] {
            let mut kb = Keyboard::new(0.05);
            assert_eq!(
                press(&mut kb, Key::Char(c), 0.0),
                [Action::Velocity(v)],
                "{c}"
            );
        }
    }

    #[test]
    fn plus_and_minus_step_the_speed_within_bounds_and_a_hold_takes_it_at_its_renewal() {
        let mut kb = Keyboard::new(DEFAULT_SPEED_M_S);
        press(&mut kb, Key::Right, 0.0);
        let out = press(&mut kb, Key::Char('+'), 0.01);
        assert!(out.is_empty(), "{out:?}");
        assert!((kb.speed_m_s() - DEFAULT_SPEED_M_S * SPEED_STEP).abs() < EPS);
        let got = run(&mut kb, 0.01, 0.06, true);
        assert_eq!(got.len(), 1);
        let Action::Velocity(v) = got[0].1 else {
            panic!("{got:?}")
        };
        assert!(close(v, [DEFAULT_SPEED_M_S * SPEED_STEP, 0.0]), "{v:?}");
        press(&mut kb, Key::Char('='), 0.07);
        press(&mut kb, Key::Char('-'), 0.08);
        press(&mut kb, Key::Char('-'), 0.09);
        assert!((kb.speed_m_s() - DEFAULT_SPEED_M_S).abs() < EPS);
        for i in 0..100 {
            press(&mut kb, Key::Char('+'), 1.0 + f64::from(i));
        }
        assert_eq!(kb.speed_m_s(), MAX_SPEED_M_S);
        for i in 0..100 {
            press(&mut kb, Key::Char('-'), 200.0 + f64::from(i));
        }
        assert_eq!(kb.speed_m_s(), MIN_SPEED_M_S);
    }

    #[test]
    fn keys_whose_command_halts_the_arm_end_a_hold_without_the_extra_zero() {
        let cases = [
            (Key::Space, Action::Stop),
            (Key::Char('e'), Action::Estop),
            (Key::Char('h'), Action::Home),
            (Key::Char('t'), Action::ToggleTorque),
            (Key::Char('x'), Action::Stop),
            (Key::Other, Action::Stop),
        ];
        for (key, action) in cases {
            let mut kb = Keyboard::new(0.05);
            press(&mut kb, Key::Up, 0.0);
            assert_eq!(press(&mut kb, key, 0.2), [action], "{key:?}");
            assert_eq!(kb.held_velocity(), None);
            assert!(run(&mut kb, 0.2, 2.0, true).is_empty(), "{key:?}");
        }
    }

    #[test]
    fn keys_whose_command_leaves_a_velocity_running_end_a_hold_with_its_zero_first() {
        // `strategy`, `take_control` and a `reset` without a latch leave a velocity to its
        // deadman: without the zero the tip would go on for up to half a second.
        let cases = [
            (Key::Tab, Action::NextStrategy),
            (Key::Char('c'), Action::TakeControl),
            (Key::Char('r'), Action::Reset),
        ];
        for (key, action) in cases {
            for releases in [false, true] {
                let mut kb = Keyboard::new(0.05);
                kb.set_releases_reported(releases);
                press(&mut kb, Key::Up, 0.0);
                assert_eq!(press(&mut kb, key, 0.2), [ZERO, action], "{key:?}");
                assert_eq!(kb.held_velocity(), None);
                assert!(run(&mut kb, 0.2, 2.0, true).is_empty(), "{key:?}");
            }
            // A hold without control sends nothing: the zero is not ours to send.
            let mut kb = Keyboard::new(0.05);
            let mut out = Vec::new();
            kb.key(Key::Up, KeyKind::Press, 0.0, false, &mut out);
            kb.key(key, KeyKind::Press, 0.2, false, &mut out);
            assert!(!out.contains(&ZERO), "{key:?}: {out:?}");
        }
    }

    #[test]
    fn giving_way_ends_a_hold_without_its_zero_or_more_renewals() {
        for releases in [false, true] {
            let mut kb = Keyboard::new(0.05);
            kb.set_releases_reported(releases);
            press(&mut kb, Key::Up, 0.0);
            kb.give_way();
            assert_eq!(kb.held_velocity(), None);
            assert_eq!(kb.next_deadline(), None);
            assert!(run(&mut kb, 0.0, 2.0, true).is_empty(), "{releases}");
            // The next press starts a hold of its own.
            assert_eq!(
                press(&mut kb, Key::Up, 2.0),
                [Action::Velocity([0.0, 0.05])]
            );
        }
    }

    #[test]
    fn quit_sends_the_one_zero_first() {
        let mut kb = Keyboard::new(0.05);
        press(&mut kb, Key::Up, 0.0);
        assert_eq!(press(&mut kb, Key::Char('q'), 0.2), [ZERO, Action::Quit]);
        assert!(run(&mut kb, 0.2, 2.0, true).is_empty());
        let mut idle = Keyboard::new(0.05);
        assert_eq!(press(&mut idle, Key::Char('q'), 0.0), [Action::Quit]);
    }

    #[test]
    fn without_control_only_stop_estop_take_control_and_quit_go_out() {
        let mut kb = Keyboard::new(0.05);
        let mut out = Vec::new();
        for key in [
            Key::Up,
            Key::Char('d'),
            Key::Char('r'),
            Key::Char('h'),
            Key::Tab,
            Key::Char('t'),
            Key::Space,
            Key::Char('e'),
            Key::Char('c'),
            Key::Char('q'),
        ] {
            kb.key(key, KeyKind::Press, 0.0, false, &mut out);
        }
        assert_eq!(
            out,
            [
                Action::Stop,
                Action::Estop,
                Action::TakeControl,
                Action::Quit
            ]
        );
        // A press without control moves nothing, now or later, and ends without a zero.
        let mut kb = Keyboard::new(0.05);
        kb.key(Key::Up, KeyKind::Press, 0.0, false, &mut out);
        assert_eq!(kb.held_velocity(), None);
        assert!(run(&mut kb, 0.0, 2.0, false).is_empty());
    }

    #[test]
    fn losing_control_during_a_hold_stops_the_renewals_without_a_zero() {
        let mut kb = Keyboard::new(0.05);
        press(&mut kb, Key::Up, 0.0);
        assert_eq!(run(&mut kb, 0.0, 0.2, true).len(), 4);
        assert!(run(&mut kb, 0.2, 0.4, false).is_empty());
        // Control back while the same hold lasts: it stays silent.
        assert!(run(&mut kb, 0.4, 2.0, true).is_empty());
        assert_eq!(kb.next_deadline(), None);
    }

    #[test]
    fn with_releases_a_hold_lasts_until_the_release_then_one_zero() {
        let mut kb = Keyboard::new(0.05);
        kb.set_releases_reported(true);
        assert_eq!(
            press(&mut kb, Key::Left, 0.0),
            [Action::Velocity([-0.05, 0.0])]
        );
        // Repeats from 0.5 s, every 0.5 s here (a terminal sends them every 30-50 ms).
        let mut out = Vec::new();
        let mut got = Vec::new();
        for k in 0..6 {
            let t = 0.5 * f64::from(k);
            if k > 0 {
                kb.key(Key::Left, KeyKind::Repeat, t, true, &mut out);
                assert!(out.is_empty(), "a repeat sends nothing by itself");
            }
            got.extend(run(&mut kb, t, t + 0.5, true));
        }
        assert!(got
            .iter()
            .all(|(_, a)| *a == Action::Velocity([-0.05, 0.0])));
        assert_eq!(got.len(), 60, "renewed at 20 Hz for 3 s");
        kb.key(Key::Left, KeyKind::Release, 3.0, true, &mut out);
        assert_eq!(out, [ZERO]);
        assert!(run(&mut kb, 3.0, 4.0, true).is_empty());
    }

    #[test]
    fn with_releases_a_hold_whose_release_is_lost_ends_by_the_guard() {
        let mut kb = Keyboard::new(0.05);
        kb.set_releases_reported(true);
        press(&mut kb, Key::Up, 0.0);
        let mut out = Vec::new();
        kb.key(Key::Up, KeyKind::Repeat, 0.6, true, &mut out);
        // No repeat and no release after 0.6 s: the hold ends RELEASE_GUARD_S later.
        let got = run(&mut kb, 0.0, 4.0, true);
        let zeros: Vec<f64> = got
            .iter()
            .filter(|(_, a)| *a == ZERO)
            .map(|(t, _)| *t)
            .collect();
        assert_eq!(zeros.len(), 1, "{got:?}");
        assert!(
            (zeros[0] - (0.6 + RELEASE_GUARD_S)).abs() < 2e-3,
            "{zeros:?}"
        );
        assert_eq!(got.last().map(|(_, a)| *a), Some(ZERO));
        assert_eq!(kb.next_deadline(), None);
    }

    #[test]
    fn with_releases_two_keys_combine_into_a_diagonal_at_the_same_speed() {
        let mut kb = Keyboard::new(0.05);
        kb.set_releases_reported(true);
        press(&mut kb, Key::Up, 0.0);
        let out = press(&mut kb, Key::Right, 0.1);
        let h = 0.05 / 2f64.sqrt();
        assert_eq!(out.len(), 1);
        let Action::Velocity(v) = out[0] else {
            panic!("{out:?}")
        };
        assert!(close(v, [h, h]), "{v:?}");
        // Opposite keys: the later pressed wins.
        let out = press(&mut kb, Key::Down, 0.2);
        let Action::Velocity(v) = out[0] else {
            panic!("{out:?}")
        };
        assert!(close(v, [h, -h]), "{v:?}");
        let mut out = Vec::new();
        kb.key(Key::Down, KeyKind::Release, 0.3, true, &mut out);
        kb.key(Key::Right, KeyKind::Release, 0.4, true, &mut out);
        let Action::Velocity(v) = out[0] else {
            panic!("{out:?}")
        };
        assert!(close(v, [h, h]), "{v:?}");
        assert_eq!(out[1], Action::Velocity([0.0, 0.05]));
        kb.key(Key::Up, KeyKind::Release, 0.5, true, &mut out);
        assert_eq!(out[2..], [ZERO]);
    }

    #[test]
    fn switching_release_reporting_during_a_hold_ends_it_with_its_zero() {
        let mut kb = Keyboard::new(0.05);
        press(&mut kb, Key::Up, 0.0);
        kb.set_releases_reported(true);
        assert_eq!(kb.next_deadline(), Some(0.0));
        let mut out = Vec::new();
        kb.tick(0.01, true, &mut out);
        assert_eq!(out, [ZERO]);
        assert!(run(&mut kb, 0.01, 2.0, true).is_empty());
    }

    #[test]
    fn a_late_tick_sends_one_renewal_not_the_missed_ones() {
        let mut kb = Keyboard::new(0.05);
        kb.set_releases_reported(true);
        press(&mut kb, Key::Up, 0.0);
        let mut out = Vec::new();
        kb.tick(1.012, true, &mut out);
        assert_eq!(out.len(), 1);
        let next = kb.next_deadline().unwrap();
        assert!((next - 1.05).abs() < 1e-9, "{next}");
    }
}
