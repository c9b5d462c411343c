//! # snakectl
//!
//! Controller and simulator for planar hyper-redundant "snake arms" and free flexible objects
//! (ropes, chains, hair), after Banerjee, Menon, Ananthasuresh and Ghosal, "Simulation of
//! Length-Preserving Motions of Flexible One Dimensional Objects using Optimization" (2011).
//!
//! Layout, lowest layer first (a layer uses only those above it in this list):
//! - [`chain`]: links, base pose, relative angles, limits; forward kinematics, Jacobian,
//!   workspace ring. Pure math.
//! - [`metrics`]: the paper's five motion metrics between two configurations. Pure math.
//! - [`resolve`]: the two redundancy-resolution strategies (sequential tractrix, overall
//!   minimization of metric 3) behind one [`resolve::Resolver`] trait. Pure math.
//! - [`motion`]: the tip (or joint) reference of each control tick from the active command,
//!   speed- and acceleration-limited. Pure math, time as `dt`.
//! - [`control`]: one control tick: motion, resolve (warm, the active strategy, bisection when
//!   out of reach), joint-speed limit; the goal pose and what happened. Pure math.
//! - [`config`]: the one TOML file that describes an arm and how to reach it, parsed raw and then
//!   validated, errors naming the file and the field.
//! - [`problem`]: the JSON problem format of `snakectl solve`: parsing, validation, the answer.
//! - [`servo`]: the `ServoBus` trait, its Dynamixel implementation, the model table, units and
//!   calibration, the joint-limit wrapper, bring-up and shut-down, the one-time servo settings,
//!   a recording bus, serial-port discovery in sysfs.
//! - [`scenario`]: flexible-object scenarios (TOML): initial curve, pull, strategies; runs them
//!   and tabulates the metrics.
//! - [`plot`]: the scenario figures as SVG and PNG.
//! - [`connect`]: the one way from a config to a running bus: the simulator spawned on a
//!   pseudo-terminal, or a serial port, opened, limited, with the arm it drives.
//! - [`protocol`]: the daemon's JSON-lines wire format: requests, replies, error codes,
//!   telemetry, events, each written and read by the same type, shared by the daemon and its
//!   clients; and where each command goes (who may send it, the socket side or the loop).
//! - [`ros`]: the ROS 2 messages the arm speaks on a Zenoh network (`JointState`,
//!   `PointStamped`, `Twist`, ...) and their CDR encoding; built from telemetry, time passed in.
//! - [`daemon`]: `snakectl run`: the fixed-rate loop on its own thread, the socket server on
//!   tokio, the bounded seam between them.
//! - [`client`]: a blocking client of the daemon's socket (requests, typed replies, events, the
//!   latest telemetry, a motion command run to its end; the arm drawn by its chain), for the
//!   one-shot commands, teleop and the demo.
//! - [`teleop`]: the teleop terminal UI: pure input logic (keyboard hold-to-move, joystick),
//!   the joystick device reader, the drawing.

pub mod chain;
pub mod client;
pub mod config;
pub mod connect;
pub mod control;
pub mod daemon;
pub mod metrics;
pub mod motion;
pub mod plot;
pub mod problem;
pub mod protocol;
pub mod resolve;
pub mod ros;
pub mod scenario;
pub mod servo;
pub mod teleop;
