//! Requests and where each goes: the command ([`Cmd`]), its name ([`CmdName`], the one table
//! of names), what it needs from the arbiter ([`Need`]) and where it is answered ([`Route`]).
//!
//! Every match over commands here is exhaustive, with no catch-all: a new [`Cmd`] variant does
//! not compile until it has a name, a need and a route, and (in `parse` and `write`) is read and
//! written; a new [`LoopCmd`] or [`Motion`] until the loop applies it.

use std::fmt;

use serde::{Deserialize, Serialize};

use super::RequestId;
use crate::resolve::Strategy;
use crate::world::{CheckedObstacle, Obstacles};

/// Declares [`CmdName`], its table [`CmdName::ALL`] and [`COMMANDS`] from one list, so that
/// the enum, the names it is written as and the names it is read from cannot disagree.
macro_rules! command_names {
    ($($(#[$doc:meta])* $variant:ident = $name:literal,)+) => {
        /// A command's name, as the `cmd` of a request says it (and as telemetry's `command.kind`
        /// and a `preempted` event's `reason` name a command).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
        pub enum CmdName {
            $($(#[$doc])* #[serde(rename = $name)] $variant,)+
        }

        impl CmdName {
            /// Every name, in the order an `unknown_cmd` message lists them.
            pub const ALL: [CmdName; COMMAND_COUNT] = [$(CmdName::$variant,)+];

            /// The name as a request writes it.
            pub const fn as_str(self) -> &'static str {
                match self {
                    $(CmdName::$variant => $name,)+
                }
            }
        }

        /// How many commands there are.
        const COMMAND_COUNT: usize = [$($name,)+].len();

        /// Every command name as a request writes it, in the order of [`CmdName::ALL`].
        pub const COMMANDS: [&str; COMMAND_COUNT] = [$($name,)+];
    };
}

command_names! {
    /// `describe`.
    Describe = "describe",
    /// `status`.
    Status = "status",
    /// `goto`.
    Goto = "goto",
    /// `goto_joints`.
    GotoJoints = "goto_joints",
    /// `reach`.
    Reach = "reach",
    /// `path`.
    Path = "path",
    /// `velocity`.
    Velocity = "velocity",
    /// `jog`.
    Jog = "jog",
    /// `stop`.
    Stop = "stop",
    /// `estop`.
    Estop = "estop",
    /// `reset`.
    Reset = "reset",
    /// `home`.
    Home = "home",
    /// `strategy`.
    Strategy = "strategy",
    /// `subscribe`.
    Subscribe = "subscribe",
    /// `unsubscribe`.
    Unsubscribe = "unsubscribe",
    /// `reset_stats`.
    ResetStats = "reset_stats",
    /// `take_control`.
    TakeControl = "take_control",
    /// `release`.
    Release = "release",
    /// `auth`.
    Auth = "auth",
    /// `torque`.
    Torque = "torque",
    /// `reboot`.
    Reboot = "reboot",
    /// `world`.
    World = "world",
    /// `set_world`.
    SetWorld = "set_world",
    /// `add_obstacle`.
    AddObstacle = "add_obstacle",
    /// `remove_obstacle`.
    RemoveObstacle = "remove_obstacle",
}

impl CmdName {
    /// The command a request's `cmd` names; `None` for a name this version does not know.
    pub fn from_name(name: &str) -> Option<CmdName> {
        CmdName::ALL.into_iter().find(|n| n.as_str() == name)
    }

    /// What a command of this name needs from the arbiter.
    pub const fn need(self) -> Need {
        match self {
            CmdName::Goto
            | CmdName::GotoJoints
            | CmdName::Reach
            | CmdName::Path
            | CmdName::Velocity
            | CmdName::Jog
            | CmdName::Home
            | CmdName::Strategy
            | CmdName::Reset
            | CmdName::Torque
            | CmdName::Reboot
            | CmdName::SetWorld
            | CmdName::AddObstacle
            | CmdName::RemoveObstacle => Need::Control,
            CmdName::Stop | CmdName::Estop => Need::Stop,
            CmdName::Describe
            | CmdName::Status
            | CmdName::Subscribe
            | CmdName::Unsubscribe
            | CmdName::ResetStats
            | CmdName::TakeControl
            | CmdName::Release
            | CmdName::Auth
            | CmdName::World => Need::Nothing,
        }
    }
}

impl fmt::Display for CmdName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl PartialEq<str> for CmdName {
    fn eq(&self, other: &str) -> bool {
        self.as_str() == other
    }
}

impl PartialEq<&str> for CmdName {
    fn eq(&self, other: &&str) -> bool {
        self.as_str() == *other
    }
}

/// What a command needs from the arbiter (who may send it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Need {
    /// Control: refused `not_in_control` to anyone but the holder; takes control when free.
    Control,
    /// Nothing, ever: stopping is never refused.
    Stop,
    /// Nothing: it reads, or manages the session.
    Nothing,
}

impl Need {
    /// What `cmd` needs.
    pub fn of(cmd: &Cmd) -> Need {
        cmd.need()
    }
}

/// What a client asks for: the `cmd` of a request line with its arguments, validated (finite,
/// within [`MAX_ARG`](super::MAX_ARG), lengths and joint numbers checked against the arm).
#[derive(Debug, Clone, PartialEq)]
pub enum Cmd {
    /// The arm's geometry and the daemon's capabilities.
    Describe,
    /// The latest telemetry, as a reply.
    Status,
    /// Tip along a straight line to `target`, m, at `speed` m/s (default: the tip speed limit).
    Goto {
        /// Target tip position, m.
        target: [f64; 2],
        /// Tip speed, m/s.
        speed: Option<f64>,
    },
    /// A joint-space move to `theta`, rad.
    GotoJoints {
        /// Target pose, one angle per joint, rad.
        theta: Vec<f64>,
    },
    /// The tip to `target` by a clear way in joint space, planned round the obstacles.
    Reach {
        /// Target tip position, m.
        target: [f64; 2],
    },
    /// Tip along a polyline, stopping at each corner.
    Path {
        /// Corner points, m.
        points: Vec<[f64; 2]>,
        /// Tip speed, m/s.
        speed: Option<f64>,
    },
    /// A tip velocity, m/s, that lapses after the deadman unless renewed.
    Velocity {
        /// Tip velocity, m/s.
        v: [f64; 2],
    },
    /// One joint at a rate, rad/s, with the same deadman.
    Jog {
        /// Joint number, from 1.
        joint: usize,
        /// Joint rate, rad/s.
        rad_s: f64,
    },
    /// Decelerate to rest and hold.
    Stop,
    /// Freeze and torque off (or hold), latched until `reset`.
    Estop,
    /// Leave estop: goal := measured pose, torque on, holding.
    Reset,
    /// A joint-space move to the configured home pose.
    Home,
    /// Switch the redundancy-resolution strategy.
    Strategy {
        /// The new strategy.
        name: Strategy,
    },
    /// Telemetry lines at `rate_hz` (at most the loop rate).
    Subscribe {
        /// Lines per second.
        rate_hz: f64,
    },
    /// No more telemetry lines.
    Unsubscribe,
    /// Zero the statistics kept since start (peak joint speed, metric 3 travelled, tick times).
    ResetStats,
    /// Become the client in control (the holder is told with a `control` event).
    TakeControl,
    /// Stop being the client in control.
    Release,
    /// The first line of a client when `[server] token_file` is set.
    Auth {
        /// The token, compared in constant time.
        token: String,
    },
    /// Torque on (goal := measured pose first) or off for every servo.
    Torque {
        /// On or off.
        on: bool,
    },
    /// Reboot servos (all when `ids` is absent) to clear a hardware error, then recover.
    Reboot {
        /// Servo ids.
        ids: Option<Vec<u8>>,
    },
    /// The obstacles the arm keeps clear of, with the link radius and the clearance.
    World,
    /// Replace every obstacle (the link radius and the clearance stay as configured).
    SetWorld {
        /// The new obstacles, each shape checked, and their ids and number.
        obstacles: Obstacles,
    },
    /// Add one obstacle.
    AddObstacle {
        /// The obstacle, its shape and id checked.
        obstacle: CheckedObstacle,
    },
    /// Remove the obstacle of this id (the request's `obstacle`).
    RemoveObstacle {
        /// Its id.
        id: String,
    },
}

impl Cmd {
    /// The name a request uses for it.
    pub fn name(&self) -> CmdName {
        match self {
            Cmd::Describe => CmdName::Describe,
            Cmd::Status => CmdName::Status,
            Cmd::Goto { .. } => CmdName::Goto,
            Cmd::GotoJoints { .. } => CmdName::GotoJoints,
            Cmd::Reach { .. } => CmdName::Reach,
            Cmd::Path { .. } => CmdName::Path,
            Cmd::Velocity { .. } => CmdName::Velocity,
            Cmd::Jog { .. } => CmdName::Jog,
            Cmd::Stop => CmdName::Stop,
            Cmd::Estop => CmdName::Estop,
            Cmd::Reset => CmdName::Reset,
            Cmd::Home => CmdName::Home,
            Cmd::Strategy { .. } => CmdName::Strategy,
            Cmd::Subscribe { .. } => CmdName::Subscribe,
            Cmd::Unsubscribe => CmdName::Unsubscribe,
            Cmd::ResetStats => CmdName::ResetStats,
            Cmd::TakeControl => CmdName::TakeControl,
            Cmd::Release => CmdName::Release,
            Cmd::Auth { .. } => CmdName::Auth,
            Cmd::Torque { .. } => CmdName::Torque,
            Cmd::Reboot { .. } => CmdName::Reboot,
            Cmd::World => CmdName::World,
            Cmd::SetWorld { .. } => CmdName::SetWorld,
            Cmd::AddObstacle { .. } => CmdName::AddObstacle,
            Cmd::RemoveObstacle { .. } => CmdName::RemoveObstacle,
        }
    }

    /// What it needs from the arbiter.
    pub fn need(&self) -> Need {
        self.name().need()
    }

    /// Where it is answered: by the socket side itself, or by the loop.
    pub fn route(self) -> Route {
        match self {
            Cmd::Describe => Route::Session(SessionCmd::Describe),
            Cmd::Subscribe { rate_hz } => Route::Session(SessionCmd::Subscribe { rate_hz }),
            Cmd::Unsubscribe => Route::Session(SessionCmd::Unsubscribe),
            Cmd::TakeControl => Route::Session(SessionCmd::TakeControl),
            Cmd::Release => Route::Session(SessionCmd::Release),
            Cmd::Auth { token } => Route::Session(SessionCmd::Auth { token }),
            Cmd::Status => Route::Loop(LoopCmd::Status),
            Cmd::Stop => Route::Loop(LoopCmd::Stop),
            Cmd::Estop => Route::Loop(LoopCmd::Estop),
            Cmd::Reset => Route::Loop(LoopCmd::Reset),
            Cmd::Strategy { name } => Route::Loop(LoopCmd::Strategy { name }),
            Cmd::ResetStats => Route::Loop(LoopCmd::ResetStats),
            Cmd::Torque { on } => Route::Loop(LoopCmd::Torque { on }),
            Cmd::Reboot { ids } => Route::Loop(LoopCmd::Reboot { ids }),
            Cmd::World => Route::Loop(LoopCmd::World),
            Cmd::SetWorld { obstacles } => Route::Loop(LoopCmd::SetWorld { obstacles }),
            Cmd::AddObstacle { obstacle } => Route::Loop(LoopCmd::AddObstacle { obstacle }),
            Cmd::RemoveObstacle { id } => Route::Loop(LoopCmd::RemoveObstacle { id }),
            Cmd::Goto { target, speed } => {
                Route::Loop(LoopCmd::Motion(Motion::Goto { target, speed }))
            }
            Cmd::GotoJoints { theta } => Route::Loop(LoopCmd::Motion(Motion::GotoJoints { theta })),
            Cmd::Reach { target } => Route::Loop(LoopCmd::Motion(Motion::Reach { target })),
            Cmd::Path { points, speed } => {
                Route::Loop(LoopCmd::Motion(Motion::Path { points, speed }))
            }
            Cmd::Velocity { v } => Route::Loop(LoopCmd::Motion(Motion::Velocity { v })),
            Cmd::Jog { joint, rad_s } => Route::Loop(LoopCmd::Motion(Motion::Jog { joint, rad_s })),
            Cmd::Home => Route::Loop(LoopCmd::Motion(Motion::Home)),
        }
    }
}

impl From<&Cmd> for CmdName {
    fn from(cmd: &Cmd) -> CmdName {
        cmd.name()
    }
}

/// Where a command is answered.
#[derive(Debug, Clone, PartialEq)]
pub enum Route {
    /// By the socket side, for the client's own session: the loop never sees it.
    Session(SessionCmd),
    /// By the loop, through the bounded command queue.
    Loop(LoopCmd),
}

/// A command the socket side answers itself.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionCmd {
    /// `describe`.
    Describe,
    /// `subscribe`.
    Subscribe {
        /// Lines per second asked for.
        rate_hz: f64,
    },
    /// `unsubscribe`.
    Unsubscribe,
    /// `take_control`.
    TakeControl,
    /// `release`.
    Release,
    /// `auth`.
    Auth {
        /// The token.
        token: String,
    },
}

impl SessionCmd {
    /// The name a request uses for it.
    pub fn name(&self) -> CmdName {
        match self {
            SessionCmd::Describe => CmdName::Describe,
            SessionCmd::Subscribe { .. } => CmdName::Subscribe,
            SessionCmd::Unsubscribe => CmdName::Unsubscribe,
            SessionCmd::TakeControl => CmdName::TakeControl,
            SessionCmd::Release => CmdName::Release,
            SessionCmd::Auth { .. } => CmdName::Auth,
        }
    }
}

/// A command the loop applies, in the tick that takes it from the queue.
#[derive(Debug, Clone, PartialEq)]
pub enum LoopCmd {
    /// `status`: the telemetry of the tick that applied it.
    Status,
    /// `stop`.
    Stop,
    /// `estop`.
    Estop,
    /// `reset`.
    Reset,
    /// `strategy`.
    Strategy {
        /// The new strategy.
        name: Strategy,
    },
    /// `reset_stats`.
    ResetStats,
    /// `torque`.
    Torque {
        /// On or off.
        on: bool,
    },
    /// `reboot`.
    Reboot {
        /// Servo ids (`None`: those in hardware error, else all).
        ids: Option<Vec<u8>>,
    },
    /// `world`: the world in force.
    World,
    /// `set_world`.
    SetWorld {
        /// The new obstacles, checked where the request was read: the loop only asks whether
        /// the arm's base keeps clear of them.
        obstacles: Obstacles,
    },
    /// `add_obstacle`.
    AddObstacle {
        /// The obstacle, its shape checked where the request was read: the loop asks whether
        /// the world has room for it and its id is free.
        obstacle: CheckedObstacle,
    },
    /// `remove_obstacle`.
    RemoveObstacle {
        /// Its id.
        id: String,
    },
    /// A command that moves the arm.
    Motion(Motion),
}

impl LoopCmd {
    /// The name a request uses for it.
    pub fn name(&self) -> CmdName {
        match self {
            LoopCmd::Status => CmdName::Status,
            LoopCmd::Stop => CmdName::Stop,
            LoopCmd::Estop => CmdName::Estop,
            LoopCmd::Reset => CmdName::Reset,
            LoopCmd::Strategy { .. } => CmdName::Strategy,
            LoopCmd::ResetStats => CmdName::ResetStats,
            LoopCmd::Torque { .. } => CmdName::Torque,
            LoopCmd::Reboot { .. } => CmdName::Reboot,
            LoopCmd::World => CmdName::World,
            LoopCmd::SetWorld { .. } => CmdName::SetWorld,
            LoopCmd::AddObstacle { .. } => CmdName::AddObstacle,
            LoopCmd::RemoveObstacle { .. } => CmdName::RemoveObstacle,
            LoopCmd::Motion(motion) => motion.name(),
        }
    }
}

impl From<&LoopCmd> for CmdName {
    fn from(cmd: &LoopCmd) -> CmdName {
        cmd.name()
    }
}

impl From<LoopCmd> for Cmd {
    fn from(cmd: LoopCmd) -> Cmd {
        match cmd {
            LoopCmd::Status => Cmd::Status,
            LoopCmd::Stop => Cmd::Stop,
            LoopCmd::Estop => Cmd::Estop,
            LoopCmd::Reset => Cmd::Reset,
            LoopCmd::Strategy { name } => Cmd::Strategy { name },
            LoopCmd::ResetStats => Cmd::ResetStats,
            LoopCmd::Torque { on } => Cmd::Torque { on },
            LoopCmd::Reboot { ids } => Cmd::Reboot { ids },
            LoopCmd::World => Cmd::World,
            LoopCmd::SetWorld { obstacles } => Cmd::SetWorld { obstacles },
            LoopCmd::AddObstacle { obstacle } => Cmd::AddObstacle { obstacle },
            LoopCmd::RemoveObstacle { id } => Cmd::RemoveObstacle { id },
            LoopCmd::Motion(motion) => motion.into(),
        }
    }
}

/// A command that moves the arm: the loop hands it to the controller, and it is the active
/// command until it ends (arrives, saturates, is preempted, stopped or estopped).
#[derive(Debug, Clone, PartialEq)]
pub enum Motion {
    /// `goto`.
    Goto {
        /// Target tip position, m.
        target: [f64; 2],
        /// Tip speed, m/s.
        speed: Option<f64>,
    },
    /// `goto_joints`.
    GotoJoints {
        /// Target pose, rad.
        theta: Vec<f64>,
    },
    /// `reach`.
    Reach {
        /// Target tip position, m.
        target: [f64; 2],
    },
    /// `path`.
    Path {
        /// Corner points, m.
        points: Vec<[f64; 2]>,
        /// Tip speed, m/s.
        speed: Option<f64>,
    },
    /// `velocity`.
    Velocity {
        /// Tip velocity, m/s.
        v: [f64; 2],
    },
    /// `jog`.
    Jog {
        /// Joint number, from 1.
        joint: usize,
        /// Joint rate, rad/s.
        rad_s: f64,
    },
    /// `home`.
    Home,
}

impl Motion {
    /// The name a request uses for it.
    pub fn name(&self) -> CmdName {
        match self {
            Motion::Goto { .. } => CmdName::Goto,
            Motion::GotoJoints { .. } => CmdName::GotoJoints,
            Motion::Reach { .. } => CmdName::Reach,
            Motion::Path { .. } => CmdName::Path,
            Motion::Velocity { .. } => CmdName::Velocity,
            Motion::Jog { .. } => CmdName::Jog,
            Motion::Home => CmdName::Home,
        }
    }
}

impl From<Motion> for Cmd {
    fn from(motion: Motion) -> Cmd {
        match motion {
            Motion::Goto { target, speed } => Cmd::Goto { target, speed },
            Motion::GotoJoints { theta } => Cmd::GotoJoints { theta },
            Motion::Reach { target } => Cmd::Reach { target },
            Motion::Path { points, speed } => Cmd::Path { points, speed },
            Motion::Velocity { v } => Cmd::Velocity { v },
            Motion::Jog { joint, rad_s } => Cmd::Jog { joint, rad_s },
            Motion::Home => Cmd::Home,
        }
    }
}

/// A request line, read and validated.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    /// The request's `id`, echoed in its reply; `None` when absent or `null`.
    pub id: Option<RequestId>,
    /// What it asks for.
    pub cmd: Cmd,
}
