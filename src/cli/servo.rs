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
use snakectl::servo::{baud_index, model_name, PingInfo, Register, ServoBus, BAUD_RATES, MAX_ID};

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
    /// Wait for replies beyond every id's slot (3 ms) and reply time, ms.
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
    /// The servo's present id, 0..=252.
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

fn open(port: &Path, baud: u32) -> Result<DynamixelBus, Failure> {
    connect::open_port(port, baud).map_err(|e: ConnectError| Failure::other(e))
}

/// A procedure's error: bad arguments are the user's, the rest the bus's.
fn admin_failure(e: AdminError) -> Failure {
    match e {
        AdminError::BadId(_) | AdminError::BadReturnDelay(_) | AdminError::IdTaken { .. } => {
            Failure::bad_input(e)
        }
        other => Failure::other(other),
    }
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
        return Err(Failure::bad_input(AdminError::BadId(args.id)));
    }
    let bauds: Vec<u32> = match args.baud {
        Some(b) => {
            check_baud(b)?;
            vec![b]
        }
        None => COMMON_BAUDS.to_vec(),
    };
    let mut bus = open(&args.port, bauds[0])?;
    match admin::find(&mut bus, args.id, &bauds, timeout) {
        Ok(info) => Ok((bus, info)),
        Err(e @ AdminError::NotFound { .. }) => Err(Failure::other(anyhow!(
            "{e} on {} (`snakectl scan --port {}` lists what does)",
            args.port.display(),
            args.port.display()
        ))),
        Err(e) => Err(admin_failure(e)),
    }
}

/// Runs `snakectl servo`.
pub fn run(args: ServoArgs) -> Result<(), Failure> {
    init_logging();
    let timeout = Duration::from_millis(args.timeout_ms);
    // Check the arguments before touching the bus.
    if args.id > MAX_ID {
        return Err(Failure::bad_input(anyhow!(
            "--id {} is out of range 0..=252 (253 is reserved, 254 is the broadcast id)",
            args.id
        )));
    }
    match args.action {
        ServoAction::SetId { new_id } if new_id > MAX_ID => {
            return Err(Failure::bad_input(anyhow!(
                "new id {new_id} is out of range 0..=252"
            )))
        }
        ServoAction::SetBaud { new_baud } => check_baud(new_baud)?,
        ServoAction::SetReturnDelay { us } if us > 508 || us % 2 != 0 => {
            return Err(Failure::bad_input(AdminError::BadReturnDelay(us)))
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
            if admin::set_id(&mut bus, id, new_id, timeout).map_err(admin_failure)? {
                outln!("servo {id}: now id {new_id}")?;
            } else {
                outln!("servo {id}: already id {id}")?;
            }
        }
        ServoAction::SetBaud { new_baud } => {
            admin::set_baud(&mut bus, id, new_baud, timeout, &RealClock).map_err(admin_failure)?;
            outln!("servo {id}: now at {new_baud} baud (set [bus] baud = {new_baud})")?;
        }
        ServoAction::SetReturnDelay { us } => {
            let back = admin::set_return_delay(&mut bus, id, us, timeout).map_err(admin_failure)?;
            outln!("servo {id}: Return Delay Time {back} µs")?;
        }
        ServoAction::ClearCalibration => {
            let (offset, drive) =
                admin::clear_calibration(&mut bus, id, timeout).map_err(admin_failure)?;
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
            let i = admin::info(&mut bus, id, timeout).map_err(admin_failure)?;
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
                .map_err(Failure::other)?;
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
