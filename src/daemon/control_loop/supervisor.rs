//! The arm's mode as one enum with explicit transitions, as a hardware lifecycle holds it:
//! operating, torque off, a protective stop for a fault, the estop latch; and the shut-down
//! that can come on top of any of them. Pure: the cycle asks it what is allowed and tells it
//! what happened; the bus work of each transition is the cycle's.

use crate::control::Activity;
use crate::protocol::State;

/// What the arm is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Torque on and nothing holds the arm: the controller moves it.
    Operating,
    /// Torque commanded off; the controller frozen until `torque` on.
    TorqueOff,
    /// A protective stop: the arm holds until every fault clears. `torque` is what the
    /// recovery restores.
    Fault {
        /// Whether torque is to be on.
        torque: bool,
    },
    /// The estop latch: frozen until `reset`.
    Estop {
        /// A fault holds the arm underneath the latch too.
        faulted: bool,
        /// Whether torque is on (an estop turns it off unless `on_exit = "hold"`).
        torque: bool,
    },
}

/// Why a command that would move the arm is refused now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Blocked {
    /// The estop latch is set.
    Estop,
    /// A fault holds the arm.
    Fault,
    /// Torque is off.
    TorqueOff,
}

/// The mode and the shut-down flag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Supervisor {
    mode: Mode,
    exiting: bool,
}

impl Default for Supervisor {
    fn default() -> Self {
        Self::new()
    }
}

impl Supervisor {
    /// Brought up: torque on, holding.
    pub fn new() -> Self {
        Self {
            mode: Mode::Operating,
            exiting: false,
        }
    }

    /// The mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The estop latch is set.
    pub fn estopped(&self) -> bool {
        matches!(self.mode, Mode::Estop { .. })
    }

    /// A fault holds the arm (under the latch or not).
    pub fn faulted(&self) -> bool {
        matches!(
            self.mode,
            Mode::Fault { .. } | Mode::Estop { faulted: true, .. }
        )
    }

    /// Torque is (to be) on.
    pub fn torque(&self) -> bool {
        match self.mode {
            Mode::Operating => true,
            Mode::TorqueOff => false,
            Mode::Fault { torque } | Mode::Estop { torque, .. } => torque,
        }
    }

    /// The controller may move the arm this tick.
    pub fn moves(&self) -> bool {
        !self.estopped() && !self.faulted()
    }

    /// Why motion is refused, in the order a client should learn it.
    pub fn blocked(&self) -> Option<Blocked> {
        match self.mode {
            Mode::Estop { .. } => Some(Blocked::Estop),
            Mode::Fault { .. } => Some(Blocked::Fault),
            Mode::TorqueOff => Some(Blocked::TorqueOff),
            Mode::Operating => None,
        }
    }

    /// The daemon is shutting down.
    pub fn exiting(&self) -> bool {
        self.exiting
    }

    /// The shut-down began: from now on only `status`, `stop` and `estop` are taken.
    pub fn begin_exit(&mut self) {
        self.exiting = true;
    }

    /// The state clients see, with the controller's `activity` when nothing holds the arm.
    pub fn state(&self, activity: Activity) -> State {
        match self.mode {
            Mode::Estop { .. } => State::Estop,
            Mode::Fault { .. } => State::Fault,
            Mode::TorqueOff => State::TorqueOff,
            Mode::Operating => match activity {
                Activity::Moving => State::Moving,
                Activity::Holding => State::Holding,
                Activity::Stopping => State::Stopping,
            },
        }
    }

    /// Whether any fault holds, as the health and the port say now. True when this enters the
    /// protective stop (the cycle then freezes the arm and ends the active command).
    pub fn set_faulted(&mut self, faulted: bool) -> bool {
        let before = self.faulted();
        self.mode = match (self.mode, faulted) {
            (Mode::Operating, true) => Mode::Fault { torque: true },
            (Mode::TorqueOff, true) => Mode::Fault { torque: false },
            (Mode::Fault { torque }, false) => {
                if torque {
                    Mode::Operating
                } else {
                    Mode::TorqueOff
                }
            }
            (Mode::Estop { torque, .. }, faulted) => Mode::Estop { faulted, torque },
            (mode, _) => mode,
        };
        faulted && !before
    }

    /// The estop latch set; `torque_off` when it also switched the torque off.
    pub fn estop(&mut self, torque_off: bool) {
        self.mode = Mode::Estop {
            faulted: self.faulted(),
            torque: self.torque() && !torque_off,
        };
    }

    /// `reset` succeeded (the latch is released, torque on, holding the measured pose).
    pub fn reset(&mut self) {
        if let Mode::Estop { faulted, .. } = self.mode {
            self.mode = if faulted {
                Mode::Fault { torque: true }
            } else {
                Mode::Operating
            };
        }
    }

    /// Torque switched on or off by command (refused on under the latch or a fault, which the
    /// cycle checks first through [`Supervisor::blocked`]).
    pub fn set_torque(&mut self, on: bool) {
        self.mode = match (self.mode, on) {
            (Mode::Operating | Mode::TorqueOff, true) => Mode::Operating,
            (Mode::Operating | Mode::TorqueOff, false) => Mode::TorqueOff,
            (Mode::Fault { .. }, torque) => Mode::Fault { torque },
            (Mode::Estop { faulted, .. }, torque) => Mode::Estop { faulted, torque },
        };
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn a_fault_holds_and_its_clearing_restores_the_torque_it_found() {
        let mut s = Supervisor::new();
        s.set_torque(false);
        assert!(s.set_faulted(true), "entering the protective stop");
        assert!(!s.set_faulted(true), "already in it");
        assert_eq!(s.mode(), Mode::Fault { torque: false });
        assert!(!s.moves());
        assert_eq!(s.blocked(), Some(Blocked::Fault));
        s.set_faulted(false);
        assert_eq!(s.mode(), Mode::TorqueOff);
        assert_eq!(s.state(Activity::Holding), State::TorqueOff);
        assert_eq!(s.blocked(), Some(Blocked::TorqueOff));
        s.set_torque(true);
        assert_eq!(s.mode(), Mode::Operating);
        assert_eq!(s.blocked(), None);
    }

    #[test]
    fn the_estop_latch_outranks_a_fault_and_reset_returns_to_it() {
        let mut s = Supervisor::new();
        s.set_faulted(true);
        s.estop(true);
        assert_eq!(s.state(Activity::Holding), State::Estop);
        assert_eq!(s.blocked(), Some(Blocked::Estop));
        assert!(!s.torque());
        // The fault clears under the latch: still latched.
        s.set_faulted(false);
        assert_eq!(
            s.mode(),
            Mode::Estop {
                faulted: false,
                torque: false
            }
        );
        s.set_faulted(true);
        s.reset();
        assert_eq!(s.mode(), Mode::Fault { torque: true });
        assert_eq!(s.state(Activity::Moving), State::Fault);
        s.set_faulted(false);
        assert_eq!(s.state(Activity::Moving), State::Moving);
    }

    #[test]
    fn an_estop_that_holds_keeps_the_torque_on() {
        let mut s = Supervisor::new();
        s.estop(false);
        assert!(s.torque() && s.estopped() && !s.moves());
        s.reset();
        assert_eq!(s.mode(), Mode::Operating);
    }

    #[test]
    fn the_shut_down_comes_on_top_of_any_mode() {
        let mut s = Supervisor::new();
        s.estop(true);
        s.begin_exit();
        assert!(s.exiting() && s.estopped());
    }
}
