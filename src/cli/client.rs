//! The one-shot clients: `status`, `describe`, `goto`, `path`, `stop`, `estop`, `reset`, `home`,
//! `strategy`, `watch`. Each connects to the daemon's socket, does one thing and exits: 0 when
//! it was done, 2 for bad input found before connecting, 1 for anything the daemon refused or
//! that ended a motion short of its target (estop, fault, preemption, the daemon gone).
//!
//! A motion command waits for the event about its own request id; the daemon sends those to
//! the client that sent the command, and estops and faults to everyone.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::anyhow;
use clap::Args;
use serde_json::{Map, Value};
use snakectl::client::{Client, ClientError, EventInfo, Incoming, REPLY_TIMEOUT};
use snakectl::protocol::{Cmd, MAX_PATH_POINTS};
use snakectl::resolve::Strategy;

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

/// `path FILE.csv`.
#[derive(Debug, Args)]
pub struct PathArgs {
    /// CSV file, two columns `x,y` in metres, an optional header line.
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
    #[arg(long, default_value_t = 10.0)]
    pub rate_hz: f64,
    #[command(flatten)]
    pub connect: ConnectArgs,
}

/// `snakectl status`.
pub fn status(args: PlainArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    let fields = client.request(&Cmd::Status).map_err(refused)?;
    print_object(fields)
}

/// `snakectl describe`.
pub fn describe(args: PlainArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    let fields = client.request(&Cmd::Describe).map_err(refused)?;
    print_object(fields)
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

/// `snakectl path`.
pub fn path(args: PathArgs) -> Result<(), Failure> {
    let speed = check_speed(args.speed)?;
    let text = std::fs::read_to_string(&args.file)
        .map_err(|e| Failure::bad_input(anyhow!("{}: cannot read it: {e}", args.file.display())))?;
    let points = parse_points(&text)
        .map_err(|e| Failure::bad_input(anyhow!("{}:{e}", args.file.display())))?;
    let mut client = connect(&args.connect)?;
    motion(&mut client, &Cmd::Path { points, speed }, args.no_wait)
}

/// `snakectl stop`.
pub fn stop(args: PlainArgs) -> Result<(), Failure> {
    one_shot(&args.connect, &Cmd::Stop)
}

/// `snakectl estop`.
pub fn estop(args: PlainArgs) -> Result<(), Failure> {
    one_shot(&args.connect, &Cmd::Estop)
}

/// `snakectl reset`.
pub fn reset(args: PlainArgs) -> Result<(), Failure> {
    one_shot(&args.connect, &Cmd::Reset)
}

/// `snakectl home`.
pub fn home(args: HomeArgs) -> Result<(), Failure> {
    let mut client = connect(&args.connect)?;
    motion(&mut client, &Cmd::Home, args.no_wait)
}

/// `snakectl strategy`.
pub fn strategy(args: StrategyArgs) -> Result<(), Failure> {
    let name = match args.name.as_str() {
        "overall" => Strategy::Overall,
        "sequential" => Strategy::Sequential,
        other => {
            return Err(Failure::bad_input(anyhow!(
                "unknown strategy `{other}`: the strategies are `overall` and `sequential`"
            )))
        }
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
        // Events are not printed; reading them keeps the client's queue from filling.
        while let Ok(Some(_)) = client.next(Duration::ZERO) {}
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

/// Events kept while a motion command waits for its reply.
const EARLY_EVENTS: usize = 64;

/// Connects as `args` say.
fn connect(args: &ConnectArgs) -> Result<Client, Failure> {
    Client::connect_with(&args.connect, args.token_file.as_deref()).map_err(refused)
}

/// Exit code 1 with the client's error; a missing token gets a hint.
fn refused(e: ClientError) -> Failure {
    let unauthorized = match &e {
        ClientError::Refused { code, .. } => code == "unauthorized",
        ClientError::Closed { reason, .. } => reason
            .as_deref()
            .is_some_and(|r| r.starts_with("unauthorized")),
        _ => false,
    };
    let error = anyhow::Error::new(e);
    Failure::other(if unauthorized {
        error.context("the daemon wants its token: pass --token-file FILE")
    } else {
        error
    })
}

/// Prints a reply's fields as one JSON object on one line.
fn print_object(fields: Map<String, Value>) -> Result<(), Failure> {
    outln!("{}", Value::Object(fields))
}

/// `--speed`, which must be positive when given.
fn check_speed(speed: Option<f64>) -> Result<Option<f64>, Failure> {
    match speed {
        Some(v) if !(v.is_finite() && v > 0.0) => Err(Failure::bad_input(anyhow!(
            "--speed must be a positive number of m/s, not {v}"
        ))),
        speed => Ok(speed),
    }
}

/// The `tick` of a reply, 0 when it has none.
fn tick_of(fields: &Map<String, Value>) -> u64 {
    fields.get("tick").and_then(Value::as_u64).unwrap_or(0)
}

/// Sends `cmd`, prints `ok: CMD at tick N`.
fn one_shot(args: &ConnectArgs, cmd: &Cmd) -> Result<(), Failure> {
    let mut client = connect(args)?;
    let fields = client.request(cmd).map_err(refused)?;
    let what = match cmd {
        Cmd::Strategy { name } => format!("strategy {}", name.name()),
        cmd => cmd.name().to_owned(),
    };
    outln!("ok: {what} at tick {}", tick_of(&fields))
}

/// Sends a motion command; unless `no_wait`, waits for the event that ends it and prints where
/// the tip arrived. Anything else that ends it is an error naming why.
fn motion(client: &mut Client, cmd: &Cmd, no_wait: bool) -> Result<(), Failure> {
    let name = cmd.name();
    let id = client.send(cmd).map_err(refused)?;
    let gone = |e: ClientError| {
        Failure::other(anyhow::Error::new(e).context(format!("`{name}` did not finish")))
    };
    // Events that come before the reply are kept (a few): their order against it is not fixed.
    let mut early = Vec::with_capacity(EARLY_EVENTS);
    let deadline = Instant::now() + REPLY_TIMEOUT;
    let accepted = loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match client.next(left).map_err(refused)? {
            Some(Incoming::Reply(reply)) if reply.id.as_u64() == Some(id) || reply.id.is_null() => {
                match reply.result {
                    Ok(fields) => break tick_of(&fields),
                    Err((code, message)) => {
                        return Err(refused(ClientError::Refused {
                            cmd: name.to_owned(),
                            code,
                            message,
                        }))
                    }
                }
            }
            Some(Incoming::Reply(_)) => {}
            Some(Incoming::Event(event)) if early.len() < EARLY_EVENTS => early.push(event),
            Some(Incoming::Event(_)) => {}
            None if left.is_zero() => {
                return Err(refused(ClientError::Timeout {
                    cmd: name.to_owned(),
                    timeout: REPLY_TIMEOUT,
                }))
            }
            None => {}
        }
    };
    if no_wait {
        return outln!("ok: {name} accepted at tick {accepted}");
    }
    for event in early {
        if let Some(end) = ending(&event, id, accepted) {
            return end.map_or_else(|e| Err(Failure::other(e)), |line| outln!("{line}"));
        }
    }
    loop {
        if let Some(event) = client.next_event(Duration::from_secs(3600)).map_err(gone)? {
            if let Some(end) = ending(&event, id, accepted) {
                return end.map_or_else(|e| Err(Failure::other(e)), |line| outln!("{line}"));
            }
        }
    }
}

/// Whether `event` ends the command with request id `id`, accepted at tick `accepted`: the
/// line to print for an arrival, or the error for anything else.
fn ending(event: &EventInfo, id: u64, accepted: u64) -> Option<Result<String, anyhow::Error>> {
    let [x, y] = event.tip;
    let at = format!("({x:.4}, {y:.4}) m, tick {}", event.tick);
    let reason = event.reason.as_deref().unwrap_or("unknown");
    let ours = event.cmd_id.as_ref().and_then(Value::as_u64) == Some(id);
    let result = match event.event.as_str() {
        "arrived" if ours => Ok(format!("arrived at {at}")),
        "saturated" if ours => Err(anyhow!(
            "saturated: the target is out of reach; the tip stopped short at {at}"
        )),
        "preempted" if ours => Err(anyhow!("preempted by `{reason}` at {at}")),
        "stopped" if ours => Err(anyhow!("stopped ({reason}) at {at}")),
        // Events for everyone: only those from the command's time on concern it.
        "estop" if event.tick >= accepted => Err(anyhow!("estop: emergency stop at {at}")),
        "fault" if event.tick >= accepted && reason == "raised" => {
            let what = event
                .fault
                .as_ref()
                .map_or_else(|| "unknown".to_owned(), ToString::to_string);
            Err(anyhow!("fault: {what}, at {at}"))
        }
        _ => return None,
    };
    Some(result)
}

/// Why a CSV line is not a point.
#[derive(Debug, PartialEq)]
enum RowError {
    /// Not two comma-separated fields.
    Fields(usize),
    /// A field that is no number.
    NotNumber(String),
    /// A number that is not finite.
    NotFinite(String),
}

impl std::fmt::Display for RowError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RowError::Fields(n) => write!(f, "expected two fields `x,y`, got {n}"),
            RowError::NotNumber(s) => write!(f, "`{s}` is not a number"),
            RowError::NotFinite(s) => write!(f, "`{s}` is not a finite number"),
        }
    }
}

/// One row `x,y`.
fn parse_row(line: &str) -> Result<[f64; 2], RowError> {
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    let [x, y] = fields[..] else {
        return Err(RowError::Fields(fields.len()));
    };
    let number = |s: &str| match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(RowError::NotFinite(s.to_owned())),
        Err(_) => Err(RowError::NotNumber(s.to_owned())),
    };
    Ok([number(x)?, number(y)?])
}

/// The points of a path CSV: blank lines skipped, the first line a header when none of its
/// fields is a number. Errors read `LINE: what` (or `: what` for the file as a whole).
fn parse_points(text: &str) -> Result<Vec<[f64; 2]>, String> {
    let mut points = Vec::new();
    let mut first = true;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim_start_matches('\u{feff}').trim();
        if line.is_empty() {
            continue;
        }
        let header = first && line.split(',').all(|f| f.trim().parse::<f64>().is_err());
        first = false;
        if header {
            continue;
        }
        points.push(parse_row(line).map_err(|e| format!("{}: {e}", i + 1))?);
        if points.len() > MAX_PATH_POINTS {
            return Err(format!(
                "{}: too many points: a path has at most {MAX_PATH_POINTS}",
                i + 1
            ));
        }
    }
    if points.is_empty() {
        return Err(" no points: expected lines `x,y` in metres".to_owned());
    }
    Ok(points)
}
