//! The command ledger: the active command (the one that moves the arm), the last one that
//! ended, and how each ended. Pure: it says which event an ending owes its sender; the cycle
//! sends it with the tick and the tip.

use crate::control::Finish;
use crate::protocol::{ClientId, CommandInfo, EventKind, RequestId};

/// How a command ended, or that it is still running.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Still moving the arm.
    Active,
    /// On its target.
    Arrived,
    /// Stopped short of a target out of reach.
    Saturated,
    /// Brought to rest (a stop, the deadman, a reboot, torque off).
    Stopped,
    /// Replaced by another command.
    Preempted,
    /// Ended by a fault.
    Fault,
    /// Ended by the estop.
    Estop,
}

impl Outcome {
    /// The name on the wire (`command.outcome`).
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Active => "active",
            Outcome::Arrived => "arrived",
            Outcome::Saturated => "saturated",
            Outcome::Stopped => "stopped",
            Outcome::Preempted => "preempted",
            Outcome::Fault => "fault",
            Outcome::Estop => "estop",
        }
    }
}

/// Why a command was brought to rest without arriving.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// A `stop` command.
    Stop,
    /// A velocity or jog not renewed within the deadman.
    Deadman,
    /// A fault (the protective stop, or the loop stalling past the Bus Watchdog).
    Fault,
    /// A `reboot` command.
    Reboot,
    /// Torque switched off by command.
    Torque,
}

impl StopReason {
    /// The name on the wire (a `stopped` event's `reason`).
    pub fn as_str(self) -> &'static str {
        match self {
            StopReason::Stop => "stop",
            StopReason::Deadman => "deadman",
            StopReason::Fault => "fault",
            StopReason::Reboot => "reboot",
            StopReason::Torque => "torque",
        }
    }
}

/// An event owed to the sender of a command that ended.
#[derive(Debug, Clone, PartialEq)]
pub struct Ended {
    /// Who sent the command.
    pub owner: ClientId,
    /// Its request id.
    pub id: Option<RequestId>,
    /// The event.
    pub kind: EventKind,
    /// The event's reason.
    pub reason: Option<&'static str>,
}

/// A command that moves the arm, and its running account.
#[derive(Debug, Clone)]
struct Entry {
    owner: ClientId,
    id: Option<RequestId>,
    kind: &'static str,
    outcome: Outcome,
    peak: f64,
    m3: f64,
}

impl Entry {
    fn ended(&self, kind: EventKind, reason: Option<&'static str>) -> Ended {
        Ended {
            owner: self.owner,
            id: self.id.clone(),
            kind,
            reason,
        }
    }
}

/// What renews the active command instead of starting a new one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Renewal {
    /// A `velocity`: any renewal from the same client.
    Velocity,
    /// A `jog` of this joint (1-based).
    Jog(usize),
    /// Anything else starts a new command.
    None,
}

/// The active and last command.
#[derive(Debug, Clone, Default)]
pub struct Ledger {
    active: Option<Entry>,
    last: Option<Entry>,
    /// The joint of the last jog, to tell a renewal from a new jog.
    last_jog: Option<usize>,
}

impl Ledger {
    /// Nothing commanded yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// The command to report: the active one, else the last one that ended.
    pub fn info(&self) -> Option<CommandInfo> {
        self.active
            .as_ref()
            .or(self.last.as_ref())
            .map(|e| CommandInfo {
                kind: e.kind,
                id: e.id.clone(),
                outcome: e.outcome.as_str(),
                peak_joint_speed_rad_s: e.peak,
                m3_rad2: e.m3,
            })
    }

    /// A command accepted by the controller becomes the active one. Renewing a velocity (or the
    /// same joint's jog) from the same client keeps the running account under the new id;
    /// anything else preempts the active command, whose sender is owed the returned event.
    pub fn begin(
        &mut self,
        owner: ClientId,
        id: Option<RequestId>,
        kind: &'static str,
        renewal: Renewal,
    ) -> Option<Ended> {
        let renews = self.active.as_ref().is_some_and(|a| {
            a.owner == owner
                && a.kind == kind
                && match renewal {
                    Renewal::Velocity => true,
                    Renewal::Jog(joint) => self.last_jog == Some(joint),
                    Renewal::None => false,
                }
        });
        if let Renewal::Jog(joint) = renewal {
            self.last_jog = Some(joint);
        }
        if renews {
            if let Some(a) = self.active.as_mut() {
                a.id = id;
            }
            return None;
        }
        let preempted = self.end(Outcome::Preempted, |e| {
            Some(e.ended(EventKind::Preempted, Some(kind)))
        });
        self.active = Some(Entry {
            owner,
            id,
            kind,
            outcome: Outcome::Active,
            peak: 0.0,
            m3: 0.0,
        });
        preempted
    }

    /// This tick's joint-speed peak and metric-3 increment, on the active command's account.
    pub fn account(&mut self, peak_joint_speed_rad_s: f64, m3_rad2: f64) {
        if let Some(a) = self.active.as_mut() {
            a.peak = a.peak.max(peak_joint_speed_rad_s);
            a.m3 += m3_rad2;
        }
    }

    /// The controller finished the active command.
    pub fn finish(&mut self, finish: Finish) -> Option<Ended> {
        let (outcome, kind, reason) = match finish {
            Finish::Arrived => (Outcome::Arrived, EventKind::Arrived, None),
            Finish::Saturated => (Outcome::Saturated, EventKind::Saturated, None),
            Finish::Stopped { deadman } => {
                let reason = if deadman {
                    StopReason::Deadman
                } else {
                    StopReason::Stop
                };
                (Outcome::Stopped, EventKind::Stopped, Some(reason.as_str()))
            }
        };
        self.end(outcome, |e| Some(e.ended(kind, reason)))
    }

    /// The active command ends without arriving: outcome `fault` for a fault, else `stopped`,
    /// its sender owed a `stopped` event with `reason`.
    pub fn interrupt(&mut self, reason: StopReason) -> Option<Ended> {
        let outcome = if reason == StopReason::Fault {
            Outcome::Fault
        } else {
            Outcome::Stopped
        };
        self.end(outcome, |e| {
            Some(e.ended(EventKind::Stopped, Some(reason.as_str())))
        })
    }

    /// The estop ends the active command (outcome `estop`; the estop event goes to everyone).
    pub fn estop(&mut self) {
        self.end(Outcome::Estop, |_| None);
    }

    fn end(
        &mut self,
        outcome: Outcome,
        event: impl FnOnce(&Entry) -> Option<Ended>,
    ) -> Option<Ended> {
        let mut done = self.active.take()?;
        done.outcome = outcome;
        let ended = event(&done);
        self.last = Some(done);
        ended
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use std::sync::Arc;

    use serde_json::json;

    use super::*;

    fn id(v: u64) -> Option<RequestId> {
        Some(Arc::new(json!(v)))
    }

    #[test]
    fn a_velocity_renewal_keeps_its_account_and_a_new_command_preempts_it() {
        let mut l = Ledger::new();
        assert!(l.begin(1, id(1), "velocity", Renewal::Velocity).is_none());
        l.account(0.5, 0.25);
        assert!(l.begin(1, id(2), "velocity", Renewal::Velocity).is_none());
        l.account(0.25, 0.25);
        let info = l.info().unwrap();
        assert_eq!((info.peak_joint_speed_rad_s, info.m3_rad2), (0.5, 0.5));
        assert_eq!(info.id, id(2));
        // Another client's velocity is a new command.
        let ended = l.begin(2, id(3), "velocity", Renewal::Velocity).unwrap();
        assert_eq!(ended.owner, 1);
        assert_eq!(ended.kind, EventKind::Preempted);
        assert_eq!(ended.reason, Some("velocity"));
        assert_eq!(l.info().unwrap().m3_rad2, 0.0);
    }

    #[test]
    fn a_jog_of_another_joint_is_a_new_command() {
        let mut l = Ledger::new();
        assert!(l.begin(1, id(1), "jog", Renewal::Jog(3)).is_none());
        assert!(l.begin(1, id(2), "jog", Renewal::Jog(3)).is_none());
        assert!(l.begin(1, id(3), "jog", Renewal::Jog(4)).is_some());
    }

    #[test]
    fn each_ending_names_its_outcome_and_event() {
        let mut l = Ledger::new();
        l.begin(1, id(1), "goto", Renewal::None);
        let e = l.finish(Finish::Stopped { deadman: true }).unwrap();
        assert_eq!((e.kind, e.reason), (EventKind::Stopped, Some("deadman")));
        assert_eq!(l.info().unwrap().outcome, "stopped");
        assert!(l.finish(Finish::Arrived).is_none(), "nothing active");

        l.begin(1, id(2), "path", Renewal::None);
        let e = l.interrupt(StopReason::Fault).unwrap();
        assert_eq!((e.kind, e.reason), (EventKind::Stopped, Some("fault")));
        assert_eq!(l.info().unwrap().outcome, "fault");

        l.begin(1, id(3), "goto", Renewal::None);
        l.interrupt(StopReason::Reboot);
        assert_eq!(l.info().unwrap().outcome, "stopped");

        l.begin(1, id(4), "goto", Renewal::None);
        l.estop();
        let info = l.info().unwrap();
        assert_eq!((info.kind, info.outcome), ("goto", "estop"));
    }
}
