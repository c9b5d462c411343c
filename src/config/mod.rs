//! The one config file: raw serde tables, then validated types.
//!
//! One TOML file describes an arm and how to reach it, and every command reads the same file.
//! Reading happens in two steps, so that nothing downstream sees an unchecked value:
//! - [`raw`]: the file as written, one `deny_unknown_fields` struct per table, units in the
//!   field names, defaults in one place;
//! - [`Config`]: the checked result. [`Config::load`] and [`Config::from_str`] are the only ways
//!   to get one; every refusal is a [`ConfigError`] naming the file and the field (or the line
//!   and column, for TOML syntax) and quoting the value.
//!
//! The tables: `[arm]` and `[[joint]]` (geometry, limits, home pose and per-joint servo
//! settings), `[bus]` (serial bus), `[sim]` with `[[sim.fault]]` (the simulated servo chain),
//! `[control]` (the loop) and `[server]` (the socket). Geometry is checked in full; the other
//! tables get the cheap checks (signs, ranges, known names, ids that exist).

mod error;
pub mod raw;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

pub use error::{ConfigError, Problem};
pub use raw::{BusKind, Fault, HardwareError, OnExit};

use crate::chain::{Chain, JointLimit, Vec2, MAX_MAGNITUDE};
use crate::resolve::Strategy;
use raw::{RawArm, RawBus, RawConfig, RawControl, RawJoint, RawServer, RawSim, StrategyName};

/// Lowest servo id a joint may use (0 is reserved by convention).
pub const MIN_SERVO_ID: u8 = 1;
/// Highest servo id a joint may use (253..=255 are reserved; 254 is broadcast).
pub const MAX_SERVO_ID: u8 = crate::servo::MAX_ID;
/// Largest software offset, ticks: one full turn of an X-series servo.
pub const MAX_OFFSET_TICKS: i32 = 4095;
/// Baud rates an X-series servo can be set to (the servo layer's list).
pub use crate::servo::BAUD_RATES;

/// A servo model this program knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ServoModel {
    /// ROBOTIS XL430-W250.
    Xl430W250,
    /// ROBOTIS XM430-W350.
    Xm430W350,
    /// ROBOTIS XL330-M288.
    Xl330M288,
}

impl ServoModel {
    /// Every known model.
    pub const ALL: [ServoModel; 3] = [
        ServoModel::Xl430W250,
        ServoModel::Xm430W350,
        ServoModel::Xl330M288,
    ];

    /// The name used in files, e.g. `"XL430-W250"`.
    pub fn name(self) -> &'static str {
        match self {
            ServoModel::Xl430W250 => "XL430-W250",
            ServoModel::Xm430W350 => "XM430-W350",
            ServoModel::Xl330M288 => "XL330-M288",
        }
    }

    /// The value of the servo's Model Number register (address 0).
    pub fn model_number(self) -> u16 {
        match self {
            ServoModel::Xl430W250 => 1060,
            ServoModel::Xm430W350 => 1020,
            ServoModel::Xl330M288 => 1200,
        }
    }

    /// The model with this file name, if known (exact spelling).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// One validated `[[joint]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    /// Length of the link this joint turns, m.
    pub link_m: f64,
    /// Allowed relative angles, rad.
    pub limit: JointLimit,
    /// Servo id, 1..=252, unique in the file.
    pub id: Option<u8>,
    /// Servo model.
    pub model: Option<ServoModel>,
    /// Ticks at 0 rad relative to the nominal centre 2048, within one turn.
    pub offset_ticks: i32,
    /// A positive angle turns the servo the negative way.
    pub reverse: bool,
}

/// The validated `[bus]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Bus {
    /// Simulated or real servos.
    pub kind: BusKind,
    /// Serial device; always present for [`BusKind::Dynamixel`].
    pub port: Option<String>,
    /// Baud rate, one of [`BAUD_RATES`].
    pub baud: u32,
    /// Return Delay Time to write, µs (even, at most 508).
    pub return_delay_us: u32,
    /// Profile Velocity to write, rad/s (0 = none).
    pub profile_velocity_rad_s: f64,
    /// Profile Acceleration to write, rad/s² (0 = none).
    pub profile_acceleration_rad_s2: f64,
    /// What the servos do when the daemon exits.
    pub on_exit: OnExit,
    /// Bus Watchdog, ms (0 = off, else a multiple of 20 up to 2540).
    pub watchdog_ms: u32,
    /// Wait for one reply, ms (1..=1000).
    pub reply_timeout_ms: u32,
}

/// The validated `[sim]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Sim {
    /// Sleep for the wire time of every packet.
    pub wire_timing: bool,
    /// Seed of the random faults.
    pub seed: u64,
    /// Faults to inject; every id names a joint's servo, fractions lie in [0, 1], windows are
    /// ordered.
    pub faults: Vec<Fault>,
}

/// The validated `[control]` (defaults when the table is absent).
#[derive(Debug, Clone, PartialEq)]
pub struct Control {
    /// Loop rate, Hz, positive.
    pub rate_hz: f64,
    /// Redundancy resolution strategy.
    pub strategy: Strategy,
    /// Fastest tip speed, m/s, positive.
    pub max_tip_speed_m_s: f64,
    /// Fastest joint speed, rad/s, positive.
    pub max_joint_speed_rad_s: f64,
    /// Straight sub-steps per tick, at least 1.
    pub substeps: u32,
}

/// The validated `[server]` (defaults when the table is absent).
#[derive(Debug, Clone, PartialEq)]
pub struct Server {
    /// Address to listen on.
    pub listen: SocketAddr,
    /// Token file, resolved against the config file's directory; `None` = no token.
    pub token_file: Option<PathBuf>,
    /// Most clients at once, at least 1.
    pub max_clients: u32,
}

/// A checked config file.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    path: PathBuf,
    chain: Chain,
    home: Vec<f64>,
    joints: Vec<Joint>,
    bus: Option<Bus>,
    sim: Option<Sim>,
    control: Control,
    server: Server,
}

impl Config {
    /// Reads and checks the file at `path`.
    pub fn load(path: impl AsRef<Path>) -> Result<Config, ConfigError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_str(&text, path)
    }

    /// Checks `text` as if read from `path`, which names the file in errors and anchors a
    /// relative `server.token_file`.
    #[allow(clippy::should_implement_trait)]
    pub fn from_str(text: &str, path: impl AsRef<Path>) -> Result<Config, ConfigError> {
        let path = path.as_ref();
        let raw: RawConfig = toml::from_str(text).map_err(|e| syntax_error(text, path, &e))?;
        Checker { path }.config(raw)
    }

    /// The file this came from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The arm's chain: links, base pose and joint limits.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// The start pose, rad, one entry per joint, inside the limits.
    pub fn home(&self) -> &[f64] {
        &self.home
    }

    /// The joints, base to tip.
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }

    /// The bus, if the file describes one.
    pub fn bus(&self) -> Option<&Bus> {
        self.bus.as_ref()
    }

    /// The simulator settings, if the file has a `[sim]` table.
    pub fn sim(&self) -> Option<&Sim> {
        self.sim.as_ref()
    }

    /// The control loop settings.
    pub fn control(&self) -> &Control {
        &self.control
    }

    /// The server settings.
    pub fn server(&self) -> &Server {
        &self.server
    }
}

/// Turns a TOML error into one naming the file, line and column.
fn syntax_error(text: &str, path: &Path, e: &toml::de::Error) -> ConfigError {
    let (line, column) = match e.span().and_then(|s| text.get(..s.start)) {
        Some(before) => {
            let line = before.matches('\n').count() + 1;
            let line_start = before.rfind('\n').map_or(0, |i| i + 1);
            (line, before[line_start..].chars().count() + 1)
        }
        None => (0, 0),
    };
    ConfigError::Syntax {
        path: path.to_path_buf(),
        line,
        column,
        message: e
            .message()
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect::<Vec<_>>()
            .join("; "),
    }
}

fn finite_within(value: f64) -> bool {
    value.is_finite() && value.abs() <= MAX_MAGNITUDE
}

/// Holds the file name while checking, so each check only says what and where.
struct Checker<'a> {
    path: &'a Path,
}

impl Checker<'_> {
    fn invalid(&self, field: impl Into<String>, problem: Problem) -> ConfigError {
        ConfigError::Invalid {
            path: self.path.to_path_buf(),
            field: field.into(),
            problem,
        }
    }

    fn positive(&self, field: impl Into<String>, value: f64) -> Result<f64, ConfigError> {
        if finite_within(value) && value > 0.0 {
            Ok(value)
        } else {
            Err(self.invalid(field, Problem::NotPositive { value }))
        }
    }

    fn non_negative(&self, field: impl Into<String>, value: f64) -> Result<f64, ConfigError> {
        if finite_within(value) && value >= 0.0 {
            Ok(value)
        } else {
            Err(self.invalid(field, Problem::Negative { value }))
        }
    }

    fn finite(&self, field: impl Into<String>, value: f64) -> Result<f64, ConfigError> {
        if finite_within(value) {
            Ok(value)
        } else {
            Err(self.invalid(field, Problem::NotFinite { value }))
        }
    }

    fn config(&self, raw: RawConfig) -> Result<Config, ConfigError> {
        let joints = raw
            .joints
            .iter()
            .enumerate()
            .map(|(i, j)| self.joint(i + 1, j))
            .collect::<Result<Vec<_>, _>>()?;
        if joints.is_empty() {
            return Err(self.invalid("joint", Problem::NoJoints));
        }
        self.unique_ids(&joints)?;
        let (base, heading, home) = self.arm(&raw.arm, &joints)?;
        let chain = Chain::new(
            joints.iter().map(|j| j.link_m).collect(),
            base,
            heading,
            joints.iter().map(|j| Some(j.limit)).collect(),
        )
        .map_err(|source| ConfigError::Chain {
            path: self.path.to_path_buf(),
            source,
        })?;
        let bus = raw.bus.map(|b| self.bus(&b, &joints)).transpose()?;
        let sim = raw.sim.map(|s| self.sim(s, &joints)).transpose()?;
        let control = self.control(&raw.control.unwrap_or_default())?;
        let server = self.server(raw.server.unwrap_or_default())?;
        Ok(Config {
            path: self.path.to_path_buf(),
            chain,
            home,
            joints,
            bus,
            sim,
            control,
            server,
        })
    }

    fn joint(&self, n: usize, raw: &RawJoint) -> Result<Joint, ConfigError> {
        let field = |name: &str| format!("joint[{n}].{name}");
        let link_m = self.positive(field("link_m"), raw.link_m)?;
        let min_rad = self.finite(field("min_rad"), raw.min_rad)?;
        let max_rad = self.finite(field("max_rad"), raw.max_rad)?;
        if min_rad >= max_rad {
            return Err(self.invalid(field("max_rad"), Problem::EmptyRange { min_rad, max_rad }));
        }
        let id = match raw.id {
            None => None,
            Some(v) => match u8::try_from(v) {
                Ok(id) if (MIN_SERVO_ID..=MAX_SERVO_ID).contains(&id) => Some(id),
                _ => return Err(self.invalid(field("id"), Problem::BadId { value: v })),
            },
        };
        let model = match &raw.model {
            None => None,
            Some(name) => match ServoModel::from_name(name) {
                Some(m) => Some(m),
                None => {
                    return Err(self.invalid(
                        field("model"),
                        Problem::UnknownModel {
                            value: name.clone(),
                        },
                    ))
                }
            },
        };
        let offset_ticks = match i32::try_from(raw.offset_ticks) {
            Ok(t) if t.abs() <= MAX_OFFSET_TICKS => t,
            _ => {
                return Err(self.invalid(
                    field("offset_ticks"),
                    Problem::OutOfRange {
                        value: raw.offset_ticks,
                        expected: "must lie within one turn, -4095..=4095",
                    },
                ))
            }
        };
        Ok(Joint {
            link_m,
            limit: JointLimit {
                lo: min_rad,
                hi: max_rad,
            },
            id,
            model,
            offset_ticks,
            reverse: raw.reverse,
        })
    }

    fn unique_ids(&self, joints: &[Joint]) -> Result<(), ConfigError> {
        let mut owner = [0usize; 256];
        for (i, j) in joints.iter().enumerate() {
            if let Some(id) = j.id {
                let slot = &mut owner[usize::from(id)];
                if *slot != 0 {
                    return Err(self.invalid(
                        format!("joint[{}].id", i + 1),
                        Problem::DuplicateId { id, other: *slot },
                    ));
                }
                *slot = i + 1;
            }
        }
        Ok(())
    }

    fn arm(&self, raw: &RawArm, joints: &[Joint]) -> Result<(Vec2, f64, Vec<f64>), ConfigError> {
        let x = self.finite("arm.base_x_m", raw.base_x_m)?;
        let y = self.finite("arm.base_y_m", raw.base_y_m)?;
        let heading = self.finite("arm.base_heading_rad", raw.base_heading_rad)?;
        let home = match &raw.home_rad {
            Some(home) => {
                if home.len() != joints.len() {
                    return Err(self.invalid(
                        "arm.home_rad",
                        Problem::Count {
                            got: home.len(),
                            expected: joints.len(),
                        },
                    ));
                }
                for (i, (&value, j)) in home.iter().zip(joints).enumerate() {
                    if !j.limit.contains(value) {
                        return Err(self.invalid(
                            format!("arm.home_rad[{}]", i + 1),
                            Problem::OutsideLimits {
                                joint: i + 1,
                                value,
                                min_rad: j.limit.lo,
                                max_rad: j.limit.hi,
                            },
                        ));
                    }
                }
                home.clone()
            }
            None => {
                if let Some((i, j)) = joints
                    .iter()
                    .enumerate()
                    .find(|(_, j)| !j.limit.contains(0.0))
                {
                    return Err(self.invalid(
                        "arm.home_rad",
                        Problem::ZeroOutsideLimits {
                            joint: i + 1,
                            min_rad: j.limit.lo,
                            max_rad: j.limit.hi,
                        },
                    ));
                }
                vec![0.0; joints.len()]
            }
        };
        Ok((Vec2::new(x, y), heading, home))
    }

    fn bus(&self, raw: &RawBus, joints: &[Joint]) -> Result<Bus, ConfigError> {
        for (i, j) in joints.iter().enumerate() {
            if j.id.is_none() {
                return Err(self.invalid(
                    format!("joint[{}].id", i + 1),
                    Problem::Missing {
                        why: "every joint needs a servo id when the file has a [bus]",
                    },
                ));
            }
            if j.model.is_none() {
                return Err(self.invalid(
                    format!("joint[{}].model", i + 1),
                    Problem::Missing {
                        why: "every joint needs a servo model when the file has a [bus]",
                    },
                ));
            }
        }
        let port = match (raw.kind, &raw.port) {
            (BusKind::Dynamixel, None) => {
                return Err(self.invalid(
                    "bus.port",
                    Problem::Missing {
                        why: "kind = \"dynamixel\" needs the serial device, e.g. /dev/ttyUSB0",
                    },
                ))
            }
            (_, port) => port.clone(),
        };
        if !BAUD_RATES.contains(&raw.baud) {
            return Err(self.invalid(
                "bus.baud",
                Problem::OutOfRange {
                    value: raw.baud.into(),
                    expected: "must be one of 9600, 57600, 115200, 1000000, 2000000, 3000000, \
                               4000000, 4500000",
                },
            ));
        }
        if raw.return_delay_us % 2 != 0 || raw.return_delay_us > 508 {
            return Err(self.invalid(
                "bus.return_delay_us",
                Problem::OutOfRange {
                    value: raw.return_delay_us.into(),
                    expected: "must be even and at most 508 (the register counts 2 µs)",
                },
            ));
        }
        let profile_velocity_rad_s =
            self.non_negative("bus.profile_velocity_rad_s", raw.profile_velocity_rad_s)?;
        let profile_acceleration_rad_s2 = self.non_negative(
            "bus.profile_acceleration_rad_s2",
            raw.profile_acceleration_rad_s2,
        )?;
        if raw.watchdog_ms % 20 != 0 || raw.watchdog_ms > 2540 {
            return Err(self.invalid(
                "bus.watchdog_ms",
                Problem::OutOfRange {
                    value: raw.watchdog_ms.into(),
                    expected: "must be 0 (off) or a multiple of 20 up to 2540",
                },
            ));
        }
        if !(1..=1000).contains(&raw.reply_timeout_ms) {
            return Err(self.invalid(
                "bus.reply_timeout_ms",
                Problem::OutOfRange {
                    value: raw.reply_timeout_ms.into(),
                    expected: "must lie in 1..=1000",
                },
            ));
        }
        Ok(Bus {
            kind: raw.kind,
            port,
            baud: raw.baud,
            return_delay_us: raw.return_delay_us,
            profile_velocity_rad_s,
            profile_acceleration_rad_s2,
            on_exit: raw.on_exit,
            watchdog_ms: raw.watchdog_ms,
            reply_timeout_ms: raw.reply_timeout_ms,
        })
    }

    fn sim(&self, raw: RawSim, joints: &[Joint]) -> Result<Sim, ConfigError> {
        for (i, fault) in raw.faults.iter().enumerate() {
            let field = |name: &str| format!("sim.fault[{}].{name}", i + 1);
            let (id, at_s, until_s, fraction) = match *fault {
                Fault::Drop {
                    fraction,
                    id,
                    at_s,
                    until_s,
                }
                | Fault::Corrupt {
                    fraction,
                    id,
                    at_s,
                    until_s,
                } => (id, at_s, until_s, Some(fraction)),
                Fault::Latency {
                    id, at_s, until_s, ..
                } => (id, at_s, until_s, None),
                Fault::Silent { id, at_s, until_s } => (Some(id), at_s, until_s, None),
                Fault::HardwareError { id, at_s, .. } => (Some(id), at_s, None, None),
            };
            if let Some(id) = id {
                if !joints.iter().any(|j| j.id == Some(id)) {
                    return Err(self.invalid(field("id"), Problem::UnknownId { id }));
                }
            }
            let at_s = self.non_negative(field("at_s"), at_s)?;
            if let Some(until_s) = until_s {
                if !(finite_within(until_s) && until_s > at_s) {
                    return Err(
                        self.invalid(field("until_s"), Problem::EndsBeforeStart { at_s, until_s })
                    );
                }
            }
            if let Some(value) = fraction {
                if !(0.0..=1.0).contains(&value) {
                    return Err(self.invalid(
                        field("fraction"),
                        Problem::Outside {
                            value,
                            lo: 0.0,
                            hi: 1.0,
                        },
                    ));
                }
            }
        }
        Ok(Sim {
            wire_timing: raw.wire_timing,
            seed: raw.seed,
            faults: raw.faults,
        })
    }

    fn control(&self, raw: &RawControl) -> Result<Control, ConfigError> {
        let rate_hz = self.positive("control.rate_hz", raw.rate_hz)?;
        let max_tip_speed_m_s =
            self.positive("control.max_tip_speed_m_s", raw.max_tip_speed_m_s)?;
        let max_joint_speed_rad_s =
            self.positive("control.max_joint_speed_rad_s", raw.max_joint_speed_rad_s)?;
        if raw.substeps == 0 {
            return Err(self.invalid(
                "control.substeps",
                Problem::OutOfRange {
                    value: 0,
                    expected: "must be at least 1",
                },
            ));
        }
        Ok(Control {
            rate_hz,
            strategy: match raw.strategy {
                StrategyName::Sequential => Strategy::Sequential,
                StrategyName::Overall => Strategy::Overall,
            },
            max_tip_speed_m_s,
            max_joint_speed_rad_s,
            substeps: raw.substeps,
        })
    }

    fn server(&self, raw: RawServer) -> Result<Server, ConfigError> {
        let listen = raw.listen.parse::<SocketAddr>().map_err(|e| {
            self.invalid(
                "server.listen",
                Problem::BadAddress {
                    value: raw.listen.clone(),
                    reason: e.to_string(),
                },
            )
        })?;
        if raw.max_clients == 0 {
            return Err(self.invalid(
                "server.max_clients",
                Problem::OutOfRange {
                    value: 0,
                    expected: "must be at least 1",
                },
            ));
        }
        let token_file = raw.token_file.map(|f| {
            if f.is_relative() {
                self.path.parent().unwrap_or(Path::new("")).join(f)
            } else {
                f
            }
        });
        Ok(Server {
            listen,
            token_file,
            max_clients: raw.max_clients,
        })
    }
}

#[cfg(test)]
mod tests;
