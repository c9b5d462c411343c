//! [`Recording`]: a bus that logs every instruction it passes on, in order, so tests can check
//! not only where a procedure leaves the servos but the order it got there (goal = present
//! position before torque on, the watchdog cleared before the goal is written). [`NullBus`]
//! beside it is a bus of servos that acknowledge everything and read zero, for tests of the
//! wrappers themselves.

use std::time::Duration;

use super::{Ack, Goal, PingInfo, ReadKind, Register, ServoBus, ServoError, SyncReadBuf, Value};

/// One instruction as sent.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Instruction {
    /// The port's baud rate was changed.
    SetBaud(u32),
    /// Ping of one servo.
    Ping(u8),
    /// Broadcast ping.
    Scan,
    /// Read of one register.
    Read(u8, Register),
    /// Write of one register.
    Write(u8, Register, i64),
    /// Sync Read of `len` bytes at `address` from these servos.
    SyncRead {
        /// The servos, in order.
        ids: Vec<u8>,
        /// First address.
        address: u16,
        /// Bytes per servo.
        len: u16,
    },
    /// Sync Write of one register.
    SyncWrite(Register, Vec<(u8, i64)>),
    /// Reboot of one servo.
    Reboot(u8),
}

/// A bus that records every instruction before passing it on to `inner`.
#[derive(Debug)]
pub struct Recording<B> {
    inner: B,
    log: Vec<Instruction>,
}

impl<B: ServoBus> Recording<B> {
    /// Record what goes to `inner`.
    pub fn new(inner: B) -> Self {
        Self {
            inner,
            log: Vec::new(),
        }
    }

    /// Everything sent so far, in order.
    pub fn log(&self) -> &[Instruction] {
        &self.log
    }

    /// Forget what was recorded.
    pub fn clear(&mut self) {
        self.log.clear();
    }

    /// The recorded bus.
    pub fn inner(&mut self) -> &mut B {
        &mut self.inner
    }
}

impl<B: ServoBus> ServoBus for Recording<B> {
    fn baud(&self) -> u32 {
        self.inner.baud()
    }
    fn close(&mut self) {
        self.inner.close()
    }
    fn set_baud(&mut self, baud: u32) -> Result<(), ServoError> {
        self.log.push(Instruction::SetBaud(baud));
        self.inner.set_baud(baud)
    }
    fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError> {
        self.log.push(Instruction::Ping(id));
        self.inner.ping(id, timeout)
    }
    fn ping_counted(&mut self, id: u8, timeout: Duration) -> Result<(PingInfo, usize), ServoError> {
        self.log.push(Instruction::Ping(id));
        self.inner.ping_counted(id, timeout)
    }
    fn scan(&mut self, timeout: Duration) -> Result<Vec<PingInfo>, ServoError> {
        self.log.push(Instruction::Scan);
        self.inner.scan(timeout)
    }
    fn read(&mut self, id: u8, register: Register, timeout: Duration) -> Result<Value, ServoError> {
        self.log.push(Instruction::Read(id, register));
        self.inner.read(id, register, timeout)
    }
    fn write(
        &mut self,
        id: u8,
        register: Register,
        value: i64,
        timeout: Duration,
    ) -> Result<Ack, ServoError> {
        self.log.push(Instruction::Write(id, register, value));
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
        self.log.push(Instruction::SyncRead {
            ids: ids.to_vec(),
            address,
            len,
        });
        self.inner.sync_read_into(ids, address, len, timeout, out)
    }
    fn sync_write(&mut self, register: Register, values: &[(u8, i64)]) -> Result<(), ServoError> {
        self.log
            .push(Instruction::SyncWrite(register, values.to_vec()));
        self.inner.sync_write(register, values)
    }
    fn write_goals(&mut self, goals: &[Goal]) -> Result<(), ServoError> {
        self.log.push(Instruction::SyncWrite(
            Register::GoalPosition,
            goals.iter().map(|g| (g.id, i64::from(g.ticks))).collect(),
        ));
        self.inner.write_goals(goals)
    }
    fn reboot(&mut self, id: u8, timeout: Duration) -> Result<Ack, ServoError> {
        self.log.push(Instruction::Reboot(id));
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

/// A bus on which every servo answers: pings with one model number, reads 0, acknowledges every
/// write; a sync read returns zeros for every servo.
#[derive(Debug, Clone, Copy)]
pub struct NullBus {
    model: u16,
}

impl NullBus {
    /// Servos of Model Number `model`.
    pub fn new(model: u16) -> Self {
        Self { model }
    }
}

impl ServoBus for NullBus {
    fn baud(&self) -> u32 {
        1_000_000
    }
    fn set_baud(&mut self, _: u32) -> Result<(), ServoError> {
        Ok(())
    }
    fn ping(&mut self, id: u8, _: Duration) -> Result<PingInfo, ServoError> {
        Ok(PingInfo {
            id,
            model: self.model,
            firmware: 1,
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
    fn write(&mut self, id: u8, _: Register, _: i64, _: Duration) -> Result<Ack, ServoError> {
        Ok(Ack { id, alert: false })
    }
    fn sync_read_into(
        &mut self,
        ids: &[u8],
        _: u16,
        len: u16,
        timeout: Duration,
        out: &mut SyncReadBuf,
    ) -> Result<(), ServoError> {
        out.reset(ids, len, timeout);
        let zeros = [0u8; 64];
        for i in 0..ids.len() {
            out.set(i, zeros.get(..usize::from(len)).unwrap_or_default(), false);
        }
        Ok(())
    }
    fn sync_write(&mut self, _: Register, _: &[(u8, i64)]) -> Result<(), ServoError> {
        Ok(())
    }
    fn write_goals(&mut self, _: &[Goal]) -> Result<(), ServoError> {
        Ok(())
    }
    fn reboot(&mut self, id: u8, _: Duration) -> Result<Ack, ServoError> {
        Ok(Ack { id, alert: false })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::servo::Fields;

    /// A bus that overrides the provided calls, to check a reference does not bypass them.
    struct Overrides(Vec<&'static str>);

    impl ServoBus for Overrides {
        fn baud(&self) -> u32 {
            1
        }
        fn set_baud(&mut self, _: u32) -> Result<(), ServoError> {
            Ok(())
        }
        fn ping(&mut self, id: u8, t: Duration) -> Result<PingInfo, ServoError> {
            NullBus::new(1).ping(id, t)
        }
        fn scan(&mut self, _: Duration) -> Result<Vec<PingInfo>, ServoError> {
            Ok(Vec::new())
        }
        fn read(&mut self, id: u8, r: Register, t: Duration) -> Result<Value, ServoError> {
            self.0.push("read");
            NullBus::new(1).read(id, r, t)
        }
        fn write(&mut self, id: u8, _: Register, _: i64, _: Duration) -> Result<Ack, ServoError> {
            self.0.push("write");
            Ok(Ack { id, alert: false })
        }
        fn sync_read_into(
            &mut self,
            ids: &[u8],
            a: u16,
            l: u16,
            t: Duration,
            out: &mut SyncReadBuf,
        ) -> Result<(), ServoError> {
            self.0.push("sync_read_into");
            NullBus::new(1).sync_read_into(ids, a, l, t, out)
        }
        fn sync_write(&mut self, _: Register, _: &[(u8, i64)]) -> Result<(), ServoError> {
            self.0.push("sync_write");
            Ok(())
        }
        fn write_goals(&mut self, _: &[Goal]) -> Result<(), ServoError> {
            self.0.push("write_goals");
            Ok(())
        }
        fn reboot(&mut self, id: u8, _: Duration) -> Result<Ack, ServoError> {
            Ok(Ack { id, alert: false })
        }
        fn sync_read(
            &mut self,
            _: &[u8],
            _: u16,
            _: u16,
            _: Duration,
        ) -> Result<Vec<Result<crate::servo::Block, ServoError>>, ServoError> {
            self.0.push("sync_read");
            Ok(Vec::new())
        }
        fn read_states_into(
            &mut self,
            _: &[u8],
            _: Fields,
            _: Duration,
            _: &mut crate::servo::States,
        ) -> Result<(), ServoError> {
            self.0.push("read_states_into");
            Ok(())
        }
        fn read_block_into(
            &mut self,
            _: &[u8],
            _: crate::servo::Layout,
            _: Duration,
            _: &mut crate::servo::States,
        ) -> Result<(), ServoError> {
            self.0.push("read_block_into");
            Ok(())
        }
        fn read_states(
            &mut self,
            _: &[u8],
            _: Fields,
            _: Duration,
        ) -> Result<Vec<crate::servo::Reading>, ServoError> {
            self.0.push("read_states");
            Ok(Vec::new())
        }
        fn set_torque(&mut self, id: u8, _: bool, _: Duration) -> Result<Ack, ServoError> {
            self.0.push("set_torque");
            Ok(Ack { id, alert: false })
        }
        fn hardware_errors(
            &mut self,
            _: u8,
            _: Duration,
        ) -> Result<crate::servo::HardwareErrors, ServoError> {
            self.0.push("hardware_errors");
            Ok(crate::servo::HardwareErrors(0))
        }
    }

    fn use_every_call(mut bus: impl ServoBus) {
        let t = Duration::from_millis(1);
        bus.write_goals(&[Goal { id: 1, ticks: 0 }]).unwrap();
        bus.sync_read(&[1], 132, 4, t).unwrap();
        bus.read_states_into(&[1], Fields::POSITION, t, &mut crate::servo::States::new())
            .unwrap();
        bus.read_states(&[1], Fields::POSITION, t).unwrap();
        let layout = crate::servo::Layout::Indirect {
            data: 224,
            watchdog: false,
        };
        bus.read_block_into(&[1], layout, t, &mut crate::servo::States::new())
            .unwrap();
        bus.set_torque(1, true, t).unwrap();
        bus.hardware_errors(1, t).unwrap();
    }

    #[test]
    fn a_reference_forwards_the_provided_calls_too() {
        let mut bus = Overrides(Vec::new());
        use_every_call(&mut bus);
        use_every_call(&mut &mut bus);
        let once = [
            "write_goals",
            "sync_read",
            "read_states_into",
            "read_states",
            "read_block_into",
            "set_torque",
            "hardware_errors",
        ];
        assert_eq!(bus.0, [once, once].concat());
    }

    #[test]
    fn the_log_keeps_the_order_of_instructions() {
        let mut rec = Recording::new(NullBus::new(1060));
        let t = Duration::from_millis(1);
        rec.ping(3, t).unwrap();
        rec.write(3, Register::BusWatchdog, 0, t).unwrap();
        rec.write_goals(&[Goal { id: 3, ticks: 2048 }]).unwrap();
        let states = rec.read_states(&[3], Fields::POSITION, t).unwrap();
        assert_eq!(states[0].as_ref().unwrap().position_ticks, 0);
        assert_eq!(
            rec.log(),
            [
                Instruction::Ping(3),
                Instruction::Write(3, Register::BusWatchdog, 0),
                Instruction::SyncWrite(Register::GoalPosition, vec![(3, 2048)]),
                Instruction::SyncRead {
                    ids: vec![3],
                    address: 132,
                    len: 4
                },
            ]
        );
    }
}
