//! A safety wrapper: [`Limited`] implements [`ServoBus`] around another bus and is the only way
//! the rest of the program reaches the servos.
//!
//! - No Goal Position outside a servo's limits gets through, with an explicit [`LimitPolicy`]:
//!   clamp the goal into the limits, or refuse the whole write. Every path a goal can take is
//!   checked: [`ServoBus::write_goals`], a Sync Write of Goal Position, single writes. A servo
//!   without known limits gets no goal at all.
//! - The registers that decide what a goal means or where the limits lie (Min/Max Position
//!   Limit, Homing Offset, Operating Mode, Drive Mode) and the bus's shape (ID, Baud Rate) are
//!   refused as raw writes ([`ServoError::Protected`]): bring-up sets them through
//!   [`Limited::configure`], which writes only the limits this wrapper holds and position mode.
//! - There is no way back to the raw bus: administrative commands open their own.
//!
//! Everything else passes through unchanged.

use std::collections::HashMap;
use std::time::Duration;

use super::ports::{Ports, ReopenPortError};
use super::{Ack, Goal, PingInfo, ReadKind, Register, ServoBus, ServoError, SyncReadBuf, Value};

/// What to do with a goal outside the limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LimitPolicy {
    /// Move it to the nearest limit and write that.
    Clamp,
    /// Write nothing and return [`ServoError::OutsideLimits`].
    Refuse,
}

/// Goal Position limits of one servo, ticks (inclusive).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TickLimits {
    /// Lowest goal.
    pub min: i32,
    /// Highest goal.
    pub max: i32,
}

/// The EEPROM settings bring-up makes through [`Limited::configure`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Setting {
    /// Operating Mode 3: position control.
    PositionMode,
    /// Min and Max Position Limit: the limits this wrapper holds for the servo.
    PositionLimits,
}

/// Operating Mode value of position control.
pub const POSITION_MODE: i64 = 3;

/// Registers no raw write through [`Limited`] may touch.
pub fn is_protected(register: Register) -> bool {
    matches!(
        register,
        Register::MinPositionLimit
            | Register::MaxPositionLimit
            | Register::HomingOffset
            | Register::OperatingMode
            | Register::DriveMode
            | Register::Id
            | Register::BaudRate
    )
}

/// A bus that never writes a goal outside the limits.
#[derive(Debug)]
pub struct Limited<B> {
    inner: B,
    limits: HashMap<u8, TickLimits>,
    strategy: LimitPolicy,
    clamped: u64,
    /// Checked goals of the last write, reused so a warm write allocates nothing.
    checked: Vec<Goal>,
    checked_values: Vec<(u8, i64)>,
}

impl<B: ServoBus> Limited<B> {
    /// Wrap `inner` with per-servo `limits` (id, limits) and a `strategy`.
    pub fn new(
        inner: B,
        limits: impl IntoIterator<Item = (u8, TickLimits)>,
        strategy: LimitPolicy,
    ) -> Self {
        Self {
            inner,
            limits: limits.into_iter().collect(),
            strategy,
            clamped: 0,
            checked: Vec::new(),
            checked_values: Vec::new(),
        }
    }

    /// The strategy.
    pub fn strategy(&self) -> LimitPolicy {
        self.strategy
    }

    /// How many goals were clamped so far.
    pub fn clamped(&self) -> u64 {
        self.clamped
    }

    /// Servo `id`'s limits, if known.
    pub fn limits(&self, id: u8) -> Option<TickLimits> {
        self.limits.get(&id).copied()
    }

    /// The goal to write for `ticks` on servo `id`, or the refusal.
    pub fn check(&mut self, id: u8, ticks: i64) -> Result<i64, ServoError> {
        let lim = *self
            .limits
            .get(&id)
            .ok_or(ServoError::UnknownServo { id })?;
        let (lo, hi) = (i64::from(lim.min), i64::from(lim.max));
        if (lo..=hi).contains(&ticks) {
            return Ok(ticks);
        }
        match self.strategy {
            LimitPolicy::Clamp => {
                self.clamped += 1;
                Ok(ticks.clamp(lo, hi))
            }
            LimitPolicy::Refuse => Err(ServoError::OutsideLimits {
                id,
                ticks: i32::try_from(ticks).unwrap_or(if ticks < 0 { i32::MIN } else { i32::MAX }),
                min: lim.min,
                max: lim.max,
            }),
        }
    }

    /// Write one of bring-up's EEPROM settings to servo `id` (torque must be off, as for any
    /// EEPROM write): position mode, or the position limits held here for it.
    pub fn configure(
        &mut self,
        id: u8,
        setting: Setting,
        timeout: Duration,
    ) -> Result<(), ServoError> {
        match setting {
            Setting::PositionMode => {
                self.inner
                    .write(id, Register::OperatingMode, POSITION_MODE, timeout)?;
            }
            Setting::PositionLimits => {
                let lim = self.limits(id).ok_or(ServoError::UnknownServo { id })?;
                self.inner
                    .write(id, Register::MinPositionLimit, i64::from(lim.min), timeout)?;
                self.inner
                    .write(id, Register::MaxPositionLimit, i64::from(lim.max), timeout)?;
            }
        }
        Ok(())
    }
}

/// A bus of several ports keeps its limits while a failed port is opened again.
impl<B: ServoBus + Send + 'static> Limited<Ports<B>> {
    /// The ports that failed and were not opened again since ([`Ports::failed`]).
    pub fn failed_ports(&self) -> Vec<&str> {
        self.inner.failed()
    }

    /// Open again only the ports that failed ([`Ports::reopen_failed`]); the others stay open
    /// and locked.
    pub fn reopen_failed<E>(
        &mut self,
        open: impl FnMut(usize) -> Result<B, E>,
    ) -> Result<(), ReopenPortError<E>> {
        self.inner.reopen_failed(open)
    }
}

fn protected(id: u8, register: Register) -> Result<(), ServoError> {
    if is_protected(register) {
        Err(ServoError::Protected { id, register })
    } else {
        Ok(())
    }
}

impl<B: ServoBus> ServoBus for Limited<B> {
    fn baud(&self) -> u32 {
        self.inner.baud()
    }

    fn close(&mut self) {
        self.inner.close()
    }

    fn set_baud(&mut self, baud: u32) -> Result<(), ServoError> {
        self.inner.set_baud(baud)
    }

    fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError> {
        self.inner.ping(id, timeout)
    }

    fn ping_counted(&mut self, id: u8, timeout: Duration) -> Result<(PingInfo, usize), ServoError> {
        self.inner.ping_counted(id, timeout)
    }

    fn scan(&mut self, timeout: Duration) -> Result<Vec<PingInfo>, ServoError> {
        self.inner.scan(timeout)
    }

    fn read(&mut self, id: u8, register: Register, timeout: Duration) -> Result<Value, ServoError> {
        self.inner.read(id, register, timeout)
    }

    fn write(
        &mut self,
        id: u8,
        register: Register,
        value: i64,
        timeout: Duration,
    ) -> Result<Ack, ServoError> {
        protected(id, register)?;
        let value = if register == Register::GoalPosition {
            self.check(id, value)?
        } else {
            value
        };
        self.inner.write(id, register, value, timeout)
    }

    fn sync_read_into(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
        out: &mut SyncReadBuf,
    ) -> Result<(), ServoError> {
        self.inner.sync_read_into(ids, address, len, timeout, out)
    }

    fn sync_write(&mut self, register: Register, values: &[(u8, i64)]) -> Result<(), ServoError> {
        for &(id, _) in values {
            protected(id, register)?;
        }
        if register != Register::GoalPosition {
            return self.inner.sync_write(register, values);
        }
        // All or nothing: one refused goal stops the whole packet.
        let mut checked = std::mem::take(&mut self.checked_values);
        checked.clear();
        let result = values.iter().try_for_each(|&(id, v)| {
            checked.push((id, self.check(id, v)?));
            Ok(())
        });
        let result = result.and_then(|()| self.inner.sync_write(register, &checked));
        self.checked_values = checked;
        result
    }

    fn write_goals(&mut self, goals: &[Goal]) -> Result<(), ServoError> {
        let mut checked = std::mem::take(&mut self.checked);
        checked.clear();
        let result = goals.iter().try_for_each(|g| {
            let ticks = self.check(g.id, i64::from(g.ticks))?;
            checked.push(Goal {
                id: g.id,
                // Within the limits, which are ticks.
                ticks: i32::try_from(ticks).unwrap_or(g.ticks),
            });
            Ok(())
        });
        let result = result.and_then(|()| self.inner.write_goals(&checked));
        self.checked = checked;
        result
    }

    fn reboot(&mut self, id: u8, timeout: Duration) -> Result<Ack, ServoError> {
        self.inner.reboot(id, timeout)
    }

    fn read_kind(&self) -> ReadKind {
        self.inner.read_kind()
    }

    fn set_read_kind(&mut self, kind: ReadKind) -> Result<(), ServoError> {
        self.inner.set_read_kind(kind)
    }

    fn port_index(&self, id: u8) -> usize {
        self.inner.port_index(id)
    }

    fn port_failed(&self, port: usize) -> bool {
        self.inner.port_failed(port)
    }

    fn adapters(&self) -> Vec<Option<super::wire::Adapter>> {
        self.inner.adapters()
    }

    fn read_kinds(&self) -> Vec<ReadKind> {
        self.inner.read_kinds()
    }

    fn set_read_kinds(&mut self, kinds: &[ReadKind]) -> Result<(), ServoError> {
        self.inner.set_read_kinds(kinds)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::servo::record::{Instruction, NullBus, Recording};

    fn limits() -> Vec<(u8, TickLimits)> {
        vec![
            (
                1,
                TickLimits {
                    min: 1000,
                    max: 3000,
                },
            ),
            (2, TickLimits { min: 0, max: 4095 }),
        ]
    }

    const T: Duration = Duration::from_millis(5);

    #[test]
    fn clamp_moves_goals_to_the_nearest_limit() {
        let mut rec = Recording::new(NullBus::new(1060));
        let mut bus = Limited::new(&mut rec, limits(), LimitPolicy::Clamp);
        bus.write_goals(&[Goal { id: 1, ticks: 3500 }, Goal { id: 2, ticks: 10 }])
            .unwrap();
        bus.write(1, Register::GoalPosition, 10, T).unwrap();
        bus.sync_write(Register::GoalPosition, &[(1, 999), (2, 4096)])
            .unwrap();
        bus.write(1, Register::Led, 1, T).unwrap();
        assert_eq!(bus.clamped(), 4);
        drop(bus);
        assert_eq!(
            rec.log(),
            [
                Instruction::SyncWrite(Register::GoalPosition, vec![(1, 3000), (2, 10)]),
                Instruction::Write(1, Register::GoalPosition, 1000),
                Instruction::SyncWrite(Register::GoalPosition, vec![(1, 1000), (2, 4095)]),
                Instruction::Write(1, Register::Led, 1),
            ]
        );
    }

    #[test]
    fn refuse_writes_nothing_and_names_the_servo() {
        let mut rec = Recording::new(NullBus::new(1060));
        let mut bus = Limited::new(&mut rec, limits(), LimitPolicy::Refuse);
        let err = bus
            .write_goals(&[Goal { id: 2, ticks: 5 }, Goal { id: 1, ticks: 999 }])
            .unwrap_err();
        assert!(matches!(
            err,
            ServoError::OutsideLimits {
                id: 1,
                ticks: 999,
                min: 1000,
                max: 3000
            }
        ));
        assert!(err.to_string().contains("servo 1"), "{err}");
        assert!(bus.write(1, Register::GoalPosition, 3001, T).is_err());
        assert!(bus
            .sync_write(Register::GoalPosition, &[(2, 7), (1, 3001)])
            .is_err());
        bus.write_goals(&[Goal { id: 1, ticks: 1000 }]).unwrap();
        drop(bus);
        assert_eq!(
            rec.log(),
            [Instruction::SyncWrite(
                Register::GoalPosition,
                vec![(1, 1000)]
            )]
        );
    }

    #[test]
    fn a_servo_without_limits_gets_no_goal() {
        for strategy in [LimitPolicy::Clamp, LimitPolicy::Refuse] {
            let mut rec = Recording::new(NullBus::new(1060));
            let mut bus = Limited::new(&mut rec, limits(), strategy);
            let err = bus.write_goals(&[Goal { id: 9, ticks: 2048 }]).unwrap_err();
            assert!(matches!(err, ServoError::UnknownServo { id: 9 }));
            // Other registers of that servo pass.
            bus.sync_write(Register::TorqueEnable, &[(9, 0)]).unwrap();
            drop(bus);
            assert_eq!(
                rec.log(),
                [Instruction::SyncWrite(Register::TorqueEnable, vec![(9, 0)])]
            );
        }
    }

    #[test]
    fn raw_writes_to_the_registers_bring_up_owns_are_refused() {
        let mut rec = Recording::new(NullBus::new(1060));
        let mut bus = Limited::new(&mut rec, limits(), LimitPolicy::Clamp);
        for register in [
            Register::MinPositionLimit,
            Register::MaxPositionLimit,
            Register::HomingOffset,
            Register::OperatingMode,
            Register::DriveMode,
            Register::Id,
            Register::BaudRate,
        ] {
            let err = bus.write(1, register, 0, T).unwrap_err();
            assert!(
                matches!(err, ServoError::Protected { id: 1, register: r } if r == register),
                "{err}"
            );
            assert!(bus.sync_write(register, &[(2, 0)]).is_err());
        }
        // The typed path writes exactly position mode and the limits held for the servo.
        bus.configure(1, Setting::PositionMode, T).unwrap();
        bus.configure(1, Setting::PositionLimits, T).unwrap();
        assert!(matches!(
            bus.configure(9, Setting::PositionLimits, T),
            Err(ServoError::UnknownServo { id: 9 })
        ));
        drop(bus);
        assert_eq!(
            rec.log(),
            [
                Instruction::Write(1, Register::OperatingMode, 3),
                Instruction::Write(1, Register::MinPositionLimit, 1000),
                Instruction::Write(1, Register::MaxPositionLimit, 3000),
            ]
        );
    }
}
