//! The free-tail sequential tractrix against the reference answers in `tests/data/vectors/free_*`
//! (computed outside this project), through the same `Problem` path `snakectl solve` uses.
//! The vectors are part of the repository: a missing, empty or incomplete directory fails.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use serde::Deserialize;
use snakectl::problem::Problem;

#[derive(Deserialize)]
struct Expected {
    theta: Vec<f64>,
    points: Vec<[f64; 2]>,
    base_displacement: f64,
}

/// Fewest free-tail vectors per step count the directory must hold (one step and eight steps).
const MIN_PER_STEPS: usize = 2;

fn expected_path(problem: &Path) -> PathBuf {
    let name = problem.file_name().unwrap().to_string_lossy();
    problem.with_file_name(name.replace(".problem.json", ".expected.json"))
}

/// The `free_*` problem files, sorted; panics if the directory cannot be read, if a problem has
/// no expected answer next to it, or if there are too few of either step count.
fn vectors() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/vectors");
    let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| {
        panic!(
            "reference vectors missing: cannot read {}: {e}",
            dir.display()
        )
    });
    let mut out: Vec<PathBuf> = entries
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name.starts_with("free_") && name.ends_with(".problem.json")
        })
        .collect();
    out.sort();
    for p in &out {
        assert!(
            expected_path(p).is_file(),
            "{} has no expected answer next to it",
            p.display()
        );
    }
    let count = |steps: &str| {
        out.iter()
            .filter(|p| {
                p.to_string_lossy()
                    .ends_with(&format!(".{steps}.problem.json"))
            })
            .count()
    };
    let (one, eight) = (count("steps1"), count("steps8"));
    assert!(
        one >= MIN_PER_STEPS && eight >= MIN_PER_STEPS,
        "{} holds {one} one-step and {eight} eight-step free vectors; at least \
         {MIN_PER_STEPS} of each expected",
        dir.display()
    );
    out
}

#[test]
fn free_tail_tractrix_matches_the_reference_vectors() {
    for problem_file in vectors() {
        let expected_file = expected_path(&problem_file);
        let problem = Problem::from_json(&std::fs::read_to_string(&problem_file).unwrap())
            .unwrap_or_else(|e| panic!("{}: {e}", problem_file.display()));
        let expected: Expected =
            serde_json::from_str(&std::fs::read_to_string(&expected_file).unwrap()).unwrap();
        let answer = problem.solve();
        let name = problem_file.display();
        assert_eq!(answer.points.len(), expected.points.len(), "{name}");
        for (i, (a, e)) in answer.points.iter().zip(&expected.points).enumerate() {
            let gap = ((a[0] - e[0]).powi(2) + (a[1] - e[1]).powi(2)).sqrt();
            assert!(gap < 1e-9, "{name}: point {i} off by {gap:e}");
        }
        for (i, (a, e)) in answer.theta.iter().zip(&expected.theta).enumerate() {
            assert!((a - e).abs() < 1e-9, "{name}: theta[{i}] {a} vs {e}");
        }
        assert!((answer.base_displacement.unwrap() - expected.base_displacement).abs() < 1e-9);
        assert!(answer.tip_error < 1e-9 && answer.converged && answer.reachable);
    }
}
