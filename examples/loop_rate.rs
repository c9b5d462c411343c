//! The daemon's loop on the simulated arm: achieved rate, tick time, overruns and
//! command-to-wire latency at fixed rates without wire timing (12 servos), then the wire table:
//! with wire timing, for 12 and 24 servos, 1 and 4 Mbps, one and two ports, each read kind and
//! adapter model the config can name, the wire bound (`snakectl::servo::wire`), the highest
//! rate held for 10 s without an overrun, and their ratio.
//!
//! `cargo run --release --example loop_rate [-- SECONDS]` (default 5 s per fixed rate).
//!
//! `cargo run --release --example loop_rate -- SECONDS --wire` runs the wire table alone.
//!
//! `cargo run --release --example loop_rate -- SECONDS --wire-row 12 1000000 1 fast none` runs
//! one row of it (servos, baud, ports, `sync` or `fast`, adapter `none` or `ftdi`), and each
//! rate it tries on stderr.
//!
//! `--realtime 50` after `--wire` or a `--wire-row` row runs the loop under `SCHED_FIFO` at that
//! priority (`[control] realtime_priority`; root or `CAP_SYS_NICE`).
//!
//! `cargo run --release --example loop_rate -- SECONDS --jitter` measures how late this machine
//! wakes a sleeping thread, which the held rates of the wire table are to be read against.
//!
//! `cargo run --release --example loop_rate -- SECONDS --busy [SERVOS BAUD PORTS READ ADAPTER]`
//! runs one row of the wire table (default `12 1000000 1 sync none`) four ways: on the idle
//! machine and beside one busy thread per core (at the normal policy, as a build or a viewer
//! would be), each with the loop at the normal policy and under `SCHED_FIFO`
//! (`[control] realtime_priority = 50`, which needs root or `CAP_SYS_NICE`; the simulated
//! servos then run under it too, as hardware does not wait for a core).
//!
//! `cargo run --release --example loop_rate -- SECONDS --obstacles` instead runs the fixed rates
//! without wire timing twice, with no obstacles and with 16 small discs near the arm (each
//! link's middle, 5 cm to alternate sides), one after the other.
//!
//! `cargo run --release --features zenoh --example loop_rate -- SECONDS --zenoh` instead runs
//! each fixed rate twice, without and with the daemon on a Zenoh network (publishing at the
//! default rate on the plain keys and, as a ROS 2 node, on rmw_zenoh's, to a peer subscribed
//! to every key that listens and that the daemon connects to), one after the other.
//!
//! `cargo run --release --example loop_rate -- SECONDS --foxglove` instead runs each fixed
//! rate twice, without and with the Foxglove view on (at its default rate), one Foxglove client
//! reading every channel and another subscribed to every channel that never reads.
//!
//! `cargo run --release --example loop_rate -- SECONDS --record` instead runs each fixed rate
//! twice, without and with the run recorded to an MCAP file (every tick's `JointState`, tips
//! and telemetry, in a temporary directory), one after the other, and says what the recording
//! wrote and dropped.
//!
//! A client streams `velocity` commands at 20 Hz (a figure eight, as a joystick would) while
//! the loop runs; the first half second of each run is left out of the figures
//! (`reset_stats`).

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use snakectl::chain::Vec2;
use snakectl::config::{Config, MAX_RATE_HZ};
use snakectl::connect;
use snakectl::daemon::{Embedded, RunOptions, Summary};
use snakectl::record::{RecordOptions, Recording};
use snakectl::servo::clock::{Clock, RealClock};
use snakectl::servo::wire::{bound_of_ports, Adapter, Bound, ReadKind};

const WARM_UP: Duration = Duration::from_millis(500);

fn config(rate_hz: f64, wire_timing: bool, zenoh_port: Option<u16>) -> Result<Config> {
    config_with(rate_hz, wire_timing, zenoh_port, 0)
}

/// [`config`], with `obstacles` small discs near the arm's home pose.
fn config_with(
    rate_hz: f64,
    wire_timing: bool,
    zenoh_port: Option<u16>,
    obstacles: usize,
) -> Result<Config> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    let mut text = std::fs::read_to_string(path)?;
    if obstacles > 0 {
        let plain = Config::from_str(&text, path)?;
        let p = plain.chain().points(plain.home());
        let links = p.len() - 1;
        text.push_str("\n[world]\n");
        for k in 0..obstacles {
            // Link by link, then again further out: 5 cm, then 8 cm, to alternate sides.
            let link = k % links;
            let (a, b) = (p[link], p[link + 1]);
            let along = (b - a).normalize();
            let side = if k % 2 == 0 { 1.0 } else { -1.0 };
            let off = if k < links { 0.05 } else { 0.08 };
            let c = (a + b) / 2.0 + Vec2::new(-along.y, along.x) * (side * off);
            text.push_str(&format!(
                "[[world.obstacle]]\nid = \"disc{k}\"\ncircle = {{ center_m = [{:.6}, {:.6}], radius_m = 0.01 }}\n",
                c.x, c.y
            ));
        }
    }
    if let Some(port) = zenoh_port {
        // The peer listens there, ready before the daemon starts: the daemon's session connects
        // at once (a peer connecting to a daemon not yet listening would retry a second later,
        // Zenoh's default, and miss that second's samples).
        text.push_str(&format!(
            "\n[zenoh]\nenabled = true\nconnect = [\"tcp/127.0.0.1:{port}\"]\nros2 = true\n"
        ));
    }
    let text = text
        .replace("rate_hz = 100.0", &format!("rate_hz = {rate_hz:.1}"))
        .replace(
            "wire_timing = false",
            &format!("wire_timing = {wire_timing}"),
        );
    Ok(Config::from_str(&text, path)?)
}

/// Sends one request line and returns its reply, skipping event lines.
fn exchange(stream: &mut BufReader<TcpStream>, line: &str) -> Result<String> {
    stream.get_mut().write_all(line.as_bytes())?;
    stream.get_mut().write_all(b"\n")?;
    loop {
        let mut reply = String::new();
        if stream.read_line(&mut reply)? == 0 {
            bail!("the daemon closed the connection");
        }
        if !reply.contains("\"type\"") {
            return Ok(reply);
        }
    }
}

/// [`exchange`], for a request that must succeed.
fn request(stream: &mut BufReader<TcpStream>, line: &str) -> Result<String> {
    let reply = exchange(stream, line)?;
    if !reply.contains("\"ok\":true") {
        bail!("{line} -> {reply}");
    }
    Ok(reply)
}

/// What one run measured, and whether the arm went to `fault` (a rate the bus cannot carry
/// loses replies until the error budget runs out).
struct Measured {
    summary: Summary,
    fault: bool,
}

/// Runs the daemon at `rate_hz` for `seconds` under a streamed figure eight.
fn run(rate_hz: f64, wire_timing: bool, seconds: f64) -> Result<Measured> {
    run_with(rate_hz, wire_timing, seconds, None)
}

/// [`run`], on a Zenoh network listening on `zenoh_port` when given.
fn run_with(
    rate_hz: f64,
    wire_timing: bool,
    seconds: f64,
    zenoh_port: Option<u16>,
) -> Result<Measured> {
    run_config(config(rate_hz, wire_timing, zenoh_port)?, rate_hz, seconds)
}

/// Runs the daemon of `config` (at `rate_hz`) for `seconds` under a streamed figure eight.
fn run_config(config: Config, rate_hz: f64, seconds: f64) -> Result<Measured> {
    run_recorded(config, rate_hz, seconds, None)
}

/// [`run_config`], the run recorded as `record` says.
fn run_recorded(
    config: Config,
    rate_hz: f64,
    seconds: f64,
    record: Option<RecordOptions>,
) -> Result<Measured> {
    // The simulators stand in for the servos, which do not wait for a core: under the loop's
    // real-time policy when it has one (started by a thread that took it, they inherit it).
    let priority = config.control().realtime_priority;
    let for_sims = config.clone();
    let sims = std::thread::spawn(move || -> Result<_> {
        if let Some(p) = priority {
            snakectl::beside::realtime(p)?;
        }
        Ok(connect::spawn_sims(
            &for_sims,
            Arc::new(snakectl_sim::RealClock),
        )?)
    })
    .join()
    .map_err(|_| anyhow::anyhow!("the thread starting the simulators panicked"))??;
    let options = RunOptions {
        ports: sims.iter().map(|s| s.path().to_path_buf()).collect(),
        record,
    };
    let daemon = Embedded::start(config, ([127, 0, 0, 1], 0).into(), options)?;
    let addr = daemon.addr();

    let stream = TcpStream::connect(addr)?;
    stream.set_nodelay(true)?;
    let mut client = BufReader::new(stream);
    request(&mut client, r#"{"cmd":"status"}"#)?;
    let start = Instant::now();
    let mut warm = false;
    let mut k = 0u32;
    let mut fault = false;
    while start.elapsed().as_secs_f64() < seconds + WARM_UP.as_secs_f64() {
        if !warm && start.elapsed() >= WARM_UP {
            request(&mut client, r#"{"cmd":"reset_stats"}"#)?;
            warm = true;
        }
        // A figure eight of 0.03 m tip speed, period 4 s.
        let t = f64::from(k) * 0.05;
        let w = std::f64::consts::TAU / 4.0;
        let (vx, vy) = (0.03 * (w * t).cos(), 0.03 * (2.0 * w * t).cos());
        let line = format!(r#"{{"cmd":"velocity","v":[{vx:.6},{vy:.6}]}}"#);
        let reply = exchange(&mut client, &line)?;
        if reply.contains(r#""code":"fault""#) {
            fault = true;
            break;
        }
        if !reply.contains(r#""ok":true"#) {
            bail!("{line} -> {reply}");
        }
        k += 1;
        // 50 ms plus a share of a period that walks around the tick (golden-ratio steps), so
        // commands arrive at every phase of the loop instead of locking onto one.
        let phase = (f64::from(k) * 0.618_034).fract() / rate_hz;
        std::thread::sleep(Duration::from_millis(50) + Duration::from_secs_f64(phase));
    }
    exchange(&mut client, r#"{"cmd":"stop"}"#)?;
    let summary = daemon.stop()?;
    drop(sims);
    Ok(Measured { summary, fault })
}

fn row(rate_hz: f64, m: &Measured) {
    println!("| {rate_hz:.0} | {}", cells(m));
}

/// A run's columns after the rate, each closed by `|`.
fn cells(m: &Measured) -> String {
    let s = &m.summary;
    let held = if m.fault { ", then `fault`" } else { "" };
    format!(
        "{:.1} | {:.0} / {:.0} | {}{held} | {:.0} / {:.0} | {:.0} / {:.0} |",
        s.rate_hz(),
        s.tick.p50_us,
        s.tick.p99_us,
        s.overruns,
        s.command_to_wire.p50_us,
        s.command_to_wire.p99_us,
        s.solve.p50_us,
        s.solve.p99_us,
    )
}

fn main() -> Result<()> {
    let seconds: f64 = match std::env::args().nth(1) {
        Some(s) => s.parse().context("seconds per rate")?,
        None => 5.0,
    };
    if !(seconds > 0.0 && seconds.is_finite()) {
        bail!("seconds per rate: a positive number, not {seconds}");
    }
    if std::env::args().nth(2).as_deref() == Some("--zenoh") {
        return with_zenoh::table(seconds);
    }
    if std::env::args().nth(2).as_deref() == Some("--foxglove") {
        // `--foxglove --record`: the view on and the run recorded at once.
        let record = std::env::args().nth(3).as_deref() == Some("--record");
        return with_foxglove::table(seconds, record);
    }
    if std::env::args().nth(2).as_deref() == Some("--obstacles") {
        println!("Without wire timing, {seconds} s per rate, with 0 and 16 obstacles:\n");
        println!("| rate, Hz | obstacles | achieved, Hz | tick p50 / p99, µs | overruns | command to wire p50 / p99, µs | solve p50 / p99, µs |");
        println!("|---|---|---|---|---|---|---|");
        for rate in [100.0, 500.0, 1000.0] {
            for obstacles in [0, 16] {
                let config = config_with(rate, false, None, obstacles)?;
                let m = run_config(config, rate, seconds)?;
                println!("| {rate:.0} | {obstacles} | {}", cells(&m));
            }
        }
        return Ok(());
    }
    if std::env::args().nth(2).as_deref() == Some("--wire") {
        return wire_table(&ROWS_READ, &ROWS_ADAPTER, realtime_arg()?);
    }
    if std::env::args().nth(2).as_deref() == Some("--record") {
        return record_table(seconds);
    }
    if std::env::args().nth(2).as_deref() == Some("--jitter") {
        return jitter(seconds);
    }
    if std::env::args().nth(2).as_deref() == Some("--wire-row") {
        let args: Vec<String> = std::env::args().skip(3).take(5).collect();
        let row = Row {
            realtime: realtime_arg()?,
            ..Row::parse(&args)?
        };
        println!("{}", wire_row(&row)?);
        return Ok(());
    }
    if std::env::args().nth(2).as_deref() == Some("--busy") {
        let args: Vec<String> = std::env::args().skip(3).collect();
        let row = if args.is_empty() {
            Row {
                realtime: None,
                servos: 12,
                baud: 1_000_000,
                ports: 1,
                read: ReadKind::Sync,
                adapter: None,
            }
        } else {
            Row::parse(&args)?
        };
        return busy(row);
    }
    println!("Without wire timing, {seconds} s per rate:\n");
    println!("| rate, Hz | achieved, Hz | tick p50 / p99, µs | overruns | command to wire p50 / p99, µs | solve p50 / p99, µs |");
    println!("|---|---|---|---|---|---|");
    for rate in [100.0, 500.0, 1000.0] {
        row(rate, &run(rate, false, seconds)?);
    }

    wire_table(&ROWS_READ, &ROWS_ADAPTER, None)
}

/// The priority after `--realtime`, if given.
fn realtime_arg() -> Result<Option<u8>> {
    let args: Vec<String> = std::env::args().collect();
    match args.iter().position(|a| a == "--realtime") {
        None => Ok(None),
        Some(i) => {
            let p = args
                .get(i + 1)
                .context("--realtime takes a priority, 1 to 99")?;
            Ok(Some(p.parse().context("--realtime: a priority, 1 to 99")?))
        }
    }
}

/// How late this machine wakes a thread: for `seconds` each, a lone thread asks to sleep
/// [`JITTER_NAP`] and measures how much longer it slept, three ways: a plain sleep at the
/// default timer slack, the same with the loop's sharp timers
/// ([`snakectl::servo::clock::sharp_timers`]), and the loop's own wait for its period (sharp timers
/// and [`Clock::sleep_until`]'s spin tail). A tick of a wire-timed loop waits on a dozen
/// such wake-ups (the simulator's replies, the loop's reads), so this bounds how close to the
/// wire bound a rate can hold with under 0.5% of its ticks late.
fn jitter(seconds: f64) -> Result<()> {
    for (label, sharp, until) in [
        ("plain sleep", false, false),
        ("sharp timers", true, false),
        ("sharp timers, spin tail", true, true),
    ] {
        let late_us = std::thread::spawn(move || {
            if sharp && !snakectl::servo::clock::sharp_timers() {
                return None;
            }
            Some(naps(seconds, until))
        })
        .join()
        .map_err(|_| anyhow::anyhow!("the jitter thread panicked"))?;
        let Some(late_us) = late_us else {
            println!("{label}: the timer slack could not be set");
            continue;
        };
        let n = late_us.len();
        let q = |f: f64| late_us[((n as f64 * f) as usize).min(n - 1)];
        let over = |us: f64| late_us.iter().filter(|&&l| l > us).count();
        println!(
            "{label}: {n} sleeps of {} µs: late by p50 {:.0} / p99 {:.0} / p99.5 {:.0} / p99.9 {:.0} / max {:.0} µs; \
             over 0.5 ms: {}, over 1 ms: {}, over 2 ms: {}",
            JITTER_NAP.as_micros(),
            q(0.5),
            q(0.99),
            q(0.995),
            q(0.999),
            late_us[n - 1],
            over(500.0),
            over(1000.0),
            over(2000.0),
        );
    }
    Ok(())
}

/// [`JITTER_NAP`]s for `seconds`, by a plain sleep or by [`Clock::sleep_until`] (`until`): how
/// late each woke, µs, sorted.
fn naps(seconds: f64, until: bool) -> Vec<f64> {
    let mut late_us = Vec::new();
    let end = Instant::now() + Duration::from_secs_f64(seconds);
    while Instant::now() < end {
        let t = Instant::now();
        if until {
            RealClock.sleep_until(t + JITTER_NAP);
        } else {
            std::thread::sleep(JITTER_NAP);
        }
        late_us.push(t.elapsed().saturating_sub(JITTER_NAP).as_secs_f64() * 1e6);
    }
    late_us.sort_by(f64::total_cmp);
    late_us
}

/// The sleep [`jitter`] asks for.
const JITTER_NAP: Duration = Duration::from_micros(500);

/// Each fixed rate without and with a recording: the loop's figures, and what the recording
/// holds (messages per tick run) and dropped.
fn record_table(seconds: f64) -> Result<()> {
    println!("Without wire timing, {seconds} s per rate, without and with a recording:\n");
    println!("| rate, Hz | recording | achieved, Hz | tick p50 / p99, µs | overruns | command to wire p50 / p99, µs | solve p50 / p99, µs | messages written / dropped | file, MB |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let dir = std::env::temp_dir().join(format!("snakectl-loop-rate-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    for rate in [100.0, 500.0, 1000.0] {
        for recorded in [false, true] {
            let path = dir.join(format!("run-{rate:.0}.mcap"));
            let record = recorded.then(|| RecordOptions::to(&path));
            let m = run_recorded(config(rate, false, None)?, rate, seconds, record)?;
            let tail = if recorded {
                let recording = Recording::open(&path)?;
                let written: usize = recording.channels.values().map(|c| c.messages.len()).sum();
                let dropped: u64 = recording
                    .metadata("snakectl.recording")
                    .into_iter()
                    .flat_map(|m| m.values())
                    .filter_map(|v| serde_json::from_str::<serde_json::Value>(v).ok())
                    .filter_map(|v| v["dropped"].as_u64())
                    .sum();
                let mb = std::fs::metadata(&path)?.len() as f64 / 1e6;
                format!(" {written} / {dropped} | {mb:.1} |")
            } else {
                " | |".to_owned()
            };
            println!(
                "| {rate:.0} | {} | {}{tail}",
                if recorded { "on" } else { "off" },
                cells(&m)
            );
        }
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}

/// How the read kinds and adapter models of the wire table's rows are spelled in a config,
/// beside the shipped `[bus]` and `[sim]`: the rows that exist are those whose settings the
/// config takes.
const ROWS_READ: [ReadKind; 2] = [ReadKind::Sync, ReadKind::Fast];
/// The adapter models of the wire table (`None`: bytes reach the host as they arrive).
const ROWS_ADAPTER: [Option<Adapter>; 2] = [None, Some(Adapter::FTDI_1MS)];

/// One row of the wire table: the arm and its bus.
#[derive(Debug, Clone, Copy)]
struct Row {
    /// `[control] realtime_priority`, when the loop runs under `SCHED_FIFO`.
    realtime: Option<u8>,
    servos: usize,
    baud: u32,
    ports: usize,
    read: ReadKind,
    adapter: Option<Adapter>,
}

impl Row {
    /// The config of this row at `rate_hz`, with wire timing: `servos` joints of 8 cm on
    /// `ports` ports (the servos split in order), the shipped simulated arm's other settings.
    fn config(&self, rate_hz: f64) -> Result<Config> {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
        let shipped = std::fs::read_to_string(path)?;
        let bus = shipped
            .find("[bus]")
            .context("config/sim.toml has a [bus]")?;
        let mut text = format!(
            "[arm]\nbase_x_m = 0.0\nbase_y_m = 0.0\nbase_heading_rad = 1.5707963267948966\n\
             home_rad = [{}]\n",
            vec!["0.1"; self.servos].join(", ")
        );
        for id in 1..=self.servos {
            text.push_str(&format!(
                "\n[[joint]]\nlink_m = 0.08\nmin_rad = -2.0\nmax_rad = 2.0\nid = {id}\n\
                 model = \"XL430-W250\"\n"
            ));
        }
        text.push('\n');
        text.push_str(&shipped[bus..]);
        let read = format!("read = \"{}\"", self.read);
        let mut sim_keys = String::new();
        if let Some(a) = self.adapter {
            sim_keys.push_str(&format!(
                "adapter = \"ftdi\"\nlatency_timer_ms = {}\n",
                a.latency.as_millis()
            ));
        }
        let control = match self.realtime {
            Some(p) => format!("max_joint_speed_rad_s = 2.0\nrealtime_priority = {p}\n"),
            None => "max_joint_speed_rad_s = 2.0\n".to_owned(),
        };
        let mut text = text
            .replace("max_joint_speed_rad_s = 2.0\n", &control)
            .replace("baud = 1000000", &format!("baud = {}", self.baud))
            .replace("read = \"auto\"", &read)
            .replace("rate_hz = 100.0", &format!("rate_hz = {rate_hz:.1}"))
            .replace(
                "wire_timing = false",
                &format!("wire_timing = true\n{sim_keys}"),
            );
        if self.ports > 1 {
            let per = self.servos.div_ceil(self.ports);
            let ids: Vec<usize> = (1..=self.servos).collect();
            for chunk in ids.chunks(per) {
                let list: Vec<String> = chunk.iter().map(|i| i.to_string()).collect();
                text.push_str(&format!("\n[[bus.ports]]\nids = [{}]\n", list.join(", ")));
            }
        }
        Ok(Config::from_str(&text, path)?)
    }

    /// A row from `SERVOS BAUD PORTS sync|fast none|ftdi` (the `--wire-row` arguments).
    fn parse(args: &[String]) -> Result<Self> {
        let [servos, baud, ports, read, adapter] = args else {
            bail!("--wire-row takes SERVOS BAUD PORTS sync|fast none|ftdi");
        };
        Ok(Self {
            realtime: None,
            servos: servos.parse().context("servos")?,
            baud: baud.parse().context("baud")?,
            ports: ports.parse().context("ports")?,
            read: match read.as_str() {
                "sync" => ReadKind::Sync,
                "fast" => ReadKind::Fast,
                other => bail!("read: `sync` or `fast`, not `{other}`"),
            },
            adapter: match adapter.as_str() {
                "none" => None,
                "ftdi" => Some(Adapter::FTDI_1MS),
                other => bail!("adapter: `none` or `ftdi`, not `{other}`"),
            },
        })
    }

    /// The wire bound of this row's configuration.
    fn bound(&self) -> Result<Bound> {
        let mut wires = self.config(100.0)?.wire(&[self.read], &[]);
        for w in &mut wires {
            w.read = self.read;
            w.adapter = self.adapter;
        }
        bound_of_ports(&wires).context("a bus with no port")
    }

    fn label(&self) -> String {
        let adapter = match self.adapter {
            None => "none".to_owned(),
            Some(a) => format!("FTDI, {} ms", a.latency.as_millis()),
        };
        format!(
            "| {} | {} | {} | {:?} | {adapter} |",
            self.servos,
            if self.baud >= 1_000_000 {
                format!("{} Mbps", self.baud / 1_000_000)
            } else {
                format!("{} bps", self.baud)
            },
            self.ports,
            self.read,
        )
    }
}

/// How long a rate must hold without an overrun.
const HOLD: Duration = Duration::from_secs(10);
/// The share of a hold's ticks that may overrun (a scheduler hiccup of a shared machine):
/// 0.5%.
const HELD_OVERRUNS: f64 = 0.005;
/// How many rates a row tries, each 5% below the last.
const STEPS: usize = 8;
/// How long the probe that finds a candidate runs.
const PROBE_S: f64 = 2.0;

/// An error's first line, shortened for a table cell.
fn first_line(e: &anyhow::Error) -> String {
    let text = e.to_string();
    let line = text.lines().next().unwrap_or_default();
    line.chars().take(80).collect()
}

/// The wire table: for every row, the wire bound, the highest rate held for [`HOLD`] with
/// overruns under [`HELD_OVERRUNS`], and their ratio. A probe above the bound makes the loop run
/// back to back, as fast as its work allows; the candidate is 97% of that rate, confirmed for
/// [`HOLD`] and stepped down 5% at a time while it overruns more, then tried once more halfway
/// up to the last rate that did not hold. The probe's 99th-percentile tick is shown beside it.
fn wire_table(
    reads: &[ReadKind],
    adapters: &[Option<Adapter>],
    realtime: Option<u8>,
) -> Result<()> {
    let policy = match realtime {
        Some(p) => format!(", the loop under SCHED_FIFO {p}"),
        None => String::new(),
    };
    println!(
        "\nWith wire timing, held {} s per rate with overruns under {}% (a probe of {PROBE_S} s \
         above the bound finds the candidate){policy}:\n",
        HOLD.as_secs(),
        HELD_OVERRUNS * 100.0
    );
    println!("| servos | baud | ports | read | adapter | wire bound, Hz (tick) | back to back, Hz (p99 tick allows) | held 10 s, Hz (overruns of ticks) | held / bound |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for servos in [12, 24] {
        for baud in [1_000_000, 4_000_000] {
            for ports in [1, 2] {
                for &read in reads {
                    for &adapter in adapters {
                        let row = Row {
                            realtime,
                            servos,
                            baud,
                            ports,
                            read,
                            adapter,
                        };
                        println!("{}", wire_row(&row)?);
                    }
                }
            }
        }
    }
    Ok(())
}

/// One row of the wire table, as a line of its table.
fn wire_row(row: &Row) -> Result<String> {
    let bound = row.bound()?;
    let bound_hz = bound.rate_hz();
    let probe_hz = (1.5 * bound_hz).min(MAX_RATE_HZ);
    let probe = match run_config(row.config(probe_hz)?, probe_hz, PROBE_S) {
        Ok(m) => m,
        Err(e) => {
            return Ok(format!(
                "{} {bound_hz:.0} | the probe at {probe_hz:.0} Hz failed: {} | | |",
                row.label(),
                first_line(&e)
            ));
        }
    };
    let back_to_back = probe.summary.rate_hz();
    let p99_hz = 1e6 / probe.summary.tick.p99_us.max(1.0);
    let mut rate = (0.97 * back_to_back).min(MAX_RATE_HZ).floor();
    let mut held = None;
    // The last rate that did not hold, above the one that did.
    let mut failed = None;
    for _ in 0..STEPS {
        if let Some((overruns, ticks)) = hold(row, rate)? {
            held = Some((rate, overruns, ticks));
            break;
        }
        failed = Some(rate);
        rate = (rate * 0.95).floor();
    }
    // Once more halfway up to the rate that failed: the held rate to 2.5%, not 5%.
    if let (Some((r, ..)), Some(f)) = (held, failed) {
        let mid = ((r + f) / 2.0).floor();
        if mid > r {
            if let Some((overruns, ticks)) = hold(row, mid)? {
                held = Some((mid, overruns, ticks));
            }
        }
    }
    let (held_hz, ratio) = match held {
        Some((r, overruns, ticks)) => (
            format!("{r:.0} ({overruns} of {ticks})"),
            format!("{:.2}", r / bound_hz),
        ),
        None => (format!("none down to {rate:.0}"), "-".to_owned()),
    };
    Ok(format!(
        "{} {bound_hz:.0} ({:.2} ms) | {back_to_back:.0} ({:.0}) | {held_hz} | {ratio} |",
        row.label(),
        bound.tick.as_secs_f64() * 1e3,
        p99_hz,
    ))
}

/// `row` run at `rate` for [`HOLD`]: its overruns and ticks when it held (overruns under
/// [`HELD_OVERRUNS`] of the ticks, no fault: a run that faulted lost replies past the error
/// budget), `None` when it did not; each try on stderr.
fn hold(row: &Row, rate: f64) -> Result<Option<(u64, u64)>> {
    let Ok(m) = run_config(row.config(rate)?, rate, HOLD.as_secs_f64()) else {
        eprintln!("  {rate:.0} Hz: did not run");
        return Ok(None);
    };
    let s = &m.summary;
    eprintln!(
        "  {rate:.0} Hz: {} overruns in {} ticks, tick p50 / p99 / max {:.0} / {:.0} / {:.0} µs{}",
        s.overruns,
        s.ticks,
        s.tick.p50_us,
        s.tick.p99_us,
        s.tick.max_us,
        if m.fault { ", fault" } else { "" }
    );
    let held = !m.fault && (s.overruns as f64) <= HELD_OVERRUNS * s.ticks as f64;
    Ok(held.then_some((s.overruns, s.ticks)))
}

/// `row` on the idle machine and beside one busy thread per core, with the loop at the normal
/// policy and under `SCHED_FIFO` at priority 50.
fn busy(row: Row) -> Result<()> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "\nOne row of the wire table on the idle machine and beside {cores} busy threads (one per \
         core, normal policy), the loop at the normal policy and under SCHED_FIFO 50:\n"
    );
    println!("| machine | loop | servos | baud | ports | read | adapter | wire bound, Hz (tick) | back to back, Hz (p99 tick allows) | held 10 s, Hz (overruns of ticks) | held / bound |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for hogs in [0, cores] {
        // Spinning until told, each on its own thread, started here (not by the loop's thread,
        // so they keep the normal policy).
        let stop = Arc::new(AtomicBool::new(false));
        let spinning: Vec<_> = (0..hogs)
            .map(|_| {
                let stop = Arc::clone(&stop);
                std::thread::spawn(move || {
                    let mut x = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        x = std::hint::black_box(
                            x.wrapping_mul(6364136223846793005).wrapping_add(1),
                        );
                    }
                })
            })
            .collect();
        let machine = match hogs {
            0 => "idle".to_owned(),
            n => format!("{n} busy threads"),
        };
        for realtime in [None, Some(50)] {
            let policy = match realtime {
                None => "normal".to_owned(),
                Some(p) => format!("SCHED_FIFO {p}"),
            };
            let line = wire_row(&Row { realtime, ..row })?;
            println!("| {machine} | {policy} {line}");
        }
        stop.store(true, Ordering::Relaxed);
        for t in spinning {
            let _ = t.join();
        }
    }
    Ok(())
}

/// The fixed rates without and with Zenoh.
#[cfg(feature = "zenoh")]
mod with_zenoh {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
    use std::sync::Arc;
    use std::time::Duration;

    use anyhow::Result;
    use snakectl::config::Endpoint;
    use snakectl::daemon::bridge::Peer;

    use super::{cells, run_with};

    pub fn table(seconds: f64) -> Result<()> {
        println!("Without wire timing, {seconds} s per rate, Zenoh off then on:\n");
        println!("| rate, Hz | Zenoh | achieved, Hz | tick p50 / p99, µs | overruns | command to wire p50 / p99, µs | solve p50 / p99, µs | samples received |");
        println!("|---|---|---|---|---|---|---|---|");
        for rate in [100.0, 500.0, 1000.0] {
            let off = run_with(rate, false, seconds, None)?;
            println!("| {rate:.0} | off | {} 0 |", cells(&off));
            let port = std::net::TcpListener::bind("127.0.0.1:0")?
                .local_addr()?
                .port();
            // A watcher on every key, plain and ROS 2, as a dashboard or ROS 2 nodes would be.
            let stop = Arc::new(AtomicBool::new(false));
            let count = Arc::new(AtomicU64::new(0));
            let (ready_tx, ready) = std::sync::mpsc::sync_channel(1);
            let watcher = {
                let (stop, count) = (stop.clone(), count.clone());
                std::thread::spawn(move || -> Result<()> {
                    let endpoint = Endpoint::parse(&format!("tcp/127.0.0.1:{port}"))
                        .map_err(anyhow::Error::msg)?;
                    let peer = Peer::open(&[], &[endpoint])?;
                    let all = peer.subscribe("**")?;
                    let _ = ready_tx.send(());
                    while !stop.load(Ordering::Relaxed) {
                        if all.recv_timeout(Duration::from_millis(100)).is_some() {
                            count.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    Ok(())
                })
            };
            // Listening and subscribed (or failed: the join below says why).
            let _ = ready.recv_timeout(Duration::from_secs(10));
            let measured = run_with(rate, false, seconds, Some(port))?;
            stop.store(true, Ordering::Relaxed);
            let _ = watcher.join();
            let received = count.load(Ordering::Relaxed);
            println!("| {rate:.0} | on | {} {received} |", cells(&measured));
        }
        Ok(())
    }
}

#[cfg(not(feature = "zenoh"))]
mod with_zenoh {
    pub fn table(_seconds: f64) -> anyhow::Result<()> {
        anyhow::bail!("--zenoh needs the zenoh feature: cargo run --release --features zenoh --example loop_rate -- 5 --zenoh")
    }
}

/// The fixed rates without and with the Foxglove view and two clients on it.
mod with_foxglove {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
    use std::sync::Arc;
    use std::time::Duration;

    use anyhow::{Context, Result};
    use futures_util::{SinkExt, StreamExt};
    use serde_json::{json, Value};
    use snakectl::config::Config;
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;
    use tokio_tungstenite::tungstenite::http::HeaderValue;
    use tokio_tungstenite::tungstenite::Message;

    use snakectl::record::RecordOptions;

    use super::{cells, config, run_config, run_recorded};

    /// A Foxglove client on `port`, subscribed to every channel: counting what it reads into
    /// `count`, or (`stalled`) reading nothing once subscribed, until `stop`.
    fn client(
        port: u16,
        stalled: bool,
        stop: Arc<AtomicBool>,
        count: Arc<AtomicU64>,
    ) -> Result<()> {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        runtime.block_on(async move {
            let mut request = format!("ws://127.0.0.1:{port}").into_client_request()?;
            request.headers_mut().insert(
                "sec-websocket-protocol",
                HeaderValue::from_static("foxglove.sdk.v1"),
            );
            let (mut ws, _) = tokio_tungstenite::connect_async(request).await?;
            let mut ids = Vec::new();
            while ids.len() < 8 {
                let Some(message) = ws.next().await else {
                    anyhow::bail!("the view closed the connection");
                };
                if let Message::Text(text) = message? {
                    let v: Value = serde_json::from_str(text.as_str())?;
                    if v["op"] == "advertise" {
                        for c in v["channels"].as_array().context("channels")? {
                            ids.push(c["id"].clone());
                        }
                    }
                }
            }
            let subscriptions: Vec<Value> = ids
                .iter()
                .enumerate()
                .map(|(i, id)| json!({"id": i + 1, "channelId": id}))
                .collect();
            let subscribe = json!({"op": "subscribe", "subscriptions": subscriptions});
            ws.send(Message::text(subscribe.to_string())).await?;
            while !stop.load(Ordering::Relaxed) {
                if stalled {
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
                match tokio::time::timeout(Duration::from_millis(100), ws.next()).await {
                    Ok(Some(Ok(Message::Binary(_)))) => {
                        count.fetch_add(1, Ordering::Relaxed);
                    }
                    Ok(Some(Ok(_))) | Err(_) => {}
                    Ok(Some(Err(e))) => return Err(e.into()),
                    Ok(None) => break,
                }
            }
            Ok(())
        })
    }

    pub fn table(seconds: f64, record: bool) -> Result<()> {
        let also = if record { ", the run recorded" } else { "" };
        println!("Without wire timing, {seconds} s per rate, the Foxglove view off then on (one client reading, one stalled){also}:\n");
        println!("| rate, Hz | Foxglove | achieved, Hz | tick p50 / p99, µs | overruns | command to wire p50 / p99, µs | solve p50 / p99, µs | messages read |");
        println!("|---|---|---|---|---|---|---|---|");
        for rate in [100.0, 500.0, 1000.0] {
            let off = run_config(config(rate, false, None)?, rate, seconds)?;
            println!("| {rate:.0} | off | {} 0 |", cells(&off));
            let port = std::net::TcpListener::bind("127.0.0.1:0")?
                .local_addr()?
                .port();
            let plain = config(rate, false, None)?;
            let path = plain.path().to_path_buf();
            let text = std::fs::read_to_string(&path)?
                .replace("rate_hz = 100.0", &format!("rate_hz = {rate:.1}"));
            let on = Config::from_str(
                &format!("{text}\n[foxglove]\nlisten = \"127.0.0.1:{port}\"\n"),
                &path,
            )?;
            let stop = Arc::new(AtomicBool::new(false));
            let count = Arc::new(AtomicU64::new(0));
            let clients: Vec<_> = [false, true]
                .into_iter()
                .map(|stalled| {
                    let (stop, count) = (stop.clone(), count.clone());
                    std::thread::spawn(move || {
                        // The view binds during start-up: try until it listens.
                        for _ in 0..200 {
                            match client(port, stalled, stop.clone(), count.clone()) {
                                Err(_) if !stop.load(Ordering::Relaxed) => {
                                    std::thread::sleep(Duration::from_millis(25))
                                }
                                _ => return,
                            }
                        }
                    })
                })
                .collect();
            let dir = std::env::temp_dir();
            let file = dir.join(format!("snakectl-loop-rate-{}.mcap", std::process::id()));
            let m = run_recorded(on, rate, seconds, record.then(|| RecordOptions::to(&file)));
            if record {
                let _ = std::fs::remove_file(&file);
            }
            stop.store(true, Ordering::Relaxed);
            for c in clients {
                let _ = c.join();
            }
            println!(
                "| {rate:.0} | on | {} {} |",
                cells(&m?),
                count.load(Ordering::Relaxed)
            );
        }
        Ok(())
    }
}
