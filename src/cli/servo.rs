//! `snakectl scan`, `snakectl ports` and `snakectl servo`: find servos on a port, list serial
//! ports, and the one-time settings a new chain needs (id, baud rate, Return Delay Time), plus
//! reboot and torque off.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, Context};
use clap::{Args, Subcommand};

use snakectl::servo::arm::reboot_and_wait;
use snakectl::servo::dynamixel::DynamixelBus;
use snakectl::servo::sysfs::Sysfs;
use snakectl::servo::{
    baud_index, model_name, units, PingInfo, Register, ServoBus, ServoError, BAUD_RATES, MAX_ID,
};

use super::{outln, Failure};

/// Baud rates tried, in this order, when none is given: the factory rate first, then the ones
/// chains are usually set to (9600 and 4.5M only on request: a scan at 9600 takes 4 s).
const COMMON_BAUDS: [u32; 6] = [57_600, 1_000_000, 115_200, 2_000_000, 3_000_000, 4_000_000];

#[derive(Debug, Args)]
pub struct ScanArgs {
    /// Serial port, e.g. /dev/ttyUSB0.
    #[arg(long)]
    port: PathBuf,
    /// Baud rate; when absent, the common ones are tried in turn.
    #[arg(long)]
    baud: Option<u32>,
    /// Wait for replies beyond their wire time, ms.
    #[arg(long, default_value_t = 50)]
    timeout_ms: u64,
}

#[derive(Debug, Args)]
pub struct PortsArgs {}

#[derive(Debug, Args)]
pub struct ServoArgs {
    /// Serial port, e.g. /dev/ttyUSB0.
    #[arg(long)]
    port: PathBuf,
    /// Baud rate the servo listens at now; when absent, the common ones are tried.
    #[arg(long)]
    baud: Option<u32>,
    /// The servo's present id.
    #[arg(long)]
    id: u8,
    /// Wait for a reply beyond its wire time, ms.
    #[arg(long, default_value_t = 50)]
    timeout_ms: u64,
    #[command(subcommand)]
    action: ServoAction,
}

#[derive(Debug, Subcommand)]
enum ServoAction {
    /// Give the servo a new id (refused if another servo has it).
    SetId {
        /// The new id, 0..=252.
        new_id: u8,
    },
    /// Set the servo's baud rate (the port must then use it too).
    SetBaud {
        /// 9600, 57600, 115200, 1000000, 2000000, 3000000, 4000000 or 4500000.
        new_baud: u32,
    },
    /// Set Return Delay Time, µs (even, 0..=508; the factory value is 500, 0 is fastest).
    SetReturnDelay {
        /// Microseconds.
        us: u32,
    },
    /// Print the servo's settings and present position (with the `offset_ticks` that would
    /// make this position 0 rad).
    Info,
    /// Reboot (clears a latched hardware error; torque comes back off).
    Reboot,
    /// Switch torque off.
    TorqueOff,
}

fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

fn check_baud(baud: u32) -> Result<(), Failure> {
    if baud_index(baud).is_none() {
        return Err(Failure::bad_input(anyhow!(
            "baud rate {baud} is not a Dynamixel baud rate (one of {BAUD_RATES:?})"
        )));
    }
    Ok(())
}

fn open(port: &Path, baud: u32) -> Result<DynamixelBus, Failure> {
    DynamixelBus::open(port, baud).map_err(|e| match e {
        ServoError::Open { .. } => Failure::other(
            anyhow!(e)
                .context("is the adapter plugged in? `snakectl ports` lists the serial ports"),
        ),
        other => Failure::other(other),
    })
}

fn describe(p: &PingInfo) -> String {
    let name = model_name(p.model).unwrap_or("unknown model");
    let alert = if p.alert {
        "  ALERT: hardware error latched"
    } else {
        ""
    };
    format!(
        "  id {:>3}  {name} ({})  firmware {}{alert}",
        p.id, p.model, p.firmware
    )
}

/// Runs `snakectl scan`.
pub fn scan(args: ScanArgs) -> Result<(), Failure> {
    init_logging();
    let bauds: Vec<u32> = match args.baud {
        Some(b) => {
            check_baud(b)?;
            vec![b]
        }
        None => COMMON_BAUDS.to_vec(),
    };
    let timeout = Duration::from_millis(args.timeout_ms);
    let mut bus = open(&args.port, bauds[0])?;
    let mut total = 0;
    for &baud in &bauds {
        bus.set_baud(baud).map_err(Failure::other)?;
        let found = bus
            .scan(timeout)
            .with_context(|| format!("scanning {} at {baud}", args.port.display()))
            .map_err(Failure::other)?;
        if found.is_empty() {
            if args.baud.is_some() {
                outln!("{baud} baud: no servo")?;
            }
            continue;
        }
        outln!("{baud} baud: {} servo(s)", found.len())?;
        for p in &found {
            outln!("{}", describe(p))?;
        }
        total += found.len();
    }
    if total == 0 {
        return Err(Failure::other(anyhow!(
            "no servo answered on {} at {} baud (check power, wiring and the baud rate)",
            args.port.display(),
            bauds
                .iter()
                .map(u32::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    Ok(())
}

/// Runs `snakectl ports`.
pub fn ports(_args: PortsArgs) -> Result<(), Failure> {
    let sysfs = Sysfs::system();
    let ports = sysfs
        .ports()
        .context("listing /sys/class/tty")
        .map_err(Failure::other)?;
    if ports.is_empty() {
        outln!("no serial port found")?;
        return Ok(());
    }
    for p in ports {
        let mut line = p.path.display().to_string();
        if let Some(usb) = &p.usb {
            line += &format!("  {:04x}:{:04x}", usb.vid, usb.pid);
            if let Some(name) = usb.known_adapter() {
                line += &format!("  {name}");
            }
            let strings: Vec<&str> = [&usb.manufacturer, &usb.product]
                .into_iter()
                .flatten()
                .map(String::as_str)
                .collect();
            if !strings.is_empty() {
                line += &format!("  [{}]", strings.join(" "));
            }
            if let Some(serial) = &usb.serial {
                line += &format!("  serial {serial}");
            }
        }
        if let Some(ms) = sysfs.latency_ms(&p.path) {
            line += &format!("  latency timer {ms} ms");
            if ms > 1 {
                if let Some(path) = sysfs.latency_timer_path(&p.path) {
                    line += &format!(
                        " (1 is best: {})",
                        snakectl::servo::sysfs::latency_command(&path)
                    );
                }
            }
        }
        outln!("{line}")?;
    }
    Ok(())
}

/// Opens the port at the servo's baud rate (given, or found by pinging it at each common one).
fn find(args: &ServoArgs, timeout: Duration) -> Result<(DynamixelBus, PingInfo), Failure> {
    if args.id > MAX_ID {
        return Err(Failure::bad_input(anyhow!(
            "servo id {} is out of range 0..=252",
            args.id
        )));
    }
    let bauds: Vec<u32> = match args.baud {
        Some(b) => {
            check_baud(b)?;
            vec![b]
        }
        None => COMMON_BAUDS.to_vec(),
    };
    let mut bus = open(&args.port, bauds[0])?;
    for &baud in &bauds {
        bus.set_baud(baud).map_err(Failure::other)?;
        match bus.ping(args.id, timeout) {
            Ok(info) => return Ok((bus, info)),
            Err(e) if e.is_timeout() || matches!(e, ServoError::Checksum { .. }) => {}
            Err(e) => return Err(Failure::other(e)),
        }
    }
    Err(Failure::other(anyhow!(
        "servo {} does not answer on {} at {} baud (`snakectl scan --port {}` lists what does)",
        args.id,
        args.port.display(),
        bauds
            .iter()
            .map(u32::to_string)
            .collect::<Vec<_>>()
            .join(", "),
        args.port.display()
    )))
}

/// Torque off, so EEPROM items can be written.
fn torque_off(bus: &mut DynamixelBus, id: u8, timeout: Duration) -> Result<(), Failure> {
    bus.set_torque(id, false, timeout)
        .with_context(|| format!("torque off before writing EEPROM on servo {id}"))
        .map_err(Failure::other)?;
    Ok(())
}

/// Runs `snakectl servo`.
pub fn run(args: ServoArgs) -> Result<(), Failure> {
    init_logging();
    let timeout = Duration::from_millis(args.timeout_ms);
    // Check the arguments before touching the bus.
    match args.action {
        ServoAction::SetId { new_id } if new_id > MAX_ID => {
            return Err(Failure::bad_input(anyhow!(
                "new id {new_id} is out of range 0..=252"
            )))
        }
        ServoAction::SetBaud { new_baud } => check_baud(new_baud)?,
        ServoAction::SetReturnDelay { us } if us > 508 || us % 2 != 0 => {
            return Err(Failure::bad_input(anyhow!(
                "return delay {us} µs: must be even and at most 508"
            )))
        }
        _ => {}
    }
    let (mut bus, info) = find(&args, timeout)?;
    let id = args.id;
    let port = args.port.display();
    let baud = bus.baud();
    eprintln!(
        "servo {id}: {} at {baud} baud on {port}",
        model_name(info.model).unwrap_or("unknown model")
    );
    match args.action {
        ServoAction::SetId { new_id } => {
            if new_id == id {
                outln!("servo {id}: already id {id}")?;
                return Ok(());
            }
            match bus.ping(new_id, timeout) {
                Err(e) if e.is_timeout() => {}
                Ok(_) => {
                    return Err(Failure::bad_input(anyhow!(
                        "id {new_id} is already taken on {port} at {baud} baud"
                    )))
                }
                Err(e) => return Err(Failure::other(e)),
            }
            torque_off(&mut bus, id, timeout)?;
            // The acknowledgement may already carry the new id.
            match bus.write(id, Register::Id, i64::from(new_id), timeout) {
                Ok(_) => {}
                // A reply already carrying the new id is skipped as another servo's.
                Err(ServoError::WrongId { from, .. }) if from == new_id => {}
                Err(ServoError::Timeout { .. }) => {}
                Err(e) => return Err(Failure::other(e)),
            }
            bus.ping(new_id, timeout)
                .with_context(|| format!("servo {id} does not answer as {new_id}"))
                .map_err(Failure::other)?;
            outln!("servo {id}: now id {new_id}")?;
        }
        ServoAction::SetBaud { new_baud } => {
            let index = baud_index(new_baud)
                .ok_or_else(|| Failure::bad_input(ServoError::Baud(new_baud)))?;
            torque_off(&mut bus, id, timeout)?;
            // The servo may answer at either rate, or not at all, as it switches.
            match bus.write(id, Register::BaudRate, i64::from(index), timeout) {
                Ok(_) | Err(ServoError::Timeout { .. }) | Err(ServoError::Checksum { .. }) => {}
                Err(e) => return Err(Failure::other(e)),
            }
            bus.set_baud(new_baud).map_err(Failure::other)?;
            std::thread::sleep(Duration::from_millis(50));
            bus.ping(id, timeout)
                .with_context(|| format!("servo {id} does not answer at {new_baud} baud"))
                .map_err(Failure::other)?;
            outln!("servo {id}: now at {new_baud} baud (set [bus] baud = {new_baud})")?;
        }
        ServoAction::SetReturnDelay { us } => {
            torque_off(&mut bus, id, timeout)?;
            let value = units::return_delay(us);
            bus.write(id, Register::ReturnDelayTime, value, timeout)
                .map_err(Failure::other)?;
            let back = bus
                .read(id, Register::ReturnDelayTime, timeout)
                .map_err(Failure::other)?
                .value;
            outln!("servo {id}: Return Delay Time {} µs", back * 2)?;
        }
        ServoAction::Info => {
            let mut read = |r: Register| {
                bus.read(id, r, timeout)
                    .map(|v| v.value)
                    .map_err(Failure::other)
            };
            let position = read(Register::PresentPosition)?;
            let baud_reg = read(Register::BaudRate)?;
            let rdt = read(Register::ReturnDelayTime)?;
            let mode = read(Register::OperatingMode)?;
            let (min, max) = (
                read(Register::MinPositionLimit)?,
                read(Register::MaxPositionLimit)?,
            );
            let torque = read(Register::TorqueEnable)?;
            let watchdog = read(Register::BusWatchdog)?;
            let errors = bus.hardware_errors(id, timeout).map_err(Failure::other)?;
            let baud_text = usize::try_from(baud_reg)
                .ok()
                .and_then(|i| BAUD_RATES.get(i))
                .map_or_else(|| format!("register {baud_reg}"), u32::to_string);
            outln!("id {id}")?;
            outln!(
                "model {} ({}), firmware {}",
                model_name(info.model).unwrap_or("unknown"),
                info.model,
                info.firmware
            )?;
            outln!("baud rate {baud_text}")?;
            outln!("return delay {} us", rdt * 2)?;
            outln!("operating mode {mode}")?;
            outln!("position limits {min}..={max} ticks")?;
            outln!("torque {}", if torque != 0 { "on" } else { "off" })?;
            outln!("bus watchdog {watchdog}")?;
            outln!("hardware errors {errors}")?;
            outln!(
                "present position {position} ticks (offset_ticks = {} makes it 0 rad)",
                position - 2048
            )?;
        }
        ServoAction::Reboot => {
            reboot_and_wait(&mut bus, id, timeout).map_err(Failure::other)?;
            let errors = bus.hardware_errors(id, timeout).map_err(Failure::other)?;
            outln!("servo {id}: rebooted; hardware errors: {errors}")?;
        }
        ServoAction::TorqueOff => {
            bus.set_torque(id, false, timeout).map_err(Failure::other)?;
            outln!("servo {id}: torque off")?;
        }
    }
    Ok(())
}
