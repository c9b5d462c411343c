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

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::{Map, Value};
use tokio::sync::oneshot;

use crate::chain::Vec2;
use crate::config::Config;
use crate::connect::{self, Connection};
use crate::control::{self, Activity, Controller, Finish, Refused};
use crate::protocol::{
    ClientId, Cmd, Code, CommandInfo, Counters, Describe, Event, EventKind, Rejection, RequestId,
    State, Telemetry, PROTOCOL_VERSION,
};
use crate::resolve::Strategy;
use crate::servo::arm::{Arm, BringUpOptions, OnExit};
use crate::servo::dynamixel::DynamixelBus;
use crate::servo::limits::Limited;
use crate::servo::{units, Fields, Goal, ServoBus, ServoError, States};

use super::link::{self, Answer, Envelope, Handle, LoopEnds, COMMAND_QUEUE};
use super::stats::Histogram;
use super::{DaemonError, RunOptions, Summary};

/// Ticks the loop-rate and tick-time statistics look back over.
const WINDOW: usize = 1000;

/// Longest a shut-down waits for the arm to come to rest before it lets go anyway.
const STOP_TIMEOUT: Duration = Duration::from_secs(10);

/// The shortest wait for a reply the deadline cap leaves a read.
const MIN_READ_WAIT: Duration = Duration::from_micros(300);

/// Start-up on the calling thread (open the bus, bring the arm up), then the cycle until `stop`
/// is set and the arm is at rest, then shut-down. `ready` receives the socket side's handle once
/// the arm holds its pose, or the reason start-up failed.
pub(super) fn main(
    config: Config,
    options: RunOptions,
    stop: Arc<AtomicBool>,
    ready: oneshot::Sender<Result<Handle, DaemonError>>,
) -> Result<Summary, DaemonError> {
    let mut cycle = match Cycle::start(&config, options) {
        Ok((cycle, handle)) => {
            // A `run` that stopped waiting is not this thread's problem: it shuts down below.
            let _ = ready.send(Ok(handle));
            cycle
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return Err(DaemonError::StartUpReported);
        }
    };
    let outcome = catch_unwind(AssertUnwindSafe(|| cycle.run(&stop)));
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
    kind: &'static str,
    outcome: &'static str,
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
}

impl Cycle {
    fn start(config: &Config, options: RunOptions) -> Result<(Self, Handle), DaemonError> {
        let Connection { mut bus, arm, sim } = connect::open(
            config,
            connect::Options {
                port: options.port,
                ..connect::Options::default()
            },
        )?;
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
        let initial = Telemetry {
            strategy: c.strategy.name(),
            tip_ref: [tip.x, tip.y],
            tip: [tip.x, tip.y],
            tip_meas: [tip.x, tip.y],
            theta_cmd: brought.pose.clone(),
            theta_meas: brought.pose.clone(),
            omega_meas: vec![0.0; n],
            counters: Counters {
                retries: u64::from(brought.retries),
                ..Counters::default()
            },
            ..Telemetry::default()
        };
        let (handle, ends) = link::channel(describe, initial);
        let settings = arm.settings().clone();
        let ids = arm.ids();
        let period = Duration::from_secs_f64(1.0 / c.rate_hz);
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

        // Motion -> resolve -> joint-speed limit.
        if self.estop {
            self.saturated = false;
            self.solve_us = 0.0;
        } else {
            let t0 = Instant::now();
            let tick = self.controller.tick(self.dt);
            let solve = t0.elapsed();
            self.solve_hist.record(solve);
            self.solve_us = solve.as_secs_f64() * 1e6;
            self.tip_ref = tick.tip_ref;
            self.saturated = tick.saturated;
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
            Ok(()) => {
                if let Err(e) = self.bus.write_goals(&self.goals) {
                    self.write_failed(&e);
                }
            }
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

        // Read, its wait capped at the end of the tick.
        if self.tick % self.read_every == 0 {
            self.read(deadline);
        }

        self.publish();
        self.answer();
    }

    fn read(&mut self, deadline: Instant) {
        let left = deadline.saturating_duration_since(Instant::now());
        let timeout = self.reply_timeout.min(left).max(MIN_READ_WAIT);
        let fields = Fields {
            velocity: true,
            ..Fields::POSITION
        };
        if let Err(e) = self
            .bus
            .read_states_into(&self.ids, fields, timeout, &mut self.states)
        {
            tracing::debug!("sync read failed: {e}");
            self.counters.dropped += self.ids.len() as u64;
            return;
        }
        for (i, reading) in self.states.readings().iter().enumerate() {
            match reading {
                Ok(s) => {
                    let Some(joint) = self.arm.joints().get(i) else {
                        continue;
                    };
                    self.theta_meas[i] = joint.calibration.radians(f64::from(s.position_ticks));
                    if let Some(v) = s.velocity {
                        self.omega_meas[i] = units::velocity_rad_s(v) * joint.calibration.sign();
                    }
                }
                Err(ServoError::Timeout { .. }) => self.counters.dropped += 1,
                Err(_) => self.counters.corrupted += 1,
            }
        }
    }

    fn write_failed(&mut self, e: &ServoError) {
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
        let strategy = self.controller.strategy().name();
        let (tick, t_s) = (self.tick, self.tick as f64 * self.dt);
        let theta_cmd = self.controller.theta();
        let (theta_meas, omega_meas) = (&self.theta_meas, &self.omega_meas);
        let (tip_ref, saturated, solve_us) = (self.tip_ref, self.saturated, self.solve_us);
        let (overruns, peak, m3, counters) =
            (self.overruns, self.peak_total, self.m3_total, self.counters);
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
            t.command = command;
            t.solve_us = solve_us;
            t.loop_hz = loop_hz;
            t.tick_p99_us = p99;
            t.overruns = overruns;
            t.peak_joint_speed_rad_s = peak;
            t.m3_total_rad2 = m3;
            t.counters = counters;
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
        if self.stopping_for_exit && !matches!(e.cmd, Cmd::Status | Cmd::Stop | Cmd::Estop) {
            return Self::refuse(Code::ShuttingDown, "the daemon is stopping");
        }
        match &e.cmd {
            Cmd::Status => Pending::Status,
            Cmd::Stop => {
                if !self.estop {
                    if let Err(r) = self.controller.command(control::Command::Stop) {
                        return Self::refuse(Code::BadArg, r.to_string());
                    }
                    self.begin(e, "stop");
                }
                self.ok()
            }
            Cmd::Estop => {
                self.estop_now(e);
                self.ok()
            }
            Cmd::Reset => self.reset(e),
            Cmd::Strategy { name } => {
                self.controller.set_strategy(*name);
                tracing::info!(strategy = name.name(), "strategy switched");
                self.ok()
            }
            Cmd::ResetStats => {
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
            Cmd::Describe | Cmd::Subscribe { .. } | Cmd::Unsubscribe => Self::refuse(
                Code::UnknownCmd,
                format!("`{}` is answered by the socket, not the loop", e.cmd.name()),
            ),
            motion => {
                if self.estop {
                    return Self::refuse(
                        Code::Estopped,
                        "the estop latch is set: send `reset` before moving",
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
                    Err(r @ Refused::OutsideLimits { .. }) => {
                        Self::refuse(Code::Unreachable, r.to_string())
                    }
                    Err(r) => Self::refuse(Code::BadArg, r.to_string()),
                }
            }
        }
    }

    fn motion(&self, cmd: &Cmd) -> Option<control::Command> {
        let v2 = |p: &[f64; 2]| Vec2::new(p[0], p[1]);
        Some(match cmd {
            Cmd::Goto { target, speed } => control::Command::Goto {
                target: v2(target),
                speed: *speed,
            },
            Cmd::GotoJoints { theta } => control::Command::GotoJoints {
                theta: theta.clone(),
            },
            Cmd::Path { points, speed } => control::Command::Path {
                points: points.iter().map(v2).collect(),
                speed: *speed,
            },
            Cmd::Velocity { v } => control::Command::Velocity { v: v2(v) },
            Cmd::Jog { joint, rad_s } => control::Command::Jog {
                joint: joint.checked_sub(1)?,
                rad_s: *rad_s,
            },
            Cmd::Home => control::Command::GotoJoints {
                theta: self.home.clone(),
            },
            _ => return None,
        })
    }

    /// A command accepted by the controller becomes the active one. Renewing a velocity (or the
    /// same joint's jog) keeps the running account; anything else preempts it.
    fn begin(&mut self, e: &Envelope, kind: &'static str) {
        let renewal = self.active.as_ref().is_some_and(|a| {
            a.owner == e.client
                && a.kind == kind
                && match e.cmd {
                    Cmd::Velocity { .. } => true,
                    Cmd::Jog { joint, .. } => self.last_jog == Some(joint),
                    _ => false,
                }
        });
        if let Cmd::Jog { joint, .. } = e.cmd {
            self.last_jog = Some(joint);
        }
        if renewal {
            if let Some(a) = self.active.as_mut() {
                a.id = e.id.clone();
            }
            return;
        }
        if let Some(mut old) = self.active.take() {
            old.outcome = "preempted";
            self.event(
                Some(old.owner),
                old.id.clone(),
                EventKind::Preempted,
                Some(kind),
            );
            self.last = Some(old);
        }
        self.active = Some(Active {
            owner: e.client,
            id: e.id.clone(),
            kind,
            outcome: "active",
            peak: 0.0,
            m3: 0.0,
        });
    }

    /// The active command ended in this tick.
    fn finish(&mut self, finish: Finish, _tip: Vec2) {
        let Some(mut done) = self.active.take() else {
            return;
        };
        let (kind, outcome, reason) = match finish {
            Finish::Arrived => (EventKind::Arrived, "arrived", None),
            Finish::Saturated => (EventKind::Saturated, "saturated", None),
            Finish::Stopped { deadman: true } => (EventKind::Stopped, "stopped", Some("deadman")),
            Finish::Stopped { deadman: false } => (EventKind::Stopped, "stopped", Some("stop")),
        };
        done.outcome = outcome;
        self.event(Some(done.owner), done.id.clone(), kind, reason);
        self.last = Some(done);
    }

    fn event(
        &self,
        owner: Option<ClientId>,
        cmd_id: Option<RequestId>,
        kind: EventKind,
        reason: Option<&'static str>,
    ) {
        let tip = self.controller.chain().tip(self.controller.theta());
        // No subscriber is not an error: nobody is listening.
        let _ = self.ends.events.send(Event {
            owner,
            cmd_id,
            kind,
            tick: self.tick,
            tip: [tip.x, tip.y],
            reason,
        });
    }

    fn estop_now(&mut self, e: &Envelope) {
        if self.estop {
            return;
        }
        self.controller.freeze();
        self.estop = true;
        if let Some(mut a) = self.active.take() {
            a.outcome = "estop";
            self.last = Some(a);
        }
        tracing::warn!("estop: goals frozen");
        if self.on_exit == OnExit::TorqueOff {
            if let Err(err) = self.arm.torque_off(&mut self.bus) {
                tracing::error!("estop: torque off failed: {err}");
            }
        }
        self.event(None, e.id.clone(), EventKind::Estop, None);
    }

    fn reset(&mut self, e: &Envelope) -> Pending {
        if !self.estop {
            return self.ok();
        }
        // Goal := the measured pose, read now; then torque on holding it.
        let fields = Fields::POSITION;
        if let Err(err) =
            self.bus
                .read_states_into(&self.ids, fields, self.reply_timeout, &mut self.states)
        {
            return Self::refuse(Code::Busy, format!("reading the pose for reset: {err}"));
        }
        for (i, reading) in self.states.readings().iter().enumerate() {
            match (reading, self.arm.joints().get(i)) {
                (Ok(s), Some(j)) => {
                    self.theta_meas[i] = j.calibration.radians(f64::from(s.position_ticks));
                }
                (Err(err), _) => {
                    return Self::refuse(Code::Busy, format!("reading the pose for reset: {err}"))
                }
                _ => {}
            }
        }
        // A servo may rest a tick past a limit; its goal is the nearest pose inside them.
        for (t, l) in self
            .theta_meas
            .iter_mut()
            .zip(self.controller.chain().limits())
        {
            if let Some(l) = l {
                *t = l.clamp(*t);
            }
        }
        if let Err(r) = self.controller.reseed(&self.theta_meas) {
            return Self::refuse(Code::Unreachable, r.to_string());
        }
        if let Err(err) = self.arm.set_torque(&mut self.bus, true) {
            return Self::refuse(Code::Busy, format!("torque on for reset: {err}"));
        }
        self.estop = false;
        tracing::info!("reset: holding the measured pose");
        self.event(None, e.id.clone(), EventKind::Reset, None);
        self.ok()
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

fn copy(dst: &mut Vec<f64>, src: &[f64]) {
    dst.clear();
    dst.extend_from_slice(src);
}

fn tick_fields(tick: u64) -> Map<String, Value> {
    let mut m = Map::new();
    m.insert("tick".into(), Value::from(tick));
    m
}

fn status_fields(t: &Telemetry) -> Answer {
    Ok(t.to_fields())
}

/// The `describe` reply: what a remote UI needs to draw the arm.
pub(super) fn describe(config: &Config, arm: &Arm) -> Describe {
    let chain = config.chain();
    let base = chain.base();
    let (min_rad, max_rad) = chain
        .limits()
        .iter()
        .map(|l| l.map_or((f64::MIN, f64::MAX), |l| (l.lo, l.hi)))
        .unzip();
    Describe {
        links_m: chain.links().to_vec(),
        base: [base.x, base.y, chain.heading()],
        min_rad,
        max_rad,
        ids: arm.ids(),
        models: arm.joints().iter().map(|j| j.model.name()).collect(),
        home_rad: config.home().to_vec(),
        rate_hz: config.control().rate_hz,
        strategies: vec![Strategy::Overall.name(), Strategy::Sequential.name()],
        protocol_version: PROTOCOL_VERSION,
    }
}
