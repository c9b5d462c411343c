//! The bus: N servos behind one line. Parses incoming bytes, dispatches each instruction to the
//! servos it addresses, orders and times the replies, and injects the configured faults.
//!
//! [`Simulator::handle_bytes`] is the whole core: bytes in, timed replies out, no I/O. The pty
//! layer only moves bytes and waits for each reply's deadline.

use std::time::{Duration, Instant};

use crate::adapter::Adapter;
use crate::clock::SharedClock;
use crate::protocol::{
    self, error, instruction as ins, FastBlock, Frame, Packet, Parser, BROADCAST_ID,
};
use crate::rng::SplitMix64;
use crate::servo::{Servo, ServoSpec};
use crate::table::hw;
use crate::SimError;

/// Baud rates selectable in the Baud Rate register (index = register value).
pub const BAUD_RATES: [u32; 8] = [
    9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000,
];

/// Largest extra latency a fault may add to a reply.
pub const MAX_LATENCY: Duration = Duration::from_secs(60);

/// How long a servo takes to boot after answering REBOOT (or a factory reset), neither hearing
/// nor answering meanwhile, unless [`SimConfig::boot_time`] says otherwise. The e-manual gives
/// no figure; about 0.4 s was measured on XC330 servos (reported to ROBOTIS in their e-manual's
/// issue 1698), and the X430s are taken to boot as long.
pub const DEFAULT_BOOT_TIME: Duration = Duration::from_millis(400);

/// Longest boot time a configuration may ask for.
pub const MAX_BOOT_TIME: Duration = Duration::from_secs(60);

/// The slot of one id in the replies to a broadcast ping: counting from id 1 once the line is
/// quiet, a servo waits this long for each id before its own that has not answered. ROBOTIS'
/// own Protocol 2.0 device firmware (OpenCR's OP3 sub-controller) counts the ids in steps of
/// 3 ms, skipping to the next id when it hears a reply, and their SDK waits 3 ms an id for
/// the replies.
pub const BROADCAST_PING_SLOT: Duration = Duration::from_millis(3);

/// A hardware error a fault can raise (bits of Hardware Error Status).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum HardwareErrorKind {
    /// Overload (bit 5): in the default Shutdown of every model.
    Overload,
    /// Overheating (bit 2): in the default Shutdown; Present Temperature jumps above the limit.
    Overheating,
    /// Input voltage (bit 0): in the XL330's default Shutdown only; Present Input Voltage drops
    /// below the limit.
    InputVoltage,
    /// Electrical shock (bit 4): in the default Shutdown.
    ElectricalShock,
    /// Motor encoder (bit 3): not in the default Shutdown.
    Encoder,
}

/// A hardware error name that is not one of [`HardwareErrorKind`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown hardware error {0:?} (known: overload, overheating, voltage, electrical_shock, encoder)"
)]
pub struct UnknownHardwareError(pub String);

impl std::str::FromStr for HardwareErrorKind {
    type Err = UnknownHardwareError;

    /// `overload`, `overheating`, `voltage` (or `input_voltage`), `electrical_shock`, `encoder`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().replace('-', "_").as_str() {
            "overload" => Ok(Self::Overload),
            "overheating" => Ok(Self::Overheating),
            "voltage" | "input_voltage" => Ok(Self::InputVoltage),
            "electrical_shock" => Ok(Self::ElectricalShock),
            "encoder" => Ok(Self::Encoder),
            _ => Err(UnknownHardwareError(s.to_string())),
        }
    }
}

impl HardwareErrorKind {
    /// The Hardware Error Status bit.
    pub fn bit(self) -> u8 {
        match self {
            Self::Overload => hw::OVERLOAD,
            Self::Overheating => hw::OVERHEATING,
            Self::InputVoltage => hw::INPUT_VOLTAGE,
            Self::ElectricalShock => hw::ELECTRICAL_SHOCK,
            Self::Encoder => hw::ENCODER,
        }
    }
}

/// A fault to inject. Random faults draw from the simulator's seeded generator, so a run with
/// the same seed and the same traffic (at the same clock times) fails the same way.
///
/// Drop, corrupt, latency, silent and blocked faults stand for the whole run unless wrapped in
/// [`Fault::During`] (see [`Fault::during`]), which limits them to a time window.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Fault {
    /// Each reply (of servo `id`, or of every servo) is lost with probability `fraction`.
    DropReplies {
        /// Only this servo, or all.
        id: Option<u8>,
        /// Probability in [0, 1].
        fraction: f64,
    },
    /// Each reply has one byte flipped (after the header, so the client sees a CRC error) with
    /// probability `fraction`.
    CorruptReplies {
        /// Only this servo, or all.
        id: Option<u8>,
        /// Probability in [0, 1].
        fraction: f64,
    },
    /// Every reply leaves `latency` later than it would.
    ExtraLatency {
        /// Only this servo, or all.
        id: Option<u8>,
        /// Added delay.
        latency: Duration,
    },
    /// From `at` after start, servo `id` neither hears nor answers (a broken cable).
    Silent {
        /// The servo.
        id: u8,
        /// Time after the simulator's start.
        at: Duration,
    },
    /// At `at` after start, servo `id` latches a hardware error.
    HardwareError {
        /// The servo.
        id: u8,
        /// Time after the simulator's start.
        at: Duration,
        /// Which error.
        kind: HardwareErrorKind,
    },
    /// From `at` after start, servo `id`'s shaft is blocked (an obstacle in its way): it stays
    /// where it was when the block began, whatever the goal, and with torque on the servo
    /// pushes, its Present Load or Current rising with the position error to a stall (see
    /// [`Servo::set_blocked`]). It still hears and answers. A window closing at `end` lets the
    /// shaft go again.
    Blocked {
        /// The servo.
        id: u8,
        /// Time after the simulator's start.
        at: Duration,
    },
    /// The serial adapter is unplugged: while this fault is active (wrap it in
    /// [`Fault::During`] for a window) the pseudo-terminal of [`crate::pty`] is gone, its master
    /// and slave ends closed, so a client's reads and writes fail; at the window's end the chain
    /// comes back on a new pseudo-terminal (the handle's link, if any, points at it). The servos
    /// keep running meanwhile: motor models move on, watchdogs fire. Without a window the bus
    /// never appears. A [`Simulator`] fed bytes directly only reports it
    /// ([`Simulator::disconnected`]).
    Disconnect,
    /// `fault` is active only from `start` after the simulator's start until `end` (exclusive;
    /// `None`: to the end of the run). A reply fault applies to the replies of instructions
    /// received inside the window; a silent servo hears and answers again from `end` on.
    /// Windows nest (the fault is active where all of them are open); a hardware error latches
    /// at one instant and cannot be windowed.
    During {
        /// Opening of the window, after the simulator's start.
        start: Duration,
        /// Closing of the window, after the simulator's start; later than `start`.
        end: Option<Duration>,
        /// The fault the window applies to.
        fault: Box<Fault>,
    },
}

impl Fault {
    /// This fault, active only from `start` until `end` (`None`: to the end of the run).
    pub fn during(self, start: Duration, end: Option<Duration>) -> Self {
        Self::During {
            start,
            end,
            fault: Box::new(self),
        }
    }

    /// The window in which this fault is active (all windows it is wrapped in, intersected)
    /// and the fault itself.
    pub fn window(&self) -> (Window, &Fault) {
        let mut window = Window::ALWAYS;
        let mut fault = self;
        while let Self::During {
            start,
            end,
            fault: inner,
        } = fault
        {
            window.start = window.start.max(*start);
            window.end = match (window.end, *end) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            };
            fault = inner;
        }
        (window, fault)
    }
}

/// A span of time after the simulator's start: `start` inclusive, `end` exclusive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// Opening.
    pub start: Duration,
    /// Closing; `None`: never.
    pub end: Option<Duration>,
}

impl Window {
    /// The whole run.
    pub const ALWAYS: Self = Self {
        start: Duration::ZERO,
        end: None,
    };

    /// Whether `elapsed` (time after the simulator's start) falls inside.
    pub fn contains(&self, elapsed: Duration) -> bool {
        elapsed >= self.start && self.end.is_none_or(|end| elapsed < end)
    }
}

/// Everything the simulator needs: plain data, no dependency on the controller.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// The servos on the bus.
    pub servos: Vec<ServoSpec>,
    /// Bus baud rate; must be one of [`BAUD_RATES`]. Written into every servo's Baud Rate.
    pub baud: u32,
    /// Return Delay Time written into every servo at start (µs, even, at most 508).
    pub return_delay_us: u32,
    /// Delay each reply by its wire time at `baud` plus the Return Delay Time.
    pub wire_timing: bool,
    /// How long a servo boots after REBOOT or a factory reset, off the bus (at most
    /// [`MAX_BOOT_TIME`]; zero: back at once).
    pub boot_time: Duration,
    /// What hands the replies to the host: nothing (default), or an FTDI chip that holds them
    /// as its USB packets and latency timer do (the pty layer applies it; see
    /// [`crate::adapter`]).
    pub adapter: Adapter,
    /// Seed of the fault generator.
    pub seed: u64,
    /// Faults to inject.
    pub faults: Vec<Fault>,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            servos: Vec::new(),
            baud: 1_000_000,
            return_delay_us: 0,
            wire_timing: false,
            boot_time: DEFAULT_BOOT_TIME,
            adapter: Adapter::Direct,
            seed: 1,
            faults: Vec::new(),
        }
    }
}

impl SimConfig {
    /// Check the configuration; returns the Baud Rate register index of `baud`.
    pub fn validate(&self) -> Result<u8, SimError> {
        let baud_index = BAUD_RATES
            .iter()
            .position(|&b| b == self.baud)
            .ok_or(SimError::Baud(self.baud))?;
        if self.return_delay_us > 508 || self.return_delay_us % 2 != 0 {
            return Err(SimError::ReturnDelay(self.return_delay_us));
        }
        if self.boot_time > MAX_BOOT_TIME {
            return Err(SimError::BootTime(self.boot_time));
        }
        let mut seen = [false; 256];
        for spec in &self.servos {
            if spec.id > 252 {
                return Err(SimError::BadId(spec.id));
            }
            if std::mem::replace(&mut seen[usize::from(spec.id)], true) {
                return Err(SimError::DuplicateId(spec.id));
            }
            let min = spec.min_position_ticks.unwrap_or(0);
            let max = spec.max_position_ticks.unwrap_or(4095);
            if min > max || max > 4095 {
                return Err(SimError::PositionLimits {
                    id: spec.id,
                    min,
                    max,
                });
            }
        }
        for fault in &self.faults {
            // Every window (they may nest) must close after it opens.
            let mut f = fault;
            while let Fault::During {
                start,
                end,
                fault: inner,
            } = f
            {
                if let Some(end) = *end {
                    if end <= *start {
                        return Err(SimError::Window { start: *start, end });
                    }
                }
                f = inner;
            }
            let (_, inner) = fault.window();
            if matches!(fault, Fault::During { .. }) && matches!(inner, Fault::HardwareError { .. })
            {
                return Err(SimError::WindowedHardwareError);
            }
            let (id, fraction) = match inner {
                Fault::DropReplies { id, fraction } | Fault::CorruptReplies { id, fraction } => {
                    (*id, Some(*fraction))
                }
                Fault::ExtraLatency { id, latency } => {
                    if *latency > MAX_LATENCY {
                        return Err(SimError::Latency(*latency));
                    }
                    (*id, None)
                }
                Fault::Silent { id, .. }
                | Fault::HardwareError { id, .. }
                | Fault::Blocked { id, .. } => (Some(*id), None),
                Fault::Disconnect | Fault::During { .. } => (None, None),
            };
            if let Some(id) = id {
                if !seen[usize::from(id)] {
                    return Err(SimError::FaultId(id));
                }
            }
            if let Some(f) = fraction {
                if !(0.0..=1.0).contains(&f) {
                    return Err(SimError::Fraction(f));
                }
            }
        }
        Ok(baud_index as u8)
    }
}

/// A reply to put on the wire no earlier than `at`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    /// When the last byte would have left the servo (wire timing), or when the instruction was
    /// handled (no wire timing), plus any injected latency.
    pub at: Instant,
    /// The id of the servo that answers ([`BROADCAST_ID`] for the one packet of a Fast Sync or
    /// Fast Bulk Read from the whole chain).
    pub id: u8,
    /// The status packet as transmitted (possibly corrupted by a fault).
    pub bytes: Vec<u8>,
}

/// Counters, for logs and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Bytes received from the line (everything fed to [`Simulator::handle_bytes`]). Tests
    /// over the pty wait on it to know the simulator has taken what they wrote.
    pub bytes: u64,
    /// Packets with a good CRC.
    pub packets: u64,
    /// Frames with a bad CRC.
    pub crc_errors: u64,
    /// Replies produced.
    pub replies: u64,
    /// Replies dropped by a fault.
    pub dropped: u64,
    /// Replies corrupted by a fault.
    pub corrupted: u64,
}

/// What happens at a timed fault's instant.
#[derive(Debug, Clone, Copy)]
enum Event {
    /// A silent window of this servo (configured id) opens or closes: its silence is
    /// recomputed from all its silent faults.
    Silence(u8),
    /// The servo (configured id) latches a hardware error.
    Hardware(u8, HardwareErrorKind),
    /// A blocked window of this servo (configured id) opens or closes: whether it is blocked
    /// is recomputed from all its blocked faults.
    Block(u8),
}

#[derive(Debug, Clone)]
struct Timed {
    at: Instant,
    event: Event,
    done: bool,
}

/// A chain of virtual servos behind one serial line.
#[derive(Debug)]
pub struct Simulator {
    servos: Vec<Servo>,
    config: SimConfig,
    line_baud: u32,
    clock: SharedClock,
    start: Instant,
    last: Instant,
    parser: Parser,
    rng: SplitMix64,
    line_free: Instant,
    timed: Vec<Timed>,
    stats: Stats,
}

/// A reply a servo wants to send, before faults and timing.
struct Outgoing {
    index: usize,
    bytes: Vec<u8>,
    /// Wire timing: how long the servo waits, once the line is quiet, before its own Return
    /// Delay Time (the empty slots before it in the replies to a broadcast ping).
    slot_wait: Duration,
}

impl Simulator {
    /// Power on the servos of `config` at the clock's current time.
    pub fn new(config: SimConfig, clock: SharedClock) -> Result<Self, SimError> {
        let baud_index = config.validate()?;
        let now = clock.now();
        let rdt = (config.return_delay_us / 2) as u8;
        let servos = config
            .servos
            .iter()
            .map(|spec| Servo::new(spec, baud_index, rdt, now))
            .collect();
        let mut timed = Vec::new();
        // A time too far to represent never comes.
        let mut at = |after: Duration, event: Event| {
            if let Some(at) = now.checked_add(after) {
                timed.push(Timed {
                    at,
                    event,
                    done: false,
                });
            }
        };
        for fault in &config.faults {
            match fault.window() {
                (window, &Fault::Silent { id, at: from }) => {
                    let on = window.start.max(from);
                    if window.end.is_none_or(|end| on < end) {
                        at(on, Event::Silence(id));
                        if let Some(end) = window.end {
                            at(end, Event::Silence(id));
                        }
                    }
                }
                (window, &Fault::Blocked { id, at: from }) => {
                    let on = window.start.max(from);
                    if window.end.is_none_or(|end| on < end) {
                        at(on, Event::Block(id));
                        if let Some(end) = window.end {
                            at(end, Event::Block(id));
                        }
                    }
                }
                (_, &Fault::HardwareError { id, at: when, kind }) => {
                    at(when, Event::Hardware(id, kind));
                }
                _ => {}
            }
        }
        let mut sim = Self {
            servos,
            rng: SplitMix64::new(config.seed),
            line_baud: config.baud,
            config,
            clock,
            start: now,
            last: now,
            parser: Parser::default(),
            line_free: now,
            timed,
            stats: Stats::default(),
        };
        sim.fire_due(now);
        Ok(sim)
    }

    /// The configuration it was built from.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// The clock it runs on.
    pub fn clock(&self) -> &SharedClock {
        &self.clock
    }

    /// When it started.
    pub fn start(&self) -> Instant {
        self.start
    }

    /// Counters.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// All servos, in configuration order.
    pub fn servos(&self) -> &[Servo] {
        &self.servos
    }

    /// The servo whose current id is `id`.
    pub fn servo(&self, id: u8) -> Option<&Servo> {
        self.servos.iter().find(|s| s.id() == id)
    }

    /// The servo whose current id is `id`, mutably.
    pub fn servo_mut(&mut self, id: u8) -> Option<&mut Servo> {
        self.servos.iter_mut().find(|s| s.id() == id)
    }

    /// The servo configured with id `id`, whatever id a client has given it since: the one a
    /// fault names.
    fn configured_mut(&mut self, id: u8) -> Option<&mut Servo> {
        let index = self.config.servos.iter().position(|s| s.id == id)?;
        self.servos.get_mut(index)
    }

    /// Servo `id` (current id) loses its power: silent and limp until
    /// [`Simulator::restore_power`]. False when there is no such servo.
    pub fn lose_power(&mut self, id: u8) -> bool {
        self.advance();
        self.servo_mut(id).map(Servo::lose_power).is_some()
    }

    /// Servo `id` (current id) gets its power back at the clock's now: it answers again with its
    /// RAM at the initial values (then as its Startup Configuration says), its EEPROM (id, baud
    /// rate, limits, ...) kept. False when there is no such servo.
    pub fn restore_power(&mut self, id: u8) -> bool {
        self.advance();
        let now = self.clock.now();
        self.servo_mut(id).map(|s| s.restore_power(now)).is_some()
    }

    /// Time one byte takes on the wire at the line's rate (start bit, 8 data bits, stop bit).
    pub fn byte_time(&self) -> Duration {
        Duration::from_nanos(10_000_000_000 / u64::from(self.line_baud.max(1)))
    }

    /// The rate the client's end of the line runs at: what [`Simulator::set_line_baud`] set
    /// last, or the configured `baud`.
    pub fn line_baud(&self) -> u32 {
        self.line_baud
    }

    /// Set the rate the client sends and listens at (as read from the terminal). A servo hears
    /// and answers only while its Baud Rate register selects exactly this rate, as on hardware.
    /// `None` (the client's rate is unknown) or 0 (hang-up) assumes the configured `baud`.
    pub fn set_line_baud(&mut self, baud: Option<u32>) {
        self.line_baud = baud.filter(|&b| b > 0).unwrap_or(self.config.baud);
    }

    /// Time after the simulator's start.
    fn elapsed(&self, now: Instant) -> Duration {
        now.saturating_duration_since(self.start)
    }

    /// Whether a silent fault keeps servo `id` (configured id) off the bus `elapsed` after start.
    fn silent_at(&self, id: u8, elapsed: Duration) -> bool {
        self.config.faults.iter().any(|f| match f.window() {
            (window, &Fault::Silent { id: fid, at }) => {
                fid == id && elapsed >= at && window.contains(elapsed)
            }
            _ => false,
        })
    }

    /// Whether a blocked fault holds servo `id`'s shaft (configured id) `elapsed` after start.
    fn blocked_at(&self, id: u8, elapsed: Duration) -> bool {
        self.config.faults.iter().any(|f| match f.window() {
            (window, &Fault::Blocked { id: fid, at }) => {
                fid == id && elapsed >= at && window.contains(elapsed)
            }
            _ => false,
        })
    }

    /// Whether a [`Fault::Disconnect`] has the line unplugged at the clock's now.
    pub fn disconnected(&self) -> bool {
        let elapsed = self.elapsed(self.clock.now());
        self.config.faults.iter().any(|f| match f.window() {
            (window, Fault::Disconnect) => window.contains(elapsed),
            _ => false,
        })
    }

    /// The line went away: a packet half received is lost with it.
    pub(crate) fn line_lost(&mut self) {
        self.parser = Parser::default();
    }

    /// Advance motor models, watchdogs and timed faults to the clock's now.
    pub fn advance(&mut self) {
        let now = self.clock.now();
        self.advance_to(now);
    }

    fn advance_to(&mut self, now: Instant) {
        if now <= self.last {
            return;
        }
        self.fire_due(now);
        for servo in &mut self.servos {
            servo.update(now);
        }
        self.last = now;
    }

    /// Apply timed faults due by `now`, in time order, each at its own instant.
    fn fire_due(&mut self, now: Instant) {
        loop {
            let next = self
                .timed
                .iter()
                .enumerate()
                .filter(|(_, t)| !t.done && t.at <= now)
                .min_by_key(|(_, t)| t.at)
                .map(|(i, _)| i);
            let Some(i) = next else { break };
            let at = self.timed[i].at;
            self.timed[i].done = true;
            for servo in &mut self.servos {
                servo.update(at);
            }
            match self.timed[i].event {
                Event::Silence(id) => {
                    let silent = self.silent_at(id, self.elapsed(at));
                    if let Some(s) = self.configured_mut(id) {
                        if s.is_silent() != silent {
                            tracing::debug!(id, silent, "fault: servo silence changes");
                            s.set_silent(silent);
                        }
                    }
                }
                Event::Hardware(id, kind) => {
                    if let Some(s) = self.configured_mut(id) {
                        tracing::debug!(id, ?kind, "fault: hardware error");
                        s.raise_hardware_error(kind.bit(), at);
                    }
                }
                Event::Block(id) => {
                    let blocked = self.blocked_at(id, self.elapsed(at));
                    if let Some(s) = self.configured_mut(id) {
                        if s.is_blocked() != blocked {
                            tracing::debug!(id, blocked, "fault: servo blocked or let go");
                            s.set_blocked(blocked, at);
                        }
                    }
                }
            }
        }
    }

    /// Feed bytes received now; return the replies, each with the instant it is due.
    pub fn handle_bytes(&mut self, bytes: &[u8]) -> Vec<Reply> {
        let now = self.clock.now();
        self.advance_to(now);
        self.stats.bytes += bytes.len() as u64;
        let bt = self.byte_time();
        let wire = self.config.wire_timing;
        let chunk_start = if wire { now.max(self.line_free) } else { now };
        let parsed = self.parser.feed(bytes, now);
        let mut replies = Vec::new();
        for p in parsed {
            let done = if wire {
                chunk_start + bt * (p.end_in_chunk as u32 + 1)
            } else {
                now
            };
            if wire {
                self.line_free = self.line_free.max(done);
            }
            let outgoing = match p.frame {
                Frame::Packet(packet)
                    if matches!(
                        packet.instruction,
                        ins::FAST_SYNC_READ | ins::FAST_BULK_READ
                    ) =>
                {
                    self.stats.packets += 1;
                    replies.extend(self.fast_read(&packet, now, done));
                    Vec::new()
                }
                Frame::Packet(packet) => {
                    self.stats.packets += 1;
                    self.dispatch(&packet, now)
                }
                Frame::BadCrc {
                    id, instruction, ..
                } => {
                    self.stats.crc_errors += 1;
                    self.crc_error(id, instruction)
                }
            };
            for out in outgoing {
                if let Some(reply) = self.schedule(out, now, done) {
                    replies.push(reply);
                }
            }
        }
        if wire {
            self.line_free = self.line_free.max(chunk_start + bt * bytes.len() as u32);
        }
        replies
    }

    /// Apply reply faults (those whose window holds `now`, when the instruction came in) and
    /// wire timing to one outgoing status packet.
    fn schedule(&mut self, out: Outgoing, now: Instant, done: Instant) -> Option<Reply> {
        let elapsed = self.elapsed(now);
        let servo = self.servos.get(out.index)?;
        let (id, rdt) = (servo.id(), servo.return_delay());
        let config_id = self.config.servos.get(out.index).map(|s| s.id);
        let (latency, drop, corrupt) = self.reply_faults(config_id, elapsed);
        let mut bytes = out.bytes;
        let at = if self.config.wire_timing {
            // Each servo waits its Return Delay Time once the line is quiet (after the
            // instruction, or after the previous servo's reply in a sync/bulk read or to a
            // broadcast ping, there after the empty slots before its own too).
            let start = done.max(self.line_free) + out.slot_wait + rdt + latency;
            let end = start + self.byte_time() * bytes.len() as u32;
            self.line_free = end;
            end
        } else {
            done + latency
        };
        if drop {
            self.stats.dropped += 1;
            tracing::debug!(id, "fault: reply dropped");
            return None;
        }
        if corrupt && bytes.len() > 7 {
            // Flip a byte after the length field, so the frame keeps its length and fails its CRC.
            let k = 7 + self.rng.below(bytes.len() - 7);
            let flip = 1u8 << self.rng.below(8);
            bytes[k] ^= flip;
            self.stats.corrupted += 1;
            tracing::debug!(id, byte = k, "fault: reply corrupted");
        }
        self.stats.replies += 1;
        Some(Reply { at, id, bytes })
    }

    /// What the reply faults active `elapsed` after start do to a reply of the servo configured
    /// as `config_id`: extra latency, dropped, corrupted. Outside its window a fault draws
    /// nothing: the generator's sequence only depends on the replies the fault could touch.
    fn reply_faults(&mut self, config_id: Option<u8>, elapsed: Duration) -> (Duration, bool, bool) {
        let applies = |fid: &Option<u8>| fid.is_none() || *fid == config_id;
        let mut latency = Duration::ZERO;
        let mut drop = false;
        let mut corrupt = false;
        for fault in &self.config.faults {
            let (window, fault) = fault.window();
            if !window.contains(elapsed) {
                continue;
            }
            match fault {
                Fault::DropReplies { id, fraction } if applies(id) => {
                    drop |= self.rng.chance(*fraction);
                }
                Fault::CorruptReplies { id, fraction } if applies(id) => {
                    corrupt |= self.rng.chance(*fraction);
                }
                Fault::ExtraLatency { id, latency: l } if applies(id) => latency += *l,
                _ => {}
            }
        }
        (latency, drop, corrupt)
    }

    /// A Fast Sync Read or Fast Bulk Read (received whole at `done`): one status packet from
    /// the chain, each listed servo appending its block in the order of the instruction. A servo
    /// that does not hear, does not answer reads (Status Return Level 0), has a firmware too old
    /// for the instruction (to which it is an unknown broadcast: no answer) or whose block a
    /// drop fault takes, breaks the chain there: the servos after it, waiting for its block,
    /// stay silent too, and the packet ends after the last block sent (nothing at all when the
    /// first servo is missing). A corrupt fault flips one bit of that servo's block, so the
    /// packet's running CRC fails from it on. The packet leaves after the first servo's Return
    /// Delay Time and the largest extra latency among the servos that sent a block.
    fn fast_read(&mut self, p: &Packet, now: Instant, done: Instant) -> Option<Reply> {
        if p.id != BROADCAST_ID {
            return None;
        }
        let reads = match p.instruction {
            ins::FAST_SYNC_READ => sync_reads(&p.params)?,
            ins::FAST_BULK_READ => bulk_reads(&p.params)?,
            _ => return None,
        };
        let elapsed = self.elapsed(now);
        let mut heard = Vec::with_capacity(reads.len());
        for &(id, _, _) in &reads {
            let index = self.find(id);
            if let Some(i) = index {
                self.servos[i].touch(now);
            }
            heard.push(index);
        }
        let mut blocks = Vec::with_capacity(reads.len());
        let mut corrupt_blocks = Vec::new();
        let mut latency = Duration::ZERO;
        let mut first = None;
        for (&(id, address, len), index) in reads.iter().zip(heard) {
            let Some(i) = index else { break };
            let servo = &self.servos[i];
            if !servo.knows_fast_read() || !Self::answers(servo, p.instruction) {
                break;
            }
            let (error, data) = match servo.read(address, len) {
                Ok(data) => (servo.status_error(error::NONE), data),
                Err(code) => (servo.status_error(code), Vec::new()),
            };
            let config_id = self.config.servos.get(i).map(|s| s.id);
            let (extra, drop, corrupt) = self.reply_faults(config_id, elapsed);
            if drop {
                self.stats.dropped += 1;
                tracing::debug!(id, "fault: fast read block dropped");
                break;
            }
            if corrupt {
                corrupt_blocks.push(blocks.len());
            }
            latency = latency.max(extra);
            first.get_or_insert(i);
            blocks.push(FastBlock { error, id, data });
        }
        let lengths: Vec<usize> = reads.iter().map(|r| usize::from(r.2)).collect();
        let mut bytes = protocol::encode_fast_reply(&lengths, &blocks);
        let first = first?;
        for k in corrupt_blocks {
            // A bit of block k (error byte to CRC) flipped on the wire.
            let from = 8 + lengths[..k].iter().map(|len| len + 4).sum::<usize>();
            let at = from + self.rng.below(lengths[k] + 4);
            if let Some(byte) = bytes.get_mut(at) {
                *byte ^= 1u8 << self.rng.below(8);
                self.stats.corrupted += 1;
                tracing::debug!(byte = at, "fault: fast read block corrupted");
            }
        }
        let rdt = self.servos[first].return_delay();
        let at = if self.config.wire_timing {
            let start = done.max(self.line_free) + rdt + latency;
            let end = start + self.byte_time() * bytes.len() as u32;
            self.line_free = end;
            end
        } else {
            done + latency
        };
        self.stats.replies += 1;
        Some(Reply {
            at,
            id: BROADCAST_ID,
            bytes,
        })
    }

    /// Indices of the servos on the bus that hear a packet for `id` (broadcast: all).
    fn listeners(&self, id: u8) -> Vec<usize> {
        (0..self.servos.len())
            .filter(|&i| self.hears(i) && (id == BROADCAST_ID || self.servos[i].id() == id))
            .collect()
    }

    /// A servo hears the bus unless it went silent, is booting or runs at another rate than
    /// the line.
    fn hears(&self, index: usize) -> bool {
        self.servos.get(index).is_some_and(|s| {
            !s.is_silent()
                && !s.is_booting()
                && BAUD_RATES.get(usize::from(s.baud_index())) == Some(&self.line_baud)
        })
    }

    fn find(&self, id: u8) -> Option<usize> {
        self.servos
            .iter()
            .position(|s| s.id() == id)
            .filter(|&i| self.hears(i))
    }

    /// Whether a servo answers `instruction` at its Status Return Level.
    fn answers(servo: &Servo, instruction: u8) -> bool {
        match instruction {
            ins::PING => true,
            ins::READ
            | ins::SYNC_READ
            | ins::FAST_SYNC_READ
            | ins::BULK_READ
            | ins::FAST_BULK_READ => servo.status_return_level() >= 1,
            _ => servo.status_return_level() >= 2,
        }
    }

    fn status(&self, index: usize, code: u8, params: &[u8]) -> Outgoing {
        let servo = &self.servos[index];
        Outgoing {
            index,
            bytes: protocol::encode_status(servo.id(), servo.status_error(code), params),
            slot_wait: Duration::ZERO,
        }
    }

    fn crc_error(&mut self, id: u8, instruction: u8) -> Vec<Outgoing> {
        if id == BROADCAST_ID {
            return Vec::new();
        }
        match self.find(id) {
            Some(i) if Self::answers(&self.servos[i], instruction) => {
                vec![self.status(i, error::CRC, &[])]
            }
            _ => Vec::new(),
        }
    }

    /// Execute one instruction; return the replies in bus order.
    fn dispatch(&mut self, p: &Packet, now: Instant) -> Vec<Outgoing> {
        match p.instruction {
            protocol::STATUS => Vec::new(),
            ins::SYNC_READ => self.sync_read(p, now),
            ins::SYNC_WRITE => self.sync_write(p, now),
            ins::BULK_READ => self.bulk_read(p, now),
            ins::BULK_WRITE => self.bulk_write(p, now),
            _ => {
                let broadcast = p.id == BROADCAST_ID;
                let mut targets = self.listeners(p.id);
                // Broadcast ping replies come in id order, each servo in its slot.
                targets.sort_by_key(|&i| self.servos[i].id());
                let mut next_slot = 1u8;
                let mut out = Vec::new();
                for i in targets {
                    self.servos[i].touch(now);
                    // Decided before executing: the write that changes the Status Return
                    // Level is answered under the old level.
                    let answers = (!broadcast || p.instruction == ins::PING)
                        && Self::answers(&self.servos[i], p.instruction);
                    if let Some((code, data, after)) = self.unicast(i, p, broadcast, now) {
                        if answers {
                            let mut status = self.status(i, code, &data);
                            if broadcast {
                                let id = self.servos[i].id();
                                let empty = id.saturating_sub(next_slot);
                                status.slot_wait = BROADCAST_PING_SLOT * u32::from(empty);
                                next_slot = id.saturating_add(1);
                            }
                            out.push(status);
                        }
                        after(&mut self.servos[i], now);
                    }
                }
                out
            }
        }
    }

    /// One single-servo instruction. Returns the status (error code, data) and what to do
    /// after the reply is built (reboot and factory reset answer first, then restart); `None`
    /// when the instruction is ignored.
    #[allow(clippy::type_complexity)]
    fn unicast(
        &mut self,
        i: usize,
        p: &Packet,
        broadcast: bool,
        now: Instant,
    ) -> Option<(u8, Vec<u8>, Box<dyn FnOnce(&mut Servo, Instant)>)> {
        let nothing: Box<dyn FnOnce(&mut Servo, Instant)> = Box::new(|_, _| {});
        let boot_time = self.config.boot_time;
        let servo = &mut self.servos[i];
        let params = &p.params;
        let ok_or = |r: Result<(), u8>| r.err().unwrap_or(error::NONE);
        Some(match p.instruction {
            ins::PING => {
                let [lo, hi] = servo.table().model_number.to_le_bytes();
                (error::NONE, vec![lo, hi, servo.firmware()], nothing)
            }
            ins::READ => {
                if params.len() != 4 {
                    return Some((error::DATA_LENGTH, Vec::new(), nothing));
                }
                let address = u16::from_le_bytes([params[0], params[1]]);
                let len = u16::from_le_bytes([params[2], params[3]]);
                match servo.read(address, len) {
                    Ok(data) => (error::NONE, data, nothing),
                    Err(code) => (code, Vec::new(), nothing),
                }
            }
            ins::WRITE | ins::REG_WRITE => {
                if params.len() < 3 {
                    return Some((error::DATA_LENGTH, Vec::new(), nothing));
                }
                let address = u16::from_le_bytes([params[0], params[1]]);
                let data = &params[2..];
                let r = if p.instruction == ins::WRITE {
                    servo.write(address, data, now)
                } else {
                    servo.reg_write(address, data)
                };
                (ok_or(r), Vec::new(), nothing)
            }
            ins::ACTION => {
                if !params.is_empty() {
                    return Some((error::DATA_LENGTH, Vec::new(), nothing));
                }
                (ok_or(servo.action(now)), Vec::new(), nothing)
            }
            ins::REBOOT => (
                error::NONE,
                Vec::new(),
                Box::new(move |s: &mut Servo, t| s.reboot(t, boot_time)),
            ),
            ins::FACTORY_RESET => {
                let option = match params.as_slice() {
                    [o @ (0x01 | 0x02 | 0xFF)] => *o,
                    [_] => return Some((error::DATA_RANGE, Vec::new(), nothing)),
                    _ => return Some((error::DATA_LENGTH, Vec::new(), nothing)),
                };
                if broadcast && option == 0xFF {
                    // The e-manual: a broadcast reset-all is not carried out.
                    return None;
                }
                (
                    error::NONE,
                    Vec::new(),
                    Box::new(move |s: &mut Servo, t| s.factory_reset(option, t, boot_time)),
                )
            }
            ins::CONTROL_TABLE_BACKUP if servo.knows_backup() => match params.as_slice() {
                [0x01, 0x43, 0x54, 0x52, 0x4C] => {
                    (ok_or(servo.store_backup()), Vec::new(), nothing)
                }
                [0x02, 0x43, 0x54, 0x52, 0x4C] => match servo.check_restore_backup() {
                    Err(code) => (code, Vec::new(), nothing),
                    // Answered first, then the EEPROM comes back and the servo reboots.
                    Ok(()) => (
                        error::NONE,
                        Vec::new(),
                        Box::new(move |s: &mut Servo, t| s.restore_backup(t, boot_time)),
                    ),
                },
                _ => return Some((error::DATA_RANGE, Vec::new(), nothing)),
            },
            ins::CLEAR if servo.table().has_clear => {
                if params.as_slice() != [0x01, 0x44, 0x58, 0x4C, 0x22] {
                    return Some((error::DATA_RANGE, Vec::new(), nothing));
                }
                (ok_or(servo.clear_multi_turn(now)), Vec::new(), nothing)
            }
            _ => (error::INSTRUCTION, Vec::new(), nothing),
        })
    }

    fn sync_read(&mut self, p: &Packet, now: Instant) -> Vec<Outgoing> {
        match sync_reads(&p.params) {
            Some(reads) if p.id == BROADCAST_ID => self.reads(&reads, p.instruction, now),
            _ => Vec::new(),
        }
    }

    fn bulk_read(&mut self, p: &Packet, now: Instant) -> Vec<Outgoing> {
        match bulk_reads(&p.params) {
            Some(reads) if p.id == BROADCAST_ID => self.reads(&reads, p.instruction, now),
            _ => Vec::new(),
        }
    }

    /// Replies of a sync/bulk read, in the order the ids appear in the packet.
    fn reads(&mut self, reads: &[(u8, u16, u16)], instruction: u8, now: Instant) -> Vec<Outgoing> {
        let mut out = Vec::new();
        for &(id, address, len) in reads {
            let Some(i) = self.find(id) else { continue };
            self.servos[i].touch(now);
            if !Self::answers(&self.servos[i], instruction) {
                continue;
            }
            out.push(match self.servos[i].read(address, len) {
                Ok(data) => self.status(i, error::NONE, &data),
                Err(code) => self.status(i, code, &[]),
            });
        }
        out
    }

    fn sync_write(&mut self, p: &Packet, now: Instant) -> Vec<Outgoing> {
        if p.id != BROADCAST_ID || p.params.len() < 4 {
            return Vec::new();
        }
        let address = u16::from_le_bytes([p.params[0], p.params[1]]);
        let len = usize::from(u16::from_le_bytes([p.params[2], p.params[3]]));
        let body = &p.params[4..];
        if len == 0 || body.len() % (len + 1) != 0 {
            return Vec::new();
        }
        for chunk in body.chunks_exact(len + 1) {
            if let Some(i) = self.find(chunk[0]) {
                self.servos[i].touch(now);
                if let Err(code) = self.servos[i].write(address, &chunk[1..], now) {
                    tracing::debug!(id = chunk[0], code, "sync write refused");
                }
            }
        }
        Vec::new()
    }

    fn bulk_write(&mut self, p: &Packet, now: Instant) -> Vec<Outgoing> {
        if p.id != BROADCAST_ID {
            return Vec::new();
        }
        let mut writes = Vec::new();
        let mut rest = p.params.as_slice();
        while !rest.is_empty() {
            let [id, a0, a1, l0, l1, tail @ ..] = rest else {
                return Vec::new();
            };
            let len = usize::from(u16::from_le_bytes([*l0, *l1]));
            if len == 0 || tail.len() < len {
                return Vec::new();
            }
            writes.push((*id, u16::from_le_bytes([*a0, *a1]), &tail[..len]));
            rest = &tail[len..];
        }
        for (id, address, data) in writes {
            if let Some(i) = self.find(id) {
                self.servos[i].touch(now);
                if let Err(code) = self.servos[i].write(address, data, now) {
                    tracing::debug!(id, code, "bulk write refused");
                }
            }
        }
        Vec::new()
    }
}

/// The reads a Sync Read's parameters ask for: (id, address, length) per listed id; `None` when
/// they name no servo.
fn sync_reads(params: &[u8]) -> Option<Vec<(u8, u16, u16)>> {
    let [a0, a1, l0, l1, ids @ ..] = params else {
        return None;
    };
    if ids.is_empty() {
        return None;
    }
    let address = u16::from_le_bytes([*a0, *a1]);
    let len = u16::from_le_bytes([*l0, *l1]);
    Some(ids.iter().map(|&id| (id, address, len)).collect())
}

/// The reads a Bulk Read's parameters ask for: (id, address, length) per 5-byte entry; `None`
/// when they are empty, cut short, or name an id twice (the e-manual: one read per servo).
fn bulk_reads(params: &[u8]) -> Option<Vec<(u8, u16, u16)>> {
    if params.is_empty() || params.len() % 5 != 0 {
        return None;
    }
    let reads: Vec<(u8, u16, u16)> = params
        .chunks_exact(5)
        .map(|c| {
            (
                c[0],
                u16::from_le_bytes([c[1], c[2]]),
                u16::from_le_bytes([c[3], c[4]]),
            )
        })
        .collect();
    let mut ids: Vec<u8> = reads.iter().map(|r| r.0).collect();
    ids.sort_unstable();
    if ids.windows(2).any(|w| w[0] == w[1]) {
        return None;
    }
    Some(reads)
}
