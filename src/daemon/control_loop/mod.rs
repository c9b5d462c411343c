//! The control loop's thread: start-up, the fixed-rate cycle, and a shut-down that runs on every
//! exit, a panic included.
//!
//! The loop is held as parts, each owning one concern, and `Cycle` only keeps their order:
//! - [`port`]: the bus (generic over [`ServoBus`]), reopening it, the Bus Watchdog's contact;
//! - [`health`]: pure: each servo's error budget in time, its fault, its warnings;
//! - [`supervisor`]: the arm's mode as one enum (operating, torque off, fault, estop) and the
//!   shut-down;
//! - [`ledger`]: the active and last command, and the event each ending owes its sender;
//! - [`measure`]: this tick's measurements in SI units;
//! - the statistics ([`crate::daemon::stats::Stats`], one reset).
//!
//! Each tick, in this order: start a `goto` or `path` whose routes were planned beside the loop
//! (module `planner`: those that need more work than a tick can spare), apply the queued
//! commands (in arrival order, `stop` and `estop` from their own queue merged in by arrival; the
//! estop latch is checked per command, so nothing queued after an `estop` can undo it), tend the
//! port (reopen a lost one, recover from a stall past the Bus Watchdog), decide (motion -> resolve ->
//! joint-speed limit, [`Controller::tick`]; frozen while the supervisor holds the arm), write
//! the goals (one Sync Write through the limits wrapper), read (one Sync Read of Present
//! Velocity and Position every `read_every`-th tick, its wait capped at the end of the tick;
//! the next tick decides on it), tend a `reboot` under way in the rest of the tick (ping its
//! booting servos; once all are back, bring the arm up and answer it), publish the telemetry (latest wins; and, when the run is
//! recorded, hand a copy to the recorder, [`crate::record::tap`]), then answer the commands
//! applied in this tick. A `reboot`, or a command planned beside the loop, is answered when that
//! work ends, in the tick that ends it and before the events about it (its sender told, when
//! the loop took it, that the answer comes later). A tick that runs late makes the loop skip the periods it missed
//! (counted as overruns), never catch up in a burst. The wait for the next period sleeps to
//! [`SPIN_TAIL`](snakectl_sim::clock::SPIN_TAIL) before it and spins the rest
//! ([`Clock::sleep_until`]), and the loop's thread and its ports' run with a timer slack of
//! 1 ns ([`crate::servo::clock::sharp_timers`]): a tick starts on time. Once warm a tick allocates
//! nothing unless a command or an event needs it.
//!
//! Time comes from an injected [`Clock`] and the servos from any [`ServoBus`]: the daemon runs
//! on the real port and the wall clock, the tests on an in-memory bus and a manual clock.
//!
//! Faults (a protective stop: hold and report, see the fault matrix in the docs):
//! - a servo is declared `silent` only once it has gone `control.max_silence_ms` without a valid
//!   reply (an error budget: a lost or damaged reply is counted, never a hold);
//! - a reply with the alert flag: Hardware Error Status is read and the servo is held in
//!   `hardware_error` until `reboot`;
//! - the serial port failing (an error of class `Bus`): `port`, reopened once a second;
//! - a stall of the loop longer than the Bus Watchdog (the process stopped): the watchdogs
//!   that fired are cleared, goals := the measured pose, re-armed (`watchdog`, recovered at
//!   once); the same for a watchdog found fired (-1) by the health rotation's read of it
//!   with no stall the loop measured (the servos saw a longer gap than the loop did);
//! - a recovery leaves a servo in hardware error out of its torque on (it refuses it until
//!   `reboot`), so the other faults clear as they would alone;
//! - a servo back from silence with its RAM at the defaults (it lost power): `power_loss`, the
//!   arm latched as by an estop, its RAM written again, torque only on `reset`;
//! - a joint's load above its `[world] contact_load` on every health read for `contact_ms`:
//!   `contact`, the command ended `fault`, goals := the measured pose (it stops pushing), the
//!   arm latched as by an estop with torque on; `reset` releases it and clears the fault.
//!
//! The fault path never holds the tick longer than a period: its exchanges wait at most to the
//! end of the tick and are not sent again past it, and servos known silent are not waited on
//! (torque off is one Sync Write, confirmed by the servos that answer).
//!
//! While a fault holds, the controller is frozen and motion commands are refused (`fault`);
//! once every fault has cleared, goals := the measured pose (tripped watchdogs cleared first)
//! and the arm holds: it never resumes the command the fault interrupted. Present
//! Current/Load, Input Voltage and Temperature ride along in every read: bring-up maps them
//! with Velocity and Position through Indirect Address into one block of 13 bytes
//! ([`Layout::Indirect`]), so every tick costs the same. Where the servos' models do not
//! share an Indirect Data address, the read extends to them (one contiguous Sync Read of 21
//! bytes) at tick 0, before any client is served, and every `control.health_every`-th tick
//! after. A `warning` event comes before the servo's own temperature and voltage limits.

mod commands;
mod faults;
pub mod health;
pub mod ledger;
pub mod measure;
mod planner;
pub mod port;
pub mod supervisor;
#[cfg(test)]
mod tests;

use std::collections::{BTreeSet, VecDeque};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::oneshot;

use crate::chain::Vec2;
use crate::config::Config;
use crate::connect::{self, ArmConnection};
use crate::control::{self, Activity, Controller, NotClear};
use crate::protocol::{
    Answer, ClientId, Describe, Event, FaultChange, FaultInfo, RequestId, StopReason, Telemetry,
    What,
};
use crate::record::Tap;
use crate::servo::arm::{Arm, BringUpOptions, OnExit, Within};
use crate::servo::clock::{Clock, RealClock};
use crate::servo::dynamixel::DynamixelBus;
use crate::servo::limits::Limited;
use crate::servo::ports::Ports;
use crate::servo::{units, Goal, Layout, ReadKind, ServoBus, States};

use self::health::{Budget, Change, Health};
use self::ledger::{Ended, Ledger};
use self::measure::Measured;
use self::port::{Opener, Port, ReopenError};
use self::supervisor::Supervisor;
use super::link::{self, Handle, LoopEnds, COMMAND_QUEUE, STOP_QUEUE};
use super::stats::Stats;
use super::{DaemonError, RunOptions, Summary};

/// Longest a shut-down waits for the arm to come to rest before it lets go anyway.
const STOP_TIMEOUT: Duration = Duration::from_secs(10);

/// What the last exchanges of a shut-down (leaving the servos as `[bus] on_exit` says) may
/// take: the servos that answer confirm in a few milliseconds, and a silent one is not waited
/// on, so this bounds only a bus that fails meanwhile.
const SHUT_DOWN_WITHIN: Duration = Duration::from_millis(250);

/// Start-up on the calling thread (open the bus, bring the arm up), then the cycle until `stop`
/// is set and the arm is at rest, then shut-down. `ready` receives the socket side's handle once
/// the arm holds its pose, or the reason start-up failed.
pub(super) fn main(
    config: Config,
    options: RunOptions,
    stop: Arc<AtomicBool>,
    ready: oneshot::Sender<Result<Handle, DaemonError>>,
    tap: Option<Tap>,
) -> Result<Summary, DaemonError> {
    crate::servo::clock::sharp_timers();
    // Before the bus opens, so that the threads it starts (each port's, an embedded
    // simulator's) inherit the policy.
    let realtime = match config.control().realtime_priority {
        Some(priority) => {
            crate::beside::realtime(priority).map_err(|source| DaemonError::Realtime {
                path: config.path().to_path_buf(),
                source,
            })
        }
        None => Ok(()),
    };
    let started = realtime
        .and_then(|()| open(&config, options))
        .and_then(|parts| Cycle::new(&config, parts));
    let (mut cycle, handle) = match started {
        Ok(started) => started,
        Err(e) => {
            let _ = ready.send(Err(e));
            return Err(DaemonError::StartUpReported);
        }
    };
    if let Some(tap) = tap {
        cycle.set_tap(tap);
    }
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        // Tick 0: one full read, so the first snapshot a client sees is measured, health
        // included, never the placeholder the channel was made with.
        cycle.read_everything();
        // A `run` that stopped waiting is not this thread's problem: it shuts down below.
        if ready.send(Ok(handle)).is_ok() {
            tracing::info!("the arm holds its pose: serving commands");
        }
        cycle.run(&stop);
    }));
    cycle.shut_down(outcome.is_err())
}

/// The real ports the config names, on the wall clock, reopened the same way when one
/// vanishes.
fn open(
    config: &Config,
    options: RunOptions,
) -> Result<Parts<Ports<DynamixelBus>, RealClock>, DaemonError> {
    let options = connect::Options {
        ports: options.ports,
        ..connect::Options::default()
    };
    // What to reopen if a port vanishes: the given ports, `[bus]`'s, or the in-process
    // simulators' links, which survive a disconnect as a USB adapter's by-id link does.
    let ArmConnection {
        bus,
        arm,
        sims,
        ports,
    } = connect::open_arm(config, options)?;
    let name = |p: &std::path::Path| p.display().to_string();
    let port = match ports.as_slice() {
        [(one, _)] => Some(name(one)),
        _ => None,
    };
    let servo_ports = if ports.len() > 1 {
        ports
            .iter()
            .flat_map(|(path, ids)| ids.iter().map(move |&id| (id, name(path))))
            .collect()
    } else {
        Vec::new()
    };
    let baud = bus.baud();
    let adapter = config.modelled_adapter();
    let config_path = config.path().to_path_buf();
    // Only the ports that failed: the others stay open and locked, their servos reachable.
    let opener: Opener<Ports<DynamixelBus>> = Box::new(
        move |_: &Arm, bus: &mut Limited<Ports<DynamixelBus>>| -> Result<(), ReopenError> {
            bus.reopen_failed(|k| match ports.get(k) {
                Some((path, _)) => connect::open_port_of_several(path, baud, adapter),
                None => Err(connect::ConnectError::NoBus {
                    path: config_path.clone(),
                }),
            })?;
            Ok(())
        },
    );
    Ok(Parts {
        bus,
        port,
        servo_ports,
        arm,
        opener,
        clock: RealClock,
        sims,
    })
}

/// What a [`Cycle`] runs on.
pub(crate) struct Parts<B: ServoBus, C: Clock> {
    /// The bus, limited to the joint limits, not yet brought up.
    pub bus: Limited<B>,
    /// The port's path, for the fault reports (`None`: not known, or several ports).
    pub port: Option<String>,
    /// With several ports, each servo's port (id, path), for the fault reports; empty with one.
    pub servo_ports: Vec<(u8, String)>,
    /// The joints and bus settings.
    pub arm: Arm,
    /// Opens the bus again after the port vanished.
    pub opener: Opener<B>,
    /// Where time comes from.
    pub clock: C,
    /// The in-process simulators to keep alive as long as the loop.
    pub sims: Vec<snakectl_sim::SimHandle>,
}

/// The loop's fixed timing.
#[derive(Debug, Clone, Copy)]
struct Schedule {
    period: Duration,
    dt: f64,
    read_every: u64,
    health_every: u64,
    reply_timeout: Duration,
    /// How long the read of a tick that starts late waits for its replies: `reply_timeout`,
    /// but at most half the Bus Watchdog's period. A lost reply with a longer wait kept the
    /// bus silent past the watchdog (a reply timeout of 100 ms and a watchdog of 100 ms: every
    /// servo's fired after two dropped replies in a row).
    late_wait: Duration,
    /// A `velocity` that waited longer than this is not applied.
    deadman: Duration,
}

/// What the controller made of this tick, for telemetry.
#[derive(Debug, Clone, Copy, Default)]
struct Decided {
    tip_ref: Vec2,
    saturated: bool,
    self_collision: bool,
    /// The step was cut short to keep clear of the obstacles.
    blocked: bool,
    /// The clearance of the commanded pose, m (`None`: no obstacles).
    min_clearance_m: Option<f64>,
    solve_us: f64,
}

impl Decided {
    /// A tick in which the controller did not run: the reference stays, nothing else happened
    /// (the pose's clearance is looked at again: a reseed or a world change may have moved it).
    fn frozen(self) -> Decided {
        Decided {
            tip_ref: self.tip_ref,
            ..Decided::default()
        }
    }
}

/// The fault and warning lists telemetry carries, rebuilt when one changes.
#[derive(Debug, Default)]
struct Lists {
    faults: Vec<FaultInfo>,
    warnings: Vec<FaultInfo>,
    changed: bool,
}

/// An answer to send once this tick's telemetry is out.
enum Pending {
    Ready(Answer),
    /// `status`: the telemetry of the tick that applied it.
    Status,
    /// `reboot`: answered once its servos have booted and the arm is up again (see
    /// [`commands::Rebooting`]), ticks later.
    Rebooting,
    /// `goto` or `path` whose routes are planned beside the loop: answered once they are (see
    /// [`commands::Planning`]), ticks later.
    Planning,
}

/// Where the fixed-rate schedule stands between two ticks.
#[derive(Debug, Clone, Copy)]
struct Pace {
    /// When the next tick is due.
    deadline: Instant,
    /// When the shut-down began.
    stop_since: Option<Instant>,
}

/// The loop: its parts and the buffers it reuses.
pub(crate) struct Cycle<B: ServoBus, C: Clock> {
    port: Port<B>,
    arm: Arm,
    clock: C,
    /// Keeps the in-process simulators alive as long as the loop.
    _sims: Vec<snakectl_sim::SimHandle>,
    controller: Controller,
    ends: LoopEnds,
    health: Health,
    supervisor: Supervisor,
    ledger: Ledger,
    stats: Stats,
    measured: Measured,
    decided: Decided,
    lists: Lists,
    schedule: Schedule,
    goals: Vec<Goal>,
    states: States,
    /// Where the servos' present values are read: through Indirect Address, every read
    /// carries the health registers.
    layout: Layout,
    /// Joints whose read showed their Indirect Address mapping reset (their RAM was lost):
    /// looked at by the fault path as servos back from a power loss.
    unmapped: Vec<usize>,
    pending: Vec<(oneshot::Sender<Answer>, Pending)>,
    /// This tick's `stop`s and `estop`s, merged with the other commands by arrival.
    stops: VecDeque<link::Envelope>,
    /// When the lines of the commands applied in this tick were read.
    received: Vec<Instant>,
    home: Vec<f64>,
    ids: Vec<u8>,
    on_exit: OnExit,
    tick: u64,
    /// No recovery is tried before this instant, after one failed.
    recover_after: Option<Instant>,
    /// Servos whose Bus Watchdog a recovery cut short left cleared (see
    /// [`Arm::recover_watchdog`]): a 0 there is not taken for a power loss.
    unarmed: BTreeSet<u8>,
    /// Servos whose fired Bus Watchdog a recovery cleared and armed again, that recovery
    /// failing at a later step: named by the recovery (or `reset`) that completes.
    rearmed: BTreeSet<u8>,
    /// Until when the fault path of this tick may wait on the bus (see [`Cycle::within`]).
    fault_until: Instant,
    /// Servos a torque off did not reach: switched off once they answer a read.
    torque_off_pending: Vec<u8>,
    /// `[bus] watchdog_ms` arms the servos' Bus Watchdog: the health rotation reads it.
    watching: bool,
    /// Servos whose Bus Watchdog a read found fired (-1), the loop having measured no stall
    /// past it: recovered at the start of the next tick (see [`Cycle::check_fired`]).
    fired: Vec<u8>,
    /// Without Indirect Address, the servo whose Bus Watchdog the next health turn reads.
    watch_next: usize,
    /// While a port of several is lost, the servos on the others, read every tick.
    reachable: commands::Reachable,
    /// The commanded pose was not clear of an obstacle when last looked at (a `not_clear`
    /// event went out; a `clear` one is owed once it is).
    not_clear: bool,
    /// The loop ran behind its configured rate when last looked at (see [`Stats::behind`]).
    behind: bool,
    /// The last tick ran past its period: this one starts at once, back to back.
    late_start: bool,
    /// The highest rate the wire allows this arm, Hz, for the log lines.
    wire_bound_hz: f64,
    /// The recorder's hand-over: every tick's snapshot and every event are offered to it.
    tap: Option<Tap>,
    /// A `reboot` whose servos are booting.
    rebooting: Option<commands::Rebooting>,
    /// A `goto` or `path` whose routes are planned beside the loop.
    planning: Option<commands::Planning>,
    /// Where they are planned.
    planner: planner::Planner,
}

impl<B: ServoBus, C: Clock> Cycle<B, C> {
    /// Brings the arm up on `parts` (holding its present pose) and makes the loop and the
    /// socket side's handle.
    pub(crate) fn new(config: &Config, parts: Parts<B, C>) -> Result<(Self, Handle), DaemonError> {
        let Parts {
            mut bus,
            port,
            servo_ports,
            arm,
            opener,
            clock,
            sims,
        } = parts;
        let brought = arm.bring_up_with_clock(&mut bus, BringUpOptions::default(), &clock)?;
        tracing::info!(
            servos = brought.servos.len(),
            retries = brought.retries,
            read = ReadKind::name_of_ports(&brought.reads),
            reads = ?brought.reads,
            "arm up, holding its present pose"
        );
        let c = config.control();
        let limits = control::Limits {
            max_tip_speed_m_s: c.max_tip_speed_m_s,
            max_tip_accel_m_s2: c.max_tip_accel_m_s2,
            max_joint_speed_rad_s: c.max_joint_speed_rad_s,
            deadman_s: c.deadman.as_secs_f64(),
        };
        let home = config.home().to_vec();
        let mut controller = Controller::new(
            config.chain().clone(),
            limits,
            c.strategy,
            home.clone(),
            &brought.pose,
        )
        .map_err(DaemonError::Controller)?;
        if let Some(contact) = controller.self_contact() {
            tracing::warn!("{contact}");
        }
        // Goals reach the servos in whole ticks: the rounded pose must keep clear too.
        let tick_rad = std::f64::consts::TAU / crate::servo::units::TICKS_PER_TURN;
        controller
            .set_joint_resolution(&vec![tick_rad; arm.joints().len()])
            .map_err(DaemonError::Controller)?;
        // The config's world: its home pose is clear, but the arm starts where it stands.
        if let Some(not_clear) = controller.set_world(config.world().clone()) {
            tracing::warn!("the measured start pose is not clear: {not_clear}");
        }
        // The channel's first value is never seen: tick 0 publishes a measured snapshot
        // before `ready` hands the handle to anyone who could read it.
        let describe = Describe {
            read: ReadKind::name_of_ports(&brought.reads).to_owned(),
            ..describe(config, &arm).with_world(controller.world())
        };
        let (handle, ends) = link::channel(describe, Telemetry::default());
        let period = Duration::from_secs_f64(1.0 / c.rate_hz);
        let schedule = Schedule {
            period,
            dt: period.as_secs_f64(),
            read_every: u64::from(c.read_every.max(1)),
            health_every: u64::from(c.health_every.max(1)),
            reply_timeout: arm.settings().reply_timeout,
            late_wait: units::watchdog_period(arm.settings().watchdog_ms)
                .map_or(arm.settings().reply_timeout, |w| {
                    arm.settings().reply_timeout.min(w / 2)
                }),
            deadman: c.deadman,
        };
        let ids = arm.ids();
        let n_servos = ids.len();
        let layout = arm.layout();
        match layout {
            Layout::Indirect { data, .. } => tracing::info!(
                indirect_data = data,
                "every read carries load, voltage and temperature (Indirect Address)"
            ),
            Layout::Direct(_) => tracing::info!(
                health_every = c.health_every,
                "the servos' models do not share an Indirect Data address: load, voltage and \
                 temperature are read every `control.health_every`-th tick"
            ),
        }
        let budget = Budget {
            max_silence: c.max_silence,
            read_interval: period * c.read_every.max(1),
        };
        let mut health = Health::new(
            &ids,
            &faults::health_limits(&arm, &mut bus),
            budget,
            port.clone(),
        );
        health.set_contact(config.contact(), period);
        if !servo_ports.is_empty() {
            health.set_ports(&servo_ports);
        }
        let wires = config.wire(&brought.reads, &bus.adapters());
        let wire = crate::servo::wire::bound_of_ports(&wires);
        let wire_bound_hz = wire.map_or(f64::INFINITY, |b| b.rate_hz());
        if let Some(b) = wire {
            tracing::info!(
                rate_hz = c.rate_hz,
                wire_bound_hz = b.rate_hz(),
                wire_tick_us = b.tick.as_secs_f64() * 1e6,
                ports = wires.len(),
                read = ReadKind::name_of_ports(&brought.reads),
                "control loop at {:.0} Hz; the wire allows this arm at most {:.0} Hz \
                 ({} bytes a tick on its busiest port{})",
                c.rate_hz,
                b.rate_hz(),
                b.bytes(),
                if b.hold.is_zero() {
                    String::new()
                } else {
                    format!(
                        ", and {:.1} ms of the adapter's latency timer",
                        b.hold.as_secs_f64() * 1e3
                    )
                },
            );
            if c.rate_hz > b.rate_hz() {
                tracing::warn!(
                    "control.rate_hz = {:.0} is above the wire bound of {:.0} Hz: the loop will \
                     run back to back at the rate its exchanges allow",
                    c.rate_hz,
                    b.rate_hz()
                );
            }
        }
        let now = clock.now();
        let watchdog = units::watchdog_period(arm.settings().watchdog_ms);
        let mut stats = Stats::new(now);
        stats.counters.retries = u64::from(brought.retries);
        let cycle = Self {
            port: Port::new(bus, port, opener, watchdog, now),
            measured: Measured::new(&arm, &brought.pose),
            decided: Decided {
                tip_ref: controller.chain().tip(&brought.pose),
                min_clearance_m: controller.min_clearance(),
                ..Decided::default()
            },
            goals: vec![Goal { id: 0, ticks: 0 }; ids.len()],
            on_exit: arm.settings().on_exit,
            arm,
            clock,
            _sims: sims,
            controller,
            ends,
            health,
            supervisor: Supervisor::new(),
            ledger: Ledger::new(),
            stats,
            lists: Lists::default(),
            schedule,
            states: States::new(),
            layout,
            unmapped: Vec::new(),
            pending: Vec::with_capacity(COMMAND_QUEUE + STOP_QUEUE),
            stops: VecDeque::with_capacity(STOP_QUEUE),
            received: Vec::with_capacity(COMMAND_QUEUE + STOP_QUEUE),
            home,
            ids,
            tick: 0,
            recover_after: None,
            unarmed: BTreeSet::new(),
            rearmed: BTreeSet::new(),
            fault_until: now,
            torque_off_pending: Vec::new(),
            watching: watchdog.is_some(),
            fired: Vec::with_capacity(n_servos),
            watch_next: 0,
            reachable: commands::Reachable::with_capacity(n_servos),
            not_clear: false,
            behind: false,
            late_start: false,
            wire_bound_hz,
            tap: None,
            rebooting: None,
            planning: None,
            planner: planner::Planner::default(),
        };
        Ok((cycle, handle))
    }

    /// Hands every tick's snapshot and every event from now on to a recorder.
    pub(crate) fn set_tap(&mut self, tap: Tap) {
        self.tap = Some(tap);
    }

    /// Ticks until `stop` is set and the arm has come to rest.
    fn run(&mut self, stop: &AtomicBool) {
        self.look_clear();
        let mut pace = Pace {
            deadline: self.clock.now(),
            stop_since: None,
        };
        while self.turn(&mut pace, stop.load(Ordering::Relaxed)) {}
        self.answer_queued_for_exit();
    }

    /// One turn of the schedule: a tick, then the wait for the next one. `stop`: the daemon is
    /// to shut down. False once the shut-down found the arm at rest (or gave up waiting).
    fn turn(&mut self, pace: &mut Pace, stop: bool) -> bool {
        let start = self.clock.now();
        let scheduled = pace.deadline;
        pace.deadline += self.schedule.period;
        if stop && !self.supervisor.exiting() {
            self.begin_exit();
            pace.stop_since = Some(start);
        }
        self.step(scheduled, pace.deadline);
        let now = self.clock.now();
        let late = now > pace.deadline;
        self.late_start = late;
        self.stats
            .record_tick(start, now.saturating_duration_since(start), late);
        if let Some(since) = pace.stop_since {
            // Held by the latch or a fault, the arm is at rest already: nothing moves it.
            let at_rest =
                !self.supervisor.moves() || self.controller.activity() == Activity::Holding;
            if at_rest || now.saturating_duration_since(since) > STOP_TIMEOUT {
                return false;
            }
        }
        if late {
            // Late: the periods missed are counted, never run in a catch-up burst; the next
            // tick starts at once and the schedule is anchored on it. Past the rate the work
            // allows, the loop so runs back to back at that rate rather than waiting for the
            // next whole period (which would halve it).
            let behind = now.duration_since(pace.deadline).as_nanos();
            let missed = (behind / self.schedule.period.as_nanos().max(1)) as u64 + 1;
            pace.deadline = now;
            if let Some((overruns, total)) = self.stats.overrun(missed, now) {
                tracing::warn!(overruns, total, "control loop overran its period");
            }
        }
        self.say_behind();
        self.wake_side();
        self.clock.sleep_until(pace.deadline);
        true
    }

    /// Wakes what waits for a tick's end (the Foxglove view, the Zenoh bridge, the recorder
    /// when a batch is whole), once the tick's work and time are done: waking a parked thread
    /// costs the waker a system call (here about 5 µs, up to tens), which stays out of the
    /// tick, and the side thread then runs in the idle rest of the period.
    fn wake_side(&self) {
        self.ends.tick_done.notify_waiters();
        if let Some(tap) = &self.tap {
            tap.wake();
        }
    }

    /// Logs when the loop falls behind its configured rate (more than half the last ticks ran
    /// late) and when it holds it again.
    fn say_behind(&mut self) {
        let behind = self.stats.behind();
        if behind == self.behind {
            return;
        }
        self.behind = behind;
        let rate_hz = 1.0 / self.schedule.period.as_secs_f64();
        let loop_hz = self.stats.rate_hz();
        if behind {
            tracing::warn!(
                rate_hz,
                loop_hz,
                wire_bound_hz = self.wire_bound_hz,
                "the loop cannot hold its rate: it runs back to back at the rate its work allows"
            );
        } else {
            tracing::info!(rate_hz, loop_hz, "the loop holds its rate again");
        }
    }

    /// The shut-down began: decelerate to rest before letting go.
    fn begin_exit(&mut self) {
        self.supervisor.begin_exit();
        self.abandon_reboot();
        self.abandon_planning();
        if self.supervisor.moves() {
            // A failure here cannot be worse than holding, which the next ticks do anyway.
            let _ = self.controller.command(control::Command::Stop);
            self.ledger.stopping(StopReason::Shutdown);
        }
        tracing::info!("stopping: bringing the arm to rest");
        self.event(None, None, |tip| What::ShuttingDown { tip });
    }

    /// One tick, scheduled at `scheduled`, ending by `deadline`.
    fn step(&mut self, scheduled: Instant, deadline: Instant) {
        self.tick += 1;
        self.set_fault_until(deadline);
        self.tend_planning();
        self.apply_commands();
        self.tend_port();
        if self.port.is_lost() {
            // Hold the goals until the port is back.
            self.decided = self.decided.frozen();
            self.decided.min_clearance_m = self.controller.min_clearance();
            if self.port.several() {
                // The other ports are still open: their servos are held on the goals, as
                // every tick, which keeps their Bus Watchdog fed (the lost port's part fails,
                // and is already reported), and read, so their pose and health stay current.
                self.write();
                self.read_if_due(scheduled, deadline);
            } else {
                self.received.clear();
            }
        } else {
            self.decide();
            self.write();
            if !self.port.is_lost() {
                self.read_if_due(scheduled, deadline);
            }
        }
        self.tend_reboot();
        self.publish();
        self.answer();
    }

    /// This tick's read, if it has one: the pose every `read_every` ticks, the health registers
    /// every `health_every` (or with every read, through Indirect Address), and with those
    /// every `health_every`-th time the Bus Watchdog ([`Cycle::watchdog_due`]).
    fn read_if_due(&mut self, scheduled: Instant, deadline: Instant) {
        let s = self.schedule;
        let read = self.tick % s.read_every == 0;
        let health = match self.layout {
            // The health registers ride along in every read's block.
            Layout::Indirect { .. } => read,
            Layout::Direct(_) => self.tick % s.health_every == 0,
        };
        if health || read {
            let watchdog = health && self.watchdog_due();
            self.read(scheduled, deadline, health, watchdog);
        }
    }

    /// Whether this tick's health read brings the Bus Watchdog too (when `[bus] watchdog_ms`
    /// arms it): every `health_every`-th read through Indirect Address (one byte a servo more
    /// on that read alone), every health read otherwise (one servo's, in turn).
    fn watchdog_due(&self) -> bool {
        let s = self.schedule;
        self.watching
            && match self.layout {
                Layout::Indirect { .. } => (self.tick / s.read_every) % s.health_every == 0,
                Layout::Direct(_) => true,
            }
    }

    /// Motion -> resolve -> joint-speed limit; frozen while the supervisor holds the arm.
    fn decide(&mut self) {
        if !self.supervisor.moves() {
            self.decided = self.decided.frozen();
            self.decided.min_clearance_m = self.controller.min_clearance();
            return;
        }
        let t0 = self.clock.now();
        let tick = self.controller.tick(self.schedule.dt);
        let solve = self.clock.now().saturating_duration_since(t0);
        self.stats
            .record_solve(solve, tick.peak_joint_speed_rad_s, tick.m3_rad2);
        self.decided = Decided {
            tip_ref: tick.tip_ref,
            saturated: tick.saturated,
            self_collision: tick.self_collision,
            blocked: tick.blocked.is_some(),
            min_clearance_m: tick.min_clearance_m,
            solve_us: solve.as_secs_f64() * 1e6,
        };
        if self.not_clear && self.controller.is_clear() {
            self.now_clear();
        }
        if tick.clamped {
            self.stats.counters.clamped += 1;
        }
        self.ledger
            .account(tick.peak_joint_speed_rad_s, tick.m3_rad2);
        if let Some(finish) = tick.finished {
            let ended = self.ledger.finish(finish);
            self.owe(ended);
        }
    }

    /// The goals, through the limits wrapper, in one Sync Write.
    fn write(&mut self) {
        let written = self
            .arm
            .goals_into(self.controller.theta(), &mut self.goals)
            .and_then(|()| self.port.bus().write_goals(&self.goals));
        let now = self.clock.now();
        match written {
            Ok(()) => self.port.contact(now),
            Err(e) => self.write_failed(&e),
        }
        for &r in &self.received {
            self.stats.record_latency(now.saturating_duration_since(r));
        }
        self.received.clear();
    }

    /// The fault path of a tick ending by `deadline` may wait on the bus until short of it, or,
    /// in a tick that started late, one period from now: never longer than a period, and the
    /// read, the publishing and the answers keep their share.
    fn set_fault_until(&mut self, deadline: Instant) {
        let now = self.clock.now();
        self.fault_until = deadline
            .max(now + self.schedule.period)
            .checked_sub(faults::READ_TAIL)
            .unwrap_or(now);
    }

    /// The time the fault path's exchanges may take, as a [`Within`]: an associated function, so
    /// it borrows the clock alone, beside the port's bus.
    fn within(clock: &C, until: Instant, timeout: Duration) -> Within<'_> {
        Within::new(clock, until, timeout)
    }

    /// Tick 0, before any client: every field of every servo, then a snapshot of it.
    fn read_everything(&mut self) {
        let now = self.clock.now();
        self.set_fault_until(now + self.schedule.period);
        self.read(now, now + self.schedule.period, true, self.watching);
        self.publish();
    }

    fn publish(&mut self) {
        let chain = self.controller.chain();
        let tip = chain.tip(self.controller.theta());
        let tip_meas = chain.tip(&self.measured.theta);
        let state = self.supervisor.state(self.controller.activity());
        // A command being planned beside the loop goes there already.
        let target = self
            .controller
            .target()
            .or_else(|| self.planning.as_ref().and_then(|p| p.target()))
            .map(|t| [t.x, t.y]);
        let command = self.ledger.info();
        let d = self.decided;
        let tracking = (d.tip_ref - tip_meas).norm();
        let (loop_hz, p99) = (self.stats.rate_hz(), self.stats.tick_p99_us());
        let strategy = self.controller.strategy();
        let (tick, t_s) = (self.tick, self.tick as f64 * self.schedule.dt);
        let theta_cmd = self.controller.theta();
        let m = &self.measured;
        let (overruns, peak, m3, counters) = (
            self.stats.overruns(),
            self.stats.peak_total(),
            self.stats.m3_total(),
            self.stats.counters,
        );
        let torque = self.supervisor.torque();
        let behind = self.behind;
        let lists = std::mem::take(&mut self.lists.changed)
            .then_some((&self.lists.faults, &self.lists.warnings));
        self.ends.telemetry.send_modify(|t| {
            t.tick = tick;
            t.t_s = t_s;
            t.state = state;
            t.strategy = strategy;
            t.tip_ref = [d.tip_ref.x, d.tip_ref.y];
            t.tip = [tip.x, tip.y];
            t.tip_meas = [tip_meas.x, tip_meas.y];
            t.target = target;
            copy(&mut t.theta_cmd, theta_cmd);
            copy(&mut t.theta_meas, &m.theta);
            copy(&mut t.omega_meas, &m.omega);
            t.tracking_error_m = tracking;
            t.saturated = d.saturated;
            t.self_collision = d.self_collision;
            t.min_clearance_m = d.min_clearance_m;
            t.blocked = d.blocked;
            t.command = command;
            t.solve_us = d.solve_us;
            t.loop_hz = loop_hz;
            t.tick_p99_us = p99;
            t.overruns = overruns;
            t.behind = behind;
            t.peak_joint_speed_rad_s = peak;
            t.m3_total_rad2 = m3;
            t.counters = counters;
            t.torque = torque;
            copy(&mut t.temperature_c, &m.temperature_c);
            copy(&mut t.voltage_v, &m.voltage_v);
            copy(&mut t.load, &m.load);
            copy(&mut t.load_unit, &m.load_unit);
            t.health_tick = m.health_tick;
            if let Some((faults, warnings)) = lists {
                t.faults.clone_from(faults);
                t.warnings.clone_from(warnings);
            }
        });
        if let Some(tap) = &self.tap {
            tap.offer_tick(&self.ends.telemetry.borrow());
        }
    }

    /// An event at this tick, with the commanded tip, to `owner` (`None`: everyone).
    fn event(
        &self,
        owner: Option<ClientId>,
        cmd_id: Option<RequestId>,
        what: impl FnOnce([f64; 2]) -> What,
    ) {
        let event = Event {
            owner,
            cmd_id,
            tick: self.tick,
            what: what(self.tip()),
        };
        if let Some(tap) = &self.tap {
            tap.offer_event(&event);
        }
        // No subscriber is not an error: nobody is listening.
        let _ = self.ends.events.send(event);
    }

    /// The commanded tip, for events.
    fn tip(&self) -> [f64; 2] {
        let tip = self.controller.chain().tip(self.controller.theta());
        [tip.x, tip.y]
    }

    /// The event a command's ending owes its sender, sent.
    fn owe(&self, ended: Option<Ended>) {
        if let Some(e) = ended {
            let world = self.controller.world();
            self.event(Some(e.owner), e.id, |tip| e.ending.what(tip, world));
        }
    }

    /// Whether the commanded pose is clear of the world (at start, or after the world
    /// changed): a `not_clear` event to everyone when it is not, a `clear` one when it is
    /// again after one. `cmd_id`: the request that changed the world.
    fn look_clear(&mut self) {
        self.look_clear_after(None, self.controller.not_clear());
    }

    /// [`Cycle::look_clear`] with what the controller said of the pose.
    fn look_clear_after(&mut self, cmd_id: Option<RequestId>, not_clear: Option<NotClear>) {
        match not_clear {
            Some(nc) => {
                tracing::warn!("{nc}");
                self.not_clear = true;
                self.event(None, cmd_id, |tip| What::NotClear {
                    tip,
                    link: nc.link,
                    obstacle: nc.obstacle,
                    clearance_m: nc.clearance_m,
                    keep_m: nc.keep_m,
                });
            }
            None if self.not_clear => self.now_clear(),
            None => {}
        }
    }

    /// The commanded pose is clear again: a `clear` event to everyone.
    fn now_clear(&mut self) {
        self.not_clear = false;
        let min_clearance_m = self.decided.min_clearance_m;
        tracing::info!(
            ?min_clearance_m,
            "the arm's pose is clear of the obstacles again"
        );
        self.event(None, None, |tip| What::Clear {
            tip,
            min_clearance_m,
        });
    }

    /// A fault or warning change: logged, sent to everyone, the lists rebuilt.
    fn report(&mut self, change: Change) {
        let Change { change, info } = change;
        // Absent fields (a port's own fault has no servo) are left out of the line.
        let (id, joint, port) = (info.id, info.joint, info.port.as_deref());
        match (info.kind.is_warning(), change) {
            (false, FaultChange::Raised) => tracing::warn!(
                id,
                joint,
                port,
                kind = %info.kind,
                "fault: {}",
                info.detail
            ),
            (false, _) => {
                tracing::info!(id, port, kind = %info.kind, "fault cleared: {}", info.detail)
            }
            (true, _) => tracing::warn!(
                id,
                port,
                kind = %info.kind,
                reason = %change,
                "health: {}",
                info.detail
            ),
        }
        self.announce(change, info);
        self.rebuild_lists();
    }

    /// A `fault` event, or a `warning` one for a warning's kind, to everyone.
    fn announce(&self, change: FaultChange, info: FaultInfo) {
        self.event(None, None, |tip| What::alarm(tip, change, info));
    }

    fn rebuild_lists(&mut self) {
        let (faults, warnings) = self.health.lists(self.port.faults());
        self.lists = Lists {
            faults,
            warnings,
            changed: true,
        };
    }

    /// The summary of the run, and the servos left as `[bus] on_exit` says (the shut-down
    /// guard: it runs whatever ended the cycle). The servos that do not answer are not waited
    /// on, and the whole takes at most [`SHUT_DOWN_WITHIN`]; a servo it could not reach is
    /// named in the error.
    fn shut_down(mut self, panicked: bool) -> Result<Summary, DaemonError> {
        let silent = if self.port.is_lost() && !self.port.several() {
            tracing::warn!("shut-down: the serial port is lost, no servo can be reached");
            self.ids.clone()
        } else {
            for lost in self.port.faults() {
                tracing::warn!(
                    "shut-down: {}; the servos on the other ports are still reached",
                    lost.detail
                );
            }
            let mut silent = self.health.unanswering();
            // Servos still booting from an abandoned reboot do not hear.
            silent.extend(self.rebooting.iter().flat_map(|r| r.booting()));
            silent
        };
        if self.late_start {
            // The loop ran back to back: replies its last read gave up on may still be on
            // their way; once in, the next instruction's send discards them instead of taking
            // them for its answer.
            self.clock
                .sleep(self.schedule.reply_timeout.min(SHUT_DOWN_WITHIN / 10));
        }
        let until = self.clock.now() + SHUT_DOWN_WITHIN;
        let within = Self::within(&self.clock, until, self.schedule.reply_timeout);
        let shut = self.arm.shut_down(self.port.bus(), &silent, &within);
        if panicked {
            if let Err(e) = shut {
                tracing::error!("shut-down after a panic of the loop: {e}");
            }
            return Err(DaemonError::LoopPanicked);
        }
        shut.map_err(DaemonError::ShutDown)?;
        Ok(self.stats.summary(self.tick, self.clock.now()))
    }
}

fn copy<T: Copy>(dst: &mut Vec<T>, src: &[T]) {
    dst.clear();
    dst.extend_from_slice(src);
}

/// The `describe` reply: what a remote UI needs to draw the arm.
pub(super) fn describe(config: &Config, arm: &Arm) -> Describe {
    Describe::of_chain(
        config.chain(),
        arm.ids(),
        arm.joints()
            .iter()
            .map(|j| j.model.name().to_owned())
            .collect(),
        config.home().to_vec(),
        config.control().rate_hz,
    )
}
