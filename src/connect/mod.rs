//! The one way from a config to a running bus: [`open`] takes a validated [`Config`] and returns
//! the opened, limited bus with the [`Arm`] it drives, and the simulator's handle when it
//! started one.
//!
//! - `[bus] kind = "sim"`: the config's servo chain is simulated in-process ([`spawn_sim`]) on
//!   a pseudo-terminal and opened through the same Dynamixel code as hardware, by way of a link
//!   in a private temporary directory ([`SimHandle::path`]) that stays valid when a
//!   `disconnect` fault replaces the pseudo-terminal.
//! - `[bus] kind = "dynamixel"`: `[bus] port` is opened.
//! - An explicit port ([`Options::port`], the CLI's `--port PATH`) is opened whatever
//!   `bus.kind` says, so the same file drives an external `snakectl sim` or a real chain.
//!
//! Every caller goes through here (the daemon, `snakectl sim`, the servo commands, benches and
//! tests); [`sim`] turns a config into the simulator's plain data.
//!
//! # One owner per port
//!
//! Every port is opened through [`open_port`], which locks the device first: a port another
//! program holds (a running daemon, a `scan`) is refused with [`ConnectError::InUse`], naming
//! that program, before anything is written to it. The lock lasts as long as the bus.
//!
//! # When the port vanishes
//!
//! A USB adapter pulled out, or a simulator's `disconnect` fault, makes every exchange on the
//! opened bus fail with [`ServoError::Io`] (or [`ServoError::Open`] when reopening too early),
//! both of [`ErrorClass::Bus`](crate::servo::ErrorClass::Bus): a missing reply is
//! [`ServoError::Timeout`] instead (transient), so `Bus` alone means the port itself is gone.
//! Such a bus is dead for good; drop (or [`close`](crate::servo::ServoBus::close)) it, which
//! frees its lock, and call [`reopen`] on [`port_path`] (the same path
//! [`open`] used: for the in-process simulator its link) until it succeeds, then bring the arm
//! up again (the servos kept their state, but their watchdogs may have fired meanwhile).
//!
//! # A simulated adapter
//!
//! A pseudo-terminal tells no latency timer, so a simulated bus with `[sim] adapter = "ftdi"`
//! is opened as behind the adapter it models ([`Config::modelled_adapter`],
//! [`DynamixelBus::assume_adapter`]): its reads then wait out the timer the simulator holds the
//! replies for, as they do behind a real FTDI chip whose timer could not be lowered.

pub mod sim;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use snakectl_sim::{Clock, RealClock, SimConfig, SimHandle, Simulator};

use crate::config::{BusKind, Config};
use crate::servo::arm::Arm;
use crate::servo::dynamixel::DynamixelBus;
use crate::servo::limits::{LimitPolicy, Limited};
use crate::servo::ports::Ports;
use crate::servo::wire::Adapter;
use crate::servo::ServoError;

pub use sim::{sim_config, sim_configs, SimBusError};
pub use snakectl_sim::Link;

/// Why a config could not be turned into a running bus.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConnectError {
    /// The file has no `[bus]`: it describes geometry only.
    #[error("{}: no [bus] table: add one (kind = \"sim\" or \"dynamixel\") to drive servos", path.display())]
    NoBus {
        /// The config file.
        path: PathBuf,
    },
    /// The config's chain cannot be simulated as written.
    #[error("{}: {source}", path.display())]
    SimConfig {
        /// The config file.
        path: PathBuf,
        /// What cannot be simulated.
        source: SimBusError,
    },
    /// The simulator refused its configuration or could not start.
    #[error("{}: simulator: {source}", path.display())]
    Sim {
        /// The config file.
        path: PathBuf,
        /// The simulator's error.
        source: snakectl_sim::SimError,
    },
    /// The serial port could not be opened.
    #[error("{source} (is the adapter plugged in? `snakectl ports` lists the serial ports)")]
    Open {
        /// The servo layer's error, naming the port.
        source: ServoError,
    },
    /// The file names several ports and the caller drives one (the administrative commands):
    /// give the port with `--port`.
    #[error("{}: [[bus.ports]] names {ports} ports; this drives one: give it with --port", path.display())]
    SeveralPorts {
        /// The config file.
        path: PathBuf,
        /// Ports in the file.
        ports: usize,
    },
    /// Explicit ports given, but not one per port of the file.
    #[error(
        "{}: {given} {flag} given for the {expected} {} of [bus]: give one per port, in order",
        path.display(),
        if *expected == 1 { "port" } else { "ports" }
    )]
    PortCount {
        /// The config file.
        path: PathBuf,
        /// What gave them (`--port`, `--link`).
        flag: &'static str,
        /// Ports given.
        given: usize,
        /// Ports in the file.
        expected: usize,
    },
    /// Another program has the serial port ([`ServoError::InUse`]: the port, the device and the
    /// process that holds it): nothing was written to it.
    #[error(transparent)]
    InUse(ServoError),
    /// Two ports given with `--port` are one device (the same path, or two paths to it): the
    /// second would be refused as in use by this very process.
    #[error("port {port} ({path}) is the same device as port {first}", path = path.display())]
    SameDevice {
        /// The later port, from 1 in order.
        port: usize,
        /// Its path as given.
        path: PathBuf,
        /// The earlier port on that device, from 1.
        first: usize,
    },
    /// [`ConnectError::SameDevice`] for two `[[bus.ports]]` of the file: named as the config's
    /// errors name a field.
    #[error(
        "{}: bus.ports[{port}].port: {path:?} is the same device as bus.ports[{first}].port \
         ({first_path:?})",
        file.display()
    )]
    SameDeviceInFile {
        /// The config file.
        file: PathBuf,
        /// The later port, from 1 in order.
        port: usize,
        /// Its path as written.
        path: PathBuf,
        /// The earlier port on that device, from 1.
        first: usize,
        /// Its path as written.
        first_path: PathBuf,
    },
}

/// How [`open`] reaches the servos.
#[derive(Clone)]
pub struct Options {
    /// Open this port whatever `[bus] kind` says.
    pub port: Option<PathBuf>,
    /// For [`open_arm`]: open these ports, one per port of `[bus]` in order, whatever
    /// `[bus] kind` says (empty: as the file says; [`Options::port`] stands for a one-port
    /// list).
    pub ports: Vec<PathBuf>,
    /// The clock of a simulator started here (wall time unless a test advances its own).
    pub clock: Arc<dyn Clock>,
    /// What the limits wrapper does with a goal outside the joint limits.
    pub strategy: LimitPolicy,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            port: None,
            ports: Vec::new(),
            clock: Arc::new(RealClock),
            strategy: LimitPolicy::Clamp,
        }
    }
}

impl std::fmt::Debug for Options {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Options")
            .field("port", &self.port)
            .field("ports", &self.ports)
            .field("strategy", &self.strategy)
            .finish_non_exhaustive()
    }
}

/// An opened bus, limited to the arm's joint limits, and what it drives.
#[derive(Debug)]
pub struct Connection {
    /// The bus: the only way to the servos.
    pub bus: Limited<DynamixelBus>,
    /// The configured joints and bus settings.
    pub arm: Arm,
    /// The in-process simulator, when `[bus] kind = "sim"` and no port was given.
    pub sim: Option<SimHandle>,
}

/// Open the bus `config` describes (see the module docs for which one).
pub fn open(config: &Config, options: Options) -> Result<Connection, ConnectError> {
    let (bus_config, arm) = match (config.bus(), config.arm()) {
        (Some(b), Some(a)) => (b, a.clone()),
        _ => {
            return Err(ConnectError::NoBus {
                path: config.path().to_path_buf(),
            })
        }
    };
    if bus_config.ports.len() > 1 && options.port.is_none() {
        return Err(ConnectError::SeveralPorts {
            path: config.path().to_path_buf(),
            ports: bus_config.ports.len(),
        });
    }
    let external = options.port.is_some()
        || (bus_config.kind == BusKind::Dynamixel && bus_config.port().is_some());
    let sim = if external {
        None
    } else {
        Some(spawn_sim(config, options.clock.clone())?)
    };
    let port = port_path(config, &options, sim.as_ref()).ok_or_else(|| ConnectError::NoBus {
        path: config.path().to_path_buf(),
    })?;
    let adapter = config.modelled_adapter();
    let bus = reopen(&port, bus_config.baud, adapter, &arm, options.strategy)?;
    Ok(Connection { bus, arm, sim })
}

/// The path [`open`] opens for `config` and `options`: the explicit port, else `[bus] port` of a
/// `"dynamixel"` bus, else the link of the simulator `sim` that [`open`] started (a path that
/// survives the simulator's disconnect faults). `None` for a file without `[bus]`, or a
/// simulated bus without its handle.
pub fn port_path(config: &Config, options: &Options, sim: Option<&SimHandle>) -> Option<PathBuf> {
    let bus = config.bus()?;
    match (&options.port, bus.kind, bus.port()) {
        (Some(port), _, _) => Some(port.clone()),
        (None, BusKind::Dynamixel, Some(port)) => Some(PathBuf::from(port)),
        (None, _, _) => sim.map(|s| s.path().to_path_buf()),
    }
}

/// Open `port` at `baud`, behind `adapter` where the port tells none
/// ([`Config::modelled_adapter`]), and limit it to `arm`'s joint limits with `strategy`, as
/// [`open`] does: how a caller gets its bus back after the port vanished (call it on
/// [`port_path`], retrying while it fails with [`ConnectError::Open`], or
/// [`ConnectError::InUse`] while another program has it).
pub fn reopen(
    port: &Path,
    baud: u32,
    adapter: Option<Adapter>,
    arm: &Arm,
    strategy: LimitPolicy,
) -> Result<Limited<DynamixelBus>, ConnectError> {
    Ok(arm.limited(behind(open_port(port, baud)?, adapter), strategy))
}

/// `bus`, taken to be behind `adapter` (if any) where its port told none.
fn behind(mut bus: DynamixelBus, adapter: Option<Adapter>) -> DynamixelBus {
    if let Some(a) = adapter {
        bus.assume_adapter(a);
    }
    bus
}

/// The whole arm opened, on every port of `[bus]`: one bus of [`Ports`], limited to the
/// joint limits, what it drives, the simulators started for it, and what to reopen.
#[derive(Debug)]
pub struct ArmConnection {
    /// The bus of every port: the only way to the servos.
    pub bus: Limited<Ports<DynamixelBus>>,
    /// The configured joints and bus settings.
    pub arm: Arm,
    /// The in-process simulators, one per port, when `[bus] kind = "sim"` and no port was
    /// given.
    pub sims: Vec<SimHandle>,
    /// Each port's path (a simulator's link) and its servo ids, in the order of `[bus]`: what
    /// [`reopen_arm`] opens again.
    pub ports: Vec<(PathBuf, Vec<u8>)>,
}

/// Refuses ports `given` (`--port`) that are not one per port of `[bus]`, and a bus whose
/// ports name one device twice: the ports `given`, else `[bus]`'s paths for real servos (a
/// simulator's ports are its own). Paths
/// are compared as resolved (symbolic links followed, `.` and `..` taken out); one that does
/// not resolve (nothing there yet) is compared as written. The one check of both, run before
/// anything is opened or bound.
pub fn check_ports(config: &Config, given: &[PathBuf]) -> Result<(), ConnectError> {
    let Some(bus) = config.bus() else {
        return Ok(());
    };
    let expected = bus.ports.len();
    if !given.is_empty() && given.len() != expected {
        return Err(ConnectError::PortCount {
            path: config.path().to_path_buf(),
            flag: "--port",
            given: given.len(),
            expected,
        });
    }
    if !given.is_empty() {
        return match same_device(given) {
            Some((k, first)) => Err(ConnectError::SameDevice {
                port: k + 1,
                path: given[k].clone(),
                first: first + 1,
            }),
            None => Ok(()),
        };
    }
    if bus.kind != BusKind::Dynamixel {
        return Ok(());
    }
    // Every port of a real bus has its path (the config checked it).
    let paths: Vec<PathBuf> = bus
        .ports
        .iter()
        .filter_map(|p| p.port.as_deref().map(PathBuf::from))
        .collect();
    match same_device(&paths) {
        Some((k, first)) => Err(ConnectError::SameDeviceInFile {
            file: config.path().to_path_buf(),
            port: k + 1,
            path: paths[k].clone(),
            first: first + 1,
            first_path: paths[first].clone(),
        }),
        None => Ok(()),
    }
}

/// The index of the first path of `paths` that resolves to an earlier one's device, and that
/// earlier one's.
fn same_device(paths: &[PathBuf]) -> Option<(usize, usize)> {
    let resolved: Vec<PathBuf> = paths
        .iter()
        .map(|p| std::fs::canonicalize(p).unwrap_or_else(|_| p.clone()))
        .collect();
    resolved
        .iter()
        .enumerate()
        .find_map(|(k, device)| Some((k, resolved[..k].iter().position(|d| d == device)?)))
}

/// Open every port of the bus `config` describes, as one bus: the explicit ports of `options`
/// (one per port, in order), else `[bus]`'s paths for real servos, else one simulator per port
/// serving that port's servos. Each port is locked as [`open_port`] does.
pub fn open_arm(config: &Config, options: Options) -> Result<ArmConnection, ConnectError> {
    let path = || config.path().to_path_buf();
    let (bus_config, arm) = match (config.bus(), config.arm()) {
        (Some(b), Some(a)) => (b, a.clone()),
        _ => return Err(ConnectError::NoBus { path: path() }),
    };
    let mut given = options.ports.clone();
    if given.is_empty() {
        given.extend(options.port.clone());
    }
    check_ports(config, &given)?;
    let real = bus_config.kind == BusKind::Dynamixel;
    let mut sims = Vec::new();
    let paths: Vec<PathBuf> = if !given.is_empty() {
        given
    } else if real {
        bus_config
            .ports
            .iter()
            .map(|p| p.port.as_deref().map(PathBuf::from))
            .collect::<Option<_>>()
            .ok_or_else(|| ConnectError::NoBus { path: path() })?
    } else {
        sims = spawn_sims(config, options.clock.clone())?;
        sims.iter().map(|s| s.path().to_path_buf()).collect()
    };
    let ports: Vec<(PathBuf, Vec<u8>)> = paths
        .into_iter()
        .zip(bus_config.ports.iter().map(|p| p.ids.clone()))
        .collect();
    let adapter = config.modelled_adapter();
    let bus = reopen_arm(&ports, bus_config.baud, adapter, &arm, options.strategy)?;
    Ok(ArmConnection {
        bus,
        arm,
        sims,
        ports,
    })
}

/// Open every port of `ports` (path and servo ids) at `baud` as one bus, each behind `adapter`
/// where it tells none ([`Config::modelled_adapter`]), limited to `arm`'s joint limits with
/// `strategy`: [`open_arm`]'s bus (a port that fails later is opened again alone,
/// [`Ports::reopen_failed`] with [`open_port_of_several`]).
pub fn reopen_arm(
    ports: &[(PathBuf, Vec<u8>)],
    baud: u32,
    adapter: Option<Adapter>,
    arm: &Arm,
    strategy: LimitPolicy,
) -> Result<Limited<Ports<DynamixelBus>>, ConnectError> {
    let mut buses = Vec::with_capacity(ports.len());
    for (path, ids) in ports {
        let bus = open_port_of_several(path, baud, adapter)?;
        buses.push((path.display().to_string(), bus, ids.clone()));
    }
    let bus = Ports::new(buses).map_err(|source| ConnectError::Open { source })?;
    Ok(arm.limited(bus, strategy))
}

/// Open one port of a bus of several, as [`reopen_arm`] does (its failure names the port): how
/// a port that failed is opened again while the others stay open
/// ([`Ports::reopen_failed`]), behind `adapter` as before.
pub fn open_port_of_several(
    path: &Path,
    baud: u32,
    adapter: Option<Adapter>,
) -> Result<DynamixelBus, ConnectError> {
    let bus = open_port(path, baud).map_err(|e| match e {
        ConnectError::Open { source } => ConnectError::Open {
            source: ServoError::OnPort {
                port: path.display().to_string(),
                source: Box::new(source),
            },
        },
        e => e,
    })?;
    Ok(behind(bus, adapter))
}

/// One simulator per port of `config`'s bus, each serving that port's servos (and the faults
/// that concern them), on `clock`, each with a link in a private temporary directory.
pub fn spawn_sims(config: &Config, clock: Arc<dyn Clock>) -> Result<Vec<SimHandle>, ConnectError> {
    let n = config.bus().map_or(1, |b| b.ports.len());
    spawn_sims_linked(config, clock, (0..n).map(|_| Link::Private).collect())
}

/// [`spawn_sims`] with a link of the caller's choice per port, in order (`snakectl sim` with
/// one `--link` per port).
pub fn spawn_sims_linked(
    config: &Config,
    clock: Arc<dyn Clock>,
    links: Vec<Link>,
) -> Result<Vec<SimHandle>, ConnectError> {
    let path = || config.path().to_path_buf();
    let configs = sim::sim_configs(config).map_err(|source| ConnectError::SimConfig {
        path: path(),
        source,
    })?;
    if links.len() != configs.len() {
        return Err(ConnectError::PortCount {
            path: path(),
            flag: "--link",
            given: links.len(),
            expected: configs.len(),
        });
    }
    configs
        .into_iter()
        .zip(links)
        .map(|(c, link)| {
            serve_linked(c, clock.clone(), link).map_err(|source| ConnectError::Sim {
                path: path(),
                source,
            })
        })
        .collect()
}

/// Start the config's servo chain, simulated, on a pseudo-terminal, on `clock`, with a link in
/// a private temporary directory ([`SimHandle::path`]; removed when the handle drops).
pub fn spawn_sim(config: &Config, clock: Arc<dyn Clock>) -> Result<SimHandle, ConnectError> {
    spawn_sim_linked(config, clock, Link::Private)
}

/// [`spawn_sim`] with the link of the caller's choice (`snakectl sim --link PATH` uses
/// [`Link::At`]; [`Link::None`] serves the bare pseudo-terminal).
pub fn spawn_sim_linked(
    config: &Config,
    clock: Arc<dyn Clock>,
    link: Link,
) -> Result<SimHandle, ConnectError> {
    let path = || config.path().to_path_buf();
    let sim_config = sim_config(config).map_err(|source| ConnectError::SimConfig {
        path: path(),
        source,
    })?;
    serve_linked(sim_config, clock, link).map_err(|source| ConnectError::Sim {
        path: path(),
        source,
    })
}

/// Serve a simulated chain on a fresh pseudo-terminal, on `clock`, without a link: the way
/// tests with chains no config describes start one.
pub fn serve(
    sim_config: SimConfig,
    clock: Arc<dyn Clock>,
) -> Result<SimHandle, snakectl_sim::SimError> {
    serve_linked(sim_config, clock, Link::None)
}

/// Serve a simulated chain on a fresh pseudo-terminal with `link`: the one place a simulator is
/// started.
pub fn serve_linked(
    sim_config: SimConfig,
    clock: Arc<dyn Clock>,
    link: Link,
) -> Result<SimHandle, snakectl_sim::SimError> {
    snakectl_sim::spawn_pty_linked(Simulator::new(sim_config, clock)?, link)
}

/// Open a serial port (a real adapter or a simulator's pseudo-terminal) at `baud`, raw: for the
/// administrative commands, or to be limited by [`open`]. The port is this process's alone
/// while the bus lives: one another program holds is refused with [`ConnectError::InUse`]
/// before a byte is written (see [`crate::servo::lock`]).
pub fn open_port(port: &Path, baud: u32) -> Result<DynamixelBus, ConnectError> {
    DynamixelBus::open(port, baud).map_err(|source| match source {
        ServoError::InUse { .. } => ConnectError::InUse(source),
        source => ConnectError::Open { source },
    })
}
