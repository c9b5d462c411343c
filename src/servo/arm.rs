//! The configured joints on a bus: which servo drives which joint, its calibration and limits;
//! bring-up, the pose in radians, torque, watchdog recovery and shut-down.
//!
//! Bring-up ([`Arm::bring_up`]), in this order, so the arm never jumps:
//! 1. ping every configured id and check its model; read Hardware Error Status (reboot the
//!    servo first if asked to); Homing Offset must read 0 and Drive Mode's reverse bit 0
//!    (calibration is applied here, in software: a servo reconfigured elsewhere would shift
//!    every angle). Any servo missing, of the wrong model, in hardware error or with such an
//!    offset: refuse, naming each one and the register. From every servo's model and firmware
//!    (the ping's), choose each port's read ([`choose_read`]: Fast Sync Read where every servo
//!    of the port speaks it, as `[bus] read` allows) and set it on the bus: every read from
//!    here on uses it;
//! 2. read the present pose; a joint outside its limits: refuse (move it by hand);
//! 3. Status Return Level 2 (every instruction acknowledged); then, only where they differ,
//!    Operating Mode 3 (position), Return Delay Time and Min/Max Position Limit (EEPROM:
//!    torque off first if it was on; the protected ones through [`Limited::configure`]);
//!    Profile Velocity and Acceleration;
//!    where every servo has Indirect Data at the same address ([`Arm::layout`]), Indirect
//!    Address 1..13 mapped onto Present Current/Load, Velocity, Position, Input Voltage and
//!    Temperature (13 Sync Writes, checked by one Sync Read), so that one read of 13 bytes
//!    brings every present value the loop uses;
//! 4. clear the Bus Watchdog (0: a watchdog that fired refuses goals until then);
//! 5. Goal Position = present position;
//! 6. arm the Bus Watchdog (`[bus] watchdog_ms`);
//! 7. torque on.
//!
//! Every exchange of bring-up, reboot, torque, watchdog recovery and shut-down is retried up
//! to [`RETRIES`] times on a transient error (no reply, a damaged reply): one lost byte on a
//! long bus must not stop a start. A refusal or a hardware alert is not retried.
//!
//! What the control loop does to a running arm (torque off and on, watchdog recovery, the RAM
//! of a servo that lost power, shut-down) runs [`Within`] a time: every wait for a reply is cut
//! to what is left and nothing is sent again past it, and servos known silent are not waited
//! on at all. Torque off is one Sync Write (no replies), then one Sync Read of Torque Enable
//! confirms it; a servo that did not confirm is named ([`Unreached`]).
//!
//! Shut-down ([`Arm::shut_down`]) follows `[bus] on_exit`: torque off (default) or hold (torque
//! stays on at the last goal; the watchdog, if armed, stops the servos once the bus goes
//! quiet). Either way a servo it could not reach is named: its state is unknown.

use std::collections::BTreeSet;
use std::fmt;
use std::time::{Duration, Instant};

use crate::chain::JointLimit;

use super::clock::{Clock, RealClock};
use super::limits::{LimitPolicy, Limited, Setting, TickLimits, POSITION_MODE};
use super::model::ServoModel;
use super::units::{self, Calibration};
use super::{
    Block, ErrorClass, Fields, Goal, HardwareErrors, Layout, PingInfo, ReadChoice, ReadKind,
    Reading, Register, ServoBus, ServoError, States, DRIVE_MODE_REVERSE, INDIRECT_ADDRESS_1,
    INDIRECT_WATCHDOG,
};

/// How far past a joint's limit, ticks, a servo may read at bring-up and still be brought up
/// (held on the limit): a servo placed on a limit by other software, which rounds the limit
/// to the nearest tick rather than inward, may sit one tick outside. Poses converted here
/// never need it ([`JointServo::position_ticks`] keeps a pose on a limit inside).
pub const LIMIT_ROUNDING_TICKS: i32 = 1;

/// Transient errors retried per exchange (so an exchange is tried at most `RETRIES + 1` times).
pub const RETRIES: u32 = 3;

/// What shut-down leaves the servos in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OnExit {
    /// Torque off every servo (the arm goes limp).
    #[default]
    TorqueOff,
    /// Torque stays on at the last goal (the Bus Watchdog, if armed, stops them later).
    Hold,
}

impl OnExit {
    /// The value as `[bus] on_exit` writes it.
    pub const fn as_str(self) -> &'static str {
        match self {
            OnExit::TorqueOff => "torque_off",
            OnExit::Hold => "hold",
        }
    }
}

impl fmt::Display for OnExit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The shortest wait for a reply worth starting: the serial port polls with millisecond
/// granularity, so less than this cannot tell a reply from a missing one.
pub const MIN_WAIT: Duration = Duration::from_micros(300);

/// The time the exchanges of one job may take, measured on `clock`: each wait for a reply is the
/// reply timeout cut to what is left before `until`, and nothing is sent once less than
/// [`MIN_WAIT`] is left. The control loop gives its fault path the rest of its tick.
#[derive(Clone, Copy)]
pub struct Within<'a> {
    clock: &'a dyn Clock,
    until: Instant,
    timeout: Duration,
}

impl fmt::Debug for Within<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Within")
            .field("until", &self.until)
            .field("timeout", &self.timeout)
            .finish()
    }
}

impl<'a> Within<'a> {
    /// Exchanges until `until` on `clock`, each reply waited for at most `timeout`.
    pub fn new(clock: &'a dyn Clock, until: Instant, timeout: Duration) -> Self {
        Self {
            clock,
            until,
            timeout,
        }
    }

    /// Exchanges on the wall clock for `span` from now, each reply waited for at most
    /// `timeout` (for callers outside the control loop: tools, tests).
    pub fn wall(span: Duration, timeout: Duration) -> Within<'static> {
        static WALL: RealClock = RealClock;
        Within::new(&WALL, Instant::now() + span, timeout)
    }

    /// The wait for the next reply, or `None` when there is no time left for one.
    pub fn wait(&self) -> Option<Duration> {
        let left = self.until.saturating_duration_since(self.clock.now());
        (left >= MIN_WAIT).then(|| self.timeout.min(left))
    }

    /// The wait for the next reply, or a timeout of `id` that was never waited for.
    fn wait_for(&self, id: u8) -> Result<Duration, ServoError> {
        self.wait().ok_or(ServoError::Timeout {
            id,
            waited: Duration::ZERO,
        })
    }
}

/// A servo a torque off (or a shut-down) could not reach: its state is unknown.
#[derive(Debug, Clone, PartialEq)]
pub struct Unreached {
    /// 1-based joint index.
    pub joint: usize,
    /// Servo id.
    pub id: u8,
    /// Why.
    pub why: String,
}

impl fmt::Display for Unreached {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "servo {} (joint {}) {}", self.id, self.joint, self.why)
    }
}

/// One joint's servo.
#[derive(Debug, Clone, PartialEq)]
pub struct JointServo {
    /// 1-based joint index, base to tip.
    pub joint: usize,
    /// Servo id.
    pub id: u8,
    /// Expected model.
    pub model: ServoModel,
    /// Software zero and direction.
    pub calibration: Calibration,
    /// Joint limits, rad.
    pub limit: JointLimit,
    /// The same limits as Goal Position ticks (rounded inward).
    pub ticks: TickLimits,
}

/// The `[bus]` settings bring-up and shut-down apply, validated (the config builds them).
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Return Delay Time, µs.
    pub return_delay_us: u32,
    /// Profile Velocity, rad/s (0 = none).
    pub profile_velocity_rad_s: f64,
    /// Profile Acceleration, rad/s² (0 = none).
    pub profile_acceleration_rad_s2: f64,
    /// Bus Watchdog, ms (0 = off).
    pub watchdog_ms: u32,
    /// What shut-down does.
    pub on_exit: OnExit,
    /// Wait for one reply.
    pub reply_timeout: Duration,
    /// Sync Read or Fast Sync Read (`[bus] read`).
    pub read: ReadChoice,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            read: ReadChoice::Auto,
            return_delay_us: 0,
            profile_velocity_rad_s: 0.0,
            profile_acceleration_rad_s2: 0.0,
            watchdog_ms: 100,
            on_exit: OnExit::TorqueOff,
            reply_timeout: Duration::from_millis(5),
        }
    }
}

/// One reason bring-up refuses to start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Refusal {
    /// The servo did not answer a ping.
    #[error("joint {joint}: servo {id} does not answer ({source})")]
    Missing {
        /// 1-based joint index.
        joint: usize,
        /// Servo id.
        id: u8,
        /// What the ping got.
        source: ServoError,
    },
    /// No servo of one port of several answers: the port's cable or power, or the ports given
    /// out of order (each port then asks for servos that are on another).
    #[error(
        "no servo on port {port} answers ({}; first: {source}): check that port's cable and \
         power, and that the ports are given in the order of [[bus.ports]]",
        servo_list(.ids)
    )]
    PortSilent {
        /// The port, 1-based in the order of `[[bus.ports]]`.
        port: usize,
        /// Its servos.
        ids: Vec<u8>,
        /// What the first one's ping got.
        source: ServoError,
    },
    /// A servo of another model answers at this id.
    #[error("joint {joint}: servo {id} is a {} (model {found}), the config says {expected}", super::model_name(*found).unwrap_or("servo of unknown model"))]
    WrongModel {
        /// 1-based joint index.
        joint: usize,
        /// Servo id.
        id: u8,
        /// The configured model.
        expected: ServoModel,
        /// The Model Number it reported.
        found: u16,
    },
    /// The servo has a hardware error latched.
    #[error("joint {joint}: servo {id} reports a hardware error: {errors} (reboot it: `snakectl servo reboot --id {id}`)")]
    HardwareError {
        /// 1-based joint index.
        joint: usize,
        /// Servo id.
        id: u8,
        /// Hardware Error Status.
        errors: HardwareErrors,
    },
    /// A calibration register is not at its neutral value: offsets and direction are applied in
    /// software, so the servo's own would shift or flip every angle.
    #[error("joint {joint}: servo {id} has {register:?} = {value}, expected {expected} (calibration is applied in software: `snakectl servo --port PORT --id {id} clear-calibration` resets it)")]
    Calibration {
        /// 1-based joint index.
        joint: usize,
        /// Servo id.
        id: u8,
        /// Homing Offset or Drive Mode.
        register: Register,
        /// The value read.
        value: i64,
        /// What it must read (Drive Mode: its reverse bit clear).
        expected: i64,
    },
    /// `[bus] read = "fast"`, and this servo's model or firmware does not answer Fast Sync
    /// Read.
    #[error("joint {joint}: servo {id} is a {model} with firmware {firmware}, which does not answer Fast Sync Read ({}): set [bus] read = \"auto\" or \"sync\"", fast_read_needs(*model))]
    NoFastRead {
        /// 1-based joint index.
        joint: usize,
        /// Servo id.
        id: u8,
        /// Its model.
        model: ServoModel,
        /// Its Firmware Version.
        firmware: u8,
    },
    /// `[bus] read = "fast"` on a bus that cannot frame Fast Sync Read.
    #[error("[bus] read = \"fast\": {source}")]
    FastReadUnsupported {
        /// What the bus said.
        source: ServoError,
    },
    /// The joint sits outside its limits: torque on would drive it there at full speed.
    #[error("joint {joint}: servo {id} is at {angle_rad:.3} rad, outside its limits [{lo}, {hi}] rad: move it inside by hand")]
    OutsideLimits {
        /// 1-based joint index.
        joint: usize,
        /// Servo id.
        id: u8,
        /// Present angle.
        angle_rad: f64,
        /// Lower limit.
        lo: f64,
        /// Upper limit.
        hi: f64,
    },
}

/// Why bring-up or shut-down did not complete.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BringUpError {
    /// One or more servos are not fit to start: each is named.
    #[error("refusing to start: {}", join(.0))]
    Refused(Vec<Refusal>),
    /// A bus error during one step.
    #[error("{step}: {source}")]
    Step {
        /// What was being done.
        step: &'static str,
        /// The error.
        source: ServoError,
    },
}

/// Servos shut-down could not leave as `[bus] on_exit` says, each named: their state is unknown.
#[derive(Debug, thiserror::Error)]
#[error("shut-down (on_exit = {on_exit}): servos left in an unknown state: {}", join(.unreached))]
pub struct ShutDownError {
    /// What shut-down was to leave them in.
    pub on_exit: OnExit,
    /// The servos it could not reach.
    pub unreached: Vec<Unreached>,
}

/// What a model needs for Fast Sync Read, for [`Refusal::NoFastRead`].
fn fast_read_needs(model: ServoModel) -> String {
    match model.fast_read_firmware() {
        Some(first) => format!("it needs firmware {first} or later"),
        None => "no firmware of this model does".into(),
    }
}

/// Whether the servo that answered this ping (its model number and firmware) answers Fast Sync
/// Read.
fn answers_fast(info: &PingInfo) -> bool {
    ServoModel::from_number(info.model).is_some_and(|m| m.supports_fast_read(info.firmware))
}

/// The read the bus is to use, from `[bus] read` and every servo's ping (model number and
/// firmware), each paired with its joint: Fast Sync Read where every servo answers it and the
/// choice allows it, Sync Read otherwise. `fast` with a servo that cannot: refused, naming
/// every such servo.
pub fn choose_read(
    choice: ReadChoice,
    servos: &[(&JointServo, PingInfo)],
) -> Result<ReadKind, Vec<Refusal>> {
    let cannot: Vec<Refusal> = servos
        .iter()
        .filter(|(_, info)| !answers_fast(info))
        .map(|(j, info)| Refusal::NoFastRead {
            joint: j.joint,
            id: j.id,
            model: ServoModel::from_number(info.model).unwrap_or(j.model),
            firmware: info.firmware,
        })
        .collect();
    match choice {
        ReadChoice::Sync => Ok(ReadKind::Sync),
        ReadChoice::Auto if cannot.is_empty() => Ok(ReadKind::Fast),
        ReadChoice::Auto => Ok(ReadKind::Sync),
        ReadChoice::Fast if cannot.is_empty() => Ok(ReadKind::Fast),
        ReadChoice::Fast => Err(cannot),
    }
}

fn join<T: std::fmt::Display>(items: &[T]) -> String {
    items
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ")
}

/// "servo 7" or "servos 7, 8, 9", for messages.
fn servo_list(ids: &[u8]) -> String {
    let list: Vec<String> = ids.iter().map(ToString::to_string).collect();
    match ids {
        [_] => format!("servo {}", list.join("")),
        _ => format!("servos {}", list.join(", ")),
    }
}

/// What bring-up found.
#[derive(Debug, Clone, PartialEq)]
pub struct BringUp {
    /// Ping replies, one per joint.
    pub servos: Vec<PingInfo>,
    /// The pose read before torque on, rad.
    pub pose: Vec<f64>,
    /// Servos rebooted to clear a hardware error.
    pub rebooted: Vec<u8>,
    /// Exchanges sent again after a transient error.
    pub retries: u32,
    /// Each port's read, in port order (one entry on a bus of one port), from `[bus] read`
    /// and the servos' firmware.
    pub reads: Vec<ReadKind>,
}

impl BringUp {
    /// The bus's read: Fast Sync Read when every port reads with it, else Sync Read.
    pub fn read(&self) -> ReadKind {
        ReadKind::of_ports(&self.reads)
    }
}

/// Options of [`Arm::bring_up`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BringUpOptions {
    /// Reboot a servo in hardware error instead of refusing (it comes back with torque off).
    pub reboot: bool,
}

/// The configured chain of joint servos.
#[derive(Debug, Clone, PartialEq)]
pub struct Arm {
    joints: Vec<JointServo>,
    settings: Settings,
}

fn step(step: &'static str) -> impl Fn(ServoError) -> BringUpError {
    move |source| BringUpError::Step { step, source }
}

/// Runs exchanges, each retried up to [`RETRIES`] times on a transient error, and counts the
/// retries.
#[derive(Debug, Default)]
pub struct Retry {
    /// Exchanges sent again so far.
    pub retries: u32,
}

impl Retry {
    /// `exchange` with servo `id` within `within`: each try gets the wait [`Within::wait`]
    /// allows, and is made again while it fails transiently, at most [`RETRIES`] more times and
    /// never once the time is up.
    pub fn within<T>(
        &mut self,
        within: &Within<'_>,
        id: u8,
        mut exchange: impl FnMut(Duration) -> Result<T, ServoError>,
    ) -> Result<T, ServoError> {
        let mut left = RETRIES;
        let mut last = None;
        loop {
            let Some(wait) = within.wait() else {
                return Err(last.unwrap_or(ServoError::Timeout {
                    id,
                    waited: Duration::ZERO,
                }));
            };
            match exchange(wait) {
                Err(e) if e.is_transient() && left > 0 => {
                    tracing::debug!(error = %e, "retrying");
                    left -= 1;
                    self.retries += 1;
                    last = Some(e);
                }
                other => return other,
            }
        }
    }

    /// `exchange`, tried again while it fails transiently, at most [`RETRIES`] more times.
    pub fn run<T>(
        &mut self,
        mut exchange: impl FnMut() -> Result<T, ServoError>,
    ) -> Result<T, ServoError> {
        let mut left = RETRIES;
        loop {
            match exchange() {
                Err(e) if e.is_transient() && left > 0 => {
                    tracing::debug!(error = %e, "retrying");
                    left -= 1;
                    self.retries += 1;
                }
                other => return other,
            }
        }
    }
}

impl Arm {
    /// An arm of these joints and settings.
    pub fn new(joints: Vec<JointServo>, settings: Settings) -> Self {
        Self { joints, settings }
    }

    /// The joints, base to tip.
    pub fn joints(&self) -> &[JointServo] {
        &self.joints
    }

    /// The joints whose present position (`present_ticks`, one per joint in order) lies past
    /// a limit by more than [`LIMIT_ROUNDING_TICKS`]: a goal of that pose clamped into the
    /// limits would drive each to its limit at full speed. A servo set exactly on a limit may
    /// read one tick past it, which passes.
    pub fn outside_limits(&self, present_ticks: &[i32]) -> Vec<Refusal> {
        self.joints
            .iter()
            .zip(present_ticks)
            .filter(|(j, &ticks)| {
                ticks < j.ticks.min - LIMIT_ROUNDING_TICKS
                    || ticks > j.ticks.max + LIMIT_ROUNDING_TICKS
            })
            .map(|(j, &ticks)| Refusal::OutsideLimits {
                joint: j.joint,
                id: j.id,
                angle_rad: j.calibration.radians(f64::from(ticks)),
                lo: j.limit.lo,
                hi: j.limit.hi,
            })
            .collect()
    }

    /// Profile Acceleration and Profile Velocity as bring-up writes them (0: no profile).
    fn profiles(&self) -> [(Register, i64); 2] {
        [
            (
                Register::ProfileAcceleration,
                units::profile_acceleration(self.settings.profile_acceleration_rad_s2),
            ),
            (
                Register::ProfileVelocity,
                units::profile_velocity(self.settings.profile_velocity_rad_s),
            ),
        ]
    }

    /// The settings.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Servo ids, base to tip.
    pub fn ids(&self) -> Vec<u8> {
        self.joints.iter().map(|j| j.id).collect()
    }

    /// Where the loop reads its servos' present values: through Indirect Address
    /// ([`Layout::Indirect`]) where every joint's model has Indirect Data at the same address
    /// (X430/X540 at 224, XL330 at 208), so that every read carries the health registers;
    /// otherwise (XL330s mixed with X430s, or a model without indirect addressing) the
    /// registers themselves, the health ones in a longer read of their own.
    pub fn layout(&self) -> Layout {
        let mut data = self.joints.iter().map(|j| j.model.indirect_data());
        match data.next().flatten() {
            Some(first) if data.all(|d| d == Some(first)) => Layout::Indirect {
                data: first,
                watchdog: false,
            },
            _ => Layout::Direct(Fields::ALL),
        }
    }

    /// Map Indirect Address 1.. of every servo in `ids` onto the registers of
    /// [`Layout::Indirect`]: one Sync Write per address, then one Sync Read of the whole
    /// range to check; a servo that does not read back its mapping gets its addresses written
    /// one by one (acknowledged, each `retry`ed). Nothing to do for [`Layout::Direct`].
    pub fn map_indirect<B: ServoBus>(
        &self,
        bus: &mut B,
        ids: &[u8],
        timeout: Duration,
        retry: &mut Retry,
    ) -> Result<(), ServoError> {
        if !matches!(self.layout(), Layout::Indirect { .. }) || ids.is_empty() {
            return Ok(());
        }
        let slots = indirect_slots();
        for &(n, target) in &slots {
            let values: Vec<(u8, i64)> = ids.iter().map(|&id| (id, i64::from(target))).collect();
            bus.sync_write(Register::IndirectAddress(n), &values)?;
        }
        let blocks = retry.run(|| {
            bus.sync_read(
                ids,
                INDIRECT_ADDRESS_1,
                2 * u16::from(INDIRECT_WATCHDOG),
                timeout,
            )
        })?;
        for (&id, block) in ids.iter().zip(blocks) {
            if block.is_ok_and(|b| mapped(&b.data)) {
                continue;
            }
            for &(n, target) in &slots {
                retry.run(|| {
                    bus.write(id, Register::IndirectAddress(n), i64::from(target), timeout)
                })?;
            }
        }
        Ok(())
    }

    /// Each servo's Goal Position limits.
    pub fn tick_limits(&self) -> Vec<(u8, TickLimits)> {
        self.joints.iter().map(|j| (j.id, j.ticks)).collect()
    }

    /// `bus` wrapped so that no goal outside the joint limits is written.
    pub fn limited<B: ServoBus>(&self, bus: B, strategy: LimitPolicy) -> Limited<B> {
        Limited::new(bus, self.tick_limits(), strategy)
    }

    /// The goals for a pose in radians, into `out` (one per joint); a non-finite angle is
    /// refused, naming the joint, and `out` is then left as it was.
    pub fn goals_into(&self, pose: &[f64], out: &mut [Goal]) -> Result<(), ServoError> {
        if pose.len() != self.joints.len() || out.len() != self.joints.len() {
            return Err(ServoError::PoseLength {
                expected: self.joints.len(),
                got: if pose.len() == self.joints.len() {
                    out.len()
                } else {
                    pose.len()
                },
            });
        }
        for (j, &theta) in self.joints.iter().zip(pose) {
            if j.position_ticks(theta).is_none() {
                return Err(ServoError::NotFinite {
                    joint: j.joint,
                    id: j.id,
                    value: theta,
                });
            }
        }
        for ((j, &theta), goal) in self.joints.iter().zip(pose).zip(out) {
            *goal = Goal {
                id: j.id,
                ticks: j.position_ticks(theta).unwrap_or(goal.ticks),
            };
        }
        Ok(())
    }

    /// The goals for a pose in radians; a non-finite angle is refused, naming the joint.
    pub fn goals(&self, pose: &[f64]) -> Result<Vec<Goal>, ServoError> {
        let mut out = vec![Goal { id: 0, ticks: 0 }; self.joints.len()];
        self.goals_into(pose, &mut out)?;
        Ok(out)
    }

    /// Write a pose (rad) in one Sync Write. Nothing is written if an angle is not finite.
    pub fn write_pose<B: ServoBus>(&self, bus: &mut B, pose: &[f64]) -> Result<(), ServoError> {
        let goals = self.goals(pose)?;
        bus.write_goals(&goals)
    }

    /// Present values of every joint in one Sync Read, base to tip.
    pub fn read_states<B: ServoBus>(
        &self,
        bus: &mut B,
        fields: Fields,
    ) -> Result<Vec<Reading>, ServoError> {
        bus.read_states(&self.ids(), fields, self.settings.reply_timeout)
    }

    /// [`Arm::read_states`] into caller-owned buffers; `ids` is [`Arm::ids`], kept by the
    /// caller so nothing is allocated.
    pub fn read_states_into<B: ServoBus>(
        &self,
        bus: &mut B,
        ids: &[u8],
        fields: Fields,
        out: &mut States,
    ) -> Result<(), ServoError> {
        bus.read_states_into(ids, fields, self.settings.reply_timeout, out)
    }

    /// The angle of joint `index` (0-based) at `ticks`.
    pub fn angle(&self, index: usize, ticks: i32) -> Option<f64> {
        self.joints
            .get(index)
            .map(|j| j.calibration.radians(f64::from(ticks)))
    }

    /// Present angle of every joint, rad, base to tip; a servo that did not answer gives its
    /// error in its place.
    pub fn read_pose<B: ServoBus>(
        &self,
        bus: &mut B,
    ) -> Result<Vec<Result<f64, ServoError>>, ServoError> {
        let states = self.read_states(bus, Fields::POSITION)?;
        Ok(self
            .joints
            .iter()
            .zip(states)
            .map(|(j, s)| s.map(|s| j.calibration.radians(f64::from(s.position_ticks))))
            .collect())
    }

    /// Ping, check and prepare every servo, then torque on (see the module docs for the order).
    /// A rebooted servo is waited for on wall time.
    pub fn bring_up<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        options: BringUpOptions,
    ) -> Result<BringUp, BringUpError> {
        self.bring_up_with_clock(bus, options, &RealClock)
    }

    /// [`Arm::bring_up`], waiting for rebooted servos on `clock`.
    pub fn bring_up_with_clock<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        options: BringUpOptions,
        clock: &dyn Clock,
    ) -> Result<BringUp, BringUpError> {
        let t = self.settings.reply_timeout;
        let mut retry = Retry::default();
        let (servos, rebooted) = self.check_counting(bus, options, clock, &mut retry)?;
        let reads = self.set_read(bus, &servos)?;

        // The present pose, before anything moves. A servo set exactly on a limit may read one
        // tick past it: that pose is held on the limit itself.
        let mut present = self.read_present(bus, &mut retry)?;
        let refusals = self.outside_limits(&present);
        let mut pose = Vec::with_capacity(self.joints.len());
        for (j, ticks) in self.joints.iter().zip(&mut present) {
            let angle = j.calibration.radians(f64::from(*ticks));
            *ticks = (*ticks).clamp(j.ticks.min, j.ticks.max);
            pose.push(j.limit.clamp(angle));
        }
        if !refusals.is_empty() {
            return Err(BringUpError::Refused(refusals));
        }

        for j in &self.joints {
            self.prepare(bus, j, &mut retry)
                .map_err(step("writing the servo settings"))?;
        }
        self.map_indirect(bus, &self.ids(), t, &mut retry)
            .map_err(step("mapping the Indirect Addresses"))?;
        // A watchdog that fired refuses Goal Position writes until 0 is written to it.
        for j in &self.joints {
            retry
                .run(|| bus.write(j.id, Register::BusWatchdog, 0, t))
                .map_err(step("clearing the bus watchdog"))?;
        }
        for (j, &ticks) in self.joints.iter().zip(&present) {
            retry
                .run(|| bus.write(j.id, Register::GoalPosition, i64::from(ticks), t))
                .map_err(step("holding the present pose"))?;
        }
        self.arm_watchdog(bus, &mut retry)?;
        for j in &self.joints {
            retry
                .run(|| bus.set_torque(j.id, true, t))
                .map_err(step("torque on"))?;
        }
        Ok(BringUp {
            servos,
            pose,
            rebooted,
            retries: retry.retries,
            reads,
        })
    }

    /// Choose each port's read from its servos' pings ([`choose_read`]) and set it on the bus:
    /// under `auto` a port whose servos all answer Fast Sync Read uses it, whatever the other
    /// ports' servos do; under `fast` every servo must. Under `auto`, a bus that cannot frame
    /// Fast Sync Read keeps Sync Read.
    fn set_read<B: ServoBus>(
        &self,
        bus: &mut B,
        servos: &[PingInfo],
    ) -> Result<Vec<ReadKind>, BringUpError> {
        // Each port's servos, paired with their pings.
        let ports = bus.read_kinds().len().max(1);
        let mut on_port: Vec<Vec<(&JointServo, PingInfo)>> = vec![Vec::new(); ports];
        for (j, info) in self.joints.iter().zip(servos.iter().copied()) {
            if let Some(group) = on_port.get_mut(bus.port_index(j.id)) {
                group.push((j, info));
            }
        }
        let mut kinds = Vec::with_capacity(ports);
        let mut refused = Vec::new();
        for group in &on_port {
            match choose_read(self.settings.read, group) {
                Ok(kind) => kinds.push(kind),
                Err(cannot) => refused.extend(cannot),
            }
        }
        if !refused.is_empty() {
            return Err(BringUpError::Refused(refused));
        }
        if let Err(source) = bus.set_read_kinds(&kinds) {
            if self.settings.read == ReadChoice::Fast {
                return Err(BringUpError::Refused(vec![Refusal::FastReadUnsupported {
                    source,
                }]));
            }
            tracing::debug!(%source, "keeping Sync Read");
            kinds.iter_mut().for_each(|k| *k = ReadKind::Sync);
            bus.set_read_kinds(&kinds)
                .map_err(step("choosing the read"))?;
        }
        if self.settings.read == ReadChoice::Auto {
            for (k, group) in on_port.iter().enumerate() {
                let slow = group.iter().find(|(_, info)| !answers_fast(info));
                if let Some((j, info)) = slow {
                    tracing::info!(
                        id = j.id,
                        firmware = info.firmware,
                        // Counted from 1, as `[[sim.fault]] port` and the messages count them.
                        port = k + 1,
                        "Sync Read: servo {} ({}, firmware {}) does not answer Fast Sync Read",
                        j.id,
                        j.model,
                        info.firmware
                    );
                }
            }
        }
        let read = ReadKind::name_of_ports(&kinds);
        tracing::info!(read, ports, servos = servos.len(), "bus read chosen");
        Ok(kinds)
    }

    /// The present position of every joint, ticks: one Sync Read, sent again (up to
    /// [`RETRIES`] times) while a servo's reply is lost or damaged.
    fn read_present<B: ServoBus>(
        &self,
        bus: &mut B,
        retry: &mut Retry,
    ) -> Result<Vec<i32>, BringUpError> {
        let ids = self.ids();
        let t = self.settings.reply_timeout;
        let states = retry
            .run(|| {
                let mut states = bus.read_states(&ids, Fields::POSITION, t)?;
                let lost = states
                    .iter()
                    .position(|s| s.as_ref().is_err_and(ServoError::is_transient));
                match lost.map(|i| states.swap_remove(i)) {
                    Some(Err(e)) => Err(e),
                    _ => Ok(states),
                }
            })
            .map_err(step("reading the present pose"))?;
        states
            .into_iter()
            .map(|s| s.map(|s| s.position_ticks))
            .collect::<Result<Vec<_>, _>>()
            .map_err(step("reading the present pose"))
    }

    fn arm_watchdog<B: ServoBus>(
        &self,
        bus: &mut B,
        retry: &mut Retry,
    ) -> Result<(), BringUpError> {
        let t = self.settings.reply_timeout;
        let watchdog = units::watchdog_units(self.settings.watchdog_ms);
        if watchdog > 0 {
            for j in &self.joints {
                retry
                    .run(|| bus.write(j.id, Register::BusWatchdog, watchdog, t))
                    .map_err(step("arming the bus watchdog"))?;
            }
        }
        Ok(())
    }

    /// Step 1 of bring-up: every servo answers, is of the configured model, has no hardware
    /// error (rebooting it first when `options.reboot`) and neutral calibration registers.
    pub fn check<B: ServoBus>(
        &self,
        bus: &mut B,
        options: BringUpOptions,
        clock: &dyn Clock,
    ) -> Result<(Vec<PingInfo>, Vec<u8>), BringUpError> {
        self.check_counting(bus, options, clock, &mut Retry::default())
    }

    fn check_counting<B: ServoBus>(
        &self,
        bus: &mut B,
        options: BringUpOptions,
        clock: &dyn Clock,
        retry: &mut Retry,
    ) -> Result<(Vec<PingInfo>, Vec<u8>), BringUpError> {
        let t = self.settings.reply_timeout;
        let mut refusals = Vec::new();
        let mut servos = Vec::new();
        let mut rebooted = Vec::new();
        for j in &self.joints {
            let info = match retry.run(|| bus.ping(j.id, t)) {
                Ok(info) => info,
                Err(source) => {
                    refusals.push(Refusal::Missing {
                        joint: j.joint,
                        id: j.id,
                        source,
                    });
                    continue;
                }
            };
            if info.model != j.model.model_number() {
                refusals.push(Refusal::WrongModel {
                    joint: j.joint,
                    id: j.id,
                    expected: j.model,
                    found: info.model,
                });
                continue;
            }
            servos.push(info);
            let mut errors = retry
                .run(|| bus.hardware_errors(j.id, t))
                .map_err(step("reading Hardware Error Status"))?;
            if !errors.is_empty() && options.reboot {
                tracing::warn!(id = j.id, %errors, "rebooting to clear a hardware error");
                reboot_and_wait(bus, j.id, t, clock, retry).map_err(step("rebooting"))?;
                rebooted.push(j.id);
                errors = retry
                    .run(|| bus.hardware_errors(j.id, t))
                    .map_err(step("reading Hardware Error Status"))?;
            }
            if !errors.is_empty() {
                refusals.push(Refusal::HardwareError {
                    joint: j.joint,
                    id: j.id,
                    errors,
                });
            }
            let offset = retry
                .run(|| bus.read(j.id, Register::HomingOffset, t))
                .map_err(step("reading Homing Offset"))?
                .value;
            if offset != 0 {
                refusals.push(Refusal::Calibration {
                    joint: j.joint,
                    id: j.id,
                    register: Register::HomingOffset,
                    value: offset,
                    expected: 0,
                });
            }
            let drive = retry
                .run(|| bus.read(j.id, Register::DriveMode, t))
                .map_err(step("reading Drive Mode"))?
                .value;
            if drive & DRIVE_MODE_REVERSE != 0 {
                refusals.push(Refusal::Calibration {
                    joint: j.joint,
                    id: j.id,
                    register: Register::DriveMode,
                    value: drive,
                    expected: drive & !DRIVE_MODE_REVERSE,
                });
            }
        }
        if refusals.is_empty() {
            Ok((servos, rebooted))
        } else {
            Err(BringUpError::Refused(self.by_port(bus, refusals)))
        }
    }

    /// `refusals` with the `Missing` of every servo on a port none of whose servos answers,
    /// on a bus of several ports, told once for that port ([`Refusal::PortSilent`]).
    fn by_port<B: ServoBus>(&self, bus: &B, refusals: Vec<Refusal>) -> Vec<Refusal> {
        let ports = bus.read_kinds().len();
        if ports < 2 {
            return refusals;
        }
        let missing = |id: u8| {
            refusals
                .iter()
                .any(|r| matches!(r, Refusal::Missing { id: m, .. } if *m == id))
        };
        let silent: Vec<usize> = (0..ports)
            .filter(|&k| {
                let mut on = self.joints.iter().filter(|j| bus.port_index(j.id) == k);
                on.clone().next().is_some() && on.all(|j| missing(j.id))
            })
            .collect();
        if silent.is_empty() {
            return refusals;
        }
        let mut out: Vec<Refusal> = Vec::new();
        for r in refusals {
            match r {
                Refusal::Missing { id, source, .. } if silent.contains(&bus.port_index(id)) => {
                    let port = bus.port_index(id) + 1;
                    let told = out.iter_mut().find_map(|o| match o {
                        Refusal::PortSilent { port: p, ids, .. } if *p == port => Some(ids),
                        _ => None,
                    });
                    match told {
                        Some(ids) => ids.push(id),
                        None => out.push(Refusal::PortSilent {
                            port,
                            ids: vec![id],
                            source,
                        }),
                    }
                }
                r => out.push(r),
            }
        }
        out
    }

    /// Step 3 for one servo: acknowledgements on, EEPROM items where they differ, profiles.
    fn prepare<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        j: &JointServo,
        retry: &mut Retry,
    ) -> Result<(), ServoError> {
        let t = self.settings.reply_timeout;
        let id = j.id;
        if retry
            .run(|| bus.read(id, Register::StatusReturnLevel, t))?
            .value
            != 2
        {
            // Below level 2 the write itself is not acknowledged: check by reading back.
            match bus.write(id, Register::StatusReturnLevel, 2, t) {
                Ok(_) | Err(ServoError::Timeout { .. }) => {}
                Err(e) => return Err(e),
            }
            let level = retry
                .run(|| bus.read(id, Register::StatusReturnLevel, t))?
                .value;
            if level != 2 {
                return Err(ServoError::Malformed {
                    id,
                    what: format!("Status Return Level stays {level} after writing 2"),
                });
            }
        }
        let return_delay = units::return_delay(self.settings.return_delay_us);
        let mode = retry
            .run(|| bus.read(id, Register::OperatingMode, t))?
            .value
            != POSITION_MODE;
        let delay = retry
            .run(|| bus.read(id, Register::ReturnDelayTime, t))?
            .value
            != return_delay;
        let min = retry
            .run(|| bus.read(id, Register::MinPositionLimit, t))?
            .value;
        let max = retry
            .run(|| bus.read(id, Register::MaxPositionLimit, t))?
            .value;
        let limits = (min, max) != (i64::from(j.ticks.min), i64::from(j.ticks.max));
        if mode || delay || limits {
            if retry.run(|| bus.read(id, Register::TorqueEnable, t))?.value != 0 {
                tracing::info!(id, "torque off to write EEPROM settings");
                retry.run(|| bus.set_torque(id, false, t))?;
            }
            if mode {
                retry.run(|| bus.configure(id, Setting::PositionMode, t))?;
            }
            if delay {
                retry.run(|| bus.write(id, Register::ReturnDelayTime, return_delay, t))?;
            }
            if limits {
                retry.run(|| bus.configure(id, Setting::PositionLimits, t))?;
            }
        }
        for (register, value) in self.profiles() {
            retry.run(|| bus.write(id, register, value, t))?;
        }
        Ok(())
    }

    /// Torque on for every servo but those in `skip`, within `within`, in three round trips:
    /// each goal := its present position (one Sync Read, one Sync Write, confirmed by one Sync
    /// Read of the goals, so nothing moves), then Torque Enable 1 (one Sync Write, confirmed by
    /// one Sync Read) to the servos whose goal was confirmed; what is not confirmed is sent again
    /// while `within` allows. A servo not confirmed in time fails the whole, naming it; the
    /// servos then switched on are switched off again (one Sync Write), so torque is on for all
    /// or for none of them as far as the bus lets it be.
    pub fn torque_on<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        skip: &[u8],
        within: &Within<'_>,
    ) -> Result<(), BringUpError> {
        let ids = self.ids_but(skip);
        let result = self.torque_on_ids(bus, &ids, within);
        if result.is_err() {
            let values: Vec<(u8, i64)> = ids.iter().map(|&id| (id, 0)).collect();
            // Best effort: a port that fails here failed the torque on already.
            let _ = bus.sync_write(Register::TorqueEnable, &values);
        }
        result
    }

    /// Torque on again, as [`Arm::torque_on`], for servos whose torque should be on already (a
    /// recovery after a fault, the arm holding): a failure leaves every servo as it was, those
    /// on still holding, for the next try. Switching them off would leave an arm reported as
    /// holding limp, and a servo read back with Torque Enable 0 would later pass for one that
    /// lost power.
    pub fn keep_torque_on<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        skip: &[u8],
        within: &Within<'_>,
    ) -> Result<(), BringUpError> {
        self.torque_on_ids(bus, &self.ids_but(skip), within)
    }

    /// Every servo's id but those in `skip`, in joint order.
    fn ids_but(&self, skip: &[u8]) -> Vec<u8> {
        self.ids()
            .into_iter()
            .filter(|id| !skip.contains(id))
            .collect()
    }

    fn torque_on_ids<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        ids: &[u8],
        within: &Within<'_>,
    ) -> Result<(), BringUpError> {
        let present = self
            .sync_read_within(bus, ids, Register::PresentPosition, within)
            .map_err(step("reading the present pose"))?;
        let goals: Vec<(u8, i64)> = ids
            .iter()
            .zip(present)
            .map(|(&id, p)| (id, self.clamp_ticks(id, p)))
            .collect();
        self.write_confirmed(bus, Register::GoalPosition, &goals, within)
            .map_err(step("holding the present pose"))?;
        let on: Vec<(u8, i64)> = ids.iter().map(|&id| (id, 1)).collect();
        self.write_confirmed(bus, Register::TorqueEnable, &on, within)
            .map_err(step("torque on"))
    }

    /// `values` (servo, value) of `register` in one Sync Write, confirmed by one Sync Read; the
    /// servos that do not read back their value get it again while `within` allows.
    fn write_confirmed<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        register: Register,
        values: &[(u8, i64)],
        within: &Within<'_>,
    ) -> Result<(), ServoError> {
        let mut pending: Vec<(u8, i64)> = values.to_vec();
        let mut last: Option<ServoError> = None;
        for _ in 0..=RETRIES {
            if pending.is_empty() {
                return Ok(());
            }
            bus.sync_write(register, &pending)?;
            let Some(wait) = within.wait() else {
                break;
            };
            let ids: Vec<u8> = pending.iter().map(|&(id, _)| id).collect();
            let blocks = bus.sync_read(&ids, register.address(), register.size(), wait)?;
            let mut still = Vec::new();
            for (&(id, value), block) in pending.iter().zip(blocks) {
                match block.map(|b| register.decode(&b.data)) {
                    Ok(Some(v)) if v == value => {}
                    Ok(read) => {
                        last = Some(ServoError::Malformed {
                            id,
                            what: format!("{register:?} reads {read:?} after writing {value}"),
                        });
                        still.push((id, value));
                    }
                    Err(e) => {
                        last = Some(e);
                        still.push((id, value));
                    }
                }
            }
            pending = still;
        }
        match pending.first() {
            None => Ok(()),
            Some(&(id, _)) => Err(last.unwrap_or(ServoError::Timeout {
                id,
                waited: Duration::ZERO,
            })),
        }
    }

    /// `register` of every servo in `ids`, in order, by Sync Reads within `within`: the servos
    /// that did not answer are asked again (at most [`RETRIES`] more times); the first error of
    /// a servo that never answered is returned.
    fn sync_read_within<B: ServoBus>(
        &self,
        bus: &mut B,
        ids: &[u8],
        register: Register,
        within: &Within<'_>,
    ) -> Result<Vec<i64>, ServoError> {
        let mut values: Vec<Option<i64>> = vec![None; ids.len()];
        let mut last: Vec<(u8, ServoError)> = Vec::new();
        for _ in 0..=RETRIES {
            let pending: Vec<u8> = ids
                .iter()
                .zip(&values)
                .filter(|(_, v)| v.is_none())
                .map(|(&id, _)| id)
                .collect();
            if pending.is_empty() {
                break;
            }
            let Some(wait) = within.wait() else {
                break;
            };
            let blocks = bus.sync_read(&pending, register.address(), register.size(), wait)?;
            for (id, block) in pending.iter().zip(blocks) {
                let decoded = block.and_then(|b| {
                    register
                        .decode(&b.data)
                        .ok_or_else(|| ServoError::Malformed {
                            id: *id,
                            what: format!("{} bytes for {register:?}", b.data.len()),
                        })
                });
                match decoded {
                    Ok(v) => {
                        if let Some(i) = ids.iter().position(|x| x == id) {
                            values[i] = Some(v);
                        }
                    }
                    Err(e) if e.is_transient() => {
                        last.retain(|(x, _)| x != id);
                        last.push((*id, e));
                    }
                    Err(e) => return Err(e),
                }
            }
        }
        if let Some(i) = values.iter().position(Option::is_none) {
            let id = ids.get(i).copied().unwrap_or_default();
            return Err(last.into_iter().find(|(x, _)| *x == id).map_or(
                ServoError::Timeout {
                    id,
                    waited: Duration::ZERO,
                },
                |(_, e)| e,
            ));
        }
        Ok(values.into_iter().flatten().collect())
    }

    /// The servos whose Bus Watchdog has fired (it reads -1): they refuse goals until
    /// [`Arm::recover_watchdog`]; with them those whose watchdog reads 0 where `[bus]
    /// watchdog_ms` arms it (a recovery cut short). One Sync Read, within `within`.
    pub fn tripped_watchdogs<B: ServoBus>(
        &self,
        bus: &mut B,
        within: &Within<'_>,
    ) -> Result<Vec<u8>, BringUpError> {
        let ids = self.ids();
        let armed = units::watchdog_units(self.settings.watchdog_ms);
        let values = self
            .sync_read_within(bus, &ids, Register::BusWatchdog, within)
            .map_err(step("reading the bus watchdog"))?;
        Ok(ids
            .into_iter()
            .zip(values)
            .filter(|&(_, v)| v < 0 || (v == 0 && armed > 0))
            .map(|(id, _)| id)
            .collect())
    }

    /// Recover every servo whose Bus Watchdog fired (after a long stall of the bus): clear
    /// it, write the profiles again (a watchdog that fires sets them to 0, no limit at all),
    /// set the goal to the present position (so the servo does not jump to a stale goal), arm
    /// it again, each step one Sync Write to all of them; one Sync Read of the watchdog, the
    /// profiles and the goal confirms it, and the servos it does not confirm go through it
    /// again while `within` allows. Returns the servos recovered.
    ///
    /// `unarmed` keeps, across calls, the servos whose watchdog this cleared and has not yet
    /// seen armed again (a recovery cut short leaves them at 0, by this daemon's doing: see
    /// [`Arm::ram_reset`]); each leaves it once its watchdog reads armed.
    pub fn recover_watchdog<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        within: &Within<'_>,
        unarmed: &mut BTreeSet<u8>,
    ) -> Result<Vec<u8>, BringUpError> {
        let tripped = self.tripped_watchdogs(bus, within)?;
        unarmed.retain(|id| tripped.contains(id));
        let armed = units::watchdog_units(self.settings.watchdog_ms);
        // Bus Watchdog (98) to Goal Position (116..119) in one read, the profiles between.
        let first = Register::BusWatchdog.address();
        let offset = |r: Register| usize::from(r.address() - first);
        let len = Register::GoalPosition.address() + Register::GoalPosition.size() - first;
        let profiles = self.profiles();
        let mut pending = tripped.clone();
        let mut last: Option<ServoError> = None;
        for _ in 0..=RETRIES {
            if pending.is_empty() {
                break;
            }
            let zeros: Vec<(u8, i64)> = pending.iter().map(|&id| (id, 0)).collect();
            unarmed.extend(&pending);
            bus.sync_write(Register::BusWatchdog, &zeros)
                .map_err(step("clearing the bus watchdog"))?;
            for (register, value) in profiles {
                let each: Vec<(u8, i64)> = pending.iter().map(|&id| (id, value)).collect();
                bus.sync_write(register, &each)
                    .map_err(step("writing the profiles"))?;
            }
            let present = self
                .sync_read_within(bus, &pending, Register::PresentPosition, within)
                .map_err(step("reading the present position"))?;
            let goals: Vec<(u8, i64)> = pending
                .iter()
                .zip(present)
                .map(|(&id, p)| (id, self.clamp_ticks(id, p)))
                .collect();
            bus.sync_write(Register::GoalPosition, &goals)
                .map_err(step("holding the present position"))?;
            if armed > 0 {
                let arm: Vec<(u8, i64)> = pending.iter().map(|&id| (id, armed)).collect();
                bus.sync_write(Register::BusWatchdog, &arm)
                    .map_err(step("arming the bus watchdog"))?;
            }
            let Some(wait) = within.wait() else {
                break;
            };
            let blocks = bus
                .sync_read(&pending, first, len, wait)
                .map_err(step("checking the bus watchdog"))?;
            let mut still = Vec::new();
            for ((&id, goal), block) in pending.iter().zip(&goals).zip(blocks) {
                let held = block.map(|b| {
                    let watchdog = b.data.first().map(|&w| i64::from(w as i8));
                    let value = |r: Register| {
                        let at = offset(r);
                        b.data
                            .get(at..at + usize::from(r.size()))
                            .and_then(|v| r.decode(v))
                    };
                    watchdog == Some(armed)
                        && value(Register::GoalPosition) == Some(goal.1)
                        && profiles.iter().all(|&(r, v)| value(r) == Some(v))
                });
                match held {
                    Ok(true) => {
                        unarmed.remove(&id);
                    }
                    Ok(false) => {
                        last = Some(ServoError::Malformed {
                            id,
                            what:
                                "the watchdog, the profiles or the goal did not take its new value"
                                    .into(),
                        });
                        still.push(id);
                    }
                    Err(e) => {
                        last = Some(e);
                        still.push(id);
                    }
                }
            }
            pending = still;
        }
        if let Some(&id) = pending.first() {
            return Err(BringUpError::Step {
                step: "recovering the bus watchdog",
                source: last.unwrap_or(ServoError::Timeout {
                    id,
                    waited: Duration::ZERO,
                }),
            });
        }
        Ok(tripped)
    }

    /// `ticks` of servo `id` inside its joint's Goal Position limits.
    fn clamp_ticks(&self, id: u8, ticks: i64) -> i64 {
        match self.joints.iter().find(|j| j.id == id) {
            Some(j) => ticks.clamp(i64::from(j.ticks.min), i64::from(j.ticks.max)),
            None => ticks,
        }
    }

    /// What of the RAM bring-up wrote servo `id` no longer holds, `None` when it all does: a
    /// servo that lost power answers again with its RAM at the defaults (Bus Watchdog 0 where
    /// it was armed, profiles 0, Torque Enable 0 where `torque` was on, Indirect Address 1 at
    /// its default where it was mapped). A Bus Watchdog that fired (-1) is a powered servo's,
    /// and so is a 0 where a recovery cut short left it (`id` in `unarmed`, as
    /// [`Arm::recover_watchdog`] keeps it; the other registers still tell a power loss).
    /// Within `within`.
    pub fn ram_reset<B: ServoBus>(
        &self,
        bus: &mut B,
        id: u8,
        torque: bool,
        unarmed: &BTreeSet<u8>,
        within: &Within<'_>,
    ) -> Result<Option<String>, ServoError> {
        let mut retry = Retry::default();
        let mut read = |r: Register| {
            retry
                .within(within, id, |w| bus.read(id, r, w))
                .map(|v| v.value)
        };
        let mut reset = Vec::new();
        let armed = units::watchdog_units(self.settings.watchdog_ms);
        let watchdog = if armed > 0 {
            Some(read(Register::BusWatchdog)?)
        } else {
            None
        };
        if watchdog == Some(0) && !unarmed.contains(&id) {
            reset.push(format!("Bus Watchdog 0 (armed at {armed})"));
        }
        // A watchdog that fired set the profiles to 0 itself (its recovery writes them again).
        let fired = watchdog.is_some_and(|w| w < 0);
        for (register, expected) in self.profiles() {
            if expected != 0 && !fired {
                let value = read(register)?;
                if value != expected {
                    reset.push(format!("{register:?} {value} (written {expected})"));
                }
            }
        }
        if torque && read(Register::TorqueEnable)? == 0 {
            reset.push("Torque Enable 0".into());
        }
        if let (Layout::Indirect { data, .. }, Some(&(n, target))) =
            (self.layout(), indirect_slots().first())
        {
            let value = read(Register::IndirectAddress(n))?;
            if value != i64::from(target) {
                reset.push(format!(
                    "Indirect Address {n} {value} (mapped {target}; default {data})"
                ));
            }
        }
        Ok((!reset.is_empty()).then(|| reset.join(", ")))
    }

    /// The RAM part of bring-up again for servo `id` (after it lost power): acknowledgements
    /// on, the profiles, the Bus Watchdog cleared, the Indirect Addresses mapped, goal :=
    /// present position, the watchdog armed. Torque stays off. Within `within`.
    pub fn restore_ram<B: ServoBus>(
        &self,
        bus: &mut Limited<B>,
        id: u8,
        within: &Within<'_>,
    ) -> Result<(), ServoError> {
        let mut retry = Retry::default();
        let mut write = |r: Register, v: i64| {
            retry
                .within(within, id, |w| bus.write(id, r, v, w))
                .map(|_| ())
        };
        write(Register::StatusReturnLevel, 2)?;
        for (register, value) in self.profiles() {
            write(register, value)?;
        }
        write(Register::BusWatchdog, 0)?;
        if matches!(self.layout(), Layout::Indirect { .. }) {
            // Thirteen writes without replies, then one read to check them.
            for (n, target) in indirect_slots() {
                bus.sync_write(Register::IndirectAddress(n), &[(id, i64::from(target))])?;
            }
            let len = 2 * u16::from(INDIRECT_WATCHDOG);
            let read = retry.within(within, id, |w| {
                bus.sync_read(&[id], INDIRECT_ADDRESS_1, len, w)
            })?;
            match read.into_iter().next() {
                Some(Ok(block)) if mapped(&block.data) => {}
                Some(Err(e)) => return Err(e),
                _ => {
                    return Err(ServoError::Malformed {
                        id,
                        what: "its Indirect Addresses do not read back as written".into(),
                    })
                }
            }
        }
        let present = retry
            .within(within, id, |w| bus.read(id, Register::PresentPosition, w))?
            .value;
        retry.within(within, id, |w| {
            bus.write(id, Register::GoalPosition, present, w)
        })?;
        let armed = units::watchdog_units(self.settings.watchdog_ms);
        if armed > 0 {
            retry.within(within, id, |w| {
                bus.write(id, Register::BusWatchdog, armed, w)
            })?;
        }
        Ok(())
    }

    /// Leave the servos as `[bus] on_exit` says: torque off (see [`Arm::torque_off`]) or hold,
    /// within `within`. The servos in `silent` are not waited on: with `hold` as with torque
    /// off, they are named as unreached.
    pub fn shut_down<B: ServoBus>(
        &self,
        bus: &mut B,
        silent: &[u8],
        within: &Within<'_>,
    ) -> Result<(), ShutDownError> {
        let on_exit = self.settings.on_exit;
        let unreached = match on_exit {
            OnExit::Hold => self
                .joints
                .iter()
                .filter(|j| silent.contains(&j.id))
                .map(|j| Unreached {
                    joint: j.joint,
                    id: j.id,
                    why: "does not answer: not waited on".into(),
                })
                .collect(),
            OnExit::TorqueOff => match self.torque_off(bus, silent, within) {
                Ok(()) => Vec::new(),
                Err(unreached) => unreached,
            },
        };
        if unreached.is_empty() {
            Ok(())
        } else {
            Err(ShutDownError { on_exit, unreached })
        }
    }

    /// Torque off every servo within `within`: one Sync Write to all (no replies, so it costs
    /// no wait, and a silent servo that still hears takes it too), then one Sync Read of Torque
    /// Enable from those not in `silent` confirms it; a servo that still reads 1 is written
    /// once more, one that did not answer is asked again while there is time. Returns the
    /// servos not confirmed, each with why (the `silent` ones were not waited on).
    ///
    /// On a bus of several ports every servo has its own port's outcome: the Sync Write goes
    /// to each port's servos apart (a port that failed is named for its servos alone, the
    /// others' are still switched off), and a read that fails is asked again port by port to
    /// tell which port it was.
    pub fn torque_off<B: ServoBus>(
        &self,
        bus: &mut B,
        silent: &[u8],
        within: &Within<'_>,
    ) -> Result<(), Vec<Unreached>> {
        let groups = by_port(bus, &self.ids());
        let mut failed: Vec<(u8, String)> = Vec::new();
        let mut pending: Vec<u8> = Vec::new();
        for group in &groups {
            let values: Vec<(u8, i64)> = group.iter().map(|&id| (id, 0)).collect();
            match bus.sync_write(Register::TorqueEnable, &values) {
                Err(e) if e.class() == ErrorClass::Bus => {
                    let why = format!("was not reached: the port failed ({e})");
                    failed.extend(group.iter().map(|&id| (id, why.clone())));
                }
                _ => pending.extend(group.iter().filter(|id| !silent.contains(id))),
            }
        }
        let mut last: Vec<(u8, String)> = Vec::new();
        for _ in 0..=RETRIES {
            let Some(wait) = pending.first().and_then(|_| within.wait()) else {
                break;
            };
            let mut still = Vec::new();
            for (id, block) in read_torque(bus, &pending, wait) {
                let written = match block {
                    Read::Off => continue,
                    // Still on: the Sync Write was lost on its way to this one.
                    Read::On => within
                        .wait_for(id)
                        .and_then(|w| bus.set_torque(id, false, w))
                        .map_err(|e| e.to_string()),
                    Read::Missed(e) => Err(e),
                    Read::PortFailed(why) => {
                        failed.push((id, why));
                        continue;
                    }
                };
                if let Err(e) = written {
                    last.retain(|(x, _)| *x != id);
                    last.push((id, e));
                    still.push(id);
                }
            }
            pending = still;
            for group in by_port(bus, &pending) {
                let values: Vec<(u8, i64)> = group.iter().map(|&id| (id, 0)).collect();
                let _ = bus.sync_write(Register::TorqueEnable, &values);
            }
        }
        for id in pending {
            let why = match last.iter().find(|(x, _)| *x == id) {
                Some((_, e)) => format!("did not confirm torque off: {e}"),
                None => "did not confirm torque off in the time allowed".into(),
            };
            failed.push((id, why));
        }
        let unreached: Vec<Unreached> = self
            .joints
            .iter()
            .filter_map(|j| {
                if silent.contains(&j.id) && !failed.iter().any(|(id, _)| *id == j.id) {
                    return Some(Unreached {
                        joint: j.joint,
                        id: j.id,
                        why: "does not answer: torque off sent, not waited on".into(),
                    });
                }
                failed
                    .iter()
                    .find(|(id, _)| *id == j.id)
                    .map(|(_, why)| Unreached {
                        joint: j.joint,
                        id: j.id,
                        why: why.clone(),
                    })
            })
            .collect();
        if unreached.is_empty() {
            Ok(())
        } else {
            Err(unreached)
        }
    }
}

/// `ids` split by the port each is on ([`ServoBus::port_index`]), in port order, each in the
/// order given: one group on a bus of one port.
fn by_port<B: ServoBus>(bus: &B, ids: &[u8]) -> Vec<Vec<u8>> {
    let mut groups: Vec<(usize, Vec<u8>)> = Vec::new();
    for &id in ids {
        let port = bus.port_index(id);
        match groups.iter_mut().find(|(p, _)| *p == port) {
            Some((_, group)) => group.push(id),
            None => groups.push((port, vec![id])),
        }
    }
    groups.sort_by_key(|(p, _)| *p);
    groups.into_iter().map(|(_, g)| g).collect()
}

/// A servo's Torque Enable as [`read_torque`] found it.
enum Read {
    Off,
    On,
    /// No (valid) reply: asked again while there is time.
    Missed(String),
    /// Its port failed: not asked again.
    PortFailed(String),
}

/// Torque Enable of `ids` in one Sync Read, waiting `wait`: each id with what it read. A read
/// that fails as a whole on a bus of several ports is asked again port by port, so that only
/// the failed port's servos are taken for unreached.
fn read_torque<B: ServoBus>(bus: &mut B, ids: &[u8], wait: Duration) -> Vec<(u8, Read)> {
    let (address, size) = (
        Register::TorqueEnable.address(),
        Register::TorqueEnable.size(),
    );
    let of = |ids: &[u8], blocks: Vec<Result<Block, ServoError>>| -> Vec<(u8, Read)> {
        ids.iter()
            .zip(blocks)
            .map(|(&id, block)| {
                let read = match block {
                    Ok(b) if b.data.first() == Some(&0) => Read::Off,
                    Ok(_) => Read::On,
                    Err(e) => Read::Missed(e.to_string()),
                };
                (id, read)
            })
            .collect()
    };
    let whole = match bus.sync_read(ids, address, size, wait) {
        Ok(blocks) => return of(ids, blocks),
        Err(e) => e,
    };
    let groups = by_port(bus, ids);
    if groups.len() < 2 {
        let why = format!("was not reached: {whole}");
        return ids
            .iter()
            .map(|&id| (id, Read::PortFailed(why.clone())))
            .collect();
    }
    let mut out = Vec::with_capacity(ids.len());
    for group in groups {
        match bus.sync_read(&group, address, size, wait) {
            Ok(blocks) => out.extend(of(&group, blocks)),
            Err(e) => {
                let why = format!("was not reached: {e}");
                out.extend(group.iter().map(|&id| (id, Read::PortFailed(why.clone()))));
            }
        }
    }
    out
}

impl JointServo {
    /// The position, ticks, of the joint angle `theta_rad`: the nearest tick, except that an
    /// angle inside the joint's limits (on one included) never lands outside the tick limits,
    /// which are the limits rounded inward. A pose exactly on a limit would otherwise round
    /// to the tick just past it. `None` for an angle that is not finite or beyond the
    /// register's range. An angle outside the limits converts as it is, for the limit wrapper
    /// to refuse or clamp.
    pub fn position_ticks(&self, theta_rad: f64) -> Option<i32> {
        let t = self.calibration.goal_ticks(theta_rad)?;
        Some(if self.limit.contains(theta_rad) {
            t.max(self.ticks.min).min(self.ticks.max)
        } else {
            t
        })
    }

    /// A joint's servo; the tick limits follow from the calibration.
    pub fn new(
        joint: usize,
        id: u8,
        model: ServoModel,
        calibration: Calibration,
        limit: JointLimit,
    ) -> Self {
        let (lo, hi) = calibration.tick_range(limit.lo, limit.hi);
        let ticks = TickLimits {
            min: lo.clamp(0.0, 4095.0) as i32,
            max: hi.clamp(0.0, 4095.0) as i32,
        };
        Self {
            joint,
            id,
            model,
            calibration,
            limit,
            ticks,
        }
    }
}

/// How long a rebooted servo may take to answer again.
pub const REBOOT_WAIT: Duration = Duration::from_secs(3);

/// The Indirect Addresses of [`Layout::Indirect`]: (slot from 1, the address it maps), the
/// block's and Bus Watchdog's past it ([`INDIRECT_WATCHDOG`]).
fn indirect_slots() -> Vec<(u8, u16)> {
    (1..=INDIRECT_WATCHDOG)
        .filter_map(|n| Layout::indirect_target(n).map(|t| (n, t)))
        .collect()
}

/// Whether `data`, the Indirect Addresses read from 168 on, hold the mapping.
fn mapped(data: &[u8]) -> bool {
    let slots = indirect_slots();
    data.len() == 2 * slots.len()
        && data
            .chunks_exact(2)
            .zip(&slots)
            .all(|(b, &(_, t))| u16::from_le_bytes([b[0], b[1]]) == t)
}

/// Reboot `id` and wait on `clock` until it answers a ping again (at most [`REBOOT_WAIT`]).
///
/// A REBOOT whose acknowledgement is lost (no reply, a damaged one) may still have arrived:
/// the servo is then booting and deaf to a second one. So it is waited for first, and REBOOT
/// is sent again (at most [`RETRIES`] times, each counted in `retry`) only if the servo comes
/// back with its alert flag set: its hardware error is still latched, the REBOOT never
/// arrived. A servo without a latched error that answers after a lost acknowledgement is taken
/// as rebooted: nothing else in its reply tells the two apart.
pub fn reboot_and_wait<B: ServoBus>(
    bus: &mut B,
    id: u8,
    timeout: Duration,
    clock: &dyn Clock,
    retry: &mut Retry,
) -> Result<(), ServoError> {
    reboot_all_and_wait(bus, &[id], timeout, clock, retry)
}

/// [`reboot_and_wait`] for every servo of `ids` at once: each is sent its REBOOT, then all are
/// waited for together, so their boots overlap and the wait is about one boot (a few hundred
/// ms), not one per servo. The first error ends it.
pub fn reboot_all_and_wait<B: ServoBus>(
    bus: &mut B,
    ids: &[u8],
    timeout: Duration,
    clock: &dyn Clock,
    retry: &mut Retry,
) -> Result<(), ServoError> {
    let mut reboots = Reboots::send(bus, ids, timeout, clock.now())?;
    let done = loop {
        let within = Within::new(clock, clock.now() + REBOOT_WAIT, timeout);
        match reboots.poll(bus, &within) {
            Ok(true) => break Ok(()),
            Ok(false) => clock.sleep(REBOOT_PING_EVERY),
            Err(e) => break Err(e),
        }
    };
    retry.retries += reboots.retries();
    done
}

/// How often a servo that has not answered since its REBOOT is pinged again.
pub const REBOOT_PING_EVERY: Duration = Duration::from_millis(10);

/// How long to wait for a ping's reply from a servo that may be back from its boot: the
/// instruction (10 bytes) and the reply (14) on the wire at `baud`, 10 bits a byte, the servo's
/// return delay, and a millisecond for the serial port's read timeout resolution. A booting
/// servo's silence so costs about that, not a whole reply timeout, which lets a control loop
/// ping it in the spare time of its ticks.
pub fn ping_wait(baud: u32, return_delay_us: u32) -> Duration {
    let wire_s = 24.0 * 10.0 / f64::from(baud.max(1));
    Duration::from_secs_f64(wire_s)
        + Duration::from_micros(u64::from(return_delay_us))
        + Duration::from_millis(1)
}

/// A reboot of several servos taken a step at a time, so that a control loop keeps ticking
/// (and serving its stops) while they boot: [`Reboots::send`] sends every REBOOT, then each
/// [`Reboots::poll`] pings the servos not back yet, as far as its time allows, until all have
/// answered. Each is waited for at most [`REBOOT_WAIT`] from its REBOOT.
///
/// A REBOOT whose acknowledgement is lost (no reply, a damaged one) may still have arrived:
/// the servo is then booting and deaf to a second one. So it is waited for first, and REBOOT
/// is sent again (at most [`RETRIES`] times in all, each counted in [`Reboots::retries`]) only if
/// it comes back with its alert flag set: its hardware error is still latched, the REBOOT
/// never arrived. A servo without a latched error that answers after a lost acknowledgement is
/// taken as rebooted: nothing else in its reply tells the two apart.
#[derive(Debug)]
pub struct Reboots {
    /// Every servo rebooted.
    targets: Vec<u8>,
    /// The servos of this round: sent their REBOOT together.
    round: Vec<u8>,
    /// Per servo of `round`: the error of its REBOOT's acknowledgement, when lost.
    lost: Vec<Option<ServoError>>,
    /// Per servo of `round`: whether it has answered a ping since, and with its alert flag.
    back: Vec<Option<bool>>,
    /// The last ping error of each servo not back yet.
    last: Vec<Option<ServoError>>,
    /// When this round gives up on a servo that has not answered.
    give_up: Instant,
    /// No ping before this instant (a booting servo is asked every [`REBOOT_PING_EVERY`]).
    next_ping: Instant,
    /// REBOOT rounds left to send again.
    left: u32,
    retries: u32,
    timeout: Duration,
}

impl Reboots {
    /// Sends REBOOT to every servo of `ids` (each acknowledgement waited for at most
    /// `timeout`), at `now`. An error other than a lost acknowledgement (a vanished port)
    /// ends it.
    pub fn send<B: ServoBus>(
        bus: &mut B,
        ids: &[u8],
        timeout: Duration,
        now: Instant,
    ) -> Result<Self, ServoError> {
        let mut reboots = Self {
            targets: ids.to_vec(),
            round: Vec::new(),
            lost: Vec::new(),
            back: Vec::new(),
            last: Vec::new(),
            give_up: now,
            next_ping: now,
            left: RETRIES,
            retries: 0,
            timeout,
        };
        reboots.send_round(bus, ids.to_vec(), now)?;
        Ok(reboots)
    }

    /// One round: REBOOT to each of `ids`, their wait started at `now`.
    fn send_round<B: ServoBus>(
        &mut self,
        bus: &mut B,
        ids: Vec<u8>,
        now: Instant,
    ) -> Result<(), ServoError> {
        self.lost.clear();
        for &id in &ids {
            match bus.reboot(id, self.timeout) {
                Ok(_) => self.lost.push(None),
                Err(e) if e.is_transient() => self.lost.push(Some(e)),
                Err(e) => return Err(e),
            }
        }
        self.back = vec![None; ids.len()];
        self.last = (0..ids.len()).map(|_| None).collect();
        self.round = ids;
        self.give_up = now + REBOOT_WAIT;
        self.next_ping = now;
        Ok(())
    }

    /// The servos rebooted, in the order they were given.
    pub fn ids(&self) -> &[u8] {
        &self.targets
    }

    /// REBOOTs sent again so far.
    pub fn retries(&self) -> u32 {
        self.retries
    }

    /// Pings the servos not back yet, each reply waited for as `within` allows, up to the first
    /// that does not answer (they boot together: while one is silent the others most likely
    /// are too, and each silence costs a whole wait). True once every servo has answered and
    /// none needs its REBOOT again; an error when one has not answered within [`REBOOT_WAIT`]
    /// (its last ping's error), or its REBOOT never arrived [`RETRIES`] rounds running.
    pub fn poll<B: ServoBus>(&mut self, bus: &mut B, within: &Within) -> Result<bool, ServoError> {
        let now = within.clock.now();
        if now < self.next_ping {
            return Ok(false);
        }
        for k in 0..self.round.len() {
            if self.back[k].is_some() {
                continue;
            }
            let id = self.round[k];
            let Some(wait) = within.wait() else {
                return Ok(false);
            };
            match bus.ping(id, wait) {
                Ok(p) => self.back[k] = Some(p.alert),
                Err(e) if e.class() == ErrorClass::Bus => return Err(e),
                Err(e) => {
                    self.last[k] = Some(e);
                    break;
                }
            }
        }
        let now = within.clock.now();
        if let Some(k) = self.back.iter().position(Option::is_none) {
            if now >= self.give_up {
                let id = self.round[k];
                return Err(self.last[k].take().unwrap_or(ServoError::Timeout {
                    id,
                    waited: REBOOT_WAIT,
                }));
            }
            self.next_ping = now + REBOOT_PING_EVERY;
            return Ok(false);
        }
        let mut again = Vec::new();
        for k in 0..self.round.len() {
            if self.back[k] != Some(true) {
                continue;
            }
            if let Some(e) = self.lost[k].take() {
                if self.left == 0 {
                    return Err(e);
                }
                tracing::debug!(error = %e, "the reboot did not arrive; sending it again");
                again.push(self.round[k]);
            }
        }
        if again.is_empty() {
            return Ok(true);
        }
        self.left -= 1;
        self.retries += u32::try_from(again.len()).unwrap_or(u32::MAX);
        self.send_round(bus, again, now)?;
        Ok(false)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::servo::clock::ManualClock;
    use crate::servo::record::NullBus;
    use crate::servo::{Ack, SyncReadBuf, Value};

    const T: Duration = Duration::from_millis(1);

    #[test]
    fn a_ping_after_a_reboot_waits_for_its_exchange_on_the_wire_not_a_reply_timeout() {
        // 24 bytes at 1 Mbps: 240 us, plus the port's millisecond.
        assert_eq!(ping_wait(1_000_000, 0), Duration::from_micros(1240));
        // At 57600 baud the exchange alone is 4.17 ms; a 250 us return delay adds to it.
        let slow = ping_wait(57_600, 250).as_secs_f64();
        assert!((slow - (240.0 / 57_600.0 + 0.00125)).abs() < 1e-6, "{slow}");
    }

    /// Servos that boot for `boot` on `clock` after each REBOOT they hear, deaf until then (a
    /// REBOOT sent meanwhile is lost); `latched`: the hardware error a REBOOT clears, shown in
    /// every ping's alert flag; what each REBOOT loses is taken from `fates` (none: nothing).
    struct Booting {
        inner: NullBus,
        clock: ManualClock,
        boot: Duration,
        until: std::collections::HashMap<u8, std::time::Instant>,
        latched: bool,
        fates: Vec<Lost>,
        reboots: u32,
    }

    impl Booting {
        fn deaf(&self, id: u8) -> bool {
            self.until.get(&id).is_some_and(|&u| self.clock.now() < u)
        }
    }

    /// What the bus loses of one REBOOT.
    #[derive(Clone, Copy)]
    enum Lost {
        /// Nothing: the servo reboots and acknowledges.
        Nothing,
        /// The acknowledgement: the servo reboots all the same.
        Ack,
        /// The instruction: the servo never hears it.
        Instruction,
    }

    impl ServoBus for Booting {
        fn baud(&self) -> u32 {
            self.inner.baud()
        }
        fn set_baud(&mut self, b: u32) -> Result<(), ServoError> {
            self.inner.set_baud(b)
        }
        fn ping(&mut self, id: u8, t: Duration) -> Result<PingInfo, ServoError> {
            if self.deaf(id) {
                return Err(ServoError::Timeout { id, waited: t });
            }
            let p = self.inner.ping(id, t)?;
            Ok(PingInfo {
                alert: self.latched,
                ..p
            })
        }
        fn scan(&mut self, t: Duration) -> Result<Vec<PingInfo>, ServoError> {
            self.inner.scan(t)
        }
        fn read(&mut self, id: u8, r: Register, t: Duration) -> Result<Value, ServoError> {
            self.inner.read(id, r, t)
        }
        fn write(&mut self, id: u8, r: Register, v: i64, t: Duration) -> Result<Ack, ServoError> {
            self.inner.write(id, r, v, t)
        }
        fn sync_read_into(
            &mut self,
            ids: &[u8],
            a: u16,
            l: u16,
            t: Duration,
            out: &mut SyncReadBuf,
        ) -> Result<(), ServoError> {
            self.inner.sync_read_into(ids, a, l, t, out)
        }
        fn sync_write(&mut self, r: Register, v: &[(u8, i64)]) -> Result<(), ServoError> {
            self.inner.sync_write(r, v)
        }
        fn write_goals(&mut self, g: &[Goal]) -> Result<(), ServoError> {
            self.inner.write_goals(g)
        }
        fn reboot(&mut self, id: u8, t: Duration) -> Result<Ack, ServoError> {
            self.reboots += 1;
            let lost = ServoError::Timeout { id, waited: t };
            if self.deaf(id) {
                return Err(lost);
            }
            let fate = if self.fates.is_empty() {
                Lost::Nothing
            } else {
                self.fates.remove(0)
            };
            if !matches!(fate, Lost::Instruction) {
                self.latched = false;
                self.until.insert(id, self.clock.now() + self.boot);
            }
            match fate {
                Lost::Nothing => self.inner.reboot(id, t),
                Lost::Ack | Lost::Instruction => Err(lost),
            }
        }
    }
    #[test]
    fn servos_rebooted_together_boot_together() {
        let boot = Duration::from_millis(400);
        let clock = ManualClock::new();
        let mut bus = booting(&clock, boot);
        let ids = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12];
        reboot_all_and_wait(&mut bus, &ids, T, &clock, &mut Retry::default()).unwrap();
        // One boot, waited for in 10 ms steps, not twelve in a row.
        let took = clock.elapsed();
        assert!(
            took >= boot && took <= boot + Duration::from_millis(10),
            "{took:?}"
        );
        for id in ids {
            assert!(bus.ping(id, T).is_ok(), "servo {id} back");
        }
        // One by one, each waits out its own boot.
        let start = clock.elapsed();
        for id in ids {
            reboot_and_wait(&mut bus, id, T, &clock, &mut Retry::default()).unwrap();
        }
        assert!(clock.elapsed() - start >= boot * 12);
    }

    /// Servos without a latched error that boot for `boot` on `clock` after each REBOOT.
    fn booting(clock: &ManualClock, boot: Duration) -> Booting {
        Booting {
            inner: NullBus::new(1060),
            clock: clock.clone(),
            boot,
            until: Default::default(),
            latched: false,
            fates: Vec::new(),
            reboots: 0,
        }
    }

    #[test]
    fn a_rebooted_servo_is_waited_for_on_the_given_clock() {
        let clock = ManualClock::new();
        let mut bus = booting(&clock, Duration::from_millis(70));
        reboot_and_wait(&mut bus, 3, T, &clock, &mut Retry::default()).unwrap();
        // Seven silent pings, 10 ms apart on the clock, none of it on wall time.
        assert_eq!(clock.elapsed(), Duration::from_millis(70));
    }

    #[test]
    fn a_servo_that_never_comes_back_is_given_up_after_the_reboot_wait() {
        let clock = ManualClock::new();
        let mut bus = booting(&clock, Duration::from_secs(3600));
        let err = reboot_and_wait(&mut bus, 3, T, &clock, &mut Retry::default()).unwrap_err();
        assert!(matches!(err, ServoError::Timeout { id: 3, .. }), "{err}");
        assert_eq!(clock.elapsed(), REBOOT_WAIT);
    }

    /// One servo with a hardware error latched, booting 40 ms (four pings 10 ms apart) after
    /// a REBOOT it hears; what each REBOOT loses is taken from `fates`.
    fn latched(clock: &ManualClock, fates: &[Lost]) -> Booting {
        Booting {
            latched: true,
            fates: fates.to_vec(),
            ..booting(clock, Duration::from_millis(40))
        }
    }

    #[test]
    fn a_reboot_whose_ack_is_lost_is_waited_for_and_not_sent_again() {
        let clock = ManualClock::new();
        let mut bus = latched(&clock, &[Lost::Ack]);
        let mut retry = Retry::default();
        reboot_and_wait(&mut bus, 3, T, &clock, &mut retry).unwrap();
        assert!(!bus.latched);
        assert_eq!((bus.reboots, retry.retries), (1, 0));
        // Four silent pings while it booted, 10 ms apart on the clock.
        assert_eq!(clock.elapsed(), Duration::from_millis(40));
    }

    #[test]
    fn a_reboot_that_never_arrived_is_sent_again_once_the_servo_answers_with_its_error() {
        let clock = ManualClock::new();
        let mut bus = latched(&clock, &[Lost::Instruction, Lost::Ack]);
        let mut retry = Retry::default();
        reboot_and_wait(&mut bus, 3, T, &clock, &mut retry).unwrap();
        assert!(!bus.latched);
        assert_eq!((bus.reboots, retry.retries), (2, 1));
    }

    #[test]
    fn reboots_that_never_arrive_are_sent_four_times_then_reported() {
        let clock = ManualClock::new();
        let mut bus = latched(&clock, &[Lost::Instruction; 5]);
        let mut retry = Retry::default();
        let err = reboot_and_wait(&mut bus, 3, T, &clock, &mut retry).unwrap_err();
        assert!(matches!(err, ServoError::Timeout { id: 3, .. }), "{err}");
        assert!(bus.latched);
        assert_eq!((bus.reboots, retry.retries), (1 + RETRIES, RETRIES));
    }

    #[test]
    fn transient_errors_are_retried_three_times_and_refusals_never() {
        let mut retry = Retry::default();
        let mut calls = 0;
        let r: Result<(), ServoError> = retry.run(|| {
            calls += 1;
            Err(ServoError::Checksum {
                id: 1,
                received: 0,
                computed: 1,
            })
        });
        assert!(r.is_err());
        assert_eq!((calls, retry.retries), (4, 3));
        let mut calls = 0;
        let r: Result<(), ServoError> = retry.run(|| {
            calls += 1;
            Err(ServoError::Status {
                id: 1,
                code: 6,
                alert: false,
            })
        });
        assert!(r.is_err());
        assert_eq!((calls, retry.retries), (1, 3));
        let mut calls = 0;
        retry
            .run(|| {
                calls += 1;
                if calls < 3 {
                    Err(ServoError::Timeout { id: 1, waited: T })
                } else {
                    Ok(())
                }
            })
            .unwrap();
        assert_eq!((calls, retry.retries), (3, 5));
    }
}
