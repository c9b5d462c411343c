//! The free-tail sequential tractrix against the reference answers in `../shared/vectors/free_*`
//! (computed outside this project), through the same `Problem` path `snakectl solve` uses.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use serde::Deserialize;
use snakectl::problem::Problem;

#[derive(Deserialize)]
struct Expected {
    theta: Vec<f64>,
    points: Vec<[f64; 2]>,
    base_displacement: f64,
}

fn vectors() -> Option<Vec<PathBuf>> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/vectors");
    let entries = std::fs::read_dir(&dir).ok()?;
    let mut out: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name.starts_with("free_") && name.ends_with(".problem.json")
        })
        .collect();
    out.sort();
    Some(out)
}

#[test]
fn free_tail_tractrix_matches_the_reference_vectors() {
    let Some(files) = vectors() else {
        eprintln!("reference vectors not present next to the checkout: skipped");
        return;
    };
    assert!(
        !files.is_empty(),
        "the vector directory holds no free_* problems"
    );
    for problem_file in files {
        let expected_file = PathBuf::from(
            problem_file
                .to_str()
                .unwrap()
                .replace(".problem.json", ".expected.json"),
        );
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
