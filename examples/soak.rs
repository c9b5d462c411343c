//! A soak of the daemon on the simulated 12-servo arm: many ticks at 1 kHz (no wire timing)
//! while a client steers the tip around a figure eight and the strategy alternates, checking
//! every telemetry sample as it goes.
//!
//! `cargo run --release --example soak [-- [--ticks] N]` (default 1 000 000 ticks, about 17
//! minutes, after a 2 s warm-up).
//!
//! The figure eight (a lemniscate of Gerono, 6 cm wide and 3 cm high, period 8 s) is centred on the home
//! tip. The client streams `velocity` commands at 50 Hz from a tracker of the curve's point at
//! the daemon's time: `v = dp/dt + K (p - tip)`, with `tip` the commanded tip of the latest
//! telemetry. It switches the strategy every 10 s. Telemetry at 100 Hz is checked throughout:
//! every goal inside the limits that `describe` reports, no NaN (which JSON carries as
//! `null`), no saturated or self-colliding tick, the commanded tip within `CURVE_TOL_M` of the
//! curve; and the process's resident memory (the daemon runs in it) may grow by at most
//! `RSS_GROWTH_KIB` from the end of the warm-up to the end. Exits non-zero when a check fails.

use std::f64::consts::TAU;
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use serde_json::Value;
use snakectl::config::Config;
use snakectl::connect;
use snakectl::daemon::{Embedded, RunOptions};

/// Loop rate, Hz.
const RATE_HZ: f64 = 1000.0;
/// Amplitude of the figure eight, m: it is twice this wide and as high.
const AMPLITUDE_M: f64 = 0.03;
/// Period of the figure eight, s.
const PERIOD_S: f64 = 8.0;
/// Gain of the tracker's position term, 1/s.
const GAIN: f64 = 5.0;
/// Velocity commands per second.
const COMMAND_HZ: f64 = 50.0;
/// Telemetry samples per second.
const TELEMETRY_HZ: f64 = 100.0;
/// Strategy switch every this long, s.
const SWITCH_S: f64 = 10.0;
/// Daemon time of motion before the figures start, s.
const WARM_UP_S: f64 = 2.0;
/// Largest distance of the commanded tip from the curve, m.
const CURVE_TOL_M: f64 = 0.005;
/// Largest growth of the resident memory over the soak, KiB.
const RSS_GROWTH_KIB: u64 = 4096;
/// Segments of the polyline that stands for the curve.
const CURVE_SEGMENTS: usize = 4000;
/// Longest wait for a telemetry line before the soak fails.
const SILENCE: Duration = Duration::from_secs(2);

/// The figure eight around `centre`: the point and its velocity at daemon time `t` (s after
/// the start of the motion).
#[derive(Debug, Clone, Copy)]
struct Eight {
    centre: [f64; 2],
}

impl Eight {
    fn at(&self, t: f64) -> ([f64; 2], [f64; 2]) {
        let w = TAU / PERIOD_S;
        let (s, c) = (w * t).sin_cos();
        let (s2, c2) = (2.0 * w * t).sin_cos();
        let p = [
            self.centre[0] + AMPLITUDE_M * s,
            self.centre[1] + 0.5 * AMPLITUDE_M * s2,
        ];
        let v = [AMPLITUDE_M * w * c, AMPLITUDE_M * w * c2];
        (p, v)
    }

    /// The curve as a closed polyline.
    fn polyline(&self) -> Vec<[f64; 2]> {
        (0..=CURVE_SEGMENTS)
            .map(|k| self.at(PERIOD_S * k as f64 / CURVE_SEGMENTS as f64).0)
            .collect()
    }
}

/// Distance from `p` to the polyline `curve`.
fn distance_to(curve: &[[f64; 2]], p: [f64; 2]) -> f64 {
    curve
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let ab = [b[0] - a[0], b[1] - a[1]];
            let ap = [p[0] - a[0], p[1] - a[1]];
            let l2 = ab[0] * ab[0] + ab[1] * ab[1];
            let s = if l2 > 0.0 {
                ((ap[0] * ab[0] + ap[1] * ab[1]) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (ap[0] - s * ab[0]).hypot(ap[1] - s * ab[1])
        })
        .fold(f64::INFINITY, f64::min)
}

fn config() -> Result<Config> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim.toml");
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {path}"))?;
    // The error budget is a time (50 ms by default, the same at every rate): written out here
    // so that the run's budget does not depend on a default.
    let text = text
        .replace("rate_hz = 100.0", &format!("rate_hz = {RATE_HZ:.1}"))
        .replace(
            "max_joint_speed_rad_s = 2.0\n",
            "max_joint_speed_rad_s = 2.0\nmax_silence_ms = 50\n",
        );
    if !text.contains(&format!("rate_hz = {RATE_HZ:.1}"))
        || !text.contains("wire_timing = false")
        || !text.contains("max_silence_ms = 50")
    {
        bail!(
            "{path} no longer has `rate_hz = 100.0`, `max_joint_speed_rad_s = 2.0` and `wire_timing = false` \
             to start from"
        );
    }
    Ok(Config::from_str(&text, path)?)
}

/// Resident memory of this process, KiB.
fn rss_kib() -> Result<u64> {
    let status = std::fs::read_to_string("/proc/self/status")?;
    let line = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .ok_or_else(|| anyhow!("no VmRSS in /proc/self/status"))?;
    Ok(line
        .split_whitespace()
        .nth(1)
        .ok_or_else(|| anyhow!("bad VmRSS line: {line}"))?
        .parse()?)
}

/// A request/reply connection.
struct Client(BufReader<TcpStream>);

impl Client {
    fn connect(addr: SocketAddr) -> Result<Self> {
        let stream = TcpStream::connect(addr)?;
        stream.set_nodelay(true)?;
        Ok(Self(BufReader::new(stream)))
    }

    /// Sends one request and returns its reply (event lines are skipped); a refusal is an
    /// error.
    fn request(&mut self, line: &str) -> Result<Value> {
        let w = self.0.get_mut();
        w.write_all(line.as_bytes())?;
        w.write_all(b"\n")?;
        loop {
            let mut reply = String::new();
            if self.0.read_line(&mut reply)? == 0 {
                bail!("the daemon closed the connection");
            }
            let v: Value = serde_json::from_str(&reply)?;
            if v.get("type").is_some() {
                continue;
            }
            if v["ok"] != Value::Bool(true) {
                bail!("{line} -> {reply}");
            }
            return Ok(v);
        }
    }
}

fn numbers(v: &Value, field: &str) -> Result<Vec<f64>> {
    v[field]
        .as_array()
        .ok_or_else(|| anyhow!("`{field}` is not an array: {}", v[field]))?
        .iter()
        .map(|x| {
            x.as_f64()
                .ok_or_else(|| anyhow!("`{field}` holds {x} (a NaN?)"))
        })
        .collect()
}

fn number(v: &Value, field: &str) -> Result<f64> {
    v[field]
        .as_f64()
        .ok_or_else(|| anyhow!("`{field}` is {} (a NaN?)", v[field]))
}

/// The latest telemetry sample, shared with the commander.
#[derive(Debug, Clone, Copy, Default)]
struct Latest {
    tick: u64,
    t_s: f64,
    tip: [f64; 2],
    samples: u64,
}

/// What the telemetry checks found.
#[derive(Debug, Default)]
struct Checks {
    samples: u64,
    failures: Vec<String>,
    max_curve_m: f64,
    max_tracker_m: f64,
    max_tracking_error_m: f64,
    saturated: u64,
    self_collision: u64,
}

impl Checks {
    fn fail(&mut self, what: String) {
        // The first few say enough.
        if self.failures.len() < 10 {
            self.failures.push(what);
        }
    }
}

/// Arm facts from `describe`.
struct Arm {
    min: Vec<f64>,
    max: Vec<f64>,
}

/// Checks one telemetry sample.
fn check(v: &Value, arm: &Arm, eight: &Eight, t0: f64, curve: &[[f64; 2]], c: &mut Checks) {
    let result = (|| -> Result<()> {
        let tick = v["tick"].as_u64().ok_or_else(|| anyhow!("no tick: {v}"))?;
        let theta = numbers(v, "theta_cmd")?;
        if theta.len() != arm.min.len() {
            bail!(
                "tick {tick}: {} goals for {} joints",
                theta.len(),
                arm.min.len()
            );
        }
        for (i, ((&q, &lo), &hi)) in theta.iter().zip(&arm.min).zip(&arm.max).enumerate() {
            if !(lo <= q && q <= hi) {
                bail!("tick {tick}: joint {} goal {q} outside [{lo}, {hi}]", i + 1);
            }
        }
        for field in ["tip_ref", "tip_meas", "theta_meas", "omega_meas"] {
            numbers(v, field)?;
        }
        for field in [
            "t_s",
            "tracking_error_m",
            "solve_us",
            "loop_hz",
            "tick_p99_us",
        ] {
            number(v, field)?;
        }
        let tip = numbers(v, "tip")?;
        let tip = [tip[0], tip[1]];
        let t = number(v, "t_s")?;
        if t >= t0 {
            let d = distance_to(curve, tip);
            c.max_curve_m = c.max_curve_m.max(d);
            if d > CURVE_TOL_M {
                bail!("tick {tick}: the commanded tip {tip:?} is {d} m off the curve");
            }
            let (p, _) = eight.at(t - t0);
            c.max_tracker_m = c.max_tracker_m.max((tip[0] - p[0]).hypot(tip[1] - p[1]));
        }
        c.max_tracking_error_m = c.max_tracking_error_m.max(number(v, "tracking_error_m")?);
        if v["saturated"] == Value::Bool(true) {
            c.saturated += 1;
            bail!("tick {tick}: saturated");
        }
        if v["self_collision"] == Value::Bool(true) {
            c.self_collision += 1;
            bail!("tick {tick}: self_collision");
        }
        Ok(())
    })();
    c.samples += 1;
    if let Err(e) = result {
        c.fail(e.to_string());
    }
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let ticks: u64 = match args.next().as_deref() {
        None => 1_000_000,
        Some("--ticks") => args
            .next()
            .ok_or_else(|| anyhow!("--ticks needs a number"))?
            .parse()
            .context("--ticks")?,
        Some(n) => n.parse().context("the number of ticks")?,
    };
    let config = config()?;
    let sim = connect::spawn_sim(&config, Arc::new(snakectl_sim::RealClock))?;
    let options = RunOptions::port(sim.path().to_path_buf());
    let daemon = Embedded::start(config, ([127, 0, 0, 1], 0).into(), options)?;
    let addr = daemon.addr();

    let mut client = Client::connect(addr)?;
    let describe = client.request(r#"{"cmd":"describe"}"#)?;
    let arm = Arm {
        min: numbers(&describe, "min_rad")?,
        max: numbers(&describe, "max_rad")?,
    };
    let status = client.request(r#"{"cmd":"status"}"#)?;
    let home_tip = numbers(&status, "tip")?;
    let eight = Eight {
        centre: [home_tip[0], home_tip[1]],
    };
    let curve = eight.polyline();

    // The telemetry reader: checks every sample and shares the latest with the commander.
    let latest = Arc::new(Mutex::new(Latest::default()));
    let t0_shared = Arc::new(Mutex::new(f64::INFINITY));
    let done = Arc::new(AtomicBool::new(false));
    let mut telemetry = Client::connect(addr)?;
    telemetry.request(&format!(
        r#"{{"cmd":"subscribe","rate_hz":{TELEMETRY_HZ:.1}}}"#
    ))?;
    telemetry
        .0
        .get_ref()
        .set_read_timeout(Some(Duration::from_millis(100)))?;
    let reader = {
        let (latest, t0_shared, done) = (latest.clone(), t0_shared.clone(), done.clone());
        std::thread::spawn(move || -> Checks {
            let mut c = Checks::default();
            let mut last = Instant::now();
            let mut line = String::new();
            while !done.load(Ordering::Relaxed) {
                match telemetry.0.read_line(&mut line) {
                    Ok(0) => {
                        c.fail("the telemetry connection closed".into());
                        break;
                    }
                    Ok(_) => {}
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) =>
                    {
                        // A partial line stays in `line` and is completed by the next read.
                        if last.elapsed() > SILENCE {
                            c.fail(format!("no telemetry for {SILENCE:?}"));
                            break;
                        }
                        continue;
                    }
                    Err(e) => {
                        c.fail(format!("telemetry: {e}"));
                        break;
                    }
                }
                last = Instant::now();
                let v: Value = match serde_json::from_str(&line) {
                    Ok(v) => v,
                    Err(e) => {
                        c.fail(format!("bad telemetry line {line:?}: {e}"));
                        line.clear();
                        continue;
                    }
                };
                line.clear();
                if v["type"] != "telemetry" {
                    continue;
                }
                let t0 = t0_shared.lock().map_or(f64::INFINITY, |t| *t);
                check(&v, &arm, &eight, t0, &curve, &mut c);
                if let (Some(tick), Some(t_s), Ok(tip)) =
                    (v["tick"].as_u64(), v["t_s"].as_f64(), numbers(&v, "tip"))
                {
                    if let Ok(mut l) = latest.lock() {
                        *l = Latest {
                            tick,
                            t_s,
                            tip: [tip[0], tip[1]],
                            samples: l.samples + 1,
                        };
                    }
                }
            }
            c
        })
    };

    let read_latest = || latest.lock().map(|l| *l).map_err(|_| anyhow!("poisoned"));
    // Wait for the first sample: the motion starts at its time.
    let deadline = Instant::now() + SILENCE;
    let first = loop {
        let l = read_latest()?;
        if l.samples > 0 {
            break l;
        }
        if Instant::now() > deadline {
            bail!("no telemetry within {SILENCE:?}");
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let t0 = first.t_s;
    if let Ok(mut t) = t0_shared.lock() {
        *t = t0;
    }

    let strategies = ["overall", "sequential"];
    let mut strategy = 0;
    let mut next_switch = t0 + SWITCH_S;
    let mut warm: Option<(u64, u64)> = None; // (tick, RSS KiB) at the end of the warm-up
    let period = Duration::from_secs_f64(1.0 / COMMAND_HZ);
    let started = Instant::now();
    let mut next = Instant::now();
    let mut commands = 0u64;
    loop {
        let l = read_latest()?;
        if let Some((tick, _)) = warm {
            if l.tick >= tick + ticks {
                break;
            }
        } else if l.t_s >= t0 + WARM_UP_S {
            client.request(r#"{"cmd":"reset_stats"}"#)?;
            warm = Some((l.tick, rss_kib()?));
        }
        if l.t_s >= next_switch {
            strategy = 1 - strategy;
            client.request(&format!(
                r#"{{"cmd":"strategy","name":"{}"}}"#,
                strategies[strategy]
            ))?;
            next_switch += SWITCH_S;
        }
        let (p, dp) = eight.at(l.t_s - t0);
        let v = [
            dp[0] + GAIN * (p[0] - l.tip[0]),
            dp[1] + GAIN * (p[1] - l.tip[1]),
        ];
        client.request(&format!(
            r#"{{"cmd":"velocity","v":[{:.9},{:.9}]}}"#,
            v[0], v[1]
        ))?;
        commands += 1;
        next += period;
        match next.checked_duration_since(Instant::now()) {
            Some(wait) => std::thread::sleep(wait),
            None => next = Instant::now(),
        }
    }
    let status = client.request(r#"{"cmd":"status"}"#)?;
    let rss_end = rss_kib()?;
    client.request(r#"{"cmd":"stop"}"#)?;
    done.store(true, Ordering::Relaxed);
    let checks = reader
        .join()
        .map_err(|_| anyhow!("the telemetry reader panicked"))?;
    let summary = daemon.stop()?;
    drop(sim);

    let (warm_tick, rss_start) = warm.ok_or_else(|| anyhow!("never warmed up"))?;
    let mut failures = checks.failures;
    let growth = rss_end.saturating_sub(rss_start);
    if growth > RSS_GROWTH_KIB {
        failures.push(format!(
            "resident memory grew by {growth} KiB (> {RSS_GROWTH_KIB} KiB)"
        ));
    }
    println!(
        "soak: {ticks} ticks at {RATE_HZ:.0} Hz after a {WARM_UP_S} s warm-up, {:.1} s of wall time",
        started.elapsed().as_secs_f64()
    );
    println!(
        "  daemon summary: {} ticks, {} overruns, {:.1} Hz achieved, tick p50 / p99 {:.0} / {:.0} µs",
        summary.ticks,
        summary.overruns,
        summary.rate_hz(),
        summary.tick.p50_us,
        summary.tick.p99_us
    );
    println!(
        "  status at the end: tick {} ({} since the warm-up), overruns {}, loop_hz {:.1}, tick_p99_us {:.0}",
        number(&status, "tick")?,
        status["tick"].as_u64().unwrap_or(0).saturating_sub(warm_tick),
        number(&status, "overruns")?,
        number(&status, "loop_hz")?,
        number(&status, "tick_p99_us")?
    );
    println!(
        "  {} velocity commands, {} telemetry samples checked, {} saturated, {} self_collision",
        commands, checks.samples, checks.saturated, checks.self_collision
    );
    println!(
        "  commanded tip: max {:.3} mm from the curve (limit {:.1} mm), max {:.3} mm from the tracked point",
        checks.max_curve_m * 1e3,
        CURVE_TOL_M * 1e3,
        checks.max_tracker_m * 1e3
    );
    println!(
        "  max tracking_error_m (tip_ref to the measured tip): {:.3} mm",
        checks.max_tracking_error_m * 1e3
    );
    println!("  VmRSS: {rss_start} KiB after the warm-up, {rss_end} KiB at the end (+{growth} KiB, limit {RSS_GROWTH_KIB})");
    if failures.is_empty() {
        println!("soak: all checks passed");
        Ok(())
    } else {
        for f in &failures {
            eprintln!("FAIL: {f}");
        }
        std::process::exit(1);
    }
}
