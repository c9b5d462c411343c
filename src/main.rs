//! The `snakectl` command line: parse the arguments, run the subcommand, print the error chain
//! once, exit with its code (0 done, 2 bad input, 1 anything else).

mod cli;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Controller and simulator for planar snake arms and flexible ropes.
#[derive(Debug, Parser)]
#[command(name = "snakectl", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
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
    /// List the servos on a port: id, model, firmware (tries the common baud rates).
    Scan(cli::servo::ScanArgs),
    /// List serial ports with their USB vendor:product (a U2D2 is named as such).
    Ports(cli::servo::PortsArgs),
    /// One servo: set id, baud rate, Return Delay Time; info (calibration), reboot, torque off.
    Servo(cli::servo::ServoArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Solve(args) => cli::solve::run(args),
        Command::Run(args) => cli::run::run(args),
        Command::Sim(args) => cli::sim::run(args),
        Command::Simulate(args) => cli::simulate::run(args),
        Command::Scan(args) => cli::servo::scan(args),
        Command::Ports(args) => cli::servo::ports(args),
        Command::Servo(args) => cli::servo::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            if f.code != 0 {
                eprintln!("snakectl: {:#}", f.error);
            }
            ExitCode::from(f.code)
        }
    }
}
