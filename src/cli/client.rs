//! The one-shot clients: `status`, `describe`, `goto`, `path`, `stop`, `estop`, `reset`, `home`,
//! `strategy`, `watch` (and `world`, in its own module). Each connects to the daemon's socket, does one thing and exits: 0 when
//! it was done, 2 for bad input found before connecting, 1 for anything the daemon refused or
//! that ended a motion short of its target (estop, fault, preemption, the daemon gone).
//!
//! A motion command waits for its ending as the client library tells it
//! ([`Client::start_motion`], [`Client::wait_ending`]): the event about its own request id
//! (the daemon sends those to the client that sent the command), or an estop or a fault (sent
//! to everyone).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::anyhow;
use clap::Args;
use serde_json::Value;
use snakectl::client::{Client, ClientError, CmdName, Ending, Fields};
use snakectl::protocol::{
    strategy_named, Cmd, Code, FaultKind, Reply, MAX_PATH_POINTS, MIN_SPEED_M_S, STRATEGIES,
};
use snakectl::textfile::{parse_points, read_text, MAX_TEXT_BYTES};

use super::{outln, Failure};

/// Where the daemon is and how to get in: every client takes these.
#[derive(Debug, Clone, Args)]
pub struct ConnectArgs {
    /// The daemon's address, `host:port`.
    #[arg(long, value_name = "ADDR", default_value = snakectl::client::DEFAULT_ADDR)]
    pub connect: String,
    /// A file whose first line is the daemon's token (`[server] token_file`).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
}

/// Arguments of the commands that take nothing else.
#[derive(Debug, Args)]
pub struct PlainArgs {
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `reboot [ID...]`.
#[derive(Debug, Args)]
pub struct RebootArgs {
    /// The servos to reboot (default: those in hardware error, else every one).
    pub ids: Vec<u8>,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `goto X Y`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct GotoArgs {
    /// Target x, m (world frame).
    pub x: f64,
    /// Target y, m.
    pub y: f64,
    /// Tip speed, m/s (default: the daemon's tip speed limit).
    #[arg(long)]
    pub speed: Option<f64>,
    /// Return once the daemon has accepted the command, without waiting for the arrival.
    #[arg(long)]
    pub no_wait: bool,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `reach X Y`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct ReachArgs {
    /// Target x, m (world frame).
    pub x: f64,
    /// Target y, m.
    pub y: f64,
    /// Return once the daemon has accepted the command (its way planned), without waiting for
    /// the arrival.
    #[arg(long)]
    pub no_wait: bool,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `path FILE.csv`.
#[derive(Debug, Args)]
pub struct PathArgs {
    /// CSV file, two columns `x,y` in metres, an optional header line (`#` lines skipped).
    pub file: PathBuf,
    /// Tip speed, m/s (default: the daemon's tip speed limit).
    #[arg(long)]
    pub speed: Option<f64>,
    /// Return once the daemon has accepted the command, without waiting for the arrival.
    #[arg(long)]
    pub no_wait: bool,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `home`.
#[derive(Debug, Args)]
pub struct HomeArgs {
    /// Return once the daemon has accepted the command, without waiting for the arrival.
    #[arg(long)]
    pub no_wait: bool,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `strategy NAME`.
#[derive(Debug, Args)]
pub struct StrategyArgs {
    /// `overall` or `sequential`.
    pub name: String,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `watch`.
#[derive(Debug, Args)]
pub struct WatchArgs {
    /// Telemetry lines per second.
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true)]
    pub rate_hz: f64,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `snakectl status`.
pub fn status(args: PlainArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    let fields = client.request(&Cmd::Status).map_err(refused)?;
    print_object(&fields)
}

/// `snakectl describe`.
pub fn describe(args: PlainArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    let fields = client.request(&Cmd::Describe).map_err(refused)?;
    print_object(&fields)
}

/// `snakectl goto`.
pub fn goto(args: GotoArgs) -> Result<(), Failure> {
    for (name, value) in [("X", args.x), ("Y", args.y)] {
        if !value.is_finite() {
            return Err(Failure::bad_input(anyhow!(
                "{name} must be a finite number of metres, not {value}"
            )));
        }
    }
    let speed = check_speed(args.speed)?;
    let mut client = connect(&args.connect)?;
    let cmd = Cmd::Goto {
        target: [args.x, args.y],
        speed,
    };
    motion(&mut client, &cmd, args.no_wait)
}

/// `snakectl reach`.
pub fn reach(args: ReachArgs) -> Result<(), Failure> {
    for (name, value) in [("X", args.x), ("Y", args.y)] {
        if !value.is_finite() {
            return Err(Failure::bad_input(anyhow!(
                "{name} must be a finite number of metres, not {value}"
            )));
        }
    }
    let mut client = connect(&args.connect)?;
    let cmd = Cmd::Reach {
        target: [args.x, args.y],
    };
    motion(&mut client, &cmd, args.no_wait)
}

/// `snakectl path`.
pub fn path(args: PathArgs) -> Result<(), Failure> {
    let speed = check_speed(args.speed)?;
    let text = read_text(&args.file, MAX_TEXT_BYTES)
        .map_err(|e| Failure::bad_input(anyhow!("{}: cannot read it: {e}", args.file.display())))?;
    let points: Vec<[f64; 2]> = parse_points(&text)
        .map_err(|e| Failure::bad_input(anyhow!("{}", e.in_file(args.file.display()))))?
        .iter()
        .map(|p| p.xy)
        .collect();
    // Refused here rather than by the daemon: every path up to the limit fits in one request
    // line, so this is the only size check a path needs.
    if points.len() > MAX_PATH_POINTS {
        return Err(Failure::bad_input(anyhow!(
            "{}: {} points, over the limit of {MAX_PATH_POINTS} points a path may have",
            args.file.display(),
            points.len()
        )));
    }
    let mut client = connect(&args.connect)?;
    motion(&mut client, &Cmd::Path { points, speed }, args.no_wait)
}

/// `snakectl stop`.
pub fn stop(args: PlainArgs) -> Result<(), Failure> {
    one_shot(&args.connect, &Cmd::Stop)
}

/// `snakectl estop`. The latch is set whatever the servos say; a servo whose torque off was not confirmed
/// makes it exit 1, naming each.
pub fn estop(args: PlainArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    let fields = client.request(&Cmd::Estop).map_err(refused)?;
    let tick = fields.reply.tick().unwrap_or(0);
    match &fields.reply {
        Reply::TorqueOff(off) if !off.unconfirmed.is_empty() => {
            let each: Vec<String> = off.unconfirmed.iter().map(ToString::to_string).collect();
            Err(Failure::other(anyhow!(
                "estop latched at tick {tick}, but torque off was not confirmed: {}; the daemon \
                 sends it again when they answer",
                each.join("; ")
            )))
        }
        _ => outln!("ok: estop at tick {tick}"),
    }
}

/// `snakectl reset`. It clears the estop latch (and a servo that lost power or a joint in
/// contact, which latch it), not a servo's hardware error: when one still holds the arm, a
/// note on stderr says so and what clears it.
pub fn reset(args: PlainArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    let fields = client.request(&Cmd::Reset).map_err(refused)?;
    outln!("ok: reset at tick {}", fields.reply.tick().unwrap_or(0))?;
    if let Ok(status) = client.status() {
        let held: Vec<String> = status
            .faults
            .iter()
            .filter(|f| f.kind == FaultKind::HardwareError)
            .filter_map(|f| f.id.map(|id| id.to_string()))
            .collect();
        if !held.is_empty() {
            eprintln!(
                "snakectl: note: a hardware error still holds the arm (servo {}); `snakectl \
                 reboot` clears it",
                held.join(", ")
            );
        }
    }
    Ok(())
}

/// `snakectl reboot [ID...]`: the reply comes once the servos have booted; it names them.
pub fn reboot(args: RebootArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    let ids = (!args.ids.is_empty()).then(|| args.ids.clone());
    let fields = client.request(&Cmd::Reboot { ids }).map_err(refused)?;
    let rebooted = fields
        .to_map()
        .get("rebooted")
        .map_or_else(|| "[]".to_owned(), Value::to_string);
    outln!(
        "ok: rebooted {rebooted} at tick {}",
        fields.reply.tick().unwrap_or(0)
    )
}

/// `snakectl home`.
pub fn home(args: HomeArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    motion(&mut client, &Cmd::Home, args.no_wait)
}

/// `snakectl strategy`.
pub fn strategy(args: StrategyArgs) -> Result<(), Failure> {
    let Some(name) = strategy_named(&args.name) else {
        let names: Vec<String> = STRATEGIES
            .iter()
            .map(|s| format!("`{}`", s.name()))
            .collect();
        return Err(Failure::bad_input(anyhow!(
            "unknown strategy `{}`: the strategies are {}",
            args.name,
            names.join(" and ")
        )));
    };
    one_shot(&args.connect, &Cmd::Strategy { name })
}

/// `snakectl watch`.
pub fn watch(args: WatchArgs) -> Result<(), Failure> {
    if !(args.rate_hz.is_finite() && args.rate_hz > 0.0) {
        return Err(Failure::bad_input(anyhow!(
            "--rate-hz must be a positive number of lines per second, not {}",
            args.rate_hz
        )));
    }
    // Installed before connecting: Ctrl-C from then on ends the loop below, with exit code 0.
    let interrupted = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&interrupted))
            .map_err(|e| Failure::other(anyhow!("installing the signal handler: {e}")))?;
    }
    let mut client = connect(&args.connect)?;
    client
        .request(&Cmd::Subscribe {
            rate_hz: args.rate_hz,
        })
        .map_err(refused)?;
    while !interrupted.load(Ordering::Relaxed) {
        // Events are not printed; reading them keeps the client's queue from filling. A line
        // that does not read is told, and the watch goes on.
        loop {
            match client.next(Duration::ZERO) {
                Ok(Some(_)) => {}
                Ok(None) => break,
                Err(e) if e.is_closed() => break,
                Err(e) => eprintln!("snakectl: {e}"),
            }
        }
        match client.wait_telemetry(POLL) {
            Ok(Some(telemetry)) => outln!("{}", telemetry.line)?,
            Ok(None) => {}
            Err(e) => {
                return Err(Failure::other(
                    anyhow::Error::new(e).context("the daemon went away"),
                ))
            }
        }
    }
    Ok(())
}

/// How often the waiting loops look at the Ctrl-C flag.
const POLL: Duration = Duration::from_millis(100);

/// How long a motion command is waited for: as long as it takes.
const FOREVER: Duration = Duration::MAX;

/// Connects as `args` say.
pub(super) fn connect(args: &ConnectArgs) -> Result<Client, Failure> {
    Client::connect_with(&args.connect, args.token_file.as_deref()).map_err(|e| {
        match (&e, &args.token_file) {
            // A token was passed and refused: the wrong one, not a missing one.
            (
                ClientError::Refused {
                    cmd: CmdName::Auth, ..
                },
                Some(file),
            ) => Failure::other(anyhow::Error::new(e).context(format!(
                "the daemon refused the token in {}",
                file.display()
            ))),
            // Found before connecting: bad input.
            (
                ClientError::TokenFile { .. }
                | ClientError::EmptyToken { .. }
                | ClientError::BlankFirstLine { .. },
                _,
            ) => Failure::bad_input(e),
            // Not an address at all (a path, no port, a port past 65535): bad input too.
            (ClientError::Connect { source, .. }, _)
                if source.kind() == std::io::ErrorKind::InvalidInput =>
            {
                let connect = args.connect.clone();
                Failure::bad_input(anyhow::Error::new(e).context(format!(
                    "--connect {connect:?} is not the daemon's TCP address: give host:port, \
                     e.g. {}",
                    snakectl::client::DEFAULT_ADDR
                )))
            }
            _ => refused(e),
        }
    })
}

/// Exit code 1 with the client's error; a missing token gets a hint.
pub(super) fn refused(e: ClientError) -> Failure {
    let unauthorized = e.code() == Some(Code::Unauthorized);
    let error = anyhow::Error::new(e);
    Failure::other(if unauthorized {
        error.context("the daemon wants its token: pass --token-file FILE")
    } else {
        error
    })
}

/// Prints a reply's fields (every one that came) as one JSON object on one line.
fn print_object(fields: &Fields) -> Result<(), Failure> {
    outln!("{}", Value::Object(fields.to_map()))
}

/// `--speed`, which must be positive (at least the daemon's least) when given.
fn check_speed(speed: Option<f64>) -> Result<Option<f64>, Failure> {
    match speed {
        Some(v) if !(v.is_finite() && v > 0.0) => Err(Failure::bad_input(anyhow!(
            "--speed must be a positive number of m/s, not {v}"
        ))),
        Some(v) if v < MIN_SPEED_M_S => Err(Failure::bad_input(anyhow!(
            "--speed {v:e} m/s is below the least, {MIN_SPEED_M_S:e} m/s"
        ))),
        speed => Ok(speed),
    }
}

/// Sends `cmd`, prints `ok: CMD at tick N`.
fn one_shot(args: &ConnectArgs, cmd: &Cmd) -> Result<(), Failure> {
    let mut client = connect(args)?;
    let fields = client.request(cmd).map_err(refused)?;
    let what = match cmd {
        Cmd::Strategy { name } => format!("strategy {}", name.name()),
        cmd => cmd.name().to_string(),
    };
    outln!("ok: {what} at tick {}", fields.reply.tick().unwrap_or(0))
}

/// Sends a motion command; unless `no_wait`, waits for its ending and prints where the tip
/// arrived. Anything else that ends it is an error naming why.
fn motion(client: &mut Client, cmd: &Cmd, no_wait: bool) -> Result<(), Failure> {
    let name = cmd.name();
    let motion = client.start_motion(cmd).map_err(refused)?;
    if no_wait {
        return outln!("ok: {name} accepted at tick {}", motion.accepted);
    }
    let ending = client
        .wait_ending(&motion, FOREVER, |_| Ok(()))
        .map_err(|e: ClientError| {
            Failure::other(anyhow::Error::new(e).context(format!("`{name}` did not finish")))
        })?;
    match ending {
        Some(arrived @ Ending::Arrived { .. }) => outln!("{arrived}"),
        // Caught on an obstacle: the way out is a way round in joint space.
        Some(blocked @ Ending::Blocked { .. }) => match cmd {
            Cmd::Goto { target: [x, y], .. } => Err(Failure::other(anyhow!(
                "{blocked}; `snakectl reach {x} {y}` plans a way round the obstacles"
            ))),
            _ => Err(Failure::other(anyhow!("{blocked}"))),
        },
        Some(other) => Err(Failure::other(anyhow!("{other}"))),
        None => Err(Failure::other(anyhow!("`{name}` did not finish"))),
    }
}
