//! Joint health, pure: each servo's error budget (a time, the same at every loop rate), the
//! fault that holds it, its temperature and voltage warnings with hysteresis, and contact
//! detection (a load above its threshold for long enough). Readings and times go in,
//! [`Change`]s come out; the cycle turns them into events and log lines, and does the bus work
//! (reading Hardware Error Status, recovering) and the stops itself.

use std::time::{Duration, Instant};

use crate::config::Contact;
use crate::protocol::{FaultChange, FaultInfo, FaultKind, LoadUnit};
use crate::servo::HardwareErrors;

/// A temperature warning this close below the servo's Temperature Limit, °C.
pub const TEMPERATURE_MARGIN_C: f64 = 5.0;

/// A voltage warning this close to the servo's Min/Max Voltage Limit, V.
pub const VOLTAGE_MARGIN_V: f64 = 0.5;

/// How far back outside its margin a temperature must come before the warning clears, °C.
pub const TEMPERATURE_HYSTERESIS_C: f64 = 1.0;

/// How far back outside its margin a voltage must come before the warning clears, V.
pub const VOLTAGE_HYSTERESIS_V: f64 = 0.1;

/// What holds one joint's servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointFault {
    /// No valid reply for `control.max_silence_ms`.
    Silent,
    /// Its alert flag: a latched hardware error (the bits read, empty when unreadable).
    Hardware(HardwareErrors),
    /// It answered again with its RAM reset (it lost power): held, with the arm latched, until
    /// `reset` (or `reboot`).
    PowerLoss,
}

impl JointFault {
    /// Its kind on the wire.
    pub fn kind(self) -> FaultKind {
        match self {
            JointFault::Silent => FaultKind::Silent,
            JointFault::Hardware(_) => FaultKind::HardwareError,
            JointFault::PowerLoss => FaultKind::PowerLoss,
        }
    }
}

/// One joint's thresholds for warnings, read once after bring-up (`None`: the servo did not
/// answer that register, so it gets no such warning).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Limits {
    /// Temperature Limit (register 31), °C.
    pub temperature_c: Option<f64>,
    /// Min and Max Voltage Limit (registers 34 and 32), V.
    pub voltage_v: Option<(f64, f64)>,
}

/// The error budget: how long a servo may go without a valid reply, and how often it is read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Budget {
    /// `control.max_silence_ms`.
    pub max_silence: Duration,
    /// Time between two reads on schedule (`read_every` periods).
    pub read_interval: Duration,
}

/// A change of a fault or warning, for the cycle to report.
#[derive(Debug, Clone, PartialEq)]
pub struct Change {
    /// Raised or cleared.
    pub change: FaultChange,
    /// Which servo, what kind, the details.
    pub info: FaultInfo,
}

impl Change {
    fn raised(info: FaultInfo) -> Change {
        Change {
            change: FaultChange::Raised,
            info,
        }
    }

    fn cleared(info: FaultInfo) -> Change {
        Change {
            change: FaultChange::Cleared,
            info,
        }
    }
}

/// A fault held, since which tick, and why.
#[derive(Debug, Clone, PartialEq)]
struct Held {
    fault: JointFault,
    since: u64,
    detail: String,
}

/// Reads missed in a row after which a servo counts as not answering for a shut-down (not
/// waited on): one or two lost replies are what a noisy line loses, and such a servo still
/// confirms its torque off.
const SILENT_READS: u32 = 3;

/// The first read of a run of reads that missed a servo's reply.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Streak {
    reads: u32,
    first_tick: u64,
    first_at: Instant,
}

#[derive(Debug, Clone, Default)]
struct Joint {
    id: u8,
    streak: Option<Streak>,
    /// The reply of this read carried the alert flag (handled after the read).
    alert: bool,
    fault: Option<Held>,
    limits: Limits,
    /// Active warnings: since which tick, and why.
    temperature: Option<(u64, String)>,
    voltage: Option<(u64, String)>,
    /// The health tick since which its load has stayed above its contact threshold.
    over: Option<u64>,
    /// A contact latched: since which tick, and why.
    contact: Option<(u64, String)>,
}

/// Contact detection as the loop counts it: thresholds per joint, and how many ticks a load
/// must stay above one.
#[derive(Debug, Clone, PartialEq)]
struct ContactRule {
    load: Vec<f64>,
    hold: Duration,
    hold_ticks: u64,
}

/// Every joint's health.
#[derive(Debug, Clone)]
pub struct Health {
    joints: Vec<Joint>,
    budget: Budget,
    /// The port the servos are on, for the reports.
    port: Option<String>,
    /// With several ports, each joint's (index as `joints`), for the reports.
    ports: Vec<Option<String>>,
    contact: Option<ContactRule>,
}

impl Health {
    /// Healthy joints with servo `ids` and their warning `limits` (one each), on `port`.
    pub fn new(ids: &[u8], limits: &[Limits], budget: Budget, port: Option<String>) -> Self {
        let joints = ids
            .iter()
            .zip(
                limits
                    .iter()
                    .copied()
                    .chain(std::iter::repeat(Limits::default())),
            )
            .map(|(&id, limits)| Joint {
                id,
                limits,
                ..Joint::default()
            })
            .collect();
        Self {
            joints,
            budget,
            port,
            ports: Vec::new(),
            contact: None,
        }
    }

    /// Each servo's port, `(id, path)`, for a bus of several: a joint's report names its own.
    pub fn set_ports(&mut self, ports: &[(u8, String)]) {
        self.ports = self
            .joints
            .iter()
            .map(|j| {
                ports
                    .iter()
                    .find(|(id, _)| *id == j.id)
                    .map(|(_, p)| p.clone())
            })
            .collect();
    }

    /// Contact detection on (`contact`) or off (`None`), on a loop whose ticks are `period`
    /// apart: a load must stay above its threshold from one health read to one at least
    /// `contact.hold` later (in ticks, rounded up).
    pub fn set_contact(&mut self, contact: Option<&Contact>, period: Duration) {
        self.contact = contact.map(|c| {
            let period = period.as_secs_f64();
            let ticks = if period > 0.0 {
                (c.hold.as_secs_f64() / period - 1e-9).ceil().max(0.0)
            } else {
                0.0
            };
            ContactRule {
                load: c.load.clone(),
                hold: c.hold,
                hold_ticks: ticks as u64,
            }
        });
        for j in &mut self.joints {
            j.over = None;
        }
    }

    /// The joints, counted.
    pub fn len(&self) -> usize {
        self.joints.len()
    }

    /// No joints at all.
    pub fn is_empty(&self) -> bool {
        self.joints.is_empty()
    }

    /// The fault report of joint `i` (1-based joint, its servo id).
    pub fn info(&self, i: usize, kind: FaultKind, since: u64, detail: String) -> FaultInfo {
        FaultInfo {
            id: self.joints.get(i).map(|j| j.id),
            joint: Some(i + 1),
            port: self
                .ports
                .get(i)
                .cloned()
                .flatten()
                .or_else(|| self.port.clone()),
            kind,
            since_tick: since,
            detail,
        }
    }

    /// Whether every servo answered the latest read (those held silent too, once back).
    pub fn all_answered(&self) -> bool {
        self.joints.iter().all(|j| j.streak.is_none())
    }

    /// The servos not to wait on: those held silent, and those that missed their latest
    /// `SILENT_READS` reads in a row.
    pub fn unanswering(&self) -> Vec<u8> {
        self.joints
            .iter()
            .filter(|j| {
                j.streak.is_some_and(|s| s.reads >= SILENT_READS)
                    || matches!(
                        j.fault,
                        Some(Held {
                            fault: JointFault::Silent,
                            ..
                        })
                    )
            })
            .map(|j| j.id)
            .collect()
    }

    /// The servos held silent.
    pub fn silent(&self) -> Vec<u8> {
        self.held_for(|f| f == JointFault::Silent)
    }

    /// The servos held for a power loss.
    pub fn power_lost(&self) -> Vec<u8> {
        self.held_for(|f| f == JointFault::PowerLoss)
    }

    /// The joint (0-based) of servo `id`.
    pub fn index_of(&self, id: u8) -> Option<usize> {
        self.joints.iter().position(|j| j.id == id)
    }

    /// Joint `i` answered a read with a valid reply (`alert`: its alert flag was set). True when
    /// the fault path has something to look at: a servo back from silence, or a new alert.
    pub fn answered(&mut self, i: usize, alert: bool) -> bool {
        let Some(j) = self.joints.get_mut(i) else {
            return false;
        };
        j.streak = None;
        let hardware = matches!(
            j.fault,
            Some(Held {
                fault: JointFault::Hardware(_),
                ..
            })
        );
        let mut attention = matches!(
            j.fault,
            Some(Held {
                fault: JointFault::Silent,
                ..
            })
        );
        if alert && !hardware {
            j.alert = true;
            attention = true;
        }
        attention
    }

    /// Joint `i`'s reply outside the loop's read (a recovery's) carried the alert flag: taken
    /// by the next [`Health::take_alerts`] unless a hardware error holds it already.
    pub fn alerted(&mut self, i: usize) {
        if let Some(j) = self.joints.get_mut(i) {
            if !matches!(
                j.fault,
                Some(Held {
                    fault: JointFault::Hardware(_),
                    ..
                })
            ) {
                j.alert = true;
            }
        }
    }

    /// Joint `i` missed its reply to the read of `tick`, scheduled at `at`; true when that
    /// exhausts its budget. The silence counts from one read interval before the first read
    /// of the run that missed (when the servo last answered, on schedule), so a stall of the
    /// loop itself before a miss is never held against the servo.
    pub fn missed(&mut self, i: usize, tick: u64, at: Instant) -> bool {
        let budget = self.budget;
        let Some(j) = self.joints.get_mut(i) else {
            return false;
        };
        let streak = j.streak.get_or_insert(Streak {
            reads: 0,
            first_tick: tick,
            first_at: at,
        });
        streak.reads = streak.reads.saturating_add(1);
        j.fault.is_none() && silence(streak, at, budget) >= budget.max_silence
    }

    /// Joint `i` is not read for a while (it reboots): a silence it may have begun is
    /// forgotten, and none is counted until it misses a read again.
    pub fn expect_silence(&mut self, i: usize) {
        if let Some(j) = self.joints.get_mut(i) {
            j.streak = None;
        }
    }

    /// Silent joints to raise, as of `at`: each with the tick its silence began and why.
    pub fn exhausted(&self, at: Instant) -> Vec<(usize, u64, String)> {
        let budget = self.budget;
        self.joints
            .iter()
            .enumerate()
            .filter(|(_, j)| j.fault.is_none())
            .filter_map(|(i, j)| {
                let s = j.streak?;
                let quiet = silence(&s, at, budget);
                (quiet >= budget.max_silence).then(|| {
                    let detail = format!(
                        "no valid reply for {} ms, {} consecutive reads since tick {} \
                         (control.max_silence_ms = {})",
                        quiet.as_millis(),
                        s.reads,
                        s.first_tick,
                        budget.max_silence.as_millis()
                    );
                    (i, s.first_tick, detail)
                })
            })
            .collect()
    }

    /// The joints whose alert flag came up since the last call, cleared.
    pub fn take_alerts(&mut self) -> Vec<usize> {
        let mut alerts = Vec::new();
        for (i, j) in self.joints.iter_mut().enumerate() {
            if std::mem::take(&mut j.alert) {
                alerts.push(i);
            }
        }
        alerts
    }

    /// Silent joints that answer again.
    pub fn back_from_silence(&self) -> Vec<usize> {
        (0..self.joints.len())
            .filter(|&i| {
                let j = &self.joints[i];
                j.streak.is_none()
                    && matches!(
                        j.fault,
                        Some(Held {
                            fault: JointFault::Silent,
                            ..
                        })
                    )
            })
            .collect()
    }

    /// A fault on any joint other than those in `except`.
    pub fn faulted_except(&self, except: &[usize]) -> bool {
        self.joints
            .iter()
            .enumerate()
            .any(|(i, j)| j.fault.is_some() && !except.contains(&i))
    }

    /// A fault on any joint.
    pub fn any_fault(&self) -> bool {
        self.faulted_except(&[])
    }

    /// The servos held by a hardware error.
    pub fn hardware_faulted(&self) -> Vec<u8> {
        self.held_for(|f| matches!(f, JointFault::Hardware(_)))
    }

    /// The servos whose fault `which` picks.
    fn held_for(&self, which: impl Fn(JointFault) -> bool) -> Vec<u8> {
        self.joints
            .iter()
            .filter(|j| j.fault.as_ref().is_some_and(|h| which(h.fault)))
            .map(|j| j.id)
            .collect()
    }

    /// Hold joint `i` for `fault`, since tick `since`.
    pub fn raise(&mut self, i: usize, fault: JointFault, since: u64, detail: String) -> Change {
        if let Some(j) = self.joints.get_mut(i) {
            j.fault = Some(Held {
                fault,
                since,
                detail: detail.clone(),
            });
        }
        Change::raised(self.info(i, fault.kind(), since, detail))
    }

    /// Joint `i`'s fault cleared (`None` when it had none); its budget starts afresh.
    pub fn clear(&mut self, i: usize, detail: String) -> Option<Change> {
        let j = self.joints.get_mut(i)?;
        let held = j.fault.take()?;
        j.streak = None;
        Some(Change::cleared(self.info(
            i,
            held.fault.kind(),
            held.since,
            detail,
        )))
    }

    /// Every budget starts afresh (after a recovery: the servos were just read).
    pub fn forgive(&mut self) {
        for j in &mut self.joints {
            j.streak = None;
        }
    }

    /// Warnings raised or cleared by joint `i`'s fresh temperature `t_c` and input voltage
    /// `v_v`, read at `tick`: raised within a margin of the servo's own limits, cleared only
    /// once the value is back past the margin by the hysteresis.
    pub fn judge(&mut self, i: usize, t_c: f64, v_v: f64, tick: u64) -> Vec<Change> {
        let mut changes = Vec::new();
        let Some(j) = self.joints.get(i) else {
            return changes;
        };
        let (limits, hot, low) = (j.limits, j.temperature.is_some(), j.voltage.is_some());
        if let Some(limit) = limits.temperature_c {
            let warn_at = limit - TEMPERATURE_MARGIN_C;
            if !hot && t_c >= warn_at {
                let detail = format!(
                    "{t_c:.0} °C, within {TEMPERATURE_MARGIN_C:.0} °C of its Temperature Limit {limit:.0} °C"
                );
                changes.extend(self.warn(i, FaultKind::Temperature, tick, Some(detail)));
            } else if hot && t_c < warn_at - TEMPERATURE_HYSTERESIS_C {
                changes.extend(self.warn(i, FaultKind::Temperature, tick, None));
            }
        }
        if let Some((lo, hi)) = limits.voltage_v {
            let near = v_v <= lo + VOLTAGE_MARGIN_V || v_v >= hi - VOLTAGE_MARGIN_V;
            let clear = v_v > lo + VOLTAGE_MARGIN_V + VOLTAGE_HYSTERESIS_V
                && v_v < hi - VOLTAGE_MARGIN_V - VOLTAGE_HYSTERESIS_V;
            if !low && near {
                let detail = format!(
                    "input {v_v:.1} V, within {VOLTAGE_MARGIN_V} V of its voltage limits {lo:.1}..{hi:.1} V"
                );
                changes.extend(self.warn(i, FaultKind::Voltage, tick, Some(detail)));
            } else if low && clear {
                changes.extend(self.warn(i, FaultKind::Voltage, tick, None));
            }
        }
        changes
    }

    /// Contact detection on joint `i`'s fresh load `load` (in `unit`), read at `tick`: a
    /// `contact` raised once its |load| has stayed above the joint's threshold on every health
    /// read for the rule's time (counted in ticks from the first read above), `None` otherwise
    /// or while a contact is latched. A contact is not a fault of [`Health::any_fault`]: the
    /// cycle latches the arm for it, and [`Health::release_contacts`] clears it with the latch.
    pub fn judge_load(&mut self, i: usize, load: f64, unit: LoadUnit, tick: u64) -> Option<Change> {
        let rule = self.contact.as_ref()?;
        let threshold = rule.load.get(i).copied()?;
        let j = self.joints.get_mut(i)?;
        if j.contact.is_some() {
            return None;
        }
        if load.abs() <= threshold {
            j.over = None;
            return None;
        }
        let since = *j.over.get_or_insert(tick);
        let ticks = tick.saturating_sub(since);
        if ticks < rule.hold_ticks {
            return None;
        }
        let unit = match unit {
            LoadUnit::Percent => "%",
            LoadUnit::Amps => "A",
        };
        let detail = format!(
            "load {load:.2} {unit} beyond contact_load = {threshold} {unit} on every read for \
             {ticks} ticks (contact_ms = {}): the arm met something; goals := the measured \
             pose, the arm latched as by an estop until `reset`",
            rule.hold.as_millis()
        );
        j.over = None;
        j.contact = Some((since, detail.clone()));
        Some(Change::raised(self.info(
            i,
            FaultKind::Contact,
            since,
            detail,
        )))
    }

    /// Whether a contact is latched on any joint.
    pub fn in_contact(&self) -> bool {
        self.joints.iter().any(|j| j.contact.is_some())
    }

    /// Every latched contact cleared (the latch that held the arm for them was released), with
    /// its report; detection starts afresh.
    pub fn release_contacts(&mut self, detail: &str) -> Vec<Change> {
        let mut changes = Vec::new();
        for i in 0..self.joints.len() {
            self.joints[i].over = None;
            if let Some((since, _)) = self.joints[i].contact.take() {
                changes.push(Change::cleared(self.info(
                    i,
                    FaultKind::Contact,
                    since,
                    detail.to_owned(),
                )));
            }
        }
        changes
    }

    /// Raise (`detail`) or clear (`None`) joint `i`'s warning of `kind`.
    fn warn(
        &mut self,
        i: usize,
        kind: FaultKind,
        tick: u64,
        detail: Option<String>,
    ) -> Option<Change> {
        let j = self.joints.get_mut(i)?;
        let slot = if kind == FaultKind::Temperature {
            &mut j.temperature
        } else {
            &mut j.voltage
        };
        Some(match detail {
            Some(d) => {
                *slot = Some((tick, d.clone()));
                Change::raised(self.info(i, kind, tick, d))
            }
            None => {
                let (since, _) = slot.take()?;
                Change::cleared(self.info(i, kind, since, format!("{kind} back in range")))
            }
        })
    }

    /// The fault and warning lists telemetry carries, the lost ports' faults (`ports`) first.
    pub fn lists(&self, ports: Vec<FaultInfo>) -> (Vec<FaultInfo>, Vec<FaultInfo>) {
        let mut faults = ports;
        let mut warnings = Vec::new();
        for (i, j) in self.joints.iter().enumerate() {
            if let Some(h) = &j.fault {
                faults.push(self.info(i, h.fault.kind(), h.since, h.detail.clone()));
            }
            if let Some((since, detail)) = &j.contact {
                faults.push(self.info(i, FaultKind::Contact, *since, detail.clone()));
            }
            for (kind, slot) in [
                (FaultKind::Temperature, &j.temperature),
                (FaultKind::Voltage, &j.voltage),
            ] {
                if let Some((since, detail)) = slot {
                    warnings.push(self.info(i, kind, *since, detail.clone()));
                }
            }
        }
        (faults, warnings)
    }
}

/// How long a run of missed reads has kept a servo silent as of `at`.
fn silence(streak: &Streak, at: Instant, budget: Budget) -> Duration {
    at.saturating_duration_since(streak.first_at) + budget.read_interval
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn health(read_interval_ms: u64) -> Health {
        let limits = Limits {
            temperature_c: Some(70.0),
            voltage_v: Some((9.5, 16.0)),
        };
        Health::new(
            &[1, 2],
            &[limits, limits],
            Budget {
                max_silence: 50 * MS,
                read_interval: read_interval_ms as u32 * MS,
            },
            Some("/dev/ttyUSB0".into()),
        )
    }

    /// Reads on schedule every `interval_ms` that miss joint 0 until it is exhausted: the
    /// number of reads it took.
    fn reads_to_exhaust(interval_ms: u64) -> u64 {
        let mut h = health(interval_ms);
        let t0 = Instant::now();
        for k in 1..=10_000u64 {
            if h.missed(0, k, t0 + Duration::from_millis(k * interval_ms)) {
                return k;
            }
        }
        panic!("never exhausted");
    }

    #[test]
    fn the_budget_is_the_same_time_at_every_read_rate() {
        // 50 ms: 5 reads at 100 Hz, 50 at 1 kHz, 1 at 20 Hz (a read every 50 ms).
        assert_eq!(reads_to_exhaust(10), 5);
        assert_eq!(reads_to_exhaust(1), 50);
        assert_eq!(reads_to_exhaust(50), 1);
    }

    #[test]
    fn a_valid_reply_restarts_the_budget() {
        let mut h = health(10);
        let t0 = Instant::now();
        for k in 1..=4u64 {
            assert!(!h.missed(0, k, t0 + k as u32 * 10 * MS));
        }
        assert!(!h.answered(0, false));
        for k in 6..=9u64 {
            assert!(!h.missed(0, k, t0 + k as u32 * 10 * MS));
        }
        assert!(h.missed(0, 10, t0 + 100 * MS));
        let exhausted = h.exhausted(t0 + 100 * MS);
        assert_eq!(exhausted.len(), 1);
        assert_eq!(exhausted[0].0, 0);
        assert_eq!(exhausted[0].1, 6, "the silence began at tick 6");
        assert!(
            exhausted[0].2.contains("5 consecutive reads"),
            "{}",
            exhausted[0].2
        );
    }

    #[test]
    fn a_stall_of_the_loop_before_a_miss_is_not_held_against_the_servo() {
        let mut h = health(10);
        let t0 = Instant::now();
        assert!(!h.answered(0, false));
        // The loop stood still for 300 ms; the first read after it misses.
        assert!(!h.missed(0, 2, t0 + 300 * MS));
        assert!(h.exhausted(t0 + 300 * MS).is_empty());
    }

    #[test]
    fn a_fault_is_raised_once_and_cleared_with_its_report() {
        let mut h = health(10);
        let change = h.raise(1, JointFault::Silent, 7, "quiet".into());
        assert_eq!(change.change, FaultChange::Raised);
        let f = &change.info;
        assert!(
            f.id == Some(2)
                && f.joint == Some(2)
                && f.port.as_deref() == Some("/dev/ttyUSB0")
                && f.kind == FaultKind::Silent
                && f.since_tick == 7
        );
        assert!(h.any_fault() && !h.faulted_except(&[1]));
        // A faulted joint does not exhaust again.
        let t0 = Instant::now();
        for k in 0..10u64 {
            assert!(!h.missed(1, k, t0 + k as u32 * 10 * MS));
        }
        assert!(h.exhausted(t0 + 100 * MS).is_empty());
        assert!(h.back_from_silence().is_empty());
        assert!(h.answered(1, false), "back from silence needs attention");
        assert_eq!(h.back_from_silence(), vec![1]);
        let cleared = h.clear(1, "answers".into());
        let cleared = cleared.unwrap();
        assert_eq!(cleared.change, FaultChange::Cleared);
        assert!(cleared.info.since_tick == 7 && cleared.info.detail == "answers");
        assert!(h.clear(1, "again".into()).is_none());
        assert!(!h.any_fault());
    }

    #[test]
    fn an_alert_is_taken_once_and_not_again_while_its_hardware_error_holds() {
        let mut h = health(10);
        assert!(h.answered(0, true));
        assert_eq!(h.take_alerts(), vec![0]);
        assert!(h.take_alerts().is_empty());
        h.raise(
            0,
            JointFault::Hardware(HardwareErrors(0x20)),
            3,
            "overload".into(),
        );
        assert!(!h.answered(0, true));
        assert!(h.take_alerts().is_empty());
        assert_eq!(h.hardware_faulted(), vec![1]);
    }

    #[test]
    fn temperature_warnings_have_hysteresis() {
        let mut h = health(10);
        // Limit 70 °C: warns at 65, clears below 64.
        assert!(h.judge(0, 64.9, 12.0, 1).is_empty());
        let raised = h.judge(0, 65.0, 12.0, 2);
        assert!(
            matches!(&raised[..], [Change { change: FaultChange::Raised, info }] if info.kind == FaultKind::Temperature && info.since_tick == 2)
        );
        assert!(
            h.judge(0, 64.5, 12.0, 3).is_empty(),
            "inside the hysteresis"
        );
        let cleared = h.judge(0, 63.9, 12.0, 4);
        assert!(
            matches!(&cleared[..], [Change { change: FaultChange::Cleared, info }] if info.since_tick == 2)
        );
        assert_eq!(h.lists(Vec::new()).1.len(), 0);
    }

    #[test]
    fn voltage_warnings_have_hysteresis_at_both_ends() {
        let mut h = health(10);
        // Limits 9.5..16 V: warns at or below 10.0, clears above 10.1.
        let raised = h.judge(1, 40.0, 10.0, 1);
        assert!(
            matches!(&raised[..], [Change { change: FaultChange::Raised, info }] if info.kind == FaultKind::Voltage && info.id == Some(2))
        );
        assert_eq!(h.lists(Vec::new()).1.len(), 1);
        assert!(h.judge(1, 40.0, 10.05, 2).is_empty());
        assert_eq!(h.judge(1, 40.0, 10.2, 3).len(), 1);
        assert_eq!(h.judge(1, 40.0, 15.5, 4).len(), 1, "the high end warns too");
    }

    #[test]
    fn the_servos_not_to_wait_on_are_the_silent_and_those_that_missed_their_last_reads() {
        let mut h = health(10);
        let t0 = Instant::now();
        assert!(h.unanswering().is_empty());
        // One or two lost replies are a noisy line: such a servo is still waited on.
        for tick in 1..SILENT_READS {
            assert!(!h.missed(1, u64::from(tick), t0));
            assert!(h.unanswering().is_empty(), "after {tick} missed reads");
        }
        assert!(!h.missed(1, u64::from(SILENT_READS), t0));
        assert_eq!(h.unanswering(), vec![2], "missed its latest reads in a row");
        assert!(!h.answered(1, false));
        assert!(h.unanswering().is_empty());
        h.raise(0, JointFault::Silent, 3, "quiet".into());
        assert_eq!(h.unanswering(), vec![1]);
        assert_eq!(h.silent(), vec![1]);
        h.raise(1, JointFault::PowerLoss, 4, "RAM reset".into());
        assert_eq!(h.power_lost(), vec![2]);
        assert_eq!(
            h.unanswering(),
            vec![1],
            "a servo back from a power loss answers"
        );
        assert_eq!(h.index_of(2), Some(1));
    }

    fn contact(h: &mut Health, hold_ms: u64) {
        let rule = Contact {
            load: vec![50.0, 1.0],
            hold: Duration::from_millis(hold_ms),
        };
        h.set_contact(Some(&rule), 10 * MS);
    }

    #[test]
    fn a_contact_is_raised_once_the_load_stays_above_its_threshold_for_its_time() {
        let mut h = health(10);
        contact(&mut h, 200);
        // Health reads every 10 ticks of 10 ms: above at ticks 10, 20 and 30 is 200 ms.
        assert_eq!(h.judge_load(0, 60.0, LoadUnit::Percent, 10), None);
        assert_eq!(h.judge_load(0, 60.0, LoadUnit::Percent, 20), None);
        assert!(!h.in_contact());
        let raised = h.judge_load(0, 60.0, LoadUnit::Percent, 30).unwrap();
        assert_eq!(raised.change, FaultChange::Raised);
        let f = &raised.info;
        assert!(
            f.kind == FaultKind::Contact
                && f.id == Some(1)
                && f.joint == Some(1)
                && f.port.as_deref() == Some("/dev/ttyUSB0")
                && f.since_tick == 10,
            "{f:?}"
        );
        assert!(
            f.detail.contains("load 60.00 %") && f.detail.contains("contact_load = 50 %"),
            "{}",
            f.detail
        );
        // Latched: listed as a fault, not raised again, not a fault that holds by itself.
        assert!(h.in_contact() && !h.any_fault());
        assert_eq!(h.judge_load(0, 90.0, LoadUnit::Percent, 40), None);
        let (faults, _) = h.lists(Vec::new());
        assert_eq!(faults.len(), 1);
        assert_eq!(faults[0].kind, FaultKind::Contact);
        let cleared = h.release_contacts("released");
        assert_eq!(cleared.len(), 1);
        assert_eq!(cleared[0].change, FaultChange::Cleared);
        assert!(cleared[0].info.since_tick == 10 && cleared[0].info.detail == "released");
        assert!(!h.in_contact() && h.lists(Vec::new()).0.is_empty());
        assert!(h.release_contacts("again").is_empty());
    }

    #[test]
    fn a_load_that_dips_below_its_threshold_starts_the_count_again() {
        let mut h = health(10);
        contact(&mut h, 200);
        assert_eq!(h.judge_load(1, -1.5, LoadUnit::Amps, 10), None);
        assert_eq!(h.judge_load(1, -1.5, LoadUnit::Amps, 20), None);
        assert_eq!(h.judge_load(1, 0.4, LoadUnit::Amps, 30), None);
        assert_eq!(h.judge_load(1, -1.5, LoadUnit::Amps, 40), None);
        assert_eq!(h.judge_load(1, 1.5, LoadUnit::Amps, 50), None);
        // Either sign counts: the magnitude is what pushes.
        let raised = h.judge_load(1, -1.5, LoadUnit::Amps, 60).unwrap();
        assert_eq!((raised.info.joint, raised.info.since_tick), (Some(2), 40));
        assert!(
            raised.info.detail.contains("-1.50 A"),
            "{}",
            raised.info.detail
        );
        // At the threshold is not above it.
        let mut h = health(10);
        contact(&mut h, 0);
        assert_eq!(h.judge_load(0, 50.0, LoadUnit::Percent, 1), None);
        assert!(
            h.judge_load(0, 50.1, LoadUnit::Percent, 2).is_some(),
            "0 ms: the first read"
        );
    }

    #[test]
    fn without_thresholds_no_load_is_a_contact() {
        let mut h = health(10);
        for tick in 0..100 {
            assert_eq!(h.judge_load(0, 100.0, LoadUnit::Percent, tick), None);
        }
        contact(&mut h, 100);
        h.set_contact(None, 10 * MS);
        assert_eq!(h.judge_load(0, 100.0, LoadUnit::Percent, 200), None);
        assert_eq!(h.judge_load(0, 100.0, LoadUnit::Percent, 300), None);
    }

    #[test]
    fn the_lists_put_the_port_first() {
        let mut h = health(10);
        h.raise(0, JointFault::Silent, 1, "quiet".into());
        let port = FaultInfo::port(Some("/dev/ttyUSB0".into()), 4, "gone".into());
        let (faults, warnings) = h.lists(vec![port]);
        assert_eq!(faults.len(), 2);
        assert_eq!(faults[0].kind, FaultKind::Port);
        assert_eq!(faults[1].kind, FaultKind::Silent);
        assert!(warnings.is_empty());
    }
}
