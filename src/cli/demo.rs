//! `snakectl demo` (and `cargo run --release` with no arguments): the whole product in one
//! command, driven through the daemon's socket as any client would drive it.
//!
//! The simulator and the daemon start in this process (a real pseudo-terminal, a real socket on
//! a free loopback port); a [`Client`] then steers the tip around a figure eight once per
//! strategy, as a joystick would (`velocity` at 50 Hz), and along a path interrupted by an
//! estop. What telemetry said becomes a summary table and `summary.json`; the daemon records
//! the run (`run.mcap`), and the two figures are drawn from that recording, as
//! `snakectl plot` draws them.

use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use clap::Args;
use serde::Serialize;
use serde_json::Value;

use snakectl::chain::{Chain, Vec2};
use snakectl::client::{ArmInfo, Client, ClientError, Ending, Motion, Seen, Status as Snapshot};
use snakectl::config::Config;
use snakectl::connect;
use snakectl::daemon::{DaemonError, Embedded, RunOptions};
use snakectl::plot::demo::{Phase, Sample};
use snakectl::protocol::{
    Cmd, CmdName, Event as ProtocolEvent, EventKind, FaultChange, State, What,
};
use snakectl::record::read::phase_note;
use snakectl::record::{Notes, RecordOptions, Recording};
use snakectl::resolve::Strategy;
use snakectl::world::{Obstacle, Shape, World};
use snakectl_sim::RealClock;

use super::signals::Signals;
use super::{outln, Failure};

/// The shipped simulator config, compiled in so the demo runs from any directory.
const SHIPPED: &str = include_str!("../../config/sim.toml");
const SHIPPED_PATH: &str = "config/sim.toml";
const DEFAULT_OUT: &str = "snakectl-demo";
/// The recording of the run, in the output directory; the figures are drawn from it.
const RECORDING: &str = "run.mcap";

/// Every file a run writes into its directory (the figures by [`super::plot::figures`]).
const OUTPUTS: [&str; 6] = [
    "summary.json",
    "motion.svg",
    "motion.png",
    "joints.svg",
    "joints.png",
    RECORDING,
];
/// Each figure eight's duration unless `--seconds` says otherwise, s.
const DEFAULT_SECONDS: f64 = 15.0;
const MIN_SECONDS: f64 = 2.0;
const MAX_SECONDS: f64 = 600.0;
/// How often the eight's `velocity` is renewed, as a joystick's would be.
const SEND_PERIOD: Duration = Duration::from_millis(20);
/// The eight's fastest feed-forward tip speed, as a share of `max_tip_speed_m_s`.
const SPEED_SHARE: f64 = 0.6;
/// No `velocity` sent is faster than this share of `max_tip_speed_m_s`.
const COMMAND_SHARE: f64 = 0.8;
/// The proportional correction toward the curve's point, 1/s.
const GAIN: f64 = 3.0;
/// About how long one loop of the eight takes, s.
const LOOP_S: f64 = 7.5;
/// The phase among obstacles moves the tip at this share of `max_tip_speed_m_s`: the links that
/// follow it round the post turn at about the speed over the route's radius.
const POCKET_SPEED_SHARE: f64 = 0.6;
/// Waits for the daemon beyond a motion's own duration; reached only when something is wrong.
const SLACK: Duration = Duration::from_secs(15);

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// The simulated arm's config (default: the shipped `config/sim.toml`).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Where to write `summary.json` and the figures.
    #[arg(long, value_name = "DIR", default_value = DEFAULT_OUT)]
    pub out: PathBuf,
    /// How long the figure eights take, each, s (the whole demo takes about twice this, plus
    /// about 15 s for the gotos, the path and the obstacle phase).
    #[arg(long)]
    pub seconds: Option<f64>,
}

impl Default for DemoArgs {
    fn default() -> Self {
        Self {
            config: None,
            out: PathBuf::from(DEFAULT_OUT),
            seconds: None,
        }
    }
}

/// Runs the demo and writes its outputs.
pub fn run(args: DemoArgs) -> Result<(), Failure> {
    init_logs();
    let seconds = args.seconds.unwrap_or(DEFAULT_SECONDS);
    if !(MIN_SECONDS..=MAX_SECONDS).contains(&seconds) {
        return Err(Failure::bad_input(anyhow!(
            "--seconds {seconds}: give {MIN_SECONDS} to {MAX_SECONDS} s"
        )));
    }
    let config = match &args.config {
        Some(path) => Config::load(path).map_err(Failure::bad_input)?,
        None => Config::from_str(SHIPPED, SHIPPED_PATH).map_err(Failure::other)?,
    };
    let out = if args.out.as_os_str().is_empty() {
        PathBuf::from(DEFAULT_OUT)
    } else {
        args.out
    };
    if out.exists() && !out.is_dir() {
        return Err(Failure::bad_input(anyhow!(
            "{} is not a directory: the demo writes its outputs there (--out names another)",
            out.display()
        )));
    }
    std::fs::create_dir_all(&out)
        .with_context(|| format!("creating {}", out.display()))
        .map_err(Failure::other)?;
    // The last run's outputs go first, so that a run that fails leaves none of them beside
    // its own partial recording.
    for name in OUTPUTS {
        let path = out.join(name);
        match std::fs::remove_file(&path) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                return Err(Failure::other(
                    anyhow::Error::new(e).context(format!("removing {}", path.display())),
                ))
            }
        }
    }
    // A signal (Ctrl-C) stops the run as a failure does: the daemon brings the arm to rest
    // and closes the recording.
    let signals = Signals::catch()
        .context("installing the signal handlers")
        .map_err(Failure::other)?;

    let mut progress = Progress::new();
    progress.line(format!(
        "snakectl demo: {} ({} joints, simulated), figure eights of {seconds} s",
        config.path().display(),
        config.chain().len()
    ));
    let sim = connect::spawn_sim(&config, Arc::new(RealClock)).map_err(Failure::bad_input)?;
    let recording = out.join(RECORDING);
    let notes = Notes::new();
    // The demo's own output: each run replaces the last one's.
    let options = RunOptions::port(sim.path().to_path_buf()).recorded(Some(RecordOptions {
        path: recording.clone(),
        notes: notes.clone(),
        overwrite: true,
    }));
    let loopback = SocketAddr::from(([127, 0, 0, 1], 0));
    let daemon = Embedded::start(config.clone(), loopback, options).map_err(Failure::other)?;
    progress.line(format!(
        "daemon on {}, simulator on {}",
        daemon.addr(),
        sim.path().display()
    ));
    let driven = drive(&config, daemon.addr(), seconds, &mut progress, &signals);
    progress.clear();
    if let Ok(demo) = &driven {
        // The phases go into the recording, which the figures are drawn from.
        for phase in &demo.phases {
            notes.add("snakectl.phase", phase_note(phase));
        }
    }
    let stopped = daemon.stop();
    drop(sim);
    if let Some(signal) = signals.received() {
        let mut failure = super::signals::stopped_by(signal);
        failure.error = failure.error.context(format!(
            "the demo was interrupted: the arm is at rest, and {} holds the run so far",
            recording.display()
        ));
        return Err(failure);
    }
    let demo = match (driven, stopped) {
        (Ok(demo), Ok(_)) => demo,
        // The daemon's own failure (a bring-up refused, say) is the cause; the client only saw
        // the connection close.
        (Err(seen), Err(e)) => {
            let code = if matches!(
                e,
                DaemonError::BringUp(_) | DaemonError::Connect(_) | DaemonError::Controller(_)
            ) {
                2
            } else {
                1
            };
            return Err(Failure {
                code,
                error: anyhow::Error::new(e).context(format!("the daemon failed ({seen:#})")),
            });
        }
        (Err(seen), Ok(_)) => return Err(Failure::other(seen.context("the demo failed"))),
        (Ok(_), Err(e)) => {
            return Err(Failure::other(
                anyhow::Error::new(e).context("the daemon did not stop cleanly"),
            ))
        }
    };
    report(&demo, &out, &recording)
}

/// Warnings and errors only: the progress lines tell the rest. `RUST_LOG` overrides.
fn init_logs() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .try_init();
}

/// Progress on stderr: a live status line (carriage return) on a terminal, plain lines
/// otherwise.
struct Progress {
    tty: bool,
    live_shown: bool,
    last_live: Option<Instant>,
}

impl Progress {
    fn new() -> Self {
        Self {
            tty: std::io::stderr().is_terminal(),
            live_shown: false,
            last_live: None,
        }
    }

    /// A line that stays.
    fn line(&mut self, text: impl AsRef<str>) {
        self.clear();
        eprintln!("{}", text.as_ref());
    }

    /// The live line, redrawn at most ten times a second; nothing when stderr is not a terminal.
    fn live(&mut self, text: impl FnOnce() -> String) {
        if !self.tty
            || self
                .last_live
                .is_some_and(|t| t.elapsed() < Duration::from_millis(100))
        {
            return;
        }
        self.last_live = Some(Instant::now());
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r\x1b[K{}", text());
        let _ = err.flush();
        self.live_shown = true;
    }

    /// Takes the live line away.
    fn clear(&mut self) {
        if self.live_shown {
            eprint!("\r\x1b[K");
            self.live_shown = false;
        }
    }
}

/// A figure eight (a lemniscate of Gerono's kind: `sin φ` along, `sin 2φ` across) around
/// `centre`, whose phase speeds up smoothly from rest and slows to rest at the end.
#[derive(Debug, Clone, Copy)]
struct Eight {
    centre: [f64; 2],
    /// Unit vector of the long axis.
    along: [f64; 2],
    /// Unit vector of the short axis.
    across: [f64; 2],
    /// Half-width along, m.
    a: f64,
    /// Half-height across, m.
    b: f64,
    /// Phase rate between the ramps, rad/s.
    omega: f64,
    /// Ramp duration at each end, s.
    ramp: f64,
    /// Total duration, s.
    duration: f64,
    loops: u32,
}

impl Eight {
    /// An eight inside the arm's workspace, in front of its home tip, sized so that its
    /// fastest point moves at [`SPEED_SHARE`] of `max_tip_speed`.
    fn new(arm: &ArmInfo, seconds: f64, max_tip_speed: f64) -> Self {
        let base = [arm.base[0], arm.base[1]];
        let home_tip = arm
            .points(&arm.home_rad)
            .last()
            .copied()
            .unwrap_or([base[0], base[1] + arm.reach()]);
        let (dx, dy) = (home_tip[0] - base[0], home_tip[1] - base[1]);
        let distance = dx.hypot(dy);
        let across = if distance > 1e-9 {
            [dx / distance, dy / distance]
        } else {
            [arm.base[2].cos(), arm.base[2].sin()]
        };
        let along = [-across[1], across[0]];
        let radius = distance.min(0.85 * arm.reach());
        let centre = [base[0] + radius * across[0], base[1] + radius * across[1]];
        let loops = ((seconds / LOOP_S).round() as u32).max(1);
        let ramp = (seconds / 5.0).min(1.0);
        let omega = 2.0 * std::f64::consts::PI * f64::from(loops) / (seconds - ramp);
        // The fastest point is the crossing: |dP/dφ| = sqrt(a² + 4b²) = a √2 with b = a / 2.
        let a = (SPEED_SHARE * max_tip_speed / (omega * std::f64::consts::SQRT_2))
            .min(0.1 * arm.reach());
        Self {
            centre,
            along,
            across,
            a,
            b: 0.5 * a,
            omega,
            ramp,
            duration: seconds,
            loops,
        }
    }

    /// The phase and its rate at `tau` s after the start.
    fn phase(&self, tau: f64) -> (f64, f64) {
        let (w, r) = (self.omega, self.ramp);
        // The rate follows smoothstep 3x² - 2x³ up over the first ramp and down over the last;
        // its integral is x³ - x⁴/2.
        let rise = |x: f64| {
            (
                3.0 * x * x - 2.0 * x * x * x,
                x * x * x - 0.5 * x * x * x * x,
            )
        };
        let tau = tau.clamp(0.0, self.duration);
        if tau < r {
            let (rate, integral) = rise(tau / r);
            (w * r * integral, w * rate)
        } else if tau > self.duration - r {
            let (rate, integral) = rise((self.duration - tau) / r);
            (w * (self.duration - r) - w * r * integral, w * rate)
        } else {
            (w * (0.5 * r + tau - r), w)
        }
    }

    /// The point at phase `phi` and its derivative by the phase.
    fn at_phase(&self, phi: f64) -> ([f64; 2], [f64; 2]) {
        let (u, v) = (self.a * phi.sin(), self.b * (2.0 * phi).sin());
        let (du, dv) = (self.a * phi.cos(), 2.0 * self.b * (2.0 * phi).cos());
        (
            [
                self.centre[0] + u * self.along[0] + v * self.across[0],
                self.centre[1] + u * self.along[1] + v * self.across[1],
            ],
            [
                du * self.along[0] + dv * self.across[0],
                du * self.along[1] + dv * self.across[1],
            ],
        )
    }

    /// The point and its velocity at `tau` s after the start.
    fn at(&self, tau: f64) -> ([f64; 2], [f64; 2]) {
        let (phi, rate) = self.phase(tau);
        let (p, d) = self.at_phase(phi);
        (p, [d[0] * rate, d[1] * rate])
    }

    /// The whole curve, for the figures.
    fn polyline(&self) -> Vec<[f64; 2]> {
        (0..=400)
            .map(|k| {
                self.at_phase(2.0 * std::f64::consts::PI * f64::from(k) / 400.0)
                    .0
            })
            .collect()
    }
}

/// One telemetry sample as recorded.
#[derive(Debug, Clone)]
struct Rec {
    tick: u64,
    solve_us: f64,
    saturated: bool,
    /// The commanded pose's clearance, m (`None` with no obstacles).
    min_clearance_m: Option<f64>,
    sample: Sample,
}

/// What one strategy's figure eight measured.
#[derive(Debug, Clone, Serialize)]
struct StrategyFigures {
    name: &'static str,
    peak_joint_speed_rad_s: f64,
    m3_rad2: f64,
    tracking_error_p50_m: f64,
    tracking_error_max_m: f64,
    loop_hz: f64,
    tick_p99_us: f64,
    solve_us_p50: f64,
    solve_us_p99: f64,
    /// The fastest reference tip speed between samples, m/s.
    peak_tip_speed_m_s: f64,
    velocity_commands: u64,
    samples: usize,
    saturated_samples: usize,
    overruns: u64,
}

/// The path with its estop.
#[derive(Debug, Clone, Serialize)]
struct PathFigures {
    corners: Vec<[f64; 2]>,
    estop_tick: u64,
    estop_tip: [f64; 2],
    /// What a motion command got while the latch was set.
    refused_while_latched: String,
    reset_tick: u64,
    arrived_tick: u64,
}

/// The eight's shape.
#[derive(Debug, Clone, Serialize)]
struct EightShape {
    centre: [f64; 2],
    width_m: f64,
    height_m: f64,
    loops: u32,
    seconds: f64,
}

/// `summary.json`.
#[derive(Debug, Clone, Serialize)]
struct Summary {
    max_joint_speed_rad_s: f64,
    max_tip_speed_m_s: f64,
    strategies: Vec<StrategyFigures>,
    eight: EightShape,
    path: PathFigures,
    world: WorldFigures,
    config: String,
}

/// What the phase among obstacles measured.
#[derive(Debug, Clone, Serialize)]
struct WorldFigures {
    /// Where the tip went in, m.
    pocket: [f64; 2],
    /// The obstacles' ids.
    obstacles: Vec<String>,
    /// The least clearance of any commanded pose in the phase, m.
    min_clearance_m: f64,
    /// The clearance kept, m.
    clearance_m: f64,
    /// The measured tip's way into the pocket, m...
    route_in_m: f64,
    /// ...against the straight line, m.
    straight_m: f64,
    /// Both ways arrived.
    arrived: bool,
    /// How the way in ended (`arrived`, or `blocked` naming the link and obstacle).
    way_in: String,
    /// How the way back ended.
    way_back: String,
}

/// The phase among obstacles: a pocket beside the eight's centre along its long axis (turned
/// by `quarters` quarter turns), a post halfway there on the straight line, and a shelf over
/// the pocket's outer side, so that the tip must go round the post.
fn pocket(eight: &Eight, reach: f64, quarters: usize) -> ([f64; 2], Vec<Obstacle>) {
    let (mut t, mut u) = (eight.along, eight.across);
    for _ in 0..quarters % 4 {
        (t, u) = ([-t[1], t[0]], [-u[1], u[0]]);
    }
    let c = eight.centre;
    let at = |p: f64, q: f64| Vec2::new(c[0] + p * t[0] + q * u[0], c[1] + p * t[1] + q * u[1]);
    let d = 0.2 * reach;
    let target = at(d, 0.0);
    let post = Obstacle {
        id: "post".into(),
        shape: Shape::Circle {
            center: at(0.5 * d, 0.0),
            radius_m: 0.03 * reach,
        },
    };
    let (x0, x1) = (0.75 * d, 1.25 * d);
    let (y0, y1) = (0.08 * reach, 0.1 * reach);
    let shelf = Obstacle {
        id: "shelf".into(),
        shape: Shape::Polygon {
            points: vec![at(x0, y0), at(x1, y0), at(x1, y1), at(x0, y1)],
        },
    };
    ([target.x, target.y], vec![post, shelf])
}

/// The pocket of [`pocket`] for an arm that stands in the pose `theta` at the eight's centre:
/// along the eight's long axis, else turned a quarter at a time, the first whose obstacles keep
/// a twentieth of the reach from every link (another arm's body may lie where one pocket is);
/// along the axis when none does (the phase then reports where the arm was held).
fn pocket_beside(
    eight: &Eight,
    chain: &Chain,
    theta: &[f64],
    link_radius_m: f64,
) -> ([f64; 2], Vec<Obstacle>) {
    let reach = chain.reach();
    let points = chain.points(theta);
    (0..4)
        .map(|q| pocket(eight, reach, q))
        .find(|(_, obstacles)| {
            World::new(link_radius_m, 0.0, obstacles.clone())
                .ok()
                .and_then(|w| w.clearance(&points))
                .is_some_and(|p| p.clearance_m >= 0.05 * reach)
        })
        .unwrap_or_else(|| pocket(eight, reach, 0))
}

/// A finished run: its figures and its phases (in the daemon's time).
struct Demo {
    summary: Summary,
    phases: Vec<Phase>,
}

/// The session on the socket: the client, and what it has seen and recorded so far.
struct Session<'p> {
    client: Client,
    rec: Recorder<'p>,
}

/// What the session has seen and recorded: kept apart from the client, so that what the
/// client shows while it waits can be recorded as it comes.
struct Recorder<'p> {
    arm: ArmInfo,
    progress: &'p mut Progress,
    /// A signal ends the run at the next thing seen.
    signals: &'p Signals,
    recs: Vec<Rec>,
    latest: Option<Snapshot>,
    phases: Vec<Phase>,
    /// What the live line says is going on.
    activity: String,
    /// Samples kept at most (a run of [`MAX_SECONDS`] eights stays within it).
    cap: usize,
}

/// The run from connecting to the last arrival.
fn drive(
    config: &Config,
    addr: SocketAddr,
    seconds: f64,
    progress: &mut Progress,
    signals: &Signals,
) -> anyhow::Result<Demo> {
    let control = config.control();
    let token = config.server().token_file.as_deref();
    let mut client = Client::connect_with(&addr.to_string(), token)?;
    progress.line("bringing the arm up ...");
    let arm = client.describe()?;
    client.request(&Cmd::Subscribe {
        rate_hz: arm.rate_hz,
    })?;
    let cap = ((2.0 * MAX_SECONDS + 600.0) * arm.rate_hz) as usize;
    let mut s = Session {
        client,
        rec: Recorder {
            arm,
            progress,
            signals,
            recs: Vec::new(),
            latest: None,
            phases: Vec::new(),
            activity: "holding".into(),
            cap,
        },
    };
    s.wait_for(|_| true, SLACK, "the first telemetry line")?;
    let eight = Eight::new(&s.rec.arm, seconds, control.max_tip_speed_m_s);
    s.rec.progress.line(format!(
        "arm up: {} links, {:.2} m reach, {} Hz; figure eight {:.0} x {:.0} mm around ({:.3}, {:.3}) m, {} loop(s)",
        s.rec.arm.links_m.len(),
        s.rec.arm.reach(),
        s.rec.arm.rate_hz,
        4e3 * eight.a / 2.0,
        4e3 * eight.b / 2.0,
        eight.centre[0],
        eight.centre[1],
        eight.loops
    ));
    let cap_speed = COMMAND_SHARE * control.max_tip_speed_m_s;
    let mut strategies = Vec::new();
    for strategy in [Strategy::Overall, Strategy::Sequential] {
        strategies.push(s.figure_eight(strategy, &eight, cap_speed)?);
    }
    let path = s.path_with_estop(&eight, control.max_tip_speed_m_s)?;
    let world = s.among_obstacles(&eight, control.max_tip_speed_m_s)?;
    s.rec.progress.line("done: the arm holds");

    let phases = s.rec.phases.clone();
    let summary = Summary {
        max_joint_speed_rad_s: control.max_joint_speed_rad_s,
        max_tip_speed_m_s: control.max_tip_speed_m_s,
        strategies,
        eight: EightShape {
            centre: eight.centre,
            width_m: 2.0 * eight.a,
            height_m: 2.0 * eight.b,
            loops: eight.loops,
            seconds,
        },
        path,
        world,
        config: config.path().display().to_string(),
    };
    Ok(Demo { summary, phases })
}

impl Recorder<'_> {
    /// Takes what the client shows: a telemetry line is recorded; a refused request or a
    /// fault raised fails the run.
    fn take(&mut self, seen: Seen<'_>) -> anyhow::Result<()> {
        if let Some(signal) = self.signals.received() {
            bail!("interrupted by signal {signal}");
        }
        match seen {
            Seen::Telemetry(t) => self.record(&t.status),
            Seen::Reply(reply) => {
                if let Err(why) = &reply.result {
                    let id = reply.id.as_deref().unwrap_or(&Value::Null);
                    bail!("the daemon refused request {id}: {why}");
                }
            }
            Seen::Event(e) => {
                if let What::Fault {
                    reason: FaultChange::Raised,
                    fault,
                    ..
                } = &e.what
                {
                    bail!("the arm holds for a fault: {fault}");
                }
            }
        }
        Ok(())
    }

    fn record(&mut self, snap: &Snapshot) {
        if self.recs.len() < self.cap {
            self.recs.push(Rec {
                tick: snap.tick,
                solve_us: snap.solve_us,
                saturated: snap.saturated,
                min_clearance_m: snap.min_clearance_m,
                sample: Sample {
                    t_s: snap.t_s,
                    theta: snap.theta_meas.clone(),
                    tip_ref: snap.tip_ref,
                    tip_meas: snap.tip_meas,
                    tracking_error_m: snap.tracking_error_m,
                },
            });
        }
        let activity = &self.activity;
        self.progress.live(|| {
            format!(
                "  {activity} | t {:6.2} s | tip ({:+.3}, {:+.3}) m | error {:5.2} mm | {:5.1} Hz | {}",
                snap.t_s,
                snap.tip_meas[0],
                snap.tip_meas[1],
                snap.tracking_error_m * 1e3,
                snap.loop_hz,
                snap.state
            )
        });
        self.latest = Some(snap.clone());
    }

    /// The arm's state as the latest telemetry says it.
    fn state(&self) -> String {
        self.latest
            .as_ref()
            .map_or_else(|| "unknown".to_owned(), |s| s.state.to_string())
    }

    fn begin_phase(&mut self, label: &str, pictured: bool, reference: Vec<[f64; 2]>) {
        let t = self.latest.as_ref().map_or(0.0, |s| s.t_s);
        self.phases.push(Phase {
            label: label.to_owned(),
            t0: t,
            t1: t,
            reference,
            pictured,
            world: None,
        });
    }

    fn end_phase(&mut self) {
        let t = self.latest.as_ref().map_or(0.0, |s| s.t_s);
        if let Some(p) = self.phases.last_mut() {
            p.t1 = t;
        }
    }
}

impl Session<'_> {
    /// Records what comes until the latest telemetry satisfies `done`.
    fn wait_for(
        &mut self,
        done: impl Fn(&Snapshot) -> bool,
        timeout: Duration,
        what: &str,
    ) -> anyhow::Result<Snapshot> {
        if let Some(latest) = self.rec.latest.as_ref().filter(|s| done(s)) {
            return Ok(latest.clone());
        }
        let rec = &mut self.rec;
        let found = self
            .client
            .watch(timeout, |seen| -> anyhow::Result<Option<Snapshot>> {
                rec.take(seen)?;
                Ok(match seen {
                    Seen::Telemetry(_) => rec.latest.as_ref().filter(|s| done(s)).cloned(),
                    Seen::Reply(_) | Seen::Event(_) => None,
                })
            })?;
        found.ok_or_else(|| anyhow!("waited {} s for {what} in vain", timeout.as_secs()))
    }

    /// Records what comes until an event `kind` (about any request) comes; a command ending
    /// meanwhile fails the run.
    fn wait_event(&mut self, kind: EventKind, timeout: Duration) -> anyhow::Result<ProtocolEvent> {
        let rec = &mut self.rec;
        let found =
            self.client
                .watch(timeout, |seen| -> anyhow::Result<Option<ProtocolEvent>> {
                    rec.take(seen)?;
                    let Seen::Event(e) = seen else {
                        return Ok(None);
                    };
                    if e.kind() == Some(kind) {
                        return Ok(Some(e.clone()));
                    }
                    let reason = match &e.what {
                        What::Saturated { .. } => String::new(),
                        What::Preempted { reason, .. } => format!(" ({reason})"),
                        What::Stopped { reason, .. } => format!(" ({reason})"),
                        _ => return Ok(None),
                    };
                    bail!(
                        "waiting for `{kind}`, the command ended `{}`{reason} at tick {}",
                        e.what.name(),
                        e.tick
                    )
                })?;
        match found {
            Some(e) => Ok(e),
            None => bail!(
                "no `{kind}` event within {:.1} s (state {})",
                timeout.as_secs_f64(),
                self.rec.state()
            ),
        }
    }

    /// Sends a motion command and records what comes until it ends; an ending other than
    /// the one `wanted` fails the run.
    fn run_motion(
        &mut self,
        cmd: &Cmd,
        wanted: fn(&Ending) -> bool,
        timeout: Duration,
    ) -> anyhow::Result<(Motion, Ending)> {
        let motion = self.client.start_motion(cmd)?;
        let rec = &mut self.rec;
        let ending = self
            .client
            .wait_ending(&motion, timeout, |seen| rec.take(seen))?;
        match ending {
            Some(ending) if wanted(&ending) => Ok((motion, ending)),
            Some(ending) => bail!("`{}` ended: {ending}", motion.cmd),
            None => bail!(
                "`{}` did not end within {:.1} s (state {})",
                motion.cmd,
                timeout.as_secs_f64(),
                self.rec.state()
            ),
        }
    }

    /// A `goto`, waited for.
    fn goto(&mut self, target: [f64; 2], max_tip_speed: f64) -> anyhow::Result<()> {
        let from = self.rec.latest.as_ref().map_or(target, |s| s.tip);
        let distance = (target[0] - from[0]).hypot(target[1] - from[1]);
        self.run_motion(
            &Cmd::Goto {
                target,
                speed: None,
            },
            |e| matches!(e, Ending::Arrived { .. }),
            secs(distance / max_tip_speed) + SLACK,
        )?;
        Ok(())
    }

    /// One strategy's figure eight: set it, go to the start, zero the statistics, stream the
    /// eight, come to rest, read the figures.
    fn figure_eight(
        &mut self,
        strategy: Strategy,
        eight: &Eight,
        cap_speed: f64,
    ) -> anyhow::Result<StrategyFigures> {
        let name = strategy.name();
        self.client.request(&Cmd::Strategy { name: strategy })?;
        self.rec
            .progress
            .line(format!("{name}: strategy set; to the eight's start"));
        self.rec.activity = format!("{name}: goto start");
        self.rec
            .begin_phase(&format!("{name}: goto"), false, Vec::new());
        self.goto(eight.centre, cap_speed / COMMAND_SHARE)?;
        self.rec.end_phase();
        self.client.request(&Cmd::ResetStats)?;
        // The daemon's count runs on from its start: the eight's are the difference.
        let overruns_before = self.client.status()?.overruns;

        self.rec.progress.line(format!(
            "{name}: figure eight, {:.1} s of `velocity` at {} Hz",
            eight.duration,
            1000 / SEND_PERIOD.as_millis().max(1)
        ));
        self.rec
            .begin_phase(&format!("{name}: eight"), true, eight.polyline());
        let first = self.rec.recs.len();
        let start = Instant::now();
        let mut next_send = start;
        let mut sent = 0u64;
        let mut next_note = 5.0;
        loop {
            let tau = start.elapsed().as_secs_f64();
            if tau >= eight.duration {
                break;
            }
            if Instant::now() >= next_send {
                let (p, v) = eight.at(tau);
                let tip = self.rec.latest.as_ref().map_or(p, |s| s.tip);
                let mut cmd = [v[0] + GAIN * (p[0] - tip[0]), v[1] + GAIN * (p[1] - tip[1])];
                let speed = cmd[0].hypot(cmd[1]);
                if speed > cap_speed {
                    cmd = [cmd[0] * cap_speed / speed, cmd[1] * cap_speed / speed];
                }
                self.client.send(&Cmd::Velocity { v: cmd })?;
                sent += 1;
                next_send += SEND_PERIOD;
                // Late (a busy machine): carry on from now, never in a burst.
                let now = Instant::now();
                if next_send < now {
                    next_send = now + SEND_PERIOD;
                }
                self.rec.activity = format!("{name}: eight {tau:5.1}/{:.1} s", eight.duration);
            }
            if !self.rec.progress.tty && tau >= next_note {
                let err = self.rec.latest.as_ref().map_or(0.0, |s| s.tracking_error_m);
                self.rec.progress.line(format!(
                    "{name}: {tau:.0}/{:.0} s, tracking error {:.2} mm",
                    eight.duration,
                    err * 1e3
                ));
                next_note += 5.0;
            }
            let wait = next_send.saturating_duration_since(Instant::now());
            let rec = &mut self.rec;
            let ended =
                self.client
                    .watch(wait, |seen| -> anyhow::Result<Option<ProtocolEvent>> {
                        rec.take(seen)?;
                        Ok(match seen {
                            Seen::Event(e)
                                if matches!(
                                    e.what,
                                    What::Preempted { .. }
                                        | What::Stopped { .. }
                                        | What::Estop { .. }
                                ) =>
                            {
                                Some(e.clone())
                            }
                            Seen::Telemetry(_) | Seen::Reply(_) | Seen::Event(_) => None,
                        })
                    })?;
            if let Some(e) = ended {
                bail!(
                    "{name}: the eight's `velocity` ended `{}` at tick {}",
                    e.what.name(),
                    e.tick
                );
            }
        }
        let end = self.rec.recs.len();
        let loop_figures = self
            .rec
            .latest
            .clone()
            .ok_or_else(|| anyhow!("no telemetry during the eight"))?;
        self.rec.end_phase();

        self.rec.activity = format!("{name}: coming to rest");
        let (zero, _) = self.run_motion(
            &Cmd::Velocity { v: [0.0, 0.0] },
            |e| matches!(e, Ending::Stopped { .. }),
            SLACK,
        )?;
        sent += 1;
        let status = self.client.status()?;
        let command = status
            .command
            .clone()
            .ok_or_else(|| anyhow!("{name}: status reports no command after the eight"))?;
        let last_id = command.id.as_deref().and_then(Value::as_u64);
        if command.kind != CmdName::Velocity || last_id != Some(zero.id) {
            bail!(
                "{name}: status reports `{}` (id {}) as the last command, not the eight's `velocity`",
                command.kind,
                command.id.as_deref().unwrap_or(&Value::Null)
            );
        }

        let recs = &self.rec.recs[first..end];
        let mut errors: Vec<f64> = recs.iter().map(|r| r.sample.tracking_error_m).collect();
        let mut solve: Vec<f64> = recs.iter().map(|r| r.solve_us).collect();
        let peak_tip_speed = recs
            .windows(2)
            .filter(|w| w[1].tick > w[0].tick)
            .map(|w| {
                let (a, b) = (w[0].sample.tip_ref, w[1].sample.tip_ref);
                let dt = (w[1].tick - w[0].tick) as f64 / self.rec.arm.rate_hz;
                (b[0] - a[0]).hypot(b[1] - a[1]) / dt
            })
            .fold(0.0, f64::max);
        let figures = StrategyFigures {
            name,
            peak_joint_speed_rad_s: command.peak_joint_speed_rad_s,
            m3_rad2: command.m3_rad2,
            tracking_error_p50_m: percentile(&mut errors, 0.5),
            tracking_error_max_m: errors.iter().copied().fold(f64::NAN, f64::max),
            loop_hz: loop_figures.loop_hz,
            tick_p99_us: loop_figures.tick_p99_us,
            solve_us_p50: percentile(&mut solve, 0.5),
            solve_us_p99: percentile(&mut solve, 0.99),
            peak_tip_speed_m_s: peak_tip_speed,
            velocity_commands: sent,
            samples: recs.len(),
            saturated_samples: recs.iter().filter(|r| r.saturated).count(),
            overruns: status.overruns.saturating_sub(overruns_before),
        };
        self.rec.progress.line(format!(
            "{name}: at rest; tracking error p50 {:.2} mm, max {:.2} mm; peak joint speed {:.3} rad/s",
            figures.tracking_error_p50_m * 1e3,
            figures.tracking_error_max_m * 1e3,
            figures.peak_joint_speed_rad_s
        ));
        Ok(figures)
    }

    /// A path of four corners with a sudden estop partway, the refusal it brings, the reset,
    /// and the rest of the path.
    fn path_with_estop(
        &mut self,
        eight: &Eight,
        max_tip_speed: f64,
    ) -> anyhow::Result<PathFigures> {
        let d = 0.8 * eight.a;
        let c = eight.centre;
        let (t, u) = (eight.along, eight.across);
        let at = |p: f64, q: f64| [c[0] + p * t[0] + q * u[0], c[1] + p * t[1] + q * u[1]];
        let corners = vec![at(d, 0.0), at(d, -d), at(-d, -d), at(-d, 0.0)];
        let length: f64 = std::iter::once(c)
            .chain(corners.iter().copied())
            .collect::<Vec<_>>()
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .sum();
        // Overall keeps the arm's shape; sequential curls the last joints toward their limits
        // on the way round the corners.
        self.client.request(&Cmd::Strategy {
            name: Strategy::Overall,
        })?;
        self.rec.progress.line(format!(
            "path (overall): {} corners, each taken at a stop; an estop partway",
            corners.len()
        ));
        let mut reference = vec![c];
        reference.extend(&corners);
        self.rec.begin_phase("path, estop", true, reference);
        self.rec.activity = "path".into();
        self.client.send(&Cmd::Path {
            points: corners.clone(),
            speed: None,
        })?;
        let budget = secs(length / max_tip_speed) + SLACK;
        let near = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]);
        let (second, third) = (corners[1], corners[2]);
        self.wait_for(
            |s| near(s.tip, second) < 5e-4,
            budget,
            "the path's second corner",
        )?;
        let half = 0.5 * near(second, third);
        self.wait_for(
            |s| near(s.tip, second) >= half,
            budget,
            "the tip halfway to the third corner",
        )?;

        self.client.request(&Cmd::Estop)?;
        let estop = self.wait_event(EventKind::Estop, SLACK)?;
        let estop_tip = self
            .rec
            .latest
            .as_ref()
            .map_or(estop.what.tip().unwrap_or_default(), |s| s.tip_meas);
        self.rec.progress.line(format!(
            "ESTOP at tick {} with the tip at ({:+.3}, {:+.3}) m: goals frozen, latched",
            estop.tick, estop_tip[0], estop_tip[1]
        ));
        self.rec.activity = "ESTOP latched".into();
        let refused = match self.client.request(&Cmd::Goto {
            target: third,
            speed: None,
        }) {
            Err(ClientError::Refused { rejection, .. }) => rejection.code.to_string(),
            Ok(_) => bail!("a `goto` was accepted while the estop latch was set"),
            Err(e) => return Err(e.into()),
        };
        self.rec
            .progress
            .line(format!("  a `goto` while latched is refused: {refused}"));
        // Stay latched for a second of the daemon's ticks.
        let hold_until = estop.tick + self.rec.arm.rate_hz.round() as u64;
        self.wait_for(|s| s.tick >= hold_until, SLACK, "a second under estop")?;

        self.client.request(&Cmd::Reset)?;
        let reset = self.wait_event(EventKind::Reset, SLACK)?;
        self.wait_for(
            |s| s.state == State::Holding,
            SLACK,
            "the arm holding after reset",
        )?;
        self.rec.progress.line(format!(
            "reset at tick {}: holding the measured pose; the rest of the path",
            reset.tick
        ));
        // The estop ended the first path; the rest of it goes as a new one.
        self.rec.activity = "path, after reset".into();
        let rest = corners[2..].to_vec();
        let (_, arrived) = self.run_motion(
            &Cmd::Path {
                points: rest,
                speed: None,
            },
            |e| matches!(e, Ending::Arrived { .. }),
            budget,
        )?;
        self.rec.end_phase();
        self.rec
            .progress
            .line(format!("path: arrived at tick {}", arrived.tick()));
        Ok(PathFigures {
            corners,
            estop_tick: estop.tick,
            estop_tip,
            refused_while_latched: refused,
            reset_tick: reset.tick,
            arrived_tick: arrived.tick(),
        })
    }
}

/// The points of a sampled curve at least [`ROUTE_STEP_M`] apart, the last one kept: a route
/// drawn from telemetry without a point per sample.
fn thinned(points: impl Iterator<Item = [f64; 2]>) -> Vec<[f64; 2]> {
    let mut kept: Vec<[f64; 2]> = Vec::new();
    let mut last = None;
    for p in points {
        last = Some(p);
        if kept
            .last()
            .is_none_or(|k| (p[0] - k[0]).hypot(p[1] - k[1]) >= ROUTE_STEP_M)
        {
            kept.push(p);
        }
    }
    if let Some(p) = last.filter(|p| kept.last() != Some(p)) {
        kept.push(p);
    }
    kept
}

/// How far apart the points of a route drawn from telemetry are, m.
const ROUTE_STEP_M: f64 = 0.5e-3;

impl Session<'_> {
    /// Under overall: a world set (a post and a shelf between the tip and a pocket), the tip
    /// into the pocket and back along the daemon's routes, and the world cleared. An arm that
    /// cannot get in is reported, not failed: the ending says where it was held.
    fn among_obstacles(
        &mut self,
        eight: &Eight,
        max_tip_speed: f64,
    ) -> anyhow::Result<WorldFigures> {
        self.client.request(&Cmd::Strategy {
            name: Strategy::Overall,
        })?;
        // From home to the eight's centre first: the overall answer depends on the way the
        // arm came, and this way is the one the tests check.
        self.rec
            .begin_phase("home, to the centre", false, Vec::new());
        self.rec.activity = "home".into();
        self.run_motion(&Cmd::Home, |e| matches!(e, Ending::Arrived { .. }), SLACK)?;
        self.goto(eight.centre, max_tip_speed)?;
        self.rec.end_phase();
        let start = eight.centre;
        let theta = self.client.status()?.theta_cmd.clone();
        let link_radius_m = self.client.world()?.link_radius_m;
        let (target, obstacles) = pocket_beside(eight, self.rec.arm.chain(), &theta, link_radius_m);
        let ids: Vec<String> = obstacles.iter().map(|o| o.id.clone()).collect();
        self.client.set_world(obstacles.clone())?;
        let info = self.client.world()?;
        let world = info.to_world()?;
        self.rec.progress.line(format!(
            "among obstacles (overall): {} set; the tip into the pocket at ({:+.3}, {:+.3}) m and back",
            ids.join(" and "),
            target[0],
            target[1]
        ));
        // The reference is the daemon's route, known only as it is taken: filled in below
        // from the telemetry's `tip_ref`.
        self.rec.begin_phase("among obstacles", true, Vec::new());
        if let Some(p) = self.rec.phases.last_mut() {
            p.world = Some(world.clone());
        }
        let first = self.rec.recs.len();
        let straight = (target[0] - start[0]).hypot(target[1] - start[1]);
        // A route round the obstacles is longer than the straight line: twice it is ample.
        let speed = POCKET_SPEED_SHARE * max_tip_speed;
        let budget = secs(2.0 * straight / speed) + SLACK;
        let any = |_: &Ending| true;
        self.rec.activity = "into the pocket".into();
        let (_, way_in) = self.run_motion(
            &Cmd::Goto {
                target,
                speed: Some(speed),
            },
            any,
            budget,
        )?;
        let inside = self.rec.recs.len();
        self.rec.activity = "out of the pocket".into();
        let (_, way_back) = self.run_motion(
            &Cmd::Goto {
                target: start,
                speed: Some(speed),
            },
            any,
            budget,
        )?;
        self.rec.end_phase();
        self.client.set_world(Vec::new())?;
        let route = thinned(self.rec.recs[first..].iter().map(|r| r.sample.tip_ref));
        if let Some(p) = self.rec.phases.last_mut() {
            p.reference = route;
        }
        let recs = &self.rec.recs[first..];
        let route_in_m = self.rec.recs[first..inside]
            .windows(2)
            .map(|w| {
                let (a, b) = (w[0].sample.tip_meas, w[1].sample.tip_meas);
                (b[0] - a[0]).hypot(b[1] - a[1])
            })
            .sum();
        let min_clearance_m = recs
            .iter()
            .filter_map(|r| r.min_clearance_m)
            .fold(f64::INFINITY, f64::min);
        let figures = WorldFigures {
            pocket: target,
            obstacles: ids,
            min_clearance_m,
            clearance_m: world.clearance_m(),
            route_in_m,
            straight_m: straight,
            arrived: matches!(way_in, Ending::Arrived { .. })
                && matches!(way_back, Ending::Arrived { .. }),
            way_in: way_in.to_string(),
            way_back: way_back.to_string(),
        };
        self.rec.progress.line(format!(
            "among obstacles: in {}, back {}; route {:.3} m against {:.3} m straight; least clearance {:.2} mm (kept {:.1} mm); world cleared",
            figures.way_in,
            figures.way_back,
            figures.route_in_m,
            figures.straight_m,
            figures.min_clearance_m * 1e3,
            figures.clearance_m * 1e3
        ));
        Ok(figures)
    }
}

fn secs(s: f64) -> Duration {
    Duration::from_secs_f64(s.clamp(0.0, 3600.0))
}

/// The `p`-quantile (nearest rank) of `values`, sorting them; NaN when empty.
fn percentile(values: &mut [f64], p: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let rank = (p * values.len() as f64).ceil() as usize;
    values[rank.clamp(1, values.len()) - 1]
}

/// The table, `summary.json` and the figures (drawn from the recording).
fn report(demo: &Demo, out: &Path, recording: &Path) -> Result<(), Failure> {
    let s = &demo.summary;
    outln!("")?;
    outln!(
        "{:<11} {:>17} {:>9} {:>9} {:>15} {:>11} {:>22}",
        "strategy",
        "tracking p50/max",
        "loop",
        "tick p99",
        "solve p50/p99",
        "metric 3",
        "peak joint speed"
    )?;
    outln!(
        "{:<11} {:>17} {:>9} {:>9} {:>15} {:>11} {:>22}",
        "",
        "mm",
        "Hz",
        "µs",
        "µs",
        "rad²",
        "rad/s (limit)"
    )?;
    for f in &s.strategies {
        outln!(
            "{:<11} {:>17} {:>9.1} {:>9.0} {:>15} {:>11.5} {:>22}",
            f.name,
            format!(
                "{:.2} / {:.2}",
                f.tracking_error_p50_m * 1e3,
                f.tracking_error_max_m * 1e3
            ),
            f.loop_hz,
            f.tick_p99_us,
            format!("{:.0} / {:.0}", f.solve_us_p50, f.solve_us_p99),
            f.m3_rad2,
            format!(
                "{:.3} ({:.1})",
                f.peak_joint_speed_rad_s, s.max_joint_speed_rad_s
            )
        )?;
    }
    outln!(
        "estop at tick {} (a `goto` then: {}), reset at tick {}, path arrived at tick {}",
        s.path.estop_tick,
        s.path.refused_while_latched,
        s.path.reset_tick,
        s.path.arrived_tick
    )?;

    outln!(
        "among obstacles (overall): into the pocket {}, back {}; the tip's way in {:.3} m \
         against {:.3} m straight; least clearance {:.2} mm (kept: {:.1} mm)",
        s.world.way_in,
        s.world.way_back,
        s.world.route_in_m,
        s.world.straight_m,
        s.world.min_clearance_m * 1e3,
        s.world.clearance_m * 1e3
    )?;

    let json = serde_json::to_string_pretty(s).map_err(Failure::other)?;
    let summary = format!("{json}\n");
    let mut written = vec![super::plot::write_file(
        out,
        "summary.json",
        summary.as_bytes(),
    )?];
    let record = Recording::open(recording)
        .map_err(|e| Failure::other(anyhow::Error::new(e).context("the demo's recording")))?
        .plot_record();
    written.extend(super::plot::figures(
        &record,
        out,
        "snakectl demo: the tip steered over the socket, as a joystick would",
        "snakectl demo: joint angles and tracking error over the run",
    )?);
    written.push(recording.to_path_buf());
    outln!("")?;
    outln!("written to {}:", out.display())?;
    for path in written {
        outln!("  {}", path.display())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    fn sim_arm() -> ArmInfo {
        ArmInfo::new(snakectl::protocol::Describe {
            links_m: vec![0.08; 12],
            base: [0.0, 0.0, std::f64::consts::FRAC_PI_2],
            home_rad: vec![0.1; 12],
            rate_hz: 100.0,
            ..Default::default()
        })
        .unwrap()
    }

    #[test]
    fn the_eight_starts_and_ends_at_rest_at_its_centre() {
        for seconds in [3.0, 15.0, 60.0] {
            let eight = Eight::new(&sim_arm(), seconds, 0.1);
            for tau in [0.0, seconds] {
                let (p, v) = eight.at(tau);
                let off = (p[0] - eight.centre[0]).hypot(p[1] - eight.centre[1]);
                assert!(off < 1e-9, "{seconds} s: {off} m off the centre at {tau} s");
                assert!(v[0].hypot(v[1]) < 1e-12, "{seconds} s: moving at {tau} s");
            }
        }
    }

    #[test]
    fn the_eight_keeps_under_its_speed_share_and_inside_the_reach() {
        for seconds in [2.0, 3.0, 15.0, 600.0] {
            let arm = sim_arm();
            let eight = Eight::new(&arm, seconds, 0.1);
            let (mut fastest, mut farthest) = (0.0f64, 0.0f64);
            let mut last = eight.at(0.0).0;
            for k in 1..=20_000 {
                let tau = seconds * f64::from(k) / 20_000.0;
                let (p, v) = eight.at(tau);
                fastest = fastest.max(v[0].hypot(v[1]));
                farthest = farthest.max(p[0].hypot(p[1]));
                // The velocity is the derivative of the point.
                let dt = seconds / 20_000.0;
                let step = ((p[0] - last[0]) / dt - v[0]).hypot((p[1] - last[1]) / dt - v[1]);
                assert!(step < 1e-3 + 0.05 * fastest, "{seconds} s at {tau}: {step}");
                last = p;
            }
            assert!(
                fastest <= SPEED_SHARE * 0.1 + 1e-9,
                "{seconds} s: {fastest} m/s"
            );
            assert!(
                fastest > 0.5 * SPEED_SHARE * 0.1,
                "{seconds} s: {fastest} m/s"
            );
            assert!(farthest < 0.9 * arm.reach(), "{seconds} s: {farthest} m");
        }
    }

    /// The phase among obstacles, run on the controller alone from the eight's centre, for
    /// both shipped arms (the simulated one of 12 links the demo runs, and the 8-link arm of
    /// `config/arm.toml`): the pocket's obstacles are clear of the arm there, the straight
    /// line is blocked, and overall takes the tip in and back out, clear throughout.
    #[test]
    fn the_pocket_is_reached_round_the_post_under_overall() {
        for file in ["sim.toml", "arm.toml"] {
            let path = format!("{}/config/{file}", env!("CARGO_MANIFEST_DIR"));
            let config = Config::load(&path).unwrap();
            let chain = config.chain();
            let arm = ArmInfo::new(snakectl::protocol::Describe {
                links_m: chain.links().to_vec(),
                base: [chain.base().x, chain.base().y, chain.heading()],
                home_rad: config.home().to_vec(),
                rate_hz: 100.0,
                ..Default::default()
            })
            .unwrap();
            pocket_round_the_post(&arm, file);
        }
    }

    fn pocket_round_the_post(arm: &ArmInfo, file: &str) {
        use snakectl::control::{Command, Controller, Finish, Limits};
        let eight = Eight::new(arm, 15.0, 0.1);
        let limits = Limits {
            max_tip_speed_m_s: 0.1,
            max_tip_accel_m_s2: 0.5,
            max_joint_speed_rad_s: 2.0,
            deadman_s: 0.5,
        };
        let home = arm.home_rad.clone();
        let n = home.len();
        let mut ctl = Controller::new(
            arm.chain().clone(),
            limits,
            Strategy::Overall,
            home.clone(),
            &home,
        )
        .unwrap();
        // As the daemon does: goals go out in whole servo ticks.
        ctl.set_joint_resolution(&vec![std::f64::consts::TAU / 4096.0; n])
            .unwrap();
        let run = |ctl: &mut Controller, to: Vec2| {
            ctl.command(Command::Goto {
                target: to,
                speed: None,
            })
            .unwrap();
            (0..5000).find_map(|_| ctl.tick(0.01).finished)
        };
        let c = Vec2::new(eight.centre[0], eight.centre[1]);
        assert_eq!(run(&mut ctl, c), Some(Finish::Arrived), "{file}");
        let (target, obstacles) = pocket_beside(&eight, arm.chain(), ctl.theta(), 0.0);
        let world = World::new(0.0, 0.005, obstacles).unwrap();
        let t = Vec2::new(target[0], target[1]);
        assert!(
            world.route(c, t).unwrap().waypoints.len() > 2,
            "{file}: the straight line is clear"
        );
        let nc = ctl.set_world(world.clone());
        assert!(nc.is_none(), "{file}: the centre pose is clear: {nc:?}");
        let mut least = f64::INFINITY;
        for to in [t, c] {
            ctl.command(Command::Goto {
                target: to,
                speed: Some(POCKET_SPEED_SHARE * 0.1),
            })
            .unwrap();
            let mut finish = None;
            for _ in 0..5000 {
                let tick = ctl.tick(0.01);
                least = least.min(tick.min_clearance_m.unwrap());
                if tick.finished.is_some() {
                    finish = tick.finished;
                    break;
                }
            }
            assert_eq!(finish, Some(Finish::Arrived), "{file}: to {to:?}");
        }
        assert!(least >= 0.005 - 1e-9, "{file}: {least}");
    }

    #[test]
    fn percentiles_are_nearest_rank() {
        let mut v = vec![5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(percentile(&mut v, 0.5), 3.0);
        assert_eq!(percentile(&mut v, 0.99), 5.0);
        assert_eq!(percentile(&mut v, 0.0), 1.0);
        assert!(percentile(&mut [], 0.5).is_nan());
    }
}
