//! `snakectl solve`: one tip move from a JSON problem or a config file, answered as JSON.

use std::path::PathBuf;

use clap::Args;

use snakectl::config::Config;
use snakectl::problem::{self, Problem, ProblemError};
use snakectl::textfile::{read_capped, read_text, MAX_TEXT_BYTES};

use super::{outln, Failure};

#[derive(Debug, Args)]
pub struct SolveArgs {
    /// Problem file in the JSON format of docs/SOLVE.md; `-` reads stdin. It says everything
    /// itself: the flags that go with `--config` are refused beside it, not ignored.
    #[arg(
        conflicts_with_all = ["config", "from", "target", "strategy", "propagation", "steps"],
        required_unless_present = "config"
    )]
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

/// Runs `snakectl solve`.
pub fn run(args: SolveArgs) -> Result<(), Failure> {
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
    .map_err(Failure::other)?;
    outln!("{text}")?;
    Ok(())
}

fn problem_from_file(path: &std::path::Path) -> Result<Problem, Failure> {
    let text = if path.as_os_str() == "-" {
        read_capped(std::io::stdin().lock(), MAX_TEXT_BYTES)
            .map_err(|e| Failure::bad_input(anyhow::anyhow!("stdin: {e}")))?
    } else {
        read_text(path, MAX_TEXT_BYTES)
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

/// An error of a problem's field renamed to the command-line flag that gave it.
fn flag(name: &'static str) -> impl Fn(ProblemError) -> ProblemError {
    move |e| ProblemError {
        field: name.into(),
        ..e
    }
}

fn problem_from_config(path: &PathBuf, args: &SolveArgs) -> Result<Problem, Failure> {
    let config = Config::load(path).map_err(Failure::bad_input)?;
    let build = || -> Result<Problem, ProblemError> {
        let target = list("--target", args.target.as_deref().unwrap_or_default())?;
        let target = problem::check_target("--target", &target)?;
        let chain = config.chain().clone();
        let theta0 = match &args.from {
            Some(text) => list("--from", text)?,
            None => config.home().to_vec(),
        };
        problem::check_pose(&chain, "--from", &theta0)?;
        let strategy = problem::parse_strategy(&args.strategy).map_err(flag("--strategy"))?;
        let base_mode = problem::BaseMode::Fixed;
        problem::check_combination(strategy, base_mode, args.propagation.is_some())
            .map_err(flag("--propagation"))?;
        Ok(Problem {
            chain,
            theta0,
            target,
            strategy,
            base_mode,
            propagation: problem::parse_propagation(
                args.propagation.as_deref().unwrap_or("tractrix"),
            )
            .map_err(flag("--propagation"))?,
            steps: problem::parse_steps(args.steps).map_err(flag("--steps"))?,
            objective: problem::parse_objective(None, None, strategy, base_mode)?,
            world: config.world().clone(),
        })
    };
    build().map_err(|e| Failure::bad_input(anyhow::anyhow!("{}: {e}", path.display())))
}
