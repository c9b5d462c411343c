//! Who may command the arm: one controller at a time, decided on the socket side before a
//! command reaches the loop.
//!
//! A controller is an id ([`ControllerId`]), not a connection: the server numbers its clients,
//! and any other source of commands (a bridge to another transport) takes an id from the same
//! space and goes through the same [`Arbiter`].
//!
//! - Motion and configuration ([`Need::Control`]) need control, and take it when nobody holds
//!   it; from anyone else they are refused `not_in_control`.
//! - Stopping ([`Need::Stop`]: `stop`, `estop`) is never refused.
//! - Reading and the session's own commands ([`Need::Nothing`]) need nothing.
//!
//! `take_control` takes control from whoever holds it; `release`, or the holder leaving, frees
//! it. Every change is a [`Change`], announced to every client as a `control` event
//! ([`Change::event`]).

use std::sync::Arc;

use serde_json::Value;

pub use crate::protocol::Need;
use crate::protocol::{event_line, ClientId, CmdName, Code, Event, Rejection, What};

/// Who would command the arm: a client of the server, or any other source given an id from the
/// same space.
pub type ControllerId = ClientId;

/// Who holds control after a change, and who held it before.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Change {
    /// The new holder; `None` when control is free.
    pub holder: Option<ControllerId>,
    /// The holder before.
    pub previous: Option<ControllerId>,
}

/// The one controller, if any. Pure: the caller announces the [`Change`]s it returns.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Arbiter {
    holder: Option<ControllerId>,
}

impl Arbiter {
    /// Nobody in control.
    pub const fn new() -> Self {
        Arbiter { holder: None }
    }

    /// Who holds control.
    pub fn holder(&self) -> Option<ControllerId> {
        self.holder
    }

    /// Whether `who` may send `cmd` (a command, or its name). A command that needs control
    /// takes it when nobody holds it (the change is returned); from anyone but the holder it is
    /// refused `not_in_control`, the message naming the holder.
    pub fn admit(
        &mut self,
        who: ControllerId,
        cmd: impl Into<CmdName>,
    ) -> Result<Option<Change>, Rejection> {
        let cmd = cmd.into();
        if cmd.need() != Need::Control {
            return Ok(None);
        }
        match self.holder {
            Some(holder) if holder == who => Ok(None),
            Some(holder) => Err(Rejection::new(
                Code::NotInControl,
                format!(
                    "`{cmd}` needs control, which client {holder} holds; send `take_control` to \
                     take it"
                ),
            )),
            None => Ok(self.take(who)),
        }
    }

    /// `who` takes control, from whoever holds it. `None` when `who` already held it.
    pub fn take(&mut self, who: ControllerId) -> Option<Change> {
        let previous = self.holder.replace(who);
        (previous != Some(who)).then_some(Change {
            holder: Some(who),
            previous,
        })
    }

    /// `who` lets go of control (by `release`, or by leaving). `None` when `who` did not hold
    /// it, and nothing changes.
    pub fn release(&mut self, who: ControllerId) -> Option<Change> {
        if self.holder != Some(who) {
            return None;
        }
        self.holder = None;
        Some(Change {
            holder: None,
            previous: Some(who),
        })
    }
}

impl Change {
    /// The `control` event announcing it: `cmd_id` the request that made the change (none
    /// when a disconnect did), `tick` the latest published tick.
    pub fn event(&self, cmd_id: Option<Arc<Value>>, tick: u64) -> Event {
        Event {
            owner: None,
            cmd_id,
            tick,
            what: What::Control {
                holder: self.holder,
                previous: self.previous,
            },
        }
    }
}

/// The `control` event line announcing `change`: `{"type": "event", "event": "control",
/// "holder": ID|null, "previous": ID|null, "cmd_id": ID?, "tick": N}` ([`Change::event`],
/// written as every event line is).
pub fn control_line(change: &Change, cmd_id: Option<&Value>, tick: u64) -> String {
    event_line(&change.event(cmd_id.cloned().map(Arc::new), tick))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use serde_json::json;

    use super::*;
    use crate::protocol::Cmd;

    fn goto() -> Cmd {
        Cmd::Goto {
            target: [0.1, 0.2],
            speed: None,
        }
    }

    #[test]
    fn the_first_motion_takes_free_control_and_others_are_refused_naming_the_holder() {
        let mut a = Arbiter::new();
        assert_eq!(
            a.admit(3, &goto()).unwrap(),
            Some(Change {
                holder: Some(3),
                previous: None
            })
        );
        assert_eq!(a.holder(), Some(3));
        assert_eq!(a.admit(3, &Cmd::Home).unwrap(), None, "the holder goes on");
        let why = a.admit(4, &Cmd::Torque { on: false }).unwrap_err();
        assert_eq!(why.code, Code::NotInControl);
        assert!(why.message.contains("client 3"), "{why}");
        assert!(why.message.contains("take_control"), "{why}");
        assert!(why.message.contains("`torque`"), "{why}");
        assert_eq!(a.holder(), Some(3), "a refusal changes nothing");
    }

    #[test]
    fn stopping_and_reading_are_never_refused_and_take_nothing() {
        let mut a = Arbiter::new();
        for cmd in [
            Cmd::Stop,
            Cmd::Estop,
            Cmd::Status,
            Cmd::Describe,
            Cmd::ResetStats,
            Cmd::Unsubscribe,
        ] {
            assert_eq!(a.admit(1, &cmd).unwrap(), None, "{cmd:?}");
        }
        assert_eq!(a.holder(), None);
        a.take(9);
        for cmd in [Cmd::Stop, Cmd::Estop, Cmd::Status] {
            assert_eq!(a.admit(1, &cmd).unwrap(), None, "{cmd:?}");
        }
        assert_eq!(a.holder(), Some(9));
    }

    #[test]
    fn every_command_needs_what_the_table_says() {
        let control = [
            goto(),
            Cmd::GotoJoints { theta: vec![0.0] },
            Cmd::Reach { target: [0.1, 0.2] },
            Cmd::Path {
                points: vec![[0.0, 0.0]],
                speed: None,
            },
            Cmd::Velocity { v: [0.0, 0.0] },
            Cmd::Jog {
                joint: 1,
                rad_s: 0.1,
            },
            Cmd::Home,
            Cmd::Strategy {
                name: crate::resolve::Strategy::Sequential,
            },
            Cmd::Reset,
            Cmd::Torque { on: true },
            Cmd::Reboot { ids: None },
            Cmd::SetWorld {
                obstacles: crate::world::Obstacles::default(),
            },
            Cmd::AddObstacle {
                obstacle: crate::world::CheckedObstacle::new(crate::world::Obstacle {
                    id: "post".into(),
                    shape: crate::world::Shape::Circle {
                        center: crate::chain::Vec2::new(1.0, 1.0),
                        radius_m: 0.1,
                    },
                })
                .unwrap(),
            },
            Cmd::RemoveObstacle { id: "post".into() },
        ];
        let nothing = [
            Cmd::Describe,
            Cmd::Status,
            Cmd::Subscribe { rate_hz: 1.0 },
            Cmd::Unsubscribe,
            Cmd::ResetStats,
            Cmd::TakeControl,
            Cmd::Release,
            Cmd::Auth { token: "t".into() },
            Cmd::World,
        ];
        for cmd in &control {
            assert_eq!(Need::of(cmd), Need::Control, "{cmd:?}");
        }
        for cmd in &nothing {
            assert_eq!(Need::of(cmd), Need::Nothing, "{cmd:?}");
        }
        assert_eq!(Need::of(&Cmd::Stop), Need::Stop);
        assert_eq!(Need::of(&Cmd::Estop), Need::Stop);
        assert_eq!(
            control.len() + nothing.len() + 2,
            crate::protocol::COMMANDS.len()
        );
    }

    #[test]
    fn take_control_takes_it_from_the_holder_and_release_frees_it() {
        let mut a = Arbiter::new();
        assert_eq!(
            a.take(1),
            Some(Change {
                holder: Some(1),
                previous: None
            })
        );
        assert_eq!(a.take(1), None, "taking what one holds changes nothing");
        assert_eq!(
            a.take(2),
            Some(Change {
                holder: Some(2),
                previous: Some(1)
            })
        );
        assert_eq!(a.admit(1, &goto()).unwrap_err().code, Code::NotInControl);
        assert_eq!(a.release(1), None, "only the holder releases");
        assert_eq!(a.holder(), Some(2));
        assert_eq!(
            a.release(2),
            Some(Change {
                holder: None,
                previous: Some(2)
            })
        );
        assert_eq!(a.release(2), None);
        assert!(a.admit(1, &goto()).unwrap().is_some(), "free again");
    }

    #[test]
    fn the_control_line_names_holder_previous_and_the_request() {
        let change = Change {
            holder: Some(4),
            previous: Some(2),
        };
        let line = control_line(&change, Some(&json!("t1")), 120);
        assert!(line.ends_with('\n') && line.matches('\n').count() == 1);
        assert_eq!(
            serde_json::from_str::<Value>(&line).unwrap(),
            json!({"type": "event", "event": "control", "holder": 4, "previous": 2,
                   "cmd_id": "t1", "tick": 120})
        );
        let freed = Change {
            holder: None,
            previous: Some(4),
        };
        assert_eq!(
            serde_json::from_str::<Value>(&control_line(&freed, None, 7)).unwrap(),
            json!({"type": "event", "event": "control", "holder": null, "previous": 4,
                   "tick": 7})
        );
    }
}
