//! The control loop's thread: start-up, the fixed-rate cycle, and a shut-down that runs on every
//! exit, a panic included.
//!
//! Each tick, in this order: apply the queued commands (in arrival order; the estop latch is
//! checked per command, so nothing queued after an `estop` can undo it), motion -> resolve ->
//! joint-speed limit ([`Controller::tick`]), one Sync Write of the goals through the limits
//! wrapper, one Sync Read of Present Velocity and Position (every `read_every`-th tick, its wait
//! capped at the end of the tick), publish the telemetry (latest wins), then answer the
//! commands applied in this tick. A tick that runs late makes the loop skip the periods it
//! missed (counted as overruns), never catch up in a burst. Once warm a tick allocates nothing
//! unless a command or an event needs it.
//!
//! Faults (a protective stop: hold and report, see the README's fault matrix):
//! - a servo is declared `silent` only after `control.max_missed_reads` consecutive reads
//!   without its reply (an error budget: a lost or damaged reply is counted, never a hold);
//! - a reply with the alert flag: Hardware Error Status is read and the servo is held in
//!   `hardware_error` until `reboot`;
//! - the serial port failing (an error of class `Bus`): `port`, reopened once a second;
//! - a stall of the loop longer than the Bus Watchdog (the process stopped): the watchdogs
//!   that fired are cleared, goals := the measured pose, re-armed (`watchdog`, recovered at
//!   once).
//!
//! While a fault holds, the controller is frozen and motion commands are refused (`fault`);
//! once every fault has cleared, goals := the measured pose (tripped watchdogs cleared first)
//! and the arm holds: it never resumes the command the fault interrupted. At tick 0, before
//! any client is served, and every `control.health_every`-th tick after, the read extends to
//! Present Current/Load, Input Voltage and Temperature (one contiguous Sync Read), and a
//! `warning` event comes before the servo's own temperature and voltage limits.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::oneshot;

use crate::chain::Vec2;
use crate::config::Config;
use crate::connect::{self, Connection};
use crate::control::{self, Activity, Controller, Finish, Refused};
use crate::protocol::{
    Answer, ClientId, CmdName, Code, CommandInfo, Counters, Describe, Event, FaultChange,
    FaultInfo, FaultKind, LoadUnit, LoopCmd, Motion, Outcome, Rebooted, Rejection, Reply,
    RequestId, State, Status, StopReason, Telemetry, What,
};
use crate::servo::arm::{self, Arm, BringUpOptions, OnExit, Retry};
use crate::servo::clock::WallClock;
use crate::servo::dynamixel::DynamixelBus;
use crate::servo::limits::{Limited, Strategy as LimitStrategy};
use crate::servo::units::CurrentUnit;
use crate::servo::{
    units, ErrorClass, Fields, Goal, HardwareErrors, Register, ServoBus, ServoError, States,
};

use super::link::{self, Envelope, Handle, LoopEnds, COMMAND_QUEUE};
use super::stats::Histogram;
use super::{DaemonError, RunOptions, Summary};

/// Ticks the loop-rate and tick-time statistics look back over.
const WINDOW: usize = 1000;

/// Longest a shut-down waits for the arm to come to rest before it lets go anyway.
const STOP_TIMEOUT: Duration = Duration::from_secs(10);

/// The shortest wait for a reply the deadline cap leaves a read.
const MIN_READ_WAIT: Duration = Duration::from_micros(300);

/// What a read leaves of its tick for publishing and answering: a reply that never comes then
/// costs no overrun.
const READ_TAIL: Duration = Duration::from_micros(500);

/// How often a lost port is reopened, and a failed recovery tried again.
const RETRY_EVERY: Duration = Duration::from_secs(1);

/// A temperature warning this close below the servo's Temperature Limit, °C.
const TEMPERATURE_MARGIN_C: f64 = 5.0;

/// A voltage warning this close to the servo's Min/Max Voltage Limit, V.
const VOLTAGE_MARGIN_V: f64 = 0.5;

/// How far back outside its margin a temperature must come before the warning clears, °C.
const TEMPERATURE_HYSTERESIS_C: f64 = 1.0;

/// How far back outside its margin a voltage must come before the warning clears, V.
const VOLTAGE_HYSTERESIS_V: f64 = 0.1;

/// Start-up on the calling thread (open the bus, bring the arm up), then the cycle until `stop`
/// is set and the arm is at rest, then shut-down. `ready` receives the socket side's handle once
/// the arm holds its pose, or the reason start-up failed.
pub(super) fn main(
    config: Config,
    options: RunOptions,
    stop: Arc<AtomicBool>,
    ready: oneshot::Sender<Result<Handle, DaemonError>>,
) -> Result<Summary, DaemonError> {
    let (mut cycle, handle) = match Cycle::start(&config, options) {
        Ok(started) => started,
        Err(e) => {
            let _ = ready.send(Err(e));
            return Err(DaemonError::StartUpReported);
        }
    };
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        // Tick 0: one full read, so the first snapshot a client sees is measured, health
        // included, never the placeholder the channel was made with.
        cycle.read_everything();
        // A `run` that stopped waiting is not this thread's problem: it shuts down below.
        let _ = ready.send(Ok(handle));
        cycle.run(&stop);
    }));
    // The shut-down guard: whatever ended the cycle, leave the servos as `[bus] on_exit` says.
    let shut = cycle.arm.shut_down(&mut cycle.bus);
    match outcome {
        Ok(()) => {
            shut.map_err(DaemonError::ShutDown)?;
            Ok(cycle.summary())
        }
        Err(_) => {
            if let Err(e) = shut {
                tracing::error!("shut-down after a panic of the loop: {e}");
            }
            Err(DaemonError::LoopPanicked)
        }
    }
}

/// What the arm is doing in the eyes of a client: the command that moves it.
#[derive(Debug, Clone)]
struct Active {
    owner: ClientId,
    id: Option<RequestId>,
    kind: CmdName,
    outcome: Outcome,
    peak: f64,
    m3: f64,
}

impl Active {
    fn info(&self) -> CommandInfo {
        CommandInfo {
            kind: self.kind,
            id: self.id.clone(),
            outcome: self.outcome,
            peak_joint_speed_rad_s: self.peak,
            m3_rad2: self.m3,
        }
    }
}

/// What holds one joint's servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum JointFault {
    /// No reply to `max_missed_reads` consecutive reads.
    Silent,
    /// Its alert flag: a latched hardware error (the bits read, empty when unreadable).
    Hardware(HardwareErrors),
}

impl JointFault {
    fn kind(self) -> FaultKind {
        match self {
            JointFault::Silent => FaultKind::Silent,
            JointFault::Hardware(_) => FaultKind::HardwareError,
        }
    }
}

/// One joint's error budget, fault, warnings and the limits the warnings watch.
#[derive(Debug, Clone, Default)]
struct JointHealth {
    /// Consecutive reads without its reply.
    missed: u32,
    /// The tick of the first of them.
    first_miss: u64,
    /// The reply of this read carried the alert flag (handled after the read).
    alert: bool,
    /// What holds it, since which tick, why.
    fault: Option<(JointFault, u64, String)>,
    /// Temperature Limit (register 31), °C.
    temperature_limit_c: Option<f64>,
    /// Min and Max Voltage Limit (registers 34 and 32), V.
    voltage_limits_v: Option<(f64, f64)>,
    /// Active warnings: since which tick, and why.
    temperature_warning: Option<(u64, String)>,
    voltage_warning: Option<(u64, String)>,
}

/// The serial port failed; it is reopened every [`RETRY_EVERY`].
#[derive(Debug, Clone)]
struct PortLost {
    since: u64,
    next_try: Instant,
    detail: String,
}

/// Why reopening the port failed.
#[derive(Debug, thiserror::Error)]
enum ReopenError {
    /// Nothing says which port to open.
    #[error("no port to reopen is known")]
    NoPath,
    /// Opening it failed.
    #[error(transparent)]
    Open(#[from] connect::ConnectError),
    /// It opened, but the arm did not recover.
    #[error("the port opened, but the arm did not recover: {0}")]
    Recover(String),
}

/// An answer to send once this tick's telemetry is out.
enum Pending {
    Ready(Answer),
    /// `status`: the telemetry of the tick that applied it.
    Status,
}

/// Times of the last [`WINDOW`] ticks, in fixed buffers.
struct Window {
    starts: Vec<Instant>,
    work_us: Vec<f64>,
    scratch: Vec<f64>,
    next: usize,
    filled: usize,
    p99_us: f64,
}

impl Window {
    fn new(now: Instant) -> Self {
        Self {
            starts: vec![now; WINDOW],
            work_us: vec![0.0; WINDOW],
            scratch: vec![0.0; WINDOW],
            next: 0,
            filled: 0,
            p99_us: 0.0,
        }
    }

    fn record(&mut self, start: Instant, work_us: f64) {
        self.starts[self.next] = start;
        self.work_us[self.next] = work_us;
        self.next = (self.next + 1) % WINDOW;
        self.filled = (self.filled + 1).min(WINDOW);
        // The percentile is refreshed every tenth tick: a selection over 1000 values.
        if self.next % 10 == 0 {
            let n = self.filled;
            self.scratch[..n].copy_from_slice(&self.work_us[..n]);
            let k = ((n as f64) * 0.99).ceil() as usize;
            let k = k.clamp(1, n) - 1;
            let (_, p, _) = self.scratch[..n].select_nth_unstable_by(k, f64::total_cmp);
            self.p99_us = *p;
        }
    }

    /// Ticks per second over the window.
    fn rate_hz(&self) -> f64 {
        if self.filled < 2 {
            return 0.0;
        }
        let newest = self.starts[(self.next + WINDOW - 1) % WINDOW];
        let oldest = if self.filled == WINDOW {
            self.starts[self.next]
        } else {
            self.starts[0]
        };
        let span = newest.saturating_duration_since(oldest).as_secs_f64();
        if span > 0.0 {
            (self.filled - 1) as f64 / span
        } else {
            0.0
        }
    }

    fn clear(&mut self) {
        self.next = 0;
        self.filled = 0;
        self.p99_us = 0.0;
    }
}

/// The loop's state and every buffer it reuses.
struct Cycle {
    bus: Limited<DynamixelBus>,
    arm: Arm,
    /// Keeps an in-process simulator alive as long as the loop.
    _sim: Option<snakectl_sim::SimHandle>,
    controller: Controller,
    ends: LoopEnds,
    home: Vec<f64>,
    ids: Vec<u8>,
    goals: Vec<Goal>,
    states: States,
    theta_meas: Vec<f64>,
    omega_meas: Vec<f64>,
    pending: Vec<(oneshot::Sender<Answer>, Pending)>,
    /// When the lines of the commands applied in this tick were read.
    received: Vec<Instant>,
    period: Duration,
    dt: f64,
    read_every: u64,
    reply_timeout: Duration,
    on_exit: OnExit,
    tick: u64,
    estop: bool,
    stopping_for_exit: bool,
    active: Option<Active>,
    last: Option<Active>,
    /// The joint of the last jog, to tell a renewal from a new jog.
    last_jog: Option<usize>,
    tip_ref: Vec2,
    saturated: bool,
    self_collision: bool,
    solve_us: f64,
    overruns: u64,
    peak_total: f64,
    m3_total: f64,
    counters: Counters,
    window: Window,
    write_errors: u64,
    last_overrun_log: Option<Instant>,
    overruns_logged: u64,
    tick_hist: Histogram,
    solve_hist: Histogram,
    latency_hist: Histogram,
    /// Start of the span the summary covers, and the ticks and overruns before it.
    since: Instant,
    ticks_before: u64,
    overruns_before: u64,
    /// Per joint: error budget, fault, warnings.
    health: Vec<JointHealth>,
    max_missed: u32,
    health_every: u64,
    /// The active faults and warnings as telemetry lists them, rebuilt when one changes.
    fault_list: Vec<FaultInfo>,
    warning_list: Vec<FaultInfo>,
    lists_changed: bool,
    port_lost: Option<PortLost>,
    /// The port [`Cycle::reopen`] opens.
    reopen_path: Option<PathBuf>,
    baud: u32,
    /// Whether torque should be on (and, as far as the loop knows, is).
    torque: bool,
    /// The last instruction that reached every servo (a Sync Write or Sync Read sent).
    last_contact: Instant,
    /// The Bus Watchdog's period, when armed.
    watchdog: Option<Duration>,
    /// No recovery is tried before this instant, after one failed.
    recover_after: Option<Instant>,
    temperature_c: Vec<f64>,
    voltage_v: Vec<f64>,
    load: Vec<f64>,
    load_unit: Vec<LoadUnit>,
    health_tick: u64,
    /// Which joints' temperature and voltage this health read brought (the others keep
    /// their last values and are not judged on them).
    health_fresh: Vec<bool>,
}

impl Cycle {
    fn start(config: &Config, options: RunOptions) -> Result<(Self, Handle), DaemonError> {
        let options = connect::Options {
            port: options.port.clone(),
            ..connect::Options::default()
        };
        let Connection { mut bus, arm, sim } = connect::open(config, options.clone())?;
        // What to reopen if the port vanishes: the given port, `[bus] port`, or the in-process
        // simulator's link, which survives a disconnect as a USB adapter's by-id link does.
        let reopen_path = connect::port_path(config, &options, sim.as_ref());
        let baud = bus.baud();
        let brought = arm.bring_up(&mut bus, BringUpOptions::default())?;
        tracing::info!(
            servos = brought.servos.len(),
            retries = brought.retries,
            "arm up, holding its present pose"
        );
        let c = config.control();
        let chain = config.chain().clone();
        let limits = control::Limits {
            max_tip_speed_m_s: c.max_tip_speed_m_s,
            max_tip_accel_m_s2: c.max_tip_accel_m_s2,
            max_joint_speed_rad_s: c.max_joint_speed_rad_s,
            deadman_s: c.deadman.as_secs_f64(),
        };
        let home = config.home().to_vec();
        let controller = Controller::new(chain, limits, c.strategy, home.clone(), &brought.pose)
            .map_err(DaemonError::Controller)?;
        let n = arm.joints().len();
        let describe = describe(config, &arm);
        let tip = controller.chain().tip(&brought.pose);
        // The channel's first value is never seen: tick 0 publishes a measured snapshot
        // before `ready` hands the handle to anyone who could read it.
        let (handle, ends) = link::channel(describe, Telemetry::default());
        let settings = arm.settings().clone();
        let ids = arm.ids();
        let period = Duration::from_secs_f64(1.0 / c.rate_hz);
        let health = health_limits(&arm, &mut bus);
        let load_unit = arm
            .joints()
            .iter()
            .map(|j| match j.model.current_unit() {
                CurrentUnit::LoadPermille => LoadUnit::Percent,
                CurrentUnit::MilliAmps(_) => LoadUnit::Amps,
            })
            .collect();
        let cycle = Self {
            bus,
            _sim: sim,
            controller,
            ends,
            home,
            goals: vec![Goal { id: 0, ticks: 0 }; n],
            states: States::new(),
            theta_meas: brought.pose.clone(),
            omega_meas: vec![0.0; n],
            pending: Vec::with_capacity(COMMAND_QUEUE),
            received: Vec::with_capacity(COMMAND_QUEUE),
            period,
            dt: period.as_secs_f64(),
            read_every: u64::from(c.read_every),
            reply_timeout: settings.reply_timeout,
            on_exit: settings.on_exit,
            tick: 0,
            estop: false,
            stopping_for_exit: false,
            active: None,
            last: None,
            last_jog: None,
            tip_ref: tip,
            saturated: false,
            self_collision: false,
            solve_us: 0.0,
            overruns: 0,
            peak_total: 0.0,
            m3_total: 0.0,
            counters: Counters {
                retries: u64::from(brought.retries),
                ..Counters::default()
            },
            window: Window::new(Instant::now()),
            write_errors: 0,
            last_overrun_log: None,
            overruns_logged: 0,
            tick_hist: Histogram::new(),
            solve_hist: Histogram::new(),
            latency_hist: Histogram::new(),
            since: Instant::now(),
            ticks_before: 0,
            overruns_before: 0,
            health,
            max_missed: c.max_missed_reads.max(1),
            health_every: u64::from(c.health_every.max(1)),
            fault_list: Vec::new(),
            warning_list: Vec::new(),
            lists_changed: false,
            port_lost: None,
            reopen_path,
            baud,
            torque: true,
            last_contact: Instant::now(),
            watchdog: Some((settings.watchdog_ms / 20).min(127))
                .filter(|&units| units > 0)
                .map(|units| Duration::from_millis(u64::from(units * 20))),
            recover_after: None,
            temperature_c: vec![0.0; n],
            voltage_v: vec![0.0; n],
            load: vec![0.0; n],
            load_unit,
            health_tick: 0,
            health_fresh: vec![false; n],
            ids,
            arm,
        };
        Ok((cycle, handle))
    }

    fn summary(&self) -> Summary {
        Summary {
            ticks: self.tick - self.ticks_before,
            overruns: self.overruns - self.overruns_before,
            elapsed_s: self.since.elapsed().as_secs_f64(),
            tick: self.tick_hist.summary(),
            solve: self.solve_hist.summary(),
            command_to_wire: self.latency_hist.summary(),
        }
    }

    /// Ticks until `stop` is set and the arm has come to rest.
    fn run(&mut self, stop: &AtomicBool) {
        let mut deadline = Instant::now();
        let mut stop_since: Option<Instant> = None;
        loop {
            let start = Instant::now();
            deadline += self.period;
            if stop.load(Ordering::Relaxed) && !self.stopping_for_exit {
                self.stopping_for_exit = true;
                stop_since = Some(start);
                if !self.estop {
                    // Decelerate to rest before letting go; a failure here cannot be worse
                    // than holding, which the next ticks do anyway.
                    let _ = self.controller.command(control::Command::Stop);
                }
                tracing::info!("stopping: bringing the arm to rest");
            }
            self.step(deadline);
            let work = start.elapsed();
            self.window.record(start, work.as_secs_f64() * 1e6);
            self.tick_hist.record(work);
            if let Some(since) = stop_since {
                let at_rest = self.estop || self.controller.activity() == Activity::Holding;
                if at_rest || since.elapsed() > STOP_TIMEOUT {
                    break;
                }
            }
            let now = Instant::now();
            if now > deadline {
                // Late: skip the periods missed instead of running them back to back.
                let late = now.duration_since(deadline).as_nanos();
                let missed = (late / self.period.as_nanos().max(1)) as u64 + 1;
                self.overruns += missed;
                deadline += self.period * missed as u32;
                self.log_overruns(now);
            }
            std::thread::sleep(deadline.saturating_duration_since(Instant::now()));
        }
        self.answer_queued_for_exit();
    }

    /// One tick, ending by `deadline`.
    fn step(&mut self, deadline: Instant) {
        self.tick += 1;
        self.apply_commands();
        if self.port_lost.is_some() {
            self.retry_port();
        } else {
            self.check_stall();
        }
        if self.port_lost.is_some() {
            // Nothing to write to: hold the goals until the port is back.
            self.received.clear();
            self.saturated = false;
            self.self_collision = false;
            self.solve_us = 0.0;
            self.publish();
            self.answer();
            return;
        }

        // Motion -> resolve -> joint-speed limit; frozen under estop or a fault.
        if self.estop || self.faulted() {
            self.saturated = false;
            self.self_collision = false;
            self.solve_us = 0.0;
        } else {
            let t0 = Instant::now();
            let tick = self.controller.tick(self.dt);
            let solve = t0.elapsed();
            self.solve_hist.record(solve);
            self.solve_us = solve.as_secs_f64() * 1e6;
            self.tip_ref = tick.tip_ref;
            self.saturated = tick.saturated;
            self.self_collision = tick.self_collision;
            if tick.clamped {
                self.counters.clamped += 1;
            }
            self.peak_total = self.peak_total.max(tick.peak_joint_speed_rad_s);
            self.m3_total += tick.m3_rad2;
            if let Some(active) = self.active.as_mut() {
                active.peak = active.peak.max(tick.peak_joint_speed_rad_s);
                active.m3 += tick.m3_rad2;
            }
            if let Some(finish) = tick.finished {
                self.finish(finish, tick.tip);
            }
        }

        // Write, through the limits wrapper.
        match self
            .arm
            .goals_into(self.controller.theta(), &mut self.goals)
        {
            Ok(()) => match self.bus.write_goals(&self.goals) {
                Ok(()) => self.last_contact = Instant::now(),
                Err(e) => self.write_failed(&e),
            },
            Err(e) => self.write_failed(&e),
        }
        if !self.received.is_empty() {
            let written = Instant::now();
            for &r in &self.received {
                self.latency_hist
                    .record(written.saturating_duration_since(r));
            }
            self.received.clear();
        }

        // Read, its wait capped short of the end of the tick; health every health_every-th.
        let health = self.tick % self.health_every == 0;
        if self.port_lost.is_none() && (health || self.tick % self.read_every == 0) {
            self.read(deadline, health);
        }

        self.publish();
        self.answer();
    }

    /// Tick 0, before any client: every field of every servo, then a snapshot of it.
    fn read_everything(&mut self) {
        self.read(Instant::now() + self.period, true);
        self.publish();
    }

    fn read(&mut self, deadline: Instant, health: bool) {
        let left = deadline
            .saturating_duration_since(Instant::now())
            .saturating_sub(READ_TAIL);
        let timeout = self.reply_timeout.min(left).max(MIN_READ_WAIT);
        let fields = if health {
            Fields::ALL
        } else {
            Fields {
                velocity: true,
                ..Fields::POSITION
            }
        };
        if health {
            self.health_fresh.iter_mut().for_each(|f| *f = false);
        }
        let read = self
            .bus
            .read_states_into(&self.ids, fields, timeout, &mut self.states);
        let mut attention = false;
        if let Err(e) = read {
            if e.class() == ErrorClass::Bus {
                self.lose_port(&e);
                return;
            }
            tracing::debug!("sync read failed: {e}");
            self.counters.dropped += self.ids.len() as u64;
            for i in 0..self.health.len() {
                attention |= self.missed(i);
            }
        } else {
            self.last_contact = Instant::now();
            for i in 0..self.ids.len() {
                let reading = match self.states.readings().get(i) {
                    Some(Ok(s)) => Ok(*s),
                    Some(Err(e)) => Err(e.is_timeout()),
                    None => Err(true),
                };
                match reading {
                    Ok(s) => {
                        let Some(joint) = self.arm.joints().get(i) else {
                            continue;
                        };
                        let cal = joint.calibration;
                        self.theta_meas[i] = cal.radians(f64::from(s.position_ticks));
                        if let Some(v) = s.velocity {
                            self.omega_meas[i] = units::velocity_rad_s(v) * cal.sign();
                        }
                        if let Some(c) = s.current {
                            self.load[i] = cal.sign()
                                * match joint.model.current_unit() {
                                    CurrentUnit::LoadPermille => f64::from(c) * 0.1,
                                    CurrentUnit::MilliAmps(ma) => f64::from(c) * ma * 1e-3,
                                };
                        }
                        if let (Some(dv), Some(t)) = (s.voltage_dv, s.temperature_c) {
                            self.voltage_v[i] = units::volts(dv);
                            self.temperature_c[i] = f64::from(t);
                            self.health_fresh[i] = true;
                        }
                        let h = &mut self.health[i];
                        h.missed = 0;
                        let hardware = matches!(h.fault, Some((JointFault::Hardware(_), _, _)));
                        // A servo back from silence, or one raising its alert flag.
                        attention |= matches!(h.fault, Some((JointFault::Silent, _, _)));
                        if s.alert && !hardware {
                            h.alert = true;
                            attention = true;
                        }
                    }
                    Err(timeout) => {
                        if timeout {
                            self.counters.dropped += 1;
                        } else {
                            self.counters.corrupted += 1;
                        }
                        attention |= self.missed(i);
                    }
                }
            }
        }
        if health {
            self.health_tick = self.tick;
            self.check_health();
        }
        if attention {
            self.review_faults();
        }
    }

    /// One more read without joint `i`'s reply; true when that exhausts its budget.
    fn missed(&mut self, i: usize) -> bool {
        let tick = self.tick;
        let Some(h) = self.health.get_mut(i) else {
            return false;
        };
        h.missed = h.missed.saturating_add(1);
        if h.missed == 1 {
            h.first_miss = tick;
        }
        h.missed >= self.max_missed && h.fault.is_none()
    }

    fn faulted(&self) -> bool {
        self.port_lost.is_some() || self.health.iter().any(|h| h.fault.is_some())
    }

    /// The fault path after a read: raise what the read showed, clear what it cleared,
    /// recover once nothing holds any more.
    fn review_faults(&mut self) {
        let tick = self.tick;
        for i in 0..self.health.len() {
            let id = self.ids.get(i).copied().unwrap_or_default();
            let h = &self.health[i];
            if h.alert {
                self.health[i].alert = false;
                let (bits, detail) =
                    match self.bus.hardware_errors(id, self.reply_timeout) {
                        Ok(bits) => (
                            bits,
                            format!("hardware error {bits}: the servo may have switched its torque off; `reboot` clears it"),
                        ),
                        Err(e) => (
                            HardwareErrors::default(),
                            format!("alert flag set; Hardware Error Status unreadable ({e}); `reboot` clears it"),
                        ),
                    };
                self.raise(i, JointFault::Hardware(bits), tick, detail);
            } else if h.fault.is_none() && h.missed >= self.max_missed {
                let detail = format!(
                    "no reply to {} consecutive reads (since tick {})",
                    h.missed, h.first_miss
                );
                let since = h.first_miss;
                self.raise(i, JointFault::Silent, since, detail);
            }
        }
        // Servos back from silence.
        let back: Vec<usize> = (0..self.health.len())
            .filter(|&i| {
                let h = &self.health[i];
                h.missed == 0 && matches!(h.fault, Some((JointFault::Silent, _, _)))
            })
            .collect();
        if back.is_empty() {
            return;
        }
        let others = self.port_lost.is_some()
            || self
                .health
                .iter()
                .enumerate()
                .any(|(i, h)| h.fault.is_some() && !back.contains(&i));
        if others {
            for i in back {
                self.clear(i, "answers again (other faults still hold the arm)".into());
            }
            return;
        }
        if self.recover_after.is_some_and(|t| Instant::now() < t) {
            return;
        }
        match self.recover() {
            Ok(watchdogs) => {
                let detail = recovered_detail(&watchdogs);
                for i in back {
                    self.clear(i, format!("answers again; {detail}"));
                }
            }
            Err(e) => {
                tracing::warn!("recovery failed, holding: {e}");
                self.recover_after = Some(Instant::now() + RETRY_EVERY);
            }
        }
    }

    /// Joint `i` faulted: the first fault freezes the arm and ends the active command.
    fn raise(&mut self, i: usize, fault: JointFault, since: u64, detail: String) {
        let was = self.faulted();
        let Some(h) = self.health.get_mut(i) else {
            return;
        };
        h.fault = Some((fault, since, detail.clone()));
        if !was {
            self.hold_for_fault();
        }
        let info = self.joint_info(i, fault.kind(), since, detail);
        tracing::warn!(
            id = info.id,
            joint = info.joint,
            kind = %info.kind,
            "fault: {}",
            info.detail
        );
        self.fault_event(FaultChange::Raised, info);
        self.rebuild_lists();
    }

    /// Joint `i`'s fault cleared.
    fn clear(&mut self, i: usize, detail: String) {
        let Some((fault, since, _)) = self.health.get_mut(i).and_then(|h| h.fault.take()) else {
            return;
        };
        self.health[i].missed = 0;
        let info = self.joint_info(i, fault.kind(), since, detail);
        tracing::info!(
            id = info.id,
            kind = %info.kind,
            "fault cleared: {}",
            info.detail
        );
        self.fault_event(FaultChange::Cleared, info);
        self.rebuild_lists();
    }

    /// The arm holds where it is commanded; the active command ends (outcome `fault`, a
    /// `stopped` event with reason `fault` to its owner).
    fn hold_for_fault(&mut self) {
        self.controller.freeze();
        self.interrupt(StopReason::Fault);
    }

    /// The active command ends without arriving (outcome `fault`, or `stopped` for a
    /// `reboot`), its sender told by a `stopped` event with `reason`.
    fn interrupt(&mut self, reason: StopReason) {
        if let Some(mut a) = self.active.take() {
            a.outcome = if reason == StopReason::Fault {
                Outcome::Fault
            } else {
                Outcome::Stopped
            };
            self.event(Some(a.owner), a.id.clone(), |tip| What::Stopped {
                tip,
                reason,
            });
            self.last = Some(a);
        }
    }

    /// After a fault: tripped Bus Watchdogs cleared (goal := present, re-armed), goals := the
    /// measured pose, torque on again where it should be. Returns the servos whose watchdog
    /// had fired.
    fn recover(&mut self) -> Result<Vec<u8>, String> {
        let watchdogs = self
            .arm
            .recover_watchdog(&mut self.bus)
            .map_err(|e| e.to_string())?;
        self.measure_pose()?;
        self.controller
            .reseed(&self.theta_meas)
            .map_err(|r| r.to_string())?;
        if self.torque {
            self.arm
                .set_torque(&mut self.bus, true)
                .map_err(|e| e.to_string())?;
        }
        self.last_contact = Instant::now();
        self.recover_after = None;
        for h in &mut self.health {
            h.missed = 0;
        }
        tracing::info!("recovered: holding the measured pose");
        Ok(watchdogs)
    }

    /// The measured pose into `theta_meas` (one Sync Read of every position), each angle
    /// clamped into its joint's limits (a servo may rest a tick past one).
    fn measure_pose(&mut self) -> Result<(), String> {
        self.bus
            .read_states_into(
                &self.ids,
                Fields::POSITION,
                self.reply_timeout,
                &mut self.states,
            )
            .map_err(|e| format!("reading the pose: {e}"))?;
        for (i, reading) in self.states.readings().iter().enumerate() {
            match (reading, self.arm.joints().get(i)) {
                (Ok(s), Some(j)) => {
                    self.theta_meas[i] = j.calibration.radians(f64::from(s.position_ticks));
                }
                (Err(err), _) => return Err(format!("reading the pose: {err}")),
                _ => {}
            }
        }
        for (t, l) in self
            .theta_meas
            .iter_mut()
            .zip(self.controller.chain().limits())
        {
            if let Some(l) = l {
                *t = l.clamp(*t);
            }
        }
        Ok(())
    }

    /// The loop went quiet longer than the Bus Watchdog (the process was stopped, the
    /// machine stalled): the servos whose watchdog fired refuse goals until recovered.
    fn check_stall(&mut self) {
        let Some(watchdog) = self.watchdog else {
            return;
        };
        let gap = self.last_contact.elapsed();
        if gap < watchdog {
            return;
        }
        let tripped = match self.arm.tripped_watchdogs(&mut self.bus) {
            Ok(t) => t,
            Err(e) => {
                tracing::warn!("after a {gap:?} stall, reading the bus watchdogs failed: {e}");
                self.last_contact = Instant::now();
                return;
            }
        };
        self.last_contact = Instant::now();
        if tripped.is_empty() {
            return;
        }
        tracing::warn!(
            ?tripped,
            "the loop stalled {gap:?}: bus watchdogs fired, recovering"
        );
        let tick = self.tick;
        let detail = format!(
            "the loop stalled {} ms (watchdog {} ms): the Bus Watchdog fired; cleared, goal := present position, re-armed",
            gap.as_millis(),
            watchdog.as_millis()
        );
        self.interrupt(StopReason::Fault);
        match self.recover() {
            Ok(_) => {
                for id in tripped {
                    if let Some(i) = self.ids.iter().position(|&x| x == id) {
                        let info = self.joint_info(i, FaultKind::Watchdog, tick, detail.clone());
                        self.fault_event(FaultChange::Recovered, info);
                    }
                }
            }
            Err(e) => {
                // Next tick's stall check (the gap is measured again) tries once more.
                tracing::warn!("watchdog recovery failed: {e}");
                self.controller.freeze();
                self.last_contact -= watchdog;
            }
        }
    }

    /// The serial port failed: hold, report, reopen every [`RETRY_EVERY`].
    fn lose_port(&mut self, e: &ServoError) {
        if self.port_lost.is_some() {
            return;
        }
        let was = self.faulted();
        let detail = format!("the serial port failed ({e}); reopening it every second");
        self.port_lost = Some(PortLost {
            since: self.tick,
            next_try: Instant::now() + RETRY_EVERY,
            detail: detail.clone(),
        });
        if !was {
            self.hold_for_fault();
        }
        tracing::error!("{detail}");
        let info = port_info(self.tick, detail);
        self.fault_event(FaultChange::Raised, info);
        self.rebuild_lists();
    }

    fn retry_port(&mut self) {
        let Some(lost) = &self.port_lost else {
            return;
        };
        if Instant::now() < lost.next_try {
            return;
        }
        let since = lost.since;
        match self.reopen() {
            Ok(()) => {
                self.port_lost = None;
                let info = port_info(
                    since,
                    "the port is open again; goals := measured pose".into(),
                );
                tracing::info!("port reopened");
                self.fault_event(FaultChange::Cleared, info);
                self.rebuild_lists();
            }
            Err(e) => {
                tracing::debug!("reopening the port: {e}");
                if let Some(lost) = self.port_lost.as_mut() {
                    lost.next_try = Instant::now() + RETRY_EVERY;
                }
            }
        }
    }

    /// Open the port again, limited as at start, then recover (tripped watchdogs cleared,
    /// goals := the measured pose).
    fn reopen(&mut self) -> Result<(), ReopenError> {
        let path = self.reopen_path.clone().ok_or(ReopenError::NoPath)?;
        self.bus = connect::reopen(&path, self.baud, &self.arm, LimitStrategy::Clamp)?;
        self.recover().map(|_| ()).map_err(ReopenError::Recover)
    }

    /// Health warnings from this tick's temperature and voltage readings, before the
    /// servo's own thresholds switch it off.
    fn check_health(&mut self) {
        for i in 0..self.health.len() {
            if !self.health_fresh[i] {
                continue;
            }
            let (t, v) = (self.temperature_c[i], self.voltage_v[i]);
            let h = &self.health[i];
            if let Some(limit) = h.temperature_limit_c {
                let warn_at = limit - TEMPERATURE_MARGIN_C;
                match &h.temperature_warning {
                    None if t >= warn_at => {
                        let detail = format!(
                            "{t:.0} °C, within {TEMPERATURE_MARGIN_C:.0} °C of its Temperature Limit {limit:.0} °C"
                        );
                        self.warn(i, FaultKind::Temperature, Some(detail));
                    }
                    Some(_) if t < warn_at - TEMPERATURE_HYSTERESIS_C => {
                        self.warn(i, FaultKind::Temperature, None);
                    }
                    _ => {}
                }
            }
            let h = &self.health[i];
            if let Some((lo, hi)) = h.voltage_limits_v {
                let near = v <= lo + VOLTAGE_MARGIN_V || v >= hi - VOLTAGE_MARGIN_V;
                let clear = v > lo + VOLTAGE_MARGIN_V + VOLTAGE_HYSTERESIS_V
                    && v < hi - VOLTAGE_MARGIN_V - VOLTAGE_HYSTERESIS_V;
                match &h.voltage_warning {
                    None if near => {
                        let detail = format!(
                            "input {v:.1} V, within {VOLTAGE_MARGIN_V} V of its voltage limits {lo:.1}..{hi:.1} V"
                        );
                        self.warn(i, FaultKind::Voltage, Some(detail));
                    }
                    Some(_) if clear => self.warn(i, FaultKind::Voltage, None),
                    _ => {}
                }
            }
        }
    }

    /// Raise (`detail`) or clear (`None`) joint `i`'s warning of `kind`.
    fn warn(&mut self, i: usize, kind: FaultKind, detail: Option<String>) {
        let tick = self.tick;
        let slot = match kind {
            FaultKind::Temperature => &mut self.health[i].temperature_warning,
            _ => &mut self.health[i].voltage_warning,
        };
        let (reason, since, detail) = match detail {
            Some(d) => {
                *slot = Some((tick, d.clone()));
                (FaultChange::Raised, tick, d)
            }
            None => match slot.take() {
                Some((since, _)) => (FaultChange::Cleared, since, format!("{kind} back in range")),
                None => return,
            },
        };
        let info = self.joint_info(i, kind, since, detail);
        tracing::warn!(id = info.id, kind = %kind, reason = %reason, "health: {}", info.detail);
        self.fault_event(reason, info);
        self.rebuild_lists();
    }

    fn joint_info(&self, i: usize, kind: FaultKind, since: u64, detail: String) -> FaultInfo {
        FaultInfo {
            id: self.ids.get(i).copied().unwrap_or_default(),
            joint: i + 1,
            kind,
            since_tick: since,
            detail,
        }
    }

    /// The fault and warning lists telemetry carries, from the joints' state.
    fn rebuild_lists(&mut self) {
        let mut faults = Vec::new();
        if let Some(lost) = &self.port_lost {
            faults.push(port_info(lost.since, lost.detail.clone()));
        }
        let mut warnings = Vec::new();
        for (i, h) in self.health.iter().enumerate() {
            if let Some((fault, since, detail)) = &h.fault {
                faults.push(self.joint_info(i, fault.kind(), *since, detail.clone()));
            }
            if let Some((since, detail)) = &h.temperature_warning {
                warnings.push(self.joint_info(i, FaultKind::Temperature, *since, detail.clone()));
            }
            if let Some((since, detail)) = &h.voltage_warning {
                warnings.push(self.joint_info(i, FaultKind::Voltage, *since, detail.clone()));
            }
        }
        self.fault_list = faults;
        self.warning_list = warnings;
        self.lists_changed = true;
    }

    /// A `fault` event, or a `warning` one for a warning's kind, to everyone.
    fn fault_event(&self, reason: FaultChange, info: FaultInfo) {
        self.event(None, None, |tip| What::alarm(tip, reason, info));
    }

    fn write_failed(&mut self, e: &ServoError) {
        if e.class() == ErrorClass::Bus {
            self.lose_port(e);
            return;
        }
        self.write_errors += 1;
        if self.write_errors.is_power_of_two() {
            tracing::warn!(count = self.write_errors, "writing the goals failed: {e}");
        }
    }

    /// Overrun messages at most once a second, with the count since the last one.
    fn log_overruns(&mut self, now: Instant) {
        let due = self
            .last_overrun_log
            .is_none_or(|t| now.duration_since(t) >= Duration::from_secs(1));
        if due {
            tracing::warn!(
                overruns = self.overruns - self.overruns_logged,
                total = self.overruns,
                "control loop overran its period"
            );
            self.last_overrun_log = Some(now);
            self.overruns_logged = self.overruns;
        }
    }

    fn publish(&mut self) {
        let chain = self.controller.chain();
        let tip = chain.tip(self.controller.theta());
        let tip_meas = chain.tip(&self.theta_meas);
        let state = if self.estop {
            State::Estop
        } else if self.faulted() {
            State::Fault
        } else {
            match self.controller.activity() {
                Activity::Moving => State::Moving,
                Activity::Holding => State::Holding,
                Activity::Stopping => State::Stopping,
            }
        };
        let target = self.controller.target().map(|t| [t.x, t.y]);
        let command = self
            .active
            .as_ref()
            .or(self.last.as_ref())
            .map(Active::info);
        let tracking = (self.tip_ref - tip_meas).norm();
        let loop_hz = self.window.rate_hz();
        let p99 = self.window.p99_us;
        let strategy = self.controller.strategy();
        let (tick, t_s) = (self.tick, self.tick as f64 * self.dt);
        let theta_cmd = self.controller.theta();
        let (theta_meas, omega_meas) = (&self.theta_meas, &self.omega_meas);
        let (tip_ref, saturated, solve_us) = (self.tip_ref, self.saturated, self.solve_us);
        let self_collision = self.self_collision;
        let (overruns, peak, m3, counters) =
            (self.overruns, self.peak_total, self.m3_total, self.counters);
        let (torque, health_tick) = (self.torque, self.health_tick);
        let (temperature, voltage) = (&self.temperature_c, &self.voltage_v);
        let (load, load_unit) = (&self.load, &self.load_unit);
        let lists = std::mem::take(&mut self.lists_changed)
            .then_some((&self.fault_list, &self.warning_list));
        self.ends.telemetry.send_modify(|t| {
            t.tick = tick;
            t.t_s = t_s;
            t.state = state;
            t.strategy = strategy;
            t.tip_ref = [tip_ref.x, tip_ref.y];
            t.tip = [tip.x, tip.y];
            t.tip_meas = [tip_meas.x, tip_meas.y];
            t.target = target;
            copy(&mut t.theta_cmd, theta_cmd);
            copy(&mut t.theta_meas, theta_meas);
            copy(&mut t.omega_meas, omega_meas);
            t.tracking_error_m = tracking;
            t.saturated = saturated;
            t.self_collision = self_collision;
            t.command = command;
            t.solve_us = solve_us;
            t.loop_hz = loop_hz;
            t.tick_p99_us = p99;
            t.overruns = overruns;
            t.peak_joint_speed_rad_s = peak;
            t.m3_total_rad2 = m3;
            t.counters = counters;
            t.torque = torque;
            copy(&mut t.temperature_c, temperature);
            copy(&mut t.voltage_v, voltage);
            copy(&mut t.load, load);
            copy(&mut t.load_unit, load_unit);
            t.health_tick = health_tick;
            if let Some((faults, warnings)) = lists {
                t.faults.clone_from(faults);
                t.warnings.clone_from(warnings);
            }
        });
    }

    /// Sends the answers of the commands applied in this tick.
    fn answer(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        let mut status = None;
        for (reply, pending) in self.pending.drain(..) {
            let answer = match pending {
                Pending::Ready(a) => a,
                Pending::Status => status
                    .get_or_insert_with(|| status_fields(&self.ends.telemetry.borrow()))
                    .clone(),
            };
            // A client gone before its answer is not an error.
            let _ = reply.send(answer);
        }
    }

    fn apply_commands(&mut self) {
        // Bounded per tick by the queue's capacity: a flood waits for the next tick.
        for _ in 0..COMMAND_QUEUE {
            let Ok(envelope) = self.ends.commands.try_recv() else {
                break;
            };
            let pending = self.apply(&envelope);
            self.received.push(envelope.received);
            self.pending.push((envelope.reply, pending));
        }
    }

    fn ok(&self) -> Pending {
        Pending::Ready(Ok(tick_fields(self.tick)))
    }

    fn refuse(code: Code, message: impl Into<String>) -> Pending {
        Pending::Ready(Err(Rejection {
            code,
            message: message.into(),
        }))
    }

    fn apply(&mut self, e: &Envelope) -> Pending {
        if self.stopping_for_exit
            && !matches!(e.cmd, LoopCmd::Status | LoopCmd::Stop | LoopCmd::Estop)
        {
            return Self::refuse(Code::ShuttingDown, "the daemon is stopping");
        }
        match &e.cmd {
            LoopCmd::Status => Pending::Status,
            LoopCmd::Stop => {
                if !self.estop {
                    if let Err(r) = self.controller.command(control::Command::Stop) {
                        return Self::refuse(Code::BadArg, r.to_string());
                    }
                    self.begin(e, CmdName::Stop);
                }
                self.ok()
            }
            LoopCmd::Estop => {
                self.estop_now(e);
                self.ok()
            }
            LoopCmd::Reset => self.reset(e),
            LoopCmd::Strategy { name } => {
                self.controller.set_strategy(*name);
                tracing::info!(strategy = name.name(), "strategy switched");
                self.ok()
            }
            LoopCmd::ResetStats => {
                self.peak_total = 0.0;
                self.m3_total = 0.0;
                self.overruns_before = self.overruns;
                self.window.clear();
                self.tick_hist.clear();
                self.solve_hist.clear();
                self.latency_hist.clear();
                self.since = Instant::now();
                self.ticks_before = self.tick;
                self.ok()
            }
            LoopCmd::Torque { on } => self.torque_cmd(*on),
            LoopCmd::Reboot { ids } => self.reboot(ids.as_deref()),
            LoopCmd::Motion(motion) => {
                if self.estop {
                    return Self::refuse(
                        Code::Estopped,
                        "the estop latch is set: send `reset` before moving",
                    );
                }
                if let Some(why) = self.fault_summary() {
                    return Self::refuse(Code::Fault, why);
                }
                if !self.torque {
                    return Self::refuse(
                        Code::Fault,
                        "torque is off: send `torque` with `on: true` before moving",
                    );
                }
                let Some(command) = self.motion(motion) else {
                    return Self::refuse(Code::UnknownCmd, format!("`{}`", motion.name()));
                };
                match self.controller.command(command) {
                    Ok(()) => {
                        self.begin(e, motion.name());
                        self.ok()
                    }
                    Err(r @ (Refused::OutsideLimits { .. } | Refused::SelfCollision { .. })) => {
                        Self::refuse(Code::Unreachable, r.to_string())
                    }
                    Err(r) => Self::refuse(Code::BadArg, r.to_string()),
                }
            }
        }
    }

    fn motion(&self, cmd: &Motion) -> Option<control::Command> {
        let v2 = |p: &[f64; 2]| Vec2::new(p[0], p[1]);
        Some(match cmd {
            Motion::Goto { target, speed } => control::Command::Goto {
                target: v2(target),
                speed: *speed,
            },
            Motion::GotoJoints { theta } => control::Command::GotoJoints {
                theta: theta.clone(),
            },
            Motion::Path { points, speed } => control::Command::Path {
                points: points.iter().map(v2).collect(),
                speed: *speed,
            },
            Motion::Velocity { v } => control::Command::Velocity { v: v2(v) },
            Motion::Jog { joint, rad_s } => control::Command::Jog {
                joint: joint.checked_sub(1)?,
                rad_s: *rad_s,
            },
            Motion::Home => control::Command::GotoJoints {
                theta: self.home.clone(),
            },
        })
    }

    /// A command accepted by the controller becomes the active one. Renewing a velocity (or the
    /// same joint's jog) keeps the running account; anything else preempts it.
    fn begin(&mut self, e: &Envelope, kind: CmdName) {
        let renewal = self.active.as_ref().is_some_and(|a| {
            a.owner == e.client
                && a.kind == kind
                && match e.cmd {
                    LoopCmd::Motion(Motion::Velocity { .. }) => true,
                    LoopCmd::Motion(Motion::Jog { joint, .. }) => self.last_jog == Some(joint),
                    _ => false,
                }
        });
        if let LoopCmd::Motion(Motion::Jog { joint, .. }) = e.cmd {
            self.last_jog = Some(joint);
        }
        if renewal {
            if let Some(a) = self.active.as_mut() {
                a.id = e.id.clone();
            }
            return;
        }
        if let Some(mut old) = self.active.take() {
            old.outcome = Outcome::Preempted;
            self.event(Some(old.owner), old.id.clone(), |tip| What::Preempted {
                tip,
                reason: kind,
            });
            self.last = Some(old);
        }
        self.active = Some(Active {
            owner: e.client,
            id: e.id.clone(),
            kind,
            outcome: Outcome::Active,
            peak: 0.0,
            m3: 0.0,
        });
    }

    /// The active command ended in this tick.
    fn finish(&mut self, finish: Finish, _tip: Vec2) {
        let Some(mut done) = self.active.take() else {
            return;
        };
        let (outcome, what): (Outcome, fn([f64; 2]) -> What) = match finish {
            Finish::Arrived => (Outcome::Arrived, |tip| What::Arrived { tip }),
            Finish::Saturated => (Outcome::Saturated, |tip| What::Saturated { tip }),
            Finish::Stopped { deadman: true } => (Outcome::Stopped, |tip| What::Stopped {
                tip,
                reason: StopReason::Deadman,
            }),
            Finish::Stopped { deadman: false } => (Outcome::Stopped, |tip| What::Stopped {
                tip,
                reason: StopReason::Stop,
            }),
        };
        done.outcome = outcome;
        self.event(Some(done.owner), done.id.clone(), what);
        self.last = Some(done);
    }

    /// An event at this tick; `what` is given the commanded tip.
    fn event(
        &self,
        owner: Option<ClientId>,
        cmd_id: Option<RequestId>,
        what: impl FnOnce([f64; 2]) -> What,
    ) {
        let tip = self.controller.chain().tip(self.controller.theta());
        // No subscriber is not an error: nobody is listening.
        let _ = self.ends.events.send(Event {
            owner,
            cmd_id,
            tick: self.tick,
            what: what([tip.x, tip.y]),
        });
    }

    fn estop_now(&mut self, e: &Envelope) {
        if self.estop {
            return;
        }
        self.controller.freeze();
        self.estop = true;
        if let Some(mut a) = self.active.take() {
            a.outcome = Outcome::Estop;
            self.last = Some(a);
        }
        tracing::warn!("estop: goals frozen");
        if self.on_exit == OnExit::TorqueOff {
            self.torque = false;
            if let Err(err) = self.arm.torque_off(&mut self.bus) {
                tracing::error!("estop: torque off failed: {err}");
            }
        }
        self.event(None, e.id.clone(), |tip| What::Estop { tip });
    }

    fn reset(&mut self, e: &Envelope) -> Pending {
        if !self.estop {
            return self.ok();
        }
        // Goal := the measured pose, read now; then torque on holding it.
        if let Err(err) = self.measure_pose() {
            return Self::refuse(Code::Busy, format!("{err} (for reset)"));
        }
        if let Err(r) = self.controller.reseed(&self.theta_meas) {
            return Self::refuse(Code::Unreachable, r.to_string());
        }
        if let Err(err) = self.arm.set_torque(&mut self.bus, true) {
            return Self::refuse(Code::Busy, format!("torque on for reset: {err}"));
        }
        self.torque = true;
        self.estop = false;
        tracing::info!("reset: holding the measured pose");
        self.event(None, e.id.clone(), |tip| What::Reset { tip });
        self.ok()
    }

    /// Why the arm holds for a fault, naming every fault; `None` when nothing holds it.
    fn fault_summary(&self) -> Option<String> {
        if !self.faulted() {
            return None;
        }
        let list: Vec<String> = self
            .fault_list
            .iter()
            .map(|f| match f.kind {
                FaultKind::Port => format!("port: {}", f.detail),
                _ => format!(
                    "servo {} (joint {}) {}: {}",
                    f.id, f.joint, f.kind, f.detail
                ),
            })
            .collect();
        Some(format!(
            "the arm holds for a fault: {}; `status` lists the faults, `reboot` clears a hardware error",
            list.join("; ")
        ))
    }

    /// `torque`: on = goals := the measured pose (tripped watchdogs cleared first), then
    /// torque on; off = torque off, the controller frozen. Refused on while a fault holds.
    fn torque_cmd(&mut self, on: bool) -> Pending {
        if on {
            if self.estop {
                return Self::refuse(
                    Code::Estopped,
                    "the estop latch is set: `reset` turns torque on",
                );
            }
            if let Some(why) = self.fault_summary() {
                return Self::refuse(Code::Fault, why);
            }
            self.torque = true;
            if let Err(err) = self.recover() {
                self.torque = false;
                return Self::refuse(Code::Busy, format!("torque on: {err}"));
            }
            tracing::info!("torque on, holding the measured pose");
        } else {
            if let Err(err) = self.arm.torque_off(&mut self.bus) {
                return Self::refuse(Code::Busy, format!("torque off: {err}"));
            }
            self.torque = false;
            self.controller.freeze();
            if let Some(mut a) = self.active.take() {
                a.outcome = Outcome::Stopped;
                self.event(Some(a.owner), a.id.clone(), |tip| What::Stopped {
                    tip,
                    reason: StopReason::Torque,
                });
                self.last = Some(a);
            }
            tracing::info!("torque off");
        }
        self.ok()
    }

    /// `reboot`: reboot `ids` (default: the servos in hardware error, else all), bring the
    /// arm up again where it stands (settings, watchdog, goal := present, torque on), goals :=
    /// that pose; every joint fault clears.
    fn reboot(&mut self, ids: Option<&[u8]>) -> Pending {
        if self.port_lost.is_some() {
            return Self::refuse(
                Code::Fault,
                "the serial port is lost: no servo can be rebooted",
            );
        }
        let targets: Vec<u8> = match ids {
            Some(ids) => {
                if let Some(id) = ids.iter().find(|id| !self.ids.contains(id)) {
                    return Self::refuse(
                        Code::BadArg,
                        format!("`ids`: servo {id} is not on this arm (ids {:?})", self.ids),
                    );
                }
                ids.to_vec()
            }
            None => {
                let hardware: Vec<u8> = self
                    .health
                    .iter()
                    .zip(&self.ids)
                    .filter(|(h, _)| matches!(h.fault, Some((JointFault::Hardware(_), _, _))))
                    .map(|(_, &id)| id)
                    .collect();
                if hardware.is_empty() {
                    self.ids.clone()
                } else {
                    hardware
                }
            }
        };
        self.controller.freeze();
        self.interrupt(StopReason::Reboot);
        let clock = WallClock::new();
        let mut retry = Retry::default();
        for &id in &targets {
            if let Err(err) =
                arm::reboot_and_wait(&mut self.bus, id, self.reply_timeout, &clock, &mut retry)
            {
                return Self::refuse(Code::Fault, format!("reboot of servo {id}: {err}"));
            }
        }
        let brought = match self.arm.bring_up(&mut self.bus, BringUpOptions::default()) {
            Ok(b) => b,
            Err(err) => {
                return Self::refuse(Code::Fault, format!("bring-up after the reboot: {err}"))
            }
        };
        self.counters.retries += u64::from(retry.retries + brought.retries);
        self.last_contact = Instant::now();
        self.theta_meas.copy_from_slice(&brought.pose);
        if let Err(r) = self.controller.reseed(&brought.pose) {
            return Self::refuse(Code::Fault, format!("after the reboot: {r}"));
        }
        self.torque = true;
        self.recover_after = None;
        tracing::info!(?targets, "rebooted; holding the measured pose");
        for i in 0..self.health.len() {
            let id = self.ids.get(i).copied().unwrap_or_default();
            let detail = if targets.contains(&id) {
                "rebooted; goals := measured pose, torque on"
            } else {
                "answers after the reboot; goals := measured pose, torque on"
            };
            self.clear(i, detail.into());
        }
        Pending::Ready(Ok(Reply::Rebooted(Rebooted {
            tick: self.tick,
            rebooted: targets,
        })
        .into()))
    }

    /// Commands still queued when the loop ends are answered, not dropped silently.
    fn answer_queued_for_exit(&mut self) {
        while let Ok(e) = self.ends.commands.try_recv() {
            let _ = e.reply.send(Err(Rejection {
                code: Code::ShuttingDown,
                message: "the daemon is stopping".into(),
            }));
        }
        self.answer();
    }
}

fn copy<T: Copy>(dst: &mut Vec<T>, src: &[T]) {
    dst.clear();
    dst.extend_from_slice(src);
}

fn tick_fields(tick: u64) -> crate::protocol::Fields {
    Reply::Applied(crate::protocol::Applied { tick }).into()
}

/// The `status` answer: the snapshot, nobody named in control (the socket side fills it in).
fn status_fields(t: &Telemetry) -> Answer {
    Ok(Reply::Status(Box::new(Status::of(t.clone()))).into())
}

/// Each joint's health thresholds, read once after bring-up: Temperature Limit and Min/Max
/// Voltage Limit (a servo that does not answer them gets no warnings, logged).
fn health_limits<B: ServoBus>(arm: &Arm, bus: &mut B) -> Vec<JointHealth> {
    let t = arm.settings().reply_timeout;
    let mut retry = Retry::default();
    arm.joints()
        .iter()
        .map(|j| {
            let mut read = |r: Register| retry.run(|| bus.read(j.id, r, t)).map(|v| v.value);
            let temperature = read(Register::TemperatureLimit);
            let voltage = (
                read(Register::MinVoltageLimit),
                read(Register::MaxVoltageLimit),
            );
            let temperature_limit_c = match temperature {
                Ok(c) => Some(c as f64),
                Err(e) => {
                    tracing::warn!(id = j.id, "no temperature warnings: {e}");
                    None
                }
            };
            let voltage_limits_v = match voltage {
                (Ok(lo), Ok(hi)) => Some((lo as f64 / 10.0, hi as f64 / 10.0)),
                (Err(e), _) | (_, Err(e)) => {
                    tracing::warn!(id = j.id, "no voltage warnings: {e}");
                    None
                }
            };
            JointHealth {
                temperature_limit_c,
                voltage_limits_v,
                ..JointHealth::default()
            }
        })
        .collect()
}

/// The port's fault, as listed and reported.
fn port_info(since: u64, detail: String) -> FaultInfo {
    FaultInfo {
        id: 0,
        joint: 0,
        kind: FaultKind::Port,
        since_tick: since,
        detail,
    }
}

/// What a recovery did, for the `cleared` event.
fn recovered_detail(watchdogs: &[u8]) -> String {
    if watchdogs.is_empty() {
        "goals := measured pose".into()
    } else {
        format!("goals := measured pose; the Bus Watchdog of servos {watchdogs:?} had fired and was cleared")
    }
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
