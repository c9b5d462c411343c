//! The `snakectl` command line: parse the arguments, run the subcommand, print the error chain
//! once, exit with its code (0 done, 2 bad input, 1 anything else).

use std::io::Read;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};

use snakectl::chain::Vec2;
use snakectl::config::Config;
use snakectl::problem::{self, Problem, ProblemError};

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
    Solve(SolveArgs),
    /// Serve the config's servo chain, simulated, on a pseudo-terminal until Ctrl-C or SIGTERM.
    Sim(SimArgs),
}

#[derive(Debug, Args)]
struct SimArgs {
    /// Config file: the servos (ids, models, limits), `[bus]` baud and delay, `[sim]` faults.
    #[arg(long)]
    config: PathBuf,
    /// Also make this path a symlink to the pseudo-terminal (replacing an old symlink).
    #[arg(long)]
    link: Option<PathBuf>,
    /// Log every packet (debug level); `RUST_LOG` overrides.
    #[arg(short, long)]
    verbose: bool,
}

#[derive(Debug, Args)]
struct SolveArgs {
    /// Problem file in the JSON format of the README; `-` reads stdin.
    #[arg(conflicts_with_all = ["config", "from"], required_unless_present = "config")]
    problem: Option<PathBuf>,
    /// Take the arm from this config file instead of a problem file.
    #[arg(long, requires = "target")]
    config: Option<PathBuf>,
    /// Tip target `X,Y` in metres (with `--config`).
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    target: Option<String>,
    /// Start pose `t1,t2,..` in radians (with `--config`; default: the config's home pose).
    #[arg(long, value_name = "T1,..", allow_hyphen_values = true)]
    from: Option<String>,
    /// Strategy (with `--config`): overall or sequential.
    #[arg(long, default_value = "overall")]
    strategy: String,
    /// Elemental step of the sequential strategy (with `--config`): tractrix or distance.
    #[arg(long)]
    propagation: Option<String>,
    /// Equal straight sub-moves of the tip (with `--config`).
    #[arg(long, default_value_t = 1)]
    steps: u64,
    /// Indent the JSON answer.
    #[arg(long)]
    pretty: bool,
}

/// An error and the exit code it maps to.
struct Failure {
    code: u8,
    error: anyhow::Error,
}

impl Failure {
    fn bad_input(error: impl Into<anyhow::Error>) -> Self {
        Self {
            code: 2,
            error: error.into(),
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Solve(args) => solve(args),
        Command::Sim(args) => sim(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("snakectl: {:#}", f.error);
            ExitCode::from(f.code)
        }
    }
}

fn solve(args: SolveArgs) -> Result<(), Failure> {
    let problem = match (&args.problem, &args.config) {
        (Some(path), _) => problem_from_file(path)?,
        (None, Some(config)) => problem_from_config(config, &args)?,
        (None, None) => {
            return Err(Failure::bad_input(anyhow::anyhow!(
                "give a problem file or --config"
            )))
        }
    };
    let answer = problem.solve();
    let text = if args.pretty {
        serde_json::to_string_pretty(&answer)
    } else {
        serde_json::to_string(&answer)
    }
    .map_err(|e| Failure {
        code: 1,
        error: e.into(),
    })?;
    println!("{text}");
    Ok(())
}

fn sim(args: SimArgs) -> Result<(), Failure> {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;

    let default = if args.verbose { "debug" } else { "info" };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
    let other = |e: anyhow::Error| Failure { code: 1, error: e };
    let config = Config::load(&args.config).map_err(Failure::bad_input)?;
    let sim_config = snakectl::simbus::sim_config(&config)
        .map_err(|e| Failure::bad_input(anyhow::anyhow!("{}: {e}", args.config.display())))?;
    let simulator = snakectl_sim::Simulator::new(sim_config, Arc::new(snakectl_sim::RealClock))
        .map_err(|e| Failure::bad_input(anyhow::anyhow!("{}: {e}", args.config.display())))?;
    let handle = snakectl_sim::spawn_pty(simulator).map_err(|e| other(e.into()))?;
    if let Some(link) = &args.link {
        if link
            .symlink_metadata()
            .is_ok_and(|m| m.file_type().is_symlink())
        {
            std::fs::remove_file(link)
                .map_err(|e| other(anyhow::anyhow!("{}: {e}", link.display())))?;
        }
        std::os::unix::fs::symlink(handle.path(), link)
            .map_err(|e| other(anyhow::anyhow!("{}: {e}", link.display())))?;
    }
    // Printed once the link exists: a script reading this line may use either at once.
    println!("{}", handle.path().display());
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .map_err(|e| other(anyhow::anyhow!("installing the signal handler: {e}")))?;
    }
    while !stop.load(Ordering::Relaxed) && handle.is_running() {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    if let Some(link) = &args.link {
        let _ = std::fs::remove_file(link);
    }
    tracing::info!("stopping");
    handle.stop().map_err(|e| other(e.into()))
}

fn problem_from_file(path: &PathBuf) -> Result<Problem, Failure> {
    let text = if path.as_os_str() == "-" {
        let mut s = String::new();
        std::io::stdin()
            .read_to_string(&mut s)
            .map_err(|e| Failure::bad_input(anyhow::anyhow!("stdin: {e}")))?;
        s
    } else {
        std::fs::read_to_string(path)
            .map_err(|e| Failure::bad_input(anyhow::anyhow!("{}: {e}", path.display())))?
    };
    Problem::from_json(&text).map_err(|e| {
        let name = if path.as_os_str() == "-" {
            "stdin".to_string()
        } else {
            path.display().to_string()
        };
        Failure::bad_input(anyhow::anyhow!("{name}: {e}"))
    })
}

/// Parses `a,b,c` into numbers, naming the flag on error.
fn list(flag: &str, text: &str) -> Result<Vec<f64>, ProblemError> {
    text.split(',')
        .map(|s| {
            s.trim().parse::<f64>().map_err(|_| ProblemError {
                field: flag.into(),
                message: format!("{s:?} is not a number"),
            })
        })
        .collect()
}

fn problem_from_config(path: &PathBuf, args: &SolveArgs) -> Result<Problem, Failure> {
    let config = Config::load(path).map_err(Failure::bad_input)?;
    let build = || -> Result<Problem, ProblemError> {
        let target = list("--target", args.target.as_deref().unwrap_or_default())?;
        if target.len() != 2 || target.iter().any(|v| !v.is_finite()) {
            return Err(ProblemError {
                field: "--target".into(),
                message: "expected two finite numbers X,Y".into(),
            });
        }
        let chain = config.chain().clone();
        let theta0 = match &args.from {
            Some(text) => list("--from", text)?,
            None => config.home().to_vec(),
        };
        problem::check_pose(&chain, "--from", &theta0)?;
        let strategy = problem::parse_strategy(&args.strategy)?;
        let base_mode = problem::BaseMode::Fixed;
        problem::check_combination(strategy, base_mode, args.propagation.is_some())?;
        Ok(Problem {
            chain,
            theta0,
            target: Vec2::new(target[0], target[1]),
            strategy,
            base_mode,
            propagation: problem::parse_propagation(
                args.propagation.as_deref().unwrap_or("tractrix"),
            )?,
            steps: problem::parse_steps(args.steps)?,
        })
    };
    build().map_err(|e| Failure::bad_input(anyhow::anyhow!("{}: {e}", path.display())))
}
