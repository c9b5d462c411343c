//! `snakectl scan`, `snakectl ports` and `snakectl servo`: find servos on a port, list serial
//! ports, and the one-time settings a new chain needs (id, baud rate, Return Delay Time), plus
//! reboot and torque off.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, Context};
use clap::{Args, Subcommand};

use snakectl::connect::{self, ConnectError};
use snakectl::servo::admin::{self, AdminError};
use snakectl::servo::arm::{reboot_and_wait, Retry};
use snakectl::servo::clock::RealClock;
use snakectl::servo::dynamixel::DynamixelBus;
use snakectl::servo::sysfs::Sysfs;
use snakectl::servo::units;
use snakectl::servo::{
    baud_index, model_name, PingInfo, Register, ServoBus, ServoError, BAUD_RATES, MAX_ID,
};

use super::{outln, Failure};

/// Baud rates tried, in this order, when none is given: every rate `set-baud` accepts, so no
/// servo is lost at one; the factory rate first, then the ones chains are usually set to, 9600
/// last (a scan there takes 4.4 s, more than the others together).
const SEARCH_BAUDS: [u32; 8] = [
    57_600, 1_000_000, 115_200, 2_000_000, 3_000_000, 4_000_000, 4_500_000, 9_600,
];

/// Longest `--timeout-ms`: a wait beyond it only hangs the command.
const MAX_TIMEOUT_MS: u64 = 10_000;

#[derive(Debug, Args)]
pub struct ScanArgs {
    /// Serial port, e.g. /dev/ttyUSB0.
    #[arg(long)]
    port: PathBuf,
    /// Baud rate; when absent, every Dynamixel rate is tried in turn.
    #[arg(long)]
    baud: Option<u32>,
    /// Wait for replies beyond every id's slot (3 ms) and reply time, ms (at most 10000).
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
    /// Baud rate the servo listens at now; when absent, every Dynamixel rate is tried.
    #[arg(long)]
    baud: Option<u32>,
    /// The servo's present id, 0..=252.
    #[arg(long)]
    id: u64,
    /// Wait for a reply beyond its wire time, ms (at most 10000).
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
        new_id: u64,
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
    /// Zero Homing Offset and clear Drive Mode's reverse bit (offsets and direction belong in
    /// the config's `offset_ticks` and `reverse`, which bring-up requires).
    ClearCalibration,
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

/// `--timeout-ms` as a wait, refused (exit 2) beyond [`MAX_TIMEOUT_MS`].
fn timeout(ms: u64) -> Result<Duration, Failure> {
    if ms > MAX_TIMEOUT_MS {
        return Err(Failure::bad_input(anyhow!(
            "--timeout-ms {ms} is out of range 0..={MAX_TIMEOUT_MS}"
        )));
    }
    Ok(Duration::from_millis(ms))
}

/// An id argument as a servo id, refused (exit 2) outside 0..=252 with one message whatever
/// the number.
fn servo_id(what: &str, id: u64) -> Result<u8, Failure> {
    match u8::try_from(id) {
        Ok(id) if id <= MAX_ID => Ok(id),
        _ => Err(Failure::bad_input(anyhow!(
            "{what} {id} is out of range 0..=252 (253 is reserved, 254 is the broadcast id)"
        ))),
    }
}

fn open(port: &Path, baud: u32) -> Result<DynamixelBus, Failure> {
    connect::open_port(port, baud).map_err(|e: ConnectError| Failure::other(e))
}

/// A bus error on `port`, naming it; a failing port most likely lost its adapter.
fn port_failure(port: &Path, e: ServoError) -> Failure {
    let context = if matches!(e, ServoError::Io(_)) {
        format!(
            "{} failed (the adapter may have been unplugged)",
            port.display()
        )
    } else {
        port.display().to_string()
    };
    Failure::other(anyhow::Error::new(e).context(context))
}

/// A procedure's error: bad arguments and a bus that would end up with two servos on one id
/// are the user's, the rest the bus's (named with its port).
fn admin_failure(port: &Path, e: AdminError) -> Failure {
    match e {
        AdminError::BadId(_)
        | AdminError::BadReturnDelay(_)
        | AdminError::IdTaken { .. }
        | AdminError::Shared { .. } => Failure::bad_input(e),
        AdminError::Servo(e) => port_failure(port, e),
        other => Failure::other(other),
    }
}

/// Tells that a procedure found torque on and switched it off: the joint went limp.
fn told_torque<T>(id: u8, written: admin::Written<T>) -> T {
    if written.torque_was_on {
        eprintln!("servo {id}: torque was on: switched off to write its EEPROM");
    }
    written.value
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
        None => SEARCH_BAUDS.to_vec(),
    };
    let timeout = timeout(args.timeout_ms)?;
    let mut bus = open(&args.port, bauds[0])?;
    let mut total = 0;
    // (id, baud, replies) of every id answered more than once.
    let mut shared: Vec<(u8, u32, usize)> = Vec::new();
    for &baud in &bauds {
        let found = bus
            .set_baud(baud)
            .and_then(|()| bus.scan(timeout))
            .map_err(|e| port_failure(&args.port, e))?;
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
        // The scan lists replies in id order: equal ids are neighbours.
        for group in found.chunk_by(|a, b| a.id == b.id) {
            if let [first, _, ..] = group {
                eprintln!(
                    "warning: id {} answered {} times at {baud} baud: servos share it",
                    first.id,
                    group.len()
                );
                shared.push((first.id, baud, group.len()));
            }
        }
        total += found.len();
    }
    if args.baud.is_none() && total > 0 {
        outln!("baud rates tried: {}", admin::list_bauds(&bauds))?;
    }
    if !shared.is_empty() {
        let ids: Vec<String> = shared
            .iter()
            .map(|(id, baud, n)| format!("id {id} ({n} servos at {baud} baud)"))
            .collect();
        return Err(Failure::other(anyhow!(
            "servos share an id on {}: {}; connect one at a time and give each its own id \
             (snakectl servo ... set-id)",
            args.port.display(),
            ids.join(", ")
        )));
    }
    if total == 0 {
        return Err(Failure::other(anyhow!(
            "no servo answered on {} at {} baud (check power, wiring and the baud rate)",
            args.port.display(),
            admin::list_bauds(&bauds)
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

/// Opens the port at servo `id`'s baud rate (given, or found by pinging it at each one).
fn find(args: &ServoArgs, id: u8, timeout: Duration) -> Result<(DynamixelBus, PingInfo), Failure> {
    let bauds: Vec<u32> = match args.baud {
        Some(b) => {
            check_baud(b)?;
            vec![b]
        }
        None => SEARCH_BAUDS.to_vec(),
    };
    let mut bus = open(&args.port, bauds[0])?;
    match admin::find(&mut bus, id, &bauds, timeout) {
        Ok(info) => Ok((bus, info)),
        Err(e @ AdminError::NotFound { .. }) => Err(Failure::other(anyhow!(
            "{e} on {} (`snakectl scan --port {}` lists what does)",
            args.port.display(),
            args.port.display()
        ))),
        Err(e) => Err(admin_failure(&args.port, e)),
    }
}

/// Runs `snakectl servo`.
pub fn run(args: ServoArgs) -> Result<(), Failure> {
    init_logging();
    // Check the arguments before touching the bus.
    let id = servo_id("--id", args.id)?;
    let timeout = timeout(args.timeout_ms)?;
    let new_id = match args.action {
        ServoAction::SetId { new_id } => Some(servo_id("new id", new_id)?),
        _ => None,
    };
    match args.action {
        ServoAction::SetBaud { new_baud } => check_baud(new_baud)?,
        ServoAction::SetReturnDelay { us } if us > 508 || us % 2 != 0 => {
            return Err(Failure::bad_input(AdminError::BadReturnDelay(us)))
        }
        _ => {}
    }
    let (mut bus, info) = find(&args, id, timeout)?;
    let path = args.port.as_path();
    let port = args.port.display();
    let baud = bus.baud();
    eprintln!(
        "servo {id}: {} at {baud} baud on {port}",
        model_name(info.model).unwrap_or("unknown model")
    );
    match args.action {
        ServoAction::SetId { .. } => {
            let new_id = new_id.unwrap_or(id);
            let written =
                admin::set_id(&mut bus, id, new_id, timeout).map_err(|e| admin_failure(path, e))?;
            if told_torque(id, written) {
                outln!("servo {id}: now id {new_id}")?;
            } else {
                outln!("servo {id}: already id {id}")?;
            }
        }
        ServoAction::SetBaud { new_baud } => {
            let written = admin::set_baud(&mut bus, id, new_baud, timeout, &RealClock)
                .map_err(|e| admin_failure(path, e))?;
            told_torque(id, written);
            if new_baud == baud {
                outln!("servo {id}: already at {baud} baud")?;
            } else {
                outln!(
                    "servo {id}: now at {new_baud} baud; servos still at {baud} baud no longer \
                     hear it: move each to {new_baud} too, then set [bus] baud = {new_baud}"
                )?;
            }
        }
        ServoAction::SetReturnDelay { us } => {
            let written = admin::set_return_delay(&mut bus, id, us, timeout)
                .map_err(|e| admin_failure(path, e))?;
            let back = told_torque(id, written);
            outln!("servo {id}: Return Delay Time {back} µs")?;
        }
        ServoAction::ClearCalibration => {
            let written = admin::clear_calibration(&mut bus, id, timeout)
                .map_err(|e| admin_failure(path, e))?;
            let (offset, drive) = told_torque(id, written);
            // What the servo holds now, read back.
            let mut read = |r| bus.read(id, r, timeout).map(|v| v.value);
            let now = (read(Register::HomingOffset), read(Register::DriveMode));
            let (Ok(offset_now), Ok(drive_now)) = now else {
                return Err(Failure::other(anyhow!(
                    "servo {id}: reading back the calibration failed"
                )));
            };
            outln!(
                "servo {id}: Homing Offset {offset} -> {offset_now}, Drive Mode {drive} -> {drive_now}"
            )?;
        }
        ServoAction::Info => {
            let i = admin::info(&mut bus, id, timeout).map_err(|e| admin_failure(path, e))?;
            let baud_text = usize::try_from(i.baud_register)
                .ok()
                .and_then(|r| BAUD_RATES.get(r))
                .map_or_else(|| format!("register {}", i.baud_register), u32::to_string);
            outln!("id {id}")?;
            outln!(
                "model {} ({}), firmware {}",
                model_name(info.model).unwrap_or("unknown"),
                info.model,
                info.firmware
            )?;
            outln!("baud rate {baud_text}")?;
            outln!("return delay {} us", i.return_delay_us)?;
            outln!("operating mode {}", i.operating_mode)?;
            outln!("position limits {}..={} ticks", i.limits.0, i.limits.1)?;
            outln!("homing offset {} ticks", i.homing_offset)?;
            outln!("drive mode {}", i.drive_mode)?;
            outln!("torque {}", if i.torque { "on" } else { "off" })?;
            outln!("bus watchdog {}", i.watchdog)?;
            outln!("hardware errors {}", i.errors)?;
            outln!(
                "present position {} ticks (offset_ticks = {} makes it 0 rad)",
                i.position,
                i.position - i64::from(units::CENTRE_TICKS)
            )?;
        }
        ServoAction::Reboot => {
            reboot_and_wait(&mut bus, id, timeout, &RealClock, &mut Retry::default())
                .map_err(|e| port_failure(path, e))?;
            let errors = bus
                .hardware_errors(id, timeout)
                .map_err(|e| port_failure(path, e))?;
            outln!("servo {id}: rebooted; hardware errors: {errors}")?;
        }
        ServoAction::TorqueOff => {
            bus.set_torque(id, false, timeout)
                .map_err(|e| port_failure(path, e))?;
            outln!("servo {id}: torque off")?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rates_searched_are_every_rate_set_baud_accepts() {
        let mut searched = SEARCH_BAUDS.to_vec();
        searched.sort_unstable();
        let mut all = BAUD_RATES.to_vec();
        all.sort_unstable();
        assert_eq!(searched, all);
    }
}
