//! A safety wrapper: [`Limited`] implements [`ServoBus`] around another bus and lets no Goal
//! Position outside a servo's limits through, with an explicit [`Strategy`]: clamp the goal
//! into the limits, or refuse the whole write. Every path a goal can take is checked: Sync
//! Write (so [`ServoBus::write_goals`]) and single writes of Goal Position. A servo without
//! known limits gets no goal at all. Everything else passes through unchanged.

use std::collections::HashMap;
use std::time::Duration;

use super::{Ack, Block, PingInfo, Register, ServoBus, ServoError, Value};

/// What to do with a goal outside the limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Strategy {
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

/// A bus that never writes a goal outside the limits.
#[derive(Debug)]
pub struct Limited<B> {
    inner: B,
    limits: HashMap<u8, TickLimits>,
    strategy: Strategy,
    clamped: u64,
}

impl<B: ServoBus> Limited<B> {
    /// Wrap `inner` with per-servo `limits` (id, limits) and a `strategy`.
    pub fn new(
        inner: B,
        limits: impl IntoIterator<Item = (u8, TickLimits)>,
        strategy: Strategy,
    ) -> Self {
        Self {
            inner,
            limits: limits.into_iter().collect(),
            strategy,
            clamped: 0,
        }
    }

    /// The wrapped bus.
    pub fn inner(&mut self) -> &mut B {
        &mut self.inner
    }

    /// Unwrap.
    pub fn into_inner(self) -> B {
        self.inner
    }

    /// The strategy.
    pub fn strategy(&self) -> Strategy {
        self.strategy
    }

    /// How many goals were clamped so far.
    pub fn clamped(&self) -> u64 {
        self.clamped
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
            Strategy::Clamp => {
                self.clamped += 1;
                Ok(ticks.clamp(lo, hi))
            }
            Strategy::Refuse => Err(ServoError::OutsideLimits {
                id,
                ticks: i32::try_from(ticks).unwrap_or(if ticks < 0 { i32::MIN } else { i32::MAX }),
                min: lim.min,
                max: lim.max,
            }),
        }
    }
}

impl<B: ServoBus> ServoBus for Limited<B> {
    fn baud(&self) -> u32 {
        self.inner.baud()
    }

    fn set_baud(&mut self, baud: u32) -> Result<(), ServoError> {
        self.inner.set_baud(baud)
    }

    fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError> {
        self.inner.ping(id, timeout)
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
        let value = if register == Register::GoalPosition {
            self.check(id, value)?
        } else {
            value
        };
        self.inner.write(id, register, value, timeout)
    }

    fn sync_read(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
    ) -> Result<Vec<Result<Block, ServoError>>, ServoError> {
        self.inner.sync_read(ids, address, len, timeout)
    }

    fn sync_write(&mut self, register: Register, values: &[(u8, i64)]) -> Result<(), ServoError> {
        if register != Register::GoalPosition {
            return self.inner.sync_write(register, values);
        }
        // All or nothing: one refused goal stops the whole packet.
        let checked = values
            .iter()
            .map(|&(id, v)| Ok((id, self.check(id, v)?)))
            .collect::<Result<Vec<_>, ServoError>>()?;
        self.inner.sync_write(register, &checked)
    }

    fn reboot(&mut self, id: u8, timeout: Duration) -> Result<Ack, ServoError> {
        self.inner.reboot(id, timeout)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::servo::Goal;

    /// Records what reaches the wire.
    #[derive(Debug, Default)]
    struct Recorder {
        sync: Vec<(Register, Vec<(u8, i64)>)>,
        writes: Vec<(u8, Register, i64)>,
    }

    impl ServoBus for Recorder {
        fn baud(&self) -> u32 {
            1_000_000
        }
        fn set_baud(&mut self, _: u32) -> Result<(), ServoError> {
            Ok(())
        }
        fn ping(&mut self, id: u8, _: Duration) -> Result<PingInfo, ServoError> {
            Ok(PingInfo {
                id,
                model: 1060,
                firmware: 48,
                alert: false,
            })
        }
        fn scan(&mut self, _: Duration) -> Result<Vec<PingInfo>, ServoError> {
            Ok(Vec::new())
        }
        fn read(&mut self, _: u8, _: Register, _: Duration) -> Result<Value, ServoError> {
            Ok(Value {
                value: 0,
                alert: false,
            })
        }
        fn write(&mut self, id: u8, r: Register, v: i64, _: Duration) -> Result<Ack, ServoError> {
            self.writes.push((id, r, v));
            Ok(Ack { id, alert: false })
        }
        fn sync_read(
            &mut self,
            _: &[u8],
            _: u16,
            _: u16,
            _: Duration,
        ) -> Result<Vec<Result<Block, ServoError>>, ServoError> {
            Ok(Vec::new())
        }
        fn sync_write(&mut self, r: Register, v: &[(u8, i64)]) -> Result<(), ServoError> {
            self.sync.push((r, v.to_vec()));
            Ok(())
        }
        fn reboot(&mut self, id: u8, _: Duration) -> Result<Ack, ServoError> {
            Ok(Ack { id, alert: false })
        }
    }

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
        let mut bus = Limited::new(Recorder::default(), limits(), Strategy::Clamp);
        bus.write_goals(&[Goal { id: 1, ticks: 3500 }, Goal { id: 2, ticks: 10 }])
            .unwrap();
        bus.write(1, Register::GoalPosition, 10, T).unwrap();
        bus.write(1, Register::Led, 1, T).unwrap();
        assert_eq!(bus.clamped(), 2);
        let rec = bus.into_inner();
        assert_eq!(
            rec.sync,
            [(Register::GoalPosition, vec![(1, 3000), (2, 10)])]
        );
        assert_eq!(
            rec.writes,
            [(1, Register::GoalPosition, 1000), (1, Register::Led, 1)]
        );
    }

    #[test]
    fn refuse_writes_nothing_and_names_the_servo() {
        let mut bus = Limited::new(Recorder::default(), limits(), Strategy::Refuse);
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
        bus.write_goals(&[Goal { id: 1, ticks: 1000 }]).unwrap();
        let rec = bus.into_inner();
        assert_eq!(rec.sync, [(Register::GoalPosition, vec![(1, 1000)])]);
        assert!(rec.writes.is_empty());
    }

    #[test]
    fn a_servo_without_limits_gets_no_goal() {
        for strategy in [Strategy::Clamp, Strategy::Refuse] {
            let mut bus = Limited::new(Recorder::default(), limits(), strategy);
            let err = bus.write_goals(&[Goal { id: 9, ticks: 2048 }]).unwrap_err();
            assert!(matches!(err, ServoError::UnknownServo { id: 9 }));
            // Other registers of that servo pass.
            bus.sync_write(Register::TorqueEnable, &[(9, 0)]).unwrap();
            assert_eq!(bus.into_inner().sync.len(), 1);
        }
    }
}
