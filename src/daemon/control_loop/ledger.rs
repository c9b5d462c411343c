//! The command ledger: the active command (the one that moves the arm), the last one that
//! ended, and how each ended. Pure: it says which event an ending owes its sender; the cycle
//! sends it with the tick and the tip.

use crate::control::Finish;
use crate::protocol::{ClientId, CmdName, CommandInfo, Outcome, RequestId, StopReason, What};
use crate::world::World;

/// What a command's ending owes its sender: the event, once the tick's tip is known.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ending {
    /// `arrived`.
    Arrived,
    /// `saturated`.
    Saturated,
    /// `preempted` by the command named.
    Preempted(CmdName),
    /// `stopped`, and why.
    Stopped(StopReason),
    /// `blocked`: the link held back (from 1) and the obstacle (its index in the world in
    /// force).
    Blocked {
        /// The link, from 1 at the base.
        link: usize,
        /// The obstacle's index in the world.
        obstacle: usize,
    },
}

impl Ending {
    /// The event, with the commanded tip at its tick; `world` (the one in force) names a
    /// blocking obstacle by its id.
    pub fn what(self, tip: [f64; 2], world: &World) -> What {
        match self {
            Ending::Blocked { link, obstacle } => What::Blocked {
                tip,
                link,
                obstacle: world
                    .obstacles()
                    .get(obstacle)
                    .map_or_else(String::new, |o| o.id.clone()),
            },
            Ending::Arrived => What::Arrived { tip },
            Ending::Saturated => What::Saturated { tip },
            Ending::Preempted(reason) => What::Preempted { tip, reason },
            Ending::Stopped(reason) => What::Stopped { tip, reason },
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
    /// The event it is owed.
    pub ending: Ending,
}

/// A command that moves the arm, and its running account.
#[derive(Debug, Clone)]
struct Entry {
    owner: ClientId,
    id: Option<RequestId>,
    kind: CmdName,
    outcome: Outcome,
    peak: f64,
    m3: f64,
}

impl Entry {
    fn ended(&self, ending: Ending) -> Ended {
        Ended {
            owner: self.owner,
            id: self.id.clone(),
            ending,
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
    /// Why the daemon itself stopped the active command ([`Ledger::stopping`]): the reason
    /// its coming to rest is told with, instead of `stop`.
    cause: Option<StopReason>,
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
                outcome: e.outcome,
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
        kind: CmdName,
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
        // A command taken (a renewal too) is what the arm does now, not the daemon's stop.
        self.cause = None;
        if renews {
            if let Some(a) = self.active.as_mut() {
                a.id = id;
            }
            return None;
        }
        let preempted = self.end(Outcome::Preempted, |e| {
            Some(e.ended(Ending::Preempted(kind)))
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
        let (outcome, ending) = match finish {
            Finish::Arrived => (Outcome::Arrived, Ending::Arrived),
            Finish::Saturated => (Outcome::Saturated, Ending::Saturated),
            Finish::Blocked { link, obstacle } => {
                (Outcome::Blocked, Ending::Blocked { link, obstacle })
            }
            Finish::Stopped { deadman: true } => {
                (Outcome::Stopped, Ending::Stopped(StopReason::Deadman))
            }
            Finish::Stopped { deadman: false } => (
                Outcome::Stopped,
                Ending::Stopped(self.cause.take().unwrap_or(StopReason::Stop)),
            ),
        };
        self.end(outcome, |e| Some(e.ended(ending)))
    }

    /// The daemon brings the active command to rest itself, for `reason`: told as the reason
    /// of the `stopped` its coming to rest ends with (until a new command begins).
    pub fn stopping(&mut self, reason: StopReason) {
        if self.active.is_some() {
            self.cause = Some(reason);
        }
    }

    /// The active command ends without arriving: outcome `fault` for a fault, else `stopped`,
    /// its sender owed a `stopped` event with `reason`.
    pub fn interrupt(&mut self, reason: StopReason) -> Option<Ended> {
        let outcome = if reason == StopReason::Fault {
            Outcome::Fault
        } else {
            Outcome::Stopped
        };
        self.end(outcome, |e| Some(e.ended(Ending::Stopped(reason))))
    }

    /// The active command ends `preempted` by `by` with none in its place yet (a `goto` whose
    /// routes are planned beside the loop begins once they are).
    pub fn preempt(&mut self, by: CmdName) -> Option<Ended> {
        self.end(Outcome::Preempted, |e| Some(e.ended(Ending::Preempted(by))))
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
        self.cause = None;
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
        assert!(l
            .begin(1, id(1), CmdName::Velocity, Renewal::Velocity)
            .is_none());
        l.account(0.5, 0.25);
        assert!(l
            .begin(1, id(2), CmdName::Velocity, Renewal::Velocity)
            .is_none());
        l.account(0.25, 0.25);
        let info = l.info().unwrap();
        assert_eq!((info.peak_joint_speed_rad_s, info.m3_rad2), (0.5, 0.5));
        assert_eq!(info.id, id(2));
        // Another client's velocity is a new command.
        let ended = l
            .begin(2, id(3), CmdName::Velocity, Renewal::Velocity)
            .unwrap();
        assert_eq!(ended.owner, 1);
        assert_eq!(ended.ending, Ending::Preempted(CmdName::Velocity));
        assert_eq!(l.info().unwrap().m3_rad2, 0.0);
    }

    #[test]
    fn a_jog_of_another_joint_is_a_new_command() {
        let mut l = Ledger::new();
        assert!(l.begin(1, id(1), CmdName::Jog, Renewal::Jog(3)).is_none());
        assert!(l.begin(1, id(2), CmdName::Jog, Renewal::Jog(3)).is_none());
        assert!(l.begin(1, id(3), CmdName::Jog, Renewal::Jog(4)).is_some());
    }

    #[test]
    fn each_ending_names_its_outcome_and_event() {
        let mut l = Ledger::new();
        l.begin(1, id(1), CmdName::Goto, Renewal::None);
        let e = l.finish(Finish::Stopped { deadman: true }).unwrap();
        assert_eq!(e.ending, Ending::Stopped(StopReason::Deadman));
        assert_eq!(l.info().unwrap().outcome, Outcome::Stopped);
        assert!(l.finish(Finish::Arrived).is_none(), "nothing active");

        l.begin(1, id(2), CmdName::Path, Renewal::None);
        let e = l.interrupt(StopReason::Fault).unwrap();
        assert_eq!(e.ending, Ending::Stopped(StopReason::Fault));
        assert_eq!(l.info().unwrap().outcome, Outcome::Fault);

        l.begin(1, id(3), CmdName::Goto, Renewal::None);
        l.interrupt(StopReason::Reboot);
        assert_eq!(l.info().unwrap().outcome, Outcome::Stopped);

        l.begin(1, id(4), CmdName::Goto, Renewal::None);
        l.estop();
        let info = l.info().unwrap();
        assert_eq!((info.kind, info.outcome), (CmdName::Goto, Outcome::Estop));
    }

    #[test]
    fn a_stop_the_daemon_made_is_told_with_its_own_reason_once() {
        let mut l = Ledger::new();
        l.begin(1, id(1), CmdName::Goto, Renewal::None);
        l.stopping(StopReason::Shutdown);
        let e = l.finish(Finish::Stopped { deadman: false }).unwrap();
        assert_eq!(e.ending, Ending::Stopped(StopReason::Shutdown));
        // The next command's stop is a client's again.
        l.begin(1, id(2), CmdName::Goto, Renewal::None);
        let e = l.finish(Finish::Stopped { deadman: false }).unwrap();
        assert_eq!(e.ending, Ending::Stopped(StopReason::Stop));
        // A command taken after the daemon's stop (a renewed velocity) is not the daemon's.
        l.begin(1, id(3), CmdName::Velocity, Renewal::Velocity);
        l.stopping(StopReason::NotClear);
        l.begin(1, id(4), CmdName::Velocity, Renewal::Velocity);
        let e = l.finish(Finish::Stopped { deadman: false }).unwrap();
        assert_eq!(e.ending, Ending::Stopped(StopReason::Stop));
        // With nothing active there is nothing to tell.
        l.stopping(StopReason::Shutdown);
        l.begin(1, id(5), CmdName::Goto, Renewal::None);
        let e = l.finish(Finish::Stopped { deadman: false }).unwrap();
        assert_eq!(e.ending, Ending::Stopped(StopReason::Stop));
    }

    #[test]
    fn a_blocked_ending_names_its_link_and_the_obstacle_by_id() {
        use crate::chain::Vec2;
        use crate::world::{Obstacle, Shape};

        let post = |id: &str, x: f64| Obstacle {
            id: id.into(),
            shape: Shape::Circle {
                center: Vec2::new(x, 0.5),
                radius_m: 0.05,
            },
        };
        let world = World::new(0.01, 0.005, vec![post("a", 0.0), post("post", 0.3)]).unwrap();
        let mut l = Ledger::new();
        l.begin(3, id(5), CmdName::Path, Renewal::None);
        let e = l
            .finish(Finish::Blocked {
                link: 4,
                obstacle: 1,
            })
            .unwrap();
        assert_eq!((e.owner, e.id.clone()), (3, id(5)));
        assert_eq!(l.info().unwrap().outcome, Outcome::Blocked);
        assert_eq!(
            e.ending.what([0.1, 0.2], &world),
            What::Blocked {
                tip: [0.1, 0.2],
                link: 4,
                obstacle: "post".into()
            }
        );
    }
}
