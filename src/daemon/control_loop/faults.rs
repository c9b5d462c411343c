//! The loop's fault path: reading the servos, judging what the read showed (through
//! [`Health`](super::health::Health)), holding the arm through the supervisor, recovering,
//! keeping the port (reopening it, recovering from a stall past the Bus Watchdog), and the
//! contact stop (a load that stayed above its `[world] contact_load`).

use std::time::{Duration, Instant};

use crate::protocol::{FaultChange, FaultKind, Unconfirmed, What};
use crate::servo::arm::{self, Arm, OnExit, Retry};
use crate::servo::clock::Clock;
use crate::servo::limits::Limited;
use crate::servo::{
    units, ErrorClass, Fields, HardwareErrors, Layout, Register, ServoBus, ServoError,
};

use super::commands::{read_set, Reachable};
use super::health::{JointFault, Limits};
use super::port::{ReopenError, RETRY_EVERY};
use super::Cycle;
use crate::protocol::StopReason;

/// The shortest wait for a reply the deadline cap leaves a read.
const MIN_READ_WAIT: Duration = Duration::from_micros(300);

/// What a read leaves of its tick for publishing and answering: a reply that never comes then
/// costs no overrun.
pub(super) const READ_TAIL: Duration = Duration::from_micros(500);

/// The wire's ticks (a Sync Write of every goal and a read of every servo) a recovery's
/// exchanges may take: about five round trips of every servo (the watchdogs, the pose, the
/// goals and the torque, the last two confirmed), with room for a retry each.
pub(super) const RECOVERY_WIRE_TICKS: f64 = 10.0;

impl<B: ServoBus, C: Clock> Cycle<B, C> {
    /// The read of the tick scheduled at `scheduled`, its wait capped short of `deadline`;
    /// with `health` (always, through Indirect Address), Present Current/Load, Input Voltage
    /// and Temperature too; with `watchdog`, the Bus Watchdog (through Indirect Address every
    /// servo's, in the same read; else one servo's in turn, in the tick's time left).
    pub(super) fn read(
        &mut self,
        scheduled: Instant,
        deadline: Instant,
        health: bool,
        watchdog: bool,
    ) {
        let mut left = deadline
            .saturating_duration_since(self.clock.now())
            .saturating_sub(READ_TAIL);
        if self.late_start {
            // Back to back, the work is longer than the period: the read waits for its replies
            // as long as any exchange does. Cut short, it would send the next instruction while
            // servos still answer the last (a collision on a real bus), and take their late
            // replies for the next exchange's. Never so long that the watchdogs fire.
            left = self.schedule.late_wait;
        }
        let timeout = self.schedule.reply_timeout.min(left).max(MIN_READ_WAIT);
        // Through Indirect Address every read is a health read.
        let health = health || matches!(self.layout, Layout::Indirect { .. });
        let layout = match self.layout {
            Layout::Indirect { .. } => self.layout.with_watchdog(watchdog),
            Layout::Direct(_) if health => Layout::Direct(Fields::ALL),
            Layout::Direct(_) => Layout::Direct(Fields {
                velocity: true,
                ..Fields::POSITION
            }),
        };
        if health {
            self.measured.begin_health();
        }
        let partial = self.port.is_lost() && self.port.several();
        let reachable = partial.then_some(&self.reachable);
        let (ids, _) = read_set(reachable, self.rebooting.as_ref(), &self.ids);
        let read = self
            .port
            .bus()
            .read_block_into(ids, layout, timeout, &mut self.states);
        let read_count = ids.len();
        let mut attention = false;
        match read {
            Err(e) if e.class() == ErrorClass::Bus => {
                self.lose_port(&e);
                return;
            }
            Err(e) => {
                tracing::debug!("sync read failed: {e}");
                self.stats.counters.dropped += read_count as u64;
                for slot in 0..read_count {
                    if let Some(i) = self.joint_of_slot(slot) {
                        attention |= self.health.missed(i, self.tick, scheduled);
                    }
                }
            }
            Ok(()) => {
                if !self.port.is_lost() {
                    // Every servo heard the loop (not so while a port of several is lost).
                    self.port.contact(self.clock.now());
                }
                for slot in 0..read_count {
                    if let Some(i) = self.joint_of_slot(slot) {
                        attention |= self.take_reading(slot, i, scheduled);
                    }
                }
                self.retry_torque_off();
                if watchdog && matches!(self.layout, Layout::Direct(_)) {
                    self.watch_one();
                }
            }
        }
        if health {
            self.measured.health_tick = self.tick;
            self.check_health();
        }
        if attention {
            self.review_faults(scheduled);
        }
    }

    /// While a port of several is lost, the servos on the others, which a tick reads.
    fn reachable(&self) -> Option<&Reachable> {
        (self.port.is_lost() && self.port.several()).then_some(&self.reachable)
    }

    /// The joint whose servo a tick's read has in `slot` ([`read_set`]).
    fn joint_of_slot(&self, slot: usize) -> Option<usize> {
        match read_set(self.reachable(), self.rebooting.as_ref(), &self.ids) {
            (_, Some(joints)) => joints.get(slot).copied(),
            (_, None) => Some(slot),
        }
    }

    /// Joint `i`'s part of this read, in its `slot`; true when the fault path has something to
    /// look at.
    fn take_reading(&mut self, slot: usize, i: usize, scheduled: Instant) -> bool {
        match self.states.readings().get(slot) {
            Some(Ok(s)) => {
                self.measured.record(i, s);
                let (id, alert) = (s.id, s.alert);
                if s.watchdog.is_some_and(|w| w < 0) {
                    self.watchdog_fired(id);
                }
                self.health.answered(i, alert)
            }
            Some(Err(ServoError::Unmapped { .. })) => {
                // It answers, with its RAM reset: the fault path looks at it as at a servo
                // back from a power loss (nothing it read is recorded).
                self.health.answered(i, false);
                if !self.unmapped.contains(&i) {
                    self.unmapped.push(i);
                }
                true
            }
            missing => {
                if matches!(missing, Some(Err(e)) if !e.is_timeout()) {
                    self.stats.counters.corrupted += 1;
                } else {
                    self.stats.counters.dropped += 1;
                }
                self.health.missed(i, self.tick, scheduled)
            }
        }
    }

    /// Servo `id`'s Bus Watchdog read -1: it stopped and refuses goals. Recovered at the start
    /// of the next tick ([`Cycle::check_fired`]).
    fn watchdog_fired(&mut self, id: u8) {
        if !self.fired.contains(&id) {
            self.fired.push(id);
        }
    }

    /// Without Indirect Address, a health read's Bus Watchdog: one servo's, in turn, within
    /// what the tick has left (none while a `reboot` boots servos or a port of several is
    /// lost). A servo that does not answer it is left to the next turn's.
    fn watch_one(&mut self) {
        if self.rebooting.is_some() || self.port.is_lost() {
            return;
        }
        let Some(&id) = self.ids.get(self.watch_next) else {
            self.watch_next = 0;
            return;
        };
        self.watch_next = (self.watch_next + 1) % self.ids.len();
        let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
        let Some(wait) = within.wait() else {
            return;
        };
        match self.port.bus().read(id, Register::BusWatchdog, wait) {
            Ok(v) if v.value < 0 => self.watchdog_fired(id),
            Ok(_) => {}
            Err(e) => tracing::debug!(id, "reading the bus watchdog: {e}"),
        }
    }

    /// Whether a fault holds the arm, as the port and the joints say now, told to the
    /// supervisor; entering the protective stop freezes the arm and ends the active command.
    pub(super) fn sync_faulted(&mut self) {
        let faulted = self.port.is_lost() || self.health.any_fault();
        if self.supervisor.set_faulted(faulted) {
            self.controller.freeze();
            let ended = self.ledger.interrupt(StopReason::Fault);
            self.owe(ended);
        }
    }

    /// Joint `i` faulted: the first fault freezes the arm and ends the active command.
    fn raise(&mut self, i: usize, fault: JointFault, since: u64, detail: String) {
        let change = self.health.raise(i, fault, since, detail);
        self.sync_faulted();
        self.report(change);
    }

    /// Joint `i`'s fault cleared.
    pub(super) fn clear(&mut self, i: usize, detail: String) {
        if let Some(change) = self.health.clear(i, detail) {
            self.report(change);
        }
    }

    /// The fault path after a read: raise what the read showed, clear what it cleared, recover
    /// once nothing holds any more.
    fn review_faults(&mut self, scheduled: Instant) {
        self.raise_alerts();
        for (i, since, detail) in self.health.exhausted(scheduled) {
            self.raise(i, JointFault::Silent, since, detail);
        }
        self.review_back();
    }

    /// Each servo whose alert flag came up (and is not held for it yet): its Hardware Error
    /// Status read, within this tick, and a `hardware_error` fault raised naming it.
    fn raise_alerts(&mut self) {
        let tick = self.tick;
        for i in self.health.take_alerts() {
            let id = self.ids.get(i).copied().unwrap_or_default();
            let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
            let read = match within.wait() {
                Some(wait) => self.port.bus().hardware_errors(id, wait),
                None => Err(ServoError::Timeout {
                    id,
                    waited: Duration::ZERO,
                }),
            };
            let (bits, detail) = match read {
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
        }
    }

    /// The servos back from silence: looked at for a power loss, cleared, and the arm
    /// recovered once nothing else holds it.
    fn review_back(&mut self) {
        let mut back = self.health.back_from_silence();
        let power_lost = self.health.power_lost();
        for i in std::mem::take(&mut self.unmapped) {
            match self.ids.get(i).copied() {
                // Held for a power loss already, it lost power once more: its RAM is written
                // again, the latch holds on.
                Some(id) if power_lost.contains(&id) => self.restore_again(id),
                _ if !back.contains(&i) => back.push(i),
                _ => {}
            }
        }
        if back.is_empty() {
            return;
        }
        // A servo that lost power answers with its RAM at the defaults: no torque for it
        // until `reset`.
        let Some(lost) = self.check_ram(&back) else {
            return;
        };
        if !lost.is_empty() {
            self.latch_power_loss(&back, lost);
            return;
        }
        if self.port.is_lost() || self.health.faulted_except(&back) {
            for i in back {
                self.clear(i, "answers again (other faults still hold the arm)".into());
            }
            if !self.port.is_lost() && !self.supervisor.torque() {
                // A torque off it missed while silent reaches it now.
                self.torque_off_all("a servo back from silence");
            }
            return;
        }
        if self.recover_after.is_some_and(|t| self.clock.now() < t) {
            return;
        }
        match self.recover(false) {
            Ok(watchdogs) => {
                let detail = recovered_detail(&watchdogs);
                for i in back {
                    self.clear(i, format!("answers again; {detail}"));
                }
                self.sync_faulted();
            }
            Err(e) => {
                tracing::warn!("recovery failed, holding: {e}");
                self.recover_after = Some(self.clock.now() + RETRY_EVERY);
            }
        }
    }

    /// Which of the servos `back` from silence (joint indices) answer with the RAM bring-up
    /// wrote reset (they lost power), each with what was reset; `None` when one could not be
    /// read (it is looked at again on its next answer).
    fn check_ram(&mut self, back: &[usize]) -> Option<Vec<(usize, String)>> {
        let torque = self.supervisor.torque();
        let mut lost = Vec::new();
        for &i in back {
            let id = self.ids.get(i).copied()?;
            let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
            match self
                .arm
                .ram_reset(self.port.bus(), id, torque, &self.unarmed, &within)
            {
                Ok(Some(what)) => lost.push((i, what)),
                Ok(None) => {}
                Err(e) => {
                    tracing::debug!(id, "servo back from silence, its RAM unreadable: {e}");
                    return None;
                }
            }
        }
        Some(lost)
    }

    /// Servos (joint index, what of their RAM was reset) answer again after losing power: the
    /// arm is latched as under an estop (torque off as `[bus] on_exit` says; the servos that
    /// lost power have none anyway), their RAM written again as bring-up did, and each held in
    /// a `power_loss` fault until `reset`, which alone turns torque back on.
    fn latch_power_loss(&mut self, back: &[usize], lost: Vec<(usize, String)>) {
        for &i in back {
            let detail = match lost.iter().find(|(j, _)| *j == i) {
                Some((_, what)) => format!("answers again, with its RAM reset: {what}"),
                None => "answers again (another servo lost power: the arm is latched)".into(),
            };
            self.clear(i, detail);
        }
        if !self.supervisor.estopped() {
            self.controller.freeze();
            self.ledger.estop();
            let torque_off = self.on_exit == OnExit::TorqueOff;
            self.supervisor.estop(torque_off);
            if torque_off {
                self.torque_off_all("power loss");
            }
            self.event(None, None, |tip| What::Estop { tip });
        } else if self.on_exit == OnExit::TorqueOff && self.supervisor.torque() {
            // Latched already, with torque kept on (a contact): off as for the estop.
            self.supervisor.estop(true);
            self.torque_off_all("power loss");
        }
        let tick = self.tick;
        for (i, what) in lost {
            let id = self.ids.get(i).copied().unwrap_or_default();
            let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
            let restored = match self.arm.restore_ram(self.port.bus(), id, &within) {
                Ok(()) => {
                    "its settings written again (profiles, Bus Watchdog, goal := present position)"
                        .to_owned()
                }
                Err(e) => format!("writing its settings again failed ({e}): `reboot` brings it up"),
            };
            let detail = format!(
                "lost power: it answers again with its RAM reset ({what}); {restored}; its torque \
                 stays off and the arm is latched as after an estop: `reset` turns torque on"
            );
            tracing::warn!(id, "servo lost power: the arm is latched until `reset`");
            self.raise(i, JointFault::PowerLoss, tick, detail);
        }
    }

    /// Servo `id`, held for a power loss, lost its RAM again: written again as bring-up did
    /// (torque stays off); a failure is tried again on its next answer, which reads unmapped.
    fn restore_again(&mut self, id: u8) {
        let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
        match self.arm.restore_ram(self.port.bus(), id, &within) {
            Ok(()) => tracing::warn!(id, "servo lost power again: its settings written again"),
            Err(e) => {
                tracing::warn!(
                    id,
                    "servo lost power again: writing its settings failed ({e})"
                )
            }
        }
    }

    /// Torque off every servo within this tick, not waiting on the silent ones; `why` names
    /// the occasion in the log line naming the servos not confirmed, which are returned (for
    /// the reply of the command that asked) and sent the torque off again once they answer.
    pub(super) fn torque_off_all(&mut self, why: &str) -> Vec<Unconfirmed> {
        let mut silent = self.health.unanswering();
        // Servos booting from a reboot hear nothing yet (and come back with torque off).
        silent.extend(self.rebooting.iter().flat_map(|job| job.booting()));
        let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
        self.torque_off_pending.clear();
        let Err(unreached) = self.arm.torque_off(self.port.bus(), &silent, &within) else {
            return Vec::new();
        };
        let list: Vec<String> = unreached.iter().map(ToString::to_string).collect();
        tracing::warn!(
            "{why}: torque off not confirmed (sent again once they answer): {}",
            list.join("; ")
        );
        self.torque_off_pending
            .extend(unreached.iter().map(|u| u.id));
        unreached
            .into_iter()
            .map(|u| Unconfirmed {
                joint: u.joint,
                id: u.id,
                why: u.why,
            })
            .collect()
    }

    /// A torque off that missed servos reaches them once one of them answers a read (torque
    /// on since makes it moot).
    fn retry_torque_off(&mut self) {
        if self.torque_off_pending.is_empty() {
            return;
        }
        if self.supervisor.torque() {
            self.torque_off_pending.clear();
            return;
        }
        let (read, _) = read_set(self.reachable(), self.rebooting.as_ref(), &self.ids);
        let answered = self.torque_off_pending.iter().any(|id| {
            read.iter()
                .position(|x| x == id)
                .and_then(|slot| self.states.readings().get(slot))
                .is_some_and(Result::is_ok)
        });
        if answered {
            self.torque_off_all("a servo answering again");
        }
    }

    /// After a fault: tripped Bus Watchdogs cleared (goal := present, re-armed), goals := the
    /// measured pose, torque on again where it should be (never for a servo held for a power
    /// loss) or off where it should be off. Returns the servos whose watchdog had fired since
    /// the last recovery that completed. Every exchange within this tick.
    ///
    /// `limp`: the servos had torque off until now (a `torque` on), so a joint may have been
    /// turned past its limits by hand; such a joint refuses the recovery ([`Cycle::measure_pose`]).
    pub(super) fn recover(&mut self, limp: bool) -> Result<Vec<u8>, String> {
        self.stretched(|cycle| cycle.recover_now(limp))
    }

    fn recover_now(&mut self, limp: bool) -> Result<Vec<u8>, String> {
        self.clear_watchdogs().map_err(|e| e.to_string())?;
        self.measure_pose(limp && self.supervisor.torque())?;
        // A servo that latched a hardware error while it was not read (the port lost) shows
        // its alert flag here: held for it, it is left out of the torque on.
        self.raise_alerts();
        if self.supervisor.torque() {
            // A servo held for a power loss gets torque only on `reset`; one in a hardware
            // error refuses it until `reboot` (its fault holds the arm meanwhile).
            let mut skip = self.health.power_lost();
            skip.extend(self.health.hardware_faulted());
            let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
            self.arm
                .keep_torque_on(self.port.bus(), &skip, &within)
                .map_err(|e| e.to_string())?;
        } else {
            self.torque_off_all("recovery");
        }
        // Only once the bus work is done: a recovery that fails leaves the goals as they were.
        self.controller
            .reseed(&self.measured.theta)
            .map_err(|r| r.to_string())?;
        self.port.contact(self.clock.now());
        self.recover_after = None;
        // Every fired watchdog was cleared with the others.
        self.fired.clear();
        self.health.forgive();
        tracing::info!("recovered: holding the measured pose");
        Ok(std::mem::take(&mut self.rearmed).into_iter().collect())
    }

    /// `work` (a recovery's or a `reset`'s exchanges) with the fault path's time stretched to
    /// [`RECOVERY_WIRE_TICKS`] of the wire's ticks (at least a period) from now, when this
    /// tick has less left and every servo answered the latest read. It runs once, the arm at
    /// rest; cut short to what a tick leaves, it failed on a timed wire try after try. The tick
    /// it runs in may overrun, and is counted as such. With a servo missing from the latest read it keeps to the tick: that servo
    /// would most likely be waited on in vain.
    pub(super) fn stretched<T>(&mut self, work: impl FnOnce(&mut Self) -> T) -> T {
        if !self.health.all_answered() {
            return work(self);
        }
        let wire_tick = if self.wire_bound_hz.is_finite() {
            Duration::from_secs_f64(RECOVERY_WIRE_TICKS / self.wire_bound_hz)
        } else {
            Duration::ZERO
        };
        let tick_until = self.fault_until;
        let span = wire_tick.max(self.schedule.period);
        self.fault_until = tick_until.max(self.clock.now() + span);
        let done = work(self);
        self.fault_until = tick_until;
        done
    }

    /// Every fired Bus Watchdog cleared, goal := present, armed again (see
    /// [`Arm::recover_watchdog`]), within this tick. The servos it re-armed join `rearmed`:
    /// when a later step of the recovery fails, the one that completes names them.
    pub(super) fn clear_watchdogs(&mut self) -> Result<(), arm::BringUpError> {
        let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
        let fired = self
            .arm
            .recover_watchdog(self.port.bus(), &within, &mut self.unarmed)?;
        self.rearmed.extend(fired);
        Ok(())
    }

    /// The measured pose (one Sync Read of every position, its wait within this tick), each
    /// angle clamped into its joint's limits (a servo may rest a tick past one). The error names
    /// every servo that did not answer; with `from_limp` (the pose of servos that had torque off
    /// is to be held with torque on), also every joint past a limit by more than a tick (turned
    /// there by hand), as bring-up refuses it: its goal, clamped, would drive it to the limit at
    /// full speed. (A joint held with torque on may sag past its limit under a load; that is
    /// not refused.)
    pub(super) fn measure_pose(&mut self, from_limp: bool) -> Result<(), String> {
        let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
        let mut heard = vec![false; self.ids.len()];
        let mut ticks = vec![0; self.ids.len()];
        let mut missing = Vec::new();
        // A lost or damaged reply is asked for again while the tick allows.
        for _ in 0..=arm::RETRIES {
            let Some(wait) = within.wait() else {
                break;
            };
            self.port
                .bus()
                .read_states_into(&self.ids, Fields::POSITION, wait, &mut self.states)
                .map_err(|e| format!("reading the pose: {e}"))?;
            missing.clear();
            for (i, reading) in self.states.readings().iter().enumerate() {
                match reading {
                    Ok(s) => {
                        self.measured.record_position(i, s.position_ticks);
                        ticks[i] = s.position_ticks;
                        if s.alert {
                            self.health.alerted(i);
                        }
                        heard[i] = true;
                    }
                    Err(_) if heard[i] => {}
                    Err(err) => missing.push(format!("joint {}: {err}", i + 1)),
                }
            }
            if missing.is_empty() {
                break;
            }
        }
        if heard.iter().any(|h| !h) {
            if missing.is_empty() {
                missing.push("no time left in this tick".into());
            }
            return Err(format!("the pose cannot be read: {}", missing.join("; ")));
        }
        let outside = if from_limp {
            self.arm.outside_limits(&ticks)
        } else {
            Vec::new()
        };
        if !outside.is_empty() {
            let named: Vec<String> = outside.iter().map(ToString::to_string).collect();
            return Err(named.join("; "));
        }
        let limits = self.controller.chain().limits();
        for (t, l) in self.measured.theta.iter_mut().zip(limits) {
            if let Some(l) = l {
                *t = l.clamp(*t);
            }
        }
        Ok(())
    }

    /// Before the tick's work: contacts whose latch a `reset` released are cleared, a lost
    /// port reopened when due, else a stall past the Bus Watchdog recovered.
    pub(super) fn tend_port(&mut self) {
        if self.health.in_contact() && !self.supervisor.estopped() {
            for change in self
                .health
                .release_contacts("reset: the latch released, holding the measured pose")
            {
                self.report(change);
            }
        }
        if self.port.is_lost() {
            self.retry_port();
        } else {
            self.check_stall();
            self.check_fired();
        }
    }

    /// A read found Bus Watchdogs fired (-1) that no stall the loop measured explains (the
    /// servos saw a longer gap between goals than the loop did: a starved thread, a USB
    /// hiccup): those servos stopped and refuse goals. The same recovery as after a stall:
    /// the watchdogs cleared and re-armed, goals := the measured pose, the active command
    /// ended `fault`, a `recovered` event per servo. Left to their own recovery while a servo
    /// is held silent or a `reboot` boots servos.
    fn check_fired(&mut self) {
        if self.fired.is_empty() || self.rebooting.is_some() || !self.health.silent().is_empty() {
            return;
        }
        let fired = self.fired.clone();
        let watchdog_ms = self.arm.settings().watchdog_ms;
        tracing::warn!(
            "the Bus Watchdog of servos {fired:?} fired ({watchdog_ms} ms) though the loop measured no stall that long: they stopped and refuse goals; recovering"
        );
        let detail = format!(
            "the Bus Watchdog read -1 (watchdog {watchdog_ms} ms) with no stall of the loop that long: the servo saw a longer gap between goals; cleared, goal := present position, re-armed"
        );
        let tick = self.tick;
        let ended = self.ledger.interrupt(StopReason::Fault);
        self.owe(ended);
        match self.recover(false) {
            Ok(watchdogs) => self.announce_watchdogs(&watchdogs, tick, &detail),
            Err(e) => {
                // Tried again next tick: the fired watchdogs are still listed.
                tracing::warn!("watchdog recovery failed: {e}");
                self.controller.freeze();
            }
        }
    }

    /// A `recovered` event (kind `watchdog`) for each servo in `watchdogs`.
    fn announce_watchdogs(&mut self, watchdogs: &[u8], tick: u64, detail: &str) {
        for &id in watchdogs {
            if let Some(i) = self.ids.iter().position(|&x| x == id) {
                let info = self
                    .health
                    .info(i, FaultKind::Watchdog, tick, detail.to_owned());
                self.announce(FaultChange::Recovered, info);
            }
        }
    }

    /// The loop went quiet longer than the Bus Watchdog (the process was stopped, the machine
    /// stalled): the servos whose watchdog fired refuse goals until recovered.
    fn check_stall(&mut self) {
        let Some((gap, watchdog)) = self.port.stalled(self.clock.now()) else {
            return;
        };
        let within = Self::within(&self.clock, self.fault_until, self.schedule.reply_timeout);
        let tripped = self.arm.tripped_watchdogs(self.port.bus(), &within);
        self.port.contact(self.clock.now());
        let tripped = match tripped {
            // None fired, or those that did were re-armed by a recovery that failed past
            // that step (completed below, naming them).
            Ok(t) if t.is_empty() && self.rearmed.is_empty() => {
                self.port.stall_handled();
                return;
            }
            Ok(t) => t,
            Err(e) => {
                // Looked at again next tick: the stall stands until they are read.
                tracing::warn!("after a {gap:?} stall, reading the bus watchdogs failed: {e}");
                self.port.stall_again(gap);
                return;
            }
        };
        if tripped.is_empty() {
            tracing::warn!(
                rearmed = ?self.rearmed,
                "the loop stalled {gap:?}: completing the recovery of re-armed bus watchdogs"
            );
        } else {
            tracing::warn!(
                ?tripped,
                "the loop stalled {gap:?}: bus watchdogs fired, recovering"
            );
        }
        let tick = self.tick;
        let detail = format!(
            "the loop stalled {} ms (watchdog {} ms): the Bus Watchdog fired; cleared, goal := present position, re-armed",
            gap.as_millis(),
            watchdog.as_millis()
        );
        let ended = self.ledger.interrupt(StopReason::Fault);
        self.owe(ended);
        match self.recover(false) {
            Ok(watchdogs) => {
                self.port.stall_handled();
                self.announce_watchdogs(&watchdogs, tick, &detail);
            }
            Err(e) => {
                // Next tick's stall check (the gap is measured again) tries once more.
                tracing::warn!("watchdog recovery failed: {e}");
                self.controller.freeze();
                self.port.stall_again(gap);
            }
        }
    }

    /// The serial port failed: hold, report, reopen every [`RETRY_EVERY`].
    pub(super) fn lose_port(&mut self, e: &ServoError) {
        // A port already lost fails every tick it is written: only a port newly lost is news.
        let Some(info) = self.port.lose(self.tick, self.clock.now(), e.port(), e) else {
            return;
        };
        if self.port.several() {
            // The servos on the ports still open go on being read.
            let (ids, joints) = read_set(None, self.rebooting.as_ref(), &self.ids);
            self.reachable.fill(self.port.bus(), ids, joints);
        }
        self.sync_faulted();
        tracing::error!("{}", info.detail);
        self.announce(FaultChange::Raised, info);
        self.rebuild_lists();
    }

    /// A lost port, when its next try is due: opened again (else tried again a
    /// [`RETRY_EVERY`] later), and from the tick after, the arm recovered on it (see
    /// [`super::port::Port::recovery_failed`]).
    fn retry_port(&mut self) {
        let now = self.clock.now();
        if !self.port.reopen_due(now) {
            return;
        }
        if !self.port.reopened() {
            // Recovery comes on the next tick, within its own time.
            if let Err(e) = self.port.reopen(&self.arm, now) {
                tracing::debug!("reopening the port: {e}");
                self.port.retry_later(now);
            }
            return;
        }
        match self.recover(false) {
            Ok(_) => {
                tracing::info!("port reopened");
                for info in self.port.found() {
                    self.announce(FaultChange::Cleared, info);
                }
                self.rebuild_lists();
                self.sync_faulted();
            }
            Err(e) => {
                let e = ReopenError::Recover(e);
                // Tried every tick: the first failure after the port was lost is worth a line,
                // the rest are the same story.
                if self.port.first_recovery_failure() {
                    tracing::warn!(
                        "{e} (tried again every tick; the port opened afresh every second)"
                    );
                } else {
                    tracing::debug!("{e}");
                }
                self.port.recovery_failed(self.clock.now());
            }
        }
    }

    pub(super) fn write_failed(&mut self, e: &ServoError) {
        if e.class() == ErrorClass::Bus {
            self.lose_port(e);
            return;
        }
        let (count, worth_a_line) = self.stats.write_failed();
        if worth_a_line {
            tracing::warn!(count, "writing the goals failed: {e}");
        }
    }

    /// Health warnings from this tick's temperature and voltage readings, before the servo's
    /// own thresholds switch it off; contact detection on its loads (a contact stops the arm).
    fn check_health(&mut self) {
        let mut contacts = Vec::new();
        for i in 0..self.health.len() {
            if !self.measured.fresh.get(i).copied().unwrap_or(false) {
                continue;
            }
            let (t, v) = (self.measured.temperature_c[i], self.measured.voltage_v[i]);
            for change in self.health.judge(i, t, v, self.tick) {
                self.report(change);
            }
            let (load, unit) = (self.measured.load[i], self.measured.load_unit[i]);
            contacts.extend(self.health.judge_load(i, load, unit, self.tick));
        }
        if !contacts.is_empty() {
            self.contact_stop();
            for change in contacts {
                self.report(change);
            }
        }
    }

    /// A joint met something: the arm stops as for a fault (the command ends `fault`), stops
    /// pushing (goals := the measured pose, clamped into the limits) and is latched as by an
    /// estop, torque kept on, until `reset`. Nothing more when the latch is already set.
    fn contact_stop(&mut self) {
        if self.supervisor.estopped() {
            return;
        }
        self.controller.freeze();
        let ended = self.ledger.interrupt(StopReason::Fault);
        self.owe(ended);
        let limits = self.controller.chain().limits();
        let pose: Vec<f64> = self
            .measured
            .theta
            .iter()
            .zip(limits)
            .map(|(&t, l)| l.map_or(t, |l| l.clamp(t)))
            .collect();
        if let Err(r) = self.controller.reseed(&pose) {
            tracing::warn!("contact: holding the goals, not the measured pose: {r}");
        }
        self.supervisor.estop(false);
        tracing::warn!("contact: the arm stops and holds the measured pose until `reset`");
        self.event(None, None, |tip| What::Estop { tip });
    }
}

/// Each joint's health thresholds, read once after bring-up: Temperature Limit and Min/Max
/// Voltage Limit (a servo that does not answer them gets no warnings, logged). One Sync Read of
/// the span that holds the three for every servo, then single reads for a servo it missed:
/// the Bus Watchdogs are armed by now, and three single reads a servo in turn would leave the
/// first servo unaddressed longer than a 100 ms watchdog on a slow bus (36 reads of 12 servos
/// take about 0.18 s at 57600 baud).
pub(super) fn health_limits<B: ServoBus>(arm: &Arm, bus: &mut Limited<B>) -> Vec<Limits> {
    const REGISTERS: [Register; 3] = [
        Register::TemperatureLimit,
        Register::MinVoltageLimit,
        Register::MaxVoltageLimit,
    ];
    let t = arm.settings().reply_timeout;
    let start = REGISTERS.iter().map(|r| r.address()).min().unwrap_or(0);
    let end = REGISTERS
        .iter()
        .map(|r| r.address() + r.size())
        .max()
        .unwrap_or(0);
    let ids = arm.ids();
    let blocks = match bus.sync_read(&ids, start, end - start, t) {
        Ok(blocks) => blocks,
        Err(e) => {
            tracing::debug!("health limits: the sync read failed ({e}); reading each servo");
            Vec::new()
        }
    };
    let mut retry = Retry::default();
    arm.joints()
        .iter()
        .enumerate()
        .map(|(i, j)| {
            let block = blocks.get(i).and_then(|b| b.as_ref().ok());
            let mut read = |r: Register| {
                let offset = usize::from(r.address() - start);
                let held = block
                    .and_then(|b| b.data.get(offset..offset + usize::from(r.size())))
                    .and_then(|bytes| r.decode(bytes));
                match held {
                    Some(v) => Ok(v),
                    None => retry.run(|| bus.read(j.id, r, t)).map(|v| v.value),
                }
            };
            let temperature = read(Register::TemperatureLimit);
            let voltage = (
                read(Register::MinVoltageLimit),
                read(Register::MaxVoltageLimit),
            );
            let temperature_c = match temperature {
                Ok(c) => Some(c as f64),
                Err(e) => {
                    tracing::warn!(id = j.id, "no temperature warnings: {e}");
                    None
                }
            };
            let voltage_v = match voltage {
                (Ok(lo), Ok(hi)) => Some((units::limit_volts(lo), units::limit_volts(hi))),
                (Err(e), _) | (_, Err(e)) => {
                    tracing::warn!(id = j.id, "no voltage warnings: {e}");
                    None
                }
            };
            Limits {
                temperature_c,
                voltage_v,
            }
        })
        .collect()
}

/// What a recovery did, for the `cleared` event.
fn recovered_detail(watchdogs: &[u8]) -> String {
    if watchdogs.is_empty() {
        "goals := measured pose".into()
    } else {
        format!("goals := measured pose; the Bus Watchdog of servos {watchdogs:?} had fired and was cleared")
    }
}
