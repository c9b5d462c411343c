//! The configured joints on a bus: which servo drives which joint, its calibration and limits;
//! bring-up, the pose in radians, and shut-down.
//!
//! Bring-up ([`Arm::bring_up`]), in this order, so the arm never jumps:
//! 1. ping every configured id and check its model; read Hardware Error Status (reboot the
//!    servo first if asked to). Any servo missing, of the wrong model or in hardware error:
//!    refuse, naming each one;
//! 2. read the present pose; a joint outside its limits: refuse (move it by hand);
//! 3. Status Return Level 2 (every instruction acknowledged); then, only where they differ,
//!    Operating Mode 3 (position), Return Delay Time and Min/Max Position Limit from the config
//!    (EEPROM: torque off first if it was on); Profile Velocity and Acceleration;
//! 4. clear the Bus Watchdog (0: a watchdog that fired refuses goals until then);
//! 5. Goal Position = present position;
//! 6. arm the Bus Watchdog (`[bus] watchdog_ms`);
//! 7. torque on.
//!
//! Shut-down ([`Arm::shut_down`]) follows `[bus] on_exit`: torque off (default; one Sync Write
//! reaches every servo at once, then each is checked) or hold (torque stays on at the last
//! goal; the watchdog, if armed, stops the servos once the bus goes quiet).

use std::time::{Duration, Instant};

use crate::chain::JointLimit;
use crate::config::{Config, OnExit, ServoModel};

use super::limits::{Limited, Strategy, TickLimits};
use super::units::{self, Calibration};
use super::{Fields, Goal, HardwareErrors, PingInfo, Reading, Register, ServoBus, ServoError};

/// How long a rebooted servo may take to answer again.
const REBOOT_WAIT: Duration = Duration::from_secs(3);

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

/// The `[bus]` settings bring-up and shut-down apply.
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
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            return_delay_us: 0,
            profile_velocity_rad_s: 0.0,
            profile_acceleration_rad_s2: 0.0,
            watchdog_ms: 100,
            on_exit: OnExit::TorqueOff,
            reply_timeout: Duration::from_millis(5),
        }
    }
}

/// A config that does not describe a servo chain.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ArmError {
    /// A joint without a servo id or model.
    #[error("joint[{joint}]: no servo id or model")]
    MissingServo {
        /// 1-based joint index.
        joint: usize,
    },
    /// No `[bus]` table.
    #[error("the config has no [bus] table")]
    NoBus,
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
    /// A servo of another model answers at this id.
    #[error("joint {joint}: servo {id} is a {} (model {found}), the config says {}", super::model_name(*found).unwrap_or("servo of unknown model"), expected.name())]
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

/// Servos that did not confirm torque off at shut-down.
#[derive(Debug, thiserror::Error)]
#[error("shut-down: torque off not confirmed: {}", join(.0))]
pub struct ShutDownError(pub Vec<ServoError>);

fn join<T: std::fmt::Display>(items: &[T]) -> String {
    items
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ")
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

impl Arm {
    /// The joints and `[bus]` settings of `config`.
    pub fn from_config(config: &Config) -> Result<Self, ArmError> {
        let bus = config.bus().ok_or(ArmError::NoBus)?;
        let settings = Settings {
            return_delay_us: bus.return_delay_us,
            profile_velocity_rad_s: bus.profile_velocity_rad_s,
            profile_acceleration_rad_s2: bus.profile_acceleration_rad_s2,
            watchdog_ms: bus.watchdog_ms,
            on_exit: bus.on_exit,
            reply_timeout: Duration::from_millis(u64::from(bus.reply_timeout_ms)),
        };
        let mut joints = Vec::with_capacity(config.joints().len());
        for (i, j) in config.joints().iter().enumerate() {
            let (Some(id), Some(model)) = (j.id, j.model) else {
                return Err(ArmError::MissingServo { joint: i + 1 });
            };
            let calibration = Calibration {
                offset_ticks: j.offset_ticks,
                reverse: j.reverse,
            };
            joints.push(JointServo::new(i + 1, id, model, calibration, j.limit));
        }
        Ok(Self { joints, settings })
    }

    /// An arm of these joints and settings.
    pub fn new(joints: Vec<JointServo>, settings: Settings) -> Self {
        Self { joints, settings }
    }

    /// The joints, base to tip.
    pub fn joints(&self) -> &[JointServo] {
        &self.joints
    }

    /// The settings.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Servo ids, base to tip.
    pub fn ids(&self) -> Vec<u8> {
        self.joints.iter().map(|j| j.id).collect()
    }

    /// Each servo's Goal Position limits.
    pub fn tick_limits(&self) -> Vec<(u8, TickLimits)> {
        self.joints.iter().map(|j| (j.id, j.ticks)).collect()
    }

    /// `bus` wrapped so that no goal outside the joint limits is written.
    pub fn limited<B: ServoBus>(&self, bus: B, strategy: Strategy) -> Limited<B> {
        Limited::new(bus, self.tick_limits(), strategy)
    }

    /// The goals for a pose in radians; a non-finite angle is refused, naming the joint.
    pub fn goals(&self, pose: &[f64]) -> Result<Vec<Goal>, ServoError> {
        if pose.len() != self.joints.len() {
            return Err(ServoError::PoseLength {
                expected: self.joints.len(),
                got: pose.len(),
            });
        }
        self.joints
            .iter()
            .zip(pose)
            .map(|(j, &theta)| {
                let ticks = j
                    .calibration
                    .goal_ticks(theta)
                    .ok_or(ServoError::NotFinite {
                        joint: j.joint,
                        id: j.id,
                        value: theta,
                    })?;
                Ok(Goal { id: j.id, ticks })
            })
            .collect()
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
    pub fn bring_up<B: ServoBus>(
        &self,
        bus: &mut B,
        options: BringUpOptions,
    ) -> Result<BringUp, BringUpError> {
        let t = self.settings.reply_timeout;
        let (servos, rebooted) = self.check(bus, options)?;

        // The present pose, before anything moves.
        let states = self
            .read_states(bus, Fields::POSITION)
            .map_err(step("reading the present pose"))?;
        let mut pose = Vec::with_capacity(self.joints.len());
        let mut present = Vec::with_capacity(self.joints.len());
        let mut refusals = Vec::new();
        for (j, s) in self.joints.iter().zip(states) {
            let s = s.map_err(step("reading the present pose"))?;
            let angle = j.calibration.radians(f64::from(s.position_ticks));
            if s.position_ticks < j.ticks.min || s.position_ticks > j.ticks.max {
                refusals.push(Refusal::OutsideLimits {
                    joint: j.joint,
                    id: j.id,
                    angle_rad: angle,
                    lo: j.limit.lo,
                    hi: j.limit.hi,
                });
            }
            pose.push(angle);
            present.push(s.position_ticks);
        }
        if !refusals.is_empty() {
            return Err(BringUpError::Refused(refusals));
        }

        for j in &self.joints {
            self.prepare(bus, j)
                .map_err(step("writing the servo settings"))?;
        }
        // A watchdog that fired refuses Goal Position writes until 0 is written to it.
        for j in &self.joints {
            bus.write(j.id, Register::BusWatchdog, 0, t)
                .map_err(step("clearing the bus watchdog"))?;
        }
        for (j, &ticks) in self.joints.iter().zip(&present) {
            bus.write(j.id, Register::GoalPosition, i64::from(ticks), t)
                .map_err(step("holding the present pose"))?;
        }
        let watchdog = i64::from(self.settings.watchdog_ms / 20).min(127);
        for j in &self.joints {
            if watchdog > 0 {
                bus.write(j.id, Register::BusWatchdog, watchdog, t)
                    .map_err(step("arming the bus watchdog"))?;
            }
        }
        for j in &self.joints {
            bus.set_torque(j.id, true, t).map_err(step("torque on"))?;
        }
        Ok(BringUp {
            servos,
            pose,
            rebooted,
        })
    }

    /// Step 1 of bring-up: every servo answers, is of the configured model and has no hardware
    /// error (rebooting it first when `options.reboot`).
    pub fn check<B: ServoBus>(
        &self,
        bus: &mut B,
        options: BringUpOptions,
    ) -> Result<(Vec<PingInfo>, Vec<u8>), BringUpError> {
        let t = self.settings.reply_timeout;
        let mut refusals = Vec::new();
        let mut servos = Vec::new();
        let mut rebooted = Vec::new();
        for j in &self.joints {
            let info = match bus.ping(j.id, t) {
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
            let mut errors = bus
                .hardware_errors(j.id, t)
                .map_err(step("reading Hardware Error Status"))?;
            if !errors.is_empty() && options.reboot {
                tracing::warn!(id = j.id, %errors, "rebooting to clear a hardware error");
                reboot_and_wait(bus, j.id, t).map_err(step("rebooting"))?;
                rebooted.push(j.id);
                errors = bus
                    .hardware_errors(j.id, t)
                    .map_err(step("reading Hardware Error Status"))?;
            }
            if !errors.is_empty() {
                refusals.push(Refusal::HardwareError {
                    joint: j.joint,
                    id: j.id,
                    errors,
                });
            }
        }
        if refusals.is_empty() {
            Ok((servos, rebooted))
        } else {
            Err(BringUpError::Refused(refusals))
        }
    }

    /// Step 3 for one servo: acknowledgements on, EEPROM items where they differ, profiles.
    fn prepare<B: ServoBus>(&self, bus: &mut B, j: &JointServo) -> Result<(), ServoError> {
        let t = self.settings.reply_timeout;
        let id = j.id;
        if bus.read(id, Register::StatusReturnLevel, t)?.value != 2 {
            // Below level 2 the write itself is not acknowledged: check by reading back.
            match bus.write(id, Register::StatusReturnLevel, 2, t) {
                Ok(_) | Err(ServoError::Timeout { .. }) => {}
                Err(e) => return Err(e),
            }
            let level = bus.read(id, Register::StatusReturnLevel, t)?.value;
            if level != 2 {
                return Err(ServoError::Malformed {
                    id,
                    what: format!("Status Return Level stays {level} after writing 2"),
                });
            }
        }
        let eeprom = [
            (Register::OperatingMode, 3),
            (
                Register::ReturnDelayTime,
                units::return_delay(self.settings.return_delay_us),
            ),
            (Register::MinPositionLimit, i64::from(j.ticks.min)),
            (Register::MaxPositionLimit, i64::from(j.ticks.max)),
        ];
        let mut changes = Vec::new();
        for (register, value) in eeprom {
            if bus.read(id, register, t)?.value != value {
                changes.push((register, value));
            }
        }
        if !changes.is_empty() {
            if bus.read(id, Register::TorqueEnable, t)?.value != 0 {
                tracing::info!(id, "torque off to write EEPROM settings");
                bus.set_torque(id, false, t)?;
            }
            for (register, value) in changes {
                bus.write(id, register, value, t)?;
            }
        }
        bus.write(
            id,
            Register::ProfileAcceleration,
            units::profile_acceleration(self.settings.profile_acceleration_rad_s2),
            t,
        )?;
        bus.write(
            id,
            Register::ProfileVelocity,
            units::profile_velocity(self.settings.profile_velocity_rad_s),
            t,
        )?;
        Ok(())
    }

    /// Leave the servos as `[bus] on_exit` says: torque off (one Sync Write, then each servo
    /// checked) or hold.
    pub fn shut_down<B: ServoBus>(&self, bus: &mut B) -> Result<(), ShutDownError> {
        match self.settings.on_exit {
            OnExit::Hold => Ok(()),
            OnExit::TorqueOff => self.torque_off(bus),
        }
    }

    /// Torque off every servo: one Sync Write, then each is read back (and written once more if
    /// it still has torque on).
    pub fn torque_off<B: ServoBus>(&self, bus: &mut B) -> Result<(), ShutDownError> {
        let t = self.settings.reply_timeout;
        let values: Vec<(u8, i64)> = self.joints.iter().map(|j| (j.id, 0)).collect();
        let mut failures = Vec::new();
        if let Err(e) = bus.sync_write(Register::TorqueEnable, &values) {
            failures.push(e);
        }
        for j in &self.joints {
            let confirmed = match bus.read(j.id, Register::TorqueEnable, t) {
                Ok(v) if v.value == 0 => Ok(()),
                _ => bus.set_torque(j.id, false, t).map(|_| ()),
            };
            if let Err(e) = confirmed {
                failures.push(e);
            }
        }
        if failures.is_empty() {
            Ok(())
        } else {
            Err(ShutDownError(failures))
        }
    }
}

impl JointServo {
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

/// Reboot `id` and wait until it answers a ping again.
pub fn reboot_and_wait<B: ServoBus>(
    bus: &mut B,
    id: u8,
    timeout: Duration,
) -> Result<(), ServoError> {
    bus.reboot(id, timeout)?;
    let give_up = Instant::now() + REBOOT_WAIT;
    loop {
        match bus.ping(id, timeout) {
            Ok(_) => return Ok(()),
            Err(e) if Instant::now() >= give_up => return Err(e),
            Err(_) => std::thread::sleep(Duration::from_millis(10)),
        }
    }
}
