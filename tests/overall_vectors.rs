//! The cold overall solve against the independent reference optima in `tests/data/vectors`.
//!
//! Every `overall_*.problem.json` must be solved to its expected global minimum of metric 3
//! (within 1e-9 relative), with the tip on target (within 1e-9 m) and no joint outside its
//! limits by any amount. The vectors are part of the repository: a missing, empty or
//! incomplete directory fails the test rather than letting it pass on nothing.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use serde::Deserialize;
use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::resolve::overall::{Overall, OverallOptions};

#[derive(Deserialize)]
struct ProblemFile {
    links: Vec<f64>,
    base: [f64; 3],
    theta0: Vec<f64>,
    #[serde(default)]
    limits: Option<Vec<[f64; 2]>>,
    target: [f64; 2],
}

#[derive(Deserialize)]
struct ExpectedFile {
    theta: Vec<f64>,
    metric3: f64,
}

/// Fewest vectors the directory must hold: 9 unconstrained plus 6 with box limits.
const MIN_OVERALL: usize = 15;
/// Fewest of them with box limits (`overall_limits_*`).
const MIN_LIMITED: usize = 6;

fn vectors_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/vectors")
}

/// The `overall_*` problem files, sorted; panics if the directory cannot be read, if a problem
/// has no expected answer next to it, or if fewer vectors than the minimum are present.
fn overall_problems(dir: &Path) -> Vec<PathBuf> {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| {
        panic!(
            "reference vectors missing: cannot read {}: {e}",
            dir.display()
        )
    });
    let mut names: Vec<PathBuf> = entries
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            name.starts_with("overall_") && name.ends_with(".problem.json")
        })
        .collect();
    names.sort();
    for p in &names {
        let expected = expected_path(p);
        assert!(
            expected.is_file(),
            "{} has no expected answer {}",
            p.display(),
            expected.display()
        );
    }
    let limited = names
        .iter()
        .filter(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("overall_limits_")
        })
        .count();
    assert!(
        names.len() >= MIN_OVERALL && limited >= MIN_LIMITED,
        "{} holds {} overall vectors ({limited} with limits); at least {MIN_OVERALL} \
         ({MIN_LIMITED} with limits) expected",
        dir.display(),
        names.len()
    );
    names
}

fn expected_path(problem: &Path) -> PathBuf {
    let name = problem.file_name().unwrap().to_string_lossy();
    problem.with_file_name(name.replace(".problem.json", ".expected.json"))
}

#[test]
fn cold_solve_reaches_every_reference_optimum() {
    let names = overall_problems(&vectors_dir());
    let mut solver = Overall::new(OverallOptions::default());
    let mut failures = Vec::new();
    for path in &names {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let problem: ProblemFile =
            serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let expected: ExpectedFile =
            serde_json::from_str(&std::fs::read_to_string(expected_path(path)).unwrap()).unwrap();
        assert_eq!(
            problem.limits.is_some(),
            name.starts_with("overall_limits_"),
            "{name}: limits present exactly in the overall_limits_* vectors"
        );
        let limits = problem
            .limits
            .as_ref()
            .map(|l| {
                l.iter()
                    .map(|&[lo, hi]| Some(JointLimit { lo, hi }))
                    .collect()
            })
            .unwrap_or_default();
        let chain = Chain::new(
            problem.links.clone(),
            Vec2::new(problem.base[0], problem.base[1]),
            problem.base[2],
            limits,
        )
        .unwrap();
        let target = Vec2::new(problem.target[0], problem.target[1]);
        let mut out = vec![0.0; chain.len()];
        let o = solver.solve_cold(&chain, &problem.theta0, target, &mut out);
        let metric3: f64 = out
            .iter()
            .zip(&problem.theta0)
            .map(|(a, b)| (a - b) * (a - b))
            .sum();
        let tip_error = (chain.tip(&out) - target).norm();
        let rel = (metric3 - expected.metric3).abs() / expected.metric3.abs().max(1e-300);
        let dtheta = out
            .iter()
            .zip(&expected.theta)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        println!(
            "{name}: metric3 {metric3:.15e} (expected {:.15e}, rel {rel:.1e}), tip {tip_error:.1e} m, \
             max |theta - expected| {dtheta:.1e}, iterations {}, converged {}",
            expected.metric3, o.iterations, o.converged
        );
        let within = chain.check_limits(&out);
        if rel > 1e-9 || tip_error > 1e-9 || within.is_err() || !o.reachable {
            failures.push(format!(
                "{name}: rel {rel:.2e}, tip {tip_error:.2e}, limits {within:?}, reachable {}",
                o.reachable
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "missed vectors:\n{}",
        failures.join("\n")
    );
}
