//! The loop's logic on an in-memory bus and a manual clock: the fault matrix, each case in a
//! few thousand ticks of manual time, no sleep, no pseudo-terminal.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use serde_json::json;
use tokio::sync::{broadcast, oneshot};

use super::port::ReopenError;
use super::{Cycle, Pace, Parts};
use crate::config::Config;
use crate::daemon::link::{Envelope, Handle};
use crate::protocol::{
    Answer, CmdName, Code, Event, FaultChange, FaultKind, LoopCmd, Motion, Outcome, Reply, State,
    StopReason, What,
};
use crate::servo::arm::Arm;
use crate::servo::clock::{Clock, ManualClock};
use crate::servo::limits::{LimitPolicy, Limited};
use crate::servo::{
    Ack, Goal, Layout, PingInfo, ReadKind, Register, ServoBus, ServoError, ServoModel, SyncReadBuf,
    Value, INDIRECT_ADDRESS_1,
};
use crate::world::{CheckedObstacle, Obstacles};

const MS: Duration = Duration::from_millis(1);

/// One servo's control table, and how it misbehaves.
#[derive(Debug, Clone)]
struct Servo {
    table: Vec<u8>,
    silent: bool,
}

impl Servo {
    fn get(&self, r: Register) -> i64 {
        let a = usize::from(r.address());
        r.decode(&self.table[a..a + usize::from(r.size())]).unwrap()
    }
    fn set(&mut self, r: Register, v: i64) {
        let a = usize::from(r.address());
        let n = usize::from(r.size());
        self.table[a..a + n].copy_from_slice(&r.encode(v)[..n]);
    }
    fn alert(&self) -> bool {
        self.get(Register::HardwareErrorStatus) != 0
    }
    /// A write as the servo takes it: Torque Enable 1 is refused while a hardware error is
    /// latched (only a reboot clears it), a goal while its Bus Watchdog has fired (until 0 is
    /// written there). The motor reaches a goal it takes at once.
    fn take(&mut self, r: Register, v: i64) {
        if (r == Register::TorqueEnable && v == 1 && self.alert())
            || (r == Register::GoalPosition && self.get(Register::BusWatchdog) < 0)
        {
            return;
        }
        self.set(r, v);
        if r == Register::GoalPosition {
            self.set(Register::PresentPosition, v);
        }
    }
    /// The byte at `address`, Indirect Data read through its Indirect Address (0, the reset
    /// value here, stands for the Indirect Data itself, which reads 0).
    fn byte(&self, address: usize) -> u8 {
        let model = ServoModel::from_number(self.get(Register::ModelNumber) as u16);
        let data = model.and_then(ServoModel::indirect_data).map(usize::from);
        match data {
            Some(d) if (d..d + 20).contains(&address) => {
                let slot = usize::from(INDIRECT_ADDRESS_1) + 2 * (address - d);
                let target =
                    usize::from(u16::from_le_bytes([self.table[slot], self.table[slot + 1]]));
                if target == 0 {
                    0
                } else {
                    self.table[target]
                }
            }
            _ => self.table[address],
        }
    }
}

#[derive(Debug, Default)]
struct Wire {
    servos: BTreeMap<u8, Servo>,
    port_gone: bool,
    /// The (address, length) of every Sync Read, in order.
    reads: Vec<(u16, u16)>,
    /// When set, a wait for a reply that never comes costs its timeout on this clock, as on a
    /// real port.
    clock: Option<ManualClock>,
    /// What a Sync Read costs on that clock, as the wire time of a real port.
    read_cost: Duration,
    /// A Sync Write of this register with this value, once the first servo has taken it,
    /// silences the second: a servo that drops off the bus in the middle of a sequence of
    /// writes (the same servo twice), or another one at that moment.
    mute_on: Option<(Register, i64, u8, u8)>,
    /// What opening the port again costs on the clock (the adapter's enumeration, bring-up).
    open_cost: Duration,
    /// How long a servo boots after REBOOT, deaf (on `clock`; zero: it answers at once)...
    boot: Duration,
    /// ...or it never comes back.
    never_back: bool,
    /// The servos booting, and when each answers again (`None`: never).
    booting: BTreeMap<u8, Option<Instant>>,
    /// Reads (not pings) waited on in vain for a servo, and Sync Writes of Torque Enable.
    vain_reads: usize,
    torque_writes: usize,
}

impl Wire {
    /// The servos whose boot is over answer again.
    fn wake(&mut self) {
        let Some(now) = self.clock.as_ref().map(ManualClock::now) else {
            return;
        };
        let done: Vec<u8> = self
            .booting
            .iter()
            .filter(|(_, until)| until.is_some_and(|u| now >= u))
            .map(|(&id, _)| id)
            .collect();
        for id in done {
            self.booting.remove(&id);
            if let Some(s) = self.servos.get_mut(&id) {
                s.silent = false;
            }
        }
    }
}

/// An in-memory chain of servos whose motors reach every goal at once. Clones share it; the
/// read kind is each handle's own, as each opened port's is.
#[derive(Debug, Clone, Default)]
struct MemoryBus(Arc<Mutex<Wire>>, ReadKind);

impl MemoryBus {
    fn wire(&self) -> MutexGuard<'_, Wire> {
        self.0.lock().unwrap()
    }
    fn servo(&self, id: u8, f: impl FnOnce(&mut Servo)) {
        f(self.wire().servos.get_mut(&id).unwrap());
    }
    fn port(&self) -> Result<(), ServoError> {
        if self.wire().port_gone {
            return Err(ServoError::Io(std::io::Error::new(
                std::io::ErrorKind::BrokenPipe,
                "the adapter is gone",
            )));
        }
        Ok(())
    }
    fn answering(&self, id: u8, timeout: Duration) -> Result<(), ServoError> {
        self.port()?;
        let mut w = self.wire();
        w.wake();
        match w.servos.get(&id) {
            Some(s) if !s.silent => Ok(()),
            _ => {
                if let Some(c) = &w.clock {
                    c.advance(timeout);
                }
                Err(ServoError::Timeout {
                    id,
                    waited: timeout,
                })
            }
        }
    }
    /// Servo `id` loses its power: silent (and limp) until [`MemoryBus::power_back`].
    fn lose_power(&self, id: u8) {
        self.servo(id, |s| {
            s.silent = true;
            s.set(Register::TorqueEnable, 0);
        });
    }
    /// Servo `id` answers again with its RAM at the defaults.
    fn power_back(&self, id: u8) {
        self.servo(id, |s| {
            s.silent = false;
            s.reset_ram();
        });
    }
    fn torque(&self, id: u8) -> i64 {
        self.wire().servos[&id].get(Register::TorqueEnable)
    }
}

impl Servo {
    /// Its RAM at the defaults, as after a power cycle or a reboot.
    fn reset_ram(&mut self) {
        let s = self;
        {
            for r in [
                Register::TorqueEnable,
                Register::BusWatchdog,
                Register::ProfileAcceleration,
                Register::ProfileVelocity,
                Register::HardwareErrorStatus,
            ] {
                s.set(r, 0);
            }
            for n in 1..=20 {
                s.set(Register::IndirectAddress(n), 0);
            }
            let present = s.get(Register::PresentPosition);
            s.set(Register::GoalPosition, present);
        }
    }
}

impl ServoBus for MemoryBus {
    fn baud(&self) -> u32 {
        1_000_000
    }
    fn set_baud(&mut self, _: u32) -> Result<(), ServoError> {
        Ok(())
    }
    fn ping(&mut self, id: u8, timeout: Duration) -> Result<PingInfo, ServoError> {
        self.answering(id, timeout)?;
        let w = self.wire();
        let s = &w.servos[&id];
        Ok(PingInfo {
            id,
            model: s.get(Register::ModelNumber) as u16,
            firmware: 46,
            alert: s.alert(),
        })
    }
    fn scan(&mut self, timeout: Duration) -> Result<Vec<PingInfo>, ServoError> {
        let ids: Vec<u8> = self.wire().servos.keys().copied().collect();
        Ok(ids
            .into_iter()
            .filter_map(|id| self.ping(id, timeout).ok())
            .collect())
    }
    fn read(&mut self, id: u8, r: Register, timeout: Duration) -> Result<Value, ServoError> {
        if let Err(e) = self.answering(id, timeout) {
            self.wire().vain_reads += 1;
            return Err(e);
        }
        let w = self.wire();
        let s = &w.servos[&id];
        Ok(Value {
            value: s.get(r),
            alert: s.alert(),
        })
    }
    fn write(&mut self, id: u8, r: Register, v: i64, timeout: Duration) -> Result<Ack, ServoError> {
        self.answering(id, timeout)?;
        let mut w = self.wire();
        let s = w.servos.get_mut(&id).unwrap();
        s.take(r, v);
        Ok(Ack {
            id,
            alert: s.alert(),
        })
    }
    fn sync_read_into(
        &mut self,
        ids: &[u8],
        address: u16,
        len: u16,
        timeout: Duration,
        out: &mut SyncReadBuf,
    ) -> Result<(), ServoError> {
        self.port()?;
        out.reset(ids, len, timeout);
        let mut w = self.wire();
        w.wake();
        w.reads.push((address, len));
        let mut missing = false;
        for (i, id) in ids.iter().enumerate() {
            if let Some(s) = w.servos.get(id).filter(|s| !s.silent) {
                let a = usize::from(address);
                let data: Vec<u8> = (a..a + usize::from(len)).map(|k| s.byte(k)).collect();
                out.set(i, &data, s.alert());
            } else {
                missing = true;
            }
        }
        if let (true, Some(c)) = (missing, &w.clock) {
            c.advance(timeout);
        }
        if missing {
            w.vain_reads += 1;
        }
        if let Some(c) = &w.clock {
            c.advance(w.read_cost);
        }
        Ok(())
    }
    fn sync_write(&mut self, r: Register, values: &[(u8, i64)]) -> Result<(), ServoError> {
        self.port()?;
        let mut w = self.wire();
        w.wake();
        if r == Register::TorqueEnable {
            w.torque_writes += 1;
        }
        let mute_on = w.mute_on;
        for &(id, v) in values {
            if let Some(s) = w.servos.get_mut(&id).filter(|s| !s.silent) {
                s.take(r, v);
                if let Some((_, _, _, muted)) = mute_on.filter(|m| (m.0, m.1, m.2) == (r, v, id)) {
                    if let Some(m) = w.servos.get_mut(&muted) {
                        m.silent = true;
                    }
                }
            }
        }
        Ok(())
    }
    fn write_goals(&mut self, goals: &[Goal]) -> Result<(), ServoError> {
        self.port()?;
        let mut w = self.wire();
        w.wake();
        for g in goals {
            if let Some(s) = w.servos.get_mut(&g.id).filter(|s| !s.silent) {
                s.take(Register::GoalPosition, g.ticks.into());
            }
        }
        Ok(())
    }
    fn reboot(&mut self, id: u8, timeout: Duration) -> Result<Ack, ServoError> {
        self.answering(id, timeout)?;
        let mut w = self.wire();
        let until = match (w.never_back, &w.clock) {
            (true, _) => Some(None),
            (false, Some(c)) if !w.boot.is_zero() => Some(Some(c.now() + w.boot)),
            _ => None,
        };
        let s = w.servos.get_mut(&id).unwrap();
        s.reset_ram();
        if let Some(until) = until {
            s.silent = true;
            w.booting.insert(id, until);
        }
        Ok(Ack { id, alert: false })
    }
    fn read_kind(&self) -> ReadKind {
        self.1
    }
    fn set_read_kind(&mut self, kind: ReadKind) -> Result<(), ServoError> {
        self.1 = kind;
        Ok(())
    }
}

/// A loop on the shipped simulated arm's config (12 joints) at `rate_hz`, its servos in memory
/// at the home pose, on a manual clock.
struct Rig {
    cycle: Cycle<MemoryBus, ManualClock>,
    handle: Handle,
    bus: MemoryBus,
    clock: ManualClock,
    pace: Pace,
    events: broadcast::Receiver<Event>,
    next_id: u64,
}

impl Rig {
    fn new(rate_hz: f64, control: &str) -> Rig {
        Self::with_tables(rate_hz, control, "")
    }

    /// [`Rig::new`] with `tables` (such as a `[world]`) added at the end of the file.
    fn with_tables(rate_hz: f64, control: &str, tables: &str) -> Rig {
        Self::edited(rate_hz, control, tables, &[])
    }

    /// [`Rig::with_tables`] with `edits` (`(old, new)`, each replacing its first occurrence,
    /// which must exist) applied to the shipped config first.
    fn edited(rate_hz: f64, control: &str, tables: &str, edits: &[(&str, &str)]) -> Rig {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
        let mut text = std::fs::read_to_string(path).unwrap();
        for (old, new) in edits {
            assert!(text.contains(old), "config/sim.toml has no `{old}`");
            text = text.replacen(old, new, 1);
        }
        let text = text.replace(
            "rate_hz = 100.0",
            &format!("rate_hz = {rate_hz:?}\n{control}"),
        ) + tables;
        let config = Config::from_str(&text, path).unwrap();
        let arm = config.arm().unwrap().clone();
        let bus = MemoryBus::default();
        let home = arm.goals(config.home()).unwrap();
        for (j, g) in arm.joints().iter().zip(&home) {
            let mut s = Servo {
                table: vec![0; 256],
                silent: false,
            };
            s.set(Register::ModelNumber, j.model.model_number().into());
            s.set(Register::TemperatureLimit, 80);
            s.set(Register::MaxVoltageLimit, 140);
            s.set(Register::MinVoltageLimit, 60);
            s.set(Register::PresentInputVoltage, 120);
            s.set(Register::PresentTemperature, 30);
            s.set(Register::PresentPosition, g.ticks.into());
            bus.wire().servos.insert(j.id, s);
        }
        let reopen = bus.clone();
        let parts = Parts {
            bus: arm.limited(bus.clone(), LimitPolicy::Clamp),
            port: Some("/dev/memory".into()),
            servo_ports: Vec::new(),
            arm,
            opener: Box::new(move |arm: &Arm, bus: &mut Limited<MemoryBus>| {
                bus.close();
                let w = reopen.wire();
                if let Some(c) = &w.clock {
                    c.advance(w.open_cost);
                }
                if w.port_gone {
                    return Err(ReopenError::NoPath);
                }
                drop(w);
                *bus = arm.limited(reopen.clone(), LimitPolicy::Clamp);
                Ok(())
            }),
            clock: ManualClock::new(),
            sims: Vec::new(),
        };
        let clock = parts.clock.clone();
        let (mut cycle, handle) = Cycle::new(&config, parts).unwrap();
        let events = handle.events.subscribe();
        cycle.read_everything();
        bus.wire().clock = Some(clock.clone());
        let pace = Pace {
            deadline: clock.now(),
            stop_since: None,
        };
        Rig {
            cycle,
            handle,
            bus,
            clock,
            pace,
            events,
            next_id: 0,
        }
    }

    /// `n` ticks on schedule.
    fn ticks(&mut self, n: usize) {
        for _ in 0..n {
            assert!(self.cycle.turn(&mut self.pace, false));
        }
    }

    /// Queues `cmd` from client 1; its answer comes with the next tick.
    fn send(&mut self, cmd: LoopCmd) -> oneshot::Receiver<Answer> {
        let (reply, answer) = oneshot::channel();
        self.next_id += 1;
        self.handle
            .commands
            .try_send(Envelope {
                client: 1,
                id: Some(Arc::new(json!(self.next_id))),
                cmd,
                received: self.clock.now(),
                reply,
                later: None,
            })
            .unwrap();
        answer
    }

    /// `cmd` applied in one tick: its answer.
    fn command(&mut self, cmd: LoopCmd) -> Answer {
        let mut answer = self.send(cmd);
        self.ticks(1);
        answer
            .try_recv()
            .expect("answered in the tick that applied it")
    }

    fn status(&self) -> crate::protocol::Telemetry {
        self.handle.telemetry.borrow().clone()
    }

    /// The events since the last call.
    fn events(&mut self) -> Vec<Event> {
        std::iter::from_fn(|| self.events.try_recv().ok()).collect()
    }

    /// After a recovery from fired Bus Watchdogs: those of `ids` are armed again, the arm
    /// holds with no overrun, and each of `ids` moves away from where it stood (`stuck`) under
    /// a goto.
    fn obeys_again_after_its_watchdog(&mut self, ids: &[u8], stuck: &[i64]) {
        for id in ids {
            let armed = self.bus.wire().servos[id].get(Register::BusWatchdog);
            assert!(armed > 0, "servo {id}: not re-armed");
        }
        let s = self.status();
        assert_eq!(s.state, State::Holding);
        assert_eq!(s.overruns, 0, "no stall");
        self.slow_goto();
        self.ticks(100);
        for (id, &from) in ids.iter().zip(stuck) {
            let now = self.bus.wire().servos[id].get(Register::PresentPosition);
            assert_ne!(now, from, "servo {id} still refuses goals");
        }
    }

    /// A goto 5 cm to the side of the present tip, slow enough to still be moving a second on.
    fn slow_goto(&mut self) {
        let tip = self.status().tip;
        let goto = LoopCmd::Motion(Motion::Goto {
            target: [tip[0] + 0.05, tip[1]],
            speed: Some(0.01),
        });
        self.command(goto).unwrap();
    }
}

fn fault_events(events: &[Event], change: FaultChange) -> Vec<(Option<u8>, FaultKind, u64)> {
    events
        .iter()
        .filter_map(|e| match &e.what {
            What::Fault { reason, fault, .. } if *reason == change => {
                Some((fault.id, fault.kind, fault.since_tick))
            }
            _ => None,
        })
        .collect()
}

fn stopped_for_fault(e: &Event) -> bool {
    matches!(
        e.what,
        What::Stopped {
            reason: StopReason::Fault,
            ..
        }
    )
}

/// How many reads it takes to declare a servo silent at `rate_hz` with the `[control]` lines
/// `control`: from the first read it missed to the one that declared it, both counted.
fn reads_to_declare_silent(rate_hz: f64, control: &str) -> u64 {
    let mut rig = Rig::new(rate_hz, control);
    rig.ticks(5);
    rig.bus.servo(5, |s| s.silent = true);
    let first_missed = rig.status().tick + 1;
    for _ in 0..10_000 {
        rig.ticks(1);
        if rig.status().state == State::Fault {
            return rig.status().tick - first_missed + 1;
        }
    }
    panic!("servo 5 never declared silent at {rate_hz} Hz");
}

#[test]
fn the_error_budget_is_50_ms_at_every_loop_rate() {
    assert_eq!(reads_to_declare_silent(100.0, ""), 5);
    assert_eq!(reads_to_declare_silent(1000.0, ""), 50);
    // At 25 Hz a read every 40 ms: the second miss spends the budget (the config refuses a
    // budget a single miss would spend, such as 50 ms at 20 Hz).
    assert_eq!(reads_to_declare_silent(25.0, ""), 2);
}

#[test]
fn a_custom_budget_is_honoured_and_the_deprecated_count_converts() {
    assert_eq!(reads_to_declare_silent(100.0, "max_silence_ms = 120"), 12);
    assert_eq!(reads_to_declare_silent(500.0, "max_missed_reads = 7"), 7);
}

#[test]
fn a_fault_during_a_move_holds_the_arm_ends_the_move_and_clears_when_the_servo_answers() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(10);
    assert_eq!(rig.status().state, State::Moving);
    rig.events();
    rig.bus.servo(5, |s| s.silent = true);
    rig.ticks(5);
    let s = rig.status();
    assert_eq!(s.state, State::Fault);
    let held = s.theta_cmd.clone();
    let events = rig.events();
    assert_eq!(
        fault_events(&events, FaultChange::Raised),
        vec![(Some(5), FaultKind::Silent, s.tick - 4)]
    );
    assert!(events.iter().any(stopped_for_fault), "{events:?}");
    assert_eq!(s.command.as_ref().unwrap().outcome, Outcome::Fault);
    assert_eq!(s.faults.len(), 1);
    assert!(
        s.faults[0].detail.contains("50 ms"),
        "{}",
        s.faults[0].detail
    );
    // Held: goals frozen, motion refused with the fault named.
    rig.ticks(20);
    assert_eq!(rig.status().theta_cmd, held);
    let refused = rig.command(LoopCmd::Motion(Motion::Home)).unwrap_err();
    assert_eq!(refused.code, Code::Fault);
    assert!(
        refused.message.contains("servo 5 (joint 5): silent"),
        "{}",
        refused.message
    );
    // It answers again: cleared, holding the measured pose, and the arm moves again.
    rig.bus.servo(5, |s| s.silent = false);
    rig.ticks(1);
    let s = rig.status();
    assert_eq!(s.state, State::Holding);
    assert!(s.faults.is_empty());
    assert_eq!(
        fault_events(&rig.events(), FaultChange::Cleared),
        vec![(Some(5), FaultKind::Silent, s.tick - 26)]
    );
    rig.slow_goto();
    rig.ticks(1);
    assert_eq!(rig.status().state, State::Moving);
}

/// Servo 5 silent long enough for its Bus Watchdog to fire, then answering, and dropping off
/// the bus again right after the recovery cleared its watchdog, before it could arm it again.
/// Returns the armed value.
fn cut_short_watchdog_recovery(rig: &mut Rig) -> i64 {
    let armed = rig.bus.wire().servos[&1].get(Register::BusWatchdog);
    assert!(armed > 0, "bring-up armed the Bus Watchdog");
    declare_silent(rig, 5);
    rig.bus.servo(5, |s| {
        s.set(Register::BusWatchdog, -1);
        s.silent = false;
    });
    rig.bus.wire().mute_on = Some((Register::BusWatchdog, 0, 5, 5));
    rig.ticks(1);
    assert_eq!(rig.bus.wire().servos[&5].get(Register::BusWatchdog), 0);
    assert_eq!(rig.status().state, State::Fault, "the recovery failed");
    rig.bus.wire().mute_on = None;
    rig.events();
    armed
}

/// The arm recovered, holding with torque on, and no servo was taken for one that lost power.
fn holding_with_no_power_loss(rig: &mut Rig) {
    let events = rig.events();
    let raised = fault_events(&events, FaultChange::Raised);
    assert!(
        raised.iter().all(|r| r.1 != FaultKind::PowerLoss),
        "{events:?}"
    );
    let s = rig.status();
    assert_eq!(
        (s.state, s.torque),
        (State::Holding, true),
        "{:?}",
        s.faults
    );
}

#[test]
fn a_servo_whose_watchdog_recovery_was_cut_short_is_not_taken_for_a_power_loss() {
    let mut rig = Rig::new(100.0, "");
    let armed = cut_short_watchdog_recovery(&mut rig);
    // Back again, its RAM as the cut recovery left it (powered all along): not a power loss,
    // and the next try of the recovery arms the watchdog.
    rig.bus.servo(5, |s| s.silent = false);
    rig.ticks(200);
    holding_with_no_power_loss(&mut rig);
    assert_eq!(rig.bus.wire().servos[&5].get(Register::BusWatchdog), armed);
}

#[test]
fn a_recovery_that_fails_at_its_torque_step_leaves_the_arm_holding_with_torque_on() {
    let mut rig = Rig::new(100.0, "");
    declare_silent(&mut rig, 5);
    rig.bus.servo(5, |s| s.silent = false);
    // Servo 9 drops off as the recovery's Torque Enable 1 reaches servo 1: the recovery fails
    // at its last step.
    rig.bus.wire().mute_on = Some((Register::TorqueEnable, 1, 1, 9));
    rig.ticks(1);
    rig.bus.wire().mute_on = None;
    assert_eq!(rig.status().state, State::Fault, "the recovery failed");
    // Nothing was switched off: the arm still holds with torque on every servo that hears.
    for id in (1..=12).filter(|&id| id != 9) {
        assert_eq!(
            rig.bus.wire().servos[&id].get(Register::TorqueEnable),
            1,
            "servo {id}"
        );
    }
    rig.events();
    // Servo 9 back: recovered, and no servo's torque taken for a power loss.
    rig.bus.servo(9, |s| s.silent = false);
    rig.ticks(200);
    holding_with_no_power_loss(&mut rig);
}

#[test]
fn a_power_loss_after_a_watchdog_recovery_cut_short_is_still_told_by_the_other_registers() {
    let mut rig = Rig::new(100.0, "");
    cut_short_watchdog_recovery(&mut rig);
    rig.bus.lose_power(5);
    rig.ticks(3);
    rig.bus.power_back(5);
    rig.ticks(1);
    let raised = fault_events(&rig.events(), FaultChange::Raised);
    assert_eq!(raised.len(), 1, "{raised:?}");
    assert_eq!((raised[0].0, raised[0].1), (Some(5), FaultKind::PowerLoss));
    let s = rig.status();
    assert_eq!((s.state, s.torque), (State::Estop, false));
    let detail = &s.faults[0].detail;
    assert!(detail.contains("Torque Enable 0"), "{detail}");
    assert!(!detail.contains("Bus Watchdog 0"), "{detail}");
}

#[test]
fn a_hardware_error_holds_until_reboot_which_brings_torque_back() {
    let mut rig = Rig::new(100.0, "");
    rig.bus.servo(3, |s| {
        s.set(Register::HardwareErrorStatus, 0x20);
        s.set(Register::TorqueEnable, 0);
    });
    rig.ticks(1);
    let s = rig.status();
    assert_eq!(s.state, State::Fault);
    assert_eq!(s.faults[0].kind, FaultKind::HardwareError);
    assert!(
        s.faults[0].detail.contains("overload"),
        "{}",
        s.faults[0].detail
    );
    assert_eq!(
        rig.command(LoopCmd::Torque { on: true }).unwrap_err().code,
        Code::Fault
    );
    let answer = rig.command(LoopCmd::Reboot { ids: None }).unwrap();
    match answer.reply {
        Reply::Rebooted(r) => assert_eq!(r.rebooted, vec![3], "only the servo in hardware error"),
        other => panic!("not a reboot's reply: {other:?}"),
    }
    let s = rig.status();
    assert_eq!(s.state, State::Holding);
    assert!(s.torque && s.faults.is_empty());
    let torque = rig.bus.wire().servos[&3].get(Register::TorqueEnable);
    assert_eq!(torque, 1, "brought up again with torque on");
    rig.slow_goto();
}

/// A servo in hardware error (torque off by its own Shutdown, refusing torque on), then the
/// port lost and back: the faults the trial left stuck.
fn hardware_error_then_port_lost(rig: &mut Rig, id: u8) {
    rig.bus.wire().port_gone = true;
    rig.ticks(1);
    let kinds: Vec<FaultKind> = rig.status().faults.iter().map(|f| f.kind).collect();
    assert!(kinds.contains(&FaultKind::Port), "{kinds:?}");
    // Unplugged long enough for every Bus Watchdog to fire.
    for s in rig.bus.wire().servos.values_mut() {
        s.set(Register::BusWatchdog, -1);
    }
    rig.bus.servo(id, |s| {
        s.set(Register::HardwareErrorStatus, 0x20);
        s.set(Register::TorqueEnable, 0);
    });
    rig.bus.wire().port_gone = false;
    // Reopened a second after the loss, recovered on the tick after.
    rig.ticks(105);
}

/// After the port came back: only the hardware error holds, and `reboot` clears it.
fn only_the_hardware_error_holds_then_reboot_clears_it(rig: &mut Rig, id: u8) {
    let s = rig.status();
    let faults: Vec<(FaultKind, Option<u8>)> = s.faults.iter().map(|f| (f.kind, f.id)).collect();
    assert_eq!(
        faults,
        vec![(FaultKind::HardwareError, Some(id))],
        "the port fault clears once the port is back; the hardware error stays"
    );
    assert_eq!(s.state, State::Fault);
    for (&other, servo) in &rig.bus.wire().servos {
        if other != id {
            assert_eq!(servo.get(Register::TorqueEnable), 1, "servo {other} holds");
            assert!(
                servo.get(Register::BusWatchdog) > 0,
                "servo {other} re-armed"
            );
        }
    }
    let answer = rig.command(LoopCmd::Reboot { ids: None }).unwrap();
    match answer.reply {
        Reply::Rebooted(r) => assert_eq!(r.rebooted, vec![id]),
        other => panic!("not a reboot's reply: {other:?}"),
    }
    let s = rig.status();
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    assert_eq!(s.state, State::Holding);
    assert!(s.torque);
    assert_eq!(rig.bus.torque(id), 1, "brought up again with torque on");
    rig.slow_goto();
}

#[test]
fn a_hardware_error_then_a_lost_port_clears_the_port_fault_once_back_and_reboot_clears_the_rest() {
    let mut rig = Rig::new(100.0, "");
    rig.bus.servo(9, |s| {
        s.set(Register::HardwareErrorStatus, 0x20);
        s.set(Register::TorqueEnable, 0);
    });
    rig.ticks(1);
    assert_eq!(rig.status().faults[0].kind, FaultKind::HardwareError);
    hardware_error_then_port_lost(&mut rig, 9);
    only_the_hardware_error_holds_then_reboot_clears_it(&mut rig, 9);
}

#[test]
fn a_hardware_error_latched_while_the_port_was_lost_is_found_on_its_recovery() {
    let mut rig = Rig::new(100.0, "");
    hardware_error_then_port_lost(&mut rig, 4);
    let raised = fault_events(&rig.events(), FaultChange::Raised);
    assert!(
        raised
            .iter()
            .any(|r| (r.0, r.1) == (Some(4), FaultKind::HardwareError)),
        "{raised:?}"
    );
    only_the_hardware_error_holds_then_reboot_clears_it(&mut rig, 4);
}

#[test]
fn an_estop_while_the_port_is_lost_stays_latched_when_the_port_comes_back() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(3);
    rig.bus.wire().port_gone = true;
    rig.ticks(1);
    let s = rig.status();
    assert_eq!(s.state, State::Fault);
    assert_eq!(s.faults[0].kind, FaultKind::Port);
    rig.command(LoopCmd::Estop).unwrap();
    assert_eq!(rig.status().state, State::Estop);
    // Reopened once a second; gone still after the first try.
    rig.ticks(150);
    assert_eq!(rig.status().faults.len(), 1);
    rig.bus.wire().port_gone = false;
    rig.ticks(100);
    let s = rig.status();
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    assert_eq!(s.state, State::Estop, "the latch outlives the fault");
    assert_eq!(
        rig.command(LoopCmd::Motion(Motion::Home)).unwrap_err().code,
        Code::Estopped
    );
    rig.command(LoopCmd::Reset).unwrap();
    assert_eq!(rig.status().state, State::Holding);
    assert!(rig.status().torque);
}

#[test]
fn a_reopening_that_takes_its_whole_tick_leaves_the_recovery_to_the_next() {
    let mut rig = Rig::new(100.0, "");
    rig.bus.wire().port_gone = true;
    rig.ticks(1);
    let lost = rig.status().tick;
    rig.bus.wire().port_gone = false;
    // Opening takes longer than a period: nothing of that tick is left for the recovery.
    rig.bus.wire().open_cost = 15 * MS;
    let mut cleared = None;
    for _ in 0..400 {
        rig.ticks(1);
        let events = rig.events();
        if let Some(c) = fault_events(&events, FaultChange::Cleared).first() {
            assert_eq!(c.1, FaultKind::Port);
            cleared = Some(rig.status().tick);
            break;
        }
    }
    let cleared = cleared.expect("the port came back");
    // Opened on the first try, a second after the loss (the opening overran: one tick fewer
    // in that second), and recovered on the tick after.
    assert!(
        cleared - lost <= 102,
        "cleared {} ticks after the loss",
        cleared - lost
    );
    let s = rig.status();
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    assert_eq!(s.state, State::Holding);
}

#[test]
fn the_recovery_on_a_reopened_port_is_tried_each_tick_for_a_second() {
    let mut rig = Rig::new(100.0, "");
    rig.bus.wire().port_gone = true;
    rig.ticks(1);
    let lost = rig.status().tick;
    // The port comes back with servo 3 not answering yet: opened on the first try, a second
    // after the loss, the arm cannot recover on it.
    rig.bus.wire().port_gone = false;
    rig.bus.servo(3, |s| s.silent = true);
    rig.ticks(130);
    assert_eq!(rig.status().faults[0].kind, FaultKind::Port);
    rig.events();
    rig.bus.servo(3, |s| s.silent = false);
    rig.ticks(1);
    let cleared = fault_events(&rig.events(), FaultChange::Cleared);
    assert_eq!(cleared.len(), 1, "recovered on the next tick: {cleared:?}");
    assert_eq!(cleared[0].1, FaultKind::Port);
    let s = rig.status();
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    assert_eq!(s.state, State::Holding);
    assert!(s.tick - lost < 200, "before the next opening");
}

#[test]
fn a_reopened_port_reads_as_bring_up_chose() {
    // The shipped config reads `auto`; these servos ping firmware 46.
    let mut rig = Rig::new(100.0, "");
    assert_eq!(rig.cycle.port.bus().read_kind(), ReadKind::Fast);
    rig.bus.wire().port_gone = true;
    rig.ticks(1);
    assert_eq!(rig.status().faults[0].kind, FaultKind::Port);
    rig.bus.wire().port_gone = false;
    rig.ticks(150);
    assert!(rig.status().faults.is_empty());
    assert_eq!(rig.cycle.port.bus().read_kind(), ReadKind::Fast);
}

#[test]
fn a_stall_past_the_bus_watchdog_recovers_the_servos_whose_watchdog_fired() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(2);
    rig.events();
    // The process stood still 300 ms; servos 2 and 7 saw their Bus Watchdog fire.
    rig.clock.advance(300 * MS);
    for id in [2, 7] {
        rig.bus.servo(id, |s| s.set(Register::BusWatchdog, -1));
    }
    rig.ticks(1);
    let events = rig.events();
    let recovered = fault_events(&events, FaultChange::Recovered);
    assert_eq!(
        recovered.iter().map(|r| (r.0, r.1)).collect::<Vec<_>>(),
        vec![
            (Some(2), FaultKind::Watchdog),
            (Some(7), FaultKind::Watchdog)
        ]
    );
    assert!(events.iter().any(stopped_for_fault), "{events:?}");
    for id in [2, 7] {
        assert!(
            rig.bus.wire().servos[&id].get(Register::BusWatchdog) > 0,
            "re-armed"
        );
    }
    assert_eq!(rig.status().state, State::Holding, "recovered at once");
    rig.ticks(1);
    let s = rig.status();
    assert_eq!(s.overruns, 30, "the stall's periods count as overruns");
}

#[test]
fn a_bus_watchdog_that_fired_without_a_stall_the_loop_measured_is_found_and_recovered() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(2);
    rig.events();
    rig.bus.wire().reads.clear();
    // The servos saw a longer gap between goals than the loop measured (their view, a starved
    // simulator thread, a USB hiccup): servos 2 and 7 stopped and refuse goals. The loop
    // itself ran on schedule.
    for id in [2, 7] {
        rig.bus.servo(id, |s| s.set(Register::BusWatchdog, -1));
    }
    let stuck: Vec<i64> = [2, 7]
        .iter()
        .map(|id| rig.bus.wire().servos[id].get(Register::PresentPosition))
        .collect();
    let mut recovered = Vec::new();
    let mut events = Vec::new();
    // Found by the next read of the health rotation (every `health_every` = 10 reads).
    for _ in 0..11 {
        rig.ticks(1);
        events.extend(rig.events());
        recovered = fault_events(&events, FaultChange::Recovered);
        if !recovered.is_empty() {
            break;
        }
    }
    assert_eq!(
        recovered.iter().map(|r| (r.0, r.1)).collect::<Vec<_>>(),
        vec![
            (Some(2), FaultKind::Watchdog),
            (Some(7), FaultKind::Watchdog)
        ],
        "{events:?}"
    );
    assert!(events.iter().any(stopped_for_fault), "{events:?}");
    rig.obeys_again_after_its_watchdog(&[2, 7], &stuck);
}

#[test]
fn the_bus_watchdog_costs_one_byte_a_servo_on_one_read_in_health_every() {
    let mut rig = Rig::new(100.0, "");
    rig.ticks(5);
    rig.bus.wire().reads.clear();
    rig.ticks(100);
    let reads = rig.bus.wire().reads.clone();
    assert_eq!(reads.len(), 100, "one read a tick, nothing else");
    let extended = reads.iter().filter(|r| **r == (224, 14)).count();
    let ordinary = reads.iter().filter(|r| **r == (224, 13)).count();
    assert_eq!((extended, ordinary), (10, 90), "{reads:?}");
}

#[test]
fn after_every_servo_went_silent_and_came_back_goals_jump_only_onto_the_servos_positions() {
    let mut rig = Rig::new(100.0, "");
    let bound = rig.cycle.controller.limits().max_joint_speed_rad_s * rig.cycle.schedule.dt;
    let ids = rig.cycle.ids.clone();
    // A joint move at the joint-speed limit: the servos, deaf while silent, fall behind the
    // goals the loop commands before it declares them silent.
    let mut theta = rig.status().theta_cmd;
    theta[2] += 1.5;
    rig.command(LoopCmd::Motion(Motion::GotoJoints { theta }))
        .unwrap();
    rig.ticks(2);
    let mut before = rig.status().theta_cmd;
    let mut faulted = false;
    let mut recovered = false;
    for tick in 0..200 {
        match tick {
            5 => ids
                .iter()
                .for_each(|&id| rig.bus.servo(id, |s| s.silent = true)),
            40 => ids
                .iter()
                .for_each(|&id| rig.bus.servo(id, |s| s.silent = false)),
            _ => {}
        }
        rig.ticks(1);
        let s = rig.status();
        faulted |= s.state == State::Fault;
        let step = before
            .iter()
            .zip(&s.theta_cmd)
            .map(|(a, b)| (b - a).abs())
            .fold(0.0, f64::max);
        let recovered_now = faulted && !recovered && s.state != State::Fault;
        if step > bound + 1e-9 || recovered_now {
            // Only a recovery moves goals faster, and only onto where the servos stand.
            assert!(recovered_now, "tick {}: goals stepped {step}", s.tick);
            let arm = rig.cycle.arm.clone();
            for (i, id) in ids.iter().enumerate() {
                let ticks = rig.bus.wire().servos[id].get(Register::PresentPosition);
                let at = arm.angle(i, ticks as i32).unwrap();
                assert!(
                    (s.theta_cmd[i] - at).abs() < 1e-9,
                    "tick {}: joint {} goal {} but the servo stands at {at}",
                    s.tick,
                    i + 1,
                    s.theta_cmd[i]
                );
            }
            recovered = true;
        }
        before = s.theta_cmd;
    }
    assert!(faulted, "the silence was never held");
    assert!(recovered, "never recovered");
    assert_eq!(rig.status().state, State::Holding);
}

/// The last joint an XL330, whose Indirect Data lies elsewhere than the XL430s': no common
/// Indirect Address block, so the loop reads the registers where they are.
fn rig_without_indirect_address() -> Rig {
    let rig = Rig::edited(
        100.0,
        "",
        "",
        &[(
            "id = 12\nmodel = \"XL430-W250\"",
            "id = 12\nmodel = \"XL330-M288\"",
        )],
    );
    assert!(
        matches!(rig.cycle.layout, Layout::Direct(_)),
        "{:?}",
        rig.cycle.layout
    );
    rig
}

#[test]
fn without_indirect_address_a_fired_bus_watchdog_is_found_by_the_rotation_and_recovered() {
    let mut rig = rig_without_indirect_address();
    let health_every = rig.cycle.schedule.health_every;
    let servos = rig.cycle.ids.len() as u64;
    rig.slow_goto();
    rig.ticks(2);
    rig.events();
    // The worst case: the servo whose watchdog the rotation read last fires right after, so
    // the loop comes back to it only once every other servo's has been read.
    rig.ticks(health_every as usize);
    let last =
        rig.cycle.ids[(rig.cycle.watch_next + rig.cycle.ids.len() - 1) % rig.cycle.ids.len()];
    rig.bus.servo(last, |s| s.set(Register::BusWatchdog, -1));
    let stuck = rig.bus.wire().servos[&last].get(Register::PresentPosition);
    let fired_at = rig.status().tick;
    let mut events = Vec::new();
    let mut recovered = Vec::new();
    // One servo's watchdog a health read (every `health_every` ticks): each servo's within
    // `servos` health reads, and the one found fired recovered at the start of the next tick.
    for _ in 0..servos * health_every + 1 {
        rig.ticks(1);
        events.extend(rig.events());
        recovered = fault_events(&events, FaultChange::Recovered);
        if !recovered.is_empty() {
            break;
        }
    }
    let took = rig.status().tick - fired_at;
    assert_eq!(
        recovered.iter().map(|r| (r.0, r.1)).collect::<Vec<_>>(),
        vec![(Some(last), FaultKind::Watchdog)],
        "not recovered within {took} ticks: {events:?}"
    );
    assert!(
        took > (servos - 1) * health_every,
        "found after {took} ticks: before the rotation came back to it"
    );
    assert!(events.iter().any(stopped_for_fault), "{events:?}");
    rig.obeys_again_after_its_watchdog(&[last], &[stuck]);
}

#[test]
fn what_waits_for_the_end_of_a_tick_is_woken_by_it_with_its_snapshot_out() {
    use futures_util::FutureExt;
    let mut rig = Rig::new(100.0, "");
    rig.ticks(1);
    let before = rig.status().tick;
    let tick_done = Arc::clone(&rig.handle.tick_done);
    let notified = tick_done.notified();
    tokio::pin!(notified);
    notified.as_mut().enable();
    assert!((&mut notified).now_or_never().is_none(), "no tick yet");
    rig.ticks(1);
    assert!(notified.now_or_never().is_some(), "the tick woke it");
    assert_eq!(rig.status().tick, before + 1, "its snapshot was out first");
}

#[test]
fn overruns_count_the_periods_a_late_tick_skipped() {
    let mut rig = Rig::new(100.0, "");
    rig.ticks(10);
    assert_eq!(rig.status().overruns, 0);
    let tick = rig.status().tick;
    // The next tick starts 35 ms late: the periods due at +10, +20 and +30 ms are missed, and
    // the next tick starts as soon as this one ends.
    rig.clock.advance(35 * MS);
    rig.ticks(1);
    assert_eq!(
        rig.status().tick,
        tick + 1,
        "one tick ran late, none ran twice"
    );
    // Telemetry goes out before the tick's lateness is known: the next one reports it.
    rig.ticks(1);
    let s = rig.status();
    assert_eq!((s.tick, s.overruns), (tick + 2, 3));
    rig.ticks(10);
    assert_eq!(rig.status().overruns, 3, "back on schedule");
}

#[test]
fn past_the_rate_its_work_allows_the_loop_runs_back_to_back_not_at_half_rate() {
    let mut rig = Rig::new(100.0, "");
    rig.ticks(5);
    assert!(!rig.status().behind);
    // Each read now takes 15 ms of a 10 ms period.
    rig.bus.wire().read_cost = 15 * MS;
    let start = rig.clock.now();
    rig.ticks(40);
    assert_eq!(
        rig.clock.now() - start,
        40 * 15 * MS,
        "each tick as long as its work: none waits for the next whole period"
    );
    let s = rig.status();
    assert!(s.behind, "telemetry says the loop is behind its rate");
    assert!(s.overruns >= 39, "every late tick counted: {}", s.overruns);
    // The work fits again: the schedule is anchored on the last late tick, no catch-up burst.
    rig.bus.wire().read_cost = Duration::ZERO;
    let start = rig.clock.now();
    rig.ticks(10);
    assert_eq!(rig.clock.now() - start, 10 * 10 * MS);
    let overruns = rig.status().overruns;
    rig.ticks(10);
    assert_eq!(rig.status().overruns, overruns, "on schedule again");
}

#[test]
fn reset_stats_starts_the_statistics_again_but_not_the_counters() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(50);
    let s = rig.status();
    assert!(s.m3_total_rad2 > 0.0 && s.peak_joint_speed_rad_s > 0.0);
    rig.bus.servo(4, |s| s.silent = true);
    rig.ticks(2);
    rig.bus.servo(4, |s| s.silent = false);
    let dropped = rig.status().counters.dropped;
    assert_eq!(dropped, 2);
    rig.command(LoopCmd::ResetStats).unwrap();
    rig.ticks(1);
    let s = rig.status();
    assert_eq!(
        (s.m3_total_rad2 > 0.0, s.counters.dropped),
        (true, 2),
        "moving still"
    );
    let summary = rig.cycle.stats.summary(rig.cycle.tick, rig.clock.now());
    assert_eq!(summary.ticks, 1, "counted from the tick that applied it");
    rig.command(LoopCmd::Stop).unwrap();
    rig.ticks(200);
    rig.command(LoopCmd::ResetStats).unwrap();
    let s = rig.status();
    assert_eq!((s.m3_total_rad2, s.peak_joint_speed_rad_s), (0.0, 0.0));
    assert_eq!(s.counters.dropped, 2);
}

#[test]
fn health_warnings_come_before_the_servo_limits_with_hysteresis() {
    let mut rig = Rig::new(100.0, "");
    // Temperature Limit 80 °C: a warning at 75, cleared below 74.
    rig.bus
        .servo(6, |s| s.set(Register::PresentTemperature, 75));
    rig.ticks(10);
    let s = rig.status();
    assert_eq!(s.warnings.len(), 1);
    assert_eq!(
        (s.warnings[0].id, s.warnings[0].kind),
        (Some(6), FaultKind::Temperature)
    );
    assert_eq!(s.temperature_c[5], 75.0);
    rig.bus
        .servo(6, |s| s.set(Register::PresentTemperature, 74));
    rig.ticks(10);
    assert_eq!(rig.status().warnings.len(), 1, "inside the hysteresis");
    rig.bus
        .servo(6, |s| s.set(Register::PresentTemperature, 73));
    rig.ticks(10);
    assert!(rig.status().warnings.is_empty());
    let events = rig.events();
    let warnings: Vec<_> = events
        .iter()
        .filter_map(|e| match &e.what {
            What::Warning { reason, .. } => Some(*reason),
            _ => None,
        })
        .collect();
    assert_eq!(warnings, vec![FaultChange::Raised, FaultChange::Cleared]);
    assert_eq!(
        rig.status().state,
        State::Holding,
        "a warning never holds the arm"
    );
}

#[test]
fn the_shut_down_brings_the_arm_to_rest_then_ends() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(5);
    let mut turns = 0;
    while rig.cycle.turn(&mut rig.pace, true) {
        turns += 1;
        assert!(turns < 1000, "never came to rest");
    }
    assert!(turns > 0, "decelerated over some ticks");
    assert_eq!(rig.status().state, State::Holding);
    let refused = rig.send(LoopCmd::Motion(Motion::Home));
    rig.cycle.answer_queued_for_exit();
    let mut refused = refused;
    assert_eq!(
        refused.try_recv().unwrap().unwrap_err().code,
        Code::ShuttingDown
    );
}

#[test]
fn a_shut_down_while_a_fault_holds_the_arm_ends_at_once() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(3);
    rig.bus.servo(5, |s| s.silent = true);
    rig.ticks(5);
    assert_eq!(rig.status().state, State::Fault);
    // Held and frozen: at rest already, so the first turn of the shut-down is the last.
    assert!(!rig.cycle.turn(&mut rig.pace, true));
}

/// Ticks until servo `id`, silent, is held for it.
fn declare_silent(rig: &mut Rig, id: u8) {
    rig.bus.servo(id, |s| s.silent = true);
    for _ in 0..100 {
        rig.ticks(1);
        if rig.status().faults.iter().any(|f| f.id == Some(id)) {
            return;
        }
    }
    panic!("servo {id} never declared silent");
}

#[test]
fn an_estop_with_a_silent_servo_is_answered_in_its_tick_without_an_overrun() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(3);
    declare_silent(&mut rig, 5);
    rig.ticks(2);
    let before = rig.status();
    let start = rig.clock.now();
    let mut answer = rig.send(LoopCmd::Estop);
    rig.ticks(1);
    let applied = answer
        .try_recv()
        .expect("answered in the tick that applied it");
    assert!(applied.is_ok(), "{applied:?}");
    rig.ticks(1);
    let s = rig.status();
    assert_eq!(s.state, State::Estop);
    assert!(!s.torque);
    assert_eq!(s.overruns, before.overruns, "the estop cost an overrun");
    // Two ticks on schedule: the silent servo was never waited on.
    assert_eq!(rig.clock.now() - start, 20 * MS);
    for id in (1..=12).filter(|&id| id != 5) {
        assert_eq!(
            rig.bus.torque(id),
            0,
            "servo {id} torque on after the estop"
        );
    }
}

#[test]
fn torque_off_with_a_silent_servo_costs_no_overrun_and_says_torque_off() {
    let mut rig = Rig::new(100.0, "");
    rig.command(LoopCmd::Torque { on: false }).unwrap();
    let s = rig.status();
    assert_eq!((s.state, s.torque), (State::TorqueOff, false));
    assert!((1..=12).all(|id| rig.bus.torque(id) == 0));
    rig.command(LoopCmd::Torque { on: true }).unwrap();
    let s = rig.status();
    assert_eq!((s.state, s.torque), (State::Holding, true));
    assert!((1..=12).all(|id| rig.bus.torque(id) == 1));
    // Servo 8 missed a read (not yet declared silent): torque off does not wait on it.
    rig.bus.servo(8, |s| s.silent = true);
    rig.ticks(1);
    let overruns = rig.status().overruns;
    let start = rig.clock.now();
    rig.command(LoopCmd::Torque { on: false }).unwrap();
    rig.ticks(1);
    assert_eq!(rig.status().overruns, overruns);
    assert_eq!(rig.clock.now() - start, 20 * MS);
    assert!((1..=12)
        .filter(|&id| id != 8)
        .all(|id| rig.bus.torque(id) == 0));
    assert_eq!(rig.status().state, State::TorqueOff);
    // It answers again: the torque off it missed reaches it.
    assert_eq!(rig.bus.torque(8), 1);
    rig.bus.servo(8, |s| s.silent = false);
    rig.ticks(1);
    assert_eq!(rig.bus.torque(8), 0, "servo 8 kept its torque");
}

#[test]
fn reset_and_torque_on_with_a_silent_servo_are_refused_with_fault_naming_it() {
    let mut rig = Rig::new(100.0, "");
    rig.command(LoopCmd::Estop).unwrap();
    declare_silent(&mut rig, 5);
    let overruns = rig.status().overruns;
    let refused = rig.command(LoopCmd::Reset).unwrap_err();
    assert_eq!(refused.code, Code::Fault, "{refused:?}");
    assert!(
        refused
            .message
            .contains("servo 5 (joint 5) does not answer"),
        "{}",
        refused.message
    );
    assert_eq!(rig.status().state, State::Estop, "the latch stays");
    rig.bus.servo(5, |s| s.silent = false);
    rig.ticks(1);
    rig.command(LoopCmd::Reset).unwrap();
    assert_eq!(rig.status().state, State::Holding);
    rig.command(LoopCmd::Torque { on: false }).unwrap();
    rig.bus.servo(9, |s| s.silent = true);
    rig.ticks(1);
    // Asked within the tick, in vain: refused, naming it.
    let refused = rig.command(LoopCmd::Torque { on: true }).unwrap_err();
    assert_eq!(refused.code, Code::Fault, "{refused:?}");
    assert!(refused.message.contains("servo 9"), "{}", refused.message);
    rig.ticks(2);
    assert_eq!(rig.status().overruns, overruns, "a refusal cost an overrun");
}

#[test]
fn a_servo_that_lost_power_latches_the_arm_and_only_reset_brings_torque_back() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(3);
    rig.bus.lose_power(5);
    rig.ticks(20);
    assert_eq!(rig.status().state, State::Fault);
    rig.events();
    rig.bus.power_back(5);
    rig.ticks(1);
    let s = rig.status();
    assert_eq!(s.state, State::Estop, "latched, not recovered");
    assert!(!s.torque);
    let events = rig.events();
    assert!(
        events
            .iter()
            .any(|e| matches!(e.what, What::Estop { .. }) && e.owner.is_none()),
        "{events:?}"
    );
    let raised: Vec<_> = events
        .iter()
        .filter_map(|e| match &e.what {
            What::Fault {
                reason: FaultChange::Raised,
                fault,
                ..
            } => Some(fault.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(raised.len(), 1, "{events:?}");
    assert_eq!(
        (raised[0].id, raised[0].joint, raised[0].kind),
        (Some(5), Some(5), FaultKind::PowerLoss)
    );
    assert!(
        raised[0].detail.contains("Bus Watchdog 0"),
        "{}",
        raised[0].detail
    );
    assert_eq!(s.faults.len(), 1);
    // Its RAM written again, torque off everywhere, for as long as nobody resets.
    assert!(rig.bus.wire().servos[&5].get(Register::BusWatchdog) > 0);
    rig.ticks(50);
    assert!((1..=12).all(|id| rig.bus.torque(id) == 0));
    assert_eq!(
        rig.command(LoopCmd::Torque { on: true }).unwrap_err().code,
        Code::Estopped
    );
    assert_eq!(
        rig.command(LoopCmd::Motion(Motion::Home)).unwrap_err().code,
        Code::Estopped
    );
    rig.command(LoopCmd::Reset).unwrap();
    let s = rig.status();
    assert_eq!((s.state, s.torque), (State::Holding, true));
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    assert!((1..=12).all(|id| rig.bus.torque(id) == 1));
    assert_eq!(
        fault_events(&rig.events(), FaultChange::Cleared),
        vec![(Some(5), FaultKind::PowerLoss, raised[0].since_tick)]
    );
}

#[test]
fn a_port_fault_names_the_port_not_a_servo() {
    let mut rig = Rig::new(100.0, "");
    rig.bus.wire().port_gone = true;
    rig.ticks(1);
    let f = rig.status().faults[0].clone();
    assert_eq!(f.kind, FaultKind::Port);
    assert_eq!((f.id, f.joint), (None, None));
    assert_eq!(f.port.as_deref(), Some("/dev/memory"));
    let refused = rig.command(LoopCmd::Motion(Motion::Home)).unwrap_err();
    assert!(
        refused.message.contains("port /dev/memory"),
        "{}",
        refused.message
    );
}

#[test]
fn a_shut_down_with_a_silent_servo_does_not_wait_on_it_and_names_it() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(3);
    declare_silent(&mut rig, 5);
    assert!(!rig.cycle.turn(&mut rig.pace, true));
    let Rig {
        cycle, bus, clock, ..
    } = rig;
    let start = clock.now();
    let err = cycle.shut_down(false).unwrap_err();
    assert_eq!(clock.now(), start, "waited on the silent servo");
    match err {
        crate::daemon::DaemonError::ShutDown(e) => {
            let ids: Vec<u8> = e.unreached.iter().map(|u| u.id).collect();
            assert_eq!(ids, vec![5], "{e}");
            assert!(e.to_string().contains("servo 5 (joint 5)"), "{e}");
        }
        other => panic!("not a shut-down error: {other}"),
    }
    assert!((1..=12).filter(|&id| id != 5).all(|id| bus.torque(id) == 0));
}

/// Servo 3 in hardware error, its servos booting for `boot` after a REBOOT (`None`: never
/// back); the loop at 100 Hz.
fn rig_with_a_servo_to_reboot(boot: Option<Duration>) -> Rig {
    let mut rig = Rig::new(100.0, "");
    rig.bus.servo(3, |s| {
        s.set(Register::HardwareErrorStatus, 0x20);
        s.set(Register::TorqueEnable, 0);
    });
    rig.ticks(1);
    assert_eq!(rig.status().state, State::Fault);
    match boot {
        Some(b) => rig.bus.wire().boot = b,
        None => rig.bus.wire().never_back = true,
    }
    rig
}

#[test]
fn the_loop_ticks_on_and_serves_an_estop_while_rebooted_servos_boot() {
    let mut rig = rig_with_a_servo_to_reboot(Some(400 * MS));
    let mut reboot = rig.send(LoopCmd::Reboot { ids: None });
    let t0 = rig.status().tick;
    rig.ticks(10);
    assert!(reboot.try_recv().is_err(), "answered before servo 3 booted");
    assert_eq!(rig.status().tick, t0 + 10, "telemetry every tick meanwhile");
    // Moving and switching torque wait for the reboot; an estop does not.
    let goto = LoopCmd::Motion(Motion::Goto {
        target: [0.3, 0.3],
        speed: None,
    });
    let busy = rig.command(goto).unwrap_err();
    assert_eq!(busy.code, Code::Busy);
    assert!(
        busy.message.contains("servos [3] are rebooting"),
        "{}",
        busy.message
    );
    let vain = rig.bus.wire().vain_reads;
    rig.command(LoopCmd::Estop).unwrap();
    assert_eq!(rig.status().state, State::Estop);
    assert!((1..=12)
        .filter(|&id| id != 3)
        .all(|id| rig.bus.torque(id) == 0));
    // The booting servo is not waited on for its torque off, nor asked again each tick.
    assert_eq!(
        rig.bus.wire().vain_reads,
        vain,
        "waited on the booting servo"
    );
    let torque_writes = rig.bus.wire().torque_writes;
    rig.ticks(10);
    assert_eq!(rig.bus.wire().torque_writes, torque_writes);
    rig.events();
    // The boot, 400 ms in all: no fault is raised for the servo that does not answer.
    let mut answer = None;
    for _ in 0..50 {
        rig.ticks(1);
        if let Ok(a) = reboot.try_recv() {
            answer = Some(a);
            break;
        }
    }
    let answer = answer.expect("answered once servo 3 was back").unwrap();
    match answer.reply {
        Reply::Rebooted(r) => assert_eq!(r.rebooted, vec![3]),
        other => panic!("not a reboot's reply: {other:?}"),
    }
    let raised = fault_events(&rig.events(), FaultChange::Raised);
    assert!(raised.is_empty(), "{raised:?}");
    let s = rig.status();
    assert!(
        s.tick >= t0 + 40,
        "servo 3 booted for 400 ms: tick {}",
        s.tick
    );
    assert_eq!(
        (s.state, s.torque),
        (State::Estop, false),
        "the latch holds"
    );
    assert_eq!(s.overruns, 0, "a tick waited on the booting servo");
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    assert!((1..=12).all(|id| rig.bus.torque(id) == 0));
    // Read again, mapped again: no power loss is taken for its reset RAM.
    rig.ticks(5);
    assert!(rig.status().faults.is_empty(), "{:?}", rig.status().faults);
    rig.command(LoopCmd::Reset).unwrap();
    assert_eq!(rig.status().state, State::Holding);
    rig.slow_goto();
}

#[test]
fn a_servo_that_never_comes_back_from_its_reboot_fails_the_reboot_not_the_loop() {
    let mut rig = rig_with_a_servo_to_reboot(None);
    let mut reboot = rig.send(LoopCmd::Reboot { ids: None });
    let t0 = rig.status().tick;
    let mut answer = None;
    for _ in 0..400 {
        rig.ticks(1);
        if let Ok(a) = reboot.try_recv() {
            answer = Some(a);
            break;
        }
    }
    let refused = answer.expect("answered within its wait").unwrap_err();
    assert_eq!(refused.code, Code::Fault);
    assert!(
        refused.message.contains("reboot of servo 3"),
        "{}",
        refused.message
    );
    let s = rig.status();
    // Every tick ran meanwhile (3 s at 100 Hz), none held up.
    assert!(s.tick >= t0 + 300, "tick {}", s.tick);
    assert_eq!(s.overruns, 0);
    assert_eq!(s.state, State::Fault, "servo 3 still holds the arm");
    // Motion is refused for the fault, not `busy`: the reboot is over.
    let goto = LoopCmd::Motion(Motion::Goto {
        target: [0.3, 0.3],
        speed: None,
    });
    assert_eq!(rig.command(goto).unwrap_err().code, Code::Fault);
}

#[test]
fn a_shut_down_during_a_reboot_answers_it_and_does_not_wait_on_the_booting_servo() {
    let mut rig = rig_with_a_servo_to_reboot(None);
    let mut reboot = rig.send(LoopCmd::Reboot { ids: Some(vec![3]) });
    rig.ticks(2);
    // Held by the fault, the arm is at rest: the shut-down ends in its first tick.
    assert!(!rig.cycle.turn(&mut rig.pace, true));
    let refused = reboot
        .try_recv()
        .expect("answered at the shut-down")
        .unwrap_err();
    assert_eq!(refused.code, Code::ShuttingDown);
    let Rig { cycle, clock, .. } = rig;
    let start = clock.now();
    let err = cycle.shut_down(false).unwrap_err();
    assert_eq!(clock.now(), start, "waited on the booting servo");
    match err {
        crate::daemon::DaemonError::ShutDown(e) => {
            let ids: Vec<u8> = e.unreached.iter().map(|u| u.id).collect();
            assert_eq!(ids, vec![3], "{e}");
        }
        other => panic!("not a shut-down error: {other}"),
    }
}

#[test]
fn a_reboot_under_the_estop_latch_leaves_torque_off_until_reset() {
    let mut rig = Rig::new(100.0, "");
    rig.bus.servo(3, |s| {
        s.set(Register::HardwareErrorStatus, 0x20);
        s.set(Register::TorqueEnable, 0);
    });
    rig.ticks(1);
    rig.command(LoopCmd::Estop).unwrap();
    rig.command(LoopCmd::Reboot { ids: None }).unwrap();
    let s = rig.status();
    assert_eq!((s.state, s.torque), (State::Estop, false));
    assert!(s.faults.is_empty(), "{:?}", s.faults);
    assert!((1..=12).all(|id| rig.bus.torque(id) == 0));
    rig.command(LoopCmd::Reset).unwrap();
    assert_eq!(rig.status().state, State::Holding);
    assert!((1..=12).all(|id| rig.bus.torque(id) == 1));
}

#[test]
fn a_stall_whose_watchdogs_cannot_be_read_at_once_is_recovered_on_a_later_tick() {
    let mut rig = Rig::new(100.0, "");
    rig.ticks(2);
    rig.events();
    rig.clock.advance(300 * MS);
    for id in [2, 7] {
        rig.bus.servo(id, |s| s.set(Register::BusWatchdog, -1));
    }
    // Servo 7 misses the first reads after the stall.
    rig.bus.servo(7, |s| s.silent = true);
    rig.ticks(1);
    rig.bus.servo(7, |s| s.silent = false);
    rig.ticks(2);
    let recovered = fault_events(&rig.events(), FaultChange::Recovered);
    assert_eq!(
        recovered.iter().map(|r| r.0).collect::<Vec<_>>(),
        vec![Some(2), Some(7)]
    );
    for id in [2, 7] {
        assert!(rig.bus.wire().servos[&id].get(Register::BusWatchdog) > 0);
    }
    assert_eq!(rig.status().state, State::Holding);
}

#[test]
fn a_stall_recovery_cut_short_after_its_watchdog_step_is_completed_and_names_them() {
    let mut rig = Rig::new(100.0, "");
    rig.ticks(2);
    rig.events();
    let armed = rig.bus.wire().servos[&1].get(Register::BusWatchdog);
    rig.clock.advance(300 * MS);
    for id in [2, 7] {
        rig.bus.servo(id, |s| s.set(Register::BusWatchdog, -1));
    }
    // Servo 9 drops off as servo 7's watchdog is armed again: the recovery then fails at
    // reading the pose, its watchdog step done.
    rig.bus.wire().mute_on = Some((Register::BusWatchdog, armed, 7, 9));
    rig.ticks(1);
    rig.bus.wire().mute_on = None;
    rig.bus.servo(9, |s| s.silent = false);
    assert!(fault_events(&rig.events(), FaultChange::Recovered).is_empty());
    assert!(rig.bus.wire().servos[&7].get(Register::BusWatchdog) > 0);
    // No watchdog reads fired now, yet the recovery is completed, naming the two.
    rig.ticks(2);
    let recovered = fault_events(&rig.events(), FaultChange::Recovered);
    assert_eq!(
        recovered.iter().map(|r| (r.0, r.1)).collect::<Vec<_>>(),
        vec![
            (Some(2), FaultKind::Watchdog),
            (Some(7), FaultKind::Watchdog)
        ]
    );
    assert_eq!(rig.status().state, State::Holding);
    // A later recovery names no watchdog of that stall.
    declare_silent(&mut rig, 4);
    rig.bus.servo(4, |s| s.silent = false);
    rig.ticks(3);
    let details: Vec<String> = rig
        .events()
        .iter()
        .filter_map(|e| match &e.what {
            What::Fault { reason, fault, .. } if *reason == FaultChange::Cleared => {
                Some(fault.detail.clone())
            }
            _ => None,
        })
        .collect();
    assert_eq!(details.len(), 1, "{details:?}");
    assert!(!details[0].contains("Watchdog"), "{}", details[0]);
}

#[test]
fn a_shut_down_with_the_port_lost_ends_at_once_naming_every_servo() {
    let mut rig = Rig::new(100.0, "");
    rig.bus.wire().port_gone = true;
    rig.ticks(1);
    assert!(
        !rig.cycle.turn(&mut rig.pace, true),
        "at rest: the port holds it"
    );
    let Rig { cycle, clock, .. } = rig;
    let start = clock.now();
    match cycle.shut_down(false).unwrap_err() {
        crate::daemon::DaemonError::ShutDown(e) => {
            assert_eq!(e.unreached.len(), 12, "{e}");
        }
        other => panic!("not a shut-down error: {other}"),
    }
    assert_eq!(clock.now(), start);
}

/// `cmd` from client 1 on the stop queue (`stops`) or the command queue, its line read at
/// `received`.
fn queue(rig: &Rig, stops: bool, cmd: LoopCmd, received: Instant) -> oneshot::Receiver<Answer> {
    let (reply, answer) = oneshot::channel();
    let envelope = Envelope {
        client: 1,
        id: None,
        cmd,
        received,
        reply,
        later: None,
    };
    let queue = if stops {
        &rig.handle.stops
    } else {
        &rig.handle.commands
    };
    queue.try_send(envelope).unwrap();
    answer
}

#[test]
fn a_stop_is_applied_after_the_commands_that_came_before_it_and_before_those_after() {
    let mut rig = Rig::new(100.0, "");
    let tip = rig.status().tip;
    let goto = |dx: f64| {
        LoopCmd::Motion(Motion::Goto {
            target: [tip[0] + dx, tip[1]],
            speed: Some(0.01),
        })
    };
    // A goto, then a stop: both in one tick, the stop last, so the arm does not set off.
    let t = rig.clock.now();
    let mut before = queue(&rig, false, goto(0.05), t);
    let mut stop = queue(&rig, true, LoopCmd::Stop, t + MS / 10);
    rig.ticks(1);
    assert!(before.try_recv().unwrap().is_ok());
    assert!(stop.try_recv().unwrap().is_ok());
    assert_eq!(rig.status().target, None, "the stop came last");
    rig.ticks(20);
    assert_eq!(rig.status().state, State::Holding);
    let held = rig.status().tip_ref;

    // A stop, then a goto, in one tick: the goto goes ahead.
    let t = rig.clock.now();
    let mut stop = queue(&rig, true, LoopCmd::Stop, t);
    let mut after = queue(&rig, false, goto(-0.05), t + MS / 10);
    rig.ticks(1);
    assert!(stop.try_recv().unwrap().is_ok());
    assert!(after.try_recv().unwrap().is_ok());
    assert_eq!(rig.status().target, Some([tip[0] - 0.05, tip[1]]));
    rig.ticks(20);
    assert!(
        rig.status().tip_ref[0] < held[0],
        "moving to the new target"
    );
}

#[test]
fn a_velocity_older_than_the_deadman_is_refused_stale_and_never_moves_the_arm() {
    let mut rig = Rig::new(100.0, "");
    let deadman = rig.cycle.schedule.deadman;
    let old = rig.clock.now() - deadman - MS;
    let velocity = LoopCmd::Motion(Motion::Velocity { v: [0.05, 0.0] });
    let mut answer = queue(&rig, false, velocity.clone(), old);
    let tip = rig.status().tip_ref;
    rig.ticks(10);
    let refused = answer.try_recv().unwrap().unwrap_err();
    assert_eq!(refused.code, Code::Stale, "{refused}");
    assert!(refused.message.contains("deadman"), "{refused}");
    assert_eq!(rig.status().tip_ref, tip, "the arm never moved");
    // A fresh one is applied.
    let now = rig.clock.now();
    let mut answer = queue(&rig, false, velocity, now);
    rig.ticks(10);
    assert!(answer.try_recv().unwrap().is_ok());
    assert!(rig.status().tip_ref[0] > tip[0]);
}

#[test]
fn the_config_files_world_is_in_force_from_start_up() {
    let world = "\n[world]\nlink_radius_m = 0.01\n\n[[world.obstacle]]\nid = \"post\"\n\
                 circle = { center_m = [0.5, 0.3], radius_m = 0.05 }\n";
    let rig = Rig::with_tables(100.0, "", world);
    let w = rig.cycle.controller.world();
    assert_eq!(w.link_radius_m(), 0.01);
    assert_eq!(w.obstacles().len(), 1);
    assert_eq!(w.obstacles()[0].id, "post");
    // Without a [world], none.
    let rig = Rig::new(100.0, "");
    assert!(rig.cycle.controller.world().obstacles().is_empty());
}

#[test]
fn a_world_change_with_an_obstacle_at_the_base_is_refused_naming_it() {
    use crate::world::{Obstacle, Shape};
    let mut rig = Rig::with_tables(100.0, "", "\n[world]\nlink_radius_m = 0.01\n");
    let base = rig.cycle.controller.chain().base();
    let disc = |id: &str, dx: f64| Obstacle {
        id: id.into(),
        shape: Shape::Circle {
            center: base + crate::chain::Vec2::new(dx, 0.0),
            radius_m: 0.02,
        },
    };
    // 2 mm from the base point, where link 1 starts: 10 mm of radius and 5 of clearance to keep.
    let set = LoopCmd::SetWorld {
        obstacles: Obstacles::new(vec![disc("far", 0.5), disc("pad", 0.022)]).unwrap(),
    };
    let refused = rig.command(set).unwrap_err();
    assert_eq!(refused.code, Code::BadArg);
    assert!(
        refused
            .message
            .starts_with("`obstacles[1]`: obstacle \"pad\" is 0.0020 m from the base"),
        "{}",
        refused.message
    );
    let add = LoopCmd::AddObstacle {
        obstacle: CheckedObstacle::new(disc("pad", 0.022)).unwrap(),
    };
    let refused = rig.command(add).unwrap_err();
    assert!(
        refused.message.starts_with("`obstacle`: "),
        "{}",
        refused.message
    );
    assert!(rig.cycle.controller.world().obstacles().is_empty());
    // Beyond what is kept, taken.
    rig.command(LoopCmd::AddObstacle {
        obstacle: CheckedObstacle::new(disc("pad", 0.036)).unwrap(),
    })
    .unwrap();
    assert_eq!(rig.cycle.controller.world().obstacles().len(), 1);
}

#[test]
fn every_read_carries_the_health_registers_through_indirect_address() {
    let mut rig = Rig::new(100.0, "");
    // Bring-up mapped Indirect Address 1..13 onto Present Load/Current .. Temperature, and 14
    // onto Bus Watchdog.
    for id in 1..=12 {
        let s = &rig.bus.wire().servos[&id];
        let mapped: Vec<i64> = (1..=14)
            .map(|n| s.get(Register::IndirectAddress(n)))
            .collect();
        assert_eq!(
            mapped,
            [126, 127, 128, 129, 130, 131, 132, 133, 134, 135, 144, 145, 146, 98],
            "servo {id}"
        );
    }
    rig.bus
        .servo(4, |s| s.set(Register::PresentInputVoltage, 115));
    rig.bus
        .servo(7, |s| s.set(Register::PresentTemperature, 41));
    rig.bus.wire().reads.clear();
    for _ in 0..25 {
        rig.ticks(1);
        let s = rig.status();
        assert_eq!(s.health_tick, s.tick, "a read without the health registers");
    }
    // Every tick's read is 13 bytes of Indirect Data from 224 (the XL430's); one in
    // `health_every` one byte longer, for the Bus Watchdog.
    let reads = std::mem::take(&mut rig.bus.wire().reads);
    assert!(
        reads.iter().all(|&(a, n)| a == 224 && (n == 13 || n == 14)),
        "{reads:?}"
    );
    assert_eq!(reads.iter().filter(|r| r.1 == 14).count(), 2, "{reads:?}");
    let s = rig.status();
    assert!((s.voltage_v[3] - 11.5).abs() < 1e-9, "{:?}", s.voltage_v);
    assert!(
        (s.temperature_c[6] - 41.0).abs() < 1e-9,
        "{:?}",
        s.temperature_c
    );
    assert_eq!(s.overruns, 0);
}

#[test]
fn a_power_loss_shorter_than_the_silence_budget_is_told_by_the_unmapped_block() {
    let mut rig = Rig::new(100.0, "");
    rig.ticks(3);
    rig.bus.lose_power(5);
    // Two lost reads: far inside the 300 ms budget, so no `silent` fault is raised.
    rig.ticks(2);
    assert_eq!(rig.status().state, State::Holding);
    rig.events();
    rig.bus.power_back(5);
    rig.ticks(1);
    let s = rig.status();
    assert_eq!(s.state, State::Estop, "latched as for a power loss");
    let power: Vec<_> = s
        .faults
        .iter()
        .filter(|f| f.kind == FaultKind::PowerLoss)
        .collect();
    assert_eq!(power.len(), 1, "{:?}", s.faults);
    assert_eq!(power[0].id, Some(5));
    assert!(
        power[0].detail.contains("Indirect Address 1"),
        "{}",
        power[0].detail
    );
    // Its mapping written again with the rest of its RAM: the next reads are whole.
    assert_eq!(
        rig.bus.wire().servos[&5].get(Register::IndirectAddress(1)),
        126
    );
    let before = s.tick;
    rig.ticks(3);
    let s = rig.status();
    assert!(s.health_tick > before);
    assert!(s.voltage_v[4] > 10.0, "{:?}", s.voltage_v);
}

/// A recording whose writes block until a gate opens: a disk that has stalled.
struct StalledSink {
    gate: Arc<(Mutex<bool>, std::sync::Condvar)>,
    /// Messages written per channel id.
    written: Arc<Mutex<BTreeMap<u16, u64>>>,
    next: u16,
}

impl crate::record::Sink for StalledSink {
    fn add_channel(
        &mut self,
        _: &crate::record::schema::ChannelSpec,
    ) -> Result<u16, crate::record::RecordError> {
        self.next += 1;
        Ok(self.next)
    }

    fn write(&mut self, channel: u16, _: u64, _: &[u8]) -> Result<(), crate::record::RecordError> {
        let (open, opened) = &*self.gate;
        let mut open = open.lock().unwrap();
        while !*open {
            open = opened.wait(open).unwrap();
        }
        *self.written.lock().unwrap().entry(channel).or_insert(0) += 1;
        Ok(())
    }

    fn metadata(
        &mut self,
        _: &str,
        _: &BTreeMap<String, String>,
    ) -> Result<(), crate::record::RecordError> {
        Ok(())
    }

    fn flush(&mut self) -> Result<(), crate::record::RecordError> {
        Ok(())
    }

    fn finish(&mut self) -> Result<(), crate::record::RecordError> {
        Ok(())
    }
}

#[test]
fn a_stalled_recording_does_not_stall_the_loop_and_its_drops_are_counted() {
    use crate::record::{Notes, Recorder, Setup};
    const QUEUE: usize = 16;
    const TICKS: u64 = 300;
    let mut rig = Rig::new(100.0, "");
    let gate = Arc::new((Mutex::new(false), std::sync::Condvar::new()));
    let written = Arc::new(Mutex::new(BTreeMap::new()));
    let sink = StalledSink {
        gate: Arc::clone(&gate),
        written: Arc::clone(&written),
        next: 0,
    };
    let setup = Setup {
        prefix: "snakectl".into(),
        period: 10 * MS,
        config_path: "config/sim.toml".into(),
        config_text: String::new(),
        joints: 12,
        queue: QUEUE,
        chain: crate::chain::Chain::unlimited(vec![0.1; 12], crate::chain::Vec2::zeros(), 0.0)
            .unwrap(),
        world: crate::world::World::default(),
        scene_every: 10,
    };
    let (recorder, tap) =
        Recorder::start(Box::new(sink), setup, Notes::new(), "stalled".into()).unwrap();
    rig.cycle.set_tap(tap);
    // Should the loop wait on the writer, this opens the gate after a while: the ticks then
    // end, and the check below fails instead of the test hanging.
    let rescue = {
        let gate = Arc::clone(&gate);
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_secs(20));
            let (open, opened) = &*gate;
            let was = std::mem::replace(&mut *open.lock().unwrap(), true);
            opened.notify_all();
            !was
        })
    };
    rig.slow_goto();
    rig.ticks(TICKS as usize - 1);
    assert!(
        !*gate.0.lock().unwrap(),
        "the ticks ended only once the writer was released"
    );
    assert_eq!(rig.status().overruns, 0);
    assert_eq!(rig.status().state, State::Moving);

    *gate.0.lock().unwrap() = true;
    gate.1.notify_all();
    let summary = recorder.close();
    assert!(summary.error.is_none(), "{:?}", summary.error);
    let joint_states = &summary.channels[0];
    assert_eq!(joint_states.topic, "/snakectl/joint_states");
    assert_eq!(joint_states.offered, TICKS);
    // The queue's worth was kept, and the one item the writer stalled on.
    assert!(
        joint_states.dropped >= TICKS - QUEUE as u64 - 1,
        "{joint_states:?}"
    );
    assert_eq!(joint_states.written + joint_states.dropped, TICKS);
    let written = written.lock().unwrap();
    for (k, channel) in summary.channels.iter().enumerate() {
        let in_sink = written.get(&(k as u16 + 1)).copied().unwrap_or(0);
        assert_eq!(in_sink, channel.written, "{channel:?}");
        assert_eq!(
            channel.written + channel.dropped,
            channel.offered,
            "{channel:?}"
        );
    }
    drop(rescue);
}

#[test]
fn a_stop_sent_while_a_fault_holds_does_not_stay_the_active_command_after_recovery() {
    let mut rig = Rig::new(100.0, "");
    rig.slow_goto();
    rig.ticks(3);
    declare_silent(&mut rig, 5);
    assert_eq!(rig.status().state, State::Fault);
    rig.command(LoopCmd::Stop).unwrap();
    rig.ticks(5);
    // The servo answers again: recovered, holding the measured pose.
    rig.bus.servo(5, |s| s.silent = false);
    rig.ticks(5);
    let s = rig.status();
    assert_eq!(s.state, State::Holding);
    let command = s.command.expect("a command to report");
    assert_ne!(
        command.outcome,
        Outcome::Active,
        "the arm holds, yet the command reads active: {command:?}"
    );
    rig.events();
    // The next command preempts nothing: nothing was moving the arm.
    rig.slow_goto();
    let events = rig.events();
    assert!(
        !events
            .iter()
            .any(|e| matches!(e.what, What::Preempted { .. })),
        "{events:?}"
    );
}

#[test]
fn an_estop_under_a_contact_latch_turns_torque_off() {
    let mut rig = Rig::with_tables(100.0, "", "\n[world]\ncontact_load = 40\ncontact_ms = 50\n");
    // Joint 1 pushes against something: Present Load 50 %.
    rig.bus.servo(1, |s| s.set(Register::PresentCurrent, 500));
    rig.ticks(10);
    let s = rig.status();
    assert_eq!((s.state, s.torque), (State::Estop, true), "{:?}", s.faults);
    assert!(s.faults.iter().any(|f| f.kind == FaultKind::Contact));
    rig.events();
    // The user's estop: torque off, as `[bus] on_exit = "torque_off"` says.
    rig.command(LoopCmd::Estop).unwrap();
    let s = rig.status();
    assert_eq!(s.state, State::Estop);
    assert!(!s.torque, "telemetry says torque on after the estop");
    for id in 1..=12 {
        assert_eq!(
            rig.bus.torque(id),
            0,
            "servo {id} torque on after the estop"
        );
    }
    // `reset` brings it back.
    rig.bus.servo(1, |s| s.set(Register::PresentCurrent, 0));
    rig.command(LoopCmd::Reset).unwrap();
    let s = rig.status();
    assert_eq!((s.state, s.torque), (State::Holding, true));
    assert!(s.faults.is_empty(), "{:?}", s.faults);
}

#[test]
fn a_power_loss_under_a_contact_latch_turns_torque_off() {
    let mut rig = Rig::with_tables(100.0, "", "\n[world]\ncontact_load = 40\ncontact_ms = 50\n");
    rig.bus.servo(1, |s| s.set(Register::PresentCurrent, 500));
    rig.ticks(10);
    assert_eq!(rig.status().state, State::Estop);
    assert!(rig.status().torque, "a contact keeps torque on");
    rig.bus.lose_power(5);
    rig.ticks(20);
    rig.bus.power_back(5);
    rig.ticks(1);
    let s = rig.status();
    assert!(
        s.faults.iter().any(|f| f.kind == FaultKind::PowerLoss),
        "{:?}",
        s.faults
    );
    assert_eq!(s.state, State::Estop);
    assert!(!s.torque, "telemetry says torque on after a power loss");
    for id in 1..=12 {
        assert_eq!(
            rig.bus.torque(id),
            0,
            "servo {id} torque on after a power loss"
        );
    }
}

#[test]
fn a_reset_that_fails_under_a_contact_latch_tells_the_torque_it_left() {
    let mut rig = Rig::with_tables(100.0, "", "\n[world]\ncontact_load = 40\ncontact_ms = 50\n");
    rig.bus.servo(1, |s| s.set(Register::PresentCurrent, 500));
    rig.ticks(10);
    let s = rig.status();
    assert_eq!((s.state, s.torque), (State::Estop, true));
    rig.bus.servo(1, |s| s.set(Register::PresentCurrent, 0));
    // Servo 9 drops off the bus as the reset's torque on holds servo 1's present position.
    let present = rig.bus.wire().servos[&1].get(Register::PresentPosition);
    rig.bus.wire().mute_on = Some((Register::GoalPosition, present, 1, 9));
    let refused = rig.command(LoopCmd::Reset).unwrap_err();
    assert_eq!(refused.code, Code::Fault, "{refused}");
    rig.bus.wire().mute_on = None;
    let s = rig.status();
    assert_eq!(s.state, State::Estop, "the latch stays");
    let on: Vec<u8> = (1..=12).filter(|&id| rig.bus.torque(id) == 1).collect();
    assert_eq!(
        s.torque,
        on.len() == 12,
        "telemetry says torque {} with torque on for servos {on:?}",
        s.torque
    );
}

#[test]
fn a_servo_that_loses_power_again_while_latched_has_its_ram_written_again() {
    let mut rig = Rig::new(100.0, "");
    rig.ticks(3);
    rig.bus.lose_power(5);
    rig.ticks(20);
    rig.bus.power_back(5);
    rig.ticks(1);
    assert_eq!(rig.status().state, State::Estop);
    let armed = rig.bus.wire().servos[&1].get(Register::BusWatchdog);
    assert_eq!(rig.bus.wire().servos[&5].get(Register::BusWatchdog), armed);
    // Latched for it, it loses power once more and comes back.
    rig.bus.lose_power(5);
    rig.ticks(20);
    rig.bus.power_back(5);
    rig.ticks(3);
    let s = rig.status();
    assert_eq!(s.state, State::Estop);
    let w = rig.bus.wire();
    let servo = &w.servos[&5];
    assert_eq!(
        (
            servo.get(Register::BusWatchdog),
            servo.get(Register::IndirectAddress(1))
        ),
        (armed, 126),
        "its RAM as the power loss left it"
    );
}

/// A star of `n` points round `centre` (radii alternating `r` and `0.6 r`): many corners for a
/// route to thread.
fn star_obstacle(id: &str, centre: crate::chain::Vec2, n: usize, r: f64) -> crate::world::Obstacle {
    let points = (0..n)
        .map(|k| {
            let a = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
            let r = if k % 2 == 0 { r } else { 0.6 * r };
            centre + crate::chain::Vec2::new(a.cos(), a.sin()) * r
        })
        .collect();
    crate::world::Obstacle {
        id: id.into(),
        shape: crate::world::Shape::Polygon { points },
    }
}

/// A rig with a 256-point star between the tip and [`beyond_the_star`], off the arm's body,
/// whose way round takes more route work than a tick may spend; the tip's position.
fn rig_with_a_star_beside_the_tip() -> (Rig, [f64; 2]) {
    let mut rig = Rig::with_tables(100.0, "", "\n[world]\nlink_radius_m = 0.01\n");
    let tip = rig.status().tip;
    // The arm curls left from its base: below and left of the tip is clear of its body.
    let centre = crate::chain::Vec2::new(tip[0] - 0.08, tip[1] - 0.08);
    rig.command(LoopCmd::SetWorld {
        obstacles: Obstacles::new(vec![star_obstacle("star", centre, 256, 0.035)]).unwrap(),
    })
    .unwrap();
    (rig, tip)
}

/// A target behind the star from the tip.
fn beyond_the_star(tip: [f64; 2]) -> [f64; 2] {
    [tip[0] - 0.16, tip[1] - 0.16]
}

#[test]
fn a_route_too_long_for_a_tick_is_planned_beside_the_loop_which_ticks_on() {
    let (mut rig, tip) = rig_with_a_star_beside_the_tip();
    let target = beyond_the_star(tip);
    let mut goto = rig.send(LoopCmd::Motion(Motion::Goto {
        target,
        speed: Some(0.1),
    }));
    // The loop serves what comes meanwhile, in its tick.
    let mut status = rig.send(LoopCmd::Status);
    rig.ticks(1);
    assert!(rig.cycle.planning_routes(), "planned within the tick");
    assert!(
        goto.try_recv().is_err(),
        "answered before its routes were planned"
    );
    status.try_recv().expect("answered in its tick").unwrap();
    assert!(rig.cycle.wait_for_routes(), "the planner never answered");
    rig.ticks(1);
    goto.try_recv()
        .expect("answered once its routes were planned")
        .expect("taken");
    assert!(!rig.cycle.planning_routes());
    // The tip goes round the star, every goal pose keeping the clearance, and arrives.
    arrives_clear(&mut rig, target, 1500);
}

/// Ticks until the command under way arrives (at most `max` ticks), every goal pose keeping
/// the clearance and nothing `blocked`; the tip then on `target`.
fn arrives_clear(rig: &mut Rig, target: [f64; 2], max: usize) {
    let keep = rig.cycle.controller.world().clearance_m();
    let mut arrived = false;
    for _ in 0..max {
        rig.ticks(1);
        let s = rig.status();
        let c = s.min_clearance_m.expect("a world with an obstacle");
        assert!(c >= keep - 1e-9, "clearance {c} at tick {}", s.tick);
        let events = rig.events();
        assert!(
            !events
                .iter()
                .any(|e| matches!(e.what, What::Blocked { .. })),
            "{events:?}"
        );
        if events
            .iter()
            .any(|e| matches!(e.what, What::Arrived { .. }))
        {
            arrived = true;
            break;
        }
    }
    assert!(arrived, "never arrived: tip {:?}", rig.status().tip);
    let end = rig.status().tip;
    assert!(
        (end[0] - target[0]).hypot(end[1] - target[1]) < 1e-6,
        "{end:?}"
    );
}

/// A `reach` is planned beside the loop (the loop answers meanwhile), then the arm goes leg by
/// leg in joint space, every goal pose clear, and arrives with the tip on the target.
#[test]
fn a_reach_is_planned_beside_the_loop_and_arrives_clear() {
    use crate::world::{Obstacle, Shape};
    let mut rig = Rig::with_tables(100.0, "", "\n[world]\nlink_radius_m = 0.01\n");
    let disc = |id: &str, x: f64, y: f64, r: f64| Obstacle {
        id: id.into(),
        shape: Shape::Circle {
            center: crate::chain::Vec2::new(x, y),
            radius_m: r,
        },
    };
    // Two discs a goto to the target is caught between (`tests/daemon_world.rs`).
    let discs = vec![
        disc("upper", -0.3001, 0.7139, 0.0127),
        disc("lower", -0.5183, 0.5435, 0.0148),
    ];
    rig.command(LoopCmd::SetWorld {
        obstacles: Obstacles::new(discs).unwrap(),
    })
    .unwrap();
    let target = [-0.6656, 0.4673];
    let mut reach = rig.send(LoopCmd::Motion(Motion::Reach { target }));
    let mut status = rig.send(LoopCmd::Status);
    rig.ticks(1);
    assert!(rig.cycle.planning_routes(), "planned within the tick");
    status.try_recv().expect("answered in its tick").unwrap();
    assert!(rig.cycle.wait_for_routes(), "the planner never answered");
    rig.ticks(1);
    reach
        .try_recv()
        .expect("answered once its way was planned")
        .expect("taken");
    arrives_clear(&mut rig, target, 3000);
}

#[test]
fn a_stop_while_the_routes_are_planned_preempts_the_goto_and_nothing_moves() {
    let (mut rig, tip) = rig_with_a_star_beside_the_tip();
    rig.events();
    let target = beyond_the_star(tip);
    let goto = LoopCmd::Motion(Motion::Goto {
        target,
        speed: Some(0.1),
    });
    // Both in one tick, so that the routes cannot have come before the stop.
    let mut first = rig.send(goto.clone());
    let mut stop = rig.send(LoopCmd::Stop);
    rig.ticks(1);
    stop.try_recv().expect("answered in its tick").unwrap();
    first
        .try_recv()
        .expect("answered when the stop came")
        .expect("taken, then preempted");
    let events = rig.events();
    assert!(
        events.iter().any(|e| matches!(
            e.what,
            What::Preempted {
                reason: CmdName::Stop,
                ..
            }
        ) && e.owner == Some(1)),
        "{events:?}"
    );
    assert!(!rig.cycle.planning_routes());
    // Whenever its routes come, they are dropped: the arm holds where it was.
    rig.ticks(50);
    assert_eq!(rig.status().tip, tip);
    // The same goto again is planned in turn, and goes.
    let mut second = rig.send(goto);
    rig.ticks(1);
    assert!(rig.cycle.wait_for_routes());
    rig.ticks(1);
    second.try_recv().expect("answered").expect("taken");
    rig.ticks(50);
    assert_ne!(rig.status().tip, tip, "the second goto did not move");
}

#[test]
fn routes_planned_before_the_world_changed_are_planned_again_in_the_new_one() {
    let (mut rig, tip) = rig_with_a_star_beside_the_tip();
    let mut goto = rig.send(LoopCmd::Motion(Motion::Goto {
        target: beyond_the_star(tip),
        speed: Some(0.1),
    }));
    let far = crate::world::Obstacle {
        id: "far".into(),
        shape: crate::world::Shape::Circle {
            center: crate::chain::Vec2::new(tip[0] + 0.12, tip[1] - 0.3),
            radius_m: 0.02,
        },
    };
    // In the goto's tick, so that its routes cannot have come before.
    let mut add = rig.send(LoopCmd::AddObstacle {
        obstacle: CheckedObstacle::new(far).unwrap(),
    });
    rig.ticks(1);
    add.try_recv().expect("answered in its tick").unwrap();
    assert!(rig.cycle.wait_for_routes());
    rig.ticks(1);
    assert!(
        goto.try_recv().is_err(),
        "started on routes planned in the old world"
    );
    assert!(rig.cycle.planning_routes(), "not planned again");
    assert!(rig.cycle.wait_for_routes());
    rig.ticks(1);
    goto.try_recv().expect("answered").expect("taken");
}

#[test]
fn a_motion_refused_while_the_routes_are_planned_leaves_them_to_come() {
    let (mut rig, tip) = rig_with_a_star_beside_the_tip();
    let mut goto = rig.send(LoopCmd::Motion(Motion::Goto {
        target: beyond_the_star(tip),
        speed: Some(0.1),
    }));
    // Into the star: refused, in the same tick (so that the routes cannot have come first).
    let mut inside = rig.send(LoopCmd::Motion(Motion::Goto {
        target: [tip[0] - 0.08, tip[1] - 0.08],
        speed: None,
    }));
    rig.ticks(1);
    let refused = inside
        .try_recv()
        .expect("answered in its tick")
        .unwrap_err();
    assert_eq!(refused.code, Code::Unreachable, "{}", refused.message);
    assert!(
        rig.cycle.planning_routes(),
        "the refused goto ended the planned one"
    );
    assert!(goto.try_recv().is_err());
    assert!(rig.cycle.wait_for_routes());
    rig.ticks(1);
    goto.try_recv().expect("answered").expect("taken");
}

/// Two long thin walls either side of the base, forming a slot the arm points out of: no clear
/// way down below them is found (the planner gives up after its work).
fn slot() -> Obstacles {
    use crate::world::{Obstacle, Shape};
    let wall = |id: &str, near: f64, far: f64| Obstacle {
        id: id.into(),
        shape: Shape::Polygon {
            points: [[near, 0.0], [far, 0.0], [far, 0.01], [near, 0.01]]
                .map(|[x, y]| crate::chain::Vec2::new(x, y))
                .to_vec(),
        },
    };
    Obstacles::new(vec![wall("right", 0.05, 1.2), wall("left", -0.05, -1.2)]).unwrap()
}

/// Regression: a `reach` refused by the planner in a world changed meanwhile was answered
/// `unreachable`, though the world in force had nothing in its way. Its way is planned again in
/// the world in force, as a way found would be.
#[test]
fn a_reach_refused_in_a_world_changed_meanwhile_is_planned_again() {
    let mut rig = Rig::with_tables(100.0, "", "\n[world]\nlink_radius_m = 0.012\n");
    rig.command(LoopCmd::SetWorld { obstacles: slot() })
        .unwrap();
    let mut reach = rig.send(LoopCmd::Motion(Motion::Reach {
        target: [0.5, -0.2],
    }));
    // In the reach's tick, so that its way is planned in the slot.
    let mut clear = rig.send(LoopCmd::SetWorld {
        obstacles: Obstacles::new(Vec::new()).unwrap(),
    });
    rig.ticks(1);
    clear.try_recv().expect("answered in its tick").unwrap();
    assert!(rig.cycle.wait_for_routes(), "the planner never answered");
    rig.ticks(1);
    assert!(
        reach.try_recv().is_err(),
        "answered on the slot's refusal, the slot gone"
    );
    assert!(rig.cycle.planning_routes(), "not planned again");
    assert!(rig.cycle.wait_for_routes(), "the planner never answered");
    rig.ticks(1);
    reach
        .try_recv()
        .expect("answered once its way was planned again")
        .expect("taken");
}
