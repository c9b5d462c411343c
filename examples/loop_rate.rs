//! The daemon's loop on the 12-servo simulated arm: achieved rate, tick time, overruns and
//! command-to-wire latency at fixed rates without wire timing, then the highest rate sustained
//! without overruns with wire timing at 1 Mbps, against the wire bound.
//!
//! `cargo run --release --example loop_rate [-- SECONDS]` (default 5 s per rate).
//!
//! `cargo run --release --example loop_rate -- SECONDS --obstacles` instead runs the fixed rates
//! without wire timing twice, with no obstacles and with 16 small discs near the arm (each
//! link's middle, 5 cm to alternate sides), one after the other.
//!
//! `cargo run --release --features zenoh --example loop_rate -- SECONDS --zenoh` instead runs
//! each fixed rate twice, without and with the daemon on a Zenoh network (publishing at the
//! default rate to a peer subscribed to every key), one after the other.
//!
//! A client streams `velocity` commands at 20 Hz (a figure eight, as a joystick would) while
//! the loop runs; the first half second of each run is left out of the figures
//! (`reset_stats`).

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use snakectl::chain::Vec2;
use snakectl::config::Config;
use snakectl::connect;
use snakectl::daemon::{Embedded, RunOptions, Summary};

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
        text.push_str(&format!(
            "\n[zenoh]\nenabled = true\nlisten = [\"tcp/127.0.0.1:{port}\"]\n"
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
    let sim = connect::spawn_sim(&config, Arc::new(snakectl_sim::RealClock))?;
    let options = RunOptions::port(sim.path().to_path_buf());
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
    drop(sim);
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
    if std::env::args().nth(2).as_deref() == Some("--zenoh") {
        return with_zenoh::table(seconds);
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
    println!("Without wire timing, {seconds} s per rate:\n");
    println!("| rate, Hz | achieved, Hz | tick p50 / p99, µs | overruns | command to wire p50 / p99, µs | solve p50 / p99, µs |");
    println!("|---|---|---|---|---|---|");
    for rate in [100.0, 500.0, 1000.0] {
        row(rate, &run(rate, false, seconds)?);
    }

    let n = 12.0;
    let baud = 1e6;
    let bound_s = (28.0 + 21.0 * n) * 10.0 / baud;
    println!(
        "\nWith wire timing at 1 Mbps (wire bound {:.2} ms per cycle = {:.0} Hz):\n",
        bound_s * 1e3,
        1.0 / bound_s
    );
    println!("| rate, Hz | achieved, Hz | tick p50 / p99, µs | overruns | command to wire p50 / p99, µs | solve p50 / p99, µs |");
    println!("|---|---|---|---|---|---|");
    let (mut strict, mut sustained) = (None, None);
    for rate in [100.0, 150.0, 200.0, 225.0, 250.0, 275.0, 300.0, 350.0] {
        let m = run(rate, true, seconds)?;
        row(rate, &m);
        let s = &m.summary;
        if m.fault {
            continue;
        }
        if s.overruns == 0 {
            strict = Some(rate);
        }
        if (s.overruns as f64) <= 1e-3 * s.ticks as f64 {
            sustained = Some(rate);
        }
    }
    let say = |what: &str, r: Option<f64>| match r {
        Some(r) => println!(
            "{what}: {r:.0} Hz ({:.0}% of the wire bound).",
            100.0 * r * bound_s
        ),
        None => println!("{what}: none of the rates tried."),
    };
    println!();
    say("Highest rate without a single overrun", strict);
    say(
        "Highest rate with overruns under 0.1% of the ticks",
        sustained,
    );
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
            // A watcher on every key, as a ROS 2 bridge or a dashboard would be.
            let stop = Arc::new(AtomicBool::new(false));
            let count = Arc::new(AtomicU64::new(0));
            let watcher = {
                let (stop, count) = (stop.clone(), count.clone());
                std::thread::spawn(move || -> Result<()> {
                    let endpoint = Endpoint::parse(&format!("tcp/127.0.0.1:{port}"))
                        .map_err(anyhow::Error::msg)?;
                    let peer = Peer::open(&[endpoint], &[])?;
                    let all = peer.subscribe("snakectl/**")?;
                    while !stop.load(Ordering::Relaxed) {
                        if all.recv_timeout(Duration::from_millis(100)).is_some() {
                            count.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    Ok(())
                })
            };
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
