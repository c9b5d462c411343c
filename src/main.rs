//! The `snakectl` command line: parse the arguments, run the subcommand, print the error chain
//! once, exit with its code (0 done, 2 bad input, 1 anything else).

mod cli;

use std::io::Write as _;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Controller and simulator for planar snake arms and flexible ropes. With no subcommand:
/// `snakectl demo`.
#[derive(Debug, Parser)]
#[command(
    name = "snakectl",
    version,
    about,
    after_help = "With no subcommand: `snakectl demo` (the daemon on the simulated arm, driven through its socket, figures at the end)."
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Resolve one tip move: joint angles, points, flags and metrics as one JSON object.
    Solve(cli::solve::SolveArgs),
    /// The control daemon: steer the arm's tip over a JSON-lines socket until Ctrl-C or SIGTERM.
    Run(cli::run::RunArgs),
    /// Serve the config's servo chain, simulated, on a pseudo-terminal until Ctrl-C or SIGTERM.
    Sim(cli::sim::SimArgs),
    /// Run a flexible-object scenario: figures (SVG, PNG) and the metrics table.
    Simulate(cli::simulate::SimulateArgs),
    /// List the servos on a port: id, model, firmware (tries every baud rate without `--baud`).
    Scan(cli::servo::ScanArgs),
    /// List serial ports with their USB vendor:product (a U2D2 is named as such).
    Ports(cli::servo::PortsArgs),
    /// One servo: set id, baud rate, Return Delay Time; info (calibration), reboot, torque off.
    Servo(cli::servo::ServoArgs),
    /// The whole product in one command: simulator, daemon, a client driving them; a summary
    /// table, `summary.json` and figures (what `cargo run --release` runs).
    Demo(cli::demo::DemoArgs),
    /// Draw the demo's figures (motion, joint angles, tracking error) from a recording (MCAP).
    Plot(cli::plot::PlotArgs),
    /// Steer the tip from the keyboard or a joystick in a terminal UI, the arm drawn live.
    Teleop(cli::teleop::TeleopArgs),
    /// The daemon's latest telemetry, one JSON object.
    Status(cli::client::PlainArgs),
    /// The arm's description (links, limits, servos, strategies), one JSON object.
    Describe(cli::client::PlainArgs),
    /// Move the tip to X Y (m) in a straight line, or round obstacles by the shortest clear
    /// route; waits for the arrival.
    Goto(cli::client::GotoArgs),
    /// Move the tip along the corners of a CSV file (x,y in m), stopping at each.
    Path(cli::client::PathArgs),
    /// Move the tip to X Y (m) by a clear way in joint space round the obstacles, the whole
    /// arm at once (for where a `goto` ends blocked, its body caught on an obstacle); waits
    /// for the arrival.
    Reach(cli::client::ReachArgs),
    /// Decelerate to rest and hold.
    Stop(cli::client::PlainArgs),
    /// Emergency stop: freeze, torque off (or hold), latched until `reset`.
    Estop(cli::client::PlainArgs),
    /// Clear the estop latch: hold the measured pose, torque on.
    Reset(cli::client::PlainArgs),
    /// Reboot servos to clear a hardware error (default: those in one, else all); the arm is
    /// brought up again where it stands.
    Reboot(cli::client::RebootArgs),
    /// Move the joints to the home pose.
    Home(cli::client::HomeArgs),
    /// Switch the strategy live: `overall` or `sequential`.
    Strategy(cli::client::StrategyArgs),
    /// Telemetry as JSON lines until Ctrl-C.
    Watch(cli::client::WatchArgs),
    /// The obstacles the arm keeps clear of: print them, or set, add, remove or clear them.
    World(cli::world::WorldArgs),
    /// The configured arm as a URDF on stdout (for robot_state_publisher and RViz).
    Urdf(cli::urdf::UrdfArgs),
    /// The arms on a Zenoh network, one line each: state, measured tip, strategy, controller
    /// (a build with `--features zenoh`).
    Fleet(cli::fleet::FleetArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // A file-size limit makes a write fail (EFBIG), never kills the process (SIGXFSZ).
    if let Err(e) = cli::signals::survive_file_size_limit() {
        let _ = writeln!(std::io::stderr(), "snakectl: catching SIGXFSZ: {e}");
        return ExitCode::from(1);
    }
    let result = match cli
        .command
        .unwrap_or(Command::Demo(cli::demo::DemoArgs::default()))
    {
        Command::Solve(args) => cli::solve::run(args),
        Command::Run(args) => cli::run::run(args),
        Command::Sim(args) => cli::sim::run(args),
        Command::Simulate(args) => cli::simulate::run(args),
        Command::Scan(args) => cli::servo::scan(args),
        Command::Ports(args) => cli::servo::ports(args),
        Command::Servo(args) => cli::servo::run(args),
        Command::Demo(args) => cli::demo::run(args),
        Command::Teleop(args) => cli::teleop::run(args),
        Command::Plot(args) => cli::plot::run(args),
        Command::Status(args) => cli::client::status(args),
        Command::Describe(args) => cli::client::describe(args),
        Command::Goto(args) => cli::client::goto(args),
        Command::Path(args) => cli::client::path(args),
        Command::Reach(args) => cli::client::reach(args),
        Command::Stop(args) => cli::client::stop(args),
        Command::Estop(args) => cli::client::estop(args),
        Command::Reset(args) => cli::client::reset(args),
        Command::Reboot(args) => cli::client::reboot(args),
        Command::Home(args) => cli::client::home(args),
        Command::Strategy(args) => cli::client::strategy(args),
        Command::Watch(args) => cli::client::watch(args),
        Command::World(args) => cli::world::run(args),
        Command::Urdf(args) => cli::urdf::run(args),
        Command::Fleet(args) => cli::fleet::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            if f.code != 0 {
                // Not `eprintln!`: a terminal hung up would make it panic. Ended by a signal, the
                // process does not wait long for a terminal that takes no output.
                let line = format!("snakectl: {}\n", with_causes(&f.error));
                let wait =
                    cli::signals::ending_on_signal().then_some(cli::term_out::LAST_LINE_WAIT);
                let _ = cli::term_out::to_stderr(line.as_bytes(), wait);
            }
            ExitCode::from(f.code)
        }
    }
}

/// The error and its causes, joined by `: `. A cause is left out where the message before it
/// already says it: the library's errors name their source in their own message (and also
/// return it as their `source`), so the plain chain would print it twice.
fn with_causes(error: &anyhow::Error) -> String {
    let mut text = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text.push_str(": ");
            text.push_str(&cause);
        }
    }
    text
}
