//! # snakectl
//!
//! Controller and simulator for planar hyper-redundant "snake arms" and free flexible objects
//! (ropes, chains, hair), after Banerjee, Menon, Ananthasuresh and Ghosal, "Simulation of
//! Length-Preserving Motions of Flexible One Dimensional Objects using Optimization" (2011).
//!
//! Layout, in groups; a module uses only its own group and the groups above it (the simulator
//! crate, `snakectl-sim`, sits below them all: it depends on nothing of this one, and its clock
//! is the workspace's one [`servo::clock::Clock`]).
//!
//! **The math core**, pure (no I/O, clock, threads, serde or tracing; `tests/layers.rs` checks):
//! - [`chain`]: links, base pose, relative angles, limits; forward kinematics, Jacobian,
//!   workspace ring.
//! - [`metrics`]: the paper's five motion metrics between two configurations.
//! - [`resolve`]: the arm's two redundancy-resolution strategies (sequential tractrix, overall
//!   minimization of metric 3) behind one [`resolve::Resolver`] trait.
//! - [`motion`]: the tip (or joint) reference of each control tick from the active command,
//!   speed- and acceleration-limited, time as `dt`.
//! - [`control`]: one control tick: motion, resolve (warm, the active strategy, bisection when
//!   out of reach), joint-speed limit; the goal pose and what happened.
//! - [`rope`]: the overall optimization of a free rope under any of the five metrics (the
//!   paper's flexible objects; not a [`resolve::Resolver`]: nothing holds its base).
//! - [`world`]: obstacles (circles, polygons) and the arm among them: exact link distances,
//!   the clearance of a pose with its gradients, the tip's shortest route around them.
//! - [`reach`]: a clear way in joint space to a target among obstacles, for where the tip's
//!   route cannot pull the body (`snakectl reach`).
//!
//! **The paper's tooling** (flexible objects, one-shot problems; uses the math core only):
//! - [`problem`]: the JSON problem format of `snakectl solve`: parsing, validation, the answer.
//! - [`scenario`]: flexible-object scenarios (TOML): initial curve, pull, strategies; runs them
//!   and tabulates the metrics.
//! - [`plot`]: the scenario figures and the demo's figures, as SVG and PNG.
//!
//! **The servos** (the hardware edge):
//! - [`servo`]: the `ServoBus` trait, its Dynamixel implementation (the one file that imports
//!   `dynamixel2`), the model table, units and calibration, the joint-limit wrapper, the arm's
//!   bring-up and shut-down, the one-time servo settings, a recording bus, serial-port
//!   discovery in sysfs.
//!
//! **The arm's configuration and connection** (use the math core and the servos):
//! - [`config`]: the one TOML file that describes an arm and how to reach it, parsed raw and then
//!   validated, errors naming the file and the field; it builds the servo layer's `Arm`.
//! - [`connect`]: the one way from a config to a running bus: the simulator spawned on a
//!   pseudo-terminal, or a serial port, opened, limited, with the arm it drives.
//!
//! **The daemon and its clients**:
//! - [`protocol`]: the daemon's JSON-lines wire format: requests, replies, error codes,
//!   telemetry, events, each written and read by the same type, shared by the daemon and its
//!   clients; and where each command goes (who may send it, the socket side or the loop).
//! - [`ros`]: the ROS 2 messages the arm speaks on a Zenoh network (`JointState`,
//!   `PointStamped`, `Twist`, ...) and their CDR encoding; built from telemetry, time passed in;
//!   and rmw_zenoh's keys, graph tokens and attachments ([`ros::rmw`]), as pure formatting.
//! - [`textfile`]: reading a text file a user named: a regular file only, at most 1 MiB; the
//!   points CSV a tip's path and a scenario's polyline share.
//! - [`urdf`]: the configured arm as a URDF robot description (`snakectl urdf`).
//! - [`view`]: the channels a Foxglove view and a recording share (topics, schemas, the
//!   messages) and the arm as a Foxglove 3-D scene; pure, time passed in.
//! - [`daemon`]: `snakectl run`: the fixed-rate loop on its own thread (held as parts: port,
//!   health, supervisor, ledger, statistics), the socket server on tokio, the bounded seam
//!   between them.
//! - [`beside`]: the threads beside the loop (recorder, Foxglove view, Zenoh bridge) run at
//!   a lower priority than it.
//! - [`record`]: recordings of a run as MCAP (ROS 2 messages, telemetry and events as JSON,
//!   the config): the loop's bounded hand-over, the recorder's thread, reading one back.
//! - [`client`]: a blocking client of the daemon's socket (requests, typed replies, events, the
//!   latest telemetry, a motion command run to its end; the arm drawn by its chain), for the
//!   one-shot commands, teleop and the demo.
//! - [`teleop`]: the teleop terminal UI: pure input logic (keyboard hold-to-move, joystick),
//!   the joystick device reader, the drawing.

// The math core.
pub mod chain;
pub mod control;
pub mod metrics;
pub mod motion;
pub mod reach;
pub mod resolve;
pub mod rope;
pub mod world;

// The paper's tooling.
pub mod plot;
pub mod problem;
pub mod scenario;

// The servos.
pub mod servo;

// The arm's configuration and connection.
pub mod config;
pub mod connect;

// The daemon and its clients.
pub mod beside;
pub mod client;
pub mod daemon;
pub mod protocol;
pub mod record;
pub mod ros;
pub mod teleop;
pub mod textfile;
pub mod urdf;
pub mod view;
